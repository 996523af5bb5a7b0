"""The experiment: every part built from its config and inspectable before anything runs
(:mod:`.experiment`), its assembly (:mod:`.assemble`), the physical checks of a built
experiment (:mod:`.checks`) and demonstrations as trajectories (:mod:`.demos`).

Imports from feltool: ``plant``, ``learning``, ``walking`` and what they import.
"""
