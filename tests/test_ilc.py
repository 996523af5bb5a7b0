"""The learners side by side: every learner learns on the standard arm, the norm-optimal ILC
update equals the closed-form lifted solution on a linear plant, the lifted Jacobian equals
finite differences of the nonlinear closed loop, and the Q filter has no phase."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from feltool.engines.ilc import cycle_runner
from feltool.errors import ConfigError
from feltool.learning.ilc import lifted_jacobian, q_filter
from feltool.runs.experiments import build_experiment, load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS

STANDARD = CONFIGS / "two_link_standard.yaml"
SEEDS = (0, 1, 2)  # fixed before any run was looked at


@pytest.mark.parametrize("update, cycles, bound", [
    ("gradient", 60, 0.05),
    ("gauss_newton", 60, 0.05),
    ("ilc_p", 30, 0.02),
    ("ilc_norm_optimal", 10, 0.01),
])
def test_every_learner_learns_on_the_standard_arm(update, cycles, bound):
    exp = load_experiment(STANDARD, [f"learning.update={update}"])
    for seed in SEEDS:
        res = run_seed(exp, seed, cycles=cycles)
        fb = [r["fb_abs_mean_error"] for r in res.rows]
        assert not res.summary["diverged"], (update, seed)
        assert fb[-1] < bound * fb[0], (update, seed, fb[0], fb[-1])


def test_feedback_only_keeps_the_feedback_constant():
    exp = load_experiment(STANDARD, ["learning.update=feedback_only"])
    for seed in SEEDS:
        res = run_seed(exp, seed, cycles=20)
        fb = np.array([r["fb_abs_mean_error"] for r in res.rows])
        assert abs(fb[-1] / fb[0] - 1.0) < 0.1, (seed, fb[0], fb[-1])
        np.testing.assert_allclose(fb[-5:], fb[-1], rtol=1e-6)  # a periodic steady state
        hist = res.params["elbow.weights_history"]
        assert np.array_equal(hist[0], hist[-1])  # no parameter ever moved
        assert not any(k.startswith("ilc.") for k in res.params)


def test_ilc_stores_its_torque_sequence():
    exp = load_experiment(STANDARD, ["learning.update=ilc_p"])
    res = run_seed(exp, 0, cycles=3)
    assert res.params["ilc.elbow.u_ff_correction"].shape == (exp.primitives.n_steps,)
    hist = res.params["elbow.weights_history"]
    assert np.array_equal(hist[0], hist[-1])  # ILC leaves the RMP alone


LINEAR_URDF = """<robot name="cart_xy">
  <link name="world"/>
  <link name="cart"><inertial><origin xyz="0 0 0"/><mass value="2.0"/>
    <inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="slider"><inertial><origin xyz="0 0 0"/><mass value="0.5"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="x" type="prismatic"><parent link="world"/><child link="cart"/>
    <axis xyz="1 0 0"/><limit lower="-10" upper="10" effort="0" velocity="10"/></joint>
  <joint name="y" type="prismatic"><parent link="cart"/><child link="slider"/>
    <axis xyz="0 1 0"/><limit lower="-10" upper="10" effort="0" velocity="10"/></joint>
