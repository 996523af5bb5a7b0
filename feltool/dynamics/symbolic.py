"""The known models as CasADi expressions built from a Pinocchio model's numbers: RNEA (and
its inertial-parameter form), ABA, the RNEA derivatives, frame kinematics, centre of mass.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pinocchio as pin

from feltool.dynamics.spatial import (
    Joint,
    check_has_joints,
    cross_force,
    cross_motion,
    describe_joints,
    dm,
    gravity_acceleration,
    joint_placement,
    joint_transform,
    motion_subspace,
    quaternion_matrix,
    skew,
    subspace_project,
    subspace_times,
)
from feltool.errors import InputError


def _velocity_pass(model: pin.Model, joints: list[Joint], q, v):
    """Root-to-leaves pass shared by RNEA and ABA: each joint's transform from its parent
    ``X_i``, body velocity ``v_i = X_i v_p + S qd_i`` and bias ``v_i x (S qd_i)``."""
    nj = model.njoints
    xforms, vel, bias = [None] * nj, [ca.SX.zeros(6)] * nj, [None] * nj
    for jt in joints:
        i = jt.index
        xforms[i] = joint_transform(jt, q)
        vJ = subspace_times(jt, v)
        vel[i] = ca.mtimes(xforms[i], vel[jt.parent]) + vJ
        bias[i] = cross_motion(vel[i], vJ)
    return xforms, vel, bias


def _spatial_inertia(pi):
    """The 6x6 spatial inertia (linear first) of a body's 10 dynamic parameters
    ``(m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz)``, the rotational inertia about the body
    frame's origin (Pinocchio's ``Inertia.FromDynamicParameters``): ``[[m I, -[m c]x],
    [[m c]x, I_o]]``."""
    m, h = pi[0], pi[1:4]
    Io = ca.vertcat(ca.horzcat(pi[4], pi[5], pi[7]), ca.horzcat(pi[5], pi[6], pi[8]),
                    ca.horzcat(pi[7], pi[8], pi[9]))
    return ca.vertcat(ca.horzcat(m * ca.DM.eye(3), -skew(h)), ca.horzcat(skew(h), Io))


def _rnea_expr(model: pin.Model, joints: list[Joint], q, v, a, pi=None, gravity=None):
    """RNEA (Featherstone, Table 5.1) as an SX expression.

    Forward pass: ``v_i = X_i v_p + S qd_i``, ``a_i = X_i a_p + S qdd_i + v_i x (S qd_i)``
    (``a_0 = -g``), ``f_i = I_i a_i + v_i x* (I_i v_i)``. Backward pass: ``tau_i = S^T f_i``,
    ``f_p += X_i^T f_i``. Finally ``tau += armature * a``. ``pi``: the bodies' dynamic
    parameters (10 per joint, in joint order) instead of the model's inertias; ``gravity``:
    the linear gravity (3) instead of the model's.
    """
    nj = model.njoints
    xforms, vel, bias = _velocity_pass(model, joints, q, v)
    a0 = ca.SX(gravity_acceleration(model)) if gravity is None else \
        ca.vertcat(-gravity, ca.SX.zeros(3))
    acc = [a0] + [None] * (nj - 1)
    force = [None] * nj
    for jt in joints:
        i = jt.index
        acc[i] = ca.mtimes(xforms[i], acc[jt.parent]) + subspace_times(jt, a) + bias[i]
        inertia = dm(jt.inertia) if pi is None else _spatial_inertia(pi[10 * (i - 1):10 * i])
        force[i] = ca.mtimes(inertia, acc[i]) + cross_force(vel[i], ca.mtimes(inertia, vel[i]))
    tau = {}
    for jt in reversed(joints):
        i = jt.index
        tau[i] = subspace_project(jt, force[i])
        if jt.parent > 0:
            force[jt.parent] = force[jt.parent] + ca.mtimes(xforms[i].T, force[i])
    tau = ca.vertcat(*(tau[jt.index] for jt in sorted(joints, key=lambda jt: jt.idx_v)))
    armature = np.asarray(model.armature, dtype=float)
    if np.any(armature != 0.0):
        tau = tau + dm(armature) * a
    return tau


def _aba_expr(model: pin.Model, joints: list[Joint], q, v, tau):
    """Articulated-body algorithm (Featherstone, Table 7.1) as an SX expression.

    Pass 1: velocities ``v_i``, bias accelerations ``c_i = v_i x (S qd_i)``, and
    ``I^A_i = I_i``, ``p^A_i = v_i x* (I_i v_i)``. Pass 2 (leaves to root): ``U = I^A S``,
    ``D = S^T U + armature``, ``u = tau_i - S^T p^A``; the parent receives
    ``X^T (I^A - U U^T / D) X`` and ``X^T (p^A + I^a c + U u / D)``. Pass 3 (root to leaves):
    ``a'_i = X_i a_p + c_i`` (``a_0 = -g``), ``qdd_i = (u - U^T a'_i) / D``,
    ``a_i = a'_i + S qdd_i``.
    Every joint here has one degree of freedom, so ``D`` is a scalar and no matrix is inverted
    (a floating base is refused: its dynamics under contacts are the KKT on ``M``).
    """
    multi = [jt.name for jt in joints if jt.nv != 1]
    if multi:
        raise InputError(f"the articulated-body algorithm is built for 1-DoF joints; joint "
                         f"'{multi[0]}' is a floating base")
    nj = model.njoints
    armature = np.asarray(model.armature, dtype=float)
    xforms, vel, bias = _velocity_pass(model, joints, q, v)
    art_inertia = [None] * nj
    art_force = [None] * nj
    for jt in joints:
        i = jt.index
        inertia = dm(jt.inertia)
        art_inertia[i] = ca.SX(inertia)
        art_force[i] = cross_force(vel[i], ca.mtimes(inertia, vel[i]))
    U, D, u = [None] * nj, [None] * nj, [None] * nj
    for jt in reversed(joints):
        i, S = jt.index, motion_subspace(jt)
        U[i] = ca.mtimes(art_inertia[i], S)
        D[i] = ca.dot(S, U[i]) + float(armature[jt.idx_v])
        u[i] = tau[jt.idx_v] - ca.dot(S, art_force[i])
        if jt.parent > 0:
            Ia = art_inertia[i] - ca.mtimes(U[i], U[i].T) / D[i]
            pa = art_force[i] + ca.mtimes(Ia, bias[i]) + U[i] * (u[i] / D[i])
            X = xforms[i]
            art_inertia[jt.parent] = art_inertia[jt.parent] + ca.mtimes([X.T, Ia, X])
            art_force[jt.parent] = art_force[jt.parent] + ca.mtimes(X.T, pa)
    acc = [ca.SX(gravity_acceleration(model))] + [None] * (nj - 1)
    qdd = [None] * model.nv
    for jt in joints:
        i, S = jt.index, motion_subspace(jt)
        a_prime = ca.mtimes(xforms[i], acc[jt.parent]) + bias[i]
        qdd[jt.idx_v] = (u[i] - ca.dot(U[i], a_prime)) / D[i]
        acc[i] = a_prime + S * qdd[jt.idx_v]
    return ca.vertcat(*qdd)


def _tangent_jacobian(model: pin.Model, joints: list[Joint], q) -> ca.SX:
    """``dq/d(delta)`` (nq x nv) of ``integrate(q, delta)`` at ``delta = 0``.

    Identity rows for revolute/prismatic joints; ``(-sin th, cos th) = (-q_1, q_0)`` for a
    continuous joint, whose configuration ``(cos th, sin th)`` turns by ``delta``; for a free
    flyer (``M exp6(delta)``) its rotation ``R`` on the position and
    ``(1/2)(w I + [u]x ; -u^T)`` of the quaternion ``(u, w)`` on its angular rates.
    """
    J = ca.SX(model.nq, model.nv)
    for jt in joints:
        if jt.kind == "free_flyer":
            iq, iv = jt.idx_q, jt.idx_v
            quat = q[iq + 3:iq + 7]
            u, w = quat[:3], quat[3]
            J[iq:iq + 3, iv:iv + 3] = quaternion_matrix(quat)
            J[iq + 3:iq + 6, iv + 3:iv + 6] = 0.5 * (w * ca.SX.eye(3) + skew(u))
            J[iq + 6, iv + 3:iv + 6] = -0.5 * u.T
        elif jt.kind == "unbounded":
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
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
    q, v, a = _symbols(model, "a")
    tau = _rnea_expr(model, joints, q, v, a)
    return ca.Function("rnea", [q, v, a], [ca.densify(tau)], ["q", "v", "a"], ["tau"])


def symbolic_rnea_gravity(model: pin.Model, parametric: bool = False) -> ca.Function:
    """``rnea(q, v, a, g) -> tau``: :func:`symbolic_rnea` with the linear gravity ``g`` (3, in
    [m/s^2]) an input instead of the model's (the same operations: with the model's gravity
    it gives :func:`symbolic_rnea`'s numbers). With ``parametric``: ``rnea(q, v, a, pi, g)``,
    the bodies' inertial parameters an input too (:func:`symbolic_rnea_world`)."""
    if parametric:
        return symbolic_rnea_world(model)
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
    q, v, a = _symbols(model, "a")
    g = ca.SX.sym("g", 3)
    tau = _rnea_expr(model, joints, q, v, a, None, g)
    return ca.Function("rnea_gravity", [q, v, a, g], [ca.densify(tau)],
                       ["q", "v", "a", "g"], ["tau"])


