"""The physical walker: stance dynamics against Newton's law for the centre of mass, rigid impacts
against momentum conservation (closed forms written here), touchdown located at contact, and
contact violations reported as not walking."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.control.feedback import FeedbackLaw
from feltool.dynamics.interface import make_dynamics
from feltool.robot.robot import load_robot, load_urdf_string
from feltool.walking.checks import ContactChecks
from feltool.walking.contact import Contact
from feltool.walking.model import FootSpec, build_walker_model
from feltool.walking.physical import PhysicalLoop, PhysicalWalker

FEET = {"left": FootSpec(frame="left_foot"), "right": FootSpec(frame="right_foot")}
M_LEG, M_H, M_T, R, L = 15.0, 10.0, 40.0, 1.0, 1.0  # Table B.1


def five_link():
    return build_walker_model(load_robot("five_link_walker"), FEET,
                              [("left_hip", "right_hip"), ("left_knee", "right_knee")])


def three_link():
    return build_walker_model(load_robot("three_link_walker"), FEET, [("left_hip", "right_hip")])


COMPASS = """<?xml version="1.0"?>
<robot name="compass">
  <link name="world_root"/>
  <link name="slider_x"/>
  <link name="slider_z"/>
  <link name="hip"><inertial><mass value="10"/>
    <inertia ixx="0.05" ixy="0" ixz="0" iyy="0.05" iyz="0" izz="0.01"/></inertial></link>
  <link name="left_leg"><inertial><origin xyz="0 0 -0.5"/><mass value="5"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.01"/></inertial></link>
  <link name="right_leg"><inertial><origin xyz="0 0 -0.5"/><mass value="5"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.01"/></inertial></link>
  <joint name="x" type="prismatic"><parent link="world_root"/><child link="slider_x"/>
    <axis xyz="1 0 0"/><limit lower="-100" upper="100" effort="0" velocity="100"/></joint>
  <joint name="z" type="prismatic"><parent link="slider_x"/><child link="slider_z"/>
    <axis xyz="0 0 1"/><limit lower="-100" upper="100" effort="0" velocity="100"/></joint>
  <joint name="pitch" type="continuous"><parent link="slider_z"/><child link="hip"/>
    <axis xyz="0 1 0"/></joint>
  <joint name="left_hip" type="revolute"><parent link="hip"/><child link="left_leg"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="50" velocity="100"/></joint>
  <joint name="right_hip" type="revolute"><parent link="hip"/><child link="right_leg"/>
    <axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="50" velocity="100"/></joint>
