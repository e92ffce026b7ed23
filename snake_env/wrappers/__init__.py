"""Opt-in observation and action modes as Gymnasium wrappers (single and vector env).

The env itself stays a joint-torque env with a clock-free observation (the default). Each mode
is a ``gymnasium.Wrapper`` for the single env and a ``gymnasium.vector.VectorWrapper`` for the
batched vector env, with the same arguments and the same per-step arithmetic, written once as a
batched mode (:mod:`.base`; the single env is a batch of one):

* ``phase_observation`` (:class:`PhaseObservation`): sin, cos of a clock per frequency;
* ``goal_frame`` (:class:`GoalFrameObservation`): the goal in the snake's heading frame;
* ``wheel_grip_observation`` (:class:`WheelGripObservation`): each wheel's lateral force over its grip;
* ``joint_target`` (:class:`JointTargetAction`): target joint angles tracked by a joint PD;
* ``cpg`` (:class:`CPGAction`): the parameters of a serpenoid CPG tracked by the joint PD;
* ``serpenoid_residual`` (:class:`SerpenoidResidualAction`): a torque correction added to the
  task's baseline controller;
* ``steering_residual`` (:class:`SteeringResidualAction`): a correction to the baseline
  cascade's steering (gait offset and frequency).

Modules: :mod:`.observation`, :mod:`.action`, :mod:`.residual` (one per family), :mod:`.parser`
(the ``env_wrapper`` config key: :data:`WRAPPERS`, :func:`parse_env_wrapper`, :func:`wrap_env`,
:func:`wrap_vector_env`) and :mod:`.base`. The PD and CPG arithmetic is in
:mod:`snake_env.controllers.joint_pd` and :mod:`snake_env.controllers.cpg`. docs/wrappers.md
describes the config key with an example per family, and what the modes measured.
"""

from snake_env.controllers.cpg import CPG_PARAMETERS
from snake_env.controllers.joint_pd import REFERENCE_RATES

from .action import CPGAction, CPGActionVector, JointTargetAction, JointTargetActionVector
from .observation import (GoalFrameObservation, GoalFrameObservationVector, PhaseObservation, PhaseObservationVector,
                          WheelGripObservation, WheelGripObservationVector)
from .parser import WRAPPERS, parse_env_wrapper, wrap_env, wrap_vector_env
from .residual import (STEERING_ACTIONS, STEERING_BASELINES, SerpenoidResidualAction, SerpenoidResidualActionVector,
                       SteeringResidualAction, SteeringResidualActionVector)

__all__ = ["PhaseObservation", "PhaseObservationVector", "GoalFrameObservation", "GoalFrameObservationVector",
           "WheelGripObservation", "WheelGripObservationVector",
           "JointTargetAction", "JointTargetActionVector", "CPGAction", "CPGActionVector", "SerpenoidResidualAction",
           "SerpenoidResidualActionVector", "SteeringResidualAction", "SteeringResidualActionVector", "WRAPPERS",
           "parse_env_wrapper", "wrap_env", "wrap_vector_env", "REFERENCE_RATES", "CPG_PARAMETERS",
           "STEERING_ACTIONS", "STEERING_BASELINES"]
