"""More faults in the spirit of issue 31 (docs/scaling.md lists them): each ends in its
documented exit code and one line naming the file, or is survived, and never loses or mixes
what was already written."""

from __future__ import annotations

import errno
import json
import os
import pickle
import resource
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from feltool.files import WriteError
from feltool.runs.runstate import run_state
from tests.test_faults import (
    ENV,
    PY,
    SHORT,
    _enospc_after,
    _main,
    _own_robot,
    cli,
    in_namespace,
    needs_tmpfs,
    one_error,
    tree,
)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "run"
    r = cli("run", "two_link_standard", *SHORT, "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out


def _copy(run: Path, to: Path) -> Path:
    shutil.copytree(run, to)
    return to


def _sweep(config: Path, out: Path) -> list[str]:
    return ["sweep", str(config), "--grid", "learning.rates.weights=0.1,0.2", "--seeds", "0",
            "--cycles", "3", "--workers", "1", "--no-progress", "--out", str(out)]


# -- 1, 2. a URDF or a config edited under a running sweep ---------------------------------------

def _edit_after_first_seed(monkeypatch, path: Path, old: str, new: str) -> None:
    import feltool.runs.sweep as sweep

    real, done = sweep.save_seed_result, []

    def save(exp, out_dir, result):
        real(exp, out_dir, result)
        if not done:
            done.append(1)
            path.write_text(path.read_text().replace(old, new, 1))

    monkeypatch.setattr(sweep, "save_seed_result", save)


def test_a_urdf_edited_under_a_running_sweep_stops_it_instead_of_mixing_robots(
        tmp_path, monkeypatch, capsys):
    config = _own_robot(tmp_path / "cfg")
    urdf = (tmp_path / "cfg" / "arm.urdf").resolve()
    original = urdf.read_text()
    _edit_after_first_seed(monkeypatch, urdf, '<mass value="1.0"/>', '<mass value="1.4"/>')
    out = tmp_path / "sweep"
    code, _, err = _main(_sweep(config, out), capsys)
    one_error(subprocess.CompletedProcess([], code, "", err), 2, "seed 0 of point 1",
              f"the robot URDF {urdf} changed since the run started", "finished seeds are kept")
    assert (out / "point-000" / "seeds" / "seed-0.json").is_file()
    assert not (out / "point-001" / "seeds").exists()  # no seed ran the other robot
    monkeypatch.undo()
    r = cli("sweep", "--resume", str(out), "--no-progress")
    one_error(r, 2, f"the robot URDF {urdf} changed since the run started")
    urdf.write_text(original)
    assert cli("sweep", "--resume", str(out), "--no-progress").returncode == 0
    clean = tmp_path / "clean"
    assert cli(*_sweep(config, clean)).returncode == 0
    assert (out / "sweep.csv").read_bytes() == (clean / "sweep.csv").read_bytes()


def test_a_config_edited_under_a_running_sweep_changes_nothing(tmp_path, monkeypatch, capsys):
    """A sweep runs the config it stored when it started."""
    config = _own_robot(tmp_path / "cfg")
    _edit_after_first_seed(monkeypatch, config, "kp: 50.0", "kp: 5.0")
    out = tmp_path / "sweep"
    code, _, err = _main(_sweep(config, out), capsys)
    assert code == 0, err
    monkeypatch.undo()
    config.write_text(config.read_text().replace("kp: 5.0", "kp: 50.0"))
    clean = tmp_path / "clean"
    assert cli(*_sweep(config, clean)).returncode == 0
    assert (out / "sweep.csv").read_bytes() == (clean / "sweep.csv").read_bytes()


# -- 3. a worker killed while it checkpoints -----------------------------------------------------

def test_a_worker_killed_mid_run_stops_it_resumably_and_resume_gives_the_same_numbers(tmp_path):
    import psutil

    args = ["run", "two_link_standard", "--seeds", "0-1", "--cycles", "1000", "--workers", "2",
            "--no-progress", "--set", "backend=pinocchio"]
    out = tmp_path / "run"
    proc = subprocess.Popen([PY, "-m", "feltool.cli", *args, "--out", str(out)], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not list((out / "checkpoints").glob("seed-*.json")):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    children = sorted((c for c in psutil.Process(proc.pid).children()
                       if "resource_tracker" not in " ".join(c.cmdline())),
                      key=lambda c: c.create_time())
    assert len(children) >= 3  # the progress manager, then the pool's two workers
    children[-1].send_signal(signal.SIGKILL)  # as the OOM killer does
    stdout, stderr = proc.communicate(timeout=300)
    r = subprocess.CompletedProcess([], proc.returncode, stdout, stderr)
    one_error(r, 1, "a worker process died while it ran seed", "killed", "kept:",
              f"feltool run --resume {out}")
    assert run_state(out) == "interrupted"
    assert cli("run", "--resume", str(out), "--no-progress").returncode == 0
    ref = tmp_path / "ref"
    assert cli(*args, "--out", str(ref)).returncode == 0
    assert (out / "metrics.csv").read_bytes() == (ref / "metrics.csv").read_bytes()


# -- 4. spaces and non-ASCII characters ----------------------------------------------------------

def test_a_run_on_a_path_with_spaces_and_non_ascii_characters(tmp_path, reference):
    config = _own_robot(tmp_path / "mes configs ä ü" / "bras 1")
    run = tmp_path / "runs ü é" / "run 1 ✓"
    assert cli("run", str(config), *SHORT, "--out", str(run)).returncode == 0
    assert (run / "metrics.csv").read_bytes() == (reference / "metrics.csv").read_bytes()
    assert cli("run", "--resume", str(run), "--cycles", "5", "--no-progress").returncode == 0
    r = cli("plot", str(run))
    assert r.returncode == 0 and (run / "figures" / "feedback_convergence.png").is_file()
    r = cli("view", str(run), "--html")
    assert r.returncode == 0 and (run / "rollout.html").stat().st_size > 10_000, r.stderr


# -- 5. a read-only compiled-engine cache --------------------------------------------------------

def _compiler() -> None:
    if shutil.which(os.environ.get("CC") or "cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler: the compiled engine cannot be tested here")


COMPILED = ["run", "two_link_standard", "--seeds", "0", "--cycles", "12", "--no-progress",
            "--set", "backend=compiled"]


def test_a_cache_that_cannot_be_written_only_costs_time(tmp_path):
    _compiler()
    good = tmp_path / "good"
    assert cli(*COMPILED, "--out", str(good),
               env={"FELTOOL_CACHE": str(tmp_path / "cache")}).returncode == 0
    blocker = tmp_path / "a file"
    blocker.write_text("not a directory")
    r = cli(*COMPILED, "--out", str(tmp_path / "run"), env={"FELTOOL_CACHE": str(blocker)})
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "feltool: note: the compiled-engine cache" in r.stderr and "cannot be written" in \
        r.stderr and "compiled engine" in r.stdout
    assert (tmp_path / "run" / "metrics.csv").read_bytes() == (good / "metrics.csv").read_bytes()


@needs_tmpfs
def test_a_read_only_cache_only_costs_time(tmp_path):
    _compiler()
    mnt = tmp_path / "cache"
    mnt.mkdir()
    in_namespace(f"""
        mount -t tmpfs -o size=1m,ro tmpfs {mnt}
        FELTOOL_CACHE={mnt} "$PY" -m feltool.cli {' '.join(COMPILED)} --out {tmp_path}/run \\
            > out.txt 2> err.txt; echo $? > rc.txt
    """, tmp_path)
    err = (tmp_path / "err.txt").read_text()
    assert (tmp_path / "rc.txt").read_text().strip() == "0", err
    assert "read-only" in err and "Traceback" not in err


# -- 6. SIGKILL while summary.json is written ----------------------------------------------------

def test_a_run_killed_while_writing_its_summary_reads_interrupted_and_resumes(tmp_path,
                                                                             reference):
    """What a SIGKILL between creating and renaming summary.json's temporary file leaves: no
    summary.json, half a temporary file, state running, the lock of a dead process."""
    run = _copy(reference, tmp_path / "run")
    summary = (run / "summary.json").read_text()
    (run / "summary.json").unlink()
    (run / ".summary.json.k1ll3d.tmp").write_text(summary[: len(summary) // 2])
    meta = json.loads((run / "run.json").read_text())
    meta["state"] = "running"
    (run / "run.json").write_text(json.dumps(meta))
    dead = subprocess.run([PY, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    (run / ".lock").write_text(json.dumps({"pid": int(dead), "host": os.uname().nodename}))
    assert run_state(run) == "interrupted"
    one_error(cli("plot", str(run)), 2, "interrupted, not complete")
    r = cli("run", "--resume", str(run), "--no-progress")
    assert r.returncode == 0, r.stderr
    assert not list(run.rglob(".*.tmp")) and run_state(run) == "complete"
    old, new = json.loads(summary), json.loads((run / "summary.json").read_text())
    assert new["seeds"] == old["seeds"] and new["aggregate"] == old["aggregate"]


# -- 7. a file size limit ------------------------------------------------------------------------

def test_a_file_size_limit_is_one_line_not_a_signal(tmp_path):
    """Under ``ulimit -f`` (40 kB) the largest figure cannot be written: SIGXFSZ would kill
    the process (exit -25); the complete run is kept and the figure named."""
    out = tmp_path / "run"

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (40_000, 40_000))

    r = cli("run", "two_link_standard", *SHORT, "--out", str(out), preexec_fn=limit)
    one_error(r, 1, f"{out}/figures/", "file too large", "the run is complete",
              f"feltool plot {out}")
    assert run_state(out) == "complete" and (out / "summary.json").is_file()
    assert not list(out.rglob(".*.tmp"))


# -- 8. a damaged checkpoint ---------------------------------------------------------------------

def test_a_truncated_checkpoint_is_named_and_moving_it_away_resumes_to_the_same_numbers(
        tmp_path, reference):
    run = _copy(reference, tmp_path / "run")
    (run / "seeds" / "seed-1.json").unlink()  # seed 1 unfinished, from its checkpoint
    ckpt = run / "checkpoints" / "seed-1.npz"
    ckpt.write_bytes(ckpt.read_bytes()[:2000])
    before = tree(run)
    r = cli("run", "--resume", str(run), "--no-progress")
    one_error(r, 2, str(ckpt), "damaged or unreadable", "seed 1 again from its first cycle")
    assert tree(run) == before
    ckpt.unlink()
    (run / "checkpoints" / "seed-1.json").unlink()
    assert cli("run", "--resume", str(run), "--no-progress").returncode == 0
    assert (run / "metrics.csv").read_bytes() == (reference / "metrics.csv").read_bytes()


# -- 9, 10. a damaged run.json, metrics.csv, summary.json ----------------------------------------

def test_a_damaged_run_json_is_named_by_every_command_that_reads_it(tmp_path, reference):
    run = _copy(reference, tmp_path / "run")
    (run / "run.json").write_text('{"source": "/x", "raw": {')
    before = tree(run)
    for args in (["run", "--resume", str(run)], ["run", "two_link_standard", *SHORT, "--out",
                                                 str(run)], ["plot", str(run)]):
        one_error(cli(*args), 2, f"{run}/run.json", "damaged or unreadable")
    assert tree(run) == before


def test_damaged_metrics_and_summary_are_named_by_plot_and_view(tmp_path, reference):
    run = _copy(reference, tmp_path / "run")
    lines = (run / "metrics.csv").read_text().splitlines()
    (run / "metrics.csv").write_text("\n".join(lines[:3] + [lines[3][:20]]) + "\n")
    one_error(cli("plot", str(run)), 2, f"{run}/metrics.csv", "line 4")
    run = _copy(reference, tmp_path / "run2")
    (run / "summary.json").write_text("[1, 2]")
    one_error(cli("view", str(run), "--html"), 2, f"{run}/summary.json", "not a dict")


# -- 11, 12. the robot's URDF gone, a mesh changed -----------------------------------------------

def test_a_deleted_urdf_is_named_with_the_runs_copy(tmp_path):
    config = _own_robot(tmp_path / "cfg")
    run = tmp_path / "run"
    assert cli("run", str(config), *SHORT, "--out", str(run)).returncode == 0
    urdf = (tmp_path / "cfg" / "arm.urdf").resolve()
    copy = run / "inputs" / "arm.urdf"
    assert copy.read_bytes() == urdf.read_bytes()
    urdf.unlink()
    one_error(cli("run", "--resume", str(run), "--cycles", "6"), 2,
              f"the robot URDF {urdf} is missing", f"the run's copy: {copy}")
    shutil.copy(copy, urdf)  # as the message says
    assert cli("run", "--resume", str(run), "--cycles", "6", "--no-progress").returncode == 0


def test_a_changed_mesh_is_refused_naming_it(tmp_path):
    folder = tmp_path / "cfg"
    config = _own_robot(folder)
    urdf = folder / "arm.urdf"
    (folder / "meshes").mkdir()
    (folder / "meshes" / "upper.stl").write_text("solid upper\nendsolid upper\n")
    urdf.write_text(urdf.read_text().replace(
        '<geometry><cylinder radius="0.03" length="1.0"/></geometry>',
        '<geometry><mesh filename="meshes/upper.stl"/></geometry>', 1))
    run = tmp_path / "run"
    assert cli("run", str(config), *SHORT, "--out", str(run)).returncode == 0
    files = json.loads((run / "run.json").read_text())["inputs"]["files"]
    mesh = (folder / "meshes" / "upper.stl").resolve()
    assert [f["role"] for f in files if f["path"] == str(mesh)] == ["mesh of arm.urdf"]
    mesh.write_text("solid upper\nfacet\nendsolid upper\n")
    one_error(cli("run", "--resume", str(run), "--cycles", "6"), 2,
              f"the mesh of arm.urdf {mesh} changed since the run started")


# -- 13. a full disk while a checkpoint is written -----------------------------------------------

def test_a_full_disk_while_checkpointing_keeps_the_previous_checkpoint_whole(tmp_path,
                                                                            monkeypatch):
    from feltool.runs.checkpoint import Checkpointer

    ck = Checkpointer(tmp_path, seed=3)
    ck.save(10, {"x": np.arange(3.0)}, {"rows": [1]})
    _enospc_after(monkeypatch, 0, ".npz")  # the arrays' write fails
    with pytest.raises(WriteError, match="seed-3.npz: cannot write .no space left"):
        ck.save(20, {"x": np.arange(4.0)}, {"rows": [1, 2]})
    monkeypatch.undo()
    saved = Checkpointer(tmp_path, seed=3).load()
    assert saved["cycle"] == 10 and saved["x"].tolist() == [0.0, 1.0, 2.0]
    _enospc_after(monkeypatch, 0, ".json")  # the arrays written, the .json beside them not
    with pytest.raises(WriteError, match="seed-3.json"):
        ck.save(30, {"x": np.arange(5.0)}, {"rows": [1, 2, 3]})
    monkeypatch.undo()
    saved = Checkpointer(tmp_path, seed=3).load()
    assert saved["cycle"] == 30 and saved["rows"] == [1, 2, 3]
    assert not list(tmp_path.glob(".*.tmp"))


# -- 14. --out through a file --------------------------------------------------------------------

def test_out_through_a_file_is_named(tmp_path):
    (tmp_path / "notes").write_text("mine")
    one_error(cli("run", "two_link_standard", *SHORT, "--out", str(tmp_path / "notes" / "run")),
              2, f"{tmp_path}/notes", "not a directory")
    assert (tmp_path / "notes").read_text() == "mine"


# -- 15. the writer's error survives the trip from a worker --------------------------------------

def test_a_write_error_travels_back_from_a_worker_intact():
    exc = WriteError("/x/seed-1.npz", "no space left on the device", errno.ENOSPC,
                     "kept: 1 of 2", 1)
    back = pickle.loads(pickle.dumps(exc))
    assert (str(back), back.code, back.exit_code, back.ran_out) == \
        (str(exc), errno.ENOSPC, 1, True)
