"""A robot's motion as one self-contained HTML file (meshcat's viewer and the animation inlined)."""

from __future__ import annotations

import base64
import html
import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from feltool.files import atomic_write
from feltool.viewer.scene import (
    DEFAULT_GHOST_OPACITY,
    GHOST,
    HOLD_SECONDS,
    SYSTEM,
    Scene,
    ViewerError,
    background_commands,
    import_meshcat,
    quaternions_of,
    subsample,
    viewer_js_source,
)


def record_html(robot, frames: Mapping[str, np.ndarray], dt: float, path: Path,
                title: str = "", ghost_frames: Mapping[str, np.ndarray] | None = None, *,
                ghost_color=None, ghost_opacity: float = DEFAULT_GHOST_OPACITY,
                ghost_offset=(0.0, 0.0, 0.0), max_fps: float = 60.0,
                mesh_materials: bool = True) -> Path:
    """Write one self-contained HTML file that plays the robot's motion in meshcat.

    The page needs no server and no network: it opens from ``file://`` (see the module docstring
    for how). All clips play one after the other in one looping animation; buttons jump to a clip.

    Args:
        robot: A :class:`feltool.robot.robot.Robot` (its ``model`` and ``visual_model`` are used).
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
    _, umsgpack = import_meshcat()
    path = Path(path)
    if not frames:
        raise ViewerError("record_html: no clips given (frames is empty)")
    if not (dt > 0 and math.isfinite(dt)):
        raise ViewerError(f"record_html: dt must be a positive time step in seconds, got {dt}")
    ghost = ghost_frames is not None
    if ghost and set(ghost_frames) != set(frames):
        raise ViewerError("record_html: ghost_frames must have the same clip names as frames; "
                          f"frames has {sorted(frames)}, ghost_frames has {sorted(ghost_frames)}")
    scene = Scene(robot, ghost=ghost, ghost_color=ghost_color, ghost_opacity=ghost_opacity,
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
        idx = subsample(len(q), dt, max_fps)
        clips.append((str(name), q[idx], None if qg is None else qg[idx], idx * dt))

    commands = background_commands() + scene.object_commands()
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
        quat = quaternions_of(list(Ts))
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
        viewer_js=viewer_js_source(),
        commands=_json_in_script(encoded),
        clips=_json_in_script(per_clip),
    )
    return atomic_write(path, page)


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
