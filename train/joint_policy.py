"""A morphology-agnostic actor-critic for SB3 PPO and SAC: one small network shared by every joint.

Select it in a config with ``policy: JointPolicy`` and its options in ``policy_kwargs``, e.g.
``"dict(hidden=64, layers=3, kernel_size=3)"``; ``snake-train`` fills in the observation layout of
the env (:mod:`snake_env.train.joint_features`). On a shipped MLP entry::

    snake-train --algo ppo --env snake_env/Snake5-v2 --set policy=JointPolicy \
        --set "policy_kwargs=dict(log_std_init=0.0)" --set normalize.norm_obs=false

Options (``policy_kwargs``): ``hidden`` (64, channels per joint), ``layers`` (2), ``kernel_size``
(3, odd), ``activation_fn`` (nn.Tanh for PPO, nn.ReLU for SAC), ``mirror`` (true), ``rate_scale``
(10 rad/s), ``speed_scale`` (1 m/s); PPO ``log_std_init`` (0.0), SAC ``n_critics`` (2). Add
``n_links_set: [5, 8, 12]`` to train on several sizes at once (:mod:`snake_env.train.multi_n_env`);
``snake-eval RUN --env ID`` and ``snake-export RUN --env ID`` run a saved policy on any n.

Architecture (every weight is independent of n, so one set of weights runs on any snake):

- :class:`~snake_env.train.joint_features.JointFeatures` turns the flat observation into a
  (batch, J, channels) tensor, J = n - 1 joints, plus a mask (1 real joint, 0 padding).
- :class:`JointTrunk`: ``layers`` times h <- act(conv1d(h) + W mean_J(h)) * mask, a 1-D
  convolution along the body (kernel ``kernel_size``: each layer reaches kernel_size // 2 joints
  towards the head and the tail) plus a body-wide context (the mean over the real joints), the
  padding zeroed after every layer.
- Actor: a linear map of each joint's last features gives it its own torque mean (PPO: a Gaussian
  with one learned log-std shared by all joints; SAC: a per-joint mean and log-std, squashed by tanh).
- Critic: a separate trunk, mean-pooled over the real joints, with 1/J beside it, into an MLP:
  PPO's state value; SAC's ``n_critics`` Q-values, each from a trunk that also reads the joint's
  own action as a channel.

Promises (tested in tests/train/test_joint_policy.py):

- Padding: a snake of J joints padded to J_max > J gets exactly the actions, log-probabilities and
  values it gets unpadded (up to float rounding); padded joints get action 0 and add nothing to
  log-probabilities or entropies. The convolution sees zeros beyond the tail either way.
- Mirror (``mirror=True``, the default): reflecting the snake about the x axis (phi -> -phi,
  phidot -> -phidot, theta_1 -> -theta_1, thetadot_1 -> -thetadot_1; V_1 unchanged) gives every
  joint the opposite torque (mean, and samples of the opposite noise), the same value and the same
  Q of the mirrored action. Built exactly by symmetrization: mean(x) = (g(x) - g(Mx)) / 2,
  V(x) = (v(x) + v(Mx)) / 2. The forward task's reward is mirror-symmetric, so the optimal policy is
  too. Head-tail reversal is not promised: link 1's heading and speed are observed, link n's not.
- SAC's log-probability is the sum over real joints times J / J_real, so SB3's target entropy
  -J (``ent_coef: auto``) is -1 per real joint at every n in a padded batch; unpadded it is the
  usual sum.

The observation must be raw (``normalize: {norm_obs: false, ...}``): VecNormalize's per-entry
statistics differ per joint slot and n, and their means break the mirror; the features are
scaled by the fixed ``rate_scale`` and ``speed_scale`` instead. Reward normalization is fine.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import torch
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy, BaseModel, BasePolicy
from stable_baselines3.sac.policies import SACPolicy
from torch import nn
from torch.distributions import Normal

from snake_env.train.joint_features import JointFeatures, LayoutError, check_layout, joint_count

POLICY_NAME = "JointPolicy"
# option -> (default, description of allowed values)
COMMON_OPTIONS = {
    "layout": (None, "an observation layout (filled in by snake-train)"),
    "hidden": (64, "a positive integer (channels per joint)"),
    "layers": (2, "a positive integer (convolution layers)"),
    "kernel_size": (3, "an odd positive integer (joints per convolution window)"),
    "activation_fn": (None, "an activation (nn.Tanh, nn.ReLU, ...)"),
    "mirror": (True, "true or false"),
    "rate_scale": (10.0, "a positive number (rad/s per feature unit)"),
    "speed_scale": (1.0, "a positive number (m/s per feature unit)"),
}
ALGO_OPTIONS = {
    "ppo": {"log_std_init": (0.0, "a number (initial log-std of every joint's torque)")},
    "sac": {"n_critics": (2, "a positive integer (Q networks)")},
}
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # SAC's clamp, as SB3's Actor


def option_names(algo: str) -> list[str]:
    return sorted({*COMMON_OPTIONS, *ALGO_OPTIONS[algo]})


def check_options(algo: str, options: dict) -> dict:
    """Validate JointPolicy ``policy_kwargs`` for ``algo``; return them with defaults filled in.

    Raises:
        ValueError: one line naming the bad option and its allowed values.
    """
    allowed = {**COMMON_OPTIONS, **ALGO_OPTIONS[algo]}
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ValueError(f"unknown {POLICY_NAME} policy_kwargs key(s) {unknown} for {algo}; "
                         f"valid: {option_names(algo)}")
    out = {key: options.get(key, default) for key, (default, _) in allowed.items()}

    def bad(key):
        return ValueError(f"{POLICY_NAME} policy_kwargs.{key} must be {allowed[key][1]}, got {options[key]!r}")

    for key in ("hidden", "layers", "kernel_size", "n_critics"):
        if key in out:
            value = out[key]
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1 \
                    or (key == "kernel_size" and value % 2 == 0):
                raise bad(key)
            out[key] = int(value)
    for key in ("rate_scale", "speed_scale", "log_std_init"):
        if key in out:
            value = out[key]
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) \
                    or (key != "log_std_init" and value <= 0):
                raise bad(key)
            out[key] = float(value)
    if not isinstance(out["mirror"], bool):
        raise bad("mirror")
    act = out["activation_fn"]
    if act is not None and not (isinstance(act, type) and issubclass(act, nn.Module)):
        raise bad("activation_fn")
    if out["activation_fn"] is None:
        out["activation_fn"] = nn.Tanh if algo == "ppo" else nn.ReLU
    if out["layout"] is not None:
        try:
            out["layout"] = check_layout(out["layout"])
        except LayoutError as exc:
            raise ValueError(f"{POLICY_NAME} policy_kwargs.layout: {exc}") from None
    return out


# --------------------------------------------------------------------------- shared modules
def masked_mean(h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of (B, J, C) over the real joints of mask (B, J): (B, C)."""
    count = mask.sum(-1, keepdim=True).clamp(min=1.0)
    return (h * mask[:, :, None]).sum(1) / count


