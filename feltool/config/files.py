"""Config files: read (bounded YAML, duplicate keys refused), overridden (``--set``), parsed into
the schema with every problem named by its YAML path, and written back resolved.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml
from pydantic import (
    ValidationError,
)

from feltool.bounds import (
    MAX_CONFIG_BYTES,
)
from feltool.config.experiment import ExperimentConfig
from feltool.config.safe_yaml import YamlBoundError, load_yaml
from feltool.errors import ConfigError
from feltool.files import dump_yaml

#: libyaml's composer when PyYAML has it (the same nodes and marks as PyYAML's, ~10x faster).
_COMPOSER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def read_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping safely (no object construction), with errors that name the file."""
    try:
        size = Path(path).stat().st_size
        if size > MAX_CONFIG_BYTES:
            raise ConfigError([("", f"the file has {size} bytes; a config may have at most "
                                    f"{MAX_CONFIG_BYTES} (1 MiB)")], str(path))
        text = Path(path).read_text()
    except FileNotFoundError:
        raise ConfigError([("", "config file not found")], str(path)) from None
    except UnicodeDecodeError:
        raise ConfigError([("", "the file is binary (not UTF-8 text), not a YAML config")],
                          str(path)) from None
    except OSError as exc:
        raise ConfigError([("", f"cannot read config: {exc}")], str(path)) from None
    if "\x00" in text:
        raise ConfigError([("", "the file is binary (not UTF-8 text), not a YAML config")],
                          str(path))
    try:
        data = load_yaml(text)  # safe: no object construction, bounded depth and aliases
        duplicates = _duplicate_keys(yaml.compose(text, Loader=_COMPOSER))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError([("", f"{where}not valid YAML ({problem})")], str(path)) from None
    except YamlBoundError as exc:
        raise ConfigError([("", f"refused: {exc}")], str(path)) from None
    if not isinstance(data, dict):
        raise ConfigError([("", "the config must be a YAML mapping of fields")], str(path))
    if duplicates:
        raise ConfigError(duplicates, str(path))
    return data


def _duplicate_keys(node, path: str = "") -> list[tuple[str, str]]:
    """Keys given twice in a mapping (plain PyYAML keeps the last one silently, so two roles
    for one joint would go unnoticed), with their YAML paths."""
    problems = []
    if isinstance(node, yaml.MappingNode):
        seen = set()
        for key_node, value_node in node.value:
            key = key_node.value
            where = f"{path}.{key}" if path else str(key)
            if key in seen:
                problems.append((where, f"given twice (line {key_node.start_mark.line + 1}); "
                                        "each key may appear once"))
            seen.add(key)
            problems += _duplicate_keys(value_node, where)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            problems += _duplicate_keys(item, f"{path}.{i}")
    return problems


