"""A legged experiment's run (``walking.base: free_flyer``): every seed's learning trot
(:func:`feltool.walking.legged.learn.learn_trot`) into a run directory, its summary and verdict.

::

    config.yaml          the resolved config (defaults filled in, a URDF path absolute)
    run.json             inputs and state (feltool.runs.runstate), the config's fingerprint
    seeds/seed-N.json    a finished seed's metrics rows and summary entry, its last file:
                         what ``feltool run --resume`` keeps (it runs the seeds without one)
    metrics.csv          one row per (seed, cycle): fb_total (the summed feedback [N m]),
                         fb_share_<motor> (each motor's RMS feedback share [N m]), t_start_s,
                         t_end_s, changed (1 once the unknown world, payload, slope or masses, is on)
    summary.json         per seed: walked, not_walking, cycles, fb before / at the change,
                         first, last, ratios, speed, contact statistics; the run's verdict
    params/seed-N.npz    the learned Fourier coefficients C (2M+1, nv), the coordinates'
                         names, feedback per cycle, shares, cycle times (allow_pickle=False)
    traces/seed-N.npz    the rollout's configurations q (n, nq) at TRACE_HZ, uniform times t
                         [s] (the nearest control step's), for the viewer (rollout.html)
    figures/legged_feedback.png   summed feedback per cycle, every seed
"""

from __future__ import annotations

import datetime as _dt
import sys
import time
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from feltool._version import __version__
from feltool.config.legged import LeggedExperimentConfig, legged_config_yaml
from feltool.errors import InputError
from feltool.files import WriteError, make_dirs
from feltool.runs.checkpoint import Interrupted
from feltool.runs.legged_robot import as_run, gait_and_controller, load_legged_robot
from feltool.runs.rundir import atomic_write, read_json, save_npz, write_by, write_json, write_metrics
from feltool.runs.runstate import (
    NOTHING_WRITTEN,
    RunLock,
    config_differences,
    describe_contents,
    has_contents,
    read_meta,
    set_state,
)

#: The free flyer's six velocity coordinates (base frame), before the motors
BASE_COORDINATES = ("base_vx", "base_vy", "base_vz", "base_wx", "base_wy", "base_wz")

#: The rate the rollout's configurations are kept at for the viewer [Hz]
TRACE_HZ = 50.0


def trace(t: np.ndarray, q: np.ndarray, rate_hz: float = TRACE_HZ) -> dict[str, np.ndarray]:
    """The configurations ``q`` ``(n, nq)`` at uniform times ``1 / rate_hz`` apart [s], each
    the last control step's at or before that time (the log's steps are uneven at events)."""
    t, q = np.asarray(t, float), np.asarray(q, float)
    if len(t) == 0:
        return {"t": np.zeros(0), "q": np.zeros((0, q.shape[1] if q.ndim == 2 else 0))}
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) * rate_hz)) + 1) / rate_hz
    idx = np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)
    return {"t": grid, "q": q[idx]}


def world(cfg: LeggedExperimentConfig, legged) -> str:
    """The unknown world in words: ``payload 20% of 2.5 kg``, ``slope 0.1 rad uphill ahead``,
    ``masses 1.2 times the model's``, together, or ``no change of the world``."""
    p, s = cfg.payload, cfg.slope
    parts = [] if p is None else [f"payload {p.fraction:.0%} of {legged.mass:.3g} kg"]
    if s is not None:
        tilt = [f"{abs(a):g} rad {word}" for a, word in
                ((s.angle, "downhill ahead" if s.angle > 0 else "uphill ahead"),
                 (s.roll, "downhill to the left" if s.roll > 0 else "downhill to the right"))
                if a != 0.0]
        parts.append("slope " + (", ".join(tilt) or "0 rad"))
    if cfg.masses is not None:
        parts.append(f"masses {cfg.masses.scale:g} times the model's")
    return " and ".join(parts) or "no change of the world"


