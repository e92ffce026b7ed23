"""The physics of a batch of snakes, picked for its config: every row's commands at once in one compiled call
(:class:`~snake_env.physics.stepping.InstantPhysics`), a motor response in time substep by substep
(:class:`~snake_env.physics.actuator_response.ActuatorResponse`), a robot of its own per row
(:class:`~snake_env.physics.randomization.RandomizedRobots`), or wheels that slide
(:class:`~snake_env.physics.sliding_wheels.SlidingWheelPhysics`, ``wheel_model="sliding"``; with a motor response
in time, an ActuatorResponse whose substeps are theirs). All four share InstantPhysics' interface, so
the envs (:class:`snake_env.envs.core.SnakeBatch`) step any of them the same way."""

from __future__ import annotations

from .randomization import RandomizedRobots, one_robot
from .stepping import PhysicsParams


def batch_physics(config, params: PhysicsParams, num_envs: int):
    """The batch physics of ``num_envs`` rows of ``config`` (built as ``params``)."""
    if config.randomized:
        return RandomizedRobots(config, num_envs)
    return one_robot(config, params, num_envs)
