"""Joints and spatial algebra for the symbolic models: each Pinocchio joint described by its
placement, axis and kind, its transform and motion subspace, and the spatial cross products.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np
import pinocchio as pin

from feltool.errors import InputError

_REVOLUTE_ALIGNED = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}


_PRISMATIC_ALIGNED = {"JointModelPX": 0, "JointModelPY": 1, "JointModelPZ": 2}


_REVOLUTE_UNBOUNDED = {"JointModelRUBX": 0, "JointModelRUBY": 1, "JointModelRUBZ": 2}


_UNALIGNED = {
    "JointModelRevoluteUnaligned": "revolute",
    "JointModelPrismaticUnaligned": "prismatic",
}


@dataclass(frozen=True)
class Joint:
    """One joint of the tree, as the algorithms below need it.

    ``kind`` is ``"revolute"``, ``"prismatic"`` or ``"unbounded"`` (revolute with ``(cos, sin)``
    configuration), each with one degree of freedom, or ``"free_flyer"`` (a floating base:
    ``q = (x, y, z, quaternion x, y, z, w)``, ``v`` the linear and angular velocity in the
    joint's frame, as Pinocchio's ``JointModelFreeFlyer``); ``axis`` is the unit axis in the
    joint frame (zero for a free flyer); ``idx_q``/``idx_v`` index the joint's first
    coordinates in ``q`` and ``v``, ``nv`` its number of velocities; ``parent`` is the parent
    joint (0 = universe).
    """

    index: int
    name: str
    kind: str
    axis: np.ndarray
    parent: int
    idx_q: int
    idx_v: int
    placement_R: np.ndarray
    placement_p: np.ndarray
    inertia: np.ndarray  # 6x6 spatial inertia of the body about the joint frame origin
    nv: int = 1

    @property
    def v_slice(self) -> slice:
        """The joint's velocities in ``v``."""
        return slice(self.idx_v, self.idx_v + self.nv)


def _unit_axis(k: int) -> np.ndarray:
    axis = np.zeros(3)
    axis[k] = 1.0
    return axis


def describe_joints(model: pin.Model, floating: bool = False) -> list[Joint]:
    """The joints of ``model`` with their numbers, or :class:`InputError` for an unsupported one
    (a free flyer is supported only with ``floating``: the expressions of a floating base, not
    the casadi dynamics backend of a fixed-base experiment)."""
    joints = []
    for i in range(1, model.njoints):
        jmodel = model.joints[i]
        shortname = jmodel.shortname()
        name = model.names[i]
        nv = 1
        if floating and shortname == "JointModelFreeFlyer":
            kind, axis, nv = "free_flyer", np.zeros(3), 6
        elif shortname in _REVOLUTE_ALIGNED:
            kind, axis = "revolute", _unit_axis(_REVOLUTE_ALIGNED[shortname])
        elif shortname in _PRISMATIC_ALIGNED:
            kind, axis = "prismatic", _unit_axis(_PRISMATIC_ALIGNED[shortname])
        elif shortname in _REVOLUTE_UNBOUNDED:
            kind, axis = "unbounded", _unit_axis(_REVOLUTE_UNBOUNDED[shortname])
        elif shortname in _UNALIGNED:
            kind = _UNALIGNED[shortname]
            axis = np.array(jmodel.extract().axis, dtype=float).reshape(3)
            axis = axis / np.linalg.norm(axis)
        else:
            raise InputError(
                f"joint '{name}' has type {shortname}, which the casadi dynamics backend does not "
                "support (supported: revolute and prismatic joints about any axis, continuous "
                "revolute joints); use the 'pinocchio' backend for this robot"
            )
        placement = model.jointPlacements[i]
        joints.append(
            Joint(
                index=i,
                name=name,
                kind=kind,
                axis=axis,
                parent=int(model.parents[i]),
                idx_q=int(jmodel.idx_q),
                idx_v=int(jmodel.idx_v),
                placement_R=np.array(placement.rotation, dtype=float),
                placement_p=np.array(placement.translation, dtype=float),
                inertia=np.array(model.inertias[i].matrix(), dtype=float),
                nv=nv,
            )
        )
    return joints


def skew(p):
    """``[p]x``, the 3x3 matrix with ``[p]x y = p x y``."""
    return ca.vertcat(
        ca.horzcat(0, -p[2], p[1]),
        ca.horzcat(p[2], 0, -p[0]),
        ca.horzcat(-p[1], p[0], 0),
    )


def dm(array: np.ndarray) -> ca.DM:
    """A constant matrix with its exact zeros dropped, so that SX products skip them."""
    return ca.sparsify(ca.DM(np.asarray(array, dtype=float)))


def joint_rotation(joint: Joint, c, s):
    """Rotation of a revolute joint by the angle with cosine ``c`` and sine ``s``.

    Axis-aligned axes (including ``-e_k``, which turns by ``-th`` about ``e_k``) get the exact
    elementary rotation; other axes use Rodrigues' formula ``c I + s [u]x + (1 - c) u u^T``.
    """
    u = joint.axis
    for k in range(3):
        if abs(abs(u[k]) - 1.0) < 1e-15 and np.count_nonzero(u) == 1:
            s_k = s if u[k] > 0 else -s
            if k == 0:
                return ca.vertcat(
                    ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s_k), ca.horzcat(0, s_k, c)
                )
            if k == 1:
                return ca.vertcat(
                    ca.horzcat(c, 0, s_k), ca.horzcat(0, 1, 0), ca.horzcat(-s_k, 0, c)
                )
            return ca.vertcat(ca.horzcat(c, -s_k, 0), ca.horzcat(s_k, c, 0), ca.horzcat(0, 0, 1))
    return c * ca.DM.eye(3) + s * dm(_skew_np(u)) + (1 - c) * dm(np.outer(u, u))


