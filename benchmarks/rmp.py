"""Cost and accuracy of building, fitting and rolling out an RMP against N, with pydmps's
rhythmic DMP (``DMPs_rhythmic``, the best-known Python one) measured as the reference in the
same run.

    pip install -e '.[bench]'        # pydmps: only for this benchmark
    python benchmarks/rmp.py [--repeats 5]

Demonstrations: one period at 1000 samples (1 kHz at T = 1 s) of the two-sine motion
0.3 + 0.5 sin(phi) + 0.2 sin(2 phi + 0.7) [rad] and of a square wave (+-0.5 rad), given as
positions only (both libraries differentiate them themselves). For N = 10, 20, 40, 80 it prints
the median time of

* build+fit: feltool ``RhythmicPrimitive(...)`` + ``spectral.from_samples`` + ``fit_series``;
  pydmps ``DMPs_rhythmic(...)`` + ``imitate_path``;
* cycle: one cycle of q_d, qdot_d, qddot_d at 1000 steps (feltool: the limit cycle at phases
  met for the first time, a matrix product; pydmps: ``rollout`` of one period, a Python loop);
* steps: a cycle's 1000 exact steps one at a time (feltool ``step``, what per-step learning
  runs; a clock's cycles repeat their phases, so each step's matrices are computed once);
* speed change: what a new period costs feltool (the same primitive at a new clock: the
  cycle's phases and the matrices at them; nothing is rebuilt), against building it;

and the fit's RMS error against the demonstration (feltool: its limit cycle; pydmps: its
rollout's third period, where it has settled), and the ratios pydmps / feltool.
"""

from __future__ import annotations

import argparse
import os
import time

# Matrices here are small: BLAS threads would only add overhead and noise (2 cores, shared).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from feltool.motion import spectral
from feltool.motion.phase import ClockPhase
from feltool.motion.rmp import PrimitiveSet, RhythmicPrimitive

N_SAMPLES = 1000  # per period: 1 kHz at T = 1 s
DT = 1.0 / N_SAMPLES


def demos() -> dict[str, np.ndarray]:
    phi = 2 * np.pi * np.arange(N_SAMPLES) / N_SAMPLES
    return {"two sines": 0.3 + 0.5 * np.sin(phi) + 0.2 * np.sin(2 * phi + 0.7),
            "square": np.where(phi < np.pi, 0.5, -0.5)}


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def feltool_fit(N: int, y: np.ndarray) -> tuple[RhythmicPrimitive, np.ndarray]:
    prim = RhythmicPrimitive(N, 1.0, DT)
    return prim, prim.fit_series(spectral.from_samples(y))


def pydmps_fit(N: int, y: np.ndarray):
    import pydmps

    dmp = pydmps.DMPs_rhythmic(n_dmps=1, n_bfs=N, dt=2 * np.pi / N_SAMPLES)
    dmp.imitate_path(y_des=y[None, :])
    return dmp


def pydmps_error(dmp, y: np.ndarray) -> float:
    track, _, _ = dmp.rollout(timesteps=3 * dmp.timesteps)
    last = track[2 * dmp.timesteps:, 0]
    return float(np.sqrt(np.mean((last - y[:len(last)]) ** 2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    try:
        import pydmps  # noqa: F401
    except ImportError:
        raise SystemExit("benchmarks/rmp.py needs pydmps as its reference: "
                         "pip install -e '.[bench]'") from None
    r = args.repeats
    phi = 2 * np.pi * np.arange(N_SAMPLES) / N_SAMPLES
    print(f"times in [ms] (median of {r}); errors: RMS over one period in [rad]")
    print(f"{'demo':<10} {'N':>3} | {'build+fit':>9} {'pydmps':>8} {'ratio':>6} | "
          f"{'cycle':>7} {'pydmps':>8} {'ratio':>6} | {'steps':>7} | {'speed':>6} | "
          f"{'fit error':>9} {'pydmps':>8}")
    for name, y in demos().items():
        for N in (10, 20, 40, 80):
            fit = median_time(lambda N=N, y=y: feltool_fit(N, y), r)
            ref = median_time(lambda N=N, y=y: pydmps_fit(N, y), r)
            prim, theta = feltool_fit(N, y)
            # a cycle at phases not met before (a clock half a step on): nothing cached
            shifted = ClockPhase(1.0, DT)
            shifted.phi = 0.5 * 2 * np.pi * DT
            fresh = shifted.next_cycle()
            cycle = median_time(lambda p=prim, th=theta, c=fresh: PrimitiveSet({0: p}, 1).desired(
                th, c), r)
            dmp = pydmps_fit(N, y)
            roll = median_time(lambda d=dmp: d.rollout(), r)

            def steps(p=prim, th=theta, q0=y[0]):
                x = np.array([q0, 0.0])
                for k in range(N_SAMPLES):
                    x = p.step(x, th, k)

            steps()  # the first cycle computes each step's matrices; later cycles reuse them
            step = median_time(steps, r)

            def speed_change(p=prim, th=theta):
                clock = ClockPhase(1.0, DT)
                clock.change_period(0.8)
                PrimitiveSet({0: p}, 1).desired(th, clock.next_cycle())

            speed = median_time(speed_change, r)
            err = prim.fit_rms(theta, y, phi)
            print(f"{name:<10} {N:>3} | {fit * 1e3:>9.2f} {ref * 1e3:>8.2f} {ref / fit:>6.1f} | "
                  f"{cycle * 1e3:>7.2f} {roll * 1e3:>8.2f} {roll / cycle:>6.1f} | "
                  f"{step * 1e3:>7.1f} | {speed * 1e3:>6.2f} | {err:>9.2e} "
                  f"{pydmps_error(dmp, y):>8.2e}")
    print("ratio: pydmps time / feltool time (above 1: feltool is faster); speed: a new period "
          "at 0.8 s, its first cycle evaluated (no rebuild)")


if __name__ == "__main__":
    main()
