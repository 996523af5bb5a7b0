"""Loading robots: bundled names, URDF files and ``example-robot-data:NAME``.

This module is the one place that builds Pinocchio models. A :class:`Robot` couples the model with
where it came from and the joint-name bookkeeping the rest of feltool needs.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.bounds import MAX_URDF_BYTES
from feltool.errors import RobotError
from feltool.robot.physical import joint_dynamics_problem, mass_problem
from feltool.robot.urdf import read_urdf

ERD_PREFIX = "example-robot-data:"


def data_dir(kind: str) -> Path:
    """Directory of bundled ``robots`` or ``configs``: inside the installed wheel, or the checkout."""
    package = Path(__file__).resolve().parent.parent  # feltool/
    packaged = package / "_data" / kind
    if packaged.is_dir():
        return packaged
    return package.parent / kind


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
        urdf_xml: The validated URDF description the model was built from
            (:mod:`feltool.robot.urdf`; read from ``urdf_path`` when not given).
        warnings: What lenient reading accepted, one line each (:mod:`feltool.robot.urdf`).
        visual_model: Pinocchio geometry model of the visuals, built lazily for viewers.
    """

    name: str
    model: pin.Model
    source: str
    urdf_path: Path | None = None
    package_dirs: list[str] = field(default_factory=list)
    _visual_model: pin.GeometryModel | None = None
    urdf_xml: str | None = None
    warnings: list[str] = field(default_factory=list)

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
    def description(self) -> str:
        """The validated URDF description (mesh paths absolute), for models built alike."""
        if self.urdf_xml is None:
            if self.urdf_path is None:
                raise RobotError(f"robot '{self.name}' has no URDF")
            self.urdf_xml = load_urdf(self.urdf_path, package_dirs=self.package_dirs).urdf_xml
        return self.urdf_xml

    @property
    def visual_model(self) -> pin.GeometryModel:
        """The visuals of the URDF's description (meshes by absolute path), built on first use."""
        if self._visual_model is None:
            with captured_stderr():  # (said when the model was loaded)
                self._visual_model = pin.buildGeomFromUrdfString(self.model, self.description,
                                                                 pin.GeometryType.VISUAL)
        return self._visual_model


def with_angle_coordinates(robot: Robot) -> Robot:
    """The robot with every continuous joint as a revolute joint without limits: one angle
    coordinate in [rad] instead of Pinocchio's (cos, sin) pair, so that every one-degree-of-
    freedom joint has ``nq == nv`` (feltool's trajectories, roles and walkers are in angles).
    Joint and frame indices, names, placements, inertias and the effort and velocity limits are
    kept; the robot itself is returned when it has no continuous joint."""
    model = robot.model
    kinds = {f"JointModelRUB{a}": getattr(pin, f"JointModelR{a}") for a in "XYZ"}
    if not any(j.shortname() in kinds or j.shortname() == "JointModelRevoluteUnboundedUnaligned"
               for j in model.joints[1:]):
        return robot
    out = pin.Model()
    out.name, out.gravity = model.name, model.gravity
    out.inertias[0] = model.inertias[0]  # a fixed root link's body
    for j in range(1, model.njoints):
        jm = model.joints[j]
        q, v = slice(jm.idx_q, jm.idx_q + jm.nq), slice(jm.idx_v, jm.idx_v + jm.nv)
        lo, hi = model.lowerPositionLimit[q], model.upperPositionLimit[q]
        name = jm.shortname()
        if name in kinds or name == "JointModelRevoluteUnboundedUnaligned":
            data = jm.createData()
            jm.calc(data, np.array([1.0, 0.0]))  # (cos, sin) of the angle 0
            axis = np.asarray(data.S).reshape(6, -1)[3:, 0]
            jm = kinds[name]() if name in kinds else pin.JointModelRevoluteUnaligned(axis)
            lo, hi = np.array([-np.inf]), np.array([np.inf])
        jid = out.addJoint(model.parents[j], jm, model.jointPlacements[j], model.names[j],
                           model.effortLimit[v], model.velocityLimit[v], lo, hi)
        out.appendBodyToJoint(jid, model.inertias[j], pin.SE3.Identity())
    for frame in list(model.frames)[1:]:  # the universe frame is already there
        out.addFrame(pin.Frame(frame.name, frame.parentJoint, frame.parentFrame,
                               frame.placement, frame.type, frame.inertia), False)
    return Robot(name=robot.name, model=out, source=robot.source, urdf_path=robot.urdf_path,
                 package_dirs=robot.package_dirs, urdf_xml=robot.urdf_xml,
                 warnings=list(robot.warnings))


def robot_spec(value) -> tuple[str, bool]:
    """``(source, lenient)`` of a config's ``robot`` value: a string (lenient), or the mapping
    ``{source, lenient}``; ``("", True)`` when it is neither (the schema reports that)."""
    if isinstance(value, str):
        return value, True
    if isinstance(value, dict) and isinstance(value.get("source"), str):
        return value["source"], value.get("lenient", True) is not False
    return "", True


