"""Model mismatch study: trajectory FEL, model FEL and both on a 30 % heavier link 2 (issue 8).

Runs the three variants of ``configs/two_link_standard_mismatch.yaml`` for several seeds, draws
``docs/figures/mismatch_feedback.png`` and prints the numbers quoted in docs/model_learning.md::

    PYTHONPATH=. python scripts/mismatch_study.py --seeds 20 --cycles 400
    PYTHONPATH=. python scripts/mismatch_study.py --seeds 20 --cycles 300 --interference
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from feltool.learning.model import identifiability, inertial_parameters
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parent.parent
#: Rows of the "when they interfere" table: label -> --set overrides (stabilizing feedback at the
#: last cycle, every seed; ``--interference``).
INTERFERENCE = {
    "all_feedback, nominal": ["learning.model.error=all_feedback", "learning.model.jacobian=nominal"],
    "all_feedback, learned": ["learning.model.error=all_feedback"],
    "all_feedback, nominal, model rate 1.5e-7": ["learning.model.error=all_feedback",
                                                  "learning.model.jacobian=nominal",
                                                  "learning.model.rate=1.5e-7"],
    "all_feedback, nominal, goal rate 2e-5": ["learning.model.error=all_feedback",
                                              "learning.model.jacobian=nominal",
                                              "learning.rates.goal=2e-5"],
    "tracking (the config)": [],
    "tracking, goal rate 2e-5": ["learning.rates.goal=2e-5"],
}
CONFIG = ROOT / "configs" / "two_link_standard_mismatch.yaml"
VARIANTS = {  # label -> --set overrides
    "(i) trajectory FEL alone": ["learning.model=null"],
    "(ii) model FEL alone": ["joints.elbow.learn=null", "learning.model.error=all_feedback"],
    "(iii) trajectory + model FEL": [],
}


def _run(args):
    label, seed, cycles = args
    exp = load_experiment(CONFIG, VARIANTS[label])
    res = run_seed(exp, seed, cycles)
    return label, seed, res.rows, res.params.get("model.theta")


def _run_row(args):
    label, seed, cycles = args
    res = run_seed(load_experiment(CONFIG, INTERFERENCE[label]), seed, cycles)
    return label, seed, (None if res.summary["diverged"] else
                         res.rows[-1]["fb_abs_mean_stabilized"])


def interference(seeds: int, cycles: int, workers: int) -> None:
    """The "when they interfere" table: stabilizing feedback after ``cycles`` per seed."""
    jobs = [(label, s, cycles) for label in INTERFERENCE for s in range(seeds)]
    with ProcessPoolExecutor(workers) as pool:
        results = list(pool.map(_run_row, jobs))
    out = {}
    for label in INTERFERENCE:
        vals = [v for lab, _, v in results if lab == label]
        ok = [v for v in vals if v is not None]
        out[label] = {"diverged": len(vals) - len(ok), "mean": float(np.mean(ok)) if ok else None,
                      "min": min(ok, default=None), "max": max(ok, default=None),
                      "per_seed": [None if v is None else round(v, 4) for v in vals]}
    print(json.dumps({"seeds": seeds, "cycles": cycles, "rows": out}, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--cycles", type=int, default=300)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "mismatch_feedback.png")
    ap.add_argument("--interference", action="store_true",
                    help="print the error-signal/Jacobian/rate table instead")
    a = ap.parse_args()
    if a.interference:
        interference(a.seeds, a.cycles, a.workers)
        return
    jobs = [(label, s, a.cycles) for label in VARIANTS for s in range(a.seeds)]
    with ProcessPoolExecutor(a.workers) as pool:
        results = list(pool.map(_run, jobs))
    curves = {label: {"total": [], "stabilized": []} for label in VARIANTS}
    thetas = {}
    for label, seed, rows, theta in results:
        curves[label]["total"].append([r["fb_abs_mean_total"] for r in rows])
        curves[label]["stabilized"].append([r["fb_abs_mean_stabilized"] for r in rows])
        thetas[(label, seed)] = theta
    plot(curves, a.out)
    report = {"seeds": a.seeds, "cycles": a.cycles, "variants": {}}
    for label, c in curves.items():
        tot, stab = np.array(c["total"]), np.array(c["stabilized"])
        report["variants"][label] = {
            "total_first_mean": tot[:, 0].mean(), "total_last_mean": tot[:, -1].mean(),
            "total_last_max_ratio": (tot[:, -1] / tot[:, 0]).max(),
            "stab_first_mean": stab[:, 0].mean(), "stab_last_mean": stab[:, -1].mean(),
            "stab_last_min": stab[:, -1].min(), "stab_last_max": stab[:, -1].max(),
            "stab_last_per_seed": stab[:, -1].round(4).tolist()}
    base = np.array(curves["(i) trajectory FEL alone"]["stabilized"])[:, -1]
    both = np.array(curves["(iii) trajectory + model FEL"]["stabilized"])[:, -1]
    report["both_below_trajectory_alone_every_seed"] = bool(np.all(both < base.min()))
    report["parameters"] = parameters(thetas[("(ii) model FEL alone", 0)])
    print(json.dumps(report, indent=1, default=float))


def parameters(theta_m: np.ndarray) -> dict:
    """Learned vs true inertial parameters of variant (ii), and what one motion identifies."""
    exp = load_experiment(CONFIG, VARIANTS["(ii) model FEL alone"])
    Qd, Vd, Ad = exp.primitives.desired(exp.theta_demo)
    feats = exp.model_learner.features
    Y = feats.features(Qd, Vd, Ad)
    ident = identifiability(Y)
    pi_m, pi_p = inertial_parameters(exp.dynamics.model), inertial_parameters(exp.plant.model)
    u_p = exp.plant.inverse_batch(Qd, Vd, Ad)
    u_l = exp.dynamics.inverse_batch(Qd, Vd, Ad) + Y @ theta_m
    seen = ident.projector @ (pi_p - pi_m)
    rows = {n: {"model": pi_m[i], "learned": pi_m[i] + theta_m[i], "plant": pi_p[i],
                "model+identifiable part of the mismatch": pi_m[i] + seen[i]}
            for i, n in enumerate(feats.names)
            if abs(pi_p[i] - pi_m[i]) > 1e-12 or abs(theta_m[i]) > 1e-4}
    return {"rank": ident.rank, "singular_values": ident.singular_values[:ident.rank + 1].tolist(),
            "identifiable_basis": {f"b{r}": {n: round(float(v), 3) for n, v in
                                             zip(feats.names, ident.basis[r]) if abs(v) > 1e-3}
                                   for r in range(ident.rank)},
            "basis_times_learned": (ident.basis @ (pi_m + theta_m)).tolist(),
            "basis_times_plant": (ident.basis @ pi_p).tolist(),
            "torque_rms_rel": (np.sqrt(np.mean((u_l - u_p) ** 2, 0) / np.mean(u_p ** 2, 0))).tolist(),
            "parameters": rows}


def plot(curves: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11.0, 4.2), sharex=True)
    for ax, key, title in zip(axes, ("total", "stabilized"),
                              ("total mean |feedback| (both joints)", "stabilizing feedback (elbow)")):
        for label, c in curves.items():
            y = np.array(c[key])
            x = np.arange(1, y.shape[1] + 1)
            line, = ax.plot(x, y.mean(axis=0), lw=2, label=label)
            ax.fill_between(x, y.min(axis=0), y.max(axis=0), color=line.get_color(), alpha=0.2)
        ax.set_yscale("log")
        ax.set_xlabel("learning cycle")
        ax.set_ylabel("[N m]")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.suptitle("Standard arm, plant link 2 30 % heavier: mean and min-max over "
                 f"{len(next(iter(curves.values()))['total'])} seeds")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main()
