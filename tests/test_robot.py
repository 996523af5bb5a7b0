"""Robot loading and the errors a broken URDF gives."""

from __future__ import annotations

import pytest

from feltool.errors import RobotError
from feltool.robot.robot import load_robot

from .conftest import ROOT

ARM = (ROOT / "robots" / "two_link_arm.urdf").read_text()


def test_bundled_path_and_example_robot_data():
    assert load_robot("two_link_arm").joint_names == ["shoulder", "elbow"]
    assert load_robot(str(ROOT / "robots" / "two_link_human_arm.urdf")).total_mass == 4.0
    pend = load_robot("example-robot-data:double_pendulum")
    assert pend.model.nv == 2 and pend.urdf_path.is_file()


def test_relative_urdf_path_resolves_against_base_dir(tmp_path):
    (tmp_path / "arm.urdf").write_text(ARM)
    assert load_robot("arm.urdf", base_dir=tmp_path).model.nv == 2


@pytest.mark.parametrize("text, needle", [
    (None, "URDF file not found"),
    ("<robot name='x'><link name='a'></robot>", ":1:"),  # not well-formed: file:line:col
    (ARM.replace('<joint name="elbow" type="revolute">\n    <parent link="link1"/>',
                 '<joint name="elbow" type="revolute">\n    <parent link="nowhere"/>'),
     "<joint name=\"elbow\"> refers to parent link 'nowhere'"),
    (ARM.replace('<mass value="1.0"/>', '<mass value="0"/>'), "<link name=\"link1\">"),
])
def test_broken_urdf_names_file_and_element(tmp_path, text, needle):
    path = tmp_path / "broken.urdf"
    if text is not None:
        path.write_text(text)
    with pytest.raises(RobotError) as err:
        load_robot(str(path))
    assert needle in str(err.value)
    assert str(path) in str(err.value)


def test_massless_moving_link_is_an_error(tmp_path):
    text = ARM.replace('<mass value="1.0"/>', '<mass value="0"/>')
    path = tmp_path / "massless.urdf"
    path.write_text(text)
    with pytest.raises(RobotError, match="no <inertial> mass"):
        load_robot(str(path))


def test_unknown_joint_lists_the_robots_joints():
    robot = load_robot("two_link_arm")
    with pytest.raises(RobotError, match="its joints are: shoulder, elbow"):
        robot.joint_id("wrist")


def test_package_dirs_resolve_package_meshes_and_urdf_strings_load(tmp_path):
    from feltool.robot.robot import load_urdf_string

    mesh_dir = tmp_path / "pkgs" / "my_robot" / "meshes"
    mesh_dir.mkdir(parents=True)
    (mesh_dir / "link.stl").write_text("solid empty\nendsolid empty\n")
    text = ARM.replace('<geometry><sphere radius="0.06"/></geometry>',
                       '<geometry><mesh filename="package://my_robot/meshes/link.stl"/></geometry>', 1)
    (tmp_path / "arm.urdf").write_text(text)
    with pytest.raises(RobotError, match="package://my_robot/meshes/link.stl' not found"):
        load_robot("arm.urdf", base_dir=tmp_path)
    assert load_robot("arm.urdf", base_dir=tmp_path, package_dirs=["pkgs"]).model.nv == 2
    robot = load_urdf_string(text, "arm", package_dirs=[str(tmp_path / "pkgs")])
    assert robot.joint_names == ["shoulder", "elbow"] and robot.urdf_path is None
    with pytest.raises(RobotError, match="URDF string 'arm'"):
        load_urdf_string(text.replace("<robot", "<robbot", 1), "arm")
