"""``feltool plot``: (re)draw a run directory's figures."""

from __future__ import annotations

import argparse
from pathlib import Path

from feltool.cli.common import subcommand


def cmd_plot(args: argparse.Namespace) -> int:
    from feltool.runs.legged import legged_run, redraw
    from feltool.runs.plots import draw_figures

    legged = legged_run(args.run_dir) is not None
    for path in redraw(args.run_dir) if legged else draw_figures(args.run_dir, args.seed):
        print(path)
    return 0


def add_command(sub) -> None:
    """Add ``feltool plot`` to the subparsers ``sub``."""
    p = subcommand(sub, "plot", "(re)draw the figures of a complete run directory",
             "  feltool plot runs/arm\n  feltool plot runs/arm --seed 3")
    p.add_argument("run_dir", type=Path, help="a complete run directory")
    p.add_argument("--seed", type=int, help="seed for the per-seed figures")
    p.set_defaults(func=cmd_plot)
