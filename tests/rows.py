"""A vector env's rows against single envs, step by step (shared by the env and physics tests)."""

import numpy as np


def assert_rows_step_like_singles(vec, singles, rng, steps: int, info_keys=()) -> None:
    """Step ``vec`` and its rows' ``singles`` (single envs in the rows' states) with the same random
    actions for ``steps`` steps: observations, rewards and ``info_keys`` must be equal bit for bit."""
    for _ in range(steps):
        a = rng.uniform(-1, 1, (len(singles),) + vec.single_action_space.shape).astype(np.float32)
        obs, rewards, _, _, info = vec.step(a)
        for b, env in enumerate(singles):
            o, r, _, _, i = env.step(a[b])
            np.testing.assert_array_equal(o, obs[b])
            assert r == rewards[b]
            for key in info_keys:
                np.testing.assert_array_equal(i[key], info[key][b])
