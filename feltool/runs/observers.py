"""What watches a seed's learning cycles: its record (metric rows, parameter history, traces,
counters, then the summary), its checkpoints, and the caller's progress and live view.

:func:`feltool.runs.seed.run_seed` drives the cycles and hands every finished cycle to its observers
(:class:`SeedObserver`); none of them changes what a cycle computes.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from feltool.control.closed_loop import CycleLog
from feltool.control.feedback import wrap
from feltool.engines.outcome import CycleOutcome, SeedState
from feltool.runs import checkpoint as checkpoints
from feltool.runs.checkpoint import Checkpointer, Interrupted

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment


class SeedObserver(Protocol):
    """Watches a seed's cycles."""

    def after_cycle(self, cycle: int, out: CycleOutcome, state: SeedState,
                    row: dict[str, float]) -> None:
        """After a cycle that did not stop the seed: its outcome, the seed's state after it
        and its metric row."""


class SeedRecord:
    """A seed's record: metric rows, the learned parameters' history, the first and last
    cycles' traces (and the desired motion across motion events), and the counters of its
    summary (control steps, impacts, limit hits, a physical walker's contact metrics, the
    time inside the cycles).

    Args:
        exp: The experiment.
        seed: The seed.
        state: The seed's state before its first cycle.
    """

    def __init__(self, exp: Experiment, seed: int, state: SeedState):
        self.exp, self.seed = exp, seed
        self.rows: list[dict[str, float]] = []
        self.history = [state.theta[exp.learner.learned].copy()]
        self.model_history = [state.theta_m] if exp.model_learner is not None else []
        self.traces: dict[str, np.ndarray] = {}
        self.steps, self.impacts = 0, {"guard": 0, "clock": 0}
        self.hits = [np.zeros(len(exp.joints), int), np.zeros(len(exp.joints), int)]
        self.checked, self.contacts = False, []
        self.loop_s, self.wall_before = 0.0, 0.0
        self.started = time.perf_counter()
        self.last: CycleOutcome | None = None
        self._switches = {ev.cycle for _, ev in exp.config.motion_events}

    def count(self, out: CycleOutcome, loop_s: float) -> None:
        """Count a cycle's steps, impacts and limit hits (also of the cycle that stops the
        seed), and ``loop_s`` [s] spent in it."""
        self.loop_s += loop_s
        self.steps += out.cycle.n if out.cycle is not None else self.exp.primitives.n_steps
        for _, by_guard, _ in out.impacts:
            self.impacts["guard" if by_guard else "clock"] += 1
        if out.limit_hits is not None:
            self.checked = True
            self.hits[0] += out.limit_hits[0]
            self.hits[1] += out.limit_hits[1]

    def row(self, cycle: int, out: CycleOutcome, theta: np.ndarray,
            theta_m: np.ndarray | None) -> dict[str, float]:
        """The cycle's metric row (``theta``, ``theta_m``: the parameters it ran with)."""
        row = metrics_row(self.exp, self.seed, cycle, out, theta)
        if theta_m is not None:
            row["model_param_norm"] = float(np.linalg.norm(theta_m))
        return row

    def after_cycle(self, cycle: int, out: CycleOutcome, state: SeedState,
                    row: dict[str, float]) -> None:
        self.rows.append(row)
        if out.contact is not None:
            self.contacts.append(out.contact)
        if cycle == 1:
            self.traces.update(cycle_trace("first", *out.trace()))
        before = self.last
        if cycle in self._switches and before is not None and before.desired is not None:
            self.traces.update(switch_trace(cycle, before, out, self.exp.config.dt))
        self.last = out
        self.history.append(state.theta[self.exp.learner.learned].copy())
        if self.exp.model_learner is not None:
            self.model_history.append(state.theta_m)

    @property
    def wall_s(self) -> float:
        """The seed's time so far [s] (with the time before a checkpoint it resumed from)."""
        return self.wall_before + time.perf_counter() - self.started

    # -- checkpoints ------------------------------------------------------------------------------
    def save(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """The record's arrays and metadata for a checkpoint."""
        arrays = {"history": np.array(self.history)}
        if self.exp.model_learner is not None:
            arrays["model_history"] = np.array(self.model_history)
        arrays.update({f"trace_{k}": val for k, val in self.traces.items()})
        meta = {"rows": self.rows, "wall_s": self.wall_s, "impacts": self.impacts,
                "contacts": self.contacts, "steps": self.steps, "loop_s": self.loop_s,
                "limit_hits": [h.tolist() for h in self.hits] if self.checked else None}
        return arrays, meta

    def restore(self, saved: dict[str, Any]) -> None:
        """Continue from a checkpoint (:meth:`save`)."""
        self.rows, self.wall_before = saved["rows"], saved["wall_s"]
        self.loop_s = saved.get("loop_s", self.wall_before)
        self.history = list(saved["history"])
        if self.exp.model_learner is not None:
            self.model_history = list(saved["model_history"])
        self.traces = {k[len("trace_"):]: v for k, v in saved.items() if k.startswith("trace_")}
        self.steps = int(saved.get("steps", self.exp.primitives.n_steps * len(self.rows)))
        self.impacts.update(saved.get("impacts", {}))
        self.contacts = list(saved.get("contacts", []))
        if saved.get("limit_hits") is not None:
            self.checked = True
            self.hits = [np.array(h, int) for h in saved["limit_hits"]]

    # -- the end ----------------------------------------------------------------------------------
    def summary(self, state: SeedState, reason: str | None, cycles: int, compile_s: float,
                failed: CycleOutcome | None) -> dict[str, Any]:
        """The seed's entry of summary.json (``failed``: the cycle that stopped the seed)."""
        exp, cfg, rows = self.exp, self.exp.config, self.rows
        if self.last is not None:
            self.traces.update(cycle_trace("last", *self.last.trace()))
        summary = seed_summary(exp, self.seed, rows, reason, self.wall_s, self.steps,
                               self.loop_s, compile_s)
        summary["cycles_planned"] = cycles
        walker = exp.hybrid is not None and exp.hybrid.walker is not None
        if cfg.walking is not None and cfg.walking.physical:
            summary["walking"] = walking_summary(
                exp, rows, self.contacts, failed.contact if reason and failed else None, reason)
        elif walker:
            summary["walking"] = pinned_walking_summary(exp, self.last, self.traces,
                                                        self.impacts, reason)
        summary["learned_feedback"] = learned_feedback(exp, rows)
        summary["limits"] = ({"joint_limit_steps": nonzero(exp.joints, self.hits[0]),
                              "torque_limit_steps": nonzero(exp.joints, self.hits[1])}
                             if self.checked else "not checked")
        if walker:
            summary["guard_impacts"] = self.impacts["guard"]
            summary["clock_impacts"] = self.impacts["clock"]
        if exp.hybrid is not None and rows and reason is None and cfg.walking is not None \
                and cfg.walking.poincare:
            from feltool.gait.poincare import poincare

            summary["poincare"] = poincare(exp, state.theta, state.q, state.v, state.plant,
                                           theta_m=state.theta_m)
        return summary

    def parameters(self, state: SeedState, run_cycle) -> dict[str, np.ndarray]:
        """params/seed-<n>.npz: the learned parameters and their history (and an ILC's
        learned sequence, the model correction's parameters)."""
        exp = self.exp
        params = exp.split_parameters(state.theta)
        if hasattr(run_cycle, "extra_params"):  # an ILC's learned torque sequence
            params.update(run_cycle.extra_params())
        hist = np.array(self.history)
        for name in exp.learned_joints:
            sl = exp.primitives.slices[exp.joints.index(name)]
            cols = [c for c, p in enumerate(exp.learner.learned) if sl.start <= p < sl.stop]
            params[f"{name}.weights_history"] = hist[:, cols[:-1]]
            params[f"{name}.goal_history"] = hist[:, cols[-1]]
        if exp.model_learner is not None:
            params["model.theta"] = state.theta_m
            params["model.theta_history"] = np.array(self.model_history)
        return params


class SeedCheckpoints:
    """Saves the seed's state and record every ``checkpointer.every`` cycles (at most once
    per ``min_interval_s``) and when a stop is requested, then raises
    :class:`~feltool.runs.checkpoint.Interrupted`; keeps the final state so that a resume may add
    cycles.

    Args:
        checkpointer: Where and how often.
        record: The seed's record (saved with the state).
        run_cycle: The cycle runner (its own state: RMP states, an ILC's sequence, the
            motion).
        cycles: The cycles the seed is to run.
        safeguard: The seed's :class:`~feltool.runs.safeguard.Safeguard` (its step scale and
            the step it would undo are saved too), or None.
    """

    def __init__(self, checkpointer: Checkpointer, record: SeedRecord, run_cycle, cycles: int,
                 safeguard=None):
        self.checkpointer, self.record = checkpointer, record
        self.run_cycle, self.cycles = run_cycle, cycles
        self.safeguard = safeguard  # (feltool.runs.safeguard.Safeguard: its own state)

    def restore(self) -> tuple[int, SeedState] | None:
        """The last checkpoint (what :meth:`save` wrote) put back: the record's rows and the
        cycle runner's own state; returns its cycle and the seed's state, or None without
        one."""
        saved = self.checkpointer.load()
        if saved is None:
            return None
        self.record.restore(saved)
        if "rmp_x" in saved:
            for key, x, S in zip(saved["rmp_keys"], saved["rmp_x"], saved["rmp_S"]):
                self.run_cycle.rmp_states[int(key)] = (x.copy(), S.copy())
        if hasattr(self.run_cycle, "restore_state"):  # ILC sequence, disturbance state, motion
            self.run_cycle.restore_state(saved)
        if self.safeguard is not None:
            self.safeguard.restore(saved)
        return saved["cycle"], SeedState(saved["theta"], saved["q"], saved["v"],
                                         saved.get("model_theta"))

    def save(self, cycle: int, state: SeedState) -> None:
        arrays, meta = self.record.save()
        arrays.update({"theta": state.theta, "q": state.q, "v": state.v})
        if state.theta_m is not None:
            arrays["model_theta"] = state.theta_m
        if hasattr(self.run_cycle, "extra_state"):
            arrays.update(self.run_cycle.extra_state())
        if self.safeguard is not None:
            arrays.update(self.safeguard.save())
        states = getattr(self.run_cycle, "rmp_states", None)
        if states is not None:
            keys = sorted(states)
            arrays["rmp_keys"] = np.array(keys)
            arrays["rmp_x"] = np.array([states[k][0] for k in keys])
            arrays["rmp_S"] = np.array([states[k][1] for k in keys])
        self.checkpointer.save(cycle, arrays, meta)

    def after_cycle(self, cycle: int, out: CycleOutcome, state: SeedState,
                    row: dict[str, float]) -> None:
        stop = checkpoints.stop_requested()
        if self.checkpointer.due(cycle) or stop:
            self.save(cycle, state)
            if stop and cycle < self.cycles:
                raise Interrupted(f"seed {self.record.seed} stopped after cycle {cycle} "
                                  "(checkpoint saved)")

    def finish(self, state: SeedState, reason: str | None) -> None:
        """The final state stays (a resume may add cycles); a diverged seed leaves none."""
        rows = self.record.rows
        if reason is None and rows and self.checkpointer.saved_cycle != rows[-1]["cycle"]:
            self.save(rows[-1]["cycle"], state)
        elif reason is not None:
            self.checkpointer.clear()


class Callback:
    """A caller's function after every cycle: ``progress(cycle, fb)``, or with
    ``with_trace`` the live view's ``on_cycle(cycle, log, Qd, fb)`` (fb: the error signal's
    mean |feedback| [N m])."""

    def __init__(self, fn, with_trace: bool = False):
        self.fn, self.with_trace = fn, with_trace

    def after_cycle(self, cycle: int, out: CycleOutcome, state: SeedState,
                    row: dict[str, float]) -> None:
        if self.with_trace:
            self.fn(cycle, *out.trace(), row["fb_abs_mean_error"])
        else:
            self.fn(cycle, row["fb_abs_mean_error"])


def metrics_row(exp: Experiment, seed: int, cycle: int, out: CycleOutcome,
                theta: np.ndarray) -> dict[str, float]:
    """The cycle's row of metrics.csv (``theta``: the parameters the cycle ran with)."""
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
                    "max_impulse_ratio", "impact_energy_lost", "step_length", "distance",
                    "stabilized_rms"):
            row[key] = out.contact[key]
    return row


