"""Serpenoid gait: the curve's math and the controller against the env's state."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import snake_env  # noqa: F401
from snake_env.controllers.serpenoid import SerpenoidController, SerpenoidParams, joint_slices, reference

ENV = "snake_env/Snake3-v2"


def test_reference_is_a_travelling_wave_and_its_rate_is_its_derivative():
    a, w, b, g = 0.7, 3.0, 0.9, 0.1
    t = np.linspace(0.0, 2.0, 41)
    ref, rate = reference(t, 4, a, w, b, g)
    assert ref.shape == (41, 4)
    # joint i lags joint 0 by i * beta: phi_i(t) = phi_0(t + i beta / omega)
    for i in range(4):
        shifted, _ = reference(t + i * b / w, 4, a, w, b, g)
        np.testing.assert_allclose(ref[:, i], shifted[:, 0], atol=1e-12)
    eps = 1e-6
    ahead, _ = reference(t + eps, 4, a, w, b, g)
    behind, _ = reference(t - eps, 4, a, w, b, g)
    np.testing.assert_allclose(rate, (ahead - behind) / (2 * eps), atol=1e-6)
    assert ref.max() <= a + g + 1e-12 and ref.min() >= -a + g - 1e-12


def test_joint_slices_match_the_env_observation():
    for include_position in (False, True):
        env = gym.make("snake_env/Snake5-v2", exclude_current_positions_from_observation=not include_position)
        obs, _ = env.reset(seed=3)
        for _ in range(5):
            obs, *_ = env.step(env.action_space.sample())
        q, u = env.unwrapped.state
        n = 5
        phi_slice, rate_slice = joint_slices(n, include_position)
        phi = np.diff(q[:n])
        np.testing.assert_allclose(obs[phi_slice], np.arctan2(np.sin(phi), np.cos(phi)), atol=1e-12)
        # joint rates from the model's link rates (eqs. 6-7)
        _, omega = env.unwrapped.model.link_velocities(q, u)
        np.testing.assert_allclose(obs[rate_slice], np.diff(omega), atol=1e-10)
        structure = env.unwrapped.observation_structure
        assert structure["joint_angles"] == phi_slice.stop - phi_slice.start
        assert structure["joint_rates"] == rate_slice.stop - rate_slice.start
        env.close()


def test_pd_torque_law_and_saturation():
    params = SerpenoidParams("pd", amplitude=0.5, frequency=2.0, phase_lag=0.3, kp=4.0, kd=0.5)
    controller = SerpenoidController(params, n_links=4, max_torque=2.0, dt=0.04)
    obs = np.zeros(2 * 4 + 2)
    phi_slice, rate_slice = joint_slices(4)
    obs[phi_slice] = [0.1, -0.2, 0.05]
    obs[rate_slice] = [0.3, 0.0, -0.4]
    action = controller.act(obs)
    ref, rate = reference(0.0, 3, 0.5, 2.0, 0.3, 0.0)
    expected = (4.0 * (ref[0] - obs[phi_slice]) + 0.5 * (rate[0] - obs[rate_slice])) / 2.0
    np.testing.assert_allclose(action, np.clip(expected, -1, 1), rtol=1e-6)
    # the clock advanced by dt; a large error saturates at the torque limit
    obs[phi_slice] = [3.0, -3.0, 3.0]
    action = controller.act(obs)
    np.testing.assert_array_equal(np.abs(action), [1.0, 1.0, 1.0])
    assert controller.time[0] == pytest.approx(0.08)
    controller.reset()
    assert controller.time[0] == 0.0


def test_torque_wave_ignores_state_and_mixed_batches():
    torque = SerpenoidParams("torque", amplitude=0.8, frequency=5.0, phase_lag=-1.0)
    pd = SerpenoidParams("pd", amplitude=0.8, frequency=5.0, phase_lag=-1.0, kp=1.0)
    controller = SerpenoidController([torque, pd], n_links=3, max_torque=1.0, dt=0.04, num_envs=2)
    obs = np.random.default_rng(0).normal(size=(2, 8))
    for _ in range(3):
        action = controller.act(obs)
    wave, _ = reference(0.08, 2, 0.8, 5.0, -1.0, 0.0)
    np.testing.assert_allclose(action[0], wave[0], rtol=1e-6)
    assert not np.allclose(action[1], wave[0])


@pytest.mark.parametrize("kwargs, pattern", [
    (dict(family="cpg", amplitude=1, frequency=1, phase_lag=0), "family must be one of"),
    (dict(family="torque", amplitude=-1, frequency=1, phase_lag=0), "amplitude must be >= 0"),
    (dict(family="pd", amplitude=1, frequency=1, phase_lag=0), "needs kp > 0"),
    (dict(family="torque", amplitude=1, frequency=math.nan, phase_lag=0), "frequency must be a finite number"),
])
def test_bad_parameters_raise(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        SerpenoidParams(**kwargs)


def test_params_round_trip_and_reject_unknown_keys():
    params = SerpenoidParams("pd", 1.0, 10.0, 0.5, 0.0, 1.0, 0.1)
    assert SerpenoidParams.from_dict(params.to_dict()) == params
    with pytest.raises(ValueError, match="unknown serpenoid parameter"):
        SerpenoidParams.from_dict({**params.to_dict(), "phase": 1.0})
