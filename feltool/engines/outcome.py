"""What one learning cycle gives, whichever engine ran it (:class:`CycleOutcome`), and where
a seed is between cycles (:class:`SeedState`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from feltool.control.closed_loop import CycleLog
    from feltool.dynamics.interface import Dynamics
    from feltool.motion.phase import PhaseSamples


@dataclass
class CycleOutcome:
    """What the learner and the metrics need from one cycle, whichever backend ran it.

    Attributes:
        theta_next: Parameters after the cycle's update.
        q_end, v_end: Robot state after the cycle.
        fb_abs_mean: Mean |u_fb| per joint over the cycle [N m].
        fb_stabilized: Sum over stabilizing controllers of their mean |output| [N m].
        fb_error: Sum over joints of the mean |error signal| [N m].
        track_err_rms: RMS of forward minus system angle per joint [rad].
        max_error: Largest |reference - controlled quantity| over the cycle [rad].
        max_speed: Largest |joint velocity| over the cycle [rad/s].
        finite: Whether every state stayed finite.
        trace: Returns ``(CycleLog, Qd)`` of the cycle (computed on demand).
        fall: Why a walker fell during the cycle (hybrid loop), or None.
        impacts: ``(step, by_guard, swing-foot x [m])`` of each impact (walkers).
        theta_m_next: The inverse-model correction after the cycle (``learning.model``), else
            None.
        contact: A physical walker's contact metrics of the cycle (:func:`contact_metrics`).
        cycle: The phase at the cycle's steps (None: the nominal cycle).
        desired: The cycle's desired positions, velocities and accelerations, each ``(n, nv)``,
            or a function that computes them when asked (:meth:`desired_motion`), where the
            engine has them.
    """

    theta_next: np.ndarray
    q_end: np.ndarray
    v_end: np.ndarray
    fb_abs_mean: np.ndarray
    track_err_rms: np.ndarray
    max_error: float
    max_speed: float
    finite: bool
    trace: Callable[[], tuple[CycleLog, np.ndarray]]
    fb_stabilized: float = 0.0
    fb_error: float = 0.0
    fall: str | None = None
    impacts: list = field(default_factory=list)
    theta_m_next: np.ndarray | None = None
    limit_hits: tuple[np.ndarray, np.ndarray] | None = None
    contact: dict | None = None
    cycle: PhaseSamples | None = None
    desired: tuple[np.ndarray, np.ndarray, np.ndarray] | Callable[[], tuple] | None = None

    def desired_motion(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """:attr:`desired`, computed now if the engine left a function."""
        return self.desired() if callable(self.desired) else self.desired


@dataclass
class SeedState:
    """Where a seed is between cycles: the RMP parameters, the robot's state, the inverse-model
    correction's parameters (``learning.model``, else None) and the simulated world."""

    theta: np.ndarray
    q: np.ndarray
    v: np.ndarray
    theta_m: np.ndarray | None
    plant: Dynamics | None = None


__all__ = ["CycleOutcome", "SeedState"]
