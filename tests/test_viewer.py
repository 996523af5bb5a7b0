"""The meshcat viewer: self-contained HTML recordings and the live viewer's server hygiene."""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from feltool.robot.robot import load_robot
from feltool.viewer.html import record_html
from feltool.viewer.live import LiveViewer
from feltool.viewer.scene import ViewerError, viewer_js_source
from tests.conftest import port_free, port_of

CHROMIUM = Path("/usr/bin/chromium")
DT = 0.01


@pytest.fixture(scope="module")
def arm():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot("two_link_arm")
        robot.visual_model  # noqa: B018 - build the visuals once, quietly
    return robot


def _clips():
    t = np.arange(0.0, 0.5, DT)
    s, c = np.sin(2 * np.pi * t), np.cos(2 * np.pi * t)
    first = np.stack([np.pi / 4 + 0.3 * s, 0.6 + 0.4 * c], 1)
    last = np.stack([np.pi / 3 + 0.2 * s, 0.3 + 0.2 * c], 1)
    ghost = {"first cycle": first + 0.15, "last cycle": last + 0.02}
    return {"first cycle": first, "last cycle": last}, ghost


@pytest.fixture(scope="module")
def arm_html(arm, tmp_path_factory):
    frames, ghost = _clips()
    path = tmp_path_factory.mktemp("viewer") / "sub" / "arm.html"
    out = record_html(arm, frames, DT, path, title="Two-link arm <test>", ghost_frames=ghost)
    assert out == path
    return path


def _commands(page: str) -> list[dict]:
    import umsgpack

    m = re.search(r'<script type="application/json" id="feltool-commands">(.*?)</script>', page,
                  re.S)
    assert m, "the page stores its meshcat commands in #feltool-commands"
    return [umsgpack.unpackb(base64.b64decode(c)) for c in json.loads(m.group(1))]


# ------------------------------------------------------------------------------------------------
# record_html
# ------------------------------------------------------------------------------------------------

def test_record_html_is_self_contained(arm_html):
    page = arm_html.read_text(encoding="utf-8")
    assert page.startswith("<!DOCTYPE html>")
    assert "new MeshCat.Viewer" in page and "handle_command_bytearray" in page
    # meshcat's viewer bundle is inlined whole ...
    bundle = viewer_js_source()
    assert len(bundle) > 100_000 and bundle in page
    # ... and around it nothing is loaded from elsewhere: no external scripts, styles, images,
    # frames, and no websocket to a meshcat server
    ours = page.replace(bundle, "")
    for pattern in (r"<script[^>]*\bsrc\s*=", r"<link\b", r"<img\b", r"<iframe\b", r"@import",
                    r"url\(", r"WebSocket", r"\.connect\(", r"fetch\("):
        assert not re.search(pattern, ours, re.I), pattern
    # the only absolute URLs are XML namespace names inside the meshcat bundle (never fetched)
    urls = set(re.findall(r"https?://[^\s\"'<>)\\]+", page))
    assert all(u.startswith(("http://www.w3.org/", "http://www.collada.org/")) for u in urls), urls
    # the title is escaped, clip names are there
    assert "Two-link arm &lt;test&gt;" in page
    assert "first cycle" in page and "last cycle" in page


