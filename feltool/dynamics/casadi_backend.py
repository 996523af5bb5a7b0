"""CasADi backend: the known models as symbolic expressions built from a Pinocchio model.

The PyPI ``pin`` wheels ship no ``pinocchio.casadi``, so this module rebuilds the rigid-body
algorithms in CasADi ``SX`` from the numbers stored in a :class:`pinocchio.Model`: the kinematic
tree (``model.parents``), the joint placements (``model.jointPlacements``, SE3), the joint types
and axes, the link inertias (``model.inertias``), the rotor armature (``model.armature``) and the
gravity (``model.gravity``). The results are checked against ``pin.rnea`` / ``pin.aba`` /
``pin.computeRNEADerivatives`` in ``tests/test_casadi_dynamics.py``.

Conventions (the same as Pinocchio's)
-------------------------------------
* A spatial motion is the 6-vector ``(v, w)``: linear velocity [m/s] first, angular [rad/s] second
  (accelerations likewise in [m/s^2], [rad/s^2]); a spatial force is ``(f, n)``: force [N] first,
  torque [N m] second. Each body's quantities are expressed in its own joint frame.
* ``liMi = jointPlacements[i] * M_J(q_i)`` is the placement of body ``i`` in its parent's frame
  (rotation ``R``, translation ``p`` [m]). Its inverse action on motions is the 6x6 matrix
  ``X_i = [[R^T, -R^T [p]x], [0, R^T]]`` (parent coordinates -> body coordinates), and ``X_i^T``
  carries a force from the body frame to the parent frame.
* The 1-DoF joints have a constant motion subspace ``S`` in their own frame: ``(0, u)`` for a
  revolute joint about the unit axis ``u`` and ``(u, 0)`` for a prismatic one, so the joint bias
  acceleration ``c_J`` is zero and ``v_i x (S qd_i)`` is the only velocity-product term.
* Gravity enters as a fictitious base acceleration ``a_0 = -g`` (``g = model.gravity``,
  e.g. ``(0, 0, -9.81)`` [m/s^2]), exactly as in Pinocchio.
* The rotor armature ``model.armature`` [kg m^2] or [kg] adds ``armature * a`` to the torque, as in
  Pinocchio >= 3 (``rnea``, ``aba`` and ``crba`` all include it).

Supported joints: revolute about X/Y/Z (``JointModelRX/RY/RZ``) or an arbitrary axis
(``JointModelRevoluteUnaligned``), prismatic along X/Y/Z (``JointModelPX/PY/PZ``) or an arbitrary
axis (``JointModelPrismaticUnaligned``), and the continuous (unbounded) revolute joints
``JointModelRUBX/RUBY/RUBZ`` whose configuration is ``(cos th, sin th)`` (nq = 2, nv = 1).
Fixed joints are merged into their parent body by Pinocchio and never reach this module. Any
other joint (free-flyer, spherical, planar, mimic, composite, helical, universal, ...) raises
:class:`feltool.errors.InputError` naming the joint.
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


# --------------------------------------------------------------------------------------------
# The joints


@dataclass(frozen=True)
class _Joint:
    """One 1-DoF joint of the tree, as the algorithms below need it.

    ``kind`` is ``"revolute"``, ``"prismatic"`` or ``"unbounded"`` (revolute with ``(cos, sin)``
    configuration); ``axis`` is the unit axis in the joint frame; ``idx_q``/``idx_v`` index the
    joint's coordinates in ``q`` and ``v``; ``parent`` is the parent joint (0 = universe).
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


def _unit_axis(k: int) -> np.ndarray:
    axis = np.zeros(3)
    axis[k] = 1.0
    return axis


def _describe_joints(model: pin.Model) -> list[_Joint]:
    """The joints of ``model`` with their numbers, or :class:`InputError` for an unsupported one."""
    joints = []
    for i in range(1, model.njoints):
        jmodel = model.joints[i]
        shortname = jmodel.shortname()
        name = model.names[i]
        if shortname in _REVOLUTE_ALIGNED:
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
            _Joint(
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
            )
        )
    return joints


# --------------------------------------------------------------------------------------------
# Spatial algebra on SX (6-vectors ordered linear, angular)


