"""Track a commanded forward speed and yaw rate (``snake_env/SnakeCommand{n}-v2``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from snake_env.controllers import SteeringController
from snake_env.physics.settings import setting
from snake_env.physics import AUX_VX, AUX_VY

from .base import (DEFAULT_CTRL_COST_WEIGHT, StepContext, Task, box_with_extras, link_centers, mean_heading,
                   squared_norm)

_SEED_HIGH = 2 ** 62  # per-env command-schedule seeds are drawn below this


@dataclass(frozen=True)
class CommandTask(Task):
    r"""Follow a velocity command: a forward speed and a yaw rate, resampled every few seconds.

    ## Description
    The snake of `snake_env/Snake{n}-v3` (same physics, actions, start state)
    tracks a command c = (v_cmd, w_cmd): a forward speed along its heading
    (m/s) and a yaw rate (rad/s), like the joystick tasks of MuJoCo Playground.
    The heading is the mean link angle theta_bar = (1/n) sum theta_k
    (Liljebäck et al. 2011). The measured velocities are filtered over
    `velocity_filter_time` because an undulating gait makes theta_bar and the
    CM velocity oscillate within each stroke:
    - v = (v_x, v_y) . (cos theta_bar, sin theta_bar) of the whole CM (m/s),
    - w = d theta_bar / dt over the step (rad/s),
    each low-pass filtered (first order, time constant `velocity_filter_time`).
    A new command is drawn every `command_period` seconds, uniformly from
    `speed_range` and `yaw_rate_range`.

    ## Action Space
    As `snake_env/Snake{n}-v3`: `Box(-1, 1, (n_links - 1,), float32)`, joint torques in units of `max_torque`.

    ## Observation Space
    `Box(-inf, inf, (2 n + 6,), float64)`: the physics observation of
    `Snake{n}-v3` (2 n + 2 entries), then, in the body frame:

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 2n+2 | v_cmd, commanded forward speed | m/s |
    | 2n+3 | w_cmd, commanded yaw rate | rad/s |
    | 2n+4 | v, filtered forward speed | m/s |
    | 2n+5 | w, filtered yaw rate | rad/s |

    ## Rewards
    reward = exp(-(v - v_cmd)^2 / `speed_sigma`) + `yaw_weight` * exp(-(w - w_cmd)^2 / `yaw_sigma`)
             - `ctrl_cost_weight` * ||a||^2
    (`info`: `reward_speed`, `reward_yaw`, `reward_ctrl`; also `speed_error` = v - v_cmd (m/s),
    `yaw_rate_error` = w - w_cmd (rad/s), `speed_command`, `yaw_rate_command`).

    ## Starting State
    As `Snake{n}-v3`; the filters start at 0. The command schedule is fixed at reset
    (a seed per episode drawn from the env's generator).

    ## Episode End
    - Termination: never.
    - Truncation: after 1000 steps (40 s, 8 commands), or on a simulator failure.

    ## Arguments
    The physical arguments of `Snake{n}-v3`, `reset_noise_scale`, the costs (`energy_cost_weight`,
    `slip_cost_weight`, `slip_margin`, `action_rate_cost_weight`), and:

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `speed_range` | (0.0, 0.6) | forward speed command range (m/s) |
    | `yaw_rate_range` | (-0.5, 0.5) | yaw rate command range (rad/s) |
    | `command_period` | 5.0 | seconds between commands |
    | `speed_sigma` | 0.05 | tracking width ((m/s)^2) |
    | `yaw_sigma` | 0.1 | tracking width ((rad/s)^2) |
    | `yaw_weight` | 0.5 | weight of the yaw term |
    | `velocity_filter_time` | 0.5 | time constant of the velocity filters (s) |
    | `ctrl_cost_weight` | 1e-4 | weight of ||a||^2 |

    ## Version History
    * v3: wheels that slide and back-EMF braking, as the forward task's v4
      (docs/envs/forward.md): each wheel grips within mu m_k g and slides under
      Coulomb friction beyond it (`wheel_model="sliding"`) instead of the no-slip
      wheels under the traction limit, and a joint back-driven past 2 omega_0 is
      braked by its motor's back-EMF beyond the current limit
      (`back_emf_braking=True`). `snake_env/SnakeCommand{n}-v2` is still
      registered with `wheel_model="no_slip", back_emf_braking=False`, its physics
      bit for bit, and v1 with `actuator="ideal", wheel_friction=None`. The
      baseline steers the newest serpenoid of that n, searched on these wheels.
    * v2: a robot a lab could build: the joints are servo motors (`actuator="servo"`:
      1 N m stall torque, 3.14 rad/s no-load speed) and the wheels grip up to
      mu m_k g (`wheel_friction=0.8`, rubber on concrete) under the traction
      limit, instead of ideal torque sources and wheels that grip at any force
      (docs/env.md). `snake_env/SnakeCommand{n}-v1` is still registered with
      `actuator="ideal", wheel_friction=None`, its physics bit for bit.
      `info` gains `wheel_lateral_force`, `wheel_slip` and `traction_scale`. Corrected
      3 Dec 2026 without a new version (observations, rewards and terminations
      unchanged): `wheel_slip` no longer flags a wheel the traction limit holds at
      its grip, which rounding put up to 4.4e-16 of the grip above it. Corrected
      4 Dec 2026 as the forward task's v3 (docs/envs/forward.md): `actuator_power`
      is the power the motors deliver, no longer the commanded torques times the
      joint rotation; only a reward with `energy_cost_weight` > 0 changes with it.
    * v1: a step that meets every accuracy check but ends folded (|phi_k| reaches
      FOLD_ANGLE) fails at once instead of being refined up to `max_refinements`
      times (the finer substeps folded too). Only settings that can fold differ
      (`paper_model=True`, `joint_limit=None`); with the default joint limit
      no step folded in the fuzz (docs/reliability.md), so those runs equal v0.
    * v0: initial version.
    """

    speed_range: tuple = setting((0.0, 0.6), "m/s", "range", minimum=-math.inf, doc="forward speed commands")
    yaw_rate_range: tuple = setting((-0.5, 0.5), "rad/s", "range", minimum=-math.inf, doc="yaw rate commands")
    command_period: float = setting(5.0, "s", minimum=0.0, doc="seconds between commands")
    speed_sigma: float = setting(0.05, "(m/s)^2", minimum=0.0, doc="speed tracking width")
    yaw_sigma: float = setting(0.1, "(rad/s)^2", minimum=0.0, doc="yaw tracking width")
    yaw_weight: float = setting(0.5, "-", minimum=0.0, strict=False, doc="weight of the yaw term")
    velocity_filter_time: float = setting(0.5, "s", minimum=0.0, strict=False, doc="filter time constant")
    ctrl_cost_weight: float = setting(DEFAULT_CTRL_COST_WEIGHT, "per unit action^2", minimum=0.0, strict=False,
                                      doc="weight of ||a||^2")

    name = "command"
    id_prefix, version = "SnakeCommand", 3
    episode_metrics = {"mean_speed_error": ("speed_error", "mean_abs"),
                       "mean_yaw_rate_error": ("yaw_rate_error", "mean_abs")}
    baseline_name, baseline_controller = "steering", SteeringController
    step_info_keys = ("reward_speed", "reward_yaw", "reward_ctrl", "speed_error", "yaw_rate_error",
                      "speed_command", "yaw_rate_command")

    def observation_space(self, config, base):
        return box_with_extras(base, np.full(4, -np.inf), np.full(4, np.inf))

    def init_state(self, num_envs):
        return {"seed": np.zeros(num_envs, np.int64), "steps": np.zeros(num_envs, np.int64),
                "command": np.zeros((num_envs, 2)), "velocity": np.zeros((num_envs, 2))}

    def command_at(self, seed: int, index: int) -> np.ndarray:
        """Command ``index`` of the schedule of ``seed``: (v_cmd (m/s), w_cmd (rad/s))."""
        rng = np.random.default_rng([int(seed), int(index)])
        return np.array([rng.uniform(*self.speed_range), rng.uniform(*self.yaw_rate_range)])

    def reset(self, config, state, rows, rng, q, aux):
        seeds = rng.integers(0, _SEED_HIGH, size=rows.size)
        state["seed"][rows] = seeds
        state["steps"][rows] = 0
        state["velocity"][rows] = 0.0
        for row, seed in zip(rows, seeds):
            state["command"][row] = self.command_at(seed, 0)

    def observe(self, config, obs, q, aux, state):
        return np.concatenate([obs, state["command"], state["velocity"]], axis=1)

    def evaluate(self, config, ctx: StepContext, state):
        n = config.n_links
        heading_prev = mean_heading(ctx.q_prev, n)
        heading = mean_heading(ctx.q, n)
        mid = 0.5 * (heading_prev + heading)
        velocity = ctx.aux[:, AUX_VX:AUX_VY + 1]  # CM displacement over the step / dt (m/s)
        speed = velocity[:, 0] * np.cos(mid) + velocity[:, 1] * np.sin(mid)
        yaw_rate = (heading - heading_prev) / ctx.dt
        # first-order low-pass filter, exact for a constant input over the step
        keep = math.exp(-ctx.dt / self.velocity_filter_time) if self.velocity_filter_time > 0 else 0.0
        filtered = state["velocity"]
        filtered[:] = keep * filtered + (1.0 - keep) * np.stack([speed, yaw_rate], axis=-1)
        command = state["command"].copy()
        speed_error = filtered[:, 0] - command[:, 0]
        yaw_error = filtered[:, 1] - command[:, 1]
        reward_speed = np.exp(-np.square(speed_error) / self.speed_sigma)
        reward_yaw = self.yaw_weight * np.exp(-np.square(yaw_error) / self.yaw_sigma)
        ctrl_cost = self.ctrl_cost_weight * squared_norm(ctx.action)
        reward = reward_speed + reward_yaw - ctrl_cost
        # next command, shown in the observation after this step
        state["steps"] += 1
        period = max(1, int(round(self.command_period / ctx.dt)))
        for row in np.flatnonzero(state["steps"] % period == 0):
            state["command"][row] = self.command_at(state["seed"][row], state["steps"][row] // period)
        info = {"reward_speed": reward_speed, "reward_yaw": reward_yaw, "reward_ctrl": -ctrl_cost,
                "speed_error": speed_error, "yaw_rate_error": yaw_error,
                "speed_command": command[:, 0], "yaw_rate_command": command[:, 1]}
        return reward, np.zeros(reward.shape[0], bool), info

    def overlay(self, config, state, row, q):
        # the command as the path it asks for over the next 2 s: an arc from the CM along theta_bar
        v_cmd, w_cmd = state["command"][row]
        start = link_centers(config, q).mean(axis=0)
        t = np.linspace(0.0, 2.0, 21)
        heading = float(mean_heading(q, config.n_links)) + w_cmd * t
        steps = v_cmd * 0.1 * np.stack([np.cos(heading), np.sin(heading)], axis=-1)
        arc = start + np.concatenate([np.zeros((1, 2)), np.cumsum(steps[:-1], axis=0)])
        return [("polyline", arc), ("arrow", (arc[-2], arc[-1]))]
