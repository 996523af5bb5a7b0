"""Reading a URDF: parsed and validated by yourdfpy, its physics checked, common dialects read.

:func:`read_urdf` turns URDF text into the *validated description* that Pinocchio builds the
model and its visuals from (:mod:`feltool.robot.robot`). Every problem names the element it is in.

1. The XML is well formed (Python's expat parser, which also bounds entity expansion), has at
   most :data:`~feltool.bounds.MAX_URDF_LINKS` links, and every number in it is finite
   (yourdfpy reads ``nan`` and ``inf`` as numbers).
2. yourdfpy parses it and validates every ``<link>`` and ``<joint>``: required names and
   attributes, joint types, ``<limit>`` where the type needs one, one shape per geometry.
3. The joints join the links into one tree (yourdfpy leaves references unchecked): every
   parent and child is a link, no link has two parents, no cycle, one root.
4. The physics is one a real robot can have (:mod:`feltool.robot.physical`): masses >= 0, inertias
   positive semi-definite and obeying the triangle inequality, non-zero joint axes, effort and
   velocity limits >= 0, ``<dynamics>`` damping and friction >= 0, mass on every moving body.
5. Every mesh file exists inside the URDF's folder or a package directory (``package://``
   resolved against those and example-robot-data's); the description names it by its
   absolute path, so Pinocchio, the viewer and the checks read the same file.

Dialects of other toolchains (Drake, Gazebo, the walking literature) that Pinocchio's parser
refuses are read when ``lenient`` (the default) and said in :attr:`UrdfDescription.warnings`;
with ``lenient=False`` each is an error naming the element:

* ``world`` as the root's parent without a ``<link name="world">``: the link is added (the
  fixed world frame);
* an ``<inertial>`` without ``<inertia>``: a point mass, zero rotational inertia (one warning
  per link);
* a revolute or prismatic joint without ``<limit>`` (or a ``<limit>`` without some of its
  attributes): unbounded in what is missing, :math:`\\pm\\infty` in the model (one warning);
* a planar model's inertia, one moment alone (``ixx="0" iyy="1.33" izz="0"``, which no rigid
  body has): the other two moments read as half of it, which motion in the plane does not feel
  (one warning per link);
* a ``<material>`` without a name (which Pinocchio's parser drops with the whole visual): named
  after its link.
"""

from __future__ import annotations

import io
import logging
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from feltool.bounds import MAX_URDF_LINKS
from feltool.errors import RobotError
from feltool.robot.deferred import yourdfpy
from feltool.robot.physical import inertia_problem, joint_dynamics_problem, mass_problem

WORLD = "world"

#: Numeric attributes of URDF elements (inside a <link> or <joint>), each a list of numbers.
_NUMERIC = {
    "origin": ("xyz", "rpy"), "axis": ("xyz",), "mass": ("value",),
    "inertia": ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
    "limit": ("lower", "upper", "effort", "velocity"), "dynamics": ("damping", "friction"),
    "safety_controller": ("soft_lower_limit", "soft_upper_limit", "k_position", "k_velocity"),
    "calibration": ("rising", "falling"), "mimic": ("multiplier", "offset"),
    "box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",), "mesh": ("scale",),
}
_LIMIT_KINDS = {"position": ("lower", "upper"), "effort": ("effort",),
                "velocity": ("velocity",)}


@dataclass
class UrdfDescription:
    """A validated URDF.

    Attributes:
        xml: The description Pinocchio builds from (dialects normalised, mesh paths absolute).
        warnings: One line per dialect element read leniently (empty in strict mode).
        unbounded: Joint name -> the limits its URDF does not give (``position``, ``effort``,
            ``velocity``): infinite in the model.
    """

    xml: str
    warnings: list[str] = field(default_factory=list)
    unbounded: dict[str, list[str]] = field(default_factory=dict)


