"""Running one seed: the learning cycles of an :class:`~feltool.experiment.experiment.Experiment`.

:func:`run_seed` loops over cycles; each cycle is run by the cycle runner of the experiment's
backend and update mode (:func:`_cycle_runner`: the Python engine's cycles of
:mod:`feltool.engines.python`, the compiled engine of :mod:`feltool.engines.compiled.engine`, ILC and
the baseline), which returns a :class:`~feltool.engines.outcome.CycleOutcome`; the observers turn
outcomes into metric rows, checkpoints and the seed's summary.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from feltool.bounds import check_cycles, check_seed
from feltool.control.closed_loop import ClosedLoop, CycleLog
from feltool.dynamics.interface import Dynamics
from feltool.engines.compiled.engine import compiled_engine, compiled_runner
from feltool.engines.ilc import cycle_runner as ilc_cycle_runner
from feltool.engines.ilc_walker import cycle_runner as walker_cycle_runner
from feltool.engines.outcome import CycleOutcome, SeedState
from feltool.engines.python import (
    hybrid_cycle,
    limit_cycle_states,
    model_cycle,
    per_cycle,
    per_step_cycle,
)
from feltool.errors import InputError
from feltool.experiment.experiment import Experiment
from feltool.learning.fel import FEL_UPDATES
from feltool.motion.motion import Motion, varying_phase
from feltool.plant.events import plant_for_cycle, world_plant
from feltool.runs.checkpoint import Checkpointer
from feltool.runs.divergence import explain as explain_divergence
from feltool.runs.observers import Callback, SeedCheckpoints, SeedRecord
from feltool.runs.redesign import Redesigner
from feltool.runs.safeguard import Safeguard


@dataclass
class SeedResult:
    """One seed's outcome: metric rows, summary entry, learned parameters and traces."""

    seed: int
    rows: list[dict[str, float]]
    summary: dict[str, Any]
    params: dict[str, np.ndarray]
    traces: dict[str, np.ndarray]


def initial_state(exp: Experiment, seed: int) -> SeedState:
    """A seed's state before its first cycle: its initial parameters (random draws from
    ``seed`` only), the robot on the forward trajectory with the stabilized quantities on
    target (a physical walker after ``walking.settle_cycles`` unlearned cycles)."""
    cfg = exp.config
    theta = exp.initial_parameters(seed)
    Qd, Vd, _ = exp.primitives.desired(theta)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    if exp.hybrid is not None:
        physical = cfg.walking is not None and cfg.walking.physical
        # a physical walker stands on its plant's stance foot (the plant's legs may differ)
        q, v = (exp.hybrid.initial_state(Qd, Vd, exp.plant) if physical
                else exp.hybrid.initial_state(Qd, Vd))
        settle = cfg.walking.settle_cycles if cfg.walking is not None and \
            cfg.walking.physical else 0
        if settle:  # onto the unperturbed gait's limit cycle, nothing learned or counted
            P0, Pv0, Pa0 = exp.primitives.desired(exp.theta_demo)
            q, v = exp.hybrid.initial_state(P0, Pv0)
            for _ in range(settle):
                log = exp.hybrid.run_cycle(exp.dynamics, q, v, P0, Pv0, Pa0)
                if log.fall:
                    break
                q, v = log.q_end, log.v_end
    model = exp.model_learner
    return SeedState(theta, q, v, model.initial_parameters() if model else None)


