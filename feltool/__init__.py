"""feltool: feedback error learning (FEL) of rhythmic movement primitives (RMPs) on URDF robots.

Python API, as simple as the CLI::

    from feltool import load_experiment, run_seed
    exp = load_experiment("configs/two_link_standard.yaml")
    result = run_seed(exp, seed=0, cycles=50)

How the package is organised (subpackages and the one way their imports run):
docs/architecture.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from feltool._version import __version__
from feltool.errors import ConfigError, FeltoolError, InputError, RobotError, SimulationDiverged

#: The public names loaded on first use (PEP 562): ``import feltool`` (and the command line's
#: ``feltool --help``) does not pay for Pinocchio, SciPy, trimesh and the experiment's modules.
_LAZY = {
    "Experiment": "feltool.experiment.experiment",
    "Robot": "feltool.robot.robot", "load_robot": "feltool.robot.robot",
    "build_experiment": "feltool.runs.experiments", "load_experiment": "feltool.runs.experiments",
    "SeedResult": "feltool.runs.seed", "run_seed": "feltool.runs.seed",
}

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment
    from feltool.robot.robot import Robot, load_robot
    from feltool.runs.experiments import build_experiment, load_experiment
    from feltool.runs.seed import SeedResult, run_seed


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'feltool' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


__all__ = [
    "ConfigError", "Experiment", "FeltoolError", "InputError", "Robot", "RobotError",
    "SeedResult", "SimulationDiverged", "__version__", "build_experiment", "load_experiment",
    "load_robot", "run_seed",
]
