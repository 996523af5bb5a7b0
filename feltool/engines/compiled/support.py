"""What the compiled engine runs: every feature it lacks, named by its YAML path."""

from __future__ import annotations

from feltool.engines.compiled.pinned import free_model, same_dynamics
from feltool.errors import ConfigError


def unsupported(exp) -> list[tuple[str, str]]:
    """What of ``exp`` the compiled engine cannot run, as ``(yaml path, reason)`` (empty: it
    runs all of it)."""
    from feltool.learning.fel import FEL_UPDATES

    cfg, L = exp.config, exp.config.learning
    out = []
    if cfg.plant is not None and cfg.plant.simulator == "mujoco":
        out.append(("plant.simulator", "MuJoCo steps the plant in the Python engine only"))
    if L.sensitivity == "finite_difference":
        out.append(("learning.sensitivity", "finite_difference is the Python engine's check of "
                                            "the exact sensitivity (the compiled engine "
                                            "differentiates exactly)"))
    if L.update not in FEL_UPDATES:
        out.append(("learning.update", f"{L.update} runs in the Python engine only (it has its "
                                       "own cycle runner, feltool.learning.ilc)"))
    if cfg.disturbances is not None:
        out.append(("disturbances", "disturbances run in the Python engine only (their "
                                    "random draws per step, feltool.plant.disturbances)"))
    if cfg.primitives.phase == "adaptive":
        out.append(("primitives.phase", "the adaptive oscillator runs in the Python engine only "
                                        "(its cycle length depends on the measured motion)"))
    if exp.learner.fit == "closed_loop" and L.q_filter_hz is not None:
        out.append(("learning.q_filter_hz", "the Q-filter runs in the Python engine only"))
    if exp.robot.model.nq != exp.robot.model.nv:
        out.append(("robot", "the compiled engine needs joints with one coordinate each"))
    if cfg.walking is not None and cfg.walking.physical:
        from feltool.engines.compiled.support import unsupported_physical

        out += unsupported_physical(exp)
    elif exp.hybrid is not None:
        from feltool.engines.compiled.support import unsupported_walker

        out += unsupported_walker(exp)
    return out


def check_supported(exp) -> None:
    """Raise :class:`ConfigError` naming each feature of ``exp`` the compiled engine lacks."""
    problems = [(where, f"backend 'compiled': {why}; use backend auto or pinocchio")
                for where, why in unsupported(exp)]
    if problems:
        raise ConfigError(problems, str(exp.source) if exp.source else None)


def unsupported_physical(exp) -> list[tuple[str, str]]:
    """What of a physical walker the compiled graph does not run."""
    W, cfg = exp.hybrid.walker, exp.config
    out = []
    if W.phase != "mechanical":
        out.append(("walking.phase", f"{W.phase} runs in the Python engine only (the compiled "
                                     "engine runs the mechanical phase)"))
    if W.steps_per_cycle % 2:
        out.append(("walking.steps_per_cycle", "an odd number of steps per cycle runs in the "
                                               "Python engine only"))
    if cfg.learning.impact_window_s > 0:
        out.append(("learning.impact_window_s", "a physical walker's impact window runs in "
                                                "the Python engine only"))
    if exp.law.frames:
        out.append(("joints", "frame-angle targets on a physical walker run in the Python "
                              "engine only"))
    if cfg.learning.update == "gauss_newton" and cfg.learning.error_space != "motors":
        out.append(("learning.error_space", "Gauss-Newton in joint torques on a physical "
                                            "walker runs in the Python engine only"))
    return out


def unsupported_walker(exp) -> list[tuple[str, str]]:
    """What of a pinned walker (or allocated motors) the compiled graph does not run."""
    H, out = exp.hybrid, []
    W = H.walker
    if W is not None and W.free_model is not None and \
            not same_dynamics(free_model(exp.robot.model), W.free_model):
        out.append(("walking.contact_frame", "the compiled engine's freed model differs from "
                                             "the walker's (locked or continuous joints)"))
    if hasattr(H.known, "rigid"):
        out.append(("plant.friction", "joint friction in a walker's known model runs in the "
                                      "Python engine only"))
    if exp.config.learning.error_space == "motors" or \
            exp.config.learning.error_estimate != "feedback":
        out.append(("learning.error_space", "motor-space errors are for physical walkers"))
    return out
