"""Wall clocks of a run: since the process started, and of the learning loop alone.

A run's ``steps/s`` counts only the time spent inside the learning cycles (the cycle engine's
calls), not the process start, the imports, the experiment's build, the compilation of the
compiled engine, nor the metrics, checkpoints and progress that observe each cycle; those are
reported apart (``compile_s``, ``wall_s``).
"""

from __future__ import annotations

import os
import time

#: Fallback when the process start cannot be read: when feltool was first imported.
_IMPORTED = time.time()


def process_started() -> float:
    """The time this process started, in [s] since the epoch (Linux: the kernel's record,
    ``/proc/self/stat``; elsewhere when feltool was first imported)."""
    try:
        with open("/proc/self/stat") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
        with open("/proc/uptime") as fh:
            uptime = float(fh.read().split()[0])
        ticks = os.sysconf("SC_CLK_TCK")
        age = uptime - int(fields[19]) / ticks  # field 22 of stat: start time after boot
        if 0.0 <= age < 1e7:
            return time.time() - age
    except (OSError, ValueError, IndexError):
        pass
    return _IMPORTED


__all__ = ["process_started"]
