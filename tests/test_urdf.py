"""URDFs from other toolchains: each dialect read leniently (it loads, a warning says what was
assumed, and the model is the physics the file means, checked against closed forms written
here) and refused in strict mode (exit 2, the element named)."""

from __future__ import annotations

import math
import os

import numpy as np
import pinocchio as pin
import pytest

from feltool.cli.main import main
from feltool.errors import RobotError
from feltool.robot.robot import load_robot, load_urdf_string

from .conftest import ROOT

# A Drake/Gazebo-style compass-gait-like pendulum: the root hangs from `world` (no <link
# name="world">), the bob is a point mass (mass, no <inertia>), and the hinge and a slider
# have no <limit>.
M_BOB, L_ROD = 2.0, 0.8  # [kg], [m]
WORLD_JOINT = """
  <joint name="pin" type="revolute">
    <parent link="world"/><child link="rod"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="10" velocity="10"/>
  </joint>"""
POINT_MASS = f"""
  <link name="rod">
    <inertial><origin xyz="0 0 -{L_ROD}"/><mass value="{M_BOB}"/></inertial>
  </link>"""
NO_LIMIT = """
  <joint name="slide" type="prismatic">
    <parent link="rod"/><child link="cart"/><axis xyz="1 0 0"/>
  </joint>"""
PHYSICAL_ROD = (f'<link name="rod"><inertial><origin xyz="0 0 -{L_ROD}"/><mass value="{M_BOB}"/>'
                '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>'
                '</link>')
CART = ('<link name="cart"><inertial><mass value="0.5"/><inertia ixx="0.001" ixy="0" ixz="0" '
        'iyy="0.001" iyz="0" izz="0.001"/></inertial></link>')
BOUNDED = ('<joint name="slide" type="prismatic"><parent link="rod"/><child link="cart"/>'
           '<axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="5" velocity="1"/></joint>')
DECLARED_WORLD = '<link name="world"/>'


def urdf(*parts: str) -> str:
    return '<robot name="drake_style">' + "".join(parts) + "</robot>"


DIALECTS = {  # name: (URDF with only this dialect, the element strict mode names)
    "world_parent": (urdf(WORLD_JOINT, PHYSICAL_ROD, CART, BOUNDED), '<joint name="pin">'),
    "point_mass": (urdf(DECLARED_WORLD, WORLD_JOINT, POINT_MASS, CART, BOUNDED),
                   '<link name="rod">'),
    "no_limit": (urdf(DECLARED_WORLD, WORLD_JOINT, PHYSICAL_ROD, CART, NO_LIMIT),
                 '<joint name="slide">'),
}
CONFIG = """
name: dialect
robot: {robot}
period_s: 1.0
sim: {{rate_hz: 200, cycles: 2}}
joints:
  pin:
    role: track
    demo: {{kind: sine, mean: 0.0, amplitude: 0.2}}
    gains: {{kp: 60.0, kd: 8.0}}
  slide:
    role: stabilize
    target: {{value: 0.0}}
    gains: {{kp: 20.0, kd: 4.0}}
    learn: {{init: random}}
seeds: 1
"""


def _check(tmp_path, capsys, text: str, robot: str) -> tuple[int, str, str]:
    (tmp_path / "r.urdf").write_text(text)
    (tmp_path / "c.yaml").write_text(CONFIG.format(robot=robot))
    code = main(["check", str(tmp_path / "c.yaml")])
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out
    return code, out.out, out.err


@pytest.mark.parametrize("dialect", DIALECTS)
def test_each_dialect_loads_leniently_with_its_warning(dialect, tmp_path, capsys):
    text, element = DIALECTS[dialect]
    code, out, err = _check(tmp_path, capsys, text, "r.urdf")
    assert code == 0, err
    assert "ok - robot r" in out
    warnings = [line for line in err.splitlines() if line.startswith("feltool: warning: ")]
    assert len(warnings) == 1, err  # one dialect element, one line
    assert element in warnings[0] or dialect == "no_limit" and "slide (position, effort, " \
        "velocity)" in warnings[0], warnings
    assert "robot.lenient" in warnings[0]


@pytest.mark.parametrize("dialect", DIALECTS)
def test_each_dialect_is_refused_in_strict_mode_naming_the_element(dialect, tmp_path, capsys):
    text, element = DIALECTS[dialect]
    code, out, err = _check(tmp_path, capsys, text, "{source: r.urdf, lenient: false}")
    assert code == 2, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and element in lines[0] and "lenient is false" in lines[0], err
    assert str(tmp_path / "r.urdf") in lines[0]


