"""A physical walker in a world its model does not know (issue 28): the plant differs from the
known model (a payload, heavier bodies, a slope), the known model stays, and classic FEL on the
walker (a model correction and motor biases, feltool.learning.walker_model) learns the gap.

The full runs (150 cycles, 10 seeds, both walkers) are benchmarks/walk_unknown_world.py's and
docs/biped.md's; here short runs that still prove learning."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.config.events import EventConfig
from feltool.learning.walker_model import WalkerModelLearner
from feltool.plant.events import changed_model
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS

THREE = CONFIGS / "gaits" / "three_link_walker.yaml"
DESIGN = ["walking.poincare=false", "joints.base_pitch.learn.init=demo"]
LEARN = ("learning.model={features: regressor, update: gauss_newton, rate: 0.5, "
         "motor_bias: 0.5, damping: 1.0e-3}")
PAYLOAD = "{kind: payload, frame: torso, mass: 8.0, com: [0.0, 0.0, 0.8]}"  # 10 % of 80 kg


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def test_a_payload_in_the_plant_changes_the_feedback_and_not_the_model():
    """The plant carries 8 kg at the torso's centre of mass; the known model's RNEA (the
    feedforward) is unchanged to the last bit, the plant's differs by the payload's weight,
    and the feedback of the design's first cycle rises from the design's rounding to N m."""
    known = load_experiment(THREE, [*DESIGN, "backend=pinocchio"])
    loaded = load_experiment(THREE, [*DESIGN, "backend=pinocchio",
                                     f"plant={{payloads: [{PAYLOAD.replace('kind: payload, ', '')}]}}"])
    rng = np.random.default_rng(0)
    nv = known.robot.model.nv
    for _ in range(5):
        q, v, a = (rng.uniform(-0.5, 0.5, nv) for _ in range(3))
        np.testing.assert_array_equal(loaded.dynamics.inverse(q, v, a),
                                      known.dynamics.inverse(q, v, a))
        np.testing.assert_array_equal(loaded.hybrid.known.inverse(q, v, a),
                                      known.dynamics.inverse(q, v, a))
        # the plant: the payload's weight, 8 kg x 9.81 m/s^2, on the base's vertical row at rest
        diff = loaded.plant.inverse(q, 0 * v, 0 * a) - known.dynamics.inverse(q, 0 * v, 0 * a)
        assert diff[1] == pytest.approx(8.0 * 9.81, rel=1e-12)
    fb_known = run_seed(known, 0, 1).rows[0]["fb_abs_mean_error"]
    fb_loaded = run_seed(loaded, 0, 1).rows[0]["fb_abs_mean_error"]
    assert fb_known < 1e-5 and fb_loaded > 1.0


def test_the_model_correction_represents_a_payload_exactly():
    """Y theta with theta the payload's change of the inertial parameters (on the regressor's
    moving columns) is the plant's RNEA minus the known model's, at any state (pin.rnea of
    both models as the reference); the columns a planar walker never moves are left out."""
    exp = load_experiment(THREE, [*DESIGN, LEARN])
    model = exp.hybrid.walker.walker.model
    ml = exp.model_learner
    assert isinstance(ml, WalkerModelLearner) and ml.n_bias == 2
    assert "base_pitch.mcy" not in ml.names and "base_pitch.Iyy" in ml.names
    plant = changed_model(model, [EventConfig(cycle=1, kind="payload", frame="torso", mass=8.0,
                                              com=[0.1, 0.0, 0.8])])
    dpi = np.concatenate([plant.inertias[j].toDynamicParameters() - model.inertias[j]
                          .toDynamicParameters() for j in range(1, model.njoints)])
    theta = np.concatenate([dpi[ml.columns], np.zeros(ml.n_bias)])
    correction = ml.correction(theta)
    rng = np.random.default_rng(1)
    dk, dp = model.createData(), plant.createData()
    for _ in range(5):
        q, v, a = (rng.uniform(-0.5, 0.5, model.nv) for _ in range(3))
        ref = pin.rnea(plant, dp, q, v, a) - pin.rnea(model, dk, q, v, a)
        np.testing.assert_allclose(correction(q, v, a), ref, atol=1e-10)


def test_the_motor_biases_rate_does_not_depend_on_the_sampling():
    """Learned alone, the biases move by the rate times the cycle's mean motor-space error:
    the same error sampled 100 or 1000 times a cycle gives the same step."""
    ml = WalkerModelLearner(None, ["hip", "knee"], rate=0.0, bias_rate=0.5)
    steps = []
    for n in (100, 1000):
        t = np.arange(n) / n
        E = np.stack([2.0 + np.sin(2 * np.pi * t), -1.0 + 0.0 * t, 0.0 * t], axis=1)
        A = np.broadcast_to(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), (n, 2, 3))
        steps.append(ml.step(np.zeros(2), E, E, E, A, E))
    np.testing.assert_allclose(steps[0], [1.0, -0.5], rtol=1e-5)
    np.testing.assert_allclose(steps[1], steps[0], rtol=1e-5)


#: world -> (event, the largest feedback ratio cycle 15 / cycle 3 allowed). Measured (seed 0,
#: compiled): payload 0.335, mass 0.146, slope 0.432 -- the payload and the slope level off
#: near their floors (docs/biped.md: the designed gait is no orbit of the changed plant).
WORLDS = {"payload": (PAYLOAD.replace("{", "{cycle: 3, "), 0.45),
          "mass": ("{cycle: 3, kind: mass, scale: 1.2}", 0.2),
          "slope": ("{cycle: 3, kind: slope, angle: 0.03}", 0.55)}


@pytest.mark.parametrize("world", sorted(WORLDS))
def test_a_short_run_of_each_world_learns_on_two_seeds(world):
    """From cycle 3 the three-link walker walks in the changed world; by cycle 15 the summed
    feedback has fallen below the stated fraction of its cycle-3 jump, on seeds 0 and 1,
    walking every step (contact checks on), the torso within 0.01 rad RMS of its target."""
    from feltool.engines.compiled.library import c_compiler

    if c_compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: install gcc")
    event, factor = WORLDS[world]
    exp = load_experiment(THREE, [*DESIGN, LEARN, "backend=compiled", f"events=[{event}]"])
    for seed in (0, 1):
        res = run_seed(exp, seed, 15)
        fb = [r["fb_abs_mean_error"] for r in res.rows]
        assert not res.summary["diverged"] and res.summary["walking"]["steps"] == 30
        assert fb[1] < 1e-5 < 1.0 < fb[2]  # the design, then the world changes
        assert fb[-1] < factor * fb[2], (world, seed, fb[-1] / fb[2])
        assert max(r["stabilized_rms"] for r in res.rows) < 0.01


def test_a_changed_world_runs_again_from_the_compiled_cache():
    """A second experiment of the same changed world loads the cached library (one build for
    every world: the physical walker's graph has one cycle and one trace, whatever the number
    of worlds) and walks the same cycles as the first, which built it."""
    from feltool.engines.compiled.library import c_compiler

    if c_compiler() is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: install gcc")
    event = WORLDS["slope"][0]
    rows = []
    for _ in range(2):
        exp = load_experiment(THREE, [*DESIGN, LEARN, "backend=compiled", f"events=[{event}]"])
        res = run_seed(exp, 0, 4)
        assert exp.engine == "compiled" and not res.summary["diverged"]
        rows.append([r["fb_abs_mean_error"] for r in res.rows])
    np.testing.assert_allclose(rows[1], rows[0], rtol=1e-12)
