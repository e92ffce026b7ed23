"""The lane (SIMD) RK4 kernel of snake_env.dynamics.compiled.

Anchors: the per-snake kernel ``rk4_step_batch`` (agreement to 1e-12), the
numpy RK4 of the paper's O(n^2) recursion, high-precision sin/cos (mpmath)
for the vectorisable sin/cos, and the independence of a snake's result from
its position in the batch (bit for bit).
"""

import numpy as np
import pytest

from snake_env.dynamics import SnakeModel, compiled
from snake_env.dynamics import rk4_step as numpy_rk4_step

mpmath = pytest.importorskip("mpmath")

LIMITS = (0.5, 30.0, 0.2)  # rad, N m/rad, N m s/rad
NO_LIMIT = (0.0, 0.0, 0.0)


def random_model(n, rng):
    """Unequal links, so no symmetry hides an index error."""
    return SnakeModel(n_links=n, mass=rng.uniform(0.5, 2.0, n), length=rng.uniform(0.1, 0.4, n),
                      inertia=rng.uniform(0.002, 0.02, n), joint_damping=rng.uniform(0.0, 0.3, n - 1),
                      wheel_damping=rng.uniform(0.0, 0.5, n))


def random_batch(n, B, rng):
    """Joint angles up to +-0.6 rad, so with LIMITS some joints are beyond the soft limit
    (larger random bends can put a long snake near a singular configuration, where the
    step blows up and no two formulations agree)."""
    q = rng.normal(size=(B, n + 2))
    q[:, :n] = rng.uniform(-np.pi, np.pi, (B, 1)) + np.cumsum(rng.uniform(-0.6, 0.6, (B, n)), axis=1)
    return q, rng.normal(size=(B, 2)), rng.normal(size=(B, n - 1))


def sincos(x):
    s, c = np.empty_like(x), np.empty_like(x)
    compiled.sincos_array(x, s, c)
    return s, c


def max_ulp_error(x):
    """Largest error of sincos over x, in units in the last place of the exact value."""
    mpmath.mp.prec = 140
    s, c = sincos(x)
    worst = 0.0
    for xi, si, ci in zip(x, s, c):
        for got, exact in ((si, mpmath.sin(mpmath.mpf(float(xi)))), (ci, mpmath.cos(mpmath.mpf(float(xi))))):
            worst = max(worst, float(abs(mpmath.mpf(float(got)) - exact)) / np.spacing(abs(float(exact))))
    return worst


def near_multiples_of_half_pi(k):
    """The doubles nearest to k pi/2 and their neighbours: where the reduction cancels most."""
    x = k * (np.pi / 2)
    return np.concatenate([np.nextafter(x, -np.inf), x, np.nextafter(x, np.inf)])


def test_sincos_is_within_one_ulp_over_a_wide_range():
    rng = np.random.default_rng(0)
    samples = {
        "uniform |x| <= 1e4": rng.uniform(-1e4, 1e4, 1500),
        "near k pi/2, |x| <= 1e4": rng.choice(near_multiples_of_half_pi(np.arange(1, 6367)), 1500),
        "the lanes' range |x| <= 2 LANE_ANGLE_MAX": rng.uniform(-2, 2, 1000) * compiled.LANE_ANGLE_MAX,
        "near k pi/2 up to 2 LANE_ANGLE_MAX": rng.choice(near_multiples_of_half_pi(np.arange(6367, 130_000, 7)), 1000),
        "tiny": np.exp(rng.uniform(np.log(1e-300), 0.0, 500)) * rng.choice([-1.0, 1.0], 500),
    }
    for name, x in samples.items():
        assert max_ulp_error(x) < 1.0, name  # measured 0.50-0.71 ulp


