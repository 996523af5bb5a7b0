"""The feltool command as a user runs it: run directory, exit codes, messages, reproducibility."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from feltool.runs.rundir import load_npz

from .conftest import CONFIGS, feltool

STANDARD = str(CONFIGS / "two_link_standard.yaml")


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "standard"
    res = feltool("run", STANDARD, "--seeds", "0-3", "--cycles", "25", "--out", str(out),
                  "--workers", "2")
    assert res.returncode == 0, res.stderr
    return out, res


def test_run_writes_the_run_directory(short_run):
    out, res = short_run
    assert "converged" in res.stdout and str(out) in res.stdout
    for name in ("config.yaml", "metrics.csv", "summary.json", "params/seed-0.npz",
                 "params/seed-3.npz", "figures/feedback_convergence.png",
                 "figures/weight_convergence.png", "figures/trajectories_first_last.png"):
        assert (out / name).is_file(), name
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert len(rows) == 4 * 25
    for col in ("seed", "cycle", "fb_abs_mean_shoulder", "fb_abs_mean_elbow",
                "fb_abs_mean_stabilized", "fb_abs_mean_total", "track_err_rms_shoulder",
                "track_err_rms_elbow", "param_norm"):
        assert col in rows[0]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config"] == "two_link_standard" and summary["feltool_version"]
    seeds = summary["seeds"]
    assert [s["seed"] for s in seeds] == [0, 1, 2, 3]
    for s in seeds:
        for key in ("cycles", "fb_initial", "fb_final", "converged_cycle", "wall_s",
                    "steps_per_s", "diverged"):
            assert key in s
        assert s["diverged"] is False and s["fb_final"] < 0.5 * s["fb_initial"]
    params = load_npz(out / "params" / "seed-0.npz")
    assert params["elbow.weights"].shape == (10,) and params["elbow.goal"].shape == ()
    assert params["elbow.weights_history"].shape == (26, 10)


def test_summary_reports_the_learning_loop_compile_and_wall_apart(short_run):
    """steps/s counts the learning cycles only: each seed's control steps over its time inside
    the cycles (not its wall time, which includes metrics, checkpoints and progress); the run
    adds them up and reports the compile time and the whole wall time beside them."""
    out, res = short_run
    summary = json.loads((out / "summary.json").read_text())
    for s in summary["seeds"]:
        assert s["steps"] == 25 * 100
        assert 0 < s["loop_s"] <= s["wall_s"]
        assert s["steps_per_s"] == pytest.approx(s["steps"] / s["loop_s"], rel=1e-3)
    t = summary["timing"]
    assert t["steps"] == 4 * 25 * 100
    assert t["loop_s"] == pytest.approx(sum(s["loop_s"] for s in summary["seeds"]), rel=1e-4)
    assert t["steps_per_s"] == pytest.approx(t["steps"] / t["loop_s"], rel=1e-3)
    assert t["compile_s"] >= 0
    # the process started before the experiment was built and the seeds ran
    assert t["wall_s"] > max(s["wall_s"] for s in summary["seeds"]) + t["compile_s"]
    assert "timing: learning loop" in res.stdout and "since the process started" in res.stdout


def test_resolved_config_repeats_the_run_exactly(short_run, tmp_path):
    out, _ = short_run
    again = tmp_path / "again"
    res = feltool("run", str(out / "config.yaml"), "--seeds", "2", "--out", str(again))
    assert res.returncode == 0, res.stderr
    first = [r for r in csv.DictReader(open(out / "metrics.csv")) if r["seed"] == "2"]
    second = list(csv.DictReader(open(again / "metrics.csv")))
    assert first == second  # same config + seed -> same numbers, pool or not
    np.testing.assert_array_equal(load_npz(out / "params/seed-2.npz")["elbow.weights"],
                                  load_npz(again / "params/seed-2.npz")["elbow.weights"])


def test_plot_redraws_figures(short_run):
    out, _ = short_run
    (out / "figures" / "feedback_convergence.png").unlink()
    res = feltool("plot", str(out))
    assert res.returncode == 0, res.stderr
    assert (out / "figures" / "feedback_convergence.png").stat().st_size > 10_000


BAD = """\
name: bad
robot: two_link_arm
sim: {rate_hz: 100, cycles: many}
joints:
  shoulder:
    role: track
    demo: {kind: sine, mean: 1.57, amplitude: 0.5}
    gains: {kp: 100, kd: 20}
  elbow:
    role: stabilize
    target: {link_angle: [shoulder, elbow], value: 1.57}
    gains: {kp: 50, kd: 10}
    learn: {}
  wrist:
    role: track
    demo: {kind: sine, amplitude: 0.1}
    gains: {kp: 1, kd: 1}
