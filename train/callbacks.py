"""SB3 callbacks that keep VecNormalize statistics with every saved model.

RL Zoo users lose runs because a checkpoint without its normalization
statistics cannot be evaluated faithfully; here every checkpoint, every new
best model and the final model are written together with ``vecnormalize``
statistics, each file atomically.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from snake_env.train import atomic

CHECKPOINT_RE = re.compile(r"^model_(\d+)_steps\.zip$")


def vecnormalize_of(model) -> VecNormalize | None:
    env = model.get_vec_normalize_env()
    return env if isinstance(env, VecNormalize) else None


def checkpoint_paths(directory, steps: int) -> dict[str, Path]:
    directory = Path(directory)
    return {
        "model": directory / f"model_{steps}_steps.zip",
        "vecnormalize": directory / f"vecnormalize_{steps}_steps.pkl",
    }


def save_snapshot(model, model_path, vecnormalize_path, replay_buffer_path=None) -> None:
    """Write the model, its normalization statistics and (off-policy) replay
    buffer; the statistics go first so a model file never exists without them."""
    vec_normalize = vecnormalize_of(model)
    with atomic.interrupts_deferred():  # the whole snapshot, so an interrupt never splits it
        if vec_normalize is not None:
            atomic.save_vecnormalize(vec_normalize, vecnormalize_path)
        if replay_buffer_path is not None and getattr(model, "replay_buffer", None) is not None:
            atomic.save_replay_buffer(model, replay_buffer_path)
        atomic.save_model(model, model_path)


def save_checkpoint(model, directory) -> Path:
    """Checkpoint at ``model.num_timesteps``; an off-policy model also keeps
    its (single, latest) replay buffer so ``--resume`` continues faithfully."""
    paths = checkpoint_paths(directory, model.num_timesteps)
    replay = Path(directory) / "replay_buffer.pkl" if hasattr(model, "replay_buffer") else None
    save_snapshot(model, paths["model"], paths["vecnormalize"], replay)
    return paths["model"]


def latest_checkpoint(directory) -> tuple[int, Path] | None:
    """(timesteps, path) of the newest ``model_<steps>_steps.zip``, or None."""
    directory = Path(directory)
    if not directory.is_dir():
        return None
    found = []
    for path in directory.iterdir():
        match = CHECKPOINT_RE.match(path.name)
        if match:
            found.append((int(match.group(1)), path))
    return max(found) if found else None


class CheckpointWithStats(BaseCallback):
    """Save a checkpoint (model + VecNormalize statistics) every ``save_freq``
    environment steps, counted over all envs."""

    def __init__(self, save_freq: int, directory, verbose: int = 0):
        super().__init__(verbose)
        self.save_freq = int(save_freq)
        self.directory = Path(directory)
        self._next_save = None

    def _on_training_start(self) -> None:
        self._next_save = (self.model.num_timesteps // self.save_freq + 1) * self.save_freq

    def _on_step(self) -> bool:
        if self.model.num_timesteps >= self._next_save:
            path = save_checkpoint(self.model, self.directory)
            self._next_save += self.save_freq
            if self.verbose:
                print(f"checkpoint saved: {path}")
        return True


class SaveBestWithStats(BaseCallback):
    """Used as ``EvalCallback(callback_on_new_best=...)``: writes the best
    model and its VecNormalize statistics atomically into ``directory``."""

    def __init__(self, directory, verbose: int = 0):
        super().__init__(verbose)
        self.directory = Path(directory)

    def _on_step(self) -> bool:
        save_snapshot(self.model, self.directory / "best_model.zip", self.directory / "vecnormalize.pkl")
        return True


class ResidualBurnIn(BaseCallback):
    """The start of residual policy learning (Silver et al. 2018, "Residual Policy Learning",
    sec. 4): for use with ``env_wrapper: serpenoid_residual``, whose zero action is the
    baseline gait.

    On a fresh model the policy's mean layer is set to zero, so the first policy *is* the
    baseline, and (SAC) its log standard deviation to the constant ``log_std``, a small
    exploration noise that the gait survives (docs/learning.md, note 4: per-step torque
    noise of 0.135 of the torque limit takes the Snake12 gait from 1.03 to 0.09 m/s). For the first ``burn_in_steps``
    env steps (summed over envs) the actor is frozen and only the critic learns, from
    rollouts of that gait; the actor's first update then follows a critic that has seen
    what the gait is worth, rather than a random one. Needs ``learning_starts: 0`` with
    SAC: SB3 acts uniformly at random before ``learning_starts``, which is not the gait.

    After the burn-in, two SAC options keep the actor near the baseline, where the critic
    has data. A critic fitted on the gait's rollouts is only right near the actions they
    tried (a ball of the exploration noise around the zero correction); followed outside it,
    its action gradient is the extrapolation error of offline RL. ``residual_penalty`` adds
    TD3+BC's regularizer (Fujimoto and Gu 2021, eq. 3) with the baseline as the behaviour
    policy: the actor's loss gets ``residual_penalty * mean|Q| * mean(a_det**2)``, a_det =
    tanh(mean) the deterministic correction and mean|Q| the critic's mean absolute value
    on a replay batch (refreshed every ``q_scale_every`` env steps), so the weight is free
    of the reward's scale (TD3+BC's alpha = 2.5 is a weight of 0.4). ``learn_log_std:
    false`` keeps the exploration noise at ``log_std`` for the whole run. ``actor_lr_scale``
    runs the actor's optimizer at that fraction of the learning rate (the critic and the
    entropy coefficient keep it): the two-timescale rule of actor-critic methods (Konda and
    Tsitsiklis 2000; TD3's delayed policy updates, Fujimoto et al. 2018, sec. 5.2), so the
    critic can re-fit the actions of the changed policy before the actor moves further.

    Args:
        burn_in_steps: env steps with the actor frozen, an integer >= 0.
        log_std: initial log standard deviation of SAC's Gaussian before its tanh, in
            [-10, 2] (SB3 clips SAC's log std to [-20, 2]); PPO keeps its ``log_std_init``.
        residual_penalty: SAC only: weight of the penalty on the correction, >= 0 (0: none).
        learn_log_std: SAC only: whether the log std learns after the burn-in.
        actor_lr_scale: SAC only: the actor's learning rate as a fraction of the
            configured one, in (0, 1].
        q_scale_every: env steps between two estimates of mean|Q|, an integer >= 1.
    """

    def __init__(self, burn_in_steps: int = 50_000, log_std: float = -3.0, residual_penalty: float = 0.0,
                 learn_log_std: bool = True, q_scale_every: int = 1000, actor_lr_scale: float = 1.0,
                 verbose: int = 0):
        super().__init__(verbose)
        if isinstance(burn_in_steps, bool) or not isinstance(burn_in_steps, int) or burn_in_steps < 0:
            raise ValueError(f"ResidualBurnIn burn_in_steps must be an integer >= 0, got {burn_in_steps!r}")
        if isinstance(log_std, bool) or not isinstance(log_std, (int, float)) or not -10.0 <= log_std <= 2.0:
            raise ValueError(f"ResidualBurnIn log_std must be a number in [-10, 2], got {log_std!r}")
        if (isinstance(residual_penalty, bool) or not isinstance(residual_penalty, (int, float))
                or not 0.0 <= residual_penalty < float("inf")):
            raise ValueError(f"ResidualBurnIn residual_penalty must be a finite number >= 0, got {residual_penalty!r}")
        if not isinstance(learn_log_std, bool):
            raise ValueError(f"ResidualBurnIn learn_log_std must be true or false, got {learn_log_std!r}")
        if isinstance(q_scale_every, bool) or not isinstance(q_scale_every, int) or q_scale_every < 1:
            raise ValueError(f"ResidualBurnIn q_scale_every must be an integer >= 1, got {q_scale_every!r}")
        if (isinstance(actor_lr_scale, bool) or not isinstance(actor_lr_scale, (int, float))
                or not 0.0 < actor_lr_scale <= 1.0):
            raise ValueError(f"ResidualBurnIn actor_lr_scale must be a number in (0, 1], got {actor_lr_scale!r}")
        self.burn_in_steps = burn_in_steps
        self.actor_lr_scale = float(actor_lr_scale)
        self.log_std = float(log_std)
        self.residual_penalty = float(residual_penalty)
        self.learn_log_std = learn_log_std
        self.q_scale_every = q_scale_every
        self.q_scale = 0.0  # mean |Q| of the last estimate; the penalty waits for the first one
        self._next_q_scale = 0
        self._hook = None
        self._lr_hooks = []
        self._training = False
        self._frozen = False

    def _actor_parts(self):
        """(mean layer, SAC log-std layer or None, parameters the actor's update changes)."""
        import torch.nn as nn

        if hasattr(self.model, "actor"):  # SAC
            actor = self.model.actor
            if not isinstance(actor.mu, nn.Linear) or not isinstance(actor.log_std, nn.Linear):
                raise ValueError("ResidualBurnIn supports SAC without gSDE (use_sde: false)")
            return actor.mu, actor.log_std, list(actor.parameters())
        policy = self.model.policy  # PPO: the policy branch, its action head and log std
        params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters(), policy.log_std]
        return policy.action_net, None, params

    def _set_frozen(self, frozen: bool) -> None:
        _, log_std, params = self._actor_parts()
        for param in params:
            param.requires_grad_(not frozen)
        if log_std is not None and not self.learn_log_std and self._training:
            log_std.requires_grad_(False)  # while training; _on_training_end releases it
        self._frozen = frozen

    def _penalize(self, module, inputs, mean):
        """Forward hook on SAC's mean layer: when the actor's loss is differentiated, add the
        gradient of residual_penalty * q_scale * mean(tanh(mean)**2) (batch and action axes)."""
        coef = self.residual_penalty * self.q_scale
        if coef > 0.0 and mean.requires_grad:
            squashed = mean.detach().tanh()
            extra = 2.0 * coef * squashed * (1.0 - squashed**2) / squashed.numel()
            mean.register_hook(lambda grad: grad + extra)

    def _scale_actor_lr(self, optimizer, args, kwargs) -> None:
        """Step pre-hook: SB3 sets every optimizer's rate from the schedule before each
        train() call; the actor steps at actor_lr_scale of it (restored after the step)."""
        for group in optimizer.param_groups:
            group["lr"] *= self.actor_lr_scale

    def _restore_actor_lr(self, optimizer, args, kwargs) -> None:
        for group in optimizer.param_groups:
            group["lr"] /= self.actor_lr_scale

    def _estimate_q_scale(self) -> None:
        """mean |Q1(s, a_det(s))| over a replay batch (TD3+BC's normalizer)."""
        import torch

        buffer = self.model.replay_buffer
        if buffer.size() == 0:
            return
        data = buffer.sample(self.model.batch_size, env=self.model.get_vec_normalize_env())
        with torch.no_grad():
            actions = self.model.actor(data.observations, deterministic=True)
            q_value = self.model.critic.q1_forward(data.observations, actions)
        self.q_scale = float(q_value.abs().mean())
        self.logger.record("train/residual_q_scale", self.q_scale)

    def _on_training_start(self) -> None:
        import torch

        # snake-train's config check says this first; RL Zoo builds the callback without it
        if getattr(self.model, "learning_starts", 0) > self.model.num_timesteps:
            raise ValueError("ResidualBurnIn needs learning_starts: 0 (SB3 acts at random before learning_starts)")
        mean, log_std, _ = self._actor_parts()
        if log_std is None and (self.residual_penalty > 0.0 or not self.learn_log_std or self.actor_lr_scale != 1.0):
            raise ValueError("ResidualBurnIn residual_penalty, learn_log_std and actor_lr_scale are SAC options "
                             "(PPO has no critic of actions)")
        if self.residual_penalty > 0.0:
            self._hook = mean.register_forward_hook(self._penalize)
        if self.actor_lr_scale != 1.0:
            optimizer = self.model.actor.optimizer
            self._lr_hooks = [optimizer.register_step_pre_hook(self._scale_actor_lr),
                              optimizer.register_step_post_hook(self._restore_actor_lr)]
        self._training = True
        if self.model.num_timesteps == 0:
            with torch.no_grad():
                mean.weight.zero_()
                mean.bias.zero_()
                if log_std is not None:
                    log_std.weight.zero_()
                    log_std.bias.fill_(self.log_std)
        self._set_frozen(self.model.num_timesteps < self.burn_in_steps)

    def _on_step(self) -> bool:
        if self._frozen and self.model.num_timesteps >= self.burn_in_steps:
            self._set_frozen(False)
            if self.verbose:
                print(f"ResidualBurnIn: actor unfrozen at {self.model.num_timesteps} steps")
        if self.residual_penalty > 0.0 and self.model.num_timesteps >= self._next_q_scale:
            self._estimate_q_scale()
            self._next_q_scale = self.model.num_timesteps + self.q_scale_every
        return True

    def _on_training_end(self) -> None:
        if self._hook is not None:
            self._hook.remove()
            self._hook = None
        for handle in self._lr_hooks:
            handle.remove()
        self._lr_hooks = []
        self._training = False
        self._set_frozen(False)  # a saved or resumed model trains as usual


class CriticWarmUp(BaseCallback):
    """Fine-tuning's start (``snake-train --init-from``): for the first ``steps`` env steps (summed over
    envs) only the value function learns, on rollouts of the loaded policy; then the actor is released.

    A critic loaded from a run on other sizes (or with fresh reward statistics) misjudges the new
    task's returns, and PPO's first updates follow its advantages; with the actor held, the critic
    first learns what the loaded gait is worth (docs/results.md, "One policy for every length", for
    the runs with and without it). The same idea as ResidualBurnIn's burn-in, for a policy that is
    already a gait. The value path is every policy parameter whose name holds
    "value" or "critic" (SB3's MlpPolicy: ``mlp_extractor.value_net``, ``value_net``; JointPolicy:
    ``critic_trunk``, ``value_head``); every other one is frozen.

    Args:
        steps: env steps with the actor frozen, an integer >= 0.
    """

    def __init__(self, steps: int = 65_536, verbose: int = 0):
        super().__init__(verbose)
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
            raise ValueError(f"CriticWarmUp steps must be an integer >= 0, got {steps!r}")
        self.steps = steps
        self._frozen = False

    def actor_parameters(self):
        policy = self.model.policy
        if hasattr(self.model, "actor"):
            raise ValueError("CriticWarmUp is for PPO (SAC's critic learns from a replay buffer: use learning_starts)")
        return [param for name, param in policy.named_parameters() if "value" not in name and "critic" not in name]

    def _set_frozen(self, frozen: bool) -> None:
        for param in self.actor_parameters():
            param.requires_grad_(not frozen)
        self._frozen = frozen

    def _on_training_start(self) -> None:
        self._set_frozen(self.model.num_timesteps < self.steps)

    def _on_step(self) -> bool:
        if self._frozen and self.model.num_timesteps >= self.steps:
            self._set_frozen(False)
            if self.verbose:
                print(f"CriticWarmUp: actor released at {self.model.num_timesteps} steps")
        return True

    def _on_training_end(self) -> None:
        self._set_frozen(False)  # a saved or resumed model trains as usual


def configured_slip_cost_weight(callback: BaseCallback) -> float:
    """The training envs' configured ``slip_cost_weight`` (one value, > 0), which a slip-cost callback needs
    (as its ``WEIGHT_ROLE``); a one-line ValueError otherwise."""
    weights = set(callback.training_env.get_attr("slip_cost_weight"))
    if len(weights) != 1 or not next(iter(weights)) > 0.0:
        raise ValueError(f"{type(callback).__name__} needs env_kwargs slip_cost_weight > 0 ({callback.WEIGHT_ROLE}), "
                         f"got {sorted(weights)}")
    return float(next(iter(weights)))


def training_progress(model) -> float:
    """``num_timesteps`` over the run's total (a resumed run included), in [0, 1]."""
    total = max(int(getattr(model, "_total_timesteps", 0)), 1)
    return min(model.num_timesteps / total, 1.0)


class SlipCostSchedule(BaseCallback):
    """A curriculum on the slip cost (``env_kwargs: {slip_cost_weight: W}``, docs/env.md): the gait is
    learned first with a small cost (or none), then the cost is ramped up to the configured weight W, a
    penalty curriculum as in legged-locomotion RL (e.g. Hwangbo et al. 2019, "Learning agile and dynamic
    motor skills for legged robots", their curriculum factor on the cost terms).

    With ``p`` the training progress (``num_timesteps`` over the run's total, a resumed run included),
    the training envs' weight is ``W * (floor + (1 - floor) * clip((p - start_fraction) / (end_fraction -
    start_fraction), 0, 1))``: ``floor * W`` up to ``start_fraction``, linear to W at ``end_fraction``,
    then W. It is set on every sub-env through ``env_method("set_slip_cost_weight", ...)`` at the start
    and after every vector step (it takes effect from the next step). The evaluation env (EvalCallback's,
    which picks the best model) keeps the configured W, so every evaluation and the best-model choice
    score the policy under the final cost, as ``snake-eval`` and the shipped env do; at the end of
    training the training envs are set back to W too.

    Args:
        start_fraction: progress at which the ramp starts, in [0, 1).
        end_fraction: progress at which the weight reaches W, in (start_fraction, 1].
        floor: the weight before the ramp as a fraction of W, in [0, 1] (0: no cost before it).
    """

    WEIGHT_ROLE = "the weight it ramps to"  # what the configured slip_cost_weight is to it

    def __init__(self, start_fraction: float = 0.4, end_fraction: float = 1.0, floor: float = 0.0,
                 verbose: int = 0):
        super().__init__(verbose)
        for name, value in (("start_fraction", start_fraction), ("end_fraction", end_fraction), ("floor", floor)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value <= 1.0:
                raise ValueError(f"SlipCostSchedule {name} must be a number in [0, 1], got {value!r}")
        if not start_fraction < end_fraction:
            raise ValueError(f"SlipCostSchedule start_fraction must be below end_fraction ({end_fraction!r}), "
                             f"got {start_fraction!r}")
        self.start_fraction = float(start_fraction)
        self.end_fraction = float(end_fraction)
        self.floor = float(floor)
        self.final_weight = None  # W, read from the training env at the start
        self.weight = None  # the weight the training envs have now

    def weight_at(self, progress: float) -> float:
        """The scheduled weight (per m g of excess) at training progress ``progress`` in [0, 1]."""
        ramp = (progress - self.start_fraction) / (self.end_fraction - self.start_fraction)
        return self.final_weight * (self.floor + (1.0 - self.floor) * min(max(ramp, 0.0), 1.0))

    def _set(self, weight: float) -> None:
        if weight != self.weight:
            self.training_env.env_method("set_slip_cost_weight", weight)
            self.weight = weight
        self.logger.record("train/slip_cost_weight", weight)

    def _on_training_start(self) -> None:
        self.final_weight = configured_slip_cost_weight(self)
        self.weight = self.final_weight
        self._on_step()

    def _on_step(self) -> bool:
        self._set(self.weight_at(training_progress(self.model)))
        return True

    def _on_training_end(self) -> None:
        self._set(self.final_weight)  # the configured weight, as the evaluation and the shipped env have it


class SlipCostLagrangian(BaseCallback):
    """A constraint on sliding instead of a fixed price: the training envs' slip-cost weight is a Lagrange
    multiplier that grows while the policy's wheels slide on more than ``target_share`` of wheel-steps and
    shrinks (to 0 at least) while they slide on fewer, the dual ascent of constrained RL (PPO-Lagrangian,
    Ray et al. 2019, "Benchmarking Safe Exploration in Deep RL"; the proportional term is the PI form of
    Stooke et al. 2020, "Responsive Safety in RL by PID Lagrangian Methods").

    The measured share is ``info["wheel_slip"]`` (the wheels that slide, on the sliding wheels; outside the
    friction cone, on the no-slip ones) over every wheel and step of the last rollout (PPO) or of the last
    ``update_every`` steps (SAC: every env step counts once). After each, with e = share - target_share,
    ``multiplier = clip(multiplier + gain * e, 0, max_weight)`` and the training envs' weight is
    ``clip(multiplier + proportional * e, 0, max_weight)``; the cost it prices is the env's slip cost
    (``slip_cost_weight`` per m g of lateral force beyond ``slip_margin`` of the grip, docs/env.md), which
    rises before a wheel slides. The multiplier is an attribute of the model (``slip_cost_multiplier``), so
    it is saved with every checkpoint and a resumed run goes on from it. The evaluation env keeps the
    configured ``slip_cost_weight``: it scores the best-model choice at that fixed price.

    Random torques slide a snake's wheels too (about 23 % of wheel-steps on Snake5-v4 at the entries' initial
    action noise): a constraint from the first step prices moving at all before a gait exists, and the
    policy learns to stand still. So the multiplier stays at ``initial_weight`` until ``start_fraction`` of the
    run (training progress, as :class:`SlipCostSchedule`) and until the policy moves: the first update at
    which the measured period's mean forward speed (``info["x_velocity"]``, m/s) is at least ``start_speed``.
    The dual steps start there and go on whatever the speed does later. (A seed that had no gait at
    ``start_fraction`` learned to stand still under the constraint and never left: Snake5-v4 seed 4 at
    0.02x the serpenoid, where seeds 0-3 moved at about 1.3 m/s by then; docs/env.md, "A gate on speed".)

    Args:
        target_share: the share of wheel-steps allowed to slide, in [0, 1).
        start_fraction: training progress at which the dual steps start, in [0, 1).
        start_speed: the mean forward speed (m/s) the policy's rollouts must reach before the dual steps
            start (>= 0; 0: at ``start_fraction`` whatever the speed).
        gain: multiplier change per unit of share above the target, per update (> 0).
        proportional: the weight's extra per unit of share above the target (>= 0).
        initial_weight: the multiplier at the start of a new run (>= 0).
        max_weight: the upper bound of the multiplier and the weight (> 0).
        update_every: env steps between updates for off-policy algorithms (PPO updates after each rollout).
    """

    WEIGHT_ROLE = "the evaluation's weight"

    def __init__(self, target_share: float = 0.03, start_fraction: float = 0.3, gain: float = 1.0,
                 proportional: float = 0.0, start_speed: float = 0.0,
                 initial_weight: float = 0.0, max_weight: float = 20.0, update_every: int = 8192,
                 verbose: int = 0):
        super().__init__(verbose)
        checks = (("target_share", target_share, lambda v: 0.0 <= v < 1.0, "a number in [0, 1)"),
                  ("start_fraction", start_fraction, lambda v: 0.0 <= v < 1.0, "a number in [0, 1)"),
                  ("gain", gain, lambda v: v > 0.0, "a number > 0"),
                  ("proportional", proportional, lambda v: v >= 0.0, "a number >= 0"),
                  ("start_speed", start_speed, lambda v: v >= 0.0, "a number >= 0"),
                  ("initial_weight", initial_weight, lambda v: v >= 0.0, "a number >= 0"),
                  ("max_weight", max_weight, lambda v: v > 0.0, "a number > 0"))
        for name, value, ok, allowed in checks:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not ok(value):
                raise ValueError(f"SlipCostLagrangian {name} must be {allowed}, got {value!r}")
        if isinstance(update_every, bool) or not isinstance(update_every, int) or update_every < 1:
            raise ValueError(f"SlipCostLagrangian update_every must be an integer >= 1, got {update_every!r}")
        if initial_weight > max_weight:
            raise ValueError(f"SlipCostLagrangian initial_weight must be <= max_weight ({max_weight!r}), "
                             f"got {initial_weight!r}")
        self.target_share = float(target_share)
        self.start_fraction = float(start_fraction)
        self.gain = float(gain)
        self.proportional = float(proportional)
        self.start_speed = float(start_speed)
        self.initial_weight = float(initial_weight)
        self.max_weight = float(max_weight)
        self.update_every = update_every
        self.configured_weight = None  # the env's slip_cost_weight: the evaluation's, restored at the end
        self.on_policy = True
        self.multiplier = None
        self.weight = None
        self._slid = 0  # sliding wheel-steps since the last update
        self._wheel_steps = 0
        self._speed_sum = 0.0  # sum of info["x_velocity"] over env-steps since the last update
        self._env_steps = 0
        self.started = False  # the dual steps have started (saved with the model, as the multiplier)
        self._steps = 0  # vector steps since the last update (off-policy)

    def update(self, share: float) -> float:
        """One dual step on the measured sliding share; returns the training envs' new weight."""
        error = share - self.target_share
        self.multiplier = min(max(self.multiplier + self.gain * error, 0.0), self.max_weight)
        return min(max(self.multiplier + self.proportional * error, 0.0), self.max_weight)

    def _set(self, weight: float) -> None:
        self.training_env.env_method("set_slip_cost_weight", weight)
        self.weight = weight

    def _on_training_start(self) -> None:
        self.configured_weight = configured_slip_cost_weight(self)
        self.on_policy = isinstance(self.model, OnPolicyAlgorithm)
        # a resumed run's multiplier came back with the model (an attribute SB3 saves)
        self.multiplier = float(getattr(self.model, "slip_cost_multiplier", self.initial_weight))
        self.started = bool(getattr(self.model, "slip_cost_started", False))
        self._set(self.multiplier)
        self._reset_counts()

    def _reset_counts(self) -> None:
        self._slid = self._wheel_steps = self._steps = self._env_steps = 0
        self._speed_sum = 0.0

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            slip = info.get("wheel_slip")
            if slip is None:
                raise ValueError("SlipCostLagrangian needs info['wheel_slip'] (an env with wheel_friction)")
            self._slid += int(np.count_nonzero(slip))
            self._wheel_steps += len(slip)
            if self.start_speed > 0.0 and not self.started:
                self._speed_sum += float(info["x_velocity"])
                self._env_steps += 1
        self._steps += 1
        if not self.on_policy and self._steps * self.training_env.num_envs >= self.update_every:
            self._update()
        return True

    def _on_rollout_end(self) -> None:
        if self.on_policy:
            self._update()

    def _update(self) -> None:
        if not self._wheel_steps:
            return
        share = self._slid / self._wheel_steps
        if not self.started and training_progress(self.model) >= self.start_fraction:
            self.started = self.start_speed == 0.0 or self._speed_sum / self._env_steps >= self.start_speed
        if self.started:
            self._set(self.update(share))
        self.model.slip_cost_multiplier = self.multiplier
        self.model.slip_cost_started = self.started
        self.logger.record("train/slip_share", share)
        self.logger.record("train/slip_cost_multiplier", self.multiplier)
        self.logger.record("train/slip_cost_weight", self.weight)
        if self._env_steps:
            self.logger.record("train/forward_speed", self._speed_sum / self._env_steps)
        self._reset_counts()

    def _on_training_end(self) -> None:
        self._set(self.configured_weight)  # as the evaluation and the shipped env have it