def symbolic_rnea_parametric(model: pin.Model) -> ca.Function:
    """``rnea(q, v, a, pi) -> tau``: the inverse model with the bodies' inertial parameters
    ``pi`` (10 per joint, Pinocchio's ``toDynamicParameters`` order: [kg], [kg m],
    [kg m^2]) as an input. ``tau`` is linear in ``pi``; its Jacobian by ``pi`` is the joint
    torque regressor (Pinocchio's ``computeJointTorqueRegressor``)."""
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
    q, v, a = _symbols(model, "a")
    pi = ca.SX.sym("pi", 10 * (model.njoints - 1))
    tau = _rnea_expr(model, joints, q, v, a, pi)
    return ca.Function("rnea_parametric", [q, v, a, pi], [ca.densify(tau)],
                       ["q", "v", "a", "pi"], ["tau"])


def symbolic_rnea_world(model: pin.Model) -> ca.Function:
    """``rnea(q, v, a, pi, g) -> tau``: the inverse model with the bodies' inertial parameters
    ``pi`` (as in :func:`symbolic_rnea_parametric`) and the linear gravity ``g`` (3, in
    [m/s^2], e.g. ``(0, 0, -9.81)``) as inputs: one expression for every world of the same
    joints (a payload, changed masses, a slope)."""
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
    q, v, a = _symbols(model, "a")
    pi, g = ca.SX.sym("pi", 10 * (model.njoints - 1)), ca.SX.sym("g", 3)
    tau = _rnea_expr(model, joints, q, v, a, pi, g)
    return ca.Function("rnea_world", [q, v, a, pi, g], [ca.densify(tau)],
                       ["q", "v", "a", "pi", "g"], ["tau"])


