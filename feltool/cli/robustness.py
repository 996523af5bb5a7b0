"""``feltool robustness``: every learner against noise, delay and model error."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from feltool.cli.common import subcommand
from feltool.errors import InputError
from feltool.runs.robustness import GOAL, LEARNERS, SCENARIOS, format_scores, robustness, scenarios_for, write


def cmd_robustness(args: argparse.Namespace) -> int:
    """``feltool robustness CONFIG``: scores of every learner x scenario."""
    from feltool.bounds import parse_seeds
    from feltool.config.files import apply_overrides, read_yaml
    from feltool.runs.experiments import build_experiment, resolve_config_path

    path = resolve_config_path(args.config)
    raw = apply_overrides(read_yaml(path), list(args.set or []))
    exp = build_experiment(raw, source=path)  # bad input fails here, before any run
    learners = _names(args.learners, LEARNERS, "--learners")
    known = scenarios_for(raw)
    scenarios = [known[n] for n in _names(args.scenarios, tuple(known), "--scenarios")]
    ranges = _ranges(args.range or [])
    scenarios = [replace(s, values=ranges.get(s.name, s.values)) for s in scenarios]
    seeds = parse_seeds(args.seeds) if args.seeds else exp.config.seed_list[:3]
    cycles = args.cycles or exp.config.sim.cycles
    out = args.out or Path("runs") / f"{exp.config.name}-robustness"
    if out.exists() and any(out.iterdir()):
        raise InputError(f"--out {out}: exists and is not empty; choose a new directory")
    result = robustness(raw, path, learners, scenarios, seeds, cycles,
                        log=None if args.quiet else sys.stderr, jobs=args.jobs)
    result["config"] = exp.config.name
    write(result, out)
    print(format_scores(result))
    print(f"\nscores: fraction of each range where every seed's feedback fell below "
          f"{GOAL:.0%} of its first cycle's; details in {out}/robustness.json")
    for s in scenarios:
        if s.not_applicable:
            print(f"{s.name}: not applicable: {s.not_applicable}")
    return 0


def _ranges(items: list[str]) -> dict[str, tuple[float, ...]]:
    """``--range NAME=V1,V2,...`` -> {NAME: (V1, V2, ...)}."""
    out = {}
    for item in items:
        name, _, values = item.partition("=")
        name = name.strip()
        if name not in SCENARIOS:
            raise InputError(f"--range {item}: unknown scenario '{name}'; choose from "
                             + ", ".join(SCENARIOS))
        try:
            out[name] = tuple(float(v) for v in values.split(",") if v.strip())
        except ValueError:
            raise InputError(f"--range {item}: the values must be numbers, e.g. "
                             f"{name}=1,1.5,2") from None
        if not out[name]:
            raise InputError(f"--range {item}: give at least one value")
    return out


def _names(spec: str | None, known: tuple[str, ...], option: str) -> list[str]:
    if not spec:
        return list(known)
    names = [s.strip() for s in spec.split(",") if s.strip()]
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise InputError(f"{option}: unknown {', '.join(bad) or 'empty list'}; choose from "
                         + ", ".join(known))
    return names


def add_command(sub) -> None:
    """Register ``feltool robustness`` on the CLI's subparsers ."""
    p = subcommand(sub, "robustness", "score every learner's robustness to noise, delay, model "
                 "error and period changes",
                 "  feltool robustness two_link_standard --seeds 0-2 --cycles 150\n"
                 "  feltool robustness two_link_standard --learners gradient,ilc_p "
                 "--scenarios delay,mass --out runs/rob")
    p.add_argument("config", help="experiment YAML, or the name of a bundled config")
    p.add_argument("--learners", help=f"comma-separated, from {', '.join(LEARNERS)} (default all)")
    p.add_argument("--scenarios", help=f"comma-separated, from {', '.join(SCENARIOS)} "
                   "(default all)")
    p.add_argument("--range", action="append", metavar="NAME=V1,V2",
                   help="the values of one scenario instead of its default range (repeatable)")
    p.add_argument("--seeds", help="seeds per point, e.g. 0-2 (default: the config's first 3)")
    p.add_argument("--cycles", type=int, help="learning cycles per run (default: the config's)")
    p.add_argument("--out", type=Path, help="output directory, new or empty (default "
                   "runs/<name>-robustness)")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE",
                   help="override a config field (repeatable)")
    p.add_argument("--jobs", "-j", type=int, default=1, help="seeds run at the same time "
                   "(processes; default 1)")
    p.add_argument("--quiet", "-q", action="store_true", help="print only the scores")
    p.set_defaults(func=cmd_robustness)
