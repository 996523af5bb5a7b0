"""Faults of a user's ordinary week (issue 31), each as a user meets it: the exit code the docs
state, one line on stderr naming the file or field, no traceback, no death by a signal, and
nothing already written lost or mixed.

A full disk and a read-only place are real where the machine allows: a small tmpfs, mounted in
a private mount namespace (``unshare -rm``); the same faults are also injected at the writer,
so they are tested everywhere.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from feltool import build_experiment, load_experiment, run_seed
from feltool.errors import ConfigError, FeltoolError, InputError
from tests.conftest import ALLOWED_SKIP, ROOT

PY = sys.executable
ENV = dict(os.environ, PYTHONPATH=str(ROOT))
#: A short run on the Python engine (no compiled library: these tests leave the cache alone).
SHORT = ["--seeds", "0-1", "--cycles", "4", "--no-progress", "--set", "backend=pinocchio"]


def cli(*args: str, cwd: Path | None = None, env: dict | None = None,
        timeout: float = 600, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([PY, "-m", "feltool.cli", *args], capture_output=True, text=True,
                          cwd=cwd, env={**ENV, **(env or {})}, timeout=timeout, **kw)


def one_error(r: subprocess.CompletedProcess, code: int, *needles: str) -> str:
    """The run ended with ``code`` and one error line holding every needle, no traceback."""
    assert r.returncode == code, (r.returncode, r.stdout[-2000:], r.stderr[-3000:])
    assert "Traceback" not in r.stderr, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("feltool: error:")]
    others = [ln for ln in r.stderr.splitlines() if ln.strip() and not ln.startswith(
        ("feltool: error:", "feltool: note:", "feltool: warning:"))]
    assert len(errors) == 1 and not others, r.stderr
    for needle in needles:
        assert needle in errors[0], (needle, errors[0])
    return errors[0]


def tree(path: Path) -> dict[str, str]:
    """Every file under ``path`` with its content hash and mode."""
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest()
            + oct(p.stat().st_mode) for p in sorted(path.rglob("*")) if p.is_file()}


def _namespaces() -> bool:
    try:
        return shutil.which("unshare") is not None and subprocess.run(
            ["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt 2>/dev/null "
             "|| mount -t tmpfs -o size=64k tmpfs /tmp"], capture_output=True,
            timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


NAMESPACES = _namespaces()
needs_tmpfs = pytest.mark.skipif(
    not NAMESPACES, reason="this machine lets no user mount a tmpfs in a private namespace "
    f"(unshare -rm); the injected faults below test the same paths {ALLOWED_SKIP}")


def in_namespace(script: str, tmp: Path) -> None:
    """Run a shell script in a private mount namespace (its mounts vanish with it); ``$PY``
    runs Python with feltool importable."""
    r = subprocess.run(["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True,
                       env={**ENV, "PY": PY}, cwd=tmp, timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The uninterrupted run every recovered run must equal, byte for byte."""
    out = tmp_path_factory.mktemp("ref") / "run"
    r = cli("run", "two_link_standard", *SHORT, "--out", str(out))
    assert r.returncode == 0, r.stderr
    return out


# -- 1. a read-only place, no permission ---------------------------------------------------------

@needs_tmpfs
def test_out_in_a_read_only_place_exits_2_naming_it_and_writes_nothing(tmp_path):
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    in_namespace(f"""
        mount -t tmpfs -o size=1m tmpfs {mnt} && mkdir {mnt}/ro && mount -o remount,ro {mnt}
        "$PY" -m feltool.cli run two_link_standard {' '.join(SHORT)} --out {mnt}/ro/run \\
            > out.txt 2> err.txt; echo $? > rc.txt
        ls -A {mnt}/ro > left.txt
    """, tmp_path)
    r = subprocess.CompletedProcess([], int((tmp_path / "rc.txt").read_text()),
                                    (tmp_path / "out.txt").read_text(),
                                    (tmp_path / "err.txt").read_text())
    one_error(r, 2, f"{mnt}/ro/run", "read-only", "nothing of the run was written")
    assert (tmp_path / "left.txt").read_text() == ""