</robot>
"""


def compass():
    robot = load_urdf_string(COMPASS, name="compass")
    feet = {"left": FootSpec(link="left_leg", offset=(0, 0, -1.0)),
            "right": FootSpec(link="right_leg", offset=(0, 0, -1.0))}
    return build_walker_model(robot, feet, [("left_hip", "right_hip")], base=["x", "z", "pitch"])


def random_state(model, rng):
    q = pin.neutral(model)
    v = rng.normal(0.0, 1.5, model.nv)
    for j in range(1, model.njoints):
        jm = model.joints[j]
        if jm.nq == 1:
            q[jm.idx_q] = rng.uniform(-1.0, 1.0)
        else:  # continuous: (cos, sin)
            a = rng.uniform(-1.0, 1.0)
            q[jm.idx_q:jm.idx_q + 2] = np.cos(a), np.sin(a)
    return q, v


@pytest.mark.parametrize("build", [five_link, three_link, compass])
def test_ground_force_balances_the_centre_of_mass(build, rng):
    """Newton for the whole robot: the ground force is m (a_com - g), to 1e-8 N; the stance
    foot does not accelerate."""
    w = build()
    model, data = w.model, w.model.createData()
    contact = Contact(w)
    mass = sum(inertia.mass for inertia in model.inertias)
    g = model.gravity.linear[[0, 2]]
    base = {model.joints[w.robot.joint_id(n)].idx_v for n in w.base}
    for _ in range(50):
        q, v = random_state(model, rng)
        tau = np.array([0.0 if i in base else rng.normal(0, 60.0) for i in range(model.nv)])
        res = contact.stance(q, v, tau, "left")
        pin.centerOfMass(model, data, q, v, res.a)
        a_com = data.acom[0][[0, 2]]
        np.testing.assert_allclose(res.force, mass * (a_com - g), atol=1e-8, rtol=0)
        pin.forwardKinematics(model, data, q, v, res.a)
        acc = pin.getFrameClassicalAcceleration(model, data, w.feet["left"],
                                                pin.LOCAL_WORLD_ALIGNED).linear
        np.testing.assert_allclose(acc, 0.0, atol=1e-9)


def test_centre_of_mass_acceleration_by_finite_differences(rng):
    """The COM acceleration of the contact dynamics, by a central difference of the COM along
    the motion q(t) = q + t v + t^2 a / 2 (no Pinocchio acceleration kinematics)."""
    w = five_link()
    model, data = w.model, w.model.createData()
    contact = Contact(w)
    mass = sum(inertia.mass for inertia in model.inertias)
    for _ in range(10):
        q, v = random_state(model, rng)
        tau = np.concatenate([np.zeros(3), rng.normal(0, 60.0, 4)])
        res = contact.stance(q, v, tau, "left")
        eps = 1e-4
        com = [pin.centerOfMass(model, data, q + t * v + 0.5 * t**2 * res.a)[[0, 2]]
               for t in (-eps, 0.0, eps)]
        a_fd = (com[0] - 2 * com[1] + com[2]) / eps**2
        np.testing.assert_allclose(res.force, mass * (a_fd - model.gravity.linear[[0, 2]]),
                                   atol=1e-3 * mass)


def point_masses(q):
    """Closed form of the three-link walker's point masses (Table B.1): positions (x, z) of
    (torso, hip, left leg, right leg), their masses; q = (x, z, pitch, q_left, q_right)."""
    x, z, th, ql, qr = q
    hip = np.array([x, z])
    torso = hip + L * np.array([np.sin(th), np.cos(th)])
    legs = [hip - 0.5 * R * np.array([np.sin(th + a), np.cos(th + a)]) for a in (ql, qr)]
    return np.array([torso, hip, *legs]), np.array([M_T, M_H, M_LEG, M_LEG])


def angular_momentum_closed_form(q, v, p):
    """Angular momentum about point p (y component) of the point masses, in [kg m^2/s]; the
    velocities by central differences of the closed-form positions."""
    pos, masses = point_masses(q)
    eps = 1e-6
    vel = sum(vi * (point_masses(q + eps * e)[0] - point_masses(q - eps * e)[0]) / (2 * eps)
              for vi, e in zip(v, np.eye(5)))
    r = pos - p
    # y component of r x (m v) with r = (x, 0, z): (r x mv)_y = z m vx - x m vz
    return float(np.sum(masses * (r[:, 1] * vel[:, 0] - r[:, 0] * vel[:, 1])))


def kinetic_energy_closed_form(q, v):
    pos, masses = point_masses(q)
    eps = 1e-6
    vel = sum(vi * (point_masses(q + eps * e)[0] - point_masses(q - eps * e)[0]) / (2 * eps)
              for vi, e in zip(v, np.eye(5)))
    return 0.5 * float(np.sum(masses * (vel**2).sum(axis=1)))


def test_impact_conserves_angular_momentum_about_the_new_contact(rng):
    """Three-link walker: a rigid impact at the landing foot keeps the angular momentum about
    that foot and, since the hips carry no impulsive torque, the trailing leg's about the hip;
    it never gains energy; the landing foot stops."""
    w = three_link()
    contact = Contact(w)
    for _ in range(30):
        q = np.array([0.3, 0.9, rng.uniform(-0.4, 0.4), rng.uniform(-0.5, 0.5),
                      rng.uniform(-0.5, 0.5)])
        v = rng.normal(0, 1.5, 5)
        p, _ = contact.foot_state(q, v, "right")
        imp = contact.impact(q, v, "right")
        np.testing.assert_allclose(angular_momentum_closed_form(q, imp.v, p),
                                   angular_momentum_closed_form(q, v, p), atol=1e-6)
        _, foot_v = contact.foot_state(q, imp.v, "right")
        np.testing.assert_allclose(foot_v, 0.0, atol=1e-10)
        lost = kinetic_energy_closed_form(q, v) - kinetic_energy_closed_form(q, imp.v)
        assert lost >= -1e-9
        assert imp.energy_lost == pytest.approx(lost, abs=1e-6)
        # the trailing (left) leg: only the hip's joint impulse acts on it, through the hip, so
        # its (absolute) angular momentum about the hip is unchanged by the impact
        assert leg_about_hip(q, imp.v) == pytest.approx(leg_about_hip(q, v), abs=1e-6)


def leg_about_hip(q, v):
    """Absolute angular momentum of the left leg's point mass about the hip [kg m^2/s]."""
    pos, _ = point_masses(q)
    eps = 1e-6
    vel = sum(vi * (point_masses(q + eps * e)[0] - point_masses(q - eps * e)[0]) / (2 * eps)
              for vi, e in zip(v, np.eye(5)))
    r = pos[2] - pos[1]
    return M_LEG * (r[1] * vel[2, 0] - r[0] * vel[2, 1])


