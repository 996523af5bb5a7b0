r"""Online gait re-acquisition (``learning.redesign``): the gait re-designed on the identified
model during a run.

A physical walker's model learner (:mod:`feltool.learning.walker_model`) identifies what the
known model gets wrong: a correction :math:`\theta_\pi` of the bodies' inertial parameters, a
ground slope :math:`\delta\alpha` (``learning.model.slope``) and motor biases. FEL of a fixed
reference cannot go further than the reference allows: a gait designed for the known model is
no orbit of a walker carrying a payload or walking a slope (the moment about the stance foot
that no motor gives, docs/biped.md), so the feedback cannot vanish whatever is learned. Here,
every ``every_s`` seconds walked, when the identified world differs from the one the current
gait was designed in, the gait is designed again by feltool's own designer
(:func:`feltool.gait.design.design_gait`, IPOPT) on

* the known model with the identified inertial parameters :math:`\pi_{model} + \theta_\pi`,
  **projected to physically consistent ones** (:func:`physical_inertia`: a body's mass not
  negative, its second moment of mass positive semi-definite: the min-norm
  Levenberg-Marquardt steps may leave either, in directions the gait barely excites), and
* the identified ground slope :math:`\alpha_0 + \delta\alpha`,

with the design options of the block (the shipped gait's: speed or step length, duration,
torso target, margins). The run continues on the new design at the end of the cycle (a cycle
boundary: the walker's state, its stance foot and velocities, carried over): the new gait's
demos replace the old ones, the learned joints' RMPs start on it (``init: demo`` refits them
to the new design), and the model correction and biases are kept. The known model the
controller, the feedforward and the error estimate use is not changed: the feedforward stays
``RNEA_known + Y theta_pi + ...``, which already holds what was learned.

A design that fails (IPOPT finds no gait) keeps the old reference; it is counted and reported
in the seed's summary (``redesign.failed``), and after ``max_failures`` no more are tried.
Nothing here draws at random (IPOPT is deterministic), so a run is reproducible. On the
compiled engine the new design needs no build: a physical walker's demos, period and gravity
are inputs of its library (:func:`feltool.engines.compiled.engine._physical_key`).
"""

from __future__ import annotations

import copy
import json
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.interpolate import CubicHermiteSpline

from feltool.errors import FeltoolError
from feltool.experiment.experiment import Experiment
from feltool.gait.config import gait_config, gait_spec, walker_from_raw
from feltool.gait.design import design_gait
from feltool.gait.orbit import close_on_orbit

#: the last designs (identified model, slope, options and config -> the closed config): the
#: seeds of a run that identify the same world re-use them
_DESIGNS: dict = {}


def physical_inertia(p: np.ndarray, moving: np.ndarray | None = None,
                     floor: float = 1e-9) -> tuple[pin.Inertia, bool]:
    r"""The physically consistent inertia nearest ``p`` (Pinocchio's 10 dynamic parameters
    ``[m, m c, I at the joint frame]``) and whether a parameter that moves a torque had to
    change.

    A real body has a mass not below zero and a second moment of mass about its centre of
    mass, :math:`\Sigma = 	frac12 \mathrm{tr}(I_c) E - I_c`, positive semi-definite (which
    gives the triangle inequalities of the principal moments). ``moving`` (10 bools): the
    parameters that some motion turns into a torque (the regressor's moving columns); the
    others change no torque and are chosen freely. A planar body (only :math:`I_{yy}` of the
    rotational inertia moving) gets :math:`\Sigma_{xx} = \Sigma_{zz} = I_{c,yy}/2`,
    :math:`\Sigma_{yy} =` ``floor``, no products: consistent, and no torque changes. Else (or
    with :math:`I_{c,yy} < 0`, or a mass below zero: then the body becomes weightless) the
    eigenvalues of :math:`\Sigma` are raised to ``floor`` [kg m^2], which changes torques."""
    p = np.asarray(p, float)
    moving = np.ones(10, bool) if moving is None else np.asarray(moving, bool)
    m = float(p[0])
    if m <= 1e-12:
        return pin.Inertia.Zero(), bool(np.any(np.abs(p[moving]) > 1e-12))
    c = p[1:4] / m
    ixx, ixy, iyy, ixz, iyz, izz = p[4:10]
    I_o = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], float)
    I_c = I_o - m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    S = 0.5 * np.trace(I_c) * np.eye(3) - I_c
    w, V = np.linalg.eigh(S)
    if w.min() >= -floor:
        return pin.Inertia(m, c, 0.5 * (I_c + I_c.T)), False
    planar = moving[6] and not moving[[4, 5, 7, 8, 9]].any()
    if planar and I_c[1, 1] >= 2 * floor:  # the free parameters make it consistent
        S = np.diag([0.5 * I_c[1, 1], floor, 0.5 * I_c[1, 1]])
        return pin.Inertia(m, c, np.trace(S) * np.eye(3) - S), False
    S = (V * np.maximum(w, floor)) @ V.T
    I_c = np.trace(S) * np.eye(3) - S
    return pin.Inertia(m, c, 0.5 * (I_c + I_c.T)), True


