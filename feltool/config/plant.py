"""The ``plant:`` section: the simulated robot where it differs from the known model
(payloads, per-link overrides, joint friction).
"""

from __future__ import annotations

from typing import Literal

from pydantic import (
    Field,
    field_validator,
    model_validator,
)

from feltool.bounds import (
    MAX_GAIN,
    MAX_LENGTH_SCALE,
    MAX_MASS,
    MAX_MASS_SCALE,
)
from feltool.config.base import FiniteFloat, Length, NonNegFloat, PositiveFloat, Strict
from feltool.robot.physical import inertia_problem


class BodyOverride(Strict):
    """The plant's physical parameters of one body: the rigid body moved by a joint (with every
    link welded to it). Unset fields keep the model's values."""

    mass_scale: PositiveFloat | None = Field(None, le=MAX_MASS_SCALE, description="Scale mass and rotational "
        "inertia together (a uniformly denser body; the centre of mass stays) [-].")
    mass: PositiveFloat | None = Field(None, le=MAX_MASS, description="Mass in [kg] (rotational inertia "
                                       "unchanged unless `inertia` is given).")
    com: list[Length] | None = Field(None, min_length=3, max_length=3, description="Centre "
                                          "of mass in the joint's frame, [x, y, z] in [m].")
    inertia: list[FiniteFloat] | None = Field(None, min_length=6, max_length=6, description=""
        "Rotational inertia about the centre of mass, [ixx, ixy, ixz, iyy, iyz, izz] in "
        "[kg m^2] (URDF order); positive semi-definite, principal moments satisfying the "
        "triangle inequality (docs/robots.md).")
    length_scale: PositiveFloat | None = Field(None, le=MAX_LENGTH_SCALE, description="Scale "
        "the body's length by this factor about its joint's origin [-]: the placements of the "
        "joints it carries (its children) and of its frames (e.g. a foot at its end) and its "
        "centre of mass scale by it, its rotational inertia about the centre of mass by its "
        "square (the same mass along a longer body); its mass stays. Applied first: `mass`, "
        "`mass_scale`, `com` and `inertia` act on the lengthened body.")

    @model_validator(mode="after")
    def _one_mass(self) -> BodyOverride:
        if self.mass_scale is not None and self.mass is not None:
            raise ValueError("give 'mass_scale' or 'mass', not both")
        return self

    @field_validator("inertia")
    @classmethod
    def _physical(cls, inertia):
        return _physical_inertia(inertia)


def _physical_inertia(inertia: list[float] | None) -> list[float] | None:
    problem = None if inertia is None else inertia_problem(inertia)
    if problem:
        raise ValueError(problem)
    return inertia


class Payload(Strict):
    """A rigid payload fixed to a frame of the plant (e.g. a tool at the arm's tip)."""

    frame: str = Field(min_length=1, description="URDF link (or Pinocchio frame) it is fixed to.")
    mass: PositiveFloat = Field(le=MAX_MASS, description=f"Mass in [kg]; at most {MAX_MASS:g}.")
    com: list[Length] = Field([0.0, 0.0, 0.0], min_length=3, max_length=3,
                                   description="Centre of mass in that frame, [x, y, z] in [m].")
    inertia: list[FiniteFloat] = Field([0.0] * 6, min_length=6, max_length=6, description=""
        "Rotational inertia about its centre of mass, [ixx, ixy, ixz, iyy, iyz, izz] in "
        "[kg m^2]; default a point mass.")

    @field_validator("inertia")
    @classmethod
    def _physical(cls, inertia):
        return _physical_inertia(inertia)


class JointFriction(Strict):
    """Joint friction of the plant, tau_f = viscous * v + coulomb * tanh(v / coulomb_velocity),
    opposing the motion (the known model has none)."""

    viscous: NonNegFloat = Field(0.0, le=MAX_GAIN, description="Viscous damping in [N m s/rad]; "
                                 f"at most {MAX_GAIN:g}.")
    coulomb: NonNegFloat = Field(0.0, le=MAX_GAIN, description="Coulomb friction level in [N m]; "
                                 f"at most {MAX_GAIN:g}.")
    coulomb_velocity: PositiveFloat = Field(0.01, description="Velocity scale of the smooth "
                                            "Coulomb term in [rad/s].")


class PlantConfig(Strict):
    """The simulated robot when it differs from the known model (which gives the feedforward):
    a second URDF and/or overrides of the model's physics. Without `plant`, plant = model."""

    robot: str | None = Field(None, description="A different robot for the plant (bundled name, "
        "URDF path relative to the config, or example-robot-data:NAME) with the same joints; "
        "default the model's robot.")
    bodies: dict[str, BodyOverride] = Field(default_factory=dict, description="Overrides per "
        "body, by the name of the joint that moves it.")
    payloads: list[Payload] = Field(default_factory=list, description="Payloads fixed to frames.")
    friction: dict[str, JointFriction] = Field(default_factory=dict, description="Friction per "
                                               "joint, by joint name.")
    motor_gain: dict[str, PositiveFloat] = Field(default_factory=dict, description="Motor gain "
        "error per actuated joint, by joint name: the plant's motor applies this factor times "
        "the commanded torque [-] (default 1: exact motors).")
    simulator: Literal["pinocchio", "mujoco"] = Field("pinocchio", description="What simulates "
        "the plant: `pinocchio` (the rigid model, changed by this block) or `mujoco` (the same "
        "URDF compiled by MuJoCo with its soft contacts, the `mujoco` package: pip install "
        "'feltool[mujoco]'; the Python engine; docs/biped.md, \"MuJoCo as the plant\").")
    mujoco_integrator: Literal["euler", "rk4"] = Field("euler", description="simulator: mujoco: "
        "MuJoCo's integrator, `euler` (semi-implicit Euler, as feltool's own plant) or `rk4` "
        "(MuJoCo's fourth-order Runge-Kutta: its contacts are evaluated inside the step).")
    contact_timeconst: PositiveFloat | None = Field(None, le=1.0, description="simulator: "
        "mujoco: the floor's and feet's `solref` time constant in [s] (stiffer when smaller; "
        "at least two MuJoCo timesteps, 1 / (sim.rate_hz sim.substeps)); default max(2 ms, "
        "two timesteps).")
    impact_sample: Literal["end", "touchdown"] = Field("end", description="simulator: mujoco, "
        "physical walkers: when the controller takes its first sample after a touchdown: "
        "`end` (MuJoCo's soft impact has stopped the landing foot, at most 10 ms; the last "
        "torque held meanwhile: the post-impact state, as the rigid walker's instantaneous "
        "impact gives it) or `touchdown` (at the foot's arrival, mid-impact).")

    @model_validator(mode="after")
    def _mujoco_alone(self) -> PlantConfig:
        if self.simulator == "mujoco":
            given = [k for k in ("robot", "bodies", "payloads", "friction", "motor_gain")
                     if getattr(self, k)]
            if given:
                raise ValueError(f"simulator: mujoco simulates the model's URDF as it is; "
                                 f"remove {', '.join(given)}")
        else:
            given = [k for k, default in (("mujoco_integrator", "euler"),
                                          ("contact_timeconst", None), ("impact_sample", "end"))
                     if getattr(self, k) != default]
            if given:
                raise ValueError(f"{', '.join(given)}: MuJoCo's settings, for simulator: mujoco")
        return self
