"""Running one seed: the learning cycles of an :class:`~feltool.experiment.Experiment`.

:func:`run_seed` loops over cycles; each cycle is run by the cycle runner of the experiment's
backend and update mode (per-cycle Python loop, per-step, compiled, walkers' hybrid loop, model
learning), which returns a :class:`CycleOutcome`; the loop turns outcomes into metric rows,
checkpoints, and the seed's summary.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from feltool.checkpoint import Checkpointer, Interrupted, stop_requested
from feltool.control import wrap
from feltool.divergence import explain as explain_divergence
from feltool.dynamics import Dynamics, make_dynamics
from feltool.events import changed_model, plant_for_cycle
from feltool.fel import feedforward
from feltool.ilc import OWN_RUNNER
from feltool.ilc import cycle_runner as ilc_cycle_runner
from feltool.ilc_walker import cycle_runner as walker_cycle_runner
from feltool.motion import Motion
from feltool.phase import PhaseSamples
from feltool.simulate import ClosedLoop, CycleLog

if TYPE_CHECKING:
    from feltool.experiment import Experiment


@dataclass
class SeedResult:
    """One seed's outcome: metric rows, summary entry, learned parameters and traces."""

    seed: int
    rows: list[dict[str, float]]
    summary: dict[str, Any]
    params: dict[str, np.ndarray]
    traces: dict[str, np.ndarray]


@dataclass
class CycleOutcome:
    """What the learner and the metrics need from one cycle, whichever backend ran it.

    Attributes:
        theta_next: Parameters after the cycle's update.
        q_end, v_end: Robot state after the cycle.
        fb_abs_mean: Mean |u_fb| per joint over the cycle [N m].
        fb_stabilized: Sum over stabilizing controllers of their mean |output| [N m].
        fb_error: Sum over joints of the mean |error signal| [N m].
        track_err_rms: RMS of forward minus system angle per joint [rad].
        max_error: Largest |reference - controlled quantity| over the cycle [rad].
        max_speed: Largest |joint velocity| over the cycle [rad/s].
        finite: Whether every state stayed finite.
        trace: Returns ``(CycleLog, Qd)`` of the cycle (computed on demand).
        fall: Why a walker fell during the cycle (hybrid loop), or None.
        impacts: ``(step, by_guard, swing-foot x [m])`` of each impact (walkers).
        theta_m_next: The inverse-model correction after the cycle (``learning.model``), else
            None.
        contact: A physical walker's contact metrics of the cycle (:func:`contact_metrics`).
        cycle: The phase at the cycle's steps (None: the nominal cycle).
        desired: The cycle's desired positions, velocities and accelerations, each ``(n, nv)``,
            where the engine has them.
    """

    theta_next: np.ndarray
    q_end: np.ndarray
    v_end: np.ndarray
    fb_abs_mean: np.ndarray
    track_err_rms: np.ndarray
    max_error: float
    max_speed: float
    finite: bool
    trace: Callable[[], tuple[CycleLog, np.ndarray]]
    fb_stabilized: float = 0.0
    fb_error: float = 0.0
    fall: str | None = None
    impacts: list = field(default_factory=list)
    theta_m_next: np.ndarray | None = None
    limit_hits: tuple[np.ndarray, np.ndarray] | None = None
    contact: dict | None = None
    cycle: PhaseSamples | None = None
    desired: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


