"""Learning rates in physical units and the safeguard (issue 29): one `learning.rates` means the
same step at any control rate and basis size, and a step that throws a seed away is undone."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import i0e

from feltool.engines.outcome import CycleOutcome, SeedState
from feltool.learning.rates import basis_gain, samples_per_cycle, translate
from feltool.runs.experiments import load_experiment
from feltool.runs.safeguard import Safeguard
from feltool.runs.seed import run_seed

from .conftest import CONFIGS

STANDARD = CONFIGS / "two_link_standard.yaml"
SEEDS = range(5)  # fixed before looking


@pytest.mark.parametrize("n_basis", [3, 10, 37])
def test_basis_gain_is_the_closed_form_of_the_von_mises_sum(n_basis):
    """mean_phi (sum_i psi_i)^2 = sum_ij mean_phi psi_i psi_j, and the product of two von
    Mises functions with centres c_i, c_j is exp(2h cos((c_i - c_j)/2) cos(phi - mid) - 2h),
    whose mean over the phase is exp(-2h) I0(2h cos((c_i - c_j)/2)) (scipy's Bessel)."""
    h = n_basis / 2.0
    c = 2.0 * np.pi * np.arange(n_basis) / n_basis
    a = 2.0 * h * np.abs(np.cos((c[:, None] - c[None, :]) / 2.0))
    expected = float(np.sum(i0e(a) * np.exp(a - 2.0 * h)))
    assert basis_gain(n_basis, h) == pytest.approx(expected, rel=1e-10)
    assert basis_gain(n_basis, h, amplitude=2.0) == pytest.approx(4.0 * expected, rel=1e-10)


@pytest.mark.parametrize("over", [[], ["sim.rate_hz=1000"], ["primitives.basis=25"],
                                  ["period_s=1.2345", "sim.rate_hz=400"]])
def test_the_sums_get_the_rates_divided_by_the_samples_and_the_basis_gain(over):
    exp = load_experiment(STANDARD, ["learning.update=gradient", *over])
    cfg = exp.config
    n = samples_per_cycle(cfg.period_s, cfg.sim.rate_hz)
    prim = exp.primitives.primitives[1]
    kappa = basis_gain(prim.n_basis, prim.width, prim.amplitude)
    rates = exp.learner.rates
    np.testing.assert_allclose(rates[~exp.learner.is_goal] * n * kappa, cfg.learning.rates.weights,
                               rtol=1e-12)
    np.testing.assert_allclose(rates[exp.learner.is_goal] * n, cfg.learning.rates.goal, rtol=1e-12)
    gn = load_experiment(STANDARD, ["learning.update=gauss_newton", *over])
    np.testing.assert_allclose(gn.learner.rates[~gn.learner.is_goal],
                               gn.config.learning.rates.gauss_newton)


def test_the_translation_keeps_the_thesis_rates():
    """configs/two_link_standard.yaml's gradient rates are the thesis's per-sample 0.2, 2e-5
    at 100 Hz, 1 s, 10 basis functions (translated once, 5 significant digits)."""
    exp = load_experiment(STANDARD, ["learning.update=gradient"])
    L = exp.config.learning.rates
    w, g = translate(0.2, 2.0e-5, 1.0, 100.0, 10)
    assert L.weights == pytest.approx(w, rel=1e-4) and L.goal == pytest.approx(g, rel=1e-12)
    assert exp.learner.rates[~exp.learner.is_goal] == pytest.approx(0.2, rel=1e-4)
    assert exp.learner.rates[exp.learner.is_goal] == pytest.approx(2.0e-5, rel=1e-12)


def test_one_gradient_step_is_the_same_at_100_hz_and_at_1_khz():
    """The first update from the same initial parameters: the mean over the cycle, not the
    sum, so ten times the samples is not ten times the step (it was, before issue 29)."""
    steps = []
    for hz in (100, 1000):
        exp = load_experiment(STANDARD, ["learning.update=gradient", f"sim.rate_hz={hz}",
                                         "learning.safeguard=false"])
        res = run_seed(exp, 0, 1)
        theta0 = exp.initial_parameters(0)[exp.learner.learned]
        steps.append(res.params["elbow.weights_history"][1] - theta0[:-1])
    rel = np.linalg.norm(steps[1] - steps[0]) / np.linalg.norm(steps[0])
    assert rel < 0.05, rel  # (the simulations differ by their sampling: a few per cent)


@pytest.mark.parametrize("update,cycles", [("gauss_newton", 30), ("gradient", 70)])
def test_the_arm_learns_the_same_curve_at_100_hz_and_at_1_khz(update, cycles):
    """Acceptance 3: cycles-to-5 % within +-2 cycles, every one of seeds 0-4."""
    curves = {}
    for hz in (100, 1000):
        exp = load_experiment(STANDARD, [f"learning.update={update}", f"sim.rate_hz={hz}"])
        curves[hz] = [run_seed(exp, s, cycles).summary["converged_cycle"] for s in SEEDS]
    assert None not in curves[100] and None not in curves[1000], curves
    assert all(abs(a - b) <= 2 for a, b in zip(curves[100], curves[1000])), curves


def test_a_huge_rate_is_caught_by_the_safeguard_and_the_seed_still_converges():
    """Acceptance 3: the Gauss-Newton step x100 throws every seed away without the safeguard;
    with it (default) the steps are undone and halved, counted, and every seed converges."""
    huge = ["learning.rates.gauss_newton=100"]
    plain = load_experiment(STANDARD, huge + ["learning.safeguard=false"])
    guarded = load_experiment(STANDARD, huge)
    for seed in SEEDS:
        assert run_seed(plain, seed, 5).summary["diverged"]
        res = run_seed(guarded, seed, 60)
        s = res.summary
        assert not s["diverged"] and s["converged_cycle"] is not None, s
        assert s["rejected_steps"] >= 3 and s["step_scale"] <= 0.125
        assert sum(r["rejected"] for r in res.rows) == s["rejected_steps"]
        assert res.rows[-1]["step_scale"] == s["step_scale"]


def test_the_safeguard_runs_the_same_on_both_engines():
    rows = {}
    for backend in ("pinocchio", "compiled"):
        exp = load_experiment(STANDARD, ["learning.rates.gauss_newton=100", f"backend={backend}"])
        rows[backend] = run_seed(exp, 1, 12).rows
    assert [r["rejected"] for r in rows["pinocchio"]] == [r["rejected"] for r in rows["compiled"]]
    assert sum(r["rejected"] for r in rows["compiled"]) >= 3
    a = np.array([r["fb_abs_mean_error"] for r in rows["pinocchio"]])
    b = np.array([r["fb_abs_mean_error"] for r in rows["compiled"]])
    np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], rtol=1e-6)


