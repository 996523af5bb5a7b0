"""The ``feltool`` command.

Exit codes: 0 success, 2 bad input (config, URDF, arguments), 1 anything else. Bad input prints
what is wrong and where, never a traceback. (argparse rather than a CLI framework: its exit code
2 for usage errors and its plain messages are exactly the contract.)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from feltool import __version__
from feltool.checkpoint import Interrupted
from feltool.errors import FeltoolError, InputError


def parse_seeds(spec: str) -> list[int]:
    """``0-19`` | ``0,3,7`` | ``5`` (a single seed) -> a sorted list of seeds."""
    seeds: list[int] = []
    try:
        for part in spec.split(","):
            part = part.strip()
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-", 1))
                if hi < lo or lo < 0:
                    raise ValueError
                seeds += list(range(lo, hi + 1))
            else:
                value = int(part)
                if value < 0:
                    raise ValueError
                seeds.append(value)
    except ValueError:
        raise InputError(f"--seeds: cannot read '{spec}'; use e.g. 0-19, 0,3,7 or 5") from None
    return sorted(set(seeds))


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _load(config: str, overrides: list[str]):
    from feltool.config import apply_overrides, read_yaml
    from feltool.experiment import build_experiment, resolve_config_path

    path = resolve_config_path(config)
    raw = apply_overrides(read_yaml(path), overrides)
    return build_experiment(raw, source=path), raw


def cmd_run(args: argparse.Namespace) -> int:
    from feltool.runner import default_out_dir, resume_run, run_experiment

    progress = args.progress and sys.stderr.isatty()
    if args.resume is not None:
        if args.config is not None:
            raise InputError("give either CONFIG or --resume RUN_DIR, not both")
        summary = resume_run(args.resume, args.workers, progress)
        print_summary(summary, args.resume)
        return 1 if summary["aggregate"]["n_diverged"] else 0
    if args.config is None:
        raise InputError("run needs a CONFIG (or --resume RUN_DIR)")
    overrides = list(args.set or [])
    if args.cycles is not None:
        overrides.append(f"sim.cycles={args.cycles}")
    if args.seeds is not None:
        overrides.append(f"seeds={parse_seeds(args.seeds)}")
    exp, raw = _load(args.config, overrides)
    out_dir = args.out or default_out_dir(exp.config.name)
    try:
        summary = run_experiment(exp, raw, out_dir, workers=args.workers, show_progress=progress)
    except Interrupted as exc:
        raise Interrupted(f"{exc}; continue with: feltool run --resume {out_dir}") from None
    print_summary(summary, out_dir)
    return 1 if summary["aggregate"]["n_diverged"] else 0


def print_summary(summary: dict, out_dir: Path) -> None:
    agg = summary["aggregate"]
    print(f"{summary['config']}: {agg['n_seeds']} seeds, error signal = feedback of "
          f"{', '.join(summary['error_joints'])}")
    print(f"  {'seed':>4} {'cycles':>6} {'fb_initial':>11} {'fb_final':>10} {'ratio':>8} "
          f"{'converged':>9} {'steps/s':>9}")
    for s in summary["seeds"]:
        if s["diverged"]:
            print(f"  {s['seed']:>4} DIVERGED: {s['diverged_reason']}")
            continue
        conv = "-" if s["converged_cycle"] is None else str(s["converged_cycle"])
        print(f"  {s['seed']:>4} {s['cycles']:>6} {s['fb_initial']:>11.4g} {s['fb_final']:>10.3g} "
              f"{s['fb_ratio']:>8.2%} {conv:>9} {s['steps_per_s']:>9.0f}")
    conv = agg["converged_cycle_max"]
    print(f"  converged (below 5 % of the initial feedback for good): {agg['n_converged']}/"
          f"{agg['n_seeds']} seeds" + (f", mean cycle {agg['converged_cycle_mean']:.1f}, "
                                        f"max {conv}" if conv is not None else ""))
    print(f"  diverged: {agg['n_diverged']}   run directory: {out_dir}")


def cmd_check(args: argparse.Namespace) -> int:
    exp, _ = _load(args.config, list(args.set or []))
    cfg = exp.config
    print(f"{exp.source}: ok - robot {exp.robot.name} ({len(exp.joints)} moving joints: "
          f"{', '.join(exp.joints)}), {cfg.steps_per_cycle} steps per cycle, learned: "
          f"{', '.join(exp.learned_joints) or 'nothing'}, error signal: "
          f"{', '.join(exp.error_joints)}, {len(cfg.seed_list)} seeds")
    return 0


def cmd_robots(args: argparse.Namespace) -> int:
    from feltool.robot import bundled_robots, erd_robots

    print("bundled:")
    for name in bundled_robots():
        print(f"  {name}")
    print("example-robot-data (use as example-robot-data:NAME):")
    for name in erd_robots():
        print(f"  {name}")
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    from feltool.robot import describe, load_robot

    info = describe(load_robot(args.robot, base_dir=Path.cwd()))
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"robot {info['name']}  ({info['source']})")
    print(f"  {'joint':<22} {'type':<18} {'axis':<18} {'limits':<20} {'parent':<16}")
    for j in info["joints"]:
        lim = f"[{j['lower']:.4g}, {j['upper']:.4g}]"
        print(f"  {j['name']:<22} {j['type']:<18} {str(j['axis']):<18} {lim:<20} {j['parent']:<16}")
    print(f"  {'body (moved by joint)':<22} {'mass [kg]':>10}")
    for b in info["bodies"]:
        print(f"  {b['name']:<22} {b['mass']:>10.4g}")
    print(f"  total mass: {info['total_mass']:.4g} kg")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from feltool.plots import draw_figures

    for path in draw_figures(args.run_dir, args.seed):
        print(path)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="feltool", description="Feedback error learning of rhythmic movement primitives "
        "on URDF robots.")
    parser.add_argument("--version", action="version", version=f"feltool {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run an experiment over its seeds, write a run directory")
    p.add_argument("config", nargs="?", help="experiment YAML, or the name of a bundled config")
    p.add_argument("--resume", type=Path, metavar="RUN_DIR",
                   help="continue an interrupted run where it stopped")
    p.add_argument("--seeds", help="seeds to run, e.g. 0-19 or 0,3,7 (default: the config's)")
    p.add_argument("--cycles", type=_positive_int, help="learning cycles per seed")
    p.add_argument("--out", type=Path, help="run directory (default runs/<name>-<UTC time>)")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE",
                   help="override a config field (repeatable)")
    p.add_argument("--workers", type=_positive_int, help="processes (default: all cores)")
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="no progress bar")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("check", help="validate a config without running it")
    p.add_argument("config")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("robots", help="list bundled and example-robot-data robots")
    p.set_defaults(func=cmd_robots)

    p = sub.add_parser("inspect", help="joints, links, masses of a robot")
    p.add_argument("robot", help="bundled name, URDF path or example-robot-data:NAME")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("plot", help="(re)draw the figures of a run directory")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--seed", type=int, help="seed for the per-seed figures")
    p.set_defaults(func=cmd_plot)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    args = build_parser().parse_args(argv)  # exits 2 on usage errors
    try:
        return args.func(args)
    except FeltoolError as exc:
        print(f"feltool: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("feltool: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
