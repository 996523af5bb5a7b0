"""Build an experiment from a config, and run it seed by seed.

Building is separate from running: :func:`load_experiment` returns an :class:`Experiment` whose
robot, primitives, feedback laws and learner can be inspected before anything is simulated;
:func:`run_seed` runs one seed's learning cycles and returns its metrics.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from feltool.checkpoint import Checkpointer, Interrupted, stop_requested
from feltool.config import ExperimentConfig, apply_overrides, parse_config, read_yaml
from feltool.control import FeedbackLaw, FrameAngle, wrap
from feltool.dynamics import Dynamics, make_dynamics
from feltool.errors import ConfigError, FeltoolError, RobotError
from feltool.events import changed_model, check_events, plant_for_cycle
from feltool.fel import FeedbackErrorLearner, feedforward
from feltool.hybrid import Allocation, HybridLoop, Walker
from feltool.model_fel import ModelLearner, PhaseBasisFeatures, RegressorFeatures
from feltool.plant import make_plant, plant_problems, plant_robot
from feltool.rmp import PrimitiveSet, RhythmicPrimitive, sine_demo
from feltool.robot import Robot, data_dir, load_robot
from feltool.simulate import ClosedLoop, CycleLog, Limits


@dataclass
class Experiment:
    """Everything one experiment needs, built from its config; inspect before running.

    Attributes:
        config: The validated config.
        robot: The robot with locked joints removed (the known model).
        dynamics: Known inverse/forward models of ``robot``.
        joints: Joint names in velocity-index order.
        primitives: The forward trajectory generator (one RMP per joint).
        theta_demo: Parameters of every joint's RMP before random initialisation ``(P,)``.
        law: Feedback laws.
        loop: Closed-loop simulator.
        learner: The FEL learner.
        init: Per learned joint: ``(slice, weight std, goal centre, goal spread, kind)``.
        hybrid: The step-by-step loop for walkers and allocated motors (else None).
        plant: The simulated robot's dynamics (``loop.dynamics``); ``dynamics`` itself unless
            the config has a ``plant:`` block.
        model_learner: Classic FEL of an inverse-model correction (``learning.model``), or None.
    """

    config: ExperimentConfig
    robot: Robot
    dynamics: Dynamics
    joints: list[str]
    primitives: PrimitiveSet
    theta_demo: np.ndarray
    law: FeedbackLaw
    loop: ClosedLoop
    learner: FeedbackErrorLearner
    init: list[tuple[slice, float, float, float, str]] = field(default_factory=list)
    source: Path | None = None
    hybrid: HybridLoop | None = None
    plant: Dynamics | None = None
    model_learner: ModelLearner | None = None

    @property
    def learned_joints(self) -> list[str]:
        return [name for name, jc in self.config.joints.items() if jc.learn is not None]

    @property
    def stabilized_joints(self) -> list[str]:
        return [n for n in self.joints if self.config.joints[n].role == "stabilize"]

    @property
    def error_joints(self) -> list[str]:
        return [n for n, m in zip(self.joints, self.learner.error_mask) if m > 0]

    def compiled_cycle(self):
        """The compiled learning cycle (built and compiled on first use, cached on disk)."""
        if getattr(self, "_compiled", None) is None:
            from feltool.compiled import CompiledCycle

            self._compiled = CompiledCycle(self)
        return self._compiled

    def initial_parameters(self, seed: int) -> np.ndarray:
        """RMP parameters at the start of learning; random draws come from ``seed`` only."""
        rng = np.random.default_rng(seed)
        theta = self.theta_demo.copy()
        for sl, w_std, g_center, g_spread, kind in self.init:
            nw = sl.stop - sl.start - 1
            if kind == "random":
                theta[sl.start:sl.stop - 1] = rng.normal(0.0, w_std, nw)
                theta[sl.stop - 1] = g_center + rng.uniform(-g_spread, g_spread)
            elif kind == "zero":
                theta[sl] = 0.0
                theta[sl.stop - 1] = g_center
        return theta

    def split_parameters(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """``{"<joint>.weights": w, "<joint>.goal": g}`` for the learned joints."""
        out = {}
        for name in self.learned_joints:
            sl = self.primitives.slices[self.joints.index(name)]
            out[f"{name}.weights"] = theta[sl.start:sl.stop - 1].copy()
            out[f"{name}.goal"] = np.array(theta[sl.stop - 1])
        return out


def resolve_config_path(spec: str | Path) -> Path:
    """A config path, or the name of a bundled config (``two_link_standard``)."""
    path = Path(spec)
    if path.is_file():
        return path
    bundled = data_dir("configs") / (path.name if path.suffix else f"{path.name}.yaml")
    if not path.exists() and bundled.is_file() and len(path.parts) <= 2:
        return bundled
    raise ConfigError([("", "config file not found")], str(spec))


def load_experiment(path: str | Path, overrides: list[str] | None = None) -> Experiment:
    """Read, validate and build an experiment (raises :class:`ConfigError` listing problems)."""
    path = resolve_config_path(path)
    raw = apply_overrides(read_yaml(path), list(overrides or []))
    return build_experiment(raw, source=path)


def validate(raw: dict[str, Any], source: Path | None = None) -> tuple[ExperimentConfig, Robot]:
    """Check a raw config completely: schema, robot, and every joint name against the robot.

    All problems are collected into one :class:`ConfigError`, one line per problem.
    """
    src = str(source) if source else None
    problems: list[tuple[str, str]] = []
    cfg = None
    try:
        cfg = parse_config(raw, src)
    except ConfigError as exc:
        problems += exc.problems
    robot = None
    if isinstance(raw.get("robot"), str) and raw["robot"]:
        try:
            dirs = raw.get("package_dirs") if isinstance(raw.get("package_dirs"), list) else []
            robot = load_robot(raw["robot"], base_dir=source.parent if source else None,
                               package_dirs=[str(d) for d in dirs])
        except RobotError as exc:
            problems.append(("robot", str(exc)))
    if robot is not None:
        problems += _name_problems(raw, robot)
        if cfg is not None and cfg.plant is not None:
            problems += plant_problems(cfg.plant, robot, source.parent if source else None)
    if problems:
        # The same path may be reported by the schema and by the name checks; keep both texts.
        raise ConfigError(_dedupe(problems), src)
    return cfg, robot


def _dedupe(problems):
    seen, out = set(), []
    for p in problems:
        if p not in seen:
            seen.add(p)
            out.append(p)
    return out


def _name_problems(raw: dict[str, Any], robot: Robot) -> list[tuple[str, str]]:
    known = robot.joint_names
    listing = ", ".join(known)
    joints = raw.get("joints")
    problems = []
    if not isinstance(joints, dict):
        return problems
    for name, jc in joints.items():
        if name not in known:
            problems.append((f"joints.{name}", f"robot '{robot.name}' has no joint '{name}' "
                                               f"(its joints: {listing})"))
            continue
        if robot.model.joints[robot.joint_id(name)].nv != 1:
            problems.append((f"joints.{name}", "feltool roles need a one-degree-of-freedom joint"))
        target = jc.get("target") if isinstance(jc, dict) else None
        frame = target.get("frame") if isinstance(target, dict) else None
        if isinstance(frame, str) and not robot.model.existFrame(frame):
            frames = ", ".join(f.name for f in robot.model.frames if f.name != "universe")
            problems.append((f"joints.{name}.target.frame", f"robot '{robot.name}' has no "
                                                            f"frame '{frame}' (its frames: {frames})"))
        links = target.get("link_angle") if isinstance(target, dict) else None
        if isinstance(links, list):
            for i, other in enumerate(links):
                if other not in known:
                    problems.append((f"joints.{name}.target.link_angle.{i}",
                                     f"robot '{robot.name}' has no joint '{other}' (its joints: {listing})"))
                elif other in joints and isinstance(joints[other], dict) and \
                        joints[other].get("role") == "locked":
                    problems.append((f"joints.{name}.target.link_angle.{i}",
                                     f"joint '{other}' is locked"))
            if name not in links:
                problems.append((f"joints.{name}.target.link_angle",
                                 f"must include the stabilizing joint '{name}' itself"))
    error = (raw.get("learning") or {}).get("error") if isinstance(raw.get("learning"), dict) else None
    if isinstance(error, list):
        for i, other in enumerate(error):
            if other not in known:
                problems.append((f"learning.error.{i}", f"robot '{robot.name}' has no joint "
                                                        f"'{other}' (its joints: {listing})"))
            elif other not in joints:
                problems.append((f"learning.error.{i}", f"joint '{other}' is not configured "
                                                        "(add it under joints)"))
    elif error == "stabilizing" or error is None:
        if not any(isinstance(jc, dict) and jc.get("role") == "stabilize" for jc in joints.values()):
            problems.append(("learning.error", "'stabilizing' needs at least one joint with "
                                               "role: stabilize"))
    return problems


def build_experiment(raw: dict[str, Any], source: Path | None = None) -> Experiment:
    """Build an :class:`Experiment` from a raw config mapping."""
    cfg, full_robot = validate(raw, source)
    locked = {n: 0.0 for n in full_robot.joint_names if n not in cfg.joints}
    locked.update({n: jc.posture for n, jc in cfg.joints.items() if jc.role == "locked"})
    robot = reduce_robot(full_robot, locked)
    robot.set_gravity(cfg.gravity)
    dynamics = make_dynamics(robot.model, "casadi" if cfg.backend == "casadi" else "pinocchio")
    nv = robot.model.nv
    joints = [""] * nv
    for name in robot.joint_names:
        joints[robot.v_index(name)] = name
    if robot.model.nq != nv:
        raise ConfigError([("robot", "after locking the unconfigured joints the model still has "
                                     "joints with more than one coordinate; lock them or list "
                                     "them under joints")], str(source) if source else None)

    # Primitives: fit demos (eq. 2.4); learned joints get their random start per seed.
    dt, T = cfg.dt, cfg.period_s
    prims: dict[int, RhythmicPrimitive] = {}
    thetas: dict[int, np.ndarray] = {}
    fine_t = np.linspace(0.0, T, 2000, endpoint=False)
    for i, name in enumerate(joints):
        jc = cfg.joints[name]
        settings = cfg.primitives.model_dump()
        if jc.primitive is not None:
            settings.update({k: v for k, v in jc.primitive.model_dump().items() if v is not None})
        prim = RhythmicPrimitive(settings["basis"], T, dt, settings["alpha_z"], settings["beta_z"],
                                 settings["width"], settings["amplitude"])
        prims[i] = prim
        if jc.demo is not None:
            d = jc.demo
            q, v, a = sine_demo(d.mean, d.amplitude, T, d.phase, fine_t, d.harmonics, d.delay)
            thetas[i] = prim.fit(q, v, a, 2.0 * np.pi * fine_t / T, goal=d.mean)
        else:
            thetas[i] = np.zeros(prim.n_params)
    primitives = PrimitiveSet(prims, nv)
    theta_demo = np.concatenate([thetas[i] for i in range(nv)])

    # Feedback laws.
    C = np.zeros((nv, nv))
    kp, kd, targets = np.zeros(nv), np.zeros(nv), np.zeros(nv)
    tracking, stabilizing, actuated = (np.zeros(nv, bool) for _ in range(3))
    frames: dict[int, FrameAngle] = {}
    for i, name in enumerate(joints):
        jc = cfg.joints[name]
        actuated[i] = jc.role != "passive"
        if jc.role == "track":
            tracking[i] = True
            for other in jc.link_angle or [name]:
                if other not in joints:
                    raise ConfigError([(f"joints.{name}.link_angle", f"'{other}' is not a "
                                        "configured (unlocked) joint")],
                                      str(source) if source else None)
                C[i, joints.index(other)] += 1.0
        elif jc.role == "stabilize":
            stabilizing[i] = True
            t = jc.target
            if t.frame is not None:
                frames[i] = FrameAngle(robot.model, t.frame, t.vector, t.about, t.zero)
            else:
                for other in t.link_angle or [name]:
                    C[i, joints.index(other)] += 1.0
            targets[i] = t.value
        if jc.gains is not None and jc.role != "passive":
            kp[i], kd[i] = jc.gains.kp, jc.gains.kd
    law = FeedbackLaw(C, kp, kd, tracking, stabilizing, targets, frames)
    if stabilizing.any() and not frames and \
            abs(np.linalg.det(C[np.ix_(stabilizing, stabilizing)])) < 1e-12:
        raise ConfigError([("joints", "the stabilized quantities do not determine the "
                                      "stabilizing joints (their link_angle rows are dependent)")],
                          str(source) if source else None)

    # Learner.
    learned, is_goal, rates, init = [], [], [], []
    demo_w = [np.abs(thetas[i][:-1]).max() for i, n in enumerate(joints)
              if cfg.joints[n].demo is not None]
    w_ref = max(demo_w) if demo_w else 1.0
    goals = np.array([thetas[i][-1] for i in range(nv)])
    centers = _goal_centers(law, goals)
    L = cfg.learning
    for i, name in enumerate(joints):
        jc = cfg.joints[name]
        if jc.learn is None:
            continue
        sl = primitives.slices[i]
        idx = list(range(sl.start, sl.stop))
        learned += idx
        is_goal += [False] * (len(idx) - 1) + [True]
        rates += [L.rates.weights] * (len(idx) - 1) + [L.rates.goal]
        center = jc.learn.goal_center if jc.learn.goal_center is not None else (
            float(centers[i]) if stabilizing[i] else float(goals[i]))
        init.append((sl, jc.learn.weight_scale * w_ref, center, jc.learn.goal_spread,
                     jc.learn.init))
    if L.error == "stabilizing":
        error_mask = stabilizing.astype(float)
    elif L.error == "all_feedback":
        error_mask = actuated.astype(float)
    else:
        error_mask = np.array([1.0 if n in L.error else 0.0 for n in joints])
    if L.step == "per_step" and L.update != "gradient":
        raise ConfigError([("learning.update", "per_step learning supports only 'gradient'")],
                          str(source) if source else None)
    if L.step == "per_step" and L.sensitivity != "exact":
        raise ConfigError([("learning.sensitivity", "per_step learning supports only 'exact'")],
                          str(source) if source else None)
    learner = FeedbackErrorLearner(primitives, np.array(learned, dtype=int),
                                   np.array(is_goal, dtype=bool), error_mask,
                                   np.array(rates), L.update, L.damping, L.sensitivity,
                                   L.fd_epsilon)
    plant = dynamics
    src = str(source) if source else None
    if cfg.plant is not None:
        if cfg.events:
            raise ConfigError([("events", "events change the known model's world; combining "
                                          "them with a plant block is not supported yet")], src)
        plant_rb = reduce_robot(plant_robot(cfg.plant, full_robot,
                                            source.parent if source else None), locked)
        plant_rb.set_gravity(cfg.gravity)
        plant = make_plant(cfg.plant, plant_rb, joints, make_dynamics(
            plant_rb.model, "casadi" if cfg.backend == "casadi" else "pinocchio"))
    model_learner = _model_learner(cfg, robot, joints, actuated, source)
    limits = None
    if dynamics.euclidean and (cfg.sim.joint_limits, cfg.sim.torque_limits) != ("ignore",) * 2:
        m = robot.model
        # URDFs write "no limit" as lower = upper (often 0) and effort 0.
        ranged = m.lowerPositionLimit < m.upperPositionLimit
        limits = Limits(np.where(ranged, m.lowerPositionLimit, -np.inf),
                        np.where(ranged, m.upperPositionLimit, np.inf),
                        np.where(m.effortLimit > 0, m.effortLimit, np.inf),
                        cfg.sim.joint_limits, cfg.sim.torque_limits)
    loop = ClosedLoop(plant, law, actuated, dt, cfg.sim.substeps, cfg.sim.integrator,
                      error_mask, limits)
    check_events(robot.model, cfg.events, src)
    hybrid = None
    if cfg.walking is not None or cfg.actuation is not None:
        if L.step == "per_step":
            raise ConfigError([("learning.step", "walking/actuation support only per_cycle "
                                                 "learning")], src)
        if L.sensitivity != "exact":
            raise ConfigError([("learning.sensitivity", "walking/actuation support only "
                                                        "'exact'")], src)
        if cfg.backend == "compiled":
            raise ConfigError([("backend", "walking/actuation need the pinocchio or casadi "
                                           "backend (the compiled cycle has no hybrid loop)")], src)
        if model_learner is not None:
            raise ConfigError([("learning.model", "model learning is not supported for "
                                                  "walking/actuated robots yet")], src)
        hybrid = HybridLoop(plant, law, _allocation(cfg, robot, joints, src),
                            _walker(cfg, robot, joints, src), actuated, dt, cfg.sim.substeps,
                            cfg.sim.integrator, error_mask)
    exp = Experiment(cfg, robot, dynamics, joints, primitives, theta_demo, law, loop, learner,
                     init, source, hybrid, plant, model_learner)
    if L.sensitivity == "casadi" and learner.n_learned:
        from feltool.compiled import feedforward_jacobian

        learner.set_casadi_jacobian(_BufferedFn(feedforward_jacobian(exp)))
    if cfg.backend == "compiled":
        from feltool.compiled import check_supported

        if cfg.events:
            raise ConfigError([("events", "backend 'compiled' simulates the known model only; "
                                          "use pinocchio or casadi for events")], src)
        # The compiled cycle simulates the known model and has no model correction.
        problems = [(f, f"backend 'compiled' does not support '{f}' yet; use backend "
                        f"pinocchio or casadi") for f, val in (("plant", cfg.plant),
                                                              ("learning.model", L.model))
                    if val is not None]
        if problems:
            raise ConfigError(problems, str(source) if source else None)
        check_supported(exp)
    return exp


class _BufferedFn:
    """A one-input CasADi function called with low overhead (see feltool.compiled)."""

    def __init__(self, fn):
        from feltool.dynamics.casadi_backend import BufferedCall

        self._call = BufferedCall(fn)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self._call(x)[0]


def _joint_row(names: dict[str, float] | list[str], joints: list[str], where: str,
               src: str | None) -> np.ndarray:
    """Row ``a`` with ``a @ q`` = the weighted sum of the named joints' angles."""
    items = names.items() if isinstance(names, dict) else [(n, 1.0) for n in names]
    row = np.zeros(len(joints))
    for name, coef in items:
        if name not in joints:
            raise ConfigError([(where, f"'{name}' is not a configured (unlocked) joint; "
                                       f"joints: {', '.join(joints)}")], src)
        row[joints.index(name)] += coef
    return row


