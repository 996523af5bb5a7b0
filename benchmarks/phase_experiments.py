"""The shared phase's experiments of docs/results.md on the standard arm, over seeds 0-19:

    python benchmarks/phase_experiments.py [--seeds 20]

1. speed change: period 1.0 s -> 0.8 s at cycle 60 (``events: [{cycle: 60, period_s: 0.8}]``),
   FEL on throughout: Levenberg-Marquardt steps, and the gradient rule at the config's rate 0.2
   and at 0.1;
2. any period: T = 1.2345 s at 1 kHz (1234.5 steps per cycle), rates per sample scaled by
   100 / 1234.5 from the 100 Hz config, beside the config's 1 s at 100 Hz;
3. an unknown rhythm: ``phase: adaptive`` entrained by an external 1.3 Hz signal from 1.0 Hz.

Prints the per-seed numbers as Markdown tables, writes them to
benchmarks/results/phase.json and draws docs/figures/phase_*.png.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from feltool.runs.experiments import load_experiment
from feltool.runs.plots import _pyplot
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parent.parent
STANDARD = ROOT / "configs" / "two_link_standard.yaml"
FIGURES = ROOT / "docs" / "figures"


def fb_of(res) -> np.ndarray:
    return np.array([r["fb_abs_mean_error"] for r in res.rows])


def speed_change(seeds: list[int]) -> dict:
    out = {}
    for label, extra in (("levenberg_marquardt", ["learning.update=gauss_newton",
                                                  "learning.rates.gauss_newton=0.2"]),
                         ("gradient_0.2", ["learning.update=gradient"]),
                         ("gradient_0.1", ["learning.update=gradient",
                                           "learning.rates.weights=33.687"])):  # per sample
        exp = load_experiment(STANDARD, ["events=[{cycle: 60, period_s: 0.8}]", *extra])
        rows, curves, traces = [], [], None
        for seed in seeds:
            res = run_seed(exp, seed, 150)
            fb = fb_of(res)
            curves.append(np.pad(fb, (0, 150 - len(fb)), constant_values=np.nan))
            above = [c + 1 for c in range(59, len(fb)) if fb[c] >= 0.05 * fb[0]]
            rows.append({"seed": seed, "diverged": res.summary["diverged"],
                         "converged_cycle_before": _converged(fb[:59]),
                         "fb59_over_fb1": fb[58] / fb[0] if len(fb) > 58 else None,
                         "peak_after_over_fb1": float(np.nanmax(fb[59:]) / fb[0])
                         if len(fb) > 59 else None,
                         "cycles_above_5pct_after": len(above),
                         "back_below_pre_change_cycle": next(
                             (c + 1 for c in range(60, len(fb)) if fb[c] < fb[58]), None),
                         "fb_final_over_fb1": fb[-1] / fb[0]})
            if seed == seeds[0]:
                traces = res.traces
        out[label] = {"rows": rows, "curves": np.array(curves), "traces": traces,
                      "joints": exp.joints}
    return out


def _converged(fb: np.ndarray) -> int | None:
    above = np.flatnonzero(fb >= 0.05 * fb[0])
    return int(above[-1] + 2) if len(above) and above[-1] + 1 < len(fb) else None


def any_period(seeds: list[int]) -> list[dict]:
    """T = 1.2345 s at 1 kHz beside the config's 1 s at 100 Hz, 150 cycles each."""
    slow = load_experiment(STANDARD, ["period_s=1.2345", "sim.rate_hz=1000",
                                      "learning.update=gradient"])  # the same rates (issue 29)
    base = load_experiment(STANDARD, ["learning.update=gradient"])
    rows = []
    for seed in seeds:
        row = {"seed": seed}
        for label, exp in (("1.2345s_1kHz", slow), ("1s_100Hz", base)):
            res = run_seed(exp, seed, 150)
            fb = fb_of(res)
            row[f"{label}_diverged"] = res.summary["diverged"]
            row[f"{label}_fb40_over_fb1"] = fb[39] / fb[0]
            row[f"{label}_converged_cycle"] = res.summary["converged_cycle"]
            row[f"{label}_fb150_over_fb1"] = fb[-1] / fb[0]
        rows.append(row)
    return rows


