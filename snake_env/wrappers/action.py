"""Action modes: target joint angles (``joint_target``) and the parameters of a serpenoid CPG
(``cpg``), both tracked by the joint PD of :mod:`snake_env.controllers.joint_pd`; each a batched
mode and its single and vector wrappers (:mod:`.base`)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from snake_env.controllers.cpg import CPG_PARAMETERS, SerpenoidCPG
from snake_env.controllers.joint_pd import TargetAnglePD, check_reference_rate

from .base import (BatchedMode, SingleEnvWrapper, VectorEnvWrapper, controller_kwargs, env_geometry, number, selected,
                   with_phase)


def _gains(name: str, kp, kd) -> tuple[float, float]:
    """Validated PD gains kp (N m/rad) and kd (N m s/rad) of the ``name`` wrapper."""
    kp = number("kp", kp, "N m/rad")
    kd = number("kd", kd, "N m s/rad")
    if kp == 0 and kd == 0:
        raise ValueError(f"{name} needs kp > 0 or kd > 0 (N m/rad, N m s/rad)")
    return kp, kd


class _JointTargets(BatchedMode):
    """One :class:`~snake_env.controllers.joint_pd.TargetAnglePD` reference per row; a row's
    reference rate is 0 on its episode's first step."""

    attributes = ("pd",)
    acts = True

    def __init__(self, env, num_envs: int, kp, kd, target_range, reference_rate):
        g = env_geometry(env)
        check_reference_rate(reference_rate)
        kp, kd = _gains("joint_target", kp, kd)
        if target_range is None:
            target_range = g["joint_limit"] if g["joint_limit"] else math.pi / 2
        limit = number("target_range", target_range, "rad", strict=True)
        if limit > math.pi:
            raise ValueError(f"target_range must be in (0, pi] rad, got {target_range!r}")
        self.pd = TargetAnglePD(kp=kp, kd=kd, target_range=limit, reference_rate=reference_rate,
                                **controller_kwargs(g))
        self.previous = None  # the last step's targets (B, n-1) (rad)
        self.first = np.ones(num_envs, bool)  # rows on an episode's first step: reference rate 0

    def restart(self, mask=None) -> None:
        self.first[selected(mask)] = True

    def act(self, obs, action):
        target = self.pd.target(action)
        previous = target if self.previous is None else np.where(self.first[:, None], target, self.previous)
        torque = self.pd.torque_action(action, obs, previous)
        self.previous = target
        self.first[:] = False
        return torque


class JointTargetAction(SingleEnvWrapper):
    """Action = target joint angles (fraction of ``target_range``, in [-1, 1]),
    tracked by a joint PD within the torque limit.

    The target is ``phi_ref = action * target_range`` (rad) per joint, tracked by
    ``T = kp (phi_ref - phi) + kd (phidot_ref - phidot)`` saturated at the env's ``max_torque``,
    with the reference rate ``phidot_ref`` the target's change over the last env step divided by
    dt (0 on an episode's first step; ``reference_rate="zero"`` drops it), as the serpenoid PD
    uses the curve's rate (:class:`snake_env.controllers.joint_pd.TargetAnglePD`). The PD runs at
    the env-step rate (one torque per 0.04 s env step, held over its RK4 sub-steps: the env's own
    action contract), so a very stiff PD overshoots.

    Args:
        kp: PD stiffness (N m/rad), default 1.0.
        kd: PD damping (N m s/rad), default 0.05.
        target_range: rad of target per unit action (default: the env's joint
            limit, pi/2 if it has none).
        reference_rate: "difference" (target change / dt, default) or "zero".
    """

    def __init__(self, env: gym.Env, kp: float = 1.0, kd: float = 0.05, target_range: float | None = None,
                 reference_rate: str = "difference"):
        super().__init__(env, _JointTargets(env, 1, kp, kd, target_range, reference_rate),
                         kp=kp, kd=kd, target_range=target_range, reference_rate=reference_rate)

    @property
    def _previous(self):
        """The last step's target (rad), None on an episode's first step (reference rate 0)."""
        return None if self.batched.first[0] else self.batched.previous[0]


