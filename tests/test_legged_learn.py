"""Feedback error learning on the legged trot, the resumable legged loop and the trot's Poincaré
map (issue 32): the learned series against closed forms, the feedback's effective part and
motor share against the KKT accelerations, Newton's law for a payload put on during a rollout,
the reference acquired on the known model, FEL bringing a 20 % payload's feedback to 0.15 of
the change's cycle on seeds 0-2 (fixed before looking) and on MuJoCo, and the Poincaré map's
fixed point stable (rho < 0.9)."""

from __future__ import annotations

import copy

import numpy as np
import pinocchio as pin
import pytest

from feltool.errors import FeltoolError
from feltool.walking.legged.control import StandingController
from feltool.walking.legged.learn import PhaseFeedforward, learn_trot
from feltool.walking.legged.model import Payload, load_solo12, with_payload
from feltool.walking.legged.orbit import acquire_orbit
from feltool.walking.legged.poincare import (
    _coordinates,
    _run,
    perturbed,
    reach_section,
    section_tangent,
    trot_jacobian,
)
from feltool.walking.legged.stand import stand
from feltool.walking.legged.trot import TrotController, TrotGait


@pytest.fixture(scope="module")
def solo():
    return load_solo12(effort=2.7)


# -- the learned series -------------------------------------------------------------------------

def _signal(phi):
    """A series of degree 2 written out: mean 0.3, cos 0.5, sin2 -0.2 (two coordinates)."""
    return np.array([0.3 + 0.5 * np.cos(phi) - 0.2 * np.sin(2 * phi), -1.0 + 0.1 * np.cos(2 * phi)])


@pytest.mark.parametrize("rate", [1.0, 0.3])
def test_one_cycle_moves_rate_times_the_series_in_whatever_sampling(rate):
    rng = np.random.default_rng(0)
    for steps in (rng.uniform(0.5, 1.5, 300), np.ones(1000)):  # uneven and even steps
        t = np.concatenate([[0.0], np.cumsum(steps)])
        t = 2 * np.pi * t / t[-1]
        ff = PhaseFeedforward(2, 2, rate=rate)
        for a, b in zip(t[:-1], t[1:]):
            ff.observe(a, _signal(a), b - a)
        ff.update()
        want = rate * np.array([[0.3, -1.0], [0.5, 0.0], [0.0, 0.1], [0.0, 0.0], [-0.2, 0.0]])
        assert np.allclose(ff.C, want, atol=1e-10)
        assert np.allclose(ff(1.234), rate * _signal(1.234), atol=1e-10)


def test_the_mean_alone_is_the_time_average_and_the_rms_is_reported():
    ff = PhaseFeedforward(0, 1, rate=1.0)
    n = 4000
    for k in range(n):
        phi = 2 * np.pi * k / n
        ff.observe(phi, np.array([2.0 + 3.0 * np.sin(phi)]), 1.0 / n)
    rms = ff.update()
    assert ff.C[0, 0] == pytest.approx(2.0, abs=1e-10)  # (the Gram matrix gets a 1e-12 ridge)
    assert rms[0] == pytest.approx(np.sqrt(4.0 + 4.5), rel=1e-9)  # mean^2 + amplitude^2 / 2


@pytest.mark.parametrize("bad", [dict(rate=0.0), dict(rate=1.5), dict(harmonics=-1)])
def test_bad_learner_settings_are_refused(bad):
    args = dict(harmonics=1, nv=3) | bad
    with pytest.raises(FeltoolError, match="rate|harmonics"):
        PhaseFeedforward(**args)


# -- what the feedback does under the contacts --------------------------------------------------

def _constrained_a(solo, q, v, tau, feet):
    """The stance dynamics' accelerations by their KKT system on Pinocchio's M, b and the feet's
    frame Jacobians (an independent solve: no W, no projector)."""
    m = solo.model
    d = m.createData()
    pin.forwardKinematics(m, d, q, v, np.zeros(m.nv))
    pin.computeJointJacobians(m, d, q)
    pin.updateFramePlacements(m, d)
    J = np.vstack([pin.getFrameJacobian(m, d, solo.feet[f], pin.LOCAL_WORLD_ALIGNED)[:3]
                   for f in feet])
    gamma = np.concatenate([pin.getFrameClassicalAcceleration(
        m, d, solo.feet[f], pin.LOCAL_WORLD_ALIGNED).linear for f in feet])
    M = pin.crba(m, d, q)
    M = np.triu(M) + np.triu(M, 1).T
    b = pin.nonLinearEffects(m, d, q, v)
    n = len(J)
    K = np.block([[M, -J.T], [J, np.zeros((n, n))]])
    return np.linalg.solve(K, np.r_[tau - b, -gamma])[:m.nv]


