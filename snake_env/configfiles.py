"""Where a configuration file is read from: one rule for training, evaluation and the controllers.

The YAML files (``ppo.yaml``, ``sac.yaml``, ``serpenoid.yaml``, ``baselines.yaml``)
are looked up as:

1. an explicit path (``--config``, ``--serpenoid-config``, a ``path=`` argument);
2. ``./configs/<name>`` of the working directory, when that file exists (a user's own
   configs take precedence, file by file);
3. the shipped file: the package data ``snake_env.configs`` of an installed wheel,
   ``<repo>/configs`` in a source checkout.

``snake-train``, ``snake-eval --baseline``, the residual wrappers' gait and the
baselines' steering settings all resolve their file here, so a local
``configs/serpenoid.yaml`` changes every one of them alike.
"""

from __future__ import annotations

from pathlib import Path

SHIPPED_CONFIGS = "snake_env.configs"  # the package data that holds configs/*.yaml in an installed wheel


def shipped_config_path(name: str) -> Path:
    """A config file shipped with snake_env: the package data ``snake_env.configs`` read
    with importlib.resources; in a source checkout that is not installed, ``<repo>/configs``."""
    from importlib.resources import files

    try:
        return Path(str(files(SHIPPED_CONFIGS).joinpath(name)))
    except ModuleNotFoundError:
        return Path(__file__).resolve().parent.parent / "configs" / name


def config_path(name: str, path=None) -> Path:
    """``path`` when given; else ``./configs/<name>`` of the working directory when it exists,
    else the shipped one (see the module doc)."""
    if path is not None:
        return Path(path)
    local = Path.cwd() / "configs" / name
    return local if local.is_file() else shipped_config_path(name)