def run_seed(exp: Experiment, seed: int, cycles: int | None = None,
             progress: Callable[[int, float], None] | None = None,
             checkpoint: Checkpointer | None = None,
             on_cycle: Callable[[int, CycleLog, np.ndarray, float], None] | None = None
             ) -> SeedResult:
    """Run one seed's learning and return its metrics (see the run directory's metrics.csv).

    Args:
        progress: Called after every cycle with (cycle, mean |error feedback| [N m]).
        checkpoint: The seed continues from its last checkpoint (bit-identically), saves one
            every ``checkpoint.every`` cycles, and on a stop request saves and raises
            :class:`~feltool.checkpoint.Interrupted`.
        on_cycle: Called after every cycle with (cycle, log, Qd, fb): the cycle's simulated
            states ``log.q`` (n_steps x nv, [rad]), its forward (desired) trajectory ``Qd``
            (n_steps x nv, [rad]) and fb as for ``progress`` (the live viewer streams these).
    """
    cfg = exp.config
    cycles = cycles or cfg.sim.cycles
    theta = exp.initial_parameters(seed)
    n = exp.primitives.n_steps
    Qd, Vd, _ = exp.primitives.desired(theta)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    if exp.hybrid is not None:
        q, v = exp.hybrid.initial_state(Qd, Vd)
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
    rows, history, traces, last = [], [theta[exp.learner.learned].copy()], {}, None
    reason, start, wall_before = None, 1, 0.0
    run_cycle = _cycle_runner(exp, theta, seed)
    motion: Motion | None = getattr(run_cycle, "motion", None)
    switches = {ev.cycle for _, ev in cfg.motion_events}
    model = exp.model_learner
    theta_m = model.initial_parameters() if model else None
    model_history = [theta_m]
    saved = checkpoint.load() if checkpoint is not None else None
    if saved is not None:
        start = saved["cycle"] + 1
        theta, q, v = saved["theta"], saved["q"], saved["v"]
        rows, wall_before = saved["rows"], saved["wall_s"]
        history = list(saved["history"])
        traces = {k[len("trace_"):]: val for k, val in saved.items() if k.startswith("trace_")}
        if "rmp_x" in saved:
            _restore_rmp_states(run_cycle, saved)
        if hasattr(run_cycle, "restore_state"):  # ILC sequence, disturbance state
            run_cycle.restore_state(saved)
        if model is not None:
            theta_m, model_history = saved["model_theta"], list(saved["model_history"])
    t0 = time.perf_counter()
    plant, impacts = _plant_at_start(exp, start), {"guard": 0, "clock": 0}
    hits = [np.zeros(len(exp.joints), int), np.zeros(len(exp.joints), int)]
    checked, contacts, out, cycle, steps = False, [], None, start - 1, 0
    if saved is not None:  # counters of the cycles before the checkpoint
        steps = int(saved.get("steps", n * len(rows)))
        impacts.update(saved.get("impacts", {}))
        contacts = list(saved.get("contacts", []))
        if saved.get("limit_hits") is not None:
            checked = True
            hits = [np.array(h, int) for h in saved["limit_hits"]]

    def save(at_cycle: int, wall: float) -> None:
        _save_checkpoint(checkpoint, at_cycle, theta, q, v, rows, history, traces, wall,
                         run_cycle, (theta_m, model_history) if model is not None else None,
                         {"impacts": impacts, "contacts": contacts, "steps": steps,
                          "limit_hits": [h.tolist() for h in hits] if checked else None})
    for cycle in range(start, cycles + 1):
        if cycle > start:
            plant = _plant_for_cycle(exp, cycle) or plant
        if motion is not None:
            theta = motion.apply_events(cycle, theta)
        before, out = out, run_cycle(theta, q, v, plant, theta_m)
        steps += out.cycle.n if out.cycle is not None else n
        for _, by_guard, _ in out.impacts:
            impacts["guard" if by_guard else "clock"] += 1
        if out.limit_hits is not None:
            checked = True
            hits[0] += out.limit_hits[0]
            hits[1] += out.limit_hits[1]
        reason = explain_divergence(exp, out, cycle, rows)
        if reason:
            break
        row = _metrics(exp, seed, cycle, out, theta)
        if model is not None:
            row["model_param_norm"] = float(np.linalg.norm(theta_m))
            theta_m = out.theta_m_next
            model_history.append(theta_m)
        rows.append(row)
        if out.contact is not None:
            contacts.append(out.contact)
        if cycle == 1:
            traces.update(_trace("first", *out.trace()))
        if cycle in switches and before is not None and before.desired is not None:
            traces.update(_switch_trace(cycle, before, out, cfg.dt))
        last = out
        theta = out.theta_next
        history.append(theta[exp.learner.learned].copy())
        q, v = out.q_end, out.v_end
        if progress is not None:
            progress(cycle, row["fb_abs_mean_error"])
        if on_cycle is not None:
            on_cycle(cycle, *out.trace(), row["fb_abs_mean_error"])
        if checkpoint is not None and (cycle % checkpoint.every == 0 or stop_requested()):
            save(cycle, wall_before + time.perf_counter() - t0)
            if stop_requested() and cycle < cycles:
                raise Interrupted(f"seed {seed} stopped after cycle {cycle} (checkpoint saved)")
    wall = wall_before + time.perf_counter() - t0
    if last is not None:
        traces.update(_trace("last", *last.trace()))
    if checkpoint is not None:  # the final state stays, so that a resume may add cycles
        if reason is None and rows and rows[-1]["cycle"] % checkpoint.every:
            save(rows[-1]["cycle"], wall)
        elif reason is not None:
            checkpoint.clear()
    summary = _seed_summary(exp, seed, rows, reason, wall, steps)
    summary["cycles_planned"] = cycles
    if cfg.walking is not None and cfg.walking.physical:
        failed = out.contact if reason and out is not None else None
        summary["walking"] = walking_summary(exp, rows, contacts, failed, reason)
    elif exp.hybrid is not None and exp.hybrid.walker is not None:
        summary["walking"] = pinned_walking_summary(exp, last, traces, impacts, reason)
    summary["learned_feedback"] = learned_feedback(exp, rows)
    summary["limits"] = ({"joint_limit_steps": _nonzero(exp.joints, hits[0]),
                          "torque_limit_steps": _nonzero(exp.joints, hits[1])}
                         if checked else "not checked")
    if exp.hybrid is not None and exp.hybrid.walker is not None:
        summary["guard_impacts"], summary["clock_impacts"] = impacts["guard"], impacts["clock"]
    if exp.hybrid is not None and rows and reason is None and cfg.walking is not None \
            and cfg.walking.poincare:
        from feltool.gait import poincare

        summary["poincare"] = poincare(exp, theta, q, v, plant)
    params = exp.split_parameters(theta)
    if hasattr(run_cycle, "extra_params"):  # an ILC's learned torque sequence
        params.update(run_cycle.extra_params())
    hist = np.array(history)
    for name in exp.learned_joints:
        sl = exp.primitives.slices[exp.joints.index(name)]
        cols = [c for c, p in enumerate(exp.learner.learned) if sl.start <= p < sl.stop]
        params[f"{name}.weights_history"] = hist[:, cols[:-1]]
        params[f"{name}.goal_history"] = hist[:, cols[-1]]
    if model is not None:
        params["model.theta"] = theta_m
        params["model.theta_history"] = np.array(model_history)
    return SeedResult(seed, rows, summary, params, traces)