def identified_model(learner, theta_m: np.ndarray, legs: list[tuple[str, str]] = ()
                     ) -> tuple[pin.Model, int]:
    r"""The known model with the learned inertial parameters :math:`\pi_{model} + \theta_\pi`,
    each body projected by :func:`physical_inertia`, and how many bodies' torques the
    projection changed. ``legs``: the walker's left/right joint pairs, whose bodies get the
    mean of the pair's parameters: the walker runs (and learns) in stance-relative labels,
    where one leg's identified parameters differ from the other's only by what the motion
    excites (a stance leg barely swings), while the two legs are one build and the gait
    designer's relabelling assumes them alike (a design with unlike legs does not walk in the
    loop)."""
    pi = learner.pi_model.copy()
    pi[learner.columns] += np.asarray(theta_m[:learner.n_pi], float)
    for a, b in legs:
        ja, jb = learner.model.getJointId(a), learner.model.getJointId(b)
        sa, sb = slice(10 * (ja - 1), 10 * ja), slice(10 * (jb - 1), 10 * jb)
        pi[sa] = pi[sb] = 0.5 * (pi[sa] + pi[sb])
    moving = np.zeros(len(pi), bool)
    moving[learner.columns] = True
    model = pin.Model(learner.model)
    projected = 0
    for j in range(1, model.njoints):
        sl = slice(10 * (j - 1), 10 * j)
        inertia, changed = physical_inertia(pi[sl], moving[sl])
        model.inertias[j] = inertia
        projected += changed
    model, moved = _onto_links(model, learner.model)
    return model, projected + int(moved)


def _onto_links(model: pin.Model, known: pin.Model) -> tuple[pin.Model, bool]:
    """``model`` with what the learner put on bodies the URDF has no link for (feltool's
    planar base joints before the root link, weightless in the known model) moved onto the
    root link's body, and whether that changed a torque: a body on a joint whose placement
    and whose descendants' up to the root are the identity carries its mass at the root's
    origin, so the move changes nothing when the body is its own joint's point mass."""
    root = next(j for j in range(1, known.njoints) if known.inertias[j].mass > 0)
    changed = False
    for j in range(1, root):
        extra = model.inertias[j]
        if extra.mass <= 0:
            continue
        changed |= bool(np.abs(extra.lever).max() > 1e-12 or np.abs(extra.inertia).max() > 1e-12
                        or model.joints[j].shortname() not in ("JointModelPZ",))
        model.inertias[root] = model.inertias[root] + extra
        model.inertias[j] = pin.Inertia.Zero()
    return model, changed