def spatial_angular_momentum(model, data, q, v, p):
    """y component of the angular momentum about the world point p = (x, z), summed over the
    bodies from their masses, inertias and velocities (r x m v_c + I omega)."""
    pin.forwardKinematics(model, data, q, v)
    total = 0.0
    for i in range(1, model.njoints):
        I = model.inertias[i]
        oMi = data.oMi[i]
        c = oMi.act(I.lever)
        vel = oMi.act(data.v[i])  # spatial velocity at the world origin, world axes
        v_c = vel.linear + np.cross(vel.angular, c)
        Iw = oMi.rotation @ I.inertia @ oMi.rotation.T
        r = c - np.array([p[0], 0.0, p[1]])
        total += (np.cross(r, I.mass * v_c) + Iw @ vel.angular)[1]
    return total


@pytest.mark.parametrize("build", [five_link, compass])
def test_impact_momentum_and_energy_with_inertias(build, rng):
    w = build()
    model, data = w.model, w.model.createData()
    contact = Contact(w)
    for _ in range(30):
        q, v = random_state(model, rng)
        p, _ = contact.foot_state(q, v, "right")
        imp = contact.impact(q, v, "right")
        np.testing.assert_allclose(spatial_angular_momentum(model, data, q, imp.v, p),
                                   spatial_angular_momentum(model, data, q, v, p), atol=1e-9)
        assert imp.energy_lost >= -1e-12
        np.testing.assert_allclose(contact.foot_state(q, imp.v, "right")[1], 0.0, atol=1e-10)


# -- the closed loop -----------------------------------------------------------------------------

def standing_loop(w, kp_scale=1.0, torques="report"):
    """The five-link walker on its left foot, joints held by PD at a posture, the torso's pitch
    stabilized."""
    model = w.model
    nv = model.nv
    walker = PhysicalWalker(w, ContactChecks(friction=0.7, effort=np.full(4, 150.0),
                                             torques=torques), 1, "clock")
    kp = kp_scale * np.array([0, 0, 400, 300, 300, 300, 300.0])
    track = np.array([0, 0, 0, 1, 1, 1, 1], bool)
    stab = np.array([0, 0, 1, 0, 0, 0, 0], bool)
    law = FeedbackLaw(np.eye(nv), kp, kp / 10, track, stab, np.zeros(nv), {})
    dyn = make_dynamics(model)
    return PhysicalLoop(dyn, law, walker, 0.005, 2, stab.astype(float)), dyn


def test_standing_on_one_foot_holds_the_weight():
    w = five_link()
    loop, dyn = standing_loop(w)
    model, data = w.model, w.model.createData()
    posture = np.array([0, 0, 0, 0, 0, -0.3, 0.6])
    n = 400  # 2 s
    P, Z = np.tile(posture, (n, 1)), np.zeros((n, model.nv))
    q, v = loop.initial_state(P, Z)
    # the pitch that puts the centre of mass above the stance foot (bisection)
    lo, hi = -0.5, 0.5
    for _ in range(60):
        q[2] = 0.5 * (lo + hi)
        q, v, _ = loop.walker.complete(q, v, np.zeros_like(v))
        if pin.centerOfMass(model, data, q)[0] > 0:
            hi = q[2]
        else:
            lo = q[2]
    loop.law.targets[2] = q[2]
    log = loop.run_cycle(dyn, q, v, P, Z, Z)
    assert log.fall is None and len(log.q) == n and not log.impacts
    mg = pin.computeTotalMass(model) * -model.gravity.linear[2]
    np.testing.assert_allclose(log.force[:, 1], mg, rtol=0.01)
    assert np.abs(log.force[:, 0]).max() < 0.05 * mg


