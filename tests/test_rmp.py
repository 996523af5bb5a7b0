"""Rhythmic movement primitives: fit (eq. 2.4), integration, limit cycle and sensitivities."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from feltool.errors import InputError
from feltool.motion.rmp import RhythmicPrimitive, sine_demo
from feltool.motion.spectral import default_width


def fitted_sine(n_basis=10, dt=0.01, period=1.0):
    prim = RhythmicPrimitive(n_basis, period, dt)
    t = np.linspace(0, period, 1000, endpoint=False)
    q, v, a = sine_demo(0.0, 1.0, period, 0.0, t)
    return prim, prim.fit(q, v, a, 2 * np.pi * t / period)


def test_fit_reproduces_sine_after_first_cycle():
    """Thesis Fig. 2.1: fitted to sin(2 pi t) with 10 basis functions, the RMP integrated from
    rest matches it to < 1e-3 rad after the first cycle."""
    prim, theta = fitted_sine()
    n = prim.n_steps
    out = prim.rollout(theta, np.array([0.0, 0.0]), 3 * n)
    t = np.arange(3 * n) * prim.dt
    q, v, _ = sine_demo(0.0, 1.0, 1.0, 0.0, t)
    assert np.abs(out.q[n:] - q[n:]).max() < 1e-3
    assert np.abs(out.v[n:] - v[n:]).max() < 0.05  # [rad/s], of an amplitude of 6.3
    # Before settling (first steps, from rest) the RMP is not on the sine: the check can fail.
    assert np.abs(out.q[:n] - q[:n]).max() > 1e-2


def test_limit_cycle_is_what_integration_settles_on():
    prim, theta = fitted_sine()
    n = prim.n_steps
    cyc = prim.periodic(theta)
    out = prim.rollout(theta, np.array([0.3, -1.0]), 4 * n)
    np.testing.assert_allclose(out.q[3 * n:], cyc.q, atol=1e-9)
    np.testing.assert_allclose(out.v[3 * n:], cyc.v, atol=1e-8)
    np.testing.assert_allclose(out.a[3 * n:], cyc.a, atol=1e-6)


def test_goal_is_the_mean_and_tau_gives_the_period():
    prim = RhythmicPrimitive(10, 2.0, 0.02)
    assert np.isclose(prim.tau, 2.0 / (2 * np.pi))
    t = np.linspace(0, 2.0, 500, endpoint=False)
    q, v, a = sine_demo(0.7, 0.2, 2.0, 0.4, t)
    theta = prim.fit(q, v, a, 2 * np.pi * t / 2.0)
    assert np.isclose(theta[-1], 0.7)
    cyc = prim.periodic(theta)
    np.testing.assert_allclose(cyc.q, sine_demo(0.7, 0.2, 2.0, 0.4, np.arange(100) * 0.02)[0],
                               atol=2e-4)


def test_periodic_sensitivity_matches_finite_differences(rng):
    prim = RhythmicPrimitive(8, 1.0, 0.01)
    theta = rng.normal(0, 20, prim.n_params)
    Xq, Xv, Xa = prim.periodic_sensitivity()
    eps = 1e-4
    for p in range(prim.n_params):
        e = np.zeros(prim.n_params)
        e[p] = eps
        hi, lo = prim.periodic(theta + e), prim.periodic(theta - e)
        np.testing.assert_allclose((hi.q - lo.q) / (2 * eps), Xq[:, p], atol=1e-8)
        np.testing.assert_allclose((hi.v - lo.v) / (2 * eps), Xv[:, p], atol=1e-7)
        np.testing.assert_allclose((hi.a - lo.a) / (2 * eps), Xa[:, p], atol=1e-5)


def test_step_sensitivity_matches_finite_differences(rng):
    """The sensitivity recursion S' = Phi S + Gamma_k equals finite differences of a rollout."""
    prim = RhythmicPrimitive(6, 0.5, 0.01)
    theta = rng.normal(0, 10, prim.n_params)
    x0 = np.array([0.1, 0.2])

    def roll(th):
        x, S = x0.copy(), np.zeros((2, prim.n_params))
        for k in range(73):
            x, S = prim.step(x, th, k), prim.step_sensitivity(S, k)
        return x, S

    _, S = roll(theta)
    eps = 1e-5
    for p in range(prim.n_params):
        e = np.zeros(prim.n_params)
        e[p] = eps
        fd = (roll(theta + e)[0] - roll(theta - e)[0]) / (2 * eps)
        np.testing.assert_allclose(fd, S[:, p], atol=1e-8)


