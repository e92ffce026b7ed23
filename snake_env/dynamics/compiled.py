"""Compiled O(n) Kane hot path (numba), for single states and batches.

The same sweep as :mod:`snake_env.dynamics.kane`, written with scalars: the
partial velocities (eqs. 12-14), velocities (eqs. 6-7) and bias
accelerations are carried link by link and M, N omega, F (eqs. 9-11) are
accumulated on the fly, so one derivative costs O(n) time and O(1) memory.
Correctness is anchored to the numpy ``kane_paper`` reference by the tests.

Joint limits (used by the RL env, off for the paper's model) are a barrier
torque applied only beyond |phi| > limit, evaluated inside every RK4 stage:
with the excess d = |phi| - limit (rad) and the room R = FOLD_ANGLE - limit
left before adjacent links fold onto each other,

    T_limit = -s(d) (sign(phi) k d / (1 - d / R) + c phidot),   s(d) = d / (d + LIMIT_RAMP)   (N m)

The spring's potential grows without bound as d -> R, so in the continuous
model no finite energy (no torque) folds a joint; near d = R it is stiff,
which the env's checked integration resolves by refining the step. (1 - d/R)
is floored at 1 - BARRIER_CAP so a state past the fold stays finite (the env
reports it as a failure). The ramp s(d) (0 at the limit, -> 1 beyond a few
LIMIT_RAMP) makes the torque and its slope continuous where the limit starts
to act: v0's damper switched on with a jump c phidot there, an error of
first order in the step that RK4 and its error estimate do not resolve
(measured: up to 0.2 rad/s in one env step against a fine reference).

Every kernel takes the model's constants as one argument ``model``, the
tuple of :class:`KernelModel` made by :func:`kernel_model` (the paper-model
kernels used by :mod:`kane` and :mod:`integrators` take the five arrays of
``SnakeModel.parameters()`` and make it inside).

Editing this module: numba's on-disk cache (``cache=True``) is checked
against the file of each cached function only, so kernels of other modules
that call these (snake_env/physics/stepping.py) keep the old code compiled in.
Delete the caches after an edit: ``find snake_env -name '*.nb[ci]' -delete``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .motor import motor_torque

# Joint angle (rad) at which adjacent links are taken to fold onto each other:
# the model has no contact between links, so a state at or beyond it is not
# physical (170 deg: links of width ~17% of their length touch there).
FOLD_ANGLE = math.radians(170.0)
BARRIER_CAP = 0.999  # largest d / R used by the barrier (its factor 1 / (1 - d/R) stays <= 1000)
LIMIT_RAMP = 0.05  # rad: the barrier's onset ramp s(d) = d / (d + LIMIT_RAMP)


class KernelModel(NamedTuple):
    """The constants every dynamics kernel reads: the model's per-link arrays
    (float64, C-contiguous) and the joint-limit barrier of the module doc.

    Kernels take them as one argument ``model``, the plain tuple of these
    fields made by :func:`kernel_model`, and unpack it in this order (so the
    arithmetic is that of separate arguments). A plain tuple, not this
    NamedTuple: numba's C dispatcher types a plain tuple of arrays and floats,
    while a NamedTuple argument is typed in Python (measured: ~1.3 us more per
    NamedTuple argument and call; two would add ~15% to the single env's step
    of ~18 us).
    """

    mass: np.ndarray  # m_k (kg), (n,)
    half_length: np.ndarray  # h_k (m), (n,): half of link k's length
    inertia: np.ndarray  # I_k (kg m^2) about the link's CM, (n,)
    joint_damping: np.ndarray  # (N m s/rad), (n-1,): viscous joint friction
    wheel_damping: np.ndarray  # (N s/m), (n,): rolling resistance of each wheel
    joint_limit: float = 0.0  # rad: the barrier acts beyond |phi_k| > joint_limit; <= 0: no limits
    limit_stiffness: float = 0.0  # N m/rad: k of the barrier
    limit_damping: float = 0.0  # N m s/rad: c of the barrier
    # the joint motors (snake_env.dynamics.motor): the actuator torques are commands clipped to the DC motor's
    # torque-speed band and current limit; torque_limit = inf is the ideal torque source (no clipping)
    stall_torque: float = math.inf  # N m
    inverse_no_load_speed: float = 0.0  # s/rad: 1 / omega_0; 0 for no speed envelope
    torque_limit: float = math.inf  # N m


def kernel_model(mass, half_length, inertia, joint_damping, wheel_damping, joint_limit=0.0, limit_stiffness=0.0,
                 limit_damping=0.0, stall_torque=math.inf, inverse_no_load_speed=0.0, torque_limit=math.inf) -> tuple:
    """The ``model`` argument of the kernels (see :class:`KernelModel`): its fields
    as a plain tuple, arrays as float64 C-contiguous (the given arrays themselves
    when they already are) and scalars as Python floats, so that every caller
    reuses one compiled (and cached) specialisation. The defaults: no joint limits, ideal torque sources."""
    def array(a):
        return np.ascontiguousarray(a, dtype=np.float64)

    return tuple(KernelModel(array(mass), array(half_length), array(inertia), array(joint_damping),
                             array(wheel_damping), float(joint_limit), float(limit_stiffness), float(limit_damping),
                             float(stall_torque), float(inverse_no_load_speed), float(torque_limit)))


@njit(cache=True, nogil=True, inline="always")
def inverse_room(limit):
    """1 / (FOLD_ANGLE - limit) (1/rad), the barrier's scale; a limit at or past the fold gets a tiny room."""
    room = FOLD_ANGLE - limit
    return 1.0 / (room if room > 1e-3 else 1e-3)


