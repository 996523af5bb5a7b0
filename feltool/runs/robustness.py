"""Robustness scores of the learners: each a sweep over one disturbance of the plant.

A *scenario* is one disturbance (``disturbances:``, see :mod:`feltool.plant.disturbances`, or the
motion's period) and a range of values of it. At each value every learner learns from scratch
with the disturbance applied from the first cycle; the value counts as *reached* when on every
seed the run did not diverge and the error signal's mean |feedback| over the last
:data:`TAIL` cycles is below :data:`GOAL` (5 %) of the first cycle's. The learner's score in the
scenario is the fraction of the range's values that are reached -- the style of the double
pendulum benchmark's robustness scores, applied to learners instead of controllers.

``feltool robustness CONFIG`` runs every learner x scenario (default ranges in
:data:`SCENARIOS`, scaled to the config where they are relative; a physical walker's in
:data:`WALKER_SCENARIOS`) and writes ``robustness.json`` and ``robustness.csv``. A physical
walker that stops walking (a contact violation or a fall) counts as not reaching the goal, like
a diverged run. A scenario that does not apply to a robot (a walker's period: its steps are
timed by its mechanics) gets no score and its reason.
"""

from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feltool.files import atomic_write

GOAL = 0.05  # the goal: feedback below 5 % of the first cycle's


TAIL = 5  # cycles averaged at the end of a run


LEARNERS = ("gradient", "gauss_newton", "ilc_p", "ilc_norm_optimal", "feedback_only")


@dataclass(frozen=True)
class Scenario:
    """One disturbance and its range.

    Attributes:
        name: Short name (``noise_q``).
        path: The config field it sets (``period`` scales ``period_s``).
        values: The range, nominal value first.
        unit: Unit of the values.
        description: What it does to the plant.
        not_applicable: Why the scenario has no meaning for the robot (no runs, no score), or
            None.
    """

    name: str
    path: str
    values: tuple[float, ...]
    unit: str
    description: str
    not_applicable: str | None = None

    @property
    def nominal(self) -> float:
        """The undisturbed value: 1 for a scale factor, else 0."""
        return 1.0 if self.unit == "x" else 0.0


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("noise_q", "disturbances.measurement_noise.q",
             (0.0, 0.0005, 0.001, 0.002, 0.005, 0.01), "rad",
             "Gaussian noise on the measured joint angles (sigma)"),
    Scenario("noise_v", "disturbances.measurement_noise.v",
             (0.0, 0.005, 0.01, 0.02, 0.05, 0.1), "rad/s",
             "Gaussian noise on the measured joint velocities (sigma)"),
    Scenario("torque_noise", "disturbances.torque_noise",
             (0.0, 0.05, 0.1, 0.2, 0.5, 1.0), "N m",
             "Gaussian noise on every applied torque (sigma)"),
    Scenario("delay", "disturbances.input_delay_steps", (0, 1, 2, 3, 5, 8), "steps",
             "the plant receives each commanded torque this many steps late"),
    Scenario("mass", "disturbances.model_error.mass_scale",
             (1.0, 0.5, 0.75, 1.25, 1.5, 2.0), "x",
             "the plant's masses and inertias scaled (known model unchanged)"),
    Scenario("length", "disturbances.model_error.length_scale",
             (1.0, 0.8, 0.9, 1.1, 1.2, 1.4), "x",
             "the plant's lengths scaled (known model unchanged)"),
    Scenario("period", "period", (1.0, 0.6, 0.8, 1.2, 1.5, 2.0), "x",
             "the motion's period scaled (rounded to whole samples), gains and rates kept"),
)}


# A physical walker's ranges (five-link walker: K_P 1500 on the pitch, 300 on the joints, 500
# Hz): noise and torque ranges from no effect up to a noise-driven feedback of several N m (5 %
# of a perturbed first cycle's ~20 N m is ~1 N m); delay in control steps as on the arm
# (2-16 ms at 500 Hz); the model-error scales as on the arm.
WALKER_SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("noise_q", SCENARIOS["noise_q"].path, (0.0, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3), "rad",
             "Gaussian noise on the measured pitch and joint angles (sigma); the base's position "
             "from the stance leg's kinematics"),
    Scenario("noise_v", SCENARIOS["noise_v"].path, (0.0, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2), "rad/s",
             "Gaussian noise on the measured pitch and joint velocities (sigma); the base's from "
             "the stance leg's kinematics"),
    Scenario("torque_noise", SCENARIOS["torque_noise"].path, (0.0, 0.03, 0.1, 0.3, 1.0, 3.0),
             "N m", "Gaussian noise on every applied motor torque (sigma)"),
    SCENARIOS["delay"], SCENARIOS["mass"],
    Scenario("length", SCENARIOS["length"].path, SCENARIOS["length"].values, "x",
             "the plant's lengths scaled, feet included (known model unchanged); the walker "
             "starts with its stance foot on the ground"),
    Scenario("period", "period", (), "x", SCENARIOS["period"].description,
             "a physical walker's steps end at touchdown and its phase follows its centre of "
             "mass (walking.phase: mechanical): the period is not a setting but a result of "
             "the designed gait; a different speed is a different design (feltool gait)"),
)}