def test_record_html_scene_and_animation(arm, arm_html):
    frames, ghost = _clips()
    cmds = _commands(arm_html.read_text(encoding="utf-8"))
    objects = [c["path"] for c in cmds if c["type"] == "set_object"]
    names = [g.name for g in arm.visual_model.geometryObjects]
    assert sorted(objects) == sorted([f"/meshcat/feltool/system/{n}" for n in names]
                                     + [f"/meshcat/feltool/ghost/{n}" for n in names])
    # colours from meshColor: the orange link is solid, its ghost translucent
    link2 = {c["path"]: c["object"]["materials"][0] for c in cmds if c["type"] == "set_object"
             and c["path"].endswith("/link2_0")}
    solid = link2["/meshcat/feltool/system/link2_0"]
    ghost_mat = link2["/meshcat/feltool/ghost/link2_0"]
    assert solid["color"] == ghost_mat["color"] == (242 << 16) | (140 << 8) | 38
    assert solid["opacity"] == 1.0 and not solid["transparent"]
    assert ghost_mat["opacity"] < 0.5 and ghost_mat["transparent"]

    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    assert anim["options"]["repetitions"] == float("inf")
    tracks = {a["path"]: {t["name"]: t for t in a["clip"]["tracks"]} for a in anim["animations"]}
    assert set(tracks) == set(objects)
    times = np.array(tracks["/meshcat/feltool/system/link2_1"][".position"]["times"])
    assert np.all(np.diff(times) > 0)
    n1, n2 = len(frames["first cycle"]), len(frames["last cycle"])
    assert len(times) == n1 + 1 + n2 + 1  # each clip plus a hold of its last pose

    # key k of the second clip is Pinocchio's placement of the geometry at that frame
    model, data = arm.model, arm.model.createData()
    gdata = pin.GeometryData(arm.visual_model)
    gid = arm.visual_model.getGeometryId("link2_1")
    for which, qs in (("system", frames["last cycle"]), ("ghost", ghost["last cycle"])):
        pos = np.array(tracks[f"/meshcat/feltool/{which}/link2_1"][".position"]["values"])
        quat = np.array(tracks[f"/meshcat/feltool/{which}/link2_1"][".quaternion"]["values"])
        pos, quat = pos.reshape(-1, 3), quat.reshape(-1, 4)
        for k in (0, 7, n2 - 1):
            pin.forwardKinematics(model, data, qs[k])
            pin.updateGeometryPlacements(model, data, arm.visual_model, gdata)
            M = gdata.oMg[gid]
            np.testing.assert_allclose(pos[n1 + 1 + k], M.translation, atol=1e-9)
            R = pin.Quaternion(*np.roll(quat[n1 + 1 + k], 1)).toRotationMatrix()
            np.testing.assert_allclose(R, M.rotation, atol=1e-9)
        assert times[n1 + 1] - times[n1] < 0.01  # the next clip starts with a jump


def test_record_html_subsamples_long_clips(arm, tmp_path):
    q = np.zeros((1000, 2))
    path = record_html(arm, {"long": q}, 0.001, tmp_path / "long.html", max_fps=50)
    (anim,) = [c for c in _commands(path.read_text()) if c["type"] == "set_animation"]
    times = anim["animations"][0]["clip"]["tracks"][0]["times"]
    assert 50 <= len(times) <= 52 and times[-2] == pytest.approx(0.999)


def test_record_html_rejects_bad_frames(arm, tmp_path):
    frames, ghost = _clips()
    with pytest.raises(ViewerError, match="nq=2"):
        record_html(arm, {"a": np.zeros((5, 3))}, DT, tmp_path / "x.html")
    with pytest.raises(ViewerError, match="same clip names"):
        record_html(arm, frames, DT, tmp_path / "x.html",
                    ghost_frames={"first cycle": frames["first cycle"]})
    with pytest.raises(ViewerError, match="ghost frames"):
        record_html(arm, {"a": np.zeros((5, 2))}, DT, tmp_path / "x.html",
                    ghost_frames={"a": np.zeros((4, 2))})
    with pytest.raises(ViewerError, match="no clips"):
        record_html(arm, {}, DT, tmp_path / "x.html")
    with pytest.raises(ViewerError, match="dt"):
        record_html(arm, frames, 0.0, tmp_path / "x.html")
    assert not (tmp_path / "x.html").exists()


