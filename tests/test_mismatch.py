"""Plant vs model and classic FEL of an inverse-model correction (issue 8): the regressor equals
RNEA, plant = model changes nothing, and a 30 % heavier link 2 is learned from the feedback."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.errors import ConfigError
from feltool.learning.model import (
    PhaseBasisFeatures,
    RegressorFeatures,
    identifiability,
    inertial_parameters,
)
from feltool.robot.robot import load_robot
from feltool.runs.checkpoint import Checkpointer, Interrupted, request_stop, reset_stop
from feltool.runs.experiments import load_experiment
from feltool.runs.rundir import write_metrics
from feltool.runs.seed import run_seed

from .conftest import CONFIGS, ROOT

MISMATCH = CONFIGS / "two_link_standard_mismatch.yaml"
MODEL_ONLY = ["joints.elbow.learn=null",            # variant (ii): the elbow follows its exact
              "learning.model.error=all_feedback"]  # demo; Kawato: all feedback is the error


@pytest.mark.parametrize("robot", ["two_link_arm", "two_link_human_arm"])
def test_regressor_times_inertial_parameters_is_rnea(robot, rng):
    """Y(q, v, a) pi == RNEA(q, v, a) with the model's own inertial parameters pi."""
    model = load_robot(robot).model
    data = model.createData()
    feats = RegressorFeatures(model)
    Q, V, A = (rng.normal(size=(25, model.nv)) for _ in range(3))
    Y = feats.features(Q, V, A)
    assert Y.shape == (25, model.nv, 10 * (model.njoints - 1))
    expected = np.array([pin.rnea(model, data, Q[k], V[k], A[k]) for k in range(25)])
    np.testing.assert_allclose(Y @ inertial_parameters(model), expected, rtol=1e-12, atol=1e-10)


def _goldens() -> dict:
    import json

    return json.loads((ROOT / "tests" / "data" / "goldens.json").read_text())


@pytest.mark.parametrize("backend", ["pinocchio", "compiled"])
@pytest.mark.parametrize("name", ["two_link_standard", "two_link_human_arm"])
def test_existing_configs_give_the_golden_metrics(name, backend, tmp_path):
    """With no plant block and with an explicit `plant: {}` (a separate copy of the model) the
    metrics are byte-identical, and they equal the golden metrics.csv (seeds 0-1, 6 cycles)
    written by scripts/make_goldens.py (its docstring says where the numbers come from; the
    goldens are regenerated only by it, for an intended change), on both engines. The
    comparison allows 1e-9 relative: refactors so far moved the last bits (< 1e-11); a real
    change of the method moves the metrics by 1e-4 or more (scripts/mutation_check.py)."""
    import csv
    import hashlib
    import io

    record = _goldens()
    fname = f"metrics_{name}.seeds0-1.cycles6.csv"
    meta = record["files"][fname]
    assert record["generated_by"] == "scripts/make_goldens.py"
    # A changed config needs new goldens on purpose (the script), not a silently relaxed test.
    assert meta["config_sha256"] == hashlib.sha256(
        (ROOT / meta["config"]).read_bytes()).hexdigest(), "re-run scripts/make_goldens.py"
    golden = list(csv.DictReader(io.StringIO((ROOT / "tests" / "data" / fname).read_text())))
    texts = []
    for overrides in ([], ["plant={}"]):
        exp = load_experiment(CONFIGS / f"{name}.yaml", [*overrides, f"backend={backend}"])
        assert (exp.plant is exp.dynamics) == (not overrides)
        rows = [row for seed in meta["seeds"] for row in run_seed(exp, seed, meta["cycles"]).rows]
        write_metrics(tmp_path / "metrics.csv", rows)
        texts.append((tmp_path / "metrics.csv").read_text())
        assert len(rows) == len(golden)
        for row, ref in zip(rows, golden):
            assert row.keys() == ref.keys()
            for key, value in row.items():
                assert value == pytest.approx(float(ref[key]), rel=1e-9, abs=1e-12), key
    assert texts[0] == texts[1]


def test_plant_overrides_change_only_the_plant():
    exp = load_experiment(MISMATCH)
    m, p = exp.dynamics.model, exp.plant.model
    assert m.inertias[2].mass == pytest.approx(1.0) and p.inertias[2].mass == pytest.approx(1.3)
    np.testing.assert_allclose(p.inertias[2].inertia, 1.3 * m.inertias[2].inertia)
    np.testing.assert_allclose(p.inertias[2].lever, m.inertias[2].lever)
    assert p.inertias[1] == m.inertias[1]
    # A payload at the tip adds its mass to link 2 and moves link 2's centre of mass outwards.
    pay = load_experiment(MISMATCH, ["plant.bodies={}",
                                     "plant.payloads=[{frame: tip, mass: 0.3}]"]).plant.model
    assert pay.inertias[2].mass == pytest.approx(1.3)
    assert pay.inertias[2].lever[0] == pytest.approx((0.5 + 0.3 * 1.0) / 1.3)


