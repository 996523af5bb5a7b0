r"""A robot's URDF compiled by MuJoCo (``mujoco.MjSpec``): the plant of ``plant: {simulator: mujoco}``.

The same URDF the known model (Pinocchio) reads is parsed by MuJoCo's own URDF importer and
compiled with these settings, so that without contacts MuJoCo's dynamics are the URDF's:

* the URDF's inertias exactly (``inertiafromgeom`` off, ``balanceinertia`` off, no
  ``boundmass``; ``boundinertia`` :data:`MIN_INERTIA`, which MuJoCo needs for a point mass's
  zero rotational inertia and which changes no inertia a real body has), fixed links kept as
  bodies (``fusestatic`` off), visuals discarded;
* joint limits off (feltool counts and reports the limits itself, ``sim.joint_limits``);
  damping and dry friction (``frictionloss``) from the URDF's ``<dynamics>`` (>= 0, checked
  when the URDF is loaded); armature 0
  (a URDF has none);
* ``integrator: Euler`` with ``eulerdamp`` disabled: a step is semi-implicit Euler,
  :math:`\dot q \mathrel{+}= h\ddot q;\ q \mathrel{+}= h\dot q`, as feltool's own plant;
* the timestep ``h = 1 / (sim.rate_hz * sim.substeps)``; the torques enter as
  ``qfrc_applied``, held over the control step.

A planar walker gets programmatically what its URDF lacks: the base joints feltool adds
(``base_x``, ``base_z`` slide joints along the world's x and z, ``base_pitch`` a hinge about y,
in that order on the root body, as :func:`feltool.walking.model.with_planar_base`), the floor,
and one small sphere per foot (:data:`FOOT_RADIUS`) centred on the foot point; the floor plane
lies :data:`FOOT_RADIUS` below z = 0, so a foot point at z = 0 touches it. Only feet and floor
collide (every other geom's ``contype``/``conaffinity`` is 0). MuJoCo's soft contacts: an
elliptic friction cone with the friction coefficient ``walking.friction``, ``solref``
(:data:`TIMECONST`, at least two timesteps, and damping ratio :data:`DAMPRATIO`: critically
damped, the soft impact of a straight leg rebounds), ``solimp``
:data:`SOLIMP`. Joints are matched by name (MuJoCo orders them its own way).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from feltool.errors import RobotError
from feltool.robot.robot import Robot

MIN_INERTIA = 1e-9        #: smallest principal moment of inertia [kg m^2] (MuJoCo's boundinertia)
FOOT_RADIUS = 0.0005      #: foot sphere radius [m]
TIMECONST = 0.002         #: contact solref time constant [s] (raised to two timesteps)
DAMPRATIO = 2.0           #: contact solref damping ratio [-] (overdamped: no rebound)
SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)  #: contact solimp (d0, dwidth, width [m], midpoint, power)


def import_mujoco() -> Any:
    """The ``mujoco`` module.

    Raises:
        RobotError: when it cannot be imported (one line: how to install it).
    """
    try:
        import mujoco
    except Exception as exc:  # an ImportError, or a broken install
        raise RobotError(f"mujoco needs the 'mujoco' package (pip install 'feltool[mujoco]'): "
                         f"{exc}") from None
    return mujoco


@dataclass
class MujocoPlant:
    """A compiled MuJoCo model with the map between Pinocchio's and MuJoCo's coordinates.

    Attributes:
        model, data: MuJoCo's ``MjModel`` and ``MjData``.
        q_map: ``(idx_q, nq, qposadr)`` per Pinocchio joint (nq 2: a continuous joint, cos/sin).
        v_pin, v_mj: ``(nv,)`` velocity indices: Pinocchio's ``v_pin[i]`` is MuJoCo's ``v_mj[i]``.
        feet: foot name -> MuJoCo geom id of its sphere.
        floor: the floor's geom id (-1: none).
    """

    model: Any
    data: Any
    q_map: list[tuple[int, int, int]]
    v_pin: np.ndarray
    v_mj: np.ndarray
    feet: dict[str, int] = field(default_factory=dict)
    floor: int = -1

    def __post_init__(self):
        import mujoco

        self._mj = mujoco
        self._f6 = np.zeros(6)
        self.nq = sum(n for _, n, _ in self.q_map)

    def set_state(self, q: np.ndarray, v: np.ndarray) -> None:
        """Set MuJoCo's ``qpos, qvel`` from Pinocchio's ``q, v``."""
        d = self.data
        for iq, n, adr in self.q_map:
            d.qpos[adr] = q[iq] if n == 1 else math.atan2(q[iq + 1], q[iq])
        d.qvel[self.v_mj] = v[self.v_pin]
        self._mj.mj_forward(self.model, d)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Pinocchio's ``(q, v)`` of MuJoCo's current state."""
        d = self.data
        q, v = np.empty(self.nq), np.empty(len(self.v_pin))
        for iq, n, adr in self.q_map:
            if n == 1:
                q[iq] = d.qpos[adr]
            else:
                q[iq], q[iq + 1] = math.cos(d.qpos[adr]), math.sin(d.qpos[adr])
        v[self.v_pin] = d.qvel[self.v_mj]
        return q, v

    def acceleration(self) -> np.ndarray:
        """The last step's generalized accelerations in Pinocchio's order [m/s^2, rad/s^2]."""
        a = np.empty(len(self.v_pin))
        a[self.v_pin] = self.data.qacc[self.v_mj]
        return a

    def step(self, tau: np.ndarray, n: int = 1) -> None:
        """``n`` MuJoCo steps under the generalized forces ``tau`` (Pinocchio's order) [N m].

        Afterwards the positions (:meth:`foot_point`) are the new state's: ``mj_step``
        computes kinematics and contacts at the state it starts from and then integrates, so
        it leaves ``geom_xpos`` one step behind ``qpos``; they are recomputed here
        (``mj_kinematics``). The contacts (:meth:`foot_contacts`) stay the last step's: the
        forces that acted over it, at the state it started from."""
        d = self.data
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[self.v_mj] = tau[self.v_pin]
        for _ in range(n):
            self._mj.mj_step(self.model, d)
        self._mj.mj_kinematics(self.model, d)

    def foot_contacts(self) -> dict[str, tuple[np.ndarray, float]]:
        """Per foot: the ground's force on it in the world ``(F_x, F_y, F_z)`` [N] (MuJoCo's
        ``mj_contactForce``, summed over the foot's contacts) and its penetration depth [m]
        (0: no contact), over the last step (at the state it started from; :meth:`step`)."""
        m, d, f6 = self.model, self.data, self._f6
        out = {name: (np.zeros(3), 0.0) for name in self.feet}
        by_geom = {g: name for name, g in self.feet.items()}
        for i in range(d.ncon):
            c = d.contact[i]
            name = by_geom.get(c.geom1, by_geom.get(c.geom2))
            if name is None:
                continue
            self._mj.mj_contactForce(m, d, i, f6)
            frame = c.frame.reshape(3, 3)
            world = frame.T @ f6[:3]  # the force geom1 exerts on geom2, in the world
            if c.geom1 == self.feet[name]:
                world = -world
            force, depth = out[name]
            out[name] = (force + world, max(depth, -float(c.dist)))
        return out

    def foot_point(self, foot: str) -> np.ndarray:
        """The foot point's world position ``(x, y, z)`` [m] (its sphere's centre) at the
        current state."""
        return self.data.geom_xpos[self.feet[foot]].copy()

    def set_collides(self, foot: str, on: bool) -> None:
        """Let a foot's sphere touch the floor (or pass through it)."""
        self.model.geom_conaffinity[self.feet[foot]] = 1 if on else 0


