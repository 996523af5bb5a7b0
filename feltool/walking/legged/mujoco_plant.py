r"""A legged robot on a free flyer in MuJoCo: the plant of the legged loop in MuJoCo
(:func:`~feltool.walking.legged.mujoco_stand.stand_mujoco`).

MuJoCo's model is built from the known model's own numbers (``mujoco.MjSpec``), as the CasADi
expressions are (:mod:`feltool.dynamics.spatial`): one body per Pinocchio joint, placed by its
``jointPlacements`` in its parent's body, with the joint's inertia (``model.inertias``: mass,
centre of mass, rotational inertia, ``explicitinertial``) and the joint itself -- MuJoCo's free
joint for the free flyer, a hinge for a revolute joint (about x, y, z or its own axis), a slide
for a prismatic one, with the model's ``armature`` (the motors' reflected inertia, which
Pinocchio's algorithms add to the mass matrix: example-robot-data's Talos has 0.1 kg m^2). So it
is exactly the robot the controller knows, whatever it was loaded from: a URDF file,
example-robot-data's robot (Talos' legs are its URDF's legs and torso, the rest removed: compiling that
URDF would add 42 kg of arms and head), a reduced model. Other joint types are refused, naming
the joint. With the settings of :func:`feltool.robot.mujoco.urdf_settings` MuJoCo's dynamics
without contacts are Pinocchio's (``tests/test_legged_mujoco.py``, to 1e-9); what differs is
what a different simulator brings: its soft contacts and its integrator. What is added:

* the **floor**, a plane :data:`~feltool.robot.mujoco.FOOT_RADIUS` below z = 0, and one small
  sphere of that radius per point foot centred on the foot point, so a foot point at z = 0
  touches the floor; only feet and floor collide;
* MuJoCo's soft contacts: an **elliptic** friction cone with ``friction`` (:math:`\mu`),
  ``solref`` ``(timeconst, dampratio)`` (defaults :data:`TIMECONST`, :data:`DAMPRATIO`),
  ``solimp`` :data:`SOLIMP`, the friction made stiffer than the normal direction
  (``impratio`` :data:`IMPRATIO`: a standing robot's feet do not creep);
* optionally a **payload**, a point mass at an offset in the base's frame
  (:class:`~feltool.walking.legged.model.Payload`; :func:`~feltool.walking.legged.model.with_payload`
  puts the same one on a Pinocchio model).

The motor torques enter as ``qfrc_applied`` on the joints matched by name.

**Coordinates.** Pinocchio's free flyer: ``q = (x, y, z, quaternion x, y, z, w, joints)``,
``v = (base linear velocity in the base frame, angular velocity in the base frame, joint
rates)``. MuJoCo's free joint: ``qpos = (x, y, z, quaternion w, x, y, z)``, ``qvel = (linear
velocity of the body origin in the world frame, angular velocity in the body frame)``. So
:math:`v^{mj}_{lin} = R\,v_{lin}`, :math:`\omega^{mj} = \omega`, and the accelerations
:math:`a_{lin} = R^\top a^{mj}_{lin} - \omega \times v_{lin}` (the time derivative of the
base-frame velocity :math:`R^\top \dot p`).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.errors import ConfigError, RobotError
from feltool.robot.mujoco import FOOT_RADIUS, MIN_INERTIA, import_mujoco, urdf_settings
from feltool.walking.legged.model import LeggedModel, Payload

TIMECONST = 0.002   #: contact solref time constant [s] (raised to two timesteps)
DAMPRATIO = 1.0     #: contact solref damping ratio [-] (critically damped)
SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)  #: contact solimp (d0, dwidth, width [m], midpoint, power)
#: friction-to-normal impedance ratio of the elliptic cone [-] (MuJoCo's ``impratio``). With
#: MuJoCo's default 1 a soft friction constraint creeps: Solo-12 standing under the standing
#: controller (friction ratio 0.39) slides a foot 2 mm in 0.72 s; with 10, 0.2 mm in 1 s; with
#: 100, 0.02 mm in 1 s (``noslip_iterations`` 10 instead: 4e-5 mm)
IMPRATIO = 100.0


#: Pinocchio's one-degree-of-freedom joints and MuJoCo's joint of each, with its axis (None:
#: the joint's own ``axis``)
_JOINTS = {"JointModelRX": ("hinge", (1.0, 0.0, 0.0)), "JointModelRY": ("hinge", (0.0, 1.0, 0.0)),
           "JointModelRZ": ("hinge", (0.0, 0.0, 1.0)), "JointModelRevoluteUnaligned": ("hinge", None),
           "JointModelPX": ("slide", (1.0, 0.0, 0.0)), "JointModelPY": ("slide", (0.0, 1.0, 0.0)),
           "JointModelPZ": ("slide", (0.0, 0.0, 1.0)), "JointModelPrismaticUnaligned": ("slide", None)}


def _wxyz(R: np.ndarray) -> np.ndarray:
    """MuJoCo's quaternion ``(w, x, y, z)`` of a rotation matrix."""
    x, y, z, w = pin.Quaternion(np.asarray(R, float)).coeffs()
    return np.array([w, x, y, z])


