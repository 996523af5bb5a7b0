"""Gait acquisition in a world the model does not know (issue 28): the table and figures of
docs/biped.md, "Learning a world the model does not know".

Each shipped physical walker (three-link, five-link) starts on its designed gait (its learned
joint at the design: ``init: demo``) and from cycle 3 walks in a world its known model does not
know (``events:``, the simulated plant only; controller, RNEA and the error estimate stay on
the known model):

* ``payload``: a point mass of 10 % of the robot's total mass at the torso body's centre of
  mass;
* ``mass``: every body's mass and rotational inertia +20 % (``{kind: mass, scale: 1.2}``);
* ``slope``: a 0.03 rad downhill slope (gravity tilted; on the compass gait, whose known model
  walks a 0.03 rad slope, 0.03 rad steeper).

``--walkers compass_gait --worlds mass slope``: the compass gait where the worlds apply (it
has no torso for the payload).

The learners: the shipped trajectory FEL (the torso's RMP) and, per ``--learner``, classic FEL
of the model (``learning.model``: the regressor's inertial-parameter correction and/or a
constant torque per motor; feltool.learning.walker_model); ``exact``: nothing learned, but
the plant's exact inverse model in the feedforward from the change on (the floor any
feedforward learner can reach while the feedback holds the design); ``redesign``:
``model_bias`` and the gait re-designed online every 10 s walked on the world identified from
the walker's measured motion (``learning.redesign``, feltool/runs/redesign.py), with the
shipped gait's design options; ``redesign_exact``: the same re-design given the plant's own
model (the oracle of the identification); ``redesign_slope``: ``redesign`` with the model
learner's ground slope too (``learning.model.slope``). Seeds 0-9 were fixed before looking;
150 cycles each, on the compiled engine, contact checks on. Per seed: walks every step after
the change, the torso's largest per-cycle RMS error from its target after the change [rad],
and the feedback ratio (summed feedback of the last cycle / of the change's cycle).

Usage::

    python benchmarks/walk_unknown_world.py [--walkers three_link_walker five_link_walker]
        [--worlds payload mass slope] [--seeds 0-9] [--cycles 150] [--learner model_bias]
        [--figures docs/figures] [--markdown table.md]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

ROOT = Path(__file__).resolve().parents[1]
CHANGE = 3  # the cycle of the world's change

#: The learners compared: overrides on top of the shipped config.
LEARNERS = {
    "trajectory": [],  # the shipped trajectory FEL alone (the torso's RMP)
    "model": ["learning.model={features: regressor, update: gauss_newton, rate: 0.5, "
              "damping: 1.0e-3}"],
    "bias": ["learning.model={features: none, update: gauss_newton, rate: 0.0, "
             "motor_bias: 0.5}"],
    "model_bias": ["learning.model={features: regressor, update: gauss_newton, rate: 0.5, "
                   "motor_bias: 0.5, damping: 1.0e-3}"],
}
#: ``--learner redesign`` / ``redesign_slope``: ``model_bias`` (and a learned ground slope),
#: and the gait re-designed online on the identified model (``learning.redesign``) with the
#: shipped gait's design options (the first line of its config)
REDESIGN = {
    "three_link_walker": "step_length_m: 0.5, duration_s: 0.6, torso_rad: 0.1, blend_cycles: 10, "
                         "friction_margin: 0.6, normal_force_margin: 0.5",
    "five_link_walker": "speed_m_s: 0.8, duration_s: 0.5, torso_rad: 0.1",
    "compass_gait": "step_length_m: 0.4, duration_s: 0.6",
}
REDESIGN_EVERY_S = 10.0  # [s] walked between re-designs
LEARNERS["redesign"] = LEARNERS["model_bias"]
LEARNERS["redesign_exact"] = LEARNERS["model_bias"]  # the re-design given the plant's model
LEARNERS["redesign_slope"] = [
    "learning.model={features: regressor, update: gauss_newton, rate: 0.5, motor_bias: 0.5, "
    "slope: 0.5, damping: 1.0e-3}"]


def learner_overrides(walker: str, learner: str) -> list[str]:
    """The overrides of ``learner`` on ``walker``."""
    over = list(LEARNERS[learner])
    if learner.startswith("redesign"):
        over.append(f"learning.redesign={{every_s: {REDESIGN_EVERY_S}, {REDESIGN[walker]}}}")
    return over


def world_event(world: str, exp) -> dict:
    """The world's event (from cycle :data:`CHANGE`) for the walker of ``exp``."""
    model = exp.hybrid.walker.walker.model
    if world == "payload":
        total = sum(float(model.inertias[j].mass) for j in range(1, model.njoints))
        torso = model.inertias[model.getJointId("base_pitch")]
        return {"cycle": CHANGE, "kind": "payload", "frame": "torso", "mass": 0.1 * total,
                "com": [float(x) for x in torso.lever]}
    if world == "mass":
        return {"cycle": CHANGE, "kind": "mass", "scale": 1.2}
    if world == "slope":
        return {"cycle": CHANGE, "kind": "slope", "angle": 0.03}
    raise ValueError(world)


