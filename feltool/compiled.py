r"""A whole learning cycle as one CasADi function, generated to C and compiled.

For per-cycle learning the cycle is a pure function of the RMP parameters :math:`\theta` and the
robot state :math:`x_0 = (q_0, \dot q_0)` at its start:

1. the limit cycle :math:`q_d, \dot q_d, \ddot q_d = X\theta` of every RMP (constant matrices,
   :mod:`feltool.rmp`);
2. feedforward :math:`u_{ff}^k` = symbolic RNEA and its Jacobian
   :math:`J_k = \partial u_{ff}^k/\partial\theta` (eq. 3.6, from the symbolic RNEA derivatives
   chained with the RMP sensitivities), ``map``-ped over the cycle's n samples;
3. the closed loop :math:`u^k = S(u_{ff}^k + b^k) - SKx`, symbolic ABA and the integrator,
   ``mapaccum``-ed over the n steps;
4. the FEL accumulations :math:`\sum_k J_k^\top e_k` and :math:`\sum_k J_k^\top E J_k`, and the
   per-cycle metrics.

The graph is built from the same :class:`pinocchio.Model` as the Pinocchio backend (through
:mod:`feltool.dynamics.casadi_backend`), generated to C, compiled with the system C compiler and
cached on disk under a hash of the graph, so seeds and later runs reuse it. Without a C compiler
it falls back to CasADi's interpreted virtual machine and says so once.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from feltool.dynamics.casadi_backend import (
    BufferedCall,
    symbolic_aba,
    symbolic_rnea,
    symbolic_rnea_derivatives,
)
from feltool.errors import ConfigError

_WARNED: set[str] = set()


def cache_dir() -> Path:
    """Where compiled cycles live: ``$FELTOOL_CACHE`` or ``~/.cache/feltool``."""
    root = os.environ.get("FELTOOL_CACHE") or Path.home() / ".cache" / "feltool"
    return Path(root) / "compiled"


def check_supported(exp) -> None:
    """Raise :class:`ConfigError` when the experiment needs something the compiled cycle lacks."""
    L = exp.config.learning
    problems = []
    if L.step != "per_cycle":
        problems.append(("learning.step", "backend 'compiled' supports only per_cycle learning"))
    if L.sensitivity == "finite_difference":
        problems.append(("learning.sensitivity", "backend 'compiled' computes exact sensitivities; "
                                                 "use exact (or casadi)"))
    if "enforce" == exp.config.sim.joint_limits or "saturate" == exp.config.sim.torque_limits:
        problems.append(("sim", "backend 'compiled' neither enforces joint limits nor saturates "
                                "torques; use report/ignore or another backend"))
    if exp.robot.model.nq != exp.robot.model.nv:
        problems.append(("robot", "backend 'compiled' needs revolute/prismatic joints only"))
    if problems:
        raise ConfigError(problems, str(exp.source) if exp.source else None)


def symbolic_desired(prims, theta):
    """The RMPs' limit cycles :math:`q_d, \\dot q_d, \\ddot q_d = X\\theta` as CasADi
    expressions, each ``nv x n`` (one column per sample)."""
    rows = {name: [] for name in ("q", "v", "a")}
    for i, prim in prims.primitives.items():
        th = theta[prims.slices[i]]
        for name, X in (("q", prim.Xq), ("v", prim.Xv), ("a", prim.Xa)):
            rows[name].append(ca.mtimes(ca.DM(X), th).T)
    return tuple(ca.vertcat(*rows[name]) for name in ("q", "v", "a"))


def cycle_graph(exp, full: bool) -> ca.Function:
    """The symbolic cycle ``(theta, x0) -> outputs`` of an experiment.

    Outputs (all dense): ``x_end`` (2 nv), ``fb_abs_mean`` (nv) [N m], ``track_err_rms`` (nv)
    [rad], ``grad`` (P) = sum_k J_k^T e_k, ``hess`` (P x P) = sum_k J_k^T E J_k, ``max_error``
    [rad] of the controlled quantities, ``max_speed`` [rad/s]; with ``full`` also ``X`` (2 nv x n)
    the states at each step's start, ``U`` (nv x n) the feedback and ``Qd`` (nv x n) the forward
    trajectory.
    """
    model = exp.robot.model
    prims, law, learner, loop = exp.primitives, exp.law, exp.learner, exp.loop
    n, nv, P = prims.n_steps, model.nv, learner.n_learned
    # The outer graph is MX, so that the mapped per-sample functions stay loops in the
    # generated C instead of being inlined 100 times (SX inlines every call).
    theta = ca.MX.sym("theta", prims.n_params)
    x0 = ca.MX.sym("x0", 2 * nv)

    # 1. Limit cycles, transposed: one column per sample.
    Qd, Vd, Ad = symbolic_desired(prims, theta)

    # 2. Feedforward and its Jacobian, one sample at a time, mapped over the cycle.
    Sq, Sv, Sa = (np.zeros((nv, P * n)) for _ in range(3))
    for i, cols, prim, rows in learner._blocks:
        sel = np.isin(rows, learner.learned)
        for k in range(n):
            Sq[i, k * P + cols] = prim.Xq[k, sel]
            Sv[i, k * P + cols] = prim.Xv[k, sel]
            Sa[i, k * P + cols] = prim.Xa[k, sel]
    q, v, a = (ca.SX.sym(s, nv) for s in ("q", "v", "a"))
    sq, sv, sa = (ca.SX.sym(s, nv, P) for s in ("sq", "sv", "sa"))
    tau = symbolic_rnea(model)(q, v, a)
    dq, dv, mass = symbolic_rnea_derivatives(model)(q, v, a)
    jac = ca.mtimes(dq, sq) + ca.mtimes(dv, sv) + ca.mtimes(mass, sa)
    ff = ca.Function("ff", [q, v, a, sq, sv, sa], [tau, jac]).map(n, "serial")
    U_ff, J = ff(Qd, Vd, Ad, ca.DM(Sq), ca.DM(Sv), ca.DM(Sa))  # nv x n, nv x (P n)

    # 3. Closed loop: u = F_k - SK x, x' by ABA and the integrator.
    track, stab = law.tracking.astype(float), law.stabilizing.astype(float)
    R = ca.diag(ca.DM(track)) @ Qd + ca.repmat(ca.DM(law.targets * stab), 1, n)
    Rd = ca.diag(ca.DM(track)) @ Vd
    K = np.hstack([law.kp[:, None] * law.C, law.kd[:, None] * law.C])
    B = ca.diag(ca.DM(law.kp)) @ R + ca.diag(ca.DM(law.kd)) @ Rd
    S = loop.actuated
    F = ca.diag(ca.DM(S)) @ (U_ff + B)
    x, f = ca.SX.sym("x", 2 * nv), ca.SX.sym("f", nv)
    torque = f - ca.mtimes(ca.DM(S[:, None] * K), x)
    aba = symbolic_aba(model)
    h = loop.dt / loop.substeps
    qs, vs = x[:nv], x[nv:]
    for _ in range(loop.substeps):
        acc = aba(qs, vs, torque)
        if loop.integrator == "semi_implicit_euler":
            vs = vs + h * acc
            qs = qs + h * vs
        else:
            qs, vs = qs + h * vs, vs + h * acc
    step = ca.Function("step", [x, f], [ca.vertcat(qs, vs)]).mapaccum("sim", n)
    X_after = step(x0, F)
    X = ca.horzcat(x0, X_after[:, : n - 1])
    U = B - ca.mtimes(ca.DM(K), X)

    # 4. FEL accumulations and metrics.
    E = exp.learner.error_mask
    jk, uk = ca.SX.sym("jk", nv, P), ca.SX.sym("uk", nv)
    # J^T E J only feeds the Levenberg-Marquardt step; skip its P^2 cost otherwise.
    jtj = (ca.mtimes(jk.T, ca.mtimes(ca.diag(ca.DM(E)), jk))
           if exp.config.learning.update == "gauss_newton" else ca.SX.zeros(P, P))
    acc_fn = ca.Function("acc", [jk, uk], [ca.mtimes(jk.T, E * uk), jtj])
    grad, hess = acc_fn.map("acc_map", "serial", n, [], [0, 1])(J, U)
    fb_mean = ca.sum2(ca.fabs(U)) / n
    err = Qd - X[:nv, :]
    rms = ca.sqrt(ca.sum2(err * err) / n)
    controlled = np.flatnonzero(law.tracking | law.stabilizing)
    ctrl_err = R - ca.mtimes(ca.DM(law.C), X[:nv, :])
    max_error = ca.mmax(ca.fabs(ctrl_err[controlled.tolist(), :])) if len(controlled) else ca.MX(0)
    max_speed = ca.mmax(ca.fabs(X[nv:, :]))
    outs = [X_after[:, n - 1], fb_mean, rms, grad, hess, max_error, max_speed]
    names = ["x_end", "fb_abs_mean", "track_err_rms", "grad", "hess", "max_error", "max_speed"]
    if full:
        outs += [X, U, Qd]
        names += ["X", "U", "Qd"]
    return ca.Function("cycle_full" if full else "cycle", [theta, x0],
                       [ca.densify(o) for o in outs], ["theta", "x0"], names)


def compile_functions(fns: list[ca.Function], directory: Path | None = None) -> list[ca.Function]:
    """Generate ``fns`` to one C file, compile it with the system compiler and load the
    functions from it; the library is cached under a hash of the graphs and the CasADi version."""
    directory = directory or cache_dir()
    digest = hashlib.sha256(ca.__version__.encode())
    for fn in fns:
        digest.update(fn.serialize().encode())
    name = f"feltool_cycle_{digest.hexdigest()[:20]}"
    lib = directory / f"{name}.so"
    compiler = shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")
    if not lib.is_file():
        if compiler is None:
            _warn_once("no C compiler found (set CC); the compiled backend runs in CasADi's "
                       "interpreted virtual machine instead, which is much slower")
            return fns
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=directory) as tmp:
            src = Path(tmp) / f"{name}.c"
            gen = ca.CodeGenerator(src.name, {"with_header": False, "casadi_int": "long long"})
            for fn in fns:
                gen.add(fn)
            gen.generate(tmp + os.sep)
            out = Path(tmp) / lib.name
            try:
                proc = subprocess.run([compiler, "-O3", "-shared", "-fPIC", "-o", str(out),
                                       str(src)], capture_output=True, text=True, timeout=600)
            except (OSError, subprocess.TimeoutExpired) as exc:
                proc = subprocess.CompletedProcess([], 1, "", str(exc))
            if proc.returncode != 0 or not out.is_file():
                _warn_once(f"compiling the cycle failed ({proc.stderr.strip()[:300]}); using "
                           "CasADi's interpreted virtual machine instead")
                return fns
            os.replace(out, lib)  # atomic: concurrent workers never load half a library
    return [ca.external(fn.name(), str(lib)) for fn in fns]


def _warn_once(message: str) -> None:
    if message not in _WARNED:
        _WARNED.add(message)
        print(f"feltool: note: {message}", file=sys.stderr)


#: Learning cycles run by one call of the compiled code (the update between them included).
CYCLES_PER_CALL = 10


def learning_graph(exp, cycles: int) -> ca.Function:
    r"""``cycles`` learning cycles, update included: ``(theta, x0) -> (states, stats)``.

    The update of :meth:`feltool.fel.FeedbackErrorLearner.apply` in CasADi: gradient
    :math:`\theta \mathrel{+}= \alpha \odot g`, or the Levenberg-Marquardt step on the
    weights. ``states`` column k is :math:`(\theta, x)` after cycle k; ``stats`` column k is
    ``(fb_abs_mean (nv), track_err_rms (nv), max_error, max_speed)`` of cycle k.
    """
    learner, P = exp.learner, exp.primitives.n_params
    nv = exp.robot.model.nv
    one = cycle_graph(exp, False)
    state = ca.MX.sym("state", P + 2 * nv)
    theta, x = state[:P], state[P:]
    x_end, fb, rms, grad, hess, max_err, max_speed = one(theta, x)
    delta = ca.DM(learner.rates) * grad
    if learner.update == "gauss_newton" and learner.n_learned:
        w = np.flatnonzero(~learner.is_goal).tolist()
        H = hess[w, w]
        lam = learner.damping * ca.trace(H) / len(w) + 1e-300
        step_w = ca.DM(learner.rates[w]) * ca.solve(H + lam * ca.DM.eye(len(w)), grad[w])
        delta = ca.vertcat(*[step_w[w.index(i)] if i in w else delta[i]
                             for i in range(learner.n_learned)])
    scatter = np.zeros((P, max(learner.n_learned, 1)))
    scatter[learner.learned, np.arange(learner.n_learned)] = 1.0
    theta_next = theta + ca.mtimes(ca.DM(scatter), delta) if learner.n_learned else theta
    step = ca.Function("learn_step", [state], [ca.vertcat(theta_next, x_end),
                                               ca.vertcat(fb, rms, max_err, max_speed)])
    return step.mapaccum("learn_cycles", cycles)


class CompiledCycle:
    """Runs learning cycles of an experiment through the compiled graph.

    ``lean(theta, x0)`` returns one cycle's metrics and FEL accumulations; ``full(theta, x0)``
    also the states, feedback and forward trajectory of every step (for the first and last
    cycle's traces); ``many(theta, x0)`` runs :data:`CYCLES_PER_CALL` cycles with their updates
    in one call.
    """

    def __init__(self, exp, compile: bool = True):
        check_supported(exp)
        self.n, self.nv = exp.primitives.n_steps, exp.robot.model.nv
        fns = [cycle_graph(exp, False), cycle_graph(exp, True),
               learning_graph(exp, CYCLES_PER_CALL)]
        if compile:
            fns = compile_functions(fns)
        self._lean, self._full, self._many = (BufferedCall(f) for f in fns)

    def lean(self, theta: np.ndarray, x0: np.ndarray) -> list[np.ndarray]:
        return self._lean(theta, x0)

    def full(self, theta: np.ndarray, x0: np.ndarray) -> list[np.ndarray]:
        return self._full(theta, x0)

    def many(self, theta: np.ndarray, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(states, stats)`` of the next :data:`CYCLES_PER_CALL` cycles (see
        :func:`learning_graph`), one column per cycle."""
        states, stats = self._many(np.concatenate([theta, x0]))
        return states.reshape(-1, CYCLES_PER_CALL), stats.reshape(-1, CYCLES_PER_CALL)


def feedforward_jacobian(exp) -> ca.Function:
    """``theta -> J`` with ``J[k*nv + r, p] = d u_ff[k, r] / d theta_learned[p]``, by CasADi's
    algorithmic differentiation through the RMP limit cycle and the symbolic RNEA
    (``sensitivity: casadi``)."""
    model, prims, learner = exp.robot.model, exp.primitives, exp.learner
    n = prims.n_steps
    theta = ca.SX.sym("theta", prims.n_params)
    Qd, Vd, Ad = symbolic_desired(prims, theta)
    U_ff = symbolic_rnea(model).map(n, "serial")(Qd, Vd, Ad)  # nv x n
    learned = theta[learner.learned.tolist()]
    jac = ca.jacobian(ca.vec(U_ff), learned)  # column-major: sample-major rows
    return ca.Function("ff_jacobian", [theta], [ca.densify(jac)])