class JointTrunk(nn.Module):
    """``layers`` shared per-joint layers: h <- act(conv1d(h) + W mean_J(h)) * mask (module doc).

    The convolution along the body is written as one linear map of each joint's window of
    ``kernel_size`` joints (zeros beyond the head and the tail): on the CPU, for the few joints
    of a snake, that is several times faster than ``nn.Conv1d``. Tensors are (batch, J, channels).
    """

    def __init__(self, in_channels: int, hidden: int, layers: int, kernel_size: int, activation_fn):
        super().__init__()
        sizes = [in_channels] + [hidden] * layers
        self.radius = kernel_size // 2
        self.convs = nn.ModuleList(nn.Linear(kernel_size * a, b) for a, b in zip(sizes, sizes[1:]))
        self.context = nn.ModuleList(nn.Linear(a, b, bias=False) for a, b in zip(sizes, sizes[1:]))
        self.act = activation_fn()
        for layer in (*self.convs, *self.context):
            nn.init.orthogonal_(layer.weight, gain=math.sqrt(2))
        for conv in self.convs:
            nn.init.zeros_(conv.bias)

    def window(self, h: torch.Tensor) -> torch.Tensor:
        """(B, J, C) -> (B, J, kernel_size * C): each joint's neighbours, head side first."""
        if not self.radius:
            return h
        joints = h.shape[1]
        padded = nn.functional.pad(h, (0, 0, self.radius, self.radius))
        return torch.cat([padded[:, i:i + joints] for i in range(2 * self.radius + 1)], dim=-1)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        m = mask[:, :, None]
        h = x * m
        for conv, context in zip(self.convs, self.context):
            h = self.act(conv(self.window(h)) + context(masked_mean(h, mask))[:, None, :]) * m
        return h


