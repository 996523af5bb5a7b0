"""The ``disturbances:`` section: measurement and torque noise, input delay, model error."""

from __future__ import annotations

from pydantic import (
    Field,
)

from feltool.config.base import NonNegFloat, PositiveFloat, Strict


class MeasurementNoise(Strict):
    """Gaussian noise on what the robot measures (the feedback and the learner see it; the
    simulated plant moves on its true state)."""

    q: NonNegFloat = Field(0.0, description="Standard deviation on the joint angles in [rad] "
                           "(a physical walker: its pitch and joints; the base's position follows "
                           "from the stance leg's kinematics).")
    v: NonNegFloat = Field(0.0, description="Standard deviation on the joint velocities in "
                           "[rad/s] (a physical walker: as for q).")


class ModelErrorConfig(Strict):
    """The plant's bodies scaled against the known model (which stays unchanged)."""

    mass_scale: PositiveFloat = Field(1.0, description="Every body's mass and rotational "
                                      "inertia times this [-].")
    length_scale: PositiveFloat = Field(1.0, description="Every joint placement and centre of "
        "mass times this, rotational inertias times its square (a uniformly stretched robot) "
        "[-].")


class DisturbanceConfig(Strict):
    """Disturbances of the plant only (feltool.plant.disturbances): the known model and the learner
    never see their source, only the noisy measurements they produce. Every draw comes from a
    numpy Generator seeded by (seed, cycle)."""

    measurement_noise: MeasurementNoise = Field(default_factory=MeasurementNoise,
                                                description="Noise on the measured q, qdot.")
    torque_noise: NonNegFloat = Field(0.0, description="Standard deviation of Gaussian noise "
                                      "added to every applied joint (a walker: motor) torque in "
                                      "[N m].")
    input_delay_steps: int = Field(0, ge=0, le=10_000, description="The plant receives each "
                                   "commanded torque this many control steps late [-].")
    model_error: ModelErrorConfig = Field(default_factory=ModelErrorConfig, description="The "
                                          "plant's physics scaled against the known model.")
