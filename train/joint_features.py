"""Per-joint features of a snake's flat observation, for the shared per-joint policy.

A forward-task observation (:class:`snake_env.tasks.forward.ForwardTask`, blocks named by
``env.unwrapped.observation_structure``) holds two kinds of entries:

- per-joint blocks of n - 1 entries (:data:`JOINT_BLOCKS`): joint angles phi_k (rad) and joint
  rates phidot_k (rad/s);
- body-level blocks: the heading of link 1 (cos, sin theta_1), its generalized speeds
  u = (V_1 (m/s), thetadot_1 (rad/s)), the CM position (x, y, m; ignored: the forward task's
  reward does not depend on it) and any task extras appended after the physics blocks.

A *layout* describes the order of blocks independently of n: a list of ``[name, size]``
pairs whose size is the string ``"joint"`` for a per-joint block (n - 1 entries) and an
integer otherwise; e.g. the default forward observation is
``[["joint_angles", "joint"], ["heading", 2], ["generalized_speeds", 2], ["joint_rates", "joint"]]``.
The same layout reads the observation of every n, which is what lets one set of weights run
on any snake.

Padded observations (:mod:`snake_env.train.multi_n_env`) hold a layout at n_max - 1 joints,
each per-joint block zero-padded after the snake's real joints, followed by a mask block
of n_max - 1 entries (1.0 for a real joint, 0.0 for padding). :func:`joint_count` tells the
two formats apart from the observation size alone.

Features of joint k (between links k and k+1, 1-based), channels in order (:data:`CHANNELS`):
phi_k; phidot_k / rate_scale; cos, sin of theta_k and of theta_{k+1}, the absolute headings of
the two links the joint connects, theta_{k} = theta_1 + sum_{j<k} phi_j; V_1 / speed_scale and
thetadot_1 / rate_scale of link 1 (body-level, broadcast to every joint); 1.0 (the joint exists:
zero-padded neighbours beyond the head and the tail read 0 here); then the entries of every
other body-level block (task extras; broadcast). The scales are fixed constants, not running
statistics, so the features of one joint mean the same at every n and the mirror map below is
exact.

Mirror symmetry: reflecting the world about the x axis (the forward task's reward is
unchanged) maps theta_k -> -theta_k, so phi, phidot, sin theta and thetadot_1 change sign and
cos theta and V_1 do not; the torques change sign (eq. 11). :data:`PARITY` is that sign per
channel, which the policy uses to make its torques exactly odd under the mirror.
"""

from __future__ import annotations

import torch

JOINT = "joint"
JOINT_BLOCKS = ("joint_angles", "joint_rates")
REQUIRED_BLOCKS = ("joint_angles", "heading", "generalized_speeds", "joint_rates")
IGNORED_BLOCKS = ("position",)
EXTRAS = "extras"
CHANNELS = ("phi", "phidot", "cos_theta_k", "sin_theta_k", "cos_theta_k1", "sin_theta_k1", "speed", "turn_rate",
            "exists")
# sign of each channel under the mirror y -> -y (extras have no known parity)
PARITY = (-1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0)


class LayoutError(ValueError):
    """An observation that the per-joint features cannot read; the message is one line."""


def layout_from_structure(structure: dict, n_links: int, obs_size: int) -> list:
    """The n-independent layout of an env's observation.

    Args:
        structure: ``env.unwrapped.observation_structure`` (block name -> size, in order;
            ``skipped_*`` blocks are not in the vector).
        n_links: the env's number of links n.
        obs_size: the size of the env's flat observation; entries beyond the physics blocks
            become one body-level ``extras`` block.
    """
    layout, used = [], 0
    for name, size in structure.items():
        if name.startswith("skipped_") or size == 0:
            continue
        layout.append([name, JOINT if name in JOINT_BLOCKS else int(size)])
        used += int(size)
    if obs_size > used:
        layout.append([EXTRAS, int(obs_size - used)])
    check_layout(layout)
    return layout


def env_layout(env) -> list:
    """The layout of a built (possibly wrapped) env's flat observation."""
    base = env.unwrapped
    structure = getattr(base, "observation_structure", None)
    shape = getattr(env.observation_space, "shape", None)
    if structure is None or shape is None or len(shape) != 1:
        raise LayoutError(f"the per-joint policy reads a snake env's flat Box observation with an "
                          f"observation_structure, got {env.observation_space}")
    return layout_from_structure(structure, int(base.n_links), int(shape[0]))


def layout_for_id(env_id: str, env_kwargs: dict | None = None) -> list:
    """The layout of ``gym.make(env_id, **env_kwargs)``'s observation (the env is not stepped)."""
    import gymnasium as gym

    import snake_env  # noqa: F401  (registers the ids)

    env = gym.make(env_id, **dict(env_kwargs or {}))
    try:
        return env_layout(env)
    finally:
        env.close()


def check_env_layout(layout, env, env_id: str) -> None:
    """Raise LayoutError unless ``env`` lays out its observation in ``layout``'s blocks (a policy
    trained on one task reads another task's observation as garbage even where the sizes fit)."""
    have = env_layout(env)
    if have != check_layout(layout):
        raise LayoutError(f"{env_id} lays out its observation as {[name for name, _ in have]}, the policy reads "
                          f"{[name for name, _ in layout]} (another task?)")