def _nonzero(names: list[str], counts: np.ndarray) -> dict[str, int]:
    return {name: int(c) for name, c in zip(names, counts) if c}


def _cycle_runner(exp: Experiment, theta0: np.ndarray,
                  seed: int = 0) -> Callable[..., CycleOutcome]:
    """The function ``(theta, q, v, plant) -> CycleOutcome`` that runs one cycle for this
    experiment's backend and update mode; ``plant`` is the simulated world (the known model, or
    the one an event changed).

    A per-step runner carries the RMP states from cycle to cycle in its ``rmp_states``.
    """
    if exp.config.backend == "compiled":
        run = _compiled_runner(exp)
        return lambda theta, q, v, plant, theta_m=None: run(theta, q, v)
    if exp.hybrid is not None:
        if exp.config.walking is not None and exp.config.walking.physical and (
                exp.config.learning.update in OWN_RUNNER or exp.config.disturbances is not None):
            return walker_cycle_runner(exp, theta0, seed)  # ILC, baseline, disturbances
        return lambda theta, q, v, plant, theta_m=None: _hybrid_cycle(exp, theta, q, v, plant)
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

    if exp.config.learning.update in OWN_RUNNER or exp.config.disturbances is not None:
        return ilc_cycle_runner(exp, theta0, seed, loop_for)  # ILC, baseline, disturbances
    if exp.model_learner is not None:
        return lambda theta, q, v, plant, theta_m: _model_cycle(exp, theta, q, v, theta_m,
                                                                loop_for(plant))
    motion = Motion(exp, continuous=exp.config.learning.step == "per_step")
    if exp.config.learning.step == "per_step":
        states = _limit_cycle_states(exp, theta0)

        def run(theta, q, v, plant, theta_m=None):
            return _per_step_cycle(exp, theta, q, v, states, motion, loop_for(plant))

        run.rmp_states = states
    else:
        def run(theta, q, v, plant, theta_m=None):
            return _per_cycle(exp, theta, q, v, loop_for(plant), motion)

    run.motion, run.extra_state, run.restore_state = motion, motion.state, motion.restore
    return run


def _plant_for_cycle(exp: Experiment, cycle: int) -> Dynamics | None:
    """The simulated world from ``cycle`` on if an event starts then, else None."""
    backend = "casadi" if exp.config.backend == "casadi" else "pinocchio"
    return plant_for_cycle(exp.robot.model, exp.config.events, cycle, backend)


def _plant_at_start(exp: Experiment, start: int) -> Dynamics:
    """The simulated world at cycle ``start`` (every event up to it applied; resumed runs)."""
    events = [ev for ev in exp.config.events if ev.cycle <= start and ev.changes_world]
    if not events:
        return exp.dynamics
    backend = "casadi" if exp.config.backend == "casadi" else "pinocchio"
    return make_dynamics(changed_model(exp.robot.model, events), backend)


def _save_checkpoint(checkpoint: Checkpointer, cycle, theta, q, v, rows, history, traces,
                     wall, run_cycle, model_state=None, counters: dict | None = None) -> None:
    arrays = {"theta": theta, "q": q, "v": v, "history": np.array(history)}
    if model_state is not None:
        arrays["model_theta"], arrays["model_history"] = model_state[0], np.array(model_state[1])
    arrays.update({f"trace_{k}": val for k, val in traces.items()})
    if hasattr(run_cycle, "extra_state"):
        arrays.update(run_cycle.extra_state())
    states = getattr(run_cycle, "rmp_states", None)
    if states is not None:
        keys = sorted(states)
        arrays["rmp_keys"] = np.array(keys)
        arrays["rmp_x"] = np.array([states[k][0] for k in keys])
        arrays["rmp_S"] = np.array([states[k][1] for k in keys])
    checkpoint.save(cycle, arrays, {"rows": rows, "wall_s": wall, **(counters or {})})


def _restore_rmp_states(run_cycle, saved: dict) -> None:
    for key, x, S in zip(saved["rmp_keys"], saved["rmp_x"], saved["rmp_S"]):
        run_cycle.rmp_states[int(key)] = (x.copy(), S.copy())


