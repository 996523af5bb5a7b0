"""feltool: feedback error learning (FEL) of rhythmic movement primitives (RMPs) on URDF robots.

Python API, as simple as the CLI::

    from feltool import load_experiment, run_seed
    exp = load_experiment("configs/two_link_standard.yaml")
    result = run_seed(exp, seed=0, cycles=50)

How the package is organised (subpackages and the one way their imports run):
docs/architecture.md.
"""

from feltool._version import __version__
from feltool.errors import ConfigError, FeltoolError, InputError, RobotError, SimulationDiverged
from feltool.experiment.experiment import Experiment
from feltool.robot.robot import Robot, load_robot
from feltool.runs.experiments import build_experiment, load_experiment
from feltool.runs.seed import SeedResult, run_seed

__all__ = [
    "ConfigError", "Experiment", "FeltoolError", "InputError", "Robot", "RobotError",
    "SeedResult", "SimulationDiverged", "__version__", "build_experiment", "load_experiment",
    "load_robot", "run_seed",
]
