"""The ``feltool`` command.

Exit codes: 0 success, 2 bad input (config, URDF, arguments), 1 anything else. Bad input prints
what is wrong and where, never a traceback.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from feltool.errors import FeltoolError, InputError

app = typer.Typer(add_completion=False, pretty_exceptions_enable=False, no_args_is_help=True,
                  help="Feedback error learning of rhythmic movement primitives on URDF robots.")


def parse_seeds(spec: str) -> list[int]:
    """``0-19`` | ``0,3,7`` | ``5`` (a single seed) -> a list of seeds."""
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


@app.command()
def run(
    config: Annotated[str, typer.Argument(help="Experiment YAML (or a bundled config's name).")],
    seeds: Annotated[Optional[str], typer.Option(help="Seeds, e.g. 0-19 or 0,3,7.")] = None,
    cycles: Annotated[Optional[int], typer.Option(min=1, help="Learning cycles per seed.")] = None,
    out: Annotated[Optional[Path], typer.Option(help="Run directory to write.")] = None,
    set_: Annotated[Optional[list[str]], typer.Option(
        "--set", help="Override a config field: a.b.c=VALUE (repeatable).")] = None,
    workers: Annotated[Optional[int], typer.Option(min=1, help="Processes (default: all cores).")] = None,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
) -> None:
    """Run an experiment over its seeds and write a run directory."""
    from feltool.config import apply_overrides, read_yaml
    from feltool.experiment import build_experiment, resolve_config_path
    from feltool.runner import default_out_dir, run_experiment

    path = resolve_config_path(config)
    overrides = list(set_ or [])
    if cycles is not None:
        overrides.append(f"sim.cycles={cycles}")
    if seeds is not None:
        overrides.append(f"seeds={parse_seeds(seeds)}")
    raw = apply_overrides(read_yaml(path), overrides)
    exp = build_experiment(raw, source=path)
    out_dir = out or default_out_dir(exp.config.name)
    summary = run_experiment(exp, raw, out_dir, workers=workers, show_progress=progress)
    print_summary(summary, out_dir)
    if summary["aggregate"]["n_diverged"]:
        raise typer.Exit(1)


def print_summary(summary: dict, out_dir: Path) -> None:
    agg = summary["aggregate"]
    typer.echo(f"{summary['config']}: {agg['n_seeds']} seeds, error signal = feedback of "
               f"{', '.join(summary['error_joints'])}")
    typer.echo(f"  {'seed':>4} {'cycles':>6} {'fb_initial':>11} {'fb_final':>10} "
               f"{'ratio':>8} {'converged':>9} {'steps/s':>9}")
    for s in summary["seeds"]:
        if s["diverged"]:
            typer.echo(f"  {s['seed']:>4} DIVERGED: {s['diverged_reason']}")
            continue
        conv = "-" if s["converged_cycle"] is None else str(s["converged_cycle"])
        typer.echo(f"  {s['seed']:>4} {s['cycles']:>6} {s['fb_initial']:>11.4g} "
                   f"{s['fb_final']:>10.3g} {s['fb_ratio']:>8.2%} {conv:>9} "
                   f"{s['steps_per_s']:>9.0f}")
    conv = agg["converged_cycle_max"]
    typer.echo(f"  converged (below 5 % of initial and staying there): {agg['n_converged']}/"
               f"{agg['n_seeds']} seeds" + (f", mean cycle {agg['converged_cycle_mean']:.1f}, "
                                             f"max {conv}" if conv is not None else ""))
    typer.echo(f"  diverged: {agg['n_diverged']}   run directory: {out_dir}")


@app.command()
def check(
    config: Annotated[str, typer.Argument(help="Experiment YAML to validate.")],
    set_: Annotated[Optional[list[str]], typer.Option("--set", help="a.b.c=VALUE overrides.")] = None,
) -> None:
    """Validate a config (schema, robot, joint names) without running it."""
    from feltool.config import apply_overrides, read_yaml
    from feltool.experiment import build_experiment, resolve_config_path

    path = resolve_config_path(config)
    exp = build_experiment(apply_overrides(read_yaml(path), list(set_ or [])), source=path)
    cfg = exp.config
    typer.echo(f"{path}: ok - robot {exp.robot.name} ({len(exp.joints)} joints moving), "
               f"{cfg.steps_per_cycle} steps per cycle, learned: "
               f"{', '.join(exp.learned_joints) or 'nothing'}, {len(cfg.seed_list)} seeds")


@app.command()
def robots() -> None:
    """List bundled robots and example-robot-data robots."""
    from feltool.robot import bundled_robots, erd_robots

    typer.echo("bundled:")
    for name in bundled_robots():
        typer.echo(f"  {name}")
    typer.echo("example-robot-data (use as example-robot-data:NAME):")
    for name in erd_robots():
        typer.echo(f"  {name}")


@app.command()
def inspect(
    robot: Annotated[str, typer.Argument(help="Bundled name, URDF path or example-robot-data:NAME.")],
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Joints (name, type, axis, limits), links with masses, and the total mass of a robot."""
    from feltool.robot import describe, load_robot

    info = describe(load_robot(robot, base_dir=Path.cwd()))
    if as_json:
        typer.echo(json.dumps(info, indent=2))
        return
    typer.echo(f"robot {info['name']}  ({info['source']})")
    typer.echo(f"  {'joint':<24} {'type':<12} {'axis':<20} {'limits [rad|m]':<22}")
    for j in info["joints"]:
        lim = f"[{j['lower']:.4g}, {j['upper']:.4g}]"
        typer.echo(f"  {j['name']:<24} {j['type']:<12} {str(j['axis']):<20} {lim:<22}")
    typer.echo(f"  {'body':<24} {'mass [kg]':>10}")
    for b in info["bodies"]:
        typer.echo(f"  {b['name']:<24} {b['mass']:>10.4g}")
    typer.echo(f"  total mass: {info['total_mass']:.4g} kg")


@app.command()
def plot(
    run_dir: Annotated[Path, typer.Argument(help="A run directory.")],
    seed: Annotated[Optional[int], typer.Option(help="Seed for per-seed figures.")] = None,
) -> None:
    """(Re)draw the figures of a run directory."""
    from feltool.plots import draw_figures

    for path in draw_figures(run_dir, seed):
        typer.echo(str(path))


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script."""
    try:
        app(args=argv, standalone_mode=False)
    except FeltoolError as exc:
        typer.echo(f"feltool: error: {exc}", err=True)
        return exc.exit_code
    except typer.Exit as exc:
        return exc.exit_code
    except typer.Abort:
        typer.echo("feltool: aborted", err=True)
        return 130
    except KeyboardInterrupt:
        typer.echo("feltool: interrupted", err=True)
        return 130
    except Exception as exc:  # click usage errors
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            return exc.exit_code
        raise
    return 0


if __name__ == "__main__":
    sys.exit(main())
