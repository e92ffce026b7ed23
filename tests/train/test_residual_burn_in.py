"""ResidualBurnIn: the first policy is the baseline gait, the actor stays frozen for the
burn-in while the critic learns, and the config accepts it in RL Zoo's ``callback`` form."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from snake_env.train import config as cfg
from snake_env.train.callbacks import ResidualBurnIn

ENV = "snake_env/Snake3-v2"
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


def _penalized(learn_log_std=True, penalty=0.4):
    """A SAC model past a 16-step burn-in and its callback, with the penalty configured."""
    kwargs = {"burn_in_steps": 16, "log_std": -2.5, "residual_penalty": penalty, "learn_log_std": learn_log_std,
              "q_scale_every": 8}
    model, config = _sac()
    config["callback"] = [{"snake_env.train.callbacks.ResidualBurnIn": kwargs}]
    config = cfg.validate(config)
    return model, config


def test_residual_penalty_adds_the_gradient_of_td3bc_term():
    model, config = _penalized()
    callback = cfg.make_callbacks(config)[0]
    model.learn(total_timesteps=48, callback=[callback])
    assert callback.q_scale > 0.0  # estimated from the replay buffer during training
    callback.on_training_start(locals(), globals())  # hook on again, as during training
    actor = model.actor
    with torch.no_grad():
        actor.mu.weight.normal_(0.0, 0.5)  # corrections far from zero, where tanh bends
    obs = torch.as_tensor(model.replay_buffer.sample(32).observations)
    expected_mean = actor.mu(actor.latent_pi(actor.extract_features(obs, actor.features_extractor))).detach()

    def grads(loss_of_mean):
        actor.zero_grad()
        mean, _, _ = actor.get_action_dist_params(obs)
        assert torch.equal(mean.detach(), expected_mean)
        loss_of_mean(mean).backward()
        return [p.grad.clone() for p in actor.mu.parameters()]

    hooked = grads(lambda mean: 0.0 * mean.sum())  # the hook alone supplies the gradient
    callback._hook.remove()
    callback._hook = None
    coef = 0.4 * callback.q_scale
    explicit = grads(lambda mean: coef * torch.tanh(mean).pow(2).mean())
    assert all(torch.count_nonzero(g) > 0 for g in hooked)
    for got, want in zip(hooked, explicit):
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-9)


def test_q_scale_is_the_critics_mean_absolute_value_on_normalized_observations():
    model, config = _penalized()
    callback = cfg.make_callbacks(config)[0]
    model.learn(total_timesteps=32, callback=[callback])
    np.random.seed(3)  # the replay buffer samples with numpy's global generator
    callback._estimate_q_scale()
    np.random.seed(3)
    raw = model.replay_buffer.sample(model.batch_size)  # no env: observations as stored, not normalized
    obs = torch.as_tensor(model.get_vec_normalize_env().normalize_obs(raw.observations.numpy()))
    with torch.no_grad():
        expected = model.critic.q1_forward(obs, model.actor(obs, deterministic=True)).abs().mean()
    assert callback.q_scale > 0.0
    assert callback.q_scale == pytest.approx(float(expected), rel=1e-5)


def test_fixed_log_std_stays_while_the_mean_learns():
    model, config = _penalized(learn_log_std=False, penalty=0.0)
    model.learn(total_timesteps=64, callback=cfg.make_callbacks(config))
    actor = model.actor
    assert torch.count_nonzero(actor.mu.weight) > 0  # past the burn-in the mean learned
    assert torch.all(actor.log_std.bias == -2.5) and torch.count_nonzero(actor.log_std.weight) == 0
    assert all(p.requires_grad for p in actor.parameters())  # released after training


@pytest.mark.parametrize("kwargs, pattern", [
    ({"residual_penalty": -1.0}, "residual_penalty must be a finite number >= 0"),
    ({"residual_penalty": float("inf")}, "residual_penalty must be a finite number >= 0"),
    ({"learn_log_std": "no"}, "learn_log_std must be true or false"),
    ({"q_scale_every": 0}, "q_scale_every must be an integer >= 1"),
    ({"actor_lr_scale": 0.0}, r"actor_lr_scale must be a number in \(0, 1\]"),
    ({"actor_lr_scale": 2}, r"actor_lr_scale must be a number in \(0, 1\]"),
])
def test_bad_penalty_settings_are_one_line_errors(kwargs, pattern):
    config = cfg.build_config("sac", ENV, overrides=["learning_starts=0"])
    config["callback"] = [{"snake_env.train.callbacks.ResidualBurnIn": kwargs}]
    with pytest.raises(cfg.ConfigError, match=pattern) as info:
        cfg.validate(config)
    assert "\n" not in str(info.value)


def test_penalty_options_are_refused_for_ppo():
    config = cfg.build_config("ppo", ENV)
    config["callback"] = [{"snake_env.train.callbacks.ResidualBurnIn": {"residual_penalty": 0.4}}]
    with pytest.raises(cfg.ConfigError, match="residual_penalty, learn_log_std and actor_lr_scale are SAC options, not ppo"):
        cfg.validate(config)
    config["callback"] = [{"snake_env.train.callbacks.ResidualBurnIn": {"actor_lr_scale": 0.5}}]
    with pytest.raises(cfg.ConfigError, match="actor_lr_scale are SAC options, not ppo"):
        cfg.validate(config)


def _first_actor_step(actor_lr_scale):
    """Actor and critic parameters before and after SAC's first gradient step (burn-in 0)."""
    model, _ = _sac()
    callback = ResidualBurnIn(burn_in_steps=0, log_std=-2.5, actor_lr_scale=actor_lr_scale)
    with torch.no_grad():  # what the callback's start does on a fresh model, so "before" is the start
        for layer in (model.actor.mu, model.actor.log_std):
            layer.weight.zero_()
        model.actor.mu.bias.zero_()
        model.actor.log_std.bias.fill_(-2.5)
    before = (_actor_state(model), {k: v.clone() for k, v in model.critic.state_dict().items()})
    np.random.seed(0)  # the replay buffer samples with numpy's global generator
    model.learn(total_timesteps=2, callback=[callback])  # one step of the 2 envs, then one gradient step
    return before, (_actor_state(model), model.critic.state_dict(), model.actor.optimizer.param_groups[0]["lr"])


def test_actor_lr_scale_scales_only_the_actors_steps():
    """Adam's step is proportional to its rate, so at actor_lr_scale 0.25 each actor
    parameter moves a quarter as far as at 1.0, the critic moves the same, and the rate
    the optimizer reports is restored after each step."""
    (actor0, critic0), (actor1, critic1, lr1) = _first_actor_step(1.0)
    (actor0_s, critic0_s), (actor1_s, critic1_s, lr_s) = _first_actor_step(0.25)
    for key in actor0:
        torch.testing.assert_close(actor0_s[key], actor0[key])
        full, scaled = actor1[key] - actor0[key], actor1_s[key] - actor0_s[key]
        if torch.count_nonzero(full):
            torch.testing.assert_close(scaled, 0.25 * full, rtol=1e-4, atol=1e-7)
    assert any(torch.count_nonzero(actor1[k] - actor0[k]) for k in actor0)
    for key in critic0:
        torch.testing.assert_close(critic1_s[key], critic1[key])
    assert lr_s == lr1
