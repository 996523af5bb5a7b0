"""The compiled engine's library: the cycle's CasADi graphs generated to C, compiled with the
system compiler and cached on disk.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import casadi as ca

from feltool.files import WriteError, atomic_write, reason

_WARNED: set[str] = set()


#: Learning cycles run by one call of the compiled code (the update between them included).
CYCLES_PER_CALL = 10

#: The compiler's options: -O2 without its instruction scheduling after register allocation,
#: partial redundancy elimination and global CSE, passes that cost 16-19 % of the compile of a
#: walker's library and gave its cycle nothing (compass gait, five-link walker and a two-link
#: arm: the same results to the bit, the same time per cycle within 2 %). No option that lets
#: the compiler reorder floating-point operations.
CFLAGS = ("-O2", "-fno-schedule-insns2", "-fno-tree-pre", "-fno-gcse")

#: What this process did with compiled libraries: ``built`` (generated and compiled) and
#: ``loaded`` (found in the cache) [-].
COUNTS = {"built": 0, "loaded": 0}


def cache_dir() -> Path:
    """Where compiled cycles live: ``$FELTOOL_CACHE`` or ``~/.cache/feltool``."""
    root = os.environ.get("FELTOOL_CACHE") or Path.home() / ".cache" / "feltool"
    return Path(root) / "compiled"


def c_compiler() -> str | None:
    """The C compiler the compiled engine uses (``$CC``, ``cc`` or ``gcc``), or None."""
    return shutil.which(os.environ.get("CC") or "cc") or shutil.which("gcc")


def source_digest() -> str:
    """SHA-256 of feltool's own source (every ``.py`` file of the package) and of the versions
    of CasADi, Pinocchio and numpy: part of every :func:`cached` key, so a changed feltool
    never loads a library built by another."""
    global _SOURCE
    if _SOURCE is None:
        import numpy as np
        import pinocchio as pin

        root = Path(__file__).resolve().parents[2]
        digest = hashlib.sha256(f"{ca.__version__} {pin.__version__} {np.__version__}".encode())
        for path in sorted(root.rglob("*.py")):
            digest.update(path.relative_to(root).as_posix().encode())
            digest.update(path.read_bytes())
        _SOURCE = digest.hexdigest()
    return _SOURCE


_SOURCE: str | None = None


def library_name(key: str) -> str:
    """The cached library's file stem for a key (:func:`cached`)."""
    digest = hashlib.sha256((source_digest() + key).encode())
    return f"feltool_cycle_k{digest.hexdigest()[:20]}"


def cached(key: str, names: list[str], directory: Path | None = None) -> list[ca.Function] | None:
    """The functions ``names`` of the library compiled for ``key`` (a string that determines
    the graphs: :meth:`feltool.engines.compiled.engine.CompiledEngine` makes it from the
    experiment's validated config, its robot model and its worlds), or None when there is none
    (or it does not match its record): the graphs need not even be built to find it."""
    lib = (directory or cache_dir()) / f"{library_name(key)}.so"
    if not verified(lib):
        return None
    COUNTS["loaded"] += 1
    return [ca.external(name, str(lib)) for name in names]


def has_library(key: str) -> bool:
    """Whether the library of ``key`` is in the cache (and matches its record)."""
    return verified(cache_dir() / f"{library_name(key)}.so")


