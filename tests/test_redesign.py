"""Online gait re-acquisition (issue 28, ``learning.redesign``, feltool/runs/redesign.py) and
the walker model learner's ground slope (``learning.model.slope``).

The full runs (150 cycles, 10 seeds, both walkers) are benchmarks/walk_unknown_world.py
``--learner redesign``'s and docs/biped.md's; here short runs on the Python engine, and
the shipped payload configs shortened as ``feltool run`` runs them (backend auto)."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
import scipy.linalg as sla

from feltool.cli.main import main
from feltool.config.events import EventConfig
from feltool.engines.python import hybrid_cycle
from feltool.gait.config import gait_spec, walker_from_raw
from feltool.gait.design import design_gait
from feltool.plant.events import changed_model, world_plant
from feltool.runs.experiments import load_experiment
from feltool.runs.redesign import (
    blend_designs,
    cycle_measurements,
    identified_model,
    identified_urdf,
    identify_motion,
    physical_inertia,
)
from feltool.runs.seed import initial_state, run_seed

from .conftest import CONFIGS

FIVE = CONFIGS / "gaits" / "five_link_walker.yaml"
COMPASS = CONFIGS / "gaits" / "compass_gait.yaml"
DESIGN = ["walking.poincare=false", "joints.base_pitch.learn.init=demo", "backend=pinocchio"]
LEARN = ("learning.model={features: regressor, update: gauss_newton, rate: 0.5, "
         "motor_bias: 0.5, damping: 1.0e-3}")
REDESIGN = "learning.redesign={every_s: %g, speed_m_s: 0.8, duration_s: 0.5, torso_rad: 0.1}"
PAYLOAD = {"kind": "payload", "frame": "torso", "mass": 3.2, "com": [0.0, 0.0, 0.24]}


@pytest.fixture(autouse=True)
def _cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _tilted(g: float, alpha: float) -> np.ndarray:
    return np.array([g * np.sin(alpha), 0.0, -g * np.cos(alpha)])


@pytest.mark.parametrize("config,extra", [(FIVE, []), (COMPASS, [])], ids=["level", "slope"])
def test_the_slope_column_is_rnea_s_derivative_in_the_gravity_angle(config, extra):
    """The learner's column (RNEA(q, 0, 0) with gravity along the ground's tangent) equals
    the central difference of Pinocchio's RNEA in the gravity's angle about the known one
    (0 on the five-link walker, 0.03 rad on the compass gait), at random states; and the
    compiled engine's regressor carries the same column."""
    exp = load_experiment(config, ["walking.poincare=false", "backend=pinocchio",
                                   "learning.model={features: regressor, update: gauss_newton, "
                                   "rate: 0.5, slope: 0.5}"] + extra)
    L = exp.model_learner
    model = pin.Model(L.model)
    g = np.array(L.model.gravity.linear, float)
    alpha0 = np.arctan2(g[0], -g[2])
    assert L.slope0 == pytest.approx(alpha0, abs=1e-15)
    rng = np.random.default_rng(0)
    data, h = model.createData(), 1e-6
    for _ in range(4):
        q, v, a = (rng.uniform(-1, 1, model.nv) for _ in range(3))
        fd = []
        for s in (1, -1):
            model.gravity = pin.Motion(_tilted(np.linalg.norm(g), alpha0 + s * h), np.zeros(3))
            fd.append(pin.rnea(model, data, q, v, a).copy())
        col = L.regressor(q, v, a)[:, -1]
        assert np.allclose(col, (fd[0] - fd[1]) / (2 * h), rtol=1e-7, atol=1e-6)
        assert np.abs(col).max() > 1.0  # a slope moves torques
    from feltool.engines.compiled.physical_step import Kin

    kin = Kin(exp)
    q, v, a = (rng.uniform(-1, 1, model.nv) for _ in range(3))
    Y = np.asarray(kin.regressor(q, v, a, g))
    assert np.allclose(Y, L.regressor(q, v, a), atol=1e-9)


