"""``SnakeEnv``: the n-link wheeled snake as a Gymnasium environment."""

from __future__ import annotations

import math
import numbers
import warnings
from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from snake_env.dynamics import SnakeModel
from snake_env.dynamics.validation import check_n_links

from . import physics
from .physics import AUX_FAILED, AUX_KINETIC, AUX_VX, AUX_VY, AUX_WORK, AUX_X, AUX_Y, PhysicsParams

# Defaults (units in the names' docs). One env step = SIM_DT * FRAME_SKIP = 0.04 s, like Swimmer-v5.
DEFAULT_SIM_DT = 0.01  # s, one RK4 step
DEFAULT_FRAME_SKIP = 4  # RK4 steps per env step
DEFAULT_MAX_TORQUE = 1.0  # N m, the paper's Table III torque amplitude
DEFAULT_JOINT_DAMPING = 0.01  # N m s/rad, viscous joint friction
DEFAULT_WHEEL_DAMPING = 0.1  # N s/m per wheel, rolling resistance
DEFAULT_JOINT_LIMIT = math.pi / 2  # rad, soft limit on |phi_k|
DEFAULT_LIMIT_STIFFNESS = 20.0  # N m/rad, spring beyond the limit
DEFAULT_LIMIT_DAMPING = 0.2  # N m s/rad, damper beyond the limit
# With the joint's effective inertia I_eff ~ 0.015 kg m^2 (n = 5, paper links) the limit
# rings at sqrt(k / I_eff) ~ 36 rad/s (omega dt = 0.36 per RK4 step) with damping ratio
# ~0.2. A larger damper switches on a larger force jump c * phidot at the limit, which
# RK4 resolves poorly at sim_dt = 0.01 s (measured energy-balance error grows ~15x at c = 1).
DEFAULT_CTRL_COST_WEIGHT = 1e-4  # per (N m / max_torque)^2, like Swimmer-v5
DEFAULT_RESET_NOISE_SCALE = 0.1  # rad for the angles, m/s and rad/s for the speeds
TRAIL_LENGTH = 250  # env steps of CM trail kept for rendering (10 s)

STEP_INFO_KEYS = ("x_position", "y_position", "distance_from_origin", "x_velocity", "y_velocity",
                  "reward_forward", "reward_ctrl", "kinetic_energy", "power", "sim_failure")
RESET_INFO_KEYS = ("x_position", "y_position", "distance_from_origin", "kinetic_energy")


def _number(name, value, unit, *, minimum=None, strict=True, integer=False):
    """A finite real scalar (int when ``integer``) within bounds, else ValueError naming ``name``."""
    kind = numbers.Integral if integer else numbers.Real
    bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum}"
    what = f"{'an integer' if integer else 'a finite number'}{bound} ({unit})"
    if isinstance(value, bool) or not isinstance(value, kind) or not math.isfinite(value):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return int(value) if integer else float(value)


def _flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def build_physics(n_links, sim_dt, frame_skip, mass, length, inertia, joint_damping, wheel_damping,
                  joint_limit, joint_limit_stiffness, joint_limit_damping, paper_model,
                  exclude_current_positions_from_observation):
    """Validate the physical kwargs shared by :class:`SnakeEnv` and the vector env;
    return (SnakeModel, PhysicsParams, effective settings dict)."""
    n_links = check_n_links(n_links)
    sim_dt = _number("sim_dt", sim_dt, "s", minimum=0.0)
    frame_skip = _number("frame_skip", frame_skip, "RK4 steps per env step", minimum=0, integer=True)
    paper_model = _flag("paper_model", paper_model)
    exclude = _flag("exclude_current_positions_from_observation", exclude_current_positions_from_observation)
    joint_damping = _number("joint_damping", joint_damping, "N m s/rad", minimum=0.0, strict=False)
    wheel_damping = _number("wheel_damping", wheel_damping, "N s/m", minimum=0.0, strict=False)
    if joint_limit is not None:
        joint_limit = _number("joint_limit", joint_limit, "rad, or None to disable", minimum=0.0)
        if joint_limit > math.pi:
            raise ValueError(f"joint_limit must be in (0, pi] rad or None, got {joint_limit!r}")
    joint_limit_stiffness = _number("joint_limit_stiffness", joint_limit_stiffness, "N m/rad", minimum=0.0, strict=False)
    joint_limit_damping = _number("joint_limit_damping", joint_limit_damping, "N m s/rad", minimum=0.0, strict=False)
    if paper_model:
        # The paper's model (section II): no dissipation, no joint limits. Only the
        # defaults may be overridden silently; anything else contradicts the flag.
        conflicts = [name for name, value, default in (
            ("joint_damping", joint_damping, DEFAULT_JOINT_DAMPING),
            ("wheel_damping", wheel_damping, DEFAULT_WHEEL_DAMPING),
        ) if value not in (default, 0.0)]
        if joint_limit not in (None, DEFAULT_JOINT_LIMIT):
            conflicts.append("joint_limit")
        if conflicts:
            raise ValueError(f"paper_model=True fixes joint_damping=0, wheel_damping=0 and joint_limit=None; "
                             f"do not also pass {', '.join(conflicts)}")
        joint_damping, wheel_damping, joint_limit = 0.0, 0.0, None
    model = SnakeModel(n_links=n_links, mass=mass, length=length, inertia=inertia,
                       joint_damping=joint_damping, wheel_damping=wheel_damping)
    m, h, inertia_arr, c_joint, c_wheel = model.parameters(np.float64)
    params = PhysicsParams(
        mass=m, half_length=h, inertia=inertia_arr, joint_damping=c_joint, wheel_damping=c_wheel,
        joint_limit=0.0 if joint_limit is None else joint_limit,  # the kernel reads <= 0 as "no limit"
        limit_stiffness=joint_limit_stiffness, limit_damping=joint_limit_damping,
        sim_dt=sim_dt, frame_skip=frame_skip, include_position=not exclude)
    settings = dict(n_links=n_links, sim_dt=sim_dt, frame_skip=frame_skip, joint_damping=joint_damping,
                    wheel_damping=wheel_damping, joint_limit=joint_limit, paper_model=paper_model,
                    exclude_current_positions_from_observation=exclude)
    return model, params, settings


