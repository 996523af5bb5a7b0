r"""Gait design: a periodic one-step gait of a planar walker by direct collocation.

The walker (:class:`feltool.walking.model.WalkerModel`) stands on its stance foot (a point contact
at the ground :math:`z = 0`) and swings the other leg forward until its foot lands a step length
:math:`L` ahead; the rigid impact and the left/right relabelling bring the state back to the
first knot, shifted by :math:`L` along x. One step is discretised at :math:`N + 1` knots
:math:`t_k = k h`, :math:`h = T/N`, with the knot variables :math:`q_k, v_k, a_k` (minimal
coordinates: a continuous joint by its angle), the motor torques :math:`u_k` and the stance
contact force :math:`\lambda_k = (F_x, F_z)`. The NLP is built in CasADi ``SX`` (exact sparse
first and second derivatives) and solved by IPOPT:

* dynamics at every knot as inverse dynamics, no mass-matrix inverse:
  :math:`\mathrm{RNEA}(q_k, v_k, a_k) = B u_k + J_s(q_k)^T \lambda_k` (the symbolic RNEA of
  :mod:`feltool.dynamics.casadi_backend`, from the same Pinocchio model);
* the stance foot does not accelerate: :math:`J_s a_k + \dot J_s v_k = 0` (its position and
  velocity at the first knot follow from the touchdown and the impact through periodicity);
* collocation with a piecewise-linear acceleration (trapezoidal on v, its exact integral on q):
  :math:`v_{k+1} = v_k + \tfrac h2 (a_k + a_{k+1})`,
  :math:`q_{k+1} = q_k + h v_k + \tfrac{h^2}{6} (2 a_k + a_{k+1})`;
* touchdown at the last knot: the swing foot at :math:`(L, 0)`, moving down;
* the rigid impact at the new stance foot: :math:`M(q_N)(v^+ - v_N) = J_w^T \Lambda`,
  :math:`J_w v^+ = 0`, with :math:`M v = \partial\,\mathrm{RNEA}/\partial a \cdot v` from the
  symbolic RNEA; the impulse in the friction cone and the trailing foot lifting off
  (:math:`\dot z \ge 0` after the impact);
* periodicity: :math:`q_0 = R\,q_N - L e_x`, :math:`v_0 = R\,v^+` (:math:`R` the relabelling,
  :meth:`WalkerModel.relabel_matrices`);
* the stance force: :math:`F_z \ge F_{min}`, :math:`|F_x| \le \mu F_z`; torques within the URDF's
  effort limits, joints within their position limits;
* swing-foot clearance :math:`z_w \ge 0` at the inner knots, except within ``scuff_exempt_m``
  horizontally of the stance foot (the scuffing rule of a walker without knees, see
  ``docs/biped.md``), where the foot may dip by up to 10 % of the walker's hip height;
* the root link (the hip) and the centre of mass moving forward throughout the step,
  :math:`\dot x \ge 0`, :math:`\dot c_x \ge 0` (monotonic phase variables for phase-based
  tracking, ``walking.phase: mechanical``; not for a passive gait);
* the torso (``pitch_joint``) on average at ``pitch_target``, its deviation penalised.

Cost: :math:`\int u^T u \, dt` (trapezoidal), scaled by :math:`(m g \ell)^{-2}`. ``passive`` fixes
:math:`u = 0`; a slope tilts gravity (downhill along +x), the ground stays at :math:`z = 0`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import pinocchio as pin

from feltool.dynamics.symbolic import (
    symbolic_center_of_mass,
    symbolic_frame_kinematics,
    symbolic_rnea,
)
from feltool.errors import FeltoolError, InputError
from feltool.walking.model import WalkerModel
from feltool.walking.standing import standing_pose, to_configuration


class GaitDesignError(FeltoolError):
    """The optimizer found no gait (infeasible or out of iterations); the message names the
    constraint group violated most at the last iterate."""


@dataclass
class GaitSpec:
    """What gait to design.

    Attributes:
        stance: Stance foot of the step (a key of ``WalkerModel.feet``).
        swing: Swing foot (the other one).
        knots: Number of collocation intervals N (N + 1 knots).
        step_length: Step length L in [m]; None: free (or from ``speed``).
        speed: Mean speed L/T in [m/s]; None: free.
        duration: Step duration T in [s]; None: free (bounded by ``duration_bounds``).
        duration_bounds: Bounds of a free T in [s].
        slope: Ground slope in [rad], downhill along +x (gravity tilted).
        passive: No motor torque at all (a passive walker on a slope).
        friction: Coulomb coefficient mu of the feet.
        normal_force_min: Least stance normal force in [N].
        scuff_exempt_m: Horizontal distance from the stance foot in [m] within which the swing
            foot is exempt from clearance; None: 0.05 with one legs pair (no knees), else 0.
        clearance: Whether to constrain the swing foot's height at all (a passive gait check may
            leave it out, as the closed-form compass gait does).
        clearance_margin_m: Least swing-foot height in [m] outside the scuffing zone from the
            third knot to the third last (a margin for tracking errors; 0 at the others).
        normal_force_margin: Added to ``normal_force_min``, in units of m g (a margin for
            tracking errors).
        pitch_joint: Base coordinate (normally ``base_pitch`` of a torso-rooted walker) held on
            average at ``pitch_target`` [rad]; None: no torso.
        pitch_target: Mean of the torso's pitch in [rad] (None: free, only its motion penalised).
        pitch_weight: Weight of the torso's squared deviation from its mean, per [rad^2 s] (the
            torque cost is ~1e-2 for torques of 0.1 m g l): the walker's torso stabilizer holds a
            constant target, so a designed torso motion is what its feedback fights.
        max_iter: IPOPT's iteration limit.
        tol: IPOPT's convergence tolerance.
    """

    stance: str = "left"
    swing: str = "right"
    knots: int = 40
    step_length: float | None = None
    speed: float | None = None
    duration: float | None = None
    duration_bounds: tuple[float, float] = (0.15, 3.0)
    slope: float = 0.0
    passive: bool = False
    friction: float = 0.7
    normal_force_min: float = 0.0
    scuff_exempt_m: float | None = None
    clearance: bool = True
    clearance_margin_m: float = 0.0
    normal_force_margin: float = 0.0
    pitch_joint: str | None = None
    pitch_target: float | None = None
    pitch_weight: float = 100.0
    max_iter: int = 500
    tol: float = 1e-8


@dataclass
class Gait:
    """A designed one-step gait, at the knots ``t`` in [s].

    Arrays are per knot (rows): ``q`` minimal coordinates (nv) in [m] or [rad], ``q_pin`` the
    Pinocchio configuration (nq), ``v`` [m/s, rad/s], ``a`` [m/s^2, rad/s^2], ``tau`` the
    generalized force of the motors (nv; zero on unactuated coordinates) in [N m] or [N],
    ``force`` the stance foot's (F_x, F_z) in [N]. ``v_plus`` is the velocity just after the
    touchdown impact (before relabelling), ``impulse`` the new stance foot's (I_x, I_z) in [N s].
    ``metrics`` has the figures printed by ``feltool gait``; ``stats`` the solver's.
    """

    t: np.ndarray
    q: np.ndarray
    q_pin: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau: np.ndarray
    force: np.ndarray
    v_plus: np.ndarray
    impulse: np.ndarray
    duration: float
    step_length: float
    metrics: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------
# The walker's pieces in minimal coordinates


@dataclass
class _Walker:
    """Symbolic pieces of one walker under one gravity, in minimal coordinates."""

    model: pin.Model
    nv: int
    to_pin: Callable  # SX minimal q -> SX Pinocchio q
    rnea: ca.Function
    feet: dict[str, ca.Function]
    actuated: list[int]
    mass: float
    gravity: float
    height: float
    stand: np.ndarray  # the standing pose (minimal coordinates)
    R: np.ndarray
    ix: int
    iz: int
    lower: np.ndarray
    upper: np.ndarray
    effort: np.ndarray


def _unbounded(model: pin.Model) -> list[tuple[int, int]]:
    """``(idx_q, idx_v)`` of every continuous joint (configuration ``(cos, sin)``)."""
    return [(int(j.idx_q), int(j.idx_v)) for j in model.joints[1:]
            if j.nq == 2 and j.nv == 1]


def minimal_configuration(model: pin.Model, q: np.ndarray) -> np.ndarray:
    """Minimal coordinates (nv) of a Pinocchio configuration (a continuous joint's angle)."""
    out = np.zeros(model.nv)
    for j in model.joints[1:]:
        if j.nq == 2 and j.nv == 1:
            out[j.idx_v] = np.arctan2(q[j.idx_q + 1], q[j.idx_q])
        elif j.nv == 1:
            out[j.idx_v] = q[j.idx_q]
    return out


def _walker_pieces(walker: WalkerModel, spec: GaitSpec) -> _Walker:
    model = pin.Model(walker.model)
    g = float(np.linalg.norm(model.gravity.linear))
    if g <= 0.0:
        raise InputError("gait design needs gravity: the walker's model has none")
    model.gravity.linear = g * np.array([np.sin(spec.slope), 0.0, -np.cos(spec.slope)])
    unb = _unbounded(model)
    nv = model.nv
    simple = [(int(j.idx_q), int(j.idx_v)) for j in model.joints[1:] if j.nq == 1]

    def to_pin(qm):
        parts = [None] * model.nq
        for iq, iv in simple:
            parts[iq] = qm[iv]
        for iq, iv in unb:
            parts[iq], parts[iq + 1] = ca.cos(qm[iv]), ca.sin(qm[iv])
        return ca.vertcat(*parts)

    feet = {}
    for name in (spec.stance, spec.swing):
        if name not in walker.feet:
            raise InputError(f"gait design: no foot '{name}' (the walker's feet: "
                             f"{', '.join(walker.feet)})")
        feet[name] = symbolic_frame_kinematics(model, walker.feet[name])
    _, R_v = walker.relabel_matrices()
    base = {walker.robot.v_index(n) for n in walker.base}
    actuated = [i for i in range(nv) if i not in base and model.effortLimit[i] > 0.0]
    if not actuated and not spec.passive:
        raise InputError("gait design: the walker has no motor (no joint with a positive effort "
                         "limit in its URDF); design a passive gait (--passive) on a slope")
    lower = np.full(nv, -np.inf)
    upper = np.full(nv, np.inf)
    for j in model.joints[1:]:
        if j.nq == 1 and j.idx_v not in base:
            lower[j.idx_v] = model.lowerPositionLimit[j.idx_q]
            upper[j.idx_v] = model.upperPositionLimit[j.idx_q]
    lower[~np.isfinite(lower) | (lower < -1e10)] = -np.inf
    upper[~np.isfinite(upper) | (upper > 1e10)] = np.inf
    stand = standing_pose(walker, spec.pitch_target)  # (whatever the URDF's zero angles)
    return _Walker(model=model, nv=nv, to_pin=to_pin, rnea=symbolic_rnea(model), feet=feet,
                   actuated=actuated, mass=float(sum(i.mass for i in model.inertias)), gravity=g,
                   height=max(stand.height, 1e-3), stand=stand.q, R=R_v,
                   ix=walker.robot.v_index(walker.base[0]),
                   iz=walker.robot.v_index(walker.base[1]), lower=lower, upper=upper,
                   effort=np.array(model.effortLimit, dtype=float))


# --------------------------------------------------------------------------------------------
# The NLP


class _Builder:
    """Collects decision variables and constraint groups (named, for the failure message)."""

    def __init__(self, sym=ca.SX):
        self.sym = sym
        self.w, self.w0, self.lbw, self.ubw = [], [], [], []
        self.g, self.lbg, self.ubg = [], [], []
        self.groups: list[tuple[str, int, int]] = []
        self._ng = 0

    def var(self, name: str, shape: tuple[int, int], guess, lb=-np.inf, ub=np.inf):
        x = self.sym.sym(name, *shape)
        n = shape[0] * shape[1]
        self.w.append(ca.vec(x))
        for store, val in ((self.w0, guess), (self.lbw, lb), (self.ubw, ub)):
            arr = np.broadcast_to(np.asarray(val, dtype=float), shape)
            store.append(np.asarray(arr, dtype=float).reshape(n, order="F"))
        return x

    def add(self, group: str, expr, lb=0.0, ub=0.0) -> None:
        expr = ca.vec(expr)
        n = expr.numel()
        self.g.append(expr)
        self.lbg.append(np.broadcast_to(np.asarray(lb, float), (n,)).copy())
        self.ubg.append(np.broadcast_to(np.asarray(ub, float), (n,)).copy())
        self.groups.append((group, self._ng, self._ng + n))
        self._ng += n

    def vectors(self):
        return (ca.vertcat(*self.w), np.concatenate(self.w0), np.concatenate(self.lbw),
                np.concatenate(self.ubw), ca.vertcat(*self.g), np.concatenate(self.lbg),
                np.concatenate(self.ubg))


GROUPS = {
    "dynamics": "the equations of motion (RNEA = B u + J^T lambda)",
    "stance": "the stance foot staying on the ground",
    "collocation": "the collocation (integration) equations",
    "touchdown": "touchdown of the swing foot at the step length",
    "impact": "the rigid impact map",
    "periodicity": "periodicity through the impact and relabelling",
    "friction": "the stance force's friction cone (F_n >= margin, |F_t| <= mu F_n)",
    "impulse": "the impact impulse's friction cone",
    "liftoff": "the trailing foot lifting off after the impact",
    "clearance": "swing-foot clearance",
    "progress": "the hip and the centre of mass moving forward throughout the step",
    "speed": "the speed (step length / duration)",
    "torso": "the torso's target pitch",
    "bounds": "torque, joint or duration limits",
}


def design_gait(walker: WalkerModel, spec: GaitSpec,
                progress: Callable[[int, float, float], None] | None = None) -> Gait:
    """Design a periodic one-step gait of ``walker`` (see the module's docstring).

    Args:
        walker: The walker (floating base, feet, relabelling).
        spec: The gait's requirements.
        progress: Called after every IPOPT iteration with (iteration, constraint violation,
            objective).

    Returns:
        The gait at its knots, with its figures in ``metrics`` and the solver's in ``stats``
        (``solve_time_s`` is IPOPT's wall time, ``build_time_s`` building the NLP).

    Raises:
        GaitDesignError: IPOPT did not converge; names the constraint group violated most.
        InputError: a spec the walker cannot have (unknown foot, no motor, over-determined).
    """
    from feltool.gait.guess import initial_guess

    t_build = time.perf_counter()
    W = _walker_pieces(walker, spec)
    N, nv, m = spec.knots, W.nv, len(W.actuated)
    if N < 4:
        raise InputError("gait design: knots must be at least 4")
    given = [x is not None for x in (spec.step_length, spec.speed, spec.duration)]
    if all(given):
        raise InputError("gait design: give at most two of step length, speed and duration")
    mg, ell = W.mass * W.gravity, W.height
    u_scale = np.array([W.effort[i] if np.isfinite(W.effort[i]) else mg * ell
                        for i in W.actuated])
    guess = initial_guess(walker, W, spec)
    b = _Builder()
    Q = b.var("q", (nv, N + 1), guess.q.T, W.lower[:, None], W.upper[:, None])
    V = b.var("v", (nv, N + 1), guess.v.T)
    A = b.var("a", (nv, N + 1), 0.0)
    F = b.var("lam", (2, N + 1), np.array([[0.0], [np.cos(spec.slope)]]))  # in [m g]
    U = b.var("u", (m, N + 1), 0.0, -1.0, 1.0) if (m and not spec.passive) else None
    Vp = b.var("v_plus", (nv, 1), guess.v_plus[:, None])
    I = b.var("impulse", (2, 1), np.array([[0.0], [0.1]]))  # in [m sqrt(g l)]
    if spec.duration is not None:
        T = spec.duration
    else:
        T = b.var("T", (1, 1), guess.duration, *spec.duration_bounds)
    if spec.step_length is not None:
        L = spec.step_length
    elif spec.speed is not None and spec.duration is not None:
        L = spec.speed * spec.duration
    else:
        L = b.var("L", (1, 1), guess.step_length, 0.01 * ell, 2.0 * ell)
    if spec.speed is not None and not isinstance(L, float):
        b.add("speed", L - spec.speed * T)
    h = T / N
    imp_scale = W.mass * np.sqrt(W.gravity * ell)
    st, sw = W.feet[spec.stance], W.feet[spec.swing]
    tau_scale = 1.0 / (mg * ell)
    B = np.zeros((nv, m))
    for c, i in enumerate(W.actuated):
        B[i, c] = u_scale[c]
    cost = 0
    exempt = spec.scuff_exempt_m
    if exempt is None:
        exempt = 0.05 if len(walker.legs) <= 1 else 0.0
    dip = 0.1 * ell
    knot, interval = _knot_functions(W, spec, B, mg, ell, tau_scale, exempt, dip)
    U_all = U if U is not None else ca.DM.zeros(m, N + 1)
    dyn, stance, fric, clear, clear_m, effort, com_rate = knot.map(N + 1)(Q, V, A, F, U_all)
    b.add("dynamics", dyn)
    b.add("stance", stance)
    b.add("friction", fric, 0.0, np.inf)
    if spec.clearance:  # the margin from the third knot to the third last
        b.add("clearance", ca.horzcat(clear[:, 1], clear_m[:, 2:N - 1], clear[:, N - 1]), 0.0,
              np.inf)
    if U is not None:
        weights = np.ones(N + 1)
        weights[[0, N]] = 0.5
        cost = cost + h * ca.dot(ca.vec(effort), weights)
    if not spec.passive:  # the hip and the centre of mass never move backwards (a passive gait
        b.add("progress", ca.vertcat(V[W.ix, :], com_rate), 0.0, np.inf)  # is left to physics)
    b.add("collocation", interval.map(N)(Q[:, :N], V[:, :N], A[:, :N], Q[:, 1:], V[:, 1:],
                                         A[:, 1:], h))
    # Touchdown, impact, relabelling, periodicity.
    qN = W.to_pin(Q[:, N])
    zeros = ca.DM.zeros(nv)
    p_w, J_w, dp_w, _ = sw(qN, V[:, N], zeros)
    _, J_s, _, _ = st(qN, V[:, N], zeros)
    b.add("touchdown", ca.vertcat(p_w[0] - L, p_w[2]) / ell)
    b.add("touchdown", dp_w[2], -np.inf, 0.0)
    # M (v+ - v-) as the directional derivative of the RNEA in a.
    mass_times = _mass_times(W)(qN, Vp - V[:, N])
    b.add("impact", (mass_times - ca.mtimes(J_w[[0, 2], :].T, I * imp_scale)) / imp_scale)
    b.add("impact", ca.mtimes(J_w[[0, 2], :], Vp))
    b.add("impulse", ca.vertcat(I[1], spec.friction * I[1] - I[0], spec.friction * I[1] + I[0]),
          0.0, np.inf)
    b.add("liftoff", ca.mtimes(J_s[2, :], Vp), 0.0, np.inf)
    shift = np.zeros(nv)
    shift[W.ix] = 1.0
    b.add("periodicity", Q[:, 0] - (ca.mtimes(W.R, Q[:, N]) - L * shift))
    b.add("periodicity", V[:, 0] - ca.mtimes(W.R, Vp))
    if spec.pitch_joint is not None:
        ip = walker.robot.v_index(spec.pitch_joint)
        mean = ca.sum2(Q[ip, :]) / (N + 1)
        if spec.pitch_target is not None:
            b.add("torso", mean - spec.pitch_target)
        cost = cost + spec.pitch_weight * h * ca.sumsqr(Q[ip, :] - mean)
    w, w0, lbw, ubw, g, lbg, ubg = b.vectors()
    nlp = {"x": w, "f": cost if not isinstance(cost, int) else b.sym(0), "g": g}
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
            "ipopt.max_iter": spec.max_iter, "ipopt.tol": spec.tol,
            "ipopt.constr_viol_tol": spec.tol, "ipopt.mu_strategy": "adaptive",
            # MUMPS without its own row/column scaling: on these KKT systems (point masses, a
            # singular Hessian block) its scaling makes IPOPT take 2-5x the iterations, each
            # with iterative refinement (measured: 20 instead of 92 iterations, 10x faster).
            "ipopt.linear_solver": "mumps", "ipopt.mumps_scaling": 0,
            "ipopt.mumps_permuting_scaling": 0}
    callback = None
    if progress is not None:
        callback = _Progress(w.numel(), g.numel(), lbg, ubg, progress)
        opts["iteration_callback"] = callback
    t_nlp = time.perf_counter()
    solver = ca.nlpsol("gait", "ipopt", nlp, opts)
    nlpsol_time = time.perf_counter() - t_nlp
    build_time = time.perf_counter() - t_build
    t_solve = time.perf_counter()
    sol = solver(x0=w0, lbx=lbw, ubx=ubw, lbg=lbg, ubg=ubg)
    stats = solver.stats()
    solve_time = time.perf_counter() - t_solve - float(stats.get("t_wall_callback_fun", 0.0))
    x = np.array(sol["x"]).ravel()
    gv = np.array(sol["g"]).ravel()
    viol = np.maximum(np.maximum(lbg - gv, gv - ubg), 0.0)
    bound_viol = float(np.max(np.maximum(np.maximum(lbw - x, x - ubw), 0.0), initial=0.0))
    by_group: dict[str, float] = {}
    for name, lo, hi in b.groups:
        by_group[name] = max(by_group.get(name, 0.0), float(np.max(viol[lo:hi], initial=0.0)))
    by_group["bounds"] = bound_viol
    max_viol = max(by_group.values())
    info = {"success": bool(stats["success"]), "status": stats["return_status"],
            "iterations": int(stats["iter_count"]), "solve_time_s": solve_time,
            "build_time_s": build_time, "nlpsol_time_s": nlpsol_time, "knots": N + 1,
            "variables": int(w.numel()),
            "constraints": int(g.numel()), "constraint_violation": max_viol,
            "violation_by_group": by_group}
    if not stats["success"] or max_viol > 1e-6:
        worst = max(by_group, key=by_group.get)
        raise GaitDesignError(
            f"gait design failed ({stats['return_status']} after {info['iterations']} "
            f"iterations): the constraint group violated most is '{worst}' - {GROUPS[worst]} - "
            f"by {by_group[worst]:.3g} (scaled); ask for a gait it can reach (another speed or "
            "step length, a lower force margin, more friction) or raise the torque limits")
    unpack = ca.Function("unpack", [w], [Q, V, A, F, Vp, I,
                                         U if U is not None else b.sym(0, N + 1),
                                         T if not isinstance(T, float) else b.sym(T),
                                         L if not isinstance(L, float) else b.sym(L)])
    Qn, Vn, An, Fn, Vpn, In, Un, Tn, Ln = (np.array(y) for y in unpack(x))
    tau = (B @ Un).T if Un.size else np.zeros((N + 1, nv))
    gait = Gait(t=np.linspace(0.0, Tn.item(), N + 1), q=Qn.T,
                q_pin=np.array([to_configuration(W.model, qq) for qq in Qn.T]), v=Vn.T, a=An.T,
                tau=tau, force=Fn.T * mg, v_plus=Vpn.ravel(), impulse=In.ravel() * imp_scale,
                duration=Tn.item(), step_length=Ln.item(), stats=info)
    gait.metrics = gait_metrics(walker, W.model, gait, spec, exempt)
    return gait


