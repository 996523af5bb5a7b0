"""Gait design speed and the designed gaits' figures, for every bundled walker (docs/performance.md).

Each walker's gait is designed ``repeats`` times from the designer's own initial guess (the NLP
built anew each time); the table gives the median solver time (IPOPT's wall time, one thread),
the median time to build the NLP (CasADi's SX graph, its derivatives), IPOPT's iterations, the
knots, and the gait's period, speed, step length, cost of transport, least normal force, largest
friction ratio and impact impulse ratio. Run with one BLAS/OpenMP thread (``OMP_NUM_THREADS=1``,
set below before numpy loads): MUMPS' threads only slow it down on a shared 2-core machine.

Then the whole process, as a user runs it: ``feltool gait`` of each shipped walker (design,
verification, orbit closure and Poincaré analysis included, its config written) timed from
launch to exit: the first design ever (a fresh ``FELTOOL_CACHE``: the walker's one library
compiled; ``repeats`` times, each in a cache of its own: min and median, the load printed
with each), a new design with other options (speed, step, slope, torso: the walker's library
cached, nothing compiled, checked), and the first command repeated (the median of
``repeats``), against the targets (compass gait 3 s, three-link 5 s, five-link 8 s on a 2-core
machine); and ``feltool --help`` (0.5 s).

Usage: ``python benchmarks/gait_design.py [repeats] [--whole-only]`` (default 5)
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from feltool.config.files import read_yaml
from feltool.gait.config import gait_spec, walker_from_raw
from feltool.gait.design import design_gait

CONFIGS = Path(__file__).resolve().parents[1] / "configs" / "gaits"
CASES = [  # label, config, designer options (as feltool gait's; the shipped configs' headers)
    ("compass gait, passive, 3 deg slope", "compass_gait",
     {"passive": True, "slope": float(np.deg2rad(3.0))}),
    ("compass gait, hip motor, 0.03 rad slope", "compass_gait",
     {"step_length": 0.4, "duration": 0.6}),
    ("three-link walker (torso 0.1 rad)", "three_link_walker",
     {"step_length": 0.5, "duration": 0.6, "torso": 0.1, "friction_margin": 0.6,
      "normal_force_margin": 0.5}),
    ("five-link walker with knees", "five_link_walker",
     {"speed": 0.8, "duration": 0.5, "torso": 0.1}),
]


def main(repeats: int = 5) -> None:
    rows = []
    for label, name, options in CASES:
        raw = read_yaml(CONFIGS / f"{name}.yaml")
        walker, settings = walker_from_raw(raw, CONFIGS / f"{name}.yaml")
        spec = gait_spec(raw, walker, settings, **options)
        runs = [design_gait(walker, spec) for _ in range(repeats)]
        solve = float(np.median([g.stats["solve_time_s"] for g in runs]))
        build = float(np.median([g.stats["build_time_s"] for g in runs]))
        g = runs[-1]
        m = g.metrics
        rows.append((label, solve, build, g.stats["iterations"], g.stats["knots"], m))
        print(f"{label}: solve {solve:.3f} s (median of {repeats}), build {build:.2f} s, "
              f"{g.stats['iterations']} iterations", file=sys.stderr, flush=True)
    print("| walker | solve [s] | build [s] | iterations | knots | period [s] | speed [m/s] | "
          "step [m] | CoT | min F_n / mg | max abs(F_t)/F_n | impulse ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for label, solve, build, it, knots, m in rows:
        print(f"| {label} | {solve:.3f} | {build:.2f} | {it} | {knots} | {m['period_s']:.3f} | "
              f"{m['speed_m_per_s']:.3f} | {m['step_length_m']:.3f} | "
              f"{m['cost_of_transport']:.3f} | {m['min_normal_force_mg']:.2f} | "
              f"{m['max_friction_ratio']:.2f} | {m['impulse_ratio']:.2f} |")


WHOLE = [  # label, config, feltool gait's options (the configs' headers), another design's, target
    ("compass gait", "compass_gait", ["--step-length", "0.4", "--duration", "0.6"],
     ["--step-length", "0.45", "--duration", "0.62", "--slope", "0.04"], 3.0),
    ("three-link walker", "three_link_walker",
     ["--step-length", "0.5", "--duration", "0.6", "--torso", "0.1", "--friction-margin", "0.6",
      "--normal-force-margin", "0.5"],
     ["--step-length", "0.45", "--duration", "0.55", "--torso", "0.12", "--friction-margin",
      "0.6", "--normal-force-margin", "0.5"], 5.0),
    ("five-link walker", "five_link_walker",
     ["--speed", "0.8", "--duration", "0.5", "--torso", "0.1"],
     ["--speed", "0.7", "--duration", "0.55", "--torso", "0.05"], 8.0),
]


def whole_process(repeats: int = 5) -> None:
    """``feltool gait`` and ``feltool --help`` timed from launch to exit (module docstring):
    per walker the first design ever (an empty cache: the walker's library compiled), then
    another design with other options (the walker's library cached, nothing compiled: the
    columns a user meets designing), then the first command repeated (the median of
    ``repeats``)."""
    import subprocess
    import tempfile
    import time

    feltool = [sys.executable, "-m", "feltool.cli"]

    def timed(args, env=None) -> float:
        t0 = time.perf_counter()
        proc = subprocess.run(feltool + args, capture_output=True, text=True, env=env)
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            raise SystemExit(f"{' '.join(args)} exited {proc.returncode}: {proc.stderr[-500:]}")
        return seconds

    print(f"\n{load()} at the start")
    print("| command | first ever (empty cache), min / median [s] | new design, walker's "
          "library cached [s] | repeated (median) [s] | target [s] | first ever (median) / "
          "target |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for _label, name, options, other, target in WHOLE:
            args = lambda opts, out, name=name: [  # noqa: E731
                "gait", str(CONFIGS / f"{name}.yaml"), *opts, "--out", f"{tmp}/{out}.yaml",
                "--no-progress"]
            colds = []
            for i in range(repeats):  # each in an empty cache of its own
                env = {**os.environ, "FELTOOL_CACHE": f"{tmp}/cache-{name}-{i}"}
                colds.append(timed(args(options, name), env))
                print(f"  {name} first ever: {colds[-1]:.2f} s ({load()})", file=sys.stderr,
                      flush=True)
            cold, cold_min = float(np.median(colds)), min(colds)
            libs = sorted(Path(f"{tmp}/cache-{name}-{i}/compiled").glob("*.so"))
            new = timed(args(other, name + "-other"), env)
            if sorted(Path(f"{tmp}/cache-{name}-{i}/compiled").glob("*.so")) != libs:
                raise SystemExit(f"{name}: the other design compiled a library of its own")
            warm = float(np.median([timed(args(options, name), env) for _ in range(repeats)]))
            print(f"| feltool gait {name} | {cold_min:.2f} / {cold:.2f} | {new:.2f} | "
                  f"{warm:.2f} | {target:g} | {cold / target:.2f} |", flush=True)
        help_s = float(np.median([timed(["--help"]) for _ in range(repeats)]))
        print(f"| feltool --help | - | - | {help_s:.2f} | 0.5 | {help_s / 0.5:.2f} |")
    print(f"{load()} at the end")


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} cores"


if __name__ == "__main__":
    count = int(sys.argv[1]) if len(sys.argv) > 1 and sys.argv[1].isdigit() else 5
    if "--whole-only" not in sys.argv:
        main(count)
    whole_process(count)
