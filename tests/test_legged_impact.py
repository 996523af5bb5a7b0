"""Rigid impacts of several feet with unilateral contacts (issue 32, the trot's blocker): the
Moreau/Gauss impulse QP against independent references -- ``pin.impulseDynamics`` when every
impulse pushes, the complementarity conditions, the energy, the centroidal momentum, and a rod
landing on its two ends written in closed form here.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.impact import polygon_cone, unilateral_impact
from feltool.walking.legged.model import legged_model, load_solo12

FEET = ("FL", "FR", "HL", "HR")
SEEDS = range(10)


@pytest.fixture(scope="module")
def solo():
    return load_solo12(effort=2.7)


def _falling(solo, seed):
    """Feet on the ground, the robot coming down at 0.3 m/s, small random joint rates: every
    foot approaches the ground and the bilateral impulses all push."""
    rng = np.random.default_rng(seed)
    q = pin.integrate(solo.model, solo.standing(), 0.05 * rng.standard_normal(18))
    q = solo.standing(q)
    v = 0.05 * rng.standard_normal(18)
    v[2] -= 0.3
    return q, v


def _twisting(solo, seed):
    """Feet on the ground, a roll or pitch of 1 rad/s (random axis and sign) about the ground
    below the base, small random velocities (0.02) and 0.05 m/s down: one side's feet come
    down, the other's go up, and the bilateral impact asks some to pull."""
    rng = np.random.default_rng(100 + seed)
    q = solo.standing(pin.integrate(solo.model, solo.standing(), 0.05 * rng.standard_normal(18)))
    v = 0.02 * rng.standard_normal(18)
    w = np.zeros(3)
    w[rng.integers(2)] = rng.choice([-1.0, 1.0])
    v[3:6] += w
    v[:3] -= np.cross(w, [0.0, 0.0, -q[2]])
    v[2] -= 0.05
    return q, v


def _momentum(model, q, v):
    d = model.createData()
    h = pin.computeCentroidalMomentum(model, d, q, v)
    return np.r_[h.linear, h.angular], np.array(d.com[0])


