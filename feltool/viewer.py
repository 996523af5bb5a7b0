"""Browser views of a robot: a self-contained HTML recording and a live meshcat viewer.

Two ways to look at a robot, both built on meshcat's three.js viewer (its JavaScript ships inside
the ``meshcat`` Python package, so nothing is fetched from the network):

* :func:`record_html` writes ONE HTML file that plays recorded motions from ``file://``, with no
  server and no network. The meshcat viewer bundle (``viewer/dist/main.min.js``) is inlined, and the
  scene (robot geometry, a translucent "ghost" of the desired motion, the camera and one
  animation) is stored as meshcat commands: the same msgpack messages a meshcat server would send
  over its websocket, base64-encoded in the page and handed to ``viewer.handle_command_bytearray``
  when the page loads. This is the mechanism of meshcat's own ``static_html()`` (the server's
  ``get_scene`` handler), without the server: we build the commands ourselves.

  All clips go into a single meshcat animation, one after the other (each followed by a short
  hold of its last pose, then a jump to the next clip's first pose), looping forever. Buttons
  above the scene jump to the start of a clip, and a label names the clip being played. One
  animation instead of one per clip because meshcat's viewer holds one animation at a time: a
  single one keeps the standard play/pause/scrub controls of meshcat working over everything.

* :class:`LiveViewer` starts a meshcat server (or connects to one) and moves the robot and its
  ghost while a simulation runs. The server it starts listens on 127.0.0.1 only (meshcat 0.3.2's
  web server binds every interface; ours does not), and it dies with its parent: :meth:`close`,
  the context manager, ``atexit``, and a watchdog in the server itself that exits when the parent
  process is gone (SIGTERM, SIGKILL, crash).

Geometry: every visual ``GeometryObject`` of ``robot.visual_model`` becomes the meshcat object
Pinocchio's own ``pinocchio.visualize.MeshcatVisualizer`` makes of it (its
``loadViewerGeometryObject``, drawing into a meshcat window that keeps the commands instead of
sending them): primitives (boxes, cylinders, cones, spheres, ellipsoids, capsules), and mesh
files (``.dae``, ``.stl``, ``.obj``) given to three.js's loaders, a Collada file with its own
materials and textures unless the URDF gives the visual a colour. The translucent ghost is drawn
from the triangles Pinocchio loaded (a three.js Collada file keeps its own opaque materials).
Per frame, the placements come from ``pinocchio.updateGeometryPlacements``; a mesh's scale is
part of its object (the animation moves, it does not scale).
"""

from __future__ import annotations

import atexit
import base64
import html
import json
import math
import os
import re
import selectors
import subprocess
import sys
import tempfile
import threading
import time
import warnings
import webbrowser
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.errors import FeltoolError

__all__ = ["LiveViewer", "ViewerError", "record_html"]

ROOT = "/meshcat/feltool"
SYSTEM = "system"
GHOST = "ghost"
BACKGROUND = ((0.98, 0.98, 0.98), (0.80, 0.80, 0.84))  # top, bottom: light grey
DEFAULT_GHOST_OPACITY = 0.3
HOLD_SECONDS = 0.5  # the last pose of a clip is held this long before the next clip starts

class ViewerError(FeltoolError):
    """The viewer could not start, reach its server, or draw what it was given."""


# --------------------------------------------------------------------------------------------
# meshcat message building (no server needed)
# --------------------------------------------------------------------------------------------

def _meshcat():
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


def _viewer_js() -> str:
    """The meshcat viewer bundle that ships inside the meshcat Python package."""
    _meshcat()  # imports meshcat without its pyzmq deprecation warning
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
        _meshcat()  # imports meshcat without its pyzmq deprecation warning
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


class _Scene:
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


def _background_commands() -> list[dict]:
    top, bottom = BACKGROUND
    return [
        {"type": "set_property", "path": "/Background", "property": "top_color",
         "value": list(top)},
        {"type": "set_property", "path": "/Background", "property": "bottom_color",
         "value": list(bottom)},
    ]


