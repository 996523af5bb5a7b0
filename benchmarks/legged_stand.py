"""Solo-12 standing on its four feet, pushed (docs/legged.md): one 0.1 s push on the base at
t = 0.2 s that the controller does not know, then 2 s in the loop at 1 kHz (RK4, one sub-step),
every contact check on (normal force > 0, circular friction cone mu = 0.7, 2.7 N m motors).

Per push: whether it stays physical (or the check that stops it), the largest roll, pitch and
sideways/forward excursion of the base, the least normal force, the largest friction ratio and
torque, how far from its height and level it ends, the allocations that were not exact, and the
loop's wall time per simulated second (the machine's load matters: say it with the numbers).

Usage: ``python benchmarks/legged_stand.py``
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from feltool.walking.legged.control import StandingController  # noqa: E402
from feltool.walking.legged.model import load_solo12  # noqa: E402
from feltool.walking.legged.stand import Push, stand  # noqa: E402

PUSHES = [
    ("sideways 10 N", Push(0.2, 0.1, force=(0.0, 10.0, 0.0))),
    ("sideways 20 N", Push(0.2, 0.1, force=(0.0, 20.0, 0.0))),
    ("sideways 40 N", Push(0.2, 0.1, force=(0.0, 40.0, 0.0))),
    ("forward 20 N", Push(0.2, 0.1, force=(20.0, 0.0, 0.0))),
    ("down 20 N", Push(0.2, 0.1, force=(0.0, 0.0, -20.0))),
    ("roll 2 N m", Push(0.2, 0.1, torque=(2.0, 0.0, 0.0))),
    ("pitch 2 N m", Push(0.2, 0.1, torque=(0.0, 2.0, 0.0))),
]


def main() -> None:
    solo = load_solo12(effort=2.7)
    q = solo.standing()
    print(f"Solo-12, {solo.mass:.3f} kg, base {q[2]:.4f} m up; 2 s at 1 kHz after each push")
    print(f"{'push (0.1 s)':15s} {'result':22s} {'roll':>7s} {'pitch':>7s} {'dx,dy [mm]':>12s} "
          f"{'min fn':>7s} {'fric':>5s} {'|u|max':>6s} {'end dz,tilt':>15s} {'inexact':>7s} "
          f"{'wall/sim':>8s}")
    for name, push in PUSHES:
        ctl = StandingController(solo, q)
        t0 = time.perf_counter()
        log = stand(solo, ctl, q, duration=2.0, push=push)
        wall = time.perf_counter() - t0
        st = log.stats
        result = "physical, 2 s" if log.not_walking is None else \
            f"{log.kind} at {log.t[-1]:.3f} s"
        dxy = np.abs(log.q[:, :2] - q[:2]).max(0) * 1e3
        end = (log.height[-1] - q[2], max(abs(log.roll[-1]), abs(log.pitch[-1])))
        print(f"{name:15s} {result:22s} {np.abs(log.roll).max():7.4f} "
              f"{np.abs(log.pitch).max():7.4f} {dxy[0]:5.1f},{dxy[1]:5.1f} "
              f"{st.min_normal_force:7.3f} {st.max_friction_ratio:5.3f} {st.max_torque:6.3f} "
              f"{end[0]:+8.1e},{end[1]:6.1e} {ctl.inexact:7d} {wall / max(log.t[-1], 1e-3):8.2f}")


if __name__ == "__main__":
    main()