def _allocation(cfg: ExperimentConfig, robot: Robot, joints: list[str],
                src: str | None) -> Allocation | None:
    if cfg.actuation is None:
        return None
    B = np.stack([_joint_row(m, joints, f"actuation.motors.{name}", src)
                  for name, m in cfg.actuation.motors.items()], axis=1)
    if np.linalg.matrix_rank(B) < B.shape[1]:
        raise ConfigError([("actuation.motors", "the motors' rows are linearly dependent")], src)
    return Allocation(B, cfg.actuation.allocation, robot.model)


def _walker(cfg: ExperimentConfig, robot: Robot, joints: list[str],
            src: str | None) -> Walker | None:
    w = cfg.walking
    if w is None:
        return None
    missing = [n for n in joints if n not in w.absolute]
    if missing:
        raise ConfigError([("walking.absolute", "needs every configured joint; missing: "
                                                + ", ".join(missing))], src)
    A = np.stack([_joint_row(w.absolute[n], joints, f"walking.absolute.{n}", src)
                  for n in joints])
    if abs(np.linalg.det(A)) < 1e-12:
        raise ConfigError([("walking.absolute", "the absolute angles do not determine the "
                                                "joint angles (singular map)")], src)
    Pi = np.eye(len(joints))
    for i, name in enumerate(w.swap):
        if name not in joints:
            raise ConfigError([(f"walking.swap.{i}", f"'{name}' is not a configured joint")], src)
    a, b = joints.index(w.swap[0]), joints.index(w.swap[1])
    Pi[[a, b]] = Pi[[b, a]]
    free, foot = None, None
    if w.impact == "rigid" and w.contact_frame is None:
        raise ConfigError([("walking.contact_frame", "impact: rigid needs the swing foot's "
                                                     "frame")], src)
    if w.contact_frame is not None:
        # The same robot with its base freed in the sagittal plane (x, z): q_e = (x, z, q).
        root = pin.JointModelComposite(pin.JointModelPX())
        root.addJoint(pin.JointModelPZ())
        free = None if robot.urdf_path is None else pin.buildModelFromUrdf(str(robot.urdf_path),
                                                                           root)
        if free is None or free.nv != robot.model.nv + 2:
            raise ConfigError([("walking.contact_frame", "needs a URDF robot with no locked "
                                                         "joints")], src)
        if not free.existFrame(w.contact_frame):
            raise ConfigError([("walking.contact_frame", f"the robot has no frame "
                                                         f"'{w.contact_frame}'")], src)
        foot = free.getFrameId(w.contact_frame)
    fall_row = (_joint_row(w.fall.link_angle, joints, "walking.fall.link_angle", src)
                if w.fall else None)
    return Walker(A, Pi, _joint_row(w.guard.link_angle, joints, "walking.guard.link_angle", src),
                  w.guard.value, 1.0 if w.guard.direction == "rising" else -1.0,
                  tuple(w.guard.window), w.steps_per_cycle, w.impact, fall_row,
                  w.fall.max_abs if w.fall else np.inf, free, foot)


