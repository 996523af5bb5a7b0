"""A quadruped URDF as published, straight-legged at its zeros, gets a bent reference posture
(feltool.walking.legged.crouch), checked against geometry computed here and against the
posture the robots' authors chose (example-robot-data's q0); and it trots from a config that
names nothing but the file."""

from __future__ import annotations

import json
from dataclasses import replace

import example_robot_data as erd
import numpy as np
import pytest
import yaml

from feltool.cli.main import main
from feltool.runs.legged_robot import straight_legs
from feltool.walking.legged.crouch import CROUCH, crouched
from feltool.walking.legged.model import load_legged_urdf


@pytest.mark.parametrize("name", ["go1", "a1", "go2", "b1"])
def test_a_straight_urdf_is_crouched_knees_back_as_its_authors_stand_it(name):
    """Each foot ends higher than in the straight posture (by CROUCH of its reach, the next
    test), at the same place horizontally; the joints within the URDF's limits; the
    leg no longer singular; every joint example-robot-data's q0 bends by more than 0.3 rad
    bent the same way (knees back)."""
    robot = erd.load(name)
    legged = load_legged_urdf(robot.urdf)
    m = legged.model
    assert straight_legs(legged) == list(legged.feet)
    q = crouched(m, legged.q0, legged.feet)
    assert q is not None
    straight = legged.foot_positions(legged.q0)
    moved = legged.foot_positions(q) - straight
    assert np.allclose(moved[:, :2], 0.0, atol=1e-8) and np.all(moved[:, 2] > 0.05)
    lo, hi = m.lowerPositionLimit[7:], m.upperPositionLimit[7:]
    assert np.all(q[7:] >= lo - 1e-9) and np.all(q[7:] <= hi + 1e-9)
    authors = np.array(robot.q0)[7:]
    bent = np.abs(authors) > 0.3
    assert np.all(np.sign(q[7:][bent]) == np.sign(authors[bent])), (q[7:], authors)
    assert straight_legs(replace(legged, q0=q)) == []


def test_solo12s_hind_knees_bend_back_where_its_authors_bend_them_forward():
    """The rule is knees back on every leg: Solo-12's front legs as example-robot-data stands
    them (HFE 0.8, KFE -1.6), its hind legs the mirror of its authors' (they stand knees in)."""
    robot = erd.load("solo12")
    legged = load_legged_urdf(robot.urdf)
    q = crouched(legged.model, legged.q0, legged.feet)[7:].reshape(4, 3)
    authors = np.array(robot.q0)[7:].reshape(4, 3)
    assert np.all(np.sign(q[:2, 1:]) == np.sign(authors[:2, 1:]))
    assert np.all(np.sign(q[2:, 1:]) == -np.sign(authors[2:, 1:]))


def test_the_crouch_is_the_fraction_of_the_reach_from_the_second_joint():
    """Solo-12's URDF: its leg's second joint (HFE) to its foot, straight, is the thigh plus
    the shank placed in one line (its URDF's placements); each foot is CROUCH of that higher."""
    legged = load_legged_urdf(erd.load("solo12").urdf)
    q = crouched(legged.model, legged.q0, legged.feet)
    rise = legged.foot_positions(q)[:, 2] - legged.foot_positions(legged.q0)[:, 2]
    m = legged.model
    for i, frame in enumerate(legged.feet.values()):
        knee = m.frames[frame].parentJoint
        thigh = m.parents[knee]
        length = np.linalg.norm(m.jointPlacements[knee].translation  # straight: one line
                                + m.frames[frame].placement.translation)
        assert m.names[thigh].endswith("HFE")
        assert rise[i] == pytest.approx(CROUCH * length, rel=1e-9)


def test_a_quadruped_urdf_naming_nothing_trots_and_records_its_posture(tmp_path, capsys):
    """Go1's URDF as published (no feet, no posture: found, crouched): the run trots its 3
    cycles, and config.yaml records the posture it ran with; run again from that record, the
    robot stands in the same posture (the first rows equal)."""
    raw = {"name": "go1_urdf", "robot": str(erd.load("go1").urdf),
           "walking": {"base": "free_flyer", "acquire": 0}, "sim": {"cycles": 3},
           "seeds": [0]}
    path = tmp_path / "go1.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--no-progress"]) == 0, \
        capsys.readouterr().err
    seed = json.loads((out / "summary.json").read_text())["seeds"][0]
    assert seed["walked"] and seed["cycles"] == 3
    recorded = yaml.safe_load((out / "config.yaml").read_text())
    posture = recorded["walking"]["posture"]
    assert set(posture) == {f"{leg}_{part}_joint" for leg in ("FL", "FR", "RL", "RR")
                            for part in ("hip", "thigh", "calf")}
    assert all(posture[f"{leg}_calf_joint"] < -0.89 for leg in ("FL", "FR", "RL", "RR"))
    from feltool.config.legged import parse_legged_config
    from feltool.runs.legged_robot import load_legged_robot

    again = load_legged_robot(parse_legged_config(recorded))
    first = load_legged_robot(parse_legged_config(raw))
    assert np.array_equal(again.q0, first.q0)
