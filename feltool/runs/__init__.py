"""Runs: an experiment ready to run (:mod:`.experiments`: ``load_experiment``), one seed's
learning cycles (:mod:`.seed`: ``run_seed``) and what watches them (:mod:`.observers`,
:mod:`.divergence`, :mod:`.checkpoint`), many seeds in parallel into a run directory
(:mod:`.runner`, :mod:`.executors`, :mod:`.rundir`, :mod:`.runstate`), sweeps
(:mod:`.sweep`), robustness scores (:mod:`.robustness`), figures (:mod:`.plots`) and clocks
(:mod:`.timing`).

Imports from feltool: ``gait`` (a walker's Poincaré analysis after a run) and what it imports.
"""