def symbolic_aba(model: pin.Model) -> ca.Function:
    """``aba(q, v, tau) -> a``: the forward model of ``model`` as a CasADi ``Function``.

    Units as in :func:`symbolic_rnea`; ``a = M(q)^-1 (tau - C(q, v) v - g(q))``.

    Built with Featherstone's articulated-body algorithm rather than CRBA + a symbolic linear
    solve: with 1-DoF joints every "inverse" in ABA is a scalar division, so the expression
    grows linearly with the number of joints and has no symbolic factorisation (no pivoting
    choices, no dense ``M^-1``), and it follows Pinocchio's own ``aba`` step by step, so the
    numbers agree to rounding error.
    """
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
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
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
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


def _placements_expr(model: pin.Model, joints: list[Joint], q) -> list:
    """World placements ``oMi = oMp * jointPlacement_i * M_J(q_i)`` of every joint frame, as
    ``(R, p)`` pairs of SX (3x3 rotation, 3-vector position in [m]); index 0 is the world."""
    placements = [(ca.SX(ca.DM.eye(3)), ca.SX.zeros(3))] + [None] * (model.njoints - 1)
    for jt in joints:
        R, p = joint_placement(jt, q)
        R_parent, p_parent = placements[jt.parent]
        placements[jt.index] = (ca.mtimes(R_parent, R), p_parent + ca.mtimes(R_parent, p))
    return placements


