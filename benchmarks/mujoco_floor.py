"""What sets the MuJoCo walkers' feedback floor (docs/biped.md, "MuJoCo as the plant": the cause).

For each shipped MuJoCo walker config, the designed start with nothing learned (as
``benchmarks/walk_mujoco.py``'s ``fixed`` start: every motor and the torso on the design, rates
0; seed 0, the run draws nothing at random), 3 cycles, under each of MuJoCo's settings below and
in Pinocchio's rigid world (the same design). Per setting: whether it walks, cycle 1's first
step (it starts on the rigid orbit's post-impact state, so it has no MuJoCo impact), the
feedback of cycles 1 and 3, and cycle 3's mean summed |feedback| [N m] split by phase: the
40 ms after each touchdown, 40-200 ms after, and the rest of the step.

Usage: ``python benchmarks/mujoco_floor.py [--configs ...]`` (a few minutes)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from feltool.engines.python import after_impacts
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

sys.path.insert(0, str(Path(__file__).resolve().parent))
from walk_mujoco import CONFIGS, overrides  # noqa: E402

#: (label, --set overrides); the shipped settings are the config's own
SETTINGS = [
    ("rigid (Pinocchio)", ["plant={simulator: pinocchio}", "backend=pinocchio"]),
    ("Euler, 0.5 ms, 2 ms, sample at touchdown",
     ["sim.substeps=4", "plant.mujoco_integrator=euler", "plant.contact_timeconst=0.002",
      "plant.impact_sample=touchdown"]),
    ("Euler, 0.5 ms, 2 ms", ["sim.substeps=4", "plant.mujoco_integrator=euler",
                             "plant.contact_timeconst=0.002"]),
    ("Euler, 0.25 ms, 0.5 ms", ["sim.substeps=8", "plant.mujoco_integrator=euler",
                                "plant.contact_timeconst=0.0005"]),
    ("RK4, 0.5 ms, 2 ms", ["sim.substeps=4", "plant.mujoco_integrator=rk4",
                           "plant.contact_timeconst=0.002"]),
    ("RK4, 0.25 ms, 2 ms, sample at touchdown",
     ["sim.substeps=8", "plant.mujoco_integrator=rk4", "plant.contact_timeconst=0.002",
      "plant.impact_sample=touchdown"]),
    ("RK4, 0.25 ms, 2 ms", ["sim.substeps=8", "plant.mujoco_integrator=rk4",
                            "plant.contact_timeconst=0.002"]),
]


def floor(config: Path, extra: list[str], cycles: int = 3) -> dict:
    """The designed start, nothing learned, ``cycles`` cycles with the ``extra`` overrides."""
    exp = load_experiment(config, overrides(config, "fixed") + extra)
    logs: list = []
    res = run_seed(exp, 0, cycles, on_cycle=lambda cycle, log, Qd, fb: logs.append(log))
    fb = [r["fb_abs_mean_error"] for r in res.rows]
    walk = res.summary.get("walking") or {}
    out = {"walked": bool(walk.get("walked")) and len(fb) == cycles,
           "reason": walk.get("reason"), "fb": fb}
    if not out["walked"]:
        return out
    dt = exp.config.dt
    first = np.abs(logs[0].u_fb).sum(axis=1)
    out["first_step"] = float(first[:logs[0].impacts[0][0]].mean())
    U = np.abs(logs[-1].u_fb).sum(axis=1)
    early = after_impacts(logs[-1].impacts, len(U), int(round(0.04 / dt)))
    late = after_impacts(logs[-1].impacts, len(U), int(round(0.2 / dt))) & ~early
    out["phases"] = [float(U[m].mean()) for m in (early, late, ~(early | late))]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="+", default=[str(c) for c in CONFIGS])
    args = ap.parse_args()
    print("| walker | MuJoCo: integrator, timestep, contact time constant | walks | cycle 1's "
          "first step [N m] | cycle 1 → 3 [N m] | cycle 3: 0–40 ms / 40–200 ms after the "
          "touchdowns / rest [N m] |")
    print("|---|---|---|---|---|---|")
    for config in map(Path, args.configs):
        name = config.stem.replace("_mujoco", "")
        for label, extra in SETTINGS:
            r = floor(config, extra)
            if not r["walked"]:
                print(f"| {name} | {label} | no: {r['reason']} | — | — | — |", flush=True)
                continue
            print(f"| {name} | {label} | yes | {r['first_step']:.3g} | {r['fb'][0]:.3g} → "
                  f"{r['fb'][-1]:.3g} | " + " / ".join(f"{p:.3g}" for p in r["phases"]) + " |",
                  flush=True)


if __name__ == "__main__":
    main()
