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
    ``obs_size``, ``action_size``.
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

    def check_spaces(self, observation_space, action_space) -> None:
        if tuple(observation_space.shape) != (self.obs_size,) or tuple(action_space.shape) != (self.action_size,):
            raise OnnxPolicyError(
                f"{self.path} maps observations of size {self.obs_size} to actions of size {self.action_size}; "
                f"the env has {observation_space.shape} -> {action_space.shape}")

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        """(batch, obs_size) -> (batch, action_size), float32."""
        return self.session.run(None, {self.input_name: np.asarray(obs, np.float32)})[0]

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.act_batch(np.asarray(obs, np.float32)[None])[0]