def _model_learner(cfg: ExperimentConfig, robot: Robot, joints: list[str], actuated: np.ndarray,
                   source: Path | None) -> ModelLearner | None:
    """The classic-FEL learner of ``learning.model`` (None when absent)."""
    M = cfg.learning.model
    if M is None:
        return None
    problems = []
    if cfg.learning.step == "per_step":
        problems.append(("learning.model", "needs learning.step: per_cycle (the trajectory "
                                           "learner's per_step loop has no model correction)"))
    if M.step == "per_step" and M.update != "gradient":
        problems.append(("learning.model.update", "per_step learning supports only 'gradient'"))
    if (cfg.learning.sensitivity == "casadi" and M.jacobian == "learned"
            and M.features == "regressor"):
        problems.append(("learning.model.jacobian", "'learned' needs learning.sensitivity exact or "
                                                    "finite_difference (the casadi Jacobian is "
                                                    "built from the known model); or use nominal"))
    if problems:
        raise ConfigError(problems, str(source) if source else None)
    if M.features == "regressor":
        features = RegressorFeatures(robot.model)
    else:
        features = PhaseBasisFeatures(cfg.steps_per_cycle, len(joints), M.basis, M.width, joints)
    if M.error == "all_feedback":
        mask = actuated.astype(float)
    elif M.error == "tracking":
        mask = np.array([1.0 if cfg.joints[n].role == "track" else 0.0 for n in joints])
    else:
        unknown = [n for n in M.error if n not in joints]
        if unknown:
            raise ConfigError([("learning.model.error", f"not moving joints of the model: "
                                                        f"{', '.join(unknown)}")],
                              str(source) if source else None)
        mask = np.array([1.0 if n in M.error else 0.0 for n in joints])
    return ModelLearner(features, mask * actuated, M.rate, M.update, M.step, M.damping)