def test_sincos_special_values():
    s, c = sincos(np.array([0.0, np.pi / 2, np.pi, np.nan, np.inf, -np.inf]))
    assert s[0] == 0.0 and c[0] == 1.0
    np.testing.assert_array_equal(s[:3], np.sin([0.0, np.pi / 2, np.pi]))
    assert np.isnan(s[3:]).all() and np.isnan(c[3:]).all()
    s, c = sincos(np.random.default_rng(1).uniform(-1e5, 1e5, 100_000))
    assert np.abs(s).max() <= 1.0 and np.abs(c).max() <= 1.0


def wrap(phi):
    out = np.empty_like(phi)
    compiled.wrap_angle_array(phi, out)
    return out


def test_wrap_angle():
    rng = np.random.default_rng(2)
    inside = rng.uniform(-np.pi, np.pi, 1000)
    np.testing.assert_array_equal(wrap(inside), inside)  # |phi| < pi is returned as is
    turns = rng.integers(-30, 30, 200)
    phi = inside[:200] + 2 * np.pi * turns
    got = wrap(phi)
    mpmath.mp.prec = 140
    exact = [float(mpmath.mpf(float(p)) - 2 * mpmath.pi * int(k)) for p, k in zip(phi, turns)]
    np.testing.assert_allclose(got, exact, rtol=0, atol=np.spacing(np.pi))


