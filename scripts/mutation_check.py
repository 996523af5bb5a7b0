"""Mutation check: does the suite catch a real fault? (issue 14)

Each named fault below is one small source edit of the kind a slip would make. For each, the
tree (``feltool/``, ``tests/``, ``configs/``, ``robots/``, ``pyproject.toml``) is copied to a
temporary directory, the edit is applied there (never to this tree), and the fault's relevant
tests run against the copy (``python -m pytest -x`` with the copy first on ``sys.path``). A fault
is *caught* when those tests fail. The same tests are first run on an unmodified copy: they must
pass, or a "caught" would mean nothing. The relevant tests are the files that exercise the
faulty code (not the whole suite, to keep the check to minutes); ``make test`` runs them all.

    PYTHONPATH=. python scripts/mutation_check.py            # every fault
    PYTHONPATH=. python scripts/mutation_check.py --only truncated_exponential

Exit status 0 when every fault is caught and the baseline passes.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
COPY = ("feltool", "tests", "configs", "robots", "pyproject.toml")


@dataclass(frozen=True)
class Fault:
    """A named fault: ``edits`` are ``(file, old, new)``, each ``old`` occurring exactly once."""

    name: str
    what: str
    edits: tuple[tuple[str, str, str], ...]
    tests: tuple[str, ...]


FAULTS = (
    Fault("wrong_sign_eq_3_6", "the FEL update of eq. 3.6 ascends: theta -= alpha J^T e",
          (("feltool/learning/fel.py", "theta[self.learned] += delta", "theta[self.learned] -= delta"),),
          ("tests/test_fel.py", "tests/test_configs_learn.py")),
    Fault("dropped_coriolis", "the known inverse model drops the velocity terms: RNEA(q, 0, a)",
          (("feltool/dynamics/pinocchio.py", "return pin.rnea(self.model, self.data, q, v, a).copy()",
            "return pin.rnea(self.model, self.data, q, 0 * v, a).copy()"),
           ("feltool/dynamics/pinocchio.py", "out[k] = rnea(model, data, Q[k], V[k], A[k])",
            "out[k] = rnea(model, data, Q[k], 0 * V[k], A[k])")),
          ("tests/test_dynamics.py",)),
    Fault("truncated_exponential", "the RMP's matrix exponential keeps only the 2nd-order Taylor "
          "terms", (("feltool/motion/rmp.py", "for k in range(1, 20):", "for k in range(1, 3):"),),
          ("tests/test_rmp.py",)),
    Fault("impact_swap_off_by_one", "the impact relabelling swaps the stance leg with the joint "
          "after the swing leg", (("feltool/experiment/assemble.py",
                                   "a, b = joints.index(w.swap[0]), joints.index(w.swap[1])",
                                   "a, b = joints.index(w.swap[0]), joints.index(w.swap[1]) + 1"),),
          ("tests/test_biped.py",)),
    Fault("wrong_basis_width", "the von Mises width defaults to h = N instead of N / 2",
          (("feltool/motion/rmp.py",
            "self.width = float(spectral.default_width(n_basis) if width is None else width)",
            "self.width = float(n_basis if width is None else width)"),),
          ("tests/test_rmp.py", "tests/test_mismatch.py")),
    Fault("width_ignores_alias", "the default width is N / 2 at every N, also where it aliases the "
          "first harmonic (five functions learn 1.7-2.4x slower)",
          (("feltool/motion/spectral.py",
            "if n_basis <= 2 or basis_alias(n_basis, half) <= ALIAS:",
            "if True:"),),
          ("tests/test_rmp.py",)),
    Fault("correction_on_every_joint", "the model correction also drives joints outside its error "
          "mask (the cause of the diverging mismatch seeds)",
          (("feltool/learning/model.py", "return (Phi @ theta_m) * self.error_mask",
            "return Phi @ theta_m"),),
          ("tests/test_mismatch.py",)),
)


def _copy_tree(dest: Path) -> None:
    for name in COPY:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=shutil.ignore_patterns(
                "__pycache__", "*.pyc", ".pytest_cache"))
        else:
            shutil.copy2(src, dest / name)


def _apply(dest: Path, fault: Fault) -> None:
    for rel, old, new in fault.edits:
        path = dest / rel
        text = path.read_text()
        if text.count(old) != 1:
            raise SystemExit(f"{fault.name}: '{old}' occurs {text.count(old)} times in {rel}; "
                             "update the fault to the current code")
        path.write_text(text.replace(old, new))


def _pytest(dest: Path, tests: tuple[str, ...]) -> tuple[bool, str, float]:
    env = dict(os.environ, PYTHONPATH=str(dest), FELTOOL_CACHE=str(dest / ".cache"))
    env.pop("CI", None)  # a skip is not a failure here: only failed tests count as caught
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                           *tests], cwd=dest, env=env, capture_output=True, text=True)
    summary = [ln for ln in proc.stdout.splitlines() if ln.startswith("FAILED")] or \
        proc.stdout.strip().splitlines()[-1:]
    return proc.returncode == 0, "; ".join(summary)[:300], time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", action="append", help="run only this fault (repeatable)")
    a = ap.parse_args()
    faults = [f for f in FAULTS if not a.only or f.name in a.only]
    rows, ok = [], True
    with tempfile.TemporaryDirectory(prefix="feltool-mutation-") as tmp:
        base = Path(tmp) / "baseline"
        _copy_tree(base)
        tests = tuple(sorted({t for f in faults for t in f.tests}))
        passed, summary, secs = _pytest(base, tests)
        print(f"baseline (no fault): {'pass' if passed else 'FAIL'} in {secs:.0f} s: {summary}",
              flush=True)
        ok &= passed
        for fault in faults:
            dest = Path(tmp) / fault.name
            _copy_tree(dest)
            _apply(dest, fault)
            passed, summary, secs = _pytest(dest, fault.tests)
            caught = not passed
            ok &= caught
            rows.append((fault, caught, summary, secs))
            print(f"{fault.name}: {'caught' if caught else 'NOT CAUGHT'} in {secs:.0f} s: "
                  f"{summary}", flush=True)
            shutil.rmtree(dest, ignore_errors=True)
    print("\n| fault | what | tests run | caught | first failing test | time [s] |")
    print("|---|---|---|---|---|---|")
    for fault, caught, summary, secs in rows:
        first = summary.split(";")[0].replace("FAILED ", "").split(" - ")[0]
        print(f"| `{fault.name}` | {fault.what} | {', '.join(fault.tests)} | "
              f"{'yes' if caught else '**no**'} | {first} | {secs:.0f} |")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
