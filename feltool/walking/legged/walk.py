r"""A biped's walk to start from: the trot's machinery (:mod:`.trot`: event-driven switch of two
groups of feet, Raibert foot placement, inverse kinematics, whole-body inverse dynamics and its
QP) on the two soles, each sole its four corners (:func:`~.model.sole_corners`), and a base that
sways sideways over the stance sole.

**Sway.** The gait's horizontal motion is the centre of mass's (``steer_com``: the inverse
kinematics places the base so that the centre of mass is there). With one sole on the ground the
centre of pressure must stay in it, so the centre of mass cannot simply travel along the midline
as a trot's base does. Its sideways motion is the linear inverted
pendulum's periodic orbit with the centre of pressure at the middle of the stance sole
(:math:`\ddot y = \omega^2 (y - p)`, :math:`\omega = \sqrt{g / z_c}`, :math:`z_c` the centre of
mass's height): over each step, from the switch that made its sole the stance (an event, as
the trot's), lasting :math:`T` = ``land * period / 2`` [s] (the swing's planned touchdown), with
the sole at :math:`s p` (:math:`s = \pm 1` its side, :math:`p` [m] its distance from the
midline, times ``sway``)

.. math::

    y(\tau) = s\,p\left(1 - \frac{\cosh \omega(\tau - T/2)}{\cosh \omega T/2}\right),

which crosses the midline at each switch with the velocity the next step's orbit starts with.
The switch is an event, so each step starts the pendulum from the last step's offset and rate
at the switch, its centre of pressure :math:`p` put where the divergent component
:math:`\xi = y + \dot y/\omega` reaches the orbit's at the step's planned end (the orbit itself
when the switch comes on time; continuous, and steered back onto the orbit, when it does not:
without it the pendulum's free motion from an early switch ran away within two steps).
Before the first step, on both soles, a quintic of ``shift`` [s] takes the base from rest on the
midline to rest at the apex of the other sole's orbit (the centre of pressure arriving at that
sole's middle), and the base follows that orbit's second half back to the midline: the weight
shift every walking biped starts with. ``start`` must leave ``shift + T / 2`` for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from feltool.walking.legged.control import StandGains
from feltool.walking.legged.model import LeggedModel
from feltool.walking.legged.trot import TrotController, TrotGait

#: The walk's time for a touchdown's impact (a Moreau-Jean window, [s]): the stance sole's
#: load acts over it (instantaneous, the landing sole's corners gave the stance sole
#: tangential impulses beyond its friction)
IMPACT_WINDOW = 1e-3

#: The mass the walk's gains were tuned on (Talos' legs and torso) [kg]
TUNED_MASS = 48.7


@dataclass
class WalkGait(TrotGait):
    """A biped's walk: :class:`~.trot.TrotGait`'s timing with the sway above.

    Attributes (beyond :class:`~.trot.TrotGait`'s):
        omega: :math:`\\omega` of the linear inverted pendulum [1/s].
        half_width: :math:`p`, the stance sole's centre's distance from the midline [m].
        first_side: :math:`s` of the first stance group (``groups[0]``), +1 left (+y).
        sway: Fraction of ``half_width`` the centre of pressure is put at [-].
        shift: Duration of the weight shift's quintic [s] (``start`` leaves ``shift + land *
            period / 4`` before the first step).
    """

    speed: float = 0.15
    period: float = 1.2
    ramp: float = 2.0
    start: float = 1.5
    step_height: float = 0.05
    landing_speed: float = 0.05
    catch: float = 0.3
    omega: float = 3.3
    half_width: float = 0.085
    first_side: float = 1.0
    sway: float = 1.0
    shift: float = 0.8
    steer_com: bool = True

    def reset(self) -> None:
        super().reset()
        w, T = self.omega, self.land * self.period / 2
        A = self.sway * self.half_width * self.first_side
        self._segment = (self.start, 0.0, A * w * np.tanh(w * T / 2))

    def touchdown(self, t: float, landed: tuple[str, ...]) -> None:
        """:meth:`TrotGait.touchdown`; at a switch the sway's next step starts from where the
        last one is at ``t`` [s] (continuous in offset and rate, whenever the switch comes)."""
        y, dy = self.lateral(t)
        steps = self.steps
        super().touchdown(t, landed)
        if self.steps != steps:
            self._segment = (t, y, dy)

    def lateral(self, t: float) -> tuple[float, float]:
        """The base's desired sideways offset [m] and rate [m/s] at ``t`` [s]."""
        w, T = self.omega, self.land * self.period / 2
        A = self.sway * self.half_width * self.first_side
        if t >= self.start:  # the pendulum over the stance group's sole since the last switch
            t0, y0, dy0 = self._segment
            p = self._pressure(y0, dy0, A if self.swing == 1 else -A)
            tau = t - t0
            ch, sh = np.cosh(w * tau), np.sinh(w * tau)
            return (p + (y0 - p) * ch + dy0 / w * sh, (y0 - p) * w * sh + dy0 * ch)
        if t >= self.start - T / 2:  # before the start, the other sole's orbit's last half
            tau, c = t - self.start + T, np.cosh(w * T / 2)
            return (-A * (1 - np.cosh(w * (tau - T / 2)) / c),
                    A * w * np.sinh(w * (tau - T / 2)) / c)
        tau = t - (self.start - T / 2 - self.shift)
        if tau <= 0.0:
            return 0.0, 0.0
        c3, c4, c5 = self._shift_coefficients()
        return (c3 * tau ** 3 + c4 * tau ** 4 + c5 * tau ** 5,
                3 * c3 * tau ** 2 + 4 * c4 * tau ** 3 + 5 * c5 * tau ** 4)

    def _pressure(self, y0: float, dy0: float, nominal: float) -> float:
        """The step's centre of pressure [m] that brings the divergent component
        :math:`\\xi = y + \\dot y / \\omega` from its value at the switch to the orbit's at the
        step's planned end (``nominal`` on the orbit itself): :math:`\\xi(T) = p + (\\xi_0 -
        p)e^{\\omega T}`."""
        w, T = self.omega, self.land * self.period / 2
        e = np.exp(w * T)
        goal = -nominal * np.tanh(w * T / 2)
        return (goal - (y0 + dy0 / w) * e) / (1.0 - e)

    def _shift_coefficients(self) -> np.ndarray:
        """``(c3, c4, c5)`` of the weight shift :math:`c_3\\tau^3 + c_4\\tau^4 + c_5\\tau^5`:
        at rest at its start, at its end at rest at the other sole's orbit's apex (with that
        orbit's acceleration: the centre of pressure reaches that sole's middle)."""
        w, T, D = self.omega, self.land * self.period / 2, self.shift
        A = -self.sway * self.half_width * self.first_side
        c = np.cosh(w * T / 2)
        goal = np.array([A * (1 - 1 / c), 0.0, w ** 2 * A / c])
        basis = np.array([[D ** 3, D ** 4, D ** 5], [3 * D ** 2, 4 * D ** 3, 5 * D ** 4],
                          [6 * D, 12 * D ** 2, 20 * D ** 3]])
        return np.linalg.solve(basis, goal)