def _skew_np(p: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


def quaternion_matrix(quat) -> ca.SX:
    """The rotation of a quaternion ``(x, y, z, w)`` (Eigen's ``toRotationMatrix``, as Pinocchio
    reads a free flyer's configuration: the same operations, no normalisation)."""
    x, y, z, w = quat[0], quat[1], quat[2], quat[3]
    tx, ty, tz = 2 * x, 2 * y, 2 * z
    twx, twy, twz = tx * w, ty * w, tz * w
    txx, txy, txz = tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    return ca.vertcat(ca.horzcat(1 - (tyy + tzz), txy - twz, txz + twy),
                      ca.horzcat(txy + twz, 1 - (txx + tzz), tyz - twx),
                      ca.horzcat(txz - twy, tyz + twx, 1 - (txx + tyy)))


def joint_placement(joint: Joint, q) -> tuple:
    """``liMi = placement * M_J(q)`` of a joint relative to its parent, as ``(R, p)`` (3x3
    rotation, position in [m])."""
    R0 = dm(joint.placement_R)
    p0 = dm(joint.placement_p)
    qi = q[joint.idx_q]
    if joint.kind == "free_flyer":
        return (ca.mtimes(R0, quaternion_matrix(q[joint.idx_q + 3:joint.idx_q + 7])),
                p0 + ca.mtimes(R0, q[joint.idx_q:joint.idx_q + 3]))
    if joint.kind == "prismatic":
        return ca.SX(R0), p0 + ca.mtimes(R0, dm(joint.axis)) * qi
    if joint.kind == "revolute":
        c, s = ca.cos(qi), ca.sin(qi)
    else:  # unbounded: q = (cos th, sin th), used as is (as Pinocchio does)
        c, s = q[joint.idx_q], q[joint.idx_q + 1]
    return ca.mtimes(R0, joint_rotation(joint, c, s)), ca.SX(p0)


def joint_transform(joint: Joint, q) -> ca.SX:
    """``X_i`` (6x6): maps a spatial motion from the parent's frame to joint ``i``'s frame.

    With ``liMi = (R, p) = placement * M_J(q)``, ``X_i = [[R^T, -R^T [p]x], [0, R^T]]``.
    """
    R, p = joint_placement(joint, q)
    Rt = R.T
    zero = ca.SX(3, 3)
    return ca.vertcat(
        ca.horzcat(Rt, -ca.mtimes(Rt, skew(p))),
        ca.horzcat(zero, Rt),
    )


def motion_subspace(joint: Joint) -> ca.DM:
    """``S`` (6 x nv): ``(0, u)`` for revolute joints, ``(u, 0)`` for prismatic ones, the
    identity for a free flyer (its velocity is the body's, in its own frame)."""
    if joint.kind == "free_flyer":
        return ca.DM.eye(6)
    if joint.kind == "prismatic":
        return dm(np.concatenate([joint.axis, np.zeros(3)]))
    return dm(np.concatenate([np.zeros(3), joint.axis]))


def subspace_times(joint: Joint, x):
    """``S x_J``: the spatial motion of the joint's coordinates ``x_J`` of a vector ``x``
    (nv: velocities or accelerations)."""
    if joint.nv == 1:
        return motion_subspace(joint) * x[joint.idx_v]
    return ca.mtimes(motion_subspace(joint), x[joint.v_slice])


def subspace_project(joint: Joint, f):
    """``S^T f`` (nv_J): a spatial force's generalized force on the joint's coordinates."""
    if joint.nv == 1:
        return ca.dot(motion_subspace(joint), f)
    return ca.mtimes(motion_subspace(joint).T, f)


def cross_motion(m, x):
    """``m x x`` for spatial motions: ``(w x v_x + v x w_x, w x w_x)``."""
    v, w = m[:3], m[3:]
    vx, wx = x[:3], x[3:]
    return ca.vertcat(ca.cross(w, vx) + ca.cross(v, wx), ca.cross(w, wx))


def cross_force(m, f):
    """``m x* f`` for a motion ``m`` and a force ``f``: ``(w x f_l, w x f_a + v x f_l)``."""
    v, w = m[:3], m[3:]
    fl, fa = f[:3], f[3:]
    return ca.vertcat(ca.cross(w, fl), ca.cross(w, fa) + ca.cross(v, fl))


def gravity_acceleration(model: pin.Model) -> ca.DM:
    """``a_0 = -g``: the base acceleration that stands in for gravity [m/s^2]."""
    g = np.concatenate([model.gravity.linear, model.gravity.angular])
    return dm(-g)


def check_has_joints(model: pin.Model) -> None:
    if model.njoints < 2:
        raise InputError("the model has no joints: nothing to build dynamics for")
