r"""The learning cycle of a continuous robot (an arm) as a CasADi graph.

One cycle, ``(state, data, params) -> (state', stats)``, built from the pieces of
:mod:`feltool.control.cycle` traced with :data:`feltool.control.ops.CASADI`:

1. the desired trajectory :math:`q_d, \dot q_d, \ddot q_d = O + \sum_l e_{i_l} X_l\theta_l`
   (``data``: each learned joint's sensitivity rows :math:`X_l` at the cycle's steps, as they
   are and transposed, and the other joints' motion :math:`O`);
2. the feedforward :math:`u_{ff} = \mathrm{RNEA}(q_d, \dot q_d, \ddot q_d)` and the learned
   joints' columns of its derivatives, ``map``-ped over the samples;
3. the closed loop, ``mapaccum``-ed over the steps: :func:`feltool.control.cycle.feedback`,
   :math:`u = S(u_{ff} + u_{fb})`, :func:`feltool.control.cycle.advance` through the plant's symbolic
   ABA (friction included), joint and torque limits;
4. the FEL sums (:func:`feltool.control.cycle.fel_sums`, per-sample vectors, no Jacobian) and the
   update (:func:`feltool.control.cycle.fel_update`), or with ``learning.fit: closed_loop`` the
   step through the closed loop (:mod:`feltool.engines.compiled.loop_fit`), applied only if the
   cycle stayed finite;
5. the metrics of :func:`feltool.runs.seed` (phase-weighted means, largest errors, limit hits).

``state`` is the learned parameters and :math:`x_0`; ``params`` the gains, targets and rates,
so one compiled library serves a sweep over them. ``many`` maps the cycle over
:data:`~feltool.engines.compiled.library.CYCLES_PER_CALL` cycles with their updates.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import casadi as ca
import numpy as np

from feltool.control.cycle import advance, feedback, fel_sums, fel_update, wrap
from feltool.control.hold import hold_mean_columns
from feltool.control.ops import CASADI
from feltool.dynamics.symbolic import (
    symbolic_aba,
    symbolic_frame_rotation,
    symbolic_rnea,
    symbolic_rnea_parametric,
)
from feltool.engines.compiled.loop_fit import fit_step

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
        n_model: Parameters of the inverse-model correction (``learning.model``), or 0.
        model_basis: Phase-basis functions per joint of that correction (0: regressor).
        masked: Cycles differ in length (:attr:`feltool.experiment.experiment.Experiment.phase_varies`):
            the graph runs ``n`` steps, the longest cycle's, and a mask in the data says which
            steps a cycle has (the others leave the state as it is and count nowhere).
    """

    nv: int
    n: int
    blocks: tuple[tuple[int, int], ...]
    n_model: int = 0
    model_basis: int = 0
    masked: bool = False

    @property
    def n_learned(self) -> int:
        return sum(p for _, p in self.blocks)

    @property
    def n_state(self) -> int:
        return self.n_learned + self.n_model + 2 * self.nv

    @property
    def n_data(self) -> int:
        return (6 * self.n * self.n_learned + 3 * self.nv * self.n + self.n
                + 2 * self.n * self.model_basis + (self.n if self.masked else 0))

    @property
    def n_params(self) -> int:
        return 3 * self.nv + self.n_learned + 1 + (2 if self.n_model else 0)

    @property
    def n_stats(self) -> int:
        return 4 * self.nv + len(SCALARS)


def layout(exp) -> Layout:
    model = exp.model_learner
    basis = 0
    if model is not None and not getattr(model, "walker", False) and \
            not hasattr(model.features, "corrected_model"):
        basis = model.n_params // exp.robot.model.nv  # phase-basis features
    return Layout(exp.robot.model.nv, max_steps(exp),
                  tuple((i, len(cols)) for i, cols in exp.learner._blocks),
                  model.n_params if model is not None else 0, basis, exp.phase_varies)


