"""Physical plausibility checks, the boolean guard and the memory estimate, each against an
independent reference: inertias built from point masses (always physical), Pinocchio's own
treatment of a non-unit axis, a revolute twin of a continuous joint, and the peak resident size
of a real process."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

from feltool.bounds import parse_seeds
from feltool.config.base import Strict
from feltool.config.files import parse_config, read_yaml
from feltool.errors import ConfigError, InputError, RobotError
from feltool.experiment.assemble import reduce_robot
from feltool.robot.physical import inertia_problem
from feltool.robot.robot import load_robot, load_urdf_string

from .conftest import CONFIGS, ROOT

ARM = (ROOT / "robots" / "two_link_arm.urdf").read_text()
STANDARD = CONFIGS / "two_link_standard.yaml"


def point_cloud_inertia(masses: np.ndarray, points: np.ndarray) -> list[float]:
    """Rotational inertia about the centre of mass of point masses, in URDF order."""
    com = masses @ points / masses.sum()
    r = points - com
    inertia = sum(m * (ri @ ri * np.eye(3) - np.outer(ri, ri)) for m, ri in zip(masses, r))
    return [inertia[0, 0], inertia[0, 1], inertia[0, 2], inertia[1, 1], inertia[1, 2],
            inertia[2, 2]]


def rotated(moments, rng) -> list[float]:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    inertia = q @ np.diag(moments) @ q.T
    return [inertia[0, 0], inertia[0, 1], inertia[0, 2], inertia[1, 1], inertia[1, 2],
            inertia[2, 2]]


def test_every_mass_distribution_passes(rng):
    for n in (1, 2, 3, 7, 50):  # 1: a point mass (I = 0); 2: a rod (one moment 0)
        for _ in range(20):
            masses = rng.uniform(0.01, 5.0, n)
            points = rng.normal(scale=rng.uniform(0.01, 2.0), size=(n, 3))
            assert inertia_problem(point_cloud_inertia(masses, points)) is None


def test_a_thin_disk_rounded_to_six_digits_passes(rng):
    """Izz = Ixx + Iyy holds with equality for a flat body; URDFs print rounded numbers."""
    masses = rng.uniform(0.1, 1.0, 40)
    points = np.column_stack([rng.normal(size=(40, 2)), np.zeros(40)])
    values = [float(f"{v:.6g}") for v in point_cloud_inertia(masses, points)]
    assert inertia_problem(values) is None


@pytest.mark.parametrize("moments, needle", [
    ([-0.01, 0.5, 0.6], "not positive semi-definite"),
    ([0.1, 0.2, 0.35], "triangle inequality"),
    ([0.0, 0.0, 0.1], "triangle inequality"),
])
def test_impossible_inertias_are_refused_in_any_orientation(moments, needle, rng):
    for _ in range(10):
        problem = inertia_problem(rotated(moments, rng))
        assert problem is not None and needle in problem


def test_non_finite_inertia_is_refused():
    assert "finite" in inertia_problem([1.0, 0.0, 0.0, float("nan"), 0.0, 1.0])


def test_a_non_unit_axis_is_normalised_as_pinocchio_does(rng):
    """A URDF axis of length 2 is the same joint as the unit axis (Pinocchio normalises it),
    so feltool accepts it: equal inverse dynamics."""
    unit = load_urdf_string(ARM.replace('<axis xyz="0 -1 0"/>', '<axis xyz="0.6 0 0.8"/>', 1))
    long = load_urdf_string(ARM.replace('<axis xyz="0 -1 0"/>', '<axis xyz="1.5 0 2.0"/>', 1))
    for _ in range(5):
        q, v, a = rng.normal(size=2), rng.normal(size=2), rng.normal(size=2)
        tau_u = pin.rnea(unit.model, unit.model.createData(), q, v, a)
        tau_l = pin.rnea(long.model, long.model.createData(), q, v, a)
        np.testing.assert_allclose(tau_l, tau_u, rtol=1e-12, atol=1e-12)


def test_a_locked_continuous_joint_is_held_at_its_posture():
    """Pinocchio stores a continuous joint as (cos, sin); locked at 0.7 rad it must put the
    tip where the same joint as a revolute one at 0.7 rad puts it."""
    cont = load_urdf_string(ARM.replace('<joint name="elbow" type="revolute">',
                                        '<joint name="elbow" type="continuous">'))
    reduced = reduce_robot(cont, {"elbow": 0.7})
    rev = load_robot("two_link_arm")
    for q1 in (-0.4, 0.0, 1.1):
        placements = []
        for robot, q in ((reduced, np.array([q1])), (rev, np.array([q1, 0.7]))):
            data = robot.model.createData()
            pin.framesForwardKinematics(robot.model, data, q)
            placements.append(data.oMf[robot.model.getFrameId("tip")].translation.copy())
        np.testing.assert_allclose(placements[0], placements[1], atol=1e-12)


def test_a_continuous_joint_is_an_angle_in_an_experiment(tmp_path):
    """A continuous elbow takes a role as one angle (no (cos, sin) pair): the standard arm with
    it learns exactly as with the revolute elbow, whose limits the run never reaches."""
    from feltool.runs.experiments import build_experiment
    from feltool.runs.seed import run_seed

    (tmp_path / "arm.urdf").write_text(ARM.replace('<joint name="elbow" type="revolute">',
                                                   '<joint name="elbow" type="continuous">'))
    raw = read_yaml(STANDARD)
    raw["robot"] = "arm.urdf"
    cont = build_experiment(raw, tmp_path / "arm.yaml")
    rev = build_experiment(read_yaml(STANDARD), STANDARD)
    assert cont.robot.model.nq == cont.robot.model.nv == 2
    assert cont.robot.model.upperPositionLimit[1] == np.inf
    rows = [run_seed(exp, 0, cycles=3).rows for exp in (cont, rev)]
    for a, b in zip(*rows):
        for key in ("fb_abs_mean_elbow", "fb_abs_mean_shoulder", "param_norm"):
            assert a[key] == pytest.approx(b[key], rel=1e-12, abs=1e-12)


def test_angle_coordinates_keep_a_walkers_dynamics(rng):
    """The five-link walker with continuous joints, on its planar base: as angles (nq == nv)
    its mass, inverse dynamics and frames equal those of Pinocchio's (cos, sin) model."""
    from feltool.robot.robot import with_angle_coordinates
    from feltool.walking.model import with_planar_base

    text = (ROOT / "robots" / "five_link_walker.urdf").read_text()
    text = text.replace('type="revolute"', 'type="continuous"')
    text = text.replace('<axis xyz="0 1 0"/>', '<axis xyz="0.6 0.8 0"/>', 1)  # one unaligned
    cos_sin = load_urdf_string(text, name="walker")
    angles = with_angle_coordinates(cos_sin)
    for fixed in (cos_sin, angles):
        assert sum(i.mass for i in fixed.model.inertias) == pytest.approx(32.0)  # RABBIT-like
    a, b = with_planar_base(angles).model, with_planar_base(cos_sin).model
    assert a.nq == a.nv == b.nv == 7 and b.nq == 11
    da, db = a.createData(), b.createData()
    for _ in range(5):
        th, v, acc = rng.uniform(-1, 1, 7), rng.normal(size=7), rng.normal(size=7)
        qb = pin.neutral(b)
        for j in range(1, b.njoints):
            jm = b.joints[j]
            qb[jm.idx_q:jm.idx_q + jm.nq] = ([np.cos(th[jm.idx_v]), np.sin(th[jm.idx_v])]
                                              if jm.nq == 2 else th[jm.idx_v])
        np.testing.assert_allclose(pin.rnea(a, da, th, v, acc), pin.rnea(b, db, qb, v, acc),
                                   atol=1e-10)
        pin.framesForwardKinematics(a, da, th)
        pin.framesForwardKinematics(b, db, qb)
        for i in range(len(b.frames)):
            assert a.frames[i].name == b.frames[i].name
            np.testing.assert_allclose(da.oMf[i].homogeneous, db.oMf[i].homogeneous, atol=1e-12)


