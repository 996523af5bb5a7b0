"""Run an experiment over many seeds in parallel and write the run directory.

Finished seeds are saved as they arrive (``seeds/seed-N.json`` with their metric rows and
summary, ``params/`` and ``traces/``), running seeds checkpoint every few cycles, and the run's
own inputs are kept in ``run.json``; so ``feltool run --resume RUN_DIR`` continues an interrupted
run, skipping finished seeds, and gives the same files as an uninterrupted run.
"""

from __future__ import annotations

import datetime as _dt
import json
import multiprocessing as mp
import os
import queue
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from feltool._version import __version__
from feltool.config.files import apply_overrides, config_to_yaml
from feltool.config.memory import check_memory
from feltool.engines.compiled.engine import compiled_engine
from feltool.errors import InputError
from feltool.experiment.experiment import Experiment
from feltool.files import WriteError, remove_stale_temporaries
from feltool.runs.checkpoint import (
    Checkpointer,
    Interrupted,
    remove_empty,
    request_stop,
    reset_stop,
    stop_requested,
)
from feltool.runs.executors import Task, inline, make_executor, run_task
from feltool.runs.experiments import build_experiment
from feltool.runs.inputs import check_inputs, fingerprints, record_inputs
from feltool.runs.observers import stabilization_errors
from feltool.runs.rundir import (
    atomic_write,
    damaged,
    load_npz,
    read_json,
    save_npz,
    write_json,
    write_metrics,
)
from feltool.runs.runstate import (
    CLAIMED_DIRS,
    RunLock,
    config_differences,
    default_out_dir,  # noqa: F401  (feltool run's and sweep's, imported from here)
    read_meta,
    refuse_existing,
    set_state,
    source_path,
)
from feltool.runs.seed import SeedResult
from feltool.runs.stops import NOTHING_WRITTEN, WorkerLost, discard_new, kept, mark, stopped

CHECKPOINT_EVERY = 10  # cycles
CHECKPOINT_INTERVAL_S = 1.0  # [s] at least between a seed's checkpoints
#: [s] about what starting a pool of worker processes costs: seeds that take less in all run in
#: this process (the compiled engine's seeds often take milliseconds)
POOL_START_S = 1.0


