"""Who owns a run directory, and what state it is in.

A run (or sweep) directory belongs to one command. Its ``run.json`` (``sweep.json``) records the
inputs, the ``state`` and a ``history`` of the commands that worked on it::

    running       a command is working on it (its lock file names the process)
    complete      every seed finished; the results are final
    interrupted   stopped by a signal (or killed: a ``running`` directory whose lock's
                  process is gone reads as interrupted); ``--resume`` continues it
    failed        the command ended with an error; not a result

Only one process at a time may write a directory: :class:`RunLock` holds ``.lock`` (created
exclusively, with the owner's PID and host); a lock whose process no longer exists on this host
is stale and is taken over.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import socket
import sys
from pathlib import Path
from typing import Any

from feltool.errors import InputError
from feltool.files import WriteError, claim_dir, create_new
from feltool.runs.rundir import damaged, read_json, write_json

STATES = ("running", "complete", "interrupted", "failed")
LOCK_NAME = ".lock"
CLAIMED_DIRS: set[Path] = set()  # run directories default_out_dir created in this process
NOTHING_WRITTEN = "nothing of the run was written; choose another --out, or make room there"


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def command_line() -> str:
    """The command that is running, as the user typed it (approximately)."""
    return " ".join(["feltool", *sys.argv[1:]]) if sys.argv and sys.argv[0].endswith(
        ("feltool", "__main__.py", "cli/main.py")) else " ".join(sys.argv)


def default_out_dir(name: str, root: Path = Path("runs")) -> Path:
    """A new run directory ``root/<name>-<UTC time>``, created here (with ``-2``, ``-3`` ...
    when a run started in the same second took the name), so two runs never share one."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    for n in range(1, 100_000):
        path = root / (f"{name}-{stamp}" + (f"-{n}" if n > 1 else ""))
        try:
            if claim_dir(path):
                CLAIMED_DIRS.add(path)
                return path
        except WriteError as exc:
            raise exc.keeping(NOTHING_WRITTEN, 2) from None
    raise InputError(f"{root}: no free run directory name for {name}-{stamp}; use --out")


def source_path(exp) -> str | None:
    """The config file ``exp`` came from as an absolute path (what run.json and tasks keep,
    so that a resume or a worker in another working directory finds the same files)."""
    return str(Path(exp.source).resolve()) if exp.source else None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


class RunLock:
    """Exclusive ownership of a directory for this process (``DIR/.lock``).

    Raises:
        InputError: when another live process holds the lock.
    """

    def __init__(self, directory: Path):
        self.path = Path(directory) / LOCK_NAME
        self.held = False

    def owner(self) -> dict[str, Any] | None:
        """The lock's content, or None when there is no lock (or it is unreadable)."""
        try:
            return json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None

    def stale(self) -> bool:
        """Whether an existing lock's process is gone (on this host)."""
        owner = self.owner()
        if owner is None:
            return self.path.exists()
        return owner.get("host") == socket.gethostname() and not _alive(int(owner.get("pid", -1)))

    def acquire(self) -> RunLock:
        record = json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                             "since_utc": utc_now(), "command": command_line()})
        for _ in range(2):
            if not create_new(self.path, record):
                if not self.stale():
                    owner = self.owner() or {}
                    raise InputError(
                        f"{self.path.parent}: in use by another feltool process (PID "
                        f"{owner.get('pid', '?')} on {owner.get('host', '?')}, since "
                        f"{owner.get('since_utc', '?')}); wait for it, or use another --out"
                    ) from None
                self.path.unlink(missing_ok=True)  # stale: its process is gone
                continue
            self.held = True
            return self
        raise InputError(f"{self.path.parent}: could not take the lock {self.path}")

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def read_meta(meta_path: Path, required: tuple[str, ...] = ()) -> dict[str, Any]:
    """A directory's ``run.json`` / ``sweep.json``, which must hold the keys ``required``;
    a damaged one is an :class:`InputError` naming it."""
    meta = read_json(Path(meta_path))
    missing = [k for k in required if k not in meta]
    if missing:
        raise damaged(meta_path, f"no {', '.join(missing)}; not written by feltool?")
    return meta


def run_state(directory: Path, meta_name: str = "run.json") -> str | None:
    """The directory's state (see the module docstring), or None if it has no metadata."""
    directory = Path(directory)
    meta_path = directory / meta_name
    if not meta_path.is_file():
        return None
    state = read_meta(meta_path).get("state", "complete")  # before states: finished runs only
    if state == "running" and RunLock(directory).owner() is None or \
            state == "running" and RunLock(directory).stale():
        return "interrupted"
    return state


def set_state(directory: Path, state: str, meta_name: str = "run.json", **extra: Any) -> None:
    """Record ``state`` in the metadata and close the newest history entry if it ends."""
    assert state in STATES, state
    meta_path = Path(directory) / meta_name
    meta = read_meta(meta_path)
    meta["state"] = state
    history = meta.setdefault("history", [])
    if state == "running":
        history.append({"command": command_line(), "started_utc": utc_now(), **extra})
    elif history:
        history[-1].update({"ended_utc": utc_now(), "state": state, **extra})
    write_json(meta_path, meta)


def describe_contents(directory: Path, limit: int = 6) -> str:
    names = sorted(p.name for p in Path(directory).iterdir() if p.name != LOCK_NAME)
    shown = ", ".join(names[:limit]) + (", ..." if len(names) > limit else "")
    return shown


def has_contents(directory: Path) -> bool:
    directory = Path(directory)
    return directory.is_dir() and any(p.name != LOCK_NAME for p in directory.iterdir())


def refuse_existing(directory: Path, meta_name: str, resume_hint: str) -> None:
    """Raise when ``directory`` already holds something (a run directory belongs to one
    command; only an explicit resume may continue it)."""
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise InputError(f"--out {directory}: exists and is not a directory")
    if not has_contents(directory):
        return
    state = run_state(directory, meta_name)
    what = (f"a feltool {meta_name.removesuffix('.json')} directory ({state})" if state
            else "files")
    raise InputError(
        f"--out {directory}: already holds {what}: {describe_contents(directory)}; a run "
        f"directory belongs to one command. Choose a new --out, or continue it with "
        f"{resume_hint}")


def require_complete(directory: Path, meta_name: str = "run.json") -> None:
    """Raise unless ``directory`` is a complete run (a partial one is never shown as a result)."""
    state = run_state(directory, meta_name)
    if state not in (None, "complete"):
        raise InputError(f"{directory}: the run is {state}, not complete, so it is not a result; "
                         f"continue it with: feltool run --resume {directory}")


def check_run_dir(path: Path) -> Path:
    """A complete run directory (with a summary), else an :class:`InputError`: a run that is
    still running, was interrupted or failed is never shown as a result."""
    path = Path(path)
    require_complete(path)
    if not (path / "summary.json").is_file() or not (path / "metrics.csv").is_file():
        raise InputError(f"{path}: not a feltool run directory (no summary.json / metrics.csv)")
    return path


def config_differences(a: Any, b: Any, path: str = "") -> list[str]:
    """Where two resolved configs (nested mappings) differ: ``path: a -> b`` per leaf."""
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b), key=str)
                for d in config_differences(a.get(k), b.get(k), f"{path}.{k}" if path else str(k))]
    return [] if a == b else [f"{path or '<config>'}: {a!r} -> {b!r}"]
