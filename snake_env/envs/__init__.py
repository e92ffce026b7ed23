"""Gymnasium environments: :class:`SnakeEnv` (one snake) and
:class:`SnakeVectorEnv` (a batch of snakes stepped by one compiled call),
both over :class:`~snake_env.physics.PhysicsConfig` and a task."""

from .snake import SnakeEnv, SnakeGoalEnv
from .vector import SnakeVectorEnv

__all__ = ["SnakeEnv", "SnakeGoalEnv", "SnakeVectorEnv"]
