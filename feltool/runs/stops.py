"""When a run stops for its surroundings rather than its inputs: a full disk, a read-only
place, a worker process that died.

Each ends in one line that names the file (or the worker), says what is kept and how to go
on, and in the exit code that tells which it was: 2 when nothing of the run was written (a bad
place to write: choose another), 1 when a run stopped with its results so far on disk, marked
``interrupted`` and resumable (a full disk, a killed worker).
"""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

from feltool.errors import FeltoolError, InputError
from feltool.files import WriteError
from feltool.runs.runstate import LOCK_NAME, NOTHING_WRITTEN, set_state

__all__ = ["NOTHING_WRITTEN", "RunStopped", "WorkerLost", "discard_new", "kept", "mark",
           "stopped"]


class WorkerLost(FeltoolError):
    """A worker process died while it ran seeds (killed by the system, e.g. out of memory, or
    by a signal); what the others finished is kept."""

    exit_code = 1


class RunStopped(FeltoolError):
    """A run stopped by a fault of its surroundings, its results so far kept (exit code 1)."""

    exit_code = 1


def kept(out_dir: Path, total: int, resume_hint: str) -> str:
    """What a stopped run (or sweep) keeps: its finished seeds (``seeds/seed-N.json`` under
    ``out_dir``, of ``total``) and its checkpoints, and the command that continues it."""
    out_dir = Path(out_dir)
    done = sum(1 for _ in out_dir.rglob("seeds/seed-*.json"))
    saved = sum(1 for c in out_dir.rglob("checkpoints/seed-*.npz")  # of unfinished seeds
                if not (c.parent.parent / "seeds" / f"{c.stem}.json").is_file())
    text = f"kept: {min(done, total)} of {total} seeds finished"
    if saved:
        text += f", checkpoints of {saved} more"
    return f"{text}; continue with: {resume_hint}"


def stopped(exc: BaseException, what_is_kept: str) -> FeltoolError:
    """``exc`` (a :class:`WriteError` or :class:`WorkerLost` while seeds ran) as the error of
    a run that stopped with its results kept: exit code 1."""
    if isinstance(exc, WriteError):
        return exc.keeping(what_is_kept.replace("; continue", "; make room, then continue")
                           if exc.ran_out else what_is_kept, 1)
    return RunStopped(f"{exc}; {what_is_kept}")


def mark(directory: Path, state: str, meta_name: str = "run.json") -> None:
    """Record ``state`` if the place still lets us (a full disk may not; the released lock
    then makes the ``running`` directory read as interrupted all the same)."""
    with contextlib.suppress(WriteError, InputError):
        set_state(directory, state, meta_name)


def discard_new(directory: Path, remove_dir: bool = True,
                names: tuple[str, ...] = ("config.yaml", "run.json", "sweep.json",
                                          "inputs")) -> None:
    """Remove what a new run wrote before it could start (the files ``names``, and with
    ``remove_dir`` the directory itself once empty): a run that never started leaves nothing
    behind."""
    directory = Path(directory)
    for name in names:
        path = directory / name
        with contextlib.suppress(OSError):
            shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
    for tmp in directory.glob(".*.tmp"):
        with contextlib.suppress(OSError):
            tmp.unlink()
    with contextlib.suppress(OSError):
        if remove_dir and not any(p.name != LOCK_NAME for p in directory.iterdir()):
            (directory / LOCK_NAME).unlink(missing_ok=True)
            directory.rmdir()
