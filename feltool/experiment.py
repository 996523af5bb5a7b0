"""Build an experiment from a config.

Building is separate from running: :func:`load_experiment` returns an :class:`Experiment` whose
robot, primitives, feedback laws and learner can be inspected before anything is simulated;
:func:`~feltool.seed.run_seed` runs one seed's learning cycles (available here too, imported on
first use: this module does not import the one that runs what it builds).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from feltool import spectral
from feltool.bounds import MAX_ANGLE
from feltool.checks import target_problems
from feltool.config import (
    MAX_DEMO_SAMPLES,
    ExperimentConfig,
    JointConfig,
    apply_overrides,
    parse_config,
    read_yaml,
    too_few_samples,
)
from feltool.control import FeedbackLaw, FrameAngle
from feltool.disturbances import problems as disturbance_problems
from feltool.dynamics import Dynamics, make_dynamics
from feltool.errors import ConfigError, FeltoolError, RobotError
from feltool.events import check_events
from feltool.fel import FEL_UPDATES, FeedbackErrorLearner
from feltool.hybrid import Allocation, HybridLoop, Walker
from feltool.memory import check_memory
from feltool.model_fel import ModelLearner, PhaseBasisFeatures, RegressorFeatures
from feltool.motion import motion_problems, refuse_varying_phase, varying_phase
from feltool.plant import make_plant, plant_problems, plant_robot
from feltool.rmp import PrimitiveSet, RhythmicPrimitive, samples_demo, sine_demo
from feltool.robot import Robot, data_dir, load_robot, robot_spec, with_angle_coordinates
from feltool.simulate import ClosedLoop, Limits
from feltool.walker_config import physical_loop, walker_model


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
        demo_fit_rms: Per joint fitted to a demonstration: RMS over the cycle of its RMP's
            limit cycle minus the demonstration, in [rad] (the fit error of eq. 2.4).
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
    demo_fit_rms: dict[str, float] = field(default_factory=dict)

    @property
    def phase_varies(self) -> bool:
        """Whether cycles differ in length (a period of no whole number of steps, period
        events, an adaptive phase): metrics.csv then has cycle_s and frequency_hz."""
        if getattr(self, "_phase_varies", None) is None:
            self._phase_varies = any(not where.endswith((".amplitude", ".goal"))
                                     for where, _ in varying_phase(self.config))
        return self._phase_varies

    @property
    def learned_joints(self) -> list[str]:
        return [name for name, jc in self.config.joints.items() if jc.learn is not None]

    @property
    def stabilized_joints(self) -> list[str]:
        return [n for n in self.joints if self.config.joints[n].role == "stabilize"]

    @property
    def error_joints(self) -> list[str]:
        return [n for n, m in zip(self.joints, self.learner.error_mask) if m > 0]

    @property
    def engine(self) -> str:
        """The engine that runs this experiment's learning cycles: ``compiled`` (the cycle as
        generated C, :mod:`feltool.compiled`) or ``python`` (Pinocchio calls per step); see
        :attr:`engine_reason`."""
        return self._engine()[0]

    @property
    def engine_reason(self) -> str:
        """Why :attr:`engine` runs this experiment, in words (``backend: auto``: what the
        compiled engine lacks, or that it runs everything)."""
        return self._engine()[1]

    def _engine(self) -> tuple[str, str]:
        if getattr(self, "_engine_choice", None) is None:
            from feltool.compiled import c_compiler, unsupported

            backend = self.config.backend
            if backend == "compiled":
                choice = ("compiled", "backend: compiled")
            elif backend != "auto":
                choice = ("python", f"backend: {backend}")
            elif c_compiler() is None:
                choice = ("python", "backend auto: no C compiler (cc or gcc; set CC)")
            else:
                missing = unsupported(self)
                choice = (("python", f"backend auto: {missing[0][0]}: {missing[0][1]}")
                          if missing else ("compiled", "backend auto"))
            self._engine_choice = choice
        return self._engine_choice

    def compiled_cycle(self):
        """The compiled engine of this experiment (its cycles built and compiled on first
        use, cached on disk; :class:`feltool.compiled_engine.CompiledEngine`). With ``backend:
        auto``, a compilation that fails switches the experiment to the Python engine (and
        says so once) and returns None."""
        if getattr(self, "_compiled", None) is None:
            from feltool.compiled_engine import CompiledEngine

            strict = self.config.backend == "compiled"
            engine = CompiledEngine(self, vm_fallback=strict)
            if engine.functions is None:
                from feltool.compiled import note_once

                reason = "backend auto: compiling the cycle failed"
                note_once(f"{reason}; running the Python engine instead")
                self._engine_choice = ("python", reason)
                return None
            self._compiled = engine
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
            elif kind == "perturbed":
                # the demo's fit plus the fit of a smooth random motion: the first three
                # harmonics of the cycle with N(0, 1) coefficients, scaled to w_std [rad] RMS
                # (a sample demo's fitted weights are huge: a scale relative to them means
                # nothing in radians, and random weights would be a rough, violent motion)
                prim = next(self.primitives.primitives[i] for i, s in
                            self.primitives.slices.items() if s == sl)
                n = prim.n_steps
                phi = 2.0 * np.pi * np.arange(n) / n
                c = rng.normal(0.0, 1.0, (3, 2))
                h = np.arange(1, 4)[:, None]
                d = c[:, :1] * np.cos(h * phi) + c[:, 1:] * np.sin(h * phi)
                dd = h * (-c[:, :1] * np.sin(h * phi) + c[:, 1:] * np.cos(h * phi))
                ddd = -h**2 * (c[:, :1] * np.cos(h * phi) + c[:, 1:] * np.sin(h * phi))
                w = 2.0 * np.pi / (n * self.config.dt)  # d phi / dt [rad/s]
                scale = w_std / float(np.sqrt(np.mean(d.sum(0) ** 2)))
                dtheta = prim.fit(scale * d.sum(0), scale * w * dd.sum(0),
                                  scale * w**2 * ddd.sum(0), phi, goal=0.0)
                theta[sl] += dtheta
                theta[sl.stop - 1] += rng.uniform(-g_spread, g_spread)
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
    if robot is not None:
        problems += _name_problems(raw, named or robot)
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


def build_experiment(raw: dict[str, Any], source: Path | None = None,
                     check_targets: bool = True) -> Experiment:
    """Build an :class:`Experiment` from a raw config mapping; a stabilized quantity no
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
    src = str(source) if source else None
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
            series = _positions_series(d, source, f"joints.{name}.demo", src)
            q, v, a = _demo_trajectory(d, T, fine_t, series)
            if series is not None:  # positions only: eq. 2.4 over the series' coefficients
                thetas[i] = prim.fit_series(series)
            else:
                goal = float(np.mean(q)) if d.kind == "samples" else d.mean
                thetas[i] = prim.fit(q, v, a, 2.0 * np.pi * fine_t / T, goal=goal)
            if not jc.follow_demo:
                fit_rms[name] = prim.fit_rms(thetas[i], q, 2.0 * np.pi * fine_t / T)
            if jc.follow_demo and jc.learn is None:
                fixed[i] = _demo_trajectory(d, T, np.arange(prim.n_steps) * dt, series)
            elif jc.follow_demo:
                # the feedback holds the demo; the forward trajectory is the demo plus the
                # learned RMP, a correction that starts at zero (init demo) or perturbed
                referenced[i] = _demo_trajectory(d, T, np.arange(prim.n_steps) * dt, series)
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
        scale = jc.learn.rate_scale
        rates += [scale * L.rates.weights] * (len(idx) - 1) + [scale * L.rates.goal]
        center = jc.learn.goal_center if jc.learn.goal_center is not None else (
            float(centers[i]) if stabilizing[i] else float(goals[i]))
        scale = (jc.learn.perturbation_rad if jc.learn.init == "perturbed"
                 else jc.learn.weight_scale * w_ref)
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
    if L.update not in FEL_UPDATES:  # (feltool.ilc imports scipy.signal: only when needed)
        from feltool.ilc import problems as ilc_problems

        unsupported = ilc_problems(cfg) + unsupported
    if unsupported:
        raise ConfigError(unsupported, str(source) if source else None)
    learner = FeedbackErrorLearner(primitives, np.array(learned, dtype=int),
                                   np.array(is_goal, dtype=bool), error_mask,
                                   np.array(rates), L.update, L.damping, L.sensitivity,
                                   L.fd_epsilon)
    _check_phase(cfg, joints, robot, {joints[i] for i in (*fixed, *referenced)}, src)
    plant = dynamics
    if cfg.plant is not None:
        if any(ev.changes_world for ev in cfg.events):
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
        if model_learner is not None:
            raise ConfigError([("learning.model", "model learning is not supported for "
                                                  "walking/actuated robots yet")], src)
        if wm is not None:
            if cfg.actuation is not None:
                raise ConfigError([("actuation", "a physical walker's motors are its URDF "
                                                 "joints (every joint but the base's); remove "
                                                 "the actuation block")], src)
            if cfg.plant is not None:
                raise ConfigError([("plant", "not supported for a physical walker yet")], src)
            hybrid = physical_loop(cfg, wm, law, dynamics, joints, error_mask, src)
            hybrid.reference = dict(referenced)
        else:
            hybrid = HybridLoop(plant, law, _allocation(cfg, robot, joints, src),
                                _walker(cfg, robot, joints, src), actuated, dt,
                                cfg.sim.substeps, cfg.sim.integrator, error_mask)
    if referenced and (wm is None or hybrid is None):
        raise ConfigError([(f"joints.{joints[i]}.follow_demo", "with learn: only for a "
                            "physical walker (walking.feet)") for i in referenced], src)
    exp = Experiment(cfg, robot, dynamics, joints, primitives, theta_demo, law, loop, learner,
                     init, source, hybrid, plant, model_learner, fit_rms)
    if L.sensitivity == "casadi" and learner.n_learned:
        from feltool.compiled import feedforward_jacobian

        learner.set_casadi_jacobian(_BufferedFn(feedforward_jacobian(exp)))
    if cfg.backend == "compiled":
        from feltool.compiled import check_supported

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
        free = None if robot.urdf_path is None and robot.urdf_xml is None else \
            pin.buildModelFromXML(robot.description, root)
        if free is None or free.nv != robot.model.nv + 2:
            raise ConfigError([("walking.contact_frame", "needs a URDF robot with no locked "
                                                         "joints")], src)
        if not free.existFrame(w.contact_frame):
            raise ConfigError([("walking.contact_frame", f"the robot has no frame "
                                                         f"'{w.contact_frame}'")], src)
        foot = free.getFrameId(w.contact_frame)
    fall_row = (_joint_row(w.fall.link_angle, joints, "walking.fall.link_angle", src)
                if w.fall else None)
    placement = None
    if w.foot_placement is not None:
        fp = w.foot_placement
        for key in ("angle_of", "follow"):
            if getattr(fp, key) not in joints:
                raise ConfigError([(f"walking.foot_placement.{key}", f"'{getattr(fp, key)}' is "
                                    "not a key of walking.absolute")], src)
        placement = (joints.index(fp.angle_of), joints.index(fp.follow), fp.gain)
    return Walker(A, Pi, _joint_row(w.guard.link_angle, joints, "walking.guard.link_angle", src),
                  w.guard.value, 1.0 if w.guard.direction == "rising" else -1.0,
                  tuple(w.guard.window), w.steps_per_cycle, w.impact, fall_row,
                  w.fall.max_abs if w.fall else np.inf, free, foot, placement)