def _skew(p):
    """``[p]x``, the 3x3 matrix with ``[p]x y = p x y``."""
    return ca.vertcat(
        ca.horzcat(0, -p[2], p[1]),
        ca.horzcat(p[2], 0, -p[0]),
        ca.horzcat(-p[1], p[0], 0),
    )


def _dm(array: np.ndarray) -> ca.DM:
    """A constant matrix with its exact zeros dropped, so that SX products skip them."""
    return ca.sparsify(ca.DM(np.asarray(array, dtype=float)))


def _joint_rotation(joint: _Joint, c, s):
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
    return c * ca.DM.eye(3) + s * _dm(_skew_np(u)) + (1 - c) * _dm(np.outer(u, u))


def _skew_np(p: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])


def _joint_transform(joint: _Joint, q) -> ca.SX:
    """``X_i`` (6x6): maps a spatial motion from the parent's frame to joint ``i``'s frame.

    With ``liMi = (R, p) = placement * M_J(q)``, ``X_i = [[R^T, -R^T [p]x], [0, R^T]]``.
    """
    R0 = _dm(joint.placement_R)
    p0 = _dm(joint.placement_p)
    qi = q[joint.idx_q]
    if joint.kind == "prismatic":
        R = R0
        p = p0 + ca.mtimes(R0, _dm(joint.axis)) * qi
    else:
        if joint.kind == "revolute":
            c, s = ca.cos(qi), ca.sin(qi)
        else:  # unbounded: q = (cos th, sin th), used as is (as Pinocchio does)
            c, s = q[joint.idx_q], q[joint.idx_q + 1]
        R = ca.mtimes(R0, _joint_rotation(joint, c, s))
        p = p0
    Rt = R.T
    zero = ca.SX(3, 3)
    return ca.vertcat(
        ca.horzcat(Rt, -ca.mtimes(Rt, _skew(p))),
        ca.horzcat(zero, Rt),
    )


def _motion_subspace(joint: _Joint) -> ca.DM:
    """``S`` (6x1): ``(0, u)`` for revolute joints, ``(u, 0)`` for prismatic ones."""
    if joint.kind == "prismatic":
        return _dm(np.concatenate([joint.axis, np.zeros(3)]))
    return _dm(np.concatenate([np.zeros(3), joint.axis]))


def _cross_motion(m, x):
    """``m x x`` for spatial motions: ``(w x v_x + v x w_x, w x w_x)``."""
    v, w = m[:3], m[3:]
    vx, wx = x[:3], x[3:]
    return ca.vertcat(ca.cross(w, vx) + ca.cross(v, wx), ca.cross(w, wx))


def _cross_force(m, f):
    """``m x* f`` for a motion ``m`` and a force ``f``: ``(w x f_l, w x f_a + v x f_l)``."""
    v, w = m[:3], m[3:]
    fl, fa = f[:3], f[3:]
    return ca.vertcat(ca.cross(w, fl), ca.cross(w, fa) + ca.cross(v, fl))


def _gravity_acceleration(model: pin.Model) -> ca.DM:
    """``a_0 = -g``: the base acceleration that stands in for gravity [m/s^2]."""
    g = np.concatenate([model.gravity.linear, model.gravity.angular])
    return _dm(-g)


def _check_has_joints(model: pin.Model) -> None:
    if model.njoints < 2:
        raise InputError("the model has no joints: nothing to build dynamics for")


# --------------------------------------------------------------------------------------------
# The algorithms


def _velocity_pass(model: pin.Model, joints: list[_Joint], q, v):
    """Root-to-leaves pass shared by RNEA and ABA: each joint's transform from its parent
    ``X_i``, body velocity ``v_i = X_i v_p + S qd_i`` and bias ``v_i x (S qd_i)``."""
    nj = model.njoints
    xforms, vel, bias = [None] * nj, [ca.SX.zeros(6)] * nj, [None] * nj
    for jt in joints:
        i = jt.index
        xforms[i] = _joint_transform(jt, q)
        vJ = _motion_subspace(jt) * v[jt.idx_v]
        vel[i] = ca.mtimes(xforms[i], vel[jt.parent]) + vJ
        bias[i] = _cross_motion(vel[i], vJ)
    return xforms, vel, bias


