"""One ``snake-tune`` trial: a ``snake-train`` run with sampled hyperparameters.

The trial builds its config, envs and model with snake-train's own functions
(:mod:`snake_env.train.config`, :func:`snake_env.train.envs.make_vec_env`,
:func:`snake_env.train.envs.wrap_normalize`, :func:`snake_env.train.train.build_model`) and trains
with SB3's ``learn``. :class:`TrialEvalCallback` (RL Zoo's pattern) evaluates
the deterministic policy E times, reports its mean forward speed to Optuna and
raises :class:`optuna.TrialPruned` when the pruner says so.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import optuna
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import sync_envs_normalization

from snake_env.train import config as cfg
from snake_env.train import tune_space


def mean_forward_speed(model, eval_env, n_episodes: int) -> float:
    """Mean over ``n_episodes`` deterministic episodes of each episode's mean
    CM forward speed ``info["x_velocity"]`` (m/s), as ``snake-eval`` reports it."""
    sums = np.zeros(eval_env.num_envs)
    steps = np.zeros(eval_env.num_envs, dtype=int)
    episode_speeds: list[float] = []

    def collect(local_vars, _globals):
        i = local_vars["i"]
        sums[i] += float(local_vars["info"]["x_velocity"])
        steps[i] += 1
        if local_vars["done"]:
            episode_speeds.append(sums[i] / steps[i])
            sums[i], steps[i] = 0.0, 0

    evaluate_policy(model, eval_env, n_eval_episodes=n_episodes, deterministic=True, callback=collect, warn=False)
    return float(np.mean(episode_speeds)) if episode_speeds else float("nan")


class TrialEvalCallback(BaseCallback):
    """Evaluate at ``n_evaluations`` evenly spaced step counts of a
    ``n_timesteps`` budget (counted over all envs), report each mean forward
    speed to the trial (step = evaluation index 1..E) and raise
    :class:`optuna.TrialPruned` when ``trial.should_prune()``.

    A non-finite speed is reported as such and prunes the trial: a blown-up
    policy never counts as a result."""

    def __init__(self, trial, eval_env, n_evaluations: int, n_timesteps: int, n_eval_episodes: int,
                 verbose: int = 0):
        super().__init__(verbose)
        self.trial = trial
        self.eval_env = eval_env
        self.n_evaluations = int(n_evaluations)
        self.n_timesteps = int(n_timesteps)
        self.n_eval_episodes = int(n_eval_episodes)
        self.eval_index = 0
        self.last_speed = float("nan")

    def threshold(self, index: int) -> int:
        """Env steps at which evaluation ``index`` (1-based) is due."""
        return math.ceil(self.n_timesteps * index / self.n_evaluations)

    def _on_step(self) -> bool:
        if self.eval_index < self.n_evaluations and self.num_timesteps >= self.threshold(self.eval_index + 1):
            self.evaluate()
        return True

    def evaluate(self) -> float:
        if self.model.get_vec_normalize_env() is not None:
            sync_envs_normalization(self.training_env, self.eval_env)
        speed = mean_forward_speed(self.model, self.eval_env, self.n_eval_episodes)
        self.report(speed)
        return speed

    def report(self, speed: float) -> None:
        """Report one evaluation to the trial; prune when the pruner says so."""
        self.eval_index += 1
        self.last_speed = speed
        if not math.isfinite(speed):
            raise optuna.TrialPruned(f"non-finite forward speed at evaluation {self.eval_index}")
        self.trial.report(speed, self.eval_index)
        if self.trial.should_prune():
            raise optuna.TrialPruned(f"pruned at evaluation {self.eval_index} ({speed:.4f} m/s)")


class Objective:
    """``study.optimize`` objective: one training run per trial.

    ``base`` is the validated config every trial starts from (the YAML entry,
    ``--set`` overrides, budget and seed); ``dimensions`` the searched ones."""

    def __init__(self, base: dict, dimensions, n_evaluations: int):
        self.base = base
        self.dimensions = tuple(dimensions)
        self.n_evaluations = int(n_evaluations)

    def trial_config(self, trial) -> dict:
        config = copy.deepcopy(self.base)
        config["policy_kwargs"] = cfg.policy_kwargs_dict(config["policy_kwargs"])
        tune_space.sample(trial, self.dimensions, config)
        return cfg.validate(config)

    def __call__(self, trial) -> float:
        import torch

        from snake_env.train.envs import make_vec_env, wrap_normalize
        from snake_env.train.train import build_model

        config = self.trial_config(trial)
        trial.set_user_attr("config", best_config_entry(config))
        torch.set_num_threads(config["torch_threads"])
        venv = make_vec_env(config, config["n_envs"], config["seed"])
        eval_env = make_vec_env(config, min(config["n_eval_episodes"], 8), config["seed"] + 10_000)
        try:
            venv = wrap_normalize(venv, config, training=True)
            eval_env = wrap_normalize(eval_env, config, training=False)
            model = build_model(config, venv, verbose=0)
            trial_eval = TrialEvalCallback(trial, eval_env, self.n_evaluations, config["n_timesteps"],
                                           config["n_eval_episodes"])
            # the config's own callbacks (e.g. ResidualBurnIn) run as they do in snake-train
            model.learn(total_timesteps=config["n_timesteps"], callback=[trial_eval, *cfg.make_callbacks(config)],
                        progress_bar=False)
            if trial_eval.eval_index == 0:  # a budget shorter than one rollout: evaluate once at the end
                trial_eval.evaluate()
            return trial_eval.last_speed
        finally:
            venv.close()
            eval_env.close()


def best_config_entry(config: dict) -> dict:
    """A validated run config as a ``configs/<algo>.yaml`` entry: without the
    run keys (algo, env id, seed), ``policy_kwargs`` in the zoo's string form."""
    entry = {k: v for k, v in config.items() if k not in cfg.RUN_KEYS}
    entry["policy_kwargs"] = cfg.python_text(cfg.policy_kwargs_dict(config["policy_kwargs"]))
    return entry
