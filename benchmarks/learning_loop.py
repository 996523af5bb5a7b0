"""Steps per second of the FEL learning loop, against a bare ``pin.aba`` loop, in one run.

    python benchmarks/learning_loop.py [--cycles 100] [--repeats 3]

Prints, for each arm config, simulated steps per second of
  * bare:     a Python loop of ``pin.aba`` + semi-implicit Euler, nothing else (the floor);
  * closed:   the closed loop (RMP limit cycle, RNEA feedforward, PD feedback, ABA), no learning;
  * learning: the whole FEL loop of ``run_seed`` (+ RNEA derivatives, sensitivities, updates),
and the ratios learning/bare and learning/closed. Best of ``--repeats`` runs of each, all in the
same process, so the ratios compare like with like on whatever machine runs it.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from feltool.experiment import load_experiment, run_seed
from feltool.fel import feedforward

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def bare_aba(exp, steps: int) -> float:
    model, data = exp.robot.model, exp.robot.model.createData()
    q, v, tau = np.full(model.nq, 0.3), np.zeros(model.nv), np.zeros(model.nv)
    dt = exp.config.dt
    t0 = time.perf_counter()
    for _ in range(steps):
        a = pin.aba(model, data, q, v, tau)
        v = v + dt * a
        q = q + dt * v
    return steps / (time.perf_counter() - t0)


def closed_loop(exp, cycles: int) -> float:
    theta = exp.initial_parameters(0)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    t0 = time.perf_counter()
    for _ in range(cycles):
        Qd, Vd, Ad = exp.primitives.desired(theta)
        R, Rd = exp.law.references(Qd, Vd)
        log = exp.loop.run_cycle(q, v, R, Rd, feedforward(exp.dynamics, Qd, Vd, Ad))
        q, v = log.q_end, log.v_end
    return cycles * exp.primitives.n_steps / (time.perf_counter() - t0)


def learning(exp, cycles: int) -> float:
    t0 = time.perf_counter()
    res = run_seed(exp, 0, cycles)
    return len(res.rows) * exp.primitives.n_steps / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"{'config':<22} {'bare aba':>12} {'closed loop':>12} {'learning':>12} "
          f"{'learn/bare':>10} {'learn/closed':>12}   [steps/s]")
    for name in ("two_link_standard", "two_link_human_arm"):
        exp = load_experiment(CONFIGS / f"{name}.yaml")
        n = args.cycles * exp.primitives.n_steps
        bare = max(bare_aba(exp, n) for _ in range(args.repeats))
        closed = max(closed_loop(exp, args.cycles) for _ in range(args.repeats))
        learn = max(learning(exp, args.cycles) for _ in range(args.repeats))
        print(f"{name:<22} {bare:>12,.0f} {closed:>12,.0f} {learn:>12,.0f} "
              f"{learn / bare:>10.2f} {learn / closed:>12.2f}")


if __name__ == "__main__":
    main()