def test_passive_walker_falls_and_is_reported():
    w = five_link()
    loop, dyn = standing_loop(w, kp_scale=0.0)
    loop.known = type("NoFeedforward", (), {"inverse": lambda self, q, v, a: np.zeros(7)})()
    posture = np.array([0, 0, 0, 0, 0, -0.3, 0.6])
    n = 400
    P, Z = np.tile(posture, (n, 1)), np.zeros((n, 7))
    q, v = loop.initial_state(P, Z)
    log = loop.run_cycle(dyn, q, v, P, Z, Z)
    assert log.fall is not None and log.fall.startswith("not walking")
    assert len(log.q) < n


def test_lifting_stance_foot_is_not_walking(rng):
    """A state whose contact force would pull the foot down (F_z <= 0, checked independently by
    the centre of mass balance) stops the loop as not walking, naming the normal force."""
    w = five_link()
    model, data = w.model, w.model.createData()
    contact = Contact(w)
    loop, dyn = standing_loop(w, kp_scale=0.0)
    zero = np.zeros(7)
    for _ in range(2000):
        q, v = random_state(model, rng)
        q, v, _ = loop.walker.complete(q, v, zero)
        (_, sz), _ = contact.foot_state(q, v, "right")
        res = contact.stance(q, v, zero, "left")
        if res.force[1] < 0 and sz > 0.05:
            break
    else:
        pytest.fail("no lifting state found")
    pin.centerOfMass(model, data, q, v, res.a)
    assert pin.computeTotalMass(model) * (data.acom[0][2] - model.gravity.linear[2]) < 0
    loop.known = type("NoFeedforward", (), {"inverse": lambda self, q, v, a: zero})()
    P = np.tile(q, (10, 1))
    log = loop.run_cycle(dyn, q, v, P, np.zeros((10, 7)), np.zeros((10, 7)))
    assert log.fall is not None and "normal force" in log.fall and "not walking" in log.fall


def test_touchdown_is_located_at_contact():
    """Three-link walker falling forward on its stance leg, the swing leg held ahead: the step
    ends where the swing foot meets the ground moving down (|z| <= 1e-9 m, not by the clock),
    and the new stance foot is at the origin after relabelling."""
    w = three_link()
    model = w.model
    walker = PhysicalWalker(w, ContactChecks(friction=5.0, effort=np.full(2, 1e4)), 1, "clock")
    kp = np.array([0, 0, 4000.0, 400.0, 400.0])
    track = np.array([0, 0, 0, 0, 1], bool)
    stab = np.array([0, 0, 1, 0, 0], bool)
    C = np.eye(5)
    C[4, 2] = 1.0  # the swing leg's absolute angle: pitch + q_right
    law = FeedbackLaw(C, kp, kp / 10, track, stab, np.array([0, 0, 0.1, 0, 0]), {})
    dyn = make_dynamics(model)
    loop = PhysicalLoop(dyn, law, walker, 0.005, 2, stab.astype(float))
    n = 300
    # stance leg 0.05 rad past the vertical (foot behind the hip), swing leg at -0.3 (ahead)
    qd = np.array([0, 0, 0.1, -0.05, -0.4])
    P, Z = np.tile(qd, (n, 1)), np.zeros((n, 5))
    q, v = loop.initial_state(P, Z)
    log = loop.run_cycle(dyn, q, v, P, Z, Z)
    assert log.impacts, log.fall
    st = log.steps[0]
    assert abs(st.touchdown_height) <= 1e-9
    assert 0.2 < st.length < 1.0
    assert st.energy_lost > 0
    assert 0 < st.duration < n * 0.005
    # right after the touchdown the (relabelled) stance foot is at the origin
    k = log.impacts[0][0]
    if k < len(log.q):
        p, pv = Contact(w).foot_state(log.q[k], log.v[k], "left")
        np.testing.assert_allclose(p, 0.0, atol=1e-9)


# -- config and run path ---------------------------------------------------------------------------

LEG = {"kind": "sine", "mean": -0.121553, "amplitude": 0.178174, "phase": 4.393794,
       "harmonics": [[0.038518, -0.0531], [0.003956, 4.165483], [0.00485, -0.09429]]}


