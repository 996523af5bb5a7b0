"""The CasADi backend (symbolic RNEA/ABA built from a Pinocchio model) against Pinocchio itself."""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import example_robot_data as erd
import numpy as np
import pinocchio as pin
import pytest

from feltool.dynamics.casadi_backend import CasadiDynamics
from feltool.dynamics.symbolic import (
    symbolic_aba,
    symbolic_center_of_mass,
    symbolic_frame_kinematics,
    symbolic_rnea,
)
from feltool.errors import InputError

ROBOTS_DIR = Path(__file__).resolve().parents[1] / "robots"
N_SAMPLES = 10
TOL = 1e-10  # RNEA/ABA vs Pinocchio
TOL_DERIV = 1e-8  # derivatives vs computeRNEADerivatives
TOL_FD = 1e-6  # derivatives vs central finite differences


def _bundled(name: str) -> pin.Model:
    model = pin.buildModelFromUrdf(str(ROBOTS_DIR / f"{name}.urdf"))
    model.gravity.linear = np.array([0.0, 0.0, -9.8])
    return model


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    return pin.exp3(rng.normal(size=3) * 2.0)


def _random_tree_model(rng: np.random.Generator) -> pin.Model:
    """A branching tree with every supported joint type, unaligned axes and armature."""
    def axis() -> np.ndarray:
        u = rng.normal(size=3)
        return u / np.linalg.norm(u)

    joint_models = [
        pin.JointModelRX(), pin.JointModelRY(), pin.JointModelRZ(),
        pin.JointModelPX(), pin.JointModelPY(), pin.JointModelPZ(),
        pin.JointModelRevoluteUnaligned(axis()), pin.JointModelPrismaticUnaligned(axis()),
        pin.JointModelRUBX(), pin.JointModelRUBY(), pin.JointModelRUBZ(),
        pin.JointModelRevoluteUnaligned(axis()),
    ]
    # Parent joint of each new joint: a branching tree, numbered depth-first as the URDF parser
    # does (Pinocchio's derivative algorithms assume each subtree's velocities are contiguous).
    parents = [0, 1, 2, 2, 4, 1, 6, 0, 8, 9, 9, 11]
    model = pin.Model()
    for k, (jm, parent) in enumerate(zip(joint_models, parents, strict=True)):
        placement = pin.SE3(_random_rotation(rng), rng.normal(size=3) * 0.3)
        jid = model.addJoint(parent, jm, placement, f"j{k}")
        root = rng.normal(size=(3, 3))
        inertia = pin.Inertia(
            float(rng.uniform(0.5, 2.0)), rng.normal(size=3) * 0.2, root @ root.T + 0.1 * np.eye(3)
        )
        model.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
    model.armature = rng.uniform(0.0, 0.2, size=model.nv)
    model.gravity.linear = np.array([0.3, -0.2, -9.81])
    return model


MODELS = {
    "two_link_arm": lambda: _bundled("two_link_arm"),
    "two_link_human_arm": lambda: _bundled("two_link_human_arm"),
    "double_pendulum": lambda: erd.load("double_pendulum").model,
    "double_pendulum_continuous": lambda: erd.load("double_pendulum_continuous").model,
    "ur5": lambda: erd.load("ur5").model,
    "panda": lambda: erd.load("panda").model,  # 7 revolute + PY and prismatic-unaligned fingers
    "random_tree": lambda: _random_tree_model(np.random.default_rng(1234)),
}


@pytest.fixture(scope="module", params=sorted(MODELS))
def robot(request):
    """(name, pin.Model, CasadiDynamics, random states) for each robot, built once per module."""
    model = MODELS[request.param]()
    dyn = CasadiDynamics(model)
    rng = np.random.default_rng(20240611)
    states = []
    for _ in range(N_SAMPLES):
        q = rng.normal(size=model.nq)
        if model.nq != model.nv:  # continuous joints: (cos, sin) pairs on the unit circle
            q = pin.normalize(model, q)
        v, a, tau = (rng.normal(size=model.nv) for _ in range(3))
        states.append((q, v, a, tau))
    return request.param, model, dyn, states


def _assert_close(actual: np.ndarray, expected: np.ndarray, tol: float, what: str) -> None:
    """``|actual - expected| <= tol * max(1, |expected|_max)``: absolute, relative when big."""
    scale = max(1.0, float(np.max(np.abs(expected))))
    err = float(np.max(np.abs(actual - expected)))
    assert err <= tol * scale, f"{what}: max error {err:.3e} > {tol:.0e} x {scale:.3g}"


