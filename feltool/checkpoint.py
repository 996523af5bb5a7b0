"""Checkpoints of a running seed, and stopping cleanly on SIGINT/SIGTERM.

A checkpoint holds everything a seed needs to continue exactly where it stopped: the cycle
reached, the RMP parameters, the robot state, the per-step RMP states, the metric rows and
parameter history so far, and the first cycle's traces. It is written atomically (temporary file,
then rename) every ``every`` cycles and when a stop is requested, so a reader never sees half a
file and a resumed run is bit-identical to an uninterrupted one.
"""

from __future__ import annotations

import json
import signal
from pathlib import Path
from typing import Any

import numpy as np

from feltool.errors import FeltoolError
from feltool.rundir import atomic_write, load_npz, save_npz

_STOP = {"requested": False}


class Interrupted(FeltoolError):
    """A run stopped on request (SIGINT/SIGTERM) after saving its checkpoints."""

    exit_code = 130


def request_stop(*_: Any) -> None:
    """Ask running seeds to checkpoint and stop at the end of their current cycle."""
    _STOP["requested"] = True


def stop_requested() -> bool:
    return _STOP["requested"]


def reset_stop() -> None:
    _STOP["requested"] = False


def install_stop_handlers() -> None:
    """SIGINT and SIGTERM request a clean stop instead of killing the process."""
    signal.signal(signal.SIGTERM, request_stop)
    signal.signal(signal.SIGINT, request_stop)


class Checkpointer:
    """Saves and restores one seed's progress in ``directory/seed-<n>.npz`` (+ ``.json``).

    Args:
        directory: Where checkpoints live (``RUN_DIR/checkpoints``).
        seed: The seed.
        every: Save every this many cycles (and on a stop request).
    """

    def __init__(self, directory: Path, seed: int, every: int = 10):
        self.directory = Path(directory)
        self.seed = seed
        self.every = max(1, int(every))
        self.arrays = self.directory / f"seed-{seed}.npz"
        self.meta = self.directory / f"seed-{seed}.json"

    def load(self) -> dict[str, Any] | None:
        if not (self.arrays.is_file() and self.meta.is_file()):
            return None
        meta = json.loads(self.meta.read_text())
        arrays = load_npz(self.arrays)
        if meta.get("arrays_id") != int(arrays.get("arrays_id", -1)):
            return None  # torn pair (should not happen with atomic writes): start over
        return {**meta, **{k: v for k, v in arrays.items() if k != "arrays_id"}}

    def save(self, cycle: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        # The arrays first, then the metadata that names them: a reader only trusts a pair.
        arrays_id = cycle
        save_npz(self.arrays, {**arrays, "arrays_id": np.array(arrays_id)})
        atomic_write(self.meta, json.dumps({**meta, "cycle": cycle, "arrays_id": arrays_id}))

    def clear(self) -> None:
        self.arrays.unlink(missing_ok=True)
        self.meta.unlink(missing_ok=True)