class JointTargetActionVector(VectorEnvWrapper):
    """:class:`JointTargetAction` for a batched vector env (one PD per sub-env row)."""

    def __init__(self, env, kp: float = 1.0, kd: float = 0.05, target_range: float | None = None,
                 reference_rate: str = "difference"):
        super().__init__(env, _JointTargets(env, env.num_envs, kp, kd, target_range, reference_rate))


class _CPG(BatchedMode):
    """One :class:`~snake_env.controllers.cpg.SerpenoidCPG` phase psi (rad) per row, restarted at 0
    with the row's episode; appends sin psi, cos psi."""

    attributes = ("cpg",)
    acts = True
    extra = 2

    def __init__(self, env, num_envs: int, max_amplitude, max_frequency, max_offset, kp, kd):
        g = env_geometry(env)
        max_amplitude = number("max_amplitude", max_amplitude, "rad", strict=True)
        max_frequency = number("max_frequency", max_frequency, "rad/s", strict=True)
        max_offset = number("max_offset", max_offset, "rad")
        kp, kd = _gains("cpg", kp, kd)
        self.cpg = SerpenoidCPG(max_amplitude=max_amplitude, max_frequency=max_frequency, max_offset=max_offset,
                                kp=kp, kd=kd, **controller_kwargs(g))
        self.action_space = spaces.Box(-1.0, 1.0, (len(CPG_PARAMETERS),), np.float32)
        self.phase = np.zeros(num_envs)

    def restart(self, mask=None) -> None:
        self.phase[selected(mask)] = 0.0

    def act(self, obs, action):
        torque, self.phase = self.cpg.torque_action(action, obs, self.phase)
        return torque

    def observe(self, obs, rows=slice(None)):
        return with_phase(obs, self.phase[rows])


class CPGAction(SingleEnvWrapper):
    """Action = parameters of a serpenoid CPG (:class:`snake_env.controllers.cpg.SerpenoidCPG`), tracked
    by a joint PD within the torque limit; observation + (sin psi, cos psi) of the oscillator.

    As in CPG-RL (Bellegarda and Ijspeert, 2022), the action (4,) in [-1, 1] sets the amplitude
    alpha (rad), frequency omega (rad/s), phase lag beta (rad) and offset gamma (rad) of one
    serpenoid wave (in the order of ``CPG_PARAMETERS``); the wrapper integrates the oscillator's
    phase psi += omega dt and tracks ``phi_i^ref = alpha sin(psi + (i-1) beta) + gamma`` with
    ``phidot_i^ref = alpha omega cos(psi + (i-1) beta)`` by the saturated PD. A constant action is
    exactly the searched ``pd`` serpenoid of :mod:`snake_env.controllers.serpenoid` with those gains,
    and the policy modulates it from state feedback.

    Args (ranges: the serpenoid search's ``pd`` box, ``BOXES`` of ``python -m snake_env.agents.search``,
    so the policy and the baseline choose from the same gaits):
        max_amplitude: rad, default 1.5.
        max_frequency: rad/s, default 40 (>= 4 env steps per gait period).
        max_offset: rad, default 0.5 (turning).
        kp: PD stiffness (N m/rad), default 1.0.
        kd: PD damping (N m s/rad), default 0.05.
    """

    def __init__(self, env: gym.Env, max_amplitude: float = 1.5, max_frequency: float = 40.0,
                 max_offset: float = 0.5, kp: float = 1.0, kd: float = 0.05):
        super().__init__(env, _CPG(env, 1, max_amplitude, max_frequency, max_offset, kp, kd),
                         max_amplitude=max_amplitude, max_frequency=max_frequency, max_offset=max_offset, kp=kp,
                         kd=kd)

    @property
    def _phase(self):
        """The oscillator's phase psi (rad)."""
        return self.batched.phase[0]


class CPGActionVector(VectorEnvWrapper):
    """:class:`CPGAction` for a batched vector env: one oscillator per sub-env, its phase
    restarted at 0 with the sub-env's (auto)reset."""

    def __init__(self, env, max_amplitude: float = 1.5, max_frequency: float = 40.0, max_offset: float = 0.5,
                 kp: float = 1.0, kd: float = 0.05):
        super().__init__(env, _CPG(env, env.num_envs, max_amplitude, max_frequency, max_offset, kp, kd))
