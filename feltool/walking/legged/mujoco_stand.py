r"""The legged loop of :func:`~feltool.walking.legged.stand.stand` with MuJoCo as the plant
(issue 32: "the same on MuJoCo as the plant").

The controller is the same (:class:`~feltool.walking.legged.control.StandingController`,
:class:`~feltool.walking.legged.trot.TrotController`), called at the control rate with the
measured state in Pinocchio's coordinates and the stance feet; only the world differs. Every
sub-step is one MuJoCo step (:class:`~feltool.walking.legged.mujoco_plant.LeggedMujoco`: the
known model built in MuJoCo, soft contacts, an elliptic friction cone) under the held torques
and the push, and what the rigid loop computes from its constraints is read from MuJoCo's
contacts (``mj_contactForce``):

* **stance**: the feet the schedule wants that are on the floor. A stance foot stays in it
  while its point is below :data:`LIFT_OFF_HYSTERESIS` (a soft contact at nanometre depth
  flickers; the stance does not). A stance foot rising above it within :data:`IMPACT_WINDOW`
  of a touchdown has been lifted by the impact (the rigid loop's unilateral impact lets such
  a foot leave; counted in ``impacts_released``), at any other time it pulled on the floor
  (not walking, kind ``normal_force``);
* **touchdown**: a wanted foot in the air whose point reaches the floor (z <= 0) at the end of
  a MuJoCo step. As in ``stand()``: recorded, ``on_touchdown(t, landed)`` called, the schedule
  asked again, the stance feet it no longer names released, and the controller called again
  for the new stance (its torques hold for the rest of the control step);
* **normal force**: each stance foot's normal force, its mean over the last
  :data:`NORMAL_FORCE_WINDOW` (once it has stood that long: a landing foot's force builds up
  from zero), must stay above ``max(0, normal_force_min)`` (kind ``normal_force``); the
  friction ratio :math:`\|f_t\|/f_n` of that mean is recorded. Points of one link (a sole's
  corners) are checked as the rigid loop checks them (:func:`~feltool.walking.legged.sole
  .distribute`): their means replaced, when one of them pulls or leaves its cone, by any
  distribution of the link's wrench that pushes inside the cones, when there is one;
* **slip**: a stance foot's horizontal travel since it joined the stance stays below
  :data:`SLIP_TOL` (MuJoCo's cone lets a foot slide where the rigid loop would report the
  friction ratio; kind ``friction``);
* **penetration**: no foot deeper in the floor than :data:`MAX_DEPTH` (kind ``clearance``), and
  a foot in the air that has left the floor not below it by more than ``clearance_tol``;
* **lift-off**: a released foot leaves the floor (its point above the hysteresis) within
  :data:`LIFT_OFF_WINDOW` (kind ``lift_off``);
* **torques** within ``legged.effort`` (``check_torques``: report, or clip and count), and the
  base's **roll and pitch** within ``max_tilt`` (kind ``tilt``).

A touchdown's impulse is the landing foot's force integrated over the :data:`IMPACT_WINDOW`
after it; its ratio :math:`\|\iota_t\|/\iota_n` is ``max_impulse_ratio`` (recorded, not
checked: the slip check sees a sliding foot). ``energy_lost`` is not measured (0).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin

from feltool.errors import ConfigError
from feltool.walking.checks import ContactChecks, NotWalking
from feltool.walking.legged.checks import LeggedStats, check_torques
from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.control import StandingController
from feltool.walking.legged.events import LIFT_OFF_WINDOW
from feltool.walking.legged.model import LeggedModel, Payload
from feltool.walking.legged.mujoco_plant import LeggedMujoco
from feltool.walking.legged.sole import distribute
from feltool.walking.legged.stand import Push, StandLog

LIFT_OFF_HYSTERESIS = 0.0002  #: a foot point this high [m] has left the floor
MAX_DEPTH = 0.002             #: deepest a foot may sink into the floor [m]
SLIP_TOL = 0.002              #: largest stance-foot travel [m] before it is sliding
IMPACT_WINDOW = 0.01          #: a touchdown's soft impact lasts this [s]
NORMAL_FORCE_WINDOW = 0.005   #: a stance foot's normal force checked is its mean over this [s]


class _Feet:
    """The feet's contact bookkeeping across MuJoCo steps (module doc)."""

    def __init__(self, names: list[str], h: float, stance: tuple[str, ...], points: np.ndarray,
                 links: list[int]):
        self.names, self.h, self.links = names, h, links
        self.soles = len(set(links)) < len(links)  # several points on one link
        self.n_window = max(1, int(round(NORMAL_FORCE_WINDOW / h)))
        self.stance = tuple(stance)
        self.anchor = {f: points[i, :2].copy() for i, f in enumerate(names)}
        self.window: dict[str, list[np.ndarray]] = {f: [] for f in names}
        self.released: dict[str, float] = {}   # released foot -> time [s], until it lifts
        self.impacts: list[list] = []          # [foot, impulse (3,), time left [s]]
        self.last_touchdown = -np.inf

    def join(self, foot: str, point: np.ndarray) -> None:
        self.anchor[foot] = point[:2].copy()
        self.window[foot] = []
        self.released.pop(foot, None)

    def release(self, feet: tuple[str, ...], t: float) -> None:
        for f in feet:
            self.released[f] = t
            self.window[f] = []


