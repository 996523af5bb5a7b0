"""Robustness scores: the goal test, the scenario overrides, and the command end to end."""

from __future__ import annotations

import json

from feltool.runs.robustness import SCENARIOS, overrides_for, points_to_run, reached

from .conftest import feltool


def test_goal_is_five_percent_of_the_first_cycle_over_the_tail():
    rows = [{"fb_abs_mean_error": f} for f in [10.0, 5.0] + [0.4] * 5]
    assert reached(rows, False) == (True, 0.04)
    rows[-1]["fb_abs_mean_error"] = 1.6  # tail mean 0.64: 6.4 %
    assert reached(rows, False)[0] is False
    assert reached(rows[:-1], True)[0] is False  # a diverged run never counts


def test_period_is_rounded_to_whole_samples():
    raw = {"period_s": 1.0, "sim": {"rate_hz": 100}}
    assert overrides_for(raw, SCENARIOS["period"], 1.234) == ["period_s=1.23"]
    assert overrides_for(raw, SCENARIOS["delay"], 3.0) == ["disturbances.input_delay_steps=3"]


def test_undisturbed_point_is_shared_only_by_scenarios_the_config_leaves_nominal():
    scenarios = [SCENARIOS["noise_q"], SCENARIOS["torque_noise"], SCENARIOS["mass"]]
    disturbed = {("gradient", sc.name, v) for sc in scenarios for v in sc.values[1:]}
    plain = points_to_run({"period_s": 1.0}, ["gradient"], scenarios)
    assert set(plain) == {("gradient", "nominal", 0.0)} | disturbed  # one undisturbed run
    # a config that brings its own torque noise: its undisturbed point turns that noise off,
    # the other scenarios' undisturbed point keeps it (the config as it is)
    noisy = {"period_s": 1.0, "disturbances": {"torque_noise": 0.3}}
    todo = points_to_run(noisy, ["gradient"], scenarios)
    assert "disturbances.torque_noise=0.0" in todo[("gradient", "torque_noise", 0.0)]
    assert not any("torque_noise" in o for o in todo[("gradient", "nominal", 0.0)])
    assert set(todo) == {("gradient", "nominal", 0.0), ("gradient", "torque_noise", 0.0)} \
        | disturbed


def test_robustness_command_scores_learners(tmp_path):
    out = tmp_path / "rob"
    res = feltool("robustness", "two_link_standard", "--learners", "gradient,feedback_only",
                  "--scenarios", "mass", "--range", "mass=1.0,0.75", "--seeds", "0",
                  "--cycles", "60", "--out", str(out), "-q")
    assert res.returncode == 0, res.stderr
    result = json.loads((out / "robustness.json").read_text())
    assert result["scores"] == {"gradient": {"mass": 1.0}, "feedback_only": {"mass": 0.0}}
    assert "| gradient | 1.00 | 1.00 |" in res.stdout
    assert len((out / "robustness.csv").read_text().splitlines()) == 1 + 4
    bad = feltool("robustness", "two_link_standard", "--learners", "ilc_q")
    assert bad.returncode == 2 and "--learners: unknown ilc_q" in bad.stderr
    assert "Traceback" not in bad.stderr
