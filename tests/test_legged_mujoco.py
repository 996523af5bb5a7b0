"""Legged robots with MuJoCo as the plant (issue 32): MuJoCo's model, built from the known
model, against Pinocchio's dynamics (coordinates both ways, ABA, a free flight integrated
independently, a payload; a URDF of one's own and Talos' reduced legs; a joint it cannot have
refused), standing, and a short trot in MuJoCo's soft contacts under the rigid model's
controllers (the 20 s runs are benchmarks/legged_trot_mujoco.py).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

from feltool.walking.legged.control import StandingController
from feltool.walking.legged.model import Payload, load_solo12, with_payload
from feltool.walking.legged.mujoco_plant import LeggedMujoco
from feltool.walking.legged.mujoco_stand import stand_mujoco
from feltool.walking.legged.trot import PAIRS, TrotController, TrotGait

from .conftest import edited_solo_urdf

mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def solo():
    return load_solo12(effort=2.7)


def _random_state(solo, seed):
    rng = np.random.default_rng(seed)
    q = pin.integrate(solo.model, solo.q0, 0.5 * rng.standard_normal(solo.nv))
    q[:3] += [0.1, -0.2, 1.0]
    return q, rng.standard_normal(solo.nv), rng


@pytest.mark.parametrize("seed", range(3))
def test_coordinates_both_ways_and_the_accelerations_are_pinocchios(solo, seed):
    """q, v -> qpos, qvel -> q, v is the identity; MuJoCo's world-frame linear velocity is the
    base frame's rotated; ``mj_forward``'s accelerations, under random motor torques, are
    ``pin.aba``'s (1e-8) -- the model's inertias built exactly, the joints matched."""
    q, v, rng = _random_state(solo, seed)
    p = LeggedMujoco(solo, floor=False)
    qpos, qvel = p.to_mujoco(q, v)
    R = pin.XYZQUATToSE3(q[:7]).rotation
    np.testing.assert_allclose(qpos[3:7], np.r_[q[6], q[3:6]], atol=1e-15)
    np.testing.assert_allclose(qvel[:3], R @ v[:3], atol=1e-14)
    q2, v2 = p.to_pinocchio(qpos, qvel)
    np.testing.assert_allclose(q2, q, atol=1e-14)
    np.testing.assert_allclose(v2, v, atol=1e-14)
    _check_accelerations(p, solo, q, v, rng.uniform(-2.7, 2.7, 12))


def _check_accelerations(p, legged, q, v, u) -> None:
    """``mj_forward``'s accelerations under motor torques ``u`` are ``pin.aba``'s (1e-8), its
    foot points Pinocchio's (1e-14)."""
    p.set_state(q, v)
    p.data.qfrc_applied[:] = p.generalized(u)
    mujoco.mj_forward(p.model, p.data)
    a = pin.aba(legged.model, legged.data, q, v, np.r_[np.zeros(6), u])
    np.testing.assert_allclose(p.acceleration(), a, atol=1e-8 * max(1.0, np.abs(a).max()))
    np.testing.assert_allclose(p.foot_points(), legged.foot_positions(q), atol=1e-14)


def _pinocchio_flight(model, q, v, tau, duration):
    """Pinocchio's free flight by ``solve_ivp`` (DOP853, 1e-11): the base's position rate R v,
    its quaternion's 1/2 quat (x) (omega, 0), joint rates, ``pin.aba``."""
    data = model.createData()
    nq = model.nq

    def rhs(_, y):
        qq, vv = y[:nq].copy(), y[nq:]
        qq[3:7] /= np.linalg.norm(qq[3:7])
        x, yq, z, w = qq[3:7]
        wx, wy, wz = vv[3:6]
        dq = np.empty(nq)
        dq[:3] = pin.Quaternion(w, x, yq, z).toRotationMatrix() @ vv[:3]
        dq[3:7] = 0.5 * np.array([w * wx + yq * wz - z * wy, w * wy + z * wx - x * wz,
                                  w * wz + x * wy - yq * wx, -x * wx - yq * wy - z * wz])
        dq[7:] = vv[6:]
        return np.r_[dq, pin.aba(model, data, qq, vv, tau)]

    sol = solve_ivp(rhs, (0.0, duration), np.r_[q, v], method="DOP853", rtol=1e-11,
                    atol=1e-12)
    y = sol.y[:, -1]
    qe = y[:nq].copy()
    qe[3:7] /= np.linalg.norm(qe[3:7])
    return qe, y[nq:]


