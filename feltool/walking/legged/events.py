r"""Feet leaving and reaching the ground in the legged loop: a scheduled lift-off and a
touchdown located inside a sub-step.

- **Lift-off**: a foot the schedule takes out of stance is released; it must then accelerate
  up, not into the ground (its vertical classical acceleration in the dynamics without its
  contact, :math:`\ge 0`; kind ``lift_off``).
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
    for foot in landed:
        if vel[names.index(foot), 2] >= 0.0:
            raise NotWalking(f"the foot {foot} reaches the ground moving up", "touchdown")
    ground = tuple(f for f in names if f in stance or f in landed)
    delta = window
    imp = unilateral_impact(contact, qs, vs, ground, chk.friction, tau=tau(qs, first),
                            window=delta)
    for foot in imp.sliding:
        raise NotWalking(f"the foot {foot} slides at the touchdown (its impulse on the friction "
                         f"cone's edge, walking.friction = {chk.friction})", "impulse")
    index = [ground.index(f) for f in imp.held]
    check_impact(chk, st, imp.held, imp.impulses[index], imp.leaving,
                 imp.normal_velocity[[ground.index(f) for f in imp.leaving]],
                 energy_lost=imp.energy_lost)
    st.impacts_released += len([f for f in imp.leaving if f in stance])
    if delta > 0.0:
        qs = pin.integrate(contact.model, qs, delta * imp.v)
    return qs, imp.v, forces, landed, first + max(delta, 0.0), imp.held
