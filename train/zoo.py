"""RL Baselines3 Zoo hyperparameters from this project's configs.

RL Zoo reads a hyperparameter file named with ``-conf``/``--conf-file``: a YAML
file or a Python module with a ``hyperparams`` dict keyed by env id. Our
``configs/<algo>.yaml`` files are in the zoo's format plus a few keys that only
``snake-train`` knows (which vector env, evaluation and checkpoint frequency,
torch threads); :func:`zoo_hyperparams` drops those, so the modules
:mod:`snake_env.train.zoo_ppo` and :mod:`snake_env.train.zoo_sac` are zoo configs::

    python -m rl_zoo3.train --algo ppo --env snake_env/Snake5-v2 --gym-packages snake_env -conf snake_env.train.zoo_ppo
    python -m rl_zoo3.enjoy --algo ppo --env snake_env/Snake5-v2 --gym-packages snake_env -f logs --no-render

The zoo then trains with its own scripts (DummyVecEnv over single envs, its own
logging, Optuna tuning with ``-optimize``) and saves in its own layout
(``logs/<algo>/<env>_<k>/``), which ``rl_zoo3.enjoy`` replays.
"""

from __future__ import annotations

from snake_env.train import config as cfg

# keys only snake-train understands (see snake_env.train.config.META_DEFAULTS)
PROJECT_ONLY_KEYS = ("vec_env", "eval_freq", "n_eval_episodes", "checkpoint_freq", "torch_threads")


def zoo_env_wrapper(spec) -> list[dict]:
    """Our ``env_wrapper`` (``{name: kwargs}``, see :mod:`snake_env.wrappers`) in the zoo's form: a list of
    ``{"module.Class": kwargs}`` that ``rl_zoo3.utils.get_wrapper_class`` applies to each single env."""
    from snake_env import wrappers

    # the public path: every wrapper class is exported by the snake_env.wrappers package
    return [{f"{wrappers.__name__}.{wrappers.WRAPPERS[name][0].__name__}": kwargs}
            for name, kwargs in wrappers.parse_env_wrapper(spec)]


def zoo_joint_policy(entry: dict, env_id: str | None, algo: str | None) -> tuple[str, dict]:
    """``policy: JointPolicy`` in the zoo's form: (the dotted name of the policy class for ``algo``, which the
    zoo imports, and its kwargs with this env's observation layout, which it hands on as they are), as
    snake-train builds them. Its options are checked as snake-train checks them."""
    if algo is None:
        raise ValueError(f"{env_id}: policy {cfg.JOINT_POLICY} needs the algorithm (ppo or sac) for its RL Zoo form")
    from snake_env.train.joint_policy import policy_class

    config = {"algo": algo, "policy": cfg.JOINT_POLICY, "policy_kwargs": entry.get("policy_kwargs"),
              "normalize": entry.get("normalize", False), "use_sde": entry.get("use_sde"), "env_id": env_id,
              "env_kwargs": entry.get("env_kwargs")}
    try:
        cfg.check_joint_policy(config)
        cls = policy_class(algo)
        return f"{cls.__module__}.{cls.__qualname__}", cfg.torch_policy_kwargs(config)
    except cfg.ConfigError as exc:
        raise ValueError(f"{env_id}: {exc}") from None


def zoo_entry(entry: dict, env_id: str | None = None, algo: str | None = None) -> dict:
    """One env's hyperparameters in the zoo's form (``algo``: ppo or sac, needed by ``policy: JointPolicy``)."""
    entry = {k: v for k, v in entry.items() if k not in PROJECT_ONLY_KEYS}
    if entry.pop("n_links_set", None) is not None:  # the zoo makes every env of a run from one env id
        raise ValueError(f"{env_id}: n_links_set (snakes of several sizes in one batched VecEnv, "
                         f"snake_env.train.multi_n_env) has no RL Zoo form; train that entry with snake-train")
    if entry.get("noise_type") == "pink":  # the zoo's noise_type is action noise (normal, ornstein-uhlenbeck)
        raise ValueError(f"{env_id}: noise_type pink (snake_env.train.exploration) has no RL Zoo form; "
                         f"train that entry with snake-train")
    if entry.pop("init_from", None) is not None:  # the zoo starts from a trained agent by its CLI only
        raise ValueError(f"{env_id}: init_from has no RL Zoo hyperparameter form; pass the model to "
                         f"rl_zoo3.train --trained-agent instead")
    if entry.get("env_wrapper") is not None:
        entry["env_wrapper"] = zoo_env_wrapper(entry["env_wrapper"])
    else:
        entry.pop("env_wrapper", None)
    if entry.get("policy") == cfg.JOINT_POLICY:
        entry["policy"], entry["policy_kwargs"] = zoo_joint_policy(entry, env_id, algo)
    elif entry.get("policy_kwargs") is not None and isinstance(
            cfg.policy_kwargs_dict(entry["policy_kwargs"]).get("features_extractor_class"), str):
        # the zoo evals a string policy_kwargs where no snake_env extractor is in scope: give it the
        # class and its kwargs for this env, as snake-train builds them
        entry["policy_kwargs"] = cfg.torch_policy_kwargs({"policy_kwargs": entry["policy_kwargs"], "env_id": env_id,
                                                          "env_kwargs": entry.get("env_kwargs")})
    elif isinstance(entry.get("policy_kwargs"), dict):
        entry["policy_kwargs"] = cfg.python_text(entry["policy_kwargs"])
    if isinstance(entry.get("normalize"), str):
        entry["normalize"] = cfg.parse_python_dict(entry["normalize"], "normalize")
    return entry


def zoo_hyperparams(algo: str, path=None) -> dict:
    """``{env_id: hyperparameters}`` of ``configs/<algo>.yaml`` (or ``path``) for RL Zoo."""
    path = cfg.default_config_path(algo) if path is None else path
    data = cfg.read_yaml(path)
    return {env_id: zoo_entry(cfg.coerce_scalar(dict(entry)), env_id, algo) for env_id, entry in data.items()
            if isinstance(entry, dict)}
