r"""Classic feedback error learning on a physical walker: a model correction and motor biases.

A world the known model does not know (a payload, heavier links, a slope) needs feedforward
torques that the learned joint trajectories give poorly: a static load needs a mean torque,
and the RMPs' corrections move the motion to get one. This learner adds two corrections to the
physical walker's command (:mod:`feltool.walking.physical`),

.. math::

    u = A(q)\,\bigl(\mathrm{RNEA}(q_d, \dot q_d, \ddot q_d) + Y(q_d, \dot q_d, \ddot q_d)\,
        \theta_\pi + u_{fb}\bigr) + b ,

* :math:`Y\theta_\pi` -- Kawato's model correction: RNEA is linear in the bodies' inertial
  parameters (Pinocchio's joint-torque regressor :math:`Y`, :mod:`feltool.learning.model`), so
  :math:`\theta_\pi` is the change of the walker's masses, first moments and inertias (10 per
  body, in the stance-relative labels the walker runs in) that the feedback asks for: a
  payload or changed masses are exactly such a change;
* :math:`b` -- a constant torque per motor (stance-relative labels) [N m]: the mean that a
  slope or an unmodelled constant load needs;
* :math:`\delta\alpha\, g_t(q_d)` (``learning.model.slope``) -- a ground slope the known
  model does not know [rad]: gravity tilted about y by :math:`\alpha_0 + \delta\alpha`
  (:math:`\alpha_0` the known model's slope, downhill along +x). RNEA is linear in the
  gravity vector, so to first order in :math:`\delta\alpha` the change is
  :math:`\delta\alpha\,\mathrm{RNEA}(q_d, 0, 0)` evaluated by Pinocchio with gravity along
  the ground's tangent, :math:`\partial g/\partial\alpha = |g|(\cos\alpha_0, 0,
  \sin\alpha_0)`: the column :math:`g_t`. (Second order: :math:`\delta\alpha^2/2` of the
  normal gravity torque, 4.5e-4 of it at 0.03 rad. The column uses the known inertias: the
  product of a mass and a slope correction is left out.)

Both are learned from the feedforward's error in motor torques, :math:`e_m = A e` (the
feedback, plus the inertial term with ``error_estimate: inverse_dynamics``), by one
Levenberg-Marquardt step over the cycle on the stacked features :math:`\Phi = [A Y,\ I]`:

.. math::

    \Delta = (\textstyle\sum_k \Phi_k^\top\Phi_k + \lambda I)^{-1}
             \textstyle\sum_k \Phi_k^\top e_{m,k},\qquad
    \theta_\pi \mathrel{+}= \alpha_\pi \Delta_\pi,\quad b \mathrel{+}= \alpha_b \Delta_b,

:math:`\lambda` relative to the mean diagonal. The rates :math:`\alpha` are fractions of that
step [-]: the step solves for the correction that removes the cycle's error, whatever the
control rate, period or number of samples (a sum over samples on both sides), so a rate
means the same at 250 Hz and at 1 kHz. Learned alone, the bias's step is the cycle's mean
motor-space error: :math:`b \mathrel{+}= \alpha_b\,\overline{e_m}`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.learning.model import INERTIAL_NAMES, inertial_parameters


class WalkerModelLearner:
    """The learner of the module docstring.

    Args:
        model: The known walker model (floating base) whose regressor gives :math:`Y`, or None
            (no model correction: the motor biases alone).
        motor_names: The motors, in the allocation's order.
        rate: :math:`\\alpha_\\pi`, the model correction's fraction of the step [-].
        bias_rate: :math:`\\alpha_b`, the motor biases' fraction of the step [-] (0: none).
        damping: Levenberg-Marquardt damping relative to the mean diagonal [-].
    """

    walker = True

    def __init__(self, model: pin.Model | None, motor_names: list[str], rate: float,
                 bias_rate: float, damping: float = 1e-6, slope_rate: float = 0.0):
        self.model = model
        self.data = model.createData() if model is not None else None
        self.pi_model = inertial_parameters(model) if model is not None else np.zeros(0)
        #: the inertial parameters that move a torque at all (a planar walker's motion never
        #: sees m c_y or I_xx, ...): the regressor's columns not zero at random states
        self.columns = moving_columns(model) if model is not None else np.zeros(0, int)
        self.n_pi = len(self.columns)
        self.motor_names = list(motor_names)
        self.k = len(motor_names)
        self.n_bias = self.k if bias_rate > 0 else 0
        self.rate, self.bias_rate, self.damping = rate, bias_rate, damping
        #: the learned ground slope's column (``slope_rate > 0``; it needs the model)
        self.n_tilt = 1 if slope_rate > 0 and model is not None else 0
        self.slope_rate = slope_rate
        if model is not None:
            g = np.asarray(model.gravity.linear, float).copy()
            #: the known model's ground slope alpha_0 [rad] (downhill along +x)
            self.slope0 = float(np.arctan2(g[0], -g[2]))
            self.tilt_model = pin.Model(model)
            self.tilt_model.gravity = pin.Motion(tilt_direction(g), np.zeros(3))
            self.tilt_data = self.tilt_model.createData()
        else:
            self.slope0 = 0.0
        names = [f"{model.names[j]}.{p}" for j in range(1, model.njoints)
                 for p in INERTIAL_NAMES] if model is not None else []
        self.names = [names[c] for c in self.columns] + ["ground.slope"] * self.n_tilt + \
            [f"{m}.bias" for m in self.motor_names[:self.n_bias]]

    @property
    def n_params(self) -> int:
        return self.n_pi + self.n_tilt + self.n_bias

    @property
    def n_features(self) -> int:
        """The columns of :meth:`regressor`: the model correction's and the slope's."""
        return self.n_pi + self.n_tilt

    def initial_parameters(self) -> np.ndarray:
        """Zero: learning starts from the known model and no bias."""
        return np.zeros(self.n_params)

    def split(self, theta_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(theta_pi, b)``: the inertial-parameter correction and the motor biases [N m]."""
        b = theta_m[self.n_features:] if self.n_bias else np.zeros(self.k)
        return theta_m[:self.n_pi], b

    def slope(self, theta_m: np.ndarray) -> float:
        r"""The identified ground slope :math:`\alpha_0 + \delta\alpha` [rad] (downhill
        along +x; the known one without ``learning.model.slope``)."""
        return self.slope0 + (float(theta_m[self.n_pi]) if self.n_tilt else 0.0)

    def tilt_column(self, qd: np.ndarray) -> np.ndarray:
        r""":math:`g_t(q)` ``(nv,)`` [N m / rad]: the generalized-force change per radian of
        ground slope, RNEA(q, 0, 0) by Pinocchio with gravity along the ground's tangent."""
        return pin.computeGeneralizedGravity(self.tilt_model, self.tilt_data, qd).copy()

    def regressor(self, qd: np.ndarray, vd: np.ndarray, ad: np.ndarray) -> np.ndarray:
        """:math:`[Y, g_t]` ``(nv, n_features)`` at one desired state: the regressor's
        :attr:`columns`, then the slope's column (``learning.model.slope``)."""
        Y = pin.computeJointTorqueRegressor(self.model, self.data, qd, vd, ad)[:, self.columns]
        if self.n_tilt:
            Y = np.column_stack([Y, self.tilt_column(qd)])
        return Y

    def correction(self, theta_m: np.ndarray):
        """``(qd, vd, ad) -> Y theta_pi (+ g_t delta alpha)`` [N m] (generalized forces), or
        None without a model correction."""
        if not self.n_features:
            return None
        theta = theta_m[:self.n_features].copy()
        return lambda qd, vd, ad: self.regressor(qd, vd, ad) @ theta

    def step(self, theta_m: np.ndarray, Qd: np.ndarray, Vd: np.ndarray, Ad: np.ndarray,
             A: np.ndarray, E: np.ndarray) -> np.ndarray:
        """The parameters after one cycle: its desired states ``(n, nv)``, allocation matrices
        ``A`` ``(n, k, nv)`` and feedforward errors ``E`` ``(n, nv)`` in generalized forces."""
        n = len(E)
        if n == 0 or not self.n_params:
            return theta_m
        Em = np.einsum("kmr,kr->km", A, E)
        blocks = []
        if self.n_features:
            Y = np.stack([self.regressor(Qd[i], Vd[i], Ad[i]) for i in range(n)])
            blocks.append(np.einsum("kmr,krp->kmp", A, Y))
        if self.n_bias:
            blocks.append(np.broadcast_to(np.eye(self.k), (n, self.k, self.k)))
        Phi = np.concatenate(blocks, axis=2)
        g = np.einsum("km,kmp->p", Em, Phi)
        H = np.einsum("kmp,kms->ps", Phi, Phi)
        lam = self.damping * float(np.mean(np.diag(H))) + 1e-300
        delta = np.linalg.solve(H + lam * np.eye(self.n_params), g)
        rates = np.concatenate([np.full(self.n_pi, self.rate),
                                np.full(self.n_tilt, self.slope_rate),
                                np.full(self.n_bias, self.bias_rate)])
        return theta_m + rates * delta


