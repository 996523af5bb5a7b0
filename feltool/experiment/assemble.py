"""Assemble an experiment from a config: validate it completely (schema, robot, names), then
build the robot, primitives, feedback laws, learner, loops and plant.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from feltool.config.experiment import ExperimentConfig
from feltool.config.files import parse_config
from feltool.config.joints import JointConfig
from feltool.config.memory import check_memory
from feltool.control.closed_loop import ClosedLoop, Limits
from feltool.control.feedback import FeedbackLaw
from feltool.dynamics.interface import make_dynamics
from feltool.errors import ConfigError, RobotError
from feltool.experiment.checks import target_problems
from feltool.experiment.demos import demo_trajectory, positions_series
from feltool.experiment.experiment import Experiment
from feltool.experiment.mujoco_plant import (
    mujoco_arm_loop,
    mujoco_problems,
    mujoco_walker_loop,
    uses_mujoco,
)
from feltool.learning.fel import FEL_UPDATES, FeedbackErrorLearner
from feltool.learning.model import ModelLearner, PhaseBasisFeatures, RegressorFeatures
from feltool.learning.rates import basis_gain, per_sample_rates, samples_per_cycle
from feltool.learning.sensitivity import CasadiJacobian
from feltool.learning.walker_model import WalkerModelLearner
from feltool.motion.motion import motion_problems, refuse_varying_phase, varying_phase
from feltool.motion.rmp import PrimitiveSet, RhythmicPrimitive
from feltool.plant.disturbances import problems as disturbance_problems
from feltool.plant.events import check_events
from feltool.plant.rigid import make_plant, plant_problems, plant_robot
from feltool.robot.frames import FrameAngle
from feltool.robot.robot import Robot, load_robot, robot_spec, with_angle_coordinates
from feltool.walking.build import physical_loop, pinned_allocation, pinned_walker, walker_model
from feltool.walking.model import with_planar_base
from feltool.walking.pinned import HybridLoop


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
        if [path for path, _ in exc.problems] == ["walking.base"]:
            raise  # no schema picked: what the others would say of the rest misleads
        problems += exc.problems
    robot = None
    spec, lenient = robot_spec(raw.get("robot"))
    if spec:
        try:
            dirs = raw.get("package_dirs") if isinstance(raw.get("package_dirs"), list) else []
            robot = with_angle_coordinates(load_robot(
                spec, base_dir=source.parent if source else None,
                package_dirs=[str(d) for d in dirs], lenient=lenient))
        except RobotError as exc:
            problems.append(("robot", str(exc)))
    named = None
    if robot is not None and cfg is not None and cfg.walking is not None and \
            cfg.walking.physical:
        wm, walker_problems = walker_model(cfg.walking, robot)
        problems += walker_problems
        if wm is not None:
            named = wm.robot  # the names include the base joints
    elif robot is not None and cfg is None and _planar_walker(raw):
        named = with_planar_base(robot)  # (the schema failed elsewhere: no false name errors)
    if robot is not None:
        problems += _name_problems(raw, named or robot)
        if cfg is not None and cfg.plant is not None:
            problems += plant_problems(cfg.plant, robot, source.parent if source else None)
            problems += mujoco_problems(cfg)
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


def _planar_walker(raw: dict[str, Any]) -> bool:
    """Whether a raw config (one that failed the schema) asks for a physical walker on the
    planar base feltool adds, whose joint names then include the base's."""
    w = raw.get("walking")
    return isinstance(w, dict) and "feet" in w and w.get("base", "planar") == "planar"


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
        joint = robot.model.joints[robot.joint_id(name)]
        role = jc.get("role") if isinstance(jc, dict) else None
        if joint.nv != 1 and role != "locked":
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