def _arm_with_mesh(filename: str) -> str:
    return ARM.replace('<geometry><box size="0.12 0.12 0.12"/></geometry>',
                       f'<geometry><mesh filename="{filename}"/></geometry>', 1)


def test_meshes_inside_the_urdf_folder_or_a_package_load_and_others_do_not(tmp_path):
    robot_dir, pkg, outside = tmp_path / "robot", tmp_path / "pkg", tmp_path / "elsewhere"
    for d in (robot_dir / "meshes", pkg / "meshes", outside):
        d.mkdir(parents=True)
    for f in (robot_dir / "meshes" / "a.stl", pkg / "meshes" / "b.stl", outside / "c.stl"):
        f.write_text("solid x\nendsolid x\n")
    (robot_dir / "linked").symlink_to(outside)  # a link inside the folder is the user's choice

    def load(filename, package_dirs=()):
        path = robot_dir / "arm.urdf"
        path.write_text(_arm_with_mesh(filename))
        return load_robot(str(path), package_dirs=[str(d) for d in package_dirs])

    load("meshes/a.stl")
    load("./meshes/../meshes/a.stl")  # climbs, but stays inside
    load("linked/c.stl")
    load("package://pkg/meshes/b.stl", [pkg])
    load(f"file://{pkg / 'meshes' / 'b.stl'}", [pkg])
    for filename, dirs in (("../elsewhere/c.stl", ()), (f"file://{outside / 'c.stl'}", ()),
                           (str(outside / "c.stl"), ()), ("package://pkg/../elsewhere/c.stl", [pkg])):
        with pytest.raises(RobotError, match="lies outside the URDF's folder"):
            load(filename, dirs)
    load("../elsewhere/c.stl", [outside])  # allowed once its folder is a package dir