def run_seed(exp: Experiment, seed: int, cycles: int | None = None,
             progress: Callable[[int, float], None] | None = None,
             checkpoint: Checkpointer | None = None,
             on_cycle: Callable[[int, CycleLog, np.ndarray, float], None] | None = None,
             redesign_world: Callable | None = None) -> SeedResult:
    """Run one seed's learning and return its metrics (see the run directory's metrics.csv).

    Its one job is to drive the cycles: each is run by the experiment's engine
    (:func:`_cycle_runner`), checked (:func:`feltool.runs.divergence.explain`) and handed to the
    observers (:mod:`feltool.runs.observers`): the seed's record, its checkpoints, ``progress`` and
    ``on_cycle``.

    Args:
        progress: Called after every cycle with (cycle, mean |error feedback| [N m]).
        checkpoint: The seed continues from its last checkpoint (bit-identically), saves one
            every ``checkpoint.every`` cycles, and on a stop request saves and raises
            :class:`~feltool.runs.checkpoint.Interrupted`.
        on_cycle: Called after every cycle with (cycle, log, Qd, fb): the cycle's simulated
            states ``log.q`` (n_steps x nv, [rad]), its forward (desired) trajectory ``Qd``
            (n_steps x nv, [rad]) and fb as for ``progress`` (the live viewer streams these).
        redesign_world: With ``learning.redesign``: ``theta_m -> (pin.Model, slope [rad])``,
            the world a re-design takes as identified (default: the model learner's,
            :mod:`feltool.runs.redesign`; a benchmark's oracle gives the plant's).
    """
    if not isinstance(exp, Experiment):
        raise InputError(f"exp: must be an Experiment (feltool.load_experiment), got "
                         f"{type(exp).__name__}")
    seed = check_seed(seed)  # the bounds the command line and the config's seeds meet
    cycles = exp.config.sim.cycles if cycles is None else check_cycles(cycles)
    state = initial_state(exp, seed)
    t_build = time.perf_counter()
    run_cycle = _cycle_runner(exp, state.theta, seed)  # the compiled engine compiles here
    compile_s = time.perf_counter() - t_build
    motion: Motion | None = getattr(run_cycle, "motion", None)
    record = SeedRecord(exp, seed, state)
    observers: list = [record]
    observers += [Callback(progress)] if progress is not None else []
    observers += [Callback(on_cycle, with_trace=True)] if on_cycle is not None else []
    guard = Safeguard(exp)  # learning.safeguard: undo a step that throws the seed away
    saver = SeedCheckpoints(checkpoint, record, run_cycle, cycles, guard) if checkpoint else None
    observers += [saver] if saver is not None else []
    start = 1
    restored = saver.restore() if saver is not None else None
    if restored is not None:
        last, state = restored
        start = last + 1
    record.started = time.perf_counter()
    state.plant = _plant_at_start(exp, start)
    reason, out = None, None
    redesigner = Redesigner(exp, seed, redesign_world) if exp.config.learning.redesign is not None else None
    guard.start()
    try:
        for cycle in range(start, cycles + 1):
            if cycle > start:
                state.plant = _plant_for_cycle(exp, cycle) or state.plant
            t_cycle = time.perf_counter()
            if motion is not None:
                state.theta = motion.apply_events(cycle, state.theta)
            out = run_cycle(state.theta, state.q, state.v, state.plant, state.theta_m)
            record.count(out, time.perf_counter() - t_cycle)
            nxt, rejected, reason = guard.judge(cycle, out, state,
                                                explain_divergence(exp, out, cycle, record.rows))
            if nxt is None:
                break
            row = guard.row(record.row(cycle, out, state.theta, state.theta_m), rejected)
            state = nxt
            for observer in observers:
                observer.after_cycle(cycle, out, state, row)
            new = redesigner.after_cycle(cycle, exp, state.theta_m, out) if redesigner \
                else None
            if new is not None and cycle < cycles:  # the next cycle walks the new design
                exp = new
                state.theta = exp.initial_parameters(seed)  # the RMPs refit to it
                run_cycle = _cycle_runner(exp, state.theta, seed)
                state.plant = _plant_at_start(exp, cycle + 1)
                guard.new_reference(exp, cycle)
                record.exp = exp
    finally:
        guard.finish()
    summary = record.summary(state, reason, cycles, compile_s, out)
    summary.update(guard.summary())
    if redesigner is not None:
        summary["redesign"] = redesigner.summary()
    if saver is not None:
        saver.finish(state, reason)
    return SeedResult(seed, record.rows, summary, record.parameters(state, run_cycle),
                      record.traces)