def max_steps(exp) -> int:
    """The most steps a cycle of ``exp`` can take: the nominal cycle's, or, when cycles differ
    in length, one revolution at the longest period (the config's and its period events') and
    two steps more."""
    if not exp.phase_varies:
        return exp.primitives.n_steps
    cfg = exp.config
    longest = max([cfg.period_s] + [ev.period_s for _, ev in cfg.motion_events
                                    if ev.period_s is not None])
    return int(np.ceil(longest / cfg.dt)) + 2


def masked_step(step: ca.Function) -> ca.Function:
    """``step`` with a mask input after the state: where it is 0 the state is left as it is
    and the step's error and limit hits are 0 (a step the cycle does not have)."""
    ins = [ca.SX.sym(step.name_in(i), step.sparsity_in(i)) for i in range(step.n_in())]
    m = ca.SX.sym("mask")
    outs = step(*ins)
    x1 = ca.if_else(m, outs[0], ins[0])
    return ca.Function(step.name() + "_masked", [ins[0], m, *ins[1:]],
                       [x1, *outs[1:4], outs[4] * m, outs[5] * m])


def symbolic_forward(plant):
    """``(q, v, tau) -> a`` of a plant (:class:`~feltool.dynamics.interface.Dynamics`): its model's
    symbolic ABA, with the joint friction and motor gains of a
    :class:`~feltool.plant.rigid.FrictionPlant`."""
    rigid = getattr(plant, "rigid", plant)
    aba = symbolic_aba(rigid.model)
    if rigid is plant:
        return lambda q, v, tau: aba(q, v, tau)
    d, c, vc, k = (ca.DM(x) for x in (plant.viscous, plant.coulomb, plant.coulomb_velocity,
                                      plant.motor_gain))
    return lambda q, v, tau: aba(q, v, k * tau - (d * v + c * ca.tanh(v / vc)))


def symbolic_frames(law, model) -> dict:
    """``{row: q -> (y, j_y)}`` of the law's frame angles (:class:`feltool.robot.frames.FrameAngle`),
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


def frames_at(frames: dict, q) -> dict:
    """:func:`symbolic_frames` traced once at ``q``: the same ``{row: q -> (y, j_y)}``, each
    returning its one evaluation (the feedback and the error metric share it)."""
    values = {row: kin(q) for row, kin in frames.items()}
    return {row: (lambda _q, value=value: value) for row, value in values.items()}


def symbolic_reference(law, qd, vd, targets):
    r"""The references :math:`r = C_{track} q_d + r_{held}`, :math:`\dot r = C_{track}\dot q_d`
    of desired joint states (:meth:`feltool.control.feedback.FeedbackLaw.reference`), the stabilized
    rows' targets an input of the graph."""
    track, stab = ca.DM(law.tracking.astype(float)), ca.DM(law.stabilizing.astype(float))
    C = ca.DM(law.C)
    return track * ca.mtimes(C, qd) + stab * targets, track * ca.mtimes(C, vd)


def controlled_error(law, r, q, frames: dict | None = None):
    r"""The largest :math:`|\mathrm{wrap}(r - y)|` over the tracked and stabilized rows [rad]
    (0 without any), :math:`y` the controlled quantities: :math:`C q` and the frame angles."""
    y = ca.mtimes(ca.DM(law.C), q)
    for row, kin in (frames or {}).items():
        y[row] = kin(q)[0]
    controlled = np.flatnonzero(law.tracking | law.stabilizing).tolist()
    return ca.mmax(ca.fabs(wrap(CASADI, r - y)[controlled])) if controlled else type(q)(0)


def _symbolic_limits(limits):
    if limits is None:
        return None
    return SimpleNamespace(lower=ca.DM(limits.lower), upper=ca.DM(limits.upper),
                           effort=ca.DM(limits.effort), joints=limits.joints,
                           torques=limits.torques)


