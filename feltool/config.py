"""The experiment config: a YAML file validated by a pydantic schema.

Every field carries a description with its unit; ``docs/configuration.md`` is generated from this
schema (``python -m feltool.docgen``) and a test keeps the two in sync. Unknown keys are errors, so
a typo is never silently ignored, and every error names the YAML path that is wrong.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from feltool.errors import ConfigError

PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class SimConfig(Strict):
    """How the closed loop is simulated."""

    rate_hz: PositiveFloat = Field(100.0, description="Control and sampling rate in [Hz]; one "
                                   "feedforward/feedback sample per step.")
    substeps: int = Field(1, ge=1, le=1000, description="Integration steps per control step "
                          "(the torque is held constant over them).")
    integrator: Literal["semi_implicit_euler", "explicit_euler"] = Field(
        "semi_implicit_euler", description="Integration scheme of the forward model: "
        "semi-implicit (symplectic) Euler, v += dt a; q += dt v, or explicit Euler.")
    cycles: int = Field(200, ge=1, le=10_000_000, description="Learning cycles to run; one "
                        "cycle is one period of the rhythmic motion.")
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


class PrimitiveConfig(Strict):
    """Parameters of a rhythmic movement primitive (eq. 2.1-2.3)."""

    basis: int = Field(10, ge=1, le=1000, description="Number of von Mises basis functions N.")
    alpha_z: PositiveFloat = Field(25.0, description="Timing constant alpha_z of eq. 2.2 [-].")
    beta_z: PositiveFloat | None = Field(None, description="Timing constant beta_z [-]; "
                                         "default alpha_z / 4 (critically damped).")
    width: PositiveFloat | None = Field(None, description="Width h of the von Mises basis [-]; "
                                        "default N / 2.")
    amplitude: PositiveFloat = Field(1.0, description="Amplitude factor r of the forcing term.")


class PrimitiveOverride(Strict):
    """Per-joint override of the primitive defaults; unset fields keep the defaults."""

    basis: int | None = Field(None, ge=1, le=1000, description="Number of basis functions N.")
    alpha_z: PositiveFloat | None = Field(None, description="Timing constant alpha_z [-].")
    beta_z: PositiveFloat | None = Field(None, description="Timing constant beta_z [-].")
    width: PositiveFloat | None = Field(None, description="Basis width h [-].")
    amplitude: PositiveFloat | None = Field(None, description="Amplitude factor r [-].")


class SineDemo(Strict):
    """A demonstrated sine (optionally with higher harmonics), fitted into the joint's RMP by
    least squares (eq. 2.4): q(t) = mean + amplitude sin(w s + phase) + sum_k A_k sin(k w s + phi_k)
    with w = 2 pi / T, s = t - delay T and k = 2, 3, ... for the entries of ``harmonics``."""

    kind: Literal["sine"] = Field(description="Demonstration kind.")
    mean: FiniteFloat = Field(0.0, description="Mean (the RMP goal) in [rad].")
    amplitude: FiniteFloat = Field(description="Amplitude in [rad].")
    phase: FiniteFloat = Field(0.0, description="Phase offset in [rad] at the start of a cycle.")
    harmonics: list[tuple[FiniteFloat, FiniteFloat]] = Field(default_factory=list, description=
        "Higher harmonics k = 2, 3, ...: [amplitude in [rad], phase in [rad]] each.")
    delay: FiniteFloat = Field(0.0, description="Delay of the whole demonstration, as a "
                               "fraction of the period (e.g. 0.5 for a walker's other leg) [-].")


class Gains(Strict):
    """PD gains of a joint's feedback law (eq. 2.7 or §3.1)."""

    kp: NonNegFloat = Field(description="Proportional gain K_P in [N m/rad].")
    kd: NonNegFloat = Field(description="Derivative gain K_D in [N m s/rad].")


Vector3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


