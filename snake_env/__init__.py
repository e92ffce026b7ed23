"""snake_env: a Gymnasium testbed for n-link wheeled snake robots.

Importing the package registers the environments (this module does nothing
else): ``snake_env/Snake-v2`` (kwarg ``n_links``, default 5) and
``snake_env/Snake{n}-v2`` for n in 3, 5, 8, 12, 20, 30 (running forward), and
the tasks ``SnakeCommand{n}-v1``, ``SnakeReach{n}-v1`` and ``SnakePath{n}-v2``
(see :mod:`snake_env.registration`).
"""

from snake_env.registration import register_envs

__version__ = "0.1.0"

register_envs()