def model_spec(mujoco, legged: LeggedModel):
    """``(spec, bodies)``: MuJoCo's spec of the legged robot's Pinocchio model (module doc)
    and its body per Pinocchio joint index (1: the root, on MuJoCo's free joint
    ``feltool_root``). Raises :class:`RobotError` naming a joint MuJoCo's spec cannot have."""
    m = legged.model
    if m.njoints < 2 or m.joints[1].shortname() != "JointModelFreeFlyer" or \
            not m.jointPlacements[1].isIdentity():
        raise RobotError(f"{legged.name}: MuJoCo's plant needs a free flyer as the first joint, "
                         "placed at the world's origin")
    spec = mujoco.MjSpec()
    bodies = {0: spec.worldbody}
    kinds = {"hinge": mujoco.mjtJoint.mjJNT_HINGE, "slide": mujoco.mjtJoint.mjJNT_SLIDE}
    for j in range(1, m.njoints):
        M, inertia, joint = m.jointPlacements[j], m.inertias[j], m.joints[j]
        body = bodies[m.parents[j]].add_body(name=f"feltool_body_{j}", pos=M.translation,
                                             quat=_wxyz(M.rotation))
        body.explicitinertial = True
        body.mass, body.ipos = float(inertia.mass), np.array(inertia.lever)
        I = np.array(inertia.inertia)
        body.fullinertia = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
        if j == 1:
            body.add_freejoint(name="feltool_root")
        elif joint.shortname() in _JOINTS:
            kind, axis = _JOINTS[joint.shortname()]
            body.add_joint(name=m.names[j], type=kinds[kind],
                           axis=np.array(joint.axis if axis is None else axis, float),
                           armature=float(m.armature[joint.idx_v]))
        else:
            raise RobotError(f"{legged.name}: joint '{m.names[j]}' ({joint.shortname()}) has "
                             "no MuJoCo counterpart in feltool's plant (revolute and prismatic "
                             "joints only)")
        bodies[j] = body
    return spec, bodies