def _knot_functions(W: _Walker, spec: GaitSpec, B: np.ndarray, mg: float, ell: float,
                    tau_scale: float, exempt: float, dip: float) -> tuple[ca.Function, ...]:
    """SX functions of one knot and of one interval, mapped over the knots by the NLP (their
    exact derivatives are built once, not once per knot).

    ``knot(q, v, a, lam, u) -> (dynamics, stance, friction, clearance, clearance with the
    margin, effort, the centre of mass's horizontal velocity)``; the margin applies fully
    outside the scuffing zone, fading to 0 at the stance foot;
    ``interval(q0, v0, a0, q1, v1, a1, h) -> collocation residuals``.
    """
    nv, m = W.nv, B.shape[1]
    q, v, a = ca.SX.sym("q", nv), ca.SX.sym("v", nv), ca.SX.sym("a", nv)
    lam, u = ca.SX.sym("lam", 2), ca.SX.sym("u", m)
    qp = W.to_pin(q)
    p_st, Js, _, dds = W.feet[spec.stance](qp, v, a)
    p_sw = W.feet[spec.swing](qp, v, a)[0]
    gen = ca.mtimes(Js[[0, 2], :].T, lam * mg) + ca.mtimes(B, u)
    dynamics = (W.rnea(qp, v, a) - gen) * tau_scale
    fmin = spec.normal_force_min / mg + spec.normal_force_margin
    friction = ca.vertcat(lam[1] - fmin, spec.friction * lam[1] - lam[0],
                          spec.friction * lam[1] + lam[0])
    allowance, outside = 0.0, 1.0
    if exempt > 0:
        dx = (p_sw[0] - p_st[0]) / exempt
        allowance = dip * ca.fmax(0.0, 1.0 - dx * dx)
        outside = ca.fmin(1.0, dx * dx)
    clearance = p_sw[2] + allowance
    effort = ca.sumsqr(ca.mtimes(B, u) * tau_scale)
    com_rate = symbolic_center_of_mass(W.model)(qp, v)[1][0]
    knot = ca.Function("knot", [q, v, a, lam, u],
                       [dynamics, dds[[0, 2]] / W.gravity, friction, clearance,
                        clearance - spec.clearance_margin_m * outside, effort, com_rate])
    q1, v1, a1, h = ca.SX.sym("q1", nv), ca.SX.sym("v1", nv), ca.SX.sym("a1", nv), ca.SX.sym("h")
    interval = ca.Function("interval", [q, v, a, q1, v1, a1, h], [ca.vertcat(
        v1 - v - h / 2 * (a + a1), q1 - q - h * v - h * h / 6 * (2 * a + a1))])
    return knot, interval


