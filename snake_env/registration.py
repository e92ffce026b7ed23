"""Gymnasium registration of the snake environments, from a (task, n) table.

A row of :data:`TASK_IDS` is one task family: the id prefix, the ``task=``
name of :data:`snake_env.tasks.TASKS` and its version. Every family is
registered as ``snake_env/<prefix>{n}-v<version>`` for n in
:data:`REGISTERED_N_LINKS` and as ``snake_env/<prefix>-v<version>`` (kwarg
``n_links``, default 5), each with the batched vector env as
``vector_entry_point`` and the task's episode length.

Forward running v1 changed the joint limit (a barrier scaled with
max_torque) and the integration (checked RK4 with refinement); the other
tasks were born on that physics. The physics' v2 (forward and path v2,
command and reach v1) fails an accurate fold at once instead of refining it
(see :mod:`snake_env.envs.physics`). Earlier versions are not registered
(gymnasium's error then names the newest): forward v0 is not reproduced by
any setting, and the previous version of each id differs from the current
one only on steps that fold, which the default joint limit prevents.
"""

from __future__ import annotations

REGISTERED_N_LINKS = (3, 5, 8, 12, 20, 30)
# (id prefix, task name, version, max_episode_steps, goal env). The last two
# are the task class's ``max_episode_steps`` and ``goal_env``, repeated here so
# that ``import snake_env`` stays light (tests check they agree).
TASK_IDS = (
    ("Snake", "forward", 2, 1000, False),
    ("SnakeCommand", "command", 1, 1000, False),
    ("SnakeReach", "reach", 1, 400, True),
    ("SnakePath", "path", 2, 1000, False),
)
MAX_EPISODE_STEPS = 1000  # of the forward task; each task class holds its own
ENTRY_POINT = "snake_env.envs.snake:SnakeEnv"
GOAL_ENTRY_POINT = "snake_env.envs.snake:SnakeGoalEnv"
VECTOR_ENTRY_POINT = "snake_env.envs.vector:SnakeVectorEnv"


def registered_ids() -> dict[str, dict]:
    """Every id with its registration kwargs."""
    ids = {}
    for prefix, task, version, _, _ in TASK_IDS:
        ids[f"snake_env/{prefix}-v{version}"] = {"task": task}
        ids.update({f"snake_env/{prefix}{n}-v{version}": {"task": task, "n_links": n} for n in REGISTERED_N_LINKS})
    return ids


def register_envs() -> None:
    """Register every snake id once; safe to call repeatedly."""
    from gymnasium.envs.registration import register, registry

    rows = {task: (steps, goal) for _, task, _, steps, goal in TASK_IDS}
    for env_id, kwargs in registered_ids().items():
        if env_id in registry:
            continue
        steps, goal = rows[kwargs["task"]]
        register(
            id=env_id,
            entry_point=GOAL_ENTRY_POINT if goal else ENTRY_POINT,
            vector_entry_point=VECTOR_ENTRY_POINT,
            max_episode_steps=steps,
            kwargs=kwargs,
        )
