"""The 3D legged foundation (issue 32, acceptance 3): Solo-12 and any free-flyer URDF with point
feet, the multi-foot stance dynamics against Pinocchio's centroidal quantities and finite
differences of the momentum, rigid impacts of several feet (momentum, energy), the contact
checks (a foot that would pull is not walking), the allocation QP, and Solo-12 standing 2 s
after a push.
"""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from feltool.errors import ConfigError, RobotError
from feltool.walking.checks import ContactChecks, NotWalking
from feltool.walking.legged.checks import LeggedStats, check_impact, check_stance
from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.control import StandingController
from feltool.walking.legged.model import legged_model, load_legged_urdf, load_solo12
from feltool.walking.legged.stand import Push, stand

FEET = ("FL", "FR", "HL", "HR")
SEEDS = range(10)


@pytest.fixture(scope="module")
def solo():
    return load_solo12(effort=2.7)


def _solo_urdf() -> Path:
    import example_robot_data as erd

    return Path(erd.load("solo12").urdf)


def _state(solo, seed, spread=0.1):
    rng = np.random.default_rng(seed)
    q = pin.integrate(solo.model, solo.standing(), spread * rng.standard_normal(solo.nv))
    v = rng.standard_normal(solo.nv)
    return rng, q, v


def test_solo12_loads_with_its_feet_and_stands_on_the_ground(solo):
    assert (solo.nq, solo.nv, len(solo.motors)) == (19, 18, 12)
    assert list(solo.feet) == list(FEET)
    assert [solo.model.frames[f].name for f in solo.feet.values()] == \
        ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"]
    urdf_mass = sum(float(m.get("value")) for m in ET.parse(_solo_urdf()).iter("mass"))
    assert solo.mass == pytest.approx(urdf_mass, abs=1e-9)
    p = solo.foot_positions(solo.standing())
    np.testing.assert_allclose(p[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(p[:, :2], solo.foot_positions(solo.q0)[:, :2], atol=1e-12)


def test_feet_by_link_and_offset_are_the_frames_they_name(solo):
    """Solo-12's URDF on a free flyer, its feet as the lower legs' points at the offset the
    URDF's fixed ankle joints give (read from the file here): the same points as its frames."""
    root = ET.parse(_solo_urdf()).getroot()
    feet = {}
    for leg in FEET:
        joint = root.find(f"joint[@name='{leg}_ANKLE']")
        offset = [float(x) for x in joint.find("origin").get("xyz").split()]
        feet[leg] = {"link": joint.find("parent").get("link"), "offset": offset}
    other = load_legged_urdf(_solo_urdf(), feet)
    assert (other.nq, other.nv) == (19, 18)
    for seed in range(3):
        _, q, _ = _state(solo, seed, 0.5)
        np.testing.assert_allclose(other.foot_positions(q), solo.foot_positions(q), atol=1e-12)


def test_any_free_flyer_urdf_with_named_feet():
    import example_robot_data.robots_loader as rl

    path = Path(rl.getModelPath("anymal_b_simple_description/robots/anymal.urdf")) / \
        "anymal_b_simple_description/robots/anymal.urdf"
    anymal = load_legged_urdf(path, {f: {"frame": f"{f}_FOOT"} for f in ("LF", "RF", "LH", "RH")})
    assert (anymal.nv, len(anymal.motors)) == (18, 12)
    q = anymal.standing(pin.neutral(anymal.model))
    np.testing.assert_allclose(anymal.foot_positions(q)[:, 2], 0.0, atol=1e-10)
    c = LeggedContact(anymal)
    ctl = StandingController(anymal, q)
    al = ctl(q, np.zeros(18), tuple(anymal.feet))
    r = c.stance(q, np.zeros(18), anymal.selection() @ al.u, tuple(anymal.feet))
    assert al.exact and np.abs(r.a).max() < 1e-9  # held still on its own torques
    np.testing.assert_allclose(r.forces.sum(0), [0.0, 0.0, anymal.mass * 9.81], atol=1e-6)


def test_bad_feet_and_bases_are_named(solo, tmp_path):
    with pytest.raises(ConfigError, match=r"walking\.feet\.FL.*no frame 'NOPE'"):
        legged_model(solo.model, {"FL": {"frame": "NOPE"}})
    with pytest.raises(ConfigError, match=r"walking\.feet\.X.*no link 'nolink'"):
        legged_model(solo.model, {"X": {"link": "nolink", "offset": [0, 0, 0]}})
    with pytest.raises(ConfigError, match=r"walking\.feet\.X\.offset"):
        legged_model(solo.model, {"X": {"link": "FL_LOWER_LEG", "offset": [0, 0]}})
    with pytest.raises(RobotError, match="free flyer"):
        legged_model(pin.buildSampleModelManipulator(), {"X": {"frame": "effector_body"}})
    with pytest.raises(RobotError, match="no such URDF"):
        load_legged_urdf(tmp_path / "missing.urdf", {"X": {"frame": "a"}})


def mu_(ctl):
    return ctl.margin * ctl.friction / np.sqrt(2)


def _stance_sets():
    return [s for n in range(1, 5) for s in itertools.combinations(FEET, n)]


@pytest.mark.parametrize("seed", SEEDS)
def test_contact_forces_balance_the_centroidal_momentum_rate(solo, seed):
    """Any stance set, random state and torques: the feet's forces equal m (a_com - g) and their
    moments about the COM the angular momentum's rate (Pinocchio's centroidal dynamics, and a
    central difference of its centroidal momentum along the motion), to 1e-8; the stance feet
    do not accelerate."""
    c = LeggedContact(solo)
    m, d = solo.model, pin.Data(solo.model)
    mass, g = solo.mass, m.gravity.linear
    rng, q, v = _state(solo, seed)
    for feet in _stance_sets():
        tau = np.r_[np.zeros(6), rng.uniform(-2.7, 2.7, 12)]
        r = c.stance(q, v, tau, feet)
        pin.computeCentroidalMomentumTimeVariation(m, d, q, v, r.a)
        dh = np.array(d.dhg)
        com = pin.centerOfMass(m, d, q, v, r.a)
        acom = np.array(d.acom[0])
        p = c.positions(q)[[FEET.index(f) for f in feet]]
        moment = sum(np.cross(pi - com, fi) for pi, fi in zip(p, r.forces))
        np.testing.assert_allclose(r.forces.sum(0), mass * (acom - g), atol=1e-8)
        np.testing.assert_allclose(r.forces.sum(0), dh[:3] - mass * g, atol=1e-8)
        np.testing.assert_allclose(moment, dh[3:], atol=1e-8)
        # independent of Pinocchio's time variation: the momentum about the moving COM,
        # differenced along q' = v, v' = a
        eps = 1e-6
        h = []
        for s in (eps, -eps):
            qs, vs = pin.integrate(m, q, s * v + 0.5 * s * s * r.a), v + s * r.a
            h.append(np.array(pin.computeCentroidalMomentum(m, d, qs, vs)))
        fd = (h[0] - h[1]) / (2 * eps)
        np.testing.assert_allclose(fd[:3], r.forces.sum(0) + mass * g, atol=1e-6)
        np.testing.assert_allclose(fd[3:], moment, atol=1e-6)
        pin.forwardKinematics(m, d, q, v, r.a)
        for f in feet:
            acc = pin.getFrameClassicalAcceleration(m, d, solo.feet[f], pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(acc.linear, 0.0, atol=1e-8)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("feet", [("FL", "HR"), ("FR", "HL"), ("FL", "FR", "HL"), FEET])
def test_an_impact_of_several_feet_conserves_momentum_about_them_and_loses_energy(solo, seed, feet):
    """A rigid touchdown of 2-4 feet: they stop; the centroidal momentum changes by exactly the
    impulses' resultant and moment about the COM; with two feet the angular momentum about the
    line through them is conserved; the kinetic energy never grows and its loss is
    1/2 dv' M dv (Kelvin's theorem for an inelastic impact)."""
    c = LeggedContact(solo)
    m, d = solo.model, pin.Data(solo.model)
    rng, q, v = _state(solo, seed, 0.3)
    imp = c.impact(q, v, feet)
    assert np.abs(c.jacobian(q, feet) @ imp.v).max() < 1e-10
    h0 = np.array(pin.computeCentroidalMomentum(m, d, q, v))
    h1 = np.array(pin.computeCentroidalMomentum(m, d, q, imp.v))
    com = pin.centerOfMass(m, d, q)
    p = c.positions(q)[[FEET.index(f) for f in feet]]
    np.testing.assert_allclose(h1[:3] - h0[:3], imp.impulses.sum(0), atol=1e-10)
    np.testing.assert_allclose(h1[3:] - h0[3:], sum(np.cross(pi - com, ii) for pi, ii in
                                                    zip(p, imp.impulses)), atol=1e-10)
    for i, j in itertools.combinations(range(len(feet)), 2):
        if len(feet) == 2:
            axis = (p[j] - p[i]) / np.linalg.norm(p[j] - p[i])
            about = [hh[3:] + np.cross(com - p[i], hh[:3]) for hh in (h0, h1)]
            assert axis @ about[1] == pytest.approx(axis @ about[0], abs=1e-10)
    M = pin.crba(m, d, q)
    M = np.triu(M) + np.triu(M, 1).T
    dv = imp.v - v
    assert imp.energy_lost >= 0.0
    assert imp.energy_lost == pytest.approx(0.5 * dv @ M @ dv, rel=1e-9, abs=1e-12)
    assert imp.energy_lost == pytest.approx(c.kinetic_energy(q, v) - c.kinetic_energy(q, imp.v),
                                            abs=1e-12)


def test_a_foot_that_would_pull_is_not_walking(solo):
    """Standing on four feet, the front-left leg's motors pulling its foot up by 20 N (its
    Jacobian's transpose): the stance solve needs that foot to pull, and the check says so; a
    roll push in the loop does the same."""
    c = LeggedContact(solo)
    q = solo.standing()
    u = (c.jacobian(q, ("FL",)).T @ np.array([0.0, 0.0, 20.0]))[6:]
    assert not u[3:].any() and np.abs(u).max() < 2.7  # the FL leg's motors only
    r = c.stance(q, np.zeros(18), solo.selection() @ u, FEET)
    assert r.forces[0, 2] < 0.0 < r.forces[1:, 2].min()
    with pytest.raises(NotWalking, match="stance foot FL would pull") as exc:
        check_stance(ContactChecks(), LeggedStats(), FEET, r.forces)
    assert exc.value.kind == "normal_force"
    ctl = StandingController(solo, q)
    # a roll push unloads the left feet; with unlimited friction (their tangential forces grow
    # relative to the vanishing normal ones: a slip otherwise comes first) the pull ends it
    chk = ContactChecks(friction=np.inf, effort=solo.effort)
    log = stand(solo, ctl, q, duration=0.3, checks=chk,
                push=Push(0.05, 0.2, torque=(8.0, 0.0, 0.0)))
    assert log.kind == "normal_force" and "would pull" in log.not_walking
    assert "FL" in log.not_walking or "HL" in log.not_walking
    assert log.t[-1] < 0.25


def test_impact_checks_name_a_pulling_or_slipping_foot_and_a_foot_that_does_not_lift():
    chk = ContactChecks(friction=0.5)
    with pytest.raises(NotWalking, match="FL would pull") as exc:
        check_impact(chk, LeggedStats(), ("FL",), np.array([[0.0, 0.0, -0.1]]))
    assert exc.value.kind == "impulse"
    with pytest.raises(NotWalking, match="HR slips"):
        check_impact(chk, LeggedStats(), ("HR",), np.array([[0.3, 0.0, 0.5]]))
    with pytest.raises(NotWalking, match="FR does not lift off") as exc:
        check_impact(chk, LeggedStats(), ("FL",), np.array([[0.0, 0.0, 0.5]]), ("FR",),
                     np.array([-0.01]))
    assert exc.value.kind == "lift_off"


@pytest.mark.parametrize("seed", range(5))
def test_the_allocation_qp_is_the_constrained_metric_allocation_with_cones(solo, seed):
    """With four feet the constrained-metric allocation is singular (rank 6 of 12) and the QP
    picks among its solutions; its predicted forces are the plant's, and the allocated torques
    give exactly the constrained accelerations the wanted force would, inside the friction
    pyramid and the torque limits."""
    c = LeggedContact(solo)
    rng, q, v = _state(solo, seed, 0.03)
    v *= 0.1
    ctl = StandingController(solo, solo.standing())
    Minv = pin.computeMinverse(solo.model, pin.Data(solo.model), q)
    Minv = np.triu(Minv) + np.triu(Minv, 1).T
    J = c.jacobian(q, FEET)
    W = Minv - Minv @ J.T @ np.linalg.solve(J @ Minv @ J.T, J @ Minv)
    B = solo.selection()
    assert np.linalg.matrix_rank(B.T @ W @ B, tol=1e-8 * np.abs(B.T @ W @ B).max()) == 6
    tau_w = ctl.wanted(q, v)
    al = ctl.allocate(q, v, tau_w, FEET)
    assert al.solved and al.exact
    plant = c.stance(q, v, B @ al.u, FEET)
    np.testing.assert_allclose(al.forces, plant.forces, atol=1e-9)
    wanted = c.stance(q, v, tau_w, FEET)
    np.testing.assert_allclose(plant.a, wanted.a, atol=1e-9 * max(1.0, np.abs(wanted.a).max()))
    # among those, the smallest torques: no other exact allocation inside the limits is smaller
    N = np.linalg.eigh(B.T @ W @ B)[1][:, :6]
    for z in rng.standard_normal((20, 6)) * 0.05:
        other = al.u + N @ z
        f = c.stance(q, v, B @ other, FEET).forces
        if np.all(np.abs(f[:, :2]) <= mu_(ctl) * f[:, 2:]) and f[:, 2].min() > \
                ctl.normal_force_min and np.all(np.abs(other) <= 2.7):
            assert other @ other >= al.u @ al.u - 1e-9
    mu = ctl.margin * ctl.friction / np.sqrt(2)
    assert np.all(al.forces[:, 2] >= ctl.normal_force_min - 1e-7)
    assert np.all(np.abs(al.forces[:, :2]) <= mu * al.forces[:, 2:] + 1e-7)
    assert np.all(np.abs(al.u) <= 2.7 + 1e-7)


def test_the_allocation_keeps_the_cone_when_the_wanted_force_would_leave_it(solo):
    """A wanted force that pushes the base sideways harder than friction allows unallocated:
    the unconstrained allocation's forces leave the cone, the QP's stay in it."""
    q = solo.standing()
    ctl = StandingController(solo, q)
    tau_w = ctl.wanted(q, np.zeros(18))
    pin.computeJointJacobians(ctl.model, ctl.data, q)
    Jb = pin.getJointJacobian(ctl.model, ctl.data, 1, pin.LOCAL_WORLD_ALIGNED)
    tau_w += Jb.T @ np.array([0.0, 30.0, 0.0, 0.0, 0.0, 0.0])
    al = ctl.allocate(q, np.zeros(18), tau_w, FEET)
    assert al.solved and not al.exact
    c = LeggedContact(solo)
    B = solo.selection()
    free = c.stance(q, np.zeros(18), tau_w, FEET).forces
    assert np.max(np.hypot(free[:, 0], free[:, 1]) / free[:, 2]) > 0.7
    mu = ctl.margin * ctl.friction / np.sqrt(2)
    f = c.stance(q, np.zeros(18), B @ al.u, FEET).forces
    assert np.all(np.abs(f[:, :2]) <= mu * f[:, 2:] + 1e-7) and f[:, 2].min() > 0.0


def test_solo12_stands_two_seconds_after_a_push_and_stays_physical(solo):
    """1 kHz, a 10 N sideways push on the base for 0.1 s: every sub-step physical (normal force,
    circular cone, 2.7 N m torques), the base rolls and comes back to its height and level."""
    q = solo.standing()
    ctl = StandingController(solo, q)
    log = stand(solo, ctl, q, duration=2.0, push=Push(0.2, 0.1, force=(0.0, 10.0, 0.0)))
    assert log.not_walking is None, log.not_walking
    assert log.t[-1] == pytest.approx(1.999)
    st = log.stats
    assert st.min_normal_force > 1.0 and st.max_friction_ratio < 0.7 and st.max_torque < 2.7
    assert ctl.infeasible == 0
    assert np.abs(log.roll).max() > 5e-3  # the push moved it
    assert abs(log.roll[-1]) < 2e-4 and abs(log.pitch[-1]) < 2e-4
    assert log.height[-1] == pytest.approx(q[2], abs=1e-4)
    # the stance forces carry the weight at rest again
    assert log.forces[-1][:, 2].sum() == pytest.approx(solo.mass * 9.81, rel=1e-3)


def test_a_dropped_robot_touches_down_on_the_ground_with_a_checked_impact(solo):
    """Solo-12 falling with every foot 5 mm up and no torque: the sub-step ends at the
    touchdown, located on the ground (1e-9 m), all four feet landing together; the impact stops
    them with pushing impulses and takes the energy it lost (the flight conserves it)."""
    from feltool.walking.legged.events import touchdown

    c = LeggedContact(solo)
    q = solo.standing()
    q[2] += 0.005
    v = np.zeros(18)
    v[2] = -0.3
    st = LeggedStats()
    q1, v1, _, landed, used, after = touchdown(c, ContactChecks(), st, q, v,
                                               lambda qq, s: np.zeros(18), 0.05, (), FEET)
    assert landed == FEET and 0.0 < used < 0.05
    np.testing.assert_allclose(c.positions(q1)[:, 2], 0.0, atol=1e-9)
    assert np.abs(c.jacobian(q1, FEET) @ v1).max() < 1e-10
    # the flight conserves energy (RK4), the impact takes what it lost
    e0 = c.kinetic_energy(q, v) + c.potential_energy(q)
    e1 = c.kinetic_energy(q1, v1) + c.potential_energy(q1)
    assert st.energy_lost > 0.0 and e1 == pytest.approx(e0 - st.energy_lost, abs=1e-6)


def test_a_lifted_leg_is_released_carried_and_its_touchdown_checked(solo):
    """The base moved over the other three feet, the front-left foot released at 0.6 s (it
    accelerates up), lifted 3 cm and put down: the three-foot stance is physical throughout. Its
    touchdown is not: the bilateral impact of four feet would ask the diagonal foot FR to pull
    (by about 1e-5 N s); the unilateral impact lets FR leave, but FL, landing straight down at
    0.22 m/s, needs |i_t|/i_n = 0.68, beyond the octagon inscribed in mu = 0.7 (0.647): it
    slides, which the checks report (kind impulse)."""
    from feltool.walking.legged.model import inverse_kinematics

    q0 = solo.standing()
    P0 = solo.foot_positions(q0)
    shift = np.r_[P0[1:, :2].mean(0), 0.0]

    def pose(t):
        base = q0[:7].copy()
        x = np.clip(t / 0.5, 0.0, 1.0)
        base[:3] += shift * x * x * (3 - 2 * x)
        P = P0.copy()
        sw = (t - 0.6) / 0.3
        if 0 < sw < 1:
            P[0, 2] = 0.03 * np.sin(np.pi * sw) ** 2 - 0.004 * sw ** 2
        elif sw >= 1:
            P[0, 2] = -0.004
        return inverse_kinematics(solo, base, P, q0)

    def motion(t, e=1e-4):
        qm, qc, qp = pose(t - e), pose(t), pose(t + e)
        return (qc, pin.difference(solo.model, qm, qp) / (2 * e),
                (pin.difference(solo.model, qc, qp) - pin.difference(solo.model, qm, qc)) / e ** 2)

    def schedule(t):
        return FEET[1:] if 0.6 <= t < 0.75 else FEET

    ctl = StandingController(solo, q0, motion=motion)
    log = stand(solo, ctl, q0, duration=1.2, schedule=schedule)
    air = (log.t > 0.61) & (log.t < 0.85)
    assert np.isnan(log.forces[air, 0]).all() and (log.forces[air, 1:, 2] > 1.0).all()
    assert solo.foot_positions(log.q[np.searchsorted(log.t, 0.75)])[0, 2] > 0.025
    assert log.kind == "impulse" and "FL slides" in log.not_walking
    assert 0.85 < log.t[-1] < 0.92
    assert log.stats.max_friction_ratio < 0.7 and log.stats.max_torque < 2.7