def _feedforward(exp: Experiment, Qd, Vd, Ad) -> tuple[np.ndarray, list | None]:
    """:math:`u_{ff}` along the desired trajectory, with the RNEA derivatives (from the same
    pass) when the learner needs exact sensitivities."""
    if exp.learner.n_learned and exp.config.learning.sensitivity == "exact":
        u_ff, *derivs = exp.dynamics.inverse_derivatives_batch(Qd, Vd, Ad)
        return u_ff, derivs
    return feedforward(exp.dynamics, Qd, Vd, Ad), None


def _per_cycle(exp: Experiment, theta: np.ndarray, q, v, loop: ClosedLoop,
               motion: Motion | None = None) -> CycleOutcome:
    """One cycle (one revolution of the phase) on the limit cycle of the current parameters,
    then one update (eq. 3.6) weighted by the phase each step covers. Without ``motion`` the
    cycle is the nominal one."""
    stalled, cycle = None, None
    if motion is not None and motion.adaptive:
        log, cycle, (Qd, Vd, Ad), stalled = motion.run_adaptive_cycle(loop, q, v, theta)
        derivs = None
        if exp.learner.n_learned and exp.config.learning.sensitivity == "exact":
            derivs = exp.dynamics.inverse_derivatives_batch(Qd, Vd, Ad)[1:]
    else:
        if motion is not None:
            cycle = motion.next_cycle()
            Qd, Vd, Ad = motion.desired(theta, cycle)
        else:
            Qd, Vd, Ad = exp.primitives.desired(theta)
        R, Rd = exp.law.references(Qd, Vd)
        u_ff, derivs = _feedforward(exp, Qd, Vd, Ad)
        log = loop.run_cycle(q, v, R, Rd, u_ff)
    weight = cycle.weight if cycle is not None else None
    theta_next = theta
    if exp.learner.n_learned and np.all(np.isfinite(log.v)) and stalled is None:
        J = exp.learner.jacobian(exp.dynamics, theta, Qd, Vd, Ad, derivs, cycle=cycle,
                                 transients=motion.transients if motion is not None else None)
        theta_next = exp.learner.step(theta, J, log.u_err, weight)
    out = _outcome(exp, log, Qd, theta_next, weight)
    out.cycle, out.desired, out.fall = cycle, (Qd, Vd, Ad), stalled
    if motion is not None:
        motion.end_cycle()
    return out


def _hybrid_cycle(exp: Experiment, theta: np.ndarray, q, v, plant: Dynamics,
                  loop=None, learn: bool = True) -> CycleOutcome:
    """One cycle of the hybrid loop (walkers, allocated motors), then one update (eq. 3.6);
    the learner's Jacobian goes through the stance-dependent map q_d = G_s p_d. ``loop``: the
    loop to run (default ``exp.hybrid``; a disturbed or ILC copy); ``learn`` False: no update."""
    P, Pv, Pa = exp.primitives.desired(theta)
    log = (loop or exp.hybrid).run_cycle(plant, q, v, P, Pv, Pa)
    theta_next = theta
    if learn and log.fall is None and exp.learner.n_learned:
        _, *derivs = exp.hybrid.jacobian_derivatives(log)
        J = exp.learner.jacobian(exp.dynamics, theta, log.Qd, log.Vd, log.Ad, derivs,
                                 samples=getattr(log, "phase_index", None))
        E = error_torques(exp, log)
        A = getattr(log, "allocation", None)
        if exp.config.learning.error_space == "motors" and A is not None and len(A):
            theta_next = _motor_step(exp, theta, A, J, E)
        else:
            theta_next = exp.learner.step(theta, J, E)
    out = _outcome(exp, log, log.Qd, theta_next)
    out.fall, out.impacts = log.fall, list(log.impacts)
    if getattr(log, "steps", None) is not None:
        out.contact = contact_metrics(log, exp)
        out.limit_hits = (np.zeros(len(exp.joints), int), _motor_hits(exp, log))
    return out


def error_torques(exp: Experiment, log) -> np.ndarray:
    """A walker's cycle's learning signal ``(n, nv)`` in generalized forces [N m]: the error
    feedback, plus the inertial term with ``learning.error_estimate: inverse_dynamics``, the
    samples of ``learning.impact_window_s`` left out."""
    E = _impact_masked(exp, log)
    if exp.config.learning.error_estimate == "inverse_dynamics" and \
            getattr(log, "inertial", None) is not None:
        E = E + _impact_masked(exp, log, log.inertial)
    return E


