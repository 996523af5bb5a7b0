"""The Solo-12 trot's Poincaré map at its fixed point (docs/legged.md, issue 32): the section
is the touchdown completing the pair (FL, HR), just after its impact
(feltool.walking.legged.poincare); the Jacobian by central differences of the closed loop
(every contact check on) along the section's 20 directions, for each ``--eps``; its spectral
radius rho (< 1: the trot's fixed point is stable; the slowest perturbation shrinks by rho per
cycle), the largest eigenvalues, and how far the reference state is from a fixed point.

The trot is the one FEL runs on, its reference acquired on the known model in ``--acquire``
rounds (feltool.walking.legged.orbit), or the plan as it is with ``--acquire 0``.

Usage: ``python benchmarks/legged_poincare.py [--cycles 20] [--eps 1e-3 2e-3 5e-3]
[--speed 0.3] [--acquire 4]``
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from feltool.walking.legged.model import load_solo12  # noqa: E402
from feltool.walking.legged.orbit import acquire_orbit  # noqa: E402
from feltool.walking.legged.poincare import trot_jacobian  # noqa: E402
from feltool.walking.legged.trot import TrotController, TrotGait  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--eps", type=float, nargs="+", default=[1e-3, 2e-3, 5e-3])
    ap.add_argument("--speed", type=float, default=0.3)
    ap.add_argument("--acquire", type=int, default=4)
    args = ap.parse_args()
    solo = load_solo12(effort=2.7)
    gait = TrotGait(speed=args.speed)
    ctl = TrotController(solo, solo.standing(), gait=gait)
    if args.acquire:
        ctl.correction = acquire_orbit(solo, gait, rounds=args.acquire).correction
    t0 = time.perf_counter()
    res = trot_jacobian(solo, gait, cycles=args.cycles, eps=tuple(args.eps), controller=ctl)
    wall = time.perf_counter() - t0
    print(f"Solo-12 trot at {args.speed} m/s, reference acquired in {args.acquire} rounds, "
          f"section after cycle {args.cycles} "
          f"({res.jacobian.shape[0]} directions), {wall:.0f} s")
    for e, rho in zip(args.eps, res.rho_spread):
        print(f"eps {e:g}: rho = {rho:.3f}")
    print(f"|P(x*) - x*| = {res.residual:.2e}")
    print("largest |eigenvalues| (first eps):",
          " ".join(f"{abs(z):.3f}" for z in res.eigenvalues[:8]))
    print("their angles [deg]:",
          " ".join(f"{np.degrees(np.angle(z)):.0f}" for z in res.eigenvalues[:8]))


if __name__ == "__main__":
    main()
