"""The same seed gives the same training run, bit for bit, on one machine: PPO, and SAC with the
long snakes' gSDE exploration held over 8 steps (configs/sac.yaml, the Snake8-v3 entry), on v3's
physics (motors, finite grip). Another seed gives another run, so the comparison can fail."""

from __future__ import annotations

import pytest
import torch

from tests.train.conftest import train_args
from snake_env.train.train import main

ENV = "snake_env/Snake3-v3"
EXTRA = {
    "ppo": [],
    "sac": ["--set", "use_sde=true", "--set", "train_freq=8", "--set", "gradient_steps=8"],
}


def policy_weights(run_dir, algo: str) -> dict[str, torch.Tensor]:
    from stable_baselines3 import PPO, SAC

    model = {"ppo": PPO, "sac": SAC}[algo].load(run_dir / "model.zip", device="cpu")
    return {name: value.detach().clone() for name, value in model.policy.state_dict().items()}


def train(tmp_path, algo: str, seed: int, name: str) -> dict[str, torch.Tensor]:
    run_dir = tmp_path / name
    assert main(train_args(algo, run_dir, 384, "--env", ENV, "--seed", str(seed), *EXTRA[algo])) == 0
    return policy_weights(run_dir, algo)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_same_seed_same_weights(tmp_path, algo):
    first = train(tmp_path, algo, 0, "first")
    again = train(tmp_path, algo, 0, "again")
    other = train(tmp_path, algo, 1, "other")
    assert first.keys() == again.keys() == other.keys()
    assert all(torch.equal(first[name], again[name]) for name in first)
    assert not all(torch.equal(first[name], other[name]) for name in first)