def _goal_centers(law: FeedbackLaw, goals: np.ndarray) -> np.ndarray:
    """Goals that meet every stabilizing target with the other joints at their goals."""
    q, _ = law.consistent_state(goals, np.zeros_like(goals))
    return q


def reduce_robot(robot: Robot, locked: dict[str, float]) -> Robot:
    """The robot with ``locked`` joints fixed at the given angles (Pinocchio's reduced model)."""
    if not locked:
        return robot
    q_ref = pin.neutral(robot.model)
    ids = []
    for name, posture in locked.items():
        jid = robot.joint_id(name)
        ids.append(jid)
        joint = robot.model.joints[jid]
        if joint.nq == 1:
            q_ref[joint.idx_q] = posture
    model = pin.buildReducedModel(robot.model, sorted(ids), q_ref)
    if model.nv == 0:
        raise ConfigError([("joints", "every joint is locked; nothing moves")])
    reduced = Robot(name=robot.name, model=model, source=robot.source, urdf_path=robot.urdf_path,
                    package_dirs=robot.package_dirs)
    if robot._visual_model is not None:
        # Visuals loaded with the robot (example-robot-data's, whose package:// meshes the URDF
        # alone cannot resolve) are reduced with it, so viewers draw the reduced robot.
        _, reduced._visual_model = pin.buildReducedModel(robot.model, robot._visual_model,
                                                         sorted(ids), q_ref)
    return reduced


