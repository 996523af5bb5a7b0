"""The ``sim:`` section: control rate, integrator, cycles, limits."""

from __future__ import annotations

from typing import Literal

from pydantic import (
    Field,
)

from feltool.bounds import (
    MAX_CYCLES,
    MAX_RATE_HZ,
)
from feltool.config.base import PositiveFloat, Strict


class SimConfig(Strict):
    """How the closed loop is simulated."""

    rate_hz: PositiveFloat = Field(100.0, le=MAX_RATE_HZ, description="Control and sampling "
                                   "rate in [Hz]; one feedforward/feedback sample per step; at "
                                   f"most {MAX_RATE_HZ:g}.")
    substeps: int = Field(1, ge=1, le=1000, description="Integration steps per control step "
                          "(the torque is held constant over them).")
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
