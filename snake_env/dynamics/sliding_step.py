"""Wheels that slide, stepped fast: the unconstrained chain with exact Coulomb friction, time-stepped.

:mod:`.sliding` integrates the sliding-wheel model with Coulomb's law regularised over a slip speed,
a stiff ODE that needs an implicit integrator (scipy's LSODA) and takes 0.1-0.3 s per env step. Here
the same chain (eqs. 22-25: q = (theta_1..theta_n, x, y), n + 2 degrees of freedom) meets the wheels'
friction without regularisation, as rigid-body simulators with contacts do (Moreau's and Stewart &
Trinkle's velocity-level time stepping; MuJoCo and Bullet solve the same kind of problem). Over a
substep h (s), with the loads Q and the bias B of eq. 24 at the substep's start,

    M (qdot+ - qdot) = h (Q - B) + A^T p,        q+ = q + h qdot+                     (semi-implicit Euler)

and the wheels' lateral impulses p_k (N s, along e_k_perp; A is eq. 26's constraint matrix) obey
Coulomb's law at the substep's end, w = A qdot+ the wheels' lateral velocities (m/s):

    |p_k| < mu m_k g h  and  w_k = 0      (the wheel grips), or
    p_k = -mu m_k g h sign(w_k)            (the wheel slides, friction against the slide).

With D = A M^-1 A^T (the wheels' Delassus matrix, symmetric positive definite) and b = A qdot* + h Adot qdot
(qdot* = qdot + h M^-1 (Q - B) the free velocity; the second term carries each wheel's lateral velocity into
its link's frame a substep on, so that a gripping wheel accelerates as eq. 27's A qddot = -Adot qdot says),
w = b + D p: a box-constrained linear complementarity problem. D is positive definite, so its solution is
unique (a strictly convex quadratic program; its primal: qdot+ minimises 1/2 (v - qdot*)^T M (v - qdot*) +
sum_k mu m_k g h |A_k v + c_k|, c = h Adot qdot). It is solved by active sets, exactly to rounding: from the
last substep's sliding wheels, the gripping wheels are held at w_k = 0 and the sliding ones at their friction;
a wheel that needs more than its grip slides, a sliding wheel whose velocity runs with its friction grips again
(one solve when nothing changes, the common case). Three formulations of that solve, equal to rounding (tested),
the O(n) one compiled in a kernel of its own (``ADVANCE_ROWS``), so that a first step compiles only it:

- :func:`_recursive_solve` (the default, O(n) per iteration): dynamic programming along the chain from the tail,
  as the articulated-body algorithm does for M^-1; each link's angular rate is an affine function of the joint
  before it, fixed by its wheel if it grips, minimising if it slides;
- :func:`_null_space_solve` (with rotors, whose inertia couples neighbouring joints; O(n m^2), m = 2 + the sliding
  wheels): the same minimisation over an explicit basis of the gripping wheels' null space;
- :func:`_delassus_solve` (O(n^3)): the gripping wheels' block of D by Cholesky, and projected Gauss-Seidel to a
  residual of ``PGS_TOLERANCE`` where active sets do not settle; where the other two fail, their callers step
  the snake again with it.

As mu grows every wheel grips and the step becomes a velocity projection onto the no-slip constraint:
its trajectories converge to eq. 27's as h -> 0 (tested against the Kane sweep). Friction is implicit,
so there is no stiff lateral time constant to resolve: h follows from the joints' own rates (motor,
dampings, joint-limit barrier), not from the friction.

The loads are those of the env's physics and of :class:`.sliding.SlidingWheels`: the joint motors'
torque-speed band and current limit (:func:`.motor.motor_torque`), joint and wheel damping, the
joint-limit barrier, the rotors' inertia in M. M and B are O(n^2) through model constants
(``G[a, b] = sum_k m_k c_ka c_kb``, c the lever arms of :func:`.lagrange.lever_arms`), so that
M_ab = G_ab e_a_perp . e_b_perp + I_a delta_ab, M_a,xy = g_a e_a_perp with g_a = sum_k m_k c_ka, and
B_a = -sum_j G_aj thetadot_j^2 e_a_perp . e_j (the Delassus solve's terms; the other two take the same loads link
by link: each CM's velocity and centripetal acceleration by the chain's recursion, O(n)).

Energy: with M frozen over a substep, Delta K = (h (Q - B) + A^T p) . (qdot + qdot+) / 2 exactly, and
B's share cancels M's change to O(h^2): the step's ``work`` and ``friction_work`` sum those two
trapezoid terms, and Delta K - work - friction_work -> 0 as h -> 0 (tested).
"""

from __future__ import annotations

import math
from functools import partial

import numpy as np
from numba import njit

from .compiled import barrier_torque
from .motor import motor_torque

PGS_TOLERANCE = 1e-12  # m/s: largest violation of Coulomb's law by the wheels' lateral velocities after a solve
PGS_MAX_SWEEPS = 5000  # projected Gauss-Seidel sweeps at most; beyond them the step reports failure (NaN)
# m/s: a wheel slides when its lateral velocity at a substep's end exceeds this (a gripping wheel's is zero to
# the solver's tolerance, ~1e-12 m/s; one that has just broken away and moves slower grips at its limit)
SLIDE_SPEED = 1e-6


# The three calls of every substep (_substep_loads, the friction solve _recursive_solve, _substep_end) are inlined
# into the row kernels. Each passes ~25 arrays, and a call of a compiled function handles every array argument
# (its reference count, most likely) on the way in and out: at n = 5 the calls cost about a third of a substep.
# Inlined, a substep takes 1.7x, 1.5x, 1.35x and 1.2x less time at n = 3, 5, 12 and 30, with the same bits
# (docs/benchmarks.md); the cold start did not move beyond its noise.
SUBSTEP_CALLS_INLINED = ("_substep_loads", "_recursive_solve", "_substep_end")


def solve_method(rotor) -> int:
    """The fastest friction solve (``advance``'s ``method``) for a rotor inertia matrix: the O(n) recursion
    without rotors, the null-space solve with them (their inertia couples neighbouring joints)."""
    return 1 if np.any(np.asarray(rotor) != 0.0) else 0


def inertia_constants(mass, lever):
    """(G (n, n), g (n,)): G_ab = sum_k m_k c_ka c_kb (kg m^2), g_a = sum_k m_k c_ka (kg m), the model
    constants of M and B (module doc)."""
    G = np.einsum("k,ka,kb->ab", mass, lever, lever)
    return np.ascontiguousarray(G), np.ascontiguousarray(mass @ lever)