# -- running one seed ----------------------------------------------------------------------------

@dataclass
class SeedResult:
    """One seed's outcome: metric rows, summary entry, learned parameters and traces."""

    seed: int
    rows: list[dict[str, float]]
    summary: dict[str, Any]
    params: dict[str, np.ndarray]
    traces: dict[str, np.ndarray]


@dataclass
class CycleOutcome:
    """What the learner and the metrics need from one cycle, whichever backend ran it.

    Attributes:
        theta_next: Parameters after the cycle's update.
        q_end, v_end: Robot state after the cycle.
        fb_abs_mean: Mean |u_fb| per joint over the cycle [N m].
        fb_stabilized: Sum over stabilizing controllers of their mean |output| [N m].
        fb_error: Sum over joints of the mean |error signal| [N m].
        track_err_rms: RMS of forward minus system angle per joint [rad].
        max_error: Largest |reference - controlled quantity| over the cycle [rad].
        max_speed: Largest |joint velocity| over the cycle [rad/s].
        finite: Whether every state stayed finite.
        trace: Returns ``(CycleLog, Qd)`` of the cycle (computed on demand).
        fall: Why a walker fell during the cycle (hybrid loop), or None.
        impacts: ``(step, by_guard, swing-foot x [m])`` of each impact (walkers).
        theta_m_next: The inverse-model correction after the cycle (``learning.model``), else
            None.
    """

    theta_next: np.ndarray
    q_end: np.ndarray
    v_end: np.ndarray
    fb_abs_mean: np.ndarray
    track_err_rms: np.ndarray
    max_error: float
    max_speed: float
    finite: bool
    trace: Callable[[], tuple[CycleLog, np.ndarray]]
    fb_stabilized: float = 0.0
    fb_error: float = 0.0
    fall: str | None = None
    impacts: list = field(default_factory=list)
    theta_m_next: np.ndarray | None = None
    limit_hits: tuple[np.ndarray, np.ndarray] | None = None


def run_seed(exp: Experiment, seed: int, cycles: int | None = None,
             progress: Callable[[int, float], None] | None = None,
             checkpoint: Checkpointer | None = None,
             on_cycle: Callable[[int, CycleLog, np.ndarray, float], None] | None = None
             ) -> SeedResult:
    """Run one seed's learning and return its metrics (see the run directory's metrics.csv).

    Args:
        progress: Called after every cycle with (cycle, mean |error feedback| [N m]).
        checkpoint: The seed continues from its last checkpoint (bit-identically), saves one
            every ``checkpoint.every`` cycles, and on a stop request saves and raises
            :class:`~feltool.checkpoint.Interrupted`.
        on_cycle: Called after every cycle with (cycle, log, Qd, fb): the cycle's simulated
            states ``log.q`` (n_steps x nv, [rad]), its forward (desired) trajectory ``Qd``
            (n_steps x nv, [rad]) and fb as for ``progress`` (the live viewer streams these).
    """
    cfg = exp.config
    cycles = cycles or cfg.sim.cycles
    theta = exp.initial_parameters(seed)
    n = exp.primitives.n_steps
    Qd, Vd, _ = exp.primitives.desired(theta)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    if exp.hybrid is not None:
        q, v = exp.hybrid.initial_state(Qd, Vd)
    rows, history, traces, last = [], [theta[exp.learner.learned].copy()], {}, None
    reason, start, wall_before = None, 1, 0.0
    run_cycle = _cycle_runner(exp, theta)
    model = exp.model_learner
    theta_m = model.initial_parameters() if model else None
    model_history = [theta_m]
    saved = checkpoint.load() if checkpoint is not None else None
    if saved is not None:
        start = saved["cycle"] + 1
        theta, q, v = saved["theta"], saved["q"], saved["v"]
        rows, wall_before = saved["rows"], saved["wall_s"]
        history = list(saved["history"])
        traces = {k[len("trace_"):]: v for k, v in saved.items() if k.startswith("trace_")}
        if "rmp_x" in saved:
            _restore_rmp_states(run_cycle, saved)
        if model is not None:
            theta_m, model_history = saved["model_theta"], list(saved["model_history"])
    t0 = time.perf_counter()
    plant, impacts = _plant_at_start(exp, start), {"guard": 0, "clock": 0}
    nv = len(exp.joints)
    hits = [np.zeros(nv, int), np.zeros(nv, int)]
    checked = False
    for cycle in range(start, cycles + 1):
        if cycle > start:
            plant = _plant_for_cycle(exp, cycle) or plant
        out = run_cycle(theta, q, v, plant, theta_m)
        for _, by_guard, _ in out.impacts:
            impacts["guard" if by_guard else "clock"] += 1
        if out.limit_hits is not None:
            checked = True
            hits[0] += out.limit_hits[0]
            hits[1] += out.limit_hits[1]
        reason = _divergence(exp, out)
        if reason:
            break
        row = _metrics(exp, seed, cycle, out, theta)
        if model is not None:
            row["model_param_norm"] = float(np.linalg.norm(theta_m))
            theta_m = out.theta_m_next
            model_history.append(theta_m)
        rows.append(row)
        if cycle == 1:
            traces.update(_trace("first", *out.trace()))
        last = out
        theta = out.theta_next
        history.append(theta[exp.learner.learned].copy())
        q, v = out.q_end, out.v_end
        if progress is not None:
            progress(cycle, row["fb_abs_mean_error"])
        if on_cycle is not None:
            on_cycle(cycle, *out.trace(), row["fb_abs_mean_error"])
        if checkpoint is not None and (cycle % checkpoint.every == 0 or stop_requested()):
            _save_checkpoint(checkpoint, cycle, theta, q, v, rows, history, traces,
                             wall_before + time.perf_counter() - t0, run_cycle,
                             (theta_m, model_history) if model is not None else None)
            if stop_requested() and cycle < cycles:
                raise Interrupted(f"seed {seed} stopped after cycle {cycle} (checkpoint saved)")
    wall = wall_before + time.perf_counter() - t0
    if last is not None:
        traces.update(_trace("last", *last.trace()))
    steps = n * (len(rows) + (1 if reason else 0))
    if checkpoint is not None:
        checkpoint.clear()
    summary = _seed_summary(exp, seed, rows, reason, wall, steps)
    summary["limits"] = ({"joint_limit_steps": {n: int(c) for n, c in zip(exp.joints, hits[0]) if c},
                          "torque_limit_steps": {n: int(c) for n, c in zip(exp.joints, hits[1]) if c}}
                         if checked else "not checked")
    if exp.hybrid is not None and exp.hybrid.walker is not None:
        summary["guard_impacts"], summary["clock_impacts"] = impacts["guard"], impacts["clock"]
    if exp.hybrid is not None and rows and reason is None and cfg.walking is not None \
            and cfg.walking.poincare:
        from feltool.gait import poincare

        summary["poincare"] = poincare(exp, theta, q, v, plant)
    params = exp.split_parameters(theta)
    hist = np.array(history)
    for name in exp.learned_joints:
        sl = exp.primitives.slices[exp.joints.index(name)]
        cols = [c for c, p in enumerate(exp.learner.learned) if sl.start <= p < sl.stop]
        params[f"{name}.weights_history"] = hist[:, cols[:-1]]
        params[f"{name}.goal_history"] = hist[:, cols[-1]]
    if model is not None:
        params["model.theta"] = theta_m
        params["model.theta_history"] = np.array(model_history)
    return SeedResult(seed, rows, summary, params, traces)


