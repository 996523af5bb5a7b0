r"""Feedback laws: tracking PD (eq. 2.7) and stabilizing PD (§3.1), in one matrix form.

Each actuated joint :math:`j` owns one controlled quantity :math:`y_j = c_j^\top q`: the joint
itself when it tracks its RMP, or a link's absolute angle (a sum of joint angles, e.g.
:math:`q_1 + q_2` for the arm's upper link) when it stabilizes or tracks with ``link_angle``.
Its feedback torque acts on joint :math:`j`:

.. math::

    u_{\mathrm{fb},j} = K_{P,j}\,(r_j - c_j^\top q) + K_{D,j}\,(\dot r_j - c_j^\top \dot q),

with :math:`r_j = c_j^\top q_d` for tracking (eq. 2.7; :math:`q_{d,j}` unless ``link_angle``)
and :math:`r_j` = the target, :math:`\dot r_j = 0` for stabilizing (§3.1:
:math:`u = K_{P2}(\pi/2 - (q_1 + q_2)) + K_{D2}(0 - (\dot q_1 + \dot q_2))`).
Passive joints have zero rows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from feltool.control.cycle import feedback
from feltool.control.cycle import wrap as wrap_angle
from feltool.control.ops import NUMPY
from feltool.robot.frames import FrameAngle


def wrap(angle):
    """Angle(s) wrapped into [-pi, pi) in [rad] (:func:`feltool.control.cycle.wrap` on numbers)."""
    return wrap_angle(NUMPY, np.asarray(angle))


@dataclass
class FeedbackLaw:
    """All joints' PD laws.

    Attributes:
        C: ``(nv, nv)`` rows :math:`c_j^\\top` mapping joint angles to controlled quantities.
        kp: Proportional gains in [N m/rad], ``(nv,)``.
        kd: Derivative gains in [N m s/rad], ``(nv,)``.
        tracking: Boolean mask of joints that track their RMP.
        stabilizing: Boolean mask of joints that hold a target.
        targets: Target values in [rad] (meaningful where ``stabilizing``).
    """

    C: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    tracking: np.ndarray
    stabilizing: np.ndarray
    targets: np.ndarray
    frames: dict[int, FrameAngle] = field(default_factory=dict)

    @property
    def linear(self) -> bool:
        """True when every quantity is a linear combination of joint angles."""
        return not self.frames

    def terms(self, q: np.ndarray, v: np.ndarray, r: np.ndarray, rd: np.ndarray,
              error_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(u_fb, u_rows, u_err)`` at one state: the joint torques, each controller's own
        output (for a frame angle: its torque about the axis), and the joint torques of the
        controllers in ``error_rows`` (the learning signal). A linear controller acts on its own
        joint; a frame angle's torque acts through :math:`j_y^\\top`."""
        return feedback(NUMPY, self, q, v, r, rd, error_rows, self.frames and
                        {row: f.value_and_jacobian for row, f in self.frames.items()})

    def references(self, q_d: np.ndarray, v_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """References :math:`r, \\dot r`, each ``(n, nv)``, for desired trajectories ``(n, nv)``."""
        tracked, held = self.reference_rows()
        return q_d @ tracked.T + held, v_d @ tracked.T

    def reference(self, q_d: np.ndarray, v_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`references` at one sample: :math:`r, \\dot r` ``(nv,)`` for the desired
        state ``q_d, v_d`` ``(nv,)`` (the same numbers, without the 2-D temporaries; called
        every control step, it keeps its rows from the first call: a law is not changed once
        a loop runs it)."""
        if getattr(self, "_rows", None) is None:
            self._rows = self.reference_rows()
        tracked, held = self._rows
        return tracked @ q_d + held, tracked @ v_d

    def reference_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """C with only the tracking rows, and the stabilizing rows' targets (0 elsewhere):
        :math:`r = C_{track} q_d + r_{held}`."""
        return self.C * self.tracking[:, None], np.where(self.stabilizing, self.targets, 0.0)

    def feedback(self, q: np.ndarray, v: np.ndarray, r: np.ndarray, rd: np.ndarray) -> np.ndarray:
        """Feedback torques :math:`u_{fb}` in [N m] at one state."""
        return self.kp * (r - self.C @ q) + self.kd * (rd - self.C @ v)

    def quantity(self, q: np.ndarray) -> np.ndarray:
        """Controlled quantities in [rad]: :math:`y = C q`, and frame angles (rows of a
        trajectory also work)."""
        y = q @ self.C.T
        for row, frame in self.frames.items():
            if y.ndim == 1:
                y[row] = frame.value(q)
            else:
                y[:, row] = [frame.value(qk) for qk in q]
        return y

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """:math:`\\partial y/\\partial q`, ``(nv, nv)``."""
        J = self.C.copy()
        for row, frame in self.frames.items():
            J[row] = frame.value_and_jacobian(q)[1]
        return J

    def consistent_state(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Adjust the stabilized joints so that every target holds with zero velocity
        (a linear solve, or Newton's method when frame angles are stabilized)."""
        s = self.stabilizing
        q, v = q.copy(), v.copy()
        if not s.any():
            return q, v
        for _ in range(1 if self.linear else 50):
            J = self.jacobian(q)
            err = wrap(self.targets[s] - self.quantity(q)[s])
            q[s] = q[s] + _solve(J[np.ix_(s, s)], err)
            if np.abs(err).max() < 1e-13:
                break
        J = self.jacobian(q)
        v[s] = _solve(J[np.ix_(s, s)], -J[np.ix_(s, ~s)] @ v[~s])
        return q, v


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A x = b``; the least-squares x when A is singular (a target its joint does not move:
    feltool check reports it, feltool.experiment.checks.target_problems)."""
    try:
        return np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]
