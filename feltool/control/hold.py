r"""The feedforward a sampled controller holds over a control step (``sim.feedforward``).

The known model's feedforward :math:`u_{ff}(t) = \mathrm{RNEA}(q_d, \dot q_d, \ddot q_d)` is a
function of continuous time; the controller holds one torque over each control step
:math:`[t_k, t_{k+1}]`. Held at its value at :math:`t_k` (``sample``, the thesis), it lags the
continuous torque by half a step, an error of the order of the step :math:`\Delta t` that no
learned joint can take out of another joint's feedback. ``hold_mean`` holds the mean over the
step by the trapezoid rule,

.. math:: \bar u_k = \tfrac12\,(u_{ff}(t_k) + u_{ff}(t_{k+1})),

whose error is of the order of :math:`\Delta t^2`; the cycle's last step, whose next sample
belongs to the next cycle (of another length, or other parameters), extrapolates it
linearly, :math:`\bar u_{n-1} = \tfrac32 u_{n-1} - \tfrac12 u_{n-2}` (also second order). It is
linear: the feedforward's sensitivity to the parameters is held the same way.
"""

from __future__ import annotations

import casadi as ca
import numpy as np


def hold_mean(U: np.ndarray) -> np.ndarray:
    """``(n, ...)``: each step's mean of the samples ``U`` ``(n, ...)`` (n >= 2) over its hold
    (in the units of ``U``, e.g. [N m])."""
    out = np.empty_like(U, dtype=float)
    out[:-1] = 0.5 * (U[:-1] + U[1:])
    out[-1] = 1.5 * U[-1] - 0.5 * U[-2]
    return out


def hold_mean_columns(U, block: int = 1, mask=None):
    """:func:`hold_mean` of a CasADi matrix whose steps are consecutive blocks of ``block``
    columns (``(rows, n block)``); ``mask`` ``(1, n)`` the steps the cycle has (its last one
    extrapolates), None: all."""
    n = U.shape[1] // block
    nxt = ca.horzcat(U[:, block:], U[:, -block:])  # step k+1's (the last: its own, unused)
    prev = ca.horzcat(U[:, :block], U[:, :-block])  # step k-1's
    has_next = ca.DM([[1.0] * (n - 1) + [0.0]]) if mask is None else \
        ca.horzcat(mask[:, 1:], ca.DM.zeros(1, 1))
    has_next = ca.repmat(ca.kron(has_next, ca.DM.ones(1, block)), U.shape[0], 1)
    return has_next * 0.5 * (U + nxt) + (1 - has_next) * (1.5 * U - 0.5 * prev)


__all__ = ["hold_mean", "hold_mean_columns"]
