"""``feltool gait``: design a walker's periodic gait, verify it in the walker, write it."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from feltool.cli.common import positive_int, subcommand
from feltool.cli.view import exit_on_sigterm
from feltool.errors import FeltoolError, InputError

#: Collocation intervals per step: a passive gait's period and step length are free and set by
#: the physics alone, so it gets more (100 match Drake's passive compass gait to 0.2 %).
KNOTS, PASSIVE_KNOTS = 40, 100


def cmd_gait(args: argparse.Namespace) -> int:
    """Design a walker's periodic gait (feltool/gait/design.py), verify it in feltool's own
    walker and close it on the loop's orbit (feltool/gait/orbit.py), write it as RMP demos."""
    from feltool.config.files import read_yaml
    from feltool.engines.compiled.library import cancel_pending
    from feltool.experiment.assemble import validate
    from feltool.gait.config import gait_config, gait_spec, walker_from_raw
    from feltool.gait.defaults import complete_walker, placeholder_gait
    from feltool.runs.experiments import resolve_config_path

    path = resolve_config_path(args.config)
    raw = read_yaml(path)
    walker, settings = walker_from_raw(raw, path)
    raw, defaults = complete_walker(raw, path, walker)
    if args.torso is not None and "base_pitch" not in walker.base:
        raise InputError(f"--torso: the walker in {path.name} has no base_pitch (its base joints "
                         f"are {', '.join(walker.base)})")
    spec = gait_spec(raw, walker, settings, speed=args.speed, step_length=args.step_length,
                     duration=args.duration, slope=args.slope, passive=args.passive,
                     knots=args.knots or (PASSIVE_KNOTS if args.passive else KNOTS),
                     torso_weight=args.torso_weight, torso=args.torso,
                     friction_margin=args.friction_margin,
                     normal_force_margin=args.normal_force_margin,
                     clearance_margin_m=args.clearance)
    # the whole config as it will be written (its demos the standing pose), before the solve
    provisional = gait_config(raw, walker, placeholder_gait(walker, spec), spec, settings)
    validate(provisional, path)
    for line in defaults:
        print(f"  default {line}")
    try:
        return _design_and_verify(args, path, raw, walker, settings, spec, defaults, provisional)
    finally:
        cancel_pending()  # (a library started ahead and not used: a failed design)