def test_record_html_mesh_robot(tmp_path):
    pytest.importorskip("example_robot_data")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ur5 = load_robot("example-robot-data:ur5")
        ur5.visual_model  # noqa: B018
    q = np.zeros((3, ur5.model.nq))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every mesh is drawn, none left out with a warning
        path = record_html(ur5, {"still": q}, 0.1, tmp_path / "ur5.html", ghost_frames={"still": q})
    cmds = _commands(path.read_text())
    objects = [c for c in cmds if c["type"] == "set_object"]
    geoms = ur5.visual_model.geometryObjects
    assert len(objects) == 2 * len(geoms)
    # the system robot: each Collada file itself (Pinocchio's MeshcatVisualizer: its own
    # materials, since the URDF gives none); the ghost: Pinocchio's triangles, translucent
    system = [o for o in objects if "/system/" in o["path"]]
    ghost = [o for o in objects if "/ghost/" in o["path"]]
    assert len(system) == len(ghost) == len(geoms)
    for obj, geom in zip(system, geoms):
        inner = obj["object"]["object"]
        assert inner["type"] == "_meshfile_object" and inner["format"] == "dae"
        assert inner["data"] == Path(geom.meshPath).read_text(), geom.name
    for obj in ghost:
        assert obj["object"]["geometries"][0]["type"] == "BufferGeometry"
        assert obj["object"]["materials"][0]["opacity"] < 0.5


# ------------------------------------------------------------------------------------------------
# LiveViewer
# ------------------------------------------------------------------------------------------------

def _listening(pid: int) -> list[tuple[str, int]]:
    import psutil

    return [(c.laddr.ip, c.laddr.port) for c in psutil.Process(pid).net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN]


_port = port_of
_port_free = port_free


def _gone(pid: int, timeout: float) -> bool:
    import psutil

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if psutil.Process(pid).status() == psutil.STATUS_ZOMBIE:
                return True
        except psutil.NoSuchProcess:
            return True
        time.sleep(0.05)
    return False


def test_live_viewer_loopback_throttle_and_close(arm, capsys):
    viewer = LiveViewer(arm, max_fps=1)  # 1 s between updates: far more than two calls take
    try:
        pid = viewer.server_pid
        assert pid is not None and viewer.url.startswith("http://127.0.0.1:")
        assert viewer.url in capsys.readouterr().out
        web, zmq_port = _port(viewer.url), _port(viewer.zmq_url)
        listening = _listening(pid)
        assert {web, zmq_port} <= {port for _, port in listening}, listening
        assert all(ip == "127.0.0.1" for ip, _ in listening), listening
        page = urllib.request.urlopen(viewer.url, timeout=5).read().decode()
        assert "MeshCat.Viewer" in page

        assert viewer.show([0.5, 0.5], [0.6, 0.4]) is True
        assert viewer.show([0.5, 0.6]) is False  # within 1/max_fps of the last update: dropped
        assert viewer.show([0.5, 0.6], force=True) is True
        deadline = time.monotonic() + 60  # once 1/max_fps has passed, an update goes through
        while not viewer.show(np.array([0.1, 0.2]), np.array([0.2, 0.1])):
            assert time.monotonic() < deadline, "show() kept dropping updates"
            time.sleep(0.05)
        with pytest.raises(ViewerError, match="nq=2"):
            viewer.show([0.1, 0.2, 0.3], force=True)
    finally:
        viewer.close()
    assert _gone(pid, 60.0)
    assert _port_free(web) and _port_free(zmq_port)
    viewer.close()  # twice is fine
    with pytest.raises(ViewerError, match="closed"):
        viewer.show([0.0, 0.0])


def test_live_viewer_context_manager_and_connect(arm):
    with LiveViewer(arm, quiet=True) as owner:
        with LiveViewer(arm, zmq_url=owner.zmq_url, quiet=True) as guest:
            assert guest.server_pid is None and guest.url == owner.url
            assert guest.show([0.3, 0.3], [0.2, 0.2])
        # the guest leaves the owner's server running
        assert not _gone(owner.server_pid, 0.2)
        assert owner.show([0.1, 0.1], force=True)
        pid = owner.server_pid
    assert _gone(pid, 60.0)


def test_live_viewer_server_dies_with_its_parent(tmp_path):
    script = textwrap.dedent("""
        import sys, time, warnings
        warnings.simplefilter("ignore")
        from feltool.robot.robot import load_robot
        from feltool.viewer.live import LiveViewer
        v = LiveViewer(load_robot("two_link_arm"), quiet=True)
        print(v.server_pid, v.url, flush=True)
        time.sleep(60)
    """)
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parent.parent))
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                              env=env)
    try:
        line = parent.stdout.readline().split()
        assert line, "the child did not start a viewer"
        pid, url = int(line[0]), line[1]
        assert not _gone(pid, 0.1)
        parent.send_signal(signal.SIGTERM)
        parent.wait(timeout=60)
        assert _gone(pid, 60.0), "the meshcat server outlived its parent"
        assert _port_free(_port(url))
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        parent.stdout.close()


