r"""Gait analysis of a walker after learning: the step-to-step (Poincaré) map.

With the learned parameters held fixed, the closed loop is periodic in time (period T, one
learning cycle = ``steps_per_cycle`` steps), so the map :math:`x_{h+1} = P(x_h)` from the state
:math:`x = (q, \dot q)` at the start of one cycle (stance label 0, just after an impact) to the
next is its Poincaré map. A fixed point :math:`x^* = P(x^*)` is a periodic gait; it is a stable
limit cycle when every eigenvalue of :math:`\partial P/\partial x` at :math:`x^*` lies inside the
unit circle. The fixed point is found by iterating :math:`P` (one cycle each) while that
reaches it sooner than a Jacobian would, then by Newton's method on :math:`P(x) - x` with a
central finite-difference Jacobian (2 n cycles), kept while the steps converge. The spectrum is that of the
forward and of the backward difference Jacobian, the larger radius reported: the loop's
reference is interpolated linearly between its samples, so the map may have a kink at the
fixed point (an orbit closed onto its own samples has its phase on them at every control
step), and a gait is stable only when both sides contract (``smooth`` says whether they
agree within 2 %). The map runs on the experiment's
compiled engine when it has one (the Python engine's loop gives the same end states,
touchdowns and durations to rounding).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from feltool.engines.compiled.engine import compiled_engine, compiled_runner


def poincare(exp, theta: np.ndarray, q: np.ndarray, v: np.ndarray, plant=None,
             iterations: int = 30, newton: int = 6, eps: float = 1e-6,
             spectrum: bool = True, theta_m: np.ndarray | None = None,
             jacobian: dict | None = None) -> dict[str, Any]:
    """Fixed point, Jacobian eigenvalues, stride length [m] and speed [m/s] of a walker's gait.

    Args:
        exp: A built :class:`feltool.experiment.experiment.Experiment` with ``walking``.
        theta: RMP parameters (held fixed).
        q, v: A start state (e.g. the end of learning) at stance label 0.
        plant: The simulated world (default the experiment's plant).
        iterations, newton: Plain iterations and Newton steps at most [-].
        eps: The finite differences' step [-] (radians, metres and their rates).
        spectrum: Also the eigenvalues, stride and speed at the fixed point (else only the
            fixed point and its residual).
        theta_m: A physical walker's learned model correction and motor biases
            (``learning.model``), held fixed too.
        jacobian: A Jacobian of a nearby map carried between calls (``{"D": (2 nv, 2 nv)}``,
            e.g. the previous round of :func:`feltool.gait.orbit.close_on_orbit`): Newton's
            first, replaced when it stalls; the last one is left in it.
    """
    hyb = exp.hybrid
    plant = plant or exp.dynamics
    if plant is exp.dynamics and exp.plant is not None:
        plant = exp.plant
    model = exp.model_learner if getattr(exp.model_learner, "walker", False) else None
    if model is not None and theta_m is not None:
        hyb.model_correction = model.correction(theta_m)
        hyb.motor_bias = model.split(theta_m)[1] if model.n_bias else None
    P, Pv, Pa = exp.primitives.desired(theta)
    nv = len(q)

    def python_step(x):
        log = hyb.run_cycle(plant, x[:nv], x[nv:], P, Pv, Pa)
        return (None if log.fall else np.concatenate([log.q_end, log.v_end])), log

    step = _compiled_step(exp, theta, plant, theta_m) or python_step
    x, residual = np.concatenate([q, v]), np.inf
    fx, cycle = step(x)
    jacobian_cycles = 2 * len(x)
    # iterate the map while that reaches TOL in fewer cycles than a Jacobian costs, then
    # Newton's method with one Jacobian kept while it converges (a chord step: one cycle)
    for i in range(iterations):
        if fx is None:
            return {"fixed_point_found": False, "reason": cycle.fall}
        last, residual = residual, float(np.abs(fx - x).max())
        if residual < TOL or (i and not _iterating_pays(residual, last, jacobian_cycles)):
            break
        x = fx
        fx, cycle = step(x)
    D, last = (jacobian or {}).get("D"), np.inf
    for _ in range(newton):
        if fx is None:
            return {"fixed_point_found": False, "reason": cycle.fall}
        residual = float(np.abs(fx - x).max())
        if residual < TOL:
            break
        if D is None or residual > CONTRACTION * last:  # (a new Jacobian when it stalls)
            D = _jacobian(step, x, eps)
            if jacobian is not None:
                jacobian["D"] = D
        last = residual
        x = x - np.linalg.solve(D - np.eye(len(x)), fx - x)
        fx, cycle = step(x)
    residual = np.inf if fx is None else float(np.abs(fx - x).max())
    if not spectrum:
        return {"fixed_point_found": residual < 1e-6, "fixed_point_residual": residual,
                "fixed_point_q": x[:nv].tolist(), "fixed_point_v": x[nv:].tolist()}
    if fx is None:
        return {"fixed_point_found": False, "reason": cycle.fall}
    D_plus, D_minus = _one_sided_jacobians(step, x, fx, eps)
    rho_sides = [_radius(D_plus), _radius(D_minus)]
    eig = np.linalg.eigvals(D_plus if rho_sides[0] >= rho_sides[1] else D_minus)
    order = np.argsort(-np.abs(eig))
    eig = eig[order]
    stride = float(sum(abs(fx_) for _, _, fx_ in cycle.impacts))
    T = exp.config.period_s
    if exp.config.walking.phase != "clock" and np.isfinite(_duration(cycle)):
        T = _duration(cycle)  # touchdown phase: the cycle's own time
    return {
        "fixed_point_found": residual < 1e-6,
        "fixed_point_residual": residual,
        "fixed_point_q": x[:nv].tolist(), "fixed_point_v": x[nv:].tolist(),
        "eigenvalues_abs": np.abs(eig).tolist(),
        "eigenvalues_real": eig.real.tolist(), "eigenvalues_imag": eig.imag.tolist(),
        "spectral_radius": float(np.abs(eig).max()),
        "spectral_radius_one_sided": rho_sides,
        "smooth": bool(abs(rho_sides[0] - rho_sides[1]) <= _SMOOTH_TOL * max(rho_sides)),
        "stable": bool(np.abs(eig).max() < 1.0),
        "impacts_per_cycle": len(cycle.impacts),
        "impacts_by_guard": sum(bool(g) for _, g, _ in cycle.impacts),
        "stride_length_m": stride, "speed_m_per_s": stride / T,
    }


#: The fixed point's residual ``max |P(x) - x|`` [-] (radians, metres and their rates) at
#: which the search stops, and the least contraction of the residual per Newton step that
#: keeps its Jacobian.
TOL, CONTRACTION = 1e-10, 0.5


def _iterating_pays(residual: float, last: float, jacobian_cycles: int) -> bool:
    """Whether plain iteration, contracting the residual from ``last`` to ``residual`` per
    cycle, reaches :data:`TOL` within the cycles of one Jacobian."""
    rate = residual / last
    if not 0.0 < rate < 0.9:
        return False
    return np.log(TOL / residual) / np.log(rate) <= jacobian_cycles


def _duration(cycle) -> float:
    """A cycle's time in [s]: a physical walker's (its control steps, each cut short at a
    touchdown) from its log or its compiled outcome; NaN for other walkers."""
    contact = getattr(cycle, "contact", None)
    if contact is not None:
        return float(contact["duration"])
    return float(getattr(cycle, "elapsed", np.nan))


def _compiled_step(exp, theta: np.ndarray, plant, theta_m=None):
    """The map ``x -> (x_next or None, why it stopped)`` on the compiled engine when it runs
    this experiment's cycles (the cycle's end state does not depend on the update that follows
    it, so θ stays held), else None."""
    if exp.engine != "compiled" or compiled_engine(exp) is None:
        return None
    run, nv = compiled_runner(exp), exp.robot.model.nv

    def end(out):
        return (None if out.fall else np.concatenate([out.q_end, out.v_end])), out

    def step(x):
        return end(run(theta, x[:nv], x[nv:], plant, theta_m))

    if hasattr(run, "many"):  # (a physical walker's cycles in parallel)
        step.many = lambda X: [end(out) for out in run.many(theta, X, plant, theta_m)]
    return step


_SMOOTH_TOL = 0.02  # one-sided spectral radii this close (relative): the map is smooth there


def _radius(D: np.ndarray) -> float:
    return float(np.abs(np.linalg.eigvals(D)).max()) if np.all(np.isfinite(D)) else np.inf


def _one_sided_jacobians(step, x: np.ndarray, fx: np.ndarray, eps: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward difference Jacobians of ``step`` at ``x`` (``fx = step(x)``), with
    the same 2 n cycles as a central difference. The loop interpolates its reference linearly
    between samples, and on an orbit closed onto its own samples (:mod:`feltool.gait.orbit`)
    the phase sits on them at every control step: the map has a kink there, and a central
    difference would average a contracting side with an expanding one. A perturbation that
    falls (NaN column) gives an infinite radius."""
    plus, minus = _perturbed(step, x, eps)
    return (np.column_stack([(p - fx) / eps for p in plus]),
            np.column_stack([(fx - m) / eps for m in minus]))


def _jacobian(step, x: np.ndarray, eps: float) -> np.ndarray:
    plus, minus = _perturbed(step, x, eps)
    return np.column_stack([(p - m) / (2 * eps) for p, m in zip(plus, minus)])


def _perturbed(step, x: np.ndarray, eps: float) -> tuple[list, list]:
    """The map at ``x`` plus and minus ``eps`` along each coordinate (NaN where it falls), the
    2 n cycles at once when the step has ``many`` (the compiled engine's threads)."""
    n = len(x)
    X = [x + sign * eps * np.eye(n)[i] for sign in (1.0, -1.0) for i in range(n)]
    many = getattr(step, "many", None)
    ends = many(X) if many is not None else [step(xi) for xi in X]
    ends = [np.full(n, np.nan) if nxt is None else nxt for nxt, _ in ends]
    return ends[:n], ends[n:]
