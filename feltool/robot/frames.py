"""A link frame's absolute angle about a world axis, and its Jacobian (a stabilized quantity)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin


class FrameAngle:
    r"""The orientation of a link frame about a world axis, as a stabilized quantity.

    With :math:`v = R(q)\,v_f` the frame's vector ``vector`` in world coordinates, ``about`` the
    world axis :math:`a` and ``zero`` the world direction :math:`z_0 \perp a` where the angle is 0,

    .. math::

        y = \operatorname{atan2}\big((z_0 \times v)\cdot a,\; z_0 \cdot v\big),
        \qquad \dot y = j_y(q)\,\dot q,\qquad
        j_y = \frac{((z_0\cdot v)\,(a \times z_0) - ((a\times z_0)\cdot v)\,z_0)^\top}{\rho^2}
              \,(-[v]_\times J_\omega(q))

    (counter-clockwise about :math:`a`; :math:`J_\omega` the frame's angular Jacobian in world
    axes, :math:`\rho^2` the squared length of :math:`v` projected on the plane). Its feedback
    torque acts on the joints through :math:`j_y^\top`.
    """

    def __init__(self, model: pin.Model, frame: str, vector, about, zero=None):
        self.model, self.data = model, model.createData()
        self.frame_id = model.getFrameId(frame)
        self.vector = np.asarray(vector, float) / np.linalg.norm(vector)
        a = np.asarray(about, float)
        self.about = a / np.linalg.norm(a)
        if zero is None:
            zero = [0.0, 0.0, 1.0] if abs(self.about[2]) < 0.9 else [1.0, 0.0, 0.0]
        z = np.asarray(zero, float)
        z = z - (z @ self.about) * self.about
        self.zero = z / np.linalg.norm(z)
        self.ortho = np.cross(self.about, self.zero)

    def value(self, q: np.ndarray) -> float:
        """The angle in [rad] at configuration q."""
        pin.framesForwardKinematics(self.model, self.data, q)
        v = self.data.oMf[self.frame_id].rotation @ self.vector
        return float(np.arctan2(self.ortho @ v, self.zero @ v))

    def value_and_jacobian(self, q: np.ndarray) -> tuple[float, np.ndarray]:
        """The angle in [rad] and its Jacobian :math:`j_y` (nv,) in [rad/rad]."""
        J = pin.computeFrameJacobian(self.model, self.data, q, self.frame_id,
                                     pin.LOCAL_WORLD_ALIGNED)
        v = self.data.oMf[self.frame_id].rotation @ self.vector
        c, s = self.zero @ v, self.ortho @ v
        dv_dq = -pin.skew(v) @ J[3:]
        grad = (c * self.ortho - s * self.zero) / (c * c + s * s)
        return float(np.arctan2(s, c)), grad @ dv_dq
