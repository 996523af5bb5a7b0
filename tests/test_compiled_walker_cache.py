"""One compiled library per physical walker, not per design (issue 30): the walker's cycle
takes the design (its demos, its number of samples per cycle, the known model's gravity, the
torso's target) as inputs, so a second ``feltool gait`` with other options on the same walker
loads the library the first one built, and the cycle it runs is still the Python engine's."""

from __future__ import annotations

import numpy as np
import pytest

from feltool.cli.main import main
from feltool.config.files import read_yaml
from feltool.engines.compiled import library
from feltool.engines.compiled.engine import _physical_key, compiled_engine
from feltool.engines.compiled.physical_step import capacity
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

CONFIG = "configs/gaits/compass_gait.yaml"
FIRST = ["--step-length", "0.4", "--duration", "0.6"]
SECOND = ["--step-length", "0.45", "--duration", "0.62", "--slope", "0.04"]


@pytest.fixture(scope="module")
def designs(tmp_path_factory):
    """Two designs of the compass gait in a fresh cache: the libraries and build counts after
    each."""
    tmp = tmp_path_factory.mktemp("designs")
    cache = tmp / "cache"
    mp = pytest.MonkeyPatch()
    mp.setenv("FELTOOL_CACHE", str(cache))
    out = []
    try:
        for i, options in enumerate((FIRST, SECOND)):
            built = library.COUNTS["built"]
            code = main(["gait", CONFIG, *options, "--out", str(tmp / f"gait{i}.yaml"),
                         "--no-progress"])
            assert code == 0
            # (the library was started before the design: no compiler's files left behind)
            assert not [p for p in (cache / "compiled").iterdir() if p.is_dir()]
            libs = {p.name: p.stat().st_mtime_ns for p in (cache / "compiled").glob("*.so")}
            out.append((tmp / f"gait{i}.yaml", libs, library.COUNTS["built"] - built))
        yield out
    finally:
        mp.undo()


def test_a_second_design_on_the_same_walker_loads_the_first_ones_library(designs):
    (path1, libs1, built1), (path2, libs2, built2) = designs
    raw1, raw2 = read_yaml(path1), read_yaml(path2)
    # the designs differ in all that used to name the library
    assert raw1["period_s"] != raw2["period_s"]
    assert raw1["gravity"] != raw2["gravity"]
    assert raw1["joints"]["base_pitch"]["demo"] != raw2["joints"]["base_pitch"]["demo"]
    assert len(libs1) == 1 and built1 == 1  # the design, its orbit, its verification: one build
    assert libs2 == libs1 and built2 == 0  # the same file, untouched, nothing compiled


def test_the_library_key_and_capacity_do_not_depend_on_the_design(designs):
    exps = [load_experiment(path) for path, _, _ in designs]
    n = [e.primitives.n_steps for e in exps]
    assert n[0] != n[1]
    assert _physical_key(exps[0]) == _physical_key(exps[1])
    assert capacity(exps[0]) == capacity(exps[1]) >= max(n)


def test_the_second_designs_cycles_on_the_shared_library_are_the_python_engines(designs,
                                                                                 monkeypatch):
    """The design whose samples per cycle and gravity are the library's inputs (not its
    build's) learns as on the Python engine: every metric of 4 cycles to 1e-9 relative."""
    monkeypatch.setenv("FELTOOL_CACHE", str(designs[0][0].parent / "cache"))
    path = designs[1][0]
    rows = {}
    for backend in ("compiled", "pinocchio"):
        exp = load_experiment(path, [f"backend={backend}", "walking.poincare=false"])
        if backend == "compiled":
            built = library.COUNTS["built"]
            assert compiled_engine(exp) is not None
            assert library.COUNTS["built"] == built
        rows[backend] = run_seed(exp, 0, 4).rows
    for a, b in zip(rows["compiled"], rows["pinocchio"], strict=True):
        for key, value in b.items():
            if isinstance(value, float) and np.isfinite(value):
                assert a[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