@pytest.mark.parametrize("seed", range(3))
def test_the_effective_part_moves_the_robot_as_the_whole_and_the_ground_takes_the_rest(solo,
                                                                                       seed):
    rng = np.random.default_rng(seed)
    q = solo.standing()
    feet = ("FL", "HR")
    ctl = StandingController(solo, q)
    J = ctl.contact.jacobian(q, feet)
    v = np.linalg.svd(J)[2][len(J):].T @ rng.standard_normal(solo.nv - len(J)) * 0.3
    tau = rng.standard_normal(solo.nv)
    ctl.allocate(q, v, tau, feet)
    eff = ctl.effective(tau)
    assert np.allclose(_constrained_a(solo, q, v, eff, feet), _constrained_a(solo, q, v, tau, feet),
                       atol=1e-8)
    lam = rng.standard_normal(len(J))
    assert np.abs(ctl.effective(J.T @ lam)).max() < 1e-10 * np.abs(lam).max()
    # the motor share: the least-norm torques whose accelerations are nearest tau's in the
    # kinetic-energy metric, by least squares on the KKT accelerations of each motor alone
    B = solo.selection()
    a0 = _constrained_a(solo, q, v, np.zeros(solo.nv), feet)
    A = np.array([_constrained_a(solo, q, v, B[:, i], feet) - a0 for i in range(B.shape[1])]).T
    # two point feet cannot turn the robot about the line through them: 11 of 12 directions
    assert np.linalg.matrix_rank(A, tol=1e-8 * np.abs(A).max()) == 11
    M = pin.crba(solo.model, solo.model.createData(), q)
    L = np.linalg.cholesky(np.triu(M) + np.triu(M, 1).T).T
    u = np.linalg.lstsq(L @ A, L @ (_constrained_a(solo, q, v, tau, feet) - a0),
                        rcond=1e-9)[0]
    assert np.allclose(ctl.motor_share(tau), u, atol=1e-7 * np.abs(u).max())


# -- the loop: resumed, stopped at a touchdown, a world that changes ---------------------------

def _trot(solo):
    q0 = solo.standing()
    gait = TrotGait(speed=0.3, ramp=0.3)
    return q0, gait, TrotController(solo, q0, gait=gait)


def test_a_resumed_rollout_is_the_same_rollout(solo):
    q0, gait, ctl = _trot(solo)
    kw = dict(impact_window=1e-4)
    c1 = copy.deepcopy(ctl)
    whole = stand(solo, c1, q0, duration=0.6, schedule=c1.gait.schedule,
                  on_touchdown=c1.gait.touchdown, **kw)
    c2 = copy.deepcopy(ctl)
    g2 = c2.gait
    first = stand(solo, c2, q0, duration=0.35, schedule=g2.schedule, on_touchdown=g2.touchdown,
                  **kw)
    rest = stand(solo, c2, None, start=first.end, duration=0.25, schedule=g2.schedule,
                 on_touchdown=g2.touchdown, **kw)
    assert whole.not_walking is None and rest.not_walking is None
    assert len(first.touchdowns) > 0 and len(rest.touchdowns) > 0
    # (the resumed clock is t_start + i dt, the whole one's i dt: they differ by rounding)
    assert np.abs(rest.end.q - whole.end.q).max() < 1e-10
    assert np.abs(rest.end.v - whole.end.v).max() < 1e-8


