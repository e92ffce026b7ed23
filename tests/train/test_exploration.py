"""noise_type: pink (snake_env.train.exploration): SAC's rollout actions take one pink-noise process per
sub-env; gradient steps keep SB3's white noise; bad configs are one-line errors."""

import numpy as np
import pytest
import torch as th

from snake_env.train import config as cfg
from snake_env.train.exploration import PinkNoiseDistribution
from snake_env.train.train import main


class _Actor(th.nn.Module):
    pass


def _dist(n_envs=4, action_dim=3, seq_len=256, training=False):
    actor = _Actor()
    actor.train(training)
    dist = PinkNoiseDistribution(action_dim, n_envs, seq_len, actor, seed=0)
    return dist, actor


def _gaussian(dist, rows, action_dim=3):
    return dist.proba_distribution(th.zeros(rows, action_dim), th.zeros(rows, action_dim))


def test_rollout_noise_is_pink_per_env_and_gradient_noise_is_white():
    dist, actor = _dist()
    steps = np.stack([np.arctanh(_gaussian(dist, 4).sample().numpy().clip(-0.999999, 0.999999))
                      for _ in range(256)])  # (time, env, joint), the Gaussian before the squash
    lag1 = np.mean([np.corrcoef(steps[:-1, e, j], steps[1:, e, j])[0, 1] for e in range(4) for j in range(3)])
    assert lag1 > 0.5  # pink: successive rollout steps are strongly correlated
    assert not np.allclose(steps[:, 0], steps[:, 1])  # each sub-env has its own process
    actor.train(True)  # a gradient step: SB3's independent samples
    batch = np.arctanh(_gaussian(dist, 4).sample().numpy().clip(-0.999999, 0.999999))
    white = np.stack([np.arctanh(_gaussian(dist, 4).sample().numpy().clip(-0.999999, 0.999999))
                      for _ in range(256)])
    lag1_white = np.mean([np.corrcoef(white[:-1, e, j], white[1:, e, j])[0, 1] for e in range(4) for j in range(3)])
    assert abs(lag1_white) < 0.2 and batch.shape == (4, 3)
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


@pytest.mark.parametrize("entry, message", [
    ({"noise_type": "brown"}, "noise_type must be one of ['pink'] or null"),
    ({"noise_type": "pink", "use_sde": True}, "does not combine with use_sde"),
])
def test_bad_noise_config_is_a_one_line_error(entry, message):
    with pytest.raises(cfg.ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
        cfg.validate({"algo": "sac", "env_id": "snake_env/Snake3-v3", **entry})
    with pytest.raises(cfg.ConfigError, match="needs algo sac"):
        cfg.validate({"algo": "ppo", "env_id": "snake_env/Snake3-v3", "noise_type": "pink"})


def test_sac_trains_with_pink_noise_end_to_end(tmp_path, capsys):
    run = tmp_path / "run"
    code = main(["--algo", "sac", "--env", "snake_env/Snake3-v3", "--total-timesteps", "400", "--run-dir", str(run),
                 "--set", "noise_type=pink", "--set", "learning_starts=100", "--set", "n_envs=4",
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
