"""RL Baselines3 Zoo interop: our configs as zoo hyperparameters, and a tiny
rl_zoo3.train + rl_zoo3.enjoy round trip (skipped when rl_zoo3 is not installed)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tests.newest_ids import newest_id
from snake_env.train import config as cfg
from snake_env.train.zoo import PROJECT_ONLY_KEYS, zoo_hyperparams

REPO = Path(__file__).resolve().parents[2]
ENV = newest_id("Snake3")
ZOO_NAME = ENV.replace("/", "-")  # RL Zoo's folder name for a namespaced id


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_zoo_hyperparams_cover_our_configs_without_project_keys(algo):
    import torch.nn as nn  # noqa: F401  (the zoo evals policy_kwargs with nn in scope)

    ours = yaml.safe_load(cfg.default_config_path(algo).read_text())
    zoo = zoo_hyperparams(algo)
    assert set(zoo) == {k for k, v in ours.items() if isinstance(v, dict)}
    allowed = set(cfg.algo_arguments(algo)) | {"policy", "n_timesteps", "n_envs", "normalize", "policy_kwargs",
                                                 "env_kwargs"}
    for env_id, entry in zoo.items():
        assert not set(entry) & set(PROJECT_ONLY_KEYS), env_id
        assert set(entry) <= allowed | {"env_wrapper", "callback"}, (env_id, set(entry) - allowed)
        if "env_wrapper" in entry:  # ours is {name: kwargs}; the zoo's a list of {"module.Class": kwargs}
            assert entry["env_wrapper"] and all(len(item) == 1 for item in entry["env_wrapper"]), env_id
        if isinstance(entry.get("policy_kwargs"), str):
            assert isinstance(eval(entry["policy_kwargs"]), dict)
        elif entry["policy"].startswith("snake_env.train.joint_policy."):  # JointPolicy: its class and env layout
            assert entry["policy"].endswith(".JointActorCriticPolicy" if algo == "ppo" else ".JointSACPolicy"), env_id
            assert [name for name, _ in entry["policy_kwargs"]["layout"]][0] == "joint_angles", env_id
            assert entry["normalize"]["norm_obs"] is False, env_id  # its features are scaled by fixed constants
        elif "policy_kwargs" in entry:  # a features extractor of ours: the class itself, for this env's layout
            from snake_env.train.extractors import GoalFrameExtractor

            assert entry["policy_kwargs"]["features_extractor_class"] is GoalFrameExtractor, env_id
            n_links = int(env_id.split("Reach")[1].split("-")[0])
            assert entry["policy_kwargs"]["features_extractor_kwargs"] == {"n_links": n_links, "phi_start": 0}
        assert entry["n_timesteps"] == cfg.coerce_scalar(ours[env_id])["n_timesteps"]


def test_zoo_builds_the_configured_callbacks():
    """``callback`` is RL Zoo's key in its own form; the zoo's loader builds ours from it."""
    from snake_env.train.callbacks import ResidualBurnIn

    entry = zoo_hyperparams("sac")["snake_env/Snake12-v2"]  # the residual entry with its burn-in callback
    rl_zoo3_utils = pytest.importorskip("rl_zoo3.utils")
    (callback,) = rl_zoo3_utils.get_callback_list(entry)
    assert isinstance(callback, ResidualBurnIn) and callback.burn_in_steps > 0


def test_zoo_env_wrapper_builds_our_single_env_wrappers():
    import gymnasium as gym

    from snake_env.wrappers import JointTargetAction, PhaseObservation
    from snake_env.train.zoo import zoo_env_wrapper

    spec = {"joint_target": {"kp": 1.0, "kd": 0.05}, "phase_observation": {"frequencies": [38.0]}}
    assert zoo_env_wrapper(spec) == [{"snake_env.wrappers.JointTargetAction": {"kp": 1.0, "kd": 0.05}},
                                     {"snake_env.wrappers.PhaseObservation": {"frequencies": [38.0]}}]
    rl_zoo3_utils = pytest.importorskip("rl_zoo3.utils")
    wrap = rl_zoo3_utils.get_wrapper_class({"env_wrapper": zoo_env_wrapper(spec)})
    env = wrap(gym.make(newest_id("Snake5")))
    assert isinstance(env, PhaseObservation) and isinstance(env.env, JointTargetAction)
    assert env.observation_space.shape[0] == gym.make(newest_id("Snake5")).observation_space.shape[0] + 2


def test_rl_zoo_train_and_enjoy(tmp_path):
    pytest.importorskip("rl_zoo3")
    pytest.importorskip("requests")  # rl_zoo3.enjoy needs it (the 'zoo' extra installs it)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
           "OMP_NUM_THREADS": "1"}
    common = ["--algo", "ppo", "--env", ENV, "--gym-packages", "snake_env",
              "--env-kwargs", "max_episode_steps:50", "-f", "logs"]
    trained = subprocess.run([sys.executable, "-m", "rl_zoo3.train", *common, "-conf", "snake_env.train.zoo_ppo", "-n", "256",
                            "--eval-freq", "-1", "-params", "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1",
                            "policy_kwargs:dict(net_arch=[8])"],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert trained.returncode == 0, trained.stderr[-2000:]
    run = tmp_path / "logs" / "ppo" / f"{ZOO_NAME}_1"
    assert (run / f"{ZOO_NAME}.zip").is_file()
    assert (run / ZOO_NAME / "vecnormalize.pkl").is_file()  # normalize came from configs/ppo.yaml
    saved = yaml.unsafe_load((run / ZOO_NAME / "config.yml").read_text())
    assert dict(saved)["gae_lambda"] == 0.95
    enjoy = subprocess.run([sys.executable, "-m", "rl_zoo3.enjoy", *common, "--exp-id", "1", "-n", "60",
                            "--no-render"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert enjoy.returncode == 0, enjoy.stderr[-2000:]
    assert "Episode Length 50" in enjoy.stdout


def test_pink_noise_has_no_zoo_form():
    from snake_env.train.zoo import zoo_entry

    with pytest.raises(ValueError, match="noise_type pink .* has no RL Zoo form"):
        zoo_entry({"policy": "MlpPolicy", "noise_type": "pink"}, "snake_env/Snake5-v3")


def test_init_from_has_no_zoo_hyperparameter_form():
    from snake_env.train.zoo import zoo_entry

    with pytest.raises(ValueError, match="init_from has no RL Zoo hyperparameter form"):
        zoo_entry({"policy": "MlpPolicy", "init_from": "runs/joint"}, "snake_env/Snake30-v3")
    assert "init_from" not in zoo_entry({"policy": "MlpPolicy", "init_from": None}, "snake_env/Snake30-v3")


def test_joint_policy_in_the_zoos_form():
    """policy: JointPolicy becomes the class for the algorithm with this env's observation layout, as
    snake-train builds it; n_links_set and observation normalization are one-line errors."""
    from snake_env.train.joint_features import layout_for_id
    from snake_env.train.joint_policy import policy_class
    from snake_env.train.zoo import zoo_entry

    entry = {"policy": "JointPolicy", "policy_kwargs": "dict(hidden=16, log_std_init=-1.0)",
             "normalize": "dict(norm_obs=False, norm_reward=True)"}
    for algo in ("ppo", "sac"):
        zoo = zoo_entry(dict(entry, policy_kwargs="dict(hidden=16)"), ENV, algo)
        cls = policy_class(algo)
        assert zoo["policy"] == f"{cls.__module__}.{cls.__qualname__}"
        assert zoo["policy_kwargs"] == {"hidden": 16, "layout": layout_for_id(ENV, {})}
    assert zoo_entry(entry, ENV, "ppo")["policy_kwargs"]["log_std_init"] == -1.0
    with pytest.raises(ValueError, match="n_links_set .* has no RL Zoo form"):
        zoo_entry(dict(entry, n_links_set=[5, 8]), ENV, "ppo")
    with pytest.raises(ValueError, match="reads raw observations"):
        zoo_entry(dict(entry, normalize=True), ENV, "ppo")
    with pytest.raises(ValueError, match="needs the algorithm"):
        zoo_entry(entry, ENV)


def test_rl_zoo_trains_a_joint_policy(tmp_path):
    """rl_zoo3.train runs a JointPolicy entry given in the zoo's form by a Python config module."""
    pytest.importorskip("rl_zoo3")
    (tmp_path / "joint_conf.py").write_text(
        "from snake_env.train.zoo import zoo_entry\n"
        f"hyperparams = {{{ENV!r}: zoo_entry({{'policy': 'JointPolicy', 'n_timesteps': 128, 'n_envs': 2, "
        "'n_steps': 64, 'batch_size': 64, 'n_epochs': 1, 'policy_kwargs': 'dict(hidden=8)', "
        f"'normalize': 'dict(norm_obs=False, norm_reward=True)'}}, {ENV!r}, 'ppo')}}\n")
    env = {**os.environ, "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(tmp_path), str(REPO), os.environ.get("PYTHONPATH", "")])}
    trained = subprocess.run([sys.executable, "-m", "rl_zoo3.train", "--algo", "ppo", "--env", ENV, "--gym-packages",
                              "snake_env", "--env-kwargs", "max_episode_steps:50", "-f", "logs", "-conf", "joint_conf",
                              "--eval-freq", "-1"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert trained.returncode == 0, trained.stderr[-2000:]
    from stable_baselines3 import PPO

    from snake_env.train.joint_policy import policy_class

    model = PPO.load(tmp_path / "logs" / "ppo" / f"{ZOO_NAME}_1" / f"{ZOO_NAME}.zip", device="cpu")
    assert isinstance(model.policy, policy_class("ppo"))
