"""Wheels that slide, in the env: the batch physics of ``wheel_model="sliding"``.

The env's default physics keeps every wheel on the paper's no-slip constraint (eq. 27) and applies the
traction limit. With ``wheel_model="sliding"`` each wheel instead grips while its sideways force stays
within mu m_k g and slides under Coulomb friction beyond it: the unconstrained chain of eqs. 22-25 with
exact Coulomb friction, time-stepped (:mod:`snake_env.dynamics.sliding_step`). The motors, dampings,
joint-limit barrier and rotors are the env's own; there is no traction limit (a wheel slides instead).

:class:`SlidingWheelPhysics` has the interface of :class:`~snake_env.physics.stepping.InstantPhysics`, so
every task's single and vector env steps it unchanged. It keeps each row's n + 2 generalized velocities
beside the env's (q, u): while wheels slide, u = (V_1, thetadot_1) no longer determines the others.
The observation keeps its layout; the joint rates are the chain's own, V_1 is link 1's CM velocity along
link 1. ``info["wheel_lateral_force"]`` is each wheel's friction force over the step's last substep (N),
``wheel_slip`` whether the wheel slid on it, ``traction_scale`` is 1.

Checked as the RK4 step is (docs/env.md, "Checked integration"): a row whose step is not finite, folds a
joint, runs away or misses the work-energy balance (friction's work included) within
``energy_tolerance`` is stepped again from its pre-step state with the substep halved, up to
``max_refinements`` times; then it is a simulation failure, its pre-step state kept.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from snake_env.dynamics import sliding_step
from snake_env.dynamics.lagrange import consistent_qdot

from . import stepping
from .sliding_reference import sliding_wheels
from .stepping import (AUX_FAILED, AUX_KINETIC, AUX_MOTOR_ENERGY, AUX_REFINEMENTS, AUX_RESIDUAL, AUX_VX, AUX_VY,
                       AUX_WORK, AUX_X, AUX_Y, FAIL_ENERGY, FAIL_FOLD, FAIL_NONFINITE, FAIL_RUNAWAY, FOLD_ANGLE,
                       MAX_SUBSTEP_ANGLE, _wrap, observe, reset)

# s: the longest time-stepping substep. Semi-implicit Euler is first order: on Snake5 under random servo
# torques at mu = 0.8 the CM after 1 s moves by 1.6e-4 m between h = 1 ms and h -> 0 (0.14 m travelled),
# and the work-energy residual is 3.5e-5 J (tests/dynamics/test_sliding_step.py measures the order).
SUBSTEP = 1e-3
# explicit Euler is stable for a rate r while r h < 2, RK4 while r h < 2.78: where RK4 needs its sim_dt
# divided (PhysicsParams.substeps), the time stepping takes this many times as many substeps
EULER_SUBSTEP_FACTOR = 2


def substeps_per_step(params) -> int:
    """Time-stepping substeps per env step for these params (module constants above)."""
    per_sim_dt = max(math.ceil(params.sim_dt / SUBSTEP - 1e-9), EULER_SUBSTEP_FACTOR * params.substeps)
    return per_sim_dt * params.frame_skip


class SlidingWheelPhysics:
    """B snakes on sliding wheels (module doc), stepped row by row by one compiled call."""

    reports_slip = True  # the env takes wheel_slip from ``slip``, not from comparing forces with the grip

    def __init__(self, config, params, num_envs: int):
        self.config = config
        self.params = params
        # (a motor response in time, torque_lag and control_latency, is ActuatorResponse's, around this physics:
        # it steps one sim_dt at a time under the torque held over it)
        wheels = sliding_wheels(config)
        self.model = wheels.model
        self.constants = wheels.compiled_constants()
        self.method = sliding_step.solve_method(wheels.rotor)  # the friction solve (sliding_step.advance)
        # its row kernel, about half of a first step's compile, in a second process while this one compiles
        # the reset, observation, task and bookkeeping kernels (step waits for it before its first call)
        stepping.compile_in_background(sliding_method=self.method)
        self.grip = config.grip()
        self.wheel_load = config.wheel_load()
        self.draws: dict[str, np.ndarray] = {}
        n, B = config.n_links, num_envs
        self.mass = wheels.mass
        self.half_length = self.model.half_length
        self.substeps = substeps_per_step(params)
        self.qdot = np.zeros((B, n + 2))
        self.impulse = np.zeros((B, n))  # N s: the last substep's lateral impulses (the solver's warm start)
        self.slip = np.zeros((B, n), np.bool_)
        self.lateral = np.zeros((B, n))  # m/s: the wheels' lateral velocities at the last substep's end
        self.last_h = np.full(B, params.dt / self.substeps)
        self._buffers = None  # the step's work arrays (_step_buffers)

    # ------------------------------------------------------------------ state
    def reset(self, rows, noise, rng):
        """(q, u, obs, aux) of the new episodes of ``rows``: the env's start states, every wheel gripping."""
        q, u, obs, aux = reset(self.params, noise)
        self.qdot[rows] = consistent_qdot(self.model, q, u)
        self.impulse[rows] = 0.0
        self.slip[rows] = False
        return q, u, obs, aux

    def set_state(self, q, u) -> None:
        """Put every row at (q, u) with its wheels gripping (the generalized velocities of eqs. 6-7)."""
        self.qdot[:] = consistent_qdot(self.model, np.asarray(q, np.float64), np.asarray(u, np.float64))
        self.impulse[:] = 0.0
        self.slip[:] = False

    # the rows' own state beyond (q, u): generalized velocities, impulses, slip, lateral velocities, last substep
    OWN_STATE = ("qdot", "impulse", "slip", "lateral", "last_h")

    def save_state(self) -> tuple:
        """Copies of :attr:`OWN_STATE` (restore_state puts rows of it back)."""
        return tuple(getattr(self, name).copy() for name in self.OWN_STATE)

    def restore_state(self, saved: tuple, rows) -> None:
        for name, before in zip(self.OWN_STATE, saved):
            getattr(self, name)[rows] = before[rows]

    def observe(self, q, u):
        """(obs, aux) of states (q, u) whose wheels grip (the env's own observation of them)."""
        return observe(self.params, q, u)

    def center_of_mass(self, q) -> np.ndarray:
        """The whole snake's CM (m) of every row, (B, 2)."""
        out = np.empty((q.shape[0], 2))
        _centers(q, self.half_length, self.mass, out)
        return out

    # ------------------------------------------------------------------ step
    def step(self, q, u, torques, obs, aux, forces=None, scale=None) -> None:
        """Every row stepped dt with ``torques`` (N m, the motors' commands) held; in place (module doc)."""
        B, n = q.shape[0], q.shape[1] - 2
        params = self.params
        dt = params.dt
        if stepping.background_compile_running():  # the first step of a process whose row kernel compiles there
            self._compile_bookkeeping(q, u, obs, aux)
            stepping.await_background_compile()
        w = self._step_buffers(B, n)
        q0, qdot0, impulse0, lateral0, cm0 = w["q0"], w["qdot0"], w["impulse0"], w["lateral0"], w["cm0"]
        substeps, h, stats, slid, kinetic = w["substeps"], w["h"], w["stats"], w["slid"], w["kinetic"]
        code, refinements, residual, rows = w["code"], w["refinements"], w["residual"], w["rows"]
        # the pre-step state (the undo of a failed row), the CMs and zeroed counters, in one compiled call: a single
        # env's step spent about a third of its time in the numpy calls that did this
        _begin(q, self.qdot, self.impulse, self.lateral, q0, qdot0, impulse0, lateral0, cm0, self.half_length,
               self.mass, self.substeps, dt, substeps, h, stats, slid, kinetic, code, refinements, residual)
        commands = np.ascontiguousarray(torques, dtype=np.float64)
        for level in range(params.max_refinements + 1):
            ok = sliding_step.ADVANCE_ROWS[self.method](q, self.qdot, commands, *self.constants, h, substeps, rows,
                                                        self.impulse, stats, slid, self.lateral, kinetic)
            # rows whose fast friction solve did not settle: those again by the Delassus solve (np.count_nonzero: a
            # tenth of .all()'s and .any()'s time on the few rows of a single env's step)
            if np.count_nonzero(ok) < B:
                unsettled = rows[~ok[rows]]
                q[unsettled], self.qdot[unsettled] = q0[unsettled], qdot0[unsettled]
                self.impulse[unsettled], self.lateral[unsettled] = impulse0[unsettled], lateral0[unsettled]
                stats[unsettled], slid[unsettled] = 0.0, 0.0
                ok[unsettled] = sliding_step.ADVANCE_ROWS[2](q, self.qdot, commands, *self.constants, h, substeps,
                                                             unsettled, self.impulse, stats, slid, self.lateral,
                                                             kinetic)[unsettled]
            failed = _verdicts(q, self.qdot, rows, ok, h, stats, kinetic, code, residual, params.energy_tolerance,
                               params.energy_floor)
            if np.count_nonzero(failed) == 0:
                break
            failing = rows[failed]
            q[failing], self.qdot[failing] = q0[failing], qdot0[failing]
            self.impulse[failing], self.lateral[failing] = impulse0[failing], lateral0[failing]
            if level == params.max_refinements:  # a simulation failure: the pre-step state is kept
                break
            stats[failing], slid[failing], code[failing] = 0.0, 0.0, 0.0
            substeps[failing] *= 2
            h[failing] = dt / substeps[failing]
            refinements[failing] += 1
            rows = failing
        self.last_h[:] = h
        _finish(q, self.qdot, cm0, kinetic, stats, code, refinements, residual, dt, params.include_position,
                self.half_length, self.mass, self.lateral, sliding_step.SLIDE_SPEED, obs, u, aux, self.slip)
        if forces is not None:
            np.divide(self.impulse, self.last_h[:, None], out=forces)
            scale[:] = 1.0

    def _step_buffers(self, B: int, n: int) -> dict:
        """The step's work arrays for B rows, made once (a step of the same B reuses them)."""
        if self._buffers is None or self._buffers["rows"].shape[0] != B:
            self._buffers = {"q0": np.empty((B, n + 2)), "qdot0": np.empty((B, n + 2)), "impulse0": np.empty((B, n)),
                             "lateral0": np.empty((B, n)), "cm0": np.empty((B, 2)),
                             "substeps": np.empty(B, np.int64), "h": np.empty(B), "stats": np.empty((B, 5)),
                             "slid": np.empty((B, n)), "kinetic": np.empty((B, 2)), "code": np.empty(B),
                             "refinements": np.empty(B), "residual": np.empty(B), "rows": np.arange(B)}
        return self._buffers

    def _compile_bookkeeping(self, q, u, obs, aux) -> None:
        """Compile the step's kernels other than the row kernel (:func:`_centers`, :func:`_begin`,
        :func:`_verdicts`, :func:`_finish`) by calling them on no row, with the argument types of :meth:`step`'s
        calls."""
        none, rows = np.zeros((0, 2)), np.zeros(0, np.int64)
        cm = self.center_of_mass(q[:0])
        n = q.shape[1] - 2
        _begin(q[:0], self.qdot[:0], self.impulse[:0], self.lateral[:0], q[:0].copy(), self.qdot[:0].copy(),
               self.impulse[:0].copy(), self.lateral[:0].copy(), cm, self.half_length, self.mass, self.substeps,
               self.params.dt, rows.copy(), np.zeros(0), np.zeros((0, 5)), np.zeros((0, n)), none.copy(), np.zeros(0),
               np.zeros(0), np.zeros(0))
        _verdicts(q[:0], self.qdot[:0], rows, np.ones(0, np.bool_), np.ones(0), np.zeros((0, 5)), none, np.zeros(0),
                  np.zeros(0), self.params.energy_tolerance, self.params.energy_floor)
        _finish(q[:0], self.qdot[:0], cm, none, np.zeros((0, 5)), np.zeros(0), np.zeros(0), np.zeros(0),
                self.params.dt, self.params.include_position, self.half_length, self.mass, self.lateral[:0],
                sliding_step.SLIDE_SPEED, obs[:0], u[:0], aux[:0], self.slip[:0])

    def bind_step(self, q, u, torques, obs, aux, forces=None, scale=None):
        return functools.partial(self.step, q, u, torques, obs, aux, forces, scale)

    def held_torques(self, torques):
        """The commands (N m) held over the last substep of every row."""
        return torques

    def wheel_lateral_forces(self, q, u, torques, out, scale) -> None:
        """The wheels' friction forces (N) over the last substep of every row (no traction limit: scale 1)."""
        out[:] = self.impulse / self.last_h[:, None]
        scale[:] = 1.0


