"""The env's physics step as a pure batched function (Brax style).

``step(params, q, u, torques)`` maps a state and an action to the next state
and everything the env reports about it; it never mutates its inputs.
Batching is a leading axis: q (B, n+2), u (B, 2), torques (B, n-1) step B
snakes in one compiled call, and 1-D inputs step one snake. Both paths run
the same lane kernel (:func:`_step_lanes`: groups of ``compiled.LANES``
snakes with the snake index innermost, so the loops compile to SIMD code),
whose result for a snake does not depend on the batch it is in: a batch of
one reproduces the single snake bit for bit, and so the single env equals
the vector env.

The integrator is the compiled RK4 lane kernel of
:mod:`snake_env.dynamics.compiled` (the O(n) Kane sweep of eqs. 6-21 plus
damping and the joint-limit barrier). Around it this module adds what the RL
interface needs: the mass-weighted centre of mass of the whole snake (whose
finite difference over one env step is the reward's velocity), the
observation vector, the kinetic energy (eq. 22 under the constraints) and the
step check below.

Checked integration (no silent blow-ups). Every env step is checked on the
state it produced; a step passes when
  * every coordinate, speed, the work and the kinetic energy are finite;
  * the embedded error estimate of every RK4 substep is within error_tolerance:
    RK4 with the FSAL stage k5 = f(y_{n+1}) carries a third-order solution
    (weights 1/6, 1/3, 1/3, 0, 1/6) whose difference to RK4's, dt/6 |k4 - k5|,
    estimates the local error; it must be <= error_tolerance * 1 rad for every
    theta_k, error_tolerance * (|V_1| + h_1 * 1 rad/s) for V_1 and
    error_tolerance * (|thetadot_1| + 1 rad/s) for thetadot_1 (one derivative
    more per env step: k5 of a substep is the next one's k1);
  * the work-energy balance holds: |K1 - K0 - W| <= energy_tolerance *
    (max(K0, K1) + energy_floor), K the kinetic energy (J) before and after,
    W the work of all loads over the step (J) (K - integral of power is
    conserved by the continuous model, so the residual is integration error);
  * no link or joint turns by more than MAX_SUBSTEP_ANGLE (rad) in one RK4
    substep (max |omega_k|, |phidot_k| times the substep, after the step): a
    faster state is not resolved by the step (a runaway);
  * no wrapped joint angle reaches compiled.FOLD_ANGLE (adjacent links folded
    onto each other: no contact in the model, not physical).
A snake whose step fails is integrated again from its pre-step state by the
per-snake kernel with the substep halved, up to ``max_refinements`` times
(only that snake: the others keep their lane result; this happens in a second
compiled call, :func:`_finish_rows`, made only when the lane kernel leaves such
snakes, so the first step compiles the lane kernel alone and a background
process compiles the rest: :func:`compile_in_background`); an attempt below the
finest level stops at its first substep over error_tolerance, since it is
redone finer anyway (the accepted step is the same, bit for bit). If the finest step
still fails, the step is a simulation failure: the pre-step state is kept
(its observation is returned again, velocity and work 0) and aux[AUX_FAILED]
holds the reason code (FAIL_*). The result of a snake still does not depend
on the batch it is in.
A fold is not refined (v2): a step that passes every accuracy check (error
estimate, work-energy balance, substep angle) and ends folded is a failure at
once. Refinement buys accuracy, and this step is already accurate; the fold is
the model's (no link contact), not the integrator's. Refining it cost up to 127
substeps' work per failing snake and ran fold-heavy paper-model settings at a
few hundred env-steps/s; the finest step folds too (tests/envs/test_stability.py).
A snake whose link angles exceed ``compiled.LANE_ANGLE_MAX`` (1e5 rad, only
after thousands of turns) is stepped by the per-snake kernel
(:func:`_step_one`, libm sin/cos) instead.
"""

from __future__ import annotations

import functools
import math
import os
import select
import subprocess
import sys
import threading
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from snake_env.dynamics import compiled, sliding_step

from .bound_kernel import BoundKernel

# Layout of the per-snake auxiliary output row (float64). AUX_FAILED is 0.0 or
# a FAIL_* reason code; AUX_REFINEMENTS the substep halvings the step needed;
# AUX_RESIDUAL its relative work-energy residual |K1 - K0 - W| / (max(K0, K1) + floor);
# AUX_MOTOR_ENERGY the motors' energy over the step (J): the integral of sum_k |s A_k phidot_k|, the
# torque each motor delivers (after its band, current limit and the traction scale s) times its joint's
# rate, by the RK4 weights of the work (compiled.derivatives_motor); 0 for a failed step.
(AUX_X, AUX_Y, AUX_VX, AUX_VY, AUX_KINETIC, AUX_WORK, AUX_FAILED, AUX_REFINEMENTS, AUX_RESIDUAL,
 AUX_MOTOR_ENERGY) = range(10)
AUX_SIZE = 10
# Reasons a step fails (aux[AUX_FAILED]); the check order is this order.
FAIL_NONFINITE, FAIL_ENERGY, FAIL_RUNAWAY, FAIL_FOLD, FAIL_ERROR = 1, 2, 3, 4, 5
FAILURE_REASONS = {FAIL_NONFINITE: "non-finite state", FAIL_ERROR: "error estimate above error_tolerance",
                   FAIL_ENERGY: "work-energy residual above energy_tolerance",
                   FAIL_RUNAWAY: "runaway: a link or joint turns more than MAX_SUBSTEP_ANGLE per RK4 substep",
                   FAIL_FOLD: "adjacent links folded (|phi_k| reached FOLD_ANGLE)"}
# rad: the most a link or joint may turn in one RK4 substep. RK4's error on a
# rotation by a per step is ~a^5/120 (1% at 1 rad); faster states are refined,
# and at the finest substep they are a runaway.
MAX_SUBSTEP_ANGLE = 1.0
FOLD_ANGLE = compiled.FOLD_ANGLE
# Batches with fewer than this many coordinates (B * (n+2)) are stepped on one
# thread, larger ones split across numba's threads. Measured on the 2-core
# machine with the lane kernel: one thread steps 1.4 million Snake5 env-steps/s
# at 1024 envs; two threads 2.2-2.3 million when the second core is idle, but a
# threaded call waits ~8 ms for a core that another process keeps busy
# (2-core machine at load ~3: 0.13 million). 2^12 coordinates (~600 Snake5 envs,
# ~128 Snake30 envs) is where an idle second core starts to pay off; users who
# share cores (several trainings at once) should call numba.set_num_threads(1).
PARALLEL_MIN_WORK = 2 ** 12


class StepSettings(NamedTuple):
    """The integration and check settings every step kernel reads: the
    :class:`PhysicsParams` fields of the same names and units.

    Kernels take them as one argument ``settings``, the plain tuple of these
    fields made by :func:`step_settings` (cached as
    ``PhysicsParams.kernel_settings``), and unpack it in this order; a plain
    tuple for the reason given at ``compiled.KernelModel`` (call overhead).
    """

    sim_dt: float  # s: one RK4 step
    frame_skip: int  # RK4 steps per env step
    include_position: bool  # the observation starts with the CM position (x, y)
    energy_tolerance: float  # largest relative work-energy residual of a step
    energy_floor: float  # J: added to max(K0, K1) in that test
    error_tolerance: float  # tolerance of the embedded error estimate; inf: not checked
    max_refinements: int  # substep halvings tried on a failing step


def step_settings(sim_dt, frame_skip, include_position, energy_tolerance, energy_floor, error_tolerance,
                  max_refinements) -> tuple:
    """The ``settings`` argument of the step kernels (see :class:`StepSettings`), with the
    field types fixed, so that every caller reuses one compiled (and cached) specialisation."""
    return tuple(StepSettings(float(sim_dt), int(frame_skip), bool(include_position), float(energy_tolerance),
                              float(energy_floor), float(error_tolerance), int(max_refinements)))