def step_function(exp, plant, lay: Layout | None = None) -> ca.Function:
    """One control step ``(x, u_ff, r, rd, kp, kd) -> (x', u_fb, u_rows, u_err, err, hits)``
    (SX): the feedback laws, the actuated torque and the plant's step; ``err`` the largest
    |reference - controlled quantity| [rad], ``hits`` the joint- and torque-limit indicators
    at the step's start. With an inverse-model correction learned per step
    (``learning.model.step: per_step``) the correction's parameters are a second state and the
    step's features and rate inputs: ``(x, theta_m, u_ff, r, rd, kp, kd, phi, rate) -> (x',
    theta_m', ...)`` (:meth:`feltool.learning.model.ModelLearner.run_cycle`)."""
    model, law, loop = exp.robot.model, exp.law, exp.loop
    nv = model.nv
    x, uff, r, rd = (ca.SX.sym(s, nv if s != "x" else 2 * nv) for s in ("x", "uff", "r", "rd"))
    kp, kd = ca.SX.sym("kp", nv), ca.SX.sym("kd", nv)
    q, v = x[:nv], x[nv:]
    frames = frames_at(symbolic_frames(law, model), q)
    sym_law = SimpleNamespace(C=ca.DM(law.C), kp=kp, kd=kd)
    u_fb, u_rows, u_err = feedback(CASADI, sym_law, q, v, r, rd, loop.error_rows, frames)
    per_step_model = exp.model_learner is not None and exp.model_learner.step_mode == "per_step"
    if per_step_model:
        Pm, B = lay.n_model, lay.model_basis
        theta_m, rate = ca.SX.sym("theta_m", Pm), ca.SX.sym("rate")
        phi = ca.SX.sym("phi", B) if B else ca.SX.sym("phi", nv, Pm)
        Phi = ca.kron(ca.DM.eye(nv), phi.T) if B else phi
        mask = ca.DM(exp.model_learner.error_mask)
        uff_total = uff + mask * ca.mtimes(Phi, theta_m)
        theta_m_next = theta_m + rate * ca.mtimes(Phi.T, mask * u_fb)
    else:
        uff_total = uff
    tau = ca.DM(loop.actuated) * (uff_total + u_fb)
    limits = _symbolic_limits(loop.limits)
    q1, v1 = advance(CASADI, symbolic_forward(plant), q, v, tau, loop.dt / loop.substeps,
                     loop.substeps, loop.integrator == "semi_implicit_euler", limits)
    err = controlled_error(law, r, q, frames)
    hit_q, hit_t = ca.SX.zeros(nv), ca.SX.zeros(nv)
    lim = loop.limits
    if lim is not None:
        if lim.joints == "enforce":
            hit_q = ca.fmax(q <= limits.lower + 1e-12, q >= limits.upper - 1e-12)
        elif lim.joints == "report":
            hit_q = ca.fmax(q < limits.lower, q > limits.upper)
        if lim.torques != "ignore":
            hit_t = ca.fabs(tau) > limits.effort * (1 + 1e-12)
    outs = [ca.vertcat(q1, v1), u_fb, u_rows, u_err, err, ca.vertcat(hit_q, hit_t)]
    if per_step_model:
        return ca.Function("step", [x, theta_m, uff, r, rd, kp, kd, phi, rate],
                           outs[:1] + [theta_m_next] + outs[1:])
    return ca.Function("step", [x, uff, r, rd, kp, kd], outs)


