"""The ``walking:`` and ``actuation:`` sections: a walker's feet, guard, impact, phase and
checks; motors that drive combinations of joints.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    model_validator,
)

from feltool.config.base import FiniteFloat, NonNegFloat, PositiveFloat, Strict


class Guard(Strict):
    """The event that ends a step: a link's absolute angle crossing a value (eq. of the guard
    surface :math:`a^\\top q = \\text{value}`), armed over a window of the nominal step."""

    link_angle: list[str] = Field(min_length=1, description="Joints whose angles add up to the "
                                  "guarded link's absolute angle, e.g. [stance_ankle, swing_hip] "
                                  "for the swing leg's angle from the vertical.")
    value: FiniteFloat = Field(description="The step ends when the angle crosses this, in [rad].")
    direction: Literal["rising", "falling"] = Field("rising", description="Crossing direction.")
    window: tuple[Annotated[float, Field(ge=0, le=1)], Annotated[float, Field(gt=0, le=1)]] = \
        Field((0.75, 1.0), description="Fractions of the nominal step (period / steps_per_cycle) "
              "between which the guard is armed; at the window's end the step ends by the clock "
              "(counted as clock_impacts in summary.json) [-].")

    @model_validator(mode="after")
    def _ordered(self) -> Guard:
        start, end = self.window
        if start > end:
            raise ValueError(f"window: the guard is armed from {start} to {end} of the step; "
                             "the start must not come after the end")
        return self


class FallCheck(Strict):
    """When a walker has fallen: a link's absolute angle beyond a limit."""

    link_angle: list[str] = Field(min_length=1, description="Joints whose angles add up to the "
                                  "checked link's absolute angle (e.g. [stance_ankle]).")
    max_abs: PositiveFloat = Field(description="The seed stops as diverged ('the robot fell') "
                                   "when |angle| exceeds this, in [rad].")


class FootPlacement(Strict):
    """Step-to-step foot placement: the reference of one link angle (e.g. the swing leg's) is
    offset by ``gain`` times another link's tracking error (e.g. the passive stance leg's
    actual minus desired angle), blended in over each step by a smoothstep 3 s^2 - 2 s^3 of the
    step's elapsed fraction s (zero at take-off, complete at the nominal landing). A stance leg
    ahead of its schedule (a fast step) then lands the swing foot further ahead, one behind it
    shorter; with gain -1 the landing is symmetric (swing angle = -stance angle at the impact),
    whatever the stance leg did."""

    angle_of: str = Field(description="Key of walking.absolute whose link angle (stance-relative "
                          "labels) is offset, e.g. swing_hip for the swing leg.")
    follow: str = Field(description="Key of walking.absolute whose link angle's tracking error "
                        "(actual - desired, and its velocity) drives the offset, e.g. "
                        "stance_ankle.")
    gain: FiniteFloat = Field(description="Offset per unit error [-]; negative moves the swing "
                              "foot ahead (against the stance leg's angle) when the stance leg "
                              "is ahead of schedule.")


class FootConfig(Strict):
    """A foot's contact point: a URDF frame, or a link and an offset in that link's frame."""

    frame: str | None = Field(None, description="URDF frame (link) at the contact point.")
    link: str | None = Field(None, description="URDF link carrying the contact point.")
    offset: tuple[FiniteFloat, FiniteFloat, FiniteFloat] = Field((0.0, 0.0, 0.0), description=
        "Contact point in the link's frame, in [m] (with link).")

    @model_validator(mode="after")
    def _one(self) -> FootConfig:
        if (self.frame is None) == (self.link is None):
            raise ValueError("give exactly one of 'frame' or 'link' (with 'offset')")
        return self


