"""The engines that run one learning cycle of an experiment and return its
:class:`~.outcome.CycleOutcome`: the Python engine (:mod:`.python`, Pinocchio calls per step),
the compiled engine (:mod:`.compiled`: the cycle as one CasADi graph generated to C), the
runners of ILC and the baseline (:mod:`.ilc`, :mod:`.ilc_walker`), disturbed loops
(:mod:`.disturbed`), and which engine runs an experiment (:mod:`.select`).

Imports from feltool: ``experiment`` and what it imports.
"""
