"""The compiled (numba) hot path against the numpy references.

Anchors: the paper's O(n^2) recursion (``kane_paper``) for udot, the model's
kinematics for qdot and power, the numpy RK4 for a step, single-state kernels
for the batched ones, and the work-energy balance for long runs.
"""

import numpy as np
import pytest

from snake_env.dynamics import SnakeModel, compiled, kane
from snake_env.dynamics import rk4_step as numpy_rk4_step

NO_LIMIT = (0.0, 0.0, 0.0)  # limit <= 0 disables the soft joint limits


def random_model(n, rng, damped=True):
    """Unequal links, so no symmetry hides an index error."""
    return SnakeModel(
        n_links=n,
        mass=rng.uniform(0.5, 2.0, n),
        length=rng.uniform(0.1, 0.4, n),
        inertia=rng.uniform(0.002, 0.02, n),
        joint_damping=rng.uniform(0.0, 0.3, n - 1) if damped else 0.0,
        wheel_damping=rng.uniform(0.0, 0.5, n) if damped else 0.0,
    )


def random_state(n, rng, batch=()):
    q = rng.normal(size=batch + (n + 2,))
    q[..., :n] = np.cumsum(rng.uniform(-0.8, 0.8, batch + (n,)), axis=-1)  # joint angles within +-0.8 rad
    u = rng.normal(size=batch + (2,))
    torques = rng.normal(size=batch + (n - 1,))
    return q, u, torques


