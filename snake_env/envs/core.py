"""``SnakeBatch``: B snakes, their task, and the one place both envs step physics.

The single env is a batch of one and the vector env a batch of B; both hold a
:class:`SnakeBatch` and only add the Gymnasium API around it (scalars and a
TimeLimit wrapper for the one, autoreset and batched info for the other).
The batched physics call is the batch physics of :mod:`snake_env.physics.batch` (one
:func:`snake_env.physics.step_inplace` call unless the motors respond in time or the robots are
randomized), here and nowhere else; a row's result does not depend on the batch it is in, so a
vector env equals N single envs step by step.
"""

from __future__ import annotations

import copy
import math
from dataclasses import fields, replace

import numpy as np
from gymnasium import spaces
from numba import njit

from snake_env.tasks import Task, task_class
from snake_env.tasks.base import (ACTUATOR_POWER_ROW, COMMON_STEP_INFO_KEYS, COMMON_VALUE_KEYS, StepContext,
                                  bind_common_step_values, common_reset_info, common_step_values)

from snake_env import physics
from snake_env.dynamics import sliding_step
from snake_env.physics import AUX_FAILED, PhysicsConfig
from snake_env.physics.batch import batch_physics
from snake_env.physics.settings import number, split_kwargs

ENERGY_KEY = "reward_energy"  # info key of the optional power cost (Task.energy_cost_weight)
SLIP_KEY = "reward_slip"  # info key of the optional cost of the wheels' excess over their grip (Task.slip_cost_weight)
ACTION_RATE_KEY = "reward_action_rate"  # info key of the optional cost of the action's change (Task.action_rate_cost_weight)
# info of every step when the wheels' grip is modelled (wheel_friction given): per sub-env the wheels'
# lateral forces (n,) (N, eq. 27's multipliers, from the step's final state and held torques under the
# traction limit), whether each exceeds its grip mu m_k g (n,) (the motion alone asks more: the wheel
# slides) and the traction scale (the share of the motors' torques the wheels let through, 1 = all).
# Without grip the sweep is not paid for (it costs ~0.35 us per snake per step, a 1.1-1.4x slower
# 1024-env vector env); SnakeEnv.wheel_lateral_forces() computes the forces.
WHEEL_INFO_KEYS = ("wheel_lateral_force", "wheel_slip", "traction_scale")
RANDOMIZED_PREFIX = "randomized_"  # reset info of a randomized env: each row's drawn robot (physics.randomization)


def make_task_and_config(task, kwargs: dict) -> tuple[Task, PhysicsConfig]:
    """Split env kwargs into the task's and the physics' (one-line error on an unknown name)."""
    cls = task_class(task)
    physics_kwargs, task_kwargs = split_kwargs(kwargs, PhysicsConfig, cls)
    return cls(**task_kwargs), PhysicsConfig(**physics_kwargs)


def env_config(env_id: str, env_kwargs: dict | None = None) -> tuple[Task, PhysicsConfig]:
    """The task and physics config a registered id builds with ``env_kwargs``, without building the env
    (an unknown id or argument is a one-line ValueError)."""
    import gymnasium as gym

    try:
        spec = gym.spec(env_id)
    except gym.error.Error as exc:
        raise ValueError(f"unknown env id {env_id!r}: {str(exc).splitlines()[0]}") from None
    kwargs = {**spec.kwargs, **dict(env_kwargs or {})}
    kwargs.pop("render_mode", None)
    return make_task_and_config(kwargs.pop("task", "forward"), kwargs)


def observation_structure(n_links: int, include_position: bool) -> dict[str, int]:
    """Sizes of the physics observation's blocks, in order (``skipped_*`` are not in the vector)."""
    return {
        "skipped_position": 0 if include_position else 2,
        "position": 2 if include_position else 0,
        "joint_angles": n_links - 1,
        "heading": 2,
        "generalized_speeds": 2,
        "joint_rates": n_links - 1,
    }


def physics_observation_space(n_links: int, include_position: bool) -> spaces.Box:
    size = physics.observation_size(n_links, include_position)
    low = np.full(size, -np.inf)
    high = np.full(size, np.inf)
    start = (2 if include_position else 0) + n_links - 1
    low[start:start + 2] = -1.0  # cos, sin of the heading
    high[start:start + 2] = 1.0
    return spaces.Box(low=low, high=high, dtype=np.float64)


NOT_FINITE_ACTION = "action must be finite (no NaN or inf); values outside [-1, 1] are clipped"


