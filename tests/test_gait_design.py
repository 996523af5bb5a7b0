"""Gait design by direct collocation, checked against independent references.

* The passive compass gait (Goswami et al. 1996) on a 3 degree slope against a shooting
  computation on the closed-form compass-gait equations written here (Lagrange's equations of
  three point masses, the impact by conservation of angular momentum, scipy's solve_ivp and
  fsolve).
* The collocation's dynamics against Pinocchio's ABA at the solution's knots; the impact and the
  periodicity against Pinocchio's mass matrix and Jacobian and the walker's relabelling.
* The failure path names the constraint group violated most.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

from feltool.gait.design import GROUPS, GaitDesignError, GaitSpec, design_gait
from feltool.robot.robot import load_robot
from feltool.walking.model import FootSpec, build_walker_model

from .conftest import other_walker_urdf

# Goswami et al. 1996: leg mass m at a from the foot, b from the hip; hip mass m_H.
M_LEG, M_HIP, A_LEG, B_LEG, G = 5.0, 10.0, 0.5, 0.5, 9.81
L_LEG = A_LEG + B_LEG
SLOPE = np.deg2rad(3.0)


def compass_walker():
    robot = load_robot("compass_gait")
    robot.set_gravity(G)
    return build_walker_model(robot, {"left": FootSpec(frame="left_foot"),
                                      "right": FootSpec(frame="right_foot")},
                              [("base_pitch", "hip")])


@pytest.fixture(scope="module")
def passive_gait():
    walker = compass_walker()
    spec = GaitSpec(passive=True, slope=SLOPE, clearance=False, knots=60)
    return walker, spec, design_gait(walker, spec)


# --- the closed-form compass gait ------------------------------------------------------------
# Coordinates in the slope's frame (x down the slope, z normal to it): th_s, th_w are the stance
# and swing legs' angles from the slope's normal, each leg's foot-to-hip vector being
# l (sin th, cos th); gravity g (sin gamma, -cos gamma).

def closed_form_dynamics(t, x):
    ts, tw, dts, dtw = x
    mlb = M_LEG * L_LEG * B_LEG
    M = np.array([[M_LEG * A_LEG**2 + (M_HIP + M_LEG) * L_LEG**2, -mlb * np.cos(ts - tw)],
                  [-mlb * np.cos(ts - tw), M_LEG * B_LEG**2]])
    c = np.array([-mlb * np.sin(ts - tw) * dtw**2, mlb * np.sin(ts - tw) * dts**2])
    g = np.array([-G * (M_LEG * A_LEG + (M_HIP + M_LEG) * L_LEG) * np.sin(ts + SLOPE),
                  M_LEG * B_LEG * G * np.sin(tw + SLOPE)])
    dd = np.linalg.solve(M, -c - g)
    return [dts, dtw, dd[0], dd[1]]


def _masses(ts, tw):
    """Positions (foot of the stance leg at 0) and velocity maps (d/d(dts, dtw)) of the stance
    leg's mass, the hip and the swing leg's mass."""
    es, ew = np.array([np.sin(ts), np.cos(ts)]), np.array([np.sin(tw), np.cos(tw)])
    ds, dw = np.array([np.cos(ts), -np.sin(ts)]), np.array([np.cos(tw), -np.sin(tw)])
    hip = L_LEG * es
    return [(M_LEG, A_LEG * es, np.column_stack([A_LEG * ds, [0, 0]])),
            (M_HIP, hip, np.column_stack([L_LEG * ds, [0, 0]])),
            (M_LEG, hip - B_LEG * ew, np.column_stack([L_LEG * ds, -B_LEG * dw]))]


def _momentum(bodies, point, rate):
    return sum(m * _cross(r - point, J @ rate) for m, r, J in bodies)


def _cross(r, v):
    return r[0] * v[1] - r[1] * v[0]


def closed_form_impact(ts, tw, dts, dtw):
    """Post-impact (th_s, th_w, dth_s, dth_w) with the legs relabelled: angular momentum about
    the new foot (whole walker) and about the hip (the leaving leg) are conserved."""
    pre = _masses(ts, tw)
    foot = pre[1][1] - L_LEG * np.array([np.sin(tw), np.cos(tw)])
    post = _masses(tw, ts)  # the new stance foot at 0
    hip_post = post[1][1]
    rate = np.array([dts, dtw])

    def leaving_leg(bodies, hip, e):  # the old stance leg's mass about the hip
        m, r, J = bodies
        return m * _cross(r - hip, J @ e)
    lhs = np.array([[_momentum(post, np.zeros(2), e) for e in np.eye(2)],
                    [leaving_leg(post[2], hip_post, e) for e in np.eye(2)]])
    rhs = np.array([_momentum(pre, foot, rate), leaving_leg(pre[0], pre[1][1], rate)])
    dts_new, dtw_new = np.linalg.solve(lhs, rhs)
    return tw, ts, dts_new, dtw_new


def closed_form_step(x0):
    """One step from just after an impact: (th_s, dth_s, dth_w), th_w = -th_s; returns the next
    one, the step's duration [s] and its length [m]."""
    ts, dts, dtw = x0
    state = [ts, -ts, dts, dtw]
    early = solve_ivp(closed_form_dynamics, (0, 0.1), state, rtol=1e-12, atol=1e-12)

    def touchdown(t, x):
        return x[0] + x[1]
    touchdown.terminal, touchdown.direction = True, 1.0
    rest = solve_ivp(closed_form_dynamics, (0.1, 5.0), early.y[:, -1], events=touchdown,
                     rtol=1e-12, atol=1e-12)
    t_end, x_end = rest.t_events[0][0], rest.y_events[0][0]
    nxt = closed_form_impact(*x_end)
    length = 2 * L_LEG * np.sin(x_end[0])
    return np.array([nxt[0], nxt[2], nxt[3]]), t_end, length