def test_out_where_permission_is_denied_exits_2_naming_it(tmp_path, monkeypatch, capsys):
    """A directory the user may not write. Root may write anywhere, so as root the OS's
    answer (EACCES, at the first directory the run makes) is injected."""
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    if os.geteuid() == 0:
        real = Path.mkdir

        def mkdir(self, *args, **kwargs):
            if str(self).startswith(str(locked)):
                raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(self))
            return real(self, *args, **kwargs)

        monkeypatch.setattr(Path, "mkdir", mkdir)
        code, _, err = _main(["run", "two_link_standard", *SHORT, "--out",
                              str(locked / "run")], capsys)
        r = subprocess.CompletedProcess([], code, "", err)
    else:
        r = cli("run", "two_link_standard", *SHORT, "--out", str(locked / "run"))
    one_error(r, 2, str(locked / "run"), "permission denied", "nothing of the run")
    assert list(locked.iterdir()) == []


# -- 2. a full disk ------------------------------------------------------------------------------

@needs_tmpfs
def test_a_full_disk_stops_the_run_keeps_its_seeds_and_resumes_to_the_same_numbers(
        tmp_path, reference):
    """A 100 kB tmpfs holds the run's first seeds but not all six; after the disk fills the
    run exits 1 naming the file, its finished seeds intact; with room made, --resume finishes
    it to the numbers of an uninterrupted run."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    args = ["two_link_standard", "--seeds", "0-5", "--cycles", "4", "--workers", "1",
            "--no-progress", "--set", "backend=pinocchio"]
    in_namespace(f"""
        mount -t tmpfs -o size=100k tmpfs {mnt}
        "$PY" -m feltool.cli run {' '.join(args)} --out {mnt}/run > 1.out 2> 1.err
        echo $? > 1.rc
        cp -a {mnt}/run kept
        mount -o remount,size=20m {mnt}
        "$PY" -m feltool.cli run --resume {mnt}/run --no-progress > 2.out 2> 2.err
        echo $? > 2.rc
        cp -a {mnt}/run resumed
    """, tmp_path)
    read = lambda name: (tmp_path / name).read_text()  # noqa: E731
    r = subprocess.CompletedProcess([], int(read("1.rc")), read("1.out"), read("1.err"))
    line = one_error(r, 1, f"{mnt}/run/", "no space left on the device", "kept:",
                     f"feltool run --resume {mnt}/run")
    kept = sorted(p.name for p in (tmp_path / "kept" / "seeds").glob("seed-*.json"))
    assert 1 <= len(kept) < 6 and f"kept: {len(kept)} of 6 seeds finished" in line
    for name in kept:  # what was written is whole
        json.loads((tmp_path / "kept" / "seeds" / name).read_text())
    assert not list((tmp_path / "kept").rglob(".*.tmp")), "a temporary file was left behind"
    assert int(read("2.rc")) == 0, read("2.err")
    full = tmp_path / "full"  # the same six seeds uninterrupted
    assert cli("run", *args, "--out", str(full)).returncode == 0
    assert (tmp_path / "resumed" / "metrics.csv").read_bytes() == \
        (full / "metrics.csv").read_bytes()


def _enospc_after(monkeypatch, n: int, match: str = "") -> dict:
    """Every write through feltool's one writer after the first ``n`` (of paths containing
    ``match``) fails as a full disk does: inside the write, with ENOSPC."""
    import feltool.files as files

    real, count = files.write_by, {"n": 0}

    def write_by(path, fill):
        if match in str(path):
            count["n"] += 1
            if count["n"] > n:
                def fail(fh):
                    fh.write(b"partial")
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                return real(path, fail)
        return real(path, fill)

    monkeypatch.setattr(files, "write_by", write_by)
    return count


def _main(args: list[str], capsys) -> tuple[int, str, str]:
    from feltool.cli.main import main

    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_a_full_disk_injected_at_the_writer_stops_the_run_and_it_resumes(
        tmp_path, monkeypatch, capsys, reference):
    out = tmp_path / "run"
    _enospc_after(monkeypatch, 1, "/seeds/")  # the second seed's record finds the disk full
    code, _, err = _main(["run", "two_link_standard", *SHORT, "--workers", "1", "--out",
                          str(out)], capsys)
    r = subprocess.CompletedProcess([], code, "", err)
    one_error(r, 1, f"{out}/seeds/seed-1.json", "no space left", "kept: 1 of 2 seeds",
              "make room, then continue with: feltool run --resume")
    assert sorted(p.name for p in (out / "seeds").iterdir()) == ["seed-0.json"]
    assert not list(out.rglob(".*.tmp")) and not (out / "summary.json").exists()
    from feltool.runs.runstate import run_state

    assert run_state(out) == "interrupted"
    monkeypatch.undo()
    code, _, err = _main(["run", "--resume", str(out), "--no-progress"], capsys)
    assert code == 0, err
    assert (out / "metrics.csv").read_bytes() == (reference / "metrics.csv").read_bytes()


def test_a_full_disk_while_the_run_directory_is_made_exits_2_and_leaves_nothing(
        tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    _enospc_after(monkeypatch, 0, "run.json")
    code, _, err = _main(["run", "two_link_standard", *SHORT, "--out", str(out)], capsys)
    one_error(subprocess.CompletedProcess([], code, "", err), 2, f"{out}/run.json",
              "no space left", "nothing of the run was written")
    assert not out.exists()


# -- 3. two runs in the same second --------------------------------------------------------------

def test_default_run_names_are_unique_within_a_second(tmp_path, monkeypatch):
    import datetime as dt
    from types import SimpleNamespace

    import feltool.runs.runstate as runstate
    from feltool.runs.runner import default_out_dir

    class Frozen(dt.datetime):
        @classmethod
        def now(cls, tz=None):
            return dt.datetime(2026, 1, 2, 3, 4, 5, tzinfo=tz)

    monkeypatch.setattr(runstate, "_dt", SimpleNamespace(datetime=Frozen, timezone=dt.timezone))
    made = [default_out_dir("arm", tmp_path) for _ in range(3)]
    assert [p.name for p in made] == ["arm-20260102T030405Z", "arm-20260102T030405Z-2",
                                      "arm-20260102T030405Z-3"]
    assert all(p.is_dir() for p in made)


def test_two_runs_started_together_without_out_both_finish(tmp_path):
    procs = [subprocess.Popen([PY, "-m", "feltool.cli", "run", "two_link_standard", *SHORT],
                              cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    results = [p.communicate(timeout=600) + (p.returncode,) for p in procs]
    assert all(rc == 0 for _, _, rc in results), results
    runs = sorted((tmp_path / "runs").iterdir())
    assert len(runs) == 2 and all((r / "summary.json").is_file() for r in runs)
    a, b = ((r / "metrics.csv").read_bytes() for r in runs)
    assert a == b  # one config, the same numbers, two directories


# -- 4. a cached library cut short ---------------------------------------------------------------

def test_a_cut_short_cached_library_is_rebuilt_not_loaded(tmp_path):
    if shutil.which(os.environ.get("CC") or "cc") is None and shutil.which("gcc") is None:
        pytest.skip("no C compiler: the compiled engine cannot be tested here")
    env = {"FELTOOL_CACHE": str(tmp_path / "cache")}
    args = ["run", "two_link_standard", "--seeds", "0", "--cycles", "12", "--no-progress",
            "--set", "backend=compiled"]
    first = cli(*args, "--out", str(tmp_path / "a"), env=env)
    assert first.returncode == 0, first.stderr
    (lib,) = (tmp_path / "cache" / "compiled").glob("*.so")
    record = json.loads(lib.with_name(lib.name + ".json").read_text())
    assert record["size"] == lib.stat().st_size
    assert record["sha256"] == hashlib.sha256(lib.read_bytes()).hexdigest()
    for damage in ("cut", "no record", "other bytes"):
        if damage == "cut":  # an interrupted copy of ~/.cache
            os.truncate(lib, lib.stat().st_size // 5)
        elif damage == "no record":
            lib.with_name(lib.name + ".json").unlink()
        else:
            data = bytearray(lib.read_bytes())
            data[len(data) // 2] ^= 0xFF
            lib.write_bytes(bytes(data))
        out = tmp_path / damage.replace(" ", "-")
        r = cli(*args, "--out", str(out), env=env)
        assert r.returncode == 0, (damage, r.returncode, r.stderr)  # 135 was SIGBUS
        assert (out / "metrics.csv").read_bytes() == (tmp_path / "a" / "metrics.csv").read_bytes()
        assert lib.stat().st_size == record["size"], damage  # rebuilt whole


# -- 5. a truncated seed record ------------------------------------------------------------------

def test_resume_with_a_truncated_seed_record_exits_2_naming_it(tmp_path, reference):
    run = tmp_path / "run"
    shutil.copytree(reference, run)
    record = run / "seeds" / "seed-1.json"
    record.write_bytes(record.read_bytes()[:100])  # an interrupted copy
    before = tree(run)
    r = cli("run", "--resume", str(run), "--cycles", "6", "--no-progress")
    one_error(r, 2, str(record), "damaged or unreadable", "not valid JSON", "seed 1 again")
    assert tree(run) == before


# -- 6. the robot of a resumed run ---------------------------------------------------------------

def _own_robot(folder: Path, mass: float = 1.0) -> Path:
    """A config whose robot is a URDF file of its own, beside it (``arm.yaml``, ``arm.urdf``)."""
    folder.mkdir(parents=True, exist_ok=True)
    urdf = (ROOT / "robots" / "two_link_arm.urdf").read_text()
    (folder / "arm.urdf").write_text(urdf.replace('<mass value="1.0"/>',
                                                  f'<mass value="{mass}"/>'))
    cfg = (ROOT / "configs" / "two_link_standard.yaml").read_text()
    (folder / "arm.yaml").write_text(cfg.replace("robot: two_link_arm", "robot: arm.urdf"))
    return folder / "arm.yaml"


def test_resume_after_the_urdf_was_edited_is_refused_naming_it(tmp_path):
    config = _own_robot(tmp_path / "cfg")
    run = tmp_path / "run"
    assert cli("run", str(config), *SHORT, "--out", str(run)).returncode == 0
    meta = json.loads((run / "run.json").read_text())
    (entry,) = [f for f in meta["inputs"]["files"] if f["role"] == "robot URDF"]
    urdf = (tmp_path / "cfg" / "arm.urdf").resolve()
    assert entry["path"] == str(urdf) and (run / entry["copy"]).read_bytes() == urdf.read_bytes()
    original = urdf.read_text()
    urdf.write_text(original.replace('<mass value="1.0"/>', '<mass value="1.3"/>', 1))
    before = tree(run)
    for args in (["run", "--resume", str(run), "--cycles", "6"],
                 ["run", str(config), "--resume", str(run), *SHORT]):
        r = cli(*args, "--no-progress")
        one_error(r, 2, f"--resume {run}", f"the robot URDF {urdf} changed since the run started",
                  f"the run's copy: {run / entry['copy']}")
        assert tree(run) == before
    urdf.write_text(original)  # restored: the resume goes on
    assert cli("run", "--resume", str(run), "--cycles", "6", "--no-progress").returncode == 0


def test_resume_from_another_working_directory_runs_the_recorded_robot(tmp_path):
    """Started as ``feltool run cfg/arm.yaml`` (relative), resumed from a directory without
    it, and from one holding another cfg/arm.yaml and arm.urdf (a 2 kg arm): each resume runs
    the robot the run started with, to the numbers of an uninterrupted run."""
    home, elsewhere, decoy = tmp_path / "home", tmp_path / "elsewhere", tmp_path / "decoy"
    _own_robot(home / "cfg")
    _own_robot(decoy / "cfg", mass=2.0)
    elsewhere.mkdir()
    for name, cwd in (("a", elsewhere), ("b", decoy)):
        run = home / name
        assert cli("run", "cfg/arm.yaml", *SHORT, "--out", name, cwd=home).returncode == 0
        r = cli("run", "--resume", str(run), "--cycles", "6", "--no-progress", cwd=cwd)
        assert r.returncode == 0, r.stderr
    ref = home / "ref"
    assert cli("run", "cfg/arm.yaml", *SHORT[:2], "--cycles", "6", *SHORT[4:], "--out", "ref",
               cwd=home).returncode == 0
    for name in ("a", "b"):
        assert (home / name / "metrics.csv").read_bytes() == (ref / "metrics.csv").read_bytes()


# -- 7. parameters that stop being numbers -------------------------------------------------------

def _nan_after(monkeypatch, cycle: int) -> None:
    """The learning update of ``cycle`` gives a NaN weight (as an ill-conditioned or huge step
    does), while the cycle itself stays finite."""
    import feltool.runs.seed as seed_module

    real = seed_module._cycle_runner

    def runner(exp, theta0, seed=0):
        run, count = real(exp, theta0, seed), {"n": 0}

        def wrapped(theta, q, v, plant, theta_m=None):
            out = run(theta, q, v, plant, theta_m)
            count["n"] += 1
            if count["n"] == cycle:
                out.theta_next = out.theta_next.copy()
                out.theta_next[exp.learner.learned[0]] = np.nan
            return out

        for name in ("motion", "extra_state", "restore_state", "rmp_states"):
            if hasattr(run, name):
                setattr(wrapped, name, getattr(run, name))
        return wrapped

    monkeypatch.setattr(seed_module, "_cycle_runner", runner)


@pytest.mark.parametrize("engine", ["pinocchio", "compiled"])
@pytest.mark.parametrize("cycle", [2, 4])
def test_non_finite_parameters_are_a_divergence_with_its_reason(engine, cycle, monkeypatch,
                                                                 tmp_path_factory):
    """Also in the last cycle (4 of 4), which no later cycle would catch."""
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
    _nan_after(monkeypatch, cycle)
    result = run_seed(load_experiment("two_link_standard", [f"backend={engine}",
                                                            "learning.safeguard=false"]), 0, 4)
    s = result.summary
    assert s["diverged"] and s["cycles"] == cycle - 1
    assert f"cycle {cycle}: the learning update after the cycle made elbow.weights (1 of 10) " \
           "non-finite" in s["diverged_reason"]
    assert all(np.isfinite(v).all() for v in result.params.values())


@pytest.mark.parametrize("engine", ["pinocchio", "compiled"])
def test_the_safeguard_undoes_a_non_finite_update_and_the_seed_goes_on(engine, monkeypatch,
                                                                       tmp_path_factory):
    """learning.safeguard (the default): the NaN step of cycle 2 is undone on the spot (cycle 3
    runs again from cycle 2's parameters and state, at half the step), counted, and the seed
    learns on to its last cycle with finite parameters."""
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))
    _nan_after(monkeypatch, 2)
    result = run_seed(load_experiment("two_link_standard", [f"backend={engine}"]), 0, 6)
    s = result.summary
    assert not s["diverged"] and s["cycles"] == 6
    assert s["rejected_steps"] == 1 and s["step_scale"] == 0.5 ** (1 + s["shortened_steps"])
    assert [row["rejected"] for row in result.rows] == [0, 1, 0, 0, 0, 0]
    fb = [row["fb_abs_mean_error"] for row in result.rows]
    assert fb[2] == pytest.approx(fb[1], rel=1e-9)  # cycle 3 is cycle 2 again
    assert fb[5] < fb[2]
    assert all(np.isfinite(v).all() for v in result.params.values())


def test_a_run_with_non_finite_parameters_exits_1_and_says_diverged(tmp_path, monkeypatch,
                                                                      capsys):
    _nan_after(monkeypatch, 3)
    out = tmp_path / "run"
    code, stdout, err = _main(["run", "two_link_standard", *SHORT, "--workers", "1", "--out",
                               str(out), "--set", "learning.safeguard=false"], capsys)
    assert code == 1 and "Traceback" not in err, err
    assert "DIVERGED: seed 0, cycle 3: the learning update" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["aggregate"]["n_diverged"] == 2
    assert "non-finite" in summary["seeds"][1]["failed_reason"]


# -- 8. the viewer ---------------------------------------------------------------------------------

def test_view_of_a_run_with_corrupt_traces_exits_2_naming_the_file(tmp_path, reference):
    run = tmp_path / "run"
    shutil.copytree(reference, run)
    traces = run / "traces" / "seed-0.npz"
    traces.write_bytes(traces.read_bytes()[:3000])
    for extra in (["--html"], ["--view-timeout", "0"]):
        r = cli("view", str(run), *extra)
        one_error(r, 2, str(traces), "damaged or unreadable", "npz")


@pytest.mark.parametrize("url", ["foo", "tcp://127.0.0.1", "tcp://127.0.0.1:99999",
                                 "http://127.0.0.1:7000/static/"])
def test_a_bad_zmq_url_is_one_clear_line_before_anything_runs(tmp_path, reference, url):
    t0 = time.monotonic()
    r = cli("view", str(reference), "--zmq-url", url, timeout=60)
    one_error(r, 2, "--zmq-url", repr(url), "tcp://HOST:PORT")
    r = cli("run", "two_link_standard", *SHORT, "--out", str(tmp_path / "run"), "--zmq-url",
            url, timeout=60)
    one_error(r, 2, "--zmq-url")
    assert not (tmp_path / "run").exists() and time.monotonic() - t0 < 60


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_zmq_url_where_no_meshcat_server_answers_fails_within_seconds(reference):
    with socket.socket() as listener:  # something holds the port, but speaks no meshcat
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        for port in (listener.getsockname()[1], _free_port()):
            t0 = time.monotonic()
            r = cli("view", str(reference), "--zmq-url", f"tcp://127.0.0.1:{port}", timeout=60)
            one_error(r, 1, f"--zmq-url tcp://127.0.0.1:{port}", "no meshcat server answered")
            assert time.monotonic() - t0 < 40


def test_view_with_the_default_ports_taken_starts_on_free_ones(reference):
    """The meshcat ports 6000 (ZMQ) and 7000 (web) held by something else: the viewer comes up
    on the next free ones and goes away at the end."""
    held = []
    for port in (6000, 7000):
        s = socket.socket()
        try:
            s.bind(("127.0.0.1", port))
            s.listen()
            held.append(s)
        except OSError:  # someone else holds it already: the case itself
            s.close()
    try:
        r = cli("view", str(reference), "--loops", "1", "--view-timeout", "1", timeout=120)
        assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
        url = next(ln for ln in r.stdout.splitlines() if "open http" in ln)
        assert ":7000/" not in url
    finally:
        for s in held:
            s.close()


def test_a_meshcat_server_that_never_starts_is_stopped_and_named(monkeypatch):
    import feltool.viewer.live as live
    from feltool.robot.robot import load_robot
    from feltool.viewer.scene import ViewerError

    robot = load_robot("two_link_arm")
    monkeypatch.setattr(live, "_SERVER_CODE", "import time\ntime.sleep(600)\n")
    t0 = time.monotonic()
    with pytest.raises(ViewerError, match=r"did not start within 2 s") as info:
        live.LiveViewer(robot, timeout=2, quiet=True)
    assert time.monotonic() - t0 < 15 and "\n" not in str(info.value)
    busy = "".join(f"Port: {p:d} in use, trying another...\\n" for p in range(7000, 7004))
    monkeypatch.setattr(live, "_SERVER_CODE", f"import sys\nsys.stderr.write('{busy}')\n"
                        "raise Exception('Could not find an available port in the range: "
                        "[7000, 7004)')\n")
    with pytest.raises(ViewerError) as info:
        live.LiveViewer(robot, timeout=20, quiet=True)
    text = str(info.value)
    assert "\n" not in text and "every port it tried 7000-7003 is in use (4 tried)" in text


# -- 9. the public API -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def arm():
    return load_experiment("two_link_standard", ["backend=pinocchio"])


@pytest.mark.parametrize("kwargs,needle", [
    ({"cycles": -5}, "cycles: must be from 1 to 10000000, got -5"),
    ({"cycles": 0}, "cycles: must be from 1 to 10000000, got 0"),
    ({"cycles": 2.5}, "cycles: must be a whole number, got 2.5"),
    ({"cycles": True}, "cycles: must be a whole number, got True"),
    ({"cycles": 10**8}, "cycles: must be from 1 to 10000000"),
    ({"seed": -1}, "seed: must be from 0 to 9223372036854775807, got -1"),
    ({"seed": "3"}, "seed: must be a whole number, got '3'"),
    ({"seed": 2**63}, "seed: must be from 0"),
])
def test_run_seed_checks_its_arguments_with_the_cli_bounds(arm, kwargs, needle):
    args = {"seed": 0, "cycles": 2, **kwargs}
    with pytest.raises(InputError) as info:
        run_seed(arm, args.pop("seed"), **args)
    assert needle in str(info.value)


def test_run_seed_runs_exactly_the_cycles_asked(arm):
    assert run_seed(arm, np.int64(1), np.int32(3)).summary["cycles"] == 3
    with pytest.raises(InputError, match="exp: must be an Experiment"):
        run_seed({"name": "x"}, 0, 2)


@pytest.mark.parametrize("raw", [[1, 2], "robot: two_link_arm", None, 5, b"x"])
def test_build_experiment_of_a_non_mapping_is_a_config_error(raw):
    with pytest.raises(ConfigError, match="a config must be a mapping of its fields"):
        build_experiment(raw)


def test_load_experiment_checks_its_overrides():
    with pytest.raises(InputError, match="overrides: must be a list"):
        load_experiment("two_link_standard", "sim.cycles=3")
    with pytest.raises(FeltoolError):
        load_experiment(42)
