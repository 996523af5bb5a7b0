"""FEL against the other learners, side by side: the tables and figures of docs/comparison.md.

    OPENBLAS_NUM_THREADS=1 python benchmarks/methods.py [--seeds 10] [--robust-seeds 3]
        [--quick] [--parts arms,walker,cost] [--jobs 2] [--out benchmarks/results]

For every learner (gradient and gauss_newton FEL, P-type and norm-optimal ILC, feedback only)
on the standard arm, the human arm, the double-pendulum balance and the UR5 keeping its tool
level, over ``--seeds`` seeds (0..n-1) at each config's cycles:

* cycles to 5 %: the converged_cycle of summary.json (median and worst over seeds; "-" when a
  seed never stays below 5 % of its first-cycle feedback),
* final feedback: the error signal's mean |u_fb| in the last cycle [N m] (mean over seeds),
* final tracking error: RMS over the last cycle of reference minus controlled quantity (the
  tracked joint against its RMP, the stabilized link against its target), over the controlled
  quantities [rad] -- the task error, the same for every learner,
* computation per cycle: wall time per learning cycle [ms] (one core),
* learned numbers: how many values the learner stores.

Then the robustness scores on the standard arm (:mod:`feltool.runs.robustness`: every learner x
scenario, ``--robust-seeds`` seeds), and the transfer test of the thesis's claim that ILC needs
the same trajectory every cycle: after learning at T = 1 s, the period changes and the
learned result is replayed without further learning -- FEL's RMP re-timed, ILC's torque
sequence resampled by phase; and the cost of one learning update alone, best of 5, against the
simulation of the cycle (``--cost-only`` runs just that). Writes ``methods.json``,
``methods.md``, ``update_cost.{json,md}`` and figures into ``--out`` and
``docs/figures/methods_*.png``.

The physical five-link walker (``--parts walker``): every learner over ``--seeds`` seeds at
:data:`WALKER_CYCLES` cycles (cycles to 5 %, final feedback, the torso's RMS from its design
and the legs' tracking error over the last cycle, computation per cycle, learned numbers,
whether every step walked), and its robustness scores (``--robust-seeds`` seeds,
:data:`WALKER_ROBUST_CYCLES` cycles per point, the walker ranges of
:data:`feltool.robustness.WALKER_SCENARIOS`); writes ``methods_walker.{md,json}`` and
``docs/figures/methods_walker_*.png``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one core per learner, as measured

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from feltool.config.files import read_yaml
from feltool.control.feedback import wrap
from feltool.engines.ilc import channels, cycle_runner
from feltool.engines.ilc_walker import lifted_model
from feltool.runs.experiments import load_experiment
from feltool.runs.robustness import LEARNERS, SCENARIOS, WALKER_SCENARIOS, format_scores, robustness
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
FIGURES = ROOT / "docs" / "figures"
ARMS = {"standard arm": "two_link_standard", "human arm": "two_link_human_arm",
        "double pendulum": "double_pendulum_balance", "UR5": "ur5_wrist_level"}
# Each learner's settings: the configs' FEL rates; gauss_newton takes half the
# Levenberg-Marquardt step (learning.rates.gauss_newton 0.5); the ILC Q filter
# below the human arm's 25 Hz Nyquist frequency, and a smaller P-type gain on the UR5 (whose
# frame-angle torque reaches three joints; at L = 1 its feedback falls, then grows again).
SETTINGS = {
    "gradient": [],
    "gauss_newton": ["learning.rates.gauss_newton=0.5"],
    "ilc_p": [],
    "ilc_norm_optimal": [],
    "feedback_only": [],
}
PER_CONFIG = {("two_link_human_arm", "ilc_p"): ["ilc.cutoff_hz=10"],
              ("ur5_wrist_level", "ilc_p"): ["ilc.gain=0.3"],
              # gradient FEL on the walker: about 1 / the largest eigenvalue of J_m'J_m (the
              # torso weights' Gauss-Newton matrix in motor torques) at the first cycle, 37-55
              # on seeds 0-2, so that the step is stable; the config's own update is GN
              # (0.02 per sample: 97.156 in physical units, feltool.learning.rates)
              ("gaits/five_link_walker", "gradient"): ["learning.rates.weights=97.156"]}
WALKER = {"five-link walker": "gaits/five_link_walker"}
WALKER_CYCLES = 40  # the table's cycles (the config's 150 for time: 5 learners x 10 seeds)
WALKER_ROBUST_CYCLES = 30  # per point: gradient FEL (the slowest) undisturbed is at 0.05-0.1 by 10


def overrides(config: str, learner: str) -> list[str]:
    return [f"learning.update={learner}", *SETTINGS[learner], *PER_CONFIG.get((config, learner), [])]


def task_error(exp, traces) -> tuple[float, float]:
    """RMS of reference minus controlled quantity over the last cycle [rad]: over the
    stabilized quantities, and over the tracked ones."""
    Qd = traces["last_q_forward"]
    R, _ = exp.law.references(Qd, Qd)
    err = wrap(R - exp.law.quantity(traces["last_q_system"]))
    return (float(np.sqrt(np.mean(err[:, exp.law.stabilizing] ** 2))),
            float(np.sqrt(np.mean(err[:, exp.law.tracking] ** 2))))


def learned_numbers(exp, learner: str) -> int:
    if learner == "feedback_only":
        return 0
    if learner.startswith("ilc"):
        return len(channels(exp)[0]) * exp.primitives.n_steps
    return exp.learner.n_learned


def table(seeds: list[int], log, arms: dict | None = None, extra: list[str] | None = None
          ) -> tuple[dict, dict]:
    results, curves = {}, {}
    for arm, config in (arms or ARMS).items():
        for learner in LEARNERS:
            exp = load_experiment(CONFIGS / f"{config}.yaml",
                                  overrides(config, learner) + list(extra or []))
            per_seed, fb_curves = [], []
            for seed in seeds:
                res = run_seed(exp, seed)
                s = res.summary
                per_seed.append({"seed": seed, "converged_cycle": s["converged_cycle"],
                                 "fb_initial": s["fb_initial"], "fb_final": s["fb_final"],
                                 "fb_ratio": s["fb_ratio"], "diverged": s["diverged"],
                                 "task_error_rad": task_error(exp, res.traces)
                                 if "last_q_system" in res.traces and not s["diverged"]
                                 else None,
                                 "ms_per_cycle": 1e3 * s["wall_s"] / max(1, s["cycles"])})
                fb_curves.append([r["fb_abs_mean_error"] for r in res.rows])
            results[(arm, learner)] = {"config": config, "cycles": exp.config.sim.cycles,
                                       "learned_numbers": learned_numbers(exp, learner),
                                       "seeds": per_seed}
            curves[(arm, learner)] = fb_curves
            conv = [p["converged_cycle"] for p in per_seed]
            print(f"methods: {arm} {learner}: converged {conv}, fb_final "
                  f"{[round(p['fb_final'], 4) for p in per_seed]}", file=log, flush=True)
    return results, curves


def summarize(results: dict) -> str:
    lines = ["| robot | learner | cycles to 5 % (median / worst) | final feedback [N m] | "
             "final / first | final error, stabilized / tracked [rad] | computation per "
             "cycle [ms] | learned numbers |", "|---|---|---:|---:|---:|---:|---:|---:|"]
    for (arm, learner), r in results.items():
        ps = r["seeds"]
        conv = [p["converged_cycle"] for p in ps]
        div = sum(p["diverged"] for p in ps)
        if all(c is not None for c in conv):
            c = f"{int(np.median(conv))} / {max(conv)}"
        else:
            got = [c for c in conv if c is not None]
            c = (f"{int(np.median(got))} / - ({len(conv) - len(got)} never)" if got
                 else "never")
        ok = [p for p in ps if not p["diverged"]] or ps
        fb = np.mean([p["fb_final"] or np.nan for p in ok])
        ratio = np.mean([p["fb_ratio"] or np.nan for p in ok])
        te = np.array([p["task_error_rad"] for p in ps if p["task_error_rad"] is not None])
        te = f"{te[:, 0].mean():.3g} / {te[:, 1].mean():.3g}" if len(te) else "-"
        ms = np.median([p["ms_per_cycle"] for p in ps])
        note = f" ({div} diverged)" if div else ""
        if div == len(ps):
            fb_txt, ratio_txt = "-", "-"
        else:
            fb_txt, ratio_txt = f"{fb:.3g}", f"{ratio:.2g}"
        lines.append(f"| {arm} | {learner}{note} | {c} | {fb_txt} | {ratio_txt} | "
                     f"{te} | {ms:.2f} | {r['learned_numbers']} |")
    return "\n".join(lines)


def transfer(log, cycles: int = 150, seeds=(0, 1, 2), scales=(0.8, 1.25)) -> list[dict]:
    """Learn at the nominal period, then replay the learned result at another period without
    learning; feedback of the replayed cycle over the first cycle of learning from scratch."""
    rows = []
    base = CONFIGS / "two_link_standard.yaml"
    T, rate = float(read_yaml(base)["period_s"]), 100.0
    for learner in ("gradient", "ilc_p", "ilc_norm_optimal"):
        exp = load_experiment(base, overrides("two_link_standard", learner))
        for seed in seeds:
            theta0 = exp.initial_parameters(seed)
            run = cycle_runner(exp, theta0, seed, lambda p, exp=exp: exp.loop) \
                if learner.startswith("ilc") else None
            res = run_seed(exp, seed, cycles=cycles) if run is None else None
            theta = theta0
            if run is None:
                theta = theta0.copy()
                sl = exp.primitives.slices[exp.joints.index("elbow")]
                theta[sl.start:sl.stop - 1] = res.params["elbow.weights"]
                theta[sl.stop - 1] = res.params["elbow.goal"]
            else:
                Qd, Vd, _ = exp.primitives.desired(theta0)
                q, v = exp.law.consistent_state(Qd[0], Vd[0])
                for _ in range(cycles):
                    out = run(theta0, q, v, exp.dynamics)
                    q, v = out.q_end, out.v_end
                dU = run.state["dU"]
            for scale in scales:
                period = round(scale * T * rate) / rate
                new = load_experiment(base, ["learning.update=ilc_p", "ilc.gain=0",
                                             "ilc.cutoff_hz=null", f"period_s={period}"])
                replay = cycle_runner(new, theta, seed, lambda p, new=new: new.loop)
                if run is not None:  # the torque sequence, resampled by phase
                    n_old, n_new = len(dU), new.primitives.n_steps
                    phase_old = np.arange(n_old) / n_old
                    phase_new = np.arange(n_new) / n_new
                    replay.state["dU"] = np.stack(
                        [np.interp(phase_new, phase_old, dU[:, c], period=1.0)
                         for c in range(dU.shape[1])], axis=1)
                Qd, Vd, _ = new.primitives.desired(theta)
                q, v = new.law.consistent_state(Qd[0], Vd[0])
                fbs = []
                for _ in range(3):  # the third replayed cycle: past the start's transient
                    out = replay(theta, q, v, new.dynamics)
                    q, v = out.q_end, out.v_end
                    fbs.append(out.fb_error)
                scratch = load_experiment(base, [f"period_s={period}",
                                                 "learning.update=feedback_only"])
                first = run_seed(scratch, seed, cycles=1).rows[0]["fb_abs_mean_error"]
                rows.append({"learner": learner, "seed": seed, "period_s": period,
                             "fb_replayed": fbs[-1], "fb_scratch_first": first,
                             "ratio": fbs[-1] / first})
                print(f"transfer: {learner} seed {seed} T={period}: {fbs[-1]:.3g} N m "
                      f"({fbs[-1] / first:.3f} of a fresh start)", file=log, flush=True)
    return rows


def transfer_table(rows: list[dict]) -> str:
    periods = sorted({r["period_s"] for r in rows})
    lines = ["| learner | " + " | ".join(f"T = {p:g} s" for p in periods) + " |",
             "|---|" + "---:|" * len(periods)]
    for learner in dict.fromkeys(r["learner"] for r in rows):
        cells = []
        for p in periods:
            rs = [r["ratio"] for r in rows if r["learner"] == learner and r["period_s"] == p]
            cells.append(f"{np.mean(rs):.3f} ({min(rs):.3f}-{max(rs):.3f})")
        lines.append(f"| {learner} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def update_cost(repeats: int = 5) -> list[dict]:
    """Wall time of one learning update alone (best of ``repeats``), after one simulated
    cycle from seed 0's start, against the cycle's simulation [ms]."""

    def best(fn) -> float:
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return 1e3 * min(times)

    return [_cost_of(arm, config, best) for arm, config in ARMS.items()] + \
        [_walker_cost_of(robot, config, best) for robot, config in WALKER.items()]


def _walker_cost_of(robot: str, config: str, best) -> dict:
    """As :func:`_cost_of` for a physical walker: FEL's motor-space update, ILC's per-sample
    updates; norm-optimal ILC's lifted model and its factor are built once (timed apart)."""
    from feltool.engines.ilc_walker import norm_optimal_factor, phase_error
    from feltool.engines.python import error_torques, motor_step
    from feltool.learning.ilc import NormOptimalILC, PTypeILC

    exp = load_experiment(CONFIGS / f"{config}.yaml", overrides(config, "gauss_newton"))
    grad = load_experiment(CONFIGS / f"{config}.yaml", overrides(config, "gradient"))
    theta = exp.initial_parameters(0)
    P, Pv, Pa = exp.primitives.desired(theta)
    q, v = exp.hybrid.initial_state(P, Pv)
    log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
    ilc = exp.config.ilc
    hz = exp.config.sim.rate_hz
    p_type = PTypeILC(ilc.gain, round(ilc.lead_s * hz), ilc.cutoff_hz, ilc.order, hz)
    norm = NormOptimalILC(ilc.weight_error, ilc.weight_change)
    dU = np.zeros((exp.primitives.n_steps, exp.hybrid.walker.B.shape[1]))
    t0 = time.perf_counter()
    G, factor = norm_optimal_factor(exp, norm)
    setup_s = time.perf_counter() - t0

    def fel(e=exp):
        _, *d = e.hybrid.jacobian_derivatives(log)
        J = e.learner.jacobian(e.dynamics, theta, log.Qd, log.Vd, log.Ad, d,
                               samples=log.phase_index)
        motor_step(e, theta, log.allocation, J, error_torques(e, log))

    return {"robot": robot, "samples": exp.primitives.n_steps,
            "simulation_ms": best(lambda: exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)),
            "gradient_ms": best(lambda: fel(grad)), "gauss_newton_ms": best(fel),
            "ilc_p_ms": best(lambda: p_type.update(dU, phase_error(exp, log))),
            "ilc_norm_optimal_ms": best(lambda: norm.update(dU, phase_error(exp, log), G,
                                                            factor)),
            "norm_optimal_setup_s": setup_s}