# ---------------------------------------------------------------------- compiled bookkeeping of a step
@njit(cache=True, nogil=True)
def _center(q, half_length, mass):
    """The whole snake's CM (m) of one state: CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1} (eq. 3)."""
    n = q.shape[0] - 2
    x, y = q[n], q[n + 1]
    sx, sy, total = mass[0] * x, mass[0] * y, mass[0]
    c_prev, s_prev = math.cos(q[0]), math.sin(q[0])
    for k in range(1, n):
        c, s = math.cos(q[k]), math.sin(q[k])
        x += half_length[k - 1] * c_prev + half_length[k] * c
        y += half_length[k - 1] * s_prev + half_length[k] * s
        sx += mass[k] * x
        sy += mass[k] * y
        total += mass[k]
        c_prev, s_prev = c, s
    return sx / total, sy / total


@njit(cache=True, nogil=True)
def _centers(q, half_length, mass, out):
    for b in range(q.shape[0]):
        out[b, 0], out[b, 1] = _center(q[b], half_length, mass)


@njit(cache=True, nogil=True)
def _begin(q, qdot, impulse, lateral, q0, qdot0, impulse0, lateral0, cm0, half_length, mass, n_substeps, dt,
           substeps, h, stats, slid, kinetic, code, refinements, residual):
    """The start of a step of every row: its state before (q0, qdot0, impulse0, lateral0; a failed row goes back to
    it), its CM (cm0, m), ``n_substeps`` substeps of h = dt / n_substeps (s) and the counters zeroed."""
    for b in range(q.shape[0]):
        q0[b] = q[b]
        qdot0[b] = qdot[b]
        impulse0[b] = impulse[b]
        lateral0[b] = lateral[b]
        cm0[b, 0], cm0[b, 1] = _center(q[b], half_length, mass)
        substeps[b] = n_substeps
        h[b] = dt / n_substeps
        stats[b] = 0.0
        slid[b] = 0.0
        kinetic[b] = 0.0
        code[b] = 0.0
        refinements[b] = 0.0
        residual[b] = 0.0


