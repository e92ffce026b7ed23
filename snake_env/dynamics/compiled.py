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
    # the wheels' grip mu m_k g (N), (n,): the traction limit of the module doc; empty (0,): unlimited grip
    wheel_grip: np.ndarray = np.empty(0)
    # each joint motor's reflected rotor inertia N^2 J_r (kg m^2), (n-1,): the rotor's kinetic energy
    # 1/2 N^2 J_r phidot_k^2 (MuJoCo's joint armature); empty (0,): massless rotors (the paper's model)
    rotor_inertia: np.ndarray = np.empty(0)
    # 1.0: back-EMF braking past the current limit (.motor's module doc; the physics from v4); 0.0: the motor's
    # braking capped at torque_limit (v3 and before)
    back_emf_braking: float = 0.0


def kernel_model(mass, half_length, inertia, joint_damping, wheel_damping, joint_limit=0.0, limit_stiffness=0.0,
                 limit_damping=0.0, stall_torque=math.inf, inverse_no_load_speed=0.0, torque_limit=math.inf,
                 wheel_grip=None, rotor_inertia=None, back_emf_braking=False) -> tuple:
    """The ``model`` argument of the kernels (see :class:`KernelModel`): its fields
    as a plain tuple, arrays as float64 C-contiguous (the given arrays themselves
    when they already are) and scalars as Python floats, so that every caller
    reuses one compiled (and cached) specialisation. The defaults: no joint limits, ideal torque sources,
    unlimited grip, massless rotors, braking capped at the current limit."""
    def array(a):
        return np.ascontiguousarray(a, dtype=np.float64)

    return tuple(KernelModel(array(mass), array(half_length), array(inertia), array(joint_damping),
                             array(wheel_damping), float(joint_limit), float(limit_stiffness), float(limit_damping),
                             float(stall_torque), float(inverse_no_load_speed), float(torque_limit),
                             array(np.empty(0) if wheel_grip is None else wheel_grip),
                             array(np.empty(0) if rotor_inertia is None else rotor_inertia),
                             1.0 if back_emf_braking else 0.0))


@njit(cache=True, nogil=True, inline="always")
def inverse_room(limit):
    """1 / (FOLD_ANGLE - limit) (1/rad), the barrier's scale; a limit at or past the fold gets a tiny room."""
    room = FOLD_ANGLE - limit
    return 1.0 / (room if room > 1e-3 else 1e-3)


@njit(cache=True, nogil=True, inline="always")
def barrier_torque(phi, phidot, limit, k_limit, c_limit, inv_room):
    """s(d) (sign(phi) k d / (1 - d / R) + c phidot) (N m) of the module doc for a joint beyond its limit
    (|phi| > limit, rad; phidot rad/s; inv_room = :func:`inverse_room`): the barrier torque is minus this."""
    excess = phi - limit if phi > limit else phi + limit
    d = abs(excess)
    depth = d * inv_room
    depth = depth if depth < BARRIER_CAP else BARRIER_CAP
    return d / (d + LIMIT_RAMP) * (k_limit * excess / (1.0 - depth) + c_limit * phidot)


@njit(cache=True, nogil=True, inline="always")
def solve_eq8(M00, M01, M11, det, r0, r1):
    """(udot_1, udot_2) of eq. 8, M udot = r, for the symmetric 2x2 M of determinant ``det``."""
    return (M11 * r0 - M01 * r1) / det, (M00 * r1 - M01 * r0) / det


@njit(cache=True, nogil=True)
def derivatives(model, q, u, torques, dq, du, scale=1.0):
    """Write qdot into dq (n+2,), udot into du (2,); return dK/dt (W).

    ``model``: :func:`kernel_model`'s tuple. The returned power is that of every
    load (actuators, damping, limits), so K(t) minus its integral is constant in
    the continuous model. A joint limit <= 0 disables the limits (see the module
    doc for the barrier). ``scale``: the traction limit's factor on the motors'
    torques (see :func:`traction_derivatives`); 1 leaves them as they are, bit for bit.
    """
    return _kane_sweep(model, q, u, torques, dq, du, _NO_LINKS, False, scale, False)[0]


@njit(cache=True, nogil=True)
def derivatives_motor(model, q, u, torques, dq, du, scale=1.0):
    """:func:`derivatives` (the same dq, du and power, bit for bit) plus the motors' absolute power
    sum_k |scale A_k phidot_k| (W): A_k the torque the motor delivers (after its torque-speed band and
    current limit), ``scale`` >= 0 the traction limit's. Returns (power, motor power)."""
    sweep = _kane_sweep(model, q, u, torques, dq, du, _NO_LINKS, False, scale, False)
    return sweep[0], scale * sweep[9]


# Per-link values _kane_sweep records when asked (row k of ``links``): the partial velocities and
# velocities of eqs. 6-7, 12-14 (a1, a2 = dV_k/du, V_k, Vb_k its bias acceleration; b1, b2, W, Wb the
# same for omega_k), the effective torque T_k of joint k (N m; actuator, damping, barrier) and
# cos, sin of phi_k (the rotation from link k's frame to link k+1's), the motor's torque A_k (N m,
# before the traction scale) and scratch for the traction limit's two backward sweeps.
LINK_CHANNELS = 14
_NO_LINKS = np.zeros((0, LINK_CHANNELS))
_NO_DU = np.zeros(0)