def test_rnea_matches_pinocchio(robot):
    name, model, dyn, states = robot
    data = model.createData()
    for q, v, a, _ in states:
        _assert_close(dyn.inverse(q, v, a), pin.rnea(model, data, q, v, a), TOL, f"{name} rnea")


def test_aba_matches_pinocchio(robot):
    name, model, dyn, states = robot
    data = model.createData()
    for q, v, _, tau in states:
        _assert_close(dyn.forward(q, v, tau), pin.aba(model, data, q, v, tau), TOL, f"{name} aba")


def test_aba_inverts_rnea(robot):
    name, _, dyn, states = robot
    for q, v, a, _ in states:
        _assert_close(dyn.forward(q, v, dyn.inverse(q, v, a)), a, 1e-8, f"{name} aba(rnea)")


def test_derivatives_match_pinocchio(robot):
    name, model, dyn, states = robot
    data = model.createData()
    for q, v, a, _ in states:
        pin.computeRNEADerivatives(model, data, q, v, a)
        mass = np.triu(data.M) + np.triu(data.M, 1).T  # Pinocchio fills the upper triangle
        dq, dv, m = dyn.inverse_derivatives(q, v, a)
        _assert_close(dq, data.dtau_dq, TOL_DERIV, f"{name} dtau_dq")
        _assert_close(dv, data.dtau_dv, TOL_DERIV, f"{name} dtau_dv")
        _assert_close(m, mass, TOL_DERIV, f"{name} M")
        _assert_close(m, m.T, 1e-12, f"{name} M symmetric")


def test_derivatives_match_finite_differences(robot):
    name, model, dyn, states = robot
    h = 1e-6
    eye = np.eye(model.nv)
    for q, v, a, _ in states[:3]:
        dq, dv, m = dyn.inverse_derivatives(q, v, a)
        fd_q = np.column_stack(
            [
                (
                    dyn.inverse(dyn.integrate(q, h * e), v, a)
                    - dyn.inverse(dyn.integrate(q, -h * e), v, a)
                )
                / (2 * h)
                for e in eye
            ]
        )
        fd_v = np.column_stack(
            [(dyn.inverse(q, v + h * e, a) - dyn.inverse(q, v - h * e, a)) / (2 * h) for e in eye]
        )
        fd_a = np.column_stack(
            [(dyn.inverse(q, v, a + h * e) - dyn.inverse(q, v, a - h * e)) / (2 * h) for e in eye]
        )
        _assert_close(dq, fd_q, TOL_FD, f"{name} dtau_dq vs FD")
        _assert_close(dv, fd_v, TOL_FD, f"{name} dtau_dv vs FD")
        _assert_close(m, fd_a, TOL_FD, f"{name} M vs FD")


def test_interface_types_and_shapes(robot):
    _, model, dyn, states = robot
    q, v, a, tau = states[0]
    assert (dyn.nq, dyn.nv) == (model.nq, model.nv)
    for out in (dyn.inverse(q, v, a), dyn.forward(q, v, tau), dyn.integrate(q, v)):
        assert isinstance(out, np.ndarray) and out.dtype == np.float64 and out.ndim == 1
    assert dyn.inverse(q, v, a).shape == (model.nv,)
    assert dyn.integrate(q, v).shape == (model.nq,)
    for mat in dyn.inverse_derivatives(q, v, a):
        assert isinstance(mat, np.ndarray) and mat.dtype == np.float64
        assert mat.shape == (model.nv, model.nv)
    np.testing.assert_allclose(dyn.integrate(q, v), pin.integrate(model, q, v), atol=1e-12)
    assert isinstance(dyn.rnea_fn, ca.Function) and isinstance(dyn.aba_fn, ca.Function)


def test_symbolic_functions_signature():
    model = _bundled("two_link_arm")
    rnea, aba = symbolic_rnea(model), symbolic_aba(model)
    assert rnea.name_in() == ["q", "v", "a"] and rnea.name_out() == ["tau"]
    assert aba.name_in() == ["q", "v", "tau"] and aba.name_out() == ["a"]
    # Usable inside larger symbolic graphs: the output is an SX expression of the inputs.
    q = ca.SX.sym("q", 2)
    tau = rnea(q, ca.SX.zeros(2), ca.SX.zeros(2))
    assert isinstance(tau, ca.SX) and ca.depends_on(tau, q)


