"""CasADi backends: symbolic sensitivities and the compiled learning cycle give the Pinocchio
backend's numbers."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from feltool.engines.compiled.engine import compiled_engine
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS, feltool

STANDARD = CONFIGS / "two_link_standard.yaml"


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _curves(result, key="fb_abs_mean_error"):
    return np.array([r[key] for r in result.rows])


def test_casadi_sensitivity_matches_exact_and_finite_differences():
    exact = load_experiment(STANDARD)
    cas = load_experiment(STANDARD, ["learning.sensitivity=casadi"])
    fd = load_experiment(STANDARD, ["learning.sensitivity=finite_difference",
                                    "learning.fd_epsilon=1e-5"])
    theta = exact.initial_parameters(5)
    Qd, Vd, Ad = exact.primitives.desired(theta)
    J = exact.learner.jacobian(exact.dynamics, theta, Qd, Vd, Ad)
    J_cas = cas.learner.jacobian(cas.dynamics, theta, Qd, Vd, Ad)
    J_fd = fd.learner.jacobian(fd.dynamics, theta, Qd, Vd, Ad)
    scale = np.abs(J).max()
    np.testing.assert_allclose(J_cas, J, atol=1e-8 * scale)
    np.testing.assert_allclose(J_cas, J_fd, atol=1e-5 * scale)


@pytest.mark.parametrize("overrides", [[], ["learning.update=gauss_newton",
                                            "learning.rates.gauss_newton=1.0"]])
def test_compiled_cycle_gives_the_pinocchio_metrics(overrides):
    ref = run_seed(load_experiment(STANDARD, overrides), 3, 40)
    comp = run_seed(load_experiment(STANDARD, ["backend=compiled", *overrides]), 3, 40)
    assert len(comp.rows) == len(ref.rows) == 40
    for key in ref.rows[0]:
        a = np.array([r[key] for r in ref.rows], dtype=float)
        b = np.array([r[key] for r in comp.rows], dtype=float)
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-12, err_msg=key)
    np.testing.assert_allclose(comp.traces["last_q_system"], ref.traces["last_q_system"],
                               atol=1e-10)
    np.testing.assert_allclose(comp.params["elbow.weights"], ref.params["elbow.weights"],
                               rtol=1e-8)


def _c_compiler() -> str:
    """The compiler feltool.engines.compiled.library would use; in CI its absence fails the suite (a skip is a
    failure there, tests/conftest.py) with this message naming what to install."""
    import os
    import shutil

    cc = shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: the compiled backend cannot be tested; "
                    "install gcc (Debian: apt-get install gcc libc6-dev)")
    return cc


def test_compiled_backend_builds_and_loads_a_shared_library(tmp_path, monkeypatch):
    """Proof that the compiled backend ran compiled code, not CasADi's virtual machine: with an
    empty cache, one run writes exactly one shared library, the process has it mapped (the
    dynamic loader's own record, /proc/self/maps), the cycle functions are CasADi externals
    loaded from it, and its metrics equal the Pinocchio backend's to 1e-8."""
    from pathlib import Path

    from feltool.engines.compiled.library import cache_dir

    _c_compiler()
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path / "fresh"))
    exp = load_experiment(STANDARD, ["backend=compiled"])
    comp = run_seed(exp, 2, 12)
    libs = sorted(cache_dir().glob("feltool_cycle_*.so"))
    assert len(libs) == 1, libs
    with open(libs[0], "rb") as fh:
        assert fh.read(4) == b"\x7fELF"
    maps = Path("/proc/self/maps")
    if maps.exists():  # Linux: the library is in this process's address space
        assert str(libs[0].resolve()) in maps.read_text()
    compiled = compiled_engine(exp)
    assert all(f.class_name() == "External" for f in compiled.functions), \
        "not loaded from the library"
    ref = run_seed(load_experiment(STANDARD), 2, 12)
    for key in ref.rows[0]:
        a = np.array([r[key] for r in ref.rows], dtype=float)
        b = np.array([r[key] for r in comp.rows], dtype=float)
        np.testing.assert_allclose(b, a, rtol=1e-8, atol=1e-12, err_msg=key)


def test_casadi_backend_gives_the_pinocchio_metrics():
    ref = run_seed(load_experiment(STANDARD), 1, 5)
    cas = run_seed(load_experiment(STANDARD, ["backend=casadi"]), 1, 5)
    np.testing.assert_allclose(_curves(cas), _curves(ref), rtol=1e-10)


