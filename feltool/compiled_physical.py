r"""The physical walker's learning cycle as a CasADi graph (:class:`feltool.walking.PhysicalLoop`
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

import casadi as ca
import numpy as np

from feltool.compiled_graph import (
    controlled_error,
    cycle_stats,
    desired_from_data,
    layout,
    split_params,
    symbolic_reference,
)
from feltool.cycle import feedback, fel_update, wrap
from feltool.dynamics.casadi_backend import (
    symbolic_center_of_mass,
    symbolic_frame_kinematics,
    symbolic_rnea,
)
from feltool.ops import CASADI

#: Bisection steps that locate a touchdown inside a sub-step (h / 2^60: far below 1e-12 s).
BISECTIONS = 60
#: Steps chained per block (the cycle is blocks of blocks: few call sites in the C code).
BLOCK = 40
#: What stopped a cycle (0: nothing).
STOP_CODES = ("", "normal_force", "friction", "clearance", "touchdown", "impulse", "lift_off",
              "torque", "phase", "fall")


def unsupported_physical(exp) -> list[tuple[str, str]]:
    """What of a physical walker the compiled graph does not run."""
    W, cfg = exp.hybrid.walker, exp.config
    out = []
    if W.phase != "mechanical":
        out.append(("walking.phase", f"{W.phase} runs in the Python engine only (the compiled "
                                     "engine runs the mechanical phase)"))
    if W.steps_per_cycle % 2:
        out.append(("walking.steps_per_cycle", "an odd number of steps per cycle runs in the "
                                               "Python engine only"))
    if cfg.learning.impact_window_s > 0:
        out.append(("learning.impact_window_s", "a physical walker's impact window runs in "
                                                "the Python engine only"))
    if exp.law.frames:
        out.append(("joints", "frame-angle targets on a physical walker run in the Python "
                              "engine only"))
    if any(ev.changes_world for ev in cfg.events):
        out.append(("events", "a physical walker's changed world runs in the Python engine "
                              "only"))
    if cfg.learning.update == "gauss_newton" and cfg.learning.error_space != "motors":
        out.append(("learning.error_space", "Gauss-Newton in joint torques on a physical "
                                            "walker runs in the Python engine only"))
    return out


class _Kin:
    """The walker's symbolic kinematics and dynamics (SX functions of one model)."""

    def __init__(self, exp):
        loop = exp.hybrid
        W = loop.walker
        model = W.walker.model
        self.nv = nv = model.nv
        self.W = W
        self.bx, self.bz = int(W.base_v[0]), int(W.base_v[1])
        self.bq0, self.bq1 = int(W.base_q[0]), int(W.base_q[1])
        q, v, a, tau = (ca.SX.sym(s, nv) for s in ("q", "v", "a", "tau"))
        rnea = symbolic_rnea(model)
        self.rnea = rnea
        M = ca.jacobian(rnea(q, v, a), a)
        self.M = ca.Function("M", [q], [ca.substitute(M, ca.vertcat(v, a),
                                                      ca.DM.zeros(2 * nv))])
        self.b = ca.Function("b", [q, v], [rnea(q, v, ca.DM.zeros(nv))])
        self.feet = {}
        for name in (W.stance, W.swing):
            fk = symbolic_frame_kinematics(model, W.walker.feet[name])
            p, J, dp, ddp = fk(q, v, a)
            self.feet[name] = ca.Function(
                f"foot_{name}", [q, v], [p[[0, 2]], J[[0, 2], :], dp[[0, 2]],
                                         ca.substitute(ddp[[0, 2]], a, ca.DM.zeros(nv))])
        com = symbolic_center_of_mass(model)
        c, dc = com(q, v)
        acc = ca.mtimes(ca.jacobian(dc, q), v) + ca.mtimes(ca.jacobian(dc, v), a)
        self.com = ca.Function("com", [q, v, a], [c[0], dc[0], acc[0]])
        Rq, Rv = W.walker.relabel_matrices()
        self.Rq, self.Rv = ca.DM(Rq), ca.DM(Rv)
        self.B = ca.DM(W.B)
        # the stance dynamics (KKT) and the rigid impact, each one linear solve
        Mq, bq = self.M(q), self.b(q, v)
        _, Js, _, gam = self.feet[W.stance](q, v)
        K = ca.blockcat([[Mq, -Js.T], [Js, ca.DM.zeros(2, 2)]])
        sol = ca.solve(K, ca.vertcat(tau - bq, -gam))
        self.stance = ca.Function("stance", [q, v, tau], [sol[:nv], sol[nv:]])
        self.impacts = {}
        for name in (W.stance, W.swing):
            _, Jf, _, _ = self.feet[name](q, v)
            Ki = ca.blockcat([[Mq, -Jf.T], [Jf, ca.DM.zeros(2, 2)]])
            si = ca.solve(Ki, ca.vertcat(ca.mtimes(Mq, v), ca.DM.zeros(2)))
            self.impacts[name] = ca.Function(f"impact_{name}", [q, v], [si[:nv], si[nv:]])
        self.energy = ca.Function("energy", [q, v], [0.5 * ca.dot(v, ca.mtimes(Mq, v))])
        self.rk4 = self._rk4()
        self.hold = {name: self._hold(name) for name in (W.stance, W.swing)}

    def _rk4(self) -> ca.Function:
        """Classical Runge-Kutta with the stance foot held: ``(q, v, tau, h, a1) -> (q1,
        v1)``, ``a1`` the stance acceleration at ``(q, v)`` (its caller has it already)."""
        nv = self.nv
        q, v, tau, a1 = (ca.SX.sym(s, nv) for s in ("q", "v", "tau", "a1"))
        h = ca.SX.sym("h")
        f = lambda qq, vv: self.stance(qq, vv, tau)[0]  # noqa: E731
        q2, v2 = q + 0.5 * h * v, v + 0.5 * h * a1
        a2 = f(q2, v2)
        q3, v3 = q + 0.5 * h * v2, v + 0.5 * h * a2
        a3 = f(q3, v3)
        q4, v4 = q + h * v3, v + h * a3
        a4 = f(q4, v4)
        q1 = q + h / 6.0 * (v + 2 * v2 + 2 * v3 + v4)
        v1 = v + h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
        return ca.Function("rk4", [q, v, tau, h, a1], [q1, v1])

    def _hold(self, foot: str) -> ca.Function:
        """:meth:`feltool.contact.Contact.hold`: two Gauss-Newton steps on the foot's position
        (each only if it is off by 1e-13 m or more) and the inelastic projection of the
        velocity (if the foot moves by 1e-13 m/s or more)."""
        nv = self.nv
        q0, v, anchor = ca.SX.sym("q", nv), ca.SX.sym("v", nv), ca.SX.sym("anchor", 2)
        fk, q = self.feet[foot], q0
        done = ca.SX(0)
        for _ in range(2):
            p, J, _, _ = fk(q, v)
            err = p - anchor
            off = ca.fmax(ca.fabs(err[0]), ca.fabs(err[1])) >= 1e-13
            step = ca.mtimes(J.T, ca.solve(ca.mtimes(J, J.T), err))  # pinv(J) err
            move = ca.logic_and(off, 1 - done)
            q = ca.if_else(move, q - step, q)
            done = ca.logic_or(done, 1 - off)
        _, J, dp, _ = fk(q, v)
        moving = ca.fmax(ca.fabs(dp[0]), ca.fabs(dp[1])) > 1e-13
        v_plus = self.impacts[foot](q, v)[0]
        return ca.Function(f"hold_{foot}", [q0, v, anchor], [q, ca.if_else(moving, v_plus, v)])

    def complete(self, qd, vd, ad):
        """:meth:`feltool.walking.PhysicalWalker.complete` with the anchor at the origin."""
        bq0, bq1, bx, bz = self.bq0, self.bq1, self.bx, self.bz
        fk = self.feet[self.W.stance]
        p = fk(qd, vd)[0]  # exact in one step: the base translates the root along x and z
        qd = ca.vertcat(*[qd[i] - (p[0] if i == bq0 else p[1] if i == bq1 else 0)
                          for i in range(self.nv)])
        vz = _with(vd, {bx: 0, bz: 0})
        _, J, _, _ = fk(qd, vz)
        Jv = ca.mtimes(J, vz)
        vd = _with(vd, {bx: -Jv[0], bz: -Jv[1]})
        az = _with(ad, {bx: 0, bz: 0})
        gam = fk(qd, vd)[3]
        Ja = ca.mtimes(J, az) + gam
        ad = _with(ad, {bx: -Ja[0], bz: -Ja[1]})
        return qd, vd, ad

    def labelled(self, qd, vd, ad, label):
        return (ca.if_else(label, ca.mtimes(self.Rq, qd), qd),
                ca.if_else(label, ca.mtimes(self.Rv, vd), vd),
                ca.if_else(label, ca.mtimes(self.Rv, ad), ad))

    def com_x(self, q, v, a):
        """The centre of mass over the stance foot [m], its rate and acceleration."""
        c, dc, acc = self.com(q, v, a)
        return c - self.feet[self.W.stance](q, v)[0][0], dc, acc

    def allocation(self, q, Mq):
        """:meth:`PhysicalWalker.allocation_matrix`, ``(k, nv)``."""
        Mi = ca.inv(Mq)
        J = self.feet[self.W.stance](q, 0 * q)[1]
        MiJ = ca.mtimes(Mi, J.T)
        Wm = Mi - ca.mtimes(MiJ, ca.solve(ca.mtimes(J, MiJ), MiJ.T))
        BW = ca.mtimes(self.B.T, Wm)
        return ca.solve(ca.mtimes(BW, self.B), BW)

    def chain(self, qd, label):
        """:meth:`PhysicalWalker.chain`: ``(nv, nv)``."""
        nv, bx, bz = self.nv, self.bx, self.bz
        G = ca.if_else(label, self.Rv, ca.DM.eye(nv))
        J = self.feet[self.W.stance](qd, 0 * qd)[1]
        rows = [(-J[0, :] if i == bx else -J[1, :] if i == bz else ca.DM.eye(nv)[i, :])
                for i in range(nv)]
        T = ca.vertcat(*rows)
        keep = ca.DM([0.0 if i in (bx, bz) else 1.0 for i in range(nv)])
        return ca.mtimes(T @ ca.diag(keep), G)


