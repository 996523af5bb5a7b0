r"""A planar walker's point contacts with the ground: stance dynamics, the rigid impact, energy.

The stance foot is a point contact held by a bilateral constraint on its (x, z) position, the
rows of its ``LOCAL_WORLD_ALIGNED`` frame Jacobian :math:`J_c` (``2 x nv``). The stance dynamics
are Pinocchio's KKT solve (``pin.forwardDynamics`` with a constraint Jacobian and drift):

.. math::

    M\ddot q + b = \tau + J_c^\top F, \qquad J_c\ddot q + \dot J_c\dot q = 0,

with :math:`F = (F_x, F_z)` the ground's force on the foot in [N] (:math:`F_z` the normal force).
The touchdown of the swing foot is a perfectly inelastic impact at its contact point
(``pin.impulseDynamics``, restitution 0):

.. math::

    M(\dot q^+ - \dot q^-) = J_c^\top I, \qquad J_c\dot q^+ = 0,

with :math:`I = (I_x, I_z)` the ground's impulse in [N s]. Nothing here writes an equation of
motion: Pinocchio builds and solves both systems.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from feltool.walking.model import WalkerModel


@dataclass
class StanceResult:
    """Accelerations under the stance contact and the contact force.

    Attributes:
        a: Generalized accelerations ``(nv,)`` [m/s^2, rad/s^2].
        force: Ground force on the stance foot ``(F_x, F_z)`` in [N].
    """

    a: np.ndarray
    force: np.ndarray


@dataclass
class ImpactResult:
    """A rigid impact at a foot.

    Attributes:
        v: Velocities after the impact ``(nv,)``.
        impulse: Ground impulse on the landing foot ``(I_x, I_z)`` in [N s].
        energy_lost: Kinetic energy before minus after, in [J] (never negative).
    """

    v: np.ndarray
    impulse: np.ndarray
    energy_lost: float


class Contact:
    """Stance dynamics and impacts of a :class:`~feltool.walking.model.WalkerModel` on the ground
    ``z = 0``.

    Args:
        walker: The walker (its model: the robot on its floating base).
        model: Dynamics to use instead of ``walker.model`` (e.g. a changed world with the same
            joints and frames).
        plant: The simulated plant's joint friction and motor gains (a
            :class:`feltool.plant.rigid.FrictionPlant`: the stance dynamics then act with
            ``gain * tau - friction(v)``), or None.
    """

    def __init__(self, walker: WalkerModel, model: pin.Model | None = None, plant=None):
        self.walker = walker
        self.model = walker.model if model is None else model
        self.data = self.model.createData()
        self.plant = plant

    def applied(self, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The generalized force the plant applies for the commanded ``tau`` [N m] at the
        velocities ``v``: ``tau`` itself, or the plant's ``gain * tau - friction(v)``."""
        if self.plant is None:
            return tau
        return self.plant.motor_gain * tau - self.plant.friction(v)

    def jacobian(self, q: np.ndarray, foot: str) -> np.ndarray:
        """``(2, nv)`` Jacobian of a foot's (x, z) in the world."""
        J = pin.computeFrameJacobian(self.model, self.data, q, self.walker.feet[foot],
                                     pin.LOCAL_WORLD_ALIGNED)
        return J[[0, 2], :]

    def foot_state(self, q: np.ndarray, v: np.ndarray, foot: str) -> tuple[np.ndarray, np.ndarray]:
        """(x, z) position in [m] and velocity in [m/s] of a foot's contact point."""
        m, d = self.model, self.data
        pin.forwardKinematics(m, d, q, v)
        fid = self.walker.feet[foot]
        pin.updateFramePlacement(m, d, fid)
        p = d.oMf[fid].translation
        vel = pin.getFrameVelocity(m, d, fid, pin.LOCAL_WORLD_ALIGNED).linear
        return np.array([p[0], p[2]]), np.array([vel[0], vel[2]])

    def foot_positions(self, q: np.ndarray, *feet: str) -> list[np.ndarray]:
        """(x, z) positions in [m] of the feet's contact points, from one kinematics pass."""
        m, d = self.model, self.data
        pin.forwardKinematics(m, d, q)
        out = []
        for foot in feet:
            fid = self.walker.feet[foot]
            pin.updateFramePlacement(m, d, fid)
            p = d.oMf[fid].translation
            out.append(np.array([p[0], p[2]]))
        return out

    def drift(self, q: np.ndarray, v: np.ndarray, foot: str) -> np.ndarray:
        r""":math:`\dot J_c\dot q`: the foot point's (x, z) acceleration at zero joint
        acceleration, in [m/s^2]."""
        m, d = self.model, self.data
        pin.forwardKinematics(m, d, q, v, np.zeros(m.nv))
        acc = pin.getFrameClassicalAcceleration(m, d, self.walker.feet[foot],
                                                pin.LOCAL_WORLD_ALIGNED).linear
        return np.array([acc[0], acc[2]])

    def stance(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, foot: str) -> StanceResult:
        """Accelerations and the ground force with ``foot`` held on the ground (KKT, Pinocchio),
        under the commanded generalized force ``tau`` (:meth:`applied`)."""
        gamma = self.drift(q, v, foot)
        J = self.jacobian(q, foot)
        a = pin.forwardDynamics(self.model, self.data, q, v, self.applied(v, tau), J, gamma)
        return StanceResult(np.array(a), np.array(self.data.lambda_c))

    def impact(self, q: np.ndarray, v: np.ndarray, foot: str) -> ImpactResult:
        """The perfectly inelastic impact of ``foot`` with the ground (``pin.impulseDynamics``)."""
        J = self.jacobian(q, foot)
        before = self.kinetic_energy(q, v)
        v_plus = np.array(pin.impulseDynamics(self.model, self.data, q, v, J))
        impulse = np.array(self.data.impulse_c)
        return ImpactResult(v_plus, impulse, before - self.kinetic_energy(q, v_plus))

    def kinetic_energy(self, q: np.ndarray, v: np.ndarray) -> float:
        """Kinetic energy in [J]."""
        return float(pin.computeKineticEnergy(self.model, self.data, q, v))

    def potential_energy(self, q: np.ndarray) -> float:
        """Potential energy in the model's gravity, in [J]."""
        return float(pin.computePotentialEnergy(self.model, self.data, q))

    def hold(self, q: np.ndarray, v: np.ndarray, foot: str, anchor: np.ndarray,
             iterations: int = 2) -> tuple[np.ndarray, np.ndarray]:
        """Put ``foot`` back on ``anchor`` (x, z) [m] and remove its velocity: the integrator's
        drift off the constraint, corrected by Gauss-Newton steps on the position (least-norm,
        through the Jacobian) and the inelastic projection of the velocity (the impulse map)."""
        for _ in range(iterations):
            p, _ = self.foot_state(q, v, foot)
            err = p - anchor
            if np.abs(err).max() < 1e-13:
                break
            J = self.jacobian(q, foot)  # 2 x nv, full row rank: J^+ = J^T (J J^T)^-1
            q = pin.integrate(self.model, q, -J.T @ np.linalg.solve(J @ J.T, err))
        J = self.jacobian(q, foot)
        if np.abs(J @ v).max() > 1e-13:
            v = np.array(pin.impulseDynamics(self.model, self.data, q, v, J))
        return q, v
