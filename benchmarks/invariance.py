"""Do the shipped rates mean the same at any control rate, period and basis size? (issue 29)

    nice python benchmarks/invariance.py [--seeds 0-19] [--configs two_link_standard,...]
        [--write docs/results.md] [--cache runs/invariance.json]

For each config (the standard arm, the human arm, UR5, Panda) and each setting changed one at
a time from the shipped config -- ``sim.rate_hz`` in {50, 100, 200, 500, 1000, 2000},
``period_s`` in {0.5, 1.0, 1.2345, 2.0}, ``primitives.basis`` in {5, 10, 20, 40, 80}, and on
the standard arm the corner rate 2000 / period 1.2345 / basis 80 together -- it runs every seed
for 150 cycles with the shipped rates and nothing else changed (compiled engine) and prints,
per point: seeds converged (below 5 % of the first cycle's error feedback for good), diverged,
the mean cycles-to-5 % and its ratio to the shipped config's (the acceptance: 20/20 within
x1.5), and the safeguard's rejected steps. A setting the config checks refuse (e.g. a control
rate too coarse for the gains: what ``feltool check`` refuses, feltool.experiment.checks) is
reported as refused, with the
reason's first words. ``--write`` puts the table into the file between the markers
``<!-- invariance:start -->`` and ``<!-- invariance:end -->``. Results are cached per point in
``--cache`` (a JSON file), so an interrupted grid continues where it stopped.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from feltool.errors import FeltoolError
from feltool.experiment.checks import experiment_problems
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ["two_link_standard", "two_link_human_arm", "ur5_wrist_level", "panda_hand_level"]
AXES = {"sim.rate_hz": [50, 100, 200, 500, 1000, 2000], "period_s": [0.5, 1.0, 1.2345, 2.0],
        "primitives.basis": [5, 10, 20, 40, 80]}
CORNER = {"sim.rate_hz": 2000, "period_s": 1.2345, "primitives.basis": 80}
CYCLES = 150
START, END = "<!-- invariance:start -->", "<!-- invariance:end -->"


def points(config: str) -> list[tuple[str, dict]]:
    """``(label, overrides)`` of the grid of ``config``: the shipped config first."""
    out = [("shipped", {})]
    for key, values in AXES.items():
        out += [(f"{key}={v:g}", {key: v}) for v in values]
    if config == "two_link_standard":
        out.append(("corner " + ", ".join(f"{k}={v:g}" for k, v in CORNER.items()), CORNER))
    return out


def run_point(config: str, over: dict, seeds: list[int]) -> dict:
    """Every seed of one point: converged, diverged, cycles-to-5 %, rejected steps."""
    sets = [f"{k}={v}" for k, v in over.items()] + ["backend=compiled"]
    try:
        exp = load_experiment(ROOT / "configs" / f"{config}.yaml", sets)
    except FeltoolError as err:
        return {"refused": str(err).splitlines()[0][:160]}
    problems = experiment_problems(exp)  # what `feltool check` refuses
    if problems:
        return {"refused": f"{problems[0][0]}: {problems[0][1]}"[:160]}
    t0 = time.perf_counter()
    conv, div, rejected, reasons = [], 0, [], []
    for seed in seeds:
        s = run_seed(exp, seed, CYCLES).summary
        div += bool(s["diverged"])
        if s["diverged"]:
            reasons.append(s.get("diverged_reason", "")[:160])
        conv.append(s["converged_cycle"])
        rejected.append(int(s.get("rejected_steps", 0)))
    done = [c for c in conv if c is not None]
    return {"seeds": len(seeds), "converged": len(done), "diverged": div,
            "mean_cycles": float(np.mean(done)) if done else None,
            "max_cycles": int(max(done)) if done else None,
            "rejected": int(sum(rejected)), "seeds_rejecting": int(sum(r > 0 for r in rejected)),
            "reasons": reasons[:2], "wall_s": round(time.perf_counter() - t0, 1)}


def table(results: dict, configs: list[str]) -> str:
    """The markdown table of the grid."""
    lines = ["| config | setting | converged | diverged | mean cycles to 5 % (max) | "
             "vs shipped | rejected steps (seeds) |", "|---|---|---|---|---|---|---|"]
    for config in configs:
        base = results.get(config, {}).get("shipped", {}).get("mean_cycles")
        for label, _ in points(config):
            r = results.get(config, {}).get(label)
            if r is None:
                continue
            if "refused" in r:
                lines.append(f"| {config} | {label} | refused: {r['refused']} | | | | |")
                continue
            mean = r["mean_cycles"]
            ratio = f"x{mean / base:.2f}" if mean and base else "n/a"
            ok = r["converged"] == r["seeds"] and mean and base and mean <= 1.5 * base
            lines.append(f"| {config} | {label} | {r['converged']}/{r['seeds']} | {r['diverged']} "
                         f"| {mean:.1f} ({r['max_cycles']}) | {ratio}{'' if ok else ' **fails**'} "
                         f"| {r['rejected']} ({r['seeds_rejecting']}) |" if mean is not None else
                         f"| {config} | {label} | {r['converged']}/{r['seeds']} | {r['diverged']} "
                         f"| never | n/a **fails** | {r['rejected']} ({r['seeds_rejecting']}) |")
    return "\n".join(lines)


def write(path: Path, text: str) -> None:
    """Replace the text between the markers in ``path`` (append the markers if missing)."""
    doc = path.read_text()
    block = f"{START}\n{text}\n{END}"
    if START in doc and END in doc:
        doc = doc[:doc.index(START)] + block + doc[doc.index(END) + len(END):]
    else:
        doc = doc.rstrip("\n") + "\n\n" + block + "\n"
    path.write_text(doc)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-19", help="seeds, a-b (default 0-19)")
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--write", type=Path, default=None, help="markdown file to put the table in")
    ap.add_argument("--cache", type=Path, default=ROOT / "runs" / "invariance.json")
    ap.add_argument("--points", default=None, help="run only the points whose label contains "
                    "one of these comma-separated strings, the corner only with 'corner' (the table "
                    "shows every cached point)")
    args = ap.parse_args(argv)
    a, _, b = args.seeds.partition("-")
    seeds = list(range(int(a), int(b or a) + 1))
    configs = args.configs.split(",")
    results = json.loads(args.cache.read_text()) if args.cache.exists() else {}
    args.cache.parent.mkdir(parents=True, exist_ok=True)
    for config in configs:
        for label, over in points(config):
            key = results.setdefault(config, {})
            if label in key and key[label].get("seeds", len(seeds)) == len(seeds):
                continue
            wanted = args.points.split(",") if args.points else []
            if wanted and label != "shipped" and not (
                    "corner" in wanted if label.startswith("corner") else
                    any(p in label for p in wanted)):
                continue
            key[label] = run_point(config, over, seeds)
            args.cache.write_text(json.dumps(results, indent=1))
            print(config, label, json.dumps(key[label]), flush=True)
    text = table(results, configs)
    print(text)
    if args.write is not None:
        write(args.write, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
