r"""A planar walker: the robot on a sagittal floating base, its feet, and the left/right relabelling.

Any planar walker URDF becomes a walker here. Its root link gets a sagittal-plane floating base,
three coordinates :math:`(x, z, \vartheta)` in [m, m, rad]: the one-DoF joints ``base_x``
(prismatic along the world's x), ``base_z`` (along z) and ``base_pitch`` (a rotation about y), in
that order, carrying massless bodies, unless the URDF already has its own base joints. (Three
plain joints rather than one composite joint, so that every backend, the CasADi one included,
handles them and each coordinate has a name.) Each foot is a point contact: a frame of the URDF, or a
link and an offset in that link's frame in [m], added to the model as a frame. The ground is the
plane :math:`z = 0` (a slope tilts gravity instead, so the ground stays at z = 0).

After each touchdown the new stance leg is called what the old one was: the pairs in ``legs``
exchange their joint coordinates (:meth:`WalkerModel.relabel`), so one step's description serves
every step. The base coordinates are not relabelled (they are the root link's, shared by both
legs).

A walker whose root link is itself a leg (the compass gait: the root is one leg, the joint
``hip`` carries the other) names the pair ``[base_pitch, hip]``: a *chained* pair (a URDF
rooted elsewhere on that leg, e.g. at its foot, is mounted on the base at the hip), the second
joint's parent being the first and both turning about the same axis at the same point.
Exchanging the two legs is then the linear map
:math:`\vartheta' = \vartheta + q_{hip},\; q_{hip}' = -q_{hip}` (and the same on the
velocities), an involution like the plain exchange.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from feltool.errors import RobotError
from feltool.robot.robot import Robot, with_angle_coordinates

BASE_JOINTS = ("base_x", "base_z", "base_pitch")  # the (x, z, pitch) base feltool adds


@dataclass(frozen=True)
class FootSpec:
    """Where a foot touches the ground: a URDF frame, or a link and an offset in it in [m]."""

    frame: str | None = None
    link: str | None = None
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


def with_planar_base(robot: Robot, mount: pin.SE3 | None = None) -> Robot:
    """A copy of ``robot`` whose root link sits on the base joints ``base_x``, ``base_z``,
    ``base_pitch`` (q[0:3], v[0:3]: x, z in [m], pitch in [rad]; unactuated, unbounded), its
    frame at ``mount`` in the base's (default: the base's own frame).

    Gravity, limits and the source are kept.
    """
    base = pin.Model()
    parent = 0
    joints = (pin.JointModelPX(), pin.JointModelPZ(), pin.JointModelRY())
    for name, joint in zip(BASE_JOINTS, joints):
        parent = base.addJoint(parent, joint, pin.SE3.Identity(), name)
        base.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
    mount_frame = base.addFrame(pin.Frame("base_mount", parent, 0, pin.SE3.Identity(),
                                          pin.FrameType.OP_FRAME))
    model = pin.appendModel(base, robot.model, mount_frame,
                            pin.SE3.Identity() if mount is None else mount)
    model.gravity = robot.model.gravity
    model.effortLimit[:3] = 0.0
    model.lowerPositionLimit[:3] = -np.inf
    model.upperPositionLimit[:3] = np.inf
    return Robot(name=robot.name, model=model, source=robot.source, urdf_path=robot.urdf_path,
                 package_dirs=list(robot.package_dirs), urdf_xml=robot.urdf_xml)


@dataclass
class WalkerModel:
    """A planar walker's model, feet and relabelling.

    Attributes:
        robot: The robot with its floating base.
        base: Names of the base's joints (``base_x, base_z, base_pitch`` when feltool added them).
        feet: Foot name (e.g. ``left``, ``right``) -> Pinocchio frame id of its contact point.
        legs: Pairs of joint names exchanged at each touchdown.
        swap_q: ``(nq,)`` index permutation that relabels q (a continuous joint's cos/sin pair
            moves as a whole).
        swap_v: ``(nv,)`` index permutation that relabels v (and torques).
        chained: Chained pairs ``(idx_q, idx_v)`` of the first and of the second joint, relabelled
            after the permutation by ``first += second; second = -second``.
    """

    robot: Robot
    base: list[str]
    feet: dict[str, int]
    legs: list[tuple[str, str]]
    swap_q: np.ndarray
    swap_v: np.ndarray
    chained: tuple[tuple[int, int, int, int], ...] = ()

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
        q, v = q[self.swap_q], v[self.swap_v]
        for iq_a, iq_b, iv_a, iv_b in self.chained:
            q[iq_a] += q[iq_b]
            q[iq_b] = -q[iq_b]
            v[iv_a] += v[iv_b]
            v[iv_b] = -v[iv_b]
        return q, v

    def relabel_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R_q, R_v)`` with ``relabel(q, v) = (R_q q, R_v v)``, ``(nq, nq)`` and ``(nv, nv)``."""
        R_q = np.eye(self.model.nq)[self.swap_q]
        R_v = np.eye(self.model.nv)[self.swap_v]
        for iq_a, iq_b, iv_a, iv_b in self.chained:
            R_q[iq_a] += R_q[iq_b]
            R_q[iq_b] *= -1.0
            R_v[iv_a] += R_v[iv_b]
            R_v[iv_b] *= -1.0
        return R_q, R_v


