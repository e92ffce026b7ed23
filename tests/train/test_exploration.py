"""noise_type: pink (snake_env.train.exploration): SAC's and PPO's rollout actions take one pink-noise process
per sub-env; gradient steps keep SB3's white noise; bad configs are one-line errors."""

import numpy as np
import pytest
import torch as th

from snake_env.train import config as cfg
from snake_env.train.exploration import PinkNoiseDistribution, PinkNoiseGaussian
from snake_env.train.train import main


class _Actor(th.nn.Module):
    pass


def _dist(n_envs=4, action_dim=3, seq_len=256, training=False):
    actor = _Actor()
    actor.train(training)
    dist = PinkNoiseDistribution(action_dim, n_envs, seq_len, actor, seed=0)
    return dist, actor


def _mean_lag1(series):
    """Mean lag-1 autocorrelation over every (env, joint) column of a (time, env, joint) array."""
    return np.mean([np.corrcoef(series[:-1, e, j], series[1:, e, j])[0, 1]
                    for e in range(series.shape[1]) for j in range(series.shape[2])])


def _gaussian(dist, rows, action_dim=3):
    return dist.proba_distribution(th.zeros(rows, action_dim), th.zeros(rows, action_dim))


def test_rollout_noise_is_pink_per_env_and_gradient_noise_is_white():
    dist, actor = _dist()
    steps = np.stack([np.arctanh(_gaussian(dist, 4).sample().numpy().clip(-0.999999, 0.999999))
                      for _ in range(256)])  # (time, env, joint), the Gaussian before the squash
    assert _mean_lag1(steps) > 0.5  # pink: successive rollout steps are strongly correlated
    assert not np.allclose(steps[:, 0], steps[:, 1])  # each sub-env has its own process
    actor.train(True)  # a gradient step: SB3's independent samples
    batch = np.arctanh(_gaussian(dist, 4).sample().numpy().clip(-0.999999, 0.999999))
    white = np.stack([np.arctanh(_gaussian(dist, 4).sample().numpy().clip(-0.999999, 0.999999))
                      for _ in range(256)])
    assert abs(_mean_lag1(white)) < 0.2 and batch.shape == (4, 3)
    actor.train(False)  # a batch of another size (e.g. a stochastic evaluation of one env): white noise too
    assert _gaussian(dist, 1).sample().shape == (1, 3)


def test_log_prob_of_a_pink_action_is_the_gaussians():
    dist, _ = _dist()
    d = _gaussian(dist, 4)
    actions = d.sample()
    reference = th.distributions.Normal(th.zeros(4, 3), th.ones(4, 3))
    gaussian = th.atanh(actions.clamp(-1 + 1e-6, 1 - 1e-6))
    expected = reference.log_prob(gaussian).sum(dim=1) - th.log(1 - actions ** 2 + 1e-6).sum(dim=1)
    assert th.allclose(d.log_prob(actions), expected, atol=1e-4)


def test_ppo_rollout_noise_is_pink_around_the_mean_and_its_log_prob_the_gaussians():
    policy = _Actor()
    policy.train(False)
    dist = PinkNoiseGaussian(3, 4, 256, policy, seed=0)
    mean, log_std = th.full((4, 3), 0.5), th.full((3,), np.log(2.0))
    steps = np.stack([dist.proba_distribution(mean, log_std).sample().numpy() for _ in range(256)])
    noise = (steps - 0.5) / 2.0  # (time, env, joint): the draw behind each action
    assert _mean_lag1(noise) > 0.5 and not np.allclose(noise[:, 0], noise[:, 1])
    assert 0.5 < noise.std() < 1.5  # the policy's std scales a unit-variance draw
    action = th.as_tensor(steps[-1])
    reference = th.distributions.Normal(mean, th.full((4, 3), 2.0)).log_prob(action).sum(dim=1)
    assert th.allclose(dist.log_prob(action), reference, atol=1e-5)
    policy.train(True)  # outside a rollout: SB3's independent samples
    white = np.stack([dist.proba_distribution(mean, log_std).sample().numpy() for _ in range(256)])
    assert abs(_mean_lag1(white)) < 0.2


@pytest.mark.parametrize("entry, message", [
    ({"noise_type": "brown"}, "noise_type must be one of ['pink'] or null"),
    ({"noise_type": "pink", "use_sde": True}, "does not combine with use_sde"),
    ({"noise_type": "pink", "policy": "JointPolicy", "normalize": {"norm_obs": False}},
     "needs policy MlpPolicy or MultiInputPolicy"),
])
@pytest.mark.parametrize("algo", ["sac", "ppo"])
def test_bad_noise_config_is_a_one_line_error(algo, entry, message):
    with pytest.raises(cfg.ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        cfg.validate({"algo": algo, "env_id": "snake_env/Snake3-v3", **entry})


@pytest.mark.parametrize("algo, extra", [("sac", ["--set", "learning_starts=100"]),
                                         ("ppo", ["--set", "n_steps=64", "--set", "batch_size=64"])])
def test_trains_with_pink_noise_end_to_end(tmp_path, capsys, algo, extra):
    run = tmp_path / "run"
    code = main(["--algo", algo, "--env", "snake_env/Snake3-v3", "--total-timesteps", "400", "--run-dir", str(run),
                 "--set", "noise_type=pink", "--set", "n_envs=4", *extra,
                 "--set", "eval_freq=100000", "--set", "checkpoint_freq=100000", "--progress", "none"])
    assert code == 0, capsys.readouterr().err
    assert (run / "model.zip").is_file()
    assert cfg.load_run_config(run / "config.yaml")["noise_type"] == "pink"


def test_apply_exploration_installs_the_distribution_only_when_asked():
    import gymnasium as gym
    from stable_baselines3 import SAC
    from stable_baselines3.common.env_util import make_vec_env

    from snake_env.train.exploration import apply_exploration

    model = SAC("MlpPolicy", make_vec_env(lambda: gym.make("snake_env/Snake3-v3"), n_envs=2), learning_starts=0)
    apply_exploration(model, {"noise_type": None, "seed": 0}, seq_len=100)
    assert not isinstance(model.actor.action_dist, PinkNoiseDistribution)
    apply_exploration(model, {"noise_type": "pink", "seed": 0}, seq_len=100)
    assert isinstance(model.actor.action_dist, PinkNoiseDistribution) and model.actor.action_dist.n_envs == 2
    model.learn(50)  # rollouts and gradient steps run through it


def test_ppo_rollout_actions_are_pink():
    """The installed distribution reaches PPO's rollout buffer: its stored actions are correlated in time."""
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    from snake_env.train.exploration import apply_exploration

    def lag1_of_rollout(noise_type):
        model = PPO("MlpPolicy", make_vec_env(lambda: gym.make("snake_env/Snake3-v3"), n_envs=2), n_steps=256,
                    batch_size=128, n_epochs=1, seed=0)
        apply_exploration(model, {"noise_type": noise_type, "seed": 0}, seq_len=1000)
        model.learn(512)
        actions = model.rollout_buffer.actions  # flattened env by env after the update: (env * time, joint)
        actions = actions.reshape(2, 256, -1).transpose(1, 0, 2)  # (time, env, joint)
        return _mean_lag1(actions - actions.mean(axis=0))

    assert lag1_of_rollout("pink") > 0.4
    assert lag1_of_rollout(None) < 0.3  # white noise around a mean that moves slowly
