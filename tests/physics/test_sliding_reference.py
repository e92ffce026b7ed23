"""An env's snake on sliding wheels (snake_env.physics.sliding_reference): it starts from the env's
state with the env's observation, follows the env's no-slip physics (motor, barrier, dampings) when
its wheels grip hard, slides where they cannot, and refuses settings it does not model."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import snake_env  # noqa: F401
from snake_env.physics.config import PhysicsConfig
from snake_env.physics.sliding_reference import SlidingSnake
from tests.newest_ids import newest_id

ENV = newest_id("Snake5")


def rollout(wheel_friction, slip_speed, steps=10):
    env = gym.make(ENV, wheel_friction=wheel_friction, wheel_model="no_slip")  # the reference against the no-slip env
    obs, _ = env.reset(seed=0)
    base = env.unwrapped
    snake = SlidingSnake(base.config, slip_speed)
    start = snake.reset(*base.state)
    assert np.max(np.abs(start - obs)) < 1e-12  # the env's observation layout and values
    rng = np.random.default_rng(0)
    sliding = []
    for _ in range(steps):
        action = rng.uniform(-1.0, 1.0, base.n_links - 1).astype(np.float32)
        mine, info = snake.step(action)
        obs, _, _, _, env_info = env.step(action)
        sliding.append(info["wheel_sliding"])
        assert info["friction_work"] <= 0.0
    env.close()
    return np.max(np.abs(mine - obs)), abs(info["x_velocity"] - env_info["x_velocity"]), np.mean(sliding)


def test_follows_the_env_when_the_wheels_grip_hard():
    # mu 1000: neither the traction limit nor sliding acts; what is left is the two integrators' error
    # (the env's RK4 to its 1e-2 tolerance) and the lateral slip of order 1/mu
    obs_error, speed_error, sliding = rollout(1000.0, 1e-2)
    assert obs_error < 1e-2 and speed_error < 1e-3
    assert sliding == 0.0


def test_random_torques_make_wheels_slide_at_the_default_grip():
    obs_error, _, sliding = rollout(0.8, 1e-3)
    assert sliding > 0.02  # measured 0.13 of wheel-steps over 10 steps
    assert obs_error > 1e-2  # the two models part


@pytest.mark.parametrize("kwargs, name", [({"wheel_friction": None}, "wheel_friction must be a number"),
                                          ({"torque_lag": 0.02}, "torque_lag and control_latency must be 0"),
                                          ({"randomize": True}, "randomize must be None for the sliding")])
def test_refuses_what_it_does_not_model(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SlidingSnake(PhysicsConfig(n_links=5, wheel_model="no_slip", **kwargs))
