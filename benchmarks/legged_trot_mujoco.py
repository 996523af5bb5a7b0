"""Solo-12 trotting with MuJoCo as the plant (issue 32, docs/legged.md): the shipped TrotGait and
TrotController (designed on the rigid model) in MuJoCo's soft contacts
(feltool.walking.legged.mujoco_stand.stand_mujoco: 1 kHz control, MuJoCo at 2 kHz, semi-implicit
Euler, elliptic cone mu = 0.7, impratio 100), every check of that loop on (stance normal force
> 0 over 5 ms, no stance foot sliding 2 mm, no foot 2 mm deep, released feet leaving the
floor, 2.7 N m motors, roll and pitch below 0.5 rad).

Per seed the draws of benchmarks/legged_trot.py (a random start velocity of the base and joints,
projected onto the four feet, and a 0.1 s horizontal push of ``--push`` N in a random
direction at a random time the controller does not know), so the rows compare with its table:
whether it stays physical for the whole run (or the check that stops it, and when), the mean
forward speed over the second half, the worst roll and pitch, the least normal force (5 ms
mean), the largest friction ratio and touchdown-impulse ratio (over 10 ms) and torque, the
lowest swing apex, the steps, and the wall time per simulated second.

Usage: ``python benchmarks/legged_trot_mujoco.py [--duration 20] [--seeds 10] [--speed 0.3]
[--push 3] [--payload 0.0] [--substeps 2] [--impratio I] [--timeconst T]`` (payload: a
fraction of the robot's mass on the base, in MuJoCo only: the unknown world)
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from feltool.walking.legged.model import Payload, load_solo12  # noqa: E402
from feltool.walking.legged.mujoco_stand import stand_mujoco  # noqa: E402
from feltool.walking.legged.stand import Push, lowest_swing_apex, random_start  # noqa: E402
from feltool.walking.legged.trot import TrotController, TrotGait  # noqa: E402


def run(solo, seed: int, duration: float, speed: float, push_n: float,
        payload: float = 0.0, **options) -> str:
    rng = np.random.default_rng(seed)
    v0 = random_start(solo, rng)
    push = Push.random(rng, duration, push_n)
    when, angle = push.start, np.arctan2(push.force[1], push.force[0]) % (2 * np.pi)
    gait = TrotGait(speed=speed)
    q0 = solo.standing()
    ctl = TrotController(solo, q0, gait=gait)
    load = Payload(payload * solo.mass) if payload > 0 else None
    t0 = time.perf_counter()
    log = stand_mujoco(solo, ctl, q0, v0=v0, duration=duration, schedule=gait.schedule,
                       on_touchdown=gait.touchdown, push=push, payload=load, **options)
    wall = time.perf_counter() - t0
    st = log.stats
    result = "physical" if log.not_walking is None else f"{log.kind} at {log.t[-1]:.3f} s"
    half = len(log.t) // 2
    mean = (log.q[-1, 0] - log.q[half, 0]) / max(log.t[-1] - log.t[half], 1e-9)
    apex = lowest_swing_apex(solo, log)  # every foot lifts off
    line = (f"{seed:4d} {when:5.2f} {np.degrees(angle):4.0f} {result:24s} "
            f"{log.t[-1] + 1e-3:6.2f} {mean:6.3f} "
            f"{np.abs(log.roll).max():7.4f} {np.abs(log.pitch).max():7.4f} "
            f"{st.min_normal_force:6.3f} {st.max_friction_ratio:5.3f} "
            f"{st.max_impulse_ratio:5.3f} {st.max_torque:5.2f} {apex * 1e3:6.1f} {gait.steps:5d} "
            f"{wall / max(log.t[-1], 1e-3):6.2f}")
    if log.not_walking is not None:
        line += f"\n     {log.not_walking}"
    return line


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="simulated time per seed [s]")
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0 .. N-1")
    ap.add_argument("--first", type=int, default=0, help="the first seed")
    ap.add_argument("--speed", type=float, default=0.3, help="forward speed [m/s]")
    ap.add_argument("--push", type=float, default=3.0,
                    help="a 0.1 s horizontal push on the base [N], random direction and time")
    ap.add_argument("--payload", type=float, default=0.0,
                    help="a point mass on the base, a fraction of the robot's mass [-]")
    ap.add_argument("--substeps", type=int, default=2, help="MuJoCo steps per control step")
    ap.add_argument("--impratio", type=float, default=None,
                    help="MuJoCo's friction-to-normal impedance ratio (default the plant's)")
    ap.add_argument("--timeconst", type=float, default=None,
                    help="the contacts' solref time constant [s] (default the plant's)")
    args = ap.parse_args()
    if args.duration <= 0 or args.seeds < 1 or args.speed < 0 or args.push < 0 or \
            args.payload < 0:
        ap.exit(2, "legged_trot_mujoco.py: --duration > 0, --seeds >= 1, --speed, --push, "
                "--payload >= 0\n")
    solo = load_solo12(effort=2.7)
    print(f"Solo-12 trot in MuJoCo at {args.speed} m/s for {args.duration} s, 1 kHz control, "
          f"{args.substeps} MuJoCo steps each, checks on, a {args.push} N push for 0.1 s per seed, payload "
          f"{args.payload:g} of the mass")
    print(f"{'seed':>4s} {'push':>5s} {'deg':>4s} {'result':24s} {'t [s]':>6s} "
          f"{'v [m/s]':>6s} {'roll':>7s} {'pitch':>7s} {'min fn':>6s} {'fric':>5s} "
          f"{'imp':>5s} {'|u|':>5s} {'apex mm':>6s} {'steps':>5s} {'wall/s':>6s}")
    options = {k: getattr(args, k) for k in ("impratio", "timeconst")
               if getattr(args, k) is not None}
    if options or args.substeps != 2:
        print(f"MuJoCo: {args.substeps} steps per control step, {options}")
    for seed in range(args.first, args.first + args.seeds):
        print(run(solo, seed, args.duration, args.speed, args.push, args.payload,
                  substeps=args.substeps, **options), flush=True)


if __name__ == "__main__":
    main()