def _cost_of(arm: str, config: str, best) -> dict:
    from feltool.learning.ilc import NormOptimalILC, PTypeILC, lifted_jacobian

    exp = load_experiment(CONFIGS / f"{config}.yaml")
    gn = load_experiment(CONFIGS / f"{config}.yaml", ["learning.update=gauss_newton"])
    theta = exp.initial_parameters(0)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_ff = exp.dynamics.inverse_batch(Qd, Vd, Ad)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    log = exp.loop.run_cycle(q, v, R, Rd, u_ff)
    inputs, outputs = channels(exp)
    ilc = exp.config.ilc
    hz = exp.config.sim.rate_hz
    p_type = PTypeILC(ilc.gain, round(ilc.lead_s * hz), ilc.cutoff_hz, ilc.order, hz)
    norm = NormOptimalILC(ilc.weight_error, ilc.weight_change)
    dU = np.zeros((len(Qd), len(inputs)))

    def fel(e=exp):
        _, *d = e.dynamics.inverse_derivatives_batch(Qd, Vd, Ad)
        e.learner.step(theta, e.learner.jacobian(e.dynamics, theta, Qd, Vd, Ad, d), log.u_err)

    def lifted():
        G = lifted_jacobian(exp.robot.model, exp.law, exp.loop.actuated, exp.loop.dt,
                            exp.loop.substeps, exp.loop.integrator, log.q, log.v, R, Rd,
                            exp.loop.actuated * (u_ff + log.u_fb), inputs, outputs,
                            exp.loop.error_rows)
        norm.update(dU, log.u_err[:, outputs], G)

    return {"robot": arm, "samples": len(Qd),
            "simulation_ms": best(lambda: exp.loop.run_cycle(q, v, R, Rd, u_ff)),
            "gradient_ms": best(fel), "gauss_newton_ms": best(lambda: fel(gn)),
            "ilc_p_ms": best(lambda: p_type.update(dU, log.u_err[:, inputs])),
            "ilc_norm_optimal_ms": best(lifted)}


