"""CasADi backend: the known models as compiled CasADi functions behind the dynamics interface,
and a low-overhead call of a CasADi function.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np
import pinocchio as pin

from feltool.dynamics.spatial import describe_joints
from feltool.dynamics.symbolic import symbolic_aba, symbolic_rnea, symbolic_rnea_derivatives


class BufferedCall:
    """Evaluates a CasADi ``Function`` of dense vectors through ``Function.buffer()``.

    Calling a ``Function`` from Python with numpy arguments costs some 40 us of argument
    conversion, whatever the work inside; the buffer interface evaluates in place on numpy arrays
    that it was handed once (about 1 us for the two-link arm). Inputs are copied into the
    pre-allocated arrays (those in ``keep`` only when a different array object is passed: the
    caller promises not to change an array it passed) and every result is returned as a fresh
    copy. Not thread-safe: one
    instance per thread (each :class:`CasadiDynamics` owns its own).
    """

    def __init__(self, fn: ca.Function, keep: tuple[int, ...] = ()):
        for i in range(fn.n_in()):
            if fn.nnz_in(i) != fn.numel_in(i) or fn.size2_in(i) != 1:
                raise ValueError(f"{fn.name()}: input {i} is not a dense column vector")
        for i in range(fn.n_out()):
            if fn.nnz_out(i) != fn.numel_out(i):
                raise ValueError(f"{fn.name()}: output {i} is not dense")
        self.fn = fn
        self._buffer, self._eval = fn.buffer()
        self._args = [np.zeros(fn.numel_in(i)) for i in range(fn.n_in())]
        self._results = [np.zeros(fn.numel_out(i)) for i in range(fn.n_out())]
        self._shapes = [fn.size_out(i) for i in range(fn.n_out())]
        for i, arr in enumerate(self._args):
            self._buffer.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self._results):
            self._buffer.set_res(i, memoryview(arr))
        self._keep = set(keep)
        self._kept: dict[int, np.ndarray] = {}

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        for i, (dst, src) in enumerate(zip(self._args, args, strict=True)):
            if i in self._keep:  # the caller never changes an array it passed
                if self._kept.get(i) is src:
                    continue
                self._kept[i] = src
            src = np.asarray(src, dtype=float)
            if src.shape != dst.shape:
                raise ValueError(
                    f"{self.fn.name()}: argument '{self.fn.name_in(i)}' has shape {src.shape}, "
                    f"expected {dst.shape}"
                )
            dst[:] = src
        self._eval()
        out = []
        for res, (rows, cols) in zip(self._results, self._shapes, strict=True):
            # CasADi stores dense matrices column by column.
            out.append(res.copy() if cols == 1 else res.reshape(rows, cols, order="F").copy())
        return out


class CasadiDynamics:
    """Known models of a :class:`pinocchio.Model` evaluated through CasADi symbolic functions.

    Same interface as :class:`feltool.dynamics.pinocchio.PinocchioDynamics`: numpy arrays in,
    new float numpy arrays out (1-D vectors, 2-D matrices). The CasADi ``Function`` objects are
    built once, in the constructor, and kept as :attr:`rnea_fn`, :attr:`aba_fn` and
    :attr:`derivatives_fn` (use them directly for code generation or inside larger CasADi graphs).
    The numeric methods evaluate them through CasADi's low-overhead buffer interface, so an
    instance must not be shared between threads; it pickles (by its model) for process pools.
    """

    def __init__(self, model: pin.Model):
        self.model = model
        self.nq = model.nq
        self.nv = model.nv
        joints = describe_joints(model)  # raises InputError for unsupported joints
        #: True when every joint is revolute/prismatic, so that integration is ``q + dq``.
        self.euclidean = all(jt.kind != "unbounded" for jt in joints)
        self.rnea_fn: ca.Function = symbolic_rnea(model)
        self.aba_fn: ca.Function = symbolic_aba(model)
        self.derivatives_fn: ca.Function = symbolic_rnea_derivatives(model)
        self._rnea = BufferedCall(self.rnea_fn)
        self._aba = BufferedCall(self.aba_fn)
        self._derivatives = BufferedCall(self.derivatives_fn)

    def __getstate__(self) -> dict:
        return {"model": self.model}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["model"])

    def inverse(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Joint torques (nv) in [N m] or [N] that produce acceleration ``a``: RNEA."""
        return self._rnea(q, v, a)[0]

    def forward(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Joint accelerations (nv) in [rad/s^2] or [m/s^2] under torques ``tau``: ABA."""
        return self._aba(q, v, tau)[0]

    def inverse_derivatives(
        self, q: np.ndarray, v: np.ndarray, a: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(d tau/d q, d tau/d v, M(q))``, each nv x nv, from CasADi's jacobians of the RNEA."""
        dq, dv, mass = self._derivatives(q, v, a)
        return dq, dv, mass

    def integrate(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """Configuration reached from ``q`` by the tangent displacement ``dq``.

        ``q + dq`` for revolute/prismatic joints; with continuous joints, Pinocchio's
        ``integrate`` (which turns each ``(cos, sin)`` pair on the unit circle).
        """
        q = np.asarray(q, dtype=float)
        dq = np.asarray(dq, dtype=float)
        if self.euclidean:
            return q + dq
        return np.array(pin.integrate(self.model, q, dq), dtype=float)

    def difference(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
        """The tangent displacement from ``q0`` to ``q1`` (Pinocchio's ``difference``)."""
        q0, q1 = np.asarray(q0, dtype=float), np.asarray(q1, dtype=float)
        if self.euclidean:
            return q1 - q0
        return np.array(pin.difference(self.model, q0, q1), dtype=float)


def call_in_threads(fn: ca.Function, firsts: list[np.ndarray], *rest: np.ndarray) -> list:
    """``fn(first, *rest)`` for each of ``firsts``, on every CPU this process may use: threads,
    each with a :class:`BufferedCall` of its own (CasADi evaluates without the interpreter's
    lock; a compiled walker cycle's 16 calls took 58 ms on two threads, 106 ms one after the
    other). The results in order, the same to the bit as one call after the other."""
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    workers = max(1, min(len(firsts), cpus or 1))
    keep = tuple(range(1, 1 + len(rest)))
    calls = [BufferedCall(fn, keep=keep) for _ in range(workers)]
    if workers == 1:
        return [calls[0](x, *rest) for x in firsts]

    def part(w: int) -> list:
        return [calls[w](x, *rest) for x in firsts[w::workers]]

    with ThreadPoolExecutor(workers) as pool:
        parts = list(pool.map(part, range(workers)))
    return [parts[i % workers][i // workers] for i in range(len(firsts))]


def _batch_methods():
    """``inverse_batch`` and ``inverse_derivatives_batch`` by looping the per-sample calls."""

    def inverse_batch(self, Q, V, A):
        return np.array([self.inverse(q, v, a) for q, v, a in zip(Q, V, A, strict=True)])

    def inverse_derivatives_batch(self, Q, V, A):
        tau = self.inverse_batch(Q, V, A)
        parts = [self.inverse_derivatives(q, v, a) for q, v, a in zip(Q, V, A, strict=True)]
        return (tau, *(np.array([p[i] for p in parts]) for i in range(3)))

    return inverse_batch, inverse_derivatives_batch


CasadiDynamics.inverse_batch, CasadiDynamics.inverse_derivatives_batch = _batch_methods()