@pytest.mark.parametrize("payload", [None, Payload(0.5, (0.05, -0.02, 0.03))])
def test_a_free_flight_is_pinocchios(solo, payload):
    """0.05 s of free flight (gravity, random state and motor torques, no floor) by MuJoCo's RK4
    at 0.1 ms against Pinocchio's ABA integrated by ``solve_ivp``: the states agree to 1e-7
    (positions [m, rad], velocities [m/s, rad/s]); with a payload, MuJoCo's payload body and
    :func:`with_payload`'s inertia are the same world."""
    q, v, rng = _random_state(solo, 7)
    tau = np.r_[np.zeros(6), rng.uniform(-1.0, 1.0, 12)]
    p = LeggedMujoco(solo, timestep=1e-4, integrator="rk4", floor=False, payload=payload)
    p.set_state(q, v)
    for _ in range(500):
        p.step(p.generalized(tau[6:]))
    qm, vm = p.state()
    known = with_payload(solo, payload)
    qe, ve = _pinocchio_flight(known.model, q, v, tau, 0.05)
    assert np.abs(pin.difference(solo.model, qe, qm)).max() < 1e-7
    assert np.abs(vm - ve).max() < 1e-7
    if payload is not None:  # the payload matters at this precision
        qn, _ = _pinocchio_flight(solo.model, q, v, tau, 0.05)
        assert np.abs(pin.difference(solo.model, qn, qm)).max() > 1e-4
        assert known.mass == pytest.approx(solo.mass + 0.5)
        assert float(np.sum(p.model.body_mass)) == pytest.approx(known.mass, abs=1e-12)


def test_solo12_stands_in_mujoco(solo):
    """1 s in MuJoCo under the standing controller: every check of the MuJoCo loop passes (no
    foot slides 2 mm, none 2 mm deep, each foot's 5 ms normal force above 0), the base level
    (1e-5 rad) at its height within 0.1 mm (MuJoCo's soft floor gives a few hundredths of a
    millimetre), the feet together carrying m g to 1e-3, none creeping 0.1 mm."""
    q0 = solo.standing()
    log = stand_mujoco(solo, StandingController(solo, q0), q0, duration=1.0)
    assert log.not_walking is None, log.not_walking
    assert len(log.t) == 1000 and log.stats.min_normal_force > 5.0
    assert np.abs(log.height - q0[2]).max() < 1e-4
    assert np.abs(log.roll).max() < 1e-5 and np.abs(log.pitch).max() < 1e-5
    weight = solo.mass * np.linalg.norm(solo.model.gravity.linear)
    assert log.forces[-1, :, 2].sum() == pytest.approx(weight, rel=1e-3)
    q, _ = log.q[-1], log.v[-1]
    creep = solo.foot_positions(q)[:, :2] - solo.foot_positions(q0)[:, :2]
    assert np.abs(creep).max() < 1e-4


def test_a_payload_pulls_the_stand_down_but_it_stands(solo):
    """20 % of the mass on the base in MuJoCo only (the controller does not know it): it still
    stands, lower (the height PD gives way), its feet carrying the payload too."""
    q0 = solo.standing()
    log = stand_mujoco(solo, StandingController(solo, q0), q0, duration=0.5,
                       payload=Payload(0.2 * solo.mass, (0.02, 0.0, 0.0)))
    assert log.not_walking is None, log.not_walking
    weight = 1.2 * solo.mass * np.linalg.norm(solo.model.gravity.linear)
    assert log.forces[-1, :, 2].sum() == pytest.approx(weight, rel=1e-2)
    assert log.height[-1] < q0[2] - 1e-3


