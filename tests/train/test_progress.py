"""Progress lines when stdout is not a terminal; the next-step commands at the end of snake-train."""

from __future__ import annotations

import io
import re

import pytest

from tests.train.conftest import train_args
from snake_env.train.progress import LogProgress, format_duration

LINE = re.compile(r"^\[ *(\d+)%\] (\d+)/(\d+) steps \| (\d+) fps \| ep return (\S+) \| speed (\S+)( m/s)? \| "
                  r"elapsed \S+ \| ETA \S+$")


def test_format_duration():
    assert format_duration(5.2) == "5s"
    assert format_duration(125) == "2m05s"
    assert format_duration(3 * 3600 + 60 * 7) == "3h07m"
    assert format_duration(float("nan")) == "?"


def test_lines_every_ten_percent_with_metrics(tmp_path, capsys):
    """A non-terminal stdout gets a line per 10 % with steps, fps, return, speed and ETA; then the hint."""
    from snake_env.train.train import main

    run_dir = tmp_path / "run"
    assert main([a for a in train_args("ppo", run_dir, 640) if a != "--no-progress-bar"] + ["--progress", "auto"]) == 0
    out = capsys.readouterr().out  # pytest's captured stdout is not a terminal
    lines = [line for line in out.splitlines() if line.startswith("[")]
    parsed = [LINE.match(line) for line in lines]
    assert all(parsed), lines
    steps = [int(m.group(2)) for m in parsed]
    assert steps == sorted(steps) and steps[-1] == 640 and len(steps) >= 5  # 32-step rollouts of 2 envs
    assert all(int(m.group(3)) == 640 for m in parsed)
    assert {int(m.group(1)) for m in parsed} >= {20, 40, 60, 80, 100}
    assert any(m.group(5) != "n/a" for m in parsed)  # 50-step episodes finished: mean return known
    assert all(m.group(6) != "n/a" for m in parsed)
    assert f"snake-eval {run_dir} --episodes 10" in out and "--video" in out
    assert f"snake-export {run_dir} --out {run_dir / 'policy.onnx'}" in out
    assert "\r" not in out  # no redrawn bar in a log


def test_time_based_lines():
    """With a slow clock a line comes every ``every_seconds`` even between percentages."""

    class FakeModel:
        num_timesteps = 0
        ep_info_buffer = [{"r": 2.0}, {"r": 4.0}]

    ticks = iter(range(0, 10_000, 30))
    stream = io.StringIO()
    callback = LogProgress(1_000_000, every_percent=50, every_seconds=60, stream=stream, clock=lambda: next(ticks))
    callback.init_callback(FakeModel())
    callback.on_training_start({}, {})
    for step in range(1, 11):
        FakeModel.num_timesteps = step * 10
        callback.update_locals({"infos": [{"x_velocity": 0.5}, {"x_velocity": 1.5}]})
        callback.on_step()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 5  # clock advances 30 s per call: one line per 60 s
    assert "ep return 3 " in lines[0] and "speed 1 m/s" in lines[0]
    with pytest.raises(ValueError):
        LogProgress(10, every_percent=0)


def test_an_overshooting_last_rollout_gives_one_final_line():
    """Past the requested total (PPO's last rollout overshoots a small total) only the end reports."""

    class FakeModel:
        num_timesteps = 0
        ep_info_buffer = []

    ticks = iter(range(1000))
    stream = io.StringIO()
    callback = LogProgress(100, every_percent=10, every_seconds=1e9, stream=stream, clock=lambda: next(ticks))
    callback.init_callback(FakeModel())
    callback.on_training_start({}, {})
    for step in range(1, 21):  # 8 steps a call, up to 160 of 100
        FakeModel.num_timesteps = step * 8
        callback.update_locals({"infos": []})
        callback.on_step()
    callback.on_training_end()
    steps = [int(m.group(2)) for m in map(LINE.match, stream.getvalue().splitlines()) if m]
    assert [s for s in steps if s >= 100] == [160] and steps == sorted(steps)
