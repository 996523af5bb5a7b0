"""A quadruped's trot scaled from Solo-12's by dynamic similarity (feltool/walking/legged/
similar.py): the laws checked against robots built here (Solo-12 with its masses, or its whole
geometry, scaled), and quadrupeds as published trotting with nothing tuned for them."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, fields

import numpy as np
import pinocchio as pin
import pytest
import yaml

from feltool.cli.main import main
from feltool.walking.legged.learn import learn_trot
from feltool.walking.legged.model import SOLO12_FEET, legged_model, load_solo12, scaled_masses
from feltool.walking.legged.similar import body_scale, trot_gains, trot_timing
from feltool.walking.legged.trot import TrotController, TrotGait

from .conftest import CONFIGS, feltool

GAIT = {f.name: getattr(TrotGait(), f.name) for f in fields(TrotGait)
        if isinstance(getattr(TrotGait(), f.name), float)}


def _expected_gains(mass: float, legs: float, lam: float) -> dict:
    """Solo-12's tuned gains under Froude similarity, written out: [N/m] * m / L, [N s/m] *
    m / sqrt(L), [N m/rad] * m L, [N m s/rad] * m L^1.5, [N] * m (base: the whole mass; joints
    and swing feet: the legs')."""
    r = np.sqrt(lam)
    return {"height": (200.0 * mass / lam, 20.0 * mass / r),
            "tilt": (20.0 * mass * lam, 1.0 * mass * lam * r),
            "yaw_rate": 0.5 * mass * lam * r,
            "joints": (3.0 * legs * lam, 0.1 * legs * lam * r),
            "horizontal": (100.0 * mass / lam, 10.0 * mass / r),
            "swing_gains": (600.0 * legs / lam, 20.0 * legs / r),
            "normal_force_min": 2.0 * mass}


def _flat(gains: dict) -> dict:
    out = asdict(gains["gains"])
    out.update({k: gains[k] for k in ("horizontal", "swing_gains", "normal_force_min")})
    return out


def _solo_scaled(lam: float):
    """Solo-12 with every length times ``lam``, every mass times ``lam**3`` (the same
    material), its rotational inertias times ``lam**5``, its motors' limit times ``lam**4``."""
    solo = load_solo12(effort=2.7)
    model = pin.Model(solo.model)
    for j in range(1, model.njoints):
        p = model.jointPlacements[j]
        model.jointPlacements[j] = pin.SE3(p.rotation, lam * p.translation)
        own = model.inertias[j]
        model.inertias[j] = pin.Inertia(own.mass * lam ** 3, own.lever * lam,
                                        own.inertia * lam ** 5)
    for f in model.frames:
        f.placement = pin.SE3(f.placement.rotation, lam * f.placement.translation)
    q0 = solo.standing().copy()
    q0[:3] *= lam
    return legged_model(model, SOLO12_FEET, q0=q0, effort=2.7 * lam ** 4, name="big_solo")


def test_solo12_is_the_tuned_robot_every_factor_exactly_one():
    solo = load_solo12(effort=2.7)
    s = body_scale(solo)
    assert (s.mass, s.legs, s.length) == (1.0, 1.0, 1.0)
    defaults = TrotController(solo, solo.standing())
    gains = trot_gains(solo)
    assert gains["gains"] == defaults.gains
    for key in ("horizontal", "swing_gains", "normal_force_min"):
        assert gains[key] == getattr(defaults, key)
    assert trot_timing(solo, GAIT) == GAIT


def test_heavier_bodies_scale_the_gains_by_the_mass_and_keep_the_timing():
    heavy = scaled_masses(load_solo12(effort=2.7), 3.0)
    s = body_scale(heavy)
    assert s.mass == pytest.approx(3.0, rel=1e-12) and s.legs == pytest.approx(3.0, rel=1e-12)
    assert s.length == 1.0
    want = _expected_gains(3.0, 3.0, 1.0)
    for key, value in _flat(trot_gains(heavy)).items():
        assert np.allclose(value, want[key], rtol=1e-12), key
    assert trot_timing(heavy, GAIT) == pytest.approx(GAIT, rel=1e-12)


def test_a_twice_as_large_solo_gets_froude_scaled_gains_and_timing():
    big = _solo_scaled(2.0)
    s = body_scale(big)
    assert s.length == pytest.approx(2.0, rel=1e-9)
    assert s.mass == pytest.approx(8.0, rel=1e-12) and s.legs == pytest.approx(8.0, rel=1e-12)
    want = _expected_gains(8.0, 8.0, 2.0)
    for key, value in _flat(trot_gains(big)).items():
        assert np.allclose(value, want[key], rtol=1e-9), key
    timing = trot_timing(big, GAIT)
    assert timing["period"] == pytest.approx(0.3 * np.sqrt(2.0), rel=1e-9)
    assert timing["speed"] == pytest.approx(0.3 * np.sqrt(2.0), rel=1e-9)
    assert timing["step_height"] == pytest.approx(0.08, rel=1e-9)
    assert timing["catch"] == GAIT["catch"] and timing["ramp"] == GAIT["ramp"]


def test_the_large_solo_trots_on_scaled_gains_and_not_on_solos_own():
    """The twice-as-large Solo-12 (8 times the mass): with the trot scaled to it, 3 cycles
    physically, roll and pitch within 0.05 rad; with Solo-12's own gains and timing its feet
    leave the trot's physics before 3 cycles."""
    big = _solo_scaled(2.0)
    gait = TrotGait(**trot_timing(big, GAIT))
    run = learn_trot(big, cycles=3, payload=0.0, gait=gait, controller=trot_gains(big),
                     acquire=0)
    assert run.kind is None and len(run.feedback) == 3, run.log.not_walking
    assert np.abs(run.log.roll).max() < 0.05 and np.abs(run.log.pitch).max() < 0.05
    assert run.speed == pytest.approx(gait.speed, rel=0.15)
    own = learn_trot(big, cycles=3, payload=0.0, acquire=0)
    assert own.kind is not None and len(own.feedback) < 3


#: Go1 as a config names it: example-robot-data's robot, nothing else (its feet its SRDF's)
GO1 = {"name": "go1", "robot": "example-robot-data:go1",
       "walking": {"base": "free_flyer", "acquire": 0}, "sim": {"cycles": 4}, "seeds": [0]}


@pytest.mark.parametrize("name", ["go1", "anymal", "hyq"])
def test_an_example_robot_data_quadrupeds_feet_come_from_its_srdf(name):
    """Each foot where its name says, in the robot's reference posture: FL ahead and left of
    the base, HR behind and right, ..., on the ground below it."""
    from feltool.config.legged import parse_legged_config
    from feltool.runs.legged import load_legged_robot

    legged = load_legged_robot(parse_legged_config({**GO1, "robot": f"example-robot-data:{name}"}))
    assert list(legged.feet) == ["FL", "FR", "HL", "HR"]
    q = legged.standing()
    P = legged.foot_positions(q) - q[:3]
    assert np.all(np.sign(P[:, :2]) == [[1, 1], [1, -1], [-1, 1], [-1, -1]]), P
    assert np.all(P[:, 2] < -0.1)


def test_go1_as_published_trots_from_a_config_naming_only_the_robot(tmp_path, capsys):
    """example-robot-data's Go1 (13.1 kg; its reference posture example-robot-data's): 4 cycles
    walked through `feltool run`, the run's config.yaml recording the timing it trotted with
    (Solo-12's scaled: the period by the square root of the height ratio)."""
    out, path = tmp_path / "run", tmp_path / "go1.yaml"
    path.write_text(yaml.safe_dump(GO1))
    assert main(["run", str(path), "--out", str(out), "--no-progress"]) == 0
    seed = json.loads((out / "summary.json").read_text())["seeds"][0]
    assert seed["walked"] and seed["cycles"] == 4, seed
    import example_robot_data as erd

    robot = erd.load("go1")
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.q0)
    feet = [data.oMf[robot.model.getFrameId(f"{f}_foot")].translation[2]
            for f in ("FL", "FR", "RL", "RR")]
    lam = (robot.q0[2] - np.mean(feet)) / 0.21589724826917053
    gait = yaml.safe_load((out / "config.yaml").read_text())["walking"]["gait"]
    assert gait["period"] == pytest.approx(0.3 * np.sqrt(lam), rel=1e-9)
    assert gait["step_height"] == pytest.approx(0.04 * lam, rel=1e-9)
    capsys.readouterr()


