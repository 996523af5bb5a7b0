"""The legged trot from a config (issue 32: ``walking.base: free_flyer``,
``configs/legged/solo12_trot.yaml``): ``feltool check`` and ``feltool run`` through the real
command, the run directory it writes, and every bad input refused with exit 2 naming its field.

The run is the shipped config shortened to 2 seeds x 8 cycles with the payload at cycle 2
(about 5 s of wall time per seed)."""

from __future__ import annotations

import csv
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from feltool.cli.main import main

from .conftest import CONFIGS, edited_solo_urdf, feltool

SHIPPED = CONFIGS / "legged" / "solo12_trot.yaml"


def _config(tmp_path: Path, name: str = "trot.yaml", shipped: Path = SHIPPED,
            **changes) -> Path:
    """The ``shipped`` config with ``changes`` (keys joined by ``__``; None removes a key),
    written to ``tmp_path``."""
    raw = yaml.safe_load(shipped.read_text())
    for key, value in changes.items():
        node, parts = raw, key.split("__")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        if value is None:
            node.pop(parts[-1], None)
        else:
            node[parts[-1]] = value
    path = tmp_path / name
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.mark.parametrize("name", ["solo12_trot.yaml", "solo12_trot_mujoco.yaml"])
def test_the_shipped_configs_check(name, capsys):
    assert main(["check", str(CONFIGS / "legged" / name)]) == 0
    out = capsys.readouterr().out
    assert "ok - robot solo12" in out and "10 seeds x 150 cycles" in out
    cfg = yaml.safe_load((CONFIGS / "legged" / name).read_text())
    assert cfg["payload"] == {"fraction": 0.2, "cycle": 3} and cfg["seeds"] == 10
    assert cfg["success"] == {"ratio_from": "change", "fb_ratio_max": 0.15}
    assert cfg["walking"]["acquire"] == 4