def config_path(walker: str) -> Path:
    """The shipped config of ``walker``."""
    return ROOT / "configs" / "gaits" / f"{walker}.yaml"


def overrides(walker: str, world: str, learner: str, config: Path | None = None,
              extra: list[str] | None = None) -> list[str]:
    """The ``--set`` overrides of one case (``config``: another config of the walker, default
    its shipped one; ``extra``: overrides first, e.g. the known model's robot or gravity)."""
    extra = list(extra or [])
    probe = load_experiment(config or config_path(walker), extra + ["walking.poincare=false"])
    learned = probe.learned_joints
    ev = json.dumps(world_event(world, probe))
    return (extra + ["walking.poincare=false", "backend=compiled", f"events=[{ev}]"]
            + [f"joints.{j}.learn.init=demo" for j in learned]
            + learner_overrides(walker, learner))


def exact_correction(exp, world: str):
    """The oracle: the plant's own inverse model minus the known one, RNEA_plant - RNEA_known
    [N m] (what a perfect model learner would add to the feedforward)."""
    import pinocchio as pin

    from feltool.config.events import EventConfig
    from feltool.plant.events import changed_model

    known = exp.hybrid.walker.walker.model
    ev = world_event(world, exp)
    plant = changed_model(known, [EventConfig(**ev)])
    dk, dp = known.createData(), plant.createData()
    return lambda qd, vd, ad: pin.rnea(plant, dp, qd, vd, ad) - pin.rnea(known, dk, qd, vd, ad)


