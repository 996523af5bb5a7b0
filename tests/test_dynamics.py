"""Pinocchio's known models against the thesis's closed form (eq. A.1) and finite differences."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from feltool.dynamics.interface import make_dynamics
from feltool.robot.robot import load_robot

# Table A.1 and A.2: (m, l, l_g) of both links.
ARMS = {"two_link_arm": (1.0, 1.0, 0.5), "two_link_human_arm": (2.0, 0.5, 0.25)}
G = 9.8


def rnea_eq_a1(m, l, lg, q, dq, ddq):
    """Eq. A.1 as printed, with I_i = m_i l_i^2 / 3 used as the inertia about the COM."""
    m1 = m2 = m
    l1 = l
    lg1 = lg2 = lg
    I1 = I2 = m * l * l / 3.0
    C1, C2, S2, C12 = np.cos(q[0]), np.cos(q[1]), np.sin(q[1]), np.cos(q[0] + q[1])
    u1 = ((m1 * lg1**2 + I1 + m2 * (l1**2 + lg2**2 + 2 * l1 * lg2 * C2) + I2) * ddq[0]
          + (m2 * (lg2**2 + l1 * lg2 * C2) + I2) * ddq[1]
          - m2 * l1 * lg2 * S2 * (2 * dq[0] * dq[1] + dq[1] ** 2)
          + m1 * G * lg1 * C1 + m2 * G * (l1 * C1 + lg2 * C12))
    u2 = ((m2 * (lg2**2 + l1 * lg2 * C2) + I2) * ddq[0] + (m2 * lg2**2 + I2) * ddq[1]
          + m2 * l1 * lg2 * S2 * dq[0] ** 2 + m2 * G * lg2 * C12)
    return np.array([u1, u2])


@pytest.mark.parametrize("name", sorted(ARMS))
def test_rnea_matches_thesis_eq_a1(name, rng):
    robot = load_robot(name)
    robot.set_gravity(G)
    dyn = make_dynamics(robot.model)
    for _ in range(200):
        q, dq, ddq = rng.uniform(-np.pi, np.pi, 2), rng.normal(0, 3, 2), rng.normal(0, 10, 2)
        np.testing.assert_allclose(dyn.inverse(q, dq, ddq), rnea_eq_a1(*ARMS[name], q, dq, ddq),
                                   rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", sorted(ARMS))
def test_forward_inverts_inverse(name, rng):
    robot = load_robot(name)
    robot.set_gravity(G)
    dyn = make_dynamics(robot.model)
    for _ in range(50):
        q, dq, ddq = rng.uniform(-3, 3, 2), rng.normal(0, 3, 2), rng.normal(0, 10, 2)
        np.testing.assert_allclose(dyn.forward(q, dq, dyn.inverse(q, dq, ddq)), ddq, atol=1e-9)


@pytest.mark.parametrize("spec", ["two_link_arm", "example-robot-data:ur5"])
def test_rnea_derivatives_match_finite_differences(spec, rng):
    robot = load_robot(spec)
    robot.set_gravity(G)
    dyn = make_dynamics(robot.model)
    n, eps = robot.model.nv, 1e-6
    for _ in range(5):
        q, v, a = rng.uniform(-2, 2, n), rng.normal(0, 1, n), rng.normal(0, 1, n)
        dq, dv, M = dyn.inverse_derivatives(q, v, a)
        for analytic, which in ((dq, 0), (dv, 1), (M, 2)):
            fd = np.zeros((n, n))
            for j in range(n):
                e = np.zeros(n)
                e[j] = eps
                args_p, args_m = [q, v, a], [q, v, a]
                args_p[which] = args_p[which] + e
                args_m[which] = args_m[which] - e
                fd[:, j] = (dyn.inverse(*args_p) - dyn.inverse(*args_m)) / (2 * eps)
            np.testing.assert_allclose(analytic, fd, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_results_are_copies_not_views(rng):
    """pin.rnea returns a view of data.tau; the backend must hand out copies."""
    robot = load_robot("two_link_arm")
    dyn = make_dynamics(robot.model)
    first = dyn.inverse(np.zeros(2), np.zeros(2), np.zeros(2))
    kept = first.copy()
    dyn.inverse(np.ones(2), np.ones(2), np.ones(2))
    np.testing.assert_array_equal(first, kept)
    first = dyn.forward(np.zeros(2), np.zeros(2), np.zeros(2))  # (ABA, called directly)
    kept = first.copy()
    dyn.forward(np.ones(2), np.ones(2), np.ones(2))
    np.testing.assert_array_equal(first, kept)


def test_gravity_is_set_in_one_place():
    robot = load_robot("two_link_arm")
    assert np.isclose(robot.model.gravity.linear[2], -9.81)  # Pinocchio's default
    robot.set_gravity(9.8)
    np.testing.assert_allclose(robot.model.gravity.linear, [0, 0, -9.8])
    robot.set_gravity([0.0, 1.0, -9.0])
    np.testing.assert_allclose(robot.model.gravity.linear, [0, 1, -9])


def test_thesis_angle_convention():
    """q1 is link 1's angle from the horizontal, q2 relative: q1 + q2 = pi/2 is link 2 vertical."""
    robot = load_robot("two_link_arm")
    model, data = robot.model, robot.model.createData()
    q = np.array([np.pi / 3, np.pi / 2 - np.pi / 3])
    pin.framesForwardKinematics(model, data, q)
    elbow = data.oMf[model.getFrameId("link2")].translation
    tip = data.oMf[model.getFrameId("tip")].translation
    np.testing.assert_allclose(elbow, [np.cos(np.pi / 3), 0, np.sin(np.pi / 3)], atol=1e-12)
    np.testing.assert_allclose(tip - elbow, [0, 0, 1.0], atol=1e-12)


def test_pinocchio_dynamics_pickle_for_process_pools(rng):
    """The loops call ABA directly (a partial of pin.aba on the dynamics' data); a pickled copy
    gets its own data and the same numbers."""
    import pickle

    dyn = make_dynamics(load_robot("two_link_arm").model, "pinocchio")
    copy = pickle.loads(pickle.dumps(dyn))
    assert copy.data is not dyn.data
    for _ in range(5):
        q, v, tau = (rng.normal(size=2) for _ in range(3))
        np.testing.assert_array_equal(copy.forward(q, v, tau), dyn.forward(q, v, tau))
        np.testing.assert_array_equal(copy.forward(q, v, tau), pin.aba(dyn.model, dyn.data, q, v, tau))