def stand_mujoco(legged: LeggedModel, controller: StandingController, q0: np.ndarray,
                 v0: np.ndarray | None = None, duration: float = 2.0,
                 rate_hz: float = 1000.0, substeps: int = 2,
                 checks: ContactChecks | None = None, push: Push | None = None,
                 schedule: Callable[[float], tuple[str, ...]] | None = None,
                 on_touchdown: Callable[[float, tuple[str, ...]], None] | None = None,
                 payload: Payload | None = None, plant: LeggedMujoco | None = None,
                 max_tilt: float = 0.5, payload_from: Callable[[float], bool] | None = None,
                 until: Callable[[float], bool] | None = None,
                 **mujoco_options) -> StandLog:
    """Roll the robot out for ``duration`` [s] with MuJoCo as the plant; the contract and the
    log of :func:`~feltool.walking.legged.stand.stand` (module doc for the checks).

    Args:
        legged: The robot (the known model is ``legged.model``).
        controller: Its controller, ``controller(q, v, stance, t).u`` the motor torques [N m].
        q0, v0: The start state, every foot on the ground (``v0`` projected onto the feet's
            contacts, as ``stand()`` does).
        duration: In [s].
        rate_hz: Control rate [Hz].
        substeps: MuJoCo steps per control step (timestep ``1 / (rate_hz * substeps)``).
        checks: The contact checks (default ``ContactChecks(effort=legged.effort)``; its
            ``friction`` is MuJoCo's :math:`\\mu`).
        push: A push on the base (the plant feels it, the controller does not).
        schedule: ``t [s] ->`` the feet meant to be in stance (default all, always).
        on_touchdown: Called with ``(time [s], landed feet)`` at each touchdown (``stand()``).
        payload: A point mass on the base in MuJoCo (the unknown world), or None.
        plant: A compiled plant to use (else one is compiled with ``payload`` and
            ``mujoco_options``, e.g. ``timeconst``, ``dampratio``, ``integrator``).
        max_tilt: Largest |roll| and |pitch| of the base [rad] (kind ``tilt``).
        payload_from: ``t [s] -> bool``: the ``payload`` is on the base (and the plant's
            ``gravity``, a slope, among ``mujoco_options``, acts) only from the first control
            step at which it is True (a world that changes; default: from the start).
        until: ``t [s] -> bool``, asked after every control step: True ends the rollout
            (as :func:`~feltool.walking.legged.stand.stand`'s).
    """
    chk = ContactChecks(effort=legged.effort) if checks is None else checks
    dt = 1.0 / rate_hz
    h = dt / substeps
    if plant is None:
        plant = LeggedMujoco(legged, timestep=h, friction=chk.friction, payload=payload,
                             **mujoco_options)
    elif abs(plant.model.opt.timestep - h) > 1e-15:
        raise ConfigError([("plant", f"its timestep {plant.model.opt.timestep} s is not "
                                     f"1 / (rate_hz * substeps) = {h} s")])
    carrying = payload_from is None
    if not carrying:
        plant.carry(False)
    names = list(legged.feet)
    contact = LeggedContact(legged)
    stance = tuple(names)
    q, v = contact.hold(np.array(q0, float), np.zeros(legged.nv) if v0 is None
                        else np.array(v0, float), stance, contact.positions(q0))
    plant.set_state(q, v)
    feet = _Feet(names, h, stance, plant.foot_points(), [contact.link(f) for f in names])
    n = int(round(duration * rate_hz))
    st = LeggedStats()
    rec = {key: [] for key in ("t", "q", "v", "u", "forces")}
    touchdowns: list = []
    reason = kind = None

    def qfrc(u, ts):
        if push is None or not push.active(ts):
            return plant.generalized(u)
        return plant.generalized(u, push.force, push.torque)

    try:
        for i in range(n):
            t = i * dt
            if not carrying and payload_from(t):
                plant.carry(carrying := True)
            q, v = plant.state()
            _tilt(q, max_tilt)
            wanted = tuple(names) if schedule is None else \
                tuple(f for f in names if f in schedule(t))
            gone = tuple(f for f in feet.stance if f not in wanted)
            feet.stance = tuple(f for f in feet.stance if f in wanted)
            feet.release(gone, t)
            u = check_torques(chk, st, controller(q, v, feet.stance, t).u, legged.motors)
            start = (q, v, u)
            for s in range(substeps):
                ts = t + s * h
                plant.step(qfrc(u, ts))
                forces, depths = plant.foot_contacts()
                if s == 0:
                    full = np.full((len(names), 3), np.nan)
                    for f in feet.stance:
                        full[names.index(f)] = forces[names.index(f)]
                    for key, val in zip(("t", "q", "v", "u", "forces"), (t,) + start + (full,)):
                        rec[key].append(np.copy(val))
                landed = _check(chk, st, feet, plant.foot_points(), forces, depths, wanted,
                                ts + h)
                if not landed:
                    continue
                touchdowns.append((ts + h, landed))
                if on_touchdown is not None and schedule is not None:
                    on_touchdown(ts + h, landed)
                    wanted = tuple(f for f in names if f in schedule(ts + h))
                    gone = tuple(f for f in feet.stance if f not in wanted)
                    feet.stance = tuple(f for f in feet.stance if f in wanted)
                    feet.release(gone, ts + h)
                    # the contact event triggers a control update for the new stance
                    qs, vs = plant.state()
                    u = check_torques(chk, st, controller(qs, vs, feet.stance, ts + h).u,
                                      legged.motors)
            if not np.all(np.isfinite(plant.data.qpos)) or \
                    not np.all(np.isfinite(plant.data.qvel)):
                raise NotWalking(f"the state is not finite at t = {t:.4g} s", "diverged")
            if until is not None and until(t + dt):
                break
    except NotWalking as exc:
        reason, kind = str(exc), exc.kind
    Q = np.array(rec["q"]).reshape(-1, legged.nq)
    rpy = np.array([pin.rpy.matrixToRpy(pin.XYZQUATToSE3(x[:7]).rotation) for x in Q]
                   ).reshape(-1, 3)
    return StandLog(t=np.array(rec["t"]), q=Q, v=np.array(rec["v"]).reshape(-1, legged.nv),
                    u=np.array(rec["u"]).reshape(len(Q), -1),
                    forces=np.array(rec["forces"]).reshape(len(Q), len(names), 3),
                    height=Q[:, 2], roll=rpy[:, 0], pitch=rpy[:, 1], stats=st,
                    not_walking=reason, kind=kind, touchdowns=touchdowns)


