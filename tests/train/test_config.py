"""Config flows once: YAML entry -> --set overrides -> explicit flags; bad keys are errors."""

from __future__ import annotations

import pytest
import yaml

from snake_env.train import config as cfg

ENV = "snake_env/Snake3-v2"


@pytest.fixture
def yaml_file(tmp_path):
    path = tmp_path / "hp.yaml"
    path.write_text(
        "snake_env/Snake3-v2:\n"
        "  n_timesteps: !!float 1e5\n"
        "  n_envs: 8\n"
        "  gamma: 0.99\n"
        "  learning_rate: 3e-4\n"  # YAML 1.1 reads this as a string; it must become a float
        "  normalize: \"{'norm_obs': True, 'norm_reward': False}\"\n"
        "  policy_kwargs: \"dict(net_arch=[32, 32], activation_fn=nn.Tanh)\"\n"
        "  env_kwargs: {max_torque: 2.0}\n"
    )
    return path


def test_yaml_values_are_read_and_typed(yaml_file):
    config = cfg.build_config("ppo", ENV, yaml_file)
    assert config["n_timesteps"] == 100_000 and isinstance(config["n_timesteps"], int)
    assert config["learning_rate"] == pytest.approx(3e-4) and isinstance(config["learning_rate"], float)
    assert cfg.normalize_options(config["normalize"], config["gamma"]) == {
        "norm_obs": True, "norm_reward": False, "gamma": 0.99}
    import torch.nn as nn

    assert cfg.torch_policy_kwargs(config) == {"net_arch": [32, 32], "activation_fn": nn.Tanh}
    # meta defaults filled, run keys set
    assert config["algo"] == "ppo" and config["env_id"] == ENV and config["seed"] == 0
    assert config["vec_env"] == cfg.META_DEFAULTS["vec_env"]


def test_precedence_yaml_then_set_then_flags(yaml_file):
    config = cfg.build_config("ppo", ENV, yaml_file, overrides=["gamma=0.999", "n_envs=4", "env_kwargs.n_links=3",
                                                                 "policy_kwargs.net_arch=[16]"],
                              n_envs=2, seed=7)
    assert config["gamma"] == 0.999  # --set beats YAML
    assert config["n_envs"] == 2  # the explicit flag beats --set
    assert config["seed"] == 7
    assert config["env_kwargs"] == {"max_torque": 2.0, "n_links": 3}  # dotted keys merge into the mapping
    # the zoo string was parsed into a mapping to receive the dotted override
    assert cfg.policy_kwargs_dict(config["policy_kwargs"])["net_arch"] == [16]
    assert cfg.policy_kwargs_dict(config["policy_kwargs"])["activation_fn"] == "nn.Tanh"
    # later --set wins over earlier --set
    assert cfg.build_config("ppo", ENV, yaml_file, overrides=["gamma=0.9", "gamma=0.95"])["gamma"] == 0.95


def test_unknown_key_lists_valid_keys(yaml_file):
    with pytest.raises(cfg.ConfigError) as info:
        cfg.build_config("ppo", ENV, yaml_file, overrides=["gamm=0.9"])
    message = str(info.value)
    assert "gamm" in message and "'gamma'" in message and "'n_steps'" in message and "\n" not in message
    # a key valid for SAC is not valid for PPO
    with pytest.raises(cfg.ConfigError, match="tau"):
        cfg.build_config("ppo", ENV, yaml_file, overrides=["tau=0.01"])
    assert cfg.build_config("sac", ENV, yaml_file, overrides=["tau=0.01"])["tau"] == 0.01


def test_unknown_algo_and_env_list_valid_ones(yaml_file):
    with pytest.raises(cfg.ConfigError, match=r"\['ppo', 'sac'\]"):
        cfg.build_config("a2c", ENV, yaml_file)
    with pytest.raises(cfg.ConfigError, match="available env ids: \\['snake_env/Snake3-v2'\\]"):
        cfg.build_config("ppo", "snake_env/Snake9-v2", yaml_file)