def closed_form_gait():
    x = np.array([-0.25, 1.2, 0.2])
    for _ in range(30):  # the passive gait is stable: iterate towards it, then polish
        x = closed_form_step(x)[0]
    x = fsolve(lambda y: closed_form_step(y)[0] - y, x, xtol=1e-12)
    _, period, length = closed_form_step(x)
    return x, period, length


# --- the tests -------------------------------------------------------------------------------

def test_passive_compass_gait_matches_closed_form_shooting(passive_gait):
    walker, _, gait = passive_gait
    x, period, length = closed_form_gait()
    assert np.max(np.abs(closed_form_step(x)[0] - x)) < 1e-9  # a true fixed point
    assert gait.duration == pytest.approx(period, rel=0.01)
    assert gait.step_length == pytest.approx(length, rel=0.01)
    # The state just after the impact: the stance leg's angle and the legs' rates.
    ip, ih = walker.robot.v_index("base_pitch"), walker.robot.v_index("hip")
    th_s, th_w = gait.q[0, ip], gait.q[0, ip] + gait.q[0, ih]
    assert th_s == pytest.approx(x[0], abs=0.005) and th_w == pytest.approx(-x[0], abs=0.005)
    assert gait.v[0, ip] == pytest.approx(x[1], rel=0.02)
    assert gait.v[0, ip] + gait.v[0, ih] == pytest.approx(x[2], rel=0.05, abs=0.01)
    assert gait.metrics["cost_of_transport"] == 0.0 and np.all(gait.tau == 0.0)


def _tilted(walker, slope):
    model = pin.Model(walker.model)
    g = np.linalg.norm(model.gravity.linear)
    model.gravity.linear = g * np.array([np.sin(slope), 0.0, -np.cos(slope)])
    return model


def test_dynamics_residual_against_pinocchio_aba(passive_gait):
    walker, spec, gait = passive_gait
    _check_dynamics(walker, spec, gait)


def _check_dynamics(walker, spec, gait):
    model = _tilted(walker, spec.slope)
    data = model.createData()
    fid = walker.feet[spec.stance]
    worst = 0.0
    for q, v, a, tau, f in zip(gait.q_pin, gait.v, gait.a, gait.tau, gait.force, strict=True):
        J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)[[0, 2]]
        a_pin = pin.aba(model, data, q, v, tau + J.T @ f)
        worst = max(worst, float(np.max(np.abs(a_pin - a))))
    assert worst <= 1e-6, f"collocation accelerations differ from ABA by {worst:.3g}"


