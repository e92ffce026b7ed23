"""``snake-export``: a saved PPO/SAC policy as one ONNX graph, raw observation -> env action.

Examples::

    snake-export runs/snake5_ppo --out policy.onnx
    snake-export runs/snake5_ppo/checkpoints/model_200000_steps.zip --out policy.onnx
    python -m snake_env.train.export runs/snake5_sac --out sac.onnx
    snake-export runs/multi_n_run --env snake_env/Snake20-v2 --out snake20.onnx   # JointPolicy: a graph for n = 20

The graph reproduces ``model.predict(normalize(obs), deterministic=True)`` of
the evaluation path (:mod:`snake_env.agents.policy_loading`), so it runs where neither
PyTorch nor Stable-Baselines3 is installed (onnxruntime alone):

1. VecNormalize observation normalization with the run's statistics, folded in
   as constants: ``clip((obs - mean) / sqrt(var + epsilon), -clip_obs, clip_obs)``,
   computed in float64 like VecNormalize, then cast to float32;
2. the deterministic action: PPO's Gaussian mean, SAC's ``tanh`` of its mean;
3. SB3's post-processing for a Box action space: an unsquashed action is
   clipped to [low, high], a squashed one (SAC) is rescaled from [-1, 1] to
   [low, high].

Input ``obs`` (batch, obs_size) float32; output ``action`` (batch, n_links - 1)
float32 joint torques in units of ``max_torque``. A goal task's Dict observation
(``observation`` / ``achieved_goal`` / ``desired_goal``, SB3's MultiInputPolicy) becomes one
input per key, named after the key, in the space's order, each normalized with its own
statistics; the metadata key ``obs_keys`` (JSON ``{key: size}``) lists them. The model's metadata
(``metadata_props``) holds the env id, its env kwargs (JSON), n_links, the
observation and action sizes, the algorithm and the snake_env version; the
graph is validated with ``onnx.checker`` before it is written (atomically).

A run trained with opt-in wrappers (``env_wrapper``: joint targets, a phase
clock, a CPG; :mod:`snake_env.wrappers`) exports its network between the
*wrapped* observation and action; the metadata key ``env_wrapper`` (JSON)
names the wrappers, which ``snake-eval --onnx`` and
:class:`snake_env.agents.onnx_policy.OnnxPolicy` users apply around the env
(a few lines of numpy per step, documented in that module).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import warnings
from pathlib import Path

from snake_env.train.config import first_line

EXIT_ERROR = 2
OPSET = 17
INPUT_NAME = "obs"
OUTPUT_NAME = "action"


class ExportError(ValueError):
    """A one-line CLI error."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="snake-export",
        description="Export a saved PPO/SAC snake policy (with its VecNormalize statistics) to ONNX.")
    parser.add_argument("target", help="run directory or model .zip written by snake-train")
    parser.add_argument("--out", required=True, help="output path, must end with .onnx")
    parser.add_argument("--env", dest="env_id", help="env id (needed when no config.yaml is beside the model; "
                                                     "otherwise it must match the run's, except for policy "
                                                     "JointPolicy, which exports a graph for this env's n)")
    parser.add_argument("--opset", type=int, default=OPSET, help=f"ONNX opset (default {OPSET})")
    return parser