def action_array(action, shape: tuple) -> np.ndarray:
    """Actions as a float64 copy of ``shape``, not yet clipped (the step's compiled call clips them);
    not real or a wrong shape -> ValueError."""
    try:
        a = np.array(action, dtype=np.float64)  # a copy: clipped in place
    except (TypeError, ValueError):
        raise ValueError(f"action must be a real array of shape {shape} in [-1, 1], got {action!r}") from None
    if a.shape != shape:
        raise ValueError(f"action must have shape {shape} (one value in [-1, 1] per joint), got {a.shape}")
    return a


@njit(cache=True, nogil=True)
def _clip_scale_and_save(actions, max_torque, torques, q, q_prev):
    """False (nothing written) if an action is NaN or inf; else clip ``actions`` (B, n-1) to [-1, 1] in
    place, torques = max_torque * actions (N m), q_prev = q: True. One compiled call where the single
    env's step would otherwise pay for several (it takes ~15 us)."""
    for b in range(actions.shape[0]):
        for k in range(actions.shape[1]):
            if not math.isfinite(actions[b, k]):
                return False
    for b in range(q.shape[0]):
        for k in range(torques.shape[1]):
            value = min(max(actions[b, k], -1.0), 1.0)
            actions[b, k] = value
            torques[b, k] = value * max_torque
        for i in range(q.shape[1]):
            q_prev[b, i] = q[b, i]
    return True


def first_row(values: dict[str, np.ndarray]) -> dict:
    """Row 0 of batched values: Python floats and bools for (B,) arrays, (n,) arrays for (B, n) ones."""
    return {key: (value.item() if value.ndim == 1 else value[0]) for key, value in values.items()}


