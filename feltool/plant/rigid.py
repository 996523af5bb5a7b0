r"""The plant: the simulated robot, when it differs from the known model.

The known model (``Experiment.dynamics``) turns desired trajectories into feedforward torque; the
plant (``ClosedLoop.dynamics``) is what the torques act on. By default they are the same object.
A config's ``plant:`` block makes them differ (docs/model_learning.md):

* ``robot:`` a second URDF with the same joints, and/or
* ``bodies:`` overrides of a body's mass, centre of mass and rotational inertia, and of its
  length (``length_scale``: the placements of the joints and frames it carries, its centre of
  mass and, squared, its rotational inertia; :func:`scale_length`),
* ``payloads:`` rigid payloads fixed to frames (added to the carrying body's inertia),
* ``friction:`` joint friction :math:`\tau_f = d\,\dot q + c \tanh(\dot q / v_c)` that opposes
  the motion, and ``motor_gain:`` a factor :math:`k` of each commanded torque, so the plant's
  forward model is :math:`\ddot q = \mathrm{ABA}(q, \dot q, k\tau - \tau_f)` and its inverse
  model :math:`(\mathrm{RNEA}(q, \dot q, \ddot q) + \tau_f) / k`.

Overrides are applied to a copy of the full robot before the experiment's locked joints are
removed, so a body is named by the joint that moves it in the URDF.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.config.plant import BodyOverride, Payload, PlantConfig
from feltool.dynamics.interface import Dynamics
from feltool.errors import RobotError
from feltool.robot.robot import Robot, load_robot


def plant_problems(plant: PlantConfig, robot: Robot,
                   base_dir: Path | None = None) -> list[tuple[str, str]]:
    """Every name in a ``plant:`` block checked against the robots, as ``(yaml_path, message)``."""
    problems: list[tuple[str, str]] = []
    target = robot
    if plant.robot is not None:
        try:
            target = load_robot(plant.robot, base_dir=base_dir)
        except RobotError as exc:
            return [("plant.robot", str(exc))]
        missing = [n for n in robot.joint_names if n not in target.joint_names]
        if missing:
            problems.append(("plant.robot", f"the plant robot '{target.name}' lacks the model's "
                                            f"joints {', '.join(missing)}"))
    listing = ", ".join(target.joint_names)
    for section, names in (("bodies", plant.bodies), ("friction", plant.friction),
                           ("motor_gain", plant.motor_gain)):
        for name in names:
            if name not in target.joint_names:
                problems.append((f"plant.{section}.{name}", f"robot '{target.name}' has no joint "
                                                            f"'{name}' (its joints: {listing})"))
    for i, payload in enumerate(plant.payloads):
        if not target.model.existFrame(payload.frame):
            frames = ", ".join(f.name for f in target.model.frames[1:])
            problems.append((f"plant.payloads.{i}.frame", f"robot '{target.name}' has no frame "
                                                          f"'{payload.frame}' (its frames: {frames})"))
    return problems


def plant_robot(plant: PlantConfig, model_robot: Robot, base_dir: Path | None = None) -> Robot:
    """The full (unreduced) plant robot: a copy of the model's robot, or ``plant.robot``, with
    the body overrides and payloads applied. The model's robot is left untouched."""
    source = load_robot(plant.robot, base_dir=base_dir) if plant.robot else model_robot
    model = source.model.copy()
    for joint, override in plant.bodies.items():
        jid = model.getJointId(joint)
        if override.length_scale is not None:
            scale_length(model, jid, override.length_scale)
        model.inertias[jid] = _override(model.inertias[jid], override)
    for payload in plant.payloads:
        frame = model.frames[model.getFrameId(payload.frame)]
        jid = frame.parentJoint
        model.inertias[jid] = model.inertias[jid] + frame.placement.act(_payload_inertia(payload))
    return replace(source, name=f"{source.name} (plant)", model=model, _visual_model=None)


def _scaled(inertia: pin.Inertia, s: float) -> pin.Inertia:
    """``inertia``'s body ``s`` times as long: centre of mass x s, rotational inertia x s^2."""
    return pin.Inertia(float(inertia.mass), inertia.lever * s, inertia.inertia * s * s)


def scale_length(model: pin.Model, jid: int, s: float) -> None:
    """Make the body moved by joint ``jid`` of ``model`` (in place) ``s`` times as long about
    its joint's origin: the translations of its child joints' placements and of its frames'
    placements (the frames it carries: welded links, a foot at its end) times ``s``, its
    centre of mass times ``s`` and its rotational inertia about the centre of mass times
    ``s^2`` (its mass unchanged; the welded links' own inertias alike)."""
    for k in range(1, model.njoints):
        if model.parents[k] == jid:
            p = model.jointPlacements[k]
            model.jointPlacements[k] = pin.SE3(p.rotation, p.translation * s)
    for i in range(len(model.frames)):
        f = model.frames[i]
        if f.parentJoint != jid or f.name == model.names[jid]:
            continue
        f.placement = pin.SE3(f.placement.rotation, f.placement.translation * s)
        f.inertia = _scaled(f.inertia, s)
        model.frames[i] = f
    model.inertias[jid] = _scaled(model.inertias[jid], s)


