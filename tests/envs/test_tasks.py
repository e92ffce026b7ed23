"""The task ids (SnakeCommand, SnakeReach, SnakePath): checkers, determinism,
vector env == single envs, argument checks, GoalEnv compute_reward, registration."""

import math
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import snake_env  # noqa: F401
from snake_env.physics.config import IDEAL_PHYSICS, PHYSICS_HISTORY, TRACTION_LIMIT_PHYSICS
from snake_env.registration import REGISTERED_N_LINKS, registered_ids
from snake_env.tasks import TASKS
from snake_env.tasks.base import squared_norm

# (id, kwargs) of every new task variant, on small snakes to keep the tests fast
CASES = [
    ("snake_env/SnakeCommand5-v2", {}),
    ("snake_env/SnakeReach5-v2", {}),
    ("snake_env/SnakeReach3-v2", {"reward_type": "dense"}),
    ("snake_env/SnakePath5-v3", {"path_type": "line"}),
    ("snake_env/SnakePath3-v3", {"path_type": "circle"}),
    ("snake_env/SnakePath5-v3", {"path_type": "sine"}),
]
IDS = [f"{env_id.split('/')[1]}-{'-'.join(map(str, kw.values())) or 'default'}" for env_id, kw in CASES]


@pytest.mark.parametrize("env_id, kwargs", CASES, ids=IDS)
def test_gymnasium_and_sb3_checkers_pass(env_id, kwargs):
    env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*observation space (minimum|maximum) value is")
        check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(env.unwrapped, warn=True)
    env.close()


@pytest.mark.parametrize("task", TASKS)
def test_registered_version_is_the_newest_of_the_version_history_and_older_ones_are_refused(task):
    """The newest version and the two before (their physics pinned) are registered; older ones are refused."""
    prefix, version = TASKS[task].id_prefix, TASKS[task].version
    history = [int(v) for v in re.findall(r"^\s*\* v(\d+):", TASKS[task].__doc__, re.MULTILINE)]
    assert history and history[0] == max(history) == version
    assert gym.spec(f"snake_env/{prefix}5-v{version - 1}").kwargs["wheel_model"] == "no_slip"
    assert gym.spec(f"snake_env/{prefix}5-v{version - 2}").kwargs["actuator"] == "ideal"
    with pytest.raises(gym.error.DeprecatedEnv, match=f"{prefix}5-v{version}"):
        gym.make(f"snake_env/{prefix}5-v{version - 3}")


def test_every_family_is_registered_for_every_n_with_its_task_settings():
    ids = registered_ids()
    assert len(ids) == (1 + len(PHYSICS_HISTORY)) * len(TASKS) * (1 + len(REGISTERED_N_LINKS))
    for task, cls in TASKS.items():
        prefix, version = cls.id_prefix, cls.version
        for n in REGISTERED_N_LINKS:
            spec = gym.spec(f"snake_env/{prefix}{n}-v{version}")
            assert spec.kwargs == {"task": task, "n_links": n}
            for back, physics in enumerate(PHYSICS_HISTORY, start=1):
                assert gym.spec(f"snake_env/{prefix}{n}-v{version - back}").kwargs == {
                    "task": task, "n_links": n, **physics}
            assert spec.max_episode_steps == cls.max_episode_steps
            assert spec.entry_point.endswith("SnakeGoalEnv" if cls.goal_env else "SnakeEnv")
            assert spec.vector_entry_point == "snake_env.envs.vector:SnakeVectorEnv"
        assert ids[f"snake_env/{prefix}-v{version}"] == {"task": task}
    env = gym.make("snake_env/SnakePath-v3", n_links=7)
    assert env.action_space.shape == (6,) and env.observation_space.shape == (20,)


@pytest.mark.parametrize("old_id, physics", [("snake_env/Snake5-v3", TRACTION_LIMIT_PHYSICS),
                                             ("snake_env/Snake5-v2", IDEAL_PHYSICS)])
def test_an_earlier_version_is_the_newest_task_on_its_physics(old_id, physics):
    """Snake5-v3 is Snake5-v4 with no-slip wheels under the traction limit and braking capped at the current
    limit, Snake5-v2 is Snake5-v4 with ideal torque sources and unlimited grip, step for step; the newest
    differs from both."""
    actions = np.random.default_rng(0).uniform(-1, 1, (50, 4))
    previous = gym.make(old_id)
    pinned = gym.make("snake_env/Snake5-v4", **physics)
    newest = gym.make("snake_env/Snake5-v4")
    for env in (previous, pinned, newest):
        env.reset(seed=0)
    for a in actions:
        obs, reward = previous.step(a)[:2]
        obs_pinned, reward_pinned = pinned.step(a)[:2]
        assert np.array_equal(obs, obs_pinned) and reward == reward_pinned
        newest.step(a)
    assert not np.array_equal(previous.unwrapped.state[0], newest.unwrapped.state[0])
    assert newest.unwrapped.config.actuator == "servo" and newest.unwrapped.config.wheel_friction == 0.8