@pytest.mark.parametrize("seed", SEEDS)
def test_it_is_impulse_dynamics_when_every_impulse_pushes(solo, seed):
    """All bilateral impulses compressive and inside the (wide) cone: the unilateral impact is
    ``pin.impulseDynamics`` on all four feet, every foot held."""
    c = LeggedContact(solo)
    q, v = _falling(solo, seed)
    ref = c.impact(q, v, FEET)
    assert (ref.impulses[:, 2] > 0).all()
    r = unilateral_impact(c, q, v, FEET, friction=3.0)
    assert r.exact and r.held == FEET and r.leaving == () and r.sliding == ()
    np.testing.assert_allclose(r.v, ref.v, atol=1e-10)
    np.testing.assert_allclose(r.impulses, ref.impulses, atol=1e-12)
    assert r.energy_lost == pytest.approx(ref.energy_lost, rel=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_foot_that_would_pull_gets_no_impulse_and_leaves(solo, seed):
    """Random approach with a roll or pitch: the bilateral impact pulls some foot; the unilateral
    one (mu = 1) gives no foot a pulling impulse and lets none move down; a held foot that
    sticks stops, and for it and every foot with no impulse the normal impulse times the normal
    velocity is 0; a foot on its cone's edge is reported sliding (Anitescu's relaxation lifts
    it a little, so there the product is not 0); some pulled foot leaves."""
    c = LeggedContact(solo)
    q, v = _twisting(solo, seed)
    ref = c.impact(q, v, FEET)
    r = unilateral_impact(c, q, v, FEET, friction=1.0)
    pulled = [f for f, i in zip(FEET, ref.impulses) if i[2] < 0]
    assert pulled, "the case should ask some foot to pull"
    assert r.exact and r.sliding == ()
    J = c.jacobian(q, FEET)
    rel = (J @ r.v).reshape(4, 3)
    scale = np.abs(J @ v).max()
    for i, foot in enumerate(FEET):
        lz, vz = r.impulses[i, 2], rel[i, 2]
        assert lz >= -1e-12 and vz >= -1e-9 * scale
        if foot not in r.sliding:
            assert abs(lz * vz) < 1e-12
        if foot in r.held and foot not in r.sliding:
            np.testing.assert_allclose(rel[i], 0.0, atol=1e-9 * scale)
        if foot in r.leaving:
            assert abs(lz) < 1e-9 * np.abs(r.impulses).max()
    assert set(r.leaving) == set(FEET) - set(r.held)
    assert set(r.leaving) & set(pulled)  # a foot the bilateral impact pulled leaves
    if r.exact:
        np.testing.assert_allclose(r.v, c.impact(q, v, r.held).v, atol=1e-12)


def test_with_less_friction_some_twisting_impacts_slide(solo):
    """At mu = 0.7 (the checks' default) three of the ten twisting cases have no sticking
    solution (a held foot's impulse is on its cone's edge): counted, and named sliding."""
    c = LeggedContact(solo)
    results = [unilateral_impact(c, *_twisting(solo, s), FEET, friction=0.7) for s in SEEDS]
    assert [r.exact for r in results].count(False) == 3
    assert all(bool(r.sliding) != r.exact for r in results)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("friction", [0.7, 3.0, np.inf])
def test_energy_never_grows_and_momentum_changes_by_the_impulses(solo, seed, friction):
    """Every case (sticking, leaving, sliding): the kinetic energy does not grow, the impulses
    stay in their cones, and the centroidal momentum (Pinocchio's) changes by exactly the
    impulses' resultant and moment about the centre of mass (1e-10)."""
    c = LeggedContact(solo)
    for q, v in (_falling(solo, seed), _twisting(solo, seed)):
        r = unilateral_impact(c, q, v, FEET, friction=friction)
        assert r.energy_lost >= -1e-12
        A = polygon_cone(4, friction)
        assert np.all(A @ r.impulses.ravel() <= 1e-9 * np.abs(r.impulses).max())
        h0, com = _momentum(solo.model, q, v)
        h1, _ = _momentum(solo.model, q, r.v)
        P = c.positions(q)
        res = r.impulses.sum(0)
        mom = sum(np.cross(p - com, i) for p, i in zip(P, r.impulses))
        np.testing.assert_allclose(h1 - h0, np.r_[res, mom], atol=1e-10)


def test_a_sliding_foot_is_reported(solo):
    """The robot dropped straight down needs more friction than 0.7 at some feet (the legs'
    inertia turns the impulse): the impact names them sliding, and with ample friction none
    slides."""
    c = LeggedContact(solo)
    found = False
    for seed in SEEDS:
        q, v = _falling(solo, seed)
        ref = c.impact(q, v, FEET)
        ratio = np.hypot(ref.impulses[:, 0], ref.impulses[:, 1]) / ref.impulses[:, 2]
        r = unilateral_impact(c, q, v, FEET, friction=0.7)
        if ratio.max() > 0.7:
            found = True
            assert r.sliding and not r.exact
        assert unilateral_impact(c, q, v, FEET, friction=3.0).sliding == ()
    assert found


def _point_mass(m=2.0):
    """A point mass ``m`` [kg] (a tiny inertia) on a free flyer, its one foot at its centre."""
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(j, pin.Inertia(m, np.zeros(3), 1e-4 * np.eye(3)), pin.SE3.Identity())
    model.addBodyFrame("ball", j, pin.SE3.Identity(), 0)
    return legged_model(model, {"P": {"link": "ball", "offset": [0, 0, 0]}},
                        q0=pin.neutral(model), name="ball")


@pytest.mark.parametrize("vx, vz", [(0.3, -1.0), (1.0, -1.0), (0.5, 0.2)])
def test_a_point_mass_is_the_closed_form(vx, vz):
    """A point mass m hitting the ground at (vx, 0, vz), octagon cone of mu = 0.7 (its face
    towards -x: -i_x <= mu' i_z, mu' = mu cos(pi/8)). Closed forms written here: coming down
    inside the cone (vx <= -mu' vz) it sticks, impulse -m v, all its kinetic energy lost; outside
    it slides on that face, the impulse the Euclidean projection of -m v onto it,
    i = -m v - m (vx + mu' vz)/(1 + mu'^2) (-1, 0, -mu'), leaving at v_z = mu' (vx + mu' vz)/
    (1 + mu'^2) > 0 (Anitescu's lift); moving up it gets nothing."""
    m, mu = 2.0, 0.7
    mup = mu * np.cos(np.pi / 8)
    ball = _point_mass(m)
    c = LeggedContact(ball)
    v = np.zeros(6)
    v[0], v[2] = vx, vz
    r = unilateral_impact(c, ball.q0, v, ("P",), friction=mu)
    vel = np.array([vx, 0.0, vz])
    if vz > 0:
        assert r.exact and r.held == () and r.leaving == ("P",)
        np.testing.assert_array_equal(r.impulses, 0.0)
        np.testing.assert_allclose(r.v, v, atol=1e-15)
        return
    if vx <= -mup * vz:
        assert r.exact and r.held == ("P",) and r.sliding == ()
        np.testing.assert_allclose(r.impulses[0], -m * vel, atol=1e-12)
        np.testing.assert_allclose(r.v[:3], 0.0, atol=1e-12)
        assert r.energy_lost == pytest.approx(0.5 * m * vel @ vel, rel=1e-12)
    else:
        n = np.array([-1.0, 0.0, -mup])
        imp = -m * vel - m * (vx + mup * vz) / (1 + mup ** 2) * n
        assert not r.exact and r.sliding == ("P",)
        np.testing.assert_allclose(r.impulses[0], imp, atol=1e-12)
        np.testing.assert_allclose(r.v[:3], vel + imp / m, atol=1e-12)
        assert r.normal_velocity[0] == pytest.approx(mup * (vx + mup * vz) / (1 + mup ** 2),
                                                     abs=1e-12)
        assert r.normal_velocity[0] > 0
