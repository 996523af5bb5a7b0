r"""A 3D legged robot: a free-flyer base (Pinocchio's ``JointModelFreeFlyer``) with named point
feet.

A foot is a point of a link, named by a frame of the model (``{"frame": "FL_FOOT"}``) or by a
link and an offset in that link's frame (``{"link": "FL_LOWER_LEG", "offset": [0, 0, -0.16]}``,
in [m]); the latter adds an operational frame ``foot_<name>`` to the model. The ground is the
plane :math:`z = 0` with gravity along :math:`-z`; a foot in stance touches it at its point.

Coordinates are Pinocchio's: ``q = (x, y, z, quaternion (x, y, z, w), joints)`` (``nq = 7 + k``),
``v = (base linear and angular velocity in the base frame, joint rates)`` (``nv = 6 + k``). Every
joint after the free flyer is a motor (:attr:`LeggedModel.motors`, velocity indices ``6 ...``), its
limit the URDF's effort limit unless :class:`LeggedModel` is given another.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.errors import ConfigError, RobotError
from feltool.robot.mujoco import MIN_INERTIA
from feltool.robot.robot import check_model_dynamics
from feltool.walking.legged.tree_feet import leg_joints, quadruped_feet

#: The feet of Solo-12 in example-robot-data, by their frames
SOLO12_FEET = {"FL": {"frame": "FL_FOOT"}, "FR": {"frame": "FR_FOOT"},
               "HL": {"frame": "HL_FOOT"}, "HR": {"frame": "HR_FOOT"}}


@dataclass
class LeggedModel:
    """A floating-base robot with point feet.

    Attributes:
        model: The Pinocchio model, its first joint a free flyer (foot frames added).
        feet: ``{foot name: frame id}`` of the feet's contact points, in the given order.
        effort: Motor effort limits ``(k,)`` in [N m] (the URDF's, or the override).
        q0: A reference configuration ``(nq,)`` (example-robot-data's, else the neutral one).
        name: The robot's name.
    """

    model: pin.Model
    feet: dict[str, int]
    effort: np.ndarray
    q0: np.ndarray
    name: str = "legged"
    data: pin.Data = field(init=False, repr=False)

    def __post_init__(self):
        self.data = self.model.createData()

    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    @property
    def motors(self) -> list[str]:
        """The motor joints' names, in velocity order (the free flyer's 6 rows are passive)."""
        return list(self.model.names[2:])

    @property
    def mass(self) -> float:
        """Total mass in [kg]."""
        return float(pin.computeTotalMass(self.model))

    def selection(self) -> np.ndarray:
        """``B`` ``(nv, k)``: the motors' generalized forces, ``tau = B u``."""
        B = np.zeros((self.nv, self.nv - 6))
        B[6:, :] = np.eye(self.nv - 6)
        return B

    def leg(self, foot: str) -> list[int]:
        """The velocity indices of the joints between the base and the ``foot`` (its leg)."""
        m = self.model
        return sorted(m.joints[j].idx_v
                      for j in leg_joints(m, m.frames[self.feet[foot]].parentJoint))

    def foot_positions(self, q: np.ndarray) -> np.ndarray:
        """``(n_feet, 3)`` positions of the feet's contact points in the world, in [m]."""
        pin.framesForwardKinematics(self.model, self.data, q)
        return np.array([self.data.oMf[f].translation for f in self.feet.values()])

    def standing(self, q: np.ndarray | None = None, iterations: int = 20) -> np.ndarray:
        """A configuration with every foot on the ground (z = 0), from ``q`` (default
        :attr:`q0`): the base lowered by the feet's mean height, then Gauss-Newton on the feet's
        heights over the joints only (least norm), the base's pose kept."""
        q = (self.q0 if q is None else q).copy()
        q[2] -= self.foot_positions(q)[:, 2].mean()
        for _ in range(iterations):
            z = self.foot_positions(q)[:, 2]
            if np.abs(z).max() < 1e-12:
                break
            pin.computeJointJacobians(self.model, self.data, q)
            J = np.array([pin.getFrameJacobian(self.model, self.data, f, pin.LOCAL_WORLD_ALIGNED)[2]
                          for f in self.feet.values()])
            J[:, :6] = 0.0
            dv = -np.linalg.pinv(J) @ z
            q = pin.integrate(self.model, q, dv)
        return q


def inverse_kinematics(legged: LeggedModel, base: np.ndarray, targets: np.ndarray,
                       q: np.ndarray | None = None, iterations: int = 30) -> np.ndarray:
    """The configuration with the base at ``base`` (``(7,)``: position [m], quaternion x, y,
    z, w) and every foot at its ``targets`` row ``(n_feet, 3)`` [m]: Gauss-Newton on the joints
    alone (least norm, from ``q`` or :attr:`LeggedModel.q0`), to 1e-12 m or ``iterations``."""
    m, d = legged.model, legged.data
    q = (legged.q0 if q is None else q).copy()
    q[:7] = base
    for _ in range(iterations):
        err = (legged.foot_positions(q) - targets).ravel()
        if np.abs(err).max() < 1e-12:
            break
        pin.computeJointJacobians(m, d, q)
        J = np.vstack([pin.getFrameJacobian(m, d, f, pin.LOCAL_WORLD_ALIGNED)[:3, 6:]
                       for f in legged.feet.values()])
        dv = np.zeros(legged.nv)
        dv[6:] = -np.linalg.lstsq(J, err, rcond=None)[0]
        q = pin.integrate(m, q, dv)
    return q


def legged_model(model: pin.Model, feet: dict[str, dict], q0: np.ndarray | None = None,
                 effort: float | np.ndarray | None = None, name: str = "legged") -> LeggedModel:
    """A :class:`LeggedModel` from a free-flyer Pinocchio model and the feet's description.

    Args:
        model: The robot on a free flyer (copied; foot frames are added to the copy).
        feet: ``{name: {"frame": FRAME}}`` or ``{name: {"link": LINK, "offset": [x, y, z]}}``
            (offset in [m], in the link's frame).
        q0: A reference configuration (default: the neutral one, base 1 m up).
        effort: Motor effort limit(s) in [N m] replacing the URDF's (one value for all motors,
            or one per motor).
        name: The robot's name.

    Raises:
        RobotError: the model has no free flyer as its first joint.
        ConfigError: a foot names no frame or link of the model, or its entry is malformed
            (the error names ``walking.feet.<name>``).
    """
    model = pin.Model(model)
    if model.njoints < 2 or model.joints[1].shortname() != "JointModelFreeFlyer":
        raise RobotError(f"{name}: a legged robot's first joint must be a free flyer "
                         f"(pinocchio.JointModelFreeFlyer); its first joint is "
                         f"{model.joints[1].shortname() if model.njoints > 1 else 'none'}")
    if not feet:
        raise ConfigError([("walking.feet", "name at least one foot")])
    problems, ids = [], {}
    for foot, spec in feet.items():
        where = f"walking.feet.{foot}"
        if not isinstance(spec, dict) or set(spec) not in ({"frame"}, {"link", "offset"}, {"link"}):
            problems.append((where, "give {frame: NAME} or {link: NAME, offset: [x, y, z]}"))
            continue
        if "frame" in spec:
            if not model.existFrame(spec["frame"]):
                problems.append((where, f"no frame '{spec['frame']}' in {name}"))
                continue
            ids[foot] = model.getFrameId(spec["frame"])
            continue
        link = spec["link"]
        if not model.existFrame(link, pin.BODY):
            problems.append((where, f"no link '{link}' in {name}"))
            continue
        offset = np.asarray(spec.get("offset", [0.0, 0.0, 0.0]), float)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            problems.append((where + ".offset", "three finite numbers [x, y, z] in [m]"))
            continue
        body = model.frames[model.getFrameId(link, pin.BODY)]
        placement = body.placement * pin.SE3(np.eye(3), offset)
        ids[foot] = model.addFrame(pin.Frame(f"foot_{foot}", body.parentJoint, placement,
                                             pin.FrameType.OP_FRAME))
    if problems:
        raise ConfigError(problems)
    k = model.nv - 6
    if effort is None:
        lim = np.array(model.effortLimit[6:], float)
    else:
        lim = np.broadcast_to(np.asarray(effort, float), (k,)).copy()
        if np.any(lim <= 0) or not np.all(np.isfinite(lim)):
            raise ConfigError([("effort", f"positive finite motor limits in [N m], got {effort}")])
    if q0 is None:
        q0 = pin.neutral(model)
        q0[2] = 1.0
    return LeggedModel(model=model, feet=ids, effort=lim, q0=np.asarray(q0, float).copy(),
                       name=name)


def posture_q(model: pin.Model, q0: np.ndarray, posture: dict[str, float], name: str
              ) -> np.ndarray:
    """``q0`` ``(nq,)`` with its motor joints set from ``posture`` (joint name -> angle [rad]
    or position [m]). Raises :class:`ConfigError` naming ``walking.posture.<name>`` for a name
    that is no motor joint of one coordinate of ``model`` (robot ``name``)."""
    q0, problems = np.array(q0, float), []
    for joint, value in posture.items():
        j = model.getJointId(joint) if model.existJointName(joint) else model.njoints
        if j < 2 or j >= model.njoints or model.joints[j].nq != 1:
            problems.append((f"walking.posture.{joint}", f"no motor joint '{joint}' in "
                             f"{name} (its motors: {', '.join(model.names[2:])})"))
            continue
        q0[model.joints[j].idx_q] = float(value)
    if problems:
        raise ConfigError(problems)
    return q0


def load_legged_urdf(path: str | Path, feet: dict[str, dict] | None = None, effort=None,
                     posture: dict[str, float] | None = None) -> LeggedModel:
    """A legged robot from a URDF file, put on a free flyer (``JointModelFreeFlyer`` above its
    root link), in its zero posture (base 1 m up) with the motor joints of ``posture`` set
    (:func:`posture_q`); ``feet`` as :func:`legged_model` takes them, None or empty: a
    quadruped's four found from its tree (:func:`~.tree_feet.quadruped_feet`). Raises
    :class:`RobotError` naming the file when it cannot be read."""
    path = Path(path)
    if not path.is_file():
        raise RobotError(f"{path}: no such URDF file")
    try:
        model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    except Exception as exc:  # urdfdom's messages
        raise RobotError(f"{path}: not a readable URDF ({exc})") from None
    check_model_dynamics(model, str(path))
    q0 = pin.neutral(model)
    q0[2] = 1.0
    q0 = posture_q(model, q0, posture or {}, path.stem)
    feet = feet or quadruped_feet(model, q0, path.stem)
    return legged_model(model, feet, q0=q0, effort=effort, name=path.stem)


def load_solo12(effort: float | None = None) -> LeggedModel:
    """Solo-12 from example-robot-data (nq 19, nv 18), its feet the frames ``FL_FOOT``,
    ``FR_FOOT``, ``HL_FOOT``, ``HR_FOOT`` (the foot spheres' centres), ``q0`` its reference
    posture. Its URDF gives every motor 1000 N m; pass ``effort`` for a real limit."""
    import example_robot_data as erd

    robot = erd.load("solo12")
    return legged_model(robot.model, SOLO12_FEET, q0=np.array(robot.q0), effort=effort,
                        name="solo12")


#: A sole's corners in its link's frame [m]: length ``(back, front)``, half width, and the
#: sole's depth below the link's origin
CORNERS = {"toe_out": (1, 1), "toe_in": (1, -1), "heel_out": (0, 1), "heel_in": (0, -1)}


def sole_corners(name: str, link: str, back: float, front: float, half_width: float,
                 depth: float, outward: float = 1.0) -> dict[str, dict]:
    """Four point feet ``<name>_toe_out``, ``_toe_in``, ``_heel_out``, ``_heel_in`` at the
    corners of a flat sole of ``link``: from ``-back`` to ``front`` [m] along the link's x,
    ``half_width`` [m] to each side along its y (``outward`` +1 when the outer edge is at +y,
    -1 when at -y), ``depth`` [m] below its origin (the feet's entries of
    :func:`legged_model`)."""
    out = {}
    for corner, (toe, side) in CORNERS.items():
        x = front if toe else -back
        out[f"{name}_{corner}"] = {"link": link,
                                   "offset": [x, side * outward * half_width, -depth]}
    return out


#: The feet of Talos' legs in example-robot-data: each sole's four corners (:func:`load_talos_legs`)
TALOS_FEET = {**sole_corners("L", "leg_left_6_link", 0.11, 0.10, 0.065, 0.107, 1.0),
              **sole_corners("R", "leg_right_6_link", 0.11, 0.10, 0.065, 0.107, -1.0)}


def load_talos_legs(effort: float | None = None) -> LeggedModel:
    """Talos' legs and torso from example-robot-data (``talos_legs``, nq 19, nv 18, 48.7 kg),
    each flat sole its four corners (:func:`sole_corners`: the feet ``L_*`` and ``R_*``), a
    rectangle 0.21 m x 0.13 m inside the sole of its collision mesh (x from -0.116 to 0.105
    m, y within +-0.067 m, 0.107 m below the ankle's last joint); ``q0`` its reference
    posture; the URDF's effort limits (100-300 N m)."""
    import example_robot_data as erd

    robot = erd.load("talos_legs")
    return legged_model(robot.model, TALOS_FEET, q0=np.array(robot.q0), effort=effort,
                        name="talos_legs")


@dataclass(frozen=True)
class Payload:
    """A point mass fixed to the base: ``mass`` [kg] at ``offset`` [m] in the base's frame
    (an unknown world for feedback error learning: the controller's model stays without it).
    Its rotational inertia about itself is :data:`~feltool.robot.mujoco.MIN_INERTIA` on each
    axis, which MuJoCo needs."""

    mass: float
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        offset = np.asarray(self.offset, float)
        if not (np.isfinite(self.mass) and self.mass > 0) or offset.shape != (3,) or \
                not np.all(np.isfinite(offset)):
            raise ConfigError([("payload", f"a positive mass [kg] and a finite offset (x, y, z) "
                                           f"[m], got {self.mass}, {self.offset}")])

    def inertia(self) -> pin.Inertia:
        """The payload as Pinocchio's spatial inertia in the base joint's frame."""
        return pin.Inertia(float(self.mass), np.asarray(self.offset, float),
                           MIN_INERTIA * np.eye(3))


def _world(legged: LeggedModel, model: pin.Model, name: str) -> LeggedModel:
    """``legged`` with another dynamics ``model`` of the same joints and frames (a world the
    known model does not know), named ``name``."""
    return LeggedModel(model=model, feet=dict(legged.feet), effort=legged.effort.copy(),
                       q0=legged.q0.copy(), name=name)


def with_payload(legged: LeggedModel, payload: Payload | None) -> LeggedModel:
    """A copy of ``legged`` with ``payload`` added to its base joint's inertia (the plant's
    model of the unknown world), or ``legged`` itself when ``payload`` is None."""
    if payload is None:
        return legged
    model = pin.Model(legged.model)
    model.inertias[1] = model.inertias[1] + payload.inertia()
    return _world(legged, model, f"{legged.name}+payload")


def sloped(legged: LeggedModel, angle: float, roll: float = 0.0) -> LeggedModel:
    """A copy of ``legged`` standing on a ground inclined by ``angle`` [rad] about the ground's
    y axis and ``roll`` [rad] about its x axis (the plant's model of the unknown world): the
    ground stays the plane z = 0 of the robot's coordinates and the gravity turns, about y
    by ``-angle`` and then about x by ``roll`` (positive ``angle``: gravity towards +x, downhill ahead,
    as the fixed-base experiments' slope event; positive ``roll``: towards +y, downhill to the
    left). The contacts, friction cones and checks keep their meaning relative to the ground."""
    if not (np.isfinite(angle) and np.isfinite(roll)) or max(abs(angle), abs(roll)) >= np.pi / 4:
        raise ConfigError([("slope", f"angles within +-pi/4 [rad], got {angle}, {roll}")])
    model = pin.Model(legged.model)
    c, s = np.cos(angle), np.sin(angle)
    pitch = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # about y by -angle
    c, s = np.cos(roll), np.sin(roll)
    lateral = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])  # about x by roll
    model.gravity = pin.Motion(lateral @ pitch @ model.gravity.linear, np.zeros(3))
    return _world(legged, model, f"{legged.name}+slope")


def scaled_masses(legged: LeggedModel, scale: float) -> LeggedModel:
    """A copy of ``legged`` with every body's mass and rotational inertia times ``scale`` [-],
    the centres of mass where they are (the plant's model of a robot whose masses the known
    model gets wrong: 1.2 is 20 % heavier than it thinks)."""
    if not (np.isfinite(scale) and scale > 0):
        raise ConfigError([("masses", f"a positive mass scale, got {scale}")])
    model = pin.Model(legged.model)
    for j in range(1, model.njoints):
        own = model.inertias[j]
        model.inertias[j] = pin.Inertia(own.mass * scale, own.lever, own.inertia * scale)
    return _world(legged, model, f"{legged.name}x{scale:g}")

