"""One learning cycle, two engines: every shipped config runs on the compiled engine (backend
auto chooses it) and gives the Python engine's metrics to 1e-8, cycle by cycle."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS, feltool

ALL_SHIPPED = sorted(CONFIGS.glob("*.yaml")) + sorted((CONFIGS / "gaits").glob("*.yaml"))
#: configs whose plant is MuJoCo run on the Python engine by design (tests/test_mujoco.py)
MUJOCO = [p for p in ALL_SHIPPED if "simulator: mujoco" in p.read_text()]
SHIPPED = [p for p in ALL_SHIPPED if p not in MUJOCO]


def test_shipped_mujoco_configs_run_on_the_python_engine_with_the_reason():
    assert len(MUJOCO) == 2
    for path in MUJOCO:
        exp = load_experiment(path)
        assert exp.engine == "python", path.stem
        assert exp.engine_reason == "backend auto: plant.simulator: mujoco runs on the Python engine"


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _rows_equal(ref, comp, rtol=1e-8, atol=1e-12):
    assert len(comp.rows) == len(ref.rows)
    for key in ref.rows[0]:
        a = np.array([r[key] for r in ref.rows], dtype=float)
        b = np.array([r[key] for r in comp.rows], dtype=float)
        np.testing.assert_allclose(b, a, rtol=rtol, atol=atol, err_msg=key)


def test_backend_auto_compiles_every_shipped_config():
    """No shipped config is refused by the compiled engine: backend auto picks it for each."""
    from feltool.engines.compiled.library import c_compiler

    if c_compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: install gcc")
    for path in SHIPPED:
        exp = load_experiment(path)
        assert exp.engine == "compiled", (path.stem, exp.engine_reason)


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_every_shipped_config_runs_compiled_with_the_python_engines_metrics(path):
    """Three cycles of seed 0 on the compiled engine equal the Python engine's metrics.csv
    rows to 1e-8 (the walkers' contact metrics and touchdowns included; the Poincare
    analysis after the run, Python either way, is left out). A world's change (events:) comes
    at cycle 1 here, so that the three cycles are in the changed world: before it, a walker on
    its designed gait has a feedback of roundoff (1e-7 N m; the payload configs' change is at
    cycle 3), which the two engines' arithmetic gives alike only to 1e-11 N m absolute."""
    from feltool.engines.compiled.library import c_compiler

    if c_compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: install gcc")
    over = ["walking.poincare=false"] if "gaits" in path.parts else []
    events = load_experiment(path, over).config.events
    if any(ev.changes_world and ev.cycle > 1 for ev in events):
        moved = [ev.model_dump(exclude_none=True) | ({"cycle": 1} if ev.changes_world else {})
                 for ev in events]
        over.append(f"events={json.dumps(moved)}")
    ref = run_seed(load_experiment(path, ["backend=pinocchio", *over]), 0, 3)
    comp = run_seed(load_experiment(path, ["backend=compiled", *over]), 0, 3)
    assert ref.summary["diverged"] is False
    _rows_equal(ref, comp)
    assert comp.summary["limits"] == ref.summary["limits"]
    walk = ref.summary.get("walking")
    if walk is not None:
        assert comp.summary["walking"]["walked"] == walk["walked"]
        assert comp.summary["walking"]["steps"] == walk["steps"]


PERTURBED = "{init: perturbed, perturbation_rad: 0.02, goal_spread: 0}"


@pytest.mark.parametrize("over", [
    ["learning.update=gradient", "learning.rates.weights=11.659"],  # per sample 0.002
    [f"joints.left_hip.learn={PERTURBED}", f"joints.right_hip.learn={PERTURBED}"],
], ids=["gradient", "three_learned_joints"])
def test_physical_walker_updates_equal_the_python_engines(over):
    """The compiled walker's FEL sums (accumulated step by step with the sensitivity row of
    each step's sample) give the Python engine's updates: plain gradient, and Gauss-Newton
    with three learned joints (the cross blocks of its matrix), three cycles to 1e-8."""
    path = CONFIGS / "gaits" / "three_link_walker.yaml"
    over = ["walking.poincare=false", *over]
    ref = run_seed(load_experiment(path, ["backend=pinocchio", *over]), 0, 3)
    comp = run_seed(load_experiment(path, ["backend=compiled", *over]), 0, 3)
    assert ref.summary["diverged"] is False and len(ref.rows) == 3
    fb = [r["fb_abs_mean_error"] for r in ref.rows]
    assert fb[2] < 0.5 * fb[0]  # it learns: the updates are not zero
    _rows_equal(ref, comp)


def test_a_physical_walker_that_stops_gives_the_python_engines_reason():
    """A contact check that fails ends the cycle on the compiled engine too, with the Python
    engine's message and kind (the stopped cycle is rerun there)."""
    path = CONFIGS / "gaits" / "three_link_walker.yaml"
    over = ["walking.poincare=false", "walking.friction=0.3"]
    ref = run_seed(load_experiment(path, ["backend=pinocchio", *over]), 0, 2)
    comp = run_seed(load_experiment(path, ["backend=compiled", *over]), 0, 2)
    assert "the touchdown impulse ratio" in ref.summary["diverged_reason"]
    assert comp.summary["diverged_reason"] == ref.summary["diverged_reason"]
    assert comp.summary["walking"]["not_walking"] == "impulse"


