r"""A designed gait in feltool's own walker: verified by simulation, then closed on its orbit.

The gait designer (:mod:`feltool.gait.design`) satisfies the walker's continuous dynamics at its
collocation knots; the walker's loop (:mod:`feltool.walking.physical`) runs a discretisation of them
(torques held over a control step, Runge-Kutta sub-steps, the reference interpolated in the
mechanical phase, the touchdown where the foot meets the ground). Tracked in the loop, a design
settles on a nearby periodic orbit on which the feedback is small but not zero — a floor that no
learning can remove, because it is the design's own residual.

:func:`verify_design` walks the design in the loop (no learning): ``steps`` steps with every
contact check, then the Poincaré fixed point :math:`x^* = P(x^*)` of the cycle map and its
spectral radius (:func:`feltool.gait.poincare.poincare`). :func:`close_on_orbit` then writes that orbit as
the demonstrations: each joint's position, velocity and acceleration at the start of every
control step of the periodic cycle, the accelerations those of the contact dynamics under the
torques the loop applied. On it the feedforward reproduces the applied torques exactly — the
inverse dynamics of a motion made by motor torques :math:`u` and a stance force :math:`F` is
:math:`B u + J_c^\top F`, and the allocation :math:`A` has :math:`A B = I`, :math:`A J_c^\top = 0`
— and the references equal the state, so the feedback is zero to rounding and the orbit is the
loop's own periodic gait.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from feltool.gait.design import GaitDesignError
from feltool.gait.poincare import poincare


@dataclass
class Verification:
    """A gait walked in feltool's loop with its designed (unperturbed) parameters.

    Attributes:
        walked: Every step passed the contact checks.
        steps: Steps walked [-].
        reason: Why it stopped (not walking, fell), or None.
        min_normal_force_mg: Least stance normal force over the walk, per m g [-].
        max_friction_ratio: Largest |F_x|/F_z [-].
        max_impulse_ratio: Largest touchdown |I_x|/I_z [-].
        min_clearance_m: Lowest swing foot outside the scuffing zone in [m].
        max_torque: Largest |motor torque| in [N m].
        step_length_m, step_duration_s: Mean over the last cycle, in [m] and [s].
        feedback: Summed mean |feedback| of the last cycle in [N m].
        poincare: :func:`feltool.gait.poincare.poincare`'s result at the end of the walk (empty when it
            did not walk).
        frames: The walk's configurations in the world ``(n, nq)``, one per control step: the
            physical legs keep their names and the base moves on by each step's length (for
            viewing; the loop itself relabels and re-anchors at every touchdown).
        scuffs: Control steps that started with the swing foot below the ground behind the
            stance foot, ignored by the compass-gait convention (``walking.scuff_behind``) [-].
        q_end, v_end: The state at the end of the walk.
    """

    walked: bool
    steps: int
    reason: str | None
    min_normal_force_mg: float = np.nan
    max_friction_ratio: float = np.nan
    max_impulse_ratio: float = np.nan
    min_clearance_m: float = np.nan
    max_torque: float = np.nan
    step_length_m: float = np.nan
    step_duration_s: float = np.nan
    feedback: float = np.nan
    poincare: dict[str, Any] = field(default_factory=dict)
    frames: np.ndarray | None = None
    scuffs: int = 0
    q_end: np.ndarray | None = None
    v_end: np.ndarray | None = None

    @property
    def stable(self) -> bool:
        """Walked, a fixed point found and its spectral radius below 1."""
        p = self.poincare
        return self.walked and bool(p.get("fixed_point_found")) and p["spectral_radius"] < 1.0


def verify_design(exp, steps: int = 20, poincare_analysis: bool = True,
                  spectrum: bool = True, jacobian: dict | None = None) -> Verification:
    """Walk the experiment's design (``exp.theta_demo``, nothing learned) for ``steps`` steps
    from its designed start, with the contact checks; then its Poincaré fixed point.

    Args:
        exp: A built physical walker experiment (:class:`feltool.experiment.experiment.Experiment`).
        steps: Steps to walk [-] (rounded up to whole cycles; 0: none, the fixed point
            searched from the designed start).
        poincare_analysis: Find the fixed point and its spectral radius after the walk.
        spectrum: With the fixed point, its eigenvalues (else only the fixed point: its
            ``spectral_radius`` is not known and :attr:`Verification.stable` is False).
        jacobian: The fixed point's Newton Jacobian carried between calls
            (:func:`feltool.gait.poincare.poincare`).
    """
    hyb = exp.hybrid
    W = hyb.walker
    spc = exp.config.walking.steps_per_cycle
    P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
    q, v = hyb.initial_state(P, Pv)
    if steps == 0:  # only the fixed point
        out = Verification(True, 0, None, q_end=q, v_end=v)
        if poincare_analysis:
            out.poincare = poincare(exp, exp.theta_demo, q, v, spectrum=spectrum,
                                    jacobian=jacobian)
        return out
    mg = exp.robot.total_mass * float(np.linalg.norm(exp.robot.model.gravity.linear))
    fast = walk_compiled(exp, q, v, steps, mg)
    if fast is not None:
        if poincare_analysis:
            fast.poincare = poincare(exp, exp.theta_demo, fast.q_end, fast.v_end,
                                     spectrum=spectrum, jacobian=jacobian)
            p = fast.poincare
            if p.get("fixed_point_found") and p.get("impacts_per_cycle"):
                n = p["impacts_per_cycle"]  # the periodic gait's own step (touchdowns located
                fast.step_length_m = p["stride_length_m"] / n  # within the sub-step)
                fast.step_duration_s = p["stride_length_m"] / p["speed_m_per_s"] / n
        return fast
    done, stats, frames, x0, log, rows_q = 0, [], [], 0.0, None, []
    for _ in range(-(-steps // spc)):
        log = hyb.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
        starts = [0] + [k for k, _, _ in log.impacts] + [len(log.q)]
        for i, (a, b) in enumerate(zip(starts[:-1], starts[1:])):
            rows_q += list(log.q[a:b])
            for qk in log.q[a:b]:  # the world's view: legs by their own names, moving on
                if (done + i) % 2:
                    qk, _ = W.walker.relabel(qk, np.zeros(exp.robot.model.nv))
                qk = qk.copy()
                qk[W.base_q[0]] += x0
                frames.append(qk)
            if i < len(log.impacts):
                x0 += log.steps[i].length
        stats += log.steps[:len(log.impacts)] if not log.fall else log.steps
        done += len(log.impacts)
        if log.fall:
            return Verification(False, done, log.fall, **_extremes(stats, mg),
                                frames=np.array(frames),
                                scuffs=_scuffs(W, exp.robot.model, np.array(rows_q)))
        q, v = log.q_end, log.v_end
    last = log.steps[:len(log.impacts)]
    out = Verification(True, done, None, **_extremes(stats, mg),
                       step_length_m=float(np.mean([s.length for s in last])),
                       step_duration_s=float(np.mean([s.duration for s in last])),
                       feedback=float(np.abs(log.u_fb).mean(0).sum()), frames=np.array(frames),
                       scuffs=_scuffs(W, exp.robot.model, np.array(rows_q)), q_end=q, v_end=v)
    if poincare_analysis:
        out.poincare = poincare(exp, exp.theta_demo, q, v, spectrum=spectrum,
                                jacobian=jacobian)
    return out


def walk_compiled(exp, q: np.ndarray, v: np.ndarray, steps: int,
                  mg: float) -> Verification | None:
    """:func:`verify_design`'s walk on the experiment's compiled engine (one traced call per
    cycle: its contact statistics and its control steps' states), or None when the experiment
    has no compiled physical engine or a cycle stops (the Python loop then walks it, for its
    message and numbers). Scuffs behind the stance foot are counted at the control steps."""
    from feltool.engines.compiled.engine import compiled_engine
    from feltool.engines.compiled.graph import SCALARS
    from feltool.engines.compiled.physical import CONTACT, row_fields, unpack

    if exp.engine != "compiled" or (engine := compiled_engine(exp)) is None \
            or not engine.physical:
        return None
    hyb, theta = exp.hybrid, exp.theta_demo
    W = hyb.walker
    model, nv, spc = exp.robot.model, engine.lay.nv, W.steps_per_cycle
    k = 4 * nv + len(SCALARS)
    data = engine.data(theta)
    frames, rows_q, rows_u, contacts, x0, done, fb = [], [], [], [], 0.0, 0, 0.0
    for _ in range(-(-steps // spc)):
        state0 = engine.state(theta, q, v)
        state, stats, rows = (np.asarray(x) for x in engine.trace(0, state0, data)[:3])
        stats = stats.ravel()
        if stats[k] != 0 or not np.isfinite(state).all():
            return None
        m = int(round(stats[k + 1]))
        rw = unpack(rows, row_fields(nv))
        Q, U = rw["q"][:, :m].T, rw["tau"][:, :m].T
        at = [int(round(a)) for a in stats[k + 2:k + 2 + spc]]
        lengths = stats[k + 2 + spc:k + 2 + 2 * spc]
        contacts.append(dict(zip(CONTACT, stats[k + 2 + 2 * spc:].tolist())))
        starts = [0] + at
        for i, (a, b) in enumerate(zip(starts, starts[1:])):
            for qk in Q[a:b]:
                rows_q.append(qk)
                if (done + i) % 2:
                    qk, _ = W.walker.relabel(qk, np.zeros(nv))
                qk = qk.copy()
                qk[W.base_q[0]] += x0
                frames.append(qk)
            x0 += float(lengths[i])
        rows_u.append(U[:, W.motor_v])
        done += spc
        fb = float(np.abs(stats[:nv]).sum())
        q, v = state[-2 * nv:-nv].copy(), state[-nv:].copy()
    pick = lambda key, f: f(c[key] for c in contacts)  # noqa: E731
    out = Verification(
        True, done, None, min_normal_force_mg=pick("min_normal_force", min) / mg,
        max_friction_ratio=pick("max_friction_ratio", max),
        max_impulse_ratio=pick("max_impulse_ratio", max),
        min_clearance_m=min((c["min_clearance"] for c in contacts
                             if np.isfinite(c["min_clearance"])), default=np.nan),
        max_torque=float(np.abs(np.vstack(rows_u)).max()) if rows_u else np.nan,
        step_length_m=contacts[-1]["step_length"],
        step_duration_s=contacts[-1]["duration"] / spc, feedback=fb,
        frames=np.array(frames), q_end=q, v_end=v)
    out.scuffs = _scuffs(W, model, np.array(rows_q))
    return out


def _scuffs(W, model, Q: np.ndarray) -> int:
    """Control steps whose state has the swing foot below the ground behind the stance foot
    (0 unless the compass-gait convention ``walking.scuff_behind`` lets the walk go on)."""
    if not W.checks.scuff_behind or not len(Q):
        return 0
    data = model.createData()
    count = 0
    for q in Q:
        pin.framesForwardKinematics(model, data, q)
        stance, swing = (W.walker.foot_position(data, f) for f in (W.stance, W.swing))
        count += int(swing[-1] < 0.0 and swing[0] <= stance[0])
    return count


def _extremes(stats: list, mg: float) -> dict[str, float]:
    finite = lambda xs: [x for x in xs if np.isfinite(x)]  # noqa: E731
    return {
        "min_normal_force_mg": min((s.min_normal_force for s in stats), default=np.nan) / mg,
        "max_friction_ratio": max((s.max_friction_ratio for s in stats), default=np.nan),
        "max_impulse_ratio": max(finite([s.impulse_ratio for s in stats]), default=np.nan),
        "min_clearance_m": min(finite([s.min_clearance for s in stats]), default=np.nan),
        "max_torque": max((s.max_torque for s in stats), default=np.nan),
    }


@dataclass
class Orbit:
    """The loop's periodic cycle at its control steps, in the cycle's first step's labels.

    Attributes:
        q, v, a: Per control step ``(n, nv)``: positions (angles of every velocity coordinate,
            [rad] or [m]), velocities and the contact dynamics' accelerations.
        samples_per_step: Control steps of each step of the cycle [-].
        feedback: Summed mean |feedback| over the cycle in [N m].
    """

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    samples_per_step: list[int]
    feedback: float


def periodic_orbit(exp, x_star: np.ndarray) -> Orbit:
    """The cycle from the fixed point ``x_star = (q, v)`` of the design's loop, recorded at its
    control steps; the steps after the first in the first step's labels (relabelled back)."""
    hyb, W = exp.hybrid, exp.hybrid.walker
    model = exp.robot.model
    cycle = _traced_cycle(exp, x_star[:model.nq], x_star[model.nq:])
    if cycle is None:
        P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
        log = hyb.run_cycle(exp.dynamics, x_star[:model.nq], x_star[model.nq:], P, Pv, Pa)
        if log.fall:  # a fixed point that was found walking: only a changed world gets here
            raise GaitDesignError(f"the gait's fixed point does not walk: {log.fall}")
        at = [k for k, _, _ in log.impacts]
        cycle = (log.q, log.v, [W.B @ tau for tau in log.tau], log.u_fb, at,
                 np.asarray(log.stance))
    Qs, Vs, Taus, u_fb, at, labels = cycle
    starts = [0] + list(at)
    counts = [b - a for a, b in zip(starts[:-1], starts[1:])]
    neutral = pin.neutral(model)
    Q, V, A = (np.zeros((len(Qs), model.nv)) for _ in range(3))
    for k, (q, v, tau) in enumerate(zip(Qs, Vs, Taus)):
        a = W.contact.stance(q, v, tau, W.stance).a
        if labels[k]:  # a step in the other labels: back to the first step's
            q, v = W.walker.relabel(q, v)
            _, a = W.walker.relabel(q, a)
        Q[k], V[k], A[k] = pin.difference(model, neutral, q), v, a
    return Orbit(Q, V, A, counts, float(np.abs(u_fb).mean(0).sum()))


def _traced_cycle(exp, q: np.ndarray, v: np.ndarray):
    """One cycle from ``(q, v)`` on the compiled engine: its control steps' ``q, v``, applied
    generalized forces, feedback, touchdown steps and step labels (1 in every second step);
    None without a compiled physical engine or when the cycle stops."""
    from feltool.engines.compiled.engine import compiled_engine
    from feltool.engines.compiled.graph import SCALARS
    from feltool.engines.compiled.physical import row_fields, unpack

    if exp.engine != "compiled" or (engine := compiled_engine(exp)) is None \
            or not engine.physical:
        return None
    nv, spc = engine.lay.nv, exp.hybrid.walker.steps_per_cycle
    k = 4 * nv + len(SCALARS)
    theta = exp.theta_demo
    _, stats, rows = (np.asarray(x) for x in engine.trace(0, engine.state(theta, q, v),
                                                          engine.data(theta))[:3])
    stats = stats.ravel()
    if stats[k] != 0:
        return None
    m = int(round(stats[k + 1]))
    rw = unpack(rows, row_fields(nv))
    at = [int(round(a)) for a in stats[k + 2:k + 2 + spc]]
    labels = np.zeros(m, dtype=int)
    for i, (a, b) in enumerate(zip([0] + at, at)):
        labels[a:b] = i % 2
    return rw["q"][:, :m].T, rw["v"][:, :m].T, rw["tau"][:, :m].T, rw["U"][:, :m].T, at, labels


def orbit_config(raw: dict[str, Any], exp, orbit: Orbit) -> dict[str, Any]:
    """``raw`` with every ``samples`` demo replaced by the orbit's samples at the control rate
    (the last knot closes the period: the first sample again) and ``period_s`` the orbit's
    cycle."""
    n = len(orbit.q)
    out = copy.deepcopy(raw)
    out["period_s"] = _num(n * exp.config.dt)
    for name, jc in (out.get("joints") or {}).items():
        if not isinstance(jc, dict) or (jc.get("demo") or {}).get("kind") != "samples":
            continue
        i = exp.robot.v_index(name)
        jc["demo"] = {"kind": "samples", **{
            key: [_num(x) for x in np.append(X[:, i], X[0, i])]
            for key, X in (("q", orbit.q), ("v", orbit.v), ("a", orbit.a))}}
    walking = out.get("walking")
    if isinstance(walking, dict) and walking.get("settle_cycles"):
        walking["settle_cycles"] = 0  # the orbit starts on itself: nothing to settle
    return out


def close_on_orbit(raw: dict[str, Any], source: Path | None, build, steps: int = 20,
                   rounds: int = 3) -> tuple[dict[str, Any], Orbit, Verification]:
    """The config whose demos are its own loop's periodic orbit.

    The design in ``raw`` is verified (:func:`verify_design`); its fixed point's cycle becomes
    the demos (:func:`orbit_config`). A cycle of several steps must give every step the same
    number of control steps (the phase gives each step an equal share of the samples); when
    the orbit's steps differ, the first step's samples are used for every step (a symmetric
    reference, whose orbit is then a fixed point of the one-step map) and the orbit is found
    again, at most ``rounds`` times.

    Args:
        raw: A physical walker's config with ``samples`` demos (e.g. ``feltool gait``'s).
        source: Where ``raw`` came from (relative robot paths).
        build: ``build(raw, source) -> Experiment`` (:func:`feltool.runs.experiments.build_experiment`).
        steps: Steps walked by each verification [-].

    Returns:
        The closed config, its orbit, and the verification of the *closed* config (walk,
        fixed point and spectral radius of the loop that tracks the orbit).

    Raises:
        GaitNotWalking: the design (or a closed round) does not walk, or has no stable fixed point.
    """
    current, jacobian = raw, {}  # (a round's Jacobian starts the next round's Newton)
    for i in range(rounds):
        exp = build(current, source)
        # the design walked; a later round's symmetric reference only has its fixed point
        # found (from its own start) before the closed config's walk
        check = verify_design(exp, steps if i == 0 else 0, spectrum=False, jacobian=jacobian)
        if not check.walked or not check.poincare.get("fixed_point_found"):
            raise GaitNotWalking(check)
        orbit = periodic_orbit(exp, np.array(check.poincare["fixed_point_q"]
                                             + check.poincare["fixed_point_v"]))
        if len(set(orbit.samples_per_step)) == 1:
            closed = orbit_config(current, exp, orbit)
            final = verify_design(build(closed, source), steps)
            if not final.stable:
                raise GaitNotWalking(final)
            return closed, orbit, final
        current = orbit_config(current, exp, _first_step_repeated(orbit, exp))
    raise GaitNotWalking(check, f"the orbit's steps kept different lengths "
                                f"{orbit.samples_per_step} after {rounds} rounds")


def _first_step_repeated(orbit: Orbit, exp) -> Orbit:
    """The orbit's first step for every step of the cycle (in the first step's labels: every
    second step relabelled)."""
    m, steps = orbit.samples_per_step[0], len(orbit.samples_per_step)
    _, R = exp.hybrid.walker.walker.relabel_matrices()
    parts = [(X[:m] @ R.T if s % 2 else X[:m]) for s in range(steps)
             for X in (orbit.q, orbit.v, orbit.a)]
    q, v, a = (np.vstack(parts[i::3]) for i in range(3))
    return Orbit(q, v, a, [m] * steps, orbit.feedback)


class GaitNotWalking(GaitDesignError):
    """A designed gait that does not walk in feltool's loop, or walks without a stable orbit
    (exit code 1)."""

    def __init__(self, check: Verification, message: str | None = None):
        p = check.poincare
        if message is None and not check.walked:
            message = f"not walking after {check.steps} steps: {check.reason}"
        elif message is None and p.get("reason"):  # fell while the orbit was looked for
            message = f"walks {check.steps} steps, then {p['reason']}"
        elif message is None and not p.get("fixed_point_found"):
            message = ("walks, but the loop has no periodic orbit nearby (fixed-point residual "
                       f"{p.get('fixed_point_residual', np.nan):.2g})")
        elif message is None and not p.get("smooth", True):
            plus, minus = p["spectral_radius_one_sided"]
            message = (f"walks, but its orbit is unstable on one side (step-to-step map "
                       f"spectral radius {plus:.3g} for perturbations ahead, {minus:.3g} behind:"
                       " the loop drifts off the orbit to a nearby one; another step length, "
                       "duration or speed may give a stable one)")
        elif message is None:
            message = f"walks, but its orbit is unstable (spectral radius {p['spectral_radius']:.3g})"
        super().__init__(message)
        self.check = check


def _num(x: float) -> float:
    """Ten significant digits: the feedback on the written orbit is then ~1e-7 N m rather than
    rounding's 1e-12, far below anything the loop or learning resolves."""
    return float(f"{float(x):.10g}")
