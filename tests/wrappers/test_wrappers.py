"""Opt-in phase observation, joint-target and CPG actions (snake_env.wrappers), single and vector env."""

from __future__ import annotations

import copy
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import snake_env  # noqa: F401
from snake_env.controllers.gaits import load_params
from snake_env.controllers.serpenoid import SerpenoidController
from snake_env.wrappers import (CPGAction, CPGActionVector, GoalFrameObservation, GoalFrameObservationVector,
                                JointTargetAction, JointTargetActionVector, PhaseObservation, PhaseObservationVector, SerpenoidResidualAction,
                                SerpenoidResidualActionVector, SteeringResidualAction, SteeringResidualActionVector,
                                WheelGripObservation, parse_env_wrapper, wrap_env, wrap_vector_env)

ENV = "snake_env/Snake3-v2"


def test_joint_target_sends_the_saturated_pd_torque_to_the_env():
    """The wrapped env's step equals the plain env's step with the PD torque
    kp (target - phi) + kd ((target - previous target) / dt - phidot), clipped
    to the torque limit, computed from the last observation."""
    kp, kd = 3.0, 0.1
    wrapped = JointTargetAction(gym.make("snake_env/Snake5-v2", max_torque=2.0), kp=kp, kd=kd)
    plain = gym.make("snake_env/Snake5-v2", max_torque=2.0)
    obs, _ = wrapped.reset(seed=4)
    plain_obs, _ = plain.reset(seed=4)
    rng = np.random.default_rng(0)
    saturated = 0
    previous = None
    for _ in range(30):
        target = rng.uniform(-1, 1, 4).astype(np.float32)
        state = obs.astype(np.float64)
        goal = target.astype(np.float64) * math.pi / 2  # joint limit pi/2 rad per unit action
        rate = 0.0 if previous is None else (goal - previous) / 0.04
        previous = goal
        torque = kp * (goal - state[0:4]) + kd * (rate - state[8:12])
        action = np.clip(torque / 2.0, -1, 1).astype(np.float32)
        saturated += int((np.abs(torque) > 2.0).sum())
        obs, reward, *_ = wrapped.step(target)
        plain_obs, plain_reward, *_ = plain.step(action)
        np.testing.assert_array_equal(obs, plain_obs)
        assert reward == plain_reward
    assert saturated > 0  # the limit was exercised


@pytest.mark.parametrize("kp, kd, reference_rate", [(0.77, 0.1, "difference"), (3.0, 0.1, "zero")])
def test_joint_target_tracks_an_admissible_trajectory_within_the_torque_limit(kp, kd, reference_rate):
    """A joint trajectory the snake really followed (under the searched gait) is
    tracked from the same start: mean error well below the trajectory's size,
    and far below what zero torque gives; the env never sees |action| > 1.
    (At the 25 Hz env-step rate the tracking is sensitive to the gains: a
    stiffer or less damped PD overshoots, see docs/learning.md.)"""
    params, _ = load_params(ENV)
    env = gym.make(ENV)
    obs, _ = env.reset(seed=3)
    controller = SerpenoidController(params, 3, 1.0, 0.04)
    reference = []
    for _ in range(25):
        obs, *_ = env.step(controller.act(obs))
        reference.append(obs[:2].copy())
    reference = np.array(reference)

    def mean_error(kp, kd):
        tracker = JointTargetAction(gym.make(ENV), kp=kp, kd=kd, reference_rate=reference_rate)
        obs, _ = tracker.reset(seed=3)
        errors = []
        for target in reference:
            assert np.all(np.abs(tracker.pd.torque_action(target / (math.pi / 2), obs, tracker._previous)) <= 1.0)
            obs, *_ = tracker.step((target / (math.pi / 2)).astype(np.float32))
            errors.append(np.abs(obs[:2] - target).mean())
        return float(np.mean(errors))

    size = float(np.abs(reference).mean())
    tracked = mean_error(kp, kd)
    untracked = mean_error(0.0, 1e-9)  # (almost) no torque
    assert tracked < 0.4 * size, (tracked, size)
    assert tracked < 0.5 * untracked, (tracked, untracked)


def side_by_side(single, vector, seed: int, n_steps: int, rng_seed: int):
    """Reset a wrapped single env and a wrapped vector env with ``seed``, then step the single env
    and every vector row with the same random actions; yields (k, single obs, vector obs), k = -1
    after the reset and k = 0, 1, ... after each step."""
    assert vector.single_observation_space == single.observation_space
    obs, _ = single.reset(seed=seed)
    vobs, _ = vector.reset(seed=seed)
    yield -1, obs, vobs
    rng = np.random.default_rng(rng_seed)
    for k in range(n_steps):
        action = rng.uniform(-1, 1, single.action_space.shape).astype(np.float32)
        obs, *_ = single.step(action)
        vobs, *_ = vector.step(np.tile(action, (vector.num_envs, 1)))
        yield k, obs, vobs


def test_vector_wrappers_match_the_single_env_wrappers():
    spec = {"joint_target": {"kp": 2.0, "kd": 0.1}, "phase_observation": {"frequencies": [30.0, 5.0]}}
    single = wrap_env(gym.make(ENV), spec)
    vector = wrap_vector_env(gym.make_vec(ENV, num_envs=1, vectorization_mode="vector_entry_point"), spec)
    assert single.observation_space.shape == (2 + 2 + 2 + 2 + 4,)
    for _, obs, vobs in side_by_side(single, vector, seed=7, n_steps=20, rng_seed=1):
        np.testing.assert_allclose(vobs[0], obs, rtol=0, atol=1e-6)


