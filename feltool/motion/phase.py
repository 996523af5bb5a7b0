r"""The phase that an experiment's RMPs share (the canonical system, eq. 2.1, generalised).

The thesis's canonical system :math:`\tau\dot\phi = 1` runs the phase at a fixed frequency. Here
the phase :math:`\phi` is integrated with its own frequency :math:`\omega(t) = \dot\phi`:

- ``clock``: :math:`\omega = 2\pi/T` (the thesis), and after a period event
  :class:`ClockPhase` moves it smoothly to a new value (a C¹ smoothstep in time, so that
  :math:`\dot q_d` and :math:`\ddot q_d` stay continuous);
- ``adaptive``: :class:`AdaptivePhase`, an adaptive-frequency oscillator that entrains
  :math:`\omega` to a periodic input signal.

A learning cycle is one revolution of the phase: the control steps whose phase, counted from the
start of the run, lies in :math:`[2\pi(h - 1), 2\pi h)`, however many steps that takes (a period
of 1.2345 s at 1 kHz gives cycles of 1234 and 1235 steps). :class:`PhaseSamples` describes one
cycle: each step's phase, its frequency and the phase it covers; per-cycle sums over the steps
(the FEL update, eq. 3.6) and means (the metrics) are weighted by the phase each step covers, so
cycles of different lengths compare.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TWO_PI = 2.0 * np.pi
#: A step whose phase lies within this fraction of a step below a revolution's end starts the
#: next revolution (so that rounding never splits a whole-sample period unevenly).
_EDGE = 1e-9


@dataclass(frozen=True)
class PhaseSamples:
    """The phase at each control step of one learning cycle.

    Attributes:
        phi: Phase at each step's start in [rad], counted within the cycle's revolution (in
            [0, 2π) for a clock).
        dphi: Phase advanced over each step in [rad].
        omega: :math:`\\dot\\phi` at each step's start in [rad/s].
        omega_dot: :math:`\\ddot\\phi` at each step's start in [rad/s^2].
        start: Phase of the cycle's first step counted from the start of the run, in [rad]
            (unwrapped; transients after an amplitude or goal event decay in it).
        weight: Phase each step covers relative to a nominal step, :math:`\\Delta\\phi_k /
            (\\omega_0 \\Delta t)`; None when every step covers exactly the nominal step (the
            thesis's uniform cycle: plain sums and means).
    """

    phi: np.ndarray
    dphi: np.ndarray
    omega: np.ndarray
    omega_dot: np.ndarray
    start: float = 0.0
    weight: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.phi)

    @property
    def elapsed(self) -> np.ndarray:
        """Phase of each step counted from the start of the run, in [rad]."""
        return self.start + (self.phi - self.phi[0])

    def key(self) -> tuple:
        """Identifies the phases and frequencies (for caching what is evaluated at them)."""
        return (self.n, hash(self.phi.tobytes()), hash(self.omega.tobytes()),
                hash(self.omega_dot.tobytes()))


def _smoothstep(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``s(u) = 3u^2 - 2u^3`` on [0, 1] (held at 0 and 1 outside), its derivative and its
    integral from 0."""
    u = np.clip(u, 0.0, 1.0)
    return 3 * u**2 - 2 * u**3, 6 * u * (1 - u), u**3 - u**4 / 2


class ClockPhase:
    """:math:`\\dot\\phi = \\omega`: the nominal :math:`\\omega_0 = 2\\pi/T`, or after
    :meth:`change_period` a smooth move to a new frequency.

    A change from :math:`\\omega_1` to :math:`\\omega_2` lasts :math:`D` seconds:
    :math:`\\omega(t) = \\omega_1 + (\\omega_2 - \\omega_1)\\,s(t/D)` with
    :math:`s(u) = 3u^2 - 2u^3`, so :math:`\\omega` and :math:`\\dot\\omega` are continuous; the
    phase is its exact integral, :math:`\\phi(t) = \\phi(0) + \\omega_1 t + (\\omega_2 -
    \\omega_1) D (u^3 - u^4/2)` for :math:`t \\le D`.

    Args:
        period_s: Nominal period T in [s].
        dt: Control step in [s].
    """

    def __init__(self, period_s: float, dt: float):
        self.dt = float(dt)
        self.omega0 = TWO_PI / float(period_s)
        self.phi = 0.0          # phase of the next step within its revolution [rad]
        self.revolutions = 0    # revolutions completed
        self.omega = self.omega0
        self.ramp: tuple[float, float, float, int] | None = None  # (w1, w2, D [s], steps done)

    def change_period(self, period_s: float, revolutions: float = 1.0) -> None:
        """Move to the period ``period_s`` [s], starting at the next step, over a time in which
        the phase advances ``revolutions`` turns (:math:`D = 4\\pi r / (\\omega_1 + \\omega_2)`)."""
        w1, w2 = self.frequency_now(), TWO_PI / float(period_s)
        self.omega, self.ramp = w2, None
        if w2 != w1:
            self.ramp = (w1, w2, 2.0 * TWO_PI * revolutions / (w1 + w2), 0)

    def frequency_now(self) -> float:
        """:math:`\\omega` at the next step in [rad/s]."""
        if self.ramp is None:
            return self.omega
        w1, w2, D, j = self.ramp
        return w1 + (w2 - w1) * float(_smoothstep(np.array(j * self.dt / D))[0])

    def _advance(self, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Phase advanced from the next step to step ``k`` after it, and :math:`\\omega,
        \\dot\\omega` there."""
        if self.ramp is None:
            w = np.full(k.shape, self.omega)
            return k * (self.omega * self.dt), w, np.zeros(k.shape)
        w1, w2, D, j = self.ramp
        t = (j + k) * self.dt
        s, ds, S = _smoothstep(t / D)
        after = np.maximum(t - D, 0.0)
        psi = w1 * np.minimum(t, D) + (w2 - w1) * D * S + w2 * after
        t0 = j * self.dt
        psi0 = w1 * min(t0, D) + (w2 - w1) * D * float(_smoothstep(np.array(t0 / D))[2]) \
            + w2 * max(t0 - D, 0.0)
        return psi - psi0, w1 + (w2 - w1) * s, (w2 - w1) / D * ds

    def next_cycle(self) -> PhaseSamples:
        """The steps of the next revolution (and the phase moves on past them)."""
        low = min(self.omega, self.frequency_now()) * self.dt
        guess = int(np.ceil((TWO_PI - self.phi) / low)) + 2
        adv, w, wd = self._advance(np.arange(guess + 1, dtype=float))
        phi = self.phi + adv
        n = int(np.argmax(phi >= TWO_PI - _EDGE * low))
        start = self.revolutions * TWO_PI + self.phi
        dphi = np.diff(phi[:n + 1])
        weight = None
        if self.ramp is not None or self.omega != self.omega0:
            weight = dphi / (self.omega0 * self.dt)
        out = PhaseSamples(phi[:n], dphi, w[:n], wd[:n], start, weight)
        nxt = phi[n] - TWO_PI
        self.phi = 0.0 if abs(nxt) < _EDGE * low else nxt
        self.revolutions += 1
        if self.ramp is not None:
            w1, w2, D, j = self.ramp
            self.ramp = None if (j + n) * self.dt >= D else (w1, w2, D, j + n)
        return out

    def state(self) -> np.ndarray:
        """Everything needed to continue exactly (for checkpoints)."""
        ramp = self.ramp or (0.0, 0.0, 0.0, -1)
        return np.array([self.phi, self.revolutions, self.omega, *ramp], dtype=float)

    def restore(self, state: np.ndarray) -> None:
        self.phi, self.omega = float(state[0]), float(state[2])
        self.revolutions = int(state[1])
        self.ramp = None if state[6] < 0 else (float(state[3]), float(state[4]),
                                               float(state[5]), int(state[6]))


def clock_cycle(period_s: float, dt: float) -> PhaseSamples:
    """The first cycle of a clock at period ``period_s`` [s] sampled every ``dt`` [s]: the
    thesis's cycle :math:`\\phi_k = 2\\pi k \\Delta t / T` when T is a whole number of steps."""
    return ClockPhase(period_s, dt).next_cycle()


class AdaptivePhase:
    r"""An adaptive-frequency oscillator (Righetti, Buchli & Ijspeert 2006) whose coupling is
    the error of an adaptive Fourier series of its input (Gams et al. 2009; Petrič et al. 2011):

    .. math::

        \dot\phi = \Omega - K e \sin\phi, \qquad \dot\Omega = -K e \sin\phi, \qquad
        e = y - \sum_{c=0}^{H} (a_c \cos c\phi + b_c \sin c\phi),

        \dot a_c = \eta\, e \cos c\phi, \qquad \dot b_c = \eta\, e \sin c\phi.

    :math:`\Omega` converges to the input's frequency and the series to the input's shape; once
    they have, :math:`e = 0` and the phase runs at :math:`\dot\phi = \Omega` without ripple.
    Integrated by the classical Runge-Kutta method over each control step, with the input
    linear between its samples at the step's ends (so the phase at a step uses the input
    measured at that step and before: causal).

    Args:
        period_s: Starting period :math:`2\pi/\Omega(0)` in [s].
        dt: Control step in [s].
        coupling: K in [1/(s · input unit)].
        learning_rate: :math:`\eta` in [1/s].
        harmonics: H, the series' highest harmonic.
    """

    def __init__(self, period_s: float, dt: float, coupling: float, learning_rate: float,
                 harmonics: int):
        self.dt, self.K, self.eta = float(dt), float(coupling), float(learning_rate)
        self.c = np.arange(harmonics + 1, dtype=float)
        self.omega0 = TWO_PI / float(period_s)
        self.s = np.zeros(2 + 2 * len(self.c))  # phi (unwrapped), Omega, a_0..a_H, b_0..b_H
        self.s[1] = self.omega0
        self.y = np.nan   # the input at the current step (nan: not measured yet)
        self.steps = 0    # steps since the start of the run

    def _rhs(self, s: np.ndarray, y: float) -> np.ndarray:
        phi, c, H = s[0], self.c, len(self.c)
        cos, sin = np.cos(c * phi), np.sin(c * phi)
        e = y - s[2:2 + H] @ cos - s[2 + H:] @ sin
        pull = self.K * e * np.sin(phi)
        return np.concatenate([[s[1] - pull, -pull], self.eta * e * cos, self.eta * e * sin])

    def measure(self, y: float) -> None:
        """Take the input at the current step (the first call starts the oscillator)."""
        self.y = float(y)

    def advance(self, y_next: float) -> None:
        """Integrate over one control step to the next, whose input is ``y_next``."""
        h, y0, y1 = self.dt, self.y, float(y_next)
        ym = 0.5 * (y0 + y1)
        s = self.s
        k1 = self._rhs(s, y0)
        k2 = self._rhs(s + 0.5 * h * k1, ym)
        k3 = self._rhs(s + 0.5 * h * k2, ym)
        k4 = self._rhs(s + h * k3, y1)
        self.s = s + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        self.y = y1
        self.steps += 1

    @property
    def phase(self) -> float:
        """Unwrapped phase at the current step [rad]."""
        return float(self.s[0])

    @property
    def frequency(self) -> float:
        """:math:`\\Omega` at the current step in [rad/s]."""
        return float(self.s[1])

    def rates(self) -> tuple[float, float]:
        """:math:`\\dot\\phi` and :math:`\\dot\\Omega` at the current step (the RMPs' time
        derivatives use them: :math:`\\dot q_d = \\dot\\phi q'`, :math:`\\ddot q_d =
        \\dot\\phi^2 q'' + \\dot\\Omega q'`)."""
        d = self._rhs(self.s, self.y)
        return float(d[0]), float(d[1])

    def state(self) -> np.ndarray:
        return np.concatenate([self.s, [self.y, self.steps]])

    def restore(self, state: np.ndarray) -> None:
        self.s = np.array(state[:-2], dtype=float)
        self.y, self.steps = float(state[-2]), int(state[-1])


__all__ = ["AdaptivePhase", "ClockPhase", "PhaseSamples", "clock_cycle"]
