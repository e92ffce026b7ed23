"""The wheels' lateral forces by the O(n) backward sweep against eq. 27's multipliers (Lagrange and
Newton–Euler), and against two invariants: the head's leftover pin force vanishes, and a snake at rest
without torques needs no grip."""

import numpy as np
import pytest

from snake_env.dynamics import SnakeModel, lagrange, newton_euler
from snake_env.dynamics.wheel_reactions import lateral_forces

from .conftest import random_model, random_state


@pytest.mark.parametrize("n", [2, 3, 5, 12, 30])
@pytest.mark.parametrize("damping", [False, True])
def test_backward_sweep_equals_the_multipliers_of_eq_27(rng, n, damping):
    model = random_model(rng, n, damping=damping)
    q, u, torques = random_state(rng, n, (16,))
    lam, head = lateral_forces(model, q, u, torques, return_residual=True)
    qdot = lagrange.consistent_qdot(model, q, u)
    for formulation in (lagrange, newton_euler):
        _, reference = formulation.qddot(model, q, qdot, torques, with_multipliers=True)
        scale = np.max(np.abs(reference), axis=-1, keepdims=True) + 1.0  # N
        assert np.max(np.abs(lam - reference) / scale) < 1e-9, formulation.__name__
    # the head's Newton equation is not used by the sweep: it closes only if udot solves eq. 8
    assert np.max(np.abs(head)) < 1e-9 * (1.0 + np.max(np.abs(lam)))
    assert np.array_equal(model.wheel_lateral_forces(q, u, torques), lam)


def test_a_snake_at_rest_without_torques_needs_no_grip_and_a_torque_needs_about_t_over_h(rng):
    model = SnakeModel(5)  # paper links: h = 0.1 m
    q = np.r_[np.zeros(5), 0.0, 0.0]
    assert np.allclose(model.wheel_lateral_forces(q, np.zeros(2), np.zeros(4)), 0.0, atol=1e-12)
    # one 1 N m joint torque from rest: the wheels react with forces of order T / h = 10 N, about the
    # link's weight m g = 9.81 N (12 N at the straight snake), so grip binds even slow gaits
    lam = model.wheel_lateral_forces(q, np.zeros(2), np.array([0.0, 1.0, 0.0, 0.0]))
    assert 5.0 < np.max(np.abs(lam)) < 20.0
    assert abs(np.sum(lam)) < 1e-9  # no net sideways force on a straight snake at rest: its momentum stays 0