@dataclass(frozen=True)
class PhysicsParams:
    """Constants of one env: the model's per-link arrays (float64) and the
    integration and joint-limit settings.

    Attributes:
        mass (kg), half_length (m), inertia (kg m^2): per link, shape (n,).
        joint_damping (N m s/rad): shape (n-1,); wheel_damping (N s/m): shape (n,).
        joint_limit: soft limit on |phi_k| (rad); 0 disables the limits.
        limit_stiffness (N m/rad), limit_damping (N m s/rad): the spring-damper
            acting beyond the limit.
        sim_dt: RK4 step (s); frame_skip: RK4 steps per env step.
        include_position: whether the observation starts with the CM position (x, y).
        energy_tolerance: largest relative work-energy residual of a step (see the module doc).
        energy_floor (J): added to max(K0, K1) in that test, so a snake at rest is not held to
            a relative tolerance of its tiny energy.
        error_tolerance: tolerance of the embedded error estimate (see the module doc); inf: not checked.
        max_refinements: substep halvings tried on a failing step (0: a failing step fails).
        substeps: equal RK4 substeps per sim_dt (chosen by ``PhysicsConfig.build`` where RK4
            needs a shorter step than sim_dt); the env step stays sim_dt * frame_skip.
        stall_torque (N m), inverse_no_load_speed (s/rad), torque_limit (N m): the joint motors
            (:mod:`snake_env.dynamics.motor`); torque_limit = inf: ideal torque sources.
        wheel_grip (N): mu m_k g of every wheel (n,), the traction limit of
            ``compiled.traction_derivatives``; None: unlimited grip (the paper's no-slip wheels).
        rotor_inertia (kg m^2): each joint motor's reflected rotor inertia N^2 J_r (n-1,); None: massless
            rotors (``compiled.KernelModel``).
        back_emf_braking: a motor back-driven past its current limit brakes with its back-EMF's torque
            (:mod:`snake_env.dynamics.motor`; the physics from v4); False: braking capped at torque_limit.

    The kernels take these as two arguments, :attr:`kernel_model` (``compiled.KernelModel``)
    and :attr:`kernel_settings` (:class:`StepSettings`), made on first use.
    """

    mass: np.ndarray
    half_length: np.ndarray
    inertia: np.ndarray
    joint_damping: np.ndarray
    wheel_damping: np.ndarray
    joint_limit: float
    limit_stiffness: float
    limit_damping: float
    sim_dt: float
    frame_skip: int
    include_position: bool
    energy_tolerance: float = 1e-2
    energy_floor: float = 1e-3
    error_tolerance: float = 1e-2
    max_refinements: int = 6
    substeps: int = 1
    stall_torque: float = math.inf
    inverse_no_load_speed: float = 0.0
    torque_limit: float = math.inf
    wheel_grip: np.ndarray | None = None
    rotor_inertia: np.ndarray | None = None
    back_emf_braking: bool = False

    @property
    def n_links(self) -> int:
        return int(self.mass.shape[0])

    @cached_property
    def kernel_model(self) -> tuple:
        """The kernels' ``model`` argument (``compiled.KernelModel``'s fields), made once."""
        return compiled.kernel_model(self.mass, self.half_length, self.inertia, self.joint_damping,
                                     self.wheel_damping, self.joint_limit, self.limit_stiffness, self.limit_damping,
                                     self.stall_torque, self.inverse_no_load_speed, self.torque_limit,
                                     self.wheel_grip, self.rotor_inertia, self.back_emf_braking)

    @cached_property
    def kernel_settings(self) -> tuple:
        """The step kernels' ``settings`` argument (:class:`StepSettings`' fields), made once; the kernels'
        RK4 step is sim_dt / substeps, frame_skip * substeps times per env step."""
        return step_settings(self.sim_dt / self.substeps, self.frame_skip * self.substeps, self.include_position,
                             self.energy_tolerance, self.energy_floor, self.error_tolerance, self.max_refinements)

    @property
    def dt(self) -> float:
        """Duration of one env step (s)."""
        return self.sim_dt * self.frame_skip

    @property
    def obs_size(self) -> int:
        return observation_size(self.n_links, self.include_position)


def observation_size(n_links: int, include_position: bool) -> int:
    """[x, y] + (n-1) joint angles + cos/sin heading + 2 speeds + (n-1) joint rates."""
    return 2 * n_links + 2 + (2 if include_position else 0)


# --------------------------------------------------------------------------- kernels
# sin/cos and angle wrapping are those of the lane kernel (compiled.sincos,
# compiled.wrap_angle) wherever they are accurate, so that a state's
# observation is the same bit for bit whether it comes from a (lane) step,
# reset() or observe(); libm beyond that range.
@njit(cache=True, nogil=True, inline="always")
def _sincos(x):
    if abs(x) <= compiled.SINCOS_MAX:
        return compiled.sincos(x)
    return math.sin(x), math.cos(x)


@njit(cache=True, nogil=True, inline="always")
def _wrap(phi):
    """phi wrapped to [-pi, pi] (rad)."""
    if abs(phi) <= compiled.SINCOS_MAX:
        return compiled.wrap_angle(phi)
    return math.atan2(math.sin(phi), math.cos(phi))


@njit(cache=True, nogil=True)
def _center_of_mass(model, q):
    """Mass-weighted CM of the whole snake (m): CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1} (eq. 3)."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit = model[:8]
    n = m.shape[0]
    px = q[n]
    py = q[n + 1]
    sx = m[0] * px
    sy = m[0] * py
    total = m[0]
    sn, cs = _sincos(q[0])
    for k in range(n - 1):
        sn_next, cs_next = _sincos(q[k + 1])
        px += h[k] * cs + h[k + 1] * cs_next
        py += h[k] * sn + h[k + 1] * sn_next
        sx += m[k + 1] * px
        sy += m[k + 1] * py
        total += m[k + 1]
        sn = sn_next
        cs = cs_next
    return sx / total, sy / total


@njit(cache=True, nogil=True)
def _observe(model, q, u, include_position, cx, cy, obs):
    """Fill obs (see :data:`OBSERVATION_DOC`); return the kinetic energy (J).

    Link speeds V_k and rates omega_k follow eqs. 6-7 from u = (V_1, thetadot_1).
    """
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit = model[:8]
    rotor = model[12]
    geared = rotor.shape[0] > 0
    n = m.shape[0]
    j = 0
    if include_position:
        obs[0] = cx
        obs[1] = cy
        j = 2
    # joint angles phi_k = theta_{k+1} - theta_k, wrapped to (-pi, pi]
    for k in range(n - 1):
        obs[j + k] = _wrap(q[k + 1] - q[k])
    j += n - 1
    sn, cs = _sincos(q[0])
    obs[j] = cs
    obs[j + 1] = sn
    obs[j + 2] = u[0]
    obs[j + 3] = u[1]
    j += 4
    V = u[0]
    W = u[1]
    kinetic = 0.5 * (m[0] * V * V + inertia[0] * W * W)
    for k in range(n - 1):
        phi = q[k + 1] - q[k]
        S, C = _sincos(phi)
        nV = V * C + W * h[k] * S  # eq. 6
        nW = (V * S - W * h[k] * C) / h[k + 1]  # eq. 7
        phidot = nW - W
        obs[j + k] = phidot  # joint rate phidot_k
        V = nV
        W = nW
        kinetic += 0.5 * (m[k + 1] * V * V + inertia[k + 1] * W * W)
        if geared:  # the rotor's 1/2 N^2 J_r phidot^2 (summed as _observe_lanes sums it)
            kinetic += 0.5 * rotor[k] * (phidot * phidot)
    return kinetic


@njit(cache=True, nogil=True)
def _measures(model, q, u):
    """(kinetic energy (J), fastest rate (rad/s), largest wrapped |phi_k| (rad)) of one state:
    the quantities of the step check. Rates are every link's omega_k and joint's phidot_k (eqs. 6-7)."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit = model[:8]
    rotor = model[12]
    geared = rotor.shape[0] > 0
    n = m.shape[0]
    V = u[0]
    W = u[1]
    kinetic = 0.5 * (m[0] * V * V + inertia[0] * W * W)
    rate = abs(W)
    fold = 0.0
    for k in range(n - 1):
        phi = q[k + 1] - q[k]
        S, C = _sincos(phi)
        nV = V * C + W * h[k] * S  # eq. 6
        nW = (V * S - W * h[k] * C) / h[k + 1]  # eq. 7
        rate = max(rate, abs(nW), abs(nW - W))
        fold = max(fold, abs(_wrap(phi)))
        phidot = nW - W
        V = nV
        W = nW
        kinetic += 0.5 * (m[k + 1] * V * V + inertia[k + 1] * W * W)
        if geared:  # the rotor's 1/2 N^2 J_r phidot^2
            kinetic += 0.5 * rotor[k] * (phidot * phidot)
    return kinetic, rate, fold


