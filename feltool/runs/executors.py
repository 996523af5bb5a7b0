"""Where seeds run: a local process pool (default) or a Dask distributed cluster.

A task is everything a worker needs to run one seed of one configuration: the raw config
mapping, where it came from, the seed, the number of cycles and where to checkpoint. Workers
build (and cache) the experiment themselves, so a Dask worker needs nothing but
``pip install feltool``; results (:class:`~feltool.experiment.SeedResult`) come back to the
submitting process, which writes every file.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
from collections import OrderedDict
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from feltool.errors import InputError
from feltool.runs.checkpoint import Checkpointer, install_stop_handlers
from feltool.runs.inputs import verify
from feltool.runs.stops import WorkerLost

#: The experiments built last in this process, by config (a sweep's or a robustness run's
#: points come one after the other: a few are enough to reuse each, and memory stays bounded)
_CACHE: OrderedDict[str, Any] = OrderedDict()
_CACHE_SIZE = 4
_PROGRESS: dict[str, Any] = {}


@dataclass(frozen=True)
class Task:
    """One seed of one configuration.

    Attributes:
        key: Identifies the configuration (a sweep point), echoed back with the result.
        raw: The raw config mapping (overrides applied).
        source: The config file it came from (for relative paths), or None.
        seed: The seed.
        cycles: Learning cycles.
        checkpoint_dir: Where to keep this seed's checkpoint, or None.
        checkpoint_every: Cycles between checkpoints.
        checkpoint_interval_s: Least time between checkpoints in [s].
        inputs: ``(role, path, sha256)`` of the files the run was built from
            (:func:`feltool.runs.inputs.fingerprints`): a worker that builds the experiment
            anew checks them, so a robot edited while a sweep runs stops it instead of mixing
            two robots.
    """

    key: str
    raw: dict
    source: str | None
    seed: int
    cycles: int
    checkpoint_dir: str | None = None
    checkpoint_every: int = 10
    checkpoint_interval_s: float = 0.0
    inputs: tuple = ()


def _ident(raw: dict, source) -> str:
    return json.dumps(raw, sort_keys=True, default=str) + str(source)


def remember(exp, raw: dict) -> None:
    """Keep a built experiment for the tasks of its config, so that this process and the
    workers forked from it reuse it (and its loaded compiled cycle) instead of rebuilding."""
    _keep(_ident(raw, str(Path(exp.source).resolve()) if exp.source else None), exp)


def _keep(ident: str, exp) -> None:
    _CACHE[ident] = exp
    _CACHE.move_to_end(ident)
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)


def run_task(task: Task, on_cycle: Callable | None = None, put: Callable | None = None):
    """Run one task in this process (a pool or Dask worker, or the main process).

    ``on_cycle`` is passed to :func:`~feltool.runs.seed.run_seed`; ``put`` receives progress
    items ``(key, seed, cycle, fb)`` (default: the worker's progress queue, if any)."""
    from feltool.runs.experiments import build_experiment
    from feltool.runs.seed import run_seed

    ident = _ident(task.raw, task.source)
    exp = _CACHE.get(ident)
    if exp is None:
        exp = build_experiment(task.raw, Path(task.source) if task.source else None)
        verify(task.inputs, f"seed {task.seed}" + (f" of point {task.key}"
                                                   if task.key != "run" else ""))
    _keep(ident, exp)
    if put is None and _PROGRESS.get("queue") is not None:
        put = _PROGRESS["queue"].put
    progress = None
    if put is not None:
        def progress(cycle: int, fb: float) -> None:
            put((task.key, task.seed, cycle, fb))
    checkpoint = (Checkpointer(Path(task.checkpoint_dir), task.seed, task.checkpoint_every,
                               task.checkpoint_interval_s)
                  if task.checkpoint_dir else None)
    return run_seed(exp, task.seed, task.cycles, progress, checkpoint, on_cycle)


def _init_local_worker(messages) -> None:
    install_stop_handlers()
    _PROGRESS["queue"] = messages


class LocalExecutor:
    """A process pool on this machine; per-cycle progress comes back through a queue."""

    def __init__(self, workers: int, messages=None):
        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        self.pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_local_worker,
                                        initargs=(messages,))

    def run(self, tasks: list[Task]) -> Iterator[tuple[Task, Any]]:
        """Submit every task now; the iterator yields ``(task, result)`` as tasks finish (a
        task's exception is raised when reached)."""
        futures = {self.pool.submit(run_task, t): t for t in tasks}

        def results():
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    try:
                        result = fut.result()
                    except BrokenProcessPool:
                        raise WorkerLost(
                            f"a worker process died while it ran seed {futures[fut].seed} "
                            "(killed by a signal, or by the system when memory ran out)"
                        ) from None
                    yield futures[fut], result

        return results()

    def interrupt(self) -> None:
        """Ask every worker to checkpoint and stop."""
        for pid in list(getattr(self.pool, "_processes", {}) or {}):
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


class DaskExecutor:
    """Tasks on a Dask distributed cluster; lost workers' tasks are retried by the scheduler."""

    def __init__(self, address: str):
        try:
            from distributed import Client
        except ImportError:
            raise InputError("--scheduler needs Dask: pip install 'feltool[dask]'") from None
        try:
            self.client = Client(address, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler: cannot reach a Dask scheduler at {address} "
                             f"({exc})") from None

    def run(self, tasks: list[Task]) -> Iterator[tuple[Task, Any]]:
        from distributed import as_completed

        futures = {self.client.submit(run_task, t, pure=False, retries=3): t for t in tasks}
        return ((futures[fut], fut.result()) for fut in as_completed(futures))

    def interrupt(self) -> None:
        pass

    def close(self) -> None:
        self.client.close()


def make_executor(scheduler: str | None, workers: int, messages=None):
    """A Dask executor for ``tcp://HOST:PORT`` (or ``$FELTOOL_SCHEDULER``), else a local pool."""
    scheduler = scheduler or os.environ.get("FELTOOL_SCHEDULER") or None
    if scheduler:
        return DaskExecutor(scheduler)
    return LocalExecutor(workers, messages)


def inline(tasks: list[Task], on_progress: Callable | None = None) -> Iterator[tuple[Task, Any]]:
    """Run tasks one after the other in this process."""
    for t in tasks:
        if on_progress is not None:
            _PROGRESS["queue"] = _Direct(on_progress)
        try:
            yield t, run_task(t)
        finally:
            _PROGRESS.pop("queue", None)


class _Direct:
    def __init__(self, fn):
        self.fn = fn

    def put(self, item) -> None:
        self.fn(*item)
