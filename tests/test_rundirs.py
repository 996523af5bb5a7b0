"""Runs you can trust: a run directory belongs to one command, its state is recorded, two
processes never write it at once, a killed run resumes to the same numbers, and exit codes tell
the truth (run and sweep)."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from feltool.runs.runstate import run_state
from tests.conftest import ROOT, feltool

ENV = dict(os.environ, PYTHONPATH=str(ROOT))
SHORT = ["two_link_standard", "--seeds", "0-1", "--cycles", "4", "--no-progress"]


def _tree(path: Path) -> dict[str, str]:
    """Every file under ``path`` with its content hash and mode."""
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
            + oct(p.stat().st_mode) for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("finished") / "run"
    r = feltool("run", *SHORT, "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out


def _popen(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "feltool.cli", *args], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f"the run ended before {path} appeared: {proc.stderr.read()}"
        assert time.monotonic() < deadline, f"{path} did not appear"
        time.sleep(0.05)


# -- one directory, one command ------------------------------------------------------------------

def test_out_onto_a_finished_run_is_refused_and_leaves_it_untouched(finished):
    before = _tree(finished)
    r = feltool("run", "two_link_human_arm", "--seeds", "0", "--cycles", "2", "--out",
                str(finished))
    assert r.returncode == 2, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    assert str(finished) in r.stderr and "complete" in r.stderr and "--resume" in r.stderr
    assert _tree(finished) == before  # byte-identical, modes too
    # the same config again is refused as well: reuse only by an explicit resume
    r = feltool("run", *SHORT, "--out", str(finished))
    assert r.returncode == 2 and _tree(finished) == before


def test_out_onto_a_directory_with_other_files_is_refused(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    r = feltool("run", *SHORT, "--out", str(tmp_path))
    assert r.returncode == 2 and "notes.txt" in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_resume_with_another_config_seeds_or_fewer_cycles_is_refused(finished):
    before = _tree(finished)
    cases = {
        "learning.rates.weights": ["run", *SHORT, "--set", "learning.rates.weights=0.3"],
        "robot": ["run", "two_link_human_arm", "--seeds", "0-1", "--cycles", "4"],
        "seeds": ["run", "two_link_standard", "--seeds", "0-2", "--cycles", "4"],
        "sim.cycles": ["run", "two_link_standard", "--seeds", "0-1", "--cycles", "3"],
    }
    for field, args in cases.items():
        r = feltool(*args, "--resume", str(finished))
        assert r.returncode == 2, (field, r.stdout, r.stderr)
        assert field in r.stderr and "Traceback" not in r.stderr, (field, r.stderr)
        assert _tree(finished) == before, field


def test_resume_of_a_complete_run_with_more_cycles_extends_it_exactly(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert feltool("run", *SHORT, "--out", str(a)).returncode == 0
    r = feltool("run", "--resume", str(a), "--cycles", "9")
    assert r.returncode == 0, r.stderr
    assert feltool("run", "two_link_standard", "--seeds", "0-1", "--cycles", "9",
                   "--no-progress", "--out", str(b)).returncode == 0
    assert (a / "metrics.csv").read_bytes() == (b / "metrics.csv").read_bytes()
    assert (a / "params" / "seed-1.npz").read_bytes() == (b / "params" / "seed-1.npz").read_bytes()
    assert "cycles: 9" in (a / "config.yaml").read_text()
    meta = json.loads((a / "run.json").read_text())
    assert meta["state"] == "complete" and meta["cycles"] == 9
    assert [h["cycles"] for h in meta["history"]] == [4, 9]
    assert all(h["state"] == "complete" and "--resume" not in meta["history"][0]["command"]
               for h in meta["history"])


def test_run_files_respect_the_umask(finished):
    mask = os.umask(0)
    os.umask(mask)
    for name in ("metrics.csv", "summary.json", "config.yaml", "run.json",
                 "params/seed-0.npz"):
        mode = stat.S_IMODE((finished / name).stat().st_mode)
        assert mode == 0o666 & ~mask, (name, oct(mode))


# -- concurrency and kills -----------------------------------------------------------------------

def test_a_second_process_cannot_write_a_running_directory(tmp_path):
    out = tmp_path / "run"
    # the Python engine and 300 cycles: still running when stopped (the compiled engine's 80
    # cycles could end between run.json appearing and the SIGSTOP on a busy machine)
    first = _popen("run", "two_link_standard", "--seeds", "0-1", "--cycles", "300",
                   "--workers", "1", "--no-progress", "--set", "backend=pinocchio",
                   "--out", str(out))
    try:
        _wait_for(out / "run.json", first)
        os.killpg(first.pid, signal.SIGSTOP)  # hold it mid-run (however fast the machine)
        assert run_state(out) == "running"
        for extra in ([], ["--resume"]):  # a new run, and a resume, on the same directory
            r = feltool("run", "two_link_standard", "--seeds", "0-1", "--cycles", "300",
                        "--out", str(out), *extra)
            assert r.returncode == 2, (extra, r.stderr)
            assert ("in use by another feltool process" in r.stderr
                    or "already holds" in r.stderr), r.stderr
        r = feltool("run", "--resume", str(out))
        assert r.returncode == 2 and f"PID {first.pid}" in r.stderr, r.stderr
        os.killpg(first.pid, signal.SIGCONT)
        assert first.wait(timeout=300) == 0, first.stderr.read()
    finally:
        if first.poll() is None:
            first.kill()
    assert run_state(out) == "complete" and not (out / ".lock").exists()
    rows = (out / "metrics.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * 300  # intact: every (seed, cycle) row once


def test_a_killed_run_reads_interrupted_and_resumes_to_the_same_numbers(tmp_path):
    out, ref = tmp_path / "killed", tmp_path / "ref"
    # the Python engine: slow enough to be killed mid-run (the compiled one ends in 0.1 s)
    args = ["two_link_standard", "--seeds", "0-1", "--cycles", "300", "--workers", "1",
            "--no-progress", "--set", "backend=pinocchio"]
    proc = _popen("run", *args, "--out", str(out))
    try:
        _wait_for(out / "checkpoints" / "seed-0.json", proc)
        os.killpg(proc.pid, signal.SIGKILL)  # no handler runs, nothing is cleaned up
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert (out / ".lock").exists()  # left behind by the dead process
    assert run_state(out) == "interrupted"
    r = feltool("plot", str(out))
    assert r.returncode == 2 and "interrupted" in r.stderr and "not complete" in r.stderr
    r = feltool("run", "--resume", str(out))
    assert r.returncode == 0, r.stderr
    assert feltool("run", *args, "--out", str(ref)).returncode == 0
    assert (out / "metrics.csv").read_bytes() == (ref / "metrics.csv").read_bytes()
    assert run_state(out) == "complete"
    history = json.loads((out / "run.json").read_text())["history"]
    assert "state" not in history[0] and history[1]["state"] == "complete"


# -- exit codes ----------------------------------------------------------------------------------

def test_a_diverging_run_exits_1_and_keeps_its_results(tmp_path):
    r = feltool("run", "two_link_standard", "--seeds", "0", "--cycles", "6", "--set",
                "learning.update=gradient", "--set", "learning.safeguard=false", "--set",
                "learning.rates.weights=1684.4", "--out", str(tmp_path / "d"), "--no-progress")
    assert r.returncode == 1, r.stdout + r.stderr
    assert "DIVERGED" in r.stdout
    summary = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert summary["aggregate"]["n_diverged"] == 1 and run_state(tmp_path / "d") == "complete"


def test_missing_the_success_criterion_exits_1(tmp_path):
    r = feltool("run", *SHORT, "--set", "success.fb_ratio_max=0.001", "--out",
                str(tmp_path / "s"))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "success.fb_ratio_max" in r.stdout
    seeds = json.loads((tmp_path / "s" / "summary.json").read_text())["seeds"]
    assert [s["learned"] for s in seeds] == [False, False]
    r = feltool("run", *SHORT, "--set", "success.fb_ratio_max=0.99", "--out",
                str(tmp_path / "ok"))
    assert r.returncode == 0, r.stdout


def test_the_success_ratio_from_the_world_s_change(tmp_path):
    """``success.ratio_from: change``: the bound is on the last cycle over the cycle of the
    first world event (a 0.2 kg tip payload at cycle 4, after the arm has learned), which the
    summary gives per seed; over cycle 1 the same run's ratio is far below it."""
    event = ["--set", "events=[{cycle: 4, kind: payload, frame: tip, mass: 0.2}]",
             "--set", "success.ratio_from=change", "--cycles", "8"]
    r = feltool("run", *SHORT, *event, "--set", "success.fb_ratio_max=0.01", "--out",
                str(tmp_path / "s"))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "fb of the world's change (cycle 4)" in r.stdout
    seeds = json.loads((tmp_path / "s" / "summary.json").read_text())["seeds"]
    rows = list(csv.DictReader(open(tmp_path / "s" / "metrics.csv")))
    for s in seeds:
        fb = [float(x["fb_abs_mean_error"]) for x in rows if int(x["seed"]) == s["seed"]]
        assert s["change_cycle"] == 4 and s["fb_change"] == pytest.approx(fb[3], rel=1e-12)
        assert s["fb_ratio_change"] == pytest.approx(fb[-1] / fb[3], rel=1e-12)
        assert s["fb_ratio"] < 0.01 < s["fb_ratio_change"]
    r = feltool("run", *SHORT, *event, "--set", "success.fb_ratio_max=0.9", "--out",
                str(tmp_path / "ok"))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "from the world's change at cycle 4" in r.stdout
    # a run that ends before the change cannot meet it, and says why
    r = feltool("run", *SHORT, *event, "--cycles", "3", "--set", "success.fb_ratio_max=0.9",
                "--out", str(tmp_path / "short"))
    assert r.returncode == 1, r.stdout + r.stderr
    assert "before the world's change at cycle 4" in r.stdout


