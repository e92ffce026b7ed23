"""The video HUD: text and scale bar change pixels only inside their boxes, the bar's length
is the labelled metres at the renderer's scale, and the text is really drawn."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from tests.newest_ids import newest_id
from snake_env.envs.hud import draw_hud, draw_text, episode_lines, hud_boxes, nice_length, text_size


@pytest.fixture(scope="module")
def frame_and_scale():
    env = gym.make(newest_id("Snake5"), render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(20):
        env.step(env.action_space.sample())
    frame = env.render()
    scale = env.unwrapped._renderer.scale  # pixels per metre of this camera
    env.close()
    return frame, scale


def test_hud_changes_only_its_boxes(frame_and_scale):
    frame, scale = frame_and_scale
    lines = episode_lines(12.34, 0.52, 3.1, -12.5, label="ppo")
    out = draw_hud(frame, lines, scale)
    assert out.shape == frame.shape and out.dtype == np.uint8
    inside = np.zeros(frame.shape[:2], bool)
    boxes = hud_boxes(frame.shape, lines, scale)
    assert len(boxes) == 2
    for r0, c0, r1, c1 in boxes:
        inside[r0:r1, c0:c1] = True
        assert np.any(out[r0:r1, c0:c1] != frame[r0:r1, c0:c1])  # each box is drawn
    changed = np.any(out != frame, axis=-1)
    assert not np.any(changed & ~inside)  # nothing outside the HUD boxes
    assert 0.02 < inside.mean() < 0.2  # a corner panel, not the whole frame
    assert np.array_equal(draw_hud(frame, [], None), frame)  # no lines, no scale: the plain frame
    assert np.array_equal(frame, frame_and_scale[0])  # the input is not modified


def test_scale_bar_length_is_the_labelled_metres(frame_and_scale):
    frame, scale = frame_and_scale
    out = draw_hud(frame, [], scale)
    (r0, c0, r1, c1), = hud_boxes(frame.shape, [], scale)
    white = np.all(out[r0:r1, c0:c1] == 255, axis=-1)
    bar_row = np.argmax(white.sum(axis=1))  # the bar is the longest white run
    bar_px = white[bar_row].sum()
    length = nice_length(0.25 * frame.shape[1] / scale)
    assert bar_px == round(length * scale)
    assert length in (0.1, 0.2, 0.5, 1.0, 2.0)


def test_text_is_drawn_and_distinct():
    canvas = np.zeros((20, 200, 3), np.float32)
    draw_text(canvas, "0.52 M/S", 2, 2, scale=2)
    height, width = text_size("0.52 M/S", scale=2)
    ink = np.argwhere(np.any(canvas > 0, axis=-1))
    assert ink[:, 0].min() >= 2 and ink[:, 0].max() < 2 + height
    assert ink[:, 1].min() >= 2 and ink[:, 1].max() < 2 + width
    glyphs = {}
    for char in "0123456789.-:/MSTVDR":
        tile = np.zeros((7, 5, 3), np.float32)
        draw_text(tile, char, 0, 0, scale=1)
        glyphs[char] = tile[..., 0].tobytes()
        assert tile.any() or char == " "
    assert len(set(glyphs.values())) == len(glyphs)  # every character looks different
    assert nice_length(0.49) == 0.2 and nice_length(1.0) == 1.0 and nice_length(0.07) == pytest.approx(0.05)
    with pytest.raises(ValueError):
        nice_length(0.0)
