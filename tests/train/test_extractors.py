"""GoalFrameExtractor: the goal_frame wrapper's features, computed inside the policy (so HER may relabel)."""

import gymnasium as gym
import numpy as np
import pytest
import torch

import snake_env  # noqa: F401
from snake_env.train import config as cfg
from snake_env.train.extractors import GoalFrameExtractor, goal_frame_kwargs
from snake_env.wrappers import wrap_vector_env

REACH = "snake_env/SnakeReach8-v1"


def test_goal_frame_extractor_equals_the_goal_frame_wrapper_also_for_relabelled_goals():
    """On a batch of 4 snakes after 40 random steps: the extractor's (ahead, left) equal what the goal_frame
    wrapper appends, and for another desired goal (a HER relabelling) they equal the wrapper's formula for it."""
    from snake_env.wrappers.observation import _goal_frame_geometry, _with_goal_frame

    spec = [{"steering_residual": {"baseline": "gait"}}]
    make = lambda: gym.make_vec(REACH, num_envs=4, vectorization_mode="vector_entry_point")  # noqa: E731
    plain, framed = wrap_vector_env(make(), spec), wrap_vector_env(make(), [*spec, "goal_frame"])
    extractor = GoalFrameExtractor(plain.single_observation_space, **goal_frame_kwargs(REACH, {}))
    assert extractor.features_dim == plain.single_observation_space["observation"].shape[0] + 6
    obs, _ = plain.reset(seed=5)
    framed_obs, _ = framed.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(40):
        action = rng.uniform(-1, 1, (4, 2)).astype(np.float32)
        obs = plain.step(action)[0]
        framed_obs = framed.step(action)[0]
    features = extractor({key: torch.as_tensor(value) for key, value in obs.items()}).numpy()
    np.testing.assert_allclose(features[:, -2:], framed_obs["observation"][:, -2:], atol=1e-5)
    np.testing.assert_allclose(features[:, :-6], obs["observation"], atol=1e-6)  # float32 features
    relabelled = {**obs, "desired_goal": obs["achieved_goal"] + rng.uniform(-1, 1, (4, 2)).astype(np.float32)}
    features = extractor({key: torch.as_tensor(value) for key, value in relabelled.items()}).numpy()
    geometry = _goal_frame_geometry(gym.make(REACH))
    expected = _with_goal_frame(relabelled, geometry)["observation"][:, -2:]
    np.testing.assert_allclose(features[:, -2:], expected, atol=1e-5)


def test_goal_frame_is_chosen_by_name_in_policy_kwargs_and_bad_names_are_refused():
    config = cfg.build_config("sac", REACH, overrides=[
        "policy_kwargs=dict(net_arch=[8], features_extractor_class='goal_frame')"])
    kwargs = cfg.torch_policy_kwargs(config)
    assert kwargs["features_extractor_class"] is GoalFrameExtractor
    assert kwargs["features_extractor_kwargs"] == {"n_links": 8, "phi_start": 0}
    config["policy_kwargs"] = "dict(features_extractor_class='goal_fram')"
    with pytest.raises(cfg.ConfigError, match=r"features_extractor_class must be one of \['goal_frame'\], "
                                              r"got 'goal_fram'"):
        cfg.torch_policy_kwargs(config)
    forward = cfg.build_config("sac", "snake_env/Snake5-v2", overrides=[
        "policy_kwargs=dict(features_extractor_class='goal_frame')"])
    with pytest.raises(ValueError, match="goal_frame needs a goal task"):
        cfg.torch_policy_kwargs(forward)
    box = gym.spaces.Box(-1.0, 1.0, (20,))
    with pytest.raises(ValueError, match="goal_frame needs a goal task's Dict observation"):
        GoalFrameExtractor(box, n_links=5)
    space = gym.make(REACH).observation_space
    with pytest.raises(ValueError, match="goal_frame n_links must be an integer >= 2, got 1"):
        GoalFrameExtractor(space, n_links=1)
    with pytest.raises(ValueError, match="goal_frame phi_start must be 0 or 2"):
        GoalFrameExtractor(space, n_links=8, phi_start=1)