def configure(env, *, n_links, frame_skip, sim_dt, max_torque, forward_reward_weight, ctrl_cost_weight,
              reset_noise_scale, exclude_current_positions_from_observation, joint_damping, wheel_damping,
              joint_limit, joint_limit_stiffness, joint_limit_damping, paper_model, mass, length, inertia,
              render_mode, width, height):
    """Validate the constructor kwargs shared by :class:`SnakeEnv` and the vector
    env and set them as attributes of ``env`` (same names as the kwargs)."""
    env.model, env.params, settings = build_physics(
        n_links, sim_dt, frame_skip, mass, length, inertia, joint_damping, wheel_damping, joint_limit,
        joint_limit_stiffness, joint_limit_damping, paper_model, exclude_current_positions_from_observation)
    for name, value in settings.items():
        setattr(env, name, value)
    env.max_torque = _number("max_torque", max_torque, "N m", minimum=0.0)
    env.forward_reward_weight = _number("forward_reward_weight", forward_reward_weight, "per m/s")
    env.ctrl_cost_weight = _number("ctrl_cost_weight", ctrl_cost_weight, "per unit action^2", minimum=0.0, strict=False)
    env.reset_noise_scale = _number("reset_noise_scale", reset_noise_scale, "rad, m/s, rad/s", minimum=0.0, strict=False)
    if render_mode is not None and render_mode not in env.metadata["render_modes"]:
        raise ValueError(f"render_mode must be one of {env.metadata['render_modes']} or None, got {render_mode!r}")
    env.render_mode = render_mode
    env.width = _number("width", width, "pixels", minimum=0, integer=True)
    env.height = _number("height", height, "pixels", minimum=0, integer=True)


def observation_structure(n_links: int, include_position: bool) -> dict[str, int]:
    """Sizes of the observation's blocks, in order (``skipped_*`` are not in the vector)."""
    return {
        "skipped_position": 0 if include_position else 2,
        "position": 2 if include_position else 0,
        "joint_angles": n_links - 1,
        "heading": 2,
        "generalized_speeds": 2,
        "joint_rates": n_links - 1,
    }


def observation_space(n_links: int, include_position: bool) -> spaces.Box:
    size = physics.observation_size(n_links, include_position)
    low = np.full(size, -np.inf)
    high = np.full(size, np.inf)
    start = (2 if include_position else 0) + n_links - 1
    low[start:start + 2] = -1.0  # cos, sin of the heading
    high[start:start + 2] = 1.0
    return spaces.Box(low=low, high=high, dtype=np.float64)


