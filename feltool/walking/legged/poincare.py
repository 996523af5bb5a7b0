r"""The trot's Poincaré map and its Jacobian at the fixed point, by finite differences of the
closed loop itself.

**Section.** The touchdown that completes the pair ``(FL, HR)``'s landing (once per cycle),
just after its impact and before the control update it triggers
(:func:`~feltool.walking.legged.stand.stand`'s ``until_touchdown``): all four feet on the
ground and stopped. The controller then has nothing under way to remember: the pair it
releases starts its swing from this state, as in the loop. A rollout resumed from a section
state runs its control grid from the section's time (at 1 kHz, the loop's own rate), so the
map is continuous in the state.

**Coordinates.** A state is written as its deviation from the reference section state
:math:`x^*` in Pinocchio's tangent space, :math:`\delta = (q \ominus q^*, v - v^*)` (36 numbers
for Solo-12), the reference moved forward by the desired base's travel since it
(:math:`x - x_d(t)` is the base's coordinate, not :math:`x`). Perturbations stay on the
section's manifold: every foot stays on the ground and stopped (:func:`section_tangent`, an
orthonormal basis :math:`T`: 20 directions for Solo-12, 14 of the configuration and 6 of the
velocities).

**Jacobian.** For each direction :math:`T_j` the loop is run one cycle from
:math:`x^* \pm \varepsilon T_j` (every contact check on; a perturbation that makes a step
unphysical is an error), and :math:`A_{:,j} = T^\top (P(x^* + \varepsilon T_j) - P(x^* -
\varepsilon T_j)) / 2\varepsilon`. The fixed point is stable when the spectral radius
:math:`\rho(A) < 1`; :math:`\rho` is the factor by which the slowest perturbation shrinks per
cycle. :func:`trot_jacobian` reports it for two ``eps`` (their spread shows the finite
differences' error) and the residual :math:`\|P(x^*) - x^*\|` of the reference state.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import null_space

from feltool.errors import FeltoolError
from feltool.walking.legged.contact import LeggedContact
from feltool.walking.legged.model import LeggedModel
from feltool.walking.legged.stand import StandState, stand
from feltool.walking.legged.trot import TrotController, TrotGait


class SectionError(FeltoolError):
    """A perturbed cycle did not reach the next section physically."""


@dataclass
class Section:
    """The loop stopped at a section: its state and the controller (with its gait) there."""

    state: StandState
    controller: TrotController


@dataclass
class PoincareResult:
    """The trot's Poincaré map at its fixed point.

    Attributes:
        eigenvalues: Of the Jacobian ``A`` in the section's coordinates, largest first.
        rho: Spectral radius of ``A`` (the first ``eps``).
        rho_spread: Spectral radius at each ``eps`` tried.
        residual: :math:`\\|P(x^*) - x^*\\|` of the reference section state (how far from a
            fixed point it is; the floor the 1 kHz grid leaves).
        jacobian: ``A`` ``(r, r)``.
        cycles: Cycles run before the reference section.
    """

    eigenvalues: np.ndarray
    rho: float
    rho_spread: list
    residual: float
    jacobian: np.ndarray
    cycles: int


def _run(legged: LeggedModel, sec: Section, stop_steps: int, impact_window: float,
         **kw) -> Section:
    ctl = copy.deepcopy(sec.controller)
    g = ctl.gait
    log = stand(legged, ctl, None, schedule=g.schedule, on_touchdown=g.touchdown,
                impact_window=impact_window, start=sec.state, duration=60.0,
                until_touchdown=lambda t: g.steps >= stop_steps, **kw)
    if log.not_walking is not None:
        raise SectionError(f"not walking before the next section: {log.not_walking}")
    if g.steps < stop_steps:
        raise SectionError("the next section was not reached")
    return Section(log.end, ctl)


def reach_section(legged: LeggedModel, controller: TrotController, q0: np.ndarray,
                  cycles: int, v0: np.ndarray | None = None, impact_window: float = 1e-4
                  ) -> Section:
    """Run the trot (a copy of ``controller`` and its gait, from the gait's start) from
    standing at ``q0`` until the section after ``cycles`` completed cycles."""
    ctl = copy.deepcopy(controller)
    g = ctl.gait
    g.reset()
    log = stand(legged, ctl, q0, v0=v0, schedule=g.schedule, on_touchdown=g.touchdown,
                impact_window=impact_window, duration=60.0 + 2 * cycles * g.period,
                until_touchdown=lambda t: g.steps >= 2 * cycles)
    if log.not_walking is not None or g.steps < 2 * cycles:
        raise SectionError(f"the trot did not reach cycle {cycles}: {log.not_walking}")
    return Section(log.end, ctl)


def section_tangent(legged: LeggedModel, sec: Section) -> np.ndarray:
    """``T`` ``(2 nv, r)``: an orthonormal basis of the perturbations ``(dq, dv)`` that keep
    every foot at its height and the stance feet stopped."""
    contact = LeggedContact(legged)
    q, stance = sec.state.q, sec.state.stance
    Jz = contact.jacobian(q, tuple(legged.feet))[2::3]  # every foot's height
    Jst = contact.jacobian(q, stance) if stance else np.zeros((0, legged.nv))
    nv = legged.nv
    C = np.zeros((len(Jz) + len(Jst), 2 * nv))
    C[:len(Jz), :nv] = Jz
    C[len(Jz):, nv:] = Jst
    return null_space(C)


def perturbed(legged: LeggedModel, sec: Section, d: np.ndarray) -> Section:
    """The section state moved by ``d = (dq, dv)`` in the tangent space (the feet put back on
    the ground by Newton steps on their heights, anchored where they are, and stopped)."""
    nv = legged.nv
    q = pin.integrate(legged.model, sec.state.q, d[:nv])
    v = sec.state.v + d[nv:]
    contact = LeggedContact(legged)
    stance = sec.state.stance
    feet = tuple(legged.feet)
    z0 = contact.positions(sec.state.q)[:, 2]
    for _ in range(5):  # second-order drift of the feet's heights off the tangent
        J = contact.jacobian(q, feet)[2::3]
        r = contact.positions(q)[:, 2] - z0
        q = pin.integrate(legged.model, q, -np.linalg.pinv(J) @ r)
    if stance:
        Js = contact.jacobian(q, stance)
        v = v - np.linalg.pinv(Js) @ (Js @ v)
    pos = contact.positions(q)
    names = list(legged.feet)
    state = StandState(sec.state.t, q, v, stance,
                       {f: pos[names.index(f)] for f in stance}, sec.state.carry)
    return Section(state, copy.deepcopy(sec.controller))


def _coordinates(legged: LeggedModel, ref: Section, out: Section) -> np.ndarray:
    """``out``'s deviation ``(dq, dv)`` from ``ref`` moved forward by the desired travel."""
    g = out.controller.gait
    q_ref = np.array(ref.state.q)
    q_ref[0] += g.base_x(out.state.t)[0] - g.base_x(ref.state.t)[0]
    return np.r_[pin.difference(legged.model, q_ref, out.state.q), out.state.v - ref.state.v]


def trot_jacobian(legged: LeggedModel, gait: TrotGait | None = None, cycles: int = 20,
                  eps: tuple[float, ...] = (2e-3, 5e-3), impact_window: float = 1e-4,
                  controller: TrotController | None = None) -> PoincareResult:
    """The trot's Poincaré map's Jacobian at the section after ``cycles`` cycles (module
    docstring), by central differences of size each of ``eps`` along every direction of
    :func:`section_tangent`."""
    gait = TrotGait() if gait is None else gait
    q0 = legged.standing()
    ctl = TrotController(legged, q0, gait=gait) if controller is None else controller
    ref = reach_section(legged, ctl, q0, cycles, impact_window=impact_window)
    T = section_tangent(legged, ref)
    nxt = 2 * (cycles + 1)
    residual = float(np.linalg.norm(_coordinates(legged, ref, _run(legged, ref, nxt,
                                                                   impact_window))))
    rhos, A0 = [], None
    for e in eps:
        cols = []
        for j in range(T.shape[1]):
            plus = _run(legged, perturbed(legged, ref, e * T[:, j]), nxt, impact_window)
            minus = _run(legged, perturbed(legged, ref, -e * T[:, j]), nxt, impact_window)
            cols.append(T.T @ (_coordinates(legged, ref, plus)
                               - _coordinates(legged, ref, minus)) / (2 * e))
        A = np.array(cols).T
        rhos.append(float(np.abs(np.linalg.eigvals(A)).max()))
        A0 = A if A0 is None else A0
    ev = np.linalg.eigvals(A0)
    ev = ev[np.argsort(-np.abs(ev))]
    return PoincareResult(ev, rhos[0], rhos, residual, A0, cycles)

