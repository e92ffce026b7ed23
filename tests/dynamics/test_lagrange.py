"""Lagrange's multiplier formulation (eqs. 22-27) against Kane and physics."""

import numpy as np
import pytest

from snake_env.dynamics import SnakeModel, lagrange, simulate
from snake_env.dynamics.multiplier_sim import constraint_residual, kinetic_energy, simulate_multipliers

from .conftest import random_model, random_state

METHODS = ("kane", "kane_paper", "lagrange", "newton_euler")


@pytest.mark.parametrize("n", [2, 3, 4, 7, 12, 20])
@pytest.mark.parametrize("damping", [False, True])
def test_four_formulations_agree(rng, n, damping):
    """All four formulations give the same udot on random consistent states."""
    model = random_model(rng, n, per_link=True, damping=damping)
    q, u, torques = random_state(rng, n, batch=(5,))
    results = {method: model.udot(q, u, torques, method=method) for method in METHODS}
    scale = 1.0 + np.max(np.abs(results["kane_paper"]))
    for method in METHODS:
        assert results[method].shape == (5, 2)
        np.testing.assert_allclose(results[method], results["kane_paper"], rtol=0, atol=1e-9 * scale,
                                   err_msg=method)


def test_inertia_matrix_gives_kinetic_energy(rng):
    """1/2 qdot^T M qdot (eq. 25) equals K of eq. 22 at a consistent state, and M is SPD."""
    n = 9
    model = random_model(rng, n)
    q, u, _ = random_state(rng, n, batch=(4,))
    qdot = model.qdot(q, u)
    np.testing.assert_allclose(kinetic_energy(model, q, qdot), model.kinetic_energy(q, u), rtol=1e-12)
    M = lagrange.inertia_matrix(model, q)
    np.testing.assert_allclose(M, np.swapaxes(M, -1, -2), atol=1e-15)
    assert np.all(np.linalg.eigvalsh(M) > 0)


def test_inertia_matrix_is_hessian_of_kinetic_energy(rng):
    """M(i, j) = d^2 K / d qdot_i d qdot_j (eq. 25), by finite differences of K(qdot)."""
    n = 5
    model = random_model(rng, n)
    q, _, _ = random_state(rng, n)
    M = lagrange.inertia_matrix(model, q)
    eps = 1e-3
    eye = np.eye(n + 2)
    K = lambda qd: kinetic_energy(model, q, qd)  # noqa: E731  (K is quadratic: central differences are exact)
    base = rng.normal(size=n + 2)
    H = np.array([[(K(base + eps * (eye[i] + eye[j])) - K(base + eps * (eye[i] - eye[j]))
                    - K(base - eps * (eye[i] - eye[j])) + K(base - eps * (eye[i] + eye[j]))) / (4 * eps ** 2)
                   for j in range(n + 2)] for i in range(n + 2)])
    np.testing.assert_allclose(H, M, atol=1e-8)


def test_bias_is_velocity_product_term(rng):
    """B(q, qdot) from eq. 24: with qddot from M^-1 (Q - B) the energy rate equals Q . qdot
    when no constraint acts (free chain), i.e. qdot^T B = 1/2 qdot^T Mdot qdot."""
    n = 6
    model = random_model(rng, n)
    q, _, _ = random_state(rng, n)
    qdot = rng.normal(size=n + 2)
    B = lagrange.bias_vector(model, q, qdot)
    dt = 1e-6
    Mdot = (lagrange.inertia_matrix(model, q + dt * qdot) - lagrange.inertia_matrix(model, q - dt * qdot)) / (2 * dt)
    np.testing.assert_allclose(qdot @ B, 0.5 * qdot @ Mdot @ qdot, rtol=1e-6)


def test_constraints_hold_at_consistent_state_and_are_kept(rng):
    """A qdot = 0 for qdot from (q, u); the solved qddot satisfies A qddot + Adot qdot = 0."""
    n = 8
    model = random_model(rng, n, damping=True)
    q, u, torques = random_state(rng, n, batch=(3,))
    qdot = model.qdot(q, u)
    _, h, _, _, _ = model.parameters()
    e, e_perp = lagrange.unit_vectors(q[..., :n])
    c = lagrange.lever_arms(h)
    A = lagrange.constraint_matrix(c, e_perp)
    Adot = lagrange.constraint_matrix_rate(c, e, e_perp, qdot, n)
    np.testing.assert_allclose(lagrange.matvec(A, qdot), 0.0, atol=1e-13)
    qdd = lagrange.qddot(model, q, qdot, torques)
    np.testing.assert_allclose(lagrange.matvec(A, qdd) + lagrange.matvec(Adot, qdot), 0.0, atol=1e-10)
    # Adot is the time derivative of A along qdot (finite difference)
    dt = 1e-6
    A_plus = lagrange.constraint_matrix(c, lagrange.unit_vectors(q[..., :n] + dt * qdot[..., :n])[1])
    A_minus = lagrange.constraint_matrix(c, lagrange.unit_vectors(q[..., :n] - dt * qdot[..., :n])[1])
    np.testing.assert_allclose((A_plus - A_minus) / (2 * dt), Adot, atol=1e-7)


