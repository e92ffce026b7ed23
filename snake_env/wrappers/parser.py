"""The ``env_wrapper`` config key: the names of the opt-in modes (:data:`WRAPPERS`), its parser and
the functions that apply it to a single env and to a batched vector env (docs/wrappers.md)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import gymnasium as gym

from .action import CPGAction, CPGActionVector, JointTargetAction, JointTargetActionVector
from .observation import (GoalFrameObservation, GoalFrameObservationVector, PhaseObservation, PhaseObservationVector,
                          WheelGripObservation, WheelGripObservationVector)
from .residual import (SerpenoidResidualAction, SerpenoidResidualActionVector, SteeringResidualAction,
                       SteeringResidualActionVector)

# config name -> (single env wrapper, vector env wrapper), applied in the order the config gives
WRAPPERS = {
    "phase_observation": (PhaseObservation, PhaseObservationVector),
    "joint_target": (JointTargetAction, JointTargetActionVector),
    "cpg": (CPGAction, CPGActionVector),
    "serpenoid_residual": (SerpenoidResidualAction, SerpenoidResidualActionVector),
    "steering_residual": (SteeringResidualAction, SteeringResidualActionVector),
    "goal_frame": (GoalFrameObservation, GoalFrameObservationVector),
    "wheel_grip_observation": (WheelGripObservation, WheelGripObservationVector),
}


def parse_env_wrapper(spec) -> list[tuple[str, dict]]:
    """``env_wrapper`` config value -> [(name, kwargs)], in order.

    Accepts None, a name, a list of names or one-key mappings, or a mapping
    ``{name: kwargs-or-None}``; an unknown name or bad kwargs is a one-line ValueError."""
    if spec is None or spec == {} or spec == []:
        return []
    if isinstance(spec, str):
        items = [(spec, {})]
    elif isinstance(spec, Mapping):
        items = list(spec.items())
    elif isinstance(spec, Sequence):
        items = []
        for entry in spec:
            if isinstance(entry, str):
                items.append((entry, {}))
            elif isinstance(entry, Mapping) and len(entry) == 1:
                items.extend(entry.items())
            else:
                raise ValueError(f"env_wrapper entries must be names or one-key mappings, got {entry!r}")
    else:
        raise ValueError(f"env_wrapper must be a mapping {{name: kwargs}}, a name or a list, got {spec!r}")
    out = []
    for name, kwargs in items:
        if name not in WRAPPERS:
            raise ValueError(f"env_wrapper name must be one of {sorted(WRAPPERS)}, got {name!r}")
        if kwargs is None:
            kwargs = {}
        if not isinstance(kwargs, Mapping):
            raise ValueError(f"env_wrapper {name!r} kwargs must be a mapping, got {kwargs!r}")
        out.append((name, dict(kwargs)))
    return out


def _construct(cls, env, name, kwargs):
    try:
        return cls(env, **kwargs)
    except TypeError as exc:
        raise ValueError(f"env_wrapper {name!r}: {str(exc).splitlines()[0]}") from None


def wrap_env(env: gym.Env, spec) -> gym.Env:
    """Apply the ``env_wrapper`` spec to a single env."""
    for name, kwargs in parse_env_wrapper(spec):
        env = _construct(WRAPPERS[name][0], env, name, kwargs)
    return env


def wrap_vector_env(envs, spec):
    """Apply the ``env_wrapper`` spec to a batched vector env."""
    for name, kwargs in parse_env_wrapper(spec):
        envs = _construct(WRAPPERS[name][1], envs, name, kwargs)
    return envs