def urdf_settings(mujoco: Any, spec: Any, timestep: float, integrator: str,
                  gravity: np.ndarray, discard_visual: bool = True) -> None:
    """Set ``spec``'s compiler and options so that MuJoCo's dynamics are the URDF's (module
    doc): exact inertias, fixed links kept, visual-only geoms discarded (unless
    ``discard_visual`` is False: a geom added without collisions stays), semi-implicit Euler
    without ``eulerdamp`` (or ``rk4``), an elliptic cone, ``timestep`` [s] and ``gravity``
    [m/s^2]."""
    c = spec.compiler
    c.fusestatic, c.discardvisual, c.balanceinertia = False, discard_visual, False
    c.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    c.boundmass, c.boundinertia = 0.0, MIN_INERTIA
    o = spec.option
    o.timestep = timestep
    o.integrator = (mujoco.mjtIntegrator.mjINT_RK4 if integrator == "rk4"
                    else mujoco.mjtIntegrator.mjINT_EULER)
    o.disableflags |= mujoco.mjtDisableBit.mjDSBL_EULERDAMP
    o.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    o.gravity = np.array(gravity, float)


def compile_mujoco(robot: Robot, timestep: float, base: list[str] | None = None,
                   feet: dict[str, int] | None = None, friction: float = 1.0,
                   gravity: np.ndarray | None = None, integrator: str = "euler",
                   timeconst: float | None = None) -> MujocoPlant:
    """The URDF of ``robot`` compiled by MuJoCo (module doc), stepping by ``timestep`` [s].

    Args:
        robot: The known model's robot (its ``model``: the joints to map, its gravity; its
            URDF: what MuJoCo compiles). A walker's robot carries its base joints.
        timestep: MuJoCo's step in [s].
        base: names of base joints to add to the root body (``base_x, base_z, base_pitch``),
            or None (a fixed base, or a URDF with its own base joints).
        feet: foot name -> Pinocchio frame id of its contact point (adds floor and spheres).
        friction: the feet's friction coefficient against the floor [-].
        gravity: the world's gravity ``(3,)`` in [m/s^2] (default the robot model's).
        integrator: ``euler`` (semi-implicit, ``eulerdamp`` off) or ``rk4`` (MuJoCo's
            Runge-Kutta: the contacts are evaluated at its four stages).
        timeconst: the contacts' ``solref`` time constant [s] (default :data:`TIMECONST`,
            raised to two timesteps).

    Raises:
        RobotError: when MuJoCo cannot compile the URDF or its joints do not match.
    """
    mujoco = import_mujoco()
    if robot.urdf_path is None:
        raise RobotError(f"robot '{robot.name}': MuJoCo needs the robot's URDF file")
    try:
        spec = mujoco.MjSpec.from_file(str(robot.urdf_path))
    except Exception as exc:
        raise RobotError(f"MuJoCo cannot read '{robot.urdf_path}': {exc}") from None
    urdf_settings(mujoco, spec, timestep, integrator,
                  robot.model.gravity.linear if gravity is None else gravity)
    for j in spec.joints:
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        j.armature = 0.0
    for g in spec.geoms:
        g.contype = g.conaffinity = 0
    if base:
        root = spec.worldbody.first_body()
        kinds = ((mujoco.mjtJoint.mjJNT_SLIDE, [1, 0, 0]), (mujoco.mjtJoint.mjJNT_SLIDE,
                 [0, 0, 1]), (mujoco.mjtJoint.mjJNT_HINGE, [0, 1, 0]))
        for name, (kind, axis) in zip(base, kinds):
            root.add_joint(name=name, type=kind, axis=axis)
    geoms = {}
    if feet:
        solref = [max(TIMECONST, 2.0 * timestep) if timeconst is None else timeconst,
                  DAMPRATIO]
        common = dict(friction=[friction, 0.005, 0.0001], solref=solref, solimp=list(SOLIMP),
                      condim=3)
        spec.worldbody.add_geom(name="feltool_floor", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                size=[0, 0, 1], pos=[0, 0, -FOOT_RADIUS], contype=1,
                                conaffinity=0, **common)
        bodies = {j.name: j.parent for j in spec.joints}
        root = spec.worldbody.first_body()
        for foot, fid in feet.items():
            frame = robot.model.frames[fid]
            jname = robot.model.names[frame.parentJoint]
            body = bodies.get(jname, root) if frame.parentJoint else root
            geoms[foot] = body.add_geom(name=f"feltool_foot_{foot}",
                                        type=mujoco.mjtGeom.mjGEOM_SPHERE,
                                        size=[FOOT_RADIUS, 0, 0],
                                        pos=np.array(frame.placement.translation),
                                        contype=0, conaffinity=1, **common)
    try:
        model = spec.compile()
    except Exception as exc:
        raise RobotError(f"MuJoCo cannot compile '{robot.urdf_path}': {exc}") from None
    return MujocoPlant(model, mujoco.MjData(model), *_joint_map(robot, model, mujoco),
                       {f: model.geom(f"feltool_foot_{f}").id for f in geoms},
                       model.geom("feltool_floor").id if feet else -1)


