r"""The thesis's pinned walker (and allocated motors) as a CasADi graph: the compiled
:class:`feltool.walking.pinned.HybridLoop` and its learning cycle
(:func:`feltool.engines.python.hybrid_cycle`).

Each control step, from the stance label :math:`s` and the number of impacts so far (both part
of the state):

* the desired joint state :math:`q_d = G_s p_d` from the gait coordinates, with the foot
  placement's offsets (:meth:`feltool.walking.pinned.Walker.placement_offset`);
* feedback (:func:`feltool.control.cycle.feedback`), :math:`\tau = \mathrm{RNEA}(q_d, \dot q_d,
  \ddot q_d) + u_{fb}` mapped onto the motors (inertia-weighted or pseudo-inverse
  allocation, :class:`feltool.walking.pinned.Allocation`), the plant's semi-implicit Euler sub-steps;
* the fall check; the guard inside its window of the step, or the clock at the window's end:
  then the impact (the relabelling, or the rigid impact of the freed model:
  :math:`\dot q^+ = \dot q^- - M^{-1}J^\top(JM^{-1}J^\top)^{-1}J\dot q^-`, what
  ``pin.impulseDynamics`` solves) and the new stance label.

A fall freezes the state for the rest of the cycle and masks its steps out. The update
(eq. 3.6) runs through the stance-dependent map (:math:`J_k = D_k G_{s_k} X_k`), with the
samples after each impact left out (``learning.impact_window_s``), only if the cycle did not
fall. Per step the graph reports whether an impact happened, whether by the guard, and the
swing foot's position, from which the Python side rebuilds the cycle's impacts.
"""

from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np
import pinocchio as pin

from feltool.control.cycle import advance, allocate, feedback
from feltool.control.ops import CASADI
from feltool.dynamics.symbolic import (
    symbolic_frame_kinematics,
    symbolic_rnea,
    symbolic_rnea_derivatives,
)
from feltool.engines.compiled.graph import (
    controlled_error,
    cycle_outputs,
    cycle_stats,
    desired_from_data,
    fel_step,
    frames_at,
    layout,
    split_params,
    symbolic_forward,
    symbolic_frames,
    symbolic_reference,
)


def free_model(model: pin.Model) -> pin.Model:
    """``model`` with a sagittal base of two prismatic joints (x, then z) above its root: the
    walker's freed model (:class:`feltool.walking.pinned.Walker`'s ``free_model``, whose composite
    root joint the symbolic algorithms do not take), built by Pinocchio's ``appendModel``."""
    base = pin.Model()
    jx = base.addJoint(0, pin.JointModelPX(), pin.SE3.Identity(), "base_x")
    jz = base.addJoint(jx, pin.JointModelPZ(), pin.SE3.Identity(), "base_z")
    frame = base.addFrame(pin.Frame("base_z_frame", jz, 0, pin.SE3.Identity(),
                                    pin.FrameType.OP_FRAME))
    return pin.appendModel(base, model, frame, pin.SE3.Identity())


def same_dynamics(a: pin.Model, b: pin.Model) -> bool:
    """Equal mass matrices and bias forces at a seeded random state (to 1e-12)."""
    if a.nq != b.nq or a.nv != b.nv:
        return False
    rng = np.random.default_rng(0)
    q, v = rng.uniform(-1, 1, a.nq), rng.uniform(-1, 1, a.nv)
    da, db = a.createData(), b.createData()
    Ma, Mb = pin.crba(a, da, q), pin.crba(b, db, q)
    return bool(np.abs(np.triu(Ma) - np.triu(Mb)).max() < 1e-12 and
                np.abs(pin.rnea(a, da, q, v, v) - pin.rnea(b, db, q, v, v)).max() < 1e-10)


def _mass_matrix(model):
    """``q -> M(q)`` of a model, symbolically (the RNEA's Jacobian by the accelerations)."""
    derivs = symbolic_rnea_derivatives(model)
    nv = model.nv
    return lambda q: derivs(q, ca.SX.zeros(nv), ca.SX.zeros(nv))[2]


