r"""A physical walker whose plant is MuJoCo (``plant: {simulator: mujoco}``).

The controller is the physical walker's (:class:`~feltool.walking.physical.PhysicalLoop`):
feedback from the measured state, feedforward from the known model's RNEA, the allocation onto
the motors with the stance foot held. Only the world differs: every sub-step is one MuJoCo step
(:mod:`feltool.robot.mujoco`) of the same URDF with MuJoCo's soft contacts, and what the rigid
walker computes from its constraint is read from MuJoCo's contacts (``mj_contactForce``):

* **forces**: the ground's force on each foot; the stance foot's ``(F_x, F_z)`` is logged; the
  ground's total normal force on the walker, its mean over :data:`NORMAL_FORCE_WINDOW`, must
  stay above ``walking.normal_force_min`` (and the step's friction ratio is that mean's; a soft contact near
  zero depth flickers: with a nearly straight stance leg its depth is nanometres, and a contact
  restarted at zero depth starts at zero force), except during the soft impact, the
  :data:`IMPACT_WINDOW` after a touchdown (the rigid walker checks the impulse there, not the
  force: while the landing foot's force builds up and the trailing foot's falls, their sum dips);
* **touchdown**: the swing foot, after it has lifted off, reaching the floor (its foot point at
  z <= 0, from above) ahead of the stance foot and outside ``walking.scuff_exempt_m``; the legs
  are then relabelled as in the rigid walker (the state the controller sees has the new
  stance foot at x = 0 where it touched down). Within the scuffing zone the swing foot passes
  through the floor (its sphere's collisions are off there), as in the rigid walker's rule;
* **lift-off**: the trailing foot must leave the floor (foot point above
  :data:`LIFT_OFF_HYSTERESIS`) within :data:`LIFT_OFF_WINDOW` of the touchdown; the stance foot
  rising above the hysteresis before the next touchdown is a lift-off too (not walking);
* **slip**: the stance foot's horizontal travel since its touchdown must stay below
  :data:`SLIP_TOL` (MuJoCo's friction cone lets a foot slide where the rigid walker would
  report the friction ratio: a sliding MuJoCo walker is not walking);
* **penetration**: no foot deeper in the floor than :data:`MAX_DEPTH` (a touchdown at 0.5 m/s
  sinks about 1 mm into the soft floor);
* the touchdown's impulse and energy lost: the landing foot's force integrated, and the
  kinetic energy's drop, over the impact's first :data:`IMPACT_WINDOW`.

Each violation ends the cycle as "not walking", with the reason and its kind.

**Observers**: :attr:`MujocoLoop.observers` are called after every MuJoCo step that passed the
checks with a :class:`MujocoStep` (the state, the torques, each foot's force, depth and
position, the touchdown): what a benchmark or test needs to watch inside a control step (e.g.
the trailing foot's force after a touchdown) without reaching into the loop's internals.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from feltool.robot.mujoco import MujocoPlant
from feltool.walking.checks import NotWalking, check_clearance
from feltool.walking.physical import PhysicalLoop, WalkLog

LIFT_OFF_HYSTERESIS = 0.0002  #: a foot point this high [m] has left the floor
LIFT_OFF_WINDOW = 0.05        #: the trailing foot leaves the floor within this [s]
MAX_DEPTH = 0.002             #: deepest a foot may sink into the floor [m]
SLIP_TOL = 0.002              #: largest stance-foot travel [m] before it is sliding
IMPACT_WINDOW = 0.01          #: the touchdown's soft impact lasts this [s]
NORMAL_FORCE_WINDOW = 0.005   #: the normal force checked is its mean over this [s]


@dataclass(frozen=True)
class MujocoStep:
    """One MuJoCo step of :class:`MujocoLoop`, as its observers see it. Feet are named by
    their labels after the step (at a touchdown the landing foot is already ``stance``), and
    positions are relative to the stance foot's touchdown point.

    Attributes:
        h: the step [s].
        q, v: the controller's state after the step (its labels) [m, rad; m/s, rad/s].
        tau: the generalized forces the controller commanded over the step, in its labels at
            the step's start [N, N m].
        stance_force, swing_force: the ground's force on each foot ``(F_x, F_y, F_z)`` [N].
        stance_depth, swing_depth: each foot's penetration into the floor [m] (0: no contact).
        stance_point, swing_point: each foot point ``(x, y, z)`` [m], x from the stance
            foot's touchdown point.
        touchdown: the swing foot touched down in this step (the labels are swapped).
        since_touchdown: time since the last touchdown [s] (inf before the first).
        trailing_lifted: the trailing foot has left the floor since the last touchdown.
    """

    h: float
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    stance_force: np.ndarray
    swing_force: np.ndarray
    stance_depth: float
    swing_depth: float
    stance_point: np.ndarray
    swing_point: np.ndarray
    touchdown: bool
    since_touchdown: float
    trailing_lifted: bool


class MujocoLoop(PhysicalLoop):
    """The physical walker's closed loop with MuJoCo as the plant (module doc).

    Args:
        loop: The rigid walker's loop of the same config (controller, walker, rates).
        sim: The walker's URDF compiled by MuJoCo with base, floor and feet, stepping by
            ``loop.dt / loop.substeps``.
        impact_sample: ``end``: after a touchdown MuJoCo steps on under the held torque until
            the landing foot has stopped (its vertical velocity >= 0, at most
            :data:`IMPACT_WINDOW`), and the controller's next sample is that post-impact
            state, as the rigid walker's instantaneous impact gives it; ``touchdown``: the
            next sample is at the foot's arrival, in the middle of the soft impact.

    Attributes:
        observers: callables ``f(step: MujocoStep) -> None`` called after every MuJoCo step
            that passed the contact checks (none by default; append to watch a run).
    """

    def __init__(self, loop: PhysicalLoop, sim: MujocoPlant, impact_sample: str = "end"):
        super().__init__(loop.known, loop.law, loop.walker, loop.dt, loop.substeps,
                         loop.error_rows)
        self.reference = loop.reference
        self.sim = sim
        self._R = loop.walker.walker.relabel_matrices()[1]
        self._R_inv_T = np.linalg.inv(self._R).T  # generalized forces: tau' = R^-T tau
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        if impact_sample not in ("end", "touchdown"):
            raise ValueError(f"impact_sample must be 'end' or 'touchdown', not {impact_sample!r}")
        self.impact_sample = impact_sample
        self.observers: list[Callable[[MujocoStep], None]] = []
        self._forces: dict = {}
        self.reset(np.zeros(sim.nq), np.zeros(len(sim.v_pin)))

    # -- the map between the controller's labels and MuJoCo's world -------------------------------
    def reset(self, q: np.ndarray, v: np.ndarray) -> None:
        """Put MuJoCo's walker at the controller's ``(q, v)`` (stance foot at x = 0, the labels
        the physical ones)."""
        W = self.walker
        self.sim.set_state(q, v)
        self._flip, self._x0 = False, 0.0
        self._lifted = self._gap(W.swing) > LIFT_OFF_HYSTERESIS
        self._since_td = np.inf if self._lifted else 0.0
        self._impact = None
        self._window: list[np.ndarray] = []  # the last NORMAL_FORCE_WINDOW's ground forces
        for foot in (W.stance, W.swing):
            self.sim.set_collides(foot, True)
        self._last = self._observe()

    def _physical(self, label: str) -> str:
        """The physical foot that is ``label`` (stance or swing) now."""
        W = self.walker
        if not self._flip:
            return label
        return W.swing if label == W.stance else W.stance

    def _gap(self, label: str) -> float:
        return float(self.sim.foot_point(self._physical(label))[2])

    def _observe(self) -> tuple[np.ndarray, np.ndarray]:
        """The controller's ``(q, v)`` of MuJoCo's state: relabelled, stance foot's touchdown
        point at x = 0."""
        q, v = self.sim.state()
        if self._flip:
            q, v = self.walker.walker.relabel(q, v)
        q[self.walker.base_q[0]] -= self._x0
        return q, v

    def run_cycle(self, plant, q: np.ndarray, v: np.ndarray, P: np.ndarray,
                  Pv: np.ndarray, Pa: np.ndarray) -> WalkLog:
        """One cycle (as :meth:`PhysicalLoop.run_cycle`) in MuJoCo's world: a state that is
        not the one the last cycle ended in restarts MuJoCo there. ``plant`` is ignored: the
        known model predicts (the inertial term), MuJoCo simulates."""
        last = self._last
        if last is None or not (np.array_equal(q, last[0]) and np.array_equal(v, last[1])):
            self.reset(q, v)
        return super().run_cycle(self.known, q, v, P, Pv, Pa)

    # -- one MuJoCo step with the contact events ----------------------------------------------------
    def _substep(self, contact, q, v, tau, h, steps, Force, k, finish: bool = True,
                 start=None):
        out = self._mujoco_step(contact, q, v, tau, h, steps, Force, k)
        if self.observers:
            self._notify(out, tau, h)
        if out[2] is None or self.impact_sample == "touchdown":
            return out
        # impact_sample "end": MuJoCo runs on through the soft impact under the held torque
        # (now in the new labels) until the landing foot has stopped; the time it takes is
        # counted in the touchdown's sub-step (the next control step starts after it)
        tau = self._R_inv_T @ tau if self._flip else self._R.T @ tau
        q1, v1, s = out
        while s < IMPACT_WINDOW - 1e-12 and \
                contact.foot_state(q1, v1, self.walker.stance)[1][1] < 0.0:
            q1, v1, _ = self._mujoco_step(contact, q1, v1, tau, h, steps, Force, k)
            s += h
            if self.observers:
                self._notify((q1, v1, None), tau, h)
        return q1, v1, s

    def _notify(self, out: tuple, tau: np.ndarray, h: float) -> None:
        """Hand the step just taken to every observer (:class:`MujocoStep`)."""
        W, touchdown = self.walker, out[2] is not None
        phys = {label: self._physical(label) for label in (W.stance, W.swing)}
        (F_st, d_st), (F_sw, d_sw) = (self._forces[phys[label]] for label in (W.stance, W.swing))
        shift = np.array([self._x0, 0.0, 0.0])
        step = MujocoStep(h, out[0].copy(), out[1].copy(), np.array(tau, float), F_st.copy(),
                          F_sw.copy(), float(d_st), float(d_sw),
                          self.sim.foot_point(phys[W.stance]) - shift,
                          self.sim.foot_point(phys[W.swing]) - shift, touchdown,
                          float(self._since_td), bool(self._lifted))
        for observer in self.observers:
            observer(step)

    def _mujoco_step(self, contact, q, v, tau, h, steps, Force, k):
        W, chk, sim, st = self.walker, self.walker.checks, self.sim, steps[-1]
        ke0 = contact.kinetic_energy(q, v)
        gap0 = self._gap(W.swing)
        sim.step(self._R.T @ tau if self._flip else tau)
        q1, v1 = self._observe()
        stance, swing = self._physical(W.stance), self._physical(W.swing)
        forces = self._forces = sim.foot_contacts()
        (F_st, d_st), (F_sw, d_sw) = forces[stance], forces[swing]
        Force[k] = F_st[[0, 2]]
        self._since_td += h
        if self._impact is not None:  # the last touchdown's impulse, over IMPACT_WINDOW
            stats, left, ke_before = self._impact
            stats.impulse += F_st[[0, 2]] * h
            if left - h <= 1e-12:
                Ix, Iz = stats.impulse
                stats.impulse_ratio = abs(Ix) / Iz if Iz > 0 else np.inf
                stats.energy_lost = ke_before - contact.kinetic_energy(q1, v1)
                self._impact = None
            else:
                self._impact = (stats, left - h, ke_before)
        # the ground's force on the walker, its mean over NORMAL_FORCE_WINDOW (a soft contact
        # near zero depth flickers), checked outside the soft impact
        self._window.append((F_st + F_sw)[[0, 2]])
        if len(self._window) > max(1, int(round(NORMAL_FORCE_WINDOW / h))):
            self._window.pop(0)
        Fx, Fz = np.mean(self._window, axis=0)
        if self._since_td >= IMPACT_WINDOW - 1e-12:
            st.min_normal_force = min(st.min_normal_force, float(Fz))
            if Fz > 0:
                st.max_friction_ratio = max(st.max_friction_ratio, abs(float(Fx)) / float(Fz))
            if Fz <= chk.normal_force_min:
                raise NotWalking(f"the ground's normal force on the walker is {Fz:.4g} N "
                                 f"(walking.normal_force_min = {chk.normal_force_min} N; "
                                 f"MuJoCo's contacts, mean over {NORMAL_FORCE_WINDOW * 1e3:g} "
                                 "ms)", "normal_force")
        depth = max(d_st, d_sw)
        if depth > MAX_DEPTH:
            raise NotWalking(f"a foot is {depth * 1e3:.3g} mm deep in MuJoCo's floor (more "
                             f"than {MAX_DEPTH * 1e3:g} mm: the soft contact gives way)",
                             "clearance")
        p_st, p_sw = sim.foot_point(stance), sim.foot_point(swing)
        slip = abs(p_st[0] - self._x0)
        if slip > SLIP_TOL:
            raise NotWalking(f"the stance foot slid {slip * 1e3:.3g} mm in MuJoCo (walking."
                             f"friction = {chk.friction}; more than {SLIP_TOL * 1e3:g} mm is "
                             "sliding)", "friction")
        if p_st[2] > LIFT_OFF_HYSTERESIS:
            raise NotWalking(f"the stance foot lifted {p_st[2] * 1e3:.3g} mm off MuJoCo's floor "
                             "before the swing foot touched down", "normal_force")
        self._last = (q1, v1)
        if not self._lifted:  # the trailing foot, after a touchdown
            if p_sw[2] > LIFT_OFF_HYSTERESIS:
                self._lifted = True
                st.trailing_vz = float(contact.foot_state(q1, v1, W.swing)[1][1])
            elif self._since_td > LIFT_OFF_WINDOW:
                raise NotWalking(f"the trailing foot does not lift off MuJoCo's floor within "
                                 f"{LIFT_OFF_WINDOW:g} s of the touchdown", "lift_off")
            return q1, v1, None
        ahead = p_sw[0] - self._x0
        exempt = abs(ahead) < chk.scuff_exempt
        # (the compass-gait convention: a knee-less swing leg passes the stance leg's foot)
        sim.set_collides(swing, not (exempt or (chk.scuff_behind and ahead <= 0.0)))
        landing = not exempt and ahead > 0.0 and gap0 > 0.0 and p_sw[2] <= 0.0
        if not landing:
            check_clearance(chk, st, float(p_sw[2]), float(ahead))
            return q1, v1, None
        # Touchdown: the swing foot is on the floor ahead; relabel (it becomes the stance foot).
        vz = float(contact.foot_state(q1, v1, W.swing)[1][1])
        st.touchdown_height = float(p_sw[2])
        st.min_clearance = min(st.min_clearance, max(float(p_sw[2]), 0.0))
        if vz >= 0.0:
            raise NotWalking("the swing foot reached the ground moving up", "touchdown")
        st.length = float(ahead)
        st.impulse, st.impulse_ratio, st.energy_lost = F_sw[[0, 2]] * h, 0.0, 0.0
        self._impact = (st, IMPACT_WINDOW - h, ke0)
        self._flip = not self._flip
        self._x0 = float(p_sw[0])
        self._lifted, self._since_td = False, 0.0
        sim.set_collides(stance, True)
        self._last = self._observe()
        return self._last[0], self._last[1], h
