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
DEFAULT_JOINT_LIMIT = math.pi / 2  # rad, limit on |phi_k|
DEFAULT_LIMIT_STIFFNESS = 20.0  # N m/rad, least stiffness of the barrier beyond the limit
DEFAULT_LIMIT_DAMPING = 0.2  # N m s/rad, damper beyond the limit (at the least stiffness)
# With the joint's effective inertia I_eff ~ 0.015 kg m^2 (n = 5, paper links) the limit
# rings at sqrt(k / I_eff) ~ 36 rad/s (omega dt = 0.36 per RK4 step) with damping ratio
# ~0.2. A larger damper switches on a larger force jump c * phidot at the limit, which
# RK4 resolves poorly at sim_dt = 0.01 s (measured energy-balance error grows ~15x at c = 1).
# The barrier's stiffness k = max(joint_limit_stiffness, LIMIT_STIFFNESS_PER_TORQUE * max_torque)
# (N m/rad): at k d = max_torque the joint is pushed 0.1 rad past the limit, and the
# barrier's potential diverges before the fold, so it wins against any torque. Its damper
# is scaled by sqrt(k / joint_limit_stiffness) so the damping ratio stays that of the kwargs.
LIMIT_STIFFNESS_PER_TORQUE = 10.0  # 1/rad
MAX_JOINT_LIMIT = math.radians(150.0)  # rad: leaves >= 20 deg of barrier before the fold (170 deg)
INTEGRATORS = ("rk4_refined", "rk4")
DEFAULT_INTEGRATOR = "rk4_refined"
DEFAULT_ENERGY_TOLERANCE = 1e-2  # relative work-energy residual per env step
DEFAULT_ERROR_TOLERANCE = 1e-2  # RK4 embedded local-error estimate per substep, relative (see physics)
DEFAULT_MAX_REFINEMENTS = 6  # substep halvings: down to sim_dt / 64
ENERGY_FLOOR_PER_TORQUE = 1e-3  # J per N m: the residual test's energy floor is this * max_torque * 1 rad
MAX_REFINEMENTS_LIMIT = 12
# RK4's stability interval is about 2.79 on the negative real axis and 2.83 on the
# imaginary axis; sim_dt must keep the stiffest rate of the setting inside it with margin.
RK4_STABLE_RATE_STEP = 2.5
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


def limit_barrier(joint_limit_stiffness, joint_limit_damping, max_torque):
    """(stiffness (N m/rad), damping (N m s/rad)) of the joint-limit barrier for these kwargs."""
    stiffness = max(joint_limit_stiffness, LIMIT_STIFFNESS_PER_TORQUE * max_torque)
    damping = joint_limit_damping
    if joint_limit_stiffness > 0.0:
        damping *= math.sqrt(stiffness / joint_limit_stiffness)
    return stiffness, damping


def stiffest_rates(params: PhysicsParams, max_torque: float) -> dict[str, float]:
    """The setting's fastest linear rates (1/s) at rest, which a stable RK4 step must resolve.

    A joint's effective inertia is at least half the smaller central inertia of its two
    links (the bound is reached by n = 2), I_j (kg m^2); against it act the joint and
    limit dampers (rate c / I_j), the limit spring (sqrt(k / I_j)) and the torque
    (sqrt(max_torque / (I_j * 1 rad)): the rate at which a joint from rest turns a
    radian); the wheel dampers act on the link masses (c / m).
    """
    inertia_j = float(np.min(params.inertia)) / 2.0
    rates = {
        "joint damping": float(np.max(params.joint_damping, initial=0.0)) / inertia_j,
        "wheel damping": float(np.max(params.wheel_damping)) / float(np.min(params.mass)),
        "torque": math.sqrt(max_torque / inertia_j),
    }
    if params.joint_limit > 0.0:
        rates["joint-limit damping"] = (params.limit_damping + float(np.max(params.joint_damping, initial=0.0))) / inertia_j
        rates["joint-limit stiffness"] = math.sqrt(params.limit_stiffness / inertia_j)
    return rates


def max_stable_sim_dt(params: PhysicsParams, max_torque: float) -> tuple[float, str]:
    """(largest accepted sim_dt (s), the rate that bounds it) for a setting."""
    rates = stiffest_rates(params, max_torque)
    name = max(rates, key=rates.get)
    return (RK4_STABLE_RATE_STEP / rates[name] if rates[name] > 0.0 else math.inf), name


