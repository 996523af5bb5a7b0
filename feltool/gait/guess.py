r"""The gait designer's initial guess: three postures of a step, interpolated.

The step starts with both feet on the ground, the stance foot at the origin and the trailing
foot a step length :math:`L` behind; at mid-step the swing foot passes the stance foot
(at the ground for a walker without knees, 10 % of the hip height above it with knees); the step
ends in the mirror image of its start: :math:`q_N = R\,(q_0 + L e_x)` (relabelling :math:`R`, an
involution). Each posture is a small inverse-kinematics problem (the feet where they must be,
the joints as close as possible to the walker's standing pose (:mod:`feltool.walking.standing`:
legs straight under the hip, whatever the URDF's zero angles; the torso at its target pitch,
the joints just inside their limits), solved by IPOPT in milliseconds. The knots interpolate the
three postures piecewise linearly in time; velocities are their finite differences.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from feltool.walking.model import WalkerModel


@dataclass
class Guess:
    """Knot values (rows) of q and v (minimal coordinates), the post-impact velocity, T [s], L [m]."""

    q: np.ndarray
    v: np.ndarray
    v_plus: np.ndarray
    duration: float
    step_length: float


def _duration_and_length(W, spec) -> tuple[float, float]:
    h, g = W.height, W.gravity
    T = spec.duration
    L = spec.step_length
    if L is None and spec.speed is not None and T is not None:
        L = spec.speed * T
    if L is None:
        L = 0.45 * h
    if T is None:
        T = L / spec.speed if spec.speed else 2.2 * np.sqrt(h / g)
        T = float(np.clip(T, *spec.duration_bounds))
    return float(T), float(L)


def _posture(W, spec, nominal: np.ndarray, swing_at: tuple[float, float]) -> np.ndarray:
    """Minimal coordinates with the stance foot at (0, 0), the swing foot at ``swing_at`` [m],
    closest to ``nominal`` (joint limits kept)."""
    q = ca.SX.sym("q", W.nv)
    qp = W.to_pin(q)
    zero = ca.DM.zeros(W.nv)
    p_st = W.feet[spec.stance](qp, zero, zero)[0]
    p_sw = W.feet[spec.swing](qp, zero, zero)[0]
    g = ca.vertcat(p_st[0], p_st[2], p_sw[0] - swing_at[0], p_sw[2] - swing_at[1])
    weight = np.ones(W.nv)
    weight[[W.ix, W.iz]] = 1e-3  # the base's position follows the feet
    f = ca.sumsqr(np.sqrt(weight) * (q - nominal))
    solver = ca.nlpsol("posture", "ipopt", {"x": q, "f": f, "g": g},
                       {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                        "ipopt.max_iter": 200})
    lb = np.where(np.isfinite(W.lower), W.lower, -1e19)
    ub = np.where(np.isfinite(W.upper), W.upper, 1e19)
    sol = solver(x0=np.clip(nominal, lb, ub), lbx=lb, ubx=ub, lbg=0.0, ubg=0.0)
    return np.array(sol["x"]).ravel()


def initial_guess(walker: WalkerModel, W, spec) -> Guess:
    """Knot values for :func:`feltool.gait.design.design_gait` (see the module's docstring)."""
    N = spec.knots
    T, L = _duration_and_length(W, spec)
    nominal = W.stand.copy()  # standing (feltool.walking.standing), whatever the zero angles
    for i in range(W.nv):
        lo, hi = W.lower[i], W.upper[i]
        if np.isfinite(lo) and np.isfinite(hi):
            margin = 0.05 * (hi - lo)
            nominal[i] = np.clip(nominal[i], lo + margin, hi - margin)
    nominal[W.ix], nominal[W.iz] = 0.0, W.height
    if spec.pitch_joint is not None and spec.pitch_target is not None:
        nominal[walker.robot.v_index(spec.pitch_joint)] = spec.pitch_target
    start_nominal = nominal.copy()
    start_nominal[W.ix] = -L / 2
    q_start = _posture(W, spec, start_nominal, (-L, 0.0))
    lift = 0.1 * W.height if len(walker.legs) > 1 else 0.0
    q_mid = _posture(W, spec, nominal, (0.0, lift))
    shift = np.zeros(W.nv)
    shift[W.ix] = L
    q_end = W.R @ (q_start + shift)
    t = np.linspace(0.0, T, N + 1)
    s = t / T
    q = np.where((s <= 0.5)[:, None],
                 q_start + (q_mid - q_start) * (2 * s)[:, None],
                 q_mid + (q_end - q_mid) * (2 * s - 1)[:, None])
    v = np.gradient(q, t, axis=0)
    v_plus = W.R @ v[0]
    return Guess(q=q, v=v, v_plus=v_plus, duration=T, step_length=L)