def apply_overrides(data: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``a.b.c=VALUE`` overrides (VALUE parsed as YAML) to a raw config mapping."""
    for item in overrides:
        if "=" not in item:
            raise ConfigError([(item, "an override must look like a.b.c=VALUE")], "--set")
        key, raw = item.split("=", 1)
        parts = [p for p in key.strip().split(".") if p]
        if not parts:
            raise ConfigError([(item, "an override needs a field path before '='")], "--set")
        try:
            value = load_yaml(raw)
        except yaml.YAMLError:
            value = raw
        except YamlBoundError as exc:
            raise ConfigError([(key.strip(), f"refused: {exc}")], "--set") from None
        node = data
        for i, part in enumerate(parts[:-1]):
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError([(".".join(parts[: i + 1]),
                                    "cannot set a field inside a value that is not a mapping")],
                                  "--set")
            node = child
        node[parts[-1]] = value
    return data


# Pydantic puts the branch of a union (``int``, ``list[int]``, ``literal['a','b']``,
# ``function-after[...]``) into an error's location; those are not YAML keys.
_BRANCH = re.compile(r"^(int|float|str|bool|none|(list|dict|literal|tuple|function-\w+)\[.*\]"
                     r"|constrained-.*|[A-Z]\w*Config)$")


def _loc(loc: tuple) -> str:
    return ".".join(str(p) for p in loc if not (isinstance(p, str) and _BRANCH.match(p)))


_SCALAR_TYPES = {"int_type", "int_parsing", "float_type", "float_parsing", "string_type"}


def _pydantic_problems(exc: ValidationError) -> list[tuple[str, str]]:
    problems = []
    for err in exc.errors():
        loc = err["loc"]
        # a demo's kind is a tag of its (discriminated) union, not a YAML key: drop it
        loc = tuple(x for i, x in enumerate(loc)
                    if not (i and loc[i - 1] == "demo" and x in ("sine", "samples", "positions")))
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "unknown field (check the spelling; see docs/configuration.md)"
        elif err["type"] == "missing":
            msg = "required field is missing"
        elif err["type"] in ("less_than_equal", "too_long") and \
                not isinstance(err.get("input"), dict):
            # feltool's upper bounds (feltool/bounds.py), stated with the value given
            bound = err.get("ctx", {})
            limit = bound.get("le", bound.get("max_length"))
            what = {"less_than_equal": "above", "too_long": "longer than"}[err["type"]]
            given = f"{len(err['input'])} items" if err["type"] == "too_long" else \
                str(err["input"])
            limit = f"{limit:g}" if isinstance(limit, float) else limit
            msg = f"{given} is {what} the limit {limit} (see docs/configuration.md)"
        problems.append((_loc(loc), msg))
    # A union (e.g. seeds: int | list) reports one error per branch: a list given where the
    # other branch wants a number is no news when the list branch says what is wrong.
    paths = [p for p, _ in problems]
    problems = [(p, m) for (p, m), err in zip(problems, exc.errors())
                if not (err["type"] in _SCALAR_TYPES and isinstance(err.get("input"), list | dict)
                        and any(q != p and q.startswith(p + ".") for q in paths))]
    seen, unique = set(), []
    for p in problems:
        if p[0] not in seen:
            seen.add(p[0])
            unique.append(p)
    return unique


def parse_config(data: dict[str, Any], source: str | None = None) -> ExperimentConfig:
    """Validate a raw mapping; raises :class:`ConfigError` listing every problem (a
    ``walking.base`` that picks no schema alone: the rest would be judged by the wrong one)."""
    walking = data.get("walking") if isinstance(data, dict) else None
    base = walking.get("base", "planar") if isinstance(walking, dict) else "planar"
    if base != "planar" and not isinstance(base, list):
        raise ConfigError([("walking.base", f"{base!r} is neither planar (a sagittal walker on "
                            "base_x, base_z, base_pitch), a list of the URDF's own three base "
                            "joints, nor free_flyer (a 3D legged robot, its own schema)")],
                          source)
    try:
        cfg = ExperimentConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_pydantic_problems(exc), source) from None
    problems = cfg.problems()
    if problems:
        raise ConfigError(problems, source)
    return cfg


def config_to_yaml(cfg: ExperimentConfig, base_dir: Path | None = None) -> str:
    """The fully resolved config (defaults filled in) as YAML. With ``base_dir`` (the original
    config's directory), relative file paths (a URDF, package dirs) become absolute, so that the
    saved config works from anywhere (``feltool run RUN_DIR/config.yaml``, ``feltool view``)."""
    data = cfg.model_dump(mode="json")
    if base_dir is not None:
        robot = cfg.robot_source
        if (robot.endswith(".urdf") or "/" in robot) and not Path(robot).expanduser().is_absolute():
            robot = str((Path(base_dir) / robot).resolve())
            if isinstance(data["robot"], dict):
                data["robot"]["source"] = robot
            else:
                data["robot"] = robot
        data["package_dirs"] = [str((Path(base_dir) / d).resolve()) for d in data["package_dirs"]]
        for jc in data["joints"].values():
            demo = jc.get("demo") or {}
            if demo.get("csv") and not Path(demo["csv"]).expanduser().is_absolute():
                demo["csv"] = str((Path(base_dir) / demo["csv"]).resolve())
        plant = data.get("plant")
        if isinstance(plant, dict) and isinstance(plant.get("robot"), str) and \
                plant["robot"].endswith(".urdf") and not Path(plant["robot"]).is_absolute():
            plant["robot"] = str((Path(base_dir) / plant["robot"]).resolve())
    return dump_yaml(data, sort_keys=False)
