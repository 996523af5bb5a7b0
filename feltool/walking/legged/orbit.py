r"""The trot's reference acquired from its own closed loop on the known model: the start gait
made an orbit of the model, as a designed gait is.

The trot's plan (:meth:`~feltool.walking.legged.trot.TrotController.plan`: inverse kinematics
of a level base moving straight on and of the feet's swings) is not a motion the robot can
follow exactly: two diagonal point feet cannot hold the base about the line through them,
impacts change its velocities, and the swing feet lag their targets. The closed loop settles
on a cycle near the plan, and the feedback that keeps it there is the start gait's own (about
0.13 N m of the motors' torque for Solo-12, in every cycle, with nothing unknown).

**Acquisition.** Run the trot on the known model until it has settled, record one cycle, and
take as the reference's correction :math:`\delta(\tau)` what the robot did minus what was
planned, by the time :math:`\tau` since the cycle began: the configuration
(:math:`q \ominus q_{plan}`), velocities, accelerations (the stance dynamics' under the torques
applied), and the feet's positions and velocities (for the swing feet's Cartesian PD). Then
run again with the plan corrected by :math:`\delta` (the controller tracks what the robot did,
RNEA now gives the forces of that motion) and record again: a fixed-point iteration
:math:`\delta_{k+1} = x(\delta_k) - x_{plan}`. A fixed point is a cycle on which the plan plus
its correction is the motion itself, so the feedback only corrects departures from it. Measured
on Solo-12 (0.3 m/s): the cycle's summed feedback 0.130, 0.060, 0.044, 0.034, 0.027 N m over
four rounds. Only the known model is used; the unknown world is FEL's (:mod:`.learn`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from feltool.errors import FeltoolError
from feltool.walking.legged.model import LeggedModel
from feltool.walking.legged.stand import stand
from feltool.walking.legged.trot import TrotController, TrotGait


@dataclass
class ReferenceCorrection:
    """:math:`\\delta(\\tau)`: the correction of the trot's plan by the time ``tau`` [s] since
    the cycle began, interpolated linearly between the recorded control steps (held before the
    first and after the last): continuous in ``tau``, so that the trot's Poincaré map stays
    continuous in the state when an event moves (a value held from the last step made it jump
    from one recorded step to the next: a spectral radius of 2.9 at perturbations of 1e-3).

    Attributes:
        tau: ``(n,)`` the recorded times in the cycle [s], increasing.
        dq: ``(n, nv)`` configuration offsets (tangent space); ``dv``, ``da`` velocities [rad/s,
            m/s] and accelerations; ``dP``, ``dV`` ``(n, 4, 3)`` the feet's positions [m] and
            velocities [m/s].
    """

    tau: np.ndarray
    dq: np.ndarray
    dv: np.ndarray
    da: np.ndarray
    dP: np.ndarray
    dV: np.ndarray

    def __call__(self, tau: float) -> tuple[np.ndarray, ...]:
        n = len(self.tau)
        j = int(np.clip(np.searchsorted(self.tau, tau, side="right") - 1, 0, n - 1))
        k = min(j + 1, n - 1)
        span = self.tau[k] - self.tau[j]
        w = float(np.clip((tau - self.tau[j]) / span, 0.0, 1.0)) if span > 0 else 0.0
        return tuple((1.0 - w) * x[j] + w * x[k]
                     for x in (self.dq, self.dv, self.da, self.dP, self.dV))


class AcquisitionError(FeltoolError):
    """The trot did not reach the cycle to record on the known model."""


@dataclass
class Acquisition:
    """The acquired correction and each round's summed feedback (RMS over the recorded cycle
    of the feedback's share of the motor torques [N m]; round 0 is the plan's own)."""

    correction: ReferenceCorrection | None
    feedback: list


def record_cycle(legged: LeggedModel, controller: TrotController, q0: np.ndarray,
                 cycle: int = 8, impact_window: float = 1e-4, rate_hz: float = 1000.0
                 ) -> tuple[ReferenceCorrection, float]:
    """Run a copy of ``controller`` (with its correction) on the known model from standing at
    ``q0`` and record its ``cycle``-th cycle after the ramp: the new correction (what the robot
    did minus the plan) and that cycle's summed feedback [N m]."""
    ctl = copy.deepcopy(controller)
    g = ctl.gait
    g.reset()
    rows, share = [], []
    starts = []

    def observe(t, q, v, feet, alloc):
        tau = g.cycle_time(t)
        if tau is None:
            return
        if not starts or g.t_cycle != starts[-1]:
            starts.append(g.t_cycle)
        if len(starts) - 1 != cycle:
            return
        a = ctl.contact.stance(q, v, ctl.B @ alloc.u, feet).a
        P, V = ctl.contact.foot_states(q, v)
        q_p, v_p, a_p, P_p, V_p = ctl.planned
        rows.append((tau, pin.difference(ctl.model, q_p, q), v - v_p, a - a_p, P - P_p,
                     V - V_p))
        share.append((t, np.sum(ctl.motor_share(ctl.feedback(q, v)) ** 2)))

    ctl.observer = observe
    log = stand(legged, ctl, q0, duration=g.start + g.ramp + 2 * (cycle + 3) * g.period,
                schedule=g.schedule, on_touchdown=g.touchdown, impact_window=impact_window,
                rate_hz=rate_hz, until=lambda t: len(starts) > cycle + 1)
    if log.not_walking is not None or len(starts) <= cycle + 1:
        raise AcquisitionError(f"the trot did not reach cycle {cycle} on the known model: "
                               f"{log.not_walking}")
    order = np.argsort([r[0] for r in rows], kind="stable")
    cols = [np.array([rows[i][k] for i in order]) for k in range(6)]
    t = np.array([s[0] for s in share] + [starts[cycle + 1]])
    fb = float(np.sqrt(np.sum(np.diff(t) * np.array([s[1] for s in share])) / (t[-1] - t[0])))
    return ReferenceCorrection(*cols), fb


def acquire_orbit(legged: LeggedModel, gait: TrotGait | None = None, rounds: int = 4,
                  cycle: int = 8, controller: TrotController | None = None,
                  impact_window: float = 1e-4, rate_hz: float = 1000.0) -> Acquisition:
    """``rounds`` rounds of the acquisition (module docstring) on the known model, from the
    plan (or ``controller``'s correction); the last round's correction and every round's
    summed feedback (``rounds + 1`` values: the last one is the acquired reference's), at the
    control rate ``rate_hz`` [Hz] of the runs it is for."""
    gait = TrotGait() if gait is None else gait
    q0 = legged.standing()
    ctl = TrotController(legged, q0, gait=copy.deepcopy(gait)) if controller is None \
        else copy.deepcopy(controller)
    feedback = []
    for _ in range(rounds + 1):
        corr, fb = record_cycle(legged, ctl, q0, cycle, impact_window, rate_hz)
        feedback.append(fb)
        if len(feedback) <= rounds:
            ctl.correction = corr
    return Acquisition(ctl.correction, feedback)