def _motor_step(exp: Experiment, theta: np.ndarray, A: np.ndarray, J: np.ndarray,
                E: np.ndarray) -> np.ndarray:
    r"""The update (eq. 3.6) with the error and the Jacobian in motor torques: the motors
    apply :math:`u = A(q)\,(\tau_{ff} + u_{fb})` (the allocation, :mod:`feltool.walking`), so
    the feedforward's error is :math:`A e` and its sensitivity :math:`A J`; the part of a
    generalized force that the contact absorbs (:math:`A\tau = 0`) is no error and no
    gradient. ``A`` ``(n, k, nv)``, ``J`` ``(n, nv, P)``, ``E`` ``(n, nv)``."""
    Jm = np.einsum("kmr,krp->kmp", A, J)
    Em = np.einsum("kmr,kr->km", A, E)
    grad = np.einsum("km,kmp->p", Em, Jm)
    hess = np.einsum("kmp,kms->ps", Jm, Jm) if exp.learner.update == "gauss_newton" else None
    return exp.learner.apply(theta, grad, hess)


def contact_metrics(log, exp: Experiment) -> dict[str, float]:
    """Per cycle of a physical walker: the stance foot's smallest normal force [N] and largest
    friction ratio, the swing foot's lowest clearance [m], the largest touchdown impulse ratio,
    the kinetic energy lost at the touchdowns [J], the mean step length [m], the walked
    distance [m], the cycle's duration [s], the motors' absolute mechanical work [J], the RMS
    of the stabilized quantities' errors from their targets [rad]; also the kind of contact
    violation (``not_walking``), if any."""
    steps = log.steps
    dt = exp.config.dt
    motors = exp.hybrid.walker.motor_v
    work = float(np.abs(log.tau * log.v[:, motors]).sum() * dt) if len(log.q) else 0.0
    law = exp.law
    stab = law.stabilizing
    if not stab.any() and exp.hybrid.reference:  # a learned joint holding a designed motion
        rows = np.array(sorted(exp.hybrid.reference))
        err = (wrap(law.quantity(log.q)[:, rows] - log.reference[:, rows]) if len(log.q)
               else np.zeros(1))
    else:
        err = (wrap(law.quantity(log.q)[:, stab] - law.targets[stab]) if len(log.q)
               else np.zeros(1))
    done = [s for s in steps if np.isfinite(s.length)]
    finite = lambda xs: [x for x in xs if np.isfinite(x)]  # noqa: E731
    clear = finite([s.min_clearance for s in steps])
    return {
        "min_normal_force": float(min(s.min_normal_force for s in steps)),
        "max_friction_ratio": float(max(s.max_friction_ratio for s in steps)),
        "min_clearance": float(min(clear)) if clear else float("nan"),
        "max_impulse_ratio": float(max((s.impulse_ratio for s in done), default=float("nan"))),
        "impact_energy_lost": float(sum(s.energy_lost for s in done)),
        "step_length": float(np.mean([s.length for s in done])) if done else float("nan"),
        "distance": float(sum(s.length for s in done)),
        "steps": len(done),
        "duration": len(log.q) * dt,
        "work": work,
        "stabilized_rms": float(np.sqrt(np.mean(err**2))) if err.size else 0.0,
        "not_walking": log.not_walking,
    }


def walking_summary(exp: Experiment, rows: list, contacts: list[dict], failed: dict | None,
                    reason: str | None) -> dict[str, Any]:
    """A physical walker's seed: whether it walked every step, the kind of contact violation
    that stopped it (``not_walking``), steps, distance [m], mean step length [m], speed [m/s],
    cost of transport (motors' absolute work / (m g distance)) and the stabilized quantities'
    RMS error [rad] over the last cycle, the contact extremes over all cycles."""
    walked = reason is None
    kind = failed.get("not_walking") if failed else None
    out: dict[str, Any] = {"walked": walked, "not_walking": kind,
                           "reason": reason if kind else None}
    if contacts:
        dist = sum(c["distance"] for c in contacts)
        dur = sum(c["duration"] for c in contacts)
        last = contacts[-1]
        mg = exp.robot.total_mass * float(np.linalg.norm(exp.robot.model.gravity.linear))
        out.update({
            "steps": int(sum(c["steps"] for c in contacts)), "distance_m": dist,
            "step_length_m": last["step_length"],
            "speed_m_per_s": last["distance"] / last["duration"] if last["duration"] else None,
            "cost_of_transport": (last["work"] / (mg * last["distance"])
                                  if last["distance"] > 0 else None),
            "stabilized_rms_last_rad": last["stabilized_rms"],
            "min_normal_force_N": min(c["min_normal_force"] for c in contacts),
            "max_friction_ratio": max(c["max_friction_ratio"] for c in contacts),
            "min_clearance_m": min(c["min_clearance"] for c in contacts),
            "max_impulse_ratio": max(c["max_impulse_ratio"] for c in contacts),
            "walk_time_s": dur,
        })
    return out