@njit(cache=True, nogil=True)
def _verdicts(q, qdot, rows, ok, h, stats, kinetic, code, residual, energy_tolerance, energy_floor):
    """The check of the stepped ``rows`` (module doc): each one's failure code (physics.FAIL_*, 0 for a valid
    step) and relative work-energy residual |K1 - K0 - W - W_friction| / (max(K0, K1) + floor) into ``code`` and
    ``residual``; returns whether each of ``rows`` failed."""
    n = q.shape[1] - 2
    failed = np.zeros(rows.shape[0], np.bool_)
    for i in range(rows.shape[0]):
        b = rows[i]
        finite = ok[b]
        for a in range(n + 2):
            finite = finite and math.isfinite(q[b, a]) and math.isfinite(qdot[b, a])
        if not finite:
            code[b] = FAIL_NONFINITE
            residual[b] = math.nan
            failed[i] = True
            continue
        k0, k1 = kinetic[b, 0], kinetic[b, 1]
        res = abs(k1 - k0 - stats[b, 0] - stats[b, 1]) / (max(k0, k1) + energy_floor)
        residual[b] = res
        fastest = 0.0
        folded = False
        for k in range(n):
            fastest = max(fastest, abs(qdot[b, k]))
            if k < n - 1:
                fastest = max(fastest, abs(qdot[b, k + 1] - qdot[b, k]))
                folded = folded or abs(_wrap(q[b, k + 1] - q[b, k])) >= FOLD_ANGLE
        if not res <= energy_tolerance:
            code[b] = FAIL_ENERGY
        elif fastest * h[b] > MAX_SUBSTEP_ANGLE:
            code[b] = FAIL_RUNAWAY
        elif folded:
            code[b] = FAIL_FOLD
        else:
            code[b] = 0.0
        failed[i] = code[b] != 0.0
    return failed


