"""A run in the browser: ``feltool run --view`` in headless Chromium, ``rollout.html`` from
``file://``, the server's lifetime under SIGTERM, and its loopback-only web port.

The browser tests judge the WebGL canvas by its pixels: the robot is drawn (pixels in its link
colours), it moves (two screenshots at different times differ where the robot is), and hiding it
changes the image (its colours vanish). A blank or empty scene fails all three.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, feltool, port_free, port_of

CHROMIUM = Path("/usr/bin/chromium")
needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(),
                                    reason="chromium is not installed (/usr/bin/chromium); "
                                    "apt-get install -y chromium chromium-driver")
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
URL = re.compile(r"feltool viewer: open (http://\S+)")
SERVER_MARK = "LoopbackBridge"  # in the meshcat server subprocess's command line
DOCS_SHOT = ROOT / "docs" / "figures" / "viewer_screenshot.png"
UR5 = """
name: ur5_view
robot: example-robot-data:ur5
period_s: 1.0
sim: {rate_hz: 100, cycles: 2}
joints:
  shoulder_lift_joint:
    role: track
    demo: {kind: sine, mean: -1.2, amplitude: 0.3}
    gains: {kp: 400.0, kd: 40.0}
  elbow_joint:
    role: stabilize
    target: {link_angle: [shoulder_lift_joint, elbow_joint], value: -0.3}
    gains: {kp: 200.0, kd: 20.0}
    learn: {init: random, weight_scale: 0.3, goal_spread: 0.1}
learning: {error: stabilizing, rates: {weights: 0.01, goal: 1.0e-6}}
seeds: 1
"""


# ------------------------------------------------------------------------------------------------
# pixels
# ------------------------------------------------------------------------------------------------

def _robot_mask(img: np.ndarray) -> np.ndarray:
    """Pixels in the two-link arm's colours: link 1 blue (0.20 0.45 0.80), link 2 orange
    (0.95 0.55 0.15), solid or seen through the ghost."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    orange = (r > 170) & (g > 0.35 * r) & (g < 0.8 * r) & (b < 0.6 * r)
    blue = (b > 140) & (b > r + 40) & (b > g + 20)
    return orange | blue


def _dilate(mask: np.ndarray, k: int = 6) -> np.ndarray:
    out = mask.copy()
    for dy in range(-k, k + 1, 2):
        for dx in range(-k, k + 1, 2):
            out |= np.roll(np.roll(mask, dy, 0), dx, 1)
    return out


def _png(data: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def _assert_drawn_moving_hideable(page, what: str) -> tuple[np.ndarray, bytes]:
    """The three pixel checks on the page's WebGL canvas; returns a screenshot (array, png)."""
    canvas = page.locator("canvas").first
    # meshcat's world axes (a blue z axis) are not the robot: out of the picture
    page.evaluate("viewer.handle_command({type: 'set_property', path: '/Axes', "
                  "property: 'visible', value: false})")
    deadline = time.monotonic() + 60
    while True:  # until the robot is drawn
        png = canvas.screenshot()
        a = _png(png)
        if _robot_mask(a).sum() > 300 or time.monotonic() > deadline:
            break
        page.wait_for_timeout(200)
    assert a.std() > 3, f"{what}: the canvas is uniform (nothing drawn)"
    robot = _robot_mask(a)
    assert robot.sum() > 300, f"{what}: only {robot.sum()} pixels in the robot's colours"

    deadline = time.monotonic() + 60  # a generous bound, not a timing claim
    while True:  # a recording holds each clip's last pose for a moment: try again
        page.wait_for_timeout(100)
        b = _png(canvas.screenshot())
        where = _dilate(robot | _robot_mask(b))
        changed = np.abs(a.astype(int) - b.astype(int)).sum(axis=2) > 30
        if changed[where].sum() > 50 or time.monotonic() > deadline:
            break
    assert changed[where].sum() > 50, f"{what}: the robot did not move between two screenshots"
    assert changed[where].sum() > 0.6 * changed.sum(), \
        f"{what}: the change is not where the robot is"

    page.evaluate("viewer.handle_command({type: 'set_property', path: '/meshcat/feltool', "
                  "property: 'visible', value: false})")
    deadline = time.monotonic() + 60
    while True:  # until the next frame is rendered without the robot
        c = _png(canvas.screenshot())
        if _robot_mask(c).sum() < 0.05 * robot.sum() or time.monotonic() > deadline:
            break
        page.wait_for_timeout(50)
    assert _robot_mask(c).sum() < 0.05 * robot.sum(), f"{what}: hiding the robot left its pixels"
    assert (np.abs(b.astype(int) - c.astype(int)).sum(axis=2) > 30)[where].sum() > 200, \
        f"{what}: hiding the robot did not change the image"
    page.evaluate("viewer.handle_command({type: 'set_property', path: '/meshcat/feltool', "
                  "property: 'visible', value: true})")
    return a, png


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.exists():
        pytest.skip("chromium is not installed (/usr/bin/chromium); "
                    "apt-get install -y chromium chromium-driver")
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="playwright is not installed (pip install playwright)")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=[
            "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--disable-quic", "--disable-background-networking", "--disable-component-update",
            "--disable-sync", "--disable-dev-shm-usage", "--ignore-gpu-blocklist"])
        yield b
        b.close()


