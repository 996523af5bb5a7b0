"""``feltool run`` and ``feltool check`` on a legged config (``walking.base: free_flyer``):
the trot with FEL over its seeds (:mod:`feltool.runs.legged`)."""

from __future__ import annotations

import argparse
import signal
import sys
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from typing import Any

from feltool.errors import InputError


def legged_raw(config: str, overrides: list[str]) -> tuple[Path, dict[str, Any]] | None:
    """``(path, raw mapping)`` when ``config`` is a legged config (overrides applied), else
    None (the walkers' and arms' path reads it again)."""
    from feltool.config.files import apply_overrides, read_yaml
    from feltool.config.legged import is_legged
    from feltool.runs.experiments import resolve_config_path

    path = resolve_config_path(config)
    raw = apply_overrides(read_yaml(path), list(overrides))
    return (path, raw) if is_legged(raw) else None


def run_legged_command(args: argparse.Namespace, path: Path, raw: dict[str, Any],
                       out_dir: Path | None = None, resume: bool = False) -> int:
    """``feltool run`` on a legged config: exit 0 when every seed trotted (or walked) physically
    through every cycle and met ``success:``, 1 otherwise, 2 on bad input, 130 / 143 when
    interrupted (the finished seeds kept for ``--resume``). With ``resume``: continue the
    interrupted run in ``out_dir``. With ``--view`` (``--zmq-url``, ``--realtime``): the first
    seed it runs streamed live to meshcat (:class:`~feltool.viewer.legged.LeggedStream`), then
    the run replayed until Ctrl-C or ``--view-timeout``."""
    from feltool.cli.common import progress_mode
    from feltool.config.legged import parse_legged_config
    from feltool.runs.legged import (
        exit_code,
        load_legged_robot,
        print_summary,
        refuse_taken,
        run_legged,
    )
    from feltool.runs.runstate import default_out_dir

    cfg = parse_legged_config(raw, str(path))
    bar, lines = progress_mode(args)
    if args.workers not in (None, 1):
        print("feltool: note: a legged run's seeds run one after another (--workers ignored)",
              file=sys.stderr)
    legged = load_legged_robot(cfg, path.parent, str(path))  # bad input: nothing written
    out_dir = out_dir or args.out
    if out_dir is not None and not resume:
        refuse_taken(out_dir)
    out_dir = out_dir or default_out_dir(cfg.name)
    gait = "walk" if cfg.walking.walk else "trot"
    print(f"feltool: legged {gait}, {cfg.plant.simulator} plant (one seed at a time)", flush=True)
    from feltool.cli.view import watching
    from feltool.viewer.legged import visual_robot

    robot = cache(lambda: visual_robot(cfg.robot, cfg.urdf_path(path.parent)))  # loaded once
    stream = None
    with watching(args, robot) as viewer:
        if viewer is not None:
            from feltool.runs.legged import finished_seeds
            from feltool.viewer.legged import LeggedStream

            done = finished_seeds(out_dir, cfg.seed_list) if resume else {}
            first = next((s for s in cfg.seed_list if s not in done), cfg.seed_list[0])
            stream = LeggedStream(viewer, 1.0 / cfg.sim.rate_hz, cfg.sim.cycles,
                                  realtime=args.realtime, label=f"seed {first}")
        with _sigterm_interrupts():
            try:
                summary = run_legged(cfg, raw, path, out_dir, legged=legged, resume=resume,
                                     progress=sys.stderr if bar or lines else None,
                                     on_cycle=stream)
            finally:
                if stream is not None:
                    stream.close()
        print_summary(summary, out_dir)
        if args.html or viewer is not None:
            show_rollout(args, out_dir, robot, viewer)
    return exit_code(summary)


def show_rollout(args: argparse.Namespace, out_dir: Path, robot, viewer) -> None:
    """After a run: ``--html``'s rollout.html, and the live viewer (``--view``) replaying what
    the first seed learned until ``--view-timeout``; a seed with no motion to show says so."""
    from feltool.cli.view import keep_viewing
    from feltool.viewer.legged import NoFrames, replay_legged, write_legged_html

    try:
        if args.html:
            print(f"  rollout: {write_legged_html(out_dir, robot())}")
        if viewer is not None:  # the page stays up after the run: replay what it learned
            keep_viewing(viewer, lambda left: replay_legged(viewer, out_dir, timeout_s=left),
                         args.view_timeout)
    except NoFrames as exc:
        print(f"  rollout: not shown ({exc})")


def resume_legged_command(args: argparse.Namespace, out_dir: Path) -> int | None:
    """``feltool run --resume RUN_DIR [CONFIG]`` when RUN_DIR holds a legged run or CONFIG is
    a legged config (else None: the walkers' and arms' resume): its unfinished seeds run, with
    the stored config (or CONFIG, which must be the same)."""
    from feltool.cli.common import config_overrides
    from feltool.runs.rundir import read_json

    meta_path = Path(out_dir) / "run.json"
    meta = read_json(meta_path) if meta_path.is_file() else {}
    given = None if args.config is None else legged_raw(args.config, config_overrides(args))
    if meta.get("kind") != "legged" and given is None:
        return None
    if given is not None:
        path, raw = given
    else:
        if args.set or args.seeds:
            raise InputError("--set/--seeds change the config: give the CONFIG too, so the "
                             "resume can check it is the same run")
        if not meta.get("source"):
            raise InputError(f"--resume {out_dir}: its run.json names no config file; give "
                             "the CONFIG")
        from feltool.config.files import apply_overrides

        path, raw = Path(meta["source"]), meta.get("raw", {})
        if args.cycles is not None:
            raw = apply_overrides(raw, [f"sim.cycles={args.cycles}"])
    return run_legged_command(args, path, raw, out_dir=Path(out_dir), resume=True)


@contextmanager
def _sigterm_interrupts():
    """SIGTERM interrupts the legged run as Ctrl-C does (its finished seeds kept, exit 143)."""
    from feltool.runs.checkpoint import request_stop

    def on_term(signum, _frame):
        request_stop(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def check_legged(path: Path, raw: dict[str, Any]) -> int:
    """``feltool check`` on a legged config: the schema, the robot and its feet."""
    from feltool.config.legged import parse_legged_config
    from feltool.runs.legged import describe, load_legged_robot

    cfg = parse_legged_config(raw, str(path))
    legged = load_legged_robot(cfg, path.parent, str(path))
    print(f"{path}: ok - {describe(cfg, legged)}")
    return 0