def test_auto_says_which_engine_and_gives_the_same_metrics_csv_either_way(tmp_path):
    """The run says once which engine runs it; metrics.csv of backend auto (compiled) and of
    the Python engine agree to 1e-8 (two seeds, 12 cycles, through the CLI)."""
    std = str(CONFIGS / "two_link_standard.yaml")
    runs = {}
    for name, extra in (("auto", []), ("python", ["--set", "backend=pinocchio"])):
        res = feltool("run", std, "--seeds", "0-1", "--cycles", "12", "--out",
                      str(tmp_path / name), "--quiet", *extra)
        assert res.returncode == 0, res.stderr
        runs[name] = res
    assert runs["auto"].stdout.count("compiled engine (backend auto)") == 1
    assert runs["python"].stdout.count("python engine (backend: pinocchio)") == 1
    a, b = (list(csv.DictReader(open(tmp_path / n / "metrics.csv"))) for n in ("python", "auto"))
    assert len(a) == len(b) == 24
    for x, y in zip(a, b):
        for key in x:
            assert float(y[key]) == pytest.approx(float(x[key]), rel=1e-8, abs=1e-12), key


def test_auto_without_a_working_compiler_runs_the_python_engine_and_says_why(tmp_path,
                                                                           monkeypatch):
    monkeypatch.setenv("CC", "false")  # a "compiler" that always fails
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path / "empty-cache"))
    res = feltool("run", str(CONFIGS / "two_link_standard.yaml"), "--seeds", "0",
                  "--cycles", "3", "--out", str(tmp_path / "run"))
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("backend auto: compiling the cycle failed; running the Python "
                            "engine instead") == 1
    assert '"engine": "python"' in (tmp_path / "run" / "summary.json").read_text()


@pytest.mark.parametrize("overrides", [
    ["learning.step=per_step", "learning.update=gradient", "learning.rates.weights=0.67374",
     "learning.rates.goal=2e-5", "events=[{cycle: 3, period_s: 0.8}]"],
    ["period_s=1.2345", "events=[{cycle: 4, goal: {elbow: 0.2}}, "
                        "{cycle: 6, kind: payload, frame: tip, mass: 0.2}]"],
    ["learning.update=gauss_newton", "learning.rates.gauss_newton=1.0", "sim.joint_limits=enforce",
     "sim.torque_limits=saturate", "plant={friction: {shoulder: {viscous: 0.1, coulomb: 0.2, "
                                   "coulomb_velocity: 0.05}}}"],
], ids=["per_step_period_event", "odd_period_goal_and_payload", "gn_limits_friction"])
def test_the_compiled_engine_runs_the_features_no_shipped_config_uses(overrides):
    """Per-step learning, cycles of changing length, motion and world events, limits,
    friction and Gauss-Newton: the compiled engine's rows equal the Python engine's."""
    std = CONFIGS / "two_link_standard.yaml"
    ref = run_seed(load_experiment(std, ["backend=pinocchio", *overrides]), 0, 9)
    comp = run_seed(load_experiment(std, ["backend=compiled", *overrides]), 0, 9)
    assert not ref.summary["diverged"]
    _rows_equal(ref, comp)


def test_the_desired_motion_across_a_motion_event_is_the_python_engines():
    """The traces of the desired motion across an amplitude and goal event (the compiled
    engine computes them only when asked, after the motion has moved on) equal the Python
    engine's."""
    over = ["events=[{cycle: 3, amplitude: {elbow: 1.3}, goal: {shoulder: 1.4}}]"]
    std = CONFIGS / "two_link_standard.yaml"
    ref = run_seed(load_experiment(std, ["backend=pinocchio", *over]), 0, 5)
    comp = run_seed(load_experiment(std, ["backend=compiled", *over]), 0, 5)
    keys = [k for k in ref.traces if k.startswith("switch3_")]
    assert len(keys) == 3
    for key in keys:
        np.testing.assert_allclose(comp.traces[key], ref.traces[key], rtol=0, atol=1e-12)


def test_the_pinned_walkers_gauss_newton_update_is_the_python_engines():
    """The rigid-impact walker with Levenberg-Marquardt steps (impact window, allocation,
    foot placement): the compiled engine's rows equal the Python engine's."""
    cfg = CONFIGS / "biped_torso_rigid.yaml"
    over = ["learning.update=gauss_newton", "learning.rates.gauss_newton=0.5",
            "walking.poincare=false"]
    ref = run_seed(load_experiment(cfg, ["backend=pinocchio", *over]), 0, 4)
    comp = run_seed(load_experiment(cfg, ["backend=compiled", *over]), 0, 4)
    assert not ref.summary["diverged"]
    assert ref.rows[-1]["fb_abs_mean_error"] != ref.rows[0]["fb_abs_mean_error"]
    _rows_equal(ref, comp)