@njit(cache=True, nogil=True)
def _cholesky(M, L):
    """L L^T = M (lower triangular L, in place); False if M is not positive definite."""
    N = M.shape[0]
    for i in range(N):
        for j in range(i + 1):
            s = M[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
        for j in range(i + 1, N):
            L[i, j] = 0.0
    return True


@njit(cache=True, nogil=True)
def _forward(L, x):
    """x <- L^-1 x."""
    N = L.shape[0]
    for i in range(N):
        s = x[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, nogil=True)
def _backward(L, x):
    """x <- L^-T x."""
    N = L.shape[0]
    for i in range(N - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, N):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]


@njit(cache=True, nogil=True)
def joint_torques(command, phi, phidot, c_joint, stall, inv_no_load, t_max, braking, joint_limit, k_lim, c_lim,
                  inv_room, out, motor):
    """The joints' torques (N m, (n-1,)) into ``out``: the motor's for ``command`` (N m), less damping and the
    joint-limit barrier, as the env's kernels and :meth:`.sliding.SlidingWheels.joint_torques` give them; the
    motors' own share (after their band and current limit) into ``motor``."""
    for k in range(phi.shape[0]):
        T = command[k]
        if t_max < math.inf:
            T = motor_torque(T, phidot[k], stall, inv_no_load, t_max, braking)
        motor[k] = T
        if joint_limit > 0.0 and abs(phi[k]) > joint_limit:
            T -= barrier_torque(phi[k], phidot[k], joint_limit, k_lim, c_lim, inv_room)
        out[k] = T - c_joint[k] * phidot[k]


def advance(q, qdot, command, G, g, total_mass, inertia, lever, grip, c_joint, c_wheel, stall, inv_no_load, t_max,
            braking, joint_limit, k_lim, c_lim, inv_room, rotor, mass, h, substeps, impulse, stats, sliding_substeps,
            lateral, method=None) -> bool:
    """``substeps`` substeps of h (s) of the module doc's scheme with ``command`` (n-1,) (N m) held, for one snake.

    q, qdot ((n+2,) each) and ``impulse`` (n,) (the last substep's p, N s; also the solver's warm start) are
    updated in place. ``stats`` (5,) gets += (work of every load but friction (J), friction's work (J), the
    largest count of active-set iterations (or PGS sweeps), substeps solved by the Delassus solve, the motors'
    energy (J): sum_k |A_k phidot_k| h with A_k the torque the motor delivers); ``sliding_substeps`` (n,) counts
    per wheel the substeps it slid (|w_k| > SLIDE_SPEED); ``lateral`` (n,) gets the wheels' slip velocities
    w = b + D p (m/s, the module doc's) of the last substep. total_mass: sum_k m_k (kg); grip: mu m_k g (N, (n,));
    rotor: (n+2, n+2) rotor inertia matrix; mass: m_k (kg, (n,)). ``method``: the friction solve, an index into
    ``ADVANCE_ROWS`` (0 the O(n) recursion, no rotors; 1 the null-space solve; 2 the Delassus solve), by default
    :func:`solve_method`'s. Returns False (state left NaN) if the solve failed: M (or S^T M S) lost definiteness,
    or the active sets (and, in the Delassus solve, Gauss-Seidel) did not settle. The callers then retry with the
    Delassus solve."""
    kernel = ADVANCE_ROWS[solve_method(rotor) if method is None else method]
    ok = kernel(q[None], qdot[None], np.ascontiguousarray(command, dtype=np.float64)[None], G, g, total_mass, inertia,
                lever, grip, c_joint, c_wheel, stall, inv_no_load, t_max, braking, joint_limit, k_lim, c_lim, inv_room,
                rotor, mass, np.array([h], dtype=np.float64), np.array([substeps], dtype=np.int64),
                np.zeros(1, np.int64), impulse[None], stats[None], sliding_substeps[None], lateral[None], np.zeros((1, 2)))
    return bool(ok[0])


@njit(cache=True, nogil=True)
def _half_lengths(lever):
    """h_k (m, (n,)) from the lever arms (c[k, 0] = h_0, c[k, k] = h_k; :func:`.lagrange.lever_arms`)."""
    n = lever.shape[0]
    half = np.empty(n)
    half[0] = lever[1, 0] if n > 1 else 0.0
    for k in range(1, n):
        half[k] = lever[k, k]
    return half


@njit(cache=True, nogil=True)
def _warm_state(impulse, grip, h):
    """Each wheel's state from the warm start (the last substep's impulses): 0 grips; +1 / -1 slides with p at
    +bound / -bound."""
    n = impulse.shape[0]
    state = np.empty(n, np.int64)
    for k in range(n):
        bound = grip[k] * h
        state[k] = 1 if impulse[k] >= bound * (1.0 - 1e-12) else (-1 if impulse[k] <= -bound * (1.0 - 1e-12) else 0)
    return state


@njit(cache=True, nogil=True, inline="always")  # per substep: see SUBSTEP_CALLS_INLINED
def _substep_loads(q, qdot, command, grip, c_joint, c_wheel, stall, inv_no_load, t_max, braking, joint_limit, k_lim,
                   c_lim, inv_room, mass, h, half, cos, sin, phi, phidot, T, A, torque, bounds, V, acc, E, cterm):
    """A substep's loads, link by link, into the arrays after ``half``: the joints' torques T (N m; the motors'
    share A) and each link's net joint torque, the wheels' impulse bounds mu m_k g h (N s), every CM's velocity
    V and centripetal acceleration (:func:`_link_velocities`, :func:`_centripetal`), E_k = rolling resistance
    less m_k acc_k (N, the link's share of Q - B) and cterm = h Adot qdot (m/s)."""
    n = q.shape[0] - 2
    for k in range(n):
        cos[k] = math.cos(q[k])
        sin[k] = math.sin(q[k])
    for k in range(n - 1):
        phi[k] = q[k + 1] - q[k]
        phidot[k] = qdot[k + 1] - qdot[k]
    joint_torques(command, phi, phidot, c_joint, stall, inv_no_load, t_max, braking, joint_limit, k_lim, c_lim,
                  inv_room, T, A)
    for k in range(n):
        torque[k] = (T[k - 1] if k > 0 else 0.0) - (T[k] if k < n - 1 else 0.0)
        bounds[k] = grip[k] * h
    _link_velocities(qdot, cos, sin, half, V)
    _centripetal(qdot, cos, sin, half, acc)
    for k in range(n):
        speed = cos[k] * V[k, 0] + sin[k] * V[k, 1]  # V_k = e_k . rdot_k (m/s), the CM's speed along its link
        roll = -c_wheel[k] * speed  # rolling resistance -c_w V_k e_k at CM_k (N)
        E[k, 0] = roll * cos[k] - mass[k] * acc[k, 0]
        E[k, 1] = roll * sin[k] - mass[k] * acc[k, 1]
        # + h Adot qdot: the wheel's lateral velocity a substep on, in the link's turned frame (eq. 27's
        # -Adot qdot; without it a gripping wheel's acceleration would miss it by O(1)); acc_k's lateral
        # part is -(Adot qdot)'s centripetal share
        cterm[k] = h * (-qdot[k] * speed + (-sin[k] * acc[k, 0] + cos[k] * acc[k, 1]))


