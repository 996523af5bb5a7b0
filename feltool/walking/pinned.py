r"""Hybrid closed loop: walking with a pinned stance foot, guards, impacts, torque allocation.

A walker is modelled with its stance foot pinned (a revolute pivot from the world). Its absolute
link angles, in stance-relative labels, are linear in the joint angles, :math:`\theta = A q`
(thesis App. B: :math:`q_{pivot} = \theta_1,\ q_{swing} = \theta_2 - \theta_1,\
q_{torso} = \theta_3 - \theta_1`); :class:`Walker` is the one place that converts. Each joint's
RMP describes, in absolute angles, the link that the joint moves in the cycle's first step
("gait coordinates" p); with stance label s (0 in the first step, toggled by each impact) the
desired joint angles are

.. math::

    q_d = G_s\,p_d, \qquad G_s = A^{-1}\Pi^s,

where :math:`\Pi` exchanges the stance and swing legs (§3.2.2: :math:`X^+ = [q_2, q_1, q_3, \dots]`).
A step ends when the guard :math:`a^\top q` crosses its value inside the armed window (or by the
clock at the window's end). The impact is either the thesis's relabelling
(:math:`q^+ = A^{-1}\Pi A q^-`, same for :math:`\dot q`) or a rigid, perfectly inelastic foot impact:
with the base freed (model :math:`q_e = (x, z, q)`), Pinocchio's ``impulseDynamics`` solves

.. math::

    M_e(\dot q_e^+ - \dot q_e^-) = J^\top F,\qquad J\dot q_e^+ = 0,
    \qquad \dot q_e^- = (0, 0, \dot q^-),

(Grizzle's planar impact map), followed by the relabelling. Joint torques
:math:`\tau = u_{ff} + u_{fb}` are mapped onto the motors by :class:`Allocation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import repeat

import numpy as np
import pinocchio as pin
import scipy.linalg

from feltool.control.cycle import allocate, stepper
from feltool.control.feedback import FeedbackLaw
from feltool.control.ops import NUMPY
from feltool.dynamics.interface import Dynamics
from feltool.dynamics.pinocchio import mass_matrix


@dataclass
class Allocation:
    r"""Motors and the allocation of joint torques onto them.

    Attributes:
        B: ``(nv, k)`` generalized force of each motor per unit torque (columns :math:`b_m`,
            linearly independent).
        rule: ``inertia_weighted``: :math:`u = (B^\top M^{-1} B)^{-1} B^\top M^{-1}\tau` (the
            motor torques whose accelerations are closest, in the kinetic-energy metric, to those
            :math:`\tau` would produce); ``pseudo_inverse``: :math:`u = B^+\tau`.
        model: The known model, whose :math:`M(q)` the controller uses.
    """

    B: np.ndarray
    rule: str
    model: pin.Model
    data: pin.Data = field(init=False)

    def __post_init__(self):
        self.data = self.model.createData()
        self._pinv = np.linalg.pinv(self.B)
        #: ``(nv, nv - k)``: the directions no motor acts on, :math:`N^\top B = 0`
        self.N = scipy.linalg.null_space(self.B.T)

    def joint_torque(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The joint torques :math:`B u` in [N m] the motors deliver for a wanted ``tau``
        (``inertia_weighted``: :func:`feltool.control.cycle.allocate`, from Pinocchio's CRBA)."""
        if self.rule == "pseudo_inverse":
            return self.B @ (self._pinv @ tau)
        M = mass_matrix(self.model, self.data, q) if self.N.shape[1] else None
        return allocate(NUMPY, M, self.N, tau)


