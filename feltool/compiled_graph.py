r"""The learning cycle of a continuous robot (an arm) as a CasADi graph.

One cycle, ``(state, data, params) -> (state', stats)``, built from the pieces of
:mod:`feltool.cycle` traced with :data:`feltool.ops.CASADI`:

1. the desired trajectory :math:`q_d, \dot q_d, \ddot q_d = O + \sum_l e_{i_l} X_l\theta_l`
   (``data``: each learned joint's sensitivity rows :math:`X_l` at the cycle's steps, as they
   are and transposed, and the other joints' motion :math:`O`);
2. the feedforward :math:`u_{ff} = \mathrm{RNEA}(q_d, \dot q_d, \ddot q_d)` and the learned
   joints' columns of its derivatives, ``map``-ped over the samples;
3. the closed loop, ``mapaccum``-ed over the steps: :func:`feltool.cycle.feedback`,
   :math:`u = S(u_{ff} + u_{fb})`, :func:`feltool.cycle.advance` through the plant's symbolic
   ABA (friction included), joint and torque limits;
4. the FEL sums (:func:`feltool.cycle.fel_sums`, per-sample vectors, no Jacobian) and the
   update (:func:`feltool.cycle.fel_update`), applied only if the cycle stayed finite;
5. the metrics of :func:`feltool.seed` (phase-weighted means, largest errors, limit hits).

``state`` is the learned parameters and :math:`x_0`; ``params`` the gains, targets and rates,
so one compiled library serves a sweep over them. ``many`` maps the cycle over
:data:`~feltool.compiled.CYCLES_PER_CALL` cycles with their updates.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import casadi as ca
import numpy as np

from feltool.cycle import advance, feedback, fel_sums, fel_update, wrap
from feltool.dynamics.casadi_backend import (
    symbolic_aba,
    symbolic_frame_rotation,
    symbolic_rnea,
)
from feltool.ops import CASADI

#: Per-cycle statistics, in order: fb_abs_mean (nv), track_err_rms (nv), then these scalars,
#: then joint-limit hits (nv) and torque-limit hits (nv).
SCALARS = ("max_error", "max_speed", "fb_stabilized", "fb_error", "finite")


@dataclass(frozen=True)
class Layout:
    """Sizes of the graph's inputs.

    Attributes:
        nv: Joints.
        n: Steps of the cycle.
        blocks: Per learned joint ``(velocity index, number of parameters)``.
    """

    nv: int
    n: int
    blocks: tuple[tuple[int, int], ...]

    @property
    def n_learned(self) -> int:
        return sum(p for _, p in self.blocks)

    @property
    def n_state(self) -> int:
        return self.n_learned + 2 * self.nv

    @property
    def n_data(self) -> int:
        return 6 * self.n * self.n_learned + 3 * self.nv * self.n + self.n

    @property
    def n_params(self) -> int:
        return 3 * self.nv + self.n_learned + 1

    @property
    def n_stats(self) -> int:
        return 4 * self.nv + len(SCALARS)


def layout(exp) -> Layout:
    return Layout(exp.robot.model.nv, exp.primitives.n_steps,
                  tuple((i, len(cols)) for i, cols, _, _ in exp.learner._blocks))


def symbolic_forward(plant):
    """``(q, v, tau) -> a`` of a plant (:class:`~feltool.dynamics.Dynamics`): its model's
    symbolic ABA, with the joint friction of a :class:`~feltool.plant.FrictionPlant`."""
    rigid = getattr(plant, "rigid", plant)
    aba = symbolic_aba(rigid.model)
    if rigid is plant:
        return lambda q, v, tau: aba(q, v, tau)
    d, c, vc = (ca.DM(x) for x in (plant.viscous, plant.coulomb, plant.coulomb_velocity))
    return lambda q, v, tau: aba(q, v, tau - (d * v + c * ca.tanh(v / vc)))


def symbolic_frames(law, model) -> dict:
    """``{row: q -> (y, j_y)}`` of the law's frame angles (:class:`feltool.control.FrameAngle`),
    symbolically: :math:`y = \\operatorname{atan2}((z_0\\times v)\\cdot a, z_0\\cdot v)`,
    :math:`v = R(q) v_f`, and its gradient by CasADi."""
    out = {}
    for row, f in law.frames.items():
        rot = symbolic_frame_rotation(model, f.frame_id)
        q = ca.SX.sym("q", model.nq)
        vec = ca.mtimes(rot(q), ca.DM(f.vector))
        y = ca.atan2(ca.dot(ca.DM(f.ortho), vec), ca.dot(ca.DM(f.zero), vec))
        out[row] = ca.Function(f"frame_angle_{row}", [q], [y, ca.jacobian(y, q).T])
    return out


def _symbolic_limits(limits):
    if limits is None:
        return None
    return SimpleNamespace(lower=ca.DM(limits.lower), upper=ca.DM(limits.upper),
                           effort=ca.DM(limits.effort), joints=limits.joints,
                           torques=limits.torques)


def step_function(exp, plant) -> ca.Function:
    """One control step ``(x, u_ff, r, rd, kp, kd) -> (x', u_fb, u_rows, u_err, err, hits)``
    (SX): the feedback laws, the actuated torque and the plant's step; ``err`` the largest
    |reference - controlled quantity| [rad], ``hits`` the joint- and torque-limit indicators
    at the step's start."""
    model, law, loop = exp.robot.model, exp.law, exp.loop
    nv = model.nv
    x, uff, r, rd = (ca.SX.sym(s, nv if s != "x" else 2 * nv) for s in ("x", "uff", "r", "rd"))
    kp, kd = ca.SX.sym("kp", nv), ca.SX.sym("kd", nv)
    q, v = x[:nv], x[nv:]
    frames = symbolic_frames(law, model)
    sym_law = SimpleNamespace(C=ca.DM(law.C), kp=kp, kd=kd)
    u_fb, u_rows, u_err = feedback(CASADI, sym_law, q, v, r, rd, loop.error_rows, frames)
    tau = ca.DM(loop.actuated) * (uff + u_fb)
    limits = _symbolic_limits(loop.limits)
    q1, v1 = advance(CASADI, symbolic_forward(plant), q, v, tau, loop.dt / loop.substeps,
                     loop.substeps, loop.integrator == "semi_implicit_euler", limits)
    y = ca.mtimes(ca.DM(law.C), q)
    for row, kin in frames.items():
        y[row] = kin(q)[0]
    controlled = np.flatnonzero(law.tracking | law.stabilizing).tolist()
    err = ca.mmax(ca.fabs(wrap(CASADI, r - y)[controlled])) if controlled else ca.SX(0)
    hit_q, hit_t = ca.SX.zeros(nv), ca.SX.zeros(nv)
    lim = loop.limits
    if lim is not None:
        if lim.joints == "enforce":
            hit_q = ca.fmax(q <= limits.lower + 1e-12, q >= limits.upper - 1e-12)
        elif lim.joints == "report":
            hit_q = ca.fmax(q < limits.lower, q > limits.upper)
        if lim.torques != "ignore":
            hit_t = ca.fabs(tau) > limits.effort * (1 + 1e-12)
    return ca.Function("step", [x, uff, r, rd, kp, kd],
                       [ca.vertcat(q1, v1), u_fb, u_rows, u_err, err, ca.vertcat(hit_q, hit_t)])


def feedforward_function(exp, lay: Layout) -> ca.Function:
    """``(q_d, v_d, a_d) -> (u_ff, D)`` (SX): RNEA and, for each learned joint l, the columns
    :math:`i_l` of :math:`\\partial\\tau/\\partial q`, :math:`\\partial\\tau/\\partial\\dot q`
    and M, as ``D`` ``(nv, 3 L)`` ordered (q of every l, then v, then a)."""
    model = exp.robot.model
    nv = model.nv
    q, v, a = (ca.SX.sym(s, nv) for s in ("q", "v", "a"))
    tau = symbolic_rnea(model)(q, v, a)
    cols = [i for i, _ in lay.blocks]
    D = [ca.jacobian(tau, z[i]) for z in (q, v, a) for i in cols]
    return ca.Function("ff", [q, v, a], [tau, ca.horzcat(*D) if D else ca.SX(nv, 0)])


def cycle_function(exp, plant, full: bool = False, name: str = "cycle") -> ca.Function:
    """The whole cycle ``(state, data, params) -> (state', stats)``; with ``full`` also the
    trace ``X`` (2 nv x n, the states at each step's start), ``U`` (nv x n, feedback),
    ``Urows``, ``Uerr`` and ``Qd`` (nv x n). See the module docstring."""
    lay = layout(exp)
    nv, n, L = lay.nv, lay.n, len(lay.blocks)
    law, learner = exp.law, exp.learner
    state = ca.MX.sym("state", lay.n_state)
    data = ca.MX.sym("data", lay.n_data)
    params = ca.MX.sym("params", lay.n_params)
    PL = lay.n_learned
    theta, x0 = state[:PL], state[PL:]
    kp, kd, targets = params[:nv], params[nv:2 * nv], params[2 * nv:3 * nv]
    rates, damping = params[3 * nv:3 * nv + PL], params[3 * nv + PL]

    # 1. the desired trajectory: the learned joints' rows times their parameters, plus O.
    # Each block of rows comes twice, (n, P) and transposed, so that both products with it
    # (here and in the FEL sums) run over contiguous memory.
    sens, pos, start = [], 0, 0
    Z = [[], [], []]
    for _, P in lay.blocks:
        X = []
        for _ in range(3):
            X.append(ca.reshape(data[pos:pos + n * P], n, P))
            pos += n * P
        for c in range(3):
            Xt = ca.reshape(data[pos:pos + n * P], P, n)
            pos += n * P
            Z[c].append(ca.mtimes(theta[start:start + P].T, Xt))
        sens.append(X)
        start += P
    O = ca.reshape(data[pos:pos + 3 * nv * n], nv, 3 * n)
    pos += 3 * nv * n
    weight = data[pos:pos + n].T  # 1 x n
    select = np.zeros((nv, L))
    for l, (i, _) in enumerate(lay.blocks):
        select[i, l] = 1.0
    Qd, Vd, Ad = (O[:, c * n:(c + 1) * n] for c in range(3))
    if L:
        Qd, Vd, Ad = (D + ca.mtimes(ca.DM(select), ca.vertcat(*z)) for D, z in
                      zip((Qd, Vd, Ad), Z))

    # 2. feedforward and the learned joints' derivative columns, per sample
    Uff, Dall = feedforward_function(exp, lay).map(n, "serial")(Qd, Vd, Ad)

    # 3. the closed loop
    track, stab = ca.DM(law.tracking.astype(float)), ca.DM(law.stabilizing.astype(float))
    C = ca.DM(law.C)
    R = ca.diag(track) @ ca.mtimes(C, Qd) + ca.repmat(stab * targets, 1, n)
    Rd = ca.diag(track) @ ca.mtimes(C, Vd)
    sim = step_function(exp, plant).mapaccum("sim", n)
    X_after, U, Urows, Uerr, err, hits = sim(x0, Uff, R, Rd, ca.repmat(kp, 1, n),
                                             ca.repmat(kd, 1, n))
    X = ca.horzcat(x0, X_after[:, :n - 1])
    x_end = X_after[:, n - 1]

    # 4. FEL sums and update, if the cycle stayed finite
    finite = (ca.sum1(ca.sum2(ca.fabs(X))) + ca.sum1(ca.fabs(x_end))) < np.inf
    theta_next = theta
    if L:
        E = Uerr * ca.repmat(weight, nv, 1)
        deriv = [[Dall[:, [c * L + l + 3 * L * k for k in range(n)]] for c in range(3)]
                 for l in range(L)]
        rows = None
        if learner.update == "gauss_newton":
            any_err = ca.sum2(ca.fabs(Uerr)) > 0
            rows = ca.fmax(any_err, ca.DM((learner.error_mask > 0).astype(float)))
            rows = ca.repmat(rows, 1, n) * ca.repmat(weight, nv, 1)
        grad, hess = fel_sums(CASADI, sens, deriv, E, rows)
        step = fel_update(CASADI, theta, grad, hess, rates, learner.is_goal, learner.update,
                          damping)
        theta_next = ca.if_else(finite, step, theta)

    # 5. metrics
    wsum = ca.sum2(weight)
    wrow = ca.repmat(weight, nv, 1)
    mean = lambda M: ca.sum2(ca.fabs(M) * wrow) / wsum  # noqa: E731
    fb = mean(U)
    dq = Qd - X[:nv, :]
    rms = ca.sqrt(ca.sum2(dq * dq * wrow) / wsum)
    stab_idx = np.flatnonzero(law.stabilizing).tolist()
    rows_mean = mean(Urows)
    fb_stab = ca.sum1(rows_mean[stab_idx]) if stab_idx else ca.MX(0)
    fb_err = ca.sum1(mean(Uerr))
    stats = ca.vertcat(fb, rms, ca.mmax(err), ca.mmax(ca.fabs(X[nv:, :])), fb_stab, fb_err,
                       finite, ca.sum2(hits))
    outs = [ca.vertcat(theta_next, x_end), stats]
    names = ["state_next", "stats"]
    if full:
        outs += [X, U, Urows, Uerr, Qd]
        names += ["X", "U", "Urows", "Uerr", "Qd"]
    return ca.Function(name, [state, data, params], [ca.densify(o) for o in outs],
                       ["state", "data", "params"], names)


def many_function(exp, plant, cycles: int, name: str = "many") -> ca.Function:
    """``cycles`` learning cycles in a row on the same data: ``(state, data, params) ->
    (states, stats)``, one column per cycle."""
    one = cycle_function(exp, plant, False, name + "_one")
    state = ca.MX.sym("state", one.size1_in(0))
    data, params = ca.MX.sym("data", one.size1_in(1)), ca.MX.sym("params", one.size1_in(2))
    states, stats = [], []
    s = state
    for _ in range(cycles):  # a chain of calls: the data are read in place, not copied
        s, st = one(s, data, params)
        states.append(s)
        stats.append(st)
    return ca.Function(name, [state, data, params], [ca.horzcat(*states), ca.horzcat(*stats)],
                       ["state", "data", "params"], ["states", "stats"])


def parameters(exp) -> np.ndarray:
    """The ``params`` input: kp, kd, targets (nv each), the learned parameters' rates and
    the Levenberg-Marquardt damping."""
    law, learner = exp.law, exp.learner
    return np.concatenate([law.kp, law.kd, law.targets, learner.rates, [learner.damping]])


__all__ = ["Layout", "SCALARS", "cycle_function", "feedforward_function", "layout",
           "many_function", "parameters", "step_function", "symbolic_forward",
           "symbolic_frames"]