def test_phase_clock_runs_with_env_time_and_restarts_on_autoreset():
    omega = 10.0
    env = PhaseObservation(gym.make(ENV, max_episode_steps=5), frequencies=omega)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs[-2:], [0.0, 1.0])
    for k in range(1, 4):
        obs, *_ = env.step(env.action_space.sample())
        np.testing.assert_allclose(obs[-2:], [math.sin(omega * 0.04 * k), math.cos(omega * 0.04 * k)], atol=1e-6)
    for mode in (AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP):
        vec = PhaseObservationVector(gym.make_vec(ENV, num_envs=2, vectorization_mode="vector_entry_point",
                                                  max_episode_steps=5, autoreset_mode=mode), frequencies=omega)
        obs, _ = vec.reset(seed=0)
        phases = []
        for _ in range(7):
            obs, _, terminated, truncated, info = vec.step(np.zeros((2, 2), np.float32))
            phases.append(obs[0, -2:].copy())
            if mode == AutoresetMode.SAME_STEP and truncated[0]:
                # the episode's last observation keeps its clock (5 steps), the returned one restarts
                final = info["final_obs"][0]
                np.testing.assert_allclose(final[-2:], [math.sin(omega * 0.2), math.cos(omega * 0.2)], atol=1e-6)
                np.testing.assert_allclose(obs[0, -2:], [0.0, 1.0], atol=1e-6)
        steps = [1, 2, 3, 4, 0, 1, 2] if mode == AutoresetMode.SAME_STEP else [1, 2, 3, 4, 5, 0, 1]
        expected = [[math.sin(omega * 0.04 * s), math.cos(omega * 0.04 * s)] for s in steps]
        np.testing.assert_allclose(np.array(phases), expected, atol=1e-6)



@pytest.mark.parametrize("spec", ["cpg", "serpenoid_residual"])
def test_clock_wrappers_restart_on_same_step_autoreset_and_clock_the_final_obs(spec):
    """Same-step autoreset (next-step: ``test_clocked_action_wrappers_...``): a vector row's appended clock (sin, cos
    of the oscillator's or the gait's phase) follows a single env's episode, ``final_obs`` keeps
    the episode's last clock and the returned observation restarts it."""
    mode = AutoresetMode.SAME_STEP
    single = wrap_env(gym.make(ENV, max_episode_steps=5), spec)
    obs, _ = single.reset(seed=0)
    clock = [obs[-2:].copy()]  # clock[k]: after k steps of an episode, constant action
    action = np.zeros(single.action_space.shape, np.float32)
    for _ in range(5):
        obs, *_ = single.step(action)
        clock.append(obs[-2:].copy())
    vec = wrap_vector_env(gym.make_vec(ENV, num_envs=2, vectorization_mode="vector_entry_point",
                                       max_episode_steps=5, autoreset_mode=mode), spec)
    vec.reset(seed=0)
    seen = []
    for _ in range(7):
        obs, _, _, truncated, info = vec.step(np.zeros((2, *action.shape), np.float32))
        seen.append(obs[:, -2:].copy())
        if truncated.any():
            assert truncated.all()
            for i in range(2):
                np.testing.assert_allclose(info["final_obs"][i][-2:], clock[5], atol=1e-6)
    for got, k in zip(seen, [1, 2, 3, 4, 0, 1, 2]):
        np.testing.assert_allclose(got, [clock[k], clock[k]], atol=1e-6)


@pytest.mark.parametrize("spec, message", [
    ({"joint_targets": {}}, "env_wrapper name must be one of ['cpg', 'goal_frame', 'joint_target', 'phase_observation', 'serpenoid_residual', "
     "'steering_residual', 'wheel_grip_observation'], "
     "got 'joint_targets'"),
    ("torque_mode", "env_wrapper name must be one of"),
    ({"joint_target": {"kp": -1.0}}, "kp must be a finite number >= 0"),
    ({"joint_target": {"gain": 1.0}}, "env_wrapper 'joint_target': "),
    ({"phase_observation": {"frequencies": []}}, "frequencies must be a number or a non-empty list"),
    ({"joint_target": {"kp": 0.0, "kd": 0.0}}, "joint_target needs kp > 0 or kd > 0"),
    ({"joint_target": {"reference_rate": "exact"}}, "reference_rate must be one of ['difference', 'zero'], got 'exact'"),
    ({"cpg": {"max_frequency": 0.0}}, "max_frequency must be a finite number > 0.0 (rad/s), got 0.0"),
    ({"cpg": {"kp": 0.0, "kd": 0.0}}, "cpg needs kp > 0 or kd > 0"),
    ({"cpg": {"frequency": 5.0}}, "env_wrapper 'cpg': "),
    ({"serpenoid_residual": {"scale": 0.0}}, "scale must be a finite number > 0.0"),
    ({"serpenoid_residual": {"scale": 3.0}}, "scale must be in (0, 2]"),
    ({"serpenoid_residual": {"gait": "snake_env/Snake99-v2"}}, "no serpenoid gait for env 'snake_env/Snake99-v2'"),
    ("steering_residual", "steering_residual needs a task whose baseline steers the gait (path, command, reach)"),
])
def test_bad_wrapper_specs_are_rejected_with_one_line(spec, message):
    with pytest.raises(ValueError) as info:
        wrap_env(gym.make(ENV), spec)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_spec_forms():
    assert parse_env_wrapper(None) == []
    assert parse_env_wrapper("joint_target") == [("joint_target", {})]
    assert parse_env_wrapper(["phase_observation", {"joint_target": {"kp": 2}}]) == [
        ("phase_observation", {}), ("joint_target", {"kp": 2})]
    assert isinstance(JointTargetActionVector(gym.make_vec(ENV, num_envs=2, vectorization_mode="vector_entry_point")),
                      JointTargetActionVector)