class WalkingConfig(Strict):
    """Walking, in one of two forms (docs/biped.md).

    **Physical walker** (``feet`` given): the robot on a sagittal floating base (x, z, pitch) with
    point feet; the stance foot is a contact constraint, a step ends when the swing foot reaches
    the ground moving down (located inside the control step), the touchdown is a rigid impact
    (``pin.impulseDynamics``) followed by the left/right relabelling of ``legs``, and the contact
    physics is checked all along: a seed that leaves it is *not walking* and stops like a fall.

    **Pinned walker** (the thesis's reference; ``absolute``, ``swap``, ``guard``): the stance foot
    pinned to the world, steps ending on a guard, stance/swing relabelling. Coordinates:
    ``absolute`` gives each joint's link angle from the vertical in stance-relative labels
    (theta = A q); after every impact the ``swap`` pair is exchanged (X+ = [q2, q1, q3, ...])."""

    # -- physical walker ---------------------------------------------------------------------
    base: Literal["planar"] | list[str] = Field("planar", description="Physical walker: planar "
        "= feltool adds the joints base_x, base_z (prismatic, [m]) and base_pitch (about y, "
        "[rad]) above the URDF's root link; or the names of the URDF's own three base joints "
        "(x translation, z translation, pitch), in that order.")
    feet: dict[Literal["left", "right"], FootConfig] | None = Field(None, description=""
        "Physical walker: the point contacts of the left and right foot (both), each at the end "
        "of its leg's chain.")
    legs: list[tuple[str, str]] | None = Field(None, min_length=1, description="Physical "
        "walker: pairs [left joint, right joint] exchanged at every touchdown (relabelling), "
        "e.g. [[left_hip, right_hip], [left_knee, right_knee]].")
    stance: Literal["left", "right"] = Field("left", description="Physical walker: the stance "
        "foot of every step in stance-relative labels (after each touchdown the relabelling "
        "gives the new stance leg this name), so each joint's RMP describes one step.")
    friction: PositiveFloat = Field(0.7, description="Physical walker: Coulomb coefficient mu "
        "[-]; the stance force must keep |F_x|/F_z <= mu and the touchdown impulse |I_x|/I_z <= "
        "mu.")
    normal_force_min: NonNegFloat = Field(0.0, description="Physical walker: the stance foot's "
        "normal force must stay above this, in [N] (and above 0).")
    scuff_exempt_m: NonNegFloat | None = Field(None, description="Physical walker: the swing "
        "foot may be below the ground within this horizontal distance of the stance foot, in "
        "[m]; default 0.05 for a walker without knees (one legs pair), 0 with knees.")
    scuff_behind: bool | None = Field(None, description="Physical walker: the classic "
        "compass-gait convention: the swing foot's scuffing is ignored while it is behind the "
        "stance foot (a knee-less leg cannot clear the ground there; the control steps with it "
        "below the ground are counted "
        "and reported, not a stop); default true for a walker without knees (one legs pair), "
        "false with knees.")
    clearance_tol_m: NonNegFloat = Field(0.001, description="Physical walker: how far the "
        "swing foot may graze below the ground outside the scuffing zone (e.g. the trailing "
        "foot just after lift-off) before the seed is not walking, in [m]; 0 = strict.")
    phase: Literal["clock", "touchdown", "mechanical"] = Field("clock", description="Physical "
        "walker: the RMPs run on time (clock); their phase restarts at every touchdown "
        "(touchdown: a cycle lasts steps_per_cycle steps, a step longer than the nominal one "
        "holds the last sample); or, restarting at touchdown too, the phase within a step "
        "follows the centre of mass's horizontal position over the stance foot through its "
        "desired values (mechanical, as in hybrid zero dynamics; the desired velocities scaled "
        "by the phase's rate; the desired centre of mass must move forward all through the "
        "step). A physical walker that gives neither this nor primitives.phase is mechanical "
        "(the clock phase drifts off a designed gait).")
    # -- pinned walker -----------------------------------------------------------------------
    absolute: dict[str, list[str]] | None = Field(None, min_length=1, description="Pinned "
        "walker: for every joint, the joints whose angles add up to its link's absolute angle "
        "(stance-relative labels).")
    swap: tuple[str, str] | None = Field(None, description="Pinned walker: the two joints whose "
        "absolute angles (and velocities) are exchanged at an impact: stance and swing leg.")
    impact: Literal["relabel", "rigid"] = Field("relabel", description="Pinned walker: relabel "
        "= the thesis's switch of labels, velocities kept; rigid = a perfectly inelastic foot "
        "impact, then relabelling. A physical walker's impact is always rigid "
        "(pin.impulseDynamics at the landing foot).")
    contact_frame: str | None = Field(None, description="Pinned walker: frame of the swing foot "
                                      "(URDF link), needed by impact: rigid.")
    steps_per_cycle: int = Field(2, ge=1, le=100, description="Steps (impacts) per cycle; "
        "default 2 for a pinned walker, 1 for a physical one (period_s is then one step).")
    guard: Guard | None = Field(None, description="Pinned walker: when a step ends.")
    fall: FallCheck | None = Field(None, description="When the walker has fallen.")
    foot_placement: FootPlacement | None = Field(None, description="Pinned walker: offset a "
        "link's reference by another link's tracking error over each step (step-to-step "
        "stabilisation, used with impact: rigid); default off.")
    poincare: bool = Field(True, description="After learning, find the step-to-step map's fixed "
                           "point and its eigenvalues (summary.json: poincare).")
    settle_cycles: int = Field(0, ge=0, le=1000, description="Physical walkers: cycles walked "
        "with the unperturbed parameters (the design, nothing learned, not counted) before "
        "learning starts, so that learning starts on the loop's own limit cycle rather than "
        "with the transient from the designed start state.")

    @model_validator(mode="before")
    @classmethod
    def _default_steps(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("feet") is not None:
            data = {"steps_per_cycle": 1, "impact": "rigid", **data}
        return data

    @model_validator(mode="after")
    def _form(self) -> WalkingConfig:
        if self.physical:
            extra = [f for f in ("absolute", "swap", "guard", "contact_frame", "foot_placement")
                     if getattr(self, f) is not None]
            problems = [f"'{', '.join(extra)}' belong to the pinned walker, not to one with "
                        "'feet' (the physical walker)"] if extra else []
            if set(self.feet) != {"left", "right"}:
                problems.append("'feet' needs both 'left' and 'right'")
            if self.legs is None:
                problems.append("a physical walker needs 'legs' (the left/right joint pairs)")
            if self.impact == "relabel":
                problems.append("a physical walker's touchdown is a rigid impact; 'impact: "
                                "relabel' is only for the pinned walker")
            if problems:
                raise ValueError("; ".join(problems))
        else:
            missing = [f for f in ("absolute", "swap", "guard") if getattr(self, f) is None]
            if missing:
                raise ValueError("a pinned walker needs " + ", ".join(missing) + " (or give "
                                 "'feet' and 'legs' for a physical walker)")
            extra = [f for f in ("legs",) if getattr(self, f) is not None]
            if extra:
                raise ValueError("'legs' is for a physical walker (with 'feet')")
        return self

    @property
    def physical(self) -> bool:
        """Whether this is a physical walker (point feet on a floating base)."""
        return self.feet is not None

    @property
    def scuff_exempt(self) -> float:
        """The scuffing zone in [m] (0.05 for one legs pair, 0 with knees, unless given)."""
        if self.scuff_exempt_m is not None:
            return self.scuff_exempt_m
        return 0.05 if self.legs is not None and len(self.legs) == 1 else 0.0

    @property
    def scuffs_behind(self) -> bool:
        """Whether scuffing behind the stance foot is ignored (default: knee-less walkers)."""
        if self.scuff_behind is not None:
            return self.scuff_behind
        return self.legs is not None and len(self.legs) == 1


class ActuationConfig(Strict):
    """Motors and how the joint torques are allocated to them (underactuated robots).

    Each motor acts on an angle that is a linear combination of joint angles, y_m = b_m^T q, so it
    applies the generalized force b_m u_m; B = [b_1 ... b_k]. The joint-space torque
    tau = u_ff + u_fb is mapped onto the motors by ``inertia_weighted``:
    u = (B^T M^-1 B)^-1 B^T M^-1 tau (the accelerations closest to those tau would produce), or
    ``pseudo_inverse``: u = B^+ tau. The robot receives B u."""

    motors: dict[str, dict[str, FiniteFloat]] = Field(min_length=1, description="Per motor: "
        "{joint: coefficient} of the angle it drives, e.g. {torso_hip: 1, swing_hip: -1} for a "
        "motor between the torso and the swing leg.")
    allocation: Literal["inertia_weighted", "pseudo_inverse"] = Field(
        "inertia_weighted", description="Allocation of joint torques onto the motors.")