def physical_config(**walking):
    """The three-link walker as a physical walker (a gait from the pinned biped's harmonics)."""
    return {
        "name": "three_link_physical", "robot": "three_link_walker", "gravity": 9.8,
        "period_s": 1.0, "sim": {"rate_hz": 200, "cycles": 2, "substeps": 2},
        "primitives": {"basis": 16},
        "joints": {
            "base_pitch": {"role": "stabilize", "gains": {"kp": 4000.0, "kd": 800.0},
                           "target": {"link_angle": ["base_pitch"], "value": 0.125},
                           "learn": {"init": "random", "weight_scale": 0.3,
                                     "goal_center": 0.125, "goal_spread": 0.1}},
            "left_hip": {"role": "passive", "demo": LEG},
            "right_hip": {"role": "track", "link_angle": ["base_pitch", "right_hip"],
                          "demo": {**LEG, "delay": 0.5}, "gains": {"kp": 400.0, "kd": 40.0}},
        },
        "walking": {"feet": {"left": {"frame": "left_foot"}, "right": {"frame": "right_foot"}},
                    "legs": [["left_hip", "right_hip"]], "steps_per_cycle": 2,
                    "poincare": False, "phase": "clock", **walking},  # (a clock gait: its
                    # centre of mass does not move forward through every step)
        "learning": {"error": "all_feedback", "update": "gradient",  # per sample 2e-5, 2e-9
                     "rates": {"weights": 0.021066, "goal": 4e-7}},
        "seeds": 1,
    }


def test_physical_walker_config_builds():
    from feltool.runs.experiments import build_experiment

    exp = build_experiment(physical_config())
    assert exp.joints == ["base_x", "base_z", "base_pitch", "left_hip", "right_hip"]
    assert exp.config.joints["base_x"].role == "passive"
    assert exp.hybrid.walker.checks.scuff_exempt == 0.05  # no knees
    np.testing.assert_allclose(exp.hybrid.walker.checks.effort, [1000.0, 1000.0])


@pytest.mark.parametrize("feet, where", [
    ({"left": {"link": "torso", "offset": [0, 0, -1]}, "right": {"frame": "right_foot"}},
     "walking.feet.left"),
    ({"left": {"frame": "right_foot"}, "right": {"frame": "left_foot"}}, "walking.feet.left"),
    ({"left": {"frame": "nowhere"}, "right": {"frame": "right_foot"}}, "walking.feet.left"),
])
def test_foot_not_at_the_end_of_its_leg_is_rejected(feet, where):
    from feltool.errors import ConfigError
    from feltool.runs.experiments import build_experiment

    with pytest.raises(ConfigError) as err:
        build_experiment(physical_config(feet=feet))
    assert where in str(err.value)


def test_pinned_walker_fields_are_rejected_on_a_physical_walker():
    from feltool.errors import ConfigError
    from feltool.runs.experiments import build_experiment

    with pytest.raises(ConfigError) as err:
        build_experiment(physical_config(swap=["left_hip", "right_hip"]))
    assert "walking" in str(err.value) and "swap" in str(err.value)


def test_lifting_foot_is_counted_as_not_walking_in_the_summary():
    """A stance foot that cannot push the demanded normal force stops the seed as not walking;
    summary and aggregate name the kind and count it."""
    from feltool.runs.experiments import build_experiment
    from feltool.runs.runner import aggregate
    from feltool.runs.seed import run_seed

    exp = build_experiment(physical_config(normal_force_min=5000.0))
    res = run_seed(exp, 0, cycles=2)
    assert res.summary["diverged"]
    assert "normal force" in res.summary["diverged_reason"]
    assert res.summary["walking"]["walked"] is False
    assert res.summary["walking"]["not_walking"] == "normal_force"
    agg = aggregate([res.summary])
    assert agg["n_not_walking"] == 1 and agg["not_walking"] == {"normal_force": 1}
    assert agg["n_walked"] == 0