def _demo_trajectory(d, T: float, t: np.ndarray, series: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A demonstration's position [rad], velocity [rad/s] and acceleration [rad/s^2] at times
    ``t`` [s] of a period ``T`` [s]; a positions demo from its Fourier ``series``."""
    if d.kind == "samples":
        return samples_demo(d.q, d.v, d.a, T, t)
    if d.kind == "positions":
        w = 2.0 * np.pi / T
        rows = spectral.trig(w * np.asarray(t, dtype=float), spectral.degree(series))
        dc = spectral.differentiate(series)
        return rows @ series, w * (rows @ dc), w * w * (rows @ spectral.differentiate(dc))
    return sine_demo(d.mean, d.amplitude, T, d.phase, t, d.harmonics, d.delay)


def _positions_series(d, source: Path | None, where: str, src: str | None) -> np.ndarray | None:
    """The Fourier series of a positions demo (None for the other kinds), from its list or its
    CSV column (read here, every problem named by its YAML path)."""
    if d.kind != "positions":
        return None
    q = d.q
    if q is None:
        path = Path(d.csv).expanduser()
        if not path.is_absolute() and source is not None:
            path = source.parent / path
        q = _csv_column(path, d.column, where, src)
        problem = too_few_samples(len(q), d.periods)
        if problem:
            raise ConfigError([(f"{where}.csv", problem)], src)
    return spectral.from_samples(np.asarray(q, dtype=float), d.periods)


def _csv_column(path: Path, column: str, where: str, src: str | None) -> list[float]:
    """The numbers of one column of a CSV file with a header row [rad]."""
    def fail(key: str, message: str):
        return ConfigError([(f"{where}.{key}", message)], src)

    try:
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            header = [h.strip() for h in next(reader, [])]
            if column not in header:
                raise fail("column", f"{path} has no column '{column}' (its columns: "
                                     f"{', '.join(header) or 'none'})")
            j, values = header.index(column), []
            for line, row in enumerate(reader, start=2):
                if not any(c.strip() for c in row):
                    continue
                cell = row[j].strip() if j < len(row) else ""
                try:
                    x = float(cell)
                except ValueError:
                    raise fail("csv", f"{path} line {line}: '{cell}' in column '{column}' is "
                                      "not a number") from None
                if not abs(x) <= MAX_ANGLE:
                    raise fail("csv", f"{path} line {line}: {cell} is not within "
                                      f"+-{MAX_ANGLE:g}")
                values.append(x)
                if len(values) > MAX_DEMO_SAMPLES:
                    raise fail("csv", f"{path} has more than {MAX_DEMO_SAMPLES} samples")
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise fail("csv", f"cannot read {path}: {getattr(exc, 'strerror', None) or exc}") \
            from None
    return values


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


_RUNNING = {"CycleOutcome": "feltool.seed", "SeedResult": "feltool.seed",
            "run_seed": "feltool.seed", "stabilization_errors": "feltool.observers"}


def __getattr__(name: str):
    """``run_seed`` and its results, from the modules that run experiments (imported on first
    use, so that building never imports running: no import cycle)."""
    if name in _RUNNING:
        import importlib

        return getattr(importlib.import_module(_RUNNING[name]), name)
    raise AttributeError(f"module 'feltool.experiment' has no attribute '{name}'")


__all__ = ["Experiment", "build_experiment", "load_experiment", "validate", "FeltoolError"]