def _frame_position_expr(model: pin.Model, joints: list[Joint], q, frame_id: int):
    """Position in the world [m] of frame ``frame_id``'s origin (``oMf.translation``)."""
    frame = model.frames[frame_id]
    R, p = _placements_expr(model, joints, q)[frame.parentJoint]
    return p + ca.mtimes(R, dm(np.array(frame.placement.translation, dtype=float)))


def symbolic_frame_kinematics(model: pin.Model, frame_id: int) -> ca.Function:
    """``(q, v, a) -> (p, J, dp, ddp)``: a frame origin's motion in the world, symbolically.

    ``p`` (3) is the position in [m] (Pinocchio's ``data.oMf[frame_id].translation``); ``J``
    (3 x nv) the Jacobian of the origin's velocity, ``dp = J v`` in [m/s] (the linear rows of
    ``pin.computeFrameJacobian(..., LOCAL_WORLD_ALIGNED)``); ``ddp = J a + (dJ/dt) v`` the
    origin's classical acceleration in [m/s^2] (``pin.getFrameClassicalAcceleration``,
    ``LOCAL_WORLD_ALIGNED``). ``J = (dp/dq) T(q)`` with ``T`` the tangent map of
    ``integrate`` (identity except for continuous joints).
    """
    check_has_joints(model)
    if not 0 <= frame_id < model.nframes:
        raise InputError(f"frame id {frame_id} is not a frame of the model (it has "
                         f"{model.nframes})")
    joints = describe_joints(model, floating=True)
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
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
    q = ca.SX.sym("q", model.nq)
    frame = model.frames[frame_id]
    R, _ = _placements_expr(model, joints, q)[frame.parentJoint]
    R = ca.mtimes(R, dm(np.array(frame.placement.rotation, dtype=float)))
    return ca.Function("frame_rotation", [q], [ca.densify(R)], ["q"], ["R"])


def symbolic_center_of_mass(model: pin.Model) -> ca.Function:
    """``(q, v) -> (c, dc)``: the centre of mass in the world [m] (``pin.centerOfMass``) and its
    velocity [m/s], symbolically."""
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
    q, v = ca.SX.sym("q", model.nq), ca.SX.sym("v", model.nv)
    placements = _placements_expr(model, joints, q)
    total = sum(float(model.inertias[jt.index].mass) for jt in joints)
    if total <= 0.0:
        raise InputError("the model has no mass: no centre of mass")
    c = ca.SX.zeros(3)
    for jt in joints:
        inertia = model.inertias[jt.index]
        R, p = placements[jt.index]
        c = c + inertia.mass * (p + ca.mtimes(R, dm(np.array(inertia.lever, dtype=float))))
    c = c / total
    dc = ca.mtimes(ca.mtimes(ca.jacobian(c, q), _tangent_jacobian(model, joints, q)), v)
    return ca.Function("center_of_mass", [q, v], [ca.densify(c), ca.densify(dc)],
                       ["q", "v"], ["c", "dc"])


def _first_order_normalize(x):
    """Pinocchio's ``firstOrderNormalize``: ``x (3 - |x|^2) / 2``, the unit vector to first
    order for an ``x`` near unit length."""
    return x * (3 - ca.sumsqr(x)) / 2


