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
import time
from pathlib import Path
from typing import Any

import numpy as np

from feltool.errors import FeltoolError
from feltool.runs.rundir import damaged, load_npz, read_json, save_npz, write_json

_STOP = {"requested": False, "signal": signal.SIGINT}


class Interrupted(FeltoolError):
    """A run stopped on request (SIGINT/SIGTERM) after saving its checkpoints; the exit code
    is 128 + the signal's number (130 for Ctrl-C, 143 for SIGTERM)."""

    @property
    def exit_code(self) -> int:  # type: ignore[override]
        return 128 + int(_STOP["signal"])


def request_stop(signum: int = signal.SIGINT, *_: Any) -> None:
    """Ask running seeds to checkpoint and stop at the end of their current cycle."""
    _STOP["requested"] = True
    _STOP["signal"] = signum


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
        min_interval_s: ... but, after the first, not sooner than this after the last save,
            in [s] (a seed whose cycles take microseconds would spend its time writing
            checkpoints).
    """

    def __init__(self, directory: Path, seed: int, every: int = 10, min_interval_s: float = 0.0):
        self.directory = Path(directory)
        self.seed = seed
        self.every = max(1, int(every))
        self.min_interval_s = float(min_interval_s)
        self._last = time.monotonic()
        #: the cycle of the last checkpoint this object wrote (None: none yet)
        self.saved_cycle: int | None = None
        self.arrays = self.directory / f"seed-{seed}.npz"
        self.meta = self.directory / f"seed-{seed}.json"

    def due(self, cycle: int) -> bool:
        """Whether a checkpoint is due after ``cycle``: every ``every`` cycles, the first at
        once, the others ``min_interval_s`` apart."""
        return cycle % self.every == 0 and (
            self.saved_cycle is None or time.monotonic() - self._last >= self.min_interval_s)

    def load(self) -> dict[str, Any] | None:
        """The last checkpoint, or None. The npz holds its own metadata (``meta_json``), so a
        checkpoint whose ``.json`` could not be written (a full disk) still counts; one
        written before that holds only the arrays and needs its ``.json`` (the pair)."""
        if not self.arrays.is_file():
            return None
        hint = (f"move {self.meta.name} and {self.arrays.name} away to run seed {self.seed} "
                "again from its first cycle (to the same numbers)")
        arrays = load_npz(self.arrays, hint)
        if "meta_json" in arrays:
            try:
                meta = json.loads(arrays.pop("meta_json").tobytes())
            except ValueError as exc:
                raise damaged(self.arrays, f"its metadata is not valid JSON: {exc}",
                              hint) from None
        elif not self.meta.is_file():
            return None
        else:
            meta = read_json(self.meta, hint)
        if meta.get("arrays_id") != int(arrays.get("arrays_id", -1)):
            return None  # torn pair (should not happen with atomic writes): start over
        return {**meta, **{k: v for k, v in arrays.items() if k != "arrays_id"}}

    def save(self, cycle: int, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        # One atomic file holds the arrays and the metadata: a write that fails (a full disk)
        # leaves the previous checkpoint whole. The .json beside it is the same metadata, for
        # people and tools that read it.
        arrays_id = cycle
        meta = {**meta, "cycle": cycle, "arrays_id": arrays_id}
        text = json.dumps(meta, separators=(",", ":"))
        save_npz(self.arrays, {**arrays, "arrays_id": np.array(arrays_id),
                               "meta_json": np.frombuffer(text.encode(), np.uint8)})
        write_json(self.meta, meta, compact=True)
        self._last, self.saved_cycle = time.monotonic(), cycle

    def clear(self) -> None:
        self.arrays.unlink(missing_ok=True)
        self.meta.unlink(missing_ok=True)


def remove_empty(directory: Path) -> None:
    """Remove a checkpoint directory once every seed is done (only if it is empty). Called by
    the process that owns the run, never by workers, which may still be writing into it."""
    try:
        Path(directory).rmdir()
    except OSError:
        pass
