"""The three-link biped: Pinocchio against the corrected closed forms of App. B, the one
absolute <-> relative conversion, the impact maps, and the fall check."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.robot.robot import load_robot
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed
from feltool.walking.pinned import Allocation

from .conftest import CONFIGS

M_LEG, M_H, M_T, R, L, G = 15.0, 10.0, 40.0, 1.0, 1.0, 9.8  # Table B.1
T = np.array([[1.0, 0, 0], [1, 1, 0], [1, 0, 1]])  # theta = T q (thesis absolute from relative)


def closed_form(theta, dtheta):
    """Eq. B.2-B.4 in absolute angles, with the two errata corrected: c13 uses dtheta3 (not
    dtheta1) and the torso's gravity entry is -g M_T l sin(theta3) (not +1/2 g M_T l sin)."""
    t1, t2, t3 = theta
    c12, c13, s12, s13 = np.cos(t1 - t2), np.cos(t1 - t3), np.sin(t1 - t2), np.sin(t1 - t3)
    M = np.array([[(1.25 * M_LEG + M_H + M_T) * R**2, -0.5 * M_LEG * R**2 * c12, M_T * R * L * c13],
                  [-0.5 * M_LEG * R**2 * c12, 0.25 * M_LEG * R**2, 0.0],
                  [M_T * R * L * c13, 0.0, M_T * L**2]])
    C = np.array([[0.0, -0.5 * M_LEG * R**2 * s12 * dtheta[1], M_T * R * L * s13 * dtheta[2]],
                  [0.5 * M_LEG * R**2 * s12 * dtheta[0], 0.0, 0.0],
                  [-M_T * R * L * s13 * dtheta[0], 0.0, 0.0]])
    g = np.array([-0.5 * G * (2 * M_H + 3 * M_LEG + 2 * M_T) * R * np.sin(t1),
                  0.5 * G * M_LEG * R * np.sin(t2),
                  -G * M_T * L * np.sin(t3)])
    return M, C @ dtheta, g


def test_pinocchio_matches_corrected_appendix_b(rng):
    robot = load_robot("three_link_biped")
    robot.set_gravity(G)
    model, data = robot.model, robot.model.createData()
    for _ in range(200):
        q, v = rng.uniform(-1.2, 1.2, 3), rng.normal(0, 3, 3)
        M_abs, c_abs, g_abs = closed_form(T @ q, T @ v)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        g = pin.computeGeneralizedGravity(model, data, q)
        c = pin.rnea(model, data, q, v, np.zeros(3)) - g
        # Generalized forces transform with T^T (constant T): M_pin = T^T M_abs T, etc.
        np.testing.assert_allclose(M, T.T @ M_abs @ T, atol=1e-9, rtol=0)
        np.testing.assert_allclose(c, T.T @ c_abs, atol=1e-9, rtol=0)
        np.testing.assert_allclose(g, T.T @ g_abs, atol=1e-9, rtol=0)


def test_thesis_printed_forms_are_wrong_where_the_errata_say(rng):
    robot = load_robot("three_link_biped")
    robot.set_gravity(G)
    model, data = robot.model, robot.model.createData()
    q = np.array([0.1, -0.3, 0.6])
    g = pin.computeGeneralizedGravity(model, data, q)
    printed = np.array([0.0, 0.0, 0.5 * G * M_T * L * np.sin((T @ q)[2])])
    assert abs((np.linalg.solve(T.T, g))[2] - printed[2]) > 1.0


@pytest.fixture(scope="module")
def biped():
    return load_experiment(CONFIGS / "biped_torso.yaml")


def test_absolute_relative_conversion_is_the_appendix_map(biped):
    W = biped.hybrid.walker
    np.testing.assert_allclose(W.A, T)
    q = np.array([0.1, -0.25, 0.4])
    np.testing.assert_allclose(W.relative(W.absolute(q)), q)
    # Relabelling exchanges the legs' absolute angles and keeps the torso's: X+ = [q2, q1, q3].
    th = W.absolute(q)
    q_plus, _ = W.apply_impact(q, np.zeros(3))
    np.testing.assert_allclose(W.absolute(q_plus), th[[1, 0, 2]])


