"""The compiled engine: the learning cycle of an arm (:mod:`.graph`), of the pinned walker
(:mod:`.pinned`) and of the physical walker (:mod:`.physical`, :mod:`.physical_step`) as CasADi
graphs, generated to C and cached (:mod:`.library`), what it runs (:mod:`.support`) and the
engine that drives them (:mod:`.engine`).

Imports from feltool: the rest of ``engines`` (the Python engine reruns a stopped cycle) and
what it imports.
"""
