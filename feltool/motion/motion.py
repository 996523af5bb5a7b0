r"""The forward motion of one seed while it runs: the phase its RMPs share, the motion events
(period, amplitude, goal) and the transients those leave.

The phase is a :class:`~feltool.motion.phase.ClockPhase` or, with ``primitives.phase: adaptive``, an
:class:`~feltool.motion.phase.AdaptivePhase` driven step by step by its input signal
(:meth:`Motion.run_adaptive_cycle`). A period event changes the clock's frequency smoothly.

An amplitude or goal event changes θ at the start of a cycle: the forcing term is
:math:`r\psi^\top w`, so a new amplitude factor scales the joint's weights by
:math:`r_{new}/r_{old}`; a new goal replaces g. The RMP's state :math:`y_s = Y(\phi_s)\theta_{old}`
carries on from where it was and settles on the new limit cycle through the transformation
system, exactly: :math:`y(\phi) = Y(\phi)\theta + e^{A(\phi - \phi_s)}\,\delta` with
:math:`\delta = Y(\phi_s)(\theta_{old} - \theta)` (:meth:`PrimitiveSet.desired`), so
:math:`q_d` and :math:`\dot q_d` do not jump. The transient does not depend on the θ learned
afterwards, so it adds nothing to the learner's Jacobian; it is dropped once below 1e-15.

A seed's motion is part of its checkpoint (:meth:`Motion.state`), so a resumed run is
bit-identical.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from feltool.config.experiment import ExperimentConfig
from feltool.control.closed_loop import CycleLog
from feltool.errors import ConfigError
from feltool.motion.phase import TWO_PI, AdaptivePhase, ClockPhase, PhaseSamples
from feltool.motion.rmp import exp2

if TYPE_CHECKING:
    from feltool.control.closed_loop import ClosedLoop
    from feltool.dynamics.interface import Dynamics
    from feltool.motion.rmp import PrimitiveSet

#: An adaptive phase that has not completed a revolution within this many nominal periods
#: stops the seed.
MAX_PERIODS_PER_CYCLE = 10


class Motion:
    """One seed's phase, motion events and RMP transients.

    Args:
        config: The experiment's config (its period, rate, phase and motion events).
        primitives: The experiment's RMPs.
        joints: Joint names in velocity-index order.
        model: The known model (an oscillator's frame input).
        dynamics: The known model's dynamics (the adaptive cycle's feedforward).
        continuous: The RMP states run on by themselves (per-step learning): amplitude and
            goal events then need no transient.
    """

    def __init__(self, config: ExperimentConfig, primitives: PrimitiveSet, joints: list[str],
                 model: pin.Model, dynamics: Dynamics, continuous: bool = False):
        cfg = config
        self.config, self.joints, self.dynamics = config, joints, dynamics
        self.continuous = continuous
        self.prims = primitives
        self.clock = ClockPhase(cfg.period_s, cfg.dt)
        self.oscillator = None
        if cfg.primitives.phase == "adaptive":
            o = cfg.primitives.oscillator
            self.oscillator = AdaptivePhase(cfg.period_s, cfg.dt, o.coupling, o.learning_rate,
                                            o.harmonics)
            self._measure = oscillator_input(cfg, joints, model)
        self.transients: dict[int, tuple[np.ndarray, float]] = {}
        self.amplitude = {i: p.amplitude for i, p in self.prims.primitives.items()}

    # -- the phase -------------------------------------------------------------------------------
    @property
    def adaptive(self) -> bool:
        return self.oscillator is not None

    def next_cycle(self) -> PhaseSamples:
        """The steps of the next revolution of a clock phase."""
        return self.clock.next_cycle()

    def phase_now(self) -> float:
        """The phase of the next step, counted from the start of the run, in [rad]."""
        if self.adaptive:
            return self.oscillator.phase
        return self.clock.revolutions * TWO_PI + self.clock.phi

    # -- events --------------------------------------------------------------------------------
    def apply_events(self, cycle: int, theta: np.ndarray) -> np.ndarray:
        """θ at the start of learning cycle ``cycle`` after its motion events (and the clock
        set to any new period)."""
        events = [ev for _, ev in self.config.motion_events if ev.cycle == cycle]
        if not events:
            return theta
        before, theta = theta, theta.copy()
        joints = self.joints
        for ev in events:
            if ev.period_s is not None:
                self.clock.change_period(ev.period_s, ev.transition_cycles)
            for name, r in (ev.amplitude or {}).items():
                i = joints.index(name)
                sl = self.prims.slices[i]
                theta[sl.start:sl.stop - 1] *= r / self.amplitude[i]
                self.amplitude[i] = r
            for name, g in (ev.goal or {}).items():
                theta[self.prims.slices[joints.index(name)].stop - 1] = g
        if not self.continuous:
            self._start_transients(before, theta)
        return theta

    def _start_transients(self, before: np.ndarray, after: np.ndarray) -> None:
        phi_s = self.phase_now()
        for i, prim in self.prims.primitives.items():
            sl = self.prims.slices[i]
            if np.array_equal(before[sl], after[sl]):
                continue
            delta = prim.state_rows(phi_s % TWO_PI) @ (before[sl] - after[sl])
            if i in self.transients:  # an earlier transient still decaying: carried over
                y0, phi0 = self.transients[i]
                delta = delta + exp2(prim.A_phase, phi_s - phi0) @ y0
            self.transients[i] = (delta, phi_s)

    def end_cycle(self) -> None:
        """Drop the transients that have decayed below 1e-15 (at the next step's phase)."""
        now = self.phase_now()
        for i in list(self.transients):
            y0, phi0 = self.transients[i]
            if np.abs(exp2(self.prims.primitives[i].A_phase, now - phi0) @ y0).max() < 1e-15:
                del self.transients[i]

    def desired(self, theta: np.ndarray, cycle: PhaseSamples
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:math:`q_d, \\dot q_d, \\ddot q_d` at the steps of ``cycle`` (each ``(n, nv)``)."""
        return self.prims.desired(theta, cycle, self.transients)

    # -- the adaptive phase's cycle, step by step -------------------------------------------------
    def run_adaptive_cycle(self, loop: ClosedLoop, q: np.ndarray, v: np.ndarray,
                           theta: np.ndarray):
        """One revolution of the adaptive phase through ``loop``: at each step the oscillator's
        phase sets the desired trajectory, the known model's RNEA the feedforward, the law the
        feedback; after the step the input is measured and the oscillator advanced. Returns
        ``(log, cycle, (Qd, Vd, Ad), stalled)``; ``stalled`` says why the revolution did not
        end (None if it did)."""
        osc, dyn, law = self.oscillator, self.dynamics, loop.law
        dt = loop.dt
        if np.isnan(osc.y):  # the run's first step
            osc.measure(self._measure(q, osc.steps * dt))
        end = TWO_PI * (np.floor(osc.phase / TWO_PI + 1e-12) + 1)
        n_max = int(MAX_PERIODS_PER_CYCLE * self.config.period_s / dt)
        rows, stalled = [], None
        start = osc.phase
        for _ in range(n_max):
            phase = osc.phase
            if phase >= end:
                break
            rate, drift = osc.rates()
            step = PhaseSamples(np.array([phase - end + TWO_PI]), np.zeros(1), np.array([rate]),
                                np.array([drift]), phase)
            qd, vd, ad = (x[0] for x in self.desired(theta, step))
            r, rd = law.references(qd[None], vd[None])
            u_fb, u_rows, u_err = law.terms(q, v, r[0], rd[0], loop.error_rows)
            tau = loop.actuated * (dyn.inverse(qd, vd, ad) + u_fb)
            rows.append((q, v, u_fb, u_rows, u_err, tau, qd, vd, ad, phase, rate, drift))
            q, v = loop.advance(q, v, tau)
            osc.advance(self._measure(q, osc.steps * dt + dt))
        else:
            stalled = (f"the adaptive phase did not complete a revolution within "
                       f"{MAX_PERIODS_PER_CYCLE} nominal periods (its frequency is "
                       f"{osc.frequency:.4g} rad/s)")
        Q, V, U, Urows, Uerr, Tau, Qd, Vd, Ad, Ph, W, Wd = (np.array(c) for c in zip(*rows))
        dphi = np.diff(np.append(Ph, osc.phase))
        cycle = PhaseSamples(Ph - end + TWO_PI, dphi, W, Wd, start,
                             dphi / (self.clock.omega0 * dt))
        log = CycleLog(Q, V, U, q, v, Urows, Uerr)
        if loop.limits is not None and Q.shape[1] == V.shape[1]:
            log.limit_hits = loop.limits.hits(Q, Tau)
        return log, cycle, (Qd, Vd, Ad), stalled

    # -- checkpoints ------------------------------------------------------------------------------
    def state(self) -> dict[str, np.ndarray]:
        """The arrays a checkpoint needs to continue the motion exactly."""
        keys = sorted(self.transients)
        out = {"motion_clock": self.clock.state(),
               "motion_amplitude": np.array([self.amplitude[i] for i in sorted(self.amplitude)]),
               "motion_transient_keys": np.array(keys, dtype=int),
               "motion_transient_y": np.array([self.transients[i][0] for i in keys]).reshape(-1, 2),
               "motion_transient_phase": np.array([self.transients[i][1] for i in keys])}
        if self.adaptive:
            out["motion_oscillator"] = self.oscillator.state()
        return out

    def restore(self, saved: dict) -> None:
        if "motion_clock" not in saved:
            return
        self.clock.restore(saved["motion_clock"])
        self.amplitude = dict(zip(sorted(self.amplitude), map(float, saved["motion_amplitude"])))
        self.transients = {int(i): (np.array(y), float(p)) for i, y, p in zip(
            saved["motion_transient_keys"], saved["motion_transient_y"],
            saved["motion_transient_phase"])}
        if self.adaptive:
            self.oscillator.restore(saved["motion_oscillator"])


def oscillator_input(cfg: ExperimentConfig, joints: list[str], model: pin.Model):
    """``(q, t) -> y``: the adaptive oscillator's input at the state ``q`` and time ``t`` [s]
    (``primitives.oscillator.input``: a joint's angle [rad], a frame's height [m] or an
    external signal)."""
    src = cfg.primitives.oscillator.input
    if src.joint is not None:
        i = joints.index(src.joint)
        return lambda q, t: float(q[i])
    if src.frame is not None:
        data, fid = model.createData(), model.getFrameId(src.frame)

        def height(q, t):
            pin.forwardKinematics(model, data, q)
            return float(pin.updateFramePlacement(model, data, fid).translation[2])

        return height
    e = src.external
    terms = [(1, e.amplitude, e.phase)] + [(k, a, p) for k, (a, p) in
                                            enumerate(e.harmonics, start=2)]
    w = TWO_PI * e.frequency_hz
    return lambda q, t: e.mean + sum(a * np.sin(k * w * t + p) for k, a, p in terms)


def motion_problems(cfg: ExperimentConfig, joints: list[str], model: pin.Model,
                    fixed: set[str]) -> list[tuple[str, str]]:
    """What the phase and the motion events of ``cfg`` need from the experiment: joints with an
    RMP, a clock for period events, a joint or frame that exists for the oscillator's input
    (``(yaml path, message)`` pairs)."""
    problems = []
    for i, ev in cfg.motion_events:
        for key in ("amplitude", "goal"):
            for name in getattr(ev, key) or {}:
                if name not in joints:
                    problems.append((f"events.{i}.{key}.{name}", f"'{name}' is not a "
                                     f"configured (unlocked) joint; joints: {', '.join(joints)}"))
                elif name in fixed:
                    problems.append((f"events.{i}.{key}.{name}", f"joint '{name}' follows its "
                                     "demonstration (follow_demo), not an RMP"))
        if ev.period_s is not None and cfg.primitives.phase != "clock":
            problems.append((f"events.{i}.period_s", "a period event sets the clock's "
                             f"frequency; primitives.phase is {cfg.primitives.phase}"))
    osc = cfg.primitives.oscillator
    if osc is not None:
        if osc.input.joint is not None and osc.input.joint not in joints:
            problems.append(("primitives.oscillator.input.joint", f"'{osc.input.joint}' is not "
                             f"a configured (unlocked) joint; joints: {', '.join(joints)}"))
        if osc.input.frame is not None and not model.existFrame(osc.input.frame):
            problems.append(("primitives.oscillator.input.frame", f"the robot has no frame "
                             f"'{osc.input.frame}'"))
    return problems


def varying_phase(cfg: ExperimentConfig) -> list[tuple[str, str]]:
    """The config's features that make cycles differ from the thesis's fixed cycle, as
    ``(yaml path, feature)`` (empty: every cycle is the nominal one)."""
    out = []
    if not cfg.whole_period:
        out.append(("period_s", f"a period of {cfg.period_s * cfg.sim.rate_hz:g} control steps "
                                "(not a whole number)"))
    if cfg.primitives.phase == "adaptive":
        out.append(("primitives.phase", "the adaptive phase"))
    names = {"period_s": "a period event", "amplitude": "an amplitude event",
             "goal": "a goal event"}
    for i, ev in cfg.motion_events:
        key = next(k for k in names if getattr(ev, k) is not None)
        out.append((f"events.{i}.{key}", names[key]))
    return out


def refuse_varying_phase(cfg: ExperimentConfig, engine: str, source: str | None) -> None:
    """Raise :class:`ConfigError` naming each feature of :func:`varying_phase` when ``engine``
    runs only the thesis's fixed cycle."""
    problems = [(where, f"{engine} runs the fixed cycle of a whole-sample clock; {what} needs "
                        "backend pinocchio or casadi with trajectory FEL")
                for where, what in varying_phase(cfg)]
    if problems:
        raise ConfigError(problems, source)


__all__ = ["Motion", "motion_problems", "oscillator_input", "refuse_varying_phase", "varying_phase"]
