"""``feltool run`` and ``feltool check`` on a legged config (``walking.base: free_flyer``):
the trot with FEL over its seeds (:mod:`feltool.runs.legged`)."""

from __future__ import annotations

import argparse
import sys
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


#: ``feltool run`` options a legged run does not take yet, and why
_REFUSED = {"resume": "a legged run cannot be resumed yet; start it again with a new --out",
            "view": "the live viewer does not show legged robots yet",
            "zmq_url": "the live viewer does not show legged robots yet",
            "realtime": "the live viewer does not show legged robots yet"}


def run_legged_command(args: argparse.Namespace, path: Path, raw: dict[str, Any]) -> int:
    """``feltool run`` on a legged config: exit 0 when every seed trotted (or walked) physically through
    every cycle and met ``success:``, 1 otherwise, 2 on bad input."""
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

    for option, why in _REFUSED.items():
        if getattr(args, option, None):
            raise InputError(f"--{option.replace('_', '-')}: {why}")
    cfg = parse_legged_config(raw, str(path))
    bar, lines = progress_mode(args)
    if args.workers not in (None, 1):
        print("feltool: note: a legged run's seeds run one after another (--workers ignored)",
              file=sys.stderr)
    legged = load_legged_robot(cfg, path.parent, str(path))  # bad input: nothing written
    if args.out is not None:
        refuse_taken(args.out)
    out_dir = args.out or default_out_dir(cfg.name)
    gait = "walk" if cfg.walking.walk else "trot"
    print(f"feltool: legged {gait}, {cfg.plant.simulator} plant (one seed at a time)", flush=True)
    summary = run_legged(cfg, raw, path, out_dir, progress=sys.stderr if bar or lines else None,
                         legged=legged)
    print_summary(summary, out_dir)
    if args.html:
        from feltool.viewer.legged import visual_robot, write_legged_html

        robot = visual_robot(cfg.robot, cfg.urdf_path(path.parent))
        print(f"  rollout: {write_legged_html(out_dir, robot)}")
    return exit_code(summary)


def check_legged(path: Path, raw: dict[str, Any]) -> int:
    """``feltool check`` on a legged config: the schema, the robot and its feet."""
    from feltool.config.legged import parse_legged_config
    from feltool.runs.legged import describe, load_legged_robot

    cfg = parse_legged_config(raw, str(path))
    legged = load_legged_robot(cfg, path.parent, str(path))
    print(f"{path}: ok - {describe(cfg, legged)}")
    return 0
