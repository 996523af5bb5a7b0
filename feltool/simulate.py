r"""The closed loop: feedforward + feedback through the forward model (ABA), integrated in time.

One control step k (the DESIGN's data flow):

.. math::

    u_{fb}^k = K_P (r^k - C q^k) + K_D (\dot r^k - C \dot q^k), \quad
    u^k = S (u_{ff}^k + u_{fb}^k), \quad
    \ddot q = \mathrm{ABA}(q, \dot q, u^k),

integrated over ``substeps`` sub-steps of the control step with the torque held
(semi-implicit Euler: :math:`\dot q \mathrel{+}= h\ddot q;\ q \mathrel{+}= h\dot q`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feltool.control import FeedbackLaw
from feltool.dynamics import Dynamics


@dataclass
class CycleLog:
    """What happened over one cycle of n steps.

    Attributes:
        q: System joint positions at each step's start, ``(n, nq)`` in [rad].
        v: System joint velocities, ``(n, nv)`` in [rad/s].
        u_fb: Feedback torques, ``(n, nv)`` in [N m].
        q_end, v_end: State after the last step.
    """

    q: np.ndarray
    v: np.ndarray
    u_fb: np.ndarray
    q_end: np.ndarray
    v_end: np.ndarray


class ClosedLoop:
    """Simulates the robot under feedforward and feedback.

    Args:
        dynamics: The forward model (the plant).
        law: The feedback laws.
        actuated: ``(nv,)`` 1 for actuated joints, 0 for passive ones (the selection S).
        dt: Control step in [s].
        substeps: Integration steps per control step.
        integrator: ``semi_implicit_euler`` or ``explicit_euler``.
    """

    def __init__(self, dynamics: Dynamics, law: FeedbackLaw, actuated: np.ndarray, dt: float,
                 substeps: int = 1, integrator: str = "semi_implicit_euler"):
        self.dynamics = dynamics
        self.law = law
        self.actuated = np.asarray(actuated, dtype=float)
        self.dt = dt
        self.substeps = substeps
        self.integrator = integrator

    def advance(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State after one control step under joint torques ``tau`` (already actuated)."""
        h = self.dt / self.substeps
        forward, integrate = self.dynamics.forward, self.dynamics.integrate
        semi = self.integrator == "semi_implicit_euler"
        for _ in range(self.substeps):
            a = forward(q, v, tau)
            if semi:
                v = v + h * a
                q = integrate(q, h * v)
            else:
                q, v = integrate(q, h * v), v + h * a
        return q, v

    def run_cycle(self, q: np.ndarray, v: np.ndarray, R: np.ndarray, Rd: np.ndarray,
                  u_ff: np.ndarray) -> CycleLog:
        """Run n steps with references ``R, Rd`` and feedforward ``u_ff`` (each ``(n, nv)``)."""
        n = len(R)
        Q = np.empty((n, q.shape[0]))
        V = np.empty((n, v.shape[0]))
        U = np.empty((n, v.shape[0]))
        C, kp, kd, S = self.law.C, self.law.kp, self.law.kd, self.actuated
        advance = self.advance
        for k in range(n):
            Q[k], V[k] = q, v
            u_fb = kp * (R[k] - C @ q) + kd * (Rd[k] - C @ v)
            U[k] = u_fb
            q, v = advance(q, v, S * (u_ff[k] + u_fb))
        return CycleLog(Q, V, U, q, v)
