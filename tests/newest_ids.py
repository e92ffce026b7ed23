"""The newest registered version of a snake env name, so tests follow version bumps (-v0 -> -v1)."""

from gymnasium.envs.registration import find_highest_version

import snake_env  # noqa: F401  (registers the ids)


def newest_id(name: str) -> str:
    """``newest_id("Snake3")`` -> ``"snake_env/Snake3-v<highest>"``."""
    version = find_highest_version("snake_env", name)
    if version is None:
        raise LookupError(f"no registered snake_env/{name}-v* id")
    return f"snake_env/{name}-v{version}"
