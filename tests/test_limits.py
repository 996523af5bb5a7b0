"""URDF joint and torque limits: reported, enforced, saturated."""

from __future__ import annotations

import json

import numpy as np

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS, ROOT, feltool

ARM = (ROOT / "robots" / "two_link_arm.urdf").read_text()
_ELBOW = '<joint name="elbow" type="revolute">'
_WIDE = '<limit lower="-6.2832" upper="6.2832" effort="1000" velocity="100"/>'
_TIGHT = '<limit lower="-0.3" upper="0.3" effort="8" velocity="100"/>'
_head, _elbow = ARM.split(_ELBOW)
TIGHT = _head + _ELBOW + _elbow.replace(_WIDE, _TIGHT, 1)  # the elbow's limits only


def tight_config(tmp_path, **sim):
    assert TIGHT != ARM
    (tmp_path / "tight_arm.urdf").write_text(TIGHT)
    text = (CONFIGS / "two_link_standard.yaml").read_text().replace(
        "robot: two_link_arm", "robot: tight_arm.urdf")
    for key, value in sim.items():
        text = text.replace("  cycles: 150", f"  cycles: 150\n  {key}: {value}")
    path = tmp_path / "tight.yaml"
    path.write_text(text)
    return path


def test_limits_are_reported_in_summary_and_terminal(tmp_path):
    out = tmp_path / "run"
    res = feltool("run", str(tight_config(tmp_path)), "--seeds", "0", "--cycles", "3", "--out",
                  str(out))
    assert res.returncode == 0, res.stderr
    limits = json.loads((out / "summary.json").read_text())["seeds"][0]["limits"]
    assert limits["joint_limit_steps"]["elbow"] > 0      # the elbow swings +-0.52 rad
    assert limits["torque_limit_steps"]["elbow"] > 0     # and needs more than 8 N m
    assert "shoulder" not in limits["joint_limit_steps"]
    assert "seed 0 hit the URDF's position limits of elbow" in res.stdout


def test_enforced_limits_hold_the_joint_and_saturation_clips_the_torque(tmp_path):
    exp = load_experiment(tight_config(tmp_path, joint_limits="enforce",
                                       torque_limits="saturate"))
    res = run_seed(exp, 0, 3)
    q = np.concatenate([res.traces["first_q_system"], res.traces["last_q_system"]])
    assert np.all(np.abs(q[:, 1]) <= 0.3 + 1e-12)
    assert res.summary["limits"]["joint_limit_steps"]["elbow"] > 0
    free = run_seed(load_experiment(tight_config(tmp_path)), 0, 3)
    qf = free.traces["first_q_system"][:, 1]
    assert np.abs(qf).max() > 0.3  # without enforcement the elbow leaves its range


def test_untouched_limits_change_nothing():
    a = run_seed(load_experiment(CONFIGS / "two_link_standard.yaml"), 0, 5)
    b = run_seed(load_experiment(CONFIGS / "two_link_standard.yaml",
                                 ["sim.joint_limits=ignore", "sim.torque_limits=ignore"]), 0, 5)
    assert a.rows == b.rows
    assert a.summary["limits"] == {"joint_limit_steps": {}, "torque_limit_steps": {}}
    assert b.summary["limits"] == "not checked"