def _outcome(theta_next, fb, q):
    return CycleOutcome(theta_next, q + 1.0, q + 2.0, np.zeros(2), np.zeros(2), 0.0, 0.0, True,
                        lambda: None, fb, fb)


def test_a_rejected_step_restores_the_parameters_and_halves_the_step():
    exp = load_experiment(STANDARD)
    rates0 = exp.learner.rates.copy()
    guard = Safeguard(exp)
    guard.start()
    try:
        theta0 = exp.initial_parameters(0)
        q0 = np.array([0.1, 0.2])
        s0 = SeedState(theta0, q0, q0, None)
        step = np.zeros_like(theta0)
        step[exp.learner.learned] = 0.3
        nxt, rejected, reason = guard.judge(1, _outcome(theta0 + step, 10.0, q0), s0, None)
        assert not rejected and reason is None and nxt.theta is not None
        np.testing.assert_allclose(nxt.theta, theta0 + step)
        # the step made the next cycle's feedback 5x: undone, half of it taken from the same
        # parameters and state the first cycle started from
        nxt2, rejected, reason = guard.judge(2, _outcome(nxt.theta + step, 50.0, nxt.q), nxt, None)
        assert rejected and reason is None
        np.testing.assert_allclose(nxt2.theta, theta0 + 0.5 * step)
        np.testing.assert_array_equal(nxt2.q, q0)
        assert guard.scale == 0.5 and guard.rejected == 1
        np.testing.assert_allclose(exp.learner.rates, 0.5 * rates0, rtol=1e-15)
        # a cycle that diverges is undone too; below safeguard_min_step the seed diverges
        for k in range(20):
            nxt2, rejected, reason = guard.judge(3 + k, _outcome(nxt2.theta, 1e3, q0), nxt2,
                                                 "the robot fell")
            if reason:
                break
        assert "learning.safeguard_min_step" in reason and "the robot fell" in reason
        assert guard.scale < exp.config.learning.safeguard_min_step <= 2 * guard.scale
    finally:
        guard.finish()
    np.testing.assert_allclose(exp.learner.rates, rates0, rtol=1e-15)


