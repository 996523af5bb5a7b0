"""A joint's ``demo:``: the demonstration its RMP is fitted to (eq. 2.4): a sine, samples of
q, v, a, or positions (inline or a CSV column).
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import (
    Field,
    model_validator,
)

from feltool.bounds import (
    MAX_ANGLE,
    MAX_HARMONICS,
)
from feltool.config.base import Angle, FiniteFloat, Strict


class SineDemo(Strict):
    """A demonstrated sine (optionally with higher harmonics), fitted into the joint's RMP by
    least squares (eq. 2.4): q(t) = mean + amplitude sin(w s + phase) + sum_k A_k sin(k w s + phi_k)
    with w = 2 pi / T, s = t - delay T and k = 2, 3, ... for the entries of ``harmonics``."""

    kind: Literal["sine"] = Field(description="Demonstration kind.")
    mean: Angle = Field(0.0, description=f"Mean (the RMP goal) in [rad]; within +-{MAX_ANGLE:g}.")
    amplitude: Angle = Field(description=f"Amplitude in [rad]; within +-{MAX_ANGLE:g}.")
    phase: FiniteFloat = Field(0.0, description="Phase offset in [rad] at the start of a cycle.")
    harmonics: list[tuple[Angle, FiniteFloat]] = Field(default_factory=list,
        max_length=MAX_HARMONICS, description="Higher harmonics k = 2, 3, ...: [amplitude in "
        f"[rad], phase in [rad]] each; at most {MAX_HARMONICS}.")
    delay: FiniteFloat = Field(0.0, description="Delay of the whole demonstration, as a "
                               "fraction of the period (e.g. 0.5 for a walker's other leg) [-].")


MAX_DEMO_SAMPLES = 100_000  # samples of a samples demo


class SamplesDemo(Strict):
    """A demonstration given by samples over one period (e.g. a designed gait's collocation knots,
    ``feltool gait``), fitted into the joint's RMP by least squares (eq. 2.4). The samples are
    equally spaced in time, the first at t = 0 and the last at t = T (a walker's one-step
    trajectory need not end where it starts); between them the trajectory is the cubic whose
    acceleration is linear in time (exact for the gait designer's collocation)."""

    kind: Literal["samples"] = Field(description="Demonstration kind.")
    q: list[Angle] = Field(min_length=3, max_length=MAX_DEMO_SAMPLES, description="Positions in "
                           f"[rad] (or [m]) at t = k T / (n - 1), k = 0..n-1; within "
                           f"+-{MAX_ANGLE:g}, at most {MAX_DEMO_SAMPLES} samples.")
    v: list[FiniteFloat] = Field(max_length=MAX_DEMO_SAMPLES, description="Velocities in "
                                 "[rad/s] at the same times.")
    a: list[FiniteFloat] = Field(max_length=MAX_DEMO_SAMPLES, description="Accelerations in "
                                 "[rad/s^2] at the same times.")

    @model_validator(mode="after")
    def _same_length(self) -> SamplesDemo:
        if not len(self.q) == len(self.v) == len(self.a):
            raise ValueError("q, v and a need one value per sample each")
        return self


class PositionsDemo(Strict):
    """A demonstration given by positions only, at any rate: equally spaced samples that span
    ``periods`` whole periods (the sample after the last would be the first again), from a
    list or a CSV column. It is resampled onto the phase by its Fourier series (the
    trigonometric interpolant, by the FFT), its velocities and accelerations come from spectral
    differentiation, and it is fitted over the whole phase (eq. 2.4). The fit error (RMS over
    the cycle of the RMP's limit cycle minus the demonstration) is reported by feltool check
    and in summary.json (demo_fit_rms_rad)."""

    kind: Literal["positions"] = Field(description="Demonstration kind.")
    q: list[Angle] | None = Field(None, min_length=3, max_length=MAX_DEMO_SAMPLES,
                                  description="Positions in [rad] (or [m]); within "
                                  f"+-{MAX_ANGLE:g}, at most {MAX_DEMO_SAMPLES} samples.")
    csv: str | None = Field(None, description="A CSV file with a header row (relative to the "
                            "config file), read instead of q.")
    column: str | None = Field(None, description="The CSV column (its header) to read.")
    periods: int = Field(1, ge=1, le=10_000, description="Whole periods the samples span.")

    @model_validator(mode="after")
    def _source(self) -> PositionsDemo:
        if (self.q is None) == (self.csv is None):
            raise ValueError("give either 'q' or 'csv' (with 'column')")
        if self.csv is not None and self.column is None:
            raise ValueError("'csv' needs 'column' (the header of the column to read)")
        problem = too_few_samples(len(self.q), self.periods) if self.q is not None else None
        if problem:
            raise ValueError(problem)
        return self


def too_few_samples(n: int, periods: int) -> str | None:
    """Why ``n`` position samples spanning ``periods`` periods cannot be a demo (too few to
    resolve one harmonic), or None."""
    if n <= 2 * periods:
        return (f"{n} samples cannot resolve one harmonic over {periods} period(s); give more "
                f"than {2 * periods}")
    return None


def demo_kind(value: Any) -> str:
    """Which demo model validates ``value``: its ``kind`` (sine when missing or unknown, so that
    the error names the sine demo's fields as before)."""
    kind = value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)
    return kind if kind in ("samples", "positions") else "sine"