@njit(cache=True, nogil=True, inline="always")
def _verdict(finite, err, k0, k1, work, rate, fold, dt_sub, settings):
    """(FAIL_* code or 0, relative work-energy residual) of a step; see the module doc.
    ``err``: the error estimate over the tolerance; dt_sub: the RK4 substep (s).
    Comparisons are written so that NaN fails them."""
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    if not finite:
        return FAIL_NONFINITE, math.inf
    if not err <= 1.0:
        return FAIL_ERROR, math.inf
    residual = abs(k1 - k0 - work) / (max(k0, k1) + e_floor)
    if not residual <= tol:
        return FAIL_ENERGY, residual
    if not rate * dt_sub <= MAX_SUBSTEP_ANGLE:
        return FAIL_RUNAWAY, residual
    if not fold < FOLD_ANGLE:
        return FAIL_FOLD, residual
    return 0, residual


# int64 values, not literals, for the r_first argument of _integrate_checked: an integer constant passed
# from a jitted caller is a Literal[int] type and gets its own compiled specialisation (~1 s cold each)
_ZERO, _ONE = np.int64(0), np.int64(1)


@njit(cache=True, nogil=True)
def _integrate_checked(model, settings, r_first, r_last, q0, u0, torques, k0, q, u):
    """One env step of one snake from (q0, u0) (kinetic energy k0) by the per-snake RK4
    kernel, with substeps sim_dt / 2^r for r = r_first, ..., r_last until one passes the
    check or one fails by a fold. Returns (code, work (J), r, residual, motors' energy (J)); (q, u)
    hold the accepted state, or (q0, u0) when the step failed (code != 0, work and energy 0)."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit = model[:8]
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    nq = q.shape[0]
    code = FAIL_NONFINITE
    residual = math.inf
    used = r_last
    for r in range(r_first, r_last + 1):
        used = r
        for j in range(nq):
            q[j] = q0[j]
        u[0] = u0[0]
        u[1] = u0[1]
        sub = 1 << r
        dt_sub = sim_dt / sub
        # below the finest level a step over the error tolerance is redone finer whatever the
        # rest of it would give (the verdict is FAIL_NONFINITE or FAIL_ERROR, never a final
        # FAIL_FOLD), so it stops at the first substep over the tolerance: the same accepted
        # step, bit for bit, without integrating the rest of a rejected one. The finest level
        # runs to the end, so that its verdict (non-finite or error) is that of the whole step.
        work, err, motor = compiled.rk4_step_estimate(model, q, u, torques, dt_sub, frame_skip * sub, err_tol,
                                                      h[0], r < r_last)
        if r < r_last and err > 1.0:
            code = FAIL_ERROR
            continue
        finite = math.isfinite(work) and math.isfinite(u[0]) and math.isfinite(u[1])
        for j in range(nq):
            finite = finite and math.isfinite(q[j])
        k1 = math.nan
        rate = math.nan
        fold = math.nan
        if finite:
            k1, rate, fold = _measures(model, q, u)
            finite = math.isfinite(k1)
        code, residual = _verdict(finite, err, k0, k1, work, rate, fold, dt_sub, settings)
        if code == 0:
            return 0, work, r, residual, motor
        if code == FAIL_FOLD:  # accurate and folded: a finer substep would fold too (module doc)
            break
    for j in range(nq):
        q[j] = q0[j]
    u[0] = u0[0]
    u[1] = u0[1]
    return code, 0.0, used, residual, 0.0


@njit(cache=True, nogil=True)
def _step_one(model, settings, q, u, torques, obs, aux):
    """Advance one snake in place by one checked env step (see the module doc); fill obs and aux.

    A step that fails at the finest substep is undone (q, u keep their
    pre-step values) and its reason put in aux[AUX_FAILED], so no NaN or
    runaway ever leaves the kernel.
    """
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    cx0, cy0 = _center_of_mass(model, q)
    k0, _, _ = _measures(model, q, u)
    q0 = q.copy()
    u0 = u.copy()
    code, work, r, residual, motor = _integrate_checked(model, settings, _ZERO, max_ref, q0, u0, torques, k0, q, u)
    cx, cy = _center_of_mass(model, q)
    env_dt = sim_dt * frame_skip
    aux[AUX_X] = cx
    aux[AUX_Y] = cy
    aux[AUX_VX] = (cx - cx0) / env_dt
    aux[AUX_VY] = (cy - cy0) / env_dt
    aux[AUX_KINETIC] = _observe(model, q, u, include_position, cx, cy, obs)
    aux[AUX_WORK] = work
    aux[AUX_FAILED] = code
    aux[AUX_REFINEMENTS] = r
    aux[AUX_RESIDUAL] = residual
    aux[AUX_MOTOR_ENERGY] = motor


# --------------------------------------------------------------------------- lane kernels
# The env step for groups of compiled.LANES snakes in the lane scratch of
# :mod:`snake_env.dynamics.compiled`: the innermost loops run over snakes and
# vectorise (see the notes there). Rows used here besides the integrator's:
_U = np.uint64
_LANES = compiled.LANES
# (the check's pre-step kinetic energy, fastest rate and largest |phi| too)
_H_CX0, _H_CY0, _H_CX, _H_CY, _H_KINETIC, _H_COS1, _H_SIN1, _H_K0, _H_RATE, _H_FOLD = (
    _U((compiled.H_FREE + i) * _LANES) for i in range(10))
assert compiled.H_FREE + 10 <= compiled.N_HEADER
# per link k: cos, sin of theta_k (CM sweep); observed joint angle and rate of joint k
_B_COS, _B_SIN, _B_PHI, _B_PHIDOT = (_U((compiled.B_FREE + i) * _LANES) for i in range(4))
# running sums of the CM and kinetic-energy sweeps, in the integrator's channel
# rows (free outside a derivative evaluation)
_B_PX, _B_PY, _B_SX, _B_SY = (_U(row * _LANES) for row in (compiled.B_A1, compiled.B_A2, compiled.B_B1, compiled.B_B2))
_B_V, _B_W, _B_K = (_U(row * _LANES) for row in (compiled.B_V, compiled.B_W, compiled.B_M00))
_B_Q = _U(compiled.B_Q * _LANES)
assert compiled.B_FREE + 4 <= compiled.BLOCK
_H_X, _H_Y, _H_U0, _H_U1, _H_WORK, _H_ERR, _H_MOTOR = (
    _U(row * _LANES) for row in (compiled.H_X, compiled.H_Y, compiled.H_U0, compiled.H_U1, compiled.H_WORK,
                                 compiled.H_ERR, compiled.H_MOTOR))


@njit(cache=True, nogil=True, error_model="numpy")
def _center_of_mass_lanes(model, total_mass, s, nl, row_x, row_y):
    """:func:`_center_of_mass` of lanes 0..nl-1 (state rows Q, X, Y) into rows row_x, row_y (m)."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit = model[:8]
    n = m.shape[0]
    lanes = _U(nl)
    b0 = compiled.lane_block(0)
    m0 = m[0]
    for l in range(lanes):
        sn, cs = compiled.sincos(s[b0 + _B_Q + l])
        s[b0 + _B_COS + l] = cs
        s[b0 + _B_SIN + l] = sn
        px = s[_H_X + l]
        py = s[_H_Y + l]
        s[b0 + _B_PX + l] = px
        s[b0 + _B_PY + l] = py
        s[b0 + _B_SX + l] = m0 * px
        s[b0 + _B_SY + l] = m0 * py
    for k in range(n - 1):
        o = compiled.lane_block(k)
        p = o + compiled.lane_block(1) - compiled.lane_block(0)
        hk = h[k]
        hn = h[k + 1]
        mn = m[k + 1]
        for l in range(lanes):
            sn, cs = compiled.sincos(s[p + _B_Q + l])
            # CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1} (eq. 3)
            px = s[o + _B_PX + l] + (hk * s[o + _B_COS + l] + hn * cs)
            py = s[o + _B_PY + l] + (hk * s[o + _B_SIN + l] + hn * sn)
            s[p + _B_COS + l] = cs
            s[p + _B_SIN + l] = sn
            s[p + _B_PX + l] = px
            s[p + _B_PY + l] = py
            s[p + _B_SX + l] = s[o + _B_SX + l] + mn * px
            s[p + _B_SY + l] = s[o + _B_SY + l] + mn * py
    o = compiled.lane_block(n - 1)
    for l in range(lanes):
        s[row_x + l] = s[o + _B_SX + l] / total_mass
        s[row_y + l] = s[o + _B_SY + l] / total_mass


