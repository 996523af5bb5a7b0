"""Walkers as the field publishes them, written here (none of them is in the repo): FROST-style
five-link walkers (planar inertias ``ixx = izz = 0``, links along +z, continuous joints, no
foot frames) and compass gaits rooted at the stance foot (point masses, nameless materials),
each with a config naming only its robot, feet, legs and (five-link) the torso's target.
``feltool gait CONFIG --speed V --out elsewhere/gait.yaml`` must exit 0 and ``feltool run
elsewhere/gait.yaml`` walk every step on 3 seeds, from another directory.

Also: the planar inertia read leniently against the rigid body's dynamics (only I_yy acts in
the plane), urdfdom's stderr in the load report, the standing pose against closed forms, the
compiled verification against the Python loop's, and the compass-gait convention's passive
gait against Drake's (period 0.73446 s, step 0.53592 m on a 0.0525 rad slope).
"""

from __future__ import annotations

import os

import numpy as np
import pinocchio as pin
import pytest

from feltool.cli.main import main
from feltool.errors import RobotError
from feltool.robot.robot import captured_stderr, load_robot
from feltool.walking.model import FootSpec, build_walker_model
from feltool.walking.standing import standing_pose

from .conftest import assert_written_gait_walks_from_elsewhere

INERTIA = '<inertia ixx="0" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="0"/>'


def frost_urdf(thigh: float = 0.4, shin: float = 0.4, torso_mass: float = 12.0) -> str:
    """A five-link walker as FROST publishes it: torso root, legs along +z at zero angles,
    continuous joints, planar inertias, a nameless material, no foot frames."""
    def link(name, mass, com, iyy):
        return (f'<link name="{name}"><inertial><origin xyz="0 0 {com}"/><mass value="{mass}"/>'
                f'{INERTIA.format(iyy=iyy)}</inertial><visual><origin xyz="0 0 {com}"/>'
                '<geometry><box size="0.04 0.04 0.3"/></geometry><material><color rgba="0.5 '
                '0.5 0.5 1"/></material></visual></link>')

    def joint(name, parent, child, z):
        return (f'<joint name="{name}" type="continuous"><parent link="{parent}"/><child '
                f'link="{child}"/><origin xyz="0 0 {z}"/><axis xyz="0 1 0"/><limit '
                'effort="200" velocity="30"/></joint>')

    parts = [link("torso", torso_mass, 0.24, 1.33)]
    for side in ("left", "right"):
        parts += [link(f"{side}_thigh", 6.8, 0.11, 0.47), link(f"{side}_shin", 3.2, 0.24, 0.2),
                  joint(f"q1_{side}", "torso", f"{side}_thigh", 0.0),
                  joint(f"q2_{side}", f"{side}_thigh", f"{side}_shin", thigh)]
    return '<?xml version="1.0"?>\n<robot name="five_link">' + "".join(parts) + "</robot>\n"


FROST_CONFIG = """robot: walker.urdf
walking:
  feet:
    left: {{link: left_shin, offset: [0, 0, {shin}]}}
    right: {{link: right_shin, offset: [0, 0, {shin}]}}
  legs: [[q1_left, q1_right], [q2_left, q2_right]]
joints:
  base_pitch: {{role: stabilize, target: {{value: {torso}}}}}
"""


def compass_urdf(hip_mass: float = 10.0, leg_mass: float = 5.0, a: float = 0.5) -> str:
    """A compass gait as Drake and the underactuated-robotics course root it: at the stance
    foot, the hip 1 m above, point masses, nameless materials."""
    point = INERTIA.format(iyy=0).replace('iyy="0"', 'iyy="0"')
    return f"""<?xml version="1.0"?>
<robot name="CompassGait">
  <link name="stance_leg">
    <inertial><origin xyz="0 0 {a}"/><mass value="{leg_mass}"/>{point}</inertial>
    <visual><origin xyz="0 0 0.5"/><geometry><cylinder radius="0.01" length="1"/></geometry>
      <material><color rgba="1 0 0 1"/></material></visual>
  </link>
  <link name="hip"><inertial><mass value="{hip_mass}"/>{point}</inertial></link>
  <joint name="hip_weld" type="fixed"><parent link="stance_leg"/><child link="hip"/>
    <origin xyz="0 0 1"/></joint>
  <link name="swing_leg">
    <inertial><origin xyz="0 0 {a - 1.0}"/><mass value="{leg_mass}"/>{point}</inertial>
    <visual><origin xyz="0 0 -0.5"/><geometry><cylinder radius="0.01" length="1"/></geometry>
      <material><color rgba="0 0 1 1"/></material></visual>
  </link>
  <joint name="hip_pin" type="continuous"><parent link="stance_leg"/><child link="swing_leg"/>
    <origin xyz="0 0 1"/><axis xyz="0 1 0"/><limit effort="100" velocity="100"/></joint>
</robot>
"""


