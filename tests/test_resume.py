"""Long runs survive interruption: SIGTERM mid-way, resume, and the files are bit-identical to
an uninterrupted run."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np

from feltool.runs.rundir import load_npz

from .conftest import CONFIGS, feltool

STANDARD = str(CONFIGS / "two_link_standard.yaml")
# the Python engine: a run long enough to be stopped mid-way (the compiled one takes 0.1 s)
ARGS = ["--seeds", "0-3", "--cycles", "120", "--workers", "2", "--no-progress", "--set",
        "backend=pinocchio"]


def test_sigterm_then_resume_is_bit_identical(tmp_path):
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    res = feltool("run", STANDARD, *ARGS, "--out", str(whole))
    assert res.returncode == 0, res.stderr

    proc = subprocess.Popen([sys.executable, "-m", "feltool.cli", "run", STANDARD, *ARGS,
                             "--out", str(cut)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    deadline = time.monotonic() + 300  # a generous bound: the first checkpoint, mid-run
    while not list((cut / "checkpoints").glob("*.json")):
        assert time.monotonic() < deadline and proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, (out, err)  # 128 + SIGTERM
    assert "feltool run --resume" in err and "Traceback" not in err
    assert not (cut / "metrics.csv").exists()  # no half result presented as a result
    assert list((cut / "checkpoints").glob("seed-*.npz"))

    res = feltool("run", "--resume", str(cut), "--workers", "2", "--no-progress")
    assert res.returncode == 0, res.stderr
    assert (cut / "metrics.csv").read_bytes() == (whole / "metrics.csv").read_bytes()
    for seed in range(4):
        a, b = load_npz(whole / f"params/seed-{seed}.npz"), load_npz(cut / f"params/seed-{seed}.npz")
        assert a.keys() == b.keys()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
    # finished seeds leave only their final state (so that a resume may add cycles)
    cycles = int(ARGS[ARGS.index("--cycles") + 1])
    finals = sorted((cut / "checkpoints").glob("seed-*.json"))
    assert len(finals) == 4 and all(json.loads(p.read_text())["cycle"] == cycles for p in finals)

    def counters(run):
        return [(s["seed"], s["cycles"], s["converged_cycle"], s["limits"])
                for s in json.loads((run / "summary.json").read_text())["seeds"]]

    assert counters(cut) == counters(whole)


def test_resume_of_a_finished_run_changes_nothing(tmp_path):
    out = tmp_path / "done"
    assert feltool("run", STANDARD, "--seeds", "0", "--cycles", "5", "--out", str(out)).returncode == 0
    before = (out / "metrics.csv").read_bytes()
    res = feltool("run", "--resume", str(out))
    assert res.returncode == 0, res.stderr
    assert (out / "metrics.csv").read_bytes() == before


def test_resume_needs_a_run_directory(tmp_path):
    res = feltool("run", "--resume", str(tmp_path))
    assert res.returncode == 2 and "run.json" in res.stderr
