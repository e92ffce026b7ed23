"""snake_env: a Gymnasium testbed for n-link wheeled snake robots.

Importing the package registers the environments (this module does nothing
else): ``snake_env/Snake-v1`` (kwarg ``n_links``, default 5) and
``snake_env/Snake{n}-v1`` for n in 3, 5, 8, 12, 20, 30 (running forward), and
the tasks ``SnakeCommand{n}-v0``, ``SnakeReach{n}-v0`` and ``SnakePath{n}-v1``
(see :mod:`snake_env.registration`).
"""

from snake_env.registration import register_envs

__version__ = "0.1.0"

register_envs()