@njit(cache=True, nogil=True)
def derivatives(model, q, u, torques, dq, du):
    """Write qdot into dq (n+2,), udot into du (2,); return dK/dt (W).

    ``model``: :func:`kernel_model`'s tuple. The returned power is that of every
    load (actuators, damping, limits), so K(t) minus its integral is constant in
    the continuous model. A joint limit <= 0 disables the limits (see the module
    doc for the barrier).
    """
    return _kane_sweep(model, q, u, torques, dq, du, _NO_LINKS, False)


# Per-link values _kane_sweep records when asked (row k of ``links``): the partial velocities and
# velocities of eqs. 6-7, 12-14 (a1, a2 = dV_k/du, V_k, Vb_k its bias acceleration; b1, b2, W, Wb the
# same for omega_k), the effective torque T_k of joint k (N m; actuator, damping, barrier) and
# cos, sin of phi_k (the rotation from link k's frame to link k+1's).
LINK_CHANNELS = 11
_NO_LINKS = np.zeros((0, LINK_CHANNELS))


@njit(cache=True, nogil=True, inline="always")
def _kane_sweep(model, q, u, torques, dq, du, links, record):
    """The O(n) sweep of :func:`derivatives`; with ``record`` (a constant, folded away when False)
    it also fills ``links`` (n, LINK_CHANNELS) for :func:`wheel_lateral_forces`."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, stall, inv_w0, t_max = model
    n = m.shape[0]
    inv_room = inverse_room(limit)
    motor = t_max < math.inf
    # channel values of link k: dV/du1, dV/du2, V, Vb and domega/du1, domega/du2, omega, omegab
    a1 = 1.0
    a2 = 0.0
    V = u[0]
    Vb = 0.0
    b1 = 0.0
    b2 = 1.0
    W = u[1]
    Wb = 0.0
    M00 = 0.0
    M01 = 0.0
    M11 = 0.0
    r0 = 0.0
    r1 = 0.0
    power = 0.0
    for k in range(n):
        if record:  # the link's channels (see LINK_CHANNELS)
            links[k, 0] = a1
            links[k, 1] = a2
            links[k, 2] = V
            links[k, 3] = Vb
            links[k, 4] = b1
            links[k, 5] = b2
            links[k, 6] = W
            links[k, 7] = Wb
        # eq. 9 and N omega, accumulated for link k
        mk = m[k]
        Ik = inertia[k]
        M00 += mk * a1 * a1 + Ik * b1 * b1
        M01 += mk * a1 * a2 + Ik * b1 * b2
        M11 += mk * a2 * a2 + Ik * b2 * b2
        f = -c_wheel[k] * V  # rolling resistance (N)
        power += f * V
        r0 += f * a1 - (mk * a1 * Vb + Ik * b1 * Wb)
        r1 += f * a2 - (mk * a2 * Vb + Ik * b2 * Wb)
        dq[k] = W
        if k == n - 1:
            break
        # eqs. 6-7, 13-14 and their time derivative, link k -> k+1
        phi = q[k + 1] - q[k]
        C = math.cos(phi)
        S = math.sin(phi)
        hk = h[k]
        inv_hn = 1.0 / h[k + 1]
        hS = hk * S
        hC = hk * C
        na1 = a1 * C + b1 * hS
        na2 = a2 * C + b2 * hS
        nV = V * C + W * hS
        nVb = Vb * C + Wb * hS
        nb1 = (a1 * S - b1 * hC) * inv_hn
        nb2 = (a2 * S - b2 * hC) * inv_hn
        nW = (V * S - W * hC) * inv_hn
        nWb = (Vb * S - Wb * hC) * inv_hn
        phidot = nW - W
        nVb -= h[k + 1] * nW * phidot
        nWb += nV * phidot * inv_hn
        # eq. 11: joint k acts +T on link k+1, -T on link k
        T = torques[k]
        if motor:  # the command clipped to the motor's torque-speed band and current limit
            T = motor_torque(T, phidot, stall, inv_w0, t_max)
        T -= c_joint[k] * phidot
        if limit > 0.0:
            if phi > limit or phi < -limit:
                excess = phi - limit if phi > limit else phi + limit
                d = abs(excess)
                depth = d * inv_room
                depth = depth if depth < BARRIER_CAP else BARRIER_CAP
                T -= d / (d + LIMIT_RAMP) * (k_limit * excess / (1.0 - depth) + c_limit * phidot)
        r0 += T * (nb1 - b1)
        r1 += T * (nb2 - b2)
        power += T * phidot
        if record:
            links[k, 8] = T
            links[k, 9] = C
            links[k, 10] = S
        a1 = na1
        a2 = na2
        V = nV
        Vb = nVb
        b1 = nb1
        b2 = nb2
        W = nW
        Wb = nWb
    det = M00 * M11 - M01 * M01
    du[0] = (M11 * r0 - M01 * r1) / det
    du[1] = (M00 * r1 - M01 * r0) / det
    dq[n] = u[0] * math.cos(q[0])
    dq[n + 1] = u[0] * math.sin(q[0])
    return power


@njit(cache=True, nogil=True)
def wheel_lateral_forces(model, q, u, torques, links, dq, du, out):
    """The wheels' lateral forces lambda_k (N, along e_k_perp) of state (q, u) under the commanded
    ``torques``: eq. 27's multipliers by the backward Newton-Euler sweep of
    :mod:`snake_env.dynamics.wheel_reactions` (its numpy reference), with the env's effective joint
    torques (motor, damping, barrier). ``links`` (n, LINK_CHANNELS), dq (n+2,), du (2,) are scratch;
    writes out (n,)."""
    m, h, inertia = model[0], model[1], model[2]
    c_wheel = model[4]
    n = m.shape[0]
    _kane_sweep(model, q, u, torques, dq, du, links, True)
    # F_k, the pin force of link k+1 on link k (N), in link k's frame (along e_k, along e_k_perp):
    # e_k x F_k is then its second component; 0 beyond the tail
    Fa = 0.0
    Fp = 0.0
    for k in range(n - 1, -1, -1):
        V = links[k, 2]
        W = links[k, 6]
        Vdot = links[k, 0] * du[0] + links[k, 1] * du[1] + links[k, 3]
        alpha = links[k, 4] * du[0] + links[k, 5] * du[1] + links[k, 7]
        T_in = links[k - 1, 8] if k > 0 else 0.0
        T_out = links[k, 8] if k < n - 1 else 0.0
        lam = (inertia[k] * alpha - T_in + T_out) / h[k] - 2.0 * Fp + m[k] * V * W
        out[k] = lam
        # Newton: F_{k-1} = F_k + f_k e_k + lambda_k e_perp - m_k (Vdot_k e_k + V_k omega_k e_perp), in frame k
        Fa += -c_wheel[k] * V - m[k] * Vdot
        Fp += lam - m[k] * V * W
        if k > 0:  # into link k-1's frame: e_k = C e_{k-1} + S e_{k-1}_perp, phi_{k-1} = theta_k - theta_{k-1}
            C = links[k - 1, 9]
            S = links[k - 1, 10]
            Fa, Fp = Fa * C - Fp * S, Fa * S + Fp * C


@njit(cache=True, nogil=True)
def wheel_lateral_forces_batch(model, q, u, torques, out):
    """:func:`wheel_lateral_forces` of every row: q (B, n+2), u (B, 2), torques (B, n-1), out (B, n)."""
    links = np.empty((q.shape[1] - 2, LINK_CHANNELS))
    dq = np.empty(q.shape[1])
    du = np.empty(2)
    for b in range(q.shape[0]):
        wheel_lateral_forces(model, q[b], u[b], torques[b], links, dq, du, out[b])


@njit(cache=True, nogil=True)
def rk4_step(model, q, u, torques, dt, n_substeps):
    """Advance one state (q, u) in place by ``n_substeps`` RK4 steps of ``dt``
    with torques held constant; return the work of all loads (J)."""
    workspace = np.empty(rk4_workspace_size(q.shape[0]))
    return rk4_step_workspace(model, q, u, torques, dt, n_substeps, workspace)


@njit(cache=True, nogil=True)
def rk4_workspace_size(nq):
    """Scratch floats :func:`rk4_step_workspace` needs for nq = n + 2 coordinates."""
    return 3 * nq + 6


@njit(cache=True, nogil=True)
def rk4_step_workspace(model, q, u, torques, dt, n_substeps, workspace):
    """:func:`rk4_step` with caller-owned scratch (``rk4_workspace_size(n+2)``
    floats), so a loop over many steps or snakes allocates nothing.

    The four stage derivatives are summed into one accumulator as they come
    (k1 + 2 k2 + 2 k3 + k4), so only the stage state, the current stage
    derivative and the sum are stored.
    """
    nq = q.shape[0]
    qs = workspace[0:nq]
    kq = workspace[nq:2 * nq]
    acc_q = workspace[2 * nq:3 * nq]
    us = workspace[3 * nq:3 * nq + 2]
    ku = workspace[3 * nq + 2:3 * nq + 4]
    acc_u = workspace[3 * nq + 4:3 * nq + 6]
    half = 0.5 * dt
    sixth = dt / 6.0
    work = 0.0
    for _ in range(n_substeps):
        # stage 1 at (q, u)
        p1 = derivatives(model, q, u, torques, kq, ku)
        for j in range(nq):
            acc_q[j] = kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] = ku[0]
        acc_u[1] = ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        # stage 2 at the midpoint predicted by stage 1
        p2 = derivatives(model, qs, us, torques, kq, ku)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        # stage 3 at the midpoint predicted by stage 2
        p3 = derivatives(model, qs, us, torques, kq, ku)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + dt * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + dt * ku[0]
        us[1] = u[1] + dt * ku[1]
        # stage 4 at the end point predicted by stage 3
        p4 = derivatives(model, qs, us, torques, kq, ku)
        for j in range(nq):
            q[j] += sixth * (acc_q[j] + kq[j])
        u[0] += sixth * (acc_u[0] + ku[0])
        u[1] += sixth * (acc_u[1] + ku[1])
        work += sixth * (p1 + 2.0 * p2 + 2.0 * p3 + p4)
    return work


@njit(cache=True, parallel=True)
def rk4_step_batch(model, q, u, torques, dt, n_substeps, work):
    """Batched :func:`rk4_step`: q (B, n+2), u (B, 2), torques (B, n-1) in place; work (B,) out."""
    size = rk4_workspace_size(q.shape[1])
    for b in prange(q.shape[0]):
        workspace = np.empty(size)
        work[b] = rk4_step_workspace(model, q[b], u[b], torques[b], dt, n_substeps, workspace)


@njit(cache=True, nogil=True)
def derivatives_batch_serial(m, h, inertia, c_joint, c_wheel, q, u, torques, dq, du, power):
    """:func:`derivatives_batch` on one thread: for small batches (e.g. one
    simulation), where starting threads at every RK4 stage costs more than the work."""
    model = (m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, math.inf, 0.0, math.inf)  # no joint limits, ideal motors
    for b in range(q.shape[0]):
        power[b] = derivatives(model, q[b], u[b], torques[b], dq[b], du[b])


@njit(cache=True, parallel=True)
def derivatives_batch(m, h, inertia, c_joint, c_wheel, q, u, torques, dq, du, power):
    """Batched :func:`derivatives` without joint limits (the paper's model).

    These paper-model kernels (used by :mod:`kane` and :mod:`integrators`) take the
    five arrays of ``SnakeModel.parameters()`` and make the KernelModel tuple inside."""
    model = (m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, math.inf, 0.0, math.inf)
    for b in prange(q.shape[0]):
        power[b] = derivatives(model, q[b], u[b], torques[b], dq[b], du[b])


@njit(cache=True, nogil=True)
def udot_single(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """udot (2,) of one state of the paper's model (no joint limits), written into du."""
    dq = np.empty(q.shape[0])
    derivatives((m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, math.inf, 0.0, math.inf), q, u, torques, dq, du)


@njit(cache=True, nogil=True)
def udot_batch(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """udot (B, 2) of the paper's model (no joint limits) for q (B, n+2),
    u (B, 2), torques (B, n-1); serial, for the small batches of ``model.udot``."""
    dq = np.empty(q.shape[1])
    model = (m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, math.inf, 0.0, math.inf)
    for b in range(q.shape[0]):
        derivatives(model, q[b], u[b], torques[b], dq, du[b])


@njit(cache=True, parallel=True)
def udot_batch_parallel(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """:func:`udot_batch` spread over threads, for large batches."""
    nq = q.shape[1]
    model = (m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, math.inf, 0.0, math.inf)
    for b in prange(q.shape[0]):
        dq = np.empty(nq)
        derivatives(model, q[b], u[b], torques[b], dq, du[b])


# =========================================================================== lanes
# The same RK4 of the same sweep, for many snakes at once, laid out so that the
# innermost loop runs over snakes ("lanes") and LLVM turns it into SIMD code
# (8 doubles per zmm register on AVX-512). Each lane is independent and every
# lane executes the same IEEE operations (no fast-math: no FMA contraction, no
# reassociation), so a snake's result does not depend on its lane or on the
# batch it is in: one snake stepped alone equals the same snake in a batch, bit
# for bit. Against the per-snake kernel above, results differ only by the
# rounding of sin/cos (<= 1 ulp) carried through the step.

# ---------------------------------------------------------------- sin and cos
# fdlibm's argument reduction and kernels (e_rem_pio2.c "medium" case with its
# second iteration, k_sin.c, k_cos.c), written without branches or integer
# conversions so that a loop of them vectorises. Valid for |x| < 2^19 pi/2:
# fn * _PIO2_1 and fn * _PIO2_2 are then exact (33-bit constants).
_INV_PIO2 = 6.36619772367581382433e-01  # 2/pi
_PIO2_1 = 1.57079632673412561417e+00  # first 33 bits of pi/2
_PIO2_2 = 6.07710050630396597660e-11  # next 33 bits of pi/2
_PIO2_2T = 2.02226624879595063154e-21  # pi/2 - _PIO2_1 - _PIO2_2
_INV_2PI = 1.59154943091895345608e-01  # 1/(2 pi)
_ROUND = 6755399441055744.0  # 1.5 * 2^52: (t + _ROUND) - _ROUND is t rounded to an integer (|t| < 2^51)
_S1 = -1.66666666666666324348e-01
_S2 = 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4 = 2.75573137070700676789e-06
_S5 = -2.50507602534068634195e-08
_S6 = 1.58969099521155010221e-10
_C1 = 4.16666666666666019037e-02
_C2 = -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4 = -2.75573143513906633035e-07
_C5 = 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11
SINCOS_MAX = 8.0e5  # rad: |x| up to which sincos is accurate (< 2^19 pi/2)
# Lanes whose link angles exceed this (rad) at the start of a step are stepped
# by the per-snake kernel (libm sin/cos) instead: with |theta| <= 1e5 every
# argument of sincos (theta_1, and joint angles phi <= 2e5) stays far inside
# the reduction's exact range 2^19 pi/2 = 8.2e5 rad.
LANE_ANGLE_MAX = 1.0e5


@njit(cache=True, nogil=True, inline="always")
def sincos(x):
    """(sin x, cos x) to about 1 ulp for |x| < 8e5 rad; NaN for non-finite x."""
    fn = (x * _INV_PIO2 + _ROUND) - _ROUND  # nearest integer to x / (pi/2)
    # y0 + y1 = x - fn pi/2 to ~118 bits (fn pi/2 in three parts)
    r = x - fn * _PIO2_1
    w = fn * _PIO2_2
    t = r
    r = t - w
    w = fn * _PIO2_2T - ((t - r) - w)
    y0 = r - w
    y1 = (r - y0) - w
    z = y0 * y0
    v = z * y0
    rs = _S2 + z * (_S3 + z * _S4) + z * (z * z) * (_S5 + z * _S6)
    ks = y0 - ((z * (0.5 * y1 - v * rs) - y1) - v * _S1)
    zz = z * z
    rc = z * (_C1 + z * (_C2 + z * _C3)) + zz * zz * (_C4 + z * (_C5 + z * _C6))
    hz = 0.5 * z
    wc = 1.0 - hz
    kc = wc + (((1.0 - wc) - hz) + (z * rc - y0 * y1))
    # quadrant fn mod 4, as a float (no integer conversion of a possibly NaN value)
    j = fn - 4.0 * np.floor(fn * 0.25)
    swap = (j == 1.0) | (j == 3.0)
    s = kc if swap else ks
    c = ks if swap else kc
    s = -s if j >= 2.0 else s
    c = -c if (j == 1.0) | (j == 2.0) else c
    return s, c


@njit(cache=True, nogil=True, inline="always")
def wrap_angle(phi):
    """phi minus the nearest multiple of 2 pi (rad): phi itself for |phi| < pi."""
    k = (phi * _INV_2PI + _ROUND) - _ROUND
    return ((phi - k * (4.0 * _PIO2_1)) - k * (4.0 * _PIO2_2)) - k * (4.0 * _PIO2_2T)


@njit(cache=True, nogil=True)
def sincos_array(x, s, c):
    """s, c = sin x, cos x elementwise with :func:`sincos` (1-D arrays)."""
    for i in range(x.shape[0]):
        s[i], c[i] = sincos(x[i])


@njit(cache=True, nogil=True)
def wrap_angle_array(phi, out):
    """out = :func:`wrap_angle` of phi elementwise (1-D arrays)."""
    for i in range(phi.shape[0]):
        out[i] = wrap_angle(phi[i])


# ---------------------------------------------------------------- lane scratch
# One flat float64 array per group of LANES snakes, row-major: row r, lane l
# is s[r * LANES + l]. A header of N_HEADER rows is followed by n + 1 blocks of
# BLOCK rows, block k holding link k's rows. Every row offset is a compile-time
# constant and indices are unsigned (no negative-index wraparound), so in each
# lane loop all addresses are affine with constant distances: LLVM proves the
# rows do not overlap and vectorises without run-time alias checks.
LANES = 16
# header rows: u (at the substep start), its stage value and RK4 sum; the CM of
# link 1 (x, y) likewise; work of the step; stage power sum. Rows from H_FREE on
# are left to callers (e.g. the env's CM and kinetic energy).
# The error-estimating variant (rk4_lanes_estimate) also keeps the last stage-4
# derivative of u and the estimate's running maximum (rows H_K4U0, H_K4U1, H_ERR).
(H_U0, H_U1, H_US0, H_US1, H_ACCU0, H_ACCU1, H_X, H_Y, H_XS, H_YS, H_ACCX, H_ACCY, H_WORK, H_PACC,
 H_K4U0, H_K4U1, H_ERR, H_FREE) = range(18)
N_HEADER = 32
# block rows of link k: theta_k (substep start, stage, RK4 sum), torque of joint k,
# the sweep's channels entering link k (dV/du1, dV/du2, V, Vb, domega/du1,
# domega/du2, omega, omegab) and the sums M, r, power over links < k.
# Rows from B_FREE on are left to callers.
(B_Q, B_QS, B_ACC, B_TQ, B_A1, B_A2, B_V, B_VB, B_B1, B_B2, B_W, B_WB, B_M00, B_M01, B_M11, B_R0, B_R1, B_PW,
 B_K4, B_FREE) = range(20)
BLOCK = 24
_U = np.uint64
# the same rows as unsigned offsets (row * LANES)
(_H_U0, _H_U1, _H_US0, _H_US1, _H_ACCU0, _H_ACCU1, _H_X, _H_Y, _H_XS, _H_YS, _H_ACCX, _H_ACCY, _H_WORK,
 _H_PACC, _H_K4U0, _H_K4U1, _H_ERR) = (np.uint64(r * LANES) for r in range(17))
(_B_Q, _B_QS, _B_ACC, _B_TQ, _B_A1, _B_A2, _B_V, _B_VB, _B_B1, _B_B2, _B_W, _B_WB, _B_M00, _B_M01, _B_M11, _B_R0,
 _B_R1, _B_PW, _B_K4) = (np.uint64(r * LANES) for r in range(19))
_NEXT = np.uint64(BLOCK * LANES)  # from one block to the next


@njit(cache=True, nogil=True)
def lanes_scratch_size(n):
    """Floats of the lane scratch for n links."""
    return (N_HEADER + (n + 1) * BLOCK) * LANES


@njit(cache=True, nogil=True, inline="always")
def lane_block(k):
    """Unsigned offset of link k's block in the lane scratch."""
    return _U(N_HEADER * LANES) + _U(k) * _NEXT


@njit(cache=True, nogil=True, inline="always")
def _rk4_update(z, acc, k, first, last, c, sixth):
    """RK4 bookkeeping of one coordinate after a stage derivative k, as in
    :func:`rk4_step_workspace`: (z, its value for the next stage, running sum)."""
    acc_new = k if first else acc + 2.0 * k
    z_new = z + sixth * (acc + k) if last else z
    zs_new = z_new if last else z + c * k
    return z_new, zs_new, acc_new


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def rk4_stage_lanes(model, s, nl, stage, dt, estimate=0, inv_tol=0.0, v_ref=1.0):
    """RK4 stage ``stage`` (1..4) of lanes 0..nl-1 of the scratch s: the
    derivative at the stage state (rows QS, US) by the sweep of
    :func:`derivatives`, then the stage's update of (Q, QS, ACC), (U, US, ACCU),
    (X, XS, ACCX), (Y, YS, ACCY) and the power sums.

    The link loop is outermost: the channels of link k are read from block k
    and those of link k+1 written to block k+1. ``error_model="numpy"``: a
    singular or NaN state gives inf/NaN (caught by the caller's finite check)
    instead of an exception, and keeps the loops free of exits.
    """
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, stall, inv_w0, t_max = model
    n = m.shape[0]
    motor = t_max < math.inf
    first = stage == 1
    last = stage == 4
    c = dt if stage == 3 else 0.5 * dt
    sixth = dt / 6.0
    use_limit = limit > 0.0
    inv_room = inverse_room(limit)
    lanes = _U(nl)
    b0 = lane_block(0)
    # link 1: qdot of x, y (eq. 1: (x, y) moves with V_1 along e_1) and the sweep's start values
    for l in range(lanes):
        V = s[_H_US0 + l]
        W = s[_H_US1 + l]
        sn, cs = sincos(s[b0 + _B_QS + l])
        x, xs, ax = _rk4_update(s[_H_X + l], s[_H_ACCX + l], V * cs, first, last, c, sixth)
        s[_H_X + l] = x
        s[_H_XS + l] = xs
        s[_H_ACCX + l] = ax
        y, ys, ay = _rk4_update(s[_H_Y + l], s[_H_ACCY + l], V * sn, first, last, c, sixth)
        s[_H_Y + l] = y
        s[_H_YS + l] = ys
        s[_H_ACCY + l] = ay
        s[b0 + _B_A1 + l] = 1.0
        s[b0 + _B_A2 + l] = 0.0
        s[b0 + _B_V + l] = V
        s[b0 + _B_VB + l] = 0.0
        s[b0 + _B_B1 + l] = 0.0
        s[b0 + _B_B2 + l] = 1.0
        s[b0 + _B_W + l] = W
        s[b0 + _B_WB + l] = 0.0
        s[b0 + _B_M00 + l] = 0.0
        s[b0 + _B_M01 + l] = 0.0
        s[b0 + _B_M11 + l] = 0.0
        s[b0 + _B_R0 + l] = 0.0
        s[b0 + _B_R1 + l] = 0.0
        s[b0 + _B_PW + l] = 0.0
    for k in range(n):
        o = lane_block(k)
        p = o + _NEXT
        mk = m[k]
        Ik = inertia[k]
        cwk = c_wheel[k]
        joint = k < n - 1
        hk = h[k]
        hn = h[k + 1] if joint else 1.0
        inv_hn = 1.0 / hn
        cjk = c_joint[k] if joint else 0.0
        for l in range(lanes):
            a1 = s[o + _B_A1 + l]
            a2 = s[o + _B_A2 + l]
            V = s[o + _B_V + l]
            Vb = s[o + _B_VB + l]
            b1 = s[o + _B_B1 + l]
            b2 = s[o + _B_B2 + l]
            W = s[o + _B_W + l]
            Wb = s[o + _B_WB + l]
            # eq. 9 and N omega, accumulated for link k
            M00 = s[o + _B_M00 + l] + (mk * a1 * a1 + Ik * b1 * b1)
            M01 = s[o + _B_M01 + l] + (mk * a1 * a2 + Ik * b1 * b2)
            M11 = s[o + _B_M11 + l] + (mk * a2 * a2 + Ik * b2 * b2)
            f = -cwk * V  # rolling resistance (N)
            power = s[o + _B_PW + l] + f * V
            r0 = s[o + _B_R0 + l] + (f * a1 - (mk * a1 * Vb + Ik * b1 * Wb))
            r1 = s[o + _B_R1 + l] + (f * a2 - (mk * a2 * Vb + Ik * b2 * Wb))
            # theta_k is not read again in this stage: its update goes here (qdot_k = omega_k)
            phi = s[p + _B_QS + l] - s[o + _B_QS + l]
            if estimate == 1:
                e = abs(sixth * (s[o + _B_K4 + l] - W)) * inv_tol  # rad / (tol * 1 rad)
                s[_H_ERR + l] = e if e > s[_H_ERR + l] else s[_H_ERR + l]
            if estimate == 4:
                s[o + _B_K4 + l] = W
            th, ths, acc = _rk4_update(s[o + _B_Q + l], s[o + _B_ACC + l], W, first, last, c, sixth)
            s[o + _B_Q + l] = th
            s[o + _B_QS + l] = ths
            s[o + _B_ACC + l] = acc
            if joint:
                # eqs. 6-7, 13-14 and their time derivative, link k -> k+1
                S, C = sincos(phi)
                hS = hk * S
                hC = hk * C
                na1 = a1 * C + b1 * hS
                na2 = a2 * C + b2 * hS
                nV = V * C + W * hS
                nVb = Vb * C + Wb * hS
                nb1 = (a1 * S - b1 * hC) * inv_hn
                nb2 = (a2 * S - b2 * hC) * inv_hn
                nW = (V * S - W * hC) * inv_hn
                nWb = (Vb * S - Wb * hC) * inv_hn
                phidot = nW - W
                nVb -= hn * nW * phidot
                nWb += nV * phidot * inv_hn
                # eq. 11: joint k acts +T on link k+1, -T on link k; barrier beyond |phi| > limit
                T = s[o + _B_TQ + l]
                if motor:  # the command clipped to the motor's torque-speed band and current limit
                    T = motor_torque(T, phidot, stall, inv_w0, t_max)
                T = T - cjk * phidot
                if use_limit:
                    beyond = (phi > limit) | (phi < -limit)
                    excess = phi - limit if phi > limit else phi + limit
                    d = abs(excess)
                    depth = d * inv_room
                    depth = depth if depth < BARRIER_CAP else BARRIER_CAP
                    ramp = d / (d + LIMIT_RAMP)
                    T = T - ramp * (k_limit * excess / (1.0 - depth) + c_limit * phidot) if beyond else T
                r0 += T * (nb1 - b1)
                r1 += T * (nb2 - b2)
                power += T * phidot
                s[p + _B_A1 + l] = na1
                s[p + _B_A2 + l] = na2
                s[p + _B_V + l] = nV
                s[p + _B_VB + l] = nVb
                s[p + _B_B1 + l] = nb1
                s[p + _B_B2 + l] = nb2
                s[p + _B_W + l] = nW
                s[p + _B_WB + l] = nWb
            s[p + _B_M00 + l] = M00
            s[p + _B_M01 + l] = M01
            s[p + _B_M11 + l] = M11
            s[p + _B_R0 + l] = r0
            s[p + _B_R1 + l] = r1
            s[p + _B_PW + l] = power
    # eq. 8 solved for udot (2x2), then the update of u and of the work
    o = lane_block(n)
    for l in range(lanes):
        M00 = s[o + _B_M00 + l]
        M01 = s[o + _B_M01 + l]
        M11 = s[o + _B_M11 + l]
        r0 = s[o + _B_R0 + l]
        r1 = s[o + _B_R1 + l]
        power = s[o + _B_PW + l]
        det = M00 * M11 - M01 * M01
        du0 = (M11 * r0 - M01 * r1) / det
        du1 = (M00 * r1 - M01 * r0) / det
        if estimate == 1:
            e0 = abs(sixth * (s[_H_K4U0 + l] - du0)) * inv_tol / (abs(s[_H_U0 + l]) + v_ref)
            e1 = abs(sixth * (s[_H_K4U1 + l] - du1)) * inv_tol / (abs(s[_H_U1 + l]) + 1.0)
            e = e0 if e0 > e1 else e1
            s[_H_ERR + l] = e if e > s[_H_ERR + l] else s[_H_ERR + l]
        if estimate == 4:
            s[_H_K4U0 + l] = du0
            s[_H_K4U1 + l] = du1
        u0, us0, acc0 = _rk4_update(s[_H_U0 + l], s[_H_ACCU0 + l], du0, first, last, c, sixth)
        u1, us1, acc1 = _rk4_update(s[_H_U1 + l], s[_H_ACCU1 + l], du1, first, last, c, sixth)
        s[_H_U0 + l] = u0
        s[_H_US0 + l] = us0
        s[_H_ACCU0 + l] = acc0
        s[_H_U1 + l] = u1
        s[_H_US1 + l] = us1
        s[_H_ACCU1 + l] = acc1
        # work += dt/6 (p1 + 2 p2 + 2 p3 + p4), summed left to right as in rk4_step_workspace
        pacc = s[_H_PACC + l]
        work = s[_H_WORK + l]
        s[_H_WORK + l] = work + sixth * (pacc + power) if last else work
        s[_H_PACC + l] = power if first else pacc + 2.0 * power


@njit(cache=True, nogil=True, error_model="numpy")
def rk4_lanes(model, s, nl, dt, n_substeps):
    """``n_substeps`` RK4 steps of lanes 0..nl-1 (loaded by :func:`load_lanes`);
    the work of the loads is added to row H_WORK.

    The four stages are written out with constant stage numbers and inlined,
    so each copy keeps only its own RK4 bookkeeping."""
    for _ in range(n_substeps):
        rk4_stage_lanes(model, s, nl, 1, dt)
        rk4_stage_lanes(model, s, nl, 2, dt)
        rk4_stage_lanes(model, s, nl, 3, dt)
        rk4_stage_lanes(model, s, nl, 4, dt)


@njit(cache=True, nogil=True, error_model="numpy")
def rk4_lanes_estimate(model, s, nl, dt, n_substeps, tol, v_ref):
    """:func:`rk4_lanes` (the same RK4, bit for bit) plus an embedded error estimate:
    row H_ERR gets, per lane, the largest over substeps and coordinates of
    |dt/6 (k4 - k5)| / scale, scale = tol * 1 rad for each theta_k,
    tol * (|V_1| + v_ref) for V_1 (v_ref in m/s) and tol * (|thetadot_1| + 1 rad/s)
    for thetadot_1 (x, y follow from these). <= 1 means within tolerance. Costs one
    derivative more per call (k5 of the last substep; the others are the next
    substep's k1)."""
    inv_tol = 1.0 / tol
    for l in range(nl):
        s[_H_ERR + np.uint64(l)] = 0.0
    rk4_stage_lanes(model, s, nl, 1, dt, 0, inv_tol, v_ref)
    rk4_stage_lanes(model, s, nl, 2, dt, 0, inv_tol, v_ref)
    rk4_stage_lanes(model, s, nl, 3, dt, 0, inv_tol, v_ref)
    rk4_stage_lanes(model, s, nl, 4, dt, 4, inv_tol, v_ref)
    for _ in range(1, n_substeps):
        rk4_stage_lanes(model, s, nl, 1, dt, 1, inv_tol, v_ref)
        rk4_stage_lanes(model, s, nl, 2, dt, 0, inv_tol, v_ref)
        rk4_stage_lanes(model, s, nl, 3, dt, 0, inv_tol, v_ref)
        rk4_stage_lanes(model, s, nl, 4, dt, 4, inv_tol, v_ref)
    # k5 of the last substep: a stage 1 at the final state, which it leaves unchanged
    # (stage 1 writes only the stage state and the running sums)
    rk4_stage_lanes(model, s, nl, 1, dt, 1, inv_tol, v_ref)


@njit(cache=True, nogil=True)
def rk4_step_estimate(model, q, u, torques, dt, n_substeps, tol, v_ref, stop_above_tol=False):
    """:func:`rk4_step` with the error estimate of :func:`rk4_lanes_estimate`;
    returns (work of all loads (J), error estimate / tolerance).

    ``stop_above_tol``: return as soon as the estimate exceeds the tolerance
    (> 1), with (q, u) and the work those of the substep reached. For a caller
    that discards a step over the tolerance anyway: the estimate is a running
    maximum, so the full step would end above the tolerance too."""
    nq = q.shape[0]
    qs = np.empty(nq)
    kq = np.empty(nq)
    acc_q = np.empty(nq)
    k4q = np.empty(nq)
    us = np.empty(2)
    ku = np.empty(2)
    acc_u = np.empty(2)
    k4u = np.empty(2)
    half = 0.5 * dt
    sixth = dt / 6.0
    inv_tol = 1.0 / tol
    n = nq - 2
    work = 0.0
    err = 0.0
    p1 = derivatives(model, q, u, torques, kq, ku)
    for i in range(n_substeps):
        # stage 1 at (q, u): kq, ku hold it (computed at the end of the previous substep)
        for j in range(nq):
            acc_q[j] = kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] = ku[0]
        acc_u[1] = ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        p2 = derivatives(model, qs, us, torques, kq, ku)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        p3 = derivatives(model, qs, us, torques, kq, ku)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + dt * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + dt * ku[0]
        us[1] = u[1] + dt * ku[1]
        p4 = derivatives(model, qs, us, torques, kq, ku)
        for j in range(nq):
            q[j] += sixth * (acc_q[j] + kq[j])
            k4q[j] = kq[j]
        u[0] += sixth * (acc_u[0] + ku[0])
        u[1] += sixth * (acc_u[1] + ku[1])
        k4u[0] = ku[0]
        k4u[1] = ku[1]
        work += sixth * (p1 + 2.0 * p2 + 2.0 * p3 + p4)
        # k5 = f(y_{n+1}), the next substep's k1 (FSAL)
        p1 = derivatives(model, q, u, torques, kq, ku)
        for k in range(n):
            e = abs(sixth * (k4q[k] - kq[k])) * inv_tol
            err = e if e > err else err
        e0 = abs(sixth * (k4u[0] - ku[0])) * inv_tol / (abs(u[0]) + v_ref)
        e1 = abs(sixth * (k4u[1] - ku[1])) * inv_tol / (abs(u[1]) + 1.0)
        err = e0 if e0 > err else err
        err = e1 if e1 > err else err
        if stop_above_tol and err > 1.0:
            break
    return work, err


@njit(cache=True, nogil=True)
def load_lanes(s, q, u, torques, index, start, nl):
    """Lane l <- snake index[start + l] of q (B, n+2), u (B, 2), torques (B, n-1), l < nl;
    stage state = state, work 0."""
    n = q.shape[1] - 2
    for l in range(nl):
        b = index[start + l]
        for k in range(n):
            o = lane_block(k)
            s[o + _B_Q + l] = q[b, k]
            s[o + _B_QS + l] = q[b, k]
            if k < n - 1:
                s[o + _B_TQ + l] = torques[b, k]
        s[_H_X + l] = q[b, n]
        s[_H_Y + l] = q[b, n + 1]
        s[_H_U0 + l] = u[b, 0]
        s[_H_U1 + l] = u[b, 1]
        s[_H_US0 + l] = u[b, 0]
        s[_H_US1 + l] = u[b, 1]
        s[_H_WORK + l] = 0.0


@njit(cache=True, nogil=True)
def store_lanes(s, q, u, work, index, start, nl):
    """Inverse of :func:`load_lanes` for the state, plus work[b] (J)."""
    n = q.shape[1] - 2
    for l in range(nl):
        b = index[start + l]
        for k in range(n):
            q[b, k] = s[lane_block(k) + _B_Q + l]
        q[b, n] = s[_H_X + l]
        q[b, n + 1] = s[_H_Y + l]
        u[b, 0] = s[_H_U0 + l]
        u[b, 1] = s[_H_U1 + l]
        work[b] = s[_H_WORK + l]


@njit(cache=True, nogil=True)
def split_lanes(q):
    """(index, count, wide): snakes whose angles all satisfy |theta_k| <=
    LANE_ANGLE_MAX go to lanes (index[:count], in order); the others
    (index[count:]) to the per-snake kernel."""
    n = q.shape[1] - 2
    B = q.shape[0]
    index = np.empty(B, np.int64)
    count = 0
    wide = B
    for b in range(B):
        inside = True
        for k in range(n):
            inside = inside and abs(q[b, k]) <= LANE_ANGLE_MAX
        if inside:
            index[count] = b
            count += 1
        else:
            wide -= 1
            index[wide] = b
    return index, count


@njit(cache=True, nogil=True)
def _rk4_lane_group(model, q, u, torques, dt, n_substeps, work, index, start, nl, s):
    load_lanes(s, q, u, torques, index, start, nl)
    rk4_lanes(model, s, nl, dt, n_substeps)
    store_lanes(s, q, u, work, index, start, nl)


@njit(cache=True, nogil=True)
def rk4_step_lanes(model, q, u, torques, dt, n_substeps, work):
    """:func:`rk4_step_batch` by the lane kernel on one thread: q (B, n+2),
    u (B, 2), torques (B, n-1) in place; work (B,) out."""
    index, count = split_lanes(q)
    for i in range(count, q.shape[0]):
        b = index[i]
        work[b] = rk4_step(model, q[b], u[b], torques[b], dt, n_substeps)
    s = np.empty(lanes_scratch_size(q.shape[1] - 2))
    for start in range(0, count, LANES):
        _rk4_lane_group(model, q, u, torques, dt, n_substeps, work, index, start, min(LANES, count - start), s)


@njit(cache=True, parallel=True)
def rk4_step_lanes_parallel(model, q, u, torques, dt, n_substeps, work):
    """:func:`rk4_step_lanes` with the lane groups spread over threads."""
    index, count = split_lanes(q)
    for i in range(count, q.shape[0]):
        b = index[i]
        work[b] = rk4_step(model, q[b], u[b], torques[b], dt, n_substeps)
    size = lanes_scratch_size(q.shape[1] - 2)
    for group in prange((count + LANES - 1) // LANES):
        start = group * LANES
        s = np.empty(size)
        _rk4_lane_group(model, q, u, torques, dt, n_substeps, work, index, start, min(LANES, count - start), s)
