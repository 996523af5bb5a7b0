r"""The learning step through the closed loop: the lifted map from a parameter change to the
error feedback's change, and the Q-filter (``learning.fit: closed_loop``, ``learning.q_filter_hz``).

The Gauss-Newton step of eq. 3.6 (``learning.fit: feedforward``) fits the feedforward's change
:math:`J\Delta\theta` to the error feedback :math:`e`. But the feedback reports the
feedforward's error only through the closed loop: with a local model :math:`M s^2` and the PD
law :math:`k_p + k_d s`, :math:`T = (k_d s + k_p)/(M s^2 + k_d s + k_p)`, low-pass and late. The
sampled loop reports it one control step late at least. A fine basis at a coarse rate then
grows harmonics the feedback does not see, and a soft loop learns a fast motion slowly.

``fit: closed_loop`` linearizes the known model's closed loop along the desired trajectory,
per control step (the inverse model's derivatives give the forward model's:
:math:`M\,\delta\ddot q = \delta\tau - \partial_q\tau\,\delta q - \partial_{\dot q}\tau\,
\delta\dot q`), and propagates each parameter's sensitivity through it (semi-implicit Euler, as
the loop integrates; the periodic solution, as the cycles repeat), so that
:math:`D = -\partial e/\partial\theta` is the lifted closed-loop map :math:`G` times
:math:`J` (:func:`error_sensitivity`). The step is the norm-optimal (Levenberg-Marquardt) one,

.. math::

    \Delta w = \alpha_w\,\arg\min_{\Delta w}\ \|Q(D\,\Delta w - e)\|^2
               + \lambda\,\overline{\mathrm{diag}}\,\|\Delta w\|^2 ,

which does not depend on the control rate, the period or the basis size: it is the change of
the parameters that removes the error as the loop will see it. ``Q`` (:func:`q_filter`) keeps
the harmonics of the cycle at or below ``learning.q_filter_hz`` [Hz] (a zero-phase projection
over one cycle); directions of the parameters that only move harmonics above it are left to the
damping, so a basis finer than the loop and the sampling can see grows nothing there.
"""

from __future__ import annotations

import numpy as np


def feedback_gains(law, Qd: np.ndarray, error_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                          np.ndarray]:
    r"""The feedback linearized along the desired positions ``Qd`` ``(n, nq)``: per step the
    torque's state gain :math:`K^{fb}_k` and the error signal's :math:`K^{e}_k` (each
    ``(n, nv, 2nv)``: :math:`\delta u = -K\,\delta x` at fixed references) and the map
    :math:`T^{e}_k` ``(n, nv, nv)`` of the controllers' own outputs to the error signal's joint
    torques. A linear row acts on its own joint with :math:`[K_P c^\top,\ K_D c^\top]`; a frame
    angle's row (:class:`feltool.control.feedback.FeedbackLaw`) has the gain of its Jacobian
    :math:`j_y(q_d)` and acts through :math:`j_y^\top` (the terms in the output itself, zero on
    the converged cycle, are left out). Returns ``(Kfb, Ke, T, Te)``, ``T`` the map of the
    controllers' outputs to the joint torques."""
    n, nv = len(Qd), len(law.kp)
    rows = np.repeat(law.C[None], n, axis=0)  # (n, nv rows, nv) d y / d q
    T = np.repeat(np.eye(nv)[None], n, axis=0)  # (n, nv joints, nv rows)
    for row, frame in law.frames.items():
        for k in range(n):
            rows[k, row] = frame.value_and_jacobian(Qd[k])[1]
        T[:, :, row] = rows[:, row, :]
    Krows = np.concatenate([law.kp[None, :, None] * rows, law.kd[None, :, None] * rows], axis=2)
    Te = T * (np.asarray(error_rows) > 0)[None, None, :]
    return np.einsum("kjr,krx->kjx", T, Krows), np.einsum("kjr,krx->kjx", Te, Krows), T, Te