def assemble_experiment(raw: dict[str, Any], source: Path | None = None,
                        check_targets: bool = True) -> Experiment:
    """Assemble an :class:`Experiment` from a raw config mapping; a stabilized quantity no
    actuated joint moves is an error (unless ``check_targets`` is False: ``feltool check``
    reports it with the problems it finds in the built experiment)."""
    cfg, full_robot = validate(raw, source)
    wm = None
    if cfg.walking is not None and cfg.walking.physical:
        wm, _ = walker_model(cfg.walking, full_robot)
        full_robot = wm.robot
        _physical_joints(cfg, wm, source)
    locked = {n: 0.0 for n in full_robot.joint_names if n not in cfg.joints}
    locked.update({n: jc.posture for n, jc in cfg.joints.items() if jc.role == "locked"})
    robot = reduce_robot(full_robot, locked)
    # Before the per-sample arrays exist: refuse a run the machine cannot hold.
    check_memory(cfg, robot.joint_names, robot.model.njoints - 1, str(source) if source else None)
    robot.set_gravity(cfg.gravity)
    dynamics = make_dynamics(robot.model, "casadi" if cfg.backend == "casadi" else "pinocchio")
    nv = robot.model.nv
    joints = [""] * nv
    for name in robot.joint_names:
        joints[robot.v_index(name)] = name
    if robot.model.nq != nv:
        multi = [n for n in robot.joint_names if robot.model.joints[robot.joint_id(n)].nq != 1]
        raise ConfigError([("robot", "after locking the unconfigured joints the model still has "
                                     "joints with more than one coordinate ("
                                     + ", ".join(multi) + "); lock them")],
                          str(source) if source else None)

    # Primitives: fit demos (eq. 2.4); learned joints get their random start per seed.
    dt, T = cfg.dt, cfg.period_s
    prims: dict[int, RhythmicPrimitive] = {}
    thetas: dict[int, np.ndarray] = {}
    fine_t = np.linspace(0.0, T, 2000, endpoint=False)
    fixed: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    referenced: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    fit_rms: dict[str, float] = {}
    demo_fits: dict[int, tuple] = {}  # eq. 2.4 of each demo in any basis (learn.init_basis)
    src = str(source) if source else None
    for i, name in enumerate(joints):
        jc = cfg.joints[name]
        settings = _settings(cfg, jc)
        prim = RhythmicPrimitive(settings["basis"], T, dt, settings["alpha_z"], settings["beta_z"],
                                 settings["width"], settings["amplitude"])
        prims[i] = prim
        if jc.demo is not None:
            d = jc.demo
            series = positions_series(d, source, f"joints.{name}.demo", src)
            q, v, a = demo_trajectory(d, T, fine_t, series)
            goal = None if series is not None else (  # (a positions demo fits its series)
                float(np.mean(q)) if d.kind == "samples" else d.mean)
            demo_fit = _demo_fitter(q, v, a, series, 2.0 * np.pi * fine_t / T, goal)
            thetas[i] = demo_fit(prim)
            if not (jc.follow_demo and jc.learn is not None):  # as the w_ref below
                demo_fits[i] = (demo_fit, settings)
            if not jc.follow_demo:
                fit_rms[name] = prim.fit_rms(thetas[i], q, 2.0 * np.pi * fine_t / T)
            if jc.follow_demo and jc.learn is None:
                fixed[i] = demo_trajectory(d, T, np.arange(prim.n_steps) * dt, series)
            elif jc.follow_demo:
                # the feedback holds the demo; the forward trajectory is the demo plus the
                # learned RMP, a correction that starts at zero (init demo) or perturbed
                referenced[i] = demo_trajectory(d, T, np.arange(prim.n_steps) * dt, series)
                thetas[i] = np.zeros(prim.n_params)
        else:
            thetas[i] = np.zeros(prim.n_params)
    primitives = PrimitiveSet(prims, nv, fixed, referenced)
    if fixed and (cfg.learning.sensitivity == "casadi" or cfg.learning.step == "per_step"):
        raise ConfigError([(f"joints.{joints[i]}.follow_demo", "needs learning.sensitivity "
                            "exact or finite_difference and learning.step per_cycle")
                           for i in fixed], str(source) if source else None)
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
    unreachable = target_problems(robot.model, law, joints, actuated) if check_targets else []
    if unreachable:
        raise ConfigError(unreachable, str(source) if source else None)
    if stabilizing.any() and not frames and \
            abs(np.linalg.det(C[np.ix_(stabilizing, stabilizing)])) < 1e-12:
        raise ConfigError([("joints", "the stabilized quantities do not determine the "
                                      "stabilizing joints (their link_angle rows are dependent)")],
                          str(source) if source else None)

    # Learner.
    learned, is_goal, rates, init, init_reference = [], [], [], [], {}
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
        scale = jc.learn.rate_scale
        prim = primitives.primitives[i]
        w_rate, g_rate = per_sample_rates(  # physical units -> the sums' (learning.rates)
            L.rates.weights, L.rates.goal, samples_per_cycle(cfg.period_s, cfg.sim.rate_hz),
            basis_gain(prim.n_basis, prim.width, prim.amplitude),
            L.rates.gauss_newton if L.update == "gauss_newton" else None)
        rates += [scale * w_rate] * (len(idx) - 1) + [scale * g_rate]
        center = jc.learn.goal_center if jc.learn.goal_center is not None else (
            float(centers[i]) if stabilizing[i] else float(goals[i]))
        w_scale = w_ref
        nb = jc.learn.init_basis
        if jc.learn.init == "random" and nb is not None and nb != prim.n_basis:
            # the draw on nb basis functions (the joint's settings otherwise, the default
            # width of nb unless one is set), and weight_scale relative to the demos' fits there
            init_reference[sl.start] = _with_basis(_settings(cfg, jc), nb, T, dt)
            refit = [np.abs(fit(_with_basis(st, nb, T, dt))[:-1]).max()
                     for fit, st in demo_fits.values()]
            w_scale = max(refit) if refit else 1.0
        scale = (jc.learn.perturbation_rad if jc.learn.init == "perturbed"
                 else jc.learn.weight_scale * w_scale)
        init.append((sl, scale, center, jc.learn.goal_spread, jc.learn.init))
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
    unsupported = disturbance_problems(cfg)
    if L.update not in FEL_UPDATES:  # (feltool.learning.ilc imports scipy.signal: only when needed)
        from feltool.learning.ilc import problems as ilc_problems

        unsupported = ilc_problems(cfg) + unsupported
    if unsupported:
        raise ConfigError(unsupported, str(source) if source else None)
    learner = FeedbackErrorLearner(primitives, np.array(learned, dtype=int),
                                   np.array(is_goal, dtype=bool), error_mask,
                                   np.array(rates), L.update, L.damping, L.sensitivity,
                                   L.fd_epsilon)
    _check_phase(cfg, joints, robot, {joints[i] for i in (*fixed, *referenced)}, src)
    plant = dynamics  # (with a MuJoCo plant: the known model predicts, MuJoCo simulates)
    if cfg.plant is not None and not uses_mujoco(cfg):
        if wm is not None and cfg.plant.robot is not None:
            raise ConfigError([("plant.robot", "a physical walker's plant is its own robot "
                                               "changed by the plant block (bodies, payloads, "
                                               "friction, motor_gain); remove plant.robot")], src)
        plant_rb = reduce_robot(plant_robot(cfg.plant, full_robot,
                                            source.parent if source else None), locked)
        plant_rb.set_gravity(cfg.gravity)
        plant = make_plant(cfg.plant, plant_rb, joints, make_dynamics(
            plant_rb.model, "casadi" if cfg.backend == "casadi" else "pinocchio"))
    model_learner = None if wm is not None else _model_learner(cfg, robot, joints, actuated,
                                                               source)
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
    if uses_mujoco(cfg) and wm is None:
        loop = mujoco_arm_loop(cfg, robot, loop, src)
    check_events(robot.model, cfg.events, src)
    if L.redesign is not None and (wm is None or L.model is None
                                   or L.model.features != "regressor"):
        raise ConfigError([("learning.redesign", "re-designs the gait on the identified model: "
                            "needs a physical walker (walking.feet) and learning.model with "
                            "features regressor")], src)
    hybrid = None
    if L.impact_window_s > 0 and cfg.walking is None:
        raise ConfigError([("learning.impact_window_s", "only for walkers (needs a walking "
                                                        "block)")], src)
    if cfg.walking is not None or cfg.actuation is not None:
        if L.step == "per_step":
            raise ConfigError([("learning.step", "walking/actuation support only per_cycle "
                                                 "learning")], src)
        if L.sensitivity != "exact":
            raise ConfigError([("learning.sensitivity", "walking/actuation support only "
                                                        "'exact'")], src)
        if L.model is not None and wm is None:
            raise ConfigError([("learning.model", "model learning on a walker needs a "
                                                  "physical walker (walking.feet)")], src)
        if wm is not None:
            if cfg.actuation is not None:
                raise ConfigError([("actuation", "a physical walker's motors are its URDF "
                                                 "joints (every joint but the base's); remove "
                                                 "the actuation block")], src)
            hybrid = physical_loop(cfg, wm, law, dynamics, joints, error_mask, src)
            hybrid.reference = dict(referenced)
            if L.model is not None:
                model_learner = _walker_model_learner(cfg, robot, hybrid.walker.motor_names,
                                                      src)
            if uses_mujoco(cfg):
                hybrid = mujoco_walker_loop(cfg, hybrid, src)
        else:
            hybrid = HybridLoop(plant, law, pinned_allocation(cfg, robot, joints, src),
                                pinned_walker(cfg, robot, joints, src), actuated, dt,
                                cfg.sim.substeps, cfg.sim.integrator, error_mask)
    if referenced and (wm is None or hybrid is None):
        raise ConfigError([(f"joints.{joints[i]}.follow_demo", "with learn: only for a "
                            "physical walker (walking.feet)") for i in referenced], src)
    exp = Experiment(cfg, robot, dynamics, joints, primitives, theta_demo, law, loop, learner,
                     init, source, hybrid, plant, model_learner, fit_rms,
                     init_reference=init_reference)
    if closed_loop_fit(cfg, hybrid, model_learner, dynamics):
        learner.fit = "closed_loop"
        learner.loop = {"law": law, "S": np.asarray(actuated, float), "dt": dt,
                        "substeps": cfg.sim.substeps,
                        "semi_implicit": cfg.sim.integrator == "semi_implicit_euler",
                        "q_filter_hz": L.q_filter_hz, "remove_transient": L.remove_transient}
    if L.sensitivity == "casadi" and learner.n_learned:
        learner.set_casadi_jacobian(CasadiJacobian(robot.model, primitives, learner.learned))
    return exp