def _design_and_verify(args: argparse.Namespace, path: Path, raw: dict, walker, settings, spec,
                       defaults: list[str], provisional: dict) -> int:
    """:func:`cmd_gait` from the design on: the walker's compiled library (its graphs do not
    depend on the design: its demos and period are inputs) compiled meanwhile."""
    from feltool.engines.compiled.engine import compile_engine_ahead
    from feltool.gait.config import gait_config, write_gait_config
    from feltool.gait.defaults import robot_relative_to
    from feltool.gait.design import design_gait
    from feltool.gait.orbit import GaitNotWalking, close_on_orbit, verify_design
    from feltool.runs.experiments import build_experiment

    try:
        compile_engine_ahead(build_experiment(provisional, path))
    except FeltoolError:
        pass  # (only time: the design's own experiment is built and reports it)
    out = args.out or Path(f"{path.stem}-gait.yaml")

    def progress(it: int, viol: float, cost: float) -> None:
        if args.progress and it % 5 == 0:
            print(f"  ipopt iteration {it:4d}  constraint violation {viol:9.3e}  cost "
                  f"{cost:10.4e}", file=sys.stderr, flush=True)

    gait = design_gait(walker, spec, progress)
    st, m = gait.stats, gait.metrics
    print(f"{path.name}: gait designed in {st['solve_time_s']:.3g} s of solver time "
          f"({st['iterations']} iterations, {st['knots']} knots; building {st['build_time_s']:.2g}"
          " s)")
    print(f"  period {m['period_s']:.4g} s   speed {m['speed_m_per_s']:.4g} m/s   step length "
          f"{m['step_length_m']:.4g} m   cost of transport {m['cost_of_transport']:.3g}")
    clearance = m["min_clearance_m"]
    print(f"  min F_n {m['min_normal_force_mg']:.3g} mg   max |F_t|/F_n "
          f"{m['max_friction_ratio']:.3g} (designed <= {spec.friction:.3g})   impulse ratio "
          f"{m['impulse_ratio']:.3g}   max torque {m['max_torque']:.4g} N m")
    print("  swing-foot clearance outside the scuffing zone "
          + ("-" if clearance is None else f"{clearance:.3g} m")
          + f"   constraint violation {m['constraint_violation']:.2e}", flush=True)
    config = gait_config(raw, walker, gait, spec, settings)
    print(f"  verifying in feltool's walker ({args.verify_steps} steps, no learning) ...",
          flush=True)
    t0 = time.perf_counter()
    try:
        if args.demos == "orbit":
            config, orbit, check = close_on_orbit(config, path, build_experiment,
                                                  steps=args.verify_steps)
        else:
            check = verify_design(build_experiment(config, path), args.verify_steps)
            if not check.stable:
                raise GaitNotWalking(check)
    except GaitNotWalking as exc:  # nothing written; the failing walk may still be watched
        _print_verification(exc.check, time.perf_counter() - t0)
        _show_gait(lambda: build_experiment(config, path), exc.check, args)
        raise
    _print_verification(check, time.perf_counter() - t0)
    if args.demos == "orbit":
        print(f"  demos: the loop's periodic orbit, {orbit.samples_per_step[0]} control steps "
              f"per step (the collocation's knots tracked in the loop: summed feedback "
              f"{orbit.feedback:.3g} N m; on the orbit: {check.feedback:.2g} N m)")
    write_gait_config(out, robot_relative_to(config, path, out), gait,
                      "feltool gait " + " ".join(sys.argv[2:]), check, defaults)
    print(f"  written: {out}")
    _show_gait(lambda: build_experiment(config, path), check, args)
    return 0


def _print_verification(check, seconds: float) -> None:
    p = check.poincare
    print(f"  walked {check.steps} steps: " + ("yes" if check.walked else f"no, {check.reason}")
          + f"   ({seconds:.3g} s)")
    if check.steps:
        print(f"  in the loop: min F_n {check.min_normal_force_mg:.3g} mg   max |F_t|/F_n "
              f"{check.max_friction_ratio:.3g}   impulse ratio {check.max_impulse_ratio:.3g}   "
              f"max torque {check.max_torque:.4g} N m   lowest swing foot "
              f"{check.min_clearance_m * 1e3:.3g} mm")
    if check.scuffs:
        print(f"  compass-gait convention (walking.scuff_behind): the swing foot scuffed behind "
              f"the stance foot at {check.scuffs} control steps (ignored)")
    if p:
        print(f"  Poincaré: fixed point residual {p.get('fixed_point_residual', float('nan')):.2g}"
              + (f", spectral radius {p['spectral_radius']:.3g}"
                 if p.get("fixed_point_found") else ", no fixed point"))


def _show_gait(build, check, args: argparse.Namespace) -> None:
    """The verified walk in meshcat: an HTML file (``--html``) and/or the live viewer
    (``--view``) until Ctrl-C or ``--view-timeout``; ``build()`` the walk's experiment (built
    only to be shown)."""
    if not (args.html or args.view) or check.frames is None or not len(check.frames):
        return
    exp = build()
    dt = exp.config.dt
    if args.html:
        from feltool.viewer.html import record_html

        clip = {f"designed gait, {check.steps} steps": check.frames}
        print(f"  walk: {record_html(exp.robot, clip, dt, args.html, title=str(args.config))}")
    if args.view:
        from feltool.viewer.live import LiveViewer
        from feltool.viewer.rollout import LiveStream

        exit_on_sigterm()
        timeout = args.view_timeout
        deadline = None if timeout is None else time.monotonic() + timeout
        with LiveViewer(exp.robot) as viewer:
            stream = LiveStream(viewer, dt, realtime=True, out=None)
            try:
                print(f"feltool viewer: serving {viewer.url} until Ctrl-C"
                      + ("" if timeout is None else f" or {timeout:g} s"), flush=True)
                while deadline is None or time.monotonic() < deadline:
                    stream.play(check.frames)
            except KeyboardInterrupt:
                pass
        print("feltool viewer: stopped", flush=True)


