"""The Python engine's learning cycles: one cycle of each kind (the arm per cycle and per
step, the walkers' hybrid loops, model learning) run by numpy and Pinocchio, each returning a
:class:`~feltool.engines.outcome.CycleOutcome` (the compiled engine returns the same,
:mod:`feltool.engines.compiled.engine`); :func:`feltool.runs.seed.run_seed` picks and drives them."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from feltool.control.closed_loop import ClosedLoop, CycleLog
from feltool.control.feedback import wrap
from feltool.control.hold import hold_mean
from feltool.dynamics.interface import Dynamics
from feltool.engines.outcome import CycleOutcome
from feltool.learning.fel import feedforward

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment
    from feltool.motion.motion import Motion


def _feedforward(exp: Experiment, Qd, Vd, Ad) -> tuple[np.ndarray, list | None]:
    """:math:`u_{ff}` along the desired trajectory, with the RNEA derivatives (from the same
    pass) when the learner needs exact sensitivities; ``sim.feedforward: hold_mean`` holds each
    step's mean (:mod:`feltool.control.hold`), the derivatives stay the samples'."""
    if exp.learner.n_learned and exp.config.learning.sensitivity == "exact":
        u_ff, *derivs = exp.dynamics.inverse_derivatives_batch(Qd, Vd, Ad)
    else:
        u_ff, derivs = feedforward(exp.dynamics, Qd, Vd, Ad), None
    return (hold_mean(u_ff) if exp.config.sim.feedforward == "hold_mean" else u_ff), derivs


def per_cycle(exp: Experiment, theta: np.ndarray, q, v, loop: ClosedLoop,
               motion: Motion | None = None) -> CycleOutcome:
    """One cycle (one revolution of the phase) on the limit cycle of the current parameters,
    then one update (eq. 3.6) weighted by the phase each step covers. Without ``motion`` the
    cycle is the nominal one."""
    stalled, cycle = None, None
    if motion is not None and motion.adaptive:
        log, cycle, (Qd, Vd, Ad), stalled = motion.run_adaptive_cycle(loop, q, v, theta)
        derivs = None
        if exp.learner.n_learned and exp.config.learning.sensitivity == "exact":
            derivs = exp.dynamics.inverse_derivatives_batch(Qd, Vd, Ad)[1:]
    else:
        if motion is not None:
            cycle = motion.next_cycle()
            Qd, Vd, Ad = motion.desired(theta, cycle)
        else:
            Qd, Vd, Ad = exp.primitives.desired(theta)
        R, Rd = exp.law.references(Qd, Vd)
        u_ff, derivs = _feedforward(exp, Qd, Vd, Ad)
        log = loop.run_cycle(q, v, R, Rd, u_ff)
    weight = cycle.weight if cycle is not None else None
    theta_next = theta
    if exp.learner.n_learned and np.all(np.isfinite(log.v)) and stalled is None:
        if exp.learner.fit == "closed_loop":  # through the known model's closed loop
            if derivs is None:
                derivs = exp.dynamics.inverse_derivatives_batch(Qd, Vd, Ad)[1:]
            J = exp.learner.jacobian(exp.dynamics, theta, Qd, Vd, Ad, derivs, cycle=cycle,
                                     transients=motion.transients if motion is not None else None)
            if exp.config.sim.feedforward == "hold_mean":  # the held feedforward's sensitivity
                J = hold_mean(J)
            theta_next = exp.learner.closed_loop_step(theta, J, derivs, log.u_err, Qd, cycle,
                                                      log.measured_change(exp.dynamics))
        elif derivs is not None:  # exact: the sums of eq. 3.6 without forming J
            theta_next = exp.learner.update_from_derivatives(theta, derivs, log.u_err, weight,
                                                             cycle)
        else:
            J = exp.learner.jacobian(exp.dynamics, theta, Qd, Vd, Ad, derivs, cycle=cycle,
                                     transients=motion.transients if motion is not None else None)
            theta_next = exp.learner.step(theta, J, log.u_err, weight)
    out = cycle_outcome(exp, log, Qd, theta_next, weight)
    out.cycle, out.desired, out.fall = cycle, (Qd, Vd, Ad), stalled
    if motion is not None:
        motion.end_cycle()
    return out


def hybrid_cycle(exp: Experiment, theta: np.ndarray, q, v, plant: Dynamics,
                  loop=None, learn: bool = True, theta_m: np.ndarray | None = None
                  ) -> CycleOutcome:
    """One cycle of the hybrid loop (walkers, allocated motors), then one update (eq. 3.6);
    the learner's Jacobian goes through the stance-dependent map q_d = G_s p_d. ``loop``: the
    loop to run (default ``exp.hybrid``; a disturbed or ILC copy); ``learn`` False: no update;
    ``theta_m``: a physical walker's model correction and motor biases (``learning.model``,
    :mod:`feltool.learning.walker_model`), updated after the cycle too."""
    if plant is exp.dynamics and exp.plant is not None:  # the seed's world: the experiment's plant
        plant = exp.plant
    P, Pv, Pa = exp.primitives.desired(theta)
    loop = loop or exp.hybrid
    model = exp.model_learner if getattr(exp.model_learner, "walker", False) else None
    if model is not None and theta_m is not None:
        loop.model_correction = model.correction(theta_m)
        loop.motor_bias = model.split(theta_m)[1] if model.n_bias else None
    log = loop.run_cycle(plant, q, v, P, Pv, Pa)
    theta_m_next = theta_m
    if model is not None and theta_m is not None and learn and log.fall is None:
        theta_m_next = model.step(theta_m, log.Qd, log.Vd, log.Ad, log.allocation,
                                  error_torques(exp, log))
    theta_next = theta
    if learn and log.fall is None and exp.learner.n_learned:
        _, *derivs = exp.hybrid.jacobian_derivatives(log)
        J = exp.learner.jacobian(exp.dynamics, theta, log.Qd, log.Vd, log.Ad, derivs,
                                 samples=getattr(log, "phase_index", None))
        E = error_torques(exp, log)
        A = getattr(log, "allocation", None)
        if exp.config.learning.error_space == "motors" and A is not None and len(A):
            theta_next = motor_step(exp, theta, A, J, E)
        else:
            theta_next = exp.learner.step(theta, J, E)
    out = cycle_outcome(exp, log, log.Qd, theta_next)
    out.theta_m_next = theta_m_next
    out.fall, out.impacts = log.fall, list(log.impacts)
    if getattr(log, "steps", None) is not None:
        out.contact = contact_metrics(log, exp)
        out.limit_hits = (np.zeros(len(exp.joints), int), _motor_hits(exp, log))
    return out


def error_torques(exp: Experiment, log) -> np.ndarray:
    """A walker's cycle's learning signal ``(n, nv)`` in generalized forces [N m]: the error
    feedback, plus the inertial term with ``learning.error_estimate: inverse_dynamics``, the
    samples of ``learning.impact_window_s`` left out."""
    E = impact_masked(exp, log)
    if exp.config.learning.error_estimate == "inverse_dynamics" and \
            getattr(log, "inertial", None) is not None:
        E = E + impact_masked(exp, log, log.inertial)
    return E


def motor_step(exp: Experiment, theta: np.ndarray, A: np.ndarray, J: np.ndarray,
                E: np.ndarray) -> np.ndarray:
    r"""The update (eq. 3.6) with the error and the Jacobian in motor torques: the motors
    apply :math:`u = A(q)\,(\tau_{ff} + u_{fb})` (the allocation, :mod:`feltool.walking.physical`), so
    the feedforward's error is :math:`A e` and its sensitivity :math:`A J`; the part of a
    generalized force that the contact absorbs (:math:`A\tau = 0`) is no error and no
    gradient. ``A`` ``(n, k, nv)``, ``J`` ``(n, nv, P)``, ``E`` ``(n, nv)``."""
    Jm = np.einsum("kmr,krp->kmp", A, J)
    Em = np.einsum("kmr,kr->km", A, E)
    grad = np.einsum("km,kmp->p", Em, Jm)
    hess = np.einsum("kmp,kms->ps", Jm, Jm) if exp.learner.update == "gauss_newton" else None
    return exp.learner.apply(theta, grad, hess)


def contact_metrics(log, exp: Experiment) -> dict[str, float]:
    """Per cycle of a physical walker: the stance foot's smallest normal force [N] and largest
    friction ratio, the swing foot's lowest clearance [m], the largest touchdown impulse ratio,
    the kinetic energy lost at the touchdowns [J], the mean step length [m], the walked
    distance [m], the cycle's duration [s] (its control steps, each cut short at a touchdown), the
    motors' absolute mechanical work [J], the RMS
    of the stabilized quantities' errors from their targets [rad]; also the kind of contact
    violation (``not_walking``), if any."""
    steps = log.steps
    dt = exp.config.dt
    motors = exp.hybrid.walker.motor_v
    work = float(np.abs(log.tau * log.v[:, motors]).sum() * dt) if len(log.q) else 0.0
    law = exp.law
    stab = law.stabilizing
    if not stab.any() and exp.hybrid.reference:  # a learned joint holding a designed motion
        rows = np.array(sorted(exp.hybrid.reference))
        err = (wrap(law.quantity(log.q)[:, rows] - log.reference[:, rows]) if len(log.q)
               else np.zeros(1))
    else:
        err = (wrap(law.quantity(log.q)[:, stab] - law.targets[stab]) if len(log.q)
               else np.zeros(1))
    done = [s for s in steps if np.isfinite(s.length)]
    finite = lambda xs: [x for x in xs if np.isfinite(x)]  # noqa: E731
    clear = finite([s.min_clearance for s in steps])
    return {
        "min_normal_force": float(min(s.min_normal_force for s in steps)),
        "max_friction_ratio": float(max(s.max_friction_ratio for s in steps)),
        "min_clearance": float(min(clear)) if clear else float("nan"),
        "max_impulse_ratio": float(max((s.impulse_ratio for s in done), default=float("nan"))),
        "impact_energy_lost": float(sum(s.energy_lost for s in done)),
        "step_length": float(np.mean([s.length for s in done])) if done else float("nan"),
        "distance": float(sum(s.length for s in done)),
        "steps": len(done),
        "duration": (float(log.elapsed) if np.isfinite(getattr(log, "elapsed", np.nan))
                     else len(log.q) * dt),
        "work": work,
        "stabilized_rms": float(np.sqrt(np.mean(err**2))) if err.size else 0.0,
        "not_walking": log.not_walking,
    }


def _motor_hits(exp: Experiment, log) -> np.ndarray:
    """Steps over the effort limit per joint (the physical walker's motors are joints)."""
    hits = np.zeros(len(exp.joints), int)
    if log.torque_hits is not None:
        hits[exp.hybrid.walker.motor_v] = log.torque_hits
    return hits


def impact_masked(exp: Experiment, log, E: np.ndarray | None = None) -> np.ndarray:
    """The cycle's error torques (or ``E``) with the rows within ``learning.impact_window_s``
    after each impact zeroed (the learning signal only; the metrics keep every sample)."""
    window = exp.config.learning.impact_window_s
    E = log.u_err if E is None else E
    if window <= 0 or not log.impacts:
        return E
    E = E.copy()
    E[after_impacts(log.impacts, len(E), int(round(window / exp.config.dt)))] = 0.0
    return E


def after_impacts(impacts: list, n: int, window: int) -> np.ndarray:
    """The cycle's ``n`` samples within ``window`` samples after each impact, as a mask; the
    cycle's last impact starts the next cycle, whose first samples follow it."""
    mask = np.zeros(n, bool)
    for k, _, _ in impacts:  # k: first sample after the impact
        k %= n
        mask[k:k + window] = True
    return mask


def model_cycle(exp: Experiment, theta: np.ndarray, q, v, theta_m: np.ndarray,
                 loop: ClosedLoop) -> CycleOutcome:
    """One cycle with the learned inverse-model correction in the feedforward, then both
    updates: the trajectory's (eq. 3.6) and the model's (eq. 3.4)."""
    model = exp.model_learner
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_ff, derivs = _feedforward(exp, Qd, Vd, Ad)
    log, theta_m_next = model.run_cycle(loop, q, v, R, Rd, u_ff, (Qd, Vd, Ad), theta_m)
    theta_next = theta
    if exp.learner.n_learned and np.all(np.isfinite(log.v)):
        J = exp.learner.jacobian(exp.dynamics, theta, Qd, Vd, Ad, derivs)
        # The joints the correction drives (model.error_mask) got u_ff from the learned model,
        # the others from the known one: the Jacobian row by row from the model each row used.
        rows = (model.error_mask > 0) & (exp.learner.error_mask > 0)
        learned = (model.learned_dynamics(theta_m)
                   if exp.config.learning.model.jacobian == "learned" and rows.any() else None)
        if learned is not None:
            d = learned.inverse_derivatives_batch(Qd, Vd, Ad)[1:] if derivs is not None else None
            J[:, rows] = exp.learner.jacobian(learned, theta, Qd, Vd, Ad, d)[:, rows]
        theta_next = exp.learner.step(theta, J, log.u_err)
    out = cycle_outcome(exp, log, Qd, theta_next)
    out.theta_m_next = theta_m_next
    return out


def cycle_outcome(exp: Experiment, log: CycleLog, Qd: np.ndarray, theta_next,
             weight: np.ndarray | None = None) -> CycleOutcome:
    """The cycle's metrics: means over its steps, each weighted by the phase it covers
    (``weight``, :class:`~feltool.motion.phase.PhaseSamples`; None: plain means)."""
    law = exp.law
    tracked, held = law.reference_rows()
    controlled = law.tracking | law.stabilizing
    nv, n = log.q_end.shape[0], len(log.q)
    # a walker's cycle that stopped (not walking) before its first sample logs no rows: its
    # means are zero, not a reduction over nothing
    if n == 0:
        average = lambda X: np.zeros(nv)  # noqa: E731
    elif weight is None:
        average = lambda X: X.sum(axis=0) / n  # noqa: E731  (np.mean's numbers)
    else:
        w, total = weight[:, None], weight.sum()
        average = lambda X: (X * w).sum(axis=0) / total  # noqa: E731
    with np.errstate(all="ignore"):
        err = wrap(Qd @ tracked.T + held - law.quantity(log.q))[:, controlled]
        u_fb = average(np.abs(log.u_fb))
        u_rows = u_fb if log.u_rows is log.u_fb else average(np.abs(log.u_rows))
        # a NaN or an infinity among the velocities is also their largest magnitude
        max_speed = float(np.abs(log.v).max()) if n else 0.0
        finite = (np.isfinite(max_speed) and bool(np.isfinite(log.q).all())
                  and math.isfinite(sum(log.q_end.tolist())))
        return CycleOutcome(
            theta_next, log.q_end, log.v_end, u_fb, np.sqrt(average((Qd - log.q) ** 2)),
            float(max(err.max(), -err.min())) if err.size else 0.0, max_speed, finite,
            lambda: (log, Qd), float(u_rows[law.stabilizing].sum()),
            float(average(np.abs(log.u_err)).sum()),
            limit_hits=getattr(log, "limit_hits", None))


def limit_cycle_states(exp: Experiment, theta: np.ndarray) -> dict[int, tuple]:
    """Each RMP's state :math:`(q, q')` (phase units) and its sensitivity at phase 0 of its
    limit cycle."""
    out = {}
    for i, p in exp.primitives.primitives.items():
        S = p.state_rows(0.0)
        out[i] = (S @ theta[exp.primitives.slices[i]], S)
    return out


def per_step_cycle(exp: Experiment, theta: np.ndarray, q, v, states: dict[int, tuple],
                    motion: Motion, loop: ClosedLoop | None = None) -> CycleOutcome:
    """One cycle with an update after every step; the RMP states :math:`y = (q, q')` (updated
    in place in ``states``) run on continuously through the exact step of the phase
    (:meth:`~feltool.motion.rmp.RhythmicPrimitive.transition`), their sensitivities propagated
    alongside. ``loop`` simulates the world (default ``exp.loop``)."""
    loop = loop or exp.loop
    cycle = motion.next_cycle()
    prims, n, nv = exp.primitives, cycle.n, exp.primitives.nv
    learner, law, dyn = exp.learner, exp.law, exp.dynamics
    theta = theta.copy()
    Q, V, U, Urows, Uerr, Qd, Vd, Ad = (np.empty((n, nv)) for _ in range(8))
    for k in range(n):
        phi, w, wd = cycle.phi[k], cycle.omega[k], cycle.omega_dot[k]
        qd, vd, ad = np.empty(nv), np.empty(nv), np.empty(nv)
        Sq, Sv, Sa = {}, {}, {}
        for i, p in prims.primitives.items():
            y, S = states[i]
            th = theta[prims.slices[i]]
            qd[i], vd[i] = y[0], w * y[1]
            a, dadth = p.phase_acceleration(y, S, th, phi)
            ad[i] = w * w * a + wd * y[1]
            Sq[i], Sv[i] = S[0], w * S[1]
            Sa[i] = w * w * dadth + wd * S[1]
        Qd[k], Vd[k], Ad[k] = qd, vd, ad
        R, Rd = law.references(qd[None], vd[None])
        u_fb, u_rows, u_err = law.terms(q, v, R[0], Rd[0], exp.loop.error_rows)
        u_ff = dyn.inverse(qd, vd, ad)
        Dq, Dv, M = dyn.inverse_derivatives(qd, vd, ad)
        J = np.zeros((1, nv, learner.n_learned))
        for i, cols in learner._blocks:
            J[0][:, cols] = (np.outer(Dq[:, i], Sq[i]) + np.outer(Dv[:, i], Sv[i])
                             + np.outer(M[:, i], Sa[i]))
        Q[k], V[k], U[k], Urows[k], Uerr[k] = q, v, u_fb, u_rows, u_err
        q, v = loop.advance(q, v, loop.actuated * (u_ff + u_fb))
        for i, p in prims.primitives.items():
            y, S = states[i]
            F, G = p.transition(phi, cycle.dphi[k])
            states[i] = (F @ y + G @ theta[prims.slices[i]], F @ S + G)
        theta = learner.step(theta, J, u_err[None],
                             None if cycle.weight is None else cycle.weight[k:k + 1])
    out = cycle_outcome(exp, CycleLog(Q, V, U, q, v, Urows, Uerr), Qd, theta, cycle.weight)
    out.cycle, out.desired = cycle, (Qd, Vd, Ad)
    return out


__all__ = ["after_impacts", "contact_metrics", "error_torques", "hybrid_cycle", "impact_masked",
           "limit_cycle_states", "model_cycle", "motor_step", "cycle_outcome", "per_cycle",
           "per_step_cycle"]
