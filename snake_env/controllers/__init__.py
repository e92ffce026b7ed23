"""The controllers the core needs: the task baselines that ``snake-eval --baseline`` runs
and the residual wrappers correct, and the inner loops of the joint-target and CPG wrappers.

- :mod:`.serpenoid`: the serpenoid gait (Hirose), as a PD-tracked curve or an open-loop
  torque wave, batched over a leading axis;
- :mod:`.gaits`: the searched gaits of ``serpenoid.yaml``, keyed by env id;
- :mod:`.steering`: Liljebäck's cascade (2011): the serpenoid as inner loop, steered by
  line-of-sight path following, a velocity command or goal seeking;
- :mod:`.joint_pd`: the saturated joint PD that tracks joint-angle references (target angles);
- :mod:`.cpg`: a serpenoid central pattern generator whose parameters are an action (CPG-RL).

They read observations as plain arrays in the envs' documented layout and import
neither Gymnasium nor the tasks: a task names its baseline controller class
(:meth:`snake_env.tasks.Task.make_baseline`).
"""

from .cpg import CPG_PARAMETERS, SerpenoidCPG
from .gaits import gait_for_links, load_gaits, load_params
from .joint_pd import REFERENCE_RATES, JointPD, TargetAnglePD
from .serpenoid import FAMILIES, SerpenoidController, SerpenoidParams, joint_slices, reference
from .steering import (GoalSeekingController, LineOfSightController, SteeredSerpenoid, SteeringController,
                       StraightGait, make_baseline)

__all__ = ["FAMILIES", "SerpenoidParams", "SerpenoidController", "joint_slices", "reference", "load_gaits",
           "load_params", "gait_for_links", "SteeredSerpenoid", "StraightGait", "LineOfSightController",
           "SteeringController", "GoalSeekingController", "make_baseline", "REFERENCE_RATES", "JointPD",
           "TargetAnglePD", "CPG_PARAMETERS", "SerpenoidCPG"]
