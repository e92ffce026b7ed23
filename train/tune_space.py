"""Hyperparameter search spaces of ``snake-tune``, one per algorithm.

Each space is a table of :class:`Dimension`: an Optuna parameter (its name,
distribution and choices, as they appear in the study and its plots) and the
config key it sets (dotted keys reach into ``policy_kwargs``, as ``--set``
does). The ranges start from RL Baselines3 Zoo's ``hyperparams_opt.py``
(``sample_ppo_params`` / ``sample_sac_params``), widened where the snake envs
need it: γ up to 0.9999, PPO's ``log_std_init`` (the hand-tuned configs found
action std 1 important for fast gaits), SAC's ``learning_starts``, separate
``train_freq`` / ``gradient_steps`` (several batched envs per vector step) and gSDE.

A config key fixed with ``--set`` (or every key, with ``--baseline``) is not
searched. Values go into the config as ``configs/<algo>.yaml`` spells them, so
the best trial's config is written back in that format unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

# zoo names -> the networks (PPO: separate policy / value nets)
PPO_NETS = {"tiny": {"pi": [64], "vf": [64]}, "small": {"pi": [64, 64], "vf": [64, 64]},
            "medium": {"pi": [256, 256], "vf": [256, 256]}}
SAC_NETS = {"small": [64, 64], "medium": [256, 256], "big": [400, 300]}
ACTIVATIONS = {"tanh": "nn.Tanh", "relu": "nn.ReLU"}


@dataclass(frozen=True)
class Dimension:
    """One searched Optuna parameter and the config key it sets."""

    param: str  # Optuna parameter name
    key: str  # config key (dotted: inside policy_kwargs)
    kind: str  # "float", "int" or "categorical"
    low: float | None = None
    high: float | None = None
    log: bool = False
    choices: tuple = ()
    to_config: Callable[[Any], Any] = lambda value: value  # Optuna value -> config value

    def suggest(self, trial) -> Any:
        if self.kind == "float":
            value = trial.suggest_float(self.param, self.low, self.high, log=self.log)
        elif self.kind == "int":
            value = trial.suggest_int(self.param, int(self.low), int(self.high), log=self.log)
        else:
            value = trial.suggest_categorical(self.param, list(self.choices))
        return self.to_config(value)

    def describe(self) -> str:
        if self.kind == "categorical":
            return f"{self.param} in {list(self.choices)}"
        scale = "log-uniform" if self.log else "uniform"
        return f"{self.param} {scale} in [{self.low:g}, {self.high:g}]"


def _one_minus(value: float) -> float:
    return round(1.0 - value, 10)


SPACES: dict[str, tuple[Dimension, ...]] = {
    "ppo": (
        Dimension("n_steps", "n_steps", "categorical", choices=(32, 64, 128, 256, 512)),  # per env
        Dimension("batch_size", "batch_size", "categorical", choices=(256, 512, 1024, 2048)),
        Dimension("n_epochs", "n_epochs", "categorical", choices=(1, 5, 10, 20)),
        Dimension("one_minus_gamma", "gamma", "float", 1e-4, 0.05, log=True, to_config=_one_minus),
        Dimension("one_minus_gae_lambda", "gae_lambda", "float", 1e-3, 0.1, log=True, to_config=_one_minus),
        Dimension("learning_rate", "learning_rate", "float", 1e-5, 3e-3, log=True),
        Dimension("ent_coef", "ent_coef", "float", 1e-8, 0.1, log=True),
        Dimension("clip_range", "clip_range", "categorical", choices=(0.1, 0.2, 0.3, 0.4)),
        Dimension("max_grad_norm", "max_grad_norm", "float", 0.3, 2.0),
        Dimension("net_arch", "policy_kwargs.net_arch", "categorical", choices=tuple(PPO_NETS),
                  to_config=lambda name: PPO_NETS[name]),
        Dimension("activation_fn", "policy_kwargs.activation_fn", "categorical", choices=tuple(ACTIVATIONS),
                  to_config=lambda name: ACTIVATIONS[name]),
        Dimension("log_std_init", "policy_kwargs.log_std_init", "float", -2.0, 1.0),
    ),
    "sac": (
        Dimension("one_minus_gamma", "gamma", "float", 1e-4, 0.05, log=True, to_config=_one_minus),
        Dimension("learning_rate", "learning_rate", "float", 1e-5, 3e-3, log=True),
        Dimension("batch_size", "batch_size", "categorical", choices=(64, 128, 256, 512, 1024)),
        Dimension("buffer_size", "buffer_size", "categorical", choices=(50_000, 300_000, 1_000_000)),
        Dimension("learning_starts", "learning_starts", "categorical", choices=(0, 1000, 5000, 10000)),
        Dimension("train_freq", "train_freq", "categorical", choices=(1, 2, 4, 8)),  # vector steps
        Dimension("gradient_steps", "gradient_steps", "categorical", choices=(1, 2, 4, 8)),
        Dimension("tau", "tau", "float", 1e-3, 0.08, log=True),
        Dimension("net_arch", "policy_kwargs.net_arch", "categorical", choices=tuple(SAC_NETS),
                  to_config=lambda name: SAC_NETS[name]),
        Dimension("use_sde", "use_sde", "categorical", choices=(False, True)),
    ),
}


def space(algo: str) -> tuple[Dimension, ...]:
    return SPACES[algo]


def searched(algo: str, fixed: set[str]) -> tuple[Dimension, ...]:
    """The dimensions whose config key is not fixed (``fixed`` holds dotted keys;
    fixing ``policy_kwargs`` as a whole fixes every key inside it)."""
    def is_fixed(key: str) -> bool:
        parts = key.split(".")
        return any(".".join(parts[:depth]) in fixed for depth in range(1, len(parts) + 1))

    return tuple(dim for dim in SPACES[algo] if not is_fixed(dim.key))


def set_key(config: dict, dotted: str, value) -> None:
    """Set ``config[a][b] = value`` for ``"a.b"``, creating the mapping."""
    parts = dotted.split(".")
    target = config
    for part in parts[:-1]:
        target = target.setdefault(part, {})
    target[parts[-1]] = value


def sample(trial, dimensions, config: dict) -> dict:
    """Suggest every dimension and write the values into ``config`` (in place);
    PPO's minibatch is capped at the rollout size (``n_steps * n_envs``), the
    cap recorded as a trial user attribute."""
    for dim in dimensions:
        set_key(config, dim.key, dim.suggest(trial))
    if config.get("algo") == "ppo" and "batch_size" in config and "n_steps" in config:
        rollout = int(config["n_steps"]) * int(config["n_envs"])
        if int(config["batch_size"]) > rollout:
            trial.set_user_attr("batch_size_capped_to", rollout)
            config["batch_size"] = rollout
    return config


def describe(algo: str) -> list[str]:
    return [f"{dim.describe()} -> {dim.key}" for dim in SPACES[algo]]