@pytest.mark.parametrize("override, pattern", [
    ("n_envs=0", "n_envs must be a positive integer"),
    ("vec_env=subproc", "vec_env must be one of"),
    ("normalize={'norm_obz': true}", "unknown normalize key"),
    ("policy_kwargs=\"dict(activation_fn=os.system)\"", "unsupported expression"),
    ("learning_rate=exp_1e-3", "learning_rate must be a number or 'lin_<number>'"),
    ("gamma", "--set expects key=value"),
    ("env_kwargs=3", "env_kwargs must be a mapping"),
])
def test_bad_values_are_one_line_errors(yaml_file, override, pattern):
    with pytest.raises(cfg.ConfigError, match=pattern) as info:
        cfg.build_config("ppo", ENV, yaml_file, overrides=[override])
    assert "\n" not in str(info.value)


def test_algo_and_env_cannot_come_from_the_yaml(tmp_path):
    path = tmp_path / "hp.yaml"
    path.write_text("snake_env/Snake3-v2:\n  algo: sac\n")
    with pytest.raises(cfg.ConfigError, match="algo cannot be set"):
        cfg.build_config("ppo", ENV, path)


def test_linear_schedule():
    schedule = cfg.parse_schedule("learning_rate", "lin_1e-3")
    assert schedule(1.0) == pytest.approx(1e-3) and schedule(0.25) == pytest.approx(2.5e-4)


def test_saved_config_round_trips(tmp_path, yaml_file):
    config = cfg.build_config("sac", ENV, yaml_file, overrides=["learning_rate=lin_7e-4"], seed=3)
    cfg.save_config(config, tmp_path / "run" / "config.yaml")
    assert cfg.load_run_config(tmp_path / "run" / "config.yaml") == config
    assert not list((tmp_path / "run").glob(".*tmp*"))  # no temp file left behind


@pytest.mark.parametrize("algo", cfg.ALGOS)
def test_shipped_configs_are_valid(algo):
    """Every entry of configs/<algo>.yaml merges and its keys are accepted by SB3."""
    data = yaml.safe_load(cfg.default_config_path(algo).read_text())
    for env_id in ("snake_env/Snake3-v2", "snake_env/Snake5-v2", "snake_env/Snake8-v2"):
        assert env_id in data
    for env_id in data:
        config = cfg.build_config(algo, env_id)
        kwargs = cfg.algo_kwargs(config)
        # sparse goal tasks use RL Zoo's goal-env discount (FetchReach: 0.95); the rest dense rewards
        low = 0.95 if "Reach" in env_id and config.get("replay_buffer_class") == "HerReplayBuffer" else 0.98
        assert low <= kwargs["gamma"] <= 0.9999
        cfg.torch_policy_kwargs(config)


def test_config_lookup_precedence(tmp_path, monkeypatch):
    """./configs/<algo>.yaml of the working directory wins over the shipped file; --config over both."""
    shipped = cfg.shipped_config_path("ppo.yaml")
    assert shipped.is_file() and shipped.parent.name == "configs"
    monkeypatch.chdir(tmp_path)
    assert cfg.default_config_path("ppo") == shipped  # no ./configs here
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "ppo.yaml").write_text("snake_env/Snake3-v2:\n  n_steps: 64\n  batch_size: 64\n")
    assert cfg.default_config_path("ppo") == tmp_path / "configs" / "ppo.yaml"
    assert cfg.build_config("ppo", "snake_env/Snake3-v2")["n_steps"] == 64
    assert cfg.default_config_path("sac") == cfg.shipped_config_path("sac.yaml")  # per file
    with pytest.raises(cfg.ConfigError, match="no ppo hyperparameters for env 'snake_env/Snake5-v2'"):
        cfg.build_config("ppo", "snake_env/Snake5-v2")
    assert cfg.build_config("ppo", "snake_env/Snake5-v2", config_path=shipped)["n_envs"] == 32
