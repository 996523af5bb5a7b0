"""Parameter sweeps: the product of a grid of config overrides, every point over every seed.

``feltool sweep CONFIG --grid learning.rates.gauss_newton=0.5,1.0 --grid joints.elbow.gains.kp=50,100``
(or a ``sweep: {grid: {...}}`` block in the YAML) writes::

    SWEEP_DIR/sweep.json          the grid, seeds, cycles and points (for --resume)
    SWEEP_DIR/point-000/ ...      one run directory per point (config.yaml, metrics.csv, ...)
    SWEEP_DIR/sweep.csv           one row per point x seed: parameters, fb_initial, fb_final,
                                  converged_cycle, diverged
    SWEEP_DIR/figures/sweep.png   converged cycle (and final feedback) over the grid

All (point, seed) tasks go to one executor (local process pool or Dask) so they run in parallel;
finished seeds are saved as they arrive, so ``--resume`` skips them.
"""

from __future__ import annotations

import copy
import csv
import io
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from feltool.bounds import MAX_SWEEP_POINTS
from feltool.config.files import apply_overrides, read_yaml
from feltool.config.safe_yaml import YamlBoundError, load_yaml
from feltool.errors import ConfigError, InputError
from feltool.files import WriteError, remove_stale_temporaries
from feltool.runs.checkpoint import Interrupted, remove_empty
from feltool.runs.executors import Task
from feltool.runs.experiments import build_experiment, resolve_config_path
from feltool.runs.inputs import check_inputs, fingerprints, input_files, record_files
from feltool.runs.rundir import atomic_write, write_by, write_json
from feltool.runs.runner import (
    CHECKPOINT_EVERY,
    CHECKPOINT_INTERVAL_S,
    CLAIMED_DIRS,
    execute,
    load_seed_result,
    save_seed_result,
    write_results,
)
from feltool.runs.runstate import RunLock, read_meta, refuse_existing, set_state
from feltool.runs.stops import NOTHING_WRITTEN, WorkerLost, discard_new, kept, mark, stopped


def parse_grid(specs: list[str]) -> dict[str, list]:
    """``["a.b=1,2", "c=x,y"]`` -> ``{"a.b": [1, 2], "c": ["x", "y"]}`` (values read as YAML)."""
    grid: dict[str, list] = {}
    for spec in specs:
        key, sep, values = spec.partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise InputError(f"--grid: cannot read '{spec}'; use a.b.c=V1,V2,...")
        try:
            grid[key] = [load_yaml(v.strip()) for v in values.split(",")]
        except (yaml.YAMLError, YamlBoundError) as exc:
            raise InputError(f"--grid: cannot read '{spec}' ({exc})") from None
    return grid


def check_grid_size(grid: Any, source: str | None = None) -> None:
    """A grid is a mapping of dotted paths to lists, with at most
    :data:`~feltool.bounds.MAX_SWEEP_POINTS` points (counted before any is built)."""
    if not isinstance(grid, dict) or not all(isinstance(v, list) for v in grid.values()):
        raise ConfigError([("sweep.grid", "must map dotted config paths to lists of values")],
                          source)
    count = math.prod(len(v) for v in grid.values())
    if count > MAX_SWEEP_POINTS:
        raise ConfigError([("sweep.grid", f"{count} points; a sweep may have at most "
                                          f"{MAX_SWEEP_POINTS}")], source)


def grid_points(grid: dict[str, list]) -> list[dict[str, Any]]:
    """Every combination of the grid's values, first key varying slowest."""
    keys = list(grid)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


