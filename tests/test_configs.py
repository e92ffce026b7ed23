"""Every registered locomotion id (newest version of each name) ships a PPO,
a SAC and a serpenoid entry, so a new variant cannot be registered without them."""

from __future__ import annotations

import re

import pytest
from gymnasium.envs.registration import find_highest_version, registry

import snake_env  # noqa: F401  (registers the ids)
from snake_env.controllers.gaits import load_gaits
from snake_env.train.config import build_config, read_yaml, default_config_path

# locomotion names: "Snake" (n_links kwarg) and "Snake<n>"; task ids (SnakeReach<n>, ...) have their own configs
LOCOMOTION_NAME = re.compile(r"^Snake\d*$")


def newest_locomotion_ids() -> list[str]:
    names = {spec.name for spec in registry.values() if spec.namespace == "snake_env" and LOCOMOTION_NAME.match(spec.name)}
    return sorted(f"snake_env/{name}-v{find_highest_version('snake_env', name)}" for name in names)


def test_the_registry_has_every_size():
    ids = newest_locomotion_ids()
    assert len(ids) == 7, ids  # Snake and Snake3, 5, 8, 12, 20, 30


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_every_locomotion_id_has_a_valid_training_entry(algo):
    entries = read_yaml(default_config_path(algo))
    missing = [env_id for env_id in newest_locomotion_ids() if env_id not in entries]
    assert not missing, f"configs/{algo}.yaml has no entry for {missing}"
    for env_id in newest_locomotion_ids():
        build_config(algo, env_id)  # merges and validates the entry (keys, wrappers, schedules)


def test_every_locomotion_id_has_a_searched_serpenoid():
    gaits = load_gaits()
    missing = [env_id for env_id in newest_locomotion_ids() if env_id not in gaits]
    assert not missing, f"configs/serpenoid.yaml has no gait for {missing} (run: python -m snake_env.agents.search --env ID)"
    for env_id in newest_locomotion_ids():
        assert gaits[env_id]["search"]["mean_forward_velocity"] > 0.0, env_id


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_newest_locomotion_entries_learn_from_plain_joint_torques(algo):
    """No gait prior (residual, steering, CPG, joint targets) between the shipped policy and the torques of
    the newest forward ids; the residual modes stay opt-in (and in the previous ids' entries). An entry may
    add to the observation (docs/wrappers.md): its wrapped env, stepped with the same seed and actions as the
    bare env, gives the bare env's observation as its first entries, its rewards and its end of episode,
    so the policy's action reaches the motors unchanged."""
    import gymnasium as gym
    import numpy as np

    from snake_env.wrappers import wrap_env

    for env_id in newest_locomotion_ids():
        config = build_config(algo, env_id)
        if not config.get("env_wrapper"):
            continue
        kwargs = dict(config.get("env_kwargs") or {})
        bare, wrapped = gym.make(env_id, **kwargs), wrap_env(gym.make(env_id, **kwargs), config["env_wrapper"])
        assert wrapped.action_space == bare.action_space, env_id
        obs_bare, _ = bare.reset(seed=3)
        obs_wrapped, _ = wrapped.reset(seed=3)
        size = obs_bare.shape[0]
        assert obs_wrapped.shape[0] > size, env_id
        np.testing.assert_array_equal(obs_wrapped[:size], obs_bare)
        actions = np.random.default_rng(0).uniform(-1.0, 1.0, (40,) + bare.action_space.shape)
        for action in actions:
            obs_bare, reward_bare, term_bare, trunc_bare, _ = bare.step(action)
            obs_wrapped, reward_wrapped, term_wrapped, trunc_wrapped, _ = wrapped.step(action)
            np.testing.assert_array_equal(obs_wrapped[:size], obs_bare)
            assert (reward_wrapped, term_wrapped, trunc_wrapped) == (reward_bare, term_bare, trunc_bare), env_id
