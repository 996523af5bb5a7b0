"""Regenerate the golden metrics in tests/data/ (the only way they are written).

Where the numbers come from: feltool's own closed-loop simulation and FEL updates of the named
bundled configs (seeds 0-1, 6 cycles), run by this script with the code of the commit it records
in ``tests/data/goldens.json``. They are *regression* goldens: they show that a refactor did not
change what the learner does; correctness comes from the tests against independent references
(closed forms, scipy, finite differences). ``tests/test_mismatch.py`` compares a fresh run with
them at rel 1e-9, far above rounding noise (< 1e-11 across the refactors so far) and far below
what a real change of the method moves (the faults of scripts/mutation_check.py move them by
1e-4 and more).

Regenerate only for an intended change of the numbers, say why in the commit, on a clean tree::

    PYTHONPATH=. python scripts/make_goldens.py
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from feltool.runs.experiments import load_experiment  # noqa: E402
from feltool.runs.rundir import write_metrics  # noqa: E402
from feltool.runs.seed import run_seed  # noqa: E402

DATA = ROOT / "tests" / "data"
GOLDENS = {"two_link_standard": (0, 1), "two_link_human_arm": (0, 1)}  # config -> seeds
CYCLES = 6


def golden_name(config: str, seeds: tuple[int, ...], cycles: int = CYCLES) -> str:
    return f"metrics_{config}.seeds{seeds[0]}-{seeds[-1]}.cycles{cycles}.csv"


def config_digest(config: str) -> str:
    return hashlib.sha256((ROOT / "configs" / f"{config}.yaml").read_bytes()).hexdigest()


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()


def main() -> None:
    dirty = bool(_git("status", "--porcelain", "--", "feltool", "configs"))
    record = {"generated_by": "scripts/make_goldens.py", "commit": _git("rev-parse", "HEAD"),
              "tree_dirty": dirty, "created_utc": datetime.now(timezone.utc).isoformat(),
              "files": {}}
    for config, seeds in GOLDENS.items():
        # the Python engine, the reference (backend auto would run the compiled one)
        exp = load_experiment(ROOT / "configs" / f"{config}.yaml", ["backend=pinocchio"])
        rows = [row for seed in seeds for row in run_seed(exp, seed, CYCLES).rows]
        name = golden_name(config, seeds)
        write_metrics(DATA / name, rows)
        record["files"][name] = {"config": f"configs/{config}.yaml",
                                 "config_sha256": config_digest(config),
                                 "seeds": list(seeds), "cycles": CYCLES}
        print(f"wrote tests/data/{name} ({len(rows)} rows)")
    (DATA / "goldens.json").write_text(json.dumps(record, indent=1) + "\n")
    if dirty:
        print("warning: feltool/ or configs/ has uncommitted changes; commit them first so that "
              "goldens.json names the code that made the numbers")


if __name__ == "__main__":
    main()