def cost_table(rows: list[dict]) -> str:
    lines = ["| robot | samples per cycle | simulating the cycle | gradient | gauss_newton | "
             "ilc_p | ilc_norm_optimal | norm-optimal set-up, once [s] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        setup = r.get("norm_optimal_setup_s")
        lines.append(f"| {r['robot']} | {r['samples']} | {r['simulation_ms']:.2f} | "
                     f"{r['gradient_ms']:.2f} | {r['gauss_newton_ms']:.2f} | "
                     f"{r['ilc_p_ms']:.2f} | {r['ilc_norm_optimal_ms']:.2f} | "
                     f"{'-' if setup is None else f'{setup:.1f}'} |")
    return "\n".join(lines)


def write_cost(out: Path) -> str:
    rows = update_cost()
    md = "\n".join(["## One learning update alone [ms] (best of 5, one core)", "",
                     cost_table(rows), ""])
    out.mkdir(parents=True, exist_ok=True)
    (out / "update_cost.json").write_text(json.dumps(rows, indent=1))
    (out / "update_cost.md").write_text(md)
    return md


def walker_table(seeds: list[int], log) -> tuple[dict, dict]:
    """Every learner on the five-link walker: per seed the summary's numbers, the torso's RMS
    from its design and the legs' tracking RMS over the last cycle [rad]."""
    results, curves = {}, {}
    for robot, config in WALKER.items():
        for learner in LEARNERS:
            exp = load_experiment(CONFIGS / f"{config}.yaml",
                                  overrides(config, learner) + ["walking.poincare=false"])
            legs = [i for i, n in enumerate(exp.joints)
                    if exp.law.tracking[i] and n not in exp.learned_joints]
            build_s = None
            if learner == "ilc_norm_optimal":  # once per known model, reused by every seed
                t0 = time.perf_counter()
                lifted_model(exp)
                build_s = round(time.perf_counter() - t0, 2)
            per_seed, fb_curves = [], []
            for seed in seeds:
                res = run_seed(exp, seed, cycles=WALKER_CYCLES)
                s, w = res.summary, res.summary["walking"]
                legs_rms = None
                if "last_q_system" in res.traces:
                    d = res.traces["last_q_system"][:, legs] - res.traces["last_q_forward"][:, legs]
                    legs_rms = float(np.sqrt(np.mean(d ** 2)))
                per_seed.append({"seed": seed, "converged_cycle": s["converged_cycle"],
                                 "fb_initial": s["fb_initial"], "fb_final": s["fb_final"],
                                 "fb_ratio": s["fb_ratio"], "diverged": s["diverged"],
                                 "walked": w["walked"], "not_walking": w.get("reason"),
                                 "torso_rms_rad": w.get("stabilized_rms_last_rad"),
                                 "legs_rms_rad": legs_rms,
                                 "ms_per_cycle": 1e3 * s["wall_s"] / max(1, s["cycles"])})
                fb_curves.append([r["fb_abs_mean_error"] for r in res.rows])
            learned = (exp.primitives.n_steps * exp.hybrid.walker.B.shape[1]
                       if learner.startswith("ilc") else learned_numbers(exp, learner))
            results[(robot, learner)] = {"config": config, "cycles": WALKER_CYCLES,
                                         "learned_numbers": learned, "seeds": per_seed,
                                         "lifted_model_s": build_s}
            curves[(robot, learner)] = fb_curves
            print(f"methods: {robot} {learner}: converged "
                  f"{[p['converged_cycle'] for p in per_seed]}, ratio "
                  f"{[round(p['fb_ratio'] or np.nan, 5) for p in per_seed]}, walked "
                  f"{sum(p['walked'] for p in per_seed)}/{len(per_seed)}", file=log, flush=True)
    return results, curves


def walker_summary(results: dict) -> str:
    lines = ["| robot | learner | walked | cycles to 5 % (median / worst) | final feedback [N m] "
             "| final / first (median, worst) | torso from design / legs' tracking, last cycle "
             "[rad] | computation per cycle [ms] | learned numbers |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for (robot, learner), r in results.items():
        ps = r["seeds"]
        conv = [p["converged_cycle"] for p in ps]
        got = [c for c in conv if c is not None]
        if len(got) == len(conv):
            c = f"{int(np.median(conv))} / {max(conv)}"
        else:
            c = (f"{int(np.median(got))} / - ({len(conv) - len(got)} never)" if got
                 else "never")
        walked = [p for p in ps if p["walked"]]
        ratios = [p["fb_ratio"] for p in walked if p["fb_ratio"] is not None] or [np.nan]
        fb = np.mean([p["fb_final"] for p in walked]) if walked else np.nan
        torso = np.mean([p["torso_rms_rad"] for p in walked]) if walked else np.nan
        legs = np.mean([p["legs_rms_rad"] for p in walked]) if walked else np.nan
        ms = np.median([p["ms_per_cycle"] for p in ps])
        lines.append(f"| {robot} | {learner} | {len(walked)}/{len(ps)} | {c} | {fb:.3g} | "
                     f"{np.median(ratios):.2g}, {max(ratios):.2g} | {torso:.2g} / {legs:.2g} | "
                     f"{ms:.0f} | {r['learned_numbers']} |")
    return "\n".join(lines)


def walker_part(seeds: list[int], robust_seeds: int, jobs: int, out: Path, log,
                robust: bool = True) -> str:
    """The walker's table, its robustness scores and figures; returns the Markdown."""
    t0 = time.perf_counter()
    results, curves = walker_table(seeds, log)
    md = [f"## Learners side by side on the physical five-link walker ({WALKER_CYCLES} cycles)",
          "", walker_summary(results), ""]
    rob = None
    if robust:
        config = CONFIGS / f"{WALKER['five-link walker']}.yaml"
        rob = robustness(read_yaml(config), config, list(LEARNERS),
                         list(WALKER_SCENARIOS.values()), list(range(robust_seeds)),
                         WALKER_ROBUST_CYCLES,
                         {lr: overrides(WALKER["five-link walker"], lr)[1:] for lr in LEARNERS},
                         log, jobs)
        md += [f"## Robustness scores (five-link walker, {WALKER_ROBUST_CYCLES} cycles per "
               "point)", "", format_scores(rob), ""]
        md += ["| scenario | values | unit | what |", "|---|---|---|---|"]
        md += [f"| {s.name} | {', '.join(f'{v:g}' for v in s.values) or 'n/a'} | {s.unit} | "
               f"{s.not_applicable and 'not applicable: ' + s.not_applicable or s.description} |"
               for s in WALKER_SCENARIOS.values()]
        md.append("")
    out.mkdir(parents=True, exist_ok=True)
    (out / "methods_walker.json").write_text(json.dumps(
        {"table": [{"robot": rb, "learner": lr, **r, "curves": curves[(rb, lr)]}
                   for (rb, lr), r in results.items()],
         "robustness": rob, "seeds": seeds, "wall_s": round(time.perf_counter() - t0, 1)},
        indent=1))
    (out / "methods_walker.md").write_text("\n".join(md))
    for path in figures(curves, rob, WALKER, "methods_walker_feedback.png",
                        "methods_walker_robustness.png", "robustness, five-link walker"):
        print(f"wrote {path}", file=log)
    return "\n".join(md)


def figures(curves: dict, rob: dict | None, robots: dict | None = None,
            convergence: str = "methods_feedback_convergence.png",
            scores: str = "methods_robustness.png",
            title: str = "robustness, standard arm") -> list[Path]:
    written = [convergence_figure(curves, robots or ARMS, convergence)]
    if rob is not None:
        written.append(scores_figure(rob, scores, title))
    return written


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    FIGURES.mkdir(parents=True, exist_ok=True)
    return plt


def convergence_figure(curves: dict, robots: dict, name: str) -> Path:
    """Mean |error feedback| per cycle, mean and min-max over seeds, one panel per robot."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(robots), figsize=(4.2 * len(robots) + 1.0, 3.4))
    for ax, arm in zip(np.atleast_1d(axes), robots):
        for learner in LEARNERS:
            runs = curves.get((arm, learner))
            if not runs:
                continue
            n = min(len(r) for r in runs)
            F = np.array([r[:n] for r in runs])
            x = np.arange(1, n + 1)
            line, = ax.semilogy(x, F.mean(axis=0), label=learner)
            ax.fill_between(x, F.min(axis=0), F.max(axis=0), alpha=0.15, color=line.get_color())
        ax.set_title(arm)
        ax.set_xlabel("cycle")
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("mean |error feedback| [N m]")
    np.atleast_1d(axes)[-1].legend(fontsize=8)
    fig.tight_layout()
    path = FIGURES / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def scores_figure(rob: dict, name: str, title: str) -> Path:
    """The robustness scores as a learner x scenario map (n/a: not applicable)."""
    plt = _pyplot()
    names = list(rob["scenarios"])
    learners = list(rob["scores"])
    S = np.array([[np.nan if rob["scores"][lr][n] is None else rob["scores"][lr][n]
                   for n in names] for lr in learners])
    fig, ax = plt.subplots(figsize=(7.5, 3.0))
    im = ax.imshow(S, vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(names)), names, rotation=30)
    ax.set_yticks(range(len(learners)), learners)
    for i in range(len(learners)):
        for j in range(len(names)):
            na = np.isnan(S[i, j])
            ax.text(j, i, "n/a" if na else f"{S[i, j]:.2f}", ha="center", va="center",
                    color="black" if na or S[i, j] >= 0.6 else "white", fontsize=8)
    fig.colorbar(im, ax=ax, label="score")
    ax.set_title(title)
    fig.tight_layout()
    path = FIGURES / name
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0..n-1 for the table")
    ap.add_argument("--robust-seeds", type=int, default=3, help="seeds per robustness point")
    ap.add_argument("--quick", action="store_true", help="2 seeds, no robustness (a smoke run)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--cost-only", action="store_true",
                    help="only the cost of one update (update_cost.md/json)")
    ap.add_argument("--parts", default="arms,walker,cost",
                    help="comma-separated: arms (tables, robustness, transfer), walker, cost")
    ap.add_argument("--jobs", type=int, default=1, help="robustness points run at the same time")
    args = ap.parse_args(argv)
    log = sys.stderr
    parts = {p.strip() for p in args.parts.split(",")}
    if args.cost_only:
        parts = {"cost"}
    t0 = time.perf_counter()
    seeds = list(range(2 if args.quick else args.seeds))
    if "walker" in parts:
        print(walker_part(seeds, args.robust_seeds, args.jobs, args.out, log,
                          robust=not args.quick))
    if "arms" in parts:
        arms_part(args, seeds, log)
    if "cost" in parts:
        print(write_cost(args.out))
    print(f"\n({time.perf_counter() - t0:.0f} s)")
    return 0


def arms_part(args, seeds: list[int], log) -> None:
    """The arms' tables, robustness scores, transfer test and figures (methods.{md,json})."""
    t0 = time.perf_counter()
    results, curves = table(seeds, log)
    md = ["## Learners side by side", "", summarize(results), ""]
    alle, _ = table(seeds, log, {"standard arm": "two_link_standard"},
                    ["learning.error=all_feedback"])
    md += ["## Standard arm, every joint's feedback as the error signal", "", summarize(alle),
           ""]
    rob = None
    if not args.quick:
        config = CONFIGS / "two_link_standard.yaml"
        raw = read_yaml(config)
        rob = robustness(raw, config, list(LEARNERS), list(SCENARIOS.values()),
                         list(range(args.robust_seeds)), 150,
                         {lr: overrides("two_link_standard", lr)[1:] for lr in LEARNERS}, log,
                         args.jobs)
        md += ["## Robustness scores (standard arm)", "", format_scores(rob), ""]
        md += ["| scenario | values | unit | what |", "|---|---|---|---|"]
        md += [f"| {s.name} | {', '.join(f'{v:g}' for v in s.values)} | {s.unit} | "
               f"{s.description} |" for s in SCENARIOS.values()]
        md.append("")
    rows = transfer(log, seeds=seeds[:3])
    md += ["## Replaying the learned result at another period (standard arm)", "",
           "Feedback of the third replayed cycle, no learning, over the first cycle of a fresh "
           "start at that period (mean, min-max over seeds):", "", transfer_table(rows), ""]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "methods.json").write_text(json.dumps(
        {"table": [{"robot": arm, "learner": lr, **r} for (arm, lr), r in results.items()],
         "table_all_feedback": [{"robot": arm, "learner": lr, **r}
                                for (arm, lr), r in alle.items()],
         "robustness": rob, "transfer": rows, "seeds": seeds,
         "wall_s": round(time.perf_counter() - t0, 1)}, indent=1))
    (args.out / "methods.md").write_text("\n".join(md))
    for path in figures(curves, rob):
        print(f"wrote {path}", file=log)
    print("\n".join(md))


if __name__ == "__main__":
    sys.exit(main())