def test_touchdown_phase_ends_the_cycle_at_the_touchdown():
    """phase: touchdown: the cycle lasts until the step's touchdown (not the clock's n steps)."""
    w = three_link()
    walker = PhysicalWalker(w, ContactChecks(friction=5.0, effort=np.full(2, 1e4)), 1,
                            "touchdown")
    kp = np.array([0, 0, 4000.0, 400.0, 400.0])
    C = np.eye(5)
    C[4, 2] = 1.0
    law = FeedbackLaw(C, kp, kp / 10, np.array([0, 0, 0, 0, 1], bool),
                      np.array([0, 0, 1, 0, 0], bool), np.array([0, 0, 0.1, 0, 0]), {})
    dyn = make_dynamics(w.model)
    loop = PhysicalLoop(dyn, law, walker, 0.005, 2)
    n = 60  # the touchdown comes after about 0.67 s, beyond the nominal 0.3 s
    qd = np.array([0, 0, 0.1, -0.05, -0.4])
    P, Z = np.tile(qd, (n, 1)), np.zeros((n, 5))
    q, v = loop.initial_state(P, Z)
    log = loop.run_cycle(dyn, q, v, P, Z, Z)
    assert log.fall is None and len(log.impacts) == 1
    assert len(log.q) == log.impacts[0][0] > n
    assert log.phase_index.max() == n - 1  # the last sample is held past the nominal step
    # and a step that never lands is not walking
    loop.walker.steps_per_cycle = 2
    log2 = loop.run_cycle(dyn, q, v, P[:20], Z[:20], Z[:20])
    assert log2.fall is not None and "not walking" in log2.fall


def test_mechanical_phase_follows_the_centre_of_mass():
    """phase: mechanical: a state on the desired trajectory at sample i (centre of mass where
    the desired one is then) gets sample i back, with the desired velocity at the nominal rate;
    moving twice as fast doubles the desired velocity and quadruples the acceleration."""
    w = three_link()
    walker = PhysicalWalker(w, ContactChecks(), 1, "mechanical")
    law = FeedbackLaw(np.eye(5), np.zeros(5), np.zeros(5), np.zeros(5, bool), np.zeros(5, bool),
                      np.zeros(5), {})
    loop = PhysicalLoop(make_dynamics(w.model), law, walker, 0.005, 1)
    n = 100
    t = np.arange(n) * 0.005
    P, Pv, Pa = np.zeros((n, 5)), np.zeros((n, 5)), np.zeros((n, 5))
    P[:, 3] = -0.3 + 1.2 * t + 0.4 * t**2  # the stance leg sweeps forward, accelerating
    Pv[:, 3] = 1.2 + 0.8 * t
    Pa[:, 3] = 0.8
    P[:, 4] = 0.2
    for i in (0, 17, 50, 98):
        q, v, _ = walker.complete(P[i], Pv[i], Pa[i])
        j, p, pv, pa = loop._mechanical(q, v, P, Pv, Pa, 0, 0)
        assert j == i
        np.testing.assert_allclose(p, P[i], atol=1e-9)
        np.testing.assert_allclose(pv, Pv[i], atol=1e-9)
        j, p, pv, pa = loop._mechanical(q, 2 * v, P, Pv, Pa, 0, 0)
        np.testing.assert_allclose(pv, 2 * Pv[i], atol=1e-9)
        np.testing.assert_allclose(pa, 4 * Pa[i], atol=1e-9)
    # halfway between two samples: linear interpolation
    q0, v0, _ = walker.complete(P[40], Pv[40], Pa[40])
    q1, v1, _ = walker.complete(P[41], Pv[41], Pa[41])
    x0, x1 = walker.com_x(q0, v0)[0], walker.com_x(q1, v1)[0]
    qm = 0.5 * (q0 + q1)
    j, p, _, _ = loop._mechanical(qm, v0, P, Pv, Pa, 0, 0)
    f = 40 + (walker.com_x(qm, v0)[0] - x0) / (x1 - x0)
    np.testing.assert_allclose(p[3], np.interp(f, np.arange(n), P[:, 3]), atol=1e-12)


