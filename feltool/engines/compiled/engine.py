"""Running an experiment's learning cycles on the compiled engine.

:class:`CompiledEngine` builds the cycle graphs of an experiment (:mod:`feltool.engines.compiled.graph`)
for every world it meets (the plant, and the plant after each ``events:`` change of the world),
compiles them into one library (:func:`feltool.engines.compiled.library.compile_functions`) and runs cycles
through them, returning the same :class:`~feltool.engines.outcome.CycleOutcome` as the Python engine.

A run whose cycles all repeat the nominal one (no motion events, a whole-sample period) is run
:data:`~feltool.engines.compiled.library.CYCLES_PER_CALL` cycles per call: the outcomes of the
cycles that follow are kept and handed out while the seed continues from the very state they
predicted (the same arrays) in the same world; a resumed or otherwise different state, or a
world event, starts a new batch. Otherwise each cycle's data (the sensitivity rows at its
phases, the other joints' motion, transients) are passed per call.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np

from feltool.control.closed_loop import CycleLog
from feltool.dynamics.casadi_backend import BufferedCall, call_in_threads
from feltool.engines.compiled.graph import (
    SCALARS,
    cycle_function,
    layout,
    many_function,
    parameters,
    per_step_cycle_function,
)
from feltool.engines.compiled.library import (
    CYCLES_PER_CALL,
    cached,
    compile_ahead,
    compile_functions,
    has_library,
    note_once,
    pending,
)
from feltool.engines.compiled.support import check_supported
from feltool.engines.outcome import CycleOutcome
from feltool.engines.python import hybrid_cycle, limit_cycle_states
from feltool.plant.events import world_plant

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment
    from feltool.motion.phase import PhaseSamples


def _fingerprint(plant) -> bytes:
    """Identifies a plant's dynamics: its model's gravity and inertial parameters (and joint
    friction)."""
    rigid = getattr(plant, "rigid", plant)
    m = rigid.model
    parts = [np.asarray(m.gravity.linear, float)]
    parts += [m.inertias[j].toDynamicParameters() for j in range(1, m.njoints)]
    for key in ("viscous", "coulomb", "coulomb_velocity", "motor_gain"):
        if hasattr(plant, key):
            parts.append(np.asarray(getattr(plant, key), float))
    return np.concatenate(parts).tobytes()


def _cache_key(exp: Experiment, plants: list) -> str:
    """What determines an experiment's cycle graphs, as text: its validated config (every
    field, the demos included), its robot model (Pinocchio's serialization: joints, placements,
    inertias, frames, limits) and its worlds' dynamics (:func:`_fingerprint`). Together with
    feltool's own source (:func:`feltool.engines.compiled.library.source_digest`) it names the
    compiled library, which is then loaded without building the graphs."""
    import hashlib

    digest = hashlib.sha256(exp.config.model_dump_json().encode())
    digest.update(exp.robot.model.saveToString().encode())
    for plant in plants:
        digest.update(_fingerprint(plant))
        digest.update(getattr(plant, "rigid", plant).model.saveToString().encode())
    return digest.hexdigest()


#: Config fields a physical walker's compiled cycle takes as inputs or does not read (besides
#: the joints' demos and targets' values): a new design of the same walker (its demos, period,
#: slope, torso target) loads the walker's cached library (:func:`_physical_key`).
DESIGN_FIELDS = ("name", "description", "period_s", "gravity", "seeds", "backend", "success",
                 "sweep")


def _physical_key(exp: Experiment) -> str:
    """What determines a physical walker's cycle graphs, as text: its validated config without
    what the graph takes as inputs (the demos, the period, the gravity: :data:`DESIGN_FIELDS`;
    the gains, targets, rates and initial parameters are inputs of every compiled cycle), the
    robot model without its gravity, and the graph's capacity in samples. Every world is an
    input (:func:`~feltool.engines.compiled.physical_step.world_vector`)."""
    import hashlib

    import pinocchio as pin

    from feltool.engines.compiled.physical_step import capacity

    cfg = exp.config.model_dump(mode="json")
    for name in DESIGN_FIELDS:
        cfg.pop(name, None)
    for joint in (cfg.get("joints") or {}).values():
        joint.pop("demo", None)  # (data)
        if isinstance(joint.get("target"), dict):
            joint["target"].pop("value", None)  # (params)
    (cfg.get("sim") or {}).pop("cycles", None)
    for name in ("poincare", "settle_cycles"):  # (after the run; the start state)
        (cfg.get("walking") or {}).pop(name, None)
    digest = hashlib.sha256(json.dumps(cfg, sort_keys=True).encode())
    model = pin.Model(exp.hybrid.walker.walker.model)
    model.gravity = pin.Motion.Zero()
    digest.update(model.saveToString().encode())
    digest.update(f"capacity {capacity(exp)}".encode())
    return digest.hexdigest()


def worlds(exp: Experiment) -> list:
    """The plants a run meets: ``exp.plant``, then that plant changed by the world events
    up to each event's cycle (the Python engine's :func:`feltool.plant.events.plant_for_cycle`)."""
    out = [exp.plant if exp.plant is not None else exp.dynamics]
    events = exp.config.events
    for c in sorted({ev.cycle for ev in events if ev.changes_world}):
        out.append(world_plant(out[0], [ev for ev in events if ev.cycle <= c]))
    return out


class CompiledEngine:
    """The compiled cycles of one experiment.

    Args:
        exp: The experiment (:func:`feltool.engines.compiled.support.check_supported` must pass).
        compile: Generate C and compile (else run CasADi's virtual machine: for tests).
        vm_fallback: When compiling fails, run CasADi's virtual machine (said once); else
            leave :attr:`functions` None.
    """

    def __init__(self, exp: Experiment, compile: bool = True, vm_fallback: bool = True,
                 ahead: bool = False):
        check_supported(exp)
        self.physical = exp.config.walking is not None and exp.config.walking.physical
        self.exp, self.lay = exp, layout(exp)
        if self.physical:  # the graph holds a capacity of samples; a cycle's are an input
            from feltool.engines.compiled.physical import physical_layout

            self.lay = physical_layout(exp)
        plants = worlds(exp)
        self._worlds = {_fingerprint(p): w for w, p in enumerate(plants)}
        self._world_of: dict[int, tuple] = {}
        self.walker = exp.hybrid is not None and not self.physical
        self.per_step = exp.config.learning.step == "per_step"
        self.key = None
        if compile:
            self.key = _physical_key(exp) if self.physical else _cache_key(exp, plants)
        key = self.key
        # (a physical walker's one build serves every world: its plant is an input)
        n_worlds = 1 if self.physical else len(plants)
        fns = cached(key, self._names(n_worlds)) if key is not None else None
        if fns is None and key is not None and pending(key) is not None:  # (started ahead)
            fns = None if ahead else compile_functions(pending(key), vm_fallback=vm_fallback,
                                                       key=key)
        elif fns is None:
            fns = self._build(exp, plants)
            if ahead:  # only started: compile_ahead's
                compile_ahead(fns, key)
                fns = None
            elif compile:
                fns = compile_functions(fns, vm_fallback=vm_fallback, key=key)
        if ahead:
            self.functions = None
            return
        self.functions = fns
        if fns is None:
            return
        self._finish(exp)

    def _names(self, n_worlds: int) -> list[str]:
        """The names of the functions :meth:`_build` makes, in order."""
        kinds = ("cycle", "trace") if self.per_step or self.physical else \
            ("cycle", "trace", "many")
        return [f"{kind}_{w}" for w in range(n_worlds) for kind in kinds]

    def _build(self, exp: Experiment, plants: list) -> list:
        """The cycle graphs of every world (CasADi functions, not compiled)."""
        fns = []
        if self.physical:  # one build for every world: the plant's parameters are inputs
            from feltool.engines.compiled.physical import PhysicalGraph
            from feltool.engines.compiled.physical import physical_cycle_function as build

            plants = plants[:1]
            graph = PhysicalGraph(exp)  # the cycle and the trace call the same step's code
            fns += [build(exp, None, False, "cycle_0", graph),
                    build(exp, None, True, "trace_0", graph)]
        for w, plant in enumerate(plants):
            if self.physical:
                continue
            if self.walker:
                from feltool.engines.compiled.pinned import walker_cycle_function as build

                fns += [build(exp, plant, False, f"cycle_{w}"),
                        build(exp, plant, True, f"trace_{w}"),
                        many_function(exp, plant, CYCLES_PER_CALL, f"many_{w}", build)]
            elif self.per_step:
                fns += [per_step_cycle_function(exp, plant, False, f"cycle_{w}"),
                        per_step_cycle_function(exp, plant, True, f"trace_{w}")]
            else:
                fns += [cycle_function(exp, plant, False, f"cycle_{w}"),
                        cycle_function(exp, plant, True, f"trace_{w}"),
                        many_function(exp, plant, CYCLES_PER_CALL, f"many_{w}")]
        return fns

    def _finish(self, exp: Experiment) -> None:
        fns = self.functions
        self._calls = [BufferedCall(f, keep=(1, 2)) for f in fns]
        self._n_fns = 2 if self.per_step or self.physical else 3
        self.params = parameters(exp)
        self._learned_joints = tuple(i for i, _ in self.lay.blocks)
        self._data_key, self._data = None, None
        self._fixed = np.ones(exp.primitives.n_params, bool)  # parameters not learned
        self._fixed[exp.learner.learned] = False
        self._n_max = self.lay.n
        self._mask_entry = [1.0] if self.lay.masked else []

    # -- inputs ---------------------------------------------------------------------------------
    def world(self, plant) -> int:
        """Which compiled world simulates ``plant`` (the seed's world: the known model stands
        for the experiment's plant, as in :func:`feltool.runs.seed.run_seed`)."""
        if plant is self.exp.dynamics:
            return 0
        seen = self._world_of.get(id(plant))
        if seen is None or seen[0] is not plant:  # (an id may be reused by a new object)
            seen = self._world_of[id(plant)] = (plant, self._worlds[_fingerprint(plant)])
        return seen[1]

    def data(self, theta: np.ndarray, cycle: PhaseSamples | None = None,
             transients: dict | None = None) -> np.ndarray:
        """The ``data`` input of a cycle (:class:`feltool.engines.compiled.graph.Layout`): the learned
        joints' sensitivity rows at its steps, the other joints' desired motion (and the learned
        joints' offsets and transients), the phase weight of each step."""
        exp, lay = self.exp, self.lay
        nominal = cycle is None and not transients
        key = theta[self._fixed].tobytes() if nominal else None
        if nominal and key == self._data_key:
            return self._data
        n = lay.n if cycle is None else cycle.n
        if self.physical:  # (the graph's n is its capacity)
            n = exp.primitives.n_steps
        pad = lambda X: np.pad(X, [(0, lay.n - n)] + [(0, 0)] * (X.ndim - 1))  # noqa: E731
        parts = []
        for blk in exp.learner.learned_sensitivities(cycle):
            parts += [pad(X).ravel(order="F") for X in blk] + [pad(X).ravel() for X in blk]
        O = exp.primitives.desired(theta, cycle, transients, without=self._learned_joints)
        parts += [np.concatenate([pad(o).T for o in O], axis=1).ravel(order="F")]
        weight = None if cycle is None else cycle.weight
        parts.append(pad(np.ones(n) if weight is None else weight))
        if lay.model_basis:  # the correction's phase basis, (n, B) as it is and transposed
            psi = exp.model_learner.features._phi[:, 0, :lay.model_basis]
            parts += [psi.ravel(order="F"), psi.ravel()]
        if lay.masked:
            parts.append(pad(np.ones(n)))
        if self.physical:  # the referenced joints' samples (a designed gait), the samples
            for i in sorted(exp.hybrid.reference):  # of the cycle and of its walk steps
                parts += [pad(np.asarray(x[:n], float)) for x in exp.hybrid.reference[i]]
            parts.append([n, n // exp.hybrid.walker.steps_per_cycle])
        out = np.concatenate(parts)
        if nominal:
            self._data_key, self._data = key, out
        return out

    def state(self, theta: np.ndarray, q: np.ndarray, v: np.ndarray,
              theta_m: np.ndarray | None = None) -> np.ndarray:
        """The ``state`` input: the learned parameters, the correction's (``learning.model``)
        and the robot's state."""
        extra = [] if theta_m is None else [theta_m]
        return np.concatenate([theta[self.exp.learner.learned], *extra, q, v])

    def world_params(self, plant) -> np.ndarray:
        """A physical walker's ``params`` input in the world ``plant``: the experiment's
        parameters, then the plant's world vector (the known model stands for the experiment's
        plant, as in :func:`feltool.runs.seed.run_seed`)."""
        from feltool.engines.compiled.physical_step import world_vector

        if plant is self.exp.dynamics and self.exp.plant is not None:
            plant = self.exp.plant
        key = getattr(self, "_world_key", None)
        if key is None or key[0] is not plant:
            gravity = self.exp.hybrid.walker.walker.model.gravity.linear  # the known model's
            self._world_key = (plant, np.concatenate([self.params, world_vector(plant),
                                                      np.asarray(gravity, float)]))
        return self._world_key[1]

    def _params(self, params: np.ndarray | None) -> np.ndarray:
        """``params``, or the experiment's own (a physical walker's: in the experiment's plant)."""
        if params is not None:
            return params
        return self.world_params(self.exp.dynamics) if self.physical else self.params

    # -- calls ------------------------------------------------------------------------------------
    def cycle(self, world: int, state: np.ndarray, data: np.ndarray,
              params: np.ndarray | None = None):
        """``(state', stats)`` of one cycle (``params``: instead of the experiment's, e.g.
        :meth:`world_params`)."""
        return self._calls[self._n_fns * world](state, data, self._params(params))

    def cycles(self, world: int, states: list[np.ndarray], data: np.ndarray,
               params: np.ndarray | None = None) -> list:
        """:meth:`cycle` of each of ``states`` (the same ``data`` and ``params``) on every CPU
        this process may use (:func:`~feltool.dynamics.casadi_backend.call_in_threads`)."""
        return call_in_threads(self.functions[self._n_fns * world], states, data,
                               self._params(params))

    def trace(self, world: int, state: np.ndarray, data: np.ndarray,
              params: np.ndarray | None = None):
        """``(state', stats, X, U, Urows, Uerr, Qd)`` of one cycle."""
        return self._calls[self._n_fns * world + 1](state, data, self._params(params))

    def many(self, world: int, state: np.ndarray, data: np.ndarray):
        """``(states, stats)`` of the next :data:`CYCLES_PER_CALL` cycles, one column each."""
        states, stats = self._calls[self._n_fns * world + 2](state, data, self._params(None))
        return (states.reshape(-1, CYCLES_PER_CALL, order="F"),
                stats.reshape(-1, CYCLES_PER_CALL, order="F"))

    def per_step_data(self, cycle: PhaseSamples) -> np.ndarray:
        """The ``data`` of a per-step cycle (:func:`feltool.engines.compiled.graph.per_step_layout`):
        per step, each RMP's transition over the step's phase ``(F, G)`` and its forcing's
        input row, then the phase's rate, its rate of change and the step's weight."""
        key = cycle.key()
        if key == self._data_key:
            return self._data
        cols = []
        for k in range(cycle.n):
            phi = cycle.phi[k]
            for prim in self.exp.primitives.primitives.values():
                F, G = prim.transition(phi, cycle.dphi[k])
                cols += [F.ravel(order="F"), G.ravel(order="F"), prim.input_row(phi)]
            cols.append([cycle.omega[k], cycle.omega_dot[k],
                         1.0 if cycle.weight is None else cycle.weight[k]] + self._mask_entry)
        per_step = sum(np.size(c) for c in cols) // cycle.n
        data = np.concatenate([np.ravel(c) for c in cols])
        data = np.pad(data, (0, per_step * (self._n_max - cycle.n)))  # mask 0: no such step
        self._data_key, self._data = key, data
        return self._data

    # -- outcomes ---------------------------------------------------------------------------------
    def outcomes(self, theta: np.ndarray, world: int, state0: np.ndarray, data: np.ndarray,
                 states: np.ndarray, stats: np.ndarray,
                 n_steps: int | None = None) -> list[CycleOutcome]:
        """The :class:`~feltool.engines.outcome.CycleOutcome` of each cycle in a row from ``state0``
        (parameters ``theta``) whose ends are the columns of ``states``, with ``stats``
        (``n_steps``: the steps of a cycle shorter than the graph's)."""

        nv, PL, Pm, exp = self.lay.nv, self.lay.n_learned, self.lay.n_model, self.exp
        models = None
        if self.per_step:  # (theta, y, S, x): every parameter
            P = exp.primitives.n_params
            thetas, ends = states[:P].T.copy(), states[3 * P + 2 * nv:].T.copy()
        else:
            thetas = np.repeat(theta[None, :], states.shape[1], axis=0)
            thetas[:, exp.learner.learned] = states[:PL].T
            models = states[PL:PL + Pm].T.copy() if Pm else None
            ends = states[PL + Pm:].T.copy()
        k = 2 * nv  # the scalars of SCALARS, then the limit hits
        scalars = stats[k:k + len(SCALARS)].T.tolist()
        finite = np.isfinite(states).all(axis=0).tolist()
        fb, rms = stats[:nv].T.copy(), stats[nv:k].T.copy()
        hits = (stats[k + len(SCALARS):k + len(SCALARS) + 2 * nv].T.round().astype(int)
                if exp.loop.limits is not None and not self.walker else None)
        walks = [self._walk(stats[:, j]) for j in range(stats.shape[1])] if self.walker \
            else None
        starts = [state0] + list(states.T)

        def tracer(j):
            def trace():
                _, _, X, U, Urows, Uerr, Qd = self.trace(world, starts[j], data)
                k = walks[j][2] if walks else (n_steps or X.shape[1])
                return CycleLog(X[:nv, :k].T, X[nv:, :k].T, U[:, :k].T, ends[j, :nv],
                                ends[j, nv:], Urows[:, :k].T, Uerr[:, :k].T), Qd[:, :k].T
            return trace

        out = []
        for j, (max_error, max_speed, fb_stab, fb_err, ok) in enumerate(scalars):
            out.append(CycleOutcome(
                thetas[j], ends[j, :nv], ends[j, nv:], fb[j], rms[j], max_error, max_speed,
                ok == 1.0 and finite[j], tracer(j), fb_stab, fb_err,
                theta_m_next=None if models is None else models[j],
                limit_hits=None if hits is None else (hits[j, :nv], hits[j, nv:])))
            if walks:
                out[-1].fall, out[-1].impacts, _ = walks[j]
                if out[-1].fall:
                    out[-1].fall = _fall_reason(exp, ends[j])
        return out

    def _walk(self, stats: np.ndarray) -> tuple:
        """``(fell, impacts, steps run)`` of a walker's cycle from its ``stats`` (after the
        arm's: the fall flag, the steps run, per step the impact flag, by the guard, the swing
        foot's x [m])."""
        nv, n = self.lay.nv, self.lay.n
        k = 4 * nv + len(SCALARS)
        fell, run = bool(stats[k]), int(round(stats[k + 1]))
        imp, guard, foot = (stats[k + 2 + c * n:k + 2 + (c + 1) * n] for c in range(3))
        impacts = [(i + 1, bool(guard[i] > 0.5), float(foot[i]))
                   for i in np.flatnonzero(imp > 0.5)]
        return fell, impacts, run


def _fall_reason(exp: Experiment, end: np.ndarray) -> str:
    """Why a walker's cycle stopped, from its end state (:func:`feltool.walking.pinned.fall_reason`)."""
    from feltool.walking.pinned import fall_reason

    nv, W = exp.robot.model.nv, exp.hybrid.walker
    if W is None:
        return "the state became non-finite"
    return fall_reason(end[:nv], end[nv:], W.fall_row, W.fall_max) or \
        "the state became non-finite"


def compiled_runner(exp: Experiment, motion=None, theta0: np.ndarray | None = None):
    """The function ``(theta, q, v, plant, theta_m) -> CycleOutcome`` of the compiled engine
    (see the module docstring); ``motion`` (a :class:`~feltool.motion.motion.Motion`) for runs whose
    cycles are not all the nominal one and for per-step learning, whose RMP states start on the
    limit cycle of ``theta0``."""
    engine = compiled_engine(exp)
    pending: list[tuple[tuple, CycleOutcome]] = []

    def run_fixed(theta, q, v, plant, theta_m=None) -> CycleOutcome:
        world = engine.world(plant)
        if pending:
            (t_exp, q_exp, v_exp, m_exp, w_exp), nxt = pending.pop(0)
            if t_exp is theta and q_exp is q and v_exp is v and m_exp is theta_m \
                    and w_exp == world:
                return nxt
        pending.clear()
        data = engine.data(theta)
        state0 = engine.state(theta, q, v, theta_m)
        outs = engine.outcomes(theta, world, state0, data, *engine.many(world, state0, data))
        pending.extend(((a.theta_next, a.q_end, a.v_end, a.theta_m_next, world), b)
                       for a, b in zip(outs, outs[1:]))
        return outs[0]

    def run_motion(theta, q, v, plant, theta_m=None) -> CycleOutcome:
        cycle = motion.next_cycle()
        world = engine.world(plant)
        data = engine.data(theta, cycle, motion.transients)
        state0 = engine.state(theta, q, v, theta_m)
        state, stats = engine.cycle(world, state0, data)
        out, = engine.outcomes(theta, world, state0, data, state[:, None], stats[:, None],
                               cycle.n)
        out.cycle = cycle
        transients = dict(motion.transients)  # as they are now: the motion moves on
        out.desired = lambda: exp.primitives.desired(theta, cycle, transients)  # (the event
        motion.end_cycle()                                 # traces ask for a few cycles')
        return out

    if engine.per_step:
        return _per_step_runner(exp, engine, motion, theta0)
    if engine.physical:
        return _physical_runner(exp, engine)
    if motion is None:
        return run_fixed
    run_motion.motion, run_motion.extra_state = motion, motion.state
    run_motion.restore_state = motion.restore
    return run_motion


def _per_step_runner(exp: Experiment, engine: CompiledEngine, motion, theta0: np.ndarray):
    """Per-step learning: one cycle per call; the RMP states run on in ``run.rmp_states``
    (``{joint: (y, S)}``, saved in checkpoints as the Python engine's)."""

    prims, nv = exp.primitives, exp.primitives.nv
    P = prims.n_params
    states = limit_cycle_states(exp, theta0)

    def run(theta, q, v, plant, theta_m=None) -> CycleOutcome:
        cycle = motion.next_cycle()
        world = engine.world(plant)
        data = engine.per_step_data(cycle)
        y = np.concatenate([states[i][0] for i in prims.primitives])
        S = np.concatenate([states[i][1].ravel(order="F") for i in prims.primitives])
        state0 = np.concatenate([theta, y, S, q, v])
        state, stats = engine.cycle(world, state0, data)
        out, = engine.outcomes(theta, world, state0, data, state[:, None], stats[:, None],
                               cycle.n)
        y, S = state[P:P + 2 * nv], state[P + 2 * nv:3 * P + 2 * nv]
        for i in prims.primitives:
            sl = prims.slices[i]
            states[i] = (y[2 * i:2 * i + 2].copy(),
                         S[2 * sl.start:2 * sl.stop].reshape(2, -1, order="F").copy())
        out.cycle = cycle
        motion.end_cycle()
        return out

    run.rmp_states = states
    run.motion, run.extra_state, run.restore_state = motion, motion.state, motion.restore
    return run


def _physical_runner(exp: Experiment, engine: CompiledEngine):
    """The physical walker: one cycle per call. A cycle the graph reports stopped (a contact
    check, a fall, no touchdown) is the seed's last: the Python engine reruns it from the same
    state for its message and numbers."""
    from feltool.engines.compiled.physical import CONTACT, row_fields, unpack

    nv, PL, spc = engine.lay.nv, engine.lay.n_learned, exp.hybrid.walker.steps_per_cycle
    k = 4 * nv + len(SCALARS)

    Pm = engine.lay.n_model

    def run(theta, q, v, plant, theta_m=None) -> CycleOutcome:
        data = engine.data(theta)
        state0 = engine.state(theta, q, v, theta_m if Pm else None)
        params = engine.world_params(plant)
        return outcome(theta, q, v, plant, theta_m, state0, data, params,
                       *engine.cycle(0, state0, data, params))

    def many(theta, X: list[np.ndarray], plant, theta_m=None) -> list[CycleOutcome]:
        """:func:`run` from each state ``x = (q, v)`` of ``X`` (e.g. a Jacobian's
        perturbations), the cycles in parallel (:meth:`CompiledEngine.cycles`)."""
        data, params = engine.data(theta), engine.world_params(plant)
        states0 = [engine.state(theta, x[:nv], x[nv:], theta_m if Pm else None) for x in X]
        return [outcome(theta, x[:nv], x[nv:], plant, theta_m, state0, data, params, *res)
                for x, state0, res in zip(X, states0, engine.cycles(0, states0, data, params),
                                          strict=True)]

    def outcome(theta, q, v, plant, theta_m, state0, data, params, state, stats
                ) -> CycleOutcome:
        if stats[k] != 0:  # stopped: the Python engine's outcome of this very cycle
            return hybrid_cycle(exp, theta, q, v, plant, theta_m=theta_m)
        m = int(round(stats[k + 1]))
        theta_next = theta.copy()
        theta_next[exp.learner.learned] = state[:PL]
        x_end = state[PL + Pm:]
        s = 2 * nv  # the scalars of SCALARS, then the limit hits (joints, motors' torques)
        max_error, max_speed, fb_stab, fb_err, finite = stats[s:s + len(SCALARS)].tolist()
        hits = stats[s + len(SCALARS):k].round().astype(int)
        at, lengths = stats[k + 2:k + 2 + spc], stats[k + 2 + spc:k + 2 + 2 * spc]
        contact = dict(zip(CONTACT, stats[k + 2 + 2 * spc:].tolist()))
        contact["steps"] = int(round(contact["steps"]))
        contact["not_walking"] = None

        def trace():
            rows = engine.trace(0, state0, data, params)[2]
            rw = {n: x[:, :m].T for n, x in unpack(rows, row_fields(nv)).items()}
            log = CycleLog(rw["q"], rw["v"], rw["U"], x_end[:nv], x_end[nv:], rw["Urows"],
                           rw["Uerr"])
            # the applied generalized forces B u and the touchdowns' control steps (what a
            # re-design identifies the world from, feltool.runs.redesign)
            log.applied, log.touchdowns = rw["tau"], np.flatnonzero(rw["impact"][:, 0] > 0)
            return log, rw["qd"]

        out = CycleOutcome(theta_next, x_end[:nv], x_end[nv:], stats[:nv], stats[nv:2 * nv],
                           max_error, max_speed, finite == 1.0 and np.isfinite(state).all(),
                           trace, fb_stab, fb_err,
                           theta_m_next=state[PL:PL + Pm].copy() if Pm else theta_m,
                           limit_hits=(hits[:nv], hits[nv:]))
        out.impacts = [(int(round(s)), True, float(length)) for s, length in zip(at, lengths)]
        out.contact = contact
        return out

    run.many = many
    return run


__all__ = ["CompiledEngine", "compiled_runner", "worlds"]


def compile_engine_ahead(exp: Experiment) -> bool:
    """Start compiling the library of ``exp``'s compiled physical walker and return at once
    (:func:`feltool.engines.compiled.library.compile_ahead`: its graphs built and generated
    now, the C compilers left running); the first :func:`compiled_engine` of an experiment with
    the same library then waits for them. ``feltool gait`` starts its walker's library so
    before the design, whose demos and period are the library's inputs. False when nothing was
    started (not a physical walker on the compiled engine, or its library cached)."""
    if exp.engine != "compiled" or exp.config.walking is None or not exp.config.walking.physical:
        return False
    key = _physical_key(exp)
    if has_library(key) or pending(key) is not None:
        return False
    CompiledEngine(exp, ahead=True)
    return pending(key) is not None


def compiled_engine(exp: Experiment) -> CompiledEngine | None:
    """The compiled engine of ``exp`` (its cycles built and compiled on first use, cached on
    disk and in ``exp.compiled``). With ``backend: auto``, a compilation that fails switches the
    experiment to the Python engine (and says so once) and returns None."""
    if exp.compiled is None:
        engine = CompiledEngine(exp, vm_fallback=exp.config.backend == "compiled")
        if engine.functions is None:
            reason = "backend auto: compiling the cycle failed"
            note_once(f"{reason}; running the Python engine instead")
            exp.engine, exp.engine_reason = "python", reason
            return None
        exp.compiled = engine
    return exp.compiled
