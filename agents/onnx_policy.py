"""Run a policy exported by ``snake-export`` with onnxruntime alone.

Neither PyTorch nor Stable-Baselines3 is imported here: the ONNX graph maps
the raw env observation to the env action (normalization, deterministic
action, clipping/rescaling folded in), and its metadata names the env id and
env kwargs it was trained on. A policy trained with opt-in wrappers
(``env_wrapper``) maps the wrapped observation to the wrapped action: wrap the
env the same way, ``snake_env.wrappers.wrap_env(env, policy.env_wrapper)``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


class OnnxPolicyError(ValueError):
    """An ONNX file that is not a usable snake policy; the message is one line."""


class OnnxPolicy:
    """``act(obs) -> action`` from an exported ``.onnx`` file.

    Attributes: ``metadata`` (dict of the model's metadata_props), ``env_id``,
    ``env_kwargs`` (dict), ``env_wrapper`` (the ``wrap_env`` spec, or None),
    ``obs_size``, ``action_size``, ``obs_keys`` (``{key: size}`` of a goal task's Dict
    observation, one graph input per key; None for a Box observation).
    """

    def __init__(self, path):
        try:
            import onnxruntime as ort
        except ImportError:
            raise OnnxPolicyError('running an ONNX policy needs onnxruntime: pip install "snake_env[export]"') from None
        path = Path(path)
        if not path.is_file():
            raise OnnxPolicyError(f"no such ONNX file: {path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1  # one small MLP per step: threads only add latency
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(path), sess_options=options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for unreadable files
            text = str(exc).strip().splitlines()
            raise OnnxPolicyError(f"{path} is not a readable ONNX model: {text[0] if text else type(exc).__name__}") from None
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)
        missing = [key for key in ("env_id", "obs_size", "action_size") if key not in self.metadata]
        if missing:
            raise OnnxPolicyError(f"{path} lacks the snake-export metadata {missing}")
        self.path = path
        self.env_id = self.metadata["env_id"]
        self.env_kwargs = json.loads(self.metadata.get("env_kwargs", "{}"))
        # opt-in wrappers the policy was trained in (snake_env.wrappers.wrap_env spec), or None
        self.env_wrapper = json.loads(self.metadata.get("env_wrapper", "null"))
        self.obs_size = int(self.metadata["obs_size"])
        self.action_size = int(self.metadata["action_size"])
        self.input_name = self.session.get_inputs()[0].name
        self.obs_keys = json.loads(self.metadata["obs_keys"]) if "obs_keys" in self.metadata else None

    def check_spaces(self, observation_space, action_space) -> None:
        if self.obs_keys is not None:
            spaces = getattr(observation_space, "spaces", None)
            have = {k: tuple(s.shape) for k, s in spaces.items()} if isinstance(spaces, dict) else observation_space.shape
            want = {k: (size,) for k, size in self.obs_keys.items()}
        else:
            have, want = getattr(observation_space, "shape", None), (self.obs_size,)
        if have != want or tuple(action_space.shape) != (self.action_size,):
            raise OnnxPolicyError(
                f"{self.path} maps observations {want} to actions of size {self.action_size}; "
                f"the env has {have} -> {action_space.shape}")

    def act_batch(self, obs) -> np.ndarray:
        """(batch, obs_size) -> (batch, action_size), float32; a Dict observation as {key: (batch, size)}."""
        if self.obs_keys is not None:
            return self.session.run(None, {key: np.asarray(obs[key], np.float32) for key in self.obs_keys})[0]
        return self.session.run(None, {self.input_name: np.asarray(obs, np.float32)})[0]

    def act(self, obs) -> np.ndarray:
        if self.obs_keys is not None:
            return self.act_batch({key: np.asarray(obs[key], np.float32)[None] for key in self.obs_keys})[0]
        return self.act_batch(np.asarray(obs, np.float32)[None])[0]
