"""The bad-input corpus: every broken config or URDF in tests/bad_inputs/ must give exit code 2
and a message that names its field or element, without a traceback and without writing anything
that looks like a result.

Each ``*.yaml`` case starts with ``# expect: <text the message must contain>``.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from feltool.cli.main import main

from .conftest import feltool

CASES = sorted((Path(__file__).parent / "bad_inputs").glob("*.yaml"))


def expected(path: Path) -> str:
    first = path.read_bytes().split(b"\n", 1)[0].decode()
    assert first.startswith("# expect: "), path
    return first[len("# expect: "):]


def test_the_corpus_is_large_enough():
    assert len(CASES) >= 30


@pytest.mark.parametrize("case", CASES, ids=[c.stem for c in CASES])
def test_bad_input_exits_2_naming_the_problem(case, tmp_path, capsys):
    out = tmp_path / "run"
    t0 = time.perf_counter()
    code = main(["run", str(case), "--out", str(out), "--no-progress"])
    elapsed = time.perf_counter() - t0
    captured = capsys.readouterr()
    assert code == 2, captured
    assert expected(case) in captured.err, captured.err
    assert "Traceback" not in captured.err + captured.out
    assert len(captured.err.strip().splitlines()) <= 4  # one line per problem, no dumps
    assert not out.exists()  # nothing that looks like a result
    print(f"{case.stem}: {elapsed * 1000:.0f} ms")


def test_a_bad_input_as_a_user_sees_it(tmp_path):
    res = feltool("run", str(CASES[0]), "--out", str(tmp_path / "x"))
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.startswith("feltool: error: ")


# -- cases that are made at test time (too big to keep) or come from the command line -----------

STANDARD = Path(__file__).resolve().parent.parent / "configs" / "two_link_standard.yaml"


def _run(args, capsys):
    code = main(args)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err + captured.out
    return code, captured.err


def test_a_giant_config_file_is_refused_before_it_is_parsed(tmp_path, capsys):
    big = tmp_path / "giant.yaml"
    big.write_text(STANDARD.read_text() + "description: " + "x" * (2 << 20) + "\n")
    code, err = _run(["run", str(big), "--out", str(tmp_path / "run"), "--no-progress"], capsys)
    assert code == 2 and "a config may have at most 1048576" in err, err
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("seeds, needle", [
    ("0-1000000000", "'0-1000000000' is 1000000001 seeds; at most 100000"),
    ("0,0,1", "seed 0 given more than once"),
    ("0-5,3", "seed 3 given more than once"),
    ("99999999999999999999", "a seed may be at most 9223372036854775807"),
])
def test_bad_seed_lists_on_the_command_line(seeds, needle, tmp_path, capsys):
    code, err = _run(["run", str(STANDARD), "--seeds", seeds, "--out", str(tmp_path / "run"),
                      "--no-progress"], capsys)
    assert code == 2 and needle in err, err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("override, needle", [
    ("sweep={grid: {a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1], b: [*a, *a, *a, *a, *a, *a, *a, *a, "
     "*a, *a], c: &c [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]}}", None),
    ("sim.cycles=on", "sim.cycles: a boolean"),
    ("seeds=[3, 3]", "seed 3 given more than once"),
    ("sim.rate_hz=1e400", "sim.rate_hz"),
    ("success.ratio_from=change", "success.ratio_from: change needs a world event"),
    ("sim.step_s=-0.001", "sim.step_s"),
    ("sim.step_s=1e-7", "sim.step_s 1e-07 s at sim.rate_hz 100 gives 100000 sub-steps"),
    ("sim.feedforward=held", "sim.feedforward"),
])
def test_bad_overrides_on_the_command_line(override, needle, tmp_path, capsys):
    """--set values are YAML too and get the same bounds; a small alias use stays fine."""
    code, err = _run(["check", str(STANDARD), "--set", override], capsys)
    if needle is None:
        assert code == 0, err
    else:
        assert code == 2 and needle in err, err


def test_a_bomb_in_an_override_is_refused(capsys):
    levels = ["a: &a [x, x, x, x, x, x, x, x, x]"] + [
        f"{c}: &{c} [" + ", ".join([f"*{p}"] * 9) + "]" for p, c in zip("abcdefgh", "bcdefghi")]
    code, err = _run(["check", str(STANDARD), "--set", "sweep={grid: {" + ", ".join(levels)
                      + "}}"], capsys)
    assert code == 2 and "--set: sweep: refused: more than 100000 values" in err, err


def test_the_bundled_configs_pass_the_new_bounds(capsys):
    for path in sorted(STANDARD.parent.glob("*.yaml")):
        code, err = _run(["check", str(path)], capsys)
        assert code == 0, (path, err)


def test_a_giant_urdf_is_refused_before_it_is_read(tmp_path, capsys):
    arm = (STANDARD.parent.parent / "robots" / "two_link_arm.urdf").read_text()
    (tmp_path / "giant.urdf").write_text(arm.replace("<robot", "<!--" + "x" * (33 << 20)
                                                     + "-->\n<robot", 1))
    config = tmp_path / "giant.yaml"
    config.write_text(STANDARD.read_text().replace("robot: two_link_arm", "robot: giant.urdf"))
    code, err = _run(["check", str(config)], capsys)
    assert code == 2 and "a URDF may have at most 33554432" in err, err


def _chain_urdf(n: int, joint_type: str) -> str:
    """A chain of n links below a massless root, the first joint revolute, the rest
    ``joint_type``."""
    inertial = ('<inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" '
                'izz="1"/></inertial>')
    links = ['<link name="l0"/>'] + [f'<link name="l{i}">{inertial}</link>' for i in range(1, n + 1)]
    joints = [f'<joint name="j{i}" type="{"revolute" if i == 1 else joint_type}"><parent '
              f'link="l{i - 1}"/><child link="l{i}"/><axis xyz="0 1 0"/><limit lower="-1" '
              'upper="1" effort="1" velocity="1"/></joint>' for i in range(1, n + 1)]
    return '<robot name="chain">' + "".join(links + joints) + "</robot>"


def test_urdf_link_count_is_bounded_and_long_chains_within_it_load(tmp_path, capsys):
    """Thousands of links overflowed the recursion of the checks (RecursionError) and of the
    URDF parser behind Pinocchio (a segfault); within the bound a long chain loads."""
    from feltool.robot.robot import load_robot

    (tmp_path / "long.urdf").write_text(_chain_urdf(5000, "revolute"))
    code, err = _run(["inspect", str(tmp_path / "long.urdf")], capsys)
    assert code == 2 and "has 5001 links; feltool loads at most 1000" in err, err
    for joint_type in ("fixed", "revolute"):
        (tmp_path / "ok.urdf").write_text(_chain_urdf(999, joint_type))
        robot = load_robot(str(tmp_path / "ok.urdf"))
        assert robot.model.nv == (1 if joint_type == "fixed" else 999)


WALKER = Path(__file__).resolve().parent.parent / "configs" / "gaits" / "five_link_walker.yaml"


@pytest.mark.parametrize("setting, needle", [
    ("plant={payloads: [{frame: backpack, mass: 3.2}]}",
     "plant.payloads.0.frame: robot 'five_link_walker' has no frame 'backpack'"),
    ("events=[{cycle: 3, kind: payload, frame: backpack, mass: 3.2}]",
     "events.0.frame: the robot has no frame/link 'backpack'"),
    ("plant={friction: {left_knee: {viscous: -1.0}}}",
     "plant.friction.left_knee.viscous: Input should be greater than or equal to 0"),
    ("plant={motor_gain: {left_knee: 0.0}}", "plant.motor_gain.left_knee"),
    ("plant={robot: five_link_walker}", "plant.robot: a physical walker's plant is its own"),
    ("learning.model={features: none, rate: 0.0, update: gauss_newton}",
     "learning.model.motor_bias: with features none, give motor_bias > 0"),
], ids=["payload_unknown_link", "event_payload_unknown_link", "negative_damping",
        "zero_motor_gain", "second_robot", "nothing_to_learn"])
def test_a_physical_walkers_bad_plant_is_one_line_naming_the_field(setting, needle, tmp_path,
                                                                    capsys):
    """A walker in a world the model does not know (issue 28): a payload on a link the walker
    lacks, a negative damping, a zero motor gain ... are one line naming the field, exit 2."""
    code, err = _run(["run", str(WALKER), "--set", setting, "--out", str(tmp_path / "run"),
                      "--no-progress"], capsys)
    assert code == 2 and needle in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "run").exists()


BAD = Path(__file__).parent / "bad_inputs"


@pytest.mark.parametrize("case, attr, value", [
    ("urdf_negative_damping", "damping", "-0.5"), ("urdf_negative_friction", "friction", "-0.2")])
@pytest.mark.parametrize("command", [["check"], ["run", "--no-progress"],
                                     ["run", "--no-progress", "--set", "plant={simulator: mujoco}"]],
                         ids=["check", "run", "run_mujoco"])
def test_a_urdfs_negative_damping_or_friction_is_one_line_exit_2(case, attr, value, command,
                                                                   tmp_path):
    """A URDF joint's <dynamics damping="-0.5"> (or a negative friction) makes a plant that
    creates energy (issue 28, acceptance 5): refused at load for every plant, MuJoCo's too,
    as a user sees it: exit 2, one line naming the file, the joint and the attribute."""
    out = tmp_path / "run"
    res = feltool(*command[:1], str(BAD / f"{case}.yaml"), *command[1:],
                  *(["--out", str(out)] if command[0] == "run" else []))
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1, lines
    assert f"{case[len('urdf_'):]}.urdf" in lines[0], lines[0]
    assert f'<joint name="elbow"> <dynamics {attr}="{value}">: must be at least 0' in lines[0]
    assert "Traceback" not in res.stderr + res.stdout
    assert not out.exists()


def test_zero_and_positive_joint_damping_load_as_before(tmp_path, capsys):
    """Only a negative <dynamics> value is refused: 0 (none) and positive ones load."""
    arm = (BAD / "negative_damping.urdf").read_text()
    for dynamics in ('damping="0" friction="0"', 'damping="0.5" friction="0.2"'):
        (tmp_path / "arm.urdf").write_text(arm.replace('damping="-0.5" friction="0"', dynamics))
        config = tmp_path / "arm.yaml"
        config.write_text(STANDARD.read_text().replace("robot: two_link_arm", "robot: arm.urdf"))
        code, err = _run(["check", str(config)], capsys)
        assert code == 0, (dynamics, err)


def test_a_negative_damping_in_a_model_built_elsewhere_is_refused(tmp_path):
    """Models that bypass feltool's URDF reader (example-robot-data's, the legged loader's)
    are held to the same rule through Pinocchio's model.damping and model.friction."""
    from feltool.errors import RobotError
    from feltool.robot.robot import check_model_dynamics, load_robot
    from feltool.walking.legged.model import load_legged_urdf

    model = load_robot("example-robot-data:ur5").model
    check_model_dynamics(model, "ur5")  # as shipped
    model.friction[2] = -0.1
    with pytest.raises(RobotError, match=r"ur5: joint 'elbow_joint' <dynamics "
                                         r'friction="-0.1">: must be at least 0'):
        check_model_dynamics(model, "ur5")
    path = tmp_path / "legged.urdf"
    path.write_text(_chain_urdf(2, "revolute").replace(
        '</joint>', '<dynamics damping="-0.5"/></joint>', 1))
    with pytest.raises(RobotError, match=r"legged.urdf: joint 'j1' <dynamics "
                                         r'damping="-0.5">: must be at least 0'):
        load_legged_urdf(path, {"X": {"frame": "l2"}})
