"""MuJoCo as the plant (``plant: {simulator: mujoco}``, issue 28 item 2): MuJoCo's compilation of
a URDF against Pinocchio's ABA (integrated here by semi-implicit Euler, written in the test),
its contact forces against Newton's law for the centre of mass, learning on the shipped MuJoCo
walkers, the engine choice, and the package missing as a user meets it."""

from __future__ import annotations

import os
import sys

import numpy as np
import pinocchio as pin
import pytest

from feltool.errors import ConfigError
from feltool.robot.mujoco import compile_mujoco
from feltool.robot.robot import load_robot
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed
from feltool.walking.model import FootSpec, build_walker_model

from .conftest import CONFIGS, ROOT, feltool

ARM = (ROOT / "robots" / "two_link_arm.urdf").read_text()
FIVE = CONFIGS / "gaits" / "five_link_walker_mujoco.yaml"
THREE = CONFIGS / "gaits" / "three_link_walker_mujoco.yaml"


def _arm(tmp_path, damping: float | None = None):
    text = ARM
    if damping is not None:  # a <dynamics> element in every joint
        text = text.replace("</joint>", f'<dynamics damping="{damping}"/></joint>')
    path = tmp_path / "arm.urdf"
    path.write_text(text)
    robot = load_robot(str(path))
    robot.set_gravity(9.81)
    return robot


def _rollout_pair(robot, damping: float, seconds: float = 1.0, h: float = 1e-3):
    """MuJoCo's and Pinocchio's (ABA with the damping's torque, semi-implicit Euler) states
    over ``seconds`` at ``1/h`` Hz under the same sinusoidal torques."""
    sim = compile_mujoco(robot, h)
    m, d = robot.model, robot.model.createData()
    q, v = np.array([0.3, -0.5]), np.array([0.2, 0.1])
    sim.set_state(q, v)
    worst = 0.0
    for k in range(int(round(seconds / h))):
        t = k * h
        tau = np.array([2.0 * np.sin(3 * t), 1.0 * np.cos(5 * t)])
        a = pin.aba(m, d, q, v, tau - damping * v)
        v = v + h * a
        q = q + h * v
        sim.step(tau)
        qm, vm = sim.state()
        worst = max(worst, float(np.abs(qm - q).max()), float(np.abs(vm - v).max()))
    return worst, q


def test_mujoco_arm_without_damping_is_pinocchios_aba(tmp_path):
    """1 s at 1 kHz: MuJoCo's Euler step (eulerdamp off) of the URDF is semi-implicit Euler on
    Pinocchio's ABA to 1e-6 in q [rad] and v [rad/s] (measured ~1e-13)."""
    worst, q = _rollout_pair(_arm(tmp_path), 0.0)
    assert worst < 1e-6, worst
    assert np.abs(q).max() > 0.5  # it moved


def test_mujoco_arm_takes_the_urdfs_damping(tmp_path):
    """The URDF's <dynamics damping> acts in MuJoCo as tau_d = -d v (the same rollout with the
    damping's torque in the ABA); without it the rollouts part."""
    robot = _arm(tmp_path, damping=0.5)
    worst, _ = _rollout_pair(robot, 0.5)
    assert worst < 1e-6, worst
    worst_without, _ = _rollout_pair(robot, 0.0)
    assert worst_without > 1e-3


def test_mujoco_arm_rk4_is_runge_kutta_on_pinocchios_aba(tmp_path):
    """integrator rk4: MuJoCo's Runge-Kutta step of the URDF, 1 s at 1 kHz under torques held
    over each step, is classical RK4 on Pinocchio's ABA (written here) to 1e-7 (measured
    1.8e-8); semi-implicit Euler on the same rollout parts from it by more than 1e-4."""
    robot = _arm(tmp_path)
    h = 1e-3
    sim = compile_mujoco(robot, h, integrator="rk4")
    m, d = robot.model, robot.model.createData()
    q, v = np.array([0.3, -0.5]), np.array([0.2, 0.1])
    sim.set_state(q, v)
    f = lambda qq, vv, tau: pin.aba(m, d, qq, vv, tau)  # noqa: E731
    worst = 0.0
    for k in range(1000):
        tau = np.array([2.0 * np.sin(3 * k * h), 1.0 * np.cos(5 * k * h)])
        a1 = f(q, v, tau)
        a2 = f(q + 0.5 * h * v, v + 0.5 * h * a1, tau)
        a3 = f(q + 0.5 * h * (v + 0.5 * h * a1), v + 0.5 * h * a2, tau)
        a4 = f(q + h * (v + 0.5 * h * a2), v + h * a3, tau)
        q = q + h / 6 * (v + 2 * (v + 0.5 * h * a1) + 2 * (v + 0.5 * h * a2) + (v + h * a3))
        v = v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
        sim.step(tau)
        qm, vm = sim.state()
        worst = max(worst, float(np.abs(qm - q).max()), float(np.abs(vm - v).max()))
    assert worst < 1e-7, worst
    _, q_euler = _rollout_pair(robot, 0.0)
    assert np.abs(q_euler - q).max() > 1e-4