# ------------------------------------------------------------------------------------------------
# the recording in a real browser (headless chromium, no network)
# ------------------------------------------------------------------------------------------------

def _chromium(url: str, *extra: str) -> subprocess.CompletedProcess:
    profile = tempfile.mkdtemp(prefix="feltool-chromium-")
    try:
        return subprocess.run(
            [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", "--disable-dev-shm-usage", f"--user-data-dir={profile}",
             # any attempt to reach the network fails: the page must not need it
             "--proxy-server=http://127.0.0.1:9", "--host-resolver-rules=MAP * ~NOTFOUND",
             "--virtual-time-budget=3000", "--window-size=800,600", *extra, url],
            capture_output=True, text=True, timeout=60)
    finally:
        shutil.rmtree(profile, ignore_errors=True)


@pytest.mark.skipif(not CHROMIUM.exists(), reason="chromium is not installed (/usr/bin/chromium)")
def test_recording_renders_offline_in_chromium(arm_html, tmp_path):
    Image = pytest.importorskip("PIL.Image")
    url = arm_html.resolve().as_uri()

    dom = _chromium(url, "--dump-dom")
    assert 'data-feltool-status="ready"' in dom.stdout, dom.stderr[-2000:]
    errors = re.search(r'<div id="feltool-errors">(.*?)</div>', dom.stdout, re.S)
    assert errors and errors.group(1).strip() == "", errors and errors.group(1)

    shot = tmp_path / "arm.png"
    run = _chromium(url, f"--screenshot={shot}")
    assert shot.is_file(), run.stderr[-2000:]
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert img.shape[:2] == (600, 800)
    scene = img[100:]  # below the title bar
    assert scene.std() > 5, "the screenshot is uniform"
    r, g, b = scene[..., 0], scene[..., 1], scene[..., 2]
    orange = (r > 170) & (g > 0.35 * r) & (g < 0.8 * r) & (b < 0.45 * r)  # link2 (0.95 0.55 0.15)
    blue = (b > 140) & (b > r + 60) & (b > g + 30)  # link1 (0.20 0.45 0.80)
    assert orange.sum() > 200, f"only {orange.sum()} orange pixels: link 2 is not drawn"
    assert blue.sum() > 200, f"only {blue.sum()} blue pixels: link 1 is not drawn"


def test_record_html_all_primitive_shapes(arm, tmp_path):
    coal = pytest.importorskip("coal")
    from feltool.robot.robot import Robot

    shapes = {"box": coal.Box(0.1, 0.2, 0.3), "sphere": coal.Sphere(0.1),
              "cylinder": coal.Cylinder(0.05, 0.4), "cone": coal.Cone(0.05, 0.2),
              "capsule": coal.Capsule(0.05, 0.3), "ellipsoid": coal.Ellipsoid(0.1, 0.2, 0.3)}
    gm = pin.GeometryModel()
    for k, (name, shape) in enumerate(shapes.items()):
        obj = pin.GeometryObject(name, 1 + k % 2, pin.SE3(np.eye(3), np.array([0.3 * k, 0, 0])),
                                 shape)
        obj.meshColor = np.array([0.1 * k, 0.5, 0.9, 1.0])
        gm.addGeometryObject(obj)
    robot = Robot(name="shapes", model=arm.model, source="test", _visual_model=gm)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        path = record_html(robot, {"a": np.zeros((4, 2))}, 0.1, tmp_path / "shapes.html")
    types = {c["path"].rsplit("/", 1)[1]: c["object"]["geometries"][0]["type"]
             for c in _commands(path.read_text()) if c["type"] == "set_object"}
    assert types == {"box": "BoxGeometry", "sphere": "SphereGeometry",
                     "cylinder": "CylinderGeometry", "cone": "CylinderGeometry",
                     "capsule": "BufferGeometry", "ellipsoid": "SphereGeometry"}
