"""Learning-loop speed of both engines, every figure against references measured in the same run.

    nice python benchmarks/backends.py [--repeats 3] [--plot docs/figures/performance.png]

References (this machine's limits, measured first):
  * bare ABA: a Python loop of ``pin.aba`` and semi-implicit Euler on the standard arm, nothing
    else (what one Pinocchio call per step costs from Python);
  * C step: the standard arm's closed-loop step written by hand in C (benchmarks/arm_step.c:
    closed-form RNEA and ABA, PD, Euler, compiled with cc -O2; checked against Pinocchio
    before it is timed): what one control step can cost at all.

Then, per shipped experiment, the learning loop's control steps per second on the Python
engine and on the compiled engine (the 3D legged trot: the Python loop only, from its start
including the speed ramp, a few cycles) (``summary.json``'s ``steps_per_s``: the time inside the
learning cycles only, compilation excluded; best of ``--repeats`` runs), the ratio of the two
and each as a ratio to the references; the cost per step as the number of basis functions
grows; the time to a first result with an empty cache; and the whole 20-seed thesis run as
``make run`` does it (``feltool run configs/two_link_standard.yaml``, wall time from the
command's start), with a warm and with an empty cache. The load average is printed at the start
and the end: other jobs on the machine slow every figure, the ratios less.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.learning.rates import translate
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
NO_POINCARE = ["walking.poincare=false"]  # the analysis after the run: not the learning loop
EXPERIMENTS = [  # (label, config, overrides)
    ("standard arm (2 DoF, 100 Hz)", "two_link_standard", []),
    ("human arm (2 DoF, 50 Hz)", "two_link_human_arm", []),
    ("UR5 wrist level (3 DoF, frame target)", "ur5_wrist_level", []),
    ("Panda hand level (3 DoF, 1 kHz)", "panda_hand_level", []),
    ("arm, plant mismatch + model FEL (1 kHz)", "two_link_standard_mismatch", []),
    ("biped, relabel impacts (200 Hz)", "biped_torso", []),
    ("biped, rigid impacts (200 Hz)", "biped_torso_rigid", []),
    ("physical walker: compass gait", "gaits/compass_gait", NO_POINCARE),
    ("physical walker: three-link", "gaits/three_link_walker", NO_POINCARE),
    ("physical walker: five-link", "gaits/five_link_walker", NO_POINCARE),
]
BASIS = (10, 20, 40, 80)


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.2f} (1 min), {five:.2f} (5 min) on {os.cpu_count()} cores"


# -- references ----------------------------------------------------------------------------------
def bare_aba(steps: int = 200_000) -> float:
    """Steps/s of a Python loop of pin.aba + semi-implicit Euler on the standard arm."""
    exp = load_experiment(CONFIGS / "two_link_standard.yaml", ["backend=pinocchio"])
    model, data = exp.robot.model, exp.robot.model.createData()
    q, v, tau, dt = np.array([1.5, 0.2]), np.zeros(2), np.array([1.0, -0.5]), exp.config.dt
    t0 = time.perf_counter()
    for _ in range(steps):
        a = pin.aba(model, data, q, v, tau)
        v = v + dt * a
        q = q + dt * v
    return steps / (time.perf_counter() - t0)


def c_step(directory: Path, steps: int = 5_000_000) -> float:
    """Steps/s of the hand-written C closed-loop step of the standard arm (arm_step.c), after
    checking its RNEA and ABA against Pinocchio's at seeded random states (1e-10)."""
    lib_path = directory / "arm_step.so"
    cc = shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")
    subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(lib_path),
                    str(Path(__file__).with_name("arm_step.c")), "-lm"], check=True)
    lib = ctypes.CDLL(str(lib_path))
    P = ctypes.POINTER(ctypes.c_double)
    lib.arm_run.restype = ctypes.c_double
    lib.arm_run.argtypes = [ctypes.c_long, ctypes.c_long, P, P, ctypes.c_double,
                            ctypes.c_double, P, P, ctypes.c_double]
    for fn in (lib.arm_rnea, lib.arm_aba):
        fn.argtypes, fn.restype = [P, P, P, ctypes.c_double, P], None
    ptr = lambda a: a.ctypes.data_as(P)  # noqa: E731
    exp = load_experiment(CONFIGS / "two_link_standard.yaml", ["backend=pinocchio"])
    model, data, g = exp.robot.model, exp.robot.model.createData(), 9.8
    rng = np.random.default_rng(0)
    for _ in range(20):
        q, v, a = (rng.uniform(-2, 2, 2) for _ in range(3))
        out = np.zeros(2)
        lib.arm_rnea(ptr(q), ptr(v), ptr(a), g, ptr(out))
        assert np.abs(out - pin.rnea(model, data, q, v, a)).max() < 1e-10, "C RNEA differs"
        lib.arm_aba(ptr(q), ptr(v), ptr(a), g, ptr(out))
        assert np.abs(out - pin.aba(model, data, q, v, a)).max() < 1e-10, "C ABA differs"
    Qd, Vd, Ad = exp.primitives.desired(exp.initial_parameters(0))
    D = np.ascontiguousarray(np.hstack([Qd, Vd, Ad]))
    x = np.array([Qd[0, 0], np.pi / 2 - Qd[0, 0], 0.0, 0.0])
    kp, kd = exp.law.kp.copy(), exp.law.kd.copy()
    t0 = time.perf_counter()
    lib.arm_run(steps, len(D), ptr(D), ptr(x), exp.config.dt, g, ptr(kp), ptr(kd), np.pi / 2)
    return steps / (time.perf_counter() - t0)


