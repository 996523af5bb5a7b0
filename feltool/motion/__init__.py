"""The desired motion: periodic functions as Fourier series (:mod:`.spectral`), the phase the RMPs
share (:mod:`.phase`, eq. 2.1), the rhythmic movement primitives (:mod:`.rmp`, eq. 2.1-2.4) and a
seed's motion while it runs: its phase, motion events and transients (:mod:`.motion`).

Imports from feltool: ``control``, ``config`` and what they import.
"""