def _cycle_runner(exp: Experiment, theta0: np.ndarray) -> Callable[..., CycleOutcome]:
    """The function ``(theta, q, v, plant) -> CycleOutcome`` that runs one cycle for this
    experiment's backend and update mode; ``plant`` is the simulated world (the known model, or
    the one an event changed).

    A per-step runner carries the RMP states from cycle to cycle in its ``rmp_states``.
    """
    if exp.config.backend == "compiled":
        run = _compiled_runner(exp)
        return lambda theta, q, v, plant, theta_m=None: run(theta, q, v)
    if exp.hybrid is not None:
        return lambda theta, q, v, plant, theta_m=None: _hybrid_cycle(exp, theta, q, v, plant)
    loops: dict[int, ClosedLoop] = {}

    def loop_for(plant: Dynamics) -> ClosedLoop:
        if plant is exp.dynamics:
            return exp.loop
        if id(plant) not in loops:
            loops.clear()
            loops[id(plant)] = ClosedLoop(plant, exp.law, exp.loop.actuated, exp.loop.dt,
                                          exp.loop.substeps, exp.loop.integrator,
                                          exp.loop.error_rows, exp.loop.limits)
        return loops[id(plant)]

    if exp.model_learner is not None:
        return lambda theta, q, v, plant, theta_m: _model_cycle(exp, theta, q, v, theta_m,
                                                                loop_for(plant))
    if exp.config.learning.step == "per_step":
        states = _limit_cycle_states(exp, theta0)

        def per_step(theta, q, v, plant, theta_m=None):
            return _outcome(exp, *_per_step_cycle(exp, theta, q, v, states, loop_for(plant)))

        per_step.rmp_states = states
        return per_step
    return lambda theta, q, v, plant, theta_m=None: _per_cycle(exp, theta, q, v, loop_for(plant))


def _plant_for_cycle(exp: Experiment, cycle: int) -> Dynamics | None:
    """The simulated world from ``cycle`` on if an event starts then, else None."""
    backend = "casadi" if exp.config.backend == "casadi" else "pinocchio"
    return plant_for_cycle(exp.robot.model, exp.config.events, cycle, backend)


def _plant_at_start(exp: Experiment, start: int) -> Dynamics:
    """The simulated world at cycle ``start`` (every event up to it applied; resumed runs)."""
    events = [ev for ev in exp.config.events if ev.cycle <= start]
    if not events:
        return exp.dynamics
    backend = "casadi" if exp.config.backend == "casadi" else "pinocchio"
    return make_dynamics(changed_model(exp.robot.model, events), backend)


def _save_checkpoint(checkpoint: Checkpointer, cycle, theta, q, v, rows, history, traces,
                     wall, run_cycle, model_state=None) -> None:
    arrays = {"theta": theta, "q": q, "v": v, "history": np.array(history)}
    if model_state is not None:
        arrays["model_theta"], arrays["model_history"] = model_state[0], np.array(model_state[1])
    arrays.update({f"trace_{k}": val for k, val in traces.items()})
    states = getattr(run_cycle, "rmp_states", None)
    if states is not None:
        keys = sorted(states)
        arrays["rmp_keys"] = np.array(keys)
        arrays["rmp_x"] = np.array([states[k][0] for k in keys])
        arrays["rmp_S"] = np.array([states[k][1] for k in keys])
    checkpoint.save(cycle, arrays, {"rows": rows, "wall_s": wall})


def _restore_rmp_states(run_cycle, saved: dict) -> None:
    for key, x, S in zip(saved["rmp_keys"], saved["rmp_x"], saved["rmp_S"]):
        run_cycle.rmp_states[int(key)] = (x.copy(), S.copy())


def _feedforward(exp: Experiment, Qd, Vd, Ad) -> tuple[np.ndarray, list | None]:
    """:math:`u_{ff}` along the desired trajectory, with the RNEA derivatives (from the same
    pass) when the learner needs exact sensitivities."""
    if exp.learner.n_learned and exp.config.learning.sensitivity == "exact":
        u_ff, *derivs = exp.dynamics.inverse_derivatives_batch(Qd, Vd, Ad)
        return u_ff, derivs
    return feedforward(exp.dynamics, Qd, Vd, Ad), None