def read_urdf(text: str, where: str, base: Path, package_dirs: list[str],
              lenient: bool = True) -> UrdfDescription:
    """Parse, validate and normalise URDF text.

    Args:
        text: The URDF (expanded: no xacro).
        where: How messages name the source (the file path).
        base: Folder that relative mesh paths resolve against (the URDF's).
        package_dirs: Folders for ``package://`` paths (example-robot-data's are added).
        lenient: Read the dialects above (True) or refuse them (False).

    Raises:
        RobotError: one message naming the file and the element.
    """
    dirs = list(package_dirs) + erd_package_dirs()
    urdf = _parse_yourdfpy(_parse_xml(text, where), where,
                           lambda name: str(resolve_mesh(name, base, dirs) or name))
    dialects = _dialects(urdf)
    if dialects and not lenient:
        raise RobotError(f"{where}: {dialects[0].element}: {dialects[0].problem} "
                         "(refused: robot.lenient is false)")
    unbounded = {d.joint: d.missing for d in dialects if d.missing}
    warnings = [f"{where}: {d.element}: {d.problem}" for d in dialects if not d.missing]
    if unbounded:
        listing = ", ".join(f"{j} ({', '.join(k)})" for j, k in unbounded.items())
        warnings.append(f"{where}: joints without limits, read as unbounded: {listing}")
    _normalise(urdf, unbounded)
    _validate_elements(urdf, where)
    _check_tree(urdf, where)
    _check_physics(urdf, where)
    _check_meshes(urdf, where, base, dirs)
    return UrdfDescription(urdf.write_xml_string().decode("utf-8"), warnings, unbounded)


# -- 1. XML ---------------------------------------------------------------------------------------

def _parse_xml(text: str, where: str) -> ET.Element:
    """Well-formed XML with a <robot> root, at most MAX_URDF_LINKS links, finite numbers, and
    the names and references yourdfpy's parser needs."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        line, col = exc.position
        raise RobotError(f"{where}:{line}:{col}: URDF is not well-formed XML ({exc})") from None
    if root.tag != "robot":
        raise RobotError(f"{where}: root element is <{root.tag}>, a URDF needs <robot>")
    links = root.findall("link")
    if not links:
        raise RobotError(f"{where}: <robot> has no <link> elements")
    if len(links) > MAX_URDF_LINKS:
        raise RobotError(f"{where}: <robot> has {len(links)} links; feltool loads at most "
                         f"{MAX_URDF_LINKS} (a real robot has a few dozen)")
    for i, el in enumerate(links + root.findall("joint")):
        if not el.get("name"):
            raise RobotError(f"{where}: a <{el.tag}> (number {i + 1}) has no name")
    for joint in root.findall("joint"):
        for tag in ("parent", "child"):
            ref = joint.find(tag)
            if ref is None or not ref.get("link"):
                raise RobotError(f"{where}: {_name(joint)} has no <{tag} link=\"...\">")
    for owner in links + root.findall("joint"):
        for el in owner.iter():
            for attr in _NUMERIC.get(el.tag, ()):
                _numbers(owner, el, attr, where)
        inertia = owner.find("inertial/inertia")
        missing = [a for a in _NUMERIC["inertia"] if inertia is not None and inertia.get(a) is None]
        if missing:
            raise RobotError(f"{where}: {_name(owner)} <inertia> lacks {', '.join(missing)} "
                             "(a URDF gives all six entries)")
    return root


def _name(element) -> str:
    return f"<{element.tag} name=\"{element.get('name')}\">"


def _numbers(owner, el, attr: str, where: str) -> list[float] | None:
    text = el.get(attr)
    if text is None:
        return None
    try:
        values = [float(x) for x in text.replace(",", " ").split()]
    except ValueError:
        raise RobotError(f"{where}: {_name(owner)} <{el.tag} {attr}=\"{text}\">: not a number"
                         ) from None
    if not all(np.isfinite(values)):
        raise RobotError(f"{where}: {_name(owner)} <{el.tag} {attr}=\"{text}\">: not a finite "
                         "number (NaN and infinity are not physical values)")
    return values


# -- 2. yourdfpy ----------------------------------------------------------------------------------

def _parse_yourdfpy(root: ET.Element, where: str, resolve) -> yourdfpy.URDF:
    """The yourdfpy model of the (already parsed, entity-free) XML; meshes are not loaded, and
    ``resolve`` maps a mesh reference to the file the written description names."""
    xml = ET.tostring(root, encoding="unicode").encode("utf-8")
    logging.getLogger("yourdfpy").setLevel(logging.ERROR)
    try:
        return yourdfpy.URDF.load(io.BytesIO(xml), build_scene_graph=False, load_meshes=False,
                                  filename_handler=resolve)
    except Exception as exc:  # yourdfpy raises plain KeyError/IndexError/ValueError
        raise RobotError(f"{where}: yourdfpy cannot read the URDF "
                         f"({type(exc).__name__}: {exc})") from None


def _validate_elements(urdf: yourdfpy.URDF, where: str) -> None:
    """yourdfpy's validation, element by element, so that its messages name the element."""
    for kind in ("links", "joints"):
        for item in getattr(urdf.robot, kind):
            probe = yourdfpy.URDF(yourdfpy.Robot(name=urdf.robot.name, **{kind: [item]}),
                                  build_scene_graph=False, load_meshes=False)
            try:
                problems = [] if probe.validate() else [e.msg for e in probe.errors]
            except Exception as exc:  # yourdfpy's validation fails on what it cannot read
                problems = [f"{type(exc).__name__}: {exc}"]
            if problems:
                raise RobotError(f"{where}: <{kind[:-1]} name=\"{item.name}\">: "
                                 + "; ".join(problems))


