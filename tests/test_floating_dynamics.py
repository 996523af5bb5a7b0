"""The symbolic dynamics of a floating base (Pinocchio's ``JointModelFreeFlyer``) built from the
model's numbers, against Pinocchio's own algorithms on the legged robots of example-robot-data:
RNEA, its derivatives and the mass matrix, a foot's kinematics, the centre of mass and
``integrate`` (the exponential map, at tiny and large angles)."""

from __future__ import annotations

import example_robot_data as erd
import numpy as np
import pinocchio as pin
import pytest

from feltool.dynamics.casadi_backend import CasadiDynamics
from feltool.dynamics.symbolic import (
    symbolic_aba,
    symbolic_center_of_mass,
    symbolic_frame_kinematics,
    symbolic_integrate,
    symbolic_rnea,
    symbolic_rnea_derivatives,
)
from feltool.errors import InputError

TOL = 1e-12  # relative to the largest magnitude compared


def _model(name: str) -> pin.Model:
    return erd.load(name).model


def _close(a, b, tol: float = TOL) -> None:
    a, b = np.asarray(a, float), np.asarray(b, float)
    a = a.reshape(b.shape)
    assert np.abs(a - b).max() <= tol * max(1.0, np.abs(b).max()), np.abs(a - b).max()


def _states(model: pin.Model, seed: int, n: int = 5):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        q[:3] = rng.normal(size=3)
        yield q, rng.normal(size=model.nv), rng.normal(size=model.nv)


@pytest.mark.parametrize("name", ["solo12", "talos_legs"])
def test_rnea_mass_matrix_and_derivatives_match_pinocchio(name):
    model = _model(name)
    data = model.createData()
    rnea, deriv = symbolic_rnea(model), symbolic_rnea_derivatives(model)
    for q, v, a in _states(model, 0):
        _close(rnea(q, v, a), pin.rnea(model, data, q, v, a))
        dq, dv, M = (np.array(x) for x in deriv(q, v, a))
        pin.computeRNEADerivatives(model, data, q, v, a)
        _close(dq, data.dtau_dq, 1e-11)  # tangent-space derivative, as Pinocchio's
        _close(dv, data.dtau_dv)
        _close(M, np.triu(data.M) + np.triu(data.M, 1).T)


@pytest.mark.parametrize("name", ["solo12", "talos_legs"])
def test_frame_kinematics_and_centre_of_mass_match_pinocchio(name):
    model = _model(name)
    data = model.createData()
    frame = model.getFrameId(model.frames[-1].name)
    kin, com = symbolic_frame_kinematics(model, frame), symbolic_center_of_mass(model)
    for q, v, a in _states(model, 1):
        p, J, dp, ddp = (np.array(x) for x in kin(q, v, a))
        pin.forwardKinematics(model, data, q, v, a)
        pin.updateFramePlacements(model, data)
        pin.computeJointJacobians(model, data, q)
        Jp = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3]
        _close(p.ravel(), data.oMf[frame].translation)
        _close(J, Jp)
        _close(dp.ravel(), Jp @ v)
        _close(ddp.ravel(), pin.getFrameClassicalAcceleration(
            model, data, frame, pin.LOCAL_WORLD_ALIGNED).linear)
        c, dc = (np.array(x).ravel() for x in com(q, v))
        pin.centerOfMass(model, data, q, v)
        _close(c, data.com[0])
        _close(dc, data.vcom[0])


@pytest.mark.parametrize("scale", [1e-9, 1e-3, 0.5, 3.0])
def test_integrate_matches_pinocchio_from_tiny_to_large_rotations(scale):
    """The free flyer's ``M exp6(dv)`` near the exponential's series switch and beyond half a
    turn (the quaternion's sign kept on the side of the start, as Pinocchio keeps it)."""
    model = _model("solo12")
    integrate = symbolic_integrate(model)
    rng = np.random.default_rng(2)
    for q, _, _ in _states(model, 3, 20):
        dv = scale * rng.normal(size=model.nv)
        _close(integrate(q, dv), pin.integrate(model, q, dv), 1e-14)


def test_integrate_of_a_continuous_joint_matches_pinocchio():
    model = pin.Model()
    joint = model.addJoint(0, pin.JointModelRUBZ(), pin.SE3.Identity(), "wheel")
    model.appendBodyToJoint(joint, pin.Inertia.FromSphere(1.0, 0.1), pin.SE3.Identity())
    integrate = symbolic_integrate(model)
    for th, dv in [(0.3, 1e-9), (-2.0, 0.7), (3.0, 4.0)]:
        q = np.array([np.cos(th), np.sin(th)])
        _close(integrate(q, [dv]), pin.integrate(model, q, np.array([dv])), 1e-15)


def test_a_floating_base_is_refused_where_it_is_not_supported():
    """The articulated-body algorithm here divides by scalars (1-DoF joints), and the casadi
    backend of a fixed-base experiment keeps its list of joints: both name the joint."""
    model = _model("solo12")
    with pytest.raises(InputError, match="root_joint"):
        symbolic_aba(model)
    with pytest.raises(InputError, match="JointModelFreeFlyer"):
        CasadiDynamics(model)
