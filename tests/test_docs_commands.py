"""Every command shown in README.md and docs/*.md runs as shown, with the exit code the docs
imply (0 unless its comment says otherwise), shortened where a run is long.

The commands are extracted from the pages' fenced code blocks (lines starting with ``feltool``,
``make`` or ``python``, ``\\`` continuations joined, comments dropped). They run in a scratch
directory that links the repository's ``configs/``, ``robots/`` and ``benchmarks/`` (so
nothing is written into the repository), ``feltool`` ones in this process (no start-up per
command), with these shortenings:

* ``feltool run`` and ``feltool sweep``: 2 cycles, seed 0, the Python engine (no C compilation
  per config; a sweep's as a one-value grid), a fresh ``--out``; a resumed run adds one cycle;
  ``--view`` closes at once; a legged config (``configs/legged/``, which has no ``backend``):
  seed 0, 8 cycles with the payload at cycle 2, the reference acquired in 2 rounds (about
  20 s), ``--view`` closing at once;
* ``feltool robustness``: 2 cycles, seed 0, one learner, one scenario at two values;
* ``feltool gait``: a fresh ``--out``, ``--view`` closes at once (its runs are seconds);
* ``runs/<run>`` is a run made by an earlier command; ``[--option value]`` (optional) dropped.

Commands that cannot run here are listed in :data:`EXEMPT` with the reason; the test fails when
a page shows a command that is neither run nor exempt, so none is skipped silently.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

from feltool.cli.main import main

from .conftest import ROOT

PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))

#: Command prefixes (after joining) that are not run, and why.
EXEMPT = {
    "make test": "the test suite itself",
    "make run": "creates .venv; it runs `feltool run configs/two_link_standard.yaml`, run here",
    "feltool run my_robot.yaml": "the reader's own config (own_robot.md builds it step by step)",
    "feltool check my_robot.yaml": "the reader's own config",
    "feltool gait my_walker.yaml": "the reader's own walker (own_robot.md writes it; the walkers "
                                   "of tests/test_walkers_published.py run this path)",
    "feltool run my_walker_gait.yaml": "the reader's own walker's gait",
    "python benchmarks/phase_experiments.py": "a measured benchmark: 20 seeds of every phase "
                                              "experiment, minutes (benchmarks/)",
    "python benchmarks/biped_figures.py": "redraws docs/figures from a full 150-cycle run",
    "python benchmarks/walk_mujoco.py": "a measured benchmark: 10 seeds x 150 cycles of both "
                                        "walkers on MuJoCo, ~40 min (tests/test_mujoco.py runs "
                                        "its short learning check)",
    "python benchmarks/legged_trot.py --seeds 10": "a measured benchmark: 10 seeds x 20 s of the "
                                                   "trot, ~10 min (the page's short run and "
                                                   "tests/test_legged_trot.py run it)",
    "python benchmarks/legged_trot_mujoco.py --seeds 10": "a measured benchmark: 10 seeds x 20 s "
                                                          "on MuJoCo, ~8 min (its short run "
                                                          "and tests/test_legged_mujoco.py)",
    "python benchmarks/legged_poincare.py --cycles 20": "a measured benchmark: 3 x 40 runs of a "
                                                        "cycle, ~5 min (the page's short run and "
                                                        "tests/test_legged_learn.py)",
    "python benchmarks/legged_fel.py --seeds 0-9": "a measured benchmark: 10 seeds x 150 cycles, "
                                                   "~20 min per plant (the page's short run and "
                                                   "tests/test_legged_learn.py)",
    "python benchmarks/legged_walk.py --seeds 10": "a measured benchmark: 10 seeds x 14 s of "
                                                   "Talos walking, ~15 min (tests/"
                                                   "test_legged_walk.py walks 20 steps)",
    "python benchmarks/legged_fel.py --robot talos": "a measured benchmark: Talos' walk learning "
                                                     "under a payload, minutes per seed "
                                                     "(tests/test_legged_config.py runs it "
                                                     "short from its config)",
    "feltool run configs/legged/solo12_slope.yaml": "10 seeds x 40 cycles on a slope, ~4 min "
                                                    "(tests/test_legged_worlds.py learns on "
                                                    "seeds 0-2; tests/test_legged_config.py "
                                                    "runs a slope short through the command)",
    "feltool run configs/legged/talos_walk.yaml": "10 seeds x 24 cycles of Talos walking, ~45 "
                                                  "min (tests/test_legged_config.py runs it "
                                                  "short through the command)",
    "feltool run configs/legged/talos_walk_mujoco.yaml": "10 seeds x 24 cycles of Talos "
                                                         "walking on MuJoCo, ~1 h "
                                                         "(tests/test_legged_config.py walks it "
                                                         "2 cycles through the command)",
    "feltool run configs/legged/go1_trot.yaml": "10 seeds x 60 cycles of Go1, ~5 min "
                                                "(tests/test_legged_similar.py runs it short "
                                                "through the command; 8 cycles would not reach "
                                                "its bound)",
    "feltool run configs/legged/go1_trot_mujoco.yaml": "10 seeds x 60 cycles of Go1 on MuJoCo, "
                                                       "~8 min (tests/test_legged_similar.py "
                                                       "runs it short through the command)",
}
#: A command with one of these needs a service that is not here.
NEEDS_SERVICE = ("--zmq-url", "--scheduler")


def doc_commands(pages=PAGES) -> list[tuple[str, int, str]]:
    """``(page, line, command)`` of every command in the pages' fenced code blocks."""
    out = []
    for page in pages:
        lines = page.read_text().splitlines()
        fenced, pending, start = False, "", 0
        for i, line in enumerate(lines, 1):
            if line.strip().startswith("```"):
                fenced, pending = not fenced, ""
                continue
            if not fenced:
                continue
            text = line.strip()
            if text.startswith("$ "):
                text = text[2:]
            if not pending and not text.startswith(("feltool ", "make ", "python ")):
                continue
            if not pending:
                start = i
            if text.endswith("\\"):
                pending += text[:-1] + " "
                continue
            out.append((page.name, start, pending + text))
            pending = ""
    return out


