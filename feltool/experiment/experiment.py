"""The :class:`Experiment`: every part of one experiment built from its config, to inspect
before anything runs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from feltool.config.experiment import ExperimentConfig
from feltool.control.closed_loop import ClosedLoop
from feltool.control.feedback import FeedbackLaw
from feltool.dynamics.interface import Dynamics
from feltool.learning.fel import FeedbackErrorLearner
from feltool.learning.model import ModelLearner
from feltool.motion.motion import varying_phase
from feltool.motion.rmp import PrimitiveSet, RhythmicPrimitive, fit_trajectory
from feltool.robot.robot import Robot
from feltool.walking.pinned import HybridLoop


@dataclass
class Experiment:
    """Everything one experiment needs, built from its config; inspect before running.

    Attributes:
        config: The validated config.
        robot: The robot with locked joints removed (the known model).
        dynamics: Known inverse/forward models of ``robot``.
        joints: Joint names in velocity-index order.
        primitives: The forward trajectory generator (one RMP per joint).
        theta_demo: Parameters of every joint's RMP before random initialisation ``(P,)``.
        law: Feedback laws.
        loop: Closed-loop simulator.
        learner: The FEL learner.
        init: Per learned joint: ``(slice, weight std, goal centre, goal spread, kind)``.
        hybrid: The step-by-step loop for walkers and allocated motors (else None).
        plant: The simulated robot's dynamics (``loop.dynamics``); ``dynamics`` itself unless
            the config has a ``plant:`` block.
        model_learner: Classic FEL of an inverse-model correction (``learning.model``), or None.
        demo_fit_rms: Per joint fitted to a demonstration: RMS over the cycle of its RMP's
            limit cycle minus the demonstration, in [rad] (the fit error of eq. 2.4).
        engine: The engine that runs the learning cycles: ``compiled`` (the cycle as generated
            C, :mod:`feltool.engines.compiled`) or ``python`` (Pinocchio calls per step), as
            chosen by :func:`feltool.engines.select.choose_engine`.
        engine_reason: Why :attr:`engine` runs this experiment, in words (``backend: auto``:
            what the compiled engine lacks, or that it runs everything).
        compiled: The compiled engine once built
            (:func:`feltool.engines.compiled.engine.compiled_engine`), else None.
    """

    config: ExperimentConfig
    robot: Robot
    dynamics: Dynamics
    joints: list[str]
    primitives: PrimitiveSet
    theta_demo: np.ndarray
    law: FeedbackLaw
    loop: ClosedLoop
    learner: FeedbackErrorLearner
    init: list[tuple[slice, float, float, float, str]] = field(default_factory=list)
    source: Path | None = None
    hybrid: HybridLoop | None = None
    plant: Dynamics | None = None
    model_learner: ModelLearner | None = None
    demo_fit_rms: dict[str, float] = field(default_factory=dict)
    #: init random with ``learn.init_basis`` other than the joint's basis: the RMP (by the
    #: slice's start) the weights are drawn on, whose forward trajectory is fitted into the basis
    init_reference: dict[int, RhythmicPrimitive] = field(default_factory=dict)
    engine: str = "python"
    engine_reason: str = "not chosen yet (feltool.engines.select.choose_engine)"
    compiled: Any = field(default=None, repr=False, compare=False)
    #: the raw config mapping it was built from (``--set`` applied; learning.redesign builds
    #: the experiment of a new design from it), or None
    raw: dict | None = field(default=None, repr=False, compare=False)

    @property
    def phase_varies(self) -> bool:
        """Whether cycles differ in length (a period of no whole number of steps, period
        events, an adaptive phase): metrics.csv then has cycle_s and frequency_hz."""
        if getattr(self, "_phase_varies", None) is None:
            self._phase_varies = any(not where.endswith((".amplitude", ".goal"))
                                     for where, _ in varying_phase(self.config))
        return self._phase_varies

    @property
    def learned_joints(self) -> list[str]:
        return [name for name, jc in self.config.joints.items() if jc.learn is not None]

    @property
    def stabilized_joints(self) -> list[str]:
        return [n for n in self.joints if self.config.joints[n].role == "stabilize"]

    @property
    def error_joints(self) -> list[str]:
        return [n for n, m in zip(self.joints, self.learner.error_mask) if m > 0]

    def initial_parameters(self, seed: int) -> np.ndarray:
        """RMP parameters at the start of learning; random draws come from ``seed`` only."""
        rng = np.random.default_rng(seed)
        theta = self.theta_demo.copy()
        for sl, w_std, g_center, g_spread, kind in self.init:
            nw = sl.stop - sl.start - 1
            ref = self.init_reference.get(sl.start)
            if kind == "random" and ref is not None:
                # the same draw on the reference basis, its forward trajectory fitted into ours
                w = rng.normal(0.0, w_std, ref.n_basis)
                g = g_center + rng.uniform(-g_spread, g_spread)
                theta[sl] = fit_trajectory(ref, self._primitive(sl), np.append(w, g))
            elif kind == "random":
                theta[sl.start:sl.stop - 1] = rng.normal(0.0, w_std, nw)
                theta[sl.stop - 1] = g_center + rng.uniform(-g_spread, g_spread)
            elif kind == "zero":
                theta[sl] = 0.0
                theta[sl.stop - 1] = g_center
            elif kind == "perturbed":
                # the demo's fit plus the fit of a smooth random motion: the first three
                # harmonics of the cycle with N(0, 1) coefficients, scaled to w_std [rad] RMS
                # (a sample demo's fitted weights are huge: a scale relative to them means
                # nothing in radians, and random weights would be a rough, violent motion)
                prim = self._primitive(sl)
                n = prim.n_steps
                phi = 2.0 * np.pi * np.arange(n) / n
                c = rng.normal(0.0, 1.0, (3, 2))
                h = np.arange(1, 4)[:, None]
                d = c[:, :1] * np.cos(h * phi) + c[:, 1:] * np.sin(h * phi)
                dd = h * (-c[:, :1] * np.sin(h * phi) + c[:, 1:] * np.cos(h * phi))
                ddd = -h**2 * (c[:, :1] * np.cos(h * phi) + c[:, 1:] * np.sin(h * phi))
                w = 2.0 * np.pi / (n * self.config.dt)  # d phi / dt [rad/s]
                scale = w_std / float(np.sqrt(np.mean(d.sum(0) ** 2)))
                dtheta = prim.fit(scale * d.sum(0), scale * w * dd.sum(0),
                                  scale * w**2 * ddd.sum(0), phi, goal=0.0)
                theta[sl] += dtheta
                theta[sl.stop - 1] += rng.uniform(-g_spread, g_spread)
        return theta

    def _primitive(self, sl: slice) -> RhythmicPrimitive:
        return next(self.primitives.primitives[i] for i, s in self.primitives.slices.items()
                    if s == sl)

    def split_parameters(self, theta: np.ndarray) -> dict[str, np.ndarray]:
        """``{"<joint>.weights": w, "<joint>.goal": g}`` for the learned joints."""
        out = {}
        for name in self.learned_joints:
            sl = self.primitives.slices[self.joints.index(name)]
            out[f"{name}.weights"] = theta[sl.start:sl.stop - 1].copy()
            out[f"{name}.goal"] = np.array(theta[sl.stop - 1])
        return out