def test_physical_inertia_keeps_consistent_bodies_and_fixes_the_others():
    """A real body passes unchanged; a planar body with inconsistent out-of-plane moments is
    made consistent without changing a parameter that moves a torque; a negative mass makes
    the body weightless (reported)."""
    real = pin.Inertia(2.0, np.array([0.1, 0.0, -0.2]), np.diag([0.3, 0.4, 0.2]))
    p = real.toDynamicParameters()
    out, changed = physical_inertia(p)
    assert not changed and np.allclose(out.toDynamicParameters(), p, atol=1e-12)
    bad = p.copy()
    bad[6] += 0.5  # I_yy up: the triangle inequality I_yy <= I_xx + I_zz fails
    moving = np.zeros(10, bool)
    moving[[0, 1, 3, 6]] = True  # a planar body: m, m c_x, m c_z, I_yy
    out, changed = physical_inertia(bad, moving)
    assert not changed
    assert np.allclose(out.toDynamicParameters()[moving], bad[moving], atol=1e-12)
    S = 0.5 * np.trace(out.inertia) * np.eye(3) - out.inertia
    assert np.linalg.eigvalsh(S).min() >= -1e-12
    neg = p.copy()
    neg[0] = -0.1
    out, changed = physical_inertia(neg, moving)
    assert changed and out.mass == 0.0


def _foot_moment(exp, model: pin.Model, ref) -> np.ndarray:
    """Per sample of ``ref``: n^T RNEA_model, n the rigid rotation about the stance foot (the
    one direction neither a motor nor the foot's force acts in; scipy's null space)."""
    W = exp.hybrid.walker
    ip = model.joints[model.getJointId("base_pitch")].idx_v
    data, out = model.createData(), []
    for qd, vd, ad in zip(*ref):
        n = sla.null_space(np.vstack([W.B.T, W.contact.jacobian(qd, W.stance)]))[:, 0]
        out.append(float(n @ pin.rnea(model, data, qd, vd, ad)) / n[ip])
    return np.array(out)


@pytest.mark.parametrize("world", ["payload", "slope"])
def test_the_world_is_identified_from_one_cycle_of_the_walker_s_motion(world):
    """One cycle of the five-link walker in the changed world (from the design, nothing
    learned): the slope comes out within 1e-3 rad of 0.03; the payload's model (legs tied
    alike, projected) gives the moment about the stance foot along the design's reference within
    5 % of the true plant's (the known model's is 0: the design's rounding)."""
    exp = load_experiment(FIVE, DESIGN + [LEARN])
    ev = EventConfig(cycle=1, **(PAYLOAD if world == "payload" else
                                 {"kind": "slope", "angle": 0.03}))
    plant = world_plant(exp.dynamics, [ev])
    st = initial_state(exp, 0)
    out = hybrid_cycle(exp, st.theta, st.q, st.v, plant, theta_m=st.theta_m)
    d_pi, d_alpha = identify_motion(exp, *cycle_measurements(exp, out))
    L = exp.model_learner
    if world == "slope":
        assert d_alpha == pytest.approx(0.03, abs=1e-3)
        return
    assert abs(d_alpha) < 1e-3
    model, _ = identified_model(L, d_pi)
    true = changed_model(L.model, [ev])
    P, Pv, Pa = exp.primitives.desired(st.theta)
    log = exp.hybrid.run_cycle(exp.dynamics, st.q, st.v, P, Pv, Pa)
    ref = (log.Qd[::5], log.Vd[::5], log.Ad[::5])
    m_true, m_id = _foot_moment(exp, true, ref), _foot_moment(exp, model, ref)
    assert np.abs(m_true).mean() > 1.0  # 1.87 N m: the reason the design is no orbit
    assert np.abs(m_id - m_true).mean() < 0.05 * np.abs(m_true).mean()
    assert np.abs(_foot_moment(exp, L.model, ref)).mean() < 1e-4


def _payload_urdf_by_hand(src, out):
    """The URDF with the payload as a fixed point-mass link at the torso (an edit of the XML,
    not feltool's)."""
    tree = ET.parse(src)
    root = tree.getroot()
    link = ET.SubElement(root, "link", name="payload")
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0.24", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value="3.2")
    ET.SubElement(inertial, "inertia", ixx="0", ixy="0", ixz="0", iyy="0", iyz="0", izz="0")
    joint = ET.SubElement(root, "joint", name="payload_fixed", type="fixed")
    ET.SubElement(joint, "parent", link="torso")
    ET.SubElement(joint, "child", link="payload")
    ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
    path = out / "by_hand.urdf"
    tree.write(path)
    return path