def test_lu_solve_matches_numpy(rng):
    """The written-out triangular decomposition solves eq. 27 like LAPACK."""
    n = 10
    model = random_model(rng, n)
    q, u, torques = random_state(rng, n, batch=(2,))
    qdot = model.qdot(q, u)
    _, h, _, _, _ = model.parameters()
    e, e_perp = lagrange.unit_vectors(q[..., :n])
    c = lagrange.lever_arms(h)
    M = lagrange.inertia_matrix(model, q)
    A = lagrange.constraint_matrix(c, e_perp)
    system, rhs = lagrange.augmented_system(M, A, rng.normal(size=(2, n + 2)), rng.normal(size=(2, n)))
    np.testing.assert_allclose(lagrange.lu_solve(system, rhs), np.linalg.solve(system, rhs[..., None])[..., 0],
                               rtol=1e-9, atol=1e-9)


def test_float32_stays_float32(rng):
    n = 6
    model = random_model(rng, n, damping=True)
    q, u, torques = (a.astype(np.float32) for a in random_state(rng, n, batch=(2,)))
    out = model.udot(q, u, torques, method="lagrange")
    assert out.dtype == np.float32
    ref = model.udot(q.astype(np.float64), u.astype(np.float64), torques.astype(np.float64), method="kane")
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-3 * (1 + np.abs(ref).max()))
    qd = model.qdot(q, u)
    assert lagrange.qddot(model, q, qd, torques, baumgarte=5.0).dtype == np.float32


def test_unknown_method_rejected():
    with pytest.raises(ValueError, match="method"):
        SnakeModel(3).udot(np.zeros(5), np.zeros(2), np.zeros(2), method="hamilton")


# ---------------------------------------------------------------- q-space simulator
def _paper_start(n):
    model = SnakeModel(n)
    q0 = np.zeros(n + 2)
    q0[:n] = np.pi * (-1.0) ** np.arange(1, n + 1) / 6
    return model, q0


@pytest.mark.parametrize("method", ["lagrange", "newton_euler"])
def test_q_space_simulation_tracks_kane(method):
    """Short Table II run: the q-space multiplier simulation follows Kane's u-space one,
    its energy function is nearly constant and the constraint residual stays small."""
    n = 5
    model, q0 = _paper_start(n)
    u0 = np.array([0.3, -0.5])
    torque = lambda t, q, v: np.sin(t) / (n - np.arange(1, n))  # noqa: E731  (Table II)
    ref = simulate(model, q0, u0, torque, 1.0, 0.005, method="kane")
    run = simulate_multipliers(model, q0, model.qdot(q0, u0), torque, 1.0, 0.005, method=method)
    np.testing.assert_allclose(run.q, ref.q, atol=1e-5)
    np.testing.assert_allclose(run.u(), ref.u, atol=1e-5)
    S = run.energy_function
    assert np.max(np.abs(S - S[0])) < 1e-6 * (1 + np.max(run.kinetic_energy))
    assert np.max(run.constraint_residual) < 1e-5
    # kinetic energy of eq. 22 at the consistent start equals Kane's
    np.testing.assert_allclose(run.kinetic_energy[0], ref.kinetic_energy[0], rtol=1e-12)


def test_baumgarte_reduces_constraint_drift():
    """A drifted start (A qdot != 0) is pulled back to the constraint manifold by beta > 0
    and not by the paper's beta = 0."""
    n = 4
    model, q0 = _paper_start(n)
    qdot0 = model.qdot(q0, np.array([0.5, 0.2])) + 1e-3  # violates A qdot = 0
    torque = lambda t, q, v: np.ones(n - 1)  # noqa: E731
    plain = simulate_multipliers(model, q0, qdot0, torque, 0.5, 0.005)
    stabilized = simulate_multipliers(model, q0, qdot0, torque, 0.5, 0.005, baumgarte=20.0)
    r0 = constraint_residual(model, q0, qdot0)
    assert plain.constraint_residual[-1] > 0.5 * r0
    assert stabilized.constraint_residual[-1] < 0.01 * r0


def test_multiplier_sim_float32():
    n = 4
    model, q0 = _paper_start(n)
    run = simulate_multipliers(model, q0, model.qdot(q0, np.zeros(2)), lambda t, q, v: np.ones(n - 1), 0.05, 0.01,
                               dtype=np.float32)
    assert run.q.dtype == np.float32 and run.qdot.dtype == np.float32


@pytest.mark.parametrize("kwargs, match", [
    (dict(method="kane"), "method"),
    (dict(t_end=-1.0), "t_end"),
    (dict(dt=0.0), "dt"),
    (dict(baumgarte=-1.0), "baumgarte"),
    (dict(dtype=np.int32), "dtype"),
    (dict(torque_fn=3), "torque_fn"),
    (dict(q0=np.zeros(3)), "q0"),
    (dict(t_end=0.001), "t_end"),
])
def test_multiplier_sim_rejects_bad_input(kwargs, match):
    n = 3
    model = SnakeModel(n)
    args = dict(q0=np.zeros(n + 2), qdot0=np.zeros(n + 2), torque_fn=lambda t, q, v: np.zeros(n - 1),
                t_end=0.1, dt=0.01)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        simulate_multipliers(model, **args)
