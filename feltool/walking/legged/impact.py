r"""The rigid impact of several feet with **unilateral** contacts: a foot the ground would have to
pull gets no impulse and leaves the ground.

Every candidate foot :math:`i` (the feet touching the ground at the impact: the landing ones and
those already in stance) has a point Jacobian :math:`J_i` (world axes, from Pinocchio) and takes
an impulse :math:`\iota_i` in [N s]. The impact is perfectly inelastic and, following Moreau and
Gauss, the velocity change is the smallest in the kinetic-energy metric that the contacts allow:

.. math::

    \min_{\Delta v}\ \tfrac12 \Delta v^\top M \Delta v \quad\text{s.t.}\quad
    J_i(\dot q^- + \Delta v) \in K_i^*,

:math:`M` Pinocchio's mass matrix (``pin.crba``), :math:`K_i` the friction cone on the impulse,
here a **polyhedral cone inscribed in the circular one**: ``faces`` planes
:math:`\cos\theta_k\,\iota_x + \sin\theta_k\,\iota_y \le \mu\cos(\pi/F)\,\iota_z`,
:math:`\theta_k = 2\pi k/F` (default :math:`F = 8`, an octagon: it keeps 92 % of the circle's
radius; an impulse in it passes the circular check), and :math:`\iota_z \ge 0`;
:math:`K_i^*` is its dual cone. It is solved in its dual, a QP in the impulses
(``qpsolvers`` with :data:`~feltool.walking.legged.control.QP_SOLVER`):

.. math::

    \min_{\iota \in K}\ \tfrac12 \iota^\top G \iota + \iota^\top J\dot q^-,
    \qquad G = J M^{-1} J^\top, \qquad \dot q^+ = \dot q^- + M^{-1}J^\top \iota,

whose optimality conditions are the impact's complementarity: :math:`\iota_{i,z} \ge 0`; a
foot that keeps an impulse inside its cone stops (:math:`J_i\dot q^+ = 0`); a foot with
:math:`\iota_i = 0` has :math:`J_i\dot q^+ \in K_i^*`, its normal velocity :math:`\ge 0`: it
leaves the ground (:math:`\iota_{i,z}\, v^+_{i,z} = 0`). The kinetic energy cannot grow
(:math:`\iota = 0` is feasible and the objective is the energy change). A foot whose impulse is
on the pyramid's boundary *slides* (the QP's dual-cone velocity of a sliding contact also lifts
it, by about :math:`\mu` times the slip speed: Anitescu's relaxation): such an impact is
reported in :attr:`UnilateralImpact.sliding`; the walker's checks call it not walking.

**A window of the forces.** Rigid impacts couple every foot: a landing foot's impulse gives the
feet already loaded in stance tiny impulses (1e-5 N s against its 5e-3) in any direction, which
a strict cone check calls sliding although their load (12 N, 1.2e-3 N s in 0.1 ms) would hold
them. With ``window`` :math:`\delta > 0` [s] the impact is one Moreau-Jean step of that length:
the generalized force ``tau`` and the bias :math:`b` (Pinocchio's ``nonLinearEffects``) act
over it, :math:`\dot q^- \to \dot q^- + \delta M^{-1}(\tau - b)` before the same QP, and the
"impulses" are the feet's impulses over the window, their loads included. :math:`\delta = 0`
is the instantaneous impact above.

**Exact polish.** The QP finds which feet keep an impulse; the impact is then recomputed
exactly by ``pin.impulseDynamics`` on those feet alone and accepted when it satisfies every
condition above (their impulses inside the pyramid, the other feet not moving down), so a
sticking impact is Pinocchio's to machine precision and equals ``pin.impulseDynamics`` on all
the feet when all its impulses push.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import qpsolvers
from scipy.linalg import cho_factor, cho_solve

from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.control import QP_SOLVER
from feltool.walking.legged.sole import distribute, polygon_cone


@dataclass
class UnilateralImpact:
    """A rigid, perfectly inelastic impact with unilateral contacts.

    Attributes:
        v: Velocities after the impact ``(nv,)``.
        impulses: ``(n, 3)`` ground impulses on the candidate ``feet`` in [N s], world axes
            (zero on the feet leaving).
        feet: The candidate feet, in the order given.
        held: The feet that keep an impulse and stop (stance after the impact).
        leaving: The feet with no impulse: they leave the ground (normal velocity >= 0).
        sliding: Held feet whose impulse is on the friction pyramid's boundary (they slip).
        normal_velocity: ``(n,)`` the feet's vertical velocities after the impact [m/s].
        energy_lost: Kinetic energy before minus after, in [J] (>= 0 for an instantaneous
            impact; over a window it includes the forces' work).
        exact: True when the result is ``pin.impulseDynamics`` on :attr:`held` (the polish
            was accepted), False when it is the QP's own solution.
    """

    v: np.ndarray
    impulses: np.ndarray
    feet: tuple[str, ...]
    held: tuple[str, ...]
    leaving: tuple[str, ...]
    sliding: tuple[str, ...]
    normal_velocity: np.ndarray
    energy_lost: float
    exact: bool


def unilateral_impact(contact: LeggedContact, q: np.ndarray, v: np.ndarray,
                      feet: tuple[str, ...], friction: float = 0.7, faces: int = 8,
                      tol: float = 1e-9, tau: np.ndarray | None = None,
                      window: float = 0.0) -> UnilateralImpact:
    """The impact of the candidate ``feet`` at ``(q, v)`` (the QP above, then the exact polish).

    Args:
        contact: The plant's contact dynamics (its model's ``M`` and the feet's Jacobians).
        q, v: Configuration and velocities just before the impact.
        feet: The feet on the ground at the impact (landing and in stance).
        friction: :math:`\\mu` [-] of the circular cone the impulses' polygon is inscribed in
            (``inf``: no limit on a held foot's tangential impulse).
        faces: The polygon's number of faces.
        tol: Relative tolerance: a normal impulse below ``tol`` times the largest is zero, a
            normal velocity above ``-tol`` times the largest approach speed is not moving down.
        tau: Generalized force ``(nv,)`` acting over the ``window`` (motor torques, external
            forces; default zero).
        window: :math:`\\delta` [s], the Moreau-Jean step the impact is resolved over (0: the
            instantaneous impact). The caller advances the configuration by it.
    """
    feet = tuple(feet)
    m, d = contact.model, contact.data
    n = len(feet)
    M = np.array(pin.crba(m, d, q))
    M = np.triu(M) + np.triu(M, 1).T
    cho = cho_factor(M)
    v_in = np.array(v, float)
    if window > 0.0:
        b = np.array(pin.nonLinearEffects(m, d, q, v_in))
        force = -b if tau is None else np.asarray(tau, float) - b
        v = v_in + window * cho_solve(cho, force)
    J = contact.jacobian(q, feet)
    c = J @ v
    MJ = cho_solve(cho, J.T)
    G = J @ MJ
    G = 0.5 * (G + G.T)
    # an unlimited friction: a wide finite cone for the QP (a half-space would let a foot with
    # no normal impulse take a tangential one), the polish checks the normal impulses alone
    A = polygon_cone(n, friction if np.isfinite(friction) else 1e3, faces)
    lam = _impulse_qp(G, c, A, contact.redundant(feet))
    if lam is None:  # the solver gave up: the pyramid always holds 0, the energy's minimum
        lam = np.zeros(3 * n)
    lam = np.asarray(lam, float)
    before = contact.kinetic_energy(q, v_in)
    speed = max(float(np.abs(c).max(initial=0.0)), 1e-300)
    scale = max(float(np.abs(lam).max(initial=0.0)), 1e-300)
    redundant = contact.redundant(feet)
    if redundant:  # a link's impulse spreads over its points at will: held are those stopped
        held = tuple(f for f, z in zip(feet, (J @ (v + MJ @ lam))[2::3]) if z <= 1e-6 * speed)
    else:
        held = tuple(f for f, lz in zip(feet, lam[2::3]) if lz > tol * scale)
    result = _polish(contact, q, v, feet, held, polygon_cone(n, friction, faces), tol * speed,
                     before, friction)
    if result is None:
        lam = _refine(G, c, A, lam)
        v_plus = v + MJ @ lam
        imp = lam.reshape(n, 3)
        if redundant:  # the held points of a link: their distribution furthest inside
            idx = [feet.index(f) for f in held]
            imp = np.zeros_like(imp)
            imp[idx] = distribute([contact.link(f) for f in held], contact.positions(q)[
                [list(contact.legged.feet).index(f) for f in held]], lam.reshape(n, 3)[idx],
                friction)
        vz = (J @ v_plus)[2::3]
        slack = (A @ imp.ravel()).reshape(n, -1)[:, :-1].max(1, initial=-np.inf)  # <= 0
        on_edge = slack >= -1e-6 * np.abs(imp[:, 2])
        sliding = tuple(f for f, e, lz in zip(feet, on_edge, imp[:, 2]) if e and lz > tol * scale)
        leaving = tuple(f for f in feet if f not in held)
        return UnilateralImpact(v_plus, imp, feet, held, leaving, sliding, vz,
                                before - contact.kinetic_energy(q, v_plus), False)
    return result


def _impulse_qp(G: np.ndarray, c: np.ndarray, A: np.ndarray, redundant: bool):
    """The QP above, or None when the solver gives up. For points of one link (``redundant``)
    :math:`G` is singular: the impulses are :math:`R\\xi + Y y`, :math:`R` the range of
    :math:`G` (the objective's, positive definite on it) and :math:`Y` its null space (impulses
    internal to a link: they change no velocity), weighted by 1e-3 of :math:`G`'s mean
    eigenvalue so the problem stays well conditioned."""
    if not redundant:
        return qpsolvers.solve_qp(G, c, A, np.zeros(A.shape[0]), solver=QP_SOLVER)
    ev, V = np.linalg.eigh(G)
    keep = ev > 1e-10 * max(float(ev.max()), 1e-300)
    R, Y = V[:, keep], V[:, ~keep]
    k, m = R.shape[1], Y.shape[1]
    P = np.block([[np.diag(ev[keep]), np.zeros((k, m))],
                  [np.zeros((m, k)), 1e-3 * ev[keep].mean() * np.eye(m)]])
    x = qpsolvers.solve_qp(P, np.r_[R.T @ c, np.zeros(m)], A @ np.hstack([R, Y]),
                           np.zeros(A.shape[0]), solver=QP_SOLVER)
    return None if x is None else R @ x[:k] + Y @ x[k:]


def _refine(G: np.ndarray, c: np.ndarray, A: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """The QP's solution made exact on its active set: the faces with ``A lam`` at 0 (to 1e-7
    of the impulses' size) held as equalities, the rest of the problem solved in their null
    space; kept only if it stays in every cone."""
    size = max(float(np.abs(lam).max(initial=0.0)), 1e-300)
    active = A @ lam >= -1e-7 * size
    if not active.any():
        N = np.eye(len(lam))
    else:
        _, sv, Vt = np.linalg.svd(A[active])
        rank = int((sv > 1e-12 * sv.max()).sum())
        N = Vt[rank:].T
    if N.shape[1] == 0:
        return np.zeros_like(lam)
    exact = N @ np.linalg.lstsq(N.T @ G @ N, -N.T @ c, rcond=None)[0]
    return exact if np.all(A @ exact <= 1e-12 * size) else lam


def _polish(contact: LeggedContact, q, v, feet, held, A, vtol, before,
            friction: float = np.inf) -> UnilateralImpact | None:
    """``pin.impulseDynamics`` on the ``held`` feet, if it satisfies the complementarity (their
    normal impulses positive and in the cones ``A``, every other candidate foot not moving
    down); else None. When the QP's guess of ``held`` is off at its tolerance, a few
    active-set corrections (drop the most pulling held foot, add the foot moving down
    fastest) are tried first."""
    n = len(feet)
    held = tuple(held)
    names = list(contact.legged.feet)
    for _ in range(n + 2):
        imp = np.zeros((n, 3))
        v_plus = np.array(v, float)
        if held:
            res = contact.impact(q, v, held)
            v_plus = res.v
            impulses = res.impulses
            if contact.redundant(held):  # a link's points: any distribution of its impulse
                impulses = distribute([contact.link(f) for f in held],
                                      contact.positions(q)[[names.index(f) for f in held]],
                                      impulses, friction)
            for f, i in zip(held, impulses):
                imp[feet.index(f)] = i
        vz = (contact.jacobian(q, feet) @ v_plus)[2::3]
        leaving = tuple(f for f in feet if f not in held)
        lz = np.array([imp[feet.index(f), 2] for f in held])
        down = [vz[feet.index(f)] for f in leaving]
        if held and lz.min() <= 0.0:
            worst = held[int(np.argmin(lz))]
            held = tuple(f for f in held if f != worst)
        elif leaving and min(down) < -vtol:
            worst = leaving[int(np.argmin(down))]
            held = tuple(f for f in feet if f in held or f == worst)
        elif np.any(A @ imp.ravel() > 0.0):
            return None
        else:
            lost = before - contact.kinetic_energy(q, v_plus)
            if contact.redundant(feet):  # a point of a link that the impact stops is held
                rest = [f for f in leaving if abs(vz[feet.index(f)]) <= vtol]  # (no impulse)
                held = tuple(f for f in feet if f in held or f in rest)
                leaving = tuple(f for f in leaving if f not in rest)
            return UnilateralImpact(v_plus, imp, feet, held, leaving, (), vz, lost, True)
    return None
