"""The physical walker from its config: the walker model, its checks, and the closed loop.

``walking.feet`` makes a walker physical (:mod:`feltool.walking.physical`). This module turns the config's
``walking`` block into a :class:`~feltool.walking.model.WalkerModel` (checking that each foot sits at
the end of its leg's chain and that the legs are mirror images under the relabelling) and builds
the :class:`~feltool.walking.physical.PhysicalLoop`; every problem names its YAML path.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.config.experiment import ExperimentConfig
from feltool.config.walking import WalkingConfig
from feltool.control.feedback import FeedbackLaw
from feltool.dynamics.interface import Dynamics
from feltool.errors import ConfigError, RobotError
from feltool.robot.robot import Robot
from feltool.walking.checks import ContactChecks
from feltool.walking.model import BASE_JOINTS, FootSpec, WalkerModel, build_walker_model
from feltool.walking.physical import PhysicalLoop, PhysicalWalker
from feltool.walking.pinned import Allocation, Walker


def walker_model(w: WalkingConfig, robot: Robot) -> tuple[WalkerModel | None, list]:
    """The walker model of a physical ``walking`` block, and the ``(yaml_path, message)``
    problems found (the model is None when it cannot be built)."""
    problems: list[tuple[str, str]] = []
    names = robot.joint_names
    # a root-leg walker (the compass gait) pairs the base's pitch with its hip: [base_pitch, hip]
    leg_names = names + (list(BASE_JOINTS) if w.base == "planar" else [])
    for i, pair in enumerate(w.legs or []):
        for j, name in enumerate(pair):
            if name not in leg_names:
                problems.append((f"walking.legs.{i}.{j}", f"robot '{robot.name}' has no joint "
                                 f"'{name}' (its joints: {', '.join(names)})"))
    if isinstance(w.base, list):
        if len(w.base) != 3:
            problems.append(("walking.base", "give the URDF's three base joints (x, z, pitch) "
                                             "or 'planar'"))
        for i, name in enumerate(w.base):
            if name not in names:
                problems.append((f"walking.base.{i}", f"robot '{robot.name}' has no joint "
                                 f"'{name}' (its joints: {', '.join(names)})"))
    if problems:
        return None, problems
    feet = {foot: FootSpec(frame=f.frame, link=f.link, offset=tuple(f.offset))
            for foot, f in w.feet.items()}
    try:
        model = build_walker_model(robot, feet, [tuple(p) for p in w.legs], w.base)
    except RobotError as exc:
        text = str(exc)
        where = next((f"walking.feet.{f}" for f in feet if f"foot '{f}'" in text), "walking")
        return None, [(where, text)]
    problems += _chain_problems(w, model)
    if not problems:
        problems += _symmetry_problems(w, model)
    return model, problems


def _chain_problems(w: WalkingConfig, wm: WalkerModel) -> list[tuple[str, str]]:
    """Each foot at the end of a leg: its frame's joint has no child joint, and its chain
    passes through that side's joint of every legs pair and through no joint of the other
    side."""
    m = wm.model
    problems = []
    children = {j: [c for c in range(1, m.njoints) if m.parents[c] == j] for j in range(m.njoints)}
    side = {"left": 0, "right": 1}
    # a root-leg walker's root leg carries the other leg: the second joint of a chained pair
    carried = {m.getJointId(p[1]) for p in w.legs if _chained(m, p)}
    for foot, fid in wm.feet.items():
        joint = m.frames[fid].parentJoint
        where = f"walking.feet.{foot}"
        if [c for c in children[joint] if c not in carried]:
            problems.append((where, f"the contact point is on joint '{m.names[joint]}', which "
                             "carries further joints ("
                             + ", ".join(m.names[c] for c in children[joint])
                             + "): a foot must be at the end of a leg's chain"))
            continue
        chain, j = set(), joint
        while j > 0:
            chain.add(m.names[j])
            j = m.parents[j]
        own = [p[side[foot]] for p in w.legs]
        # a chained pair (the compass gait's [base_pitch, hip]: the second joint carried by the
        # first) lies on both chains; only the other side's joint of a plain pair must not
        other = [p[1 - side[foot]] for p in w.legs if not _chained(m, p)]
        if not all(n in chain for n in own) or any(n in chain for n in other):
            problems.append((where, f"the contact point's chain ({', '.join(sorted(chain))}) "
                             f"must pass through the {foot} joints of walking.legs "
                             f"({', '.join(own)}) and not through the other side's"))
    return problems


def _chained(m: pin.Model, pair) -> bool:
    a, b = (m.getJointId(n) for n in pair)
    return m.parents[b] == a or m.parents[a] == b


def _symmetry_problems(w: WalkingConfig, wm: WalkerModel) -> list[tuple[str, str]]:
    """The relabelling must map one foot onto the other: right(q) == left(relabel(q))."""
    m, d = wm.model, wm.model.createData()
    rng = np.random.default_rng(0)
    q = pin.neutral(m)
    for j in range(1, m.njoints):
        if m.joints[j].nq == 1:
            q[m.joints[j].idx_q] = rng.uniform(-0.5, 0.5)
    q2, _ = wm.relabel(q, np.zeros(m.nv))
    pin.framesForwardKinematics(m, d, q)
    right = wm.foot_position(d, "right")
    pin.framesForwardKinematics(m, d, q2)
    left = wm.foot_position(d, "left")
    if np.abs(right - left).max() > 1e-9:
        return [("walking.legs", "exchanging the legs' joints does not move the left foot to "
                                 "where the right one was: the legs pairs (or the URDF's legs) "
                                 "are not mirror images")]
    return []


def physical_loop(cfg: ExperimentConfig, wm: WalkerModel, law: FeedbackLaw, dynamics: Dynamics,
                  joints: list[str], error_mask: np.ndarray, src: str | None) -> PhysicalLoop:
    """The closed loop of a physical walker (config already validated)."""
    w = cfg.walking
    m = wm.model
    effort = np.array([m.effortLimit[i] for i in range(m.nv)])
    checks = ContactChecks(w.friction, w.normal_force_min, w.scuff_exempt, None,
                           cfg.sim.torque_limits, w.clearance_tol_m, w.scuffs_behind)
    fall_row, fall_max = None, np.inf
    if w.fall is not None:
        fall_row = np.zeros(m.nv)
        for name in w.fall.link_angle:
            if name not in joints:
                raise ConfigError([("walking.fall.link_angle", f"'{name}' is not a joint of the "
                                    f"walker; joints: {', '.join(joints)}")], src)
            fall_row[joints.index(name)] += 1.0
        fall_max = w.fall.max_abs
    other = "right" if w.stance == "left" else "left"
    try:
        walker = PhysicalWalker(wm, checks, w.steps_per_cycle, w.phase, fall_row, fall_max,
                                w.stance, other)
    except RobotError as exc:
        raise ConfigError([("walking.base", str(exc))], src) from None
    walker.checks.effort = np.where(effort[walker.motor_v] > 0, effort[walker.motor_v], np.inf)
    return PhysicalLoop(dynamics, law, walker, cfg.dt, cfg.sim.substeps, error_mask)


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


def pinned_allocation(cfg: ExperimentConfig, robot: Robot, joints: list[str],
                src: str | None) -> Allocation | None:
    if cfg.actuation is None:
        return None
    B = np.stack([_joint_row(m, joints, f"actuation.motors.{name}", src)
                  for name, m in cfg.actuation.motors.items()], axis=1)
    if np.linalg.matrix_rank(B) < B.shape[1]:
        raise ConfigError([("actuation.motors", "the motors' rows are linearly dependent")], src)
    return Allocation(B, cfg.actuation.allocation, robot.model)


def pinned_walker(cfg: ExperimentConfig, robot: Robot, joints: list[str],
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
