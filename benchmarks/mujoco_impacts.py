"""MuJoCo's touchdown against the rigid impact, per walker and contact stiffness (docs/biped.md,
"MuJoCo as the plant": the cause experiment).

For each shipped MuJoCo walker config, the designed start with nothing learned (as
``benchmarks/walk_mujoco.py``'s ``fixed`` start), seed 0, 3 cycles: the last cycle's touchdowns in
MuJoCo (the config's settings, and a stiff contact: ``solref`` time constant 0.5 ms at a
0.25 ms timestep, the config's integrator) and in Pinocchio's rigid world
(``plant={simulator: pinocchio}``, the same design). Per touchdown: the landing foot's
impulse (MuJoCo's over the 10 ms impact window), the kinetic energy lost, the velocity at
the first control step after the touchdown against the rigid
impact's, and the trailing foot's impulse and lift-off time in MuJoCo (the rigid trailing foot
carries none and leaves at once).

Usage: ``python benchmarks/mujoco_impacts.py`` (a few minutes)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

sys.path.insert(0, str(Path(__file__).resolve().parent))
from walk_mujoco import CONFIGS, overrides, soften  # noqa: E402

STIFF = (0.0005, 8)  # solref time constant [s], sim.substeps (MuJoCo timestep 0.25 ms at 500 Hz)


def touchdowns(config: Path, stiffness=None, rigid: bool = False) -> dict:
    """The last of 3 cycles' touchdowns: mean impulse [N s], energy lost [J], post-touchdown
    velocities, and (MuJoCo) the trailing foot's impulse [N s] and lift-off time [s]."""
    over = overrides(config, "fixed")
    if rigid:
        over += ["plant={simulator: pinocchio}", "backend=pinocchio"]
    if stiffness is not None:
        over.append(f"sim.substeps={stiffness[1]}")
    exp = load_experiment(config, over)
    if stiffness is not None:
        soften(exp, stiffness[0])
    trailing: list[list[float]] = []  # per touchdown: [impulse z, lift-off time]

    def watch(step) -> None:  # MujocoLoop's per-step observer (feltool.walking.mujoco_walk)
        if step.touchdown:  # the old stance foot now trails
            trailing.append([0.0, np.nan])
        elif trailing and np.isnan(trailing[-1][1]):
            trailing[-1][0] += float(step.swing_force[2]) * step.h
            if step.trailing_lifted:
                trailing[-1][1] = step.since_touchdown

    if not rigid:
        exp.hybrid.observers.append(watch)
    logs: list = []
    run_seed(exp, 0, 3, on_cycle=lambda cycle, log, Qd, fb: logs.append(log))
    last = logs[-1]
    steps = last.steps[:len(last.impacts)]
    n = len(steps)
    return {"impulse": np.mean([s.impulse for s in steps], axis=0),
            "energy_lost": float(np.mean([s.energy_lost for s in steps])),
            "post": [last.v[k] if k < len(last.v) else last.v_end for k, _, _ in last.impacts],
            "trailing": np.array(trailing[-n:]) if trailing else None}


def main() -> None:
    print("| walker | contact | landing impulse (I_x, I_z) [N s] | energy lost [J] | "
          "\\|v⁺ − v⁺_rigid\\| (\\|v⁺_rigid\\|) | trailing foot: impulse [N s], lift-off [ms] |")
    print("|---|---|---|---|---|---|")
    for config in CONFIGS:
        name = config.stem.replace("_mujoco", "")
        rigid = touchdowns(config, rigid=True)
        print(f"| {name} | rigid (Pinocchio) | {rigid['impulse'][0]:.2f}, {rigid['impulse'][1]:.2f}"
              f" | {rigid['energy_lost']:.3g} | 0 ({np.mean([np.linalg.norm(v) for v in rigid['post']]):.3g})"
              " | 0, 0 |")
        for label, stiffness in (("MuJoCo, shipped config", None),
                                 ("MuJoCo, stiff (0.5 ms time constant, 0.25 ms step)", STIFF)):
            m = touchdowns(config, stiffness)
            dv = np.mean([np.linalg.norm(a - b) for a, b in zip(m["post"], rigid["post"])])
            tr = m["trailing"]
            print(f"| {name} | {label} | {m['impulse'][0]:.2f}, {m['impulse'][1]:.2f} | "
                  f"{m['energy_lost']:.3g} | {dv:.3g} | {tr[:, 0].mean():.3g}, "
                  f"{np.nanmean(tr[:, 1]) * 1e3:.3g} |", flush=True)


if __name__ == "__main__":
    main()
