"""Training progress that reads well in a terminal and in a log file.

On a terminal SB3's own progress bar (tqdm/rich) redraws one line. When
stdout is not a terminal (a server log, CI, ``nohup``) a redrawn bar shows
only its final line, so a long run looks hung; :class:`LogProgress` prints a
plain line instead every ``every_percent`` of the run or every
``every_seconds``, whichever comes first::

    [ 40%] 320000/800000 steps | 2210 fps | ep return 151.2 | speed 1.53 m/s | elapsed 2m25s | ETA 3m37s

``ep return`` is SB3's ``ep_rew_mean`` (the last 100 finished episodes, raw
rewards from VecMonitor); ``speed`` is the mean of ``info["x_velocity"]``
(m/s, whole-snake CM) over the steps since the previous line.
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback


def format_duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    seconds = int(round(max(seconds, 0.0)))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    if hours:
        return f"{hours}h{minutes:02d}m"
    if minutes:
        return f"{minutes}m{secs:02d}s"
    return f"{secs}s"


def stdout_is_terminal() -> bool:
    try:
        return sys.stdout.isatty()
    except (AttributeError, ValueError):
        return False


class LogProgress(BaseCallback):
    """Print a progress line every ``every_percent`` % of ``total_timesteps`` or every ``every_seconds``.

    ``total_timesteps`` counts from zero (a resumed run reports against the whole run).
    """

    def __init__(self, total_timesteps: int, every_percent: float = 10.0, every_seconds: float = 60.0,
                 stream=None, clock=time.monotonic):
        super().__init__(verbose=0)
        if every_percent <= 0 or every_seconds <= 0:
            raise ValueError("every_percent and every_seconds must be > 0")
        self.total = int(total_timesteps)
        self.every_steps = max(1, int(self.total * every_percent / 100.0))
        self.every_seconds = float(every_seconds)
        self.stream = stream
        self.clock = clock
        self.lines: list[str] = []

    def _on_training_start(self) -> None:
        self._start_time = self.clock()
        self._start_steps = self.model.num_timesteps
        self._last_time = self._start_time
        self._next_steps = (self.model.num_timesteps // self.every_steps + 1) * self.every_steps
        self._speed_sum = 0.0
        self._speed_count = 0

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            speed = info.get("x_velocity")
            if speed is not None and math.isfinite(speed):
                self._speed_sum += float(speed)
                self._speed_count += 1
        now = self.clock()
        steps = self.model.num_timesteps
        # past the requested total (PPO's last rollout overshoots it) only the end of training reports
        if steps < self.total and (steps >= self._next_steps or now - self._last_time >= self.every_seconds):
            self.report(steps, now)
            self._next_steps = (steps // self.every_steps + 1) * self.every_steps
        return True

    def _on_training_end(self) -> None:
        if self.model.num_timesteps != getattr(self, "_reported_steps", None):
            self.report(self.model.num_timesteps, self.clock())

    def report(self, steps: int, now: float) -> str:
        elapsed = now - self._start_time
        done = steps - self._start_steps
        fps = done / elapsed if elapsed > 0 else float("nan")
        remaining = max(self.total - steps, 0)
        eta = remaining / fps if fps and math.isfinite(fps) and fps > 0 else float("nan")
        buffer = getattr(self.model, "ep_info_buffer", None) or []
        ep_return = f"{np.mean([e['r'] for e in buffer]):.4g}" if len(buffer) else "n/a"
        speed = f"{self._speed_sum / self._speed_count:.3g} m/s" if self._speed_count else "n/a"
        percent = min(100.0 * steps / self.total, 100.0) if self.total else 100.0  # PPO overshoots by < 1 rollout
        line = (f"[{percent:3.0f}%] {steps}/{self.total} steps | {fps:.0f} fps | ep return {ep_return} | "
                f"speed {speed} | elapsed {format_duration(elapsed)} | ETA {format_duration(eta)}")
        print(line, file=self.stream or sys.stdout, flush=True)
        self.lines.append(line)
        self._last_time = now
        self._reported_steps = steps
        self._speed_sum = 0.0
        self._speed_count = 0
        return line
