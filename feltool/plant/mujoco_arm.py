"""A fixed-base robot (an arm) whose plant is MuJoCo (``plant: {simulator: mujoco}``).

The closed loop is feltool's (:class:`~feltool.control.closed_loop.ClosedLoop`: feedback from
the measured state, the feedforward given); each control step's torque is held over
``sim.substeps`` MuJoCo steps of the URDF compiled by :func:`feltool.robot.mujoco.compile_mujoco`
(semi-implicit Euler, the URDF's ``<dynamics>`` damping and friction included).
"""

from __future__ import annotations

import numpy as np

from feltool.control.closed_loop import ClosedLoop, CycleLog
from feltool.robot.mujoco import MujocoPlant


class MujocoArmLoop(ClosedLoop):
    """:class:`ClosedLoop` whose plant steps are MuJoCo's.

    Args:
        loop: The loop the known model's plant would run (law, selection, rates, limits).
        sim: The robot's URDF compiled by MuJoCo, stepping by ``loop.dt / loop.substeps``.
    """

    def __init__(self, loop: ClosedLoop, sim: MujocoPlant):
        super().__init__(loop.dynamics, loop.law, loop.actuated, loop.dt, loop.substeps,
                         loop.integrator, loop.error_rows, loop.limits)
        self.sim = sim

    def advance(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """State after one control step of MuJoCo under the joint torques ``tau`` [N m]."""
        self.sim.set_state(q, v)
        self.sim.step(tau, self.substeps)
        return self.sim.state()

    def run_cycle(self, q: np.ndarray, v: np.ndarray, R: np.ndarray, Rd: np.ndarray,
                  u_ff: np.ndarray) -> CycleLog:
        """Run n steps with references ``R, Rd`` and feedforward ``u_ff`` (each ``(n, nv)``)."""
        return self._run_cycle_general(q, v, R, Rd, u_ff)