def tilt_direction(g: np.ndarray) -> np.ndarray:
    r""":math:`\partial g / \partial \alpha` [m/s^2 / rad] for gravity ``g`` =
    :math:`|g|(\sin\alpha, 0, -\cos\alpha)`: :math:`|g|(\cos\alpha, 0, \sin\alpha)`
    (gravity turned a quarter turn about y, along the ground's tangent)."""
    return np.array([-g[2], 0.0, g[0]])


def moving_columns(model: pin.Model, samples: int = 8) -> np.ndarray:
    """The inertial parameters (columns of the joint-torque regressor) that some motion of
    ``model`` turns into a torque: the columns not zero at ``samples`` states drawn by
    ``numpy.random.default_rng(0)`` (structural zeros are zero at every state)."""
    rng = np.random.default_rng(0)
    data = model.createData()
    norm = np.zeros(10 * (model.njoints - 1))
    for _ in range(samples):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq)) \
            if model.nq != model.nv else rng.uniform(-1.0, 1.0, model.nq)
        Y = pin.computeJointTorqueRegressor(model, data, q, rng.normal(size=model.nv),
                                            rng.normal(size=model.nv))
        norm += np.abs(Y).sum(axis=0)
    return np.flatnonzero(norm > 1e-9 * max(norm.max(), 1e-300))


__all__ = ["WalkerModelLearner", "moving_columns", "tilt_direction"]
