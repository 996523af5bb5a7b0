"""ILC and the baseline on an arm: their cycle runner (the Python engine's cycle, then the ILC
update of the feedforward), the channels they act on.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from feltool.engines.python import cycle_outcome, per_cycle
from feltool.learning.fel import feedforward
from feltool.learning.ilc import ILC_UPDATES, OWN_RUNNER, NormOptimalILC, PTypeILC, lifted_jacobian

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment




def channels(exp: Experiment) -> tuple[np.ndarray, np.ndarray]:
    """Joint indices of ILC's learned torques (inputs) and of its error signal (outputs): the
    error joints, or every actuated joint when a frame angle is in the error signal (its torque
    acts on all joints that move the frame)."""
    actuated = exp.loop.actuated > 0
    mask = exp.learner.error_mask > 0
    if any(exp.loop.error_rows[row] > 0 for row in exp.law.frames):
        mask = mask | actuated
    return np.flatnonzero(mask & actuated), np.flatnonzero(mask)


def cycle_runner(exp: Experiment, theta0: np.ndarray, seed: int,
                 loop_for: Callable) -> Callable:
    """The cycle function ``(theta, q, v, plant, theta_m=None) -> CycleOutcome`` for the ILC
    learners, the baseline, and any learner under ``disturbances:``.

    The returned function carries its state (the learned sequence, the cycle count that seeds
    each cycle's disturbances, the delay buffer) and exposes it to checkpoints as
    ``extra_state()`` / ``restore_state(saved)`` and to the run's params as ``extra_params()``.
    """
    from feltool.engines.disturbed import disturbed_loop
    from feltool.plant.disturbances import cycle_rng

    cfg = exp.config
    update = cfg.learning.update
    n = exp.primitives.n_steps
    Qd, Vd, Ad = exp.primitives.desired(theta0)
    R, Rd = exp.law.references(Qd, Vd)
    u0 = feedforward(exp.dynamics, Qd, Vd, Ad)
    inputs, outputs = channels(exp)
    state = {"dU": np.zeros((n, len(inputs))), "cycle": 0}
    dloop = disturbed_loop(exp)  # None without a disturbances block
    settings = cfg.ilc
    p_type = PTypeILC(settings.gain, round(settings.lead_s * cfg.sim.rate_hz),
                      settings.cutoff_hz, settings.order, cfg.sim.rate_hz)
    norm_opt = NormOptimalILC(settings.weight_error, settings.weight_change)

    def run(theta, q, v, plant, theta_m=None):
        state["cycle"] += 1
        loop = loop_for(plant)
        if dloop is not None:
            loop = dloop
            dloop.rng = cycle_rng(seed, state["cycle"])
        if update not in OWN_RUNNER:
            return per_cycle(exp, theta, q, v, loop)
        u_ff = u0.copy()
        u_ff[:, inputs] += state["dU"]
        log = loop.run_cycle(q, v, R, Rd, u_ff)
        if np.all(np.isfinite(log.v)) and np.all(np.isfinite(log.q)):
            E = log.u_err[:, outputs]
            if update == "ilc_p":
                state["dU"] = p_type.update(state["dU"], log.u_err[:, inputs])
            elif update == "ilc_norm_optimal":
                Tau = exp.loop.actuated * (u_ff + log.u_fb)
                G = lifted_jacobian(exp.robot.model, exp.law, exp.loop.actuated, exp.loop.dt,
                                    exp.loop.substeps, exp.loop.integrator, log.q, log.v,
                                    R, Rd, Tau, inputs, outputs, exp.loop.error_rows)
                state["dU"] = norm_opt.update(state["dU"], E, G)
        return cycle_outcome(exp, log, Qd, theta)

    names = [exp.joints[j] for j in inputs] if update in ILC_UPDATES else []
    return with_state(run, state, dloop, names)


def with_state(run: Callable, state: dict, disturbance, names: list[str]) -> Callable:
    """``run`` with its learned sequence ``state["dU"]`` (one column per name in ``names``)
    and its cycle count ``state["cycle"]`` exposed to checkpoints (``extra_state()``,
    ``restore_state(saved)``, together with the ``disturbance``'s own state) and to the run's
    params (``extra_params()``: ``ilc.<name>.u_ff_correction``, ``(n,)`` in [N m])."""

    def extra_state() -> dict[str, np.ndarray]:
        out = {"ilc_dU": state["dU"], "ilc_cycle": np.array(state["cycle"])}
        if disturbance is not None:
            out.update(disturbance.extra_state())
        return out

    def restore_state(saved) -> None:
        if "ilc_dU" in saved:
            state["dU"] = np.array(saved["ilc_dU"], dtype=float)
            state["cycle"] = int(saved["ilc_cycle"])
        if disturbance is not None:
            disturbance.restore_state(saved)

    def extra_params() -> dict[str, np.ndarray]:
        return {f"ilc.{name}.u_ff_correction": state["dU"][:, c].copy()
                for c, name in enumerate(names)}

    run.extra_state, run.restore_state, run.extra_params = extra_state, restore_state, extra_params
    run.state = state
    return run