def test_follow_demo_gives_the_demonstration_itself():
    """A follow_demo joint's forward trajectory is its demonstration at the control rate (here
    the sine and its derivatives in closed form), not its RMP fit."""
    from feltool.errors import ConfigError
    from feltool.runs.experiments import build_experiment

    raw = physical_config()
    raw["joints"]["left_hip"]["follow_demo"] = True
    exp = build_experiment(raw)
    theta = exp.initial_parameters(0)
    Q, V, A = exp.primitives.desired(theta)
    T, n = 1.0, 200
    t = np.arange(n) * T / n
    w = 2 * np.pi / T
    q = LEG["mean"] + LEG["amplitude"] * np.sin(w * t + LEG["phase"])
    qd = LEG["amplitude"] * w * np.cos(w * t + LEG["phase"])
    qdd = -LEG["amplitude"] * w**2 * np.sin(w * t + LEG["phase"])
    for k, (amp, ph) in enumerate(LEG["harmonics"], start=2):
        q += amp * np.sin(k * w * t + ph)
        qd += amp * k * w * np.cos(k * w * t + ph)
        qdd -= amp * (k * w) ** 2 * np.sin(k * w * t + ph)
    i = exp.joints.index("left_hip")
    np.testing.assert_allclose(Q[:, i], q, atol=1e-12)
    np.testing.assert_allclose(V[:, i], qd, atol=1e-10)
    np.testing.assert_allclose(A[:, i], qdd, atol=1e-8)
    raw["joints"]["left_hip"]["learn"] = {"init": "random"}
    with pytest.raises(ConfigError) as err:
        build_experiment(raw)
    assert "joints.left_hip" in str(err.value) and "follow_demo" in str(err.value)


def test_late_touchdown_holds_the_step_last_sample():
    """phase: touchdown with two steps per cycle: a touchdown later than the nominal step holds
    the first step's last sample; it never runs into the second step's samples (whose desired
    velocities are the post-impact ones) before the impact."""
    w = three_link()
    walker = PhysicalWalker(w, ContactChecks(friction=5.0, effort=np.full(2, 1e4)), 2,
                            "touchdown")
    kp = np.array([0, 0, 4000.0, 400.0, 400.0])
    C = np.eye(5)
    C[4, 2] = 1.0
    law = FeedbackLaw(C, kp, kp / 10, np.array([0, 0, 0, 0, 1], bool),
                      np.array([0, 0, 1, 0, 0], bool), np.array([0, 0, 0.1, 0, 0]), {})
    dyn = make_dynamics(w.model)
    loop = PhysicalLoop(dyn, law, walker, 0.005, 2)
    ns = 60  # samples per step; the touchdown comes after about 0.67 s, beyond 0.3 s
    qd = np.array([0, 0, 0.1, -0.05, -0.4])
    P, Z = np.tile(qd, (2 * ns, 1)), np.zeros((2 * ns, 5))
    q, v = loop.initial_state(P, Z)
    log = loop.run_cycle(dyn, q, v, P, Z, Z)
    assert len(log.impacts) >= 1
    k_td = log.impacts[0][0]
    assert k_td > ns  # late
    assert log.phase_index[:k_td].max() == ns - 1
    if len(log.phase_index) > k_td:  # the second step starts at its first sample
        assert log.phase_index[k_td] == ns


def test_not_walking_before_the_first_sample_is_reported():
    """A cycle that stops before its first sample (here the mechanical phase of a desired
    centre of mass that does not move forward) is reported as not walking, no exception."""
    from feltool.runs.experiments import build_experiment
    from feltool.runs.seed import run_seed

    exp = build_experiment(physical_config(phase="mechanical"))
    res = run_seed(exp, 0, cycles=2)
    assert res.summary["diverged"] and res.summary["cycles"] == 0
    assert res.summary["walking"]["walked"] is False
    assert res.summary["walking"]["not_walking"] == "phase"


def test_mechanical_phase_reference_acceleration_is_its_velocitys_rate():
    """Off the designed orbit (a perturbed torso RMP) the phase speeds up and slows down; the
    reference's acceleration then includes p' s_ddot, so it matches the finite difference of the
    reference's velocity along the walk: RMS 1.4 % of the accelerations' (without the term
    3.0 %; the rest is the samples' linear interpolation and the term's one-step lag)."""
    from feltool.runs.experiments import load_experiment

    exp = load_experiment("configs/gaits/five_link_walker.yaml", ["walking.poincare=false"])
    P, Pv, Pa = exp.primitives.desired(exp.initial_parameters(0))
    q, v = exp.hybrid.initial_state(P, Pv)
    log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
    dt = exp.config.dt
    ks = np.arange(5, log.impacts[0][0] - 5)  # inside the first step
    cols = [exp.joints.index(n) for n in ("base_pitch", "left_hip", "left_knee", "right_hip",
                                          "right_knee")]
    fd = (log.Vd[ks + 1][:, cols] - log.Vd[ks - 1][:, cols]) / (2 * dt)
    ad = log.Ad[ks][:, cols]
    assert np.sqrt(np.mean((fd - ad) ** 2)) < 0.02 * np.sqrt(np.mean(ad**2))
