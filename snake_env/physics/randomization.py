"""Per-episode domain randomization (``randomize=``): each episode's robot drawn from ranges around the nominal one.

``randomize=None`` (the default) is off. ``randomize=True`` draws every parameter below from its
default range; a mapping ``{name: [low, high], ...}`` draws only the names it lists, from the ranges
it gives (YAML: ``randomize: {mass: [0.9, 1.1], control_latency: [0.0, 0.02]}``). Each reset draws
uniformly, independently per parameter (and per link for the per-link ones), from the env's seeded
generator after the start noise and before the task's draws (the start state's centre of mass
depends on the drawn masses), so a seed gives the same start angles and speeds with or without
randomization, and the same draws every time. The drawn values are in the reset ``info`` as
``randomized_<name>`` (physical units).

| name | kind | default range | unit | source of the default range |
|---|---|---|---|---|
| ``mass`` | factor, per link | 0.8-1.2 | x nominal | Tan et al., Sim-to-Real: Learning Agile Locomotion for Quadruped Robots, RSS 2018, Table I: mass 80-120 % |
| ``inertia`` | factor, per link | 0.5-1.5 | x nominal | Tan et al. 2018, Table I: inertia 50-150 % |
| ``stall_torque`` | factor | 0.8-1.2 | x nominal | Tan et al. 2018, Table I: motor strength 80-120 % (scales the torque limit too) |
| ``no_load_speed`` | factor | 0.91-1.09 | x nominal | Tan et al. 2018, Table I: battery voltage 14.0-16.8 V, +-9 % about its middle; a DC motor's no-load speed is proportional to its voltage |
| ``wheel_damping`` | factor | 0.5-1.5 | x nominal | rolling resistance is poorly known; the same +-50 % as the inertia |
| ``wheel_friction`` | value | 0.5-1.25 | mu | Tan et al. 2018, Table I: lateral friction 0.5-1.25 |
| ``control_latency`` | value | 0-0.04 | s | Tan et al. 2018, Table I: control latency 0-40 ms; drawn in whole sim_dt substeps, at most one env step |
| ``rotor_inertia`` | factor | 0.5-1.5 | x nominal | no servo datasheet gives it (it is identified, as MuJoCo Menagerie's Dynamixel armature): the same +-50 % as the inertia |

The motor's constants are drawn only with a DC-motor actuator, ``wheel_friction`` only with finite
grip and ``rotor_inertia`` only with rotors (``rotor_inertia`` > 0): ``randomize=True`` leaves them out
otherwise, and naming them is then an error.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers

import numpy as np

from .actuator_response import WHOLE_SUBSTEP_SLACK, ActuatorResponse
from .stepping import InstantPhysics

_FIRST = np.zeros(1, np.int64)  # the one row of a single robot's batch

# name -> (kind, default low, default high): "factor" multiplies the nominal value, "value" is the value
RANGES = {
    "mass": ("factor", 0.8, 1.2),
    "inertia": ("factor", 0.5, 1.5),
    "stall_torque": ("factor", 0.8, 1.2),
    "no_load_speed": ("factor", 0.91, 1.09),
    "wheel_damping": ("factor", 0.5, 1.5),
    "wheel_friction": ("value", 0.5, 1.25),
    "control_latency": ("value", 0.0, 0.04),
    "rotor_inertia": ("factor", 0.5, 1.5),  # last: a config without rotors draws what it drew before
}
PER_LINK = ("mass", "inertia")
MOTOR = ("stall_torque", "no_load_speed")


def _pair(name, value):
    kind = RANGES[name][0]
    unit = "x the nominal value" if kind == "factor" else {"wheel_friction": "mu", "control_latency": "s"}[name]
    ok = (isinstance(value, (list, tuple)) and len(value) == 2
          and all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) for v in value))
    zero_allowed = name in ("wheel_damping", "control_latency")
    if not ok or not 0.0 <= value[0] <= value[1] or (not zero_allowed and value[0] <= 0.0):
        lowest = ">= 0" if zero_allowed else "> 0"
        raise ValueError(f"randomize[{name!r}] must be a pair [low, high] with {lowest} low <= high ({unit}), "
                         f"got {value!r}")
    return float(value[0]), float(value[1])


def resolve(randomize, *, motor: bool, grip: bool, rotor: bool, sim_dt: float,
            frame_skip: int) -> dict[str, tuple[float, float]]:
    """The ranges ``randomize`` asks for ({} when off); a bad value is a one-line ValueError naming it."""
    ranges = _resolve(randomize, motor=motor, grip=grip, rotor=rotor)
    if "control_latency" in ranges:  # whole substeps, at most one env step
        low, high = ranges["control_latency"]
        dt = sim_dt * frame_skip
        first, last = latency_substep_range(low, high, sim_dt)
        if high > dt * (1 + WHOLE_SUBSTEP_SLACK) or last < first:
            raise ValueError(f"randomize['control_latency'] must be a range [low, high] (s) within [0, dt = {dt:g}] "
                             f"that holds a whole number of sim_dt = {sim_dt:g} s substeps, got {[low, high]}")
    return ranges


def _resolve(randomize, *, motor: bool, grip: bool, rotor: bool) -> dict[str, tuple[float, float]]:
    if randomize is None or randomize is False:
        return {}
    if randomize is True:
        return {name: (low, high) for name, (_, low, high) in RANGES.items()
                if (motor or name not in MOTOR) and (grip or name != "wheel_friction")
                and (rotor or name != "rotor_inertia")}
    if not isinstance(randomize, dict) or not randomize:
        raise ValueError(f"randomize must be None, True or a non-empty mapping {{name: [low, high]}} with names "
                         f"from {list(RANGES)}, got {randomize!r}")
    unknown = sorted(set(randomize) - set(RANGES), key=str)
    if unknown:
        raise ValueError(f"randomize has unknown name(s) {unknown}; allowed: {list(RANGES)}")
    if not motor and any(name in randomize for name in MOTOR):
        raise ValueError("randomize names a motor constant, but actuator='ideal' has none; pick a DC-motor actuator")
    if not grip and "wheel_friction" in randomize:
        raise ValueError("randomize names wheel_friction, but wheel_friction=None (unlimited grip); give a mu")
    if not rotor and "rotor_inertia" in randomize:
        raise ValueError("randomize names rotor_inertia, but rotor_inertia=0 (massless rotors); give one (kg m^2)")
    return {name: _pair(name, value) for name, value in randomize.items()}


def latency_substep_range(low: float, high: float, sim_dt: float) -> tuple[int, int]:
    """(first, last): the whole numbers of sim_dt substeps within a latency range [low, high] (s)."""
    return (math.ceil(low / sim_dt - WHOLE_SUBSTEP_SLACK), math.floor(high / sim_dt + WHOLE_SUBSTEP_SLACK))


def draw(config, ranges: dict, rng: np.random.Generator) -> tuple[object, dict[str, np.ndarray]]:
    """One episode's robot: (the PhysicsConfig with the drawn values, {name: drawn value (physical units)})."""
    n = config.n_links
    changes, factors = {}, {}
    for name, (low, high) in ranges.items():
        if name == "control_latency":  # whole substeps from ceil(low / sim_dt) to floor(high / sim_dt), <= one step
            first, last = latency_substep_range(low, high, config.sim_dt)
            changes[name] = int(rng.integers(first, last + 1)) * float(config.sim_dt)
            continue
        value = rng.uniform(low, high, n if name in PER_LINK else None)
        if name in PER_LINK:
            changes[name] = np.broadcast_to(np.asarray(getattr(config, name), np.float64), (n,)) * value
        elif name in MOTOR:
            factors[name] = float(value)
        elif name in ("wheel_damping", "rotor_inertia"):
            changes[name] = getattr(config, name) * float(value)
        else:  # wheel_friction
            changes[name] = float(value)
    if factors:  # motor strength scales the stall torque and the current limit alike
        motor, strength = config._motor, factors.get("stall_torque", 1.0)
        changes.update(stall_torque=motor.stall_torque * strength, torque_limit=motor.torque_limit * strength,
                       no_load_speed=motor.no_load_speed * factors.get("no_load_speed", 1.0))
    drawn = {name: np.asarray(changes[name], np.float64) for name in ranges}
    return dataclasses.replace(config, randomize=None, **changes), drawn


