r"""Rhythmic movement primitives (thesis §2.1, eq. 2.1-2.4).

Canonical system (eq. 2.1) and transformation system (eq. 2.2) with von Mises basis (eq. 2.3):

.. math::

    \tau \dot\phi = 1, \qquad
    \tau^2 \ddot q = \alpha_z(\beta_z(g - q) - \tau \dot q) + r\,\psi(\phi)^\top w, \qquad
    \psi_i(\phi) = \exp(h(\cos(\phi - c_i) - 1)).

With :math:`\tau = T / 2\pi` the phase advances :math:`2\pi` per period :math:`T`. The state
:math:`x = (q, \dot q)` obeys the *linear* system :math:`\dot x = A x + E(\phi)\,\theta` in the
parameters :math:`\theta = (w, g)`, so feltool discretises it exactly: over one control step of
length :math:`\Delta t` with constant :math:`\theta`,

.. math::

    x_{k+1} = \Phi x_k + \Gamma_k \theta, \qquad \Phi = e^{A\Delta t}, \qquad
    \Gamma_k = \int_0^{\Delta t} e^{A(\Delta t - s)} E(\phi_k + s/\tau)\, ds

(:math:`\Gamma_k` by Gauss-Legendre quadrature). The same recursion integrates the sensitivity
:math:`S_k = \partial x_k / \partial\theta`: :math:`S_{k+1} = \Phi S_k + \Gamma_k` (the linear
sensitivity ODE, exactly). The periodic solution (the limit cycle the RMP settles on) and its
sensitivity are closed-form: :math:`x_0 = (I - \Phi^n)^{-1} \sum_k \Phi^{n-1-k} \Gamma_k \theta`,
so a whole cycle of :math:`q_d, \dot q_d, \ddot q_d` is a fixed matrix times :math:`\theta`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feltool.errors import InputError

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(12)


def expm(A: np.ndarray) -> np.ndarray:
    """Matrix exponential by scaling and squaring of a Taylor series (small matrices; accurate
    to rounding for the RMP's 2 x 2 systems, and cheaper to import than scipy.linalg)."""
    norm = float(np.abs(A).sum(axis=1).max())
    squarings = max(0, int(np.ceil(np.log2(norm / 0.25))) if norm > 0.25 else 0)
    X = A / 2.0**squarings
    result, term = np.eye(len(A)), np.eye(len(A))
    for k in range(1, 20):
        term = term @ X / k
        result = result + term
    for _ in range(squarings):
        result = result @ result
    return result


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


class RhythmicPrimitive:
    """One joint's RMP sampled at a fixed control rate.

    Args:
        n_basis: Number of von Mises basis functions N, centres :math:`c_i = 2\\pi i / N`.
        period_s: Period T of the rhythmic motion in [s].
        dt: Control (sampling) step in [s]; ``period_s / dt`` must be a whole number.
        alpha_z: Timing constant :math:`\\alpha_z` (thesis: 25).
        beta_z: Timing constant :math:`\\beta_z`; default :math:`\\alpha_z / 4` (critical damping).
        width: Basis width h; default N/2 (h = N leaves ripple in :math:`\\ddot q` at T = 1 s).
        amplitude: Amplitude factor r of the forcing term (eq. 2.2).
    """

    def __init__(self, n_basis: int, period_s: float, dt: float, alpha_z: float = 25.0,
                 beta_z: float | None = None, width: float | None = None,
                 amplitude: float = 1.0):
        steps = period_s / dt
        n_steps = int(round(steps))
        if n_steps < 2 or abs(steps - n_steps) > 1e-9 * max(1.0, steps):
            raise InputError(f"a period of {period_s} s at a step of {dt} s is {steps:g} samples; "
                             "it must be a whole number of at least 2")
        self.n_basis = int(n_basis)
        self.period_s = float(period_s)
        self.dt = float(dt)
        self.n_steps = n_steps
        self.tau = period_s / (2.0 * np.pi)
        self.alpha_z = float(alpha_z)
        self.beta_z = float(alpha_z / 4.0 if beta_z is None else beta_z)
        self.width = float(n_basis / 2.0 if width is None else width)
        self.amplitude = float(amplitude)
        self.centers = 2.0 * np.pi * np.arange(self.n_basis) / self.n_basis
        self.n_params = self.n_basis + 1  # weights, then the goal
        self._discretise()

    # -- eq. 2.3 -------------------------------------------------------------------------------
    def basis(self, phi: np.ndarray | float) -> np.ndarray:
        """von Mises basis :math:`\\psi(\\phi)`, shape ``(..., N)`` (eq. 2.3); phase in [rad]."""
        phi = np.asarray(phi, dtype=float)[..., None]
        return np.exp(self.width * (np.cos(phi - self.centers) - 1.0))

    def phase(self, k: np.ndarray | int) -> np.ndarray:
        """Phase :math:`\\phi` in [rad] at step k (eq. 2.1 with :math:`\\phi(0) = 0`)."""
        return 2.0 * np.pi * np.asarray(k, dtype=float) / self.n_steps

    # -- eq. 2.2 as a linear system ------------------------------------------------------------
    def _input_row(self, phi: np.ndarray) -> np.ndarray:
        """Row of :math:`E(\\phi)` acting on the acceleration: :math:`\\ddot q` gets this times θ."""
        tau2 = self.tau**2
        psi = self.basis(phi) * (self.amplitude / tau2)
        goal = np.full(psi.shape[:-1] + (1,), self.alpha_z * self.beta_z / tau2)
        return np.concatenate([psi, goal], axis=-1)

    def _discretise(self) -> None:
        tau, az, bz, dt, n = self.tau, self.alpha_z, self.beta_z, self.dt, self.n_steps
        A = np.array([[0.0, 1.0], [-az * bz / tau**2, -az / tau]])
        self.A = A
        self.Phi = expm(A * dt)
        # Gamma_k = int_0^dt expm(A (dt - s)) [0; E(phi_k + s/tau)] ds, Gauss-Legendre in s.
        s = 0.5 * dt * (_GL_NODES + 1.0)
        decay = np.stack([expm(A * (dt - si))[:, 1] for si in s])  # (G, 2)
        phis = self.phase(np.arange(n))[:, None] + s[None, :] / tau  # (n, G)
        rows = self._input_row(phis)  # (n, G, P)
        self.Gamma = 0.5 * dt * np.einsum("g,gi,kgp->kip", _GL_WEIGHTS, decay, rows)  # (n, 2, P)
        # Periodic solution: x_k = X[k] @ theta for the limit cycle.
        X = np.zeros((n + 1, 2, self.n_params))
        for k in range(n):
            X[k + 1] = self.Phi @ X[k] + self.Gamma[k]
        PhiN = np.linalg.matrix_power(self.Phi, n)
        x0 = np.linalg.solve(np.eye(2) - PhiN, X[n])
        Phik = np.eye(2)
        for k in range(n):
            X[k] += Phik @ x0
            Phik = self.Phi @ Phik
        X = X[:n]
        self.in_rows = self._input_row(self.phase(np.arange(n)))  # (n, P)
        self.Xq = X[:, 0, :]
        self.Xv = X[:, 1, :]
        self.Xa = A[1, 0] * self.Xq + A[1, 1] * self.Xv + self.in_rows

    # -- the limit cycle and its sensitivity ---------------------------------------------------
    def periodic(self, theta: np.ndarray) -> Trajectory:
        """The limit cycle for parameters ``theta = (w_1..w_N, g)``, sampled at the n steps."""
        return Trajectory(self.Xq @ theta, self.Xv @ theta, self.Xa @ theta)

    def periodic_sensitivity(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:math:`\\partial(q_d, \\dot q_d, \\ddot q_d)/\\partial\\theta` on the limit cycle,
        each ``(n, N + 1)``; constant because the RMP is linear in θ."""
        return self.Xq, self.Xv, self.Xa

    # -- step-by-step integration (per-step learning, demos, tests) ----------------------------
    def step(self, x: np.ndarray, theta: np.ndarray, k: int) -> np.ndarray:
        """State ``(q, qdot)`` at step k+1 from step k with θ held over the step."""
        return self.Phi @ x + self.Gamma[k % self.n_steps] @ theta

    def step_sensitivity(self, S: np.ndarray, k: int) -> np.ndarray:
        """Sensitivity :math:`\\partial x_{k+1}/\\partial\\theta` from
        :math:`\\partial x_k/\\partial\\theta` (the linear sensitivity recursion)."""
        return self.Phi @ S + self.Gamma[k % self.n_steps]

    def acceleration(self, x: np.ndarray, theta: np.ndarray, k: int) -> float:
        """:math:`\\ddot q` at step k from eq. 2.2."""
        return float(self.A[1] @ x + self.in_rows[k % self.n_steps] @ theta)

    def acceleration_sensitivity(self, S: np.ndarray, k: int) -> np.ndarray:
        return self.A[1] @ S + self.in_rows[k % self.n_steps]

    def rollout(self, theta: np.ndarray, x0: np.ndarray, n: int) -> Trajectory:
        """Integrate n steps from state ``x0 = (q, qdot)`` with fixed θ."""
        qs, vs, accs = np.empty(n), np.empty(n), np.empty(n)
        x = np.asarray(x0, dtype=float)
        for k in range(n):
            qs[k], vs[k] = x
            accs[k] = self.acceleration(x, theta, k)
            x = self.step(x, theta, k)
        return Trajectory(qs, vs, accs)

    # -- eq. 2.4 ---------------------------------------------------------------------------------
    def fit(self, q, v, a, phi: np.ndarray, goal: float | None = None) -> np.ndarray:
        """Least-squares weights for a demonstration (eq. 2.4); returns ``theta = (w, g)``.

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
    designer's collocation, :mod:`feltool.gait_design`). Returns ``(q, v, a)`` at ``t``."""
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
        self.n_steps = next(iter(self.primitives.values())).n_steps
        self.slices: dict[int, slice] = {}
        start = 0
        for i, prim in self.primitives.items():
            self.slices[i] = slice(start, start + prim.n_params)
            start += prim.n_params
        self.n_params = start

    def desired(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Limit-cycle :math:`q_d, \\dot q_d, \\ddot q_d` of every joint, each ``(n, nv)``."""
        n = self.n_steps
        Q, V, A = np.zeros((n, self.nv)), np.zeros((n, self.nv)), np.zeros((n, self.nv))
        for i, prim in self.primitives.items():
            if i in self.fixed:
                Q[:, i], V[:, i], A[:, i] = self.fixed[i]
                continue
            th = theta[self.slices[i]]
            Q[:, i], V[:, i], A[:, i] = prim.Xq @ th, prim.Xv @ th, prim.Xa @ th
            if i in self.offsets:  # a learned correction on top of a given motion
                q, v, a = self.offsets[i]
                Q[:, i] += q
                V[:, i] += v
                A[:, i] += a
        return Q, V, A
