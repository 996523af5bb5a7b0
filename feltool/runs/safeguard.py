r"""A learning step that cannot throw a seed away (``learning.safeguard``, on by default).

Cycle h's update moves the parameters by :math:`\Delta_h`; cycle h+1, run with them, tests the
step. If its mean error feedback grows by more than ``learning.safeguard_growth`` over cycle
h's (the cycle whose update it is), or the cycle diverges
(:func:`feltool.runs.divergence.explain`), the step is undone -- the parameters cycle h ran
with and the state it started from are restored -- and taken again at half its length, as a
trust region does; every later step is scaled by the same (halved) factor. A step after which
the feedback grew by less than that factor (but more than :data:`SHRINK`) is kept, and with
the Gauss-Newton update (whose rise is an overshoot of its fraction) the steps after it are
halved too (the trust region shrinks; not below the floor). A seed counts
as diverged only when that factor fell below ``learning.safeguard_min_step``. The rejected
cycle stays in metrics.csv (``rejected`` 1; its feedback, infinite when the cycle diverged), so
cycles-to-convergence count it. An update that makes the parameters non-finite after a cycle that ran
well is undone at once: the cycle runs again from its parameters and state, the steps halved.

Both engines: the factor scales the rates the engine steps with (the learner's, the model
learner's, and the compiled engine's ``params``, :func:`set_step_scale`), so an accepted
cycle's update is the engine's own, per cycle and per step alike. The growth test is suspended
at the cycles an event changes the world or the motion, through its transition and one cycle
after, and at a cycle whose length differs by over 1 % from the one before (an adaptive phase
entraining: the step did not cause that), and the
feedback compared with is counted no lower than :data:`FLOOR` of the first cycle's (a
converged seed's noise is no growth). A slow drift (a few per cent per cycle) is no rejected
step: only a step that throws the cycle after it away is undone. ILC and the feedback-only
baseline have no such step: off for them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from feltool.engines.compiled.graph import parameters
from feltool.engines.outcome import CycleOutcome, SeedState
from feltool.learning.fel import FEL_UPDATES

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment

#: A kept step after which the feedback grew by more than this factor halves the steps after it.
SHRINK = 1.1

#: The feedback a step is compared with is counted as at least this fraction of the first cycle's.
FLOOR = 0.01


class Safeguard:
    """One seed's safeguard: the step scale, the last accepted cycle's feedback, the step to
    undo.

    Args:
        exp: The experiment (its ``learning.safeguard`` settings).
    """

    def __init__(self, exp: Experiment):
        L = exp.config.learning
        self.exp = exp
        self.enabled = bool(L.safeguard) and L.update in FEL_UPDATES and \
            exp.learner.n_learned > 0
        self.growth, self.min_step = float(L.safeguard_growth), float(L.safeguard_min_step)
        self.scale, self.last_fb, self.first, self.rejected = 1.0, math.inf, None, 0
        self.shortened = 0
        # Gauss-Newton's step is a fraction of the model's full step: a rise after a kept step
        # is its overshoot (a fraction over 1), which a trust region shrinks; the gradient's
        # rise is as often the walker's impacts' noise, and only a throwing-away step counts
        self.trust = L.update == "gauss_newton"
        self._n: int | None = None  # the last cycle's steps (a cycle of another speed: no test)
        self.fallback: SeedState | None = None  # parameters and state to go back to
        self.delta: np.ndarray | None = None    # the last accepted step
        self.delta_m: np.ndarray | None = None
        # the cycles whose feedback an event changes: its own, those of its transition, and
        # the next one (compared with a cycle that was partly before the change)
        self._events: set[int] = set()
        for ev in [*exp.config.events, *(e for _, e in exp.config.motion_events)]:
            span = int(getattr(ev, "transition_cycles", 0) or 0)
            self._events.update(range(ev.cycle, ev.cycle + span + 2))

    def start(self) -> None:
        """Before the seed's first cycle (or its resumed one): the engines step with the
        current scale."""
        if self.enabled:
            set_step_scale(self.exp, self.scale)

    def new_reference(self, exp: Experiment, cycle: int) -> None:
        """After ``cycle`` the run walks a new design (``learning.redesign``, experiment
        ``exp``): the next two cycles' feedback is not compared with the old reference's, and
        no step of the old one is undone."""
        self.exp, self.fallback, self._n = exp, None, None
        self._events.update({cycle + 1, cycle + 2})
        if self.enabled:
            set_step_scale(exp, self.scale)

    def finish(self) -> None:
        """After the seed: the experiment's rates as they were (scale 1)."""
        if self.enabled:
            set_step_scale(self.exp, 1.0)

    def judge(self, cycle: int, out: CycleOutcome, state: SeedState,
              reason: str | None) -> tuple[SeedState | None, bool, str | None]:
        """After ``cycle`` ran from ``state`` with outcome ``out`` (``reason``: why it
        diverged, or None): ``(next state, rejected, reason)``. The next state is None when the
        seed stops (``reason`` then says why)."""
        accepted = SeedState(out.theta_next, out.q_end, out.v_end, out.theta_m_next,
                             state.plant)
        if not self.enabled:
            return (None, False, reason) if reason else (accepted, False, None)
        fb = out.fb_error if out.finite and math.isfinite(out.fb_error) else math.inf
        if self.first is None:
            self.first = fb
        floor = FLOOR * self.first if math.isfinite(self.first) else 0.0
        n = out.cycle.n if out.cycle is not None else None  # the cycle's steps (its length)
        same = cycle not in self._events and (n is None or self._n is None
                                               or abs(n - self._n) <= 0.01 * self._n)
        self._n = n
        if out.finite and not _finite_update(out):
            # the cycle ran well, its own update is what broke: run it again from the same
            # parameters and state, with the steps at half the length
            self.rejected += 1
            self.scale *= 0.5
            if self.scale < self.min_step:
                return None, True, (f"learning.safeguard: {self.rejected} steps undone, the "
                                    f"step scale {self.scale:.3g} fell below "
                                    f"learning.safeguard_min_step {self.min_step:g}; last: "
                                    f"{reason}")
            set_step_scale(self.exp, self.scale)
            return SeedState(state.theta, state.q, state.v, state.theta_m,
                             state.plant), True, None
        grew = same and fb > self.growth * max(self.last_fb, floor)
        if (reason or grew) and self.fallback is not None:
            self.rejected += 1
            self.scale *= 0.5
            if self.scale < self.min_step:
                why = reason or (f"the error feedback grew to {fb:.3g} N m from "
                                 f"{self.last_fb:.3g} N m in the cycle before the step")
                return None, True, (f"learning.safeguard: {self.rejected} steps undone, the "
                                    f"step scale {self.scale:.3g} fell below "
                                    f"learning.safeguard_min_step {self.min_step:g}; last: {why}")
            set_step_scale(self.exp, self.scale)
            back = self.fallback
            self.delta = 0.5 * self.delta
            theta_m = None
            if back.theta_m is not None and self.delta_m is not None:
                self.delta_m = 0.5 * self.delta_m
                theta_m = back.theta_m + self.delta_m
            return SeedState(back.theta + self.delta, back.q, back.v,
                             theta_m if theta_m is not None else back.theta_m,
                             state.plant), True, None
        if reason:
            return None, False, reason
        worse = (same and math.isfinite(self.last_fb)
                 and fb > SHRINK * max(self.last_fb, floor))
        if worse and self.trust and 0.5 * self.scale >= self.min_step:  # kept, next ones shorter
            self.scale *= 0.5
            self.shortened += 1
            set_step_scale(self.exp, self.scale)
            accepted.theta = out.theta_next.copy()  # (a new array: the compiled engine's
            if out.theta_m_next is not None:        # batch of cycles ahead had the old rates)
                accepted.theta_m = out.theta_m_next.copy()
        self.last_fb = fb  # the accepted cycle's: its update is tested next
        self.fallback = SeedState(state.theta, state.q, state.v, state.theta_m, state.plant)
        self.delta = out.theta_next - state.theta
        self.delta_m = (None if out.theta_m_next is None or state.theta_m is None
                        else out.theta_m_next - state.theta_m)
        return accepted, False, None

    def row(self, row: dict[str, float], rejected: bool) -> dict[str, float]:
        """The safeguard's columns of a metrics row (``rejected``, ``step_scale``: the scale
        of the step this cycle's update takes)."""
        if self.enabled:
            row["rejected"] = int(rejected)
            row["step_scale"] = self.scale
            if rejected and not math.isfinite(row["fb_abs_mean_error"]):
                row["fb_abs_mean_error"] = math.inf
        return row

    # -- checkpoints ------------------------------------------------------------------------------
    def save(self) -> dict[str, Any]:
        """Arrays for a checkpoint (the seed resumes bit-identically)."""
        if not self.enabled:
            return {}
        first = np.nan if self.first is None else self.first
        n = np.nan if self._n is None else self._n
        out = {"safeguard_scalars": np.array([self.scale, self.last_fb, first, self.rejected,
                                              self.shortened, n], float)}
        if self.fallback is not None:
            out.update({"safeguard_theta": self.fallback.theta, "safeguard_q": self.fallback.q,
                        "safeguard_v": self.fallback.v, "safeguard_delta": self.delta})
            if self.fallback.theta_m is not None and self.delta_m is not None:
                out.update({"safeguard_theta_m": self.fallback.theta_m,
                            "safeguard_delta_m": self.delta_m})
        return out

    def restore(self, saved: dict[str, Any]) -> None:
        """Continue from :meth:`save`'s arrays."""
        if not self.enabled or "safeguard_scalars" not in saved:
            return
        scale, last_fb, first, rejected, shortened, n = np.asarray(
            saved["safeguard_scalars"], float).tolist()
        self.scale, self.last_fb, self.rejected = scale, last_fb, int(rejected)
        self.shortened, self._n = int(shortened), None if math.isnan(n) else int(n)
        self.first = None if math.isnan(first) else first
        if "safeguard_theta" in saved:
            self.fallback = SeedState(saved["safeguard_theta"], saved["safeguard_q"],
                                      saved["safeguard_v"], saved.get("safeguard_theta_m"))
            self.delta, self.delta_m = saved["safeguard_delta"], saved.get("safeguard_delta_m")

    def summary(self) -> dict[str, Any]:
        """The seed's summary entries: ``rejected_steps`` (undone), ``shortened_steps`` (kept,
        the steps after them halved) and the final ``step_scale``."""
        if not self.enabled:
            return {}
        return {"rejected_steps": self.rejected, "shortened_steps": self.shortened,
                "step_scale": self.scale}


def _finite_update(out: CycleOutcome) -> bool:
    """Whether the parameters ``out``'s update gives are all finite."""
    return bool(np.isfinite(out.theta_next).all()) and (
        out.theta_m_next is None or bool(np.isfinite(out.theta_m_next).all()))


def set_step_scale(exp: Experiment, scale: float) -> None:
    """The engines step with ``scale`` times the experiment's rates: the learner's, the model
    learner's (gradient and Levenberg-Marquardt fraction alike) and, when built, the compiled
    engine's ``params`` (:func:`feltool.engines.compiled.graph.parameters`)."""
    base = getattr(exp, "_safeguard_rates", None)
    if base is None:
        base = exp._safeguard_rates = (exp.learner.rates.copy(), exp.model_learner.rate
                                       if exp.model_learner is not None else None)
    exp.learner.rates = base[0] * scale
    if exp.model_learner is not None:
        exp.model_learner.rate = base[1] * scale
    if exp.compiled is not None and getattr(exp.compiled, "functions", None) is not None:
        exp.compiled.params = parameters(exp)


__all__ = ["FLOOR", "SHRINK", "Safeguard", "set_step_scale"]
