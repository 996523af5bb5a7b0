"""A legged run in the browser: streamed live while it learns, saved as one HTML file, and
replayed.

* :func:`write_legged_html`: the robot's meshes (Pinocchio's MeshcatVisualizer, as
  :func:`feltool.viewer.html.record_html` draws them) moving along a seed's recorded
  configurations (``traces/seed-N.npz`` of :mod:`feltool.runs.legged`): the cycles around the
  world's change (payload, slope, masses) and the last cycles.
* :class:`LeggedStream`: the learning trot's ``on_cycle`` hook
  (:class:`~feltool.walking.legged.learn.CycleFrames`) feeding a
  :class:`~feltool.viewer.rollout.LiveStream`: the newest cycle, the robot as simulated and a
  ghost at its desired configuration.
* :func:`replay_legged`: the HTML file's clips in the live viewer.

The live viewer's camera is aimed once, at the robot's base at the origin, so whatever it shows
is shown *in place*: each clip (a cycle streamed live, or a few recorded cycles) shifted
horizontally so that its base starts at the origin, as on a treadmill (the HTML page's camera
takes in the whole clip instead).
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from feltool.errors import ConfigError, InputError
from feltool.runs.legged import trace
from feltool.runs.rundir import load_npz, read_json
from feltool.runs.runstate import check_run_dir
from feltool.viewer.rollout import LiveStream, play_clips

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


class NoFrames(InputError):
    """A seed's rollout has no recorded configuration to show."""


def _reason(summary: dict, seed: int) -> str:
    entry = next(s for s in summary["seeds"] if s["seed"] == seed)
    return entry.get("not_walking") or "no reason recorded"


def legged_clips(run_dir: Path, seed: int | None = None
                 ) -> tuple[int, float, dict[str, np.ndarray], str]:
    """``(seed, dt [s], {clip name: q (n, nq)}, title)`` of a legged run directory's ``seed``
    (default the run's first): the cycles from one before the world's change (payload, slope,
    masses), and the last cycles; the whole rollout when the seed stopped before its first
    cycle."""
    run_dir = check_run_dir(run_dir)  # a running, interrupted or failed run is not shown
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
        if not len(q):
            raise NoFrames(f"{run_dir}: seed {seed} stopped in its first control step "
                           f"({_reason(summary, seed)}): no motion to show")
        clips["rollout"] = q
    return seed, dt, clips, f"{summary.get('config', run_dir.name)}, seed {seed}"


def write_legged_html(run_dir: Path, robot, seed: int | None = None,
                      path: Path | None = None) -> Path:
    """Write ``rollout.html`` (default ``run_dir/rollout.html``) for ``seed`` (default the
    run's first): the clips of :func:`legged_clips`."""
    from feltool.viewer.html import record_html

    run_dir = Path(run_dir)
    _, dt, clips, title = legged_clips(run_dir, seed)
    return record_html(robot, clips, dt, path or run_dir / "rollout.html", title=title)


def in_place(q: np.ndarray, *more: np.ndarray) -> list[np.ndarray]:
    """``q`` ``(n, nq)`` (and ``more`` arrays of the same shape) shifted horizontally by one
    offset [m], so that ``q``'s first base position is above the origin (module docstring)."""
    shift = -q[0, :2]
    out = []
    for x in (q, *more):
        x = np.array(x, float)
        x[:, :2] += shift
        out.append(x)
    return out


class LeggedStream:
    """The learning trot's ``on_cycle`` hook (:func:`~feltool.walking.legged.learn.learn_trot`)
    that streams each cycle, resampled to uniform steps of ``dt`` [s] (the control updates
    are uneven at events) and played in place, to a :class:`LiveStream` on ``viewer``, the
    ghost at the desired configuration; the status line counts cycles from 1.

    Args:
        viewer: The live viewer (with a ghost).
        dt: The control step [s].
        cycles: The cycles the seed runs (for the status line).
        realtime: Play every cycle in full at wall-clock speed.
        label: The status line's prefix, e.g. ``"seed 0"``.
    """

    def __init__(self, viewer, dt: float, cycles: int | None = None, *,
                 realtime: bool = False, label: str = ""):
        self.dt = float(dt)
        self.stream = LiveStream(viewer, dt, cycles, realtime=realtime, label=label)

    def __call__(self, cycle: int, t: np.ndarray, q: np.ndarray, q_d: np.ndarray,
                 fb: float) -> None:
        nq = q.shape[1]
        order = np.argsort(t, kind="stable")  # an impact's window can put an update late
        both = trace(t[order], np.hstack([q, q_d])[order], 1.0 / self.dt)["q"]
        q, q_d = in_place(both[:, :nq], both[:, nq:])
        self.stream(cycle + 1, SimpleNamespace(q=q), q_d, fb)

    @property
    def frames_drawn(self) -> int:
        """Frames drawn so far (the drawing process's count is known after :meth:`close`)."""
        return self.stream.frames_drawn

    def close(self) -> None:
        self.stream.close()


def replay_legged(viewer, run_dir: Path, seed: int | None = None, loops: int = 0,
                  timeout_s: float | None = None) -> int:
    """Play :func:`legged_clips` in the live viewer at wall-clock speed, each in place,
    ``loops`` times (0: until interrupted, or until ``timeout_s`` [s] has passed), each clip
    announced on stdout. Returns the seed played."""
    seed, dt, clips, _ = legged_clips(run_dir, seed)
    play_clips(viewer, {name: (in_place(q)[0], None) for name, q in clips.items()}, dt,
               f"seed {seed}", loops, timeout_s=timeout_s)
    return seed