def _check_impact_and_periodicity(walker, spec, gait):
    model = _tilted(walker, spec.slope)
    data = model.createData()
    qN, vN = gait.q_pin[-1], gait.v[-1]
    M = pin.crba(model, data, qN)
    M = np.triu(M) + np.triu(M, 1).T
    Jw = pin.computeFrameJacobian(model, data, qN, walker.feet[spec.swing],
                                  pin.LOCAL_WORLD_ALIGNED)[[0, 2]]
    Js = pin.computeFrameJacobian(model, data, qN, walker.feet[spec.stance],
                                  pin.LOCAL_WORLD_ALIGNED)[[0, 2]]
    assert np.allclose(M @ (gait.v_plus - vN), Jw.T @ gait.impulse, atol=1e-7)
    assert np.allclose(Jw @ gait.v_plus, 0.0, atol=1e-8)
    assert (Js @ gait.v_plus)[1] >= -1e-8  # the trailing foot lifts off
    assert gait.impulse[1] > 0 and abs(gait.impulse[0]) <= spec.friction * gait.impulse[1] + 1e-9
    pin.framesForwardKinematics(model, data, qN)
    foot = data.oMf[walker.feet[spec.swing]].translation
    assert foot[2] == pytest.approx(0.0, abs=1e-9)
    assert foot[0] == pytest.approx(gait.step_length, abs=1e-9)
    q_next, v_next = walker.relabel(qN.copy(), gait.v_plus.copy())
    q_next[walker.robot.q_index("base_x")] -= gait.step_length
    assert np.allclose(q_next, gait.q_pin[0], atol=1e-9)
    assert np.allclose(v_next, gait.v[0], atol=1e-9)


def test_impact_and_periodicity_hold_at_the_solution(passive_gait):
    walker, spec, gait = passive_gait
    _check_impact_and_periodicity(walker, spec, gait)


def test_actuated_compass_gait_respects_its_constraints():
    walker = compass_walker()
    spec = GaitSpec(slope=0.03, step_length=0.4, duration=0.6, knots=30)
    gait = design_gait(walker, spec)
    _check_dynamics(walker, spec, gait)
    _check_impact_and_periodicity(walker, spec, gait)
    effort = walker.model.effortLimit[walker.robot.v_index("hip")]
    assert np.abs(gait.tau).max() <= effort + 1e-6
    assert np.all(gait.force[:, 1] >= -1e-6)
    assert np.all(np.abs(gait.force[:, 0]) <= spec.friction * gait.force[:, 1] + 1e-6)
    assert gait.step_length == pytest.approx(0.4) and gait.duration == pytest.approx(0.6)
    assert gait.metrics["min_clearance_m"] >= -1e-6  # outside the 5 cm scuffing band


def test_infeasible_step_names_the_violated_constraint_group():
    walker = compass_walker()
    spec = GaitSpec(step_length=2.5, duration=0.6, knots=20, max_iter=60)  # legs are 1 m long
    with pytest.raises(GaitDesignError, match="constraint group violated most is '") as info:
        design_gait(walker, spec)
    name = str(info.value).split("violated most is '")[1].split("'")[0]
    assert name in GROUPS


# --- the demos it writes ---------------------------------------------------------------------

def test_samples_demo_is_exact_for_a_cubic_with_linear_acceleration():
    from feltool.motion.rmp import samples_demo

    T, knots = 0.8, np.linspace(0.0, 0.8, 9)
    t = np.linspace(0.0, T, 101, endpoint=False)
    q, v, a = samples_demo(knots**3 - knots, 3 * knots**2 - 1, 6 * knots, T, t)
    assert np.allclose(q, t**3 - t, atol=1e-12)
    assert np.allclose(v, 3 * t**2 - 1, atol=1e-12)
    assert np.allclose(a, 6 * t, atol=1e-12)
    # A time on a knot takes that knot's values (not the end of the interval before: a velocity
    # jumps there at an impact), even where floating point puts t / h just below the knot.
    step = np.array([0.0, 1.0, 2.0, 3.0, 10.0, 11.0, 12.0])
    T = 0.0125 * 6
    q, v, _ = samples_demo(step, step, np.zeros(7), T, np.array([0.5 * T, 4 * 0.0125]))
    assert v[1] == pytest.approx(10.0) and q[1] == pytest.approx(10.0)