def run_case(walker: str, world: str, learner: str, seed: int, cycles: int,
             config: Path | None = None, extra: list[str] | None = None) -> dict:
    """One seed of one case: its per-cycle feedback and the acceptance's numbers. Learner
    ``exact`` (the experiment behind the table's "why"): the plant's exact inverse model in the
    feedforward from the change on (Python engine: the correction is a hook of its loop).
    ``config`` (default the walker's shipped one) and ``extra`` overrides: the gait designed in
    the changed world (benchmarks/walk_unknown_world_cause.py)."""
    over = overrides(walker, world, learner if learner != "exact" else "trajectory", config,
                     extra)
    if learner == "exact":  # nothing learned: the feedforward's floor
        over = [o for o in over if o != "backend=compiled"] + ["backend=pinocchio",
                                                                "learning.rates.weights=0",
                                                                "learning.rates.gauss_newton=0"]
    exp = load_experiment(config or config_path(walker), over)
    progress = None
    if learner == "exact":
        oracle = exact_correction(exp, world)

        def progress(cycle, fb):
            if cycle == CHANGE - 1:
                exp.hybrid.model_correction = oracle

    oracle = None
    if learner == "redesign_exact":  # the re-design on the plant's own model (from the change)
        from feltool.config.events import EventConfig
        from feltool.plant.events import changed_model

        known = exp.model_learner.model
        ev = world_event(world, exp)
        plant = changed_model(known, [EventConfig(**ev)])
        if ev["kind"] == "slope":  # the designer takes the slope apart; the model stays level
            plant = known
        slope = exp.model_learner.slope0 + (ev["angle"] if ev["kind"] == "slope" else 0.0)
        oracle = lambda theta_m: (plant, slope)  # noqa: E731
    res = run_seed(exp, seed, cycles=cycles, progress=progress, redesign_world=oracle)
    fb = [r["fb_abs_mean_error"] for r in res.rows]
    torso = [r.get("stabilized_rms", np.nan) for r in res.rows[CHANGE - 1:]]
    walk = res.summary.get("walking", {})
    steps = walk.get("steps", 0)
    spc = exp.hybrid.walker.steps_per_cycle
    walked = (not res.summary["diverged"] and len(res.rows) == cycles
              and steps == cycles * spc)
    # the steps of the cycles from the change on (a cycle's distance / its mean step length)
    after = sum(int(round(r["distance"] / r["step_length"])) for r in res.rows[CHANGE - 1:]
                if r.get("step_length", 0) > 0)
    walked_after = (not res.summary["diverged"] and len(res.rows) == cycles
                    and after == (cycles - CHANGE + 1) * spc)
    return {"walker": walker, "world": world, "learner": learner, "seed": seed,
            "walked": bool(walked), "walked_after_change": bool(walked_after),
            "reason": res.summary.get("diverged_reason"),
            "cycles": len(res.rows), "fb": fb,
            "torso_rms_max": float(np.nanmax(torso)) if torso else float("nan"),
            "ratio": fb[-1] / fb[CHANGE - 1] if len(fb) >= CHANGE else float("nan"),
            "engine": exp.engine, "redesign": res.summary.get("redesign")}


def impact_share(walker: str, world: str, cycles: int = 10, window_s: float = 0.05) -> dict:
    """Where the floor's feedback is: the walker in the changed world from cycle 1 with the
    plant's exact inverse model in its feedforward and nothing learned; of its last cycle, the
    mean summed feedback [N m] and the share of it in the ``window_s`` after each touchdown
    (the cycle starts at one)."""
    from feltool.config.events import EventConfig
    from feltool.engines.python import after_impacts, hybrid_cycle
    from feltool.plant.events import world_plant
    from feltool.runs.seed import initial_state

    over = [o for o in overrides(walker, world, "trajectory") if o != "backend=compiled"]
    exp = load_experiment(ROOT / "configs" / "gaits" / f"{walker}.yaml",
                          over + ["backend=pinocchio", "learning.rates.weights=0",
                                  "learning.rates.gauss_newton=0"])
    plant = world_plant(exp.dynamics, [EventConfig(**world_event(world, exp))])
    exp.hybrid.model_correction = exact_correction(exp, world)
    st = initial_state(exp, 0)
    q, v = st.q, st.v
    for _ in range(cycles - 1):
        out = hybrid_cycle(exp, st.theta, q, v, plant)
        q, v = out.q_end, out.v_end
    P, Pv, Pa = exp.primitives.desired(st.theta)
    log = exp.hybrid.run_cycle(plant, q, v, P, Pv, Pa)
    U = np.abs(log.u_err).sum(axis=1)
    near = after_impacts(log.impacts, len(U), int(round(window_s / exp.config.dt)))
    return {"walker": walker, "world": world, "fb": float(U.mean()),
            "share_after_touchdowns": float(U[near].sum() / U.sum()),
            "time_share": float(near.mean())}