COMPASS_CONFIG = """robot: walker.urdf
gravity: [0.294, 0, -9.8056]
walking:
  feet:
    left: {link: stance_leg, offset: [0, 0, 0]}
    right: {link: swing_leg, offset: [0, 0, -1]}
  legs: [[base_pitch, hip_pin]]
"""

WALKERS = [  # id, URDF, config, --speed
    ("frost_five_link", frost_urdf(), FROST_CONFIG.format(shin=0.4, torso=0.1), 0.8),
    ("frost_five_link_long_shins", frost_urdf(0.45, 0.5, 15.0),
     FROST_CONFIG.format(shin=0.5, torso=0.05), 0.7),
    ("compass_rooted_at_foot", compass_urdf(), COMPASS_CONFIG, 0.6),
    ("compass_rooted_at_foot_light_hip", compass_urdf(6.0, 4.0, 0.6), COMPASS_CONFIG, 0.5),
]


@pytest.mark.parametrize("name, urdf, config, speed", WALKERS, ids=[w[0] for w in WALKERS])
def test_a_published_walker_designs_writes_elsewhere_and_walks_3_seeds(
        tmp_path, monkeypatch, capsys, name, urdf, config, speed):
    src = tmp_path / "src"
    src.mkdir()
    (src / "walker.urdf").write_text(urdf)
    (src / f"{name}.yaml").write_text(config)
    monkeypatch.chdir(src)
    code = main(["gait", f"{name}.yaml", "--speed", str(speed), "--out", "elsewhere/gait.yaml",
                 "--no-progress"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    assert "walked 20 steps: yes" in out.out
    written = (src / "elsewhere" / "gait.yaml").read_text()
    assert "robot: ../walker.urdf" in written and f"name: {name}" in written
    assert "# Learning: no joint learns" in written and "learning:" in written
    assert "Default walking.phase: mechanical" in written
    assert_written_gait_walks_from_elsewhere(src / "elsewhere" / "gait.yaml", tmp_path,
                                             monkeypatch, capsys)


def test_planar_inertia_is_read_leniently_and_acts_as_the_rigid_body_in_the_plane(tmp_path):
    path = tmp_path / "five.urdf"
    path.write_text(frost_urdf())
    robot = load_robot(str(path))
    assert sum("planar model's inertia" in w for w in robot.warnings) == 5
    assert any("material without a name" in w for w in robot.warnings)
    with pytest.raises(RobotError, match="refused: robot.lenient is false"):
        load_robot(str(path), lenient=False)
    # independent reference: the same walker with rigid bodies' inertias of the same I_yy
    # (other moments arbitrary but physical): in the plane the mass matrix and the bias forces
    # are the same
    rigid = tmp_path / "rigid.urdf"
    rigid.write_text(frost_urdf().replace('<material><color rgba="0.5 0.5 0.5 1"/></material>',
                                          "").replace('ixx="0"', 'ixx="{X}"')
                     .replace('izz="0"', 'izz="{Z}"'))
    rng = np.random.default_rng(0)
    text = rigid.read_text()
    for iyy in ("1.33", "0.47", "0.2"):
        x = float(iyy) * rng.uniform(0.3, 0.9)
        text = text.replace(f'ixx="{{X}}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{{Z}}"',
                            f'ixx="{x}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{float(iyy) - x + 0.01}"')
    rigid.write_text(text)
    other = load_robot(str(rigid))
    assert not any("planar" in w for w in other.warnings)
    for m in (robot.model, other.model):
        assert m.nv == 4
    q = pin.randomConfiguration(robot.model, -np.pi * np.ones(robot.model.nq),
                                np.pi * np.ones(robot.model.nq))
    q = np.concatenate([[np.cos(a), np.sin(a)] for a in rng.uniform(-3, 3, 4)])
    v = rng.normal(size=4)
    for m in (robot.model, other.model):
        m.gravity.linear = np.array([0, 0, -9.81])
    d1, d2 = robot.model.createData(), other.model.createData()
    np.testing.assert_allclose(pin.crba(robot.model, d1, q), pin.crba(other.model, d2, q),
                               atol=1e-12)
    np.testing.assert_allclose(pin.rnea(robot.model, d1, q, v, 0 * v),
                               pin.rnea(other.model, d2, q, v, 0 * v), atol=1e-10)


def test_urdfdoms_stderr_is_captured_into_lines():
    with captured_stderr() as said:
        os.write(2, b"Error:   Visual material must contain a name attribute\n"
                    b"         at line 457 in link.cpp\n")
    assert said == ["Error: Visual material must contain a name attribute"]


def test_standing_pose_is_solved_from_the_kinematics(tmp_path):
    path = tmp_path / "five.urdf"
    path.write_text(frost_urdf(0.45, 0.5))
    feet = {s: FootSpec(link=f"{s}_shin", offset=(0.0, 0.0, 0.5)) for s in ("left", "right")}
    walker = build_walker_model(load_robot(str(path)), feet,
                                [("q1_left", "q1_right"), ("q2_left", "q2_right")])
    stand = standing_pose(walker, 0.2)
    r = walker.robot
    assert stand.height == pytest.approx(0.95, abs=1e-9)  # thigh + shin, straight down
    assert stand.q[r.v_index("base_pitch")] == pytest.approx(0.2)
    for side in ("left", "right"):  # legs along +z: the hip at pi less the torso's pitch
        assert stand.q[r.v_index(f"q1_{side}")] == pytest.approx(np.pi - 0.2, abs=1e-6)
        assert stand.q[r.v_index(f"q2_{side}")] == pytest.approx(0.0, abs=1e-6)
    path = tmp_path / "compass.urdf"
    path.write_text(compass_urdf())
    walker = build_walker_model(load_robot(str(path)), {
        "left": FootSpec(link="stance_leg"), "right": FootSpec(link="swing_leg",
                                                               offset=(0.0, 0.0, -1.0))},
        [("base_pitch", "hip_pin")])
    stand = standing_pose(walker)  # rooted at the foot: mounted at the hip, legs straight down
    assert stand.height == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(stand.q[2:], 0.0, atol=1e-6)


def test_compiled_verification_agrees_with_the_python_loop(tmp_path):
    from feltool.config.files import read_yaml
    from feltool.gait.orbit import verify_design
    from feltool.runs.experiments import build_experiment, resolve_config_path

    path = resolve_config_path("configs/gaits/compass_gait.yaml")
    raw = read_yaml(path)
    fast = build_experiment(raw, path)
    slow = build_experiment(raw, path)
    slow.engine = "python"
    a, b = verify_design(fast, 4), verify_design(slow, 4)
    assert fast.engine == "compiled" and a.walked and b.walked
    for field in ("steps", "min_normal_force_mg", "max_friction_ratio", "max_impulse_ratio",
                  "max_torque", "feedback", "scuffs"):
        assert getattr(a, field) == pytest.approx(getattr(b, field), rel=1e-6, abs=1e-9), field
    np.testing.assert_allclose(a.frames, b.frames, atol=1e-9)
    assert a.poincare["spectral_radius"] == pytest.approx(b.poincare["spectral_radius"],
                                                          rel=1e-6)


def test_passive_compass_gait_matches_drakes_on_the_documented_slope(tmp_path, capsys):
    out = tmp_path / "passive.yaml"
    code = main(["gait", "configs/gaits/compass_gait.yaml", "--passive", "--slope", "0.0525",
                 "--out", str(out), "--no-progress"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "walked 20 steps: yes" in text
    assert "compass-gait convention (walking.scuff_behind)" in text  # counted and reported
    header = out.read_text().splitlines()[3]
    length = float(header.split(" steps of ")[1].split(" m in ")[0])
    period = float(header.split(" m in ")[1].split(" s,")[0])
    assert period == pytest.approx(0.73446, rel=0.01)  # Drake's passive compass gait
    assert length == pytest.approx(0.53592, rel=0.01)
