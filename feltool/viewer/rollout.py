"""A run's rollouts in the browser: streamed live while learning runs, saved, and replayed.

Three uses of :mod:`feltool.viewer.scene`, each showing the *system* robot (as simulated, solid) and a
translucent ghost at the *forward* configuration (what the RMPs alone command), as the thesis's
Figs. A.2, A.3 and B.2 do:

* :class:`LiveStream` is the ``on_cycle`` hook of :func:`feltool.runs.seed.run_seed`. Without
  ``realtime`` it hands the newest cycle to a drawing *process* (forked, with its own connection
  to the same meshcat server) whenever that process has taken the previous one, and the process
  draws at most ``max_fps`` frames per second, the frame chosen by the wall clock, so the motion
  plays at its true speed while learning runs at full speed. A process, not a thread: a second
  Python thread waking 30 times per second costs the learning loop ~9 % through the GIL alone;
  the pipe costs a few microseconds per cycle. With ``realtime`` every cycle is played in full,
  paced to wall time, so learning runs at the robot's own pace.
* :func:`write_rollout_html` writes ``rollout.html`` into a run directory: the first and the last
  learning cycle of one seed, from ``traces/seed-N.npz``, as one self-contained page.
* :func:`replay` plays recorded cycles of a run directory in the live viewer.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from feltool.errors import InputError
from feltool.runs.rundir import damaged, load_npz, read_json
from feltool.runs.runstate import check_run_dir

__all__ = ["CYCLES", "LiveStream", "load_rollouts", "parse_cycles", "play_clips", "replay",
           "run_robot", "write_rollout_html"]

CYCLES = ("first", "last")  # the cycles a run directory keeps traces of
STATUS_EVERY_S = 1.0  # the terminal status line is printed at most this often [s]
#: ``out=STDOUT``: the standard output at the call (``sys.stdout`` as a default would be the
#: stream of the moment this module was imported, which a test's capture may have closed since)
STDOUT = object()
DRAW_BUDGET = 0.08  # at full speed, drawing (mostly waiting on the server) takes at most this
# share of wall time: ~30 frames/s on an idle machine, fewer on a loaded one


def _draw_process(viewer, conn, dt: float) -> None:
    """Body of the drawing process: take the newest cycle when one arrives (and say so, which
    lets the learner send the next), draw at most ``viewer.max_fps`` frames per second, the
    frame chosen by the wall clock; stop at an empty message or when the learner is gone."""
    frames, cpu0 = 0, time.process_time()
    try:
        viewer.detach_for_child()
        period = 1.0 / viewer.max_fps if viewer.max_fps > 0 else 1.0 / 30.0
        latest, start, next_frame = None, time.monotonic(), time.monotonic()
        while True:
            if conn.poll(max(0.0, next_frame - time.monotonic())):
                data = conn.recv_bytes()
                if not data:
                    break
                arr = np.frombuffer(data)
                n, nq, nv = (int(x) for x in arr[:3])
                latest = (arr[3:3 + n * nq].reshape(n, nq), arr[3 + n * nq:].reshape(n, nv))
                conn.send_bytes(b"1")
                continue
            if latest is not None:
                q, qf = latest
                k = int((time.monotonic() - start) / dt) % len(q)
                viewer.show(q[k], qf[k], force=True)
                frames += 1
            next_frame = time.monotonic() + period
        conn.send_bytes(f"stats {frames} {time.process_time() - cpu0}".encode())
    except (EOFError, BrokenPipeError, OSError, KeyboardInterrupt):
        pass
    except Exception as exc:  # pragma: no cover - shown, never fatal to learning
        print(f"feltool viewer: drawing stopped: {exc}", file=sys.stderr, flush=True)
    finally:
        os._exit(0)  # skip the parent's atexit handlers: the parent owns the server


class LiveStream:
    """Streams one seed's learning to a :class:`feltool.viewer.live.LiveViewer`.

    Call it as ``on_cycle(cycle, log, Qd, fb)`` after every learning cycle (see
    :func:`feltool.runs.seed.run_seed`); call :meth:`close` at the end (or use ``with``).

    Args:
        viewer: The live viewer (its ``max_fps`` bounds the frames drawn per second).
        dt: Control step [s] between two rows of ``log.q``.
        cycles: Cycles the seed will run (for the status line).
        realtime: Play every cycle in full at wall-clock speed (slows learning to real time).
        label: Prefix of the status line, e.g. ``"seed 0"``.
        out: Where the status line goes (default stdout); None for no status line.
    """

    def __init__(self, viewer, dt: float, cycles: int | None = None, *, realtime: bool = False,
                 label: str = "", out=STDOUT):
        self.viewer = viewer
        self.dt = float(dt)
        self.cycles = cycles
        self.realtime = bool(realtime)
        self.label = label
        self.out = sys.stdout if out is STDOUT else out
        self.frames_drawn = 0
        self.draw_cpu_s = 0.0  # CPU time the drawing process has used [s] (known after close)
        self._last_status = -np.inf
        self._conn = None
        self._proc = None
        self._credit = True  # the drawing process has taken the last cycle sent
        self._inline = not self.realtime and "fork" not in mp.get_all_start_methods()
        self._start = time.monotonic()
        if not self.realtime and not self._inline:
            ctx = mp.get_context("fork")
            self._conn, child = ctx.Pipe(duplex=True)
            self._proc = ctx.Process(target=_draw_process, args=(viewer, child, self.dt),
                                     name="feltool-viewer", daemon=True)
            self._proc.start()
            child.close()

    # -- the on_cycle hook ---------------------------------------------------------------------

    def __call__(self, cycle: int, log, Qd: np.ndarray, fb: float) -> None:
        self._status(cycle, fb)
        if self.realtime:
            self.play(log.q, Qd)
            return
        if self._inline:  # no fork on this platform: draw here, throttled by the viewer
            k = int((time.monotonic() - self._start) / self.dt) % len(log.q)
            self.frames_drawn += bool(self.viewer.show(log.q[k], Qd[k]))
            return
        try:
            while not self._credit and self._conn.poll():
                self._conn.recv_bytes()
                self._credit = True
            if self._credit:
                q = np.ascontiguousarray(log.q, dtype=float)
                qf = np.ascontiguousarray(Qd, dtype=float)
                header = np.array([q.shape[0], q.shape[1], qf.shape[1]], dtype=float)
                self._conn.send_bytes(np.concatenate([header, q.ravel(), qf.ravel()]).tobytes())
                self._credit = False
        except (BrokenPipeError, EOFError, OSError):
            pass  # the drawing process is gone (its server stopped): learning goes on

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
        """Stop the drawing process (the viewer itself is closed by its owner)."""
        if self._proc is None:
            return
        try:
            self._conn.send_bytes(b"")
            if self._conn.poll(5):
                while True:  # the last message is the process's statistics
                    data = self._conn.recv_bytes()
                    if data.startswith(b"stats "):
                        frames, cpu = data[6:].split()
                        self.frames_drawn, self.draw_cpu_s = int(frames), float(cpu)
                        break
        except (BrokenPipeError, EOFError, OSError):
            pass
        self._proc.join(timeout=5)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=5)
        self._conn.close()
        self._proc = None

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
    summary = read_json(run_dir / "summary.json")
    entries = {s["seed"]: s for s in summary.get("seeds", []) if isinstance(s, dict)}
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
    path = run_dir / "traces" / f"seed-{seed}.npz"
    traces = load_npz(path)
    try:
        dt = float(traces["dt"]) if "dt" in traces else 0.01
    except (TypeError, ValueError):
        raise damaged(path, "its 'dt' is not a number") from None
    entry = entries.get(seed, {})
    clips = {}
    for which in cycles:
        if f"{which}_q_system" not in traces:
            raise InputError(f"{run_dir}: traces/seed-{seed}.npz has no '{which}' cycle")
        number = 1 if which == "first" else entry.get("cycles", "?")
        fb = entry.get("fb_initial" if which == "first" else "fb_final")
        name = f"{which} cycle ({number})" + (f", feedback {fb:.3g} N m" if fb is not None else "")
        q, qf = traces[f"{which}_q_system"], traces.get(f"{which}_q_forward")
        if q.ndim != 2 or q.dtype.kind != "f" or qf is None or qf.shape != q.shape:
            raise damaged(path, f"its '{which}' cycle is not two n x nv arrays of angles")
        clips[name] = (q, qf)
    return seed, dt, clips


def write_rollout_html(robot, run_dir: Path, seed: int | None = None,
                       cycles: Sequence[str] = CYCLES, path: Path | None = None) -> Path:
    """Write ``rollout.html`` (default ``run_dir/rollout.html``): recorded cycles of one seed,
    system robot and forward ghost, playable from ``file://`` with no server."""
    from feltool.viewer.html import record_html

    run_dir = Path(run_dir)
    seed, dt, clips = load_rollouts(run_dir, seed, cycles)
    summary = read_json(run_dir / "summary.json")
    title = f"{summary.get('config', run_dir.name)}, seed {seed}"
    return record_html(robot, {k: v[0] for k, v in clips.items()}, dt,
                       path or run_dir / "rollout.html", title=title,
                       ghost_frames={k: v[1] for k, v in clips.items()})


