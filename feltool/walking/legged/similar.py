r"""A quadruped's trot scaled from Solo-12's by dynamic similarity.

The trot's gains and timing (:class:`~.trot.TrotController`, :class:`~.trot.TrotGait`) were
tuned on Solo-12 (2.5 kg, its base 0.216 m above its feet). Another quadruped -- Go1, A1,
ANYmal as their URDFs are published -- with the same numbers is a different dynamical system:
Solo's 200 N/m on the height of a 13 kg robot is a fifth of the stiffness relative to its
weight, and its feet slide at the first touchdown. Under Froude similarity two robots of
masses :math:`m_1, m_2` and lengths :math:`L_1, L_2` move alike when times scale by
:math:`\sqrt{\lambda}`, :math:`\lambda = L_2 / L_1` (the same :math:`g`), so

- lengths (step height, sink, approach height) by :math:`\lambda`, times (period, Raibert's
  gain [s]) and speeds (forward, landing) by :math:`\sqrt\lambda`;
- a stiffness on a length [N/m] by :math:`\mu / \lambda` and its damping [N s/m] by
  :math:`\mu / \sqrt\lambda`, :math:`\mu = m_2 / m_1`; on an angle [N m/rad] by
  :math:`\mu \lambda` and [N m s/rad] by :math:`\mu \lambda^{3/2}`; forces [N] by :math:`\mu`.

The base's gains scale with the whole robot's mass, the joints' PD and the swing feet's
Cartesian PD with the legs' (the bodies between the base and the feet, which they move: 54 %
of Solo-12's mass, 58 % of Go1's, 30 % of HyQ's). :math:`L` is the base's height above its
feet in the reference posture. For Solo-12 every factor is 1 (the tuned numbers themselves).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from feltool.walking.legged.control import StandGains
from feltool.walking.legged.model import LeggedModel
from feltool.walking.legged.tree_feet import leg_joints
from feltool.walking.legged.trot import TrotController

#: Solo-12's mass [kg], its legs' [kg] and its base's height above its feet [m] in its
#: reference posture, as :func:`body_scale` computes them: the robot the trot was tuned on
#: (every factor exactly 1 for it: a test loads it)
TUNED_MASS, TUNED_LEGS, TUNED_HEIGHT = 2.5000027900000004, 1.33885188, 0.21589724826917053

#: The trot's tuned gains: :class:`~.trot.TrotController`'s defaults
TUNED = {f.name: f.default for f in fields(TrotController)
         if f.name in ("horizontal", "swing_gains", "normal_force_min")}

#: The trot's timing fields that are lengths [m] and times or speeds ([s], [m/s])
LENGTHS = ("step_height", "sink", "approach_height")
TIMES = ("speed", "period", "landing_speed", "raibert")


@dataclass(frozen=True)
class BodyScale:
    """A robot against Solo-12: ``mass``, ``legs`` (its legs' mass) and ``length`` (its base's
    height above its feet) each as a ratio to Solo-12's [-]."""

    mass: float
    legs: float
    length: float


def legs_mass(legged: LeggedModel) -> float:
    """The mass [kg] of the bodies between the base and the feet (each once)."""
    m = legged.model
    joints = {j for frame in legged.feet.values()
              for j in leg_joints(m, m.frames[frame].parentJoint)}
    return float(sum(m.inertias[j].mass for j in sorted(joints)))


def body_scale(legged: LeggedModel) -> BodyScale:
    """``legged`` against Solo-12, in its reference posture (:meth:`LeggedModel.standing`)."""
    q = legged.standing()
    height = float(q[2] - legged.foot_positions(q)[:, 2].mean())
    return BodyScale(legged.mass / TUNED_MASS, legs_mass(legged) / TUNED_LEGS,
                     height / TUNED_HEIGHT)


def trot_gains(legged: LeggedModel) -> dict:
    """:class:`~.trot.TrotController`'s gains for ``legged``: Solo-12's, scaled as above."""
    s = body_scale(legged)
    mu, legs, lam = s.mass, s.legs, s.length
    root = float(np.sqrt(lam))
    g, (k, d), (ks, ds) = StandGains(), TUNED["horizontal"], TUNED["swing_gains"]
    gains = StandGains(height=(g.height[0] * mu / lam, g.height[1] * mu / root),
                       tilt=(g.tilt[0] * mu * lam, g.tilt[1] * mu * lam * root),
                       yaw_rate=g.yaw_rate * mu * lam * root,
                       joints=(g.joints[0] * legs * lam, g.joints[1] * legs * lam * root))
    return dict(gains=gains, horizontal=(k * mu / lam, d * mu / root),
                swing_gains=(ks * legs / lam, ds * legs / root),
                normal_force_min=TUNED["normal_force_min"] * mu)


def trot_timing(legged: LeggedModel, tuned: dict) -> dict:
    """``tuned``, Solo-12's trot timing (:class:`~.trot.TrotGait`'s fields), scaled to
    ``legged``: its lengths by :math:`\\lambda`, its times and speeds by
    :math:`\\sqrt\\lambda` (the others as they are)."""
    lam = body_scale(legged).length
    root = float(np.sqrt(lam))
    return {key: value * lam if key in LENGTHS else value * root if key in TIMES else value
            for key, value in tuned.items()}
