"""``feltool view``: replay a recorded run in meshcat, or write it as one HTML file."""

from __future__ import annotations

import argparse
import signal
import time
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

from feltool.cli.common import subcommand


def keep_viewing(viewer, play: Callable[[float | None], object],
                 timeout_s: float | None) -> None:
    """Replay a run (``play(timeout_s)``: :func:`~feltool.viewer.rollout.replay` or
    :func:`~feltool.viewer.legged.replay_legged` with their loops), then keep the server up
    showing the last pose; until Ctrl-C or ``timeout_s`` in [s] (0: return at once). An
    interrupt here loses nothing: the run is already written."""
    if timeout_s is not None and timeout_s <= 0:
        return
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    until = "Ctrl-C" if timeout_s is None else f"Ctrl-C or {timeout_s:g} s"
    try:  # announced inside: a Ctrl-C right after the line is the one the line asks for
        print(f"feltool viewer: serving {viewer.url} until {until}", flush=True)
        play(timeout_s)
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2 if deadline is None else min(0.2, deadline - time.monotonic()))
    except KeyboardInterrupt:
        pass
    print("feltool viewer: stopped", flush=True)


@contextmanager
def watching(args: argparse.Namespace, robot: Callable[[], object]):
    """``feltool run``'s live viewer: with ``--view`` (``--zmq-url``, ``--realtime``) a
    :class:`~feltool.viewer.live.LiveViewer` of ``robot()`` (SIGTERM then ends the command as
    Ctrl-C does, so its server is stopped), closed when the block ends; else None."""
    if not (args.view or args.zmq_url or args.realtime):
        yield None
        return
    from feltool.viewer.live import LiveViewer

    exit_on_sigterm()
    viewer = LiveViewer(robot(), zmq_url=args.zmq_url)
    try:
        yield viewer
    finally:
        viewer.close()


def exit_on_sigterm() -> None:
    """Turn SIGTERM into SystemExit(143), so that ``finally`` blocks (the viewer's server
    shutdown) run as they do on Ctrl-C."""
    def handler(signum, frame):
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)


def cmd_view(args: argparse.Namespace) -> int:
    from feltool.runs.legged import legged_run
    from feltool.viewer.rollout import load_rollouts, parse_cycles, run_robot, write_rollout_html

    if legged_run(args.run_dir) is not None:
        return view_legged(args)

    cycles = parse_cycles(args.cycles)
    if args.zmq_url is not None:
        from feltool.viewer.live import check_zmq_url

        check_zmq_url(args.zmq_url)  # before anything slow
    seed, _, _ = load_rollouts(args.run_dir, args.seed, cycles)  # bad input fails first
    robot = run_robot(args.run_dir)
    if args.html:
        name = "rollout.html" if args.seed is None else f"rollout-seed{seed}.html"
        print(write_rollout_html(robot, args.run_dir, seed, cycles,
                                 path=args.run_dir / name))
        return 0
    from feltool.viewer.rollout import replay

    return serve(args, robot, lambda viewer, left: replay(viewer, args.run_dir, seed, cycles,
                                                          loops=args.loops, timeout_s=left))


def serve(args: argparse.Namespace, robot, play: Callable[[object, float | None], object],
          **options) -> int:
    """``feltool view``'s live viewer of ``robot`` (``options``: the
    :class:`~feltool.viewer.live.LiveViewer`'s), ``play(viewer, timeout_s)`` in it, kept up
    by :func:`keep_viewing` (SIGTERM ends it as Ctrl-C does); exit code 0."""
    from feltool.viewer.live import LiveViewer

    exit_on_sigterm()
    with LiveViewer(robot, zmq_url=args.zmq_url, **options) as viewer:
        keep_viewing(viewer, lambda left: play(viewer, left), args.view_timeout)
    return 0


def view_legged(args: argparse.Namespace) -> int:
    """``feltool view RUN_DIR`` on a legged run: its clips (the seed's cycles around the world's
    change and its last ones) in the live viewer, each in place; with ``--html`` its
    rollout.html."""
    from feltool.errors import InputError
    from feltool.runs.legged import stored_config
    from feltool.viewer.legged import legged_clips, replay_legged, visual_robot, write_legged_html
    from feltool.viewer.rollout import CYCLES, parse_cycles

    if parse_cycles(args.cycles) != list(CYCLES):
        raise InputError(f"--cycles {args.cycles}: a legged run shows the cycles around its "
                         "world's change and its last ones (leave out --cycles)")
    if args.zmq_url is not None:
        from feltool.viewer.live import check_zmq_url

        check_zmq_url(args.zmq_url)
    cfg, base_dir = stored_config(args.run_dir)
    seed = legged_clips(args.run_dir, args.seed)[0]  # bad input fails first
    robot = visual_robot(cfg.robot, cfg.urdf_path(base_dir))
    if args.html:
        name = "rollout.html" if args.seed is None else f"rollout-seed{args.seed}.html"
        print(write_legged_html(args.run_dir, robot, args.seed, path=args.run_dir / name))
        return 0
    return serve(args, robot, lambda viewer, left: replay_legged(
        viewer, args.run_dir, seed, args.loops, timeout_s=left), ghost=False)


def add_command(sub) -> None:
    """Add ``feltool view`` to the subparsers ``sub``."""
    p = subcommand(sub, "view", "replay a recorded run in meshcat (or write rollout.html)",
             "  feltool view runs/arm                       # until Ctrl-C\n"
             "  feltool view runs/arm --seed 3 --cycles last --loops 2 --view-timeout 30\n"
             "  feltool view runs/arm --html --seed 3       # runs/arm/rollout-seed3.html")
    p.add_argument("run_dir", type=Path, help="a complete run directory")
    p.add_argument("--seed", type=int, help="seed to show (default: the first with traces)")
    p.add_argument("--cycles", default="first,last",
                   help="recorded cycles to show: first, last or first,last (default)")
    p.add_argument("--html", action="store_true",
                   help="write RUN_DIR/rollout.html (rollout-seedN.html with --seed) instead of "
                   "starting a viewer")
    p.add_argument("--zmq-url", metavar="URL", help="use this running meshcat-server")
    p.add_argument("--loops", type=int, default=0, metavar="N",
                   help="play the cycles N times, then keep showing the last pose "
                   "(default 0: play until Ctrl-C)")
    p.add_argument("--view-timeout", type=float, metavar="S",
                   help="close the viewer after S seconds (default: on Ctrl-C)")
    p.set_defaults(func=cmd_view)
