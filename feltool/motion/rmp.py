r"""Rhythmic movement primitives (thesis §2.1, eq. 2.1-2.4) as functions of the phase.

Canonical system (eq. 2.1, :mod:`feltool.motion.phase`) and transformation system (eq. 2.2) with von
Mises basis (eq. 2.3):

.. math::

    \dot\phi = \omega = 1/\tau, \qquad
    \tau^2 \ddot q = \alpha_z(\beta_z(g - q) - \tau \dot q) + r\,\psi(\phi)^\top w, \qquad
    \psi_i(\phi) = \exp(h(\cos(\phi - c_i) - 1)).

Written in the phase (primes are :math:`d/d\phi`, :math:`\dot q = \omega q'`), the
transformation system does not involve the frequency at all:

.. math::

    q'' = \alpha_z(\beta_z(g - q) - q') + r\,\psi(\phi)^\top w .

It is the thesis's eq. 2.2 at a fixed :math:`\omega`, and Ijspeert's form with the velocity
state :math:`z = \tau\dot q` when :math:`\omega` changes. So an RMP is one function of the phase
whatever the speed: :math:`q_d(t) = q(\phi(t))`, :math:`\dot q_d = \omega q'`,
:math:`\ddot q_d = \omega^2 q'' + \dot\omega q'`. The state :math:`y = (q, q')` is linear in the
parameters :math:`\theta = (w, g)`, :math:`y' = A y + E(\phi)\theta`, and feltool solves it in
closed form. The basis is a Fourier series with Bessel coefficients (Jacobi-Anger,
:func:`feltool.motion.spectral.von_mises`), and harmonic m of the forcing passes through the
transformation system with the gain :math:`H_m = 1/(\alpha_z\beta_z - m^2 + i\alpha_z m)`.
So the periodic solution, the limit cycle the RMP settles on, is a fixed series in the phase,
:math:`y^*(\phi) = Y(\phi)\theta`, exact to rounding (harmonics whose basis coefficient is
below 1e-17 of the mean are dropped). It is evaluated at any phase without any time step, and
its sensitivity :math:`\partial y^*/\partial\theta = Y(\phi)` is the same matrix. Off the limit
cycle the deviation decays by the homogeneous solution, so one step of any length
:math:`\Delta\phi` is exact too:

.. math::

    y(\phi + \Delta\phi) = Y(\phi + \Delta\phi)\theta + e^{A\Delta\phi}(y(\phi) - Y(\phi)\theta).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feltool.errors import InputError
from feltool.motion import spectral
from feltool.motion.phase import PhaseSamples, clock_cycle


def exp2(A: np.ndarray, s: np.ndarray | float) -> np.ndarray:
    """:math:`e^{As}` of a 2 x 2 matrix for times ``s`` (any shape; result ``s.shape + (2,
    2)``), in closed form: :math:`e^{\\mu s}(\\cosh(\\gamma s) I + \\sinh(\\gamma s)/\\gamma\\,
    (A - \\mu I))` with :math:`\\mu = \\mathrm{tr}A/2`, :math:`\\gamma^2 = \\mu^2 - \\det A`."""
    s = np.asarray(s, dtype=float)
    mu = 0.5 * (A[0, 0] + A[1, 1])
    gamma = np.sqrt(complex(mu * mu - (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0])))
    gs = gamma * s
    small = np.abs(gs) < 1e-3
    with np.errstate(all="ignore"):
        up, down = np.exp((mu + gamma) * s), np.exp((mu - gamma) * s)
        f1 = np.where(small, np.exp(mu * s) * (1 + gs**2 / 2 + gs**4 / 24), (up + down) / 2).real
        f2 = np.where(small, np.exp(mu * s) * s * (1 + gs**2 / 6 + gs**4 / 120),
                      (up - down) / (2 * gamma if gamma != 0 else 1.0)).real
    B = A - mu * np.eye(2)
    return f1[..., None, None] * np.eye(2) + f2[..., None, None] * B


@dataclass(frozen=True)
class Trajectory:
    """Samples of a desired trajectory over one cycle, ``n`` steps.

    Attributes:
        q: positions in [rad], shape ``(n,)``.
        v: velocities in [rad/s].
        a: accelerations in [rad/s^2].
    """

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray


def time_derivatives(Yq: np.ndarray, Yp: np.ndarray, Ypp: np.ndarray, cycle: PhaseSamples
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Phase derivatives (rows per step of ``cycle``) as time derivatives: :math:`\\dot q =
    \\omega q'`, :math:`\\ddot q = \\omega^2 q'' + \\dot\\omega q'`."""
    w = cycle.omega.reshape((-1,) + (1,) * (Yp.ndim - 1))
    wd = cycle.omega_dot.reshape(w.shape)
    return Yq, w * Yp, w * w * Ypp + wd * Yp