def feedforward_function(exp, lay: Layout) -> ca.Function:
    r"""``(q_d, v_d, a_d, theta_m) -> (u_ff, D, Y)`` (SX): the known model's RNEA; for each
    learned joint l the columns :math:`i_l` of :math:`\partial\tau/\partial q`,
    :math:`\partial\tau/\partial\dot q` and M, as ``D`` ``(nv, 3 L)`` ordered (q of every l,
    then v, then a); and for a regressor correction (``learning.model``) the joint torque
    regressor ``Y`` ``(nv, n_model)`` of the known model (:class:`feltool.learning.model.
    RegressorFeatures`). With ``learning.model.jacobian: learned`` the rows of ``D`` whose
    feedforward the correction drives are the corrected model's (:func:`feltool.runs.seed.
    model_cycle`)."""
    model = exp.robot.model
    nv = model.nv
    q, v, a = (ca.SX.sym(s, nv) for s in ("q", "v", "a"))
    theta_m = ca.SX.sym("theta_m", lay.n_model)
    tau = symbolic_rnea(model)(q, v, a)
    cols = [i for i, _ in lay.blocks]
    D = ca.horzcat(*[ca.jacobian(tau, z[i]) for z in (q, v, a) for i in cols]) if cols \
        else ca.SX(nv, 0)
    Y = ca.SX(nv, 0)
    learner = exp.model_learner
    if learner is not None and lay.model_basis == 0:
        from feltool.learning.model import inertial_parameters

        pi = ca.SX.sym("pi", lay.n_model)
        rnea_pi = symbolic_rnea_parametric(model)
        Y = ca.jacobian(rnea_pi(q, v, a, pi), pi)  # linear in pi: Y does not depend on it
        Y = ca.substitute(Y, pi, ca.DM.zeros(lay.n_model))
        rows = (learner.error_mask > 0) & (exp.learner.error_mask > 0)
        if exp.config.learning.model.jacobian == "learned" and rows.any() and cols:
            tau_c = rnea_pi(q, v, a, ca.DM(inertial_parameters(model)) + theta_m)
            Dc = ca.horzcat(*[ca.jacobian(tau_c, z[i]) for z in (q, v, a) for i in cols])
            pick = ca.DM(rows.astype(float))
            D = ca.diag(1 - pick) @ D + ca.diag(pick) @ Dc
    return ca.Function("ff", [q, v, a, theta_m], [tau, D, Y])


def model_update(exp, lay: Layout, theta_m, Y, Psi, U, rate, damping):
    r"""The correction's parameters after a cycle (eq. 3.4, :meth:`feltool.learning.model.
    ModelLearner.step`): :math:`g = \sum_k \Phi_k^\top S_m u_{fb}^k`, then the gradient step
    or the Levenberg-Marquardt step with :math:`H = \sum_k \Phi_k^\top\Phi_k`. ``Y``: the
    regressor of every sample ``(nv, n_model n)`` (or None with ``Psi``, the phase basis
    ``(n, B)``); ``U``: the feedback ``(nv, n)``."""
    learner = exp.model_learner
    nv, n, Pm, B = lay.nv, lay.n, lay.n_model, lay.model_basis
    E = ca.diag(ca.DM(learner.error_mask)) @ U
    if B:
        g = ca.vec(ca.mtimes(Psi.T, E.T))  # (B, nv) column by column: joint j's block
        H = ca.kron(ca.DM.eye(nv), ca.mtimes(Psi.T, Psi)) if learner.update != "gradient" \
            else None
    else:
        y, e = ca.SX.sym("y", nv, Pm), ca.SX.sym("e", nv)
        outs = [ca.mtimes(y.T, e)]
        if learner.update != "gradient":
            outs.append(ca.mtimes(y.T, y))
        sums = ca.Function("model_sums", [y, e], outs).map("model_map", "serial", n, [],
                                                            list(range(len(outs)))).call([Y, E])
        g, H = sums[0], sums[1] if len(outs) > 1 else None
    if learner.update == "gradient":
        return theta_m + rate * g
    lam = damping * ca.trace(H) / Pm + 1e-300
    return theta_m + rate * ca.solve(H + lam * ca.DM.eye(Pm), g)