def test_go1_on_solos_unscaled_trot_slides_at_its_first_touchdown():
    """What the scaling is for: Go1 on Solo-12's gains and timing does not trot."""
    from feltool.config.legged import parse_legged_config
    from feltool.runs.legged import load_legged_robot

    go1 = load_legged_robot(parse_legged_config(GO1))
    run = learn_trot(go1, cycles=3, payload=0.0, acquire=0)
    assert run.kind is not None and len(run.feedback) == 0, run.log.not_walking


@pytest.mark.parametrize("name", ["go1_trot.yaml", "go1_trot_mujoco.yaml"])
def test_the_shipped_go1_configs_learn_shortened(tmp_path, name):
    """configs/legged/go1_trot.yaml (rigid plant) and go1_trot_mujoco.yaml shortened for CI
    (their full runs in the configs' comments and docs/legged.md): seeds 0 and 1, 12 cycles,
    the payload at cycle 2, the reference acquired in 2 rounds, the bound 0.25: every cycle
    physical, the payload's feedback taken back (0.167 and 0.172 of the change's by cycle 11
    when measured)."""
    raw = yaml.safe_load((CONFIGS / "legged" / name).read_text())
    assert raw["robot"] == "example-robot-data:go1" and raw["seeds"] == 10
    assert raw["success"] == {"ratio_from": "change", "fb_ratio_max": 0.15}
    raw["payload"]["cycle"], raw["walking"]["acquire"] = 2, 2
    raw["success"]["fb_ratio_max"] = 0.25
    path, out = tmp_path / "go1.yaml", tmp_path / "run"
    path.write_text(yaml.safe_dump(raw))
    proc = feltool("run", str(path), "--seeds", "0-1", "--cycles", "12", "--out", str(out),
                   "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    for s in summary["seeds"]:
        assert s["walked"] and s["cycles"] == 12, s
        assert s["fb_before_change"] < 0.1 * s["fb_change"]
        assert s["fb_ratio_change"] < 0.25
        assert s["stats"]["torque_hits"] == 0
    with open(out / "metrics.csv") as fh:
        rows = list(csv.DictReader(fh))
    for seed in ("0", "1"):
        fb = [float(r["fb_total"]) for r in rows if r["seed"] == seed]
        assert fb[3] > fb[5] > fb[8] > fb[11]  # falling after the change


def test_gains_from_the_config_reach_the_controller_and_are_recorded(tmp_path, capsys):
    """Go1 given Solo-12's own gains in `walking.gains` (the trot's timing still scaled):
    its feet slide at the first touchdown, as with Solo's whole trot (exit 1, nothing learned,
    the reason said); the run's config.yaml records the gains given and the scaled others
    (here none)."""
    solo = {"height": [200.0, 20.0], "tilt": [20.0, 1.0], "yaw_rate": 0.5,
            "joints": [3.0, 0.1], "horizontal": [100.0, 10.0], "swing": [600.0, 20.0],
            "normal_force_min": 2.0}
    raw = {**GO1, "walking": {**GO1["walking"], "gains": solo}}
    out, path = tmp_path / "run", tmp_path / "go1.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["run", str(path), "--out", str(out), "--no-progress"]) == 1
    seed = json.loads((out / "summary.json").read_text())["seeds"][0]
    assert not seed["walked"] and seed["cycles"] == 0 and "slide" in seed["not_walking"]
    recorded = yaml.safe_load((out / "config.yaml").read_text())["walking"]["gains"]
    assert recorded == solo
    capsys.readouterr()
    raw["walking"]["gains"] = {"height": [200.0, -1.0]}
    path.write_text(yaml.safe_dump(raw))
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "walking.gains.height" in err and err.count("\n") == 1, err


def test_the_joint_loop_radius_is_the_held_pd_on_the_joints_inertia():
    """Against the loop built here: the joint's inertia from the inverse of Pinocchio's CRBA
    mass matrix, the double integrator under a torque held over the step discretized by
    scipy's matrix exponential, the PD closed around it."""
    from scipy.linalg import expm

    from feltool.walking.legged.control import joint_loop_radius

    solo = load_solo12(effort=2.7)
    q = solo.standing()
    M = pin.crba(solo.model, solo.model.createData(), q)
    M = np.triu(M) + np.triu(M, 1).T
    inertia = 1.0 / np.diag(np.linalg.inv(M))[6:]
    for gains, rate in (((3.0, 0.1), 1000.0), ((3.0, 1.2), 1000.0), ((50.0, 0.5), 400.0)):
        h = 1.0 / rate
        want = []
        for I in inertia:
            G = expm(np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0 / I], [0.0, 0.0, 0.0]]) * h)
            A = G[:2, :2] + np.outer(G[:2, 2], -np.array(gains))
            want.append(np.abs(np.linalg.eigvals(A)).max())
        got = joint_loop_radius(solo, q, gains, rate)
        assert np.allclose(got, want, rtol=1e-10, atol=0), (gains, rate)


