"""snake_env: a Gymnasium testbed for n-link wheeled snake robots.

Importing the package registers the environments (this module does nothing
else): ``snake_env/Snake-v2`` (kwarg ``n_links``, default 5) and
``snake_env/Snake{n}-v2`` for n in 3, 5, 8, 12, 20, 30 (running forward), and
the tasks ``SnakeCommand{n}-v1``, ``SnakeReach{n}-v1`` and ``SnakePath{n}-v2``
(see :mod:`snake_env.registration`; :func:`register_task` registers a task of
one's own).

Layers, each importing only those before it: ``dynamics`` (the equations of
motion) -> ``physics`` (config and checked batched step) -> ``controllers``
(the baselines) -> ``tasks`` -> ``envs`` (single and vector env) ->
``wrappers``; above the core: ``agents``, ``train``, ``benchmarks``.
"""

from snake_env.registration import register_envs, register_task

__version__ = "0.1.0"

__all__ = ["register_task", "__version__"]

register_envs()