def run_experiment(exp: Experiment, raw: dict, out_dir: Path, seeds: list[int] | None = None,
                   cycles: int | None = None, workers: int | None = None,
                   show_progress: bool = True, figures: bool = True,
                   scheduler: str | None = None,
                   on_cycle: Callable | None = None, resume: bool = False,
                   progress_lines: TextIO | None = None,
                   started: float | None = None) -> dict[str, Any]:
    """Run every seed (in parallel on all cores, or on a Dask cluster), write the run
    directory, return the summary.

    A run directory belongs to one command: ``out_dir`` must be new or empty, unless ``resume``
    continues a run of the same config, seeds and (at least as many) cycles; more cycles than
    before extend every finished seed from its final state. The directory is locked while the
    run writes it, and ``run.json`` records its state (:mod:`feltool.runs.runstate`).

    Args:
        exp: The built experiment (used in-process when one worker suffices).
        raw: The raw config mapping it was built from (workers rebuild the experiment from it).
        out_dir: Run directory to create (or to continue, with ``resume``).
        seeds: Seeds to run; default the config's.
        cycles: Learning cycles per seed; default the config's.
        workers: Local processes; default all cores (at most one per seed).
        scheduler: A Dask scheduler address (``tcp://HOST:8786``) to run the seeds there.
        on_cycle: Hook of :func:`~feltool.runs.seed.run_seed` for the first pending seed (the
            live viewer's stream); that seed then runs in this process, the others meanwhile in
            the pool.
        resume: Continue ``out_dir`` (an :class:`InputError` if its inputs differ).
        progress_lines: Without a progress bar, print a progress line per seed every few cycles
            to this stream (e.g. ``sys.stderr`` when it is not a terminal).
        started: When the run started, in [s] since the epoch (the CLI: its process's start);
            default now. summary.json's ``timing.wall_s`` counts from it.

    Raises:
        InputError: ``out_dir`` holds something and ``resume`` is false; the stored run differs
            from the one asked for; another process is writing ``out_dir``.
    """
    started = time.time() if started is None else started
    cfg = exp.config
    out_dir = Path(out_dir)
    seeds = list(seeds if seeds is not None else cfg.seed_list)
    cycles = cycles or cfg.sim.cycles
    if not resume:
        refuse_existing(out_dir, "run.json", f"feltool run --resume {out_dir}")
    parallel = min(workers or os.cpu_count() or 1, len(seeds))
    if parallel > 1:  # building checked one process; the pool runs this many at once
        try:
            check_memory(cfg, exp.robot.joint_names, exp.robot.model.njoints - 1,
                         str(exp.source) if exp.source else None, processes=parallel)
        except InputError:
            if out_dir in CLAIMED_DIRS:
                discard_new(out_dir)
            raise
    fresh = not resume  # refuse_existing found it empty: what is in it is this command's
    made = fresh and (not out_dir.exists() or out_dir in CLAIMED_DIRS)  # and the directory too
    try:
        lock = RunLock(out_dir).acquire()
    except WriteError as exc:
        raise exc.keeping(NOTHING_WRITTEN, 2) from None
    ours = False  # whether what is in out_dir is this command's (to remove if it fails here)
    try:
        try:
            done = None
            if resume:  # everything it reads is checked before anything changes
                meta = _check_resumable(out_dir, exp, seeds, cycles)
                done = _finished_seeds(out_dir, seeds, cycles)
                remove_stale_temporaries(out_dir)
                _record_cycles(out_dir, exp, meta, cycles)
            else:
                refuse_existing(out_dir, "run.json", f"feltool run --resume {out_dir}")  # a race
                ours = True
            compile_s = prepare_engine(exp, raw)
            if not resume:
                atomic_write(out_dir / "config.yaml",
                             config_to_yaml(cfg, exp.source.parent if exp.source else None))
                write_json(out_dir / "run.json", {
                    "source": source_path(exp), "raw": raw, "seeds": seeds, "cycles": cycles,
                    "config_fingerprint": _fingerprint(exp),
                    "inputs": record_inputs(exp, out_dir)})
            set_state(out_dir, "running", cycles=cycles)
        except BaseException as exc:
            lock.release()
            if ours:
                discard_new(out_dir, remove_dir=made)
            if isinstance(exc, WriteError):
                raise exc.keeping(NOTHING_WRITTEN if fresh else "the run is as it was", 2) \
                    from None
            raise
        try:
            summary = _run_seeds(exp, raw, out_dir, seeds, cycles, workers, show_progress,
                                 scheduler, on_cycle, progress_lines,
                                 {"started": started, "compile_s": compile_s}, done)
            set_state(out_dir, "complete", outcome=_outcome(summary))
        except Interrupted:
            mark(out_dir, "interrupted")
            raise
        except (WriteError, WorkerLost) as exc:
            mark(out_dir, "interrupted")
            raise stopped(exc, kept(out_dir, len(seeds), f"feltool run --resume {out_dir}")) \
                from None
        except BaseException:
            mark(out_dir, "failed")
            raise
    finally:
        lock.release()
    if figures:
        from feltool.runs.plots import draw_figures

        try:
            draw_figures(out_dir)
        except WriteError as exc:
            raise exc.keeping(f"the run is complete; draw its figures again with: feltool plot "
                              f"{out_dir}", 1) from None
    return summary


def prepare_engine(exp: Experiment, raw: dict) -> float:
    """Build the experiment's cycle engine in this process before any seed runs (the compiled
    engine: generate and compile its C code, or load it from the cache), so that worker
    processes forked from here share it; returns the time it took in [s]."""
    from feltool.runs.executors import remember

    t0 = time.perf_counter()
    if exp.engine == "compiled":
        compiled_engine(exp)
    remember(exp, raw)
    return time.perf_counter() - t0


