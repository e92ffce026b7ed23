"""Joint actuator presets: the DC-motor constants of :mod:`snake_env.dynamics.motor`, with their sources.

``actuator=`` names one; ``stall_torque``, ``no_load_speed`` and ``torque_limit`` override its fields.

- ``"ideal"``: an ideal torque source: any commanded torque at any joint rate (the paper's
  model and the env up to v2). No motor field may be given with it.
- ``"servo"``: the torque-speed line of the servo class snake robots are built from, scaled to
  the paper's torque. The no-load speed is the Dynamixel XH430-W350's, 30 rpm = 3.14 rad/s at
  12 V (ROBOTIS e-Manual); the stall torque and the current limit are the paper's 1 N m
  (Table III), so the action keeps its meaning. Its back-EMF slope tau_s / omega_0 =
  0.32 N m s/rad is close to the joint damping of 0.333 N m s/rad with which PPO learned
  Snake12 from plain torques (1.26 m/s in 1M steps, measured 2 Dec 2026).
- ``"xh430_w350"``: the Dynamixel XH430-W350 at 12 V as its datasheet gives it: stall torque
  3.4 N m, no-load speed 30 rpm = 3.14 rad/s (gear 353.5:1, 82 g); current limit = stall.
- ``"dc_motor"``: no preset: ``stall_torque`` and ``no_load_speed`` must be given
  (``torque_limit`` defaults to the stall torque).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class ActuatorPreset:
    """stall_torque (N m), no_load_speed (rad/s), torque_limit (N m) at the joint, and where they come from."""

    stall_torque: float
    no_load_speed: float
    torque_limit: float
    source: str


XH430_W350_NO_LOAD_SPEED = 30.0 * 2.0 * math.pi / 60.0  # rad/s: 30 rpm at 12 V (ROBOTIS e-Manual, XH430-W350)
PRESETS: dict[str, ActuatorPreset | None] = {
    "ideal": None,
    "servo": ActuatorPreset(1.0, XH430_W350_NO_LOAD_SPEED, 1.0,
                            "XH430-W350 no-load speed, the paper's 1 N m (Table III) as stall torque and limit"),
    "xh430_w350": ActuatorPreset(3.4, XH430_W350_NO_LOAD_SPEED, 3.4, "Dynamixel XH430-W350 at 12 V (datasheet)"),
    "dc_motor": None,
}
ACTUATORS = tuple(PRESETS)
MOTOR_FIELDS = ("stall_torque", "no_load_speed", "torque_limit")


def resolve(actuator: str, stall_torque, no_load_speed, torque_limit) -> ActuatorPreset | None:
    """The motor of an ``actuator`` name and the fields given (None: the preset's); None for ``"ideal"``.
    A contradiction is a one-line ValueError naming the argument."""
    given = {name: value for name, value in zip(MOTOR_FIELDS, (stall_torque, no_load_speed, torque_limit))
             if value is not None}
    if actuator == "ideal":
        if given:
            raise ValueError(f"{sorted(given)[0]} needs a motor: actuator='ideal' is a torque source; "
                             f"pick actuator from {[a for a in ACTUATORS if a != 'ideal']}")
        return None
    preset = PRESETS[actuator]
    if preset is None:  # dc_motor: the user's own constants
        missing = [name for name in MOTOR_FIELDS[:2] if name not in given]
        if missing:
            raise ValueError(f"actuator='dc_motor' needs {missing[0]} (N m for the stall torque, rad/s for the "
                             f"no-load speed), got None")
        preset = ActuatorPreset(given["stall_torque"], given["no_load_speed"],
                                given.get("torque_limit", given["stall_torque"]), "given")
    values = {name: given.get(name, getattr(preset, name)) for name in MOTOR_FIELDS}
    return ActuatorPreset(**values, source=preset.source if not given else f"{preset.source}; overridden: "
                                                                           f"{sorted(given)}")