# -- dialects -------------------------------------------------------------------------------------

@dataclass
class _Dialect:
    """An element Pinocchio's parser refuses that lenient reading accepts."""

    element: str
    problem: str
    joint: str = ""
    missing: list[str] = field(default_factory=list)  # limits the joint does not give


def _dialects(urdf: yourdfpy.URDF) -> list[_Dialect]:
    """Every dialect element of the URDF, in document order of its kind."""
    found = []
    if WORLD not in urdf.link_map:
        found += [_Dialect(f"<joint name=\"{j.name}\">", f"parent link '{WORLD}' is no <link> "
                           "of the URDF; read as the fixed world frame")
                  for j in urdf.robot.joints if j.parent == WORLD]
    for link in urdf.robot.links:
        if link.inertial is not None and link.inertial.inertia is None:
            found.append(_Dialect(f"<link name=\"{link.name}\">", f"<inertial> has a mass "
                                  f"({link.inertial.mass or 0.0:g} kg) but no <inertia>; read "
                                  "as a point mass (zero rotational inertia)"))
        elif link.inertial is not None and _planar_axis(link.inertial.inertia) is not None:
            axis = "xyz"[_planar_axis(link.inertial.inertia)]
            found.append(_Dialect(f"<link name=\"{link.name}\"> <inertial> <inertia>", "a "
                                  f"planar model's inertia (only i{axis}{axis}, the moment about "
                                  "the plane's normal); the other two moments read as half of "
                                  f"it, which a plane's motion does not feel (only i{axis}{axis} "
                                  "acts in it)"))
        for i, visual in enumerate(link.visuals or []):
            if visual.material is not None and not visual.material.name:
                found.append(_Dialect(f"<link name=\"{link.name}\"> <visual> <material>", "a "
                                      f"material without a name; named '{link.name}_{i}' (the "
                                      "URDF parser needs one)"))
    for joint in urdf.robot.joints:
        if joint.type not in ("revolute", "prismatic") and \
                (joint.type != "continuous" or joint.limit is None):
            continue  # a continuous joint needs no <limit>, nor position limits in one
        limit = joint.limit or yourdfpy.Limit()
        missing = [k for k, attrs in _LIMIT_KINDS.items()
                   if any(getattr(limit, a) is None for a in attrs)
                   and (k != "position" or joint.type != "continuous")]
        if missing:
            what = "no <limit>" if joint.limit is None else \
                f"<limit> without {', '.join(missing)}"
            found.append(_Dialect(f"<joint name=\"{joint.name}\">", f"{joint.type} joint with "
                                  f"{what}; read as unbounded", joint.name, missing))
    return found


def _planar_axis(inertia) -> int | None:
    """The axis of a planar model's inertia: one positive diagonal moment, the rest zero (as
    planar walkers are published, e.g. ``ixx="0" iyy="1.33" izz="0"``: not a rigid body's,
    which the triangle inequality refuses); else None."""
    if inertia is None:
        return None
    I = np.asarray(inertia, dtype=float)  # noqa: E741
    diag = np.diag(I)
    if I.shape != (3, 3) or np.any(I - np.diag(diag)) or np.count_nonzero(diag) != 1:
        return None
    axis = int(np.flatnonzero(diag)[0])
    return axis if diag[axis] > 0.0 else None


def _normalise(urdf: yourdfpy.URDF, unbounded: dict[str, list[str]]) -> None:
    """Write the dialects as Pinocchio's parser reads them: the world link, zero inertias of
    point masses, and 0 for missing limits (the model's are then set to infinity)."""
    if WORLD not in urdf.link_map and any(j.parent == WORLD for j in urdf.robot.joints):
        urdf.robot.links.append(yourdfpy.Link(name=WORLD))
        urdf.link_map[WORLD] = urdf.robot.links[-1]
    for link in urdf.robot.links:
        if link.inertial is not None and link.inertial.inertia is None:
            link.inertial.inertia = np.zeros((3, 3))
        elif link.inertial is not None and (axis := _planar_axis(link.inertial.inertia)) is not None:
            moment = float(link.inertial.inertia[axis, axis])
            link.inertial.inertia = np.diag([moment / 2.0] * 3)
            link.inertial.inertia[axis, axis] = moment
        for i, visual in enumerate(link.visuals or []):
            if visual.material is not None and not visual.material.name:
                visual.material.name = f"{link.name}_{i}"
    for name in unbounded:
        joint = urdf.joint_map[name]
        joint.limit = joint.limit or yourdfpy.Limit()
        for attr in ("lower", "upper", "effort", "velocity"):
            if getattr(joint.limit, attr) is None:
                setattr(joint.limit, attr, 0.0)


