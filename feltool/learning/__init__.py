"""The learners: feedback error learning of the RMPs' parameters (:mod:`.fel`, eq. 3.4-3.6) and
its CasADi sensitivity (:mod:`.sensitivity`), classic FEL of an inverse-model correction
(:mod:`.model`) and iterative learning control (:mod:`.ilc`).

Imports from feltool: ``motion`` and what it imports; not ``plant`` or ``walking``.
"""
