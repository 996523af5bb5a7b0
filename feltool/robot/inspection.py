"""What ``feltool inspect`` reports about a robot: the answers a config needs.

:func:`describe` lists, at a pose (the neutral one unless given):

* every joint: type, axis, position, limits (``None`` where there is none: a continuous joint
  is an angle with no limits, whatever Pinocchio's cos/sin coordinates say), effort;
* every frame: its parent joint, its position in [m], and the ``target: {frame, vector,
  about}`` that holds it, with that target's value at the pose;
* total mass in [kg] and centre of mass in [m];
* every target a stabilizing joint can hold and its value at the pose: link angles (sums of
  joint angles about one axis) and frame angles (:class:`~feltool.robot.frames.FrameAngle`).

:func:`config_skeleton` writes a config that ``feltool check`` accepts unchanged.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from feltool.dynamics.pinocchio import mass_matrix
from feltool.errors import InputError
from feltool.files import dump_yaml
from feltool.robot.frames import FrameAngle
from feltool.robot.robot import Robot

_KINDS = {"R": "revolute", "RevoluteUnaligned": "revolute", "RUB": "continuous",
          "RevoluteUnboundedUnaligned": "continuous", "P": "prismatic",
          "PrismaticUnaligned": "prismatic", "FreeFlyer": "floating", "Planar": "planar",
          "Spherical": "spherical", "SphericalZYX": "spherical", "Translation": "translation"}
#: Natural frequency of the skeleton's PD loops in [rad/s] (2 Hz; well inside 100 Hz sampling).
SKELETON_OMEGA = 2.0 * math.pi * 2.0


def joint_kind(model: pin.Model, jid: int) -> str:
    """revolute | continuous | prismatic | floating | planar | spherical | ... of a joint."""
    short = model.joints[jid].shortname().removeprefix("JointModel")
    for key in sorted(_KINDS, key=len, reverse=True):
        if short.startswith(key) and (len(short) == len(key) or short[len(key)] in "XYZ"):
            return _KINDS[key]
    return short


def joint_angle(model: pin.Model, jid: int, q: np.ndarray) -> float | None:
    """A one-degree-of-freedom joint's coordinate in [rad] or [m] (a continuous joint's angle
    from its cos/sin pair), else None."""
    joint = model.joints[jid]
    if joint.nv != 1:
        return None
    if joint.nq == 2:
        return float(math.atan2(q[joint.idx_q + 1], q[joint.idx_q]))
    return float(q[joint.idx_q])


def parse_pose(robot: Robot, text: str | None) -> np.ndarray:
    """The configuration ``joint=value,...`` (values in [rad] or [m]; others neutral)."""
    model = robot.model
    q = pin.neutral(model)
    for item in (text or "").split(","):
        if not item.strip():
            continue
        name, sep, value = item.partition("=")
        name = name.strip()
        try:
            x = float(value)
        except ValueError:
            x = math.nan
        if not sep or not math.isfinite(x):
            raise InputError(f"--pose: cannot read '{item.strip()}'; write joint=value, e.g. "
                             f"{robot.joint_names[0]}=0.5")
        jid = robot.joint_id(name) if model.existJointName(name) else None
        if jid is None or model.joints[jid].nv != 1:
            one = [n for n in robot.joint_names if model.joints[model.getJointId(n)].nv == 1]
            raise InputError(f"--pose: robot '{robot.name}' has no one-degree-of-freedom joint "
                             f"'{name}'; its joints: {', '.join(one)}")
        joint = model.joints[jid]
        if joint.nq == 2:
            q[joint.idx_q:joint.idx_q + 2] = math.cos(x), math.sin(x)
        else:
            q[joint.idx_q] = x
    return q


def _limits(model: pin.Model, jid: int) -> tuple[float | None, float | None]:
    """Position limits in [rad] or [m]; None where there is none (infinite, a URDF's
    lower = upper, a continuous joint)."""
    joint = model.joints[jid]
    if joint.nq != 1 or joint.nv != 1:
        return None, None
    lo, hi = float(model.lowerPositionLimit[joint.idx_q]), float(model.upperPositionLimit[joint.idx_q])
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        return None, None
    return lo, hi


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _vec(v) -> list[float]:
    """A vector rounded for display (and -0.0 made 0.0)."""
    return [round(float(x), 6) + 0.0 for x in v]


def _joint_jacobian(model: pin.Model, data: pin.Data, jid: int, frame) -> np.ndarray:
    """The motion (6,) of a one-degree-of-freedom joint per unit of its velocity (Pinocchio's
    joint Jacobian column; kinematics already computed)."""
    J = pin.getJointJacobian(model, data, jid, frame).reshape(6, -1)
    return J[:, model.joints[jid].idx_v]


def world_axes(model: pin.Model, data: pin.Data, q: np.ndarray) -> dict[int, np.ndarray]:
    """Joint id -> the world axis a one-degree-of-freedom joint turns about at ``q`` (unit),
    for rotating joints."""
    pin.computeJointJacobians(model, data, q)
    axes = {}
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nv == 1:
            w = _joint_jacobian(model, data, jid, pin.LOCAL_WORLD_ALIGNED)[3:]
            if np.linalg.norm(w) > 1e-9:
                axes[jid] = w / np.linalg.norm(w)
    return axes


def link_chain(model: pin.Model, jid: int, axes: dict[int, np.ndarray]) -> list[str]:
    """The joints whose angles add up to the absolute angle, about joint ``jid``'s axis, of the
    link it moves: ``jid`` and its ancestors turning about the same world axis (parallel, same
    sense), root first. Only joints with one coordinate (a config can give them a role)."""
    if jid not in axes or model.joints[jid].nq != 1:
        return []
    chain, j = [], jid
    while j > 0:
        if j in axes and model.joints[j].nq == 1 and axes[j] @ axes[jid] > 1.0 - 1e-9:
            chain.append(model.names[j])
        j = model.parents[j]
    return chain[::-1]


def frame_target(model: pin.Model, frame_id: int, axes: dict[int, np.ndarray],
                 q: np.ndarray) -> dict | None:
    """The ``target: {frame, vector, about, value}`` that holds a frame at ``q``: ``about`` is
    the world axis of the nearest rotating joint moving it, ``vector`` the frame's own x, y or
    z axis most perpendicular to it (z when several are). None for a frame no joint turns."""
    frame = model.frames[frame_id]
    j = frame.parentJoint
    while j > 0 and j not in axes:
        j = model.parents[j]
    if j == 0:
        return None
    about = axes[j]
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    R = data.oMf[frame_id].rotation
    k = min((2, 0, 1), key=lambda i: abs(R[:, i] @ about) - (1e-9 if i == 2 else 0.0))
    vector = np.eye(3)[k]
    about = np.where(np.abs(about) < 1e-9, 0.0, about)
    angle = FrameAngle(model, frame.name, vector, about).value(q)
    return {"frame": frame.name, "vector": _vec(vector), "about": _vec(about),
            "value": round(angle, 6) + 0.0}


def describe(robot: Robot, q: np.ndarray | None = None) -> dict:
    """Joints, bodies, frames, mass, centre of mass and targets of ``robot`` at ``q`` (default
    neutral), as plain data (JSON-safe: no infinities)."""
    model = robot.model
    q = pin.neutral(model) if q is None else q
    data = model.createData()
    axes = world_axes(model, data, q)
    joints = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        lo, hi = _limits(model, jid)
        axis = None
        if joint.nv == 1:  # the motion subspace in the joint's frame: turning or sliding axis
            S = _joint_jacobian(model, data, jid, pin.LOCAL)
            axis = _vec(S[3:] if np.linalg.norm(S[3:]) > 1e-9 else S[:3])
        joints.append({
            "name": model.names[jid], "type": joint_kind(model, jid), "axis": axis,
            "nq": joint.nq, "nv": joint.nv, "position": joint_angle(model, jid, q),
            "lower": lo, "upper": hi,
            "effort": _finite(model.effortLimit[joint.idx_v]) if joint.nv == 1 else None,
            "actuated": bool(joint.nv and model.effortLimit[joint.idx_v] > 0),
            "parent": model.names[model.parents[jid]],
        })
    bodies = [{"name": model.names[jid], "mass": float(model.inertias[jid].mass)}
              for jid in range(1, model.njoints)]
    frames = []
    pin.framesForwardKinematics(model, data, q)
    for fid, frame in enumerate(model.frames):
        if frame.name == "universe":
            continue
        frames.append({"name": frame.name, "type": str(frame.type).rsplit(".", 1)[-1],
                       "parent_joint": model.names[frame.parentJoint],
                       "position": _vec(data.oMf[fid].translation),
                       "target": frame_target(model, fid, axes, q)})
    targets = []
    for jid in range(1, model.njoints):
        chain = link_chain(model, jid, axes)
        if chain:
            value = sum(joint_angle(model, model.getJointId(n), q) for n in chain)
            targets.append({"link_angle": chain, "value": round(value, 6) + 0.0})
    targets += [f["target"] for f in frames if f["target"] is not None]
    com = pin.centerOfMass(model, data, q)
    return {"name": robot.name, "source": robot.source, "warnings": list(robot.warnings),
            "pose": {j["name"]: j["position"] for j in joints if j["position"] is not None},
            "joints": joints, "bodies": bodies, "total_mass": robot.total_mass,
            "com": _vec(com), "frames": frames, "targets": targets}


# -- the config skeleton --------------------------------------------------------------------------

def _posture(model: pin.Model, jid: int, q: np.ndarray | None) -> float:
    """The skeleton's posture of a joint: its value at the given pose, else the middle of its
    limits (0 without limits)."""
    if q is not None:
        return float(joint_angle(model, jid, q))
    lo, hi = _limits(model, jid)
    return 0.0 if lo is None else 0.5 * (lo + hi)


def skeleton_gains(model: pin.Model, q: np.ndarray, rows: np.ndarray, cols: list[int],
                   omega: float = SKELETON_OMEGA) -> list[tuple[float, float]]:
    r"""PD gains ``(kp, kd)`` per controlled quantity ``y_i = rows[i] @ q[cols]`` (its torque
    acting on joint ``cols[i]``), the other joints held: for the effective inertia
    :math:`m_i = 1 / (r_i M^{-1} e_i)` at ``q``, a loop of natural frequency ``omega`` [rad/s]
    stiffened by twice the gravity stiffness it must overcome, critically damped:
    :math:`k_P = m_i \omega^2 + 2 \|\partial g/\partial q\|_2`,
    :math:`k_D = 2 \sqrt{m_i k_P}`."""
    data = model.createData()
    M = mass_matrix(model, data, q)
    G = pin.computeGeneralizedGravityDerivatives(model, data, q)[np.ix_(cols, cols)]
    Minv = np.linalg.inv(M[np.ix_(cols, cols)])
    k_g = float(np.linalg.norm(G, 2))
    masses = [1.0 / max(float(row @ Minv[:, i]), 1e-12) for i, row in enumerate(rows)]
    kps = [m * omega**2 + 2.0 * k_g for m in masses]
    return [(kp, 2.0 * math.sqrt(m * kp)) for m, kp in zip(masses, kps)]


def _num(x: float) -> str:
    return f"{x:.4g}"


def config_skeleton(robot: Robot, q: np.ndarray | None = None) -> str:
    """A config for ``robot`` that ``feltool check`` accepts unchanged: the first two joints
    with one coordinate move (the first tracks a small sine, the second holds its link's
    absolute angle, or its own, and learns its RMP), the others are locked at their postures;
    gains from the robot's inertia (:func:`skeleton_gains`). ``q``: the pose to start from."""
    model = robot.model
    free = [jid for jid in range(1, model.njoints)
            if model.joints[jid].nv == 1 and model.joints[jid].nq == 1][:2]
    postures = {jid: _posture(model, jid, q) for jid in range(1, model.njoints)
                if model.joints[jid].nv == 1}
    qp = pin.neutral(model)
    for jid, value in postures.items():
        j = model.joints[jid]
        qp[j.idx_q:j.idx_q + j.nq] = [value] if j.nq == 1 else [math.cos(value), math.sin(value)]
    axes = world_axes(model, model.createData(), qp)
    names = [model.names[j] for j in free]
    rows = np.eye(len(free))
    chain = link_chain(model, free[-1], axes) if free else []
    if len(free) == 2 and names[0] in chain:
        rows[1, 0] = 1.0
    cols = [model.joints[j].idx_v for j in free]
    gains = skeleton_gains(model, qp, rows, cols) if free else []
    lines = [f"name: {robot.name}_experiment", f"robot: {robot.source}",
             "gravity: 9.81", "period_s: 1.0", "sim: {rate_hz: 100, cycles: 20}",
             "primitives: {basis: 10}",
             "joints:   # role: track | stabilize | passive | locked (joints not listed are "
             "locked at 0)"]
    for k, jid in enumerate(free):
        (kp, kd), name, posture = gains[k], model.names[jid], postures[jid]
        lo, hi = _limits(model, jid)
        gain = f"gains: {{kp: {_num(kp)}, kd: {_num(kd)}}}"
        if k == 0 and len(free) == 2:
            size = 0.2 if joint_kind(model, jid) != "prismatic" else 0.05
            amplitude = size if lo is None else min(size, 0.25 * (hi - lo))
            lines += [f"  {name}:   # {joint_kind(model, jid)}: tracks a sine",
                      "    role: track",
                      f"    demo: {{kind: sine, mean: {_num(posture)}, amplitude: "
                      f"{_num(amplitude)}}}", f"    {gain}"]
        else:
            held = [names[0], name] if rows[k, 0] and k == 1 else [name]
            value = float(rows[k] @ [postures[j] for j in free])
            lines += [f"  {name}:   # {joint_kind(model, jid)}: holds a target, RMP learned by FEL",
                      "    role: stabilize",
                      f"    target: {{link_angle: [{', '.join(held)}], value: {_num(value)}}}",
                      f"    {gain}", "    learn: {init: random, weight_scale: 0.3, "
                      "goal_spread: 0.05}"]
    for jid, posture in postures.items():
        if jid in free:
            continue
        j = model.joints[jid]
        lo, hi = _limits(model, jid)
        span = "no limits" if lo is None else f"limits [{lo:.3g}, {hi:.3g}]"
        lines.append(f"  {model.names[jid]}: {{role: locked, posture: {_num(posture)}}}   # "
                     f"{joint_kind(model, jid)}, {span}")
    for jid in range(1, model.njoints):
        if model.joints[jid].nv != 1:
            lines.append(f"  # {model.names[jid]}: {joint_kind(model, jid)} joint "
                         f"({model.joints[jid].nv} DoF) - locked at its neutral value")
    lines += ["  # other targets: feltool inspect lists link angles and frame angles, e.g.",
              "  #   target: {frame: LINK, vector: [0, 0, 1], about: [0, 1, 0], value: 0.0}",
              "learning:   # a Levenberg-Marquardt step (its rate a fraction, whatever the "
              "robot's scale); the goal fixed",
              "  {error: stabilizing, update: gauss_newton, rates: {gauss_newton: 0.3, goal: 0.0}}",
              "seeds: 2"]
    if not free:
        lines.insert(0, "# this robot has no joint with one coordinate: nothing can move")
    return "\n".join(lines) + "\n"


def to_yaml(info: dict) -> str:
    """``describe``'s data as YAML (for ``feltool inspect --format yaml``)."""
    return dump_yaml(info, sort_keys=False, width=100)