def _rollout(env, seed, steps=60):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
        flat = np.concatenate([np.ravel(v) for v in obs.values()]) if isinstance(obs, dict) else obs
        out.append(np.concatenate([flat, [reward, terminated, truncated], np.concatenate([np.ravel(v).astype(float) for v in info.values()])]))
        if terminated or truncated:
            break
    return np.concatenate(out)


@pytest.mark.parametrize("env_id, kwargs", CASES, ids=IDS)
def test_deterministic_under_seed(env_id, kwargs):
    a = _rollout(gym.make(env_id, **kwargs), 3)
    b = _rollout(gym.make(env_id, **kwargs), 3)
    c = _rollout(gym.make(env_id, **kwargs), 4)
    assert np.array_equal(a, b)
    assert a.shape != c.shape or not np.array_equal(a, c)


@pytest.mark.parametrize("env_id, kwargs", CASES + [("snake_env/Snake5-v3", {"slip_cost_weight": 1.0})],
                         ids=IDS + ["Snake5-slip"])
def test_the_first_steps_warm_up_changes_nothing(env_id, kwargs):
    """While a background compile runs, the first step evaluates the task once on a copy of the state
    (SnakeBatch._warm_up) to compile its kernels early: the rollout is the same bit for bit."""
    plain = gym.make(env_id, **kwargs)
    warmed = gym.make(env_id, **kwargs)
    calls = []
    batch = warmed.unwrapped._batch
    batch._warm_up_pending = True
    evaluate = batch.task.evaluate
    batch.task.__dict__["evaluate"] = lambda *args: calls.append(1) or evaluate(*args)  # (a frozen dataclass)
    assert np.array_equal(_rollout(plain, 3), _rollout(warmed, 3))
    assert len(calls) == 61 and not batch._warm_up_pending  # 60 steps and the warm-up


def _row(obs, i):
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


def _assert_obs_equal(a, b):
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            assert np.array_equal(a[key], b[key]), key
    else:
        assert np.array_equal(a, b)


@pytest.mark.parametrize("env_id, kwargs", CASES, ids=IDS)
def test_vector_env_equals_single_envs_step_by_step(env_id, kwargs):
    B, steps = 3, 40
    vec = gym.make_vec(env_id, num_envs=B, vectorization_mode="vector_entry_point", autoreset_mode="Disabled",
                       **kwargs)
    obs, _ = vec.reset(seed=11)
    singles = [gym.make(env_id, **kwargs) for _ in range(B)]
    q, u = vec.unwrapped.state
    for i, env in enumerate(singles):
        env.reset(seed=100 + i)  # a different draw, overwritten by the vector env's row i below
        for key, value in vec.unwrapped.task_state.items():
            env.unwrapped.task_state[key][0] = value[i]
        _assert_obs_equal(env.unwrapped.set_state(q[i], u[i]), _row(obs, i))
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, B) + singles[0].action_space.shape)
    for a in actions:
        obs, rewards, terminated, truncated, info = vec.step(a)
        for i, env in enumerate(singles):
            s_obs, s_reward, s_term, s_trunc, s_info = env.step(a[i])
            _assert_obs_equal(s_obs, _row(obs, i))
            assert s_reward == rewards[i] and s_term == terminated[i] and s_trunc == truncated[i]
            for key in vec.unwrapped.step_info_keys:
                assert np.array_equal(s_info[key], info[key][i]), key
        if (terminated | truncated).any():
            break


