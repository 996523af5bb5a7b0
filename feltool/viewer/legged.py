"""A legged run's rollout as one HTML file: the robot's meshes (Pinocchio's MeshcatVisualizer,
as :func:`feltool.viewer.html.record_html` draws them) moving along a seed's recorded
configurations (``traces/seed-N.npz`` of :mod:`feltool.runs.legged`): the cycles around the
world's change (payload, slope, masses) and the last cycles."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from feltool.errors import ConfigError, InputError
from feltool.runs.rundir import load_npz, read_json

#: Cycles shown in each clip
CLIP_CYCLES = 3


def visual_robot(robot: str, urdf: Path | None):
    """``model``, ``visual_model`` and ``name`` of a legged robot on a free flyer (the same
    joints as :func:`feltool.runs.legged.load_legged_robot`'s model, so its ``q`` fits)."""
    import pinocchio as pin

    if urdf is None:
        import example_robot_data as erd

        name = robot.split(":")[-1]
        r = erd.load(name)
        return SimpleNamespace(model=r.model, visual_model=r.visual_model, name=name)
    try:
        model, _, visual = pin.buildModelsFromUrdf(str(urdf), str(Path(urdf).parent),
                                                   pin.JointModelFreeFlyer())
    except Exception as exc:  # urdfdom's and the mesh loader's messages
        raise ConfigError([("robot", f"{urdf}: its visual model cannot be read ({exc})")]) \
            from None
    return SimpleNamespace(model=model, visual_model=visual, name=Path(urdf).stem)


def write_legged_html(run_dir: Path, robot, seed: int | None = None,
                      path: Path | None = None) -> Path:
    """Write ``rollout.html`` (default ``run_dir/rollout.html``) for ``seed`` (default the
    run's first): the cycles from one before the world's change (payload, slope, masses), and the last
    cycles."""
    from feltool.viewer.html import record_html

    run_dir = Path(run_dir)
    summary = read_json(run_dir / "summary.json")
    seeds = [s["seed"] for s in summary.get("seeds", [])]
    seed = seeds[0] if seed is None and seeds else seed
    if seed not in seeds:
        raise InputError(f"{run_dir}: no seed {seed} (seeds {seeds})")
    tr = load_npz(run_dir / "traces" / f"seed-{seed}.npz")
    t, q, times = tr["t"], tr["q"], tr["cycle_times"]
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.02
    clips = {}
    n = len(times)
    change = summary.get("change_cycle")
    if n:
        windows = {"last cycles": (max(0, n - CLIP_CYCLES), n - 1)}
        if change is not None and change < n:
            windows = {f"world changes (cycle {change})": (max(0, change - 1),
                                                         min(n - 1, change + CLIP_CYCLES - 2)),
                       **windows}
        for name, (a, b) in windows.items():
            keep = (t >= times[a, 0]) & (t <= times[b, 1])
            if np.any(keep):
                clips[name] = q[keep]
    if not clips:  # a seed that stopped before its first cycle: the whole rollout
        clips["rollout"] = q
    title = f"{summary.get('config', run_dir.name)}, seed {seed}"
    return record_html(robot, clips, dt, path or run_dir / "rollout.html", title=title)
