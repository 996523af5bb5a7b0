"""Why a seed diverged: the quantity that ran away, its value, the step of the cycle it
happened at, and the setting of the config most likely behind it.

A seed stops (:func:`feltool.runs.seed.run_seed`) when its state becomes non-finite, a joint
velocity exceeds ``sim.max_velocity``, or a controlled quantity strays further than
``sim.max_error_rad`` from its reference (a fall). :func:`explain` finds the first step and
the joint or target where that happened in the cycle's trace, and names the likely cause:
in the first cycle nothing has been learned yet, so the loop itself (the gains against the
rate: :mod:`feltool.experiment.checks`, or the learned joints' random start); later, the learning step
(the rates, when the error feedback had been growing), or an event of that cycle.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from feltool.control.feedback import wrap

if TYPE_CHECKING:
    from feltool.engines.outcome import CycleOutcome
    from feltool.experiment.experiment import Experiment


def explain(exp: Experiment, out: CycleOutcome, cycle: int,
            rows: list[dict[str, Any]]) -> str | None:
    """The reason a seed stops after ``cycle`` (its metric ``rows`` before it), or None."""
    sim = exp.config.sim
    if out.fall:
        return out.fall
    if out.finite and out.max_speed <= sim.max_velocity and out.max_error <= sim.max_error_rad:
        bad = _nonfinite_parameters(exp, out)
        if bad is None:
            return None
        L = exp.config.learning
        return (f"the learning update after the cycle made {bad} non-finite (NaN or infinite) "
                f"while the cycle itself stayed finite; the last finite parameters are kept; "
                f"likely cause: the step of learning.update {L.update} (learning.rates: "
                f"weights {L.rates.weights:g}, gauss_newton {L.rates.gauss_newton:g}, goal "
                f"{L.rates.goal:g}) is too large or "
                "ill-conditioned for this robot")
    return f"{_runaway(exp, out)}; likely cause: {_cause(exp, cycle, rows)}"


def _nonfinite_parameters(exp: Experiment, out: CycleOutcome) -> str | None:
    """The parameters a cycle's update made non-finite, named as params/seed-N.npz names
    them, or None when every one is finite."""
    parts = []
    theta = np.asarray(out.theta_next, dtype=float)
    if not np.all(np.isfinite(theta)):
        for key, value in exp.split_parameters(theta).items():
            bad = ~np.isfinite(np.asarray(value, dtype=float))
            if bad.any():
                parts.append(f"{key} ({int(bad.sum())} of {bad.size})")
        parts = parts or ["the RMP parameters"]
    if out.theta_m_next is not None and \
            not np.all(np.isfinite(np.asarray(out.theta_m_next, dtype=float))):
        parts.append("model.theta (the inverse-model correction)")
    return ", ".join(parts) or None


def _unit(exp: Experiment, j: int) -> str:
    joint = exp.robot.model.joints[exp.robot.joint_id(exp.joints[j])]
    return "m" if joint.shortname().removeprefix("JointModel").startswith("P") else "rad"


def _at(exp: Experiment, k: int) -> str:
    return f"at step {k} of the cycle (t = {k * exp.config.dt:.4g} s)"


def _runaway(exp: Experiment, out: CycleOutcome) -> str:
    """The first quantity beyond its bound in the cycle, its value and the step."""
    sim, law = exp.config.sim, exp.law
    log, Qd = out.trace()
    q, v = np.asarray(log.q), np.asarray(log.v)
    with np.errstate(all="ignore"):
        bad = ~(np.isfinite(q) & np.isfinite(v))  # nq = nv: every joint has one coordinate
        fast = np.abs(v) > sim.max_velocity
        k_bad = int(np.argmax(bad.any(axis=1))) if bad.any() else None
        if fast.any():
            k = int(np.argmax(fast.any(axis=1)))
            j = int(np.argmax(np.where(fast[k], np.abs(v[k]), -1.0)))
            then = "" if k_bad is None else \
                f"; the state became non-finite at step {k_bad}"
            return (f"joint {exp.joints[j]}'s velocity reached {v[k, j]:.3g} {_unit(exp, j)}/s "
                    f"{_at(exp, k)} (sim.max_velocity = {sim.max_velocity:g}){then}")
        if not out.finite:
            if k_bad is None:
                return f"the state became non-finite in the cycle's last step ({len(q)})"
            j = int(np.argmax(bad[k_bad]))
            return f"joint {exp.joints[j]}'s state became non-finite {_at(exp, k_bad)}"
        R, _ = law.references(Qd, Qd)
        y = law.quantity(q)
        err = np.abs(wrap(R - y))
        err[:, ~(law.tracking | law.stabilizing)] = 0.0
    far = err > sim.max_error_rad
    k = int(np.argmax(far.any(axis=1)))
    row = int(np.argmax(far[k]))
    return (f"{_quantity(exp, row)} was {y[k, row]:.3g} rad against its reference "
            f"{R[k, row]:.3g} rad {_at(exp, k)}, {err[k, row]:.3g} rad off (sim.max_error_rad "
            f"= {sim.max_error_rad:g}): the robot fell")


def _quantity(exp: Experiment, row: int) -> str:
    """How the config names a controlled quantity."""
    name = exp.joints[row]
    jc = exp.config.joints[name]
    if jc.role == "stabilize":
        t = jc.target
        what = f"frame {t.frame}'s angle" if t.frame else \
            f"link angle {t.link_angle or [name]}"
        return f"the target of joint {name} ({what})"
    return f"joint {name}'s tracked " + (f"link angle {jc.link_angle}" if jc.link_angle
                                         else "angle")


def _cause(exp: Experiment, cycle: int, rows: list[dict[str, Any]]) -> str:
    """The setting most likely behind a divergence in ``cycle``."""
    cfg = exp.config
    L = cfg.learning
    events = [ev for ev in cfg.events if ev.cycle == cycle]
    if events:
        return (f"the world changed at this cycle (events: {events[0].kind}); the feedback "
                "gains could not hold the changed robot")
    if not rows:
        from feltool.experiment.checks import gain_problems, timestep_problems

        loop = gain_problems(exp) + timestep_problems(exp)
        if loop:
            return f"the loop itself, before any learning step: {loop[0][0]}: {loop[0][1]}"
        learned = ", ".join(exp.learned_joints)
        return ("the first cycle, before any learning step: the feedback gains (joints.*.gains) "
                "are too weak or too stiff for the motion" + (
                    f", or the learned joints' random start is too far off (joints.{learned}"
                    ".learn.weight_scale, goal_spread)" if learned else ""))
    fb = np.array([r["fb_abs_mean_error"] for r in rows])
    norms = [r["param_norm"] for r in rows]
    if L.update in ("gradient", "gauss_newton") and exp.learned_joints:
        trend = (f"the error feedback went from {fb.min():.3g} (cycle "
                 f"{int(np.argmin(fb)) + 1}) to {fb[-1]:.3g} N m and the parameters' norm from "
                 f"{norms[0]:.3g} to {norms[-1]:.3g}")
        hint = "lower it" + (", or use learning.update: gauss_newton" if L.update == "gradient"
                             else ", or raise learning.damping")
        hint += "" if L.safeguard else ", or turn learning.safeguard on"
        field = "weights" if L.update == "gradient" else "gauss_newton"
        return (f"the learning step: {trend}; learning.rates.{field} = "
                f"{getattr(L.rates, field):g} (goal {L.rates.goal:g}) is likely too large for "
                f"this robot ({hint})")
    return (f"learning.update {L.update} after {len(rows)} cycles: its step (learning.rates, "
            "ilc.gain) is likely too large, or the gains too weak for the learned motion")
