"""Run forward along +x: the task of ``snake_env/Snake{n}-v0``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snake_env.envs.config import setting
from snake_env.envs.physics import AUX_VX

from .base import DEFAULT_CTRL_COST_WEIGHT, StepContext, Task, squared_norm


@dataclass(frozen=True)
class ForwardTask(Task):
    r"""An n-link wheeled snake robot on a plane, driven by joint torques, running along +x.

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
    NaN/inf or a wrong shape raise `ValueError`. (The same for every task.)

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
    `info` as `x_position`, `y_position`. Other tasks append their extras to
    this vector (the "physics observation").

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
    All randomness comes from `self.np_random`. (The same for every task.)

    ## Episode End
    - Termination: never (`terminated` is always False).
    - Truncation: after 1000 steps (`max_episode_steps` of the registration),
      or at once if the integrated state ever becomes non-finite: the step is
      then undone, the pre-step observation returned, `info["sim_failure"]`
      is True and a `RuntimeWarning` is issued (a simulator failure is not an
      outcome of the task, so it truncates rather than terminates; every task).

    ## Info
    Every step (every task): `x_position`, `y_position`, `distance_from_origin`
    (m, whole CM), `x_velocity`, `y_velocity` (m/s, whole CM over the step),
    `kinetic_energy` (J, eq. 22), `power` (W, mean power of all loads over the
    step: actuators, damping, limits; dK/dt), `actuator_power` (W, sum_k
    |T_k dphi_k| / dt, for the cost of transport), `sim_failure` (bool); here
    also `reward_forward`, `reward_ctrl`. Reset: `x_position`, `y_position`,
    `distance_from_origin`, `kinetic_energy`.

    ## Arguments
    `gym.make("snake_env/Snake5-v0", **kwargs)`; all are plain scalars so they
    can come from YAML. Physical arguments (every task, `PhysicsConfig`):

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `n_links` | 5 | number of links n >= 2 |
    | `frame_skip` | 4 | RK4 steps per env step |
    | `sim_dt` | 0.01 | RK4 step (s); env dt = sim_dt * frame_skip = 0.04 s |
    | `max_torque` | 1.0 | joint torque at action 1 (N m), paper Table III |
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
    | `reset_noise_scale` | 0.1 | half-width of the uniform start noise (rad, m/s, rad/s) |

    This task's arguments:

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `forward_reward_weight` | 1.0 | weight of v_x (per m/s) |
    | `ctrl_cost_weight` | 1e-4 | weight of ||a||^2 |

    ## Version History
    * v0: initial version.
    """

    forward_reward_weight: float = setting(1.0, "per m/s", doc="weight of v_x")
    ctrl_cost_weight: float = setting(DEFAULT_CTRL_COST_WEIGHT, "per unit action^2", minimum=0.0, strict=False,
                                      doc="weight of ||a||^2")

    name = "forward"
    step_info_keys = ("reward_forward", "reward_ctrl")

    def evaluate(self, config, ctx: StepContext, state):
        reward_forward = self.forward_reward_weight * ctx.aux[:, AUX_VX]
        ctrl_cost = self.ctrl_cost_weight * squared_norm(ctx.action)
        reward = reward_forward - ctrl_cost
        terminated = np.zeros(reward.shape[0], bool)
        return reward, terminated, {"reward_forward": reward_forward, "reward_ctrl": -ctrl_cost}