def _inertia_matrix(values: list[float]) -> np.ndarray:
    ixx, ixy, ixz, iyy, iyz, izz = values
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])


def _override(inertia: pin.Inertia, o: BodyOverride) -> pin.Inertia:
    mass, com, rot = float(inertia.mass), inertia.lever.copy(), inertia.inertia.copy()
    if o.mass_scale is not None:
        mass, rot = mass * o.mass_scale, rot * o.mass_scale
    if o.mass is not None:
        mass = o.mass
    if o.com is not None:
        com = np.array(o.com, dtype=float)
    if o.inertia is not None:
        rot = _inertia_matrix(o.inertia)
    return pin.Inertia(mass, com, rot)


def _payload_inertia(p: Payload) -> pin.Inertia:
    return pin.Inertia(p.mass, np.array(p.com, dtype=float), _inertia_matrix(p.inertia))


class FrictionPlant:
    """A rigid-body plant with joint friction and motor gain errors (see the module docstring
    for the law): a joint's commanded torque ``tau`` acts as ``gain * tau``.

    Args:
        rigid: The plant's rigid-body dynamics (Pinocchio backend).
        viscous: ``(nv,)`` viscous coefficients in [N m s/rad].
        coulomb: ``(nv,)`` Coulomb levels in [N m].
        coulomb_velocity: ``(nv,)`` smoothing velocities in [rad/s].
        motor_gain: ``(nv,)`` factors of the commanded torques [-]; default 1.
    """

    def __init__(self, rigid: Dynamics, viscous: np.ndarray, coulomb: np.ndarray,
                 coulomb_velocity: np.ndarray, motor_gain: np.ndarray | None = None):
        self.rigid = rigid
        self.nq, self.nv = rigid.nq, rigid.nv
        self.euclidean = getattr(rigid, "euclidean", False)
        self.viscous, self.coulomb, self.coulomb_velocity = viscous, coulomb, coulomb_velocity
        self.motor_gain = np.ones(rigid.nv) if motor_gain is None else motor_gain

    def with_rigid(self, rigid: Dynamics) -> FrictionPlant:
        """The same friction and motor gains on another rigid-body plant (a world event's)."""
        return FrictionPlant(rigid, self.viscous, self.coulomb, self.coulomb_velocity,
                             self.motor_gain)

    def friction(self, v: np.ndarray) -> np.ndarray:
        """Friction torque in [N m] at joint velocities ``v`` (rows or one vector)."""
        return self.viscous * v + self.coulomb * np.tanh(v / self.coulomb_velocity)

    def forward(self, q, v, tau):
        return self.rigid.forward(q, v, self.motor_gain * tau - self.friction(v))

    def inverse(self, q, v, a):
        return (self.rigid.inverse(q, v, a) + self.friction(v)) / self.motor_gain

    def inverse_batch(self, Q, V, A):
        return (self.rigid.inverse_batch(Q, V, A) + self.friction(V)) / self.motor_gain

    def integrate(self, q, dq):
        return self.rigid.integrate(q, dq)

    def difference(self, q0, q1):
        return self.rigid.difference(q0, q1)


def make_plant(plant: PlantConfig, robot: Robot, joints: list[str], rigid: Dynamics) -> Dynamics:
    """The plant's dynamics: ``rigid`` (the reduced plant robot's backend), with friction if any.

    Raises:
        RobotError: when the reduced plant's joints differ from the model's ``joints``.
    """
    order = [""] * robot.model.nv
    for name in robot.joint_names:
        order[robot.v_index(name)] = name
    if order != joints:
        raise RobotError(f"the plant's moving joints {order} differ from the model's {joints}")
    if not plant.friction and not plant.motor_gain:
        return rigid
    nv = len(joints)
    d, c, vc, gain = np.zeros(nv), np.zeros(nv), np.ones(nv), np.ones(nv)
    for name, f in plant.friction.items():
        if name in joints:
            i = joints.index(name)
            d[i], c[i], vc[i] = f.viscous, f.coulomb, f.coulomb_velocity
    for name, k in plant.motor_gain.items():
        if name in joints:
            gain[joints.index(name)] = k
    return FrictionPlant(rigid, d, c, vc, gain)


__all__ = ["FrictionPlant", "make_plant", "plant_problems", "plant_robot", "scale_length"]