def load_robot(spec: str, base_dir: Path | None = None,
               package_dirs: list[str] | None = None, lenient: bool = True) -> Robot:
    """Load a robot by bundled name, URDF path, or ``example-robot-data:NAME``.

    Args:
        spec: ``two_link_arm`` | ``path/to/robot.urdf`` | ``example-robot-data:ur5``.
        base_dir: Directory that relative URDF paths are resolved against (the config's).
        package_dirs: Extra directories for ``package://`` mesh paths (relative ones resolve
            against ``base_dir``).
        lenient: Read the URDF dialects of :mod:`feltool.robot.urdf` (example-robot-data's robots
            are taken as shipped either way).

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
        return load_urdf(path, source=spec, package_dirs=dirs, lenient=lenient)
    bundled = data_dir("robots") / f"{spec}.urdf"
    if bundled.is_file():
        return load_urdf(bundled, source=spec, name=spec, lenient=lenient)
    raise RobotError(
        f"unknown robot '{spec}': not a bundled robot ({', '.join(bundled_robots())}), not a "
        f"path to a .urdf file, and not '{ERD_PREFIX}NAME'"
    )


def load_urdf(path: Path, source: str | None = None, name: str | None = None,
              package_dirs: list[str] | None = None, lenient: bool = True) -> Robot:
    """Load a URDF file through :func:`feltool.robot.urdf.read_urdf` (problems name the file and the
    element; ``lenient`` reads the dialects described there)."""
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
    robot = _from_text(text, str(path), path.parent, dirs, lenient)
    robot.name, robot.source, robot.urdf_path = name or path.stem, source or str(path), path
    return robot


def load_urdf_string(text: str, name: str = "robot", package_dirs: list[str] | None = None,
                     base_dir: Path | None = None, lenient: bool = True) -> Robot:
    """A robot from URDF text (already expanded: no xacro), with the same checks as a file;
    mesh paths resolve against ``base_dir`` (default: the current directory) and
    ``package_dirs``."""
    where = f"<URDF string '{name}'>"
    if not text.strip():
        raise RobotError(f"{where}: the URDF is empty")
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    robot = _from_text(text, where, base, [str(base)] + list(package_dirs or []), lenient)
    robot.name, robot.source = name, where
    return robot


def _from_text(text: str, where: str, base: Path, dirs: list[str], lenient: bool) -> Robot:
    """The Pinocchio model of a URDF's validated description; a joint without limits gets
    infinite ones (Pinocchio's own value for a continuous joint's effort and velocity)."""
    description = read_urdf(text, where, base, dirs, lenient)
    try:
        with captured_stderr() as said:
            model = pin.buildModelFromXML(description.xml)
    except Exception as exc:  # Pinocchio raises ValueError/RuntimeError with its own text
        raise RobotError(f"{where}: Pinocchio could not build a model: {exc}"
                         + "".join(f"; {line}" for line in said)) from None
    description.warnings += [f"{where}: Pinocchio's URDF parser (urdfdom) said: {line}"
                             for line in said]
    for joint_name, missing in description.unbounded.items():
        joint = model.joints[model.getJointId(joint_name)]
        if "position" in missing:
            model.lowerPositionLimit[joint.idx_q:joint.idx_q + joint.nq] = -np.inf
            model.upperPositionLimit[joint.idx_q:joint.idx_q + joint.nq] = np.inf
        for kind, limits in (("effort", model.effortLimit), ("velocity", model.velocityLimit)):
            if kind in missing:
                limits[joint.idx_v] = np.inf
    return Robot(name="robot", model=model, source=where, package_dirs=dirs,
                 urdf_xml=description.xml, warnings=description.warnings)


@contextmanager
def captured_stderr() -> Iterator[list[str]]:
    """What C++ code (urdfdom, inside Pinocchio's parser) writes to the process's stderr while
    the block runs, as its non-empty lines (filled in when the block ends), instead of a screen
    of text under feltool's own report."""
    lines: list[str] = []
    fd = 2  # where C++'s std::cerr writes, whatever Python's sys.stderr is now
    try:
        saved = os.dup(fd)
    except OSError:  # no stderr to redirect: nothing to capture
        yield lines
        return
    with tempfile.TemporaryFile() as tmp:
        sys.stderr.flush()
        os.dup2(tmp.fileno(), fd)
        try:
            yield lines
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode("utf-8", errors="replace")
            lines += [" ".join(line.split()) for line in text.splitlines() if line.strip()
                      and not line.strip().startswith("at line ")]


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
    """Finite, non-negative masses, finite inertias and non-negative joint damping and friction
    of a model built elsewhere (the example-robot-data robots are taken as shipped: several of
    them, e.g. go1 and pr2, have inertias that violate the triangle inequality, which URDF files
    given by path may not)."""
    for jid in range(1, model.njoints):
        inertia = model.inertias[jid]
        problem = mass_problem(float(inertia.mass), allow_zero=True)
        if problem is None and not np.all(np.isfinite(inertia.inertia)):
            problem = "its rotational inertia has an entry that is not a finite number"
        if problem:
            raise RobotError(f"{where}: the body moved by joint '{model.names[jid]}': {problem}")
    check_model_dynamics(model, where)


def check_model_dynamics(model: pin.Model, where: str) -> None:
    """Non-negative joint damping and friction (the URDF's ``<dynamics>``, in Pinocchio's
    ``model.damping`` and ``model.friction``) of a model built without
    :func:`feltool.robot.urdf.read_urdf`: a negative one is a plant that creates energy.

    Raises:
        RobotError: one line naming ``where``, the joint and the attribute.
    """
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        for attr in ("damping", "friction"):
            for value in np.asarray(getattr(model, attr))[joint.idx_v:joint.idx_v + joint.nv]:
                problem = joint_dynamics_problem(attr, float(value))
                if problem:
                    raise RobotError(f"{where}: joint '{model.names[jid]}' <dynamics "
                                     f"{attr}=\"{float(value):g}\">: {problem}")