def test_train_config_rejects_a_bad_wrapper_name_in_one_line():
    from snake_env.train.config import ConfigError, build_config

    with pytest.raises(ConfigError) as info:
        build_config("ppo", "snake_env/Snake12-v2", overrides=["env_wrapper={joint_targte: {kp: 1.0}}"])
    assert "env_wrapper name must be one of" in str(info.value) and "\n" not in str(info.value)


def test_a_constant_cpg_action_is_the_searched_serpenoid():
    """CPG-RL action mode against the serpenoid controller: the action that encodes a
    searched ``pd`` gait gives the controller's env actions step for step (the phase is
    summed as omega dt and wrapped, the controller's is omega t: equal to rounding)."""
    env_id = "snake_env/Snake12-v2"
    params, _ = load_params(env_id)
    cpg = CPGAction(gym.make(env_id), kp=params.kp, kd=params.kd)
    plain = gym.make(env_id)
    controller = SerpenoidController(params, n_links=12, max_torque=1.0, dt=0.04)
    action = cpg.cpg.encode(params.amplitude, params.frequency, params.phase_lag, params.offset)
    np.testing.assert_allclose([cpg.cpg.decode(action)[name] for name in ("amplitude", "frequency", "phase_lag")],
                               [params.amplitude, params.frequency, params.phase_lag], rtol=1e-12)
    assert cpg.cpg.decode(action)["offset"] == params.offset
    assert cpg.action_space.shape == (4,) and cpg.observation_space.shape == (plain.observation_space.shape[0] + 2,)
    obs, _ = cpg.reset(seed=3)
    plain_obs, _ = plain.reset(seed=3)
    speeds = []
    for k in range(200):
        expected = controller.act(plain_obs)
        torque, _ = cpg.cpg.torque_action(action, cpg._obs, cpg._phase)
        np.testing.assert_allclose(torque, expected, rtol=0, atol=1e-6)
        np.testing.assert_allclose(obs[-2:], [math.sin(cpg._phase), math.cos(cpg._phase)], atol=1e-6)
        obs, _, _, _, info = cpg.step(action)
        plain_obs, *_ = plain.step(expected)
        speeds.append(info["x_velocity"])
    assert np.mean(speeds[50:]) > 0.9  # the searched gait's 1.05 m/s, not a stalled snake


# the command task with one command: its draws then agree between a single env and a vector env's row 0
ONE_COMMAND = {"speed_range": (0.3, 0.3), "yaw_rate_range": (0.2, 0.2)}


@pytest.mark.parametrize("single_cls, vector_cls, env_id, env_kwargs, kwargs", [
    (CPGAction, CPGActionVector, ENV, {}, {"max_frequency": 30.0}),
    (SerpenoidResidualAction, SerpenoidResidualActionVector, "snake_env/Snake5-v2", {}, {}),
    (SteeringResidualAction, SteeringResidualActionVector, "snake_env/SnakeCommand5-v1", ONE_COMMAND,
     {"offset_scale": 0.3}),
], ids=["cpg", "serpenoid_residual", "steering_residual"])
def test_clocked_action_wrappers_batch_and_restart_their_clock_on_autoreset(single_cls, vector_cls, env_id,
                                                                            env_kwargs, kwargs):
    """The vector wrapper equals the single one row by row, and a sub-env's oscillator phase
    restarts at 0 with its (next-step) autoreset."""
    single = single_cls(gym.make(env_id, max_episode_steps=6, **env_kwargs), **kwargs)
    vector = vector_cls(gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point",
                                     max_episode_steps=6, **env_kwargs), **kwargs)
    assert vector.single_action_space == single.action_space
    for k, obs, vobs in side_by_side(single, vector, seed=5, n_steps=8, rng_seed=2):
        if k < 6:  # the single env is truncated after 6 steps; the vector's 7th step resets both rows
            np.testing.assert_allclose(vobs[0], obs, rtol=0, atol=1e-6)
        if k == 6:
            np.testing.assert_allclose(vobs[:, -2:], [[0.0, 1.0], [0.0, 1.0]], atol=1e-12)


def test_cpg_wrapped_env_passes_gymnasiums_env_checker():
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "wrapped env" and unbounded-Box advice
        check_env(CPGAction(gym.make("snake_env/Snake5-v2")), skip_render_check=True)


