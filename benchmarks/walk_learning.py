"""FEL on the physical walkers: per seed, whether it walked, the feedback's ratio, the torso's
error, and (``--poincare``) the fixed point and a torso kick; the figures of docs/biped.md.

Usage::

    python benchmarks/walk_learning.py configs/gaits/five_link_walker.yaml --seeds 0-9 \
        --cycles 15 --out docs/figures/walk_five_link --json results/five_link.json \
        [--poincare 0-2] [--kick 0.3]

Per seed it prints: walked (every step passed the contact checks), the summed feedback of the
first and last cycle [N m] and their ratio, the RMS error of the learned joint from its designed
motion over the last cycle [rad], the contact extremes (min F_n / mg, max |F_t|/F_n, max
|I_x|/I_z), the motor torque steps over the URDF limit; with ``--poincare``: the fixed point's
residual and the Poincaré spectral radius of the learned gait, and whether a kick of
``--kick`` rad/s to the torso (the pitch) is recovered (the learned gait held fixed: every step
walks for 20 cycles and the state's distance from the fixed point shrinks by 1000 from the
first cycle's). Figures (PNG):
the summed feedback over cycles (every seed), the normal force and friction ratio over the last
cycle of seed 0, and the limit cycle of the stance leg's angle (phase plot).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from feltool.gait.poincare import poincare
from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed


def seeds(spec: str) -> list[int]:
    if "-" in spec:
        a, b = spec.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in spec.split(",") if s]


def kick_recovered(exp, theta, x_star, dv: float, cycles: int = 20) -> dict:
    """The learned gait (theta fixed) from its fixed point with ``dv`` [rad/s] added to the
    pitch's rate: every cycle walks, and the distance to the fixed point at the end."""
    nv = exp.robot.model.nv
    P, Pv, Pa = exp.primitives.desired(theta)
    pitch = exp.joints.index("base_pitch")
    q, v = x_star[:nv].copy(), x_star[nv:].copy()
    v[pitch] += dv
    dist = []
    for _ in range(cycles):
        log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
        if log.fall:
            return {"recovered": False, "reason": log.fall}
        q, v = log.q_end, log.v_end
        dist.append(float(np.abs(np.concatenate([q, v]) - x_star).max()))
    return {"recovered": bool(dist[-1] < 1e-3 * dist[0]), "distance_end": dist[-1],
            "distance_first": dist[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--cycles", type=int, default=15)
    ap.add_argument("--poincare", default="", help="seeds to analyse, e.g. 0-2")
    ap.add_argument("--kick", type=float, default=0.3, help="[rad/s]")
    ap.add_argument("--out", default=None, help="figure path prefix")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    exp = load_experiment(args.config, ["walking.poincare=false"])
    mg = exp.robot.total_mass * float(np.linalg.norm(exp.robot.model.gravity.linear))
    analysed = set(seeds(args.poincare))
    results, curves, last_trace = [], {}, None
    for seed in seeds(args.seeds):
        res = run_seed(exp, seed, cycles=args.cycles)
        fb = [r["fb_abs_mean_error"] for r in res.rows]
        w = res.summary.get("walking", {})
        hits = res.summary["limits"]
        row = {
            "seed": seed, "walked": bool(w.get("walked")), "cycles": len(fb),
            "fb_first": fb[0] if fb else None, "fb_last": fb[-1] if fb else None,
            "ratio": fb[-1] / fb[0] if fb else None,
            "torso_rms_last_rad": w.get("stabilized_rms_last_rad"),
            "min_normal_force_mg": (w["min_normal_force_N"] / mg
                                    if "min_normal_force_N" in w else None),
            "max_friction_ratio": w.get("max_friction_ratio"),
            "max_impulse_ratio": w.get("max_impulse_ratio"),
            "torque_limit_steps": (hits.get("torque_limit_steps")
                                   if isinstance(hits, dict) else None),
            "reason": res.summary.get("diverged_reason"),
        }
        curves[seed] = fb
        if seed in analysed and row["walked"]:
            theta = exp.initial_parameters(seed)
            for name in exp.learned_joints:  # the learned parameters at the end
                sl = exp.primitives.slices[exp.joints.index(name)]
                theta[sl.start:sl.stop - 1] = res.params[f"{name}.weights_history"][-1]
                theta[sl.stop - 1] = res.params[f"{name}.goal_history"][-1]
            pc = poincare(exp, theta, *_end_state(exp, res, theta))
            row["fixed_point_residual"] = pc.get("fixed_point_residual")
            row["spectral_radius"] = pc.get("spectral_radius")
            if pc.get("fixed_point_found"):
                x_star = np.concatenate([pc["fixed_point_q"], pc["fixed_point_v"]])
                for dv in (args.kick, -args.kick):
                    row[f"kick_{dv:+.2f}"] = kick_recovered(exp, theta, x_star, dv)
        if seed == min(seeds(args.seeds)):
            last_trace = _last_cycle(exp, res)
        results.append(row)
        print(json.dumps(row), flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({"config": args.config, "cycles": args.cycles,
                                               "seeds": results, "curves": curves}, indent=1))
    if args.out:
        figures(args.out, exp, curves, last_trace, mg)


def _end_state(exp, res, theta):
    """A start state of the learned gait: five cycles with the learned parameters from the
    designed start (the analysis then iterates to the fixed point)."""
    P, Pv, Pa = exp.primitives.desired(theta)
    q, v = exp.hybrid.initial_state(P, Pv)
    for _ in range(5):
        log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
        if log.fall:
            break
        q, v = log.q_end, log.v_end
    return q, v


def _last_cycle(exp, res):
    """Seed's last-cycle log, rerun with the learned parameters from the designed start."""
    theta = exp.initial_parameters(res.seed)
    for name in exp.learned_joints:
        sl = exp.primitives.slices[exp.joints.index(name)]
        theta[sl.start:sl.stop - 1] = res.params[f"{name}.weights_history"][-1]
        theta[sl.stop - 1] = res.params[f"{name}.goal_history"][-1]
    q, v = _end_state(exp, res, theta)
    P, Pv, Pa = exp.primitives.desired(theta)
    return exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)


def figures(prefix: str, exp, curves: dict, log, mg: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    Path(prefix).parent.mkdir(parents=True, exist_ok=True)
    name = exp.config.name
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for seed, fb in curves.items():
        ax.semilogy(np.arange(1, len(fb) + 1), fb, lw=1, label=f"seed {seed}")
    ax.set_xlabel("cycle")
    ax.set_ylabel("summed mean |feedback| [N m]")
    ax.set_title(f"{name}: FEL from a perturbed RMP")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(f"{prefix}_feedback.png", dpi=110)
    plt.close(fig)
    if log is None or log.fall:
        return
    dt = exp.config.dt
    t = np.arange(len(log.q)) * dt
    F = log.force
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(5, 4), sharex=True)
    a1.plot(t, F[:, 1] / mg)
    a1.axhline(0.2, color="r", ls="--", lw=0.8)
    a1.set_ylabel("F_n / mg")
    a2.plot(t, np.abs(F[:, 0]) / F[:, 1])
    a2.axhline(0.6, color="r", ls="--", lw=0.8)
    a2.set_ylabel("|F_t| / F_n")
    a2.set_xlabel("t [s] (one cycle, two steps)")
    a1.set_title(f"{name}: stance foot's force, learned gait", fontsize=10)
    fig.tight_layout()
    fig.savefig(f"{prefix}_grf.png", dpi=110)
    plt.close(fig)
    pitch = exp.joints.index("base_pitch")
    W = exp.hybrid.walker
    hip = W.motor_v[0]
    fig, ax = plt.subplots(figsize=(4.2, 3.6))
    for idx, lab in ((pitch, "base_pitch"), (hip, exp.joints[hip])):
        ax.plot(log.q[:, idx], log.v[:, idx], lw=1, label=lab)
    ax.set_xlabel("angle [rad]")
    ax.set_ylabel("rate [rad/s]")
    ax.legend(fontsize=8)
    ax.set_title(f"{name}: limit cycle (one cycle)")
    fig.tight_layout()
    fig.savefig(f"{prefix}_phase.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
