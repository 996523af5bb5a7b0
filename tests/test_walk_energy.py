"""The physical walker's energy budget per stride, from its log: the motors' work plus gravity's
(the potential energy's drop) minus the impact's loss equals the change of kinetic energy."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.runs.experiments import load_experiment


def energy(model, data, q, v) -> float:
    """Kinetic plus potential energy [J] (potential: -m g . c, the same zero for all states)."""
    ke = pin.computeKineticEnergy(model, data, q, v)
    c = pin.centerOfMass(model, data, q)
    m = sum(model.inertias[i].mass for i in range(1, model.njoints))
    return float(ke - m * model.gravity.linear @ c)


@pytest.mark.parametrize("config", ["configs/gaits/three_link_walker.yaml",
                                    "configs/gaits/five_link_walker.yaml"])
def test_energy_budget_closes_per_stride(config):
    exp = load_experiment(config)
    loop, W = exp.hybrid, exp.hybrid.walker
    W.phase, W.steps_per_cycle = "touchdown", 1  # one stride: take-off to touchdown
    P, Pv, Pa = exp.primitives.desired(exp.theta_demo)
    q0, v0 = loop.initial_state(P, Pv)
    log = loop.run_cycle(exp.dynamics, q0, v0, P, Pv, Pa)
    assert log.fall is None and len(log.impacts) == 1
    model = W.walker.model
    data = model.createData()
    m = W.motor_v
    mq = np.array([model.joints[j].idx_q for j in range(1, model.njoints)
                   if model.joints[j].idx_v in set(m)])
    # the touchdown's (pre-impact) joint angles: the relabelling swaps the legs back
    q_td, _ = W.walker.relabel(log.q_end, log.v_end)
    back, _ = W.walker.relabel(q_td, log.v_end)
    np.testing.assert_allclose(back, log.q_end, atol=1e-12)  # an involution
    Q = np.vstack([log.q[:, mq], q_td[mq]])
    # the torque is held over each control step: its work is u_k . (q_{k+1} - q_k), exactly
    work = float(np.sum(log.tau * np.diff(Q, axis=0)))
    lost = log.steps[0].energy_lost
    e0 = energy(model, data, q0, v0)
    e1 = energy(model, data, log.q_end, log.v_end)
    budget = work - lost - (e1 - e0)
    scale = abs(work) + abs(lost) + abs(e1 - e0)
    assert lost > 0.0
    # the acceptance asks for 1 %; the integration closes it to ~1e-9 (RK4, 1 ms sub-steps)
    assert abs(budget) <= 1e-6 * scale, (work, lost, e1 - e0, budget)
