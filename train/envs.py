"""Vectorized training/evaluation envs for SB3, built from a validated config."""

from __future__ import annotations

from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor, VecNormalize

from snake_env.train.config import ConfigError, first_line, normalize_options


def make_vec_env(config: dict, n_envs: int, seed: int) -> VecEnv:
    """See :func:`_make_vec_env`; a bad env id or env kwarg becomes a one-line ConfigError."""
    import gymnasium as gym

    try:
        return _make_vec_env(config, n_envs, seed)
    except (ValueError, TypeError, gym.error.Error) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"cannot make env {config['env_id']!r} with env_kwargs {config['env_kwargs']}: "
                          f"{first_line(exc)}") from None


def _make_vec_env(config: dict, n_envs: int, seed: int) -> VecEnv:
    """``n_envs`` copies of ``config['env_id']`` with ``env_kwargs``, episode
    statistics recorded by VecMonitor (SB3's ``ep_rew_mean`` and EvalCallback need them).

    ``vec_env: batched`` steps all copies with one call of the batched
    dynamics (SnakeSB3VecEnv over the env's vector entry point);
    ``dummy`` loops over single envs (SB3 DummyVecEnv), for any gymnasium id.
    ``n_links_set`` makes one :class:`~snake_env.train.multi_n_env.MultiNVecEnv` of several sizes.
    """
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    import snake_env  # noqa: F401  (registers the ids)
    from snake_env.wrappers import wrap_env, wrap_vector_env

    env_id = config["env_id"]
    env_kwargs = dict(config["env_kwargs"])
    env_wrapper = config.get("env_wrapper")
    if config.get("n_links_set"):
        from snake_env.train.multi_n_env import MultiNVecEnv

        venv = MultiNVecEnv(env_id, config["n_links_set"], n_envs, **env_kwargs)
        venv.seed(seed)
    elif config["vec_env"] == "batched":
        from snake_env.agents.sb3_vec_env import SnakeSB3VecEnv

        if env_wrapper:
            # SB3 resets finished envs in the same step; the wrappers sit between it and the batched env
            batched = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point",
                                   autoreset_mode=AutoresetMode.SAME_STEP, **env_kwargs)
            venv = SnakeSB3VecEnv(wrap_vector_env(batched, env_wrapper))
        else:
            venv = SnakeSB3VecEnv(env_id, num_envs=n_envs, **env_kwargs)
        venv.seed(seed)  # seeds the first reset
    else:
        def factory(rank):
            def make():
                env = wrap_env(gym.make(env_id, **env_kwargs), env_wrapper)
                env.reset(seed=seed + rank)
                env.action_space.seed(seed + rank)
                return env

            return make

        venv = DummyVecEnv([factory(rank) for rank in range(n_envs)])
        venv.seed(seed)
    return VecMonitor(venv)


def wrap_normalize(venv: VecEnv, config: dict, training: bool) -> VecEnv:
    """VecNormalize per the zoo's ``normalize`` key (unchanged env if off).

    Evaluation envs never update statistics and report raw rewards."""
    options = normalize_options(config["normalize"], config.get("gamma"))
    if options is None:
        return venv
    if not training:
        options = {**options, "norm_reward": False}
    venv = VecNormalize(venv, training=training, **options)
    return venv
