"""Loading robots: bundled names, URDF files and ``example-robot-data:NAME``.

This module is the one place that builds Pinocchio models. A :class:`Robot` couples the model with
where it came from and the joint-name bookkeeping the rest of feltool needs.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.bounds import MAX_URDF_BYTES, MAX_URDF_LINKS
from feltool.errors import RobotError
from feltool.physical import inertia_problem, mass_problem

ERD_PREFIX = "example-robot-data:"


def data_dir(kind: str) -> Path:
    """Directory of bundled ``robots`` or ``configs``: inside the installed wheel, or the checkout."""
    packaged = Path(__file__).parent / "_data" / kind
    if packaged.is_dir():
        return packaged
    return Path(__file__).resolve().parent.parent / kind


def bundled_robots() -> list[str]:
    """Names of the robots shipped with feltool."""
    return sorted(p.stem for p in data_dir("robots").glob("*.urdf"))


def erd_robots() -> list[str]:
    """Names ``example-robot-data`` knows (not all of them load; see :func:`load_robot`)."""
    try:
        import example_robot_data as erd
    except ImportError:  # pragma: no cover - a declared dependency
        return []
    return sorted(erd.robots_loader.ROBOTS)


@dataclass
class Robot:
    """A rigid-body model with its origin.

    Attributes:
        name: Display name (bundled name, URDF stem or example-robot-data name).
        model: The Pinocchio model (the known model of the robot).
        source: What the user wrote to get it (name, path or ``example-robot-data:NAME``).
        urdf_path: The URDF file, when there is one.
        package_dirs: Directories used to resolve ``package://`` mesh paths.
        visual_model: Pinocchio geometry model of the visuals, built lazily for viewers.
    """

    name: str
    model: pin.Model
    source: str
    urdf_path: Path | None = None
    package_dirs: list[str] = field(default_factory=list)
    _visual_model: pin.GeometryModel | None = None

    @property
    def joint_names(self) -> list[str]:
        """Names of the moving joints, in Pinocchio's order (the universe joint left out)."""
        return list(self.model.names)[1:]

    def joint_id(self, name: str) -> int:
        """Pinocchio joint id of a joint, with an error listing the joints the robot has."""
        if not self.model.existJointName(name):
            raise RobotError(
                f"robot '{self.name}' has no joint '{name}'; its joints are: "
                + ", ".join(self.joint_names)
            )
        return int(self.model.getJointId(name))

    def v_index(self, name: str) -> int:
        """Index of a one-degree-of-freedom joint in the velocity (and torque) vector."""
        jid = self.joint_id(name)
        if self.model.joints[jid].nv != 1:
            raise RobotError(f"joint '{name}' of robot '{self.name}' has "
                             f"{self.model.joints[jid].nv} degrees of freedom; feltool roles need "
                             "one (revolute or prismatic)")
        return int(self.model.joints[jid].idx_v)

    def q_index(self, name: str) -> int:
        """Index of a one-degree-of-freedom joint in the configuration vector."""
        self.v_index(name)
        return int(self.model.joints[self.joint_id(name)].idx_q)

    def set_gravity(self, gravity: float | list[float] | np.ndarray) -> None:
        """Set gravity: a magnitude in [m/s^2] along the world's -z, or a 3-vector in [m/s^2].

        This is the one place feltool changes gravity (Pinocchio's default is 9.81; the thesis
        uses 9.8).
        """
        g = np.asarray(gravity, dtype=float)
        vec = np.array([0.0, 0.0, -float(g)]) if g.ndim == 0 else g.reshape(3)
        self.model.gravity = pin.Motion(vec, np.zeros(3))

    @property
    def total_mass(self) -> float:
        """Sum of the link masses in [kg]."""
        return float(sum(inertia.mass for inertia in self.model.inertias))

    @property
    def visual_model(self) -> pin.GeometryModel:
        if self._visual_model is None:
            if self.urdf_path is None:
                raise RobotError(f"robot '{self.name}' has no URDF to take visuals from")
            self._visual_model = pin.buildGeomFromUrdf(
                self.model, str(self.urdf_path), pin.GeometryType.VISUAL,
                package_dirs=self.package_dirs)
        return self._visual_model


