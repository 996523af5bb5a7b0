"""A kneed walker whose URDF is rooted at a foot (issue 30, acceptance 1: walkers rooted
anywhere), written here: feltool re-roots its tree at the hip (feltool/robot/reroot.py). Its
model is the torso-rooted walker's (the same rigid-body dynamics in the same coordinates,
checked against that URDF built by Pinocchio directly: a reversed joint's angle is the
negative of the foot-rooted URDF's), and ``feltool gait CONFIG
--speed V --out elsewhere/gait.yaml`` exits 0 and ``feltool run elsewhere/gait.yaml`` walks
every step on 3 seeds from another directory."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.cli.main import main
from feltool.robot.robot import load_urdf_string, with_angle_coordinates
from feltool.walking.model import FootSpec, build_walker_model

from .conftest import assert_written_gait_walks_from_elsewhere

INERTIA = '<inertia ixx="0" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="0"/>'
THIGH, SHIN = 0.4, 0.4


def _link(name, mass, com, iyy):
    return (f'<link name="{name}"><inertial><origin xyz="0.01 0 {com}" rpy="0 0.1 0"/><mass '
            f'value="{mass}"/>{INERTIA.format(iyy=iyy)}</inertial><visual><origin xyz="0 0 '
            f'{com}"/><geometry><box size="0.04 0.04 0.3"/></geometry></visual></link>')


def _joint(name, parent, child, z, limits=""):
    kind = "revolute" if limits else "continuous"
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 {z}"/><axis xyz="0 1 0"/><limit {limits}effort="200" '
            'velocity="30"/></joint>')


def foot_rooted_urdf(knee_limits: bool = True) -> str:
    """Rooted at the left foot: left shin -> knee -> left thigh -> hip -> torso -> right leg,
    continuous joints (the left knee with limits when ``knee_limits``, so that reversing them
    shows)."""
    limits = 'lower="-0.1" upper="2.5" ' if knee_limits else ""
    parts = [_link("left_shin", 3.2, SHIN - 0.24, 0.2),
             _joint("q2_left", "left_shin", "left_thigh", SHIN, limits),
             _link("left_thigh", 6.8, THIGH - 0.11, 0.47),
             _joint("q1_left", "left_thigh", "torso", THIGH),
             _link("torso", 12.0, 0.24, 1.33),
             _joint("q1_right", "torso", "right_thigh", 0.0), _link("right_thigh", 6.8, -0.11, 0.47),
             _joint("q2_right", "right_thigh", "right_shin", -THIGH), _link("right_shin", 3.2,
                                                                            -0.24, 0.2)]
    return '<?xml version="1.0"?>\n<robot name="five_link_foot">' + "".join(parts) + "</robot>\n"


def torso_rooted_urdf() -> str:
    """The same walker rooted at the torso, both legs hanging along -z (the reference)."""
    parts = [_link("torso", 12.0, 0.24, 1.33)]
    for side in ("left", "right"):
        limits = 'lower="-2.5" upper="0.1" ' if side == "left" else ""
        parts += [_joint(f"q1_{side}", "torso", f"{side}_thigh", 0.0),
                  _link(f"{side}_thigh", 6.8, -0.11, 0.47),
                  _joint(f"q2_{side}", f"{side}_thigh", f"{side}_shin", -THIGH, limits),
                  _link(f"{side}_shin", 3.2, -0.24, 0.2)]
    return '<?xml version="1.0"?>\n<robot name="five_link_torso">' + "".join(parts) + "</robot>\n"


CONFIG = f"""robot: walker.urdf
walking:
  feet:
    left: {{link: left_shin, offset: [0, 0, 0]}}
    right: {{link: right_shin, offset: [0, 0, -{SHIN}]}}
  legs: [[q1_left, q1_right], [q2_left, q2_right]]
joints:
  base_pitch: {{role: stabilize, target: {{value: 0.1}}}}
"""
LEGS = [("q1_left", "q1_right"), ("q2_left", "q2_right")]


def test_the_foot_rooted_walker_is_rerooted_at_its_hip_with_the_torso_rooted_dynamics():
    foot = build_walker_model(with_angle_coordinates(load_urdf_string(foot_rooted_urdf(), "foot")),
                              {"left": FootSpec(link="left_shin"),
                               "right": FootSpec(link="right_shin", offset=(0, 0, -SHIN))}, LEGS)
    ref = build_walker_model(with_angle_coordinates(load_urdf_string(torso_rooted_urdf(),
                                                                     "torso")),
                             {"left": FootSpec(link="left_shin", offset=(0, 0, -SHIN)),
                              "right": FootSpec(link="right_shin", offset=(0, 0, -SHIN))}, LEGS)
    mf, mr = foot.model, ref.model
    assert mf.nv == mr.nv == 7 and mf.nq == mf.nv
    assert any("re-rooted at its hip link 'torso'" in w for w in foot.robot.warnings)
    assert foot.chained == ()  # both pairs exchange as plain pairs now
    # the same coordinates by name: a reversed joint's angle is the negative of the foot-rooted
    # URDF's, which is the torso-rooted walker's own (its child relative to its parent)
    P = np.zeros((mr.nv, mr.nv))
    for name in list(mr.names)[1:]:
        P[mf.joints[mf.getJointId(name)].idx_v, mr.joints[mr.getJointId(name)].idx_v] = 1.0
    i = mf.joints[mf.getJointId("q2_left")].idx_q  # limits reversed: [-2.5, 0.1]
    assert np.allclose([mf.lowerPositionLimit[i], mf.upperPositionLimit[i]], [-2.5, 0.1])
    rng = np.random.default_rng(0)
    df, dr = mf.createData(), mr.createData()
    for _ in range(5):
        q, v, a = (rng.normal(size=mr.nv) for _ in range(3))
        qf, vf, af = P @ q, P @ v, P @ a
        np.testing.assert_allclose(pin.rnea(mf, df, qf, vf, af), P @ pin.rnea(mr, dr, q, v, a),
                                   rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(pin.crba(mf, df, qf), P @ pin.crba(mr, dr, q) @ P.T,
                                   rtol=1e-10, atol=1e-10)  # (upper triangles filled alike)
        pin.framesForwardKinematics(mf, df, qf)
        pin.framesForwardKinematics(mr, dr, q)
        for f in ("left", "right"):  # the feet where they were
            np.testing.assert_allclose(foot.foot_position(df, f), ref.foot_position(dr, f),
                                       atol=1e-12)


def test_a_foot_rooted_kneed_walker_designs_writes_elsewhere_and_walks_3_seeds(
        tmp_path, monkeypatch, capsys):
    src = tmp_path / "src"
    src.mkdir()
    (src / "walker.urdf").write_text(foot_rooted_urdf(knee_limits=False))  # (as FROST's)
    (src / "five_foot.yaml").write_text(CONFIG)
    monkeypatch.chdir(src)
    code = main(["gait", "five_foot.yaml", "--speed", "0.8", "--out", "elsewhere/gait.yaml",
                 "--no-progress"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    assert "walked 20 steps: yes" in out.out
    assert "robot: ../walker.urdf" in (src / "elsewhere" / "gait.yaml").read_text()
    assert_written_gait_walks_from_elsewhere(src / "elsewhere" / "gait.yaml", tmp_path,
                                             monkeypatch, capsys)