# -- the engines -----------------------------------------------------------------------------------
def learning_speed(config: str, overrides: list[str], engine: str, repeats: int,
                   budget_s: float = 0.5) -> float:
    """Best steps/s of the learning loop (summary.json's steps_per_s) of seed 0 on
    ``engine``, over runs of about ``budget_s`` of cycles each (at most the config's)."""
    backend = "pinocchio" if engine == "python" else "compiled"
    exp = load_experiment(CONFIGS / f"{config}.yaml", [f"backend={backend}", *overrides])
    first = run_seed(exp, 0, 2)  # compiles (cached), and the time of a cycle
    per_cycle = first.summary["loop_s"] / max(1, len(first.rows))
    cycles = int(min(exp.config.sim.cycles, max(2, budget_s / max(per_cycle, 1e-9))))
    best = 0.0
    for _ in range(repeats):
        res = run_seed(exp, 0, cycles)
        best = max(best, res.summary["steps_per_s"] or 0.0)
    return best


def legged_speed(repeats: int, cycles: int = 6) -> float:
    """Best control steps/s of the 3D legged trot's learning loop (Solo-12, the Python loop
    with its QP allocation and the contact events; ``cycles`` cycles after the ramp, the
    reference taken as planned: acquiring it costs the same per step)."""
    from feltool.walking.legged.learn import learn_trot
    from feltool.walking.legged.model import load_solo12

    solo = load_solo12(effort=2.7)
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        run = learn_trot(solo, cycles=cycles, acquire=0)
        best = max(best, len(run.log.t) / (time.perf_counter() - t0))
    return best


def first_result(config: str) -> tuple[float, float]:
    """Seconds to the first cycle's result with an empty cache (build + generate C + compile +
    one cycle), and again with the cache filled."""
    times = []
    with tempfile.TemporaryDirectory() as cache:
        os.environ["FELTOOL_CACHE"] = cache
        for _ in range(2):
            t0 = time.perf_counter()
            over = NO_POINCARE if config.startswith("gaits/") else []
            run_seed(load_experiment(CONFIGS / f"{config}.yaml", ["backend=compiled", *over]),
                     0, 1)
            times.append(time.perf_counter() - t0)
    return times[0], times[1]


