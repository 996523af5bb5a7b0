"""Learning-loop speed of every backend, in one run: Pinocchio Python loop, CasADi interpreted,
and the compiled cycle (CasADi -> C).

    python benchmarks/backends.py [--cycles 200]

Prints (1) learning steps per second per backend and robot with the ratio compiled / Pinocchio,
(2) the time to the first result (experiment build + code generation + C compilation + one
cycle, with an empty cache), (3) the cost per step as the number of basis functions grows, and
(4) the wall time of the full 20-seed standard-arm run with the compiled backend on all cores
after the first compilation. All measured in this process, on this machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from ur5_config import UR5  # noqa: E402

from feltool.config import apply_overrides, read_yaml  # noqa: E402
from feltool.experiment import build_experiment, run_seed  # noqa: E402

CONFIGS = HERE.parent / "configs"


def raw_config(name: str) -> dict:
    return dict(UR5) if name == "ur5" else read_yaml(CONFIGS / f"{name}.yaml")


def experiment(name: str, overrides: list[str]):
    source = None if name == "ur5" else CONFIGS / f"{name}.yaml"
    return build_experiment(apply_overrides(raw_config(name), overrides), source=source)


def steps_per_second(exp, cycles: int, repeats: int = 3) -> float:
    best = 0.0
    run_seed(exp, 0, 1)  # warm up (and compile, for the compiled backend)
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = run_seed(exp, 0, cycles)
        best = max(best, len(res.rows) * exp.primitives.n_steps / (time.perf_counter() - t0))
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=200)
    args = parser.parse_args()
    os.environ.setdefault("FELTOOL_CACHE", tempfile.mkdtemp(prefix="feltool-bench-"))

    print("1. learning steps per second (one core)")
    print(f"  {'robot':<22} {'pinocchio':>11} {'casadi':>11} {'compiled':>11} "
          f"{'compiled/pin':>13} {'us/step compiled':>17}")
    for name in ("two_link_standard", "two_link_human_arm", "ur5"):
        pin_sps = steps_per_second(experiment(name, []), args.cycles)
        cas_sps = steps_per_second(experiment(name, ["backend=casadi"]), max(2, args.cycles // 20),
                                   repeats=1)
        comp_sps = steps_per_second(experiment(name, ["backend=compiled"]), args.cycles * 5)
        print(f"  {name:<22} {pin_sps:>11,.0f} {cas_sps:>11,.0f} {comp_sps:>11,.0f} "
              f"{comp_sps / pin_sps:>12.1f}x {1e6 / comp_sps:>17.3f}")

    print("\n2. time to first result (build + generate + compile + one cycle, empty cache)")
    for name in ("two_link_standard", "ur5"):
        os.environ["FELTOOL_CACHE"] = tempfile.mkdtemp(prefix="feltool-bench-")
        t0 = time.perf_counter()
        exp = experiment(name, ["backend=compiled"])
        run_seed(exp, 0, 1)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        exp = experiment(name, ["backend=compiled"])
        run_seed(exp, 0, 1)
        cached = time.perf_counter() - t0
        print(f"  {name:<22} first {first:6.2f} s, again with the cache {cached:6.2f} s")

    print("\n3. cost per step [us] as the number of basis functions grows (standard arm)")
    print(f"  {'basis':>5} {'pinocchio':>10} {'compiled':>10}")
    for basis in (10, 20, 40, 80):
        over = [f"primitives.basis={basis}"]
        p = steps_per_second(experiment("two_link_standard", over), args.cycles // 2, repeats=1)
        c = steps_per_second(experiment("two_link_standard", over + ["backend=compiled"]),
                             args.cycles * 2, repeats=1)
        print(f"  {basis:>5} {1e6 / p:>10.2f} {1e6 / c:>10.3f}")

    print("\n4. full thesis run, 20 seeds x 150 cycles, compiled, all cores (after compilation)")
    from feltool.runner import run_experiment

    raw = apply_overrides(raw_config("two_link_standard"), ["backend=compiled"])
    exp = build_experiment(raw, source=CONFIGS / "two_link_standard.yaml")
    run_seed(exp, 0, 1)
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        summary = run_experiment(exp, raw, Path(out), show_progress=False, figures=False)
        wall = time.perf_counter() - t0
    agg = summary["aggregate"]
    print(f"  wall {wall:.2f} s on {os.cpu_count()} cores; converged {agg['n_converged']}/"
          f"{agg['n_seeds']}, max cycle {agg['converged_cycle_max']}")


if __name__ == "__main__":
    main()