def _mass_times(W: _Walker) -> ca.Function:
    """``(q_pin, dv) -> M(q) dv``: the directional derivative of the RNEA in a (SX)."""
    q, dv, a = ca.SX.sym("q", W.model.nq), ca.SX.sym("dv", W.nv), ca.SX.sym("a", W.nv)
    return ca.Function("mass_times", [q, dv],
                       [ca.jtimes(W.rnea(q, ca.DM.zeros(W.nv), a), a, dv)])


class _Progress(ca.Callback):
    """IPOPT iteration callback: reports (iteration, constraint violation, objective)."""

    def __init__(self, nx: int, ng: int, lbg: np.ndarray, ubg: np.ndarray, report):
        ca.Callback.__init__(self)
        self.nx, self.ng, self.lbg, self.ubg, self.report = nx, ng, lbg, ubg, report
        self.iteration = 0
        self.construct("gait_progress", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.nx)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.ng)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        g = np.array(arg[ca.nlpsol_out().index("g")]).ravel()
        viol = float(np.max(np.maximum(np.maximum(self.lbg - g, g - self.ubg), 0.0), initial=0.0))
        self.report(self.iteration, viol, float(arg[ca.nlpsol_out().index("f")]))
        self.iteration += 1
        return [0]


# --------------------------------------------------------------------------------------------
# Figures of a gait