def test_until_touchdown_stops_just_after_the_impact_with_every_foot_down_and_stopped(solo):
    q0, gait, ctl = _trot(solo)
    g = ctl.gait
    log = stand(solo, ctl, q0, duration=3.0, impact_window=1e-4, schedule=g.schedule,
                on_touchdown=g.touchdown, until_touchdown=lambda t: g.steps >= 4)
    end = log.end
    assert g.steps == 4 and end.t == pytest.approx(log.touchdowns[-1][0], abs=1e-3)
    assert set(end.stance) == set(solo.feet)
    P, V = ctl.contact.foot_states(end.q, end.v)
    # the feet stopped at the impact; the configuration then moved over the 0.1 ms window,
    # which turns the feet's Jacobian by about |v|^2 / r * 1e-4 s
    assert np.abs(P[:, 2]).max() < 1e-8 and np.abs(V).max() < 1e-4


def test_a_payload_put_on_during_the_rollout_is_carried_by_the_feet(solo):
    """Newton: standing still after the payload is put on, the feet carry (m + m_p) g."""
    q0 = solo.standing()
    load = Payload(0.5, (0.03, -0.02, 0.01))
    heavy = with_payload(solo, load).model
    ctl = StandingController(solo, q0)
    log = stand(solo, ctl, q0, duration=2.0, plant=lambda t: heavy if t >= 0.5 else None)
    assert log.not_walking is None
    g = -solo.model.gravity.linear[2]
    before = np.nansum(log.forces[490, :, 2])
    after = np.nansum(log.forces[-1, :, 2])
    assert before == pytest.approx(solo.mass * g, rel=1e-3)
    assert after == pytest.approx((solo.mass + load.mass) * g, rel=1e-3)
    assert log.height[-1] < log.height[490] - 1e-3  # it sags under the unknown load


def test_a_payload_adds_its_mass_and_moves_the_com(solo):
    load = Payload(0.7, (0.05, 0.01, -0.02))
    heavy = with_payload(solo, load)
    q = solo.standing()
    m, c = solo.mass, pin.centerOfMass(solo.model, solo.data, q).copy()
    base = pin.XYZQUATToSE3(q[:7])
    want = (m * c + load.mass * base.act(np.array(load.offset))) / (m + load.mass)
    assert heavy.mass == pytest.approx(m + load.mass, rel=1e-14)
    assert np.allclose(pin.centerOfMass(heavy.model, heavy.data, q), want, atol=1e-12)


# -- the reference acquired on the known model, FEL with an unknown payload, seeds 0-2 ---------

@pytest.fixture(scope="module")
def acquired(solo):
    return acquire_orbit(solo, rounds=4)


def test_the_acquired_reference_leaves_a_third_of_the_plans_feedback(acquired):
    fb = acquired.feedback
    assert len(fb) == 5 and acquired.correction is not None
    assert np.all(np.diff(fb) < 0)          # every round lowers it
    assert fb[-1] < 0.35 * fb[0]            # 0.130 -> 0.027 N m measured


@pytest.mark.parametrize("seed", range(3))
def test_fel_takes_a_payloads_feedback_away(solo, acquired, seed):
    """20 % of the mass from cycle 3: FEL brings the last of 12 cycles to at most 0.15 of the
    payload's cycle (the issue's bound, with 150 cycles), and it falls every cycle to cycle 8;
    without learning (seed 0) the feedback stays above 3 times the cycle before the change."""
    seen = []
    on = learn_trot(solo, cycles=12, seed=seed, correction=acquired.correction,
                    on_cycle=lambda *cycle: seen.append(cycle))
    assert on.kind is None and len(on.feedback) == 12
    _check_cycles_handed_on(seen, on)
    assert on.speed == pytest.approx(0.3, abs=0.01)
    assert on.feedback[3] > 3.0 * on.feedback[2]       # the payload's cycle
    assert on.feedback[-1] < 0.15 * on.feedback[3]     # 0.083 measured on seed 0
    assert np.all(np.diff(on.feedback[3:9]) < 0)
    if seed == 0:
        off = learn_trot(solo, cycles=12, seed=seed, learn=False, correction=acquired.correction)
        assert off.kind is None and off.feedback[-1] > 3.0 * off.feedback[2]


