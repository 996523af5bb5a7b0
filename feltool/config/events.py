"""The ``events:`` section: changes of the motion (period, amplitude, goal) or of the world
(payload, mass, slope) at a given cycle.
"""

from __future__ import annotations

from typing import Literal

from pydantic import (
    Field,
    model_validator,
)

from feltool.bounds import (
    MAX_CYCLES,
    MAX_MASS,
    MAX_MASS_SCALE,
    MAX_PERIOD_S,
)
from feltool.config.base import Angle, Length, NonNegFloat, PositiveFloat, Strict


class EventConfig(Strict):
    """A change at the start of a learning cycle: of the world (``kind``: the simulated plant
    changes, the known model stays as it was, so FEL has to adapt), or of the motion (no
    ``kind``; period_s, amplitude and goal, alone or together), applied without a jump in the
    desired positions and velocities while FEL goes on learning."""

    cycle: int = Field(ge=1, le=MAX_CYCLES, description="Learning cycle at whose start the "
                       "change happens.")
    kind: Literal["slope", "payload", "mass"] | None = Field(None, description="A change of "
        "the world: slope: tilt gravity (the ground) by `angle` about the world's y axis; "
        "payload: add a point mass `mass` at `frame`; mass: set the mass of the body moved by "
        "the joint of `link` to `mass` (its inertia scaled alike). None: a change of the motion.")
    angle: Angle | None = Field(None, description="Slope angle in [rad] (kind slope); "
                                      "positive tilts gravity towards +x (downhill ahead).")
    mass: NonNegFloat | None = Field(None, le=MAX_MASS, description="Mass in [kg] (payload, "
                                     f"mass); at most {MAX_MASS:g}.")
    frame: str | None = Field(None, description="URDF link/frame carrying the payload.")
    com: list[Length] | None = Field(None, min_length=3, max_length=3, description="Payload: "
        "where its point mass sits in `frame`, [x, y, z] in [m]; default the frame's origin.")
    link: str | None = Field(None, description="URDF link whose mass is set (kind mass); "
                             "with `scale` and no link: every body.")
    scale: PositiveFloat | None = Field(None, le=MAX_MASS_SCALE, description="Kind mass: "
        "instead of `mass`, multiply the body's (no `link`: every body's) mass and rotational "
        "inertia by this factor [-] (the centres of mass stay).")
    period_s: PositiveFloat | None = Field(None, le=MAX_PERIOD_S, description="The motion's "
        "new period in [s]: the phase's frequency moves to 2 pi / period_s smoothly (C1 in "
        "time), so q_d and its velocity stay continuous; the RMPs, functions of the phase, "
        "keep their learned shape (phase: clock).")
    transition_cycles: PositiveFloat = Field(1.0, le=1000, description="With period_s: the "
        "revolutions of the phase the change of speed takes [-].")
    amplitude: dict[str, PositiveFloat] | None = Field(None, description="Per joint: its RMP's "
        "amplitude factor r (eq. 2.2) from now on [-]. The forcing term is r psi^T w, so the "
        "weights are scaled by r_new / r_old; the RMP's state carries on from where it was and "
        "settles on the new limit cycle (no jump in q_d, qdot_d).")
    goal: dict[str, Angle] | None = Field(None, description="Per joint: its RMP's goal g (the "
        "motion's centre) from now on, in [rad] (a learned goal is set and learned on from "
        "there); the state carries on as with amplitude.")

    @model_validator(mode="after")
    def _fields(self) -> EventConfig:
        motion = [f for f in ("period_s", "amplitude", "goal") if getattr(self, f) is not None]
        if self.kind is None:
            if not motion:
                raise ValueError("an event changes the world (kind: slope, payload or mass) or "
                                 "the motion (period_s, amplitude, goal); give one")
            return self
        if self.com is not None and self.kind != "payload":
            raise ValueError("'com' is the position of a payload; give it with kind payload")
        if motion:
            raise ValueError(f"'{', '.join(motion)}' change the motion; give them in an event "
                             f"of their own, without kind '{self.kind}'")
        need = {"slope": ["angle"], "payload": ["mass", "frame"], "mass": ["mass", "link"]}
        if self.scale is not None:
            if self.kind != "mass" or self.mass is not None:
                raise ValueError("'scale' is a kind mass event's factor, instead of 'mass'")
            need["mass"] = []
        missing = [f for f in need[self.kind] if getattr(self, f) is None]
        if missing:
            raise ValueError(f"a '{self.kind}' event needs " + ", ".join(missing))
        return self

    @property
    def changes_world(self) -> bool:
        """Whether the event changes the simulated plant (else the motion)."""
        return self.kind is not None
