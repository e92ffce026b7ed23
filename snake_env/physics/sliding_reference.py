"""An env's snake on sliding wheels (:mod:`snake_env.dynamics.sliding`), stepped as the env steps it.

The env's physics keeps every wheel on the no-slip constraint and applies the traction limit: torque
that would push a wheel past mu m_k g is not transmitted, but a wheel whose own motion asks for more
keeps its grip anyway (docs/env.md, "Finite grip"). The sliding-wheel model lets such a wheel slide
under Coulomb friction instead. :class:`SlidingSnake` runs a controller written for the env (the env's
observation layout, actions in [-1, 1] times ``max_torque`` held for ``dt``) on that model, from a state
of the env, so that one policy's speed and slip can be measured on both (``snake-eval --sliding-wheels``).
"""

from __future__ import annotations

import math

import numpy as np

from snake_env.dynamics.lagrange import consistent_qdot
from snake_env.dynamics.kinematics import cm_positions
from snake_env.dynamics.sliding import SlidingWheels

from .config import PhysicsConfig

# A wheel counts as sliding when its lateral velocity exceeds this many slip speeds: its friction is
# then above 99.5 % of mu m g (the regularised law's grip below a few v_eps is its stand-in for sticking).
SLIDING_FACTOR = 10.0


def sliding_wheels(config: PhysicsConfig, slip_speed: float = 1e-3) -> SlidingWheels:
    """The sliding-wheel model of an env's physics settings: the same links, dampings, motor, joint-limit
    barrier and rotors; the wheels' friction coefficient ``wheel_friction`` as Coulomb's mu."""
    if config.wheel_friction is None:
        raise ValueError("wheel_friction must be a number > 0 for the sliding-wheel model (None: unlimited grip, "
                         "the no-slip model itself)")
    model, params = config.build()
    no_load = math.inf if params.inverse_no_load_speed == 0.0 else 1.0 / params.inverse_no_load_speed
    return SlidingWheels(model, float(config.wheel_friction), slip_speed, stall_torque=params.stall_torque,
                         no_load_speed=no_load, torque_limit=params.torque_limit, joint_limit=params.joint_limit,
                         limit_stiffness=params.limit_stiffness, limit_damping=params.limit_damping,
                         rotor_inertia=params.rotor_inertia, back_emf_braking=params.back_emf_braking)


class SlidingSnake:
    """One snake of ``config`` on sliding wheels, with the env's observation and action conventions."""

    def __init__(self, config: PhysicsConfig, slip_speed: float = 1e-3):
        # this reference holds each command over dt itself: no motor response in time, one robot
        if not config.responds_instantly:
            raise ValueError("torque_lag and control_latency must be 0 for the sliding-wheel model, got "
                             f"{config.torque_lag!r} and {config.control_latency!r}")
        if config.randomized:
            raise ValueError("randomize must be None for the sliding-wheel model")
        self.config = config
        self.wheels = sliding_wheels(config, slip_speed)
        self.n = config.n_links
        self.dt = config.dt
        self.y = None

    def reset(self, q, u) -> np.ndarray:
        """Start from an env state (q, u) (no wheel sliding); returns its observation."""
        q = np.asarray(q, dtype=np.float64)
        self.y = self.wheels.initial(q, consistent_qdot(self.wheels.model, q, np.asarray(u, dtype=np.float64)))
        return self.observation()

    @property
    def q(self) -> np.ndarray:
        return self.y[:self.n + 2]

    @property
    def qdot(self) -> np.ndarray:
        return self.y[self.n + 2:2 * self.n + 4]

    def center_of_mass(self) -> np.ndarray:
        """The whole snake's CM (m), (2,)."""
        m = self.wheels.mass
        cms = cm_positions(self.q[:self.n], self.q[self.n:], self.wheels.model.half_length)
        return m @ cms / np.sum(m)

    def observation(self) -> np.ndarray:
        """The env's physics observation of the state (stepping._observe's layout): the CM if positions
        are observed, the joint angles (wrapped), cos and sin of theta_1, V_1 (link 1's speed along
        itself, m/s), thetadot_1, the joint rates."""
        n, q, qdot = self.n, self.q, self.qdot
        phi = np.diff(q[:n])
        phi = (phi + math.pi) % (2.0 * math.pi) - math.pi
        c1, s1 = math.cos(q[0]), math.sin(q[0])
        parts = [] if self.config.exclude_current_positions_from_observation else [self.center_of_mass()]
        parts += [phi, [c1, s1, c1 * qdot[n] + s1 * qdot[n + 1], qdot[0]], np.diff(qdot[:n])]
        return np.concatenate(parts)

    def step(self, action) -> tuple[np.ndarray, dict]:
        """Hold ``action`` (n-1,) in [-1, 1] (clipped, times max_torque) for dt; returns (observation, info):
        ``x_velocity`` (the CM's, m/s, over the step), ``wheel_lateral_velocity`` and
        ``wheel_lateral_force`` (n,) (m/s, N) at the step's end, ``wheel_sliding`` (n,) bool,
        ``friction_work`` (J, <= 0) and ``work`` (J, every other load) of the step."""
        command = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * self.config.max_torque
        before = self.center_of_mass()
        work0, friction0 = self.y[-2], self.y[-1]
        self.y = self.wheels.advance(self.y, command, self.dt)
        after = self.center_of_mass()
        v, f = self.wheels.lateral(self.q, self.qdot)
        info = {
            "x_velocity": float((after[0] - before[0]) / self.dt),
            "y_velocity": float((after[1] - before[1]) / self.dt),
            "wheel_lateral_velocity": v,
            "wheel_lateral_force": f,
            "wheel_sliding": np.abs(v) > SLIDING_FACTOR * self.wheels.slip_speed,
            "work": float(self.y[-2] - work0),
            "friction_work": float(self.y[-1] - friction0),
        }
        return self.observation(), info
