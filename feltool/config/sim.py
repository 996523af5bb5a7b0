"""The ``sim:`` section: control rate, integrator, cycles, limits."""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import (
    Field,
    model_validator,
)

from feltool.bounds import (
    MAX_CYCLES,
    MAX_RATE_HZ,
)
from feltool.config.base import PositiveFloat, Strict

#: The most integration sub-steps of one control step.
MAX_SUBSTEPS = 1000


class SimConfig(Strict):
    """How the closed loop is simulated."""

    rate_hz: PositiveFloat = Field(100.0, le=MAX_RATE_HZ, description="Control and sampling "
                                   "rate in [Hz]; one feedforward/feedback sample per step; at "
                                   f"most {MAX_RATE_HZ:g}.")
    substeps: int = Field(1, ge=1, le=MAX_SUBSTEPS, description="Integration steps per control step "
                          "(the torque is held constant over them); with step_s: derived from it.")
    step_s: PositiveFloat | None = Field(None, le=1.0, description="The plant's integration "
        "step in [s]: each control step is integrated in ceil(1 / (rate_hz step_s)) equal "
        "sub-steps (sets substeps; give one of the two), so the simulated robot stays the same "
        "robot when rate_hz changes; null: substeps sub-steps per control step, an integration "
        "step that grows with the control step (the thesis's one step per sample).")
    feedforward: Literal["sample", "hold_mean"] = Field("sample", description="The torque the "
        "known model's feedforward holds over a control step: sample = RNEA at the step's "
        "start, t_k (the thesis); hold_mean = the mean of the continuous feedforward over the "
        "hold [t_k, t_k+1] by the trapezoid rule, (u_ff(t_k) + u_ff(t_k+1)) / 2, which removes "
        "the held torque's half-step lag: the error feedback that sampling leaves then falls "
        "with the square of the control step instead of with the step (docs/theory.md). Arms "
        "learning per cycle (not walkers, per-step or model learning, the adaptive phase).")
    integrator: Literal["semi_implicit_euler", "explicit_euler"] = Field(
        "semi_implicit_euler", description="Integration scheme of the forward model: "
        "semi-implicit (symplectic) Euler, v += dt a; q += dt v, or explicit Euler.")
    cycles: int = Field(200, ge=1, le=MAX_CYCLES, description="Learning cycles to run; one "
                        f"cycle is one period of the rhythmic motion; 1 to {MAX_CYCLES}.")
    max_error_rad: PositiveFloat = Field(1.5, description="A seed is stopped as diverged (a "
                                         "fall) when a controlled quantity is further than this "
                                         "from its reference, in [rad].")
    max_velocity: PositiveFloat = Field(1000.0, description="A seed is stopped as diverged when a "
                                        "joint velocity exceeds this, in [rad/s].")
    joint_limits: Literal["report", "enforce", "ignore"] = Field("report", description="URDF "
        "position limits: report the steps beyond them (summary.json and terminal), enforce them "
        "(hold the joint at the limit) as well, or ignore them. lower = upper in the URDF means "
        "no limit.")
    torque_limits: Literal["report", "saturate", "ignore"] = Field("report", description="URDF "
        "effort limits: report the steps the commanded torque exceeds them, saturate the applied "
        "torque as well, or ignore them. An effort of 0 in the URDF means no limit.")

    @model_validator(mode="before")
    @classmethod
    def _substeps_from_step(cls, raw: Any) -> Any:
        """``step_s`` sets ``substeps``: the fewest equal sub-steps of the control step that
        are at most ``step_s`` long."""
        if not isinstance(raw, dict) or raw.get("step_s") is None:
            return raw
        if "substeps" in raw:
            raise ValueError("sim.substeps and sim.step_s both set: give one (step_s sets "
                             "the sub-steps of each control step)")
        try:  # as the fields will read them (a string "1e-3" too); a bad one is theirs to name
            rate, step = float(raw.get("rate_hz", 100.0)), float(raw["step_s"])
        except (TypeError, ValueError):
            return raw
        if not (0 < rate < math.inf and 0 < step < math.inf):
            return raw
        substeps = max(1, math.ceil(1.0 / (rate * step) - 1e-9))
        if substeps > MAX_SUBSTEPS:
            raise ValueError(f"sim.step_s {step:g} s at sim.rate_hz {rate:g} gives {substeps} "
                             f"sub-steps per control step; at most {MAX_SUBSTEPS} (a step of at "
                             f"least {1.0 / (rate * MAX_SUBSTEPS):g} s)")
        return {**raw, "substeps": substeps}