@dataclass
class Walker:
    """Hybrid walking: coordinates, guard, impact and fall check (all from the config).

    Attributes:
        A: ``(nv, nv)`` absolute link angles from joint angles, :math:`\\theta = A q`.
        Pi: ``(nv, nv)`` permutation exchanging stance and swing in absolute angles.
        guard_row, guard_value, guard_sign: the step ends when
            ``guard_sign * (guard_row @ q - guard_value) >= 0`` inside the window.
        window: armed fractions of the nominal step.
        steps_per_cycle: impacts per cycle.
        impact: ``relabel`` or ``rigid``.
        fall_row, fall_max: fall when ``|fall_row @ q| > fall_max`` [rad].
        free_model: the model with a free planar base (x, z), for rigid impacts and foot positions.
        foot_frame: frame id of the swing foot in ``free_model`` (or None).
        placement: ``(angle_index, follow_index, gain)`` of the foot-placement correction
            (indices into the absolute angles), or None.
    """

    A: np.ndarray
    Pi: np.ndarray
    guard_row: np.ndarray
    guard_value: float
    guard_sign: float
    window: tuple[float, float]
    steps_per_cycle: int
    impact: str = "relabel"
    fall_row: np.ndarray | None = None
    fall_max: float = np.inf
    free_model: pin.Model | None = None
    foot_frame: int | None = None
    placement: tuple | None = None

    def __post_init__(self):
        self.A_inv = np.linalg.inv(self.A)
        self.G = (self.A_inv, self.A_inv @ self.Pi)
        self.R = self.A_inv @ self.Pi @ self.A
        if self.free_model is not None:
            self.free_data = self.free_model.createData()

    # -- the one place absolute (thesis) <-> relative (Pinocchio) angles are converted -----------
    def absolute(self, q: np.ndarray) -> np.ndarray:
        """Absolute link angles :math:`\\theta = A q` (rows of a trajectory also work) [rad]."""
        return q @ self.A.T

    def relative(self, theta: np.ndarray) -> np.ndarray:
        """Joint angles :math:`q = A^{-1}\\theta` [rad]."""
        return theta @ self.A_inv.T

    def to_model(self, p: np.ndarray, stance: int) -> np.ndarray:
        """Joint coordinates from gait coordinates at stance label ``stance``: :math:`G_s p`."""
        return self.G[stance % 2] @ p

    def foot_x(self, q: np.ndarray) -> float:
        """Horizontal position of the swing foot relative to the stance foot, in [m]."""
        if self.free_model is None:
            return float("nan")
        qe = np.concatenate([[0.0, 0.0], q])
        pin.framesForwardKinematics(self.free_model, self.free_data, qe)
        return float(self.free_data.oMf[self.foot_frame].translation[0])

    def apply_impact(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State after the impact (and the relabelling), in joint coordinates."""
        if self.impact == "rigid":
            model, data = self.free_model, self.free_data
            qe, ve = np.concatenate([[0.0, 0.0], q]), np.concatenate([[0.0, 0.0], v])
            pin.computeJointJacobians(model, data, qe)
            pin.updateFramePlacements(model, data)
            J = pin.getFrameJacobian(model, data, self.foot_frame,
                                     pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[[0, 2], :]
            v = np.array(pin.impulseDynamics(model, data, qe, ve, J))[2:]
        return self.R @ q, self.R @ v

    def placement_offset(self, q: np.ndarray, v: np.ndarray, qd: np.ndarray, vd: np.ndarray,
                         elapsed: float, Ts: float) -> tuple[float, float]:
        """Foot placement: the desired joint state moves by ``(a c, b c)``, ``elapsed`` [s] into
        a step of nominal length ``Ts`` [s], with ``c`` the joint-space direction of absolute
        angle ``angle_index`` (:attr:`placement_direction`); returns ``(a, b)``. The angle moves
        by ``a = gain * e * r(s)``, with ``e`` the tracking error of absolute angle
        ``follow_index`` (actual - desired) and ``r(s) = 3 s^2 - 2 s^3``, ``s = elapsed / Ts``
        in [0, 1]; ``b`` is its time derivative (the desired acceleration is left unchanged)."""
        _, j, gain = self.placement
        s = min(max(elapsed / Ts, 0.0), 1.0)
        e, ev = float(self.A[j].dot(q - qd)), float(self.A[j].dot(v - vd))
        r = 3 * s**2 - 2 * s**3
        rd = (6 * s - 6 * s**2) / Ts
        return gain * e * r, gain * (ev * r + e * rd)

    @property
    def placement_direction(self) -> np.ndarray:
        """The joint angles that move the placed absolute angle alone, :math:`A^{-1} e_i`."""
        return self.A_inv[:, self.placement[0]]

    def guard(self, q: np.ndarray) -> bool:
        return bool(self.guard_sign * (self.guard_row @ q - self.guard_value) >= 0.0)

    def fallen(self, q: np.ndarray, v: np.ndarray) -> str | None:
        return fall_reason(q, v, self.fall_row, self.fall_max)


def fall_reason(q: np.ndarray, v: np.ndarray, fall_row: np.ndarray | None,
                fall_max: float) -> str | None:
    """Why a walker fell (a non-finite state, or ``|fall_row @ q| > fall_max`` in [rad]), or
    None. Shared by the pinned and the physical walker."""
    if not math.isfinite(sum(q.tolist()) + sum(v.tolist())):  # a NaN or infinity anywhere
        return "the state became non-finite"
    if fall_row is not None:
        angle = float(fall_row @ q)
        if abs(angle) > fall_max:
            return (f"the checked link's angle reached {angle:.3g} rad "
                    f"(walking.fall.max_abs = {fall_max}): the robot fell")
    return None


@dataclass
class HybridLog:
    """One cycle of the hybrid loop (model coordinates), like :class:`feltool.control.closed_loop.CycleLog`.

    Attributes:
        q, v, u_fb: system positions [rad], velocities [rad/s], feedback [N m], ``(n, nv)``.
        u_rows, u_err: each controller's own output and the learning signal (the error
            controllers' joint torques), ``(n, nv)``, as in :class:`feltool.control.closed_loop.CycleLog`.
        q_end, v_end: state after the last step (stance label 0 again after a full cycle).
        Qd, Vd, Ad: desired trajectory in joint coordinates, ``(n, nv)``.
        stance: stance label per step ``(n,)``.
        impacts: ``(step, by_guard, swing-foot x [m])`` of each impact.
        fall: why the robot fell (the cycle then stops early), or None.
    """

    q: np.ndarray
    v: np.ndarray
    u_fb: np.ndarray
    q_end: np.ndarray
    v_end: np.ndarray
    Qd: np.ndarray
    Vd: np.ndarray
    Ad: np.ndarray
    stance: np.ndarray
    impacts: list = field(default_factory=list)
    fall: str | None = None
    u_rows: np.ndarray | None = None
    u_err: np.ndarray | None = None


class HybridLoop:
    """Closed loop stepped one control step at a time, with allocation and walking events.

    Args:
        known: The known model (feedforward and allocation).
        law: Feedback laws (in joint coordinates).
        allocation: Motor allocation, or None for "every non-passive joint is a motor".
        walker: Hybrid walking, or None for a continuous robot.
        actuated: ``(nv,)`` selection used when ``allocation`` is None.
        dt, substeps, integrator, error_rows: as :class:`feltool.control.closed_loop.ClosedLoop`.
    """

    def __init__(self, known: Dynamics, law: FeedbackLaw, allocation: Allocation | None,
                 walker: Walker | None, actuated: np.ndarray, dt: float, substeps: int = 1,
                 integrator: str = "semi_implicit_euler", error_rows: np.ndarray | None = None):
        self.known, self.law, self.allocation, self.walker = known, law, allocation, walker
        self.actuated = np.asarray(actuated, dtype=float)
        self.error_rows = (np.zeros(len(self.actuated)) if error_rows is None
                           else np.asarray(error_rows, dtype=float))
        self.dt, self.substeps, self.integrator = dt, substeps, integrator

    def initial_state(self, P: np.ndarray, Pv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Start on the desired trajectory (stance label 0), stabilized quantities on target."""
        G = self.walker.G[0] if self.walker else np.eye(len(P[0]))
        return self.law.consistent_state(G @ P[0], G @ Pv[0])

    def run_cycle(self, plant: Dynamics, q: np.ndarray, v: np.ndarray, P: np.ndarray,
                  Pv: np.ndarray, Pa: np.ndarray) -> HybridLog:
        r"""One cycle from ``(q, v)`` with desired gait-coordinate trajectories ``P, Pv, Pa``
        ``(n, nv)``; ``plant`` is the simulated world (the known model, or a changed one).

        A linear law's feedback is affine in the state, :math:`u_{fb} = b_k - K_P C q - K_D C
        \dot q` with :math:`b_k = K_P r_k + K_D \dot r_k` computed for every step and stance
        label before the loop (the foot placement adds :math:`a K_P C c + b K_D C c`), so a
        step is a few vector operations around Pinocchio's RNEA, CRBA (allocation) and ABA."""
        n, nv = P.shape
        W, law, alloc = self.walker, self.law, self.allocation
        Q, V, U = (np.zeros((n, nv)) for _ in range(3))
        placing = W is not None and W.placement is not None
        offsets = np.zeros((n, 2)) if placing else None  # (a, b) of the foot placement
        # the desired joint state at each stance label, q_d = G_s p_d, and its references
        G = W.G if W else (np.eye(nv),)
        desired = [(P @ g.T, Pv @ g.T, Pa @ g.T) for g in G]
        linear = law.linear  # its own outputs are the joint torques, the learning signal their
        if linear:           # error rows (feltool.control.cycle.feedback), formed after the loop
            Kq, Kv = law.kp[:, None] * law.C, law.kd[:, None] * law.C
            affine = []
            for qd, vd, _ in desired:
                R, Rd = law.references(qd, vd)
                affine.append(law.kp * R + law.kd * Rd)
        else:  # (each label its own iterator)
            affine = [repeat(None, n) for _ in desired]
            Urows, Uerr = np.zeros((n, nv)), np.zeros((n, nv))
        rows = [list(zip(*d, b)) for d, b in zip(desired, affine)]
        if placing:
            c = W.placement_direction
            tc = law.reference_rows()[0] @ c
            kc, kdc = law.kp * tc, law.kd * tc
        impacts, stance, fall = [], 0, None
        h = self.dt / self.substeps
        Ts = n * self.dt / W.steps_per_cycle if W else None
        lo = hi = np.inf
        if W:
            lo, hi = W.window[0] * Ts - 1e-9, W.window[1] * Ts - 1e-9
        k_step = 0  # first control step of the current step
        step = stepper(NUMPY, plant.forward, h, self.substeps,
                       self.integrator == "semi_implicit_euler")
        inverse = self.known.inverse
        fallen = W.fallen if W else lambda q, v: fall_reason(q, v, None, np.inf)
        k_end = n
        for k in range(n):
            qd, vd, ad, b = rows[stance][k]
            Q[k], V[k] = q, v
            if placing:
                a_, b_ = offsets[k] = W.placement_offset(q, v, qd, vd, (k - k_step) * self.dt,
                                                          Ts)
                qd, vd = qd + a_ * c, vd + b_ * c
                if linear:
                    b = b + a_ * kc + b_ * kdc
            if linear:
                u = U[k] = b - Kq.dot(q) - Kv.dot(v)
            else:
                r, rd = law.reference(qd, vd)
                u, Urows[k], Uerr[k] = law.terms(q, v, r, rd, self.error_rows)
                U[k] = u
            tau = inverse(qd, vd, ad) + u
            tau = alloc.joint_torque(q, tau) if alloc else self.actuated * tau
            q, v = step(q, v, tau)
            fall = fallen(q, v)
            if fall:
                k_end = k + 1
                break
            t = (k + 1) * self.dt
            if t >= lo:
                by_guard = W.guard(q)
                if by_guard or t >= hi:
                    impacts.append((k + 1, bool(by_guard), W.foot_x(q)))
                    q, v = W.apply_impact(q, v)
                    stance = 1 - stance
                    k_step = k + 1
                    j = len(impacts)
                    lo, hi = ((j + W.window[0]) * Ts - 1e-9, (j + W.window[1]) * Ts - 1e-9) \
                        if j < W.steps_per_cycle else (np.inf, np.inf)
        labels = np.zeros(k_end, dtype=int)
        for k_impact, _, _ in impacts:
            labels[k_impact:] ^= 1
        steps = np.arange(k_end)
        Qd, Vd, Ad = (np.stack([d[i] for d in desired])[labels, steps] for i in range(3))
        if placing:  # the same numbers as the loop's q_d + a c
            Qd, Vd = Qd + offsets[:k_end, :1] * c, Vd + offsets[:k_end, 1:] * c
        U = U[:k_end]
        if linear:
            u_rows, u_err = U, np.where(self.error_rows > 0, U, 0.0)
        else:
            u_rows, u_err = Urows[:k_end], Uerr[:k_end]
        return HybridLog(Q[:k_end], V[:k_end], U, q, v, Qd, Vd, Ad, labels, impacts, fall,
                         u_rows, u_err)

    def jacobian_derivatives(self, log: HybridLog) -> tuple:
        """``(u_ff, Dq G, Dv G, M G)`` along the cycle: the inverse model's derivatives with
        respect to the gait coordinates (chain rule through :math:`q_d = G_s p_d`)."""
        u_ff, Dq, Dv, M = self.known.inverse_derivatives_batch(log.Qd, log.Vd, log.Ad)
        if self.walker is None:
            return u_ff, Dq, Dv, M
        Gs = np.stack(self.walker.G)[log.stance]  # (n, nv, nv)
        mul = lambda D: np.einsum("kij,kjl->kil", D, Gs)  # noqa: E731
        return u_ff, mul(Dq), mul(Dv), mul(M)