def compile_functions(fns: list[ca.Function], directory: Path | None = None,
                      vm_fallback: bool = True, key: str | None = None
                      ) -> list[ca.Function] | None:
    """Generate ``fns`` to one C file, compile it with the system compiler and load the
    functions from it; the library is cached under a hash of the graphs and the CasADi version.
    Without a working compiler: ``fns`` themselves (CasADi's virtual machine, said once), or
    None unless ``vm_fallback``.

    A cached library is loaded only after its size and SHA-256 match the record written
    beside it when it was built (``NAME.so.json``): a library cut short (an interrupted copy of
    the cache, a full disk) would crash the process when loaded (SIGBUS), so one that does not
    match, or has no record, is built again. A cache directory that cannot be written (read
    only, full) costs only time: the library is then built in a temporary directory, used by
    this process and not kept (said once). With ``key`` the library is named by it
    (:func:`cached` finds it without the graphs), else by a hash of the graphs."""
    directory = directory or cache_dir()
    if key is not None:
        name = library_name(key)
    else:
        digest = hashlib.sha256(ca.__version__.encode())
        for fn in fns:
            digest.update(fn.serialize().encode())
        name = f"feltool_cycle_{digest.hexdigest()[:20]}"
    lib = directory / f"{name}.so"
    running = _PENDING.pop(name, None)
    if running is not None and running.directory == directory:  # started ahead: wait for it
        try:
            return _build(fns, name, running.compiler, running.tmp, lib, vm_fallback, running)
        except (OSError, WriteError):
            pass  # (then as if it had not been started)
        finally:
            running.cancel()
    elif running is not None:
        running.cancel()
    if verified(lib):
        COUNTS["loaded"] += 1
        return [ca.external(fn.name(), str(lib)) for fn in fns]
    compiler = c_compiler()
    if compiler is None:
        if not vm_fallback:
            return None
        note_once("no C compiler found (set CC); the compiled backend runs in CasADi's "
                  "interpreted virtual machine instead, which is much slower")
        return fns
    try:
        directory.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=directory) as tmp:
            return _build(fns, name, compiler, Path(tmp), lib, vm_fallback)
    except (OSError, WriteError) as exc:  # the cache cannot be written: build elsewhere
        why = exc.reason if isinstance(exc, WriteError) else reason(exc)
        note_once(f"the compiled-engine cache {directory} cannot be written ({why}); the "
                  "cycle is compiled in a temporary directory and not kept (set "
                  "FELTOOL_CACHE to a writable directory)")
    try:
        with tempfile.TemporaryDirectory() as tmp:
            loaded = _build(fns, name, compiler, Path(tmp), Path(tmp) / "lib" / f"{name}.so",
                            vm_fallback)
        return loaded  # loaded before its directory went: the process keeps the mapping
    except (OSError, WriteError) as exc:
        if not vm_fallback:
            return None
        note_once(f"the cycle cannot be compiled anywhere ({exc}); using CasADi's interpreted "
                  "virtual machine instead")
        return fns


def verified(lib: Path) -> bool:
    """Whether ``lib`` exists and has the size and SHA-256 recorded beside it."""
    record = lib.with_name(lib.name + ".json")
    try:
        expected = json.loads(record.read_text())
        data = lib.read_bytes()
    except (OSError, ValueError):
        return False
    return isinstance(expected, dict) and expected.get("size") == len(data) and \
        expected.get("sha256") == hashlib.sha256(data).hexdigest()


def _build(fns: list[ca.Function], name: str, compiler: str, tmp: Path, lib: Path,
           vm_fallback: bool, running: _Compilation | None = None) -> list[ca.Function] | None:
    """Generate and compile in ``tmp`` (or wait for ``running``, started there), record the
    library's size and digest, move it to ``lib`` (atomic: concurrent workers never load half a
    library) and load it."""
    running = running or _Compilation(fns, name, compiler, tmp)
    proc = running.wait()
    out = running.out
    if proc.returncode != 0 or not out.is_file():
        if not vm_fallback:
            return None
        note_once(f"compiling the cycle failed ({proc.stderr.strip()[:300]}); using "
                  "CasADi's interpreted virtual machine instead")
        return fns
    COUNTS["built"] += 1
    data = out.read_bytes()
    lib.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(lib.with_name(lib.name + ".json"), json.dumps(
        {"size": len(data), "sha256": hashlib.sha256(data).hexdigest(),
         "casadi": ca.__version__}) + "\n")
    os.replace(out, lib)
    return [ca.external(fn.name(), str(lib)) for fn in fns]


def compile_parts() -> int:
    """How many translation units a library is compiled in at once: the cores this process
    may run on, at most 4 (``$FELTOOL_COMPILE_PARTS`` overrides; 1 compiles the file whole)."""
    given = os.environ.get("FELTOOL_COMPILE_PARTS", "")
    if given.isdigit() and int(given) > 0:
        return int(given)
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cores = os.cpu_count() or 1
    return max(1, min(cores, 4))


