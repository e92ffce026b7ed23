"""Gymnasium registration of the snake environments."""

from __future__ import annotations

REGISTERED_N_LINKS = (3, 5, 8, 12, 20, 30)
MAX_EPISODE_STEPS = 1000
ENTRY_POINT = "snake_env.envs.snake:SnakeEnv"
VECTOR_ENTRY_POINT = "snake_env.envs.vector:SnakeVectorEnv"


def register_envs() -> None:
    """Register every snake id once; safe to call repeatedly.

    Only -v1 is registered: v1 changed the joint limit (a barrier scaled with
    max_torque) and the integration (checked RK4 with refinement), so v0's
    behaviour for the same seed and actions is not reproduced by any setting."""
    from gymnasium.envs.registration import register, registry

    ids = {"snake_env/Snake-v1": {}}
    ids.update({f"snake_env/Snake{n}-v1": {"n_links": n} for n in REGISTERED_N_LINKS})
    for env_id, kwargs in ids.items():
        if env_id in registry:
            continue
        register(
            id=env_id,
            entry_point=ENTRY_POINT,
            vector_entry_point=VECTOR_ENTRY_POINT,
            max_episode_steps=MAX_EPISODE_STEPS,
            kwargs=kwargs,
        )
