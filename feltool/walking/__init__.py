"""Walkers: a planar walker's model and relabelling (:mod:`.model`), its point contacts and rigid
impacts (:mod:`.contact`), the physical walker's closed loop (:mod:`.physical`) and what makes
each step physical (:mod:`.checks`), the thesis's pinned walker (:mod:`.pinned`), and both
built from their config (:mod:`.build`); 3D legged robots on a free flyer (:mod:`.legged`).

Imports from feltool: ``motion`` and what it imports; not ``plant`` or ``learning``.
"""