def test_rigid_impact_is_inelastic_and_conserves_momentum_about_the_new_foot(biped, rng):
    W = biped.hybrid.walker
    model, data = W.free_model, W.free_model.createData()
    W.impact = "rigid"
    try:
        for _ in range(5):
            th1 = rng.uniform(0.1, 0.3)
            q = W.relative(np.array([th1, -th1, rng.uniform(0.3, 0.7)]))  # both feet down
            v = rng.normal(0, 1.0, 3)
            foot = np.array([2 * R * np.sin(th1), 0.0, 0.0])

            def momentum_about_foot(qq, vv, p):
                qe, ve = np.r_[0.0, 0.0, qq], np.r_[0.0, 0.0, vv]
                h = pin.computeCentroidalMomentum(model, data, qe, ve)
                com = pin.centerOfMass(model, data, qe)
                return h.angular + np.cross(com - p, h.linear), 0.5 * ve @ pin.crba(model, data, qe) @ ve

            L_before, E_before = momentum_about_foot(q, v, foot)
            # The post-impact state in the NEW labels has its stance foot at the origin; map it
            # back to absolute angular velocities to compare in the same (old) frame.
            q_plus, v_plus = W.apply_impact(q, v)
            th_dot_new = W.absolute(v_plus)
            th_dot_old = th_dot_new[[1, 0, 2]]
            v_old = W.relative(th_dot_old)
            qe, ve = np.r_[0.0, 0.0, q], np.r_[0.0, 0.0, v_old]
            # The old-labelled model's base must move so that the swing foot is at rest.
            pin.computeJointJacobians(model, data, qe)
            pin.updateFramePlacements(model, data)
            J = pin.getFrameJacobian(model, data, W.foot_frame,
                                     pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[[0, 2]]
            base = -np.linalg.solve(J[:, :2], J[:, 2:] @ v_old)
            ve = np.r_[base, v_old]
            h = pin.computeCentroidalMomentum(model, data, qe, ve)
            com = pin.centerOfMass(model, data, qe)
            L_after = h.angular + np.cross(com - foot, h.linear)
            E_after = 0.5 * ve @ pin.crba(model, data, qe) @ ve
            np.testing.assert_allclose(L_after, L_before, atol=1e-9)
            assert E_after <= E_before + 1e-9
    finally:
        W.impact = "relabel"


@pytest.mark.parametrize("B", [
    [[0.0, 0.0], [0.0, -1.0], [1.0, 1.0]],   # the shipped walker's hip motors (pivot free)
    [[0.3], [1.0], [-0.5]],                  # one motor: two free directions
    [[1.0, 0.2, 0.0], [0.0, 1.0, 0.0], [0.5, 0.0, 1.0]],  # a motor for every direction
])
def test_inertia_weighted_allocation_is_the_formula_with_the_inverse_mass_matrix(B, rng):
    """B u = B (B^T M^-1 B)^-1 B^T M^-1 tau, written here with Pinocchio's M^-1 and numpy's
    solve, against the allocation's null-space form (CRBA, the unactuated directions)."""
    robot = load_robot("three_link_biped")
    B = np.array(B)
    alloc = Allocation(B, "inertia_weighted", robot.model)
    data = robot.model.createData()
    for _ in range(20):
        q, tau = rng.uniform(-1.0, 1.0, 3), rng.normal(0.0, 50.0, 3)
        Mi = pin.computeMinverse(robot.model, data, q)
        Mi = np.triu(Mi) + np.triu(Mi, 1).T
        u = np.linalg.solve(B.T @ Mi @ B, B.T @ Mi @ tau)
        np.testing.assert_allclose(alloc.joint_torque(q, tau), B @ u, rtol=0, atol=1e-11)


def test_a_pinned_walker_with_a_frame_angle_target_runs_across_its_impacts():
    """A nonlinear (frame-angle) law on the pinned walker takes the loop's general path: each
    stance label has its own rows (a shared iterator once left the second label's empty and
    the first impact raised IndexError); its rows equal the compiled engine's."""
    over = ["walking.poincare=false",
            "joints.torso_hip.target={frame: torso, vector: [0, 0, 1], about: [0, 1, 0], "
            "value: 0.5235987755982988}"]
    ref = run_seed(load_experiment(CONFIGS / "biped_torso.yaml", ["backend=pinocchio", *over]),
                   0, 2)
    comp = run_seed(load_experiment(CONFIGS / "biped_torso.yaml", ["backend=compiled", *over]),
                    0, 2)
    assert len(ref.rows) == 2 and ref.summary["guard_impacts"] + ref.summary["clock_impacts"] == 4
    for key in ref.rows[0]:
        np.testing.assert_allclose([r[key] for r in comp.rows], [r[key] for r in ref.rows],
                                   rtol=1e-8, atol=1e-12, err_msg=key)


def test_a_fall_stops_the_seed_as_diverged():
    exp = load_experiment(CONFIGS / "biped_torso.yaml",
                          ["walking.fall.max_abs=0.05", "sim.cycles=3"])
    result = run_seed(exp, 0, 3)
    assert result.summary["diverged"] is True
    assert "fell" in result.summary["diverged_reason"]


WALK_SEEDS = range(5)  # every claim below holds on each (20 cycles: ratio 0.19-0.27)


@pytest.fixture(scope="module")
def walked():
    """Seeds 0-4 learning the torso for 20 cycles while walking, with the Poincaré analysis."""
    exp = load_experiment(CONFIGS / "biped_torso.yaml")
    return exp, [run_seed(exp, seed, 20) for seed in WALK_SEEDS]


def test_the_biped_walks_and_fel_reduces_the_summed_feedback(walked):
    from feltool.runs.observers import stabilization_errors

    exp, results = walked
    for result in results:
        s = result.summary
        assert s["diverged"] is False and s["cycles"] == 20, s["seed"]
        assert s["fb_ratio"] <= 0.4, s  # full run: <= 0.16 after 150 cycles (docs/biped.md)
        # The system torso stays within 0.01 rad of pi/6 over the last cycle.
        assert stabilization_errors(exp, result.traces)["torso_hip_system"] < 0.01, s["seed"]
        # Every impact came at the nominal step time (2 per cycle).
        assert s["guard_impacts"] + s["clock_impacts"] == 40, s["seed"]
        # What a walking researcher looks for (the terminal's walker lines): it walked, 40
        # steps, the last cycle's step length and speed from its impacts, the torso's RMS
        # error, and each learned joint's own feedback
        w = s["walking"]
        assert w["walked"] and w["steps"] == 40 and w["not_walking"] is None
        last = result.rows[-1]
        assert w["stabilized_rms_last_rad"] < 0.01
        assert 0.8 * 2 * np.sin(np.pi / 18) < w["step_length_m"] < 1.1 * 2 * np.sin(np.pi / 18)
        assert w["speed_m_per_s"] == pytest.approx(2 * w["step_length_m"])
        for joint in exp.learned_joints:
            fb = s["learned_feedback"][joint]
            assert fb["first"] == result.rows[0][f"fb_abs_mean_{joint}"]
            assert fb["last"] == last[f"fb_abs_mean_{joint}"] < fb["first"]


def test_poincare_map_has_a_stable_fixed_point(walked):
    for result in walked[1]:
        p = result.summary["poincare"]
        assert p["fixed_point_found"] and p["fixed_point_residual"] < 1e-8, result.seed
        assert p["stable"] and max(p["eigenvalues_abs"]) < 1.0, result.seed
        assert p["impacts_per_cycle"] == 2
        # Two steps of about 2 r sin(pi/18) each (legs at about +-pi/18 at the impacts).
        assert 0.8 * 4 * np.sin(np.pi / 18) < p["stride_length_m"] < 1.1 * 4 * np.sin(np.pi / 18)
        assert p["speed_m_per_s"] == pytest.approx(p["stride_length_m"] / 1.0)


def test_poincare_spectral_radius_matches_the_decay_of_a_perturbation(walked):
    """An independent reading of the step-to-step map's spectral radius: perturb the fixed point
    (seeded direction, 1e-4) and iterate the walker itself for 20 cycles; the deviation shrinks
    by the dominant |eigenvalue| per cycle once the faster modes have died out. This uses no
    Jacobian and no eigen-solver, so it checks the finite-difference Jacobian and its spectrum."""
    exp, results = walked
    rng = np.random.default_rng(2012)
    for result in results:
        theta = exp.initial_parameters(result.seed)
        for name in exp.learned_joints:
            sl = exp.primitives.slices[exp.joints.index(name)]
            theta[sl.start:sl.stop - 1] = result.params[f"{name}.weights"]
            theta[sl.stop - 1] = result.params[f"{name}.goal"]
        P, Pv, Pa = exp.primitives.desired(theta)
        p = result.summary["poincare"]
        fixed = np.array(p["fixed_point_q"] + p["fixed_point_v"])
        nv = len(fixed) // 2
        d = rng.standard_normal(len(fixed))
        x = fixed + 1e-4 * d / np.linalg.norm(d)
        norms = []
        for _ in range(20):
            log = exp.hybrid.run_cycle(exp.dynamics, x[:nv], x[nv:], P, Pv, Pa)
            x = np.concatenate([log.q_end, log.v_end])
            norms.append(np.linalg.norm(x - fixed))
        decay = np.exp(np.polyfit(np.arange(7, 21), np.log(norms[6:]), 1)[0])
        assert decay == pytest.approx(p["spectral_radius"], rel=0.01), result.seed


def test_biped_slope_event_feedback_rises_then_returns():
    exp = load_experiment(CONFIGS / "biped_torso.yaml",
                          ["walking.poincare=false",
                           "events=[{cycle: 30, kind: slope, angle: 0.05}]"])
    result = run_seed(exp, 0, 60)
    assert result.summary["diverged"] is False
    fb = np.array([r["fb_abs_mean_error"] for r in result.rows])
    before = fb[28]  # cycle 29, the last before the 2.9 degree downhill slope
    assert fb[29] > 1.2 * before and fb[29:].max() > 1.8 * before  # the feedback rises
    assert fb[-1] <= 2.0 * before and fb[-1] < 0.8 * fb[29:].max()  # and FEL brings it down


def test_compiled_backend_runs_the_walker_and_events_with_the_python_numbers():
    """The pinned walker (guards, relabelling, allocation, falls) and a world event run on the
    compiled engine (they were refused before) and give the Python engine's metrics."""
    cases = ((CONFIGS / "biped_torso.yaml", []),
             (CONFIGS / "two_link_standard.yaml",
              ["events=[{cycle: 3, kind: payload, frame: tip, mass: 0.2}]"]))
    for path, over in cases:
        comp = load_experiment(path, ["backend=compiled", *over])
        assert comp.engine == "compiled"
        ref = run_seed(load_experiment(path, ["backend=pinocchio", *over]), 0, 4)
        got = run_seed(comp, 0, 4)
        for key in ref.rows[0]:
            np.testing.assert_allclose([r[key] for r in got.rows], [r[key] for r in ref.rows],
                                       rtol=1e-8, atol=1e-12, err_msg=key)


def _rigid_walk(placement: bool, cycles: int):
    """Cycles walked with impact: rigid, the torso RMP held at 0.15 rad (no learning)."""
    ov = ["walking.impact=rigid", "joints.torso_hip.target.value=0.15"]
    if placement:
        ov += ["walking.foot_placement.angle_of=swing_hip",
               "walking.foot_placement.follow=stance_ankle", "walking.foot_placement.gain=-0.6"]
    exp = load_experiment(CONFIGS / "biped_torso.yaml", ov)
    prims = exp.primitives
    theta = exp.theta_demo.copy()
    torso = prims.slices[2]
    theta[torso], theta[torso.stop - 1] = 0.0, 0.15
    P, Pv, Pa = prims.desired(theta)
    q, v = exp.hybrid.initial_state(P, Pv)
    for c in range(cycles):
        log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
        if log.fall:
            return c
        q, v = log.q_end, log.v_end
    return cycles


def test_foot_placement_lets_the_rigid_impact_walker_walk():
    """docs/biped.md: with rigid impacts the timed gait falls within a few cycles; offsetting the
    swing leg's reference by -0.6 x the stance leg's tracking error keeps it walking."""
    assert _rigid_walk(False, 10) < 5
    assert _rigid_walk(True, 40) == 40


def test_foot_placement_names_must_be_walking_angles():
    from feltool.errors import ConfigError
    with pytest.raises(ConfigError, match="foot_placement.follow"):
        load_experiment(CONFIGS / "biped_torso.yaml",
                        ["walking.foot_placement.angle_of=swing_hip",
                         "walking.foot_placement.follow=nope", "walking.foot_placement.gain=-1"])


def test_rigid_impact_walker_learns_with_an_impact_window():
    """configs/biped_torso_rigid.yaml, its documented run: every one of its seeds 0-2 walks 100
    cycles with rigid impacts and FEL reduces the summed feedback (0.73, 0.59, 0.56 of the first
    cycle, docs/biped.md; at 40 cycles seed 0 is still at 1.01, so the full length is run); the
    Poincaré analysis reports the eigenvalues (seed 1)."""
    exp = load_experiment(CONFIGS / "biped_torso_rigid.yaml", ["walking.poincare=false"])
    for seed in range(3):
        s = run_seed(exp, seed, 100).summary
        assert s["diverged"] is False and s["cycles"] == 100, seed
        assert s["fb_ratio"] <= 0.8, (seed, s["fb_ratio"])
    exp = load_experiment(CONFIGS / "biped_torso_rigid.yaml")
    s = run_seed(exp, 1, 5).summary
    assert len(s["poincare"]["eigenvalues_abs"]) == 6


def test_impact_window_masks_the_learning_signal_and_is_only_for_walkers():
    from types import SimpleNamespace

    from feltool.engines.python import impact_masked
    from feltool.errors import ConfigError
    exp = load_experiment(CONFIGS / "biped_torso_rigid.yaml")
    E = np.ones((200, 3))
    out = impact_masked(exp, SimpleNamespace(u_err=E, impacts=[(100, True, 0.3),
                                                                (200, True, 0.6)]))
    zero = np.flatnonzero(~out.any(axis=1))
    assert list(zero) == list(range(0, 10)) + list(range(100, 110))
    assert E.all()  # the log itself is untouched
    with pytest.raises(ConfigError, match="impact_window_s"):
        load_experiment(CONFIGS / "two_link_standard.yaml", ["learning.impact_window_s=0.05"])


def test_terminal_summary_of_a_walker(tmp_path, capsys):
    """`feltool run` of the pinned walker prints the walker's numbers and each learned joint's
    own feedback, not the arm's 'converged' line (a walker's summed feedback has a floor)."""
    from feltool.cli.main import main

    code = main(["run", str(CONFIGS / "biped_torso.yaml"), "--seeds", "0", "--cycles", "3",
                 "--out", str(tmp_path / "run"), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    assert "seed 0 walked: 6 steps, step 0." in out and "Poincare rho" in out
    assert "learned, own feedback first -> last cycle: torso_hip" in out
    assert "walked without falling: 1/1 seeds" in out
    assert "converged (below 5 %" not in out


def test_rate_scale_scales_one_joints_rates():
    exp = load_experiment(CONFIGS / "biped_torso.yaml",
                          ["joints.swing_hip.learn={init: demo, rate_scale: 0.02}"])
    from feltool.learning.rates import basis_gain, per_sample_rates, samples_per_cycle

    rates = dict(zip(exp.learner.learned, exp.learner.rates))
    L, cfg = exp.config.learning.rates, exp.config
    for name, scale in (("swing_hip", 0.02), ("torso_hip", 1.0)):
        i = exp.joints.index(name)
        sl, prim = exp.primitives.slices[i], exp.primitives.primitives[i]
        w, g = per_sample_rates(L.weights, L.goal, samples_per_cycle(cfg.period_s, cfg.sim.rate_hz),
                                basis_gain(prim.n_basis, prim.width, prim.amplitude))
        assert [rates[p] for p in range(sl.start, sl.stop)] == pytest.approx(
            [scale * w] * (sl.stop - sl.start - 1) + [scale * g])