@pytest.mark.parametrize("n", [2, 3, 7, 20])
def test_derivatives_match_paper_recursion_and_kinematics(n):
    rng = np.random.default_rng(n)
    model = random_model(n, rng)
    for _ in range(5):
        q, u, torques = random_state(n, rng)
        dq, du = np.empty(n + 2), np.empty(2)
        power = compiled.derivatives(compiled.kernel_model(*model.parameters(), *NO_LIMIT), q, u, torques, dq, du)
        np.testing.assert_allclose(du, model.udot(q, u, torques, method="kane_paper"), rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(dq, model.qdot(q, u), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(power, model.power(q, u, torques), rtol=1e-10, atol=1e-12)


def limit_torques(model, q, u, torques, limit, k_limit, c_limit):
    """Joint torques with the limit barrier added (s(d) (k d / (1 - d/R) + c phidot),
    R = fold - limit, s(d) = d / (d + ramp)), computed with numpy kinematics."""
    _, omega = model.link_velocities(q, u)
    phi = np.diff(q[: model.n_links])
    phidot = np.diff(omega)
    excess = np.where(phi > limit, phi - limit, np.where(phi < -limit, phi + limit, 0.0))
    depth = np.minimum(np.abs(excess) / (compiled.FOLD_ANGLE - limit), compiled.BARRIER_CAP)
    ramp = np.abs(excess) / (np.abs(excess) + compiled.LIMIT_RAMP)
    return torques - np.where(excess != 0.0, ramp * (k_limit * excess / (1.0 - depth) + c_limit * phidot), 0.0)


def test_soft_joint_limit_equals_extra_joint_torque():
    n = 6
    rng = np.random.default_rng(1)
    model = random_model(n, rng)
    limit, k_limit, c_limit = 0.3, 40.0, 0.7  # rad, N m/rad, N m s/rad
    for _ in range(5):
        q, u, torques = random_state(n, rng)
        # joints 0, 2, 4 beyond +-0.3 rad (joint 4 deep in the barrier, d/R ~ 0.8), joints 1, 3 inside
        phi = np.array([0.5, -0.1, -0.45, 0.2, 2.5]) + rng.uniform(-0.005, 0.005, n - 1)
        q[:n] = rng.normal() + np.concatenate([[0.0], np.cumsum(phi)])
        phi = np.diff(q[:n])
        assert np.any(np.abs(phi) > limit) and np.any(np.abs(phi) < limit)
        dq, du = np.empty(n + 2), np.empty(2)
        limited = compiled.kernel_model(*model.parameters(), limit, k_limit, c_limit)
        power = compiled.derivatives(limited, q, u, torques, dq, du)
        effective = limit_torques(model, q, u, torques, limit, k_limit, c_limit)
        np.testing.assert_allclose(du, model.udot(q, u, effective, method="kane_paper"), rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(power, model.power(q, u, effective), rtol=1e-10, atol=1e-12)


def test_rk4_step_matches_numpy_rk4_of_paper_recursion():
    n = 5
    rng = np.random.default_rng(2)
    model = random_model(n, rng)
    q, u, torques = random_state(n, rng)
    dt = 0.01  # s
    q_ref, u_ref, w_ref = numpy_rk4_step(model, q, u, torques, dt, method="kane_paper")
    qc, uc = q.copy(), u.copy()
    work = compiled.rk4_step(compiled.kernel_model(*model.parameters(), *NO_LIMIT), qc, uc, torques, dt, 1)
    np.testing.assert_allclose(qc, q_ref, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(uc, u_ref, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(work, w_ref, rtol=1e-10, atol=1e-14)


def test_substeps_equal_repeated_single_steps():
    n = 4
    rng = np.random.default_rng(3)
    model = random_model(n, rng)
    q, u, torques = random_state(n, rng)
    model_args = compiled.kernel_model(*model.parameters(), 0.4, 20.0, 0.5)
    qa, ua = q.copy(), u.copy()
    work_a = compiled.rk4_step(model_args, qa, ua, torques, 0.005, 3)
    qb, ub, work_b = q.copy(), u.copy(), 0.0
    for _ in range(3):
        work_b += compiled.rk4_step(model_args, qb, ub, torques, 0.005, 1)
    np.testing.assert_allclose(qa, qb, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(ua, ub, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(work_a, work_b, rtol=1e-12, atol=1e-15)


def test_batch_kernels_equal_single_kernels():
    n, B = 6, 9
    rng = np.random.default_rng(4)
    model = random_model(n, rng)
    q, u, torques = random_state(n, rng, (B,))
    params = model.parameters()
    limits = (0.5, 30.0, 0.2)

    qb, ub, work = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_batch(compiled.kernel_model(*params, *limits), qb, ub, torques, 0.01, 2, work)
    dq, du, power = np.empty_like(q), np.empty_like(u), np.empty(B)
    compiled.derivatives_batch(*params, q, u, torques, dq, du, power)
    du_serial, du_parallel = np.empty_like(u), np.empty_like(u)
    compiled.udot_batch(*params, q, u, torques, du_serial)
    compiled.udot_batch_parallel(*params, q, u, torques, du_parallel)
    du_single = np.empty(2)
    for b in range(B):
        qs, us = q[b].copy(), u[b].copy()
        ws = compiled.rk4_step(compiled.kernel_model(*params, *limits), qs, us, torques[b], 0.01, 2)
        np.testing.assert_array_equal(qb[b], qs)
        np.testing.assert_array_equal(ub[b], us)
        assert work[b] == ws
        dqs, dus = np.empty(n + 2), np.empty(2)
        ps = compiled.derivatives(compiled.kernel_model(*params, *NO_LIMIT), q[b], u[b], torques[b], dqs, dus)
        np.testing.assert_array_equal(dq[b], dqs)
        np.testing.assert_array_equal(du[b], dus)
        np.testing.assert_array_equal(du_serial[b], dus)
        np.testing.assert_array_equal(du_parallel[b], dus)
        compiled.udot_single(*params, q[b], u[b], torques[b], du_single)
        np.testing.assert_array_equal(du_single, dus)
        assert power[b] == ps


def energy_drift(model, q, u, limits, dt, t_end=4.0):
    """|K(t_end) - W(t_end) - K(0)| (J) and W(t_end) (J), torques piecewise constant over 8 ms."""
    q, u = q.copy(), u.copy()
    k0 = model.kinetic_energy(q, u)
    work = 0.0
    steps_per_hold = int(round(0.008 / dt))
    for step in range(int(round(t_end / dt))):
        t_hold = 0.008 * (step // steps_per_hold)  # s
        torques = np.sin(5.0 * t_hold + np.arange(model.n_joints))  # N m
        work += compiled.rk4_step(compiled.kernel_model(*model.parameters(), *limits), q, u, torques, dt, 1)
    return abs(model.kinetic_energy(q, u) - work - k0), work


@pytest.mark.parametrize("limits, min_ratio", [(NO_LIMIT, 12.0), ((0.35, 50.0, 0.3), 3.0)])
def test_work_energy_balance_converges(limits, min_ratio):
    """K(t) - W(t) is constant in the continuous model (paper section VI.3):
    the RK4 drift must shrink with dt at 4th order for the smooth model (2^4 = 16)
    and still clearly converge with the soft limits, whose torque has a kink at
    the limit angle (second order there, 2^2 = 4)."""
    n = 8
    rng = np.random.default_rng(5)
    model = random_model(n, rng)
    q, u, _ = random_state(n, rng)
    coarse, work = energy_drift(model, q, u, limits, 0.004)
    fine, _ = energy_drift(model, q, u, limits, 0.002)
    assert abs(work) > 0.1  # the loads did real work, so the balance is not trivially met
    assert fine < 1e-3 * abs(work)
    assert coarse / fine > min_ratio


@pytest.mark.parametrize("batch", [(), (7,), (2, 3)])
def test_model_udot_float64_dispatch_matches_paper(batch):
    n = 9
    rng = np.random.default_rng(6)
    model = random_model(n, rng)
    q, u, torques = random_state(n, rng, batch)
    expected = model.udot(q, u, torques, method="kane_paper")
    got = model.udot(q, u, torques)
    assert got.shape == batch + (2,) and got.dtype == np.float64
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-10)
    sweep = kane.udot_sweep(model, q, u, torques)
    np.testing.assert_allclose(got, sweep, rtol=1e-11, atol=1e-11)


def test_model_udot_broadcasts_and_uses_parallel_kernel_for_large_batches():
    n = 3
    rng = np.random.default_rng(7)
    model = random_model(n, rng)
    q, u, torques = random_state(n, rng, (kane.PARALLEL_BATCH + 5,))
    single_torque = torques[0]
    got = model.udot(q, u[0], single_torque)  # u and torques broadcast over the batch
    expected = kane.udot_sweep(model, q, np.broadcast_to(u[0], q.shape[:-1] + (2,)),
                               np.broadcast_to(single_torque, q.shape[:-1] + (n - 1,)))
    np.testing.assert_allclose(got, expected, rtol=1e-11, atol=1e-11)


def test_float32_stays_on_numpy_sweep():
    n = 5
    rng = np.random.default_rng(8)
    model = random_model(n, rng, damped=False)
    q, u, torques = (a.astype(np.float32) for a in random_state(n, rng, (4,)))
    got = model.udot(q, u, torques)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, kane.udot_sweep(model, q, u, torques))
    np.testing.assert_allclose(got, model.udot(q.astype(np.float64), u.astype(np.float64), torques.astype(np.float64)),
                               rtol=1e-3, atol=1e-4)