def _spatial_inertia(pi):
    """The 6x6 spatial inertia (linear first) of a body's 10 dynamic parameters
    ``(m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz)``, the rotational inertia about the body
    frame's origin (Pinocchio's ``Inertia.FromDynamicParameters``): ``[[m I, -[m c]x],
    [[m c]x, I_o]]``."""
    m, h = pi[0], pi[1:4]
    Io = ca.vertcat(ca.horzcat(pi[4], pi[5], pi[7]), ca.horzcat(pi[5], pi[6], pi[8]),
                    ca.horzcat(pi[7], pi[8], pi[9]))
    return ca.vertcat(ca.horzcat(m * ca.DM.eye(3), -_skew(h)), ca.horzcat(_skew(h), Io))


def _rnea_expr(model: pin.Model, joints: list[_Joint], q, v, a, pi=None):
    """RNEA (Featherstone, Table 5.1) as an SX expression.

    Forward pass: ``v_i = X_i v_p + S qd_i``, ``a_i = X_i a_p + S qdd_i + v_i x (S qd_i)``
    (``a_0 = -g``), ``f_i = I_i a_i + v_i x* (I_i v_i)``. Backward pass: ``tau_i = S^T f_i``,
    ``f_p += X_i^T f_i``. Finally ``tau += armature * a``. ``pi``: the bodies' dynamic
    parameters (10 per joint, in joint order) instead of the model's inertias.
    """
    nj = model.njoints
    xforms, vel, bias = _velocity_pass(model, joints, q, v)
    acc = [ca.SX(_gravity_acceleration(model))] + [None] * (nj - 1)
    force = [None] * nj
    for jt in joints:
        i, S = jt.index, _motion_subspace(jt)
        acc[i] = ca.mtimes(xforms[i], acc[jt.parent]) + S * a[jt.idx_v] + bias[i]
        inertia = _dm(jt.inertia) if pi is None else _spatial_inertia(pi[10 * (i - 1):10 * i])
        force[i] = ca.mtimes(inertia, acc[i]) + _cross_force(vel[i], ca.mtimes(inertia, vel[i]))
    tau = [None] * model.nv
    for jt in reversed(joints):
        i = jt.index
        tau[jt.idx_v] = ca.dot(_motion_subspace(jt), force[i])
        if jt.parent > 0:
            force[jt.parent] = force[jt.parent] + ca.mtimes(xforms[i].T, force[i])
    tau = ca.vertcat(*tau)
    armature = np.asarray(model.armature, dtype=float)
    if np.any(armature != 0.0):
        tau = tau + _dm(armature) * a
    return tau


def _aba_expr(model: pin.Model, joints: list[_Joint], q, v, tau):
    """Articulated-body algorithm (Featherstone, Table 7.1) as an SX expression.

    Pass 1: velocities ``v_i``, bias accelerations ``c_i = v_i x (S qd_i)``, and
    ``I^A_i = I_i``, ``p^A_i = v_i x* (I_i v_i)``. Pass 2 (leaves to root): ``U = I^A S``,
    ``D = S^T U + armature``, ``u = tau_i - S^T p^A``; the parent receives
    ``X^T (I^A - U U^T / D) X`` and ``X^T (p^A + I^a c + U u / D)``. Pass 3 (root to leaves):
    ``a'_i = X_i a_p + c_i`` (``a_0 = -g``), ``qdd_i = (u - U^T a'_i) / D``,
    ``a_i = a'_i + S qdd_i``.
    Every joint here has one degree of freedom, so ``D`` is a scalar and no matrix is inverted.
    """
    nj = model.njoints
    armature = np.asarray(model.armature, dtype=float)
    xforms, vel, bias = _velocity_pass(model, joints, q, v)
    art_inertia = [None] * nj
    art_force = [None] * nj
    for jt in joints:
        i = jt.index
        inertia = _dm(jt.inertia)
        art_inertia[i] = ca.SX(inertia)
        art_force[i] = _cross_force(vel[i], ca.mtimes(inertia, vel[i]))
    U, D, u = [None] * nj, [None] * nj, [None] * nj
    for jt in reversed(joints):
        i, S = jt.index, _motion_subspace(jt)
        U[i] = ca.mtimes(art_inertia[i], S)
        D[i] = ca.dot(S, U[i]) + float(armature[jt.idx_v])
        u[i] = tau[jt.idx_v] - ca.dot(S, art_force[i])
        if jt.parent > 0:
            Ia = art_inertia[i] - ca.mtimes(U[i], U[i].T) / D[i]
            pa = art_force[i] + ca.mtimes(Ia, bias[i]) + U[i] * (u[i] / D[i])
            X = xforms[i]
            art_inertia[jt.parent] = art_inertia[jt.parent] + ca.mtimes([X.T, Ia, X])
            art_force[jt.parent] = art_force[jt.parent] + ca.mtimes(X.T, pa)
    acc = [ca.SX(_gravity_acceleration(model))] + [None] * (nj - 1)
    qdd = [None] * model.nv
    for jt in joints:
        i, S = jt.index, _motion_subspace(jt)
        a_prime = ca.mtimes(xforms[i], acc[jt.parent]) + bias[i]
        qdd[jt.idx_v] = (u[i] - ca.dot(U[i], a_prime)) / D[i]
        acc[i] = a_prime + S * qdd[jt.idx_v]
    return ca.vertcat(*qdd)