def _run_seeds(exp: Experiment, raw: dict, out_dir: Path, seeds: list[int], cycles: int,
               workers, show_progress, scheduler, on_cycle, progress_lines,
               timing: dict | None = None, finished: dict | None = None) -> dict[str, Any]:
    if finished is None:
        finished = _finished_seeds(out_dir, seeds, cycles)
    inputs = fingerprints(read_meta(out_dir / "run.json").get("inputs"))
    tasks = [Task("run", raw, source_path(exp), s, cycles, str(out_dir / "checkpoints"),
                  CHECKPOINT_EVERY, CHECKPOINT_INTERVAL_S, inputs)
             for s in seeds if s not in finished]
    results = dict(finished)
    batches = [tasks]
    if exp.engine == "compiled" and len(tasks) > 1 and on_cycle is None and not scheduler \
            and (workers or 2) > 1:
        batches = [tasks[:1], tasks[1:]]  # the first seed here: is a pool worth its start?
    for b, batch in enumerate(batches):
        t0 = time.perf_counter()
        for task, result in execute(batch, workers if len(batches) == 1 or b else 1, scheduler,
                                    exp.config.name, cycles * len(batch), show_progress,
                                    on_cycle, progress_lines, cycles):
            save_seed_result(exp, out_dir, result)
            results[task.seed] = result
        if b == 0 and len(batches) > 1 and \
                (time.perf_counter() - t0) * len(batches[1]) < POOL_START_S:
            workers = 1  # the other seeds take less time than starting workers would
    remove_empty(out_dir / "checkpoints")
    return write_results(exp, out_dir, [results[s] for s in seeds], timing)


def _finished_seeds(out_dir: Path, seeds: list[int], cycles: int) -> dict[int, SeedResult]:
    """The seeds saved as finished (with the cycles asked); every seed record and checkpoint
    is read, so a damaged one is named before the run changes anything."""
    finished = {s: r for s in seeds if (r := load_seed_result(out_dir, s)) is not None
                and not _needs_more_cycles(r, cycles)}
    for s in seeds:
        if s not in finished:
            Checkpointer(out_dir / "checkpoints", s).load()
    return finished


def _needs_more_cycles(result: SeedResult, cycles: int) -> bool:
    """A finished seed that ran fewer cycles than now asked for (and did not stop early)."""
    s = result.summary
    return not s["diverged"] and s.get("cycles_planned", s["cycles"]) < cycles


def _fingerprint(exp: Experiment) -> dict[str, Any]:
    """The resolved config without what a resume may change (cycles) or checks apart (seeds)."""
    dump = exp.config.model_dump(mode="json")
    dump.pop("seeds", None)
    dump.get("sim", {}).pop("cycles", None)
    return json.loads(json.dumps(dump))


def _check_resumable(run_dir: Path, exp: Experiment, seeds: list[int],
                     cycles: int) -> dict[str, Any]:
    """Refuse to continue ``run_dir`` with another config, other seeds, fewer cycles or other
    input files; its ``run.json``."""
    meta_path = run_dir / "run.json"
    if not meta_path.is_file():
        raise InputError(f"{run_dir}: no run.json, so not a feltool run directory to resume")
    meta = read_meta(meta_path, REQUIRED)  # no other process runs it: the caller holds its lock
    check_inputs(meta.get("inputs"), run_dir, f"--resume {run_dir}")
    stored = meta.get("config_fingerprint")
    if stored is None:  # a directory from before fingerprints: rebuild its config
        stored = _fingerprint(build_experiment(meta["raw"], Path(meta["source"])
                                               if meta["source"] else None))
    problems = config_differences(stored, _fingerprint(exp))
    if list(meta["seeds"]) != list(seeds):
        problems.append(f"seeds: {_seed_text(meta['seeds'])} -> {_seed_text(seeds)}")
    if cycles < meta["cycles"]:
        problems.append(f"sim.cycles: {meta['cycles']} -> {cycles} (a resume may add cycles, "
                        "not remove them)")
    if problems:
        raise InputError(f"--resume {run_dir}: the stored run differs from the one asked for; "
                         "resume it as it is (feltool run --resume RUN_DIR) or start a new run:\n  "
                         + "\n  ".join(problems[:12])
                         + (f"\n  ... ({len(problems) - 12} more)" if len(problems) > 12 else ""))
    return meta


def _record_cycles(run_dir: Path, exp: Experiment, meta: dict, cycles: int) -> None:
    """A resume that adds cycles: the stored config says so too."""
    if cycles != meta["cycles"]:
        cfg = exp.config.model_copy(update={"sim": exp.config.sim.model_copy(
            update={"cycles": cycles})})
        atomic_write(run_dir / "config.yaml",
                     config_to_yaml(cfg, exp.source.parent if exp.source else None))
        meta["cycles"] = cycles
        meta["raw"] = apply_overrides(meta["raw"], [f"sim.cycles={cycles}"])
        write_json(run_dir / "run.json", meta)