def desired_from_data(lay: Layout, theta, data):
    """The learned joints' sensitivity rows (per joint ``[Xq, Xv, Xa]``, each ``(n, P)``),
    the desired trajectory ``(Qd, Vd, Ad)`` (each ``(nv, n)``: the rows times θ plus the other
    joints' motion O), the phase weights ``(1, n)`` and where the rest of ``data`` starts.
    Each block of rows comes twice in ``data``, ``(n, P)`` and transposed, so that both
    products with it (here and in the FEL sums) run over contiguous memory."""
    nv, n, L = lay.nv, lay.n, len(lay.blocks)
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
    pos += n
    select = np.zeros((nv, L))
    for l, (i, _) in enumerate(lay.blocks):
        select[i, l] = 1.0
    desired = [O[:, c * n:(c + 1) * n] for c in range(3)]
    if L:
        desired = [D + ca.mtimes(ca.DM(select), ca.vertcat(*z)) for D, z in zip(desired, Z)]
    return sens, desired, weight, pos


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
    PL, Pm, B = lay.n_learned, lay.n_model, lay.model_basis
    theta, theta_m, x0 = state[:PL], state[PL:PL + Pm], state[PL + Pm:]
    kp, kd, targets, rates, damping, rate_m, damping_m = split_params(lay, params)
    model = exp.model_learner

    # 1. the desired trajectory
    sens, (Qd, Vd, Ad), weight, pos = desired_from_data(lay, theta, data)
    Psi = ca.reshape(data[pos:pos + n * B], n, B)  # the correction's phase basis, if any
    PsiT = ca.reshape(data[pos + n * B:pos + 2 * n * B], B, n)
    pos += 2 * n * B
    mask = data[pos:pos + n].T if lay.masked else None  # 1 x n

    # 2. feedforward and the learned joints' derivative columns (and the correction's
    # regressor), per sample
    Uff, Dall, Y = feedforward_function(exp, lay).map(n, "serial")(Qd, Vd, Ad, theta_m)
    if exp.config.sim.feedforward == "hold_mean":  # each step's mean over its hold
        Uff = hold_mean_columns(Uff, 1, mask)
    per_step_model = model is not None and model.step_mode == "per_step"
    if model is not None and not per_step_model:  # the correction with this cycle's theta_m
        drives = ca.DM(model.error_mask)  # the joints the correction drives
        if B:
            Uff = Uff + ca.diag(drives) @ ca.mtimes(ca.reshape(theta_m, B, nv).T, PsiT)
        else:
            y, th = ca.SX.sym("y", nv, Pm), ca.SX.sym("th", Pm)
            corr = ca.Function("correction", [y, th], [drives * ca.mtimes(y, th)])
            Uff = Uff + corr.map(n, "serial")(Y, theta_m)

    # 3. the closed loop
    track, stab = ca.DM(law.tracking.astype(float)), ca.DM(law.stabilizing.astype(float))
    C = ca.DM(law.C)
    R = ca.diag(track) @ ca.mtimes(C, Qd) + ca.repmat(stab * targets, 1, n)
    Rd = ca.diag(track) @ ca.mtimes(C, Vd)
    kps, kds = ca.repmat(kp, 1, n), ca.repmat(kd, 1, n)
    if per_step_model:
        sim = step_function(exp, plant, lay).mapaccum("sim", n, [0, 1], [0, 1])
        X_after, TM, U, Urows, Uerr, err, hits = sim(x0, theta_m, Uff, R, Rd, kps, kds,
                                                     PsiT if B else Y, ca.repmat(rate_m, 1, n))
        theta_m_next = TM[:, n - 1]
    else:
        if lay.masked:
            sim = masked_step(step_function(exp, plant, lay)).mapaccum("sim", n)
            X_after, U, Urows, Uerr, err, hits = sim(x0, mask, Uff, R, Rd, kps, kds)
        else:
            sim = step_function(exp, plant, lay).mapaccum("sim", n)
            X_after, U, Urows, Uerr, err, hits = sim(x0, Uff, R, Rd, kps, kds)
        theta_m_next = model_update(exp, lay, theta_m, Y, Psi, U, rate_m, damping_m) \
            if model is not None else theta_m
    X = ca.horzcat(x0, X_after[:, :n - 1])
    x_end = X_after[:, n - 1]

    # 4. FEL sums and update, if the cycle stayed finite
    finite = (ca.sum1(ca.sum2(ca.fabs(X))) + ca.sum1(ca.fabs(x_end))) < np.inf
    theta_next = theta
    if L:
        errors = Uerr * ca.repmat(mask, nv, 1) if lay.masked else Uerr
        step = fit_step(exp, lay, theta, sens, (Qd, Vd, Ad), kp, kd, Dall, Uerr, rates, damping,
                        symbolic_frames(law, exp.robot.model), mask, x_end - x0) \
            if learner.fit == "closed_loop" else \
            fel_step(learner, lay, theta, sens, Dall, Uerr * ca.repmat(weight, nv, 1), errors,
                     rates, damping, weight)
        theta_next = ca.if_else(finite, step, theta)

    # 5. metrics
    stats = cycle_stats(law, weight, X, Qd, U, Urows, Uerr, err, hits, finite, mask)
    return cycle_outputs(name, state, data, params, ca.vertcat(theta_next, theta_m_next, x_end),
                         stats, (X, U, Urows, Uerr, Qd), full)


