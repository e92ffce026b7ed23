"""Physical invariants that any correct formulation must satisfy.

These checks do not reuse the recursion under test: kinetic-energy rates come
from finite differences of K along the motion, constraint accelerations from
the position kinematics CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1}.
"""

import numpy as np
import pytest

from .conftest import random_model, random_state

METHODS = ["kane", "kane_paper"]


def rate_along_motion(model, q, u, T, method, fn, eps=3e-5):
    """d/dt fn(q, u) by the fourth-order central stencil (error O(eps^4))."""
    qd = model.qdot(q, u)
    ud = model.udot(q, u, T, method=method)
    f = {k: fn(q + k * eps * qd, u + k * eps * ud) for k in (-2, -1, 1, 2)}
    return (f[-2] - 8 * f[-1] + 8 * f[1] - f[2]) / (12 * eps)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("n", [2, 3, 6, 15])
@pytest.mark.parametrize("damping", [False, True])
def test_kinetic_energy_rate_equals_load_power(rng, method, n, damping):
    """dK/dt = sum T_k phidot_k - dissipation, by central differences of K."""
    model = random_model(rng, n, damping=damping)
    q, u, T = random_state(rng, n, batch=(8,))
    dK = rate_along_motion(model, q, u, T, method, model.kinetic_energy)
    power = model.power(q, u, T)
    scale = 1.0 + np.abs(power)
    assert np.max(np.abs(dK - power) / scale) < 1e-8
    if damping:  # with zero torques, damping only removes energy
        dK0 = rate_along_motion(model, q, u, np.zeros_like(T), method, model.kinetic_energy)
        assert np.all(dK0 < 1e-8)


def cm_velocity_and_acceleration(model, q, u, T, method, eps=1e-4):
    """CM velocities from the position kinematics and CM accelerations from
    them, with link angular accelerations by central differences."""
    n = model.n_links
    h = model.half_length
    theta = q[..., :n]
    _, W = model.link_velocities(q, u)
    Wdot = rate_along_motion(model, q, u, T, method, lambda q, u: model.link_velocities(q, u)[1], eps)
    e = np.stack([np.cos(theta), np.sin(theta)], -1)
    e_perp = np.stack([-np.sin(theta), np.cos(theta)], -1)
    udot = model.udot(q, u, T, method=method)
    # head CM: velocity V_1 e_1 (eq. 4), acceleration Vdot_1 e_1 + V_1 omega_1 e_1perp
    v = [u[..., 0, None] * e[..., 0, :]]
    a = [udot[..., 0, None] * e[..., 0, :] + (u[..., 0] * W[..., 0])[..., None] * e_perp[..., 0, :]]
    for k in range(n - 1):
        # CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1}, differentiated twice
        dv = sum(h[j] * W[..., j, None] * e_perp[..., j, :] for j in (k, k + 1))
        da = sum(h[j] * (Wdot[..., j, None] * e_perp[..., j, :] - W[..., j, None] ** 2 * e[..., j, :]) for j in (k, k + 1))
        v.append(v[-1] + dv)
        a.append(a[-1] + da)
    return np.stack(v, -2), np.stack(a, -2), e, e_perp, W


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("n", [2, 4, 10])
def test_no_side_slip_constraints_and_their_derivative_hold(rng, method, n):
    model = random_model(rng, n, damping=True)
    q, u, T = random_state(rng, n, batch=(6,))
    v, a, e, e_perp, W = cm_velocity_and_acceleration(model, q, u, T, method)
    # constraint: e_k^perp . CMdot_k = 0
    assert np.max(np.abs(np.sum(e_perp * v, -1))) < 1e-12
    # its time derivative: e_k^perp . CMddot_k - omega_k e_k . CMdot_k = 0
    residual = np.sum(e_perp * a, -1) - W * np.sum(e * v, -1)
    scale = 1.0 + np.max(np.abs(a))
    assert np.max(np.abs(residual)) / scale < 1e-7


@pytest.mark.parametrize("method", METHODS)
def test_rigid_rotation_and_translation_leave_udot_unchanged(rng, method):
    n = 7
    model = random_model(rng, n, damping=True)
    q, u, T = random_state(rng, n, batch=(5,))
    moved = q.copy()
    moved[..., :n] += 1.234  # rotate every link by the same angle (rad)
    moved[..., n:] += np.array([10.0, -3.0])  # translate (m)
    np.testing.assert_allclose(model.udot(moved, u, T, method=method), model.udot(q, u, T, method=method),
                               rtol=1e-11, atol=1e-11)


@pytest.mark.parametrize("method", METHODS)
def test_mirror_image_flips_turning_only(rng, method):
    """Reflecting the snake: (phi, T, u_2) -> (-phi, -T, -u_2) gives
    (udot_1, udot_2) -> (udot_1, -udot_2)."""
    n = 6
    model = random_model(rng, n, damping=True)
    q, u, T = random_state(rng, n, batch=(5,))
    mirrored_q = q.copy()
    mirrored_q[..., :n] = -q[..., :n]
    mirrored_u = u * np.array([1.0, -1.0])
    out = model.udot(q, u, T, method=method)
    mirrored = model.udot(mirrored_q, mirrored_u, -T, method=method)
    np.testing.assert_allclose(mirrored, out * np.array([1.0, -1.0]), rtol=1e-11, atol=1e-11)


def test_qdot_matches_finite_difference_of_positions(rng):
    """qdot from the recursion moves every link CM along its own axis."""
    n = 5
    model = random_model(rng, n)
    q, u, _ = random_state(rng, n, batch=(4,))
    eps = 1e-6
    qd = model.qdot(q, u)
    v_fd = (model.cm_positions(q + eps * qd) - model.cm_positions(q - eps * qd)) / (2 * eps)
    V, _ = model.link_velocities(q, u)
    theta = q[..., :n]
    v_pred = V[..., None] * np.stack([np.cos(theta), np.sin(theta)], -1)
    np.testing.assert_allclose(v_fd, v_pred, rtol=1e-7, atol=1e-8)


def test_actuator_power_is_total_power_without_damping_and_exceeds_it_with(rng):
    """joint_power counts the actuators only; power adds the (dissipative) damping."""
    n = 5
    q, u, T = random_state(rng, n, batch=(6,))
    undamped = random_model(rng, n)
    np.testing.assert_allclose(undamped.joint_power(q, u, T), undamped.power(q, u, T), rtol=1e-14, atol=1e-14)
    damped = random_model(rng, n, damping=True)
    dissipation = damped.joint_power(q, u, T) - damped.power(q, u, T)
    assert np.all(dissipation > 0)
    V, W = damped.link_velocities(q, u)
    expected = np.sum(damped.joint_damping * np.diff(W, axis=-1) ** 2, -1) + np.sum(damped.wheel_damping * V**2, -1)
    np.testing.assert_allclose(dissipation, expected, rtol=1e-12)