def table(results: list[dict]) -> str:
    """The docs' markdown table: one row per seed."""
    lines = ["| walker | world | learner | seed | walks every step | torso RMS max after the "
             "change [rad] | feedback: change cycle → last [N m] | ratio last / change |",
             "|---|---|---|---|---|---|---|---|"]
    for r in results:
        ok = "y" if r["walked"] else f"n ({r['reason']})"
        lines.append(f"| {r['walker']} | {r['world']} | {r['learner']} | {r['seed']} | {ok} | "
                     f"{r['torso_rms_max']:.2g} | {r['fb'][CHANGE - 1]:.3g} → "
                     f"{r['fb'][-1]:.3g} | {r['ratio']:.3f} |")
    return "\n".join(lines)


def figure(results: list[dict], path: Path) -> None:
    """Feedback per cycle (log scale), one panel per walker, one line per world and seed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    walkers = sorted({r["walker"] for r in results})
    fig, axes = plt.subplots(1, len(walkers), figsize=(6 * len(walkers), 4), squeeze=False)
    colours = {"payload": "C0", "mass": "C1", "slope": "C2"}
    for ax, walker in zip(axes[0], walkers):
        for r in results:
            if r["walker"] != walker:
                continue
            ax.semilogy(np.arange(1, len(r["fb"]) + 1), r["fb"], color=colours[r["world"]],
                        alpha=0.5, label=r["world"] if r["seed"] == 0 else None)
        ax.axvline(CHANGE, color="k", lw=0.8, ls=":")
        ax.set_title(f"{walker}: the world changes at cycle {CHANGE}")
        ax.set_xlabel("cycle")
        ax.set_ylabel("summed feedback [N m]")
        ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi or lo) + 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--walkers", nargs="+", default=["three_link_walker", "five_link_walker"])
    ap.add_argument("--worlds", nargs="+", default=["payload", "mass", "slope"])
    ap.add_argument("--learner", default="model_bias", choices=sorted(LEARNERS) + ["exact"])
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--figures", type=Path, default=None, help="write "
                    "walk_unknown_world_<learner>.png there")
    ap.add_argument("--json", type=Path, default=None, help="write every number there")
    ap.add_argument("--profile", action="store_true", help="instead: where the floor's "
                    "feedback is (impact_share), per walker and world")
    args = ap.parse_args()
    if args.profile:
        for walker in args.walkers:
            for world in args.worlds:
                p = impact_share(walker, world)
                print(f"{walker} {world}: exact inverse model, nothing learned, cycle 10: "
                      f"{p['fb']:.3g} N m, {100 * p['share_after_touchdowns']:.0f} % of it in "
                      f"the 50 ms after the touchdowns ({100 * p['time_share']:.0f} % of the "
                      "time)", flush=True)
        return
    results = []
    for walker in args.walkers:
        for world in args.worlds:
            for seed in _seeds(args.seeds):
                t = time.perf_counter()
                r = run_case(walker, world, args.learner, seed, args.cycles)
                results.append(r)
                print(f"{walker} {world} {args.learner} seed {seed}: walked {r['walked']}, "
                      f"torso RMS max {r['torso_rms_max']:.2g} rad, feedback "
                      f"{r['fb'][CHANGE - 1]:.3g} -> {r['fb'][-1]:.3g} N m (ratio "
                      f"{r['ratio']:.3f}), {time.perf_counter() - t:.1f} s, {r['engine']}",
                      flush=True)
                if r.get("redesign"):
                    rd = r["redesign"]
                    print(f"  re-designs: {rd['designed']} at cycles "
                          f"{[d['cycle'] for d in rd['designs']]}, failed {rd['failed']}"
                          + "".join(f"; cycle {f['cycle']}: {f['reason'][:120]}"
                                    for f in rd["failures"]), flush=True)
    print(table(results))
    if args.figures is not None:
        figure(results, args.figures / f"walk_unknown_world_{args.learner}.png")
    if args.json is not None:
        args.json.write_text(json.dumps(results))


if __name__ == "__main__":
    main()
