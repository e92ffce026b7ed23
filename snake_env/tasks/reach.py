"""Reach a goal position: a gymnasium_robotics-style GoalEnv (``snake_env/SnakeReach{n}-v2``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces

from snake_env.controllers import GoalSeekingController
from snake_env.physics.settings import setting

from .base import StepContext, Task, link_centers


@dataclass(frozen=True)
class ReachTask(Task):
    r"""Move the snake's centre of mass to a goal on the plane (GoalEnv, HER-ready).

    ## Description
    The snake of `snake_env/Snake{n}-v3` (same physics, actions, start state)
    must bring its whole mass-weighted centre of mass (CM) within
    `distance_threshold` of a goal drawn at reset. The env follows the
    `gymnasium_robotics.GoalEnv` convention without depending on it: a Dict
    observation with `observation`, `achieved_goal`, `desired_goal` and a
    vectorized `compute_reward(achieved_goal, desired_goal, info)` that equals
    the step reward, so SB3's `HerReplayBuffer` can relabel goals.

    ## Action Space
    As `snake_env/Snake{n}-v3`: `Box(-1, 1, (n_links - 1,), float32)`, joint torques in units of `max_torque`.

    ## Observation Space
    `Dict`:

    | Key | Space | Content | Unit |
    |-----|-------|---------|------|
    | `observation` | `Box(2 n + 2,)` | the physics observation of `Snake{n}-v3` (joint angles, heading cos/sin, V_1, thetadot_1, joint rates) | rad, -, m/s, rad/s |
    | `achieved_goal` | `Box(2,)` | x, y of the whole snake's CM | m |
    | `desired_goal` | `Box(2,)` | x, y of the goal | m |

    `observation` does not hold the goal (HER relabels `desired_goal` only).

    ## Rewards
    With d = ||achieved_goal - desired_goal|| (m) after the step:
    - `reward_type="sparse"` (default): -1 if d > `distance_threshold`, else 0.
    - `reward_type="dense"`: -d.
    `info["reward_goal"]` holds it; there is no control cost (it would make the
    reward depend on more than the goals). `info["is_success"]` is
    d <= `distance_threshold`; `info["goal_distance"]` is d (m).

    ## Starting State
    As `Snake{n}-v3` (CM at the origin); the goal is drawn uniformly in an
    annulus around the origin: distance U(`goal_distance_range`) (m), direction U(-pi, pi).

    ## Episode End
    - Termination: on success when `terminate_on_success` (default True).
    - Truncation: after 400 steps (16 s), or on a simulator failure (see `Snake{n}-v3`).

    ## Arguments
    The physical arguments of `Snake{n}-v3`, `reset_noise_scale`, the costs (`energy_cost_weight`,
    `slip_cost_weight`, `slip_margin`, `action_rate_cost_weight`), and:

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `reward_type` | "sparse" | "sparse" or "dense" |
    | `distance_threshold` | 0.1 | success radius (m) |
    | `goal_distance_range` | (0.5, 1.5) | goal distance from the start CM (m) |
    | `terminate_on_success` | True | end the episode on success |

    ## Version History
    * v3: wheels that slide and back-EMF braking, as the forward task's v4
      (docs/envs/forward.md): each wheel grips within mu m_k g and slides under
      Coulomb friction beyond it (`wheel_model="sliding"`) instead of the no-slip
      wheels under the traction limit, and a joint back-driven past 2 omega_0 is
      braked by its motor's back-EMF beyond the current limit
      (`back_emf_braking=True`). `snake_env/SnakeReach{n}-v2` is still
      registered with `wheel_model="no_slip", back_emf_braking=False`, its physics
      bit for bit, and v1 with `actuator="ideal", wheel_friction=None`. The
      baseline steers the newest serpenoid of that n, searched on these wheels.
    * v2: a robot a lab could build: the joints are servo motors (`actuator="servo"`:
      1 N m stall torque, 3.14 rad/s no-load speed) and the wheels grip up to
      mu m_k g (`wheel_friction=0.8`, rubber on concrete) under the traction
      limit, instead of ideal torque sources and wheels that grip at any force
      (docs/env.md). `snake_env/SnakeReach{n}-v1` is still registered with
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

    reward_type: str = setting("sparse", "-", "choice", maximum=("sparse", "dense"), doc="sparse or dense reward")
    distance_threshold: float = setting(0.1, "m", minimum=0.0, doc="success radius")
    goal_distance_range: tuple = setting((0.5, 1.5), "m", "range", minimum=0.0, doc="goal distance from start")
    terminate_on_success: bool = setting(True, "-", "bool", doc="end the episode on success")

    name = "reach"
    id_prefix, version = "SnakeReach", 3
    max_episode_steps = 400
    goal_env = True
    step_info_keys = ("reward_goal", "goal_distance", "is_success")
    episode_metrics = {"success": ("is_success", "any"), "final_goal_distance": ("goal_distance", "last")}
    baseline_name, baseline_controller = "homing", GoalSeekingController

    def observation_space(self, config, base):
        goal = spaces.Box(-np.inf, np.inf, (2,), np.float64)
        return spaces.Dict({"observation": base, "achieved_goal": goal, "desired_goal": goal})

    def init_state(self, num_envs):
        return {"goal": np.zeros((num_envs, 2))}

    def reset(self, config, state, rows, rng, q, aux):
        low, high = self.goal_distance_range
        distance = rng.uniform(low, high, size=rows.size)
        direction = rng.uniform(-math.pi, math.pi, size=rows.size)
        state["goal"][rows] = np.stack([distance * np.cos(direction), distance * np.sin(direction)], axis=-1)

    def observe(self, config, obs, q, aux, state):
        from snake_env.physics import AUX_X, AUX_Y

        return {"observation": obs, "achieved_goal": aux[:, [AUX_X, AUX_Y]], "desired_goal": state["goal"]}

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        """Reward for goals (..., 2) (m), vectorized over leading axes (the step's reward). ``info``
        (a dict, or an array of the steps' dicts as HER passes them) is read only with
        ``energy_cost_weight``, ``slip_cost_weight`` or ``action_rate_cost_weight`` > 0, for its ``reward_energy``,
        ``reward_slip`` or ``reward_action_rate``."""
        reward = self._goal_reward(achieved_goal, desired_goal)
        if self.energy_cost_weight:
            reward = reward + self.energy_term(info, reward.shape)
        if self.slip_cost_weight:
            reward = reward + self.energy_term(info, reward.shape, "reward_slip")
        if self.action_rate_cost_weight:
            reward = reward + self.energy_term(info, reward.shape, "reward_action_rate")
        return reward

    def _goal_reward(self, achieved_goal, desired_goal):
        d = np.linalg.norm(np.asarray(achieved_goal, np.float64) - np.asarray(desired_goal, np.float64), axis=-1)
        if self.reward_type == "sparse":
            return -(d > self.distance_threshold).astype(np.float64)
        return -d

    def evaluate(self, config, ctx: StepContext, state):
        achieved = ctx.cm
        reward = self._goal_reward(achieved, state["goal"])
        distance = np.linalg.norm(achieved - state["goal"], axis=-1)
        success = distance <= self.distance_threshold
        terminated = success & self.terminate_on_success
        return reward, terminated, {"reward_goal": reward.copy(), "goal_distance": distance, "is_success": success}

    def overlay(self, config, state, row, q):
        goal = state["goal"][row]
        angles = np.linspace(0.0, 2.0 * math.pi, 33)
        circle = goal + self.distance_threshold * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
        # the goal is often outside the view (which follows the snake): an arrow towards it too
        cm = link_centers(config, q).mean(axis=0)
        to_goal = goal - cm
        distance = float(np.hypot(*to_goal))
        tip = cm + to_goal * min(1.0, 0.5 / distance) if distance > 0 else cm
        return [("point", goal), ("polyline", circle), ("arrow", (cm, tip))]
