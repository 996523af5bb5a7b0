"""Pinocchio backend: RNEA as the inverse model, ABA as the forward model."""

from __future__ import annotations

import numpy as np
import pinocchio as pin


class PinocchioDynamics:
    """Known models of a :class:`pinocchio.Model` computed by Pinocchio's algorithms.

    Pinocchio returns views into its ``Data`` buffers; every method here returns a copy so that
    a later call cannot change an earlier result.
    """

    def __init__(self, model: pin.Model):
        self.model = model
        self.data = model.createData()
        self.nq = model.nq
        self.nv = model.nv
        #: True when configuration and velocity spaces coincide (revolute/prismatic joints only),
        #: so that integration is a plain vector addition.
        self.euclidean = model.nq == model.nv and all(
            j.shortname() in _EUCLIDEAN_JOINTS for j in model.joints[1:]
        )

    def inverse(self, q, v, a):
        return pin.rnea(self.model, self.data, q, v, a).copy()

    def forward(self, q, v, tau):
        return pin.aba(self.model, self.data, q, v, tau).copy()

    def inverse_derivatives(self, q, v, a):
        pin.computeRNEADerivatives(self.model, self.data, q, v, a)
        mass = self.data.M.copy()
        # Pinocchio fills only the upper triangle of M here.
        mass = np.triu(mass) + np.triu(mass, 1).T
        return self.data.dtau_dq.copy(), self.data.dtau_dv.copy(), mass

    def integrate(self, q, dq):
        if self.euclidean:
            return q + dq
        return pin.integrate(self.model, q, dq)


_EUCLIDEAN_JOINTS = {
    "JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned",
    "JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned",
    "JointModelRUBX", "JointModelRUBY", "JointModelRUBZ",
}
