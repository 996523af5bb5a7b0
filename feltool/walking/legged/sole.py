r"""Several contact points of one rigid link (a flat sole's corners): is the link's contact
physical?

The stance dynamics give such points the least-norm forces (:mod:`.contact`), one of infinitely
many distributions that hold the link the same way: the link feels only their resultant wrench.
The link's contact is physical when **some** distribution of that wrench over its points has
every point pushing and inside its friction cone -- the contact wrench cone of a flat contact
(Caron, Pham and Nakamura, 2015) -- found as a linear program (``scipy.optimize.linprog``,
HiGHS):

.. math::

    \sum_i f_i = \sum_i \bar f_i, \quad \sum_i r_i \times f_i = \sum_i r_i \times \bar f_i,
    \quad A f_i \le 0, \quad f_{i,z} \ge f_{min},

:math:`\bar f_i` the given forces (or impulses), :math:`r_i` the points' positions relative to
their mean [m], :math:`A` the polyhedral cone inscribed in the circular one of :math:`\mu`
(:func:`polygon_cone`), and the normal-force floor :math:`f_{min}` [N]. The distribution
found maximises the smallest margin of the forces from their cones' faces and floors, so a
feasible wrench is reported with the distribution that keeps the link's points furthest from
pulling and slipping.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog


def polygon_cone(n: int, friction: float, faces: int = 8) -> np.ndarray:
    """``A`` ``(n (F + 1), 3 n)`` with ``A iota <= 0`` the ``n`` feet's friction cones inscribed
    in the circular cone of :math:`\\mu` = ``friction`` (``faces`` planes, then
    ``-iota_z <= 0``); an infinite ``friction`` keeps only ``-iota_z <= 0``."""
    if not np.isfinite(friction):
        return np.kron(np.eye(n), np.array([[0.0, 0.0, -1.0]]))
    theta = 2.0 * np.pi * np.arange(faces) / faces
    rows = np.column_stack([np.cos(theta), np.sin(theta),
                            -friction * np.cos(np.pi / faces) * np.ones(faces)])
    rows = np.vstack([rows, [0.0, 0.0, -1.0]])
    return np.kron(np.eye(n), rows)


def spread(points: np.ndarray, forces: np.ndarray, friction: float, floor: float = 0.0,
           faces: int = 8) -> np.ndarray | None:
    """A distribution ``(n, 3)`` of the resultant wrench of ``forces`` ``(n, 3)`` over the
    ``points`` ``(n, 3)`` [m] of one link inside their friction cones (:math:`\\mu` =
    ``friction``) with normal forces at least ``floor``, or None when there is none."""
    points, forces = np.asarray(points, float), np.asarray(forces, float)
    n = len(points)
    r = points - points.mean(axis=0)
    cross = np.hstack([np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
                       for p in r])
    A_eq = np.vstack([np.tile(np.eye(3), n), cross])
    b_eq = A_eq @ forces.ravel()
    # variables (f, s): maximise the margin s of every force from its cone's faces and of
    # every normal force over the floor
    cone = polygon_cone(n, friction if np.isfinite(friction) else 1e3, faces)
    normal = np.kron(np.eye(n), np.array([[0.0, 0.0, -1.0]]))
    A_ub = np.vstack([np.hstack([cone, np.ones((len(cone), 1))]),
                      np.hstack([normal, np.ones((n, 1))])])
    b_ub = np.r_[np.zeros(len(cone)), -floor * np.ones(n)]
    scale = max(float(np.abs(forces).max(initial=0.0)), 1e-300)
    res = linprog(np.r_[np.zeros(3 * n), -1.0], A_ub=A_ub, b_ub=b_ub / scale,
                  A_eq=np.hstack([A_eq, np.zeros((6, 1))]), b_eq=b_eq / scale,
                  bounds=[(None, None)] * (3 * n) + [(None, 1.0)], method="highs")
    if res.status != 0 or res.x[-1] <= 0.0:
        return None
    return res.x[:-1].reshape(n, 3) * scale


def inside(forces: np.ndarray, friction: float, floor: float = 0.0) -> np.ndarray:
    r"""``(n,)``: each force ``(n, 3)`` pushing more than ``floor`` and inside the polyhedral
    cone (:func:`polygon_cone`) of :math:`\mu` = ``friction``."""
    forces = np.asarray(forces, float).reshape(-1, 3)
    n = len(forces)
    if n == 0:
        return np.zeros(0, bool)
    faces = (polygon_cone(n, friction) @ forces.ravel()).reshape(n, -1)
    return (forces[:, 2] > floor) & (faces.max(axis=1) <= 0.0)


def distribute(links: list[int], points: np.ndarray, forces: np.ndarray, friction: float,
               floor: float = 0.0) -> np.ndarray:
    """The ``forces`` ``(n, 3)`` with those of every link carrying several points, where any
    of them leaves its cone or pulls, replaced by a distribution inside the cones
    (:func:`spread`) when there is one (the link's contact is then physical; else they are
    returned as they are, for the point checks to report)."""
    out = np.array(forces, float)
    ok = inside(out, friction, floor)
    links = np.asarray(links)
    for link in set(links[~ok].tolist()):
        idx = np.flatnonzero(links == link)
        if len(idx) < 2:
            continue
        f = spread(points[idx], out[idx], friction, floor)
        if f is not None:
            out[idx] = f
    return out
