"""Which engine runs an experiment's learning cycles.

``backend: auto`` (the default) runs the compiled engine (:mod:`feltool.engines.compiled`) when
a C compiler exists and the engine runs every feature of the experiment, else the Python engine
(:mod:`feltool.engines.python`); ``backend: compiled`` insists and refuses, naming each feature
it lacks; ``pinocchio`` and ``casadi`` run the Python engine.
"""

from __future__ import annotations

from feltool.engines.compiled.library import c_compiler
from feltool.engines.compiled.support import check_supported, unsupported
from feltool.errors import ConfigError
from feltool.experiment.experiment import Experiment


def choose_engine(exp: Experiment) -> Experiment:
    """Set ``exp.engine`` and ``exp.engine_reason`` (and return ``exp``); raise
    :class:`~feltool.errors.ConfigError` when ``backend: compiled`` asks for a feature the
    compiled engine lacks."""
    backend = exp.config.backend
    plant = exp.config.plant
    if plant is not None and plant.simulator == "mujoco":
        if backend == "compiled":
            raise ConfigError([("plant.simulator", "backend 'compiled': MuJoCo steps the plant "
                                "in the Python engine only; use backend auto or pinocchio")],
                              str(exp.source) if exp.source else None)
        exp.engine, exp.engine_reason = "python", (
            f"backend {backend}: plant.simulator: mujoco runs on the Python engine")
        return exp
    if backend == "compiled":
        check_supported(exp)
        choice = ("compiled", "backend: compiled")
    elif backend != "auto":
        choice = ("python", f"backend: {backend}")
    elif c_compiler() is None:
        choice = ("python", "backend auto: no C compiler (cc or gcc; set CC)")
    else:
        missing = unsupported(exp)
        choice = (("python", f"backend auto: {missing[0][0]}: {missing[0][1]}")
                  if missing else ("compiled", "backend auto"))
    exp.engine, exp.engine_reason = choice
    return exp