def add_command(sub) -> None:
    """Add ``feltool gait`` to the subparsers ``sub``."""
    p = subcommand(sub, "gait", "design a walker's periodic gait by trajectory optimization",
             "  feltool gait configs/gaits/compass_gait.yaml --out gait.yaml\n"
             "  feltool gait configs/gaits/three_link_walker.yaml --speed 0.8\n"
             "  feltool gait configs/gaits/compass_gait.yaml --passive --slope 0.0525\n\n"
             "exit code 0 with the gait written, 1 when no gait was found or the design does "
             "not walk stably in feltool's walker (nothing written), "
             "2 bad input")
    p.add_argument("config", help="a physical walker's experiment YAML (walking.feet, legs)")
    length = p.add_mutually_exclusive_group()
    length.add_argument("--speed", type=float, metavar="V", help="mean speed in [m/s]")
    length.add_argument("--step-length", type=float, metavar="L", help="step length in [m] "
                        "(default 0.35 hip heights)")
    p.add_argument("--duration", type=float, metavar="T", help="step duration in [s] (default: "
                   "period_s / walking.steps_per_cycle; free for --passive)")
    p.add_argument("--slope", type=float, metavar="RAD", help="ground slope in [rad], downhill "
                   "along +x (default: the config's gravity)")
    p.add_argument("--passive", action="store_true", help="no motor torque: the passive gait "
                   "on the slope (period and step length free)")
    p.add_argument("--knots", type=positive_int, help="collocation intervals per "
                   f"step (default {KNOTS}, {PASSIVE_KNOTS} with --passive)")
    p.add_argument("--torso-weight", type=float, metavar="W", help="weight of the torso's "
                   "motion about its mean per [rad^2 s] (default 100; the torque cost is ~0.01)")
    p.add_argument("--torso", type=float, metavar="RAD", help="the torso's (base_pitch's) mean "
                   "pitch in [rad] (default: its stabilize target, else free)")
    p.add_argument("--friction-margin", type=float, default=0.85, metavar="F",
                   help="design within F times walking.friction (default 0.85)")
    p.add_argument("--normal-force-margin", type=float, default=0.05, metavar="F",
                   help="least normal force F m g above walking.normal_force_min (default 0.05)")
    p.add_argument("--clearance", type=float, default=0.002, metavar="M",
                   help="least swing-foot height in [m] outside the scuffing zone (default 0.002)")
    p.add_argument("--demos", choices=("orbit", "knots"), default="orbit",
                   help="orbit (default): the loop's own periodic orbit at the control rate, on "
                   "which the feedback is zero; knots: the collocation's knots")
    p.add_argument("--verify-steps", type=positive_int, default=20, metavar="N",
                   help="steps walked in feltool's walker to verify the design (default 20)")
    p.add_argument("--out", type=Path, help="config to write (default <config>-gait.yaml)")
    p.add_argument("--html", type=Path, metavar="PATH", help="write the verified walk as one "
                   "HTML file (meshcat, no server)")
    p.add_argument("--view", action="store_true", help="show the verified walk in meshcat in "
                   "the browser, until Ctrl-C or --view-timeout")
    p.add_argument("--view-timeout", type=float, metavar="S", help="with --view: stop after S s")
    p.add_argument("--no-progress", dest="progress", action="store_false",
                   help="no IPOPT progress lines")
    p.set_defaults(func=cmd_gait)