def test_a_sweep_with_a_diverging_point_exits_1_and_names_it(tmp_path):
    out = tmp_path / "sweep"
    r = feltool("sweep", "two_link_standard", "--grid", "learning.update=gradient", "--grid",
                "learning.safeguard=false", "--grid", "learning.rates.weights=67.374,1684.4",
                "--seeds", "0", "--cycles", "4", "--out", str(out), "--no-progress")
    assert r.returncode == 1, r.stdout + r.stderr
    assert "point 1 (" in r.stdout and "learning.rates.weights=1684.4), seed 0:" in r.stdout, \
        r.stdout
    assert "point 0 " not in r.stdout
    assert run_state(out, "sweep.json") == "complete"
    # a sweep directory belongs to one command too
    r = feltool("sweep", "two_link_standard", "--grid", "learning.rates.weights=0.1",
                "--seeds", "0", "--cycles", "2", "--out", str(out))
    assert r.returncode == 2 and "--resume" in r.stderr


# -- CLI manners ---------------------------------------------------------------------------------

def test_progress_lines_without_a_terminal_and_quiet(tmp_path):
    r = feltool("run", "two_link_standard", "--seeds", "0", "--cycles", "20", "--out",
                str(tmp_path / "p"))
    lines = [ln for ln in r.stderr.splitlines() if "error feedback" in ln]
    assert [ln.split("cycle ")[1].split(",")[0] for ln in lines] == \
        [f"{c}/20" for c in range(2, 21, 2)], r.stderr
    r = feltool("run", "two_link_standard", "--seeds", "0", "--cycles", "3", "--quiet",
                "--out", str(tmp_path / "q"))
    assert r.returncode == 0 and r.stderr == ""