class SnakeBatch:
    """State (B rows) of snakes doing one task, stepped by one compiled call."""

    def __init__(self, task: Task, config: PhysicsConfig, num_envs: int):
        sliding = config.wheel_model == "sliding"
        # never a silent first-run wait: the notice if the first step's kernel is not cached yet
        physics.stepping.announce_compile(sliding_step.advance_rows if sliding else None)
        if not sliding:  # the no-slip kernels only some steps need, in a second process beside this one's compile
            # (the sliding physics starts its own: physics.sliding_wheels)
            physics.stepping.compile_in_background(unlimited_grip=config.wheel_friction is None)
        self.task = task
        self.config = config
        self.model, self.params = config.build()
        n, B = config.n_links, num_envs
        self.num_envs = B
        self.physics_observation_space = physics_observation_space(n, self.params.include_position)
        self.single_observation_space = task.observation_space(config, self.physics_observation_space)
        energy = (((ENERGY_KEY,) if task.energy_cost_weight else ()) + ((SLIP_KEY,) if task.slip_cost_weight else ())
                  + ((ACTION_RATE_KEY,) if task.action_rate_cost_weight else ()))
        if task.slip_cost_weight and config.wheel_friction is None:
            raise ValueError("slip_cost_weight needs wheel_friction (a mu): with unlimited grip no wheel slips")
        # the slip cost's info key is fixed at construction; set_slip_cost_weight may change its weight (even to 0)
        self.slip_cost = bool(task.slip_cost_weight)
        self.report_grip = config.wheel_friction is not None
        self.step_info_keys = (COMMON_STEP_INFO_KEYS + WHEEL_INFO_KEYS * self.report_grip + task.step_info_keys
                               + energy)
        self.wheel_force = np.zeros((B, n))
        self.traction_scale = np.ones(B)
        self.q = np.zeros((B, n + 2))
        self.u = np.zeros((B, 2))
        self.torques = np.zeros((B, n - 1))
        # the last step's clipped actions, for the action-rate cost (0 after a reset); None without the cost
        self.previous_action = np.zeros((B, n - 1)) if task.action_rate_cost_weight else None
        # one compiled call, a motor response in time, or a robot per row (randomize): physics.batch
        self.physics = batch_physics(config, self.params, B)  # (the sliding physics may start its compile there)
        # the first step's task kernels compile before its physics while that process is at work (_warm_up)
        self._warm_up_pending = physics.stepping.background_compile_running()
        self.grip, self.wheel_load = self.physics.grip, self.physics.wheel_load
        # the grips (N) of every row for the compiled slip test: a randomized batch's own (B, n) array, which
        # its resets redraw in place, or one robot's (n,) copied to every row
        self.row_grip = self.grip if self.grip.ndim == 2 else np.tile(self.grip, (B, 1))
        # a physics whose wheels really slide says which do (reports_slip); else a wheel slips whose force exceeds
        # its grip, compared in the common values' compiled call
        own_slip = getattr(self.physics, "reports_slip", False)
        self.slip = self.physics.slip if own_slip else np.zeros((B, n), np.bool_)
        # the wheel forces at the step's end come from the step's own sweep
        self._grip_buffers = (self.wheel_force, self.traction_scale) if self.report_grip else (None, None)
        self._wheels = (self.wheel_force, self.row_grip, self.slip) if self.report_grip and not own_slip else None
        self.physics_obs = np.zeros((B, self.params.obs_size))
        self.aux = np.zeros((B, physics.AUX_SIZE))
        self.q_prev = np.zeros((B, n + 2))
        self.task_state = task.init_state(B)
        # a task without an observe() of its own (forward) observes the physics observation as it is
        self._observes_physics = type(task).observe is Task.observe
        # the last step's common info, filled in place by one compiled pass: float values (rows
        # COMMON_VALUE_KEYS) and failed rows; step() hands out copies, step_first() Python scalars
        self.common_values = np.empty((len(COMMON_VALUE_KEYS), B))
        self.failed = np.zeros(B, np.bool_)
        self._context = StepContext(action=self.torques, torques=self.torques, q_prev=self.q_prev, q=self.q,
                                    u=self.u, aux=self.aux, dt=config.dt)
        self._bind()

    # made by _bind, again for a copy (a pickled or deep-copied view is an array of its own)
    _BOUND = ("_first_values", "_first_force", "_first_slip", "_step_physics", "_common_step_values")

    def _bind(self) -> None:
        """Row 0's views, read by step_first, and the physics step and the common values on this batch's
        buffers, bound once (no per-call dispatch); again on unpickling and copying, whose copies have
        buffers of their own."""
        self._first_values = self.common_values[:, 0]
        self._first_force, self._first_slip = self.wheel_force[0], self.slip[0]
        self._step_physics = self.physics.bind_step(self.q, self.u, self.torques, self.physics_obs, self.aux,
                                                    *self._grip_buffers)
        self._common_step_values = bind_common_step_values(self._context, self.common_values, self.failed,
                                                           self._wheels)

    def __getstate__(self):
        return {key: value for key, value in self.__dict__.items() if key not in self._BOUND}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._bind()

    def observation(self):
        """The task's observation of every row (fresh arrays)."""
        obs = self.task.observe(self.config, self.physics_obs, self.q, self.aux, self.task_state)
        if isinstance(obs, dict):
            return {key: value.copy() for key, value in obs.items()}
        return obs.copy()

    def observation_first(self):
        """:meth:`observation` of row 0 (the single env's): an array, or a dict of arrays for goal tasks."""
        if self._observes_physics:
            return self.physics_obs[0].copy()
        obs = self.task.observe(self.config, self.physics_obs, self.q, self.aux, self.task_state)
        if isinstance(obs, dict):
            return {key: value[0].copy() for key, value in obs.items()}
        return obs[0].copy()

    def reset(self, mask: np.ndarray, rng: np.random.Generator) -> None:
        """New episodes for the rows of ``mask``: start noise first, then (randomized) the robots, then the
        task's draws."""
        rows = np.flatnonzero(mask)
        noise = self.task.reset_noise(rng, rows.size, self.config.n_links)
        q, u, obs, aux = self.physics.reset(rows, noise, rng)  # a randomized batch draws its robots here
        self.q[rows], self.u[rows], self.physics_obs[rows], self.aux[rows] = q, u, obs, aux
        self.task.reset(self.config, self.task_state, rows, rng, q, aux)
        if self.previous_action is not None:
            self.previous_action[rows] = 0.0

    def set_state(self, q, u) -> None:
        if hasattr(self.physics, "set_state"):  # a physics with a state of its own beyond (q, u)
            self.physics.set_state(q, u)
        obs, aux = self.physics.observe(np.asarray(q, np.float64), np.asarray(u, np.float64))
        self.q[:], self.u[:] = q, u
        self.physics_obs[:], self.aux[:] = obs.reshape(self.physics_obs.shape), aux.reshape(self.aux.shape)

    def reset_info(self) -> dict[str, np.ndarray]:
        info = common_reset_info(self.aux)
        # a randomized batch: each row's drawn robot (physical units)
        info.update({RANDOMIZED_PREFIX + name: value.copy() for name, value in self.physics.draws.items()})
        return info

    def step(self, actions, checked: bool = False) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Advance every row; return (rewards (B,), terminated (B,), info of arrays (B,) or (B, n)).
        ``checked``: the actions are already a float64 copy of the right shape (:func:`action_array`), which
        the step clips in place."""
        rewards, terminated, extras = self._advance(actions, checked)
        info = dict(zip(COMMON_VALUE_KEYS, self.common_values.copy()))
        info["sim_failure"] = self.failed.copy()
        if self.report_grip:
            info["wheel_lateral_force"] = self.wheel_force.copy()
            info["wheel_slip"] = self.slip.copy()
            info["traction_scale"] = self.traction_scale.copy()
        info.update(extras)
        return rewards, terminated, info

    def step_first(self, action: np.ndarray) -> tuple[float, bool, dict]:
        """:meth:`step` of a batch of one with an action made by :func:`action_array`: (reward,
        terminated, info) of row 0 as the single env gives them, Python floats and bools and (n,) arrays.
        The same values as :meth:`step`'s row 0, without its arrays of one element (the single env steps
        in tens of microseconds, where each of those costs a few hundred nanoseconds)."""
        rewards, terminated, extras = self._advance(action[None], True)
        info = dict(zip(COMMON_VALUE_KEYS, self._first_values.tolist()))
        info["sim_failure"] = self.failed.item()
        if self.report_grip:
            info["wheel_lateral_force"] = self._first_force.copy()
            info["wheel_slip"] = self._first_slip.copy()
            info["traction_scale"] = self.traction_scale.item()
        for key, value in extras.items():  # first_row's rule, without its call
            info[key] = value.item() if value.ndim == 1 else value[0]
        return rewards.item(), terminated.item(), info

    def _advance(self, actions, checked: bool) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Step the physics of every row and evaluate its task: (rewards, terminated, the info of the task
        and the costs); the common values are left in ``common_values`` and ``failed``, the wheels' (with
        grip) in ``wheel_force``, ``slip`` and ``traction_scale``."""
        a = actions if checked else action_array(actions, self.torques.shape)
        if self._warm_up_pending:
            self._warm_up()
        if not _clip_scale_and_save(a, self.config.max_torque, self.torques, self.q, self.q_prev):
            raise ValueError(NOT_FINITE_ACTION)
        self._step_physics()
        ctx = self._context
        ctx.action = a  # every other field is one of this batch's buffers
        rewards, terminated, task_info = self.task.evaluate(self.config, ctx, self.task_state)
        failures = self._common_step_values()
        extras = task_info
        if self.task.energy_cost_weight:
            # every task: a cost on the actuator power (W; common_step_values), off by default
            extras[ENERGY_KEY] = -self.task.energy_cost_weight * self.common_values[ACTUATOR_POWER_ROW]
            rewards = rewards + extras[ENERGY_KEY]
        if self.slip_cost:
            # every task: a cost on the wheels' lateral force beyond their grip, in link weights (the motion's
            # own excess: the traction limit already keeps the motors' torques from adding any)
            # (a wheel the traction limit holds at its grip is above it by rounding: < 1e-15 link weights)
            # slip_margin < 1 charges force beyond that share of the grip too (1 * grip is grip exactly)
            excess = np.maximum(np.abs(self.wheel_force) - self.task.slip_margin * self.grip, 0.0) / self.wheel_load
            extras[SLIP_KEY] = -self.task.slip_cost_weight * excess.sum(axis=1)
            rewards = rewards + extras[SLIP_KEY]
        if self.previous_action is not None:
            # every task: a cost on the change of the (clipped) action since the last step, as legged-robot RL
            # charges its action rate (Rudin et al. 2022): torque that chatters at the control rate costs
            change = a - self.previous_action
            extras[ACTION_RATE_KEY] = -self.task.action_rate_cost_weight * np.einsum("bk,bk->b", change, change)
            rewards = rewards + extras[ACTION_RATE_KEY]
            self.previous_action[:] = a
        if failures:
            failed = self.failed
            # A failed step was undone (the pre-step state is kept): it is not an outcome of
            # the action, so every task's reward and reward terms are exactly 0 and it never
            # terminates (the env truncates instead).
            rewards = np.where(failed, 0.0, rewards)
            terminated = terminated & ~failed
            for key in extras:
                if key.startswith("reward_"):
                    extras[key] = np.where(failed, 0.0, extras[key])
        return rewards, terminated, extras

    def _warm_up(self) -> None:
        """Evaluate the task and the common values once on a copy of the current (reset) state, results
        discarded, so that their kernels compile before the first step's physics. The first step of a
        process may wait for the background compile of the refinement kernel (physics.stepping); without
        this the task's ~1.5 s compile would follow that wait, and with it the two compiles overlap."""
        self._warm_up_pending = False
        copies = {field.name: np.array(getattr(self._context, field.name)) for field in fields(self._context)
                  if isinstance(getattr(self._context, field.name), np.ndarray)}
        context = replace(self._context, **copies)
        self.task.evaluate(self.config, context, copy.deepcopy(self.task_state))
        wheels = None if self._wheels is None else tuple(np.array(a) for a in self._wheels)
        common_step_values(context, np.empty_like(self.common_values), np.zeros_like(self.failed), wheels)

    def set_slip_cost_weight(self, weight: float) -> Task:
        """Make the slip cost's weight ``weight`` (per m g of excess, >= 0) from the next step on: the task
        (frozen) is replaced by a copy with that weight, which is returned. Only a batch made with
        ``slip_cost_weight`` > 0 can (its info key ``reward_slip`` is fixed at construction)."""
        if not self.slip_cost:
            raise ValueError("set_slip_cost_weight needs an env made with slip_cost_weight > 0 (its info key "
                             f"{SLIP_KEY} is fixed at construction), got slip_cost_weight=0")
        if isinstance(weight, bool) or not isinstance(weight, (int, float, np.floating, np.integer)):
            raise ValueError(f"slip_cost_weight must be a finite number >= 0, got {weight!r}")
        self.task = replace(self.task, slip_cost_weight=float(weight))  # the task's own check of the value
        return self.task

    def wheel_lateral_forces(self) -> np.ndarray:
        """The wheels' lateral forces (B, n) (N) of the current states under the torques held last."""
        self.physics.wheel_lateral_forces(self.q, self.u, self.torques, self.wheel_force, self.traction_scale)
        return self.wheel_force.copy()

    def failure_reasons(self, rows: np.ndarray) -> list[str]:
        """The distinct reasons (:data:`physics.FAILURE_REASONS`) of the failed ``rows`` of the last step."""
        return sorted({physics.FAILURE_REASONS[int(code)] for code in self.aux[rows, AUX_FAILED]})

    def env_attributes(self) -> dict:
        """The settings exposed as env attributes (same names as the kwargs)."""
        values = {f.name: getattr(self.config, f.name) for f in fields(self.config)}
        values["sim_dt"] = float(values["sim_dt"])  # a plain float (the default's marker type is the config's)
        values.update({f.name: getattr(self.task, f.name) for f in fields(self.task)})
        values.update(model=self.model, params=self.params, task=self.task, config=self.config)
        return values