def build_physics(n_links, sim_dt, frame_skip, mass, length, inertia, joint_damping, wheel_damping,
                  joint_limit, joint_limit_stiffness, joint_limit_damping, paper_model,
                  exclude_current_positions_from_observation, max_torque=DEFAULT_MAX_TORQUE,
                  integrator=DEFAULT_INTEGRATOR, energy_tolerance=DEFAULT_ENERGY_TOLERANCE,
                  max_refinements=DEFAULT_MAX_REFINEMENTS, error_tolerance=DEFAULT_ERROR_TOLERANCE):
    """Validate the physical kwargs shared by :class:`SnakeEnv` and the vector env;
    return (SnakeModel, PhysicsParams, effective settings dict).

    Settings that no refinement makes sound are refused here: sim_dt above the RK4
    stability limit of the setting's stiffest rate (see :func:`stiffest_rates`)."""
    n_links = check_n_links(n_links)
    sim_dt = _number("sim_dt", sim_dt, "s", minimum=0.0)
    frame_skip = _number("frame_skip", frame_skip, "RK4 steps per env step", minimum=0, integer=True)
    paper_model = _flag("paper_model", paper_model)
    exclude = _flag("exclude_current_positions_from_observation", exclude_current_positions_from_observation)
    max_torque = _number("max_torque", max_torque, "N m", minimum=0.0)
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator must be one of {list(INTEGRATORS)}, got {integrator!r}")
    energy_tolerance = _number("energy_tolerance", energy_tolerance, "relative residual", minimum=0.0)
    if energy_tolerance > 1.0:
        raise ValueError(f"energy_tolerance must be in (0, 1] (relative work-energy residual), got {energy_tolerance!r}")
    error_tolerance = _number("error_tolerance", error_tolerance, "relative local error", minimum=0.0)
    if error_tolerance > 1.0:
        raise ValueError(f"error_tolerance must be in (0, 1] (relative local error per RK4 substep), "
                         f"got {error_tolerance!r}")
    max_refinements = _number("max_refinements", max_refinements, "substep halvings", minimum=0, strict=False,
                              integer=True)
    if max_refinements > MAX_REFINEMENTS_LIMIT:
        raise ValueError(f"max_refinements must be an integer in [0, {MAX_REFINEMENTS_LIMIT}] (substep halvings), "
                         f"got {max_refinements!r}")
    joint_damping = _number("joint_damping", joint_damping, "N m s/rad", minimum=0.0, strict=False)
    wheel_damping = _number("wheel_damping", wheel_damping, "N s/m", minimum=0.0, strict=False)
    if joint_limit is not None:
        joint_limit = _number("joint_limit", joint_limit, "rad, or None to disable", minimum=0.0)
        if joint_limit > MAX_JOINT_LIMIT:
            raise ValueError(f"joint_limit must be in (0, {MAX_JOINT_LIMIT:.4f}] rad (150 deg: the barrier needs room "
                             f"before links fold at 170 deg) or None, got {joint_limit!r}")
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
    limit_stiffness, limit_damping = limit_barrier(joint_limit_stiffness, joint_limit_damping, max_torque)
    params = PhysicsParams(
        mass=m, half_length=h, inertia=inertia_arr, joint_damping=c_joint, wheel_damping=c_wheel,
        joint_limit=0.0 if joint_limit is None else joint_limit,  # the kernel reads <= 0 as "no limit"
        limit_stiffness=limit_stiffness, limit_damping=limit_damping,
        sim_dt=sim_dt, frame_skip=frame_skip, include_position=not exclude,
        energy_tolerance=energy_tolerance, energy_floor=ENERGY_FLOOR_PER_TORQUE * max_torque,
        # "rk4": a plain fixed step, no error control (the guards still apply)
        error_tolerance=error_tolerance if integrator == "rk4_refined" else math.inf,
        max_refinements=max_refinements if integrator == "rk4_refined" else 0)
    bound, rate_name = max_stable_sim_dt(params, max_torque)
    if sim_dt > bound:
        raise ValueError(f"sim_dt must be in (0, {bound:.3g}] s for these settings (the {rate_name} rate "
                         f"{RK4_STABLE_RATE_STEP / bound:.3g} 1/s needs rate * sim_dt <= {RK4_STABLE_RATE_STEP} "
                         f"for a stable RK4 step), got {sim_dt!r}")
    settings = dict(n_links=n_links, sim_dt=sim_dt, frame_skip=frame_skip, joint_damping=joint_damping,
                    wheel_damping=wheel_damping, joint_limit=joint_limit, paper_model=paper_model,
                    exclude_current_positions_from_observation=exclude, max_torque=max_torque,
                    integrator=integrator, energy_tolerance=energy_tolerance, error_tolerance=error_tolerance,
                    max_refinements=max_refinements)
    return model, params, settings


