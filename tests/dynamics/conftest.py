"""Shared fixtures: random models and random states."""

import numpy as np
import pytest

from snake_env.dynamics import SnakeModel


def random_model(rng, n, per_link=True, damping=False):
    """A model with paper-like parameters, per link random when ``per_link``."""
    if per_link:
        kwargs = dict(mass=rng.uniform(0.5, 2.0, n), length=rng.uniform(0.1, 0.4, n),
                      inertia=rng.uniform(0.002, 0.02, n))
    else:
        kwargs = {}
    if damping:
        kwargs.update(joint_damping=rng.uniform(0.0, 0.5, n - 1), wheel_damping=rng.uniform(0.0, 1.0, n))
    return SnakeModel(n, **kwargs)


def random_state(rng, n, batch=()):
    """q with joint angles within +-90 deg, u and torques of order 1."""
    theta1 = rng.uniform(-np.pi, np.pi, batch + (1,))
    phi = rng.uniform(-1.5, 1.5, batch + (n - 1,))
    theta = np.concatenate([theta1, theta1 + np.cumsum(phi, axis=-1)], axis=-1)
    q = np.concatenate([theta, rng.normal(size=batch + (2,))], axis=-1)
    u = rng.normal(size=batch + (2,))
    torques = rng.normal(size=batch + (n - 1,))
    return q, u, torques


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
