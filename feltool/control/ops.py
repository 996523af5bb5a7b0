"""The few array operations the learning cycle needs, for numbers and for CasADi graphs.

:mod:`feltool.control.cycle` writes each piece of a learning cycle once, against one of these
namespaces: :data:`NUMPY` evaluates it on numpy arrays (the Python engine, one control step at
a time), :data:`CASADI` builds it as a CasADi expression (the compiled engine, traced once and
generated to C). Vectors are 1-D numpy arrays or CasADi column vectors; ``@``, ``+``, ``-``,
``*`` and ``/`` work on both and need nothing from here.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


class NumpyOps:
    """Operations on numpy arrays."""

    symbolic = False

    @staticmethod
    def where(cond, a, b):
        return np.where(cond, a, b)

    floor, fmax = np.floor, np.maximum

    @staticmethod
    def clip(x, low, high):
        return np.clip(x, low, high)

    @staticmethod
    def dot(a, b):
        return a @ b

    @staticmethod
    def solve(A, b):
        return np.linalg.solve(A, b)

    @staticmethod
    def vec(values):
        return np.array(values, dtype=float)

    eye = staticmethod(np.eye)

    @staticmethod
    def colsum(M):
        """Sum over the rows: one value per column (1-D)."""
        return M.sum(axis=0)

    @staticmethod
    def vecmat(s, X):
        """:math:`X^T s`."""
        return s @ X

    @staticmethod
    def scale_rows(X, s):
        """Row k of ``X`` times ``s[k]``."""
        return s[:, None] * X

    @staticmethod
    def concat(vectors):
        return np.concatenate(vectors)

    @staticmethod
    def blocks(rows):
        return np.block(rows)


class CasadiOps:
    """The same operations building CasADi expressions."""

    symbolic = True

    @staticmethod
    def where(cond, a, b):
        return ca.if_else(cond, a, b)

    floor, fmax = staticmethod(ca.floor), staticmethod(ca.fmax)

    @staticmethod
    def clip(x, low, high):
        return ca.fmin(ca.fmax(x, low), high)

    @staticmethod
    def dot(a, b):
        return ca.dot(a, b)

    @staticmethod
    def solve(A, b):
        return ca.solve(A, b)

    @staticmethod
    def vec(values):
        return ca.vertcat(*values)

    @staticmethod
    def eye(n):
        return ca.DM.eye(n)

    @staticmethod
    def colsum(M):
        """Sum over the rows: one value per column (a column vector)."""
        return ca.sum1(M).T

    @staticmethod
    def vecmat(s, X):
        """:math:`X^T s` without transposing X."""
        return ca.mtimes(s.T, X).T

    @staticmethod
    def scale_rows(X, s):
        return X * ca.repmat(s, 1, X.shape[1])

    @staticmethod
    def concat(vectors):
        return ca.vertcat(*vectors)

    @staticmethod
    def blocks(rows):
        return ca.blockcat(rows)


NUMPY = NumpyOps()
CASADI = CasadiOps()

__all__ = ["CASADI", "NUMPY", "CasadiOps", "NumpyOps"]
