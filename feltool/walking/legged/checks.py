r"""What keeps a legged robot's contacts physical: the planar walker's checks
(:class:`feltool.walking.checks.ContactChecks`, the same fields) for any set of 3D point feet.

- stance, every foot: the normal force :math:`f_z > \max(0, f_{min})` (a foot that would pull
  on the ground is *not walking*, kind ``normal_force``) and inside the friction cone
  :math:`\|f_t\| \le \mu f_z` (kind ``friction``, the circular cone, not a pyramid);
- the feet in the air not below the ground by more than ``clearance_tol`` (no penetration,
  kind ``clearance``);
- at a touchdown: each held foot's normal impulse :math:`\iota_z > 0` and
  :math:`\|\iota_t\| \le \mu \iota_z` (kind ``impulse``), each foot leaving the ground moving up
  or not at all after the impact (kind ``lift_off``), the landing feet moving down before it
  (kind ``touchdown``);
- motor torques within their effort limits (kind ``torque``; ``torques: saturate`` clips and
  counts instead).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from feltool.walking.checks import ContactChecks, NotWalking


@dataclass
class LeggedStats:
    """The contact physics seen so far.

    Attributes:
        min_normal_force: Smallest stance normal force [N].
        max_friction_ratio: Largest :math:`\\|f_t\\|/f_z` [-].
        min_clearance: Lowest height of a foot in the air [m].
        max_torque: Largest |motor torque| [N m].
        max_impulse_ratio: Largest :math:`\\|\\iota_t\\|/\\iota_z` at a touchdown [-].
        energy_lost: Kinetic energy lost in the impacts [J].
        torque_hits: Control steps with a clipped torque (``torques: saturate``).
        impacts_released: Feet in stance before a touchdown that its unilateral impact lifted
            off the ground (no impulse, moving up).
    """

    min_normal_force: float = np.inf
    max_friction_ratio: float = 0.0
    min_clearance: float = np.inf
    max_torque: float = 0.0
    max_impulse_ratio: float = 0.0
    energy_lost: float = 0.0
    torque_hits: int = 0
    impacts_released: int = 0


def check_stance(chk: ContactChecks, st: LeggedStats, feet: tuple[str, ...],
                 forces: np.ndarray) -> None:
    """The stance feet's ground forces ``(n, 3)`` [N]: pushing, and inside the friction cone."""
    floor = max(0.0, chk.normal_force_min)
    for foot, f in zip(feet, forces):
        fn, ft = float(f[2]), float(np.hypot(f[0], f[1]))
        st.min_normal_force = min(st.min_normal_force, fn)
        if not fn > floor:
            if not np.all(np.isfinite(forces)):  # a singular contact problem, or diverged
                raise NotWalking(f"the stance feet {', '.join(feet)} have no finite contact "
                                 "forces: their contacts' constraints are dependent (more "
                                 "than the robot's legs can resolve) or the state diverged",
                                 "diverged")
            raise NotWalking(f"the stance foot {foot} would pull on the ground: normal force "
                             f"{fn:.4g} N (walking.normal_force_min = {chk.normal_force_min} N)",
                             "normal_force")
        ratio = ft / fn
        st.max_friction_ratio = max(st.max_friction_ratio, ratio)
        if ratio > chk.friction:
            raise NotWalking(f"the stance foot {foot} slips: |f_t|/f_n = {ratio:.3g} > "
                             f"walking.friction = {chk.friction}", "friction")


def check_air(chk: ContactChecks, st: LeggedStats, feet: tuple[str, ...],
              heights: np.ndarray) -> None:
    """The feet in the air, ``heights`` [m] above the ground: none below it (beyond
    ``clearance_tol``)."""
    for foot, z in zip(feet, heights):
        st.min_clearance = min(st.min_clearance, float(z))
        if z < -chk.clearance_tol:
            raise NotWalking(f"the foot {foot} is {-z * 1e3:.3g} mm below the ground while in "
                             f"the air (walking.clearance_tol_m = {chk.clearance_tol})",
                             "clearance")


def check_impact(chk: ContactChecks, st: LeggedStats, feet: tuple[str, ...],
                 impulses: np.ndarray, leaving: tuple[str, ...] = (),
                 leaving_vz: np.ndarray | None = None, energy_lost: float = 0.0) -> None:
    """A touchdown's impulses ``(n, 3)`` [N s] on the held ``feet`` (pushing, in the cone) and
    the vertical velocities [m/s] after it of the feet ``leaving`` the ground (not down)."""
    st.energy_lost += energy_lost
    for foot, imp in zip(feet, impulses):
        n, t = float(imp[2]), float(np.hypot(imp[0], imp[1]))
        if not n > 0.0:
            raise NotWalking(f"the foot {foot} would pull on the ground at the touchdown: "
                             f"normal impulse {n:.4g} N s", "impulse")
        st.max_impulse_ratio = max(st.max_impulse_ratio, t / n)
        if t / n > chk.friction:
            raise NotWalking(f"the foot {foot} slips at the touchdown: |i_t|/i_n = {t / n:.3g} "
                             f"> walking.friction = {chk.friction}", "impulse")
    for foot, vz in zip(leaving, [] if leaving_vz is None else leaving_vz):
        if vz < -1e-9:
            raise NotWalking(f"the foot {foot} does not lift off: it moves down at "
                             f"{-vz:.3g} m/s after the touchdown", "lift_off")


def check_torques(chk: ContactChecks, st: LeggedStats, u: np.ndarray,
                  names: list[str]) -> np.ndarray:
    """Motor torques ``u`` [N m] against ``chk.effort``: returned as they are, clipped
    (``saturate``, counted), or :class:`NotWalking` (``report``)."""
    st.max_torque = max(st.max_torque, float(np.abs(u).max(initial=0.0)))
    if chk.effort is None or chk.torques == "ignore":
        return u
    over = np.abs(u) > chk.effort * (1 + 1e-9)
    if not over.any():
        return u
    if chk.torques == "saturate":
        st.torque_hits += 1
        return np.clip(u, -chk.effort, chk.effort)
    i = int(np.argmax(np.abs(u) - chk.effort))
    raise NotWalking(f"motor {names[i]} needs {u[i]:.4g} N m, over its limit "
                     f"{chk.effort[i]:.4g} N m", "torque")
