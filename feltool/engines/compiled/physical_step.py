"""The physical walker's control step as CasADi expressions: kinematics of the feet, the
stance solve, the sub-step with touchdown by bisection and the rigid impact, the controller.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from feltool.control.cycle import feedback
from feltool.control.ops import CASADI
from feltool.dynamics.symbolic import (
    symbolic_center_of_mass,
    symbolic_frame_kinematics,
    symbolic_rnea_gravity,
    symbolic_rnea_world,
)
from feltool.engines.compiled.graph import (
    controlled_error,
    symbolic_reference,
)
from feltool.walking.walker import same_kinematics

#: Bisection steps that locate a touchdown inside a sub-step (h / 2^60: far below 1e-12 s).
BISECTIONS = 60


#: The ``design`` input of a physical walker's step: the cycle's samples n and samples per
#: walk step ns, and the known model's linear gravity (3) [m/s^2].
DESIGN = 5

#: A walk step's duration the graph holds at least, in [s] (:func:`capacity`).
STEP_CAPACITY_S = 1.0


def capacity(exp) -> int:
    """The samples per cycle a physical walker's graph holds: per walk step the samples of
    :data:`STEP_CAPACITY_S` at the control rate, doubled until the experiment's own fit, times
    the steps per cycle. It depends on the rate and the steps per cycle only (not on the
    design's period): every design of a walker whose steps last up to a second shares one
    build."""
    spc = exp.hybrid.walker.steps_per_cycle
    ns = exp.primitives.n_steps // spc
    cap = int(np.ceil(STEP_CAPACITY_S / exp.hybrid.dt - 1e-9))
    while cap < ns:
        cap *= 2
    return spc * cap


#: What stopped a cycle (0: nothing).
STOP_CODES = ("", "normal_force", "friction", "clearance", "touchdown", "impulse", "lift_off",
              "torque", "phase", "fall")


def world_size(model) -> int:
    """The size of a world vector (:func:`world_vector`) of ``model``'s joints."""
    return 10 * (model.njoints - 1) + 3 + 4 * model.nv


def world_vector(plant) -> np.ndarray:
    """The simulated world as the compiled walker's input: the plant's inertial parameters (10
    per body, Pinocchio's order), its linear gravity (3) [m/s^2], and per joint its viscous
    damping [N m s/rad], Coulomb level [N m], Coulomb velocity [rad/s] and motor gain [-]
    (:class:`feltool.plant.rigid.FrictionPlant`; none and 1 for a rigid plant)."""
    rigid = getattr(plant, "rigid", plant)
    m = rigid.model
    pi = [m.inertias[j].toDynamicParameters() for j in range(1, m.njoints)]
    if rigid is plant:
        extra = [np.zeros(m.nv), np.zeros(m.nv), np.ones(m.nv), np.ones(m.nv)]
    else:
        extra = [np.asarray(x, float) for x in (plant.viscous, plant.coulomb,
                                                 plant.coulomb_velocity, plant.motor_gain)]
    return np.concatenate(pi + [np.asarray(m.gravity.linear, float)] + extra)


class Kin:
    """The walker's symbolic kinematics and dynamics (SX functions): the known model's
    (feedforward, allocation, mechanical phase, feet) and the simulated plant's, whose inertial
    parameters, gravity and friction are the input ``w`` (:func:`world_vector`) and whose
    kinematics (joint and foot placements) are the plant's model's: its stance dynamics,
    impacts, energy, Runge-Kutta step, the stance foot's hold and the feet's contact checks
    (``pfeet``)."""

    def __init__(self, exp):
        loop = exp.hybrid
        W = loop.walker
        model = W.walker.model
        self.nv = nv = model.nv
        self.W = W
        self.bx, self.bz = int(W.base_v[0]), int(W.base_v[1])
        self.bq0, self.bq1 = int(W.base_q[0]), int(W.base_q[1])
        q, v, a, tau = (ca.SX.sym(s, nv) for s in ("q", "v", "a", "tau"))
        g_known = ca.SX.sym("g_known", 3)
        # the known model's gravity is an input (a slope is a design's, not the graph's)
        rnea = symbolic_rnea_gravity(model)
        self.rnea = rnea
        M = ca.jacobian(rnea(q, v, a, g_known), a)
        self.M = ca.Function("M", [q], [ca.substitute(M, ca.vertcat(v, a, g_known),
                                                      ca.DM.zeros(2 * nv + 3))])
        # the model correction's regressor (learning.model): Y = d RNEA / d pi, its columns
        learner = exp.model_learner
        # (with a learned ground slope its column last: RNEA(q, 0, 0) with gravity along the
        # ground's tangent, feltool.learning.walker_model.tilt_direction)
        self.n_pi = learner.n_features if getattr(learner, "walker", False) else 0
        if self.n_pi:
            pi_s = ca.SX.sym("pi", 10 * (model.njoints - 1))
            Y = ca.jacobian(symbolic_rnea_world(model)(q, v, a, pi_s, g_known), pi_s)
            Y = ca.substitute(Y, pi_s, ca.DM.zeros(pi_s.shape[0]))[:, list(learner.columns)]
            if learner.n_tilt:
                tangent = ca.vertcat(-g_known[2], 0.0, g_known[0])
                Y = ca.horzcat(Y, rnea(q, ca.DM.zeros(nv), ca.DM.zeros(nv), tangent))
            self.regressor = ca.Function("regressor", [q, v, a, g_known], [ca.densify(Y)])
        # the plant: RNEA of the world's parameters
        self.n_world = world_size(model)
        w = ca.SX.sym("w", self.n_world)
        npi = 10 * (model.njoints - 1)
        pi, g = w[:npi], w[npi:npi + 3]
        visc, coul, vc, gain = (w[npi + 3 + c * nv:npi + 3 + (c + 1) * nv] for c in range(4))
        # the plant's kinematics (its joints' and feet's placements: a plant whose bodies are
        # longer, plant.bodies.*.length_scale; else the model's); its inertias come with w
        plant = exp.plant if exp.plant is not None else exp.dynamics
        pmodel = getattr(getattr(plant, "rigid", plant), "model", model)
        if same_kinematics(pmodel, model):
            pmodel = model
        rnea_w = symbolic_rnea_world(pmodel)
        Mw = ca.jacobian(rnea_w(q, v, a, pi, g), a)
        Mq = ca.substitute(Mw, ca.vertcat(v, a), ca.DM.zeros(2 * nv))
        bq = rnea_w(q, v, ca.DM.zeros(nv), pi, g)
        applied = gain * tau - (visc * v + coul * ca.tanh(v / vc))
        self.feet = {}
        for name in (W.stance, W.swing):
            fk = symbolic_frame_kinematics(model, W.walker.feet[name])
            p, J, dp, ddp = fk(q, v, a)
            self.feet[name] = ca.Function(
                f"foot_{name}", [q, v], [p[[0, 2]], J[[0, 2], :], dp[[0, 2]],
                                         ca.substitute(ddp[[0, 2]], a, ca.DM.zeros(nv))])
        #: the plant's feet (the known model's ``feet`` when its kinematics are the model's)
        self.pfeet = self.feet
        if pmodel is not model:
            self.pfeet = {}
            for name in (W.stance, W.swing):
                fk = symbolic_frame_kinematics(pmodel, W.walker.feet[name])
                p, J, dp, ddp = fk(q, v, a)
                self.pfeet[name] = ca.Function(
                    f"plant_foot_{name}", [q, v], [p[[0, 2]], J[[0, 2], :], dp[[0, 2]],
                                                   ca.substitute(ddp[[0, 2]], a,
                                                                 ca.DM.zeros(nv))])
        com = symbolic_center_of_mass(model)
        c, dc = com(q, v)
        acc = ca.mtimes(ca.jacobian(dc, q), v) + ca.mtimes(ca.jacobian(dc, v), a)
        self.com = ca.Function("com", [q, v, a], [c[0], dc[0], acc[0]])
        Rq, Rv = W.walker.relabel_matrices()
        self.Rq, self.Rv = ca.DM(Rq), ca.DM(Rv)
        self.B = ca.DM(W.B)
        # the plant's stance dynamics (KKT) and rigid impact, each one linear solve
        _, Js, _, gam = self.pfeet[W.stance](q, v)
        K = ca.blockcat([[Mq, -Js.T], [Js, ca.DM.zeros(2, 2)]])
        sol = ca.solve(K, ca.vertcat(applied - bq, -gam))
        self.stance = ca.Function("stance", [q, v, tau, w], [sol[:nv], sol[nv:]])
        self.impacts = {}
        for name in (W.stance, W.swing):
            _, Jf, _, _ = self.pfeet[name](q, v)
            Ki = ca.blockcat([[Mq, -Jf.T], [Jf, ca.DM.zeros(2, 2)]])
            si = ca.solve(Ki, ca.vertcat(ca.mtimes(Mq, v), ca.DM.zeros(2)))
            self.impacts[name] = ca.Function(f"impact_{name}", [q, v, w], [si[:nv], si[nv:]])
        self.energy = ca.Function("energy", [q, v, w], [0.5 * ca.dot(v, ca.mtimes(Mq, v))])
        self.rk4 = self._rk4()
        self.hold = {name: self._hold(name) for name in (W.stance, W.swing)}

    def _rk4(self) -> ca.Function:
        """Classical Runge-Kutta with the stance foot held: ``(q, v, tau, h, a1) -> (q1,
        v1)``, ``a1`` the stance acceleration at ``(q, v)`` (its caller has it already)."""
        nv = self.nv
        q, v, tau, a1 = (ca.SX.sym(s, nv) for s in ("q", "v", "tau", "a1"))
        h, w = ca.SX.sym("h"), ca.SX.sym("w", self.n_world)
        f = lambda qq, vv: self.stance(qq, vv, tau, w)[0]  # noqa: E731
        q2, v2 = q + 0.5 * h * v, v + 0.5 * h * a1
        a2 = f(q2, v2)
        q3, v3 = q + 0.5 * h * v2, v + 0.5 * h * a2
        a3 = f(q3, v3)
        q4, v4 = q + h * v3, v + h * a3
        a4 = f(q4, v4)
        q1 = q + h / 6.0 * (v + 2 * v2 + 2 * v3 + v4)
        v1 = v + h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
        return ca.Function("rk4", [q, v, tau, h, a1, w], [q1, v1])

    def _hold(self, foot: str) -> ca.Function:
        """:meth:`feltool.walking.contact.Contact.hold`: two Gauss-Newton steps on the foot's position
        (each only if it is off by 1e-13 m or more) and the inelastic projection of the
        velocity (if the foot moves by 1e-13 m/s or more)."""
        nv = self.nv
        q0, v, anchor = ca.SX.sym("q", nv), ca.SX.sym("v", nv), ca.SX.sym("anchor", 2)
        w = ca.SX.sym("w", self.n_world)
        fk, q = self.pfeet[foot], q0
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
        v_plus = self.impacts[foot](q, v, w)[0]
        return ca.Function(f"hold_{foot}", [q0, v, anchor, w],
                           [q, ca.if_else(moving, v_plus, v)])

    def complete(self, qd, vd, ad):
        """:meth:`feltool.walking.physical.PhysicalWalker.complete` with the anchor at the origin."""
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


def stop_code(code: str):
    return float(STOP_CODES.index(code))


class Step:
    """The control step of a physical walker (MX, conditional on the cycle still running).

    ``n`` is the graph's capacity in samples per cycle (:func:`capacity`), ``ns`` per walk
    step; a cycle's own numbers of samples are inputs (the ``design`` input of
    :class:`Control`), so one build serves every design of the walker."""

    def __init__(self, exp, kin: Kin):
        self.kin = kin
        loop, W = exp.hybrid, kin.W
        self.nv, self.k = kin.nv, W.B.shape[1]
        self.spc = W.steps_per_cycle
        self.n = capacity(exp)
        self.ns = self.n // self.spc
        self.dt, self.substeps = loop.dt, loop.substeps
        self.refs = sorted(loop.reference)

    def sizes(self) -> dict:
        """The state carried from step to step, in order, with the sizes of its fields."""
        nv, k = self.nv, self.k
        return {"q": nv, "v": nv, "n_imp": 1, "phase_acc": 1, "stop": 1, "done": 1,
                "min_fn": 1, "max_ratio": 1, "min_clear": 1, "max_imp_ratio": 1, "energy": 1,
                "length": 1, "time": 1, "hits": k}

    def substep(self) -> ca.Function:
        """One sub-step without a touchdown's branch: ``(q, v, tau, h, st, a1, F, w) -> (q1,
        v1, st, landing, anchor, z0)`` with the contact checks (``st``: stop, min_fn, max_ratio,
        min_clear); ``a1, F``: the stance dynamics at ``(q, v, tau)`` (the control step's for
        its first sub-step)."""
        kin, W = self.kin, self.kin.W
        chk = W.checks
        nv = self.nv
        q, v, tau, a1 = (ca.MX.sym(s, nv) for s in ("q", "v", "tau", "a1"))
        h, st, F = ca.MX.sym("h"), ca.MX.sym("st", 4), ca.MX.sym("F", 2)
        w = ca.MX.sym("w", kin.n_world)
        stop, min_fn, max_ratio, min_clear = st[0], st[1], st[2], st[3]
        Fx, Fz = F[0], F[1]
        min_fn = ca.fmin(min_fn, Fz)
        bad_fn = ca.logic_or(Fz <= chk.normal_force_min, Fz <= 0.0)
        stop = ca.if_else(ca.logic_and(stop == 0, bad_fn), stop_code("normal_force"), stop)
        ratio = ca.fabs(Fx) / Fz
        max_ratio = ca.if_else(bad_fn, max_ratio, ca.fmax(max_ratio, ratio))
        stop = ca.if_else(ca.logic_and(stop == 0, ratio > chk.friction), stop_code("friction"), stop)
        anchor = kin.pfeet[W.stance](q, v)[0]
        z0 = kin.pfeet[W.swing](q, v)[0][1]
        q1, v1 = kin.rk4(q, v, tau, h, a1, w)
        q1, v1 = kin.hold[W.stance](q1, v1, anchor, w)
        sp = kin.pfeet[W.swing](q1, v1)[0]
        ahead = sp[0] - anchor[0]
        exempt = ca.fabs(ahead) < chk.scuff_exempt
        if chk.scuff_behind:  # the compass-gait convention: no stop behind the stance foot
            exempt = ca.logic_or(exempt, ahead <= 0.0)
        landing = ca.logic_and(ca.logic_and(1 - exempt, ahead > 0.0),
                               ca.logic_and(z0 > 0.0, sp[1] <= 0.0))
        count = ca.logic_and(1 - landing, 1 - exempt)
        min_clear = ca.if_else(count, ca.fmin(min_clear, sp[1]), min_clear)
        stop = ca.if_else(ca.logic_and(ca.logic_and(stop == 0, count), sp[1] < -chk.clearance_tol),
                          stop_code("clearance"), stop)
        return ca.Function("substep", [q, v, tau, h, st, a1, F, w],
                           [q1, v1, ca.vertcat(stop, min_fn, max_ratio, min_clear), landing,
                            anchor, z0])

    def touchdown(self) -> ca.Function:
        """The touchdown inside a sub-step (MX): ``(q, v, tau, h, anchor, st, w) -> (qn, vn, st,
        impulse_ratio, energy_lost, length, s)``, ``s`` the touchdown's time in the sub-step in
        [s]; the bisection calls the Runge-Kutta step."""
        kin, W = self.kin, self.kin.W
        chk = W.checks
        nv = self.nv
        q, v, tau = (ca.MX.sym(s, nv) for s in ("q", "v", "tau"))
        h, anchor, st = ca.MX.sym("h"), ca.MX.sym("anchor", 2), ca.MX.sym("st", 4)
        w = ca.MX.sym("w", kin.n_world)
        qs_, vs_ = ca.SX.sym("q", nv), ca.SX.sym("v", nv)
        height = ca.Function("height", [qs_, vs_], [kin.pfeet[W.swing](qs_, vs_)[0][1]])
        lo, hi = ca.MX(0), h
        a1 = kin.stance(q, v, tau, w)[0]  # every bisection starts from (q, v)
        for _ in range(BISECTIONS):
            mid = 0.5 * (lo + hi)
            qm, vm = kin.rk4(q, v, tau, mid, a1, w)
            above = height(qm, vm) > 0
            lo, hi = ca.if_else(above, mid, lo), ca.if_else(above, hi, mid)
        s = 0.5 * (lo + hi)
        qs, vs = kin.rk4(q, v, tau, s, a1, w)
        qs, vs = kin.hold[W.stance](qs, vs, anchor, w)
        p, _, dp, _ = kin.pfeet[W.swing](qs, vs)
        stop, min_fn, max_ratio, min_clear = st[0], st[1], st[2], st[3]
        min_clear = ca.fmin(min_clear, ca.fmax(p[1], 0.0))
        stop = ca.if_else(ca.logic_and(stop == 0, dp[1] >= 0.0), stop_code("touchdown"), stop)
        v_plus, I = kin.impacts[W.swing](qs, vs, w)
        lost = kin.energy(qs, vs, w) - kin.energy(qs, v_plus, w)
        ratio = ca.if_else(I[1] > 0, ca.fabs(I[0]) / I[1], np.inf)
        length = p[0] - anchor[0]
        trail_vz = kin.pfeet[W.stance](qs, v_plus)[2][1]
        stop = ca.if_else(ca.logic_and(stop == 0, I[1] <= 0.0), stop_code("impulse"), stop)
        stop = ca.if_else(ca.logic_and(stop == 0, ratio > chk.friction), stop_code("impulse"), stop)
        stop = ca.if_else(ca.logic_and(stop == 0, trail_vz < -1e-9), stop_code("lift_off"), stop)
        qn, vn = ca.mtimes(kin.Rq, qs), ca.mtimes(kin.Rv, v_plus)
        qn, vn = kin.hold[W.stance](qn, vn, ca.vertcat(p[0], 0.0), w)
        qn = qn - p[0] * ca.DM([1.0 if i == kin.bq0 else 0.0 for i in range(nv)])
        return ca.Function("touchdown", [q, v, tau, h, anchor, st, w],
                           [qn, vn, ca.vertcat(stop, min_fn, max_ratio, min_clear), ratio, lost,
                            length, s])


def _interp_index(xc, x, ns):
    """``np.interp(xc, x[:ns], arange(ns))`` for a grid ``x`` increasing in its first ``ns``
    entries (``ns`` symbolic; the entries after them are not read): held at the ends, linear
    in between."""
    cap = x.shape[0]
    lo, hi = x[:cap - 1], x[1:]
    j = ca.DM(np.arange(cap - 1))
    inside = ca.logic_and(ca.logic_and(xc >= lo, xc < hi), j < ns - 1)
    f = ca.sum1(ca.if_else(inside, j + (xc - lo) / (hi - lo), 0.0))
    last = x[ca.fmin(ca.fmax(ns - 1, 0), cap - 1)]
    return f + (xc >= last) * (ns - 1)


def _lerp(M, position, n: int):
    """``M`` ``(rows, n)`` at the fractional column ``position`` in [0, n - 1], linear between
    its two neighbouring columns (picked by a symbolic index: O(rows), not O(n))."""
    rows = M.shape[0]
    j = ca.fmin(ca.floor(ca.fmax(position, 0.0)), n - 2)
    w = position - j
    flat, idx = ca.vec(M), j * rows + ca.DM(np.arange(rows))
    return (1 - w) * flat[idx] + w * flat[idx + rows]


class Control:
    """One control step before its sub-steps (SX): the mechanical phase, the desired and
    reference states, feedback, allocation, the motors' torques and the inertial error."""

    def __init__(self, exp, kin: Kin, step: Step):
        self.exp, self.kin, self.st = exp, kin, step

    def consts_size(self) -> int:
        return 6 * self.st.nv * self.st.n + 3 * self.st.n

    def n_model(self) -> int:
        """The physical walker's model correction and motor biases (``learning.model``)."""
        learner = self.exp.model_learner
        return learner.n_params if getattr(learner, "walker", False) else 0

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
        w = ca.MX.sym("w", kin.n_world)
        theta_m = ca.MX.sym("theta_m", self.n_model())
        design = ca.MX.sym("design", DESIGN)
        n_in, ns_in, g_known = design[0], design[1], design[2:5]
        arrays = [ca.reshape(consts[c * nv * n:(c + 1) * nv * n], nv, n) for c in range(6)]
        P, Pv, Pa, R, Rv, Ra = arrays
        grid = [consts[6 * nv * n + c * n:6 * nv * n + (c + 1) * n] for c in range(3)]
        s_idx = ca.fmod(n_imp, spc)
        label = ca.fmod(n_imp, 2)
        i0 = s_idx * ns_in
        pick = ca.fmin(i0 + ca.DM(np.arange(ns)), n - 1)  # the walk step's grids
        x, xv, xa = (grid[c][pick] for c in range(3))
        xc, xc_rate, _ = kin.com_x(q, v, ca.MX.zeros(nv))
        f = _interp_index(xc, x, ns_in)
        x_rate = _lerp(xv.T, f, ns_in)
        rate = ca.if_else(x_rate > 1e-9, xc_rate / x_rate, 1.0)
        xa_f = _lerp(xa.T, f, ns_in)
        lerp = lambda M: _lerp(M, i0 + f, n_in)  # noqa: E731
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
        tau_w = kin.rnea(qd, vd, ad, g_known) + u_fb
        if kin.n_pi:  # the learned model correction Y theta_pi (feltool.learning.walker_model)
            tau_w = tau_w + ca.mtimes(kin.regressor(qd, vd, ad, g_known), theta_m[:kin.n_pi])
        u = ca.mtimes(A, tau_w)
        if self.n_model() > kin.n_pi:  # the learned motor biases
            u = u + theta_m[kin.n_pi:]
        effort = ca.DM(np.where(np.isfinite(W.checks.effort), W.checks.effort, 1e300))
        over = ca.fabs(u) > effort
        if W.checks.torques == "saturate":
            u = ca.fmin(ca.fmax(u, -effort), effort)
        if W.checks.torques == "ignore":
            over = ca.MX.zeros(k)
        tau = ca.mtimes(kin.B, u)
        a_now, F_now = kin.stance(q, v, tau, w)  # the plant's (also the first sub-step's start)
        inert = ca.mtimes(Mq, ar - a_now)
        xc_acc = kin.com_x(q, v, a_now)[2]
        phase_acc_next = ca.if_else(x_rate > 1e-9, (xc_acc - xa_f * rate**2) / x_rate, 0.0)
        # the metric's largest error: forward (not reference) desired against the system
        err = controlled_error(law, symbolic_reference(law, qd, vd, targets)[0], q)
        return ca.Function("control", [q, v, phase_acc, n_imp, consts, kp, kd, targets, w,
                                       theta_m, design],
                           [tau, u, over, qd, vd, ad, r, u_fb, u_rows, u_err, ca.vec(A), inert,
                            phase_acc_next, jj, label, err, a_now, F_now])


def _with(x, values: dict):
    """``x`` with the entries ``values`` set."""
    return ca.vertcat(*[values[i] if i in values else x[i] for i in range(x.shape[0])])