def biped_walk(legged: LeggedModel, q: np.ndarray, left: tuple[str, ...],
               right: tuple[str, ...], **timing) -> WalkGait:
    """A :class:`WalkGait` for ``legged`` standing at ``q``: the ``left`` sole's feet stand
    first (the right one steps first), :math:`p` the soles' centres' half distance and
    :math:`\\omega` from the centre of mass's height in the model's gravity. ``timing``:
    :class:`WalkGait`'s other fields."""
    P = legged.foot_positions(q)
    names = list(legged.feet)
    yl = P[[names.index(f) for f in left], 1].mean()
    yr = P[[names.index(f) for f in right], 1].mean()
    zc = float(pin.centerOfMass(legged.model, legged.data, q)[2])
    g = float(np.linalg.norm(legged.model.gravity.linear))
    return WalkGait(groups=(tuple(left), tuple(right)), omega=float(np.sqrt(g / zc)),
                    half_width=float(abs(yl - yr) / 2), first_side=float(np.sign(yl - yr)),
                    **timing)


def biped_gains(legged: LeggedModel) -> dict:
    """:class:`~.trot.TrotController`'s gains for a biped's walk, tuned on Talos' legs (48.7
    kg), the base's and the centre of mass's scaled by the robot's mass over that (height 82
    N/m and 8.2 N s/m per kg; roll and pitch 33 N m/rad and 1.6 N m s/rad per kg; the centre of
    mass's horizontal PD 41 N/m and 4.1 N s/m per kg); the joints' PD 600 N m/rad and 100 N m
    s/rad, the swing soles' corners pulled to their targets at 10 kN/m and 200 N s/m; each
    stance corner keeps 5 N."""
    r = legged.mass / TUNED_MASS
    gains = StandGains(height=(4000.0 * r, 400.0 * r), tilt=(1600.0 * r, 80.0 * r),
                       yaw_rate=50.0 * r, joints=(600.0, 100.0))
    return dict(gains=gains, normal_force_min=5.0, horizontal=(2000.0 * r, 200.0 * r),
                swing_gains=(1e4, 200.0))


def biped_controller(legged: LeggedModel, q: np.ndarray, gait: WalkGait) -> TrotController:
    """The whole-body controller of :class:`~.trot.TrotController` for a biped's walk, with
    :func:`biped_gains`."""
    return TrotController(legged, q, gait=gait, **biped_gains(legged))