class Target(Strict):
    """What a stabilizing controller holds (§3.1): a joint angle; a link's absolute angle given
    as the sum of the joint angles from the base to that link (planar chains); or the
    orientation of any frame about a world axis (its torque then acts through the frame
    Jacobian on every joint that moves the frame)."""

    value: FiniteFloat = Field(description="Target value of the stabilized quantity in [rad].")
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

    init: Literal["random", "demo", "zero"] = Field("random", description="Initial weights: "
                                                   "random (from the seed), the demo's fit, or zero.")
    weight_scale: NonNegFloat = Field(0.3, description="Random initial weights ~ N(0, s^2) with "
                                      "s = weight_scale * max |w| over the demo-fitted primitives [-].")
    goal_spread: NonNegFloat = Field(0.3, description="Random initial goal uniform in goal_center "
                                     "+- goal_spread, in [rad].")
    goal_center: FiniteFloat | None = Field(None, description="Centre of the initial goal in [rad]; "
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
    demo: SineDemo | None = Field(None, description="Demonstration fitted into the RMP (eq. 2.4).")
    gains: Gains | None = Field(None, description="Feedback gains (track and stabilize).")
    target: Target | None = Field(None, description="Stabilized quantity (stabilize only).")
    learn: LearnConfig | None = Field(None, description="Learn this joint's RMP by FEL.")
    primitive: PrimitiveOverride | None = Field(None, description="Per-joint RMP settings.")
    posture: FiniteFloat = Field(0.0, description="Angle a locked joint is held at, in [rad].")

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
    width: PositiveFloat | None = Field(None, description="Width h of the phase basis [-] "
                                        "(phase_basis only); default basis / 2.")
    update: Literal["gradient", "gauss_newton"] = Field("gradient", description="gradient: "
        "eq. 3.4, theta_m += rate * sum_k Phi_k^T e_k; gauss_newton: the Levenberg-Marquardt "
        "step rate * (Phi^T Phi + lambda I)^-1 Phi^T e over the cycle (per_cycle only; fast "
        "alone, but it interferes with trajectory FEL).")
    step: Literal["per_cycle", "per_step"] = Field("per_cycle", description="Update once per "
        "cycle or after every control step (per_step: gradient only).")
    rate: NonNegFloat = Field(description="Learning rate alpha_m (required; its unit depends on "
        "the features): gradient: per sample and cycle, in [theta_m unit / (N m)^2] -- stable "
        "below 2 / (largest eigenvalue of sum_k Phi_k^T Phi_k); gauss_newton: the fraction of the "
        "Levenberg-Marquardt step [-]. See docs/model_learning.md.")
    damping: PositiveFloat = Field(1.0e-6, description="Levenberg-Marquardt damping, relative "
                                   "to the mean diagonal of Phi^T Phi [-]; directions the motion "
                                   "does not excite are then left unchanged.")
    jacobian: Literal["learned", "nominal"] = Field("learned", description="Inverse model whose "
        "derivatives the trajectory learner's Jacobian uses when both learn: learned = the known "
        "model plus the current correction (chain rule through Phi theta_m; regressor features "
        "give RNEA with pi_model + theta_m; on the joints the correction drives), nominal = the "
        "known model alone.")


class BodyOverride(Strict):
    """The plant's physical parameters of one body: the rigid body moved by a joint (with every
    link welded to it). Unset fields keep the model's values."""

    mass_scale: PositiveFloat | None = Field(None, description="Scale mass and rotational "
        "inertia together (a uniformly denser body; the centre of mass stays) [-].")
    mass: PositiveFloat | None = Field(None, description="Mass in [kg] (rotational inertia "
                                       "unchanged unless `inertia` is given).")
    com: list[FiniteFloat] | None = Field(None, min_length=3, max_length=3, description="Centre "
                                          "of mass in the joint's frame, [x, y, z] in [m].")
    inertia: list[FiniteFloat] | None = Field(None, min_length=6, max_length=6, description=""
        "Rotational inertia about the centre of mass, [ixx, ixy, ixz, iyy, iyz, izz] in "
        "[kg m^2] (URDF order).")

    @model_validator(mode="after")
    def _one_mass(self) -> BodyOverride:
        if self.mass_scale is not None and self.mass is not None:
            raise ValueError("give 'mass_scale' or 'mass', not both")
        return self


class Payload(Strict):
    """A rigid payload fixed to a frame of the plant (e.g. a tool at the arm's tip)."""

    frame: str = Field(min_length=1, description="URDF link (or Pinocchio frame) it is fixed to.")
    mass: PositiveFloat = Field(description="Mass in [kg].")
    com: list[FiniteFloat] = Field([0.0, 0.0, 0.0], min_length=3, max_length=3,
                                   description="Centre of mass in that frame, [x, y, z] in [m].")
    inertia: list[FiniteFloat] = Field([0.0] * 6, min_length=6, max_length=6, description=""
        "Rotational inertia about its centre of mass, [ixx, ixy, ixz, iyy, iyz, izz] in "
        "[kg m^2]; default a point mass.")


class JointFriction(Strict):
    """Joint friction of the plant, tau_f = viscous * v + coulomb * tanh(v / coulomb_velocity),
    opposing the motion (the known model has none)."""

    viscous: NonNegFloat = Field(0.0, description="Viscous damping in [N m s/rad].")
    coulomb: NonNegFloat = Field(0.0, description="Coulomb friction level in [N m].")
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

    weights: NonNegFloat = Field(0.15, description="Rate for the RMP weights (gradient) or the "
                                 "fraction of the Levenberg-Marquardt step taken (gauss_newton).")
    goal: NonNegFloat = Field(2.0e-5, description="Rate for the RMP goal (always gradient). The "
                              "update sums over a cycle's samples, so rates scale with rate_hz.")


class LearningConfig(Strict):
    """Feedback error learning of the RMP parameters (eq. 3.6)."""

    error: Literal["stabilizing", "all_feedback"] | list[str] = Field(
        "stabilizing", description="Error signal e: the stabilizing feedback (fully actuated "
        "robots), all feedback (underactuated robots), or a list of joints whose feedback counts.")
    update: Literal["gradient", "gauss_newton"] = Field("gradient", description="gradient: eq. "
        "3.6; gauss_newton: a Levenberg-Marquardt step on the weights (goal stays on gradient).")
    step: Literal["per_cycle", "per_step"] = Field("per_cycle", description="Update once per "
        "cycle (the RMP is then reset onto its new limit cycle) or after every control step.")
    rates: Rates = Field(default_factory=Rates, description="Learning rates.")
    damping: PositiveFloat = Field(1.0e-2, description="Levenberg-Marquardt damping, relative to "
                                   "the mean diagonal of J^T J [-].")
    sensitivity: Literal["exact", "finite_difference", "casadi"] = Field("exact", description=
        "How d u_ff / d theta is computed: exact (RMP sensitivity x Pinocchio's RNEA "
        "derivatives), the thesis's numerical differentiation, or CasADi's algorithmic "
        "differentiation through the RMP and a symbolic RNEA.")
    fd_epsilon: PositiveFloat = Field(1.0e-6, description="Finite-difference step, relative "
                                      "to max(1, |theta_i|) [-].")
    impact_window_s: NonNegFloat = Field(0.0, description="Walkers only: leave the error "
        "signal's samples within this time after every impact out of the update (the impact's "
        "velocity jump makes a feedback spike that no smooth RMP can remove) [s]; 0 = off.")
    model: ModelLearningConfig | None = Field(None, description="Also learn an inverse-model "
        "correction by classic FEL (docs/model_learning.md); default off.")


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


class WalkingConfig(Strict):
    """Hybrid walking: a pinned stance foot, steps ending on a guard, stance/swing relabelling.

    Coordinates: ``absolute`` gives each joint's link angle from the vertical in stance-relative
    labels (theta = A q). Each joint's RMP describes, in these absolute angles, the link that the
    joint moves in the cycle's first step; after every impact the ``swap`` pair is exchanged
    (X+ = [q2, q1, q3, ...] in the thesis's absolute angles)."""

    absolute: dict[str, list[str]] = Field(min_length=1, description="For every joint: the joints "
        "whose angles add up to its link's absolute angle (stance-relative labels).")
    swap: tuple[str, str] = Field(description="The two joints whose absolute angles (and "
                                  "velocities) are exchanged at an impact: stance and swing leg.")
    impact: Literal["relabel", "rigid"] = Field("relabel", description="relabel: the thesis's "
        "switch of labels, velocities kept; rigid: a perfectly inelastic foot impact (planar "
        "impact map solved in the model with a free base), then relabelling.")
    contact_frame: str | None = Field(None, description="Frame of the swing foot (URDF link), "
                                      "needed by impact: rigid.")
    steps_per_cycle: int = Field(2, ge=1, le=100, description="Steps (impacts) per cycle.")
    guard: Guard = Field(description="When a step ends.")
    fall: FallCheck | None = Field(None, description="When the walker has fallen.")
    foot_placement: FootPlacement | None = Field(None, description="Offset a link's reference by "
        "another link's tracking error over each step (step-to-step stabilisation, used with "
        "impact: rigid); default off.")
    poincare: bool = Field(True, description="After learning, find the step-to-step map's fixed "
                           "point and its eigenvalues (summary.json: poincare).")


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
    """A change of the world at the start of a learning cycle; the known model stays as it was,
    only the simulated plant changes, so FEL has to adapt."""

    cycle: int = Field(ge=1, description="Learning cycle at whose start the change happens.")
    kind: Literal["slope", "payload", "mass"] = Field(description="slope: tilt gravity (the "
        "ground) by `angle` about the world's y axis; payload: add a point mass `mass` at "
        "`frame`; mass: set the mass of the body moved by the joint of `link` to `mass` "
        "(its inertia scaled alike).")
    angle: FiniteFloat | None = Field(None, description="Slope angle in [rad] (kind slope); "
                                      "positive tilts gravity towards +x (downhill ahead).")
    mass: NonNegFloat | None = Field(None, description="Mass in [kg] (payload, mass).")
    frame: str | None = Field(None, description="URDF link/frame carrying the payload.")
    link: str | None = Field(None, description="URDF link whose mass is set (kind mass).")

    @model_validator(mode="after")
    def _fields(self) -> EventConfig:
        need = {"slope": ["angle"], "payload": ["mass", "frame"], "mass": ["mass", "link"]}
        missing = [f for f in need[self.kind] if getattr(self, f) is None]
        if missing:
            raise ValueError(f"a '{self.kind}' event needs " + ", ".join(missing))
        return self


class SweepConfig(Strict):
    """A grid for ``feltool sweep`` (ignored by ``feltool run``)."""

    grid: dict[str, list[Any]] = Field(default_factory=dict, description="Dotted config paths "
                                       "and the values to try, e.g. {learning.rates.weights: "
                                       "[0.1, 0.2]}; the product of all is run.")


class SuccessConfig(Strict):
    """What counts as a seed that learned: ``feltool run`` exits 0 only when every seed does
    (and 1, with every result kept, when some seed diverged, fell or missed this)."""

    fb_ratio_max: PositiveFloat | None = Field(None, description="Largest allowed fb_final / "
        "fb_initial (the error signal's mean |feedback| in the last cycle over the first); "
        "default: no bound.")
    converged: bool = Field(False, description="Require a converged_cycle (below 5 % of the "
                            "initial feedback for good) by the last cycle.")


class ExperimentConfig(Strict):
    """One FEL experiment: a robot, the roles of its joints, and how to learn."""

    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$",
                      description="Experiment name; used for the run directory.")
    description: str = Field("", description="Free text shown in summaries.")
    robot: str = Field(min_length=1, description="Bundled robot name, a URDF path (relative to "
                       "the config file), or example-robot-data:NAME.")
    package_dirs: list[str] = Field(default_factory=list, description="Directories searched for "
                                    "package:// mesh paths of a URDF file (relative to the "
                                    "config file).")
    gravity: FiniteFloat | list[FiniteFloat] = Field(9.8, description="Gravity in [m/s^2]: a "
        "magnitude along the world's -z, or a 3-vector. The thesis uses 9.8.")
    backend: Literal["pinocchio", "casadi", "compiled"] = Field("pinocchio", description=
        "Known models: Pinocchio; CasADi symbolic expressions built from the same model; or "
        "compiled: a whole learning cycle generated to C and compiled (cached on disk).")
    period_s: PositiveFloat = Field(description="Period T of the rhythmic motion in [s].")
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
    seeds: int | list[Annotated[int, Field(ge=0)]] = Field(20, description="Number of seeds "
                                                          "(0..n-1) or an explicit list.")
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
        if isinstance(s, int) and s < 1:
            raise ValueError("needs at least one seed")
        if isinstance(s, list) and not s:
            raise ValueError("needs at least one seed")
        return s

    def problems(self) -> list[tuple[str, str]]:
        """Checks across fields, as ``(yaml_path, message)`` pairs."""
        steps = self.period_s * self.sim.rate_hz
        if abs(steps - round(steps)) > 1e-9 * max(1.0, steps) or round(steps) < 2:
            return [("period_s", f"period_s * sim.rate_hz = {steps:g} samples per cycle; it "
                                 "must be a whole number of at least 2")]
        bases = {"primitives.basis": self.primitives.basis}
        for name, jc in self.joints.items():
            if jc.primitive is not None and jc.primitive.basis is not None:
                bases[f"joints.{name}.primitive.basis"] = jc.primitive.basis
        return [(where, f"{basis} basis functions but only {round(steps)} samples per cycle "
                        "(period_s * sim.rate_hz); use at most that many")
                for where, basis in bases.items() if basis > round(steps)]

    @property
    def seed_list(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)

    @property
    def dt(self) -> float:
        """Control step in [s]."""
        return 1.0 / self.sim.rate_hz

    @property
    def steps_per_cycle(self) -> int:
        return int(round(self.period_s * self.sim.rate_hz))


