"""``python -m feltool.cli``: the ``feltool`` command."""

from feltool.cli.main import console

console()
