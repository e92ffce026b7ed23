"""The env step through the lane (SIMD) kernel against the per-snake step
``stepping._step_one``, and the batch/single bit-for-bit equality with the
cases that leave the lanes: large angles and non-finite states."""

import numpy as np
import pytest

from snake_env.dynamics import compiled
from snake_env import physics
from snake_env.physics import stepping
from snake_env.envs import SnakeEnv
from snake_env.physics import AUX_FAILED, AUX_KINETIC, AUX_MOTOR_ENERGY, AUX_SIZE, AUX_WORK


def _states(rng, n, batch, bend=1.2):
    """Random states with joint angles up to +-bend (rad): beyond the default soft limit too."""
    theta = rng.uniform(-np.pi, np.pi, (batch, 1)) + np.cumsum(rng.uniform(-bend, bend, (batch, n)), axis=1)
    q = np.concatenate([theta, rng.normal(size=(batch, 2))], axis=1)
    return q, rng.normal(scale=0.5, size=(batch, 2)), rng.uniform(-1, 1, (batch, n - 1))


def _step_one_each(params, q, u, torques):
    """The per-snake kernel (libm sin/cos in RK4) row by row."""
    q, u = q.copy(), u.copy()
    obs = np.empty((q.shape[0], params.obs_size))
    aux = np.empty((q.shape[0], AUX_SIZE))
    for b in range(q.shape[0]):
        stepping._step_one(params.kernel_model, params.kernel_settings, q[b], u[b], torques[b], obs[b], aux[b])
    return q, u, obs, aux