def stiffest_robot(config, ranges: dict):
    """The drawable robot with the fastest rates (lightest links, strongest and slowest motors, most wheel
    damping, lightest rotors): if RK4 steps it at the config's sim_dt, it steps every robot the ranges can draw."""
    corner = {"mass": 0, "inertia": 0, "stall_torque": 1, "no_load_speed": 0, "wheel_damping": 1,
              "wheel_friction": 0, "control_latency": 0, "rotor_inertia": 0}
    picks = {name: (low, high)[corner[name]] for name, (low, high) in ranges.items()}
    # a range [v, v] draws v exactly
    return draw(config, {name: (value, value) for name, value in picks.items()}, np.random.default_rng(0))[0]


def one_robot(config, params, num_envs: int = 1):
    """The batch physics of one robot's rows: instant commands (on sliding wheels, their physics), or a motor
    response in time (on either wheels)."""
    if not config.responds_instantly:
        return ActuatorResponse(config, params, num_envs)
    if config.wheel_model == "sliding":
        from .sliding_wheels import SlidingWheelPhysics  # here: it imports the config, which imports this module

        return SlidingWheelPhysics(config, params, num_envs)
    return InstantPhysics(config, params, num_envs)


class RandomizedRobots:
    """B rows, each with its own robot drawn at its reset: the physics of a randomized batch, stepped row
    by row (each row's constants differ, so one compiled call cannot take them all; a row's result is that
    of a single env with its drawn robot, bit for bit). The interface of
    :class:`~snake_env.physics.stepping.InstantPhysics`; each row is one of those (or an
    :class:`~snake_env.physics.actuator_response.ActuatorResponse`) of its own."""

    def __init__(self, config, num_envs: int):
        self.config = config
        self.ranges = config.randomized
        stiffest_robot(config, self.ranges).build()  # an explicit sim_dt too long for a drawable robot: refused now
        _, nominal = config.build()
        plain = dataclasses.replace(config, randomize=None)  # the nominal robot until each row's first reset
        self.rows = [one_robot(plain, nominal) for _ in range(num_envs)]
        self.grip = np.tile(config.grip(), (num_envs, 1))
        self.wheel_load = np.tile(config.wheel_load(), (num_envs, 1))
        n = config.n_links
        self.draws = {name: np.zeros((num_envs, n) if name in PER_LINK else num_envs) for name in self.ranges}
        # sliding wheels say which wheels slid; the env reads this array, which each row's step fills in
        self.reports_slip = config.wheel_model == "sliding"
        self.slip = np.zeros((num_envs, n), np.bool_)

    def reset(self, rows, noise, rng):
        """Draw a robot for each row of ``rows`` and put it at its start state from ``noise`` (rows, n+2);
        returns (q, u, obs, aux) of those rows."""
        parts = []
        for i, b in enumerate(rows):
            drawn_config, drawn = draw(self.config, self.ranges, rng)
            _, params = drawn_config.build()
            self.rows[b] = one_robot(drawn_config, params)
            self.grip[b] = drawn_config.grip()
            self.wheel_load[b] = drawn_config.wheel_load()
            for name, value in drawn.items():
                self.draws[name][b] = value
            parts.append(self.rows[b].reset(_FIRST, noise[i:i + 1], rng))
            self.slip[b] = False
        return tuple(np.concatenate(arrays) for arrays in zip(*parts))

    def set_state(self, q, u) -> None:
        """Put every row at (q, u): a row with a state of its own beyond them (sliding wheels) grips."""
        for b, row in enumerate(self.rows):
            if hasattr(row, "set_state"):
                row.set_state(q[b:b + 1], u[b:b + 1])
        self.slip[:] = False

    def held_torques(self, torques):
        """The torque each row held over its last substep (the commanded one without a lag or latency)."""
        return np.concatenate([row.held_torques(torques[b:b + 1]) for b, row in enumerate(self.rows)])

    def bind_step(self, q, u, torques, obs, aux, forces=None, scale=None):
        return functools.partial(self.step, q, u, torques, obs, aux, forces, scale)

    def step(self, q, u, torques, obs, aux, forces=None, scale=None) -> None:
        """Every row stepped with its own robot, in place."""
        for b, row in enumerate(self.rows):
            r = slice(b, b + 1)
            grip = (None, None) if forces is None else (forces[r], scale[r])
            row.step(q[r], u[r], torques[r], obs[r], aux[r], *grip)
            if self.reports_slip:
                self.slip[b] = row.slip[0]

    def observe(self, q, u):
        pairs = [row.observe(q[b:b + 1], u[b:b + 1]) for b, row in enumerate(self.rows)]
        return np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])

    def wheel_lateral_forces(self, q, u, torques, out, scale):
        for b, row in enumerate(self.rows):
            r = slice(b, b + 1)
            row.wheel_lateral_forces(q[r], u[r], torques[r], out[r], scale[r])