def cycle_measurements(exp: Experiment, out) -> tuple[np.ndarray, ...]:
    """A cycle's measured motion: per control step the positions ``Q`` ``(n, nq)``,
    velocities ``V`` ``(n + 1, nv)`` (the cycle's end last), applied generalized forces
    ``Tau = B u`` ``(n, nv)`` [N m] and the touchdowns' control steps (either engine's trace;
    the walker's own labels)."""
    log, _ = out.trace()
    tau = getattr(log, "applied", None)
    if tau is None:  # the Python engine's log: motor torques
        tau = np.asarray(log.tau) @ exp.hybrid.walker.B.T
        touchdowns = np.array([k for k, _, _ in log.impacts], int)
    else:
        touchdowns = np.asarray(log.touchdowns, int)
    n = len(tau)
    Q = np.vstack([log.q[:n], log.q_end])
    V = np.vstack([log.v[:n], log.v_end])
    return Q, V, np.asarray(tau, float), touchdowns


def tied_legs(learner, legs) -> np.ndarray:
    """``T`` ``(n_pi, r)``: the learner's inertial columns as functions of ``r`` free ones, a
    right leg's body's parameter the same as its left twin's (``delta_pi = T x``)."""
    cols = [int(c) for c in learner.columns]
    where = {c: i for i, c in enumerate(cols)}
    twin = {}
    for a, b in legs:
        ja, jb = learner.model.getJointId(a), learner.model.getJointId(b)
        for k in range(10):
            ca, cb = 10 * (ja - 1) + k, 10 * (jb - 1) + k
            if ca in where and cb in where:
                twin[where[cb]] = where[ca]
    free = [i for i in range(len(cols)) if i not in twin]
    T = np.zeros((len(cols), len(free)))
    for r, i in enumerate(free):
        T[i, r] = 1.0
    for i, j in twin.items():
        T[i, free.index(j)] = 1.0
    return T


def identify_motion(exp: Experiment, Q: np.ndarray, V: np.ndarray, Tau: np.ndarray,
                    touchdowns: np.ndarray, damping: float = 1e-6) -> tuple[np.ndarray, float]:
    r"""The world identified from the walker's measured motion: ``(delta_pi, delta_alpha)``,
    the inertial parameters' change (the learner's :attr:`columns`) and the ground slope's
    [rad].

    Over each control step :math:`[t_k, t_{k+1}]` away from a touchdown the walker's mean
    acceleration :math:`a = (v_{k+1} - v_k)/\Delta t` at the midpoint state obeys the plant's
    stance dynamics :math:`\mathrm{RNEA}(q, v, a) = B u_k + J_s^T\lambda`. The foot's force
    :math:`\lambda` is not measured: projected onto the null space :math:`N` of the stance
    foot's Jacobian (:math:`J_s N = 0`: the directions the foot's force does not act in,
    among them the rotation about the foot that no motor acts in either),

    .. math:: N^T igl(Y(q, v, a)\,\delta\pi + g_t(q)\,\deltalphaigr)
              = N^T igl(B u_k - \mathrm{RNEA}_{known}(q, v, a)igr),

    solved by damped least squares over the cycle (``damping`` relative to the mean
    diagonal: the directions the motion does not excite stay at the known model's), the two
    legs' bodies tied alike (:func:`tied_legs`: the walker runs in stance-relative labels,
    but its legs are one build, and a design with unlike legs does not walk). The
    feedback's motor-space error the model learner steps on (:math:`A e`) does not see the
    rotation about the foot at all, so it cannot identify what makes the design no orbit
    (docs/biped.md)."""
    import scipy.linalg as sla

    L = exp.model_learner
    W = exp.hybrid.walker
    model, data = L.model, L.model.createData()
    dt = exp.config.dt
    T = tied_legs(L, W.walker.legs)
    skip = set()
    for k in touchdowns:
        skip.update(range(int(k) - 2, int(k) + 3))
    rows, rhs = [], []
    for k in range(len(Tau)):
        if k in skip:
            continue
        q = pin.interpolate(model, Q[k], Q[k + 1], 0.5)
        v = 0.5 * (V[k] + V[k + 1])
        a = (V[k + 1] - V[k]) / dt
        N = sla.null_space(W.contact.jacobian(q, W.stance))
        Y = pin.computeJointTorqueRegressor(model, data, q, v, a)[:, L.columns]
        Phi = np.column_stack([Y @ T, L.tilt_column(q)])
        rows.append(N.T @ Phi)
        rhs.append(N.T @ (Tau[k] - pin.rnea(model, data, q, v, a)))
    if not rows:
        raise FeltoolError("learning.redesign: no control step of the cycle away from a "
                           "touchdown to identify the world from")
    Phi, r = np.vstack(rows), np.concatenate(rhs)
    H = Phi.T @ Phi
    lam = damping * float(np.mean(np.diag(H))) + 1e-300
    x = np.linalg.solve(H + lam * np.eye(len(H)), Phi.T @ r)
    return T @ x[:-1], float(x[-1])


