r"""Disturbances of the plant only: measurement noise, torque noise, input delay, model error.

The config's ``disturbances:`` block turns the closed loop into

.. math::

    \tilde x_k = x_k + n_k,\quad n_k \sim \mathcal N(0, \operatorname{diag}(\sigma_q^2,
    \sigma_{\dot q}^2)),\qquad
    u_{fb}^k = u_{fb}(\tilde x_k),\qquad
    \tau_k^{cmd} = S(u_{ff}^k + u_{fb}^k),\qquad
    \tau_k = \tau_{k-d}^{cmd} + S w_k,\ w_k \sim \mathcal N(0, \sigma_\tau^2 I),

with the plant :math:`x_{k+1} = F_{plant}(x_k, \tau_k)` whose bodies may be scaled against the
known model (masses and inertias by :math:`s_m`, lengths by :math:`s_l`, rotational inertias by
:math:`s_m s_l^2`). The feedback, the learner and the metrics see only the measurements
:math:`\tilde x_k` (``CycleLog.q``, ``.v``) and the feedback computed from them; the true
states are logged apart (``CycleLog.q_true``) for tests. The known model
(``Experiment.dynamics``) is never changed and is never given the noise.

Every draw comes from the loop's ``rng``, a numpy Generator that the cycle runner seeds from
(seed, cycle) before each cycle (:func:`feltool.engines.ilc.cycle_runner`), so a resumed run draws the
same noise. A physical walker gets the same disturbances through :class:`WalkerDisturbance`, a
hook of its loop (:func:`feltool.engines.ilc_walker.cycle_runner`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from feltool.config.disturbances import DisturbanceConfig
from feltool.control.closed_loop import ClosedLoop, CycleLog
from feltool.dynamics.interface import Dynamics
from feltool.dynamics.pinocchio import mass_matrix

if TYPE_CHECKING:
    from feltool.config.experiment import ExperimentConfig


def scaled_model(model: pin.Model, mass_scale: float, length_scale: float) -> pin.Model:
    """A copy of ``model`` with every body's mass and inertia times ``mass_scale`` and every
    length times ``length_scale`` (joint placements, frame placements such as a walker's feet,
    centres of mass; rotational inertia times ``mass_scale * length_scale**2``)."""
    out = model.copy()
    for j in range(1, out.njoints):
        placement = out.jointPlacements[j]
        out.jointPlacements[j] = pin.SE3(placement.rotation,
                                         placement.translation * length_scale)
        inertia = out.inertias[j]
        out.inertias[j] = pin.Inertia(float(inertia.mass) * mass_scale,
                                      inertia.lever * length_scale,
                                      inertia.inertia * mass_scale * length_scale ** 2)
    for frame in out.frames:
        frame.placement = pin.SE3(frame.placement.rotation,
                                  frame.placement.translation * length_scale)
    return out


class DisturbedLoop(ClosedLoop):
    """The closed loop of :class:`~feltool.control.closed_loop.ClosedLoop` with the disturbances of the
    module docstring; :meth:`run_cycle` has the same interface.

    Args:
        spec: The ``disturbances:`` block.
        (others): As for :class:`~feltool.control.closed_loop.ClosedLoop`; ``dynamics`` is the plant.

    Attributes:
        rng: The Generator of the next cycle's draws (set by the cycle runner).
    """

    def __init__(self, dynamics: Dynamics, law, actuated, dt, substeps, integrator,
                 error_rows, limits, spec: DisturbanceConfig):
        super().__init__(dynamics, law, actuated, dt, substeps, integrator, error_rows, limits)
        self.spec = spec
        self.rng: np.random.Generator = np.random.default_rng(0)
        self.buffer: np.ndarray | None = None  # commanded torques not yet applied (d, nv)

    def run_cycle(self, q, v, R, Rd, u_ff) -> CycleLog:
        """One cycle; ``log.q``/``log.v`` are the measurements, ``log.q_true``/``log.v_true`` the
        plant's states, ``log.tau_applied`` the torques the plant received, in [N m]."""
        n, nv, nq = len(R), len(v), len(q)
        sp, rng = self.spec, self.rng
        Nq = rng.normal(0.0, 1.0, (n, nq)) * sp.measurement_noise.q
        Nv = rng.normal(0.0, 1.0, (n, nv)) * sp.measurement_noise.v
        W = rng.normal(0.0, 1.0, (n, nv)) * sp.torque_noise
        d = sp.input_delay_steps
        Qm, Vm, Qt, Vt = (np.empty((n, m)) for m in (nq, nv, nq, nv))
        U, Urows, Uerr, Cmd, Tau = (np.empty((n, nv)) for _ in range(5))
        S = self.actuated
        for k in range(n):
            Qt[k], Vt[k] = q, v
            Qm[k] = self.dynamics.integrate(q, Nq[k][:nv]) if nq != nv else q + Nq[k]
            Vm[k] = v + Nv[k]
            U[k], Urows[k], Uerr[k] = self.law.terms(Qm[k], Vm[k], R[k], Rd[k], self.error_rows)
            Cmd[k] = S * (u_ff[k] + U[k])
            applied, self.buffer = delayed(self.buffer, Cmd[k], d)
            Tau[k] = applied + S * W[k]
            q, v = self.advance(q, v, Tau[k])
        log = CycleLog(Qm, Vm, U, q, v, Urows, Uerr)
        log.q_true, log.v_true, log.tau_applied = Qt, Vt, Tau
        nq_end = rng.normal(0.0, 1.0, nq) * sp.measurement_noise.q  # (drawn last: the draws
        nv_end = rng.normal(0.0, 1.0, nv) * sp.measurement_noise.v  # before are as they were)
        log.end_measured = (self.dynamics.integrate(q, nq_end[:nv]) if nq != nv else q + nq_end,
                            v + nv_end)
        if self.limits is not None and nq == nv:
            log.limit_hits = self.limits.hits(Qt, Cmd)
        return log

    def extra_state(self) -> dict[str, np.ndarray]:
        """The delay buffer, for checkpoints."""
        return {} if self.buffer is None else {"disturbance_buffer": self.buffer.copy()}

    def restore_state(self, saved) -> None:
        if "disturbance_buffer" in saved:
            self.buffer = np.array(saved["disturbance_buffer"], dtype=float)


