"""What compiling the legged plant alone would give (issue 32, acceptance 4: a compiled engine
for the quadruped): Solo-12's stance sub-step -- classical Runge-Kutta over 1 ms with two feet
held, four KKT solves of M a + b = tau + J^T f, J a + Jdot v = 0 -- as a CasADi graph of
feltool's symbolic free-flyer dynamics (M, b, the feet's Jacobians and drifts from Pinocchio's
numbers, Pinocchio's ``integrate``), generated to C and compiled, against the Python loop's own
sub-step (feltool.walking.legged.events.rk4: Pinocchio's ``constraintDynamics`` called from
Python), and against one call of a compiled function that does nothing (the cost of calling
compiled code from Python). A second compiled sub-step is all scalar expressions (CasADi SX:
the KKT system solved symbolically, no call into a linear solver), called on ``--batch``
states at once (CasADi's ``map``): its time per sub-step is the generated code's own, without
the cost of the call. Both are first checked against the Python one.

    python benchmarks/legged_compiled_step.py [--calls 3000] [--batch 200]

Prints each per-call time in [us] and the ratios, measured in one run.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import casadi as ca  # noqa: E402
import numpy as np  # noqa: E402

from feltool.dynamics import symbolic  # noqa: E402
from feltool.dynamics.spatial import describe_joints  # noqa: E402
from feltool.engines.compiled.library import compile_functions  # noqa: E402
from feltool.walking.legged.contact import LeggedContact  # noqa: E402
from feltool.walking.legged.events import rk4  # noqa: E402
from feltool.walking.legged.model import load_solo12  # noqa: E402

FEET = ("FL", "HR")  # a trot's stance pair


def stance_terms(legged) -> ca.Function:
    """``(q, v) -> (M, b, J, Jdot v)`` of the stance feet, symbolically."""
    m = legged.model
    joints = describe_joints(m, floating=True)
    q, v, a = ca.SX.sym("q", m.nq), ca.SX.sym("v", m.nv), ca.SX.sym("a", m.nv)
    zero = ca.SX.zeros(m.nv)
    M = ca.jacobian(symbolic._rnea_expr(m, joints, q, zero, a), a)
    b = symbolic._rnea_expr(m, joints, q, v, zero)
    tangent = symbolic._tangent_jacobian(m, joints, q)
    rows, drift = [], []
    for foot in FEET:
        p = symbolic._frame_position_expr(m, joints, q, legged.feet[foot])
        J = ca.mtimes(ca.jacobian(p, q), tangent)
        rows.append(J)
        drift.append(ca.mtimes(ca.jacobian(ca.mtimes(J, v), q), ca.mtimes(tangent, v)))
    return ca.Function("terms", [q, v], [M, b, ca.vertcat(*rows), ca.vertcat(*drift)])


def substep(legged) -> ca.Function:
    """The RK4 sub-step ``(q, v, tau, h) -> (q', v', forces at the start)``."""
    m, terms, integrate = legged.model, stance_terms(legged), symbolic.symbolic_integrate(legged.model)
    q, v, tau, h = (ca.MX.sym("q", m.nq), ca.MX.sym("v", m.nv), ca.MX.sym("tau", m.nv),
                    ca.MX.sym("h"))

    def dynamics(q, v):
        M, b, J, drift = terms(q, v)
        free = ca.solve(M, tau - b, "ldl")
        MJ = ca.solve(M, J.T, "ldl")
        f = -ca.solve(ca.mtimes(J, MJ), ca.mtimes(J, free) + drift, "ldl")
        return free + ca.mtimes(MJ, f), f

    return ca.Function("substep", [q, v, tau, h], rk4_step(dynamics, integrate, q, v, h))


def rk4_step(dynamics, integrate, q, v, h) -> list:
    """Classical Runge-Kutta over ``h`` on ``dynamics(q, v) -> (a, f)``: ``[q', v', f at the
    start]`` (the configuration moved by ``integrate``, as the Python loop's rk4)."""
    a1, f1 = dynamics(q, v)
    v2, q2 = v + 0.5 * h * a1, integrate(q, 0.5 * h * v)
    a2, _ = dynamics(q2, v2)
    v3, q3 = v + 0.5 * h * a2, integrate(q, 0.5 * h * v2)
    a3, _ = dynamics(q3, v3)
    v4, q4 = v + h * a3, integrate(q, h * v3)
    a4, _ = dynamics(q4, v4)
    return [integrate(q, h / 6 * (v + 2 * v2 + 2 * v3 + v4)),
            v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4), f1]