def cycle_outputs(name: str, state, data, params, state_next, stats, traces,
                  full: bool) -> ca.Function:
    """A cycle as ``(state, data, params) -> (state_next, stats)``, with ``full`` also its
    ``traces`` ``(X, U, Urows, Uerr, Qd)`` (one column per step)."""
    outs, names = [state_next, stats], ["state_next", "stats"]
    if full:
        outs += list(traces)
        names += ["X", "U", "Urows", "Uerr", "Qd"]
    return ca.Function(name, [state, data, params], [ca.densify(o) for o in outs],
                       ["state", "data", "params"], names)


def cycle_stats(law, weight, X, Qd, U, Urows, Uerr, err, hits, finite, mask=None):
    """The cycle's ``stats`` (:data:`SCALARS` and the rest, :func:`feltool.engines.python.cycle_outcome`):
    phase-weighted means of |feedback| and of each controller's and the error's, the RMS of
    the forward minus the system trajectory, the largest error and speed, the limit hits
    (``mask``: the steps the cycle has, else all)."""
    nv = X.shape[0] // 2
    V = X[nv:, :] if mask is None else X[nv:, :] * ca.repmat(mask, nv, 1)
    wsum = ca.sum2(weight)
    wrow = ca.repmat(weight, nv, 1)
    mean = lambda M: ca.sum2(ca.fabs(M) * wrow) / wsum  # noqa: E731
    dq = Qd - X[:nv, :]
    stab = np.flatnonzero(law.stabilizing).tolist()
    fb_stab = ca.sum1(mean(Urows)[stab]) if stab else ca.MX(0)
    return ca.vertcat(mean(U), ca.sqrt(ca.sum2(dq * dq * wrow) / wsum), ca.mmax(err),
                      ca.mmax(ca.fabs(V)), fb_stab, ca.sum1(mean(Uerr)), finite, ca.sum2(hits))


def per_step_layout(exp) -> dict:
    """Sizes of the per-step graph's inputs: ``P`` parameters, ``S`` sensitivity entries
    (2 P), ``per_step`` data per step (per RMP its transition F (4), G (2 P_i) and input row
    (P_i), then the phase rate, its rate of change, the step's phase weight and, when cycles
    differ in length, the step's mask: :func:`masked_step`)."""
    prims = exp.primitives
    P, nv = prims.n_params, prims.nv
    return {"P": P, "nv": nv, "n": max_steps(exp), "masked": exp.phase_varies,
            "state": P + 2 * nv + 2 * P + 2 * nv,
            "per_step": 4 * nv + 3 * P + 3 + (1 if exp.phase_varies else 0)}