@pytest.mark.parametrize("n", [2, 3, 7, 20])
@pytest.mark.parametrize("limits", [NO_LIMIT, LIMITS])
def test_lanes_agree_with_the_per_snake_kernel(n, limits):
    """B = 2 LANES + 5: full and partial lane groups; 3 RK4 substeps."""
    rng = np.random.default_rng(n)
    model = random_model(n, rng)
    B = 2 * compiled.LANES + 5
    q, u, torques = random_batch(n, B, rng)
    params = model.parameters()
    q_ref, u_ref, w_ref = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_batch(compiled.kernel_model(*params, *limits), q_ref, u_ref, torques, 0.01, 3, w_ref)
    q_lane, u_lane, w_lane = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_lanes(compiled.kernel_model(*params, *limits), q_lane, u_lane, torques, 0.01, 3, w_lane)
    assert not np.array_equal(q_lane, q)  # the state moved
    # a random long snake can start next to a singular configuration, where the step
    # blows up (|u| ~ 1e200 or NaN) in both kernels; compare the regular ones
    regular = np.abs(u_ref).max(axis=1) < 100.0
    assert regular.sum() >= B - 2
    assert not (np.abs(u_lane[~regular]) < 100.0).all(axis=1).any()
    np.testing.assert_allclose(q_lane[regular], q_ref[regular], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(u_lane[regular], u_ref[regular], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(w_lane[regular], w_ref[regular], rtol=1e-12, atol=1e-13)
    q_par, u_par, w_par = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_lanes_parallel(compiled.kernel_model(*params, *limits), q_par, u_par, torques, 0.01, 3, w_par)
    np.testing.assert_array_equal(q_par, q_lane)  # NaN equals NaN here
    np.testing.assert_array_equal(u_par, u_lane)
    np.testing.assert_array_equal(w_par, w_lane)


def test_lanes_match_numpy_rk4_of_the_paper_recursion():
    n, B = 6, 9
    rng = np.random.default_rng(3)
    model = random_model(n, rng)
    q, u, torques = random_batch(n, B, rng)
    dt = 0.01  # s
    q_lane, u_lane, work = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_lanes(compiled.kernel_model(*model.parameters(), *NO_LIMIT), q_lane, u_lane, torques, dt, 1, work)
    for b in range(B):
        q_ref, u_ref, w_ref = numpy_rk4_step(model, q[b], u[b], torques[b], dt, method="kane_paper")
        np.testing.assert_allclose(q_lane[b], q_ref, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(u_lane[b], u_ref, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(work[b], w_ref, rtol=1e-10, atol=1e-14)


def test_a_snake_alone_equals_the_same_snake_anywhere_in_a_batch():
    """Every lane runs the same IEEE operations (no FMA contraction): results do
    not depend on the lane, the group size or the vector/remainder code path."""
    n = 5
    rng = np.random.default_rng(4)
    model = random_model(n, rng)
    B = compiled.LANES + 7
    q, u, torques = random_batch(n, B, rng)
    params = model.parameters()
    q_all, u_all, w_all = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_lanes(compiled.kernel_model(*params, *LIMITS), q_all, u_all, torques, 0.005, 4, w_all)
    order = rng.permutation(B)
    q_perm, u_perm, w_perm = q[order].copy(), u[order].copy(), np.empty(B)
    compiled.rk4_step_lanes(compiled.kernel_model(*params, *LIMITS), q_perm, u_perm, torques[order], 0.005, 4, w_perm)
    np.testing.assert_array_equal(q_perm, q_all[order])
    np.testing.assert_array_equal(u_perm, u_all[order])
    np.testing.assert_array_equal(w_perm, w_all[order])
    for b in (0, 9, B - 1):
        q1, u1, w1 = q[b:b + 1].copy(), u[b:b + 1].copy(), np.empty(1)
        compiled.rk4_step_lanes(compiled.kernel_model(*params, *LIMITS), q1, u1, torques[b:b + 1], 0.005, 4, w1)
        np.testing.assert_array_equal(q1[0], q_all[b])
        np.testing.assert_array_equal(u1[0], u_all[b])
        assert w1[0] == w_all[b]


def test_large_angles_take_the_per_snake_kernel():
    """A snake turned by 32000 full turns (|theta| > LANE_ANGLE_MAX) is stepped by
    compiled.rk4_step (bit for bit) and moves as the unturned snake."""
    n, B = 4, 5
    rng = np.random.default_rng(5)
    model = random_model(n, rng)
    q, u, torques = random_batch(n, B, rng)
    turned = q.copy()
    turned[2, :n] += 2 * np.pi * 32_000
    assert np.abs(turned[2, :n]).min() > compiled.LANE_ANGLE_MAX
    params = model.parameters()
    q_lane, u_lane, w_lane = turned.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_lanes(compiled.kernel_model(*params, *LIMITS), q_lane, u_lane, torques, 0.01, 2, w_lane)
    q_one, u_one = turned[2].copy(), u[2].copy()
    w_one = compiled.rk4_step(compiled.kernel_model(*params, *LIMITS), q_one, u_one, torques[2], 0.01, 2)
    np.testing.assert_array_equal(q_lane[2], q_one)
    np.testing.assert_array_equal(u_lane[2], u_one)
    assert w_lane[2] == w_one
    q_plain, u_plain, w_plain = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_lanes(compiled.kernel_model(*params, *LIMITS), q_plain, u_plain, torques, 0.01, 2, w_plain)
    # the turned angles carry ~3e-11 rad of rounding (ulp at 2e5 rad)
    np.testing.assert_allclose(q_lane[2, :n] - 2 * np.pi * 32_000, q_plain[2, :n], atol=1e-9)
    np.testing.assert_allclose(u_lane[2], u_plain[2], atol=1e-9)
    for b in (0, 1, 3, 4):
        np.testing.assert_array_equal(q_lane[b], q_plain[b])


def test_non_finite_lane_does_not_touch_its_neighbours():
    n, B = 5, 6
    rng = np.random.default_rng(6)
    model = random_model(n, rng)
    q, u, torques = random_batch(n, B, rng)
    u[3, 0] = np.nan
    params = model.parameters()
    q_lane, u_lane, w_lane = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_lanes(compiled.kernel_model(*params, *LIMITS), q_lane, u_lane, torques, 0.01, 2, w_lane)
    assert np.isnan(u_lane[3]).all() and np.isnan(w_lane[3])
    keep = [0, 1, 2, 4, 5]
    q_ok, u_ok, w_ok = q[keep].copy(), u[keep].copy(), np.empty(B - 1)
    compiled.rk4_step_lanes(compiled.kernel_model(*params, *LIMITS), q_ok, u_ok, torques[keep], 0.01, 2, w_ok)
    np.testing.assert_array_equal(q_lane[keep], q_ok)
    np.testing.assert_array_equal(w_lane[keep], w_ok)