def _seed_text(seeds: list[int]) -> str:
    return str(seeds) if len(seeds) <= 8 else f"[{seeds[0]}, ..., {seeds[-1]}] ({len(seeds)})"


def _outcome(summary: dict[str, Any]) -> dict[str, int]:
    agg = summary["aggregate"]
    return {"seeds": agg["n_seeds"], "diverged": agg["n_diverged"], "failed": agg["n_failed"]}


def resume_run(run_dir: Path, workers: int | None = None, show_progress: bool = True,
               scheduler: str | None = None, cycles: int | None = None,
               on_cycle: Callable | None = None,
               progress_lines: TextIO | None = None) -> dict[str, Any]:
    """Continue an interrupted run where it stopped, with its own stored config (``cycles``
    may extend it)."""
    run_dir = Path(run_dir)
    exp, meta = stored_experiment(run_dir)
    return run_experiment(exp, meta["raw"], run_dir, meta["seeds"], cycles or meta["cycles"],
                          workers, show_progress, scheduler=scheduler, on_cycle=on_cycle,
                          resume=True, progress_lines=progress_lines)


def stored_experiment(run_dir: Path) -> tuple[Experiment, dict[str, Any]]:
    """The experiment a run directory was made with, and its ``run.json`` (its recorded
    inputs checked first: a changed robot is refused, naming it)."""
    meta_path = Path(run_dir) / "run.json"
    if not meta_path.is_file():
        raise InputError(f"{run_dir}: no run.json, so not a feltool run directory to resume")
    meta = read_meta(meta_path, REQUIRED)
    check_inputs(meta.get("inputs"), Path(run_dir), f"--resume {run_dir}")
    source = Path(meta["source"]) if meta["source"] else None
    return build_experiment(meta["raw"], source), meta


#: What ``run.json`` must hold for a resume.
REQUIRED = ("source", "raw", "seeds", "cycles")


