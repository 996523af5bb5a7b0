"""Robots nobody here wrote: every bundled config runs, locked joints are exact, and the
frame-orientation target's feedback and Jacobian are right."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.experiment.assemble import reduce_robot
from feltool.robot.frames import FrameAngle
from feltool.robot.inspection import config_skeleton
from feltool.robot.robot import load_robot
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS, feltool

ALL_CONFIGS = sorted(CONFIGS.glob("*.yaml"))


@pytest.mark.parametrize("path", ALL_CONFIGS, ids=[p.stem for p in ALL_CONFIGS])
def test_every_config_runs_a_few_cycles(path):
    exp = load_experiment(path)
    res = run_seed(exp, 0, 3)
    assert not res.summary["diverged"], res.summary
    assert len(res.rows) == 3 and np.isfinite(res.rows[-1]["fb_abs_mean_error"])


def test_locked_joints_are_exactly_at_their_posture():
    """The reduced model is the full model with the locked joints held: same kinematics and
    the same torques on the free joints, to rounding."""
    full = load_robot("example-robot-data:ur5")
    locked = {"shoulder_pan_joint": 0.3, "wrist_2_joint": 1.2, "wrist_3_joint": -0.4}
    reduced = reduce_robot(full, locked)
    free = [n for n in full.joint_names if n not in locked]
    assert reduced.joint_names == free
    rng = np.random.default_rng(4)
    fm, rm = full.model, reduced.model
    fd, rd = fm.createData(), rm.createData()
    for _ in range(10):
        qr, vr, ar = rng.uniform(-2, 2, 3), rng.normal(size=3), rng.normal(size=3)
        qf, vf, af = np.zeros(6), np.zeros(6), np.zeros(6)
        for name, val in locked.items():
            qf[full.q_index(name)] = val
        for i, name in enumerate(free):
            qf[full.q_index(name)], vf[full.v_index(name)], af[full.v_index(name)] = qr[i], vr[i], ar[i]
        pin.framesForwardKinematics(fm, fd, qf)
        pin.framesForwardKinematics(rm, rd, qr)
        a = fd.oMf[fm.getFrameId("tool0")]
        b = rd.oMf[rm.getFrameId("tool0")]
        np.testing.assert_allclose(a.homogeneous, b.homogeneous, atol=1e-12)
        tau_full = pin.rnea(fm, fd, qf, vf, af)
        tau_red = pin.rnea(rm, rd, qr, vr, ar)
        np.testing.assert_allclose(tau_full[[full.v_index(n) for n in free]], tau_red, atol=1e-10)


@pytest.mark.parametrize("spec, frame", [("example-robot-data:ur5", "tool0"),
                                         ("example-robot-data:panda", "panda_link7"),
                                         ("two_link_arm", "tip")])
def test_frame_angle_jacobian_matches_finite_differences(spec, frame):
    model = load_robot(spec).model
    angle = FrameAngle(model, frame, [0.3, -0.2, 1.0], [0.1, 1.0, 0.2])
    rng = np.random.default_rng(1)
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, model.nq)
        y, jac = angle.value_and_jacobian(q)
        fd = np.array([(angle.value(q + 1e-6 * e) - angle.value(q - 1e-6 * e)) / 2e-6
                       for e in np.eye(model.nv)])
        assert y == pytest.approx(angle.value(q))
        np.testing.assert_allclose(jac, fd, atol=1e-7)


def test_frame_feedback_is_the_gradient_of_its_potential():
    """At rest, the stabilizing frame torque on the joints is -d/dq of 1/2 kp (r - y(q))^2."""
    exp = load_experiment(CONFIGS / "ur5_wrist_level.yaml")
    law, row = exp.law, exp.joints.index("wrist_1_joint")
    r = np.zeros(len(exp.joints))
    r[row] = law.targets[row] + 0.2
    q = np.array([-1.1, 0.9, 0.1])
    zero = np.zeros(3)
    only = np.zeros(3)
    only[row] = 1.0
    u_fb, u_rows, u_err = law.terms(q, zero, r, zero, only)

    def potential(qq):
        return 0.5 * law.kp[row] * (r[row] - law.quantity(qq)[row]) ** 2

    grad = np.array([(potential(q + 1e-6 * e) - potential(q - 1e-6 * e)) / 2e-6 for e in np.eye(3)])
    stab = u_err  # the stabilizing controller's joint torques (the learning signal)
    np.testing.assert_allclose(stab, -grad, atol=1e-6)
    assert abs(u_rows[row]) > 1.0


def test_inspect_gives_a_table_json_and_a_skeleton():
    res = feltool("inspect", "example-robot-data:panda")
    assert res.returncode == 0
    assert "panda_joint4" in res.stdout and "actuated" in res.stdout and "total mass" in res.stdout
    skeleton = config_skeleton(load_robot("example-robot-data:panda"))
    assert all(f"panda_joint{i}:" in skeleton for i in range(1, 8))
