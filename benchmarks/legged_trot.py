"""Solo-12 trotting (docs/legged.md, issue 32): the trot start of feltool.walking.legged.trot
(a phase per diagonal pair, whole-body inverse dynamics with the QP allocation under the stance
pair) in the closed loop at 1 kHz (RK4), every contact check on (normal force > 0, circular
friction cone mu = 0.7, impulses pushing and in the cone, no foot below the ground, released
feet accelerating up, 2.7 N m motors).

Per seed (a random start velocity of the base and joints, projected onto the four feet, and a
0.1 s horizontal push on the base of ``--push`` N in a random direction at a random time between
10 % and 90 % of the run, which the controller does not know): whether
it stays physical for the whole run (or the check that stops it, and when), the mean forward
speed over the second half, the worst roll and pitch, the least normal force, the largest
friction and impulse ratios and torque, the lowest swing apex (every foot lifts off), the steps
and the loop's wall time per simulated second (the machine's load matters: say it with the
numbers), and a Poincare section of the base's state (once per cycle): its distance to the
last cycle's after the speed ramp, how much it shrinks per cycle over the next four, and the
floor it settles to. Then seed 0 with instantaneous impacts (no Moreau-Jean window) for
comparison.

Usage: ``python benchmarks/legged_trot.py [--duration 20] [--seeds 10] [--speed 0.3] [--push 3]``
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

from feltool.walking.legged.model import load_solo12  # noqa: E402
from feltool.walking.legged.stand import Push, lowest_swing_apex, random_start, stand  # noqa: E402
from feltool.walking.legged.trot import PAIRS, TrotController, TrotGait  # noqa: E402


def section(log, gait: TrotGait) -> tuple[float, float, float]:
    """The base's state at a Poincare section (the control step after each time the pair
    (FL, HR) completes its touchdown): x minus the desired x, y, z, roll, pitch, yaw and the
    base's 6 velocities. Returns the distance to the last cycle's at the first section after
    the ramp, the per-cycle shrink factor over the next four cycles, and the median distance of
    the last ten (the floor the 1 kHz steps and event times leave)."""
    down, sw, rows, times = set(), 1, [], []
    for t, feet in log.touchdowns:
        down |= set(feet) & set(PAIRS[sw])
        if down != set(PAIRS[sw]):
            continue
        if sw == 0:
            k = int(np.searchsorted(log.t, t)) + 1
            if k < len(log.t):
                q, v = log.q[k], log.v[k]
                rpy = pin.rpy.matrixToRpy(pin.XYZQUATToSE3(q[:7]).rotation)
                rows.append(np.r_[q[0] - gait.base_x(log.t[k])[0], q[1:3], rpy, v[:6]])
                times.append(t)
        sw, down = 1 - sw, set()
    if len(rows) < 16:
        return np.nan, np.nan, np.nan
    X = np.array(rows)
    d = np.linalg.norm(X - X[-1], axis=1)
    k0 = int(np.searchsorted(times, gait.start + gait.ramp + 0.1))
    return float(d[k0]), float((d[k0 + 4] / d[k0]) ** 0.25), float(np.median(d[-11:-1]))


def run(solo, seed: int, duration: float, speed: float, push_n: float,
        window: float = 1e-4) -> str:
    rng = np.random.default_rng(seed)
    v0 = random_start(solo, rng)
    push = Push.random(rng, duration, push_n)
    when, angle = push.start, np.arctan2(push.force[1], push.force[0]) % (2 * np.pi)
    gait = TrotGait(speed=speed)
    q0 = solo.standing()
    ctl = TrotController(solo, q0, gait=gait)
    t0 = time.perf_counter()
    log = stand(solo, ctl, q0, v0=v0, duration=duration, schedule=gait.schedule,
                on_touchdown=gait.touchdown, impact_window=window, push=push)
    wall = time.perf_counter() - t0
    st = log.stats
    result = "physical" if log.not_walking is None else f"{log.kind} at {log.t[-1]:.3f} s"
    half = len(log.t) // 2
    mean = (log.q[-1, 0] - log.q[half, 0]) / max(log.t[-1] - log.t[half], 1e-9)
    apex = lowest_swing_apex(solo, log)  # every foot lifts off
    d0, rate, floor = section(log, gait)
    return (f"{seed:4d} {when:5.2f} {np.degrees(angle):4.0f} {result:22s} "
            f"{log.t[-1] + 1e-3:6.2f} {mean:6.3f} "
            f"{np.abs(log.roll).max():7.4f} {np.abs(log.pitch).max():7.4f} "
            f"{st.min_normal_force:6.3f} {st.max_friction_ratio:5.3f} "
            f"{st.max_impulse_ratio:5.3f} {st.max_torque:5.2f} {apex * 1e3:6.1f} {gait.steps:5d} "
            f"{d0:8.1e} {rate:5.2f} {floor:8.1e} {wall / max(log.t[-1], 1e-3):6.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="simulated time per seed [s]")
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0 .. N-1")
    ap.add_argument("--speed", type=float, default=0.3, help="forward speed [m/s]")
    ap.add_argument("--push", type=float, default=3.0,
                    help="a 0.1 s horizontal push on the base [N], random direction and time")
    args = ap.parse_args()
    if args.duration <= 0 or args.seeds < 1 or args.speed < 0 or args.push < 0:
        ap.exit(2, "legged_trot.py: --duration > 0, --seeds >= 1, --speed >= 0, --push >= 0\n")
    solo = load_solo12(effort=2.7)
    print(f"Solo-12 trot at {args.speed} m/s for {args.duration} s, 1 kHz, checks on, "
          f"a {args.push} N push for 0.1 s per seed")
    header = (f"{'seed':>4s} {'push':>5s} {'deg':>4s} {'result':22s} {'t [s]':>6s} "
              f"{'v [m/s]':>6s} {'roll':>7s} "
              f"{'pitch':>7s} {'min fn':>6s} {'fric':>5s} {'imp':>5s} {'|u|':>5s} "
              f"{'apex mm':>6s} {'steps':>5s} {'d post':>8s} {'rate':>5s} {'floor':>8s} "
              f"{'wall/s':>6s}")
    print(header)
    for seed in range(args.seeds):
        print(run(solo, seed, args.duration, args.speed, args.push), flush=True)
    print("no push, seed 0:")
    print(run(solo, 0, args.duration, args.speed, 0.0), flush=True)
    print("instantaneous impacts (no window), no push, seed 0:")
    print(run(solo, 0, args.duration, args.speed, 0.0, window=0.0), flush=True)


if __name__ == "__main__":
    main()
