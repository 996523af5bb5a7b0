"""feltool: feedback error learning (FEL) of rhythmic movement primitives (RMPs) on URDF robots.

Python API, as simple as the CLI::

    from feltool import load_experiment, run_seed
    exp = load_experiment("configs/two_link_standard.yaml")
    result = run_seed(exp, seed=0, cycles=50)
"""

__version__ = "0.1.0"

from feltool.errors import ConfigError, FeltoolError, InputError, RobotError, SimulationDiverged  # noqa: E402
from feltool.experiment import Experiment, build_experiment, load_experiment  # noqa: E402
from feltool.robot import Robot, load_robot  # noqa: E402
from feltool.seed import SeedResult, run_seed  # noqa: E402

__all__ = [
    "ConfigError", "Experiment", "FeltoolError", "InputError", "Robot", "RobotError",
    "SeedResult", "SimulationDiverged", "__version__", "build_experiment", "load_experiment",
    "load_robot", "run_seed",
]