def _wait_for_url(proc: subprocess.Popen, timeout: float = 120) -> tuple[str, list[str]]:
    lines: list[str] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        m = URL.search(line)
        if m:
            return m.group(1), lines
    raise AssertionError("no viewer URL printed:\n" + "".join(lines))


def _server_of(pid: int):
    import psutil

    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        for child in psutil.Process(pid).children(recursive=True):
            try:
                if any(SERVER_MARK in part for part in child.cmdline()):
                    return child
            except psutil.NoSuchProcess:
                continue
        time.sleep(0.1)
    raise AssertionError("the meshcat server process was not found")


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=60)
    if proc.stdout:
        proc.stdout.close()


# ------------------------------------------------------------------------------------------------
# live: feltool run --view
# ------------------------------------------------------------------------------------------------

@needs_chromium
def test_run_view_streams_a_moving_robot_to_the_browser(browser, tmp_path):
    """The browser sees a moving robot whether it connects during the realtime run or after it
    (the page then replays): no race with the run's length. The streamed cycles are shown by
    the viewer's per-cycle lines; the run ends on Ctrl-C (SIGINT), not on a clock."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "feltool.cli", "run", "two_link_standard", "--seeds", "0-1",
         "--cycles", "6", "--realtime", "--view", "--view-timeout", "600", "--out",
         str(tmp_path / "run"), "--no-progress"], stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True, env=ENV, start_new_session=True)
    try:
        url, lines = _wait_for_url(proc)
        assert url.startswith("http://127.0.0.1:")
        page = browser.new_page(viewport={"width": 800, "height": 600})
        page.goto(url)
        _assert_drawn_moving_hideable(page, "live view")
        page.close()
        while not any("feltool viewer: serving" in ln for ln in lines):  # the run is over
            line = proc.stdout.readline()
            assert line, "".join(lines)
            lines.append(line)
        os.killpg(proc.pid, signal.SIGINT)
        rest, _ = proc.communicate(timeout=120)
        out = "".join(lines) + rest
        assert proc.returncode == 0, out
        assert re.search(r"view: seed 0: cycle 6/6, error feedback [\d.e+-]+ N m", out), out
        assert (tmp_path / "run" / "summary.json").is_file()
    finally:
        _stop(proc)


@needs_chromium
def test_view_url_still_shows_the_robot_after_the_run_has_ended(browser, tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "feltool.cli", "run", "two_link_standard", "--seeds", "0",
         "--cycles", "2", "--view", "--view-timeout", "120", "--out", str(out),
         "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV,
        start_new_session=True)
    try:
        url, lines = _wait_for_url(proc)
        deadline = time.monotonic() + 60
        while not any("feltool viewer: serving" in ln for ln in lines):  # the run is over
            assert time.monotonic() < deadline and proc.poll() is None, "".join(lines)
            lines.append(proc.stdout.readline())
        assert any("run directory" in ln for ln in lines), "".join(lines)
        assert (out / "summary.json").is_file()
        time.sleep(1.0)  # a user who opens the page a moment later
        page = browser.new_page(viewport={"width": 800, "height": 600})
        page.goto(url)
        _assert_drawn_moving_hideable(page, "view after the run")
        page.close()
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C ends the viewing, not the results
        rest, _ = proc.communicate(timeout=120)
        assert proc.returncode == 0, "".join(lines) + rest
        assert "feltool viewer: stopped" in rest
    finally:
        _stop(proc)


# ------------------------------------------------------------------------------------------------
# rollout.html: written by run --html and view --html, played from file:// with no server
# ------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def html_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rollout") / "run"
    res = feltool("run", "two_link_standard", "--seeds", "0-1", "--cycles", "40", "--html",
                  "--out", str(out), "--no-progress")
    assert res.returncode == 0, res.stderr
    assert f"rollout: {out / 'rollout.html'}" in res.stdout
    return out


def test_run_html_holds_first_and_last_cycle(html_run):
    page = (html_run / "rollout.html").read_text(encoding="utf-8")
    assert "first cycle (1), feedback" in page and "last cycle (40), feedback" in page
    assert "two_link_standard, seed 0" in page
    from feltool.viewer.scene import viewer_js_source

    ours = page.replace(viewer_js_source(), "")  # meshcat's bundle names a default server it never calls
    assert "127.0.0.1" not in ours and "ws://" not in ours


def test_view_html_rewrites_the_page_for_a_chosen_seed_and_cycle(html_run):
    first_seed_page = (html_run / "rollout.html").read_bytes()
    res = feltool("view", str(html_run), "--html", "--seed", "1", "--cycles", "last")
    assert res.returncode == 0, res.stderr
    # another seed gets its own file: the run's rollout.html is not overwritten
    assert (html_run / "rollout.html").read_bytes() == first_seed_page
    page = (html_run / "rollout-seed1.html").read_text(encoding="utf-8")
    assert "seed 1" in page and "last cycle (40)" in page and "first cycle" not in page
    for args, needle in ((["--seed", "7"], "no traces for seed 7"),
                         (["--cycles", "middle"], "--cycles")):
        res = feltool("view", str(html_run), "--html", *args)
        assert res.returncode == 2 and needle in res.stderr and "Traceback" not in res.stderr


@needs_chromium
def test_rollout_html_plays_offline_from_file(browser, html_run):
    import psutil

    assert not [c for c in psutil.net_connections("inet") if c.status == psutil.CONN_LISTEN
                and c.laddr.port in (6000, 7000)], "a meshcat server is running"
    page = browser.new_page(viewport={"width": 800, "height": 600})
    requests: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    page.on("websocket", lambda ws: requests.append(ws.url))
    url = (html_run / "rollout.html").resolve().as_uri()
    page.goto(url)
    page.wait_for_selector('body[data-feltool-status="ready"]', timeout=20_000)
    assert page.inner_text("#feltool-errors").strip() == ""
    assert page.inner_text("#feltool-clip").startswith(("first cycle", "last cycle"))
    _, png = _assert_drawn_moving_hideable(page, "rollout.html")
    page.close()
    assert requests and all(u.startswith("file:") for u in requests), requests
    if os.environ.get("FELTOOL_UPDATE_DOCS") == "1":
        from PIL import Image

        full = _png(png)
        DOCS_SHOT.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(full).save(DOCS_SHOT, optimize=True)


# ------------------------------------------------------------------------------------------------
# the server: stopped on SIGTERM, loopback only
# ------------------------------------------------------------------------------------------------

_port = port_of
_port_free = port_free


def test_sigterm_stops_the_run_and_its_meshcat_server(tmp_path):
    import psutil

    proc = subprocess.Popen(
        [sys.executable, "-m", "feltool.cli", "run", "two_link_standard", "--seeds", "0-2",
         "--cycles", "60", "--realtime", "--workers", "2", "--out", str(tmp_path / "run"),
         "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV)
    try:
        url, _ = _wait_for_url(proc)
        server = _server_of(proc.pid)
        web = _port(url)
        ports = {c.laddr.port for c in server.net_connections("inet")
                 if c.status == psutil.CONN_LISTEN}
        assert web in ports and len(ports) == 2, ports
        deadline = time.monotonic() + 120  # learning under way: the pool's workers exist
        while len(psutil.Process(proc.pid).children(recursive=True)) < 3:  # server + 2 workers
            assert time.monotonic() < deadline and proc.poll() is None, "no worker processes"
            time.sleep(0.05)
        family = [server] + [c for c in psutil.Process(proc.pid).children(recursive=True)]
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=120)
        assert proc.returncode == 128 + signal.SIGTERM, out
        assert "Traceback" not in out, out
        _, alive = psutil.wait_procs(family, timeout=60)
        assert not alive, f"left running: {[p.pid for p in alive]}"
        assert all(_port_free(p) for p in ports), ports
    finally:
        _stop(proc)


def _non_loopback_ipv4() -> str | None:
    import psutil

    for addrs in psutil.net_if_addrs().values():
        for a in addrs:
            if a.family == socket.AF_INET and not a.address.startswith("127."):
                return a.address
    return None


def test_web_port_is_not_reachable_on_a_non_loopback_address():
    from feltool.robot.robot import load_robot
    from feltool.viewer.live import LiveViewer

    address = _non_loopback_ipv4()
    if address is None:
        pytest.skip("this machine has no non-loopback IPv4 address to try (allowed skip)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        robot = load_robot("two_link_arm")
    with LiveViewer(robot, quiet=True) as viewer:
        for port in (_port(viewer.url), _port(viewer.zmq_url)):
            with socket.create_connection(("127.0.0.1", port), timeout=2):
                pass  # served on loopback ...
            with pytest.raises(OSError):  # ... refused on the machine's other address
                socket.create_connection((address, port), timeout=2).close()


# ------------------------------------------------------------------------------------------------
# replay, and a robot with meshes and locked joints
# ------------------------------------------------------------------------------------------------

def test_view_replays_a_run_in_the_live_viewer(html_run):
    """Played once, then the page stays up (showing the last pose) until --view-timeout: the
    page answers after the play has ended, and the command then ends by itself. No wall-clock
    assertion; the 10 s timeout is only the margin for one HTTP request."""
    import urllib.request

    proc = subprocess.Popen([sys.executable, "-m", "feltool.cli", "view", str(html_run),
                             "--cycles", "first", "--loops", "1", "--view-timeout", "10"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        url, lines = _wait_for_url(proc)
        while not any("view: seed 0, first cycle (1)" in ln for ln in lines):
            line = proc.stdout.readline()
            assert line, "".join(lines)
            lines.append(line)
        assert "MeshCat" in urllib.request.urlopen(url, timeout=5).read().decode()
        rest, err = proc.communicate(timeout=120)
        out = "".join(lines) + rest
        assert proc.returncode == 0, err
        assert out.count("view: seed 0, first cycle (1)") == 1
        assert "until Ctrl-C or 10 s" in out and "feltool viewer: stopped" in out
    finally:
        _stop(proc)


def test_example_robot_data_mesh_robot_with_locked_joints(tmp_path):
    pytest.importorskip("example_robot_data")
    import umsgpack

    from feltool.runs.experiments import load_experiment
    from feltool.viewer.live import LiveViewer
    from feltool.viewer.rollout import LiveStream

    config = tmp_path / "ur5.yaml"
    config.write_text(UR5)
    res = feltool("run", str(config), "--html", "--out", str(tmp_path / "run"), "--no-progress")
    assert res.returncode == 0, res.stderr
    page = (tmp_path / "run" / "rollout.html").read_text(encoding="utf-8")
    found = re.search(r'id="feltool-commands">(.*?)</script>', page, re.S).group(1)
    import base64
    import json

    cmds = [umsgpack.unpackb(base64.b64decode(c)) for c in json.loads(found)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exp = load_experiment(config)
    assert exp.robot.model.nq == 2  # four of the six joints are locked
    n_geoms = len(exp.robot.visual_model.geometryObjects)
    assert n_geoms >= 6  # the UR5's meshes, carried through the reduction
    objects = [c for c in cmds if c["type"] == "set_object"]
    assert len(objects) == 2 * n_geoms  # system and ghost
    with LiveViewer(exp.robot, quiet=True) as viewer, \
            LiveStream(viewer, exp.config.dt, realtime=True, out=None) as stream:
        q = np.linspace([-1.2, 0.5], [-1.0, 0.8], 10)
        stream.play(q, q + 0.1)
        assert stream.frames_drawn >= 3


# ------------------------------------------------------------------------------------------------
# robots with mesh files: drawn from their meshes in the browser
# ------------------------------------------------------------------------------------------------

_MESHES_JS = """() => {
  const out = [];
  viewer.scene.traverse(o => {
    if (!o.isMesh) return;
    const path = [];
    for (let p = o; p; p = p.parent) if (p.name) path.unshift(p.name);
    const pos = o.geometry.attributes.position;
    out.push([path.join("/"), o.geometry.type, pos ? pos.count : 0]);
  });
  return out;
}"""


@needs_chromium
@pytest.mark.parametrize("config", ["ur5_wrist_level", "panda_hand_level"])
def test_panda_and_ur5_appear_with_their_meshes(browser, config, tmp_path):
    """rollout.html of a real run, opened in Chromium: every visual of the robot is a mesh
    loaded from its Collada file (three.js's loader finds the triangles Pinocchio's loader
    found, to 0.1 %), the ghost Pinocchio's own triangles, and no box or cylinder stands in
    for a link."""
    from feltool.runs.experiments import load_experiment

    out = tmp_path / "run"
    res = feltool("run", config, "--seeds", "0", "--cycles", "1", "--html", "--out", str(out),
                  "--no-progress")
    assert res.returncode == 0, res.stderr
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        visuals = load_experiment(ROOT / "configs" / f"{config}.yaml").robot.visual_model
    page = browser.new_page(viewport={"width": 800, "height": 600})
    page.goto((out / "rollout.html").resolve().as_uri())
    page.wait_for_selector('body[data-feltool-status="ready"]', timeout=120_000)
    assert page.inner_text("#feltool-errors").strip() == ""
    meshes = {path.split("/meshcat/feltool/", 1)[1]: (kind, count)
              for path, kind, count in page.evaluate(_MESHES_JS) if "/meshcat/feltool/" in path}
    page.close()
    assert len(meshes) == 2 * len(visuals.geometryObjects), sorted(meshes)
    for geom in visuals.geometryObjects:
        assert geom.meshPath.endswith(".dae"), geom.meshPath
        kind, count = meshes[f"system/{geom.name}"]
        assert kind == "BufferGeometry"
        assert count == pytest.approx(3 * geom.geometry.num_tris, rel=1e-3), geom.name
        assert meshes[f"ghost/{geom.name}"] == ("BufferGeometry", geom.geometry.num_vertices)
    assert not {kind for kind, _ in meshes.values()} & {"BoxGeometry", "CylinderGeometry",
                                                        "SphereGeometry"}


@needs_chromium
def test_a_legged_run_replays_in_the_browser_a_moving_robot(browser, tmp_path):
    """``feltool view`` on a legged run (Solo-12, 3 cycles): the canvas shows the robot (the
    pixels that vanish when it is hidden) and the robot moves between two screenshots."""
    out = tmp_path / "legged"
    run = feltool("run", str(ROOT / "configs" / "legged" / "solo12_trot.yaml"), "--seeds", "0",
                  "--cycles", "3", "--set", "walking.acquire=0", "--out", str(out),
                  "--no-progress")
    assert run.returncode in (0, 1) and (out / "summary.json").is_file(), run.stderr
    proc = subprocess.Popen([sys.executable, "-m", "feltool.cli", "view", str(out),
                             "--view-timeout", "300"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=ENV,
                            start_new_session=True)
    try:
        url, lines = _wait_for_url(proc)
        page = browser.new_page(viewport={"width": 800, "height": 600})
        page.goto(url)
        page.evaluate("viewer.handle_command({type: 'set_property', path: '/Axes', "
                      "property: 'visible', value: false})")
        canvas = page.locator("canvas").first
        page.wait_for_timeout(3000)  # the scene loaded and the replay under way

        def robot_hidden(hidden: bool) -> np.ndarray:
            page.evaluate("viewer.handle_command({type: 'set_property', path: "
                          f"'/meshcat/feltool', property: 'visible', value: {str(not hidden).lower()}}})")
            page.wait_for_timeout(300)
            return _png(canvas.screenshot())

        deadline = time.monotonic() + 60  # a generous bound, not a timing claim
        while True:
            a, empty = robot_hidden(False), robot_hidden(True)
            robot = np.abs(a.astype(int) - empty.astype(int)).sum(axis=2) > 30
            b = robot_hidden(False)
            moved = (np.abs(a.astype(int) - b.astype(int)).sum(axis=2) > 30) & _dilate(robot)
            if (robot.sum() > 300 and moved.sum() > 50) or time.monotonic() > deadline:
                break
        assert robot.sum() > 300, f"only {robot.sum()} pixels of the robot"
        assert moved.sum() > 50, "the robot did not move between two screenshots"
        page.close()
        os.killpg(proc.pid, signal.SIGINT)
        rest, _ = proc.communicate(timeout=120)
        assert proc.returncode == 0, "".join(lines) + rest
        assert "view: seed 0, last cycles" in "".join(lines) + rest
    finally:
        _stop(proc)
