"""The live meshcat viewer: a loopback meshcat server started and stopped with feltool, and
rollouts streamed to it.
"""

from __future__ import annotations

import atexit
import math
import os
import re
import selectors
import subprocess
import sys
import tempfile
import threading
import time
import webbrowser

import pinocchio as pin

from feltool.errors import InputError
from feltool.viewer.scene import (
    DEFAULT_GHOST_OPACITY,
    GHOST,
    ROOT,
    SYSTEM,
    Scene,
    ViewerError,
    background_commands,
    import_meshcat,
)

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


#: [s] at most to wait for a server at ``zmq_url`` to answer its first request
HANDSHAKE_S = 5.0
_ZMQ_URL = re.compile(r"tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})|ipc://\S+")


def check_zmq_url(url: str) -> str:
    """``url`` if it is a ZMQ address a meshcat server can listen on (``tcp://HOST:PORT``, as
    ``meshcat-server`` prints it, or ``ipc://PATH``), else an :class:`InputError` naming it."""
    m = _ZMQ_URL.fullmatch(url.strip()) if isinstance(url, str) else None
    if m is None or (m.group(2) is not None and not 0 < int(m.group(2)) < 65536):
        raise InputError(f"--zmq-url {url!r}: not a meshcat server's ZMQ address; use "
                         "tcp://HOST:PORT as meshcat-server prints it (e.g. "
                         "tcp://127.0.0.1:6000)")
    return url.strip()


def _server_failure(err: str) -> str:
    """One line on why the meshcat server did not start, from its stderr."""
    lines = [ln.strip() for ln in err.splitlines() if ln.strip()]
    busy = [ln for ln in lines if "in use" in ln]
    last = next((ln for ln in reversed(lines) if "in use" not in ln), "")
    if "available port" in last or busy:
        span = re.search(r"\[(\d+), (\d+)\)", last)
        where = f" {span.group(1)}-{int(span.group(2)) - 1}" if span else ""
        return (f"every port it tried{where} is in use ({len(busy)} tried); stop other "
                "meshcat servers, or connect to one with --zmq-url")
    return last[:300]


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
        robot: A :class:`feltool.robot.robot.Robot`.
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

        _, self._umsgpack = import_meshcat()
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
        self.scene = Scene(robot, ghost=ghost, ghost_color=ghost_color,
                            ghost_opacity=ghost_opacity, ghost_offset=ghost_offset,
                            mesh_materials=mesh_materials)
        atexit.register(self.close)
        try:
            if zmq_url is None:
                self.zmq_url, self.url = self._start_server()
            else:
                self.zmq_url = check_zmq_url(zmq_url)
                self._connect(min(self._timeout, HANDSHAKE_S))
                try:
                    self.url = self._request(b"url").decode("utf-8", "replace")
                except ViewerError:
                    raise ViewerError(
                        f"--zmq-url {zmq_url}: no meshcat server answered within "
                        f"{min(self._timeout, HANDSHAKE_S):g} s (is one running there? leave "
                        "out --zmq-url to start one)") from None
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
            why = _server_failure(self._stderr.read().decode("utf-8", "replace")[-20000:])
            raise ViewerError("the meshcat server did not start"
                              + (f" (exit code {self._proc.poll()})" if self._proc.poll()
                                 is not None else f" within {self._timeout:g} s")
                              + (f": {why}" if why else ""))
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

    def _connect(self, timeout: float | None = None) -> None:
        zmq = self._zmq
        if self._context is None:
            self._context = zmq.Context()
        if self._socket is not None:
            self._socket.close(linger=0)
            self._socket = None
        ms = int((self._timeout if timeout is None else timeout) * 1000)
        sock = self._context.socket(zmq.REQ)
        try:
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.RCVTIMEO, ms)
            sock.setsockopt(zmq.SNDTIMEO, ms)
            sock.connect(self.zmq_url)
        except zmq.ZMQError as exc:
            sock.close(linger=0)  # an open socket would make closing the context wait forever
            raise InputError(f"--zmq-url {self.zmq_url}: cannot connect ({exc})") from None
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
        for cmd in ([{"type": "delete", "path": ROOT}] + background_commands() + objects
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
                self._context.destroy(linger=0)  # closes every socket: never waits
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