def exemption(command: str) -> str | None:
    for prefix, why in EXEMPT.items():
        if command.startswith(prefix):
            return why
    if any(flag in command for flag in NEEDS_SERVICE):
        return "needs a running service (meshcat-server, Dask scheduler)"
    return None


class Runner:
    """Runs the docs' commands in ``work`` (see the module docstring)."""

    def __init__(self, work: Path):
        self.work, self.n, self.run_dir = work, 0, None

    def fresh(self, kind: str) -> str:
        self.n += 1
        return str(self.work / "out" / f"{kind}{self.n}")

    def argv(self, command: str) -> list[str]:
        args = shlex.split(command, comments=True)
        args = [a for a in _drop_optional(args)]
        if any("<run>" in a for a in args):
            assert self.run_dir is not None, "a runs/<run> command before any run"
            args = [a.replace("runs/<run>", self.run_dir) for a in args]
        if args[:1] != ["feltool"]:
            return args
        cmd = args[1] if len(args) > 1 else ""
        if cmd == "run" and "--resume" in args:
            return args + ["--cycles", "3", "--no-progress"]
        if cmd == "run" and any(a.startswith("configs/legged/") for a in args):
            extra = ["--view-timeout", "0"] if "--view" in args or "--realtime" in args else []
            return args + ["--cycles", "8", "--seeds", "0", "--out", self.fresh("legged"),
                           "--no-progress", "--set", "payload.cycle=2",
                           "--set", "walking.acquire=2", *extra]
        if cmd == "run":
            out = self.fresh("run")
            seeds = "0" if self.run_dir else "0,3"  # the runs/<run> examples show seed 3
            extra = ["--cycles", "2", "--seeds", seeds, "--out", out, "--no-progress",
                     "--set", "backend=pinocchio"]
            if "--view" in args or "--realtime" in args:
                extra += ["--view-timeout", "0"]
            self.run_dir = self.run_dir or out
            return args + extra
        if cmd == "sweep":
            return args + ["--cycles", "2", "--seeds", "0", "--out", self.fresh("sweep"),
                           "--no-progress", "--grid", "backend=pinocchio"]
        if cmd == "robustness":
            return args + ["--cycles", "2", "--seeds", "0", "--out", self.fresh("robust"),
                           "--learners", "gradient", "--scenarios", "noise_q",
                           "--range", "noise_q=0,0.001", "--jobs", "1",
                           "--set", "backend=pinocchio"]
        if cmd == "gait":
            extra = ["--out", self.fresh("gait") + ".yaml", "--no-progress"]
            if "--view" in args:
                extra += ["--view-timeout", "0"]
            return args + extra
        if cmd == "view" and "--html" not in args:
            return args + ["--view-timeout", "0"]
        return args

    def run(self, command: str) -> tuple[int, str]:
        args = self.argv(command)
        if args[0] == "feltool":
            try:
                return main(args[1:]), ""
            except SystemExit as exc:  # argparse: a usage error
                return int(exc.code or 0), ""
        if args[0] == "python":
            proc = subprocess.run([sys.executable] + args[1:], cwd=self.work, text=True,
                                  capture_output=True, timeout=600)
            return proc.returncode, proc.stdout[-2000:] + proc.stderr[-2000:]
        raise AssertionError(f"no rule to run {command!r}")