@njit(cache=True, nogil=True, inline="always")  # per substep: see SUBSTEP_CALLS_INLINED
def _substep_end(q, qdot, v_new, V, V_new, T, A, phidot, cos, sin, c_wheel, impulse, lateral, h, iterations, stats,
                 sliding_substeps):
    """The end of a substep whose solve gave v_new (V_new): the work counters of ``stats`` (the trapezoid terms of
    the module doc), the sliding wheels' count, and (q, qdot) moved on (semi-implicit Euler)."""
    n = q.shape[0] - 2
    N = n + 2
    stats[2] = max(stats[2], iterations)
    # the trapezoid work terms (module doc) as the loads' power: the joint torques on the joint rates, the
    # rolling resistance on the CMs' velocities, friction on the wheels' lateral velocities
    work = 0.0
    for k in range(n - 1):
        work += T[k] * 0.5 * (phidot[k] + v_new[k + 1] - v_new[k])
    friction = 0.0
    motor_energy = 0.0  # |A_k phidot_k| by the trapezoid of the joint rates, as the work
    for k in range(n):
        speed = cos[k] * V[k, 0] + sin[k] * V[k, 1]
        roll = -c_wheel[k] * speed
        work += roll * 0.5 * (speed + cos[k] * V_new[k, 0] + sin[k] * V_new[k, 1])
        wk_old = -sin[k] * V[k, 0] + cos[k] * V[k, 1]
        wk_new = -sin[k] * V_new[k, 0] + cos[k] * V_new[k, 1]
        friction += impulse[k] * 0.5 * (wk_old + wk_new)
        if abs(lateral[k]) > SLIDE_SPEED:
            sliding_substeps[k] += 1
    for k in range(n - 1):
        motor_energy += abs(A[k] * 0.5 * (phidot[k] + v_new[k + 1] - v_new[k])) * h
    for a in range(N):
        qdot[a] = v_new[a]
        q[a] += h * v_new[a]
    stats[0] += h * work
    stats[1] += friction
    stats[4] += motor_energy


@njit(cache=True, nogil=True)
def advance_rows(q, qdot, commands, G, g, total_mass, inertia, lever, grip, c_joint, c_wheel, stall,
                 inv_no_load, t_max, braking, joint_limit, k_lim, c_lim, inv_room, rotor, mass, h, substeps, rows,
                 impulse, stats, sliding_substeps, lateral, kinetic):
    """:func:`advance` by the O(n) recursive solve (chains without rotors), for the rows ``rows`` of a batch: q,
    qdot (B, n+2), commands (B, n-1), impulse, sliding_substeps and lateral (B, n) and stats (B, 5) in place, h and
    substeps (B,) per row, the rest as :func:`advance`; the kinetic energy before and after each step into ``kinetic`` (B, 2) (J).
    Returns ok (B,) (False: that row's solve failed and it is NaN)."""
    B, n = q.shape[0], q.shape[1] - 2
    N = n + 2
    half = _half_lengths(lever)
    cos, sin, bounds, torque, cterm = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    v_new = np.empty(N)
    phi, phidot, T, A = np.empty(n - 1), np.empty(n - 1), np.empty(n - 1), np.empty(n - 1)
    V, V_new, acc, E = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
    Ak, bk, alpha, beta, Zp = np.empty((n, 2, 2)), np.empty((n, 2)), np.empty((n, 2)), np.empty(n), np.empty((n, 2))
    K, Lk, f = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    ok = np.ones(B, np.bool_)
    for b in rows:
        kinetic[b, 0] = kinetic_energy(q[b], qdot[b], lever, mass, inertia, rotor)
        state = _warm_state(impulse[b], grip, h[b])
        for _ in range(substeps[b]):
            _substep_loads(q[b], qdot[b], commands[b], grip, c_joint, c_wheel, stall, inv_no_load, t_max, braking,
                           joint_limit, k_lim, c_lim, inv_room, mass, h[b], half, cos, sin, phi, phidot, T, A, torque,
                           bounds, V, acc, E, cterm)
            iterations = _recursive_solve(qdot[b], cos, sin, half, mass, inertia, rotor, V, E, torque, cterm, bounds,
                                          h[b], state, impulse[b], v_new, V_new, lateral[b], Ak, bk, alpha, beta, Zp,
                                          K, Lk, f)
            if iterations < 0:
                ok[b] = _fail(q[b], qdot[b])
                break
            _substep_end(q[b], qdot[b], v_new, V, V_new, T, A, phidot, cos, sin, c_wheel, impulse[b], lateral[b], h[b],
                         iterations, stats[b], sliding_substeps[b])
        kinetic[b, 1] = kinetic_energy(q[b], qdot[b], lever, mass, inertia, rotor) if ok[b] else math.nan
    return ok