def walker_step_function(exp, plant, lay) -> ca.Function:
    """One control step of the hybrid loop (SX), see the module docstring::

        (x, s, j, k_step, fallen, p, pv, pa, k, kp, kd, targets)
            -> (x', s', j', k_step', fallen', qd, vd, ad, u_fb, u_rows, u_err, err,
                impact, by_guard, foot_x, D)

    ``D`` ``(nv, 3 L)``: the learned joints' derivative columns through :math:`G_s`.
    """
    H = exp.hybrid
    W, alloc, law = H.walker, H.allocation, exp.law
    model = exp.robot.model
    nv, dt = model.nv, H.dt
    sym = {name: ca.SX.sym(name, size) for name, size in (
        ("x", 2 * nv), ("s", 1), ("j", 1), ("k_step", 1), ("fallen", 1), ("p", nv),
        ("pv", nv), ("pa", nv), ("k", 1), ("kp", nv), ("kd", nv), ("targets", nv))}
    x, s, j, k_step, fallen = (sym[n] for n in ("x", "s", "j", "k_step", "fallen"))
    p, pv, pa, k = sym["p"], sym["pv"], sym["pa"], sym["k"]
    q, v = x[:nv], x[nv:]
    if W is not None:
        Gs = [ca.DM(G) for G in W.G]
        one = s > 0.5
        qd = ca.if_else(one, Gs[1] @ p, Gs[0] @ p)
        vd = ca.if_else(one, Gs[1] @ pv, Gs[0] @ pv)
        ad = ca.if_else(one, Gs[1] @ pa, Gs[0] @ pa)
        Ts = lay.n * dt / W.steps_per_cycle
        if W.placement is not None:
            i, jj, gain = W.placement
            u = ca.fmin(ca.fmax((k - k_step) * dt / Ts, 0.0), 1.0)
            e = ca.dot(ca.DM(W.A[jj]), q - qd)
            ev = ca.dot(ca.DM(W.A[jj]), v - vd)
            rr, rrd = 3 * u**2 - 2 * u**3, (6 * u - 6 * u**2) / Ts
            col = ca.DM(W.A_inv[:, i])
            qd, vd = qd + gain * e * rr * col, vd + gain * (ev * rr + e * rrd) * col
    else:
        qd, vd, ad = p, pv, pa
    r, rd = symbolic_reference(law, qd, vd, sym["targets"])
    frames = frames_at(symbolic_frames(law, model), q)
    sym_law = SimpleNamespace(C=ca.DM(law.C), kp=sym["kp"], kd=sym["kd"])
    u_fb, u_rows, u_err = feedback(CASADI, sym_law, q, v, r, rd, H.error_rows, frames)
    known = getattr(H.known, "model", model)
    qs, vs, as_ = (ca.SX.sym(n, nv) for n in ("qs", "vs", "as"))
    tau_s = symbolic_rnea(known)(qs, vs, as_)
    Dfull = [ca.jacobian(tau_s, z) for z in (qs, vs, as_)]
    ff = ca.Function("ff_walk", [qs, vs, as_], [tau_s, *Dfull])
    tau_ff, Dq, Dv, M = ff(qd, vd, ad)
    tau = tau_ff + u_fb
    if alloc is not None:
        B = ca.DM(alloc.B)
        if alloc.rule == "pseudo_inverse":
            tau = B @ (ca.DM(np.linalg.pinv(alloc.B)) @ tau)
        else:
            N = ca.DM(alloc.N)
            tau = allocate(CASADI, _mass_matrix(alloc.model)(q) if N.shape[1] else None, N,
                           tau)
    else:
        tau = ca.DM(H.actuated) * tau
    q1, v1 = advance(CASADI, symbolic_forward(plant), q, v, tau, dt / H.substeps, H.substeps,
                     H.integrator == "semi_implicit_euler")
    finite = (ca.sum1(ca.fabs(q1)) + ca.sum1(ca.fabs(v1))) < np.inf
    fall_now = 1 - finite
    if W is not None and W.fall_row is not None and np.isfinite(W.fall_max):
        fall_now = ca.fmax(fall_now, ca.fabs(ca.dot(ca.DM(W.fall_row), q1)) > W.fall_max)
    impact = by_guard = ca.SX(0)
    foot_x = ca.SX(np.nan)
    q2, v2, s2, j2, kstep2 = q1, v1, s, j, k_step
    if W is not None:
        t = (k + 1) * dt
        lo, hi = (j + W.window[0]) * Ts, (j + W.window[1]) * Ts
        guard = W.guard_sign * (ca.dot(ca.DM(W.guard_row), q1) - W.guard_value) >= 0
        by_guard = ca.logic_and(t >= lo - 1e-9, guard)
        impact = ca.logic_and(ca.logic_and(j < W.steps_per_cycle, 1 - fall_now),
                              ca.logic_or(by_guard, t >= hi - 1e-9))
        by_guard = ca.logic_and(by_guard, impact)
        vi = v1
        if W.free_model is not None:
            fm = free_model(model)
            fk = symbolic_frame_kinematics(fm, fm.getFrameId(W.free_model.frames[
                W.foot_frame].name))
            qe = ca.vertcat(0, 0, q1)
            pos, J = fk(qe, ca.SX.zeros(nv + 2), ca.SX.zeros(nv + 2))[:2]
            foot_x = pos[0]
            if W.impact == "rigid":
                Jc = J[[0, 2], :]
                Me = _mass_matrix(fm)(qe)
                ve = ca.vertcat(0, 0, v1)
                X = ca.solve(Me, Jc.T)
                vi = (ve - X @ ca.solve(Jc @ X, Jc @ ve))[2:]
        R = ca.DM(W.R)
        q2 = ca.if_else(impact, R @ q1, q1)
        v2 = ca.if_else(impact, R @ vi, v1)
        s2 = ca.if_else(impact, 1 - s, s)
        j2 = j + impact
        kstep2 = ca.if_else(impact, k + 1, k_step)
    # derivative columns of the learned joints through G_s
    cols = []
    for D in (Dq, Dv, M):
        for i, _ in lay.blocks:
            if W is not None:
                cols.append(ca.if_else(one, D @ ca.DM(W.G[1][:, i]), D @ ca.DM(W.G[0][:, i])))
            else:
                cols.append(D[:, i])
    Dcols = ca.horzcat(*cols) if cols else ca.SX(nv, 0)
    err = controlled_error(law, r, q, frames)
    # a cycle that fell keeps its state for the steps left
    live = 1 - fallen
    nxt = [ca.if_else(live, a, b) for a, b in ((ca.vertcat(q2, v2), x), (s2, s), (j2, j),
                                                (kstep2, k_step))]
    fallen2 = ca.fmax(fallen, fall_now)
    names = ["x", "s", "j", "k_step", "fallen", "p", "pv", "pa", "k", "kp", "kd", "targets"]
    return ca.Function("walk_step", [sym[n] for n in names],
                       [*nxt, fallen2, qd, vd, ad, u_fb, u_rows, u_err, err * live,
                        impact * live, by_guard * live, foot_x, Dcols])


