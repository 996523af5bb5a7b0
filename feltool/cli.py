"""The ``feltool`` command.

Exit codes: 0 success, 2 bad input (config, URDF, arguments), 1 anything else. Bad input prints
what is wrong and where, never a traceback. (argparse rather than a CLI framework: its exit code
2 for usage errors and its plain messages are exactly the contract.)
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from feltool import __version__
from feltool.checkpoint import Interrupted
from feltool.errors import FeltoolError, InputError


def parse_seeds(spec: str) -> list[int]:
    """``0-19`` | ``0,3,7`` | ``5`` (a single seed) -> a sorted list of seeds."""
    seeds: list[int] = []
    try:
        for part in spec.split(","):
            part = part.strip()
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-", 1))
                if hi < lo or lo < 0:
                    raise ValueError
                seeds += list(range(lo, hi + 1))
            else:
                value = int(part)
                if value < 0:
                    raise ValueError
                seeds.append(value)
    except ValueError:
        raise InputError(f"--seeds: cannot read '{spec}'; use e.g. 0-19, 0,3,7 or 5") from None
    return sorted(set(seeds))


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _load(config: str, overrides: list[str]):
    from feltool.config import apply_overrides, read_yaml
    from feltool.experiment import build_experiment, resolve_config_path

    path = resolve_config_path(config)
    raw = apply_overrides(read_yaml(path), overrides)
    return build_experiment(raw, source=path), raw


def cmd_run(args: argparse.Namespace) -> int:
    from feltool.runner import default_out_dir, resume_run, run_experiment

    progress = args.progress and sys.stderr.isatty()
    if args.resume is not None:
        if args.config is not None:
            raise InputError("give either CONFIG or --resume RUN_DIR, not both")
        summary = resume_run(args.resume, args.workers, progress)
        print_summary(summary, args.resume)
        return 1 if summary["aggregate"]["n_diverged"] else 0
    if args.config is None:
        raise InputError("run needs a CONFIG (or --resume RUN_DIR)")
    overrides = list(args.set or [])
    if args.cycles is not None:
        overrides.append(f"sim.cycles={args.cycles}")
    if args.seeds is not None:
        overrides.append(f"seeds={parse_seeds(args.seeds)}")
    exp, raw = _load(args.config, overrides)
    out_dir = args.out or default_out_dir(exp.config.name)
    viewer = stream = None
    if args.view or args.zmq_url or args.realtime:
        from feltool.rollout import LiveStream
        from feltool.viewer import LiveViewer

        _exit_on_sigterm()  # so that the viewer's server is stopped on SIGTERM too
        viewer = LiveViewer(exp.robot, zmq_url=args.zmq_url)
    try:
        if viewer is not None:
            stream = LiveStream(viewer, exp.config.dt, exp.config.sim.cycles,
                                realtime=args.realtime, label=f"seed {exp.config.seed_list[0]}")
        summary = run_experiment(exp, raw, out_dir, workers=args.workers, show_progress=progress,
                                 on_cycle=stream)
    except Interrupted as exc:
        raise Interrupted(f"{exc}; continue with: feltool run --resume {out_dir}") from None
    finally:
        if stream is not None:
            stream.close()
        if viewer is not None:
            viewer.close()
    print_summary(summary, out_dir)
    if args.html:
        from feltool.rollout import write_rollout_html

        print(f"  rollout: {write_rollout_html(exp.robot, out_dir)}")
    return 1 if summary["aggregate"]["n_diverged"] else 0


def _exit_on_sigterm() -> None:
    """Turn SIGTERM into SystemExit(143), so that ``finally`` blocks (the viewer's server
    shutdown) run as they do on Ctrl-C."""
    def handler(signum, frame):
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)


def cmd_view(args: argparse.Namespace) -> int:
    from feltool.rollout import load_rollouts, parse_cycles, replay, run_robot, write_rollout_html

    cycles = parse_cycles(args.cycles)
    load_rollouts(args.run_dir, args.seed, cycles)  # bad input fails before a server starts
    robot = run_robot(args.run_dir)
    if args.html:
        print(write_rollout_html(robot, args.run_dir, args.seed, cycles))
        return 0
    from feltool.viewer import LiveViewer

    _exit_on_sigterm()
    with LiveViewer(robot, zmq_url=args.zmq_url) as viewer:
        if args.loops == 0:
            print("feltool viewer: replaying until interrupted (Ctrl-C)", flush=True)
        replay(viewer, args.run_dir, args.seed, cycles, loops=args.loops)
    return 0


def _print_walking(summary: dict) -> None:
    """Physical walkers: per seed, whether it walked, and the gait's numbers."""
    walkers = [s for s in summary["seeds"] if isinstance(s.get("walking"), dict)]
    if not walkers:
        return
    fmt = lambda x, f: "-" if x is None else format(x, f)  # noqa: E731
    for s in walkers:
        w = s["walking"]
        rho = (s.get("poincare") or {}).get("spectral_radius")
        head = "walked" if w["walked"] else f"NOT WALKING ({w['not_walking'] or 'fell'})"
        print(f"  seed {s['seed']} {head}: {w.get('steps', 0)} steps, step "
              f"{fmt(w.get('step_length_m'), '.3f')} m, speed {fmt(w.get('speed_m_per_s'), '.3f')}"
              f" m/s, CoT {fmt(w.get('cost_of_transport'), '.3f')}, torso RMS "
              f"{fmt(w.get('stabilized_rms_last_rad'), '.3g')} rad, ratio "
              f"{fmt(s.get('fb_ratio'), '.2%')}, Poincare rho {fmt(rho, '.3f')}; min F_n "
              f"{fmt(w.get('min_normal_force_N'), '.4g')} N, max |F_t|/F_n "
              f"{fmt(w.get('max_friction_ratio'), '.3f')}")
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
    for s in summary["seeds"]:
        lim = s.get("limits")
        if isinstance(lim, dict) and (lim["joint_limit_steps"] or lim["torque_limit_steps"]):
            parts = [f"{kind} limits of " + ", ".join(f"{j} ({c} steps)" for j, c in d.items())
                     for kind, d in (("position", lim["joint_limit_steps"]),
                                     ("torque", lim["torque_limit_steps"])) if d]
            print(f"  seed {s['seed']} hit the URDF's " + "; ".join(parts))
    _print_walking(summary)
    conv = agg["converged_cycle_max"]
    print(f"  converged (below 5 % of the initial feedback for good): {agg['n_converged']}/"
          f"{agg['n_seeds']} seeds" + (f", mean cycle {agg['converged_cycle_mean']:.1f}, "
                                        f"max {conv}" if conv is not None else ""))
    print(f"  diverged: {agg['n_diverged']}   run directory: {out_dir}")