@njit(cache=True, nogil=True)
def advance_rows_exact(q, qdot, commands, G, g, total_mass, inertia, lever, grip, c_joint, c_wheel, stall,
                       inv_no_load, t_max, braking, joint_limit, k_lim, c_lim, inv_room, rotor, mass, h, substeps, rows,
                       impulse, stats, sliding_substeps, lateral, kinetic, delassus):
    """:func:`advance_rows` by the null-space solve (any rotors) or, with ``delassus``, the Delassus solve (where
    another solve failed). The two rare paths share this kernel; the common one has its own, so that a first step
    compiles neither."""
    B, n = q.shape[0], q.shape[1] - 2
    N = n + 2
    half = _half_lengths(lever)
    cos, sin, bounds, torque, cterm = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    v_new = np.empty(N)
    phi, phidot, T, A = np.empty(n - 1), np.empty(n - 1), np.empty(n - 1), np.empty(n - 1)
    V, V_new, acc, E = np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2)), np.empty((n, 2))
    Sv, SV = np.empty((N + 1, N)), np.empty((N + 1, n, 2))  # the basis S (rows) and v_p (row m), and their CMs' V
    H, Lh, rhs, unit, dv = np.empty((N, N)), np.empty((N, N)), np.empty(N), np.empty(N), np.empty(N)
    Z, z = np.empty((n, 2)), np.empty(n)
    rotor_on = np.any(rotor != 0.0)
    ok = np.ones(B, np.bool_)
    for b in rows:
        kinetic[b, 0] = kinetic_energy(q[b], qdot[b], lever, mass, inertia, rotor)
        state = _warm_state(impulse[b], grip, h[b])
        for _ in range(substeps[b]):
            _substep_loads(q[b], qdot[b], commands[b], grip, c_joint, c_wheel, stall, inv_no_load, t_max, braking,
                           joint_limit, k_lim, c_lim, inv_room, mass, h[b], half, cos, sin, phi, phidot, T, A, torque,
                           bounds, V, acc, E, cterm)
            if delassus:
                iterations = _delassus_solve(q[b], qdot[b], cos, sin, G, g, total_mass, inertia, lever, c_wheel, rotor,
                                             T, h[b], bounds, state, impulse[b], v_new, lateral[b])
                if iterations >= 0:
                    _link_velocities(v_new, cos, sin, half, V_new)
                    stats[b, 3] += 1
            else:
                iterations = _null_space_solve(qdot[b], cos, sin, half, mass, inertia, rotor, rotor_on, V, E, torque,
                                               cterm, bounds, h[b], state, impulse[b], v_new, V_new, lateral[b], Sv,
                                               SV, H, Lh, rhs, unit, Z, z, dv)
            if iterations < 0:
                ok[b] = _fail(q[b], qdot[b])
                break
            _substep_end(q[b], qdot[b], v_new, V, V_new, T, A, phidot, cos, sin, c_wheel, impulse[b], lateral[b], h[b],
                         iterations, stats[b], sliding_substeps[b])
        kinetic[b, 1] = kinetic_energy(q[b], qdot[b], lever, mass, inertia, rotor) if ok[b] else math.nan
    return ok


@njit(cache=True, nogil=True)
def _link_velocities(v, cos, sin, half, V):
    """V (n, 2): every link's CM velocity (m/s) for the generalized velocities v (n+2,), J_k v by the chain's
    recursion: CM_0 moves with (xdot, ydot); the joint after link k moves with the one before plus L_k thetadot_k
    e_k_perp, and CM_k with the joint before it plus h_k thetadot_k e_k_perp (the lever arms of eq. 6)."""
    n = V.shape[0]
    px, py = v[n], v[n + 1]
    V[0, 0], V[0, 1] = px, py
    t = half[0] * v[0]
    px, py = px - t * sin[0], py + t * cos[0]
    for k in range(1, n):
        t = half[k] * v[k]
        V[k, 0], V[k, 1] = px - t * sin[k], py + t * cos[k]
        px, py = px - 2.0 * t * sin[k], py + 2.0 * t * cos[k]


@njit(cache=True, nogil=True)
def _centripetal(qdot, cos, sin, half, acc):
    """acc (n, 2): every CM's acceleration at zero angular accelerations and zero (xddot, yddot) (m/s^2),
    Jdot_k qdot = -sum_j c_kj thetadot_j^2 e_j, by the recursion of :func:`_link_velocities`."""
    n = acc.shape[0]
    acc[0, 0], acc[0, 1] = 0.0, 0.0
    t = half[0] * qdot[0] * qdot[0]
    px, py = -t * cos[0], -t * sin[0]
    for k in range(1, n):
        t = half[k] * qdot[k] * qdot[k]
        acc[k, 0], acc[k, 1] = px - t * cos[k], py - t * sin[k]
        px, py = px - 2.0 * t * cos[k], py - 2.0 * t * sin[k]



@njit(cache=True, nogil=True)
def _propagate(u, state, cos, sin, half, cterm, inhomogeneous, v, V):
    """v (n+2,) and V (n, 2) (every CM's velocity, m/s) of the velocities whose gripping wheels move sideways
    with w_k = 0, parametrised by u: u_0 = thetadot_0 (wheel 0 sits at CM_0, so it never constrains it), then
    link 0's speed along itself if wheel 0 grips or (xdot, ydot) if it slides, then thetadot_k of every sliding
    wheel k >= 1 in order. A gripping wheel k >= 1 fixes thetadot_k from the joint before it (eq. 26's row k,
    solved for its diagonal term h_k). ``inhomogeneous``: with A_k v = -cterm_k (the particular solution);
    else A_k v = 0 (a null-space basis vector)."""
    n = state.shape[0]
    v[0] = u[0]
    if state[0] == 0:
        lat = -cterm[0] if inhomogeneous else 0.0
        v[n], v[n + 1] = u[1] * cos[0] - lat * sin[0], u[1] * sin[0] + lat * cos[0]
        i = 2
    else:
        v[n], v[n + 1] = u[1], u[2]
        i = 3
    px, py = v[n], v[n + 1]
    V[0, 0], V[0, 1] = px, py
    t = half[0] * v[0]
    px, py = px - t * sin[0], py + t * cos[0]
    for k in range(1, n):
        if state[k] == 0:
            c = cterm[k] if inhomogeneous else 0.0
            v[k] = -(c + (-sin[k] * px + cos[k] * py)) / half[k]
        else:
            v[k] = u[i]
            i += 1
        t = half[k] * v[k]
        V[k, 0], V[k, 1] = px - t * sin[k], py + t * cos[k]
        px, py = px - 2.0 * t * sin[k], py + 2.0 * t * cos[k]