def test_serpenoid_residual_with_zero_action_is_the_searched_gait_and_a_correction_adds_torque():
    env_id = "snake_env/Snake12-v2"
    params, _ = load_params(env_id)
    residual = SerpenoidResidualAction(gym.make(env_id), scale=0.25)
    plain = gym.make(env_id)
    controller = SerpenoidController(params, n_links=12, max_torque=1.0, dt=0.04)
    obs, _ = residual.reset(seed=1)
    plain_obs, _ = plain.reset(seed=1)
    assert obs.shape == (plain_obs.shape[0] + 2,)
    for k in range(60):
        np.testing.assert_array_equal(obs[:-2], plain_obs)
        np.testing.assert_allclose(obs[-2:], [math.sin(params.frequency * 0.04 * k),
                                              math.cos(params.frequency * 0.04 * k)], atol=1e-9)
        obs, _, _, _, info = residual.step(np.zeros(11, np.float32))
        plain_obs, _, _, _, plain_info = plain.step(controller.act(plain_obs))
        assert info["x_velocity"] == plain_info["x_velocity"]
    # a unit correction adds scale * max_torque before the clip to [-1, 1]
    base = SerpenoidController(params, n_links=12, max_torque=1.0, dt=0.04)
    base.time[:] = residual.controller.time
    expected = np.clip(base.act(residual._obs).astype(np.float64) + 0.25, -1.0, 1.0).astype(np.float32)
    recorder = {}
    original_step = residual.env.step
    residual.env.step = lambda action: (recorder.setdefault("action", action), original_step(action))[1]
    residual.step(np.ones(11, np.float32))
    np.testing.assert_allclose(recorder["action"], expected, atol=1e-6)


@pytest.mark.parametrize("env_id, controller_name", [("snake_env/SnakePath5-v2", "LineOfSightController"),
                                                     ("snake_env/SnakeCommand5-v1", "SteeringController")])
def test_serpenoid_residual_on_a_task_starts_at_the_tasks_baseline(env_id, controller_name):
    """Zero action = the baseline of snake-eval --baseline (line of sight, steering) step for step."""
    from snake_env.controllers import steering as path_following
    from snake_env.controllers.gaits import gait_for_links

    params, speed = gait_for_links(5, versions_back=2)
    baseline = getattr(path_following, controller_name)(params, 5, 1.0, 0.04, gait_speed=float(speed))
    residual = SerpenoidResidualAction(gym.make(env_id))
    assert type(residual.controller).__name__ == controller_name
    plain = gym.make(env_id)
    obs, _ = residual.reset(seed=2)
    plain_obs, _ = plain.reset(seed=2)
    for _ in range(40):
        np.testing.assert_array_equal(obs[:-2], plain_obs)
        obs, reward, *_ = residual.step(np.zeros(4, np.float32))
        plain_obs, plain_reward, *_ = plain.step(baseline.act(plain_obs))
        assert reward == plain_reward


def test_serpenoid_residual_on_the_reach_task_starts_at_goal_seeking_and_extends_the_dict_observation():
    from snake_env.controllers.steering import GoalSeekingController
    from snake_env.controllers.gaits import gait_for_links

    params, speed = gait_for_links(5, versions_back=2)
    baseline = GoalSeekingController(params, 5, 1.0, 0.04, gait_speed=float(speed))
    residual = SerpenoidResidualAction(gym.make("snake_env/SnakeReach5-v1"))
    plain = gym.make("snake_env/SnakeReach5-v1")
    space = residual.observation_space
    assert isinstance(space, gym.spaces.Dict) and space["observation"].shape == (14,)
    assert space["desired_goal"] == plain.observation_space["desired_goal"]
    obs, _ = residual.reset(seed=2)
    plain_obs, _ = plain.reset(seed=2)
    for _ in range(60):
        assert space.contains(obs)
        np.testing.assert_array_equal(obs["observation"][:-2], plain_obs["observation"])
        np.testing.assert_array_equal(obs["desired_goal"], plain_obs["desired_goal"])
        obs, reward, terminated, _, _ = residual.step(np.zeros(4, np.float32))
        plain_obs, plain_reward, *_ = plain.step(baseline.act(plain_obs))
        assert reward == plain_reward
        if terminated:
            break


def test_serpenoid_residual_vector_on_the_reach_task_phases_the_final_dict_observation():
    vector = SerpenoidResidualActionVector(gym.make_vec("snake_env/SnakeReach5-v1", num_envs=2,
                                                        vectorization_mode="vector_entry_point",
                                                        autoreset_mode=AutoresetMode.SAME_STEP,
                                                        max_episode_steps=5))
    vector.reset(seed=0)
    for _ in range(4):
        vector.step(np.zeros((2, 4), np.float32))
    twin = copy.deepcopy(vector.controller)
    twin.act(vector._obs)  # the phase after this step (the gait may run backwards)
    phase = twin.phase
    obs, _, _, truncated, info = vector.step(np.zeros((2, 4), np.float32))
    assert truncated.all()
    for i in range(2):
        final = info["final_obs"][i]["observation"]
        np.testing.assert_allclose(final[-2:], [math.sin(phase[i]), math.cos(phase[i])], atol=1e-9)
    np.testing.assert_allclose(obs["observation"][:, -2:], [[0.0, 1.0], [0.0, 1.0]], atol=1e-12)


