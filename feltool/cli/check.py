"""``feltool check``: validate a config (schema, URDF, targets, gains, rate) without running it."""

from __future__ import annotations

import argparse

from feltool.cli.common import load_config, print_warnings, subcommand


def cmd_check(args: argparse.Namespace) -> int:
    from feltool.cli.legged import check_legged, legged_raw
    from feltool.errors import ConfigError
    from feltool.experiment.checks import experiment_problems

    legged = legged_raw(args.config, list(args.set or []))
    if legged is not None:  # walking.base: free_flyer (docs/legged.md)
        return check_legged(*legged)
    exp, _ = load_config(args.config, list(args.set or []), check_targets=False)
    cfg = exp.config
    print_warnings(exp.robot)
    problems = experiment_problems(exp)
    if problems:
        raise ConfigError(problems, str(exp.source) if exp.source else None)
    print(f"{exp.source}: ok - robot {exp.robot.name} ({len(exp.joints)} moving joints: "
          f"{', '.join(exp.joints)}), {cfg.period_s * cfg.sim.rate_hz:g} steps per cycle, "
          f"phase {cfg.primitives.phase}, learned: "
          f"{', '.join(exp.learned_joints) or 'nothing'}, error signal: "
          f"{', '.join(exp.error_joints)}, {len(cfg.seed_list)} seeds")
    if exp.demo_fit_rms:
        print("  demo fit (RMS of the RMP's limit cycle minus the demonstration): "
              + ", ".join(f"{j} {e:.3g} rad" for j, e in exp.demo_fit_rms.items()))
    return 0



def add_command(sub) -> None:
    """Add ``feltool check`` to the subparsers ``sub``."""
    p = subcommand(sub, "check", "validate a config without running it",
             "  feltool check configs/two_link_human_arm.yaml\n"
             "  feltool check two_link_standard --set sim.rate_hz=1000\n\n"
             "exit code 0 when the config is valid, 2 with one line per problem otherwise")
    p.add_argument("config", help="experiment YAML, or the name of a bundled config")
    p.add_argument("--set", action="append", metavar="A.B.C=VALUE",
                   help="override a config field before checking (repeatable)")
    p.set_defaults(func=cmd_check)