@pytest.mark.parametrize("path", ["sim.rate_hz", "sim.substeps", "sim.cycles", "period_s",
                                  "primitives.basis", "primitives.alpha_z", "seeds",
                                  "learning.rates.weights", "joints.elbow.gains.kp",
                                  "joints.elbow.learn.weight_scale", "joints.shoulder.demo.amplitude",
                                  "joints.elbow.target.value", "gravity"])
@pytest.mark.parametrize("value", [True, False])
def test_a_boolean_is_no_number_anywhere(path, value):
    raw = read_yaml(STANDARD)
    node = raw
    *parents, leaf = path.split(".")
    for part in parents:
        node = node[part]
    node[leaf] = value
    with pytest.raises(ConfigError) as exc:
        parse_config(raw)
    assert any(p == path and "a boolean" in m for p, m in exc.value.problems), exc.value.problems


def test_a_boolean_field_still_takes_booleans():
    class WithFlag(Strict):
        flag: bool = True
        count: int = 1

    assert WithFlag(flag=False).flag is False
    with pytest.raises(ValueError, match="a boolean"):
        WithFlag(count=True)


def test_seed_lists_are_distinct_sorted_and_counted_before_they_exist():
    assert parse_seeds("3,0-2") == [0, 1, 2, 3]
    with pytest.raises(InputError, match="at most 100000"):
        parse_seeds(f"0-{10**18}")  # would need exabytes if it were built


# The peak resident size from /proc (VmHWM, this process's own: ru_maxrss would carry the
# parent's peak over exec).
_MEASURE = """
import json, sys
from pathlib import Path
from feltool import load_experiment, run_seed
from feltool.config.memory import estimate_bytes
def hwm():
    line = next(x for x in Path("/proc/self/status").read_text().splitlines() if x.startswith("VmHWM"))
    return int(line.split()[1])
before = hwm()
exp = load_experiment(sys.argv[1], sys.argv[2:])
run_seed(exp, 0, 1)
after = hwm()
est = estimate_bytes(exp.config, exp.robot.joint_names, exp.robot.model.njoints - 1)
print(json.dumps({"peak": (after - before) * 1024, "estimate": est}))
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux /proc")
@pytest.mark.parametrize("overrides", [["period_s=300"],
                                       ["period_s=100", "primitives.basis=60"]])
def test_the_memory_estimate_bounds_the_real_peak(overrides):
    """One cycle of a long period: the peak resident size it adds stays below the estimate
    that decides whether a run is refused (and the estimate is not absurdly loose)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", _MEASURE, str(STANDARD), *overrides],
                         capture_output=True, text=True, env=env, timeout=600, check=True)
    m = json.loads(out.stdout.strip().splitlines()[-1])
    assert m["peak"] < m["estimate"] < 10 * m["peak"], m
