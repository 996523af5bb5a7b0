"""The ``joints:`` section: each joint's role (track, stabilize, passive, locked), target,
gains and what of its RMP is learned.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    Discriminator,
    Field,
    Tag,
    model_validator,
)

from feltool.bounds import (
    MAX_ANGLE,
    MAX_GAIN,
    MAX_WEIGHT_SCALE,
)
from feltool.config.base import Angle, NonNegFloat, PositiveFloat, Strict, Vector3
from feltool.config.demos import PositionsDemo, SamplesDemo, SineDemo, demo_kind
from feltool.config.primitives import PrimitiveOverride


class Gains(Strict):
    """PD gains of a joint's feedback law (eq. 2.7 or §3.1)."""

    kp: NonNegFloat = Field(le=MAX_GAIN, description="Proportional gain K_P in [N m/rad]; 0 to "
                            f"{MAX_GAIN:g}.")
    kd: NonNegFloat = Field(le=MAX_GAIN, description="Derivative gain K_D in [N m s/rad]; 0 to "
                            f"{MAX_GAIN:g}.")


class Target(Strict):
    """What a stabilizing controller holds (§3.1): a joint angle; a link's absolute angle given
    as the sum of the joint angles from the base to that link (planar chains); or the
    orientation of any frame about a world axis (its torque then acts through the frame
    Jacobian on every joint that moves the frame)."""

    value: Angle = Field(description="Target value of the stabilized quantity in [rad]; "
                         f"within +-{MAX_ANGLE:g}.")
    link_angle: list[str] | None = Field(None, min_length=1, description="Joints whose angles "
                                         "add up to the stabilized link's absolute angle, e.g. "
                                         "[shoulder, elbow] for q1 + q2; default the joint itself.")
    frame: str | None = Field(None, description="A URDF link/frame name: stabilize the angle of "
                              "its `vector` about the world axis `about`, measured from `zero`.")
    vector: Vector3 = Field([0.0, 0.0, 1.0], description="Direction in the frame's own "
                            "coordinates whose orientation is held (with `frame`).")
    about: Vector3 = Field([0.0, 1.0, 0.0], description="World axis the angle turns about, "
                           "counter-clockwise (with `frame`).")
    zero: Vector3 | None = Field(None, description="World direction where the angle is 0 "
                                 "(with `frame`); default +z, or +x when `about` is vertical.")

    @model_validator(mode="after")
    def _one_kind(self) -> Target:
        if self.frame is not None and self.link_angle is not None:
            raise ValueError("give either 'link_angle' or 'frame', not both")
        for name in ("vector", "about") + (("zero",) if self.zero is not None else ()):
            if sum(x * x for x in getattr(self, name)) < 1e-12:
                raise ValueError(f"'{name}' must not be the zero vector")
        return self


class LearnConfig(Strict):
    """Marks a joint's RMP as learned by FEL and says how its parameters start."""

    init: Literal["random", "demo", "zero", "perturbed"] = Field(
        "random", description="Initial weights: random (from the seed), the demo's fit, zero, "
        "or perturbed: the demo's fit plus a random perturbation from the seed whose forward "
        "trajectory has the RMS perturbation_rad (and the goal moved by goal_spread at most).")
    perturbation_rad: NonNegFloat = Field(0.05, le=MAX_ANGLE, description="init perturbed: RMS "
        "over the cycle of the perturbation of the forward trajectory, in [rad] (a smooth "
        "random motion: the cycle's first three harmonics with N(0, 1) coefficients from the "
        f"seed, scaled to it, fitted into the RMP); at most {MAX_ANGLE:g}.")
    weight_scale: NonNegFloat = Field(0.3, le=MAX_WEIGHT_SCALE, description="Random initial "
                                      "weights ~ N(0, s^2) with s = weight_scale * max |w| over "
                                      "the demo-fitted primitives [-]; at most "
                                      f"{MAX_WEIGHT_SCALE:g}.")
    goal_spread: NonNegFloat = Field(0.3, le=MAX_ANGLE, description="Random initial goal uniform "
                                     f"in goal_center +- goal_spread, in [rad]; at most {MAX_ANGLE:g}.")
    init_basis: int | None = Field(None, ge=1, le=1000, description="init random: the basis "
        "size the random weights are drawn on (and weight_scale's demo fit is made with); the "
        "start is that RMP's forward trajectory fitted into the joint's own basis, so that "
        "changing primitives.basis changes the basis only, not the task (the start's "
        "trajectory); default the joint's own basis size (a draw per basis function).")
    rate_scale: PositiveFloat = Field(1.0, le=1e6, description="Multiplies learning.rates for "
        "this joint's weights and goal [-] (e.g. a tracked leg learned more slowly than the "
        "torso it carries); at most 1e6.")
    goal_center: Angle | None = Field(None, description="Centre of the initial goal in [rad]; "
                                            "default: the value that meets the joint's target with "
                                            "the other joints at their goals (or the demo's mean).")


