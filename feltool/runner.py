"""Run an experiment over many seeds in parallel and write the run directory."""

from __future__ import annotations

import datetime as _dt
import multiprocessing as mp
import os
import queue
import threading
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from feltool import __version__
from feltool.config import config_to_yaml
from feltool.experiment import (
    Experiment,
    SeedResult,
    build_experiment,
    run_seed,
    stabilization_errors,
)
from feltool.rundir import save_npz, write_json, write_metrics

_WORKER: dict[str, Any] = {}


def _init_worker(raw: dict, source: str | None, messages) -> None:
    _WORKER["exp"] = build_experiment(raw, Path(source) if source else None)
    _WORKER["queue"] = messages


def _run_in_worker(seed: int, cycles: int) -> SeedResult:
    messages = _WORKER["queue"]

    def progress(cycle: int, fb: float) -> None:
        messages.put((seed, cycle, fb))

    return run_seed(_WORKER["exp"], seed, cycles, progress)


def default_out_dir(name: str, root: Path = Path("runs")) -> Path:
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return root / f"{name}-{stamp}"


def run_experiment(exp: Experiment, raw: dict, out_dir: Path, seeds: list[int] | None = None,
                   cycles: int | None = None, workers: int | None = None,
                   show_progress: bool = True, figures: bool = True) -> dict[str, Any]:
    """Run every seed (in parallel on all cores), write the run directory, return the summary.

    Args:
        exp: The built experiment (used in-process when one worker suffices).
        raw: The raw config mapping it was built from (workers rebuild the experiment from it).
        out_dir: Run directory to create.
        seeds: Seeds to run; default the config's.
        cycles: Learning cycles per seed; default the config's.
        workers: Processes; default all cores (at most one per seed).
    """
    cfg = exp.config
    seeds = list(seeds if seeds is not None else cfg.seed_list)
    cycles = cycles or cfg.sim.cycles
    workers = max(1, min(workers or os.cpu_count() or 1, len(seeds)))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.yaml").write_text(config_to_yaml(cfg))

    bar = _progress_bar(len(seeds) * cycles, cfg.name, show_progress)
    last_fb: dict[int, float] = {}

    def on_progress(seed: int, cycle: int, fb: float) -> None:
        last_fb[seed] = fb
        if bar is not None:
            bar.update(1)
            bar.set_postfix(fb=f"{np.mean(list(last_fb.values())):.3g} N m", refresh=False)

    results: list[SeedResult] = []
    try:
        if workers == 1:
            for seed in seeds:
                results.append(run_seed(exp, seed, cycles,
                                        lambda c, fb, s=seed: on_progress(s, c, fb)))
        else:
            results = _run_pool(exp, raw, seeds, cycles, workers, on_progress)
    finally:
        if bar is not None:
            bar.close()
    results.sort(key=lambda r: r.seed)
    summary = write_results(exp, out_dir, results)
    if figures:
        from feltool.plots import draw_figures

        draw_figures(out_dir)
    return summary


def _run_pool(exp, raw, seeds, cycles, workers, on_progress) -> list[SeedResult]:
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    manager = ctx.Manager()
    messages = manager.Queue()
    stop = threading.Event()

    def pump() -> None:
        while not stop.is_set() or not messages.empty():
            try:
                on_progress(*messages.get(timeout=0.1))
            except queue.Empty:
                continue
            except (EOFError, OSError):
                return

    thread = threading.Thread(target=pump, daemon=True)
    thread.start()
    source = str(exp.source) if exp.source else None
    try:
        with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker,
                                 initargs=(raw, source, messages)) as pool:
            futures = [pool.submit(_run_in_worker, s, cycles) for s in seeds]
            return [f.result() for f in futures]
    finally:
        stop.set()
        thread.join(timeout=5)
        manager.shutdown()


def _progress_bar(total: int, name: str, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=name, unit="cycle", dynamic_ncols=True, leave=False)


def write_results(exp: Experiment, out_dir: Path, results: list[SeedResult]) -> dict[str, Any]:
    """Write metrics.csv, summary.json, params/ and traces/ for finished seeds."""
    rows = [row for r in results for row in r.rows]
    write_metrics(out_dir / "metrics.csv", rows)
    seeds = []
    for r in results:
        entry = dict(r.summary)
        if r.traces:
            entry["stabilization_error_max_last_cycle_rad"] = stabilization_errors(exp, r.traces)
        seeds.append(entry)
        save_npz(out_dir / "params" / f"seed-{r.seed}.npz", r.params)
        if r.traces:
            save_npz(out_dir / "traces" / f"seed-{r.seed}.npz",
                     {**r.traces, "joint_names": np.array(exp.joints),
                      "dt": np.array(exp.config.dt)})
    summary = {"config": exp.config.name, "feltool_version": __version__,
               "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
               "robot": exp.config.robot, "joints": exp.joints,
               "learned_joints": exp.learned_joints, "error_joints": exp.error_joints,
               "seeds": seeds, "aggregate": aggregate(seeds)}
    write_json(out_dir / "summary.json", summary)
    return summary


def aggregate(seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """Across-seed statistics of the per-seed summaries."""
    ok = [s for s in seeds if s["fb_initial"] is not None]
    conv = [s["converged_cycle"] for s in ok]
    ratios = [s["fb_ratio"] for s in ok if s["fb_ratio"] is not None]
    steps = [s["steps_per_s"] for s in ok if s["steps_per_s"]]
    return {
        "n_seeds": len(seeds),
        "n_diverged": sum(bool(s["diverged"]) for s in seeds),
        "n_converged": sum(c is not None for c in conv),
        "converged_cycle_mean": float(np.mean(conv)) if conv and None not in conv else None,
        "converged_cycle_max": max(conv) if conv and None not in conv else None,
        "fb_initial_mean": float(np.mean([s["fb_initial"] for s in ok])) if ok else None,
        "fb_final_mean": float(np.mean([s["fb_final"] for s in ok])) if ok else None,
        "fb_ratio_max": max(ratios) if ratios else None,
        "steps_per_s_mean": float(np.mean(steps)) if steps else None,
    }
