"""The one writer: every file feltool writes goes through here.

A file is written atomically: into a temporary file beside it, then renamed over it. A reader
never sees half of it, and a write that fails (a full disk, a read-only file system, no
permission, a file size limit) leaves what was there before untouched and no temporary file
behind. Every OS error becomes one :class:`WriteError` that names the path and says why, in
words (``runs/arm/summary.json: cannot write (no space left on the device)``), never a
traceback; the caller says what is kept (:mod:`feltool.runs.runner`).

Temporary files are named ``.NAME.XXXXXXXX.tmp``; one can only outlive its write when the
process is killed between creating and renaming it (SIGKILL, a lost machine), and
:func:`remove_stale_temporaries` clears those before a directory is written again.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

from feltool.errors import FeltoolError

#: What an OS error number means for a file feltool writes, in words.
_REASONS = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large (a file size limit: ulimit -f)",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "a directory of the path does not exist",
    errno.ENOTDIR: "a part of the path is a file, not a directory",
    errno.EISDIR: "it is a directory",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EIO: "input/output error (a failing disk or a lost network mount?)",
    errno.EEXIST: "it exists and is not a directory",
}
#: Errors of a place that was fine and ran out (the run stopped; its results so far count).
FULL = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
TEMP_SUFFIX = ".tmp"


class WriteError(FeltoolError):
    """A file or directory could not be written.

    Attributes:
        path: The file or directory.
        reason: Why, in words.
        code: The OS error number (``errno.ENOSPC`` ...), or None.
        kept: What the command keeps of what it wrote, and how to go on (a run says it; see
            :meth:`keeping`).
        exit_code: 2 (a bad place to write: nothing was written), or 1 (a run that stopped:
            what it wrote so far is kept).
    """

    def __init__(self, path: str | Path, reason: str, code: int | None = None,
                 kept: str = "", exit_code: int = 2):
        self.path, self.reason, self.code = str(path), reason, code
        self.kept, self.exit_code = kept, exit_code
        super().__init__(f"{path}: cannot write ({reason})" + (f"; {kept}" if kept else ""))

    def __reduce__(self):  # travels back from worker processes intact
        return type(self), (self.path, self.reason, self.code, self.kept, self.exit_code)

    def keeping(self, kept: str, exit_code: int) -> WriteError:
        """The same error, saying what is kept and with this exit code."""
        return WriteError(self.path, self.reason, self.code, kept, exit_code)

    @property
    def ran_out(self) -> bool:
        """The place was fine and ran out of space (or quota, or the file size limit)."""
        return self.code in FULL


def reason(exc: OSError) -> str:
    """An OS error in words (its number's meaning, else the system's text)."""
    return _REASONS.get(exc.errno, exc.strerror or str(exc))


def as_write_error(exc: OSError, path: str | Path) -> WriteError:
    """``exc`` as a :class:`WriteError` naming the file it is about (``path`` if it names
    none; a temporary file counts as the file it was for)."""
    where = exc.filename if isinstance(exc.filename, str) and exc.filename else str(path)
    if Path(where).name.startswith(".") and where.endswith(TEMP_SUFFIX):
        where = str(path)
    return WriteError(where, reason(exc), exc.errno)


@contextlib.contextmanager
def writing(path: str | Path) -> Iterator[None]:
    """Turn an OS error raised inside the block (by another library writing ``path``: a
    compiler, matplotlib) into a :class:`WriteError` naming ``path``."""
    try:
        yield
    except WriteError:
        raise
    except OSError as exc:
        raise as_write_error(exc, path) from None


def make_dirs(path: str | Path) -> Path:
    """Create a directory and its parents (nothing if it exists)."""
    path = Path(path)
    with writing(path):
        path.mkdir(parents=True, exist_ok=True)
    return path


def claim_dir(path: str | Path) -> bool:
    """Create the directory ``path`` (its parents if needed); False when it exists already, so
    two processes never claim the same one."""
    path = Path(path)
    make_dirs(path.parent)
    try:
        with writing(path):
            path.mkdir()
    except WriteError as exc:
        if exc.code == errno.EEXIST:
            return False
        raise
    return True


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()  # read once (os.umask can only be read by setting it)


def write_by(path: str | Path, fill: Callable[[BinaryIO], None]) -> Path:
    """Write ``path`` atomically with ``fill(binary file)`` (e.g. ``fig.savefig``)."""
    path = Path(path)
    make_dirs(path.parent)
    tmp = None
    try:
        with writing(path):
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.",
                                       suffix=TEMP_SUFFIX)
            os.fchmod(fd, 0o666 & ~_UMASK)  # like any file a tool writes (mkstemp gives 0600)
            with os.fdopen(fd, "wb") as fh:
                fill(fh)
            os.replace(tmp, path)
            tmp = None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    return path


def atomic_write(path: str | Path, data: bytes | str) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` so that a reader never sees half of it."""
    raw = data.encode() if isinstance(data, str) else data
    return write_by(path, lambda fh: fh.write(raw))


def create_new(path: str | Path, data: str) -> bool:
    """Create ``path`` with ``data`` only if it does not exist (a lock file); False if it
    does. A write that fails leaves no file."""
    path = Path(path)
    make_dirs(path.parent)
    try:
        with writing(path):
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666)
    except WriteError as exc:
        if exc.code == errno.EEXIST:
            return False
        raise
    try:
        with writing(path), os.fdopen(fd, "w") as fh:
            fh.write(data)
    except WriteError:
        with contextlib.suppress(OSError):
            path.unlink()
        raise
    return True


def remove_stale_temporaries(directory: str | Path) -> list[Path]:
    """Remove the temporary files of writes that a killed process never finished, anywhere
    under ``directory`` (call only while owning it); returns those removed."""
    removed = []
    for tmp in Path(directory).rglob(f".*{TEMP_SUFFIX}"):
        if tmp.is_file():
            with contextlib.suppress(OSError):
                tmp.unlink()
                removed.append(tmp)
    return removed


def dump_yaml(data: Any, **options: Any) -> str:
    """``yaml.safe_dump(data, **options)`` (plain data only) through libyaml's emitter when
    PyYAML has it (the same text as PyYAML's own, checked on the gait configs; four times
    faster on their long lists of samples)."""
    import yaml

    return yaml.dump(data, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper), **options)