def closed_loop_fit(cfg: ExperimentConfig, hybrid, model_learner, dynamics) -> bool:
    """Whether the Gauss-Newton step fits through the closed loop (``learning.fit:
    closed_loop``, :mod:`feltool.learning.loop_map`): for arms (no walking or actuation
    block, plain joint coordinates) learning per cycle with update gauss_newton and no
    inverse-model correction, and no period events or adaptive phase (a period of no whole
    number of steps is fine: each cycle's map is its own); the others fit the feedforward."""
    events = [where for where, _ in varying_phase(cfg)  # (a fractional period_s is fine)
              if where != "period_s" and not where.endswith((".amplitude", ".goal"))]
    return (cfg.closed_loop_fit and hybrid is None and model_learner is None
            and dynamics.euclidean and not events)


def _check_phase(cfg: ExperimentConfig, joints: list[str], robot: Robot, fixed: set[str],
                 src: str | None) -> None:
    """The phase's and the motion events' names exist, and the engine this config runs on can
    run cycles of changing length (or refuses, naming each feature and its YAML path)."""
    problems = motion_problems(cfg, joints, robot.model, fixed)
    if problems:
        raise ConfigError(problems, src)
    L = cfg.learning
    if cfg.primitives.phase == "adaptive" and L.step == "per_step":
        raise ConfigError([("primitives.phase", "adaptive runs with learning.step per_cycle "
                                                "(the per-step engine has no oscillator)")], src)
    for engine, used in (("the walking/actuated loop", cfg.walking is not None
                          or cfg.actuation is not None),
                         (f"learning.update {L.update}", L.update not in FEL_UPDATES),
                         ("a disturbances block", cfg.disturbances is not None),
                         ("learning.model", L.model is not None),
                         ("learning.sensitivity casadi", L.sensitivity == "casadi"),
                         ("follow_demo", bool(fixed))):
        if used:
            refuse_varying_phase(cfg, engine, src)


