"""Flat soles as their four corners (issue 32, the 3D biped's feet): several points of one link
are redundant contacts. Checked against independent references: Pinocchio's 6D contact at the
sole (``CONTACT_6D``, its constraint dynamics and impulse dynamics) for the accelerations, the
resultant wrench and the impact; the centroidal momentum's rate; the least-norm forces against
the null space of the points' Jacobian (scipy); the contact wrench cone of a rectangle in closed
form (centre of pressure inside it); Talos standing after a push with every check on.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.linalg import null_space

from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.control import StandGains, StandingController
from feltool.walking.legged.model import load_talos_legs
from feltool.walking.legged.sole import spread
from feltool.walking.legged.stand import Push, random_start, stand

SEEDS = range(5)


@pytest.fixture(scope="module")
def talos():
    return load_talos_legs()


def _sole(talos, side):
    return tuple(f for f in talos.feet if f.startswith(side + "_"))


def _six_d(talos, sides, q, v, tau=None, impulse=False):
    """Pinocchio's own solution with each sole a 6D contact at its corners' centre."""
    m = talos.model
    data = m.createData()
    models = pin.StdVec_RigidConstraintModel()
    for side in sides:
        fids = [talos.feet[f] for f in _sole(talos, side)]
        joint = m.frames[fids[0]].parentJoint
        centre = np.mean([m.frames[f].placement.translation for f in fids], axis=0)
        models.append(pin.RigidConstraintModel(pin.ContactType.CONTACT_6D, m, joint,
                                               pin.SE3(np.eye(3), centre),
                                               pin.LOCAL_WORLD_ALIGNED))
    datas = pin.StdVec_RigidConstraintData()
    for cm in models:
        datas.append(cm.createData())
    pin.initConstraintDynamics(m, data, models, datas)
    prox = pin.ProximalSettings(1e-13, 1e-13, 0.0, 1)
    if impulse:
        out = pin.impulseDynamics(m, data, q, v, models, datas, 0.0, prox)
    else:
        out = pin.constraintDynamics(m, data, q, v, tau, models, datas, prox)
    return np.array(out), [cd.contact_force for cd in datas], models


def _state(talos, seed):
    rng = np.random.default_rng(seed)
    q = talos.standing()
    v = np.zeros(talos.nv)
    v[6:] = 0.3 * rng.standard_normal(talos.nv - 6)
    contact = LeggedContact(talos)
    v = contact.impact(q, v, tuple(talos.feet)).v  # the soles flat and still on the ground
    tau = np.zeros(talos.nv)
    tau[6:] = 20.0 * rng.standard_normal(talos.nv - 6)
    return q, v, tau


@pytest.mark.parametrize("seed", SEEDS)
def test_two_soles_as_corners_move_the_robot_as_pinocchios_6d_contacts(talos, seed):
    q, v, tau = _state(talos, seed)
    contact = LeggedContact(talos)
    feet = tuple(talos.feet)
    assert contact.redundant(feet)
    r = contact.stance(q, v, tau, feet)
    a6, wrenches, models = _six_d(talos, "LR", q, v, tau)
    np.testing.assert_allclose(r.a, a6, atol=1e-8)
    # the corners' resultant about each sole's centre is the 6D contact's wrench
    P = contact.positions(q)
    for k, side in enumerate("LR"):
        idx = [list(talos.feet).index(f) for f in _sole(talos, side)]
        f = r.forces[[feet.index(x) for x in _sole(talos, side)]]
        c = P[idx].mean(axis=0)
        np.testing.assert_allclose(f.sum(0), wrenches[k].linear, atol=1e-7)
        np.testing.assert_allclose(np.cross(P[idx] - c, f).sum(0), wrenches[k].angular, atol=1e-7)
    # the least-norm forces: nothing along the null space of J^T (scipy)
    J = contact.jacobian(q, feet)
    N = null_space(J.T)
    assert N.shape[1] == 12  # 24 rows of rank 12: two soles of four corners
    np.testing.assert_allclose(N.T @ r.forces.ravel(), 0.0, atol=1e-7)
    # the centroidal momentum's rate: m (a_com - g) and the moment of the forces about the COM
    m = talos.model
    data = m.createData()
    dh = pin.computeCentroidalMomentumTimeVariation(m, data, q, v, r.a)
    com = data.com[0]
    gvec = m.gravity.linear
    np.testing.assert_allclose(r.forces.sum(0), np.array(dh.linear) - talos.mass * gvec,
                               atol=1e-8)
    np.testing.assert_allclose(np.cross(P - com, r.forces).sum(0), np.array(dh.angular),
                               atol=1e-8)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_sole_landing_flat_is_pinocchios_6d_impact(talos, seed):
    """Both soles on the ground, moving down at the touchdown: the corners' impact gives the
    6D impact's velocities; the corners stop; momentum about the contacts is conserved to the
    impulses' moment, and kinetic energy is lost, never gained."""
    rng = np.random.default_rng(seed)
    q = talos.standing()
    v = 0.2 * rng.standard_normal(talos.nv)
    contact = LeggedContact(talos)
    feet = tuple(talos.feet)
    res = contact.impact(q, v, feet)
    v6, _, _ = _six_d(talos, "LR", q, v, impulse=True)
    np.testing.assert_allclose(res.v, v6, atol=1e-9)
    np.testing.assert_allclose(contact.jacobian(q, feet) @ res.v, 0.0, atol=1e-10)
    m = talos.model
    data = m.createData()
    h0 = pin.computeCentroidalMomentum(m, data, q, v)
    h1 = pin.computeCentroidalMomentum(m, data, q, res.v)
    P = contact.positions(q)
    com = data.com[0]
    np.testing.assert_allclose(np.array(h1.linear - h0.linear), res.impulses.sum(0), atol=1e-9)
    np.testing.assert_allclose(np.array(h1.angular - h0.angular),
                               np.cross(P - com, res.impulses).sum(0), atol=1e-9)
    assert res.energy_lost >= -1e-12


