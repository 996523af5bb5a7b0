"""The per-seed table of docs/biped.md from benchmarks/walk_learning.py's JSON files.

Usage: ``python benchmarks/walk_learning_table.py docs/figures/walk_*.json``
"""

from __future__ import annotations

import json
import sys


def fmt(x, f="{:.3g}"):
    return "–" if x is None else f.format(x)


def main() -> None:
    for path in sys.argv[1:]:
        d = json.load(open(path))
        print(f"\n`{d['config']}`, {d['cycles']} cycles:\n")
        print("| seed | walked | fb first → last [N m] | ratio | RMS from design, last cycle "
              "[rad] | min F_n/mg | max \\|F_t\\|/F_n | max \\|I_x\\|/I_z | clipped steps | "
              "fixed-point residual | ρ | kick ±0.3 rad/s |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for r in d["seeds"]:
            kicks = [r.get(k) for k in ("kick_+0.30", "kick_-0.30")]
            kick = ("–" if kicks[0] is None else
                    " / ".join("recovered" if k and k.get("recovered") else "no" for k in kicks))
            clip = sum((r.get("torque_limit_steps") or {}).values())
            fb = (f"{fmt(r['fb_first'])} → {fmt(r['fb_last'])}" if r["fb_first"] is not None
                  else "–")
            walked = "yes" if r["walked"] else f"no ({(r.get('reason') or '')[:60]})"
            print(f"| {r['seed']} | {walked} | {fb} | {fmt(r['ratio'], '{:.1e}')} | "
                  f"{fmt(r['torso_rms_last_rad'], '{:.2e}')} | "
                  f"{fmt(r['min_normal_force_mg'], '{:.2f}')} | "
                  f"{fmt(r['max_friction_ratio'], '{:.2f}')} | "
                  f"{fmt(r['max_impulse_ratio'], '{:.2f}')} | {clip} | "
                  f"{fmt(r.get('fixed_point_residual'), '{:.1e}')} | "
                  f"{fmt(r.get('spectral_radius'), '{:.3f}')} | {kick} |")


if __name__ == "__main__":
    main()