def _tangent_jacobian(model: pin.Model, joints: list[_Joint], q) -> ca.SX:
    """``dq/d(delta)`` (nq x nv) of ``integrate(q, delta)`` at ``delta = 0``.

    Identity rows for revolute/prismatic joints; ``(-sin th, cos th) = (-q_1, q_0)`` for a
    continuous joint, whose configuration ``(cos th, sin th)`` turns by ``delta``.
    """
    J = ca.SX(model.nq, model.nv)
    for jt in joints:
        if jt.kind == "unbounded":
            J[jt.idx_q, jt.idx_v] = -q[jt.idx_q + 1]
            J[jt.idx_q + 1, jt.idx_v] = q[jt.idx_q]
        else:
            J[jt.idx_q, jt.idx_v] = 1
    return J


def _symbols(model: pin.Model, third: str):
    return (
        ca.SX.sym("q", model.nq),
        ca.SX.sym("v", model.nv),
        ca.SX.sym(third, model.nv),
    )


def symbolic_rnea(model: pin.Model) -> ca.Function:
    """``rnea(q, v, a) -> tau``: the inverse model of ``model`` as a CasADi ``Function``.

    ``q`` (nq) [rad] or [m] (``(cos, sin)`` pairs for continuous joints), ``v`` (nv) [rad/s] or
    [m/s], ``a`` (nv) [rad/s^2] or [m/s^2]; ``tau`` (nv) [N m] or [N]:
    ``tau = M(q) a + C(q, v) v + g(q)`` computed by the recursive Newton-Euler algorithm.
    """
    _check_has_joints(model)
    joints = _describe_joints(model)
    q, v, a = _symbols(model, "a")
    tau = _rnea_expr(model, joints, q, v, a)
    return ca.Function("rnea", [q, v, a], [ca.densify(tau)], ["q", "v", "a"], ["tau"])


def symbolic_rnea_parametric(model: pin.Model) -> ca.Function:
    """``rnea(q, v, a, pi) -> tau``: the inverse model with the bodies' inertial parameters
    ``pi`` (10 per joint, Pinocchio's ``toDynamicParameters`` order: [kg], [kg m],
    [kg m^2]) as an input. ``tau`` is linear in ``pi``; its Jacobian by ``pi`` is the joint
    torque regressor (Pinocchio's ``computeJointTorqueRegressor``)."""
    _check_has_joints(model)
    joints = _describe_joints(model)
    q, v, a = _symbols(model, "a")
    pi = ca.SX.sym("pi", 10 * (model.njoints - 1))
    tau = _rnea_expr(model, joints, q, v, a, pi)
    return ca.Function("rnea_parametric", [q, v, a, pi], [ca.densify(tau)],
                       ["q", "v", "a", "pi"], ["tau"])


def symbolic_aba(model: pin.Model) -> ca.Function:
    """``aba(q, v, tau) -> a``: the forward model of ``model`` as a CasADi ``Function``.

    Units as in :func:`symbolic_rnea`; ``a = M(q)^-1 (tau - C(q, v) v - g(q))``.

    Built with Featherstone's articulated-body algorithm rather than CRBA + a symbolic linear
    solve: with 1-DoF joints every "inverse" in ABA is a scalar division, so the expression
    grows linearly with the number of joints and has no symbolic factorisation (no pivoting
    choices, no dense ``M^-1``), and it follows Pinocchio's own ``aba`` step by step, so the
    numbers agree to rounding error.
    """
    _check_has_joints(model)
    joints = _describe_joints(model)
    q, v, tau = _symbols(model, "tau")
    acc = _aba_expr(model, joints, q, v, tau)
    return ca.Function("aba", [q, v, tau], [ca.densify(acc)], ["q", "v", "tau"], ["a"])


