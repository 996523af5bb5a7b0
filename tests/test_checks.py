"""``feltool check``'s physics: a target no actuated joint moves, a learned joint the error
signal never sees, gains unstable for the robot's inertia, a rate too coarse for the gains.
The timestep bound is checked against the simulator itself, the unstable gain against the
closed form of an inverted pendulum."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from feltool.cli.main import main
from feltool.experiment.checks import integrator_factor, sampled_pd_stable

from .conftest import CONFIGS

STANDARD = CONFIGS / "two_link_standard.yaml"


def _check(capsys, path, *overrides: str) -> tuple[int, list[str]]:
    code = main(["check", str(path), *[a for o in overrides for a in ("--set", o)]])
    out = capsys.readouterr()
    assert "Traceback" not in out.err + out.out
    return code, out.err.strip().splitlines()


def test_an_unreachable_target_and_an_unstable_gain_one_line_each(capsys):
    """The elbow holds the base frame's angle, which no joint turns, and the shoulder's kp is
    below the arm's gravity stiffness: two problems, two lines, exit 2."""
    code, lines = _check(capsys, STANDARD, "joints.elbow.target={frame: base, value: 0.3}",
                         "joints.shoulder.gains.kp=1")
    assert code == 2
    assert len(lines) == 2, lines
    assert "joints.elbow.target: no actuated joint moves it" in lines[0]
    assert "joints.shoulder.gains: kp 1, kd 20 leave the closed loop unstable" in lines[1]


def test_an_unreachable_target_is_refused_by_run_too(tmp_path, capsys):
    code = main(["run", str(STANDARD), "--out", str(tmp_path / "r"), "--set",
                 "joints.elbow.target={frame: tip, vector: [0, 0, 1], about: [1, 0, 0], "
                 "value: 0.3}"])
    assert code == 2 and not (tmp_path / "r").exists()
    assert "joints.elbow.target: no actuated joint moves it" in capsys.readouterr().err


@pytest.mark.parametrize("config, joint", [("ur5_wrist_level", "elbow_joint"),
                                           ("panda_hand_level", "panda_joint4")])
def test_run_refuses_a_rate_check_refuses(config, joint, tmp_path, capsys):
    """UR5 and Panda at 50 Hz: ``feltool check`` refuses them (the stiff gains beyond the sampled
    PD loop's bound), and ``feltool run`` refuses them the same way, before it writes anything:
    one line per joint naming its field, exit 2."""
    code, lines = _check(capsys, CONFIGS / f"{config}.yaml", "sim.rate_hz=50")
    assert code == 2 and any(f"joints.{joint}.gains: sim.rate_hz 50 is too coarse" in line
                             for line in lines), lines
    assert all(".gains: sim.rate_hz 50 is too coarse" in line for line in lines), lines
    code = main(["run", str(CONFIGS / f"{config}.yaml"), "--out", str(tmp_path / "r"),
                 "--seeds", "0", "--set", "sim.rate_hz=50"])
    out = capsys.readouterr()
    assert code == 2 and not (tmp_path / "r").exists() and "Traceback" not in out.err
    assert out.err.strip().splitlines() == lines


@pytest.mark.parametrize("kp, unstable", [(4.0, True), (6.0, False)])
def test_the_gain_bound_is_the_inverted_pendulum_s(kp, unstable, capsys):
    """Link 2 held upright by the elbow (the shoulder stiff): the upper link is an inverted
    pendulum about the elbow, stable only for kp > m g l_g = 1 kg * 9.8 * 0.5 m = 4.9 N m/rad
    (at the start pose, the shoulder at its demo's first angle, pi/2)."""
    code, lines = _check(capsys, STANDARD, f"joints.elbow.gains.kp={kp}",
                         "joints.shoulder.gains.kp=1e5", "joints.shoulder.gains.kd=600",
                         "sim.rate_hz=2000")
    assert (code == 2) == unstable, lines
    if unstable:
        assert len(lines) == 1 and "joints.elbow.gains" in lines[0]


@pytest.mark.parametrize("integrator", ["semi_implicit_euler", "explicit_euler"])
@pytest.mark.parametrize("substeps", [1, 3])
def test_the_timestep_bound_is_the_simulator_s(integrator, substeps):
    """The one-step map of feltool's own closed loop (Pinocchio's ABA, the integrator and
    sub-steps of the config, the torque held over the step) for a 1-DoF link without gravity:
    its spectral radius is below 1 exactly where sampled_pd_stable says the loop is stable."""
    from feltool.control.closed_loop import ClosedLoop
    from feltool.control.feedback import FeedbackLaw
    from feltool.dynamics.interface import make_dynamics
    from feltool.robot.robot import load_urdf_string

    inertia = 0.7  # [kg m^2] about the joint
    link = (f'<link name="l"><inertial><mass value="1"/><inertia ixx="{inertia}" ixy="0" '
            f'ixz="0" iyy="{inertia}" iyz="0" izz="{inertia}"/></inertial></link>')
    robot = load_urdf_string(f'<robot name="one"><link name="b"/>{link}<joint name="j" '
                             'type="revolute"><parent link="b"/><child link="l"/><axis '
                             'xyz="0 1 0"/><limit lower="-9" upper="9" effort="0" velocity="0"/>'
                             '</joint></robot>')
    robot.set_gravity(0.0)
    dyn = make_dynamics(robot.model, "pinocchio")
    dt, c = 0.01, integrator_factor(integrator, substeps)
    agree = 0
    for alpha in np.linspace(0.05, 4.0, 14):
        for beta in np.linspace(0.0, 2.6, 14):
            kp, kd = alpha * inertia / dt**2, beta * inertia / dt
            law = FeedbackLaw(np.eye(1), np.array([kp]), np.array([kd]), np.array([True]),
                              np.array([False]), np.zeros(1))
            loop = ClosedLoop(dyn, law, np.ones(1), dt, substeps, integrator)
            Phi = np.column_stack([np.concatenate(loop.advance(x[:1], x[1:], law.feedback(
                x[:1], x[1:], np.zeros(1), np.zeros(1)))) for x in np.eye(2)])
            rho = max(abs(np.linalg.eigvals(Phi)))
            if abs(rho - 1.0) < 1e-6:
                continue  # on the boundary: either answer is right
            assert sampled_pd_stable(alpha, beta, c) == (rho < 1.0), (alpha, beta, rho)
            agree += 1
    assert agree > 150


