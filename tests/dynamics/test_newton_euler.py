"""Walker-Orin Newton-Euler formulation: cross-checked against Lagrange's pieces."""

import numpy as np
import pytest

from snake_env.dynamics import lagrange, newton_euler

from .conftest import random_model, random_state


@pytest.mark.parametrize("n", [2, 3, 6, 11, 20])
def test_composite_inertia_equals_eq25(rng, n):
    """Composite-rigid-body M equals the Jacobian-sum M of eq. 25."""
    model = random_model(rng, n)
    q, _, _ = random_state(rng, n, batch=(3,))
    np.testing.assert_allclose(newton_euler.inertia_matrix(model, q), lagrange.inertia_matrix(model, q),
                               rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("n", [2, 5, 13, 20])
def test_recursive_bias_equals_lagrange_bias(rng, n):
    """Recursive Newton-Euler with qddot = 0 equals B from differentiating eq. 22,
    for arbitrary (not only consistent) qdot."""
    model = random_model(rng, n)
    q, _, _ = random_state(rng, n, batch=(3,))
    qdot = rng.normal(size=(3, n + 2))
    np.testing.assert_allclose(newton_euler.bias_vector(model, q, qdot), lagrange.bias_vector(model, q, qdot),
                               rtol=1e-10, atol=1e-12)


def test_bias_is_quadratic_velocity_product(rng):
    """B(q, qdot) holds only velocity products: zero at rest, quadratic in qdot,
    and nonzero for a moving chain (it accelerates the free chain)."""
    n = 4
    model = random_model(rng, n)
    q, _, _ = random_state(rng, n)
    qdot = rng.normal(size=n + 2)
    B = newton_euler.bias_vector(model, q, qdot)
    M = newton_euler.inertia_matrix(model, q)
    np.testing.assert_array_equal(newton_euler.bias_vector(model, q, np.zeros(n + 2)), 0.0)
    assert np.linalg.norm(np.linalg.solve(M, -B)) > 1e-3  # velocity products do accelerate the free chain
    # B is quadratic in qdot
    np.testing.assert_allclose(newton_euler.bias_vector(model, q, 2 * qdot), 4 * B, rtol=1e-12)


def test_multipliers_agree_between_lagrange_and_newton_euler(rng):
    """Same constraint forces lambda from both formulations."""
    n = 7
    model = random_model(rng, n, damping=True)
    q, u, torques = random_state(rng, n, batch=(2,))
    qdot = model.qdot(q, u)
    qdd_l, lam_l = lagrange.qddot(model, q, qdot, torques, with_multipliers=True)
    qdd_n, lam_n = newton_euler.qddot(model, q, qdot, torques, with_multipliers=True)
    np.testing.assert_allclose(qdd_n, qdd_l, atol=1e-9)
    np.testing.assert_allclose(lam_n, lam_l, atol=1e-8)


def test_float32_stays_float32(rng):
    n = 5
    model = random_model(rng, n)
    q, u, torques = (a.astype(np.float32) for a in random_state(rng, n, batch=(2,)))
    assert model.udot(q, u, torques, method="newton_euler").dtype == np.float32


def test_single_state_without_batch(rng):
    n = 4
    model = random_model(rng, n, damping=True)
    q, u, torques = random_state(rng, n)
    out = model.udot(q, u, torques, method="newton_euler")
    assert out.shape == (2,)
    np.testing.assert_allclose(out, model.udot(q, u, torques, method="kane_paper"), atol=1e-10)
