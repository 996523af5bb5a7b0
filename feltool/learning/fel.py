r"""Feedback error learning of RMP parameters (thesis §3.1, eq. 3.4-3.6).

The feedforward torque is the known inverse model applied to the desired trajectory,
:math:`u_{ff}^k = f(q_d^k, \dot q_d^k, \ddot q_d^k)` (RNEA, eq. 3.1), and the desired trajectory
comes from the RMPs with parameters :math:`\theta`. The learner moves :math:`\theta` along

.. math::

    \theta_{h+1} = \theta_h + \alpha \odot \sum_{k=1}^{N} J_k^\top e_k, \qquad
    J_k = \frac{\partial u_{ff}^k}{\partial\theta}
        = \frac{\partial f}{\partial q}\frac{\partial q_d^k}{\partial\theta}
        + \frac{\partial f}{\partial \dot q}\frac{\partial \dot q_d^k}{\partial\theta}
        + M(q_d^k)\frac{\partial \ddot q_d^k}{\partial\theta}
    \qquad \text{(eq. 3.6)}

where :math:`e_k` is the error signal: the stabilizing feedback (fully actuated robots) or all
feedback (underactuated robots), zero elsewhere. ``sensitivity: exact`` chains Pinocchio's RNEA
derivatives with the RMP's exact sensitivities; ``finite_difference`` differentiates the whole
chain numerically as the thesis did. ``update: gauss_newton`` replaces the gradient step on the
weights by the Levenberg-Marquardt step
:math:`\Delta w = \alpha_w (J_w^\top J_w + \lambda\,\overline{\mathrm{diag}}\,I)^{-1} J_w^\top e`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# FEL_UPDATES: the learning.update values this learner runs, defined with the schema (the
# config's checks read them too), the name kept here for the learner's users
from feltool.config.learning import FEL_UPDATES as FEL_UPDATES
from feltool.control.cycle import fel_sums, fel_update, goal_step_scale
from feltool.control.ops import NUMPY
from feltool.dynamics.interface import Dynamics
from feltool.learning.loop_map import apply_q, error_sensitivity, feedback_gains, q_filter, transient_error
from feltool.motion.phase import PhaseSamples
from feltool.motion.rmp import PrimitiveSet


@dataclass
class FeedbackErrorLearner:
    """The learner of eq. 3.6.

    Attributes:
        primitives: The forward trajectory generator.
        learned: Indices into ``theta`` that are learned (the learned joints' weights and goals).
        is_goal: For each learned index, whether it is a goal (else a weight).
        error_mask: ``(nv,)`` 1 where a joint's feedback is part of the error signal.
        rates: Learning rate per learned index.
        update: ``gradient`` or ``gauss_newton``.
        damping: Levenberg-Marquardt damping relative to the mean diagonal of J^T J.
        sensitivity: ``exact`` or ``finite_difference``.
        fd_epsilon: Relative finite-difference step.
        fit: What the Gauss-Newton step fits: ``feedforward`` (:math:`J`) or ``closed_loop``
            (the lifted closed-loop map times :math:`J`, :meth:`closed_loop_step`).
        loop: For ``closed_loop``: ``law`` (the :class:`~feltool.control.feedback.FeedbackLaw`),
            ``S`` (the actuation selection), ``dt`` [s], ``substeps``, ``semi_implicit`` and
            ``q_filter_hz`` [Hz] or None.
    """

    primitives: PrimitiveSet
    learned: np.ndarray
    is_goal: np.ndarray
    error_mask: np.ndarray
    rates: np.ndarray
    update: str = "gradient"
    damping: float = 1e-2
    sensitivity: str = "exact"
    fd_epsilon: float = 1e-6
    fit: str = "feedforward"
    loop: dict | None = None

    def set_casadi_jacobian(self, fn) -> None:
        """Install the CasADi function ``theta -> J`` used by ``sensitivity: casadi``."""
        self._casadi = fn

    def __post_init__(self):
        self._casadi = None
        # Learned blocks: (velocity index, columns into the learned vector); a learned joint
        # learns every parameter of its RMP, so a block's sensitivities are used whole.
        self._blocks = []
        pos = {int(p): c for c, p in enumerate(self.learned)}
        for i in self.primitives.primitives:
            sl = self.primitives.slices[i]
            cols = [pos[p] for p in range(sl.start, sl.stop) if p in pos]
            if cols:
                if len(cols) != sl.stop - sl.start:
                    raise ValueError("a learned joint learns every parameter of its RMP")
                self._blocks.append((i, np.array(cols)))

    @property
    def n_learned(self) -> int:
        return len(self.learned)

    def jacobian(self, dynamics: Dynamics, theta: np.ndarray, Qd: np.ndarray, Vd: np.ndarray,
                 Ad: np.ndarray, derivatives: tuple | None = None,
                 samples: np.ndarray | None = None, cycle: PhaseSamples | None = None,
                 transients: dict | None = None) -> np.ndarray:
        """:math:`J_k = \\partial u_{ff}^k / \\partial\\theta_{learned}`, shape ``(n, nv, P)``.

        ``derivatives``: ``(Dq, Dv, M)`` of the inverse model along ``Qd, Vd, Ad`` if already
        computed (see :func:`feedforward_and_derivatives`). ``samples``: the RMP sample of each
        row of ``Qd`` (a walker whose phase restarts at touchdown), default ``0 .. n-1``.
        ``cycle``: the phase at each row (default the nominal cycle); ``transients``: those of
        :meth:`PrimitiveSet.desired` (for finite differences; they do not depend on θ).
        """
        n, nv = Qd.shape
        J = np.zeros((n, nv, self.n_learned))
        if self.n_learned == 0:
            return J
        if self.sensitivity == "finite_difference":
            return self._jacobian_fd(dynamics, theta, cycle, transients)
        if self.sensitivity == "casadi":
            if self._casadi is None:
                raise RuntimeError("sensitivity 'casadi' needs set_casadi_jacobian() first")
            return np.asarray(self._casadi(theta)).reshape(n, nv, self.n_learned)
        if derivatives is None:
            derivatives = dynamics.inverse_derivatives_batch(Qd, Vd, Ad)[1:]
        Dq, Dv, M = derivatives
        sens = self.primitives.sensitivities(cycle)
        for i, cols in self._blocks:
            Xq, Xv, Xa = sens[i]
            if samples is not None:
                Xq, Xv, Xa = Xq[samples], Xv[samples], Xa[samples]
            J[:, :, cols] = (Dq[:, :, i, None] * Xq[:, None, :] + Dv[:, :, i, None] * Xv[:, None, :]
                             + M[:, :, i, None] * Xa[:, None, :])
        return J

    def _jacobian_fd(self, dynamics: Dynamics, theta: np.ndarray, cycle: PhaseSamples | None,
                     transients: dict | None) -> np.ndarray:
        """Central differences of the whole chain RMP -> RNEA, one parameter at a time."""
        n, nv = (cycle or self.primitives.nominal).n, self.primitives.nv
        J = np.zeros((n, nv, self.n_learned))
        for c, p in enumerate(self.learned):
            eps = self.fd_epsilon * max(1.0, abs(theta[p]))
            taus = []
            for sign in (1.0, -1.0):
                th = theta.copy()
                th[p] += sign * eps
                Q, V, A = self.primitives.desired(th, cycle, transients)
                taus.append(feedforward(dynamics, Q, V, A))
            J[:, :, c] = (taus[0] - taus[1]) / (2.0 * eps)
        return J

    def closed_loop_step(self, theta: np.ndarray, J: np.ndarray, derivatives: tuple,
                         E: np.ndarray, Qd: np.ndarray,
                         cycle: PhaseSamples | None = None,
                         dx: np.ndarray | None = None) -> np.ndarray:
        """The Gauss-Newton step through the closed loop (``learning.fit: closed_loop``,
        :mod:`feltool.learning.loop_map`): the weights' step fits :math:`Q D\\Delta w` to
        :math:`Q e`, :math:`D` the lifted closed-loop map times ``J`` along the desired
        trajectory (``derivatives``: the inverse model's ``(Dq, Dv, M)`` there); the goals keep
        the gradient step of :meth:`step` on the error the weights' step is predicted to
        leave, :math:`e - D\\Delta w` (a goal and the weights' mean move the same offset: on
        all of :math:`e` both would take it out). ``dx`` ``(2nv,)``: the state's tangent change
        over the cycle; with ``loop["remove_transient"]`` the fit is to the error without the
        transient of the cycle's start (:func:`~feltool.learning.loop_map.transient_error`)."""
        if self.n_learned == 0:
            return theta.copy()
        L = self.loop
        n = J.shape[0]
        Bref = None
        law = L["law"]
        if (law.tracking & (law.C != 0).any(axis=1)).any():
            dQ, dV = np.zeros_like(J), np.zeros_like(J)
            for (i, cols), (Xq, Xv, _) in zip(self._blocks, self.learned_sensitivities(cycle)):
                dQ[:, i, cols], dV[:, i, cols] = Xq, Xv
            Ct = law.C * law.tracking[:, None]
            Bref = (law.kp[None, :, None] * np.einsum("ij,kjp->kip", Ct, dQ)
                    + law.kd[None, :, None] * np.einsum("ij,kjp->kip", Ct, dV))
        gains = feedback_gains(law, Qd, self.error_mask)
        D = error_sensitivity(derivatives, J, gains, L["S"], L["dt"], Bref, True,
                              L.get("substeps", 1), L.get("semi_implicit", True))
        if dx is not None and L.get("remove_transient"):
            E = E - transient_error(derivatives, gains, L["S"], L["dt"], dx,
                                    L.get("substeps", 1), L.get("semi_implicit", True))
        keep = q_filter(n, n * L["dt"], L.get("q_filter_hz"))
        Dq, Eq = apply_q(D, keep), apply_q(E, keep)
        hess = np.einsum("krp,krs->ps", Dq, Dq)
        grad = np.einsum("kr,krp->p", Eq, Dq)
        # the weights' Levenberg-Marquardt step, then the goals' gradient step of step() on the
        # error that step leaves (both on all of it: an offset corrected twice)
        theta_next = self.apply(theta, np.where(self.is_goal, 0.0, grad), hess)
        dw = (theta_next - theta)[self.learned]
        left = E - np.einsum("krp,p->kr", D, dw)
        dg = np.where(self.is_goal, self.rates * self.gradient(J, left), 0.0)
        theta_next[self.learned] += float(goal_step_scale(NUMPY, grad, hess, dw, dg)) * dg
        return theta_next

    def error(self, U_fb: np.ndarray) -> np.ndarray:
        """Error signal :math:`e_k` of joint-local feedback samples ``(n, nv)``: the feedback
        of the error joints (frame-angle controllers give theirs as ``CycleLog.u_err``)."""
        return U_fb * self.error_mask

    def gradient(self, J: np.ndarray, E: np.ndarray) -> np.ndarray:
        """:math:`\\sum_k J_k^\\top e_k` over the learned parameters, for error torques
        ``E`` ``(n, nv)``."""
        return np.einsum("kr,krp->p", E, J)

    def step(self, theta: np.ndarray, J: np.ndarray, E: np.ndarray,
             weight: np.ndarray | None = None) -> np.ndarray:
        """Parameters after one update from a cycle's (or a step's) Jacobian and error torques
        :math:`e_k` ``(n, nv)``. ``weight``: the phase each step covers relative to a nominal
        step (:class:`feltool.motion.phase.PhaseSamples`), so that the sums of eq. 3.6 integrate over
        the phase and cycles of different lengths give updates of the same size; None: 1."""
        if self.n_learned == 0:
            return theta.copy()
        Ew = E if weight is None else E * weight[:, None]
        hess = None
        if self.update == "gauss_newton":
            rows = np.any(E != 0, axis=0) | (self.error_mask > 0)
            JE = J * rows[None, :, None]
            if weight is not None:
                JE = JE * weight[:, None, None]
            hess = np.einsum("krp,krs->ps", JE, J)
        return self.apply(theta, self.gradient(J, Ew), hess)

    def apply(self, theta: np.ndarray, grad: np.ndarray, hess: np.ndarray | None) -> np.ndarray:
        """The update from :math:`g = \\sum_k J_k^\\top e_k` and (for gauss_newton)
        :math:`H = \\sum_k J_k^\\top E J_k`, E selecting the error joints
        (:func:`feltool.control.cycle.fel_update`)."""
        theta = theta.copy()
        if self.n_learned == 0:
            return theta
        theta[self.learned] = fel_update(NUMPY, theta[self.learned], grad, hess, self.rates,
                                         self.is_goal, self.update, self.damping)
        return theta

    def learned_sensitivities(self, cycle: PhaseSamples | None = None,
                              samples: np.ndarray | None = None) -> list[tuple]:
        """Per learned joint (in the order of :attr:`learned`) the rows ``(Xq, Xv, Xa)``, each
        ``(n, P_l)``, of its desired position, velocity and acceleration by its parameters at
        the steps of ``cycle`` (``samples``: the RMP sample of each row)."""
        sens = self.primitives.sensitivities(cycle)
        out = []
        for i, _ in self._blocks:
            X = sens[i]
            out.append(tuple(x[samples] for x in X) if samples is not None else X)
        return out

    def sums(self, derivatives: tuple, E: np.ndarray, weight: np.ndarray | None = None,
             cycle: PhaseSamples | None = None, samples: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray | None]:
        """:math:`g = \\sum_k J_k^\\top e_k` and, for gauss_newton, :math:`H` of one cycle from
        the inverse model's derivatives ``(Dq, Dv, M)`` ``(n, nv, nv)`` along it and the error
        torques ``E`` ``(n, nv)``, without forming J (:func:`feltool.control.cycle.fel_sums`);
        ``weight``, ``cycle``, ``samples`` as in :meth:`step` and :meth:`jacobian`."""
        Dq, Dv, M = derivatives
        deriv = [(Dq[:, :, i].T, Dv[:, :, i].T, M[:, :, i].T) for i, _ in self._blocks]
        Ew = E if weight is None else E * weight[:, None]
        rows = None
        if self.update == "gauss_newton":
            rows = (np.any(E != 0, axis=0) | (self.error_mask > 0)).astype(float)[:, None]
            if weight is not None:
                rows = rows * weight[None, :]
        return fel_sums(NUMPY, self.learned_sensitivities(cycle, samples), deriv, Ew.T, rows)

    def update_from_derivatives(self, theta: np.ndarray, derivatives: tuple, E: np.ndarray,
                                weight: np.ndarray | None = None,
                                cycle: PhaseSamples | None = None,
                                samples: np.ndarray | None = None) -> np.ndarray:
        """:meth:`step` for exact sensitivities, from the inverse model's derivatives (see
        :meth:`sums`)."""
        if self.n_learned == 0:
            return theta.copy()
        return self.apply(theta, *self.sums(derivatives, E, weight, cycle, samples))


def feedforward(dynamics: Dynamics, Qd: np.ndarray, Vd: np.ndarray, Ad: np.ndarray) -> np.ndarray:
    """:math:`u_{ff}^k` = RNEA along a desired trajectory, ``(n, nv)`` in [N m] (eq. 3.1)."""
    return dynamics.inverse_batch(Qd, Vd, Ad)