def test_a_coarse_rate_is_named_with_the_rate_that_fixes_it(capsys):
    code, lines = _check(capsys, STANDARD, "joints.elbow.gains.kp=30000")
    assert code == 2 and len(lines) == 1, lines
    assert "joints.elbow.gains: sim.rate_hz 100 is too coarse for kp 30000" in lines[0]
    assert "raise sim.rate_hz to 200" in lines[0]
    code, _ = _check(capsys, STANDARD, "joints.elbow.gains.kp=30000", "sim.rate_hz=200")
    assert code == 0


def test_explicit_euler_needs_damping_at_every_rate(capsys):
    code, lines = _check(capsys, STANDARD, "sim.integrator=explicit_euler",
                         "joints.elbow.gains.kd=0")
    assert code == 2 and "explicit Euler needs kd > 0" in lines[0], lines


BRANCHES = """<robot name="two_branches"><link name="base"/>
  <link name="a"><inertial><origin xyz="0.5 0 0"/><mass value="1"/><inertia ixx="0.01" ixy="0"
   ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="b"><inertial><origin xyz="0.5 0 0"/><mass value="1"/><inertia ixx="0.01" ixy="0"
   ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <joint name="ja" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 -1 0"/>
   <limit lower="-3" upper="3" effort="100" velocity="10"/></joint>
  <joint name="jb" type="revolute"><parent link="base"/><child link="b"/><axis xyz="0 -1 0"/>
   <origin xyz="0 0.5 0"/><limit lower="-3" upper="3" effort="100" velocity="10"/></joint>
</robot>"""


@pytest.mark.parametrize("error, seen", [("[ja]", False), ("[ja, jb]", True)])
def test_a_learned_joint_the_error_signal_never_sees(error, seen, tmp_path, capsys):
    """Two arms on one base: learning jb's RMP from ja's feedback alone cannot work (jb's
    feedforward never loads ja); with jb's own feedback in the signal it can."""
    (tmp_path / "r.urdf").write_text(BRANCHES)
    config = yaml.safe_load(STANDARD.read_text())
    config.update(robot="r.urdf", joints={
        "ja": config["joints"]["shoulder"],
        "jb": {**config["joints"]["elbow"], "target": {"value": 1.0}}})
    config["learning"]["error"] = yaml.safe_load(error)
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(config))
    code, lines = _check(capsys, tmp_path / "c.yaml")
    assert (code == 0) == seen, lines
    if not seen:
        assert len(lines) == 1 and "joints.jb.learn: the error signal" in lines[0], lines


def test_coupled_error_joints_see_the_learned_joint(capsys):
    """The arm's shoulder feedback does see the elbow's feedforward (they share inertia)."""
    code, lines = _check(capsys, STANDARD, "learning.error=[shoulder]")
    assert code == 0, lines


@pytest.mark.parametrize("path", sorted((CONFIGS / "gaits").glob("*.yaml")),
                         ids=lambda p: p.stem)
def test_every_walker_config_passes_the_physics_checks(path, capsys):
    """(tests/test_cli.py checks configs/*.yaml.) The walkers' passive base joints are no
    unreachable targets, their learned joints are seen by their error signals, and the gain
    and timestep checks leave the hybrid loop alone (feltool.experiment.checks' docstring)."""
    code, lines = _check(capsys, path)
    assert code == 0, lines


def test_the_bound_in_the_docstring_is_the_one_implemented():
    """Semi-implicit Euler with one sub-step: beta < 2 and alpha + 2 beta < 4; explicit Euler:
    alpha <= beta and 2 beta - alpha < 4 (feltool.experiment.checks.sampled_pd_stable's docstring)."""
    rng = np.random.default_rng(0)
    for alpha, beta in rng.uniform(0, 4, (500, 2)):
        assert sampled_pd_stable(alpha, beta, 1.0) == (beta < 2 and alpha + 2 * beta < 4)
        assert sampled_pd_stable(alpha, beta, 0.0) == (alpha <= beta and 2 * beta - alpha < 4)
    assert integrator_factor("semi_implicit_euler", 1) == 1.0
    assert integrator_factor("explicit_euler", 1) == 0.0
    assert math.isclose(integrator_factor("semi_implicit_euler", 3), 2 / 3)
