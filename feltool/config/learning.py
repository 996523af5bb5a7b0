"""The ``learning:`` section: the error signal, the update (FEL, ILC, baseline), its rates,
classic FEL of the model.
"""

from __future__ import annotations

from typing import Literal

from pydantic import (
    Field,
    model_validator,
)

from feltool.bounds import (
    MAX_DAMPING,
    MAX_RATE,
    MAX_WIDTH,
)
from feltool.config.base import NonNegFloat, PositiveFloat, Strict

#: ``learning.update`` values feedback error learning runs (eq. 3.6,
#: :class:`feltool.learning.fel.FeedbackErrorLearner`); the others (ILC, the feedback-only
#: baseline) have their own cycle runner (:mod:`feltool.learning.ilc`). Here, in the schema's
#: layer, so that the config's own checks and the learners read the same names.
FEL_UPDATES = ("gradient", "gauss_newton")


class ModelLearningConfig(Strict):
    """Classic (Kawato) feedback error learning of an inverse-model correction (eq. 2.8, 3.4):
    u_ff = RNEA_model(q_d, qd_d, qdd_d) + S_m Phi(q_d, qd_d, qdd_d) theta_m, with the feedback of
    the error joints S_m (default: every actuated joint) as the error signal."""

    features: Literal["regressor", "phase_basis", "none"] = Field("regressor", description=""
        "Features Phi: regressor = Pinocchio's joint-torque regressor, so theta_m are "
        "corrections of the 10 inertial parameters per body [m, m c, I at the joint frame "
        "origin]; phase_basis = normalised von Mises functions of the phase, one set per "
        "joint, theta_m in [N m]; none = no model correction (physical walkers: the motor "
        "biases alone).")
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
    motor_bias: NonNegFloat = Field(0.0, le=1.0, description="Physical walkers: also learn a "
        "constant torque per motor (stance-relative labels), its step this fraction of the "
        "cycle's Levenberg-Marquardt step (alone: of the cycle's mean motor-space error) [-]; "
        "independent of rate_hz, period and basis; 0 = none (docs/biped.md).")
    slope: NonNegFloat = Field(0.0, le=1.0, description="Physical walkers: also learn the "
        "ground slope the known model does not know (gravity tilted about y, downhill along +x) "
        "[rad], its step this fraction of the cycle's Levenberg-Marquardt step [-]; 0 = none "
        "(docs/biped.md).")
    jacobian: Literal["learned", "nominal"] = Field("learned", description="Inverse model whose "
        "derivatives the trajectory learner's Jacobian uses when both learn: learned = the known "
        "model plus the current correction (chain rule through Phi theta_m; regressor features "
        "give RNEA with pi_model + theta_m; on the joints the correction drives), nominal = the "
        "known model alone.")


