"""A run's inputs: the files it was built from, recorded when it starts and checked whenever
it continues, so that a resumed run (or a sweep's later seeds) never mixes two robots.

``run.json`` (and ``sweep.json``) keep::

    "inputs": {"config": {"path", "size", "sha256"},
               "files": [{"role", "path", "size", "sha256", "copy"}, ...]}

``files`` holds every file the experiment reads when it is built: the robot's URDF (also a
bundled or an example-robot-data one), every mesh it names, and every file another field of
the config names (a plant's URDF, a demonstration's CSV), each by its resolved absolute path,
size in [bytes] and SHA-256. A file the config names outside an installed package is also
copied into ``RUN_DIR/inputs/`` (``copy``), so the run keeps what it ran. The config file
itself is recorded but not checked: a run continues with its stored config (``run.json``'s
``raw``), and ``feltool run CONFIG --resume`` compares the config field by field.
"""

from __future__ import annotations

import hashlib
import re
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from feltool.bounds import MAX_URDF_BYTES
from feltool.errors import InputError
from feltool.files import make_dirs, writing
from feltool.robot.robot import data_dir
from feltool.robot.urdf import resolve_mesh

if TYPE_CHECKING:
    from feltool.experiment.experiment import Experiment

INPUTS_DIR = "inputs"
_MESH = re.compile(r"<mesh\b[^>]*?\bfilename\s*=\s*(\"[^\"]*\"|'[^']*')", re.S)


def digest(path: Path) -> tuple[int, str]:
    """``(size in bytes, SHA-256 hex)`` of a file's content."""
    h, size = hashlib.sha256(), 0
    with open(path, "rb") as fh:
        while chunk := fh.read(1 << 20):
            h.update(chunk)
            size += len(chunk)
    return size, h.hexdigest()


