"""The env's pure physics step (snake_env.physics.stepping) against the numpy
dynamics, the work-energy balance, and the batch/single equivalence."""

import numpy as np
import pytest

from snake_env.dynamics import rk4_step
from snake_env import physics
from snake_env.envs import SnakeEnv
from snake_env.physics import AUX_FAILED, AUX_KINETIC, AUX_WORK, AUX_X, AUX_Y
from snake_env.physics.config import IDEAL_PHYSICS as IDEAL  # ideal torque sources, unlimited grip


def _random_states(rng, n, batch):
    phi = rng.uniform(-1.2, 1.2, (batch, n - 1))
    theta = np.concatenate([rng.uniform(-np.pi, np.pi, (batch, 1)), np.zeros((batch, n - 1))], axis=1)
    theta[:, 1:] = theta[:, :1] + np.cumsum(phi, axis=1)
    q = np.concatenate([theta, rng.normal(size=(batch, 2))], axis=1)
    u = rng.normal(scale=0.5, size=(batch, 2))
    return q, u


@pytest.mark.parametrize("n", [3, 7])
@pytest.mark.parametrize("method", ["kane_paper", "kane"])
def test_one_env_step_equals_frame_skip_numpy_rk4_steps(rng, n, method):
    """No joint limits: the compiled env step and the numpy RK4 on another formulation agree."""
    env = SnakeEnv(n_links=n, joint_limit=None, joint_damping=0.05, wheel_damping=0.3, **IDEAL)
    q, u = _random_states(rng, n, 1)
    q, u = q[0], u[0]
    torques = rng.uniform(-1, 1, n - 1)
    q1, u1, obs, aux = physics.step(env.params, q, u, torques)
    qn, un, work = q.copy(), u.copy(), 0.0
    for _ in range(env.frame_skip):
        qn, un, w = rk4_step(env.model, qn, un, torques, env.sim_dt, method=method)
        work += w
    np.testing.assert_allclose(q1, qn, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u1, un, rtol=0, atol=1e-12)
    np.testing.assert_allclose(aux[AUX_WORK], work, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(aux[[AUX_X, AUX_Y]], env.model.center_of_mass(q1), atol=1e-14)
    np.testing.assert_allclose(aux[AUX_KINETIC], env.model.kinetic_energy(q1, u1), rtol=1e-12)


def test_step_is_pure_and_batch_rows_equal_single_steps_bit_for_bit(rng):
    env = SnakeEnv(n_links=6)
    q, u = _random_states(rng, 6, 5)
    q[:, 2] = q[:, 1] + 1.7  # one joint beyond the soft limit: the limit branch runs too
    torques = rng.uniform(-1, 1, (5, 5))
    q0, u0, t0 = q.copy(), u.copy(), torques.copy()
    qb, ub, obs_b, aux_b = physics.step(env.params, q, u, torques)
    np.testing.assert_array_equal(q, q0)
    np.testing.assert_array_equal(u, u0)
    np.testing.assert_array_equal(torques, t0)
    for b in range(5):
        qs, us, obs_s, aux_s = physics.step(env.params, q[b], u[b], torques[b])
        np.testing.assert_array_equal(qs, qb[b])
        np.testing.assert_array_equal(us, ub[b])
        np.testing.assert_array_equal(obs_s, obs_b[b])
        np.testing.assert_array_equal(aux_s, aux_b[b])


def test_step_rejects_bad_shapes():
    env = SnakeEnv(n_links=4)
    with pytest.raises(ValueError, match="q must have shape"):
        physics.step(env.params, np.zeros(5), np.zeros(2), np.zeros(3))
    with pytest.raises(ValueError, match="torques must have shape"):
        physics.step(env.params, np.zeros(6), np.zeros(2), np.zeros(4))
    with pytest.raises(ValueError, match="noise must have shape"):
        physics.reset(env.params, np.zeros(3))


def _energy_residual(n, sim_dt, frame_skip, steps, seed=0, **kwargs):
    """max over a batch of |K(T) - K(0) - W(0, T)| (J), with the work W of all loads
    integrated by the kernel: the continuous model keeps this exactly 0."""
    rng = np.random.default_rng(seed)
    env = SnakeEnv(n_links=n, sim_dt=sim_dt, frame_skip=frame_skip, **kwargs)
    q, u, _, aux = physics.reset(env.params, rng.uniform(-0.1, 0.1, (8, n + 2)))
    k0, work = aux[:, AUX_KINETIC].copy(), np.zeros(8)
    actions = rng.uniform(-1, 1, (steps, 8, n - 1))
    for a in actions:
        q, u, _, aux = physics.step(env.params, q, u, env.max_torque * a)
        work += aux[:, AUX_WORK]
        # without joint limits (paper model) random torques can fold a joint: that step is
        # refused (state kept, work 0), which keeps the balance; no other failure may occur
        assert set(aux[:, AUX_FAILED]) <= {0.0, float(physics.FAIL_FOLD)}
    return np.max(np.abs(aux[:, AUX_KINETIC] - k0 - work)), np.max(aux[:, AUX_KINETIC])


def test_energy_balance_of_the_paper_model_at_the_default_step():
    """paper_model=True, sim_dt = 0.01 s: 250 random-action env steps (10 s)."""
    residual, k_max = _energy_residual(5, 0.01, 4, 250, paper_model=True)
    assert k_max > 1.0  # the undamped snake really is driven hard
    assert residual < 1e-3 * k_max  # measured 7e-3 J of 13.5 J


def test_energy_residual_converges_at_fourth_order():
    # plain RK4 with the energy test off, so no step is refined: the order of the method itself
    plain = dict(paper_model=True, integrator="rk4", energy_tolerance=1.0)
    # (40 steps: with 100, a joint that folds at different steps in the two runs mixes in)
    coarse, _ = _energy_residual(5, 0.01, 4, 40, **plain)
    fine, _ = _energy_residual(5, 0.005, 8, 40, **plain)
    assert fine < coarse / 10.0  # RK4: ~16x for half the step


def test_damping_dissipates():
    """Damped snake, no torques, no limits: K decays and the loads' work is negative
    (for 30 steps: coasting on, a joint of this snake folds at step 34, a sim_failure)."""
    env = SnakeEnv(n_links=5, joint_limit=None, **IDEAL)
    q, u, _, aux = physics.reset(env.params, np.array([0.1, -0.2, 0.3, -0.1, 0.2, 1.0, 2.0]))
    k = [aux[AUX_KINETIC]]
    for _ in range(30):
        q, u, _, aux = physics.step(env.params, q, u, np.zeros(4))
        assert aux[AUX_WORK] < 0.0
        k.append(aux[AUX_KINETIC])
    assert np.all(np.diff(k) < 0.0)


def test_soft_joint_limit_holds_under_full_torque():
    """Full torque on every joint for 4 s: the joints bend to about the limit and stop
    (static overshoot max_torque / stiffness), while without limits they fold over."""
    limited = SnakeEnv(n_links=4, **IDEAL)
    free = SnakeEnv(n_links=4, joint_limit=None, **IDEAL)
    results = []
    for env in (limited, free):
        q, u, _, _ = physics.reset(env.params, np.zeros(6) + 1e-3)
        peak = 0.0
        for _ in range(100):
            q, u, _, _ = physics.step(env.params, q, u, np.full(3, env.max_torque))
            peak = max(peak, np.max(np.abs(np.diff(q[:4]))))
        results.append(peak)
    overshoot = limited.max_torque / 20.0  # rad, torque / DEFAULT_LIMIT_STIFFNESS
    assert np.pi / 2 < results[0] < np.pi / 2 + 4 * overshoot
    assert results[1] > np.pi / 2 + 4 * overshoot
