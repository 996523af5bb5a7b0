"""The experiment config: a YAML file validated by a pydantic schema.

Every field carries a description with its unit; ``docs/configuration.md`` is generated from this
schema (``python -m feltool.docgen``) and a test keeps the two in sync. Unknown keys are errors, so
a typo is never silently ignored, and every error names the YAML path that is wrong.
"""

from __future__ import annotations

import re
import types
import typing
from collections import Counter
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import yaml
from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    Tag,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from feltool.bounds import (
    MAX_ABS_GRAVITY,
    MAX_ALPHA,
    MAX_AMPLITUDE,
    MAX_ANGLE,
    MAX_CONFIG_BYTES,
    MAX_CYCLES,
    MAX_DAMPING,
    MAX_GAIN,
    MAX_HARMONICS,
    MAX_LENGTH,
    MAX_MASS,
    MAX_MASS_SCALE,
    MAX_PERIOD_S,
    MAX_RATE,
    MAX_RATE_HZ,
    MAX_SEED,
    MAX_SEEDS,
    MAX_STEPS_PER_CYCLE,
    MAX_SWEEP_POINTS,
    MAX_WEIGHT_SCALE,
    MAX_WIDTH,
)
from feltool.errors import ConfigError
from feltool.physical import inertia_problem
from feltool.safe_yaml import YamlBoundError, load_yaml

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Angle = Annotated[float, Field(ge=-MAX_ANGLE, le=MAX_ANGLE, allow_inf_nan=False)]
Length = Annotated[float, Field(ge=-MAX_LENGTH, le=MAX_LENGTH, allow_inf_nan=False)]
Gravity = Annotated[float, Field(ge=-MAX_ABS_GRAVITY, le=MAX_ABS_GRAVITY, allow_inf_nan=False)]


def _numeric(tp: Any) -> bool:
    """Whether a field type would read a YAML boolean as the number 1 or 0."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Annotated:
        return _numeric(args[0])
    if origin in (Union, types.UnionType):
        return any(_numeric(a) for a in args) and bool not in args
    return tp in (int, float)


def _bool_in(tp: Any, value: Any) -> str | None:
    """Where a boolean sits in ``value`` that the type ``tp`` would read as a number ("" for
    the value itself, ".2" for an item of a list), or None. Nested models check their own."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Annotated:
        return _bool_in(args[0], value)
    if isinstance(value, bool):
        return "" if _numeric(tp) else None
    if origin in (Union, types.UnionType):
        return next((w for a in args if (w := _bool_in(a, value)) is not None), None)
    if isinstance(value, list | tuple) and origin in (list, tuple) and args:
        for i, item in enumerate(value):
            item_tp = args[0] if origin is list or args[-1] is Ellipsis else \
                args[i] if i < len(args) else Any
            where = _bool_in(item_tp, item)
            if where is not None:
                return f".{i}{where}"
    if isinstance(value, dict) and origin is dict and len(args) == 2:
        for key, item in value.items():
            where = _bool_in(args[1], item)
            if where is not None:
                return f".{key}{where}"
    return None


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    @field_validator("*", mode="before")
    @classmethod
    def _booleans_are_not_numbers(cls, value: Any, info: ValidationInfo) -> Any:
        """YAML reads yes/no/on/off/true/false as booleans, and pydantic would take a boolean
        for the number 1 or 0 (``cycles: yes`` would run one cycle): refuse them wherever a
        number is expected."""
        field = cls.model_fields.get(info.field_name)
        if field is None:
            return value
        where = _bool_in(field.annotation, value)
        if where is not None:
            item = f" (item {where.lstrip('.')})" if where else ""
            raise ValueError(f"a boolean (yes/no/true/false/on/off){item} is not a number; "
                             "write the number")
        return value


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
                                        f"Mises basis [-]; default N / 2; at most {MAX_WIDTH:g}.")
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


