"""The bad-input corpus: every broken config or URDF in tests/bad_inputs/ must give exit code 2
and a message that names its field or element, without a traceback and without writing anything
that looks like a result.

Each ``*.yaml`` case starts with ``# expect: <text the message must contain>``.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from feltool.cli import main

from .conftest import feltool

CASES = sorted((Path(__file__).parent / "bad_inputs").glob("*.yaml"))


def expected(path: Path) -> str:
    first = path.read_bytes().split(b"\n", 1)[0].decode()
    assert first.startswith("# expect: "), path
    return first[len("# expect: "):]


def test_the_corpus_is_large_enough():
    assert len(CASES) >= 30


@pytest.mark.parametrize("case", CASES, ids=[c.stem for c in CASES])
def test_bad_input_exits_2_naming_the_problem(case, tmp_path, capsys):
    out = tmp_path / "run"
    t0 = time.perf_counter()
    code = main(["run", str(case), "--out", str(out), "--no-progress"])
    elapsed = time.perf_counter() - t0
    captured = capsys.readouterr()
    assert code == 2, captured
    assert expected(case) in captured.err, captured.err
    assert "Traceback" not in captured.err + captured.out
    assert len(captured.err.strip().splitlines()) <= 4  # one line per problem, no dumps
    assert not out.exists()  # nothing that looks like a result
    print(f"{case.stem}: {elapsed * 1000:.0f} ms")


def test_a_bad_input_as_a_user_sees_it(tmp_path):
    res = feltool("run", str(CASES[0]), "--out", str(tmp_path / "x"))
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.startswith("feltool: error: ")
