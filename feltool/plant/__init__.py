"""The plant, the simulated robot where it is not the known model: the rigid model changed by a
``plant:`` block (:mod:`.rigid`: payloads, per-link overrides, joint friction), world events
(:mod:`.events`) and disturbances (:mod:`.disturbances`).

Imports from feltool: ``motion`` and what it imports; not ``learning`` or ``walking``.
"""