def test_joint_gains_that_diverge_are_refused_naming_them_and_do_diverge(tmp_path, capsys):
    """Solo-12's joints' damping 10 N m s/rad: its knees' own loop grows at 1 kHz; the config
    is refused (exit 2, nothing written, walking.gains.joints named with the joint). The same
    gains trotting (a swing leg's joints are free) chatter: the motor torques change sign
    from one control step to the next at nine steps in ten, at their limit, and the trot
    stops within 0.3 s; on Solo's own gains it trots its 2 cycles."""
    from feltool.walking.legged.control import StandGains, joint_loop_radius

    solo = load_solo12(effort=2.7)
    assert joint_loop_radius(solo, solo.standing(), (3.0, 10.0), 1000.0).max() > 1.0
    raw = yaml.safe_load((CONFIGS / "legged" / "solo12_trot.yaml").read_text())
    raw["walking"]["gains"] = {"joints": [3.0, 10.0]}
    path = tmp_path / "trot.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["run", str(path), "--out", str(tmp_path / "never")]) == 2
    err = capsys.readouterr().err
    assert "walking.gains.joints: [3, 10] make" in err and "_KFE's own loop diverge" in err, err
    assert "Traceback" not in err and err.count("\n") == 1
    assert not (tmp_path / "never").exists()
    for joints, trots in (((3.0, 10.0), False), ((3.0, 0.1), True)):
        run = learn_trot(solo, cycles=2, payload=0.0, acquire=0,
                         controller={"gains": StandGains(joints=joints)})
        du = np.diff(run.log.u, axis=0)
        flips = np.mean(du[1:] * du[:-1] < 0)
        assert (run.kind is None and len(run.feedback) == 2) == trots, run.log.not_walking
        if not trots:
            assert run.log.t[-1] < 0.3 and flips > 0.9
            assert np.abs(run.log.u).max() == pytest.approx(2.7)
        else:
            assert flips < 0.1