#: Below this squared angle [rad^2] the exponential maps use their Taylor series (whose next
#: term is then below 1e-18)
_SMALL_ANGLE2 = 1e-6


def _se3_exp_parts(w):
    """For an angular displacement ``w`` (3) [rad]: ``(sin(t/2)/t, cos(t/2), a, b)`` with
    ``t = |w|``, ``a = (1 - cos t)/t^2``, ``b = (t - sin t)/t^3`` (``exp6``'s translation is
    ``(I + a [w]x + b [w]x^2) v``), by their Taylor series near ``t = 0``."""
    t2 = ca.sumsqr(w)
    small = t2 < _SMALL_ANGLE2
    t = ca.sqrt(ca.if_else(small, 1.0, t2))
    half_sin = ca.if_else(small, 0.5 - t2 / 48 + t2 ** 2 / 3840, ca.sin(t / 2) / t)
    a = ca.if_else(small, 0.5 - t2 / 24 + t2 ** 2 / 720, (1 - ca.cos(t)) / t2)
    b = ca.if_else(small, 1 / 6 - t2 / 120 + t2 ** 2 / 5040, (t - ca.sin(t)) / (t2 * t))
    return half_sin, ca.cos(ca.sqrt(t2) / 2), a, b


def _integrate_expr(joints: list[Joint], q, dv):
    """``integrate(q, dv)`` of every joint (Pinocchio's ``pin.integrate``): ``q + dv`` for a
    revolute or prismatic joint; a continuous one's ``(cos, sin)`` turned by ``dv`` and
    normalised to first order; a free flyer moved by ``M exp6(dv)``, its quaternion multiplied
    by ``exp(dv_w)``'s (the sign on the side of ``q``'s) and normalised to first order."""
    out = [q[k] for k in range(q.shape[0])]
    for jt in joints:
        iq, iv = jt.idx_q, jt.idx_v
        if jt.kind == "free_flyer":
            vl, w = dv[iv:iv + 3], dv[iv + 3:iv + 6]
            quat = q[iq + 3:iq + 7]
            half_sin, half_cos, a, b = _se3_exp_parts(w)
            W = skew(w)
            step = vl + a * ca.mtimes(W, vl) + b * ca.mtimes(W, ca.mtimes(W, vl))
            p = q[iq:iq + 3] + ca.mtimes(quaternion_matrix(quat), step)
            u, s = quat[:3], quat[3]
            eu, es = half_sin * w, half_cos
            qu = s * eu + es * u + ca.cross(u, eu)
            qs = s * es - ca.dot(u, eu)
            new = ca.vertcat(qu, qs)
            new = _first_order_normalize(ca.if_else(ca.dot(new, quat) < 0, -new, new))
            out[iq:iq + 7] = [p[0], p[1], p[2], new[0], new[1], new[2], new[3]]
        elif jt.kind == "unbounded":
            c, s = q[iq], q[iq + 1]
            cw, sw = ca.cos(dv[iv]), ca.sin(dv[iv])
            new = _first_order_normalize(ca.vertcat(cw * c - sw * s, sw * c + cw * s))
            out[iq:iq + 2] = [new[0], new[1]]
        else:
            out[iq] = q[iq] + dv[iv]
    return ca.vertcat(*out)


def symbolic_integrate(model: pin.Model) -> ca.Function:
    """``(q, dv) -> q'``: the configuration ``q`` moved by the tangent displacement ``dv`` (nv),
    Pinocchio's ``pin.integrate``, symbolically (any of the joints above and a free flyer)."""
    check_has_joints(model)
    joints = describe_joints(model, floating=True)
    q, dv = ca.SX.sym("q", model.nq), ca.SX.sym("dv", model.nv)
    return ca.Function("integrate", [q, dv], [_integrate_expr(joints, q, dv)], ["q", "dv"],
                       ["q_next"])