@njit(cache=True, nogil=True, error_model="numpy")
def _observe_lanes(model, s, nl):
    """The parts of :func:`_observe` that need a sweep, for lanes 0..nl-1 (state
    rows Q, U): joint angles wrapped to (-pi, pi] and joint rates (per-link rows),
    cos/sin of theta_1, the kinetic energy (J) and the check's fastest rate (rad/s)
    and largest |phi_k| (rad) of :func:`_measures` (header rows)."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit = model[:8]
    rotor = model[12]
    geared = rotor.shape[0] > 0
    n = m.shape[0]
    lanes = _U(nl)
    b0 = compiled.lane_block(0)
    for l in range(lanes):
        V = s[_H_U0 + l]
        W = s[_H_U1 + l]
        s[b0 + _B_V + l] = V
        s[b0 + _B_W + l] = W
        s[b0 + _B_K + l] = 0.5 * (m[0] * V * V + inertia[0] * W * W)
        s[_H_RATE + l] = abs(W)
        s[_H_FOLD + l] = 0.0
        sn, cs = compiled.sincos(s[b0 + _B_Q + l])
        s[_H_COS1 + l] = cs
        s[_H_SIN1 + l] = sn
    for k in range(n - 1):
        o = compiled.lane_block(k)
        p = o + compiled.lane_block(1) - compiled.lane_block(0)
        hk = h[k]
        hn = h[k + 1]
        mn = m[k + 1]
        In = inertia[k + 1]
        jr = rotor[k] if geared else 0.0
        for l in range(lanes):
            phi = s[p + _B_Q + l] - s[o + _B_Q + l]
            S, C = compiled.sincos(phi)
            V = s[o + _B_V + l]
            W = s[o + _B_W + l]
            nV = V * C + W * hk * S  # eq. 6
            nW = (V * S - W * hk * C) / hn  # eq. 7
            wrapped = compiled.wrap_angle(phi)
            s[o + _B_PHI + l] = wrapped
            s[o + _B_PHIDOT + l] = nW - W
            s[p + _B_V + l] = nV
            s[p + _B_W + l] = nW
            kin = s[o + _B_K + l] + 0.5 * (mn * nV * nV + In * nW * nW)
            if geared:  # the rotor's 1/2 N^2 J_r phidot^2 (compiled.KernelModel.rotor_inertia)
                kin += 0.5 * jr * ((nW - W) * (nW - W))
            s[p + _B_K + l] = kin
            s[_H_RATE + l] = max(s[_H_RATE + l], abs(nW), abs(nW - W))
            s[_H_FOLD + l] = max(s[_H_FOLD + l], abs(wrapped))
    o = compiled.lane_block(n - 1)
    for l in range(lanes):
        s[_H_KINETIC + l] = s[o + _B_K + l]


# aux[b, AUX_REFINEMENTS] of a row that the lane kernel (_step_lanes) left to :func:`_finish_rows`; negative,
# so never a real count of halvings. The rest of such a row is written by _finish_rows.
PENDING_LANE = -1.0  # the lane attempt failed the check: refined or undone from the pre-step state;
#                      aux[AUX_FAILED] and aux[AUX_RESIDUAL] hold the lane attempt's verdict meanwhile
PENDING_ALONE = -2.0  # link angles beyond the lanes' sin/cos range: stepped by the per-snake kernel


@njit(cache=True, nogil=True)
def _load_lane(s, lane, q, u, work, motor):
    """Put one snake's state (q (n+2,), u (2,)), work and motors' energy (J) into lane ``lane`` of the scratch."""
    n = q.shape[0] - 2
    for k in range(n):
        s[compiled.lane_block(k) + _B_Q + lane] = q[k]
    s[_H_X + lane] = q[n]
    s[_H_Y + lane] = q[n + 1]
    s[_H_U0 + lane] = u[0]
    s[_H_U1 + lane] = u[1]
    s[_H_WORK + lane] = work
    s[_H_MOTOR + lane] = motor


@njit(cache=True, nogil=True, inline="always")
def _load_pre_step(model, total_mass, q, u, torques, index, start, nl, s):
    """Load snakes index[start:start+nl] into the lanes with their pre-step kinetic energy (row K0) and
    centre of mass (rows CX0, CY0)."""
    compiled.load_lanes(s, q, u, torques, index, start, nl)
    _observe_lanes(model, s, nl)
    for l in range(nl):
        lane = _U(l)
        s[_H_K0 + lane] = s[_H_KINETIC + lane]
    _center_of_mass_lanes(model, total_mass, s, nl, _H_CX0, _H_CY0)


@njit(cache=True, nogil=True, inline="always")
def _store_lane(settings, s, lane, n, b, q, u, obs, aux, code, refinements, residual):
    """Snake b's state, observation and aux row from lane ``lane`` (after _observe_lanes and the
    final _center_of_mass_lanes into rows CX, CY)."""
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    for k in range(n):
        q[b, k] = s[compiled.lane_block(k) + _B_Q + lane]
    q[b, n] = s[_H_X + lane]
    q[b, n + 1] = s[_H_Y + lane]
    u[b, 0] = s[_H_U0 + lane]
    u[b, 1] = s[_H_U1 + lane]
    cx = s[_H_CX + lane]
    cy = s[_H_CY + lane]
    j = 0
    if include_position:
        obs[b, 0] = cx
        obs[b, 1] = cy
        j = 2
    for k in range(n - 1):
        obs[b, j + k] = s[compiled.lane_block(k) + _B_PHI + lane]
    j += n - 1
    obs[b, j] = s[_H_COS1 + lane]
    obs[b, j + 1] = s[_H_SIN1 + lane]
    obs[b, j + 2] = u[b, 0]
    obs[b, j + 3] = u[b, 1]
    j += 4
    for k in range(n - 1):
        obs[b, j + k] = s[compiled.lane_block(k) + _B_PHIDOT + lane]
    env_dt = sim_dt * frame_skip
    aux[b, AUX_X] = cx
    aux[b, AUX_Y] = cy
    aux[b, AUX_VX] = (cx - s[_H_CX0 + lane]) / env_dt
    aux[b, AUX_VY] = (cy - s[_H_CY0 + lane]) / env_dt
    aux[b, AUX_KINETIC] = s[_H_KINETIC + lane]
    aux[b, AUX_WORK] = s[_H_WORK + lane]
    aux[b, AUX_FAILED] = code
    aux[b, AUX_REFINEMENTS] = refinements
    aux[b, AUX_RESIDUAL] = residual
    aux[b, AUX_MOTOR_ENERGY] = s[_H_MOTOR + lane]


# inline="always": one dispatcher level less between the env step and the lane stages (see
# compiled.rk4_lanes_estimate); _step_lanes and _step_lanes_parallel each get their own copy
@njit(cache=True, nogil=True, inline="always")
def _step_lane_group(model, settings, total_mass, q, u, torques, obs, aux, index, start, nl, s, forces, scale):
    """The first attempt of :func:`_step_one` for the snakes index[start:start+nl] (nl <= LANES), in
    lanes. A snake that passes the check gets its results (and with ``forces`` (B, n) not empty, its
    wheel forces and traction scale from the integrator's last traction pass at the final state: the
    model must have finite grip). A snake that fails keeps its pre-step state, its verdict in
    aux[AUX_FAILED] and aux[AUX_RESIDUAL] and aux[AUX_REFINEMENTS] = PENDING_LANE, for
    :func:`_finish_rows`. Returns the number of those."""
    m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit = model[:8]
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    n = m.shape[0]
    _load_pre_step(model, total_mass, q, u, torques, index, start, nl, s)
    compiled.rk4_lanes_estimate(model, s, nl, sim_dt, frame_skip, err_tol, h[0])
    _observe_lanes(model, s, nl)
    _center_of_mass_lanes(model, total_mass, s, nl, _H_CX, _H_CY)
    pending = 0
    for l in range(nl):
        lane = _U(l)
        b = index[start + l]
        finite = (math.isfinite(s[_H_WORK + lane]) and math.isfinite(s[_H_U0 + lane])
                  and math.isfinite(s[_H_U1 + lane]) and math.isfinite(s[_H_X + lane])
                  and math.isfinite(s[_H_Y + lane]) and math.isfinite(s[_H_KINETIC + lane]))
        for k in range(n):
            finite = finite and math.isfinite(s[compiled.lane_block(k) + _B_Q + lane])
        code, residual = _verdict(finite, s[_H_ERR + lane], s[_H_K0 + lane], s[_H_KINETIC + lane],
                                  s[_H_WORK + lane], s[_H_RATE + lane], s[_H_FOLD + lane], sim_dt, settings)
        if code != 0:
            aux[b, AUX_FAILED] = code
            aux[b, AUX_RESIDUAL] = residual
            aux[b, AUX_REFINEMENTS] = PENDING_LANE
            pending += 1
            continue
        _store_lane(settings, s, lane, n, b, q, u, obs, aux, 0, 0, residual)
        if forces.shape[0] > 0:
            scale[b] = compiled.lane_wheel_forces(s, lane, n, forces[b])
    return pending


@njit(cache=True, nogil=True)
def _total_mass(m):
    total = m[0]  # summed in the order of _center_of_mass
    for k in range(1, m.shape[0]):
        total += m[k]
    return total


@njit(cache=True, nogil=True, inline="always")
def _lane_rows(q, aux):
    """(index, count) of ``compiled.split_lanes(q)``, the rows beyond the lanes' range marked
    aux[AUX_REFINEMENTS] = PENDING_ALONE."""
    index, count = compiled.split_lanes(q)
    for i in range(count, q.shape[0]):
        aux[index[i], AUX_REFINEMENTS] = PENDING_ALONE
    return index, count


@njit(cache=True, nogil=True)
def _step_lanes(model, settings, q, u, torques, obs, aux, forces, scale):
    """The first attempt of the env step of B snakes on one thread, in lane groups of compiled.LANES
    (:func:`_step_lane_group`). Returns the numbers of snakes left (state untouched): to
    :func:`_finish_rows`, those that failed the check; to :func:`_step_alone`, the rare snake whose angles
    exceed the lanes' sin/cos range (aux[AUX_REFINEMENTS] = PENDING_ALONE). ``forces`` (B, n), ``scale``
    (B,): the wheel forces and traction scale at the step's end with finite grip, or empty arrays for none."""
    m = model[0]
    n = m.shape[0]
    index, count = _lane_rows(q, aux)
    s = np.empty(compiled.lanes_scratch_size(n))
    total_mass = _total_mass(m)
    pending = 0
    for start in range(0, count, _LANES):
        pending += _step_lane_group(model, settings, total_mass, q, u, torques, obs, aux, index, start,
                                    min(_LANES, count - start), s, forces, scale)
    return pending, q.shape[0] - count


