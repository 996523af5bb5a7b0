"""The whole experiment config (:class:`ExperimentConfig`): robot, sections, seeds, success
criterion and sweeps; the cross-section rules.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    field_validator,
    model_validator,
)

from feltool.bounds import (
    MAX_ABS_GRAVITY,
    MAX_PERIOD_S,
    MAX_SEED,
    MAX_SEEDS,
    MAX_STEPS_PER_CYCLE,
    MAX_SWEEP_POINTS,
)
from feltool.config.base import Gravity, PositiveFloat, Strict, once_each
from feltool.config.disturbances import DisturbanceConfig
from feltool.config.events import EventConfig
from feltool.config.joints import JointConfig
from feltool.config.learning import FEL_UPDATES, ILCConfig, LearningConfig
from feltool.config.plant import PlantConfig
from feltool.config.primitives import PrimitiveConfig
from feltool.config.sim import SimConfig
from feltool.config.walking import ActuationConfig, WalkingConfig


class SweepConfig(Strict):
    """A grid for ``feltool sweep`` (ignored by ``feltool run``)."""

    grid: dict[str, list[Any]] = Field(default_factory=dict, description="Dotted config paths "
                                       "and the values to try, e.g. {learning.rates.gauss_newton: "
                                       "[0.5, 1.0]}; the product of all is run (at most "
                                       f"{MAX_SWEEP_POINTS} points).")


class SuccessConfig(Strict):
    """What counts as a seed that learned: ``feltool run`` exits 0 only when every seed does
    (and 1, with every result kept, when some seed diverged, fell or missed this)."""

    fb_ratio_max: PositiveFloat | None = Field(None, description="Largest allowed fb_final / "
        "fb_initial (the error signal's mean |feedback| in the last cycle over the first); "
        "default: no bound.")
    converged: bool = Field(False, description="Require a converged_cycle (below 5 % of the "
                            "initial feedback for good) by the last cycle.")
    ratio_from: Literal["first", "change"] = Field("first", description="The cycle whose error "
        "feedback fb_ratio_max divides the last cycle's by: first = cycle 1 (fb_ratio); change "
        "= the cycle of the first world event (events: payload, mass, slope; fb_ratio_change "
        "in summary.json), for a run that starts on a gait exact for the known model, whose "
        "first cycles have almost no feedback.")


class RobotConfig(Strict):
    """The robot in its long form, with how its URDF is read (docs/robots.md)."""

    source: str = Field(min_length=1, description="Bundled robot name, a URDF path (relative "
                        "to the config file), or example-robot-data:NAME.")
    lenient: bool = Field(True, description="Read the URDF dialects of other toolchains that "
        "Pinocchio's parser refuses, each said in a warning: `world` as the root's parent, an "
        "`<inertial>` without `<inertia>` (a point mass), a revolute or prismatic joint "
        "without `<limit>` (unbounded). false: refuse them, naming the element.")


class ExperimentConfig(Strict):
    """One FEL experiment: a robot, the roles of its joints, and how to learn."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$",
                      description="Experiment name; used for the run directory.")
    description: str = Field("", description="Free text shown in summaries.")
    robot: Annotated[str, Field(min_length=1)] | RobotConfig = Field(description="Bundled "
        "robot name, a URDF path (relative to the config file), or example-robot-data:NAME; "
        "or {source: ..., lenient: false} to refuse the URDF dialects lenient reading accepts.")
    package_dirs: list[str] = Field(default_factory=list, description="Directories searched for "
                                    "package:// mesh paths of a URDF file (relative to the "
                                    "config file).")
    gravity: Gravity | list[Gravity] = Field(9.8, description="Gravity in [m/s^2]: a "
        "magnitude along the world's -z, or a 3-vector. The thesis uses 9.8. Each component "
        f"within +-{MAX_ABS_GRAVITY:g}.")
    backend: Literal["auto", "pinocchio", "casadi", "compiled"] = Field("auto", description=
        "The engine of the learning cycles. auto: compiled when a C compiler is present and "
        "the compiled engine runs everything the config asks (feltool.engines.compiled.support.unsupported), "
        "else pinocchio (the run says which, once). compiled: each learning cycle as one CasADi "
        "graph generated to C and compiled (cached on disk), an error naming what it does not "
        "run. pinocchio: the Python engine, Pinocchio calls per step (the reference). casadi: "
        "the Python engine with the known models as CasADi expressions built from the same "
        "model.")
    period_s: PositiveFloat = Field(le=MAX_PERIOD_S, description="Period T of the rhythmic "
        f"motion in [s] (the phase's starting frequency is 2 pi / T); at most "
        f"{MAX_PERIOD_S:g}, and period_s * sim.rate_hz (the samples per cycle, any number: a "
        "cycle is one revolution of the phase) from 2 to "
        f"{MAX_STEPS_PER_CYCLE}.")
    sim: SimConfig = Field(default_factory=SimConfig, description="Simulation settings.")
    primitives: PrimitiveConfig = Field(default_factory=PrimitiveConfig,
                                        description="Defaults for every joint's RMP.")
    joints: dict[str, JointConfig] = Field(min_length=1, description="Role of each joint, by "
                                           "URDF joint name; joints not listed are locked at 0.")
    learning: LearningConfig = Field(default_factory=LearningConfig,
                                     description="Feedback error learning.")
    walking: WalkingConfig | None = Field(None, description="Hybrid walking (walkers only).")
    actuation: ActuationConfig | None = Field(None, description="Motors and torque allocation "
        "(underactuated robots); default every non-passive joint is its own motor.")
    events: list[EventConfig] = Field(default_factory=list, description="Changes of the world "
                                      "at given cycles (adaptation experiments).")
    plant: PlantConfig | None = Field(None, description="The simulated robot, when it differs "
                                      "from the known model; default plant = model.")
    ilc: ILCConfig = Field(default_factory=ILCConfig, description="Iterative learning "
                           "control settings (learning.update ilc_p, ilc_norm_optimal).")
    disturbances: DisturbanceConfig | None = Field(None, description="Noise, delay and model "
        "error applied to the plant only (robustness studies); default none.")
    seeds: Annotated[int, Field(ge=1, le=MAX_SEEDS)] | Annotated[
        list[Annotated[int, Field(ge=0, le=MAX_SEED)]], Field(min_length=1, max_length=MAX_SEEDS)
    ] = Field(20, description=f"Number of seeds (0..n-1, at most {MAX_SEEDS}) or an explicit "
              "list of distinct seeds (each 0 to 2^63 - 1).")
    sweep: SweepConfig | None = Field(None, description="Grid for feltool sweep.")
    success: SuccessConfig = Field(default_factory=SuccessConfig, description="When a seed "
                                   "counts as learned (the exit code); default: it did not "
                                   "diverge.")

    @field_validator("gravity")
    @classmethod
    def _gravity_vector(cls, g):
        if isinstance(g, list) and len(g) != 3:
            raise ValueError("a gravity vector needs 3 components [m/s^2]")
        return g

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, s):
        return once_each(s)

    @model_validator(mode="before")
    @classmethod
    def _one_mechanical_phase(cls, data: Any) -> Any:
        """``primitives.phase: mechanical`` and ``walking.phase: mechanical`` are one setting:
        either one given alone sets the other. A physical walker (``walking.feet``) that gives
        neither is mechanical (the clock phase drifts off a designed gait: docs/biped.md)."""
        if not isinstance(data, dict):
            return data
        prims, walking = data.get("primitives"), data.get("walking")
        if not isinstance(walking, dict) or (prims is not None and not isinstance(prims, dict)):
            return data
        prims = dict(prims or {})
        if walking.get("feet") is not None and "phase" not in walking and "phase" not in prims:
            return {**data, "walking": {**walking, "phase": "mechanical"},
                    "primitives": {**prims, "phase": "mechanical"}}
        if "phase" not in prims and walking.get("phase") == "mechanical":
            return {**data, "primitives": {**prims, "phase": "mechanical"}}
        if "phase" not in walking and prims.get("phase") == "mechanical":
            return {**data, "walking": {**walking, "phase": "mechanical"}}
        return data

    def problems(self) -> list[tuple[str, str]]:
        """Checks across fields, as ``(yaml_path, message)`` pairs."""
        steps = self.period_s * self.sim.rate_hz
        if steps > MAX_STEPS_PER_CYCLE:
            return [("period_s", f"period_s * sim.rate_hz = {steps:g} samples per cycle; at "
                                 f"most {MAX_STEPS_PER_CYCLE} (feltool's limit)")]
        if steps < 2:
            return [("period_s", f"period_s * sim.rate_hz = {steps:g} samples per cycle; at "
                                 "least 2")]
        w = self.walking
        if w is not None and w.physical and w.phase != "clock" and (
                not self.whole_period or round(steps) % w.steps_per_cycle):
            return [("period_s", f"period_s * sim.rate_hz = {steps:g} samples per cycle: a "
                                 "physical walker's cycle must be a whole number of them that "
                                 f"splits into walking.steps_per_cycle = {w.steps_per_cycle} "
                                 "equal steps (each step's phase runs over its own share)")]
        bases = {"primitives.basis": self.primitives.basis}
        for name, jc in self.joints.items():
            if jc.primitive is not None and jc.primitive.basis is not None:
                bases[f"joints.{name}.primitive.basis"] = jc.primitive.basis
        low = int(steps)
        out = [(where, f"{basis} basis functions but only {low} samples per cycle "
                       "(period_s * sim.rate_hz); use at most that many")
               for where, basis in bases.items() if basis > low]
        out += self._hold_problems()
        if self.success.ratio_from == "change" and self.world_change_cycle is None:
            out.append(("success.ratio_from", "change needs a world event (events: with kind "
                                              "payload, mass or slope)"))
        return out + self._phase_problems()

    def _hold_problems(self) -> list[tuple[str, str]]:
        """``sim.feedforward: hold_mean`` is for an arm learning per cycle (or learning
        nothing): the held mean needs the cycle's desired trajectory before the cycle runs
        (feltool.control.hold)."""
        if self.sim.feedforward != "hold_mean":
            return []
        L = self.learning
        why = [what for bad, what in (
            (self.walking is not None or self.actuation is not None, "a walker"),
            (L.model is not None, "model learning"),
            (self.disturbances is not None, "disturbances"),
            (L.update not in FEL_UPDATES, f"update: {L.update}"),
            (L.step != "per_cycle", "learning.step: per_step"),
            (self.primitives.phase == "adaptive", "the adaptive phase"),
        ) if bad]
        return [("sim.feedforward", "hold_mean is for arms learning per cycle; not with "
                 + ", ".join(why))] if why else []

    @property
    def world_change_cycle(self) -> int | None:
        """The cycle at whose start the first world event changes the plant, or None."""
        cycles = [ev.cycle for ev in self.events if ev.changes_world]
        return min(cycles) if cycles else None

    def _phase_problems(self) -> list[tuple[str, str]]:
        phase, w = self.primitives.phase, self.walking
        if phase == "mechanical" and (w is None or not w.physical):
            return [("primitives.phase", "mechanical is the physical walker's phase (it follows "
                                         "the centre of mass over the stance foot): it needs a "
                                         "walking block with feet")]
        if w is not None and w.physical and (phase == "mechanical") != (w.phase == "mechanical"):
            return [("primitives.phase", f"primitives.phase: {phase} and walking.phase: "
                                         f"{w.phase} disagree; mechanical is one setting for "
                                         "both (give it in one place)")]
        if w is not None and phase == "adaptive":
            return [("primitives.phase", "adaptive is not available for walkers yet (their "
                                         "phase is clock, touchdown or mechanical)")]
        return []

    @property
    def whole_period(self) -> bool:
        """Whether a period is a whole number of control steps (the thesis's cycle)."""
        steps = self.period_s * self.sim.rate_hz
        return abs(steps - round(steps)) <= 1e-9 * max(1.0, steps)

    @property
    def motion_events(self) -> list[tuple[int, EventConfig]]:
        """``(index, event)`` of the events that change the motion (period, amplitude, goal)."""
        return [(i, ev) for i, ev in enumerate(self.events) if not ev.changes_world]

    @property
    def closed_loop_fit(self) -> bool:
        """Whether the config asks for the closed-loop Gauss-Newton fit and its learner can give
        it (``learning.fit: closed_loop``, :mod:`feltool.learning.loop_map`): an arm (no walking
        or actuation block, no model learning) learning per cycle with update gauss_newton. The
        assembly adds what only the built experiment knows (plain joint coordinates, no phase
        events)."""
        L = self.learning
        return (L.fit == "closed_loop" and L.update == "gauss_newton" and L.step == "per_cycle"
                and self.walking is None and self.actuation is None and L.model is None)

    @property
    def robot_source(self) -> str:
        """The robot as ``robot`` names it (bundled name, URDF path or example-robot-data:NAME)."""
        return self.robot if isinstance(self.robot, str) else self.robot.source

    @property
    def seed_list(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)

    @property
    def dt(self) -> float:
        """Control step in [s]."""
        return 1.0 / self.sim.rate_hz

    @property
    def steps_per_cycle(self) -> int:
        """Steps of a cycle at the nominal period (rounded)."""
        return int(round(self.period_s * self.sim.rate_hz))