@njit(cache=True, nogil=True, inline="always")
def _kane_sweep(model, q, u, torques, dq, du, links, record, scale, split):
    """The O(n) sweep of :func:`derivatives`; with ``record`` (a constant, folded away when False)
    it also fills ``links`` (n, LINK_CHANNELS) for :func:`wheel_lateral_forces`.

    Returns (power (W), M00, M01, M11, ra0, ra1, pa, r0, r1, pm). The motors' torques A_k enter scaled by
    ``scale``; with ``split`` (a constant) also their generalized forces (ra0, ra1) and power pa
    alone, so that the caller can add them at another scale (eq. 8 is linear in the torques).
    pm = sum_k |A_k phidot_k| (W): the motors' absolute power before any scale (scale >= 0 multiplies it)."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, stall, inv_w0, t_max = model[:11]
    rotor, braking = model[12], model[13]
    n = m.shape[0]
    inv_room = inverse_room(limit)
    motor = t_max < math.inf
    geared = rotor.shape[0] > 0
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
    ra0 = 0.0
    ra1 = 0.0
    pa = 0.0
    pm = 0.0
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
            T = motor_torque(T, phidot, stall, inv_w0, t_max, braking)
        A = T
        pm += abs(A * phidot)
        T = scale * A
        T -= c_joint[k] * phidot
        if limit > 0.0:
            if phi > limit or phi < -limit:
                T -= barrier_torque(phi, phidot, limit, k_limit, c_limit, inv_room)
        r0 += T * (nb1 - b1)
        r1 += T * (nb2 - b2)
        power += T * phidot
        if geared:  # the rotor's kinetic energy 1/2 J phidot^2 with phidot = d . u: J d d^T in eq. 9's M, and
            # its bias J (d . u)' - J d . udot = J (omegab_{k+1} - omegab_k) on the right of eq. 8, as eq. 10's
            # for a link (the order of the lane kernel's, which adds it in a loop of its own)
            jr = rotor[k]
            d1 = nb1 - b1
            d2 = nb2 - b2
            M00 += jr * d1 * d1
            M01 += jr * d1 * d2
            M11 += jr * d2 * d2
            jb = jr * (nWb - Wb)
            r0 -= jb * d1
            r1 -= jb * d2
        if split:
            ra0 += A * (nb1 - b1)
            ra1 += A * (nb2 - b2)
            pa += A * phidot
        if record:
            links[k, 8] = T
            links[k, 9] = C
            links[k, 10] = S
            links[k, 11] = A
        a1 = na1
        a2 = na2
        V = nV
        Vb = nVb
        b1 = nb1
        b2 = nb2
        W = nW
        Wb = nWb
    det = M00 * M11 - M01 * M01
    du[0], du[1] = solve_eq8(M00, M01, M11, det, r0, r1)
    dq[n] = u[0] * math.cos(q[0])
    dq[n + 1] = u[0] * math.sin(q[0])
    return power, M00, M01, M11, ra0, ra1, pa, r0, r1, pm


@njit(cache=True, nogil=True, inline="always")
def joint_rate_partials(links, j):
    """(d1, d2, phib) of joint j from the channels :func:`_kane_sweep` recorded for links j and j+1: its
    acceleration is phiddot_j = d1 udot_1 + d2 udot_2 + phib (d = b_{j+1} - b_j, the partial rates;
    phib = omegab_{j+1} - omegab_j, the bias). A rotor of reflected inertia J_r takes J_r phiddot_j of
    the joint's torque to turn itself; the links get the rest."""
    return links[j + 1, 4] - links[j, 4], links[j + 1, 5] - links[j, 5], links[j + 1, 7] - links[j, 7]


@njit(cache=True, nogil=True, inline="always")
def grip_room(lam0, lamg, grip):
    """The largest traction scale s >= 0 that keeps wheel k's lateral force lam0 + s lamg (N) within
    max(grip, |lam0|) (N): the cone when the torques alone would leave it, no further out than the
    motion alone takes it otherwise; inf where the torques do not load the wheel (lamg = 0)."""
    bound = grip if grip > abs(lam0) else abs(lam0)
    if lamg > 0.0:
        return (bound - lam0) / lamg
    if lamg < 0.0:
        return (bound + lam0) / -lamg
    return math.inf


