"""A 3D biped's walk (issue 32, acceptance 2): Talos' legs from example-robot-data on two soles
of four corners. The sway against the linear inverted pendulum's equation (finite differences)
and its orbit's closed form; the contact events of soles (a released sole that would press stays
down, a sole whose centre of pressure leaves it tips onto an edge, a sole landing within 1 mm of
flat lands whole); Talos walking 20 steps with every contact check on.
"""

from __future__ import annotations

import numpy as np
import pytest

from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.control import StandingController
from feltool.walking.legged.events import FLAT_TOL, flat_landing, lingering, tipping
from feltool.walking.legged.model import load_talos_legs
from feltool.walking.legged.stand import random_start, stand
from feltool.walking.legged.walk import IMPACT_WINDOW, WalkGait, biped_controller, biped_walk


@pytest.fixture(scope="module")
def talos():
    return load_talos_legs()


def _soles(talos):
    names = list(talos.feet)
    return (tuple(f for f in names if f.startswith("L_")),
            tuple(f for f in names if f.startswith("R_")))


def test_the_sway_is_the_inverted_pendulums_orbit():
    """On the orbit, y'' = w^2 (y - p) with the centre of pressure p at the stance sole's
    middle (finite differences of the gait's own offset, against the pendulum's equation); the
    offset and rate are continuous at the start and through the weight shift; at the planned
    touchdown the base is back on the midline with the rate the next step starts with."""
    g = WalkGait(omega=4.0, half_width=0.085, start=1.5, shift=0.8, period=1.2, sway=1.0)
    T = g.land * g.period / 2
    h = 1e-4
    for tau in np.linspace(0.02, T - 0.02, 9):
        t = g.start + tau
        y = g.lateral(t)[0]
        acc = (g.lateral(t + h)[0] - 2 * y + g.lateral(t - h)[0]) / h ** 2
        assert acc == pytest.approx(4.0 ** 2 * (y - 0.085), abs=1e-5)
        rate = (g.lateral(t + h)[0] - g.lateral(t - h)[0]) / (2 * h)
        assert g.lateral(t)[1] == pytest.approx(rate, abs=1e-7)
    for t in (g.start, g.start - T / 2, g.start - T / 2 - g.shift):
        for k in (0, 1):
            assert g.lateral(t - 1e-9)[k] == pytest.approx(g.lateral(t + 1e-9)[k], abs=1e-6)
    y, dy = g.lateral(g.start + T)
    assert y == pytest.approx(0.0, abs=1e-12)
    # the closed form: |y'| = p w tanh(w T / 2) at the midline
    assert dy == pytest.approx(-0.085 * 4.0 * np.tanh(4.0 * T / 2), rel=1e-9)


@pytest.mark.parametrize("early", [-0.03, 0.0, 0.02])
def test_an_early_or_late_switch_is_steered_back_onto_the_orbit(early):
    """A switch ``early`` [s] off the planned touchdown: the next step starts where the last one
    is (continuous) and its centre of pressure brings xi = y + y'/w to the orbit's value at its
    planned end (closed form)."""
    g = WalkGait(omega=4.0, half_width=0.085, start=1.5, shift=0.8, period=1.2)
    T = g.land * g.period / 2
    g.swing, g.t_switch = 1, g.start  # the right sole steps first; the left one stands
    t = g.start + T + early
    before = g.lateral(t)
    g.down = set(g.groups[1])
    g.touchdown(t, ())  # the swinging group down: the switch
    assert g.swing == 0 and g.steps == 1
    np.testing.assert_allclose(g.lateral(t), before, atol=1e-12)
    y, dy = g.lateral(t + T)
    assert y + dy / 4.0 == pytest.approx(0.085 * np.tanh(4.0 * T / 2), abs=1e-9)


def test_a_released_sole_that_would_press_stays_down_until_it_lifts(talos):
    """Both soles down, the left released: with no torques the robot sags and the left sole
    would accelerate into the ground, so it stays (its contact pushes); with the right sole
    alone able to hold the robot and the left leg lifted hard, it leaves."""
    q = talos.standing()
    v = np.zeros(talos.nv)
    left, right = _soles(talos)
    contact = LeggedContact(talos)
    assert set(lingering(contact, q, v, np.zeros(talos.nv), right, left)) == set(left)
    tau = np.zeros(talos.nv)
    # hold the robot on its right sole (gravity compensation through it) and pull the left
    # knee up: the left corners accelerate up
    ctl = StandingController(talos, q, normal_force_min=5.0)
    u = ctl(q, v, right).u
    tau[6:] = u
    i = talos.leg(left[0])
    tau[i[3]] += 40.0  # knee
    tau[i[2]] -= 40.0  # hip pitch
    assert lingering(contact, q, v, tau, right, left) == ()