def test_two_link_arm_gravity_torque():
    """Arm horizontal at rest (q = 0): gravity torques m g l_g + m g l_1 + m g l_g and m g l_g."""
    dyn = CasadiDynamics(_bundled("two_link_arm"))
    tau = dyn.inverse(np.zeros(2), np.zeros(2), np.zeros(2))
    # The joints turn about -y, so lifting torque is positive: tau = (g (0.5 + 1.5), g 0.5).
    np.testing.assert_allclose(tau, [9.8 * 2.0, 9.8 * 0.5], atol=1e-12)


def test_unsupported_joint_names_the_joint():
    model = pin.buildModelFromUrdf(str(ROBOTS_DIR / "two_link_arm.urdf"), pin.JointModelFreeFlyer())
    with pytest.raises(InputError, match="root_joint.*JointModelFreeFlyer"):
        CasadiDynamics(model)


def test_results_are_independent_copies():
    dyn = CasadiDynamics(_bundled("two_link_arm"))
    zeros = np.zeros(2)
    first = dyn.inverse(zeros, zeros, zeros)
    kept = first.copy()
    dyn.inverse(np.ones(2), np.ones(2), np.ones(2))
    np.testing.assert_array_equal(first, kept)
    first[:] = 123.0  # writing into a result does not change the next one
    np.testing.assert_array_equal(dyn.inverse(zeros, zeros, zeros), kept)


def test_wrong_shape_is_rejected():
    dyn = CasadiDynamics(_bundled("two_link_arm"))
    with pytest.raises(ValueError, match="'q' has shape"):
        dyn.inverse(np.zeros(3), np.zeros(2), np.zeros(2))


def test_pickles_for_process_pools():
    import pickle

    model = erd.load("ur5").model
    dyn = CasadiDynamics(model)
    clone = pickle.loads(pickle.dumps(dyn))
    q, v, a = (np.linspace(-1.0, 1.0, 6) * k for k in (1.0, 0.5, 2.0))
    np.testing.assert_array_equal(clone.inverse(q, v, a), dyn.inverse(q, v, a))
    np.testing.assert_array_equal(clone.forward(q, v, a), dyn.forward(q, v, a))


def test_frame_kinematics_match_pinocchio(robot):
    """Every frame's position, Jacobian, velocity and classical acceleration against Pinocchio
    (oMf, computeFrameJacobian and getFrameClassicalAcceleration, LOCAL_WORLD_ALIGNED), 1e-12."""
    name, model, _, states = robot
    data = model.createData()
    frames = range(1, model.nframes, max(1, model.nframes // 6))
    for fid in frames:
        fn = symbolic_frame_kinematics(model, fid)
        for q, v, a, _ in states[:4]:
            p, J, dp, ddp = (np.array(x) for x in fn(q, v, a))
            pin.forwardKinematics(model, data, q, v, a)
            pin.updateFramePlacements(model, data)
            J_pin = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
            acc = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            vel = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            frame = model.frames[fid].name
            _assert_close(p.ravel(), data.oMf[fid].translation, 1e-12, f"{name} {frame} p")
            _assert_close(J, J_pin, 1e-12, f"{name} {frame} J")
            _assert_close(dp.ravel(), vel.linear, 1e-12, f"{name} {frame} dp")
            _assert_close(ddp.ravel(), acc.linear, 1e-11, f"{name} {frame} ddp")


def test_center_of_mass_matches_pinocchio(robot):
    """Position and velocity of the centre of mass against pin.centerOfMass, 1e-12."""
    name, model, _, states = robot
    data = model.createData()
    fn = symbolic_center_of_mass(model)
    for q, v, _, _ in states[:4]:
        c, dc = (np.array(x).ravel() for x in fn(q, v))
        pin.centerOfMass(model, data, q, v)
        _assert_close(c, data.com[0], 1e-12, f"{name} com")
        _assert_close(dc, data.vcom[0], 1e-12, f"{name} vcom")


def test_calls_in_threads_equal_pinocchio_and_keep_their_order():
    """call_in_threads (a compiled Jacobian's columns on every CPU): each result is Pinocchio's
    ABA at its own state (the threads' buffers do not mix), in the order given."""
    from feltool.dynamics.casadi_backend import call_in_threads

    model = _bundled("two_link_arm")
    data = model.createData()
    fn = symbolic_aba(model)
    rng = np.random.default_rng(2012)
    states = [rng.normal(size=model.nv) for _ in range(9)]
    v0, tau0 = rng.normal(size=model.nv), rng.normal(size=model.nv)
    out = call_in_threads(fn, states, v0, tau0)
    assert len(out) == len(states)
    for x, (a,) in zip(states, out, strict=True):
        np.testing.assert_allclose(a, pin.aba(model, data, x, v0, tau0), atol=TOL)
