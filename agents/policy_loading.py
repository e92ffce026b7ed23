"""Loading saved SB3 policies together with their VecNormalize statistics.

A saved policy is a run directory (``model.zip``, ``config.yaml``,
``vecnormalize.pkl``) or one model file inside it (``model.zip``,
``checkpoints/model_<steps>_steps.zip``, ``best_model/best_model.zip``);
the statistics that belong to that exact file are found beside it.
Statistics are loaded for evaluation (``training=False``,
``norm_reward=False``) and only ever applied, never updated.

Every failure (missing file, not a zip, corrupt archive, algorithm unknown,
spaces that do not match the env, e.g. another ``n_links``) raises
:class:`PolicyLoadError` with a one-line message. A policy that runs on any n
(one with ``for_spaces``, the shared per-joint policy of ``snake_env.train.joint_policy``)
is rebuilt with the same weights for the env's n instead.
"""

from __future__ import annotations

import json
import pickle
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

CHECKPOINT_RE = re.compile(r"^model_(\d+)_steps\.zip$")
SUPPORTED_ALGOS = ("ppo", "sac")


class PolicyLoadError(ValueError):
    """A saved policy cannot be used; the message is one line."""


@dataclass
class SavedPolicyFiles:
    model: Path
    config: Path | None
    vecnormalize: Path | None


@dataclass
class LoadedPolicy:
    model: object  # an SB3 BaseAlgorithm
    algo: str
    files: SavedPolicyFiles
    config: dict = field(default_factory=dict)
    normalizer: object | None = None  # VecNormalize with training=False, norm_reward=False

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self.normalizer is None:
            return obs if isinstance(obs, dict) else np.asarray(obs, dtype=np.float32)
        return self.normalizer.normalize_obs(obs)

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        action, _ = self.model.predict(self.normalize(obs), deterministic=deterministic)
        return action


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def locate(target) -> SavedPolicyFiles:
    """Find the model, config and statistics files of a run dir or model file."""
    target = Path(target)
    if not target.exists():
        raise PolicyLoadError(f"no such run directory or model file: {target}")
    if target.is_dir():
        model = target / "model.zip"
        if not model.is_file():
            raise PolicyLoadError(f"{target} holds no model.zip (not a snake-train run directory?)")
    else:
        model = target
    folder = model.parent
    match = CHECKPOINT_RE.match(model.name)
    if match:
        stats = folder / f"vecnormalize_{match.group(1)}_steps.pkl"
    else:
        stats = folder / "vecnormalize.pkl"
    config = None
    for candidate in (folder / "config.yaml", folder.parent / "config.yaml"):
        if candidate.is_file():
            config = candidate
            break
    return SavedPolicyFiles(model=model, config=config, vecnormalize=stats if stats.is_file() else None)


def detect_algo(model_path: Path) -> str:
    """The SB3 algorithm of a saved model, from its ``data`` entry: SAC's policy
    class lives in ``stable_baselines3.sac``; PPO uses the shared
    ActorCriticPolicy, so it is told apart by its own hyperparameters."""
    if not zipfile.is_zipfile(model_path):
        raise PolicyLoadError(f"{model_path} is not an SB3 model file (not a zip archive)")
    try:
        with zipfile.ZipFile(model_path) as archive:
            data = json.loads(archive.read("data").decode())
        module = data["policy_class"]["__module__"]
    except (KeyError, ValueError, TypeError, zipfile.BadZipFile, OSError) as exc:
        raise PolicyLoadError(f"{model_path} is not a readable SB3 model file: {_first_line(exc)}") from None
    if module.startswith("stable_baselines3.sac"):
        return "sac"
    if module.startswith("stable_baselines3.common.policies") and "clip_range" in data and "n_epochs" in data:
        return "ppo"
    if module.startswith("snake_env."):  # a policy of this package (the shared per-joint one): by hyperparameters
        if "clip_range" in data and "n_epochs" in data:
            return "ppo"
        if "target_entropy" in data and "tau" in data:
            return "sac"
    raise PolicyLoadError(f"{model_path} holds a {module} policy that is not one of {list(SUPPORTED_ALGOS)}")


