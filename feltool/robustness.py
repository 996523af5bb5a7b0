r"""Robustness scores of the learners: each a sweep over one disturbance of the plant.

A *scenario* is one disturbance (``disturbances:``, see :mod:`feltool.disturbances`, or the
motion's period) and a range of values of it. At each value every learner learns from scratch
with the disturbance applied from the first cycle; the value counts as *reached* when on every
seed the run did not diverge and the error signal's mean |feedback| over the last
:data:`TAIL` cycles is below :data:`GOAL` (5 %) of the first cycle's. The learner's score in the
scenario is the fraction of the range's values that are reached -- the style of the double
pendulum benchmark's robustness scores, applied to learners instead of controllers.

``feltool robustness CONFIG`` runs every learner x scenario (default ranges in
:data:`SCENARIOS`, scaled to the config where they are relative) and writes
``robustness.json`` and ``robustness.csv``.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feltool.errors import InputError

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
    """

    name: str
    path: str
    values: tuple[float, ...]
    unit: str
    description: str


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


def run_point(raw: dict[str, Any], source: Path | None, overrides: list[str], seeds: list[int],
              cycles: int) -> list[dict[str, Any]]:
    """Learn at one point of a scenario; one entry per seed."""
    import copy

    from feltool.config import apply_overrides
    from feltool.experiment import build_experiment, run_seed

    exp = build_experiment(apply_overrides(copy.deepcopy(raw), overrides), source=source)
    out = []
    for seed in seeds:
        t0 = time.perf_counter()
        res = run_seed(exp, seed, cycles=cycles)
        ok, ratio = reached(res.rows, res.summary["diverged"])
        out.append({"seed": seed, "reached": ok, "fb_ratio_tail": ratio,
                    "diverged": res.summary["diverged"], "cycles": len(res.rows),
                    "wall_s": round(time.perf_counter() - t0, 3)})
    return out


def robustness(raw: dict[str, Any], source: Path | None, learners: list[str],
               scenarios: list[Scenario], seeds: list[int], cycles: int,
               learner_overrides: dict[str, list[str]] | None = None,
               log=None) -> dict[str, Any]:
    """Every learner x scenario: per value the seeds' outcomes, and the score.

    Args:
        raw: The experiment's raw config mapping.
        learner_overrides: Extra ``--set`` overrides per learner (its tuned settings).
        log: A stream for one progress line per point, or None.

    Returns:
        ``{"goal": GOAL, "tail": TAIL, "seeds", "cycles", "scenarios": {name: {...}},
        "scores": {learner: {scenario: score}}, "points": [...]}``.
    """
    learner_overrides = learner_overrides or {}
    points, scores = [], {}
    for learner in learners:
        scores[learner] = {}
        for sc in scenarios:
            hits = []
            for value in sc.values:
                sets = [f"learning.update={learner}", *learner_overrides.get(learner, []),
                        *overrides_for(raw, sc, value)]
                per_seed = run_point(raw, source, sets, seeds, cycles)
                ok = all(p["reached"] for p in per_seed)
                hits.append(ok)
                points.append({"learner": learner, "scenario": sc.name, "value": value,
                               "reached": ok, "seeds": per_seed})
                if log is not None:
                    ratios = ", ".join("diverged" if p["diverged"] else f"{p['fb_ratio_tail']:.3g}"
                                       for p in per_seed)
                    print(f"robustness: {learner} {sc.name}={value:g}: "
                          f"{'reached' if ok else 'not reached'} ({ratios})", file=log, flush=True)
            scores[learner][sc.name] = sum(hits) / len(hits)
    return {"goal": GOAL, "tail": TAIL, "seeds": seeds, "cycles": cycles,
            "scenarios": {s.name: {"path": s.path, "values": list(s.values), "unit": s.unit,
                                   "description": s.description} for s in scenarios},
            "scores": scores, "points": points}


def format_scores(result: dict[str, Any]) -> str:
    """The scores as a Markdown table (learners x scenarios)."""
    names = list(result["scenarios"])
    lines = ["| learner | " + " | ".join(names) + " | mean |",
             "|---|" + "---:|" * (len(names) + 1)]
    for learner, row in result["scores"].items():
        vals = [row[n] for n in names]
        lines.append(f"| {learner} | " + " | ".join(f"{v:.2f}" for v in vals)
                     + f" | {np.mean(vals):.2f} |")
    return "\n".join(lines)


