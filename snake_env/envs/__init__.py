"""Gymnasium environments: :class:`SnakeEnv` (one snake) and
:class:`SnakeVectorEnv` (a batch of snakes stepped by one compiled call)."""

from .snake import SnakeEnv

__all__ = ["SnakeEnv", "SnakeVectorEnv"]


def __getattr__(name):
    # the vector env is imported on first use so `import snake_env.envs` stays light
    if name == "SnakeVectorEnv":
        from .vector import SnakeVectorEnv

        return SnakeVectorEnv
    raise AttributeError(name)
