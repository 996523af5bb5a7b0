r"""Feet leaving and reaching the ground in the legged loop: a scheduled lift-off and a
touchdown located inside a sub-step.

- **Lift-off**: a foot the schedule takes out of stance is released; a unilateral contact keeps
  it on the ground while it would accelerate into it (its vertical classical acceleration in
  the dynamics without its contact below 0) and the ground pushes it (:func:`lingering`); it
  must leave within :data:`LIFT_OFF_WINDOW` (kind ``lift_off``, :func:`check_release`).
- **Touchdown**: a foot in the air that the schedule wants in stance, its height crossing
  :math:`z = 0` moving down within a sub-step, is located by Brent's method on the sub-step's
  length (to 1e-12 s); the rigid impact of the held feet plus it, with **unilateral** contacts
  (:func:`~feltool.walking.legged.impact.unilateral_impact`: a foot the ground would have to
  pull gets no impulse and leaves), is checked
  (:func:`~feltool.walking.legged.checks.check_impact`: the held feet's impulses push and stay
  in the cone, none slides, the feet leaving move up); the feet that keep an impulse are the
  stance after it, the landed ones anchored where they landed.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.optimize import brentq

from feltool.walking.checks import ContactChecks, NotWalking
from feltool.walking.legged.checks import LeggedStats, check_impact
from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.impact import unilateral_impact
from feltool.walking.legged.sole import distribute


def rk4(contact: LeggedContact, q: np.ndarray, v: np.ndarray, tau, h: float,
        feet: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One classical Runge-Kutta step of length ``h`` [s] with ``feet`` held, under the
    generalized force ``tau(q, t_offset)``: ``(q, v, forces at the start)``."""
    r1 = contact.stance(q, v, tau(q, 0.0), feet)
    a1 = r1.a
    v2 = v + 0.5 * h * a1
    q2 = pin.integrate(contact.model, q, 0.5 * h * v)
    a2 = contact.stance(q2, v2, tau(q2, 0.5 * h), feet).a
    v3 = v + 0.5 * h * a2
    q3 = pin.integrate(contact.model, q, 0.5 * h * v2)
    a3 = contact.stance(q3, v3, tau(q3, 0.5 * h), feet).a
    v4 = v + h * a3
    q4 = pin.integrate(contact.model, q, h * v3)
    a4 = contact.stance(q4, v4, tau(q4, h), feet).a
    return (pin.integrate(contact.model, q, h / 6 * (v + 2 * v2 + 2 * v3 + v4)),
            v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4), r1.forces)


def check_release(contact: LeggedContact, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
                  stance: tuple[str, ...], released: tuple[str, ...]) -> None:
    """The ``released`` feet, out of the contact set ``stance`` (the feet kept), accelerate up."""
    a = contact.stance(q, v, tau, stance).a
    J = contact.jacobian(q, released)
    acc = (J @ a + contact.drift(q, v, released)).reshape(-1, 3)
    for foot, az in zip(released, acc[:, 2]):
        if az < -1e-9:
            raise NotWalking(f"the foot {foot} does not lift off: released, it accelerates into "
                             f"the ground at {-az:.3g} m/s^2", "lift_off")


#: A foot reaching the ground slower than this [m/s] grazes it (a touchdown at rest)
GRAZING = 1e-6

#: A released foot leaves the ground within this [s] (else kind ``lift_off``), on the rigid
#: plant and on MuJoCo's floor (:mod:`~feltool.walking.legged.mujoco_stand`)
LIFT_OFF_WINDOW = 0.05


def lingering(contact: LeggedContact, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
              kept: tuple[str, ...], released: tuple[str, ...]) -> tuple[str, ...]:
    """The ``released`` feet that stay on the ground: a unilateral contact holds a foot until
    it accelerates up. Those that would accelerate into the ground without their contact
    (with the feet ``kept``) stay, as long as the ground pushes them (the one pulling hardest
    is let go, and the rest solved again): the lift-off's complementarity, by active set."""
    if not released:
        return ()
    a = contact.stance(q, v, tau, kept).a
    J = contact.jacobian(q, released)
    az = (J @ a + contact.drift(q, v, released))[2::3]
    stay = [f for f, z in zip(released, az) if z < -1e-9]
    names = list(contact.legged.feet)
    while stay:
        feet = tuple(f for f in names if f in kept or f in stay)
        fz = contact.stance(q, v, tau, feet).forces[:, 2]
        pull = {f: fz[feet.index(f)] for f in stay}
        worst = min(pull, key=pull.get)
        if pull[worst] >= 0.0:
            break
        stay.remove(worst)
    return tuple(stay)


def tipping(contact: LeggedContact, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
            stance: tuple[str, ...]) -> tuple[str, ...]:
    """The stance without the points of a link that lift off: when no distribution of a
    link's wrench over its stance points pushes on every one (:func:`~.sole.spread`: its
    centre of pressure outside their polygon), the point the least-norm forces pull on
    hardest is let go and the stance solved again -- a sole tipping onto an edge."""
    stance = tuple(stance)
    names = list(contact.legged.feet)
    while contact.redundant(stance):
        forces = contact.stance(q, v, tau, stance).forces
        links = [contact.link(f) for f in stance]
        pos = contact.positions(q)[[names.index(f) for f in stance]]
        spread_ = distribute(links, pos, forces, np.inf, 0.0)
        pulling = [i for i, f in enumerate(spread_) if f[2] <= 0.0 and links.count(links[i]) > 1]
        if not pulling:
            return stance
        worst = min(pulling, key=lambda i: forces[i, 2])
        stance = stance[:worst] + stance[worst + 1:]
    return stance


