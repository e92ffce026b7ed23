"""slip_margin: the slip cost beyond a share of the grip. 1 (the default) is the cost beyond the grip
itself, bit for bit; below 1 it also charges wheels near their grip."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import snake_env  # noqa: F401
from tests.newest_ids import newest_id

ENV = newest_id("Snake5")


def slip_rewards(**kwargs):
    env = gym.make(ENV, slip_cost_weight=1.0, **kwargs)
    env.reset(seed=3)
    rng = np.random.default_rng(3)
    out = []
    for _ in range(60):
        _, reward, _, _, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
        out.append((reward, info["reward_slip"]))
    env.close()
    return np.array(out)


def test_margin_one_is_the_grip_and_a_smaller_margin_charges_more():
    plain, one, half = slip_rewards(), slip_rewards(slip_margin=1.0), slip_rewards(slip_margin=0.5)
    assert np.array_equal(plain, one)
    assert np.all(half[:, 1] <= one[:, 1])
    assert np.sum(half[:, 1]) < np.sum(one[:, 1]) - 1.0  # random torques hold wheels near their grip


@pytest.mark.parametrize("margin", [0.0, -0.5, 1.5, float("nan")])
def test_bad_margin_names_the_argument(margin):
    with pytest.raises(ValueError, match="slip_margin"):
        gym.make(ENV, slip_cost_weight=1.0, slip_margin=margin)
