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

from dataclasses import dataclass

import numpy as np


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

    def references(self, q_d: np.ndarray, v_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """References :math:`r, \\dot r`, each ``(n, nv)``, for desired trajectories ``(n, nv)``."""
        R = np.where(self.tracking, q_d @ self.C.T, 0.0)
        Rd = np.where(self.tracking, v_d @ self.C.T, 0.0)
        R[:, self.stabilizing] = self.targets[self.stabilizing]
        return R, Rd

    def feedback(self, q: np.ndarray, v: np.ndarray, r: np.ndarray, rd: np.ndarray) -> np.ndarray:
        """Feedback torques :math:`u_{fb}` in [N m] at one state."""
        return self.kp * (r - self.C @ q) + self.kd * (rd - self.C @ v)

    def quantity(self, q: np.ndarray) -> np.ndarray:
        """Controlled quantities :math:`y = C q` in [rad] (rows of a trajectory also work)."""
        return q @ self.C.T

    def consistent_state(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Adjust the stabilized joints so that every target holds with zero velocity."""
        s = self.stabilizing
        q, v = q.copy(), v.copy()
        if s.any():
            Css, Cso = self.C[np.ix_(s, s)], self.C[np.ix_(s, ~s)]
            q[s] = np.linalg.solve(Css, self.targets[s] - Cso @ q[~s])
            v[s] = np.linalg.solve(Css, -Cso @ v[~s])
        return q, v
