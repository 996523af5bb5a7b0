"""The learner: exact sensitivities against the thesis's numerical differentiation, and
shortened standard-arm runs that must show learning (a broken learner fails these)."""

from __future__ import annotations

import numpy as np

from feltool.learning.fel import feedforward
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS

STANDARD = CONFIGS / "two_link_standard.yaml"


def test_exact_jacobian_matches_finite_differences():
    exact = load_experiment(STANDARD)
    fd = load_experiment(STANDARD, ["learning.sensitivity=finite_difference",
                                    "learning.fd_epsilon=1e-5"])
    theta = exact.initial_parameters(3)
    Qd, Vd, Ad = exact.primitives.desired(theta)
    J = exact.learner.jacobian(exact.dynamics, theta, Qd, Vd, Ad)
    J_fd = fd.learner.jacobian(fd.dynamics, theta, Qd, Vd, Ad)
    assert J.shape == (exact.primitives.n_steps, 2, 11)
    np.testing.assert_allclose(J, J_fd, atol=1e-5 * np.abs(J).max())
    # The goal column is not trivially zero: gravity and the attractor make u_ff depend on it.
    assert np.abs(J[:, 1, -1]).max() > 1.0


def test_only_stabilizing_feedback_is_the_error_signal():
    exp = load_experiment(STANDARD)
    assert exp.error_joints == ["elbow"]
    U = np.array([[5.0, 2.0], [-1.0, 3.0]])
    np.testing.assert_array_equal(exp.learner.error(U), [[0.0, 2.0], [0.0, 3.0]])


def test_update_follows_eq_3_6():
    """One gradient update is rates * sum_k J_k^T e_k on the learned parameters only."""
    exp = load_experiment(STANDARD, ["learning.update=gradient"])
    theta = exp.initial_parameters(0)
    n = exp.primitives.n_steps
    rng = np.random.default_rng(0)
    J = rng.normal(size=(n, 2, exp.learner.n_learned))
    U = rng.normal(size=(n, 2))
    new = exp.learner.step(theta, J, exp.learner.error(U))
    expected = theta.copy()
    expected[exp.learner.learned] += exp.learner.rates * np.einsum("k,kp->p", U[:, 1], J[:, 1])
    np.testing.assert_allclose(new, expected)
    assert np.array_equal(new[: exp.learner.learned[0]], theta[: exp.learner.learned[0]])


def test_random_start_is_reproducible_and_seed_dependent():
    exp = load_experiment(STANDARD)
    a, b, c = exp.initial_parameters(7), exp.initial_parameters(7), exp.initial_parameters(8)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    goal = a[exp.learner.learned[-1]]
    assert abs(goal - 0.0) <= 0.3  # centred on q2 = pi/2 - goal(q1) = 0


def test_shortened_standard_arm_run_learns():
    """CI's proof of learning: 60 cycles cut the stabilizing feedback by far more than 10x."""
    exp = load_experiment(STANDARD)
    for seed in (0, 1):
        res = run_seed(exp, seed, cycles=60)
        fb = [r["fb_abs_mean_stabilized"] for r in res.rows]
        assert not res.summary["diverged"]
        assert fb[-1] < fb[0] / 10.0, (seed, fb[0], fb[-1])
        # and the learned forward trajectory approaches the system's
        assert res.rows[-1]["track_err_rms_elbow"] < res.rows[0]["track_err_rms_elbow"] / 3.0


def test_learned_feedforward_alone_nearly_balances_the_arm():
    """After learning, u_ff(q_d) alone is close to the torque the closed loop applies."""
    exp = load_experiment(STANDARD)
    res = run_seed(exp, 0, cycles=100)
    theta = exp.theta_demo.copy()
    for key, value in res.params.items():
        if key == "elbow.weights":
            sl = exp.primitives.slices[1]
            theta[sl.start:sl.stop - 1] = value
        elif key == "elbow.goal":
            theta[exp.primitives.slices[1].stop - 1] = value
    u_ff = feedforward(exp.dynamics, *exp.primitives.desired(theta))
    fb = np.abs(res.traces["last_u_fb"][:, 1]).mean()
    assert fb < 0.01 * np.abs(u_ff[:, 1]).mean()


def test_gauss_newton_converges_faster_than_gradient():
    grad = load_experiment(STANDARD, ["learning.update=gradient"])
    gn = load_experiment(STANDARD, ["learning.update=gauss_newton", "learning.rates.gauss_newton=1.0"])
    for seed in (0, 4):
        c_grad = run_seed(grad, seed, 80).summary["converged_cycle"]
        c_gn = run_seed(gn, seed, 30).summary["converged_cycle"]
        assert c_gn is not None and c_gn <= 20
        assert c_grad is None or c_gn < c_grad


def test_exact_sensitivity_learns_at_least_as_fast_as_finite_difference():
    exact = load_experiment(STANDARD)
    fd = load_experiment(STANDARD, ["learning.sensitivity=finite_difference"])
    a, b = run_seed(exact, 2, 40), run_seed(fd, 2, 40)
    fa = [r["fb_abs_mean_error"] for r in a.rows]
    fb = [r["fb_abs_mean_error"] for r in b.rows]
    assert fa[-1] <= fb[-1] * 1.01
    np.testing.assert_allclose(fa, fb, rtol=1e-3)  # same method, different derivatives


def test_per_step_update_also_learns():
    """Per-step updates (no reset of the RMP; sensitivities propagated step by step) learn too,
    more slowly per unit of rate than per-cycle updates."""
    exp = load_experiment(STANDARD, ["learning.step=per_step", "learning.update=gradient",
                                     "learning.rates.weights=16.844", "learning.rates.goal=1e-4"])
    res = run_seed(exp, 0, cycles=60)
    fb = [r["fb_abs_mean_error"] for r in res.rows]
    assert not res.summary["diverged"]
    assert fb[-1] < fb[0] / 5.0
