"""A legged experiment (``walking: {base: free_flyer}``): a 3D robot on a free flyer with four
point feet, trotting, learning its feedforward by FEL while a payload its model does not know
is put on (:func:`feltool.walking.legged.learn.learn_trot`; docs/legged.md, "From a config").

A legged config is its own schema, :class:`LeggedExperimentConfig`, not a variant of the
walkers' :class:`~feltool.config.experiment.ExperimentConfig`: the trot has no RMPs per joint,
no ``joints:`` roles and no ``period_s`` of the motion (the gait's period is ``walking.gait``'s),
so the walkers' required fields and cross-section rules do not apply. ``walking.base:
free_flyer`` selects it (:func:`is_legged`), as issue 32 names it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, field_validator

from feltool.bounds import MAX_CYCLES, MAX_RATE_HZ, MAX_SEED, MAX_SEEDS
from feltool.config.base import FiniteFloat, NonNegFloat, PositiveFloat, Strict, once_each
from feltool.config.experiment import SuccessConfig
from feltool.config.files import _pydantic_problems
from feltool.config.walking import FootConfig
from feltool.errors import ConfigError

#: The trot's feet: front left, front right, hind left, hind right (diagonal pairs FL-HR, FR-HL)
TROT_FEET = ("FL", "FR", "HL", "HR")

#: The robots a legged config names without a URDF path
NAMED_ROBOTS = ("solo12", "example-robot-data:solo12", "talos_legs",
                "example-robot-data:talos_legs")

#: A robot of example-robot-data by its loader's name (e.g. ``example-robot-data:go1``)
ERD = "example-robot-data:"


class TrotGaitConfig(Strict):
    """The trot (:class:`~feltool.walking.legged.trot.TrotGait`): the diagonal pairs (FL, HR)
    and (FR, HL) alternate, each pair's switch an event (both its feet down). The defaults are
    Solo-12's; for another robot the lengths and times a config leaves out (speed, period,
    step_height, sink, landing_speed, raibert, approach_height) are Solo-12's scaled to it by
    dynamic similarity, as are the trot's gains (feltool/walking/legged/similar.py, docs/
    legged.md): the run directory's config.yaml records the values it trotted with."""

    speed: PositiveFloat = Field(0.3, le=5.0, description="Forward speed after the ramp, in "
                                 "[m/s] (at most 5).")
    period: PositiveFloat = Field(0.3, le=10.0, description="One cycle, both pairs stepping "
                                  "once, in [s] (at most 10).")
    ramp: PositiveFloat = Field(1.0, le=100.0, description="Time to reach the speed from "
                                "standing, in [s] (a smoothstep).")
    start: NonNegFloat = Field(0.1, le=100.0, description="Time standing on four feet before "
                               "the first step, in [s].")
    step_height: PositiveFloat = Field(0.04, le=1.0, description="The swing foot's apex above "
                                       "the ground, in [m].")
    sink: NonNegFloat = Field(0.003, le=0.1, description="How far below the ground the swing "
                              "target ends, in [m].")
    landing_speed: PositiveFloat = Field(0.2, le=5.0, description="The swing target's downward "
                                         "speed at its end, in [m/s].")
    raibert: NonNegFloat = Field(0.03, le=10.0, description="Raibert's gain on the base's "
                                 "velocity error, in [s].")
    approach_height: NonNegFloat = Field(0.005, le=0.5, description="The last height above the "
        "ground the swing target covers in a straight line at the landing velocity, in [m].")
    catch: Annotated[float, Field(gt=0, lt=1)] = Field(0.2, description="Fraction of a swing "
        "after which the foot is wanted back on the ground [-], in (0, 1).")


