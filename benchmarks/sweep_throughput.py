"""Sweep throughput (runs per second) with 1 and 2 local workers and on a 2-worker Dask
cluster, measured in one run.

    python benchmarks/sweep_throughput.py [--points 8] [--cycles 30]

A "run" is one (point, seed) task of the standard arm: build the experiment in the worker
(cached per point), learn for --cycles cycles, return the results. The same sweep is run three
ways; the rows of sweep.csv are checked to be identical.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from feltool.runs.sweep import run_sweep

CONFIG = Path(__file__).resolve().parent.parent / "configs" / "two_link_standard.yaml"


def timed(out: Path, grid, seeds, cycles, workers=None, scheduler=None) -> tuple[float, list]:
    t0 = time.perf_counter()
    rows = run_sweep(CONFIG, grid, out, seeds, cycles, workers, scheduler, show_progress=False)
    return len(rows) / (time.perf_counter() - t0), rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=8)
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--cycles", type=int, default=30)
    args = parser.parse_args()
    grid = {"learning.rates.weights": [0.1 + 0.02 * i for i in range(args.points)]}
    seeds = list(range(args.seeds))
    tmp = Path(tempfile.mkdtemp(prefix="feltool-sweep-bench-"))
    one, rows1 = timed(tmp / "one", grid, seeds, args.cycles, workers=1)
    two, rows2 = timed(tmp / "two", grid, seeds, args.cycles, workers=2)
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster):
        dask, rows3 = timed(tmp / "dask", grid, seeds, args.cycles,
                            scheduler=cluster.scheduler_address)
    same = rows1 == rows2 == rows3
    n = len(rows1)
    print(f"sweep of {n} runs ({args.points} points x {args.seeds} seeds x {args.cycles} cycles) "
          f"on {os.cpu_count()} cores; identical sweep.csv rows: {same}")
    print(f"  {'executor':<24} {'runs/s':>8} {'vs 1 worker':>12}")
    for name, rate in (("local, 1 worker", one), ("local, 2 workers", two),
                       ("Dask, 2 workers", dask)):
        print(f"  {name:<24} {rate:>8.2f} {rate / one:>11.2f}x")


if __name__ == "__main__":
    main()
