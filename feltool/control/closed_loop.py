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

from feltool.control.cycle import advance, euler_map, plain
from feltool.control.feedback import FeedbackLaw
from feltool.control.ops import NUMPY
from feltool.dynamics.interface import Dynamics


@dataclass
class CycleLog:
    """What happened over one cycle of n steps.

    Attributes:
        q: System joint positions at each step's start, ``(n, nq)`` in [rad].
        v: System joint velocities, ``(n, nv)`` in [rad/s].
        u_fb: Feedback torques on the joints, ``(n, nv)`` in [N m].
        q_end, v_end: State after the last step.
        u_rows: Each controller's own output, ``(n, nv)`` (equals ``u_fb`` for linear laws).
        u_err: The learning signal: joint torques of the error controllers, ``(n, nv)``.
        limit_hits: Steps per joint beyond a position limit and beyond a torque limit.
        end_measured: The state after the last step as the controller measures it ``(q, v)``
            (a noisy loop's, :mod:`feltool.plant.disturbances`); None: ``(q_end, v_end)``.
    """

    q: np.ndarray
    v: np.ndarray
    u_fb: np.ndarray
    q_end: np.ndarray
    v_end: np.ndarray
    u_rows: np.ndarray | None = None
    u_err: np.ndarray | None = None
    limit_hits: tuple[np.ndarray, np.ndarray] | None = None
    end_measured: tuple[np.ndarray, np.ndarray] | None = None

    def measured_change(self, dynamics: Dynamics) -> np.ndarray:
        """``(2nv,)``: the tangent change of the measured state over the cycle, from its first
        step's start to its end."""
        q_end, v_end = self.end_measured or (self.q_end, self.v_end)
        return np.concatenate([dynamics.difference(self.q[0], q_end), v_end - self.v[0]])


