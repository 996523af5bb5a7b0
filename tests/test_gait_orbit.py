"""A designed gait closed on feltool's own walker: the orbit's demos are a physical motion that the
feedforward alone drives (checked with scipy's integrator on a constrained dynamics assembled
here from Pinocchio's mass matrix, bias forces and foot Jacobian, and the motor allocation
written here), the loop's feedback on them is zero, and `feltool gait` verifies a design in the
walker before it writes anything."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

from feltool.config.files import read_yaml
from feltool.gait.config import gait_config, gait_spec, walker_from_raw
from feltool.gait.design import design_gait
from feltool.gait.orbit import GaitNotWalking, close_on_orbit, verify_design
from feltool.gait.poincare import poincare
from feltool.runs.experiments import build_experiment

from .conftest import other_walker_urdf

COMPASS = Path("configs/gaits/compass_gait.yaml")
FIVE_LINK = Path("configs/gaits/five_link_walker.yaml")


def compass_design(knots: int = 24, rate_hz: int = 250):
    """The compass gait's config (a coarse design, a coarser control rate: quick) with its
    collocation knots as demos."""
    raw = read_yaml(COMPASS)
    raw["sim"]["rate_hz"] = rate_hz
    raw["walking"]["poincare"] = False
    walker, settings = walker_from_raw(raw, COMPASS)
    spec = gait_spec(raw, walker, settings, step_length=0.4, knots=knots)
    return gait_config(raw, walker, design_gait(walker, spec), spec, settings)


@pytest.fixture(scope="module")
def closed():
    raw = compass_design()
    knots_check = verify_design(build_experiment(raw, COMPASS), steps=4)
    config, orbit, check = close_on_orbit(raw, COMPASS, build_experiment, steps=4)
    return raw, knots_check, config, orbit, check


def constrained_acceleration(model, data, foot: int, q, v, tau):
    """M a + b = tau + J^T F, J a + Jdot v = 0 (the stance foot's x and z), by a KKT solve."""
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    b = pin.nonLinearEffects(model, data, q, v)
    pin.computeJointJacobians(model, data, q)
    pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
    pin.updateFramePlacements(model, data)
    J = pin.getFrameJacobian(model, data, foot, pin.LOCAL_WORLD_ALIGNED)[[0, 2]]
    drift = pin.getFrameClassicalAcceleration(model, data, foot, pin.LOCAL_WORLD_ALIGNED).linear
    K = np.block([[M, -J.T], [J, np.zeros((2, 2))]])
    return np.linalg.solve(K, np.concatenate([tau - b, -drift[[0, 2]]]))[:model.nv]


def allocation(model, data, foot: int, q, motors):
    """u = (B^T W B)^-1 B^T W tau with W = M^-1 - M^-1 J^T (J M^-1 J^T)^-1 J M^-1."""
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J = pin.getFrameJacobian(model, data, foot, pin.LOCAL_WORLD_ALIGNED)[[0, 2]]
    Mi = np.linalg.inv(M)
    W = Mi - Mi @ J.T @ np.linalg.solve(J @ Mi @ J.T, J @ Mi)
    B = np.eye(model.nv)[:, motors]
    return np.linalg.solve(B.T @ W @ B, B.T @ W)


def test_the_orbit_is_a_physical_motion_of_the_feedforward_alone(closed):
    raw, knots_check, config, orbit, check = closed
    exp = build_experiment(config, COMPASS)
    model, data = exp.robot.model, exp.robot.model.createData()
    W = exp.hybrid.walker
    foot = model.getFrameId("left_foot")  # the stance foot in the first step's labels
    x = np.array(check.poincare["fixed_point_q"] + check.poincare["fixed_point_v"])
    P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
    log = exp.hybrid.run_cycle(exp.dynamics, x[:model.nq], x[model.nq:], P, Pv, Pa)
    m = orbit.samples_per_step[0]
    assert log.impacts[0][0] == m and len(log.q) == 2 * m
    # the loop's feedback on the orbit vanishes; the knots' design left a floor
    assert np.abs(log.u_fb).max() < 1e-5
    assert knots_check.feedback > 1e-2
    dt = exp.config.dt
    for k in range(2, m - 1, 7):  # control steps of the first step (no touchdown inside)
        q, v = log.q[k], log.v[k]
        # the feedforward of the orbit's own demo sample, allocated onto the motor
        tau_ff = pin.rnea(model, data, q, v, orbit.a[k])
        u = allocation(model, data, foot, q, W.motor_v) @ tau_ff
        assert u == pytest.approx(log.tau[k], abs=1e-6)
        tau = W.B @ u
        nv = model.nv

        def f(t, y, tau=tau, nv=nv):
            return np.concatenate([y[nv:], constrained_acceleration(model, data, foot,
                                                                     y[:nv], y[nv:], tau)])

        sol = solve_ivp(f, (0.0, dt), np.concatenate([q, v]), rtol=1e-11, atol=1e-12,
                        method="DOP853")
        np.testing.assert_allclose(sol.y[:nv, -1], log.q[k + 1], atol=1e-8)
        np.testing.assert_allclose(sol.y[nv:, -1], log.v[k + 1], atol=1e-7)


def test_a_cycle_lasts_its_control_steps_cut_short_at_the_touchdowns(closed):
    """A touchdown ends its control step (the next starts there): the cycle's duration, in both
    engines and in the Poincare map's speed, is its full control steps plus the times into the
    touchdowns' control steps, each located here by scipy's integrator (the stance dynamics
    under the held torque, an event on the swing foot's height)."""
    from feltool.engines.compiled.engine import compiled_runner

    _, _, config, orbit, check = closed
    exp = build_experiment(config, COMPASS)
    model, data = exp.robot.model, exp.robot.model.createData()
    W, dt, nv = exp.hybrid.walker, exp.config.dt, exp.robot.model.nv
    x = np.array(check.poincare["fixed_point_q"] + check.poincare["fixed_point_v"])
    P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
    log = exp.hybrid.run_cycle(exp.dynamics, x[:nv], x[nv:], P, Pv, Pa)
    k = orbit.samples_per_step[0] - 1  # the first touchdown's control step
    stance, swing = (model.getFrameId(f) for f in ("left_foot", "right_foot"))
    tau = W.B @ log.tau[k]

    def f(t, y):
        return np.concatenate([y[nv:], constrained_acceleration(model, data, stance, y[:nv],
                                                                y[nv:], tau)])

    def height(t, y):
        pin.framesForwardKinematics(model, data, y[:nv])
        return data.oMf[swing].translation[2]

    height.terminal, height.direction = True, -1
    sol = solve_ivp(f, (0.0, dt), np.concatenate([log.q[k], log.v[k]]), events=height,
                    rtol=1e-11, atol=1e-12, method="DOP853")
    into = float(sol.t_events[0][0])
    assert 0.0 < into < dt
    assert log.steps[0].duration == pytest.approx(k * dt + into, abs=1e-7)
    # the orbit's two steps are alike: the cycle is two of them, not its 2 m control steps
    assert log.elapsed == pytest.approx(2 * (k * dt + into), abs=1e-6)
    assert log.elapsed < len(log.q) * dt - 1e-6
    out = compiled_runner(exp)(exp.theta_demo, x[:nv], x[nv:], exp.dynamics)
    assert out.contact["duration"] == pytest.approx(log.elapsed, abs=1e-12)
    p = check.poincare
    assert p["speed_m_per_s"] == pytest.approx(p["stride_length_m"] / log.elapsed, rel=1e-9)


def test_the_closed_config_replays_its_orbit(closed):
    raw, _, config, orbit, check = closed
    n = len(orbit.q)
    assert config["period_s"] == pytest.approx(n / raw["sim"]["rate_hz"])
    demo = config["joints"]["hip"]["demo"]
    assert demo["kind"] == "samples" and len(demo["q"]) == n + 1
    assert config["joints"]["hip"]["follow_demo"] and config["joints"]["base_pitch"]["follow_demo"]
    assert check.walked and check.stable and check.feedback < 1e-5
    # periodic: the fixed point of the closed loop is the orbit's start, the demos' first sample
    exp = build_experiment(config, COMPASS)
    q0, _ = exp.hybrid.initial_state(*exp.primitives.desired(exp.theta_demo)[:2])
    np.testing.assert_allclose(q0, check.poincare["fixed_point_q"], atol=1e-8)


def compass_file(tmp_path, rate_hz: int = 250) -> Path:
    """The compass gait's config at a coarser control rate (quicker to verify), as a file."""
    import yaml

    raw = read_yaml(COMPASS)
    raw["sim"]["rate_hz"] = rate_hz
    raw["robot"] = str(Path("robots/compass_gait.urdf").resolve())
    path = tmp_path / "compass.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def unstabilized_three_link(tmp_path) -> Path:
    """The three-link walker with its torso's gains ~0: its designed gait falls in the loop."""
    import yaml

    raw = read_yaml(Path("configs/gaits/three_link_walker.yaml"))
    raw["joints"]["base_pitch"]["gains"] = {"kp": 1.0, "kd": 0.1}
    raw["robot"] = str(Path("robots/three_link_walker.urdf").resolve())
    path = tmp_path / "unstabilized.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_design_that_does_not_walk_is_refused(tmp_path):
    path = unstabilized_three_link(tmp_path)
    raw = read_yaml(path)
    walker, settings = walker_from_raw(raw, path)
    spec = gait_spec(raw, walker, settings, speed=0.8, torso=0.1, knots=24)
    design = gait_config(raw, walker, design_gait(walker, spec), spec, settings)
    with pytest.raises(GaitNotWalking, match="not walking") as info:
        close_on_orbit(design, path, build_experiment, steps=20)
    assert not info.value.check.stable


def test_cli_verifies_closes_and_refuses(tmp_path, capsys):
    import yaml

    from feltool.cli.main import main

    out, html = tmp_path / "gait.yaml", tmp_path / "walk.html"
    assert main(["gait", str(compass_file(tmp_path)), "--step-length", "0.4", "--knots", "24",
                 "--verify-steps", "4", "--out", str(out), "--html", str(html),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    for word in ("walked 4 steps: yes", "spectral radius", "the loop's periodic orbit",
                 f"walk: {html}"):
        assert word in text
    assert "designed gait, 4 steps" in html.read_text()  # the verified walk, one clip
    head = out.read_text().splitlines()[3]
    assert head.startswith("# In feltool's walker: walked 4 steps")
    config = yaml.safe_load(out.read_text())
    n = round(config["period_s"] * config["sim"]["rate_hz"])
    assert len(config["joints"]["hip"]["demo"]["q"]) == n + 1
    # a design that does not walk in the loop: exit 1, the reason, nothing written
    bad = tmp_path / "bad.yaml"
    assert main(["gait", str(unstabilized_three_link(tmp_path)), "--speed", "0.8", "--torso",
                 "0.1", "--knots", "24", "--out", str(bad), "--no-progress"]) == 1
    captured = capsys.readouterr()
    assert "walked" in captured.out
    assert "feltool: error:" in captured.err and "not walking" in captured.err
    assert "Traceback" not in captured.err
    assert not bad.exists()


def test_a_walker_never_seen_gets_a_walking_gait_from_its_config_alone(tmp_path, capsys):
    """A torso-rooted five-link walker with other masses and lengths and continuous joints, its
    feet as link + offset, a config naming only its legs, feet and torso: `feltool gait` writes
    a gait that walks in feltool's walker (motors completed with gains, continuous joints as
    angles), and `feltool run` walks it with zero feedback."""
    import yaml

    from feltool.cli.main import main

    (tmp_path / "other_walker.urdf").write_text(other_walker_urdf())
    foot = {"offset": [0, 0, -0.45]}
    raw = {"name": "other_walker", "robot": "other_walker.urdf", "gravity": 9.81,
           "period_s": 1.2, "sim": {"rate_hz": 200},
           "joints": {"base_pitch": {"role": "stabilize", "target": {"value": 0.05},
                                     "gains": {"kp": 800.0, "kd": 150.0}}},
           "walking": {"feet": {"left": {"link": "left_shin", **foot},
                                "right": {"link": "right_shin", **foot}},
                       "legs": [["left_hip", "right_hip"], ["left_knee", "right_knee"]],
                       "friction": 0.8, "phase": "mechanical", "steps_per_cycle": 2}}
    (tmp_path / "other.yaml").write_text(yaml.safe_dump(raw))
    out = tmp_path / "gait.yaml"
    assert main(["gait", str(tmp_path / "other.yaml"), "--speed", "0.7", "--verify-steps", "6",
                 "--out", str(out), "--no-progress"]) == 0
    assert "walked 6 steps: yes" in capsys.readouterr().out
    config = yaml.safe_load(out.read_text())
    for name in ("left_hip", "right_hip", "left_knee", "right_knee", "base_pitch"):
        jc = config["joints"][name]
        assert jc["role"] == "track" and jc["follow_demo"] and jc["demo"]["kind"] == "samples"
    exp = build_experiment(config, out)
    assert exp.robot.model.nq == exp.robot.model.nv  # continuous joints as angles
    check = verify_design(exp, steps=4, poincare_analysis=False)
    assert check.walked and check.feedback < 1e-5


def test_the_spectral_radius_of_a_kinked_orbit_is_the_slower_sides():
    """On an orbit closed onto its own samples the loop's phase sits on the linearly interpolated
    reference's samples at every control step, so the step-to-step map has a kink at its fixed
    point: forward and backward differences disagree (the shipped five-link walker: about 0.58
    and 0.14), and a central difference would average them. Read independently of any Jacobian:
    a seeded perturbation of the fixed point and its negative, iterated in the walker itself,
    decay at the reported (larger) radius per cycle."""
    exp = build_experiment(read_yaml(FIVE_LINK), FIVE_LINK)
    P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
    q, v = exp.hybrid.initial_state(P, Pv)
    p = poincare(exp, exp.theta_demo, q, v)
    plus, minus = p["spectral_radius_one_sided"]
    assert not p["smooth"] and min(plus, minus) < 0.5 * max(plus, minus)
    assert p["spectral_radius"] == max(plus, minus) and p["stable"]
    fixed = np.array(p["fixed_point_q"] + p["fixed_point_v"])
    nv = len(fixed) // 2
    d = np.random.default_rng(2012).standard_normal(len(fixed))
    for sign in (1.0, -1.0):
        x = fixed + sign * 1e-4 * d / np.linalg.norm(d)
        norms = []
        for _ in range(10):
            log = exp.hybrid.run_cycle(exp.dynamics, x[:nv], x[nv:], P, Pv, Pa)
            x = np.concatenate([log.q_end, log.v_end])
            norms.append(np.linalg.norm(x - fixed))
        decay = np.exp(np.polyfit(np.arange(3, 11), np.log(norms[2:]), 1)[0])
        assert decay == pytest.approx(p["spectral_radius"], rel=0.02), sign