@njit(cache=True, nogil=True)
def traction_derivatives(model, q, u, torques, dq, du, links, lam, old_scale=1.0, du_old=_NO_DU):
    """:func:`derivatives` under the traction limit; returns (power (W), the scale s in [0, 1], the motors'
    absolute power s sum_k |A_k phidot_k| (W), as :func:`derivatives_motor`).

    The wheels' lateral forces are affine in the motors' torques A at a given state,
    lambda = lambda_0 + s G A (eq. 27's multipliers; lambda_0 that of the motion, the damping and
    the barrier alone). The motors' torques are scaled by the largest s <= 1 that keeps every
    wheel within its grip mu m_k g (model field ``wheel_grip``), or, where the motion alone takes
    a wheel past it, that adds no excess (:func:`grip_room`): torque that would make a wheel slip
    buys no acceleration. One sweep at s = 0 with the motors' share kept apart gives udot at any s
    (eq. 8 is linear in the torques); one backward Newton-Euler sweep (as in
    :func:`wheel_lateral_forces`) gives lambda_0 and G A together. Writes dq, du at s and
    lam (n,) = lambda at s (N); ``links`` (n, LINK_CHANNELS) is scratch. ``du_old`` (2,), if given,
    gets udot at ``old_scale`` from the same sweep: the error estimate of a substep compares its
    last stage with f(y1) at the substep's own scale, since the jump of the held scale to the next
    substep's is a change of the control, not an integration error.
    """
    m, h, inertia = model[0], model[1], model[2]
    c_wheel = model[4]
    grip = model[11]
    rotor = model[12]
    geared = rotor.shape[0] > 0
    n = m.shape[0]
    power, M00, M01, M11, ra0, ra1, pa, r0, r1, pm = _kane_sweep(model, q, u, torques, dq, du, links, True, 0.0, True)
    det = M00 * M11 - M01 * M01
    g0, g1 = solve_eq8(M00, M01, M11, det, ra0, ra1)
    du0 = du[0]
    du1 = du[1]
    # pin forces (along e_k, e_k_perp in link k's frame) of the two right-hand sides
    Fa = 0.0
    Fp = 0.0
    Ga = 0.0
    Gp = 0.0
    scale = 1.0
    for k in range(n - 1, -1, -1):
        V = links[k, 2]
        W = links[k, 6]
        a1 = links[k, 0]
        a2 = links[k, 1]
        b1 = links[k, 4]
        b2 = links[k, 5]
        Vdot = a1 * du0 + a2 * du1 + links[k, 3]
        alpha = b1 * du0 + b2 * du1 + links[k, 7]
        Vdot_g = a1 * g0 + a2 * g1
        alpha_g = b1 * g0 + b2 * g1
        P_in = links[k - 1, 8] if k > 0 else 0.0
        P_out = links[k, 8] if k < n - 1 else 0.0
        A_in = links[k - 1, 11] if k > 0 else 0.0
        A_out = links[k, 11] if k < n - 1 else 0.0
        if geared:  # what the rotors take of the joints' torques, split as the torques are (lambda_0, G A)
            if k > 0:
                d1, d2, phib = joint_rate_partials(links, k - 1)
                P_in -= rotor[k - 1] * (d1 * du0 + d2 * du1 + phib)
                A_in -= rotor[k - 1] * (d1 * g0 + d2 * g1)
            if k < n - 1:
                d1, d2, phib = joint_rate_partials(links, k)
                P_out -= rotor[k] * (d1 * du0 + d2 * du1 + phib)
                A_out -= rotor[k] * (d1 * g0 + d2 * g1)
        mVW = m[k] * V * W
        lam0 = (inertia[k] * alpha - P_in + P_out) / h[k] - 2.0 * Fp + mVW
        lamg = (inertia[k] * alpha_g - A_in + A_out) / h[k] - 2.0 * Gp
        links[k, 12] = lam0
        links[k, 13] = lamg
        Fa += -c_wheel[k] * V - m[k] * Vdot
        Fp += lam0 - mVW
        Ga += -m[k] * Vdot_g
        Gp += lamg
        if k > 0:
            C = links[k - 1, 9]
            S = links[k - 1, 10]
            Fa, Fp = Fa * C - Fp * S, Fa * S + Fp * C
            Ga, Gp = Ga * C - Gp * S, Ga * S + Gp * C
        room = grip_room(lam0, lamg, grip[k])
        scale = room if room < scale else scale
    if du_old.shape[0] == 2:
        r0_old = r0 + old_scale * ra0
        r1_old = r1 + old_scale * ra1
        du_old[0], du_old[1] = solve_eq8(M00, M01, M11, det, r0_old, r1_old)
    # eq. 8 at the scale, as the lane kernel computes it (_traction_lanes)
    r0 = r0 + scale * ra0
    r1 = r1 + scale * ra1
    du[0], du[1] = solve_eq8(M00, M01, M11, det, r0, r1)
    for k in range(n):
        lam[k] = links[k, 12] + scale * links[k, 13]
    return power + scale * pa, scale, scale * pm


@njit(cache=True, nogil=True)
def wheel_lateral_forces(model, q, u, torques, links, dq, du, out):
    """The wheels' lateral forces lambda_k (N, along e_k_perp) of state (q, u) under the commanded
    ``torques``: eq. 27's multipliers by the backward Newton-Euler sweep of
    :mod:`snake_env.dynamics.wheel_reactions` (its numpy reference), with the env's effective joint
    torques (motor, traction limit, damping, barrier). ``links`` (n, LINK_CHANNELS), dq (n+2,),
    du (2,) are scratch; writes out (n,); returns the traction scale (1 with unlimited grip)."""
    if model[11].shape[0] > 0:
        # the defaults given explicitly: one compiled specialisation for every caller (~2 s cold each)
        return traction_derivatives(model, q, u, torques, dq, du, links, out, 1.0, np.empty(0))[1]
    m, h, inertia = model[0], model[1], model[2]
    c_wheel = model[4]
    rotor = model[12]
    geared = rotor.shape[0] > 0
    n = m.shape[0]
    _kane_sweep(model, q, u, torques, dq, du, links, True, 1.0, False)
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
        if geared:  # the rotors take J_r phiddot of the joints' torques
            if k > 0:
                d1, d2, phib = joint_rate_partials(links, k - 1)
                T_in -= rotor[k - 1] * (d1 * du[0] + d2 * du[1] + phib)
            if k < n - 1:
                d1, d2, phib = joint_rate_partials(links, k)
                T_out -= rotor[k] * (d1 * du[0] + d2 * du[1] + phib)
        lam = (inertia[k] * alpha - T_in + T_out) / h[k] - 2.0 * Fp + m[k] * V * W
        out[k] = lam
        # Newton: F_{k-1} = F_k + f_k e_k + lambda_k e_perp - m_k (Vdot_k e_k + V_k omega_k e_perp), in frame k
        Fa += -c_wheel[k] * V - m[k] * Vdot
        Fp += lam - m[k] * V * W
        if k > 0:  # into link k-1's frame: e_k = C e_{k-1} + S e_{k-1}_perp, phi_{k-1} = theta_k - theta_{k-1}
            C = links[k - 1, 9]
            S = links[k - 1, 10]
            Fa, Fp = Fa * C - Fp * S, Fa * S + Fp * C
    return 1.0


@njit(cache=True, nogil=True)
def wheel_lateral_forces_batch(model, q, u, torques, out, scale):
    """:func:`wheel_lateral_forces` of every row: q (B, n+2), u (B, 2), torques (B, n-1), out (B, n);
    scale (B,) gets each row's traction scale."""
    links = np.empty((q.shape[1] - 2, LINK_CHANNELS))
    dq = np.empty(q.shape[1])
    du = np.empty(2)
    for b in range(q.shape[0]):
        scale[b] = wheel_lateral_forces(model, q[b], u[b], torques[b], links, dq, du, out[b])


