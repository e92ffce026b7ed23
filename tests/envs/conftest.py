"""Headless test settings for the env tests: SDL (pygame) gets dummy video and
audio drivers so the "human" render mode can be exercised without a display."""

import os

import numpy as np
import pytest

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import snake_env  # noqa: E402,F401  (registers the ids)

ALL_IDS = ["snake_env/Snake-v2"] + [f"snake_env/Snake{n}-v2" for n in (3, 5, 8, 12, 20, 30)]


@pytest.fixture
def rng():
    return np.random.default_rng(2024)
