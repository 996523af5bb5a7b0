r"""The physical walker: a robot on a floating base with point feet, its contact, its motors
(the allocation of a wanted generalized force onto them), the desired state completed by the
stance foot's constraint, and its fall check (:mod:`feltool.walking.physical` runs its loop).

The wanted generalized force :math:`\tau_w` is mapped onto the motors :math:`B` (every
non-base joint) by the inertia-weighted allocation in the metric of the constrained system,

.. math::

    u = (B^\top W B)^{-1} B^\top W \tau_w,\qquad
    W = M^{-1} - M^{-1}J_c^\top (J_c M^{-1} J_c^\top)^{-1} J_c M^{-1},

the motor torques whose constrained accelerations are closest, in the kinetic-energy metric, to
those :math:`\tau_w` would produce with the foot held. Every quantity here is the known
model's; only :meth:`PhysicalWalker.contact_for` builds the contact of a simulated plant.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.dynamics.pinocchio import mass_matrix
from feltool.errors import RobotError
from feltool.walking.checks import ContactChecks
from feltool.walking.contact import Contact
from feltool.walking.model import WalkerModel
from feltool.walking.pinned import fall_reason


def same_kinematics(a: pin.Model, b: pin.Model) -> bool:
    """Whether two models of the same joints place their joints and frames alike (a plant
    whose bodies are only heavier, not longer)."""
    if a.njoints != b.njoints or len(a.frames) != len(b.frames):
        return False
    return (all(np.array_equal(a.jointPlacements[j].homogeneous, b.jointPlacements[j].homogeneous)
                for j in range(a.njoints))
            and all(np.array_equal(fa.placement.homogeneous, fb.placement.homogeneous)
                    for fa, fb in zip(a.frames, b.frames)))


class PhysicalWalker:
    """A walker on a floating base with point feet: its contact, checks, motors and fall check.

    Args:
        walker: The walker model.
        checks: The contact checks.
        steps_per_cycle: Touchdowns per learning cycle.
        phase: ``clock`` (the RMPs run on time), ``touchdown`` (their phase restarts at every
            touchdown; a cycle lasts ``steps_per_cycle`` steps) or ``mechanical`` (as touchdown,
            the phase within a step following the centre of mass's horizontal position over the
            stance foot, :meth:`PhysicalLoop._mechanical`).
        fall_row, fall_max: fall when ``|fall_row @ q| > fall_max`` [rad].
        stance, swing: the feet's names in stance-relative labels.
    """

    def __init__(self, walker: WalkerModel, checks: ContactChecks, steps_per_cycle: int = 1,
                 phase: str = "clock", fall_row: np.ndarray | None = None,
                 fall_max: float = np.inf, stance: str = "left", swing: str = "right"):
        self.walker, self.checks = walker, checks
        self.steps_per_cycle, self.phase = steps_per_cycle, phase
        self.fall_row, self.fall_max = fall_row, fall_max
        self.stance, self.swing = stance, swing
        self.contact = Contact(walker)
        model = walker.model
        self.base_v = np.array([model.joints[walker.robot.joint_id(n)].idx_v
                                for n in walker.base])
        self.base_q = np.array([model.joints[walker.robot.joint_id(n)].idx_q
                                for n in walker.base])
        motors = [i for i in range(model.nv) if i not in set(self.base_v)]
        v_name = {model.joints[j].idx_v: model.names[j] for j in range(1, model.njoints)}
        self.motor_names = [v_name[i] for i in motors]
        self.B = np.eye(model.nv)[:, motors]
        self.motor_v = np.array(motors)
        J = self.contact.jacobian(pin.neutral(model), stance)
        if len(self.base_v) < 2 or not np.allclose(J[:, self.base_v[:2]], np.eye(2)):
            raise RobotError(f"robot '{walker.robot.name}': the walker's first two base joints "
                             f"({', '.join(walker.base[:2])}) must translate the root along the "
                             "world's x and z")
        if checks.effort is None:
            checks.effort = np.full(len(motors), np.inf)

    def contact_for(self, plant) -> Contact:
        """The contact of a simulated world (same joints and frames): ``plant`` a
        :class:`pinocchio.Model` (e.g. an event's), or the plant's dynamics (a ``plant:``
        block's :class:`feltool.plant.rigid.FrictionPlant` brings its friction and motor
        gains)."""
        rigid = getattr(plant, "rigid", plant)
        model = getattr(rigid, "model", rigid)
        extra = plant if rigid is not plant else None
        if model is self.walker.model and extra is None:
            return self.contact
        key = (id(model), id(extra))
        cached = getattr(self, "_contacts", {}).get(key)
        if cached is not None and cached.model is model and cached.plant is extra:
            return cached
        self._contacts = {key: Contact(self.walker, model, extra)}
        return self._contacts[key]

    # -- desired trajectory and allocation --------------------------------------------------------
    def complete(self, qd: np.ndarray, vd: np.ndarray, ad: np.ndarray,
                 anchor: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The desired base translation from the stance foot's constraint: the foot at
        ``anchor`` (x, z) [m] with zero velocity and acceleration, the pitch and joints as given.
        The first two base coordinates must be the world's x and z (checked at build)."""
        c = self.contact
        anchor = np.zeros(2) if anchor is None else anchor
        qd, vd, ad = qd.copy(), vd.copy(), ad.copy()
        bx, bz = self.base_v[0], self.base_v[1]
        # exact in one step: the first two base coordinates translate the root along x and z
        p, = c.foot_positions(qd, self.stance)
        qd[self.base_q[0]] += anchor[0] - p[0]
        qd[self.base_q[1]] += anchor[1] - p[1]
        J = c.jacobian(qd, self.stance)
        vd[[bx, bz]] = 0.0
        vd[[bx, bz]] = -(J @ vd)
        ad[[bx, bz]] = 0.0
        ad[[bx, bz]] = -(J @ ad + c.drift(qd, vd, self.stance))
        return qd, vd, ad

    def anchored(self, q: np.ndarray, v: np.ndarray, contact: Contact
                 ) -> tuple[np.ndarray, np.ndarray]:
        """``(q, v)`` with the base translated so that ``contact``'s (a plant's) stance foot is
        at the origin with zero velocity; the pitch and the joints unchanged (``(q, v)`` itself
        when its kinematics are the known model's: the foot is there already)."""
        if contact is self.contact or same_kinematics(contact.model, self.walker.model):
            return q, v
        q, v = q.copy(), v.copy()
        p, = contact.foot_positions(q, self.stance)
        q[self.base_q[0]] -= p[0]
        q[self.base_q[1]] -= p[1]
        vf = contact.jacobian(q, self.stance) @ v
        v[self.base_v[0]] -= vf[0]
        v[self.base_v[1]] -= vf[1]
        return q, v

    def labelled(self, qd: np.ndarray, vd: np.ndarray, ad: np.ndarray, label: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The RMPs' values in the current labels: with an even ``steps_per_cycle`` the RMPs
        describe the cycle in its first step's labels (the thesis's gait coordinates), so in
        every second step (``label`` 1) the legs' values are exchanged."""
        if label == 0:
            return qd, vd, ad
        q2, v2 = self.walker.relabel(qd, vd)
        _, a2 = self.walker.relabel(qd, ad)
        return q2, v2, a2

    def chain(self, qd: np.ndarray, label: int) -> np.ndarray:
        r"""``(nv, nv)`` derivative of the completed desired state by the RMPs' values: the
        label's permutation, then the base translation that keeps the stance foot in place
        (:math:`\partial x_b/\partial p = -J_c` for the other coordinates, base columns zero;
        the same matrix maps velocities and, to first order, accelerations)."""
        nv = len(qd)
        G = np.eye(nv)
        if label:  # the relabelling is linear on velocities: its matrix column by column
            G = np.stack([self.walker.relabel(qd, e)[1] for e in np.eye(nv)], axis=1)
        J = self.contact.jacobian(qd, self.stance)
        T = np.eye(nv)
        bx, bz = self.base_v[0], self.base_v[1]
        T[[bx, bz], :] = -J
        T[:, [bx, bz]] = 0.0
        return T @ G

    def allocate(self, q: np.ndarray, tau_w: np.ndarray) -> np.ndarray:
        """Motor torques ``(k,)`` in [N m] for the wanted generalized force ``tau_w``."""
        return self.allocation_matrix(q) @ tau_w

    def allocation_matrix(self, q: np.ndarray) -> np.ndarray:
        """``A = (B^T W B)^{-1} B^T W``, ``(k, nv)``: motor torques per wanted generalized
        force at ``q``."""
        c = self.contact
        M = mass_matrix(c.model, c.data, q)
        J = c.jacobian(q, self.stance)
        Mi = np.linalg.inv(M)
        MiJ = Mi @ J.T
        W = Mi - MiJ @ np.linalg.solve(J @ MiJ, MiJ.T)
        BW = self.B.T @ W
        return np.linalg.solve(BW @ self.B, BW)

    def com_x(self, q: np.ndarray, v: np.ndarray, a: np.ndarray | None = None):
        """The centre of mass's horizontal position over the stance foot in [m] and its rate
        in [m/s]; with the accelerations ``a`` also its acceleration in [m/s^2] (the stance
        foot held)."""
        c = self.contact
        if a is None:
            com = pin.centerOfMass(c.model, c.data, q, v)
        else:
            com = pin.centerOfMass(c.model, c.data, q, v, a)
        foot, _ = c.foot_state(q, v, self.stance)
        out = (float(com[0] - foot[0]), float(c.data.vcom[0][0]))
        return out if a is None else out + (float(c.data.acom[0][0]),)

    def fallen(self, q: np.ndarray, v: np.ndarray) -> str | None:
        return fall_reason(q, v, self.fall_row, self.fall_max)


__all__ = ["PhysicalWalker", "same_kinematics"]