# ---------------------------------------------------------------------- what the lanes left
# The refinement and the per-snake path compile on their own (:func:`_finish_rows`), so the first step
# compiles only the lane kernel; a background process compiles them meanwhile (compile_in_background).

@njit(cache=True, nogil=True, inline="always")
def _finish_lane_group(model, settings, total_mass, q, u, torques, obs, aux, index, start, nl, s, forces, scale,
                       links, dq, du):
    """Snakes index[start:start+nl] whose lane attempt failed (PENDING_LANE): each is integrated again
    from its pre-step state by the per-snake kernel from one halving on (:func:`_integrate_checked`), or
    undone (a fold, or no refinements allowed); then observed and stored in lanes exactly as a passing
    lane is, so a snake's result does not depend on its batch. With ``forces`` not empty (finite grip:
    see step_inplace), its wheel forces and traction scale by their own sweep, as
    ``compiled.wheel_lateral_forces`` gives them with grip (without compiling its unlimited-grip sweep)."""
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    n = model[0].shape[0]
    _load_pre_step(model, total_mass, q, u, torques, index, start, nl, s)
    codes = np.zeros(nl, np.int64)
    refinements = np.zeros(nl, np.int64)
    residuals = np.zeros(nl)
    q1 = np.empty(n + 2)
    u1 = np.empty(2)
    no_du = np.empty(0)
    for l in range(nl):
        lane = _U(l)
        b = index[start + l]
        code = np.int64(aux[b, AUX_FAILED])
        residual = aux[b, AUX_RESIDUAL]
        work = 0.0
        motor = 0.0
        r = 0
        if max_ref > 0 and code != FAIL_FOLD:  # an accurate fold is final (module doc)
            code, work, r, residual, motor = _integrate_checked(model, settings, _ONE, max_ref, q[b], u[b],
                                                                torques[b], s[_H_K0 + lane], q1, u1)
        else:  # element by element: a slice copy compiles numba's shape-mismatch message (~2 s cold)
            for j in range(n + 2):
                q1[j] = q[b, j]
            u1[0] = u[b, 0]
            u1[1] = u[b, 1]
        # the accepted refined state, or the pre-step state of a failed step
        _load_lane(s, lane, q1, u1, work, motor)
        codes[l] = code
        refinements[l] = r
        residuals[l] = residual
    _observe_lanes(model, s, nl)
    _center_of_mass_lanes(model, total_mass, s, nl, _H_CX, _H_CY)
    for l in range(nl):
        b = index[start + l]
        _store_lane(settings, s, _U(l), n, b, q, u, obs, aux, codes[l], refinements[l], residuals[l])
        if forces.shape[0] > 0:
            scale[b] = compiled.traction_derivatives(model, q[b], u[b], torques[b], dq, du, links, forces[b], 1.0,
                                                     no_du)[1]


@njit(cache=True, nogil=True)
def _step_forces(model, q, u, torques, b, forces, scale, links, dq, du):
    """Snake b's wheel forces and traction scale at its current state by their own sweep
    (compiled.wheel_lateral_forces), for a snake stepped alone (beyond the lanes' range)."""
    scale[b] = compiled.wheel_lateral_forces(model, q[b], u[b], torques[b], links, dq, du, forces[b])


@njit(cache=True, nogil=True)
def _step_alone(model, settings, q, u, torques, obs, aux, forces, scale):
    """Step the rows :func:`_step_lanes` left as PENDING_ALONE by the per-snake kernel :func:`_step_one`
    (libm sin/cos); compiled only when a snake first turns beyond the lanes' range."""
    n = model[0].shape[0]
    links = np.empty((n, compiled.LINK_CHANNELS))
    dq = np.empty(n + 2)
    du = np.empty(2)
    for b in range(q.shape[0]):
        if aux[b, AUX_REFINEMENTS] == PENDING_ALONE:
            _step_one(model, settings, q[b], u[b], torques[b], obs[b], aux[b])
            if forces.shape[0] > 0:
                _step_forces(model, q, u, torques, b, forces, scale, links, dq, du)