@pytest.mark.parametrize("n, include_position", [(3, False), (8, True)])
def test_lane_step_agrees_with_the_per_snake_step(rng, n, include_position):
    env = SnakeEnv(n_links=n, exclude_current_positions_from_observation=not include_position)
    B = 2 * compiled.LANES + 3
    q, u, torques = _states(rng, n, B)
    torques *= env.max_torque
    q_lane, u_lane, obs_lane, aux_lane = physics.step(env.params, q, u, torques)
    q_ref, u_ref, obs_ref, aux_ref = _step_one_each(env.params, q, u, torques)
    assert not aux_lane[:, AUX_FAILED].any()
    np.testing.assert_allclose(q_lane, q_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u_lane, u_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(obs_lane, obs_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(aux_lane, aux_ref, rtol=1e-12, atol=1e-12)


def test_batch_rows_equal_single_steps_with_large_angles_and_failures(rng):
    """B = LANES + 5 snakes: one turned by 32000 full turns (stepped outside the
    lanes), one whose step overflows (undone and flagged). Every row equals the
    same snake stepped alone, bit for bit; the others are unaffected."""
    n = 5
    env = SnakeEnv(n_links=n)
    B = compiled.LANES + 5
    q, u, torques = _states(rng, n, B, bend=0.6)
    q[4, :n] += 2 * np.pi * 32_000
    u[9] = 1e150  # finite, but udot ~ u^2 overflows
    q_b, u_b, obs_b, aux_b = physics.step(env.params, q, u, torques)
    assert list(np.flatnonzero(aux_b[:, AUX_FAILED])) == [9]
    np.testing.assert_array_equal(q_b[9], q[9])
    np.testing.assert_array_equal(u_b[9], u[9])
    assert aux_b[9, AUX_WORK] == 0.0
    assert aux_b[9, AUX_MOTOR_ENERGY] == 0.0
    obs_before, _ = physics.observe(env.params, q[9], u[9])
    np.testing.assert_array_equal(obs_b[9], obs_before)
    for b in range(B):
        q_s, u_s, obs_s, aux_s = physics.step(env.params, q[b], u[b], torques[b])
        np.testing.assert_array_equal(q_s, q_b[b])
        np.testing.assert_array_equal(u_s, u_b[b])
        np.testing.assert_array_equal(obs_s, obs_b[b])
        np.testing.assert_array_equal(aux_s, aux_b[b])
    # the turned snake moved as the unturned one (up to the rounding of its angles, ~3e-11 rad)
    q_plain, u_plain, obs_plain, aux_plain = physics.step(env.params, q[4] - np.r_[np.full(n, 2 * np.pi * 32_000), 0, 0],
                                                          u[4], torques[4])
    np.testing.assert_allclose(u_b[4], u_plain, atol=1e-9)
    np.testing.assert_allclose(obs_b[4], obs_plain, atol=1e-9)
    assert aux_plain[AUX_MOTOR_ENERGY] > 0.0  # the per-snake kernel's motor energy, as the lanes'
    assert aux_b[4, AUX_MOTOR_ENERGY] == pytest.approx(aux_plain[AUX_MOTOR_ENERGY], rel=1e-8)


def test_observation_of_a_stepped_state_equals_observe(rng):
    """The step's observation and observe() of the resulting state agree bit for bit
    (same sin/cos, same angle wrapping)."""
    env = SnakeEnv(n_links=6, exclude_current_positions_from_observation=False)
    q, u, torques = _states(rng, 6, 7)
    q1, u1, obs, aux = physics.step(env.params, q, u, torques)
    obs_again, aux_again = physics.observe(env.params, q1, u1)
    np.testing.assert_array_equal(obs_again, obs)
    np.testing.assert_array_equal(aux_again[:, :2], aux[:, :2])  # CM position
    np.testing.assert_array_equal(aux_again[:, AUX_KINETIC], aux[:, AUX_KINETIC])


def test_threaded_lane_step_equals_the_serial_one(rng, monkeypatch):
    """The threaded kernel (used for very large batches: _step_lanes_parallel, each lane group finishing
    its own failed snakes) gives the serial kernels' bits (_step_lanes, then _finish_rows)."""
    env = SnakeEnv(n_links=4)
    p = env.params
    B = 3 * compiled.LANES + 1
    q, u, torques = _states(rng, 4, B, bend=0.6)
    outputs = []
    for threaded in (False, True):
        monkeypatch.setattr(stepping, "_threaded", lambda q, threaded=threaded: threaded)
        qk, uk = q.copy(), u.copy()
        obs, aux = np.empty((B, p.obs_size)), np.empty((B, AUX_SIZE))
        forces, scale = np.empty((B, 4)), np.empty(B)  # the wheel forces at the step's end too
        stepping.step_inplace(p, qk, uk, torques, obs, aux, forces, scale)
        outputs.append((qk, uk, obs, aux, forces, scale))
    assert (outputs[0][3][:, stepping.AUX_REFINEMENTS] > 0).any()  # some rows went through _finish_rows
    for serial, threaded in zip(*outputs):
        np.testing.assert_array_equal(threaded, serial)


@pytest.mark.parametrize("include_position", [False, True])
def test_reset_and_observe_in_lanes_equal_the_per_snake_kernels(rng, include_position):
    """reset() and observe() run in lanes (the step's lane helpers); every row, one beyond the lanes'
    angle range included (it goes to the per-snake kernel), equals _reset_one / _observe bit for bit."""
    env = SnakeEnv(n_links=5, exclude_current_positions_from_observation=not include_position)
    p = env.params
    B = compiled.LANES + 3
    noise = rng.uniform(-0.3, 0.3, (B, 7))
    noise[4, 2] = 2.0 * compiled.LANE_ANGLE_MAX
    q, u, obs, aux = physics.reset(p, noise)
    for b in range(B):
        qb, ub = np.empty(7), np.empty(2)
        obs_b, aux_b = np.empty(p.obs_size), np.empty(AUX_SIZE)
        stepping._reset_one(p.kernel_model, p.kernel_settings, noise[b], qb, ub, obs_b, aux_b)
        for got, want in ((q[b], qb), (u[b], ub), (obs[b], obs_b), (aux[b], aux_b)):
            np.testing.assert_array_equal(got, want)
    states, speeds, torques = _states(rng, 5, B)
    states[7, 0] = -2.0 * compiled.LANE_ANGLE_MAX
    obs, aux = physics.observe(p, states, speeds)
    obs_ref, aux_ref = np.empty_like(obs), np.full_like(aux, stepping.PENDING_ALONE)
    stepping._observe_alone(p.kernel_model, p.kernel_settings, states, speeds, obs_ref, aux_ref)
    np.testing.assert_array_equal(obs, obs_ref)
    np.testing.assert_array_equal(aux, aux_ref)