class _Compilation:
    """CasADi's C of ``fns`` generated in ``tmp`` and ``cc -O2`` started on it: its functions
    spread over :func:`compile_parts` translation units
    (:func:`feltool.engines.compiled.csplit.split_source`) compiled at once, then linked (the
    file whole when it cannot be split). The functions' code and the options are the same
    either way, so are the results (to the bit). :meth:`wait` for the library ``out``."""

    def __init__(self, fns: list[ca.Function], name: str, compiler: str, tmp: Path):
        from feltool.engines.compiled.csplit import split_source

        self.fns, self.compiler, self.tmp, self.directory = fns, compiler, tmp, tmp.parent
        self.holder: tempfile.TemporaryDirectory | None = None  # (removes tmp when cancelled)
        src = tmp / f"{name}.c"
        gen = ca.CodeGenerator(src.name, {"with_header": False, "casadi_int": "long long"})
        for fn in fns:
            gen.add(fn)
        gen.generate(str(tmp) + os.sep)
        self.out = tmp / f"{name}.so"
        parts = split_source(src.read_text(), name, compile_parts())
        self.commands = [[compiler, *CFLAGS, "-shared", "-fPIC", "-o", str(self.out), str(src)]]
        self.objects: list[str] = []
        if parts is not None:
            self.commands = []
            for j, text in enumerate(parts):
                part = src.with_name(f"{src.stem}_part{j}.c")
                part.write_text(text)
                self.objects.append(str(part.with_suffix(".o")))
                self.commands.append([compiler, *CFLAGS, "-fPIC", "-c", "-o", self.objects[-1],
                                      str(part)])
        self.procs: list[subprocess.Popen] = []
        self.error = ""
        try:  # (their messages to files: a pipe not read while they run could fill)
            for j, c in enumerate(self.commands):
                with open(tmp / f"cc{j}.err", "w") as err:
                    self.procs.append(subprocess.Popen(c, stdout=subprocess.DEVNULL, stderr=err))
        except OSError as exc:
            self.error = str(exc)

    def wait(self) -> subprocess.CompletedProcess:
        """The compilers' (and the linker's) outcome: return code and errors."""
        try:
            errors = self.error
            for j, p in enumerate(self.procs):
                if p.wait(timeout=600) != 0:
                    errors += (self.tmp / f"cc{j}.err").read_text(errors="replace") or \
                        f"{self.commands[j][0]} exited {p.returncode}"
            if errors or not self.objects:
                return subprocess.CompletedProcess(self.commands[0], 1 if errors else 0, "",
                                                   errors)
            return subprocess.run([self.compiler, "-shared", "-o", str(self.out), *self.objects],
                                  capture_output=True, text=True, timeout=600)
        except (OSError, subprocess.TimeoutExpired) as exc:
            self.cancel()
            return subprocess.CompletedProcess([], 1, "", str(exc))

    def cancel(self) -> None:
        """Stop the compilers still running and remove a temporary directory held."""
        for p in self.procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        if self.holder is not None:
            self.holder.cleanup()
            self.holder = None


#: Compilations started ahead (:func:`compile_ahead`), by library name.
_PENDING: dict[str, _Compilation] = {}


def compile_ahead(fns: list[ca.Function], key: str) -> bool:
    """Start compiling the library of ``key`` and return at once: its C is generated now and
    the compilers are left running (e.g. while ``feltool gait`` designs the gait); the
    :func:`compile_functions` of the same key then waits for them instead of starting again,
    and :func:`pending` gives the graphs meanwhile. False (nothing started) when the library is
    cached, already under way, or cannot be compiled here (then it is compiled when needed).
    :func:`cancel_pending` stops what was started and not used."""
    directory = cache_dir()
    name = library_name(key)
    compiler = c_compiler()
    if name in _PENDING or compiler is None or verified(directory / f"{name}.so"):
        return False
    try:
        directory.mkdir(parents=True, exist_ok=True)
        holder = tempfile.TemporaryDirectory(dir=directory)
    except OSError:
        return False
    try:
        running = _Compilation(fns, name, compiler, Path(holder.name))
    except OSError:
        holder.cleanup()
        return False
    running.holder = holder
    _PENDING[name] = running
    return True


def pending(key: str) -> list[ca.Function] | None:
    """The graphs of the library of ``key`` while it compiles (:func:`compile_ahead`), or
    None."""
    running = _PENDING.get(library_name(key))
    return None if running is None else running.fns


def cancel_pending() -> None:
    """Stop every compilation started ahead and not used, and remove its files."""
    while _PENDING:
        _PENDING.popitem()[1].cancel()


def note_once(message: str) -> None:
    """Print ``feltool: note: message`` to stderr, once per process."""
    if message not in _WARNED:
        _WARNED.add(message)
        print(f"feltool: note: {message}", file=sys.stderr)