@njit(cache=True, nogil=True, inline="always")
def _pending_lanes(aux, rows):
    """(index, count): the rows among ``rows`` (row numbers) marked PENDING_LANE, in order."""
    index = np.empty(rows.shape[0], np.int64)
    count = 0
    for b in rows:
        if aux[b, AUX_REFINEMENTS] == PENDING_LANE:
            index[count] = b
            count += 1
    return index, count


@njit(cache=True, nogil=True)
def _finish_rows(model, settings, q, u, torques, obs, aux, forces, scale):
    """Finish the step of the rows :func:`_step_lanes` left as PENDING_LANE, on one thread: refinement in
    the per-snake kernel, or the step undone. ``forces``, ``scale``: as given to _step_lanes."""
    m = model[0]
    n = m.shape[0]
    index, count = _pending_lanes(aux, np.arange(aux.shape[0]))
    links = np.empty((n, compiled.LINK_CHANNELS))
    dq = np.empty(n + 2)
    du = np.empty(2)
    s = np.empty(compiled.lanes_scratch_size(n))
    total_mass = _total_mass(m)
    for start in range(0, count, _LANES):
        _finish_lane_group(model, settings, total_mass, q, u, torques, obs, aux, index, start,
                           min(_LANES, count - start), s, forces, scale, links, dq, du)