class JointConfig(Strict):
    """The role of one joint in the experiment."""

    role: Literal["track", "stabilize", "passive", "locked"] = Field(description="track: PD on "
        "the joint's RMP (eq. 2.7); stabilize: PD holding a target (§3.1); passive: unactuated; "
        "locked: removed from the model at `posture`.")
    link_angle: list[str] | None = Field(None, min_length=1, description="track only: the "
        "tracked quantity is this link's absolute angle, the sum of these joints' angles "
        "(reference: the same sum of the desired joint angles); default the joint's own angle.")
    demo: Annotated[Annotated[SineDemo, Tag("sine")] | Annotated[SamplesDemo, Tag("samples")]
                    | Annotated[PositionsDemo, Tag("positions")],
                    Discriminator(demo_kind)] | None = Field(
        None, description="Demonstration fitted into the RMP (eq. 2.4): kind sine, samples or "
        "positions.")
    gains: Gains | None = Field(None, description="Feedback gains (track and stabilize).")
    target: Target | None = Field(None, description="Stabilized quantity (stabilize only).")
    learn: LearnConfig | None = Field(None, description="Learn this joint's RMP by FEL.")
    primitive: PrimitiveOverride | None = Field(None, description="Per-joint RMP settings.")
    posture: Angle = Field(0.0, description="Angle a locked joint is held at, in [rad]; within "
                           f"+-{MAX_ANGLE:g}.")
    follow_demo: bool = Field(False, description="The forward trajectory is the demonstration "
        "itself at the control rate, not its RMP fit (e.g. a designed gait's joints: an impact's "
        "velocity jump is beyond a smooth periodic RMP). With learn (a physical walker's track "
        "joint): the feedback's reference (and the mechanical phase) follows the demonstration, "
        "the feedforward the learned RMP, so that FEL learns the feedforward of the designed "
        "motion from a perturbed start.")

    @model_validator(mode="after")
    def _role_fields(self) -> JointConfig:
        problems = []
        if self.role in ("track", "stabilize") and self.gains is None:
            problems.append(f"a '{self.role}' joint needs 'gains'")
        if self.role == "stabilize" and self.target is None:
            problems.append("a 'stabilize' joint needs 'target'")
        if self.role != "track" and self.link_angle is not None:
            problems.append(f"'link_angle' is only for 'track' joints, not '{self.role}'")
        if self.role != "stabilize" and self.target is not None:
            problems.append(f"'target' is only for 'stabilize' joints, not '{self.role}'")
        if self.role in ("track", "stabilize", "passive") and self.demo is None and (
                self.learn is None or self.learn.init == "demo"):
            problems.append(f"a '{self.role}' joint needs a 'demo' or 'learn' (with init random "
                            "or zero) to define its RMP")
        if self.follow_demo and self.demo is None:
            problems.append("'follow_demo' needs a 'demo'")
        if self.follow_demo and self.learn is not None and self.role != "track":
            problems.append("'follow_demo' with 'learn' needs role 'track'")
        if self.role == "locked" and (self.learn or self.demo or self.gains):
            problems.append("a 'locked' joint takes only 'posture'")
        if problems:
            raise ValueError("; ".join(problems))
        return self