def identified_urdf(robot, model: pin.Model, out: Path) -> Path:
    """A copy of ``robot``'s URDF in ``out`` whose links carry ``model``'s inertias (each
    joint's body on its child link, the other links of the body weightless): the identified
    world as a robot feltool builds from scratch (the mechanical phase's centre of mass, the
    contact model and RNEA all on it)."""
    import xml.etree.ElementTree as ET

    from feltool.files import atomic_write

    tree = ET.parse(robot.urdf_path)
    links = {el.get("name"): el for el in tree.getroot().iter("link")}
    first: dict[int, str] = {}
    for f in model.frames:
        if f.type == pin.FrameType.BODY and f.name in links:
            j = f.parentJoint
            el = links[f.name]
            for old in el.findall("inertial"):
                el.remove(old)
            if j in first or model.inertias[j].mass <= 0:
                continue
            first[j] = f.name
            inertia = f.placement.actInv(model.inertias[j])  # in the link's frame
            I = inertia.inertia
            node = ET.Element("inertial")
            ET.SubElement(node, "origin", xyz=" ".join(repr(float(x)) for x in inertia.lever),
                          rpy="0 0 0")
            ET.SubElement(node, "mass", value=repr(float(inertia.mass)))
            ET.SubElement(node, "inertia", ixx=repr(float(I[0, 0])), ixy=repr(float(I[0, 1])),
                          ixz=repr(float(I[0, 2])), iyy=repr(float(I[1, 1])), iyz=repr(float(I[1, 2])),
                          izz=repr(float(I[2, 2])))
            el.insert(0, node)
    path = out / Path(robot.urdf_path).name
    atomic_write(path, ET.tostring(tree.getroot(), encoding="unicode"))
    return path


@dataclass
class World:
    """What a design depends on that the learner identifies: total mass [kg], the centre of
    mass with every joint at zero [m] (in the base's frame) and the ground slope [rad]."""

    mass: float
    com: np.ndarray
    slope: float

    @classmethod
    def of(cls, model: pin.Model, slope: float) -> World:
        data = model.createData()
        com = pin.centerOfMass(model, data, pin.neutral(model)).copy()
        return cls(float(sum(model.inertias[j].mass for j in range(1, model.njoints))), com,
                   float(slope))


