"""A walker's gait: designed by direct collocation (:mod:`.design`) from an initial guess
(:mod:`.guess`), read from and written as a config (:mod:`.config`), verified in feltool's
walker and closed on its orbit (:mod:`.orbit`), and analysed by its Poincaré map
(:mod:`.poincare`).

Imports from feltool: ``engines`` (the Poincaré map runs the compiled cycle) and what it imports.
"""