def symbolic_rnea_derivatives(model: pin.Model) -> ca.Function:
    """``(q, v, a) -> (dtau_dq, dtau_dv, M)``, each nv x nv, by CasADi's automatic differentiation.

    ``dtau_dq`` is taken in the tangent space (as Pinocchio's ``computeRNEADerivatives``):
    ``d tau(integrate(q, delta)) / d delta`` at ``delta = 0``, which equals ``d tau / d q`` for
    revolute and prismatic joints. ``M = d tau / d a`` is the joint-space mass matrix [kg m^2]
    (plus the armature on its diagonal).
    """
    _check_has_joints(model)
    joints = _describe_joints(model)
    q, v, a = _symbols(model, "a")
    tau = _rnea_expr(model, joints, q, v, a)
    dtau_dq = ca.mtimes(ca.jacobian(tau, q), _tangent_jacobian(model, joints, q))
    dtau_dv = ca.jacobian(tau, v)
    mass = ca.jacobian(tau, a)
    return ca.Function(
        "rnea_derivatives",
        [q, v, a],
        [ca.densify(dtau_dq), ca.densify(dtau_dv), ca.densify(mass)],
        ["q", "v", "a"],
        ["dtau_dq", "dtau_dv", "M"],
    )


def _placements_expr(model: pin.Model, joints: list[_Joint], q) -> list:
    """World placements ``oMi = oMp * jointPlacement_i * M_J(q_i)`` of every joint frame, as
    ``(R, p)`` pairs of SX (3x3 rotation, 3-vector position in [m]); index 0 is the world."""
    placements = [(ca.SX(ca.DM.eye(3)), ca.SX.zeros(3))] + [None] * (model.njoints - 1)
    for jt in joints:
        R0, p0 = _dm(jt.placement_R), _dm(jt.placement_p)
        qi = q[jt.idx_q]
        if jt.kind == "prismatic":
            R, p = ca.SX(R0), p0 + ca.mtimes(R0, _dm(jt.axis)) * qi
        else:
            if jt.kind == "revolute":
                c, s = ca.cos(qi), ca.sin(qi)
            else:
                c, s = q[jt.idx_q], q[jt.idx_q + 1]
            R, p = ca.mtimes(R0, _joint_rotation(jt, c, s)), ca.SX(p0)
        R_parent, p_parent = placements[jt.parent]
        placements[jt.index] = (ca.mtimes(R_parent, R), p_parent + ca.mtimes(R_parent, p))
    return placements


def _frame_position_expr(model: pin.Model, joints: list[_Joint], q, frame_id: int):
    """Position in the world [m] of frame ``frame_id``'s origin (``oMf.translation``)."""
    frame = model.frames[frame_id]
    R, p = _placements_expr(model, joints, q)[frame.parentJoint]
    return p + ca.mtimes(R, _dm(np.array(frame.placement.translation, dtype=float)))


def symbolic_frame_kinematics(model: pin.Model, frame_id: int) -> ca.Function:
    """``(q, v, a) -> (p, J, dp, ddp)``: a frame origin's motion in the world, symbolically.

    ``p`` (3) is the position in [m] (Pinocchio's ``data.oMf[frame_id].translation``); ``J``
    (3 x nv) the Jacobian of the origin's velocity, ``dp = J v`` in [m/s] (the linear rows of
    ``pin.computeFrameJacobian(..., LOCAL_WORLD_ALIGNED)``); ``ddp = J a + (dJ/dt) v`` the
    origin's classical acceleration in [m/s^2] (``pin.getFrameClassicalAcceleration``,
    ``LOCAL_WORLD_ALIGNED``). ``J = (dp/dq) T(q)`` with ``T`` the tangent map of
    ``integrate`` (identity except for continuous joints).
    """
    _check_has_joints(model)
    if not 0 <= frame_id < model.nframes:
        raise InputError(f"frame id {frame_id} is not a frame of the model (it has "
                         f"{model.nframes})")
    joints = _describe_joints(model)
    q, v, a = _symbols(model, "a")
    p = _frame_position_expr(model, joints, q, frame_id)
    tangent = _tangent_jacobian(model, joints, q)
    J = ca.mtimes(ca.jacobian(p, q), tangent)
    dp = ca.mtimes(J, v)
    ddp = ca.mtimes(J, a) + ca.mtimes(ca.jacobian(dp, q), ca.mtimes(tangent, v))
    return ca.Function("frame_kinematics", [q, v, a],
                       [ca.densify(p), ca.densify(J), ca.densify(dp), ca.densify(ddp)],
                       ["q", "v", "a"], ["p", "J", "dp", "ddp"])