def build_walker_model(robot: Robot, feet: dict[str, FootSpec], legs: list[tuple[str, str]],
                       base: str | list[str] = "planar") -> WalkerModel:
    """A :class:`WalkerModel` from a fixed-base URDF robot.

    Args:
        robot: The walker as loaded from its URDF (root link free of the world).
        feet: Foot name -> where it touches the ground.
        legs: Pairs of one-DoF joints exchanged at touchdown (``[[left_hip, right_hip], ...]``),
            or a chained pair ``[base_pitch, hip]`` of a walker whose root link is a leg.
        base: ``planar`` to add the (x, z, pitch) base above the root link, or the names of the
            URDF's own base joints (their coordinates are not relabelled).

    Raises:
        RobotError: naming an unknown frame, link or joint.
    """
    if base == "planar":
        robot, feet, note = _rerooted_at_the_hip(robot, feet, legs)
        if any(a == BASE_JOINTS[2] and robot.model.existJointName(b)
               and robot.model.joints[robot.model.getJointId(b)].nq == 2 for a, b in legs):
            robot = with_angle_coordinates(robot)  # a continuous hip paired with base_pitch
        robot = with_planar_base(robot, _hip_mount(robot, legs))
        robot.warnings += note  # (the load report's other lines were said when it was loaded)
        base_names = list(BASE_JOINTS)
    else:
        base_names = list(base)
        for name in base_names:
            robot.joint_id(name)
    model = robot.model
    frame_ids: dict[str, int] = {}
    for foot, spec in feet.items():
        frame_ids[foot] = _contact_frame(model, robot.name, foot, spec)
    swap_q, swap_v = np.arange(model.nq), np.arange(model.nv)
    chained = []
    for a, b in legs:
        ja, jb = (model.joints[robot.joint_id(n)] for n in (a, b))
        if (ja.nq, ja.nv) != (jb.nq, jb.nv) or ja.nv != 1:
            raise RobotError(f"robot '{robot.name}': legs pair [{a}, {b}]: both joints must be of "
                             "one kind with one degree of freedom")
        if _is_chained(model, robot, a, b):
            chained.append((ja.idx_q, jb.idx_q, ja.idx_v, jb.idx_v))
            continue
        qa, qb = np.arange(ja.idx_q, ja.idx_q + ja.nq), np.arange(jb.idx_q, jb.idx_q + jb.nq)
        swap_q[qa], swap_q[qb] = qb, qa
        swap_v[ja.idx_v], swap_v[jb.idx_v] = jb.idx_v, ja.idx_v
    return WalkerModel(robot=robot, base=base_names, feet=frame_ids,
                       legs=[(a, b) for a, b in legs], swap_q=swap_q, swap_v=swap_v,
                       chained=tuple(chained))