def walker_cycle_function(exp, plant, full: bool = False,
                          name: str = "walk_cycle") -> ca.Function:
    """The pinned walker's cycle ``(state, data, params) -> (state', stats)`` (the data and
    params of :mod:`feltool.engines.compiled.graph`); ``stats`` also hold, after the arm's, the fall
    flag, the number of steps run, and per step the impact flag, whether by the guard, and
    the swing foot's x [m]. With ``full``: the trace (``X``, ``U``, ``Urows``, ``Uerr``,
    ``Qd``)."""
    lay = layout(exp)
    learner, law = exp.learner, exp.law
    nv, n, L, PL = lay.nv, lay.n, len(lay.blocks), lay.n_learned
    state = ca.MX.sym("state", lay.n_state)
    data = ca.MX.sym("data", lay.n_data)
    params = ca.MX.sym("params", lay.n_params)
    theta, x0 = state[:PL], state[PL:]
    kp, kd, targets, rates, damping = split_params(lay, params)[:5]
    sens, (P, Pv, Pa), _, _ = desired_from_data(lay, theta, data)
    step = walker_step_function(exp, plant, lay).mapaccum("walk", n, [0, 1, 2, 3, 4],
                                                         [0, 1, 2, 3, 4])
    zero = ca.MX(0)
    X_after, S, Jn, Ks, F, Qd, Vd, Ad, U, Urows, Uerr, err, imp, guard, foot, Dall = step(
        x0, zero, zero, zero, zero, P, Pv, Pa, ca.DM(np.arange(n)).T,
        ca.repmat(kp, 1, n), ca.repmat(kd, 1, n), ca.repmat(targets, 1, n))
    X = ca.horzcat(x0, X_after[:, :n - 1])
    x_end = X_after[:, n - 1]
    fell = F[:, n - 1]
    live = ca.horzcat(ca.DM.ones(1, 1), 1 - F[:, :n - 1])  # the steps the cycle ran
    n_run = ca.sum2(live)
    finite = (ca.sum1(ca.sum2(ca.fabs(X) * ca.repmat(live, 2 * nv, 1)))
              + ca.sum1(ca.fabs(x_end))) < np.inf
    theta_next = theta
    if L:
        keep = live
        window = int(round(exp.config.learning.impact_window_s / exp.config.dt))
        if window > 0:  # the samples after each impact leave the update (impact_masked)
            hit = ca.MX.zeros(1, n)
            for d in range(1, window + 1):  # impact after step k: rows k+1 .. k+window
                hit = hit + ca.horzcat(ca.DM.zeros(1, d), imp[:, :n - d])
            hit = hit + ca.horzcat(ca.repmat(imp[:, n - 1], 1, window),
                                   ca.DM.zeros(1, n - window))  # the last wraps to row 0
            keep = keep * (hit < 0.5)
        E = Uerr * ca.repmat(keep, nv, 1)
        step_ = fel_step(learner, lay, theta, sens, Dall, E, E, rates, damping)
        theta_next = ca.if_else(fell, theta, step_)
    stats = cycle_stats(law, live, X, Qd, U, Urows, Uerr, err, ca.MX.zeros(2 * nv, n),
                        finite, live)
    stats = ca.vertcat(stats, fell, n_run, imp.T, guard.T, foot.T)
    return cycle_outputs(name, state, data, params, ca.vertcat(theta_next, x_end), stats,
                         (X, U, Urows, Uerr, Qd), full)
