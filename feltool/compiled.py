r"""The compiled engine: whole learning cycles as one CasADi graph, generated to C and compiled.

A learning cycle is a pure function of the learned RMP parameters :math:`\theta`, the robot
state :math:`x_0 = (q_0, \dot q_0)` at its start and the cycle's data: the learned joints'
sensitivity rows at each step (:math:`q_d, \dot q_d, \ddot q_d = X\theta` plus the other
joints' desired motion, whatever phase the cycle runs at), the phase weight of each step, and
the settings (gains, targets, rates). The graph (:mod:`feltool.compiled_graph`) is built from
the same :mod:`feltool.cycle` pieces the Python engine evaluates (feedback laws, the plant's
step, the FEL sums and update), with the known and simulated models rebuilt symbolically from
the Pinocchio models (:mod:`feltool.dynamics.casadi_backend`).

It is generated to C, compiled with the system C compiler and cached on disk under a hash of the
graph and CasADi's version, so seeds, runs and sweeps over gains or rates reuse it. Without a C
compiler the engine runs in CasADi's interpreted virtual machine and says so once.

:func:`unsupported` lists what the compiled engine does not run, each with its YAML path and
the reason; ``backend: auto`` then runs the experiment on the Python engine.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import casadi as ca

from feltool.errors import ConfigError

_WARNED: set[str] = set()

#: Learning cycles run by one call of the compiled code (the update between them included).
CYCLES_PER_CALL = 10


def cache_dir() -> Path:
    """Where compiled cycles live: ``$FELTOOL_CACHE`` or ``~/.cache/feltool``."""
    root = os.environ.get("FELTOOL_CACHE") or Path.home() / ".cache" / "feltool"
    return Path(root) / "compiled"


def c_compiler() -> str | None:
    """The C compiler the compiled engine uses (``$CC``, ``cc`` or ``gcc``), or None."""
    return shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")


def unsupported(exp) -> list[tuple[str, str]]:
    """What of ``exp`` the compiled engine cannot run, as ``(yaml path, reason)`` (empty: it
    runs all of it)."""
    from feltool.fel import FEL_UPDATES

    cfg, L = exp.config, exp.config.learning
    out = []
    if L.sensitivity == "finite_difference":
        out.append(("learning.sensitivity", "finite_difference is the Python engine's check of "
                                            "the exact sensitivity (the compiled engine "
                                            "differentiates exactly)"))
    if L.update not in FEL_UPDATES:
        out.append(("learning.update", f"{L.update} runs in the Python engine only (it has its "
                                       "own cycle runner, feltool.ilc)"))
    if cfg.disturbances is not None:
        out.append(("disturbances", "disturbances run in the Python engine only (their "
                                    "random draws per step, feltool.disturbances)"))
    if cfg.primitives.phase == "adaptive":
        out.append(("primitives.phase", "the adaptive oscillator runs in the Python engine only "
                                        "(its cycle length depends on the measured motion)"))
    if exp.robot.model.nq != exp.robot.model.nv:
        out.append(("robot", "the compiled engine needs joints with one coordinate each"))
    if cfg.walking is not None and cfg.walking.physical:
        from feltool.compiled_physical import unsupported_physical

        out += unsupported_physical(exp)
    elif exp.hybrid is not None:
        from feltool.compiled_walker import unsupported_walker

        out += unsupported_walker(exp)
    return out


def check_supported(exp) -> None:
    """Raise :class:`ConfigError` naming each feature of ``exp`` the compiled engine lacks."""
    problems = [(where, f"backend 'compiled': {why}; use backend auto or pinocchio")
                for where, why in unsupported(exp)]
    if problems:
        raise ConfigError(problems, str(exp.source) if exp.source else None)


def compile_functions(fns: list[ca.Function], directory: Path | None = None,
                      vm_fallback: bool = True) -> list[ca.Function] | None:
    """Generate ``fns`` to one C file, compile it with the system compiler and load the
    functions from it; the library is cached under a hash of the graphs and the CasADi version.
    Without a working compiler: ``fns`` themselves (CasADi's virtual machine, said once), or
    None unless ``vm_fallback``."""
    directory = directory or cache_dir()
    digest = hashlib.sha256(ca.__version__.encode())
    for fn in fns:
        digest.update(fn.serialize().encode())
    name = f"feltool_cycle_{digest.hexdigest()[:20]}"
    lib = directory / f"{name}.so"
    compiler = c_compiler()
    if not lib.is_file():
        if compiler is None:
            if not vm_fallback:
                return None
            note_once("no C compiler found (set CC); the compiled backend runs in CasADi's "
                      "interpreted virtual machine instead, which is much slower")
            return fns
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=directory) as tmp:
            src = Path(tmp) / f"{name}.c"
            gen = ca.CodeGenerator(src.name, {"with_header": False, "casadi_int": "long long"})
            for fn in fns:
                gen.add(fn)
            gen.generate(tmp + os.sep)
            out = Path(tmp) / lib.name
            try:
                proc = subprocess.run([compiler, "-O2", "-shared", "-fPIC", "-o", str(out),
                                       str(src)], capture_output=True, text=True, timeout=600)
            except (OSError, subprocess.TimeoutExpired) as exc:
                proc = subprocess.CompletedProcess([], 1, "", str(exc))
            if proc.returncode != 0 or not out.is_file():
                if not vm_fallback:
                    return None
                note_once(f"compiling the cycle failed ({proc.stderr.strip()[:300]}); using "
                          "CasADi's interpreted virtual machine instead")
                return fns
            os.replace(out, lib)  # atomic: concurrent workers never load half a library
    return [ca.external(fn.name(), str(lib)) for fn in fns]


def note_once(message: str) -> None:
    """Print ``feltool: note: message`` to stderr, once per process."""
    if message not in _WARNED:
        _WARNED.add(message)
        print(f"feltool: note: {message}", file=sys.stderr)


def feedforward_jacobian(exp) -> ca.Function:
    """``theta -> J`` with ``J[k*nv + r, p] = d u_ff[k, r] / d theta_learned[p]``, by CasADi's
    algorithmic differentiation through the RMP limit cycle and the symbolic RNEA
    (``sensitivity: casadi``)."""
    from feltool.dynamics.casadi_backend import symbolic_rnea

    model, prims, learner = exp.robot.model, exp.primitives, exp.learner
    n = prims.n_steps
    theta = ca.SX.sym("theta", prims.n_params)
    rows = {name: [] for name in ("q", "v", "a")}
    for i, prim in prims.primitives.items():
        th = theta[prims.slices[i]]
        for name, X in (("q", prim.Xq), ("v", prim.Xv), ("a", prim.Xa)):
            rows[name].append(ca.mtimes(ca.DM(X), th).T)
    Qd, Vd, Ad = (ca.vertcat(*rows[name]) for name in ("q", "v", "a"))
    U_ff = symbolic_rnea(model).map(n, "serial")(Qd, Vd, Ad)  # nv x n
    learned = theta[learner.learned.tolist()]
    jac = ca.jacobian(ca.vec(U_ff), learned)  # column-major: sample-major rows
    return ca.Function("ff_jacobian", [theta], [ca.densify(jac)])


__all__ = ["CYCLES_PER_CALL", "c_compiler", "note_once", "cache_dir", "check_supported", "compile_functions",
           "feedforward_jacobian", "unsupported"]