def run_sweep(config: str | Path | None, grid: dict[str, list] | None, out_dir: Path,
              seeds: list[int] | None = None, cycles: int | None = None,
              workers: int | None = None, scheduler: str | None = None,
              show_progress: bool = True, resume: bool = False,
              progress_lines=None) -> list[dict[str, Any]]:
    """Run a sweep into a new ``out_dir``, or continue one with ``resume``; returns the rows
    of sweep.csv. Like a run directory, a sweep directory belongs to one command, is locked
    while written, and ``sweep.json`` records its state (:mod:`feltool.runs.runstate`)."""
    out_dir = Path(out_dir)
    meta_path = out_dir / "sweep.json"
    hint = f"feltool sweep --resume {out_dir}"
    made = not resume and (not out_dir.exists() or out_dir in CLAIMED_DIRS)
    if not resume:
        refuse_existing(out_dir, "sweep.json", hint)
        try:
            meta = _new_sweep(config, grid, seeds, cycles)  # bad input fails before any write
        except BaseException:
            discard_new(out_dir, remove_dir=made)
            raise
    elif not meta_path.is_file():
        raise InputError(f"{out_dir}: no sweep.json, so not a sweep directory to resume")
    try:
        lock = RunLock(out_dir).acquire()
    except WriteError as exc:
        raise exc.keeping(NOTHING_WRITTEN, 2) from None
    ours = False  # whether what is in out_dir is this command's (to remove if it fails here)
    try:
        try:
            if not resume:
                refuse_existing(out_dir, "sweep.json", hint)  # another process got here first
                ours = True
                write_json(meta_path, meta)
            else:
                remove_stale_temporaries(out_dir)
            set_state(out_dir, "running", "sweep.json")
        except BaseException as exc:
            lock.release()
            if ours:
                discard_new(out_dir, remove_dir=made)
            if isinstance(exc, WriteError):
                raise exc.keeping(NOTHING_WRITTEN if not resume else "the sweep is as it was",
                                  2) from None
            raise
        try:
            rows = _sweep_points(out_dir, workers, scheduler, show_progress, progress_lines)
            set_state(out_dir, "complete", "sweep.json")
        except Interrupted:
            mark(out_dir, "interrupted", "sweep.json")
            raise
        except (WriteError, WorkerLost) as exc:
            mark(out_dir, "interrupted", "sweep.json")
            meta = read_meta(meta_path)
            raise stopped(exc, kept(out_dir, len(meta["points"]) * len(meta["seeds"]), hint)) \
                from None
        except BaseException:
            mark(out_dir, "failed", "sweep.json")
            raise
    finally:
        lock.release()
    return rows


def _new_sweep(config, grid, seeds, cycles) -> dict[str, Any]:
    """The ``sweep.json`` of a new sweep, every point validated first."""
    source = resolve_config_path(config)
    raw = read_yaml(source)
    block = raw.pop("sweep", None) or {}
    if not isinstance(block, dict) or not isinstance(block.get("grid") or {}, dict):
        raise ConfigError([("sweep", "must be a mapping with a grid: {a.b: [1, 2]}")],
                          str(source))
    full_grid = dict(block.get("grid") or {})
    full_grid.update(grid or {})
    check_grid_size(full_grid, str(source))
    if not full_grid:
        raise ConfigError([("sweep.grid", "a sweep needs a grid: --grid a.b=1,2 or a "
                                          "sweep: {grid: {a.b: [1, 2]}} block")], str(source))
    points = grid_points(full_grid)
    # Validate every point before anything runs: a bad value fails fast, naming its point.
    first, files = None, {}
    for i, point in enumerate(points):
        exp = _build(raw, point, source, cycles, i)
        first = first or exp
        files.update({p: r for p, r in input_files(exp).items() if p not in files})
    meta = {"source": str(Path(source).resolve()), "raw": raw, "grid": full_grid,
            "points": points,
            "seeds": list(seeds if seeds is not None else first.config.seed_list),
            "cycles": cycles or first.config.sim.cycles,
            "inputs": record_files(files, source)}
    return meta


def _sweep_points(out_dir: Path, workers, scheduler, show_progress, progress_lines):
    meta = read_meta(out_dir / "sweep.json", ("source", "raw", "grid", "points", "seeds",
                                              "cycles"))
    check_inputs(meta.get("inputs"), None, f"sweep {out_dir}")
    source = Path(meta["source"])
    exps, tasks = [], []
    for i, point in enumerate(meta["points"]):
        exp = _build(meta["raw"], point, source, meta["cycles"], i)
        exps.append(exp)
        inputs = tuple(f for f in fingerprints(meta.get("inputs"))
                       if Path(f[1]) in input_files(exp))
        run_dir = out_dir / f"point-{i:03d}"
        if not (run_dir / "config.yaml").is_file():
            from feltool.config.files import config_to_yaml

            atomic_write(run_dir / "config.yaml", config_to_yaml(exp.config, source.parent))
        for seed in meta["seeds"]:
            if load_seed_result(run_dir, seed) is None:
                tasks.append(Task(str(i), _point_raw(meta["raw"], point, meta["cycles"]),
                                  str(source), seed, meta["cycles"],
                                  str(run_dir / "checkpoints"), CHECKPOINT_EVERY,
                                  CHECKPOINT_INTERVAL_S, inputs))
    for task, result in execute(tasks, workers, scheduler, "sweep",
                                len(tasks) * meta["cycles"], show_progress,
                                progress_lines=progress_lines, cycles=meta["cycles"]):
        i = int(task.key)
        save_seed_result(exps[i], out_dir / f"point-{i:03d}", result)
    rows = []
    for i, (exp, point) in enumerate(zip(exps, meta["points"])):
        run_dir = out_dir / f"point-{i:03d}"
        results = [load_seed_result(run_dir, s) for s in meta["seeds"]]
        remove_empty(run_dir / "checkpoints")
        summary = write_results(exp, run_dir, results)
        for s in summary["seeds"]:
            rows.append({"point": i, **point, "seed": s["seed"], "fb_initial": s["fb_initial"],
                         "fb_final": s["fb_final"], "converged_cycle": s["converged_cycle"],
                         "diverged": s["diverged"], "learned": s["learned"],
                         "failed_reason": s["failed_reason"] or ""})
    _write_csv(out_dir / "sweep.csv", rows)
    plot_sweep(out_dir, meta["grid"], rows)
    return rows