def _stop(code: str):
    return float(STOP_CODES.index(code))


class _Step:
    """The control step of a physical walker (MX, conditional on the cycle still running)."""

    def __init__(self, exp, kin: _Kin):
        self.kin = kin
        loop, W = exp.hybrid, kin.W
        self.nv, self.k = kin.nv, W.B.shape[1]
        self.n, self.spc = exp.primitives.n_steps, W.steps_per_cycle
        self.ns = self.n // self.spc
        self.dt, self.substeps = loop.dt, loop.substeps
        self.refs = sorted(loop.reference)

    def sizes(self) -> dict:
        """The state carried from step to step, in order, with the sizes of its fields."""
        nv, k = self.nv, self.k
        return {"q": nv, "v": nv, "n_imp": 1, "phase_acc": 1, "stop": 1, "done": 1,
                "min_fn": 1, "max_ratio": 1, "min_clear": 1, "max_imp_ratio": 1, "energy": 1,
                "length": 1, "hits": k}

    def substep(self) -> ca.Function:
        """One sub-step without a touchdown's branch: ``(q, v, tau, h, st, a1, F) -> (q1, v1,
        st, landing, anchor, z0)`` with the contact checks (``st``: stop, min_fn, max_ratio,
        min_clear); ``a1, F``: the stance dynamics at ``(q, v, tau)`` (the control step's for
        its first sub-step)."""
        kin, W = self.kin, self.kin.W
        chk = W.checks
        nv = self.nv
        q, v, tau, a1 = (ca.MX.sym(s, nv) for s in ("q", "v", "tau", "a1"))
        h, st, F = ca.MX.sym("h"), ca.MX.sym("st", 4), ca.MX.sym("F", 2)
        stop, min_fn, max_ratio, min_clear = st[0], st[1], st[2], st[3]
        Fx, Fz = F[0], F[1]
        min_fn = ca.fmin(min_fn, Fz)
        bad_fn = ca.logic_or(Fz <= chk.normal_force_min, Fz <= 0.0)
        stop = ca.if_else(ca.logic_and(stop == 0, bad_fn), _stop("normal_force"), stop)
        ratio = ca.fabs(Fx) / Fz
        max_ratio = ca.if_else(bad_fn, max_ratio, ca.fmax(max_ratio, ratio))
        stop = ca.if_else(ca.logic_and(stop == 0, ratio > chk.friction), _stop("friction"), stop)
        anchor = kin.feet[W.stance](q, v)[0]
        z0 = kin.feet[W.swing](q, v)[0][1]
        q1, v1 = kin.rk4(q, v, tau, h, a1)
        q1, v1 = kin.hold[W.stance](q1, v1, anchor)
        sp = kin.feet[W.swing](q1, v1)[0]
        ahead = sp[0] - anchor[0]
        exempt = ca.fabs(ahead) < chk.scuff_exempt
        landing = ca.logic_and(ca.logic_and(1 - exempt, ahead > 0.0),
                               ca.logic_and(z0 > 0.0, sp[1] <= 0.0))
        count = ca.logic_and(1 - landing, 1 - exempt)
        min_clear = ca.if_else(count, ca.fmin(min_clear, sp[1]), min_clear)
        stop = ca.if_else(ca.logic_and(ca.logic_and(stop == 0, count), sp[1] < -chk.clearance_tol),
                          _stop("clearance"), stop)
        return ca.Function("substep", [q, v, tau, h, st, a1, F],
                           [q1, v1, ca.vertcat(stop, min_fn, max_ratio, min_clear), landing,
                            anchor, z0])

    def touchdown(self) -> ca.Function:
        """The touchdown inside a sub-step (MX): ``(q, v, tau, h, anchor, st) -> (qn, vn, st,
        impulse_ratio, energy_lost, length)``; the bisection calls the Runge-Kutta step."""
        kin, W = self.kin, self.kin.W
        chk = W.checks
        nv = self.nv
        q, v, tau = (ca.MX.sym(s, nv) for s in ("q", "v", "tau"))
        h, anchor, st = ca.MX.sym("h"), ca.MX.sym("anchor", 2), ca.MX.sym("st", 4)
        qs_, vs_ = ca.SX.sym("q", nv), ca.SX.sym("v", nv)
        height = ca.Function("height", [qs_, vs_], [kin.feet[W.swing](qs_, vs_)[0][1]])
        lo, hi = ca.MX(0), h
        a1 = kin.stance(q, v, tau)[0]  # every bisection starts from (q, v)
        for _ in range(BISECTIONS):
            mid = 0.5 * (lo + hi)
            qm, vm = kin.rk4(q, v, tau, mid, a1)
            above = height(qm, vm) > 0
            lo, hi = ca.if_else(above, mid, lo), ca.if_else(above, hi, mid)
        s = 0.5 * (lo + hi)
        qs, vs = kin.rk4(q, v, tau, s, a1)
        qs, vs = kin.hold[W.stance](qs, vs, anchor)
        p, _, dp, _ = kin.feet[W.swing](qs, vs)
        stop, min_fn, max_ratio, min_clear = st[0], st[1], st[2], st[3]
        min_clear = ca.fmin(min_clear, ca.fmax(p[1], 0.0))
        stop = ca.if_else(ca.logic_and(stop == 0, dp[1] >= 0.0), _stop("touchdown"), stop)
        v_plus, I = kin.impacts[W.swing](qs, vs)
        lost = kin.energy(qs, vs) - kin.energy(qs, v_plus)
        ratio = ca.if_else(I[1] > 0, ca.fabs(I[0]) / I[1], np.inf)
        length = p[0] - anchor[0]
        trail_vz = kin.feet[W.stance](qs, v_plus)[2][1]
        stop = ca.if_else(ca.logic_and(stop == 0, I[1] <= 0.0), _stop("impulse"), stop)
        stop = ca.if_else(ca.logic_and(stop == 0, ratio > chk.friction), _stop("impulse"), stop)
        stop = ca.if_else(ca.logic_and(stop == 0, trail_vz < -1e-9), _stop("lift_off"), stop)
        qn, vn = ca.mtimes(kin.Rq, qs), ca.mtimes(kin.Rv, v_plus)
        qn, vn = kin.hold[W.stance](qn, vn, ca.vertcat(p[0], 0.0))
        qn = qn - p[0] * ca.DM([1.0 if i == kin.bq0 else 0.0 for i in range(nv)])
        return ca.Function("touchdown", [q, v, tau, h, anchor, st],
                           [qn, vn, ca.vertcat(stop, min_fn, max_ratio, min_clear), ratio, lost,
                            length])