def test_mujoco_foot_points_are_the_new_states():
    """After a MuJoCo step the foot points are those of the state it reached (Pinocchio's
    forward kinematics at sim.state(), to 1e-12 m), not of the state it started from
    (mj_step leaves its kinematics one step behind qpos): 50 steps of the five-link walker
    falling onto the floor."""
    robot = load_robot("five_link_walker")
    wm = build_walker_model(robot, {"left": FootSpec(frame="left_foot"),
                                    "right": FootSpec(frame="right_foot")},
                            [("left_hip", "right_hip"), ("left_knee", "right_knee")])
    model, data = wm.model, wm.model.createData()
    sim = compile_mujoco(wm.robot, 0.0005, list(wm.base), dict(wm.feet), 0.7,
                         np.array([0.0, 0.0, -9.81]))
    q0 = np.zeros(model.nq)
    q0[1] = 0.005  # 5 mm above the floor, falling
    sim.set_state(q0, np.zeros(model.nv))
    moved = 0.0
    for _ in range(50):
        before = sim.foot_point("left")
        sim.step(np.zeros(model.nv))
        q, _ = sim.state()
        pin.framesForwardKinematics(model, data, q)
        for foot, fid in wm.feet.items():
            assert np.abs(sim.foot_point(foot) - data.oMf[fid].translation).max() < 1e-12
        moved = max(moved, float(np.abs(sim.foot_point("left") - before).max()))
    assert moved > 1e-5  # the feet moved in a step: stale positions would have failed


def test_mujoco_arm_config_runs_and_learns():
    """The standard arm on MuJoCo: the Python engine (with the reason), and FEL's feedback
    falls as on the rigid model (plant = model here: the same URDF, no damping)."""
    exp = load_experiment(CONFIGS / "two_link_standard.yaml", ["plant={simulator: mujoco}"])
    assert exp.engine == "python" and "plant.simulator: mujoco" in exp.engine_reason
    ref = run_seed(load_experiment(CONFIGS / "two_link_standard.yaml",
                                   ["backend=pinocchio"]), 0, 5)
    res = run_seed(exp, 0, 5)
    a = np.array([r["fb_abs_mean_error"] for r in ref.rows])
    b = np.array([r["fb_abs_mean_error"] for r in res.rows])
    np.testing.assert_allclose(b, a, rtol=1e-6)
    assert b[-1] < 0.7 * b[0]


def test_standing_walkers_contact_force_balances_its_centre_of_mass():
    """The five-link walker standing on both feet under joint PD, 0.3 s of MuJoCo steps of
    0.5 ms: the ground's force on the feet (mj_contactForce) equals m (a_com - g), a_com from
    Pinocchio at MuJoCo's state and accelerations, to 1e-9 m g at every step (measured
    6e-14: the soft contact changes where the feet are, not Newton's law); the feet sink
    less than 0.5 mm (measured 0.13 mm)."""
    robot = load_robot("five_link_walker")
    wm = build_walker_model(robot, {"left": FootSpec(frame="left_foot"),
                                    "right": FootSpec(frame="right_foot")},
                            [("left_hip", "right_hip"), ("left_knee", "right_knee")])
    model = wm.model
    model.gravity = pin.Motion(np.array([0.0, 0.0, -9.81]), np.zeros(3))
    data = model.createData()
    sim = compile_mujoco(wm.robot, 0.0005, list(wm.base), dict(wm.feet), 0.7)
    names = [model.names[j] for j in range(1, model.njoints)]
    q0 = np.zeros(model.nq)
    for name, value in (("left_hip", -0.2), ("right_hip", 0.2), ("left_knee", 0.1),
                        ("right_knee", 0.1)):
        q0[model.joints[names.index(name) + 1].idx_q] = value
    pin.framesForwardKinematics(model, data, q0)
    q0[1] -= min(data.oMf[f].translation[2] for f in wm.feet.values())
    sim.set_state(q0, np.zeros(model.nv))
    mass = pin.computeTotalMass(model)
    g = model.gravity.linear
    worst, depth = 0.0, 0.0
    for _ in range(600):
        q, v = sim.state()
        tau = np.zeros(model.nv)
        tau[3:] = -300.0 * (q[3:] - q0[3:]) - 30.0 * v[3:]
        sim.step(tau)
        forces = sim.foot_contacts()
        F = sum(f for f, _ in forces.values())
        depth = max(depth, *(dd for _, dd in forces.values()))
        pin.centerOfMass(model, data, q, v, sim.acceleration())
        worst = max(worst, float(np.abs(F - mass * (data.acom[0] - g)).max()))
    assert worst < 1e-9 * mass * 9.81, worst
    assert F[2] > 0.5 * mass * 9.81  # it stands on the floor
    assert depth < 5e-4, depth