def substep_sx(legged, h: float) -> ca.Function:
    """The same sub-step, ``(q, v, tau) -> (q', v', forces at the start)`` for a fixed ``h``
    [s], all in SX: each KKT system [[M, -J^T], [J, 0]] [a; f] = [tau - b; -Jdot v] solved
    symbolically."""
    m, terms, integrate = legged.model, stance_terms(legged), symbolic.symbolic_integrate(legged.model)
    q, v, tau = ca.SX.sym("q", m.nq), ca.SX.sym("v", m.nv), ca.SX.sym("tau", m.nv)

    def dynamics(q, v):
        M, b, J, drift = terms(q, v)
        n = J.shape[0]
        x = ca.solve(ca.blockcat([[M, -J.T], [J, ca.SX.zeros(n, n)]]), ca.vertcat(tau - b, -drift))
        return x[:m.nv], x[m.nv:]

    return ca.Function("substep_sx", [q, v, tau], rk4_step(dynamics, integrate, q, v, h))


def per_call(fn, calls: int) -> float:
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return (time.perf_counter() - t0) / calls * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=3000)
    ap.add_argument("--batch", type=int, default=200)
    args = ap.parse_args()
    solo = load_solo12(effort=2.7)
    contact = LeggedContact(solo)
    rng = np.random.default_rng(0)
    q0 = solo.standing()
    v0 = 0.1 * rng.normal(size=solo.nv)
    tau = np.r_[np.zeros(6), rng.normal(size=solo.nv - 6)]
    t0 = time.perf_counter()
    (compiled,) = compile_functions([substep(solo)])
    built = time.perf_counter() - t0
    x = ca.SX.sym("x", solo.nv)
    (nothing,) = compile_functions([ca.Function("nothing", [x], [x])])
    sx = substep_sx(solo, 1e-3)
    t0 = time.perf_counter()
    (batched,) = compile_functions([sx.map(args.batch)])
    built_sx = time.perf_counter() - t0
    qp, vp, fp = rk4(contact, q0, v0, lambda qq, off: tau, 1e-3, FEET)
    states = [np.tile(x[:, None], args.batch) for x in (q0, v0, tau)]
    for name, out, took in (("compiled", compiled(q0, v0, tau, 1e-3), built),
                            ("SX", [r[:, 0] for r in batched(*states)], built_sx)):
        qc, vc, fc = (np.array(r).ravel() for r in out)
        err = max(np.abs(qc - qp).max(), np.abs(vc - vp).max(), np.abs(fc - fp.ravel()).max())
        print(f"{name} sub-step built in {took:.1f} s; against the Python sub-step: largest "
              f"difference {err:.1e} (q [m, -], v [m/s, rad/s], forces [N])")
    python = per_call(lambda: rk4(contact, q0, v0, lambda qq, off: tau, 1e-3, FEET), args.calls)
    comp = per_call(lambda: compiled(q0, v0, tau, 1e-3), args.calls)
    call = per_call(lambda: nothing(v0), args.calls)
    each = per_call(lambda: batched(*states), max(1, args.calls // args.batch)) / args.batch
    print(f"| Python sub-step (Pinocchio's constraintDynamics x 4) | {python:.1f} us | 1 |")
    print(f"| compiled sub-step (CasADi C, 4 KKT solves) | {comp:.1f} us | "
          f"{python / comp:.2f}x |")
    print(f"| compiled sub-step, SX ({sx.n_instructions()} instructions), {args.batch} per "
          f"call | {each:.1f} us | {python / each:.2f}x |")
    print(f"| a compiled call doing nothing | {call:.1f} us | {python / call:.1f}x |")


if __name__ == "__main__":
    main()
