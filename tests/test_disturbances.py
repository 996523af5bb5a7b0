"""Disturbances act on the plant only: the learner's inputs are the noisy measurements, the
known model sees nothing but the desired trajectory, delay and torque noise reach the plant,
and model error scales the plant's physics by the scaling laws."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.engines.disturbed import disturbed_loop
from feltool.engines.ilc import cycle_runner
from feltool.learning.ilc import lifted_jacobian
from feltool.plant.disturbances import scaled_model
from feltool.runs.experiments import load_experiment

from .conftest import CONFIGS

STANDARD = CONFIGS / "two_link_standard.yaml"
NOISE = ["disturbances.measurement_noise.q=0.01", "disturbances.measurement_noise.v=0.1"]


class Recorder:
    """Our own known model wrapped so that every argument it is given is kept."""

    def __init__(self, inner):
        self.inner, self.calls = inner, []
        self.nq, self.nv, self.euclidean = inner.nq, inner.nv, inner.euclidean

    def __getattr__(self, name):
        fn = getattr(self.inner, name)

        def call(*args):
            self.calls.append((name, [np.array(a, copy=True) for a in args]))
            return fn(*args)

        return call


def _stabilizing_pd(exp, Q, V):
    """The elbow's law in closed form (§3.1): kp (pi/2 - (q1 + q2)) - kd (v1 + v2)."""
    kp, kd = 50.0, 10.0
    return kp * (np.pi / 2 - Q.sum(axis=1)) - kd * V.sum(axis=1)


def test_fel_learns_from_the_noisy_measurements_and_the_model_never_sees_them():
    exp = load_experiment(STANDARD, NOISE)
    known = Recorder(exp.dynamics)
    plant = exp.plant
    exp.dynamics = known  # the plant (exp.plant) stays the unwrapped object
    theta = exp.initial_parameters(0)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    run = cycle_runner(exp, theta, 0, lambda p: exp.loop)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    out = run(theta, q, v, plant)
    log, _ = out.trace()

    # The measurements are the true states plus noise of the configured size.
    dq, dv = log.q - log.q_true, log.v - log.v_true
    assert 0.8 * 0.01 < dq.std() < 1.2 * 0.01 and abs(dq.mean()) < 0.003
    assert 0.8 * 0.1 < dv.std() < 1.2 * 0.1
    # The error signal is the PD law of the measurements, not of the true states.
    np.testing.assert_allclose(log.u_err[:, 1], _stabilizing_pd(exp, log.q, log.v), atol=1e-10)
    e_true = _stabilizing_pd(exp, log.q_true, log.v_true)
    assert np.abs(log.u_err[:, 1] - e_true).std() > 0.3  # kp 0.01 sqrt(2) + kd 0.1 sqrt(2)
    # FEL's update used that noisy error signal (the default step fits it through the known
    # model's closed loop, learning.fit: closed_loop).
    assert exp.learner.fit == "closed_loop"
    derivs = known.inner.inverse_derivatives_batch(Qd, Vd, Ad)[1:]
    J = exp.learner.jacobian(known.inner, theta, Qd, Vd, Ad, derivs)

    def step(E, dx):
        return exp.learner.closed_loop_step(theta, J, derivs, E, Qd, None, dx)

    E_true = np.zeros_like(log.u_err)
    E_true[:, 1] = e_true
    # ... and the measured change of state over the cycle (for its start's transient)
    dx = log.measured_change(known.inner)
    dx_true = np.concatenate([log.q_end - log.q_true[0], log.v_end - log.v_true[0]])
    assert np.abs(dx[2:] - dx_true[2:]).max() > 0.05  # the velocities' noise, 0.1 rad/s
    np.testing.assert_allclose(out.theta_next, step(log.u_err, dx), atol=1e-10)
    assert not np.allclose(out.theta_next, step(E_true, dx), atol=1e-6)
    assert not np.allclose(out.theta_next, step(log.u_err, dx_true), atol=1e-6)
    # The known model was only asked about the desired trajectory (and the measured states'
    # difference), and never simulated.
    inverse = [args for name, args in known.calls if name.startswith("inverse")]
    assert inverse and [name for name, _ in known.calls if name not in (
        "inverse_batch", "inverse_derivatives_batch")] == ["difference"]
    diff = next(args for name, args in known.calls if name == "difference")
    np.testing.assert_array_equal(diff[0], log.q[0])  # measured, not true
    for args in inverse:
        np.testing.assert_array_equal(args[0], Qd)
        np.testing.assert_array_equal(args[1], Vd)
        np.testing.assert_array_equal(args[2], Ad)
    # The plant moved on the true states: its own forward model reproduces them.
    qk, vk = q.copy(), v.copy()
    for k in range(len(Qd)):
        np.testing.assert_allclose(qk, log.q_true[k], atol=1e-12)
        vk = vk + exp.config.dt * pin.aba(exp.robot.model, exp.robot.model.createData(), qk, vk,
                                          log.tau_applied[k])
        qk = qk + exp.config.dt * vk
    np.testing.assert_allclose(log.tau_applied, log.u_fb + exp.dynamics.inverse_batch(Qd, Vd, Ad),
                               atol=1e-10)


