"""What the thesis's relabel touchdown does to energy and momentum, measured on its walker.

The pinned walker (``configs/biped_torso.yaml``, ``impact: relabel``) swaps stance and swing at
each touchdown and keeps every link's angular rate. A foot that lands on the ground can only
exchange an impulse with it at the landing point, so the walker's angular momentum about that
point is conserved through any physical touchdown (the trailing foot leaves the ground: no
impulse there), and the kinetic energy cannot rise. This script runs the config's cycles and, at
every touchdown, measures the kinetic energy and the angular momentum about the landing foot
before and after the relabelling, and compares with the rigid impact (``impact: rigid``) of the
same pre-touchdown state. Prints a table (docs/biped.md).

Usage::

    python benchmarks/relabel_touchdown.py [--seed 0] [--learn 150] [--cycles 2]

(``--learn N``: the torso is learned for N cycles first, and the touchdowns of the learned gait
are measured.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "biped_torso.yaml"


def energy_and_momentum(model, data, q, v, point: np.ndarray) -> tuple[float, float]:
    """Kinetic energy [J] and the angular momentum about ``point`` (x, y, z) [m] in [kg m^2/s]
    (its y component), in the pinned model (stance foot at the origin)."""
    ke = float(pin.computeKineticEnergy(model, data, q, v))
    pin.computeCentroidalMomentum(model, data, q, v)
    h = data.hg
    c = data.com[0]
    r = c - point
    return ke, float(h.angular[1] + np.cross(r, h.linear)[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--learn", type=int, default=150, help="cycles learned before measuring")
    ap.add_argument("--cycles", type=int, default=2, help="cycles measured")
    args = ap.parse_args()
    exp = load_experiment(CONFIG, ["walking.poincare=false"])
    rigid = load_experiment(CONFIG, ["walking.poincare=false", "walking.impact=rigid"])
    W, Wr = exp.hybrid.walker, rigid.hybrid.walker
    model, data = exp.robot.model, exp.robot.model.createData()
    rows = []
    relabel = W.apply_impact

    def recording(q, v):  # the state at each touchdown, before and after the relabelling
        q_plus, v_plus = relabel(q, v)
        q_r, v_r = Wr.apply_impact(q, v)
        foot = swing_foot(q)
        rows.append((energy_and_momentum(model, data, q, v, foot),
                     energy_and_momentum(model, data, q_plus, v_plus, np.zeros(3)),
                     energy_and_momentum(model, data, q_r, v_r, np.zeros(3))))
        return q_plus, v_plus

    def swing_foot(q):  # where the landing foot is, in the pinned model's frame [m]
        data_f = W.free_model.createData()
        pin.framesForwardKinematics(W.free_model, data_f, np.concatenate([[0.0, 0.0], q]))
        return data_f.oMf[W.foot_frame].translation.copy()

    theta = exp.initial_parameters(args.seed)
    if args.learn:
        res = run_seed(exp, args.seed, cycles=args.learn)
        for name in exp.learned_joints:
            sl = exp.primitives.slices[exp.joints.index(name)]
            theta[sl.start:sl.stop - 1] = res.params[f"{name}.weights"]
            theta[sl.stop - 1] = res.params[f"{name}.goal"]
    W.apply_impact = recording
    P, Pv, Pa = exp.primitives.desired(theta)
    q, v = exp.hybrid.initial_state(P, Pv)
    for _ in range(args.cycles):
        log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
        if log.fall:
            print("fell:", log.fall)
            break
        q, v = log.q_end, log.v_end
    print("| touchdown | KE before [J] | KE after, relabel [J] | KE after, rigid impact [J] | "
          "L before [kg m^2/s] | L after, relabel | L after, rigid impact |")
    print("|---|---|---|---|---|---|---|")
    for i, ((ke0, l0), (ke1, l1), (ke2, l2)) in enumerate(rows):
        print(f"| {i + 1} | {ke0:.3g} | {ke1:.3g} | {ke2:.3g} | {l0:.4g} | {l1:.4g} | {l2:.4g} |")
    ke0, l0 = np.array([r[0] for r in rows]).T
    ke1, l1 = np.array([r[1] for r in rows]).T
    ke2, l2 = np.array([r[2] for r in rows]).T
    print(f"\nrelabel: kinetic energy after / before {np.min(ke1 / ke0):.3g} to "
          f"{np.max(ke1 / ke0):.3g}; angular momentum about the landing foot after / before "
          f"{np.min(l1 / l0):.3g} to {np.max(l1 / l0):.3g} (a physical touchdown: <= 1 and 1)")
    print(f"rigid impact: kinetic energy after / before {np.min(ke2 / ke0):.3g} to "
          f"{np.max(ke2 / ke0):.3g}; angular momentum {np.min(l2 / l0):.10f} to "
          f"{np.max(l2 / l0):.10f}")


if __name__ == "__main__":
    main()
