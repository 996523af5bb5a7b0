"""Does a designed gait walk? Phase-based tracking of it in the physical walker's contact model.

Needs the physical walker (issue 12: ``feltool/contact.py``), so it runs once that is merged.
The outputs y = (torso pitch, motor joints) track the designed trajectory as functions of the
phase s = (x_hip - x_0) / (x_N - x_0) (the design's hip moves forward throughout the step, a
monotonic phase, as in hybrid zero dynamics): the design's feedforward RNEA(q, v, a_d(s)) plus
PD on y, allocated onto the motors in the constrained system's metric (as feltool/walking.py
does); stance by the point-contact dynamics (RK4, 1 ms), touchdown by root finding on the swing
foot's height, the rigid impact by ``pin.impulseDynamics``, relabelling. It walks 20 steps,
printing each step's contact figures, then finds the step-to-step map's Jacobian at the state
reached by central differences and prints its largest eigenvalue magnitudes.

Usage: ``python benchmarks/gait_phase_tracking.py configs/gaits/five_link_walker.yaml
--speed 0.8 [--kp 400 --kd 40]`` (the designer's options as in ``feltool gait``).
"""

from __future__ import annotations

import argparse

import numpy as np
import pinocchio as pin
from scipy.optimize import brentq

from feltool.config import read_yaml
from feltool.contact import Contact
from feltool.gait_config import gait_spec, walker_from_raw
from feltool.gait_design import design_gait
from feltool.rmp import samples_demo

parser = argparse.ArgumentParser()
parser.add_argument("config")
parser.add_argument("--speed", type=float)
parser.add_argument("--step-length", type=float)
parser.add_argument("--kp", type=float, default=400.0)
parser.add_argument("--kd", type=float, default=40.0)
args = parser.parse_args()
cfg, kp, kd = args.config, args.kp, args.kd
kw = {"speed": args.speed, "step_length": args.step_length}
raw = read_yaml(cfg)
wm, st = walker_from_raw(raw)
spec = gait_spec(raw, wm, st, **kw)
g = design_gait(wm, spec)
model = pin.Model(wm.model)
gm = np.linalg.norm(model.gravity.linear)
model.gravity.linear = gm * np.array([np.sin(spec.slope), 0, -np.cos(spec.slope)])
c = Contact(wm, model)
data = model.createData()
nv = model.nv
ix = wm.robot.v_index("base_x")
base = [wm.robot.v_index(n) for n in wm.base]
motors = [i for i in range(nv) if i not in base and model.effortLimit[i] > 0]
B = np.eye(nv)[:, motors]
rows = [wm.robot.v_index("base_pitch")] + motors if spec.pitch_joint else motors
T = g.duration
tf = np.linspace(0, T, 2001)
Qf, Vf, Af = (np.array(x).T for x in zip(*[samples_demo(g.q[:, i], g.v[:, i], g.a[:, i], T, tf)
                                            for i in range(nv)], strict=True))
x0, xN = Qf[0, ix], Qf[-1, ix]
S = (Qf[:, ix] - x0) / (xN - x0)
S = np.maximum.accumulate(S) + np.arange(len(S)) * 1e-12  # strictly increasing for np.interp
dQ = np.gradient(Qf, S, axis=0)
mg = sum(i.mass for i in model.inertias) * gm


def allocate(q, tau_w):
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    J = c.jacobian(q, "left")
    Mi = np.linalg.inv(M)
    MiJ = Mi @ J.T
    Wm = Mi - MiJ @ np.linalg.solve(J @ MiJ, MiJ.T)
    BW = B.T @ Wm
    return np.linalg.solve(BW @ B, BW @ tau_w)


