"""Tasks on the one snake physics core (dm_control's Physics/Task split).

A task is one :class:`Task` subclass: its fields are its kwargs, its class
attributes its registration (id prefix, version, episode length, GoalEnv),
its eval metrics and its baseline controller. :data:`TASKS` lists the
shipped ones; :func:`snake_env.registration.register_task` registers any
other subclass, which is all a new task needs.
"""

from __future__ import annotations

from .base import Task
from .command import CommandTask
from .forward import ForwardTask
from .path import PathTask
from .reach import ReachTask

TASKS: dict[str, type[Task]] = {cls.name: cls for cls in (ForwardTask, CommandTask, ReachTask, PathTask)}


def task_class(task) -> type[Task]:
    """The Task class of a name in :data:`TASKS` or a Task subclass; else a one-line ValueError."""
    if isinstance(task, type) and issubclass(task, Task):
        return task
    if isinstance(task, str) and task in TASKS:
        return TASKS[task]
    raise ValueError(f"task must be one of {sorted(TASKS)} or a Task subclass, got {task!r}")


__all__ = ["TASKS", "Task", "task_class", "ForwardTask", "CommandTask", "ReachTask", "PathTask"]