def pinned_walking_summary(exp: Experiment, last: CycleOutcome | None, traces: dict,
                           impacts: dict[str, int], reason: str | None) -> dict[str, Any]:
    """The thesis's pinned walker (``impact: relabel`` or ``rigid``, no contact model): whether it
    walked without falling, steps, the last cycle's mean step length [m] and speed [m/s], and
    the stabilized quantities' RMS error [rad] over the last cycle."""
    out: dict[str, Any] = {"walked": reason is None, "not_walking": None,
                           "steps": impacts["guard"] + impacts["clock"]}
    if last is not None and last.impacts:
        lengths = [abs(x) for _, _, x in last.impacts]
        out["step_length_m"] = float(np.mean(lengths))
        out["speed_m_per_s"] = float(np.sum(lengths) / exp.config.period_s)
    stab = exp.law.stabilizing
    if "last_q_system" in traces and stab.any():
        err = wrap(exp.law.quantity(traces["last_q_system"])[:, stab] - exp.law.targets[stab])
        out["stabilized_rms_last_rad"] = float(np.sqrt(np.mean(err**2)))
    return out


def learned_feedback(exp: Experiment, rows: list[dict]) -> dict[str, dict[str, float]]:
    """Each learned joint's own mean |feedback| [N m] in the first and the last cycle."""
    out = {}
    for name in exp.learned_joints:
        fb = [r[f"fb_abs_mean_{name}"] for r in rows]
        if fb:
            out[name] = {"first": fb[0], "last": fb[-1],
                         "ratio": fb[-1] / fb[0] if fb[0] else None}
    return out


def _motor_hits(exp: Experiment, log) -> np.ndarray:
    """Steps over the effort limit per joint (the physical walker's motors are joints)."""
    hits = np.zeros(len(exp.joints), int)
    if log.torque_hits is not None:
        hits[exp.hybrid.walker.motor_v] = log.torque_hits
    return hits


def _impact_masked(exp: Experiment, log, E: np.ndarray | None = None) -> np.ndarray:
    """The cycle's error torques (or ``E``) with the rows within ``learning.impact_window_s``
    after each impact zeroed (the learning signal only; the metrics keep every sample)."""
    window = exp.config.learning.impact_window_s
    E = log.u_err if E is None else E
    if window <= 0 or not log.impacts:
        return E
    E = E.copy()
    n = int(round(window / exp.config.dt))
    for k, _, _ in log.impacts:  # k: first sample after the impact; the cycle's last impact
        k %= len(E)              # starts the next cycle, whose first samples follow it
        E[k:k + n] = 0.0
    return E


def _model_cycle(exp: Experiment, theta: np.ndarray, q, v, theta_m: np.ndarray,
                 loop: ClosedLoop) -> CycleOutcome:
    """One cycle with the learned inverse-model correction in the feedforward, then both
    updates: the trajectory's (eq. 3.6) and the model's (eq. 3.4)."""
    model = exp.model_learner
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_ff, derivs = _feedforward(exp, Qd, Vd, Ad)
    log, theta_m_next = model.run_cycle(loop, q, v, R, Rd, u_ff, (Qd, Vd, Ad), theta_m)
    theta_next = theta
    if exp.learner.n_learned and np.all(np.isfinite(log.v)):
        J = exp.learner.jacobian(exp.dynamics, theta, Qd, Vd, Ad, derivs)
        # The joints the correction drives (model.error_mask) got u_ff from the learned model,
        # the others from the known one: the Jacobian row by row from the model each row used.
        rows = (model.error_mask > 0) & (exp.learner.error_mask > 0)
        learned = (model.learned_dynamics(theta_m)
                   if exp.config.learning.model.jacobian == "learned" and rows.any() else None)
        if learned is not None:
            d = learned.inverse_derivatives_batch(Qd, Vd, Ad)[1:] if derivs is not None else None
            J[:, rows] = exp.learner.jacobian(learned, theta, Qd, Vd, Ad, d)[:, rows]
        theta_next = exp.learner.step(theta, J, log.u_err)
    out = _outcome(exp, log, Qd, theta_next)
    out.theta_m_next = theta_m_next
    return out


def _outcome(exp: Experiment, log: CycleLog, Qd: np.ndarray, theta_next,
             weight: np.ndarray | None = None) -> CycleOutcome:
    """The cycle's metrics: means over its steps, each weighted by the phase it covers
    (``weight``, :class:`~feltool.phase.PhaseSamples`; None: plain means)."""
    R, _ = exp.law.references(Qd, Qd)
    controlled = exp.law.tracking | exp.law.stabilizing
    nv = log.q_end.shape[0]
    # a walker's cycle that stopped (not walking) before its first sample logs no rows: its
    # means are zero, not a reduction over nothing
    if weight is None:
        average = lambda X: X.mean(axis=0)  # noqa: E731
    else:
        average = lambda X: (X * weight[:, None]).sum(axis=0) / weight.sum()  # noqa: E731
    mean = lambda X: average(np.abs(X)) if len(X) else np.zeros(nv)  # noqa: E731
    with np.errstate(all="ignore"):
        err = np.abs(wrap(R - exp.law.quantity(log.q)))[:, controlled]
        return CycleOutcome(
            theta_next, log.q_end, log.v_end, mean(log.u_fb),
            np.sqrt(average((Qd - log.q) ** 2)) if len(log.q) else np.zeros(nv),
            float(err.max()) if err.size else 0.0,
            float(np.abs(log.v).max()) if log.v.size else 0.0,
            bool(np.all(np.isfinite(log.q)) and np.all(np.isfinite(log.v))
                 and np.all(np.isfinite(log.q_end))),
            lambda: (log, Qd),
            float(mean(log.u_rows)[exp.law.stabilizing].sum()),
            float(mean(log.u_err).sum()),
            limit_hits=getattr(log, "limit_hits", None))