def _quaternions(Ts: list[np.ndarray]) -> np.ndarray:
    """three.js (x, y, z, w) quaternions of rotations, signs kept continuous along time."""
    out = np.array([pin.Quaternion(T[:3, :3]).coeffs() for T in Ts])  # (x, y, z, w)
    for k in range(1, len(out)):
        if np.dot(out[k], out[k - 1]) < 0:
            out[k] = -out[k]
    return out


def _subsample(n: int, dt: float, max_fps: float) -> np.ndarray:
    """Frame indices that keep at most max_fps frames per second, always the last one."""
    stride = max(1, int(math.floor((1.0 / max_fps) / dt + 1e-9))) if max_fps > 0 else 1
    idx = np.arange(0, n, stride)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return idx


# --------------------------------------------------------------------------------------------
# the self-contained HTML recording
# --------------------------------------------------------------------------------------------

def record_html(robot, frames: Mapping[str, np.ndarray], dt: float, path: Path,
                title: str = "", ghost_frames: Mapping[str, np.ndarray] | None = None, *,
                ghost_color=None, ghost_opacity: float = DEFAULT_GHOST_OPACITY,
                ghost_offset=(0.0, 0.0, 0.0), max_fps: float = 60.0,
                mesh_materials: bool = True) -> Path:
    """Write one self-contained HTML file that plays the robot's motion in meshcat.

    The page needs no server and no network: it opens from ``file://`` (see the module docstring
    for how). All clips play one after the other in one looping animation; buttons jump to a clip.

    Args:
        robot: A :class:`feltool.robot.Robot` (its ``model`` and ``visual_model`` are used).
        frames: Clip name -> joint configurations of the system robot, shape (n_frames, nq).
            Clips play in the order of the mapping.
        dt: Time between two frames in [s].
        path: The HTML file to write (parent directories are created).
        title: Shown in the page title and above the scene.
        ghost_frames: Clip name -> configurations of the forward (desired) motion, with the same
            keys and frame counts as ``frames``; drawn as a translucent ghost of the robot.
        ghost_color: RGB(A) in [0, 1] for the ghost; by default the robot's own colours.
        ghost_opacity: Opacity of the ghost when ``ghost_color`` has no alpha.
        ghost_offset: Shift of the ghost in [m] (default: none, it overlaps the system robot).
        max_fps: Frames are subsampled to at most this rate to keep the file small.
        mesh_materials: Draw the system robot's meshes from their files, as Pinocchio's
            MeshcatVisualizer does (a Collada file in its own materials and textures unless
            the URDF gives a colour; default); False: from the triangles Pinocchio loaded,
            in the URDF's colour or Pinocchio's grey (a smaller file).

    Returns:
        The path written.

    Raises:
        ViewerError: for empty or mis-shaped frames, mismatched ghost clips, or dt <= 0.
    """
    _, umsgpack = _meshcat()
    path = Path(path)
    if not frames:
        raise ViewerError("record_html: no clips given (frames is empty)")
    if not (dt > 0 and math.isfinite(dt)):
        raise ViewerError(f"record_html: dt must be a positive time step in seconds, got {dt}")
    ghost = ghost_frames is not None
    if ghost and set(ghost_frames) != set(frames):
        raise ViewerError("record_html: ghost_frames must have the same clip names as frames; "
                          f"frames has {sorted(frames)}, ghost_frames has {sorted(ghost_frames)}")
    scene = _Scene(robot, ghost=ghost, ghost_color=ghost_color, ghost_opacity=ghost_opacity,
                   ghost_offset=ghost_offset, mesh_materials=mesh_materials)
    clips: list[tuple[str, np.ndarray, np.ndarray | None, np.ndarray]] = []
    for name, qs in frames.items():
        q = scene.check_q(qs, f"clip '{name}'")
        if len(q) == 0:
            raise ViewerError(f"record_html: clip '{name}' has no frames")
        qg = None
        if ghost:
            qg = scene.check_q(ghost_frames[name], f"ghost clip '{name}'")
            if qg.shape != q.shape:
                raise ViewerError(f"record_html: clip '{name}' has {len(q)} system frames but "
                                  f"{len(qg)} ghost frames")
        idx = _subsample(len(q), dt, max_fps)
        clips.append((str(name), q[idx], None if qg is None else qg[idx], idx * dt))

    commands = _background_commands() + scene.object_commands()
    all_q = [q for _, qs, qg, _ in clips for q in ([qs] + ([qg] if qg is not None else []))]
    sample = [q for qs in all_q for q in qs[:: max(1, len(qs) // 20)]] + [qs[-1] for qs in all_q]
    commands += scene.camera_commands(*scene.bounds(sample))
    first_name, first_q, first_g, _ = clips[0]
    commands += scene.transform_commands(SYSTEM, first_q[0])
    if ghost:
        commands += scene.transform_commands(GHOST, first_g[0])

    # One animation: clip after clip, each holding its last pose for HOLD_SECONDS.
    times: list[float] = []
    per_clip: list[dict] = []
    tracks: dict[str, list[np.ndarray]] = {}
    t0 = 0.0
    for name, qs, qg, t in clips:
        start = t0
        clip_times = list(start + t) + [start + t[-1] + HOLD_SECONDS]
        duration = clip_times[-1] - start
        for which, q in ((SYSTEM, qs), (GHOST, qg)):
            if q is None:
                continue
            placements = [scene.placements(qk) for qk in q]
            for j, i in enumerate(scene.drawn):
                Ts = [p[j] for p in placements]
                Ts.append(Ts[-1])  # hold
                tracks.setdefault(scene.path(which, i), []).append(np.array(Ts))
        times += clip_times
        per_clip.append({"name": name, "start": start, "end": start + duration,
                         "frames": int(len(qs))})
        # the next clip starts a hair after the hold ends: a jump, not a sweep
        t0 = start + duration + 1e-3
    animations = []
    for node_path, chunks in tracks.items():
        Ts = np.concatenate(chunks)
        pos = Ts[:, :3, 3]
        quat = _quaternions(list(Ts))
        animations.append({
            "path": node_path,
            "clip": {"fps": 1.0, "name": "default", "tracks": [
                {"name": ".position", "type": "vector3", "times": [float(x) for x in times],
                 "values": [float(x) for x in pos.flatten()]},
                {"name": ".quaternion", "type": "quaternion",
                 "times": [float(x) for x in times],
                 "values": [float(x) for x in quat.flatten()]},
            ]},
        })
    commands.append({"type": "set_animation", "path": "", "animations": animations,
                     "options": {"play": True, "repetitions": float("inf")}})

    encoded = [base64.b64encode(umsgpack.packb(c)).decode("ascii") for c in commands]
    page = _PAGE.format(
        title=html.escape(title or f"{robot.name}: feltool recording"),
        heading=html.escape(title or robot.name),
        ghost_note=("system robot (solid) and desired motion (translucent ghost)" if ghost
                    else "system robot"),
        viewer_js=_viewer_js(),
        commands=_json_in_script(encoded),
        clips=_json_in_script(per_clip),
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    return path


def _json_in_script(obj) -> str:
    """JSON that is safe inside a <script> element."""
    return json.dumps(obj).replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


_PAGE = """<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
  body {{ margin: 0; font-family: sans-serif; }}
  #meshcat-pane {{ width: 100vw; height: 100vh; overflow: hidden; }}
  #feltool-bar {{ position: absolute; left: 8px; top: 8px; padding: 6px 10px; z-index: 10;
                  background: rgba(255, 255, 255, 0.85); border-radius: 6px; font-size: 14px; }}
  #feltool-bar button {{ margin: 4px 4px 0 0; }}
  #feltool-bar .current {{ font-weight: bold; }}
  #feltool-errors {{ color: #b00; white-space: pre-wrap; }}
</style>
<script>
  // Record script errors in the page (a test reads them back with --dump-dom).
  window.feltoolErrors = [];
  window.addEventListener("error", function (e) {{
    window.feltoolErrors.push(String(e.message || e));
    var el = document.getElementById("feltool-errors");
    if (el) el.textContent = window.feltoolErrors.join("\\n");
  }});
</script>
</head>
<body data-feltool-status="loading">
<div id="feltool-bar">
  <div><strong>{heading}</strong> &mdash; {ghost_note}</div>
  <div>clip: <span id="feltool-clip">&ndash;</span></div>
  <div id="feltool-buttons"></div>
  <div id="feltool-errors"></div>
</div>
<div id="meshcat-pane"></div>
<script>
{viewer_js}
</script>
<script type="application/json" id="feltool-commands">{commands}</script>
<script type="application/json" id="feltool-clips">{clips}</script>
<script>
(function () {{
  function bytes(b64) {{
    var s = atob(b64), a = new Uint8Array(s.length);
    for (var i = 0; i < s.length; i++) a[i] = s.charCodeAt(i);
    return a;
  }}
  var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
  window.viewer = viewer;
  var commands = JSON.parse(document.getElementById("feltool-commands").textContent);
  for (var i = 0; i < commands.length; i++) viewer.handle_command_bytearray(bytes(commands[i]));
  var clips = JSON.parse(document.getElementById("feltool-clips").textContent);
  var total = clips.length ? clips[clips.length - 1].end : 0;
  var label = document.getElementById("feltool-clip");
  var box = document.getElementById("feltool-buttons");
  clips.forEach(function (c) {{
    var b = document.createElement("button");
    b.textContent = "\\u25B6 " + c.name;
    b.onclick = function () {{ viewer.animator.play(); viewer.animator.seek(c.start); }};
    box.appendChild(b);
  }});
  function update() {{
    var a = viewer.animator.actions;
    var t = a.length ? a[0].time : 0;
    var name = clips.length ? clips[0].name : "";
    clips.forEach(function (c) {{ if (t >= c.start - 1e-6) name = c.name; }});
    if (label.textContent !== name) label.textContent = name;
    requestAnimationFrame(update);
  }}
  update();
  document.body.setAttribute("data-feltool-status", "ready");
  document.body.setAttribute("data-feltool-commands", String(commands.length));
}})();
</script>
</body>
</html>
"""


# --------------------------------------------------------------------------------------------
# the live viewer
# --------------------------------------------------------------------------------------------

# Runs in the server subprocess: meshcat's bridge, with the web server bound to loopback (meshcat
# 0.3.2 calls ``app.listen(port)``, which binds every interface) and a watchdog that exits when
# the parent process is gone, however it went.
_SERVER_CODE = r"""
import os, sys
try:
    os.nice(10)  # the viewer yields the CPU to learning
except OSError:
    pass
parent = int(sys.argv[1])
zmq_url = sys.argv[2] or None
import tornado.ioloop
from meshcat.servers import zmqserver

class LoopbackBridge(zmqserver.ZMQWebSocketBridge):
    def make_app(self):
        app = super().make_app()
        listen = app.listen
        app.listen = lambda port, **kw: listen(port, address="127.0.0.1", **kw)
        return app

bridge = LoopbackBridge(zmq_url=zmq_url, host="127.0.0.1")
print("zmq_url=" + bridge.zmq_url, flush=True)
print("web_url=" + bridge.web_url, flush=True)

def watchdog():
    if os.getppid() != parent:
        os._exit(0)

tornado.ioloop.PeriodicCallback(watchdog, 250).start()
try:
    bridge.run()
except KeyboardInterrupt:
    pass
"""


def _stop_process(proc: subprocess.Popen, timeout: float = 3.0) -> None:
    """Terminate, then kill, a subprocess we started, and reap it."""
    if proc.poll() is None:
        try:
            proc.terminate()
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=timeout)
        except ProcessLookupError:  # pragma: no cover - already gone
            pass
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            try:
                stream.close()
            except OSError:  # pragma: no cover
                pass


class LiveViewer:
    """A meshcat viewer that shows the system robot and a ghost of the desired motion live.

    Starts a private meshcat server on 127.0.0.1 (or connects to one at ``zmq_url``), loads the
    robot into it, and moves it on :meth:`show`. Open :attr:`url` in a browser on this machine.

    Use it as a context manager, or call :meth:`close`; a server it started is also stopped at
    interpreter exit, and stops by itself when this process dies (SIGTERM, SIGKILL).

    Args:
        robot: A :class:`feltool.robot.Robot`.
        zmq_url: Connect to this running meshcat server instead of starting one.
        ghost: Load a translucent ghost copy for the forward (desired) configuration.
        ghost_color, ghost_opacity, ghost_offset, mesh_materials: As in :func:`record_html`.
        max_fps: :meth:`show` drops updates that come faster than this.
        open_browser: Open :attr:`url` in the default browser.
        timeout: Seconds to wait for the server to start and for each reply.
        quiet: Do not print the URL.
    """

    def __init__(self, robot, *, zmq_url: str | None = None, ghost: bool = True,
                 ghost_color=None, ghost_opacity: float = DEFAULT_GHOST_OPACITY,
                 ghost_offset=(0.0, 0.0, 0.0), max_fps: float = 30.0,
                 mesh_materials: bool = True, open_browser: bool = False,
                 timeout: float = 20.0, quiet: bool = False):
        import zmq

        _, self._umsgpack = _meshcat()
        self._zmq = zmq
        self._timeout = float(timeout)
        self.max_fps = float(max_fps)
        self._proc: subprocess.Popen | None = None
        self._stderr = None
        self._socket = None
        self._context = None
        self._closed = False
        self._last_show = -math.inf
        self._ghost_shown = False
        self._lock = threading.Lock()
        self.scene = _Scene(robot, ghost=ghost, ghost_color=ghost_color,
                            ghost_opacity=ghost_opacity, ghost_offset=ghost_offset,
                            mesh_materials=mesh_materials)
        atexit.register(self.close)
        try:
            if zmq_url is None:
                self.zmq_url, self.url = self._start_server()
            else:
                self.zmq_url = zmq_url
                self._connect()
                self.url = self._request(b"url").decode("utf-8")
                # as meshcat's own client does: reconnect after asking for the URL, or the
                # server's receiver can stall until the next connection
            self._connect()
            self._load()
        except BaseException:
            self.close()
            raise
        if not quiet:
            print(f"feltool viewer: open {self.url}", flush=True)
        if open_browser:
            webbrowser.open(self.url, new=2)

    # -- server and connection -----------------------------------------------------------------

    @property
    def server_pid(self) -> int | None:
        """Process id of the meshcat server this viewer started (None when it connected)."""
        return None if self._proc is None else self._proc.pid

    def _start_server(self) -> tuple[str, str]:
        self._stderr = tempfile.TemporaryFile()
        args = [sys.executable, "-u", "-c", _SERVER_CODE, str(os.getpid()), ""]
        self._proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                      stderr=self._stderr, start_new_session=True)
        found: dict[str, str] = {}
        deadline = time.monotonic() + self._timeout
        buf = b""
        with selectors.DefaultSelector() as sel:
            sel.register(self._proc.stdout, selectors.EVENT_READ)
            while "web_url" not in found:
                left = deadline - time.monotonic()
                if left <= 0 or self._proc.poll() is not None:
                    break
                if not sel.select(timeout=min(left, 0.2)):
                    continue
                chunk = os.read(self._proc.stdout.fileno(), 4096)
                if not chunk:
                    break
                buf += chunk
                *lines, buf = buf.split(b"\n")
                for line in lines:
                    key, _, value = line.decode("utf-8", "replace").strip().partition("=")
                    if key in ("zmq_url", "web_url"):
                        found[key] = value
        if "web_url" not in found or "zmq_url" not in found:
            self._stderr.seek(0)
            err = self._stderr.read().decode("utf-8", "replace")[-2000:]
            raise ViewerError("the meshcat server did not start"
                              + (f" (exit code {self._proc.poll()})" if self._proc.poll()
                                 is not None else f" within {self._timeout:g} s")
                              + (f":\n{err}" if err.strip() else ""))
        # keep draining stdout so a chatty server never blocks on a full pipe
        stdout = self._proc.stdout
        threading.Thread(target=lambda: [None for _ in iter(lambda: stdout.read(4096), b"")],
                         daemon=True).start()
        return found["zmq_url"], found["web_url"]

    def detach_for_child(self) -> None:
        """In a forked child process: forget the parent's connection and server (never close
        or kill them from here) and connect afresh to the same server."""
        self._proc = None  # the parent owns the server
        self._context = None  # a zmq context must not cross a fork; the child makes its own
        self._socket = None
        self._lock = threading.Lock()
        self._connect()

    def _connect(self) -> None:
        zmq = self._zmq
        if self._context is None:
            self._context = zmq.Context()
        if self._socket is not None:
            self._socket.close(linger=0)
        sock = self._context.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.RCVTIMEO, int(self._timeout * 1000))
        sock.setsockopt(zmq.SNDTIMEO, int(self._timeout * 1000))
        sock.connect(self.zmq_url)
        self._socket = sock

    def _request(self, *parts: bytes) -> bytes:
        try:
            if len(parts) == 1:
                self._socket.send(parts[0])
            else:
                self._socket.send_multipart(list(parts))
            return self._socket.recv()
        except self._zmq.error.Again:
            self._connect()  # a REQ socket that missed its reply is stuck; start afresh
            raise ViewerError(f"the meshcat server at {self.zmq_url} did not answer within "
                              f"{self._timeout:g} s") from None

    def _send(self, command: dict) -> None:
        reply = self._request(command["type"].encode(), command.get("path", "").encode(),
                              self._umsgpack.packb(command))
        if reply != b"ok":
            raise ViewerError(f"meshcat server refused '{command['type']}': {reply[:200]!r}")

    def _load(self) -> None:
        q0 = pin.neutral(self.scene.model)
        objects = self.scene.object_commands()
        camera = self.scene.camera_commands(*self.scene.reach_bounds(q0))
        for cmd in ([{"type": "delete", "path": ROOT}] + _background_commands() + objects
                    + camera + self.scene.transform_commands(SYSTEM, q0)):
            self._send(cmd)
        if self.scene.ghost:
            self._send(self.scene.visible_command(GHOST, False))

    # -- drawing ---------------------------------------------------------------------------------

    def show(self, q_system, q_forward=None, *, force: bool = False) -> bool:
        """Move the robot to ``q_system`` and the ghost to ``q_forward``.

        Returns False, doing nothing, when called sooner than 1/max_fps after the last update
        that was drawn (unless ``force``). The ghost is hidden while ``q_forward`` is None.
        """
        if self._closed:
            raise ViewerError("show() on a closed LiveViewer")
        now = time.monotonic()
        if not force and self.max_fps > 0 and now - self._last_show < 1.0 / self.max_fps:
            return False
        q = self.scene.check_q(q_system, "q_system")[0]
        qf = None if q_forward is None else self.scene.check_q(q_forward, "q_forward")[0]
        with self._lock:
            self._last_show = now
            for cmd in self.scene.transform_commands(SYSTEM, q):
                self._send(cmd)
            if self.scene.ghost:
                if qf is not None:
                    for cmd in self.scene.transform_commands(GHOST, qf):
                        self._send(cmd)
                if (qf is not None) != self._ghost_shown:
                    self._ghost_shown = qf is not None
                    self._send(self.scene.visible_command(GHOST, self._ghost_shown))
        return True

    # -- lifetime --------------------------------------------------------------------------------

    def close(self) -> None:
        """Disconnect, and stop the server if this viewer started it. Safe to call twice."""
        if self._closed:
            return
        self._closed = True
        if self._socket is not None:
            try:
                self._socket.close(linger=0)
            except Exception:  # pragma: no cover
                pass
            self._socket = None
        if self._context is not None:
            try:
                self._context.term()
            except Exception:  # pragma: no cover
                pass
            self._context = None
        if self._proc is not None:
            _stop_process(self._proc)
        if self._stderr is not None:
            self._stderr.close()
        try:
            atexit.unregister(self.close)
        except Exception:  # pragma: no cover
            pass

    def __enter__(self) -> LiveViewer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else self.url
        return f"<LiveViewer {state}>"
