"""The env's physics step as a pure batched function (Brax style).

``step(params, q, u, torques)`` maps a state and an action to the next state
and everything the env reports about it; it never mutates its inputs.
Batching is a leading axis: q (B, n+2), u (B, 2), torques (B, n-1) step B
snakes in one compiled call, and 1-D inputs step one snake. Both paths run
the same compiled per-snake function (:func:`_step_one`), so a batch of one
reproduces the single snake bit for bit; the single env uses the 1-D path
and the vector env the batched one.

The integrator is the compiled RK4 kernel of
:mod:`snake_env.dynamics.compiled` (the O(n) Kane sweep of eqs. 6-21 plus
damping and soft joint limits). Around it this module adds what the RL
interface needs: the mass-weighted centre of mass of the whole snake (whose
finite difference over one env step is the reward's velocity), the
observation vector, the kinetic energy (eq. 22 under the constraints) and a
non-finite guard that restores the pre-step state instead of returning NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from snake_env.dynamics import compiled

# Layout of the per-snake auxiliary output row (float64).
AUX_X, AUX_Y, AUX_VX, AUX_VY, AUX_KINETIC, AUX_WORK, AUX_FAILED = range(7)
AUX_SIZE = 7
# Batches with fewer than this many coordinates (B * (n+2)) are stepped on one thread.
PARALLEL_MIN_WORK = 512


@dataclass(frozen=True)
class PhysicsParams:
    """Constants of one env: the model's per-link arrays (float64) and the
    integration and joint-limit settings.

    Attributes:
        mass (kg), half_length (m), inertia (kg m^2): per link, shape (n,).
        joint_damping (N m s/rad): shape (n-1,); wheel_damping (N s/m): shape (n,).
        joint_limit: soft limit on |phi_k| (rad); 0 disables the limits.
        limit_stiffness (N m/rad), limit_damping (N m s/rad): the spring-damper
            acting beyond the limit.
        sim_dt: RK4 step (s); frame_skip: RK4 steps per env step.
        include_position: whether the observation starts with the CM position (x, y).
    """

    mass: np.ndarray
    half_length: np.ndarray
    inertia: np.ndarray
    joint_damping: np.ndarray
    wheel_damping: np.ndarray
    joint_limit: float
    limit_stiffness: float
    limit_damping: float
    sim_dt: float
    frame_skip: int
    include_position: bool

    @property
    def n_links(self) -> int:
        return int(self.mass.shape[0])

    @property
    def dt(self) -> float:
        """Duration of one env step (s)."""
        return self.sim_dt * self.frame_skip

    @property
    def obs_size(self) -> int:
        return observation_size(self.n_links, self.include_position)


def observation_size(n_links: int, include_position: bool) -> int:
    """[x, y] + (n-1) joint angles + cos/sin heading + 2 speeds + (n-1) joint rates."""
    return 2 * n_links + 2 + (2 if include_position else 0)


# --------------------------------------------------------------------------- kernels
@njit(cache=True, nogil=True)
def _center_of_mass(m, h, q):
    """Mass-weighted CM of the whole snake (m): CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1} (eq. 3)."""
    n = m.shape[0]
    px = q[n]
    py = q[n + 1]
    sx = m[0] * px
    sy = m[0] * py
    total = m[0]
    for k in range(n - 1):
        px += h[k] * math.cos(q[k]) + h[k + 1] * math.cos(q[k + 1])
        py += h[k] * math.sin(q[k]) + h[k + 1] * math.sin(q[k + 1])
        sx += m[k + 1] * px
        sy += m[k + 1] * py
        total += m[k + 1]
    return sx / total, sy / total


@njit(cache=True, nogil=True)
def _observe(m, h, inertia, q, u, include_position, cx, cy, obs):
    """Fill obs (see :data:`OBSERVATION_DOC`); return the kinetic energy (J).

    Link speeds V_k and rates omega_k follow eqs. 6-7 from u = (V_1, thetadot_1).
    """
    n = m.shape[0]
    j = 0
    if include_position:
        obs[0] = cx
        obs[1] = cy
        j = 2
    # joint angles phi_k = theta_{k+1} - theta_k, wrapped to (-pi, pi]
    for k in range(n - 1):
        phi = q[k + 1] - q[k]
        obs[j + k] = math.atan2(math.sin(phi), math.cos(phi))
    j += n - 1
    obs[j] = math.cos(q[0])
    obs[j + 1] = math.sin(q[0])
    obs[j + 2] = u[0]
    obs[j + 3] = u[1]
    j += 4
    V = u[0]
    W = u[1]
    kinetic = 0.5 * (m[0] * V * V + inertia[0] * W * W)
    for k in range(n - 1):
        phi = q[k + 1] - q[k]
        C = math.cos(phi)
        S = math.sin(phi)
        nV = V * C + W * h[k] * S  # eq. 6
        nW = (V * S - W * h[k] * C) / h[k + 1]  # eq. 7
        obs[j + k] = nW - W  # joint rate phidot_k
        V = nV
        W = nW
        kinetic += 0.5 * (m[k + 1] * V * V + inertia[k + 1] * W * W)
    return kinetic


@njit(cache=True, nogil=True)
def _step_one(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, sim_dt, frame_skip, include_position,
              q, u, torques, obs, aux):
    """Advance one snake in place by frame_skip RK4 steps; fill obs and aux.

    A step whose result is not finite is undone (q, u keep their pre-step
    values) and flagged in aux[AUX_FAILED], so no NaN ever leaves the kernel.
    """
    nq = q.shape[0]
    cx0, cy0 = _center_of_mass(m, h, q)
    q_before = q.copy()
    u_before = u.copy()
    work = compiled.rk4_step(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, sim_dt, frame_skip)
    finite = math.isfinite(work) and math.isfinite(u[0]) and math.isfinite(u[1])
    for j in range(nq):
        finite = finite and math.isfinite(q[j])
    if finite:
        cx, cy = _center_of_mass(m, h, q)
        finite = math.isfinite(cx) and math.isfinite(cy)
    if not finite:
        for j in range(nq):
            q[j] = q_before[j]
        u[0] = u_before[0]
        u[1] = u_before[1]
        cx = cx0
        cy = cy0
        work = 0.0
    env_dt = sim_dt * frame_skip
    aux[AUX_X] = cx
    aux[AUX_Y] = cy
    aux[AUX_VX] = (cx - cx0) / env_dt
    aux[AUX_VY] = (cy - cy0) / env_dt
    aux[AUX_KINETIC] = _observe(m, h, inertia, q, u, include_position, cx, cy, obs)
    aux[AUX_WORK] = work
    aux[AUX_FAILED] = 0.0 if finite else 1.0


@njit(cache=True, parallel=True)
def _step_batch(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, sim_dt, frame_skip, include_position,
                q, u, torques, obs, aux):
    for b in prange(q.shape[0]):
        _step_one(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, sim_dt, frame_skip, include_position,
                  q[b], u[b], torques[b], obs[b], aux[b])


@njit(cache=True, nogil=True)
def _step_batch_serial(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, sim_dt, frame_skip, include_position,
                       q, u, torques, obs, aux):
    for b in range(q.shape[0]):
        _step_one(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, sim_dt, frame_skip, include_position,
                  q[b], u[b], torques[b], obs[b], aux[b])


@njit(cache=True, nogil=True)
def _reset_one(m, h, inertia, include_position, noise, q, u, obs, aux):
    """Near-straight start: theta_k = noise_k, u = noise[n:], CM of the whole snake at the origin."""
    n = m.shape[0]
    for k in range(n):
        q[k] = noise[k]
    q[n] = 0.0
    q[n + 1] = 0.0
    u[0] = noise[n]
    u[1] = noise[n + 1]
    cx, cy = _center_of_mass(m, h, q)
    # shift so the whole snake's CM sits at the origin (x, y of eq. 1 is link 1's CM)
    q[n] = -cx
    q[n + 1] = -cy
    cx, cy = _center_of_mass(m, h, q)
    aux[AUX_X] = cx
    aux[AUX_Y] = cy
    aux[AUX_VX] = 0.0
    aux[AUX_VY] = 0.0
    aux[AUX_KINETIC] = _observe(m, h, inertia, q, u, include_position, cx, cy, obs)
    aux[AUX_WORK] = 0.0
    aux[AUX_FAILED] = 0.0


@njit(cache=True, nogil=True)
def _reset_batch(m, h, inertia, include_position, noise, q, u, obs, aux):
    for b in range(noise.shape[0]):
        _reset_one(m, h, inertia, include_position, noise[b], q[b], u[b], obs[b], aux[b])


@njit(cache=True, nogil=True)
def _observe_batch(m, h, inertia, include_position, q, u, obs, aux):
    for b in range(q.shape[0]):
        cx, cy = _center_of_mass(m, h, q[b])
        aux[b, AUX_X] = cx
        aux[b, AUX_Y] = cy
        aux[b, AUX_VX] = 0.0
        aux[b, AUX_VY] = 0.0
        aux[b, AUX_KINETIC] = _observe(m, h, inertia, q[b], u[b], include_position, cx, cy, obs[b])
        aux[b, AUX_WORK] = 0.0
        aux[b, AUX_FAILED] = 0.0


# --------------------------------------------------------------------------- pure API
def _outputs(params: PhysicsParams, batch: tuple):
    return np.empty(batch + (params.obs_size,)), np.empty(batch + (AUX_SIZE,))


def _as_state(params: PhysicsParams, q, u):
    q = np.array(q, dtype=np.float64, order="C", copy=True)
    u = np.array(u, dtype=np.float64, order="C", copy=True)
    n = params.n_links
    if q.shape[-1:] != (n + 2,) or u.shape[-1:] != (2,) or q.shape[:-1] != u.shape[:-1] or q.ndim > 2:
        raise ValueError(f"q must have shape (n+2,)=({n + 2},) or (B, {n + 2}) and u shape (2,) or (B, 2), "
                         f"got q {q.shape}, u {u.shape}")
    return q, u


def step(params: PhysicsParams, q, u, torques):
    """One env step of duration ``params.dt`` with torques (N m) held constant.

    Args:
        q: (n+2,) or (B, n+2) coordinates (eq. 1); u: (2,) or (B, 2) speeds (eq. 2);
        torques: (n-1,) or (B, n-1) joint torques (N m), already scaled and clipped.

    Returns (q_next, u_next, obs, aux); aux columns are AUX_* (CM position (m),
    CM velocity over the step (m/s), kinetic energy (J), work of all loads (J),
    failed flag). Inputs are not modified.
    """
    q, u = _as_state(params, q, u)
    torques = np.ascontiguousarray(torques, dtype=np.float64)
    if torques.shape != q.shape[:-1] + (params.n_links - 1,):
        raise ValueError(f"torques must have shape {q.shape[:-1] + (params.n_links - 1,)}, got {torques.shape}")
    obs, aux = _outputs(params, q.shape[:-1])
    kernel = _kernel(q)
    kernel(params.mass, params.half_length, params.inertia, params.joint_damping, params.wheel_damping,
           params.joint_limit, params.limit_stiffness, params.limit_damping, params.sim_dt, params.frame_skip,
           params.include_position, q, u, torques, obs, aux)
    return q, u, obs, aux


def _kernel(q):
    if q.ndim == 1:
        return _step_one
    # threads pay off only for enough work per call; waking them costs more than
    # stepping a few snakes (and far more on a loaded machine)
    return _step_batch if q.shape[0] * q.shape[1] >= PARALLEL_MIN_WORK else _step_batch_serial


def step_inplace(params: PhysicsParams, q, u, torques, obs, aux):
    """:func:`step` writing into caller-owned float64 C-contiguous buffers (the envs' hot path)."""
    kernel = _kernel(q)
    kernel(params.mass, params.half_length, params.inertia, params.joint_damping, params.wheel_damping,
           params.joint_limit, params.limit_stiffness, params.limit_damping, params.sim_dt, params.frame_skip,
           params.include_position, q, u, torques, obs, aux)


def reset(params: PhysicsParams, noise):
    """Initial states from uniform noise (B, n+2) or (n+2,): theta_k = noise[k] (rad),
    (V_1, thetadot_1) = noise[n:] (m/s, rad/s), whole-snake CM at the origin.

    Returns (q, u, obs, aux) shaped like :func:`step`'s output.
    """
    noise = np.ascontiguousarray(noise, dtype=np.float64)
    n = params.n_links
    if noise.shape[-1:] != (n + 2,) or noise.ndim > 2:
        raise ValueError(f"noise must have shape ({n + 2},) or (B, {n + 2}), got {noise.shape}")
    flat = noise.reshape(-1, n + 2)
    q = np.empty((flat.shape[0], n + 2))
    u = np.empty((flat.shape[0], 2))
    obs, aux = _outputs(params, (flat.shape[0],))
    _reset_batch(params.mass, params.half_length, params.inertia, params.include_position, flat, q, u, obs, aux)
    if noise.ndim == 1:
        return q[0], u[0], obs[0], aux[0]
    return q, u, obs, aux


def observe(params: PhysicsParams, q, u):
    """(obs, aux) of given states (aux velocity and work are 0: no step was taken)."""
    q, u = _as_state(params, q, u)
    qf = q.reshape(-1, params.n_links + 2)
    uf = u.reshape(-1, 2)
    obs, aux = _outputs(params, (qf.shape[0],))
    _observe_batch(params.mass, params.half_length, params.inertia, params.include_position, qf, uf, obs, aux)
    if q.ndim == 1:
        return obs[0], aux[0]
    return obs, aux