def test_a_short_run_writes_its_directory_and_the_feedback_falls_after_the_change(tmp_path):
    """2 seeds x 8 cycles, payload at cycle 2, the reference acquired in 2 rounds, through the
    installed command: exit 0, every file, the summary's numbers, and the learned feedforward
    bringing the feedback to the config's 0.15 of the change's cycle."""
    out = tmp_path / "run"
    proc = feltool("run", str(_config(tmp_path, payload__cycle=2, walking__acquire=2)),
                   "--seeds", "0-1", "--cycles", "8", "--out", str(out), "--no-progress",
                   "--html")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    assert "walked every cycle: 2/2" in proc.stdout
    reference = json.loads((out / "reference.json").read_text())
    assert reference["rounds"] == 2 and len(reference["feedback_n_m"]) == 3
    assert reference["feedback_n_m"][2] < 0.5 * reference["feedback_n_m"][0]
    for name in ("config.yaml", "run.json", "metrics.csv", "summary.json", "params/seed-0.npz",
                 "params/seed-1.npz", "traces/seed-0.npz", "figures/legged_feedback.png",
                 "rollout.html"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["verdict"] == "learned" and summary["change_cycle"] == 2
    assert [s["seed"] for s in summary["seeds"]] == [0, 1]
    for s in summary["seeds"]:
        assert s["walked"] and s["not_walking"] is None and s["cycles"] == 8
        before, change, last = s["fb_before_change"], s["fb_change"], s["fb_last"]
        assert 0 < before < change  # the payload adds feedback ...
        assert last < 0.6 * change  # ... that FEL takes back
        assert s["fb_ratio_change"] == pytest.approx(last / change)
        assert s["fb_ratio_change"] <= 0.15 and s["learned"]
        assert s["stats"]["torque_hits"] == 0 and s["stats"]["max_torque"] <= 2.7
    with open(out / "metrics.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 16 and {"fb_total", "fb_share_FL_HAA", "changed"} <= set(rows[0])
    fb0 = [float(r["fb_total"]) for r in rows if r["seed"] == "0"]
    assert fb0[2] == pytest.approx(summary["seeds"][0]["fb_change"])
    assert fb0[3] > fb0[4] > fb0[5] > fb0[6]  # falling after the change
    shares = np.array([[float(v) for k, v in r.items() if k.startswith("fb_share_")]
                       for r in rows])
    assert shares.shape == (16, 12)
    assert np.allclose(np.sqrt((shares ** 2).sum(axis=1)), [float(r["fb_total"]) for r in rows])
    with np.load(out / "params" / "seed-0.npz", allow_pickle=False) as p:
        assert p["C"].shape == (1, 18) and np.any(p["C"] != 0)
        assert list(p["coordinates"][6:9]) == ["FL_HAA", "FL_HFE", "FL_KFE"]
    assert yaml.safe_load((out / "config.yaml").read_text())["payload"]["cycle"] == 2
    _check_rollout_html(out)
    _check_plot_and_view(out)


def _check_plot_and_view(out: Path) -> None:
    """``feltool plot`` and ``feltool view`` on the legged run directory: the figure drawn
    again from metrics.csv, seed 1's rollout written, its clips played in the live viewer
    (--cycles, which names a fixed-base run's cycles, refused)."""
    figure = out / "figures" / "legged_feedback.png"
    figure.unlink()
    plot = feltool("plot", str(out))
    assert plot.returncode == 0 and plot.stdout.strip() == str(figure), plot.stderr
    assert figure.stat().st_size > 10_000
    view = feltool("view", str(out), "--html", "--seed", "1")
    assert view.returncode == 0, view.stderr
    assert "world changes (cycle 2)" in (out / "rollout-seed1.html").read_text()
    live = feltool("view", str(out), "--seed", "1", "--view-timeout", "4")
    assert live.returncode == 0, live.stderr
    assert "view: seed 1, world changes (cycle 2)" in live.stdout
    assert "feltool viewer: stopped" in live.stdout
    cycles = feltool("view", str(out), "--cycles", "last", "--view-timeout", "0")
    assert cycles.returncode == 2 and "--cycles last: a legged run" in cycles.stderr
    assert "Traceback" not in plot.stderr + view.stderr + live.stderr + cycles.stderr


def test_a_slope_from_the_config_reaches_the_plant_and_the_run_says_so(tmp_path, capsys):
    """The shipped slope config checks; a short run of it (1 seed x 6 cycles, the slope from
    cycle 2, no payload) through the command: the summary names the world, the metrics mark
    the cycles after the change, and the slope's feedback arrives at the change and falls."""
    slope = CONFIGS / "legged" / "solo12_slope.yaml"
    assert main(["check", str(slope)]) == 0
    assert "slope 0.1 rad uphill ahead from cycle 3" in capsys.readouterr().out
    out = tmp_path / "run"
    path = _config(tmp_path, "slope.yaml", slope, slope__cycle=2, walking__acquire=1,
                   success__fb_ratio_max=None)
    proc = feltool("run", str(path), "--seeds", "0", "--cycles", "6", "--out", str(out),
                   "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "slope 0.1 rad uphill ahead from cycle 2" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["world"] == "slope 0.1 rad uphill ahead" and summary["change_cycle"] == 2
    s = summary["seeds"][0]
    assert s["walked"] and s["fb_change"] > 5.0 * s["fb_before_change"]
    assert s["fb_last"] < 0.5 * s["fb_change"]
    with open(out / "metrics.csv") as fh:
        assert [int(r["changed"]) for r in csv.DictReader(fh)] == [0, 0, 1, 1, 1, 1]


def _check_rollout_html(out: Path) -> None:
    """rollout.html draws Solo-12's meshes (every visual of example-robot-data's model) and
    moves them along seed 0's recorded trot: the base goes forward at the trot's speed."""
    import example_robot_data as erd

    from .test_viewer import _commands

    page = (out / "rollout.html").read_text(encoding="utf-8")
    assert "world changes (cycle 2)" in page and "last cycles" in page
    cmds = _commands(page)
    visuals = erd.load("solo12").visual_model.geometryObjects
    objects = [c["path"] for c in cmds if c["type"] == "set_object"]
    assert len(objects) == len(visuals) > 10
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    base = next(a for a in anim["animations"] if "base_link" in a["path"])
    track = {t["name"]: t for t in base["clip"]["tracks"]}[".position"]
    times, x = np.array(track["times"]), np.array(track["values"]).reshape(-1, 3)[:, 0]
    assert np.all(np.diff(times) > 0)
    with np.load(out / "traces" / "seed-0.npz", allow_pickle=False) as tr:
        q, t = tr["q"], tr["t"]
    assert np.allclose(np.diff(t), 0.02) and q.shape[1] == 19
    last = times > times[len(times) // 2 + 1]  # the second clip, "last cycles"
    speed = (x[last][-2] - x[last][0]) / (times[last][-2] - times[last][0])
    assert speed == pytest.approx(0.3, abs=0.03)


def test_a_missed_success_bound_exits_1_and_keeps_the_results(tmp_path, capsys):
    out = tmp_path / "run"
    path = _config(tmp_path, payload__cycle=1, success__fb_ratio_max=0.01)
    assert main(["run", str(path), "--seeds", "0", "--cycles", "3", "--out", str(out),
                 "--no-progress"]) == 1
    printed = capsys.readouterr().out
    assert "fb_last / fb_change" in printed and "> success.fb_ratio_max = 0.01" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["verdict"] == "failed" and summary["seeds"][0]["walked"]
    # a run directory belongs to one command: not reused; resumed, a finished run runs
    # nothing again and says its verdict again
    assert main(["run", str(path), "--out", str(out)]) == 2
    assert "already holds" in capsys.readouterr().err
    params = (out / "params" / "seed-0.npz").stat().st_mtime_ns
    assert main(["run", "--resume", str(out)]) == 1
    assert "seed 0 (1/1): kept from the run directory" in capsys.readouterr().err
    assert (out / "params" / "seed-0.npz").stat().st_mtime_ns == params
    assert json.loads((out / "summary.json").read_text())["verdict"] == "failed"


def test_a_quadruped_urdf_of_ones_own_runs_on_mujoco_as_itself(tmp_path, capsys):
    """Solo-12's URDF with every joint renamed, as a config's robot on MuJoCo's plant, its
    reference posture (example-robot-data's, knees bent) from ``walking.posture``, its feet not
    named (found from its tree): the run trots this robot (MuJoCo's model built from it, not
    example-robot-data's Solo-12, whose joints it would not find)."""
    posture = solo_posture("my_")
    path = _config(tmp_path, shipped=CONFIGS / "legged" / "solo12_trot_mujoco.yaml",
                   robot=str(edited_solo_urdf(tmp_path)), walking__feet=None, effort=2.7,
                   walking__acquire=0, walking__posture=posture)
    out = tmp_path / "run"
    code = main(["run", str(path), "--seeds", "0", "--cycles", "3", "--out", str(out),
                 "--no-progress"])
    summary = json.loads((out / "summary.json").read_text())
    assert code in (0, 1), capsys.readouterr()  # 3 cycles: the success bound may be missed
    assert summary["plant"] == "mujoco" and summary["motors"][0] == "my_FL_HAA"
    assert summary["seeds"][0]["walked"] and summary["seeds"][0]["cycles"] == 3


def test_the_motors_armature_from_the_config_reaches_the_model_and_mujocos_plant(tmp_path):
    """``armature: 0.02``: the known model's joint-space inertia is Pinocchio's CRBA of the
    robot without it plus 0.02 on each motor's diagonal (the base's rows untouched), and
    MuJoCo's plant built from the model has it on every motor's dof (its accelerations are
    checked against pin.aba in test_legged_mujoco)."""
    import mujoco
    import pinocchio as pin

    from feltool.config.legged import parse_legged_config
    from feltool.runs.legged_robot import load_legged_robot
    from feltool.walking.legged.mujoco_plant import model_spec

    raw = yaml.safe_load((CONFIGS / "legged" / "solo12_trot.yaml").read_text())
    models = {}
    for armature in (None, 0.02):
        raw["armature"] = armature
        models[armature] = load_legged_robot(parse_legged_config(raw))
    q = models[None].standing()
    M0, M1 = (pin.crba(m.model, m.model.createData(), q) for m in models.values())
    add = np.r_[np.zeros(6), np.full(12, 0.02)]
    assert np.allclose(np.triu(M1) - np.triu(M0), np.diag(add), rtol=0, atol=1e-13)
    spec, _ = model_spec(mujoco, models[0.02])
    mj = spec.compile()
    assert np.allclose(mj.dof_armature, add, rtol=0, atol=0)


def test_a_seed_that_stops_before_its_first_cycle_exits_1_with_its_figure(tmp_path, capsys):
    """Motors too weak to stand (0.5 N m): a foot slips before the first cycle; the run says
    why, exits 1, and draws its (empty) figure without a traceback."""
    out = tmp_path / "run"
    path = _config(tmp_path, effort=0.5, walking__acquire=0)
    assert main(["run", str(path), "--seeds", "0", "--cycles", "3", "--out", str(out),
                 "--no-progress"]) == 1
    printed = capsys.readouterr()
    assert "Traceback" not in printed.err and "NOT WALKING" in printed.out.upper()
    entry = json.loads((out / "summary.json").read_text())["seeds"][0]
    assert entry["cycles"] == 0 and entry["kind"] == "friction"
    assert (out / "figures" / "legged_feedback.png").stat().st_size > 5_000


def test_a_seed_that_records_no_state_is_reported_and_shows_no_motion(tmp_path, capsys):
    """A trot whose start velocity (1000 times the usual draws) pulls a foot in the first
    control step: learn_trot reports it (before: a traceback, the speed taken of no recorded
    state). A run directory whose seed recorded no configuration, as such a seed's is:
    --html and `feltool view` say there is no motion to show (before: "clip 'rollout' has no
    frames"), exit 2, one line."""
    from feltool.runs.legged import trace
    from feltool.runs.rundir import save_npz
    from feltool.walking.legged.learn import learn_trot
    from feltool.walking.legged.model import load_solo12

    run = learn_trot(load_solo12(effort=2.7), cycles=1, payload=0.0, acquire=0,
                     start_speed=1000.0)
    assert len(run.log.t) == 0 and len(run.feedback) == 0 and run.speed == 0.0
    assert run.kind == "normal_force" and "would pull" in run.log.not_walking
    out = tmp_path / "run"
    path = _config(tmp_path, walking__acquire=0)
    assert main(["run", str(path), "--seeds", "0", "--cycles", "1", "--out", str(out),
                 "--no-progress"]) in (0, 1)
    save_npz(out / "traces" / "seed-0.npz",
             {**trace(run.log.t, run.log.q), "cycle_times": np.zeros((0, 2))})
    capsys.readouterr()
    assert main(["view", str(out), "--html"]) == 2
    err = capsys.readouterr().err
    assert "seed 0 stopped in its first control step" in err and "no motion to show" in err
    assert err.count("\n") == 1


def solo_posture(prefix: str = "") -> dict[str, float]:
    """Solo-12's reference posture [rad] by its joints' names (``prefix`` before each)."""
    return {f"{prefix}{leg}_{j}": a for leg, side, end in (("FL", 1, 1), ("FR", -1, 1),
                                                          ("HL", 1, -1), ("HR", -1, -1))
            for j, a in (("HAA", 0.1 * side), ("HFE", 0.8 * end), ("KFE", -1.6 * end))}


def _solo_urdf(name: str = "solo12") -> str:
    """Solo-12's URDF file (or another example-robot-data robot's)."""
    import example_robot_data as erd

    return str(erd.load(name).urdf)


def _stiff_knees_urdf(directory: Path) -> str:
    """Solo-12's URDF with its knees' range 0 +- 1e-3 rad: straight at its zeros, no bent
    posture within its limits."""
    text = Path(_solo_urdf()).read_text()
    text = re.sub(r'(<joint name="\w\w_KFE".*?<limit[^>]*?)lower="[^"]*" upper="[^"]*"',
                  r'\1lower="-0.001" upper="0.001"', text, flags=re.S)
    assert text.count('lower="-0.001"') == 4
    path = directory / "stiff_knees.urdf"
    path.write_text(text)
    return str(path)




SOLO_FEET = {f: {"frame": f"{f}_FOOT"} for f in ("FL", "FR", "HL", "HR")}
BAD = [
    ({"robot": "example-robot-data:nonsense", "walking__feet": SOLO_FEET},
     "robot: example-robot-data has no robot 'nonsense'"),
    ({"robot": "example-robot-data:ur5", "walking__feet": SOLO_FEET},
     "robot: ur5: a legged robot's first joint must be a free flyer"),
    ({"robot": "example-robot-data:talos", "walking__feet": None},
     "walking.feet: required: talos names no feet (walking.feet, SRDF end effectors lf_*, "
     "rf_*, lh_*, rh_*) and its tree ends in 2 at the bottom of legs of three or more joints"),
    ({"robot": "example-robot-data:cassie", "walking__feet": SOLO_FEET},
     "robot: example-robot-data's cassie failed to load"),
    ({"robot": "{bolt}", "walking__feet": None},
     "walking.feet: required: bolt names no feet (walking.feet, SRDF end effectors"),
    ({"robot": "example-robot-data:ur5", "walking__feet": None},
     "robot: ur5: a legged robot's first joint must be a free flyer"),
    ({"robot": "example-robot-data:solo8", "walking__feet": None},
     "walking.feet: the gait places each foot in 3D, which takes a leg of at least three "
     "joints: FL's has 2"),
    ({"robot": "{stiff}"}, "walking.posture: in the reference posture (none given: the "
                           "model's, a URDF's zeros) the legs of FL, FR, HL, HR cannot move"),
    ({"walking__base": "free-flyer"}, "walking.base: 'free-flyer' is neither planar"),
    ({"robot": "example-robot-data:go1", "walking__feet": {
        "FL": {"frame": "FL_FOOT"}, "FR": {"frame": "FR_foot"}, "HL": {"frame": "RL_foot"},
        "HR": {"frame": "RR_foot"}}}, "walking.feet.FL: no frame 'FL_FOOT' in go1"),
    ({"walking__gait__sped": 0.3}, "walking.gait.sped: unknown field"),
    ({"walking__gait__speed": -0.3}, "walking.gait.speed:"),
    ({"walking__gait__period": 0}, "walking.gait.period:"),
    ({"walking__feet__XL": {"frame": "FL_FOOT"}}, "walking.feet.XL: unknown foot name 'XL'"),
    ({"walking__feet__HR": None}, "walking.feet: the trot needs all four feet"),
    ({"walking__feet__FL": {"frame": "NOPE"}}, "walking.feet.FL: no frame 'NOPE'"),
    ({"walking__feet__FL": {"frame": "FL_FOOT", "link": "FL_LOWER_LEG"}}, "walking.feet.FL:"),
    ({"robot": "missing.urdf"}, "robot: "),
    ({"robot": "anymal"}, "robot: 'anymal' is neither solo12, talos_legs, "
                         "example-robot-data:NAME nor a URDF"),
    ({"robot": "{stiff}", "walking__feet": None},  # its feet found, its zeros straight
     "walking.posture: in the reference posture (none given: the model's, a URDF's zeros)"),
    ({"effort": -1}, "effort:"),
    ({"armature": -0.01}, "armature:"),
    ({"armature": "heavy"}, "armature:"),
    ({"walking__posture": {"FL_KNEE": -1.6}}, "walking.posture.FL_KNEE: no motor joint 'FL_KNEE'"),
    ({"walking__posture": {"root_joint": 0.0}}, "walking.posture.root_joint: no motor joint"),
    ({"walking__posture": {"FL_KFE": float("nan")}}, "walking.posture.FL_KFE:"),
    ({"walking__posture": {"FL_KFE": "bent"}}, "walking.posture.FL_KFE:"),
    ({"walking__posture": {"FL_KFE": -3.1, "FR_KFE": -3.1, "HL_KFE": 3.1, "HR_KFE": 3.1}},
     "walking.posture: in the reference posture the base's origin is"),  # knees folded up
    ({"payload__fraction": 0}, "payload.fraction:"),
    ({"payload__cycle": 0}, "payload.cycle:"),
    ({"payload": None}, "success.ratio_from: change needs a change of the world"),
    ({"slope": {"angle": 0.1, "cycle": 4}}, "slope.cycle: the world changes once"),
    ({"masses": {"scale": 1.2, "cycle": 5}}, "masses.cycle: the world changes once"),
    ({"masses": {"scale": 0, "cycle": 3}}, "masses.scale:"),
    ({"slope": {"angle": 1.2, "cycle": 3}}, "slope.angle:"),
    ({"slope": {"angle": 0.1, "roll": "steep", "cycle": 3}}, "slope.roll:"),
    ({"slope": {"roll": 0.1, "cycle": 3}}, "slope.angle: required"),
    ({"plant__simulator": "bullet"}, "plant.simulator:"),
    ({"sim__cycles": True}, "sim.cycles: a boolean"),
    ({"sim__rate_hz": 10}, "sim.rate_hz:"),
    ({"plant__simulator": "mujoco", "sim__impact_window_s": 0.001}, "sim.impact_window_s:"),
    ({"learning__rate": 2}, "learning.rate:"),
    ({"learning__harmonics": -1}, "learning.harmonics:"),
    ({"seeds": [1, 1]}, "seeds: seed 1 given more than once"),
    ({"period_s": 0.3}, "period_s: unknown field"),
]


@pytest.mark.parametrize("changes, message", BAD, ids=[m.split(":")[0] for _, m in BAD])
def test_a_bad_field_exits_2_naming_it(tmp_path, capsys, changes, message):
    urdfs = {"{urdf}": _solo_urdf, "{bolt}": lambda: _solo_urdf("bolt"),  # a biped
             "{stiff}": lambda: _stiff_knees_urdf(tmp_path)}
    changes = {k: urdfs[v]() if isinstance(v, str) and v in urdfs else v
               for k, v in changes.items()}
    path = _config(tmp_path, **changes)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert main(["run", str(path), "--out", str(tmp_path / "never")]) == 2
    assert not (tmp_path / "never").exists()
    capsys.readouterr()


def test_a_urdf_robot_with_link_and_offset_feet_checks(tmp_path, capsys):
    """Any URDF on a free flyer: Solo-12's own file with its feet as the lower legs' points,
    its posture from the config (at the URDF's zeros its legs are straight: refused, BAD)."""
    feet = {f: {"link": f"{f}_LOWER_LEG", "offset": [0.0, 0.0, -0.16]}
            for f in ("FL", "FR", "HL", "HR")}
    path = _config(tmp_path, robot=_solo_urdf(), walking__feet=feet,
                   walking__posture=solo_posture())
    assert main(["check", str(path)]) == 0
    assert "feet FL, FR, HL, HR" in capsys.readouterr().out


def test_a_legged_run_streams_its_first_seed_to_the_live_viewer(tmp_path, capsys):
    """``feltool run --view`` on a legged config: every cycle of the first seed reported by
    the viewer's status line with the feedback metrics.csv records, the run then replayed
    until --view-timeout; the drawing process drew frames of the robot."""
    out = tmp_path / "run"
    path = _config(tmp_path, walking__acquire=0)
    code = main(["run", str(path), "--out", str(out), "--cycles", "3", "--seeds", "0",
                 "--view", "--view-timeout", "1", "--no-progress"])
    text = capsys.readouterr().out
    assert code in (0, 1), text  # 3 cycles: the config's success bound may be missed
    with (out / "metrics.csv").open() as fh:
        fb = [float(r["fb_total"]) for r in csv.DictReader(fh)]
    assert len(fb) == 3
    assert f"view: seed 0: cycle 3/3, error feedback {fb[2]:.4g} N m" in text
    assert "view: seed 0, last cycles" in text and "feltool viewer: stopped" in text


def test_the_legged_stream_draws_frames_in_place():
    """The stream's drawing process draws the cycles it is handed, each shifted to start above
    the origin (the live camera's aim), its ghost with it."""
    from feltool.viewer.legged import LeggedStream, in_place, visual_robot
    from feltool.viewer.live import LiveViewer
    from feltool.walking.legged.learn import learn_trot
    from feltool.walking.legged.model import load_solo12

    seen = []
    with LiveViewer(visual_robot("example-robot-data:solo12", None), quiet=True) as viewer:
        stream = LeggedStream(viewer, 1e-3, 2)
        run = learn_trot(load_solo12(effort=2.7), cycles=2, payload=0.0, acquire=0,
                         on_cycle=lambda *c: (seen.append(c), stream(*c)))
        stream.close()
    assert run.kind is None and len(seen) == 2
    assert stream.frames_drawn > 0  # at most 30 a second, while the second cycle ran
    _, _, q, q_d, _ = seen[1]
    shifted, ghost = in_place(q, q_d)
    assert np.allclose(shifted[0, :2], 0.0) and shifted[-1, 0] > 0.05  # it walks forward
    assert np.allclose(ghost[:, :2] - shifted[:, :2], q_d[:, :2] - q[:, :2])
    assert np.array_equal(shifted[:, 2:], q[:, 2:])


def test_a_bad_resume_exits_2_and_makes_nothing(tmp_path, capsys):
    assert main(["run", str(SHIPPED), "--resume", str(tmp_path / "x")]) == 2
    assert "no run.json" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def _summary_numbers(path: Path) -> dict:
    """summary.json without what differs between two runs of the same seeds (times)."""
    summary = json.loads(path.read_text())
    summary.pop("created_utc")
    for s in summary["seeds"]:
        s.pop("wall_s")
    return summary


def test_an_interrupted_run_resumes_its_unfinished_seeds(tmp_path):
    """SIGTERM while seed 1 trots: exit 143, seed 0's results kept and the hint printed; the
    same config with other cycles or payload is refused naming what differs (exit 2, nothing
    changed); ``--resume`` runs seed 1 only (seed 0's files untouched), and the run's summary
    and metrics are those of an uninterrupted run."""
    path = _config(tmp_path, payload__cycle=2, walking__acquire=1)
    cut, whole = tmp_path / "cut", tmp_path / "whole"
    args = [str(path), "--seeds", "0-1", "--cycles", "12"]
    proc = subprocess.Popen([sys.executable, "-m", "feltool.cli", "run", *args, "--out",
                             str(cut)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (cut / "seeds" / "seed-0.json").exists() and proc.poll() is None:
        assert time.monotonic() < deadline, "seed 0 did not finish"
        time.sleep(0.2)
    time.sleep(1.0)  # into seed 1
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, (out, err)
    assert f"feltool run --resume {cut}" in err and "Traceback" not in err
    assert not (cut / "summary.json").exists() and not (cut / "seeds" / "seed-1.json").exists()
    kept = (cut / "params" / "seed-0.npz").stat().st_mtime_ns
    for changed, said in ((["--cycles", "14"], "cycles: 12 -> 14"),
                          (["--set", "payload.fraction=0.3"], "payload.fraction: 0.2 -> 0.3")):
        bad = feltool("run", *args, *changed, "--resume", str(cut))
        assert bad.returncode == 2 and said in bad.stderr, bad.stderr
    assert json.loads((cut / "run.json").read_text())["state"] == "interrupted"
    resumed = feltool("run", "--resume", str(cut))
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert "seed 0 (1/2): kept from the run directory" in resumed.stderr
    assert (cut / "params" / "seed-0.npz").stat().st_mtime_ns == kept
    assert feltool("run", *args, "--out", str(whole)).returncode == 0
    assert _summary_numbers(cut / "summary.json") == _summary_numbers(whole / "summary.json")
    assert (cut / "metrics.csv").read_text() == (whole / "metrics.csv").read_text()


WALK = CONFIGS / "legged" / "talos_walk.yaml"


def _walk(tmp_path: Path, **changes) -> Path:
    return _config(tmp_path, "walk.yaml", WALK, **changes)


@pytest.mark.parametrize("config", [WALK, CONFIGS / "legged" / "talos_walk_mujoco.yaml"])
def test_the_shipped_biped_walks_check(config, capsys):
    assert main(["check", str(config)]) == 0
    out = capsys.readouterr().out
    assert "ok - robot talos_legs" in out and "walk 0.15 m/s" in out
    assert "feet L_toe_out, L_toe_in, L_heel_out, L_heel_in, R_toe_out" in out
    assert f"plant {'mujoco' if 'mujoco' in config.name else 'pinocchio'}" in out


WALK_BAD = [
    ({"walking__walk": None}, "walking.walk: a biped (talos_legs) walks"),
    ({"walking__walk__right": ["L_toe_out"]}, "walking.walk: a foot in both soles or twice"),
    ({"walking__gait": {"speed": 0.3}}, "walking.gait: the trot's"),
    ({"plant__simulator": "mujoco"}, "sim.impact_window_s: the rigid plant's impact window"),
    ({"walking__walk__sway": 3}, "walking.walk.sway:"),
    ({"walking__feet": {"L_toe_out": {"link": "leg_left_6_link", "offset": [0.1, 0.065, -0.107]}}},
     "walking.walk: not among walking.feet: L_toe_in, L_heel_out"),
    ({"walking__feet": {"L_toe_out": {"link": "no_such_link", "offset": [0, 0, 0]},
                        "L_toe_in": {"link": "leg_left_6_link"}, "L_heel_out":
                        {"link": "leg_left_6_link"}, "L_heel_in": {"link": "leg_left_6_link"},
                        "R_toe_out": {"link": "leg_right_6_link"}, "R_toe_in":
                        {"link": "leg_right_6_link"}, "R_heel_out": {"link": "leg_right_6_link"},
                        "R_heel_in": {"link": "leg_right_6_link"}}},
     "walking.feet.L_toe_out: no link 'no_such_link'"),
]


@pytest.mark.parametrize("changes, message", WALK_BAD, ids=[m.split(":")[0] + str(i) for i, (_, m)
                                                            in enumerate(WALK_BAD)])
def test_a_bad_walk_field_exits_2_naming_it(tmp_path, capsys, changes, message):
    path = _walk(tmp_path, **changes)
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err and err.count("\n") == 1, err


def test_the_biped_walks_on_mujoco_from_its_config(tmp_path):
    """configs/legged/talos_walk_mujoco.yaml: Talos' walk with MuJoCo as the plant (its eight
    sole corners MuJoCo's contacts, each sole's load checked as a whole: checked corner by
    corner, the walk stopped at its first control step), 1 seed x 2 cycles: every cycle
    walked physically, every corner pushing (after the sole's distribution), none sliding."""
    out = tmp_path / "run"
    path = CONFIGS / "legged" / "talos_walk_mujoco.yaml"
    assert main(["run", str(path), "--seeds", "0", "--cycles", "2", "--out", str(out),
                 "--no-progress"]) in (0, 1)
    seed = json.loads((out / "summary.json").read_text())["seeds"][0]
    assert seed["walked"] and seed["cycles"] == 2, seed["not_walking"]
    assert seed["stats"]["min_normal_force"] > 0.0
    assert seed["stats"]["max_friction_ratio"] <= 0.7 + 1e-9  # MuJoCo's cone (mu 0.7)


def test_a_short_biped_run_walks_and_writes_its_directory(tmp_path):
    """Talos' walk from its config through the installed command, 1 seed x 4 cycles, the
    payload at cycle 2, the success bound taken out (two cycles of learning do not reach it):
    exit 0, every cycle walked physically, the summary's feedback rising at the payload's
    cycle."""
    out = tmp_path / "run"
    proc = feltool("run", str(_walk(tmp_path, payload__cycle=2, success=None)), "--seeds", "0",
                   "--cycles", "4", "--out", str(out), "--no-progress")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    seed = summary["seeds"][0]
    assert seed["walked"] and seed["cycles"] == 4
    assert seed["fb_change"] > 3 * seed["fb_before_change"]
    with open(out / "metrics.csv") as fh:
        assert len(list(csv.DictReader(fh))) == 4