def per_step_cycle_function(exp, plant, full: bool = False,
                            name: str = "cycle_per_step") -> ca.Function:
    r"""A cycle with an update after every step (``learning.step: per_step``,
    :func:`feltool.engines.python.per_step_cycle`): each RMP's state :math:`y = (q, q')` and its
    sensitivity S run on through the exact transition of each step's phase,
    :math:`y \leftarrow F y + G\theta`, :math:`S \leftarrow F S + G`; the desired state is
    :math:`q_d = y_0`, :math:`\dot q_d = \omega y_1`, :math:`\ddot q_d = \omega^2 q'' +
    \dot\omega y_1` with :math:`q'' = A_{2,\cdot} y + E(\phi)\theta`; the learned parameters
    move by :math:`\alpha \odot J_k^\top e_k w_k` after the step. ``state``: θ (all
    parameters), y (2 per joint), S (2 P), x; ``data``: the per-step inputs
    (:func:`per_step_layout`) of every step."""
    lay0 = layout(exp)
    pl = per_step_layout(exp)
    prims, learner, law = exp.primitives, exp.learner, exp.law
    nv, n, P = pl["nv"], pl["n"], pl["P"]
    sl = prims.slices
    theta, y, S = ca.SX.sym("theta", P), ca.SX.sym("y", 2 * nv), ca.SX.sym("S", 2 * P)
    x = ca.SX.sym("x", 2 * nv)
    d = ca.SX.sym("d", pl["per_step"])
    kp, kd, targets = ca.SX.sym("kp", nv), ca.SX.sym("kd", nv), ca.SX.sym("targets", nv)
    rates = ca.SX.sym("rates", lay0.n_learned)
    end = pl["per_step"] - (1 if pl["masked"] else 0)
    w, wd, weight = d[end - 3], d[end - 2], d[end - 1]
    qd, vd, ad = [], [], []
    F, G, row, Ss = {}, {}, {}, {}
    pos = 0
    for i, prim in prims.primitives.items():
        P_i = sl[i].stop - sl[i].start
        F[i] = ca.reshape(d[pos:pos + 4], 2, 2)
        G[i] = ca.reshape(d[pos + 4:pos + 4 + 2 * P_i], 2, P_i)
        row[i] = d[pos + 4 + 2 * P_i:pos + 4 + 3 * P_i]
        pos += 4 + 3 * P_i
        yi, th = y[2 * i:2 * i + 2], theta[sl[i]]
        Ss[i] = ca.reshape(S[2 * sl[i].start:2 * sl[i].stop], 2, P_i)
        a_row = ca.DM(prim.A_phase[1]).T
        qd.append(yi[0])
        vd.append(w * yi[1])
        ad.append(w * w * (ca.mtimes(a_row, yi) + ca.dot(row[i], th)) + wd * yi[1])
    qd, vd, ad = ca.vertcat(*qd), ca.vertcat(*vd), ca.vertcat(*ad)
    r, rd = symbolic_reference(law, qd, vd, targets)
    tau, Dcols, _ = feedforward_function(exp, lay0)(qd, vd, ad, ca.SX(0, 1))
    x1, u_fb, u_rows, u_err, err, hits = step_function(exp, plant, lay0)(x, tau, r, rd, kp, kd)
    L, e = len(lay0.blocks), u_err * weight
    grad = []
    for l, (i, _) in enumerate(lay0.blocks):
        a_row = ca.DM(prims.primitives[i].A_phase[1]).T
        Sq, Sv = Ss[i][0, :], w * Ss[i][1, :]
        Sa = w * w * (ca.mtimes(a_row, Ss[i]) + row[i].T) + wd * Ss[i][1, :]
        g = sum(ca.dot(Dcols[:, c * L + l], e) * s for c, s in enumerate((Sq, Sv, Sa)))
        grad.append(g.T)
    y_next = ca.vertcat(*[ca.mtimes(F[i], y[2 * i:2 * i + 2]) + ca.mtimes(G[i], theta[sl[i]])
                          for i in prims.primitives])
    S_next = ca.vertcat(*[ca.vec(ca.mtimes(F[i], Ss[i]) + G[i]) for i in prims.primitives])
    theta_next = theta
    if grad:
        scatter = np.zeros((P, lay0.n_learned))
        scatter[learner.learned, np.arange(lay0.n_learned)] = 1.0
        theta_next = theta + ca.mtimes(ca.DM(scatter), rates * ca.vertcat(*grad))
    if pl["masked"]:  # a step the cycle does not have leaves everything as it is
        m = d[pl["per_step"] - 1]
        theta_next, y_next, S_next, x1 = (ca.if_else(m, a, b) for a, b in
                                          ((theta_next, theta), (y_next, y), (S_next, S),
                                           (x1, x)))
        err, hits = err * m, hits * m
    step_all = ca.Function("step_per_step", [theta, y, S, x, d, kp, kd, targets, rates],
                           [theta_next, y_next, S_next, x1, u_fb, u_rows, u_err, err, hits, qd])
    state = ca.MX.sym("state", pl["state"])
    data = ca.MX.sym("data", pl["per_step"] * n)
    params = ca.MX.sym("params", lay0.n_params)
    th0, y0 = state[:P], state[P:P + 2 * nv]
    S0, x0 = state[P + 2 * nv:3 * P + 2 * nv], state[3 * P + 2 * nv:]
    D = ca.reshape(data, pl["per_step"], n)
    kps, kds, tgs, rts = (ca.repmat(x, 1, n) for x in split_params(lay0, params)[:4])
    run = step_all.mapaccum("sim_per_step", n, [0, 1, 2, 3], [0, 1, 2, 3])
    TH, Y, SS, X_after, U, Urows, Uerr, err, hits, Qd = run(th0, y0, S0, x0, D, kps, kds, tgs,
                                                           rts)
    X = ca.horzcat(x0, X_after[:, :n - 1])
    x_end = X_after[:, n - 1]
    finite = (ca.sum1(ca.sum2(ca.fabs(X))) + ca.sum1(ca.fabs(x_end))) < np.inf
    stats = cycle_stats(law, D[end - 1, :], X, Qd, U, Urows, Uerr, err, hits, finite,
                        D[pl["per_step"] - 1, :] if pl["masked"] else None)
    return cycle_outputs(name, state, data, params,
                         ca.vertcat(TH[:, n - 1], Y[:, n - 1], SS[:, n - 1], x_end), stats,
                         (X, U, Urows, Uerr, Qd), full)


