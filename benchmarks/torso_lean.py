"""Which torso lean can the three-link walker (thesis Table B.1) hold while it walks physically?

For each torso pitch (the thesis holds pi/6 from the vertical) and each step (duration T [s],
length L [m]), ``feltool gait``'s collocation looks for a periodic gait with rigid impacts, the
friction cone, effort limits and the scuffing rule; a design found is then walked in feltool's
own walker (20 steps, the contact checks) and its Poincaré spectral radius computed.
``--relaxed`` repeats the designs with friction 5 and unlimited torque, to tell whether
friction or torque is what rules a lean out. Prints one line per design and a summary table
(docs/biped.md).

Usage::

    python benchmarks/torso_lean.py [--torso 0.1,0.2,0.3,0.4,0.5236] [--durations 0.4,0.5,0.6,0.8]
        [--lengths 0.3,0.5,0.7,0.9] [--relaxed] [--no-verify] [--friction-margin 0.85]
        [--normal-force-margin 0.05] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from feltool.config.files import read_yaml
from feltool.gait.config import gait_config, gait_spec, walker_from_raw
from feltool.gait.design import GaitDesignError, design_gait
from feltool.gait.orbit import verify_design
from feltool.runs.experiments import build_experiment

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "gaits" / "three_link_walker.yaml"


def floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--torso", type=floats, default=[0.1, 0.2, 0.3, 0.4, np.pi / 6])
    ap.add_argument("--durations", type=floats, default=[0.4, 0.5, 0.6, 0.8])
    ap.add_argument("--lengths", type=floats, default=[0.3, 0.5, 0.7, 0.9])
    ap.add_argument("--relaxed", action="store_true", help="friction 5, no effort limits")
    ap.add_argument("--friction-margin", type=float, default=0.85)
    ap.add_argument("--normal-force-margin", type=float, default=0.05)
    ap.add_argument("--no-verify", dest="verify", action="store_false")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    raw = read_yaml(CONFIG)
    raw["walking"]["poincare"] = False
    walker, settings = walker_from_raw(raw, CONFIG)
    if args.relaxed:
        settings["friction"] = 5.0
        walker.model.effortLimit[:] = 1e9
    rows = []
    for torso in args.torso:
        for T in args.durations:
            for L in args.lengths:
                spec = gait_spec(raw, walker, settings, step_length=L, duration=T, torso=torso,
                                 friction_margin=args.friction_margin,
                                 normal_force_margin=args.normal_force_margin)
                row = {"torso": torso, "duration_s": T, "step_length_m": L}
                try:
                    gait = design_gait(walker, spec)
                except GaitDesignError as exc:
                    row["found"], row["why"] = False, str(exc).split(": ", 1)[-1][:120]
                    rows.append(row)
                    print(json.dumps(row), flush=True)
                    continue
                m = gait.metrics
                row.update(found=True, cot=m["cost_of_transport"],
                           min_fn_mg=m["min_normal_force_mg"], friction=m["max_friction_ratio"],
                           max_torque=m["max_torque"])
                if args.verify and not args.relaxed:
                    check = verify_design(build_experiment(
                        gait_config(raw, walker, gait, spec, settings), CONFIG))
                    row["walks"] = check.walked
                    row["why"] = check.reason
                    if check.walked:
                        row["spectral_radius"] = check.poincare.get("spectral_radius")
                rows.append(row)
                print(json.dumps(row), flush=True)
    print("\n| torso [rad] | steps designed (of T x L) | walking in feltool's walker | best CoT |")
    print("|---|---|---|---|")
    for torso in args.torso:
        mine = [r for r in rows if r["torso"] == torso]
        found = [r for r in mine if r["found"]]
        walks = [r for r in found if r.get("walks")]
        cot = min((r["cot"] for r in found), default=None)
        print(f"| {torso:.4g} | {len(found)} of {len(mine)} | {len(walks)} | "
              + ("-" if cot is None else f"{cot:.3g}") + " |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
