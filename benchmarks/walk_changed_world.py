"""FEL on a physical walker whose world changes: the summed feedback per cycle (docs/biped.md).

The walker starts on its designed gait (its learned joint at the design: ``init: demo``, no
random draw), the world changes at ``--event-cycle`` (``events:``, the simulated plant only),
and FEL learns either the torso alone or every motor as well (their feedforward corrections
start at zero, so the design is unchanged until the world changes).

Usage::

    python benchmarks/walk_changed_world.py [--config configs/gaits/five_link_walker.yaml]
        [--event "{kind: slope, angle: 0.02}"] [--event-cycle 3] [--cycles 14]
"""

from __future__ import annotations

import argparse

import yaml

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/gaits/five_link_walker.yaml")
    ap.add_argument("--event", default="{kind: slope, angle: 0.02}")
    ap.add_argument("--event-cycle", type=int, default=3)
    ap.add_argument("--cycles", type=int, default=14)
    args = ap.parse_args()
    event = yaml.safe_load(args.event) | {"cycle": args.event_cycle}
    base = ["walking.poincare=false", f"events=[{yaml.safe_dump(event, default_flow_style=True)}]"]
    probe = load_experiment(args.config, base)
    learned = probe.learned_joints
    motors = [n for n in probe.hybrid.walker.motor_names if n not in learned]
    variants = {"learned joint only": [],
                "every motor too": [f"joints.{m}.learn={{init: demo}}" for m in motors]}
    for name, extra in variants.items():
        exp = load_experiment(args.config, base + extra + [f"joints.{j}.learn.init=demo"
                                                           for j in learned])
        res = run_seed(exp, 0, cycles=args.cycles)
        fb = [r["fb_abs_mean_error"] for r in res.rows]
        walked = res.summary.get("walking", {}).get("walked")
        print(f"{name}: walked {walked}; summed feedback per cycle [N m]: "
              + " ".join(f"{f:.3g}" for f in fb), flush=True)


if __name__ == "__main__":
    main()
