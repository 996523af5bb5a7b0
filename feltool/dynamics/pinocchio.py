"""Pinocchio backend: RNEA as the inverse model, ABA as the forward model."""

from __future__ import annotations

from functools import cache, partial

import numpy as np
import pinocchio as pin


class PinocchioDynamics:
    """Known models of a :class:`pinocchio.Model` computed by Pinocchio's algorithms.

    Pinocchio returns views into its ``Data`` buffers; every method here returns a new array so
    that a later call cannot change an earlier result (``forward`` is Pinocchio's ABA itself
    where that already returns one).
    """

    def __init__(self, model: pin.Model):
        self.model = model
        self.data = model.createData()
        self.nq = model.nq
        self.nv = model.nv
        self._lower = np.tril_indices(model.nv, -1)
        #: True when configuration and velocity spaces coincide (revolute/prismatic joints only),
        #: so that integration is a plain vector addition.
        self.euclidean = model.nq == model.nv and all(
            j.shortname() in _EUCLIDEAN_JOINTS for j in model.joints[1:]
        )
        # pin.aba returns a new array (copying it cost more than ABA itself), unless this
        # Pinocchio returns a view into its Data: then forward copies
        q0, z = pin.neutral(model), np.zeros(model.nv)
        first = pin.aba(model, self.data, q0, z, z)
        second = pin.aba(model, self.data, q0, z, np.ones(model.nv))
        self._aba_owns = first is not second and not np.shares_memory(first, second)
        self._direct()

    def _direct(self) -> None:
        """The loops' per-step call goes straight to Pinocchio (when ABA's result is new)."""
        if self._aba_owns:
            self.forward = partial(pin.aba, self.model, self.data)

    def __getstate__(self) -> dict:  # pickles by its model and data (process pools)
        state = dict(self.__dict__)
        state.pop("forward", None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._direct()

    def inverse(self, q, v, a):
        return pin.rnea(self.model, self.data, q, v, a).copy()

    def forward(self, q, v, tau):  # (a Pinocchio that returns a view; else see _direct)
        return pin.aba(self.model, self.data, q, v, tau).copy()

    def inverse_derivatives(self, q, v, a):
        pin.computeRNEADerivatives(self.model, self.data, q, v, a)
        mass = self.data.M.copy()
        mass[self._lower] = mass.T[self._lower]  # Pinocchio fills only the upper triangle
        return self.data.dtau_dq.copy(), self.data.dtau_dv.copy(), mass

    def inverse_batch(self, Q, V, A):
        """RNEA along a trajectory: rows of ``Q, V, A`` -> rows of torques ``(n, nv)``."""
        out = np.empty((len(Q), self.nv))
        model, data, rnea = self.model, self.data, pin.rnea
        for k in range(len(Q)):
            out[k] = rnea(model, data, Q[k], V[k], A[k])
        return out

    def inverse_derivatives_batch(self, Q, V, A):
        """``(tau, d tau/d q, d tau/d v, M)`` along a trajectory, shapes ``(n, nv)`` and
        ``(n, nv, nv)``: one pass of Pinocchio's RNEA derivatives per sample."""
        n, nv = len(Q), self.nv
        tau, D = np.empty((n, nv)), np.empty((n, 3, nv, nv))
        derivatives = partial(pin.computeRNEADerivatives, self.model, self.data)
        tau_now = self.data.tau  # (views into data, which each call overwrites: copied at once)
        for q, v, a, d, t in zip(Q, V, A, D, tau):
            d[0], d[1], d[2] = derivatives(q, v, a)
            t[:] = tau_now
        M = D[:, 2]
        lower, upper = self._lower, self._lower[::-1]
        M[:, lower[0], lower[1]] = M[:, upper[0], upper[1]]  # Pinocchio fills the upper triangle
        return tau, D[:, 0], D[:, 1], M

    def integrate(self, q, dq):
        if self.euclidean:
            return q + dq
        return pin.integrate(self.model, q, dq)

    def difference(self, q0, q1):
        if self.euclidean:
            return q1 - q0
        return pin.difference(self.model, q0, q1)


_EUCLIDEAN_JOINTS = {
    "JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned",
    "JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned",
    "JointModelRUBX", "JointModelRUBY", "JointModelRUBZ",
}


def mass_matrix(model: pin.Model, data: pin.Data, q: np.ndarray) -> np.ndarray:
    """The joint-space inertia matrix M(q), whole and symmetric, by Pinocchio's CRBA (a new
    array: a later call cannot change it)."""
    M = pin.crba(model, data, q)
    if not _crba_fills_whole():  # Pinocchio 3 fills the upper triangle only
        return np.triu(M) + np.triu(M, 1).T
    return M if M.flags.owndata else M.copy()


@cache
def _crba_fills_whole() -> bool:
    """Whether this Pinocchio's CRBA fills the whole matrix (Pinocchio 4) or only its upper
    triangle (Pinocchio 3), tried once on its sample manipulator."""
    model = pin.buildSampleModelManipulator()
    M = pin.crba(model, model.createData(),
                 pin.integrate(model, pin.neutral(model), np.full(model.nv, 0.3)))
    return bool(np.array_equal(M, M.T))