def load_robot(spec: str, base_dir: Path | None = None,
               package_dirs: list[str] | None = None) -> Robot:
    """Load a robot by bundled name, URDF path, or ``example-robot-data:NAME``.

    Args:
        spec: ``two_link_arm`` | ``path/to/robot.urdf`` | ``example-robot-data:ur5``.
        base_dir: Directory that relative URDF paths are resolved against (the config's).
        package_dirs: Extra directories for ``package://`` mesh paths (relative ones resolve
            against ``base_dir``).

    Raises:
        RobotError: naming the file and element when the robot cannot be loaded.
    """
    if spec.startswith(ERD_PREFIX):
        return _load_erd(spec[len(ERD_PREFIX):], spec)
    if spec.endswith(".urdf") or "/" in spec or "\\" in spec:
        path = Path(spec).expanduser()
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        dirs = [str(Path(d) if Path(d).is_absolute() or base_dir is None else base_dir / d)
                for d in (package_dirs or [])]
        return load_urdf(path, source=spec, package_dirs=dirs)
    bundled = data_dir("robots") / f"{spec}.urdf"
    if bundled.is_file():
        return load_urdf(bundled, source=spec, name=spec)
    raise RobotError(
        f"unknown robot '{spec}': not a bundled robot ({', '.join(bundled_robots())}), not a "
        f"path to a .urdf file, and not '{ERD_PREFIX}NAME'"
    )


def load_urdf(path: Path, source: str | None = None, name: str | None = None,
              package_dirs: list[str] | None = None) -> Robot:
    """Load a URDF file, checking it first so that problems name the file and the element."""
    path = Path(path)
    if not path.is_file():
        raise RobotError(f"URDF file not found: {path}")
    try:
        size = path.stat().st_size
        if size > MAX_URDF_BYTES:
            raise RobotError(f"{path}: the file has {size} bytes; a URDF may have at most "
                             f"{MAX_URDF_BYTES} (feltool's limit; meshes belong in their own "
                             "files)")
        text = path.read_text()
    except UnicodeDecodeError:
        raise RobotError(f"{path}: the file is binary (not UTF-8 text), not a URDF") from None
    except OSError as exc:
        raise RobotError(f"{path}: cannot read URDF ({exc})") from None
    if not text.strip():
        raise RobotError(f"{path}: the URDF file is empty")
    dirs = [str(path.parent)] + list(package_dirs or [])
    _check_urdf_xml(text, str(path), path.parent, dirs)
    try:
        model = pin.buildModelFromXML(text)
    except Exception as exc:  # Pinocchio raises ValueError/RuntimeError with its own text
        raise RobotError(f"{path}: Pinocchio could not build a model: {exc}") from None
    return Robot(name=name or path.stem, model=model, source=source or str(path),
                 urdf_path=path, package_dirs=dirs)


def load_urdf_string(text: str, name: str = "robot", package_dirs: list[str] | None = None,
                     base_dir: Path | None = None) -> Robot:
    """A robot from URDF text (already expanded: no xacro), with the same checks as a file;
    mesh paths resolve against ``base_dir`` (default: the current directory) and
    ``package_dirs``."""
    where = f"<URDF string '{name}'>"
    if not text.strip():
        raise RobotError(f"{where}: the URDF is empty")
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    dirs = [str(base)] + list(package_dirs or [])
    _check_urdf_xml(text, where, base, dirs)
    try:
        model = pin.buildModelFromXML(text)
    except Exception as exc:
        raise RobotError(f"{where}: Pinocchio could not build a model: {exc}") from None
    return Robot(name=name, model=model, source=where, urdf_path=None, package_dirs=dirs)


