"""The run directory: what a run writes (through the one writer, :mod:`feltool.files`:
atomically, OS errors named), and what reads it back (resume, plots, the viewer), each reader
checking what it reads and naming a damaged file.

::

    config.yaml         the fully resolved config (defaults filled in)
    metrics.csv         one row per (seed, cycle)
    summary.json        per-seed outcome and aggregates
    params/seed-N.npz   learned RMP parameters and their history (allow_pickle=False)
    traces/seed-N.npz   system and forward trajectories of the first and last cycle
    figures/*.png       the thesis's figures
"""

from __future__ import annotations

import csv
import io
import json
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from feltool.errors import InputError
from feltool.files import atomic_write, write_by

__all__ = ["atomic_write", "damaged", "load_npz", "read_json", "read_metrics", "save_npz",
           "write_by", "write_json", "write_metrics"]


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    atomic_write(path, buf.getvalue())


def damaged(path: Path, detail: str, hint: str = "") -> InputError:
    """The error for a file of a run directory that cannot be read as what it should be (cut
    short by an interrupted copy, overwritten, a failing disk): one line naming it."""
    return InputError(f"{path}: damaged or unreadable ({detail})" + (f"; {hint}" if hint else ""))


#: What a damaged npz (a zip file of arrays) raises while it is opened or read.
_NPZ_ERRORS = (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile, zlib.error,
               NotImplementedError)


def load_npz(path: Path, hint: str = "") -> dict[str, np.ndarray]:
    """Every array of an npz file (``allow_pickle=False``); a damaged file is an
    :class:`InputError` naming it (``hint``: what to do about it)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except FileNotFoundError:
        raise damaged(path, "missing", hint) from None
    except _NPZ_ERRORS as exc:
        raise damaged(path, f"not a readable npz file: {str(exc)[:120] or type(exc).__name__}",
                      hint) from None


def read_json(path: Path, hint: str = "", kind: type = dict) -> Any:
    """A JSON file's content, which must be a ``kind``; a missing, cut-short or otherwise
    damaged file is an :class:`InputError` naming it (``hint``: what to do about it)."""
    try:
        data = json.loads(Path(path).read_bytes())
    except FileNotFoundError:
        raise damaged(path, "missing", hint) from None
    except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError included
        raise damaged(path, f"not valid JSON: {exc}", hint) from None
    if not isinstance(data, kind):
        raise damaged(path, f"holds a JSON {type(data).__name__}, not a {kind.__name__}", hint)
    return data


def write_metrics(path: Path, rows: list[dict[str, float]]) -> None:
    if not rows:
        atomic_write(path, "")
        return
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0].keys()), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
    atomic_write(path, buf.getvalue())


def read_metrics(path: Path) -> list[dict[str, float]]:
    """metrics.csv's rows; a damaged file (a row cut short, a value that is no number) is an
    :class:`InputError` naming it and the line."""
    try:
        with open(path, newline="") as fh:
            rows = []
            for line, row in enumerate(csv.DictReader(fh), start=2):
                if None in row or None in row.values():
                    raise damaged(path, f"line {line} has {'more' if None in row else 'fewer'} "
                                        "fields than the header")
                try:
                    rows.append({k: (int(v) if k in ("seed", "cycle") else float(v))
                                 for k, v in row.items()})
                except ValueError as exc:
                    raise damaged(path, f"line {line}: {exc}") from None
            return rows
    except FileNotFoundError:
        raise damaged(path, "missing") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise damaged(path, str(exc)) from None


def write_json(path: Path, obj: Any, compact: bool = False) -> None:
    """Write ``obj`` as JSON, indented for people (``compact``: one line, for feltool's own
    records, which the C encoder writes many times faster)."""
    atomic_write(path, (json.dumps(obj, separators=(",", ":")) if compact
                        else json.dumps(obj, indent=2)) + "\n")
