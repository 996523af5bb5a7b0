r"""Classic feedback error learning (Kawato): learn an inverse-model correction from feedback.

The feedforward torque is the known inverse model plus a learned correction linear in its
parameters :math:`\theta_m` (eq. 2.8):

.. math::

    u_{ff}^k = \mathrm{RNEA}_{model}(q_d^k, \dot q_d^k, \ddot q_d^k)
             + S_m\,\Phi(q_d^k, \dot q_d^k, \ddot q_d^k)\,\theta_m ,

and the feedback of the error joints :math:`S_m` (a 0/1 diagonal; Kawato: every actuated joint)
is the error signal that moves :math:`\theta_m` (eq. 2.10, 3.4). The correction drives only the
joints whose feedback trains it (:meth:`ModelLearner.step` says why):

.. math::

    \theta_{m,h+1} = \theta_{m,h} + \alpha_m \sum_{k=1}^{N} \Phi_k^\top S_m u_{fb}^k
    \qquad \text{(gradient, per cycle; per step: one sample at a time)}

or the Levenberg-Marquardt step
:math:`\Delta\theta_m = \alpha_m (\sum_k \Phi_k^\top\Phi_k + \lambda I)^{-1} \sum_k \Phi_k^\top u_{fb}^k`,
with :math:`\lambda` relative to the mean diagonal so that directions the motion does not excite
are (almost) left where they are.

Features :math:`\Phi`:

* :class:`RegressorFeatures` -- Pinocchio's joint-torque regressor :math:`Y(q, \dot q, \ddot q)`,
  RNEA being linear in the inertial parameters :math:`\pi` (10 per body:
  :math:`m, m c_x, m c_y, m c_z, I_{xx}, I_{xy}, I_{yy}, I_{xz}, I_{yz}, I_{zz}`, the rotational
  inertia taken about the joint frame's origin): :math:`\mathrm{RNEA}_\pi = Y\pi`. The learned
  model is then RNEA with :math:`\\pi_{model} + \theta_m`; only the combinations of :math:`\pi` in
  the row space of :math:`Y` stacked along the motion are identifiable (:func:`identifiability`).
* :class:`PhaseBasisFeatures` -- normalised von Mises functions of the phase, per joint: a
  periodic torque profile :math:`\Delta u_j(\phi)`; no physics, any periodic mismatch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np
import pinocchio as pin

from feltool.control.closed_loop import ClosedLoop, CycleLog

#: Pinocchio's order of a body's 10 inertial parameters (``Inertia.toDynamicParameters``).
INERTIAL_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")


class Features(Protocol):
    """Features :math:`\\Phi` of the learned inverse-model correction."""

    n_params: int
    names: list[str]

    def features(self, Qd: np.ndarray, Vd: np.ndarray, Ad: np.ndarray) -> np.ndarray:
        """:math:`\\Phi_k` along a desired trajectory ``(n, nv)`` -> ``(n, nv, n_params)``."""


class RegressorFeatures:
    """Pinocchio's joint-torque regressor of the known model.

    Attributes:
        pi_model: The known model's inertial parameters ``(10 * bodies,)`` (units [kg], [kg m],
            [kg m^2]); the learned model has ``pi_model + theta_m``.
        names: ``<joint>.<parameter>`` per column.
    """

    def __init__(self, model: pin.Model):
        self.model, self.data = model, model.createData()
        self.pi_model = inertial_parameters(model)
        self.n_params = self.pi_model.size
        self.names = [f"{model.names[j]}.{p}" for j in range(1, model.njoints)
                      for p in INERTIAL_NAMES]

    def corrected_model(self, theta_m: np.ndarray) -> pin.Model:
        """The known model with inertial parameters :math:`\\pi_{model} + \\theta_m`: its RNEA is
        :math:`Y(\\pi_{model} + \\theta_m)`, the learned inverse model."""
        model = self.model.copy()
        pi = self.pi_model + theta_m
        for j in range(1, model.njoints):
            model.inertias[j] = pin.Inertia.FromDynamicParameters(pi[10 * (j - 1):10 * j])
        return model

    def features(self, Qd, Vd, Ad):
        n = len(Qd)
        out = np.empty((n, self.model.nv, self.n_params))
        model, data, regressor = self.model, self.data, pin.computeJointTorqueRegressor
        for k in range(n):
            out[k] = regressor(model, data, Qd[k], Vd[k], Ad[k])
        return out


class PhaseBasisFeatures:
    """Normalised von Mises functions of the phase :math:`\\phi_k = 2\\pi k / n`, one set per joint:
    :math:`\\Delta u_j(\\phi) = \\sum_i \\bar\\psi_i(\\phi)\\,\\theta_{j,i}` with
    :math:`\\bar\\psi_i = \\psi_i / \\sum_l \\psi_l`, :math:`\\psi_i = \\exp(h(\\cos(\\phi - c_i) - 1))`.

    Args:
        n_steps: Samples per cycle.
        nv: Joints.
        basis: Functions per joint N.
        width: Width h [-]; default N / 2.
        joint_names: For :attr:`names`.
    """

    def __init__(self, n_steps: int, nv: int, basis: int, width: float | None = None,
                 joint_names: list[str] | None = None):
        h = basis / 2.0 if width is None else width
        phi = 2.0 * np.pi * np.arange(n_steps) / n_steps
        centres = 2.0 * np.pi * np.arange(basis) / basis
        psi = np.exp(h * (np.cos(phi[:, None] - centres[None, :]) - 1.0))
        psi /= psi.sum(axis=1, keepdims=True)
        self._phi = np.zeros((n_steps, nv, nv * basis))
        for j in range(nv):
            self._phi[:, j, j * basis:(j + 1) * basis] = psi
        self.n_params = nv * basis
        joint_names = joint_names or [str(j) for j in range(nv)]
        self.names = [f"{j}.psi{i}" for j in joint_names for i in range(basis)]

    def features(self, Qd, Vd, Ad):
        return self._phi


@dataclass
class ModelLearner:
    """The learner of eq. 3.4 for the inverse-model correction.

    Attributes:
        features: The features :math:`\\Phi`.
        error_mask: ``(nv,)`` 1 for actuated joints (their feedback is the error), else 0.
        rate: :math:`\\alpha_m` (gradient) or the fraction of the Levenberg-Marquardt step.
        update: ``gradient`` or ``gauss_newton``.
        step_mode: ``per_cycle`` or ``per_step``.
        damping: Levenberg-Marquardt damping relative to the mean diagonal of
            :math:`\\Phi^\\top\\Phi` [-].
    """

    features: Features
    error_mask: np.ndarray
    rate: float
    update: str = "gauss_newton"
    step_mode: str = "per_cycle"
    damping: float = 1e-6

    @property
    def n_params(self) -> int:
        return self.features.n_params

    def initial_parameters(self) -> np.ndarray:
        """:math:`\\theta_m = 0`: learning starts from the known model."""
        return np.zeros(self.n_params)

    def learned_dynamics(self, theta_m: np.ndarray):
        """The learned inverse model (known model plus correction) as a :class:`Dynamics`, for the
        trajectory learner's Jacobian, or None when the correction does not depend on the
        desired state (phase-basis features: the nominal model's derivatives are exact)."""
        corrected = getattr(self.features, "corrected_model", None)
        if corrected is None:
            return None
        from feltool.dynamics.interface import make_dynamics

        return make_dynamics(corrected(theta_m), "pinocchio")

    def correction(self, Phi: np.ndarray, theta_m: np.ndarray) -> np.ndarray:
        """:math:`S_m\\Phi_k\\theta_m` for every sample, ``(n, nv)`` in [N m]: the correction
        drives only the joints whose feedback trains it (:math:`S_m` = ``error_mask``; see
        :meth:`step` for why)."""
        return (Phi @ theta_m) * self.error_mask

    def step(self, theta_m: np.ndarray, Phi: np.ndarray, U_fb: np.ndarray) -> np.ndarray:
        """Parameters after one cycle's update from its features and feedback.

        FEL's gradient :math:`\\sum_k \\Phi_k^\\top S_m u_{fb}^k` is a descent direction of the
        feedback only if a change of the feedforward on joint j shows up, with opposite sign, in
        the feedback *of joint j* (:math:`u_{fb} \\approx -\\Delta u_{ff}`). A correction that
        also drove joints outside :math:`S_m` would act on the error only through the arm's
        dynamic coupling and those joints' controllers; with a stabilized elbow following none of
        its (random) desired trajectory, that path has the wrong sign along directions the
        desired trajectory excites and the true motion does not (link 2's inertia), and the
        parameters drifted until the arm fell (docs/model_learning.md). Hence
        :meth:`correction` applies :math:`S_m`."""
        e = U_fb * self.error_mask
        g = np.einsum("kj,kjp->p", e, Phi)
        if self.update == "gradient":
            return theta_m + self.rate * g
        A = Phi.reshape(-1, self.n_params)
        H = A.T @ A
        lam = self.damping * float(np.mean(np.diag(H))) + 1e-300
        return theta_m + self.rate * np.linalg.solve(H + lam * np.eye(self.n_params), g)

    def run_cycle(self, loop: ClosedLoop, q: np.ndarray, v: np.ndarray, R: np.ndarray,
                  Rd: np.ndarray, u_ff_model: np.ndarray, desired: tuple, theta_m: np.ndarray
                  ) -> tuple[CycleLog, np.ndarray]:
        """Run one cycle with the corrected feedforward; return its log and the new
        :math:`\\theta_m` (updated once at the end, or after every step for ``per_step``).

        Args:
            u_ff_model: :math:`\\mathrm{RNEA}_{model}` along the desired trajectory ``(n, nv)``.
            desired: ``(Qd, Vd, Ad)`` the features are evaluated on.
        """
        Phi = self.features.features(*desired)
        if self.step_mode == "per_cycle":
            log = loop.run_cycle(q, v, R, Rd, u_ff_model + self.correction(Phi, theta_m))
            return log, self.step(theta_m, Phi, log.u_fb)
        theta_m = theta_m.copy()
        n, nv = R.shape
        Q, V = np.empty((n, len(q))), np.empty((n, nv))
        U, Urows, Uerr = np.empty((n, nv)), np.empty((n, nv)), np.empty((n, nv))
        for k in range(n):
            Q[k], V[k] = q, v
            U[k], Urows[k], Uerr[k] = loop.law.terms(q, v, R[k], Rd[k], loop.error_rows)
            tau = loop.actuated * (u_ff_model[k] + (Phi[k] @ theta_m) * self.error_mask + U[k])
            q, v = loop.advance(q, v, tau)
            theta_m += self.rate * Phi[k].T @ (U[k] * self.error_mask)
        return CycleLog(Q, V, U, q, v, Urows, Uerr), theta_m


def inertial_parameters(model: pin.Model) -> np.ndarray:
    """The model's inertial parameters :math:`\\pi`, 10 per body in Pinocchio's order."""
    return np.concatenate([model.inertias[j].toDynamicParameters()
                           for j in range(1, model.njoints)])


class Identifiability(NamedTuple):
    """What one motion can tell about the inertial parameters.

    Attributes:
        rank: Rank of the stacked regressor (number of identifiable combinations).
        singular_values: Of the stacked regressor, largest first.
        basis: ``(rank, P)`` orthonormal rows spanning the identifiable combinations
            (the row space of the stacked regressor); ``basis @ pi`` is what is identified.
        projector: ``(P, P)`` projector onto that row space.
    """

    rank: int
    singular_values: np.ndarray
    basis: np.ndarray
    projector: np.ndarray


def identifiability(Phi: np.ndarray, rtol: float = 1e-8) -> Identifiability:
    """Identifiable parameter combinations from features stacked along a motion ``(n, nv, P)``.

    Two parameter vectors that differ by a null-space vector of the stacked regressor give the
    same torques all along the motion, so only the projection onto its row space is learned.
    """
    A = Phi.reshape(-1, Phi.shape[-1])
    _, s, Vt = np.linalg.svd(A, full_matrices=False)
    rank = int((s > rtol * s[0]).sum()) if s.size and s[0] > 0 else 0
    basis = Vt[:rank]
    return Identifiability(rank, s, basis, basis.T @ basis)


__all__ = ["INERTIAL_NAMES", "Identifiability", "ModelLearner", "PhaseBasisFeatures",
           "RegressorFeatures", "identifiability", "inertial_parameters"]