def test_friction_opposes_motion():
    exp = load_experiment(MISMATCH, ["plant.friction={elbow: {viscous: 0.5, coulomb: 0.2}}"])
    q, v, a = np.array([1.0, 0.2]), np.array([0.3, -2.0]), np.zeros(2)
    rigid = exp.plant.rigid.inverse(q, v, a)
    np.testing.assert_allclose(exp.plant.inverse(q, v, a) - rigid,
                               [0.0, 0.5 * -2.0 - 0.2 * np.tanh(200.0)])
    np.testing.assert_allclose(exp.plant.forward(q, v, exp.plant.inverse(q, v, a)), a, atol=1e-9)


def test_plant_and_model_errors_name_the_yaml_path():
    with pytest.raises(ConfigError) as err:
        load_experiment(MISMATCH, ["plant.bodies={wrist: {mass: 2}}",
                                   "plant.payloads=[{frame: nowhere, mass: 1}]"])
    text = str(err.value)
    assert "plant.bodies.wrist" in text and "plant.payloads.0.frame" in text
    with pytest.raises(ConfigError, match="learning.model.rate"):
        load_experiment(MISMATCH, ["learning.model={features: regressor}"])
    with pytest.raises(ConfigError, match="learning.model"):
        load_experiment(MISMATCH, ["learning.step=per_step", "learning.update=gradient"])


def test_identifiable_combinations_of_the_planar_arm():
    """One periodic motion of the planar arm identifies 5 of the 20 inertial parameters'
    combinations; the heavier link 2 is not fully identifiable, its torques are."""
    exp = load_experiment(MISMATCH, MODEL_ONLY)
    Qd, Vd, Ad = exp.primitives.desired(exp.theta_demo)
    Y = exp.model_learner.features.features(Qd, Vd, Ad)
    ident = identifiability(Y)
    assert ident.rank == 5
    d_pi = inertial_parameters(exp.plant.model) - inertial_parameters(exp.dynamics.model)
    # the part of the true correction the motion cannot see does not change the torques
    unseen = d_pi - ident.projector @ d_pi
    assert np.linalg.norm(unseen) > 0.1
    np.testing.assert_allclose(Y @ unseen, 0.0, atol=1e-9)


def test_model_fel_learns_a_heavier_link_2():
    """Acceptance: model FEL with regressor features takes the total mean |feedback| below 5 %
    of its first cycle, and the learned torques match the plant's RNEA to 5 % RMS. This variant
    draws nothing at random (the elbow follows its demo): every seed is the same run, so one
    seed covers them all (checked: seeds 0 and 1 start from the same parameters)."""
    exp = load_experiment(MISMATCH, MODEL_ONLY)
    np.testing.assert_array_equal(exp.initial_parameters(0), exp.initial_parameters(1))
    Qd, Vd, Ad = exp.primitives.desired(exp.theta_demo)
    Y = exp.model_learner.features.features(Qd, Vd, Ad)
    u_plant = exp.plant.inverse_batch(Qd, Vd, Ad)
    u_model = exp.dynamics.inverse_batch(Qd, Vd, Ad)
    for seed in (0,):
        res = run_seed(exp, seed, cycles=25)
        total = [r["fb_abs_mean_total"] for r in res.rows]
        assert not res.summary["diverged"]
        assert total[-1] < 0.05 * total[0], (seed, total[0], total[-1])
        u_learned = u_model + Y @ res.params["model.theta"]
        rms = np.sqrt(np.mean((u_learned - u_plant) ** 2, axis=0) / np.mean(u_plant ** 2, axis=0))
        assert rms.max() < 0.05, rms
        # and the unlearned model is far off: the mismatch is real
        rms0 = np.sqrt(np.mean((u_model - u_plant) ** 2, axis=0) / np.mean(u_plant ** 2, axis=0))
        assert rms0.min() > 0.15


def test_phase_basis_features_are_a_partition_of_unity():
    feats = PhaseBasisFeatures(100, 2, 12)
    Phi = feats.features(None, None, None)
    assert Phi.shape == (100, 2, 24)
    np.testing.assert_allclose(Phi.sum(axis=2), 1.0)
    assert feats.names[12] == "1.psi0"


def test_model_fel_with_phase_basis_also_learns():
    exp = load_experiment(MISMATCH, MODEL_ONLY + ["learning.model={features: phase_basis, "
                                                  "update: gauss_newton, rate: 0.5}"])
    res = run_seed(exp, 0, cycles=15)
    total = [r["fb_abs_mean_total"] for r in res.rows]
    assert total[-1] < 0.3 * total[0]  # slower than the regressor: the feedback lags the torque


def test_per_step_model_update_learns():
    exp = load_experiment(MISMATCH, MODEL_ONLY + ["learning.model.step=per_step",
                                                  "learning.model.rate=1e-3"])  # 1e-6 per sample
    res = run_seed(exp, 0, cycles=15)
    total = [r["fb_abs_mean_total"] for r in res.rows]
    assert total[-1] < 0.1 * total[0]


