"""A body's length in the plant (``plant.bodies.<joint>.length_scale``, issue 28): the plant's
body is longer (its child joints, frames and centre of mass further from its joint, its
rotational inertia about the centre of mass times the square), the known model unchanged.

The independent reference is the URDF edited by hand: the shins' lengths (the foot's fixed
joint), centres of mass and inertias written as a longer shin's, read by Pinocchio."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

from feltool.runs.experiments import load_experiment
from feltool.runs.seed import run_seed

from .conftest import CONFIGS, ROOT

FIVE = CONFIGS / "gaits" / "five_link_walker.yaml"
DESIGN = ["walking.poincare=false", "joints.base_pitch.learn.init=demo", "backend=pinocchio"]
S = 1.1
#: both shins (the walker runs in stance-relative labels: its legs trade labels every step, so
#: a change of one leg would alternate between them)
LONGER = f"plant={{bodies: {{left_knee: {{length_scale: {S}}}, right_knee: {{length_scale: {S}}}}}}}"


def _edited_urdf(tmp_path):
    """The five-link walker's URDF with shins S times as long, written by hand."""
    text = (ROOT / "robots" / "five_link_walker.urdf").read_text()
    for side in ("left", "right"):
        shin = text.index(f'<link name="{side}_shin">')
        end = text.index("</link>", shin)
        body = text[shin:end]
        body = body.replace('xyz="0 0 -0.24"', f'xyz="0 0 {-0.24 * S!r}"', 1).replace(
            'ixx="0.2" ixy="0" ixz="0" iyy="0.2"', f'ixx="{0.2 * S * S!r}" ixy="0" ixz="0" '
            f'iyy="{0.2 * S * S!r}"', 1).replace('izz="0.001"', f'izz="{0.001 * S * S!r}"', 1)
        text = text[:shin] + body + text[end:]
        foot = text.index(f'<joint name="{side}_foot_fixed"')
        end = text.index("</joint>", foot)
        text = (text[:foot] + text[foot:end].replace('xyz="0 0 -0.4"', f'xyz="0 0 {-0.4 * S!r}"')
                + text[end:])
    path = tmp_path / "five_link_walker_long_shins.urdf"
    path.write_text(text)
    return path


def test_longer_shins_change_the_plant_and_not_the_model(tmp_path):
    """The plant's RNEA is the hand-edited URDF's (to 1e-12 N m) at random states, its foot is
    0.04 m further down at the neutral pose; the known model's RNEA is the unchanged walker's
    to the last bit; and the design's first cycle's feedback rises from its rounding (1e-7) to
    above 0.1 N m (the factor of a real change of the walker)."""
    known = load_experiment(FIVE, DESIGN)
    longer = load_experiment(FIVE, [*DESIGN, LONGER])
    edited = load_experiment(FIVE, [*DESIGN, f"robot={_edited_urdf(tmp_path)}"])
    rng = np.random.default_rng(0)
    nv = known.robot.model.nv
    for _ in range(5):
        q, v, a = (rng.uniform(-0.5, 0.5, nv) for _ in range(3))
        np.testing.assert_array_equal(longer.dynamics.inverse(q, v, a),
                                      known.dynamics.inverse(q, v, a))
        np.testing.assert_allclose(longer.plant.inverse(q, v, a),
                                   edited.dynamics.inverse(q, v, a), rtol=0, atol=1e-12)
        assert np.abs(longer.plant.inverse(q, v, a) - known.dynamics.inverse(q, v, a)).max() > 0.1
    m = longer.plant.model
    foot = m.getFrameId("left_foot")
    data = m.createData()
    pin.framesForwardKinematics(m, data, pin.neutral(m))
    kd = known.robot.model.createData()
    pin.framesForwardKinematics(known.robot.model, kd, pin.neutral(known.robot.model))
    drop = kd.oMf[foot].translation[2] - data.oMf[foot].translation[2]
    assert drop == pytest.approx(0.4 * (S - 1.0), abs=1e-12)
    fb_known = run_seed(known, 0, 1).rows[0]["fb_abs_mean_error"]
    fb_longer = run_seed(longer, 0, 1).rows[0]["fb_abs_mean_error"]
    assert fb_known < 1e-5 and fb_longer > 0.1


def test_both_engines_walk_the_longer_shins_alike(tmp_path, monkeypatch):
    """Shins 2 % longer in the plant (the walker stands on the plant's foot): two cycles on the
    Python and the compiled engine give the same feedback (to 1e-8 relative) and every step."""
    monkeypatch.setenv("FELTOOL_CACHE", str(tmp_path / "cache"))
    longer = LONGER.replace(str(S), "1.02")
    runs = {}
    for backend in ("pinocchio", "compiled"):
        exp = load_experiment(FIVE, [*DESIGN[:-1], f"backend={backend}", longer])
        res = run_seed(exp, 0, 2)
        assert exp.engine == ("python" if backend == "pinocchio" else "compiled")
        assert res.summary["walking"]["steps"] == 4, res.summary
        runs[backend] = np.array([r["fb_abs_mean_error"] for r in res.rows])
    assert runs["pinocchio"][0] > 0.1  # a real change (the design's rounding is 1e-7)
    np.testing.assert_allclose(runs["compiled"], runs["pinocchio"], rtol=1e-8)


@pytest.mark.parametrize("value, message", [
    ("{nope: {length_scale: 1.1}}", "plant.bodies.nope"),
    ("{left_knee: {length_scale: 0}}", "plant.bodies.left_knee.length_scale"),
    ("{left_knee: {length_scale: -1.0}}", "plant.bodies.left_knee.length_scale"),
])
def test_a_bad_length_override_is_one_line_naming_the_field(value, message):
    """An unknown body or a non-positive scale: exit 2, one line naming the field."""
    r = subprocess.run([sys.executable, "-m", "feltool.cli", "check", str(FIVE), "--set",
                        f"plant={{bodies: {value}}}"], capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and message in lines[0], r.stderr
    assert "Traceback" not in r.stderr
