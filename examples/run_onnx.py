"""Drive a snake env with a policy exported by ``snake-export``, using onnxruntime only.

    snake-export runs/snake5_ppo --out policy.onnx
    python examples/run_onnx.py policy.onnx --episodes 5 --seed 0

Neither PyTorch nor Stable-Baselines3 is imported: the ONNX graph takes the raw
observation and returns the env action; the env id and env kwargs come from
the graph's metadata. The table has the same metrics (and the same numbers
for the same seed) as ``snake-eval RUN_DIR --episodes 5 --seed 0``.
"""

from __future__ import annotations

import argparse
import sys

import gymnasium as gym
import numpy as np
import onnxruntime as ort

import snake_env  # noqa: F401  (registers the snake ids)
from snake_env.agents.onnx_policy import OnnxPolicy, OnnxPolicyError
from snake_env.train.evaluate import print_table, run_episodes, summarize
from snake_env.wrappers import wrap_env


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Run an exported snake policy with onnxruntime.")
    parser.add_argument("onnx", help="policy.onnx written by snake-export")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="seed of episode k is seed + k")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.exit(2, f"run_onnx.py: error: --episodes must be >= 1, got {args.episodes}\n")
    try:
        policy = OnnxPolicy(args.onnx)  # an onnxruntime.InferenceSession and the metadata
    except OnnxPolicyError as exc:
        parser.exit(2, f"run_onnx.py: error: {exc}\n")
    # a policy trained with opt-in wrappers (joint targets, a clock, a CPG) acts in the wrapped env
    env = wrap_env(gym.make(policy.env_id, **policy.env_kwargs), policy.env_wrapper)
    policy.check_spaces(env.observation_space, env.action_space)
    results, _ = run_episodes(env, policy.act, lambda: None, args.episodes, args.seed)
    env.close()
    print_table(f"{args.onnx} on {policy.env_id} (onnxruntime {ort.__version__}, numpy {np.__version__})",
                results, summarize(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