@njit(cache=True, nogil=True)
def _null_space_solve(qdot, cos, sin, half, mass, inertia, rotor, rotor_on, V, E, torque, cterm, bounds, h, state,
                      impulse, v_new, V_new, lateral, Sv, SV, H, Lh, rhs, unit, Z, z, dv):
    """The module doc's complementarity problem by active sets in the gripping wheels' null space, O(n m^2) with
    m = 2 + the sliding wheels (the Delassus solve is O(n^3)): for a guess of which wheels slide (``state``),
    qdot+ = v_p + S u minimises 1/2 (v - qdot*)^T M (v - qdot*) - p_s . A_s v over the velocities whose gripping
    wheels do not move sideways (v_p, S from :func:`_propagate`), so (S^T M S) u = S^T (M (qdot - v_p) + h (Q - B)
    + A_s^T p_s), every term a sum over the links of eq. 22's m_k, I_k and CM velocities. The gripping wheels'
    impulses then follow from each link's change of momentum, from the tail to the head (Newton-Euler on the
    substep's impulses, with the joints' reaction impulses eliminated). The active-set rules are
    :func:`_active_set`'s, so the solution is the same unique one, to rounding (tested). Fills v_new, V_new, impulse
    and lateral (w = A qdot+ + cterm, m/s); returns the iterations, or -1 if it did not settle within 2 n + 8 or
    S^T M S is not positive definite. The rotors act on the joint angles only (lagrange.rotor_inertia_matrix)."""
    n = V.shape[0]
    N = n + 2
    for iteration in range(2 * n + 8):
        m = 2
        for k in range(n):
            if state[k] != 0:
                m += 1
                impulse[k] = state[k] * bounds[k]
        for i in range(m):
            unit[i] = 0.0
        _propagate(unit, state, cos, sin, half, cterm, True, Sv[m], SV[m])  # the particular solution v_p
        for i in range(m):
            unit[i] = 1.0
            _propagate(unit, state, cos, sin, half, cterm, False, Sv[i], SV[i])
            unit[i] = 0.0
        # S^T (M (qdot - v_p) + h (Q - B) + A_s^T p_s) = sum_k Z_k . S V_k + z_k S thetadot_k
        for a in range(N):
            dv[a] = qdot[a] - Sv[m, a]
        for k in range(n):
            Z[k, 0] = mass[k] * (V[k, 0] - SV[m, k, 0]) + h * E[k, 0]
            Z[k, 1] = mass[k] * (V[k, 1] - SV[m, k, 1]) + h * E[k, 1]
            if state[k] != 0:
                Z[k, 0] -= impulse[k] * sin[k]
                Z[k, 1] += impulse[k] * cos[k]
            z[k] = inertia[k] * dv[k] + h * torque[k]
            if rotor_on:
                for c in range(n):
                    z[k] += rotor[k, c] * dv[c]
        for i in range(m):
            s = 0.0
            for k in range(n):
                s += Z[k, 0] * SV[i, k, 0] + Z[k, 1] * SV[i, k, 1] + z[k] * Sv[i, k]
            rhs[i] = s
            for j in range(i + 1):
                s = 0.0
                for k in range(n):
                    s += (mass[k] * (SV[i, k, 0] * SV[j, k, 0] + SV[i, k, 1] * SV[j, k, 1])
                          + inertia[k] * Sv[i, k] * Sv[j, k])
                if rotor_on:
                    for a in range(n):
                        for c in range(n):
                            s += Sv[i, a] * rotor[a, c] * Sv[j, c]
                H[i, j] = s
                H[j, i] = s
        if not _cholesky(H[:m, :m], Lh[:m, :m]):
            return -1
        _forward(Lh[:m, :m], rhs[:m])
        _backward(Lh[:m, :m], rhs[:m])
        for a in range(N):
            s = Sv[m, a]
            for i in range(m):
                s += rhs[i] * Sv[i, a]
            v_new[a] = s
        for k in range(n):
            sx, sy = SV[m, k, 0], SV[m, k, 1]
            for i in range(m):
                sx += rhs[i] * SV[i, k, 0]
                sy += rhs[i] * SV[i, k, 1]
            V_new[k, 0], V_new[k, 1] = sx, sy
        _wheel_impulses(qdot, cos, sin, half, mass, inertia, rotor, rotor_on, V, V_new, v_new, E, torque, h, state,
                        impulse)
        for k in range(n):
            lateral[k] = -sin[k] * V_new[k, 0] + cos[k] * V_new[k, 1] + cterm[k]
        if _switch(state, impulse, bounds, lateral):
            continue
        return iteration + 1
    return -1