@dataclass
class Limits:
    """Joint and torque limits of the simulated robot (from the URDF) and what to do at them.

    Attributes:
        lower, upper: Position limits ``(nq,)`` in [rad] or [m].
        effort: Torque limits ``(nv,)`` in [N m] or [N].
        joints: ``report`` (count the steps outside), ``enforce`` (also hold the joint at the
            limit: position clamped, velocity into the limit set to zero), or ``ignore``.
        torques: ``report`` (count the steps the commanded torque exceeds the limit),
            ``saturate`` (also clip the applied torque), or ``ignore``.
    """

    lower: np.ndarray
    upper: np.ndarray
    effort: np.ndarray
    joints: str = "report"
    torques: str = "report"

    def hits(self, Q: np.ndarray, Tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Steps per joint at or beyond a position limit, and beyond a torque limit."""
        joints = np.zeros(Q.shape[1], int)
        torques = np.zeros(Tau.shape[1], int)
        if self.joints != "ignore":
            tol = 1e-12
            joints = ((Q <= self.lower + tol) | (Q >= self.upper - tol)).sum(axis=0) \
                if self.joints == "enforce" else ((Q < self.lower) | (Q > self.upper)).sum(axis=0)
        if self.torques != "ignore":
            torques = (np.abs(Tau) > self.effort * (1 + 1e-12)).sum(axis=0)
        return joints, torques


class ClosedLoop:
    """Simulates the robot under feedforward and feedback.

    Args:
        dynamics: The forward model (the plant).
        law: The feedback laws.
        actuated: ``(nv,)`` 1 for actuated joints, 0 for passive ones (the selection S).
        dt: Control step in [s].
        substeps: Integration steps per control step.
        integrator: ``semi_implicit_euler`` or ``explicit_euler``.
        error_rows: ``(nv,)`` 1 for the controllers whose feedback is the learning signal.
        limits: Joint and torque limits (None: no checks).
    """

    def __init__(self, dynamics: Dynamics, law: FeedbackLaw, actuated: np.ndarray, dt: float,
                 substeps: int = 1, integrator: str = "semi_implicit_euler",
                 error_rows: np.ndarray | None = None, limits: Limits | None = None):
        self.dynamics = dynamics
        self.limits = limits
        self.error_rows = (np.zeros(len(actuated)) if error_rows is None
                           else np.asarray(error_rows, dtype=float))
        self.law = law
        self.actuated = np.asarray(actuated, dtype=float)
        self.dt = dt
        self.substeps = substeps
        self.integrator = integrator

    def advance(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """State after one control step under joint torques ``tau`` (already actuated)."""
        euclidean = getattr(self.dynamics, "euclidean", False)
        return advance(NUMPY, self.dynamics.forward, q, v, tau, self.dt / self.substeps,
                       self.substeps, self.integrator == "semi_implicit_euler", self.limits,
                       None if euclidean else self.dynamics.integrate)

    def run_cycle(self, q: np.ndarray, v: np.ndarray, R: np.ndarray, Rd: np.ndarray,
                  u_ff: np.ndarray) -> CycleLog:
        """Run n steps with references ``R, Rd`` and feedforward ``u_ff`` (each ``(n, nv)``).

        The feedback is affine in the state, :math:`u_{fb}^k = b^k - K x` with
        :math:`x = (q, \\dot q)`, :math:`b^k = K_P r^k + K_D \\dot r^k` and
        :math:`K = [K_P C,\\ K_D C]`, so the loop computes only :math:`u^k = S(u_{ff}^k + b^k) - S K x`
        and the logged feedback is recovered afterwards from the logged states.
        """
        if not (getattr(self.dynamics, "euclidean", False) and self.law.linear):
            return self._run_cycle_general(q, v, R, Rd, u_ff)
        n, nv = len(R), v.shape[0]
        law, S = self.law, self.actuated
        K = np.hstack([law.kp[:, None] * law.C, law.kd[:, None] * law.C])
        B = law.kp * R + law.kd * Rd
        F = S * (u_ff + B)
        SK = S[:, None] * K
        lim, semi = self.limits, self.integrator == "semi_implicit_euler"
        X = np.empty((n + 1, 2 * nv))
        X[0, :nv], X[0, nv:] = q, v
        if plain(self.substeps, semi, lim):  # x+ = Phi x + Gamma a, written into the log
            Phi, Gamma = euler_map(self.dt, nv)
            forward = self.dynamics.forward
            for x, f, qk, vk, x_next in zip(X, F, X[:, :nv], X[:, nv:], X[1:]):
                Gamma.dot(forward(qk, vk, f - SK.dot(x)), out=x_next)
                x_next += Phi.dot(x)
        else:  # sub-steps, explicit Euler or limits to apply
            for x, f, x_next in zip(X, F, X[1:]):  # (.dot: less call overhead than @)
                x_next[:nv], x_next[nv:] = self.advance(x[:nv], x[nv:], f - SK.dot(x))
        q, v, X = X[n, :nv].copy(), X[n, nv:].copy(), X[:n]
        U = B - X @ K.T
        log = CycleLog(X[:, :nv], X[:, nv:], U, q, v, U, U * self.error_rows)
        if lim is not None:
            log.limit_hits = lim.hits(log.q, F - X @ SK.T)
        return log

    def _run_cycle_general(self, q, v, R, Rd, u_ff) -> CycleLog:
        """The same loop for nonlinear feedback laws (frame angles) and for models whose
        configuration is not a plain vector (``pin.integrate``)."""
        n, nv = len(R), v.shape[0]
        Q, V = np.empty((n, q.shape[0])), np.empty((n, nv))
        U, Urows, Uerr = np.empty((n, nv)), np.empty((n, nv)), np.empty((n, nv))
        Tau = np.empty((n, nv))
        for k in range(n):
            Q[k], V[k] = q, v
            U[k], Urows[k], Uerr[k] = self.law.terms(q, v, R[k], Rd[k], self.error_rows)
            Tau[k] = self.actuated * (u_ff[k] + U[k])
            q, v = self.advance(q, v, Tau[k])
        log = CycleLog(Q, V, U, q, v, Urows, Uerr)
        if self.limits is not None and Q.shape[1] == nv:
            log.limit_hits = self.limits.hits(Q, Tau)
        return log
