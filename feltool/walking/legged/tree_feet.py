"""A quadruped's feet found from its kinematic tree, for a URDF or example-robot-data robot that
does not name them (no ``walking.feet``, no SRDF end effectors).

A foot is the end of a leg: a chain of at least three joints from the base to a leaf of the tree
(a joint no other joint hangs from), its point the frame on that leaf's body farthest from the
leaf joint (a URDF's foot link fixed below the shank, as published quadrupeds have it; a shank
with no foot frame has none, its frame sits on the knee). Of those, the feet are the ones at
the bottom of the robot in its reference posture (within :data:`LOW` of the robot's height
above the lowest one: not an arm or a head). Four feet are named by where they are in the
base's frame: the two ahead (larger x) front, the two behind hind, each pair's one at larger y
left.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.errors import ConfigError

#: A leg's end counts as a foot when it is within this fraction of the base's height above the
#: lowest leg end, in the reference posture [-]
LOW = 0.1


def leg_joints(model: pin.Model, joint: int) -> list[int]:
    """The joints from the base (joint 1, the free flyer, not included) to ``joint``, base
    first: a leg, when ``joint`` is its last."""
    out = []
    while joint > 1:
        out.append(joint)
        joint = model.parents[joint]
    return out[::-1]


def leg_ends(model: pin.Model, q: np.ndarray) -> list[tuple[str, np.ndarray, int]]:
    """``(frame name, position in the world [m] at q, joints from the base)`` for every leaf
    joint's farthest frame (a point beyond the leaf joint's origin) of a free-flyer ``model``."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    has_child = {model.parents[j] for j in range(2, model.njoints)}
    ends = []
    for j in range(2, model.njoints):
        if j in has_child:
            continue
        frames = [i for i, f in enumerate(model.frames) if f.parentJoint == j]
        reach = [np.linalg.norm(model.frames[i].placement.translation) for i in frames]
        if not frames or max(reach) < 1e-9:
            continue
        best = frames[int(np.argmax(reach))]
        ends.append((model.frames[best].name, data.oMf[best].translation.copy(),
                     len(leg_joints(model, j))))
    return ends


def quadruped_feet(model: pin.Model, q: np.ndarray, name: str) -> dict[str, dict]:
    """``{FL, FR, HL, HR: {"frame": NAME}}``: the four feet of the free-flyer ``model`` in the
    reference configuration ``q`` (``(nq,)``; module docstring). Raises :class:`ConfigError`
    naming ``walking.feet`` when the tree does not end in exactly four feet, front and hind,
    left and right."""
    legs = [(f, p) for f, p, depth in leg_ends(model, q) if depth >= 3]
    if legs:
        low = min(p[2] for _, p in legs)
        reach = max(q[2] - low, 1e-9)
        legs = [(f, p) for f, p in legs if p[2] <= low + LOW * reach]
    found = ", ".join(f for f, _ in legs) or "none"
    if len(legs) != 4:
        raise ConfigError([("walking.feet", f"required: {name} names no feet (walking.feet, "
                                            "SRDF end effectors lf_*, rf_*, lh_*, rh_*) and "
                                            f"its tree ends in {len(legs)} at the bottom of legs of three or "
                                            f"more joints ({found}), not a quadruped's four; "
                                            "give FL, FR, HL, HR")])
    base = pin.XYZQUATToSE3(q[:7])
    local = {f: base.rotation.T @ (p - base.translation) for f, p in legs}
    order = sorted(local, key=lambda f: -local[f][0])
    front, hind = order[:2], order[2:]
    feet = {}
    for pair, (left, right) in ((front, ("FL", "FR")), (hind, ("HL", "HR"))):
        a, b = sorted(pair, key=lambda f: -local[f][1])
        feet[left], feet[right] = a, b
    ahead = min(local[f][0] for f in front) > max(local[f][0] for f in hind)
    sides = all(local[feet[f]][1] > 0 for f in ("FL", "HL")) and \
        all(local[feet[f]][1] < 0 for f in ("FR", "HR"))
    if not (ahead and sides):
        raise ConfigError([("walking.feet", f"required: {name}'s four leg ends ({found}) are not "
                                            "two ahead of two, each pair left and right of the "
                                            "base's x axis; give FL, FR, HL, HR")])
    return {f: {"frame": feet[f]} for f in ("FL", "FR", "HL", "HR")}
