"""The compiled engine's library: the cycle's CasADi graphs generated to C, compiled with the
system compiler and cached on disk.
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
