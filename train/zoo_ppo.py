"""RL Zoo config: ``-conf snake_env.train.zoo_ppo`` (see :mod:`snake_env.train.zoo`)."""

from snake_env.train.zoo import zoo_hyperparams

hyperparams = zoo_hyperparams("ppo")
