"""What the subcommands share: exit codes in the help, the subparser factory, common options."""

from __future__ import annotations

import argparse
import sys

from feltool.bounds import parse_seeds


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def cycle_count(text: str) -> int:
    """``--cycles``: a whole number from 1 to the bound every API and config meets."""
    from feltool.bounds import MAX_CYCLES

    value = positive_int(text)
    if value > MAX_CYCLES:
        raise argparse.ArgumentTypeError(f"at most {MAX_CYCLES}, got {value}")
    return value


def progress_mode(args: argparse.Namespace) -> tuple[bool, object]:
    """(progress bar?, stream for progress lines or None): a bar on a terminal, else lines."""
    if getattr(args, "quiet", False) or not args.progress:
        return False, None
    if sys.stderr.isatty():
        return True, None
    return False, sys.stderr


EXIT_CODES = """exit codes:
  0    every seed learned as the config asks (it did not diverge or fall, and met success:)
  1    some seed diverged, fell or missed the config's success: criterion (results kept)
  2    bad input: config, URDF, arguments, or a run directory that is not this command's
  130  interrupted by Ctrl-C (143: SIGTERM); continue with --resume"""


def subcommand(sub, name: str, help: str, examples: str, exit_codes: bool = False):
    epilog = "examples:\n" + examples + ("\n\n" + EXIT_CODES if exit_codes else "")
    return sub.add_parser(name, help=help, description=help[0].upper() + help[1:] + ".",
                          epilog=epilog, formatter_class=argparse.RawDescriptionHelpFormatter)


def add_progress_options(p) -> None:
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="no progress bar (on a terminal) or progress lines (elsewhere)")
    p.add_argument("--quiet", "-q", action="store_true", help="print only the summary")


def load_config(config: str, overrides: list[str], check_targets: bool = True):
    from feltool.config.files import apply_overrides, read_yaml
    from feltool.runs.experiments import build_experiment, resolve_config_path

    path = resolve_config_path(config)
    raw = apply_overrides(read_yaml(path), overrides)
    return build_experiment(raw, source=path, check_targets=check_targets), raw


def print_warnings(robot) -> None:
    """What lenient URDF reading accepted (robot.lenient), one line each, on stderr."""
    for line in robot.warnings:
        print(f"feltool: warning: {line} (robot.lenient)", file=sys.stderr)


def config_overrides(args: argparse.Namespace) -> list[str]:
    """``feltool run``'s changes to its CONFIG: ``--set`` as given, ``--cycles`` and
    ``--seeds`` as ``sim.cycles=`` and ``seeds=``."""
    out = list(args.set or [])
    if args.cycles is not None:
        out.append(f"sim.cycles={args.cycles}")
    if args.seeds is not None:
        out.append(f"seeds={parse_seeds(args.seeds)}")
    return out