def blend_designs(old: dict, new: dict, cycles: int, period_unit_s: float | None = None
                  ) -> list[dict]:
    r"""The configs of the ``cycles`` cycles from the ``old`` design's reference to the ``new``
    one's (``learning.redesign.blend_cycles``): the k-th walks :math:`s = k/K` of the way, its
    period :math:`T_s = (1-s) T_0 + s T_1` [s] (a whole multiple of ``period_unit_s``) and each
    samples demo blended in phase :math:`\varphi \in [0, 1]`,
    :math:`q_s(\varphi) = (1-s) q_0(\varphi) + s q_1(\varphi)`,
    with the velocities and accelerations of that same curve in time
    (:math:`\dot q_s = ((1-s) T_0 \dot q_0 + s T_1 \dot q_1) / T_s`, :math:`\ddot q_s` alike
    with :math:`T^2`); the old demo is interpolated onto the new one's samples (cubic
    Hermite). The last is ``new``."""
    out = []
    T0, T1 = float(old["period_s"]), float(new["period_s"])
    for k in range(1, cycles):
        s = k / cycles
        Ts = (1 - s) * T0 + s * T1
        if period_unit_s is not None:
            Ts = round(Ts / period_unit_s) * period_unit_s
        cfg = copy.deepcopy(new)
        cfg["period_s"] = Ts
        for name, jc in new["joints"].items():
            d1 = jc.get("demo") if isinstance(jc, dict) else None
            d0 = (old["joints"].get(name) or {}).get("demo")
            if not (isinstance(d1, dict) and isinstance(d0, dict)
                    and d1.get("kind") == d0.get("kind") == "samples"):
                continue
            phi1 = np.linspace(0.0, 1.0, len(d1["q"]))
            phi0 = np.linspace(0.0, 1.0, len(d0["q"]))
            # the old demo in phase (d/dphi = T d/dt), on the new one's samples: positions and
            # velocities by cubic Hermite interpolation on their derivatives
            q0, v0, a0 = (np.asarray(d0[key], float) * T0**p for key, p in
                          (("q", 0), ("v", 1), ("a", 2)))
            old_phase = (CubicHermiteSpline(phi0, q0, v0)(phi1),
                         CubicHermiteSpline(phi0, v0, a0)(phi1), np.interp(phi1, phi0, a0))
            blended = {"kind": "samples"}
            for (key, power), x0 in zip((("q", 0), ("v", 1), ("a", 2)), old_phase):
                x1 = np.asarray(d1[key], float) * T1**power
                blended[key] = (((1 - s) * x0 + s * x1) / Ts**power).tolist()
            cfg["joints"][name]["demo"] = blended
        out.append(cfg)
    return out + [new]


