"""The ``feltool`` command: its parser and entry point (:mod:`.main`), one module per subcommand
(:mod:`.run`, :mod:`.sweep`, :mod:`.view`, :mod:`.check`, :mod:`.robots`, :mod:`.gait`,
:mod:`.plot`, :mod:`.robustness`) and what they share (:mod:`.common`).

Imports from feltool: anything.
"""