def test_a_seed_resumed_amid_rejected_steps_continues_bit_identically(tmp_path):
    """The safeguard's state (step scale, the step it would undo) is in the checkpoint: a seed
    stopped after cycle 4, in the middle of its undone steps, and continued to cycle 14 gives
    the rows of the uninterrupted seed."""
    from feltool.runs.checkpoint import Checkpointer

    exp = load_experiment(STANDARD, ["learning.rates.gauss_newton=100"])
    whole = run_seed(exp, 2, 14)
    run_seed(exp, 2, 4, checkpoint=Checkpointer(tmp_path, 2, every=2))
    resumed = run_seed(exp, 2, 14, checkpoint=Checkpointer(tmp_path, 2, every=2))
    assert sum(r["rejected"] for r in whole.rows[:4]) >= 2
    assert sum(r["rejected"] for r in whole.rows[4:]) >= 1
    assert [r.keys() for r in resumed.rows] == [r.keys() for r in whole.rows]
    np.testing.assert_array_equal([list(r.values()) for r in resumed.rows],
                                  [list(r.values()) for r in whole.rows])  # (NaN == NaN here)
    assert resumed.summary["rejected_steps"] == whole.summary["rejected_steps"]


def _start_trajectory(exp, seed):
    """The learned joint's (the elbow's) start: its forward trajectory on the nominal cycle
    [rad] and its goal [rad]."""
    i = exp.joints.index("elbow")
    sl = exp.primitives.slices[i]
    theta = exp.initial_parameters(seed)[sl]
    return exp.primitives.primitives[i].periodic(theta).q, theta[-1]


def test_init_basis_keeps_the_shipped_draw_at_the_shipped_basis():
    """``learn.init_basis: 10`` at basis 10 is the draw of the thesis's configs, bit for bit
    (their numbers and goldens do not move)."""
    own = load_experiment(STANDARD, ["joints.elbow.learn.init_basis=null"])
    ten = load_experiment(STANDARD)
    assert ten.config.joints["elbow"].learn.init_basis == 10
    for seed in SEEDS:
        assert np.array_equal(own.initial_parameters(seed), ten.initial_parameters(seed))


@pytest.mark.parametrize("n_basis", [20, 40, 80])
def test_the_random_start_is_one_trajectory_at_any_basis_size(n_basis):
    """With init_basis the basis size changes the basis, not the task: the start's forward
    trajectory is the shipped one (to the fit of eq. 2.4); drawn per basis function (init_basis
    null) it is another motion, with less amplitude (issue 29's basis axis)."""
    ship = load_experiment(STANDARD)
    same = load_experiment(STANDARD, [f"primitives.basis={n_basis}"])
    own = load_experiment(STANDARD, [f"primitives.basis={n_basis}",
                                     "joints.elbow.learn.init_basis=null"])
    for seed in SEEDS:
        q0, g0 = _start_trajectory(ship, seed)
        q1, g1 = _start_trajectory(same, seed)
        q2, _ = _start_trajectory(own, seed)
        assert g1 == g0
        assert np.abs(q1 - q0).max() < 1e-4
        assert np.sqrt(np.mean((q2 - q0) ** 2)) > 0.02


@pytest.mark.parametrize("n_basis,rate_hz", [(5, 100), (20, 100), (40, 200)])
def test_other_basis_sizes_learn_the_same_curve(n_basis, rate_hz):
    """Cycles-to-5 % within +-2 cycles of the shipped basis 10, every one of seeds 0-4 (40
    basis functions reach harmonic 44 of the cycle: at 100 Hz their learning is not stable,
    docs/results.md, so 200 Hz; 5 functions at their default width, which keeps harmonic 4
    from coming with the first: at h = N / 2 seed 6 of 0-19 took 42 cycles)."""
    ship = load_experiment(STANDARD)
    more = load_experiment(STANDARD, [f"primitives.basis={n_basis}", f"sim.rate_hz={rate_hz}"])
    a = [run_seed(ship, s, 30).summary["converged_cycle"] for s in SEEDS]
    b = [run_seed(more, s, 30).summary["converged_cycle"] for s in SEEDS]
    assert None not in a and None not in b, (a, b)
    assert all(abs(x - y) <= 2 for x, y in zip(a, b)), (a, b)