def _rerooted_at_the_hip(robot: Robot, feet: dict[str, FootSpec], legs: list[tuple[str, str]]
                         ) -> tuple[Robot, dict[str, FootSpec], list[str]]:
    """A walker whose URDF is rooted on a leg (a foot, a shin: a legs pair ``[a, b]`` of
    joints, neither ``base_pitch``, one hanging from the other) re-rooted at the link between
    the pair's joints (the hip's: :func:`feltool.robot.reroot.reroot_urdf`), so that its base is
    there and the pair exchanges like any other; the feet's offsets follow their links' new
    frames. The reversed joints' coordinates are the negatives of the URDF's (the note said).
    Else ``robot`` and ``feet`` as they are, and no note."""
    from feltool.robot.reroot import reroot_urdf
    from feltool.robot.robot import load_urdf_string

    model = robot.model
    for a, b in legs:
        if BASE_JOINTS[2] in (a, b) or not (model.existJointName(a) and model.existJointName(b)):
            continue
        ia, ib = model.getJointId(a), model.getJointId(b)
        if ib in (ia, 0) or ia == 0 or (model.parents[ib] != ia and model.parents[ia] != ib):
            continue
        lower = b if model.parents[ib] == ia else a
        xml = robot.description
        joint = next(j for j in ET.fromstring(xml).findall("joint") if j.get("name") == lower)
        hip = joint.find("parent").get("link")
        text, moved, flipped = reroot_urdf(xml, hip)
        new = load_urdf_string(text, name=robot.name, package_dirs=robot.package_dirs)
        if model.nq == model.nv:  # (its continuous joints were read in angle coordinates)
            new = with_angle_coordinates(new)
        new.source, new.urdf_path, new.model.gravity = robot.source, robot.urdf_path, \
            robot.model.gravity
        note = [f"robot '{robot.name}': rooted on a leg, re-rooted at its hip link '{hip}' "
                f"(joints {', '.join(flipped)} reversed: their angles are the negatives of the "
                "URDF's)"]
        out = {}
        for foot, spec in feet.items():
            if spec.link in moved:
                p = moved[spec.link].actInv(np.asarray(spec.offset, dtype=float))
                spec = FootSpec(frame=spec.frame, link=spec.link,
                                offset=tuple(float(x) for x in p))
            out[foot] = spec
        return new, out, note
    return robot, feet, []


def _hip_mount(robot: Robot, legs: list[tuple[str, str]]) -> pin.SE3 | None:
    """Where a root-leg walker's root link goes on the base: a chained pair ``[base_pitch,
    hip]`` whose ``hip`` hangs from the root link away from its origin (a URDF rooted at the
    stance foot, as Drake's and the course's compass gaits are: the hip 1 m above the root's
    frame) puts the root link at the inverse of the hip's placement, so that the base's
    (x, z, pitch) are the hip's position and the root leg's angle about it. None otherwise."""
    model = robot.model
    for a, b in legs:
        if a != BASE_JOINTS[2] or not model.existJointName(b):
            continue
        jb = model.getJointId(b)
        if model.parents[jb] != 0:
            continue
        placement = model.jointPlacements[jb]
        if not placement.isIdentity(1e-12):
            return placement.inverse()
    return None


def _is_chained(model: pin.Model, robot: Robot, a: str, b: str) -> bool:
    """Whether joint ``b`` hangs from joint ``a``'s body, at its origin, turning about the same
    axis (a root-leg walker's hip): then exchanging the legs is the chained relabelling.

    Raises:
        RobotError: when ``b`` hangs from ``a`` but not at its origin or not about its axis.
    """
    ia, ib = robot.joint_id(a), robot.joint_id(b)
    if model.parents[ib] != ia:
        return False
    names = [model.joints[i].shortname() for i in (ia, ib)]
    placement = model.jointPlacements[ib]
    if (names[0] != names[1] or not names[0].startswith("JointModelR") or names[0].startswith(
            "JointModelRUB") or not np.allclose(placement.translation, 0.0, atol=1e-12)
            or not np.allclose(placement.rotation, np.eye(3), atol=1e-12)):
        raise RobotError(f"robot '{robot.name}': legs pair [{a}, {b}]: '{b}' hangs from '{a}', so "
                         f"the pair is chained (a root-leg walker), which needs '{b}' at the "
                         f"origin of '{a}''s body, turning about the same axis")
    return True


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
