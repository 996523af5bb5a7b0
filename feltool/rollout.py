"""A run's rollouts in the browser: streamed live while learning runs, saved, and replayed.

Three uses of :mod:`feltool.viewer`, each showing the *system* robot (as simulated, solid) and a
translucent ghost at the *forward* configuration (what the RMPs alone command), as the thesis's
Figs. A.2, A.3 and B.2 do:

* :class:`LiveStream` is the ``on_cycle`` hook of :func:`feltool.experiment.run_seed`. Without
  ``realtime`` it only keeps a reference to the newest cycle, and a background thread draws from
  it at most ``max_fps`` times per second, the frame chosen by the wall clock, so the motion
  plays at its true speed while learning runs at full speed (cost: one reference per cycle in the
  learning loop; the drawing, in the other thread, takes at most ``DRAW_BUDGET`` of wall time,
  fewer frames when the machine is loaded). With ``realtime`` every cycle is played in
  full, paced to wall time, so learning runs at the robot's own pace.
* :func:`write_rollout_html` writes ``rollout.html`` into a run directory: the first and the last
  learning cycle of one seed, from ``traces/seed-N.npz``, as one self-contained page.
* :func:`replay` plays recorded cycles of a run directory in the live viewer.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from feltool.errors import InputError
from feltool.rundir import check_run_dir, load_npz

__all__ = ["CYCLES", "LiveStream", "load_rollouts", "parse_cycles", "replay", "run_robot",
           "write_rollout_html"]

CYCLES = ("first", "last")  # the cycles a run directory keeps traces of
STATUS_EVERY_S = 1.0  # the terminal status line is printed at most this often [s]
DRAW_BUDGET = 0.08  # at full speed, drawing (mostly waiting on the server) takes at most this
# share of wall time: ~30 frames/s on an idle machine, fewer on a loaded one


class LiveStream:
    """Streams one seed's learning to a :class:`feltool.viewer.LiveViewer`.

    Call it as ``on_cycle(cycle, log, Qd, fb)`` after every learning cycle (see
    :func:`feltool.experiment.run_seed`); call :meth:`close` at the end (or use ``with``).

    Args:
        viewer: The live viewer (its ``max_fps`` bounds the frames drawn per second).
        dt: Control step [s] between two rows of ``log.q``.
        cycles: Cycles the seed will run (for the status line).
        realtime: Play every cycle in full at wall-clock speed (slows learning to real time).
        label: Prefix of the status line, e.g. ``"seed 0"``.
        out: Where the status line goes (default stdout); None for no status line.
    """

    def __init__(self, viewer, dt: float, cycles: int | None = None, *, realtime: bool = False,
                 label: str = "", out=sys.stdout):
        self.viewer = viewer
        self.dt = float(dt)
        self.cycles = cycles
        self.realtime = bool(realtime)
        self.label = label
        self.out = out
        self.frames_drawn = 0
        self.draw_cpu_s = 0.0  # CPU time the drawing thread has used [s]
        self._latest: tuple[int, np.ndarray, np.ndarray, float] | None = None
        self._last_status = -np.inf
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = None
        if not self.realtime:
            self._thread = threading.Thread(target=self._draw_loop, name="feltool-viewer",
                                            daemon=True)
            self._thread.start()

    # -- the on_cycle hook ---------------------------------------------------------------------

    def __call__(self, cycle: int, log, Qd: np.ndarray, fb: float) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        self._latest = (cycle, log.q, Qd, fb)  # one reference: the cost in the learning loop
        self._status(cycle, fb)
        if self.realtime:
            self.play(log.q, Qd)

    def play(self, q: np.ndarray, q_forward: np.ndarray | None = None) -> None:
        """Show one recorded cycle at wall-clock speed (at most ``max_fps`` frames per second)."""
        n = len(q)
        stride = max(1, int(np.ceil(1.0 / (self.viewer.max_fps * self.dt)))) \
            if self.viewer.max_fps > 0 else 1
        start = time.monotonic()
        for k in list(range(0, n, stride)) + [None]:
            due = start + (n if k is None else k) * self.dt
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            if k is not None:
                self.viewer.show(q[k], None if q_forward is None else q_forward[k], force=True)
                self.frames_drawn += 1

    def _draw_loop(self) -> None:
        period = 1.0 / self.viewer.max_fps if self.viewer.max_fps > 0 else 1.0 / 30.0
        start = time.monotonic()
        cpu0 = time.thread_time()
        try:
            while not self._stop.wait(period):
                latest = self._latest
                if latest is None:
                    continue
                _, q, qf, _ = latest
                t = time.monotonic()
                k = int((t - start) / self.dt) % len(q)
                self.viewer.show(q[k], qf[k], force=True)
                self.frames_drawn += 1
                self.draw_cpu_s = time.thread_time() - cpu0
                # fewer frames when drawing is slow (a loaded machine): learning comes first
                took = time.monotonic() - t
                period = max(1.0 / max(self.viewer.max_fps, 1e-9), took / DRAW_BUDGET)
        except BaseException as exc:  # handed to the learning thread at its next cycle
            self._error = exc

    def _status(self, cycle: int, fb: float) -> None:
        now = time.monotonic()
        last = self.cycles is not None and cycle >= self.cycles
        if self.out is None or (now - self._last_status < STATUS_EVERY_S and cycle > 1
                                and not last and not self.realtime):
            return
        self._last_status = now
        of = f"/{self.cycles}" if self.cycles else ""
        prefix = f"{self.label}: " if self.label else ""
        print(f"view: {prefix}cycle {cycle}{of}, error feedback {fb:.4g} N m", file=self.out,
              flush=True)

    # -- lifetime ------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the drawing thread (the viewer itself is closed by its owner)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def __enter__(self) -> LiveStream:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -- recorded rollouts -----------------------------------------------------------------------------

def parse_cycles(spec: str | Sequence[str]) -> list[str]:
    """``"first,last"`` -> ``["first", "last"]``; anything but those names is an InputError."""
    names = [s.strip() for s in (spec.split(",") if isinstance(spec, str) else spec) if s.strip()]
    bad = [n for n in names if n not in CYCLES]
    if bad or not names:
        raise InputError(f"--cycles: '{spec if isinstance(spec, str) else ','.join(spec)}': "
                         f"a run directory keeps the cycles {', '.join(CYCLES)}; "
                         "give one or both, e.g. first,last")
    return list(dict.fromkeys(names))


def load_rollouts(run_dir: Path, seed: int | None = None, cycles: Sequence[str] = CYCLES
                  ) -> tuple[int, float, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """The recorded cycles of one seed of a run directory.

    Args:
        run_dir: The run directory.
        seed: The seed; default the first seed that has traces.
        cycles: Which of ``first`` and ``last``.

    Returns:
        ``(seed, dt, {clip name: (q_system, q_forward)})``; configurations are n x nv in the
        experiment's (reduced) model, in [rad]; clip names say the cycle and its feedback.
    """
    run_dir = check_run_dir(run_dir)
    summary = json.loads((run_dir / "summary.json").read_text())
    entries = {s["seed"]: s for s in summary.get("seeds", [])}
    have = sorted(int(p.stem.removeprefix("seed-"))
                  for p in (run_dir / "traces").glob("seed-*.npz"))
    if seed is None:
        if not have:
            raise InputError(f"{run_dir}: no traces/seed-N.npz (every seed diverged before its "
                             "first cycle ended?)")
        seed = have[0]
    elif seed not in have:
        raise InputError(f"{run_dir}: no traces for seed {seed}; seeds with traces: "
                         + (", ".join(map(str, have)) or "none"))
    traces = load_npz(run_dir / "traces" / f"seed-{seed}.npz")
    dt = float(traces["dt"]) if "dt" in traces else 0.01
    entry = entries.get(seed, {})
    clips = {}
    for which in cycles:
        if f"{which}_q_system" not in traces:
            raise InputError(f"{run_dir}: traces/seed-{seed}.npz has no '{which}' cycle")
        number = 1 if which == "first" else entry.get("cycles", "?")
        fb = entry.get("fb_initial" if which == "first" else "fb_final")
        name = f"{which} cycle ({number})" + (f", feedback {fb:.3g} N m" if fb is not None else "")
        clips[name] = (traces[f"{which}_q_system"], traces[f"{which}_q_forward"])
    return seed, dt, clips


def write_rollout_html(robot, run_dir: Path, seed: int | None = None,
                       cycles: Sequence[str] = CYCLES, path: Path | None = None) -> Path:
    """Write ``rollout.html`` (default ``run_dir/rollout.html``): recorded cycles of one seed,
    system robot and forward ghost, playable from ``file://`` with no server."""
    from feltool.viewer import record_html

    run_dir = Path(run_dir)
    seed, dt, clips = load_rollouts(run_dir, seed, cycles)
    summary = json.loads((run_dir / "summary.json").read_text())
    title = f"{summary.get('config', run_dir.name)}, seed {seed}"
    return record_html(robot, {k: v[0] for k, v in clips.items()}, dt,
                       path or run_dir / "rollout.html", title=title,
                       ghost_frames={k: v[1] for k, v in clips.items()})


def replay(viewer, run_dir: Path, seed: int | None = None, cycles: Sequence[str] = CYCLES,
           loops: int = 0, out=sys.stdout) -> int:
    """Play recorded cycles in the live viewer at wall-clock speed, ``loops`` times (0: until
    interrupted). Returns the seed played."""
    seed, dt, clips = load_rollouts(run_dir, seed, cycles)
    stream = LiveStream(viewer, dt, realtime=True, out=None)
    done = 0
    while loops <= 0 or done < loops:
        for name, (q, qf) in clips.items():
            if out is not None:
                print(f"view: seed {seed}, {name}", file=out, flush=True)
            stream.play(q, qf)
            time.sleep(0.5)
        done += 1
    return seed


def run_robot(run_dir: Path):
    """The (reduced) robot of a run directory, rebuilt from its resolved ``config.yaml``."""
    from feltool.config import read_yaml
    from feltool.experiment import build_experiment

    path = check_run_dir(run_dir) / "config.yaml"
    return build_experiment(read_yaml(path), source=path).robot
