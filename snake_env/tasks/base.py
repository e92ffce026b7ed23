"""The ``Task`` half of dm_control's Physics/Task split.

A task is a frozen dataclass whose fields are its kwargs (same names in YAML
``env_kwargs``), validated through :func:`snake_env.physics.settings.setting`
metadata. It supplies only what differs between tasks, always for a batch of
B snakes (the single env is a batch of one, so single and vector env share
every line):

- the starting-state noise and the goal / command / path draws at reset,
- observation extras appended to the physics observation (or a Dict),
- the reward terms (into ``info`` as ``reward_*``), termination and task info.

Per-env task state (a goal, a command schedule, a path offset, ...) lives in
a dict of (B, ...) arrays owned by the env, so the vector env equals N single
envs given the same rows. Randomness comes only from the env's generator, at
reset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from numba import njit

from snake_env.controllers import gait_for_links, make_baseline
from snake_env.physics import GRAVITY, PhysicsConfig
from snake_env.physics.bound_kernel import BoundKernel
from snake_env.physics.config import sliding_into
from snake_env.physics.settings import check_fields, setting
from snake_env.physics import AUX_FAILED, AUX_KINETIC, AUX_MOTOR_ENERGY, AUX_VX, AUX_VY, AUX_WORK, AUX_X, AUX_Y

DEFAULT_RESET_NOISE_SCALE = 0.1  # rad for the angles, m/s and rad/s for the speeds
DEFAULT_CTRL_COST_WEIGHT = 1e-4  # per (N m / max_torque)^2, like Swimmer-v5

# info of every task at every step, and at reset
COMMON_STEP_INFO_KEYS = ("x_position", "y_position", "distance_from_origin", "x_velocity", "y_velocity",
                         "kinetic_energy", "power", "actuator_power", "sim_failure")
RESET_INFO_KEYS = ("x_position", "y_position", "distance_from_origin", "kinetic_energy")
# how an episode's values of an info key become one metric (Task.episode_metrics); the reducers are snake-eval's
REDUCTIONS = ("any", "last", "mean", "mean_abs")


def controller_geometry(config: PhysicsConfig) -> dict:
    """What a controller reads of the physics: n_links, max_torque (N m), dt (s) and whether the
    observation starts with the CM position."""
    return dict(n_links=config.n_links, max_torque=config.max_torque, dt=config.dt,
                include_position=not config.exclude_current_positions_from_observation)


@dataclass(slots=True)
class StepContext:
    """What one batched physics step produced (rows = sub-envs).

    action: (B, n-1) clipped actions; torques (N m); q_prev, q: (B, n+2) before /
    after; u: (B, 2); aux: (B, AUX_SIZE) of :mod:`snake_env.physics.stepping`;
    dt: env step (s).
    """

    action: np.ndarray
    torques: np.ndarray
    q_prev: np.ndarray
    q: np.ndarray
    u: np.ndarray
    aux: np.ndarray
    dt: float

    @property
    def cm(self) -> np.ndarray:
        return self.aux[:, [AUX_X, AUX_Y]]


def mean_heading(q: np.ndarray, n_links: int) -> np.ndarray:
    """Mean link angle theta_bar = (1/n) sum theta_k (rad), the snake's heading
    (Liljebäck et al. 2011). The angles are not wrapped, so it is continuous."""
    return np.mean(q[..., :n_links], axis=-1)


def link_centers(config: PhysicsConfig, q: np.ndarray) -> np.ndarray:
    """CMs of the links (n, 2) (m) of one state q: CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1} (eq. 3)."""
    n = config.n_links
    h = 0.5 * np.broadcast_to(np.asarray(config.length, np.float64), (n,))
    e = np.stack([np.cos(q[:n]), np.sin(q[:n])], axis=-1)
    steps = e[:-1] * h[:-1, None] + e[1:] * h[1:, None]
    return q[n:n + 2] + np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])


# rows of the matrix filled by _common_info, in the order of COMMON_STEP_INFO_KEYS
_X, _Y, _DISTANCE, _VX, _VY, _KINETIC, _POWER, _ACTUATOR = range(8)


@njit(cache=True, nogil=True)
def _common_info(aux, dt, out, failed):
    """out (8, B), failed (B,): the common step info of every row (one compiled pass: the single env
    steps at tens of microseconds, where a dozen numpy calls on (1,) arrays would dominate).
    Actuator power: the motors' energy of the step (aux's AUX_MOTOR_ENERGY) / dt (W).
    Returns the number of failed rows."""
    failures = 0
    for b in range(aux.shape[0]):
        x = aux[b, AUX_X]
        y = aux[b, AUX_Y]
        out[_X, b] = x
        out[_Y, b] = y
        out[_DISTANCE, b] = math.hypot(x, y)
        out[_VX, b] = aux[b, AUX_VX]
        out[_VY, b] = aux[b, AUX_VY]
        out[_KINETIC, b] = aux[b, AUX_KINETIC]
        out[_POWER, b] = aux[b, AUX_WORK] / dt
        out[_ACTUATOR, b] = aux[b, AUX_MOTOR_ENERGY] / dt
        failed[b] = aux[b, AUX_FAILED] != 0.0
        failures += failed[b]
    return failures


# the float values of the common step info (every key but sim_failure), rows of common_step_values' matrix
COMMON_VALUE_KEYS = COMMON_STEP_INFO_KEYS[:-1]
ACTUATOR_POWER_ROW = _ACTUATOR


def common_step_values(ctx: StepContext, out: np.ndarray, failed: np.ndarray, wheels: tuple | None = None) -> int:
    """Fill ``out`` (len(COMMON_VALUE_KEYS), B) with the info of every task and ``failed`` (B,) with the
    failed rows; return the number of failed rows. Caller-owned buffers: the vector env hands out copies,
    the single env Python scalars of row 0 (one ``tolist``). ``actuator_power`` (W) = the step's mean of
    sum_k |s A_k phidot_k|: the torque each motor delivers (the command through its torque-speed band and
    current limit, times the traction scale s) times its joint's rate, integrated by the physics step with
    the work's RK4 weights (:data:`snake_env.physics.AUX_MOTOR_ENERGY`). Negative work (a motor braking
    its joint) counts as a cost too, as a motor without regeneration spends it. ``wheels``: (lateral
    forces (B, n) (N), grips (B, n) (N), out (B, n) bool) to flag in the same compiled call each wheel
    that slides (:func:`snake_env.physics.config.sliding`)."""
    if wheels is None:
        return _common_info(ctx.aux, ctx.dt, out, failed)
    return _common_info_and_slip(ctx.aux, ctx.dt, out, failed, *wheels)


def bind_common_step_values(ctx: StepContext, out: np.ndarray, failed: np.ndarray, wheels: tuple | None = None):
    """:func:`common_step_values` on these buffers (the caller's own, updated in place) as a call of no
    arguments, without numba's per-call dispatch (~0.4 us of the single env's step; :class:`BoundKernel`)."""
    if wheels is None:
        bound = BoundKernel(_common_info, ctx.aux, ctx.dt, out, failed)
    else:
        bound = BoundKernel(_common_info_and_slip, ctx.aux, ctx.dt, out, failed, *wheels)
    return lambda: bound.call()  # (bound.call is replaced by its first call)


@njit(cache=True, nogil=True)
def _common_info_and_slip(aux, dt, out, failed, forces, grip, slip):
    """:func:`_common_info` and :func:`~snake_env.physics.config.sliding_into` in one compiled call (each
    call costs the single env's ~15 us step ~0.4 us)."""
    sliding_into(forces, grip, slip)
    return _common_info(aux, dt, out, failed)


def common_reset_info(aux: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "x_position": aux[:, AUX_X].copy(),
        "y_position": aux[:, AUX_Y].copy(),
        "distance_from_origin": np.hypot(aux[:, AUX_X], aux[:, AUX_Y]),
        "kinetic_energy": aux[:, AUX_KINETIC].copy(),
    }


_PAIRWISE_BLOCK = 128  # numpy's PW_BLOCKSIZE
# start index 0 as an int64 value: a literal 0 from a jitted caller compiles its own specialisation
# of squared_sum and _squared_sum_block (Literal[int](0)), beside the int64 one (~1 s cold)
ZERO_INDEX = np.int64(0)


@njit(cache=True, nogil=True)
def squared_sum(a, start, count):
    """sum of a[start:start+count]^2 in numpy's pairwise order (np.sum of a 1-d float64
    array): bit for bit what np.sum(np.square(a)) gives, in compiled code. numpy splits
    blocks longer than 128 in two recursively; that tree is walked with a stack here
    (numba's cache cannot hold a recursive function)."""
    if count <= _PAIRWISE_BLOCK:
        return _squared_sum_block(a, start, count)
    node_start = np.empty(64, np.int64)
    node_count = np.empty(64, np.int64)
    node_stage = np.empty(64, np.int64)
    values = np.empty(64)
    nodes = 1
    node_start[0], node_count[0], node_stage[0] = start, count, 0
    filled = 0
    while nodes:
        top = nodes - 1
        lo, n, stage = node_start[top], node_count[top], node_stage[top]
        half = n // 2
        half -= half % 8
        if n <= _PAIRWISE_BLOCK:
            values[filled] = _squared_sum_block(a, lo, n)
            filled += 1
            nodes -= 1
        elif stage == 0:  # left half first
            node_stage[top] = 1
            node_start[nodes], node_count[nodes], node_stage[nodes] = lo, half, 0
            nodes += 1
        elif stage == 1:
            node_stage[top] = 2
            node_start[nodes], node_count[nodes], node_stage[nodes] = lo + half, n - half, 0
            nodes += 1
        else:  # both halves done: left + right
            values[filled - 2] = values[filled - 2] + values[filled - 1]
            filled -= 1
            nodes -= 1
    return values[0]


@njit(cache=True, nogil=True)
def _squared_sum_block(a, start, count):
    """numpy's pairwise_sum of a block of at most 128 squares: 8 running sums."""
    if count < 8:
        total = -0.0
        for i in range(start, start + count):
            total += a[i] * a[i]
        return total
    r0 = a[start] * a[start]
    r1 = a[start + 1] * a[start + 1]
    r2 = a[start + 2] * a[start + 2]
    r3 = a[start + 3] * a[start + 3]
    r4 = a[start + 4] * a[start + 4]
    r5 = a[start + 5] * a[start + 5]
    r6 = a[start + 6] * a[start + 6]
    r7 = a[start + 7] * a[start + 7]
    i = start + 8
    end = start + count - count % 8
    while i < end:
        r0 += a[i] * a[i]
        r1 += a[i + 1] * a[i + 1]
        r2 += a[i + 2] * a[i + 2]
        r3 += a[i + 3] * a[i + 3]
        r4 += a[i + 4] * a[i + 4]
        r5 += a[i + 5] * a[i + 5]
        r6 += a[i + 6] * a[i + 6]
        r7 += a[i + 7] * a[i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < start + count:
        total += a[i] * a[i]
        i += 1
    return total


@njit(cache=True, nogil=True)
def _squared_norms(a, out):
    for b in range(a.shape[0]):
        out[b] = squared_sum(a[b], ZERO_INDEX, a.shape[1])


def squared_norm(a: np.ndarray) -> np.ndarray:
    """||a||^2 of each row of a (B, m) array (B,); the same compiled reduction for one
    action and for each row of a batch, so the single and the vector env give
    bit-identical control costs (and the same bits as np.sum(np.square(a), axis=-1))."""
    out = np.empty(a.shape[0])
    _squared_norms(a, out)
    return out


def box_with_extras(base: spaces.Box, low, high) -> spaces.Box:
    """``base`` with extra entries of bounds ``low``/``high`` appended."""
    return spaces.Box(low=np.concatenate([base.low, low]), high=np.concatenate([base.high, high]), dtype=np.float64)


@dataclass(frozen=True)
class Task:
    """Base of every task: the start-state noise and the hooks a task overrides.

    Subclasses are frozen dataclasses; their docstring is the env's spec
    (Gymnasium style). Every fact about a task lives on its class:

    - ``name``: the ``task=`` value;
    - registration: ids ``snake_env/<id_prefix>{n}-v<version>`` and
      ``snake_env/<id_prefix>-v<version>`` (:func:`snake_env.registration.register_task`),
      truncated after ``max_episode_steps``; ``goal_env``: a Dict observation with
      ``compute_reward`` (Gymnasium's GoalEnv);
    - ``step_info_keys``: info keys beyond :data:`COMMON_STEP_INFO_KEYS`;
    - ``episode_metrics``: what ``snake-eval`` reports per episode beside the cost of
      transport, ``{metric: (info key, reduction)}`` with a reduction of :data:`REDUCTIONS`;
    - the baseline controller (``snake-eval --baseline <baseline_name>``, the residual
      wrappers): :meth:`make_baseline`, by default ``baseline_controller`` (a
      :class:`~snake_env.controllers.SteeredSerpenoid`) steering the searched gait of this n.
    """

    reset_noise_scale: float = setting(DEFAULT_RESET_NOISE_SCALE, "rad, m/s, rad/s", minimum=0.0, strict=False,
                                       doc="half-width of the uniform start noise")
    energy_cost_weight: float = setting(0.0, "per W", minimum=0.0, strict=False,
                                        doc="weight of the actuator power in the reward (a cost; 0: none)")
    slip_cost_weight: float = setting(0.0, "per m g of excess", minimum=0.0, strict=False,
                                      doc="weight of the wheels' lateral force beyond their grip in the reward "
                                          "(sum over wheels of max(0, |lambda_k| - mu m_k g) / (m_k g); a cost; "
                                          "0: none; needs wheel_friction)")
    action_rate_cost_weight: float = setting(0.0, "per (action change)^2", minimum=0.0, strict=False,
                                             doc="weight of the squared change of the action since the last "
                                                 "step, sum_k (a_k - a_k,prev)^2 with a in [-1, 1] and a_prev = 0 "
                                                 "after a reset, in the reward (a cost; 0: none): the action-rate "
                                                 "penalty of legged-robot RL (Rudin et al. 2022), against torque "
                                                 "chatter at the control rate")
    slip_margin: float = setting(1.0, "fraction of mu m g", minimum=0.0, maximum=1.0,
                                 doc="the slip cost counts lateral force beyond this fraction of the grip, "
                                     "max(0, |lambda_k| - margin mu m_k g): below 1 it also charges wheels the "
                                     "traction limit holds near their grip, where a real wheel slides; on sliding "
                                     "wheels only a margin below 1 charges anything")

    name: ClassVar[str] = ""
    id_prefix: ClassVar[str] = ""
    version: ClassVar[int] = 0
    max_episode_steps: ClassVar[int] = 1000
    goal_env: ClassVar[bool] = False
    step_info_keys: ClassVar[tuple[str, ...]] = ()
    episode_metrics: ClassVar[dict[str, tuple[str, str]]] = {}
    baseline_name: ClassVar[str | None] = None
    baseline_controller: ClassVar[type | None] = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        for metric, (key, reduction) in cls.episode_metrics.items():
            if reduction not in REDUCTIONS:
                raise TypeError(f"{cls.__name__}.episode_metrics[{metric!r}]: reduction must be one of "
                                f"{list(REDUCTIONS)}, got {reduction!r}")
            if key not in cls.step_info_keys:
                raise TypeError(f"{cls.__name__}.episode_metrics[{metric!r}] reads info key {key!r}, which is not "
                                f"in its step_info_keys {list(cls.step_info_keys)}")

    def __post_init__(self):
        check_fields(self)

    @classmethod
    def make_baseline(cls, config: PhysicsConfig, num_envs: int = 1, gait: str | None = None, gaits=None,
                      settings=None):
        """This task's baseline controller for ``num_envs`` snakes of ``config``: ``baseline_controller``
        steering the searched gait of ``snake_env/Snake{n}-v*`` (newest version) in the gait file
        ``gaits``, with the steering settings of ``settings`` for this n (both resolved by
        :func:`snake_env.configfiles.config_path`). ``gait`` (an env id) is the forward task's."""
        if cls.baseline_controller is None:
            raise ValueError(f"the {cls.name!r} task has no baseline controller")
        if gait is not None:
            raise ValueError(f"gait applies to the forward task; the {cls.name} baseline steers the gait of "
                             f"snake_env/Snake{config.n_links}-v*, got gait={gait!r}")
        params, speed = gait_for_links(config.n_links, gaits, config.versions_back)
        if speed is None:
            raise ValueError(f"the serpenoid gait for n_links={config.n_links} has no search.mean_forward_velocity")
        return make_baseline(cls.baseline_controller, cls.name, params, speed, num_envs=num_envs,
                             settings_path=settings, **controller_geometry(config))

    # ------------------------------------------------------------------ spaces
    def observation_space(self, config: PhysicsConfig, base: spaces.Box) -> spaces.Space:
        """The single env's observation space given the physics part ``base``."""
        return base

    # ------------------------------------------------------------------ batched hooks
    def init_state(self, num_envs: int) -> dict[str, np.ndarray]:
        """Per-env task state arrays (B, ...), filled at reset."""
        return {}

    def reset_noise(self, rng: np.random.Generator, count: int, n_links: int) -> np.ndarray:
        """Uniform start noise (count, n+2): link angles (rad), V_1 (m/s), thetadot_1 (rad/s)."""
        s = self.reset_noise_scale
        return rng.uniform(low=-s, high=s, size=(count, n_links + 2))

    def reset(self, config: PhysicsConfig, state: dict, rows: np.ndarray, rng: np.random.Generator,
              q: np.ndarray, aux: np.ndarray) -> None:
        """Draw the task's per-env state for ``rows`` (after the start state q, aux of those rows)."""

    def observe(self, config: PhysicsConfig, obs: np.ndarray, q: np.ndarray, aux: np.ndarray, state: dict) -> Any:
        """Observation of every row from the physics observation ``obs`` (B, d)."""
        return obs

    def evaluate(self, config: PhysicsConfig, ctx: StepContext, state: dict
                 ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """(reward (B,), terminated (B,), task info) of a step; may update ``state``. The info is a new dict
        of new arrays on every call: the caller adds its costs to it and hands it out."""
        raise NotImplementedError

    def overlay(self, config: PhysicsConfig, state: dict, row: int, q: np.ndarray) -> list | None:
        """What to draw for sub-env ``row`` in state ``q``: a list of (kind, data) in world
        coordinates (m), kinds "polyline", "point", "arrow" (see :mod:`snake_env.envs.rendering`)."""
        return None

    # ------------------------------------------------------------------ helpers
    def energy_term(self, info, shape, key: str = "reward_energy") -> np.ndarray:
        """The power cost (reward units, <= 0) of the steps behind ``info``: its ``reward_energy`` (or
        another cost ``key``, e.g. ``reward_slip``), from one info dict or an array of them (HER's
        relabelling passes the stored infos)."""
        if info is None:
            raise ValueError(f"compute_reward needs the steps' info (its {key}) when a cost weight is > 0")
        if isinstance(info, dict):
            return np.broadcast_to(np.asarray(info[key], np.float64), shape)
        return np.array([item[key] for item in np.ravel(info)], np.float64).reshape(shape)

    @staticmethod
    def total_mass(config: PhysicsConfig) -> float:
        return float(np.sum(np.broadcast_to(np.asarray(config.mass, dtype=np.float64), (config.n_links,))))

    @classmethod
    def weight(cls, config: PhysicsConfig) -> float:
        """m_total g (N), the cost of transport's normalizer."""
        return cls.total_mass(config) * GRAVITY
