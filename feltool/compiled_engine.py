"""Running an experiment's learning cycles on the compiled engine.

:class:`CompiledEngine` builds the cycle graphs of an experiment (:mod:`feltool.compiled_graph`)
for every world it meets (the plant, and the plant after each ``events:`` change of the world),
compiles them into one library (:func:`feltool.compiled.compile_functions`) and runs cycles
through them, returning the same :class:`~feltool.seed.CycleOutcome` as the Python engine.

A run whose cycles all repeat the nominal one (no motion events, a whole-sample period) is run
:data:`~feltool.compiled.CYCLES_PER_CALL` cycles per call: the outcomes of the cycles that follow
are kept and handed out while the seed continues from the very state they predicted (the same
arrays) in the same world; a resumed or otherwise different state, or a world event, starts a
new batch. Otherwise each cycle's data
(the sensitivity rows at its phases, the other joints' motion, transients) are passed per call.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from feltool.compiled import CYCLES_PER_CALL, check_supported, compile_functions
from feltool.compiled_graph import SCALARS, cycle_function, layout, many_function, parameters
from feltool.dynamics.casadi_backend import BufferedCall
from feltool.events import changed_model
from feltool.simulate import CycleLog

if TYPE_CHECKING:
    from feltool.experiment import Experiment
    from feltool.phase import PhaseSamples
    from feltool.seed import CycleOutcome


def _fingerprint(plant) -> bytes:
    """Identifies a plant's dynamics: its model's gravity and inertial parameters (and joint
    friction)."""
    rigid = getattr(plant, "rigid", plant)
    m = rigid.model
    parts = [np.asarray(m.gravity.linear, float)]
    parts += [m.inertias[j].toDynamicParameters() for j in range(1, m.njoints)]
    for key in ("viscous", "coulomb", "coulomb_velocity"):
        if hasattr(plant, key):
            parts.append(np.asarray(getattr(plant, key), float))
    return np.concatenate(parts).tobytes()


def worlds(exp: Experiment) -> list:
    """The plants a run meets: ``exp.plant``, then the known model changed by the world events
    up to each event's cycle (the Python engine's :func:`feltool.events.plant_for_cycle`)."""
    from feltool.dynamics import make_dynamics

    out = [exp.plant if exp.plant is not None else exp.dynamics]
    events = exp.config.events
    for c in sorted({ev.cycle for ev in events if ev.changes_world}):
        out.append(make_dynamics(changed_model(exp.robot.model,
                                               [ev for ev in events if ev.cycle <= c])))
    return out


class CompiledEngine:
    """The compiled cycles of one experiment.

    Args:
        exp: The experiment (:func:`feltool.compiled.check_supported` must pass).
        compile: Generate C and compile (else run CasADi's virtual machine: for tests).
        vm_fallback: When compiling fails, run CasADi's virtual machine (said once); else
            leave :attr:`functions` None.
    """

    def __init__(self, exp: Experiment, compile: bool = True, vm_fallback: bool = True):
        check_supported(exp)
        self.exp, self.lay = exp, layout(exp)
        plants = worlds(exp)
        self._worlds = {_fingerprint(p): w for w, p in enumerate(plants)}
        self._world_of: dict[int, tuple] = {}
        fns = []
        for w, plant in enumerate(plants):
            fns += [cycle_function(exp, plant, False, f"cycle_{w}"),
                    cycle_function(exp, plant, True, f"trace_{w}"),
                    many_function(exp, plant, CYCLES_PER_CALL, f"many_{w}")]
        if compile:
            fns = compile_functions(fns, vm_fallback=vm_fallback)
        self.functions = fns
        if fns is None:
            return
        self._calls = [BufferedCall(f, keep=(1, 2)) for f in fns]
        self.params = parameters(exp)
        self._learned_joints = tuple(i for i, _ in self.lay.blocks)
        self._data_key, self._data = None, None
        self._fixed = np.ones(exp.primitives.n_params, bool)  # parameters not learned
        self._fixed[exp.learner.learned] = False

    # -- inputs ---------------------------------------------------------------------------------
    def world(self, plant) -> int:
        """Which compiled world simulates ``plant`` (the seed's world: the known model stands
        for the experiment's plant, as in :func:`feltool.seed.run_seed`)."""
        if plant is self.exp.dynamics:
            return 0
        seen = self._world_of.get(id(plant))
        if seen is None or seen[0] is not plant:  # (an id may be reused by a new object)
            seen = self._world_of[id(plant)] = (plant, self._worlds[_fingerprint(plant)])
        return seen[1]

    def data(self, theta: np.ndarray, cycle: PhaseSamples | None = None,
             transients: dict | None = None) -> np.ndarray:
        """The ``data`` input of a cycle (:class:`feltool.compiled_graph.Layout`): the learned
        joints' sensitivity rows at its steps, the other joints' desired motion (and the learned
        joints' offsets and transients), the phase weight of each step."""
        exp, lay = self.exp, self.lay
        nominal = cycle is None and not transients
        key = theta[self._fixed].tobytes() if nominal else None
        if nominal and key == self._data_key:
            return self._data
        parts = []
        for blk in exp.learner.learned_sensitivities(cycle):
            parts += [X.ravel(order="F") for X in blk] + [X.ravel() for X in blk]
        O = exp.primitives.desired(theta, cycle, transients, without=self._learned_joints)
        parts += [np.concatenate([o.T for o in O], axis=1).ravel(order="F")]
        weight = None if cycle is None else cycle.weight
        parts.append(np.ones(lay.n) if weight is None else weight)
        out = np.concatenate(parts)
        if nominal:
            self._data_key, self._data = key, out
        return out

    def state(self, theta: np.ndarray, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.concatenate([theta[self.exp.learner.learned], q, v])

    # -- calls ------------------------------------------------------------------------------------
    def cycle(self, world: int, state: np.ndarray, data: np.ndarray):
        """``(state', stats)`` of one cycle."""
        return self._calls[3 * world](state, data, self.params)

    def trace(self, world: int, state: np.ndarray, data: np.ndarray):
        """``(state', stats, X, U, Urows, Uerr, Qd)`` of one cycle."""
        return self._calls[3 * world + 1](state, data, self.params)

    def many(self, world: int, state: np.ndarray, data: np.ndarray):
        """``(states, stats)`` of the next :data:`CYCLES_PER_CALL` cycles, one column each."""
        states, stats = self._calls[3 * world + 2](state, data, self.params)
        return (states.reshape(-1, CYCLES_PER_CALL, order="F"),
                stats.reshape(-1, CYCLES_PER_CALL, order="F"))

    # -- outcomes ---------------------------------------------------------------------------------
    def outcomes(self, theta: np.ndarray, world: int, state0: np.ndarray, data: np.ndarray,
                 states: np.ndarray, stats: np.ndarray) -> list[CycleOutcome]:
        """The :class:`~feltool.seed.CycleOutcome` of each cycle in a row from ``state0``
        (parameters ``theta``) whose ends are the columns of ``states``, with ``stats``."""
        from feltool.seed import CycleOutcome

        nv, PL, exp = self.lay.nv, self.lay.n_learned, self.exp
        thetas = np.repeat(theta[None, :], states.shape[1], axis=0)
        thetas[:, exp.learner.learned] = states[:PL].T
        ends = states[PL:].T.copy()
        k = 2 * nv  # the scalars of SCALARS, then the limit hits
        scalars = stats[k:k + len(SCALARS)].T.tolist()
        finite = np.isfinite(states).all(axis=0).tolist()
        fb, rms = stats[:nv].T.copy(), stats[nv:k].T.copy()
        hits = (stats[k + len(SCALARS):].T.round().astype(int)
                if exp.loop.limits is not None else None)
        starts = [state0] + list(states.T)

        def tracer(j):
            def trace():
                _, _, X, U, Urows, Uerr, Qd = self.trace(world, starts[j], data)
                return CycleLog(X[:nv].T, X[nv:].T, U.T, ends[j, :nv], ends[j, nv:], Urows.T,
                                Uerr.T), Qd.T
            return trace

        out = []
        for j, (max_error, max_speed, fb_stab, fb_err, ok) in enumerate(scalars):
            out.append(CycleOutcome(
                thetas[j], ends[j, :nv], ends[j, nv:], fb[j], rms[j], max_error, max_speed,
                ok == 1.0 and finite[j], tracer(j), fb_stab, fb_err,
                limit_hits=None if hits is None else (hits[j, :nv], hits[j, nv:])))
        return out


def compiled_runner(exp: Experiment, motion=None):
    """The function ``(theta, q, v, plant, theta_m) -> CycleOutcome`` of the compiled engine
    (see the module docstring); ``motion`` (a :class:`~feltool.motion.Motion`) for runs whose
    cycles are not all the nominal one."""
    engine = exp.compiled_cycle()
    pending: list[tuple[tuple, CycleOutcome]] = []

    def run_fixed(theta, q, v, plant, theta_m=None) -> CycleOutcome:
        world = engine.world(plant)
        if pending:
            (t_exp, q_exp, v_exp, w_exp), nxt = pending.pop(0)
            if t_exp is theta and q_exp is q and v_exp is v and w_exp == world:
                return nxt
        pending.clear()
        data = engine.data(theta)
        state0 = engine.state(theta, q, v)
        outs = engine.outcomes(theta, world, state0, data, *engine.many(world, state0, data))
        pending.extend(((a.theta_next, a.q_end, a.v_end, world), b)
                       for a, b in zip(outs, outs[1:]))
        return outs[0]

    def run_motion(theta, q, v, plant, theta_m=None) -> CycleOutcome:
        cycle = motion.next_cycle()
        world = engine.world(plant)
        data = engine.data(theta, cycle, motion.transients)
        state0 = engine.state(theta, q, v)
        state, stats = engine.cycle(world, state0, data)
        out, = engine.outcomes(theta, world, state0, data, state[:, None], stats[:, None])
        out.cycle = cycle
        out.desired = motion.desired(theta, cycle)
        motion.end_cycle()
        return out

    if motion is None:
        return run_fixed
    run_motion.motion, run_motion.extra_state = motion, motion.state
    run_motion.restore_state = motion.restore
    return run_motion


__all__ = ["CompiledEngine", "compiled_runner", "worlds"]
