"""The shipped JointPolicy run (examples/joint_policy: one PPO run on snakes of 5, 8, 12 and 16 links at
once; docs/results.md, "One policy for every length") loads and walks, zero-shot, on a length it never
saw: faster than the serpenoid searched for that length, on the same episode. A physics change that
breaks it is a reason to train the run again."""

import json
from pathlib import Path

from snake_env.train import evaluate

RUN = Path(__file__).resolve().parents[2] / "examples" / "joint_policy"


def _speed(tmp_path, name: str, *args: str) -> float:
    path = tmp_path / f"{name}.json"
    assert evaluate.main([*args, "--env", "snake_env/Snake20-v3", "--episodes", "1", "--max-steps", "500",
                          "--json", str(path)]) == 0
    return json.loads(path.read_text())["mean_forward_velocity"]


def test_the_shipped_joint_policy_outruns_the_serpenoid_on_an_unseen_length(tmp_path):
    policy = _speed(tmp_path, "policy", str(RUN))
    serpenoid = _speed(tmp_path, "serpenoid", "--baseline", "serpenoid")
    assert policy > serpenoid > 0.0
