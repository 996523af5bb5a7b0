"""A legged config's robot and controller: the robot loaded (a named one, one of
example-robot-data, a URDF; its feet and posture), the gait and the gains it runs with (the
config's, else the robot's defaults); refused before a run: a straight leg in the reference
posture, a leg of fewer than three joints, gains under which a joint's own loop diverges."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from feltool.bounds import MAX_RATE_HZ
from feltool.config.legged import LeggedExperimentConfig, LeggedGainsConfig, TrotGaitConfig
from feltool.errors import ConfigError, RobotError


def load_legged_robot(cfg: LeggedExperimentConfig, base_dir: Path | None = None,
                      source: str | None = None):
    """The config's robot as a :class:`~feltool.walking.legged.model.LeggedModel` (``base_dir``:
    the config's directory, for a relative URDF path). Raises :class:`ConfigError` (of the
    config file ``source``) naming ``robot`` (a missing or unreadable URDF),
    ``walking.feet.<foot>`` (no such frame or link), ``walking.feet`` / ``walking.posture``
    (:func:`check_legs_bent`) or ``walking.gains.joints`` (:func:`check_joint_gains`)."""
    from feltool.walking.legged.crouch import crouched
    from feltool.walking.legged.model import (
        SOLO12_FEET,
        TALOS_FEET,
        legged_model,
        load_legged_urdf,
        posture_q,
    )
    from feltool.walking.legged.tree_feet import quadruped_feet

    feet = {name: foot.model_dump(exclude_none=True) for name, foot in
            (cfg.walking.feet or {}).items()}
    for spec in feet.values():
        if "link" in spec:
            spec["offset"] = list(spec["offset"])
        else:
            spec.pop("offset", None)
    path = cfg.urdf_path(base_dir)
    try:
        if path is None:
            from example_robot_data.robots_loader import load_full

            name = cfg.robot.split(":")[-1]
            try:
                robot, q0, _, srdf = load_full(name)
            except ValueError:
                raise ConfigError([("robot", f"example-robot-data has no robot '{name}' (its "
                                             "quadrupeds: a1, anymal, anymal_c, b1, go1, go2, "
                                             "hyq, solo12)")]) from None
            except Exception as exc:  # its loader's own failure (cassie: an SDF model)
                raise ConfigError([("robot", f"example-robot-data's {name} failed to load: "
                                             f"{exc}")]) from None
            m = robot.model
            floating = m.njoints > 1 and m.joints[1].shortname() == "JointModelFreeFlyer"
            q0 = posture_q(m, np.array(q0), cfg.walking.posture or {}, name)
            if floating and not feet:  # else refused for its base
                feet = {"solo12": SOLO12_FEET, "talos_legs": TALOS_FEET}.get(name) or \
                    srdf_feet(srdf) or quadruped_feet(m, q0, name)
            legged = legged_model(m, feet, q0=q0, effort=cfg.effort, name=name)
        elif not path.is_file():
            raise ConfigError([("robot", f"{path}: no such URDF file")])
        else:
            legged = load_legged_urdf(path, feet, effort=cfg.effort,
                                      posture=cfg.walking.posture or {})
        if cfg.armature is not None:
            legged.model.armature[6:] = cfg.armature
        if cfg.walking.walk is None and not cfg.walking.posture and straight_legs(legged):
            # a quadruped's URDF at its zeros: crouched (a biped's soles are not point feet)
            q0 = crouched(legged.model, legged.q0, legged.feet)
            legged = legged if q0 is None else dataclasses.replace(legged, q0=q0)
        check_legs_bent(cfg, legged)
        check_joint_gains(cfg, legged)
        return legged
    except RobotError as exc:
        raise ConfigError([("robot", str(exc))], source) from None
    except ConfigError as exc:
        raise ConfigError(exc.problems, source) from None


#: An SRDF end effector's name prefix -> the trot's foot (example-robot-data's quadrupeds:
#: lf_foot, rf_foot, lh_foot, rh_foot)
SRDF_FEET = {"lf": "FL", "rf": "FR", "lh": "HL", "rh": "HR"}


def srdf_feet(srdf: str | None) -> dict[str, dict] | None:
    """The trot's feet of an example-robot-data robot from its SRDF file ``srdf``'s end
    effectors named ``lf_*``, ``rf_*``, ``lh_*``, ``rh_*`` (each its parent link's frame); None
    when it has not all four."""
    import xml.etree.ElementTree as ET

    feet = {}
    try:
        root = ET.parse(srdf).getroot() if srdf else None
    except (OSError, ET.ParseError):
        root = None
    for effector in ([] if root is None else root.iter("end_effector")):
        foot = SRDF_FEET.get(str(effector.get("name", "")).lower()[:2])
        if foot and effector.get("parent_link"):
            feet.setdefault(foot, {"frame": effector.get("parent_link")})
    if len(feet) < 4:
        return None
    return {f: feet[f] for f in ("FL", "FR", "HL", "HR")}


def straight_legs(legged, q: np.ndarray | None = None) -> list[str]:
    """The feet whose leg cannot move them in every direction in ``q`` (default the reference
    posture, standing): straight, or folded onto itself."""
    from feltool.walking.legged.contact import LeggedContact
    from feltool.walking.legged.crouch import singular_leg

    q = legged.standing() if q is None else q
    J = LeggedContact(legged).jacobian(q, tuple(legged.feet))
    return [foot for i, foot in enumerate(legged.feet)
            if singular_leg(J[3 * i:3 * i + 3, legged.leg(foot)])]


def check_legs_bent(cfg: LeggedExperimentConfig, legged) -> None:
    """Refuse legs of fewer than three joints (naming ``walking.feet``), and naming
    ``walking.posture`` a reference posture with the base not above the feet or in which a
    foot cannot move along every direction by its leg's joints (and the feet): a straight leg,
    as a URDF's zero posture mostly is, on which the gait's inverse kinematics and the contact
    forces are singular."""
    short = {f: len(legged.leg(f)) for f in legged.feet if len(legged.leg(f)) < 3}
    if short:
        raise ConfigError([("walking.feet", "the gait places each foot in 3D, which takes a "
                            "leg of at least three joints: " + ", ".join(
                                f"{f}'s has {n}" for f, n in short.items()))])
    q = legged.standing()
    given = "" if cfg.walking.posture else " (none given: the model's, a URDF's zeros)"
    height = float(q[2] - legged.foot_positions(q)[:, 2].mean())
    if not height > 0.0:  # feet above the base: a leg folded up, or a posture of another robot
        raise ConfigError([("walking.posture", (
            f"in the reference posture{given} the base's origin is {-height:.3g} m below its "
            "feet, not above them: give a posture that stands on them"))])
    straight = straight_legs(legged, q)
    if straight:
        raise ConfigError([("walking.posture", (
            f"in the reference posture{given} the legs of {', '.join(straight)} cannot move "
            "their feet in every direction (straight: singular): give a posture with the "
            "knees bent, motor joint by motor joint"))])


#: A joint's loop diverges when its spectral radius is above this [-] (gains of zero give 1:
#: the joint left to itself, refused by no check here; the run shows what it does)
DIVERGES = 1.0 + 1e-9


def check_joint_gains(cfg: LeggedExperimentConfig, legged) -> None:
    """Refuse joint gains whose loop around a joint alone diverges at the control rate
    (:func:`~feltool.walking.legged.control.joint_loop_radius`, in the reference posture): a
    :class:`ConfigError` naming ``walking.gains.joints``, the joint and what would do."""
    from feltool.walking.legged.control import joint_loop_radius

    joints = gait_and_controller(cfg, legged)[1]["gains"].joints
    rate, q = cfg.sim.rate_hz, legged.standing()
    radius = joint_loop_radius(legged, q, joints, rate)
    if radius.max() <= DIVERGES:  # 1 exactly: no stiffness or no damping, not a divergence
        return
    i = int(radius.argmax())
    bad = [legged.motors[j] for j in np.flatnonzero(radius > DIVERGES)]
    ok_rate = rate  # the rate at which these gains keep the worst joint's loop inside
    while joint_loop_radius(legged, q, joints, ok_rate)[i] > DIVERGES and ok_rate < 1e7:
        ok_rate *= 1.25
    others = f" ({len(bad) - 1} other joints too)" if len(bad) > 1 else ""
    raise ConfigError([("walking.gains.joints", (
        f"[{joints[0]:.4g}, {joints[1]:.4g}] make {legged.motors[i]}'s own loop diverge"
        f"{others}: fed back every 1/sim.rate_hz = {1e3 / rate:.3g} ms on the joint's inertia "
        f"(the other joints free), its error grows {radius[i]:.3g} times per control step; "
        f"lower the joints' gains or raise sim.rate_hz (these gains need {ok_rate:.3g} Hz "
        f"for it, at most {MAX_RATE_HZ:g})"))])


def gait_and_controller(cfg: LeggedExperimentConfig, legged):
    """The config's gait (the trot, or a biped's walk) and the controller's other arguments:
    the gains ``walking.gains`` gives, the others the robot's defaults (a trot's Solo-12's
    scaled to the robot, :mod:`~feltool.walking.legged.similar`, with the timing the config
    leaves out; a walk's :func:`~feltool.walking.legged.walk.biped_gains`)."""
    from feltool.walking.legged.similar import trot_gains, trot_timing
    from feltool.walking.legged.trot import TrotGait
    from feltool.walking.legged.walk import biped_gains, biped_walk

    walk = cfg.walking.walk
    if walk is None:
        gait = cfg.walking.gait
        given = gait.model_dump(include=gait.model_fields_set)
        gait = TrotGait(**{**trot_timing(legged, gait.model_dump()), **given})
        extra = trot_gains(legged)
    else:
        timing = walk.model_dump(exclude={"left", "right"})
        gait = biped_walk(legged, legged.standing(), tuple(walk.left), tuple(walk.right),
                          **timing)
        extra = biped_gains(legged)
    return gait, _with_gains(extra, cfg.walking.gains)