def _compiled_runner(exp: Experiment) -> Callable[..., CycleOutcome]:
    """Cycles from the compiled code, several per call: the outcomes of the cycles that follow
    are kept and handed out while the loop continues from the very state they predicted (the
    same arrays); a resumed or otherwise different state starts a new batch."""
    compiled = exp.compiled_cycle()
    nv, P = exp.robot.model.nv, exp.primitives.n_params
    stab = np.flatnonzero(exp.law.stabilizing)
    err_mask = exp.learner.error_mask
    pending: list[tuple[tuple, CycleOutcome]] = []

    def outcome(theta, x0, state, stat) -> CycleOutcome:
        x_end = state[P:]
        fb = stat[:nv]
        max_speed = float(stat[2 * nv + 1])

        def trace():
            out = compiled.full(theta, x0)
            X, U, Qd = out[7].T, out[8].T, out[9].T
            return CycleLog(X[:, :nv], X[:, nv:], U, x_end[:nv], x_end[nv:], U,
                            U * err_mask), Qd

        return CycleOutcome(state[:P], x_end[:nv], x_end[nv:], fb, stat[nv:2 * nv],
                            float(stat[2 * nv]), max_speed,
                            bool(np.isfinite(state).all()) and max_speed == max_speed, trace,
                            float(fb[stab].sum()), float(fb @ err_mask))

    def run(theta, q, v) -> CycleOutcome:
        if pending:
            (t_exp, q_exp, v_exp), nxt = pending.pop(0)
            if t_exp is theta and q_exp is q and v_exp is v:
                return nxt
        pending.clear()
        x0 = np.concatenate([q, v])
        states, stats = compiled.many(theta, x0)
        outs, prev_theta, prev_x = [], theta, x0
        for k in range(states.shape[1]):
            outs.append(outcome(prev_theta, prev_x, states[:, k], stats[:, k]))
            prev_theta, prev_x = outs[-1].theta_next, states[P:, k]
        pending.extend(((a.theta_next, a.q_end, a.v_end), b) for a, b in zip(outs, outs[1:]))
        return outs[0]

    return run


def _limit_cycle_states(exp: Experiment, theta: np.ndarray) -> dict[int, tuple]:
    """Each RMP's state :math:`(q, q')` (phase units) and its sensitivity at phase 0 of its
    limit cycle."""
    out = {}
    for i, p in exp.primitives.primitives.items():
        S = p.state_rows(0.0)
        out[i] = (S @ theta[exp.primitives.slices[i]], S)
    return out


def _per_step_cycle(exp: Experiment, theta: np.ndarray, q, v, states: dict[int, tuple],
                    motion: Motion, loop: ClosedLoop | None = None) -> CycleOutcome:
    """One cycle with an update after every step; the RMP states :math:`y = (q, q')` (updated
    in place in ``states``) run on continuously through the exact step of the phase
    (:meth:`~feltool.rmp.RhythmicPrimitive.transition`), their sensitivities propagated
    alongside. ``loop`` simulates the world (default ``exp.loop``)."""
    loop = loop or exp.loop
    cycle = motion.next_cycle()
    prims, n, nv = exp.primitives, cycle.n, exp.primitives.nv
    learner, law, dyn = exp.learner, exp.law, exp.dynamics
    theta = theta.copy()
    Q, V, U, Urows, Uerr, Qd, Vd, Ad = (np.empty((n, nv)) for _ in range(8))
    for k in range(n):
        phi, w, wd = cycle.phi[k], cycle.omega[k], cycle.omega_dot[k]
        qd, vd, ad = np.empty(nv), np.empty(nv), np.empty(nv)
        Sq, Sv, Sa = {}, {}, {}
        for i, p in prims.primitives.items():
            y, S = states[i]
            th = theta[prims.slices[i]]
            qd[i], vd[i] = y[0], w * y[1]
            ad[i] = w * w * p.phase_acceleration(y, th, phi) + wd * y[1]
            Sq[i], Sv[i] = S[0], w * S[1]
            Sa[i] = w * w * p.phase_acceleration_sensitivity(S, phi) + wd * S[1]
        Qd[k], Vd[k], Ad[k] = qd, vd, ad
        R, Rd = law.references(qd[None], vd[None])
        u_fb, u_rows, u_err = law.terms(q, v, R[0], Rd[0], exp.loop.error_rows)
        u_ff = dyn.inverse(qd, vd, ad)
        Dq, Dv, M = dyn.inverse_derivatives(qd, vd, ad)
        J = np.zeros((1, nv, learner.n_learned))
        for i, cols, _, rows in learner._blocks:
            sel = np.isin(rows, learner.learned)
            J[0][:, cols] = (np.outer(Dq[:, i], Sq[i][sel]) + np.outer(Dv[:, i], Sv[i][sel])
                             + np.outer(M[:, i], Sa[i][sel]))
        Q[k], V[k], U[k], Urows[k], Uerr[k] = q, v, u_fb, u_rows, u_err
        q, v = loop.advance(q, v, loop.actuated * (u_ff + u_fb))
        for i, p in prims.primitives.items():
            y, S = states[i]
            F, G = p.transition(phi, cycle.dphi[k])
            states[i] = (F @ y + G @ theta[prims.slices[i]], F @ S + G)
        theta = learner.step(theta, J, u_err[None],
                             None if cycle.weight is None else cycle.weight[k:k + 1])
    out = _outcome(exp, CycleLog(Q, V, U, q, v, Urows, Uerr), Qd, theta, cycle.weight)
    out.cycle, out.desired = cycle, (Qd, Vd, Ad)
    return out