def cmd_sweep(args: argparse.Namespace) -> int:
    from feltool.runner import default_out_dir
    from feltool.sweep import parse_grid, run_sweep

    progress = args.progress and sys.stderr.isatty()
    if args.resume is not None:
        out_dir, config, grid = args.resume, None, None
        if not (out_dir / "sweep.json").is_file():
            raise InputError(f"{out_dir}: no sweep.json, so not a sweep directory to resume")
    else:
        if args.config is None:
            raise InputError("sweep needs a CONFIG (or --resume SWEEP_DIR)")
        config, grid = args.config, parse_grid(args.grid or [])
        out_dir = args.out or default_out_dir(Path(config).stem + "-sweep")
    seeds = parse_seeds(args.seeds) if args.seeds else None
    try:
        rows = run_sweep(config, grid, out_dir, seeds, args.cycles, args.workers, args.scheduler,
                         progress)
    except Interrupted as exc:
        raise Interrupted(f"{exc}; continue with: feltool sweep --resume {out_dir}") from None
    points = len({r["point"] for r in rows})
    conv = sum(r["converged_cycle"] is not None for r in rows)
    div = sum(bool(r["diverged"]) for r in rows)
    print(f"sweep: {points} points x {len(rows) // max(points, 1)} seeds; converged {conv}, "
          f"diverged {div}; {out_dir / 'sweep.csv'}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    exp, _ = _load(args.config, list(args.set or []))
    cfg = exp.config
    print(f"{exp.source}: ok - robot {exp.robot.name} ({len(exp.joints)} moving joints: "
          f"{', '.join(exp.joints)}), {cfg.steps_per_cycle} steps per cycle, learned: "
          f"{', '.join(exp.learned_joints) or 'nothing'}, error signal: "
          f"{', '.join(exp.error_joints)}, {len(cfg.seed_list)} seeds")
    return 0


def cmd_robots(args: argparse.Namespace) -> int:
    from feltool.robot import bundled_robots, erd_robots

    print("bundled:")
    for name in bundled_robots():
        print(f"  {name}")
    print("example-robot-data (use as example-robot-data:NAME):")
    for name in erd_robots():
        print(f"  {name}")
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    from feltool.robot import config_skeleton, describe, load_robot

    robot = load_robot(args.robot, base_dir=Path.cwd())
    info = describe(robot)
    if args.json:
        print(json.dumps({**info, "config_skeleton": config_skeleton(robot)}, indent=2))
        return 0
    print(f"robot {info['name']}  ({info['source']})")
    print(f"  {'joint':<22} {'type':<18} {'axis':<18} {'limits [rad|m]':<20} {'effort':>8} "
          f"{'actuated':>8}  {'parent':<16}")
    for j in info["joints"]:
        lim = f"[{j['lower']:.4g}, {j['upper']:.4g}]"
        axis = "-" if j["axis"] is None else str([round(a, 3) for a in j["axis"]])
        print(f"  {j['name']:<22} {j['type']:<18} {axis:<18} {lim:<20} {j['effort']:>8.4g} "
              f"{'yes' if j['actuated'] else 'no':>8}  {j['parent']:<16}")
    print(f"  {'body (moved by joint)':<22} {'mass [kg]':>10}")
    for b in info["bodies"]:
        print(f"  {b['name']:<22} {b['mass']:>10.4g}")
    print(f"  total mass: {info['total_mass']:.4g} kg")
    print("\nsuggested config (every joint locked; give some a role):\n")
    print(config_skeleton(robot))
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from feltool.plots import draw_figures

    for path in draw_figures(args.run_dir, args.seed):
        print(path)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="feltool", description="Feedback error learning of rhythmic movement primitives "
        "on URDF robots.")
    parser.add_argument("--version", action="version", version=f"feltool {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run an experiment over its seeds, write a run directory")
    p.add_argument("config", nargs="?", help="experiment YAML, or the name of a bundled config")
    p.add_argument("--resume", type=Path, metavar="RUN_DIR",
                   help="continue an interrupted run where it stopped")
    p.add_argument("--seeds", help="seeds to run, e.g. 0-19 or 0,3,7 (default: the config's)")
    p.add_argument("--cycles", type=_positive_int, help="learning cycles per seed")
    p.add_argument("--out", type=Path, help="run directory (default runs/<name>-<UTC time>)")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE",
                   help="override a config field (repeatable)")
    p.add_argument("--workers", type=_positive_int, help="processes (default: all cores)")
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="no progress bar")
    p.add_argument("--view", action="store_true",
                   help="stream the first seed's rollout to a meshcat viewer in the browser "
                   "(system robot and a ghost at the forward configuration)")
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

    p = sub.add_parser("sweep", help="run a grid of config overrides over seeds")
    p.add_argument("config", nargs="?", help="experiment YAML, or the name of a bundled config")
    p.add_argument("--grid", action="append", metavar="A.B.C=V1,V2",
                   help="a swept field and its values (repeatable; the product is run)")
    p.add_argument("--seeds", help="seeds per point, e.g. 0-9")
    p.add_argument("--cycles", type=_positive_int, help="learning cycles per seed")
    p.add_argument("--out", type=Path, help="sweep directory (default runs/<name>-sweep-<time>)")
    p.add_argument("--workers", type=_positive_int, help="local processes (default: all cores)")
    p.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="run on a Dask cluster (default $FELTOOL_SCHEDULER, else locally)")
    p.add_argument("--resume", type=Path, metavar="SWEEP_DIR", help="continue a sweep")
    p.add_argument("--no-progress", dest="progress", action="store_false")
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("view", help="replay a recorded run in meshcat (or write rollout.html)")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--seed", type=int, help="seed to show (default: the first with traces)")
    p.add_argument("--cycles", default="first,last",
                   help="recorded cycles to show: first, last or first,last (default)")
    p.add_argument("--html", action="store_true",
                   help="write RUN_DIR/rollout.html instead of starting a viewer")
    p.add_argument("--zmq-url", metavar="URL", help="use this running meshcat-server")
    p.add_argument("--loops", type=int, default=0, metavar="N",
                   help="play the cycles N times, then stop (default 0: until Ctrl-C)")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("check", help="validate a config without running it")
    p.add_argument("config")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("robots", help="list bundled and example-robot-data robots")
    p.set_defaults(func=cmd_robots)

    p = sub.add_parser("inspect", help="joints, links, masses of a robot")
    p.add_argument("robot", help="bundled name, URDF path or example-robot-data:NAME")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("plot", help="(re)draw the figures of a run directory")
    p.add_argument("run_dir", type=Path)
    p.add_argument("--seed", type=int, help="seed for the per-seed figures")
    p.set_defaults(func=cmd_plot)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    args = build_parser().parse_args(argv)  # exits 2 on usage errors
    try:
        return args.func(args)
    except FeltoolError as exc:
        print(f"feltool: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("feltool: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