def test_observe_mode_appends_goal_seekings_hidden_state_and_makes_its_action_a_function_of_the_observation():
    """With ``observe_mode`` the observation's last two entries are the baseline's mode, which its next action
    depends on (flipping it changes the action on some steps: it is state the plain observation lacks).
    The single env and a one-row vector env agree."""
    from snake_env.controllers.steering import GoalSeekingController

    spec = {"serpenoid_residual": {"observe_mode": True}}
    single = wrap_env(gym.make("snake_env/SnakeReach12-v1"), spec)
    assert single.observation_space["observation"].shape == (26 + 2 + 2,)
    vector = wrap_vector_env(gym.make_vec("snake_env/SnakeReach12-v1", num_envs=1,
                                          vectorization_mode="vector_entry_point"), spec)
    obs, _ = single.reset(seed=5)
    vobs, _ = vector.reset(seed=5)
    rng = np.random.default_rng(0)
    modes, mode_mattered = set(), False
    for step in range(200):
        np.testing.assert_allclose(vobs["observation"][0], obs["observation"], atol=1e-6)
        o = obs["observation"]
        np.testing.assert_array_equal(o[-2:], single.controller.mode()[0])
        modes.add(tuple(o[-2:]))
        plain = {**obs, "observation": o[:-4]}
        flipped = copy.deepcopy(single.controller)
        flipped.backing_away[:] = ~flipped.backing_away
        mode_mattered |= not np.array_equal(flipped.act(plain), copy.deepcopy(single.controller).act(plain))
        action = rng.normal(0.0, 0.1, 11).astype(np.float32)
        obs, _, terminated, truncated, _ = single.step(action)
        vobs, *_ = vector.step(action[None])
        if terminated or truncated:
            break
    assert (0.0, 0.0) in modes and len(modes) > 1 and mode_mattered  # the reset's zeros, then a direction
    with pytest.raises(ValueError, match="observe_mode needs a baseline with a hidden mode.*LineOfSightController"):
        wrap_env(gym.make("snake_env/SnakePath5-v2"), spec)
    with pytest.raises(ValueError, match="observe_mode must be true or false"):
        wrap_env(gym.make("snake_env/SnakeReach5-v1"), {"serpenoid_residual": {"observe_mode": "yes"}})
    assert isinstance(single.controller, GoalSeekingController)


def test_observe_mode_final_obs_keeps_the_episodes_last_mode():
    vector = SerpenoidResidualActionVector(gym.make_vec("snake_env/SnakeReach5-v1", num_envs=2,
                                                        vectorization_mode="vector_entry_point",
                                                        autoreset_mode=AutoresetMode.SAME_STEP,
                                                        max_episode_steps=5), observe_mode=True)
    vector.reset(seed=0)
    for _ in range(4):
        vector.step(np.zeros((2, 4), np.float32))
    obs, _, _, truncated, info = vector.step(np.zeros((2, 4), np.float32))
    assert truncated.all()
    for i in range(2):
        final = info["final_obs"][i]["observation"]
        assert final[-1] in (-1.0, 1.0)  # the direction the gait ran in on the last step
    np.testing.assert_array_equal(obs["observation"][:, -2:], np.zeros((2, 2)))  # restarted


def test_serpenoid_residual_refuses_a_task_without_a_baseline(monkeypatch):
    env = gym.make("snake_env/Snake5-v2")
    from snake_env.tasks import Task

    monkeypatch.setattr(env.unwrapped, "task", type("Dance", (Task,), {"name": "dance"})())
    with pytest.raises(ValueError, match="the 'dance' task has no baseline controller"):
        SerpenoidResidualAction(env)


def test_goal_frame_is_the_goal_rotated_into_the_mean_heading_frame():
    """Cross-check: theta_bar from the env's state (mean of the link angles) against the wrapper's
    reconstruction from the observation; the appended vector keeps the goal distance (a rotation)
    and its angle is the goal's bearing from theta_bar."""
    from snake_env.tasks.base import mean_heading

    env = wrap_env(gym.make("snake_env/SnakeReach5-v1"), ["serpenoid_residual", "goal_frame"])
    space = env.observation_space
    assert space["observation"].shape == (16,) and np.isinf(space["observation"].high[-2:]).all()
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(80):
        assert space.contains(obs)
        q = env.unwrapped._batch.q[0]
        theta_bar = mean_heading(q, 5)
        delta = obs["desired_goal"] - obs["achieved_goal"]
        bearing = math.atan2(delta[1], delta[0]) - theta_bar
        ahead, left = obs["observation"][-2:]
        np.testing.assert_allclose([ahead, left], np.hypot(*delta) * np.array([math.cos(bearing), math.sin(bearing)]),
                                   atol=1e-5)
        obs, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
        checked += 1
        if terminated or truncated:
            break
        assert math.hypot(*obs["observation"][-2:]) == pytest.approx(info["goal_distance"], rel=1e-5)
    assert checked >= 40