@njit(cache=True, parallel=True)
def _step_lanes_parallel(model, settings, q, u, torques, obs, aux, forces, scale):
    """:func:`_step_lanes` with the lane groups spread over threads, each group finishing its own failed
    snakes as :func:`_finish_rows` does (the same bits): one parallel region per step, since each region
    waits for a free core (see PARALLEL_MIN_WORK), and large batches refine every step. Compiled on the
    first large batch with more than one thread, refinement included. Returns (0, snakes left to
    :func:`_step_alone`)."""
    m = model[0]
    n = m.shape[0]
    index, count = _lane_rows(q, aux)
    size = compiled.lanes_scratch_size(n)
    total_mass = _total_mass(m)
    for group in prange((count + _LANES - 1) // _LANES):
        start = group * _LANES
        nl = min(_LANES, count - start)
        s = np.empty(size)
        if _step_lane_group(model, settings, total_mass, q, u, torques, obs, aux, index, start, nl, s,
                            forces, scale) > 0:
            left, k = _pending_lanes(aux, index[start:start + nl])
            _finish_lane_group(model, settings, total_mass, q, u, torques, obs, aux, left, 0, k, s, forces,
                               scale, np.empty((n, compiled.LINK_CHANNELS)), np.empty(n + 2), np.empty(2))
    return 0, q.shape[0] - count


@njit(cache=True, nogil=True)
def _reset_one(model, settings, noise, q, u, obs, aux):
    """Near-straight start: theta_k = noise_k, u = noise[n:], CM of the whole snake at the origin."""
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    n = q.shape[0] - 2
    for k in range(n):
        q[k] = noise[k]
    q[n] = 0.0
    q[n + 1] = 0.0
    u[0] = noise[n]
    u[1] = noise[n + 1]
    cx, cy = _center_of_mass(model, q)
    # shift so the whole snake's CM sits at the origin (x, y of eq. 1 is link 1's CM)
    q[n] = -cx
    q[n + 1] = -cy
    cx, cy = _center_of_mass(model, q)
    aux[AUX_X] = cx
    aux[AUX_Y] = cy
    aux[AUX_VX] = 0.0
    aux[AUX_VY] = 0.0
    aux[AUX_KINETIC] = _observe(model, q, u, include_position, cx, cy, obs)
    aux[AUX_WORK] = 0.0
    aux[AUX_FAILED] = 0.0
    aux[AUX_REFINEMENTS] = 0.0
    aux[AUX_RESIDUAL] = 0.0
    aux[AUX_MOTOR_ENERGY] = 0.0


@njit(cache=True, nogil=True)
def _reset_alone(model, settings, noise, q, u, obs, aux):
    """:func:`_reset_one` of the rows :func:`_reset_lanes` left (aux[AUX_REFINEMENTS] = PENDING_ALONE)."""
    for b in range(noise.shape[0]):
        if aux[b, AUX_REFINEMENTS] == PENDING_ALONE:
            _reset_one(model, settings, noise[b], q[b], u[b], obs[b], aux[b])


@njit(cache=True, nogil=True)
def _observe_alone(model, settings, q, u, obs, aux):
    """:func:`_observe` of the rows :func:`_observe_rows_lanes` left (aux[AUX_REFINEMENTS] = PENDING_ALONE)."""
    sim_dt, frame_skip, include_position, tol, e_floor, err_tol, max_ref = settings
    for b in range(q.shape[0]):
        if aux[b, AUX_REFINEMENTS] != PENDING_ALONE:
            continue
        cx, cy = _center_of_mass(model, q[b])
        aux[b, AUX_X] = cx
        aux[b, AUX_Y] = cy
        aux[b, AUX_VX] = 0.0
        aux[b, AUX_VY] = 0.0
        aux[b, AUX_KINETIC] = _observe(model, q[b], u[b], include_position, cx, cy, obs[b])
        aux[b, AUX_WORK] = 0.0
        aux[b, AUX_FAILED] = 0.0
        aux[b, AUX_REFINEMENTS] = 0.0
        aux[b, AUX_RESIDUAL] = 0.0
        aux[b, AUX_MOTOR_ENERGY] = 0.0


# Reset and observation in lanes: the lane helpers the step compiles anyway, so a first reset compiles no
# per-snake code (that waits for a snake beyond the lanes' range); the same bits as _reset_one and
# _observe (the lane sin/cos and wrapping are theirs; tests/physics/test_lanes.py).

@njit(cache=True, nogil=True, inline="always")
def _store_still(settings, s, lane, n, b, q, u, obs, aux):
    """:func:`_store_lane` of a state that was not stepped: velocity, work, energy and verdict 0."""
    _store_lane(settings, s, lane, n, b, q, u, obs, aux, 0, 0, 0.0)
    aux[b, AUX_VX] = 0.0
    aux[b, AUX_VY] = 0.0


@njit(cache=True, nogil=True)
def _reset_lanes(model, settings, noise, q, u, obs, aux):
    """:func:`_reset_one` of every row of noise (B, n+2), in lane groups. Returns the number of rows left
    to :func:`_reset_alone` (angles beyond the lanes' range), marked aux[AUX_REFINEMENTS] = PENDING_ALONE."""
    m = model[0]
    n = m.shape[0]
    index, count = _lane_rows(noise, aux)  # the angles are noise[:, :n]
    s = np.empty(compiled.lanes_scratch_size(n))
    total_mass = _total_mass(m)
    for start in range(0, count, _LANES):
        nl = min(_LANES, count - start)
        for l in range(nl):
            lane = _U(l)
            b = index[start + l]
            for k in range(n):
                s[compiled.lane_block(k) + _B_Q + lane] = noise[b, k]
            s[_H_X + lane] = 0.0
            s[_H_Y + lane] = 0.0
            s[_H_U0 + lane] = noise[b, n]
            s[_H_U1 + lane] = noise[b, n + 1]
            s[_H_WORK + lane] = 0.0
            s[_H_MOTOR + lane] = 0.0
        _center_of_mass_lanes(model, total_mass, s, nl, _H_CX, _H_CY)
        for l in range(nl):  # shift so the whole snake's CM sits at the origin, as _reset_one
            lane = _U(l)
            s[_H_X + lane] = -s[_H_CX + lane]
            s[_H_Y + lane] = -s[_H_CY + lane]
        _center_of_mass_lanes(model, total_mass, s, nl, _H_CX, _H_CY)
        _observe_lanes(model, s, nl)
        for l in range(nl):
            _store_still(settings, s, _U(l), n, index[start + l], q, u, obs, aux)
    return noise.shape[0] - count


@njit(cache=True, nogil=True)
def _observe_rows_lanes(model, settings, q, u, obs, aux):
    """The observation and aux row of every state q (B, n+2), u (B, 2), as :func:`_observe` and
    :func:`_center_of_mass` give them (velocity and work 0), in lane groups. Returns the number of rows
    left to :func:`_observe_alone`, marked aux[AUX_REFINEMENTS] = PENDING_ALONE."""
    m = model[0]
    n = m.shape[0]
    index, count = _lane_rows(q, aux)
    s = np.empty(compiled.lanes_scratch_size(n))
    total_mass = _total_mass(m)
    for start in range(0, count, _LANES):
        nl = min(_LANES, count - start)
        for l in range(nl):
            _load_lane(s, _U(l), q[index[start + l]], u[index[start + l]], 0.0, 0.0)
        _center_of_mass_lanes(model, total_mass, s, nl, _H_CX, _H_CY)
        _observe_lanes(model, s, nl)
        for l in range(nl):
            _store_still(settings, s, _U(l), n, index[start + l], q, u, obs, aux)
    return q.shape[0] - count


# --------------------------------------------------------------------------- pure API
def _outputs(params: PhysicsParams, batch: tuple):
    return np.empty(batch + (params.obs_size,)), np.empty(batch + (AUX_SIZE,))


def _as_state(params: PhysicsParams, q, u):
    q = np.array(q, dtype=np.float64, order="C", copy=True)
    u = np.array(u, dtype=np.float64, order="C", copy=True)
    n = params.n_links
    if q.shape[-1:] != (n + 2,) or u.shape[-1:] != (2,) or q.shape[:-1] != u.shape[:-1] or q.ndim > 2:
        raise ValueError(f"q must have shape (n+2,)=({n + 2},) or (B, {n + 2}) and u shape (2,) or (B, 2), "
                         f"got q {q.shape}, u {u.shape}")
    return q, u


def step(params: PhysicsParams, q, u, torques):
    """One env step of duration ``params.dt`` with torques (N m) held constant.

    Args:
        q: (n+2,) or (B, n+2) coordinates (eq. 1); u: (2,) or (B, 2) speeds (eq. 2);
        torques: (n-1,) or (B, n-1) joint torques (N m), already scaled and clipped.

    Returns (q_next, u_next, obs, aux); aux columns are AUX_* (CM position (m),
    CM velocity over the step (m/s), kinetic energy (J), work of all loads (J),
    failure code (0 or FAIL_*), substep halvings used, relative work-energy
    residual, the motors' energy (J)). A failed snake keeps its input state. Inputs are not modified.
    """
    q, u = _as_state(params, q, u)
    torques = np.ascontiguousarray(torques, dtype=np.float64)
    if torques.shape != q.shape[:-1] + (params.n_links - 1,):
        raise ValueError(f"torques must have shape {q.shape[:-1] + (params.n_links - 1,)}, got {torques.shape}")
    obs, aux = _outputs(params, q.shape[:-1])
    if q.ndim == 1:  # a batch of one: the same lane kernel, so it equals any row of a batch bit for bit
        step_inplace(params, q[None], u[None], torques[None], obs[None], aux[None])
    else:
        step_inplace(params, q, u, torques, obs, aux)
    return q, u, obs, aux


def _threaded(q) -> bool:
    # threads pay off only for enough work per call (see PARALLEL_MIN_WORK), and only with more than one
    # thread: with one, the parallel kernel runs the same loop after a compile of its own (the whole
    # lane kernel again) on the first large batch
    return q.shape[0] * q.shape[1] >= PARALLEL_MIN_WORK and numba.get_num_threads() > 1


_NO_FORCES = np.empty((0, 0))
_NO_SCALE = np.empty(0)


def step_inplace(params: PhysicsParams, q, u, torques, obs, aux, forces=None, scale=None):
    """:func:`step` of a batch (2-D arrays) writing into caller-owned float64 C-contiguous buffers (the
    envs' hot path). With ``forces`` (B, n) and ``scale`` (B,), also each snake's wheel lateral forces
    (N) and traction scale at the step's end, as :func:`wheel_lateral_forces` gives them: with finite
    grip read from the integrator's last traction pass at the final state, so they cost no sweep.

    The lane kernel steps every snake it can (:func:`_step_lanes`); :func:`_finish_rows` finishes the
    snakes that failed its check (refinement, undone steps) and :func:`_step_alone` those beyond the
    lanes' range, each called only when there are any."""
    model = params.kernel_model
    settings = params.kernel_settings
    gripped = model[11].shape[0] > 0
    if forces is None or not gripped:  # unlimited grip: the forces by their own sweep, below
        lane_forces, lane_scale = _NO_FORCES, _NO_SCALE
    else:
        lane_forces, lane_scale = forces, scale
    threaded = _threaded(q)
    pending, alone = (_step_lanes_parallel if threaded else _step_lanes)(model, settings, q, u, torques, obs,
                                                                          aux, lane_forces, lane_scale)
    if pending or alone:
        _finish_step(model, settings, q, u, torques, obs, aux, lane_forces, lane_scale, pending, alone)
    if forces is not None and not gripped:
        compiled.wheel_lateral_forces_batch(model, q, u, torques, forces, scale)


def _finish_step(model, settings, q, u, torques, obs, aux, forces, scale, pending, alone) -> None:
    """The rows :func:`_step_lanes` left: ``alone`` ones by the per-snake kernel, ``pending`` ones
    refined or undone by :func:`_finish_rows` (loaded from the background compile's cache)."""
    if alone:
        _step_alone(model, settings, q, u, torques, obs, aux, forces, scale)
    if pending:  # (never threaded: the parallel kernel finishes its own)
        if _background is not None and not _finish_rows.signatures:
            await_background_compile()
        _finish_rows(model, settings, q, u, torques, obs, aux, forces, scale)


def reset(params: PhysicsParams, noise):
    """Initial states from uniform noise (B, n+2) or (n+2,): theta_k = noise[k] (rad),
    (V_1, thetadot_1) = noise[n:] (m/s, rad/s), whole-snake CM at the origin.

    Returns (q, u, obs, aux) shaped like :func:`step`'s output.
    """
    noise = np.ascontiguousarray(noise, dtype=np.float64)
    n = params.n_links
    if noise.shape[-1:] != (n + 2,) or noise.ndim > 2:
        raise ValueError(f"noise must have shape ({n + 2},) or (B, {n + 2}), got {noise.shape}")
    flat = noise.reshape(-1, n + 2)
    q = np.empty((flat.shape[0], n + 2))
    u = np.empty((flat.shape[0], 2))
    obs, aux = _outputs(params, (flat.shape[0],))
    if _reset_lanes(params.kernel_model, params.kernel_settings, flat, q, u, obs, aux):
        _reset_alone(params.kernel_model, params.kernel_settings, flat, q, u, obs, aux)
    if noise.ndim == 1:
        return q[0], u[0], obs[0], aux[0]
    return q, u, obs, aux


def observe(params: PhysicsParams, q, u):
    """(obs, aux) of given states (aux velocity and work are 0: no step was taken)."""
    q, u = _as_state(params, q, u)
    qf = q.reshape(-1, params.n_links + 2)
    uf = u.reshape(-1, 2)
    obs, aux = _outputs(params, (qf.shape[0],))
    if _observe_rows_lanes(params.kernel_model, params.kernel_settings, qf, uf, obs, aux):
        _observe_alone(params.kernel_model, params.kernel_settings, qf, uf, obs, aux)
    if q.ndim == 1:
        return obs[0], aux[0]
    return obs, aux


def wheel_lateral_forces(params: PhysicsParams, q, u, torques, out, scale) -> None:
    """The wheels' lateral forces (N) of states q (B, n+2), u (B, 2) under the commanded torques
    (B, n-1) (N m) into out (B, n): eq. 27's multipliers by the compiled O(n) backward sweep
    (``compiled.wheel_lateral_forces``), with the step's motor, traction limit, damping and barrier;
    the traction scale of each state into scale (B,) (1 with unlimited grip)."""
    compiled.wheel_lateral_forces_batch(params.kernel_model, q, u, torques, out, scale)


# Said once per process on stderr before the first step compiles the kernels: measured 11-16 s from an
# empty cache on the idle 2-core machine for the no-slip wheels, 13-16 s for the sliding ones with their row
# kernel compiled in a second process (docs/benchmarks.md, cold start); numba caches the result on disk.
COMPILE_NOTICE = ("snake_env: compiling the physics kernels, first run only (about 10-20 s on a "
                  "2-core machine; cached afterwards)")
_compile_announced = False


def _cached(dispatcher) -> bool:
    """Whether numba's on-disk cache holds compiled code of ``dispatcher`` for its source file; True when
    it cannot tell."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba internals moved: say nothing rather than something wrong
        return True


def announce_compile(kernel=None) -> bool:
    """Print :data:`COMPILE_NOTICE` to stderr once per process if the kernels are not cached yet; True if printed.
    ``kernel``: the compiled step the env's first step needs (default: the lane kernel of the no-slip wheels)."""
    global _compile_announced
    kernel = _step_lanes if kernel is None else kernel
    if _compile_announced or kernel.signatures or _cached(kernel):
        return False
    _compile_announced = True
    print(COMPILE_NOTICE, file=sys.stderr, flush=True)
    return True


# The kernels only some steps need (:func:`_finish_rows`: refinement and the per-snake path; the wheel
# forces of unlimited grip) compile in a second process, :mod:`snake_env.physics.background_compile`,
# while this one compiles the lane kernel of the first step: numba compiles one function at a time per
# process, so on two cores the two compiles overlap. The child writes numba's on-disk cache, from which
# this process loads them when a step first needs them (waiting for the child if it is still at work).
BACKGROUND_WAIT_S = 600.0  # s: longest wait for the child before compiling here instead
_background = None  # the child process (subprocess.Popen) until awaited
_background_done = None  # POSIX: the read end of a pipe on which the child says it has cached every kernel
_background_started = False
_compiling_on = []  # children awaited on their pipe, which may compile on (await_background_compile(until_exit))


def compile_in_background(unlimited_grip: bool = False, sliding_method: int | None = None) -> bool:
    """Start :mod:`snake_env.physics.background_compile` once per process if :func:`_finish_rows` is not
    compiled or cached yet; with ``unlimited_grip`` (the env's wheels never slip) it compiles the wheel
    forces' own sweep too, which such an env needs at its first step. With ``sliding_method`` it compiles
    instead the sliding wheels' row kernel of that friction solve (``sliding_step.ADVANCE_ROWS``), if not
    compiled or cached yet. True if started."""
    global _background, _background_done, _background_started
    if sliding_method is None:
        kernel = _finish_rows
    else:
        kernel = sliding_step.ADVANCE_ROWS[sliding_method]
        kernel = getattr(kernel, "func", kernel)  # (a partial of a kernel: the exact solves)
    if (_background_started or getattr(kernel, "signatures", True) or getattr(sys, "frozen", False)
            or _cached(kernel)):
        return False  # (a frozen app's sys.executable is the app, not Python; not a numba kernel: nothing to cache)
    _background_started = True
    args = [sys.executable, "-m", "snake_env.physics.background_compile"]
    args += ["--unlimited-grip"] if unlimited_grip else []
    args += ["--sliding", str(sliding_method)] if sliding_method is not None else []
    done_read, done_write, pass_fds = None, None, ()
    if os.name == "posix":  # the child says "done" before its exit, which takes ~0.4 s more (numba, LLVM)
        done_read, done_write = os.pipe()
        args += ["--done-fd", str(done_write)]
        pass_fds = (done_write,)
    try:
        _background = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.DEVNULL, pass_fds=pass_fds)
    except OSError:  # no process to spare: the kernels compile here when first needed
        if done_read is not None:
            os.close(done_read)
        return False
    finally:
        if done_write is not None:
            os.close(done_write)  # the child's copy stays open until it writes or exits
    _background_done = done_read
    return True