def test_compiled_run_in_a_process_pool_equals_pinocchio_metrics_csv(tmp_path):
    """Two workers load (and one compiles) the same cached library; metrics.csv agrees."""
    a, b = tmp_path / "pin", tmp_path / "compiled"
    for out, extra in ((a, []), (b, ["--set", "backend=compiled"])):
        res = feltool("run", str(STANDARD), "--seeds", "0-1", "--cycles", "15", "--out",
                      str(out), "--workers", "2", *extra)
        assert res.returncode == 0, res.stderr
    ra, rb = (list(csv.DictReader(open(d / "metrics.csv"))) for d in (a, b))
    assert len(ra) == len(rb) == 30
    for x, y in zip(ra, rb):
        for key in x:
            assert float(y[key]) == pytest.approx(float(x[key]), rel=1e-8, abs=1e-12), key


def test_without_a_c_compiler_it_falls_back_and_says_so_once(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", "false")  # a "compiler" that always fails
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path / "empty-cache"))
    res = feltool("run", str(STANDARD), "--seeds", "0", "--cycles", "3", "--out",
                  str(tmp_path / "run"), "--set", "backend=compiled")
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("interpreted virtual machine") == 1


def test_compiled_backend_rejects_what_it_cannot_do(tmp_path):
    res = feltool("check", str(STANDARD), "--set", "backend=compiled",
                  "--set", "learning.sensitivity=finite_difference")
    assert res.returncode == 2
    assert ("learning.sensitivity: backend 'compiled': finite_difference is the Python engine's "
            "check") in res.stderr and "Traceback" not in res.stderr


def test_compiled_runs_several_cycles_per_call_and_resumes_bit_identically(tmp_path, monkeypatch):
    """The compiled code runs CYCLES_PER_CALL cycles per call; stopping at a cycle that is not a
    multiple of it and resuming from the checkpoint gives the same rows and parameters."""
    import feltool.runs.checkpoint as experiment
    from feltool.engines.compiled.library import CYCLES_PER_CALL
    from feltool.runs.checkpoint import Checkpointer, Interrupted

    exp = load_experiment(STANDARD, ["backend=compiled"])
    ref = run_seed(exp, 0, 30)
    calls = {"n": 0}

    def stop_after_13():
        calls["n"] += 1
        return calls["n"] >= 13

    assert 13 % CYCLES_PER_CALL
    monkeypatch.setattr(experiment, "stop_requested", stop_after_13)
    with pytest.raises(Interrupted):
        run_seed(exp, 0, 30, checkpoint=Checkpointer(tmp_path, 0, every=5))
    monkeypatch.undo()
    res = run_seed(load_experiment(STANDARD, ["backend=compiled"]), 0, 30,
                   checkpoint=Checkpointer(tmp_path, 0, every=5))
    assert res.rows == ref.rows
    np.testing.assert_array_equal(res.params["elbow.weights"], ref.params["elbow.weights"])


def test_a_cached_library_loads_without_building_the_graphs(tmp_path, monkeypatch):
    """The cache is keyed by what determines the graphs (config, robot model, worlds, feltool's
    source): a second engine of the same experiment loads the library without building a graph
    and runs the same cycle; another config (another gain) is another library."""
    from feltool.engines.compiled.engine import CompiledEngine

    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path / "cache"))
    exp = load_experiment(CONFIGS / "two_link_standard.yaml", ["sim.cycles=2"])
    first = CompiledEngine(exp)
    libs = sorted((tmp_path / "cache" / "compiled").glob("*.so"))
    assert len(libs) == 1

    def no_build(*_):
        raise AssertionError("the graphs were built on a cache hit")

    monkeypatch.setattr(CompiledEngine, "_build", no_build)
    again = CompiledEngine(load_experiment(CONFIGS / "two_link_standard.yaml", ["sim.cycles=2"]))
    theta = exp.theta_demo
    q, v = np.zeros(exp.robot.model.nv), np.zeros(exp.robot.model.nv)
    data = first.data(theta)
    state = first.state(theta, q, v)
    for a, b in zip(first.cycle(0, state, data), again.cycle(0, state, data)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    monkeypatch.undo()
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path / "cache"))
    CompiledEngine(load_experiment(CONFIGS / "two_link_standard.yaml",
                                   ["sim.cycles=2", "joints.elbow.gains.kp=77"]))
    assert len(list((tmp_path / "cache" / "compiled").glob("*.so"))) == 2
