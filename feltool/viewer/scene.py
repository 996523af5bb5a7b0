"""A robot's scene for meshcat: its geometry from Pinocchio's visual model, the system robot and
its ghost, and the commands that draw them (shared by the HTML recorder and the live viewer).
"""

from __future__ import annotations

import math
import re
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.errors import FeltoolError

ROOT = "/meshcat/feltool"


SYSTEM = "system"


GHOST = "ghost"


BACKGROUND = ((0.98, 0.98, 0.98), (0.80, 0.80, 0.84))  # top, bottom: light grey


DEFAULT_GHOST_OPACITY = 0.3


HOLD_SECONDS = 0.5  # the last pose of a clip is held this long before the next clip starts


class ViewerError(FeltoolError):
    """The viewer could not start, reach its server, or draw what it was given."""


def import_meshcat():
    """Import meshcat lazily: only the viewer needs it."""
    try:
        with warnings.catch_warnings():
            # meshcat 0.3.2 imports pyzmq's deprecated zmq.eventloop.ioloop
            warnings.simplefilter("ignore", DeprecationWarning)
            import meshcat.geometry as mg
            import umsgpack
    except ImportError as exc:  # pragma: no cover - a declared dependency
        raise ViewerError(f"the viewer needs the 'meshcat' package ({exc})") from None
    return mg, umsgpack


def viewer_js_source() -> str:
    """The meshcat viewer bundle that ships inside the meshcat Python package."""
    import_meshcat()  # imports meshcat without its pyzmq deprecation warning
    import meshcat

    path = Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"
    if not path.is_file():
        raise ViewerError(f"meshcat's viewer bundle is missing: {path}")
    text = path.read_text(encoding="utf-8")
    # The bundle is inlined in a <script>; a literal "</script" in it would end that element.
    return re.sub(r"</(script)", r"<\\/\1", text, flags=re.IGNORECASE)


def _colmajor(matrix: np.ndarray) -> list[float]:
    """A 4x4 matrix as three.js wants it in JSON: column-major."""
    return [float(x) for x in np.asarray(matrix, dtype=float).T.flatten()]


def _node_names(visual_model: pin.GeometryModel) -> list[str]:
    """One unique meshcat path element per geometry object ('/' is meshcat's separator)."""
    names, seen = [], set()
    for i, gobj in enumerate(visual_model.geometryObjects):
        name = re.sub(r"[/\s]+", "_", gobj.name) or f"geom{i}"
        if name in seen:
            name = f"{name}_{i}"
        seen.add(name)
        names.append(name)
    return names


class _CommandWindow:
    """A meshcat window that keeps the commands sent to it (``meshcat.Visualizer(window=...)``
    sends every command through its window), lowered to the dicts a server would pack."""

    def __init__(self):
        self.commands: list[dict] = []

    def send(self, command) -> None:
        self.commands.append(command.lower())


class _PinocchioGeometry:
    """Pinocchio's MeshcatVisualizer as a converter: a geometry object in, the meshcat
    ``set_object`` command it would send out (or None, with Pinocchio's warning)."""

    def __init__(self, robot):
        import_meshcat()  # imports meshcat without its pyzmq deprecation warning
        import meshcat
        from pinocchio.visualize import MeshcatVisualizer

        self.window = _CommandWindow()
        self.viz = MeshcatVisualizer(robot.model, None, robot.visual_model)
        self.viz.initViewer(viewer=meshcat.Visualizer(window=self.window))

    def command(self, gobj: pin.GeometryObject, group: str, name: str, rgba=None,
                from_file: bool = True) -> dict | None:
        """The object of ``gobj`` at ``{ROOT}/{group}/{name}``, in ``rgba`` (default its URDF
        colour); ``from_file=False`` draws a mesh from the triangles Pinocchio loaded."""
        import coal
        from pinocchio.visualize.meshcat_visualizer import hasMeshFileInfo

        obj = pin.GeometryObject(gobj)
        obj.name = name
        if not from_file:
            obj.meshPath = ""  # Pinocchio then draws the loaded (already scaled) triangles
        scaled = hasMeshFileInfo(obj) or isinstance(obj.geometry, coal.ShapeBase)
        self.viz.viewerVisualGroupName = f"{ROOT.removeprefix('/meshcat/')}/{group}"
        sent = len(self.window.commands)
        self.viz.loadViewerGeometryObject(obj, pin.GeometryType.VISUAL,
                                          None if rgba is None else np.asarray(rgba, float))
        if len(self.window.commands) == sent:
            return None  # Pinocchio warned why
        cmd = self.window.commands.pop()
        inner = cmd["object"]["object"]
        if scaled and np.any(obj.meshScale != 1.0):  # Pinocchio scales each placement
            S = np.diag(np.concatenate([np.asarray(obj.meshScale, float).reshape(3), [1.0]]))
            inner["matrix"] = _colmajor(S @ np.reshape(inner["matrix"], (4, 4)).T)
        return cmd


