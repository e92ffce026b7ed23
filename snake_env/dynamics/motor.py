"""A geared DC motor at a joint: what torque reaches the joint for a commanded one.

A DC motor behind a gear (joint side, gear included) obeys tau = k_t i and
V = R i + k_e phidot. At full voltage the torque it can deliver falls
linearly with speed, from the stall torque tau_s at rest to zero at the
no-load speed omega_0 (when driving); braking against the motion it can give
up to tau_s (1 + |phidot| / omega_0). A commanded torque is clipped to that
band, then to the current (torque) limit tau_max:

    hi = tau_s (1 - phidot / omega_0),   lo = -tau_s (1 + phidot / omega_0)
    tau = clip(clip(tau_cmd, lo, hi), -tau_max, tau_max)          (N m)

This is the convention of Isaac Lab's DCMotor (saturation torque, maximum
velocity, effort limit). The motor needs more than a sign of phidot: with the
band, a joint driven by the full command settles at omega_0, and a faster one
is braked, so the torque-speed envelope bounds the joint rates a policy can use.

Known flaw, kept for v3's bits (docs/env.md, "Joint rates"): past
|phidot| = omega_0 (1 + tau_max / tau_s) the band lies wholly beyond -tau_max
(or tau_max), and a real motor brakes with at least |hi| (or |lo|), which its
driver cannot cap. The clip above caps it at tau_max. Clipping to the limit
first, then to the band, gives the physical value there and the same bits
everywhere else; it waits for the next physics version.

``motor_torque`` is compiled inline into the derivative kernels, evaluated at
every RK4 stage (the envelope depends on the state); the ideal torque source
(``torque_limit`` = inf in the kernels' model) skips it altogether.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def motor_torque(command, phidot, stall_torque, inverse_no_load_speed, torque_limit):
    """Torque (N m) at the joint for ``command`` (N m) at joint rate ``phidot`` (rad/s); see the module doc.
    ``inverse_no_load_speed`` = 1 / omega_0 (s/rad), 0 for no speed envelope."""
    slope = stall_torque * phidot * inverse_no_load_speed
    hi = stall_torque - slope
    lo = -stall_torque - slope
    tau = command if command < hi else hi
    tau = tau if tau > lo else lo
    tau = tau if tau < torque_limit else torque_limit
    return tau if tau > -torque_limit else -torque_limit


def motor_torque_reference(command, phidot, stall_torque, no_load_speed, torque_limit):
    """:func:`motor_torque` in plain numpy, vectorised (the tests' reference)."""
    inverse = 0.0 if math.isinf(no_load_speed) else 1.0 / no_load_speed
    hi = stall_torque * (1.0 - np.asarray(phidot) * inverse)
    lo = -stall_torque * (1.0 + np.asarray(phidot) * inverse)
    return np.clip(np.clip(command, lo, hi), -torque_limit, torque_limit)
