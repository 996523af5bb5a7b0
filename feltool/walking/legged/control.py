r"""Standing and balancing a legged robot: the wanted generalized force and its allocation to the
motors under the stance contacts.

**Wanted force.** :math:`\tau_w = \mathrm{RNEA}(q_d, \dot q_d, \ddot q_d) + u_{fb}` (eq. 3.1 plus
feedback), with the feedback on the base's *stabilized* quantities -- height, roll, pitch and yaw
rate -- as a wrench :math:`w` at the base's origin in the world's axes, mapped to generalized
forces by the base joint's Jacobian (:math:`J_b^\top w`, world-aligned), and PD tracking on the
motor joints:

.. math::

    w = \bigl(0,\ 0,\ k_h (z_d - z) - d_h \dot z,\ \ k_t e_x - d_t \omega_x,\
        k_t e_y - d_t \omega_y,\ -d_y \omega_z\bigr), \quad e = \log(R_d R^\top),

:math:`u_{fb,j} = k_p (q_{d,j} - q_j) + k_d (\dot q_{d,j} - \dot q_j)` on the motors.

**Allocation: a QP.** The planar walker's allocation -- the motor torques whose constrained
accelerations are closest to those :math:`\tau_w` would give with the feet held, in the
kinetic-energy metric,
:math:`\min_u (Bu - \tau_w)^\top W (Bu - \tau_w)`,
:math:`W = M^{-1} - M^{-1}J^\top(JM^{-1}J^\top)^{-1}JM^{-1}` -- has the unique solution
:math:`(B^\top W B)^{-1}B^\top W\tau_w` only when :math:`B^\top W B` is invertible. With several
feet it is not: on four feet Solo-12's 12 motors move only the 6 degrees of freedom the contacts
leave (``rank`` :math:`B^\top W B = 6`); the other 6 directions of :math:`u` squeeze the feet
against each other, changing the contact forces and nothing else. Choosing them is what keeps
each foot pushing and inside its friction cone: an inequality problem, solved as a QP
(``qpsolvers`` with :data:`QP_SOLVER`) in two stages. The contact forces are affine in :math:`u`,
:math:`\lambda(u) = \Lambda(JM^{-1}(b - Bu) - \gamma)`, :math:`\Lambda = (JM^{-1}J^\top)^{-1}`
(the KKT solution of the stance dynamics on Pinocchio's :math:`M, b, J, \gamma`), and are kept
in an inner friction pyramid :math:`|f_{x}|, |f_{y}| \le \mu' f_z/\sqrt 2`,
:math:`\mu' = ` ``margin`` :math:`\mu`, above a normal-force floor; the torques within their
limits.

1. *Exact*: every minimiser of the cost, :math:`u = u_0 + N z` (:math:`u_0` the least-norm one,
   :math:`N` the null space of :math:`B^\top W B`), gives the wanted constrained accelerations;
   the smallest :math:`\|u\|` of them inside the cones and limits (a QP in :math:`z`).
2. *Least squares*, when no exact one keeps the cones (the wanted force would make a foot slip
   or pull): the cost plus :math:`\varepsilon\|u\|^2` under the same constraints.

Several points of one link (a sole's corners) take forces :math:`\lambda(u) + Y y`: the
least-norm ones (:mod:`.contact`) plus any along :math:`Y`, the null space of :math:`J^\top`
(forces internal to the link, which move nothing). Both stages choose :math:`y` too (weighted
by :math:`\varepsilon`), so the cones bound the link's whole contact wrench cone -- a centre of
pressure anywhere in the sole -- not the least-norm distribution's smaller diamond; the plant's
checks accept any distribution inside the cones (:mod:`.sole`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
import qpsolvers
from scipy.linalg import null_space

from feltool.walking.legged.contact import LeggedContact, pinv_psd
from feltool.walking.legged.model import LeggedModel

#: The weight of a link's internal forces [N] against the torques [N m] in the QP's cost (a
#: choice among equally good distributions; 1e-6 left the problem on Talos' soles too
#: ill-conditioned for an iterative solver)
INTERNAL = 1e-3

#: The legged loop's QP solver (``qpsolvers``' name): DAQP, a dual active-set method, exact on
#: its active set and deterministic. ProxQP (an augmented Lagrangian, to a tolerance) was used
#: before: the same problem, bit for bit, came back different by 1e-11 from one call to the
#: next in one process (measured), so a seed's rollout was not the same twice.
QP_SOLVER = "daqp"


@dataclass
class StandGains:
    """Feedback gains of the standing controller.

    Attributes:
        height: ``(k_h [N/m], d_h [N s/m])`` on the base's height.
        tilt: ``(k_t [N m/rad], d_t [N m s/rad])`` on the base's roll and pitch.
        yaw_rate: ``d_y`` [N m s/rad] on the base's yaw rate.
        joints: ``(k_p [N m/rad], d_p [N m s/rad])`` on every motor joint.
    """

    height: tuple[float, float] = (200.0, 20.0)
    tilt: tuple[float, float] = (20.0, 1.0)
    yaw_rate: float = 0.5
    joints: tuple[float, float] = (3.0, 0.1)


def joint_loop_radius(legged: LeggedModel, q: np.ndarray, joints: tuple[float, float],
                      rate_hz: float) -> np.ndarray:
    r"""``(k,)``: per motor, the spectral radius of its joint PD ``joints`` = ``(k_p [N m/rad],
    k_d [N m s/rad])`` closed around the joint alone at the control rate ``rate_hz`` [Hz]: the
    torque computed from the state at a control step and held over it (zero-order hold) on the
    joint's apparent inertia :math:`I = 1 / (M^{-1})_{jj}` at ``q`` (the other joints free),

    .. math::

        \begin{pmatrix} q \\ \dot q \end{pmatrix}_{k+1} =
        \begin{pmatrix} 1 - a/2 & h (1 - b/2) \\ -a/h & 1 - b \end{pmatrix}
        \begin{pmatrix} q \\ \dot q \end{pmatrix}_k, \quad
        a = k_p h^2 / I, \ b = k_d h / I, \ h = 1/\mathrm{rate}.

    At 1 or above the joint's own feedback loop diverges, whatever the rest of the controller
    does (the damping alone when :math:`b > 2`)."""
    Minv = pin.computeMinverse(legged.model, legged.data, q)
    Minv = np.triu(Minv) + np.triu(Minv, 1).T
    inertia = 1.0 / np.diag(Minv)[6:]
    h = 1.0 / rate_hz
    out = np.empty(len(inertia))
    for i, I in enumerate(inertia):
        a, b = joints[0] * h ** 2 / I, joints[1] * h / I
        A = np.array([[1.0 - a / 2, h * (1.0 - b / 2)], [-a / h, 1.0 - b]])
        out[i] = np.abs(np.linalg.eigvals(A)).max()
    return out


@dataclass
class Allocation:
    """One allocation.

    Attributes:
        u: Motor torques ``(k,)`` [N m].
        forces: The contact forces ``(n, 3)`` [N] the stance dynamics give under ``u`` (the
            QP's affine model of them, exact for the known model at this state).
        solved: False when no torques within the limits keep the cones (then ``u`` is the
            unconstrained allocation clipped to the limits and the checks decide).
        exact: True when ``u`` gives the wanted constrained accelerations exactly (else they
            are met in least squares, the cones and limits kept).
    """

    u: np.ndarray
    forces: np.ndarray
    solved: bool = True
    exact: bool = True


@dataclass
class StandingController:
    """RNEA on the desired motion plus base and joint feedback, allocated by the QP above.

    Args:
        legged: The robot (its model is the known model).
        q_d: Desired configuration ``(nq,)`` (a standing pose); ``v_d``, ``a_d`` ``(nv,)``
            its velocity and acceleration (default zero).
        gains: The feedback gains.
        friction: :math:`\\mu` of the ground [-]; the QP keeps ``margin * friction``.
        normal_force_min: The QP's floor on each stance foot's normal force, in [N].
        margin: Fraction of :math:`\\mu` the QP uses.
        regularization: :math:`\\varepsilon` relative to the mean diagonal of
            :math:`B^\\top W B`, when no allocation is exact (below).
        motion: ``t [s] -> (q_d, v_d, a_d)``, a desired motion replacing the constant
            ``q_d`` (None: stand at ``q_d``).
        rank_tol: Eigenvalues of :math:`B^\\top W B` below this fraction of its largest span
            its null space.
    """

    legged: LeggedModel
    q_d: np.ndarray
    v_d: np.ndarray | None = None
    a_d: np.ndarray | None = None
    gains: StandGains = field(default_factory=StandGains)
    friction: float = 0.7
    normal_force_min: float = 0.5
    margin: float = 0.8
    regularization: float = 1e-6
    rank_tol: float = 1e-8
    motion: Callable[[float], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
    #: Allocations with no torques inside the cones and limits / not exact, so far
    infeasible: int = field(default=0, init=False)
    inexact: int = field(default=0, init=False)

    def __post_init__(self):
        nv = self.legged.nv
        self.v_d = np.zeros(nv) if self.v_d is None else np.asarray(self.v_d, float)
        self.a_d = np.zeros(nv) if self.a_d is None else np.asarray(self.a_d, float)
        self.contact = LeggedContact(self.legged)
        self.model, self.data = self.contact.model, self.contact.data
        self.B = self.legged.selection()

    def feedforward(self) -> np.ndarray:
        """:math:`\\mathrm{RNEA}(q_d, \\dot q_d, \\ddot q_d)` ``(nv,)`` [N, N m]."""
        return np.array(pin.rnea(self.model, self.data, self.q_d, self.v_d, self.a_d))

    def feedback(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``u_fb`` ``(nv,)``: the base wrench's generalized force plus the joints' PD."""
        m, d, g = self.model, self.data, self.gains
        base = pin.XYZQUATToSE3(q[:7])
        goal = pin.XYZQUATToSE3(self.q_d[:7])
        lin = base.rotation @ v[:3]  # world-frame velocity of the base origin
        omega = base.rotation @ v[3:6]
        e = pin.log3(goal.rotation @ base.rotation.T)
        wrench = np.array([0.0, 0.0,
                           g.height[0] * (goal.translation[2] - base.translation[2])
                           - g.height[1] * lin[2],
                           g.tilt[0] * e[0] - g.tilt[1] * omega[0],
                           g.tilt[0] * e[1] - g.tilt[1] * omega[1],
                           -g.yaw_rate * omega[2]])
        pin.computeJointJacobians(m, d, q)
        Jb = pin.getJointJacobian(m, d, 1, pin.LOCAL_WORLD_ALIGNED)
        out = Jb.T @ wrench
        dq = pin.difference(m, q, self.q_d)
        out[6:] += g.joints[0] * dq[6:] + g.joints[1] * (self.v_d[6:] - v[6:])
        return out

    def wanted(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """:math:`\\tau_w = \\mathrm{RNEA}(q_d, \\dot q_d, \\ddot q_d) + u_{fb}` ``(nv,)``."""
        return self.feedforward() + self.feedback(q, v)

    def allocate(self, q: np.ndarray, v: np.ndarray, tau_w: np.ndarray,
                 feet: tuple[str, ...]) -> Allocation:
        """Motor torques for the wanted ``tau_w`` under the stance ``feet`` (the QP above)."""
        m, d, B = self.model, self.data, self.B
        k = B.shape[1]
        Minv = pin.computeMinverse(m, d, q)
        Minv = np.triu(Minv) + np.triu(Minv, 1).T
        b = np.array(pin.nonLinearEffects(m, d, q, v))
        feet = tuple(feet)
        n = len(feet)
        if n:
            J = self.contact.jacobian(q, feet)
            gamma = self.contact.drift(q, v, feet)
            MJ = Minv @ J.T
            Lam = pinv_psd(J @ MJ)  # the inverse; least-norm forces for points of one link
            W = Minv - MJ @ Lam @ MJ.T
            self._absorbed = (J, Lam @ MJ.T)
            lam0 = Lam @ (MJ.T @ b - gamma)
            L = -Lam @ (MJ.T @ B)
        else:
            W, lam0, L = Minv, np.zeros(0), np.zeros((0, k))
            self._absorbed = None
        H = B.T @ W @ B
        H = 0.5 * (H + H.T)
        c = B.T @ W @ tau_w
        lim = np.minimum(self.legged.effort, 1e6)
        C, d = self._cones(n)
        # points of one link: forces along the null space of J^T (internal to the link) change
        # nothing but the distribution; the QP chooses them too (the link's whole wrench cone)
        Y = null_space(J.T) if n and self.contact.redundant(feet) else np.zeros((3 * n, 0))
        G = h = Gy = None
        if C is not None:
            G, h, Gy = C @ L, d - C @ lam0, C @ Y
        ev, V = np.linalg.eigh(H)
        keep = ev > self.rank_tol * max(ev.max(), 1e-300)
        self._metric = (B.T @ W, V[:, keep], ev[keep])
        u, y, exact = self._exact(ev, V, keep, c, G, h, Gy, lim)
        solved = u is not None
        if u is None:  # the wanted accelerations break a cone or a limit: least squares in them
            self.inexact += 1
            eps = self.regularization * max(np.trace(H) / k, 1e-300)
            m = Y.shape[1]
            P = np.block([[H + eps * np.eye(k), np.zeros((k, m))],
                          [np.zeros((m, k)), INTERNAL * np.trace(H) / k * np.eye(m)]])
            big = np.full(m, 1e9)
            x = qpsolvers.solve_qp(P, np.r_[-c, np.zeros(m)],
                                   None if G is None else np.hstack([G, Gy]), h,
                                   lb=np.r_[-lim, -big], ub=np.r_[lim, big], solver=QP_SOLVER)
            solved = x is not None
            u, y = (None, None) if x is None else (x[:k], x[k:])
        if u is None:
            self.infeasible += 1
            u = np.clip(np.linalg.lstsq(H, c, rcond=None)[0], -lim, lim)
            y = np.zeros(Y.shape[1])
        u = np.asarray(u, float)
        return Allocation(u, (lam0 + L @ u + Y @ y).reshape(n, 3), solved, exact)

    def motor_share(self, tau: np.ndarray) -> np.ndarray:
        """``(k,)`` [N m]: the least-norm motor torques that give a generalized force ``tau``
        ``(nv,)``'s constrained accelerations, :math:`(B^\\top W B)^+ B^\\top W \\tau`, in the
        state and stance of the last :meth:`allocate` (what the motors do for ``tau``; the
        allocation is linear in it while no cone or limit binds)."""
        BW, Vr, ev = self._metric
        return Vr @ ((Vr.T @ (BW @ tau)) / ev)

    def effective(self, tau: np.ndarray) -> np.ndarray:
        """``(nv,)``: the part of a generalized force ``tau`` that moves the robot under the
        stance contacts of the last :meth:`allocate`, :math:`M W \\tau = \\tau - J^\\top
        (J M^{-1} J^\\top)^{-1} J M^{-1} \\tau` (the rest, :math:`J^\\top \\lambda`, the
        ground takes: it changes only the contact forces)."""
        if self._absorbed is None:
            return np.array(tau, float)
        J, LMJ = self._absorbed
        return tau - J.T @ (LMJ @ tau)

    def _exact(self, s, V, keep, c, G, h, Gy, lim):
        """The allocations that give the wanted constrained accelerations exactly, ``u = u_0 + N
        z`` (``u_0`` the least-norm one, ``N`` the null space of :math:`B^\\top W B`, whose
        eigenvalues ``s`` and vectors ``V`` are given, ``keep`` its range), the smallest within
        the cones ``G u + G_y y <= h`` (``y`` the links' internal forces, ``Gy`` their
        columns) and limits: a QP in ``(z, y)`` (identity Hessian on ``z``). ``(u, y, exact)``,
        ``(None, None, False)`` when there is none."""
        Vr, N = V[:, keep], V[:, ~keep]
        u0 = Vr @ ((Vr.T @ c) / s[keep])
        m = 0 if Gy is None else Gy.shape[1]
        if N.shape[1] == 0 and m == 0:
            inside = np.all(np.abs(u0) <= lim) and (G is None or np.all(G @ u0 <= h + 1e-9))
            return (u0, np.zeros(0), True) if inside else (None, None, False)
        k = N.shape[1]
        pad = np.zeros((len(u0), m))
        Gz = np.vstack([np.hstack([N, pad]), np.hstack([-N, pad])]
                       + ([np.hstack([G @ N, Gy])] if G is not None else []))
        hz = np.concatenate([lim - u0, lim + u0] + ([h - G @ u0] if G is not None else []))
        P = np.block([[np.eye(k), np.zeros((k, m))],
                      [np.zeros((m, k)), INTERNAL * np.eye(m)]])
        x = qpsolvers.solve_qp(P, np.r_[N.T @ u0, np.zeros(m)], Gz, hz, solver=QP_SOLVER)
        if x is None:
            return None, None, False
        return u0 + N @ x[:k], x[k:], True

    def _cones(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """``C lambda <= d`` on the stance feet's forces ``lambda`` ``(3 n,)``: each foot's
        normal-force floor and its inner friction pyramid."""
        mu = self.margin * self.friction / np.sqrt(2.0)
        if n == 0:
            return None, None
        rows, rhs = [], []
        for i in range(n):
            x, y, z = 3 * i, 3 * i + 1, 3 * i + 2
            row = np.zeros(3 * n)
            row[z] = -1.0
            rows.append(row)
            rhs.append(-self.normal_force_min)
            for t in (x, y):
                for sign in (1.0, -1.0):  # sign f_t - mu f_z <= 0
                    row = np.zeros(3 * n)
                    row[t], row[z] = sign, -mu
                    rows.append(row)
                    rhs.append(0.0)
        return np.array(rows), np.array(rhs)

    def __call__(self, q: np.ndarray, v: np.ndarray, feet: tuple[str, ...],
                 t: float = 0.0) -> Allocation:
        """The motor torques at the state ``(q, v)`` with ``feet`` in stance, at time ``t`` [s]
        of the :attr:`motion`."""
        if self.motion is not None:
            self.q_d, self.v_d, self.a_d = (np.asarray(x, float) for x in self.motion(t))
        return self.allocate(q, v, self.wanted(q, v), feet)
