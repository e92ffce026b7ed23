"""The O(n) Kane sweep against the paper's O(n^2) recursion (eqs. 8-21)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snake_env.dynamics import SnakeModel
from snake_env.dynamics.kane_paper import mass_matrix

from .conftest import random_model, random_state

SIZES = [2, 3, 5, 8, 20, 50]


def relative_error(a, b):
    return np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)))


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("per_link", [False, True])
@pytest.mark.parametrize("damping", [False, True])
def test_kane_matches_paper_recursion_batched(rng, n, per_link, damping):
    model = random_model(rng, n, per_link=per_link, damping=damping)
    q, u, T = random_state(rng, n, batch=(7, 3))
    fast = model.udot(q, u, T, method="kane")
    paper = model.udot(q, u, T, method="kane_paper")
    assert fast.shape == (7, 3, 2)
    assert relative_error(fast, paper) < 1e-10


@pytest.mark.parametrize("n", SIZES)
def test_kane_matches_paper_recursion_unbatched(rng, n):
    model = random_model(rng, n)
    q, u, T = random_state(rng, n)
    fast = model.udot(q, u, T)
    assert fast.shape == (2,)
    assert relative_error(fast, model.udot(q, u, T, method="kane_paper")) < 1e-10


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 30), seed=st.integers(0, 2**32 - 1))
def test_kane_matches_paper_recursion_property(n, seed):
    rng = np.random.default_rng(seed)
    model = random_model(rng, n, damping=bool(seed % 2))
    q, u, T = random_state(rng, n, batch=(2,))
    assert relative_error(model.udot(q, u, T), model.udot(q, u, T, method="kane_paper")) < 1e-10


def test_batched_equals_rowwise(rng):
    model = random_model(rng, 6)
    q, u, T = random_state(rng, 6, batch=(5,))
    batched = model.udot(q, u, T)
    for i in range(5):
        np.testing.assert_allclose(batched[i], model.udot(q[i], u[i], T[i]), rtol=1e-13, atol=1e-13)


def test_batch_dimensions_broadcast(rng):
    """One state, many torque vectors: leading dimensions broadcast."""
    model = random_model(rng, 4)
    q, u, _ = random_state(rng, 4)
    T = rng.normal(size=(9, 3))
    out = model.udot(q, u, T)
    assert out.shape == (9, 2)
    np.testing.assert_allclose(out[4], model.udot(q, u, T[4]), rtol=1e-13)


@pytest.mark.parametrize("method", ["kane", "kane_paper"])
def test_float32_stays_float32(rng, method):
    model = random_model(rng, 5)
    q, u, T = random_state(rng, 5, batch=(3,))
    out32 = model.udot(q.astype(np.float32), u.astype(np.float32), T.astype(np.float32), method=method)
    assert out32.dtype == np.float32
    out64 = model.udot(q, u, T, method=method)
    np.testing.assert_allclose(out32, out64, rtol=1e-3, atol=1e-3)
    # mixing precisions promotes to float64
    assert model.udot(q.astype(np.float32), u, T, method=method).dtype == np.float64


@pytest.mark.parametrize("n", [2, 3, 7, 20])
def test_mass_matrix_symmetric_positive_definite_and_gives_kinetic_energy(rng, n):
    model = random_model(rng, n)
    q, u, _ = random_state(rng, n, batch=(10,))
    M = mass_matrix(model, q)
    np.testing.assert_allclose(M, np.swapaxes(M, -1, -2), rtol=0, atol=1e-14)
    assert np.all(np.linalg.eigvalsh(M) > 0)
    # K = 1/2 u^T M u (eq. 9) against the link-by-link sum (eq. 22)
    K_matrix = 0.5 * np.einsum("...i,...ij,...j->...", u, M, u)
    np.testing.assert_allclose(K_matrix, model.kinetic_energy(q, u), rtol=1e-12)


def test_udot_is_affine_in_torques_with_mass_matrix(rng):
    """udot(T) - udot(0) = M^-1 F(T): torques enter only through eq. 11."""
    n = 6
    model = random_model(rng, n)
    q, u, T = random_state(rng, n)
    delta = model.udot(q, u, T) - model.udot(q, u, np.zeros(n - 1))
    M = mass_matrix(model, q)
    V, W = model.link_velocities(q, u)
    # eq. 11 with domega/du from finite differences of the velocity map (linear in u)
    dW = np.stack([model.link_velocities(q, np.eye(2)[i])[1] for i in range(2)])  # (2, n)
    F = np.sum(T * (dW[:, 1:] - dW[:, :-1]), axis=-1)
    np.testing.assert_allclose(M @ delta, F, rtol=1e-10, atol=1e-12)


def test_two_link_closed_form():
    """n = 2, equal links, phi = 0 and u = 0, worked by hand from eqs. 6-11:
    V_2 = V_1 and omega_2 = -omega_1, so M = diag(2m, 2I) and F = (0, -2T):
    the joint cannot push a straight snake along its axis, the head turns at -T/I."""
    model = SnakeModel(2, mass=1.0, length=0.2, inertia=0.005)
    q = np.zeros(4)
    out = model.udot(q, np.zeros(2), np.array([1.0]))
    assert out[0] == pytest.approx(0.0, abs=1e-15)
    assert out[1] == pytest.approx(-2.0 / (2 * 0.005), rel=1e-12)