def test_a_wrench_spreads_over_the_corners_exactly_when_its_centre_of_pressure_is_inside():
    """A sole 0.2 m x 0.1 m: a vertical force of 100 N with its centre of pressure at (x, y)
    has a distribution over the corners that pushes (closed form: |x| <= 0.1, |y| <= 0.05);
    near a corner the least-norm one pulls (outside the diamond) but another exists."""
    corners = np.array([[0.1, 0.05, 0.0], [0.1, -0.05, 0.0], [-0.1, 0.05, 0.0],
                        [-0.1, -0.05, 0.0]])
    G = np.vstack([np.hstack([np.eye(3)] * 4),
                   np.hstack([pin.skew(c) for c in corners])])
    for x, y, ok in [(0.0, 0.0, True), (0.09, 0.045, True), (-0.099, 0.0, True),
                     (0.0, -0.049, True), (0.11, 0.0, False), (0.0, 0.06, False),
                     (0.095, 0.055, False)]:
        wrench = np.r_[0.0, 0.0, 100.0, 100.0 * y, -100.0 * x, 0.0]
        least = (np.linalg.pinv(G) @ wrench).reshape(4, 3)
        f = spread(corners, least, friction=0.7, floor=0.0)
        assert (f is not None) == ok, (x, y)
        if ok:
            assert np.all(f[:, 2] > 0)
            np.testing.assert_allclose(G @ f.ravel(), wrench, atol=1e-6)
    # near the corner (0.09, 0.045) the least-norm distribution pulls on the opposite corner
    least = (np.linalg.pinv(G) @ np.r_[0, 0, 100.0, 4.5, -9.0, 0]).reshape(4, 3)
    assert least[:, 2].min() < 0


def test_a_sideways_force_beyond_the_soles_friction_has_no_distribution():
    corners = np.array([[0.1, 0.05, 0.0], [0.1, -0.05, 0.0], [-0.1, 0.05, 0.0],
                        [-0.1, -0.05, 0.0]])
    f = np.tile([60.0, 0.0, 25.0], (4, 1))  # |f_t| / f_n = 2.4
    assert spread(corners, f, friction=0.7) is None
    f = np.tile([15.0, 0.0, 25.0], (4, 1))  # 0.6, inside the octagon inscribed in 0.7
    assert spread(corners, f, friction=0.7) is not None


@pytest.mark.parametrize("seed", range(3))
def test_talos_stands_on_its_soles_after_a_push_with_every_check_on(talos, seed):
    """Talos' legs (48.7 kg) on eight corner points, the allocation QP with the redundant
    stance, a random start and a 30 N push for 0.1 s: one second, every contact check on. (At
    the base's 1.02 m, 60 N is about the push that tips it over its outer sole's edge: 478 N
    of weight times 0.15 m against 61 N m; the controller does not know the push.)"""
    rng = np.random.default_rng(seed)
    q = talos.standing()
    gains = StandGains(height=(4000.0, 400.0), tilt=(1600.0, 80.0), yaw_rate=50.0,
                       joints=(600.0, 100.0))
    ctl = StandingController(talos, q, gains=gains, normal_force_min=5.0)
    log = stand(talos, ctl, q, v0=random_start(talos, rng, 0.2), duration=1.0,
                push=Push.random(rng, 1.0, 30.0))
    assert log.not_walking is None, log.not_walking
    assert log.stats.min_normal_force > 0.0
    assert max(np.abs(log.roll).max(), np.abs(log.pitch).max()) < 0.02