def background_compile_running() -> bool:
    """Whether this process started a background compile that it has not awaited yet."""
    return _background is not None


def await_background_compile(until_exit: bool = False) -> None:
    """Wait for the background compile (if any) to finish, so the next call loads its kernels from the
    cache: until the child says so on its pipe (or exits, which closes the pipe), else until it exits.
    ``until_exit``: until it exits, having cached the kernels it compiles after saying so (the sliding
    wheels' exact solves), as a benchmark's next fresh process expects."""
    global _background, _background_done
    child, _background = _background, None
    done, _background_done = _background_done, None
    if child is None:
        if until_exit:  # one awaited earlier (its pipe read) may still be compiling what it compiles after
            for earlier in _compiling_on:
                earlier.wait()
        return
    if done is not None:
        with os.fdopen(done, "rb") as pipe:
            ready, _, _ = select.select([pipe], [], [], BACKGROUND_WAIT_S)
            if ready:
                pipe.read(1)  # b"d" when done; b"" when the child exited without saying so
            else:  # stuck: compile here (the cache write is atomic either way)
                child.kill()
        if not until_exit:
            _compiling_on.append(child)
            threading.Thread(target=child.wait, daemon=True).start()  # reaps it when it exits
            return
    try:
        child.wait(timeout=BACKGROUND_WAIT_S)
    except subprocess.TimeoutExpired:  # stuck: compile here (the cache write is atomic either way)
        child.kill()
        child.wait()


class InstantPhysics:
    """B snakes whose commands reach the joints at once, stepped by one compiled call (:func:`step_inplace`).

    The interface every batch physics shares (:func:`snake_env.physics.batch.batch_physics` picks one):
    ``reset(rows, noise, rng)``, ``observe(q, u)``, ``step(q, u, torques, obs, aux, forces, scale)``
    (in place: the state, observation, aux row with the motors' energy, and the wheels' forces) and
    ``bind_step`` (the same on fixed buffers, as a call of no arguments),
    ``wheel_lateral_forces``, the wheels' ``grip`` and ``wheel_load`` (N, (B, n) or (n,)) and the
    per-row ``draws`` of a randomized batch ({} here)."""

    def __init__(self, config, params: PhysicsParams, num_envs: int):
        self.params = params
        self.grip = config.grip()
        self.wheel_load = config.wheel_load()
        self.draws: dict[str, np.ndarray] = {}
        # finite grip and a batch too small for threads (the single env): step_inplace's path without its
        # per-step choices, ~0.5 us of a ~12 us single-env step
        self._lanes_alone = (params.kernel_model[11].shape[0] > 0
                             and num_envs * (config.n_links + 2) < PARALLEL_MIN_WORK)
        self._model, self._settings = params.kernel_model, params.kernel_settings

    def reset(self, rows, noise, rng):
        """(q, u, obs, aux) of the new episodes of ``rows`` from their start ``noise`` (rows, n+2)."""
        return reset(self.params, noise)

    def observe(self, q, u):
        return observe(self.params, q, u)

    def step(self, q, u, torques, obs, aux, forces=None, scale=None):
        if self._lanes_alone and forces is not None:
            pending, alone = _step_lanes(self._model, self._settings, q, u, torques, obs, aux, forces, scale)
            if pending or alone:
                _finish_step(self._model, self._settings, q, u, torques, obs, aux, forces, scale, pending, alone)
        else:
            step_inplace(self.params, q, u, torques, obs, aux, forces, scale)

    def bind_step(self, q, u, torques, obs, aux, forces=None, scale=None):
        """:meth:`step` on these buffers as a call of no arguments, for a caller that owns them and updates
        them in place (:class:`snake_env.envs.core.SnakeBatch`). The single env's lane kernel is then called
        without numba's per-call dispatch (:class:`.bound_kernel.BoundKernel`, ~1 us of a ~12 us step)."""
        if not (self._lanes_alone and forces is not None):
            return functools.partial(self.step, q, u, torques, obs, aux, forces, scale)
        lanes = BoundKernel(_step_lanes, self._model, self._settings, q, u, torques, obs, aux, forces, scale)

        def step():
            pending, alone = lanes.call()
            if pending or alone:
                _finish_step(self._model, self._settings, q, u, torques, obs, aux, forces, scale, pending, alone)

        return step

    def held_torques(self, torques):
        """The torques (N m) held over the last substep of every row."""
        return torques

    def wheel_lateral_forces(self, q, u, torques, out, scale) -> None:
        wheel_lateral_forces(self.params, q, u, self.held_torques(torques), out, scale)
