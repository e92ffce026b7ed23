"""The controllers the core needs: the task baselines that ``snake-eval --baseline`` runs
and the residual wrappers correct.

- :mod:`.serpenoid`: the serpenoid gait (Hirose), as a PD-tracked curve or an open-loop
  torque wave, batched over a leading axis;
- :mod:`.gaits`: the searched gaits of ``serpenoid.yaml``, keyed by env id;
- :mod:`.steering`: Liljebäck's cascade (2011): the serpenoid as inner loop, steered by
  line-of-sight path following, a velocity command or goal seeking.

They read observations as plain arrays in the envs' documented layout and import
neither Gymnasium nor the tasks: a task names its baseline controller class
(:meth:`snake_env.tasks.Task.make_baseline`).
"""

from .gaits import gait_for_links, load_gaits, load_params
from .serpenoid import FAMILIES, SerpenoidController, SerpenoidParams, joint_slices, reference
from .steering import (GoalSeekingController, LineOfSightController, SteeredSerpenoid, SteeringController,
                       StraightGait, make_baseline)

__all__ = ["FAMILIES", "SerpenoidParams", "SerpenoidController", "joint_slices", "reference", "load_gaits",
           "load_params", "gait_for_links", "SteeredSerpenoid", "StraightGait", "LineOfSightController",
           "SteeringController", "GoalSeekingController", "make_baseline"]
