"""snake-eval --video: GIF and MP4 open with the expected frame count, the HUD is on the
frames, --compare puts two episodes side by side."""

from __future__ import annotations

import numpy as np
import pytest

from tests.newest_ids import newest_id
from snake_env.train.evaluate import main

ENV = newest_id("Snake3")
STEPS = 30


def read_frames(path):
    import imageio.v3 as iio

    return iio.imread(path)


def test_gif_frame_count_and_hud(tmp_path):
    plain, hud = tmp_path / "plain.gif", tmp_path / "hud.gif"
    for path, extra in ((plain, ["--no-hud"]), (hud, [])):
        assert main(["--baseline", "serpenoid", "--env", ENV, "--episodes", "1", "--max-steps", str(STEPS),
                     "--video", str(path), *extra]) == 0
    a, b = read_frames(plain), read_frames(hud)
    # STEPS + 1 frames (the reset frame too), every other one in a GIF
    assert a.shape == b.shape == ((STEPS + 1 + 1) // 2, 480, 480, 3)
    # GIF palettes are quantized per file, so compare magnitudes: the HUD darkens its corners
    # (panel top left, scale bar bottom left); elsewhere only palette rounding remains
    diff = np.abs(a.astype(float) - b.astype(float)).mean(axis=(0, 3))
    assert diff[:40, :100].mean() > 30 and diff[-30:, :60].mean() > 30
    # the panel holds 9 lines (time, speed, distance, return and five gait metrics): ~190 px
    assert diff[220:-60, :].mean() < 3 and diff[:, 300:].mean() < 3


def test_mp4_frame_count(tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    path = tmp_path / "snake.mp4"
    assert main(["--baseline", "serpenoid", "--env", ENV, "--episodes", "1", "--max-steps", str(STEPS),
                 "--video", str(path)]) == 0
    frames = read_frames(path)
    assert frames.shape == (STEPS + 1, 480, 480, 3)


def test_side_by_side(ppo_run, tmp_path):
    path = tmp_path / "both.gif"
    assert main([str(ppo_run), "--episodes", "1", "--max-steps", "20", "--video", str(path),
                 "--compare", "serpenoid"]) == 0
    frames = read_frames(path)
    assert frames.shape == (11, 480, 2 * 480 + 4, 3)
    assert not np.array_equal(frames[-1, :, :480], frames[-1, :, 484:])
    with pytest.raises(SystemExit) as info:
        main([str(ppo_run), "--compare", "serpenoid"])  # no --video
    assert info.value.code == 2
