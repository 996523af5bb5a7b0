"""The MuJoCo plant of an experiment (``plant: {simulator: mujoco}``): what it cannot be
combined with, and the loops that step it (:mod:`feltool.plant.mujoco_arm` for fixed-base
robots, :mod:`feltool.walking.mujoco_walk` for physical walkers)."""

from __future__ import annotations

from feltool.config.experiment import ExperimentConfig
from feltool.control.closed_loop import ClosedLoop
from feltool.errors import ConfigError, RobotError
from feltool.plant.mujoco_arm import MujocoArmLoop
from feltool.robot.mujoco import compile_mujoco, import_mujoco
from feltool.robot.robot import Robot
from feltool.walking.mujoco_walk import MujocoLoop
from feltool.walking.physical import PhysicalLoop


def uses_mujoco(cfg: ExperimentConfig | None) -> bool:
    """Whether the config's plant is MuJoCo."""
    return cfg is not None and cfg.plant is not None and cfg.plant.simulator == "mujoco"


def mujoco_problems(cfg: ExperimentConfig) -> list[tuple[str, str]]:
    """What a MuJoCo plant cannot run in ``cfg``, as ``(yaml path, message)`` (the package
    missing first)."""
    if not uses_mujoco(cfg):
        return []
    try:
        import_mujoco()
    except RobotError as exc:
        return [("plant.simulator", str(exc))]
    out = []
    if any(ev.changes_world for ev in cfg.events):
        out.append(("events", "a changed world is not supported with plant.simulator: mujoco"))
    if cfg.disturbances is not None:
        out.append(("disturbances", "not supported with plant.simulator: mujoco"))
    if cfg.sim.integrator != "semi_implicit_euler":
        out.append(("sim.integrator", "MuJoCo's Euler step is semi-implicit: use "
                                      "semi_implicit_euler with plant.simulator: mujoco"))
    if cfg.sim.joint_limits == "enforce":
        out.append(("sim.joint_limits", "enforce is not supported with plant.simulator: mujoco "
                                        "(report or ignore)"))
    if cfg.walking is not None and not cfg.walking.physical:
        out.append(("plant.simulator", "mujoco runs fixed-base robots and physical walkers "
                                       "(walking.feet), not a pinned walker"))
    if cfg.walking is not None and cfg.walking.physical and cfg.walking.poincare:
        out.append(("walking.poincare", "the Poincare map is not computed on MuJoCo's plant (its "
                                        "finite differences would restart MuJoCo's soft "
                                        "contacts at every perturbed state): set it false"))
    if cfg.actuation is not None:
        out.append(("actuation", "not supported with plant.simulator: mujoco"))
    tc, h = cfg.plant.contact_timeconst, cfg.dt / cfg.sim.substeps
    if tc is not None and tc < 2.0 * h * (1 - 1e-9):
        out.append(("plant.contact_timeconst", f"{tc:g} s is below two MuJoCo timesteps "
                    f"(2 x {h:g} s; MuJoCo needs at least two): raise sim.substeps or it"))
    return out


def mujoco_arm_loop(cfg: ExperimentConfig, robot: Robot, loop: ClosedLoop,
                    src: str | None) -> MujocoArmLoop:
    """``loop`` with MuJoCo stepping ``robot``'s URDF."""
    try:
        sim = compile_mujoco(robot, cfg.dt / cfg.sim.substeps,
                             integrator=cfg.plant.mujoco_integrator)
    except RobotError as exc:
        raise ConfigError([("plant.simulator", str(exc))], src) from None
    return MujocoArmLoop(loop, sim)


def mujoco_walker_loop(cfg: ExperimentConfig, loop: PhysicalLoop, src: str | None) -> MujocoLoop:
    """The physical walker's ``loop`` with MuJoCo as its world."""
    wm = loop.walker.walker
    base = list(wm.base) if cfg.walking.base == "planar" else None
    try:
        sim = compile_mujoco(wm.robot, cfg.dt / cfg.sim.substeps, base, dict(wm.feet),
                             cfg.walking.friction, loop.known.model.gravity.linear,
                             cfg.plant.mujoco_integrator, cfg.plant.contact_timeconst)
    except RobotError as exc:
        raise ConfigError([("plant.simulator", str(exc))], src) from None
    return MujocoLoop(loop, sim, cfg.plant.impact_sample)