@pytest.mark.parametrize("joints", [[0.0, 0.0], [0.0, 0.1]])
def test_joint_gains_without_stiffness_are_not_refused(tmp_path, capsys, joints):
    """No stiffness: the loop's matrix is [[1, h(1 - b/2)], [0, 1 - b]] (closed form), an
    eigenvalue 1 exactly: the joint's position is left to itself, not made to diverge, and the
    config checks (the run shows what it does). Stiffness without damping is refused: the
    held torque's lag makes the determinant 1 + a/2 > 1, radius sqrt(1 + a/2)."""
    from feltool.walking.legged.control import joint_loop_radius

    solo = load_solo12(effort=2.7)
    radius = joint_loop_radius(solo, solo.standing(), tuple(joints), 1000.0)
    assert np.allclose(radius, 1.0, rtol=0, atol=1e-12)
    raw = yaml.safe_load((CONFIGS / "legged" / "solo12_trot.yaml").read_text())
    raw["walking"]["gains"] = {"joints": joints}
    path = tmp_path / "trot.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["check", str(path)]) == 0, capsys.readouterr().err
    stiff = joint_loop_radius(solo, solo.standing(), (3.0, 0.0), 1000.0)
    M = pin.crba(solo.model, solo.model.createData(), solo.standing())
    inertia = 1.0 / np.diag(np.linalg.inv(np.triu(M) + np.triu(M, 1).T))[6:]
    assert np.allclose(stiff, np.sqrt(1.0 + 3.0 * 1e-6 / inertia / 2), rtol=1e-9)