def test_a_design_on_the_true_plant_model_is_the_design_in_that_world(tmp_path):
    """The re-design's robot (the model's inertias written into the URDF,
    :func:`identified_urdf`) given the payload world's model designs the same gait as
    ``feltool gait``'s designer on a URDF edited by hand to carry the payload (the offline
    "designed in the world" of benchmarks/walk_unknown_world_cause.py): knots within 1e-6."""
    exp = load_experiment(FIVE, DESIGN + [LEARN])
    true = changed_model(exp.model_learner.model, [EventConfig(cycle=1, **PAYLOAD)])
    gaits = []
    for urdf in (identified_urdf(exp.robot, true, tmp_path),
                 _payload_urdf_by_hand(exp.robot.urdf_path, tmp_path)):
        raw = dict(exp.raw, robot=str(urdf))
        walker, settings = walker_from_raw(raw, exp.source)
        spec = gait_spec(raw, walker, settings, speed=0.8, duration=0.5, torso=0.1)
        gaits.append(design_gait(walker, spec))
    a, b = gaits
    assert np.abs(a.q - b.q).max() < 1e-6 and np.abs(a.v - b.v).max() < 1e-5
    known = design_gait(*_known(exp))
    assert np.abs(known.q - a.q).max() > 1e-3  # the payload changes the design


def _known(exp):
    walker, settings = walker_from_raw(exp.raw, exp.source)
    return walker, gait_spec(exp.raw, walker, settings, speed=0.8, duration=0.5, torso=0.1)


PAYLOAD_EVENT = "events=[{cycle: 1, kind: payload, frame: torso, mass: 3.2, com: [0, 0, 0.24]}]"


def test_the_redesign_takes_the_feedback_further_down_than_without():
    """Five-link walker, the payload from cycle 1, 5 cycles, seeds 0 and 1: with the gait
    re-designed after 2 s walked (on the world identified from cycle 2's motion) the last
    cycle's feedback is below 0.5 of the same run's without re-design (0.45 -> measured
    about 0.2 of it: docs/biped.md), every step walked."""
    for seed in (0, 1):
        fb = {}
        for name, extra in (("without", []), ("with", [REDESIGN % 2.0])):
            exp = load_experiment(FIVE, DESIGN + [LEARN, PAYLOAD_EVENT] + extra)
            res = run_seed(exp, seed, cycles=5)
            assert not res.summary["diverged"] and len(res.rows) == 5
            fb[name] = res.rows[-1]["fb_abs_mean_error"]
            if name == "with":
                assert res.summary["redesign"]["designed"] == 1
                assert res.summary["redesign"]["failed"] == 0
        assert fb["with"] < 0.5 * fb["without"], fb


def test_a_failing_redesign_keeps_the_reference_and_is_reported():
    """A torso target no gait of this walker can hold: the design fails, the run walks on
    the old reference (the same feedback as without re-design), and the summary counts it
    with IPOPT's reason."""
    bad = REDESIGN.replace("torso_rad: 0.1", "torso_rad: 1.5") % 1.0
    rows = {}
    for name, extra in (("without", []), ("failing", [bad])):
        exp = load_experiment(FIVE, DESIGN + [LEARN, PAYLOAD_EVENT] + extra)
        res = run_seed(exp, 0, cycles=2)
        rows[name] = [r["fb_abs_mean_error"] for r in res.rows]
        assert len(res.rows) == 2 and not res.summary["diverged"]
    summary = res.summary["redesign"]
    assert summary["designed"] == 0 and summary["failed"] >= 1
    assert summary["failures"][0]["cycle"] == 1 and summary["failures"][0]["reason"]
    assert rows["failing"] == rows["without"]


@pytest.mark.parametrize("overrides,field", [
    ([REDESIGN % 10.0], "learning.redesign"),  # no learning.model
    ([LEARN, "learning.redesign={every_s: 10.0, speed_m_s: 0.8, step_length_m: 0.4}"],
     "learning.redesign"),
    ([LEARN, "learning.redesign={every_s: -1.0, speed_m_s: 0.8}"], "learning.redesign.every_s"),
    (["learning.model={features: none, update: gauss_newton, rate: 0.0, motor_bias: 0.5, "
      "slope: 0.5}"], "learning.model.slope"),
])
def test_bad_redesign_fields_exit_2_naming_the_field(overrides, field, tmp_path, capsys):
    args = ["run", str(FIVE), "--out", str(tmp_path / "run"), "--no-progress"]
    for o in overrides:
        args += ["--set", o]
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    assert field in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "run").exists()


def test_redesign_on_an_arm_exits_2(tmp_path, capsys):
    code = main(["run", str(CONFIGS / "two_link_standard.yaml"), "--out", str(tmp_path / "r"),
                 "--no-progress", "--set", REDESIGN % 10.0])
    err = capsys.readouterr().err
    assert code == 2 and "learning.redesign" in err and len(err.strip().splitlines()) == 1


