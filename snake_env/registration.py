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
(see :mod:`snake_env.physics.stepping`). The physics' v3 (forward and path
v3, command and reach v2) is a robot a lab could build: servo motors and
wheels with finite grip under a traction limit. The physics' v4 (forward and
path v4, command and reach v3) has wheels that slide beyond their grip and
motors that brake with their back-EMF. The two versions before the newest of
each shipped id stay registered as the same task with their physics pinned in
the kwargs (:data:`~snake_env.physics.config.PHYSICS_HISTORY`, as CartPole-v0
differs from v1 by its registration), so runs and configs made on them keep
working. Older versions are not registered (gymnasium's error then names the
newest): forward v0 is not reproduced by any setting, and v1 differs from v2
only on steps that fold, which the default joint limit prevents.
"""

from __future__ import annotations

from snake_env.physics.config import PHYSICS_HISTORY
from snake_env.tasks import TASKS, Task, task_class

REGISTERED_N_LINKS = (3, 5, 8, 12, 20, 30)
ENTRY_POINT = "snake_env.envs.snake:SnakeEnv"
GOAL_ENTRY_POINT = "snake_env.envs.snake:SnakeGoalEnv"
VECTOR_ENTRY_POINT = "snake_env.envs.vector:SnakeVectorEnv"


def task_ids(task: type[Task], n_links=REGISTERED_N_LINKS, previous: bool = False) -> dict[str, dict]:
    """The ids of one task class with their registration kwargs. A shipped task is named by its
    ``task=`` string (so a spec prints and pickles plainly), any other by its class. ``previous``:
    also the ids of the versions before, each with its physics pinned (see the module doc)."""
    cls = task_class(task)
    if not cls.id_prefix:
        raise ValueError(f"{cls.__name__}.id_prefix must name the task's ids (e.g. 'SnakeMyTask'), got ''")
    name = cls.name if TASKS.get(cls.name) is cls else cls
    versions = [(cls.version, {})]
    if previous:
        versions += [(cls.version - back, dict(physics)) for back, physics in enumerate(PHYSICS_HISTORY, start=1)
                     if cls.version - back >= 0]
    ids = {}
    for version, physics in versions:
        ids[f"snake_env/{cls.id_prefix}-v{version}"] = {"task": name, **physics}
        ids.update({f"snake_env/{cls.id_prefix}{n}-v{version}": {"task": name, "n_links": int(n), **physics}
                    for n in n_links})
    return ids


def registered_ids() -> dict[str, dict]:
    """Every id of the shipped tasks with its registration kwargs."""
    return {env_id: kwargs for cls in TASKS.values() for env_id, kwargs in task_ids(cls, previous=True).items()}


def register_task(task: type[Task], n_links=REGISTERED_N_LINKS, previous: bool = False) -> list[str]:
    """Register a task class's ids (see the module doc); ids already registered are kept.
    ``previous``: also the earlier versions' ids (the shipped tasks). Returns the ids."""
    from gymnasium.envs.registration import register, registry

    cls = task_class(task)
    ids = task_ids(cls, n_links, previous)
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
        register_task(cls, previous=True)