def describe(cfg: LeggedExperimentConfig, legged) -> str:
    """One line: the robot, gait, plant, unknown world and seeds (``feltool check``)."""
    g = cfg.walking.walk or gait_and_controller(cfg, legged)[0]
    load = world(cfg, legged) + ("" if cfg.change_cycle is None else
                                 f" from cycle {cfg.change_cycle}")
    return (f"robot {legged.name} ({legged.mass:.3g} kg, {legged.nv - 6} motors, limit "
            f"{float(np.max(legged.effort)):g} N m, feet {', '.join(legged.feet)}), "
            f"{'walk' if cfg.walking.walk else 'trot'} "
            f"{g.speed:.3g} m/s, period {g.period:.3g} s, plant {cfg.plant.simulator}, {load}, "
            f"learning {'on' if cfg.learning.enabled else 'off'}, {len(cfg.seed_list)} seeds x "
            f"{cfg.sim.cycles} cycles")


def acquire_reference(cfg: LeggedExperimentConfig, legged):
    """The reference's correction acquired on the known model (``walking.acquire`` rounds,
    :func:`~feltool.walking.legged.orbit.acquire_orbit`), or None for 0 rounds."""
    from feltool.walking.legged.orbit import acquire_orbit
    from feltool.walking.legged.trot import TrotController

    if cfg.walking.acquire == 0:
        return None
    gait, extra = gait_and_controller(cfg, legged)
    return acquire_orbit(legged, gait, rounds=cfg.walking.acquire,
                         impact_window=cfg.sim.impact_window_s, rate_hz=cfg.sim.rate_hz,
                         controller=TrotController(legged, legged.standing(), gait=gait,
                                                   **extra))


def run_seed(cfg: LeggedExperimentConfig, legged, seed: int, cycles: int,
             correction=None, on_cycle=None) -> dict[str, Any]:
    """One seed's learning trot on the reference ``correction`` (:func:`acquire_reference`);
    its metrics rows, params and summary entry. ``on_cycle``: :func:`~feltool.walking.legged
    .learn.learn_trot`'s hook (the live viewer)."""
    from feltool.walking.legged.learn import PhaseFeedforward, learn_trot

    L, p, change = cfg.learning, cfg.payload, cfg.change_cycle
    gait, extra = gait_and_controller(cfg, legged)
    t0 = time.perf_counter()
    run = learn_trot(legged, cycles=cycles, payload=p.fraction if p else 0.0,
                     slope=None if cfg.slope is None else (cfg.slope.angle, cfg.slope.roll),
                     mass_scale=None if cfg.masses is None else cfg.masses.scale,
                     change=cycles + 10 if change is None else change, seed=seed,
                     learn=L.enabled,
                     plant=cfg.plant.simulator, gait=gait, controller=extra,
                     rate_hz=cfg.sim.rate_hz, impact_window=cfg.sim.impact_window_s,
                     start_speed=cfg.sim.start_velocity_scale,
                     feedforward=PhaseFeedforward(L.harmonics, legged.nv, L.rate),
                     correction=correction, acquire=0, on_cycle=on_cycle)
    wall = time.perf_counter() - t0
    ctl, fb = run.controller, np.asarray(run.feedback, float)
    n = len(fb)
    shares = np.array(ctl.share_rms, float).reshape(n, legged.nv - 6)
    times = np.array(ctl.cycle_times, float).reshape(n, 2)
    rows = [{"seed": seed, "cycle": c, "fb_total": float(fb[c]),
             **{f"fb_share_{m}": float(shares[c, i]) for i, m in enumerate(legged.motors)},
             "t_start_s": float(times[c, 0]), "t_end_s": float(times[c, 1]),
             "changed": int(change is not None and c >= change)} for c in range(n)]
    walked = run.kind is None and n >= cycles
    reason = run.log.not_walking or (None if walked else
                                     f"stopped after {n} of {cycles} cycles")
    at = lambda i: float(fb[i]) if 0 <= i < n else None  # noqa: E731
    entry = {"seed": seed, "cycles": n, "walked": walked, "not_walking": reason,
             "kind": run.kind, "fb_first": at(0), "fb_last": at(n - 1),
             "fb_ratio": at(n - 1) / fb[0] if n and fb[0] > 0 else None,
             "speed_m_per_s": run.speed, "wall_s": round(wall, 3),
             "stats": {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                       for k, v in vars(run.log.stats).items()}}
    if change is not None:
        entry.update({"change_cycle": change, "fb_before_change": at(change - 1),
                      "fb_change": at(change),
                      "fb_ratio_change": at(n - 1) / fb[change] if n > change and fb[change] > 0
                      else None})
    below = fb < 0.05 * fb[0] if n else np.zeros(0, bool)
    stays = [c for c in range(n) if below[c:].all()]
    entry["converged_cycle"] = stays[0] if stays else None
    params = {"C": ctl.learned.C, "coordinates": np.array(BASE_COORDINATES + tuple(legged.motors)),
              "feedback": fb, "share_rms": shares, "cycle_times": times,
              "harmonics": np.array(L.harmonics), "rate": np.array(L.rate)}
    return {"rows": rows, "params": params, "entry": entry,
            "trace": {**trace(run.log.t, run.log.q), "cycle_times": times}}