def control(q, v):
    s = float(np.clip((q[ix] - x0) / (xN - x0), 0.0, 1.0))  # revolute joints: q is minimal
    sd = v[ix] / (xN - x0)
    yd = np.array([np.interp(s, S, Qf[:, i]) for i in range(nv)])
    dyd = np.array([np.interp(s, S, dQ[:, i]) for i in range(nv)])
    a_ff = np.array([np.interp(s, S, Af[:, i]) for i in range(nv)])
    tau_w = pin.rnea(model, data, q, v, a_ff)
    fb = np.zeros(nv)
    fb[rows] = kp * (yd[rows] - q[rows]) + kd * (dyd[rows] * sd - v[rows])
    return allocate(q, tau_w + fb)


def rk4(q, v, u, h):
    tau = B @ u

    def f(qq, vv):
        return c.stance(qq, vv, tau, "left").a
    a1 = f(q, v)
    q2, v2 = q + h / 2 * v, v + h / 2 * a1
    a2 = f(q2, v2)
    q3, v3 = q + h / 2 * v2, v + h / 2 * a2
    a3 = f(q3, v3)
    q4, v4 = q + h * v3, v + h * a3
    a4 = f(q4, v4)
    return q + h / 6 * (v + 2 * v2 + 2 * v3 + v4), v + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)


def step(q, v, dt=0.001):
    """One step from a post-impact state; returns the next post-impact state (relabelled,
    shifted), or raises with a reason."""
    t = 0.0
    minF, maxr, minclear, maxu = np.inf, 0.0, np.inf, 0.0
    while t < 3 * T:
        u = control(q, v)
        maxu = max(maxu, np.abs(u).max())
        res = c.stance(q, v, B @ u, "left")
        Fx, Fz = res.force
        minF, maxr = min(minF, Fz), max(maxr, abs(Fx) / max(Fz, 1e-9))
        anchor = c.foot_state(q, v, "left")[0]
        z0 = c.foot_state(q, v, "right")[0][1]
        q1, v1 = rk4(q, v, u, dt)
        q1, v1 = c.hold(q1, v1, "left", anchor)
        (sx, sz), _ = c.foot_state(q1, v1, "right")
        ahead = sx - anchor[0]
        exempt = abs(ahead) < (0.05 if len(wm.legs) == 1 else 0.0)
        if not exempt and t > 0.2 * T:
            minclear = min(minclear, sz)
        if not exempt and ahead > 0 and z0 > 0 and sz <= 0 and t > 0.3 * T:
            def height(s, q=q, v=v, u=u):
                return c.foot_state(*rk4(q, v, u, s), "right")[0][1]
            sstar = brentq(height, 0, dt)
            qs, vs = rk4(q, v, u, sstar)
            imp = c.impact(qs, vs, "right")
            tx = c.foot_state(qs, vs, "right")[0][0]
            qn, vn = wm.relabel(qs, imp.v)
            qn = qn.copy()
            qn, vn = c.hold(qn, vn, "left", np.array([tx, 0.0]))
            qn[ix] -= tx
            info = dict(L=tx - anchor[0], T=t + sstar, minF=minF / mg, fr=maxr, clear=minclear,
                        imp=abs(imp.impulse[0]) / imp.impulse[1], u=maxu)
            return qn, vn, info
        q, v, t = q1, v1, t + dt
    raise RuntimeError("no touchdown")


q, v = g.q_pin[0].copy(), g.v[0].copy()
for k in range(20):
    try:
        q, v, info = step(q, v)
    except RuntimeError as e:
        print("step", k, "failed:", e)
        break
    if k < 3 or k > 16:
        print(k, {a: round(float(b), 4) for a, b in info.items()})
else:
    x = np.concatenate([q, v])

    def P(x):
        qn, vn, _ = step(x[:nv].copy(), x[nv:].copy())
        return np.concatenate([qn, vn])
    fx = P(x)
    print("residual after 20 steps", np.abs(fx - x).max())
    eps = 1e-6
    D = np.empty((2 * nv, 2 * nv))
    for i in range(2 * nv):
        dx = np.zeros(2 * nv)
        dx[i] = eps
        D[:, i] = (P(x + dx) - P(x - dx)) / (2 * eps)
    eig = np.linalg.eigvals(D)
    print("eigenvalue magnitudes", np.sort(np.abs(eig))[::-1][:6])
