r"""The Gauss-Newton step through the closed loop in the compiled graph (``learning.fit:
closed_loop``): the numbers of :meth:`feltool.learning.fel.FeedbackErrorLearner.closed_loop_step`
(:mod:`feltool.learning.loop_map`) as CasADi expressions of the cycle.

Per control step, along the desired trajectory, the known model's symbolic RNEA gives
:math:`\partial_q\tau, \partial_{\dot q}\tau, M`; with the feedback linearized there
(linear rows :math:`[K_P c^\top, K_D c^\top]`, frame angles through their Jacobian) they give
the linearized step :math:`\delta x^+ = A_k\delta x + B_k\delta u` and the feedforward's
sensitivity :math:`J_k`. The parameters' state sensitivity is propagated over the cycle
(``mapaccum``), made periodic with the monodromy, and the error feedback's sensitivity
:math:`D_k = K^e_k Z_k` summed into :math:`H = \sum_k D_k^\top D_k`, :math:`g = \sum_k
D_k^\top e_k` for the Levenberg-Marquardt step (:func:`feltool.control.cycle.fel_update`),
:math:`e_k` without the transient of the cycle's start (the monodromy and the cycle's change of
state give the start's offset from the periodic state). The goals take the gradient step on
the error the weights' step leaves, :math:`\sum_k J_k^\top (e_k - D_k\Delta w)`.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from feltool.control.cycle import fel_sums, fel_update, goal_step_scale
from feltool.control.hold import hold_mean_columns
from feltool.control.ops import CASADI
from feltool.dynamics.symbolic import symbolic_rnea


def linearization(exp, blocks: tuple, frames: dict) -> ca.Function:
    """``(q, v, a, kp, kd, xq, xv, xa) -> (A, W, Ke, TB, J, B)`` at one step (SX): the
    linearized step's ``A`` ``(2nv, 2nv)``, the parameters' input ``W = B U`` ``(2nv, P)``, the
    error signal's state gain ``Ke`` ``(nv, 2nv)``, its direct term ``TB`` ``(nv, P)`` (learned
    tracked joints' references), the feedforward's sensitivity ``J`` ``(nv, P)`` and the
    torque's input ``B`` ``(2nv, nv)``; ``xq, xv,
    xa`` the learned joints' sensitivity rows at the step, concatenated in the order of
    ``blocks`` ``((velocity index, parameters), ...)``."""
    model, law, loop = exp.robot.model, exp.law, exp.loop
    nv = model.nv
    P = sum(p for _, p in blocks)
    q, v, a, kp, kd = (ca.SX.sym(s, nv) for s in ("q", "v", "a", "kp", "kd"))
    xq, xv, xa = (ca.SX.sym(s, P) for s in ("xq", "xv", "xa"))
    tau = symbolic_rnea(model)(q, v, a)
    Dq, Dv, M = ca.jacobian(tau, q), ca.jacobian(tau, v), ca.jacobian(tau, a)
    J, dQ, dV = ca.SX(nv, P), ca.SX(nv, P), ca.SX(nv, P)
    start = 0
    for i, p in blocks:
        cols = slice(start, start + p)
        J[:, cols] = (ca.mtimes(Dq[:, i], xq[cols].T) + ca.mtimes(Dv[:, i], xv[cols].T)
                      + ca.mtimes(M[:, i], xa[cols].T))
        dQ[i, cols], dV[i, cols] = xq[cols].T, xv[cols].T
        start += p
    rows = ca.SX(ca.DM(law.C))
    T = ca.SX(ca.DM.eye(nv))
    for row, kin in frames.items():
        jac = kin(q)[1]
        rows[row, :] = jac.T
        T[:, row] = jac
    Krows = ca.horzcat(ca.diag(kp) @ rows, ca.diag(kd) @ rows)
    err = ca.DM((np.asarray(loop.error_rows) > 0).astype(float))
    Te = T @ ca.diag(err)
    Ct = ca.DM(law.C * law.tracking[:, None])
    Bref = ca.diag(kp) @ Ct @ dQ + ca.diag(kd) @ Ct @ dV
    U = J + T @ Bref
    S = ca.DM(np.asarray(loop.actuated, float))
    Ax = -ca.solve(M, ca.horzcat(Dq, Dv))  # the dynamics' (the feedback: held, below)
    Au = ca.solve(M, ca.diag(S))
    h, semi = loop.dt / loop.substeps, loop.integrator == "semi_implicit_euler"
    eye, zero = ca.DM.eye(nv), ca.DM.zeros(nv, nv)
    if semi:  # v+ = v + h a; q+ = q + h v+
        a_v = ca.horzcat(zero, eye) + h * Ax
        a_s = ca.vertcat(ca.horzcat(eye, zero) + h * a_v, a_v)
        b_s = ca.vertcat(h * h * Au, h * Au)
    else:  # q+ = q + h v; v+ = v + h a
        a_s = ca.vertcat(ca.horzcat(eye, h * eye), ca.horzcat(zero, eye) + h * Ax)
        b_s = ca.vertcat(ca.DM.zeros(nv, nv), h * Au)
    A, B = a_s, b_s
    for _ in range(loop.substeps - 1):
        A, B = a_s @ A, a_s @ B + b_s
    A = A - B @ (T @ Krows)  # the feedback from the control step's start, held
    return ca.Function("loop_linearization", [q, v, a, kp, kd, xq, xv, xa],
                       [A, B @ U, Te @ Krows, Te @ Bref, J, B])


def closed_loop_step(exp, lay, theta, sens, desired, kp, kd, E, rates, damping, g_plain,
                     frames: dict, mask=None, dx=None):
    """The learned parameters after the closed-loop fit's step, in the graph: ``sens`` per
    learned joint ``[Xq, Xv, Xa]`` (each ``(n, P_l)``), ``desired`` ``(Qd, Vd, Ad)`` (each
    ``(nv, n)``), ``E`` the error torques ``(nv, n)``, ``g_plain`` the gradient of eq. 3.6 (the
    goals keep its step; None with ``sim.feedforward: hold_mean``: from the held
    sensitivity); ``frames`` the law's symbolic frame angles; ``mask`` ``(1, n)`` the
    steps the cycle has (cycles of changing length: a step it does not have leaves the
    sensitivity as it is and counts nowhere), None: all; ``dx`` ``(2nv, 1)`` the state's change
    over the cycle (with ``learning.remove_transient`` the fit is to the error without the
    transient of the cycle's start, :func:`feltool.learning.loop_map.transient_error`), None:
    the error as it is."""
    nv, n, P = lay.nv, lay.n, lay.n_learned
    Qd, Vd, Ad = desired
    XT = [ca.vertcat(*[blk[c].T for blk in sens]) for c in range(3)]  # (P, n) each
    lin = linearization(exp, lay.blocks, frames).map(n, "serial")
    A, W, Ke, TB, Jk, Bk = lin(Qd, Vd, Ad, ca.repmat(kp, 1, n), ca.repmat(kd, 1, n), *XT)
    if exp.config.sim.feedforward == "hold_mean":  # the held torque's sensitivity: J's mean
        Jbar = hold_mean_columns(Jk, P, mask)
        b, dj, e = ca.SX.sym("b", 2 * nv, nv), ca.SX.sym("dj", nv, P), ca.SX.sym("e", nv)
        through = ca.Function("hold_input", [b, dj], [ca.mtimes(b, dj)]).map(n, "serial")
        W, Jk = W + through(Bk, Jbar - Jk), Jbar
        # the goals' gradient of eq. 3.6 on the held feedforward: sum_k Jbar_k^T e_k
        g_plain = ca.sum2(ca.Function("hold_gradient", [dj, e], [ca.mtimes(dj.T, e)]).map(
            n, "serial")(Jbar, E))
    if mask is not None:
        def spread(rows, cols):  # the mask of every step over its block of columns
            return ca.kron(mask, ca.DM.ones(rows, cols))

        m2 = spread(2 * nv, 2 * nv)
        A = A * m2 + ca.repmat(ca.DM.eye(2 * nv), 1, n) * (1 - m2)
        W, Ke, TB = W * spread(2 * nv, P), Ke * spread(nv, 2 * nv), TB * spread(nv, P)
        Jk = Jk * spread(nv, P)
    z, x = ca.SX.sym("z", 2 * nv, P), ca.SX.sym("x", 2 * nv, 2 * nv)
    a_k, w_k = ca.SX.sym("a", 2 * nv, 2 * nv), ca.SX.sym("w", 2 * nv, P)
    roll = ca.Function("loop_roll", [z, x, a_k, w_k], [ca.mtimes(a_k, z) + w_k,
                                                        ca.mtimes(a_k, x)])
    roll = roll.mapaccum("loop_rolls", n, [0, 1], [0, 1])
    Zs, Xs = roll(ca.DM.zeros(2 * nv, P), ca.DM.eye(2 * nv), A, W)
    monodromy = Xs[:, (n - 1) * 2 * nv:]
    z0 = ca.solve(ca.DM.eye(2 * nv) - monodromy, Zs[:, (n - 1) * P:])
    d0 = ca.DM.zeros(2 * nv, 1)  # the cycle's start off the periodic state
    if dx is not None and exp.learner.loop.get("remove_transient"):
        d0 = ca.solve(monodromy - ca.DM.eye(2 * nv), dx)
    Zk = ca.horzcat(ca.DM.zeros(2 * nv, P), Zs[:, :(n - 1) * P])  # the state's at each start
    Xk = ca.horzcat(ca.DM.eye(2 * nv), Xs[:, :(n - 1) * 2 * nv])
    ke, zk, xk = ca.SX.sym("ke", nv, 2 * nv), ca.SX.sym("zk", 2 * nv, P), \
        ca.SX.sym("xk", 2 * nv, 2 * nv)
    tb, e, zz = ca.SX.sym("tb", nv, P), ca.SX.sym("e", nv), ca.SX.sym("z0", 2 * nv, P)
    jk, d = ca.SX.sym("jk", nv, P), ca.SX.sym("d0", 2 * nv)
    D = ca.mtimes(ke, zk + ca.mtimes(xk, zz)) - tb
    e_periodic = e + ca.mtimes(ke, ca.mtimes(xk, d))
    sums = ca.Function("loop_sums", [ke, zk, xk, zz, tb, e, jk, d],
                       [ca.mtimes(D.T, D), ca.mtimes(D.T, e_periodic), ca.mtimes(jk.T, D),
                        ca.mtimes(jk.T, e_periodic - e)])
    H, g, JD, g_transient = sums.map("loop_sum", "serial", n, [3, 7], [0, 1, 2, 3])(
        Ke, Zk, Xk, z0, TB, E, Jk, d0)
    is_goal = np.asarray(exp.learner.is_goal)
    pick = ca.DM(is_goal.astype(float))
    # the weights' Levenberg-Marquardt step, then the goals' gradient step on what it leaves
    theta_w = fel_update(CASADI, theta, (1 - pick) * g, H, rates, is_goal, "gauss_newton",
                         damping)
    g_goal = g_plain + g_transient - ca.mtimes(JD, theta_w - theta)
    dg = pick * rates * g_goal
    return theta_w + goal_step_scale(CASADI, g, H, theta_w - theta, dg) * dg


def fit_step(exp, lay, theta, sens, desired, kp, kd, Dall, E, rates, damping, frames: dict,
             mask=None, dx=None):
    """:func:`closed_loop_step` with the goals' gradient from the learned joints' derivative
    columns ``Dall`` (:func:`feltool.engines.compiled.graph.feedforward_function`'s, as
    :func:`feltool.engines.compiled.graph.fel_step` uses them)."""
    L, n = len(lay.blocks), lay.n
    deriv = [[Dall[:, [c * L + l + 3 * L * k for k in range(n)]] for c in range(3)]
             for l in range(L)]
    if mask is not None:
        E = E * ca.repmat(mask, lay.nv, 1)
    # the held feedforward's gradient comes from its own sensitivity, in closed_loop_step
    g_plain = fel_sums(CASADI, sens, deriv, E, None)[0] \
        if exp.config.sim.feedforward == "sample" else None
    return closed_loop_step(exp, lay, theta, sens, desired, kp, kd, E, rates, damping,
                            g_plain, frames, mask, dx)


__all__ = ["closed_loop_step", "fit_step", "linearization"]
