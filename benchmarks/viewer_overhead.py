"""How much the live viewer slows learning: steps per second of ``run_seed`` with and without
``feltool run --view``'s stream, in one process.

    python benchmarks/viewer_overhead.py [--cycles 1500] [--repeats 7] [--browser]

Runs the same seed alternately without a viewer and with a :class:`feltool.viewer.rollout.LiveStream`
on a private meshcat server (30 frames per second, as ``--view``), and prints the median steps
per second of each, the slowdown, and the CPU share of the drawing process. With ``--browser`` a
headless Chromium shows the page meanwhile, so the server forwards every frame to a browser.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
import warnings

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed
from feltool.viewer.live import LiveViewer
from feltool.viewer.rollout import LiveStream


def steps_per_s(exp, cycles: int, on_cycle=None) -> float:
    t0 = time.perf_counter()
    run_seed(exp, 0, cycles, on_cycle=on_cycle)
    return cycles * exp.primitives.n_steps / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="two_link_standard")
    parser.add_argument("--cycles", type=int, default=1500)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--browser", action="store_true")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    exp = load_experiment(args.config)
    steps_per_s(exp, 20)  # warm up
    plain, viewed = [], []
    with LiveViewer(exp.robot, quiet=True) as viewer:
        browser = None
        if args.browser:
            browser = subprocess.Popen(
                ["/usr/bin/chromium", "--headless", "--no-sandbox", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--disable-gpu", "--no-first-run",
                 f"--user-data-dir={tempfile.mkdtemp()}", "--remote-debugging-port=0",
                 viewer.url], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            time.sleep(3)
        try:
            cpu = []
            for r in range(args.repeats):
                for viewing in ((False, True) if r % 2 else (True, False)):  # alternate order
                    if not viewing:
                        plain.append(steps_per_s(exp, args.cycles))
                        continue
                    with LiveStream(viewer, exp.config.dt, args.cycles, out=None) as stream:
                        t0 = time.perf_counter()
                        viewed.append(steps_per_s(exp, args.cycles, stream))
                        elapsed = time.perf_counter() - t0
                    # the drawing process reports its statistics when the stream closes
                    cpu.append(stream.draw_cpu_s / elapsed)
                    frames = stream.frames_drawn
        finally:
            if browser is not None:
                browser.terminate()
                browser.wait()
    a, b = statistics.median(plain), statistics.median(viewed)
    paired = statistics.median(1 - v / p for p, v in zip(plain, viewed, strict=True))
    print(f"{args.config}: {args.cycles} cycles x {args.repeats}, median steps/s: without viewer "
          f"{a:.0f}, with --view {b:.0f} ({frames} frames in the last run): "
          f"slowdown {100 * (1 - b / a):.1f} % (median of paired runs "
          f"{100 * paired:.1f} %); the drawing process used "
          f"{100 * statistics.median(cpu):.1f} % of a core")


if __name__ == "__main__":
    main()
