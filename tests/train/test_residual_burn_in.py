"""ResidualBurnIn: the first policy is the baseline gait, the actor stays frozen for the
burn-in while the critic learns, and the config accepts it in RL Zoo's ``callback`` form."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from snake_env.train import config as cfg
from snake_env.train.callbacks import ResidualBurnIn

ENV = "snake_env/Snake3-v1"
BURN_IN = [{"snake_env.train.callbacks.ResidualBurnIn": {"burn_in_steps": 64, "log_std": -2.5}}]


def _sac(overrides=()):
    from snake_env.train.envs import make_vec_env, wrap_normalize
    from snake_env.train.train import build_model

    config = cfg.build_config("sac", ENV, overrides=[
        "env_wrapper=serpenoid_residual", "learning_starts=0", "batch_size=16", "buffer_size=1000",
        "policy_kwargs.net_arch=[16]", "env_kwargs.max_episode_steps=40", *overrides], n_envs=2)
    config["callback"] = BURN_IN
    config = cfg.validate(config)
    venv = wrap_normalize(make_vec_env(config, 2, 0), config, training=True)
    return build_model(config, venv, 0), config


def _actor_state(model):
    return {k: v.clone() for k, v in model.actor.state_dict().items()}


def test_first_policy_is_the_baseline_and_actor_waits_for_the_burn_in():
    model, config = _sac()
    critic_before = {k: v.clone() for k, v in model.critic.state_dict().items()}
    model.learn(total_timesteps=48, callback=cfg.make_callbacks(config))  # inside the 64-step burn-in
    actor = model.actor
    # mean layer zero: the deterministic action is 0, i.e. exactly the serpenoid gait
    assert torch.count_nonzero(actor.mu.weight) == 0 and torch.count_nonzero(actor.mu.bias) == 0
    obs = model.env.reset()
    assert np.array_equal(model.predict(obs, deterministic=True)[0], np.zeros((2, *model.action_space.shape), np.float32))
    assert torch.all(actor.log_std.bias == -2.5) and torch.count_nonzero(actor.log_std.weight) == 0
    # the critic learned meanwhile
    assert any(not torch.equal(v, model.critic.state_dict()[k]) for k, v in critic_before.items())
    # and every actor parameter is trainable again for whatever trains next
    assert all(p.requires_grad for p in actor.parameters())


def test_actor_learns_after_the_burn_in():
    model, config = _sac()
    model.learn(total_timesteps=48, callback=cfg.make_callbacks(config))
    frozen = _actor_state(model)
    # continuing past burn_in_steps (64): the actor's updates start
    model.learn(total_timesteps=48, callback=cfg.make_callbacks(config), reset_num_timesteps=False)
    assert torch.count_nonzero(model.actor.mu.weight) > 0
    assert any(not torch.equal(v, model.actor.state_dict()[k]) for k, v in frozen.items())


@pytest.mark.parametrize("value, pattern", [
    ([{"snake_env.train.callbacks.ResidualBurnIn": {"burn_in_steps": -1}}], "burn_in_steps must be an integer >= 0"),
    ([{"snake_env.train.callbacks.ResidualBurnIn": {"log_std": 5}}], r"log_std must be a number in \[-10, 2\]"),
    ([{"snake_env.train.callbacks.ResidualBurnIn": {"steps": 3}}], "unexpected keyword"),
    ("os.system", "not an importable SB3 callback class"),
    ("snake_env.train.callbacks.NoSuchCallback", "not an importable SB3 callback class"),
    ([["a"]], "callback entries must be dotted class names or one-key mappings"),
])
def test_bad_callback_values_are_one_line_errors(value, pattern):
    config = cfg.build_config("sac", ENV, overrides=["learning_starts=0"])
    config["callback"] = value
    with pytest.raises(cfg.ConfigError, match=pattern) as info:
        cfg.validate(config)
    assert "\n" not in str(info.value)


def test_burn_in_refuses_random_warmup():
    config = cfg.build_config("sac", ENV, overrides=["learning_starts=100"])
    config["callback"] = BURN_IN
    with pytest.raises(cfg.ConfigError, match="ResidualBurnIn needs learning_starts: 0"):
        cfg.validate(config)


def test_callback_reaches_the_zoo_unchanged():
    from snake_env.train.zoo import zoo_entry

    assert zoo_entry({"callback": BURN_IN, "n_envs": 2})["callback"] == BURN_IN


def test_ppo_learns_only_its_value_function_during_the_burn_in():
    from snake_env.train.envs import make_vec_env, wrap_normalize
    from snake_env.train.train import build_model

    config = cfg.build_config("ppo", ENV, overrides=[
        "env_wrapper=serpenoid_residual", "n_steps=16", "batch_size=32", "n_epochs=2",
        "policy_kwargs.net_arch=[16]", "env_kwargs.max_episode_steps=40"], n_envs=2)
    config["callback"] = [{"snake_env.train.callbacks.ResidualBurnIn": {"burn_in_steps": 1000}}]
    config = cfg.validate(config)
    model = build_model(config, wrap_normalize(make_vec_env(config, 2, 0), config, training=True), 0)
    policy = model.policy
    actor_before = [p.clone() for p in (*policy.mlp_extractor.policy_net.parameters(), policy.log_std)]
    value_before = [p.clone() for p in policy.value_net.parameters()]
    model.learn(total_timesteps=64, callback=cfg.make_callbacks(config))
    assert torch.count_nonzero(policy.action_net.weight) == 0 and torch.count_nonzero(policy.action_net.bias) == 0
    after = [*policy.mlp_extractor.policy_net.parameters(), policy.log_std]
    assert all(torch.equal(a, b) for a, b in zip(actor_before, after))
    assert any(not torch.equal(a, b) for a, b in zip(value_before, policy.value_net.parameters()))
