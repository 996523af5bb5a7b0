"""An experiment ready to run: read, assembled (:mod:`feltool.experiment.assemble`) and given
the engine that runs its cycles (:func:`feltool.engines.select.choose_engine`).

Building is separate from running: :func:`load_experiment` returns an
:class:`~feltool.experiment.experiment.Experiment` whose robot, primitives, feedback laws and
learner can be inspected before anything is simulated; :func:`feltool.runs.seed.run_seed` runs
one seed's learning cycles.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from feltool.config.files import apply_overrides, read_yaml
from feltool.engines.select import choose_engine
from feltool.errors import ConfigError, InputError
from feltool.experiment.assemble import assemble_experiment
from feltool.experiment.experiment import Experiment
from feltool.robot.robot import data_dir


def resolve_config_path(spec: str | Path) -> Path:
    """A config path, or the name of a bundled config (``two_link_standard``)."""
    path = Path(spec)
    if path.is_file():
        return path
    bundled = data_dir("configs") / (path.name if path.suffix else f"{path.name}.yaml")
    if not path.exists() and bundled.is_file() and len(path.parts) <= 2:
        return bundled
    raise ConfigError([("", "config file not found")], str(spec))


def build_experiment(raw: dict[str, Any], source: Path | None = None,
                     check_targets: bool = True) -> Experiment:
    """Build an :class:`Experiment` from a raw config mapping and choose its engine (raises
    :class:`ConfigError` listing problems; see
    :func:`~feltool.experiment.assemble.assemble_experiment` for ``check_targets``); a
    ``raw`` that is not a mapping, or a ``source`` that is not a path, is a ConfigError too."""
    where = str(source) if isinstance(source, (str, Path)) else None
    if not isinstance(raw, dict):
        raise ConfigError([("", f"a config must be a mapping of its fields (a dict, as YAML "
                                f"reads one), got {type(raw).__name__}")], where)
    if source is not None and not isinstance(source, (str, Path)):
        raise ConfigError([("", f"source: must be the config file's path or None, got "
                                f"{type(source).__name__}")])
    exp = choose_engine(assemble_experiment(raw, Path(source) if source is not None else None,
                                            check_targets))
    exp.raw = raw
    return exp


def load_experiment(path: str | Path, overrides: list[str] | None = None) -> Experiment:
    """Read, validate and build an experiment (raises :class:`ConfigError` listing problems;
    ``overrides`` as ``--set``: a list of ``"a.b.c=VALUE"`` strings)."""
    if not isinstance(path, (str, Path)):
        raise InputError(f"path: must be a config file's path or a bundled config's name, got "
                         f"{type(path).__name__}")
    if isinstance(overrides, str) or not all(isinstance(o, str) for o in overrides or []):
        raise InputError("overrides: must be a list of 'a.b.c=VALUE' strings, as --set takes "
                         f"them, got {overrides!r}"[:300])
    path = resolve_config_path(path)
    raw = apply_overrides(read_yaml(path), list(overrides or []))
    return build_experiment(raw, source=path)