class SineDemo(Strict):
    """A demonstrated sine (optionally with higher harmonics), fitted into the joint's RMP by
    least squares (eq. 2.4): q(t) = mean + amplitude sin(w s + phase) + sum_k A_k sin(k w s + phi_k)
    with w = 2 pi / T, s = t - delay T and k = 2, 3, ... for the entries of ``harmonics``."""

    kind: Literal["sine"] = Field(description="Demonstration kind.")
    mean: Angle = Field(0.0, description=f"Mean (the RMP goal) in [rad]; within +-{MAX_ANGLE:g}.")
    amplitude: Angle = Field(description=f"Amplitude in [rad]; within +-{MAX_ANGLE:g}.")
    phase: FiniteFloat = Field(0.0, description="Phase offset in [rad] at the start of a cycle.")
    harmonics: list[tuple[Angle, FiniteFloat]] = Field(default_factory=list,
        max_length=MAX_HARMONICS, description="Higher harmonics k = 2, 3, ...: [amplitude in "
        f"[rad], phase in [rad]] each; at most {MAX_HARMONICS}.")
    delay: FiniteFloat = Field(0.0, description="Delay of the whole demonstration, as a "
                               "fraction of the period (e.g. 0.5 for a walker's other leg) [-].")


MAX_DEMO_SAMPLES = 100_000  # samples of a samples demo


class SamplesDemo(Strict):
    """A demonstration given by samples over one period (e.g. a designed gait's collocation knots,
    ``feltool gait``), fitted into the joint's RMP by least squares (eq. 2.4). The samples are
    equally spaced in time, the first at t = 0 and the last at t = T (a walker's one-step
    trajectory need not end where it starts); between them the trajectory is the cubic whose
    acceleration is linear in time (exact for the gait designer's collocation)."""

    kind: Literal["samples"] = Field(description="Demonstration kind.")
    q: list[Angle] = Field(min_length=3, max_length=MAX_DEMO_SAMPLES, description="Positions in "
                           f"[rad] (or [m]) at t = k T / (n - 1), k = 0..n-1; within "
                           f"+-{MAX_ANGLE:g}, at most {MAX_DEMO_SAMPLES} samples.")
    v: list[FiniteFloat] = Field(max_length=MAX_DEMO_SAMPLES, description="Velocities in "
                                 "[rad/s] at the same times.")
    a: list[FiniteFloat] = Field(max_length=MAX_DEMO_SAMPLES, description="Accelerations in "
                                 "[rad/s^2] at the same times.")

    @model_validator(mode="after")
    def _same_length(self) -> SamplesDemo:
        if not len(self.q) == len(self.v) == len(self.a):
            raise ValueError("q, v and a need one value per sample each")
        return self


class PositionsDemo(Strict):
    """A demonstration given by positions only, at any rate: equally spaced samples that span
    ``periods`` whole periods (the sample after the last would be the first again), from a
    list or a CSV column. It is resampled onto the phase by its Fourier series (the
    trigonometric interpolant, by the FFT), its velocities and accelerations come from spectral
    differentiation, and it is fitted over the whole phase (eq. 2.4). The fit error (RMS over
    the cycle of the RMP's limit cycle minus the demonstration) is reported by feltool check
    and in summary.json (demo_fit_rms_rad)."""

    kind: Literal["positions"] = Field(description="Demonstration kind.")
    q: list[Angle] | None = Field(None, min_length=3, max_length=MAX_DEMO_SAMPLES,
                                  description="Positions in [rad] (or [m]); within "
                                  f"+-{MAX_ANGLE:g}, at most {MAX_DEMO_SAMPLES} samples.")
    csv: str | None = Field(None, description="A CSV file with a header row (relative to the "
                            "config file), read instead of q.")
    column: str | None = Field(None, description="The CSV column (its header) to read.")
    periods: int = Field(1, ge=1, le=10_000, description="Whole periods the samples span.")

    @model_validator(mode="after")
    def _source(self) -> PositionsDemo:
        if (self.q is None) == (self.csv is None):
            raise ValueError("give either 'q' or 'csv' (with 'column')")
        if self.csv is not None and self.column is None:
            raise ValueError("'csv' needs 'column' (the header of the column to read)")
        problem = too_few_samples(len(self.q), self.periods) if self.q is not None else None
        if problem:
            raise ValueError(problem)
        return self