def _interp_index(xc, x):
    """``np.interp(xc, x, arange(len(x)))`` for an increasing grid ``x`` (SX): held at the
    ends, linear in between."""
    ns = x.shape[0]
    lo, hi = x[:ns - 1], x[1:]
    inside = (xc >= lo) * (xc < hi)
    f = ca.sum1(inside * (ca.DM(np.arange(ns - 1)) + (xc - lo) / (hi - lo)))
    return f + (xc >= x[ns - 1]) * (ns - 1)


def _lerp(M, position, n: int):
    """``M`` ``(rows, n)`` at the fractional column ``position`` in [0, n - 1], linear between
    its two neighbouring columns (picked by a symbolic index: O(rows), not O(n))."""
    rows = M.shape[0]
    j = ca.fmin(ca.floor(ca.fmax(position, 0.0)), n - 2)
    w = position - j
    flat, idx = ca.vec(M), j * rows + ca.DM(np.arange(rows))
    return (1 - w) * flat[idx] + w * flat[idx + rows]


class _Control:
    """One control step before its sub-steps (SX): the mechanical phase, the desired and
    reference states, feedback, allocation, the motors' torques and the inertial error."""

    def __init__(self, exp, kin: _Kin, step: _Step):
        self.exp, self.kin, self.st = exp, kin, step

    def consts_size(self) -> int:
        return 6 * self.st.nv * self.st.n + 3 * self.st.n

    def function(self) -> ca.Function:
        exp, kin, stp = self.exp, self.kin, self.st
        W, law, loop = kin.W, exp.law, exp.hybrid
        nv, n, ns, spc, k = stp.nv, stp.n, stp.ns, stp.spc, stp.k
        # MX: the symbolic pieces (kinematics, KKT solves) stay functions of their own in
        # the generated C instead of being inlined at every use
        q, v = ca.MX.sym("q", nv), ca.MX.sym("v", nv)
        phase_acc, n_imp = ca.MX.sym("phase_acc"), ca.MX.sym("n_imp")
        consts = ca.MX.sym("consts", self.consts_size())
        kp, kd, targets = (ca.MX.sym(s, nv) for s in ("kp", "kd", "targets"))
        arrays = [ca.reshape(consts[c * nv * n:(c + 1) * nv * n], nv, n) for c in range(6)]
        P, Pv, Pa, R, Rv, Ra = arrays
        grid = [consts[6 * nv * n + c * n:6 * nv * n + (c + 1) * n] for c in range(3)]
        s_idx = ca.fmod(n_imp, spc)
        label = ca.fmod(n_imp, 2)
        i0 = s_idx * ns
        seg = [ca.MX.zeros(ns) for _ in range(3)]
        for si in range(spc):  # the walk step's grids
            for c in range(3):
                seg[c] = ca.if_else(s_idx == si, grid[c][si * ns:(si + 1) * ns], seg[c])
        x, xv, xa = seg
        xc, xc_rate, _ = kin.com_x(q, v, ca.MX.zeros(nv))
        f = _interp_index(xc, x)
        x_rate = _lerp(xv.T, f, ns)
        rate = ca.if_else(x_rate > 1e-9, xc_rate / x_rate, 1.0)
        xa_f = _lerp(xa.T, f, ns)
        lerp = lambda M: _lerp(M, i0 + f, n)  # noqa: E731
        p, pv, pa = lerp(P), rate * lerp(Pv), rate**2 * lerp(Pa) + phase_acc * lerp(Pv)
        rp, rpv = lerp(R), rate * lerp(Rv)
        rpa = rate**2 * lerp(Ra) + phase_acc * lerp(Rv)
        jj = i0 + ca.floor(f + 0.5)
        qd, vd, ad = kin.complete(*kin.labelled(p, pv, pa, label))
        if stp.refs:
            qr, vr, ar = kin.complete(*kin.labelled(rp, rpv, rpa, label))
        else:
            qr, vr, ar = qd, vd, ad
        r, rd = symbolic_reference(law, qr, vr, targets)
        sym_law = type("Law", (), {"C": ca.DM(law.C), "kp": kp, "kd": kd})
        u_fb, u_rows, u_err = feedback(CASADI, sym_law, q, v, r, rd, loop.error_rows)
        Mq = kin.M(q)
        A = kin.allocation(q, Mq)
        u = ca.mtimes(A, kin.rnea(qd, vd, ad) + u_fb)
        effort = ca.DM(np.where(np.isfinite(W.checks.effort), W.checks.effort, 1e300))
        over = ca.fabs(u) > effort
        if W.checks.torques == "saturate":
            u = ca.fmin(ca.fmax(u, -effort), effort)
        if W.checks.torques == "ignore":
            over = ca.MX.zeros(k)
        tau = ca.mtimes(kin.B, u)
        a_now, F_now = kin.stance(q, v, tau)  # (also the first sub-step's start)
        inert = ca.mtimes(Mq, ar - a_now)
        xc_acc = kin.com_x(q, v, a_now)[2]
        phase_acc_next = ca.if_else(x_rate > 1e-9, (xc_acc - xa_f * rate**2) / x_rate, 0.0)
        # the metric's largest error: forward (not reference) desired against the system
        err = controlled_error(law, symbolic_reference(law, qd, vd, targets)[0], q)
        return ca.Function("control", [q, v, phase_acc, n_imp, consts, kp, kd, targets],
                           [tau, u, over, qd, vd, ad, r, u_fb, u_rows, u_err, ca.vec(A), inert,
                            phase_acc_next, jj, label, err, a_now, F_now])


