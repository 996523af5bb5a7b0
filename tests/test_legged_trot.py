"""Solo-12's trot start (issue 32): the event-driven diagonal schedule, the landing velocity whose
impulse needs no friction, the impact over a short Moreau-Jean window, and a short trot in the
closed loop with every contact check on (the 20 s run is benchmarks/legged_trot.py).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.impact import unilateral_impact
from feltool.walking.legged.model import load_solo12
from feltool.walking.legged.stand import stand
from feltool.walking.legged.trot import PAIRS, TrotController, TrotGait

FEET = ("FL", "FR", "HL", "HR")


@pytest.fixture(scope="module")
def solo():
    return load_solo12(effort=2.7)


def test_the_pairs_switch_when_both_swing_feet_are_down():
    g = TrotGait(period=0.3, start=0.1, catch=0.5)
    assert set(g.schedule(0.05)) == set(FEET)  # standing before the start
    assert g.schedule(0.12) == PAIRS[0]  # (FR, HL) swings first, not wanted early
    assert set(g.schedule(0.1 + 0.076)) == set(FEET)  # from half its swing on: wanted back
    g.touchdown(0.2, ("HL",))
    assert g.swing == 1 and g.steps == 0  # one foot down: the old pair still stands
    g.touchdown(0.21, ("FR",))
    assert g.swing == 0 and g.steps == 1 and g.t_switch == 0.21
    assert g.schedule(0.22) == PAIRS[1]  # (FL, HR) released, swinging


@pytest.mark.parametrize("seed", range(5))
def test_landing_along_g_ez_needs_no_friction(solo, seed):
    """A foot reaching the ground with the controller's landing velocity (along G e_z, G = J
    M^-1 J^T) is stopped by a vertical impulse: ``pin.impulseDynamics`` on that foot, the
    robot's other joints at random rates that the foot does not feel."""
    rng = np.random.default_rng(seed)
    q = pin.integrate(solo.model, solo.standing(), 0.05 * rng.standard_normal(18))
    ctl = TrotController(solo, solo.standing())
    c = LeggedContact(solo)
    for i, foot in enumerate(FEET):
        d = ctl._landing_velocity(q, i)
        assert d[2] == pytest.approx(-ctl.gait.landing_speed)
        # a velocity giving the foot exactly d: the least-norm one through its Jacobian
        J = c.jacobian(q, (foot,))
        v = np.linalg.pinv(J) @ d
        imp = c.impact(q, v, (foot,)).impulses[0]
        assert imp[2] > 0 and np.hypot(imp[0], imp[1]) < 1e-9 * imp[2]


@pytest.mark.parametrize("seed", range(5))
def test_an_impact_over_a_window_is_one_moreau_jean_step(solo, seed):
    """With a window delta the impact is M (v+ - v- - delta a_free) = J^T P (a_free from
    ``pin.aba``, an independent reference) with the held feet stopped; delta -> 0 is the
    instantaneous impact."""
    rng = np.random.default_rng(seed)
    c = LeggedContact(solo)
    q = solo.standing(pin.integrate(solo.model, solo.standing(), 0.05 * rng.standard_normal(18)))
    v = 0.05 * rng.standard_normal(18)
    v[2] -= 0.3
    tau = np.r_[np.zeros(6), rng.uniform(-1.0, 1.0, 12)]
    delta = 1e-4
    r = unilateral_impact(c, q, v, FEET, friction=3.0, tau=tau, window=delta)
    M = pin.crba(solo.model, solo.data, q)
    M = np.triu(M) + np.triu(M, 1).T
    a_free = pin.aba(solo.model, solo.data, q, v, tau)
    J = c.jacobian(q, FEET)
    np.testing.assert_allclose(M @ (r.v - v - delta * a_free), J.T @ r.impulses.ravel(),
                               atol=1e-10)
    for foot in r.held:
        k = FEET.index(foot)
        np.testing.assert_allclose((J @ r.v)[3 * k:3 * k + 3], 0.0, atol=1e-10)
    r0 = unilateral_impact(c, q, v, FEET, friction=3.0)
    r9 = unilateral_impact(c, q, v, FEET, friction=3.0, tau=tau, window=1e-9)
    np.testing.assert_allclose(r9.v, r0.v, atol=1e-6)


def _trot(solo, duration, **gait):
    g = TrotGait(**gait)
    q0 = solo.standing()
    ctl = TrotController(solo, q0, gait=g)
    log = stand(solo, ctl, q0, duration=duration, schedule=g.schedule,
                on_touchdown=g.touchdown, impact_window=1e-4)
    return g, ctl, log


def test_solo12_trots_physically_for_its_first_steps(solo):
    """0.75 s at 1 kHz (speed ramped to 0.3 m/s in 0.3 s): every sub-step physical -- normal
    forces above 0, circular cones, the impulses pushing and in the cone, no foot below the
    ground, each released foot accelerating up -- the pairs alternating, every foot lifted
    above 2 cm, the base level within 0.05 rad and moving forward with the desired base."""
    g, ctl, log = _trot(solo, 0.75, ramp=0.3)
    assert log.not_walking is None, log.not_walking
    st = log.stats
    assert st.min_normal_force > 0.0 and st.max_friction_ratio < 0.7
    assert st.max_impulse_ratio < 0.7 and st.min_clearance > -1e-9 and st.max_torque < 2.7
    assert g.steps >= 4
    heights = np.array([solo.foot_positions(x)[:, 2] for x in log.q])
    assert (heights.max(0) > 0.02).all()
    pairs = [frozenset(p) for p in PAIRS]
    landed = [next(p for p in pairs if set(feet) <= p) for _, feet in log.touchdowns]
    firsts = [landed[k] for k in range(0, len(landed)) if k == 0 or landed[k] != landed[k - 1]]
    assert all(a != b for a, b in zip(firsts, firsts[1:]))
    assert np.abs(log.roll).max() < 0.05 and np.abs(log.pitch).max() < 0.05
    x_d = g.base_x(log.t[-1])[0]
    assert x_d > 0.1 and log.q[-1, 0] - log.q[0, 0] == pytest.approx(x_d, abs=0.02)