def _tilt(q: np.ndarray, max_tilt: float) -> None:
    roll, pitch, _ = pin.rpy.matrixToRpy(pin.XYZQUATToSE3(q[:7]).rotation)
    if max(abs(roll), abs(pitch)) > max_tilt:
        raise NotWalking(f"the base tilts over: roll {roll:.3g} rad, pitch {pitch:.3g} rad "
                         f"(more than {max_tilt:g} rad)", "tilt")


def _check(chk: ContactChecks, st: LeggedStats, feet: _Feet, points: np.ndarray,
           forces: np.ndarray, depths: np.ndarray, wanted: tuple[str, ...],
           t: float) -> tuple[str, ...]:
    """The checks after one MuJoCo step ending at ``t`` [s] (module doc); the feet that touched
    down (they join ``feet.stance``)."""
    names, h = feet.names, feet.h
    deepest = int(np.argmax(depths))
    if depths[deepest] > MAX_DEPTH:
        raise NotWalking(f"the foot {names[deepest]} is {depths[deepest] * 1e3:.3g} mm deep in "
                         f"MuJoCo's floor (more than {MAX_DEPTH * 1e3:g} mm: the soft contact "
                         "gives way)", "clearance")
    for imp in feet.impacts:  # the touchdowns' impulses, over IMPACT_WINDOW
        imp[1] += forces[names.index(imp[0])] * h
        imp[2] -= h
        if imp[2] <= 1e-12 and imp[1][2] > 0:
            st.max_impulse_ratio = max(st.max_impulse_ratio,
                                       float(np.hypot(*imp[1][:2]) / imp[1][2]))
    feet.impacts = [imp for imp in feet.impacts if imp[2] > 1e-12]
    floor = max(0.0, chk.normal_force_min)
    for f in feet.stance:
        k = names.index(f)
        if points[k, 2] > LIFT_OFF_HYSTERESIS:
            if t - feet.last_touchdown <= IMPACT_WINDOW + 1e-12:
                st.impacts_released += 1
                feet.stance = tuple(g for g in feet.stance if g != f)
                feet.release((f,), t)
                continue
            raise NotWalking(f"the stance foot {f} lifted {points[k, 2] * 1e3:.3g} mm off "
                             f"MuJoCo's floor at t = {t:.4f} s (it pulled on it)",
                             "normal_force")
        slip = float(np.hypot(*(points[k, :2] - feet.anchor[f])))
        if slip > SLIP_TOL:
            raise NotWalking(f"the stance foot {f} slid {slip * 1e3:.3g} mm in MuJoCo at "
                             f"t = {t:.4f} s (walking.friction = {chk.friction}; more than "
                             f"{SLIP_TOL * 1e3:g} mm is sliding)", "friction")
        win = feet.window[f]
        win.append(forces[k])
        if len(win) > feet.n_window:
            win.pop(0)
    held = [k for k, f in enumerate(names) if f in feet.stance
            and len(feet.window[f]) == feet.n_window]
    means = np.array([np.mean(feet.window[names[k]], axis=0) for k in held]).reshape(-1, 3)
    if feet.soles:  # points of one link (a sole's corners): any distribution of their wrench
        means = distribute([feet.links[k] for k in held], points[held], means, chk.friction,
                           floor)
    for k, (fx, fy, fz) in zip(held, means, strict=True):
        st.min_normal_force = min(st.min_normal_force, float(fz))
        if not fz > floor:
            raise NotWalking(f"the stance foot {names[k]} would pull on the ground: MuJoCo's "
                             f"normal force {fz:.4g} N (mean over {NORMAL_FORCE_WINDOW * 1e3:g} "
                             f"ms) at t = {t:.4f} s (walking.normal_force_min = "
                             f"{chk.normal_force_min} N)", "normal_force")
        st.max_friction_ratio = max(st.max_friction_ratio, float(np.hypot(fx, fy) / fz))
    for f, since in list(feet.released.items()):
        k = names.index(f)
        if points[k, 2] > LIFT_OFF_HYSTERESIS:
            del feet.released[f]
        elif t - since > LIFT_OFF_WINDOW:
            raise NotWalking(f"the foot {f}, released at t = {since:.4f} s, does not leave "
                             f"MuJoCo's floor within {LIFT_OFF_WINDOW:g} s", "lift_off")
    landed = []
    for k, f in enumerate(names):
        if f in feet.stance:
            continue
        if f in wanted and points[k, 2] <= 0.0:
            landed.append(f)
        elif f not in feet.released:  # in the air, and it has left the floor
            st.min_clearance = min(st.min_clearance, float(points[k, 2]))
            if points[k, 2] < -chk.clearance_tol:
                raise NotWalking(f"the foot {f} is {-points[k, 2] * 1e3:.3g} mm below the "
                                 f"ground while in the air at t = {t:.4f} s (walking."
                                 f"clearance_tol_m = {chk.clearance_tol})", "clearance")
    for f in landed:
        feet.join(f, points[names.index(f)])
        feet.impacts.append([f, forces[names.index(f)] * h, IMPACT_WINDOW - h])
    if landed:
        feet.stance = tuple(f for f in names if f in feet.stance or f in landed)
        feet.last_touchdown = t
    return tuple(landed)