def _strings(value: Any, where: str = ""):
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _strings(v, f"{where}.{k}" if where else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _strings(v, f"{where}[{i}]")
    elif isinstance(value, str):
        yield where, value


def _named_file(text: str, base: Path) -> Path | None:
    """The file a config string names (a path with a suffix or a folder, relative to the
    config's folder), or None when it names no existing file."""
    if not text or "\n" in text or len(text) > 4096 or not (Path(text).suffix or "/" in text):
        return None
    path = Path(text).expanduser()
    path = path if path.is_absolute() else base / path
    try:
        return path.resolve() if path.is_file() else None
    except OSError:  # a name too long, a loop of links: not a file the config names
        return None


def _meshes(urdf: Path, package_dirs: list[str]) -> list[Path]:
    """The mesh files a URDF names that exist (its loader has already refused missing ones)."""
    try:
        text = urdf.read_text(errors="replace")
    except OSError:
        return []
    found = []
    for quoted in _MESH.findall(text):
        mesh = resolve_mesh(quoted[1:-1], urdf.parent, [str(urdf.parent), *package_dirs])
        if mesh is not None:
            found.append(mesh.resolve())
    return found


def input_files(exp: Experiment) -> dict[Path, str]:
    """Every file ``exp`` was built from, ``{absolute path: role}`` (see the module
    docstring)."""
    base = Path(exp.source).resolve().parent if exp.source else Path.cwd()
    files: dict[Path, str] = {}
    if exp.robot.urdf_path is not None:
        files[Path(exp.robot.urdf_path).resolve()] = "robot URDF"
    for where, text in _strings(exp.config.model_dump(mode="json")):
        path = _named_file(text, base)
        if path is not None:
            files.setdefault(path, "robot URDF" if where in ("robot", "robot.source")
                             else f"file of {where}")
    dirs = [str(d if Path(d).is_absolute() else base / d) for d in exp.config.package_dirs]
    dirs += list(exp.robot.package_dirs)
    for urdf in [p for p in files if p.suffix.lower() == ".urdf"]:
        for mesh in _meshes(urdf, dirs):
            files.setdefault(mesh, f"mesh of {urdf.name}")
    return files


def _in_a_package(path: Path) -> bool:
    """Whether ``path`` ships with an installed package (feltool's own robots,
    example-robot-data): those are found again by name and are not copied."""
    roots = [data_dir("robots").resolve(), Path(sys.prefix).resolve(),
             Path(sys.base_prefix).resolve()]
    return any(part in ("site-packages", "dist-packages") for part in path.parts) or \
        any(path.is_relative_to(r) for r in roots)


def record_inputs(exp: Experiment, run_dir: Path | None = None) -> dict[str, Any]:
    """The inputs of ``exp`` as ``run.json`` keeps them; with ``run_dir``, the files the
    config names outside a package are copied into ``run_dir/inputs/`` (at most
    :data:`~feltool.bounds.MAX_URDF_BYTES` each)."""
    return record_files(input_files(exp), exp.source, run_dir)


def record_files(files: dict[Path, str], config: Path | None,
                 run_dir: Path | None = None) -> dict[str, Any]:
    """The record of ``files`` (``{path: role}``, :func:`input_files`; a sweep's points'
    together) and of the ``config`` file; see :func:`record_inputs`."""
    record: dict[str, Any] = {"config": None, "files": []}
    if config is not None and Path(config).is_file():
        size, sha = digest(Path(config))
        record["config"] = {"path": str(Path(config).resolve()), "size": size, "sha256": sha}
    taken: set[str] = set()
    for path, role in files.items():
        size, sha = digest(path)
        entry = {"role": role, "path": str(path), "size": size, "sha256": sha, "copy": None}
        if run_dir is not None and not role.startswith("mesh") and size <= MAX_URDF_BYTES \
                and not _in_a_package(path):
            name, n = path.name, 1
            while name in taken:
                n += 1
                name = f"{path.stem}-{n}{path.suffix}"
            taken.add(name)
            target = make_dirs(Path(run_dir) / INPUTS_DIR) / name
            with writing(target):
                shutil.copyfile(path, target)
            entry["copy"] = f"{INPUTS_DIR}/{name}"
        record["files"].append(entry)
    return record


def fingerprints(record: dict[str, Any] | None) -> tuple[tuple[str, str, str], ...]:
    """``((role, path, sha256), ...)`` of a record, what a task carries to its worker."""
    return tuple((e["role"], e["path"], e["sha256"]) for e in (record or {}).get("files", []))


def changed(files: tuple[tuple[str, str, str], ...] | list[dict]) -> list[tuple[Any, str]]:
    """Each recorded input that is missing or differs now: ``(its entry, a phrase naming
    it)``."""
    out = []
    for item in files:
        role, path, sha = (item["role"], item["path"], item["sha256"]) \
            if isinstance(item, dict) else item
        try:
            _, now = digest(Path(path))
        except FileNotFoundError:
            out.append((item, f"the {role} {path} is missing"))
            continue
        except OSError as exc:
            out.append((item, f"the {role} {path} cannot be read ({exc.strerror})"))
            continue
        if now != sha:
            out.append((item, f"the {role} {path} changed since the run started (sha256 "
                               f"{sha[:12]} -> {now[:12]})"))
    return out


def check_inputs(record: dict[str, Any] | None, run_dir: Path | None, what: str) -> None:
    """Raise an :class:`InputError` (one line, naming the first file) when an input of the
    recorded run is missing or has changed; ``what`` starts the message (``--resume RUN``).
    A run recorded before inputs were kept passes."""
    files = (record or {}).get("files") or []
    problems = changed(files)
    if not problems:
        return
    first, phrase = problems[0]
    copy = f" (the run's copy: {Path(run_dir) / first['copy']})" \
        if run_dir is not None and first.get("copy") else ""
    more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
    raise InputError(f"{what}: {phrase}{more}; continuing would mix what the seeds ran "
                     f"with: restore it{copy}, or start a new run")


def verify(files: tuple[tuple[str, str, str], ...], what: str) -> None:
    """Raise an :class:`InputError` naming the first of ``files`` that differs now (a worker
    that has just built an experiment checks it was built from the run's inputs)."""
    problems = changed(files)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise InputError(f"{what}: {problems[0][1]}{more}; the run stopped rather than mix two "
                         "versions: finished seeds are kept; restore it and resume, or start a "
                         "new run")
