r"""ILC, the baseline and disturbances on a physical walker: a torque per RMP sample, per motor.

On a physical walker (:mod:`feltool.walking.physical`) a cycle is two steps that end at touchdowns, so
its number of control steps changes from cycle to cycle, and with ``walking.phase:
mechanical`` the RMP sample a control step uses follows the centre of mass
(``WalkLog.phase_index``). ILC's learned feedforward is therefore a sequence
:math:`\Delta U \in \mathbb R^{n \times m}` over the cycle's *RMP samples* (n of them, the
demonstrations' grid) in *motor torques* (m motors), added to the allocated command of every
control step k that uses sample :math:`i_k`:

.. math::

    u_k = A(q_k)\,(\tau_{ff,k} + u_{fb,k}) + \Delta U_{i_k}.

The error of sample i is the mean, over the control steps that used it, of the motor error
:math:`e_k = A(q_k)\,\epsilon_k` (:math:`\epsilon_k` the learning signal of
:func:`feltool.engines.python.error_torques`: the error feedback, plus :math:`M(\ddot q_r - \ddot q)` with
``learning.error_estimate: inverse_dynamics`` -- the signal FEL's motor update uses); a sample
no control step used has no error. Cycles of different lengths so update the same sequence.

``ilc_norm_optimal`` needs the lifted model :math:`G = \partial E / \partial \Delta U` of the
walker's cycle. :func:`lifted_model` linearizes the *known* model's closed loop about the
walker's own periodic orbit (the demonstrations with their unperturbed parameters: what the
learned feedforward should bring the walker back to) by central differences of each control
step (:class:`OrbitStep`) in the coordinates the contact leaves free (pitch and joints,
positions and velocities, and the mechanical phase's acceleration carried to the next step;
the base follows from the stance foot), through the contact dynamics, the mechanical phase, the
allocation, the saturation and, where a touchdown falls inside the control step, the located
touchdown and the impact. Assumptions: the cycle's step-to-sample map, the touchdowns' control
steps and the saturated motors (none) are those of the orbit; the cycle starts on the orbit
(the coupling through the next cycle's start is left out, as on the arm); where the orbit sits
on a kink of the step map (the mechanical phase interpolates the reference linearly between
samples, and the orbit's control steps fall on the samples) G has the mean of the one-sided
slopes. G and the factor of :math:`G^\top G + (w_u/w_e) I` are computed once per known model
and reused every cycle and every seed (the last one kept: ``(n m)^2`` numbers each).
"""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from feltool.dynamics.pinocchio import mass_matrix
from feltool.engines.disturbed import disturbed_plant, walker_disturbance
from feltool.engines.ilc import OWN_RUNNER, with_state
from feltool.engines.python import error_torques, hybrid_cycle, impact_masked
from feltool.learning.ilc import ILC_UPDATES, NormOptimalILC, PTypeILC
from feltool.plant.disturbances import cycle_rng
from feltool.walking.checks import StepStats

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment
    from feltool.walking.physical import WalkLog

_LIFTED: dict[str, np.ndarray] = {}  # the last lifted model, by known-model fingerprint
_FACTORS: dict[tuple, tuple] = {}  # its Cholesky factor, by (fingerprint, w_e, w_u)


def motor_error(exp: Experiment, log: WalkLog) -> np.ndarray:
    """The cycle's error in motor torques, :math:`e_k = A(q_k)\\,\\epsilon_k`, ``(n_k, m)``
    in [N m] (one row per control step)."""
    return np.einsum("kmr,kr->km", log.allocation, error_torques(exp, log))


def phase_error(exp: Experiment, log: WalkLog) -> np.ndarray:
    """The motor error per RMP sample ``(n, m)`` in [N m]: the mean over the control steps that
    used the sample (zero for a sample none used)."""
    n = exp.primitives.n_steps
    E = motor_error(exp, log)
    out = np.zeros((n, E.shape[1]))
    np.add.at(out, log.phase_index, E)
    counts = np.bincount(log.phase_index, minlength=n)
    return out / np.maximum(counts, 1)[:, None]