@pytest.mark.parametrize("env_id, kwargs", CASES, ids=IDS)
def test_vector_env_of_one_reproduces_the_single_env_with_the_same_seed(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    vec = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", **kwargs)
    obs, _ = env.reset(seed=5)
    v_obs, _ = vec.reset(seed=5)
    _assert_obs_equal(obs, _row(v_obs, 0))
    rng = np.random.default_rng(1)
    for _ in range(30):
        a = rng.uniform(-1, 1, env.action_space.shape)
        obs, reward, *_ = env.step(a)
        v_obs, v_reward, *_ = vec.step(a[None])
        _assert_obs_equal(obs, _row(v_obs, 0))
        assert reward == v_reward[0]


@pytest.mark.parametrize("env_id, kwargs, name", [
    ("snake_env/SnakeReach5-v1", {"reward_type": "shaped"}, "reward_type"),
    ("snake_env/SnakeReach5-v1", {"distance_threshold": -0.1}, "distance_threshold"),
    ("snake_env/SnakeReach5-v1", {"goal_distance_range": (2.0, 1.0)}, "goal_distance_range"),
    ("snake_env/SnakeReach5-v1", {"terminate_on_success": "yes"}, "terminate_on_success"),
    ("snake_env/SnakePath5-v2", {"path_type": "spiral"}, "path_type"),
    ("snake_env/SnakePath5-v2", {"radius": 0.0}, "radius"),
    ("snake_env/SnakePath5-v2", {"forward_reward_weight": 1.0}, "forward_reward_weight"),
    ("snake_env/SnakeCommand5-v1", {"speed_range": (0.1,)}, "speed_range"),
    ("snake_env/SnakeCommand5-v1", {"command_period": float("nan")}, "command_period"),
    ("snake_env/SnakeCommand5-v1", {"max_torque": -1.0}, "max_torque"),
    ("snake_env/SnakeCommand5-v1", {"task": "dance"}, "task"),
])
def test_bad_kwargs_raise_one_line_errors_naming_the_argument(env_id, kwargs, name):
    for make in (lambda: gym.make(env_id, **kwargs),
                 lambda: gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **kwargs)):
        with pytest.raises(ValueError, match=name) as info:
            make()
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("reward_type, energy_cost_weight", [("sparse", 0.0), ("dense", 0.0), ("dense", 0.02)])
def test_compute_reward_on_a_batch_equals_the_step_rewards(reward_type, energy_cost_weight):
    env = gym.make("snake_env/SnakeReach5-v1", reward_type=reward_type, distance_threshold=0.5,
                   goal_distance_range=(0.3, 0.6), energy_cost_weight=energy_cost_weight)
    achieved, desired, rewards, infos = [], [], [], []
    rng = np.random.default_rng(0)
    for seed in range(4):
        env.reset(seed=seed)
        for _ in range(80):
            obs, reward, terminated, truncated, info = env.step(rng.uniform(-1, 1, 4))
            achieved.append(obs["achieved_goal"])
            desired.append(obs["desired_goal"])
            rewards.append(reward)
            infos.append(info)
            if terminated or truncated:
                break
    rewards = np.array(rewards)
    batch = env.unwrapped.compute_reward(np.array(achieved), np.array(desired), np.array(infos))
    assert batch.shape == rewards.shape
    assert np.array_equal(batch, rewards)
    if reward_type == "sparse":
        assert set(np.unique(rewards)) <= {-1.0, 0.0} and (rewards == 0.0).any() and (rewards == -1.0).any()
        successes = np.array([i["is_success"] for i in infos])
        assert np.array_equal(successes, rewards == 0.0)
    # the vector env's compute_reward (the one SB3's HerReplayBuffer calls) agrees
    vec = gym.make_vec("snake_env/SnakeReach5-v1", num_envs=2, vectorization_mode="vector_entry_point",
                       reward_type=reward_type, distance_threshold=0.5, energy_cost_weight=energy_cost_weight)
    vec_infos = None if not energy_cost_weight else np.array(infos)
    assert np.array_equal(vec.unwrapped.compute_reward(np.array(achieved), np.array(desired), vec_infos), rewards)
    if energy_cost_weight:
        assert all(i["reward_energy"] == -energy_cost_weight * i["actuator_power"] for i in infos)
        assert any(i["reward_energy"] < 0 for i in infos)
        with pytest.raises(ValueError, match="needs the steps' info"):
            env.unwrapped.compute_reward(np.array(achieved), np.array(desired), None)


@pytest.mark.parametrize("task", ["forward", "command", "path"])
def test_energy_cost_is_the_actuator_power_off_by_default(task):
    """energy_cost_weight: reward = the task's reward - weight * actuator_power (W), in the single and the
    vector env alike; at its default 0 neither the reward nor the info keys change."""
    env_id = f"snake_env/{TASKS[task].id_prefix}5-v{TASKS[task].version}"
    rng = np.random.default_rng(1)
    actions = rng.uniform(-1, 1, (30, 4))
    plain, costly = gym.make(env_id), gym.make(env_id, energy_cost_weight=0.05)
    vec = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", energy_cost_weight=0.05)
    plain.reset(seed=2)
    costly.reset(seed=2)
    vec.reset(seed=2)
    for action in actions:
        *_, reward, _, _, info = plain.step(action)
        *_, cost_reward, _, _, cost_info = costly.step(action)
        _, vec_reward, _, _, vec_info = vec.step(action[None])
        assert "reward_energy" not in info
        assert cost_info["reward_energy"] == -0.05 * cost_info["actuator_power"]
        assert cost_reward == reward + cost_info["reward_energy"] and vec_reward[0] == cost_reward
        assert vec_info["reward_energy"][0] == cost_info["reward_energy"]
    with pytest.raises(ValueError, match="energy_cost_weight must be a finite number >= 0"):
        gym.make(env_id, energy_cost_weight=-1.0)