def _physical_joints(cfg: ExperimentConfig, wm, source: Path | None) -> None:
    """A physical walker's base joints default to passive; no joint may be locked (the walker
    model's frames and relabelling are of the whole robot)."""
    for name in wm.base:
        if name not in cfg.joints:
            cfg.joints[name] = JointConfig.model_validate(
                {"role": "passive", "demo": {"kind": "sine", "amplitude": 0.0}})
    locked = [n for n in wm.robot.joint_names
              if n not in cfg.joints or cfg.joints[n].role == "locked"]
    if locked:
        raise ConfigError([("joints", "a physical walker cannot lock joints; configure "
                                      + ", ".join(locked) + " (e.g. role: passive)")],
                          str(source) if source else None)


def _model_learner(cfg: ExperimentConfig, robot: Robot, joints: list[str], actuated: np.ndarray,
                   source: Path | None) -> ModelLearner | None:
    """The classic-FEL learner of ``learning.model`` (None when absent)."""
    M = cfg.learning.model
    if M is None:
        return None
    problems = []
    if M.features == "none" or M.motor_bias > 0 or M.slope > 0:
        problems.append(("learning.model.features" if M.features == "none" else
                         "learning.model.motor_bias" if M.motor_bias > 0 else
                         "learning.model.slope", "only for a physical walker (walking.feet)"))
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
    # gradient: the rate of the mean over the cycle (feltool.learning.rates), the sums get
    # rate / (N kappa): the normalised phase basis passes 1 / basis of the mean error (kappa),
    # the regressor is physical (1); gauss_newton: the fraction of the step, unscaled
    kappa = 1.0 / M.basis if M.features == "phase_basis" else 1.0
    rate = M.rate if M.update == "gauss_newton" else \
        M.rate / (samples_per_cycle(cfg.period_s, cfg.sim.rate_hz) * kappa)
    return ModelLearner(features, mask * actuated, rate, M.update, M.step, M.damping)