def _joint_map(robot: Robot, model: Any, mujoco: Any):
    pm = robot.model
    q_map, v_pin, v_mj = [], [], []
    names = {model.joint(i).name: i for i in range(model.njnt)}
    for j in range(1, pm.njoints):
        name, joint = pm.names[j], pm.joints[j]
        if name not in names:
            raise RobotError(f"robot '{robot.name}': MuJoCo's model of the URDF has no joint "
                             f"'{name}' (a locked or added joint)")
        i = names.pop(name)
        if joint.nv != 1 or int(model.jnt_type[i]) not in (int(mujoco.mjtJoint.mjJNT_HINGE),
                                                           int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise RobotError(f"robot '{robot.name}': joint '{name}': the MuJoCo plant maps "
                             "one-degree-of-freedom joints only")
        q_map.append((joint.idx_q, joint.nq, int(model.jnt_qposadr[i])))
        v_pin.append(joint.idx_v)
        v_mj.append(int(model.jnt_dofadr[i]))
    if names:
        raise RobotError(f"robot '{robot.name}': the experiment's model lacks the URDF's "
                         f"joints {', '.join(sorted(names))} (locked joints are not supported "
                         "with plant.simulator: mujoco)")
    return q_map, np.array(v_pin, int), np.array(v_mj, int)
