"""The searched serpenoid gaits (``serpenoid.yaml``), keyed by env id.

Each entry holds ``params`` (:class:`~snake_env.controllers.serpenoid.SerpenoidParams`),
``env_kwargs`` (the kwargs the gait was searched with) and ``search`` (its mean
forward speed, m/s, and how it was found). The file is resolved by
:func:`snake_env.configfiles.config_path`; ``python -m snake_env.agents.search``
writes it.
"""

from __future__ import annotations

import re

import yaml

from snake_env.configfiles import config_path

from .serpenoid import SerpenoidParams

GAITS_FILE = "serpenoid.yaml"


def load_gaits(path=None) -> dict:
    """Every entry of the gait file (``{}`` when it does not exist)."""
    path = config_path(GAITS_FILE, path)
    if not path.is_file():
        return {}
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path} must hold a mapping keyed by env id")
    return data


def load_params(env_id: str, path=None) -> tuple[SerpenoidParams, dict]:
    """(gait, env_kwargs it was searched with) for ``env_id`` from ``serpenoid.yaml``."""
    path = config_path(GAITS_FILE, path)
    data = load_gaits(path)
    if env_id not in data:
        raise ValueError(f"no serpenoid gait for env {env_id!r} in {path}; available: {sorted(data)} "
                         f"(run: python -m snake_env.agents.search --env {env_id})")
    entry = data[env_id]
    if not isinstance(entry, dict) or "params" not in entry:
        raise ValueError(f"entry {env_id!r} of {path} must be a mapping with 'params'")
    return SerpenoidParams.from_dict(entry["params"]), dict(entry.get("env_kwargs") or {})


def gait_for_links(n_links: int, path=None, versions_back: int = 0) -> tuple[SerpenoidParams, float | None]:
    """(gait, its straight-line speed (m/s) or None) of the locomotion id ``snake_env/Snake{n}-v*``
    with this n (newest version) in ``path``: the gait the task baselines steer. ``versions_back``
    (a config with an earlier version's physics, ``PhysicsConfig.versions_back``): the gait that many
    versions before the newest in the file, or the oldest it has, since a gait is searched for its physics."""
    path = config_path(GAITS_FILE, path)
    gaits = load_gaits(path)
    pattern = re.compile(rf"^snake_env/Snake{n_links}-v(\d+)$")
    matches = sorted((int(m.group(1)), key) for key in gaits if (m := pattern.match(str(key))))
    if versions_back > 0 and matches:  # the version that many before the file's newest, or the newest before it
        target = matches[-1][0] - int(versions_back)
        matches = [match for match in matches if match[0] <= target] or matches[:1]
    if not matches:
        raise ValueError(f"no serpenoid gait for n_links={n_links} in {path} (run: python -m "
                         f"snake_env.agents.search --env snake_env/Snake{n_links}-vN, or --env snake_env/Snake-vN "
                         f"--n-links {n_links} for a length with no id of its own; N the newest version)")
    entry = gaits[matches[-1][1]]
    return SerpenoidParams.from_dict(entry["params"]), (entry.get("search") or {}).get("mean_forward_velocity")