@njit(cache=True, nogil=True)
def rk4_step(model, q, u, torques, dt, n_substeps):
    """Advance one state (q, u) in place by ``n_substeps`` RK4 steps of ``dt``
    with torques held constant; return the work of all loads (J)."""
    workspace = np.empty(rk4_workspace_size(q.shape[0]))
    return rk4_step_workspace(model, q, u, torques, dt, n_substeps, workspace)


@njit(cache=True, nogil=True)
def rk4_workspace_size(nq):
    """Scratch floats :func:`rk4_step_workspace` needs for nq = n + 2 coordinates."""
    return 3 * nq + 6 + (nq - 2) * (LINK_CHANNELS + 1)


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
    n = nq - 2
    links = workspace[3 * nq + 6:3 * nq + 6 + n * LINK_CHANNELS].reshape((n, LINK_CHANNELS))
    lam = workspace[3 * nq + 6 + n * LINK_CHANNELS:3 * nq + 6 + n * (LINK_CHANNELS + 1)]
    traction = model[11].shape[0] > 0
    half = 0.5 * dt
    sixth = dt / 6.0
    work = 0.0
    scale = 1.0
    for _ in range(n_substeps):
        # stage 1 at (q, u); with finite grip the traction scale is set here and held for the substep
        if traction:
            p1, scale, _ = traction_derivatives(model, q, u, torques, kq, ku, links, lam)
        else:
            p1 = derivatives(model, q, u, torques, kq, ku)
        for j in range(nq):
            acc_q[j] = kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] = ku[0]
        acc_u[1] = ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        # stage 2 at the midpoint predicted by stage 1
        p2 = derivatives(model, qs, us, torques, kq, ku, scale)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        # stage 3 at the midpoint predicted by stage 2
        p3 = derivatives(model, qs, us, torques, kq, ku, scale)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + dt * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + dt * ku[0]
        us[1] = u[1] + dt * ku[1]
        # stage 4 at the end point predicted by stage 3
        p4 = derivatives(model, qs, us, torques, kq, ku, scale)
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


@njit(cache=True, nogil=True, inline="always")
def _paper_model(m, h, inertia, c_joint, c_wheel):
    """The KernelModel tuple of the paper's model: no joint limits, ideal torque sources, unlimited grip,
    massless rotors."""
    return (m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, math.inf, 0.0, math.inf, np.empty(0), np.empty(0), 0.0)


@njit(cache=True, nogil=True)
def derivatives_batch_serial(m, h, inertia, c_joint, c_wheel, q, u, torques, dq, du, power):
    """:func:`derivatives_batch` on one thread: for small batches (e.g. one
    simulation), where starting threads at every RK4 stage costs more than the work."""
    model = _paper_model(m, h, inertia, c_joint, c_wheel)
    for b in range(q.shape[0]):
        power[b] = derivatives(model, q[b], u[b], torques[b], dq[b], du[b])


@njit(cache=True, parallel=True)
def derivatives_batch(m, h, inertia, c_joint, c_wheel, q, u, torques, dq, du, power):
    """Batched :func:`derivatives` without joint limits (the paper's model).

    These paper-model kernels (used by :mod:`kane` and :mod:`integrators`) take the
    five arrays of ``SnakeModel.parameters()`` and make the KernelModel tuple inside."""
    model = _paper_model(m, h, inertia, c_joint, c_wheel)
    for b in prange(q.shape[0]):
        power[b] = derivatives(model, q[b], u[b], torques[b], dq[b], du[b])


