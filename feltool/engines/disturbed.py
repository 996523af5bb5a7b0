"""An experiment's disturbed plant and loop: the model error, the disturbed arm loop and the
walker's disturbance, built from the experiment's parts.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from feltool.dynamics.interface import Dynamics, make_dynamics
from feltool.plant.disturbances import DisturbedLoop, WalkerDisturbance, scaled_model

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment


def walker_disturbance(exp: Experiment) -> WalkerDisturbance | None:
    """A fresh walker disturbance (one per seed), or None without a ``disturbances:`` block."""
    spec = exp.config.disturbances
    if spec is None:
        return None
    return WalkerDisturbance(exp.hybrid.walker, spec, exp.config.dt)


def disturbed_plant(exp: Experiment) -> Dynamics:
    """The plant under ``disturbances.model_error``: the known model's robot scaled (the known
    model itself untouched), or the experiment's plant when nothing is scaled."""
    me = exp.config.disturbances.model_error
    if me.mass_scale == 1.0 and me.length_scale == 1.0:
        return exp.plant if exp.plant is not None else exp.dynamics
    backend = "casadi" if exp.config.backend == "casadi" else "pinocchio"
    return make_dynamics(scaled_model(exp.robot.model, me.mass_scale, me.length_scale), backend)


def disturbed_loop(exp: Experiment) -> DisturbedLoop | None:
    """A fresh disturbed loop (one per seed: it owns the delay buffer), or None without a
    ``disturbances:`` block."""
    spec = exp.config.disturbances
    if spec is None:
        return None
    loop = exp.loop
    return DisturbedLoop(disturbed_plant(exp), exp.law, loop.actuated, loop.dt, loop.substeps,
                         loop.integrator, loop.error_rows, loop.limits, spec)
