"""MuJoCo as the plant: the shipped walkers' gaits, designed on Pinocchio's rigid model, walked
by MuJoCo from cycle 1 (issue 28, acceptance 1d), one row per seed (docs/biped.md, "MuJoCo as
the plant").

Two starts per walker: ``shipped`` (the config as shipped: its torso RMP perturbed, as the rigid
walkers' configs) and ``designed`` (every motor and the torso at the design, ``init: demo``,
every one learned: the only thing to learn is what MuJoCo's world does differently; this start
draws nothing at random, so every seed is the same run and it runs once). Per seed:
whether every step walked (MuJoCo's contact checks on), the torso's RMS from its target in the
last cycle, the summed feedback of the first and last cycles and their ratio, the share of
the last cycle's feedback that falls in the 40 ms after each touchdown, and the last cycle's
feedback over time (the soft impact's transient: the cause where the ratio stays above 0.15).

Usage::

    python benchmarks/walk_mujoco.py [--seeds 0-9] [--cycles 150] [--workers 2]
        [--configs configs/gaits/five_link_walker_mujoco.yaml ...] [--starts shipped designed]
        [--out benchmarks/results/walk_mujoco.md]
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from feltool.engines.python import after_impacts
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = [ROOT / "configs" / "gaits" / "five_link_walker_mujoco.yaml",
           ROOT / "configs" / "gaits" / "three_link_walker_mujoco.yaml"]
WINDOW_S = 0.04  # after each touchdown


def overrides(config: Path, start: str) -> list[str]:
    """The ``--set`` overrides of a start (``fixed``: the designed start, nothing learned)."""
    if start == "shipped":
        return []
    probe = load_experiment(config)
    out = [f"joints.{j}.learn.init=demo" for j in probe.learned_joints]
    out += [f"joints.{m}.learn={{init: demo}}" for m in probe.hybrid.walker.motor_names
            if m not in probe.learned_joints]
    if start == "fixed":
        out += ["learning.rates.weights=0", "learning.rates.gauss_newton=0"]
    return out


def soften(exp, timeconst: float | None) -> None:
    """The contact's stiffness: MuJoCo's ``solref`` time constant [s] of the floor and the feet
    (its damping ratio kept; MuJoCo needs at least two timesteps, ``sim.substeps`` sets the
    timestep). None: as compiled (feltool.robot.mujoco.TIMECONST)."""
    if timeconst is None:
        return
    m = exp.hybrid.sim.model
    if timeconst < 2.0 * m.opt.timestep - 1e-12:
        raise SystemExit(f"--timeconst {timeconst}: below two MuJoCo timesteps "
                         f"({m.opt.timestep} s); raise --substeps")
    m.geom_solref[:, 0] = timeconst


def one(job: tuple) -> dict:
    config, start, seed, cycles = job[:4]
    timeconst, substeps = (job[4], job[5]) if len(job) > 4 else (None, None)
    over = overrides(Path(config), start)
    if substeps is not None:
        over.append(f"sim.substeps={substeps}")
    exp = load_experiment(config, over)
    soften(exp, timeconst)
    share: dict[str, float] = {}
    profile: list[float] = []

    def on_cycle(cycle, log, Qd, fb):
        if cycle not in (1, cycles):
            return
        U = np.abs(log.u_fb).sum(axis=1)
        mask = after_impacts(log.impacts, len(U), int(round(WINDOW_S / exp.config.dt)))
        share[str(cycle)] = float(U[mask].sum() / U.sum()) if U.sum() > 0 else float("nan")
        if cycle == cycles:  # the last cycle's summed |feedback| [N m] in 25 bins of time
            profile[:] = [float(b.mean()) for b in np.array_split(U, 25)]

    res = run_seed(exp, seed, cycles, on_cycle=on_cycle)
    fb = [r["fb_abs_mean_error"] for r in res.rows]
    walk = res.summary.get("walking") or {}
    return {"config": Path(config).stem, "start": start, "seed": seed,
            "timeconst": float(exp.hybrid.sim.model.geom_solref[0, 0]),
            "substeps": exp.config.sim.substeps, "rate_hz": exp.config.sim.rate_hz,
            "cycles_run": len(fb), "walked": bool(walk.get("walked")) and len(fb) == cycles,
            "reason": walk.get("reason") or res.summary.get("reason"),
            "torso_rms": walk.get("stabilized_rms_last_rad"),
            "fb_first": fb[0] if fb else float("nan"), "fb_last": fb[-1] if fb else float("nan"),
            "ratio": fb[-1] / fb[0] if fb else float("nan"),
            "impact_share_first": share.get("1"), "impact_share_last": share.get(str(cycles)),
            "profile": profile, "fb": fb}


def table(rows: list[dict]) -> str:
    out = ["| walker | start | seed | walks every step | torso RMS [rad] | feedback cycle 1 "
           "[N m] | last [N m] | last/first | share of last in 40 ms after touchdowns |",
           "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        walked = "yes" if r["walked"] else f"no ({r['reason']})"
        rms = f"{r['torso_rms']:.2g}" if r["torso_rms"] is not None else "-"
        share = (f"{r['impact_share_last']:.2f}" if r["impact_share_last"] is not None else "-")
        out.append(f"| {r['config']} | {r['start']} | {r['seed']} | {walked} | {rms} | "
                   f"{r['fb_first']:.3g} | {r['fb_last']:.3g} | {r['ratio']:.3f} | {share} |")
    return "\n".join(out)


def summary(rows: list[dict]) -> str:
    lines = []
    for key in sorted({(r["config"], r["start"]) for r in rows}):
        rs = [r for r in rows if (r["config"], r["start"]) == key]
        ratios = [r["ratio"] for r in rs]
        ok = [r["walked"] and (r["torso_rms"] or 1) < 0.01 and r["ratio"] <= 0.15 for r in rs]
        lines.append(f"- {key[0]}, {key[1]}: walks {sum(r['walked'] for r in rs)}/{len(rs)}, "
                     f"torso RMS <= {max(r['torso_rms'] or np.nan for r in rs):.2g} rad, "
                     f"last/first {min(ratios):.3f}-{max(ratios):.3f}, all three criteria "
                     f"{sum(ok)}/{len(rs)}")
        lines.append(f"  seed {rs[0]['seed']}'s last cycle, summed |feedback| [N m] in 25 bins of "
                     "time (touchdowns at its start and middle): "
                     + " ".join(f"{b:.2g}" for b in rs[0]["profile"]))
    return "\n".join(lines)


def stiffness_table(rows: list[dict]) -> str:
    """The contact-stiffness experiment's rows: per walker and solref time constant, the
    feedback of the first and last cycles from the design (nothing learned) and where the
    last cycle's is."""
    out = ["| walker | solref time constant [ms] | MuJoCo timestep [ms] | walks every step | "
           "feedback cycle 1 [N m] | last [N m] | share of last in 40 ms after touchdowns | "
           "last cycle in 25 bins [N m] |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        walked = "yes" if r["walked"] else f"no ({r['reason']})"
        share = (f"{r['impact_share_last']:.2f}" if r["impact_share_last"] is not None else "-")
        dt_ms = 1e3 / (r["rate_hz"] * r["substeps"])
        out.append(f"| {r['config']} | {1e3 * r['timeconst']:.3g} | {dt_ms:.3g} | {walked} | "
                   f"{r['fb_first']:.3g} | {r['fb_last']:.3g} | {share} | "
                   + " ".join(f"{b:.2g}" for b in r["profile"]) + " |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--configs", nargs="+", default=[str(c) for c in CONFIGS])
    ap.add_argument("--starts", nargs="+", default=["shipped", "designed"],
                    choices=["shipped", "designed"])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "walk_mujoco.md"))
    ap.add_argument("--stiffness", type=float, nargs="+", metavar="TIMECONST", default=None,
                    help="instead: the contact-stiffness experiment, the designed start with "
                    "nothing learned (start 'fixed', seed 0, --cycles) at each solref time "
                    "constant [s] (4 substeps; 8 below 1 ms; --substeps: all alike)")
    ap.add_argument("--substeps", type=int, default=None, help="with --stiffness: MuJoCo "
                    "steps per control step")
    args = ap.parse_args()
    if args.stiffness:
        jobs = [(c, "fixed", 0, args.cycles, tc, args.substeps or (8 if tc < 1e-3 else 4))
                for c in args.configs for tc in args.stiffness]
        with ProcessPoolExecutor(args.workers) as pool:
            rows = list(pool.map(one, jobs))
        print(stiffness_table(rows))
        Path(args.out).with_name("walk_mujoco_stiffness.json").write_text(
            json.dumps(rows, indent=1))
        return
    a, _, b = args.seeds.partition("-")
    seeds = range(int(a), int(b or a) + 1)
    # the designed start draws nothing at random: every seed is the same run, run once
    jobs = [(c, s, seed, args.cycles) for c in args.configs for s in args.starts
            for seed in (seeds if s == "shipped" else seeds[:1])]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(one, jobs))
    text = (f"MuJoCo as the plant, {args.cycles} cycles, seeds {args.seeds} "
            f"(benchmarks/walk_mujoco.py)\n\n{table(rows)}\n\n{summary(rows)}\n")
    print(text)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
