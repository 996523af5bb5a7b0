r"""The physical walker's learning cycle as a CasADi graph (:class:`feltool.walking.physical.PhysicalLoop`
compiled, with ``walking.phase: mechanical``).

Each control step, as the Python engine does it:

* the mechanical phase: the centre of mass's horizontal position over the stance foot located
  in the step's desired values (a piecewise-linear inverse, as ``np.interp``), the forward and
  reference trajectories interpolated there, with the phase's rate and acceleration;
* the desired state completed by the stance foot's constraint (:meth:`PhysicalWalker.complete`),
  relabelled in every second step; feedback; the wanted generalized force mapped onto the
  motors in the constrained metric (:meth:`PhysicalWalker.allocation_matrix`), saturated or
  counted against the effort limits; the inertial error term :math:`M(\ddot q_r - \ddot q)`;
* the sub-steps: the stance contact's force and its checks, classical Runge-Kutta with the
  stance foot held (KKT solves of :math:`M\ddot q + b = \tau + J_c^\top F`,
  :math:`J_c\ddot q + \dot J_c\dot q = 0`), the swing foot's clearance; a touchdown located
  inside the sub-step by bisection on the foot's height (to far below Brent's 1e-12 s), the
  rigid impact (:math:`M(\dot q^+ - \dot q^-) = J^\top I`, :math:`J\dot q^+ = 0`), the
  relabelling and the new stance foot put at the origin.

A touchdown's branch and the steps after the cycle's last touchdown are conditional: the
generated code runs only what the Python engine would. The steps are chained calls that read the
cycle's trajectories in place (``mapaccum`` would copy them to every step). Whatever stops a
cycle (a contact check, a fall, no touchdown) is reported by a code; the Python engine then
reruns that cycle for its message and numbers (it is the seed's last). The update (eq. 3.6,
Gauss-Newton in motor torques with the inverse-dynamics error estimate) uses the sensitivity row
of the sample nearest each step's phase, as the Python engine does; its sums are accumulated in
the step's state, step by step (a row picked by index per step, not a steps x samples
assignment matrix after the cycle).
"""

from __future__ import annotations

from dataclasses import replace

import casadi as ca
import numpy as np

from feltool.control.cycle import fel_update, wrap
from feltool.control.ops import CASADI
from feltool.engines.compiled.graph import (
    desired_from_data,
    layout,
    split_params,
)
from feltool.engines.compiled.physical_step import (
    DESIGN,
    Control,
    Kin,
    Step,
    capacity,
    stop_code,
)

#: Steps chained per block (the cycle is blocks of blocks: few call sites in the C code).
BLOCK = 40


def physical_layout(exp):
    """The physical walker's :class:`~feltool.engines.compiled.graph.Layout`: its ``n`` the
    graph's capacity in samples (:func:`~feltool.engines.compiled.physical_step.capacity`),
    the cycle's own samples an input (the data's last two entries)."""
    return replace(layout(exp), n=capacity(exp))


def row_fields(nv: int) -> list[tuple[str, int]]:
    """A control step's row of the trace: its fields in order, with their sizes."""
    return [("valid", 1), ("q", nv), ("v", nv), ("qd", nv), ("r", nv), ("U", nv),
            ("Urows", nv), ("Uerr", nv), ("err", 1), ("work", 1), ("impact", 1), ("length", 1),
            ("tau", nv)]


def unpack(vec, fields) -> dict:
    """``vec``'s consecutive rows (a column's entries, a matrix's rows) named by ``fields``
    (``(name, size)`` pairs)."""
    out, pos = {}, 0
    for name, size in fields:
        out[name] = vec[pos:pos + size, :]
        pos += size
    return out


