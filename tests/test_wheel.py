"""Bundled robots and configs work from an installed wheel, not only from a checkout."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile

from .conftest import ROOT


def test_wheel_ships_robots_and_configs_and_loads_them(tmp_path):
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet",
                            "-w", str(tmp_path / "dist"), str(ROOT)],
                           capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    wheel = next((tmp_path / "dist").glob("feltool-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    assert "feltool/_data/robots/two_link_arm.urdf" in names
    assert "feltool/_data/configs/two_link_standard.yaml" in names
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    # Run from a directory without the checkout, importing feltool from the unpacked wheel only.
    code = ("import feltool, sys; from feltool.robot.robot import load_robot; "
            "from feltool import load_experiment; "
            "assert 'site' in feltool.__file__, feltool.__file__; "
            "print(load_robot('two_link_human_arm').total_mass); "
            "print(load_experiment('two_link_standard').config.name)")
    env = dict(os.environ, PYTHONPATH=str(site))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=tmp_path, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["4.0", "two_link_standard"]