class PooledHead(nn.Module):
    """Body-level scalar from per-joint features: mean over real joints, 1/J beside it, an MLP."""

    def __init__(self, hidden: int, activation_fn, gain: float = 1.0):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(hidden + 1, hidden), activation_fn(), nn.Linear(hidden, 1))
        nn.init.orthogonal_(self.net[0].weight, gain=math.sqrt(2))
        nn.init.orthogonal_(self.net[2].weight, gain=gain)
        nn.init.zeros_(self.net[0].bias)
        nn.init.zeros_(self.net[2].bias)

    def forward(self, h: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        inv_count = 1.0 / mask.sum(-1, keepdim=True).clamp(min=1.0)
        return self.net(torch.cat([masked_mean(h, mask), inv_count], dim=1))


def _features_module(observation_space, action_space, options) -> JointFeatures:
    if not isinstance(observation_space, spaces.Box) or len(observation_space.shape) != 1 \
            or not isinstance(action_space, spaces.Box) or len(action_space.shape) != 1:
        raise ValueError(f"{POLICY_NAME} needs a flat Box observation and Box action, got {observation_space} and "
                         f"{action_space}")
    if options["layout"] is None:
        raise ValueError(f"{POLICY_NAME} needs policy_kwargs.layout (snake-train fills it in from the env)")
    try:
        joints, masked = joint_count(options["layout"], observation_space.shape[0], action_space.shape[0])
    except LayoutError as exc:
        raise ValueError(f"{POLICY_NAME}: {exc}") from None
    features = JointFeatures(options["layout"], joints, masked, options["rate_scale"], options["speed_scale"])
    if options["mirror"] and features.n_extras:
        raise ValueError(f"{POLICY_NAME} mirror=True needs the forward task's observation; this one has "
                         f"{features.n_extras} extra entries of unknown mirror parity (set mirror=False)")
    return features


class _JointMixin:
    """Shared by the PPO and SAC policies: options, symmetrization and rebuilding for other spaces."""

    _joint: dict

    def _both(self, features: torch.Tensor, mask: torch.Tensor):
        """(features, mask) of the snake and, with mirror, of its mirror image stacked after it."""
        if not self._joint["mirror"]:
            return features, mask
        return torch.cat([features, self.joint_features.mirror(features)]), torch.cat([mask, mask])

    def _odd(self, out: torch.Tensor) -> torch.Tensor:
        if not self._joint["mirror"]:
            return out
        a, b = out.chunk(2)
        return 0.5 * (a - b)

    def _even(self, out: torch.Tensor) -> torch.Tensor:
        if not self._joint["mirror"]:
            return out
        a, b = out.chunk(2)
        return 0.5 * (a + b)

    @property
    def layout(self) -> list:
        """The observation layout the policy reads (:mod:`snake_env.train.joint_features`)."""
        return self._joint["layout"]

    def for_spaces(self, observation_space, action_space):
        """This policy, with the same weights, for an env of another n (or padded/unpadded).

        Raises:
            ValueError: the observation does not fit the policy's layout.
        """
        other = type(self)(observation_space, action_space, self._dummy_schedule, **self._joint)
        other.load_state_dict(self.state_dict())
        other.set_training_mode(False)
        return other


# --------------------------------------------------------------------------- PPO
class MaskedNormal:
    """Diagonal Gaussian over real joints: padded joints sample 0 and add nothing to sums."""

    def __init__(self, mean: torch.Tensor, log_std: torch.Tensor, mask: torch.Tensor):
        self.mean = mean
        self.mask = mask
        self.distribution = Normal(mean, torch.ones_like(mean) * log_std.exp(), validate_args=False)

    def log_prob(self, actions: torch.Tensor) -> torch.Tensor:
        return (self.distribution.log_prob(actions) * self.mask).sum(-1)

    def entropy(self) -> torch.Tensor:
        return (self.distribution.entropy() * self.mask).sum(-1)

    def sample(self) -> torch.Tensor:
        return self.distribution.rsample() * self.mask

    def mode(self) -> torch.Tensor:
        return self.mean * self.mask

    def get_actions(self, deterministic: bool = False) -> torch.Tensor:
        return self.mode() if deterministic else self.sample()


class JointActorCriticPolicy(_JointMixin, ActorCriticPolicy):
    """PPO's actor-critic with the shared per-joint network (module doc).

    Args:
        observation_space, action_space, lr_schedule: as SB3 passes them.
        layout, hidden, layers, kernel_size, activation_fn, mirror, rate_scale, speed_scale,
        log_std_init: see :data:`COMMON_OPTIONS` and :data:`ALGO_OPTIONS`.
        use_sde: must be False (no gSDE for this policy).
        optimizer_class, optimizer_kwargs: as for SB3's ActorCriticPolicy.
    """

    def __init__(self, observation_space, action_space, lr_schedule, use_sde: bool = False,
                 optimizer_class=torch.optim.Adam, optimizer_kwargs: dict | None = None, **options: Any):
        if use_sde:
            raise ValueError(f"{POLICY_NAME} has no gSDE; set use_sde: false")
        options = check_options("ppo", options)
        super().__init__(observation_space, action_space, lr_schedule, net_arch=[],
                         activation_fn=options["activation_fn"], ortho_init=False,
                         log_std_init=options["log_std_init"], optimizer_class=optimizer_class,
                         optimizer_kwargs=optimizer_kwargs)
        self._joint = options
        self._build_joint(lr_schedule)

    def _build(self, lr_schedule) -> None:
        """SB3's builder, called from ActorCriticPolicy.__init__: nothing (see _build_joint)."""

    def _build_joint(self, lr_schedule) -> None:
        o = self._joint
        self.joint_features = _features_module(self.observation_space, self.action_space, o)
        channels = self.joint_features.channels
        self.actor_trunk = JointTrunk(channels, o["hidden"], o["layers"], o["kernel_size"], o["activation_fn"])
        self.actor_head = nn.Linear(o["hidden"], 1)
        nn.init.orthogonal_(self.actor_head.weight, gain=0.01)
        nn.init.zeros_(self.actor_head.bias)
        self.critic_trunk = JointTrunk(channels, o["hidden"], o["layers"], o["kernel_size"], o["activation_fn"])
        self.value_head = PooledHead(o["hidden"], o["activation_fn"])
        self.log_std = nn.Parameter(torch.full((1,), o["log_std_init"]))
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        for key in ("net_arch", "activation_fn", "log_std_init", "squash_output", "full_std", "use_expln",
                    "ortho_init", "features_extractor_class", "features_extractor_kwargs", "normalize_images"):
            data.pop(key, None)
        return {**data, **self._joint}

    # ---------------------------------------------------------------- pieces
    def _mean(self, features, mask) -> torch.Tensor:
        x, m = self._both(features, mask)
        return self._odd(self.actor_head(self.actor_trunk(x, m))[..., 0]) * mask

    def _value(self, features, mask) -> torch.Tensor:
        x, m = self._both(features, mask)
        return self._even(self.value_head(self.critic_trunk(x, m), m))

    def _distribution(self, features, mask) -> MaskedNormal:
        return MaskedNormal(self._mean(features, mask), self.log_std, mask)

    # ---------------------------------------------------------------- SB3 API
    def forward(self, obs: torch.Tensor, deterministic: bool = False):
        features, mask = self.joint_features(obs)
        distribution = self._distribution(features, mask)
        actions = distribution.get_actions(deterministic=deterministic)
        return actions, self._value(features, mask), distribution.log_prob(actions)

    def evaluate_actions(self, obs: torch.Tensor, actions: torch.Tensor):
        features, mask = self.joint_features(obs)
        distribution = self._distribution(features, mask)
        return self._value(features, mask), distribution.log_prob(actions), distribution.entropy()

    def get_distribution(self, obs: torch.Tensor) -> MaskedNormal:
        return self._distribution(*self.joint_features(obs))

    def predict_values(self, obs: torch.Tensor) -> torch.Tensor:
        return self._value(*self.joint_features(obs))

    def _predict(self, observation: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        return self.get_distribution(observation).get_actions(deterministic=deterministic)

    def action_mean(self, obs: torch.Tensor) -> torch.Tensor:
        """The deterministic action (batch, J) before clipping; padded joints 0 (ONNX export)."""
        return self._mean(*self.joint_features(obs))


# --------------------------------------------------------------------------- SAC
class JointActor(_JointMixin, BasePolicy):
    """SAC's actor: per-joint tanh-squashed Gaussian (mean and log-std per joint)."""

    def __init__(self, observation_space, action_space, options: dict):
        super().__init__(observation_space, action_space, squash_output=True)
        self._joint = options
        o = options
        self.joint_features = _features_module(observation_space, action_space, o)
        self.trunk = JointTrunk(self.joint_features.channels, o["hidden"], o["layers"], o["kernel_size"],
                                o["activation_fn"])
        self.mean_head = nn.Linear(o["hidden"], 1)
        self.log_std_head = nn.Linear(o["hidden"], 1)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "options": self._joint}

    def get_action_dist_params(self, obs: torch.Tensor):
        """(mean, log_std, {}) of the pre-tanh Gaussian, each (batch, J); padded joints mean 0."""
        mean, log_std, _ = self._params(obs)
        return mean, log_std, {}

    def _params(self, obs):
        features, mask = self.joint_features(obs)
        x, m = self._both(features, mask)
        h = self.trunk(x, m)
        mean = self._odd(self.mean_head(h)[..., 0]) * mask
        log_std = torch.clamp(self._even(self.log_std_head(h)[..., 0]), LOG_STD_MIN, LOG_STD_MAX)
        return mean, log_std, mask

    def forward(self, obs: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        mean, log_std, mask = self._params(obs)
        if deterministic:
            return torch.tanh(mean)
        return torch.tanh(mean + log_std.exp() * torch.randn_like(mean)) * mask

    def action_log_prob(self, obs: torch.Tensor):
        """(actions, log-probabilities): the sum over real joints times J / J_real (module doc)."""
        mean, log_std, mask = self._params(obs)
        gaussian = Normal(mean, log_std.exp(), validate_args=False)
        pre = gaussian.rsample()
        actions = torch.tanh(pre)
        per_joint = gaussian.log_prob(pre) - torch.log(1.0 - actions.pow(2) + 1e-6)
        count = mask.sum(-1).clamp(min=1.0)
        log_prob = (per_joint * mask).sum(-1) * (mask.shape[1] / count)
        return actions * mask, log_prob

    def _predict(self, observation: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        return self(observation, deterministic)


class JointCritic(_JointMixin, BaseModel):
    """SAC's critics: ``n_critics`` Q(s, a), each a per-joint trunk over (features, a_k), pooled."""

    def __init__(self, observation_space, action_space, options: dict):
        super().__init__(observation_space, action_space)
        self._joint = options
        o = options
        self.joint_features = _features_module(observation_space, action_space, o)
        channels = self.joint_features.channels + 1
        self.share_features_extractor = False
        self.trunks = nn.ModuleList(JointTrunk(channels, o["hidden"], o["layers"], o["kernel_size"], o["activation_fn"])
                                    for _ in range(o["n_critics"]))
        self.heads = nn.ModuleList(PooledHead(o["hidden"], o["activation_fn"]) for _ in range(o["n_critics"]))

    def forward(self, obs: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, ...]:
        features, mask = self.joint_features(obs)
        x = torch.cat([features, (actions.float() * mask)[:, :, None]], dim=2)
        if self._joint["mirror"]:
            parity = torch.cat([self.joint_features.parity, -torch.ones_like(self.joint_features.parity[..., :1])], 2)
            x, m = torch.cat([x, x * parity]), torch.cat([mask, mask])
        else:
            m = mask
        return tuple(self._even(head(trunk(x, m), m)) for trunk, head in zip(self.trunks, self.heads))


class JointSACPolicy(_JointMixin, SACPolicy):
    """SAC's policy with :class:`JointActor` and :class:`JointCritic` (module doc).

    Args: as :class:`JointActorCriticPolicy`, with ``n_critics`` instead of ``log_std_init``.
    """

    def __init__(self, observation_space, action_space, lr_schedule, use_sde: bool = False,
                 optimizer_class=torch.optim.Adam, optimizer_kwargs: dict | None = None, **options: Any):
        if use_sde:
            raise ValueError(f"{POLICY_NAME} has no gSDE; set use_sde: false")
        options = check_options("sac", options)
        _features_module(observation_space, action_space, options)  # one-line errors before SB3 builds
        self._pending = options
        super().__init__(observation_space, action_space, lr_schedule, activation_fn=options["activation_fn"],
                         optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs,
                         n_critics=options["n_critics"])
        self._joint = options
        del self._pending

    def make_actor(self, features_extractor=None) -> JointActor:
        return JointActor(self.observation_space, self.action_space, self._pending).to(self.device)

    def make_critic(self, features_extractor=None) -> JointCritic:
        return JointCritic(self.observation_space, self.action_space, self._pending).to(self.device)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        for key in ("net_arch", "activation_fn", "log_std_init", "use_expln", "clip_mean", "n_critics",
                    "features_extractor_class", "features_extractor_kwargs", "normalize_images"):
            data.pop(key, None)
        return {**data, **self._joint}


POLICIES = {"ppo": JointActorCriticPolicy, "sac": JointSACPolicy}


def policy_class(algo: str):
    """The JointPolicy class of ``algo`` ("ppo" or "sac")."""
    if algo not in POLICIES:
        raise ValueError(f"{POLICY_NAME} supports algo {sorted(POLICIES)}, got {algo!r}")
    return POLICIES[algo]
