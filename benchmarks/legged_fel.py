"""Feedback error learning on the Solo-12 trot (or Talos' walk, ``--robot talos``) in an unknown
world (docs/legged.md, issue 32):
the trot of feltool.walking.legged.trot, its reference acquired on the known model
(feltool.walking.legged.orbit, ``--acquire`` rounds, once for every seed), with the learned
feedforward of feltool.walking.legged.learn, a payload of ``--payload`` of the robot's mass put on its base at
the start of cycle ``--change`` (the controller's model does not know it), every contact check
on (normal force > 0, circular friction cone mu = 0.7, impulses pushing and in the cone, no foot
below the ground, released feet accelerating up, 2.7 N m motors).

Per seed (a random start velocity of the base and joints, as benchmarks/legged_trot.py): whether
every step is physical (or the check that stops it, and when), the summed feedback -- the RMS
over a cycle of the feedback's share of the motor torques, in [N m] -- of the cycle before the
change, of the change's cycle and of the last one, the last over the change's (the issue's
ratio) and over the one before (how much of the payload's feedback is left), the worst roll and
pitch, least normal force, largest friction ratio and torque, the forward speed over the second
half, and the wall time.

With ``--robot talos``: Talos' legs walking (feltool.walking.legged.walk: two soles of four
corners, the centre of mass swaying as the inverted pendulum's orbit, the URDF's 100-300 N m
motors), each cycle two steps.

With ``--slope ANGLE[,ROLL]`` (in [rad]) the unknown world is (also) a ground inclined from the
change's cycle on (feltool.walking.legged.model.sloped: positive ANGLE downhill ahead, ROLL
downhill to the left); with ``--masses SCALE`` every body's mass and inertia that many times the
model's (feltool.walking.legged.model.scaled_masses); ``--payload 0`` for either alone.

Usage: ``python benchmarks/legged_fel.py [--robot solo12|talos] [--cycles 150] [--seeds 0-9]
[--payload 0.2] [--slope ANGLE[,ROLL]] [--masses SCALE] [--change 3] [--no-learning] [--harmonics 0]
[--acquire 4] [--plant pinocchio|mujoco]``
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from feltool.walking.legged.learn import PhaseFeedforward, learn_trot  # noqa: E402
from feltool.walking.legged.model import load_solo12, load_talos_legs  # noqa: E402
from feltool.walking.legged.orbit import acquire_orbit  # noqa: E402
from feltool.walking.legged.trot import TrotController  # noqa: E402
from feltool.walking.legged.walk import IMPACT_WINDOW, biped_gains, biped_walk  # noqa: E402


def seeds(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", choices=("solo12", "talos"), default="solo12")
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--seeds", type=seeds, default=seeds("0-9"))
    ap.add_argument("--payload", type=float, default=0.2, help="fraction of the robot's mass")
    ap.add_argument("--slope", type=lambda x: tuple(float(a) for a in (x + ",0").split(",")[:2]),
                    default=None, help="ANGLE[,ROLL] of the ground in [rad] from the change on")
    ap.add_argument("--masses", type=float, default=None,
                    help="every body's mass and inertia times this from the change on")
    ap.add_argument("--change", type=int, default=3, help="the cycle the world changes")
    ap.add_argument("--no-learning", action="store_true")
    ap.add_argument("--harmonics", type=int, default=0,
                    help="highest harmonic M of the learned feedforward (0: the cycle's mean)")
    ap.add_argument("--plant", choices=("pinocchio", "mujoco"), default="pinocchio")
    ap.add_argument("--acquire", type=int, default=4,
                    help="rounds of the reference's acquisition on the known model (0: none)")
    args = ap.parse_args()
    if args.robot == "talos":
        robot = load_talos_legs()
        q0 = robot.standing()
        names = list(robot.feet)
        gait = biped_walk(robot, q0, tuple(f for f in names if f.startswith("L_")),
                          tuple(f for f in names if f.startswith("R_")))
        extra, window = biped_gains(robot), IMPACT_WINDOW
    else:
        robot, gait, extra, window = load_solo12(effort=2.7), None, {}, 1e-4
    correction = None
    if args.acquire:
        t0 = time.perf_counter()
        known = None if gait is None else TrotController(robot, robot.standing(), gait=gait,
                                                         **extra)
        acq = acquire_orbit(robot, gait, rounds=args.acquire, controller=known,
                            impact_window=window)
        correction = acq.correction
        print(f"reference acquired on the known model in {args.acquire} rounds "
              f"({time.perf_counter() - t0:.0f} s): summed feedback per round "
              + ", ".join(f"{f:.4f}" for f in acq.feedback) + " N m")
    slope = "" if args.slope is None else f", slope {args.slope[0]:g}, {args.slope[1]:g} rad"
    slope += "" if args.masses is None else f", masses x {args.masses:g}"
    print(f"{robot.name} ({robot.mass:.3f} kg), payload {args.payload:.0%}{slope} from cycle "
          f"{args.change}, "
          f"{args.cycles} cycles, learning {'off' if args.no_learning else 'on'} "
          f"(M = {args.harmonics}), "
          f"plant {args.plant}")
    print("| seed | result | fb before [N m] | fb change | fb last | last/change | "
          "last/before | max roll / pitch [rad] | min f_n [N] | max f_t/f_n | max |u| [N m] "
          "| v 2nd half [m/s] | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        t0 = time.perf_counter()
        run = learn_trot(robot, cycles=args.cycles, payload=args.payload, change=args.change,
                         seed=seed, learn=not args.no_learning, plant=args.plant,
                         slope=args.slope, mass_scale=args.masses,
                         correction=correction, acquire=0, gait=gait, controller=extra,
                         impact_window=window,
                         feedforward=PhaseFeedforward(args.harmonics, robot.nv))
        wall = time.perf_counter() - t0
        k = args.change
        fb = np.r_[run.feedback, np.full(max(0, k + 1 - len(run.feedback)), np.nan)]
        done = len(run.feedback) == args.cycles
        result = "physical, all cycles" if done else f"`{run.kind}` at {run.log.t[-1]:.2f} s"
        ratio, before = fb[-1] / fb[k], fb[-1] / fb[k - 1]
        st = run.log.stats
        print(f"| {seed} | {result} | {fb[k - 1]:.4f} | {fb[k]:.4f} | {fb[-1]:.4f} | "
              f"{ratio:.3f} | {before:.3f} | {np.abs(run.log.roll).max():.4f} / "
              f"{np.abs(run.log.pitch).max():.4f} | {st.min_normal_force:.3f} | "
              f"{st.max_friction_ratio:.3f} | {st.max_torque:.2f} | {run.speed:.3f} | "
              f"{wall:.0f} |", flush=True)


if __name__ == "__main__":
    main()
