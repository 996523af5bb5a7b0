"""The ``primitives:`` section and a joint's ``primitive:`` override: the RMPs' settings and
the phase they share (clock or adaptive oscillator).
"""

from __future__ import annotations

from typing import Literal

from pydantic import (
    Field,
    model_validator,
)

from feltool.bounds import (
    MAX_ALPHA,
    MAX_AMPLITUDE,
    MAX_HARMONICS,
    MAX_WIDTH,
)
from feltool.config.base import FiniteFloat, PositiveFloat, Strict


class ExternalSignal(Strict):
    """A periodic input from outside the robot: y(t) = mean + amplitude sin(2 pi f t + phase) +
    sum_k A_k sin(2 pi k f t + phi_k), k = 2, 3, ..., t from the start of the run."""

    frequency_hz: PositiveFloat = Field(description="Its frequency f in [Hz].")
    amplitude: FiniteFloat = Field(1.0, description="Amplitude [input unit].")
    mean: FiniteFloat = Field(0.0, description="Mean [input unit].")
    phase: FiniteFloat = Field(0.0, description="Phase at t = 0 [rad].")
    harmonics: list[tuple[FiniteFloat, FiniteFloat]] = Field(default_factory=list,
        max_length=MAX_HARMONICS, description="Higher harmonics k = 2, 3, ...: [amplitude, "
        f"phase in [rad]] each; at most {MAX_HARMONICS}.")


class OscillatorInput(Strict):
    """The periodic signal the adaptive oscillator entrains to: exactly one of these."""

    joint: str | None = Field(None, description="A configured joint's measured angle [rad] "
                              "(or position [m]).")
    frame: str | None = Field(None, description="A URDF link/frame's measured height (world "
                              "z) [m].")
    external: ExternalSignal | None = Field(None, description="A signal from outside the "
                                            "robot.")

    @model_validator(mode="after")
    def _one(self) -> OscillatorInput:
        given = [k for k in ("joint", "frame", "external") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of joint, frame or external"
                             + (f" (got {', '.join(given)})" if given else ""))
        return self


class OscillatorConfig(Strict):
    """An adaptive-frequency oscillator (Righetti, Buchli & Ijspeert 2006) coupled through the
    error of an adaptive Fourier series of its input (Gams et al. 2009): phi' = Omega - K e sin
    phi, Omega' = -K e sin phi, e = y - sum_c (a_c cos c phi + b_c sin c phi), a_c' = eta e cos
    c phi, b_c' = eta e sin c phi (docs/theory.md)."""

    input: OscillatorInput = Field(description="The signal y it entrains to.")
    coupling: PositiveFloat = Field(10.0, le=1.0e4, description="Coupling K in [1/(s input "
        "unit)]: larger locks faster; K times the input's amplitude of about 10 locks a sine "
        "within 10 periods (docs/theory.md).")
    learning_rate: PositiveFloat = Field(2.0, le=1.0e4, description="Learning rate eta of the "
        "Fourier series in [1/s]; about K / 5 (much larger makes it learn the input before the "
        "frequency has locked).")
    harmonics: int = Field(10, ge=0, le=100, description="Highest harmonic H of the series "
                           "(0 to 100).")


class PrimitiveConfig(Strict):
    """Parameters of a rhythmic movement primitive (eq. 2.1-2.3)."""

    basis: int = Field(10, ge=1, le=1000, description="Number of von Mises basis functions N; "
                       "1 to 1000 (and at most the samples per cycle).")
    alpha_z: PositiveFloat = Field(25.0, le=MAX_ALPHA, description="Timing constant alpha_z of "
                                   f"eq. 2.2 [-]; at most {MAX_ALPHA:g}.")
    beta_z: PositiveFloat | None = Field(None, le=MAX_ALPHA, description="Timing constant beta_z "
                                         "[-]; default alpha_z / 4 (critically damped); at most "
                                         f"{MAX_ALPHA:g}.")
    width: PositiveFloat | None = Field(None, le=MAX_WIDTH, description="Width h of the von "
                                        "Mises basis [-]; default N / 2, smaller where N / 2 would "
                                        "alias the first harmonic by more than 1 % (N = 5: 1.29, "
                                        f"N = 6: 2.31); at most {MAX_WIDTH:g}.")
    amplitude: PositiveFloat = Field(1.0, le=MAX_AMPLITUDE, description="Amplitude factor r of "
                                     f"the forcing term [-]; at most {MAX_AMPLITUDE:g}.")
    phase: Literal["clock", "mechanical", "adaptive"] = Field("clock", description="The phase "
        "every RMP shares (one learning cycle is one revolution of it, however many steps that "
        "takes): clock = integrated at 2 pi / period_s (changed smoothly by period_s events); "
        "mechanical = a physical walker's phase, following its centre of mass over the stance "
        "foot (the same setting as walking.phase: mechanical; either one sets both); adaptive "
        "= an adaptive-frequency oscillator entrained to the signal of `oscillator`, starting "
        "at 2 pi / period_s (docs/theory.md).")
    oscillator: OscillatorConfig | None = Field(None, description="phase: adaptive: the "
        "adaptive-frequency oscillator and the signal it follows.")

    @model_validator(mode="after")
    def _oscillator(self) -> PrimitiveConfig:
        if self.phase == "adaptive" and self.oscillator is None:
            raise ValueError("phase: adaptive needs an 'oscillator' block (its input signal)")
        if self.phase != "adaptive" and self.oscillator is not None:
            raise ValueError("'oscillator' is only for phase: adaptive")
        return self


class PrimitiveOverride(Strict):
    """Per-joint override of the primitive defaults; unset fields keep the defaults."""

    basis: int | None = Field(None, ge=1, le=1000, description="Number of basis functions N; "
                              "1 to 1000.")
    alpha_z: PositiveFloat | None = Field(None, le=MAX_ALPHA, description="Timing constant "
                                          f"alpha_z [-]; at most {MAX_ALPHA:g}.")
    beta_z: PositiveFloat | None = Field(None, le=MAX_ALPHA, description="Timing constant "
                                         f"beta_z [-]; at most {MAX_ALPHA:g}.")
    width: PositiveFloat | None = Field(None, le=MAX_WIDTH, description="Basis width h [-]; at "
                                        f"most {MAX_WIDTH:g}.")
    amplitude: PositiveFloat | None = Field(None, le=MAX_AMPLITUDE, description="Amplitude "
                                            f"factor r [-]; at most {MAX_AMPLITUDE:g}.")
