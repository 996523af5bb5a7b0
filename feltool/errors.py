"""Exceptions raised by feltool.

Every error a user can cause derives from :class:`FeltoolError`; the CLI turns those into one
clear message and exit code 2 (bad input) or 1 (a run that failed), never a traceback.
"""

from __future__ import annotations


class FeltoolError(Exception):
    """Root of all feltool errors."""

    exit_code = 1


class InputError(FeltoolError):
    """Bad user input (config, URDF, command-line argument): exit code 2."""

    exit_code = 2


class ConfigError(InputError):
    """An experiment config is invalid.

    Attributes:
        problems: One ``(yaml_path, message)`` pair per problem found.
        source: The config file the problems were found in, if any.
    """

    def __init__(self, problems: list[tuple[str, str]], source: str | None = None):
        self.problems = list(problems)
        self.source = source
        super().__init__(self.format())

    def format(self) -> str:
        prefix = f"{self.source}: " if self.source else ""
        return "\n".join(f"{prefix}{path or '<top level>'}: {msg}" for path, msg in self.problems)


class RobotError(InputError):
    """A robot could not be loaded (missing file, broken URDF, unknown name, bad element)."""


class SimulationDiverged(FeltoolError):
    """The closed loop left the region where its results mean anything (non-finite state,
    a fall, a runaway velocity)."""
