"""Run forward along +x: the task of ``snake_env/Snake{n}-v3``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from snake_env.controllers import SerpenoidController, gait_for_links, load_params
from snake_env.physics.settings import setting
from snake_env.physics import AUX_VX

from .base import DEFAULT_CTRL_COST_WEIGHT, ZERO_INDEX, StepContext, Task, controller_geometry, squared_sum


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
    step fails at once (no refinement). Where the setting's stiffest rate at rest
    (joint and limit damping and a motor's back-EMF against the smallest joint
    inertia, limit stiffness, torque, wheel damping) is beyond RK4's stability
    at `sim_dt`, a `sim_dt` left at its default is divided into the fewest
    equal substeps that RK4 steps stably (dt is unchanged); an explicit
    `sim_dt` is honoured or refused with a ValueError that gives the largest
    accepted one (`snake_env.physics.config.max_stable_sim_dt`). The physics (limits,
    integration, failures) is the same for every task.

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
    With `energy_cost_weight` > 0 (every task) the reward also loses
    `energy_cost_weight` * `actuator_power` (W), reported as `info["reward_energy"]`, and with
    `slip_cost_weight` > 0 it loses that weight times the wheels' lateral force beyond their grip,
    sum_k max(0, |lambda_k| - mu m_k g) / (m_k g), reported as `info["reward_slip"]`; with
    `slip_margin` < 1, beyond that share of the grip instead. On the sliding wheels (v4) a wheel's
    force never exceeds its grip (a sliding wheel's is its friction, mu m_k g), so only a margin
    below 1 charges anything: the sliding wheels and the gripping ones pushed beyond the margin.
    With `action_rate_cost_weight` > 0 (every task) it loses that weight times the squared change of the
    clipped action since the last step, sum_k (a_k - a_k,prev)^2 (a_prev = 0 after a reset), reported as
    `info["reward_action_rate"]`: the action-rate penalty of legged-robot RL, against torque chatter.

    ## Starting State
    theta_k ~ U(-s, s) (rad) for every link, V_1 ~ U(-s, s) (m/s),
    thetadot_1 ~ U(-s, s) (rad/s), s = `reset_noise_scale`; the snake is
    placed so its whole CM is at the origin. A perfectly straight snake is
    singular (torques cannot change its forward speed), the noise moves it off.
    All randomness comes from `self.np_random`. (The same for every task.)

    ## Episode End
    - Termination: never (`terminated` is always False).
    - Truncation: after 1000 steps (`max_episode_steps` of the registration),
      or at once on a simulation failure (a step that fails the check above
      even at the finest substep: non-finite, error estimate, energy balance,
      runaway speed or fold): the step is then undone, the pre-step
      observation (finite, the last valid state) returned with reward exactly
      0 (every `reward_*` term 0), `info["sim_failure"]` is True and a
      `RuntimeWarning` names the reason (a simulator failure is not an
      outcome of the task, so it truncates rather than terminates; every task).

    ## Info
    Every step (every task): `x_position`, `y_position`, `distance_from_origin`
    (m, whole CM), `x_velocity`, `y_velocity` (m/s, whole CM over the step),
    `kinetic_energy` (J, eq. 22, with the rotors' 1/2 N^2 J_r phidot^2 if any), `power` (W, mean power of all loads over the
    step: actuators, damping, limits; dK/dt), `actuator_power` (W, the step's
    mean of sum_k |s A_k phidot_k|: the torque each motor delivers, after its
    torque-speed band, current limit and the traction scale s, times its joint's
    rate; for the cost of transport), `sim_failure` (bool); with
    finite grip (`wheel_friction`, the default), `wheel_lateral_force` (n,) (N: the
    sideways force each wheel exerts on its link, eq. 27's multiplier, from the
    step's final state and held torques under the traction limit;
    `env.unwrapped.wheel_lateral_forces()` without grip), `wheel_slip` (n,) (bool:
    |force| > `wheel_friction` m_k g beyond rounding, which only the motion itself can
    cause: such a wheel would slide, which the no-slip model does not follow) and
    `traction_scale` (the share of the motors' torques the wheels let through,
    1 = all); here also `reward_forward`, `reward_ctrl`. Reset: `x_position`, `y_position`,
    `distance_from_origin`, `kinetic_energy`.

    ## Arguments
    `gym.make("snake_env/Snake5-v3", **kwargs)`; all are plain scalars so they
    can come from YAML. Physical arguments (every task, `PhysicsConfig`):

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `n_links` | 5 | number of links n >= 2 |
    | `frame_skip` | 4 | RK4 steps per env step |
    | `sim_dt` | 0.01 | RK4 step (s); env dt = sim_dt * frame_skip = 0.04 s; the default is divided into substeps where RK4 needs them |
    | `max_torque` | 1.0 | joint torque at action 1 (N m), paper Table III |
    | `exclude_current_positions_from_observation` | True | leave CM x, y out of obs |
    | `joint_damping` | 0.01 | viscous joint damping (N m s/rad) |
    | `wheel_damping` | 0.1 | rolling resistance per wheel (N s/m) |
    | `joint_limit` | pi/2 | limit on abs(phi_k) (rad), in (0, 150 deg]; None disables |
    | `joint_limit_stiffness` | 20.0 | least barrier stiffness beyond the limit (N m/rad); raised to 10 * max_torque |
    | `joint_limit_damping` | 0.2 | barrier damper at that least stiffness (N m s/rad) |
    | `paper_model` | False | True: joint_damping = wheel_damping = 0, no limits (the paper's model) |
    | `wheel_friction` | 0.8 | mu of the wheels on the floor (> 0; rubber on concrete): each wheel holds mu m_k g sideways; None: unlimited grip, the paper's no-slip wheels (v2; `wheel_model` is then "no_slip") |
    | `wheel_model` | "sliding" | "sliding": each wheel grips within `wheel_friction` m_k g and slides under Coulomb friction beyond it, the n + 2 coordinates of eqs. 22-25 time-stepped at 1 ms (`snake_env.physics.sliding_wheels`); `wheel_slip` flags the wheels that slide and `wheel_lateral_force` is their friction. "no_slip" (v3): the paper's wheels (eq. 27) under the traction limit, which scales the motors' torques, on every substep, by the largest s <= 1 that keeps each wheel's sideways force within mu m_k g (or adds nothing where the motion alone exceeds it) |
    | `actuator` | "servo" | joint motors: "ideal" torque sources (v2), or a DC-motor preset "servo" (1 N m, 3.14 rad/s), "xh430_w350", "dc_motor" (`snake_env.physics.actuators`): the torque T_k = max_torque * a_k is a command, clipped to stall_torque (1 - phidot_k / no_load_speed) above and -stall_torque (1 + phidot_k / no_load_speed) below, then to +-torque_limit |
    | `stall_torque`, `no_load_speed`, `torque_limit` | None | N m, rad/s, N m: override the preset's motor constants |
    | `back_emf_braking` | True | a motor back-driven past no_load_speed (1 + torque_limit / stall_torque) brakes with its back-EMF's torque, stall_torque (abs(phidot_k) / no_load_speed - 1), which the current limit cannot cap (the command is clipped to +-torque_limit first, then to the band); False: braking capped at torque_limit (v3) |
    | `rotor_inertia` | 0.0 | kg m^2: each joint motor's reflected rotor inertia N^2 J_r (MuJoCo's armature), its kinetic energy 1/2 N^2 J_r phidot_k^2 in the dynamics and the energy check; 0: massless rotors (every preset) |
    | `torque_lag` | 0.0 | s: time constant of the first-order lag from command to torque (the current loop); 0: instant |
    | `control_latency` | 0.0 | s: delay of each command before it reaches the motor, whole sim_dt substeps, at most dt; 0: none |
    | `randomize` | None | per-episode domain randomization: True (default ranges) or {name: [low, high]} over mass, inertia, stall_torque, no_load_speed, wheel_damping, rotor_inertia (factors), wheel_friction, control_latency (values); draws in the reset info as `randomized_<name>` (`snake_env.physics.randomization`) |
    | `mass`, `length`, `inertia` | 1.0, 0.2, 0.005 | per-link kg, m, kg m^2 (paper Table II) |
    | `integrator` | "rk4_refined" | "rk4_refined": checked RK4, failing steps refined; "rk4": checked fixed-step RK4 |
    | `energy_tolerance` | 1e-2 | largest relative work-energy residual of an env step |
    | `error_tolerance` | 1e-2 | tolerance of RK4's embedded local-error estimate per substep (relative) |
    | `max_refinements` | 6 | substep halvings of a failing step (finest sim_dt / 64) |
    | `render_mode` | None | "rgb_array" or "human" |
    | `width`, `height` | 480, 480 | frame size (pixels) |
    | `reset_noise_scale` | 0.1 | half-width of the uniform start noise (rad, m/s, rad/s) |
    | `energy_cost_weight` | 0.0 | reward lost per W of actuator power (every task) |
    | `slip_cost_weight` | 0.0 | reward lost per link weight (m_k g) of lateral wheel force beyond the grip mu m_k g, summed over wheels (every task; info `reward_slip`) |
    | `action_rate_cost_weight` | 0.0 | reward lost per unit of sum_k (a_k - a_k,prev)^2, the squared change of the clipped action since the last step (every task; info `reward_action_rate`) |
    | `slip_margin` | 1.0 | the slip cost counts lateral force beyond this share of the grip (0 < margin <= 1; below 1 it also charges wheels held near their grip, where a real wheel slides: `snake-eval --sliding-wheels`) |

    This task's arguments:

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `forward_reward_weight` | 1.0 | weight of v_x (per m/s) |
    | `ctrl_cost_weight` | 1e-4 | weight of ||a||^2 |

    ## Version History
    * v4: wheels that slide: each wheel grips within mu m_k g and slides under
      Coulomb friction beyond it (`wheel_model="sliding"`, the n + 2 coordinates of
      eqs. 22-25 time-stepped with the friction solved exactly), instead of the
      no-slip wheels under the traction limit, which held a wheel at its grip
      where a real one slides and so flattered learned long-snake gaits
      (docs/env.md); and back-EMF braking (`back_emf_braking=True`): a joint
      back-driven past 2 omega_0 (the `servo` preset) is braked by its motor's
      back-EMF beyond the current limit, which capped it before. `wheel_slip`
      flags the wheels that slide, `wheel_lateral_force` is their friction and
      `traction_scale` is 1. `snake_env/Snake{n}-v3` is still registered with
      `wheel_model="no_slip", back_emf_braking=False`, its physics bit for bit,
      and v2 with `actuator="ideal", wheel_friction=None`.
    * v3: a robot a lab could build: the joints are servo motors (`actuator="servo"`:
      1 N m stall torque, 3.14 rad/s no-load speed) and the wheels grip up to
      mu m_k g (`wheel_friction=0.8`, rubber on concrete) under the traction
      limit, instead of ideal torque sources and wheels that grip at any force
      (docs/env.md). `snake_env/Snake{n}-v3` is still registered with
      `actuator="ideal", wheel_friction=None`, its physics bit for bit.
      `info` gains `wheel_lateral_force`, `wheel_slip` and `traction_scale`. Corrected
      3 Dec 2026 without a new version (observations, rewards and terminations
      unchanged): `wheel_slip` no longer flags a wheel the traction limit holds at
      its grip, which rounding put up to 4.4e-16 of the grip above it. Corrected
      4 Dec 2026 without a new version (observations, terminations and rewards at
      the default `energy_cost_weight=0` unchanged): `actuator_power` is the power
      the motors deliver, the step's mean of sum_k |s A_k phidot_k| (the torque
      after the motor's band, current limit and traction scale s, integrated with
      the step); it was sum_k |T_k dphi_k| / dt of the commanded torques, about 4x
      too high where the band or the traction limit binds (Snake5-v3 PPO entry:
      205 J against 50 J over an episode). A reward with `energy_cost_weight` > 0
      changes with it.
    * v2: a step that meets every accuracy check but ends folded (|phi_k| reaches
      FOLD_ANGLE) fails at once instead of being refined up to `max_refinements`
      times (the finer substeps folded too). Only settings that can fold differ
      (`paper_model=True`, `joint_limit=None`); with the default joint limit
      no step folded in the fuzz (docs/reliability.md), so those runs equal v1.
    * v1: joint limit is a barrier scaled with max_torque (was a 20 N m/rad linear
      spring that strong torques overcame); checked integration with per-sub-env
      refinement; runaway and fold detection (`sim_failure` no longer only for
      non-finite values); reward 0 on a failed step; kwargs `integrator`,
      `energy_tolerance`, `error_tolerance`, `max_refinements`; settings RK4
      cannot step stably and `joint_limit` > 150 deg are refused. The env is
      one task (`ForwardTask`) of the shared single and vector env; `info`
      gains `actuator_power`.
    * v0: initial version.
    """

    forward_reward_weight: float = setting(1.0, "per m/s", doc="weight of v_x")
    ctrl_cost_weight: float = setting(DEFAULT_CTRL_COST_WEIGHT, "per unit action^2", minimum=0.0, strict=False,
                                      doc="weight of ||a||^2")

    name = "forward"
    id_prefix, version = "Snake", 4
    step_info_keys = ("reward_forward", "reward_ctrl")
    baseline_name = "serpenoid"

    @classmethod
    def make_baseline(cls, config, num_envs=1, gait=None, gaits=None, settings=None):
        """The searched serpenoid of ``gait`` (an env id of the gait file; default: the newest
        ``snake_env/Snake{n}-v*`` of this n searched on this physics), run open loop in its own clock."""
        params = (load_params(gait, gaits)[0] if gait is not None
                  else gait_for_links(config.n_links, gaits, config.versions_back)[0])
        return SerpenoidController(params, num_envs=num_envs, **controller_geometry(config))

    def evaluate(self, config, ctx: StepContext, state):
        rows = ctx.aux.shape[0]
        terms = np.empty((3, rows))
        _forward_terms(ctx.aux, ctx.action, self.forward_reward_weight, self.ctrl_cost_weight, terms)
        return terms[0], np.zeros(rows, np.bool_), {"reward_forward": terms[1], "reward_ctrl": terms[2]}


@njit(cache=True, nogil=True)
def _forward_terms(aux, action, forward_reward_weight, ctrl_cost_weight, out):
    """out (3, B): reward, reward_forward, reward_ctrl of every row (compiled: a dozen numpy
    calls on (1,) arrays would cost more than the single env's physics step)."""
    for b in range(aux.shape[0]):
        reward_forward = forward_reward_weight * aux[b, AUX_VX]
        ctrl_cost = ctrl_cost_weight * squared_sum(action[b], ZERO_INDEX, action.shape[1])
        out[0, b] = reward_forward - ctrl_cost
        out[1, b] = reward_forward
        out[2, b] = -ctrl_cost