def execute(tasks: list[Task], workers: int | None, scheduler: str | None, name: str,
            total_cycles: int, show_progress: bool, on_cycle: Callable | None = None,
            progress_lines: TextIO | None = None, cycles: int | None = None):
    """Run tasks inline, in a local pool or on Dask; yield ``(task, result)`` as they finish.

    With ``on_cycle``, the first task runs in this process with that hook while the others
    run in the pool. SIGINT/SIGTERM make running seeds checkpoint and stop; then
    :class:`Interrupted` is raised. Progress: a bar when ``show_progress``, else with
    ``progress_lines`` one line per task every ``cycles / 10`` cycles (at least every 10).
    """
    if not tasks:
        return
    in_main = tasks[0] if on_cycle is not None else None
    if in_main is not None:
        tasks = tasks[1:]
    workers = max(1, min(workers or os.cpu_count() or 1, max(1, len(tasks))))
    bar = _progress_bar(total_cycles, name, show_progress)
    latest: dict[tuple, float] = {}
    every = max(1, min(10, (cycles or 100) // 10))

    def on_progress(key, seed, cycle, fb) -> None:
        latest[(key, seed)] = fb
        if bar is not None:
            bar.update(1)
            bar.set_postfix(fb=f"{np.mean(list(latest.values())):.3g} N m", refresh=False)
        elif progress_lines is not None and (cycle % every == 0 or cycle == cycles):
            where = f"{name} " + (f"point {key} " if key != "run" else "")
            of = f"/{cycles}" if cycles else ""
            print(f"{where}seed {seed}: cycle {cycle}{of}, error feedback {fb:.4g} N m",
                  file=progress_lines, flush=True)

    reset_stop()
    executor, manager, pump = None, None, None
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def on_signal(signum, _frame):
        request_stop(signum)
        if executor is not None:
            executor.interrupt()

    try:
        for sig in previous:
            signal.signal(sig, on_signal)
        if not tasks:
            stream = iter(())
        elif workers == 1 and not (scheduler or os.environ.get("FELTOOL_SCHEDULER")) \
                and in_main is None:
            stream = inline(tasks, on_progress)
        else:
            messages = None
            if not (scheduler or os.environ.get("FELTOOL_SCHEDULER")):
                ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
                manager = ctx.Manager()
                messages = manager.Queue()
                pump = _Pump(messages, on_progress)
            executor = make_executor(scheduler, workers, messages)
            stream = executor.run(tasks)
        interrupted = None
        if in_main is not None:
            try:
                yield in_main, run_task(in_main, on_cycle, _progress_to(on_progress))
            except Interrupted as exc:
                interrupted = exc
        for item in _guarded(stream):
            if isinstance(item, Interrupted):
                interrupted = item
                continue
            yield item
        if interrupted is not None or stop_requested():
            raise Interrupted("stopped on request; finished seeds and checkpoints are saved")
    except BaseException:  # a fault here (a full disk, a lost worker): the others stop too
        if executor is not None:
            executor.interrupt()
        raise
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if executor is not None:
            executor.close()
        if pump is not None:
            pump.stop()
        if manager is not None:
            manager.shutdown()
        if bar is not None:
            bar.close()


def _progress_to(on_progress: Callable) -> Callable:
    def put(item) -> None:
        on_progress(*item)

    return put


def _guarded(stream):
    """Pass results through; turn a seed's Interrupted into a value so others still finish."""
    while True:
        try:
            yield next(stream)
        except StopIteration:
            return
        except Interrupted as exc:
            yield exc


class _Pump:
    """Forwards progress messages from worker processes to a callback, on a thread."""

    def __init__(self, messages, callback):
        self.messages, self.callback = messages, callback
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.is_set() or not self.messages.empty():
            try:
                self.callback(*self.messages.get(timeout=0.1))
            except queue.Empty:
                continue
            except (EOFError, OSError, BrokenPipeError):
                return

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(timeout=5)


def _progress_bar(total: int, name: str, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=name, unit="cycle", dynamic_ncols=True, leave=False)


def save_seed_result(exp: Experiment, out_dir: Path, r: SeedResult) -> None:
    """Write one finished seed's files (params, traces, then the record that marks it done)."""
    save_npz(out_dir / "params" / f"seed-{r.seed}.npz", r.params)
    if r.traces:
        save_npz(out_dir / "traces" / f"seed-{r.seed}.npz",
                 {**r.traces, "joint_names": np.array(exp.joints), "dt": np.array(exp.config.dt)})
    entry = dict(r.summary)
    if r.traces:
        entry["stabilization_error_max_last_cycle_rad"] = stabilization_errors(exp, r.traces)
    write_json(out_dir / "seeds" / f"seed-{r.seed}.json", {"rows": r.rows, "summary": entry},
               compact=True)


def load_seed_result(out_dir: Path, seed: int) -> SeedResult | None:
    """A seed saved by :func:`save_seed_result`, or None if it has not finished."""
    record = out_dir / "seeds" / f"seed-{seed}.json"
    if not record.is_file():
        return None
    hint = (f"move it away to run seed {seed} again (its params/ and traces/ files go with it)")
    data = read_json(record, hint)
    if not isinstance(data.get("rows"), list) or not isinstance(data.get("summary"), dict) \
            or data["summary"].get("seed") != seed:
        raise damaged(record, f"not the record of seed {seed}", hint)
    traces_path = out_dir / "traces" / f"seed-{seed}.npz"
    traces = {k: v for k, v in load_npz(traces_path, hint).items()
              if k not in ("joint_names", "dt")} if traces_path.is_file() else {}
    return SeedResult(seed, data["rows"], data["summary"],
                      load_npz(out_dir / "params" / f"seed-{seed}.npz", hint), traces)


def write_results(exp: Experiment, out_dir: Path, results: list[SeedResult],
                  timing: dict | None = None) -> dict[str, Any]:
    """Write metrics.csv and summary.json from finished seeds (in the given order);
    ``timing``: ``{"started": epoch [s], "compile_s": [s]}`` of the run (see
    :func:`run_timing`)."""
    write_metrics(out_dir / "metrics.csv", [row for r in results for row in r.rows])
    seeds = []
    for r in results:
        entry = dict(r.summary)
        if r.traces and "stabilization_error_max_last_cycle_rad" not in entry:
            entry["stabilization_error_max_last_cycle_rad"] = stabilization_errors(exp, r.traces)
        entry["failed_reason"] = success_failure(exp, entry)
        entry["learned"] = entry["failed_reason"] is None
        seeds.append(entry)
    summary = {"config": exp.config.name, "feltool_version": __version__,
               "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
               "robot": exp.config.robot_source, "joints": exp.joints,
               "learned_joints": exp.learned_joints, "error_joints": exp.error_joints,
               "demo_fit_rms_rad": exp.demo_fit_rms,
               "engine": exp.engine, "seeds": seeds, "aggregate": aggregate(seeds)}
    if timing is not None:
        summary["timing"] = run_timing(seeds, timing["started"], timing["compile_s"])
    write_json(out_dir / "summary.json", summary)
    return summary


def run_timing(seeds: list[dict[str, Any]], started: float, compile_s: float) -> dict[str, Any]:
    """The run's honest figures: ``steps_per_s`` of the learning loop alone (every seed's
    control steps over the time spent inside its cycles, per core: process start, imports,
    building, compiling and the observers of each cycle excluded), ``compile_s`` (building the
    cycle engine before the seeds: for the compiled engine, generating and compiling its C code
    or loading it from the cache) and ``wall_s``, the whole run from ``started`` (the process's
    start, for the CLI) to writing summary.json, in [s]."""
    loop = sum(s.get("loop_s") or 0.0 for s in seeds)
    steps = sum(s.get("steps") or 0 for s in seeds)
    return {"steps_per_s": round(steps / loop, 1) if loop > 0 else None, "steps": steps,
            "loop_s": round(loop, 6), "compile_s": round(compile_s, 4),
            "wall_s": round(time.time() - started, 4)}


def success_failure(exp: Experiment, entry: dict[str, Any]) -> str | None:
    """Why a finished seed did not learn as the config's ``success:`` asks, or None."""
    if entry["diverged"]:
        return entry.get("diverged_reason") or "diverged"
    crit = exp.config.success
    key, what = ("fb_ratio", "fb_final / fb_initial") if crit.ratio_from == "first" else \
        ("fb_ratio_change", f"fb_final / fb of the world's change (cycle "
                            f"{exp.config.world_change_cycle})")
    if crit.fb_ratio_max is not None and key == "fb_ratio_change" and "change_cycle" not in entry:
        return (f"the seed ended after {entry['cycles']} cycles, before the world's change at "
                f"cycle {exp.config.world_change_cycle} that success.ratio_from: change measures from")
    if crit.fb_ratio_max is not None and (entry.get(key) is None
                                          or entry[key] > crit.fb_ratio_max):
        ratio = "none" if entry.get(key) is None else f"{entry[key]:.4g}"
        return f"{what} = {ratio} > success.fb_ratio_max = {crit.fb_ratio_max:g}"
    if crit.converged and entry["converged_cycle"] is None:
        return "never stayed below 5 % of the initial feedback (success.converged: true)"
    return None


def aggregate(seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """Across-seed statistics of the per-seed summaries."""
    ok = [s for s in seeds if s["fb_initial"] is not None]
    conv = [s["converged_cycle"] for s in ok]
    ratios = [s["fb_ratio"] for s in ok if s["fb_ratio"] is not None]
    steps = [s["steps_per_s"] for s in ok if s["steps_per_s"]]
    return {
        "n_seeds": len(seeds),
        "n_diverged": sum(bool(s["diverged"]) for s in seeds),
        "n_failed": sum(not s.get("learned", not s["diverged"]) for s in seeds),
        "n_converged": sum(c is not None for c in conv),
        "converged_cycle_mean": float(np.mean(conv)) if conv and None not in conv else None,
        "converged_cycle_max": max(conv) if conv and None not in conv else None,
        "fb_initial_mean": float(np.mean([s["fb_initial"] for s in ok])) if ok else None,
        "fb_final_mean": float(np.mean([s["fb_final"] for s in ok])) if ok else None,
        "fb_ratio_max": max(ratios) if ratios else None,
        "steps_per_s_mean": float(np.mean(steps)) if steps else None,
        **_walking_aggregate(seeds),
    }


def _walking_aggregate(seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """Physical walkers: seeds that walked every step, and the not-walking kinds' counts."""
    walks = [s["walking"] for s in seeds if isinstance(s.get("walking"), dict)]
    if not walks:
        return {}
    kinds: dict[str, int] = {}
    for w in walks:
        if w["not_walking"]:
            kinds[w["not_walking"]] = kinds.get(w["not_walking"], 0) + 1
    return {"n_walked": sum(bool(w["walked"]) for w in walks),
            "n_not_walking": sum(kinds.values()), "not_walking": kinds}