def test_norm_optimal_ilc_linearizes_about_the_measured_cycle():
    exp = load_experiment(STANDARD, NOISE + ["learning.update=ilc_norm_optimal"])
    theta = exp.initial_parameters(1)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    run = cycle_runner(exp, theta, 1, lambda p: exp.loop)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    log, _ = run(theta, q, v, exp.plant).trace()
    u_ff = exp.dynamics.inverse_batch(Qd, Vd, Ad)
    idx = np.array([1])
    w = exp.config.ilc

    def update(Q, V, E):
        G = lifted_jacobian(exp.robot.model, exp.law, exp.loop.actuated, exp.config.dt, 1,
                            "semi_implicit_euler", Q, V, R, Rd, u_ff + log.u_fb, idx, idx,
                            exp.loop.error_rows)
        n = len(E)
        return -np.linalg.solve(w.weight_error * G.T @ G + w.weight_change * np.eye(n),
                                w.weight_error * G.T @ E)

    measured = update(log.q, log.v, log.u_err[:, 1])
    np.testing.assert_allclose(run.state["dU"][:, 0], measured, atol=1e-9)
    true = update(log.q_true, log.v_true, _stabilizing_pd(exp, log.q_true, log.v_true))
    assert np.abs(true - measured).max() > 1e-3


def test_delay_and_torque_noise_reach_the_plant():
    exp = load_experiment(STANDARD, ["disturbances.input_delay_steps=3",
                                     "disturbances.torque_noise=0.5"])
    theta = exp.initial_parameters(2)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    R, Rd = exp.law.references(Qd, Vd)
    u_ff = exp.dynamics.inverse_batch(Qd, Vd, Ad)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    loop = disturbed_loop(exp)
    loop.rng = np.random.default_rng(5)
    log = loop.run_cycle(q, v, R, Rd, u_ff)
    cmd = u_ff + log.u_fb
    np.testing.assert_array_equal(log.q, log.q_true)  # no measurement noise configured
    w = log.tau_applied[3:] - cmd[:-3]
    assert 0.4 < w.std() < 0.6 and abs(w.mean()) < 0.15
    assert np.all(np.abs(log.tau_applied[:3] - cmd[0]) < 5 * 0.5)
    # The second cycle receives the first cycle's last three commands.
    loop.rng = np.random.default_rng(6)
    log2 = loop.run_cycle(log.q_end, log.v_end, R, Rd, u_ff)
    w2 = log2.tau_applied[:3] - cmd[-3:]
    assert np.abs(w2).max() < 5 * 0.5
    # The same generator draws the same noise.
    loop2 = disturbed_loop(exp)
    loop2.rng = np.random.default_rng(5)
    np.testing.assert_array_equal(loop2.run_cycle(q, v, R, Rd, u_ff).tau_applied, log.tau_applied)


def test_model_error_scales_the_plant_by_the_scaling_laws_and_leaves_the_model():
    exp = load_experiment(STANDARD, ["disturbances.model_error.mass_scale=1.5",
                                     "disturbances.model_error.length_scale=0.8"])
    model = exp.robot.model
    masses = [float(i.mass) for i in model.inertias]
    plant = disturbed_loop(exp).dynamics
    assert plant is not exp.dynamics
    assert [float(i.mass) for i in exp.robot.model.inertias] == masses
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-np.pi, np.pi, 2)
        # Every term of M is a mass times a length squared: M_plant = s_m s_l^2 M.
        M = pin.crba(model, model.createData(), q)
        Ms = pin.crba(plant.model, plant.model.createData(), q)
        np.testing.assert_allclose(np.triu(Ms), 1.5 * 0.8 ** 2 * np.triu(M), atol=1e-12)
        # Gravity torques are a mass times a length: g_plant = s_m s_l g.
        g = pin.computeGeneralizedGravity(model, model.createData(), q)
        gs = pin.computeGeneralizedGravity(plant.model, plant.model.createData(), q)
        np.testing.assert_allclose(gs, 1.5 * 0.8 * g, atol=1e-12)
    scaled = scaled_model(model, 2.0, 1.0)
    assert sum(float(i.mass) for i in scaled.inertias) == 2.0 * sum(masses)