@pytest.mark.parametrize("n_basis", range(3, 13))
def test_the_default_width_keeps_the_first_harmonics_alias_small(n_basis):
    """With N equally spaced centres, the weights that make cos(phi) make harmonic N - 1 too,
    in the ratio of the basis function's Fourier coefficients a_{N-1} / a_1 (here by scipy's
    quadrature of exp(h (cos phi - 1)) cos(m phi)). The default width holds that ratio at or
    below 1 %, is N / 2 wherever N / 2 already does (N >= 7: the shipped configs' basis), and
    not below 0.5 (N = 3, 4)."""
    h = default_width(n_basis)

    def coefficient(m):
        return quad(lambda p: np.exp(h * (np.cos(p) - 1.0)), 0, np.pi, weight="cos", wvar=m,
                    epsabs=0.0, epsrel=1e-10, limit=200)[0]

    alias = coefficient(n_basis - 1) / coefficient(1)
    assert alias <= 1e-2 * (1 + 1e-6) or h == 0.5
    assert (h == n_basis / 2) == (n_basis >= 7)
    assert 0.5 <= h <= n_basis / 2
    if 0.5 < h < n_basis / 2:  # the widest width meeting the bound, not any width below it
        assert alias == pytest.approx(1e-2, rel=1e-6)


def test_five_functions_fit_a_sine_to_a_percent_at_the_default_width():
    """A 1 Hz sine through eq. 2.2's limit cycle, fitted by least squares: at N = 5 the default
    width leaves about 1 % (its alias), N / 2 = 2.5 left 5 % -- a floor learning cannot pass."""
    t = np.linspace(0, 1.0, 500, endpoint=False)
    q, _, _ = sine_demo(0.0, 1.0, 1.0, 0.0, t)

    def residual(prim):
        Yq, _, _ = prim.limit_cycle(2 * np.pi * t)
        theta = np.linalg.lstsq(Yq, q, rcond=None)[0]
        return np.sqrt(np.mean((Yq @ theta - q) ** 2)) / np.sqrt(np.mean(q ** 2))

    assert residual(RhythmicPrimitive(5, 1.0, 0.01)) < 0.012
    assert residual(RhythmicPrimitive(5, 1.0, 0.01, width=2.5)) > 0.045


def test_basis_is_von_mises():
    prim = RhythmicPrimitive(4, 1.0, 0.1, width=2.0)
    psi = prim.basis(0.3)
    np.testing.assert_allclose(psi, np.exp(2.0 * (np.cos(0.3 - prim.centers) - 1.0)))
    assert prim.basis(prim.centers[2])[2] == pytest.approx(1.0)


def test_a_period_needs_two_steps_but_not_a_whole_number_of_them():
    with pytest.raises(InputError, match="at least 2"):
        RhythmicPrimitive(10, 0.015, 0.01)
    prim = RhythmicPrimitive(10, 1.0, 0.03)  # 33.3 steps: the first cycle has 34
    assert prim.n_steps == 34 and prim.nominal.phi[-1] < 2 * np.pi < prim.phase(34)


# -- independent references: scipy's matrix exponential and ODE solver (issue 14) ----------------

def _rmp_ode(prim: RhythmicPrimitive, theta: np.ndarray):
    """Eq. 2.1-2.2 as a first-order ODE in (phi, q, qdot), written out here from the thesis
    (not from feltool.motion.rmp's matrices): tau phi' = 1, tau^2 q'' = alpha_z (beta_z (g - q) - tau q')
    + r psi(phi)^T w, psi_i = exp(h (cos(phi - c_i) - 1)), c_i = 2 pi i / N."""
    N, w, g = prim.n_basis, theta[:-1], theta[-1]
    tau, az, bz, h, r = prim.tau, prim.alpha_z, prim.beta_z, prim.width, prim.amplitude
    c = 2.0 * np.pi * np.arange(N) / N

    def f(t, y):
        phi, q, qd = y
        psi = np.exp(h * (np.cos(phi - c) - 1.0))
        return [1.0 / tau, qd, (az * (bz * (g - q) - tau * qd) + r * psi @ w) / tau**2]

    return f