def test_strict_inspect_refuses_and_lenient_inspect_reports(tmp_path, capsys):
    path = tmp_path / "r.urdf"
    path.write_text(DIALECTS["point_mass"][0])
    assert main(["inspect", str(path), "--strict"]) == 2
    assert '<link name="rod">' in capsys.readouterr().err
    assert main(["inspect", str(path)]) == 0
    assert "read leniently" in capsys.readouterr().out


def test_the_dialects_together_are_the_physics_they_mean(rng):
    """All three at once: the point-mass pendulum hanging from the world, with an unbounded
    slider: M(q) and gravity torque equal the closed forms of a point mass m at distance l
    (plus the cart), and the slider's limits are infinite."""
    robot = load_urdf_string(urdf(WORLD_JOINT, POINT_MASS, CART, NO_LIMIT), "drake")
    assert len(robot.warnings) == 3, robot.warnings  # world, point mass, limits
    model = robot.model
    assert robot.joint_names == ["pin", "slide"] and model.existFrame("world")
    rod = model.inertias[model.getJointId("pin")]
    assert rod.mass == M_BOB and np.allclose(rod.inertia, 0.0)
    np.testing.assert_allclose(rod.lever, [0.0, 0.0, -L_ROD])
    i = robot.q_index("slide")
    assert model.lowerPositionLimit[i] == -math.inf and model.upperPositionLimit[i] == math.inf
    assert model.effortLimit[i] == math.inf and model.velocityLimit[i] == math.inf
    data = model.createData()
    m_cart, I_cart = 0.5, 0.001
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, 2)
        th, x = q
        # cart at p = R_y(th) (x, 0, 0): its distance from the pin is |x|
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        expected = np.array([[M_BOB * L_ROD**2 + m_cart * x**2 + I_cart, 0.0],
                             [0.0, m_cart]])
        np.testing.assert_allclose(M, expected, atol=1e-12)
        g = pin.computeGeneralizedGravity(model, data, q)
        # potential V = -m g l cos(th) + m_cart g (x sin(-th))... with R_y: z = -x sin(th)
        g0 = 9.81
        dV_dth = M_BOB * g0 * L_ROD * math.sin(th) - m_cart * g0 * x * math.cos(th)
        dV_dx = -m_cart * g0 * math.sin(th)
        np.testing.assert_allclose(g, [dV_dth, dV_dx], atol=1e-10)


def test_a_lenient_urdf_runs_and_is_viewed(tmp_path):
    """The Drake-style file runs a cycle and draws (its visuals come from the same validated
    description Pinocchio built the model from)."""
    from feltool.runs.experiments import load_experiment
    from feltool.runs.seed import run_seed

    (tmp_path / "r.urdf").write_text(urdf(WORLD_JOINT, POINT_MASS, CART, NO_LIMIT))
    (tmp_path / "c.yaml").write_text(CONFIG.format(robot="r.urdf"))
    exp = load_experiment(tmp_path / "c.yaml")
    res = run_seed(exp, 0, 2)
    assert not res.summary["diverged"]
    assert len(exp.robot.visual_model.geometryObjects) == 0  # the file has no visuals


def test_yourdfpy_validation_names_the_element():
    arm = (ROOT / "robots" / "two_link_arm.urdf").read_text()
    with pytest.raises(RobotError, match='<joint name="elbow">: The <joint> tag misses a '
                                         "'type' attribute or value is not part"):
        load_urdf_string(arm.replace('name="elbow" type="revolute"', 'name="elbow" type="hinge"'))
    with pytest.raises(RobotError, match="the links form 2 separate trees"):
        load_urdf_string(arm.replace("</robot>", '<link name="stray"/></robot>'))
    with pytest.raises(RobotError, match=r'<link name="link1"> <inertia> lacks iyz, izz'):
        load_urdf_string(arm.replace('iyz="0" izz="0.333333333333"', "", 1))


def test_package_paths_resolve_against_example_robot_data(tmp_path):
    """A URDF of one's own that uses example-robot-data's meshes by package:// loads and draws
    them, without package_dirs."""
    ur5 = load_robot("example-robot-data:ur5")
    mesh = "package://example-robot-data/robots/ur_description/meshes/ur5/visual/base.dae"
    arm = (ROOT / "robots" / "two_link_arm.urdf").read_text().replace(
        '<geometry><box size="0.12 0.12 0.12"/></geometry>',
        f'<geometry><mesh filename="{mesh}"/></geometry>', 1)
    (tmp_path / "arm.urdf").write_text(arm)
    robot = load_robot(str(tmp_path / "arm.urdf"))
    paths = [g.meshPath for g in robot.visual_model.geometryObjects if g.meshPath.endswith(".dae")]
    base = [g.meshPath for g in ur5.visual_model.geometryObjects if g.meshPath.endswith("base.dae")]
    assert len(paths) == 1 and os.path.realpath(paths[0]) == os.path.realpath(base[0])