# -- loading --------------------------------------------------------------------------------------

def read_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping safely (no object construction), with errors that name the file."""
    try:
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
        data = yaml.safe_load(text)  # safe: no object construction
        duplicates = _duplicate_keys(yaml.compose(text, Loader=yaml.SafeLoader))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError([("", f"{where}not valid YAML ({problem})")], str(path)) from None
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
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            value = raw
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


def _pydantic_problems(exc: ValidationError) -> list[tuple[str, str]]:
    problems = []
    for err in exc.errors():
        loc = err["loc"]
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling; see docs/configuration.md)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        problems.append((_loc(loc), msg))
    # A union (e.g. seeds: int | list) reports one error per branch; keep one per path.
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
        robot = data["robot"]
        if (robot.endswith(".urdf") or "/" in robot) and not Path(robot).expanduser().is_absolute():
            data["robot"] = str((Path(base_dir) / robot).resolve())
        data["package_dirs"] = [str((Path(base_dir) / d).resolve()) for d in data["package_dirs"]]
        plant = data.get("plant")
        if isinstance(plant, dict) and isinstance(plant.get("robot"), str) and \
                plant["robot"].endswith(".urdf") and not Path(plant["robot"]).is_absolute():
            plant["robot"] = str((Path(base_dir) / plant["robot"]).resolve())
    return yaml.safe_dump(data, sort_keys=False)