class LeggedMujoco:
    """A :class:`LeggedModel` compiled by MuJoCo (module doc).

    Args:
        legged: The robot (its joints, inertias and foot frames; the known model).
        timestep: MuJoCo's step [s].
        friction: The feet's friction coefficient :math:`\\mu` against the floor [-].
        integrator: ``euler`` (semi-implicit, ``eulerdamp`` off) or ``rk4``.
        timeconst: ``solref``'s time constant [s] (default :data:`TIMECONST`, at least two
            timesteps); ``dampratio`` its damping ratio [-]; ``solimp`` MuJoCo's impedance.
        impratio: MuJoCo's friction-to-normal impedance ratio [-] (:data:`IMPRATIO`);
            ``noslip_iterations`` its no-slip post-solver's iterations (0: off).
        payload: A point mass on the base (:class:`Payload`), or None.
        gravity: The linear gravity [m/s^2] of the unknown world (a slope:
            :func:`~feltool.walking.legged.model.sloped`), or None: the known model's.
        mass_scale: Every body's mass and rotational inertia times this in the unknown world
            (:func:`~feltool.walking.legged.model.scaled_masses`), or None.
        floor: False: no floor (free flight).

    Attributes:
        model, data: MuJoCo's ``MjModel``, ``MjData``.
        feet: foot name -> geom id of its sphere (the order of ``legged.feet``).
        base: the base body's id.
    """

    def __init__(self, legged: LeggedModel, timestep: float = 5e-4, friction: float = 0.7,
                 integrator: str = "euler",
                 timeconst: float | None = None, dampratio: float = DAMPRATIO,
                 solimp: tuple = SOLIMP, impratio: float = IMPRATIO,
                 noslip_iterations: int = 0, payload: Payload | None = None,
                 gravity: np.ndarray | None = None, mass_scale: float | None = None,
                 floor: bool = True):
        mujoco = self._mj = import_mujoco()
        self.legged = legged
        if integrator not in ("euler", "rk4"):
            raise ConfigError([("integrator", f"'euler' or 'rk4', not {integrator!r}")])
        spec, bodies = model_spec(mujoco, legged)
        self.gravity = None if gravity is None else np.array(gravity, float)
        urdf_settings(mujoco, spec, timestep, integrator, legged.model.gravity.linear
                      if gravity is None else self.gravity, discard_visual=False)
        spec.option.impratio, spec.option.noslip_iterations = impratio, noslip_iterations
        root = bodies[1]
        if payload is not None:
            root.add_body(name="feltool_payload", pos=np.asarray(payload.offset, float),
                          ipos=[0.0, 0.0, 0.0], mass=float(payload.mass),
                          inertia=[MIN_INERTIA] * 3,
                          explicitinertial=True)
        self.timeconst = max(TIMECONST, 2.0 * timestep) if timeconst is None else timeconst
        common = dict(friction=[friction, 0.005, 0.0001], solref=[self.timeconst, dampratio],
                      solimp=list(solimp), condim=3)
        if floor:
            spec.worldbody.add_geom(name="feltool_floor", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                    size=[0, 0, 1], pos=[0, 0, -FOOT_RADIUS], contype=1,
                                    conaffinity=0, **common)
        pm = legged.model
        for foot, fid in legged.feet.items():
            frame = pm.frames[fid]  # the foot point in its joint's frame: its body's frame
            bodies[frame.parentJoint].add_geom(name=f"feltool_foot_{foot}", type=mujoco.mjtGeom.mjGEOM_SPHERE,
                          size=[FOOT_RADIUS, 0, 0], pos=np.array(frame.placement.translation),
                          contype=0, conaffinity=1 if floor else 0, **common)
        try:
            self.model = spec.compile()
        except Exception as exc:
            raise RobotError(f"{legged.name}: MuJoCo cannot compile its model: {exc}") from None
        self.data = mujoco.MjData(self.model)
        self._map(legged)
        self.feet = {f: self.model.geom(f"feltool_foot_{f}").id for f in legged.feet}
        self.floor = self.model.geom("feltool_floor").id if floor else -1
        self.base = int(self.model.body(root.name).id)
        self.payload = payload
        self.mass_scale = mass_scale
        robot = [b for b in range(1, self.model.nbody) if self.model.body(b).name !=
                 "feltool_payload"]
        self._masses = (robot, self.model.body_mass[robot].copy(),
                        self.model.body_inertia[robot].copy())
        self._f6 = np.zeros(6)
        if mass_scale is not None:
            self.carry(True)

    def carry(self, on: bool) -> None:
        """Put the unknown world this plant was compiled with on (``on``) or off: the payload
        on the base or taken off (its mass 0), the gravity of a slope or the known model's, the
        bodies' masses scaled or as compiled: a world that changes during a rollout."""
        if self.payload is None and self.gravity is None and self.mass_scale is None:
            raise ConfigError([("payload", "the plant was compiled without a payload, a slope "
                                           "or scaled masses")])
        if self.mass_scale is not None:
            robot, mass, inertia = self._masses
            scale = self.mass_scale if on else 1.0
            self.model.body_mass[robot] = mass * scale
            self.model.body_inertia[robot] = inertia * scale
        if self.gravity is not None:
            self.model.opt.gravity[:] = self.gravity if on else self.legged.model.gravity.linear
        if self.payload is not None:
            body = self.model.body("feltool_payload").id
            self.model.body_mass[body] = float(self.payload.mass) if on else 0.0
        mj, d = self._mj, self.data
        spec = mj.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mj.mj_stateSize(self.model, spec))
        mj.mj_getState(self.model, d, state, spec)
        mj.mj_setConst(self.model, d)  # the masses' derived constants (it uses d as scratch)
        mj.mj_setState(self.model, d, state, spec)
        mj.mj_forward(self.model, d)

    def _map(self, legged: LeggedModel) -> None:
        """The joints matched by name: ``self.q_mj``/``self.v_mj``, MuJoCo's qpos/qvel address
        of each motor joint, in Pinocchio's order."""
        m, pm, mj = self.model, legged.model, self._mj
        names = {m.joint(i).name: i for i in range(m.njnt)}
        free = names.pop("feltool_root")
        if m.jnt_qposadr[free] != 0 or m.jnt_dofadr[free] != 0:
            raise RobotError(f"{legged.name}: MuJoCo's free joint is not its first joint")
        q_mj, v_mj = [], []
        for j in range(2, pm.njoints):
            name = pm.names[j]
            i = names.pop(name, None)
            if i is None or pm.joints[j].nq != 1 or \
                    int(m.jnt_type[i]) not in (int(mj.mjtJoint.mjJNT_HINGE),
                                               int(mj.mjtJoint.mjJNT_SLIDE)):
                raise RobotError(f"{legged.name}: MuJoCo's model has no one-degree-of-freedom "
                                 f"joint '{name}'")
            q_mj.append(int(m.jnt_qposadr[i]))
            v_mj.append(int(m.jnt_dofadr[i]))
        self.q_mj, self.v_mj = np.array(q_mj, int), np.array(v_mj, int)

    # -- coordinates --------------------------------------------------------------------------
    def to_mujoco(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo's ``(qpos, qvel)`` of Pinocchio's ``(q, v)`` (module doc)."""
        qpos, qvel = np.zeros(self.model.nq), np.zeros(self.model.nv)
        quat = np.asarray(q[3:7], float) / np.linalg.norm(q[3:7])
        qpos[:3], qpos[3], qpos[4:7] = q[:3], quat[3], quat[:3]
        qpos[self.q_mj] = q[7:]
        R = pin.Quaternion(quat[3], *quat[:3]).toRotationMatrix()
        qvel[:3], qvel[3:6] = R @ v[:3], v[3:6]
        qvel[self.v_mj] = v[6:]
        return qpos, qvel

    def to_pinocchio(self, qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pinocchio's ``(q, v)`` of MuJoCo's ``(qpos, qvel)`` (module doc)."""
        q, v = np.empty(self.legged.nq), np.empty(self.legged.nv)
        quat = np.asarray(qpos[3:7], float) / np.linalg.norm(qpos[3:7])
        q[:3], q[3:6], q[6] = qpos[:3], quat[1:], quat[0]
        q[7:] = qpos[self.q_mj]
        R = pin.Quaternion(*quat).toRotationMatrix()
        v[:3], v[3:6] = R.T @ qvel[:3], qvel[3:6]
        v[6:] = qvel[self.v_mj]
        return q, v

    def set_state(self, q: np.ndarray, v: np.ndarray) -> None:
        """Put MuJoCo's robot at Pinocchio's ``(q, v)`` (``mj_forward``: positions, contacts and
        accelerations at it, no torque)."""
        d = self.data
        d.qpos[:], d.qvel[:] = self.to_mujoco(q, v)
        d.qfrc_applied[:] = 0.0
        d.xfrc_applied[:] = 0.0
        self._mj.mj_forward(self.model, d)

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Pinocchio's ``(q, v)`` of MuJoCo's current state."""
        return self.to_pinocchio(self.data.qpos, self.data.qvel)

    def acceleration(self) -> np.ndarray:
        """Pinocchio's generalized acceleration ``(nv,)`` of MuJoCo's ``qacc`` (the last
        ``mj_forward``'s or step's) [m/s^2, rad/s^2]."""
        q, v = self.state()
        qa = self.data.qacc
        R = pin.XYZQUATToSE3(q[:7]).rotation
        a = np.empty(self.legged.nv)
        a[:3] = R.T @ qa[:3] - np.cross(v[3:6], v[:3])
        a[3:6] = qa[3:6]
        a[6:] = qa[self.v_mj]
        return a

    # -- stepping ------------------------------------------------------------------------------
    def generalized(self, u: np.ndarray, force=None, torque=None) -> np.ndarray:
        """MuJoCo's ``qfrc`` ``(nv,)`` of motor torques ``u`` ``(k,)`` [N m] and a push on the
        base: ``force`` [N] at the base's origin and ``torque`` [N m], world axes."""
        out = np.zeros(self.model.nv)
        out[self.v_mj] = u
        if force is not None or torque is not None:
            f = np.zeros(3) if force is None else np.asarray(force, float)
            tq = np.zeros(3) if torque is None else np.asarray(torque, float)
            self._mj.mj_applyFT(self.model, self.data, f, tq, self.data.xpos[self.base].copy(),
                                self.base, out)
        return out

    def step(self, qfrc: np.ndarray) -> None:
        """One MuJoCo step under the generalized force ``qfrc`` (MuJoCo's order, e.g.
        :meth:`generalized`). Afterwards the kinematics (:meth:`foot_points`) are the new
        state's; the contacts (:meth:`foot_contacts`) are the ones that acted over the step, at
        the state it started from."""
        d = self.data
        d.qfrc_applied[:] = qfrc
        self._mj.mj_step(self.model, d)
        self._mj.mj_kinematics(self.model, d)

    def foot_points(self) -> np.ndarray:
        """``(n_feet, 3)`` the foot points in the world [m] (the spheres' centres)."""
        return self.data.geom_xpos[list(self.feet.values())].copy()

    def foot_contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """``(forces (n_feet, 3) [N], depths (n_feet,) [m])``: the floor's force on each foot
        in the world's axes (``mj_contactForce``, summed over its contacts) and its
        penetration (0 in the air), over the last step."""
        m, d, f6 = self.model, self.data, self._f6
        ids = list(self.feet.values())
        forces, depths = np.zeros((len(ids), 3)), np.zeros(len(ids))
        for i in range(d.ncon):
            c = d.contact[i]
            k = ids.index(c.geom2) if c.geom2 in ids else ids.index(c.geom1) \
                if c.geom1 in ids else -1
            if k < 0:
                continue
            self._mj.mj_contactForce(m, d, i, f6)
            world = c.frame.reshape(3, 3).T @ f6[:3]  # geom1's force on geom2, world axes
            forces[k] += world if c.geom2 == ids[k] else -world
            depths[k] = max(depths[k], -float(c.dist))
        return forces, depths
