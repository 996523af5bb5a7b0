r"""A planar walker: the robot on a sagittal floating base, its feet, and the left/right relabelling.

Any planar walker URDF becomes a walker here. Its root link gets a sagittal-plane floating base,
three coordinates :math:`(x, z, \vartheta)` in [m, m, rad] (prismatic along the world's x and z,
then a rotation about the world's y: Pinocchio's composite joint ``PX * PZ * RY``), unless the
URDF already has its own base joints. Each foot is a point contact: a frame of the URDF, or a
link and an offset in that link's frame in [m], added to the model as a frame. The ground is the
plane :math:`z = 0` (a slope tilts gravity instead, so the ground stays at z = 0).

After each touchdown the new stance leg is called what the old one was: the pairs in ``legs``
exchange their joint coordinates (:meth:`WalkerModel.relabel`), so one step's description serves
every step. The base coordinates are not relabelled (they are the root link's, shared by both
legs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from feltool.errors import RobotError
from feltool.robot import Robot

BASE_JOINT = "walker_base"  # name of the (x, z, pitch) base joint feltool adds


@dataclass(frozen=True)
class FootSpec:
    """Where a foot touches the ground: a URDF frame, or a link and an offset in it in [m]."""

    frame: str | None = None
    link: str | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


def planar_base_joint() -> pin.JointModel:
    """The sagittal floating base: x, z translation in [m], then pitch about y in [rad]."""
    joint = pin.JointModelComposite(3)
    joint.addJoint(pin.JointModelPX())
    joint.addJoint(pin.JointModelPZ())
    joint.addJoint(pin.JointModelRY())
    return joint


def with_planar_base(robot: Robot) -> Robot:
    """A copy of ``robot`` whose root link sits on the (x, z, pitch) base joint ``walker_base``.

    Gravity and the source are kept; the base is the model's first joint (q[0:3], v[0:3]).
    """
    if robot.urdf_path is None:
        raise RobotError(f"robot '{robot.name}': a planar base needs the URDF file")
    try:
        model = pin.buildModelFromXML(robot.urdf_path.read_text(), planar_base_joint(), BASE_JOINT)
    except Exception as exc:
        raise RobotError(f"{robot.urdf_path}: Pinocchio could not add a planar base: {exc}") from None
    model.gravity = robot.model.gravity
    return Robot(name=robot.name, model=model, source=robot.source, urdf_path=robot.urdf_path,
                 package_dirs=list(robot.package_dirs))


@dataclass
class WalkerModel:
    """A planar walker's model, feet and relabelling.

    Attributes:
        robot: The robot with its floating base (``model.nq == model.nv``: planar, no quaternion).
        base: Names of the base's joints (``[walker_base]`` when feltool added it).
        feet: Foot name (e.g. ``left``, ``right``) -> Pinocchio frame id of its contact point.
        legs: Pairs of joint names exchanged at each touchdown.
        swap: ``(nv,)`` index permutation that relabels q and v (the same permutation: nq == nv).
    """

    robot: Robot
    base: list[str]
    feet: dict[str, int]
    legs: list[tuple[str, str]]
    swap: np.ndarray

    @property
    def model(self) -> pin.Model:
        return self.robot.model

    def foot_position(self, data: pin.Data, foot: str) -> np.ndarray:
        """(x, z) of a foot's contact point in [m], after ``pin.framesForwardKinematics``."""
        p = data.oMf[self.feet[foot]].translation
        return np.array([p[0], p[2]])

    def foot_jacobian(self, q: np.ndarray, data: pin.Data, foot: str) -> np.ndarray:
        """``(2, nv)`` Jacobian of a foot's (x, z) in the world, in [m/rad] or [1]."""
        J = pin.computeFrameJacobian(self.model, data, q, self.feet[foot],
                                     pin.LOCAL_WORLD_ALIGNED)
        return J[[0, 2], :]

    def relabel(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exchange the legs' coordinates (q and v), so the new stance leg has the old one's name."""
        return q[self.swap], v[self.swap]


def build_walker_model(robot: Robot, feet: dict[str, FootSpec], legs: list[tuple[str, str]],
                       base: str | list[str] = "planar") -> WalkerModel:
    """A :class:`WalkerModel` from a fixed-base URDF robot.

    Args:
        robot: The walker as loaded from its URDF (root link free of the world).
        feet: Foot name -> where it touches the ground.
        legs: Pairs of one-DoF joints exchanged at touchdown (``[[left_hip, right_hip], ...]``).
        base: ``planar`` to add the (x, z, pitch) base above the root link, or the names of the
            URDF's own base joints (their coordinates are not relabelled).

    Raises:
        RobotError: naming an unknown frame, link or joint.
    """
    if base == "planar":
        robot = with_planar_base(robot)
        base_names = [BASE_JOINT]
    else:
        base_names = list(base)
        for name in base_names:
            robot.joint_id(name)
    model = robot.model
    if model.nq != model.nv:
        raise RobotError(f"robot '{robot.name}': a planar walker needs nq == nv (no quaternion "
                         f"joints); it has nq = {model.nq}, nv = {model.nv}")
    frame_ids: dict[str, int] = {}
    for foot, spec in feet.items():
        frame_ids[foot] = _contact_frame(model, robot.name, foot, spec)
    swap = np.arange(model.nv)
    for a, b in legs:
        ia, ib = robot.v_index(a), robot.v_index(b)
        swap[ia], swap[ib] = ib, ia
    return WalkerModel(robot=robot, base=base_names, feet=frame_ids,
                       legs=[(a, b) for a, b in legs], swap=swap)


def _contact_frame(model: pin.Model, robot_name: str, foot: str, spec: FootSpec) -> int:
    if spec.frame is not None:
        if not model.existFrame(spec.frame):
            raise RobotError(f"robot '{robot_name}': foot '{foot}': no frame '{spec.frame}'; its "
                             "frames are: " + ", ".join(f.name for f in model.frames))
        return int(model.getFrameId(spec.frame))
    if spec.link is None or not model.existBodyName(spec.link):
        raise RobotError(f"robot '{robot_name}': foot '{foot}': no link '{spec.link}'; its links "
                         "are: " + ", ".join(f.name for f in model.frames
                                             if f.type == pin.FrameType.BODY))
    body = model.frames[model.getBodyId(spec.link)]
    placement = body.placement * pin.SE3(np.eye(3), np.asarray(spec.offset, dtype=float))
    return int(model.addFrame(pin.Frame(f"{foot}_contact", body.parentJoint, model.getBodyId(spec.link),
                                        placement, pin.FrameType.OP_FRAME)))
