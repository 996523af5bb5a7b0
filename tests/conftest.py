"""Shared fixtures: paths, a seeded generator, and helpers to run the CLI as a user would."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
IN_CI = any(os.environ.get(v, "").lower() in ("1", "true", "yes") for v in ("CI", "FELTOOL_CI"))
ALLOWED_SKIP = "(allowed skip)"  # a skip reason that names a fact of the machine, not a tool
_skipped: list[str] = []


def pytest_runtest_logreport(report) -> None:
    if report.skipped:
        reason = report.longrepr[-1] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        if ALLOWED_SKIP not in reason:
            _skipped.append(f"{report.nodeid}: {reason}")


def pytest_sessionfinish(session, exitstatus) -> None:
    """In CI nothing skips silently: a missing browser, compiler or test dependency fails the
    run, naming each test it kept from running."""
    if IN_CI and _skipped and exitstatus == 0:
        print("\nCI: these tests were skipped, so CI fails (install what they name):\n  "
              + "\n  ".join(_skipped))
        session.exitstatus = 1


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


def feltool(*args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run the ``feltool`` command in a fresh interpreter, as a user would."""
    return subprocess.run([sys.executable, "-m", "feltool.cli", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)


def port_of(url: str) -> int:
    """The port number in a URL such as ``tcp://127.0.0.1:6000`` or ``http://127.0.0.1:7000/``."""
    return int(re.search(r":(\d+)(/|$)", url).group(1))


def port_free(port: int) -> bool:
    """Nothing listens on the port: a server could bind it (TIME_WAIT leftovers allowed)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def other_walker_urdf() -> str:
    """A torso-rooted five-link walker the project does not ship: the bundled one with other
    masses (torso 18 kg, thighs 5 kg, shins 2.5 kg), 0.45 m segments and continuous joints."""
    text = (ROOT / "robots" / "five_link_walker.urdf").read_text()
    for old, new in (('name="five_link_walker"', 'name="other_walker"'),
                     ('<mass value="12.0"/>', '<mass value="18.0"/>'),
                     ('<mass value="6.8"/>', '<mass value="5.0"/>'),
                     ('<mass value="3.2"/>', '<mass value="2.5"/>'),
                     ('xyz="0 0 -0.4"', 'xyz="0 0 -0.45"'),
                     ('type="revolute"', 'type="continuous"')):
        assert old in text
        text = text.replace(old, new)
    return text


def assert_written_gait_walks_from_elsewhere(gait: Path, tmp_path: Path, monkeypatch, capsys
                                             ) -> None:
    """``feltool run`` of the gait config ``gait`` (written by ``feltool gait --out``) from
    another working directory: seeds 0-2, 6 cycles, every seed walks every step (one step per
    cycle) and exits 0."""
    import json

    from feltool.cli.main import main

    other = tmp_path / "other"
    other.mkdir()
    monkeypatch.chdir(other)  # run from anywhere: the robot path is the written config's
    run_dir = tmp_path / "run"
    code = main(["run", str(gait), "--seeds", "0-2", "--out", str(run_dir), "--set",
                 "sim.cycles=6", "--set", "walking.poincare=false"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    assert "walked without falling: 3/3 seeds; not walking: 0" in out.out
    summary = json.loads((run_dir / "summary.json").read_text())
    assert [s["seed"] for s in summary["seeds"]] == [0, 1, 2]
    for seed in summary["seeds"]:  # every step of every cycle walked
        assert seed["walking"]["walked"] is True and seed["walking"]["not_walking"] is None
        assert seed["walking"]["steps"] == seed["cycles"] == 6


def edited_solo_urdf(directory: Path, extra_base_mass: float = 0.0) -> Path:
    """Solo-12's URDF as someone might publish their own quadruped, written to ``directory``:
    every joint renamed (``my_`` before its name), the base ``extra_base_mass`` [kg] heavier."""
    import xml.etree.ElementTree as ET

    import example_robot_data as erd

    root = ET.parse(erd.load("solo12").urdf).getroot()
    for link in root.iter("link"):
        if link.get("name") == "base_link":
            mass = link.find("inertial/mass")
            mass.set("value", str(float(mass.get("value")) + extra_base_mass))
    text = re.sub(r'(joint name="|joint=")([A-Z]{2}_)', r"\1my_\2",
                  ET.tostring(root, encoding="unicode"))
    path = Path(directory) / "my_quadruped.urdf"
    path.write_text(text)
    return path
