"""Physical plausibility of rigid-body parameters: masses, rotational inertias, joint dynamics.

One set of rules for every place a body's parameters enter feltool (URDF ``<inertial>``
elements, ``plant.bodies`` overrides, payloads), so that a body no physical object could have
is refused before anything is simulated, instead of producing numbers that look like results.

The rules (what a researcher expects of a rigid body):

* a mass is finite and positive; a URDF link may have mass 0 (a massless helper link, e.g. a
  tool frame), but a body moved by a joint must carry some mass;
* the rotational inertia about the centre of mass is a symmetric 3 x 3 matrix with finite
  entries that is positive *semi*-definite (all principal moments >= 0) and whose principal
  moments satisfy the triangle inequality I_1 + I_2 >= I_3 (for every ordering). Zero moments
  are legitimate idealisations: a point mass has I = 0, a thin rod has one principal moment 0
  (and I_2 = I_3); a negative moment, or moments no mass distribution can produce, are not.
  The inequalities are checked with a relative tolerance of :data:`INERTIA_RTOL` (URDFs round
  their numbers).
* a joint's ``<dynamics>`` damping [N m s/rad] and friction [N m] are >= 0: a negative damping
  or friction pushes the joint along its motion, a plant that creates energy.
"""

from __future__ import annotations

import math

import numpy as np

#: Relative tolerance of the inertia checks, relative to the largest principal moment.
INERTIA_RTOL = 1e-6

#: Absolute tolerance in [kg m^2] (rounding noise of zero entries; 1 g at 30 um).
INERTIA_ATOL = 1e-12


def mass_problem(mass: float, allow_zero: bool = False) -> str | None:
    """Why ``mass`` (in [kg]) is not a physical mass, or None when it is."""
    if not math.isfinite(mass):
        return f"mass {mass} is not a finite number"
    if mass < 0.0 or (mass == 0.0 and not allow_zero):
        need = "at least 0 (0 for a massless helper link)" if allow_zero else "positive"
        return f"mass {mass:g} kg must be {need}"
    return None


def inertia_matrix(ixx: float, ixy: float, ixz: float, iyy: float, iyz: float,
                   izz: float) -> np.ndarray:
    """The symmetric rotational inertia matrix from its six URDF entries, in [kg m^2]."""
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)


def inertia_problem(values: list[float] | tuple[float, ...] | np.ndarray) -> str | None:
    """Why the rotational inertia ``[ixx, ixy, ixz, iyy, iyz, izz]`` in [kg m^2] (about the
    centre of mass, URDF order) is not one a rigid body can have, or None when it is."""
    values = [float(v) for v in values]
    if not all(math.isfinite(v) for v in values):
        return f"inertia {values} has an entry that is not a finite number"
    moments = np.linalg.eigvalsh(inertia_matrix(*values))  # ascending principal moments
    scale = max(float(np.abs(moments).max()), 0.0)
    tol = INERTIA_RTOL * scale + INERTIA_ATOL
    if moments[0] < -tol:
        return (f"inertia is not positive semi-definite (principal moments "
                f"{_fmt(moments)} kg m^2; a moment of inertia cannot be negative)")
    if moments[0] + moments[1] < moments[2] - tol:
        return (f"inertia violates the triangle inequality of its principal moments "
                f"({_fmt(moments)} kg m^2: I1 + I2 < I3, which no mass distribution gives)")
    return None


def _fmt(moments: np.ndarray) -> str:
    return "[" + ", ".join(f"{m:.4g}" for m in moments) + "]"


#: What a negative value of a joint's ``<dynamics>`` attribute would do.
_DYNAMICS_SIGN = {"damping": "a negative damping pushes the joint along its velocity",
                  "friction": "a negative friction pushes the joint along its motion"}


def joint_dynamics_problem(attr: str, value: float) -> str | None:
    """Why ``value`` of a joint's ``<dynamics>`` attribute ``attr`` (``damping`` in
    [N m s/rad], ``friction`` in [N m]) is not physical, or None when it is."""
    if not math.isfinite(value):
        return f"{attr} {value} is not a finite number"
    if value < 0.0:
        return (f"must be at least 0 ({_DYNAMICS_SIGN[attr]}: a plant that creates energy; "
                "0 = none)")
    return None