def check_layout(layout) -> list:
    """Validate a layout (see the module doc); return it as a list of [name, size] lists."""
    if not isinstance(layout, (list, tuple)) or not all(
            isinstance(b, (list, tuple)) and len(b) == 2 and isinstance(b[0], str) for b in layout):
        raise LayoutError(f"layout must be a list of [name, size] pairs, got {layout!r}")
    layout = [[name, size] for name, size in layout]
    for name, size in layout:
        ok = size == JOINT if name in JOINT_BLOCKS else (
            isinstance(size, int) and not isinstance(size, bool) and size >= 1)
        if not ok:
            want = f"{JOINT!r}" if name in JOINT_BLOCKS else "a positive integer"
            raise LayoutError(f"layout block {name!r} must have size {want}, got {size!r}")
    names = [name for name, _ in layout]
    missing = [name for name in REQUIRED_BLOCKS if name not in names]
    if missing or len(set(names)) != len(names):
        raise LayoutError(f"layout must hold the blocks {list(REQUIRED_BLOCKS)} once each (the forward task's "
                          f"physics observation), got {names}")
    sizes = dict(layout)
    if sizes["heading"] != 2 or sizes["generalized_speeds"] != 2:
        raise LayoutError(f"layout blocks heading and generalized_speeds must have size 2, got {sizes['heading']} "
                          f"and {sizes['generalized_speeds']}")
    return layout


def base_size(layout, joints: int) -> int:
    """Observation size of the layout at ``joints`` = n - 1 joints, without a mask."""
    return sum(joints if size == JOINT else size for _, size in layout)


def joint_count(layout, obs_size: int, action_size: int) -> tuple[int, bool]:
    """(joints J, masked) of an observation of ``obs_size`` entries with ``action_size`` torques:
    ``base_size(layout, J)`` entries, or that plus a mask of J entries (a padded observation)."""
    joints = int(action_size)
    if obs_size == base_size(layout, joints):
        return joints, False
    if obs_size == base_size(layout, joints) + joints:
        return joints, True
    raise LayoutError(f"an observation of {obs_size} entries with {joints} torques does not fit the layout "
                      f"{[name for name, _ in layout]}: it needs {base_size(layout, joints)} entries (or "
                      f"{base_size(layout, joints) + joints} with a padding mask)")


class JointFeatures(torch.nn.Module):
    """Flat observation (batch, obs) -> per-joint features (batch, J, C) and mask (batch, J).

    Args:
        layout: the observation layout (module doc).
        joints: J = n - 1 of the observations this module reads (n_max - 1 when padded).
        masked: whether a padding mask of J entries ends the observation.
        rate_scale: rad/s that count as one unit of a rate feature (phidot_k, thetadot_1).
        speed_scale: m/s that count as one unit of V_1.

    Features of padded joints are zero (so a convolution over them sees what it sees beyond
    the tail of an unpadded snake).
    """

    def __init__(self, layout, joints: int, masked: bool, rate_scale: float, speed_scale: float):
        super().__init__()
        self.layout = check_layout(layout)
        self.joints = int(joints)
        self.masked = bool(masked)
        self.rate_scale = float(rate_scale)
        self.speed_scale = float(speed_scale)
        self.slices = {}
        start = 0
        for name, size in self.layout:
            width = self.joints if size == JOINT else size
            self.slices[name] = (start, start + width)
            start += width
        self.mask_slice = (start, start + self.joints) if self.masked else None
        # every body-level block the features do not name (task extras, blocks of a newer physics)
        self.extra_blocks = [name for name, size in self.layout
                             if size != JOINT and name not in REQUIRED_BLOCKS + IGNORED_BLOCKS]
        self.n_extras = sum(dict(self.layout)[name] for name in self.extra_blocks)
        self.channels = len(CHANNELS) + self.n_extras
        self.register_buffer("parity", torch.tensor(PARITY + (0.0,) * self.n_extras).view(1, 1, -1),
                             persistent=False)

    def _block(self, obs, name):
        lo, hi = self.slices[name]
        return obs[:, lo:hi]

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        obs = obs.float()
        batch = obs.shape[0]
        if self.masked:
            mask = obs[:, self.mask_slice[0]:self.mask_slice[1]]
        else:
            mask = torch.ones(batch, self.joints, dtype=obs.dtype, device=obs.device)
        phi = self._block(obs, "joint_angles") * mask
        phidot = self._block(obs, "joint_rates") * mask
        heading = self._block(obs, "heading")
        cos1, sin1 = heading[:, 0:1], heading[:, 1:2]
        speeds = self._block(obs, "generalized_speeds")
        # theta_{k} - theta_1 = sum_{j<k} phi_j (link before joint k), and + phi_k (the link after)
        after = torch.cumsum(phi, dim=1)
        before = after - phi
        rel = torch.stack([before, after], dim=1)  # (B, 2, J)
        cos_rel, sin_rel = torch.cos(rel), torch.sin(rel)
        cos_abs = cos1[:, :, None] * cos_rel - sin1[:, :, None] * sin_rel
        sin_abs = sin1[:, :, None] * cos_rel + cos1[:, :, None] * sin_rel
        ones = torch.ones_like(phi)
        body = [speeds[:, 0:1] / self.speed_scale * ones, speeds[:, 1:2] / self.rate_scale * ones]
        channels = [phi, phidot / self.rate_scale, cos_abs[:, 0], sin_abs[:, 0], cos_abs[:, 1], sin_abs[:, 1],
                    *body, ones]
        for name in self.extra_blocks:
            extras = self._block(obs, name)
            channels += [extras[:, i:i + 1] * ones for i in range(extras.shape[1])]
        features = torch.stack(channels, dim=2) * mask[:, :, None]
        return features, mask

    def mirror(self, features: torch.Tensor) -> torch.Tensor:
        """The features of the snake reflected about the x axis (see the module doc)."""
        return features * self.parity
