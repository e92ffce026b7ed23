"""The serpenoid search (snake_env.agents.search): its score, its result, the shipped gaits it wrote."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import snake_env  # noqa: F401
from snake_env.agents import search
from snake_env.controllers.gaits import load_gaits, load_params
from snake_env.controllers.serpenoid import SerpenoidController, SerpenoidParams

ENV = "snake_env/Snake3-v2"


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
    params, env_kwargs = load_params(ENV, path)
    assert params == result.params and env_kwargs == {}
    with pytest.raises(ValueError, match="no serpenoid gait for env"):
        load_params("snake_env/Snake30-v2", path)


def test_shipped_gaits_reproduce_their_recorded_speed():
    """configs/serpenoid.yaml: the stored gaits reproduce, from starts the
    search never saw, a mean forward speed close to the one it recorded."""
    gaits = load_gaits()
    assert "snake_env/Snake3-v2" in gaits and "snake_env/Snake5-v2" in gaits
    for env_id in ("snake_env/Snake3-v2", "snake_env/Snake5-v2"):
        params, env_kwargs = load_params(env_id)
        recorded = gaits[env_id]["search"]["mean_forward_velocity"]
        speed = search.rollout_speeds(env_id, env_kwargs, [params] * 8, 1000, seed=123).mean()
        assert speed > 0.8 * recorded > 0


def test_a_length_with_no_id_is_searched_on_the_generic_id(tmp_path, capsys):
    """--n-links n on snake_env/Snake-vN saves the gait as snake_env/Snake{n}-vN, where the baselines of
    n_links=n look it up (gait_for_links); other ids or lengths are a one-line error, exit 2."""
    from snake_env.controllers.gaits import gait_for_links

    path = tmp_path / "serpenoid.yaml"
    args = ["--population", "4", "--generations", "1", "--search-steps", "20", "--repeats", "1",
            "--final-episodes", "1", "--output", str(path)]
    assert search.main(["--env", "snake_env/Snake-v3", "--n-links", "4", *args]) == 0
    gaits = load_gaits(path)
    assert list(gaits) == ["snake_env/Snake4-v3"] and gaits["snake_env/Snake4-v3"]["env_kwargs"] == {"n_links": 4}
    assert gait_for_links(4, path)[0] == SerpenoidParams.from_dict(gaits["snake_env/Snake4-v3"]["params"])
    for bad in (["--env", "snake_env/Snake5-v3", "--n-links", "4"], ["--env", "snake_env/Snake-v3", "--n-links", "1"]):
        with pytest.raises(SystemExit) as exit_info:
            search.main([*bad, *args])
        assert exit_info.value.code == 2
        assert "--n-links needs the generic id snake_env/Snake-vN" in capsys.readouterr().err


def test_outside_share_is_the_share_of_wheel_steps_the_env_flags():
    """rollout_scores' second value is the mean over steps and wheels of info["wheel_slip"] in a single env."""
    env_id = "snake_env/Snake8-v3"
    params = load_params(env_id)[0]  # the searched Snake8-v3 gait leaves the cone (19 % of wheel-steps over 1000 steps)
    steps = 120
    speeds, shares = search.rollout_scores(env_id, {}, [params], steps, seed=3)
    env = gym.make(env_id)
    controller = SerpenoidController(params, 8, env.unwrapped.max_torque, env.unwrapped.dt)
    obs, _ = env.reset(seed=3)
    flags = []
    for _ in range(steps):
        obs, _, _, _, info = env.step(controller.act(obs))
        flags.append(info["wheel_slip"])
    env.close()
    assert shares[0] == pytest.approx(np.mean(flags), rel=1e-12)
    assert 0.0 < shares[0] < 0.6
    _, no_grip = search.rollout_scores("snake_env/Snake8-v2", {}, [params], 20, seed=3)
    assert no_grip[0] == 0.0  # v2: unlimited grip, no info["wheel_slip"]


def test_slip_limit_ranks_every_gait_within_it_above_every_gait_beyond_it():
    scores = np.array([0.30, 0.02, 0.50, 0.40, -0.10, 0.20])
    shares = np.array([0.005, 0.0, 0.02, 0.30, 0.0, 0.011])
    limited = search.limit_slip(scores, shares, 0.01)
    within, beyond = limited[shares <= 0.01], limited[shares > 0.01]
    np.testing.assert_array_equal(within, scores[shares <= 0.01])
    assert beyond.max() < within[within > 0.0].min()
    assert limited[5] > limited[2] > limited[3]  # nearer the limit ranks higher


def test_search_with_a_slip_limit_returns_a_gait_within_it():
    env_id = "snake_env/Snake8-v3"
    result = search.search(env_id, population=8, generations=1, elite=2, search_steps=40, repeats=1, final_steps=60,
                           final_episodes=2, finalists=3, seed=2, max_outside_share=0.05)
    assert result.outside_share <= 0.05 and result.max_outside_share == 0.05
    with pytest.raises(ValueError, match="max_outside_share must be in"):
        search.search(env_id, max_outside_share=1.0)
