"""Rendering: headless rgb_array frames show the snake; "human" opens a window
through pygame (SDL dummy driver here) and explains how to install it if missing."""

import sys

import gymnasium as gym
import numpy as np
import pytest

from snake_env.envs import SnakeVectorEnv
from snake_env.envs.rendering import BACKGROUND, WHEEL, SnakeRenderer


def _frame_after_steps(n=5, steps=40, **kwargs):
    env = gym.make(f"snake_env/Snake{n}-v2", render_mode="rgb_array", **kwargs)
    env.reset(seed=0)
    t = np.arange(n - 1)
    for k in range(steps):
        env.step(np.sin(2 * np.pi * 0.5 * k * env.unwrapped.dt - 0.8 * t).astype(np.float32))
    return env, env.render()


@pytest.mark.parametrize("n", [3, 5, 30])
def test_rgb_array_frame_is_not_blank(n):
    env, frame = _frame_after_steps(n)
    assert frame.shape == (480, 480, 3) and frame.dtype == np.uint8
    background = np.all(frame == BACKGROUND.astype(np.uint8), axis=-1).mean()
    assert 0.5 < background < 0.995  # mostly floor, but something is drawn
    assert np.any(np.all(frame == WHEEL.astype(np.uint8), axis=-1))  # wheels fully covered pixels
    # the snake is drawn around the camera centre (its centre of mass)
    centre = frame[200:280, 200:280]
    assert np.any(np.abs(centre.astype(int) - BACKGROUND.astype(int)).sum(-1) > 100)


def test_frame_size_and_camera_follow():
    env, frame = _frame_after_steps(5, width=320, height=200)
    assert frame.shape == (200, 320, 3)
    q = env.unwrapped.state[0]
    renderer = SnakeRenderer(320, 200, env.unwrapped.params.half_length)
    cm = env.unwrapped.model.center_of_mass(q)
    np.testing.assert_allclose(renderer.to_pixels(cm, cm), [160, 100])
    shifted = renderer.draw(q, trail=np.array([cm + [10.0, 0.0]]))  # camera 10 m away: only floor
    assert not np.any(np.all(shifted == WHEEL.astype(np.uint8), axis=-1))


def test_render_without_mode_warns_and_returns_none():
    env = gym.make("snake_env/Snake3-v2")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.unwrapped.render() is None


def test_vector_env_renders_one_frame_per_sub_env():
    vec = SnakeVectorEnv(num_envs=2, n_links=4, render_mode="rgb_array", width=64, height=48)
    vec.reset(seed=0)
    for _ in range(5):
        vec.step(np.full((2, 3), 0.7, np.float32))
    frames = vec.render()
    assert len(frames) == 2 and all(f.shape == (48, 64, 3) for f in frames)
    assert not np.array_equal(frames[0], frames[1])


def test_human_mode_opens_a_window_headless():
    pytest.importorskip("pygame")
    env = gym.make("snake_env/Snake3-v2", render_mode="human", width=64, height=64)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    assert env.unwrapped._window is not None
    env.close()
    assert env.unwrapped._window is None


def test_human_mode_without_pygame_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "pygame", None)  # import pygame -> ImportError
    env = gym.make("snake_env/Snake3-v2", render_mode="human")
    with pytest.raises(ImportError, match=r"snake_env\[human\]"):
        env.reset(seed=0)
