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

Back-EMF braking (``braking``, the physics from v4; docs/env.md, "Joint rates"): past
|phidot| = omega_0 (1 + tau_max / tau_s) the band lies wholly beyond -tau_max (or tau_max): the
back-EMF exceeds the supply by more than the current limit allows, so even full forward voltage
drives more than the limit's current, and a real motor brakes with at least |hi| (or |lo|), which
its driver cannot cap. The clip above caps it at tau_max (v3 and before, kept for their bits). With
``braking`` the result is clipped to the band once more, which is the limit first, then the band:

    tau = clip(clip(tau_cmd, -tau_max, tau_max), lo, hi)

Where band and limit overlap the extra clip changes no bit; it acts only past that speed.

``motor_torque`` is compiled inline into the derivative kernels, evaluated at
every RK4 stage (the envelope depends on the state); the ideal torque source
(``torque_limit`` = inf in the kernels' model) skips it altogether.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, inline="always")
def motor_torque(command, phidot, stall_torque, inverse_no_load_speed, torque_limit, braking):
    """Torque (N m) at the joint for ``command`` (N m) at joint rate ``phidot`` (rad/s); see the module doc.
    ``inverse_no_load_speed`` = 1 / omega_0 (s/rad), 0 for no speed envelope; ``braking`` (> 0): back-EMF
    braking past the current limit (the limit first, then the band)."""
    slope = stall_torque * phidot * inverse_no_load_speed
    hi = stall_torque - slope
    lo = -stall_torque - slope
    tau = command if command < hi else hi
    tau = tau if tau > lo else lo
    tau = tau if tau < torque_limit else torque_limit
    tau = tau if tau > -torque_limit else -torque_limit
    if braking > 0.0:  # the band once more: only where it lies wholly beyond the limit does this move tau
        tau = tau if tau < hi else hi
        tau = tau if tau > lo else lo
    return tau


def motor_torque_reference(command, phidot, stall_torque, no_load_speed, torque_limit, braking=False):
    """:func:`motor_torque` in plain numpy, vectorised (the tests' reference); with ``braking`` written as
    the limit first, then the band."""
    inverse = 0.0 if math.isinf(no_load_speed) else 1.0 / no_load_speed
    hi = stall_torque * (1.0 - np.asarray(phidot) * inverse)
    lo = -stall_torque * (1.0 + np.asarray(phidot) * inverse)
    if braking:
        return np.clip(np.clip(command, -torque_limit, torque_limit), lo, hi)
    return np.clip(np.clip(command, lo, hi), -torque_limit, torque_limit)