class RedesignConfig(Strict):
    """Physical walkers with ``learning.model``: online gait re-acquisition. During the run the
    gait is re-designed (feltool/gait/design.py, IPOPT) on the known model corrected by what
    the model learner identified (its inertial parameters, projected to physically consistent
    ones, and its ground slope), with these design options; the run continues on the new
    reference at the cycle's end (docs/biped.md, "Online gait re-acquisition")."""

    identify: Literal["motion", "model"] = Field("motion", description="The world the gait "
        "is re-designed in: motion = identified from the last cycle's measured motion and "
        "applied torques in the directions the stance foot's force does not act in (the "
        "rotation about the foot included); model = the model learner's own correction and "
        "slope (learned from the motor-space feedback, which does not see the rotation about "
        "the foot: docs/biped.md).")
    every_s: PositiveFloat = Field(10.0, le=1.0e6, description="Time walked between two "
        "re-designs (and before the first) [s]; a re-design happens at the end of the first "
        "cycle after it.")
    min_mass_change: NonNegFloat = Field(0.01, le=1.0, description="Re-design only when the "
        "identified total mass differs from the current design's by more than this fraction "
        "of the known total mass [-] ... ")
    min_slope_change_rad: NonNegFloat = Field(0.002, le=1.0, description="... or the "
        "identified ground slope from the design's by more than this [rad], or the identified "
        "centre of mass (the walker standing) from the design's by more than "
        "min_com_change_m.")
    min_com_change_m: NonNegFloat = Field(0.002, le=1.0, description="See "
        "min_slope_change_rad [m].")
    speed_m_s: PositiveFloat | None = Field(None, le=100.0, description="The design's mean "
        "speed [m/s] (give it or step_length_m, as feltool gait --speed).")
    step_length_m: PositiveFloat | None = Field(None, le=100.0, description="The design's step "
        "length [m] (feltool gait --step-length).")
    duration_s: PositiveFloat | None = Field(None, le=100.0, description="The design's step "
        "duration [s] (default period_s / walking.steps_per_cycle).")
    torso_rad: float | None = Field(None, ge=-1.6, le=1.6, description="The torso's mean "
        "pitch [rad] (default its stabilize target).")
    friction_margin: PositiveFloat = Field(0.85, le=1.0, description="Design within this "
        "times walking.friction [-] (feltool gait --friction-margin).")
    normal_force_margin: NonNegFloat = Field(0.05, le=10.0, description="Least normal force "
        "this times m g above walking.normal_force_min [-] (feltool gait "
        "--normal-force-margin).")
    knots: int = Field(40, ge=4, le=1000, description="Collocation intervals per step.")
    verify_steps: int = Field(4, ge=2, le=1000, description="Steps the new design walks in "
        "the identified world before its orbit is closed (feltool gait --verify-steps).")
    blend_cycles: int = Field(1, ge=1, le=1000, description="Cycles over which the reference "
        "moves from the old design to the new one, linearly in phase (the k-th of them walks "
        "k/blend_cycles of the way; 1: the new design at once). A walker whose new gait is far "
        "from the old one may slide or lift a foot at a sudden switch.")
    max_failures: int = Field(5, ge=1, le=1000, description="Stop re-designing after this "
        "many failed designs (each keeps the old reference; counted in the summary).")

    @model_validator(mode="after")
    def _one_length(self):
        if (self.speed_m_s is None) == (self.step_length_m is None):
            raise ValueError("give exactly one of speed_m_s and step_length_m")
        return self


class Rates(Strict):
    """Learning rates alpha of eq. 3.6 in physical units (feltool.learning.rates): the rates of
    the mean over the cycle, the weights' divided by the basis's gain, so that one value means
    the same step at any sim.rate_hz, period_s and primitives.basis."""

    weights: NonNegFloat = Field(50.0, le=MAX_RATE, description="Rate for the RMP weights of "
        "the gradient step (update: gradient): Delta w = rates.weights / kappa_0 * mean over "
        "the cycle of J_w^T e, kappa_0 the basis's gain (docs/theory.md, eq. 3.6) [rad/(N m)^2 "
        f"per cycle]; independent of rate_hz, period_s and basis; at most {MAX_RATE:g}.")
    goal: NonNegFloat = Field(2.0e-3, le=MAX_RATE, description="Rate for the RMP goal "
        "(always the gradient step): Delta g = rates.goal * mean over the cycle of J_g^T e "
        f"[rad/(N m)^2 per cycle]; independent of rate_hz and period_s; at most {MAX_RATE:g}.")
    gauss_newton: NonNegFloat = Field(1.0, le=MAX_RATE, description="update: gauss_newton: "
        "the fraction of the Levenberg-Marquardt step taken on the weights [-] (invariant to "
        f"the sampling and the basis by construction); at most {MAX_RATE:g}.")