def gait_metrics(walker: WalkerModel, model: pin.Model, gait: Gait, spec: GaitSpec,
                 exempt: float) -> dict:
    """The gait's figures: period [s], speed [m/s], step length [m], cost of transport
    (positive motor work per weight and distance, 1), min F_n / (m g), max |F_t|/F_n, impact
    impulse ratio |I_x/I_z|, max |torque| [N m], the swing foot's least height outside the
    scuffing band [m], the stance foot's drift from the origin [m] and the constraint violation.
    """
    data = model.createData()
    mg = float(sum(i.mass for i in model.inertias)) * float(np.linalg.norm(model.gravity.linear))
    clear, drift = np.inf, 0.0
    for k, qp in enumerate(gait.q_pin):
        pin.framesForwardKinematics(model, data, qp)
        ps = data.oMf[walker.feet[spec.stance]].translation
        pw = data.oMf[walker.feet[spec.swing]].translation
        drift = max(drift, float(np.hypot(ps[0], ps[2])))
        if 0 < k < len(gait.t) - 1 and abs(pw[0] - ps[0]) >= exempt:
            clear = min(clear, float(pw[2]))
    power = np.sum(np.maximum(gait.tau * gait.v, 0.0), axis=1)
    dt = np.diff(gait.t)
    work = float(np.sum(dt * 0.5 * (power[1:] + power[:-1])))
    fn, ft = gait.force[:, 1], gait.force[:, 0]
    return {
        "period_s": gait.duration, "step_length_m": gait.step_length,
        "speed_m_per_s": gait.step_length / gait.duration,
        "cost_of_transport": work / (mg * gait.step_length),
        "min_normal_force_mg": float(fn.min() / mg),
        "max_friction_ratio": float(np.max(np.abs(ft) / np.maximum(fn, 1e-12))),
        "impulse_ratio": float(abs(gait.impulse[0]) / max(gait.impulse[1], 1e-12)),
        "max_torque": float(np.abs(gait.tau).max(initial=0.0)),
        "min_clearance_m": clear if np.isfinite(clear) else None,
        "stance_drift_m": drift,
        "constraint_violation": gait.stats["constraint_violation"],
    }
