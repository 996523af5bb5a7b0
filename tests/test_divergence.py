"""A diverged seed's message names what ran away (joint or target), its value, the cycle and
step, and the likely cause from the config."""

from __future__ import annotations

import re

import numpy as np
import pytest

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS

STANDARD = CONFIGS / "two_link_standard.yaml"


def _reason(overrides: list[str], cycles: int) -> tuple[str, object]:
    exp = load_experiment(STANDARD, overrides)
    summary = run_seed(exp, 0, cycles).summary
    assert summary["diverged"], summary
    return summary["diverged_reason"], exp


def test_a_rate_too_coarse_for_the_gains_in_the_first_cycle():
    reason, exp = _reason(["joints.elbow.gains.kp=30000"], 3)
    m = re.match(r"seed 0, cycle 1: joint elbow's velocity reached (\S+) rad/s at step (\d+) of "
                 r"the cycle \(t = (\S+) s\) \(sim.max_velocity = 1000\)", reason)
    assert m, reason
    assert "likely cause: the loop itself, before any learning step: joints.elbow.gains: " \
           "sim.rate_hz 100 is too coarse for kp 30000" in reason
    # the step is the first sample of the cycle whose elbow velocity is beyond the bound
    theta = exp.initial_parameters(0)
    Qd, Vd, Ad = exp.primitives.desired(theta)
    q, v = exp.law.consistent_state(Qd[0], Vd[0])
    R, Rd = exp.law.references(Qd, Vd)
    u_ff = np.array([exp.dynamics.inverse(*x) for x in zip(Qd, Vd, Ad)])
    with np.errstate(all="ignore"):
        log = exp.loop.run_cycle(q, v, R, Rd, u_ff)
        k = int(np.argmax(np.abs(log.v[:, 1]) > 1000))
    assert int(m.group(2)) == k and float(m.group(1)) == pytest.approx(log.v[k, 1], rel=1e-3)
    assert float(m.group(3)) == pytest.approx(k * exp.config.dt)


def test_a_learning_rate_too_large_is_named_with_the_feedback_that_grew():
    reason, _ = _reason(["learning.update=gradient", "learning.safeguard=false",
                         "learning.rates.weights=1010.6"], 30)  # per sample 3
    cycle = int(re.match(r"seed 0, cycle (\d+): ", reason).group(1))
    assert cycle > 1 and "velocity reached" in reason, reason
    assert "likely cause: the learning step: the error feedback went from" in reason
    assert "learning.rates.weights = 1010.6 (goal 0.002) is likely too large" in reason


def test_weak_gains_let_the_target_fall():
    reason, _ = _reason(["joints.elbow.gains.kp=1", "joints.elbow.gains.kd=1"], 3)
    assert reason.startswith("seed 0, cycle 1: the target of joint elbow (link angle "
                             "['shoulder', 'elbow']) was "), reason
    value, ref = re.search(r"was (\S+) rad against its reference (\S+) rad", reason).groups()
    assert abs(float(value) - float(ref)) > 1.5 and float(ref) == pytest.approx(np.pi / 2,
                                                                              abs=1e-3)
    assert "joints.elbow.gains: kp 1, kd 1 leave the closed loop unstable" in reason
