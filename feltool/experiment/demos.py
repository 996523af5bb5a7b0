"""Demonstrations as trajectories: a demo's position, velocity and acceleration over the
period, a positions demo's Fourier series and its CSV column.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from feltool.bounds import MAX_ANGLE
from feltool.config.demos import MAX_DEMO_SAMPLES, too_few_samples
from feltool.errors import ConfigError
from feltool.motion import spectral
from feltool.motion.rmp import samples_demo, sine_demo


def demo_trajectory(d, T: float, t: np.ndarray, series: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A demonstration's position [rad], velocity [rad/s] and acceleration [rad/s^2] at times
    ``t`` [s] of a period ``T`` [s]; a positions demo from its Fourier ``series``."""
    if d.kind == "samples":
        return samples_demo(d.q, d.v, d.a, T, t)
    if d.kind == "positions":
        w = 2.0 * np.pi / T
        rows = spectral.trig(w * np.asarray(t, dtype=float), spectral.degree(series))
        dc = spectral.differentiate(series)
        return rows @ series, w * (rows @ dc), w * w * (rows @ spectral.differentiate(dc))
    return sine_demo(d.mean, d.amplitude, T, d.phase, t, d.harmonics, d.delay)


def positions_series(d, source: Path | None, where: str, src: str | None) -> np.ndarray | None:
    """The Fourier series of a positions demo (None for the other kinds), from its list or its
    CSV column (read here, every problem named by its YAML path)."""
    if d.kind != "positions":
        return None
    q = d.q
    if q is None:
        path = Path(d.csv).expanduser()
        if not path.is_absolute() and source is not None:
            path = source.parent / path
        q = _csv_column(path, d.column, where, src)
        problem = too_few_samples(len(q), d.periods)
        if problem:
            raise ConfigError([(f"{where}.csv", problem)], src)
    return spectral.from_samples(np.asarray(q, dtype=float), d.periods)


def _csv_column(path: Path, column: str, where: str, src: str | None) -> list[float]:
    """The numbers of one column of a CSV file with a header row [rad]."""
    def fail(key: str, message: str):
        return ConfigError([(f"{where}.{key}", message)], src)

    try:
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            if column not in header:
                raise fail("column", f"{path} has no column '{column}' (its columns: "
                                     f"{', '.join(header) or 'none'})")
            j, values = header.index(column), []
            for line, row in enumerate(reader, start=2):
                if not any(c.strip() for c in row):
                    continue
                cell = row[j].strip() if j < len(row) else ""
                try:
                    x = float(cell)
                except ValueError:
                    raise fail("csv", f"{path} line {line}: '{cell}' in column '{column}' is "
                                      "not a number") from None
                if not abs(x) <= MAX_ANGLE:
                    raise fail("csv", f"{path} line {line}: {cell} is not within "
                                      f"+-{MAX_ANGLE:g}")
                values.append(x)
                if len(values) > MAX_DEMO_SAMPLES:
                    raise fail("csv", f"{path} has more than {MAX_DEMO_SAMPLES} samples")
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise fail("csv", f"cannot read {path}: {getattr(exc, 'strerror', None) or exc}") \
            from None
    return values