class TaskEnvBase:
    """What the single and the vector env share: construction from ``task`` and kwargs
    (physics config, task, rendering settings), attributes named as the kwargs, ``dt``."""

    def _build(self, task, num_envs: int, render_mode, width, height, kwargs: dict) -> None:
        task_obj, config = make_task_and_config(task, kwargs)
        self._batch = SnakeBatch(task_obj, config, num_envs)
        for name, value in self._batch.env_attributes().items():
            setattr(self, name, value)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        self.render_mode = render_mode
        self.width = number("width", width, "pixels", minimum=0, integer=True)
        self.height = number("height", height, "pixels", minimum=0, integer=True)
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt))}
        self.step_info_keys = self._batch.step_info_keys
        self.observation_structure = observation_structure(config.n_links, self.params.include_position)
        self._renderer = None
        self._has_reset = False

    @property
    def dt(self) -> float:
        """Duration of one env step (s)."""
        return self.params.dt

    @property
    def task_state(self) -> dict[str, np.ndarray]:
        """The task's per-episode state (goal, command, path offset, ...) as arrays of B rows
        (one row for the single env)."""
        return self._batch.task_state

    @property
    def wheel_grip(self) -> np.ndarray | None:
        """Each wheel's grip mu m_k g (N), one row per sub-env (B, n), None without ``wheel_friction``. A
        randomized env's rows change at their resets (the array is updated in place)."""
        return self._batch.row_grip if self._batch.report_grip else None

    def set_slip_cost_weight(self, weight: float) -> None:
        """Change the slip cost's weight (per m g of excess, >= 0) of every sub-env from the next step on,
        e.g. a curriculum during training (:class:`snake_env.train.callbacks.SlipCostSchedule`). The env
        must be made with ``slip_cost_weight`` > 0: its info key ``reward_slip`` (kept, 0 at weight 0) is
        fixed at construction."""
        self.task = self._batch.set_slip_cost_weight(weight)
        self.slip_cost_weight = self.task.slip_cost_weight

    def _overlay(self, row: int):
        """The task's drawing for sub-env ``row`` (see :meth:`Task.overlay`)."""
        return self.task.overlay(self.config, self._batch.task_state, row, self._batch.q[row])
