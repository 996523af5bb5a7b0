"""The experiment config: the pydantic schema split by YAML section (:mod:`.sim`, :mod:`.joints`,
:mod:`.learning`, :mod:`.walking`, ...; the whole in :mod:`.experiment`), config files read with
bounds, overridden and parsed with every problem named by its YAML path (:mod:`.files`,
:mod:`.safe_yaml`), the memory a run needs (:mod:`.memory`) and the generated reference
(:mod:`.docgen`).

Imports from feltool: ``robot`` (plausibility of plant inertias) and what it imports.
"""