def lifted_state_sensitivity(derivatives: tuple, Kfb: np.ndarray, S: np.ndarray, dt: float,
                             U: np.ndarray, periodic: bool = True, substeps: int = 1,
                             semi_implicit: bool = True) -> np.ndarray:
    r"""The state's sensitivity :math:`Z_k = \partial x_k/\partial\theta` ``(n, 2nv, P)`` of the
    closed loop linearized along the desired trajectory, for the loop's inputs' sensitivity
    ``U`` ``(n, nv, P)`` (the joint torques' change at fixed state: the feedforward's, and the
    feedback's through changed references).

    Per step: :math:`\delta\tau = S(U_k - K^{fb}_k \delta x_k)`, :math:`\delta\ddot q =
    M^{-1}(\delta\tau - \partial_q\tau\,\delta q - \partial_{\dot q}\tau\,\delta\dot q)`,
    :math:`\delta\dot q^+ = \delta\dot q + h\,\delta\ddot q`, :math:`\delta q^+ = \delta q + h\,
    \delta\dot q^+` (``semi_implicit`` False: explicit Euler), ``substeps`` times with
    :math:`h = dt/\mathrm{substeps}` and the torque held, as the loop integrates
    (:func:`feltool.control.cycle.advance`; joint and torque limits are not linearized).
    ``periodic``: :math:`Z_0 = Z_n` (the cycles repeat); else :math:`Z_0 = 0`.

    Args:
        derivatives: ``(Dq, Dv, M)`` ``(n, nv, nv)`` of the known inverse model along the
            desired trajectory.
        Kfb: ``(n, nv, 2nv)`` the feedback torque's state gain (:func:`feedback_gains`).
        S: ``(nv,)`` the actuation selection.
        dt: Control step in [s].
    """
    n, nv, P = U.shape
    A, B = closed_loop_maps(derivatives, Kfb, S, dt, substeps, semi_implicit)
    W = np.einsum("kij,kjp->kip", B, U)  # (n, 2nv, P)
    Z = np.zeros((n + 1, 2 * nv, P))
    for k in range(n):
        Z[k + 1] = A[k] @ Z[k] + W[k]
    if periodic:
        Xs = state_transitions(A)
        z0 = np.linalg.solve(np.eye(2 * nv) - Xs[n], Z[n])
        Z = Z + np.einsum("kij,jp->kip", Xs, z0)
    return Z[:n]


def closed_loop_maps(derivatives: tuple, Kfb: np.ndarray, S: np.ndarray, dt: float,
                     substeps: int = 1, semi_implicit: bool = True) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    r"""The closed loop's linearized control steps :math:`\delta x_{k+1} = A_k\delta x_k +
    B_k\delta u_k` ``(n, 2nv, 2nv)``, ``(n, 2nv, nv)`` along the desired trajectory, the
    feedback :math:`-K^{fb}_k\delta x_k` closed in :math:`A_k` (arguments as
    :func:`lifted_state_sensitivity`)."""
    Dq, Dv, M = derivatives
    Minv = np.linalg.inv(M)  # (n, nv, nv)
    # the acceleration's sensitivity: a = Ax x_sub + Minv S (U - Kfb x), the feedback from the
    # control step's start (held over its sub-steps), the dynamics' at each sub-step
    Ax = -np.einsum("kij,kjl->kil", Minv, np.concatenate([Dq, Dv], axis=2))
    A, B = step_map(Ax, Minv * S[None, None, :], dt, substeps, semi_implicit)
    return A - np.einsum("kij,kjl->kil", B, Kfb), B


def state_transitions(A: np.ndarray) -> np.ndarray:
    r"""``(n + 1, 2nv, 2nv)``: :math:`X_k = A_{k-1}\cdots A_0`, the response of the state at
    each step's start to the cycle's start; :math:`X_n` is the monodromy."""
    Xs = np.empty((len(A) + 1,) + A.shape[1:])
    Xs[0] = np.eye(A.shape[1])
    for k in range(len(A)):
        Xs[k + 1] = A[k] @ Xs[k]
    return Xs


def transient_error(derivatives: tuple, gains: tuple, S: np.ndarray, dt: float,
                    dx: np.ndarray, substeps: int = 1, semi_implicit: bool = True) -> np.ndarray:
    r"""The part ``(n, nv)`` of a cycle's error feedback [N m] that is the transient of its
    start, not the loop's periodic response to the parameters (``learning.remove_transient``).

    A cycle starts where the cycle before ended, off the periodic state :math:`x^\star_0` of
    the parameters it runs (they changed). In the linearized loop the offset
    :math:`d_0 = x_0 - x^\star_0` evolves as :math:`X_k d_0` and ends as :math:`X_n d_0`, so the
    measured change over the cycle ``dx`` :math:`= x_n - x_0 = (X_n - I)\,d_0` gives
    :math:`d_0`; its error feedback is :math:`-K^e_k X_k d_0`. A loop that forgets its start
    within a cycle (a slow period) has none; at a fast period it can carry over most of the
    step's change from cycle to cycle, and the periodic map :math:`D` would fit the step to
    it. ``dx`` ``(2nv,)``: the tangent change of the state over the cycle."""
    Kfb, Ke = gains[:2]
    A, _ = closed_loop_maps(derivatives, Kfb, S, dt, substeps, semi_implicit)
    Xs = state_transitions(A)
    d0 = np.linalg.solve(Xs[-1] - np.eye(len(dx)), dx)
    return -np.einsum("kjx,kxy,y->kj", Ke, Xs[:-1], d0)


