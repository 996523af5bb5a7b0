r"""Physical checks of a built experiment, beyond its schema: ``feltool check`` reports each
problem on its own line with the config path it concerns.

* :func:`target_problems` — a stabilized quantity that no actuated joint moves: its row of the
  controlled quantities' Jacobian is zero on the actuated joints at the neutral pose and at
  :data:`RANDOM_POSES` seeded random poses (the stabilizing torque acts through that row, so it
  could never act). Building an experiment refuses such a target; ``feltool check`` lists it
  with the other problems.
* :func:`learning_problems` — a learned joint whose feedforward the error signal never sees:
  the learner's gradient :math:`\sum_k e_k^\top \partial u_{ff}/\partial\theta_j` goes through
  the columns :math:`\partial\tau/\partial q_j, \partial\tau/\partial\dot q_j, M_{:,j}` of the
  inverse model (Pinocchio's RNEA derivatives); when their rows on the joints the error signal
  acts on are zero at the neutral and the random poses, FEL cannot move that joint's RMP.
* :func:`gain_problems` — PD gains the closed loop is unstable with, at the start pose: the
  eigenvalues of the loop linearised there (Pinocchio's ABA derivatives, feedforward holding
  gravity) with a positive real part.
* :func:`timestep_problems` — a control rate too coarse for the gains: the sampled loop of
  each controller, with its effective inertia at the start pose, beyond the stability bound
  of the integrator in use (:func:`sampled_pd_stable`).

The gain and timestep checks are for robots whose every configured joint is actuated and
whose base is fixed (no ``walking``/``actuation`` block): a walker's passive base is held by
its contact, and what "stable gains" means for the hybrid, underactuated loop is the
Poincaré analysis after learning (docs/biped.md), not this linearisation.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from feltool.bounds import MAX_RATE_HZ
from feltool.dynamics.pinocchio import mass_matrix

if TYPE_CHECKING:
    from feltool.control.feedback import FeedbackLaw
    from feltool.experiment.experiment import Experiment

#: Random poses (besides the neutral one) at which Jacobians are evaluated.
RANDOM_POSES = 4
_ZERO = 1e-9


def sample_poses(model: pin.Model, n: int = RANDOM_POSES, seed: int = 0) -> list[np.ndarray]:
    """The neutral pose and ``n`` poses drawn uniformly within the joint limits (within
    [-pi, pi] rad or [-1, 1] m where a joint has none), from a generator seeded by ``seed``."""
    rng = np.random.default_rng(seed)
    lo, hi = model.lowerPositionLimit.copy(), model.upperPositionLimit.copy()
    none = ~(np.isfinite(lo) & np.isfinite(hi) & (lo < hi))
    lo[none], hi[none] = -math.pi, math.pi
    poses = [pin.neutral(model)]
    for _ in range(n):
        q = rng.uniform(lo, hi)
        poses.append(pin.normalize(model, q) if model.nq != model.nv else q)
    return poses


def target_problems(model: pin.Model, law: FeedbackLaw, joints: list[str],
                    actuated: np.ndarray) -> list[tuple[str, str]]:
    """Stabilized quantities that no actuated joint moves, as ``(yaml_path, message)``."""
    poses = sample_poses(model)
    rows = np.flatnonzero(law.stabilizing)
    reach = np.zeros(len(rows))
    for q in poses:
        reach = np.maximum(reach, np.abs(law.jacobian(q)[rows][:, actuated > 0]).max(axis=1,
                                                                                   initial=0))
    moving = ", ".join(n for n, a in zip(joints, actuated) if a) or "none"
    return [(f"joints.{joints[i]}.target", f"no actuated joint moves it: its Jacobian on the "
             f"actuated joints ({moving}) is zero at the neutral pose and {len(poses) - 1} "
             "random poses, so the stabilizing torque cannot act on it (feltool inspect lists "
             "the frames and axes the joints turn)")
            for i, r in zip(rows, reach) if r < _ZERO]


def learning_problems(exp: Experiment) -> list[tuple[str, str]]:
    """Learned joints whose feedforward the error signal never sees."""
    model, law = exp.robot.model, exp.law
    learned = [exp.joints.index(n) for n in exp.learned_joints]
    if not learned:
        return []
    mask = np.asarray(exp.learner.error_mask) > 0
    data = model.createData()
    rng = np.random.default_rng(1)
    seen = np.zeros(len(learned))
    for q in sample_poses(model):
        rows = mask.copy()
        J = law.jacobian(q)
        for row in law.frames:  # a frame controller's torque acts through its Jacobian
            if mask[row]:
                rows |= np.abs(J[row]) > _ZERO
        v, a = rng.normal(size=model.nv), rng.normal(size=model.nv)
        pin.computeRNEADerivatives(model, data, q, v, a)
        M = np.triu(data.M) + np.triu(data.M, 1).T
        for k, j in enumerate(learned):
            cols = np.concatenate([data.dtau_dq[rows, j], data.dtau_dv[rows, j], M[rows, j]])
            seen[k] = max(seen[k], float(np.abs(cols).max(initial=0.0)))
    error = exp.config.learning.error
    return [(f"joints.{exp.joints[j]}.learn", f"the error signal (learning.error: {error}; "
             f"joints {', '.join(exp.error_joints)}) never sees this joint's feedforward: the "
             "inverse model's derivatives with respect to its motion are zero on those joints "
             "at the neutral pose and random poses, so FEL cannot learn its RMP; add a joint "
             "it loads to learning.error")
            for j, s in zip(learned, seen) if s < _ZERO]


# -- the closed loop at the start pose -------------------------------------------------------------

def _fixed_and_actuated(exp: Experiment) -> bool:
    """Whether the gain and timestep checks apply (see the module docstring)."""
    return exp.hybrid is None and bool(np.all(exp.loop.actuated > 0))


def start_pose(exp: Experiment) -> np.ndarray:
    """The configuration a seed starts from, with the learned goals at their centres (the
    forward trajectory's first sample with every target held)."""
    theta = exp.theta_demo.copy()
    for sl, _, center, _, _ in exp.init:
        theta[sl.stop - 1] = center
    Qd, Vd, _ = exp.primitives.desired(theta)
    q, _ = exp.law.consistent_state(Qd[0], np.zeros_like(Vd[0]))
    return q


def _torque_map(law: FeedbackLaw, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(J, T)``: the controlled quantities' Jacobian (rows) and the joint torque of one unit
    of each controller's output (columns: the joint itself, or a frame's Jacobian row)."""
    J = law.jacobian(q)
    T = np.eye(len(J))
    for row in law.frames:
        T[:, row] = J[row]
    return J, T


def gain_problems(exp: Experiment) -> list[tuple[str, str]]:
    r"""Gains with which the loop linearised at the start pose is unstable.

    With the feedforward holding the start pose (:math:`u_{ff} = g(q_0)`) and the feedback
    :math:`u_{fb} = -T (K_P J\,\delta q + K_D J\,\delta\dot q)`, the state
    :math:`(\delta q, \delta\dot q)` obeys :math:`\dot x = A x` with
    :math:`A = [[0, I], [\partial\ddot q/\partial q - M^{-1} T K_P J,
    \partial\ddot q/\partial\dot q - M^{-1} T K_D J]]` (Pinocchio's ABA derivatives). An
    eigenvalue with a positive real part is a problem, named after the controller whose
    quantity its mode moves most."""
    if not _fixed_and_actuated(exp):
        return []
    model, law = exp.robot.model, exp.law
    q = start_pose(exp)
    nv = model.nv
    data = model.createData()
    tau = pin.rnea(model, data, q, np.zeros(nv), np.zeros(nv))
    pin.computeABADerivatives(model, data, q, np.zeros(nv), tau)
    Minv = np.triu(data.Minv) + np.triu(data.Minv, 1).T
    J, T = _torque_map(law, q)
    A = np.block([[np.zeros((nv, nv)), np.eye(nv)],
                  [data.ddq_dq - Minv @ T @ (law.kp[:, None] * J),
                   data.ddq_dv - Minv @ T @ (law.kd[:, None] * J)]])
    values, vectors = np.linalg.eig(A)
    scale = 1.0 + float(np.abs(values).max())
    problems: dict[int, float] = {}
    for lam, vec in zip(values, vectors.T):
        if lam.real > 1e-9 * scale:
            row = int(np.argmax(np.abs(vec[:nv])))
            problems[row] = max(problems.get(row, 0.0), float(lam.real))
    return [(f"joints.{exp.joints[row]}.gains", f"kp {law.kp[row]:g}, kd {law.kd[row]:g} leave "
             f"the closed loop unstable for the robot's inertia at the start pose: eigenvalue "
             f"with real part {growth:.3g} 1/s (the motion grows e-fold every "
             f"{1.0 / growth:.3g} s), mostly in this joint; raise kp above the gravity "
             "stiffness it holds, and kd with it")
            for row, growth in sorted(problems.items())]


def integrator_factor(integrator: str, substeps: int) -> float:
    """The factor :math:`c` of :func:`sampled_pd_stable`: the position's share of a control
    step's acceleration, :math:`\\Delta x = \\Delta t\\,v + c\\,\\Delta t^2 a`, for ``substeps``
    steps of size :math:`h = \\Delta t / n` with the acceleration held over the control step:
    semi-implicit Euler :math:`c = (n + 1)/(2n)`, explicit Euler :math:`c = (n - 1)/(2n)`."""
    n = substeps
    return (n + 1) / (2 * n) if integrator == "semi_implicit_euler" else (n - 1) / (2 * n)


def sampled_pd_stable(alpha: float, beta: float, c: float) -> bool:
    r"""Whether the sampled PD loop of a body of inertia :math:`m` is stable.

    The controller's torque :math:`u = -(k_P x + k_D \dot x)` is held over the control step
    :math:`\Delta t`; with :math:`\alpha = k_P \Delta t^2 / m`, :math:`\beta = k_D \Delta t / m`
    and the integrator's :math:`c` (:func:`integrator_factor`) one step maps
    :math:`(x, \Delta t\,\dot x)` by :math:`[[1 - c\alpha, 1 - c\beta], [-\alpha, 1 - \beta]]`,
    whose characteristic polynomial is
    :math:`\lambda^2 - (2 - c\alpha - \beta)\lambda + 1 - \beta + (1 - c)\alpha`. Jury's
    conditions for both roots inside the unit circle give the bound

    .. math::

        (1 - c)\,\alpha \le \beta,\qquad \beta - (1 - c)\,\alpha < 2,\qquad
        2\beta + (2c - 1)\,\alpha < 4

    (for semi-implicit Euler with one sub-step, :math:`c = 1`: :math:`\beta < 2` and
    :math:`\alpha + 2\beta < 4`; explicit Euler, :math:`c = 0`: :math:`\alpha \le \beta`, i.e.
    :math:`k_P \Delta t \le k_D`, and :math:`2\beta - \alpha < 4`). The first condition holds
    with equality for an undamped loop (:math:`|\lambda| = 1`), accepted as the continuous loop
    is undamped too; :math:`k_P > 0`, the remaining condition, does not depend on
    :math:`\Delta t`.
    """
    tol = 1e-12 * (1.0 + alpha + beta)
    return ((1 - c) * alpha <= beta + tol and beta - (1 - c) * alpha < 2.0
            and 2 * beta + (2 * c - 1) * alpha < 4.0)


def timestep_problems(exp: Experiment) -> list[tuple[str, str]]:
    """Controllers whose gains the control rate is too coarse for (:func:`sampled_pd_stable`,
    each with its effective inertia :math:`m = 1 / (J_i M^{-1} T_i)` at the start pose)."""
    if not _fixed_and_actuated(exp):
        return []
    cfg, model, law = exp.config, exp.robot.model, exp.law
    q = start_pose(exp)
    data = model.createData()
    Minv = np.linalg.inv(mass_matrix(model, data, q))
    J, T = _torque_map(law, q)
    c = integrator_factor(cfg.sim.integrator, cfg.sim.substeps)
    dt = cfg.dt
    problems = []
    for row in range(len(J)):
        b = float(J[row] @ Minv @ T[:, row])  # 1 / effective inertia
        kp, kd = law.kp[row], law.kd[row]
        if b <= _ZERO or kp + kd == 0 or sampled_pd_stable(kp * b * dt**2, kd * b * dt, c):
            continue
        fine = [r for r in cfg.sim.rate_hz * 2.0 ** np.arange(1, 21)
                if r <= MAX_RATE_HZ and sampled_pd_stable(kp * b / r**2, kd * b / r, c)]
        remedy = (f"raise sim.rate_hz to {fine[0]:g} or more, or lower the gains" if fine else
                  "no rate helps: explicit Euler needs kd > 0 (use semi_implicit_euler)"
                  if kd == 0 and c < 1 else "lower the gains")
        problems.append((f"joints.{exp.joints[row]}.gains", f"sim.rate_hz {cfg.sim.rate_hz:g} "
                         f"is too coarse for kp {kp:g}, kd {kd:g}: kp dt^2/m = "
                         f"{kp * b * dt**2:.3g} and kd dt/m = {kd * b * dt:.3g} (effective "
                         f"inertia m = {1.0 / b:.3g} at the start pose) are beyond "
                         f"{cfg.sim.integrator}'s stability bound (feltool.experiment.checks."
                         f"sampled_pd_stable); {remedy}"))
    return problems


def experiment_problems(exp: Experiment) -> list[tuple[str, str]]:
    """Every problem of :func:`target_problems`, :func:`learning_problems`,
    :func:`gain_problems` and :func:`timestep_problems`."""
    targets = target_problems(exp.robot.model, exp.law, exp.joints, exp.loop.actuated)
    unreachable = {path.rsplit(".", 1)[0] for path, _ in targets}
    return targets + learning_problems(exp) + [  # a joint whose target is out of reach is
        (path, msg) for path, msg in gain_problems(exp) + timestep_problems(exp)  # reported once
        if path.rsplit(".", 1)[0] not in unreachable]