def configure(env, *, n_links, frame_skip, sim_dt, max_torque, forward_reward_weight, ctrl_cost_weight,
              reset_noise_scale, exclude_current_positions_from_observation, joint_damping, wheel_damping,
              joint_limit, joint_limit_stiffness, joint_limit_damping, paper_model, mass, length, inertia,
              render_mode, width, height, integrator=DEFAULT_INTEGRATOR, energy_tolerance=DEFAULT_ENERGY_TOLERANCE,
              error_tolerance=DEFAULT_ERROR_TOLERANCE, max_refinements=DEFAULT_MAX_REFINEMENTS):
    """Validate the constructor kwargs shared by :class:`SnakeEnv` and the vector
    env and set them as attributes of ``env`` (same names as the kwargs)."""
    env.model, env.params, settings = build_physics(
        n_links, sim_dt, frame_skip, mass, length, inertia, joint_damping, wheel_damping, joint_limit,
        joint_limit_stiffness, joint_limit_damping, paper_model, exclude_current_positions_from_observation,
        max_torque=max_torque, integrator=integrator, energy_tolerance=energy_tolerance,
        max_refinements=max_refinements, error_tolerance=error_tolerance)
    for name, value in settings.items():
        setattr(env, name, value)
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
    posed) and joint limits. `paper_model=True` removes all three.

    Joint limits. Beyond |phi_k| > joint_limit a barrier torque acts on the
    joint: with the excess d = |phi_k| - joint_limit (rad) and the room
    R = 170 deg - joint_limit before adjacent links fold onto each other,
    T = -sign(phi_k) k d / (1 - d/R) - c phidot_k (N m). Its stiffness is
    k = max(joint_limit_stiffness, 10 * max_torque) N m/rad (the full torque
    pushes the joint only ~0.1 rad past the limit), its damping
    c = joint_limit_damping * sqrt(k / joint_limit_stiffness) N m s/rad (the
    damping ratio of the kwargs). Its potential diverges at the fold, so no
    torque and no momentum folds the snake; it acts through the constraints,
    so |phi_k| can exceed the limit by some tenths of a radian (the barrier
    is stiff there; the checked integration below resolves it).

    Checked integration (`integrator="rk4_refined"`, the default). Every env
    step is checked: all values finite; the embedded error estimate of RK4
    with its FSAL stage, dt/6 |k4 - k5| per substep, within `error_tolerance`
    times 1 rad for the angles and times |u_i| + 1 (m/s, rad/s) for u; the
    work-energy balance
    |K1 - K0 - W| <= `energy_tolerance` * (max(K0, K1) + 1e-3 J/(N m) * max_torque)
    (K kinetic energy before/after, W the work of all loads over the step, J);
    no link or joint turning more than 1 rad per RK4 substep (a runaway);
    no wrapped |phi_k| at or beyond 170 deg (a fold: links through each
    other, not physical). A sub-env whose step fails is integrated again
    from its pre-step state with the substep halved, up to `max_refinements`
    times (only that sub-env; the others keep their result); if it still
    fails, the step is a simulation failure (see Episode End).
    `integrator="rk4"`: plain fixed-step RK4 with the same check, a failing
    step fails at once (no refinement). Settings whose stiffest rate at rest
    (joint and limit damping against the smallest joint inertia, limit
    stiffness, torque, wheel damping) is beyond RK4's stability at `sim_dt`
    are refused with a ValueError that gives the largest accepted `sim_dt`
    (`snake_env.envs.snake.max_stable_sim_dt`).

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
      or at once on a simulation failure (a step that fails the check above
      even at the finest substep: non-finite, energy balance, runaway speed or
      fold): the step is then undone, the pre-step observation (finite, the
      last valid state) returned with reward exactly 0 (`reward_forward` =
      `reward_ctrl` = 0, velocities 0, power 0), `info["sim_failure"]` is True
      and a `RuntimeWarning` names the reason (a simulator failure is not an
      outcome of the task, so it truncates rather than terminates).

    ## Info
    Every step: `x_position`, `y_position`, `distance_from_origin` (m, whole
    CM), `x_velocity`, `y_velocity` (m/s, whole CM over the step),
    `reward_forward`, `reward_ctrl`, `kinetic_energy` (J, eq. 22), `power`
    (W, mean power of all loads over the step: actuators, damping, limits;
    dK/dt), `sim_failure` (bool). Reset: `x_position`, `y_position`,
    `distance_from_origin`, `kinetic_energy`.

    ## Arguments
    `gym.make("snake_env/Snake5-v1", **kwargs)`; all are plain scalars so they
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
    | `joint_limit` | pi/2 | limit on abs(phi_k) (rad), in (0, 150 deg]; None disables |
    | `joint_limit_stiffness` | 20.0 | least barrier stiffness beyond the limit (N m/rad); raised to 10 * max_torque |
    | `joint_limit_damping` | 0.2 | barrier damper at that least stiffness (N m s/rad) |
    | `paper_model` | False | True: joint_damping = wheel_damping = 0, no limits (the paper's model) |
    | `mass`, `length`, `inertia` | 1.0, 0.2, 0.005 | per-link kg, m, kg m^2 (paper Table II) |
    | `render_mode` | None | "rgb_array" or "human" |
    | `width`, `height` | 480, 480 | frame size (pixels) |
    | `integrator` | "rk4_refined" | "rk4_refined": checked RK4, failing steps refined; "rk4": checked fixed-step RK4 |
    | `error_tolerance` | 1e-2 | tolerance of RK4's embedded local-error estimate per substep (relative) |
    | `energy_tolerance` | 1e-2 | largest relative work-energy residual of an env step |
    | `max_refinements` | 6 | substep halvings of a failing step (finest sim_dt / 64) |

    ## Version History
    * v1: joint limit is a barrier scaled with max_torque (was a 20 N m/rad linear
      spring that strong torques overcame); checked integration with per-sub-env
      refinement; runaway and fold detection (`sim_failure` no longer only for
      non-finite values); reward 0 on a failed step; kwargs `integrator`,
      `error_tolerance`, `energy_tolerance`, `max_refinements`; settings RK4 cannot step stably and
      `joint_limit` > 150 deg are refused.
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
        integrator: str = DEFAULT_INTEGRATOR,
        energy_tolerance: float = DEFAULT_ENERGY_TOLERANCE,
        error_tolerance: float = DEFAULT_ERROR_TOLERANCE,
        max_refinements: int = DEFAULT_MAX_REFINEMENTS,
    ):
        configure(self, n_links=n_links, frame_skip=frame_skip, sim_dt=sim_dt, max_torque=max_torque,
                  forward_reward_weight=forward_reward_weight, ctrl_cost_weight=ctrl_cost_weight,
                  reset_noise_scale=reset_noise_scale,
                  exclude_current_positions_from_observation=exclude_current_positions_from_observation,
                  joint_damping=joint_damping, wheel_damping=wheel_damping, joint_limit=joint_limit,
                  joint_limit_stiffness=joint_limit_stiffness, joint_limit_damping=joint_limit_damping,
                  paper_model=paper_model, mass=mass, length=length, inertia=inertia,
                  render_mode=render_mode, width=width, height=height, integrator=integrator,
                  energy_tolerance=energy_tolerance, error_tolerance=error_tolerance,
                  max_refinements=max_refinements)
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
            warnings.warn(f"snake_env: simulation failure ({physics.FAILURE_REASONS[int(aux[AUX_FAILED])]}); the step "
                          "was undone, reward 0 and the episode truncated (info['sim_failure'] = True)",
                          RuntimeWarning, stacklevel=2)
        reward_forward = self.forward_reward_weight * aux[AUX_VX]  # 0 on failure: the state was kept
        # a failed step is not an outcome of the action: no control cost either (reward exactly 0)
        ctrl_cost = 0.0 if failed else self.ctrl_cost_weight * float(squared_norm(a))
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
