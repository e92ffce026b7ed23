"""The physics half of dm_control's Physics/Task split, free of Gymnasium.

- :mod:`.settings`: typed, self-validating dataclass fields (shared with the tasks);
- :mod:`.config`: :class:`PhysicsConfig`, every physical kwarg with its unit and bounds,
  and the refusal of settings RK4 cannot step;
- :mod:`.stepping`: the checked, batched step (Brax style: a pure function of
  state and torques, batching a leading axis) over the compiled kernels of
  :mod:`snake_env.dynamics.compiled`.
- :mod:`.actuator_response`: the motor's torque lag and control latency, stepped
  substep by substep; :mod:`.randomization`: per-episode domain randomization, a
  robot per row; :mod:`.sliding_wheels`: wheels that slide under Coulomb friction
  (``wheel_model="sliding"``); :mod:`.batch`: which of these (or one compiled call) steps a batch.

Layers read top-down: dynamics -> physics -> controllers -> tasks -> envs ->
wrappers; nothing here imports a layer above it.
"""

from .config import GRAVITY, PhysicsConfig
from .stepping import (AUX_FAILED, AUX_KINETIC, AUX_MOTOR_ENERGY, AUX_REFINEMENTS, AUX_RESIDUAL, AUX_SIZE, AUX_VX,
                       AUX_VY, AUX_WORK,
                       AUX_X, AUX_Y, FAIL_ENERGY, FAIL_ERROR, FAIL_FOLD, FAIL_NONFINITE, FAIL_RUNAWAY, FAILURE_REASONS,
                       FOLD_ANGLE, MAX_SUBSTEP_ANGLE, PhysicsParams, observation_size, observe, reset, step,
                       step_inplace, wheel_lateral_forces)

__all__ = ["GRAVITY", "PhysicsConfig", "PhysicsParams", "step", "step_inplace", "reset", "observe",
           "wheel_lateral_forces", "observation_size", "FAILURE_REASONS", "MAX_SUBSTEP_ANGLE", "FOLD_ANGLE", "FAIL_NONFINITE", "FAIL_ENERGY",
           "FAIL_RUNAWAY", "FAIL_FOLD", "FAIL_ERROR", "AUX_SIZE", "AUX_X", "AUX_Y", "AUX_VX", "AUX_VY", "AUX_KINETIC",
           "AUX_WORK", "AUX_FAILED", "AUX_REFINEMENTS", "AUX_RESIDUAL", "AUX_MOTOR_ENERGY"]