# -- the physical walker (feltool.plant.disturbances.WalkerDisturbance) -------------------------------
FIVE_LINK = CONFIGS / "gaits" / "five_link_walker.yaml"


def _walker_cycle(sets: list[str], seed: int = 0):
    """One cycle of the five-link walker through its cycle runner: (exp, run, outcome, log)."""
    from feltool.runs.seed import _cycle_runner

    exp = load_experiment(FIVE_LINK, ["walking.poincare=false", *sets])
    theta = exp.initial_parameters(seed)
    P, Pv, _ = exp.primitives.desired(theta)
    q, v = exp.hybrid.initial_state(P, Pv)
    run = _cycle_runner(exp, theta, seed)
    out = run(theta, q, v, exp.dynamics)
    assert out.fall is None
    return exp, run, out, out.trace()[0]


def test_walker_learner_sees_the_noisy_measurements_and_the_plant_the_true_state():
    """The walker's feedback, allocation, inertial error term and FEL's update come from the
    measurements (angles and rates with noise, the base from the stance leg's kinematics); the
    plant moves on its true state under the torques it received. ``walking.phase: touchdown``
    (one cycle), so that the references do not depend on the measured state."""
    from feltool.engines.python import error_torques, motor_step

    exp, run, out, log = _walker_cycle(["walking.phase=touchdown",
                                        "disturbances.measurement_noise.q=0.001",
                                        "disturbances.measurement_noise.v=0.01"])
    dist, W = run.loop.disturbance, exp.hybrid.walker
    Qt, Vt = np.array(dist.true_q), np.array(dist.true_v)
    sensed = [exp.joints.index(n) for n in ("base_pitch", "left_hip", "left_knee", "right_hip",
                                             "right_knee")]
    dq, dv = log.q[:, sensed] - Qt[:, sensed], log.v[:, sensed] - Vt[:, sensed]
    assert 0.8e-3 < dq.std() < 1.2e-3 and abs(dq.mean()) < 2e-4
    assert 0.8e-2 < dv.std() < 1.2e-2
    # the base is not sensed: leg odometry puts the known model's stance foot at the origin
    for k in range(0, len(log.q), 37):
        p, pv = W.contact.foot_state(log.q[k], log.v[k], "left")
        assert np.abs(p).max() < 1e-9 and np.abs(pv).max() < 1e-9
    assert np.abs(log.q[:, :2] - Qt[:, :2]).max() > 1e-4
    # the feedback is the PD law (closed form) of the measurements against the references
    P, Pv, Pa = exp.primitives.desired(exp.initial_parameters(0))
    Rq, Rv, Ra = exp.hybrid._referenced(P, Pv, Pa)
    kp = np.array([exp.config.joints[exp.joints[j]].gains.kp for j in sensed])
    kd = np.array([exp.config.joints[exp.joints[j]].gains.kd for j in sensed])
    for k in range(len(log.q)):
        j, s = log.phase_index[k], log.stance[k]
        qr, vr, ar = W.complete(*W.labelled(Rq[j], Rv[j], Ra[j], s))
        pd = kp * (qr[sensed] - log.q[k, sensed]) + kd * (vr[sensed] - log.v[k, sensed])
        np.testing.assert_allclose(log.u_fb[k, sensed], pd, atol=1e-9)
        pd_true = kp * (qr[sensed] - Qt[k, sensed]) + kd * (vr[sensed] - Vt[k, sensed])
        assert np.abs(pd - pd_true).max() > 0.1  # kp 1e-3 + kd 1e-2: 1.5-6 N m per joint
        if k % 50 == 0:
            # the allocation is the known model's at the measurement (A B = I)
            A = log.allocation[k]
            np.testing.assert_allclose(A @ W.B, np.eye(4), atol=1e-9)
            np.testing.assert_allclose(A, W.allocation_matrix(log.q[k]), atol=1e-12)
            assert np.abs(A - W.allocation_matrix(Qt[k])).max() > 1e-6
            # the inertial term: known M at the measurement, the plant's acceleration under
            # the applied torques plus the differentiated velocity noise
            a = W.contact.stance(Qt[k], Vt[k], W.B @ dist.applied[k], "left").a
            noise = log.v - Vt
            a_measured = a + (noise[k] - noise[max(k - 1, 0)]) / exp.config.dt
            M = pin.crba(W.contact.model, W.contact.model.createData(), log.q[k])
            M = np.triu(M) + np.triu(M, 1).T
            np.testing.assert_allclose(log.inertial[k], M @ (ar - a_measured), atol=1e-6)
    # FEL's update is the one of these measured arrays
    theta = exp.initial_parameters(0)
    _, *derivs = exp.hybrid.jacobian_derivatives(log)
    J = exp.learner.jacobian(exp.dynamics, theta, log.Qd, log.Vd, log.Ad, derivs,
                             samples=log.phase_index)
    np.testing.assert_allclose(out.theta_next, motor_step(exp, theta, log.allocation, J,
                                                           error_torques(exp, log)), atol=1e-12)
    assert np.abs(out.theta_next - theta).max() > 1e-6
    # the plant moved on the true states under the applied torques (steps without touchdown)
    touch = {k for k, _, _ in log.impacts}
    for k in range(0, len(Qt) - 1, 23):
        if k + 1 in touch:
            continue
        q1, v1 = exp.hybrid._rk4(W.contact, Qt[k], Vt[k], W.B @ dist.applied[k], exp.config.dt)
        q1, v1 = W.contact.hold(q1, v1, "left", np.zeros(2))
        np.testing.assert_allclose(q1, Qt[k + 1], atol=1e-10)
        np.testing.assert_allclose(v1, Vt[k + 1], atol=1e-8)