def adaptive(seeds: list[int]) -> dict:
    exp = load_experiment(STANDARD, ["primitives.phase=adaptive", "learning.update=gauss_newton",
                                     "primitives.oscillator={input: {external: "
                                     "{frequency_hz: 1.3}}}"])
    rows, freqs, curves = [], [], []
    for seed in seeds:
        res = run_seed(exp, seed, 80)
        fb = fb_of(res)
        f = np.array([r["frequency_hz"] for r in res.rows])
        off = np.flatnonzero(np.abs(f / 1.3 - 1) >= 1e-3)
        rows.append({"seed": seed, "diverged": res.summary["diverged"],
                     "locked_from_cycle": int(off[-1] + 2) if len(off) else 1,
                     "frequency_error_last": float(abs(f[-1] / 1.3 - 1)),
                     "fb80_over_fb2": fb[-1] / fb[1]})
        freqs.append(f)
        curves.append(fb)
    return {"rows": rows, "freqs": np.array(freqs), "curves": np.array(curves)}


def draw(sc: dict, ad: dict) -> None:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    cycles = np.arange(1, 151)
    for label, color in (("levenberg_marquardt", "C0"), ("gradient_0.1", "C1")):
        c = sc[label]["curves"]
        ax.fill_between(cycles, np.nanmin(c, 0), np.nanmax(c, 0), color=color, alpha=0.2)
        ax.plot(cycles, np.nanmean(c, 0), color=color, lw=2,
                label=label.replace("_", " ").replace("levenberg marquardt",
                                                      "Levenberg-Marquardt"))
    ax.axvline(60, color="k", ls=":", lw=1, label="period 1.0 s -> 0.8 s")
    ax.axhline(0.05 * np.nanmean(sc["levenberg_marquardt"]["curves"][:, 0]), color="k",
               ls="--", lw=1, label="5 % of initial")
    ax.set_yscale("log")
    ax.set_xlabel("learning cycle")
    ax.set_ylabel("mean |error feedback| per cycle [N m]")
    ax.set_title(f"Speed change, {len(c)} seeds (mean, min-max)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(FIGURES / "phase_speed_change_feedback.png", dpi=120)
    plt.close(fig)

    tr = sc["levenberg_marquardt"]["traces"]
    t = tr["switch60_t"]
    fig, axes = plt.subplots(2, 1, figsize=(6.4, 5.2), sharex=True)
    for j, name in enumerate(sc["levenberg_marquardt"]["joints"]):
        axes[0].plot(t, tr["switch60_q_forward"][:, j], ".-", ms=2, label=name)
        axes[1].plot(t, tr["switch60_v_forward"][:, j], ".-", ms=2, label=name)
    for ax, label in zip(axes, ("q_d [rad]", "qdot_d [rad/s]")):
        ax.axvline(0.0, color="k", ls=":", lw=1)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[0].set_title("desired trajectory across the change (cycles 59 and 60, seed 0)")
    axes[0].legend()
    axes[1].set_xlabel("time from the change [s]")
    fig.tight_layout()
    fig.savefig(FIGURES / "phase_speed_change_qd.png", dpi=120)
    plt.close(fig)

    fig, axes = plt.subplots(2, 1, figsize=(6.4, 5.2), sharex=True)
    cyc = np.arange(1, ad["freqs"].shape[1] + 1)
    axes[0].plot(cyc, ad["freqs"].T, color="C0", alpha=0.5)
    axes[0].axhline(1.3, color="k", ls=":", lw=1)
    axes[0].set_ylabel("frequency of the cycle [Hz]")
    axes[1].plot(cyc, ad["curves"].T, color="C1", alpha=0.5)
    axes[1].set_yscale("log")
    axes[1].set_ylabel("mean |error feedback| [N m]")
    axes[1].set_xlabel("learning cycle")
    axes[0].set_title(f"Adaptive phase entrained by 1.3 Hz, {len(ad['freqs'])} seeds")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(FIGURES / "phase_adaptive.png", dpi=120)
    plt.close(fig)


def table(rows: list[dict]) -> str:
    keys = list(rows[0])
    fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(fmt(r[k]) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    seeds = list(range(args.seeds))
    sc, ap, ad = speed_change(seeds), any_period(seeds), adaptive(seeds)
    draw(sc, ad)
    result = {"speed_change": {k: v["rows"] for k, v in sc.items()}, "any_period": ap,
              "adaptive": ad["rows"]}
    (ROOT / "benchmarks" / "results" / "phase.json").write_text(json.dumps(result, indent=1))
    for name, rows in (("speed change, Levenberg-Marquardt", sc["levenberg_marquardt"]["rows"]),
                       ("speed change, gradient 0.2", sc["gradient_0.2"]["rows"]),
                       ("speed change, gradient 0.1", sc["gradient_0.1"]["rows"]),
                       ("T = 1.2345 s at 1 kHz", ap), ("adaptive, 1.3 Hz", ad["rows"])):
        print(f"\n### {name}\n\n{table(rows)}")


if __name__ == "__main__":
    main()
