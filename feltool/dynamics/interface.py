"""The known models of a robot behind one small interface.

``inverse(q, v, a)`` is the inverse model (RNEA, eq. 3.1: ``u_ff = M(q) a + c(q, v) + g(q)``) that
turns desired trajectories into feedforward torque; ``forward(q, v, tau)`` is the forward model
(ABA) that simulates the robot; ``inverse_derivatives(q, v, a)`` returns the partial derivatives of
the inverse model that the learner chains with the RMP sensitivities (eq. 3.6).

Backends register by name in :data:`BACKENDS`; pick one with :func:`make_dynamics`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import pinocchio as pin

from feltool.errors import InputError


class Dynamics(Protocol):
    """What the simulator and the learner need from a dynamics backend."""

    nq: int
    nv: int

    def inverse(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Joint torques in [N m] (or [N]) that produce acceleration ``a``: RNEA."""

    def forward(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Joint accelerations in [rad/s^2] under torques ``tau``: ABA."""

    def inverse_derivatives(
        self, q: np.ndarray, v: np.ndarray, a: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d tau/d q, d tau/d v, d tau/d a = M(q))`` of the inverse model, each ``nv x nv``."""

    def inverse_batch(self, Q: np.ndarray, V: np.ndarray, A: np.ndarray) -> np.ndarray:
        """:meth:`inverse` on every row of ``(n, nv)`` arrays."""

    def inverse_derivatives_batch(
        self, Q: np.ndarray, V: np.ndarray, A: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(tau, d tau/d q, d tau/d v, M)`` on every row; ``(n, nv)`` and ``(n, nv, nv)``."""

    def integrate(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Configuration reached from ``q`` by the displacement ``dq`` (tangent vector)."""

    def difference(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
        """The tangent displacement ``dq`` that :meth:`integrate` takes from ``q0`` to ``q1``."""


def make_dynamics(model: pin.Model, backend: str = "pinocchio") -> Dynamics:
    """The known model of ``model`` in the named backend."""
    if backend == "pinocchio":
        from feltool.dynamics.pinocchio import PinocchioDynamics

        return PinocchioDynamics(model)
    if backend == "casadi":
        from feltool.dynamics.casadi_backend import CasadiDynamics

        return CasadiDynamics(model)
    raise InputError(f"unknown dynamics backend '{backend}'; available: pinocchio, casadi")


__all__ = ["Dynamics", "make_dynamics"]