def step_map(Ax: np.ndarray, Au: np.ndarray, dt: float, substeps: int = 1,
             semi_implicit: bool = True) -> tuple[np.ndarray, np.ndarray]:
    r"""The linearized control step :math:`\delta x^+ = A_k\delta x + B_k\delta u` ``(n, 2nv,
    2nv)``, ``(n, 2nv, nv)`` from the acceleration's linearization :math:`\delta\ddot q = A^x_k
    \delta x + A^u_k \delta u` (``Ax`` ``(n, nv, 2nv)``, ``Au`` ``(n, nv, nv)``): ``substeps``
    Euler steps of :math:`h = dt/\mathrm{substeps}` [s] with :math:`\delta u` held."""
    n, nv = Au.shape[:2]
    h = dt / substeps
    a = np.zeros((n, 2 * nv, 2 * nv))
    b = np.zeros((n, 2 * nv, nv))
    if semi_implicit:  # v+ = v + h a; q+ = q + h v+
        a[:, nv:] = h * Ax
        a[:, nv:, nv:] += np.eye(nv)
        a[:, :nv] = h * a[:, nv:]
        a[:, :nv, :nv] += np.eye(nv)
        b[:, nv:] = h * Au
        b[:, :nv] = h * h * Au
    else:  # q+ = q + h v; v+ = v + h a
        a[:, :nv, :nv] = np.eye(nv)
        a[:, :nv, nv:] = h * np.eye(nv)
        a[:, nv:] = h * Ax
        a[:, nv:, nv:] += np.eye(nv)
        b[:, nv:] = h * Au
    A, B = a, b
    for _ in range(substeps - 1):
        A, B = a @ A, a @ B + b
    return A, B


def error_sensitivity(derivatives: tuple, J: np.ndarray, gains: tuple, S: np.ndarray,
                      dt: float, Bref: np.ndarray | None = None, periodic: bool = True,
                      substeps: int = 1, semi_implicit: bool = True) -> np.ndarray:
    r""":math:`D = -\partial e/\partial\theta` ``(n, nv, P)``: how much less error feedback the
    loop will report at each step per unit parameter, for the feedforward's sensitivity ``J``
    ``(n, nv, P)`` [N m per unit] and the change ``Bref`` ``(n, nv, P)`` of the controllers'
    reference term :math:`K_P r + K_D \dot r` (learned tracking joints; None: 0). ``gains``: the
    :func:`feedback_gains` along the desired trajectory."""
    Kfb, Ke, T, Te = gains
    U = J if Bref is None else J + np.einsum("kjr,krp->kjp", T, Bref)
    Z = lifted_state_sensitivity(derivatives, Kfb, S, dt, U, periodic, substeps, semi_implicit)
    D = np.einsum("kjx,kxp->kjp", Ke, Z)
    return D if Bref is None else D - np.einsum("kjr,krp->kjp", Te, Bref)


def q_filter(n: int, period_s: float, cutoff_hz: float | None) -> np.ndarray | None:
    """The Q-filter's harmonics: a 0/1 mask over ``numpy.fft.rfft``'s bins of a cycle of ``n``
    samples lasting ``period_s`` [s], 1 at frequencies at or below ``cutoff_hz`` [Hz] (harmonic
    m is m / period_s Hz); None when nothing is cut."""
    if cutoff_hz is None:
        return None
    freqs = np.arange(n // 2 + 1) / float(period_s)
    keep = (freqs <= cutoff_hz + 1e-9).astype(float)
    return None if keep.all() else keep


def apply_q(signal: np.ndarray, keep: np.ndarray | None) -> np.ndarray:
    """``signal`` ``(n, ...)`` with the harmonics outside ``keep`` removed (zero phase, over one
    cycle as a periodic sequence)."""
    if keep is None:
        return signal
    F = np.fft.rfft(signal, axis=0)
    F *= keep.reshape((-1,) + (1,) * (signal.ndim - 1))
    return np.fft.irfft(F, n=signal.shape[0], axis=0)


__all__ = ["apply_q", "closed_loop_maps", "error_sensitivity", "feedback_gains",
           "lifted_state_sensitivity", "q_filter", "state_transitions", "step_map",
           "transient_error"]