class PhysicalGraph:
    """The physical walker's cycle functions (see the module docstring)."""

    def __init__(self, exp):
        self.exp = exp
        self.kin = Kin(exp)
        self.stp = Step(exp, self.kin)
        self.ctl = Control(exp, self.kin, self.stp)
        stp = self.stp
        self.nv, self.k, self.n = stp.nv, stp.k, stp.n  # n: the capacity (samples)
        self.n_max = BLOCK * int(np.ceil(3 * self.n / BLOCK))
        self.lay = physical_layout(exp)
        self.sizes = stp.sizes()
        # the FEL sums of eq. 3.6, accumulated step by step (grad; Gauss-Newton: its matrix)
        PL = self.lay.n_learned
        self.gauss_newton = exp.learner.update == "gauss_newton"
        self.sizes.update(grad=PL, hess=PL * PL if self.gauss_newton else 0)
        # the model correction's and motor biases' sums (feltool.learning.walker_model)
        self.n_model = Pm = self.ctl.n_model()
        self.sizes.update(grad_m=Pm, hess_m=Pm * Pm)
        self.sizes.update(count=1)  # the control steps run (the cycle's limit: 3 n)
        # the cycle's metrics, accumulated step by step (no steps x fields matrix of rows:
        # the graph holds more steps than a cycle runs)
        nv, law = self.nv, exp.law
        self.stab = np.flatnonzero(law.stabilizing).tolist()
        self.err_refs = not self.stab and bool(stp.refs)
        n_err = len(stp.refs) if self.err_refs else len(self.stab)
        self.acc_start = sum(self.sizes.values())
        self.sizes.update(abs_u=nv, dq2=nv, max_err=1, max_speed=1, abs_urows=nv, abs_uerr=nv,
                          abs_q=1, work=1, stab_sq=n_err, at=stp.spc, lengths=stp.spc)
        self.n_state = sum(self.sizes.values())
        self.row_size = sum(sz for _, sz in row_fields(self.nv))
        self._body = None  # (one step's code for the cycle and the trace)

    def input_sizes(self) -> list[int]:
        """The sizes of a step's inputs after its state: ``consts, kp, kd, targets, srows, w,
        theta_m, design``."""
        nv = self.nv
        return [self.ctl.consts_size(), nv, nv, nv, self.srows_size(), self.kin.n_world,
                self.n_model, DESIGN]

    def inputs(self) -> list:
        """The step's inputs after its state as one vector (:meth:`input_sizes`): one
        argument per call, so that building the graph's thousands of chained calls is quick
        (CasADi's calls with several large and empty arguments cost milliseconds each)."""
        return [ca.MX.sym("C", sum(self.input_sizes()))]

    def split_inputs(self, C) -> list:
        """The pieces of :meth:`inputs`' vector."""
        out, pos = [], 0
        for size in self.input_sizes():
            out.append(C[pos:pos + size])
            pos += size
        return out

    def step_function(self, full: bool = True) -> ca.Function:
        """One control step (MX) ``(S, consts, kp, kd, targets, srows, w, theta_m, design)
        -> (S', row)``, run only while the cycle runs (the state and an empty row otherwise);
        ``w`` the plant's world vector (:func:`feltool.engines.compiled.physical_step.
        world_vector`), ``design`` the cycle's samples and the known model's gravity
        (:data:`~feltool.engines.compiled.physical_step.DESIGN`). Without ``full``: no row
        (the same step's code, its row not written)."""
        if self._body is None:
            self._body = self._step_body()
        body = self._body
        S = ca.MX.sym("S", self.n_state)
        ins = self.inputs()
        args = [S, *ins]
        running = self.is_running(S, self.split_inputs(ins[0])[-1])
        if not full:
            run = ca.Function("phys_run_s", args, [body(*args)[0]])
            idle = ca.Function("phys_idle_s", args, [S])
            switch = ca.Function.conditional("phys_switch_s", [idle], run)
            return ca.Function("phys_step_s", args, [switch(running, *args)])
        idle = ca.Function("phys_idle", args, [S, ca.DM.zeros(self.row_size)])
        switch = ca.Function.conditional("phys_switch", [idle], body)  # 0: idle, else: run
        S_out, row_out = switch(running, *args)
        return ca.Function("phys_step", args, [S_out, row_out])

    def _step_body(self) -> ca.Function:
        """The control step itself: ``(S, consts, ..., design) -> (S', row)``."""
        stp, W, nv = self.stp, self.kin.W, self.nv
        S = ca.MX.sym("S", self.n_state)
        ins = self.inputs()
        consts, kp, kd, targets, srows, w, theta_m, design = self.split_inputs(ins[0])
        st = unpack(S, self.sizes.items())
        (tau, u, over, qd, vd, ad, r, U, Urows, Uerr, A, inert, phase_acc_next, jj, label,
         err, a1, F) = self.ctl.function()(st["q"], st["v"], st["phase_acc"], st["n_imp"], consts,
                                           kp, kd, targets, w, theta_m, design)
        hits = st["hits"] + over
        stop = st["stop"]
        if W.checks.torques == "report":
            stop = ca.if_else(ca.logic_and(stop == 0, ca.sum1(over) > 0), stop_code("torque"), stop)
        motors = [int(i) for i in W.motor_v]
        work = ca.sum1(ca.fabs(u * st["v"][motors])) * stp.dt
        q, v = st["q"], st["v"]
        checks = ca.vertcat(stop, st["min_fn"], st["max_ratio"], st["min_clear"])
        impact, length, ratio, lost = ca.MX(0), ca.MX(0), ca.MX(-np.inf), ca.MX(0)
        h = stp.dt / stp.substeps
        elapsed = ca.MX(stp.dt)  # the control step's time in [s]: a touchdown ends it
        sub, td = self.stp.substep(), self.stp.touchdown()
        branch_fn = self._touchdown_switch(td)
        for i_sub in range(stp.substeps):
            if i_sub:
                a1, F = self.kin.stance(q, v, tau, w)
            q1, v1, checks1, landing, anchor, _ = sub(q, v, tau, h, checks, a1, F, w)
            land = ca.logic_and(landing, impact == 0)
            # the touchdown's branch is evaluated only when landing
            branch = branch_fn(land, q, v, tau, h, anchor, checks, q1, v1, checks1, w)
            frozen = impact > 0  # after a touchdown the control step ends
            q = ca.if_else(frozen, q, branch[:nv])
            v = ca.if_else(frozen, v, branch[nv:2 * nv])
            checks = ca.if_else(frozen, checks, branch[2 * nv:2 * nv + 4])
            ratio = ca.if_else(land, branch[2 * nv + 4], ratio)
            lost = ca.if_else(land, branch[2 * nv + 5], lost)
            length = ca.if_else(land, branch[2 * nv + 6], length)
            elapsed = ca.if_else(land, i_sub * h + branch[2 * nv + 7], elapsed)
            impact = ca.fmax(impact, land)
        n_imp = st["n_imp"] + impact
        stop = checks[0]
        finite = (ca.sum1(ca.fabs(q)) + ca.sum1(ca.fabs(v))) < np.inf
        fell = 1 - finite
        if W.fall_row is not None and np.isfinite(W.fall_max):
            fell = ca.fmax(fell, ca.fabs(ca.dot(ca.DM(W.fall_row), q)) > W.fall_max)
        stop = ca.if_else(ca.logic_and(stop == 0, fell), stop_code("fall"), stop)
        new = {"q": q, "v": v, "n_imp": n_imp,
               "phase_acc": ca.if_else(impact, 0.0, phase_acc_next), "stop": stop,
               "done": n_imp >= stp.spc, "min_fn": checks[1], "max_ratio": checks[2],
               "min_clear": checks[3],
               "max_imp_ratio": ca.if_else(impact, ca.fmax(st["max_imp_ratio"], ratio),
                                           st["max_imp_ratio"]),
               "energy": st["energy"] + impact * lost, "length": st["length"] + impact * length,
               "time": st["time"] + elapsed, "hits": hits}
        E = Uerr + inert if self.inverse_dynamics else Uerr
        new["grad"], new["hess"] = self._fel_sums(st, qd, vd, ad, label, A, E, jj, srows,
                                                  design)
        new["grad_m"], new["hess_m"] = self._model_sums(st, qd, vd, ad, A, E, design)
        new["count"] = st["count"] + 1
        new.update(self._metric_sums(st, new, qd, r, U, Urows, Uerr, err, work, impact, length,
                                     targets))
        S_new = ca.vertcat(*[new[name] for name in self.sizes])
        row = ca.vertcat(1, st["q"], st["v"], qd, r, U, Urows, Uerr, err, work, impact,
                         impact * length, tau)  # (row_fields)
        return ca.Function("phys_body", [S, *ins], [S_new, row])

    def _metric_sums(self, st, new, qd, r, U, Urows, Uerr, err, work, impact, length,
                     targets) -> dict:
        """The step's terms of the cycle's metrics (:func:`feltool.engines.compiled.graph.
        cycle_stats` and the contact metrics, summed over the steps in the same order) added
        to the state's; ``st`` the state at the step's start, ``new`` the one after it."""
        q, v = st["q"], st["v"]
        dq = qd - q
        C = ca.DM(self.exp.law.C)
        if self.err_refs:
            errs = [(C[i, :] @ q) - r[i] for i in self.stp.refs]
        else:
            errs = [(C[i, :] @ q) - targets[i] for i in self.stab]
        sq = ca.vertcat(*[wrap(CASADI, e) ** 2 for e in errs]) if errs else ca.MX.zeros(0)
        landed = [ca.logic_and(impact > 0, st["n_imp"] == t) for t in range(self.stp.spc)]
        return {
            "abs_u": st["abs_u"] + ca.fabs(U), "dq2": st["dq2"] + dq * dq,
            "max_err": ca.fmax(st["max_err"], err),
            "max_speed": ca.fmax(st["max_speed"], ca.mmax(ca.fabs(v))),
            "abs_urows": st["abs_urows"] + ca.fabs(Urows),
            "abs_uerr": st["abs_uerr"] + ca.fabs(Uerr),
            "abs_q": st["abs_q"] + ca.sum1(ca.fabs(q)), "work": st["work"] + work,
            "stab_sq": st["stab_sq"] + sq,
            "at": ca.vertcat(*[ca.if_else(hit, new["count"], st["at"][t])
                               for t, hit in enumerate(landed)]),
            "lengths": ca.vertcat(*[ca.if_else(hit, length, st["lengths"][t])
                                    for t, hit in enumerate(landed)])}

    @property
    def inverse_dynamics(self) -> bool:
        return self.exp.config.learning.error_estimate == "inverse_dynamics"

    def srows_size(self) -> int:
        """The learned joints' sensitivity rows, row-major per joint and derivative order."""
        return 3 * self.n * self.lay.n_learned

    def is_running(self, S, design):
        """Whether the cycle of state ``S`` still runs: nothing stopped it, its walk steps
        are not all done, and it has run fewer control steps than its limit (3 n, rounded up
        to whole blocks, n the cycle's samples in ``design``)."""
        st = unpack(S, self.sizes.items())
        limit = BLOCK * ca.ceil(3 * design[0] / BLOCK)
        return ca.logic_and(ca.logic_and(st["stop"] == 0, st["done"] == 0),
                            st["count"] < limit)

    def _fel_sums(self, st, qd, vd, ad, label, A, E, jj, srows, design):
        """The step's terms of eq. 3.6's sums added to the state's: with the sensitivity row
        of the step's sample ``jj`` (:math:`T_l`, 3 x P_l) and the step's derivative columns
        ``s = d^T e``, ``g = d_a^T d_b`` (:func:`_fel_step`): grad_l += T_l^T s_l,
        hess_(l1, l2) += T_l1^T G_(l1, l2) T_l2."""
        blocks, n = self.lay.blocks, self.n
        L = len(blocks)
        if not L:
            return st["grad"], st["hess"]
        s_vals, g_vals = _fel_step(self.kin, self.lay, self.exp, self.k)(qd, vd, ad, label, A, E,
                                                                         design[2:5])
        j = ca.fmin(ca.fmax(jj, 0), design[0] - 1)
        T, grads, off = [], [], 0
        for l, (_, P) in enumerate(blocks):
            rows = [srows[off + c * n * P + j * P + ca.DM(np.arange(P))] for c in range(3)]
            T.append(ca.horzcat(*rows))  # P x 3
            grads.append(ca.mtimes(T[l], ca.vertcat(*[s_vals[c * L + l] for c in range(3)])))
            off += 3 * n * P
        grad = st["grad"] + ca.vertcat(*grads)
        if not self.gauss_newton:
            return grad, st["hess"]
        D3 = 3 * L
        blocks_h = [[ca.mtimes(T[l1], ca.mtimes(
            ca.reshape(ca.vertcat(*[g_vals[(a * L + l1) * D3 + (b * L + l2)]
                                    for b in range(3) for a in range(3)]), 3, 3), T[l2].T))
            for l2 in range(L)] for l1 in range(L)]
        return grad, st["hess"] + ca.vec(ca.blockcat(blocks_h))

    def _model_sums(self, st, qd, vd, ad, A, E, design):
        r"""The step's terms of the model learner's sums (:mod:`feltool.learning.walker_model`)
        added to the state's: with :math:`\Phi = [A Y, I]` and :math:`e_m = A e`,
        ``grad_m += Phi^T e_m``, ``hess_m += Phi^T Phi``."""
        if not self.n_model:
            return st["grad_m"], st["hess_m"]
        kin, k = self.kin, self.k
        Am = ca.reshape(A, k, self.nv)
        cols = []
        if kin.n_pi:
            cols.append(ca.mtimes(Am, kin.regressor(qd, vd, ad, design[2:5])))
        if self.n_model > kin.n_pi:
            cols.append(ca.DM.eye(k))
        Phi = ca.horzcat(*cols)
        em = ca.mtimes(Am, E)
        return (st["grad_m"] + ca.mtimes(Phi.T, em),
                st["hess_m"] + ca.vec(ca.mtimes(Phi.T, Phi)))

    def _touchdown_switch(self, td: ca.Function) -> ca.Function:
        """``(land, q, v, tau, h, anchor, checks, q1, v1, checks1) -> branch``: the
        touchdown's state, checks, impulse ratio, energy lost, step length and time in the
        sub-step when ``land``, else the sub-step's state and checks (only the chosen branch is
        evaluated)."""
        nv = self.nv
        args = [ca.MX.sym(n, sz) for n, sz in (("q", nv), ("v", nv), ("tau", nv), ("h", 1),
                                               ("anchor", 2), ("checks", 4), ("q1", nv),
                                               ("v1", nv), ("checks1", 4),
                                               ("w", self.kin.n_world))]
        q, v, tau, h, anchor, checks, q1, v1, checks1, w = args
        no = ca.Function("no_touchdown", args, [ca.vertcat(q1, v1, checks1, -np.inf, 0, 0, h)])
        qn, vn, checks_td, ratio, lost, length, s = td(q, v, tau, h, anchor, checks1, w)
        yes = ca.Function("touchdown_branch", args,
                          [ca.vertcat(qn, vn, checks_td, ratio, lost, length, s)])
        switch = ca.Function.conditional("touchdown_switch", [no], yes)
        land = ca.MX.sym("land")
        return ca.Function("touchdown_or_not", [land, *args], [switch(land, *args)])

    def steps_function(self, full: bool = True) -> ca.Function:
        """All the cycle's steps: blocks of :data:`BLOCK` chained steps, chained (few call
        sites; the constants read in place). A block that starts with the cycle over is not
        run (the state and empty rows): the graph holds the capacity's steps, a cycle runs
        its own. Without ``full``: the state only (no rows)."""
        one = self.step_function(full)
        S = ca.MX.sym("S", self.n_state)
        args = self.inputs()
        if not full:
            s = S
            for _ in range(BLOCK):
                s = one(s, *args)
            body = ca.Function("phys_block_run_s", [S, *args], [s])
            idle = ca.Function("phys_block_idle_s", [S, *args], [S])
            switch = ca.Function.conditional("phys_block_switch_s", [idle], body)
            block = ca.Function("phys_block_s", [S, *args],
                                [switch(self.is_running(S, self.split_inputs(args[0])[-1]),
                                        S, *args)])
            s = S
            for _ in range(self.n_max // BLOCK):
                s = block(s, *args)
            return ca.Function("phys_steps_s", [S, *args], [s])
        s, rows = S, []
        for _ in range(BLOCK):
            s, row = one(s, *args)
            rows.append(row)
        body = ca.Function("phys_block_run", [S, *args], [s, ca.horzcat(*rows)])
        idle = ca.Function("phys_block_idle", [S, *args],
                           [S, ca.DM.zeros(self.row_size, BLOCK)])
        switch = ca.Function.conditional("phys_block_switch", [idle], body)
        block = ca.Function("phys_block", [S, *args],
                            list(switch(self.is_running(S, self.split_inputs(args[0])[-1]),
                                        S, *args)))
        s, rows = S, []
        for _ in range(self.n_max // BLOCK):
            s, r = block(s, *args)
            rows.append(r)
        return ca.Function("phys_steps", [S, *args], [s, ca.horzcat(*rows)])


#: The contact metrics of a cycle in the graph's stats, in order (:func:`feltool.runs.seed.
#: contact_metrics`).
CONTACT = ("min_normal_force", "max_friction_ratio", "min_clearance", "max_impulse_ratio",
           "impact_energy_lost", "step_length", "distance", "steps", "duration", "work",
           "stabilized_rms")


def physical_cycle_function(exp, plant=None, full: bool = False, name: str = "phys_cycle",
                            graph: PhysicalGraph | None = None) -> ca.Function:
    """The physical walker's cycle ``(state, data, params) -> (state', stats)`` (the arm's
    data with the referenced joints' samples appended; the params with the simulated world's
    vector appended, :func:`~feltool.engines.compiled.physical_step.world_vector`: one build
    runs every world of the walker's joints, ``plant`` is not used); ``stats``: the arm's, then the stop
    code, the steps run, the touchdowns' steps and lengths, and :data:`CONTACT`. With
    ``full``: the rows of every step (:func:`row_fields`). ``graph``: the walker's
    :class:`PhysicalGraph`, shared by its cycle and its trace (one step's code in the library,
    compiled once)."""
    g = graph or PhysicalGraph(exp)
    lay = g.lay
    kin, stp, W, learner = g.kin, g.stp, g.kin.W, exp.learner
    nv, n, k, L, PL = g.nv, g.n, g.k, len(lay.blocks), lay.n_learned
    spc, refs = stp.spc, stp.refs
    state = ca.MX.sym("state", lay.n_state)
    data = ca.MX.sym("data", lay.n_data + 3 * n * len(refs) + 2)  # the cycle's n, ns last
    params = ca.MX.sym("params", lay.n_params + kin.n_world + 3)  # the worlds last
    Pm = g.n_model
    theta, theta_m, x0 = state[:PL], state[PL:PL + Pm], state[PL + Pm:]
    kp, kd, targets, rates, damping = split_params(lay, params[:lay.n_params])[:5]
    world = params[lay.n_params:lay.n_params + kin.n_world]
    n_in, ns_in = data[-2], data[-1]  # this cycle's samples (n: the graph's capacity)
    design = ca.vertcat(n_in, ns_in, params[lay.n_params + kin.n_world:])
    sens, (P, Pv, Pa), _, _ = desired_from_data(lay, theta, data)
    R = [P, Pv, Pa]
    for j, i in enumerate(refs):  # a referenced joint's feedback and phase follow samples
        for c in range(3):
            start = lay.n_data + (3 * j + c) * n
            R[c] = ca.vertcat(R[c][:i, :], data[start:start + n].T, R[c][i + 1:, :])
    # the mechanical phase's grids: the reference's centre of mass over each walk step
    p_, pv_, pa_, lab_ = (ca.SX.sym(s, nv if s != "l" else 1) for s in ("p", "v", "a", "l"))
    qd_, vd_, ad_ = kin.complete(*kin.labelled(p_, pv_, pa_, lab_))
    grid = ca.Function("grid", [p_, pv_, pa_, lab_], [ca.vertcat(*kin.com_x(qd_, vd_, ad_))])
    # (only the cycle's spc * ns samples: zeros after them)
    none = ca.Function("no_grid", [p_, pv_, pa_, lab_], [ca.DM.zeros(3)])
    grid_or_not = ca.Function.conditional("grid_or_not", [none], grid)
    at = ca.DM(np.arange(n)).T
    labels = ca.fmod(ca.floor(at / ns_in), 2)
    G = grid_or_not.map(n, "serial")(at < spc * ns_in, R[0], R[1], R[2], labels)
    # the grid must increase within each walk step
    after = ca.DM(np.arange(1, n)).T
    inside = ca.logic_and(after < spc * ns_in, ca.fmod(after, ns_in) != 0)
    phase_bad = ca.mmax(ca.if_else(inside, (G[0, 1:] - G[0, :n - 1]) <= 0, 0))
    consts = ca.vertcat(*[ca.vec(M) for M in (P, Pv, Pa, *R)], *[G[c, :].T for c in range(3)])
    S0 = ca.vertcat(x0, 0, 0, ca.if_else(phase_bad, stop_code("phase"), 0), 0, np.inf, 0, np.inf,
                    -np.inf, 0, 0, 0, ca.DM.zeros(k), ca.DM.zeros(g.sizes["grad"]),
                    ca.DM.zeros(g.sizes["hess"]))
    srows = ca.vertcat(*[ca.vec(sens[l][c].T) for l in range(L) for c in range(3)]) if L \
        else ca.MX.zeros(0)
    S0 = ca.vertcat(S0, ca.DM.zeros(g.n_state - g.acc_start + Pm + Pm * Pm + 1))  # (count,
    # the metrics' sums)
    args = (S0, ca.vertcat(consts, kp, kd, targets, srows, world, theta_m, design))
    if full:
        S, rows = g.steps_function(True)(*args)
    else:
        S = g.steps_function(False)(*args)
    st = unpack(S, g.sizes.items())
    ended = st["n_imp"] >= spc
    stop = ca.if_else(ca.logic_and(st["stop"] == 0, 1 - ended), stop_code("touchdown"), st["stop"])
    m = st["count"]
    # the update (eq. 3.6): the sums accumulated over the steps with the sensitivity rows of
    # the samples nearest the steps' phases
    theta_next = theta
    if L:
        g_ = st["grad"]
        hess = ca.reshape(st["hess"], PL, PL) if g.gauss_newton else None
        step = fel_update(CASADI, theta, g_, hess, rates, learner.is_goal, learner.update,
                          damping)
        theta_next = ca.if_else(stop == 0, step, theta)
    # metrics (feltool.engines.python.cycle_outcome and contact_metrics over the steps run,
    # as feltool.engines.compiled.graph.cycle_stats)
    finite = (st["abs_q"] + ca.sum1(ca.fabs(st["q"]))) < np.inf
    hits = ca.MX.zeros(2 * nv)  # the joints' limits are not checked; the motors' torques are
    for j, i in enumerate(W.motor_v):
        hits[nv + int(i)] = st["hits"][j]
    stab = g.stab
    fb_stab = ca.sum1((st["abs_urows"] / m)[stab]) if stab else ca.MX(0)
    stats = [st["abs_u"] / m, ca.sqrt(st["dq2"] / m), st["max_err"], st["max_speed"], fb_stab,
             ca.sum1(st["abs_uerr"] / m), finite, hits]
    n_err = g.sizes["stab_sq"]
    sq = sum(st["stab_sq"][i] for i in range(n_err)) if n_err else ca.MX(0)
    stab_rms = ca.sqrt(sq / (m * n_err)) if n_err else ca.MX(0)
    steps_at = [st["at"][t] for t in range(spc)]
    lengths = [st["lengths"][t] for t in range(spc)]
    n_steps = st["n_imp"]
    nan = ca.MX(np.nan)
    contact = [st["min_fn"], st["max_ratio"],
               ca.if_else(st["min_clear"] < np.inf, st["min_clear"], nan),
               ca.if_else(n_steps > 0, st["max_imp_ratio"], nan), st["energy"],
               ca.if_else(n_steps > 0, st["length"] / n_steps, nan), st["length"], n_steps,
               st["time"], st["work"], stab_rms]
    stats += [stop, m, *steps_at, *lengths, *contact]
    theta_m_next = theta_m
    if Pm:  # the model correction's and biases' Levenberg-Marquardt step
        H = ca.reshape(st["hess_m"], Pm, Pm)
        lam = split_params(lay, params[:lay.n_params])[6] * ca.sum1(ca.diag(H)) / Pm + 1e-300
        delta = ca.solve(H + lam * ca.DM.eye(Pm), st["grad_m"])
        ml = exp.model_learner
        rates = ca.vertcat(ca.repmat(split_params(lay, params[:lay.n_params])[5], ml.n_pi, 1),
                           ca.DM.ones(ml.n_tilt) * ml.slope_rate,
                           ca.DM.ones(ml.n_bias) * ml.bias_rate)
        theta_m_next = ca.if_else(stop == 0, theta_m + rates * delta, theta_m)
    outs = [ca.vertcat(theta_next, theta_m_next, st["q"], st["v"]), ca.vertcat(*stats)]
    names = ["state_next", "stats"]
    if full:
        outs.append(rows)
        names.append("rows")
    return ca.Function(name, [state, data, params], [ca.densify(o) for o in outs],
                       ["state", "data", "params"], names)


def _fel_step(kin: Kin, lay, exp, k: int) -> ca.Function:
    """Per step ``(qd, vd, ad, label, A, e) -> (s, g)``: the learned joints' derivative
    columns d through the completion's chain (:meth:`PhysicalWalker.chain`), in motor torques
    when ``learning.error_space: motors`` (:math:`A d`, :math:`A e`): ``s = d^T e`` (3 L) and
    the Gram ``g = d_a^T d_b`` (9 L^2)."""
    nv = kin.nv
    qs, vs, as_ = (ca.SX.sym(s, nv) for s in ("q", "v", "a"))
    ls, Am, e = ca.SX.sym("l"), ca.SX.sym("A", k * nv), ca.SX.sym("e", nv)
    gk = ca.SX.sym("g", 3)  # the known model's gravity
    tau = kin.rnea(qs, vs, as_, gk)
    Gc = kin.chain(qs, ls)
    cols = [i for i, _ in lay.blocks]
    d = [ca.mtimes(ca.jacobian(tau, z), Gc[:, i]) for z in (qs, vs, as_) for i in cols]
    em = e
    if exp.config.learning.error_space == "motors":
        Amat = ca.reshape(Am, k, nv)
        d = [ca.mtimes(Amat, di) for di in d]
        em = ca.mtimes(Amat, e)
    svals = ca.vertcat(*[ca.dot(di, em) for di in d])
    gvals = ca.vertcat(*[ca.dot(da, db) for da in d for db in d])
    return ca.Function("fel_step", [qs, vs, as_, ls, Am, e, gk], [svals, gvals])