def test_a_sole_whose_pressure_leaves_it_tips_onto_an_edge(talos):
    """On the right sole alone with a roll torque at the ankle: none, the sole keeps its four
    corners; large enough that the centre of pressure would leave the sole, the corners on one
    side lift (what stays is an edge), and the result holds with pushing forces."""
    q = talos.standing()
    v = np.zeros(talos.nv)
    _, right = _soles(talos)
    contact = LeggedContact(talos)
    ctl = StandingController(talos, q, normal_force_min=5.0)
    tau = np.zeros(talos.nv)
    tau[6:] = ctl(q, v, right).u
    assert tipping(contact, q, v, tau, right) == right
    push = tau.copy()
    push[talos.leg(right[0])[-1]] += 100.0  # the ankle's roll [N m]: the sole holds ~31 N m
    kept = tipping(contact, q, v, push, right)
    assert 0 < len(kept) < 4
    forces = contact.stance(q, v, push, kept).forces
    assert np.all(forces[:, 2] > 0.0)


def test_a_sole_landing_within_a_millimetre_of_flat_lands_whole(talos):
    """The first corner of a sole in the air touching: the sole's other corners within
    FLAT_TOL of the ground and moving down land with it; one above it does not."""
    q = talos.standing()
    left, right = _soles(talos)
    contact = LeggedContact(talos)
    names = list(talos.feet)
    vel = np.zeros((len(names), 3))
    vel[:, 2] = -0.05
    z = contact.positions(q)[:, 2]
    assert np.abs(z).max() < 1e-9
    assert set(flat_landing(contact, q, vel, (right[0],), list(right), left)) == set(right[1:])
    vel[names.index(right[1]), 2] = 0.01  # moving up: not landing
    assert right[1] not in flat_landing(contact, q, vel, (right[0],), list(right), left)
    # a corner 2 mm up (the sole tilted about its inner edge): it lands on its own later
    q2 = q.copy()
    i = talos.leg(right[0])
    q2[7 + i[-1] - 6] += 2.2 * FLAT_TOL / 0.13
    zr = contact.positions(q2)[[names.index(f) for f in right], 2]
    high = [f for f, h in zip(right, zr - zr.min()) if h > FLAT_TOL]
    assert high
    low = right[int(np.argmin(zr))]
    vel[:, 2] = -0.05
    got = flat_landing(contact, q2, vel, (low,), list(right), left)
    assert not set(high) & set(got)


def test_talos_walks_twenty_steps_with_every_contact_check_on(talos):
    """Seed 0 (a random start velocity, projected onto the soles): 20 steps at 0.15 m/s, every
    contact check on (each sole's wrench inside its corners' friction cones, impulses pushing
    and in their cones, no corner below the ground, released soles leaving within 50 ms, the
    URDF's motor limits), the base level within 0.05 rad. (10 seeds with a push:
    benchmarks/legged_walk.py, docs/legged.md.)"""
    q = talos.standing()
    left, right = _soles(talos)
    gait = biped_walk(talos, q, left, right, speed=0.15)
    ctl = biped_controller(talos, q, gait)
    rng = np.random.default_rng(0)
    log = stand(talos, ctl, q, v0=random_start(talos, rng, 0.2), duration=13.0,
                schedule=gait.schedule, on_touchdown=gait.touchdown,
                impact_window=IMPACT_WINDOW, until=lambda t: gait.steps >= 20)
    assert log.not_walking is None, log.not_walking
    assert gait.steps >= 20
    assert max(np.abs(log.roll).max(), np.abs(log.pitch).max()) < 0.05
    assert log.stats.min_normal_force > 0.0 and log.stats.max_torque <= talos.effort.max()
    half = log.t >= log.t[-1] / 2
    assert (log.q[half, 0][-1] - log.q[half, 0][0]) / (log.t[half][-1] - log.t[half][0]) > 0.1