def check_actions(action, shape: tuple) -> np.ndarray:
    """Actions as float64 clipped to [-1, 1]; wrong shape or NaN/inf -> ValueError."""
    try:
        a = np.array(action, dtype=np.float64)  # a copy: clipped in place below
    except (TypeError, ValueError):
        raise ValueError(f"action must be a real array of shape {shape} in [-1, 1], got {action!r}") from None
    if a.shape != shape:
        raise ValueError(f"action must have shape {shape} (one value in [-1, 1] per joint), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError("action must be finite (no NaN or inf); values outside [-1, 1] are clipped")
    # minimum/maximum in place: several times cheaper than np.clip on small arrays
    np.minimum(a, 1.0, out=a)
    np.maximum(a, -1.0, out=a)
    return a


def squared_norm(a: np.ndarray) -> np.ndarray:
    """||a||^2 over the last axis; the same reduction for one action and for each row
    of a batch, so the single and the vector env give bit-identical control costs."""
    return np.sum(np.square(a), axis=-1)


class SnakeEnv(gym.Env):
    r"""An n-link wheeled snake robot on a plane, driven by joint torques.

    ## Description
    The snake of Tavakoli Nia, Pishkenari and Meghdari ("A recursive approach
    for the analysis of snake robots using Kane's equations"): n rigid links in
    a chain, each with a passive wheel at its centre of mass that cannot slip
    sideways. The n nonholonomic constraints leave only two degrees of freedom,
    u = (V_1, thetadot_1) (eq. 2); every link's speed and rate follows from u
    and the joint angles (eqs. 6-7). The joints are actuated; bending the body
    against the wheels' constraints is what propels it, as in a real snake.
    The goal is to move the snake's centre of mass as fast as possible along +x.

    Physics is the O(n) recursive Kane formulation (eq. 8) integrated with
    classical RK4 (`frame_skip` steps of `sim_dt` per env step, torques held
    constant). Beyond the paper's model, by default: viscous joint damping,
    viscous wheel rolling resistance (so speed is bounded and the task is well
    posed) and soft joint limits. `paper_model=True` removes all three.
    The soft limit is a torque -k (phi - limit) - c phidot applied beyond
    |phi_k| > joint_limit; since the joints are not independent degrees of
    freedom it acts through the constraints and does not always hold
    |phi_k| below the limit (random actions can fold an n = 5 snake to
    125-140 deg for a while; adjacent links have not been seen to fold over).

    Link 1 is the link whose CM is (x, y) in eq. 1; link k+1 is attached to
    the +e_k end of link k, so with theta = 0 link n is the one furthest along +x.

    ## Action Space
    `Box(-1, 1, (n_links - 1,), float32)`. Action k is the torque of joint k,
    in units of `max_torque`: T_k = max_torque * a_k (N m), acting +T_k on
    link k+1 and -T_k on link k (eq. 11). Out-of-range values are clipped;
    NaN/inf or a wrong shape raise `ValueError`.

    | Num     | Action           | Min | Max | Unit                  |
    |---------|------------------|-----|-----|-----------------------|
    | 0..n-2  | torque of joint k| -1  | 1   | max_torque (N m)      |

    ## Observation Space
    `Box(-inf, inf, (2 n + 2,), float64)` by default (cos/sin bounded by 1);
    `(2 n + 4,)` with `exclude_current_positions_from_observation=False`.
    `env.observation_structure` gives the block sizes. In order:

    | Num           | Observation                                  | Unit  |
    |---------------|----------------------------------------------|-------|
    | excluded (0-1)| x, y of the whole snake's mass-weighted CM   | m     |
    | 0 .. n-2      | joint angles phi_k = theta_{k+1} - theta_k, wrapped to (-pi, pi] | rad |
    | n-1           | cos(theta_1), heading of link 1              | -     |
    | n             | sin(theta_1)                                 | -     |
    | n+1           | V_1, speed of link 1's CM along link 1 (eq. 2) | m/s |
    | n+2           | thetadot_1, rate of link 1 (eq. 2)           | rad/s |
    | n+3 .. 2n+1   | joint rates phidot_k = omega_{k+1} - omega_k (eq. 7) | rad/s |

    (Indices shift by 2 when the position is included.) x, y are always in
    `info` as `x_position`, `y_position`.

    ## Rewards
    reward = forward_reward - ctrl_cost, with
    - forward_reward = `forward_reward_weight` * v_x, where v_x is the x-velocity
      of the mass-weighted centre of mass of the *whole* snake, measured as its
      displacement over the env step divided by dt = sim_dt * frame_skip
      (Swimmer-v5 measures it at the front tip, which rewards wagging the tip).
    - ctrl_cost = `ctrl_cost_weight` * ||a||^2 with a the clipped action.
    `info` has `reward_forward` and `reward_ctrl` (= -ctrl_cost).

    ## Starting State
    theta_k ~ U(-s, s) (rad) for every link, V_1 ~ U(-s, s) (m/s),
    thetadot_1 ~ U(-s, s) (rad/s), s = `reset_noise_scale`; the snake is
    placed so its whole CM is at the origin. A perfectly straight snake is
    singular (torques cannot change its forward speed), the noise moves it off.
    All randomness comes from `self.np_random`.

    ## Episode End
    - Termination: never (`terminated` is always False).
    - Truncation: after 1000 steps (`max_episode_steps` of the registration),
      or at once if the integrated state ever becomes non-finite: the step is
      then undone, the pre-step observation returned, `info["sim_failure"]`
      is True and a `RuntimeWarning` is issued (a simulator failure is not an
      outcome of the task, so it truncates rather than terminates).

    ## Info
    Every step: `x_position`, `y_position`, `distance_from_origin` (m, whole
    CM), `x_velocity`, `y_velocity` (m/s, whole CM over the step),
    `reward_forward`, `reward_ctrl`, `kinetic_energy` (J, eq. 22), `power`
    (W, mean power of all loads over the step: actuators, damping, limits;
    dK/dt), `sim_failure` (bool). Reset: `x_position`, `y_position`,
    `distance_from_origin`, `kinetic_energy`.

    ## Arguments
    `gym.make("snake_env/Snake5-v0", **kwargs)`; all are plain scalars so they
    can come from YAML.

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `n_links` | 5 | number of links n >= 2 |
    | `frame_skip` | 4 | RK4 steps per env step |
    | `sim_dt` | 0.01 | RK4 step (s); env dt = sim_dt * frame_skip = 0.04 s |
    | `max_torque` | 1.0 | joint torque at action 1 (N m), paper Table III |
    | `forward_reward_weight` | 1.0 | weight of v_x (per m/s) |
    | `ctrl_cost_weight` | 1e-4 | weight of ||a||^2 |
    | `reset_noise_scale` | 0.1 | half-width of the uniform start noise (rad, m/s, rad/s) |
    | `exclude_current_positions_from_observation` | True | leave CM x, y out of obs |
    | `joint_damping` | 0.01 | viscous joint damping (N m s/rad) |
    | `wheel_damping` | 0.1 | rolling resistance per wheel (N s/m) |
    | `joint_limit` | pi/2 | soft limit on abs(phi_k) (rad); None disables |
    | `joint_limit_stiffness` | 20.0 | spring beyond the limit (N m/rad) |
    | `joint_limit_damping` | 0.2 | damper beyond the limit (N m s/rad) |
    | `paper_model` | False | True: joint_damping = wheel_damping = 0, no limits (the paper's model) |
    | `mass`, `length`, `inertia` | 1.0, 0.2, 0.005 | per-link kg, m, kg m^2 (paper Table II) |
    | `render_mode` | None | "rgb_array" or "human" |
    | `width`, `height` | 480, 480 | frame size (pixels) |

    ## Version History
    * v0: initial version.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 25}

    def __init__(
        self,
        n_links: int = 5,
        frame_skip: int = DEFAULT_FRAME_SKIP,
        sim_dt: float = DEFAULT_SIM_DT,
        max_torque: float = DEFAULT_MAX_TORQUE,
        forward_reward_weight: float = 1.0,
        ctrl_cost_weight: float = DEFAULT_CTRL_COST_WEIGHT,
        reset_noise_scale: float = DEFAULT_RESET_NOISE_SCALE,
        exclude_current_positions_from_observation: bool = True,
        joint_damping: float = DEFAULT_JOINT_DAMPING,
        wheel_damping: float = DEFAULT_WHEEL_DAMPING,
        joint_limit: float | None = DEFAULT_JOINT_LIMIT,
        joint_limit_stiffness: float = DEFAULT_LIMIT_STIFFNESS,
        joint_limit_damping: float = DEFAULT_LIMIT_DAMPING,
        paper_model: bool = False,
        mass: float = 1.0,
        length: float = 0.2,
        inertia: float = 0.005,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ):
        configure(self, n_links=n_links, frame_skip=frame_skip, sim_dt=sim_dt, max_torque=max_torque,
                  forward_reward_weight=forward_reward_weight, ctrl_cost_weight=ctrl_cost_weight,
                  reset_noise_scale=reset_noise_scale,
                  exclude_current_positions_from_observation=exclude_current_positions_from_observation,
                  joint_damping=joint_damping, wheel_damping=wheel_damping, joint_limit=joint_limit,
                  joint_limit_stiffness=joint_limit_stiffness, joint_limit_damping=joint_limit_damping,
                  paper_model=paper_model, mass=mass, length=length, inertia=inertia,
                  render_mode=render_mode, width=width, height=height)
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt))}

        n = self.n_links
        self.action_space = spaces.Box(-1.0, 1.0, (n - 1,), np.float32)
        self.observation_space = observation_space(n, self.params.include_position)
        self.observation_structure = observation_structure(n, self.params.include_position)

        # state buffers, written in place by the compiled step
        self._q = np.zeros(n + 2)
        self._u = np.zeros(2)
        self._torques = np.zeros(n - 1)
        self._obs = np.zeros(self.params.obs_size)
        self._aux = np.zeros(physics.AUX_SIZE)
        self._trail = deque(maxlen=TRAIL_LENGTH)
        self._renderer = None
        self._window = None
        self._has_reset = False

    # ------------------------------------------------------------------ properties
    @property
    def dt(self) -> float:
        """Duration of one env step (s)."""
        return self.params.dt

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (q, u): q = (theta_1..theta_n, x, y) (eq. 1), u = (V_1, thetadot_1) (eq. 2)."""
        return self._q.copy(), self._u.copy()

    def set_state(self, q, u) -> np.ndarray:
        """Put the snake in state (q, u); return the new observation."""
        obs, aux = physics.observe(self.params, q, u)
        self._q[:], self._u[:] = q, u
        self._obs[:], self._aux[:] = obs, aux
        self._trail.clear()
        self._trail.append((aux[AUX_X], aux[AUX_Y]))
        self._has_reset = True
        return self._obs.copy()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        s = self.reset_noise_scale
        noise = self.np_random.uniform(low=-s, high=s, size=self.n_links + 2)
        q, u, obs, aux = physics.reset(self.params, noise)
        self._q[:], self._u[:], self._obs[:], self._aux[:] = q, u, obs, aux
        self._trail.clear()
        self._trail.append((aux[AUX_X], aux[AUX_Y]))
        self._has_reset = True
        if self.render_mode == "human":
            self.render()
        return self._obs.copy(), self._reset_info()

    def step(self, action):
        if not self._has_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = check_actions(action, self.action_space.shape)
        np.multiply(a, self.max_torque, out=self._torques)
        physics.step_inplace(self.params, self._q, self._u, self._torques, self._obs, self._aux)
        aux = self._aux
        failed = bool(aux[AUX_FAILED])
        if failed:
            warnings.warn("snake_env: the simulated state became non-finite; the step was undone and the episode "
                          "truncated (info['sim_failure'] = True)", RuntimeWarning, stacklevel=2)
        reward_forward = self.forward_reward_weight * aux[AUX_VX]
        ctrl_cost = self.ctrl_cost_weight * float(squared_norm(a))
        reward = float(reward_forward - ctrl_cost)
        self._trail.append((aux[AUX_X], aux[AUX_Y]))
        info = {
            "x_position": float(aux[AUX_X]),
            "y_position": float(aux[AUX_Y]),
            "distance_from_origin": float(np.hypot(aux[AUX_X], aux[AUX_Y])),  # as the vector env computes it
            "x_velocity": float(aux[AUX_VX]),
            "y_velocity": float(aux[AUX_VY]),
            "reward_forward": float(reward_forward),
            "reward_ctrl": -ctrl_cost,
            "kinetic_energy": float(aux[AUX_KINETIC]),
            "power": float(aux[AUX_WORK] / self.dt),
            "sim_failure": failed,
        }
        if self.render_mode == "human":
            self.render()
        return self._obs.copy(), reward, False, failed, info

    def _reset_info(self) -> dict[str, float]:
        aux = self._aux
        return {
            "x_position": float(aux[AUX_X]),
            "y_position": float(aux[AUX_Y]),
            "distance_from_origin": float(np.hypot(aux[AUX_X], aux[AUX_Y])),  # as the vector env computes it
            "kinetic_energy": float(aux[AUX_KINETIC]),
        }

    # ------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human' "
                            "to gym.make")
            return None
        from .rendering import HumanWindow, SnakeRenderer

        if self._renderer is None:
            self._renderer = SnakeRenderer(self.width, self.height, self.params.half_length)
        frame = self._renderer.draw(self._q, np.asarray(self._trail))
        if self.render_mode == "rgb_array":
            return frame
        if self._window is None:
            self._window = HumanWindow(self.width, self.height, fps=self.metadata["render_fps"])
        self._window.show(frame)
        return None

    def close(self):
        if self._window is not None:
            self._window.close()
            self._window = None
        self._renderer = None

    def __getstate__(self):
        # the window and renderer hold OS / cache resources; they are rebuilt on demand
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_window"] = None
        return state