# -- 3. tree --------------------------------------------------------------------------------------

def _check_tree(urdf: yourdfpy.URDF, where: str) -> None:
    """Every joint joins two links, each link has at most one parent, the links form one tree
    (iteratively: a long chain must not exhaust Python's recursion)."""
    parent_of: dict[str, yourdfpy.Joint] = {}
    for joint in urdf.robot.joints:
        for tag in ("parent", "child"):
            if getattr(joint, tag) not in urdf.link_map:
                raise RobotError(f"{where}: <joint name=\"{joint.name}\"> refers to {tag} link "
                                 f"'{getattr(joint, tag)}', which is not a <link> of the URDF")
        if joint.child in parent_of:
            raise RobotError(f"{where}: <link name=\"{joint.child}\"> is the child of two "
                             f"joints ('{parent_of[joint.child].name}' and '{joint.name}'); a "
                             "URDF must be a tree")
        parent_of[joint.child] = joint
    for start in parent_of:
        seen, link = {start}, start
        while link in parent_of:
            link = parent_of[link].parent
            if link in seen:
                raise RobotError(f"{where}: the joints form a cycle through <link name=\"{link}\">"
                                 "; a URDF must be a tree")
            seen.add(link)
    roots = [link.name for link in urdf.robot.links if link.name not in parent_of]
    if len(roots) > 1:
        raise RobotError(f"{where}: the links form {len(roots)} separate trees (roots "
                         f"{', '.join(roots[:5])}); a URDF must be one tree")


# -- 4. physics -----------------------------------------------------------------------------------

def _check_physics(urdf: yourdfpy.URDF, where: str) -> None:
    """Masses, inertias (:mod:`feltool.robot.physical`), joint axes, limits and damping and
    friction that a real robot can have, and mass on every body a joint moves; each problem
    names the element."""
    for link in urdf.robot.links:
        inertial = link.inertial
        if inertial is None:
            continue
        problem = mass_problem(float(inertial.mass or 0.0), allow_zero=True)
        if problem:
            raise RobotError(f"{where}: <link name=\"{link.name}\"> <inertial>: {problem}")
        I = inertial.inertia  # noqa: E741
        problem = inertia_problem([I[0, 0], I[0, 1], I[0, 2], I[1, 1], I[1, 2], I[2, 2]])
        if problem:
            raise RobotError(f"{where}: <link name=\"{link.name}\"> <inertial> <inertia>: "
                             f"{problem}")
    for joint in urdf.robot.joints:
        owner = f"<joint name=\"{joint.name}\">"
        if joint.type in ("revolute", "continuous", "prismatic"):
            if len(joint.axis) != 3:
                raise RobotError(f"{where}: {owner} <axis>: needs xyz with 3 numbers")
            if float(np.linalg.norm(joint.axis)) < 1e-12:
                raise RobotError(f"{where}: {owner} <axis xyz=\"{_fmt(joint.axis)}\">: the "
                                 "zero vector is no axis (a non-unit axis is normalised, as "
                                 "Pinocchio does)")
        for attr in ("effort", "velocity"):
            value = None if joint.limit is None else getattr(joint.limit, attr)
            if value is not None and value < 0:
                raise RobotError(f"{where}: {owner} <limit {attr}=\"{value:g}\">: must be at "
                                 "least 0 (0 = no limit)")
        for attr in ("damping", "friction"):
            value = None if joint.dynamics is None else getattr(joint.dynamics, attr)
            value = None if value is None else float(value)  # yourdfpy keeps the text
            problem = None if value is None else joint_dynamics_problem(attr, value)
            if problem:
                raise RobotError(f"{where}: {owner} <dynamics {attr}=\"{value:g}\">: {problem}")
    _check_moving_bodies_have_mass(urdf, where)


def _fmt(values) -> str:
    return " ".join(f"{float(v):g}" for v in values)