class LearningConfig(Strict):
    """Feedback error learning of the RMP parameters (eq. 3.6)."""

    error: Literal["stabilizing", "all_feedback"] | list[str] = Field(
        "stabilizing", description="Error signal e: the stabilizing feedback (fully actuated "
        "robots), all feedback (underactuated robots), or a list of joints whose feedback counts.")
    update: Literal["gradient", "gauss_newton", "ilc_p", "ilc_norm_optimal", "feedback_only"] = \
        Field("gauss_newton", description="gauss_newton (default, the fastest to converge on "
              "the shipped configs): a Levenberg-Marquardt step on the weights (rates."
              "gauss_newton; goal stays on gradient); gradient: the thesis's eq. 3.6 "
              "(rates.weights); ilc_p: P-type ILC of a per-sample "
              "feedforward torque with a zero-phase Q filter; ilc_norm_optimal: norm-optimal ILC "
              "on the lifted cycle model of the known model; feedback_only: no learning (the "
              "baseline). The ILC settings are in `ilc` (docs/comparison.md).")
    step: Literal["per_cycle", "per_step"] = Field("per_cycle", description="Update once per "
        "cycle (the RMP is then reset onto its new limit cycle) or after every control step.")
    rates: Rates = Field(default_factory=Rates, description="Learning rates.")
    damping: PositiveFloat = Field(1.0e-2, le=MAX_DAMPING, description="Levenberg-Marquardt "
                                   "damping, relative to the mean diagonal of J^T J [-]; at most "
                                   f"{MAX_DAMPING:g}.")
    fit: Literal["closed_loop", "feedforward"] = Field("closed_loop", description="What the "
        "Gauss-Newton step fits to the error feedback (arms learning per cycle): closed_loop "
        "(default): the change of the error feedback the known model's closed loop predicts, "
        "the lifted closed-loop map G times d u_ff / d theta along the desired trajectory "
        "(norm-optimal; invariant to rate_hz, period_s and basis; feltool.learning.loop_map); "
        "feedforward: the feedforward's change d u_ff / d theta itself (the step before, "
        "which assumes the feedback reports the feedforward's error at once and in full). "
        "Walkers, per_step learning, inverse-model learning (learning.model), cycles of changing "
        "length (period events, an adaptive phase, a period of no whole number of steps) and "
        "update: gradient use feedforward.")
    q_filter_hz: PositiveFloat | None = Field(None, description="fit: closed_loop: learn only "
        "the cycle's harmonics at or below this frequency [Hz] (a zero-phase projection of the "
        "fit over one cycle; the parameters' directions that only move higher harmonics are "
        "left to the damping); null (default): every harmonic the closed loop passes. Python "
        "engine only.")
    remove_transient: bool = Field(True, description="fit: closed_loop: fit the step to the "
        "periodic part of the cycle's error feedback, without the transient of the cycle "
        "starting where the one before ended (off the periodic state of the new parameters; "
        "estimated from the cycle's change of state through the linearized loop, "
        "feltool.learning.loop_map.transient_error). Matters where the loop does not forget its "
        "start within a period (period 0.5 s on the standard arm, seeds 0-9: 5-21 cycles to 5 % "
        "without, 3-4 with); false: the measured error as it is.")
    safeguard: bool = Field(True, description="Undo a learning step that makes the next "
        "cycle's mean error feedback exceed safeguard_growth times that of the cycle whose "
        "update it is, or diverge: the parameters before the step are restored and the step halved (a trust "
        "region); a seed diverges only when the step fell below safeguard_min_step "
        "(feltool.runs.safeguard). false: the plain eq. 3.6 (the thesis's runs).")
    safeguard_growth: float = Field(2.0, gt=1.0, le=1.0e6, description="The factor of growth "
        "of the mean error feedback from one cycle to the next that rejects the step between "
        "them [-].")
    safeguard_min_step: float = Field(1.0e-3, gt=0.0, lt=1.0, description="The smallest step "
        "scale (halved at every rejected step) before the seed counts as diverged [-].")
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
    redesign: RedesignConfig | None = Field(None, description="Physical walkers with "
        "learning.model: re-design the gait online on the identified model (docs/biped.md, "
        "\"Online gait re-acquisition\"); default off.")
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
    initial RMP (feltool.learning.ilc); on a physical walker a motor torque per RMP sample, added to the
    allocated command (feltool.engines.ilc_walker)."""

    gain: NonNegFloat = Field(1.0, description="ilc_p: learning gain L of "
                              "u_{h+1} = Q(u_h + L e_h) [-] (error and input are torques at the "
                              "same instant, so L is independent of the sampling).")
    lead_s: NonNegFloat = Field(0.0, le=1.0e3, description="ilc_p: phase lead of the error "
                                "in [s] (u_h(t) is corrected by e_h(t + lead), rounded to whole "
                                "samples; time, so that it means the same at any rate_hz).")
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