def test_goal_frame_vector_matches_single_envs_and_passes_the_env_checker():
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "wrapped env" and unbounded-Box advice
        check_env(GoalFrameObservation(gym.make("snake_env/SnakeReach5-v1")), skip_render_check=True)
    spec = ["serpenoid_residual", "goal_frame"]
    single = wrap_env(gym.make("snake_env/SnakeReach5-v1"), spec)
    vector = wrap_vector_env(gym.make_vec("snake_env/SnakeReach5-v1", num_envs=1,
                                          vectorization_mode="vector_entry_point"), spec)
    single_obs, _ = single.reset(seed=4)
    obs, _ = vector.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(30):
        for key in single_obs:
            np.testing.assert_allclose(obs[key][0], single_obs[key], rtol=0, atol=1e-6)
        action = rng.uniform(-1, 1, 4).astype(np.float32)
        single_obs, *_ = single.step(action)
        obs, *_ = vector.step(action[None])


def test_goal_frame_vector_extends_the_final_obs_of_same_step_autoreset():
    vector = wrap_vector_env(gym.make_vec("snake_env/SnakeReach5-v1", num_envs=2, vectorization_mode="vector_entry_point",
                                          autoreset_mode=AutoresetMode.SAME_STEP, max_episode_steps=5),
                             ["serpenoid_residual", "goal_frame"])
    assert vector.single_observation_space["observation"].shape == (16,)
    vector.reset(seed=0)
    for _ in range(5):
        obs, _, _, truncated, info = vector.step(np.zeros((2, 4), np.float32))
    assert truncated.all()
    for i in range(2):
        final = info["final_obs"][i]
        assert vector.single_observation_space.contains(final)
        assert math.hypot(*final["observation"][-2:]) == pytest.approx(info["goal_distance"][i], rel=1e-5)
    # the new episodes' observations are extended too, from their own goals
    np.testing.assert_allclose(np.hypot(*obs["observation"][:, -2:].T),
                               np.linalg.norm(obs["desired_goal"] - obs["achieved_goal"], axis=-1), rtol=1e-5)


def test_goal_frame_refuses_a_task_without_goals():
    with pytest.raises(ValueError, match="goal_frame needs a goal task"):
        GoalFrameObservation(gym.make("snake_env/Snake5-v2"))


def test_train_config_refuses_goal_reading_wrappers_with_her():
    from snake_env.train import config as cfg

    assert cfg.build_config("sac", "snake_env/SnakeReach5-v1")["replay_buffer_class"] == "HerReplayBuffer"
    with pytest.raises(cfg.ConfigError, match=r"env_wrapper \['goal_frame'\] does not combine with .*HerReplayBuffer"):
        cfg.build_config("sac", "snake_env/SnakeReach5-v1", overrides=["env_wrapper=goal_frame"])
    with pytest.raises(cfg.ConfigError, match=r"env_wrapper \['steering_residual'\] does not combine"):
        cfg.build_config("sac", "snake_env/SnakeReach5-v1", overrides=["env_wrapper=steering_residual"])


@pytest.mark.parametrize("env_id, n_links", [("snake_env/SnakePath12-v2", 12), ("snake_env/SnakeCommand5-v1", 5),
                                             ("snake_env/SnakeReach12-v1", 12)])
def test_steering_residual_with_zero_action_is_the_tasks_baseline(env_id, n_links):
    """Zero action = the baseline of snake-eval --baseline (with its configs/baselines.yaml settings) step for step."""
    from snake_env.controllers.steering import make_baseline
    from snake_env.controllers.gaits import gait_for_links

    params, speed = gait_for_links(n_links, versions_back=2)  # the ideal-physics ids: their gaits
    plain = gym.make(env_id)
    task = plain.unwrapped.task
    baseline = make_baseline(task.baseline_controller, task.name, params, speed, n_links, 1.0, 0.04)
    residual = SteeringResidualAction(gym.make(env_id))
    assert residual.action_space == gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    obs, _ = residual.reset(seed=3)
    plain_obs, _ = plain.reset(seed=3)
    for _ in range(80):
        obs, reward, terminated, truncated, _ = residual.step(np.zeros(2, np.float32))
        plain_obs, plain_reward, *_ = plain.step(baseline.act(plain_obs))
        assert reward == plain_reward
        if terminated or truncated:
            break


def test_steering_residual_on_the_forward_task_starts_at_the_searched_serpenoid():
    """The forward task has no steering baseline, but baseline: gait does: its zero action sends the torques of
    the serpenoid of snake-eval --baseline serpenoid (configs/serpenoid.yaml, this id) step for step."""
    from snake_env.controllers.gaits import load_params
    from snake_env.controllers.serpenoid import SerpenoidController

    env_id = "snake_env/Snake20-v2"
    residual = SteeringResidualAction(gym.make(env_id), baseline="gait")
    plain = gym.make(env_id)
    serpenoid = SerpenoidController(load_params(env_id)[0], n_links=20, max_torque=plain.unwrapped.max_torque,
                                    dt=plain.unwrapped.dt)
    sent = {}
    original_step = residual.env.step
    residual.env.step = lambda action: (sent.__setitem__("action", action), original_step(action))[1]
    residual.reset(seed=3)
    plain_obs, _ = plain.reset(seed=3)
    for _ in range(150):
        reward = residual.step(np.zeros(2, np.float32))[1]
        action = serpenoid.act(plain_obs)
        plain_obs, plain_reward, *_ = plain.step(action)
        np.testing.assert_allclose(sent["action"], action, atol=1e-7)
        assert reward == plain_reward
    with pytest.raises(ValueError, match="the forward task's baseline SerpenoidController has no steering"):
        SteeringResidualAction(gym.make(env_id))