def _metrics(exp: Experiment, seed: int, cycle: int, out: CycleOutcome,
             theta: np.ndarray) -> dict[str, float]:
    fb, rms = out.fb_abs_mean, out.track_err_rms
    row: dict[str, float] = {"seed": seed, "cycle": cycle}
    for i, name in enumerate(exp.joints):
        row[f"fb_abs_mean_{name}"] = float(fb[i])
    row["fb_abs_mean_stabilized"] = out.fb_stabilized
    row["fb_abs_mean_total"] = float(fb.sum())
    row["fb_abs_mean_error"] = out.fb_error
    for i, name in enumerate(exp.joints):
        row[f"track_err_rms_{name}"] = float(rms[i])
    row["param_norm"] = float(np.linalg.norm(theta[exp.learner.learned]))
    if exp.phase_varies and out.cycle is not None:  # cycles of changing length
        row["cycle_s"] = out.cycle.n * exp.config.dt
        row["frequency_hz"] = float(out.cycle.dphi.sum() / (2.0 * np.pi * row["cycle_s"]))
    if out.contact is not None:
        for key in ("min_normal_force", "max_friction_ratio", "min_clearance",
                    "max_impulse_ratio", "impact_energy_lost", "step_length", "distance"):
            row[key] = out.contact[key]
    return row


def _trace(which: str, log: CycleLog, Qd: np.ndarray) -> dict[str, np.ndarray]:
    return {f"{which}_q_system": log.q, f"{which}_q_forward": Qd, f"{which}_u_fb": log.u_fb}


def _switch_trace(cycle: int, before: CycleOutcome, after: CycleOutcome,
                  dt: float) -> dict[str, np.ndarray]:
    """The desired trajectory across a motion event at the start of ``cycle``: the cycle
    before it and the cycle it starts, one after the other (``switch<cycle>_t`` [s] from the
    event, ``_q_forward`` [rad], ``_v_forward`` [rad/s])."""
    Q = np.concatenate([before.desired[0], after.desired[0]])
    V = np.concatenate([before.desired[1], after.desired[1]])
    t = (np.arange(len(Q)) - len(before.desired[0])) * dt
    return {f"switch{cycle}_t": t, f"switch{cycle}_q_forward": Q, f"switch{cycle}_v_forward": V}


def _seed_summary(exp: Experiment, seed: int, rows, reason: str | None,
                  wall: float, steps: int) -> dict[str, Any]:
    fb = [r["fb_abs_mean_error"] for r in rows]
    fb0 = fb[0] if fb else None
    converged = None
    if fb:
        threshold = 0.05 * fb0
        above = [i for i, f in enumerate(fb) if f >= threshold]
        last_above = above[-1] if above else -1
        if last_above < len(fb) - 1:
            converged = rows[last_above + 1]["cycle"]
    out = {"seed": seed, "cycles": len(rows), "fb_initial": fb0, "fb_final": fb[-1] if fb else None,
           "fb_ratio": (fb[-1] / fb0) if fb and fb0 else None, "converged_cycle": converged,
           "wall_s": round(wall, 4), "steps_per_s": round(steps / wall, 1) if wall > 0 else None,
           "diverged": reason is not None}
    if reason:
        out["diverged_reason"] = f"seed {seed}, cycle {len(rows) + 1}: {reason}"
    return out


def stabilization_errors(exp: Experiment, traces: dict[str, np.ndarray]) -> dict[str, float]:
    """Max deviation of each stabilized quantity from its target over the last cycle, in [rad],
    for the system (``<joint>_system``) and the forward trajectory (``<joint>_forward``)."""
    out = {}
    for i, name in enumerate(exp.joints):
        if not exp.law.stabilizing[i]:
            continue
        for kind in ("system", "forward"):
            y = exp.law.quantity(traces[f"last_q_{kind}"])[:, i]
            out[f"{name}_{kind}"] = float(np.abs(wrap(y - exp.law.targets[i])).max())
    return out
