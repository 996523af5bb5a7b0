"""The control loop, written once for both engines: the array operations for numbers and CasADi
graphs (:mod:`.ops`), the learning cycle's pieces (:mod:`.cycle`: feedback, the plant's step,
allocation, the FEL sums), the feedback laws (:mod:`.feedback`, eq. 2.7 and §3.1) and the
arm's closed loop (:mod:`.closed_loop`).

Imports from feltool: ``robot``, ``dynamics`` and the root modules.
"""