def test_fel_takes_a_payloads_feedback_away_on_mujoco(solo, acquired):
    """The reference acquired on the rigid known model, MuJoCo's soft contacts as the plant."""
    seen = []
    on = learn_trot(solo, cycles=12, seed=0, plant="mujoco", correction=acquired.correction,
                    on_cycle=lambda *cycle: seen.append(cycle))
    assert on.kind is None and len(on.feedback) == 12
    _check_cycles_handed_on(seen, on)
    assert on.feedback[3] > 3.0 * on.feedback[2]
    assert on.feedback[-1] < 0.15 * on.feedback[3]


def _check_cycles_handed_on(seen: list, run) -> None:
    """The live viewer's hook got every cycle once, in order, with the summed feedback the run
    reports and every control update from the cycle's first touchdown to the next cycle's: the
    rollout log's steps (their configurations the log's own) and the few updates touchdowns
    triggered between them."""
    times = np.array(run.controller.cycle_times)
    assert [c[0] for c in seen] == list(range(len(run.feedback)))
    handed = {}
    for cycle, t, q, q_d, fb in seen:
        assert fb == run.feedback[cycle]
        assert t[0] == times[cycle, 0]  # it began at a touchdown's update
        assert len(t) < 1.05 * (times[cycle, 1] - times[cycle, 0]) * 1000  # 1 kHz
        assert q_d.shape == q.shape and np.abs(q_d[:, 7:] - q[:, 7:]).max() < 0.3
        for tk, qk in zip(t, q, strict=True):
            handed.setdefault(tk, []).append(qk)
    logged = (run.log.t >= times[0, 0]) & (run.log.t < times[-1, 1] - 1e-3)
    assert logged.sum() > 0.95 * (times[-1, 1] - times[0, 0]) * 1000
    for tk, qk in zip(run.log.t[logged], run.log.q[logged], strict=True):
        assert any(np.array_equal(qk, x) for x in handed[tk]), tk


def test_an_unknown_plant_is_refused(solo):
    with pytest.raises(FeltoolError, match="plant 'gazebo'"):
        learn_trot(solo, cycles=1, plant="gazebo")


# -- the Poincaré map ---------------------------------------------------------------------------

def test_perturbed_section_states_keep_every_foot_down_and_stopped(solo):
    q0, gait, ctl = _trot(solo)
    ref = reach_section(solo, ctl, q0, 4)
    T = section_tangent(solo, ref)
    assert T.shape == (2 * solo.nv, 2 * solo.nv - 4 - 12)
    assert np.allclose(T.T @ T, np.eye(T.shape[1]), atol=1e-12)
    rng = np.random.default_rng(1)
    sec = perturbed(solo, ref, 3e-3 * T @ rng.standard_normal(T.shape[1]))
    P, V = ctl.contact.foot_states(sec.state.q, sec.state.v)
    P0 = ctl.contact.positions(ref.state.q)
    assert np.abs(P[:, 2] - P0[:, 2]).max() < 1e-12 and np.abs(V).max() < 1e-10
    assert np.abs(P[:, :2] - P0[:, :2]).max() > 1e-4  # and the feet did move


def test_the_trots_fixed_point_is_stable_and_the_jacobian_predicts_a_perturbation(solo,
                                                                                  acquired):
    """The trot FEL runs on (its reference acquired): rho 0.76 measured after 20 cycles."""
    gait = TrotGait()
    q0 = solo.standing()
    ctl = TrotController(solo, q0, gait=gait, correction=acquired.correction)
    res = trot_jacobian(solo, gait, cycles=12, eps=(2e-3,), controller=ctl)
    assert res.rho < 0.9
    # the linear map predicts a random perturbation off the basis directions
    ref = reach_section(solo, ctl, q0, 12)
    T = section_tangent(solo, ref)
    rng = np.random.default_rng(7)
    d = T @ rng.standard_normal(T.shape[1])
    d *= 2e-3 / np.linalg.norm(d)
    nxt = 2 * 13
    plus = _coordinates(solo, ref, _run(solo, perturbed(solo, ref, d), nxt, 1e-4))
    minus = _coordinates(solo, ref, _run(solo, perturbed(solo, ref, -d), nxt, 1e-4))
    got = T.T @ (plus - minus) / 2
    want = res.jacobian @ (T.T @ d)
    assert np.linalg.norm(got - want) < 0.2 * np.linalg.norm(want)
