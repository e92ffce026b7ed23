"""Gymnasium environments: :class:`SnakeEnv` (one snake) and
:class:`SnakeVectorEnv` (a batch of snakes stepped by one compiled call),
both over :class:`~snake_env.envs.config.PhysicsConfig` and a task."""

__all__ = ["SnakeEnv", "SnakeGoalEnv", "SnakeVectorEnv"]


def __getattr__(name):
    # imported on first use, so that the task modules can import the config without a cycle
    if name in ("SnakeEnv", "SnakeGoalEnv"):
        from . import snake

        return getattr(snake, name)
    if name == "SnakeVectorEnv":
        from .vector import SnakeVectorEnv

        return SnakeVectorEnv
    raise AttributeError(name)