def test_resume_with_model_learning_is_bit_identical(tmp_path):
    """theta_m and its history are checkpointed: a stop after cycle 6 and a resume give the same
    rows and parameters as an uninterrupted run."""
    exp = load_experiment(MISMATCH)
    whole = run_seed(exp, 3, cycles=10)

    def stop_at_6(cycle, _):
        if cycle == 6:
            request_stop()

    ckpt = Checkpointer(tmp_path, 3, every=4)
    try:
        with pytest.raises(Interrupted):
            run_seed(exp, 3, cycles=10, progress=stop_at_6, checkpoint=ckpt)
    finally:
        reset_stop()
    assert ckpt.load()["cycle"] == 6 and "model_theta" in ckpt.load()
    resumed = run_seed(exp, 3, cycles=10, checkpoint=ckpt)
    assert resumed.rows == whole.rows
    assert resumed.params.keys() == whole.params.keys()
    for key in whole.params:
        np.testing.assert_array_equal(resumed.params[key], whole.params[key])


def test_compiled_backend_runs_plant_and_model_learning_with_the_python_numbers():
    """The plant block and classic FEL of the model run compiled (they were refused before):
    the same rows and the same learned correction as the Python engine."""
    ref = run_seed(load_experiment(MISMATCH, ["backend=pinocchio"]), 0, 2)
    comp = run_seed(load_experiment(MISMATCH, ["backend=compiled"]), 0, 2)
    for key in ref.rows[0]:
        np.testing.assert_allclose([r[key] for r in comp.rows], [r[key] for r in ref.rows],
                                   rtol=1e-8, atol=1e-12, err_msg=key)
    np.testing.assert_allclose(comp.params["model.theta"], ref.params["model.theta"],
                               rtol=1e-8, atol=1e-14)


def test_learned_dynamics_is_the_corrected_inverse_model(rng):
    """The trajectory learner's Jacobian through the learned model: RNEA with pi_model + theta_m
    equals RNEA_model + Y theta_m (so its derivatives are the chain rule through Phi theta_m)."""
    exp = load_experiment(MISMATCH)
    ml = exp.model_learner
    theta_m = 0.05 * rng.normal(size=ml.n_params)
    theta_m[0] = theta_m[10] = 0.1  # keep the masses positive
    Q, V, A = (rng.normal(size=(7, 2)) for _ in range(3))
    learned = ml.learned_dynamics(theta_m)
    expected = exp.dynamics.inverse_batch(Q, V, A) + ml.features.features(Q, V, A) @ theta_m
    np.testing.assert_allclose(learned.inverse_batch(Q, V, A), expected, rtol=1e-10, atol=1e-10)


#: Seeds of the acceptance tests below, fixed before looking (issue 14): the first ten.
ACCEPTANCE_SEEDS = range(10)


def test_trajectory_and_model_fel_beat_either_alone_on_every_seed():
    """Acceptance, seeds 0-9 (every one must pass), 150 cycles: the config as written (both
    learners) against the same config with one learner switched off.

    * vs trajectory FEL alone (``learning.model=null``, same seed): the stabilizing feedback (the
      trajectory learner's own error) ends below 0.6x, the total feedback below 0.15x. Measured
      at 150 cycles: 0.0116-0.0132 vs 0.0294-0.0299 N m (0.39-0.45x) and 0.28-0.37 vs 4.59 N m.
    * vs model FEL alone (``joints.elbow.learn=null``: the elbow's forward trajectory stays its
      demo, no random draw, so one run serves every seed): both below 0.15x. Measured: total
      4.59, stabilizing 2.05 N m (the model's error is the shoulder's feedback only).
    The three seeds that diverged before the correction was restricted to its error joints (13,
    15, 18 of 20) are covered by the 20-seed run in docs/model_learning.md; the test keeps to
    ten for CI time."""
    both = load_experiment(MISMATCH)
    # (like for like: with learning.model the trajectory's step fits the feedforward, so it
    # does alone; the closed-loop fit alone is its own comparison, docs/model_learning.md)
    alone = load_experiment(MISMATCH, ["learning.model=null", "learning.fit=feedforward"])
    model = load_experiment(MISMATCH, ["joints.elbow.learn=null"])
    np.testing.assert_array_equal(model.initial_parameters(0), model.initial_parameters(7))
    m = run_seed(model, 0, cycles=150).rows[-1]
    failures = []
    for seed in ACCEPTANCE_SEEDS:
        res = run_seed(both, seed, cycles=150)
        assert not res.summary["diverged"], res.summary
        assert res.summary["limits"] == {"joint_limit_steps": {}, "torque_limit_steps": {}}
        b = res.rows[-1]
        a = run_seed(alone, seed, cycles=150).rows[-1]
        ratios = (b["fb_abs_mean_stabilized"] / a["fb_abs_mean_stabilized"],
                  b["fb_abs_mean_total"] / a["fb_abs_mean_total"],
                  b["fb_abs_mean_stabilized"] / m["fb_abs_mean_stabilized"],
                  b["fb_abs_mean_total"] / m["fb_abs_mean_total"])
        if not (ratios[0] < 0.6 and ratios[1] < 0.15 and ratios[2] < 0.15 and ratios[3] < 0.15):
            failures.append((seed, [round(r, 3) for r in ratios]))
    assert not failures, failures