@njit(cache=True, nogil=True, inline="always")  # per substep: see SUBSTEP_CALLS_INLINED
def _recursive_solve(qdot, cos, sin, half, mass, inertia, rotor, V, E, torque, cterm, bounds, h, state, impulse, v_new,
                     V_new, lateral, Ak, bk, alpha, beta, Zp, K, Lk, f):
    """:func:`_null_space_solve`'s problem in O(n) per active-set iteration, for chains without rotors: the
    same minimisation, 1/2 v^T M v - v . (M qdot + h (Q - B) + A_s^T p_s) over the velocities whose gripping wheels
    do not move sideways, by dynamic programming along the chain (as the articulated-body algorithm does for
    M^-1). The objective is a sum over the links of 1/2 m_k |V_k|^2 + 1/2 I_k thetadot_k^2 - Z_k . V_k -
    z_k thetadot_k (eq. 22's kinetic energy less the momentum and the impulses to reach), and link k's CM and the
    joint after it move with the joint before it, P_k, and thetadot_k (:func:`_link_velocities`). So, from the
    tail, the least value of the links k.. given P_k is a quadratic 1/2 P^T A_k P - b_k . P: a gripping wheel
    fixes thetadot_k as an affine function of P_k (eq. 26's row), a sliding one's thetadot_k minimises it (a
    scalar), and either way thetadot_k = alpha_k . P_k + beta_k. At the head, (xdot, ydot, thetadot_0) minimise
    what is left (a 3 x 3 problem, 2 x 2 if wheel 0 grips); a forward pass gives qdot+. The impulses and the
    active-set rules are :func:`_null_space_solve`'s. Returns the iterations, or -1 (not settled within 2 n + 8,
    or a head problem that is not positive definite). K, Lk (3, 3) and f (3,): the head problem's work arrays."""
    n = V.shape[0]
    for iteration in range(2 * n + 8):
        for k in range(n):
            if state[k] != 0:
                impulse[k] = state[k] * bounds[k]
            Zp[k, 0] = mass[k] * V[k, 0] + h * E[k, 0]
            Zp[k, 1] = mass[k] * V[k, 1] + h * E[k, 1]
            if state[k] != 0:
                Zp[k, 0] -= impulse[k] * sin[k]
                Zp[k, 1] += impulse[k] * cos[k]
        a00 = a01 = a11 = b0 = b1 = 0.0  # A_{k+1}, b_{k+1}: nothing beyond the tail
        for k in range(n - 1, 0, -1):
            hk, ex, ey = half[k], -sin[k], cos[k]  # e_k_perp
            z = inertia[k] * qdot[k] + h * torque[k]
            if state[k] == 0:  # e_k_perp . (P + h_k thetadot e_k_perp) = -cterm_k
                al0, al1, be = -ex / hk, -ey / hk, -cterm[k] / hk
            else:  # d/dthetadot of the links k.. = 0
                Ae0, Ae1 = a00 * ex + a01 * ey, a01 * ex + a11 * ey
                curv = mass[k] * hk * hk + inertia[k] + 4.0 * hk * hk * (ex * Ae0 + ey * Ae1)
                al0 = -(mass[k] * hk * ex + 2.0 * hk * Ae0) / curv
                al1 = -(mass[k] * hk * ey + 2.0 * hk * Ae1) / curv
                be = (hk * (Zp[k, 0] * ex + Zp[k, 1] * ey) + z + 2.0 * hk * (ex * b0 + ey * b1)) / curv
            alpha[k, 0], alpha[k, 1], beta[k] = al0, al1, be
            # V_k = T1 P + t1, P_{k+1} = T2 P + t2 (T = I + s e_perp alpha^T, t = s beta e_perp; s = h_k, 2 h_k)
            p00, p01, p10, p11 = 1.0 + hk * ex * al0, hk * ex * al1, hk * ey * al0, 1.0 + hk * ey * al1
            q00, q01, q10, q11 = 1.0 + 2 * hk * ex * al0, 2 * hk * ex * al1, 2 * hk * ey * al0, 1.0 + 2 * hk * ey * al1
            t1x, t1y, t2x, t2y = hk * be * ex, hk * be * ey, 2 * hk * be * ex, 2 * hk * be * ey
            # A' T2 and A' t2 - b'
            m00, m01 = a00 * q00 + a01 * q10, a00 * q01 + a01 * q11
            m10, m11 = a01 * q00 + a11 * q10, a01 * q01 + a11 * q11
            r0, r1 = a00 * t2x + a01 * t2y - b0, a01 * t2x + a11 * t2y - b1
            mk, ik = mass[k], inertia[k]
            n00 = mk * (p00 * p00 + p10 * p10) + ik * al0 * al0 + q00 * m00 + q10 * m10
            n01 = mk * (p00 * p01 + p10 * p11) + ik * al0 * al1 + q00 * m01 + q10 * m11
            n11 = mk * (p01 * p01 + p11 * p11) + ik * al1 * al1 + q01 * m01 + q11 * m11
            # b_k = -(m T1^T t1 + I alpha beta - T1^T Z - alpha z + T2^T (A' t2 - b'))
            c0 = mk * (p00 * t1x + p10 * t1y) + ik * al0 * be - (p00 * Zp[k, 0] + p10 * Zp[k, 1]) - al0 * z \
                + q00 * r0 + q10 * r1
            c1 = mk * (p01 * t1x + p11 * t1y) + ik * al1 * be - (p01 * Zp[k, 0] + p11 * Zp[k, 1]) - al1 * z \
                + q01 * r0 + q11 * r1
            Ak[k, 0, 0], Ak[k, 0, 1], Ak[k, 1, 1], bk[k, 0], bk[k, 1] = n00, n01, n11, -c0, -c1
            a00, a01, a11, b0, b1 = n00, n01, n11, -c0, -c1
        # the head: x = (xdot, ydot, thetadot_0), P_1 = (xdot, ydot) + h_0 thetadot_0 e_0_perp = W x
        h0, ex, ey = half[0], -sin[0], cos[0]
        w0, w1 = h0 * ex, h0 * ey  # W's third column
        K[0, 0], K[0, 1], K[1, 1] = mass[0] + a00, a01, mass[0] + a11
        K[0, 2] = a00 * w0 + a01 * w1
        K[1, 2] = a01 * w0 + a11 * w1
        K[2, 2] = inertia[0] + w0 * K[0, 2] + w1 * K[1, 2]
        K[1, 0], K[2, 0], K[2, 1] = K[0, 1], K[0, 2], K[1, 2]
        f[0] = Zp[0, 0] + b0
        f[1] = Zp[0, 1] + b1
        f[2] = inertia[0] * qdot[0] + h * torque[0] + w0 * b0 + w1 * b1
        if state[0] == 0:  # (xdot, ydot) = v_f e_0 + lat e_0_perp with lat = -cterm_0: solve for (v_f, thetadot_0)
            lat = -cterm[0]
            c, s = cos[0], sin[0]
            fx = f[0] - (K[0, 0] * ex + K[0, 1] * ey) * lat
            fy = f[1] - (K[1, 0] * ex + K[1, 1] * ey) * lat
            ft = f[2] - (K[2, 0] * ex + K[2, 1] * ey) * lat
            r00 = c * (K[0, 0] * c + K[0, 1] * s) + s * (K[1, 0] * c + K[1, 1] * s)
            r01 = c * K[0, 2] + s * K[1, 2]
            r11 = K[2, 2]
            g0, g1 = c * fx + s * fy, ft
            det = r00 * r11 - r01 * r01
            if not (r00 > 0.0 and det > 0.0):
                return -1
            vf = (r11 * g0 - r01 * g1) / det
            th0 = (r00 * g1 - r01 * g0) / det
            rx, ry = vf * c + lat * ex, vf * s + lat * ey
        else:
            if not _cholesky(K, Lk):
                return -1
            _forward(Lk, f)
            _backward(Lk, f)
            rx, ry, th0 = f[0], f[1], f[2]
        v_new[0], v_new[n], v_new[n + 1] = th0, rx, ry
        V_new[0, 0], V_new[0, 1] = rx, ry
        px, py = rx + th0 * w0, ry + th0 * w1
        for k in range(1, n):
            t = alpha[k, 0] * px + alpha[k, 1] * py + beta[k]
            v_new[k] = t
            t *= half[k]
            V_new[k, 0], V_new[k, 1] = px - t * sin[k], py + t * cos[k]
            px, py = px - 2.0 * t * sin[k], py + 2.0 * t * cos[k]
        _wheel_impulses(qdot, cos, sin, half, mass, inertia, rotor, False, V, V_new, v_new, E, torque, h, state,
                        impulse)
        for k in range(n):
            lateral[k] = -sin[k] * V_new[k, 0] + cos[k] * V_new[k, 1] + cterm[k]
        if _switch(state, impulse, bounds, lateral):
            continue
        return iteration + 1
    return -1


@njit(cache=True, nogil=True)
def _wheel_impulses(qdot, cos, sin, half, mass, inertia, rotor, rotor_on, V, V_new, v_new, E, torque, h, state,
                    impulse):
    """The gripping wheels' impulses p_k (N s) of a substep from qdot to v_new (V, V_new: the CMs' velocities),
    from the tail: link k's momentum change (Pi, ang) is its wheel's impulse p_k e_k_perp at CM_k and the joints'
    reaction impulses J_k (from link k-1, at h_k behind CM_k) and -J_{k+1} (at h_k ahead), beside h times its
    loads (E, torque); the moment about CM_k gives p_k, the force balance J_k (Newton-Euler on the substep's
    impulses). Sliding wheels keep theirs."""
    n = V.shape[0]
    jx, jy = 0.0, 0.0
    for k in range(n - 1, -1, -1):
        px = mass[k] * (V_new[k, 0] - V[k, 0]) - h * E[k, 0]
        py = mass[k] * (V_new[k, 1] - V[k, 1]) - h * E[k, 1]
        if k == 0:
            if state[0] == 0:
                impulse[0] = -sin[0] * (px + jx) + cos[0] * (py + jy)
            break
        if state[k] == 0:
            ang = inertia[k] * (v_new[k] - qdot[k]) - h * torque[k]
            if rotor_on:
                for c in range(n):
                    ang += rotor[k, c] * (v_new[c] - qdot[c])
            impulse[k] = ang / half[k] + cos[k] * (py + 2.0 * jy) - sin[k] * (px + 2.0 * jx)
        jx += px + impulse[k] * sin[k]
        jy += py - impulse[k] * cos[k]