def test_the_blend_walks_from_the_old_design_to_the_new_one_on_one_curve():
    """``blend_cycles``: K configs, the last the new design, the k-th's period and positions
    k/K of the way in phase; its velocities and accelerations are that blended curve's own
    derivatives in time (finite differences of its positions), whatever the two designs'
    periods and sample counts."""
    def demo(f, T, n):
        t = np.linspace(0.0, T, n)
        h = 1e-6
        q = f(t / T)
        v = (f((t + h) / T) - f((t - h) / T)) / (2 * h)
        a = (f((t + h) / T) - 2 * q + f((t - h) / T)) / h**2
        return {"kind": "samples", "q": q.tolist(), "v": v.tolist(), "a": a.tolist()}

    f0 = lambda p: 0.3 * np.sin(2 * np.pi * p)  # noqa: E731
    f1 = lambda p: 0.2 * np.cos(2 * np.pi * p) + 0.1 * p  # noqa: E731
    old = {"period_s": 1.0, "joints": {"hip": {"demo": demo(f0, 1.0, 801)}, "knee": {}}}
    new = {"period_s": 1.25, "joints": {"hip": {"demo": demo(f1, 1.25, 1001)}, "knee": {}}}
    configs = blend_designs(old, new, 4)
    assert len(configs) == 4 and configs[-1] is new
    sampled = blend_designs(old, dict(new, period_s=1.2), 3, period_unit_s=2 / 500)
    assert [c["period_s"] * 500 for c in sampled] == pytest.approx([534, 566, 600], abs=1e-9)
    for k, cfg in enumerate(configs[:-1], start=1):
        s = k / 4
        T = cfg["period_s"]
        assert T == pytest.approx(1.0 + 0.25 * s, rel=1e-12)
        d = {key: np.asarray(val) for key, val in cfg["joints"]["hip"]["demo"].items()
             if key != "kind"}
        phi = np.linspace(0.0, 1.0, 1001)
        np.testing.assert_allclose(d["q"], (1 - s) * f0(phi) + s * f1(phi), atol=2e-6)
        dt = T / 1000
        np.testing.assert_allclose(np.gradient(d["q"], dt)[5:-5], d["v"][5:-5], atol=2e-4)
        np.testing.assert_allclose(np.gradient(d["v"], dt)[5:-5], d["a"][5:-5], atol=2e-2)
        assert cfg["joints"]["knee"] == {}


@pytest.mark.parametrize("walker,cycles,designed_at,measured", [
    ("five_link_walker", 13, 10, 0.081),
    ("three_link_walker", 19, 9, 0.037),
], ids=["five_link", "three_link"])
def test_the_shipped_payload_configs_redesign_and_meet_the_issues_bound(walker, cycles,
                                                                         designed_at, measured,
                                                                         tmp_path, capsys):
    """``feltool run configs/gaits/<walker>_payload.yaml`` as shipped (the payload from
    cycle 3, ``learning.redesign``), seed 0, shortened to the first cycles after the
    re-design (the three-link walker's blended over 10 cycles): exit 0, every step walked,
    one re-design at the cycle docs/biped.md gives, and the feedback already below issue 28's
    0.15 of the change's cycle (measured 0.081 / 0.037 here; 0.0073 / 0.027 at cycle 150).
    Without the re-design (``model_bias`` alone) it stays above 0.44 / 0.31 of it."""
    out = tmp_path / "run"
    code = main(["run", str(CONFIGS / "gaits" / f"{walker}_payload.yaml"), "--seeds", "0",
                 "--cycles", str(cycles), "--out", str(out), "--no-progress", "--quiet",
                 "--workers", "1"])
    assert code == 0, capsys.readouterr().err
    seed = json.loads((out / "summary.json").read_text())["seeds"][0]
    assert seed["walking"]["walked"] and seed["walking"]["steps"] == 2 * cycles
    assert seed["redesign"]["designed"] == 1 and seed["redesign"]["failed"] == 0
    assert seed["redesign"]["designs"][0]["cycle"] == designed_at
    with open(out / "metrics.csv") as fh:
        rows = list(csv.DictReader(fh))
    fb = [float(r["fb_abs_mean_error"]) for r in rows]
    assert fb[0] < 1e-6 and fb[1] < 1e-6  # the designed gait, before the payload
    ratio = fb[-1] / fb[2]
    assert ratio <= 0.15, ratio
    assert ratio == pytest.approx(measured, abs=0.01)
    # the summary's ratio from the world's change is that one, and success: checks it
    assert seed["change_cycle"] == 3 and seed["fb_change"] == pytest.approx(fb[2], rel=1e-12)
    assert seed["fb_ratio_change"] == pytest.approx(ratio, rel=1e-12)
    assert seed["fb_ratio"] > 1e3  # over cycle 1, the designed gait's roundoff