def too_few_samples(n: int, periods: int) -> str | None:
    """Why ``n`` position samples spanning ``periods`` periods cannot be a demo (too few to
    resolve one harmonic), or None."""
    if n <= 2 * periods:
        return (f"{n} samples cannot resolve one harmonic over {periods} period(s); give more "
                f"than {2 * periods}")
    return None


def _demo_kind(value: Any) -> str:
    """Which demo model validates ``value``: its ``kind`` (sine when missing or unknown, so that
    the error names the sine demo's fields as before)."""
    kind = value.get("kind") if isinstance(value, dict) else getattr(value, "kind", None)
    return kind if kind in ("samples", "positions") else "sine"


class Gains(Strict):
    """PD gains of a joint's feedback law (eq. 2.7 or §3.1)."""

    kp: NonNegFloat = Field(le=MAX_GAIN, description="Proportional gain K_P in [N m/rad]; 0 to "
                            f"{MAX_GAIN:g}.")
    kd: NonNegFloat = Field(le=MAX_GAIN, description="Derivative gain K_D in [N m s/rad]; 0 to "
                            f"{MAX_GAIN:g}.")


Vector3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


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
                    Discriminator(_demo_kind)] | None = Field(
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


class ModelLearningConfig(Strict):
    """Classic (Kawato) feedback error learning of an inverse-model correction (eq. 2.8, 3.4):
    u_ff = RNEA_model(q_d, qd_d, qdd_d) + S_m Phi(q_d, qd_d, qdd_d) theta_m, with the feedback of
    the error joints S_m (default: every actuated joint) as the error signal."""

    features: Literal["regressor", "phase_basis"] = Field("regressor", description="Features "
        "Phi: regressor = Pinocchio's joint-torque regressor, so theta_m are corrections of the "
        "10 inertial parameters per body [m, m c, I at the joint frame origin]; phase_basis = "
        "normalised von Mises functions of the phase, one set per joint, theta_m in [N m].")
    error: Literal["all_feedback", "tracking"] | list[str] = Field("all_feedback", description=""
        "Error signal: all actuated feedback (Kawato's FEL), only the tracking joints' feedback "
        "(leaves the stabilizing feedback to trajectory FEL when both run), or a list of joints. "
        "The correction drives only these joints (docs/model_learning.md).")
    basis: int = Field(20, ge=1, le=1000, description="Number of phase basis functions per "
                       "joint (phase_basis only).")
    width: PositiveFloat | None = Field(None, le=MAX_WIDTH, description="Width h of the phase basis [-] "
                                        "(phase_basis only); default basis / 2.")
    update: Literal["gradient", "gauss_newton"] = Field("gradient", description="gradient: "
        "eq. 3.4, theta_m += rate * sum_k Phi_k^T e_k; gauss_newton: the Levenberg-Marquardt "
        "step rate * (Phi^T Phi + lambda I)^-1 Phi^T e over the cycle (per_cycle only; fast "
        "alone, but it interferes with trajectory FEL).")
    step: Literal["per_cycle", "per_step"] = Field("per_cycle", description="Update once per "
        "cycle or after every control step (per_step: gradient only).")
    rate: NonNegFloat = Field(le=MAX_RATE, description="Learning rate alpha_m (required; at "
        f"most {MAX_RATE:g}; its unit depends on "
        "the features): gradient: per sample and cycle, in [theta_m unit / (N m)^2] -- stable "
        "below 2 / (largest eigenvalue of sum_k Phi_k^T Phi_k); gauss_newton: the fraction of the "
        "Levenberg-Marquardt step [-]. See docs/model_learning.md.")
    damping: PositiveFloat = Field(1.0e-6, le=MAX_DAMPING, description="Levenberg-Marquardt "
                                   "damping, relative to the mean diagonal of Phi^T Phi [-]; "
                                   "directions the motion does not excite are then left "
                                   f"unchanged; at most {MAX_DAMPING:g}.")
    jacobian: Literal["learned", "nominal"] = Field("learned", description="Inverse model whose "
        "derivatives the trajectory learner's Jacobian uses when both learn: learned = the known "
        "model plus the current correction (chain rule through Phi theta_m; regressor features "
        "give RNEA with pi_model + theta_m; on the joints the correction drives), nominal = the "
        "known model alone.")


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


class Rates(Strict):
    """Learning rates alpha of eq. 3.6, separate for weights and goal."""

    weights: NonNegFloat = Field(0.15, le=MAX_RATE, description="Rate for the RMP weights "
                                 "(gradient) or the fraction of the Levenberg-Marquardt step "
                                 f"taken (gauss_newton); at most {MAX_RATE:g}.")
    goal: NonNegFloat = Field(2.0e-5, le=MAX_RATE, description="Rate for the RMP goal (always "
                              "gradient). The update sums over a cycle's samples, so rates "
                              f"scale with rate_hz; at most {MAX_RATE:g}.")


class LearningConfig(Strict):
    """Feedback error learning of the RMP parameters (eq. 3.6)."""

    error: Literal["stabilizing", "all_feedback"] | list[str] = Field(
        "stabilizing", description="Error signal e: the stabilizing feedback (fully actuated "
        "robots), all feedback (underactuated robots), or a list of joints whose feedback counts.")
    update: Literal["gradient", "gauss_newton", "ilc_p", "ilc_norm_optimal", "feedback_only"] = \
        Field("gradient", description="gradient: eq. 3.6; gauss_newton: a Levenberg-Marquardt "
              "step on the weights (goal stays on gradient); ilc_p: P-type ILC of a per-sample "
              "feedforward torque with a zero-phase Q filter; ilc_norm_optimal: norm-optimal ILC "
              "on the lifted cycle model of the known model; feedback_only: no learning (the "
              "baseline). The ILC settings are in `ilc` (docs/comparison.md).")
    step: Literal["per_cycle", "per_step"] = Field("per_cycle", description="Update once per "
        "cycle (the RMP is then reset onto its new limit cycle) or after every control step.")
    rates: Rates = Field(default_factory=Rates, description="Learning rates.")
    damping: PositiveFloat = Field(1.0e-2, le=MAX_DAMPING, description="Levenberg-Marquardt "
                                   "damping, relative to the mean diagonal of J^T J [-]; at most "
                                   f"{MAX_DAMPING:g}.")
    sensitivity: Literal["exact", "finite_difference", "casadi"] = Field("exact", description=
        "How d u_ff / d theta is computed: exact (RMP sensitivity x Pinocchio's RNEA "
        "derivatives), the thesis's numerical differentiation, or CasADi's algorithmic "
        "differentiation through the RMP and a symbolic RNEA.")
    fd_epsilon: PositiveFloat = Field(1.0e-6, le=1.0, description="Finite-difference step, "
                                      "relative to max(1, |theta_i|) [-]; at most 1.")
    impact_window_s: NonNegFloat = Field(0.0, description="Walkers only: leave the error "
        "signal's samples within this time after every impact out of the update (the impact's "
        "velocity jump makes a feedback spike that no smooth RMP can remove) [s]; 0 = off.")
    model: ModelLearningConfig | None = Field(None, description="Also learn an inverse-model "
        "correction by classic FEL (docs/model_learning.md); default off.")
    error_estimate: Literal["feedback", "inverse_dynamics"] = Field("feedback", description=
        "Physical walkers: the feedforward's error is estimated by the feedback (eq. 3.6), or "
        "by the feedback plus the inertial term M (a_r - a) of the reference's acceleration "
        "against the walker's (inverse_dynamics: the feedforward's error itself, also when the "
        "feedback's bandwidth, bounded by the torque limits, is below the gait's; "
        "docs/biped.md).")
    error_space: Literal["generalized", "motors"] = Field("generalized", description="Physical "
        "walkers: the error signal and the feedforward's Jacobian in generalized forces "
        "(generalized), or both mapped through the allocation onto the motors (motors: the "
        "torques the motors apply, the part of the feedforward that acts; docs/biped.md).")


class ILCConfig(Strict):
    """Iterative learning control (learning.update ilc_p / ilc_norm_optimal): the learned
    feedforward is a torque per sample of the cycle, added to the known model's torque along the
    initial RMP (feltool.ilc); on a physical walker a motor torque per RMP sample, added to the
    allocated command (feltool.ilc_walker)."""

    gain: NonNegFloat = Field(1.0, description="ilc_p: learning gain L of "
                              "u_{h+1} = Q(u_h + L e_h) [-] (error and input are torques).")
    lead_steps: int = Field(0, ge=0, le=100_000, description="ilc_p: phase lead of the error "
                            "in samples (u_h^k is corrected by e_h^{k+lead}) [-].")
    cutoff_hz: PositiveFloat | None = Field(20.0, description="ilc_p: cutoff of the zero-phase "
        "Butterworth Q filter in [Hz] (run forwards and backwards over the periodic cycle); "
        "null: no filter.")
    order: int = Field(2, ge=1, le=8, description="ilc_p: order of the Q filter's Butterworth "
                       "low pass [-].")
    weight_error: PositiveFloat = Field(1.0, description="ilc_norm_optimal: weight w_e of the "
                                        "error norm ||e||^2 [1/(N m)^2].")
    weight_change: PositiveFloat = Field(0.01, description="ilc_norm_optimal: weight w_u of "
                                         "the input-change norm ||u_{h+1} - u_h||^2 "
                                         "[1/(N m)^2].")


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
    """Disturbances of the plant only (feltool.disturbances): the known model and the learner
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
        "step).")
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
    link: str | None = Field(None, description="URDF link whose mass is set (kind mass).")
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
        if motion:
            raise ValueError(f"'{', '.join(motion)}' change the motion; give them in an event "
                             f"of their own, without kind '{self.kind}'")
        need = {"slope": ["angle"], "payload": ["mass", "frame"], "mass": ["mass", "link"]}
        missing = [f for f in need[self.kind] if getattr(self, f) is None]
        if missing:
            raise ValueError(f"a '{self.kind}' event needs " + ", ".join(missing))
        return self

    @property
    def changes_world(self) -> bool:
        """Whether the event changes the simulated plant (else the motion)."""
        return self.kind is not None


class SweepConfig(Strict):
    """A grid for ``feltool sweep`` (ignored by ``feltool run``)."""

    grid: dict[str, list[Any]] = Field(default_factory=dict, description="Dotted config paths "
                                       "and the values to try, e.g. {learning.rates.weights: "
                                       "[0.1, 0.2]}; the product of all is run (at most "
                                       f"{MAX_SWEEP_POINTS} points).")


class SuccessConfig(Strict):
    """What counts as a seed that learned: ``feltool run`` exits 0 only when every seed does
    (and 1, with every result kept, when some seed diverged, fell or missed this)."""

    fb_ratio_max: PositiveFloat | None = Field(None, description="Largest allowed fb_final / "
        "fb_initial (the error signal's mean |feedback| in the last cycle over the first); "
        "default: no bound.")
    converged: bool = Field(False, description="Require a converged_cycle (below 5 % of the "
                            "initial feedback for good) by the last cycle.")


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
        "the compiled engine runs everything the config asks (feltool.compiled.unsupported), "
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
        if isinstance(s, list):
            repeated = sorted(x for x, n in Counter(s).items() if n > 1)
            if repeated:
                raise ValueError(f"seed {', '.join(map(str, repeated))} given more than once; "
                                 "each seed runs once (a repeat would be the same run again)")
        return s

    @model_validator(mode="before")
    @classmethod
    def _one_mechanical_phase(cls, data: Any) -> Any:
        """``primitives.phase: mechanical`` and ``walking.phase: mechanical`` are one setting:
        either one given alone sets the other."""
        if not isinstance(data, dict):
            return data
        prims, walking = data.get("primitives"), data.get("walking")
        if not isinstance(walking, dict) or (prims is not None and not isinstance(prims, dict)):
            return data
        prims = dict(prims or {})
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
        return out + self._phase_problems()

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


# -- loading --------------------------------------------------------------------------------------

def read_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping safely (no object construction), with errors that name the file."""
    try:
        size = Path(path).stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError([("", f"the file has {size} bytes; a config may have at most "
                                    f"{MAX_CONFIG_BYTES} (1 MiB)")], str(path))
        text = Path(path).read_text()
    except FileNotFoundError:
        raise ConfigError([("", "config file not found")], str(path)) from None
    except UnicodeDecodeError:
        raise ConfigError([("", "the file is binary (not UTF-8 text), not a YAML config")],
                          str(path)) from None
    except OSError as exc:
        raise ConfigError([("", f"cannot read config: {exc}")], str(path)) from None
    if "\x00" in text:
        raise ConfigError([("", "the file is binary (not UTF-8 text), not a YAML config")],
                          str(path))
    try:
        data = load_yaml(text)  # safe: no object construction, bounded depth and aliases
        duplicates = _duplicate_keys(yaml.compose(text, Loader=yaml.SafeLoader))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError([("", f"{where}not valid YAML ({problem})")], str(path)) from None
    except YamlBoundError as exc:
        raise ConfigError([("", f"refused: {exc}")], str(path)) from None
    if not isinstance(data, dict):
        raise ConfigError([("", "the config must be a YAML mapping of fields")], str(path))
    if duplicates:
        raise ConfigError(duplicates, str(path))
    return data


def _duplicate_keys(node, path: str = "") -> list[tuple[str, str]]:
    """Keys given twice in a mapping (plain PyYAML keeps the last one silently, so two roles
    for one joint would go unnoticed), with their YAML paths."""
    problems = []
    if isinstance(node, yaml.MappingNode):
        seen = set()
        for key_node, value_node in node.value:
            key = key_node.value
            where = f"{path}.{key}" if path else str(key)
            if key in seen:
                problems.append((where, f"given twice (line {key_node.start_mark.line + 1}); "
                                        "each key may appear once"))
            seen.add(key)
            problems += _duplicate_keys(value_node, where)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            problems += _duplicate_keys(item, f"{path}.{i}")
    return problems


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``a.b.c=VALUE`` overrides (VALUE parsed as YAML) to a raw config mapping."""
    for item in overrides:
        if "=" not in item:
            raise ConfigError([(item, "an override must look like a.b.c=VALUE")], "--set")
        key, raw = item.split("=", 1)
        parts = [p for p in key.strip().split(".") if p]
        if not parts:
            raise ConfigError([(item, "an override needs a field path before '='")], "--set")
        try:
            value = load_yaml(raw)
        except yaml.YAMLError:
            value = raw
        except YamlBoundError as exc:
            raise ConfigError([(key.strip(), f"refused: {exc}")], "--set") from None
        node = data
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError([(".".join(parts[: i + 1]),
                                    "cannot set a field inside a value that is not a mapping")],
                                  "--set")
            node = child
        node[parts[-1]] = value
    return data


# Pydantic puts the branch of a union (``int``, ``list[int]``, ``literal['a','b']``,
# ``function-after[...]``) into an error's location; those are not YAML keys.
_BRANCH = re.compile(r"^(int|float|str|bool|none|(list|dict|literal|tuple|function-\w+)\[.*\]"
                     r"|constrained-.*|[A-Z]\w*Config)$")


def _loc(loc: tuple) -> str:
    return ".".join(str(p) for p in loc if not (isinstance(p, str) and _BRANCH.match(p)))


_SCALAR_TYPES = {"int_type", "int_parsing", "float_type", "float_parsing", "string_type"}


def _pydantic_problems(exc: ValidationError) -> list[tuple[str, str]]:
    problems = []
    for err in exc.errors():
        loc = err["loc"]
        # a demo's kind is a tag of its (discriminated) union, not a YAML key: drop it
        loc = tuple(x for i, x in enumerate(loc)
                    if not (i and loc[i - 1] == "demo" and x in ("sine", "samples", "positions")))
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling; see docs/configuration.md)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        elif err["type"] in ("less_than_equal", "too_long") and \
                not isinstance(err.get("input"), dict):
            # feltool's upper bounds (feltool/bounds.py), stated with the value given
            bound = err.get("ctx", {})
            limit = bound.get("le", bound.get("max_length"))
            what = {"less_than_equal": "above", "too_long": "longer than"}[err["type"]]
            given = f"{len(err['input'])} items" if err["type"] == "too_long" else \
                str(err["input"])
            limit = f"{limit:g}" if isinstance(limit, float) else limit
            msg = f"{given} is {what} the limit {limit} (see docs/configuration.md)"
        problems.append((_loc(loc), msg))
    # A union (e.g. seeds: int | list) reports one error per branch: a list given where the
    # other branch wants a number is no news when the list branch says what is wrong.
    paths = [p for p, _ in problems]
    problems = [(p, m) for (p, m), err in zip(problems, exc.errors())
                if not (err["type"] in _SCALAR_TYPES and isinstance(err.get("input"), list | dict)
                        and any(q != p and q.startswith(p + ".") for q in paths))]
    seen, unique = set(), []
    for p in problems:
        if p[0] not in seen:
            seen.add(p[0])
            unique.append(p)
    return unique


def parse_config(data: dict[str, Any], source: str | None = None) -> ExperimentConfig:
    """Validate a raw mapping; raises :class:`ConfigError` listing every problem."""
    try:
        cfg = ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_pydantic_problems(exc), source) from None
    problems = cfg.problems()
    if problems:
        raise ConfigError(problems, source)
    return cfg


def config_to_yaml(cfg: ExperimentConfig, base_dir: Path | None = None) -> str:
    """The fully resolved config (defaults filled in) as YAML. With ``base_dir`` (the original
    config's directory), relative file paths (a URDF, package dirs) become absolute, so that the
    saved config works from anywhere (``feltool run RUN_DIR/config.yaml``, ``feltool view``)."""
    data = cfg.model_dump(mode="json")
    if base_dir is not None:
        robot = cfg.robot_source
        if (robot.endswith(".urdf") or "/" in robot) and not Path(robot).expanduser().is_absolute():
            robot = str((Path(base_dir) / robot).resolve())
            if isinstance(data["robot"], dict):
                data["robot"]["source"] = robot
            else:
                data["robot"] = robot
        data["package_dirs"] = [str((Path(base_dir) / d).resolve()) for d in data["package_dirs"]]
        for jc in data["joints"].values():
            demo = jc.get("demo") or {}
            if demo.get("csv") and not Path(demo["csv"]).expanduser().is_absolute():
                demo["csv"] = str((Path(base_dir) / demo["csv"]).resolve())
        plant = data.get("plant")
        if isinstance(plant, dict) and isinstance(plant.get("robot"), str) and \
                plant["robot"].endswith(".urdf") and not Path(plant["robot"]).is_absolute():
            plant["robot"] = str((Path(base_dir) / plant["robot"]).resolve())
    return yaml.safe_dump(data, sort_keys=False)