@njit(cache=True, nogil=True)
def _switch(state, impulse, bounds, lateral):
    """One active-set update (:func:`_active_set`'s rules): a gripping wheel that needs more than its grip slides;
    if none does, a sliding wheel whose velocity runs with its friction grips again. True if anything changed."""
    changed = False
    for k in range(state.shape[0]):
        if state[k] == 0:
            if impulse[k] > bounds[k]:
                state[k] = 1
                changed = True
            elif impulse[k] < -bounds[k]:
                state[k] = -1
                changed = True
    if changed:
        return True
    for k in range(state.shape[0]):
        if state[k] != 0 and state[k] * lateral[k] > PGS_TOLERANCE:
            state[k] = 0
            changed = True
    return changed


@njit(cache=True, nogil=True)
def _delassus_solve(q, qdot, cos, sin, G, g, total_mass, inertia, lever, c_wheel, rotor, T, h, bounds, state,
                    impulse, v_new, lateral):
    """The module doc's problem through the Delassus matrix D = A M^-1 A^T (M from the constants G, g; O(n^3)):
    active sets from ``state``, projected Gauss-Seidel where they do not settle. The fallback of
    :func:`_null_space_solve` and its cross-check. Fills v_new, impulse and lateral (w = b + D p, m/s); returns the
    iterations (or sweeps), -1 if M is not positive definite or Gauss-Seidel did not converge."""
    n = q.shape[0] - 2
    N = n + 2
    M = np.empty((N, N))
    L = np.empty((N, N))
    Y = np.empty((n, N))  # rows: L^-1 A^T's columns
    D = np.empty((n, n))
    Dff = np.empty((n, n))  # the gripping wheels' block of D, its Cholesky factor, right side and indices
    Lff = np.empty((n, n))
    rhs = np.empty(n)
    free = np.empty(n, np.int64)
    force = np.empty(N)  # Q (eq. 24's loads)
    bias = np.empty(N)  # B (eq. 24)
    b = np.empty(n)
    vfree = np.empty(N)
    speed = np.empty(n)  # m/s: V_k of every link
    # M (eq. 25 through the constants G, g) and the rotors
    for a in range(n):
        for c in range(a + 1):
            dot = sin[a] * sin[c] + cos[a] * cos[c]  # e_a_perp . e_c_perp
            M[a, c] = G[a, c] * dot + rotor[a, c]
            M[c, a] = M[a, c]
        M[a, a] += inertia[a]
        M[a, n] = -g[a] * sin[a] + rotor[a, n]
        M[a, n + 1] = g[a] * cos[a] + rotor[a, n + 1]
        M[n, a] = M[a, n]
        M[n + 1, a] = M[a, n + 1]
    M[n, n] = total_mass + rotor[n, n]
    M[n + 1, n + 1] = total_mass + rotor[n + 1, n + 1]
    M[n, n + 1] = rotor[n, n + 1]
    M[n + 1, n] = rotor[n + 1, n]
    # Q - B: joint loads (eq. 11), wheel rolling resistance along each link, minus the centripetal bias
    for a in range(N):
        force[a] = 0.0
    for k in range(n - 1):
        force[k] -= T[k]
        force[k + 1] += T[k]
    for a in range(N):
        bias[a] = 0.0
    for a in range(n):  # B_a = -sum_j G_aj thetadot_j^2 e_a_perp . e_j
        s = 0.0
        for j in range(n):
            s += G[a, j] * qdot[j] * qdot[j] * (-sin[a] * cos[j] + cos[a] * sin[j])
        bias[a] = -s
    for j in range(n):  # B_xy = -sum_j g_j thetadot_j^2 e_j
        bias[n] -= g[j] * qdot[j] * qdot[j] * cos[j]
        bias[n + 1] -= g[j] * qdot[j] * qdot[j] * sin[j]
    for k in range(n):  # V_k = e_k . rdot_k (m/s), each CM's speed along its link
        rx, ry = qdot[n], qdot[n + 1]
        for j in range(k + 1):
            rx -= lever[k, j] * sin[j] * qdot[j]
            ry += lever[k, j] * cos[j] * qdot[j]
        speed[k] = cos[k] * rx + sin[k] * ry
    for k in range(n):
        if c_wheel[k] != 0.0:  # rolling resistance -c_w V_k e_k at CM_k
            f = -c_wheel[k] * speed[k]
            fx, fy = f * cos[k], f * sin[k]
            for j in range(k + 1):
                force[j] += lever[k, j] * (-sin[j] * fx + cos[j] * fy)
            force[n] += fx
            force[n + 1] += fy
    if not _cholesky(M, L):
        return -1
    for a in range(N):
        vfree[a] = h * (force[a] - bias[a])
    _forward(L, vfree)
    _backward(L, vfree)
    for a in range(N):
        vfree[a] += qdot[a]
    # A's rows (eq. 26): A_kj = c_kj e_k_perp . e_j_perp (j <= k), A_k,xy = e_k_perp; Y_k = L^-1 A_k^T
    for k in range(n):
        for a in range(N):
            Y[k, a] = 0.0
        for j in range(k + 1):
            Y[k, j] = lever[k, j] * (sin[k] * sin[j] + cos[k] * cos[j])
        Y[k, n] = -sin[k]
        Y[k, n + 1] = cos[k]
        s = 0.0
        for a in range(N):
            s += Y[k, a] * vfree[a]
        # + h Adot qdot: the wheel's lateral velocity a substep on, in the link's turned frame (eq. 27's
        # -Adot qdot; without it a gripping wheel's acceleration would miss it by O(1))
        curve = 0.0
        for j in range(k + 1):
            curve += lever[k, j] * qdot[j] * qdot[j] * (cos[k] * sin[j] - sin[k] * cos[j])
        b[k] = s + h * (-qdot[k] * speed[k] - curve)
        _forward(L, Y[k])
    for k in range(n):  # D = A M^-1 A^T = Y Y^T
        for j in range(k + 1):
            s = 0.0
            for a in range(N):
                s += Y[k, a] * Y[j, a]
            D[k, j] = s
            D[j, k] = s
    # the wheels' impulses: an active-set solve from the last substep's sliding set, exact to rounding;
    # projected Gauss-Seidel if it does not settle
    iterations = _active_set(D, b, bounds, impulse, state, Dff, Lff, rhs, free)
    if iterations < 0:
        sweeps = _projected_gauss_seidel(D, b, bounds, impulse)
        if sweeps < 0:
            return -1
        for k in range(n):
            state[k] = 1 if impulse[k] >= bounds[k] else (-1 if impulse[k] <= -bounds[k] else 0)
        iterations = sweeps
    # qdot+ = qdot* + M^-1 A^T p = qdot* + L^-T (Y^T p)
    for a in range(N):
        s = 0.0
        for k in range(n):
            s += Y[k, a] * impulse[k]
        v_new[a] = s
    _backward(L, v_new)
    for a in range(N):
        v_new[a] += vfree[a]
    for k in range(n):  # the complementarity problem's w_k = b_k + (D p)_k: zero where the wheel grips
        slip = b[k]
        for j in range(n):
            slip += D[k, j] * impulse[j]
        lateral[k] = slip
    return iterations