@njit(cache=True, nogil=True)
def udot_single(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """udot (2,) of one state of the paper's model (no joint limits), written into du."""
    dq = np.empty(q.shape[0])
    derivatives(_paper_model(m, h, inertia, c_joint, c_wheel), q, u, torques, dq, du)


@njit(cache=True, nogil=True)
def udot_batch(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """udot (B, 2) of the paper's model (no joint limits) for q (B, n+2),
    u (B, 2), torques (B, n-1); serial, for the small batches of ``model.udot``."""
    dq = np.empty(q.shape[1])
    model = _paper_model(m, h, inertia, c_joint, c_wheel)
    for b in range(q.shape[0]):
        derivatives(model, q[b], u[b], torques[b], dq, du[b])


@njit(cache=True, parallel=True)
def udot_batch_parallel(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """:func:`udot_batch` spread over threads, for large batches."""
    nq = q.shape[1]
    model = _paper_model(m, h, inertia, c_joint, c_wheel)
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
# With finite grip (traction_derivatives): the substep's traction scale and the previous substep's.
# The motors' energy of the step and its stage sum (as the work's; see derivatives_motor).
(H_U0, H_U1, H_US0, H_US1, H_ACCU0, H_ACCU1, H_X, H_Y, H_XS, H_YS, H_ACCX, H_ACCY, H_WORK, H_PACC,
 H_K4U0, H_K4U1, H_ERR, H_SCALE, H_SCALE_OLD, H_MOTOR, H_MACC, H_FREE) = range(22)
N_HEADER = 48  # >= BLOCK: block -1 (lane_block(0) - one block) lies in the header, see _traction_lanes
# block rows of link k: theta_k (substep start, stage, RK4 sum), torque of joint k,
# the sweep's channels entering link k (dV/du1, dV/du2, V, Vb, domega/du1,
# domega/du2, omega, omegab) and the sums M, r, power over links < k.
# With finite grip also joint k's motor torque A_k and passive torque P_k, cos, sin of phi_k,
# the sums of the motors' generalized forces and power over links < k, the traction scale, and
# the backward sweep's values carried from link k+1 to k (udot at scale 0 and the motors' share,
# the two pin forces, the least room so far). The error estimate's running maximum over the links
# before k. The backward sweep's lambda_0 and lambda_g of wheel k (so the step's wheel forces come
# from the k5 sweep at the final state, lambda_0 + s lambda_g, with no sweep of their own). The sum
# of |A_j phidot_j| over joints j < k (the motors' absolute power before the traction scale).
# Values a lane loop carries from link to link live
# in the blocks, never in the header: every address in the loop is then a constant distance from
# the block's, so LLVM vectorises it without run-time alias checks.
# Rows from B_FREE on are left to callers.
(B_Q, B_QS, B_ACC, B_TQ, B_A1, B_A2, B_V, B_VB, B_B1, B_B2, B_W, B_WB, B_M00, B_M01, B_M11, B_R0, B_R1, B_PW,
 B_K4, B_TA, B_TP, B_C, B_S, B_RA0, B_RA1, B_PA, B_SC, B_DP0, B_DP1, B_G0, B_G1, B_FA, B_FP, B_GA, B_GP, B_ROOM,
 B_ERR, B_L0, B_LG, B_PM, B_FREE) = range(41)
BLOCK = 44
assert N_HEADER >= BLOCK
_U = np.uint64
# the same rows as unsigned offsets (row * LANES)
(_H_U0, _H_U1, _H_US0, _H_US1, _H_ACCU0, _H_ACCU1, _H_X, _H_Y, _H_XS, _H_YS, _H_ACCX, _H_ACCY, _H_WORK,
 _H_PACC, _H_K4U0, _H_K4U1, _H_ERR, _H_SCALE, _H_SCALE_OLD, _H_MOTOR, _H_MACC) = (np.uint64(r * LANES) for r in range(21))
(_B_Q, _B_QS, _B_ACC, _B_TQ, _B_A1, _B_A2, _B_V, _B_VB, _B_B1, _B_B2, _B_W, _B_WB, _B_M00, _B_M01, _B_M11, _B_R0,
 _B_R1, _B_PW, _B_K4, _B_TA, _B_TP, _B_C, _B_S, _B_RA0, _B_RA1, _B_PA, _B_SC, _B_DP0, _B_DP1, _B_G0, _B_G1, _B_FA,
 _B_FP, _B_GA, _B_GP, _B_ROOM, _B_ERR, _B_L0, _B_LG, _B_PM) = (np.uint64(r * LANES) for r in range(40))
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


# rk4_stage_lanes is compiled on its own, not inlined: numba's front end (typing and lowering, not LLVM:
# NUMBA_OPT=0 saves 10 %) grows faster than linearly in a function's size, and nine inlined stages made
# rk4_lanes_estimate 83 s of a 120 s cold start. Its stage number is a run-time int64 (_STAGE[k], not the
# literal k, which numba would compile once per value); ``first`` and ``estimate`` stay literal constants,
# so that their branches inside the lane loops are folded away and the loops stay vectorised: four
# specialisations, (True, 0), (True, 1), (False, 0), (False, 4).
_STAGE = tuple(np.int64(k) for k in range(5))


@njit(cache=True, nogil=True, error_model="numpy")
def rk4_stage_lanes(model, s, nl, stage, first, dt, estimate, inv_tol, v_ref):
    """RK4 stage ``stage`` (1..4) of lanes 0..nl-1 of the scratch s: the
    derivative at the stage state (rows QS, US) by the sweep of
    :func:`derivatives`, then the stage's update of (Q, QS, ACC), (U, US, ACCU),
    (X, XS, ACCX), (Y, YS, ACCY) and the power sums. ``first`` (a literal: stage == 1) starts the RK4
    sums and, with finite grip, sets the substep's traction scale. ``estimate`` (run-time): 1 compares
    this stage-1 derivative, the previous substep's k5, with the stored k4 into row H_ERR; 4 stores k4;
    0 neither.

    The link loop is outermost: the channels of link k are read from block k
    and those of link k+1 written to block k+1. ``error_model="numpy"``: a
    singular or NaN state gives inf/NaN (caught by the caller's finite check)
    instead of an exception, and keeps the loops free of exits.
    """
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, stall, inv_w0, t_max, grip, rotor, braking = model
    n = m.shape[0]
    motor = t_max < math.inf
    geared = rotor.shape[0] > 0
    traction = grip.shape[0] > 0  # finite grip: stage 1 sets the substep's traction scale (traction_derivatives)
    last = stage == 4
    c = dt if stage == 3 else 0.5 * dt
    compare = estimate == 1  # this stage's k1 is the previous substep's k5: compare it with the stored k4
    keep = estimate == 4  # store this stage's k4
    sixth = dt / 6.0
    use_limit = limit > 0.0
    inv_room = inverse_room(limit)
    lanes = _U(nl)
    b0 = lane_block(0)
    if first:
        if traction:  # the sweep at scale 0: the passive torques alone (the motors' share kept apart)
            for l in range(lanes):
                s[_H_SCALE_OLD + l] = s[_H_SCALE + l]
                s[_H_SCALE + l] = 0.0
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
        s[b0 + _B_PM + l] = 0.0
        s[b0 + _B_SC + l] = s[_H_SCALE + l]
        s[b0 + _B_ERR + l] = s[_H_ERR + l]
        if first:
            s[b0 + _B_RA0 + l] = 0.0
            s[b0 + _B_RA1 + l] = 0.0
            s[b0 + _B_PA + l] = 0.0
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
        jr = rotor[k] if joint and geared else 0.0
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
            pm = s[o + _B_PM + l]
            r0 = s[o + _B_R0 + l] + (f * a1 - (mk * a1 * Vb + Ik * b1 * Wb))
            r1 = s[o + _B_R1 + l] + (f * a2 - (mk * a2 * Vb + Ik * b2 * Wb))
            # theta_k is not read again in this stage: its update goes here (qdot_k = omega_k)
            phi = s[p + _B_QS + l] - s[o + _B_QS + l]
            # the estimate's rows, stored unconditionally (a select, not a branch: the loop stays vectorised)
            k4 = s[o + _B_K4 + l]
            e = abs(sixth * (k4 - W)) * inv_tol  # rad / (tol * 1 rad)
            err = s[o + _B_ERR + l]
            s[p + _B_ERR + l] = e if compare and e > err else err
            s[o + _B_K4 + l] = W if keep else k4
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
                    T = motor_torque(T, phidot, stall, inv_w0, t_max, braking)
                # the traction scale: 1 without grip (bit for bit A); with grip 0 in the stage-1 sweep, then
                # the substep's (read, not branched on, so that the lane loop stays one vectorised loop)
                A = T
                pm += abs(A * phidot)
                scale = s[o + _B_SC + l]
                s[p + _B_SC + l] = scale
                T = scale * A
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
                if first:  # the motors' share and what the backward sweep reads (used with grip only)
                    s[p + _B_RA0 + l] = s[o + _B_RA0 + l] + A * (nb1 - b1)
                    s[p + _B_RA1 + l] = s[o + _B_RA1 + l] + A * (nb2 - b2)
                    s[p + _B_PA + l] = s[o + _B_PA + l] + A * phidot
                    s[o + _B_TA + l] = A
                    s[o + _B_TP + l] = T
                    s[o + _B_C + l] = C
                    s[o + _B_S + l] = S
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
            s[p + _B_PM + l] = pm
            if first:
                if not joint:
                    s[p + _B_RA0 + l] = s[o + _B_RA0 + l]
                    s[p + _B_RA1 + l] = s[o + _B_RA1 + l]
                    s[p + _B_PA + l] = s[o + _B_PA + l]
        if joint and geared:  # the rotor's inertia on phi_k, as in _kane_sweep: a lane loop of its own, so that
            # the loop above carries no branch for it when the rotors are massless
            for l in range(lanes):
                d1 = s[p + _B_B1 + l] - s[o + _B_B1 + l]
                d2 = s[p + _B_B2 + l] - s[o + _B_B2 + l]
                jb = jr * (s[p + _B_WB + l] - s[o + _B_WB + l])
                s[p + _B_M00 + l] = s[p + _B_M00 + l] + jr * d1 * d1
                s[p + _B_M01 + l] = s[p + _B_M01 + l] + jr * d1 * d2
                s[p + _B_M11 + l] = s[p + _B_M11 + l] + jr * d2 * d2
                s[p + _B_R0 + l] = s[p + _B_R0 + l] - jb * d1
                s[p + _B_R1 + l] = s[p + _B_R1 + l] - jb * d2
    if first:
        if traction:  # the scale; r and power of block n become those at the scale
            _traction_lanes(m, h, inertia, c_wheel, grip, rotor, s, lanes)
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
        du0, du1 = solve_eq8(M00, M01, M11, det, r0, r1)
        k5u0 = du0
        k5u1 = du1
        if traction:  # k5 at the finished substep's own scale (see traction_derivatives)
            k5u0, k5u1 = solve_eq8(M00, M01, M11, det, s[o + _B_DP0 + l], s[o + _B_DP1 + l])
        k4u0 = s[_H_K4U0 + l]
        k4u1 = s[_H_K4U1 + l]
        e0 = abs(sixth * (k4u0 - k5u0)) * inv_tol / (abs(s[_H_U0 + l]) + v_ref)
        e1 = abs(sixth * (k4u1 - k5u1)) * inv_tol / (abs(s[_H_U1 + l]) + 1.0)
        e = e0 if e0 > e1 else e1
        err = s[o + _B_ERR + l]  # the links' maximum, carried to block n
        s[_H_ERR + l] = e if compare and e > err else err
        s[_H_K4U0 + l] = du0 if keep else k4u0
        s[_H_K4U1 + l] = du1 if keep else k4u1
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
        # the motors' energy likewise, from |A phidot| at the substep's traction scale (1 without grip;
        # in stage 1 with grip the scale _traction_lanes just set)
        pmot = s[_H_SCALE + l] * s[o + _B_PM + l]
        macc = s[_H_MACC + l]
        motor = s[_H_MOTOR + l]
        s[_H_MOTOR + l] = motor + sixth * (macc + pmot) if last else motor
        s[_H_MACC + l] = pmot if first else macc + 2.0 * pmot


@njit(cache=True, nogil=True, error_model="numpy")
def _traction_lanes(m, h, inertia, c_wheel, grip, rotor, s, lanes):
    """The traction scale of :func:`traction_derivatives` for every lane, after a stage-1 sweep at
    scale 0 that kept the motors' share apart (rows B_TA, B_TP, B_C, B_S, B_RA0, B_RA1, B_PA):
    the backward sweep from link n to 1 carries udot at scale 0, the motors' udot, the two pin
    forces and the least room in block rows; then row H_SCALE gets the scale, and block n's r and
    power become those at the scale. The same operations in the same order as the per-snake kernel."""
    n = m.shape[0]
    geared = rotor.shape[0] > 0
    o = lane_block(n)
    for l in range(lanes):
        M00 = s[o + _B_M00 + l]
        M01 = s[o + _B_M01 + l]
        M11 = s[o + _B_M11 + l]
        r0 = s[o + _B_R0 + l]
        r1 = s[o + _B_R1 + l]
        ra0 = s[o + _B_RA0 + l]
        ra1 = s[o + _B_RA1 + l]
        det = M00 * M11 - M01 * M01
        s[o + _B_DP0 + l], s[o + _B_DP1 + l] = solve_eq8(M00, M01, M11, det, r0, r1)
        s[o + _B_G0 + l], s[o + _B_G1 + l] = solve_eq8(M00, M01, M11, det, ra0, ra1)
        s[o + _B_FA + l] = 0.0
        s[o + _B_FP + l] = 0.0
        s[o + _B_GA + l] = 0.0
        s[o + _B_GP + l] = 0.0
        s[o + _B_ROOM + l] = 1.0
    if geared:  # the rotors take J_r phiddot of the joints' torques (traction_derivatives): the passive and the
        # motors' torques in rows TP, TA become what reaches the links, at udot of scale 0 and the motors' udot
        for j in range(n - 1):
            oj = lane_block(j)
            pj = oj + _NEXT
            jr = rotor[j]
            for l in range(lanes):
                d1 = s[pj + _B_B1 + l] - s[oj + _B_B1 + l]
                d2 = s[pj + _B_B2 + l] - s[oj + _B_B2 + l]
                phib = s[pj + _B_WB + l] - s[oj + _B_WB + l]
                du0 = s[o + _B_DP0 + l]
                du1 = s[o + _B_DP1 + l]
                g0 = s[o + _B_G0 + l]
                g1 = s[o + _B_G1 + l]
                s[oj + _B_TP + l] = s[oj + _B_TP + l] - jr * (d1 * du0 + d2 * du1 + phib)
                s[oj + _B_TA + l] = s[oj + _B_TA + l] - jr * (d1 * g0 + d2 * g1)
    for k in range(n - 1, -1, -1):
        o = lane_block(k)
        x = o + _NEXT  # link k+1's block: the carried values
        # joint k-1, between links k-1 and k: read only for k > 0, but its address is always one block
        # back (in the header for k = 0), a constant distance from o, so the lane loop vectorises
        i = o - _NEXT
        inner = k > 0
        outer = k < n - 1
        mk = m[k]
        Ik = inertia[k]
        hk = h[k]
        cwk = c_wheel[k]
        gk = grip[k]
        for l in range(lanes):
            du0 = s[x + _B_DP0 + l]
            du1 = s[x + _B_DP1 + l]
            g0 = s[x + _B_G0 + l]
            g1 = s[x + _B_G1 + l]
            s[o + _B_DP0 + l] = du0
            s[o + _B_DP1 + l] = du1
            s[o + _B_G0 + l] = g0
            s[o + _B_G1 + l] = g1
            V = s[o + _B_V + l]
            W = s[o + _B_W + l]
            a1 = s[o + _B_A1 + l]
            a2 = s[o + _B_A2 + l]
            b1 = s[o + _B_B1 + l]
            b2 = s[o + _B_B2 + l]
            Vdot = a1 * du0 + a2 * du1 + s[o + _B_VB + l]
            alpha = b1 * du0 + b2 * du1 + s[o + _B_WB + l]
            Vdot_g = a1 * g0 + a2 * g1
            alpha_g = b1 * g0 + b2 * g1
            P_in = s[i + _B_TP + l] if inner else 0.0
            P_out = s[o + _B_TP + l] if outer else 0.0
            A_in = s[i + _B_TA + l] if inner else 0.0
            A_out = s[o + _B_TA + l] if outer else 0.0
            Fa = s[x + _B_FA + l]
            Fp = s[x + _B_FP + l]
            Ga = s[x + _B_GA + l]
            Gp = s[x + _B_GP + l]
            mVW = mk * V * W
            lam0 = (Ik * alpha - P_in + P_out) / hk - 2.0 * Fp + mVW
            lamg = (Ik * alpha_g - A_in + A_out) / hk - 2.0 * Gp
            s[o + _B_L0 + l] = lam0
            s[o + _B_LG + l] = lamg
            Fa += -cwk * V - mk * Vdot
            Fp += lam0 - mVW
            Ga += -mk * Vdot_g
            Gp += lamg
            if inner:
                C = s[i + _B_C + l]
                S = s[i + _B_S + l]
                Fa, Fp = Fa * C - Fp * S, Fa * S + Fp * C
                Ga, Gp = Ga * C - Gp * S, Ga * S + Gp * C
            s[o + _B_FA + l] = Fa
            s[o + _B_FP + l] = Fp
            s[o + _B_GA + l] = Ga
            s[o + _B_GP + l] = Gp
            room = grip_room(lam0, lamg, gk)
            least = s[x + _B_ROOM + l]
            s[o + _B_ROOM + l] = room if room < least else least
    b0 = lane_block(0)
    o = lane_block(n)
    for l in range(lanes):
        scale = s[b0 + _B_ROOM + l]
        s[_H_SCALE + l] = scale
        # r at the previous substep's scale, for the error estimate (rows free again: DP of block n)
        old = s[_H_SCALE_OLD + l]
        s[o + _B_DP0 + l] = s[o + _B_R0 + l] + old * s[o + _B_RA0 + l]
        s[o + _B_DP1 + l] = s[o + _B_R1 + l] + old * s[o + _B_RA1 + l]
        s[o + _B_R0 + l] = s[o + _B_R0 + l] + scale * s[o + _B_RA0 + l]
        s[o + _B_R1 + l] = s[o + _B_R1 + l] + scale * s[o + _B_RA1 + l]
        s[o + _B_PW + l] = s[o + _B_PW + l] + scale * s[o + _B_PA + l]


@njit(cache=True, nogil=True, inline="always")
def lane_wheel_forces(s, lane, n, out):
    """Lane ``lane``'s wheel forces (N) from the last traction pass (rows B_L0, B_LG, H_SCALE) into out
    (n,), lambda_k = lambda_0 + s lambda_g as :func:`traction_derivatives` forms them; returns s."""
    scale = s[_H_SCALE + lane]
    for k in range(n):
        o = lane_block(k)
        out[k] = s[o + _B_L0 + lane] + scale * s[o + _B_LG + lane]
    return scale


@njit(cache=True, nogil=True, error_model="numpy")
def rk4_lanes(model, s, nl, dt, n_substeps):
    """``n_substeps`` RK4 steps of lanes 0..nl-1 (loaded by :func:`load_lanes`);
    the work of the loads is added to row H_WORK.

    The four stages call the one compiled stage function (see _STAGE)."""
    for _ in range(n_substeps):
        rk4_stage_lanes(model, s, nl, _STAGE[1], True, dt, _STAGE[0], 0.0, 1.0)
        rk4_stage_lanes(model, s, nl, _STAGE[2], False, dt, _STAGE[0], 0.0, 1.0)
        rk4_stage_lanes(model, s, nl, _STAGE[3], False, dt, _STAGE[0], 0.0, 1.0)
        rk4_stage_lanes(model, s, nl, _STAGE[4], False, dt, _STAGE[0], 0.0, 1.0)


# inline="always": numba links the compiled code of every callee into each caller and optimises it there
# again, so each dispatcher level between the env step and rk4_stage_lanes recompiles the stages
@njit(cache=True, nogil=True, error_model="numpy", inline="always")
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
    rk4_stage_lanes(model, s, nl, _STAGE[1], True, dt, _STAGE[0], inv_tol, v_ref)
    rk4_stage_lanes(model, s, nl, _STAGE[2], False, dt, _STAGE[0], inv_tol, v_ref)
    rk4_stage_lanes(model, s, nl, _STAGE[3], False, dt, _STAGE[0], inv_tol, v_ref)
    rk4_stage_lanes(model, s, nl, _STAGE[4], False, dt, _STAGE[4], inv_tol, v_ref)
    for _ in range(1, n_substeps):
        rk4_stage_lanes(model, s, nl, _STAGE[1], True, dt, _STAGE[1], inv_tol, v_ref)
        rk4_stage_lanes(model, s, nl, _STAGE[2], False, dt, _STAGE[0], inv_tol, v_ref)
        rk4_stage_lanes(model, s, nl, _STAGE[3], False, dt, _STAGE[0], inv_tol, v_ref)
        rk4_stage_lanes(model, s, nl, _STAGE[4], False, dt, _STAGE[4], inv_tol, v_ref)
    # k5 of the last substep: a stage 1 at the final state, which it leaves unchanged
    # (stage 1 writes only the stage state and the running sums)
    rk4_stage_lanes(model, s, nl, _STAGE[1], True, dt, _STAGE[1], inv_tol, v_ref)


@njit(cache=True, nogil=True)
def rk4_step_estimate(model, q, u, torques, dt, n_substeps, tol, v_ref, stop_above_tol=False):
    """:func:`rk4_step` with the error estimate of :func:`rk4_lanes_estimate`;
    returns (work of all loads (J), error estimate / tolerance, the motors' energy (J): the integral of
    sum_k |s A_k phidot_k| by the same RK4 weights as the work, see :func:`derivatives_motor`).

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
    traction = model[11].shape[0] > 0
    links = np.empty((n, LINK_CHANNELS))
    lam = np.empty(n)
    du_old = np.empty(2)  # f(y1)'s udot at the substep's own traction scale, for the estimate
    work = 0.0
    motor = 0.0
    err = 0.0
    scale = 1.0
    if traction:  # the traction scale of each substep is set at its start (see rk4_step_workspace)
        # the defaults given explicitly: one compiled specialisation for every caller (~2 s cold each)
        p1, scale, m1 = traction_derivatives(model, q, u, torques, kq, ku, links, lam, 1.0, np.empty(0))
    else:
        p1, m1 = derivatives_motor(model, q, u, torques, kq, ku, 1.0)
    for i in range(n_substeps):
        # stage 1 at (q, u): kq, ku hold it (computed at the end of the previous substep)
        for j in range(nq):
            acc_q[j] = kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] = ku[0]
        acc_u[1] = ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        p2, m2 = derivatives_motor(model, qs, us, torques, kq, ku, scale)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        p3, m3 = derivatives_motor(model, qs, us, torques, kq, ku, scale)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + dt * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + dt * ku[0]
        us[1] = u[1] + dt * ku[1]
        p4, m4 = derivatives_motor(model, qs, us, torques, kq, ku, scale)
        for j in range(nq):
            q[j] += sixth * (acc_q[j] + kq[j])
            k4q[j] = kq[j]
        u[0] += sixth * (acc_u[0] + ku[0])
        u[1] += sixth * (acc_u[1] + ku[1])
        k4u[0] = ku[0]
        k4u[1] = ku[1]
        work += sixth * (p1 + 2.0 * p2 + 2.0 * p3 + p4)
        motor += sixth * (m1 + 2.0 * m2 + 2.0 * m3 + m4)
        # k5 = f(y_{n+1}), the next substep's k1 (FSAL); with grip the estimate takes k5's udot at
        # this substep's scale (du_old), the next substep its own
        if traction:
            p1, scale, m1 = traction_derivatives(model, q, u, torques, kq, ku, links, lam, scale, du_old)
        else:
            p1, m1 = derivatives_motor(model, q, u, torques, kq, ku, 1.0)
            du_old[0] = ku[0]
            du_old[1] = ku[1]
        for k in range(n):
            e = abs(sixth * (k4q[k] - kq[k])) * inv_tol
            err = e if e > err else err
        e0 = abs(sixth * (k4u[0] - du_old[0])) * inv_tol / (abs(u[0]) + v_ref)
        e1 = abs(sixth * (k4u[1] - du_old[1])) * inv_tol / (abs(u[1]) + 1.0)
        err = e0 if e0 > err else err
        err = e1 if e1 > err else err
        if stop_above_tol and err > 1.0:
            break
    return work, err, motor


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
        s[_H_MOTOR + l] = 0.0
        s[_H_SCALE + l] = 1.0  # the motors' torques in full; with grip each substep sets its traction scale


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
