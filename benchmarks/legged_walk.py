"""Talos walking (docs/legged.md, issue 32's 3D biped): the walk start of
feltool.walking.legged.walk (the trot's event-driven switch on two soles of four corners each, a
sideways sway of the centre of mass as the linear inverted pendulum's orbit, whole-body inverse
dynamics with the QP allocation) in the closed loop at 1 kHz (RK4), every contact check on
(each sole's wrench inside its corners' friction cones, impulses pushing and in the cone, no
corner below the ground, released soles leaving within 50 ms, the URDF's 100-300 N m motors).

Per seed (a random start velocity of the base and joints, projected onto the soles, and a 0.1 s
horizontal push on the base of ``--push`` N in a random direction at a random time between
10 % and 90 % of the run, which the controller does not know): whether it stays physical for the
whole run (or the check that stops it, and when), the steps, the mean forward speed over the
second half, the worst roll and pitch, the least corner normal force, the largest friction and
impulse ratios and torque, and the loop's wall time per simulated second.

Usage: ``python benchmarks/legged_walk.py [--duration 14] [--seeds 10] [--speed 0.15] [--push 20]``
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from feltool.walking.legged.model import load_talos_legs  # noqa: E402
from feltool.walking.legged.stand import Push, random_start, stand  # noqa: E402
from feltool.walking.legged.walk import IMPACT_WINDOW, biped_controller, biped_walk  # noqa: E402


def run(seed: int, duration: float, speed: float, push: float) -> dict:
    """One seed's walk."""
    talos = load_talos_legs()
    q = talos.standing()
    names = list(talos.feet)
    gait = biped_walk(talos, q, tuple(f for f in names if f.startswith("L_")),
                      tuple(f for f in names if f.startswith("R_")), speed=speed)
    ctl = biped_controller(talos, q, gait)
    rng = np.random.default_rng(seed)
    v0 = random_start(talos, rng, 0.2)
    kick = Push.random(rng, duration, push) if push > 0 else None
    t0 = time.perf_counter()
    log = stand(talos, ctl, q, v0=v0, duration=duration, schedule=gait.schedule,
                on_touchdown=gait.touchdown, impact_window=IMPACT_WINDOW, push=kick)
    wall = time.perf_counter() - t0
    half = log.t >= log.t[-1] / 2
    v = np.diff(log.q[half, 0]).sum() / max(log.t[half][-1] - log.t[half][0], 1e-9)
    return dict(seed=seed, ok=log.not_walking is None, why=log.not_walking, t=log.t[-1],
                steps=gait.steps, v=v, roll=np.abs(log.roll).max(),
                pitch=np.abs(log.pitch).max(), fn=log.stats.min_normal_force,
                mu=log.stats.max_friction_ratio, imp=log.stats.max_impulse_ratio,
                tau=log.stats.max_torque, wall=wall / max(log.t[-1], 1e-9))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=14.0)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--speed", type=float, default=0.15)
    ap.add_argument("--push", type=float, default=20.0)
    args = ap.parse_args()
    print(f"Talos' legs walking {args.duration:g} s at {args.speed} m/s, a {args.push:g} N push, "
          f"seeds 0-{args.seeds - 1}\n")
    print("| seed | physical | steps | v [m/s] | max roll / pitch [rad] | min F_n [N] | "
          "max f_t/f_n | max i_t/i_n | max torque [N m] | wall s per s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    ok = 0
    for seed in range(args.seeds):
        r = run(seed, args.duration, args.speed, args.push)
        ok += r["ok"]
        state = "yes" if r["ok"] else f"no, t = {r['t']:.2f} s: {r['why']}"
        print(f"| {seed} | {state} | {r['steps']} | {r['v']:.3f} | {r['roll']:.4f} / "
              f"{r['pitch']:.4f} | {r['fn']:.2f} | {r['mu']:.3f} | {r['imp']:.3f} | "
              f"{r['tau']:.1f} | {r['wall']:.1f} |", flush=True)
    print(f"\n{ok}/{args.seeds} seeds walked physically for {args.duration:g} s")


if __name__ == "__main__":
    main()