@njit(cache=True, nogil=True)
def _finish(q, qdot, cm0, kinetic, stats, code, refinements, residual, dt, include_position, half_length, mass,
            lateral, slide_speed, obs, u, aux, slip):
    """Every row's u, physics observation and aux row after its step (a failed row keeps its pre-step state,
    observation and u), and the wheels that slid on its last substep. The observation: the CM if included, the
    wrapped joint angles, cos and sin theta_1, V_1 = e_1 . (xdot, ydot), thetadot_1, the joint rates."""
    n = q.shape[1] - 2
    for b in range(q.shape[0]):
        cx, cy = _center(q[b], half_length, mass)
        good = code[b] == 0.0
        if good:
            c1, s1 = math.cos(q[b, 0]), math.sin(q[b, 0])
            u[b, 0] = c1 * qdot[b, n] + s1 * qdot[b, n + 1]
            u[b, 1] = qdot[b, 0]
            j = 0
            if include_position:
                obs[b, 0] = cx
                obs[b, 1] = cy
                j = 2
            for k in range(n - 1):
                obs[b, j + k] = _wrap(q[b, k + 1] - q[b, k])  # (-pi, pi], as the env's observation
            j += n - 1
            obs[b, j] = c1
            obs[b, j + 1] = s1
            obs[b, j + 2] = u[b, 0]
            obs[b, j + 3] = u[b, 1]
            j += 4
            for k in range(n - 1):
                obs[b, j + k] = qdot[b, k + 1] - qdot[b, k]
        aux[b, AUX_X] = cx
        aux[b, AUX_Y] = cy
        aux[b, AUX_VX] = (cx - cm0[b, 0]) / dt if good else 0.0
        aux[b, AUX_VY] = (cy - cm0[b, 1]) / dt if good else 0.0
        aux[b, AUX_KINETIC] = kinetic[b, 1] if good else kinetic[b, 0]
        aux[b, AUX_WORK] = stats[b, 0] + stats[b, 1] if good else 0.0
        aux[b, AUX_FAILED] = code[b]
        aux[b, AUX_REFINEMENTS] = refinements[b]
        aux[b, AUX_RESIDUAL] = residual[b]
        aux[b, AUX_MOTOR_ENERGY] = stats[b, 4] if good else 0.0
        for k in range(n):
            slip[b, k] = abs(lateral[b, k]) > slide_speed