def failure(cfg: LeggedExperimentConfig, entry: dict[str, Any], cycles: int) -> str | None:
    """Why a seed did not learn as the config asks (None: it did)."""
    if not entry["walked"]:
        return f"not walking: {entry['not_walking']}"
    crit = cfg.success
    if crit.fb_ratio_max is not None:
        if crit.ratio_from == "change" and entry.get("fb_ratio_change") is None:
            return (f"the seed ended after {entry['cycles']} cycles, before the world's change "
                    f"at cycle {cfg.change_cycle} that success.ratio_from: change measures from")
        key = "fb_ratio_change" if crit.ratio_from == "change" else "fb_ratio"
        ratio = entry.get(key)
        if ratio is None or ratio > crit.fb_ratio_max:
            what = "fb_last / fb_change" if key == "fb_ratio_change" else "fb_last / fb_first"
            shown = "none" if ratio is None else f"{ratio:.4g}"
            return f"{what} = {shown} > success.fb_ratio_max = {crit.fb_ratio_max:g}"
    if crit.converged and entry["converged_cycle"] is None:
        return "never stayed below 5 % of the first cycle's feedback (success.converged: true)"
    return None


def refuse_taken(out_dir: Path) -> None:
    """Raise :class:`InputError` unless ``out_dir`` is new or empty (a run directory belongs
    to one command; only an explicit resume continues it)."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"--out {out_dir}: exists and is not a directory")
    if has_contents(out_dir):
        raise InputError(f"--out {out_dir}: already holds {describe_contents(out_dir)}; a run "
                         "directory belongs to one command: choose a new --out, or continue "
                         f"an interrupted run with feltool run --resume {out_dir}")


def run_legged(cfg: LeggedExperimentConfig, raw: dict, source: Path | None, out_dir: Path,
               seeds: list[int] | None = None, cycles: int | None = None,
               progress: TextIO | None = None, legged=None,
               resume: bool = False, on_cycle=None) -> dict[str, Any]:
    """Run every seed one after another into ``out_dir`` (new or empty: a run directory
    belongs to one command), write it, return the summary (``legged``: the config's robot,
    already loaded by :func:`load_legged_robot`). With ``resume``: continue the interrupted
    run in ``out_dir`` made with the same config, seeds and cycles (else an
    :class:`InputError` naming what differs), keeping its finished seeds and running the
    others. Ctrl-C or SIGTERM between control steps: the finished seeds are kept, the run
    marked interrupted (:class:`~feltool.runs.checkpoint.Interrupted`). ``on_cycle``: the
    first seed run here calls it after each cycle (:func:`run_seed`; the live viewer)."""
    seeds = list(seeds if seeds is not None else cfg.seed_list)
    cycles = cycles or cfg.sim.cycles
    base_dir = source.parent if source is not None else None
    if legged is None:  # bad input fails before anything is written
        legged = load_legged_robot(cfg, base_dir, str(source) if source else None)
    out_dir = Path(out_dir)
    if not resume:
        refuse_taken(out_dir)
    elif not (out_dir / "run.json").is_file():  # before the lock makes the directory
        raise InputError(f"--resume {out_dir}: no run.json, so not a feltool run directory to "
                         "resume")
    try:
        lock = RunLock(out_dir).acquire()
    except WriteError as exc:
        raise exc.keeping(NOTHING_WRITTEN, 2) from None
    try:
        if resume:
            check_resumable(out_dir, cfg, seeds, cycles)
        else:
            atomic_write(out_dir / "config.yaml",
                         legged_config_yaml(as_run(cfg, legged), base_dir))
            write_json(out_dir / "run.json", {
                "source": str(source.resolve()) if source else None, "raw": raw,
                "seeds": seeds, "cycles": cycles, "kind": "legged",
                "fingerprint": fingerprint(cfg)})
        set_state(out_dir, "running", cycles=cycles)
    except WriteError as exc:
        lock.release()
        raise exc.keeping(NOTHING_WRITTEN, 2) from None
    except BaseException:
        lock.release()
        raise
    done = finished_seeds(out_dir, seeds) if resume else {}
    results: list[dict] = []
    try:
        t0 = time.perf_counter()
        todo = [s for s in seeds if s not in done]
        acquired = acquire_reference(cfg, legged) if todo else None
        if acquired is not None:
            write_json(out_dir / "reference.json", {
                "rounds": cfg.walking.acquire, "feedback_n_m": acquired.feedback,
                "wall_s": round(time.perf_counter() - t0, 3)})
            if progress is not None:
                print(f"feltool: reference acquired on the known model in {cfg.walking.acquire} "
                      f"rounds, its feedback " + " -> ".join(f"{f:.4f}" for f in
                                                             acquired.feedback) + " N m",
                      file=progress, flush=True)
        for i, seed in enumerate(seeds):
            if seed in done:
                results.append(done[seed])
                if progress is not None:
                    print(f"feltool: seed {seed} ({i + 1}/{len(seeds)}): kept from the "
                          "run directory", file=progress, flush=True)
                continue
            r = run_seed(cfg, legged, seed, cycles,
                         None if acquired is None else acquired.correction,
                         on_cycle=on_cycle if seed == todo[0] else None)
            results.append(r)
            save_npz(out_dir / "params" / f"seed-{seed}.npz", r["params"])
            save_npz(out_dir / "traces" / f"seed-{seed}.npz", r.pop("trace"))
            write_json(out_dir / SEEDS_DIR / f"seed-{seed}.json",
                       {"rows": r["rows"], "entry": r["entry"]})
            if progress is not None:
                e = r["entry"]
                print(f"feltool: seed {seed} ({i + 1}/{len(seeds)}): {e['cycles']} cycles, "
                      f"{'walked' if e['walked'] else 'NOT WALKING'}, {e['wall_s']:.3g} s",
                      file=progress, flush=True)
        summary = write_summary(cfg, legged, out_dir, results, cycles)
        set_state(out_dir, "complete", outcome={"n_failed": summary["aggregate"]["n_failed"]})
    except KeyboardInterrupt:
        set_state(out_dir, "interrupted")
        raise Interrupted(f"interrupted with {len(results)} of {len(seeds)} seeds finished in "
                          f"{out_dir}; continue with: feltool run --resume {out_dir}") from None
    except BaseException:
        set_state(out_dir, "failed")
        raise
    finally:
        lock.release()
    draw_feedback(out_dir, results, cfg.change_cycle)
    return summary


def legged_run(run_dir: Path) -> dict[str, Any] | None:
    """``run.json`` of ``run_dir`` when it is a legged run, else None."""
    path = Path(run_dir) / "run.json"
    if not path.is_file():
        return None
    meta = read_json(path)
    return meta if meta.get("kind") == "legged" else None


def stored_config(run_dir: Path) -> tuple[LeggedExperimentConfig, Path | None]:
    """A legged run's config (its ``run.json``'s, as run) and the directory its relative paths
    start from."""
    from feltool.config.legged import parse_legged_config

    meta = read_meta(Path(run_dir) / "run.json", ("raw", "source"))
    source = Path(meta["source"]) if meta["source"] else None
    return (parse_legged_config(meta["raw"], str(source) if source else None),
            None if source is None else source.parent)


def redraw(run_dir: Path) -> list[Path]:
    """``feltool plot`` on a complete legged run: its figure drawn again from ``metrics.csv``."""
    from feltool.runs.rundir import read_metrics

    run_dir = Path(run_dir)
    for name in ("metrics.csv", "summary.json"):
        if not (run_dir / name).is_file():
            raise InputError(f"{run_dir}: no {name}; plot a complete legged run (finish an "
                             f"interrupted one with feltool run --resume {run_dir})")
    rows = read_metrics(run_dir / "metrics.csv")
    seeds = list(dict.fromkeys(int(r["seed"]) for r in rows))
    results = [{"entry": {"seed": seed}, "params": {"feedback": np.array(
        [r["fb_total"] for r in rows if int(r["seed"]) == seed], float)}} for seed in seeds]
    change = read_json(run_dir / "summary.json").get("change_cycle")
    return [draw_feedback(run_dir, results, change)]


#: Where each finished seed's rows and entry are kept (:func:`run_legged`)
SEEDS_DIR = "seeds"


def fingerprint(cfg: LeggedExperimentConfig) -> dict[str, Any]:
    """The resolved config without its seeds (a resume checks them apart)."""
    dump = cfg.model_dump(mode="json")
    dump.pop("seeds", None)
    return dump


def check_resumable(out_dir: Path, cfg: LeggedExperimentConfig, seeds: list[int],
                    cycles: int) -> None:
    """Refuse to continue ``out_dir`` unless it is a legged run of the same config, seeds and
    cycles (an :class:`InputError` listing what differs)."""
    meta = read_meta(Path(out_dir) / "run.json", ("raw", "seeds", "cycles", "fingerprint"))
    if meta.get("kind") != "legged":
        raise InputError(f"--resume {out_dir}: not a legged run; resume it with its own config")
    problems = config_differences(meta["fingerprint"], fingerprint(cfg))
    if list(meta["seeds"]) != list(seeds):
        problems.append(f"seeds: {meta['seeds']} -> {seeds}")
    if int(meta["cycles"]) != cycles:
        problems.append(f"cycles: {meta['cycles']} -> {cycles} (a seed trots its cycles in one "
                        "rollout: a resume runs the unfinished seeds, it cannot add cycles)")
    if problems:
        raise InputError(f"--resume {out_dir}: the stored run differs from the one asked for; "
                         "resume it as it is (feltool run --resume RUN_DIR) or start a new run:"
                         "\n  " + "\n  ".join(problems[:12]))


def finished_seeds(out_dir: Path, seeds: list[int]) -> dict[int, dict[str, Any]]:
    """The seeds of ``seeds`` that finished in ``out_dir`` (their ``seeds/seed-N.json``), as
    results of :func:`run_seed` without the trace (the feedback per cycle from the rows)."""
    out = {}
    for seed in seeds:
        path = Path(out_dir) / SEEDS_DIR / f"seed-{seed}.json"
        if path.is_file():
            kept = read_json(path)
            fb = np.array([row["fb_total"] for row in kept["rows"]], float)
            out[seed] = {"rows": kept["rows"], "entry": kept["entry"],
                         "params": {"feedback": fb}}
    return out


def write_summary(cfg: LeggedExperimentConfig, legged, out_dir: Path, results: list[dict],
                  cycles: int) -> dict[str, Any]:
    """metrics.csv and summary.json from the seeds' results."""
    write_metrics(out_dir / "metrics.csv", [row for r in results for row in r["rows"]])
    entries = []
    for r in results:
        e = dict(r["entry"])
        e["failed_reason"] = failure(cfg, e, cycles)
        e["learned"] = e["failed_reason"] is None
        entries.append(e)
    ratios = [e["fb_ratio_change"] for e in entries if e.get("fb_ratio_change") is not None]
    n_failed = sum(not e["learned"] for e in entries)
    summary = {
        "config": cfg.name, "kind": "legged", "feltool_version": __version__,
        "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "robot": legged.name, "mass_kg": legged.mass, "motors": legged.motors,
        "feet": list(legged.feet), "plant": cfg.plant.simulator, "cycles": cycles,
        "change_cycle": cfg.change_cycle, "world": world(cfg, legged),
        "success": cfg.success.model_dump(), "seeds": entries,
        "aggregate": {"n_seeds": len(entries), "n_walked": sum(e["walked"] for e in entries),
                      "n_failed": n_failed, "n_diverged": 0,
                      "fb_ratio_change_min": min(ratios) if ratios else None,
                      "fb_ratio_change_max": max(ratios) if ratios else None},
        "verdict": "learned" if n_failed == 0 else "failed"}
    write_json(out_dir / "summary.json", summary)
    return summary


