r"""One learning cycle, written once for both engines.

The pieces of a cycle (DESIGN's data flow) that act on one control step or on one cycle's
sums, written against an operations namespace ``xp`` (:mod:`feltool.control.ops`): the Python
engine evaluates them on numbers with :data:`~feltool.control.ops.NUMPY`
(:class:`~feltool.control.feedback.FeedbackLaw`, :class:`~feltool.control.closed_loop.ClosedLoop`,
:class:`~feltool.learning.fel.FeedbackErrorLearner` call them), the compiled engine traces them
with :data:`~feltool.control.ops.CASADI` into the graph it generates to C
(:mod:`feltool.engines.compiled`). A feature written here reaches both engines.

* :func:`feedback` -- the PD laws of every controller (eq. 2.7 and §3.1), linear rows and frame
  angles, with each controller's own output and the learning signal;
* :func:`advance` -- one control step of the plant: torque limits, the forward model, the
  integrator's sub-steps, joint limits;
* :func:`fel_update` -- the learning step of eq. 3.6 from the cycle's sums (gradient or
  Levenberg-Marquardt);
* :func:`wrap` -- angles into (-pi, pi].
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

TWO_PI = 2.0 * np.pi


def wrap(xp, angle):
    """Angle(s) wrapped into [-pi, pi) in [rad] (``(a + pi) mod 2 pi - pi``)."""
    a = angle + np.pi
    if not xp.symbolic:
        return a % TWO_PI - np.pi
    return a - TWO_PI * xp.floor(a / TWO_PI) - np.pi


def feedback(xp, law, q, v, r, rd, error_rows: np.ndarray,
             frames: dict[int, Callable[[Any], tuple[Any, Any]]] | None = None):
    """``(u_fb, u_rows, u_err)`` at one state (the PD laws, :mod:`feltool.control.feedback`).

    Each controller's output ``u_rows`` is :math:`K_P (r - c^\\top q) + K_D(\\dot r - c^\\top
    \\dot q)`, or for a frame angle :math:`K_P\\,\\mathrm{wrap}(r - y) + K_D(\\dot r - j_y\\dot q)`.
    A linear controller's torque acts on its own joint, a frame angle's through
    :math:`j_y^\\top`; ``u_err`` keeps the torques of the controllers in ``error_rows``.

    Args:
        law: The :class:`~feltool.control.feedback.FeedbackLaw` (its numbers: C, kp, kd).
        frames: ``{row: q -> (y, j_y)}`` evaluating each frame-angle quantity [rad] and its
            Jacobian (default: none).
    """
    u_rows = law.kp * (r - law.C @ q) + law.kd * (rd - law.C @ v)
    jacs = {}
    for row, kin in (frames or {}).items():
        y, jac = kin(q)
        jacs[row] = jac
        u_rows[row] = law.kp[row] * wrap(xp, r[row] - y) + law.kd[row] * (rd[row] - xp.dot(jac, v))
    u_fb = 1.0 * u_rows
    u_err = xp.where(error_rows > 0, u_rows, 0.0) if not xp.symbolic else \
        xp.vec([u_rows[i] if error_rows[i] > 0 else 0.0 for i in range(len(error_rows))])
    for row, jac in jacs.items():
        u_fb[row] = u_fb[row] - u_rows[row]
        u_fb = u_fb + jac * u_rows[row]
        if error_rows[row] > 0:
            u_err[row] = u_err[row] - u_rows[row]
            u_err = u_err + jac * u_rows[row]
    return u_fb, u_rows, u_err


def advance(xp, forward, q, v, tau, h: float, substeps: int, semi_implicit: bool,
            limits=None, integrate=None):
    """The state after one control step under the joint torques ``tau`` (held over the step).

    ``forward(q, v, tau)`` is the plant's forward model (ABA); ``substeps`` integrator steps of
    ``h`` [s] each: semi-implicit Euler (:math:`\\dot q \\mathrel{+}= h\\ddot q;\\ q
    \\mathrel{+}= h\\dot q`) or explicit Euler. ``limits`` (:class:`~feltool.control.closed_loop.Limits`):
    ``saturate`` clips the torque to the effort limits, ``enforce`` holds each joint at its
    position limits (clamped, the velocity into the limit zeroed). ``integrate(q, dq)`` for
    configurations that are not plain vectors (default ``q + dq``).
    """
    if limits is not None and limits.torques == "saturate":
        tau = xp.clip(tau, -limits.effort, limits.effort)
    enforce = limits is not None and limits.joints == "enforce"
    for _ in range(substeps):
        a = forward(q, v, tau)
        if semi_implicit:
            v = v + h * a
            q = q + h * v if integrate is None else integrate(q, h * v)
        else:
            q, v = (q + h * v if integrate is None else integrate(q, h * v)), v + h * a
        if enforce:
            q, v = clamp(xp, limits, q, v)
    return q, v


def plain(substeps: int, semi_implicit: bool, limits=None, integrate=None) -> bool:
    """True for the common control step: one semi-implicit Euler sub-step of plain vectors with
    no limit to apply (the loops then skip :func:`advance`'s option checks)."""
    applies = limits is not None and (limits.torques == "saturate" or limits.joints == "enforce")
    return substeps == 1 and semi_implicit and integrate is None and not applies


def euler_map(h: float, nv: int) -> tuple[np.ndarray, np.ndarray]:
    r"""The plain step (:func:`plain`) as one linear map of the state :math:`x = (q, \dot q)`
    and the acceleration: :math:`x^+ = \Phi x + \Gamma \ddot q` with :math:`\Phi =
    \begin{pmatrix} I & hI \\ 0 & I \end{pmatrix}`, :math:`\Gamma = \begin{pmatrix} h^2 I
    \\ hI \end{pmatrix}` (:math:`\dot q^+ = \dot q + h\ddot q,\ q^+ = q + h\dot q^+`;
    ``h`` in [s]); the same numbers as :func:`advance`'s to rounding."""
    eye, zero = np.eye(nv), np.zeros((nv, nv))
    return np.block([[eye, h * eye], [zero, eye]]), np.vstack([h * h * eye, h * eye])


def stepper(xp, forward, h: float, substeps: int, semi_implicit: bool, limits=None,
            integrate=None):
    """:func:`advance` with its options fixed once for a loop: ``(q, v, tau) -> (q, v)``. The
    plain step (:func:`plain`) skips the per-call option checks; its numbers are
    :func:`advance`'s."""
    if plain(substeps, semi_implicit, limits, integrate):
        def step(q, v, tau):
            v = v + h * forward(q, v, tau)
            return q + h * v, v

        return step
    return lambda q, v, tau: advance(xp, forward, q, v, tau, h, substeps, semi_implicit,
                                     limits, integrate)


def clamp(xp, limits, q, v):
    """Joints held at their position limits: the position clipped, the velocity into the
    limit set to zero."""
    low, high = q < limits.lower, q > limits.upper
    if not xp.symbolic:
        if not (low.any() or high.any()):
            return q, v
        v = v.copy()
        v[(low & (v < 0)) | (high & (v > 0))] = 0.0
        return np.clip(q, limits.lower, limits.upper), v
    stop = xp.fmax(low * (v < 0), high * (v > 0))
    return xp.clip(q, limits.lower, limits.upper), xp.where(stop, 0.0, v)


def allocate(xp, M, N, tau):
    r"""The joint torques :math:`B u` of the inertia-weighted allocation
    :math:`u = (B^\top M^{-1} B)^{-1} B^\top M^{-1}\tau` (:class:`feltool.walking.pinned.Allocation`):
    the projection of :math:`\tau` onto the motors' range along :math:`M N` (its complement in
    the metric :math:`M^{-1}`), :math:`B u = \tau - M N (N^\top M N)^{-1} N^\top \tau`, with
    ``N`` ``(nv, nv - k)`` the directions no motor acts on (:math:`N^\top B = 0`; numbers, in
    the namespace's matrix type): M itself and a solve of the size of the unactuated directions
    (a division for one). ``M`` may be None when every direction has a motor."""
    if N.shape[1] == 0:  # a motor for every direction: B u = tau
        return tau
    MN = M @ N
    S, r = N.T @ MN, N.T @ tau
    return tau - MN @ (r / S[0, 0] if N.shape[1] == 1 else xp.solve(S, r))


def fel_update(xp, theta_learned, grad, hess, rates: np.ndarray, is_goal: np.ndarray,
               update: str, damping: float):
    """The learned parameters after one update (eq. 3.6) from :math:`g = \\sum_k J_k^\\top
    e_k` and, for ``gauss_newton``, :math:`H = \\sum_k J_k^\\top E J_k`.

    ``gradient``: :math:`\\Delta\\theta = \\alpha \\odot g`. ``gauss_newton``: on the weights the
    Levenberg-Marquardt step :math:`\\Delta w = \\alpha_w (H_{ww} + \\lambda I)^{-1} g_w` with
    :math:`\\lambda` = ``damping`` times the mean of :math:`\\mathrm{diag}\\,H_{ww}`; the goals
    keep the gradient step.
    """
    delta = rates * grad
    if update == "gauss_newton":
        w = np.flatnonzero(~is_goal)
        idx = w if not xp.symbolic else w.tolist()
        H = hess[idx, :][:, idx] if not xp.symbolic else hess[idx, idx]
        n = len(w)
        mean_diag = float(np.mean(np.diag(H))) if not xp.symbolic else \
            sum(H[i, i] for i in range(n)) / n
        lam = damping * mean_diag + 1e-300
        step = rates[idx] * xp.solve(H + lam * xp.eye(n), grad[idx])
        if not xp.symbolic:
            delta[w] = step
        else:
            pos = {int(i): j for j, i in enumerate(w)}
            delta = xp.vec([step[pos[i]] if i in pos else delta[i] for i in range(len(is_goal))])
    return theta_learned + delta


def goal_step_scale(xp, grad, hess, dw, dg):
    r"""The fraction :math:`s \in [0, 1]` of the goals' gradient step ``dg`` that the closed
    loop's quadratic model of the error keeps (``learning.fit: closed_loop``): the step stops at
    the model's least error along ``dg`` where it would pass it.

    With :math:`g = \sum_k D_k^\top e_k`, :math:`H = \sum_k D_k^\top D_k` and the weights'
    step :math:`\Delta w` (``dw``), the error after both steps is :math:`e - D\Delta w -
    s D\Delta g`, least at :math:`s^\star = (g^\top\Delta g - \Delta w^\top H\Delta g) /
    (\Delta g^\top H\Delta g)`; :math:`s = \min(1, \max(0, s^\star))` (1 where the loop does
    not see the step). A gradient step's rate fits one loop gain; where the loop passes the
    goal more strongly (a faster period) the same rate overshoots."""
    Hdg = hess @ dg
    den = xp.dot(dg, Hdg)
    num = xp.dot(grad, dg) - xp.dot(dw, Hdg)
    return xp.where(den > 1e-300, xp.clip(num / (den + 1e-300), 0.0, 1.0), 1.0)


def fel_sums(xp, sens: list, deriv: list, E, rows=None):
    r"""The cycle's sums of eq. 3.6 without forming the Jacobian: :math:`g = \sum_k J_k^\top
    e_k` and (with ``rows``) :math:`H = \sum_k J_k^\top \mathrm{diag}(\mathrm{rows}) J_k`.

    A learned joint :math:`l` (velocity index :math:`i_l`) moves only its own desired
    position, velocity and acceleration, each linear in its parameters with the sample's
    sensitivity rows :math:`X_{q,l}[k], X_{v,l}[k], X_{a,l}[k]`, so the feedforward's Jacobian
    at sample k is :math:`J_k[:, l] = \partial_q\tau[:, i_l] X_{q,l}[k] + \partial_{\dot q}
    \tau[:, i_l] X_{v,l}[k] + M[:, i_l] X_{a,l}[k]`, and

    .. math::

        g_l = \sum_{c \in \{q, \dot q, \ddot q\}} X_{c,l}^\top s_{c,l}, \qquad
        s_{c,l}[k] = d_{c,l}[k]^\top e_k ,

    with :math:`d_{c,l}[k]` the derivative column :math:`i_l` at sample k: per sample a few
    dot products of length nv, then one product with each sensitivity matrix per cycle, so
    the cost per step does not grow with the number of basis functions.

    Args:
        sens: Per learned joint ``(Xq, Xv, Xa)``, each ``(n, P_l)``.
        deriv: Per learned joint ``(dq, dv, dm)``, each ``(nv, n)``: column :math:`i_l` of
            :math:`\partial\tau/\partial q`, :math:`\partial\tau/\partial\dot q` and M at
            every sample (through any map of the desired state, e.g. a walker's relabelling).
        E: ``(nv, n)`` error torques :math:`e_k`, already weighted by the phase each step
            covers.
        rows: ``(nv,)`` 0/1 (or ``(nv, n)`` weights) of the error rows for :math:`H`, or None
            (gradient only).

    Returns ``(g, H)`` over the learned joints' parameters in order (H None without ``rows``).
    """
    grads = []
    for X, d in zip(sens, deriv):
        grads.append(sum(xp.vecmat(xp.colsum(d[c] * E), X[c]) for c in range(3)))
    g = xp.concat(grads)
    if rows is None:
        return g, None
    blocks = []
    for X1, d1 in zip(sens, deriv):
        line = []
        for X2, d2 in zip(sens, deriv):
            line.append(sum(X1[a].T @ xp.scale_rows(X2[b], xp.colsum(rows * d1[a] * d2[b]))
                            for a in range(3) for b in range(3)))
        blocks.append(line)
    return g, xp.blocks(blocks)


__all__ = ["advance", "allocate", "clamp", "euler_map", "feedback", "fel_sums", "fel_update", "plain",
           "stepper", "wrap"]