def test_steering_residual_corrects_the_offset_and_the_gait_frequency():
    """A unit action sends the PD serpenoid's torque for offset + offset_scale and frequency x (1 + speed_range);
    a positive offset correction turns the snake left (its yaw rate rises), as gamma does in the baseline."""
    env_id = "snake_env/SnakeCommand5-v1"
    residual = SteeringResidualAction(gym.make(env_id), offset_scale=0.1, speed_range=0.5)
    obs, _ = residual.reset(seed=0)
    for _ in range(5):
        obs, *_ = residual.step(np.zeros(2, np.float32))
    twin = copy.deepcopy(residual.controller)
    physics, offset, freq_scale, _ = twin.guidance(residual._obs)
    expected = twin.gait_action(physics, offset + 0.1 * 0.5, freq_scale * (1.0 - 0.5 * 0.5))
    recorder = {}
    original_step = residual.env.step
    residual.env.step = lambda action: (recorder.setdefault("action", action), original_step(action))[1]
    residual.step(np.array([0.5, -0.5], np.float32))
    np.testing.assert_allclose(recorder["action"], expected[0], atol=1e-7)
    np.testing.assert_allclose(residual.controller.phase, twin.phase, atol=1e-12)  # the slowed clock

    def run(action):
        """Mean link angles (rad) and CM speeds (m/s) of 150 steps under a constant action (1 m/s, no turn)."""
        from snake_env.controllers.steering import mean_link_angle

        env = SteeringResidualAction(gym.make(env_id, speed_range=(1.0, 1.0), yaw_rate_range=(0.0, 0.0)),
                                     offset_scale=0.1)
        env.reset(seed=1)
        heading, speed = [], []
        for _ in range(150):
            info = env.step(np.asarray(action, np.float32))[4]
            heading.append(mean_link_angle(env._obs[None], 5, False)[0])
            speed.append(math.hypot(info["x_velocity"], info["y_velocity"]))
        return np.array(heading), np.mean(speed[50:])

    heading, speed = run([0.0, 0.0])
    left = np.angle(np.exp(1j * (run([1.0, 0.0])[0] - heading)))
    assert np.mean(left[100:]) > 0.2  # measured 0.4-0.65 rad: the heading feedback resists, but late
    # no-slip wheels: the speed follows the gait frequency (measured x1.53 and x0.41)
    assert 1.3 < run([0.0, 1.0])[1] / speed < 1.8 and 0.25 < run([0.0, -1.0])[1] / speed < 0.7


def test_steering_residual_on_reach_passes_the_env_checker_and_batches_its_dict_observation():
    from gymnasium.utils.env_checker import check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        check_env(SteeringResidualAction(gym.make("snake_env/SnakeReach8-v1"), observe_mode=True),
                  skip_render_check=True)
    spec = [{"steering_residual": {"observe_mode": True}}, "goal_frame"]
    single = wrap_env(gym.make("snake_env/SnakeReach8-v1"), spec)
    vector = wrap_vector_env(gym.make_vec("snake_env/SnakeReach8-v1", num_envs=1,  # one row: the same goal draw
                                          vectorization_mode="vector_entry_point"), spec)
    assert vector.single_observation_space == single.observation_space
    obs, _ = single.reset(seed=4)
    vobs, _ = vector.reset(seed=4)
    rng = np.random.default_rng(3)
    for _ in range(40):
        for key in obs:
            np.testing.assert_allclose(vobs[key][0], obs[key], atol=1e-6)
        action = rng.uniform(-1, 1, 2).astype(np.float32)
        obs, _, terminated, truncated, _ = single.step(action)
        vobs, *_ = vector.step(action[None])
        if terminated or truncated:
            break
    with pytest.raises(ValueError, match=r"offset_scale must be in \(0, 1\] rad and speed_range in \[0, 1\]"):
        wrap_env(gym.make("snake_env/SnakeReach8-v1"), {"steering_residual": {"offset_scale": 2.0}})


def test_steering_residual_on_the_straight_gait_reads_no_goal():
    """baseline: gait steers the searched serpenoid run straight: the zero action is that gait (offset 0, its
    frequency) whatever the goal, so HER may relabel goals; the gait moves the snake at its searched speed."""
    from snake_env.controllers.gaits import gait_for_links

    env = SteeringResidualAction(gym.make("snake_env/SnakeReach5-v1"), baseline="gait", offset_scale=0.3)
    obs, _ = env.reset(seed=0)
    moved = {**obs, "desired_goal": obs["desired_goal"] + 5.0}  # another goal: the same action
    np.testing.assert_array_equal(copy.deepcopy(env.controller).act(moved), copy.deepcopy(env.controller).act(obs))
    expected = copy.deepcopy(env.controller).gait_action(np.asarray(obs["observation"], float)[None], np.zeros(1), np.ones(1))
    recorder = {}
    original_step = env.env.step
    env.env.step = lambda action: (recorder.setdefault("action", action), original_step(action))[1]
    env.step(np.zeros(2, np.float32))
    np.testing.assert_allclose(recorder["action"], expected[0], atol=1e-7)
    speeds = []
    for _ in range(80):
        info = env.step(np.zeros(2, np.float32))[4]
        speeds.append(math.hypot(info["x_velocity"], info["y_velocity"]))
    assert np.mean(speeds[20:]) > 0.8 * gait_for_links(5, versions_back=2)[1]
    with pytest.raises(ValueError, match=r"baseline must be one of \['task', 'gait'\], got 'goal'"):
        SteeringResidualAction(gym.make("snake_env/SnakeReach5-v1"), baseline="goal")
    with pytest.raises(ValueError, match="observe_mode needs a baseline with a hidden mode.*StraightGait"):
        SteeringResidualAction(gym.make("snake_env/SnakeReach5-v1"), baseline="gait", observe_mode=True)
    # goal-free: the config lets HER relabel its goals
    from snake_env.train import config as cfg

    config = cfg.build_config("sac", "snake_env/SnakeReach5-v1",
                              overrides=["env_wrapper={steering_residual: {baseline: gait}}"])
    assert config["replay_buffer_class"] == "HerReplayBuffer"


