r"""A URDF's kinematic tree re-rooted at another link (a walker published rooted at a foot).

The joints on the path from the old root to the new one are reversed: a joint from ``P`` to
``C`` (``F_C = F_P T R(a, q)``) becomes one from ``C`` to ``P`` about the same axis, with the
negated coordinate (``q' = -q``, limits ``[-hi, -lo]``). Each link ``L`` on the path gets a new
frame :math:`F'_L = F_L S_L`, ``S_L`` the origin of the joint that led from ``L`` towards the new
root (the identity for the new root): its inertial, visuals and collisions, the origins of its
other joints and the reversed joint that now leads from it are re-expressed in it
(:math:`X' = S_L^{-1} X`), and the reversed joint's origin is :math:`S_L^{-1}`. Every body keeps
its mass, inertia and place in space: the model's dynamics are the same, in other coordinates.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

from feltool.errors import RobotError


def _origin(el) -> pin.SE3:
    o = el.find("origin") if el is not None else None
    if o is None:
        return pin.SE3.Identity()
    xyz = np.array([float(x) for x in o.get("xyz", "0 0 0").split()])
    rpy = np.array([float(x) for x in o.get("rpy", "0 0 0").split()])
    return pin.SE3(pin.rpy.rpyToMatrix(rpy), xyz)


def _set_origin(el, placement: pin.SE3) -> None:
    o = el.find("origin")
    if o is None:
        o = ET.Element("origin")
        el.insert(0, o)
    o.set("xyz", " ".join(repr(float(x)) for x in placement.translation))
    o.set("rpy", " ".join(repr(float(x)) for x in pin.rpy.matrixToRpy(placement.rotation)))


def reroot_urdf(xml: str, root: str) -> tuple[str, dict[str, pin.SE3], list[str]]:
    """``xml`` with its tree rooted at the link ``root``.

    Returns:
        The new URDF text; per link whose frame moved, ``S_L`` (a point ``p`` in the link's old
        frame is ``S_L^{-1} p`` in its new one); the reversed joints (their coordinates are the
        negatives of the URDF's).

    Raises:
        RobotError: ``root`` is not a link, or a joint on the path is not revolute,
            continuous or prismatic.
    """
    tree = ET.fromstring(xml)
    links = {lk.get("name"): lk for lk in tree.findall("link")}
    if root not in links:
        raise RobotError(f"cannot re-root the URDF at '{root}': no such link")
    joints = tree.findall("joint")
    parent_joint = {j.find("child").get("link"): j for j in joints}
    path, link = [], root  # the joints from the new root up to the old one
    while link in parent_joint:
        j = parent_joint[link]
        path.append(j)
        link = j.find("parent").get("link")
    shift: dict[str, pin.SE3] = {}
    reversed_names = []
    below = root  # the link the next reversed joint leads from (its new parent)
    shift[root] = pin.SE3.Identity()
    for j in path:
        kind = j.get("type")
        if kind not in ("revolute", "continuous", "prismatic", "fixed"):
            raise RobotError(f"cannot re-root the URDF at '{root}': joint '{j.get('name')}' on "
                             f"the way to the root is of type '{kind}'")
        old_parent = j.find("parent").get("link")
        shift[old_parent] = _origin(j)  # S of the link above: the joint that led from it down
        j.find("parent").set("link", below)
        j.find("child").set("link", old_parent)
        _set_origin(j, shift[below].inverse())
        limit = j.find("limit")
        if limit is not None and kind != "fixed":
            lo, hi = limit.get("lower"), limit.get("upper")
            if lo is not None:
                limit.set("upper", repr(-float(lo)))
            if hi is not None:
                limit.set("lower", repr(-float(hi)))
        if kind != "fixed":
            reversed_names.append(j.get("name"))
        below = old_parent
    # the joint's new axis is the old one: a coordinate q' = -q (the rotation R(a, -q) reversed)
    on_path = {id(j) for j in path}
    for name, S in shift.items():
        if name == root:
            continue
        inv = S.inverse()
        lk = links[name]
        for el in [*lk.findall("inertial"), *lk.findall("visual"), *lk.findall("collision")]:
            _set_origin(el, inv * _origin(el))
        for j in joints:
            if id(j) not in on_path and j.find("parent").get("link") == name:
                _set_origin(j, inv * _origin(j))
    moved = {name: S for name, S in shift.items() if name != root}
    return ET.tostring(tree, encoding="unicode"), moved, reversed_names