class WalkGaitConfig(Strict):
    """A biped's walk (feltool/walking/legged/walk.py): the two soles step in turn, the centre
    of mass sways over the stance sole as the linear inverted pendulum's orbit."""

    left: list[str] = Field(min_length=1, description="The left sole's feet (its corners), "
                            "standing first.")
    right: list[str] = Field(min_length=1, description="The right sole's feet, stepping first.")
    speed: NonNegFloat = Field(0.15, le=2.0, description="Forward speed after the ramp, in "
                               "[m/s].")
    period: PositiveFloat = Field(1.2, le=10.0, description="One cycle, both soles stepping "
                                  "once, in [s].")
    ramp: PositiveFloat = Field(2.0, le=100.0, description="Time to reach the speed from the "
                                "first step, in [s].")
    start: PositiveFloat = Field(1.5, le=100.0, description="Time on both soles before the "
        "first step, in [s]; it must leave room for the weight shift (shift + 0.9 period / 4).")
    step_height: PositiveFloat = Field(0.05, le=1.0, description="The swing sole's apex above "
                                       "the ground, in [m].")
    landing_speed: PositiveFloat = Field(0.05, le=5.0, description="The swing target's downward "
                                         "speed at its end, in [m/s].")
    catch: Annotated[float, Field(gt=0, lt=1)] = Field(0.3, description="Fraction of a swing "
        "after which the sole is wanted back on the ground [-].")
    sway: PositiveFloat = Field(1.0, le=2.0, description="Where the centre of pressure is put in "
        "the stance sole, as a fraction of the sole's distance from the midline [-].")
    shift: PositiveFloat = Field(0.8, le=100.0, description="The weight shift's duration before "
                                 "the first step, in [s].")


#: A PD pair: (stiffness, damping), each >= 0
Gains = tuple[Annotated[float, Field(ge=0.0, le=1e7, allow_inf_nan=False)],
              Annotated[float, Field(ge=0.0, le=1e7, allow_inf_nan=False)]]


class LeggedGainsConfig(Strict):
    """The whole-body controller's gains (feltool/walking/legged/control.py, trot.py). Each one
    left out is the robot's default: for a trot Solo-12's scaled to the robot by dynamic
    similarity (feltool/walking/legged/similar.py), for a walk Talos' scaled by its mass
    (feltool/walking/legged/walk.py ``biped_gains``); the run directory's config.yaml records
    the gains it ran with."""

    height: Gains | None = Field(None, description="[k_h, d_h] on the base's height, in [N/m] "
                                 "and [N s/m].")
    tilt: Gains | None = Field(None, description="[k_t, d_t] on the base's roll and pitch, in "
                               "[N m/rad] and [N m s/rad].")
    yaw_rate: Annotated[float, Field(ge=0.0, le=1e7, allow_inf_nan=False)] | None = Field(
        None, description="d_y on the base's yaw rate, in [N m s/rad].")
    joints: Gains | None = Field(None, description="[k_p, d_p] on every motor joint, in "
                                 "[N m/rad] and [N m s/rad]; refused when they make a joint's "
                                 "own loop diverge at sim.rate_hz (the torque held over a "
                                 "control step on the joint's inertia, the others free).")
    horizontal: Gains | None = Field(None, description="[k, d] on the base's (a walk: the "
                                     "centre of mass's) horizontal position, in [N/m] and "
                                     "[N s/m].")
    swing: Gains | None = Field(None, description="[k, d] of the Cartesian PD pulling each foot "
                                "in the air to its target, in [N/m] and [N s/m].")
    normal_force_min: Annotated[float, Field(ge=0.0, le=1e6, allow_inf_nan=False)] | None = \
        Field(None, description="The least normal force the allocation leaves each stance "
              "foot, in [N].")