@pytest.mark.parametrize("task", ["forward", "command", "reach"])
def test_action_rate_cost_is_the_squared_change_of_the_clipped_action(task):
    """action_rate_cost_weight: reward = the task's reward - weight * sum_k (a_k - a_k,prev)^2 of the clipped
    actions, a_prev = 0 after every reset (the vector env's autoreset rows too), in the single and the vector env
    alike; at its default 0 neither the reward nor the info keys change. Reach's compute_reward (HER) adds it."""
    env_id = f"snake_env/{TASKS[task].id_prefix}5-v{TASKS[task].version}"
    rng = np.random.default_rng(3)
    actions = rng.uniform(-1.6, 1.6, (40, 4))  # beyond [-1, 1] too: the cost is on what the motors were sent
    weight = 0.3
    plain, costly = gym.make(env_id), gym.make(env_id, action_rate_cost_weight=weight)
    vec = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", action_rate_cost_weight=weight)
    for seed in (2, 5):  # the second episode starts again from a_prev = 0
        plain.reset(seed=seed)
        costly.reset(seed=seed)
        vec.reset(seed=seed)
        previous = np.zeros(4)
        for action in actions:
            *_, reward, _, _, info = plain.step(action)
            *_, cost_reward, _, _, cost_info = costly.step(action)
            _, vec_reward, _, _, vec_info = vec.step(action[None])
            clipped = np.clip(action, -1.0, 1.0)
            expected = -weight * np.sum((clipped - previous) ** 2)
            previous = clipped
            assert "reward_action_rate" not in info
            assert cost_info["reward_action_rate"] == pytest.approx(expected, rel=1e-12, abs=1e-15)
            assert cost_reward == reward + cost_info["reward_action_rate"] and vec_reward[0] == cost_reward
            assert vec_info["reward_action_rate"][0] == cost_info["reward_action_rate"]
    # a partial reset (the vector env's autoreset rows) starts only those rows again from a_prev = 0
    pair = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", action_rate_cost_weight=weight)
    pair.reset(seed=0)
    first, second = np.clip(actions[:2], -1.0, 1.0)
    pair.step(np.stack([first, first]))
    pair.reset(options={"reset_mask": np.array([True, False])})
    _, _, _, _, pair_info = pair.step(np.stack([second, second]))
    assert pair_info["reward_action_rate"][0] == pytest.approx(-weight * np.sum(second ** 2), rel=1e-12)
    assert pair_info["reward_action_rate"][1] == pytest.approx(-weight * np.sum((second - first) ** 2), rel=1e-12)
    if task == "reach":
        # HER's relabelling: the stored step's cost comes back from its info
        obs, *_ = costly.reset(seed=7)
        obs, reward, _, _, info = costly.step(actions[0])
        relabelled = costly.unwrapped.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
        assert relabelled == reward and info["reward_action_rate"] < 0.0
    with pytest.raises(ValueError, match="action_rate_cost_weight must be a finite number >= 0"):
        gym.make(env_id, action_rate_cost_weight=-1.0)


def test_reach_terminates_on_success_and_reports_it():
    env = gym.make("snake_env/SnakeReach5-v1")
    obs, _ = env.reset(seed=0)
    goal = obs["desired_goal"]
    q, u = env.unwrapped.state
    assert 0.5 <= np.linalg.norm(goal) <= 1.5
    # move the snake so that its CM sits on the goal: the next step succeeds and terminates
    q[-2:] += goal - obs["achieved_goal"]
    env.unwrapped.set_state(q, np.zeros(2))
    obs, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert info["is_success"] and terminated and reward == 0.0 and info["goal_distance"] < 0.1