def test_solo12_trots_in_mujoco(solo):
    """1.2 s of the shipped trot (0.3 m/s ramped in 0.3 s) with MuJoCo as the plant: every
    check of the loop passes, the pairs alternate, every foot lifts above 2 cm, roll and pitch
    stay below 0.05 rad, and the base follows the desired one to 2 cm."""
    g = TrotGait(speed=0.3, ramp=0.3)
    q0 = solo.standing()
    ctl = TrotController(solo, q0, gait=g)
    log = stand_mujoco(solo, ctl, q0, duration=1.2, schedule=g.schedule,
                       on_touchdown=g.touchdown)
    assert log.not_walking is None, log.not_walking
    st = log.stats
    assert st.min_normal_force > 0.0 and st.max_friction_ratio < 0.7 and st.max_torque < 2.7
    assert g.steps >= 6
    pairs = [frozenset(p) for p in PAIRS]
    landed = [next(p for p in pairs if set(feet) <= p) for _, feet in log.touchdowns]
    firsts = [landed[k] for k in range(len(landed)) if k == 0 or landed[k] != landed[k - 1]]
    assert len(firsts) >= 6 and all(a != b for a, b in zip(firsts, firsts[1:]))
    heights = np.array([solo.foot_positions(x)[:, 2] for x in log.q])
    assert (heights.max(0) > 0.02).all()
    assert np.abs(log.roll).max() < 0.05 and np.abs(log.pitch).max() < 0.05
    x_d = g.base_x(log.t[-1])[0]
    assert log.q[-1, 0] - log.q[0, 0] == pytest.approx(x_d, abs=0.02)


def test_bad_plant_inputs_are_named(solo):
    """A payload without a positive mass, an unknown integrator and a plant whose timestep is
    not the loop's are configuration errors naming the field."""
    from feltool.errors import ConfigError

    for bad in (lambda: Payload(0.0), lambda: Payload(1.0, (0.0, np.nan, 0.0)),
                lambda: LeggedMujoco(solo, integrator="implicit")):
        with pytest.raises(ConfigError):
            bad()
    q0 = solo.standing()
    with pytest.raises(ConfigError, match="timestep"):
        stand_mujoco(solo, StandingController(solo, q0), q0, duration=0.01,
                     plant=LeggedMujoco(solo, timestep=1e-3))


@pytest.mark.parametrize("robot", ["urdf", "talos_legs"])
def test_mujoco_compiles_the_known_models_robot_whatever_it_was_loaded_from(robot, tmp_path):
    """Any legged model, not Solo-12's file: a URDF of one's own (renamed joints, a heavier
    base) and example-robot-data's Talos legs (its URDF is the whole robot, 42 kg more). MuJoCo's
    mass is the model's and its accelerations are ``pin.aba``'s at a random state (1e-8)."""
    from feltool.walking.legged.model import load_legged_urdf, load_talos_legs

    if robot == "urdf":
        legged = load_legged_urdf(edited_solo_urdf(tmp_path, extra_base_mass=1.0),
                                  {f: {"frame": f"{f}_FOOT"} for f in ("FL", "FR", "HL", "HR")})
        assert legged.motors[0].startswith("my_")
        assert legged.mass == pytest.approx(load_solo12().mass + 1.0, abs=1e-12)
    else:
        legged = load_talos_legs()
    p = LeggedMujoco(legged, floor=False)
    assert p.model.body_mass.sum() == pytest.approx(legged.mass, rel=1e-12)
    q, v, rng = _random_state(legged, 3)
    _check_accelerations(p, legged, q, v, rng.uniform(-1.0, 1.0, legged.nv - 6))


def test_a_joint_mujoco_cannot_have_is_refused_naming_it():
    """A spherical joint (Pinocchio's JointModelSpherical) in a legged model: MuJoCo's plant
    refuses it, naming the joint, before anything is compiled."""
    from feltool.errors import RobotError
    from feltool.walking.legged.model import legged_model

    m = pin.Model()
    root = m.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root")
    m.appendBodyToJoint(root, pin.Inertia.FromBox(1.0, 0.2, 0.1, 0.1), pin.SE3.Identity())
    ball = m.addJoint(root, pin.JointModelSpherical(), pin.SE3(np.eye(3), np.array([0, 0, -0.1])),
                      "hip_ball")
    m.appendBodyToJoint(ball, pin.Inertia.FromCylinder(0.2, 0.01, 0.2), pin.SE3.Identity())
    m.addFrame(pin.Frame("toe", ball, pin.SE3(np.eye(3), np.array([0, 0, -0.2])),
                         pin.FrameType.OP_FRAME))
    legged = legged_model(m, {"toe": {"frame": "toe"}}, effort=1.0)
    with pytest.raises(RobotError, match="joint 'hip_ball' \\(JointModelSpherical\\)"):
        LeggedMujoco(legged, floor=False)
