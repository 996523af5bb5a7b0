"""The thesis's figures from a run directory (Figs. 3.3-3.6 for the arms).

* ``feedback_convergence.png``: mean |error feedback| per cycle, mean and spread over seeds
  (Fig. 3.5(a) / 3.6(a)).
* ``weight_convergence.png``: the learned weights (and goal) over cycles for one seed
  (Fig. 3.5(b) / 3.6(b)).
* ``trajectories_first_last.png``: forward (learned RMP) vs system trajectory of every joint at
  the first and the last cycle (Figs. 3.3 and 3.4).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from feltool.files import make_dirs
from feltool.runs.rundir import load_npz, read_metrics, write_by
from feltool.runs.runstate import check_run_dir


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _layout(fig) -> None:
    """Fixed margins in inches (``tight_layout`` measures every label and tick, which took
    about half of a figure's drawing time)."""
    w, h = fig.get_size_inches()
    rows = fig.axes[0].get_gridspec().get_geometry()[0]
    fig.subplots_adjust(left=0.8 / w, right=1 - 0.2 / w, bottom=0.55 / h, top=1 - 0.4 / h,
                        wspace=0.9 / (w / 2), hspace=0.75 * rows / h if rows > 1 else 0.2)


def draw_figures(run_dir: Path, seed: int | None = None) -> list[Path]:
    """(Re)draw every figure of a run directory; returns the files written."""
    run_dir = check_run_dir(Path(run_dir))
    rows = read_metrics(run_dir / "metrics.csv")
    out = run_dir / "figures"
    make_dirs(out)
    if not rows:
        return []
    seeds = sorted({r["seed"] for r in rows})
    seed = seeds[0] if seed is None else seed
    written = [_feedback_convergence(rows, seeds, out)]
    params = run_dir / "params" / f"seed-{seed}.npz"
    if params.is_file():
        written.append(_weight_convergence(load_npz(params), seed, out))
    traces = run_dir / "traces" / f"seed-{seed}.npz"
    if traces.is_file():
        tr = load_npz(traces)
        written.append(_trajectories(tr, seed, out))
        written.append(_switches(tr, seed, out))
    return [w for w in written if w is not None]


def _feedback_convergence(rows, seeds, out: Path) -> Path:
    plt = _pyplot()
    n = max(r["cycle"] for r in rows)
    fb = np.full((len(seeds), n), np.nan)
    for r in rows:
        fb[seeds.index(r["seed"]), r["cycle"] - 1] = r["fb_abs_mean_error"]
    cycles = np.arange(1, n + 1)
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    with np.errstate(all="ignore"):
        mean = np.nanmean(fb, axis=0)
        ax.fill_between(cycles, np.nanmin(fb, axis=0), np.nanmax(fb, axis=0), alpha=0.25,
                        label=f"min-max over {len(seeds)} seeds")
    ax.plot(cycles, mean, lw=2, label="mean over seeds")
    ax.axhline(0.05 * np.nanmean(fb[:, 0]), color="k", ls=":", lw=1, label="5 % of initial")
    ax.set_yscale("log")
    ax.set_xlabel("learning cycle")
    ax.set_ylabel("mean |error feedback| per cycle [N m]")
    ax.set_title("Feedback convergence")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    _layout(fig)
    path = out / "feedback_convergence.png"
    write_by(path, lambda fh: fig.savefig(fh, format="png", dpi=120))
    plt.close(fig)
    return path


def _weight_convergence(params: dict[str, np.ndarray], seed: int, out: Path) -> Path | None:
    plt = _pyplot()
    joints = [k[: -len(".weights_history")] for k in params if k.endswith(".weights_history")]
    if not joints:
        return None
    fig, axes = plt.subplots(len(joints), 2, figsize=(9.0, 3.2 * len(joints)), squeeze=False)
    for row, name in zip(axes, joints):
        w = params[f"{name}.weights_history"]
        g = params[f"{name}.goal_history"]
        row[0].plot(np.arange(len(w)), w)
        row[0].set_title(f"{name}: {w.shape[1]} weights (seed {seed})")
        row[0].set_xlabel("learning cycle")
        row[0].set_ylabel("weight")
        row[1].plot(np.arange(len(g)), g, color="k")
        row[1].set_title(f"{name}: goal g")
        row[1].set_xlabel("learning cycle")
        row[1].set_ylabel("goal [rad]")
        for ax in row:
            ax.grid(True, alpha=0.3)
    _layout(fig)
    path = out / "weight_convergence.png"
    write_by(path, lambda fh: fig.savefig(fh, format="png", dpi=120))
    plt.close(fig)
    return path


def _trajectories(tr: dict[str, np.ndarray], seed: int, out: Path) -> Path:
    plt = _pyplot()
    names = [str(n) for n in tr["joint_names"]]
    dt = float(tr["dt"])
    fig, axes = plt.subplots(len(names), 2, figsize=(9.0, 2.8 * len(names)), squeeze=False,
                             sharex=True)
    for j, name in enumerate(names):
        for c, which in enumerate(("first", "last")):
            ax = axes[j][c]
            t = np.arange(len(tr[f"{which}_q_system"])) * dt
            ax.plot(t, tr[f"{which}_q_forward"][:, j], lw=2, label="forward (RMP)")
            ax.plot(t, tr[f"{which}_q_system"][:, j], "--", lw=2, label="system")
            ax.set_title(f"{name}, {which} cycle (seed {seed})")
            ax.set_ylabel("angle [rad]")
            ax.grid(True, alpha=0.3)
        axes[j][0].legend(loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("time in cycle [s]")
    _layout(fig)
    path = out / "trajectories_first_last.png"
    write_by(path, lambda fh: fig.savefig(fh, format="png", dpi=120))
    plt.close(fig)
    return path


def _switches(tr: dict[str, np.ndarray], seed: int, out: Path) -> Path | None:
    """The desired positions and velocities across each motion event (traces switch<c>_*)."""
    cycles = sorted(int(k[len("switch"):-len("_t")]) for k in tr
                    if k.startswith("switch") and k.endswith("_t"))
    if not cycles:
        return None
    plt = _pyplot()
    names = [str(n) for n in tr["joint_names"]]
    fig, axes = plt.subplots(2, len(cycles), figsize=(4.8 * len(cycles), 5.6), squeeze=False,
                             sharex="col")
    for c, cycle in enumerate(cycles):
        t = tr[f"switch{cycle}_t"]
        for r, (key, label) in enumerate((("q", "q_d [rad]"), ("v", "qdot_d [rad/s]"))):
            ax = axes[r][c]
            for j, name in enumerate(names):
                ax.plot(t, tr[f"switch{cycle}_{key}_forward"][:, j], lw=1.5, label=name)
            ax.axvline(0.0, color="k", ls=":", lw=1)
            ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
        axes[0][c].set_title(f"motion event at cycle {cycle} (seed {seed})")
        axes[1][c].set_xlabel("time from the event [s]")
    axes[0][0].legend(loc="best")
    _layout(fig)
    path = out / "motion_events.png"
    write_by(path, lambda fh: fig.savefig(fh, format="png", dpi=120))
    plt.close(fig)
    return path