@njit(cache=True, nogil=True)
def _active_set(D, b, bounds, impulse, state, Dff, Lff, rhs, free):
    """The box-constrained complementarity problem of the module doc (the wheels' impulses p, |p_k| <= bounds_k,
    w = b + D p) by active sets from ``state`` (0 grips, +-1 slides at +-bound; updated): the gripping wheels'
    impulses solve their block of D exactly given the sliding ones', wheels that would need more than their
    bound start sliding, sliding wheels whose velocity runs with their friction grip again. D is positive
    definite, so the solution is unique (a strictly convex quadratic program). Returns the iterations, or -1 if
    it did not settle within 2 n + 8 (then p is not a solution)."""
    n = b.shape[0]
    for iteration in range(2 * n + 8):
        m = 0
        for k in range(n):
            if state[k] == 0:
                free[m] = k
                m += 1
            else:
                impulse[k] = state[k] * bounds[k]
        if m > 0:
            for i in range(m):
                k = free[i]
                s = -b[k]
                for j in range(n):
                    if state[j] != 0:
                        s -= D[k, j] * impulse[j]
                rhs[i] = s
                for c in range(m):
                    Dff[i, c] = D[k, free[c]]
            if not _cholesky(Dff[:m, :m], Lff[:m, :m]):
                return -1
            _forward(Lff[:m, :m], rhs[:m])
            _backward(Lff[:m, :m], rhs[:m])
            for i in range(m):
                impulse[free[i]] = rhs[i]
        changed = False
        for i in range(m):  # a gripping wheel that needs more than its grip slides
            k = free[i]
            if impulse[k] > bounds[k]:
                state[k] = 1
                changed = True
            elif impulse[k] < -bounds[k]:
                state[k] = -1
                changed = True
        if changed:
            continue
        for k in range(n):  # a sliding wheel whose velocity runs with its friction grips again
            if state[k] != 0:
                w = b[k]
                for j in range(n):
                    w += D[k, j] * impulse[j]
                if state[k] * w > PGS_TOLERANCE:
                    state[k] = 0
                    changed = True
        if not changed:
            return iteration + 1
    return -1


@njit(cache=True, nogil=True)
def _projected_gauss_seidel(D, b, bounds, impulse):
    """The same problem by projected Gauss-Seidel from the all-gripping solution clipped to the bounds, until
    Coulomb's law holds to PGS_TOLERANCE (m/s); returns the sweeps, or -1 after PGS_MAX_SWEEPS."""
    n = b.shape[0]
    Ld = np.empty((n, n))
    if not _cholesky(D, Ld):
        return -1
    for k in range(n):
        impulse[k] = -b[k]
    _forward(Ld, impulse)
    _backward(Ld, impulse)
    for k in range(n):
        impulse[k] = min(max(impulse[k], -bounds[k]), bounds[k])
    sweeps = 0
    while True:
        sweeps += 1
        worst = 0.0
        for k in range(n):
            s = b[k]
            for j in range(n):
                s += D[k, j] * impulse[j]
            bound = bounds[k]
            p = impulse[k] - s / D[k, k]
            p = bound if p > bound else (-bound if p < -bound else p)
            # Coulomb's violation at k: a gripping wheel's velocity, or a sliding one's velocity along
            # its friction (p = +bound needs w <= 0, p = -bound needs w >= 0)
            if -bound < impulse[k] < bound:
                viol = abs(s)
            elif impulse[k] >= bound:
                viol = s if s > 0.0 else 0.0
            else:
                viol = -s if s < 0.0 else 0.0
            worst = max(worst, viol)
            impulse[k] = p
        if worst <= PGS_TOLERANCE:
            return sweeps
        if sweeps >= PGS_MAX_SWEEPS:
            return -1


@njit(cache=True, nogil=True)
def _fail(q, qdot):
    for a in range(q.shape[0]):
        q[a] = math.nan
        qdot[a] = math.nan
    return False


@njit(cache=True, nogil=True)
def kinetic_energy(q, qdot, lever, mass, inertia, rotor):
    """1/2 qdot^T M qdot (J) of one state, rotors included: eq. 22's sum over the links of 1/2 m_k |V_k|^2 +
    1/2 I_k thetadot_k^2 (the CM velocities by :func:`_link_velocities`, O(n)) and the rotors' 1/2 qdot^T R qdot."""
    n = q.shape[0] - 2
    cos = np.empty(n)
    sin = np.empty(n)
    half = np.empty(n)
    for k in range(n):
        cos[k] = math.cos(q[k])
        sin[k] = math.sin(q[k])
        half[k] = lever[k, k] if k > 0 else (lever[1, 0] if n > 1 else 0.0)
    V = np.empty((n, 2))
    _link_velocities(qdot, cos, sin, half, V)
    K = 0.0
    for k in range(n):
        K += 0.5 * (mass[k] * (V[k, 0] * V[k, 0] + V[k, 1] * V[k, 1]) + inertia[k] * qdot[k] * qdot[k])
    for a in range(n):  # the rotors act on neighbouring joint angles only (lagrange.rotor_inertia_matrix)
        for c in range(max(a - 1, 0), min(a + 2, n)):
            K += 0.5 * rotor[a, c] * qdot[a] * qdot[c]
    return K


# the row kernels by ``advance``'s method: the O(n) recursion, the null-space solve, the Delassus solve
ADVANCE_ROWS = (advance_rows, partial(advance_rows_exact, delassus=False), partial(advance_rows_exact, delassus=True))
