"""Robots: loading them (bundled names, URDF files, ``example-robot-data:NAME``) and reading their
URDF (:mod:`.robot`, :mod:`.urdf`), the physical plausibility of masses and inertias
(:mod:`.physical`), a link frame's absolute angle (:mod:`.frames`) and what ``feltool inspect``
reports (:mod:`.inspection`).

Imports from feltool: ``dynamics`` and the root modules.
"""
