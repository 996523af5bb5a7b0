"""Sweeps: the product of a grid over seeds, on the local pool and on a real Dask cluster
(scheduler and two worker processes on loopback), including a worker killed mid-sweep."""

from __future__ import annotations

import csv
import os
import signal
import threading
import time

import pytest

from feltool.runs.sweep import grid_points, parse_grid, run_sweep

from .conftest import CONFIGS, feltool

STANDARD = str(CONFIGS / "two_link_standard.yaml")
GRID = ["--grid", "learning.update=gradient", "--grid", "learning.rates.weights=33.687,67.374",
        "--grid", "joints.elbow.gains.kp=50,100"]  # (per sample: 0.1, 0.2)


def rows(path):
    return list(csv.DictReader(open(path)))


def test_grid_parsing_and_product():
    grid = parse_grid(["a.b=1,2", "c=x,0.5"])
    assert grid == {"a.b": [1, 2], "c": ["x", 0.5]}
    assert grid_points(grid) == [{"a.b": 1, "c": "x"}, {"a.b": 1, "c": 0.5},
                                 {"a.b": 2, "c": "x"}, {"a.b": 2, "c": 0.5}]


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "local"
    res = feltool("sweep", STANDARD, *GRID, "--seeds", "0-1", "--cycles", "30", "--out", str(out),
                  "--workers", "2")
    assert res.returncode == 0, res.stderr
    return out


def test_local_sweep_writes_points_csv_and_figure(local_sweep):
    table = rows(local_sweep / "sweep.csv")
    assert len(table) == 4 * 2
    assert {r["learning.rates.weights"] for r in table} == {"33.687", "67.374"}
    for col in ("point", "seed", "fb_initial", "fb_final", "converged_cycle", "diverged"):
        assert col in table[0]
    for i in range(4):
        assert (local_sweep / f"point-{i:03d}" / "metrics.csv").is_file()
    assert (local_sweep / "figures" / "sweep.png").stat().st_size > 5000
    # the faster learning rate has learned more after 30 cycles, at every gain and seed
    final = {(r["learning.rates.weights"], r["joints.elbow.gains.kp"], r["seed"]): float(r["fb_final"])
             for r in table}
    for (rate, kp, seed), fb in final.items():
        if rate == "67.374":
            assert fb < final[("33.687", kp, seed)]


def test_bad_grid_value_fails_before_running(tmp_path):
    res = feltool("sweep", STANDARD, "--grid", "sim.rate_hz=100,-5", "--out", str(tmp_path / "s"))
    assert res.returncode == 2
    assert "sim.rate_hz" in res.stderr and "sweep point 1" in res.stderr
    assert not (tmp_path / "s").exists()


def test_sweep_block_in_yaml(tmp_path):
    config = tmp_path / "swept.yaml"
    config.write_text(open(STANDARD).read() + "sweep:\n  grid:\n    learning.rates.goal: [1.0e-5, 2.0e-5]\n")
    assert feltool("check", str(config)).returncode == 0
    out = run_sweep(config, None, tmp_path / "out", seeds=[0], cycles=3, workers=1,
                    show_progress=False)
    assert [r["learning.rates.goal"] for r in out] == [1e-5, 2e-5]


distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as lc, Client(lc) as client:
        yield lc, client


def test_dask_sweep_equals_local_pool(cluster, local_sweep, tmp_path):
    lc, _ = cluster
    out = tmp_path / "dask"
    res = feltool("sweep", STANDARD, *GRID, "--seeds", "0-1", "--cycles", "30", "--out",
                  str(out), "--scheduler", lc.scheduler_address)
    assert res.returncode == 0, res.stderr
    assert rows(out / "sweep.csv") == rows(local_sweep / "sweep.csv")


def test_dask_sweep_survives_a_killed_worker(cluster, local_sweep, tmp_path):
    """A worker is killed (SIGKILL) while the scheduler has a sweep task processing on it and
    a checkpoint has been written (tasks are mid-run); the scheduler's own transition log
    shows each task it held go processing -> released by the lost worker's cleanup and later
    finish (processing -> memory), and sweep.csv has every row, equal to the local pool's. No
    sleep decides anything: the killer polls the scheduler (bound: 120 s)."""
    lc, client = cluster
    out = tmp_path / "killed"
    killed: dict = {}
    # the Python engine: tasks long enough to be killed mid-run (compiled they take ms); the
    # local pool's reference runs it too
    config = tmp_path / "standard_python.yaml"
    config.write_text(open(STANDARD).read() + "\nbackend: pinocchio\n")
    local = tmp_path / "local"
    run_sweep(config, parse_grid(GRID[1::2]), local, seeds=[0, 1], cycles=30, workers=2,
              show_progress=False)

    def kill_a_busy_worker():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            busy = {w: keys for w, keys in client.processing().items() if keys}
            started = list(out.glob("point-*/checkpoints/*.json"))
            if busy and started:
                address, keys = next(iter(busy.items()))
                pid = client.run(os.getpid, workers=[address])[address]
                killed.update(address=address, keys=list(keys), pid=pid)
                os.kill(pid, signal.SIGKILL)
                return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    run_sweep(config, parse_grid(GRID[1::2]), out, seeds=[0, 1], cycles=30,
              scheduler=lc.scheduler_address, show_progress=False)
    killer.join()
    assert killed.get("keys"), "no worker was seen holding a task mid-run"
    # The scheduler's record: a task that was processing on the killed worker ran again.
    for key in killed["keys"]:
        steps = [(t.start, t.finish, t.stimulus_id.rsplit("-", 1)[0])
                 for t in lc.scheduler.story(key)]
        lost = steps.index(("processing", "released", "handle-worker-cleanup"))
        assert ("processing", "memory", "task-finished") in steps[lost:], steps
    table = rows(out / "sweep.csv")
    assert len(table) == 8
    # same numbers as the local pool: a retried seed restarts from its checkpoint or from scratch
    assert table == rows(local / "sweep.csv")