def _cycle_runner(exp: Experiment, theta0: np.ndarray,
                  seed: int = 0) -> Callable[..., CycleOutcome]:
    """The function ``(theta, q, v, plant) -> CycleOutcome`` that runs one cycle for this
    experiment's backend and update mode; ``plant`` is the simulated world (the known model, or
    the one an event changed).

    A per-step runner carries the RMP states from cycle to cycle in its ``rmp_states``.
    """
    if exp.engine == "compiled" and compiled_engine(exp) is not None:
        cfg = exp.config
        per_step = cfg.learning.step == "per_step"
        moving = per_step or bool(varying_phase(cfg))
        return compiled_runner(exp, _motion(exp, per_step) if moving else None,
                               theta0)
    if exp.hybrid is not None:
        if exp.config.walking is not None and exp.config.walking.physical and (
                exp.config.learning.update not in FEL_UPDATES
                or exp.config.disturbances is not None):
            return walker_cycle_runner(exp, theta0, seed)  # ILC, baseline, disturbances
        return lambda theta, q, v, plant, theta_m=None: hybrid_cycle(exp, theta, q, v, plant,
                                                                      theta_m=theta_m)
    loops: dict[int, ClosedLoop] = {}

    def loop_for(plant: Dynamics) -> ClosedLoop:
        if plant is exp.dynamics:
            return exp.loop
        if id(plant) not in loops:
            loops.clear()
            loops[id(plant)] = ClosedLoop(plant, exp.law, exp.loop.actuated, exp.loop.dt,
                                          exp.loop.substeps, exp.loop.integrator,
                                          exp.loop.error_rows, exp.loop.limits)
        return loops[id(plant)]

    if exp.config.learning.update not in FEL_UPDATES or exp.config.disturbances is not None:
        return ilc_cycle_runner(exp, theta0, seed, loop_for)  # ILC, baseline, disturbances
    if exp.model_learner is not None:
        return lambda theta, q, v, plant, theta_m: model_cycle(exp, theta, q, v, theta_m,
                                                                loop_for(plant))
    motion = _motion(exp, exp.config.learning.step == "per_step")
    if exp.config.learning.step == "per_step":
        states = limit_cycle_states(exp, theta0)

        def run(theta, q, v, plant, theta_m=None):
            return per_step_cycle(exp, theta, q, v, states, motion, loop_for(plant))

        run.rmp_states = states
    else:
        def run(theta, q, v, plant, theta_m=None):
            return per_cycle(exp, theta, q, v, loop_for(plant), motion)

    run.motion, run.extra_state, run.restore_state = motion, motion.state, motion.restore
    return run


def _motion(exp: Experiment, continuous: bool) -> Motion:
    """The seed's phase, motion events and RMP transients (:class:`~feltool.motion.motion.Motion`)."""
    return Motion(exp.config, exp.primitives, exp.joints, exp.robot.model, exp.dynamics,
                  continuous)


def _plant_for_cycle(exp: Experiment, cycle: int) -> Dynamics | None:
    """The simulated world from ``cycle`` on if an event starts then, else None."""
    if not exp.config.events:
        return None
    backend = "casadi" if exp.config.backend == "casadi" else "pinocchio"
    return plant_for_cycle(_base_plant(exp), exp.config.events, cycle, backend)


def _base_plant(exp: Experiment) -> Dynamics:
    """The simulated world before any event: the ``plant:`` block's, else the known model."""
    return exp.plant if exp.plant is not None else exp.dynamics


def _plant_at_start(exp: Experiment, start: int) -> Dynamics:
    """The simulated world at cycle ``start`` (every event up to it applied; resumed runs)."""
    events = [ev for ev in exp.config.events if ev.cycle <= start and ev.changes_world]
    if not events:
        return exp.dynamics
    backend = "casadi" if exp.config.backend == "casadi" else "pinocchio"
    return world_plant(_base_plant(exp), events, backend)
