"""A compiled library built in parallel parts (feltool/engines/compiled/csplit.py) computes
what the one-file build computes, to the bit, and exports only the entry points; a library
started ahead (``compile_ahead``, as ``feltool gait`` does before its design) is the one later
loaded, built once, and one not used leaves nothing behind."""

from __future__ import annotations

import ctypes
import os

import casadi as ca
import numpy as np
import pytest

from feltool.engines.compiled import library
from feltool.engines.compiled.csplit import split_source

pytestmark = pytest.mark.skipif(library.c_compiler() is None and not os.environ.get("CI"),
                                reason="no C compiler")


def _functions() -> list[ca.Function]:
    """Two entry points sharing called subfunctions (a mapped step, a rootless chain of
    transcendental functions: rounding would show any reordering)."""
    x, p = ca.SX.sym("x", 3), ca.SX.sym("p", 2)
    step = ca.Function("step", [x, p], [ca.vertcat(
        ca.sin(x[0] * p[0]) + ca.exp(-x[1] ** 2) / (1 + x[2] ** 2),
        ca.atan2(x[2], x[0] + p[1]) * ca.sqrt(1 + x[1] ** 2),
        ca.log(1 + x[0] ** 2) - ca.cos(x[1] * x[2]) * p[0])])
    other = ca.Function("other", [x], [ca.vertcat(ca.tanh(x[0]) * x[1], x[2] / 3, x[0] * x[1])])
    X, P = ca.MX.sym("X", 3), ca.MX.sym("P", 2)
    y = X
    for _ in range(4):
        y = step(y, P) + other(y) * 1e-3
    many = step.map(16, "serial")(ca.repmat(y, 1, 16), ca.repmat(P, 1, 16))
    return [ca.Function("cycle_0", [X, P], [y, ca.sum2(many)]),
            ca.Function("trace_0", [X, P], [many, other(y)])]


def _build(fns, tmp, name, parts, monkeypatch):
    monkeypatch.setenv("FELTOOL_COMPILE_PARTS", str(parts))
    tmp.mkdir()
    run = library._Compilation(fns, name, library.c_compiler(), tmp)
    assert run.wait().returncode == 0
    return run


def test_parts_compute_what_the_whole_file_computes_to_the_bit(tmp_path, monkeypatch):
    fns = _functions()
    whole = _build(fns, tmp_path / "whole", "lib_whole", 1, monkeypatch)
    split = _build(fns, tmp_path / "split", "lib_split", 2, monkeypatch)
    assert len(whole.commands) == 1 and len(split.commands) == 2  # (one cc each, at once)
    text = (tmp_path / "split" / "lib_split.c").read_text()
    parts = split_source(text, "lib_split", 2)
    assert parts is not None and all("casadi_f" in p for p in parts)
    assert split_source(text, "lib_split", 1) is None
    assert split_source(text, "another_name", 2) is None  # (not its layout: compiled whole)
    rng = np.random.default_rng(0)
    for name in ("cycle_0", "trace_0"):
        a = ca.external(name, str(whole.out))
        b = ca.external(name, str(split.out))
        for _ in range(20):
            x, p = rng.normal(size=3), rng.normal(size=2)
            for ya, yb in zip(a(x, p), b(x, p)):
                assert np.array_equal(np.asarray(ya), np.asarray(yb))  # bit for bit
                assert np.isfinite(np.asarray(ya)).all()
    # the parts' shared functions are hidden: the library exports what the whole one does
    lib = ctypes.CDLL(str(split.out))
    assert hasattr(lib, "cycle_0") and hasattr(lib, "trace_0_sparsity_out")
    assert not hasattr(lib, "lib_split_f0") and not hasattr(lib, "lib_split_f1")


def test_a_library_started_ahead_is_built_once_and_loaded(tmp_path, monkeypatch):
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path))
    fns = _functions()
    built = library.COUNTS["built"]
    assert library.compile_ahead(fns, "test-ahead")
    assert not library.compile_ahead(fns, "test-ahead")  # (under way)
    assert library.pending("test-ahead") is fns
    loaded = library.compile_functions(fns, key="test-ahead")
    assert library.COUNTS["built"] == built + 1 and library.pending("test-ahead") is None
    assert library.has_library("test-ahead")
    assert not library.compile_ahead(fns, "test-ahead")  # (cached now)
    x, p = np.array([0.3, -0.2, 0.5]), np.array([1.1, 0.4])
    for got, want in zip(loaded[0](x, p), fns[0](x, p)):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-12, atol=1e-14)
    cache = tmp_path / "compiled"
    assert sorted(p.name for p in cache.iterdir()) == sorted(
        [f"{library.library_name('test-ahead')}.so", f"{library.library_name('test-ahead')}.so.json"])


def test_a_library_started_ahead_and_not_used_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path))
    assert library.compile_ahead(_functions(), "test-unused")
    procs = list(library._PENDING[library.library_name("test-unused")].procs)
    library.cancel_pending()
    assert all(p.poll() is not None for p in procs)  # stopped
    assert library.pending("test-unused") is None
    assert list((tmp_path / "compiled").iterdir()) == []