@pytest.mark.parametrize("scale", [1e-3, 0.3, 1.0, 4.0, 20.0])
def test_matrix_exponential_matches_scipy(scale, rng):
    """The closed-form 2 x 2 exponential against scipy, for random matrices, several times at
    once, and the RMP's critically damped matrix (a repeated eigenvalue)."""
    from scipy.linalg import expm as scipy_expm

    from feltool.motion.rmp import exp2

    times = np.array([0.0, 0.01, 0.37, 1.0])
    for _ in range(5):
        A = rng.normal(size=(2, 2)) * scale
        for s, E in zip(times, exp2(A, times)):
            ref = scipy_expm(A * s)
            np.testing.assert_allclose(E, ref, rtol=1e-11, atol=1e-14 * np.abs(ref).max())
    # critically damped (eq. 2.2 with beta_z = alpha_z / 4): A - mu I is nilpotent, so
    # exp(A s) = exp(mu s) (I + s (A - mu I)) exactly (scipy's Pade is off by 1e-11 far out)
    A = scale * np.array([[0.0, 1.0], [-25.0 * 6.25, -25.0]])
    mu = -12.5 * scale
    for s, E in zip(times, exp2(A, times)):
        ref = np.exp(mu * s) * (np.eye(2) + s * (A - mu * np.eye(2)))
        np.testing.assert_allclose(E, ref, rtol=1e-13, atol=1e-15 * np.abs(ref).max())


@pytest.mark.parametrize("dt", [1e-3, 1e-2, 2e-2])
def test_step_matrix_is_scipys_exponential_of_eq_2_2(dt):
    """The step's homogeneous part F = exp(A dphi) with A written from eq. 2.2 in the test
    (phase units: y = (q, q'), dphi = 2 pi dt / T), compared with scipy."""
    from scipy.linalg import expm as scipy_expm

    prim = RhythmicPrimitive(10, 1.0, dt)
    az, bz = 25.0, 25.0 / 4
    A = np.array([[0.0, 1.0], [-az * bz, -az]])
    dphi = 2 * np.pi * dt
    F, _ = prim.transition(0.3, dphi)
    np.testing.assert_allclose(F, scipy_expm(A * dphi), rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("dt, n_basis, period", [(1e-2, 10, 1.0), (1e-3, 10, 1.0),
                                                  (2e-2, 6, 2.0)])
def test_rollout_matches_solve_ivp_of_eq_2_1_2_2(dt, n_basis, period, rng):
    """The RMP's exact discretisation against scipy's adaptive integrator of the continuous
    eq. 2.1-2.2 (rtol 1e-12), from an off-cycle state over 2.5 periods: positions to 1e-9 of the
    motion's range, velocities and accelerations to 1e-8 of theirs."""
    from scipy.integrate import solve_ivp

    prim = RhythmicPrimitive(n_basis, period, dt)
    theta = np.concatenate([rng.normal(0.0, 30.0, n_basis), [0.4]])
    x0 = np.array([-0.2, 1.5])
    n = int(2.5 * prim.n_steps)
    out = prim.rollout(theta, x0, n)
    t = np.arange(n) * dt
    sol = solve_ivp(_rmp_ode(prim, theta), (0.0, t[-1]), [0.0, *x0], method="DOP853",
                    t_eval=t, rtol=1e-12, atol=1e-12)
    assert sol.success
    f = _rmp_ode(prim, theta)
    acc = np.array([f(0.0, y)[2] for y in sol.y.T])
    for ours, ref in ((out.q, sol.y[1]), (out.v, sol.y[2]), (out.a, acc)):
        span = np.ptp(ref)
        assert span > 0.1
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-8 * span)


def test_limit_cycle_is_the_periodic_solution_of_eq_2_1_2_2(rng):
    """Started on the RMP's closed-form limit cycle, scipy's integration of the ODE comes back
    to the same state after one period and passes through every sample of it."""
    from scipy.integrate import solve_ivp

    prim = RhythmicPrimitive(10, 1.0, 1e-2)
    theta = np.concatenate([rng.normal(0.0, 30.0, 10), [-0.3]])
    cyc = prim.periodic(theta)
    n = prim.n_steps
    t = np.arange(n + 1) * prim.dt
    sol = solve_ivp(_rmp_ode(prim, theta), (0.0, t[-1]), [0.0, cyc.q[0], cyc.v[0]],
                    method="DOP853", t_eval=t, rtol=1e-12, atol=1e-12)
    span_q, span_v = np.ptp(cyc.q), np.ptp(cyc.v)
    np.testing.assert_allclose(sol.y[1, :n], cyc.q, atol=1e-9 * span_q)
    np.testing.assert_allclose(sol.y[2, :n], cyc.v, atol=1e-8 * span_v)
    np.testing.assert_allclose(sol.y[1:, n], [cyc.q[0], cyc.v[0]], atol=1e-8 * span_v)