@pytest.mark.parametrize("overrides", [
    ["learning.model.update=gauss_newton", "learning.model.rate=0.5"],
    ["learning.model.features=phase_basis", "learning.model.basis=6",
     "learning.model.step=per_step", "learning.model.rate=0.016667"],  # 1e-4 per sample
    ["learning.model.error=[elbow]"],
], ids=["regressor_gn", "phase_basis_per_step", "learned_jacobian_rows"])
def test_compiled_model_learning_equals_the_python_engine(overrides):
    """Classic FEL of the model (regressor or phase-basis features, per cycle or per step,
    the learned model's Jacobian rows) on the mismatched plant: equal rows, equal
    parameters."""
    cfg = CONFIGS / "two_link_standard_mismatch.yaml"
    ref = run_seed(load_experiment(cfg, ["backend=pinocchio", *overrides]), 1, 3)
    comp = run_seed(load_experiment(cfg, ["backend=compiled", *overrides]), 1, 3)
    _rows_equal(ref, comp)
    # relative to the vector: the Levenberg-Marquardt solve with the regressor's unidentifiable
    # directions (condition ~1e6) moves single small entries by rounding times that
    theta_m = ref.params["model.theta"]
    np.testing.assert_allclose(comp.params["model.theta"], theta_m, rtol=0,
                               atol=1e-8 * np.abs(theta_m).max())


def test_poincare_map_on_the_compiled_engine_finds_the_python_engines_fixed_point():
    """The walker's Poincare analysis iterates the cycle on the compiled engine when it runs
    the walker: the fixed point equals the Python engine's to 1e-9 and the spectral radius to
    1e-4 (central differences with eps 1e-6 on both)."""
    path = CONFIGS / "gaits" / "compass_gait.yaml"
    got = {}
    for backend in ("compiled", "pinocchio"):
        exp = load_experiment(path, [f"backend={backend}"])
        assert exp.engine == ("compiled" if backend == "compiled" else "python")
        got[backend] = run_seed(exp, 0, 2).summary["poincare"]
    comp, ref = got["compiled"], got["pinocchio"]
    assert ref["fixed_point_found"] and comp["fixed_point_found"]
    x_ref = np.array(ref["fixed_point_q"] + ref["fixed_point_v"])
    x_comp = np.array(comp["fixed_point_q"] + comp["fixed_point_v"])
    np.testing.assert_allclose(x_comp, x_ref, atol=1e-9)
    assert abs(comp["spectral_radius"] - ref["spectral_radius"]) < 1e-4
    assert comp["stride_length_m"] == pytest.approx(ref["stride_length_m"], rel=1e-9)


WORLD_PLANT = ("plant={payloads: [{frame: torso, mass: 8.0, com: [0.0, 0.0, 0.2]}], "
               "friction: {left_hip: {viscous: 0.5, coulomb: 0.3, coulomb_velocity: 0.05}}, "
               "motor_gain: {right_hip: 0.95}}")


@pytest.mark.parametrize("over", [
    [WORLD_PLANT],
    ["events=[{cycle: 2, kind: payload, frame: torso, mass: 8.0, com: [0.0, 0.0, 0.3]}]"],
    ["plant={bodies: {left_hip: {mass_scale: 1.2}, right_hip: {mass_scale: 1.2}}}",
     "events=[{cycle: 2, kind: mass, link: torso, mass: 48.0}]"],
    ["events=[{cycle: 2, kind: slope, angle: 0.03}]"],
    ["events=[{cycle: 2, kind: mass, scale: 1.2}]"],
    ["events=[{cycle: 2, kind: payload, frame: torso, mass: 3.2, com: [0.0, 0.0, 0.24]}]"],
], ids=["payload_friction_gain", "payload_event", "mass_plant_and_event", "slope_event",
        "every_mass_event", "five_link_payload_event"])
def test_a_physical_walker_in_a_world_the_model_does_not_know_is_the_python_engines(over, request):
    """Plant != model on a physical walker (issue 28): a plant block (a payload with an
    offset, joint friction, a motor gain error), world events on top of it (payload, mass,
    slope, every body's mass +20 % from cycle 2; the five-link walker's torso payload), on
    the compiled engine (one build, the world an input) give the Python engine's rows to
    1e-8; the feedback rises in the changed world."""
    from feltool.engines.compiled.library import c_compiler

    if c_compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: install gcc")
    walker = "five_link" if "five_link" in request.node.callspec.id else "three_link"
    path = CONFIGS / "gaits" / f"{walker}_walker.yaml"
    over = ["walking.poincare=false", "joints.base_pitch.learn.init=demo", *over]
    ref = run_seed(load_experiment(path, ["backend=pinocchio", *over]), 0, 3)
    comp = run_seed(load_experiment(path, ["backend=compiled", *over]), 0, 3)
    assert ref.summary["diverged"] is False and len(ref.rows) == 3
    fb = [r["fb_abs_mean_error"] for r in ref.rows]
    assert max(fb) > 1e-2  # the world differs from the model: the design's 1e-7 N m is gone
    # (on the design's orbit the feedback is rounding, 1e-7 N m: compared to 1e-9 absolute)
    _rows_equal(ref, comp, atol=1e-9)