def symbolic_frame_rotation(model: pin.Model, frame_id: int) -> ca.Function:
    """``q -> R``: the orientation of a frame in the world (3x3, Pinocchio's
    ``data.oMf[frame_id].rotation``), symbolically."""
    _check_has_joints(model)
    joints = _describe_joints(model)
    q = ca.SX.sym("q", model.nq)
    frame = model.frames[frame_id]
    R, _ = _placements_expr(model, joints, q)[frame.parentJoint]
    R = ca.mtimes(R, _dm(np.array(frame.placement.rotation, dtype=float)))
    return ca.Function("frame_rotation", [q], [ca.densify(R)], ["q"], ["R"])


def symbolic_center_of_mass(model: pin.Model) -> ca.Function:
    """``(q, v) -> (c, dc)``: the centre of mass in the world [m] (``pin.centerOfMass``) and its
    velocity [m/s], symbolically."""
    _check_has_joints(model)
    joints = _describe_joints(model)
    q, v = ca.SX.sym("q", model.nq), ca.SX.sym("v", model.nv)
    placements = _placements_expr(model, joints, q)
    total = sum(float(model.inertias[jt.index].mass) for jt in joints)
    if total <= 0.0:
        raise InputError("the model has no mass: no centre of mass")
    c = ca.SX.zeros(3)
    for jt in joints:
        inertia = model.inertias[jt.index]
        R, p = placements[jt.index]
        c = c + inertia.mass * (p + ca.mtimes(R, _dm(np.array(inertia.lever, dtype=float))))
    c = c / total
    dc = ca.mtimes(ca.mtimes(ca.jacobian(c, q), _tangent_jacobian(model, joints, q)), v)
    return ca.Function("center_of_mass", [q, v], [ca.densify(c), ca.densify(dc)],
                       ["q", "v"], ["c", "dc"])


# --------------------------------------------------------------------------------------------
# The backend


class BufferedCall:
    """Evaluates a CasADi ``Function`` of dense vectors through ``Function.buffer()``.

    Calling a ``Function`` from Python with numpy arguments costs some 40 us of argument
    conversion, whatever the work inside; the buffer interface evaluates in place on numpy arrays
    that it was handed once (about 1 us for the two-link arm). Inputs are copied into the
    pre-allocated arrays (those in ``keep`` only when a different array object is passed: the
    caller promises not to change an array it passed) and every result is returned as a fresh
    copy. Not thread-safe: one
    instance per thread (each :class:`CasadiDynamics` owns its own).
    """

    def __init__(self, fn: ca.Function, keep: tuple[int, ...] = ()):
        for i in range(fn.n_in()):
            if fn.nnz_in(i) != fn.numel_in(i) or fn.size2_in(i) != 1:
                raise ValueError(f"{fn.name()}: input {i} is not a dense column vector")
        for i in range(fn.n_out()):
            if fn.nnz_out(i) != fn.numel_out(i):
                raise ValueError(f"{fn.name()}: output {i} is not dense")
        self.fn = fn
        self._buffer, self._eval = fn.buffer()
        self._args = [np.zeros(fn.numel_in(i)) for i in range(fn.n_in())]
        self._results = [np.zeros(fn.numel_out(i)) for i in range(fn.n_out())]
        self._shapes = [fn.size_out(i) for i in range(fn.n_out())]
        for i, arr in enumerate(self._args):
            self._buffer.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self._results):
            self._buffer.set_res(i, memoryview(arr))
        self._keep = set(keep)
        self._kept: dict[int, np.ndarray] = {}

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        for i, (dst, src) in enumerate(zip(self._args, args, strict=True)):
            if i in self._keep:  # the caller never changes an array it passed
                if self._kept.get(i) is src:
                    continue
                self._kept[i] = src
            src = np.asarray(src, dtype=float)
            if src.shape != dst.shape:
                raise ValueError(
                    f"{self.fn.name()}: argument '{self.fn.name_in(i)}' has shape {src.shape}, "
                    f"expected {dst.shape}"
                )
            dst[:] = src
        self._eval()
        out = []
        for res, (rows, cols) in zip(self._results, self._shapes, strict=True):
            # CasADi stores dense matrices column by column.
            out.append(res.copy() if cols == 1 else res.reshape(rows, cols, order="F").copy())
        return out


