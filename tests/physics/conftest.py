"""Fixtures of the physics tests (the env tests' seed, so the moved tests draw the same states)."""

import numpy as np
import pytest

import snake_env  # noqa: F401  (registers the ids)


@pytest.fixture
def rng():
    return np.random.default_rng(2024)
