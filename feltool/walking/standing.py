r"""A walker's standing pose, from its kinematics alone: feet on the ground, legs straight under
the hip, the torso at its target.

The zero angles of a walker's URDF say nothing about how it stands: legs modelled along +z (as
FROST's five-link walker is) stand with their hips near :math:`\pi`, legs along -z at 0, a URDF
rooted at a foot with the hip somewhere above. :func:`standing_pose` finds the pose instead: with
the base at the origin and its pitch at the torso's target (or free when ``base_pitch`` is a
leg's angle, a root-leg walker), the joints that move the feet take the angles at which both
feet are lowest and straight below the base, :math:`\min \sum_f z_f + w\,x_f^2` (a straight leg
is the one that reaches furthest down), from a few starts (every joint at 0, ±π/2 and π) within
the joints' limits. The hip height is then the feet's depth below the base.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.optimize import minimize

from feltool.walking.model import BASE_JOINTS, WalkerModel

#: Weight of the feet's horizontal offset from the base against their height [1/m].
ALIGN = 10.0


@dataclass(frozen=True)
class Standing:
    """A standing pose.

    Attributes:
        q: Minimal coordinates ``(nv,)`` (a continuous joint's angle), the base's x and z 0 and
            the feet ``height`` below it, in [rad] and [m].
        height: The base's height above the lower foot in [m] (the hip height).
    """

    q: np.ndarray
    height: float


def standing_pose(walker: WalkerModel, pitch: float | None = None) -> Standing:
    """The walker standing (see the module docstring), the torso's pitch at ``pitch`` [rad]
    (default 0) unless ``base_pitch`` is a leg's angle."""
    model, robot = walker.model, walker.robot
    data = model.createData()
    base = {robot.v_index(n) for n in walker.base}
    leg_angle = any(BASE_JOINTS[2] in pair for pair in walker.legs)
    moving = _joints_moving_feet(walker)
    free = sorted(i for i in moving if i not in base or (leg_angle and i == _pitch(walker)))
    q0 = np.zeros(model.nv)
    if not leg_angle and BASE_JOINTS[2] in walker.base:
        q0[_pitch(walker)] = 0.0 if pitch is None else float(pitch)
    lower, upper = _limits(model)
    bounds = [(lower[i] if np.isfinite(lower[i]) else None,
               upper[i] if np.isfinite(upper[i]) else None) for i in free]

    def cost(x: np.ndarray) -> tuple[float, np.ndarray]:
        q = q0.copy()
        q[free] = x
        qc = to_configuration(model, q)
        pin.computeJointJacobians(model, data, qc)
        pin.updateFramePlacements(model, data)
        f, grad = 0.0, np.zeros(len(free))
        for frame in walker.feet.values():
            p = data.oMf[frame].translation
            J = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, free]
            f += p[2] + ALIGN * p[0] ** 2
            grad += J[2] + 2.0 * ALIGN * p[0] * J[0]
        return float(f), grad

    best = None
    for start in (0.0, np.pi / 2, -np.pi / 2, np.pi):
        x0 = np.clip(np.full(len(free), start), np.where(np.isfinite(lower[free]), lower[free],
                     -np.inf), np.where(np.isfinite(upper[free]), upper[free], np.inf))
        res = minimize(cost, x0, jac=True, method="L-BFGS-B", bounds=bounds or None,
                       options={"maxiter": 500, "ftol": 1e-14, "gtol": 1e-10})
        if best is None or res.fun < best.fun - 1e-9:
            best = res
    q = q0.copy()
    if free:
        q[free] = _wrapped(best.x, lower[free], upper[free])
    pin.framesForwardKinematics(model, data, to_configuration(model, q))
    height = float(max(-data.oMf[f].translation[2] for f in walker.feet.values()))
    q[robot.v_index(walker.base[1])] = height if len(walker.base) > 1 else 0.0
    return Standing(q=q, height=height)


def to_configuration(model: pin.Model, q_min: np.ndarray) -> np.ndarray:
    """Pinocchio's configuration (nq) from minimal coordinates (nv): a continuous joint's
    angle becomes ``(cos, sin)``."""
    q = np.zeros(model.nq)
    for j in model.joints[1:]:
        if j.nq == 2 and j.nv == 1:
            q[j.idx_q:j.idx_q + 2] = np.cos(q_min[j.idx_v]), np.sin(q_min[j.idx_v])
        elif j.nv == 1:
            q[j.idx_q] = q_min[j.idx_v]
    return q


def _pitch(walker: WalkerModel) -> int:
    return walker.robot.v_index(walker.base[2] if len(walker.base) > 2 else BASE_JOINTS[2])


def _joints_moving_feet(walker: WalkerModel) -> set[int]:
    """Velocity indices of the one-DoF joints between the root and a foot."""
    model = walker.model
    out: set[int] = set()
    for frame in walker.feet.values():
        j = model.frames[frame].parentJoint
        while j > 0:
            if model.joints[j].nv == 1:
                out.add(int(model.joints[j].idx_v))
            j = model.parents[j]
    return out


def _limits(model: pin.Model) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = np.full(model.nv, -np.inf), np.full(model.nv, np.inf)
    for j in model.joints[1:]:
        if j.nq == 1 and j.nv == 1:
            lo, hi = model.lowerPositionLimit[j.idx_q], model.upperPositionLimit[j.idx_q]
            lower[j.idx_v] = lo if np.isfinite(lo) and lo > -1e10 else -np.inf
            upper[j.idx_v] = hi if np.isfinite(hi) and hi < 1e10 else np.inf
    return lower, upper


def _wrapped(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Angles into (-π, π] where the limits allow it."""
    w = (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi
    w[np.isclose(w, -np.pi)] = np.pi
    ok = (w >= lower) & (w <= upper)
    return np.where(ok, w, x)
