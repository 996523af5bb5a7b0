"""The feedforward's sensitivity to the learned parameters by CasADi's algorithmic
differentiation (``learning.sensitivity: casadi``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pinocchio as pin

from feltool.dynamics.casadi_backend import BufferedCall
from feltool.dynamics.symbolic import symbolic_rnea
from feltool.motion.rmp import PrimitiveSet


def feedforward_jacobian(model: pin.Model, prims: PrimitiveSet, learned: np.ndarray
                         ) -> ca.Function:
    """``theta -> J`` with ``J[k*nv + r, p] = d u_ff[k, r] / d theta_learned[p]`` (in [N m]
    per unit parameter), by CasADi's algorithmic differentiation through the RMP limit cycle
    and the symbolic RNEA of ``model``; ``learned`` are the learned parameters' indices."""
    n = prims.n_steps
    theta = ca.SX.sym("theta", prims.n_params)
    rows = {name: [] for name in ("q", "v", "a")}
    for i, prim in prims.primitives.items():
        th = theta[prims.slices[i]]
        for name, X in (("q", prim.Xq), ("v", prim.Xv), ("a", prim.Xa)):
            rows[name].append(ca.mtimes(ca.DM(X), th).T)
    Qd, Vd, Ad = (ca.vertcat(*rows[name]) for name in ("q", "v", "a"))
    U_ff = symbolic_rnea(model).map(n, "serial")(Qd, Vd, Ad)  # nv x n
    jac = ca.jacobian(ca.vec(U_ff), theta[np.asarray(learned).tolist()])  # sample-major rows
    return ca.Function("ff_jacobian", [theta], [ca.densify(jac)])


class CasadiJacobian:
    """:func:`feedforward_jacobian` called with low overhead: ``theta -> J`` as an array."""

    def __init__(self, model: pin.Model, prims: PrimitiveSet, learned: np.ndarray):
        self._call = BufferedCall(feedforward_jacobian(model, prims, learned))

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        return self._call(theta)[0]