def scenarios_for(raw: dict[str, Any]) -> dict[str, Scenario]:
    """The default scenarios of a raw config: a physical walker's (``walking.feet``), else the
    arms'."""
    walking = raw.get("walking") or {}
    return WALKER_SCENARIOS if walking.get("feet") else SCENARIOS


def overrides_for(raw: dict[str, Any], scenario: Scenario, value: float) -> list[str]:
    """The ``--set`` overrides that put a raw config at ``value`` of ``scenario``."""
    if scenario.path == "period":
        rate = float((raw.get("sim") or {}).get("rate_hz", 100.0))
        steps = max(2, int(round(value * float(raw["period_s"]) * rate)))
        return [f"period_s={steps / rate!r}"]
    if scenario.path.endswith("input_delay_steps"):
        return [f"{scenario.path}={int(value)}"]
    return [f"{scenario.path}={value!r}"]


def reached(rows: list[dict], diverged: bool) -> tuple[bool, float | None]:
    """Whether a run reached the goal, and its tail / first-cycle feedback ratio."""
    if not rows:
        return False, None
    fb = np.array([r["fb_abs_mean_error"] for r in rows])
    ratio = float(fb[-TAIL:].mean() / fb[0]) if fb[0] > 0 else None
    return (not diverged and ratio is not None and ratio < GOAL), ratio


def seed_outcome(result) -> dict[str, Any]:
    """One seed's entry of a point: whether it reached the goal, its tail ratio, whether it
    stopped, its cycles and wall time [s]."""
    diverged = result.summary["diverged"]
    ok, ratio = reached(result.rows, diverged)
    return {"seed": result.seed, "reached": ok, "fb_ratio_tail": ratio, "diverged": diverged,
            "cycles": len(result.rows), "wall_s": result.summary["wall_s"]}


def robustness(raw: dict[str, Any], source: Path | None, learners: list[str],
               scenarios: list[Scenario], seeds: list[int], cycles: int,
               learner_overrides: dict[str, list[str]] | None = None,
               log=None, jobs: int = 1) -> dict[str, Any]:
    """Every learner x scenario: per value the seeds' outcomes, and the score.

    A learner's undisturbed point (every scenario at its nominal value) is run once and shared
    by its scenarios. A walker's Poincare analysis is left out (it does not enter the score).

    Args:
        raw: The experiment's raw config mapping.
        learner_overrides: Extra ``--set`` overrides per learner (its tuned settings).
        log: A stream for one progress line per point, or None.
        jobs: Seeds run at the same time (processes).

    Returns:
        ``{"goal": GOAL, "tail": TAIL, "seeds", "cycles", "scenarios": {name: {...}},
        "scores": {learner: {scenario: score or None}}, "points": [...]}``.
    """
    todo = points_to_run(raw, learners, scenarios, learner_overrides)
    done = _run_points(raw, source, todo, seeds, cycles, log, jobs)
    points, scores = [], {}
    for learner in learners:
        scores[learner] = {}
        for sc in scenarios:
            if sc.not_applicable is not None:
                scores[learner][sc.name] = None
                continue
            hits = []
            for value in sc.values:
                per_seed = done[_point_key(raw, learner, sc, value)]
                ok = all(p["reached"] for p in per_seed)
                hits.append(ok)
                points.append({"learner": learner, "scenario": sc.name, "value": value,
                               "reached": ok, "seeds": per_seed})
            scores[learner][sc.name] = sum(hits) / len(hits)
    return {"goal": GOAL, "tail": TAIL, "seeds": seeds, "cycles": cycles,
            "scenarios": {s.name: {"path": s.path, "values": list(s.values), "unit": s.unit,
                                   "description": s.description,
                                   "not_applicable": s.not_applicable} for s in scenarios},
            "scores": scores, "points": points}