class OrbitStep:
    """One control step of the known model's closed loop, as :class:`~feltool.walking.physical.
    PhysicalLoop` runs it, in the coordinates the stance contact leaves free:
    the map :func:`lifted_model` linearizes.

    The state ``x`` is the pitch's and the joints' positions and velocities and, with
    ``walking.phase: mechanical``, the phase's acceleration carried from one control step to
    the next (zero after a touchdown); the base follows from the stance foot at the origin.

    Args:
        exp: The experiment (its ``hybrid`` loop, undisturbed).
        P, Pv, Pa: The cycle's forward trajectories ``(n, nv)``.
        q0: A state whose base coordinates start the stance-foot completion.
    """

    def __init__(self, exp: Experiment, P: np.ndarray, Pv: np.ndarray, Pa: np.ndarray,
                 q0: np.ndarray):
        self.exp, self.loop = exp, exp.hybrid
        self.walker = self.loop.walker
        self.P, self.Pv, self.Pa = P, Pv, Pa
        self.R = self.loop._referenced(P, Pv, Pa)
        nv = self.walker.walker.model.nv
        self.free = np.setdiff1d(np.arange(nv), self.walker.base_v[:2])  # pitch and joints
        self.q0 = q0.copy()

    def chart(self, q: np.ndarray, v: np.ndarray, phase_acc: float) -> np.ndarray:
        """``x`` from a full state and the phase's acceleration [1/s^2]."""
        return np.concatenate([q[self.free], v[self.free], [phase_acc]])

    def state(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """The full state ``(q, v)`` and the phase's acceleration of ``x``."""
        nf = len(self.free)
        q, v = self.q0.copy(), np.zeros_like(self.q0)
        q[self.free], v[self.free] = x[:nf], x[nf:2 * nf]
        q, v, _ = self.walker.complete(q, v, np.zeros_like(v))
        return q, v, float(x[-1])

    def __call__(self, x: np.ndarray, du: np.ndarray, steps_before: int, label: int,
                 sample: int) -> tuple[np.ndarray, np.ndarray, bool]:
        r"""From ``x`` with ``du`` ``(m,)`` [N m] added to the motor command, in the cycle's
        step ``steps_before`` (touchdowns so far) with stance ``label``; ``sample``: the RMP
        sample of a phase that is not mechanical. Returns ``x`` after the control step, the
        motor error :math:`A\epsilon` of the step ``(m,)`` (before any impact window) and
        whether a touchdown happened in it."""
        L, W, exp = self.loop, self.walker, self.exp
        q, v, phase_acc = self.state(x)
        mechanical = W.phase == "mechanical"
        if mechanical:
            _, p, pv, pa, rp, rpv, rpa = L._mechanical(q, v, self.P, self.Pv, self.Pa,
                                                       steps_before, label, self.R, phase_acc)
        else:
            Rq, Rv, Ra = self.R
            p, pv, pa = self.P[sample], self.Pv[sample], self.Pa[sample]
            rp, rpv, rpa = Rq[sample], Rv[sample], Ra[sample]
        (_, _, _, ar), _, (_, _, u_err), A, u = L.command(q, v, (p, pv, pa), (rp, rpv, rpa),
                                                          label)
        u = u + du
        if W.checks.torques == "saturate":
            u = np.clip(u, -W.checks.effort, W.checks.effort)
        tau = W.B @ u
        c = W.contact
        now = c.stance(q, v, tau, W.stance)  # (also the first sub-step's start)
        a = now.a
        err = u_err
        if exp.config.learning.error_estimate == "inverse_dynamics":
            M = mass_matrix(c.model, c.data, q)
            err = err + M @ (ar - a)
        phase_acc = L._phase_acceleration(W.com_x(q, v, a)[2]) if mechanical else 0.0
        touched = False
        h = L.dt / L.substeps
        stats, force = [StepStats()], np.zeros((1, 2))
        for i_sub in range(L.substeps):
            q, v, s = L._substep(c, q, v, tau, h, stats, force, 0, W.phase == "clock",
                                 now if i_sub == 0 else None)
            if s is not None:
                touched, phase_acc = True, 0.0
                if W.phase != "clock":
                    break
        return self.chart(q, v, phase_acc), A @ err, touched


def orbit_cycle(exp: Experiment) -> tuple[WalkLog, OrbitStep]:
    """The known model's cycle on the walker's periodic orbit (the unperturbed parameters from
    the loop's initial state) and the step map along it."""
    P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
    q, v = exp.hybrid.initial_state(P, Pv)
    log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
    if log.fall is not None:
        from feltool.errors import FeltoolError

        raise FeltoolError(f"ilc_norm_optimal: the walker's unperturbed cycle does not walk "
                           f"({log.fall}); there is no orbit to linearize about")
    return log, OrbitStep(exp, P, Pv, Pa, q)


def orbit_steps(log: WalkLog):
    """``(k, (steps_before, label, sample))`` for each control step of a cycle."""
    impacts = [k for k, _, _ in log.impacts]
    for k in range(len(log.q)):
        yield k, (sum(1 for i in impacts if i <= k), int(log.stance[k]),
                  int(log.phase_index[k]))


def lifted_model(exp: Experiment, eps: float = 1e-6) -> np.ndarray:
    r"""The lifted model :math:`G = \partial E / \partial \Delta U` ``(n m, n m)``,
    sample-major, of the known model's walker about its orbit (module docstring), cached by the
    known model's settings.

    Per control step k the central differences of :class:`OrbitStep` give
    :math:`x_{k+1} \approx A_k x_k + B_k \delta u_k` and :math:`e_k \approx C_k x_k + D_k
    \delta u_k` in the free coordinates; :math:`G_{kj} = C_k A_{k-1}\cdots A_{j+1} B_j` (j < k),
    :math:`G_{kk} = D_k`, then rows and columns are gathered by the RMP sample of each control
    step (columns summed: one sample's torque acts at every step that uses it; rows averaged,
    as :func:`phase_error`). Where one side of a difference changes whether the control step
    touches down, the other side's one-sided difference is used."""
    key = _fingerprint(exp)
    if key in _LIFTED:
        return _LIFTED[key]
    log, step = orbit_cycle(exp)
    n, n_k = exp.primitives.n_steps, len(log.q)
    m = step.walker.B.shape[1]
    mask = _error_rows_kept(exp, log)
    G = np.zeros((n_k, m, n_k, m))
    x = step.chart(log.q[0], log.v[0], 0.0)
    Z = np.zeros((len(x), n_k * m))  # d x_k / d u_j, propagated forward
    for k, args in orbit_steps(log):
        y0, e0, touched = step(x, np.zeros(m), *args)
        Ax, Cx = np.zeros((len(x), len(x))), np.zeros((m, len(x)))
        for i in range(len(x)):
            dx = np.zeros(len(x))
            dx[i] = eps
            Ax[:, i], Cx[:, i] = _difference(step, x, dx, np.zeros(m), args, touched, y0, e0)
        B, D = np.zeros((len(x), m)), np.zeros((m, m))
        for i in range(m):
            du = np.zeros(m)
            du[i] = eps  # [N m]
            B[:, i], D[:, i] = _difference(step, x, 0 * x, du, args, touched, y0, e0)
        if mask[k]:
            G[k, :, :k, :] = (Cx @ Z[:, :k * m]).reshape(m, k, m)
            G[k, :, k, :] = D
        Z[:, :k * m] = Ax @ Z[:, :k * m]
        Z[:, k * m:(k + 1) * m] = B
        x = y0
    G = _by_sample(G, log.phase_index, n)
    _LIFTED.clear()
    _LIFTED[key] = G
    return G


def _difference(step: OrbitStep, x, dx, du, args, touched, y0, e0):
    """Central difference of the step map (state and error) along ``(dx, du)``; one-sided
    where one side's touchdown differs from the orbit's (zero if both do)."""
    scale = float(np.abs(dx).max() + np.abs(du).max())
    sides = []
    for sign in (1.0, -1.0):
        y, e, hit = step(x + sign * dx, sign * du, *args)
        if hit == touched:
            sides.append((sign, y, e))
    if len(sides) == 2:
        (_, ya, ea), (_, yb, eb) = sides
        return (ya - yb) / (2 * scale), (ea - eb) / (2 * scale)
    if sides:
        sign, y, e = sides[0]
        return sign * (y - y0) / scale, sign * (e - e0) / scale
    return np.zeros_like(y0), np.zeros_like(e0)


def _by_sample(G: np.ndarray, index: np.ndarray, n: int) -> np.ndarray:
    """``(n_k, m, n_k, m)`` per control step -> ``(n m, n m)`` per RMP sample: columns summed
    over the steps that use a sample, rows averaged over them."""
    n_k, m = G.shape[:2]
    cols = np.zeros((n_k, m, n, m))
    np.add.at(cols, (slice(None), slice(None), index), G)
    rows = np.zeros((n, m, n, m))
    np.add.at(rows, index, cols)
    rows /= np.maximum(np.bincount(index, minlength=n), 1)[:, None, None, None]
    return rows.reshape(n * m, n * m)


def _error_rows_kept(exp: Experiment, log: WalkLog) -> np.ndarray:
    """``(n_k,)`` False for the control steps ``learning.impact_window_s`` leaves out."""
    return impact_masked(exp, log, np.ones((len(log.q), 1)))[:, 0] > 0


def _fingerprint(exp: Experiment) -> str:
    """What the lifted model depends on: the config without the plant's disturbances, the
    learner's settings, the seeds and the run length."""
    cfg = exp.config.model_dump(mode="json")
    for key in ("name", "description", "disturbances", "ilc", "seeds", "events"):
        cfg.pop(key, None)
    cfg["sim"].pop("cycles", None)
    for key in ("update", "rates", "damping", "model"):
        cfg["learning"].pop(key, None)
    return json.dumps([str(exp.source), cfg], sort_keys=True, default=str)


def norm_optimal_factor(exp: Experiment, ilc: NormOptimalILC) -> tuple[np.ndarray, tuple]:
    """The lifted model and its Cholesky factor for ``ilc``'s weights (both cached)."""
    G = lifted_model(exp)
    key = (_fingerprint(exp), ilc.weight_error, ilc.weight_change)
    if key not in _FACTORS:
        _FACTORS.clear()  # one factor at a time: (n m)^2 numbers each
        _FACTORS[key] = ilc.factor(G)
    return G, _FACTORS[key]


def on_ground(exp: Experiment, plant, q: np.ndarray, v: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """The state ``(q, v)`` with the base moved so that the stance foot of ``plant`` (a
    scaled walker) is at the origin at rest, angles and joint rates unchanged."""
    walker = copy.copy(exp.hybrid.walker)
    walker.contact = exp.hybrid.walker.contact_for(plant.model)
    q, v, _ = walker.complete(q, v, np.zeros_like(v))
    return q, v


def cycle_runner(exp: Experiment, theta0: np.ndarray, seed: int) -> Callable:
    """The cycle function ``(theta, q, v, plant, theta_m=None) -> CycleOutcome`` of a physical
    walker for the ILC learners, the baseline, and any learner under ``disturbances:``
    (FEL's own update then runs as without them, on the disturbed loop's measurements).

    The disturbances are drawn from :func:`~feltool.plant.disturbances.cycle_rng`; the learned sequence,
    the cycle count and the disturbances' state are exposed to checkpoints and params as in
    :func:`feltool.engines.ilc.with_state`.
    """

    cfg = exp.config
    update = cfg.learning.update
    loop = copy.copy(exp.hybrid)  # this seed's: its hooks are set here
    loop.disturbance = walker_disturbance(exp)
    me = cfg.disturbances.model_error if cfg.disturbances is not None else None
    scaled = me is not None and (me.mass_scale != 1.0 or me.length_scale != 1.0)
    plant_scaled = disturbed_plant(exp) if scaled else None
    m = loop.walker.B.shape[1]
    state = {"dU": np.zeros((exp.primitives.n_steps, m)), "cycle": 0}
    ilc = cfg.ilc
    p_type = PTypeILC(ilc.gain, round(ilc.lead_s * cfg.sim.rate_hz), ilc.cutoff_hz, ilc.order,
                      cfg.sim.rate_hz)
    norm_opt = NormOptimalILC(ilc.weight_error, ilc.weight_change)

    def run(theta, q, v, plant, theta_m=None):
        state["cycle"] += 1
        if loop.disturbance is not None:
            loop.disturbance.start_cycle(cycle_rng(seed, state["cycle"]))
        if plant_scaled is not None:
            plant = plant_scaled
            if state["cycle"] == 1:  # the designed start, stood on the scaled walker's foot
                q, v = on_ground(exp, plant, q, v)
        if update not in OWN_RUNNER:
            return hybrid_cycle(exp, theta, q, v, plant, loop)
        loop.motor_feedforward = state["dU"] if update in ILC_UPDATES else None
        out = hybrid_cycle(exp, theta, q, v, plant, loop, learn=False)
        log, _ = out.trace()
        if log.fall is None and update == "ilc_p":
            state["dU"] = p_type.update(state["dU"], phase_error(exp, log))
        elif log.fall is None and update == "ilc_norm_optimal":
            G, factor = norm_optimal_factor(exp, norm_opt)
            state["dU"] = norm_opt.update(state["dU"], phase_error(exp, log), G, factor)
        return out

    names = loop.walker.motor_names if update in ILC_UPDATES else []
    run.loop = loop
    return with_state(run, state, loop.disturbance, names)


__all__ = ["OrbitStep", "cycle_runner", "lifted_model", "motor_error", "norm_optimal_factor",
           "on_ground", "orbit_cycle", "orbit_steps", "phase_error"]
