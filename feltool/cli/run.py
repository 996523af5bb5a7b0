"""``feltool run``: an experiment over its seeds into a run directory, its summary and exit code."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from feltool.cli.common import (
    add_progress_options,
    config_overrides,
    cycle_count,
    load_config,
    positive_int,
    print_warnings,
    progress_mode,
    subcommand,
)
from feltool.cli.view import keep_viewing, watching
from feltool.errors import InputError
from feltool.runs.checkpoint import Interrupted


def cmd_run(args: argparse.Namespace) -> int:
    from feltool.runs.runner import default_out_dir, run_experiment, stored_experiment
    from feltool.runs.timing import process_started

    bar, lines = progress_mode(args)
    resume = args.resume is not None
    if args.zmq_url is not None:
        from feltool.viewer.live import check_zmq_url

        check_zmq_url(args.zmq_url)  # a bad address fails before anything runs
    if resume and args.resume is not True and args.out is not None \
            and Path(args.resume) != args.out:
        raise InputError(f"--resume {args.resume} and --out {args.out} name two directories")
    if args.config is None and not resume:
        raise InputError("run needs a CONFIG (or --resume RUN_DIR); see feltool run --help")
    out_dir = args.out if args.resume in (None, True) else Path(args.resume)
    if resume and out_dir is None:
        raise InputError("--resume needs the run directory: --resume RUN_DIR (or --out RUN_DIR)")
    if resume:
        from feltool.cli.legged import resume_legged_command

        code = resume_legged_command(args, out_dir)
        if code is not None:  # a legged run (walking.base: free_flyer)
            return code
    if args.config is None:  # resume with the stored config
        if args.set or args.seeds:
            raise InputError("--set/--seeds change the config: give the CONFIG too, so the "
                             "resume can check it is the same run")
        exp, meta = stored_experiment(out_dir)
        raw, seeds, cycles = meta["raw"], meta["seeds"], args.cycles or meta["cycles"]
    else:
        overrides = config_overrides(args)
        from feltool.cli.legged import legged_raw, run_legged_command

        legged = legged_raw(args.config, overrides)
        if legged is not None:  # walking.base: free_flyer, the trot (docs/legged.md)
            return run_legged_command(args, *legged)
        exp, raw = load_config(args.config, overrides)
        print_warnings(exp.robot)
        refuse_what_check_refuses(exp)
        seeds, cycles = None, None
        out_dir = out_dir or default_out_dir(exp.config.name)
    print(f"feltool: {exp.engine} engine ({exp.engine_reason})", flush=True)
    stream = None
    with watching(args, lambda: exp.robot) as viewer:
        if viewer is not None:
            from feltool.viewer.rollout import LiveStream

            stream = LiveStream(viewer, exp.config.dt, cycles or exp.config.sim.cycles,
                                realtime=args.realtime, label=f"seed {exp.config.seed_list[0]}")
        try:
            summary = run_experiment(exp, raw, out_dir, seeds, cycles, workers=args.workers,
                                     show_progress=bar, on_cycle=stream, resume=resume,
                                     progress_lines=lines, started=process_started())
        except Interrupted as exc:
            raise Interrupted(f"{exc}; continue with: feltool run --resume {out_dir}") from None
        finally:
            if stream is not None:
                stream.close()
        print_summary(summary, out_dir)
        if args.html:
            from feltool.viewer.rollout import write_rollout_html

            print(f"  rollout: {write_rollout_html(exp.robot, out_dir)}")
        if viewer is not None:  # the page stays up after the run: replay what it learned
            from feltool.viewer.rollout import replay

            keep_viewing(viewer, lambda left: replay(viewer, out_dir, timeout_s=left),
                         args.view_timeout)
    return run_exit_code(summary)


def refuse_what_check_refuses(exp) -> None:
    """Raise the :class:`~feltool.errors.ConfigError` ``feltool check`` raises for ``exp``
    (:func:`feltool.experiment.checks.experiment_problems`: unreachable targets, learned joints
    the error never sees, unstable gains, a rate too coarse for the gains), before anything
    is run or written: one line per problem naming its field, exit 2."""
    from feltool.errors import ConfigError
    from feltool.experiment.checks import experiment_problems

    problems = experiment_problems(exp)
    if problems:
        raise ConfigError(problems, str(exp.source) if exp.source else None)


def run_exit_code(summary: dict) -> int:
    """0 every seed learned as the config asks, 1 some seed diverged, fell or missed it."""
    agg = summary["aggregate"]
    return 1 if agg["n_diverged"] or agg.get("n_failed") else 0


def _print_walking(summary: dict) -> None:
    """Walkers: per seed, whether it walked, the gait's numbers and each learned joint's own
    feedback, first and last cycle."""
    walkers = [s for s in summary["seeds"] if isinstance(s.get("walking"), dict)]
    if not walkers:
        return
    fmt = lambda x, f: "-" if x is None else format(x, f)  # noqa: E731
    for s in walkers:
        w = s["walking"]
        rho = (s.get("poincare") or {}).get("spectral_radius")
        head = "walked" if w["walked"] else f"NOT WALKING ({w['not_walking'] or 'fell'})"
        line = (f"  seed {s['seed']} {head}: {w.get('steps', 0)} steps, step "
                f"{fmt(w.get('step_length_m'), '.3f')} m, speed "
                f"{fmt(w.get('speed_m_per_s'), '.3f')} m/s, CoT "
                f"{fmt(w.get('cost_of_transport'), '.3f')}, torso RMS "
                f"{fmt(w.get('stabilized_rms_last_rad'), '.3g')} rad, ratio "
                + (f"{fmt(s.get('fb_ratio'), '.2%')}" if s.get("fb_ratio_change") is None else
                   f"from the change {fmt(s['fb_ratio_change'], '.4g')}")
                + f", Poincare rho {fmt(rho, '.3f')}")
        if "min_normal_force_N" in w:
            line += (f"; min F_n {fmt(w.get('min_normal_force_N'), '.4g')} N, max |F_t|/F_n "
                     f"{fmt(w.get('max_friction_ratio'), '.3f')}")
        print(line)
        learned = s.get("learned_feedback") or {}
        if learned:
            print("      learned, own feedback first -> last cycle: " + ", ".join(
                f"{j} {d['first']:.3g} -> {d['last']:.3g} N m" for j, d in learned.items()))
    agg = summary["aggregate"]
    kinds = ", ".join(f"{k} {c}" for k, c in agg.get("not_walking", {}).items())
    print(f"  walked without falling: {agg.get('n_walked', 0)}/{len(walkers)} seeds; not "
          f"walking: {agg.get('n_not_walking', 0)}" + (f" ({kinds})" if kinds else ""))


def print_summary(summary: dict, out_dir: Path) -> None:
    agg = summary["aggregate"]
    print(f"{summary['config']}: {agg['n_seeds']} seeds, error signal = feedback of "
          f"{', '.join(summary['error_joints'])}")
    print(f"  {'seed':>4} {'cycles':>6} {'fb_initial':>11} {'fb_final':>10} {'ratio':>8} "
          f"{'converged':>9} {'steps/s':>9}")
    for s in summary["seeds"]:
        if s["diverged"]:
            print(f"  {s['seed']:>4} DIVERGED: {s['diverged_reason']}")
            continue
        conv = "-" if s["converged_cycle"] is None else str(s["converged_cycle"])
        print(f"  {s['seed']:>4} {s['cycles']:>6} {s['fb_initial']:>11.4g} {s['fb_final']:>10.3g} "
              f"{s['fb_ratio']:>8.2%} {conv:>9} {s['steps_per_s']:>9.0f}")
    changed = [s for s in summary["seeds"] if s.get("fb_ratio_change") is not None]
    if changed:
        r = [s["fb_ratio_change"] for s in changed]
        print(f"  from the world's change at cycle {changed[0]['change_cycle']}: fb_final / "
              f"its cycle's feedback {min(r):.4g} to {max(r):.4g} over {len(r)} seeds")
    for s in summary["seeds"]:
        lim = s.get("limits")
        if isinstance(lim, dict) and (lim["joint_limit_steps"] or lim["torque_limit_steps"]):
            parts = [f"{kind} limits of " + ", ".join(f"{j} ({c} steps)" for j, c in d.items())
                     for kind, d in (("position", lim["joint_limit_steps"]),
                                     ("torque", lim["torque_limit_steps"])) if d]
            print(f"  seed {s['seed']} hit the URDF's " + "; ".join(parts))
    _print_walking(summary)
    conv = agg["converged_cycle_max"]
    if "n_walked" not in agg:  # a walker: its block above reports what walking needs
        print(f"  converged (below 5 % of the initial feedback for good): {agg['n_converged']}/"
              f"{agg['n_seeds']} seeds" + (f", mean cycle {agg['converged_cycle_mean']:.1f}, "
                                            f"max {conv}" if conv is not None else ""))
    for s in summary["seeds"]:
        if s.get("failed_reason") and not s["diverged"]:
            print(f"  seed {s['seed']} did not learn as the config asks: {s['failed_reason']}")
    learned = agg["n_seeds"] - agg.get("n_failed", agg["n_diverged"])
    print(f"  learned as the config asks: {learned}/{agg['n_seeds']}   diverged: "
          f"{agg['n_diverged']}   run directory: {out_dir}")
    _print_timing(summary)


def _print_timing(summary: dict) -> None:
    """The run's honest figures (summary.json's ``timing``): the learning loop alone, the
    compilation, and the whole run since the process started (figures included)."""
    t = summary.get("timing")
    if not t:
        return
    from feltool.runs.timing import process_started

    sps = t["steps_per_s"]
    rate = "-" if sps is None else (f"{sps / 1e6:.3g} M" if sps >= 1e6 else f"{sps / 1e3:.3g} k")
    print(f"  timing: learning loop {rate} steps/s per core ({t['steps']:,} steps in "
          f"{t['loop_s']:.3g} s, {summary.get('engine', '?')} engine); build/compile "
          f"{t['compile_s']:.3g} s; whole run {time.time() - process_started():.3g} s wall "
          "since the process started")


def add_command(sub) -> None:
    """Add ``feltool run`` to the subparsers ``sub``."""
    p = subcommand(sub, "run", "run an experiment over its seeds, write a run directory",
             "  feltool run configs/two_link_standard.yaml\n"
             "  feltool run two_link_standard --seeds 0-4 --cycles 60 --set learning.update=gauss_newton\n"
             "  feltool run two_link_standard --out runs/arm --view       # watch it in the browser\n"
             "  feltool run --resume runs/arm                             # continue after Ctrl-C\n"
             "  feltool run --resume runs/arm --cycles 300                # add cycles to a run",
             exit_codes=True)
    p.add_argument("config", nargs="?", help="experiment YAML, or the name of a bundled config "
                   "(feltool robots lists robots; configs/ holds the bundled configs)")
    p.add_argument("--resume", nargs="?", const=True, metavar="RUN_DIR",
                   help="continue RUN_DIR (or --out) where it stopped; with CONFIG, only if it is "
                   "the stored run's config and seeds; --cycles may add cycles")
    p.add_argument("--seeds", help="seeds to run, e.g. 0-19 or 0,3,7 (default: the config's)")
    p.add_argument("--cycles", type=cycle_count, help="learning cycles per seed (default: "
                   "the config's sim.cycles)")
    p.add_argument("--out", type=Path, help="run directory; must be new or empty unless "
                   "--resume (default runs/<name>-<UTC time>)")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE",
                   help="override a config field, VALUE read as YAML (repeatable)")
    p.add_argument("--workers", type=positive_int, help="processes (default: all cores)")
    add_progress_options(p)
    p.add_argument("--view", action="store_true",
                   help="stream the first seed's rollout to a meshcat viewer in the browser "
                   "(system robot and a ghost at the forward configuration); after the run the "
                   "page stays up, replaying the first and last cycle, until Ctrl-C")
    p.add_argument("--view-timeout", type=float, metavar="S",
                   help="with --view: close the viewer S seconds after the run ends "
                   "(0: at once; default: on Ctrl-C)")
    p.add_argument("--zmq-url", metavar="URL",
                   help="use this running meshcat-server (implies --view; default: start one "
                   "on 127.0.0.1 and stop it at the end)")
    p.add_argument("--realtime", action="store_true",
                   help="play every cycle at wall-clock speed (implies --view; learning runs "
                   "at the robot's pace)")
    p.add_argument("--html", action="store_true",
                   help="write rollout.html (first and last cycle, no server needed) into the "
                   "run directory")
    p.set_defaults(func=cmd_run)