@pytest.mark.parametrize("config,cycles,bound", [(FIVE, 8, 0.1), (THREE, 8, 0.15)],
                         ids=["five_link", "three_link"])
def test_mujoco_walker_learns_on_two_seeds(config, cycles, bound):
    """The shipped MuJoCo walkers, seeds 0 and 1: every cycle walks every step (MuJoCo's
    contact checks on), the torso within 0.01 rad RMS of its target, and the summed feedback
    of the last cycle below ``bound`` of the first (measured at 8 cycles: five-link
    0.033/0.054, three-link 0.101/0.095; before the post-impact sample and the three-link
    walker's RK4 they were 0.16/0.23 and 0.32/0.29)."""
    exp = load_experiment(config)
    assert exp.engine == "python"
    for seed in (0, 1):
        res = run_seed(exp, seed, cycles)
        s = res.summary
        assert not s["diverged"], s
        walk = s["walking"]
        assert walk["walked"] and walk["not_walking"] is None, walk
        assert walk["stabilized_rms_last_rad"] < 0.01, walk
        fb = [r["fb_abs_mean_error"] for r in res.rows]
        assert len(fb) == cycles and fb[-1] < bound * fb[0], (seed, fb)


def test_mujoco_walker_observer_sees_every_step_as_newton_says():
    """MujocoLoop.observers, one cycle of the shipped five-link MuJoCo walker: one call per
    MuJoCo step (4 per control step; a touchdown ends its control step early, the soft impact's
    steps until the next sample are seen too), as many touchdowns
    as the cycle's impacts, the trailing foot lifted within 50 ms of each; between two
    steps the ground's force on both feet equals m (a_com - g), a_com from Pinocchio at the
    previous step's state with the acceleration (v1 - v0) / h (MuJoCo's semi-implicit Euler
    step), to 1e-9 m g (the labels, the feet and the forces the observer gets agree with
    Newton's law, an independent reference; measured 4e-14 m g)."""
    exp = load_experiment(FIVE)
    loop = exp.hybrid
    seen = []
    loop.observers.append(seen.append)
    logs = []
    run_seed(exp, 0, 1, on_cycle=lambda cycle, log, Qd, fb: logs.append(log))
    log = logs[0]
    assert log.fall is None and len(log.impacts) == 2
    n_ctrl = len(log.u_fb)
    # two touchdowns end control steps early; the soft impact runs on for at most 10 ms
    assert 4 * (n_ctrl - 2) < len(seen) <= 4 * n_ctrl + 2 * 20
    assert sum(s.touchdown for s in seen) == len(log.impacts)
    model = loop.walker.walker.model
    data = model.createData()
    mass = pin.computeTotalMass(model)
    g = model.gravity.linear[[0, 2]]
    worst = 0.0
    for s0, s1 in zip(seen, seen[1:]):
        if s1.touchdown:  # the labels swap inside this step
            continue
        if 0.0 < s1.since_touchdown <= 0.05:
            assert s1.trailing_lifted or s1.since_touchdown < 0.05
        pin.centerOfMass(model, data, s0.q, s0.v, (s1.v - s0.v) / s1.h)
        F = (s1.stance_force + s1.swing_force)[[0, 2]]
        worst = max(worst, float(np.abs(F - mass * (data.acom[0][[0, 2]] - g)).max()))
        assert abs(s1.stance_point[0]) < 2e-3  # the stance foot where it touched down
        if s1.since_touchdown > 0.05:  # the swing foot in the air, the stance foot loaded
            assert not s1.swing_force.any() and s1.swing_depth == 0.0
            assert s1.stance_force[2] > 0.2 * mass * 9.81 and s1.stance_point[2] <= 0.0
    assert worst < 1e-9 * mass * 9.81, worst
    assert all(s.trailing_lifted for s in seen if 0.05 < s.since_touchdown < np.inf)


@pytest.mark.parametrize("sample", ["end", "touchdown"])
def test_mujoco_controller_samples_after_the_soft_impact(sample):
    """plant.impact_sample: with ``end`` the controller's first sample after each touchdown
    has the landing foot stopped (its vertical velocity >= 0, Pinocchio's kinematics at that
    state) after at most 10 ms of MuJoCo steps; with ``touchdown`` it is the foot's arrival,
    still moving down into the floor."""
    exp = load_experiment(FIVE, [f"plant.impact_sample={sample}"])
    loop, logs = exp.hybrid, []
    run_seed(exp, 0, 1, on_cycle=lambda cycle, log, Qd, fb: logs.append(log))
    log, contact = logs[0], loop.walker.contact
    assert log.fall is None and len(log.impacts) == 2
    for k, _, _ in log.impacts:
        q, v = (log.q[k], log.v[k]) if k < len(log.q) else (log.q_end, log.v_end)
        vz = contact.foot_state(q, v, loop.walker.stance)[1][1]
        assert (vz >= 0.0) if sample == "end" else (vz < -0.01), (sample, vz)
    durations = [s.duration for s in log.steps[:2]]
    assert all(0.2 < d < 1.0 for d in durations), durations


