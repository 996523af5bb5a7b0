"""Changes of the world during a run: the plant changes, the known model does not, FEL adapts."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.config.events import EventConfig
from feltool.errors import ConfigError
from feltool.plant.events import changed_model
from feltool.robot.robot import load_robot
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS


def test_payload_at_the_tip_adds_its_gravity_torque():
    robot = load_robot("two_link_arm")
    robot.set_gravity(9.8)
    plant = changed_model(robot.model, [EventConfig(cycle=1, kind="payload", frame="tip",
                                                    mass=0.2)])
    q = np.zeros(2)  # both links horizontal: the tip is 2 m out
    g0 = pin.computeGeneralizedGravity(robot.model, robot.model.createData(), q)
    g1 = pin.computeGeneralizedGravity(plant, plant.createData(), q)
    np.testing.assert_allclose(g1 - g0, [0.2 * 9.8 * 2.0, 0.2 * 9.8 * 1.0], atol=1e-12)


def test_slope_tilts_gravity_and_mass_scales_a_link():
    robot = load_robot("two_link_arm")
    robot.set_gravity(9.8)
    plant = changed_model(robot.model, [EventConfig(cycle=1, kind="slope", angle=0.1),
                                        EventConfig(cycle=1, kind="mass", link="link2", mass=2.0)])
    np.testing.assert_allclose(plant.gravity.linear, 9.8 * np.array([np.sin(0.1), 0, -np.cos(0.1)]))
    assert plant.inertias[2].mass == pytest.approx(2.0)
    assert robot.model.inertias[2].mass == pytest.approx(1.0)  # the known model is untouched


def test_unknown_event_frame_names_the_yaml_path():
    with pytest.raises(ConfigError) as err:
        load_experiment(CONFIGS / "two_link_standard.yaml",
                        ["events=[{cycle: 3, kind: payload, frame: nose, mass: 1}]"])
    assert "events.0.frame" in str(err.value)


def test_arm_payload_event_feedback_rises_then_falls_back():
    exp = load_experiment(CONFIGS / "two_link_standard.yaml",
                          ["events=[{cycle: 40, kind: payload, frame: tip, mass: 0.2}]"])
    fb = np.array([r["fb_abs_mean_error"] for r in run_seed(exp, 0, 70).rows])
    before = fb[38]  # cycle 39, the last before the event
    assert fb[39] > 2.0 * before  # the payload makes the feedback jump
    assert fb[-1] <= 2.0 * before  # and FEL brings it back down
