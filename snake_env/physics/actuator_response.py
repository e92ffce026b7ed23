"""The motor's response in time: a control latency and a first-order torque lag.

A servo does not deliver a new command at once. Between the policy's command c
(N m, the action times max_torque) and the DC motor's torque-speed envelope
(:mod:`snake_env.dynamics.motor`, which clips at every RK4 stage) sit:

- ``control_latency`` L (s): the command reaches the motor L later (bus transfer, the
  servo's own control period). L is a whole number of sim_dt substeps and at most one
  env step, so over a step the motor sees the previous command for L / sim_dt substeps
  and the new one after.
- ``torque_lag`` T (s): the current loop's first-order time constant. The torque
  follows the command that reached the motor as dtau/dt = (c - tau) / T, that is
  tau(t) = c + (tau_0 - c) exp(-t / T) under a held c (MuJoCo's ``dyntype="filter"``).

Time discretisation. The command chain advances once per sim_dt substep j of
length h. The torque held over substep j is the lag's exact mean over it,
``c_j + (tau_{j-1} - c_j) (T / h) (1 - exp(-h / T))``, and the lag's state at its end is
``tau_j = c_j + (tau_{j-1} - c_j) exp(-h / T)``: every substep gets the exact
impulse of the continuous lag (a zero-order hold of the mean). The env step is
then ``frame_skip`` checked physics steps of one substep each
(:func:`snake_env.physics.step_inplace` with frame_skip 1, RK4 substeps and
refinement as usual, each held to energy_tolerance / frame_skip), summed into one
step's aux row: its work, the centre of mass's velocity over dt, the largest
refinement count, and the env step's own work-energy residual, checked against
energy_tolerance as the one-call step checks it. A row whose substep fails, or
whose env step misses that balance, is undone as a whole env step (the module doc of
:mod:`snake_env.physics.stepping`): its state and its lag state are those before
the step.

On wheels that slide (``wheel_model="sliding"``, :mod:`snake_env.physics.sliding_wheels`) each
sim_dt substep is one step of that physics (its own 1 ms time-stepping substeps and refinement inside),
under the held torque above; its summed work includes the friction's, and an env step undone restores
the wheels' own state (generalized velocities, impulses, slip) and the step's observation as well.

Both at 0 (the default of every preset) is the instant response of the physics
before them, bit for bit: the env then takes the one-call path and this module
is not used.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from .stepping import (AUX_FAILED, AUX_KINETIC, AUX_MOTOR_ENERGY, AUX_REFINEMENTS, AUX_RESIDUAL, AUX_VX, AUX_VY,
                       AUX_WORK, AUX_X, AUX_Y, FAIL_ENERGY, InstantPhysics, PhysicsParams, observe, step_inplace,
                       wheel_lateral_forces)

# relative slack when checking that a latency is a whole number of substeps (0.03 / 0.01 = 2.9999999999999996)
WHOLE_SUBSTEP_SLACK = 1e-9


def latency_substeps(control_latency: float, sim_dt: float, frame_skip: int) -> int:
    """The latency (s) as a whole number of sim_dt substeps, at most ``frame_skip`` (one env step);
    anything else is a one-line ValueError naming ``control_latency``."""
    ratio = control_latency / sim_dt
    whole = round(ratio)
    allowed = f"a whole number of sim_dt = {sim_dt:g} s substeps from 0 to one env step, {sim_dt * frame_skip:g} s"
    if abs(ratio - whole) > WHOLE_SUBSTEP_SLACK * max(1.0, ratio):
        raise ValueError(f"control_latency must be {allowed}, got {control_latency!r}")
    if whole > frame_skip:
        raise ValueError(f"control_latency must be {allowed} (a latency longer than a step), got {control_latency!r}")
    return int(whole)


@dataclasses.dataclass(frozen=True)
class LagCoefficients:
    """Per substep of length h under a lag of time constant T: the state's decay exp(-h/T) and the
    mean's weight on the state's distance to the command, (T / h)(1 - exp(-h/T)); both 0 for T = 0."""

    decay: float
    mean_weight: float

    @classmethod
    def of(cls, torque_lag: float, h: float) -> "LagCoefficients":
        if torque_lag == 0.0:
            return cls(0.0, 0.0)
        x = h / torque_lag
        return cls(math.exp(-x), -math.expm1(-x) / x)


class ActuatorResponse(InstantPhysics):
    """The latency and lag state of B motors' rows, and the env step that advances them with the physics
    (the interface of :class:`~snake_env.physics.stepping.InstantPhysics`).

    State per row: the command of the previous env step (N m, (B, n-1)) and the lag's torque (N m);
    both 0 at reset (a motor at rest with no command). ``held`` is the torque held over the last
    substep (the wheel forces' torques)."""

    def __init__(self, config, params: PhysicsParams, num_envs: int):
        super().__init__(config, params, num_envs)
        torque_lag, control_latency = config.torque_lag, config.control_latency
        # each substep's balance to 1/frame_skip of the tolerance, so that their sum meets the env step's
        # (checked again over the whole step below)
        self.substep_params = dataclasses.replace(params, frame_skip=1,
                                                  energy_tolerance=params.energy_tolerance / params.frame_skip)
        self.frame_skip = params.frame_skip
        self.latency = latency_substeps(control_latency, params.sim_dt, params.frame_skip)
        self.lag = LagCoefficients.of(torque_lag, params.sim_dt)
        shape = (num_envs, params.n_links - 1)
        self.previous_command = np.zeros(shape)
        self.torque = np.zeros(shape)  # the lag's state at the end of the last substep
        self.held = np.zeros(shape)
        # sliding wheels: each substep a step of their physics of sim_dt (module doc); None: the RK4 substep
        from .sliding_wheels import SlidingWheelPhysics  # here: it imports the config, which imports this module

        self.wheels = (SlidingWheelPhysics(config, self.substep_params, num_envs)
                       if config.wheel_model == "sliding" else None)
        if self.wheels is not None:
            self.reports_slip = True  # the env reads which wheels slid from ``slip`` (SlidingWheelPhysics)
            self.slip = self.wheels.slip

    def reset(self, rows, noise, rng):
        self.previous_command[rows] = 0.0
        self.torque[rows] = 0.0
        self.held[rows] = 0.0
        if self.wheels is not None:
            return self.wheels.reset(rows, noise, rng)
        return super().reset(rows, noise, rng)

    def observe(self, q, u):
        return super().observe(q, u) if self.wheels is None else self.wheels.observe(q, u)

    def set_state(self, q, u) -> None:
        """Put every row at (q, u) (sliding wheels: gripping); the lag's state is kept."""
        if self.wheels is not None:
            self.wheels.set_state(q, u)

    def wheel_lateral_forces(self, q, u, torques, out, scale) -> None:
        if self.wheels is None:
            super().wheel_lateral_forces(q, u, torques, out, scale)
        else:
            self.wheels.wheel_lateral_forces(q, u, self.held, out, scale)

    def _substep(self, q, u, held, obs, aux, forces, scale) -> None:
        if self.wheels is None:
            step_inplace(self.substep_params, q, u, held, obs, aux, forces, scale)
        else:
            self.wheels.step(q, u, held, obs, aux, forces, scale)

    def bind_step(self, q, u, command, obs, aux, forces=None, scale=None):
        return functools.partial(self.step, q, u, command, obs, aux, forces, scale)

    def held_torques(self, torques):
        return self.held

    def substep_torques(self, command: np.ndarray, j: int) -> np.ndarray:
        """The torque held over substep j of this step (advances the lag's state); see the module doc."""
        arrived = self.previous_command if j < self.latency else command
        if self.lag.decay == 0.0 and self.lag.mean_weight == 0.0:  # no lag: the command itself
            self.held[:] = arrived
            self.torque[:] = arrived
            return self.held
        gap = self.torque - arrived
        self.held[:] = arrived + gap * self.lag.mean_weight
        self.torque[:] = arrived + gap * self.lag.decay
        return self.held

    def step(self, q, u, command, obs, aux, forces=None, scale=None) -> None:
        """One env step of every row under ``command`` (B, n-1) (N m): q, u, obs, aux (and forces,
        scale) as :func:`snake_env.physics.step_inplace` fills them; the motors' energy is the sum of the
        substeps' (each from its held torque through the motor's band and the traction scale)."""
        q0, u0 = q.copy(), u.copy()
        saved = self.previous_command.copy(), self.torque.copy(), self.held.copy()
        if self.wheels is not None:
            wheels_saved = self.wheels.save_state()
            obs0, aux0 = obs.copy(), aux.copy()
        x0, y0, k0 = aux[:, AUX_X].copy(), aux[:, AUX_Y].copy(), aux[:, AUX_KINETIC].copy()
        work = np.zeros(q.shape[0])
        refinements = np.zeros(q.shape[0])
        failed = np.zeros(q.shape[0])
        energy = np.zeros(q.shape[0])
        for j in range(self.frame_skip):
            held = self.substep_torques(command, j)
            self._substep(q, u, held, obs, aux, forces, scale)
            energy += aux[:, AUX_MOTOR_ENERGY]
            work += aux[:, AUX_WORK]
            np.maximum(refinements, aux[:, AUX_REFINEMENTS], out=refinements)
            failed = np.where(failed == 0.0, aux[:, AUX_FAILED], failed)  # the first failure's reason
        # the env step's own work-energy balance, as the one-call step checks it (stepping's module doc)
        k1 = aux[:, AUX_KINETIC]
        with np.errstate(invalid="ignore"):
            residual = np.abs(k1 - k0 - work) / (np.maximum(k0, k1) + self.params.energy_floor)
            unbalanced = (failed == 0.0) & ~(residual <= self.params.energy_tolerance)
        failed = np.where(unbalanced, float(FAIL_ENERGY), failed)
        self.previous_command[:] = command
        dt = self.params.dt
        aux[:, AUX_VX] = (aux[:, AUX_X] - x0) / dt
        aux[:, AUX_VY] = (aux[:, AUX_Y] - y0) / dt
        aux[:, AUX_WORK] = work
        aux[:, AUX_MOTOR_ENERGY] = np.where(failed == 0.0, energy, 0.0)
        aux[:, AUX_RESIDUAL] = np.where(failed == 0.0, residual, 0.0)
        aux[:, AUX_REFINEMENTS] = refinements
        aux[:, AUX_FAILED] = failed
        rows = np.flatnonzero(failed)
        if rows.size:  # undone as a whole env step: the pre-step state, its observation, velocity and work 0
            q[rows], u[rows] = q0[rows], u0[rows]
            for array, before in zip((self.previous_command, self.torque, self.held), saved):
                array[rows] = before[rows]
            if self.wheels is not None:
                self._undo_sliding(rows, wheels_saved, q, u, obs, aux, obs0, aux0, failed, refinements, forces, scale)
                return
            row_obs, row_aux = observe(self.params, q[rows], u[rows])
            obs[rows] = row_obs.reshape(rows.size, -1)
            row_aux = row_aux.reshape(rows.size, -1)
            row_aux[:, AUX_FAILED] = failed[rows]
            row_aux[:, AUX_REFINEMENTS] = refinements[rows]
            aux[rows] = row_aux
            if forces is not None:
                row_forces, row_scale = forces[rows], scale[rows]
                wheel_lateral_forces(self.params, q[rows], u[rows], self.held[rows], row_forces, row_scale)
                forces[rows], scale[rows] = row_forces, row_scale

    def _undo_sliding(self, rows, wheels_saved, q, u, obs, aux, obs0, aux0, failed, refinements, forces,
                      scale) -> None:
        """Sliding wheels: the rows' wheel state, observation and aux row of before the step (a state whose
        wheels may slide has no observation from (q, u) alone), velocity and work 0, the failure's code."""
        self.wheels.restore_state(wheels_saved, rows)
        obs[rows] = obs0[rows]
        row_aux = aux0[rows]
        row_aux[:, [AUX_VX, AUX_VY, AUX_WORK, AUX_MOTOR_ENERGY, AUX_RESIDUAL]] = 0.0
        row_aux[:, AUX_FAILED] = failed[rows]
        row_aux[:, AUX_REFINEMENTS] = refinements[rows]
        aux[rows] = row_aux
        if forces is not None:  # from the restored impulses (the other rows' are the last piece's, unchanged)
            self.wheels.wheel_lateral_forces(q, u, self.held, forces, scale)