class LeggedWalkingConfig(Strict):
    """The legged robot's base and feet, and its gait."""

    base: Literal["free_flyer"] = Field(description="free_flyer: the robot on Pinocchio's free "
        "flyer (x, y, z, orientation), a 3D legged experiment (this schema).")
    feet: dict[str, FootConfig] | None = Field(None, description="The point feet FL, FR, HL, "
        "HR (all four, no others), each a URDF frame ({frame: NAME}) or a link and an offset "
        "in its frame ({link: NAME, offset: [x, y, z]} in [m]); default for solo12 its "
        "FL_FOOT, FR_FOOT, HL_FOOT, HR_FOOT frames, for another example-robot-data:NAME the "
        "end effectors lf_*, rf_*, lh_*, rh_* of its SRDF; without those (a URDF) the four ends "
        "of legs of three or more joints at the bottom of the robot in its reference posture "
        "(each the frame on the leg's last body farthest from its joint), named by where they "
        "are on the base (larger x front, larger y left).")
    posture: dict[str, Annotated[FiniteFloat, Field(ge=-100.0, le=100.0)]] | None = Field(
        None, description="The robot's reference posture: motor joint name -> its angle in "
        "[rad] (a prismatic joint's position in [m]); the joints not named keep the model's "
        "(solo12, talos_legs, example-robot-data:NAME: example-robot-data's reference posture; "
        "a URDF: 0). For a trot, with none given and the legs straight there (singular, as a "
        "URDF's zeros mostly are), each leg is bent until its foot is 0.3 of its reach "
        "higher, knees back (feltool/walking/legged/crouch.py); config.yaml records the "
        "posture run with. The "
        "robot stands in it, the feet put on the ground, and the gait's poses start from it.")
    gait: TrotGaitConfig = Field(default_factory=TrotGaitConfig, description="The trot.")
    walk: WalkGaitConfig | None = Field(None, description="A biped's walk instead of the trot "
        "(the feet are then the soles' corners, left and right; default for talos_legs: each "
        "sole's four corners L_* and R_*).")
    gains: LeggedGainsConfig = Field(default_factory=LeggedGainsConfig, description="The "
        "controller's gains, each left out the robot's default.")
    acquire: int = Field(4, ge=0, le=20, description="Rounds of the reference's acquisition "
        "on the known model before the seeds run, once for all of them [-] (the plan corrected "
        "by what the robot did in a settled cycle, feltool/walking/legged/orbit.py); 0: the "
        "plan as it is, whose own feedback is a floor FEL does not go below.")

    @field_validator("feet")
    @classmethod
    def _in_order(cls, feet):
        """FL, FR, HL, HR first (the order the robot's feet are listed in), others after
        (refused by :meth:`LeggedExperimentConfig.problems`, naming each)."""
        if feet is None:
            return feet
        return {**{f: feet[f] for f in TROT_FEET if f in feet}, **feet}


class LeggedSimConfig(Strict):
    """How the trot is simulated."""

    rate_hz: PositiveFloat = Field(1000.0, ge=100.0, le=MAX_RATE_HZ, description="Control rate "
        "in [Hz] (the plant is integrated by RK4 at it, the torque held), from 100.")
    cycles: int = Field(150, ge=1, le=MAX_CYCLES, description="Cycles trotted per seed after the "
        "ramp (a cycle: both pairs stepping once, from one (FL, HR) touchdown to the next; "
        "numbered from 0).")
    impact_window_s: NonNegFloat = Field(1e-4, le=0.01, description="plant pinocchio: the "
        "Moreau-Jean window over which a touchdown impact is resolved, in [s] (0: "
        "instantaneous; docs/legged.md, the trot).")
    start_velocity_scale: NonNegFloat = Field(1.0, le=10.0, description="The seed's random "
        "start velocity: standard normal draws times 0.05 m/s (base linear), 0.2 rad/s (base "
        "angular, joints), times this [-]; 0: start at rest (every seed alike).")


class LeggedPlantConfig(Strict):
    """What simulates the robot; the controller's model is always the known rigid one."""

    simulator: Literal["pinocchio", "mujoco"] = Field("pinocchio", description="pinocchio: the "
        "rigid contact loop (unilateral impacts, every contact check); mujoco: the known model "
        "(its joints and inertias) built in MuJoCo, with MuJoCo's soft contacts "
        "(docs/legged_mujoco.md; pip install 'feltool[mujoco]').")


