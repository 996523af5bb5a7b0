"""Changes of the world during a run (adaptation experiments).

A world event changes only the simulated plant; the known model that computes the feedforward (and
the allocation) stays as it was, so the feedback rises at the event and FEL has to bring it back
down. Events apply to any robot: a ground slope (gravity rotated about the world's y axis; for a
walker whose stance foot is pinned this is the slope under the foot), a payload (a point mass at a
frame), or a link's new mass (or every body's mass scaled). Events that change the motion
(period, amplitude, goal) are applied by :mod:`feltool.motion.motion`. The events change the
experiment's plant (a ``plant:`` block's, else the known model): :func:`world_plant`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.config.events import EventConfig
from feltool.dynamics.interface import Dynamics, make_dynamics
from feltool.errors import ConfigError


def check_events(model: pin.Model, events: list[EventConfig], source: str | None = None) -> None:
    """Every frame and link an event names exists in the (reduced) model (the joints a motion
    event names are checked with the primitives, :mod:`feltool.motion.motion`)."""
    problems = []
    for i, ev in enumerate(events):
        for key in ("frame", "link"):
            name = getattr(ev, key)
            if name is not None and not model.existFrame(name):
                problems.append((f"events.{i}.{key}", f"the robot has no frame/link '{name}'"))
    if problems:
        raise ConfigError(problems, source)


def changed_model(model: pin.Model, events: list[EventConfig]) -> pin.Model:
    """A copy of ``model`` with ``events`` applied, in order."""
    plant = pin.Model(model)
    for ev in events:
        if not ev.changes_world:
            continue
        if ev.kind == "slope":
            c, s = np.cos(ev.angle), np.sin(ev.angle)
            # Rotation about y by -angle: gravity (0, 0, -g) tilts towards +x (downhill ahead).
            Ry = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]).T
            plant.gravity = pin.Motion(Ry @ plant.gravity.linear, np.zeros(3))
        elif ev.kind == "payload":
            frame = plant.frames[plant.getFrameId(ev.frame)]
            at = np.zeros(3) if ev.com is None else np.array(ev.com, dtype=float)
            point = pin.Inertia(ev.mass, at, np.zeros((3, 3)))
            plant.inertias[frame.parentJoint] = (plant.inertias[frame.parentJoint]
                                                 + frame.placement.act(point))
        elif ev.kind == "mass" and ev.link is None:  # every body scaled
            for j in range(1, plant.njoints):
                own = plant.inertias[j]
                plant.inertias[j] = pin.Inertia(own.mass * ev.scale, own.lever,
                                                own.inertia * ev.scale)
        elif ev.kind == "mass":
            frame = plant.frames[plant.getFrameId(ev.link)]
            own, at = frame.inertia, frame.placement
            if own.mass <= 0.0:  # a joint's own body: Pinocchio keeps it in the joint inertia
                own, at = plant.inertias[frame.parentJoint], pin.SE3.Identity()
            if own.mass <= 0.0:
                raise ConfigError([("events", f"link '{ev.link}' has no mass to change")])
            scale = (ev.scale if ev.scale is not None else ev.mass / own.mass) - 1.0
            delta = pin.Inertia(own.mass * scale, own.lever, own.inertia * scale)
            plant.inertias[frame.parentJoint] = plant.inertias[frame.parentJoint] + at.act(delta)
    return plant


def world_plant(base: Dynamics, events: list[EventConfig], backend: str = "pinocchio"
                ) -> Dynamics:
    """``base`` (the experiment's plant: the known model or a ``plant:`` block's) with the world
    ``events`` applied to its rigid model; its joint friction and motor gains are kept."""
    rigid = getattr(base, "rigid", base)
    changed = make_dynamics(changed_model(rigid.model, events), backend)
    return changed if rigid is base else base.with_rigid(changed)


def plant_for_cycle(base: Dynamics, events: list[EventConfig], cycle: int,
                    backend: str = "pinocchio") -> Dynamics | None:
    """The plant to simulate from ``cycle`` on if an event changes the world at ``cycle``, else
    None; ``base`` is the experiment's plant before any event."""
    if not any(ev.cycle == cycle and ev.changes_world for ev in events):
        return None
    return world_plant(base, [ev for ev in events if ev.cycle <= cycle], backend)


__all__ = ["changed_model", "check_events", "plant_for_cycle", "world_plant"]