class CasadiDynamics:
    """Known models of a :class:`pinocchio.Model` evaluated through CasADi symbolic functions.

    Same interface as :class:`feltool.dynamics.pinocchio.PinocchioDynamics`: numpy arrays in,
    new float numpy arrays out (1-D vectors, 2-D matrices). The CasADi ``Function`` objects are
    built once, in the constructor, and kept as :attr:`rnea_fn`, :attr:`aba_fn` and
    :attr:`derivatives_fn` (use them directly for code generation or inside larger CasADi graphs).
    The numeric methods evaluate them through CasADi's low-overhead buffer interface, so an
    instance must not be shared between threads; it pickles (by its model) for process pools.
    """

    def __init__(self, model: pin.Model):
        self.model = model
        self.nq = model.nq
        self.nv = model.nv
        joints = _describe_joints(model)  # raises InputError for unsupported joints
        #: True when every joint is revolute/prismatic, so that integration is ``q + dq``.
        self.euclidean = all(jt.kind != "unbounded" for jt in joints)
        self.rnea_fn: ca.Function = symbolic_rnea(model)
        self.aba_fn: ca.Function = symbolic_aba(model)
        self.derivatives_fn: ca.Function = symbolic_rnea_derivatives(model)
        self._rnea = BufferedCall(self.rnea_fn)
        self._aba = BufferedCall(self.aba_fn)
        self._derivatives = BufferedCall(self.derivatives_fn)

    def __getstate__(self) -> dict:
        return {"model": self.model}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["model"])

    def inverse(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Joint torques (nv) in [N m] or [N] that produce acceleration ``a``: RNEA."""
        return self._rnea(q, v, a)[0]

    def forward(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Joint accelerations (nv) in [rad/s^2] or [m/s^2] under torques ``tau``: ABA."""
        return self._aba(q, v, tau)[0]

    def inverse_derivatives(
        self, q: np.ndarray, v: np.ndarray, a: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d tau/d q, d tau/d v, M(q))``, each nv x nv, from CasADi's jacobians of the RNEA."""
        dq, dv, mass = self._derivatives(q, v, a)
        return dq, dv, mass

    def integrate(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Configuration reached from ``q`` by the tangent displacement ``dq``.

        ``q + dq`` for revolute/prismatic joints; with continuous joints, Pinocchio's
        ``integrate`` (which turns each ``(cos, sin)`` pair on the unit circle).
        """
        q = np.asarray(q, dtype=float)
        dq = np.asarray(dq, dtype=float)
        if self.euclidean:
            return q + dq
        return np.array(pin.integrate(self.model, q, dq), dtype=float)


__all__ = [
    "CasadiDynamics",
    "symbolic_aba",
    "symbolic_center_of_mass",
    "symbolic_frame_kinematics",
    "symbolic_frame_rotation",
    "symbolic_rnea",
    "symbolic_rnea_derivatives",
    "symbolic_rnea_parametric",
]


def _batch_methods():
    """``inverse_batch`` and ``inverse_derivatives_batch`` by looping the per-sample calls."""

    def inverse_batch(self, Q, V, A):
        return np.array([self.inverse(q, v, a) for q, v, a in zip(Q, V, A, strict=True)])

    def inverse_derivatives_batch(self, Q, V, A):
        tau = self.inverse_batch(Q, V, A)
        parts = [self.inverse_derivatives(q, v, a) for q, v, a in zip(Q, V, A, strict=True)]
        return (tau, *(np.array([p[i] for p in parts]) for i in range(3)))

    return inverse_batch, inverse_derivatives_batch


CasadiDynamics.inverse_batch, CasadiDynamics.inverse_derivatives_batch = _batch_methods()