def _check_urdf_xml(text: str, where: str, base: Path | None = None,
                    package_dirs: list[str] | None = None) -> None:
    """Structural checks Pinocchio reports badly or not at all: well-formed XML, a tree of
    links (no dangling references, no second parent, no cycle), masses, existing mesh files."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        line, col = exc.position
        raise RobotError(f"{where}:{line}:{col}: URDF is not well-formed XML ({exc})") from None
    if root.tag != "robot":
        raise RobotError(f"{where}: root element is <{root.tag}>, a URDF needs <robot>")
    links = {link.get("name"): link for link in root.findall("link")}
    if not links:
        raise RobotError(f"{where}: <robot> has no <link> elements")
    if len(links) > MAX_URDF_LINKS:
        raise RobotError(f"{where}: <robot> has {len(links)} links; feltool loads at most "
                         f"{MAX_URDF_LINKS} (a real robot has a few dozen)")
    children: dict[str, list[tuple[str, str]]] = {}
    for joint in root.findall("joint"):
        jname = joint.get("name")
        for tag in ("parent", "child"):
            el = joint.find(tag)
            if el is None or el.get("link") not in links:
                ref = None if el is None else el.get("link")
                raise RobotError(f"{where}: <joint name=\"{jname}\"> refers to {tag} link "
                                 f"'{ref}', which is not a <link> of the URDF")
        children.setdefault(joint.find("parent").get("link"), []).append(
            (joint.find("child").get("link"), joint.get("type", "")))

    parent_of: dict[str, str] = {}
    for joint in root.findall("joint"):
        child = joint.find("child").get("link")
        if child in parent_of:
            raise RobotError(f"{where}: <link name=\"{child}\"> is the child of two joints "
                             f"('{parent_of[child]}' and '{joint.get('name')}'); a URDF must be "
                             "a tree")
        parent_of[child] = joint.get("name")
    parent_link = {j.find("child").get("link"): j.find("parent").get("link")
                   for j in root.findall("joint")}
    for start in parent_link:
        seen, link = {start}, start
        while link in parent_link:
            link = parent_link[link]
            if link in seen:
                raise RobotError(f"{where}: the joints form a cycle through <link name=\"{link}\">;"
                                 " a URDF must be a tree")
            seen.add(link)
    _check_numbers(root, where)
    _check_physics(root, where)
    if base is not None:
        _check_meshes(root, where, base, package_dirs or [])

    def link_mass(name: str) -> float:
        inertial = links[name].find("inertial")
        mass = None if inertial is None else inertial.find("mass")
        try:
            return 0.0 if mass is None else float(mass.get("value", "0"))
        except ValueError:
            raise RobotError(f"{where}: <link name=\"{name}\"> has a mass that is not a "
                             f"number: '{mass.get('value')}'") from None

    def body_mass(name: str) -> float:
        """Mass of a link and everything welded to it by fixed joints (iteratively: a long
        chain must not exhaust Python's recursion)."""
        total, stack = 0.0, [name]
        while stack:
            link = stack.pop()
            total += link_mass(link)
            stack += [c for c, t in children.get(link, []) if t == "fixed"]
        return total

    for joint in root.findall("joint"):
        if joint.get("type") in ("fixed", None):
            continue
        child = joint.find("child").get("link")
        if body_mass(child) <= 0.0 and not _subtree_has_mass(child, children, link_mass):
            raise RobotError(
                f"{where}: <link name=\"{child}\"> (moved by <joint name=\"{joint.get('name')}\">) "
                "has no <inertial> mass, and nothing it carries has any: its joint would have "
                "no inertia and forward dynamics would be singular"
            )


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
    URDF, or absolute), or None when it does not exist or lies outside the URDF's folder and
    the package dirs."""
    return next((c for c, roots in _mesh_candidates(filename, base, package_dirs)
                 if c.is_file() and _inside(c, roots)), None)


def _check_meshes(root, where: str, base: Path, package_dirs: list[str]) -> None:
    """Every mesh file exists and lies inside the URDF's folder or a package dir: a path that
    climbs out (``../../elsewhere``) is refused, so a URDF cannot make feltool (or the mesh
    loader behind the viewer) read arbitrary files."""
    for link in root.findall("link"):
        for kind in ("visual", "collision"):
            for element in link.findall(kind):
                mesh = element.find("geometry/mesh")
                if mesh is None:
                    continue
                filename = mesh.get("filename", "")
                if resolve_mesh(filename, base, package_dirs) is not None:
                    continue
                if any(not _inside(c, roots)
                       for c, roots in _mesh_candidates(filename, base, package_dirs)):
                    raise RobotError(f"{where}: <link name=\"{link.get('name')}\"> <{kind}> mesh "
                                     f"'{filename}' lies outside the URDF's folder "
                                     f"{os.path.abspath(base)} and the package dirs "
                                     f"{[d for d in package_dirs if d != str(base)]}; refusing "
                                     "to read it (put the mesh there, "
                                     "or add its folder to package_dirs)")
                raise RobotError(f"{where}: <link name=\"{link.get('name')}\"> <{kind}> mesh "
                                 f"'{filename}' not found (looked relative to {base} and in "
                                 f"package dirs {package_dirs})")


#: Numeric attributes of URDF elements (inside a <link> or <joint>), each a list of numbers.
_NUMERIC = {
    "origin": ("xyz", "rpy"), "axis": ("xyz",), "mass": ("value",),
    "inertia": ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
    "limit": ("lower", "upper", "effort", "velocity"), "dynamics": ("damping", "friction"),
    "safety_controller": ("soft_lower_limit", "soft_upper_limit", "k_position", "k_velocity"),
    "calibration": ("rising", "falling"), "mimic": ("multiplier", "offset"),
    "box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",), "mesh": ("scale",),
}


def _owner(element) -> str:
    return f"<{element.tag} name=\"{element.get('name')}\">"


def _numbers(owner, el, attr: str, where: str) -> list[float] | None:
    text = el.get(attr)
    if text is None:
        return None
    try:
        values = [float(x) for x in text.split()]
    except ValueError:
        raise RobotError(f"{where}: {_owner(owner)} <{el.tag} {attr}=\"{text}\">: not a number"
                         ) from None
    if not all(np.isfinite(values)):
        raise RobotError(f"{where}: {_owner(owner)} <{el.tag} {attr}=\"{text}\">: not a finite "
                         "number (NaN and infinity are not physical values)")
    return values


def _check_numbers(root, where: str) -> None:
    """Every number of every link and joint parses and is finite (urdfdom reads ``nan`` and
    ``inf`` in some places and not others)."""
    for owner in root.findall("link") + root.findall("joint"):
        for el in owner.iter():
            for attr in _NUMERIC.get(el.tag, ()):
                _numbers(owner, el, attr, where)


def _check_physics(root, where: str) -> None:
    """Masses, inertias (:mod:`feltool.physical`), joint axes and limits that a real robot can
    have; each problem names the element."""
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            continue
        mass = inertial.find("mass")
        if mass is not None:
            problem = mass_problem(float(mass.get("value", "0")), allow_zero=True)
            if problem:
                raise RobotError(f"{where}: {_owner(link)} <inertial>: {problem}")
        inertia = inertial.find("inertia")
        if inertia is not None:
            values = [float(inertia.get(k, "0")) for k in _NUMERIC["inertia"]]
            problem = inertia_problem(values)
            if problem:
                raise RobotError(f"{where}: {_owner(link)} <inertial> <inertia>: {problem}")
    for joint in root.findall("joint"):
        kind = joint.get("type")
        axis = joint.find("axis")
        if kind in ("revolute", "continuous", "prismatic") and axis is not None:
            xyz = _numbers(joint, axis, "xyz", where)
            if xyz is None or len(xyz) != 3:
                raise RobotError(f"{where}: {_owner(joint)} <axis>: needs xyz with 3 numbers")
            if float(np.linalg.norm(xyz)) < 1e-12:
                raise RobotError(f"{where}: {_owner(joint)} <axis xyz=\"{axis.get('xyz')}\">: "
                                 "the zero vector is no axis (a non-unit axis is normalised, as "
                                 "Pinocchio does)")
        limit = joint.find("limit")
        if limit is not None:
            for attr in ("effort", "velocity"):
                value = _numbers(joint, limit, attr, where)
                if value is not None and value[0] < 0:
                    raise RobotError(f"{where}: {_owner(joint)} <limit {attr}=\""
                                     f"{limit.get(attr)}\">: must be at least 0 (0 = no limit)")


def _subtree_has_mass(name, children, link_mass) -> bool:
    stack = [c for c, _ in children.get(name, [])]
    while stack:
        link = stack.pop()
        if link_mass(link) > 0:
            return True
        stack += [c for c, _ in children.get(link, [])]
    return False


def _load_erd(name: str, source: str) -> Robot:
    try:
        import example_robot_data as erd
    except ImportError:  # pragma: no cover - a declared dependency
        raise RobotError("example-robot-data robots need the package "
                         "'example-robot-data-loaders' (pip install example-robot-data-loaders)") from None
    known = erd_robots()
    if name not in known:
        raise RobotError(f"unknown example-robot-data robot '{name}'; known names: "
                         + ", ".join(known))
    try:
        loaded = erd.robots_loader.ROBOTS[name]()
    except Exception as exc:
        raise RobotError(f"example-robot-data robot '{name}' failed to load: {exc}") from None
    wrapper = loaded.robot
    urdf = Path(loaded.df_path).resolve() if getattr(loaded, "df_path", None) else None
    robot = Robot(name=name, model=wrapper.model, source=source, urdf_path=urdf,
                  package_dirs=[str(urdf.parent)] if urdf else [])
    robot._visual_model = wrapper.visual_model
    _check_model_numbers(robot.model, f"example-robot-data robot '{name}'")
    return robot


def _check_model_numbers(model: pin.Model, where: str) -> None:
    """Finite, non-negative masses and finite inertias of a model built elsewhere (the
    example-robot-data robots are taken as shipped: several of them, e.g. go1 and pr2, have
    inertias that violate the triangle inequality, which URDF files given by path may not)."""
    for jid in range(1, model.njoints):
        inertia = model.inertias[jid]
        problem = mass_problem(float(inertia.mass), allow_zero=True)
        if problem is None and not np.all(np.isfinite(inertia.inertia)):
            problem = "its rotational inertia has an entry that is not a finite number"
        if problem:
            raise RobotError(f"{where}: the body moved by joint '{model.names[jid]}': {problem}")


def describe(robot: Robot) -> dict:
    """Joints (name, type, axis, limits), bodies with masses and total mass, as plain data."""
    model = robot.model
    joints = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        axis = None
        try:
            axis = [round(float(x), 6) for x in joint.extract().axis]
        except AttributeError:
            short = joint.shortname()
            for letter, vec in (("X", [1, 0, 0]), ("Y", [0, 1, 0]), ("Z", [0, 0, 1])):
                if short.endswith(letter):
                    axis = vec
        lo, hi = joint.idx_q, joint.idx_q + joint.nq
        joints.append({
            "name": model.names[jid], "type": joint.shortname().removeprefix("JointModel"),
            "axis": axis, "nq": joint.nq, "nv": joint.nv,
            "lower": float(model.lowerPositionLimit[lo:hi].min()) if joint.nq else 0.0,
            "upper": float(model.upperPositionLimit[lo:hi].max()) if joint.nq else 0.0,
            "effort": float(model.effortLimit[joint.idx_v]) if joint.nv else 0.0,
            "actuated": bool(joint.nv and model.effortLimit[joint.idx_v] > 0),
            "parent": model.names[model.parents[jid]],
        })
    bodies = [{"name": model.names[jid], "mass": float(model.inertias[jid].mass)}
              for jid in range(1, model.njoints)]
    return {"name": robot.name, "source": robot.source, "joints": joints, "bodies": bodies,
            "total_mass": robot.total_mass}


def config_skeleton(robot: Robot) -> str:
    """A YAML experiment skeleton listing every joint of ``robot`` (all locked, with the roles
    to choose from), ready to edit."""
    info = describe(robot)
    lines = [f"name: {robot.name}_experiment", f"robot: {robot.source}", "gravity: 9.81",
             "period_s: 1.0", "sim: {rate_hz: 100, cycles: 100}", "primitives: {basis: 10}",
             "joints:   # role: track | stabilize | passive | locked (joints not listed are locked at 0)"]
    for j in info["joints"]:
        if j["nv"] != 1:
            lines.append(f"  # {j['name']}: {j['type']} joint ({j['nv']} DoF) - can only be locked")
            continue
        mid = 0.5 * (max(j["lower"], -3.14) + min(j["upper"], 3.14))
        lines.append(f"  {j['name']}: {{role: locked, posture: {mid:.3g}}}"
                     f"   # {j['type']}, limits [{j['lower']:.3g}, {j['upper']:.3g}]")
    lines += ["  # e.g. a tracked joint:",
              "  #   role: track",
              "  #   demo: {kind: sine, mean: 0.0, amplitude: 0.3}",
              "  #   gains: {kp: 100.0, kd: 10.0}",
              "  # e.g. a stabilizing joint whose RMP is learned:",
              "  #   role: stabilize",
              "  #   target: {frame: LINK, vector: [0, 0, 1], about: [0, 1, 0], value: 0.0}",
              "  #   gains: {kp: 50.0, kd: 5.0}",
              "  #   learn: {init: random}",
              "learning: {error: stabilizing, rates: {weights: 0.2, goal: 2.0e-5}}",
              "seeds: 5"]
    return "\n".join(lines) + "\n"
