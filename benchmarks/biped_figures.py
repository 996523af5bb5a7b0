"""Figures and numbers of docs/biped.md.

Usage (from the repository root, after ``feltool run configs/biped_torso.yaml --out RUN``)::

    python benchmarks/biped_figures.py RUN docs/figures

Writes ``biped_torso_first_last.png`` (the thesis's Fig. 3.8: the torso's forward trajectory
against the system's absolute torso angle, first and last cycle of seed 0),
``biped_slope_event.png`` (feedback of seed 0 with a 0.05 rad downhill slope from cycle 75,
the event marked) and prints the numbers quoted in docs/biped.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "biped_torso.yaml"


def torso_figure(run: Path, out: Path) -> None:
    tr = np.load(run / "traces" / "seed-0.npz")
    dt = float(tr["dt"])
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for ax, which in zip(axes, ("first", "last")):
        sysq, fwd = tr[f"{which}_q_system"], tr[f"{which}_q_forward"]
        t = np.arange(len(sysq)) * dt
        # Absolute torso angle theta3 = q_stance_ankle + q_torso_hip (kept by the relabelling).
        ax.plot(t, fwd[:, 0] + fwd[:, 2], label="forward (RMP + stance leg)")
        ax.plot(t, sysq[:, 0] + sysq[:, 2], "--", label="system")
        ax.axhline(np.pi / 6, color="k", lw=0.6, ls=":", label="target pi/6")
        ax.set_title(f"torso angle from the vertical, {which} cycle (seed 0)")
        ax.set_xlabel("time in cycle [s]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("angle [rad]")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "biped_torso_first_last.png", dpi=110)
    plt.close(fig)


def slope_figure(out: Path, cycles: int = 150, event: int = 75, angle: float = 0.05) -> None:
    exp = load_experiment(CONFIG, ["walking.poincare=false",
                                   f"events=[{{cycle: {event}, kind: slope, angle: {angle}}}]"])
    result = run_seed(exp, 0, cycles)
    fb = np.array([r["fb_abs_mean_error"] for r in result.rows])
    before, peak = fb[event - 2], fb[event - 1:].max()
    back = next((c for c in range(event + int(np.argmax(fb[event - 1:])), len(fb))
                 if fb[c] <= 2 * before), None)
    print(f"slope {angle} rad at cycle {event}: before {before:.2f} N m, at the event "
          f"{fb[event - 1]:.2f}, peak {peak:.2f} (x{peak / before:.2f}), last {fb[-1]:.2f} "
          f"(x{fb[-1] / before:.2f}); within 2x from cycle {None if back is None else back + 1}")
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.semilogy(np.arange(1, len(fb) + 1), fb)
    ax.axvline(event, color="r", ls="--", lw=1, label=f"slope {angle} rad (downhill)")
    ax.set_xlabel("learning cycle")
    ax.set_ylabel("summed mean |feedback| [N m]")
    ax.set_title("biped, seed 0: a changed world at the event")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "biped_slope_event.png", dpi=110)
    plt.close(fig)


def main(argv: list[str]) -> int:
    run, out = Path(argv[0]), Path(argv[1])
    out.mkdir(parents=True, exist_ok=True)
    torso_figure(run, out)
    slope_figure(out)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