def row_fields(nv: int) -> list[tuple[str, int]]:
    """A control step's row of the trace: its fields in order, with their sizes."""
    return [("valid", 1), ("q", nv), ("v", nv), ("qd", nv), ("r", nv), ("U", nv),
            ("Urows", nv), ("Uerr", nv), ("err", 1), ("work", 1), ("impact", 1), ("length", 1)]


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
        self.kin = _Kin(exp)
        self.stp = _Step(exp, self.kin)
        self.ctl = _Control(exp, self.kin, self.stp)
        stp = self.stp
        self.nv, self.k, self.n = stp.nv, stp.k, stp.n
        self.n_max = BLOCK * int(np.ceil(3 * self.n / BLOCK))
        self.lay = layout(exp)
        self.sizes = stp.sizes()
        # the FEL sums of eq. 3.6, accumulated step by step (grad; Gauss-Newton: its matrix)
        PL = self.lay.n_learned
        self.gauss_newton = exp.learner.update == "gauss_newton"
        self.sizes.update(grad=PL, hess=PL * PL if self.gauss_newton else 0)
        self.n_state = sum(self.sizes.values())
        self.row_size = sum(sz for _, sz in row_fields(self.nv))

    def step_function(self) -> ca.Function:
        """One control step (MX) ``(S, consts, kp, kd, targets) -> (S', row)``, run only while
        the cycle runs (the state and an empty row otherwise)."""
        stp, W, nv = self.stp, self.kin.W, self.nv
        S = ca.MX.sym("S", self.n_state)
        consts = ca.MX.sym("consts", self.ctl.consts_size())
        kp, kd, targets = (ca.MX.sym(s, nv) for s in ("kp", "kd", "targets"))
        srows = ca.MX.sym("srows", self.srows_size())
        st = unpack(S, self.sizes.items())
        running = ca.logic_and(st["stop"] == 0, st["done"] == 0)
        (tau, u, over, qd, vd, ad, r, U, Urows, Uerr, A, inert, phase_acc_next, jj, label,
         err, a1, F) = self.ctl.function()(st["q"], st["v"], st["phase_acc"], st["n_imp"], consts,
                                    kp, kd, targets)
        hits = st["hits"] + over
        stop = st["stop"]
        if W.checks.torques == "report":
            stop = ca.if_else(ca.logic_and(stop == 0, ca.sum1(over) > 0), _stop("torque"), stop)
        motors = [int(i) for i in W.motor_v]
        work = ca.sum1(ca.fabs(u * st["v"][motors])) * stp.dt
        q, v = st["q"], st["v"]
        checks = ca.vertcat(stop, st["min_fn"], st["max_ratio"], st["min_clear"])
        impact, length, ratio, lost = ca.MX(0), ca.MX(0), ca.MX(-np.inf), ca.MX(0)
        h = stp.dt / stp.substeps
        sub, td = self.stp.substep(), self.stp.touchdown()
        branch_fn = self._touchdown_switch(td)
        for i_sub in range(stp.substeps):
            if i_sub:
                a1, F = self.kin.stance(q, v, tau)
            q1, v1, checks1, landing, anchor, _ = sub(q, v, tau, h, checks, a1, F)
            land = ca.logic_and(landing, impact == 0)
            # the touchdown's branch is evaluated only when landing
            branch = branch_fn(land, q, v, tau, h, anchor, checks, q1, v1, checks1)
            frozen = impact > 0  # after a touchdown the control step ends
            q = ca.if_else(frozen, q, branch[:nv])
            v = ca.if_else(frozen, v, branch[nv:2 * nv])
            checks = ca.if_else(frozen, checks, branch[2 * nv:2 * nv + 4])
            ratio = ca.if_else(land, branch[2 * nv + 4], ratio)
            lost = ca.if_else(land, branch[2 * nv + 5], lost)
            length = ca.if_else(land, branch[2 * nv + 6], length)
            impact = ca.fmax(impact, land)
        n_imp = st["n_imp"] + impact
        stop = checks[0]
        finite = (ca.sum1(ca.fabs(q)) + ca.sum1(ca.fabs(v))) < np.inf
        fell = 1 - finite
        if W.fall_row is not None and np.isfinite(W.fall_max):
            fell = ca.fmax(fell, ca.fabs(ca.dot(ca.DM(W.fall_row), q)) > W.fall_max)
        stop = ca.if_else(ca.logic_and(stop == 0, fell), _stop("fall"), stop)
        new = {"q": q, "v": v, "n_imp": n_imp,
               "phase_acc": ca.if_else(impact, 0.0, phase_acc_next), "stop": stop,
               "done": n_imp >= stp.spc, "min_fn": checks[1], "max_ratio": checks[2],
               "min_clear": checks[3],
               "max_imp_ratio": ca.if_else(impact, ca.fmax(st["max_imp_ratio"], ratio),
                                           st["max_imp_ratio"]),
               "energy": st["energy"] + impact * lost, "length": st["length"] + impact * length,
               "hits": hits}
        new["grad"], new["hess"] = self._fel_sums(st, qd, vd, ad, label, A, Uerr + inert
                                                  if self.inverse_dynamics else Uerr, jj, srows)
        S_new = ca.vertcat(*[new[name] for name in self.sizes])
        row = ca.vertcat(1, st["q"], st["v"], qd, r, U, Urows, Uerr, err, work, impact,
                         impact * length)  # (row_fields)
        args = [S, consts, kp, kd, targets, srows]
        body = ca.Function("phys_body", args, [S_new, row])
        idle = ca.Function("phys_idle", args, [S, ca.DM.zeros(self.row_size)])
        switch = ca.Function.conditional("phys_switch", [idle], body)  # 0: idle, else: run
        S_out, row_out = switch(running, *args)
        return ca.Function("phys_step", args, [S_out, row_out])

    @property
    def inverse_dynamics(self) -> bool:
        return self.exp.config.learning.error_estimate == "inverse_dynamics"

    def srows_size(self) -> int:
        """The learned joints' sensitivity rows, row-major per joint and derivative order."""
        return 3 * self.n * self.lay.n_learned

    def _fel_sums(self, st, qd, vd, ad, label, A, E, jj, srows):
        """The step's terms of eq. 3.6's sums added to the state's: with the sensitivity row
        of the step's sample ``jj`` (:math:`T_l`, 3 x P_l) and the step's derivative columns
        ``s = d^T e``, ``g = d_a^T d_b`` (:func:`_fel_step`): grad_l += T_l^T s_l,
        hess_(l1, l2) += T_l1^T G_(l1, l2) T_l2."""
        blocks, n = self.lay.blocks, self.n
        L = len(blocks)
        if not L:
            return st["grad"], st["hess"]
        s_vals, g_vals = _fel_step(self.kin, self.lay, self.exp, self.k)(qd, vd, ad, label, A, E)
        j = ca.fmin(ca.fmax(jj, 0), n - 1)
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

    def _touchdown_switch(self, td: ca.Function) -> ca.Function:
        """``(land, q, v, tau, h, anchor, checks, q1, v1, checks1) -> branch``: the
        touchdown's state, checks, impulse ratio, energy lost and step length when ``land``,
        else the sub-step's state and checks (only the chosen branch is evaluated)."""
        nv = self.nv
        args = [ca.MX.sym(n, sz) for n, sz in (("q", nv), ("v", nv), ("tau", nv), ("h", 1),
                                               ("anchor", 2), ("checks", 4), ("q1", nv),
                                               ("v1", nv), ("checks1", 4))]
        q, v, tau, h, anchor, checks, q1, v1, checks1 = args
        no = ca.Function("no_touchdown", args, [ca.vertcat(q1, v1, checks1, -np.inf, 0, 0)])
        qn, vn, checks_td, ratio, lost, length = td(q, v, tau, h, anchor, checks1)
        yes = ca.Function("touchdown_branch", args,
                          [ca.vertcat(qn, vn, checks_td, ratio, lost, length)])
        switch = ca.Function.conditional("touchdown_switch", [no], yes)
        land = ca.MX.sym("land")
        return ca.Function("touchdown_or_not", [land, *args], [switch(land, *args)])

    def steps_function(self) -> ca.Function:
        """All the cycle's steps: blocks of :data:`BLOCK` chained steps, chained (few call
        sites; the constants read in place)."""
        one = self.step_function()
        S = ca.MX.sym("S", self.n_state)
        consts = ca.MX.sym("consts", self.ctl.consts_size())
        kp, kd, targets = (ca.MX.sym(s, self.nv) for s in ("kp", "kd", "targets"))
        srows = ca.MX.sym("srows", self.srows_size())
        args = [consts, kp, kd, targets, srows]
        s, rows = S, []
        for _ in range(BLOCK):
            s, row = one(s, *args)
            rows.append(row)
        block = ca.Function("phys_block", [S, *args], [s, ca.horzcat(*rows)])
        s, rows = S, []
        for _ in range(self.n_max // BLOCK):
            s, r = block(s, *args)
            rows.append(r)
        return ca.Function("phys_steps", [S, *args], [s, ca.horzcat(*rows)])


#: The contact metrics of a cycle in the graph's stats, in order (:func:`feltool.seed.
#: contact_metrics`).
CONTACT = ("min_normal_force", "max_friction_ratio", "min_clearance", "max_impulse_ratio",
           "impact_energy_lost", "step_length", "distance", "steps", "duration", "work",
           "stabilized_rms")


def physical_cycle_function(exp, plant=None, full: bool = False,
                            name: str = "phys_cycle") -> ca.Function:
    """The physical walker's cycle ``(state, data, params) -> (state', stats)`` (the arm's
    data with the referenced joints' samples appended); ``stats``: the arm's, then the stop
    code, the steps run, the touchdowns' steps and lengths, and :data:`CONTACT`. With
    ``full``: the rows of every step (:func:`row_fields`)."""
    g = PhysicalGraph(exp)
    lay = g.lay
    kin, stp, W, law, learner = g.kin, g.stp, g.kin.W, exp.law, exp.learner
    nv, n, k, L, PL = g.nv, g.n, g.k, len(lay.blocks), lay.n_learned
    ns, spc = stp.ns, stp.spc
    refs = stp.refs
    state = ca.MX.sym("state", lay.n_state)
    data = ca.MX.sym("data", lay.n_data + 3 * n * len(refs))
    params = ca.MX.sym("params", lay.n_params)
    theta, x0 = state[:PL], state[PL:]
    kp, kd, targets, rates, damping = split_params(lay, params)[:5]
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
    labels = ca.DM([(i // ns) % 2 for i in range(spc * ns)]).T
    G = grid.map(spc * ns, "serial")(R[0][:, :spc * ns], R[1][:, :spc * ns],
                                      R[2][:, :spc * ns], labels)
    phase_bad = ca.MX(0)
    for si in range(spc):
        xs = G[0, si * ns:(si + 1) * ns]
        phase_bad = ca.fmax(phase_bad, ca.mmin(xs[:, 1:] - xs[:, :ns - 1]) <= 0)
    pad = ca.DM.zeros(1, n - spc * ns)
    consts = ca.vertcat(*[ca.vec(M) for M in (P, Pv, Pa, *R)],
                        *[ca.horzcat(G[c, :], pad).T for c in range(3)])
    S0 = ca.vertcat(x0, 0, 0, ca.if_else(phase_bad, _stop("phase"), 0), 0, np.inf, 0, np.inf,
                    -np.inf, 0, 0, ca.DM.zeros(k), ca.DM.zeros(g.sizes["grad"]),
                    ca.DM.zeros(g.sizes["hess"]))
    srows = ca.vertcat(*[ca.vec(sens[l][c].T) for l in range(L) for c in range(3)]) if L \
        else ca.MX.zeros(0)
    S, rows = g.steps_function()(S0, consts, kp, kd, targets, srows)
    st, rw = unpack(S, g.sizes.items()), unpack(rows, row_fields(nv))
    ended = st["n_imp"] >= spc
    stop = ca.if_else(ca.logic_and(st["stop"] == 0, 1 - ended), _stop("touchdown"), st["stop"])
    valid = rw["valid"]
    m = ca.sum2(valid)
    n_max = g.n_max
    # the update (eq. 3.6): the sums accumulated over the steps with the sensitivity rows of
    # the samples nearest the steps' phases
    theta_next = theta
    if L:
        g_ = st["grad"]
        hess = ca.reshape(st["hess"], PL, PL) if g.gauss_newton else None
        step = fel_update(CASADI, theta, g_, hess, rates, learner.is_goal, learner.update,
                          damping)
        theta_next = ca.if_else(stop == 0, step, theta)
    # metrics (feltool.python_engine.cycle_outcome and contact_metrics over the steps run)
    vrow = ca.repmat(valid, nv, 1)
    finite = (ca.sum1(ca.sum2(ca.fabs(rw["q"]) * vrow)) + ca.sum1(ca.fabs(st["q"]))) < np.inf
    hits = ca.MX.zeros(2 * nv)  # the joints' limits are not checked; the motors' torques are
    for j, i in enumerate(W.motor_v):
        hits[nv + int(i)] = st["hits"][j]
    stats = [cycle_stats(law, valid, ca.vertcat(rw["q"], rw["v"]), rw["qd"], rw["U"],
                         rw["Urows"], rw["Uerr"], rw["err"] * valid, hits, finite, valid)]
    stab = np.flatnonzero(law.stabilizing).tolist()
    cum = ca.cumsum(rw["impact"].T).T
    steps_at, lengths = [], []
    for t in range(spc):
        hit = rw["impact"] * (ca.fabs(cum - (t + 1)) < 0.5)
        steps_at.append(ca.sum2(hit * ca.DM(np.arange(1, n_max + 1)).T))
        lengths.append(ca.sum2(hit * rw["length"]))
    C = ca.DM(law.C)
    if not stab and refs:
        err_rows = [(C[i, :] @ rw["q"]) - rw["r"][i, :] for i in refs]
    else:
        err_rows = [(C[i, :] @ rw["q"]) - targets[i] for i in stab]
    sq = sum(ca.sum2(wrap(CASADI, e_) ** 2 * valid) for e_ in err_rows) if err_rows else ca.MX(0)
    stab_rms = ca.sqrt(sq / (m * len(err_rows))) if err_rows else ca.MX(0)
    n_steps = st["n_imp"]
    nan = ca.MX(np.nan)
    contact = [st["min_fn"], st["max_ratio"],
               ca.if_else(st["min_clear"] < np.inf, st["min_clear"], nan),
               ca.if_else(n_steps > 0, st["max_imp_ratio"], nan), st["energy"],
               ca.if_else(n_steps > 0, st["length"] / n_steps, nan), st["length"], n_steps,
               m * stp.dt, ca.sum2(rw["work"]), stab_rms]
    stats += [stop, m, *steps_at, *lengths, *contact]
    outs = [ca.vertcat(theta_next, st["q"], st["v"]), ca.vertcat(*stats)]
    names = ["state_next", "stats"]
    if full:
        outs.append(rows)
        names.append("rows")
    return ca.Function(name, [state, data, params], [ca.densify(o) for o in outs],
                       ["state", "data", "params"], names)


def _fel_step(kin: _Kin, lay, exp, k: int) -> ca.Function:
    """Per step ``(qd, vd, ad, label, A, e) -> (s, g)``: the learned joints' derivative
    columns d through the completion's chain (:meth:`PhysicalWalker.chain`), in motor torques
    when ``learning.error_space: motors`` (:math:`A d`, :math:`A e`): ``s = d^T e`` (3 L) and
    the Gram ``g = d_a^T d_b`` (9 L^2)."""
    nv = kin.nv
    qs, vs, as_ = (ca.SX.sym(s, nv) for s in ("q", "v", "a"))
    ls, Am, e = ca.SX.sym("l"), ca.SX.sym("A", k * nv), ca.SX.sym("e", nv)
    tau = kin.rnea(qs, vs, as_)
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
    return ca.Function("fel_step", [qs, vs, as_, ls, Am, e], [svals, gvals])


def _with(x, values: dict):
    """``x`` with the entries ``values`` set."""
    return ca.vertcat(*[values[i] if i in values else x[i] for i in range(x.shape[0])])


__all__ = ["BISECTIONS", "CONTACT", "STOP_CODES", "PhysicalGraph", "physical_cycle_function",
           "unsupported_physical"]