def _drop_optional(args: list[str]):
    """Without the ``[--option value]`` groups (the docs' notation for optional parts)."""
    depth = 0
    for a in args:
        if a.startswith("["):
            depth += 1
        if not depth:
            yield a
        if a.endswith("]") and depth:
            depth -= 1


def expected_code(command: str) -> int:
    """The exit code a command's comment implies: ``exit N`` alone (not ``exit 0, or ...``)."""
    m = re.search(r"#.*\bexits? (\d)\b(?!,? or)", command)
    return int(m.group(1)) if m and "or exit" not in command else 0


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    work = tmp_path_factory.mktemp("docs")
    for name in ("configs", "robots", "benchmarks"):
        (work / name).symlink_to(ROOT / name)
    (work / "docs" / "figures").mkdir(parents=True)
    return work


def test_every_command_in_the_docs_runs_as_shown(work, monkeypatch, capsys):
    monkeypatch.chdir(work)
    monkeypatch.setenv("PYTHONPATH", str(ROOT))
    commands = doc_commands()
    assert len(commands) > 40  # the extraction finds the pages' commands
    runner, failures, ran, timings = Runner(work), [], 0, []
    # the runs first: the commands on runs/<run> use one of them
    order = sorted(commands, key=lambda c: "<run>" in c[2])
    for page, line, command in order:
        if exemption(command):
            continue
        t0 = time.perf_counter()
        code, output = runner.run(command)
        printed = capsys.readouterr()
        timings.append((time.perf_counter() - t0, command))
        ran += 1
        if code != expected_code(command):
            failures.append(f"{page}:{line}: `{command}` exited {code} (expected "
                            f"{expected_code(command)}): {(printed.err + output)[-400:]}")
    with capsys.disabled():
        for seconds, command in sorted(timings, reverse=True)[:8]:
            print(f"\n  {seconds:6.1f} s  {command[:100]}", end="")
    assert not failures, "\n".join(failures)
    assert ran > 30


def test_a_broken_example_fails_the_check(work, tmp_path, monkeypatch, capsys):
    """The check above can fail: a page with a command that does not run is reported."""
    monkeypatch.chdir(work)
    page = tmp_path / "broken.md"
    page.write_text("```bash\nfeltool check configs/no_such_config.yaml\n"
                    "feltool inspect two_link_arm --pose shoulder=1.2\n```\n")
    (first, _, broken), (_, _, fine) = doc_commands([page])
    runner = Runner(work)
    assert runner.run(broken)[0] == 2 != expected_code(broken)
    assert runner.run(fine)[0] == expected_code(fine) == 0
    capsys.readouterr()


def test_every_command_is_run_or_exempt_with_a_reason():
    for page, line, command in doc_commands():
        assert command.split()[0] in ("feltool", "make", "python"), (page, line, command)
        if command.startswith(("make", "python")):
            assert exemption(command) or command.startswith("python benchmarks/"), command