def draw_feedback(out_dir: Path, results: list[dict], change: int | None) -> Path:
    """``figures/legged_feedback.png``: the summed feedback per cycle of every seed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    make_dirs(out_dir / "figures")
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for r in results:
        fb = r["params"]["feedback"]
        ax.plot(np.arange(len(fb)), fb, lw=1.2, label=f"seed {r['entry']['seed']}")
    if change is not None:
        ax.axvline(change, color="k", ls=":", lw=1, label=f"world changes (cycle {change})")
    if any(np.any(np.asarray(r["params"]["feedback"]) > 0) for r in results):
        ax.set_yscale("log")
    else:  # a log axis of nothing positive is an error in matplotlib
        ax.text(0.5, 0.5, "no seed completed a cycle", transform=ax.transAxes, ha="center")
    ax.set_xlabel("cycle")
    ax.set_ylabel("summed feedback per cycle [N m]")
    ax.set_title("Legged trot: feedback over the cycles")
    ax.grid(True, which="both", alpha=0.3)
    if len(results) <= 10:
        ax.legend(fontsize=7)
    fig.subplots_adjust(left=0.14, right=0.97, bottom=0.13, top=0.91)
    path = out_dir / "figures" / "legged_feedback.png"
    write_by(path, lambda fh: fig.savefig(fh, format="png", dpi=120))
    plt.close(fig)
    return path


def print_summary(summary: dict[str, Any], out_dir: Path, out: TextIO | None = None) -> None:
    """The run's table (to ``out``, default stdout): per seed, whether it trotted (walked), its
    feedback around the change, the ratio; the verdict."""
    out = sys.stdout if out is None else out
    fmt = lambda x, f: "-" if x is None else format(x, f)  # noqa: E731
    agg = summary["aggregate"]
    n = agg["n_seeds"]
    change = summary["change_cycle"]
    print(f"{summary['config']}: {n} seed{'' if n == 1 else 's'} x {summary['cycles']} cycles, "
          f"{summary['robot']} on {summary['plant']}, {summary['world']}"
          f"{'' if change is None else f' from cycle {change}'}; summed feedback [N m]",
          file=out)
    print(f"  {'seed':>4} {'cycles':>6} {'outcome':<12} {'fb_first':>9} {'fb_before':>9} "
          f"{'fb_change':>9} {'fb_last':>9} {'last/chg':>8} {'speed':>6}", file=out)
    for s in summary["seeds"]:
        print(f"  {s['seed']:>4} {s['cycles']:>6} "
              f"{'walked' if s['walked'] else 'NOT WALKING':<12} {fmt(s['fb_first'], '.4g'):>9} "
              f"{fmt(s.get('fb_before_change'), '.4g'):>9} {fmt(s.get('fb_change'), '.4g'):>9} "
              f"{fmt(s['fb_last'], '.4g'):>9} {fmt(s.get('fb_ratio_change'), '.3f'):>8} "
              f"{fmt(s['speed_m_per_s'], '.3f'):>6}", file=out)
        if s["failed_reason"]:
            print(f"       seed {s['seed']} did not learn as the config asks: "
                  f"{s['failed_reason']}", file=out)
    crit = summary["success"]
    bound = "" if crit["fb_ratio_max"] is None else \
        f" (success: last / {crit['ratio_from']} <= {crit['fb_ratio_max']:g})"
    print(f"  walked every cycle: {agg['n_walked']}/{agg['n_seeds']}; learned as the config "
          f"asks{bound}: {agg['n_seeds'] - agg['n_failed']}/{agg['n_seeds']}; run directory: "
          f"{out_dir}", file=out)


def exit_code(summary: dict[str, Any]) -> int:
    """0 every seed trotted (walked) through every cycle and met success:, else 1."""
    return 1 if summary["aggregate"]["n_failed"] else 0


__all__ = ["check_resumable", "describe", "exit_code", "legged_run", "load_legged_robot",
           "print_summary", "redraw", "refuse_taken", "run_legged", "run_seed", "stored_config"]