def test_walker_delay_and_torque_noise_reach_the_motors():
    exp, run, out, log = _walker_cycle(["disturbances.input_delay_steps=2",
                                        "disturbances.torque_noise=0.3"], seed=1)
    dist = run.loop.disturbance
    applied = np.array(dist.applied)
    np.testing.assert_allclose(log.q, np.array(dist.true_q), atol=1e-9)  # no sensor noise
    w = applied[2:] - log.tau[:-2]  # the command two control steps earlier, plus the noise
    assert 0.25 < w.std() < 0.35 and abs(w.mean()) < 0.05
    assert np.abs(applied[:2] - log.tau[0]).max() < 5 * 0.3  # the first command, held
    # the same generator draws the same disturbances
    _, run2, _, log2 = _walker_cycle(["disturbances.input_delay_steps=2",
                                      "disturbances.torque_noise=0.3"], seed=1)
    np.testing.assert_array_equal(np.array(run2.loop.disturbance.applied), applied)
    np.testing.assert_array_equal(log2.q, log.q)


def test_walker_model_error_scales_the_feet_and_stands_the_plant_on_its_foot():
    from feltool.engines.disturbed import disturbed_plant
    from feltool.engines.ilc_walker import on_ground

    exp, run, out, log = _walker_cycle(["disturbances.model_error.length_scale=1.2"])
    plant = disturbed_plant(exp)
    W = exp.hybrid.walker
    known, scaled = W.contact, W.contact_for(plant.model)
    q = pin.neutral(plant.model)
    q[exp.joints.index("left_knee")] = 0.3
    for foot in ("left", "right"):  # a foot's position scales with the lengths
        np.testing.assert_allclose(scaled.foot_state(q, 0 * q, foot)[0],
                                   1.2 * known.foot_state(q, 0 * q, foot)[0], atol=1e-12)
    assert plant.model is not exp.dynamics.model
    assert exp.hybrid.walker.walker.model is exp.dynamics.model  # the known model unchanged
    # the designed start stands on the scaled walker's foot: at the origin, at rest
    q0 = run.loop.disturbance.true_q[0]
    v0 = run.loop.disturbance.true_v[0]
    p, pv = scaled.foot_state(q0, v0, "left")
    assert np.abs(p).max() < 1e-9 and np.abs(pv).max() < 1e-9
    P, Pv, _ = exp.primitives.desired(exp.initial_parameters(0))
    qs, vs = on_ground(exp, plant, *exp.hybrid.initial_state(P, Pv))
    np.testing.assert_allclose(qs, q0, atol=1e-12)
    assert out.contact["step_length"] > 0.45  # longer legs, longer steps (design: 0.40 m)