def cycle_rng(seed: int, cycle: int) -> np.random.Generator:
    """The disturbances' random draws of one cycle of a seed (the same after a resume)."""
    return np.random.default_rng([seed, 17, cycle])


def delayed(buffer: np.ndarray | None, command: np.ndarray, d: int):
    """``(applied, buffer)``: the command ``d`` control steps late (the first ``d`` steps
    repeat the first command), and the buffer of the ``d`` commands still to come (None
    before the first command; unused when ``d`` is 0)."""
    if not d:
        return command, buffer
    if buffer is None:
        buffer = np.repeat(command[None], d, axis=0)
    return buffer[0].copy(), np.vstack([buffer[1:], command[None]])


class WalkerDisturbance:
    r"""The disturbances of the module docstring for a physical walker
    (:class:`feltool.walking.physical.PhysicalLoop`'s ``disturbance`` hook); the contact checks, the
    touchdown and the fall check keep running on the true state.

    * **Measurements.** The sensed coordinates (the pitch and every joint: all but the base's
      translation) get the noise; the base's position and velocity are not sensed but follow
      from the measured angles by the stance leg's kinematics in the known model (leg
      odometry: :meth:`~feltool.walking.physical.PhysicalWalker.complete`, the stance foot at the
      origin).
    * **Torques.** The commanded motor torques reach the plant ``input_delay_steps`` control
      steps late, plus :math:`\sigma_\tau w`, :math:`w \sim \mathcal N(0, I)` per motor.
    * **The inverse-dynamics error estimate** (``learning.error_estimate``) needs the walker's
      acceleration: as measured, the plant's true acceleration plus what differentiating the
      measured velocities adds to it, :math:`(n_{\dot q,k} - n_{\dot q,k-1}) / \Delta t`; its
      inertia matrix is the known model's at the measured angles. The mechanical phase's
      acceleration (part of the reference, computed by the controller) is the known model's
      prediction at the measured state under the commanded torque instead: taken from the
      differentiated velocities it makes the reference itself noisy, and at
      :math:`\sigma_{\dot q}` = 0.003 rad/s the five-link walker's stance foot slid in its
      second cycle (friction ratio 0.743 > 0.7).

    Attributes:
        rng: The Generator of the next draws (set by the cycle runner every cycle).
        true_q, true_v: The plant's states at this cycle's control steps (for tests).
        applied: The motor torques the plant received at this cycle's control steps [N m].
    """

    def __init__(self, walker, spec: DisturbanceConfig, dt: float):
        self.walker, self.spec, self.dt = walker, spec, dt
        nv = walker.walker.model.nv
        self.sensed = np.ones(nv)
        self.sensed[walker.base_v[:2]] = 0.0
        self.rng: np.random.Generator = np.random.default_rng(0)
        self.buffer: np.ndarray | None = None  # commanded motor torques not yet applied (d, k)
        self.noise_v: np.ndarray | None = None  # the last measured minus true velocity
        self._dv = np.zeros(nv)
        self.true_q, self.true_v, self.applied = [], [], []

    def start_cycle(self, rng: np.random.Generator) -> None:
        """Draw the next cycle from ``rng``; the records start anew."""
        self.rng = rng
        self.true_q, self.true_v, self.applied = [], [], []

    def measure(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What the robot measures of the true state ``(q, v)``, in [rad], [m], [rad/s]."""
        self.true_q.append(q.copy())
        self.true_v.append(v.copy())
        noise = self.spec.measurement_noise
        nq = self.rng.normal(0.0, 1.0, len(q)) * noise.q * self.sensed
        nv = self.rng.normal(0.0, 1.0, len(v)) * noise.v * self.sensed
        qm, vm, _ = self.walker.complete(q + nq, v + nv, np.zeros_like(v))
        error_v = vm - v
        previous = error_v if self.noise_v is None else self.noise_v
        self._dv = (error_v - previous) / self.dt
        self.noise_v = error_v
        return qm, vm

    def apply(self, u: np.ndarray) -> np.ndarray:
        """The motor torques the plant receives for the command ``u`` ``(k,)`` in [N m]."""
        late, self.buffer = delayed(self.buffer, u, self.spec.input_delay_steps)
        applied = late + self.rng.normal(0.0, 1.0, len(u)) * self.spec.torque_noise
        self.applied.append(applied)
        return applied

    def inertia(self, qm: np.ndarray) -> np.ndarray:
        """The known model's joint-space inertia matrix at the measured ``qm``."""
        c = self.walker.contact
        return mass_matrix(c.model, c.data, qm)

    def acceleration(self, a: np.ndarray) -> np.ndarray:
        """The measured acceleration for the plant's true ``a`` at this control step."""
        return a + self._dv

    def extra_state(self) -> dict[str, np.ndarray]:
        """The delay buffer and the last velocity error, for checkpoints."""
        out = {}
        if self.buffer is not None:
            out["disturbance_buffer"] = self.buffer.copy()
        if self.noise_v is not None:
            out["disturbance_noise_v"] = self.noise_v.copy()
        return out

    def restore_state(self, saved) -> None:
        if "disturbance_buffer" in saved:
            self.buffer = np.array(saved["disturbance_buffer"], dtype=float)
        if "disturbance_noise_v" in saved:
            self.noise_v = np.array(saved["disturbance_noise_v"], dtype=float)


def problems(cfg: ExperimentConfig) -> list[tuple[str, str]]:
    """Combinations ``disturbances:`` does not support, as ``(yaml_path, message)``."""
    if cfg.disturbances is None:
        return []
    out = []
    if cfg.learning.step != "per_cycle":
        out.append(("disturbances", "needs learning.step: per_cycle"))
    if cfg.backend == "compiled":
        out.append(("disturbances", "needs the pinocchio or casadi backend"))
    if (cfg.walking is not None and not cfg.walking.physical) or cfg.actuation is not None:
        out.append(("disturbances", "not available for the pinned walker (impact: relabel or "
                                    "rigid) or allocated motors; a physical walker "
                                    "(walking.feet) has them"))
    if cfg.learning.model is not None:
        out.append(("disturbances", "cannot be combined with learning.model yet"))
    if cfg.events:
        out.append(("disturbances", "cannot be combined with events"))
    me = cfg.disturbances.model_error
    if cfg.plant is not None and (me.mass_scale != 1.0 or me.length_scale != 1.0):
        out.append(("disturbances.model_error", "scales the known model into the plant; it "
                                                "cannot be combined with a plant block"))
    return out
