"""Follow a path: a line, a circle or a sine (``snake_env/SnakePath{n}-v3``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from snake_env.controllers import LineOfSightController
from snake_env.physics.settings import setting
from snake_env.physics import AUX_VX, AUX_VY

from .base import DEFAULT_CTRL_COST_WEIGHT, StepContext, Task, box_with_extras, mean_heading, squared_norm

PATH_TYPES = ("line", "circle", "sine")
_NEWTON_STEPS = 4  # projection onto the sine: Newton steps from the previous foot point


@dataclass(frozen=True)
class PathTask(Task):
    r"""Follow a planar path with the snake's centre of mass: a straight line, a circle or a sine.

    ## Description
    The snake of `snake_env/Snake{n}-v3` (same physics, actions, start state;
    CM at the origin, heading near +x) follows a path given in its start
    frame, shifted sideways by a cross-track offset d = +-`initial_offset`
    (sign drawn at reset) so that the snake starts off the path:
    - "line": y = d, travelled along +x;
    - "circle": radius `radius`, centre (0, d + radius), travelled
      counter-clockwise from (0, d) (heading +x there);
    - "sine": y = d + `amplitude` sin(2 pi x / `wavelength`), along +x.
    The cross-track error e (m) is the signed distance from the whole CM
    to its closest path point, positive to the left of the direction of
    travel; the path speed is the CM's velocity along the path's tangent
    at that point (m/s).
    The heading is the mean link angle theta_bar (Liljebäck et al. 2011).

    ## Action Space
    As `snake_env/Snake{n}-v3`: `Box(-1, 1, (n_links - 1,), float32)`, joint torques in units of `max_torque`.

    ## Observation Space
    `Box(-inf, inf, (2 n + 6,), float64)`: the physics observation of
    `Snake{n}-v3` (2 n + 2 entries), then:

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 2n+2 | e, cross-track error | m |
    | 2n+3 | cos(psi - theta_bar), path tangent psi relative to the heading | - |
    | 2n+4 | sin(psi - theta_bar) | - |
    | 2n+5 | curvature of the path at the closest point (left turn > 0) | 1/m |

    ## Rewards
    reward = `progress_weight` * v_t - `cross_track_weight` * |e| - `ctrl_cost_weight` * ||a||^2,
    v_t = v . t the CM velocity over the step (m/s) along the unit tangent t of
    the path at the closest point after the step. On a line v_t is the
    along-track speed ds/dt; off a curved path it is bounded by the snake's
    speed, where ds/dt = v_t / (1 - curvature e) grows without bound towards
    a circle's centre. `info`: `reward_progress`, `reward_cross_track`,
    `reward_ctrl`, `cross_track_error` (e, m), `path_speed` (v_t, m/s).

    ## Starting State
    As `Snake{n}-v3`; the offset sign is drawn from the env's generator.

    ## Episode End
    - Termination: when |e| > `max_cross_track_error` (m).
    - Truncation: after 1000 steps (40 s), or on a simulator failure.

    ## Arguments
    The physical arguments of `Snake{n}-v3`, `reset_noise_scale`, the costs (`energy_cost_weight`,
    `slip_cost_weight`, `slip_margin`, `action_rate_cost_weight`), and:

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `path_type` | "line" | "line", "circle" or "sine" |
    | `initial_offset` | 0.5 | start cross-track offset magnitude (m) |
    | `radius` | 1.5 | circle radius (m) |
    | `amplitude`, `wavelength` | 0.5, 8.0 | sine shape (m) |
    | `progress_weight` | 1.0 | per m/s of along-track speed |
    | `cross_track_weight` | 1.0 | per m of abs(e) |
    | `max_cross_track_error` | 2.0 | termination distance (m) |
    | `ctrl_cost_weight` | 1e-4 | weight of ||a||^2 |

    ## Version History
    * v4: wheels that slide and back-EMF braking, as the forward task's v4
      (docs/envs/forward.md): each wheel grips within mu m_k g and slides under
      Coulomb friction beyond it (`wheel_model="sliding"`) instead of the no-slip
      wheels under the traction limit, and a joint back-driven past 2 omega_0 is
      braked by its motor's back-EMF beyond the current limit
      (`back_emf_braking=True`). `snake_env/SnakePath{n}-v3` is still
      registered with `wheel_model="no_slip", back_emf_braking=False`, its physics
      bit for bit, and v2 with `actuator="ideal", wheel_friction=None`. The
      baseline steers the newest serpenoid of that n, searched on these wheels.
    * v3: a robot a lab could build: the joints are servo motors (`actuator="servo"`:
      1 N m stall torque, 3.14 rad/s no-load speed) and the wheels grip up to
      mu m_k g (`wheel_friction=0.8`, rubber on concrete) under the traction
      limit, instead of ideal torque sources and wheels that grip at any force
      (docs/env.md). `snake_env/SnakePath{n}-v2` is still registered with
      `actuator="ideal", wheel_friction=None`, its physics bit for bit.
      `info` gains `wheel_lateral_force`, `wheel_slip` and `traction_scale`. Corrected
      3 Dec 2026 without a new version (observations, rewards and terminations
      unchanged): `wheel_slip` no longer flags a wheel the traction limit holds at
      its grip, which rounding put up to 4.4e-16 of the grip above it. Corrected
      4 Dec 2026 as the forward task's v3 (docs/envs/forward.md): `actuator_power`
      is the power the motors deliver, no longer the commanded torques times the
      joint rotation; only a reward with `energy_cost_weight` > 0 changes with it.
    * v2: a step that meets every accuracy check but ends folded (|phi_k| reaches
      FOLD_ANGLE) fails at once instead of being refined up to `max_refinements`
      times (the finer substeps folded too). Only settings that can fold differ
      (`paper_model=True`, `joint_limit=None`); with the default joint limit
      no step folded in the fuzz (docs/reliability.md), so those runs equal v1.
    * v1: the progress term is the CM velocity along the path tangent (was the
      rate of the closest point's arc length, ds/dt: near a circle's centre
      the closest point swings round the circle for small motions, and a PPO
      policy learned to circle there for 10 m/s of "progress" 1.2 m off the path).
    * v0: initial version.
    """

    path_type: str = setting("line", "-", "choice", maximum=PATH_TYPES, doc="line, circle or sine")
    initial_offset: float = setting(0.5, "m", minimum=0.0, strict=False, doc="start cross-track offset")
    radius: float = setting(1.5, "m", minimum=0.0, doc="circle radius")
    amplitude: float = setting(0.5, "m", minimum=0.0, strict=False, doc="sine amplitude")
    wavelength: float = setting(8.0, "m", minimum=0.0, doc="sine wavelength")
    progress_weight: float = setting(1.0, "per m/s", doc="weight of the along-track speed")
    cross_track_weight: float = setting(1.0, "per m", minimum=0.0, strict=False, doc="weight of abs(e)")
    max_cross_track_error: float = setting(2.0, "m", minimum=0.0, doc="termination distance")
    ctrl_cost_weight: float = setting(DEFAULT_CTRL_COST_WEIGHT, "per unit action^2", minimum=0.0, strict=False,
                                      doc="weight of ||a||^2")

    name = "path"
    id_prefix, version = "SnakePath", 4
    episode_metrics = {"mean_cross_track_error": ("cross_track_error", "mean_abs"),
                       "mean_path_speed": ("path_speed", "mean")}
    baseline_name, baseline_controller = "los", LineOfSightController
    step_info_keys = ("reward_progress", "reward_cross_track", "reward_ctrl", "cross_track_error", "path_speed")

    def observation_space(self, config, base):
        return box_with_extras(base, np.array([-np.inf, -1.0, -1.0, -np.inf]), np.array([np.inf, 1.0, 1.0, np.inf]))

    def init_state(self, num_envs):
        # offset d (m); foot: the closest point's parameter (x for line/sine, polar angle for the circle)
        return {"offset": np.zeros(num_envs), "foot": np.zeros(num_envs), "error": np.zeros(num_envs),
                "tangent": np.zeros(num_envs), "curvature": np.zeros(num_envs)}

    # ------------------------------------------------------------------ geometry
    def project(self, p: np.ndarray, offset: np.ndarray, foot_guess: np.ndarray):
        """Closest path points of CMs p (B, 2): (foot parameter, signed cross-track error e (m),
        tangent angle psi (rad), curvature (1/m))."""
        x, y = p[:, 0], p[:, 1]
        if self.path_type == "line":
            return x.copy(), y - offset, np.zeros_like(x), np.zeros_like(x)
        if self.path_type == "circle":
            cy = offset + self.radius
            angle = np.arctan2(y - cy, x)
            # left of a counter-clockwise circle is inside it
            error = self.radius - np.hypot(x, y - cy)
            return angle, error, angle + 0.5 * np.pi, np.full_like(x, 1.0 / self.radius)
        k = 2.0 * np.pi / self.wavelength
        a = self.amplitude
        xf = foot_guess.copy()
        for _ in range(_NEWTON_STEPS):
            # minimize (xf - x)^2 + (f(xf) - y)^2, f = d + a sin(k xf)
            f = offset + a * np.sin(k * xf)
            f1 = a * k * np.cos(k * xf)
            f2 = -a * k * k * np.sin(k * xf)
            grad = (xf - x) + (f - y) * f1
            hess = 1.0 + f1 * f1 + (f - y) * f2
            xf = xf - grad / np.where(hess > 0.1, hess, 1.0 + f1 * f1)
        f = offset + a * np.sin(k * xf)
        f1 = a * k * np.cos(k * xf)
        f2 = -a * k * k * np.sin(k * xf)
        tangent = np.arctan(f1)
        error = (y - f) * np.cos(tangent) - (x - xf) * np.sin(tangent)
        curvature = f2 / (1.0 + f1 * f1) ** 1.5
        return xf, error, tangent, curvature

    # ------------------------------------------------------------------ task hooks
    def reset(self, config, state, rows, rng, q, aux):
        from snake_env.physics import AUX_X, AUX_Y

        sign = np.where(rng.uniform(size=rows.size) < 0.5, -1.0, 1.0)
        state["offset"][rows] = sign * self.initial_offset
        start = aux[:, [AUX_X, AUX_Y]]
        guess = start[:, 0] if self.path_type == "sine" else np.zeros(rows.size)
        foot, error, tangent, curvature = self.project(start, state["offset"][rows], guess)
        state["foot"][rows], state["error"][rows] = foot, error
        state["tangent"][rows], state["curvature"][rows] = tangent, curvature

    def observe(self, config, obs, q, aux, state):
        relative = state["tangent"] - mean_heading(q, config.n_links)
        extras = np.stack([state["error"], np.cos(relative), np.sin(relative), state["curvature"]], axis=-1)
        return np.concatenate([obs, extras], axis=1)

    def evaluate(self, config, ctx: StepContext, state):
        foot, error, tangent, curvature = self.project(ctx.cm, state["offset"], state["foot"])
        path_speed = ctx.aux[:, AUX_VX] * np.cos(tangent) + ctx.aux[:, AUX_VY] * np.sin(tangent)
        state["foot"][:], state["error"][:], state["tangent"][:], state["curvature"][:] = (
            foot, error, tangent, curvature)
        reward_progress = self.progress_weight * path_speed
        reward_cross_track = -self.cross_track_weight * np.abs(error)
        ctrl_cost = self.ctrl_cost_weight * squared_norm(ctx.action)
        reward = reward_progress + reward_cross_track - ctrl_cost
        terminated = np.abs(error) > self.max_cross_track_error
        info = {"reward_progress": reward_progress, "reward_cross_track": reward_cross_track,
                "reward_ctrl": -ctrl_cost, "cross_track_error": error.copy(), "path_speed": path_speed}
        return reward, terminated, info

    def path_points(self, offset: float, around: np.ndarray, span: float = 6.0) -> np.ndarray:
        """Points (K, 2) of the path near ``around`` (m), for drawing."""
        if self.path_type == "circle":
            angles = np.linspace(0.0, 2.0 * math.pi, 121)
            return np.stack([self.radius * np.cos(angles), offset + self.radius * (1.0 + np.sin(angles))], axis=-1)
        x = np.linspace(around[0] - span, around[0] + span, 241)
        y = np.full_like(x, offset)
        if self.path_type == "sine":
            y = y + self.amplitude * np.sin(2.0 * np.pi * x / self.wavelength)
        return np.stack([x, y], axis=-1)

    def overlay(self, config, state, row, q):
        from .base import link_centers

        return [("polyline", self.path_points(float(state["offset"][row]), link_centers(config, q).mean(axis=0)))]