def test_mujoco_settings_are_checked_in_one_line():
    """A contact time constant below two MuJoCo timesteps names plant.contact_timeconst; MuJoCo's
    settings without simulator: mujoco name the field."""
    with pytest.raises(ConfigError) as info:
        load_experiment(FIVE, ["plant.contact_timeconst=0.0005"])  # 4 substeps: 0.5 ms steps
    assert [p[0] for p in info.value.problems] == ["plant.contact_timeconst"]
    exp = load_experiment(FIVE, ["plant.contact_timeconst=0.0005", "sim.substeps=8"])
    assert np.allclose(exp.hybrid.sim.model.geom_solref[:, 0], 0.0005)
    with pytest.raises(ConfigError, match="mujoco_integrator"):
        load_experiment(CONFIGS / "two_link_standard.yaml",
                        ["plant={mujoco_integrator: rk4}"])


def test_backend_compiled_with_mujoco_is_one_line():
    with pytest.raises(ConfigError) as info:
        load_experiment(FIVE, ["backend=compiled"])
    assert len(info.value.problems) == 1
    assert info.value.problems[0][0] == "plant.simulator"


def test_mujoco_is_not_combined_with_a_changed_rigid_plant():
    with pytest.raises(ConfigError, match="plant.*simulator: mujoco simulates.*payloads"):
        load_experiment(CONFIGS / "two_link_standard.yaml",
                        ["plant={simulator: mujoco, payloads: [{frame: tip, mass: 1.0}]}"])


def test_mujoco_walker_that_slides_is_not_walking():
    """Friction 0.05 in MuJoCo's floor: the stance foot slides; the walker is not walking,
    with the reason."""
    res = run_seed(load_experiment(FIVE, ["walking.friction=0.05"]), 0, 1)
    walk = res.summary["walking"]
    assert not walk["walked"] and walk["not_walking"] == "friction", walk
    assert "slid" in walk["reason"]


def test_mujoco_missing_is_one_line_exit_2(tmp_path):
    """A mujoco package that cannot be imported (a shadow package first on the path that
    raises ImportError, as a missing install does): one line naming plant.simulator, exit 2,
    no run directory."""
    shadow = tmp_path / "shadow" / "mujoco"
    shadow.mkdir(parents=True)
    (shadow / "__init__.py").write_text("raise ImportError(\"No module named 'mujoco'\")\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path / "shadow"),
                                                        *sys.path]))
    import subprocess

    out = tmp_path / "run"
    res = subprocess.run([sys.executable, "-m", "feltool.cli", "run", str(FIVE), "--out",
                          str(out), "--cycles", "1", "--seeds", "0"], capture_output=True,
                         text=True, env=env, timeout=300)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1 and "plant.simulator" in lines[0] and "mujoco" in lines[0], lines
    assert "Traceback" not in res.stderr
    assert not out.exists() or not any(out.iterdir())


def test_mujoco_rollout_feeds_the_viewer(tmp_path):
    """``feltool run --html`` on a MuJoCo walker writes the rollout page of MuJoCo's states."""
    res = feltool("run", str(FIVE), "--seeds", "0", "--cycles", "1", "--out",
                  str(tmp_path / "r"), "--html", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "r" / "rollout.html").stat().st_size > 1000


def test_mujoco_walker_refuses_the_poincare_map():
    with pytest.raises(ConfigError, match="walking.poincare: the Poincare map is not computed"):
        load_experiment(CONFIGS / "gaits" / "five_link_walker.yaml", ["plant={simulator: mujoco}"])


def test_mujoco_never_gets_a_urdfs_negative_damping(tmp_path):
    """A negative <dynamics damping> would make MuJoCo's plant create energy: the URDF is
    refused when it is loaded, naming the joint and the attribute, before MuJoCo compiles it;
    a zero damping compiles and is Pinocchio's ABA as before."""
    from feltool.errors import RobotError

    with pytest.raises(RobotError, match=r'<joint name="shoulder"> <dynamics damping="-0.5">'):
        _arm(tmp_path, damping=-0.5)
    worst, _ = _rollout_pair(_arm(tmp_path, damping=0.0), 0.0, seconds=0.2)
    assert worst < 1e-6, worst
