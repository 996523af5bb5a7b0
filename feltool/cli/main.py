"""The ``feltool`` command: its parser (one module per subcommand adds its own) and entry point."""

from __future__ import annotations

import argparse
import os
import signal
import sys

# feltool's matrices are small (tens of rows): BLAS threads only contend with each other and
# with other processes (a 556 x 30 least squares takes 13 ms with OpenBLAS's threads on a busy
# 2-core machine, 0.25 ms with one). Set before numpy loads; the environment's choice wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from feltool._version import __version__  # noqa: E402
from feltool.cli import check, gait, plot, robots, robustness, run, sweep, view  # noqa: E402
from feltool.cli.common import EXIT_CODES  # noqa: E402
from feltool.errors import FeltoolError  # noqa: E402
from feltool.files import reason  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="feltool", description="Feedback error learning of rhythmic movement primitives "
        "on URDF robots.", epilog="examples:\n  feltool run two_link_standard\n"
        "  feltool check configs/biped_torso.yaml\n  feltool inspect example-robot-data:ur5\n"
        "\nfeltool COMMAND --help shows each command's options.\n\n" + EXIT_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"feltool {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    for module in (run, sweep, view, check, robots, gait, plot, robustness):
        module.add_command(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    args = build_parser().parse_args(argv)  # exits 2 on usage errors
    if hasattr(signal, "SIGXFSZ"):  # past a file size limit (ulimit -f) a write fails with
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG, named, instead of killing us
    try:
        return args.func(args)
    except FeltoolError as exc:
        print(f"feltool: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("feltool: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # e.g. feltool inspect ... | head: the reader has gone
        _silence_stdout()
        return 0
    except OSError as exc:  # the last net: an OS error no writer or reader named
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"feltool: error: {where}{reason(exc)}", file=sys.stderr)
        return 1


def _silence_stdout() -> None:
    """After a broken pipe, point stdout at /dev/null so that the interpreter's final flush
    does not raise again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def console() -> None:
    """The ``feltool`` command: :func:`main`, then exit at once. Everything is written and
    closed by then; skipping the interpreter's teardown (freeing Pinocchio, CasADi,
    matplotlib) saves a few tenths of a second per command."""
    code = main()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


if __name__ == "__main__":
    console()