def load_normalizer(path: Path, obs_shape: tuple):
    """VecNormalize statistics for evaluation: ``training=False, norm_reward=False``; None when they
    normalize rewards only (``norm_obs=False``), as nothing is left to apply."""
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with open(path, "rb") as handle:
            normalizer = pickle.load(handle)
    except Exception as exc:  # pickle raises many types on corrupt input
        raise PolicyLoadError(f"{path} is not readable VecNormalize statistics: {_first_line(exc)}") from None
    if not isinstance(normalizer, VecNormalize):
        raise PolicyLoadError(f"{path} holds a {type(normalizer).__name__}, not VecNormalize statistics")
    normalizer.training = False
    normalizer.norm_reward = False
    if not normalizer.norm_obs:
        # reward statistics only (VecNormalize then has no obs_rms; evaluation never normalizes rewards)
        return None
    if isinstance(normalizer.obs_rms, dict):  # a Dict observation (goal tasks): one statistic per key
        if obs_shape is not None:
            raise PolicyLoadError(f"{path} normalizes Dict observations, the env gives a Box of shape {obs_shape}")
        return normalizer
    mean_shape = tuple(np.shape(normalizer.obs_rms.mean)) if normalizer.norm_obs else obs_shape
    if mean_shape != tuple(obs_shape):
        raise PolicyLoadError(f"{path} normalizes observations of shape {mean_shape}, the env gives {tuple(obs_shape)}")
    return normalizer


def load_policy(target, observation_space, action_space, config: dict | None = None,
                require_stats: bool | None = None) -> LoadedPolicy:
    """Load a saved policy for an env with the given spaces.

    ``require_stats``: whether VecNormalize statistics must exist (default:
    when the run's config normalizes).
    """
    from stable_baselines3 import PPO, SAC

    files = locate(target)
    algo = detect_algo(files.model)
    if config and config.get("algo") not in (None, algo):
        raise PolicyLoadError(f"{files.model} holds a {algo} model but {files.config} says algo {config['algo']!r}")
    algo_cls = {"ppo": PPO, "sac": SAC}[algo]
    try:
        # an acting policy needs no replay buffer: a 1-slot plain one (HerReplayBuffer could not be
        # rebuilt without the training env)
        custom = {"replay_buffer_class": None, "replay_buffer_kwargs": {}, "buffer_size": 1} if algo == "sac" else None
        model = algo_cls.load(files.model, device="cpu", custom_objects=custom)
    except Exception as exc:  # corrupt archives surface as many exception types
        raise PolicyLoadError(f"cannot load {algo} model {files.model}: {_first_line(exc)}") from None
    from gymnasium import spaces

    if transferable(model) and (model.observation_space.shape != getattr(observation_space, "shape", None)
                                or model.action_space.shape != action_space.shape):
        model = for_spaces(model, files.model, observation_space, action_space)
    if isinstance(observation_space, spaces.Dict) or isinstance(model.observation_space, spaces.Dict):
        if model.observation_space != observation_space:
            raise PolicyLoadError(f"{files.model} expects observations {model.observation_space}, the env gives "
                                  f"{observation_space} (another task or n_links?)")
    elif model.observation_space.shape != observation_space.shape:
        raise PolicyLoadError(
            f"{files.model} expects observations of shape {model.observation_space.shape}, the env gives "
            f"{observation_space.shape} (another env or n_links?)")
    if model.action_space.shape != action_space.shape:
        raise PolicyLoadError(
            f"{files.model} outputs actions of shape {model.action_space.shape}, the env takes {action_space.shape} "
            f"(n_links - 1 joint torques: another n_links?)")
    if require_stats is None:
        require_stats = bool(config) and config.get("normalize") not in (None, False)
    normalizer = None
    if files.vecnormalize is not None:
        normalizer = load_normalizer(files.vecnormalize, observation_space.shape)
    elif require_stats:
        raise PolicyLoadError(f"{files.model} was trained with normalize={config.get('normalize')!r} but its "
                              f"VecNormalize statistics are missing beside it")
    return LoadedPolicy(model=model, algo=algo, files=files, config=dict(config or {}), normalizer=normalizer)


def transferable(model) -> bool:
    """Whether the model's policy runs on snakes of any n (the shared per-joint policy has
    ``for_spaces``; an MLP's input size fixes n)."""
    return callable(getattr(model.policy, "for_spaces", None))


def for_spaces(model, path: Path, observation_space, action_space):
    """The model with its policy rebuilt, same weights, for an env of another n (see
    :mod:`snake_env.train.joint_policy`): padded or unpadded, any number of joints."""
    try:
        policy = model.policy.for_spaces(observation_space, action_space)
    except ValueError as exc:
        raise PolicyLoadError(f"{path} cannot run on this env: {_first_line(exc)}") from None
    model.policy = policy
    model.observation_space = observation_space
    model.action_space = action_space
    if hasattr(model, "_create_aliases"):  # SAC's actor / critic attributes
        model._create_aliases()
    return model