def test_samples_demo_fits_the_rmp_as_the_same_sine_does():
    from feltool.config.files import read_yaml
    from feltool.runs.experiments import build_experiment, resolve_config_path

    raw = read_yaml(resolve_config_path("two_link_standard"))
    sine = build_experiment(raw)
    demo = raw["joints"]["shoulder"]["demo"]
    T = raw["period_s"]
    t = np.linspace(0.0, T, 201)
    w = 2 * np.pi / T
    raw["joints"]["shoulder"]["demo"] = {
        "kind": "samples", "q": list(demo["mean"] + demo["amplitude"] * np.sin(w * t)),
        "v": list(demo["amplitude"] * w * np.cos(w * t)),
        "a": list(-demo["amplitude"] * w**2 * np.sin(w * t))}
    samples = build_experiment(raw)
    block = sine.primitives.slices[0]
    expected = sine.theta_demo[block]
    assert np.allclose(samples.theta_demo[block], expected, atol=1e-3 * np.abs(expected).max())


def test_cli_writes_a_gait_config_and_fails_cleanly(tmp_path, capsys):
    import yaml

    from feltool.cli.main import main

    out = tmp_path / "gait.yaml"
    assert main(["gait", "configs/gaits/compass_gait.yaml", "--step-length", "0.4", "--knots",
                 "24", "--duration", "0.6", "--demos", "knots", "--verify-steps", "2",
                 "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    for word in ("solver time", "iterations", "period", "speed", "step length",
                 "cost of transport", "min F_n", "max |F_t|/F_n", "constraint violation"):
        assert word in text
    config = yaml.safe_load(out.read_text())
    hip = config["joints"]["hip"]["demo"]
    # steps_per_cycle 2: two steps in the first step's labels, 2 x 24 intervals; the demo is
    # periodic in position (the second step is the first relabelled), its velocity jumps at
    # the touchdown (knot 24) and at the cycle's end.
    assert hip["kind"] == "samples" and len(hip["q"]) == 49
    assert config["period_s"] == pytest.approx(1.2)
    for joint in ("hip", "base_pitch"):
        demo = config["joints"][joint]["demo"]
        assert demo["q"][-1] == pytest.approx(demo["q"][0], abs=1e-6)
    bad = tmp_path / "bad.yaml"
    assert main(["gait", "configs/gaits/compass_gait.yaml", "--step-length", "2.5", "--knots",
                 "16", "--out", str(bad), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "constraint group violated most" in err and "Traceback" not in err
    assert not bad.exists()


def test_a_walker_never_seen_gets_a_gait_from_its_config_alone(tmp_path):
    """A torso-rooted five-link walker with other masses and lengths and continuous joints,
    feet given as link + offset: the designer needs nothing but the config."""
    from feltool.gait.config import gait_spec, walker_from_raw

    (tmp_path / "other_walker.urdf").write_text(other_walker_urdf())
    raw = {"robot": "other_walker.urdf", "gravity": 9.81, "period_s": 0.55,
           "joints": {"base_pitch": {"role": "stabilize", "target": {"value": 0.05}}},
           "walking": {"feet": {"left": {"link": "left_shin", "offset": [0, 0, -0.45]},
                                "right": {"link": "right_shin", "offset": [0, 0, -0.45]}},
                       "legs": [["left_hip", "right_hip"], ["left_knee", "right_knee"]],
                       "friction": 0.8}}
    walker, settings = walker_from_raw(raw, tmp_path / "other.yaml")
    assert walker.model.nq == walker.model.nv + 4  # four (cos, sin) joints
    spec = gait_spec(raw, walker, settings, speed=0.7, knots=24)
    gait = design_gait(walker, spec)
    _check_dynamics(walker, spec, gait)
    _check_impact_and_periodicity(walker, spec, gait)
    assert gait.metrics["min_clearance_m"] >= -1e-6  # no scuffing zone with knees
    assert np.mean(gait.q[:, walker.robot.v_index("base_pitch")]) == pytest.approx(0.05)


def test_margins_for_tracking_hold_at_the_solution():
    walker = compass_walker()
    spec = GaitSpec(slope=0.03, step_length=0.4, duration=0.6, knots=24,
                    normal_force_margin=0.7, clearance_margin_m=0.004)
    gait = design_gait(walker, spec)
    mg = 20.0 * G
    assert gait.force[:, 1].min() >= 0.7 * mg - 1e-5
    model = _tilted(walker, spec.slope)
    data = model.createData()
    for q in gait.q_pin[2:-2]:
        pin.framesForwardKinematics(model, data, q)
        swing = data.oMf[walker.feet["right"]].translation
        stance = data.oMf[walker.feet["left"]].translation
        if abs(swing[0] - stance[0]) >= 0.05:  # outside the scuffing zone
            assert swing[2] >= 0.004 - 1e-7