def _point_raw(raw: dict, point: dict[str, Any], cycles: int | None) -> dict:
    over = [f"{k}={json.dumps(v)}" for k, v in point.items()]
    if cycles:
        over.append(f"sim.cycles={cycles}")
    return apply_overrides(copy.deepcopy(raw), over)


def _build(raw: dict, point: dict[str, Any], source: Path, cycles: int | None, index: int):
    try:
        return build_experiment(_point_raw(raw, point, cycles), source)
    except ConfigError as exc:
        desc = ", ".join(f"{k}={v}" for k, v in point.items())
        raise ConfigError([(path, f"{msg} (sweep point {index}: {desc})")
                           for path, msg in exc.problems], exc.source) from None


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    buf = io.StringIO()
    if rows:
        writer = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    atomic_write(path, buf.getvalue())


def plot_sweep(out_dir: Path, grid: dict[str, list], rows: list[dict[str, Any]]) -> Path:
    """Mean converged cycle over the grid: a line for 1-D grids, a map for 2-D (first two keys).

    Points where a seed never converged or diverged are marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(grid)
    by_point: dict[int, list] = {}
    for r in rows:
        by_point.setdefault(r["point"], []).append(r)

    def value(rs):
        conv = [r["converged_cycle"] for r in rs]
        return np.nan if any(c is None for c in conv) else float(np.mean(conv))

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    if len(keys) == 1:
        xs = [by_point[i][0][keys[0]] for i in sorted(by_point)]
        ys = [value(by_point[i]) for i in sorted(by_point)]
        ax.plot(range(len(xs)), ys, "o-")
        ax.set_xticks(range(len(xs)), [str(x) for x in xs])
        ax.set_xlabel(keys[0])
        ax.set_ylabel("mean converged cycle (gap: some seed never converged)")
    else:
        xk, yk = keys[0], keys[1]
        xs, ys = grid[xk], grid[yk]
        Z = np.full((len(ys), len(xs)), np.nan)
        for rs in by_point.values():
            r = rs[0]
            cell = Z[ys.index(r[yk]), xs.index(r[xk])]
            Z[ys.index(r[yk]), xs.index(r[xk])] = value(rs) if np.isnan(cell) else cell
        cmap = matplotlib.colormaps["viridis"].with_extremes(bad="lightgrey")
        im = ax.imshow(np.ma.masked_invalid(Z), origin="lower", cmap=cmap, aspect="auto")
        ax.set_xticks(range(len(xs)), [str(x) for x in xs])
        ax.set_yticks(range(len(ys)), [str(y) for y in ys])
        ax.set_xlabel(xk)
        ax.set_ylabel(yk)
        fig.colorbar(im, ax=ax, label="mean converged cycle")
        diverged = {(r[xk], r[yk]) for r in rows if r["diverged"]}
        for j, y in enumerate(ys):
            for i, x in enumerate(xs):
                label = ("diverged" if (x, y) in diverged else "not conv.") \
                    if np.isnan(Z[j, i]) else f"{Z[j, i]:.0f}"
                ax.text(i, j, label, ha="center", va="center",
                        color="k" if np.isnan(Z[j, i]) else "w")
    ax.set_title("Sweep: mean cycles to converge over seeds")
    fig.tight_layout()
    path = write_by(out_dir / "figures" / "sweep.png",
                    lambda fh: fig.savefig(fh, format="png", dpi=110))
    plt.close(fig)
    return path