def test_broken_pipe_is_not_a_traceback():
    r = subprocess.run(f"{sys.executable} -m feltool.cli inspect example-robot-data:ur5 | head -1",
                       shell=True, capture_output=True, text=True, env=ENV, timeout=120)
    assert r.stdout.startswith("robot ur5"), r.stdout
    assert "Traceback" not in r.stderr and "BrokenPipe" not in r.stderr, r.stderr


def test_view_html_with_a_seed_names_the_file(finished, tmp_path):
    r = feltool("view", str(finished), "--html", "--seed", "1")
    assert r.returncode == 0, r.stderr
    assert Path(r.stdout.strip()) == finished / "rollout-seed1.html"
    assert (finished / "rollout-seed1.html").stat().st_size > 10_000
    assert not (finished / "rollout.html").exists()
    (finished / "rollout-seed1.html").unlink()  # the module's other tests compare the tree


def test_every_command_and_option_has_help_and_an_example():
    from feltool.cli.main import build_parser

    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert {"run", "sweep", "view", "check", "robots", "inspect", "plot"} <= set(commands)
    for name, sub in commands.items():
        assert sub.description and "examples:" in (sub.epilog or ""), name
        assert f"feltool {name}" in sub.epilog, name
        for action in sub._actions:
            assert action.help, f"feltool {name} {action.option_strings or action.dest}"
    for name in ("run", "sweep"):
        assert "130" in commands[name].epilog and "exit codes" in commands[name].epilog
