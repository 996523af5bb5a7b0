"""ILC and the baseline on the physical five-link walker (short runs): the learned torque per
RMP sample and motor learns, cycles of different lengths update the same sequence, and the
lifted model of the walker's cycle agrees with differences of the loop itself."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from feltool.engines.ilc_walker import lifted_model, motor_error, orbit_cycle, phase_error
from feltool.errors import ConfigError
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS

FIVE_LINK = CONFIGS / "gaits" / "five_link_walker.yaml"
QUIET = ["walking.poincare=false"]


# learner, cycles, bound on last/first error feedback on seeds 0 and 1 (measured at 8 cycles:
# ilc_p 0.018, 0.021; ilc_norm_optimal 0.0021, 0.0041; feedback_only stays at 1.1 of it)
@pytest.mark.parametrize("update, cycles, bound", [("ilc_p", 8, 0.05),
                                                    ("ilc_norm_optimal", 8, 0.05)])
def test_ilc_learns_on_the_physical_walker(update, cycles, bound):
    exp = load_experiment(FIVE_LINK, QUIET + [f"learning.update={update}"])
    for seed in (0, 1):
        res = run_seed(exp, seed, cycles=cycles)
        assert res.summary["walking"]["walked"], res.summary.get("diverged_reason")
        fb = [r["fb_abs_mean_error"] for r in res.rows]
        assert fb[-1] / fb[0] < bound, fb
        # the learned sequence: one torque per RMP sample and motor, nothing in the RMP
        dU = np.stack([res.params[f"ilc.{m}.u_ff_correction"] for m in
                       exp.hybrid.walker.motor_names], axis=1)
        assert dU.shape == (exp.primitives.n_steps, 4) and np.abs(dU).max() > 1.0
        np.testing.assert_array_equal(res.params["base_pitch.weights_history"][-1],
                                      res.params["base_pitch.weights_history"][0])


def test_feedback_only_walks_without_learning():
    exp = load_experiment(FIVE_LINK, QUIET + ["learning.update=feedback_only"])
    res = run_seed(exp, 0, cycles=3)
    fb = [r["fb_abs_mean_error"] for r in res.rows]
    assert res.summary["walking"]["walked"] and fb[-1] / fb[0] > 0.9
    assert not any(k.startswith("ilc.") for k in res.params)


def test_cycles_of_different_lengths_share_the_sequence_by_rmp_sample():
    """A perturbed cycle is shorter than the orbit's and skips and repeats RMP samples: its
    error reaches the sequence by sample, each sample's error the mean of its control steps'."""
    exp = load_experiment(FIVE_LINK, QUIET)
    P, Pv, Pa = exp.primitives.desired(exp.initial_parameters(0))
    q, v = exp.hybrid.initial_state(P, Pv)
    log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
    n = exp.primitives.n_steps
    assert len(log.q) < n  # 447 control steps for 500 samples
    E, Es = motor_error(exp, log), phase_error(exp, log)
    for i in (0, 100, 240, 300, n - 1):
        used = np.flatnonzero(log.phase_index == i)
        expected = E[used].mean(axis=0) if len(used) else np.zeros(4)
        np.testing.assert_allclose(Es[i], expected, atol=1e-12)
    assert (np.bincount(log.phase_index, minlength=n) == 0).any()  # samples no step used
    assert (np.bincount(log.phase_index, minlength=n) > 1).any()  # and samples used twice


def test_the_linearized_step_is_the_loops_own_step():
    """OrbitStep, the control step the lifted model differentiates, reproduces PhysicalLoop's
    cycle step by step: on the orbit, and on a perturbed cycle whose touchdowns come early and
    whose hip saturates at its 150 N m once (seed 0)."""
    from feltool.engines.ilc_walker import OrbitStep, orbit_steps

    exp = load_experiment(FIVE_LINK, QUIET)
    for theta in (exp.theta_demo, exp.initial_parameters(0)):
        P, Pv, Pa = exp.primitives.desired(theta)
        q, v = exp.hybrid.initial_state(P, Pv)
        log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
        step, E = OrbitStep(exp, P, Pv, Pa, q), motor_error(exp, log)
        x = step.chart(log.q[0], log.v[0], 0.0)
        for k, args in orbit_steps(log):
            x, e, _ = step(x, np.zeros(4), *args)
            np.testing.assert_allclose(e, E[k], atol=1e-6)
            if k + 1 < len(log.q):
                np.testing.assert_allclose(x[:-1], step.chart(log.q[k + 1], log.v[k + 1], 0)[:-1],
                                           atol=1e-8)
    assert len(log.q) < exp.primitives.n_steps and log.torque_hits.sum() >= 1


def test_lifted_model_of_the_walker_agrees_with_differences_of_the_loop():
    """Columns of the lifted model against whole cycles of the loop itself (PhysicalLoop with a
    perturbed per-sample motor torque) from the orbit's start; the feedthrough of a sample's
    torque onto its own error is -I in closed form: the allocation A = (B'WB)^-1 B'W and the
    constrained accelerations' response W B give A M W B = I (W M W = W)."""
    exp = load_experiment(FIVE_LINK, QUIET + ["learning.update=ilc_norm_optimal"])
    G = lifted_model(exp)
    n, m = exp.primitives.n_steps, 4
    assert G.shape == (n * m, n * m)
    blocks = np.array([G[i * m:(i + 1) * m, i * m:(i + 1) * m] for i in range(n)])
    np.testing.assert_allclose(blocks, np.broadcast_to(-np.eye(m), blocks.shape), atol=1e-5)
    assert np.allclose(np.triu(G, m), 0.0)  # causal: no torque acts on an earlier sample
    orbit, _ = orbit_cycle(exp)
    P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
    q, v = orbit.q[0], orbit.v[0]
    loop = copy.copy(exp.hybrid)

    def error(dU):
        loop.motor_feedforward = dU
        return phase_error(exp, loop.run_cycle(exp.dynamics, q, v, P, Pv, Pa)).reshape(-1)

    e0 = error(np.zeros((n, m)))
    for i, a in ((10, 0), (120, 1), (250, 2), (400, 3)):
        dU = np.zeros((n, m))
        dU[i, a] = 1e-3
        column = (error(dU) - e0) / 1e-3
        g = G[:, i * m + a]
        assert np.linalg.norm(column - g) < 5e-3 * np.linalg.norm(g)
        # the dynamic part, the torque's effect on later samples (~1 % of the feedthrough):
        # its direction and size (measured: cosine 0.90-0.9999, relative error 0.01-0.43; the
        # largest at the cycle's last sample, where the mechanical phase's linear interpolation
        # of the reference has a kink on the orbit: G takes the mean of its one-sided slopes)
        c, gl = column[(i + 1) * m:], g[(i + 1) * m:]
        assert np.abs(c).max() > 1e-4
        assert c @ gl > 0.85 * np.linalg.norm(c) * np.linalg.norm(gl)
        assert np.linalg.norm(c - gl) < 0.6 * np.linalg.norm(gl)


def test_ilc_and_disturbances_still_refuse_the_pinned_walker():
    for sets in (["learning.update=ilc_p"], ["disturbances.torque_noise=0.1"]):
        with pytest.raises(ConfigError) as err:
            load_experiment(CONFIGS / "biped_torso.yaml", sets)
        assert "pinned walker" in str(err.value)


def test_walker_resume_continues_the_sequence_and_the_noise_bit_identically(tmp_path):
    from feltool.runs.checkpoint import Checkpointer

    exp = load_experiment(FIVE_LINK, QUIET + ["learning.update=ilc_p",
                                              "disturbances.measurement_noise.v=0.001",
                                              "disturbances.input_delay_steps=1"])
    whole = run_seed(exp, 2, cycles=4)
    ck = Checkpointer(tmp_path, 2, every=2)
    run_seed(exp, 2, cycles=2, checkpoint=ck)
    resumed = run_seed(exp, 2, cycles=4, checkpoint=ck)
    assert [r["fb_abs_mean_error"] for r in resumed.rows] == \
        [r["fb_abs_mean_error"] for r in whole.rows]
    for key, value in whole.params.items():
        np.testing.assert_array_equal(resumed.params[key], value)


def test_robustness_on_a_walker_uses_its_ranges_and_has_no_period(tmp_path):
    import json

    from .conftest import feltool

    out = tmp_path / "rob"
    res = feltool("robustness", str(FIVE_LINK), "--learners", "ilc_p", "--scenarios",
                  "mass,period", "--range", "mass=1", "--seeds", "0", "--cycles", "10",
                  "--out", str(out), "-q")
    assert res.returncode == 0, res.stderr
    result = json.loads((out / "robustness.json").read_text())
    assert result["scores"]["ilc_p"]["period"] is None
    assert "steps end at touchdown" in result["scenarios"]["period"]["not_applicable"]
    # undisturbed, P-type ILC reaches the goal within 10 cycles (tail ratio measured 0.020)
    assert result["scores"]["ilc_p"]["mass"] == 1.0
    assert result["points"][0]["seeds"][0]["fb_ratio_tail"] < 0.05
    assert "| ilc_p |" in res.stdout and "| n/a |" in res.stdout