def points_to_run(raw: dict[str, Any], learners: list[str], scenarios: list[Scenario],
                  learner_overrides: dict[str, list[str]] | None = None
                  ) -> dict[tuple, list[str]]:
    """Every point to learn at, ``(learner, scenario or "nominal", value)`` -> its ``--set``
    overrides. The scenarios that the raw config leaves at their nominal value share one
    undisturbed point per learner (the config as it is); a scenario the config itself sets
    (e.g. a ``disturbances:`` block with torque noise) has its own nominal point, where only
    that disturbance is off."""
    learner_overrides = learner_overrides or {}
    common = ["walking.poincare=false"] if raw.get("walking") else []
    todo: dict[tuple, list[str]] = {}
    for learner in learners:
        for sc in scenarios:
            for value in sc.values if sc.not_applicable is None else ():
                todo.setdefault(_point_key(raw, learner, sc, value),
                                [f"learning.update={learner}", *common,
                                 *learner_overrides.get(learner, []),
                                 *overrides_for(raw, sc, value)])
    return todo


def _point_key(raw: dict[str, Any], learner: str, sc: Scenario, value: float) -> tuple:
    shared = value == sc.nominal and _config_value(raw, sc) == sc.nominal
    return (learner, "nominal", 0.0) if shared else (learner, sc.name, value)


def _config_value(raw: dict[str, Any], sc: Scenario) -> float:
    """The raw config's own value of a scenario (its nominal value where the config is silent;
    the period scenario scales the config's period: nominal)."""
    node: Any = raw
    for part in sc.path.split(".") if sc.path != "period" else ():
        node = node.get(part) if isinstance(node, dict) else None
        if node is None:
            break
    return sc.nominal if node is None or isinstance(node, dict) else float(node)


def _run_points(raw, source, todo: dict[tuple, list[str]], seeds, cycles, log, jobs: int
                ) -> dict[tuple, list[dict]]:
    """Every point's seeds as tasks of :func:`feltool.runs.runner.execute` (``jobs`` processes; a
    stop request ends them as a run's seeds end); one progress line per finished point."""
    import copy

    from feltool.config.files import apply_overrides
    from feltool.runs.executors import Task
    from feltool.runs.runner import execute

    keys = list(todo)
    where = str(source) if source is not None else None
    tasks = [Task(str(i), apply_overrides(copy.deepcopy(raw), todo[key]), where, seed, cycles)
             for i, key in enumerate(keys) for seed in seeds]
    found: dict[tuple, dict[int, dict]] = {key: {} for key in keys}
    done = {}
    for task, result in execute(tasks, jobs, None, "robustness", len(tasks) * cycles,
                                show_progress=False):
        key = keys[int(task.key)]
        found[key][task.seed] = seed_outcome(result)
        if len(found[key]) < len(seeds):
            continue
        done[key] = per_seed = [found[key][seed] for seed in seeds]
        if log is not None:
            learner, name, value = key
            ok = all(p["reached"] for p in per_seed)
            ratios = ", ".join("stopped" if p["diverged"] else f"{p['fb_ratio_tail']:.3g}"
                               for p in per_seed)
            print(f"robustness: {learner} {name}={value:g}: "
                  f"{'reached' if ok else 'not reached'} ({ratios})", file=log, flush=True)
    return done


def format_scores(result: dict[str, Any]) -> str:
    """The scores as a Markdown table (learners x scenarios; n/a where a scenario does not
    apply, the mean over those that do)."""
    names = list(result["scenarios"])
    lines = ["| learner | " + " | ".join(names) + " | mean |",
             "|---|" + "---:|" * (len(names) + 1)]
    for learner, row in result["scores"].items():
        vals = [row[n] for n in names]
        scored = [v for v in vals if v is not None]
        lines.append(f"| {learner} | " + " | ".join("n/a" if v is None else f"{v:.2f}"
                                                    for v in vals)
                     + f" | {np.mean(scored):.2f} |")
    return "\n".join(lines)


def write(result: dict[str, Any], out: Path) -> None:
    """``robustness.json`` (everything) and ``robustness.csv`` (one row per point and seed)."""
    atomic_write(out / "robustness.json", json.dumps(result, indent=1))
    fh = io.StringIO(newline="")
    w = csv.writer(fh)
    w.writerow(["learner", "scenario", "value", "seed", "reached", "fb_ratio_tail",
                "diverged", "wall_s"])
    for p in result["points"]:
        for s in p["seeds"]:
            w.writerow([p["learner"], p["scenario"], p["value"], s["seed"], s["reached"],
                        s["fb_ratio_tail"], s["diverged"], s["wall_s"]])
    atomic_write(out / "robustness.csv", fh.getvalue())