class LeggedPayloadConfig(Strict):
    """The unknown world: a point mass on the base (at its origin) the plant carries from the
    start of a cycle on, and the controller's model does not know."""

    fraction: PositiveFloat = Field(le=10.0, description="The payload's mass as a fraction of "
                                    "the robot's mass [-] (0.2: 20 %).")
    cycle: int = Field(ge=1, le=MAX_CYCLES, description="The cycle at whose start it is put on "
                       "(cycles numbered from 0, so at least one cycle runs without it).")


#: The steepest slope a legged config may ask for, in [rad] (45 degrees)
MAX_SLOPE = 0.785


class LeggedSlopeConfig(Strict):
    """The unknown world: the ground inclined from the start of a cycle on (the plant's gravity
    turned, feltool/walking/legged/model.py ``sloped``), which the controller's model does not
    know: it keeps the base level with the ground and its gravity vertical to it."""

    angle: Annotated[float, Field(ge=-MAX_SLOPE, le=MAX_SLOPE, allow_inf_nan=False)] = Field(
        description="Inclination in [rad] about the ground's y axis; positive: downhill ahead "
        "(gravity towards +x, as the fixed-base experiments' slope event), negative: uphill.")
    roll: Annotated[float, Field(ge=-MAX_SLOPE, le=MAX_SLOPE, allow_inf_nan=False)] = Field(
        0.0, description="Inclination in [rad] about the ground's x axis; positive: downhill to "
        "the left (gravity towards +y).")
    cycle: int = Field(ge=1, le=MAX_CYCLES, description="The cycle at whose start the ground "
                       "tilts (with a payload: the payload's cycle, one change of the world).")


class LeggedMassesConfig(Strict):
    """The unknown world: the robot's bodies heavier (or lighter) than the model says from the
    start of a cycle on (every body's mass and rotational inertia scaled, the centres of mass
    kept; feltool/walking/legged/model.py ``scaled_masses``)."""

    scale: PositiveFloat = Field(le=10.0, description="Every body's mass and rotational "
                                 "inertia in the plant, times the model's [-] (1.2: 20 % "
                                 "heavier).")
    cycle: int = Field(ge=1, le=MAX_CYCLES, description="The cycle at whose start the masses "
                       "change (with a payload or a slope: theirs, one change of the world).")


class LeggedLearningConfig(Strict):
    """FEL of the trot's feedforward: a Fourier series in the gait's phase per generalized
    coordinate, moved each cycle towards the feedback that moves the robot
    (feltool/walking/legged/learn.py)."""

    enabled: bool = Field(True, description="false: the same rollout without learning (the "
                          "feedback the trot needs).")
    rate: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = Field(0.5, description=
        "Learning rate eta [-] in (0, 1]: the share of the cycle's feedback series moved into "
        "the feedforward per cycle.")
    harmonics: int = Field(0, ge=0, le=20, description="Highest harmonic M of the learned "
        "series [-]; 0: the cycle's mean (higher harmonics lag the base's PDs by more than 90 "
        "degrees and grew the feedback, feltool/walking/legged/learn.py).")