def many_function(exp, plant, cycles: int, name: str = "many",
                  build=None) -> ca.Function:
    """``cycles`` learning cycles in a row on the same data: ``(state, data, params) ->
    (states, stats)``, one column per cycle (``build``: the cycle's builder, default
    :func:`cycle_function`)."""
    one = (build or cycle_function)(exp, plant, False, name + "_one")
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
    the Levenberg-Marquardt damping; with ``learning.model`` its rate and damping."""
    law, learner, model = exp.law, exp.learner, exp.model_learner
    extra = [model.rate, model.damping] if model is not None else []
    return np.concatenate([law.kp, law.kd, law.targets, learner.rates, [learner.damping],
                           extra])


def split_params(lay: Layout, params) -> tuple:
    """The graph's ``params`` input (:func:`parameters`) taken apart: ``(kp, kd, targets,
    rates, damping, rate_m, damping_m)`` (the last two 0 without ``learning.model``)."""
    nv, PL = lay.nv, lay.n_learned
    o = 3 * nv + PL
    model = (params[o + 1], params[o + 2]) if lay.n_model else (0, 0)
    return (params[:nv], params[nv:2 * nv], params[2 * nv:3 * nv], params[3 * nv:o],
            params[o], *model)


def fel_step(learner, lay: Layout, theta, sens, Dall, E, errors, rates, damping, weight=None):
    """The learned parameters after the cycle's update (eq. 3.6) in the graph: the sums of
    :func:`feltool.control.cycle.fel_sums` from the learned joints' derivative columns ``Dall``
    (``nv x 3 L n``, :func:`feedforward_function`'s per step) and the error torques ``E``
    (``nv x n``, weighted as the update wants them); for Gauss-Newton the error rows are those
    with a nonzero entry in ``errors`` (``nv x n``) or in the learner's error mask, each step
    weighted by ``weight`` (``1 x n``; None: 1), as :meth:`feltool.learning.fel.FeedbackErrorLearner.
    sums` does."""
    L, n = len(lay.blocks), lay.n
    deriv = [[Dall[:, [c * L + l + 3 * L * k for k in range(n)]] for c in range(3)]
             for l in range(L)]
    rows = None
    if learner.update == "gauss_newton":
        rows = ca.fmax(ca.sum2(ca.fabs(errors)) > 0,
                       ca.DM((learner.error_mask > 0).astype(float)))
        rows = ca.repmat(rows, 1, n) * (1 if weight is None else ca.repmat(weight, lay.nv, 1))
    grad, hess = fel_sums(CASADI, sens, deriv, E, rows)
    return fel_update(CASADI, theta, grad, hess, rates, learner.is_goal, learner.update, damping)


__all__ = ["Layout", "SCALARS", "cycle_function", "feedforward_function", "layout",
           "many_function", "parameters", "split_params", "step_function", "symbolic_forward",
           "symbolic_frames"]