#: ``walking.gains``' fields that are :class:`~feltool.walking.legged.control.StandGains`'
BASE_GAINS = ("height", "tilt", "yaw_rate", "joints")


def _with_gains(extra: dict, gains) -> dict:
    """The controller's arguments ``extra`` with the gains the config gives."""
    given = gains.model_dump(exclude_none=True)
    out = dict(extra)
    out["gains"] = dataclasses.replace(extra["gains"], **{k: v for k, v in given.items()
                                                          if k in BASE_GAINS})
    for key, name in (("horizontal", "horizontal"), ("swing", "swing_gains"),
                      ("normal_force_min", "normal_force_min")):
        if key in given:
            out[name] = given[key]
    return out


def as_run(cfg: LeggedExperimentConfig, legged) -> LeggedExperimentConfig:
    """``cfg`` with the gains and the trot's timing the robot runs with
    (:func:`gait_and_controller`: the robot's defaults where the config leaves them out) and its
    reference posture (every motor joint's; a crouched URDF's too), as ``config.yaml`` records
    it."""
    gait, extra = gait_and_controller(cfg, legged)
    g = extra["gains"]
    gains = LeggedGainsConfig(**{k: getattr(g, k) for k in BASE_GAINS},
                              horizontal=extra["horizontal"], swing=extra["swing_gains"],
                              normal_force_min=extra["normal_force_min"])
    m = legged.model
    posture = {m.names[j]: float(legged.q0[m.joints[j].idx_q]) for j in range(2, m.njoints)
               if m.joints[j].nq == 1}
    walking = {"gains": gains, "posture": posture}
    if cfg.walking.walk is None:
        walking["gait"] = TrotGaitConfig(**{k: float(getattr(gait, k))
                                            for k in TrotGaitConfig.model_fields})
    return cfg.model_copy(update={"walking": cfg.walking.model_copy(update=walking)})