#: A sole whose first point lands with its other points within this of the ground [m], moving
#: down, lands flat: they land with it
FLAT_TOL = 1e-3


def flat_landing(contact: LeggedContact, q: np.ndarray, vel: np.ndarray,
                 landed: tuple[str, ...], air: list[str], stance: tuple[str, ...]
                 ) -> tuple[str, ...]:
    """The points landing with the first of a sole: the other wanted points in the air of a
    link none of whose points is in stance, within :data:`FLAT_TOL` [m] of the ground and
    moving down (``vel`` ``(n_feet, 3)`` [m/s]). A sole is flat to that tolerance when its
    first corner touches, and its impact is that of the whole sole (Pinocchio's 6D contact,
    to which the corners' impact is equal); :func:`~.stand.stand` puts its corners on the
    ground with the same projection that removes the integrator's drift."""
    if not landed:
        return ()
    names = list(contact.legged.feet)
    links = {contact.link(f) for f in landed} - {contact.link(f) for f in stance}
    z = contact.positions(q)[:, 2]
    return tuple(f for f in air if f not in landed and contact.link(f) in links
                 and z[names.index(f)] <= FLAT_TOL and vel[names.index(f), 2] < 0.0)


def touchdown(contact: LeggedContact, chk: ContactChecks, st: LeggedStats, q, v, tau,
              h: float, stance: tuple[str, ...], wanted: tuple[str, ...],
              window: float = 0.0):
    """One sub-step of length ``h`` with the feet ``stance`` held, ending at the first touchdown
    of a ``wanted`` foot in the air: ``(q, v, forces, landed feet, the time it took [s], the
    stance after it)``; the velocities are after the impact when a foot landed, and the stance
    after it is the feet that kept an impulse (``stance`` when none landed). ``window`` [s]
    resolves the impact over a Moreau-Jean step of that length
    (:func:`~feltool.walking.legged.impact.unilateral_impact`), the configuration advanced by
    it and the time it took included (it may reach past the sub-step)."""
    names = list(contact.legged.feet)
    air = [f for f in wanted if f not in stance]
    q1, v1, forces = rk4(contact, q, v, tau, h, stance)
    if not air:
        return q1, v1, forces, (), h, tuple(stance)
    idx = [names.index(f) for f in air]
    z0 = contact.positions(q)[idx, 2]
    z1 = contact.positions(q1)[idx, 2]
    # a wanted foot already on the ground (an impact window can carry it there) lands now
    vz0 = contact.foot_states(q, v)[1][idx, 2]
    now = [i for i in range(len(air)) if z0[i] <= 0.0 and vz0[i] < 0.0]
    crossing = now + [i for i in range(len(air)) if z0[i] > 0.0 >= z1[i]]
    if not crossing:
        return q1, v1, forces, (), h, tuple(stance)

    def height(s, i):
        qs, _, _ = rk4(contact, q, v, tau, s, stance)
        return contact.positions(qs)[idx[i], 2]

    times = {i: 0.0 if i in now else brentq(height, 0.0, h, args=(i,), xtol=1e-12)
             for i in crossing}
    first = min(times.values())
    landed = tuple(air[i] for i in crossing if times[i] - first < 1e-9)
    qs, vs, _ = rk4(contact, q, v, tau, first, stance)
    vel = contact.foot_states(qs, vs)[1]
    for foot in landed:  # (a point of a sole released at rest may graze back: |v_z| ~ 0)
        if vel[names.index(foot), 2] >= GRAZING:
            raise NotWalking(f"the foot {foot} reaches the ground moving up", "touchdown")
    landed += flat_landing(contact, qs, vel, landed, air, stance)
    ground = tuple(f for f in names if f in stance or f in landed)
    delta = window
    imp = unilateral_impact(contact, qs, vs, ground, chk.friction, tau=tau(qs, first),
                            window=delta)
    for foot in imp.sliding:
        raise NotWalking(f"the foot {foot} slides at the touchdown (its impulse on the friction "
                         f"cone's edge, walking.friction = {chk.friction})", "impulse")
    # a held point of a link that stops with no impulse in any distribution is at rest in
    # contact (the impact's complementarity allows it): only the pushing ones are checked
    pushing = tuple(f for f in imp.held if not (contact.redundant(imp.held)
                                                and imp.impulses[ground.index(f), 2] == 0.0))
    index = [ground.index(f) for f in pushing]
    check_impact(chk, st, pushing, imp.impulses[index], imp.leaving,
                 imp.normal_velocity[[ground.index(f) for f in imp.leaving]],
                 energy_lost=imp.energy_lost)
    st.impacts_released += len([f for f in imp.leaving if f in stance])
    if delta > 0.0:
        qs = pin.integrate(contact.model, qs, delta * imp.v)
    return qs, imp.v, forces, landed, first + max(delta, 0.0), imp.held
