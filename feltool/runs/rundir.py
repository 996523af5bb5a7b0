"""The run directory: what a run writes, written atomically, and read back for plots.

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
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np


def atomic_write(path: Path, data: bytes | str) -> None:
    """Write a file so that a reader never sees half of it (temporary file, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # like any file a tool writes (mkstemp gives 0600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()  # read once (os.umask can only be read by setting it)


def save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    atomic_write(path, buf.getvalue())


def load_npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


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
    with open(path, newline="") as fh:
        return [{k: (int(v) if k in ("seed", "cycle") else float(v)) for k, v in row.items()}
                for row in csv.DictReader(fh)]


def write_json(path: Path, obj: Any, compact: bool = False) -> None:
    """Write ``obj`` as JSON, indented for people (``compact``: one line, for feltool's own
    records, which the C encoder writes many times faster)."""
    atomic_write(path, (json.dumps(obj, separators=(",", ":")) if compact
                        else json.dumps(obj, indent=2)) + "\n")