def test_phase_observation_on_a_goal_task_extends_the_observation_entry():
    env = PhaseObservation(gym.make("snake_env/SnakeReach5-v1"), frequencies=[10.0, 20.0])
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs) and obs["observation"].shape == (16,)
    obs, *_ = env.step(np.zeros(4, np.float32))
    t = env.unwrapped.dt
    np.testing.assert_allclose(obs["observation"][-4:], [np.sin(10 * t), np.cos(10 * t), np.sin(20 * t),
                                                          np.cos(20 * t)], rtol=1e-12)


def test_wheel_grip_observation_is_each_wheels_force_over_its_grip_and_says_which_slide():
    """The appended shares are info's lateral forces over mu m g, computed here from the env's settings; 0
    after a reset; on the sliding wheels (v4) within [-1, 1], and +-1 exactly on the wheels that slid."""
    from gymnasium.utils.env_checker import check_env

    env = WheelGripObservation(gym.make("snake_env/Snake3-v4"))
    base = env.unwrapped
    grip = base.wheel_friction * np.broadcast_to(base.mass, (3,)) * 9.81
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "wrapped env" and unbounded-Box advice
        check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (2 + 2 + 2 + 2 + 3,) and not obs[-3:].any()
    rng = np.random.default_rng(0)
    slid = 0
    for _ in range(120):
        obs, _, _, _, info = env.step(rng.choice([-1.0, 1.0], 2).astype(np.float32))  # bang-bang: wheels slide
        share = info["wheel_lateral_force"] / grip
        np.testing.assert_allclose(obs[-3:], share, rtol=1e-6, atol=1e-7)  # float32 observation
        assert np.all(np.abs(share) <= 1.0 + 1e-9)
        np.testing.assert_allclose(np.abs(share[info["wheel_slip"]]), 1.0, rtol=1e-9)
        slid += info["wheel_slip"].sum()
    assert slid > 0


@pytest.mark.parametrize("mode", [AutoresetMode.SAME_STEP, AutoresetMode.NEXT_STEP])
def test_wheel_grip_observation_vector_follows_each_sub_env_and_restarts_with_its_episode(mode):
    """Each row's shares are its own step's forces over its grip (a one-env vector env gives the single env's);
    a row whose episode restarts shows zeros, and same-step autoreset's ``final_obs`` keeps the last shares."""
    single = wrap_env(gym.make("snake_env/Snake3-v4"), "wheel_grip_observation")
    one = wrap_vector_env(gym.make_vec("snake_env/Snake3-v4", num_envs=1, vectorization_mode="vector_entry_point"),
                          "wheel_grip_observation")
    for _, obs, vobs in side_by_side(single, one, seed=7, n_steps=20, rng_seed=1):
        np.testing.assert_allclose(vobs[0], obs, rtol=0, atol=1e-6)
    vector = wrap_vector_env(gym.make_vec("snake_env/Snake3-v4", num_envs=2, vectorization_mode="vector_entry_point",
                                          max_episode_steps=5, autoreset_mode=mode), "wheel_grip_observation")
    grip = vector.unwrapped.wheel_grip
    assert vector.single_observation_space.shape == (11,)
    obs, _ = vector.reset(seed=0)
    assert not obs[:, -3:].any()
    restarted = []
    for step in range(7):
        obs, _, _, truncated, info = vector.step(np.tile(np.array([1.0, -1.0], np.float32), (2, 1)))
        share = info["wheel_lateral_force"] / grip
        restarting = step == 5 if mode == AutoresetMode.NEXT_STEP else bool(truncated.all())
        restarted.append(restarting)
        if restarting:
            assert not obs[:, -3:].any()
        else:
            np.testing.assert_allclose(obs[:, -3:], share, rtol=0, atol=1e-6)
            assert np.abs(share).max() > 0
        if mode == AutoresetMode.SAME_STEP and truncated.any():
            for i in range(2):
                np.testing.assert_allclose(info["final_obs"][i][-3:], share[i], rtol=0, atol=1e-6)
    assert sum(restarted) == 1


def test_wheel_grip_observation_refuses_wheels_without_a_grip():
    with pytest.raises(ValueError, match="wheel_grip_observation needs wheels with a grip: wheel_friction must be"):
        WheelGripObservation(gym.make("snake_env/Snake3-v2"))
