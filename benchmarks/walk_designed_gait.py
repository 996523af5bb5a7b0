"""Walk a designed gait in the physical walker's closed loop, without RMPs, and print each step.

Usage (needs ``feltool gait``, i.e. the gait designer merged)::

    python benchmarks/walk_designed_gait.py configs/gaits/five_link_walker.yaml --speed 0.8 \
        --phase mechanical --steps 20

The gait is designed by ``feltool.gait_design.design_gait``; its knots are interpolated at the
control rate (cubic with linear acceleration, exact for the collocation) and given to
:class:`feltool.walking.PhysicalLoop` as the desired trajectory of every coordinate (the torso
tracked along the designed pitch). Printed: the allocation's torques against the designed ones
at the knots, then per step the duration [s], step length [m], min normal force [N], max
friction ratio, touchdown impulse ratio, the trailing foot's lift-off velocity [m/s], max motor
torque [N m], the located touchdown height [m], the impact's energy loss [J] and the distance of
the post-step state from the designed start state.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from feltool.experiment import load_experiment


def samples(g, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The gait's knots at the control rate (acceleration linear between knots)."""
    n = int(round(g.duration / dt))
    P, Pv, Pa = (np.zeros((n, g.q.shape[1])) for _ in range(3))
    for k, tk in enumerate(np.arange(n) * dt):
        i = min(np.searchsorted(g.t, tk, side="right") - 1, len(g.t) - 2)
        h, s = g.t[i + 1] - g.t[i], tk - g.t[i]
        a0, a1 = g.a[i], g.a[i + 1]
        Pa[k] = a0 + (a1 - a0) * s / h
        Pv[k] = g.v[i] + a0 * s + (a1 - a0) * s**2 / (2 * h)
        P[k] = g.q[i] + g.v[i] * s + a0 * s**2 / 2 + (a1 - a0) * s**3 / (6 * h)
    return P, Pv, Pa


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config")
    ap.add_argument("--speed", type=float, required=True, help="[m/s]")
    ap.add_argument("--phase", default="touchdown", choices=["touchdown", "mechanical"])
    ap.add_argument("--steps", type=int, default=20)
    args = ap.parse_args()
    from feltool.gait_config import gait_spec, walker_from_raw  # the gait designer's
    from feltool.gait_design import design_gait

    raw = yaml.safe_load(Path(args.config).read_text())
    walker, settings = walker_from_raw(raw, Path(args.config))
    g = design_gait(walker, gait_spec(raw, walker, settings, speed=args.speed))
    exp = load_experiment(args.config)
    loop, W = exp.hybrid, exp.hybrid.walker
    W.phase, W.steps_per_cycle = args.phase, 1
    law = loop.law
    pitch = exp.joints.index("base_pitch") if "base_pitch" in exp.joints else None
    if pitch is not None and law.stabilizing[pitch]:  # track the designed torso motion
        law.stabilizing[pitch], law.tracking[pitch] = False, True
    err = max(np.abs(W.allocate(qd, loop.known.inverse(qd, vd, ad))
                     - g.tau[k][W.motor_v]).max()
              for k in range(len(g.t)) for qd, vd, ad in [W.complete(g.q[k], g.v[k], g.a[k])])
    print(f"designed: step {g.duration:.3f} s, {g.step_length:.3f} m, max torque "
          f"{np.abs(g.tau).max():.1f} N m; allocation vs designed torques: {err:.2e} N m")
    P, Pv, Pa = samples(g, exp.config.dt)
    q, v, _ = W.complete(g.q[0], g.v[0], np.zeros_like(g.v[0]))
    x_star = np.concatenate([q, v])
    for step in range(args.steps):
        log = loop.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
        if log.fall:
            print(f"step {step}: {log.fall}")
            break
        st = log.steps[0]
        q, v = log.q_end, log.v_end
        print(f"step {step}: {st.duration:.4f} s {st.length:.4f} m  F_n >= "
              f"{st.min_normal_force:.1f} N  |F_t|/F_n <= {st.max_friction_ratio:.3f}  "
              f"|I_x|/I_z {st.impulse_ratio:.3f}  lift-off {st.trailing_vz:.3f} m/s  "
              f"torque <= {st.max_torque:.1f} N m  touchdown z {st.touchdown_height:.1e} m  "
              f"impact loss {st.energy_lost:.2f} J  |x - x*| "
              f"{np.abs(np.concatenate([q, v]) - x_star).max():.2e}")


if __name__ == "__main__":
    main()
