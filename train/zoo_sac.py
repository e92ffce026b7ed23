"""RL Zoo config: ``-conf train.zoo_sac`` (see :mod:`train.zoo`)."""

from train.zoo import zoo_hyperparams

hyperparams = zoo_hyperparams("sac")
