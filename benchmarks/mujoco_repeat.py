"""What of MuJoCo's feedback repeats from cycle to cycle (issue 28, acceptance 1(d)).

FEL learns a periodic feedforward: a function of the phase, the same in every cycle. It can
cancel only the part of the feedback that repeats. Each MuJoCo walker is run from its designed
gait for ``--cycles`` cycles twice, seed 0: with the designed feedforward held (nothing learned)
and learning from it (every motor and the torso, the *designed* start of
``benchmarks/walk_mujoco.py``). Over the last ``--last`` cycles each cycle's feedback is aligned
at its touchdowns (step by step, cut to the shortest step) and split into its mean over those
cycles (the repeating part, what a periodic feedforward could cancel) and the rest (what differs
from cycle to cycle). Printed per walker, in [N m] (the mean |feedback| per
control step, summed over the joints): cycle 1's feedback and the acceptance bound (0.15 of it),
the last cycles' feedback, its repeating and non-repeating parts, and the control steps at which
the last cycles' touchdowns came. Pinocchio's rigid five-link walker is the contrast: its walk
repeats, the non-repeating part is zero.

Usage: ``python benchmarks/mujoco_repeat.py [--cycles 150] [--last 20]``
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from walk_mujoco import overrides  # noqa: E402

from feltool.runs.experiments import load_experiment  # noqa: E402
from feltool.runs.seed import run_seed  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RUNS = [("five_link_walker_mujoco", "fixed"), ("five_link_walker_mujoco", "designed"),
        ("three_link_walker_mujoco", "fixed"), ("three_link_walker_mujoco", "designed"),
        ("five_link_walker", "fixed")]
START = {"fixed": "design held", "designed": "learning from the design"}


def summed(u_fb: np.ndarray) -> float:
    """Mean |feedback| per control step summed over the joints, in [N m] (last axis: joints)."""
    return float(np.abs(u_fb).mean(axis=-2).sum(axis=-1).mean())


def one(job: tuple[str, str, int, int]) -> dict:
    """Run ``name`` from its design (``start``: ``fixed`` holds it, ``designed`` learns from it);
    the last cycles' feedback split into its repeating and non-repeating parts."""
    name, start, cycles, last = job
    config = ROOT / "configs" / "gaits" / f"{name}.yaml"
    exp = load_experiment(config, overrides(config, start) + ["backend=pinocchio"])
    kept: list[list[np.ndarray]] = []
    touchdowns: set[tuple[int, ...]] = set()

    def on_cycle(cycle, log, Qd, fb):
        if cycle > cycles - last:
            at = [k for k, _, _ in log.impacts]
            bounds = [0] + at
            kept.append([log.u_fb[a:b] for a, b in zip(bounds[:-1], bounds[1:])])
            touchdowns.add(tuple(at))

    res = run_seed(exp, 0, cycles, on_cycle=on_cycle)
    row = {"walker": name, "start": start}
    walk = res.summary.get("walking") or {}
    if len(res.rows) < cycles or not walk.get("walked"):
        return row | {"fell": len(res.rows),
                      "why": walk.get("reason") or res.summary.get("reason")}
    n = [min(len(c[s]) for c in kept) for s in range(len(kept[0]))]
    F = np.stack([np.vstack([c[s][:n[s]] for s in range(len(n))]) for c in kept])
    repeating = F.mean(axis=0)
    return row | {"first": res.rows[0]["fb_abs_mean_error"], "last": summed(F),
                  "repeating": summed(repeating), "non_repeating": summed(F - repeating),
                  "touchdowns": sorted(touchdowns)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--last", type=int, default=20)
    args = ap.parse_args()
    print(f"| walker | feedback cycle 1 [N m] | 0.15 of it | last {args.last} of {args.cycles} "
          "cycles | repeating part | non-repeating part | touchdowns at control steps |")
    print("|---|---|---|---|---|---|---|")
    jobs = [(name, start, args.cycles, args.last) for name, start in RUNS]
    with ProcessPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(one, jobs))
    for r in results:
        name = f"{r['walker']}, {START[r['start']]}"
        if "fell" in r:
            print(f"| {name} | not walking in cycle {r['fell']}: {r['why']} | | | | | |",
                  flush=True)
            continue
        steps = "; ".join(" ".join(map(str, t)) for t in r["touchdowns"])
        print(f"| {name} | {r['first']:.3g} | {0.15 * r['first']:.3g} | {r['last']:.3g} | "
              f"{r['repeating']:.3g} | {r['non_repeating']:.3g} | {steps} |", flush=True)


if __name__ == "__main__":
    main()