def _walker_model_learner(cfg: ExperimentConfig, robot: Robot, motors: list[str],
                          src: str | None) -> WalkerModelLearner:
    """A physical walker's classic FEL (``learning.model``): the regressor's model correction
    and/or the motor biases (:mod:`feltool.learning.walker_model`)."""
    M = cfg.learning.model
    problems = []
    if M.features == "phase_basis":
        problems.append(("learning.model.features", "a physical walker learns 'regressor' "
                                                    "(a model correction) or 'none' (with "
                                                    "motor_bias)"))
    if M.update != "gauss_newton" or M.step != "per_cycle":
        problems.append(("learning.model.update", "a physical walker's model learning is a "
                                                  "Levenberg-Marquardt step per cycle: "
                                                  "update gauss_newton, step per_cycle"))
    if M.features == "none" and M.motor_bias == 0:
        problems.append(("learning.model.motor_bias", "with features none, give motor_bias "
                                                      "> 0 (else nothing is learned)"))
    if M.features == "none" and M.slope > 0:
        problems.append(("learning.model.slope", "a learned ground slope needs the known "
                                                 "model: features regressor"))
    if problems:
        raise ConfigError(problems, src)
    model = robot.model if M.features == "regressor" else None
    return WalkerModelLearner(model, motors, M.rate, M.motor_bias, M.damping, M.slope)


def _demo_fitter(q, v, a, series, phi, goal):
    """Eq. 2.4 of one demonstration into a given primitive (a positions demo over its
    series' coefficients, else over the fine samples ``q, v, a`` at the phases ``phi``)."""
    if series is not None:
        return lambda prim: prim.fit_series(series)
    return lambda prim: prim.fit(q, v, a, phi, goal=goal)


def _settings(cfg: ExperimentConfig, jc: JointConfig) -> dict:
    """The primitives block with the joint's own overrides."""
    settings = cfg.primitives.model_dump()
    if jc.primitive is not None:
        settings.update({k: v for k, v in jc.primitive.model_dump().items() if v is not None})
    return settings


def _with_basis(settings: dict, n_basis: int, T: float, dt: float) -> RhythmicPrimitive:
    """The primitive of ``settings`` (the primitives block with a joint's override) with
    ``n_basis`` basis functions; a width that was set is kept."""
    return RhythmicPrimitive(n_basis, T, dt, settings["alpha_z"], settings["beta_z"],
                             settings["width"], settings["amplitude"])


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
        elif joint.nq == 2 and joint.nv == 1:  # continuous: (cos, sin) of the angle
            q_ref[joint.idx_q:joint.idx_q + 2] = np.cos(posture), np.sin(posture)
    model = pin.buildReducedModel(robot.model, sorted(ids), q_ref)
    if model.nv == 0:
        raise ConfigError([("joints", "every joint is locked; nothing moves")])
    reduced = replace(robot, model=model, _visual_model=None)
    if robot._visual_model is not None:
        # Visuals loaded with the robot (example-robot-data's, whose package:// meshes the URDF
        # alone cannot resolve) are reduced with it, so viewers draw the reduced robot.
        _, reduced._visual_model = pin.buildReducedModel(robot.model, robot._visual_model,
                                                         sorted(ids), q_ref)
    return reduced
