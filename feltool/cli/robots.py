"""``feltool robots`` and ``feltool inspect``: the robots there are, and what one of them has."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from feltool.cli.common import subcommand


def cmd_robots(args: argparse.Namespace) -> int:
    from feltool.robot.robot import bundled_robots, erd_robots

    print("bundled:")
    for name in bundled_robots():
        print(f"  {name}")
    print("example-robot-data (use as example-robot-data:NAME):")
    for name in erd_robots():
        print(f"  {name}")
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    from feltool.robot.inspection import config_skeleton, describe, parse_pose, to_yaml
    from feltool.robot.robot import load_robot

    robot = load_robot(args.robot, base_dir=Path.cwd(), lenient=not args.strict)
    q = parse_pose(robot, args.pose)
    info = describe(robot, q)
    skeleton = config_skeleton(robot, q if args.pose else None)
    fmt = "json" if args.json else args.format
    if fmt == "json":
        print(json.dumps({**info, "config_skeleton": skeleton}, indent=2, allow_nan=False))
        return 0
    if fmt == "yaml":
        print(to_yaml({**info, "config_skeleton": skeleton}), end="")
        return 0
    _print_inspection(info)
    print("\nsuggested config (feltool check accepts it as it is; give other joints a role):\n")
    print(skeleton)
    return 0


def _print_inspection(info: dict) -> None:
    """``feltool inspect``'s tables."""
    fmt = lambda x: "-" if x is None else f"{x:.4g}"  # noqa: E731
    print(f"robot {info['name']}  ({info['source']})")
    for line in info["warnings"]:
        print(f"  read leniently: {line}")
    print(f"  {'joint':<22} {'type':<11} {'axis':<18} {'position':>9} {'limits [rad|m]':<20} "
          f"{'effort':>8} {'actuated':>8}  {'parent':<16}")
    for j in info["joints"]:
        lim = "none" if j["lower"] is None else f"[{j['lower']:.4g}, {j['upper']:.4g}]"
        axis = "-" if j["axis"] is None else str([round(a, 3) for a in j["axis"]])
        print(f"  {j['name']:<22} {j['type']:<11} {axis:<18} {fmt(j['position']):>9} {lim:<20} "
              f"{'inf' if j['effort'] is None and j['nv'] == 1 else fmt(j['effort']):>8} "
              f"{'yes' if j['actuated'] else 'no':>8}  {j['parent']:<16}")
    print(f"  {'body (moved by joint)':<22} {'mass [kg]':>10}")
    for b in info["bodies"]:
        print(f"  {b['name']:<22} {b['mass']:>10.4g}")
    print(f"  total mass: {info['total_mass']:.4g} kg   centre of mass: {info['com']} m")
    print(f"\n  {'frame':<28} {'type':<12} {'parent joint':<22} {'position [m]':<30} target "
          "(about: world axis, vector: in the frame)")
    for f in info["frames"]:
        t = f["target"]
        target = "- (no joint turns it)" if t is None else \
            f"vector {t['vector']}, about {t['about']}"
        print(f"  {f['name']:<28} {f['type']:<12} {f['parent_joint']:<22} "
              f"{str(f['position']):<30} {target}")
    print("\n  targets a stabilizing joint can hold, with their values at this pose [rad]:")
    for t in info["targets"]:
        print("    target: {" + ", ".join(f"{k}: {v}" for k, v in t.items()) + "}")


def add_command(sub) -> None:
    """Add ``feltool robots / inspect`` to the subparsers ``sub``."""
    p = subcommand(sub, "robots", "list bundled and example-robot-data robots",
             "  feltool robots\n  feltool inspect $(feltool robots | sed -n 2p)")
    p.set_defaults(func=cmd_robots)

    p = subcommand(sub, "inspect", "joints, frames, masses and targets of a robot, and a config "
             "skeleton", "  feltool inspect two_link_arm\n"
             "  feltool inspect path/to/robot.urdf --format json\n"
             "  feltool inspect two_link_arm --pose shoulder=1.2,elbow=0.4   # targets' values\n"
             "  feltool inspect example-robot-data:ur5 | head")
    p.add_argument("robot", help="bundled name, URDF path or example-robot-data:NAME")
    p.add_argument("--pose", metavar="JOINT=VALUE,...", help="the pose [rad or m] at which "
                   "positions and targets are given (other joints neutral)")
    p.add_argument("--format", choices=("text", "yaml", "json"), default="text",
                   help="text tables (default), or yaml / json for scripts")
    p.add_argument("--json", action="store_true", help="the same as --format json")
    p.add_argument("--strict", action="store_true", help="refuse the URDF dialects that "
                   "lenient reading accepts (as robot: {source: ..., lenient: false} does)")
    p.set_defaults(func=cmd_inspect)