def check_output(path: Path) -> None:
    if path.suffix != ".onnx":
        raise ExportError(f"--out must end with .onnx, got {str(path)!r}")
    if path.is_dir():
        raise ExportError(f"--out {path} is a directory")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ExportError(f"--out: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ExportError(f"--out: {path} is not writable")


def load_for_export(target, env_id=None):
    """(loaded policy, env_id, env_kwargs, env_wrapper, observation_space, action_space, n_links) of a run."""
    import gymnasium as gym

    import snake_env  # noqa: F401  (registers the ids)
    from snake_env.agents.policy_loading import PolicyLoadError, detect_algo, load_policy, locate
    from snake_env.train.config import JOINT_POLICY, ConfigError, load_run_config
    from snake_env.train.joint_features import LayoutError, check_env_layout
    from snake_env.wrappers import wrap_env

    try:
        files = locate(target)
        detect_algo(files.model)  # a readable PPO/SAC archive before anything else
        config = load_run_config(files.config) if files.config is not None else {}
    except (PolicyLoadError, ConfigError) as exc:
        raise ExportError(str(exc)) from None
    any_n = config.get("policy") == JOINT_POLICY  # the shared per-joint policy: a graph for another n
    if env_id and config.get("env_id") not in (None, env_id) and not any_n:
        raise ExportError(f"{files.model} was trained on {config['env_id']}, not {env_id} (only policy "
                          f"{JOINT_POLICY} exports for another env)")
    env_id = env_id or config.get("env_id")
    if env_id is None:
        raise ExportError(f"no config.yaml beside {files.model}; pass --env ID")
    env_kwargs = dict(config.get("env_kwargs") or {})
    env_wrapper = config.get("env_wrapper") or None
    try:
        env = wrap_env(gym.make(env_id, **env_kwargs), env_wrapper)
    except (ValueError, TypeError, gym.error.Error) as exc:
        raise ExportError(f"cannot make env {env_id!r} with env_kwargs {env_kwargs} and env_wrapper {env_wrapper}: "
                          f"{first_line(exc)}") from None
    try:
        obs_space = env.observation_space
        parts = obs_space.spaces.values() if isinstance(obs_space, gym.spaces.Dict) else [obs_space]
        if not all(isinstance(part, gym.spaces.Box) and len(part.shape) == 1 for part in parts) \
                or not isinstance(env.action_space, gym.spaces.Box):
            raise ExportError(f"{env_id} has {type(obs_space).__name__} observations and "
                              f"{type(env.action_space).__name__} actions; export supports flat Box observations "
                              f"(or a Dict of them) and Box actions")
        loaded = load_policy(files.model, env.observation_space, env.action_space, config)
        if any_n:
            check_env_layout(loaded.model.policy.layout, env, env_id)
        n_links = int(getattr(env.unwrapped, "n_links", env.action_space.shape[0] + 1))
        return loaded, env_id, env_kwargs, env_wrapper, env.observation_space, env.action_space, n_links
    except (PolicyLoadError, LayoutError) as exc:
        raise ExportError(str(exc)) from None
    finally:
        env.close()


def observation_keys(observation_space) -> list[str] | None:
    """The keys of a Dict observation, in the space's order (one graph input each); None for a Box."""
    from gymnasium import spaces

    return list(observation_space.spaces) if isinstance(observation_space, spaces.Dict) else None


def policy_graph(loaded, observation_space, action_space):
    """A torch module: raw observation (batch, obs) float32 -> env action (batch, act) float32; for a
    Dict observation space, one (batch, size) input per key in :func:`observation_keys`' order."""
    import numpy as np
    import torch
    from torch import nn

    policy = loaded.model.policy
    normalizer = loaded.normalizer
    keys = observation_keys(observation_space)
    # (mean, var) per normalized input: index 0 for a Box, the normalized keys for a Dict
    stats = {}
    if normalizer is not None and normalizer.norm_obs:
        if keys is None:
            stats[0] = normalizer.obs_rms
        else:
            stats = {keys.index(key): normalizer.obs_rms[key] for key in normalizer.norm_obs_keys}
    epsilon = float(normalizer.epsilon) if normalizer is not None else 0.0
    clip_obs = float(normalizer.clip_obs) if normalizer is not None else 0.0

    class ObsToAction(nn.Module):
        def __init__(self):
            super().__init__()
            self.policy = policy
            self.keys = keys
            self.normalized = sorted(stats)  # indices of the inputs with VecNormalize statistics
            for index, rms in stats.items():
                self.register_buffer(f"obs_mean_{index}", torch.as_tensor(np.asarray(rms.mean, np.float64)))
                self.register_buffer(f"obs_std_{index}",
                                     torch.sqrt(torch.as_tensor(np.asarray(rms.var, np.float64)) + epsilon))
            self.clip_obs = clip_obs
            self.register_buffer("low", torch.as_tensor(action_space.low, dtype=torch.float32))
            self.register_buffer("high", torch.as_tensor(action_space.high, dtype=torch.float32))
            self.is_sac = loaded.algo == "sac"
            self.squash = bool(policy.squash_output)

        def forward(self, *inputs):
            inputs = list(inputs)
            for index in self.normalized:
                # VecNormalize._normalize_obs in float64, then .astype(float32)
                mean, std = getattr(self, f"obs_mean_{index}"), getattr(self, f"obs_std_{index}")
                inputs[index] = torch.clamp((inputs[index].double() - mean) / std,
                                            -self.clip_obs, self.clip_obs).float()
            obs = inputs[0] if self.keys is None else dict(zip(self.keys, inputs))
            if self.is_sac:
                mean_actions, _, _ = self.policy.actor.get_action_dist_params(obs)
            elif hasattr(self.policy, "action_mean"):  # the shared per-joint policy (snake_env.train.joint_policy)
                mean_actions = self.policy.action_mean(obs)
            else:
                features = self.policy.extract_features(obs, self.policy.pi_features_extractor)
                latent_pi = self.policy.mlp_extractor.forward_actor(features)
                mean_actions = self.policy.action_net(latent_pi)
            if self.squash:
                # SquashedDiagGaussian / gSDE bijector mode, then BasePolicy.unscale_action
                action = torch.tanh(mean_actions)
                return self.low + 0.5 * (action + 1.0) * (self.high - self.low)
            return torch.maximum(torch.minimum(mean_actions, self.high), self.low)  # np.clip(low, high)

    module = ObsToAction().eval()
    return module


def export_onnx(target, out, env_id=None, opset: int = OPSET) -> dict:
    """Write the ONNX graph of a saved policy to ``out``; return its metadata."""
    import io

    import onnx
    import torch

    import snake_env
    from snake_env.atomic import atomic_write_bytes

    out = Path(out)
    check_output(out)
    loaded, env_id, env_kwargs, env_wrapper, obs_space, action_space, n_links = load_for_export(target, env_id)
    module = policy_graph(loaded, obs_space, action_space)
    keys = module.keys
    sizes = {INPUT_NAME: obs_space.shape[0]} if keys is None else {k: obs_space[k].shape[0] for k in keys}
    dummies = tuple(torch.zeros((1, size), dtype=torch.float32) for size in sizes.values())
    buffer = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        # the TorchScript-based exporter: a plain MLP needs neither onnxscript nor torch.export
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(module, dummies, buffer, input_names=list(sizes), output_names=[OUTPUT_NAME],
                          dynamic_axes={name: {0: "batch"} for name in (*sizes, OUTPUT_NAME)},
                          opset_version=opset, dynamo=False)
    model = onnx.load_from_string(buffer.getvalue())
    metadata = {
        "env_id": env_id,
        "env_kwargs": json.dumps(env_kwargs, sort_keys=True),
        "n_links": str(n_links),
        "obs_size": str(sum(sizes.values())),
        **({"obs_keys": json.dumps(sizes)} if keys is not None else {}),
        "action_size": str(action_space.shape[0]),
        "algo": loaded.algo,
        "vecnormalize": "folded" if module.normalized else "none",
        "snake_env_version": snake_env.__version__,
        "source_model": loaded.files.model.name,
        **({"env_wrapper": json.dumps(env_wrapper, sort_keys=True)} if env_wrapper else {}),
    }
    model.producer_name = "snake_env"
    model.producer_version = snake_env.__version__
    model.doc_string = (f"{loaded.algo.upper()} policy for {env_id}: raw observation -> joint torques "
                        f"(units of max_torque), deterministic")
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    try:
        onnx.checker.check_model(model, full_check=True)
    except onnx.checker.ValidationError as exc:
        raise ExportError(f"the exported graph does not validate: {first_line(exc)}") from None
    try:
        atomic_write_bytes(out, model.SerializeToString())
    except OSError as exc:
        raise ExportError(f"--out: cannot write {out}: {first_line(exc)}") from None
    return metadata


def read_metadata(path) -> dict:
    """The ``metadata_props`` of an ONNX file as a dict (needs only the onnx package)."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    return {entry.key: entry.value for entry in model.metadata_props}


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.opset < 13:
            raise ExportError(f"--opset must be >= 13, got {args.opset}")
        metadata = export_onnx(args.target, args.out, args.env_id, args.opset)
    except ExportError as exc:
        parser.exit(EXIT_ERROR, f"snake-export: error: {exc}\n")
    except ImportError as exc:
        parser.exit(EXIT_ERROR, f"snake-export: error: {exc.name or exc} is missing; "
                                f"pip install \"snake_env[export]\"\n")
    print(f"{metadata['algo'].upper()} policy for {metadata['env_id']} exported to {args.out} "
          f"(obs {metadata['obs_size']} -> action {metadata['action_size']}, "
          f"VecNormalize {metadata['vecnormalize']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
