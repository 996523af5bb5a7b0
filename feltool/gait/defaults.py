r"""A minimal walker config completed: what ``feltool gait`` fills in, and its check before the
solve.

A walker config may name only its robot, its feet, its legs and the torso's target; the rest
has defaults, each said in the written config's header:

* ``name``: the config file's name (its stem, characters outside ``[A-Za-z0-9_.-]`` as ``_``);
* ``sim.rate_hz``: :data:`RATE_HZ`, the shipped walkers' control rate;
* ``walking.phase``: ``mechanical`` (a designed gait tracked on the clock drifts off it: the
  step's duration in the loop is the physics', not the design's; docs/biped.md);
* the gains of a tracked or stabilized joint that gives none, and of every motor the config
  does not name (:func:`critically_damped`): a critically damped loop at
  :data:`GAIN_HZ` on the joint's own inertia in the standing pose (the diagonal entry of
  the mass matrix, :math:`k_p = I\omega^2`, :math:`k_d = 2I\omega`, :math:`\omega = 2\pi f`),
  with :math:`f` at most the control rate over :data:`RATE_PER_HZ` (an explicit PD loop is
  stable only for :math:`\omega\,\Delta t` well below 1);
* ``learning``: the thesis's choice for an underactuated walker (``error: all_feedback``, the
  Gauss-Newton update in motor torques) with the rates of the shipped walkers.

:func:`provisional_config` is the config ``feltool gait`` would write, its demos the standing
pose held: validated in full (:func:`feltool.experiment.assemble.validate`) before the design
starts, so a config that could not run is refused in a second, not after the solve.
"""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from feltool.walking.model import WalkerModel
from feltool.walking.standing import standing_pose, to_configuration

#: The control rate of a walker config that gives none, in [Hz]: the shipped walkers'. (At the
#: schema's 100 Hz a designed gait's first steps are tracked coarsely enough to leave the
#: friction cone on some walkers.)
RATE_HZ = 500.0
#: Natural frequency of the default gains' loop in [Hz].
GAIN_HZ = 2.0
#: The default gains' frequency is at most the control rate over this [-].
RATE_PER_HZ = 100.0
#: The learning block of a config that has none.
LEARNING = {"error": "all_feedback", "update": "gauss_newton", "error_space": "motors",
            "error_estimate": "inverse_dynamics", "rates": {"gauss_newton": 0.3, "goal": 0.0}}


def critically_damped(inertia: float, rate_hz: float, hz: float = GAIN_HZ) -> dict[str, float]:
    """``{kp, kd}`` of a critically damped loop at ``hz`` [Hz] (at most ``rate_hz`` /
    :data:`RATE_PER_HZ`) on ``inertia`` [kg m^2]: in [N m/rad] and [N m s/rad]."""
    w = 2.0 * np.pi * min(hz, rate_hz / RATE_PER_HZ)
    return {"kp": _num(inertia * w * w), "kd": _num(2.0 * inertia * w)}


def complete_walker(raw: dict[str, Any], source: Path | None, walker: WalkerModel
                    ) -> tuple[dict[str, Any], list[str]]:
    """``raw`` with the defaults of the module docstring, and one line per default taken."""
    out, notes = copy.deepcopy(raw), []
    if not out.get("name") and source is not None:
        out = {"name": re.sub(r"[^A-Za-z0-9_.-]", "_", source.stem) or "walker", **out}
        notes.append(f"name: {out['name']} (the file's name)")
    sim = out.setdefault("sim", {})
    if isinstance(sim, dict) and "rate_hz" not in sim:
        sim["rate_hz"] = RATE_HZ
        notes.append(f"sim.rate_hz: {RATE_HZ:g} (the shipped walkers' control rate)")
    rate = float(sim.get("rate_hz", RATE_HZ)) if isinstance(sim, dict) else RATE_HZ
    walking = out.setdefault("walking", {})
    if isinstance(walking, dict) and "phase" not in walking:
        walking["phase"] = "mechanical"
        notes.append("walking.phase: mechanical (the designed gait's own step, not the clock's)")
    joints = out.get("joints")
    if isinstance(joints, dict):
        M = standing_inertia(walker)
        given = []
        for name, jc in joints.items():
            if isinstance(jc, dict) and jc.get("role") in ("track", "stabilize") \
                    and jc.get("gains") is None and name in walker.robot.joint_names:
                i = walker.robot.v_index(name)
                jc["gains"] = critically_damped(float(M[i, i]), rate)
                given.append(f"{name} {jc['gains']['kp']:.4g}/{jc['gains']['kd']:.4g}")
        if given:
            notes.append(f"gains kp/kd (critically damped at {GAIN_HZ:g} Hz on each joint's "
                         f"inertia standing): {', '.join(given)}")
    if not isinstance(out.get("learning"), dict):
        out["learning"] = copy.deepcopy(LEARNING)
        notes.append("learning: error all_feedback, Gauss-Newton in motor torques")
    return out, notes


def standing_inertia(walker: WalkerModel) -> np.ndarray:
    """The walker's mass matrix ``(nv, nv)`` in its standing pose."""
    model = walker.model
    q = to_configuration(model, standing_pose(walker).q)
    return pin.crba(model, model.createData(), q)


def placeholder_gait(walker: WalkerModel, spec, knots: int = 8):
    """A :class:`feltool.gait.design.Gait` that stands still in the standing pose for the
    step's duration (1 s when free): the shape of the design, for :func:`provisional_config`."""
    from feltool.gait.design import Gait

    model = walker.model
    stand = standing_pose(walker, spec.pitch_target).q
    q = np.tile(stand, (knots + 1, 1))
    zeros = np.zeros_like(q)
    T = spec.duration or 1.0
    return Gait(t=np.linspace(0.0, T, knots + 1), q=q,
                q_pin=np.array([to_configuration(model, x) for x in q]), v=zeros, a=zeros,
                tau=zeros, force=np.zeros((knots + 1, 2)), v_plus=np.zeros(model.nv),
                impulse=np.zeros(2), duration=T, step_length=0.0)


def robot_relative_to(raw: dict[str, Any], source: Path | None, out: Path) -> dict[str, Any]:
    """``raw`` with a ``robot:`` URDF path (relative to ``source``'s folder) rewritten relative
    to ``out``'s folder, so the written config runs wherever it is written."""
    spec = raw.get("robot")
    path = spec.get("source") if isinstance(spec, dict) else spec
    if not isinstance(path, str) or not (path.endswith(".urdf") or "/" in path):
        return raw
    full = Path(path).expanduser()
    if not full.is_absolute():
        full = (source.parent if source else Path.cwd()) / full
    rel = Path(_relpath(full.resolve(), out.resolve().parent))
    new = copy.deepcopy(raw)
    if isinstance(spec, dict):
        new["robot"]["source"] = rel.as_posix()
    else:
        new["robot"] = rel.as_posix()
    return new


def _relpath(target: Path, start: Path) -> str:
    import os

    try:
        return os.path.relpath(target, start)
    except ValueError:  # another drive (Windows): the absolute path
        return str(target)


def _num(x: float) -> float:
    return float(f"{float(x):.4g}")
