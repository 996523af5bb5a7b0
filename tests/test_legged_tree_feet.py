"""A quadruped's feet found from its kinematic tree (feltool.walking.legged.tree_feet), checked
against what the robots' authors wrote: the feet example-robot-data's SRDFs name (``lf_foot``
.. ``rh_foot``), by position, and the front / left of each foot by where it is on the base."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from example_robot_data.robots_loader import load_full

from feltool.errors import ConfigError
from feltool.runs.legged_robot import srdf_feet
from feltool.walking.legged.model import load_legged_urdf
from feltool.walking.legged.tree_feet import quadruped_feet

from .conftest import edited_solo_urdf

#: example-robot-data's quadrupeds whose SRDF names their feet
SRDF_QUADRUPEDS = ("solo12", "go1", "go2", "a1", "anymal", "anymal_c", "hyq", "b1", "b1_z1",
                   "anymal_kinova")


def _positions(model: pin.Model, q: np.ndarray, feet: dict) -> dict[str, np.ndarray]:
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    return {f: data.oMf[model.getFrameId(spec["frame"])].translation for f, spec in feet.items()}


@pytest.mark.parametrize("name", SRDF_QUADRUPEDS)
def test_the_feet_found_are_the_ones_the_srdf_names(name):
    """Every example-robot-data quadruped with feet in its SRDF: the four leg ends found from
    the tree are those feet, each under the same name (b1_z1 and anymal_kinova carry an arm,
    whose end is not a foot)."""
    robot, q0, _, srdf = load_full(name)
    q0 = np.array(q0)
    found = _positions(robot.model, q0, quadruped_feet(robot.model, q0, name))
    named = _positions(robot.model, q0, srdf_feet(srdf))
    for foot in ("FL", "FR", "HL", "HR"):
        assert np.allclose(found[foot], named[foot], atol=1e-12), (foot, found, named)


def test_a_renamed_urdf_gets_its_feet_by_where_they_are():
    """Solo-12's URDF with every joint renamed and no feet named: its feet are Solo-12's
    FL_FOOT .. HR_FOOT points, front ahead of hind and left at +y of the base."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        legged = load_legged_urdf(edited_solo_urdf(tmp))
    base = pin.XYZQUATToSE3(legged.q0[:7])
    local = {f: base.rotation.T @ (p - base.translation)
             for f, p in zip(legged.feet, legged.foot_positions(legged.q0))}
    assert local["FL"][0] > 0 > local["HL"][0] and local["FR"][0] > 0 > local["HR"][0]
    assert local["FL"][1] > 0 > local["FR"][1] and local["HL"][1] > 0 > local["HR"][1]
    robot, _, _, srdf = load_full("solo12")
    solo = _positions(robot.model, legged.q0, srdf_feet(srdf))
    for foot, p in zip(legged.feet, legged.foot_positions(legged.q0)):
        assert np.allclose(p, solo[foot], atol=1e-12)


@pytest.mark.parametrize("name, ends", [("talos", 2), ("bolt", 2), ("solo8", 0)])
def test_a_robot_that_is_no_quadruped_is_refused_naming_walking_feet(name, ends):
    """A humanoid, a biped and legs of two joints: not four leg ends of three joints at the
    bottom of the robot."""
    robot, q0, _, _ = load_full(name)
    with pytest.raises(ConfigError) as err:
        quadruped_feet(robot.model, np.array(q0), name)
    (where, message), = err.value.problems
    assert where == "walking.feet" and f"its tree ends in {ends} at the bottom" in message


def test_feet_that_are_not_two_ahead_of_two_are_refused():
    """Solo-12 with its four legs turned 45 degrees about the base's z (hip placements rotated):
    both front feet at +y, no right foot ahead, refused."""
    robot, q0, _, _ = load_full("solo12")
    model = pin.Model(robot.model)
    turn = pin.SE3(pin.utils.rotate("z", np.pi / 4), np.zeros(3))
    for j in range(2, model.njoints):
        if model.parents[j] == 1:
            model.jointPlacements[j] = turn * model.jointPlacements[j]
    with pytest.raises(ConfigError, match="not two ahead of two"):
        quadruped_feet(model, np.array(q0), "solo12")
