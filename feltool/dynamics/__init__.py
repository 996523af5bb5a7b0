"""The known models of a robot behind one small interface (:mod:`.interface`): the inverse
model (RNEA, eq. 3.1), the forward model (ABA) and their derivatives, by Pinocchio
(:mod:`.pinocchio`) or as CasADi expressions built from the Pinocchio model's numbers
(:mod:`.spatial`, :mod:`.symbolic`, :mod:`.casadi_backend`).

Imports from feltool: the root modules only (errors, bounds).
"""
