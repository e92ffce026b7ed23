"""Gymnasium registration of the snake environments, read from the Task classes.

Every task class carries its registration (``id_prefix``, ``version``,
``max_episode_steps``, ``goal_env``; see :class:`snake_env.tasks.Task`).
:func:`register_task` registers one as ``snake_env/<prefix>{n}-v<version>``
for each n of ``n_links`` and as ``snake_env/<prefix>-v<version>`` (kwarg
``n_links``, default 5), each with the batched vector env as
``vector_entry_point``. :func:`register_envs` does so for the shipped tasks
(:data:`snake_env.tasks.TASKS`); a task of one's own is one class and one
``register_task`` call.

Forward running v1 changed the joint limit (a barrier scaled with
max_torque) and the integration (checked RK4 with refinement); the other
tasks were born on that physics. The physics' v2 (forward and path v2,
command and reach v1) fails an accurate fold at once instead of refining it
(see :mod:`snake_env.physics.stepping`). Earlier versions are not registered
(gymnasium's error then names the newest): forward v0 is not reproduced by
any setting, and the previous version of each id differs from the current
one only on steps that fold, which the default joint limit prevents.
"""

from __future__ import annotations

from snake_env.tasks import TASKS, Task, task_class

REGISTERED_N_LINKS = (3, 5, 8, 12, 20, 30)
ENTRY_POINT = "snake_env.envs.snake:SnakeEnv"
GOAL_ENTRY_POINT = "snake_env.envs.snake:SnakeGoalEnv"
VECTOR_ENTRY_POINT = "snake_env.envs.vector:SnakeVectorEnv"


def task_ids(task: type[Task], n_links=REGISTERED_N_LINKS) -> dict[str, dict]:
    """The ids of one task class with their registration kwargs. A shipped task is named by its
    ``task=`` string (so a spec prints and pickles plainly), any other by its class."""
    cls = task_class(task)
    if not cls.id_prefix:
        raise ValueError(f"{cls.__name__}.id_prefix must name the task's ids (e.g. 'SnakeMyTask'), got ''")
    name = cls.name if TASKS.get(cls.name) is cls else cls
    ids = {f"snake_env/{cls.id_prefix}-v{cls.version}": {"task": name}}
    ids.update({f"snake_env/{cls.id_prefix}{n}-v{cls.version}": {"task": name, "n_links": int(n)} for n in n_links})
    return ids


def registered_ids() -> dict[str, dict]:
    """Every id of the shipped tasks with its registration kwargs."""
    return {env_id: kwargs for cls in TASKS.values() for env_id, kwargs in task_ids(cls).items()}


def register_task(task: type[Task], n_links=REGISTERED_N_LINKS) -> list[str]:
    """Register a task class's ids (see the module doc); ids already registered are kept.
    Returns the ids."""
    from gymnasium.envs.registration import register, registry

    cls = task_class(task)
    ids = task_ids(cls, n_links)
    for env_id, kwargs in ids.items():
        if env_id in registry:
            continue
        register(
            id=env_id,
            entry_point=GOAL_ENTRY_POINT if cls.goal_env else ENTRY_POINT,
            vector_entry_point=VECTOR_ENTRY_POINT,
            max_episode_steps=cls.max_episode_steps,
            kwargs=kwargs,
        )
    return list(ids)


def register_envs() -> None:
    """Register every shipped snake id once; safe to call repeatedly."""
    for cls in TASKS.values():
        register_task(cls)