def _per_cycle(exp: Experiment, theta: np.ndarray, q, v, loop: ClosedLoop) -> CycleOutcome:
    """One cycle on the limit cycle of the current parameters, then one update (eq. 3.6)."""
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_ff, derivs = _feedforward(exp, Qd, Vd, Ad)
    log = loop.run_cycle(q, v, R, Rd, u_ff)
    theta_next = theta
    if exp.learner.n_learned and np.all(np.isfinite(log.v)):
        J = exp.learner.jacobian(exp.dynamics, theta, Qd, Vd, Ad, derivs)
        theta_next = exp.learner.step(theta, J, log.u_err)
    return _outcome(exp, log, Qd, theta_next)


def _hybrid_cycle(exp: Experiment, theta: np.ndarray, q, v, plant: Dynamics) -> CycleOutcome:
    """One cycle of the hybrid loop (walkers, allocated motors), then one update (eq. 3.6);
    the learner's Jacobian goes through the stance-dependent map q_d = G_s p_d."""
    P, Pv, Pa = exp.primitives.desired(theta)
    log = exp.hybrid.run_cycle(plant, q, v, P, Pv, Pa)
    theta_next = theta
    if log.fall is None and exp.learner.n_learned:
        _, *derivs = exp.hybrid.jacobian_derivatives(log)
        J = exp.learner.jacobian(exp.dynamics, theta, log.Qd, log.Vd, log.Ad, derivs)
        theta_next = exp.learner.step(theta, J, log.u_err)
    out = _outcome(exp, log, log.Qd, theta_next)
    out.fall, out.impacts = log.fall, list(log.impacts)
    return out


def _model_cycle(exp: Experiment, theta: np.ndarray, q, v, theta_m: np.ndarray,
                 loop: ClosedLoop) -> CycleOutcome:
    """One cycle with the learned inverse-model correction in the feedforward, then both
    updates: the trajectory's (eq. 3.6) and the model's (eq. 3.4)."""
    model = exp.model_learner
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_ff, derivs = _feedforward(exp, Qd, Vd, Ad)
    log, theta_m_next = model.run_cycle(loop, q, v, R, Rd, u_ff, (Qd, Vd, Ad), theta_m)
    theta_next = theta
    if exp.learner.n_learned and np.all(np.isfinite(log.v)):
        dyn = exp.dynamics
        if exp.config.learning.model.jacobian == "learned":
            learned = model.learned_dynamics(theta_m)  # the model this cycle's u_ff came from
            if learned is not None:
                dyn = learned
                if derivs is not None:
                    derivs = learned.inverse_derivatives_batch(Qd, Vd, Ad)[1:]
        J = exp.learner.jacobian(dyn, theta, Qd, Vd, Ad, derivs)
        theta_next = exp.learner.step(theta, J, log.u_err)
    out = _outcome(exp, log, Qd, theta_next)
    out.theta_m_next = theta_m_next
    return out


def _outcome(exp: Experiment, log: CycleLog, Qd: np.ndarray, theta_next) -> CycleOutcome:
    R, _ = exp.law.references(Qd, Qd)
    controlled = exp.law.tracking | exp.law.stabilizing
    with np.errstate(all="ignore"):
        err = np.abs(wrap(R - exp.law.quantity(log.q)))[:, controlled]
        return CycleOutcome(
            theta_next, log.q_end, log.v_end, np.abs(log.u_fb).mean(axis=0),
            np.sqrt(np.mean((Qd - log.q) ** 2, axis=0)),
            float(err.max()) if err.size else 0.0, float(np.abs(log.v).max()),
            bool(np.all(np.isfinite(log.q)) and np.all(np.isfinite(log.v))
                 and np.all(np.isfinite(log.q_end))),
            lambda: (log, Qd),
            float(np.abs(log.u_rows[:, exp.law.stabilizing]).mean(axis=0).sum()),
            float(np.abs(log.u_err).mean(axis=0).sum()),
            limit_hits=getattr(log, "limit_hits", None))


def _compiled_runner(exp: Experiment) -> Callable[..., CycleOutcome]:
    """Cycles from the compiled code, several per call: the outcomes of the cycles that follow
    are kept and handed out while the loop continues from the very state they predicted (the
    same arrays); a resumed or otherwise different state starts a new batch."""
    compiled = exp.compiled_cycle()
    nv, P = exp.robot.model.nv, exp.primitives.n_params
    stab = np.flatnonzero(exp.law.stabilizing)
    err_mask = exp.learner.error_mask
    pending: list[tuple[tuple, CycleOutcome]] = []

    def outcome(theta, x0, state, stat) -> CycleOutcome:
        x_end = state[P:]
        fb = stat[:nv]
        max_speed = float(stat[2 * nv + 1])

        def trace():
            out = compiled.full(theta, x0)
            X, U, Qd = out[7].T, out[8].T, out[9].T
            return CycleLog(X[:, :nv], X[:, nv:], U, x_end[:nv], x_end[nv:], U,
                            U * err_mask), Qd

        return CycleOutcome(state[:P], x_end[:nv], x_end[nv:], fb, stat[nv:2 * nv],
                            float(stat[2 * nv]), max_speed,
                            bool(np.isfinite(state).all()) and max_speed == max_speed, trace,
                            float(fb[stab].sum()), float(fb @ err_mask))

    def run(theta, q, v) -> CycleOutcome:
        if pending:
            (t_exp, q_exp, v_exp), nxt = pending.pop(0)
            if t_exp is theta and q_exp is q and v_exp is v:
                return nxt
        pending.clear()
        x0 = np.concatenate([q, v])
        states, stats = compiled.many(theta, x0)
        outs, prev_theta, prev_x = [], theta, x0
        for k in range(states.shape[1]):
            outs.append(outcome(prev_theta, prev_x, states[:, k], stats[:, k]))
            prev_theta, prev_x = outs[-1].theta_next, states[P:, k]
        pending.extend(((a.theta_next, a.q_end, a.v_end), b) for a, b in zip(outs, outs[1:]))
        return outs[0]

    return run