class RhythmicPrimitive:
    """One joint's RMP (eq. 2.2) as a function of the phase, with a nominal clock.

    Args:
        n_basis: Number of von Mises basis functions N, centres :math:`c_i = 2\\pi i / N`.
        period_s: Period T of the nominal clock in [s] (the time-based helpers below: ``Xq``,
            ``periodic``, ``step``, ``rollout``, ``fit``); any value of at least two steps.
        dt: Control (sampling) step of the nominal clock in [s].
        alpha_z: Timing constant :math:`\\alpha_z` (thesis: 25).
        beta_z: Timing constant :math:`\\beta_z`; default :math:`\\alpha_z / 4` (critical damping).
        width: Basis width h; default :func:`feltool.motion.spectral.default_width` (N/2 from
            N = 7 on; h = N leaves ripple in :math:`\\ddot q` at T = 1 s).
        amplitude: Amplitude factor r of the forcing term (eq. 2.2).
    """

    def __init__(self, n_basis: int, period_s: float, dt: float, alpha_z: float = 25.0,
                 beta_z: float | None = None, width: float | None = None,
                 amplitude: float = 1.0):
        if not period_s / dt >= 2.0:
            raise InputError(f"a period of {period_s} s at a step of {dt} s is "
                             f"{period_s / dt:g} samples; it must be at least 2")
        self.n_basis = int(n_basis)
        self.period_s = float(period_s)
        self.dt = float(dt)
        self.tau = period_s / (2.0 * np.pi)
        self.omega = 2.0 * np.pi / period_s
        self.alpha_z = float(alpha_z)
        self.beta_z = float(alpha_z / 4.0 if beta_z is None else beta_z)
        self.width = float(spectral.default_width(n_basis) if width is None else width)
        self.amplitude = float(amplitude)
        self.centers = 2.0 * np.pi * np.arange(self.n_basis) / self.n_basis
        self.n_params = self.n_basis + 1  # weights, then the goal
        az, bz = self.alpha_z, self.beta_z
        #: the transformation system in the phase: y' = A y + E(phi) theta, y = (q, q')
        self.A_phase = np.array([[0.0, 1.0], [-az * bz, -az]])
        self.n_harmonics = spectral.von_mises_harmonics(self.width)
        M = self.n_harmonics
        # The forcing's series (weights: r psi_i; goal: alpha_z beta_z g), then the limit
        # cycle's: harmonic m passes with the gain H_m (a cosine/sine pair as one complex number).
        U = np.zeros((2 * M + 1, self.n_params))
        self._basis_series = spectral.von_mises(self.width, self.centers, M)
        U[:, :self.n_basis] = self.amplitude * self._basis_series
        U[0, -1] = az * bz
        m = np.arange(1, M + 1)[:, None]
        H = 1.0 / (az * bz - m**2 + 1j * az * m)
        z = H * (U[1:M + 1] - 1j * U[M + 1:])
        Cq = np.concatenate([U[:1] / (az * bz), z.real, -z.imag])
        Cp = spectral.differentiate(Cq)
        #: ``(2M + 1, 3P)``: series of q, q' and q'' of the limit cycle, per parameter
        self.series = np.concatenate([Cq, Cp, spectral.differentiate(Cp)], axis=1)
        self.nominal = clock_cycle(self.period_s, self.dt)
        self.n_steps = self.nominal.n
        self._whole = abs(self.period_s / self.dt - self.n_steps) <= 1e-9 * self.n_steps
        self._nominal_rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._transitions: dict[tuple[float, float], tuple[np.ndarray, np.ndarray]] = {}

    # -- eq. 2.3 -------------------------------------------------------------------------------
    def basis(self, phi: np.ndarray | float) -> np.ndarray:
        """von Mises basis :math:`\\psi(\\phi)`, shape ``(..., N)`` (eq. 2.3); phase in [rad]."""
        phi = np.asarray(phi, dtype=float)[..., None]
        return np.exp(self.width * (np.cos(phi - self.centers) - 1.0))

    def phase(self, k: np.ndarray | int) -> np.ndarray:
        """Phase :math:`\\phi` in [rad] at step k of the nominal clock (:math:`\\phi(0) = 0`)."""
        return np.asarray(k, dtype=float) * (self.omega * self.dt)

    def input_row(self, phi: np.ndarray | float) -> np.ndarray:
        """Row of :math:`E(\\phi)` acting on :math:`q''`: :math:`(r\\psi(\\phi), \\alpha_z
        \\beta_z)`, shape ``(..., P)``."""
        psi = self.basis(phi) * self.amplitude
        goal = np.full(psi.shape[:-1] + (1,), self.alpha_z * self.beta_z)
        return np.concatenate([psi, goal], axis=-1)

    # -- the limit cycle and its sensitivity ---------------------------------------------------
    def limit_cycle(self, phi: np.ndarray | float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:math:`\\partial(q, q', q'')/\\partial\\theta` on the limit cycle at the phases
        ``phi`` [rad] (primes: phase derivatives), each ``(n, P)``; the limit cycle itself is
        these times θ."""
        Y = spectral.trig(phi, self.n_harmonics) @ self.series
        P = self.n_params
        return Y[:, :P], Y[:, P:2 * P], Y[:, 2 * P:]

    def sensitivity(self, cycle: PhaseSamples) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:math:`\\partial(q_d, \\dot q_d, \\ddot q_d)/\\partial\\theta` at the steps of a
        cycle, each ``(n, N + 1)``; constant in θ because the RMP is linear in θ."""
        return time_derivatives(*self.limit_cycle(cycle.phi), cycle)

    def periodic_sensitivity(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`sensitivity` on the nominal clock's first cycle (computed once)."""
        if self._nominal_rows is None:
            self._nominal_rows = time_derivatives(*self.limit_cycle(self.nominal.phi),
                                                  self.nominal)
        return self._nominal_rows

    @property
    def Xq(self) -> np.ndarray:
        """:math:`\\partial q_d/\\partial\\theta` on the nominal cycle ``(n, P)``."""
        return self.periodic_sensitivity()[0]

    @property
    def Xv(self) -> np.ndarray:
        return self.periodic_sensitivity()[1]

    @property
    def Xa(self) -> np.ndarray:
        return self.periodic_sensitivity()[2]

    def periodic(self, theta: np.ndarray) -> Trajectory:
        """The limit cycle for parameters ``theta = (w_1..w_N, g)`` on the nominal cycle."""
        Xq, Xv, Xa = self.periodic_sensitivity()
        return Trajectory(Xq @ theta, Xv @ theta, Xa @ theta)

    # -- step by step, exact for any step of the phase -----------------------------------------
    def state_rows(self, phi: float) -> np.ndarray:
        """``(2, P)``: :math:`\\partial(q, q')/\\partial\\theta` on the limit cycle at ``phi``."""
        Yq, Yp, _ = self.limit_cycle(phi)
        return np.concatenate([Yq, Yp])

    def transition(self, phi: float, dphi: float) -> tuple[np.ndarray, np.ndarray]:
        """``(F, G)`` with :math:`y(\\phi + \\Delta\\phi) = F y(\\phi) + G\\theta` for θ held
        over the step (phase units, ``y = (q, q')``). Kept for phases met again (a clock's
        cycles repeat theirs); the arrays are shared, not to be modified."""
        key = (float(phi), float(dphi))
        out = self._transitions.get(key)
        if out is None:
            if len(self._transitions) >= 8192:
                self._transitions.clear()
            F = exp2(self.A_phase, dphi)
            out = self._transitions[key] = (F, self.state_rows(phi + dphi)
                                            - F @ self.state_rows(phi))
        return out

    def phase_acceleration(self, y: np.ndarray, S: np.ndarray, theta: np.ndarray,
                           phi: float) -> tuple[float, np.ndarray]:
        """:math:`q''` at the state ``y = (q, q')`` and phase ``phi`` (the transformation
        system in the phase), and :math:`\\partial q''/\\partial\\theta` from the state's
        sensitivity ``S`` ``(2, P)``."""
        row = self.input_row(phi)
        return float(self.A_phase[1] @ y + row @ theta), self.A_phase[1] @ S + row

    # time units at the nominal clock, step k (demos, tests)
    def _nominal_step(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        S = np.array([1.0, self.omega])
        F, G = self.transition(float(self.phase(k % self.n_steps if self._whole else k)),
                               self.omega * self.dt)
        return S[:, None] * F / S[None, :], S[:, None] * G

    def step(self, x: np.ndarray, theta: np.ndarray, k: int) -> np.ndarray:
        """State ``(q, qdot)`` at step k+1 from step k with θ held over the step."""
        F, G = self._nominal_step(k)
        return F @ x + G @ theta

    def step_sensitivity(self, S: np.ndarray, k: int) -> np.ndarray:
        """Sensitivity :math:`\\partial x_{k+1}/\\partial\\theta` from
        :math:`\\partial x_k/\\partial\\theta` (the linear sensitivity recursion)."""
        F, G = self._nominal_step(k)
        return F @ S + G

    def rollout(self, theta: np.ndarray, x0: np.ndarray, n: int) -> Trajectory:
        """n steps of the nominal clock from the state ``x0 = (q, qdot)`` with fixed θ: the
        limit cycle plus the homogeneous solution of the deviation from it (what :meth:`step`
        gives step by step, in one evaluation)."""
        phi = self.phase(np.arange(n))
        Yq, Yp, Ypp = (Y @ theta for Y in self.limit_cycle(phi))
        x0 = np.asarray(x0, dtype=float)
        d = exp2(self.A_phase, phi) @ np.array([x0[0] - Yq[0], x0[1] / self.omega - Yp[0]])
        w = self.omega
        return Trajectory(Yq + d[:, 0], w * (Yp + d[:, 1]), w * w * (Ypp + d @ self.A_phase[1]))

    # -- eq. 2.4 ---------------------------------------------------------------------------------
    def fit(self, q, v, a, phi: np.ndarray, goal: float | None = None) -> np.ndarray:
        """Least-squares weights for a demonstration at the nominal clock (eq. 2.4); returns
        ``theta = (w, g)``.

        Args:
            q, v, a: Demonstrated position [rad], velocity [rad/s], acceleration [rad/s^2].
            phi: Phase [rad] of each sample.
            goal: Baseline g in [rad]; default the demonstration's mean.
        """
        q, v, a = (np.asarray(x, dtype=float) for x in (q, v, a))
        g = float(np.mean(q)) if goal is None else float(goal)
        target = self.tau**2 * a - self.alpha_z * (self.beta_z * (g - q) - self.tau * v)
        design = self.basis(phi) * self.amplitude
        w, *_ = np.linalg.lstsq(design, target, rcond=None)
        return np.concatenate([w, [g]])

    def fit_series(self, series: np.ndarray, goal: float | None = None) -> np.ndarray:
        """Eq. 2.4 over the whole phase: the weights whose forcing term is closest in
        :math:`L^2(0, 2\\pi)` to the demonstration's, :math:`q'' - \\alpha_z(\\beta_z(g - q) -
        q')`, for a demonstration given as a Fourier series of the phase
        (:mod:`feltool.motion.spectral`; its derivatives are exact). The least squares runs over the
        series' coefficients (Parseval), not over samples. Returns ``theta = (w, g)``.

        Args:
            series: Coefficients of :math:`q(\\phi)` [rad], see :mod:`feltool.motion.spectral`.
            goal: Baseline g in [rad]; default the demonstration's mean.
        """
        # harmonics above the basis's are orthogonal to every basis function: they add the
        # same residual whatever the weights, so the least squares runs without them
        M = self.n_harmonics
        c = spectral.pad(np.asarray(series, dtype=float), M)
        g = float(c[0]) if goal is None else float(goal)
        dc = spectral.differentiate(c)
        target = spectral.differentiate(dc) + self.alpha_z * dc + self.alpha_z * self.beta_z * c
        target[0] -= self.alpha_z * self.beta_z * g
        design = self.amplitude * self._basis_series
        w, *_ = np.linalg.lstsq(spectral.parseval_rows(design), spectral.parseval_rows(target),
                                rcond=None)
        return np.concatenate([w, [g]])

    def fit_rms(self, theta: np.ndarray, q: np.ndarray, phi: np.ndarray) -> float:
        """RMS in [rad] of the limit cycle minus the demonstration ``q`` at the phases
        ``phi`` (the fit error; on a fine uniform grid of the phase this is the RMS over the
        cycle)."""
        return float(np.sqrt(np.mean((self.limit_cycle(phi)[0] @ theta - q) ** 2)))


def fit_trajectory(source: RhythmicPrimitive, target: RhythmicPrimitive,
                   theta: np.ndarray) -> np.ndarray:
    """Parameters of ``target`` whose limit cycle is closest in :math:`L^2(0, 2\\pi)` to that of
    ``source`` with parameters ``theta`` (eq. 2.4 over the phase, :meth:`RhythmicPrimitive.
    fit_series`), with the same goal [rad]: one forward trajectory written in another basis."""
    theta = np.asarray(theta, dtype=float)
    return target.fit_series(source.series[:, :source.n_params] @ theta, goal=float(theta[-1]))


def sine_demo(mean: float, amplitude: float, period_s: float, phase: float, t: np.ndarray,
              harmonics=(), delay: float = 0.0):
    """``q(t) = mean + amplitude sin(w s + phase) + sum_k A_k sin(k w s + phi_k)`` with
    ``w = 2 pi / T``, ``s = t - delay T``, harmonics ``(A_k, phi_k)`` for k = 2, 3, ..., and its
    derivatives ([rad], [s])."""
    w = 2.0 * np.pi / period_s
    s = np.asarray(t, dtype=float) - delay * period_s
    q, v, a = np.full_like(s, mean), np.zeros_like(s), np.zeros_like(s)
    for k, (amp, ph) in enumerate([(amplitude, phase), *harmonics], start=1):
        arg = k * w * s + ph
        q += amp * np.sin(arg)
        v += amp * k * w * np.cos(arg)
        a -= amp * (k * w) ** 2 * np.sin(arg)
    return q, v, a


def samples_demo(q, v, a, period_s: float, t: np.ndarray):
    """The trajectory through knots ``q, v, a`` equally spaced over ``[0, T]`` (first at 0, last
    at T), evaluated at times ``t`` in [0, T): on each interval the cubic with a linearly
    changing acceleration, ``q_k + v_k s + a_k s^2/2 + (a_{k+1} - a_k) s^3 / (6 h)`` (the gait
    designer's collocation, :mod:`feltool.gait.design`). Returns ``(q, v, a)`` at ``t``."""
    q, v, a = (np.asarray(x, dtype=float) for x in (q, v, a))
    h = period_s / (len(q) - 1)
    t = np.asarray(t, dtype=float)
    # a time on a knot belongs to the interval it starts (rounded: 0.5 // 0.0125 is 39.0)
    k = np.clip(np.floor(np.round(t / h, 9)).astype(int), 0, len(q) - 2)
    s = t - k * h
    jerk = (a[k + 1] - a[k]) / h
    return (q[k] + v[k] * s + a[k] * s**2 / 2 + jerk * s**3 / 6,
            v[k] + a[k] * s + jerk * s**2 / 2, a[k] + jerk * s)


class PrimitiveSet:
    """The forward trajectory generator: one RMP per joint of the model, parameters stacked.

    ``theta`` concatenates each joint's ``(w_1..w_N, g)`` in joint order; :attr:`slices` says
    where each joint's block sits.

    Args:
        primitives: ``{joint velocity index: RhythmicPrimitive}`` for every joint of the model.
        nv: Number of velocity coordinates of the model.
        fixed: ``{joint velocity index: (q, v, a)}``: joints whose forward trajectory is given
            sample by sample (``follow_demo``, never learned) instead of by their RMP.
        offsets: ``{joint velocity index: (q, v, a)}``: joints whose forward trajectory is the
            given samples plus their (learned) RMP's output (``follow_demo`` with ``learn``).
    """

    def __init__(self, primitives: dict[int, RhythmicPrimitive], nv: int,
                 fixed: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
                 offsets: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None):
        self.primitives = dict(sorted(primitives.items()))
        self.nv = nv
        self.fixed = dict(fixed or {})
        self.offsets = dict(offsets or {})
        first = next(iter(self.primitives.values()))
        self.n_steps = first.n_steps
        #: the nominal clock's first cycle (the thesis's cycle at a whole-sample period)
        self.nominal = first.nominal
        self._nominal_key = self.nominal.key()  # (a frozen cycle: hashed once)
        self.slices: dict[int, slice] = {}
        start = 0
        for i, prim in self.primitives.items():
            self.slices[i] = slice(start, start + prim.n_params)
            start += prim.n_params
        self.n_params = start
        self._cache: dict[tuple, dict[int, tuple]] = {}

    def sensitivities(self, cycle: PhaseSamples | None = None
                      ) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per joint, :math:`\\partial(q_d, \\dot q_d, \\ddot q_d)/\\partial\\theta_i` at the
        steps of ``cycle`` (default the nominal one), each ``(n, P_i)``; the last few cycles'
        are kept (a clock repeats its cycles)."""
        cycle = cycle or self.nominal
        key = cycle.key()
        if key == self._nominal_key:
            return {i: p.periodic_sensitivity() for i, p in self.primitives.items()}
        if key not in self._cache:
            if len(self._cache) >= 4:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = {i: p.sensitivity(cycle) for i, p in self.primitives.items()}
        return self._cache[key]

    def desired(self, theta: np.ndarray, cycle: PhaseSamples | None = None,
                transients: dict[int, tuple[np.ndarray, float]] | None = None,
                without: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:math:`q_d, \\dot q_d, \\ddot q_d` of every joint at the steps of ``cycle`` (default
        the nominal cycle), each ``(n, nv)``: the limit cycle of ``theta``, plus for the joints
        in ``transients`` (``{index: (y0, phi0)}``) the homogeneous solution
        :math:`e^{A(\\phi - \\phi_0)} y_0` started at the phase :math:`\\phi_0` [rad] (counted
        from the run's start) by an amplitude or goal change. The joints in ``without`` leave
        out their limit cycle (the compiled engine adds it, :mod:`feltool.engines.compiled.graph`)."""
        cycle = cycle or self.nominal
        n = cycle.n
        sens = self.sensitivities(cycle)
        Q, V, A = np.zeros((n, self.nv)), np.zeros((n, self.nv)), np.zeros((n, self.nv))
        for i, prim in self.primitives.items():
            if i in self.fixed:
                Q[:, i], V[:, i], A[:, i] = self.fixed[i]
                continue
            if i not in without:
                th = theta[self.slices[i]]
                Xq, Xv, Xa = sens[i]
                Q[:, i], V[:, i], A[:, i] = Xq @ th, Xv @ th, Xa @ th
            if i in self.offsets:  # a learned correction on top of a given motion
                q, v, a = self.offsets[i]
                Q[:, i] += q
                V[:, i] += v
                A[:, i] += a
            if transients and i in transients:
                y0, phi0 = transients[i]
                y = exp2(prim.A_phase, cycle.elapsed - phi0) @ y0
                q, v, a = time_derivatives(y[:, 0], y[:, 1], y @ prim.A_phase[1], cycle)
                Q[:, i] += q
                V[:, i] += v
                A[:, i] += a
        return Q, V, A
