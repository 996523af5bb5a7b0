r"""A trot to start from (issue 32's "documented simpler start"): the feet's trajectories from a
phase per diagonal pair, the joints' desired motion by inverse kinematics of the base's desired
pose and the feet's, and the whole-body inverse dynamics of
:class:`~feltool.walking.legged.control.StandingController` (RNEA on the desired motion plus
feedback, allocated by its QP under the stance pair) in the closed loop of
:func:`~feltool.walking.legged.stand.stand` (every contact check on).

**Phase.** The diagonal pairs ``(FL, HR)`` and ``(FR, HL)`` alternate, each swing planned to
last ``period / 2`` [s]. The switch is an event, not a clock: the schedule wants the swinging
pair back from ``catch`` of its swing on, and the touchdown of the second of its feet (each
located, a unilateral impact; the first one down shares the stance with the old pair until
then) makes it the stance pair and releases the other at once
(:meth:`TrotGait.touchdown`, ``stand(on_touchdown=)``), so a foot never waits on the ground for a
clock, and the old stance pair is not asked to stay down after the impact.

**Base.** The desired base moves forward at a speed ramped from 0 to ``speed`` [m/s] over
``ramp`` [s] (a smoothstep), at its standing height, level, heading along x; its feedback adds a
horizontal PD (``horizontal`` gains) to the standing controller's height, roll, pitch and yaw
rate.

**Swing foot.** From where it left the ground to the target
:math:`p_1 = p_{hip}(t_1) + \tfrac{T_{st}}{2} \dot x_d + k_r (\dot x - \dot x_d)`
(Raibert's rule: the nominal foot under the desired hip at the touchdown time :math:`t_1`, half
a stance's travel ahead, corrected by the base's velocity error, ``raibert`` [s]), chosen when
the foot lifts off; horizontally a quintic smoothstep done at ``0.8`` of the swing; vertically
a :math:`\sin^2` up to ``step_height`` [m] at 0.4 (it accelerates up from the start, so the
released foot lifts off) and a quintic down that reaches ``-sink`` [m] at
the swing's end moving down at ``landing_speed`` [m/s] (so it lands gently, a little before
the end). Its last ``approach_height`` [m] is a straight line at that velocity, so a foot that
lands a little early still lands along it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from feltool.walking.legged.control import StandingController
from feltool.walking.legged.model import inverse_kinematics

#: The diagonal pairs of a quadruped's feet named FL, FR, HL, HR
PAIRS = (("FL", "HR"), ("FR", "HL"))


@dataclass
class TrotGait:
    """The trot's timing and shape.

    Attributes:
        speed: Forward speed after the ramp [m/s].
        period: One cycle, both pairs stepping once [s].
        ramp: Time to reach ``speed`` [s] (after ``start``).
        start: Time standing on four feet before the first step [s].
        step_height: Swing foot's apex above the ground [m].
        sink: How far below the ground the swing target ends [m].
        landing_speed: The swing target's downward speed at its end [m/s].
        raibert: Raibert's gain on the base's velocity error [s].
        approach_height: The last height above the ground [m] the swing target covers in a
            straight line at the landing velocity (an early touchdown still lands along it).
        catch: Fraction of a swing after which the foot is wanted back on the ground [-].
    """

    speed: float = 0.3
    period: float = 0.3
    ramp: float = 1.0
    start: float = 0.1
    step_height: float = 0.04
    sink: float = 0.003
    landing_speed: float = 0.2
    raibert: float = 0.03
    approach_height: float = 0.005
    catch: float = 0.2
    #: fraction of a swing at which its target reaches the ground (then goes on down) [-]
    land: float = 0.9
    #: feet of the swinging group down that make it the stance group (None: all of them; a
    #: sole's corners: three, a support triangle, the last one landing after the switch)
    switch_after: int | None = None
    #: the two groups of feet that step in turn (a quadruped's diagonal pairs; a biped's soles)
    groups: tuple[tuple[str, ...], tuple[str, ...]] = PAIRS
    #: the desired horizontal motion is the centre of mass's (the base is placed under it by
    #: the inverse kinematics), not the base's
    steer_com: bool = False

    def lateral(self, t: float) -> tuple[float, float]:
        """The base's desired sideways offset [m] and its rate [m/s] at ``t`` [s] (none for a
        trot: its diagonal support line runs under the base)."""
        return 0.0, 0.0

    def base_x(self, t: float) -> tuple[float, float, float]:
        """Desired forward position [m], speed [m/s] and acceleration [m/s^2] at ``t`` [s]."""
        s = np.clip((t - self.start) / self.ramp, 0.0, 1.0)
        if t <= self.start:
            return 0.0, 0.0, 0.0
        if s < 1.0:  # the speed follows a smoothstep 3s^2 - 2s^3
            x = self.speed * self.ramp * (s ** 3 - s ** 4 / 2)
            return x, self.speed * (3 * s ** 2 - 2 * s ** 3), \
                self.speed * (6 * s - 6 * s ** 2) / self.ramp
        return self.speed * (self.ramp / 2 + (t - self.start - self.ramp)), self.speed, 0.0

    def __post_init__(self):
        self.reset()

    def reset(self) -> None:
        """Back to the start: standing, the second group (a trot's ``(FR, HL)``) to swing
        first."""
        self.swing = 1
        self.t_switch = self.start
        self.steps = 0
        self.t_cycle: float | None = None  # when the current cycle began (after the ramp)
        self.down: set[str] = set()

    def swinging(self, t: float) -> int | None:
        """Index in :attr:`groups` of the group in the air at ``t`` [s] (None standing)."""
        return None if t < self.start else self.swing

    def schedule(self, t: float) -> tuple[str, ...]:
        """The feet wanted on the ground at ``t`` [s]: the stance pair, and the swinging pair
        from ``catch`` of a swing (``period / 2``) after the last switch on."""
        g = self.groups
        if t < self.start:
            return g[0] + g[1]
        late = t - self.t_switch >= self.catch * self.period / 2
        return g[1 - self.swing] + (g[self.swing] if late else ())

    def touchdown(self, t: float, landed: tuple[str, ...]) -> None:
        """Feet landed at ``t`` [s]: once both feet of the swinging pair are down, it is the
        stance pair and the other one swings (released at once); until then the first one down
        shares the stance with the old pair."""
        if t < self.start:
            return
        self.down |= set(landed) & set(self.groups[self.swing])
        group = self.groups[self.swing]
        if len(self.down) >= (len(group) if self.switch_after is None else self.switch_after):
            self.swing = 1 - self.swing
            self.t_switch = t
            self.steps += 1
            self.down = set()
            if self.steps % 2 == 0 and t >= self.start + self.ramp:
                self.t_cycle = t  # the first group, (FL, HR), down: a cycle begins

    def cycle_time(self, t: float) -> float | None:
        """Time [s] since the current cycle began (the pair ``(FL, HR)``'s touchdown after the
        speed ramp), None before the first one."""
        return None if self.t_cycle is None else t - self.t_cycle


def _quintic(s: float) -> float:
    s = min(max(s, 0.0), 1.0)
    return s ** 3 * (10 - 15 * s + 6 * s ** 2)


def _hermite5(s: float, z0: float, z1: float, v1: float) -> float:
    """Quintic on ``s`` in [0, 1] from ``z0`` (zero slope and curvature) to ``z1`` with slope
    ``v1`` and zero curvature."""
    # basis: h(s) = z0 + (z1 - z0) * q(s) + v1 * r(s), q the smoothstep, r zero at both ends
    # with r'(0) = r''(0) = 0, r'(1) = 1, r''(1) = 0: r = -4 s^3 + 7 s^4 - 3 s^5
    r = -4 * s ** 3 + 7 * s ** 4 - 3 * s ** 5
    return z0 + (z1 - z0) * _quintic(s) + v1 * r


@dataclass
class TrotController(StandingController):
    """The whole-body trot controller: the standing controller's wanted force and QP on the
    trot's desired motion (joints by inverse kinematics of the desired base and feet), a
    horizontal PD on the base.

    Args (beyond :class:`StandingController`'s):
        gait: The trot.
        horizontal: ``(k [N/m], d [N s/m])`` on the base's horizontal position and velocity.
        swing_gains: ``(k [N/m], d [N s/m])`` of a Cartesian PD pulling each foot in the air
            to its target in the world (through its leg's joints, :math:`J^\\top F`), so it
            lands with the landing velocity although the base is not where it was meant to be.
    """

    gait: TrotGait = field(default_factory=TrotGait)
    #: a stance foot keeps at least this load [N] (the standing controller's 0.5 N left the
    #: foot about to be released so little friction over an impact window that the other
    #: pair's landing made it slip after 1e-3 perturbations of the state)
    normal_force_min: float = 2.0
    horizontal: tuple[float, float] = (100.0, 10.0)
    swing_gains: tuple[float, float] = (600.0, 20.0)
    #: the reference's correction by the time in the cycle (:mod:`.orbit`), or None
    correction: Callable | None = None
    #: called at the end of every control update with ``(t, q, v, feet, allocation)``
    observer: Callable | None = None

    def __post_init__(self):
        super().__post_init__()
        self.names = list(self.legged.feet)
        self.q_ref = np.array(self.q_d, float)
        base = pin.XYZQUATToSE3(self.q_ref[:7])
        P = self.legged.foot_positions(self.q_ref)
        self.offsets = P - base.translation  # nominal feet around the base, world axes
        self.com_ref = np.array(pin.centerOfMass(self.model, self.data, self.q_ref)[:2])
        self.lift = {f: P[i].copy() for i, f in enumerate(self.names)}
        self.target = {f: P[i].copy() for i, f in enumerate(self.names)}
        self.anchor = {f: P[i].copy() for i, f in enumerate(self.names)}
        self.approach = {f: np.zeros(3) for f in self.names}
        self.t_lift = {f: 0.0 for f in self.names}
        self.stepping = {f: False for f in self.names}
        self._stance = tuple(self.names)
        self._q_ik = self.q_ref.copy()
        self._t = 0.0
        P0 = np.array([self.anchor[f] for f in self.names])
        self.feet_d = (P0, np.zeros_like(P0))

    def _base(self, t: float) -> np.ndarray:
        b = self.q_ref[:7].copy()
        b[0] += self.gait.base_x(t)[0]
        b[1] += self.gait.lateral(t)[0]
        return b

    def _feet(self, t: float) -> np.ndarray:
        """The feet's desired positions ``(4, 3)`` [m] at ``t`` [s]: a stance foot where it
        stands, a foot in the air on its swing (by the time since it lifted off)."""
        g = self.gait
        P = np.array([self.anchor[f] for f in self.names])
        ts = g.period / 2
        for i, f in enumerate(self.names):
            if f in self._stance:
                continue
            p0, p1, d = self.lift[f], self.target[f], self.approach[f]
            tau = t - self.t_lift[f]
            if not self.stepping[f]:  # lifted by an impact while in stance: back down
                P[i] = p0 + d * tau
                continue
            # the last approach_height above the ground: a straight line along d
            t_c = g.land * ts - g.approach_height / -d[2]
            p_c = p1 + d * (t_c - g.land * ts)
            if tau >= t_c:
                P[i] = p_c + d * (tau - t_c)
                continue
            P[i, :2] = _hermite5(tau / t_c, p0[:2], p_c[:2], d[:2] * t_c)
            t_up = 0.4 * ts
            if tau < t_up:  # sin^2: it starts accelerating up at once
                P[i, 2] = p0[2] + (g.step_height - p0[2]) * np.sin(0.5 * np.pi * tau / t_up) ** 2
            else:
                P[i, 2] = _hermite5((tau - t_up) / (t_c - t_up), g.step_height, p_c[2],
                                    d[2] * (t_c - t_up))
        return P

    def pose(self, t: float) -> np.ndarray:
        """The desired configuration at ``t`` [s] (inverse kinematics, warm-started); with
        ``gait.steer_com`` the base shifted horizontally until the centre of mass is where the
        gait wants the base's origin to be, relative to the reference posture's (to 1e-9 m)."""
        base, feet = self._base(t), self._feet(t)
        q = inverse_kinematics(self.legged, base, feet, self._q_ik, iterations=10)
        if not self.gait.steer_com:
            return q
        goal = self.com_ref + base[:2] - self.q_ref[:2]
        for _ in range(5):
            miss = goal - pin.centerOfMass(self.model, self.data, q)[:2]
            if np.abs(miss).max() < 1e-9:
                break
            base[:2] += miss
            q = inverse_kinematics(self.legged, base, feet, q, iterations=10)
        return q

    def _landing_velocity(self, q: np.ndarray, i: int) -> np.ndarray:
        """The foot's velocity [m/s] to land with: down at ``landing_speed``, along
        :math:`G e_z`, :math:`G = J M^{-1} J^\\top` its inverse apparent inertia (known model),
        so that the impulse stopping it alone is vertical (no friction needed)."""
        m, d = self.model, self.data
        M = np.array(pin.crba(m, d, q))
        M = np.triu(M) + np.triu(M, 1).T
        J = self.contact.jacobian(q, (self.names[i],))
        G = J @ np.linalg.solve(M, J.T)
        return -self.gait.landing_speed * G[:, 2] / G[2, 2]

    def _update(self, q: np.ndarray, v: np.ndarray, stance: tuple[str, ...], t: float):
        """Follow the feet: a stance foot's anchor is where it is; a foot that just left the
        ground starts its swing there, towards its Raibert target (a foot the schedule keeps in
        stance, lifted by an impact, only goes back down)."""
        P = self.legged.foot_positions(q)
        g = self.gait
        wanted = g.schedule(t)
        sw = g.swinging(t)
        approach = {}
        for i, f in enumerate(self.names):
            if f not in stance:
                link = self.model.frames[self.legged.feet[f]].parentJoint
                approach.setdefault(link, []).append(self._landing_velocity(q, i))
        for i, f in enumerate(self.names):
            if f in stance:
                self.anchor[f] = P[i].copy()
                continue
            # points of one link (a sole's corners) share their approach, so the sole moves
            # as a rigid body
            self.approach[f] = np.mean(approach[self.model.frames[self.legged.feet[f]]
                                                .parentJoint], axis=0)
            if f not in self._stance:
                continue
            self.lift[f], self.t_lift[f] = P[i].copy(), t
            self.stepping[f] = sw is not None and f in g.groups[sw] and f not in wanted
            self.target[f] = self._aim(i, q, v, t) if self.stepping[f] else P[i].copy()
        self._stance = tuple(stance)

    def _aim(self, i: int, q: np.ndarray, v: np.ndarray, t: float) -> np.ndarray:
        """Foot ``i``'s Raibert target [m] for a swing lifting off at ``t`` [s] in the state
        ``(q, v)``."""
        g = self.gait
        xd, vd, _ = g.base_x(t + g.land * g.period / 2)
        vel = pin.XYZQUATToSE3(q[:7]).rotation @ v[:3]
        hip = self.q_ref[:3] + np.array([xd, 0.0, 0.0]) + self.offsets[i]
        aim = hip + np.array([vd, 0.0, 0.0]) * g.period / 4
        aim[:2] += g.raibert * (vel[:2] - np.array([g.base_x(t)[1], g.lateral(t)[1]]))
        return np.array([aim[0], aim[1], 0.0])

    def feedback(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The standing feedback plus a horizontal PD on the base (world axes; on the centre of
        mass with ``gait.steer_com``); a leg in the air follows its feet's targets in the world
        by the Cartesian PD and keeps only the
        damping of its joint PD (the joint stiffness, towards the inverse kinematics of the
        *desired* base, would push the foot into the ground whenever the base is lower than
        meant: with a 20 % payload the base sags 7 mm and the released foot accelerated into
        the ground at 8 m/s^2)."""
        out = super().feedback(q, v)
        g = self.gains
        dq = pin.difference(self.model, q, self.q_d)
        swing = sorted({i for foot in self.names if foot not in self._stance
                        for i in self.legged.leg(foot)})  # once per leg (a sole has 4 feet)
        out[swing] -= g.joints[0] * dq[swing]
        k, d = self.horizontal
        f = np.zeros(6)
        if self.gait.steer_com:  # the gait's motion is the centre of mass's: its error
            com = pin.centerOfMass(self.model, self.data, q, v)
            x, vx, _ = self.gait.base_x(self._t)
            y, vy = self.gait.lateral(self._t)
            f[:2] = k * (self.com_ref + [x, y] - com[:2]) + d * (np.array([vx, vy])
                                                                - self.data.vcom[0][:2])
        else:
            base = pin.XYZQUATToSE3(q[:7])
            goal = pin.XYZQUATToSE3(self.q_d[:7])
            lin, lin_d = base.rotation @ v[:3], goal.rotation @ self.v_d[:3]
            f[:2] = k * (goal.translation[:2] - base.translation[:2]) + d * (lin_d[:2] - lin[:2])
        pin.computeJointJacobians(self.model, self.data, q)
        Jb = pin.getJointJacobian(self.model, self.data, 1, pin.LOCAL_WORLD_ALIGNED)
        out += Jb.T @ f
        air = [f for f in self.names if f not in self._stance]
        if air:  # the feet in the air follow their targets in the world, not from the base
            kp, kd = self.swing_gains
            P, V = self.contact.foot_states(q, v)
            Pd, Vd = self.feet_d
            J = self.contact.jacobian(q, tuple(air))
            for k, foot in enumerate(air):
                i = self.names.index(foot)
                F = kp * (Pd[i] - P[i]) + kd * (Vd[i] - V[i])
                out[6:] += (J[3 * k:3 * k + 3].T @ F)[6:]
        return out

    def plan(self, t: float) -> tuple[np.ndarray, ...]:
        """The planned motion at ``t`` [s]: ``(q_d, v_d, a_d)`` of the joints by inverse
        kinematics of the desired base and feet (central differences of 0.1 ms) and the feet's
        targets ``(P_d, V_d)`` ``(4, 3)`` [m, m/s]."""
        e = 1e-4
        qm, qc, qp = self.pose(t - e), self.pose(t), self.pose(t + e)
        self._q_ik = qc
        m = self.model
        v_d = np.array(pin.difference(m, qm, qp)) / (2 * e)
        a_d = (np.array(pin.difference(m, qc, qp)) - np.array(pin.difference(m, qm, qc))) / e ** 2
        Pm, Pc, Pp = self._feet(t - e), self._feet(t), self._feet(t + e)
        return qc, v_d, a_d, Pc, (Pp - Pm) / (2 * e)

    def __call__(self, q: np.ndarray, v: np.ndarray, feet: tuple[str, ...], t: float = 0.0):
        self._update(q, v, tuple(feet), t)
        self._t = t
        self.planned = self.plan(t)
        q_d, v_d, a_d, P_d, V_d = self.planned
        tau = self.gait.cycle_time(t)
        if self.correction is not None and tau is not None:  # the acquired orbit (.orbit)
            dq, dv, da, dP, dV = self.correction(tau)
            q_d, v_d, a_d = pin.integrate(self.model, q_d, dq), v_d + dv, a_d + da
            P_d, V_d = P_d + dP, V_d + dV
        self.q_d, self.v_d, self.a_d, self.feet_d = q_d, v_d, a_d, (P_d, V_d)
        alloc = self.allocate(q, v, self.wanted(q, v), feet)
        if self.observer is not None:
            self.observer(t, q, v, tuple(feet), alloc)
        return alloc
