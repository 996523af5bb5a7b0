"""What makes a physical walker's step physical: the contact checks (normal force, friction
cone, clearance, impulse, lift-off, torque limits), each step's statistics, and the stop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class ContactChecks:
    """What a physical step must satisfy.

    Attributes:
        friction: Coulomb coefficient :math:`\\mu` [-]: :math:`|F_x|/F_z \\le \\mu` in stance and
            :math:`|I_x|/I_z \\le \\mu` at touchdown.
        normal_force_min: The stance foot's normal force must stay at least this, in [N].
        scuff_exempt: The swing foot may be below the ground within this horizontal distance of
            the stance foot, in [m].
        effort: Motor effort limits ``(k,)`` in [N m] (inf: none).
        torques: ``report`` (a motor torque over its limit is not walking), ``saturate`` (clip
            it, count the steps), ``ignore``.
        clearance_tol: How far the swing foot may graze below the ground outside the scuffing
            zone (e.g. the trailing foot just after lift-off), in [m].
        scuff_behind: The classic compass-gait convention: the swing foot below the ground while
            it is behind the stance foot is not a stop (feltool gait counts and reports it).
    """

    friction: float = 0.7
    normal_force_min: float = 0.0
    scuff_exempt: float = 0.0
    effort: np.ndarray | None = None
    torques: str = "report"
    clearance_tol: float = 1e-3
    scuff_behind: bool = False


@dataclass
class StepStats:
    """One step's contact physics (from its take-off to its touchdown).

    Attributes:
        min_normal_force: Smallest stance normal force :math:`F_z` [N].
        max_friction_ratio: Largest :math:`|F_x|/F_z` [-].
        min_clearance: Lowest swing-foot height outside the scuffing zone [m].
        max_torque: Largest |motor torque| [N m].
        impulse: Touchdown impulse ``(I_x, I_z)`` [N s] (NaN until touchdown).
        impulse_ratio: :math:`|I_x|/I_z` [-].
        trailing_vz: The trailing foot's vertical velocity just after the impact [m/s].
        energy_lost: Kinetic energy lost at the impact [J].
        length: Touchdown position of the swing foot ahead of the stance foot [m].
        duration: Step duration [s].
        touchdown_height: The swing foot's height at the located touchdown [m].
    """

    min_normal_force: float = np.inf
    max_friction_ratio: float = 0.0
    min_clearance: float = np.inf
    max_torque: float = 0.0
    impulse: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    impulse_ratio: float = np.nan
    trailing_vz: float = np.nan
    energy_lost: float = np.nan
    length: float = np.nan
    duration: float = 0.0
    touchdown_height: float = np.nan


class NotWalking(Exception):
    """Contact physics violated: the reason, in words, and its kind (``normal_force``,
    ``friction``, ``clearance``, ``touchdown``, ``impulse``, ``lift_off``, ``torque``)."""

    def __init__(self, message: str, kind: str):
        super().__init__(message)
        self.kind = kind


def check_clearance(chk: ContactChecks, st: StepStats, height: float, ahead: float) -> None:
    """The swing foot away from a touchdown, ``height`` [m] above the ground and ``ahead`` [m]
    of the stance foot: its lowest height counted, and :class:`NotWalking` when it is below
    the ground by over ``chk.clearance_tol`` -- outside the scuffing zone, and (with
    ``chk.scuff_behind``, the compass-gait convention) ahead of the stance foot only."""
    if abs(ahead) < chk.scuff_exempt or (chk.scuff_behind and ahead <= 0.0):
        return
    st.min_clearance = min(st.min_clearance, height)
    if height < -chk.clearance_tol:
        where = "behind" if ahead <= 0.0 else "ahead of"
        raise NotWalking(f"the swing foot is {-height * 1e3:.3g} mm below the ground, "
                         f"{abs(ahead):.3g} m {where} the stance foot, away from a touchdown "
                         f"(walking.scuff_exempt_m = {chk.scuff_exempt}, walking.clearance_tol_m"
                         f" = {chk.clearance_tol})", "clearance")