def cycle_trace(which: str, log: CycleLog, Qd: np.ndarray) -> dict[str, np.ndarray]:
    """A cycle's recorded trace (``first`` or ``last``): system and forward angles, feedback."""
    return {f"{which}_q_system": log.q, f"{which}_q_forward": Qd, f"{which}_u_fb": log.u_fb}


def switch_trace(cycle: int, before: CycleOutcome, after: CycleOutcome,
                 dt: float) -> dict[str, np.ndarray]:
    """The desired trajectory across a motion event at the start of ``cycle``: the cycle
    before it and the cycle it starts, one after the other (``switch<cycle>_t`` [s] from the
    event, ``_q_forward`` [rad], ``_v_forward`` [rad/s])."""
    (Qb, Vb, _), (Qa, Va, _) = before.desired_motion(), after.desired_motion()
    Q, V = np.concatenate([Qb, Qa]), np.concatenate([Vb, Va])
    t = (np.arange(len(Q)) - len(Qb)) * dt
    return {f"switch{cycle}_t": t, f"switch{cycle}_q_forward": Q, f"switch{cycle}_v_forward": V}


def seed_summary(exp: Experiment, seed: int, rows, reason: str | None, wall: float,
                  steps: int, loop: float, compile_s: float) -> dict[str, Any]:
    """The seed's entry of summary.json. ``wall_s``: the seed's whole time [s] (its cycles and
    what observes them: metrics, traces, checkpoints, progress); ``loop_s``: inside the learning
    cycles only, which ``steps_per_s`` counts; ``compile_s``: building (the compiled engine:
    generating and compiling, or loading) the cycle engine before the first cycle."""
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
           "wall_s": round(wall, 4), "loop_s": round(loop, 6), "compile_s": round(compile_s, 4),
           "steps": steps, "steps_per_s": round(steps / loop, 1) if loop > 0 else None,
           "diverged": reason is not None}
    change = exp.config.world_change_cycle
    if change is not None and len(fb) >= change:  # the feedback from the world's change on
        out.update(change_cycle=change, fb_change=fb[change - 1],
                   fb_ratio_change=fb[-1] / fb[change - 1] if fb[change - 1] else None)
    if reason:
        out["diverged_reason"] = f"seed {seed}, cycle {len(rows) + 1}: {reason}"
    return out


def nonzero(names: list[str], counts: np.ndarray) -> dict[str, int]:
    """``{name: count}`` of the nonzero counts."""
    return {name: int(c) for name, c in zip(names, counts) if c}


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


__all__ = ["Callback", "SeedCheckpoints", "SeedObserver", "SeedRecord", "learned_feedback",
           "metrics_row", "pinned_walking_summary", "seed_summary", "stabilization_errors",
           "walking_summary"]
