"""The steered-serpenoid baselines: the LOS law, its effect on the path task, the command steering, goal seeking."""

import math

import gymnasium as gym
import numpy as np
import pytest

import snake_env  # noqa: F401
from snake_env.controllers.steering import (GoalSeekingController, LineOfSightController, SteeringController,
                                             mean_link_angle)
from snake_env.controllers.gaits import load_params
from snake_env.controllers.serpenoid import SerpenoidController, SerpenoidParams

GAIT, _ = load_params("snake_env/Snake5-v2")


def test_on_the_path_and_aligned_the_los_controller_is_the_plain_serpenoid_gait():
    los = LineOfSightController(GAIT, 5, 1.0, 0.04, gait_speed=1.86)
    plain = SerpenoidController(GAIT, 5, 1.0, 0.04)
    rng = np.random.default_rng(0)
    for _ in range(20):
        physics = rng.normal(size=12)
        extras = np.array([0.0, 1.0, 0.0, 0.0])  # e = 0, psi - theta_bar = 0, straight line
        assert np.allclose(los.act(np.r_[physics, extras]), plain.act(physics), atol=1e-6)


def test_los_steers_towards_the_path():
    los = LineOfSightController(GAIT, 5, 1.0, 0.04, gait_speed=1.86, num_envs=2, gain=0.1, lookahead=3.0)
    obs = np.zeros((2, 16))
    obs[:, -3] = 1.0
    obs[0, -4], obs[1, -4] = -0.5, 0.5  # right of the path, left of it
    # right of the path -> a positive joint offset (left turn), left of it -> negative: the same wave
    # (same phase) shifted by kp * (gamma_0 - gamma_1) > 0 before the torque limit
    actions = los.act(obs)
    assert np.all(actions[0] >= actions[1]) and np.any(actions[0] > actions[1])


def _mean_cross_track(controller_factory, path_type, seeds=(0, 1, 2), steps=500):
    errors = []
    for seed in seeds:
        env = gym.make("snake_env/SnakePath5-v2", path_type=path_type)
        obs, _ = env.reset(seed=seed)
        controller = controller_factory()
        for k in range(steps):
            obs, _, terminated, truncated, info = env.step(controller.act(obs))
            if k >= 200:
                errors.append(abs(info["cross_track_error"]))
            if terminated or truncated:
                errors.extend([2.0] * (steps - 1 - k))  # a lost path counts as the termination distance
                break
    return float(np.mean(errors))


class _Straight:
    """The gait without steering (the LOS controller's inner loop alone)."""

    def __init__(self):
        self.inner = SerpenoidController(GAIT, 5, 1.0, 0.04)

    def act(self, obs):
        return self.inner.act(obs[:-4])


@pytest.mark.parametrize("path_type", ["line", "circle"])
def test_los_follows_the_path_far_better_than_the_unsteered_gait(path_type):
    los = _mean_cross_track(lambda: LineOfSightController(GAIT, 5, 1.0, 0.04, gait_speed=1.86), path_type)
    straight = _mean_cross_track(_Straight, path_type)
    assert los < 0.5 * straight
    assert los < 0.5  # below the initial offset


def test_steering_controller_turns_with_the_yaw_command():
    yaw = {}
    for rate in (-0.5, 0.5):
        env = gym.make("snake_env/SnakeCommand5-v1", speed_range=(1.5, 1.5), yaw_rate_range=(rate, rate))
        obs, _ = env.reset(seed=0)
        controller = SteeringController(GAIT, 5, 1.0, 0.04, gait_speed=1.86)
        q0, _ = env.unwrapped.state
        for _ in range(250):
            obs, *_ = env.step(controller.act(obs))
        q1, _ = env.unwrapped.state
        yaw[rate] = (q1[:5].mean() - q0[:5].mean()) / 10.0  # rad/s over 10 s
    assert yaw[-0.5] < -0.2 and yaw[0.5] > 0.2


def test_mean_link_angle_from_the_observation_matches_the_state():
    env = gym.make("snake_env/Snake5-v2")
    obs, _ = env.reset(seed=3)
    for _ in range(30):
        obs, *_ = env.step(env.action_space.sample())
    q, _ = env.unwrapped.state
    expected = np.angle(np.exp(1j * q[:5].mean()))
    assert mean_link_angle(obs[None], 5, False)[0] == pytest.approx(expected, abs=1e-9)