class LeggedExperimentConfig(Strict):
    """A legged experiment: a robot on a free flyer trotting, FEL on its feedforward, an
    unknown payload (selected by ``walking: {base: free_flyer}``)."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$",
                      description="Experiment name; used for the run directory.")
    description: str = Field("", description="Free text shown in summaries.")
    robot: str = Field(min_length=1, description="solo12 (Solo-12 from example-robot-data; also "
        "example-robot-data:solo12), talos_legs (Talos' legs and torso, a biped on two soles; "
        "walking.walk), example-robot-data:NAME (any robot of example-robot-data on its free "
        "flyer, e.g. go1, a1, anymal; its reference posture example-robot-data's, its feet its "
        "SRDF's) or a URDF file's path (relative to the config file), put on a free flyer "
        "(its feet found, walking.feet).")
    effort: PositiveFloat | None = Field(None, le=1.0e4, description="Every motor's torque limit "
        "in [N m], replacing the URDF's (Solo-12's URDF says 1000; its actuator's peak is "
        "2.7); default the URDF's.")
    armature: Annotated[float, Field(ge=0.0, le=100.0)] | None = Field(None, description=(
        "Every motor's rotor inertia reflected through its gear, in [kg m^2] (a prismatic "
        "motor's in [kg]), the model's armature: the known model's and the plant's alike; "
        "default the model's (a URDF has none: 0; Talos' legs 0.1). A URDF as published mostly "
        "leaves it out, and joints of light links then have an inertia too small for a joint "
        "PD held over a control step (walking.gains.joints)."))
    walking: LeggedWalkingConfig = Field(description="Base, feet and gait.")
    sim: LeggedSimConfig = Field(default_factory=LeggedSimConfig, description="Simulation.")
    plant: LeggedPlantConfig = Field(default_factory=LeggedPlantConfig,
                                     description="What simulates the robot.")
    payload: LeggedPayloadConfig | None = Field(None, description="The unknown world; default "
                                                "none.")
    slope: LeggedSlopeConfig | None = Field(None, description="The unknown world (also, or "
                                            "instead of the payload): a slope; default none.")
    masses: LeggedMassesConfig | None = Field(None, description="The unknown world (also, or "
                                              "instead): wrong masses; default none.")
    learning: LeggedLearningConfig = Field(default_factory=LeggedLearningConfig,
                                           description="Feedback error learning.")
    seeds: Annotated[int, Field(ge=1, le=MAX_SEEDS)] | Annotated[
        list[Annotated[int, Field(ge=0, le=MAX_SEED)]], Field(min_length=1, max_length=MAX_SEEDS)
    ] = Field(10, description=f"Number of seeds (0..n-1, at most {MAX_SEEDS}) or a list of "
              "distinct seeds; a seed draws the start velocity.")
    success: SuccessConfig = Field(default_factory=SuccessConfig, description="When a seed "
        "counts as learned (the exit code), beyond trotting physically through every cycle: "
        "fb_ratio_max bounds the last cycle's summed feedback over the first cycle's "
        "(ratio_from: first) or over the payload's cycle's (ratio_from: change); converged: "
        "below 5 % of the first cycle's for good.")

    @field_validator("robot")
    @classmethod
    def _robot(cls, robot: str) -> str:
        if robot not in NAMED_ROBOTS and not robot.endswith(".urdf") and not (
                robot.startswith(ERD) and len(robot) > len(ERD)):
            raise ValueError(f"'{robot}' is neither {NAMED_ROBOTS[0]}, {NAMED_ROBOTS[2]}, "
                             f"{ERD}NAME nor a URDF file's path (ending in .urdf)")
        return robot

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, s):
        return once_each(s)

    def problems(self) -> list[tuple[str, str]]:
        """Checks across fields, as ``(yaml_path, message)`` pairs."""
        out = []
        if self.plant.simulator == "mujoco" and "impact_window_s" in self.sim.model_fields_set:
            out.append(("sim.impact_window_s", "the rigid plant's impact window; MuJoCo's soft "
                                               "contacts have none (plant.simulator: mujoco)"))
        feet, walk = self.walking.feet, self.walking.walk
        talos = self.robot in NAMED_ROBOTS[2:]
        if walk is not None or talos:
            return out + self._walk_problems()
        if feet is not None:
            out += [(f"walking.feet.{f}", f"unknown foot name '{f}': the trot's feet are "
                                          f"{', '.join(TROT_FEET)} (front/hind, left/right)")
                    for f in feet if f not in TROT_FEET]
            missing = [f for f in TROT_FEET if f not in feet]
            if missing:
                out.append(("walking.feet", f"the trot needs all four feet "
                                            f"{', '.join(TROT_FEET)}; missing {', '.join(missing)}"))
        out += self._world_problems()
        return out

    def _walk_problems(self) -> list[tuple[str, str]]:
        """A biped's walk: ``walking.walk`` given, not with ``walking.gait``; its soles' feet
        the feet, each once."""
        w = self.walking
        if w.walk is None:
            return [("walking.walk", "a biped (talos_legs) walks: give walking.walk with its "
                                     "left and right soles' feet")]
        out = []
        if "gait" in w.model_fields_set:
            out.append(("walking.gait", "the trot's; a walk's timing is walking.walk's"))
        sole = w.walk.left + w.walk.right
        twice = sorted({f for f in sole if sole.count(f) > 1})
        if twice:
            out.append(("walking.walk", f"a foot in both soles or twice: {', '.join(twice)}"))
        if w.feet is not None:
            missing = [f for f in sole if f not in w.feet]
            if missing:
                out.append(("walking.walk", f"not among walking.feet: {', '.join(missing)}"))
            spare = [f for f in w.feet if f not in sole]
            if spare:
                out.append(("walking.feet", f"in neither sole (walking.walk.left, .right): "
                                            f"{', '.join(spare)}"))
        elif self.robot not in NAMED_ROBOTS:
            out.append(("walking.feet", "required for a URDF robot: each sole's corners, "
                                        "{link: NAME, offset: [x, y, z]}"))
        out += self._world_problems()
        return out

    def _world_problems(self) -> list[tuple[str, str]]:
        """The unknown world changes once (a payload, a slope, wrong masses: together at one
        cycle); the feedback ratio from the change needs one."""
        out = []
        worlds = [(name, w) for name, w in (("payload", self.payload), ("slope", self.slope),
                                            ("masses", self.masses)) if w is not None]
        first, at = worlds[0] if worlds else (None, None)
        for name, w in worlds[1:]:
            if w.cycle != at.cycle:
                out.append((f"{name}.cycle", f"the world changes once: cycle {w.cycle} is not "
                                             f"{first}.cycle {at.cycle}"))
        if self.success.ratio_from == "change" and self.change_cycle is None:
            out.append(("success.ratio_from", "change needs a change of the world (payload: "
                                              "{fraction: ..., cycle: ...}, slope: {angle: "
                                              "..., cycle: ...} or masses: {scale: ..., "
                                              "cycle: ...})"))
        return out

    @property
    def change_cycle(self) -> int | None:
        """The cycle at whose start the unknown world arrives (payload, slope, masses), or
        None."""
        world = self.payload or self.slope or self.masses
        return None if world is None else world.cycle

    @property
    def seed_list(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)

    def urdf_path(self, base_dir: Path | None) -> Path | None:
        """The URDF file (relative paths from ``base_dir``, the config's directory), or None
        for a named robot or one of example-robot-data."""
        if self.robot in NAMED_ROBOTS or self.robot.startswith(ERD):
            return None
        path = Path(self.robot).expanduser()
        return path if path.is_absolute() or base_dir is None else Path(base_dir) / path


def is_legged(raw: Any) -> bool:
    """Whether a raw config mapping is a legged experiment (``walking.base: free_flyer``)."""
    walking = raw.get("walking") if isinstance(raw, dict) else None
    return isinstance(walking, dict) and walking.get("base") == "free_flyer"


def parse_legged_config(data: dict[str, Any], source: str | None = None
                        ) -> LeggedExperimentConfig:
    """Validate a legged config mapping; raises :class:`ConfigError` naming every bad field."""
    try:
        cfg = LeggedExperimentConfig.model_validate(data)
    except ValidationError as exc:
        problems = [(p, m.replace("see docs/configuration.md", "see docs/configuration.md, "
                                  "LeggedExperimentConfig") if m.startswith("unknown field")
                     else m) for p, m in _pydantic_problems(exc)]
        raise ConfigError(problems, source) from None
    problems = cfg.problems()
    if problems:
        raise ConfigError(problems, source)
    return cfg


def legged_config_yaml(cfg: LeggedExperimentConfig, base_dir: Path | None) -> str:
    """The resolved config (defaults filled in) as YAML, a URDF path made absolute."""
    from feltool.files import dump_yaml

    data = cfg.model_dump(mode="json")
    path = cfg.urdf_path(base_dir)
    if path is not None:
        data["robot"] = str(path.resolve())
    return dump_yaml(data, sort_keys=False)
