r"""Contact dynamics of a legged robot on the ground: any set of point feet in stance, and the
rigid impact of a set of feet.

Each stance foot is a 3D point contact (``pin.RigidConstraintModel``, ``CONTACT_3D``, at the
foot's point of its parent joint, forces expressed ``LOCAL_WORLD_ALIGNED``). The stance dynamics
are Pinocchio's constraint dynamics (``pin.constraintDynamics``):

.. math::

    M\ddot q + b = \tau + \sum_i J_i^\top f_i, \qquad J_i\ddot q + \dot J_i\dot q = 0,

with :math:`f_i` the ground's force on foot :math:`i` in [N], in the world's axes (its third
component the normal force), :math:`J_i` the foot point's linear Jacobian in the world's axes,
the constraint on the point's classical acceleration. A touchdown is a perfectly inelastic
impact of the feet in contact after it (``pin.impulseDynamics``, restitution 0):

.. math::

    M(\dot q^+ - \dot q^-) = \sum_i J_i^\top \iota_i, \qquad J_i\dot q^+ = 0,

with :math:`\iota_i` the ground's impulse on foot :math:`i` in [N s]. Pinocchio builds and
solves both systems; nothing here writes an equation of motion.

**Several points of one link** (a flat sole as its corners): their constraints are redundant
(four corners give 12 rows of rank 6), the accelerations and the velocities after an impact are
still unique, the forces are not. Pinocchio's proximal solver does not settle on any of them
(its multipliers drift along the null space), so such a set is solved as the KKT system on
Pinocchio's :math:`M`, :math:`b`, :math:`J`, :math:`\dot J\dot q` with the pseudo-inverse of
:math:`G = JM^{-1}J^\top`: :math:`f = -G^+(JM^{-1}(\tau - b) + \dot J\dot q)`,
:math:`\ddot q = M^{-1}(\tau - b + J^\top f)`, the least-norm forces, which are those of a sole
on equal, stiff springs at its points (the distribution minimising their elastic energy). The
checks then judge that distribution: a conservative test of the sole's contact (it asks each
point to push, which holds whenever the centre of pressure is inside the diamond of the
corners, a subset of the sole).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import cho_factor, cho_solve

from feltool.walking.legged.model import LeggedModel

#: Exact KKT solves (no proximal regularisation): the stance feet's Jacobian has full row rank
_PROX = pin.ProximalSettings(1e-13, 1e-13, 0.0, 1)

#: Eigenvalues of :math:`G` below this fraction of its largest are its null space (redundant sets)
_RANK_TOL = 1e-10


def pinv_psd(G: np.ndarray) -> np.ndarray:
    """The pseudo-inverse of a symmetric positive semi-definite ``G``."""
    ev, V = np.linalg.eigh(0.5 * (G + G.T))
    keep = ev > _RANK_TOL * max(float(ev.max(initial=0.0)), 1e-300)
    return (V[:, keep] / ev[keep]) @ V[:, keep].T


@dataclass
class StanceResult:
    """Accelerations under the stance contacts and the contact forces.

    Attributes:
        a: Generalized accelerations ``(nv,)``.
        forces: ``(n, 3)`` ground forces on the stance feet in [N], world axes, in the order of
            ``feet``.
        feet: The stance feet's names.
    """

    a: np.ndarray
    forces: np.ndarray
    feet: tuple[str, ...]


@dataclass
class ImpactResult:
    """A rigid impact of a set of feet.

    Attributes:
        v: Velocities after the impact ``(nv,)``.
        impulses: ``(n, 3)`` ground impulses on the feet in [N s], world axes.
        feet: The feet held after the impact (landing and staying), in that order.
        energy_lost: Kinetic energy before minus after, in [J].
    """

    v: np.ndarray
    impulses: np.ndarray
    feet: tuple[str, ...]
    energy_lost: float


class LeggedContact:
    """Stance dynamics and impacts of a :class:`LeggedModel` on the ground ``z = 0``.

    Args:
        legged: The robot.
        model: Dynamics to use instead of ``legged.model`` (a changed world with the same joints
            and frames, e.g. a payload on the base).
    """

    def __init__(self, legged: LeggedModel, model: pin.Model | None = None):
        self.legged = legged
        self.model = legged.model if model is None else model
        self.data = self.model.createData()
        self._sets: dict[tuple[str, ...], tuple] = {}

    def constraints(self, feet: tuple[str, ...]):
        """Pinocchio's constraint models and datas of the feet ``feet`` and the model's data
        they were initialised with (built once per set: ``initConstraintDynamics`` sizes a
        data for one set, and a data used with another set of another size corrupts memory)."""
        feet = tuple(feet)
        if feet not in self._sets:
            models = pin.StdVec_RigidConstraintModel()
            for foot in feet:
                frame = self.model.frames[self.legged.feet[foot]]
                cm = pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, self.model,
                                              frame.parentJoint, frame.placement,
                                              pin.LOCAL_WORLD_ALIGNED)
                cm.name = foot
                models.append(cm)
            datas = pin.StdVec_RigidConstraintData()
            for cm in models:
                datas.append(cm.createData())
            data = self.model.createData()
            pin.initConstraintDynamics(self.model, data, models, datas)
            self._sets[feet] = (models, datas, data)
        return self._sets[feet]

    def link(self, foot: str) -> int:
        """The joint index of the link that carries ``foot``."""
        return self.model.frames[self.legged.feet[foot]].parentJoint

    def redundant(self, feet: tuple[str, ...]) -> bool:
        """Whether two or more of ``feet`` are points of the same link (their constraints are
        then linearly dependent, and solved with :func:`pinv_psd`)."""
        joints = [self.link(f) for f in feet]
        return len(set(joints)) < len(joints)

    def _kkt(self, q: np.ndarray, v: np.ndarray, feet: tuple[str, ...]):
        """``(M^{-1} as a Cholesky factor, J, M^{-1} J^T, G^+)`` of a redundant set."""
        m, d = self.model, self.data
        M = np.array(pin.crba(m, d, q))
        M = np.triu(M) + np.triu(M, 1).T
        cho = cho_factor(M)
        J = self.jacobian(q, feet)
        MJ = cho_solve(cho, J.T)
        return cho, J, MJ, pinv_psd(J @ MJ)

    def stance(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
               feet: tuple[str, ...]) -> StanceResult:
        """Accelerations and ground forces with ``feet`` held on the ground, under the
        generalized force ``tau`` ``(nv,)`` (motor torques on the motor rows, external forces on
        any row); no feet: the free flight (``pin.aba``)."""
        feet = tuple(feet)
        if not feet:
            return StanceResult(np.array(pin.aba(self.model, self.data, q, v, tau)),
                                np.zeros((0, 3)), feet)
        if self.redundant(feet):
            cho, J, MJ, Gp = self._kkt(q, v, feet)
            free = cho_solve(cho, np.asarray(tau, float)
                             - np.array(pin.nonLinearEffects(self.model, self.data, q, v)))
            f = -Gp @ (J @ free + self.drift(q, v, feet))
            return StanceResult(free + MJ @ f, f.reshape(-1, 3), feet)
        models, datas, data = self.constraints(feet)
        a = pin.constraintDynamics(self.model, data, q, v, tau, models, datas, _PROX)
        forces = np.array([np.array(cd.contact_force.linear) for cd in datas])
        return StanceResult(np.array(a), forces, feet)

    def impact(self, q: np.ndarray, v: np.ndarray, feet: tuple[str, ...]) -> ImpactResult:
        """The perfectly inelastic impact that stops the feet ``feet`` (``pin.impulseDynamics``
        on their constraints): the velocities after it and each foot's impulse."""
        feet = tuple(feet)
        before = self.kinetic_energy(q, v)
        if self.redundant(feet):
            _, J, MJ, Gp = self._kkt(q, v, feet)
            imp = -Gp @ (J @ v)
            v_plus = np.asarray(v, float) + MJ @ imp
            return ImpactResult(v_plus, imp.reshape(-1, 3), feet,
                                before - self.kinetic_energy(q, v_plus))
        models, datas, data = self.constraints(feet)
        v_plus = np.array(pin.impulseDynamics(self.model, data, q, v, models, datas, 0.0,
                                              _PROX))
        impulses = np.array([np.array(cd.contact_force.linear) for cd in datas])
        return ImpactResult(v_plus, impulses, feet, before - self.kinetic_energy(q, v_plus))

    def jacobian(self, q: np.ndarray, feet: tuple[str, ...]) -> np.ndarray:
        """``(3n, nv)``: the feet points' linear Jacobians in the world's axes, stacked."""
        m, d = self.model, self.data
        pin.computeJointJacobians(m, d, q)
        pin.updateFramePlacements(m, d)
        return np.vstack([pin.getFrameJacobian(m, d, self.legged.feet[f],
                                               pin.LOCAL_WORLD_ALIGNED)[:3] for f in feet])

    def drift(self, q: np.ndarray, v: np.ndarray, feet: tuple[str, ...]) -> np.ndarray:
        r""":math:`\dot J\dot q` ``(3n,)``: the feet points' classical accelerations at zero
        joint acceleration, in [m/s^2]."""
        m, d = self.model, self.data
        pin.forwardKinematics(m, d, q, v, np.zeros(m.nv))
        return np.hstack([pin.getFrameClassicalAcceleration(m, d, self.legged.feet[f],
                                                            pin.LOCAL_WORLD_ALIGNED).linear
                          for f in feet])

    def foot_states(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(n_feet, 3)`` positions [m] and velocities [m/s] of every foot point, in the
        world, in the order of ``legged.feet``."""
        m, d = self.model, self.data
        pin.forwardKinematics(m, d, q, v)
        pos, vel = [], []
        for fid in self.legged.feet.values():
            pin.updateFramePlacement(m, d, fid)
            pos.append(np.array(d.oMf[fid].translation))
            vel.append(np.array(pin.getFrameVelocity(m, d, fid, pin.LOCAL_WORLD_ALIGNED).linear))
        return np.array(pos), np.array(vel)

    def positions(self, q: np.ndarray) -> np.ndarray:
        """``(n_feet, 3)`` positions [m] of every foot point in the world."""
        m, d = self.model, self.data
        pin.framesForwardKinematics(m, d, q)
        return np.array([d.oMf[f].translation for f in self.legged.feet.values()])

    def kinetic_energy(self, q: np.ndarray, v: np.ndarray) -> float:
        """Kinetic energy in [J]."""
        return float(pin.computeKineticEnergy(self.model, self.data, q, v))

    def potential_energy(self, q: np.ndarray) -> float:
        """Potential energy in the model's gravity, in [J]."""
        return float(pin.computePotentialEnergy(self.model, self.data, q))

    def hold(self, q: np.ndarray, v: np.ndarray, feet: tuple[str, ...], anchors: np.ndarray,
             iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
        """Put the stance feet back on their ``anchors`` ``(n, 3)`` [m] and remove their
        velocity: the integrator's drift off the constraints, corrected by Gauss-Newton steps
        on the position (least norm, through the Jacobian) and the inelastic projection of the
        velocity (the impulse map)."""
        feet = tuple(feet)
        if not feet:
            return q, v
        index = [list(self.legged.feet).index(f) for f in feet]
        for _ in range(iterations):
            pos = self.positions(q)[index]
            err = (pos - anchors).ravel()
            if np.abs(err).max() < 1e-13:
                break
            J = self.jacobian(q, feet)
            q = pin.integrate(self.model, q, -np.linalg.lstsq(J, err, rcond=None)[0])
        J = self.jacobian(q, feet)
        if np.abs(J @ v).max() > 1e-13:
            v = self.impact(q, v, feet).v
        return q, v