def test_bad_arguments_are_one_line_errors():
    with pytest.raises(ValueError, match="lookahead"):
        LineOfSightController(GAIT, 5, 1.0, 0.04, gait_speed=1.86, lookahead=0.0)
    with pytest.raises(ValueError, match="gait_speed"):
        SteeringController(GAIT, 5, 1.0, 0.04, gait_speed=float("nan"))
    with pytest.raises(ValueError, match="'pd' gait"):
        LineOfSightController(SerpenoidParams("torque", 0.5, 10.0, 1.0), 5, 1.0, 0.04, gait_speed=1.0)
    with pytest.raises(ValueError, match="obs must have shape"):
        LineOfSightController(GAIT, 5, 1.0, 0.04, gait_speed=1.86).act(np.zeros(12))
    with pytest.raises(ValueError, match="hysteresis must be >= 1"):
        GoalSeekingController(GAIT, 5, 1.0, 0.04, gait_speed=1.86, hysteresis=0.5)
    with pytest.raises(ValueError, match="reads the reach task's Dict observation"):
        GoalSeekingController(GAIT, 5, 1.0, 0.04, gait_speed=1.86).act(np.zeros(12))
    with pytest.raises(ValueError, match="reads a Box observation, got a Dict"):
        LineOfSightController(GAIT, 5, 1.0, 0.04, gait_speed=1.86).act({"observation": np.zeros(12)})


def _goal_obs(goal, heading=0.0):
    """A reach observation of a straight snake at rest, CM at the origin, heading ``heading`` (rad)."""
    physics = np.zeros(12)
    physics[4:6] = math.cos(heading), math.sin(heading)
    return {"observation": physics, "achieved_goal": np.zeros(2), "desired_goal": np.asarray(goal, float)}


@pytest.mark.parametrize("goal, backing_away, runs_forward", [
    ((1.0, 0.3), False, True),      # ahead: head first
    ((-1.0, -0.3), False, False),   # behind: tail first (the gait's phase runs backwards)
    ((0.2, 0.3), True, False),      # ahead but inside the left turning circle: back away first
    ((-0.2, -0.3), True, True),     # behind, inside the right turning circle: go forward first
])
def test_goal_seeking_chooses_the_end_that_faces_the_goal_and_backs_away_from_an_unreachable_one(
        goal, backing_away, runs_forward):
    controller = GoalSeekingController(GAIT, 5, 1.0, 0.04, gait_speed=1.77)
    assert controller.turn_radius == pytest.approx(1.77 / (9.0 * 0.3))
    controller.act(_goal_obs(goal))
    assert controller.backing_away[0] == backing_away
    assert (controller.phase[0] > 0) == runs_forward and controller.phase[0] != 0


def test_goal_seeking_steers_towards_the_goal_head_first_and_tail_first():
    """gamma's sign: a goal on the left gives gamma > 0 (a larger joint torque than for the mirrored
    goal) head first, and also tail first: the tail's bearing and the reversed yaw rate both flip sign."""
    actions = {}
    for name, goal in {"ahead_left": (1.0, 0.5), "ahead_right": (1.0, -0.5),
                       "behind_left": (-1.0, 0.5), "behind_right": (-1.0, -0.5)}.items():
        controller = GoalSeekingController(GAIT, 5, 1.0, 0.04, gait_speed=1.77)
        actions[name] = controller.act(_goal_obs(goal))
    assert np.all(actions["ahead_left"] >= actions["ahead_right"]) and np.any(actions["ahead_left"] > actions["ahead_right"])
    assert np.all(actions["behind_left"] >= actions["behind_right"]) and np.any(actions["behind_left"] > actions["behind_right"])


@pytest.mark.parametrize("direction", [0.0, math.pi])
def test_goal_seeking_reaches_a_goal_ahead_and_one_behind_on_the_reach_task(direction):
    env = gym.make("snake_env/SnakeReach5-v1")
    obs, _ = env.reset(seed=4)
    goal = np.array([math.cos(direction), math.sin(direction)])
    env.unwrapped.task_state["goal"][0] = goal
    obs = {**obs, "desired_goal": goal.copy()}
    controller = GoalSeekingController(GAIT, 5, 1.0, 0.04, gait_speed=1.77)
    for step in range(400):
        obs, _, terminated, truncated, info = env.step(controller.act(obs))
        assert np.sign(info["x_velocity"]) in (0.0, np.sign(goal[0])) or step < 10 or terminated
        if terminated or truncated:
            break
    assert terminated and info["is_success"] and step < 100  # 1 m at the gait's ~1.8 m/s, from rest