def make_run(cache: str | None) -> tuple[float, dict]:
    """Wall seconds of ``feltool run configs/two_link_standard.yaml`` (20 seeds x 150 cycles,
    backend auto) from the command's start, and its summary's timing (``cache``: the compiled
    cycles' cache, None: the user's)."""
    import json

    env = dict(os.environ)
    if cache is not None:
        env["FELTOOL_CACHE"] = cache
    feltool = Path(sys.executable).with_name("feltool")
    with tempfile.TemporaryDirectory() as out:
        t0 = time.perf_counter()
        subprocess.run([str(feltool), "run", str(CONFIGS / "two_link_standard.yaml"), "--out",
                        out + "/run", "--quiet"], check=True, capture_output=True, env=env)
        wall = time.perf_counter() - t0
        summary = json.loads((Path(out) / "run" / "summary.json").read_text())
    return wall, summary["timing"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--plot", type=Path, help="write the figure here (PNG)")
    args = parser.parse_args()
    user_cache = os.environ.get("FELTOOL_CACHE")
    os.environ["FELTOOL_CACHE"] = tempfile.mkdtemp(prefix="feltool-bench-")
    print(f"start: {load()}")

    with tempfile.TemporaryDirectory() as tmp:
        ref_c = c_step(Path(tmp))
    ref_aba = bare_aba()
    print("\n1. references (standard arm, steps/s)")
    print(f"  bare pin.aba loop in Python   {ref_aba:>14,.0f}   ({1e6 / ref_aba:.3f} us/step)")
    print(f"  hand-written C step           {ref_c:>14,.0f}   ({1e6 / ref_c:.3f} us/step)")

    print("\n2. learning steps/s (the learning cycles only; best of "
          f"{args.repeats}), and as ratios")
    head = ("  | experiment | Python engine | compiled engine | compiled / Python | "
            "compiled / bare ABA | compiled / C step | Python / bare ABA |")
    print(head)
    print("  |---|---|---|---|---|---|---|")
    rows = []
    for label, config, over in EXPERIMENTS:
        py = learning_speed(config, over, "python", args.repeats)
        exp = load_experiment(CONFIGS / f"{config}.yaml", over)
        comp = learning_speed(config, over, "compiled", args.repeats) \
            if exp.engine == "compiled" else None
        rows.append((label, py, comp))
        c = (f"{comp:,.0f} | {comp / py:.1f}x | {comp / ref_aba:.2f} | {comp / ref_c:.3f}"
             if comp else f"- ({exp.engine_reason.split(': ', 2)[-1][:40]}) | - | - | -")
        print(f"  | {label} | {py:,.0f} | {c} | {py / ref_aba:.2f} |", flush=True)

    legged = legged_speed(args.repeats)
    print(f"  | 3D legged trot with FEL (Solo-12, configs/legged/solo12_trot) | {legged:,.0f} | "
          f"- (no compiled form of the legged loop yet: docs/legged.md, benchmarks/"
          f"legged_compiled_step.py) | - | - | "
          f"- | {legged / ref_aba:.4f} |", flush=True)

    print("\n3. cost per step [us] as the number of basis functions grows (standard arm; "
          "weight rate 0.2 (10/N)^2 so that every N learns)")
    print("  | basis functions | Python engine | compiled engine | compiled vs 10 |")
    print("  |---|---|---|---|")
    scaling = []
    for basis in BASIS:
        w, _ = translate(0.2 * (10 / basis)**2, 0.0, 1.0, 100.0, basis)  # (per sample)
        over = [f"primitives.basis={basis}", "learning.update=gradient",
                f"learning.rates.weights={w!r}"]
        py = learning_speed("two_link_standard", over, "python", args.repeats)
        comp = learning_speed("two_link_standard", over, "compiled", args.repeats)
        scaling.append((basis, 1e6 / py, 1e6 / comp))
        print(f"  | {basis} | {1e6 / py:.2f} | {1e6 / comp:.3f} | "
              f"{scaling[-1][2] / scaling[0][2]:.2f}x |", flush=True)

    print("\n4. time to the first result, compiled (build + generate C + compile + one cycle)")
    for config in ("two_link_standard", "ur5_wrist_level", "biped_torso_rigid",
                   "gaits/three_link_walker"):
        cold, warm = first_result(config)
        print(f"  {config:<24} empty cache {cold:6.2f} s, cache filled {warm:6.2f} s")

    print("\n5. make run: feltool run configs/two_link_standard.yaml (20 seeds x 150 cycles, "
          "backend auto), wall from the command's start")
    with tempfile.TemporaryDirectory() as empty:
        cold, t_cold = make_run(empty)
    if user_cache is not None:
        os.environ["FELTOOL_CACHE"] = user_cache
    else:
        os.environ.pop("FELTOOL_CACHE", None)
    make_run(None)  # fill the user's cache, as the first make run after install does
    warm = min(make_run(None)[0] for _ in range(args.repeats))
    print(f"  empty cache {cold:.2f} s (compile {t_cold['compile_s']:.2f} s); "
          f"cache filled {warm:.2f} s (best of {args.repeats})")
    print(f"\nend: {load()}")

    if args.plot:
        _plot(args.plot, rows, scaling, ref_aba, ref_c)
        print(f"figure: {args.plot}")


def _plot(path: Path, rows, scaling, ref_aba: float, ref_c: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [2, 1]})
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [r[1] for r in rows], 0.4, label="Python engine")
    ax.barh(y + 0.2, [r[2] or 0 for r in rows], 0.4, label="compiled engine")
    ax.axvline(ref_aba, color="k", ls=":", label="bare pin.aba loop (Python)")
    ax.axvline(ref_c, color="k", ls="--", label="hand-written C step (arm)")
    ax.set_yticks(y, [r[0] for r in rows], fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("learning steps per second (one core)")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(True, axis="x", which="both", alpha=0.3)
    basis = [s[0] for s in scaling]
    bx.plot(basis, [s[1] for s in scaling], "o-", label="Python engine")
    bx.plot(basis, [s[2] for s in scaling], "s-", label="compiled engine")
    bx.set_yscale("log")
    bx.set_xlabel("basis functions")
    bx.set_ylabel("cost per step [us]")
    bx.set_title("standard arm")
    bx.legend(fontsize=8)
    bx.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
