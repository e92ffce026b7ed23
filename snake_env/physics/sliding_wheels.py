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

from snake_env.dynamics import sliding_step
from snake_env.dynamics.lagrange import consistent_qdot

from .sliding_reference import sliding_wheels
from .stepping import (AUX_FAILED, AUX_KINETIC, AUX_MOTOR_ENERGY, AUX_REFINEMENTS, AUX_RESIDUAL, AUX_VX, AUX_VY,
                       AUX_WORK, AUX_X, AUX_Y, FAIL_ENERGY, FAIL_FOLD, FAIL_NONFINITE, FAIL_RUNAWAY, FOLD_ANGLE,
                       MAX_SUBSTEP_ANGLE, observe, reset)

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
        wheels = sliding_wheels(config)
        self.model = wheels.model
        self.constants = wheels.compiled_constants()
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
        self.sliding_share = np.zeros((B, n))

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

    def observe(self, q, u):
        """(obs, aux) of states (q, u) whose wheels grip (the env's own observation of them)."""
        return observe(self.params, q, u)

    def center_of_mass(self, q) -> np.ndarray:
        """The whole snake's CM (m) of every row, (B, 2)."""
        n = q.shape[1] - 2
        e = np.stack([np.cos(q[:, :n]), np.sin(q[:, :n])], axis=-1) * self.half_length[:, None]
        offsets = np.concatenate([np.zeros_like(e[:, :1]), np.cumsum(e[:, :-1] + e[:, 1:], axis=1)], axis=1)
        return q[:, n:] + np.einsum("k,bkd->bd", self.mass, offsets) / np.sum(self.mass)

    def _observation(self, q, qdot, cm, obs) -> None:
        """The env's physics observation of sliding states into ``obs``: the CM if included, the wrapped joint
        angles, cos and sin theta_1, V_1 = e_1 . (xdot, ydot), thetadot_1, the joint rates."""
        n = q.shape[1] - 2
        j = 0
        if self.params.include_position:
            obs[:, :2] = cm
            j = 2
        obs[:, j:j + n - 1] = np.mod(np.diff(q[:, :n], axis=1) + math.pi, 2.0 * math.pi) - math.pi
        j += n - 1
        c1, s1 = np.cos(q[:, 0]), np.sin(q[:, 0])
        obs[:, j], obs[:, j + 1] = c1, s1
        obs[:, j + 2] = c1 * qdot[:, n] + s1 * qdot[:, n + 1]
        obs[:, j + 3] = qdot[:, 0]
        obs[:, j + 4:] = np.diff(qdot[:, :n], axis=1)

    # ------------------------------------------------------------------ step
    def step(self, q, u, torques, obs, aux, forces=None, scale=None) -> None:
        """Every row stepped dt with ``torques`` (N m, the motors' commands) held; in place (module doc)."""
        B, n = q.shape[0], q.shape[1] - 2
        params = self.params
        dt = params.dt
        q0, qdot0, impulse0, lateral0 = q.copy(), self.qdot.copy(), self.impulse.copy(), self.lateral.copy()
        cm0 = self.center_of_mass(q0)
        substeps = np.full(B, self.substeps, np.int64)
        stats = np.zeros((B, 5))
        slid = np.zeros((B, n))
        kinetic = np.zeros((B, 2))
        code = np.zeros(B)
        refinements = np.zeros(B)
        residual = np.zeros(B)
        rows = np.arange(B)
        max_refinements = params.max_refinements
        commands = np.ascontiguousarray(torques, dtype=np.float64)
        for level in range(max_refinements + 1):
            h = dt / substeps
            ok = sliding_step.advance_rows(q, self.qdot, commands, *self.constants, h, substeps, rows, self.impulse,
                                           stats, slid, self.lateral, kinetic)
            failing = self._verdict(q, rows, ok, h, stats, kinetic, code, residual)
            if failing.size == 0:
                break
            q[failing], self.qdot[failing] = q0[failing], qdot0[failing]
            self.impulse[failing], self.lateral[failing] = impulse0[failing], lateral0[failing]
            if level == max_refinements:  # a simulation failure: the pre-step state is kept
                break
            stats[failing], slid[failing], code[failing] = 0.0, 0.0, 0.0
            substeps[failing] *= 2
            refinements[failing] += 1
            rows = failing
        good = code == 0.0
        self.last_h = dt / substeps
        self.sliding_share = slid / substeps[:, None]  # the share of the step's substeps each wheel slid
        cm = self.center_of_mass(q)
        if np.any(good):
            g = np.flatnonzero(good)
            qg, qdg = q[g], self.qdot[g]
            u[g, 0] = np.cos(qg[:, 0]) * qdg[:, n] + np.sin(qg[:, 0]) * qdg[:, n + 1]
            u[g, 1] = qdg[:, 0]
            view = obs[g]
            self._observation(qg, qdg, cm[g], view)
            obs[g] = view
        aux[:, AUX_X] = cm[:, 0]
        aux[:, AUX_Y] = cm[:, 1]
        aux[:, AUX_VX] = np.where(good, (cm[:, 0] - cm0[:, 0]) / dt, 0.0)
        aux[:, AUX_VY] = np.where(good, (cm[:, 1] - cm0[:, 1]) / dt, 0.0)
        aux[:, AUX_KINETIC] = np.where(good, kinetic[:, 1], kinetic[:, 0])
        aux[:, AUX_WORK] = np.where(good, stats[:, 0] + stats[:, 1], 0.0)
        aux[:, AUX_FAILED] = code
        aux[:, AUX_REFINEMENTS] = refinements
        aux[:, AUX_RESIDUAL] = residual
        aux[:, AUX_MOTOR_ENERGY] = np.where(good, stats[:, 4], 0.0)
        # the wheels over the last substep (a failed row: the one before its step)
        self.slip[:] = np.abs(self.lateral) > sliding_step.SLIDE_SPEED
        if forces is not None:
            forces[:] = self.impulse / self.last_h[:, None]
            scale[:] = 1.0

    def _verdict(self, q, rows, ok, h, stats, kinetic, code, residual) -> np.ndarray:
        """Check the stepped ``rows`` (module doc); write each one's failure code and relative work-energy
        residual; return the failing rows."""
        n = q.shape[1] - 2
        params = self.params
        r = rows
        finite = ok[r] & np.all(np.isfinite(q[r]), axis=1) & np.all(np.isfinite(self.qdot[r]), axis=1)
        k0, k1 = kinetic[r, 0], kinetic[r, 1]
        res = np.abs(k1 - k0 - stats[r, 0] - stats[r, 1]) / (np.maximum(k0, k1) + params.energy_floor)
        phi = np.diff(q[r, :n], axis=1)
        wrapped = np.abs(np.mod(phi + math.pi, 2.0 * math.pi) - math.pi)
        rates = np.concatenate([np.abs(self.qdot[r, :n]), np.abs(np.diff(self.qdot[r, :n], axis=1))], axis=1)
        with np.errstate(invalid="ignore"):
            fold = np.any(wrapped >= FOLD_ANGLE, axis=1)
            runaway = np.max(rates, axis=1) * h[r] > MAX_SUBSTEP_ANGLE
            energy = ~(res <= params.energy_tolerance)
        verdict = np.where(~finite, FAIL_NONFINITE, np.where(energy, FAIL_ENERGY, np.where(
            runaway, FAIL_RUNAWAY, np.where(fold, FAIL_FOLD, 0.0))))
        code[r] = verdict
        residual[r] = np.where(finite, res, np.nan)
        return r[verdict != 0.0]

    def bind_step(self, q, u, torques, obs, aux, forces=None, scale=None):
        return functools.partial(self.step, q, u, torques, obs, aux, forces, scale)

    def held_torques(self, torques):
        """The commands (N m) held over the last substep of every row."""
        return torques

    def wheel_lateral_forces(self, q, u, torques, out, scale) -> None:
        """The wheels' friction forces (N) over the last substep of every row (no traction limit: scale 1)."""
        out[:] = self.impulse / self.last_h[:, None]
        scale[:] = 1.0
