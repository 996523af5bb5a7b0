"""``feltool sweep``: a grid of config overrides over seeds."""

from __future__ import annotations

import argparse
from pathlib import Path

from feltool.bounds import parse_seeds
from feltool.cli.common import (
    add_progress_options,
    cycle_count,
    positive_int,
    progress_mode,
    subcommand,
)
from feltool.errors import InputError
from feltool.runs.checkpoint import Interrupted


def cmd_sweep(args: argparse.Namespace) -> int:
    from feltool.runs.runner import default_out_dir
    from feltool.runs.sweep import parse_grid, run_sweep

    bar, lines = progress_mode(args)
    if args.resume is not None:
        if args.config is not None or args.grid:
            raise InputError("--resume continues a sweep as it was: give no CONFIG or --grid")
        out_dir, config, grid = args.resume, None, None
    else:
        if args.config is None:
            raise InputError("sweep needs a CONFIG (or --resume SWEEP_DIR); see feltool sweep "
                             "--help")
        config, grid = args.config, parse_grid(args.grid or [])
        out_dir = args.out or default_out_dir(Path(config).stem + "-sweep")
    seeds = parse_seeds(args.seeds) if args.seeds else None
    try:
        rows = run_sweep(config, grid, out_dir, seeds, args.cycles, args.workers, args.scheduler,
                         bar, resume=args.resume is not None, progress_lines=lines)
    except Interrupted as exc:
        raise Interrupted(f"{exc}; continue with: feltool sweep --resume {out_dir}") from None
    points = len({r["point"] for r in rows})
    conv = sum(r["converged_cycle"] is not None for r in rows)
    div = sum(bool(r["diverged"]) for r in rows)
    print(f"sweep: {points} points x {len(rows) // max(points, 1)} seeds; converged {conv}, "
          f"diverged {div}; {out_dir / 'sweep.csv'}")
    bad = [r for r in rows if not r["learned"]]
    for r in bad:
        where = ", ".join(f"{k}={v}" for k, v in r.items() if k not in _ROW_FIELDS)
        print(f"  point {r['point']} ({where}), seed {r['seed']}: {r['failed_reason']}")
    return 1 if bad else 0


_ROW_FIELDS = {"point", "seed", "fb_initial", "fb_final", "converged_cycle", "diverged", "learned",
               "failed_reason"}


def add_command(sub) -> None:
    """Add ``feltool sweep`` to the subparsers ``sub``."""
    p = subcommand(sub, "sweep", "run a grid of config overrides over seeds",
             "  feltool sweep two_link_standard --grid learning.rates.gauss_newton=0.5,1.0 --seeds 0-9\n"
             "  feltool sweep two_link_standard --grid learning.rates.gauss_newton=0.5,1.0 \\\n"
             "      --grid joints.elbow.gains.kp=50,100 --scheduler tcp://10.0.0.5:8786\n"
             "  feltool sweep --resume runs/two_link_standard-sweep-20261201T120000Z",
             exit_codes=True)
    p.add_argument("config", nargs="?", help="experiment YAML, or the name of a bundled config")
    p.add_argument("--grid", action="append", metavar="A.B.C=V1,V2",
                   help="a swept field and its values (repeatable; the product is run)")
    p.add_argument("--seeds", help="seeds per point, e.g. 0-9 (default: the config's)")
    p.add_argument("--cycles", type=cycle_count, help="learning cycles per seed")
    p.add_argument("--out", type=Path, help="sweep directory, new or empty (default "
                   "runs/<name>-sweep-<UTC time>)")
    p.add_argument("--workers", type=positive_int, help="local processes (default: all cores)")
    p.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="run on a Dask cluster (default $FELTOOL_SCHEDULER, else locally)")
    p.add_argument("--resume", type=Path, metavar="SWEEP_DIR",
                   help="continue an interrupted sweep as it was")
    add_progress_options(p)
    p.set_defaults(func=cmd_sweep)
