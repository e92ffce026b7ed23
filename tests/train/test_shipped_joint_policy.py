"""The shipped JointPolicy runs (examples/joint_policy on v3 and examples/joint_policy_v4 on v4: one PPO run each
on snakes of 5, 8, 12 and 16 links at once; docs/results.md, "One policy for every length") load and walk,
zero-shot, on a length they never saw: faster than the serpenoid searched for that length, on the same episode.
A physics change that breaks one is a reason to train it again."""

import json
from pathlib import Path

import pytest

from snake_env.train import evaluate

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _speed(tmp_path, name: str, env_id: str, *args: str) -> float:
    path = tmp_path / f"{name}.json"
    assert evaluate.main([*args, "--env", env_id, "--episodes", "1", "--max-steps", "500",
                          "--json", str(path)]) == 0
    return json.loads(path.read_text())["mean_forward_velocity"]


@pytest.mark.parametrize("run, env_id", [("joint_policy", "snake_env/Snake20-v3"),
                                         ("joint_policy_v4", "snake_env/Snake30-v4")])
def test_the_shipped_joint_policy_outruns_the_serpenoid_on_an_unseen_length(tmp_path, run, env_id):
    policy = _speed(tmp_path, "policy", env_id, str(EXAMPLES / run))
    serpenoid = _speed(tmp_path, "serpenoid", env_id, "--baseline", "serpenoid")
    assert policy > serpenoid > 0.0
