"""Design of the biped's leg gait in configs/biped_torso.yaml (see docs/biped.md).

The stance foot has no motor, so the stance leg moves as the rest of the robot lets it: the leg
gait must be (close to) the periodic motion the unactuated stance leg actually makes. This script
finds it by a fixed-point iteration, with the torso held at pi/6 (zero RMP weights, goal pi/6):

1. a physical leg's cycle: stance (0 to T/2) from -pi/18 to +pi/18 as sampled from the last
   simulation, then swing back by a cubic Hermite segment that starts with the stance's end
   velocity and ends with the next stance's start velocity (the relabelling keeps the swing leg's
   velocity as the new stance leg's); the cycle is projected onto 8 harmonics (smooth, as an RMP
   can represent it) and fitted into both legs' RMPs (the second leg half a cycle later);
2. walk 12 cycles with it and record the stance leg over the first step of the last cycle;
3. rescale that record to end at +pi/18, mix it 50/50 into the stance samples, and correct the
   swing leg's landing velocity (= the next stance start velocity) by the end-angle error.

Prints the ``demo:`` block (mean, amplitude, phase, harmonics) of the legs.

Usage: ``python benchmarks/biped_gait_design.py [iterations]``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from feltool.experiment import load_experiment

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "biped_torso.yaml"
A = np.pi / 18  # leg amplitude [rad]
HARMONICS = 8


def hermite(tau, p0, p1, v0, v1, H):
    """Cubic Hermite segment on [0, H] and its first two time derivatives."""
    s = tau / H
    q = (2*s**3 - 3*s**2 + 1)*p0 + (s**3 - 2*s**2 + s)*H*v0 + (-2*s**3 + 3*s**2)*p1 \
        + (s**3 - s**2)*H*v1
    v = ((6*s**2 - 6*s)*p0 + (-6*s**2 + 6*s)*p1)/H + (3*s**2 - 4*s + 1)*v0 + (3*s**2 - 2*s)*v1
    a = ((12*s - 6)*p0 + (-12*s + 6)*p1)/H**2 + ((6*s - 4)*v0 + (6*s - 2)*v1)/H
    return q, v, a


def leg_cycle(t, T, st, sq, v_start, v_end):
    """A physical leg over one cycle: stance samples ``(st, sq)`` then the Hermite swing."""
    h = T / 2
    cs = CubicSpline(st, sq, bc_type=((1, v_start), (1, v_end)))
    tt = np.mod(t, T)
    ts = np.minimum(tt, h)
    qw, vw, aw = hermite(np.maximum(tt - h, 0.0), A, -A, v_end, v_start, h)
    stance = tt < h
    return (np.where(stance, cs(ts), qw), np.where(stance, cs(ts, 1), vw),
            np.where(stance, cs(ts, 2), aw))


def harmonics(q, K=HARMONICS):
    """``(mean, [(amplitude_k, phase_k)])`` with q ~ mean + sum_k A_k sin(k w t + phi_k)."""
    c = np.fft.rfft(q) / len(q)
    return c[0].real, [(2 * abs(c[k]), float(np.angle(c[k]) + np.pi / 2)) for k in range(1, K + 1)]


def smooth(t, T, mean, terms):
    w = 2 * np.pi / T
    q, v, a = np.full_like(t, mean), np.zeros_like(t), np.zeros_like(t)
    for k, (amp, ph) in enumerate(terms, start=1):
        q += amp * np.sin(k*w*t + ph)
        v += amp * k*w * np.cos(k*w*t + ph)
        a -= amp * (k*w)**2 * np.sin(k*w*t + ph)
    return q, v, a


def main(iterations: int = 30) -> int:
    exp = load_experiment(CONFIG, ["walking.poincare=false"])
    prims, W, T = exp.primitives, exp.hybrid.walker, exp.config.period_s
    n = prims.n_steps
    dt, h = T / n, T / 2
    tf = np.linspace(0.0, T, 2000, endpoint=False)
    st = np.linspace(0.0, h, 51)
    sq = -A + 2 * A * st / h  # first guess: a uniform stance
    v_start, v_end = 0.45, 1.2  # [rad/s]
    tk = np.arange(n // 2) * dt
    for it in range(iterations):
        mean, terms = harmonics(leg_cycle(tf, T, st, sq, v_start, v_end)[0])
        theta = exp.theta_demo.copy()
        for i, delay in ((0, 0.0), (1, h)):
            q, v, a = smooth(tf - delay, T, mean, terms)
            theta[prims.slices[i]] = prims.primitives[i].fit(q, v, a, 2*np.pi*tf/T, goal=mean)
        torso = prims.slices[2]
        theta[torso], theta[torso.stop - 1] = 0.0, np.pi / 6
        P, Pv, Pa = prims.desired(theta)
        q, v = exp.hybrid.initial_state(P, Pv)
        for _ in range(12):
            log = exp.hybrid.run_cycle(exp.dynamics, q, v, P, Pv, Pa)
            if log.fall:
                print(f"iteration {it}: fell ({log.fall}); lowering the landing velocity")
                v_start *= 0.8
                break
            q, v = log.q_end, log.v_end
        else:
            th, thv = W.absolute(log.q)[: n // 2, 0], W.absolute(log.v)[: n // 2, 0]
            end = th[-1] + dt * thv[-1]
            scale = 2 * A / (end - th[0])
            rec = -A + (np.interp(st, np.r_[tk, h], np.r_[th, end]) - th[0]) * scale
            print(f"iteration {it}: stance {th[0]:+.4f} -> {end:+.4f} rad, "
                  f"velocity {thv[0]:.3f} -> {thv[-1]:.3f} rad/s, mean |u_fb| "
                  f"{np.round(np.abs(log.u_fb).mean(axis=0), 2)}")
            sq = 0.5 * sq + 0.5 * rec
            v_start -= 1.0 * (end - A)
            v_end = 0.5 * v_end + 0.5 * thv[-1] * scale
    mean, terms = harmonics(leg_cycle(tf, T, st, sq, v_start, v_end)[0])
    print(f"demo: {{kind: sine, mean: {mean:.6f}, amplitude: {terms[0][0]:.6f}, "
          f"phase: {terms[0][1]:.6f},")
    print("       harmonics: [" + ", ".join(f"[{a:.6f}, {p:.6f}]" for a, p in terms[1:]) + "]}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*(int(a) for a in sys.argv[1:])))