def replay(viewer, run_dir: Path, seed: int | None = None, cycles: Sequence[str] = CYCLES,
           loops: int = 0, out=STDOUT, timeout_s: float | None = None) -> int:
    """Play recorded cycles in the live viewer at wall-clock speed, ``loops`` times (0: until
    interrupted, or until ``timeout_s`` in [s] has passed). Returns the seed played."""
    seed, dt, clips = load_rollouts(run_dir, seed, cycles)
    play_clips(viewer, clips, dt, f"seed {seed}", loops, out, timeout_s)
    return seed


def play_clips(viewer, clips: dict[str, tuple[np.ndarray, np.ndarray | None]], dt: float,
               label: str, loops: int = 0, out=STDOUT,
               timeout_s: float | None = None) -> None:
    """Play ``clips`` (name -> system and ghost configurations, the ghost None for none) one
    after the other at wall-clock speed, ``dt`` [s] a frame, ``loops`` times (0: until
    interrupted, or until ``timeout_s`` [s] has passed), each announced with ``label``."""
    out = sys.stdout if out is STDOUT else out
    stream = LiveStream(viewer, dt, realtime=True, out=None)
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    done = 0
    while loops <= 0 or done < loops:
        for name, (q, qf) in clips.items():
            if deadline is not None and time.monotonic() >= deadline:
                return
            if out is not None:
                print(f"view: {label}, {name}", file=out, flush=True)
            stream.play(q, qf)
            time.sleep(0.5)
        done += 1


def run_robot(run_dir: Path):
    """The (reduced) robot of a run directory, rebuilt from its resolved ``config.yaml``."""
    from feltool.config.files import read_yaml
    from feltool.runs.experiments import build_experiment
    from feltool.runs.inputs import check_inputs

    run_dir = check_run_dir(run_dir)
    if (run_dir / "run.json").is_file():  # the robot it ran, not one edited since
        check_inputs(read_json(run_dir / "run.json").get("inputs"), run_dir, str(run_dir))
    path = run_dir / "config.yaml"
    return build_experiment(read_yaml(path), source=path).robot
