"""The paper's simulations (Tables II and III, section VI.3) with RK4 at dt = 1 ms.

S(t) = K(t) - integral of sum T_k (omega_{k+1} - omega_k) dt is constant in the
continuous model; its drift measures integration and formulation error. The
CM of every link must also move along its link (no side slip).
"""

import numpy as np
import pytest

from snake_env.dynamics import SnakeModel, simulate

DT = 1e-3  # s


def table2_initial(n):
    """q_k = pi (-1)^k / 6, x = y = 0, u0 = 0 (Table II)."""
    q0 = np.zeros(n + 2)
    q0[:n] = np.pi * (-1.0) ** np.arange(1, n + 1) / 6
    return q0, np.zeros(2)


def table2_torques(n):
    """T_k = sin(t) / (n - k) N m, k = 1..n-1 (Table II)."""
    k = np.arange(1, n)
    return lambda t, q, u: np.sin(t) / (n - k)


def assert_no_side_slip(model, sim):
    """Finite differences of each CM position stay parallel to the link."""
    n = model.n_links
    pos = model.cm_positions(sim.q)  # (T, n, 2)
    # fourth-order central stencil: truncation O(dt^4), far below any real slip
    vel = (-pos[4:] + 8 * pos[3:-1] - 8 * pos[1:-3] + pos[:-4]) / (12 * DT)
    theta = sim.q[2:-2, :n]
    lateral = -np.sin(theta) * vel[..., 0] + np.cos(theta) * vel[..., 1]
    speed = np.max(np.abs(vel))
    assert speed > 1e-3  # the snake does move
    assert np.max(np.abs(lateral)) < 1e-6 * max(speed, 1.0)


@pytest.mark.parametrize("n", [3, 12, 20])
def test_table2_runs_conserve_energy_function(n):
    model = SnakeModel(n)
    q0, u0 = table2_initial(n)
    sim = simulate(model, q0, u0, table2_torques(n), t_end=10.0, dt=DT)
    S = sim.energy_function
    assert sim.t[-1] == pytest.approx(10.0)
    assert np.all(np.isfinite(sim.q)) and np.all(np.isfinite(sim.u))
    assert np.max(sim.kinetic_energy) > 1e-3  # the torques do work
    assert np.max(np.abs(S - S[0])) <= 1e-6
    assert_no_side_slip(model, sim)


def test_table3_run_conserves_energy_function():
    n = 30
    model = SnakeModel(n)
    sim = simulate(model, np.zeros(n + 2), np.zeros(2), lambda t, q, u: np.ones(n - 1), t_end=100.0, dt=DT)
    S = sim.energy_function
    assert np.all(np.isfinite(sim.q))
    assert np.max(sim.kinetic_energy) > 1e-2
    assert np.max(np.abs(S - S[0])) <= 1e-6
    assert_no_side_slip(model, sim)


def test_table2_run_agrees_between_compiled_and_numpy_paths():
    """simulate() uses the compiled kernel for float64 "kane" and numpy for
    "kane_paper": both trajectories must coincide."""
    n = 5
    model = SnakeModel(n)
    q0, u0 = table2_initial(n)
    fast = simulate(model, q0, u0, table2_torques(n), t_end=1.0, dt=DT, method="kane")
    paper = simulate(model, q0, u0, table2_torques(n), t_end=1.0, dt=DT, method="kane_paper")
    np.testing.assert_allclose(fast.q, paper.q, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fast.u, paper.u, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fast.work, paper.work, rtol=1e-10, atol=1e-12)


def test_float32_run_stays_finite_and_close_to_float64():
    n = 5
    model = SnakeModel(n)
    q0, u0 = table2_initial(n)
    single = simulate(model, q0, u0, table2_torques(n), t_end=1.0, dt=DT, dtype=np.float32)
    double = simulate(model, q0, u0, table2_torques(n), t_end=1.0, dt=DT)
    assert single.q.dtype == np.float32 and single.u.dtype == np.float32
    assert np.all(np.isfinite(single.q)) and np.all(np.isfinite(single.u))
    np.testing.assert_allclose(single.q, double.q, atol=1e-3)
    np.testing.assert_allclose(single.u, double.u, atol=1e-3)


def test_batched_simulation_equals_separate_runs():
    n = 4
    model = SnakeModel(n, wheel_damping=0.3, joint_damping=0.05)
    rng = np.random.default_rng(3)
    q0 = rng.normal(scale=0.3, size=(3, n + 2))
    u0 = rng.normal(size=(3, 2))
    amplitudes = np.array([0.5, 1.0, -0.7])[:, None]

    def torques(t, q, u):
        return amplitudes * np.sin(2 * t + np.arange(n - 1))

    batch = simulate(model, q0, u0, torques, t_end=0.5, dt=DT)
    for i in range(3):
        one = simulate(model, q0[i], u0[i], lambda t, q, u, i=i: torques(t, q, u)[i], t_end=0.5, dt=DT)
        np.testing.assert_allclose(batch.q[:, i], one.q, rtol=1e-12, atol=1e-12)
    # with damping, S = K - (work of torques and damping) is still conserved
    S = batch.energy_function
    assert np.max(np.abs(S - S[0])) < 1e-8