def write(result: dict[str, Any], out: Path) -> None:
    """``robustness.json`` (everything) and ``robustness.csv`` (one row per point and seed)."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "robustness.json").write_text(json.dumps(result, indent=1))
    with open(out / "robustness.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["learner", "scenario", "value", "seed", "reached", "fb_ratio_tail",
                    "diverged", "wall_s"])
        for p in result["points"]:
            for s in p["seeds"]:
                w.writerow([p["learner"], p["scenario"], p["value"], s["seed"], s["reached"],
                            s["fb_ratio_tail"], s["diverged"], s["wall_s"]])


def cmd_robustness(args: argparse.Namespace) -> int:
    """``feltool robustness CONFIG``: scores of every learner x scenario."""
    from feltool.cli import parse_seeds
    from feltool.config import apply_overrides, read_yaml
    from feltool.experiment import build_experiment, resolve_config_path

    path = resolve_config_path(args.config)
    raw = apply_overrides(read_yaml(path), list(args.set or []))
    exp = build_experiment(raw, source=path)  # bad input fails here, before any run
    learners = _names(args.learners, LEARNERS, "--learners")
    scenarios = [SCENARIOS[n] for n in _names(args.scenarios, tuple(SCENARIOS), "--scenarios")]
    ranges = _ranges(args.range or [])
    scenarios = [Scenario(s.name, s.path, ranges.get(s.name, s.values), s.unit, s.description)
                 for s in scenarios]
    seeds = parse_seeds(args.seeds) if args.seeds else exp.config.seed_list[:3]
    cycles = args.cycles or exp.config.sim.cycles
    out = args.out or Path("runs") / f"{exp.config.name}-robustness"
    if out.exists() and any(out.iterdir()):
        raise InputError(f"--out {out}: exists and is not empty; choose a new directory")
    result = robustness(raw, path, learners, scenarios, seeds, cycles,
                        log=None if args.quiet else sys.stderr)
    result["config"] = exp.config.name
    write(result, out)
    print(format_scores(result))
    print(f"\nscores: fraction of each range where every seed's feedback fell below "
          f"{GOAL:.0%} of its first cycle's; details in {out}/robustness.json")
    return 0


def _ranges(items: list[str]) -> dict[str, tuple[float, ...]]:
    """``--range NAME=V1,V2,...`` -> {NAME: (V1, V2, ...)}."""
    out = {}
    for item in items:
        name, _, values = item.partition("=")
        name = name.strip()
        if name not in SCENARIOS:
            raise InputError(f"--range {item}: unknown scenario '{name}'; choose from "
                             + ", ".join(SCENARIOS))
        try:
            out[name] = tuple(float(v) for v in values.split(",") if v.strip())
        except ValueError:
            raise InputError(f"--range {item}: the values must be numbers, e.g. "
                             f"{name}=1,1.5,2") from None
        if not out[name]:
            raise InputError(f"--range {item}: give at least one value")
    return out


def _names(spec: str | None, known: tuple[str, ...], option: str) -> list[str]:
    if not spec:
        return list(known)
    names = [s.strip() for s in spec.split(",") if s.strip()]
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise InputError(f"{option}: unknown {', '.join(bad) or 'empty list'}; choose from "
                         + ", ".join(known))
    return names


def add_command(sub, make_sub) -> None:
    """Register ``feltool robustness`` on the CLI's subparsers (``make_sub`` as cli._sub)."""
    p = make_sub(sub, "robustness", "score every learner's robustness to noise, delay, model "
                 "error and period changes",
                 "  feltool robustness two_link_standard --seeds 0-2 --cycles 150\n"
                 "  feltool robustness two_link_standard --learners gradient,ilc_p "
                 "--scenarios delay,mass --out runs/rob")
    p.add_argument("config", help="experiment YAML, or the name of a bundled config")
    p.add_argument("--learners", help=f"comma-separated, from {', '.join(LEARNERS)} (default all)")
    p.add_argument("--scenarios", help=f"comma-separated, from {', '.join(SCENARIOS)} "
                   "(default all)")
    p.add_argument("--range", action="append", metavar="NAME=V1,V2",
                   help="the values of one scenario instead of its default range (repeatable)")
    p.add_argument("--seeds", help="seeds per point, e.g. 0-2 (default: the config's first 3)")
    p.add_argument("--cycles", type=int, help="learning cycles per run (default: the config's)")
    p.add_argument("--out", type=Path, help="output directory, new or empty (default "
                   "runs/<name>-robustness)")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE",
                   help="override a config field (repeatable)")
    p.add_argument("--quiet", "-q", action="store_true", help="print only the scores")
    p.set_defaults(func=cmd_robustness)


__all__ = ["GOAL", "LEARNERS", "SCENARIOS", "Scenario", "add_command", "format_scores",
           "overrides_for", "reached", "robustness", "run_point", "write"]