def test_command_is_resampled_every_period_within_its_ranges():
    env = gym.make("snake_env/SnakeCommand5-v1", command_period=1.0, speed_range=(0.2, 0.4),
                   yaw_rate_range=(-0.3, -0.1))
    obs, _ = env.reset(seed=0)
    commands = [obs[-4:-2].copy()]
    for _ in range(75):  # 3 s of 0.04 s steps
        obs, *_ = env.step(np.zeros(4))
        commands.append(obs[-4:-2].copy())
    commands = np.array(commands)
    changes = np.flatnonzero(np.any(np.diff(commands, axis=0) != 0, axis=1)) + 1
    assert changes.tolist() == [25, 50, 75]
    assert (commands[:, 0] >= 0.2).all() and (commands[:, 0] <= 0.4).all()
    assert (commands[:, 1] >= -0.3).all() and (commands[:, 1] <= -0.1).all()


@pytest.mark.parametrize("path_type", ["line", "circle", "sine"])
def test_cross_track_error_is_the_signed_distance_to_the_closest_path_point(path_type):
    env = gym.make("snake_env/SnakePath5-v2", path_type=path_type, initial_offset=0.4)
    task = env.unwrapped.task
    signs = set()
    rng = np.random.default_rng(0)
    for seed in range(4):
        obs, info = env.reset(seed=seed)
        offset = env.unwrapped.task_state["offset"][0]
        assert abs(offset) == 0.4
        signs.add(np.sign(offset))
        for step in range(40):
            cm = np.array([info["x_position"], info["y_position"]])
            # brute force: the distance to a dense sampling of the path
            x = np.linspace(cm[0] - 3, cm[0] + 3, 600001)
            if path_type == "circle":
                a = np.linspace(-np.pi, np.pi, 600001)
                points = np.stack([task.radius * np.cos(a), offset + task.radius * (1 + np.sin(a))], axis=-1)
            else:
                y = offset + (task.amplitude * np.sin(2 * np.pi * x / task.wavelength) if path_type == "sine" else 0 * x)
                points = np.stack([x, y], axis=-1)
            nearest = np.min(np.hypot(*(points - cm).T))
            assert abs(obs[-4]) == pytest.approx(nearest, abs=1e-4)
            if step == 0:  # the CM starts at the origin, on the side opposite to the offset
                assert np.sign(obs[-4]) == -np.sign(offset)
            obs, _, _, _, info = env.step(rng.uniform(-1, 1, 4))
    assert signs == {-1.0, 1.0}


def test_path_progress_along_a_line_is_the_x_speed():
    env = gym.make("snake_env/SnakePath5-v2", path_type="line")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        _, reward, _, _, info = env.step(rng.uniform(-1, 1, 4))
        assert info["path_speed"] == pytest.approx(info["x_velocity"], rel=1e-12, abs=1e-12)
        assert info["cross_track_error"] == pytest.approx(info["y_position"] - env.unwrapped.task_state["offset"][0])
        assert reward == pytest.approx(info["reward_progress"] + info["reward_cross_track"] + info["reward_ctrl"])


@pytest.mark.parametrize("env_id, kwargs", CASES, ids=IDS)
def test_rendering_draws_the_task_overlay(env_id, kwargs):
    env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    env.reset(seed=0)
    frame = env.render()
    from snake_env.envs.rendering import OVERLAY

    assert frame.shape == (480, 480, 3)
    # the goal / path / command arc is drawn in the overlay colour
    assert np.any(np.all(frame == OVERLAY.astype(np.uint8), axis=-1))


@pytest.mark.parametrize("length", [0, 1, 7, 8, 9, 29, 128, 129, 300, 1031])
def test_compiled_squared_norm_has_the_bits_of_numpys_sum(length):
    """The control cost's compiled ||a||^2 follows numpy's pairwise summation, so the forward
    task's rewards keep the bits they had when they were computed with np.sum (the fixture)."""
    a = np.random.default_rng(length).uniform(-1.0, 1.0, (3, length))
    assert np.array_equal(squared_norm(a), np.sum(np.square(a), axis=-1))


def test_path_progress_is_bounded_by_the_cm_speed_even_at_a_circles_centre():
    """v1: the progress term is the CM velocity along the path tangent, so it never exceeds
    the CM's speed; v0's arc-length rate of the closest point did near the centre of a small
    circle (a policy circled there for 10 m/s of progress)."""
    env = gym.make("snake_env/SnakePath5-v2", path_type="circle", radius=0.1, initial_offset=0.0,
                   max_cross_track_error=5.0)
    env.reset(seed=0)
    env.action_space.seed(0)
    near_centre = 0
    for _ in range(300):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        speed = math.hypot(info["x_velocity"], info["y_velocity"])
        assert abs(info["path_speed"]) <= speed + 1e-12
        near_centre += info["cross_track_error"] > 0.02  # inside, where ds/dt = v_t / (1 - e / r) > v_t
        if terminated or truncated:
            env.reset()
    assert near_centre > 0  # the case that broke v0 was exercised
