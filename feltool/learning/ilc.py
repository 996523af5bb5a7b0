r"""Iterative learning control (ILC) and the no-learning baseline, next to FEL.

FEL (:mod:`feltool.learning.fel`) learns the RMP parameters :math:`\theta` and gets its feedforward from
the known inverse model, :math:`u_{ff} = f(q_d(\theta), \dot q_d, \ddot q_d)` (eq. 3.1, 3.6).
ILC instead learns the feedforward torque itself, one value per sample of the cycle: the
forward trajectory stays at its initial RMP and the feedforward of cycle :math:`h` is

.. math::

    u_{ff,h}^k = f(q_d^k, \dot q_d^k, \ddot q_d^k) + \Delta u_h^k, \qquad \Delta u_0 = 0,

so both methods start from the same torque and the same first-cycle feedback. The error
:math:`e_h` is the error signal exactly as FEL uses it (``learning.error``: the stabilizing
feedback, or all feedback, as joint torques); the learned channels are the actuated joints of
the error signal (every actuated joint when a frame angle is stabilized: its torque acts on
all joints that move the frame).

* ``ilc_p`` -- P-type (Arimoto) ILC with a zero-phase Q filter,
  :math:`\Delta u_{h+1} = Q(\Delta u_h + L\, e_h(\cdot + \delta))`, where :math:`L` is a scalar
  gain, :math:`\delta` an optional phase lead in samples and :math:`Q` a Butterworth low pass run
  forwards and backwards (``scipy.signal.filtfilt``) over the periodically extended cycle, so it
  has no phase lag (its gain is :math:`|H(\omega)|^2`).
* ``ilc_norm_optimal`` -- norm-optimal ILC on the lifted cycle model. Linearizing the known
  model's closed loop about the measured cycle gives :math:`e_{h+1} \approx e_h + G\,(\Delta
  u_{h+1} - \Delta u_h)`, with :math:`G = \partial e / \partial u` the Jacobian of the cycle's
  sampled error signal with respect to the per-sample feedforward torques (block lower
  triangular). Minimizing :math:`\|e_{h+1}\|_{W_e}^2 + \|\Delta u_{h+1} - \Delta u_h\|_{W_u}^2`
  gives the closed-form update

  .. math::

      \Delta u_{h+1} = \Delta u_h - (G^\top W_e G + W_u)^{-1} G^\top W_e\, e_h,
      \qquad W_e = w_e I,\; W_u = w_u I.

* ``feedback_only`` -- no learning: the stabilizing gains alone, the baseline.

What ILC costs against FEL of RMPs: it stores a torque per sample and learned joint (a cycle of
:math:`n` samples: :math:`n \cdot n_u` numbers instead of the RMP's :math:`N + 1` per joint), and
the learned sequence belongs to one trajectory at one period: there is no goal or period to
change afterwards, as the thesis notes ILC needs the same trajectory every cycle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin
from scipy import linalg

if TYPE_CHECKING:
    from feltool.config.experiment import ExperimentConfig
    from feltool.control.feedback import FeedbackLaw


ILC_UPDATES = ("ilc_p", "ilc_norm_optimal")
#: The updates that run their own cycle runner (ILC and the no-learning baseline).
OWN_RUNNER = (*ILC_UPDATES, "feedback_only")


def q_filter(U: np.ndarray, cutoff_hz: float | None, rate_hz: float, order: int = 2) -> np.ndarray:
    """Zero-phase low pass of a periodic sequence ``U`` (n, ...) along its first axis.

    A Butterworth filter of ``order`` with cutoff ``cutoff_hz`` in [Hz] (sampled at ``rate_hz``
    in [Hz]) is run forwards and backwards (``scipy.signal.filtfilt``) over three copies of the
    cycle, and the middle copy is kept: a periodic input of frequency f comes out scaled by
    :math:`|H(f)|^2` with no phase shift. ``cutoff_hz`` None (or at/above Nyquist) is no filter.
    """
    if cutoff_hz is None or cutoff_hz >= 0.5 * rate_hz:
        return np.array(U, dtype=float, copy=True)
    from scipy import signal  # (a third of a second to import: only when filtering)

    b, a = signal.butter(order, cutoff_hz / (0.5 * rate_hz))
    n = len(U)
    ext = np.concatenate([U, U, U], axis=0)
    return signal.filtfilt(b, a, ext, axis=0, padtype=None)[n:2 * n]


@dataclass
class PTypeILC:
    """Arimoto's P-type update with a zero-phase Q filter (see the module docstring).

    Attributes:
        gain: Learning gain L [-] (error and input are both torques in [N m]).
        lead_steps: Phase lead delta of the error in samples.
        cutoff_hz: Q filter cutoff in [Hz]; None: no filter.
        order: Butterworth order of the Q filter.
        rate_hz: Sampling rate in [Hz].
    """

    gain: float
    lead_steps: int
    cutoff_hz: float | None
    order: int
    rate_hz: float

    def update(self, dU: np.ndarray, E: np.ndarray) -> np.ndarray:
        """:math:`\\Delta u_{h+1} = Q(\\Delta u_h + L e_h(\\cdot+\\delta))` for ``(n, n_u)``
        sequences in [N m]."""
        lead = np.roll(E, -self.lead_steps, axis=0) if self.lead_steps else E
        return q_filter(dU + self.gain * lead, self.cutoff_hz, self.rate_hz, self.order)


@dataclass
class NormOptimalILC:
    """Norm-optimal ILC on the lifted cycle model (see the module docstring).

    Attributes:
        weight_error: w_e of the error norm [1/(N m)^2].
        weight_change: w_u of the input-change norm [1/(N m)^2].
    """

    weight_error: float
    weight_change: float

    def factor(self, G: np.ndarray) -> tuple:
        """The Cholesky factor of :math:`G^\\top W_e G + W_u` (symmetric positive definite),
        for :meth:`update` when ``G`` stays the same from cycle to cycle."""
        H = self.weight_error * G.T @ G + self.weight_change * np.eye(G.shape[1])
        return linalg.cho_factor(H)

    def update(self, dU: np.ndarray, E: np.ndarray, G: np.ndarray,
               factor: tuple | None = None) -> np.ndarray:
        """:math:`\\Delta u_{h+1} = \\Delta u_h - (G^\\top W_e G + W_u)^{-1} G^\\top W_e e_h`;
        ``dU`` ``(n, n_u)``, ``E`` ``(n, n_e)``, ``G`` ``(n n_e, n n_u)`` sample-major;
        ``factor`` from :meth:`factor` (computed here when None)."""
        factor = self.factor(G) if factor is None else factor
        step = linalg.cho_solve(factor, self.weight_error * G.T @ E.reshape(-1))
        return dU - step.reshape(dU.shape)


def lifted_jacobian(model: pin.Model, law: FeedbackLaw, actuated: np.ndarray, dt: float,
                    substeps: int, integrator: str, Q: np.ndarray, V: np.ndarray,
                    R: np.ndarray, Rd: np.ndarray, Tau: np.ndarray, inputs: np.ndarray,
                    outputs: np.ndarray, error_rows: np.ndarray) -> np.ndarray:
    r"""The lifted cycle model :math:`G = \partial e / \partial u` of the known model's closed
    loop, linearized about a cycle.

    With :math:`x_k = (q_k, \dot q_k)` and the control step
    :math:`x_{k+1} = F(x_k, \tau_k)`, :math:`\tau_k = S(u_k + u_{fb}(x_k))` (ABA integrated as in
    :class:`~feltool.control.closed_loop.ClosedLoop`), :math:`A_k = F_x + F_\tau S\, \partial u_{fb}/\partial
    x`, :math:`B_k = F_\tau S P_u` and :math:`H_k = P_e\, \partial u_{err}/\partial x`, the block
    :math:`G_{kj} = H_k A_{k-1} \cdots A_{j+1} B_j` for :math:`j < k` (zero otherwise).
    Pinocchio's ABA derivatives give :math:`F`'s partials.

    Args:
        model: The known model (Pinocchio; its own data is created here).
        Q, V: The cycle's states at each step's start, ``(n, nv)`` in [rad], [rad/s].
        R, Rd: The references, ``(n, nv)``.
        Tau: The torques applied at each step, ``(n, nv)`` in [N m].
        inputs: Joint indices of the learned torque channels (n_u).
        outputs: Joint indices of the error channels (n_e).
        error_rows: ``(nv,)`` 1 for the controllers whose feedback is the error signal.

    Returns:
        ``(n n_e, n n_u)``, rows and columns sample-major.
    """
    n, nv = Q.shape
    nu, ne = len(inputs), len(outputs)
    data = model.createData()
    h = dt / substeps
    semi = integrator == "semi_implicit_euler"
    S = np.asarray(actuated, float)
    G = np.zeros((n * ne, n * nu))
    Z = np.zeros((2 * nv, n * nu))  # dx_k / du_j for every j, propagated forward
    eye = np.eye(nv)
    for k in range(n):
        Dfb, Derr = _feedback_jacobians(law, Q[k], V[k], R[k], Rd[k], error_rows)
        if k:
            G[k * ne:(k + 1) * ne, :k * nu] = Derr[outputs] @ Z[:, :k * nu]
        Fx, Ftau = _step_jacobian(model, data, Q[k], V[k], Tau[k], h, substeps, semi, eye)
        FS = Ftau * S[None, :]
        A = Fx + FS @ Dfb
        Z[:, :k * nu] = A @ Z[:, :k * nu]
        Z[:, k * nu:(k + 1) * nu] = FS[:, inputs]
    return G


def _step_jacobian(model, data, q, v, tau, h, substeps, semi, eye):
    """``(dx'/dx, dx'/dtau)`` of one control step with the torque held over its substeps."""
    nv = len(v)
    Jx, Jt = np.eye(2 * nv), np.zeros((2 * nv, nv))
    q, v = q.copy(), v.copy()
    for _ in range(substeps):
        aq, av, at = (np.array(m) for m in pin.computeABADerivatives(model, data, q, v, tau))
        a = np.array(data.ddq)
        if semi:
            dv = np.hstack([h * aq, eye + h * av])
            dq = np.hstack([eye, np.zeros((nv, nv))]) + h * dv
            dvt, dqt = h * at, h * h * at
            v = v + h * a
            q = q + h * v
        else:
            dq = np.hstack([eye, h * eye])
            dv = np.hstack([h * aq, eye + h * av])
            dqt, dvt = np.zeros((nv, nv)), h * at
            q, v = q + h * v, v + h * a
        step = np.vstack([dq, dv])
        Jt = step @ Jt + np.vstack([dqt, dvt])
        Jx = step @ Jx
    return Jx, Jt


def _feedback_jacobians(law: FeedbackLaw, q, v, r, rd, error_rows, eps: float = 1e-7):
    """``(d u_fb/dx, d u_err/dx)`` at one state, ``(nv, 2nv)`` each: exact for linear laws,
    central differences of :meth:`FeedbackLaw.terms` for frame angles."""
    if law.linear:
        K = np.hstack([law.kp[:, None] * law.C, law.kd[:, None] * law.C])
        return -K, -K * (np.asarray(error_rows) > 0)[:, None]
    nv = len(v)
    Dfb, Derr = np.zeros((nv, 2 * nv)), np.zeros((nv, 2 * nv))
    for i in range(2 * nv):
        outs = []
        for sign in (1.0, -1.0):
            dq, dv = np.zeros(nv), np.zeros(nv)
            (dq if i < nv else dv)[i % nv] = sign * eps
            u_fb, _, u_err = law.terms(q + dq, v + dv, r, rd, error_rows)
            outs.append((u_fb, u_err))
        Dfb[:, i] = (outs[0][0] - outs[1][0]) / (2 * eps)
        Derr[:, i] = (outs[0][1] - outs[1][1]) / (2 * eps)
    return Dfb, Derr


def problems(cfg: ExperimentConfig) -> list[tuple[str, str]]:
    """What the ILC learners and the baseline do not support, as ``(yaml_path, message)``."""
    update = cfg.learning.update
    if update not in OWN_RUNNER:
        return []
    out = []
    if cfg.learning.step != "per_cycle":
        out.append(("learning.step", f"'{update}' runs per_cycle only"))
    if cfg.backend == "compiled":
        out.append(("backend", f"'{update}' needs the pinocchio or casadi backend"))
    if (cfg.walking is not None and not cfg.walking.physical) or cfg.actuation is not None:
        out.append(("learning.update", f"'{update}' is not available for the pinned walker "
                                       "(impact: relabel or rigid) or allocated motors; a "
                                       "physical walker (walking.feet) has it, its torques "
                                       "indexed by the RMP's sample"))
    if cfg.learning.model is not None:
        out.append(("learning.model", f"'{update}' cannot be combined with model learning"))
    return out