def _check_moving_bodies_have_mass(urdf: yourdfpy.URDF, where: str) -> None:
    """The body a joint moves (its child link, everything welded to it, or anything further
    out) carries mass: otherwise forward dynamics is singular."""
    children: dict[str, list[str]] = {}
    for joint in urdf.robot.joints:
        children.setdefault(joint.parent, []).append(joint.child)

    def mass(link: str) -> float:
        inertial = urdf.link_map[link].inertial
        return float(inertial.mass or 0.0) if inertial is not None else 0.0

    for joint in urdf.robot.joints:
        if joint.type == "fixed":
            continue
        stack, carried = [joint.child], 0.0
        while stack and carried <= 0.0:
            link = stack.pop()
            carried += mass(link)
            stack += children.get(link, [])
        if carried <= 0.0:
            raise RobotError(
                f"{where}: <link name=\"{joint.child}\"> (moved by <joint name=\"{joint.name}\">) "
                "has no <inertial> mass, and nothing it carries has any: its joint would have "
                "no inertia and forward dynamics would be singular")


# -- 5. meshes ------------------------------------------------------------------------------------

def erd_package_dirs() -> list[str]:
    """example-robot-data's folders, for ``package://example-robot-data/...`` and
    ``package://<robot>_description/...`` paths (empty when the package is missing)."""
    try:
        import example_robot_data as erd
    except ImportError:  # pragma: no cover - a declared dependency
        return []
    robots = Path(erd.getModelPath("ur_description/urdf/ur5_robot.urdf")).resolve()
    return [str(robots.parent), str(robots)]


def _mesh_candidates(filename: str, base: Path,
                     package_dirs: list[str]) -> list[tuple[Path, list[Path]]]:
    """Files a mesh reference may mean, each with the folders it must stay inside."""
    roots = [Path(base)] + [Path(d) for d in package_dirs]
    if filename.startswith("package://"):
        rest = filename[len("package://"):].lstrip("/")
        package, _, inner = rest.partition("/")
        out = []
        for d in map(Path, package_dirs):
            out += [(d / rest, [d]), (d / inner, [d]), (d.parent / rest, [d.parent / package])]
        return out
    if filename.startswith("file://"):
        return [(Path(filename[len("file://"):]), roots)]
    return [(Path(base) / filename, roots)]


def _inside(path: Path, roots: list[Path]) -> bool:
    """Whether ``path`` lies inside one of ``roots``, judged on the normalised path text (so a
    ``../`` cannot climb out, while a symbolic link inside a root stays allowed)."""
    target = os.path.normpath(os.path.abspath(path))
    for root in roots:
        top = os.path.normpath(os.path.abspath(root))
        if target == top or target.startswith(top.rstrip(os.sep) + os.sep):
            return True
    return False


def resolve_mesh(filename: str, base: Path, package_dirs: list[str]) -> Path | None:
    """The file a URDF mesh reference points to (``package://``, ``file://``, relative to the
    URDF, or absolute), as an absolute path, or None when it does not exist or lies outside
    the URDF's folder and the package dirs."""
    found = next((c for c, roots in _mesh_candidates(filename, base, package_dirs)
                  if c.is_file() and _inside(c, roots)), None)
    return None if found is None else Path(os.path.abspath(found))


def _check_meshes(urdf: yourdfpy.URDF, where: str, base: Path, package_dirs: list[str]) -> None:
    """Every mesh file exists and lies inside the URDF's folder or a package dir: a path that
    climbs out (``../../elsewhere``) is refused, so a URDF cannot make feltool (or the mesh
    loader behind the viewer) read arbitrary files."""
    for link in urdf.robot.links:
        for kind, elements in (("visual", link.visuals), ("collision", link.collisions)):
            for element in elements:
                mesh = element.geometry.mesh if element.geometry is not None else None
                if mesh is None or resolve_mesh(mesh.filename or "", base, package_dirs):
                    continue
                filename = mesh.filename or ""
                owner = f"{where}: <link name=\"{link.name}\"> <{kind}> mesh '{filename}'"
                if any(not _inside(c, roots)
                       for c, roots in _mesh_candidates(filename, base, package_dirs)):
                    raise RobotError(f"{owner} lies outside the URDF's folder "
                                     f"{os.path.abspath(base)} and the package dirs "
                                     f"{[d for d in package_dirs if d != str(base)]}; refusing "
                                     "to read it (put the mesh there, or add its folder to "
                                     "package_dirs)")
                raise RobotError(f"{owner} not found (looked relative to {base} and in package "
                                 f"dirs {package_dirs})")