class Scene:
    """The meshcat messages that draw one robot (system, optionally ghost) and move it."""

    def __init__(self, robot, ghost: bool, ghost_color=None,
                 ghost_opacity: float = DEFAULT_GHOST_OPACITY,
                 ghost_offset=(0.0, 0.0, 0.0), mesh_materials: bool = True):
        self.robot = robot
        self.model: pin.Model = robot.model
        self.visual_model: pin.GeometryModel = robot.visual_model
        self.data = self.model.createData()
        self.visual_data = pin.GeometryData(self.visual_model)
        self.names = _node_names(self.visual_model)
        self.ghost = ghost
        self.ghost_color = ghost_color
        self.ghost_opacity = float(ghost_opacity)
        self.ghost_offset = np.asarray(ghost_offset, dtype=float).reshape(3)
        self.mesh_materials = bool(mesh_materials)
        self.drawn: list[int] = []  # geometry indices that have a meshcat object

    def path(self, which: str, i: int) -> str:
        return f"{ROOT}/{which}/{self.names[i]}"

    def check_q(self, q, what: str) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim == 1:
            q = q[None, :]
        if q.ndim != 2 or q.shape[1] != self.model.nq:
            raise ViewerError(f"{what}: expected configurations of size nq={self.model.nq} "
                              f"(array n_frames x {self.model.nq}), got shape {np.shape(q)}")
        if not np.all(np.isfinite(q)):
            raise ViewerError(f"{what}: configurations contain NaN or inf")
        return q

    def object_commands(self) -> list[dict]:
        """``set_object`` of every visual (system, and ghost), as Pinocchio's MeshcatVisualizer
        draws them (:class:`_PinocchioGeometry`)."""
        convert = _PinocchioGeometry(self.robot)
        cmds = []
        self.drawn = []
        for i, gobj in enumerate(self.visual_model.geometryObjects):
            obj = convert.command(gobj, SYSTEM, self.names[i], from_file=self.mesh_materials)
            if obj is None:
                continue
            self.drawn.append(i)
            cmds.append(obj)
            if self.ghost:
                rgba = list(gobj.meshColor)[:3] + [self.ghost_opacity]
                if self.ghost_color is not None:
                    given = [float(c) for c in self.ghost_color]
                    rgba = given[:3] + [given[3] if len(given) > 3 else self.ghost_opacity]
                cmds.append(convert.command(gobj, GHOST, self.names[i], rgba, from_file=False))
        if self.ghost and np.any(self.ghost_offset):
            cmds.append({"type": "set_transform", "path": f"{ROOT}/{GHOST}",
                         "matrix": _colmajor(_translation(self.ghost_offset))})
        return cmds

    def placements(self, q: np.ndarray) -> list[np.ndarray]:
        """World placement (4x4) of every drawn geometry at configuration q."""
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateGeometryPlacements(self.model, self.data, self.visual_model, self.visual_data)
        return [self.visual_data.oMg[i].homogeneous.copy() for i in self.drawn]

    def transform_commands(self, which: str, q: np.ndarray) -> list[dict]:
        return [{"type": "set_transform", "path": self.path(which, i), "matrix": _colmajor(T)}
                for i, T in zip(self.drawn, self.placements(q), strict=True)]

    def visible_command(self, which: str, visible: bool) -> dict:
        return {"type": "set_property", "path": f"{ROOT}/{which}", "property": "visible",
                "value": bool(visible)}

    def bounds(self, qs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned box around the robot over the given configurations."""
        radii, centers = [], []
        for i in self.drawn:
            geom = self.visual_model.geometryObjects[i].geometry
            try:
                geom.computeLocalAABB()
                radii.append(float(geom.aabb_radius))
                centers.append(np.asarray(geom.aabb_center, dtype=float))
            except Exception:
                radii.append(0.1)
                centers.append(np.zeros(3))
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for q in qs:
            for T, r, c in zip(self.placements(q), radii, centers, strict=True):
                p = T[:3, :3] @ c + T[:3, 3]
                lo, hi = np.minimum(lo, p - r), np.maximum(hi, p + r)
        if not np.all(np.isfinite(lo)):
            lo, hi = -np.ones(3), np.ones(3)
        return lo, hi

    def reach_bounds(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A cube around the first joint holding every pose the robot can reach from q.

        (Conservative: the farthest geometry from the first joint at q, in every direction.)
        """
        lo, hi = self.bounds([q])
        base = self.data.oMi[1].translation.copy() if self.model.njoints > 1 else np.zeros(3)
        reach = float(np.max(np.maximum(np.abs(lo - base), np.abs(hi - base))))
        reach = max(reach, float(np.linalg.norm(np.maximum(np.abs(lo - base),
                                                             np.abs(hi - base)))))
        return base - reach, base + reach

    def camera_commands(self, lo: np.ndarray, hi: np.ndarray) -> list[dict]:
        """Aim meshcat's default camera at the box [lo, hi], looking along its thinnest side."""
        if self.ghost and np.any(self.ghost_offset):
            lo, hi = np.minimum(lo, lo + self.ghost_offset), np.maximum(hi, hi + self.ghost_offset)
        center = 0.5 * (lo + hi)
        extent = np.maximum(hi - lo, 1e-3)
        thin = int(np.argmin(extent)) if extent.max() > 1.2 * extent.min() else 1
        view = np.zeros(3)
        view[thin] = -1.0  # look from the negative side of the thinnest axis (-y for x-z arms)
        if thin == 2:
            view = np.array([0.3, -1.0, 0.0])
        view += np.array([0.15, -0.15, 0.25])  # a little from above and aside, for depth
        view /= np.linalg.norm(view)
        # meshcat's default camera: vertical field of view 75 deg; fit the box with a margin.
        size = float(np.linalg.norm(extent))
        dist = max(0.5, 0.5 * size / math.tan(math.radians(75.0 / 2.0)))
        eye = view * dist
        # The orbit controls always look at the world origin (three.js lookAt is in world
        # coordinates, whatever the transform of /Cameras/default), so instead of moving the
        # camera's target we move the world: the robot, the grid and the axes shift by -center.
        shift = _colmajor(_translation(-center))
        # The camera sits in /Cameras/default/rotated, turned +90 deg about x (three.js is y-up):
        # a world offset (a, b, c) is (a, c, -b) there.
        local = [float(eye[0]), float(eye[2]), float(-eye[1])]
        return [
            {"type": "set_transform", "path": ROOT, "matrix": shift},
            {"type": "set_transform", "path": "/Grid", "matrix": shift},
            {"type": "set_transform", "path": "/Axes", "matrix": shift},
            {"type": "set_property", "path": "/Cameras/default/rotated/<object>",
             "property": "position", "value": local},
        ]


def _translation(p) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = np.asarray(p, dtype=float).reshape(3)
    return T


def background_commands() -> list[dict]:
    top, bottom = BACKGROUND
    return [
        {"type": "set_property", "path": "/Background", "property": "top_color",
         "value": list(top)},
        {"type": "set_property", "path": "/Background", "property": "bottom_color",
         "value": list(bottom)},
    ]


def quaternions_of(Ts: list[np.ndarray]) -> np.ndarray:
    """three.js (x, y, z, w) quaternions of rotations, signs kept continuous along time."""
    out = np.array([pin.Quaternion(T[:3, :3]).coeffs() for T in Ts])  # (x, y, z, w)
    for k in range(1, len(out)):
        if np.dot(out[k], out[k - 1]) < 0:
            out[k] = -out[k]
    return out


def subsample(n: int, dt: float, max_fps: float) -> np.ndarray:
    """Frame indices that keep at most max_fps frames per second, always the last one."""
    stride = max(1, int(math.floor((1.0 / max_fps) / dt + 1e-9))) if max_fps > 0 else 1
    idx = np.arange(0, n, stride)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return idx