def _limit_cycle_states(exp: Experiment, theta: np.ndarray) -> dict[int, tuple]:
    """Each RMP's state (q, qdot) and sensitivity at phase 0 of its limit cycle."""
    return {i: (np.array([p.Xq[0] @ theta[exp.primitives.slices[i]],
                          p.Xv[0] @ theta[exp.primitives.slices[i]]]),
                np.stack([p.Xq[0], p.Xv[0]]))
            for i, p in exp.primitives.primitives.items()}


def _per_step_cycle(exp: Experiment, theta: np.ndarray, q, v, states: dict[int, tuple],
                    loop: ClosedLoop | None = None):
    """One cycle with an update after every step; the RMP states (updated in place in
    ``states``) run on continuously, their sensitivities propagated alongside. ``loop``
    simulates the world (default ``exp.loop``)."""
    loop = loop or exp.loop
    prims, n, nv = exp.primitives, exp.primitives.n_steps, exp.primitives.nv
    learner, law, dyn = exp.learner, exp.law, exp.dynamics
    theta = theta.copy()
    Q, V, U, Urows, Uerr, Qd, Vd = (np.empty((n, nv)) for _ in range(7))
    for k in range(n):
        qd, vd, ad = np.empty(nv), np.empty(nv), np.empty(nv)
        Sq, Sv, Sa = {}, {}, {}
        for i, p in prims.primitives.items():
            x, S = states[i]
            th = theta[prims.slices[i]]
            qd[i], vd[i], ad[i] = x[0], x[1], p.acceleration(x, th, k)
            Sq[i], Sv[i], Sa[i] = S[0], S[1], p.acceleration_sensitivity(S, k)
        Qd[k], Vd[k] = qd, vd
        R, Rd = law.references(qd[None], vd[None])
        u_fb, u_rows, u_err = law.terms(q, v, R[0], Rd[0], exp.loop.error_rows)
        u_ff = dyn.inverse(qd, vd, ad)
        Dq, Dv, M = dyn.inverse_derivatives(qd, vd, ad)
        J = np.zeros((1, nv, learner.n_learned))
        for i, cols, _, rows in learner._blocks:
            sel = np.isin(rows, learner.learned)
            J[0][:, cols] = (np.outer(Dq[:, i], Sq[i][sel]) + np.outer(Dv[:, i], Sv[i][sel])
                             + np.outer(M[:, i], Sa[i][sel]))
        Q[k], V[k], U[k], Urows[k], Uerr[k] = q, v, u_fb, u_rows, u_err
        q, v = loop.advance(q, v, loop.actuated * (u_ff + u_fb))
        for i, p in prims.primitives.items():
            x, S = states[i]
            th = theta[prims.slices[i]]
            states[i] = (p.step(x, th, k), p.step_sensitivity(S, k))
        theta = learner.step(theta, J, u_err[None])
    return CycleLog(Q, V, U, q, v, Urows, Uerr), Qd, theta


def _divergence(exp: Experiment, out: CycleOutcome) -> str | None:
    sim = exp.config.sim
    if out.fall:
        return out.fall
    if not out.finite:
        return "the state became non-finite"
    if out.max_speed > sim.max_velocity:
        return (f"a joint velocity reached {out.max_speed:.3g} rad/s "
                f"(sim.max_velocity = {sim.max_velocity})")
    if out.max_error > sim.max_error_rad:
        return (f"a controlled quantity was {out.max_error:.3g} rad from its reference "
                f"(sim.max_error_rad = {sim.max_error_rad}): the robot fell")
    return None


def _metrics(exp: Experiment, seed: int, cycle: int, out: CycleOutcome,
             theta: np.ndarray) -> dict[str, float]:
    fb, rms = out.fb_abs_mean, out.track_err_rms
    row: dict[str, float] = {"seed": seed, "cycle": cycle}
    for i, name in enumerate(exp.joints):
        row[f"fb_abs_mean_{name}"] = float(fb[i])
    row["fb_abs_mean_stabilized"] = out.fb_stabilized
    row["fb_abs_mean_total"] = float(fb.sum())
    row["fb_abs_mean_error"] = out.fb_error
    for i, name in enumerate(exp.joints):
        row[f"track_err_rms_{name}"] = float(rms[i])
    row["param_norm"] = float(np.linalg.norm(theta[exp.learner.learned]))
    return row


def _trace(which: str, log: CycleLog, Qd: np.ndarray) -> dict[str, np.ndarray]:
    return {f"{which}_q_system": log.q, f"{which}_q_forward": Qd, f"{which}_u_fb": log.u_fb}


def _seed_summary(exp: Experiment, seed: int, rows, reason: str | None,
                  wall: float, steps: int) -> dict[str, Any]:
    fb = [r["fb_abs_mean_error"] for r in rows]
    fb0 = fb[0] if fb else None
    converged = None
    if fb:
        threshold = 0.05 * fb0
        above = [i for i, f in enumerate(fb) if f >= threshold]
        last_above = above[-1] if above else -1
        if last_above < len(fb) - 1:
            converged = rows[last_above + 1]["cycle"]
    out = {"seed": seed, "cycles": len(rows), "fb_initial": fb0, "fb_final": fb[-1] if fb else None,
           "fb_ratio": (fb[-1] / fb0) if fb and fb0 else None, "converged_cycle": converged,
           "wall_s": round(wall, 4), "steps_per_s": round(steps / wall, 1) if wall > 0 else None,
           "diverged": reason is not None}
    if reason:
        out["diverged_reason"] = f"seed {seed}, cycle {len(rows) + 1}: {reason}"
    return out


def stabilization_errors(exp: Experiment, traces: dict[str, np.ndarray]) -> dict[str, float]:
    """Max deviation of each stabilized quantity from its target over the last cycle, in [rad],
    for the system (``<joint>_system``) and the forward trajectory (``<joint>_forward``)."""
    out = {}
    for i, name in enumerate(exp.joints):
        if not exp.law.stabilizing[i]:
            continue
        for kind in ("system", "forward"):
            y = exp.law.quantity(traces[f"last_q_{kind}"])[:, i]
            out[f"{name}_{kind}"] = float(np.abs(wrap(y - exp.law.targets[i])).max())
    return out


__all__ = ["Experiment", "SeedResult", "build_experiment", "load_experiment", "run_seed",
           "validate", "FeltoolError"]