learning:
  rates: {weights: -0.1}
"""


def test_check_reports_every_problem_with_its_yaml_path(tmp_path):
    """Unknown joint, negative rate, missing field, wrong type: one line each, exit 2."""
    path = tmp_path / "bad.yaml"
    path.write_text(BAD)
    res = feltool("check", str(path))
    assert res.returncode == 2
    assert "Traceback" not in res.stderr + res.stdout
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 4, res.stderr
    text = res.stderr
    assert "period_s: required field is missing" in text
    assert "sim.cycles:" in text and "integer" in text
    assert "learning.rates.weights:" in text and "greater than or equal to 0" in text
    assert "joints.wrist:" in text and "no joint 'wrist'" in text
    assert all(str(path) in line for line in lines)


@pytest.mark.parametrize("args, needle", [
    (["check", "does/not/exist.yaml"], "config file not found"),
    (["run", STANDARD, "--seeds", "x"], "--seeds"),
    (["run", STANDARD, "--cycles", "0"], "--cycles"),
    (["run", STANDARD, "--set", "joints.elbow.gains.kp=-3"], "joints.elbow.gains.kp"),
    (["run", STANDARD, "--set", "sim.bogus=1"], "sim.bogus: unknown field"),
    (["inspect", "no_such_robot"], "unknown robot 'no_such_robot'"),
    (["inspect", "example-robot-data:no_such"], "unknown example-robot-data robot"),
    (["frobnicate"], "invalid choice"),
])
def test_bad_input_exits_2_without_traceback(args, needle, tmp_path):
    res = feltool(*args, cwd=tmp_path)
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert needle in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "runs").exists()  # nothing that looks like a result


def test_every_bundled_config_passes_check():
    for path in sorted(CONFIGS.glob("*.yaml")):
        res = feltool("check", str(path))
        assert res.returncode == 0, (path, res.stderr)
        assert "ok" in res.stdout


def test_robots_and_inspect():
    res = feltool("robots")
    assert res.returncode == 0 and "two_link_arm" in res.stdout and "ur5" in res.stdout
    res = feltool("inspect", "two_link_human_arm", "--json")
    info = json.loads(res.stdout)
    assert [j["name"] for j in info["joints"]] == ["shoulder", "elbow"]
    assert info["total_mass"] == pytest.approx(4.0)


def test_diverging_seed_is_reported_and_keeps_its_metrics(tmp_path):
    """Too large a learning rate makes the arm fall: the seed stops with a clear message,
    "diverged": true, and every metric up to the failing cycle; exit code 1."""
    out = tmp_path / "div"
    res = feltool("run", STANDARD, "--seeds", "0", "--cycles", "30", "--out", str(out),
                  "--set", "learning.update=gradient", "--set", "learning.safeguard=false",
                  "--set", "learning.rates.weights=1010.6")
    assert res.returncode == 1
    assert "DIVERGED: seed 0, cycle" in res.stdout
    assert "Traceback" not in res.stderr and "Warning" not in res.stderr
    seed = json.loads((out / "summary.json").read_text())["seeds"][0]
    assert seed["diverged"] is True
    assert "non-finite" in seed["diverged_reason"] or "fell" in seed["diverged_reason"]
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert len(rows) == seed["cycles"] >= 1
    assert [int(r["cycle"]) for r in rows] == list(range(1, len(rows) + 1))


def test_saved_config_repeats_a_run_whose_urdf_is_relative(tmp_path):
    """A config naming its URDF relative to itself: the run directory's config.yaml points at
    the same file from anywhere."""
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "arm.urdf").write_text((CONFIGS.parent / "robots" / "two_link_arm.urdf").read_text())
    text = open(STANDARD).read().replace("robot: two_link_arm", "robot: arm.urdf")
    (tmp_path / "cfg" / "mine.yaml").write_text(text)
    out = tmp_path / "elsewhere" / "run"
    assert feltool("run", str(tmp_path / "cfg" / "mine.yaml"), "--seeds", "0", "--cycles", "2",
                   "--out", str(out)).returncode == 0
    res = feltool("check", str(out / "config.yaml"), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