@dataclass
class Redesigner:
    """Decides at each cycle's end whether to re-design and builds the new design's
    experiment (the module docstring). ``designs`` and ``failures`` are the summary's."""

    exp: Experiment
    seed: int
    #: ``theta_m -> (model, slope [rad])``: the world the re-design takes as identified
    #: (default :func:`identified_model` and the learner's slope; a benchmark's oracle)
    identify: Callable | None = None
    walked_s: float = 0.0
    designs: list[dict] = field(default_factory=list)
    failures: list[dict] = field(default_factory=list)
    #: the experiments of the blend's cycles still to walk (``blend_cycles``)
    pending: list[Experiment] = field(default_factory=list)

    def __post_init__(self):
        self.cfg = self.exp.config.learning.redesign
        self.learner = self.exp.model_learner
        self.legs = list(self.exp.hybrid.walker.walker.legs)
        self.known_mass = World.of(self.learner.model, 0.0).mass
        self.current = World.of(self.learner.model, self.learner.slope0)

    def due(self, world: World) -> bool:
        """Whether ``world`` differs from the current design's by more than the block's
        tolerances."""
        c = self.cfg
        return (abs(world.mass - self.current.mass) > c.min_mass_change * self.known_mass
                or abs(world.slope - self.current.slope) > c.min_slope_change_rad
                or float(np.linalg.norm((world.com - self.current.com)[[0, 2]]))
                > c.min_com_change_m)

    def after_cycle(self, cycle: int, exp: Experiment, theta_m: np.ndarray | None, out=None
                    ) -> Experiment | None:
        """After ``cycle`` of ``exp`` (the current design's experiment, its outcome ``out``):
        the new design's experiment when one is due and found, else None."""
        self.walked_s += exp.config.period_s
        if self.pending:  # the blend towards the last design goes on
            return self.pending.pop(0)
        if (theta_m is None or self.walked_s < self.cfg.every_s - 1e-9
                or len(self.failures) >= self.cfg.max_failures):
            return None
        if self.identify is not None:
            (model, slope), projected = self.identify(theta_m), 0
        elif self.cfg.identify == "motion":
            if out is None or getattr(out, "trace", None) is None:
                return None
            try:
                d_pi, d_alpha = identify_motion(exp, *cycle_measurements(exp, out))
            except FeltoolError:
                return None
            model, projected = identified_model(self.learner, d_pi)
            slope = self.learner.slope0 + d_alpha
        else:
            model, projected = identified_model(self.learner, theta_m, self.legs)
            slope = self.learner.slope(theta_m)
        world = World.of(model, slope)
        if not self.due(world):
            return None
        self.walked_s = 0.0
        t0 = time.perf_counter()
        entry = {"cycle": cycle, "mass_kg": world.mass, "com_m": world.com[[0, 2]].tolist(),
                 "slope_rad": world.slope, "projected_bodies": projected}
        try:
            # a physical walker's cycle: a whole number of samples per step
            unit = exp.config.walking.steps_per_cycle / exp.config.sim.rate_hz
            configs = blend_designs(exp.raw, self.design_config(model, world.slope),
                                    self.cfg.blend_cycles, unit)
            blend = [self._build(config) for config in configs]
        except FeltoolError as exc:  # IPOPT found no gait (or it is not a config): keep the old
            entry["reason"] = str(exc).splitlines()[0][:300]
            self.failures.append(entry)
            return None
        entry["seconds"] = time.perf_counter() - t0
        self.designs.append(entry)
        self.current = world
        self.pending = blend[1:]
        return blend[0]

    def _build(self, config: dict) -> Experiment:
        from feltool.runs.experiments import build_experiment

        return build_experiment(config, self.exp.source)

    def design_config(self, model: pin.Model, slope: float) -> dict:
        """The run's config with the demos of the gait designed on ``model`` and ``slope``
        [rad] with the block's options (the known model's gravity and robot unchanged)."""
        raw = copy.deepcopy(self.exp.raw)
        c = self.cfg
        key = (model.saveToString(), float(slope), c.model_dump_json(),
               json.dumps(raw, sort_keys=True, default=str))
        if key not in _DESIGNS:  # (deterministic: a seed that identified the same world)
            if len(_DESIGNS) >= 32:
                _DESIGNS.pop(next(iter(_DESIGNS)))
            _DESIGNS[key] = self.designed(raw, model, slope)
        closed = _DESIGNS[key]
        config = copy.deepcopy(raw)  # the run's config with the new design's demos
        config["period_s"] = closed["period_s"]
        for name, jc in closed.get("joints", {}).items():
            if isinstance(jc, dict) and "demo" in jc:
                config["joints"][name]["demo"] = copy.deepcopy(jc["demo"])
                if jc.get("follow_demo"):
                    config["joints"][name]["follow_demo"] = True
        return config

    def designed(self, raw: dict, model: pin.Model, slope: float) -> dict:
        """The config of the gait designed in the identified world (``model``'s inertias as a
        URDF, :func:`identified_urdf`; gravity tilted by ``slope``), its demos the loop's own
        periodic orbit there (:func:`feltool.gait.orbit.close_on_orbit`: on the collocation's
        knots the loop's feedback would be 0.5-0.8 N m), on the Python engine (the compiled
        one would need a build of this model), without the run's world changes (nor the run's
        ``success:``, whose ratio may be from one of them)."""
        from feltool.runs.experiments import build_experiment

        c = self.cfg
        cfg = copy.deepcopy(raw)
        cfg["backend"] = "pinocchio"
        for name in ("events", "plant", "success"):  # the run's world and its criterion
            cfg.pop(name, None)
        cfg.setdefault("learning", {})["redesign"] = None
        with tempfile.TemporaryDirectory(prefix="feltool-redesign-") as tmp:
            cfg["robot"] = str(identified_urdf(self.exp.robot, model, Path(tmp)))
            walker, settings = walker_from_raw(cfg, self.exp.source)
            spec = gait_spec(cfg, walker, settings, speed=c.speed_m_s,
                             step_length=c.step_length_m, duration=c.duration_s, slope=slope,
                             knots=c.knots, friction_margin=c.friction_margin,
                             normal_force_margin=c.normal_force_margin, torso=c.torso_rad)
            designed = gait_config(cfg, walker, design_gait(walker, spec), spec, settings)
            return close_on_orbit(designed, self.exp.source, build_experiment,
                                  steps=c.verify_steps)[0]

    def summary(self) -> dict:
        """``{designed, failed, designs, failures}`` for the seed's summary."""
        return {"designed": len(self.designs), "failed": len(self.failures),
                "designs": self.designs, "failures": self.failures}


__all__ = ["Redesigner", "World", "blend_designs", "identified_model", "physical_inertia"]