</robot>
"""


def _linear_experiment(tmp_path, update: str = "ilc_norm_optimal"):
    urdf = tmp_path / "cart_xy.urdf"
    urdf.write_text(LINEAR_URDF)
    raw = {"name": "linear", "robot": str(urdf), "gravity": 0.0, "period_s": 0.5,
           "sim": {"rate_hz": 40},
           "joints": {"x": {"role": "track", "demo": {"kind": "sine", "amplitude": 0.3},
                            "gains": {"kp": 40.0, "kd": 6.0}},
                      "y": {"role": "stabilize", "target": {"value": 0.1},
                            "gains": {"kp": 30.0, "kd": 4.0},
                            "learn": {"init": "random", "goal_spread": 0.05}}},
           "learning": {"update": update},
           "ilc": {"weight_error": 2.0, "weight_change": 0.05}}
    return build_experiment(raw, source=tmp_path / "linear.yaml")


def test_norm_optimal_update_equals_the_closed_form_lifted_solution(tmp_path):
    exp = _linear_experiment(tmp_path)
    n, h = exp.primitives.n_steps, exp.config.dt
    m_x, m_y = 2.5, 0.5  # the cart carries the slider; the slider moves alone along y
    Minv = np.diag([1.0 / m_x, 1.0 / m_y])
    kp, kd = np.array([40.0, 30.0]), np.array([6.0, 4.0])
    # Semi-implicit Euler: v' = v + h M^-1 tau, q' = q + h v'; tau = u_ff + b_k - K x.
    Phi = np.block([[np.eye(2), h * np.eye(2)], [np.zeros((2, 2)), np.eye(2)]])
    Gam = np.vstack([h * h * Minv, h * Minv])
    K = np.hstack([np.diag(kp), np.diag(kd)])
    A = Phi - Gam @ K
    Ke = K[1]  # the error signal: the stabilizing (y) feedback
    G = np.zeros((n, n))
    for k in range(n):
        for j in range(k):
            G[k, j] = -Ke @ np.linalg.matrix_power(A, k - 1 - j) @ Gam[:, 1]
    we, wu = 2.0, 0.05

    theta = exp.initial_parameters(4)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_nominal = Ad @ np.diag([m_x, m_y])  # RNEA of a linear plant without gravity: M qdd
    run = cycle_runner(exp, theta, 4, lambda plant: exp.loop)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    dU = np.zeros(n)
    for _ in range(3):  # three cycles: the update also holds from a nonzero correction
        # the cycle in closed form
        x, E = np.concatenate([q, v]), np.empty(n)
        for k in range(n):
            b = kp * R[k] + kd * Rd[k]
            E[k] = b[1] - Ke @ x
            x = A @ x + Gam @ (u_nominal[k] + np.array([0.0, dU[k]]) + b)
        out = run(theta, q, v, exp.dynamics)
        log, _ = out.trace()
        np.testing.assert_allclose(log.u_err[:, 1], E, rtol=0, atol=1e-9)
        dU = dU - np.linalg.solve(we * G.T @ G + wu * np.eye(n), we * G.T @ E)
        np.testing.assert_allclose(run.state["dU"][:, 0], dU, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.concatenate([out.q_end, out.v_end]), x, atol=1e-9)
        q, v = out.q_end, out.v_end
    assert np.abs(dU).max() > 0.1  # the update did something


def test_lifted_jacobian_matches_finite_differences_on_the_nonlinear_arm():
    exp = load_experiment(STANDARD, ["learning.update=ilc_norm_optimal"])
    theta = exp.initial_parameters(1)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_ff = exp.dynamics.inverse_batch(Qd, Vd, Ad)
    q0, v0 = exp.law.consistent_state(Qd[0], Vd[0])
    log = exp.loop.run_cycle(q0, v0, R, Rd, u_ff)
    Tau = exp.loop.actuated * (u_ff + log.u_fb)
    inputs = outputs = np.array([1])
    G = lifted_jacobian(exp.robot.model, exp.law, exp.loop.actuated, exp.loop.dt, 1,
                        "semi_implicit_euler", log.q, log.v, R, Rd, Tau, inputs, outputs,
                        exp.loop.error_rows)
    n = len(R)
    assert G.shape == (n, n)
    assert np.allclose(np.triu(G), 0.0)  # causal: a torque acts only on later samples
    eps = 1e-5
    for j in (0, 17, 60, n - 2):
        cols = []
        for sign in (1.0, -1.0):
            u = u_ff.copy()
            u[j, 1] += sign * eps
            cols.append(exp.loop.run_cycle(q0, v0, R, Rd, u).u_err[:, 1])
        fd = (cols[0] - cols[1]) / (2 * eps)
        np.testing.assert_allclose(G[:, j], fd, atol=1e-6 * max(1.0, np.abs(fd).max()))


def test_q_filter_is_zero_phase_with_the_squared_butterworth_gain():
    rate, cutoff, n = 100.0, 8.0, 100
    t = np.arange(n) / rate
    b, a = signal.butter(2, cutoff / (0.5 * rate))
    for f in (1.0, 3.0, 7.0, 12.0):
        x = np.sin(2 * np.pi * f * t + 0.4)
        _, H = signal.freqz(b, a, worN=[f], fs=rate)
        np.testing.assert_allclose(q_filter(x, cutoff, rate, 2), np.abs(H[0]) ** 2 * x,
                                   atol=1e-6)
    np.testing.assert_array_equal(q_filter(x, None, rate), x)


def test_ilc_learners_refuse_what_they_cannot_do():
    with pytest.raises(ConfigError) as err:
        load_experiment(STANDARD, ["learning.update=ilc_p", "backend=compiled"])
    assert "backend: 'ilc_p' needs the pinocchio or casadi backend" in str(err.value)


@pytest.mark.parametrize("sets", [
    ["learning.update=ilc_norm_optimal", "disturbances.measurement_noise.q=0.002"],
    ["learning.update=ilc_p", "disturbances.torque_noise=0.2"],
    ["learning.update=gradient", "disturbances.input_delay_steps=1"],
])
def test_resume_continues_the_learned_sequence_and_the_noise_bit_identically(tmp_path, sets):
    from feltool.runs.checkpoint import Checkpointer

    exp = load_experiment(STANDARD, sets)
    whole = run_seed(exp, 3, cycles=12)
    ck = Checkpointer(tmp_path, 3, every=4)
    run_seed(exp, 3, cycles=6, checkpoint=ck)  # stops after cycle 6, its state kept
    resumed = run_seed(exp, 3, cycles=12, checkpoint=ck)
    assert [r["fb_abs_mean_error"] for r in resumed.rows] == \
        [r["fb_abs_mean_error"] for r in whole.rows]
    for key, value in whole.params.items():
        np.testing.assert_array_equal(resumed.params[key], value)


def test_lifted_jacobian_of_a_frame_angle_law_matches_finite_differences():
    """The UR5 holds its tool axis level (a frame angle, whose torque acts on every joint that
    moves the frame): the lifted model's feedback derivatives come from differences of the law."""
    exp = load_experiment(CONFIGS / "ur5_wrist_level.yaml", ["learning.update=ilc_norm_optimal"])
    from feltool.engines.ilc import channels

    inputs, outputs = channels(exp)
    assert len(inputs) == 3  # the frame torque reaches shoulder, elbow and wrist
    theta = exp.initial_parameters(0)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    n = 30  # the first 30 samples are enough to check the chain
    Qd, Vd, Ad = Qd[:n], Vd[:n], Ad[:n]
    R, Rd = exp.law.references(Qd, Vd)
    u_ff = exp.dynamics.inverse_batch(Qd, Vd, Ad)
    q0, v0 = exp.law.consistent_state(Qd[0], Vd[0])
    log = exp.loop.run_cycle(q0, v0, R, Rd, u_ff)
    G = lifted_jacobian(exp.robot.model, exp.law, exp.loop.actuated, exp.loop.dt, 1,
                        "semi_implicit_euler", log.q, log.v, R, Rd, u_ff + log.u_fb, inputs,
                        outputs, exp.loop.error_rows)
    assert G.shape == (3 * n, 3 * n)
    eps = 1e-5
    for j, c in ((0, 2), (7, 0), (20, 1)):
        outs = []
        for sign in (1.0, -1.0):
            u = u_ff.copy()
            u[j, inputs[c]] += sign * eps
            outs.append(exp.loop.run_cycle(q0, v0, R, Rd, u).u_err[:, outputs].reshape(-1))
        fd = (outs[0] - outs[1]) / (2 * eps)
        np.testing.assert_allclose(G[:, 3 * j + c], fd, atol=1e-5 * max(1.0, np.abs(fd).max()))
