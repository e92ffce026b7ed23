"""Serpenoid gait: the curve's math, the controller against the env's state, the search."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import snake_env  # noqa: F401
from snake_env.agents import search
from snake_env.agents.serpenoid import SerpenoidController, SerpenoidParams, joint_slices, reference

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


def test_rollout_speed_is_the_cm_displacement_rate():
    """The search score (mean of info x_velocity in the vector env) equals the
    single env's CM x displacement over the episode time."""
    params = SerpenoidParams("torque", amplitude=0.9, frequency=10.0, phase_lag=0.1)
    steps = 150
    speed = search.rollout_speeds(ENV, {}, [params], steps, seed=5)[0]
    env = gym.make(ENV)
    controller = SerpenoidController(params, 3, env.unwrapped.max_torque, env.unwrapped.dt)
    obs, info = env.reset(seed=5)
    x0 = info["x_position"]
    for _ in range(steps):
        obs, _, _, _, info = env.step(controller.act(obs))
    assert speed == pytest.approx((info["x_position"] - x0) / (steps * env.unwrapped.dt), rel=1e-9)
    assert speed > 0.1  # a travelling torque wave propels the 3-link snake
    env.close()


def test_search_returns_its_best_scored_gait(tmp_path):
    result = search.search(ENV, population=8, generations=1, elite=2, search_steps=40, repeats=2, final_steps=60,
                           final_episodes=3, finalists=2, seed=1)
    assert result.evaluated == 2 * 2 * 8 * 2 + 2 * 2 * 3
    # the winner is the best mean of the re-scoring (reproducible from the seed)
    again = search.search(ENV, population=8, generations=1, elite=2, search_steps=40, repeats=2, final_steps=60,
                          final_episodes=3, finalists=2, seed=1)
    assert again.params == result.params and again.speed == result.speed
    scores = search.final_scores(ENV, {}, [result.params], 60, 3, seed=1 + 1000)
    assert scores.shape == (3, 1) and np.all(np.isfinite(scores))
    path = tmp_path / "serpenoid.yaml"
    search.save_result(ENV, {}, result, path)
    params, env_kwargs = search.load_params(ENV, path)
    assert params == result.params and env_kwargs == {}
    with pytest.raises(ValueError, match="no serpenoid gait for env"):
        search.load_params("snake_env/Snake30-v2", path)


def test_shipped_gaits_reproduce_their_recorded_speed():
    """configs/serpenoid.yaml: the stored gaits reproduce, from starts the
    search never saw, a mean forward speed close to the one it recorded."""
    gaits = search.load_gaits()
    assert "snake_env/Snake3-v2" in gaits and "snake_env/Snake5-v2" in gaits
    for env_id in ("snake_env/Snake3-v2", "snake_env/Snake5-v2"):
        params, env_kwargs = search.load_params(env_id)
        recorded = gaits[env_id]["search"]["mean_forward_velocity"]
        speed = search.rollout_speeds(env_id, env_kwargs, [params] * 8, 1000, seed=123).mean()
        assert speed > 0.8 * recorded > 0
