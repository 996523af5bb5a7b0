r"""Gait analysis of a walker after learning: the step-to-step (Poincaré) map.

With the learned parameters held fixed, the closed loop is periodic in time (period T, one
learning cycle = ``steps_per_cycle`` steps), so the map :math:`x_{h+1} = P(x_h)` from the state
:math:`x = (q, \dot q)` at the start of one cycle (stance label 0, just after an impact) to the
next is its Poincaré map. A fixed point :math:`x^* = P(x^*)` is a periodic gait; it is a stable
limit cycle when every eigenvalue of :math:`\partial P/\partial x` at :math:`x^*` lies inside the
unit circle. The fixed point is found by iterating :math:`P` and then Newton's method on
:math:`P(x) - x` with a central finite-difference Jacobian. The spectrum is that of the
forward and of the backward difference Jacobian, the larger radius reported: the loop's
reference is interpolated linearly between its samples, so the map may have a kink at the
fixed point (an orbit closed onto its own samples has its phase on them at every control
step), and a gait is stable only when both sides contract (``smooth`` says whether they
agree within 2 %). The map runs on the experiment's
compiled engine when it has one (the Python engine's loop gives the same end states to
rounding), the last cycle on the Python engine for its touchdowns.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from feltool.engines.compiled.engine import compiled_engine, compiled_runner


def poincare(exp, theta: np.ndarray, q: np.ndarray, v: np.ndarray, plant=None,
             iterations: int = 10, newton: int = 6, eps: float = 1e-6,
             spectrum: bool = True, theta_m: np.ndarray | None = None) -> dict[str, Any]:
    """Fixed point, Jacobian eigenvalues, stride length [m] and speed [m/s] of a walker's gait.

    Args:
        exp: A built :class:`feltool.experiment.experiment.Experiment` with ``walking``.
        theta: RMP parameters (held fixed).
        q, v: A start state (e.g. the end of learning) at stance label 0.
        plant: The simulated world (default the experiment's plant).
        spectrum: Also the eigenvalues, stride and speed at the fixed point (else only the
            fixed point and its residual).
        theta_m: A physical walker's learned model correction and motor biases
            (``learning.model``), held fixed too.
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
        return (None if log.fall else np.concatenate([log.q_end, log.v_end])), log.fall

    step = _compiled_step(exp, theta, plant, theta_m) or python_step
    x = np.concatenate([q, v])
    for _ in range(iterations):
        nxt, fall = step(x)
        if nxt is None:
            return {"fixed_point_found": False, "reason": fall}
        x = nxt
    residual = np.inf
    for _ in range(newton):
        fx, _ = step(x)
        r = fx - x
        residual = float(np.abs(r).max())
        if residual < 1e-10:
            break
        D = _jacobian(step, x, eps)
        x = x - np.linalg.solve(D - np.eye(len(x)), r)
    if not spectrum:
        fx = step(x)[0]
        residual = np.inf if fx is None else float(np.abs(fx - x).max())
        return {"fixed_point_found": residual < 1e-6, "fixed_point_residual": residual,
                "fixed_point_q": x[:nv].tolist(), "fixed_point_v": x[nv:].tolist()}
    log = hyb.run_cycle(plant, x[:nv], x[nv:], P, Pv, Pa)  # its touchdowns and steps
    fx = np.concatenate([log.q_end, log.v_end]) if step is python_step else step(x)[0]
    residual = float(np.abs(fx - x).max())
    D_plus, D_minus = _one_sided_jacobians(step, x, fx, eps)
    rho_sides = [_radius(D_plus), _radius(D_minus)]
    eig = np.linalg.eigvals(D_plus if rho_sides[0] >= rho_sides[1] else D_minus)
    order = np.argsort(-np.abs(eig))
    eig = eig[order]
    stride = float(sum(abs(fx_) for _, _, fx_ in log.impacts))
    T = exp.config.period_s
    if getattr(log, "steps", None) is not None and exp.config.walking.phase != "clock":
        T = float(sum(st.duration for st in log.steps[:len(log.impacts)]))  # touchdown phase
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
        "impacts_per_cycle": len(log.impacts),
        "impacts_by_guard": sum(bool(g) for _, g, _ in log.impacts),
        "stride_length_m": stride, "speed_m_per_s": stride / T,
    }


def _compiled_step(exp, theta: np.ndarray, plant, theta_m=None):
    """The map ``x -> (x_next or None, why it stopped)`` on the compiled engine when it runs
    this experiment's cycles (the cycle's end state does not depend on the update that follows
    it, so θ stays held), else None."""
    if exp.engine != "compiled" or compiled_engine(exp) is None:
        return None
    run, nv = compiled_runner(exp), exp.robot.model.nv

    def step(x):
        out = run(theta, x[:nv], x[nv:], plant, theta_m)
        return (None if out.fall else np.concatenate([out.q_end, out.v_end])), out.fall

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
    n = len(x)
    D = [np.empty((n, n)), np.empty((n, n))]
    for i in range(n):
        for side, sign in enumerate((1.0, -1.0)):
            dx = np.zeros(n)
            dx[i] = sign * eps
            nxt, _ = step(x + dx)
            D[side][:, i] = np.nan if nxt is None else (nxt - fx) / (sign * eps)
    return D[0], D[1]


def _jacobian(step, x: np.ndarray, eps: float) -> np.ndarray:
    D = np.empty((len(x), len(x)))
    for i in range(len(x)):
        dx = np.zeros(len(x))
        dx[i] = eps
        plus, _ = step(x + dx)
        minus, _ = step(x - dx)
        if plus is None or minus is None:
            D[:, i] = np.nan
        else:
            D[:, i] = (plus - minus) / (2 * eps)
    return D
