r"""The closed loop of a legged robot standing on its feet, pushed: the controller at the control
rate, the plant's stance dynamics (:class:`~feltool.walking.legged.contact.LeggedContact`, the
feet held where they stand) integrated by classical Runge-Kutta over ``substeps`` sub-steps of
each control step (torque held, the push a force on the base the controller does not know),
the feet put back on their anchors after every sub-step, and every contact check of
:mod:`feltool.walking.legged.checks` at every sub-step: a violation stops the rollout with the
reason (*not walking*).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from feltool.walking.checks import ContactChecks, NotWalking
from feltool.walking.legged.checks import LeggedStats, check_air, check_stance, check_torques
from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.control import StandingController
from feltool.walking.legged.events import (
    LIFT_OFF_WINDOW,
    check_release,
    lingering,
    tipping,
    touchdown,
)
from feltool.walking.legged.model import LeggedModel
from feltool.walking.legged.sole import distribute


@dataclass
class Push:
    """A push on the base: ``force`` [N] (world axes, at the base's origin) and ``torque``
    [N m] from ``start`` [s] for ``duration`` [s]."""

    start: float = 0.2
    duration: float = 0.1
    force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    torque: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def active(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration

    @classmethod
    def random(cls, rng: np.random.Generator, duration: float, force: float) -> Push:
        """A 0.1 s horizontal push of ``force`` [N] in a random direction at a random time
        between 10 % and 90 % of ``duration`` [s]."""
        angle = rng.uniform(0.0, 2 * np.pi)
        when = rng.uniform(0.1, 0.9) * duration
        return cls(when, 0.1, force=(force * np.cos(angle), force * np.sin(angle), 0.0))


def random_start(legged: LeggedModel, rng: np.random.Generator, scale: float = 1.0
                 ) -> np.ndarray:
    """A random start velocity ``(nv,)``: the base's linear ``0.05`` [m/s], angular ``0.2``
    [rad/s] and the joints' ``0.2`` [rad/s], each times ``scale`` times a standard normal draw
    (:func:`stand` projects it onto the feet on the ground)."""
    v0 = np.zeros(legged.nv)
    v0[:3] = 0.05 * scale * rng.standard_normal(3)
    v0[3:6] = 0.2 * scale * rng.standard_normal(3)
    v0[6:] = 0.2 * scale * rng.standard_normal(legged.nv - 6)
    return v0


@dataclass
class StandLog:
    """A standing rollout, per control step.

    Attributes:
        t: Times [s] ``(n,)``; ``q`` ``(n, nq)``, ``v`` ``(n, nv)`` the states at them.
        u: Motor torques ``(n, k)`` [N m].
        forces: Ground forces at the start of each control step ``(n, n_feet, 3)`` [N] (NaN
            for a foot in the air).
        height: Base height [m]; ``roll``, ``pitch`` [rad] (of the base's rotation, ZYX).
        stats: The contact physics seen.
        not_walking: The reason the rollout stopped, or None; ``kind`` its kind.
        touchdowns: ``(time [s], feet)`` of each touchdown.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    forces: np.ndarray
    height: np.ndarray
    roll: np.ndarray
    pitch: np.ndarray
    stats: LeggedStats = field(default_factory=LeggedStats)
    not_walking: str | None = None
    kind: str | None = None
    touchdowns: list = field(default_factory=list)
    end: StandState | None = None


def lowest_swing_apex(legged: LeggedModel, log: StandLog) -> float:
    """The lowest apex [m] among the finished swings of ``log`` (a foot in the air from one
    control step to its touchdown): every foot that stepped lifted at least this high (inf:
    no swing finished)."""
    heights = np.array([legged.foot_positions(x)[:, 2] for x in log.q])
    air = np.isnan(log.forces[:, :, 2])
    apex = np.inf
    for j in range(air.shape[1]):
        edges = np.flatnonzero(np.diff(np.r_[0, air[:, j].astype(int), 0]))
        for a, b in zip(edges[::2], edges[1::2]):
            if b < len(log.t):
                apex = min(apex, float(heights[a:b, j].max()))
    return apex


class _Stop(Exception):
    """Ends a rollout at a touchdown (``until_touchdown``)."""


@dataclass
class StandState:
    """Where a rollout is, to resume it (:func:`stand`'s ``start``, :attr:`StandLog.end`).

    Attributes:
        t: Time [s] (a control step's).
        q, v: The state ``(nq,)``, ``(nv,)``.
        stance: The feet on the ground.
        anchors: ``{foot: (3,)}`` where each stance foot is held [m].
        carry: An impact window reaching into this control step [s].
        lingering: ``{foot: time released [s]}`` of the released feet still on the ground.
    """

    t: float
    q: np.ndarray
    v: np.ndarray
    stance: tuple[str, ...]
    anchors: dict
    carry: float = 0.0
    lingering: dict = field(default_factory=dict)


def stand(legged: LeggedModel, controller: StandingController, q0: np.ndarray,
          v0: np.ndarray | None = None, duration: float = 2.0, rate_hz: float = 1000.0,
          substeps: int = 1, checks: ContactChecks | None = None, push: Push | None = None,
          plant: pin.Model | None = None,
          schedule: Callable[[float], tuple[str, ...]] | None = None,
          on_touchdown: Callable[[float, tuple[str, ...]], None] | None = None,
          impact_window: float = 0.0, start: StandState | None = None,
          until: Callable[[float], bool] | None = None,
          until_touchdown: Callable[[float], bool] | None = None) -> StandLog:
    """Roll the robot out on its feet for ``duration`` [s].

    Args:
        legged: The robot.
        controller: Its controller (the known model is ``legged.model``).
        q0, v0: The start state (every foot on the ground; they are held where they are).
        duration: In [s].
        rate_hz: Control rate [Hz].
        substeps: Runge-Kutta sub-steps per control step.
        checks: The contact checks (default: ``ContactChecks(effort=legged.effort)``).
        push: A push on the base (the plant feels it, the controller does not).
        plant: The plant's model when it differs from the known one (same joints and frames),
            or ``t [s] ->`` that model (None: the known one), asked at every control step: a
            world that changes during the rollout (a payload put on at an event).
        schedule: ``t [s] ->`` the feet meant to be in stance (default: all, always). A foot it
            drops is released (:func:`~feltool.walking.legged.events.check_release`); a foot it
            names that is in the air joins the stance at its touchdown
            (:func:`~feltool.walking.legged.events.touchdown`), recorded in
            :attr:`StandLog.touchdowns`.
        on_touchdown: Called with ``(time [s], landed feet)`` at each touchdown; the schedule
            is asked again at once, the stance feet it no longer names are released there (an
            event-driven gait's switch), and the controller is called again for the new stance
            (the contact event triggers a control update; its torques hold until the next one).
        impact_window: Resolve each touchdown's impact over a Moreau-Jean step of this length
            [s] (the stance feet's loads act in it), 0 for the instantaneous impact.
        start: Resume from this state (:attr:`StandLog.end` of an earlier rollout, or one
            made for it) instead of ``q0``, ``v0`` at t = 0 on every foot; ``duration`` counts
            from its time.
        until: ``t [s] -> bool``, asked after every control step: True ends the rollout there
            (its :attr:`StandLog.end` is the state at ``t``).
        until_touchdown: ``t [s] -> bool``, asked at each touchdown once ``on_touchdown`` has
            run: True ends the rollout at the touchdown, just after its impact and before the
            control update (:attr:`StandLog.end` has the stance the impact left; resumed, the
            feet the schedule no longer wants are released at once).
    """
    chk = ContactChecks(effort=legged.effort) if checks is None else checks
    worlds: dict = {}

    def world(t: float) -> LeggedContact:
        model = plant(t) if callable(plant) else plant
        if id(model) not in worlds:
            worlds[id(model)] = (model, LeggedContact(legged, model))
        return worlds[id(model)][1]

    t_start = 0.0 if start is None else float(start.t)
    contact = world(t_start)
    names = list(legged.feet)
    if start is None:
        stance = tuple(names)
        pos0 = contact.positions(q0)
        anchor = dict(zip(names, pos0))
        q, v = contact.hold(np.array(q0, float), np.zeros(legged.nv) if v0 is None
                            else np.array(v0, float), stance, pos0)
    else:
        stance, anchor = tuple(start.stance), {f: np.array(p) for f, p in start.anchors.items()}
        q, v = np.array(start.q, float), np.array(start.v, float)
    B, dt = legged.selection(), 1.0 / rate_hz
    h = dt / substeps
    n = int(round(duration * rate_hz))
    st = LeggedStats()
    rec = {key: [] for key in ("t", "q", "v", "u", "forces")}
    touchdowns: list = []
    reason = kind = None

    def external(qq, t):
        if push is None or not push.active(t):
            return np.zeros(legged.nv)
        pin.computeJointJacobians(contact.model, contact.data, qq)
        Jb = pin.getJointJacobian(contact.model, contact.data, 1, pin.LOCAL_WORLD_ALIGNED)
        return Jb.T @ np.r_[push.force, push.torque]

    since = {} if start is None else dict(start.lingering)  # released feet still down [s]

    def release(contact, q, v, tau, kept, released, t):
        """The plant's stance: the ``kept`` feet and the released ones still held (each
        within :data:`LIFT_OFF_WINDOW` of its release, else :func:`check_release` reports
        it); the controller has let them go."""
        stay = lingering(contact, q, v, tau, kept, released)
        for f in [f for f in since if f not in stay]:
            del since[f]
        late = [f for f in stay if t - since.setdefault(f, t) > LIFT_OFF_WINDOW]
        if late:
            check_release(contact, q, v, tau, kept, tuple(late))
        return tuple(f for f in names if f in kept or f in stay)

    # an impact's window reaching past its sub-step, taken from the next one
    carry = 0.0 if start is None else start.carry
    section = None
    t = t_start
    try:
        for i in range(n):
            t = t_start + i * dt
            contact = world(t)
            wanted = stance if schedule is None else \
                tuple(f for f in names if f in schedule(t))
            released = tuple(f for f in stance if f not in wanted)
            stance = tuple(f for f in stance if f in wanted)
            alloc = controller(q, v, stance, t)
            u = check_torques(chk, st, alloc.u, legged.motors)
            tau = B @ u
            stance = release(contact, q, v, tau + external(q, t), stance, released, t)
            start = (q, v)
            recorded = False
            for s in range(substeps):
                done, carry = carry, 0.0
                while h - done > 1e-12:
                    ts = t + s * h + done

                    def forcing(qq, offset, ts=ts, tau=tau):
                        return tau + external(qq, ts + offset)

                    stance = tipping(contact, q, v, forcing(q, 0.0), stance)
                    q, v, f1, landed, used, after = touchdown(contact, chk, st, q, v, forcing,
                                                              h - done, stance, wanted,
                                                              impact_window)
                    if stance and contact.redundant(stance):  # a sole: any distribution
                        f1 = distribute([contact.link(f) for f in stance],
                                        np.array([anchor[f] for f in stance]), f1,
                                        chk.friction, max(0.0, chk.normal_force_min))
                    if stance:
                        check_stance(chk, st, stance, f1)
                    if not recorded:
                        recorded = True
                        full = np.full((len(names), 3), np.nan)
                        for f, fv in zip(stance, f1):
                            full[names.index(f)] = fv
                        for key, val in (("t", t), ("q", start[0]), ("v", start[1]), ("u", u),
                                         ("forces", full)):
                            rec[key].append(np.copy(val))
                    if landed:
                        stance = tuple(f for f in names if f in after)
                        pos = contact.positions(q)
                        for f in (f for f in landed if f in stance):
                            anchor[f] = pos[names.index(f)] * [1.0, 1.0, 0.0]  # on z = 0
                        # the landed feet put on the ground while every foot down is held
                        q, v = contact.hold(q, v, stance, np.array([anchor[f] for f in stance]))
                        touchdowns.append((ts + used, landed))
                        if on_touchdown is not None and schedule is not None:
                            on_touchdown(ts + used, landed)
                            if until_touchdown is not None and until_touchdown(ts + used):
                                section = StandState(ts + used, q, v, stance,
                                                     {f: anchor[f] for f in stance},
                                                     lingering=dict(since))
                                raise _Stop
                            wanted = tuple(f for f in names if f in schedule(ts + used))
                            gone = tuple(f for f in stance if f not in wanted)
                            stance = tuple(f for f in stance if f in wanted)
                            # the contact event triggers a control update for the new stance
                            u = check_torques(chk, st, controller(q, v, stance, ts + used).u,
                                              legged.motors)
                            tau = B @ u
                            stance = release(contact, q, v, tau + external(q, ts + used),
                                             stance, gone, ts + used)
                    done = done + used if landed else h
                    q, v = contact.hold(q, v, stance, np.array([anchor[f] for f in stance]))
                    air = tuple(f for f in names if f not in stance)
                    if air:
                        check_air(chk, st, air,
                                  contact.positions(q)[[names.index(f) for f in air], 2])
                carry = max(0.0, done - h)
            if not np.all(np.isfinite(q)) or not np.all(np.isfinite(v)):
                raise NotWalking(f"the state is not finite at t = {t:.4g} s", "diverged")
            t = t_start + (i + 1) * dt
            if until is not None and until(t):
                break
    except _Stop:
        pass
    except NotWalking as exc:
        reason, kind = str(exc), exc.kind
    Q = np.array(rec["q"]).reshape(-1, legged.nq)
    rpy = np.array([pin.rpy.matrixToRpy(pin.XYZQUATToSE3(x[:7]).rotation) for x in Q]
                   ).reshape(-1, 3)
    return StandLog(t=np.array(rec["t"]), q=Q, v=np.array(rec["v"]), u=np.array(rec["u"]),
                    forces=np.array(rec["forces"]), height=Q[:, 2], roll=rpy[:, 0],
                    pitch=rpy[:, 1], stats=st, not_walking=reason, kind=kind,
                    touchdowns=touchdowns,
                    end=None if reason else section or StandState(
                        t, q, v, stance, {f: anchor[f] for f in stance}, carry, dict(since)))
