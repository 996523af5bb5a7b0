"""``feltool gait``'s input and output: the walker of a config, the gait as RMP demonstrations.

The input is an experiment config of a physical walker (``walking.feet``, ``walking.legs``,
``walking.base``, ``walking.friction``, ... as in docs/biped.md). The output is the same config
with the designed gait: each tracked or passive joint's ``demo`` becomes its trajectory over one
step (stance-relative labels) or two (``steps_per_cycle: 2``, the first step's labels, continuous)
as ``kind: samples`` at the collocation knots (fitted into its RMP by eq. 2.4), ``period_s`` the
cycle's duration, and a slope becomes a tilted ``gravity``.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from feltool.errors import ConfigError, InputError, RobotError
from feltool.files import atomic_write, dump_yaml
from feltool.gait.design import Gait, GaitSpec
from feltool.robot.robot import load_robot, robot_spec
from feltool.walking.model import BASE_JOINTS, FootSpec, WalkerModel, build_walker_model
from feltool.walking.standing import standing_pose


def walker_from_raw(raw: dict[str, Any], source: Path | None = None
                    ) -> tuple[WalkerModel, dict[str, Any]]:
    """The walker and its ``walking`` settings from a raw config mapping.

    TO BE REPLACED by the physical walker's config schema (``feltool.walking.build``) once it is
    on main: this reads the few fields the gait designer needs (``robot``, ``gravity``,
    ``walking.base/feet/legs/stance/friction/normal_force_min/scuff_exempt_m/steps_per_cycle``)
    from the raw YAML mapping, naming the YAML path of a problem.

    Returns:
        The walker, and a dict with ``stance``, ``friction``, ``normal_force_min`` [N],
        ``scuff_exempt_m`` [m] or None, ``steps_per_cycle``, ``gravity`` [m/s^2] and ``slope``
        [rad] (the tilt of a gravity vector about y, positive downhill along +x).

    Raises:
        ConfigError: naming the YAML path of a missing or wrong field.
    """
    where = str(source) if source else None
    walking = raw.get("walking")
    if not isinstance(walking, dict) or not isinstance(walking.get("feet"), dict):
        raise ConfigError([("walking.feet", "feltool gait needs a physical walker: give "
                            "walking.feet (left and right contact points) and walking.legs")],
                          where)
    feet = {}
    for name in ("left", "right"):
        spec = walking["feet"].get(name)
        if not isinstance(spec, dict) or ("frame" in spec) == ("link" in spec):
            raise ConfigError([(f"walking.feet.{name}", "give a foot as {frame: NAME} or "
                                "{link: NAME, offset: [x, y, z]}")], where)
        feet[name] = FootSpec(frame=spec.get("frame"), link=spec.get("link"),
                              offset=tuple(float(x) for x in spec.get("offset", (0, 0, 0))))
    legs = walking.get("legs")
    if not isinstance(legs, list) or not legs or not all(
            isinstance(p, list) and len(p) == 2 for p in legs):
        raise ConfigError([("walking.legs", "give the left/right joint pairs, e.g. "
                            "[[left_hip, right_hip]]")], where)
    base_dir = source.parent if source else Path.cwd()
    try:
        source, lenient = robot_spec(raw.get("robot"))
        robot = load_robot(source, base_dir=base_dir, lenient=lenient)
    except RobotError as exc:
        raise ConfigError([("robot", str(exc))], where) from None
    gravity = raw.get("gravity", 9.8)
    if isinstance(gravity, list):
        g = np.asarray(gravity, dtype=float)
        magnitude, slope = float(np.linalg.norm(g)), float(np.arctan2(g[0], -g[2]))
    else:
        magnitude, slope = float(gravity), 0.0
    robot.set_gravity(magnitude)
    try:
        walker = build_walker_model(robot, feet, [tuple(p) for p in legs],
                                    walking.get("base", "planar"))
    except RobotError as exc:
        raise ConfigError([("walking", str(exc))], where) from None
    settings = {
        "stance": walking.get("stance", "left"),
        "friction": float(walking.get("friction", 0.7)),
        "normal_force_min": float(walking.get("normal_force_min", 0.0)),
        "scuff_exempt_m": walking.get("scuff_exempt_m"),
        "steps_per_cycle": int(walking.get("steps_per_cycle", 1)),
        "gravity": magnitude, "slope": slope,
    }
    return walker, settings


def gait_spec(raw: dict[str, Any], walker: WalkerModel, settings: dict[str, Any], *,
              speed: float | None = None, step_length: float | None = None,
              slope: float | None = None, passive: bool = False, knots: int = 40,
              friction_margin: float = 0.85, torso_weight: float | None = None,
              normal_force_margin: float = 0.05, clearance_margin_m: float = 0.002,
              torso: float | None = None, duration: float | None = None) -> GaitSpec:
    """The :class:`GaitSpec` of a config and the command line's choices.

    The step's duration is ``duration`` [s], else the config's ``period_s`` over
    ``steps_per_cycle`` (free for a passive gait); the friction cone is designed within
    ``friction_margin`` times the config's mu, the normal force ``normal_force_margin`` m g
    above ``walking.normal_force_min`` and the
    swing foot ``clearance_margin_m`` above the ground outside the scuffing zone (margins for
    tracking errors, none for a passive gait); the torso is ``base_pitch`` when the config
    stabilizes it, at its ``target.value``, or at ``torso`` [rad] when given (``torso_weight``:
    the weight of its motion, default GaitSpec's). Without speed or step length, the step length
    is 0.35 hip heights.
    """
    stance = settings["stance"]
    joints = raw.get("joints") or {}
    pitch = joints.get(BASE_JOINTS[2]) if walker.base == list(BASE_JOINTS) else None
    pitch_target = torso
    if pitch_target is None and isinstance(pitch, dict) and pitch.get("role") == "stabilize":
        pitch_target = (pitch.get("target") or {}).get("value")
    period = raw.get("period_s")
    if passive:
        duration = None
    elif duration is None and period is not None:
        duration = float(period) / settings["steps_per_cycle"]
    if duration is not None:
        n = duration * rate_hz(raw)
        if abs(n - round(n)) > 1e-6:
            dt = 1.0 / rate_hz(raw)
            raise InputError(f"--duration (or period_s / walking.steps_per_cycle): a step of "
                             f"{duration:g} s at sim.rate_hz {rate_hz(raw):g} is {n:g} control "
                             f"steps; give a whole number of them, e.g. {np.floor(n) * dt:g} or "
                             f"{np.ceil(n) * dt:g} s")
    if not passive and speed is None and step_length is None:
        step_length = 0.35 * _hip_height(walker, stance)
    extra = {} if torso_weight is None else {"pitch_weight": torso_weight}
    return GaitSpec(
        **extra, stance=stance, swing="right" if stance == "left" else "left", knots=knots,
        step_length=step_length, speed=speed, duration=duration,
        slope=settings["slope"] if slope is None else slope, passive=passive,
        friction=friction_margin * settings["friction"],
        normal_force_min=settings["normal_force_min"], scuff_exempt_m=settings["scuff_exempt_m"],
        clearance=not passive, clearance_margin_m=0.0 if passive else clearance_margin_m,
        normal_force_margin=0.0 if passive else normal_force_margin,
        pitch_joint=BASE_JOINTS[2] if pitch_target is not None else None,
        pitch_target=None if pitch_target is None else float(pitch_target))


def _hip_height(walker: WalkerModel, foot: str) -> float:
    """The hip height in [m] of the walker standing (:mod:`feltool.walking.standing`)."""
    return standing_pose(walker).height


def gait_config(raw: dict[str, Any], walker: WalkerModel, gait: Gait, spec: GaitSpec,
                settings: dict[str, Any]) -> dict[str, Any]:
    """``raw`` with the designed gait: samples demos of its tracked, passive and stabilized joints
    (not the base's x and z, which follow from the stance foot; a stabilized torso's demo is its
    designed motion, the RMP's start with ``learn.init: demo``), ``period_s`` and the slope's
    gravity. Each of those joints follows its demo (``follow_demo``: the forward trajectory is
    the design, not the RMP's smooth fit of its impact's velocity jump), except a learned joint
    that is not tracked (its RMP starts from the fit).

    With ``steps_per_cycle: 1`` each demo is the step in stance-relative labels (a leg joint's
    trajectory then ends elsewhere than it starts: the other leg carries its label after the
    touchdown). With ``steps_per_cycle: 2`` each demo is two steps in the first step's labels:
    the step, then its relabelled copy ``R q(t)`` (the physical walker exchanges the legs' desired
    values in every second step), continuous in position because the gait is periodic through
    the relabelling, ``q(T) = R q(0)`` up to the shift along x; at the touchdown knot the samples
    hold the post-impact velocity and acceleration.
    """
    spc = settings["steps_per_cycle"]
    if spc not in (1, 2):
        raise ConfigError([("walking.steps_per_cycle", "feltool gait writes demos of one step "
                            "(stance-relative labels) or two (the first step's labels): set "
                            "walking.steps_per_cycle to 1 or 2")])
    _, R = walker.relabel_matrices()
    q, v, a = gait.q, gait.v, gait.a
    if spc == 2:
        q = np.vstack([q, (R @ q[1:].T).T])
        v = np.vstack([v[:-1], [gait.v_plus], (R @ v[1:].T).T])
        a = np.vstack([a[:-1], [R @ a[0]], (R @ a[1:].T).T])
    out = copy.deepcopy(raw)
    # a whole number of control steps per step (a passive gait's free duration is rounded: the
    # knots' times stretch by less than half a control step)
    dt = 1.0 / rate_hz(raw)
    out["period_s"] = _num(spc * round(gait.duration / dt) * dt)
    if spec.slope != 0.0:
        g = settings["gravity"]
        out["gravity"] = [_num(g * np.sin(spec.slope)), 0.0, _num(-g * np.cos(spec.slope))]
    joints = out.setdefault("joints", {})
    _complete_joints(joints, walker, gait)
    learning = out.setdefault("learning", {})
    if not any(isinstance(jc, dict) and jc.get("role") == "stabilize" for jc in joints.values()) \
            and learning.get("error", "stabilizing") == "stabilizing":
        learning["error"] = "all_feedback"  # an underactuated walker: the thesis's choice
    for name, jc in joints.items():
        if name in BASE_JOINTS[:2] or not isinstance(jc, dict):
            continue
        if jc.get("role") not in ("track", "passive", "stabilize"):
            continue
        i = walker.robot.v_index(name)
        jc["demo"] = {"kind": "samples", "q": [_num(x) for x in q[:, i]],
                      "v": [_num(x) for x in v[:, i]], "a": [_num(x) for x in a[:, i]]}
        if jc.get("learn") is None or jc.get("role") == "track":
            jc["follow_demo"] = True  # the design itself, not a smooth RMP's fit of it
    return out


def rate_hz(raw: dict[str, Any]) -> float:
    """The config's control rate in [Hz] (the schema's default when it gives none)."""
    from feltool.config.sim import SimConfig

    sim = raw.get("sim") if isinstance(raw.get("sim"), dict) else {}
    return float(sim.get("rate_hz", SimConfig.model_fields["rate_hz"].default))


def _complete_joints(joints: dict[str, Any], walker: WalkerModel, gait: Gait,
                     hz: float = 2.0) -> None:
    r"""What the walker's loop needs besides the designed motion: every motor the config does
    not name tracks its design, with gains of a critically damped ``hz`` [Hz] loop on its own
    inertia at the step's start (:math:`k_p = I\omega^2`, :math:`k_d = 2I\omega`; edit them
    in the written config); an unnamed base pitch is passive with its designed motion; a
    stabilized torso (``base_pitch``) tracks its designed motion,
    whose mean is its target (a constant target would fight the design's own torso motion)."""
    model = walker.model
    M = pin.crba(model, model.createData(), gait.q_pin[0])
    w = 2.0 * np.pi * hz
    for name in walker.robot.joint_names:
        if name in walker.base or name in joints:
            continue
        inertia = float(M[walker.robot.v_index(name), walker.robot.v_index(name)])
        joints[name] = {"role": "track",
                        "gains": {"kp": _num(inertia * w**2), "kd": _num(2.0 * inertia * w)}}
    pitch = walker.base[2] if len(walker.base) > 2 else None
    if pitch is not None and pitch not in joints:  # unactuated: it follows its designed motion
        joints[pitch] = {"role": "passive"}  # (the base's x and z follow from the stance foot)
    torso = joints.get(BASE_JOINTS[2])
    if isinstance(torso, dict) and torso.get("role") == "stabilize":
        torso["role"] = "track"
        torso.pop("target", None)


def _num(x: float) -> float:
    return float(f"{float(x):.7g}")


def write_gait_config(path: Path, config: dict[str, Any], gait: Gait, command: str,
                      check=None, defaults: list[str] | None = None) -> None:
    """Write ``config`` as YAML with a header of the gait's figures and, with ``check`` (a
    :class:`feltool.gait.orbit.Verification`), of its walk in feltool's walker; the
    ``defaults`` taken (:func:`feltool.gait.defaults.complete_walker`), and what there is to
    learn."""
    m = gait.metrics
    two = config.get("walking", {}).get("steps_per_cycle", 1) == 2
    labels = ("two steps in the first step's labels" if two
              else "one step in stance-relative labels")
    header = (f"# Gait designed by: {command}\n"
              f"# step {m['period_s']:.4g} s, speed {m['speed_m_per_s']:.4g} m/s, step length "
              f"{m['step_length_m']:.4g} m, cost of transport {m['cost_of_transport']:.3g},\n"
              f"# min F_n {m['min_normal_force_mg']:.3g} mg, max |F_t|/F_n "
              f"{m['max_friction_ratio']:.3g}, impulse ratio {m['impulse_ratio']:.3g}; demos: "
              f"{labels} (kind: samples).\n")
    if check is not None and check.poincare.get("fixed_point_found"):
        header += (f"# In feltool's walker: walked {check.steps} steps of "
                   f"{check.step_length_m:.4g} m in {check.step_duration_s:.4g} s, min F_n "
                   f"{check.min_normal_force_mg:.3g} mg, max |F_t|/F_n "
                   f"{check.max_friction_ratio:.3g}, Poincaré spectral radius "
                   f"{check.poincare['spectral_radius']:.3g}; summed feedback on the demos' "
                   f"orbit {check.feedback:.2g} N m.\n")
    for line in defaults or []:
        header += f"# Default {line}.\n"
    header += _learning_note(config)
    text = dump_yaml(config, sort_keys=False, default_flow_style=None, width=100)
    atomic_write(path, header + text)


def _learning_note(config: dict[str, Any]) -> str:
    """The header's lines on what FEL has to learn in this config."""
    learned = [name for name, jc in (config.get("joints") or {}).items()
               if isinstance(jc, dict) and jc.get("learn") is not None]
    worlds = [k for k in ("events", "plant", "disturbances") if config.get(k)]
    if not learned:
        return ("# Learning: no joint learns (joints.J.learn): run as written, the walker walks "
                "its designed orbit,\n# on which the feedback is ~1e-8 N m: nothing to learn. "
                "FEL has work from a perturbed start\n# (joints.J.learn: {init: perturbed}) or "
                "in a world that differs from the design (events:, plant:).\n")
    if not worlds:
        return (f"# Learning: {', '.join(learned)} learn from their start (joints.J.learn); on "
                "the designed orbit itself\n# the feedback is ~1e-8 N m: a world that differs "
                "from the design (events:, plant:) gives FEL more.\n")
    return f"# Learning: {', '.join(learned)} learn in a world changed by {', '.join(worlds)}.\n"
