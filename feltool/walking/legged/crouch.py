"""A reference posture for a legged robot whose own has straight legs (a URDF's zeros, as most
are published): each leg bent until its foot is :data:`CROUCH` of the leg's reach higher
under the base, knees back.

Per leg (the joints between the base and the foot), Gauss-Newton on the leg's joints puts the
foot at its straight posture's horizontal place, ``CROUCH`` times its reach (the distance from
the leg's second joint to the foot) higher, from four starts (the leg's last joint bent either
way, the one before it the other way or the same): of the solutions within the joints' limits
whose leg can move its foot in every direction, the one with the leg's last joint furthest
behind the line from its first joint to the foot (knees back, as Unitree's and most
quadrupeds' stand). None: the legs are left as they are (and refused, naming
``walking.posture``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from feltool.walking.legged.tree_feet import leg_joints

#: How much higher the feet are put than in the straight posture, as a fraction of each leg's
#: reach from its second joint [-]
CROUCH = 0.3


#: A leg whose foot's Jacobian (on the leg's joints) has its smallest singular value below
#: this fraction of its largest is singular: straight, or folded onto itself
SINGULAR_LEG = 1e-6


def singular_leg(J: np.ndarray) -> bool:
    """Whether a foot's Jacobian ``(3, joints of its leg)`` cannot move it in every direction
    (:data:`SINGULAR_LEG`)."""
    s = np.linalg.svd(J, compute_uv=False)
    return bool(s[-1] < SINGULAR_LEG * s[0])


def crouched(model: pin.Model, q: np.ndarray, feet: dict[str, int]) -> np.ndarray | None:
    """``q`` ``(nq,)`` with every leg of ``feet`` (name -> frame id) bent as the module says,
    or None when a leg has no such posture."""
    data = model.createData()
    out = np.array(q, float)
    pin.framesForwardKinematics(model, data, out)
    base = data.oMi[1]
    for frame in feet.values():
        joints = leg_joints(model, model.frames[frame].parentJoint)
        if len(joints) < 3 or any(model.joints[j].nq != 1 for j in joints):
            return None
        iq = [model.joints[j].idx_q for j in joints]
        iv = [model.joints[j].idx_v for j in joints]
        lo, hi = model.lowerPositionLimit[iq], model.upperPositionLimit[iq]
        pin.framesForwardKinematics(model, data, out)
        foot = data.oMf[frame].translation.copy()
        reach = np.linalg.norm(foot - data.oMi[joints[1]].translation)
        target = foot + base.rotation @ np.array([0.0, 0.0, CROUCH * reach])
        best, behind = None, -np.inf
        for last, before in ((1.0, -0.5), (-1.0, 0.5), (1.0, 0.5), (-1.0, -0.5)):
            x = out.copy()
            x[iq[-1]] = last
            x[iq[-2]] = before
            x[iq] = np.clip(x[iq], lo, hi)
            for _ in range(50):
                pin.framesForwardKinematics(model, data, x)
                err = data.oMf[frame].translation - target
                if np.abs(err).max() < 1e-10:
                    break
                pin.computeJointJacobians(model, data, x)
                J = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, iv]
                dv = np.zeros(model.nv)
                dv[iv] = -np.linalg.lstsq(J, err, rcond=None)[0]
                x = pin.integrate(model, x, dv)
            pin.computeJointJacobians(model, data, x)
            pin.updateFramePlacements(model, data)
            J = pin.getFrameJacobian(model, data, frame, pin.LOCAL_WORLD_ALIGNED)[:3, iv]
            if np.abs(data.oMf[frame].translation - target).max() > 1e-8 or \
                    np.any(x[iq] < lo - 1e-9) or np.any(x[iq] > hi + 1e-9) or singular_leg(J):
                continue
            hip, knee = data.oMi[joints[0]].translation, data.oMi[joints[-1]].translation
            line = target - hip
            off = knee - hip - line * (line @ (knee - hip)) / (line @ line)
            back = -float(base.rotation[:, 0] @ off)  # behind the hip-foot line [m]
            if back > behind + 1e-9:
                best, behind = x, back
        if best is None:
            return None
        wrapped = np.arctan2(np.sin(best[iq]), np.cos(best[iq]))  # a turn's multiples off
        out[iq] = np.where((wrapped >= lo) & (wrapped <= hi), wrapped, best[iq])
    return out
