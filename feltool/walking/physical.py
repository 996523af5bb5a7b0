r"""The physical walker's closed loop: stance on a point contact, touchdown by contact, rigid impact.

One step: the stance foot ("left" in stance-relative labels, the config's ``walking.stance``) is
held on the ground by a contact constraint (:class:`feltool.walking.contact.Contact`), the swing foot
("right") flies. The control step's torque is held while the state is integrated (classical
Runge-Kutta, ``sim.substeps`` sub-steps per control step). Touchdown is an event: the swing foot's
height crossing :math:`z = 0` moving down, ahead of the stance foot and outside the scuffing
zone, located inside the sub-step by root finding (Brent's method on the sub-step's length), not
by the clock. At touchdown the landing foot's rigid impact (``pin.impulseDynamics``) changes the
velocities, the legs are relabelled (the landing leg becomes "left") and the state is shifted
so that the new stance foot is at :math:`x = 0`; the rest of the sub-step runs on (with
``phase: touchdown`` the next control step starts at the touchdown instead).

Control, in generalized coordinates :math:`(x, z, \vartheta, q_j)` of the floating base:
the desired joint and pitch trajectories come from the RMPs; the desired base position follows
from the stance foot's constraint (:meth:`PhysicalWalker.complete`). The wanted generalized
force :math:`\tau_w = \mathrm{RNEA}(q_d, \dot q_d, \ddot q_d) + u_{fb}` (eq. 3.1 plus feedback)
is mapped onto the motors :math:`B` (every non-base joint) by the inertia-weighted allocation in
the metric of the constrained system,

.. math::

    u = (B^\top W B)^{-1} B^\top W \tau_w,\qquad
    W = M^{-1} - M^{-1}J_c^\top (J_c M^{-1} J_c^\top)^{-1} J_c M^{-1},

the motor torques whose constrained accelerations are closest, in the kinetic-energy metric, to
those :math:`\tau_w` would produce with the foot held.

Contact physics is checked all along (:class:`ContactChecks`); a violation ends the cycle like a
fall, with the reason: the walker is then *not walking*.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin
from scipy.optimize import brentq

from feltool.control.feedback import FeedbackLaw
from feltool.dynamics.interface import Dynamics
from feltool.dynamics.pinocchio import mass_matrix
from feltool.walking.checks import NotWalking, StepStats, check_clearance
from feltool.walking.contact import Contact, StanceResult
from feltool.walking.pinned import HybridLog
from feltool.walking.walker import PhysicalWalker


@dataclass
class WalkLog(HybridLog):
    r"""One cycle of the physical walker (generalized coordinates of the floating base).

    Like :class:`feltool.walking.pinned.HybridLog`; ``impacts`` are ``(step, True, step length [m])``,
    ``steps`` the per-step :class:`StepStats`, ``phase_index`` the RMP sample used at each
    control step, ``tau`` the motor torques ``(n, k)`` [N m], ``allocation`` the allocation's
    matrix ``(n, k, nv)`` at each control step (motor torques per generalized force),
    ``reference`` the feedback's references ``(n, nv)`` [rad], ``inertial`` the inertial
    term :math:`M(q)(\ddot q_r - \ddot q)` ``(n, nv)`` [N m] of the reference's acceleration
    :math:`\ddot q_r` against the walker's; ``elapsed`` the cycle's time in [s] (its control
    steps, each cut short at a touchdown).
    """

    steps: list = field(default_factory=list)
    phase_index: np.ndarray | None = None
    tau: np.ndarray | None = None
    force: np.ndarray | None = None
    torque_hits: np.ndarray | None = None
    not_walking: str | None = None
    allocation: np.ndarray | None = None
    reference: np.ndarray | None = None
    inertial: np.ndarray | None = None
    elapsed: float = np.nan


class PhysicalLoop:
    """Closed loop of a physical walker, stepped one control step at a time.

    Args:
        known: The known model's dynamics (floating base; feedforward).
        law: Feedback laws (generalized coordinates).
        walker: The physical walker.
        dt: Control step [s].
        substeps: Runge-Kutta steps per control step.
        error_rows: ``(nv,)`` controllers whose output is the learning signal.
    """

    def __init__(self, known: Dynamics, law: FeedbackLaw, walker: PhysicalWalker, dt: float,
                 substeps: int = 1, error_rows: np.ndarray | None = None):
        self.known, self.law, self.walker = known, law, walker
        self.dt, self.substeps = dt, substeps
        nv = walker.walker.model.nv
        self.error_rows = np.zeros(nv) if error_rows is None else np.asarray(error_rows, float)
        self.allocation = None
        self._ends: dict = {}
        #: ``{velocity index: (q, v, a)}`` sampled at the control rate: coordinates whose
        #: feedback reference (and the mechanical phase) follows these samples (a designed
        #: gait) while their forward trajectory, the feedforward's, is their learned RMP
        self.reference: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        # -- hooks of the learner comparison (feltool.engines.ilc_walker, feltool.plant.disturbances) --------
        #: ``(n, k)`` motor torques [N m] added to the command at each control step's RMP
        #: sample (``WalkLog.phase_index``): ILC's learned feedforward, or None
        self.motor_feedforward: np.ndarray | None = None
        # -- hooks of classic FEL on the walker (feltool.learning.walker_model) --
        #: ``(qd, vd, ad) -> (nv,)`` generalized forces [N m] added to the known model's
        #: feedforward (a learned model correction), or None
        self.model_correction = None
        #: ``(k,)`` motor torques [N m] added to every command (learned biases), or None
        self.motor_bias: np.ndarray | None = None
        #: Plant-only disturbances (:class:`feltool.plant.disturbances.WalkerDisturbance`), or None:
        #: the controller and the learner see its measurements, the plant gets its torques
        self.disturbance = None

    def _referenced(self, P: np.ndarray, Pv: np.ndarray, Pa: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The reference trajectories: the forward ones with the :attr:`reference` rows."""
        if not self.reference:
            return P, Pv, Pa
        R, Rv, Ra = P.copy(), Pv.copy(), Pa.copy()
        for i, (q, v, a) in self.reference.items():
            R[:, i], Rv[:, i], Ra[:, i] = q[:len(P)], v[:len(P)], a[:len(P)]
        return R, Rv, Ra

    def initial_state(self, P: np.ndarray, Pv: np.ndarray, plant: Dynamics | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Start on the desired trajectory, stabilized quantities on target, stance foot at the
        origin with zero velocity — the ``plant``'s foot when given (a plant whose legs are
        not the model's, ``plant.bodies.*.length_scale``: the base translated onto it, the
        joints as desired)."""
        R, Rv, _ = self._referenced(P, Pv, Pv)
        q, v = self.law.consistent_state(R[0], Rv[0])
        q, v, _ = self.walker.complete(q, v, np.zeros_like(v))
        if plant is not None:
            q, v = self.walker.anchored(q, v, self.walker.contact_for(plant))
        return q, v

    def run_cycle(self, plant: Dynamics, q: np.ndarray, v: np.ndarray, P: np.ndarray,
                  Pv: np.ndarray, Pa: np.ndarray) -> WalkLog:
        """One cycle from ``(q, v)`` (stance foot at the origin) with desired trajectories
        ``P, Pv, Pa`` ``(n, nv)``; ``plant`` is the simulated world."""
        W = self.walker
        contact = W.contact_for(plant)
        n, nv = P.shape
        clock = W.phase == "clock"  # else touchdown or mechanical: the cycle ends at touchdowns
        n_max = n if clock else 3 * n
        ns = n // W.steps_per_cycle  # samples per step (the last step takes the remainder)
        k_motors = W.B.shape[1]
        Q, V, U, Qd, Vd, Ad, Urows, Uerr = (np.zeros((n_max, nv)) for _ in range(8))
        Tau, Force = np.zeros((n_max, k_motors)), np.zeros((n_max, 2))
        Alloc = np.zeros((n_max, k_motors, nv))
        Ref, Inert = np.zeros((n_max, nv)), np.zeros((n_max, nv))
        Rq, Rv, Ra = self._referenced(P, Pv, Pa)
        index = np.zeros(n_max, dtype=int)
        labels = np.zeros(n_max, dtype=int)
        hits = np.zeros(k_motors, int)
        steps, impacts = [StepStats()], []
        h = self.dt / self.substeps
        j, m, fall, t_step, kind = 0, 0, None, 0.0, None
        t_ctrl = 0.0  # the control step's start in [s] (a touchdown ends its control step)
        phase_acc = 0.0  # the mechanical phase's acceleration [1/s], from the last step
        try:
            while m < n_max and not (clock and m >= n):
                if not clock and len(impacts) >= W.steps_per_cycle:
                    break
                k = m
                dist = self.disturbance  # the controller's view: qm, vm (measured); q, v true
                qm, vm = (q, v) if dist is None else dist.measure(q, v)
                # a late touchdown holds the step's last sample (its segment of the cycle's
                # samples; clock: the cycle's last), never the next step's post-impact samples
                s_idx = len(impacts) % W.steps_per_cycle
                last = clock or s_idx == W.steps_per_cycle - 1
                jj = min(j, (n if last else (s_idx + 1) * ns) - 1)
                label = len(impacts) % 2 if W.steps_per_cycle % 2 == 0 else 0
                labels[k] = label
                if W.phase == "mechanical":
                    jj, p, pv, pa, rp, rpv, rpa = self._mechanical(
                        qm, vm, P, Pv, Pa, len(impacts), label, (Rq, Rv, Ra), phase_acc)
                else:
                    p, pv, pa, rp, rpv, rpa = P[jj], Pv[jj], Pa[jj], Rq[jj], Rv[jj], Ra[jj]
                index[k] = jj
                (qd, vd, ad, ar), Ref[k], (U[k], Urows[k], Uerr[k]), Alloc[k], u = \
                    self.command(qm, vm, (p, pv, pa), (rp, rpv, rpa), label)
                Q[k], V[k], Qd[k], Vd[k], Ad[k] = qm, vm, qd, vd, ad
                m += 1
                if self.motor_feedforward is not None:
                    u = u + self.motor_feedforward[jj]
                over = np.abs(u) > W.checks.effort
                if over.any() and W.checks.torques != "ignore":
                    hits += over
                    if W.checks.torques == "saturate":
                        u = np.clip(u, -W.checks.effort, W.checks.effort)
                    else:
                        i = int(np.argmax(np.abs(u) - W.checks.effort))
                        raise NotWalking(
                            f"the torque of motor '{W.motor_names[i]}' is {u[i]:.4g} N m, beyond "
                            f"its effort limit {W.checks.effort[i]:.4g} N m "
                            "(sim.torque_limits: report; saturate clips it)", "torque")
                Tau[k] = u
                tau = W.B @ (u if dist is None else dist.apply(u))
                # the inertial part of the feedforward's error, M (a_r - a): what the feedback
                # has not (yet) produced of the reference's acceleration (PhysicalLoop doc)
                now = contact.stance(q, v, tau, W.stance)  # (also the first sub-step's start)
                a = a_phase = now.a
                if dist is None:  # the known model's M (the plant's is unknown to the learner)
                    M = mass_matrix(W.contact.model, W.contact.data, q)
                else:  # as measured: the known model's M at qm, a measured;
                    M, a = dist.inertia(qm), dist.acceleration(a)  # the phase's: predicted
                Inert[k] = M @ (ar - a)
                if W.phase == "mechanical":  # the phase's acceleration for the next step,
                    # from the (known model's) centre of mass's acceleration now
                    if dist is not None:
                        a_phase = W.contact.stance(qm, vm, W.B @ u, W.stance).a
                    phase_acc = self._phase_acceleration(W.com_x(qm, vm, a_phase)[2])
                steps[-1].max_torque = max(steps[-1].max_torque, float(np.abs(u).max()))
                ended, t_next = False, t_ctrl + self.dt
                for i_sub in range(self.substeps):
                    q, v, s = self._substep(contact, q, v, tau, h, steps, Force, k, clock,
                                            now if i_sub == 0 else None)
                    if s is not None:
                        t_td = t_ctrl + i_sub * h + s
                        steps[-1].duration = t_td - t_step
                        t_step = t_td
                        impacts.append((k + 1, True, steps[-1].length))
                        steps.append(StepStats())
                        phase_acc = 0.0
                        if not clock:
                            # the phase restarts at the touchdown: step i of the cycle starts
                            # at sample i n / steps_per_cycle (the increment below adds 1), and
                            # the next control step starts at the touchdown (the sub-step's
                            # rest is not run); the cycle ends at its last touchdown
                            j = len(impacts) * (n // W.steps_per_cycle) - 1
                            t_next = t_td
                            ended = len(impacts) >= W.steps_per_cycle
                            break
                t_ctrl = t_next
                fall = W.fallen(q, v)
                if fall or ended:
                    break
                j += 1
            if fall is None and not clock and len(impacts) < W.steps_per_cycle:
                raise NotWalking(f"no touchdown within {n_max * self.dt:.3g} s "
                                 f"({len(impacts)} of {W.steps_per_cycle})", "touchdown")
        except NotWalking as exc:
            fall, kind = f"not walking: {exc}", exc.kind
        sl = slice(0, m)
        return WalkLog(Q[sl], V[sl], U[sl], q, v, Qd[sl], Vd[sl], Ad[sl], labels[sl],
                       impacts, fall, Urows[sl], Uerr[sl], steps, index[sl], Tau[sl], Force[sl],
                       hits, kind, Alloc[sl], Ref[sl], Inert[sl], t_ctrl)

    def command(self, q: np.ndarray, v: np.ndarray, forward: tuple, reference: tuple,
                label: int) -> tuple:
        """The controller of one control step at the (measured) state ``q, v``: the desired
        joint state from the RMPs' ``forward`` values ``(p, pv, pa)`` (and the reference
        rows' from ``reference``) at stance ``label``, the feedback laws' terms, the
        allocation A and the motors' command :math:`u = A(u_{ff} + u_{fb})` [N m], before the
        effort limits. Returns ``((qd, vd, ad, ar), r, (u_fb, u_rows, u_err), A, u)``, ``ar``
        the reference's acceleration."""
        W = self.walker
        qd, vd, ad = W.complete(*W.labelled(*forward, label))
        qr, vr, ar = W.complete(*W.labelled(*reference, label)) if self.reference else \
            (qd, vd, ad)
        r, rd = self.law.references(qr[None], vr[None])
        terms = self.law.terms(q, v, r[0], rd[0], self.error_rows)
        A = W.allocation_matrix(q)
        tau_w = self.known.inverse(qd, vd, ad) + terms[0]
        if self.model_correction is not None:
            tau_w = tau_w + self.model_correction(qd, vd, ad)
        u = A @ tau_w
        if self.motor_bias is not None:
            u = u + self.motor_bias
        return (qd, vd, ad, ar), r[0], terms, A, u

    def _mechanical(self, q, v, P, Pv, Pa, step: int, label: int, ref=None,
                    phase_acc: float = 0.0):
        r"""The RMPs' values at the mechanical phase. The phase variable is the centre of
        mass's horizontal position over the stance foot, :math:`x` (the stance foot is at
        x = 0), whose desired values over the step's samples, :math:`x_d(s_i)`, must increase:
        the current :math:`x` gives the fractional sample time :math:`s` with
        :math:`x_d(s) = x` (held at the step's ends), and the samples are interpolated
        linearly at :math:`s`. The phase runs at :math:`\dot s = \dot x / \dot x_d(s)` and
        accelerates at :math:`\ddot s = (\ddot x - \ddot x_d(s)\,\dot s^2) / \dot x_d(s)`,
        so a trajectory :math:`p(s)` is :math:`p`, :math:`\dot p = p'\dot s`,
        :math:`\ddot p = p''\dot s^2 + p'\ddot s` (``phase_acc``: :math:`\ddot s` in [1/s],
        the last control step's, which needs that step's :math:`\ddot x`: the torque's; see
        :meth:`_phase_acceleration`). On the reference's own motion :math:`\dot s = 1`,
        :math:`\ddot s = 0`. With ``ref`` (reference trajectories
        ``(R, Rv, Ra)``) the phase follows the reference's centre of mass and the reference's
        position, velocity and acceleration are returned too: ``(nearest sample, p, pv, pa,
        rp, rpv, rpa)``; else ``(nearest sample, p, pv, pa)``."""
        W = self.walker
        out_ref = ref is not None
        Ph, Phv, Pha = ref if out_ref else (P, Pv, Pa)
        n = len(P)
        ns = n // W.steps_per_cycle
        i0 = (step % W.steps_per_cycle) * ns
        # keyed by content: a new cycle's arrays may reuse a freed array's id
        key = (hash(Ph[i0:i0 + ns].tobytes()), hash(Phv[i0:i0 + ns].tobytes()),
               hash(Pha[i0:i0 + ns].tobytes()), i0, label)
        if self._ends.get("key") != key:
            x, xv, xa = np.empty(ns), np.empty(ns), np.empty(ns)
            for i in range(ns):
                qd, vd, ad = W.complete(*W.labelled(Ph[i0 + i], Phv[i0 + i], Pha[i0 + i], label))
                x[i], xv[i], xa[i] = W.com_x(qd, vd, ad)
            if np.any(np.diff(x) <= 0):
                raise NotWalking("walking.phase: mechanical needs the desired centre of mass to "
                                 "move forward over the stance foot through the whole step",
                                 "phase")
            self._ends = {"key": key, "x": x, "xv": xv, "xa": xa}
        x, xv, xa = self._ends["x"], self._ends["xv"], self._ends["xa"]
        xc, xc_rate = W.com_x(q, v)
        f = float(np.interp(xc, x, np.arange(ns)))
        a = min(int(f), ns - 2)
        w = f - a
        lerp = lambda X: (1 - w) * X[i0 + a] + w * X[i0 + a + 1]  # noqa: E731
        x_rate = (1 - w) * xv[a] + w * xv[a + 1]
        rate = xc_rate / x_rate if x_rate > 1e-9 else 1.0
        self._phase = (rate, x_rate, (1 - w) * xa[a] + w * xa[a + 1])
        out = (i0 + int(round(f)), lerp(P), rate * lerp(Pv),
               rate**2 * lerp(Pa) + phase_acc * lerp(Pv))
        return out + (lerp(Ph), rate * lerp(Phv),
                      rate**2 * lerp(Pha) + phase_acc * lerp(Phv)) if out_ref else out

    def _phase_acceleration(self, xc_acc: float) -> float:
        r""":math:`\ddot s` [1/s] at the last :meth:`_mechanical` call's phase, for the centre
        of mass's acceleration ``xc_acc`` [m/s^2] under that control step's torque."""
        rate, x_rate, xa = self._phase
        return (xc_acc - xa * rate**2) / x_rate if x_rate > 1e-9 else 0.0

    def jacobian_derivatives(self, log: WalkLog) -> tuple:
        """``(u_ff, Dq G, Dv G, M G)`` along the cycle: the inverse model's derivatives with
        respect to the RMPs' values, through :meth:`PhysicalWalker.chain`."""
        u_ff, Dq, Dv, M = self.known.inverse_derivatives_batch(log.Qd, log.Vd, log.Ad)
        Gs = np.stack([self.walker.chain(qd, s) for qd, s in zip(log.Qd, log.stance)])
        mul = lambda D: np.einsum("kij,kjl->kil", D, Gs)  # noqa: E731
        return u_ff, mul(Dq), mul(Dv), mul(M)

    # -- one Runge-Kutta sub-step with the contact events ------------------------------------------
    def _rk4(self, contact: Contact, q, v, tau, h, a1=None):
        """Classical Runge-Kutta over ``h`` [s] with the stance foot held (``a1``: the
        accelerations at ``(q, v)``, if known)."""
        W, model = self.walker, contact.model

        def f(qq, vv):
            return contact.stance(qq, vv, tau, W.stance).a

        a1 = f(q, v) if a1 is None else a1
        q2, v2 = pin.integrate(model, q, 0.5 * h * v), v + 0.5 * h * a1
        a2 = f(q2, v2)
        q3, v3 = pin.integrate(model, q, 0.5 * h * v2), v + 0.5 * h * a2
        a3 = f(q3, v3)
        q4, v4 = pin.integrate(model, q, h * v3), v + h * a3
        a4 = f(q4, v4)
        dq = h / 6.0 * (v + 2 * v2 + 2 * v3 + v4)
        return pin.integrate(model, q, dq), v + h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)

    def _substep(self, contact: Contact, q, v, tau, h, steps, Force, k, finish: bool = True,
                 start: StanceResult | None = None):
        """Integrate one sub-step; returns ``(q, v, s)`` with ``s`` the touchdown's time in the
        sub-step [s], or None. After a touchdown the rest of the sub-step runs on when
        ``finish`` (clock phase); otherwise the state at the touchdown is returned. ``start``:
        the stance dynamics at ``(q, v, tau)``, if the caller has them."""
        W, chk, st = self.walker, self.walker.checks, steps[-1]
        res = contact.stance(q, v, tau, W.stance) if start is None else start
        Fx, Fz = res.force
        Force[k] = res.force
        st.min_normal_force = min(st.min_normal_force, float(Fz))
        if Fz <= chk.normal_force_min or Fz <= 0.0:
            raise NotWalking(f"the stance foot's normal force is {Fz:.4g} N (walking."
                             f"normal_force_min = {chk.normal_force_min} N): the foot would lift",
                             "normal_force")
        ratio = abs(Fx) / Fz
        st.max_friction_ratio = max(st.max_friction_ratio, float(ratio))
        if ratio > chk.friction:
            raise NotWalking(f"the stance foot's friction ratio |F_x|/F_z is {ratio:.3g} "
                             f"(walking.friction = {chk.friction}): the foot would slide", "friction")
        anchor, (_, z0) = contact.foot_positions(q, W.stance, W.swing)
        q1, v1 = self._rk4(contact, q, v, tau, h, res.a)
        q1, v1 = contact.hold(q1, v1, W.stance, anchor)
        (sx, sz), _ = contact.foot_state(q1, v1, W.swing)
        ahead = sx - anchor[0]
        exempt = abs(ahead) < chk.scuff_exempt
        landing = not exempt and ahead > 0.0 and z0 > 0.0 and sz <= 0.0
        if not landing:
            check_clearance(chk, st, float(sz), float(ahead))
            return q1, v1, None
        # Touchdown inside this sub-step: its time by Brent's method on the sub-step's length.
        def height(s):
            qs, vs = self._rk4(contact, q, v, tau, s, res.a)
            return contact.foot_positions(qs, W.swing)[0][1]

        s = brentq(height, 0.0, h, xtol=1e-12, rtol=1e-12, maxiter=100)
        qs, vs = self._rk4(contact, q, v, tau, s, res.a)
        qs, vs = contact.hold(qs, vs, W.stance, anchor)
        (tx, tz), (tvx, tvz) = contact.foot_state(qs, vs, W.swing)
        st.touchdown_height = float(tz)
        st.min_clearance = min(st.min_clearance, max(float(tz), 0.0))
        if tvz >= 0.0:
            raise NotWalking("the swing foot reached the ground moving up", "touchdown")
        imp = contact.impact(qs, vs, W.swing)
        Ix, Iz = imp.impulse
        st.impulse, st.energy_lost = imp.impulse.copy(), imp.energy_lost
        st.impulse_ratio = abs(Ix) / Iz if Iz > 0 else np.inf
        st.length = float(tx - anchor[0])
        _, (_, trail_vz) = contact.foot_state(qs, imp.v, W.stance)
        st.trailing_vz = float(trail_vz)
        if Iz <= 0.0:
            raise NotWalking(f"the touchdown impulse would pull the ground (I_z = {Iz:.4g} N s)", "impulse")
        if st.impulse_ratio > chk.friction:
            raise NotWalking(f"the touchdown impulse ratio |I_x|/I_z is {st.impulse_ratio:.3g} "
                             f"(walking.friction = {chk.friction}): the landing foot would slide",
                             "impulse")
        if trail_vz < -1e-9:
            raise NotWalking(f"the trailing foot does not lift off after the touchdown (its "
                             f"vertical velocity is {trail_vz:.4g} m/s)", "lift_off")
        # Relabel (the landing leg becomes the stance leg) and put its foot at x = 0, z = 0.
        qn, vn = W.walker.relabel(qs, imp.v)
        qn = qn.copy()
        qn, vn = contact.hold(qn, vn, W.stance, np.array([tx, 0.0]))
        qn[W.base_q[0]] -= tx
        rest = h - s
        if finish and rest > 1e-12:
            qn, vn = self._rk4(contact, qn, vn, tau, rest)
            qn, vn = contact.hold(qn, vn, W.stance, np.zeros(2))
        return qn, vn, s


__all__ = ["PhysicalLoop", "PhysicalWalker", "WalkLog"]
