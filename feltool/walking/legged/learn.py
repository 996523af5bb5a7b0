r"""Feedback error learning on the legged trot: a feedforward generalized force learned, cycle by
cycle, from the feedback the trot needs (Kawato's FEL, the thesis's section 2.3, on the gait's
rhythmic phase).

The trot's wanted generalized force (:class:`~feltool.walking.legged.trot.TrotController`) is
:math:`\tau_w = \mathrm{RNEA}(q_d, \dot q_d, \ddot q_d) + \tau_{ff}(\varphi) + u_{fb}`, which
the QP allocates to the motors under the stance feet. The learned term is a truncated Fourier
series in the gait's phase (the spectral form of an RMP's forcing,
:func:`feltool.motion.spectral.trig`), one per generalized coordinate (``nv``: the base's six
and every motor):

.. math:: \tau_{ff}(\varphi) = C^\top s(\varphi), \qquad
          s(\varphi) = (1, \cos\varphi, .., \cos M\varphi, \sin\varphi, .., \sin M\varphi).

The phase is the event-driven gait's own, :math:`\varphi = 2\pi (t - t_k) / T`, :math:`t_k`
the time the pair ``(FL, HR)`` completed its touchdown (a cycle is both pairs stepping once),
T the gait's period.

**Error.** Not the feedback itself but its part that moves the robot under the stance
contacts, :math:`e = M W u_{fb}` (:meth:`~feltool.walking.legged.control.StandingController
.effective`): the rest, :math:`J^\top\lambda`, the ground takes, and a feedforward learned
along it would change nothing but the contact forces and grow without end (the base's and the
stance legs' feedback pulling against each other through the feet, measured: a slow drift that
made a foot slip after about 20 cycles).

**Update.** At the end of each cycle the error's least-squares series over that cycle
(time-weighted: the event-triggered control updates make uneven steps) is moved into the
feedforward at the rate :math:`\eta` [-]:

.. math:: C \leftarrow C + \eta\, G^{-1} \int_{\text{cycle}} s\, e^\top\,dt, \qquad
          G = \int_{\text{cycle}} s s^\top\,dt,

FEL's gradient :math:`\int s\, e^\top dt` preconditioned by the basis's Gram matrix, so that
:math:`\eta` means the same at any control rate, period and number of harmonics: with
:math:`\eta = 1` the feedforward takes in one cycle the whole of the error the series can
represent.

**Harmonics.** The default is M = 0: the cycle's mean. FEL's plain gradient converges where
the loop gives a feedforward back with a lag under 90 degrees; the trot's base is held by PDs
whose natural frequencies (about 1 Hz horizontally, 1.4 Hz in height) are below the cycle's
3.7 Hz, so at the first harmonic and above it lags more than that, and learning them grew
the feedback (measured in docs/legged.md). The mean is what an unknown payload changes most:
its weight.

**Summed feedback.** A cycle's feedback is reported as the RMS over it of the feedback's share
of the motor torques, :math:`(B^\top W B)^+ B^\top W u_{fb}`
(:meth:`~feltool.walking.legged.control.StandingController.motor_share`), in [N m]: what the
motors spend on feedback.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from feltool.errors import InputError
from feltool.motion import spectral
from feltool.walking.legged.model import (
    LeggedModel,
    Payload,
    scaled_masses,
    sloped,
    with_payload,
)
from feltool.walking.legged.mujoco_stand import stand_mujoco
from feltool.walking.legged.orbit import ReferenceCorrection, acquire_orbit
from feltool.walking.legged.stand import StandLog, random_start, stand
from feltool.walking.legged.trot import TrotController, TrotGait


@dataclass
class PhaseFeedforward:
    r"""A generalized force ``(nv,)`` [N, N m] as a rhythmic function of the phase, a truncated
    Fourier series (the RMP forcing's spectral form, :func:`feltool.motion.spectral.trig`),
    learned by feedback error learning (module docstring).

    Args:
        harmonics: Highest harmonic M of the cycle (``2M + 1`` coefficients per coordinate).
        nv: Number of generalized coordinates.
        rate: Learning rate :math:`\eta` [-], in (0, 1].
    """

    harmonics: int
    nv: int
    rate: float = 0.5

    def __post_init__(self):
        if not 0.0 < self.rate <= 1.0:
            raise InputError(f"the learning rate {self.rate} is outside (0, 1]")
        if self.harmonics < 0:
            raise InputError(f"{self.harmonics} harmonics")
        M = self.harmonics
        self.C = np.zeros((2 * M + 1, self.nv))
        self.reset_cycle()

    def reset_cycle(self) -> None:
        """Forget the current cycle's samples."""
        n = 2 * self.harmonics + 1
        self._gram = np.zeros((n, n))
        self._cross = np.zeros((n, self.nv))
        self._sq = np.zeros(self.nv)
        self._time = 0.0

    def basis(self, phi: float) -> np.ndarray:
        r"""``(2M + 1,)``: :math:`(1, \cos\varphi, .., \cos M\varphi, \sin\varphi, ..)`."""
        return spectral.trig(phi, self.harmonics)[0]

    def __call__(self, phi: float) -> np.ndarray:
        r""":math:`\tau_{ff}(\varphi)` ``(nv,)`` [N, N m] at the phase ``phi`` [rad]."""
        return self.basis(phi) @ self.C

    def observe(self, phi: float, feedback: np.ndarray, dt: float) -> None:
        """Add the ``feedback`` ``(nv,)`` [N, N m] held for ``dt`` [s] at the phase ``phi``."""
        b = self.basis(phi)
        self._gram += dt * np.outer(b, b)
        self._cross += dt * np.outer(b, feedback)
        self._sq += dt * np.asarray(feedback) ** 2
        self._time += dt

    def update(self, learn: bool = True) -> np.ndarray:
        """End the cycle: move ``rate`` of the feedback's series into the feedforward's (if
        ``learn``); return the cycle's RMS feedback per coordinate ``(nv,)``."""
        rms = np.sqrt(self._sq / max(self._time, 1e-300))
        if learn and self._time > 0.0:
            n = 2 * self.harmonics + 1
            gram = self._gram + 1e-12 * np.trace(self._gram) * np.eye(n)
            self.C += self.rate * np.linalg.solve(gram, self._cross)
        self.reset_cycle()
        return rms


@dataclass
class LearningTrotController(TrotController):
    """The trot controller with a learned feedforward :math:`\\tau_{ff}(\\varphi)` (module
    docstring) and the cycle's bookkeeping.

    Cycles are counted from the first completed ``(FL, HR)`` touchdown after the speed ramp
    (cycle 0); each one ends at the next. The feedback of every control step is observed with
    the time it held, and at each cycle's end the feedforward is updated (from cycle
    ``learn_from`` on); the cycle's RMS error per coordinate is appended to
    :attr:`feedback_rms` and its summed feedback per motor to :attr:`share_rms`.

    Args (beyond :class:`TrotController`'s):
        learned: The learned feedforward (``None``: the mean, M = 0, at rate 0.5).
        learn_from: The first cycle whose feedback is learned from (a large number: never).
    """

    learned: PhaseFeedforward | None = None
    learn_from: int = 0
    #: per completed cycle: the error's RMS per generalized coordinate [N, N m]
    feedback_rms: list = field(default_factory=list, init=False)
    #: per completed cycle: the RMS of the feedback's share of the motor torques per motor
    share_rms: list = field(default_factory=list, init=False)
    #: per completed cycle: its start and end [s]
    cycle_times: list = field(default_factory=list, init=False)

    def __post_init__(self):
        super().__post_init__()
        if self.learned is None:
            self.learned = PhaseFeedforward(0, self.legged.nv)
        self.cycle = -1          # the cycle under way (-1: before the first)
        self._t_cycle = 0.0
        self._last: tuple | None = None  # t, phi, the error, the motor share
        self._phi = 0.0
        self._share_sq, self._share_time = 0.0, 0.0

    def _phase(self, t: float) -> float:
        return 2.0 * np.pi * (t - self._t_cycle) / self.gait.period

    def _bookkeeping(self, t: float) -> None:
        g = self.gait
        if self._last is not None and self.cycle >= 0:
            t0, phi0, fb0, share0 = self._last
            if t > t0:
                self.learned.observe(phi0, fb0, t - t0)
                self._share_sq += (t - t0) * share0 ** 2
                self._share_time += t - t0
        if g.t_cycle is not None and g.t_cycle != self._t_cycle:  # a cycle ends
            if self.cycle >= 0:
                self.feedback_rms.append(self.learned.update(self.cycle >= self.learn_from))
                self.share_rms.append(np.sqrt(self._share_sq / max(self._share_time, 1e-300)))
                self.cycle_times.append((self._t_cycle, g.t_cycle))
            self._share_sq, self._share_time = 0.0, 0.0
            self.cycle += 1
            self._t_cycle = g.t_cycle
        self._phi = self._phase(t)

    def feedforward(self) -> np.ndarray:
        """RNEA on the desired motion plus the learned :math:`\\tau_{ff}(\\varphi)` ``(nv,)``."""
        return super().feedforward() + self.learned(self._phi)

    def feedback(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        out = super().feedback(q, v)
        self._fb = out
        return out

    def __call__(self, q: np.ndarray, v: np.ndarray, feet: tuple[str, ...], t: float = 0.0):
        self._bookkeeping(t)
        alloc = super().__call__(q, v, feet, t)
        self._last = (t, self._phi, self.effective(self._fb), self.motor_share(self._fb))
        return alloc


def summed_feedback(shares) -> np.ndarray:
    """Each cycle's summed feedback [N m] from its motors' RMS feedback shares ``(cycles,
    motors)`` (module docstring): their Euclidean norm."""
    return np.sqrt((np.asarray(shares, float) ** 2).sum(axis=1))


@dataclass
class CycleFrames:
    """An observer of the learning trot's control updates (``TrotController.observer``) that
    hands every completed cycle to ``on_cycle(cycle, t, q, q_d, fb)``: the cycle's number (0:
    the first), its control updates' times ``(n,)`` [s], configurations and desired
    configurations ``(n, nq)``, and its summed feedback [N m] (as :func:`learn_trot` reports
    it). The updates before the first cycle (standing, the speed ramp) are not handed on."""

    controller: LearningTrotController
    on_cycle: Callable[[int, np.ndarray, np.ndarray, np.ndarray, float], None]

    def __post_init__(self):
        self._rows: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._done = 0

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray, feet, allocation) -> None:
        ctl = self.controller
        if len(ctl.share_rms) > self._done:  # this update began the next cycle
            self._done = len(ctl.share_rms)
            if self._rows:
                ts, qs, qds = (np.array(x) for x in zip(*self._rows, strict=True))
                self.on_cycle(self._done - 1, ts, qs, qds,
                              float(summed_feedback(ctl.share_rms[-1:])[0]))
            self._rows = []
        if ctl.cycle >= 0:
            self._rows.append((t, np.array(q, float), np.array(ctl.q_d, float)))


@dataclass
class TrotLearning:
    """A learning trot's outcome (:func:`learn_trot`).

    Attributes:
        feedback: Per completed cycle, the summed feedback: the RMS over the cycle of the norm
            of the feedback's share of the motor torques [N m].
        controller: The controller (its learned feedforward, per-motor records).
        log: The rollout (:class:`~feltool.walking.legged.stand.StandLog`).
        kind: Why it stopped early (a contact check's kind), or None.
        speed: Mean forward speed over the rollout's second half [m/s].
    """

    feedback: np.ndarray
    controller: LearningTrotController
    log: StandLog
    kind: str | None
    speed: float


def learn_trot(legged: LeggedModel, cycles: int = 150, payload: float = 0.2, change: int = 3,
               seed: int = 0, learn: bool = True, plant: str = "pinocchio",
               gait: TrotGait | None = None, rate_hz: float = 1000.0,
               impact_window: float = 1e-4, start_speed: float = 1.0,
               correction: ReferenceCorrection | None = None, acquire: int = 4,
               feedforward: PhaseFeedforward | None = None,
               controller: dict | None = None,
               slope: tuple[float, float] | None = None,
               mass_scale: float | None = None,
               on_cycle: Callable[[int, np.ndarray, np.ndarray, np.ndarray, float], None]
               | None = None) -> TrotLearning:
    """Trot ``cycles`` cycles learning the feedforward in a world the controller's model does
    not know from the start of cycle ``change`` on: the robot carrying a payload of
    ``payload`` times its mass on its base (a point mass at its origin,
    :class:`~feltool.walking.legged.model.Payload`; 0: none), with ``slope`` on a ground
    inclined by ``(angle, roll)`` [rad] (:func:`~feltool.walking.legged.model.sloped`), with
    ``mass_scale`` its bodies' masses and inertias that many times the model's
    (:func:`~feltool.walking.legged.model.scaled_masses`).

    Args:
        legged: The robot (its feet those of ``gait.groups``).
        seed: Seeds the start velocity: the base's linear velocity ``0.05``, angular ``0.2``,
            joints ``0.2`` times ``start_speed`` times standard normal draws [m/s, rad/s].
        learn: False: the same rollout without learning (the feedback it needs).
        plant: ``"pinocchio"`` (the rigid contact loop of :func:`stand`) or ``"mujoco"``
            (:func:`~feltool.walking.legged.mujoco_stand.stand_mujoco`, soft contacts; the
            impact window does not apply).
        gait: The trot (default :class:`TrotGait` ``()``).
        correction: The reference's correction acquired on the known model
            (:func:`~feltool.walking.legged.orbit.acquire_orbit`, the same for every seed:
            pass it to save its time); None: acquired here in ``acquire`` rounds (0: the plan
            as it is).
        feedforward: The learned feedforward to start from and learn into (its harmonics and
            rate; default ``PhaseFeedforward(0, nv)``: the cycle's mean at rate 0.5).
        controller: :class:`~feltool.walking.legged.trot.TrotController`'s other arguments
            (gains), for the acquisition and the learning alike (a biped's walk:
            :func:`~feltool.walking.legged.walk.biped_gains`).
        on_cycle: Called after every completed cycle with its control updates
            (:class:`CycleFrames`; the live viewer's hook).
    """
    if plant not in ("pinocchio", "mujoco"):
        raise InputError(f"plant {plant!r}: 'pinocchio' or 'mujoco'")
    gait = TrotGait() if gait is None else gait
    q0 = legged.standing()
    extra = dict(controller or {})
    if correction is None and acquire > 0:
        known = TrotController(legged, q0, gait=copy.deepcopy(gait), **extra)
        correction = acquire_orbit(legged, gait, rounds=acquire, impact_window=impact_window,
                                   rate_hz=rate_hz, controller=known).correction
    ctl = LearningTrotController(legged, q0, gait=copy.deepcopy(gait), correction=correction,
                                 learn_from=0 if learn else np.iinfo(np.int64).max,
                                 learned=feedforward, **extra)
    gait = ctl.gait
    if on_cycle is not None:
        ctl.observer = CycleFrames(ctl, on_cycle)
    load = None if payload == 0 else Payload(payload * legged.mass)
    world = legged if mass_scale is None else scaled_masses(legged, mass_scale)
    world = with_payload(world, load)  # the payload's mass: a fraction of the model's
    world = world if slope is None else sloped(world, *slope)
    v0 = random_start(legged, np.random.default_rng(seed), start_speed)
    duration = gait.start + gait.ramp + 2.0 * (cycles + 2) * gait.period
    common = dict(v0=v0, duration=duration, rate_hz=rate_hz, schedule=gait.schedule,
                  on_touchdown=gait.touchdown, until=lambda t: ctl.cycle >= cycles)
    if plant == "pinocchio":
        log = stand(legged, ctl, q0, impact_window=impact_window,
                    plant=lambda t: world.model if ctl.cycle >= change else None, **common)
    else:
        gravity = None if slope is None else world.model.gravity.linear
        changes = load is not None or slope is not None or mass_scale is not None
        log = stand_mujoco(legged, ctl, q0, payload=load, gravity=gravity, mass_scale=mass_scale,
                           payload_from=(lambda t: ctl.cycle >= change) if changes else None,
                           **common)
    fb = summed_feedback(np.array(ctl.share_rms).reshape(-1, legged.nv - 6))
    half = len(log.t) // 2
    speed = float((log.q[-1, 0] - log.q[half, 0]) / max(log.t[-1] - log.t[half], 1e-300)) \
        if len(log.t) > 1 else 0.0  # a rollout that stopped at its first control step
    return TrotLearning(fb, ctl, log, log.kind, speed)
