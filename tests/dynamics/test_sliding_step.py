"""The time-stepped sliding-wheel model (snake_env.dynamics.sliding_step): its mass matrix and loads are those
of eq. 24-25, it is first order in the substep, the regularised reference converges to it as the regularisation
vanishes, the no-slip model of eq. 27 is its limit at high friction, the work-energy balance closes with
friction's work as h -> 0, and the friction obeys Coulomb's law."""

from __future__ import annotations

import math

import numpy as np
import pytest

from snake_env.dynamics import lagrange, sliding_step
from snake_env.dynamics.model import SnakeModel
from snake_env.dynamics.sliding import SlidingWheels

from .test_sliding import COMMAND, SERVO, N, no_slip, start  # noqa: F401  (start: a fixture)

DT = 0.04  # s, the env's control period


def step(wheels, y, substeps, steps, command=COMMAND):
    for _ in range(steps):
        y, _ = wheels.advance_time_stepping(y, command, DT, substeps)
    return y


def test_kinetic_energy_is_eq_22_with_rotors(start):
    model, q, qdot = start
    wheels = SlidingWheels(model, 0.8, rotor_inertia=np.full(N - 1, 0.004), **SERVO)
    _, _, _, inertia, lever, _, _, _, _, _, _, _, _, _, _, _, rotor, mass = wheels.compiled_constants()
    rng = np.random.default_rng(1)
    for _ in range(5):
        qq = np.concatenate([rng.uniform(-2, 2, N), rng.normal(size=2)])
        qd = rng.normal(size=N + 2)
        assert sliding_step.kinetic_energy(qq, qd, lever, mass, inertia, rotor) == pytest.approx(
            wheels.kinetic_energy(qq, qd), rel=1e-12)


def test_one_short_substep_accelerates_as_eq_27(start):
    """With grip that never runs out, (qdot+ - qdot) / h is eq. 27's qddot (Lagrange's multipliers) to O(h):
    M, B, the loads and the constraint projection of the time step are the paper's."""
    model, q, qdot = start
    wheels = SlidingWheels(model, 1e9, **SERVO)
    torques = wheels.joint_torques(COMMAND, q, qdot)
    expected = lagrange.qddot(model, q, qdot, torques)
    for h in (1e-5, 1e-6):
        y, _ = wheels.advance_time_stepping(wheels.initial(q, qdot), COMMAND, h, 1)
        accel = (y[N + 2:2 * N + 4] - qdot) / h
        assert np.max(np.abs(accel - expected)) < 200 * h * np.max(np.abs(expected))


def test_first_order_in_the_substep(start):
    model, q, qdot = start
    wheels = SlidingWheels(model, 0.8, **SERVO)
    y = {sub: step(wheels, wheels.initial(q, qdot), sub, 6) for sub in (20, 40, 80)}
    coarse, fine = np.max(np.abs(y[20] - y[40])), np.max(np.abs(y[40] - y[80]))
    assert 1.5 < coarse / fine < 3.0  # halving h halves the error


def test_regularised_reference_converges_to_it(start):
    """The LSODA model of :mod:`.sliding` (Coulomb's law smoothed over v_eps) approaches the exact-Coulomb time
    step as v_eps -> 0, by about 1/v_eps: the two models agree where they should."""
    model, q, qdot = start
    exact = step(SlidingWheels(model, 0.8, **SERVO), SlidingWheels(model, 0.8, **SERVO).initial(q, qdot), 640, 6)
    distances = []
    for slip_speed in (1e-2, 1e-3, 1e-4):
        wheels = SlidingWheels(model, 0.8, slip_speed=slip_speed, **SERVO)
        y = wheels.initial(q, qdot)
        for _ in range(6):
            y = wheels.advance(y, COMMAND, DT)
        distances.append(np.max(np.abs(y[:N + 2] - exact[:N + 2])))
    assert distances[0] > 5 * distances[1] > 25 * distances[2]
    assert distances[2] < 1e-3  # rad, m after 0.24 s


def test_sliding_happens_and_converges_to_the_no_slip_model_as_friction_grows(start):
    model, q, qdot = start
    reference = no_slip(model, q, qdot, 6 * DT)
    slow = SlidingWheels(model, 0.8, **SERVO)
    y = step(slow, slow.initial(q, qdot), 40, 1)
    _, share = slow.advance_time_stepping(y, COMMAND, DT, 40)
    assert np.max(share) > 0.5  # at mu = 0.8 these torques make wheels slide in the second step
    errors = []
    for substeps in (40, 160):
        wheels = SlidingWheels(model, 1e6, **SERVO)
        y = wheels.initial(q, qdot)
        for _ in range(6):
            y, share = wheels.advance_time_stepping(y, COMMAND, DT, substeps)
            assert not np.any(share)
        errors.append(np.max(np.abs(y[:N + 2] - reference[:N + 2])))
    assert errors[0] > 3 * errors[1]
    assert errors[1] < 2e-3


def test_work_energy_balance_closes_with_friction_as_h_shrinks(start):
    model, q, qdot = start
    residuals = []
    for substeps in (40, 160, 640):
        wheels = SlidingWheels(model, 0.8, **SERVO)
        y0 = wheels.initial(q, qdot)
        y = step(wheels, y0, substeps, 10)
        k0, k1 = wheels.kinetic_energy(q, qdot), wheels.kinetic_energy(y[:N + 2], y[N + 2:2 * N + 4])
        assert y[-1] < 0.0  # friction takes energy out
        residuals.append(abs(k1 - k0 - y[-2] - y[-1]))
    assert residuals[0] > 3 * residuals[1] > 9 * residuals[2]
    assert residuals[2] < 1e-4 * abs(y[-1])  # J: 3e-6 J at h = 62.5 us beside 0.25 J of friction's work


def test_coulomb_law_at_every_wheel(start):
    model, q, qdot = start
    wheels = SlidingWheels(model, 0.8, **SERVO)
    y = wheels.initial(q, qdot)
    h = DT / 40
    impulse = np.zeros(N)
    slid_any = False
    for _ in range(10):
        y, _ = wheels.advance_time_stepping(y, COMMAND, DT, 40, impulse)
        constants = wheels.compiled_constants()
        grip = constants[5]
        lateral = np.zeros(N)
        # the lateral velocities of the last substep, from one more substep's kernel call on a copy
        qq, qd = y[:N + 2].copy(), y[N + 2:2 * N + 4].copy()
        p = impulse.copy()
        sliding_step.advance(qq, qd, COMMAND, *constants, h, 1, p, np.zeros(5), np.zeros(N), lateral, 0)
        assert np.all(np.abs(p) <= grip * h * (1 + 1e-12))
        sliding = np.abs(lateral) > sliding_step.SLIDE_SPEED
        slid_any |= bool(np.any(sliding))
        # a sliding wheel's friction is mu m g against its slide; a gripping wheel does not move sideways
        np.testing.assert_allclose(p[sliding], -grip[sliding] * h * np.sign(lateral[sliding]), rtol=1e-12)
        assert np.all(np.abs(lateral[~sliding]) <= sliding_step.SLIDE_SPEED)
        impulse = p
        y = np.concatenate([qq, qd, y[-2:]])
    assert slid_any


def test_bad_substeps_is_one_line_error(start):
    model, q, qdot = start
    wheels = SlidingWheels(model, 0.8, **SERVO)
    for bad in (0, 2.5, None):
        with pytest.raises(ValueError, match="substeps must be an int >= 1"):
            wheels.advance_time_stepping(wheels.initial(q, qdot), COMMAND, DT, bad)


def test_long_snake_steps_and_stays_finite():
    """n = 30: the friction solve (projected Gauss-Seidel) converges on a long chain's Delassus matrix."""
    n = 30
    model = SnakeModel(n, mass=1.0, length=0.2, inertia=0.005, joint_damping=0.01, wheel_damping=0.1)
    rng = np.random.default_rng(3)
    q = np.concatenate([rng.uniform(-0.3, 0.3, n), [0.0, 0.0]])
    qdot = lagrange.consistent_qdot(model, q, np.array([0.3, 0.5]))
    wheels = SlidingWheels(model, 0.8, **SERVO)
    y = wheels.initial(q, qdot)
    for _ in range(10):
        y, share = wheels.advance_time_stepping(y, rng.uniform(-1, 1, n - 1), DT, 40)
        assert np.all(np.isfinite(y))
    assert math.isfinite(wheels.solver_stats[2]) and wheels.solver_stats[2] < sliding_step.PGS_MAX_SWEEPS


def test_active_set_and_gauss_seidel_find_the_same_unique_solution():
    """The box-constrained problem with a positive definite D has one solution; the active-set solve (exact to
    rounding) and projected Gauss-Seidel (to its tolerance) find it from any start, and it obeys Coulomb's law."""
    rng = np.random.default_rng(0)
    settled = 0
    for _ in range(300):
        n = int(rng.integers(2, 31))
        X = rng.normal(size=(n, n))
        D = X @ X.T + 0.05 * np.eye(n)
        b, bounds = rng.normal(size=n), rng.uniform(0.05, 1.0, n)
        exact, state = np.zeros(n), rng.integers(-1, 2, n)
        iterations = sliding_step._active_set(D, b, bounds, exact, state, np.empty((n, n)), np.empty((n, n)),
                                              np.empty(n), np.empty(n, np.int64))
        pgs = np.zeros(n)
        assert sliding_step._projected_gauss_seidel(D, b, bounds, pgs) > 0
        if iterations < 0:
            continue  # the step falls back to Gauss-Seidel there
        settled += 1
        np.testing.assert_allclose(exact, pgs, atol=1e-9)
        w = b + D @ exact
        grips = np.abs(exact) < bounds * (1 - 1e-12)
        assert np.all(np.abs(w[grips]) < 1e-9)
        assert np.all(np.abs(exact) <= bounds * (1 + 1e-12))
        assert np.all(-np.sign(exact[~grips]) * w[~grips] >= -1e-9)  # friction against the slide
    assert settled > 290


@pytest.mark.parametrize("n, rotor", [(2, 0.0), (3, 0.0), (5, 0.0), (12, 0.004), (30, 0.0)])
def test_the_three_friction_solves_agree(n, rotor):
    """The O(n) recursive solve (no rotors), the null-space solve and the Delassus-matrix solve are three
    formulations of one strictly convex problem: on random states, torques and warm starts (wheels gripping and
    sliding) they give the same velocities and impulses to rounding, and each obeys Coulomb's law."""
    model = SnakeModel(n, mass=1.0, length=0.2, inertia=0.005, joint_damping=0.01, wheel_damping=0.1)
    wheels = SlidingWheels(model, 0.8, rotor_inertia=np.full(n - 1, rotor) if rotor else None, **SERVO)
    constants = wheels.compiled_constants()
    grip, h = constants[5], 1e-3
    rng = np.random.default_rng(n)
    states = {"grip": 0, "slide": 0}
    for _ in range(40):
        q = np.concatenate([rng.uniform(-1, 1, n), rng.normal(size=2)])
        qdot = rng.normal(size=n + 2) * rng.uniform(0.05, 2.0)
        command = rng.uniform(-1, 1, n - 1)
        warm = rng.uniform(-1, 1, n) * grip * h * rng.integers(0, 2)
        results = []
        for method in ((1, 2) if rotor else (0, 1, 2)):  # the recursion takes no rotors (solve_method)
            qq, qd, p, lateral, stats = q.copy(), qdot.copy(), warm.copy(), np.zeros(n), np.zeros(5)
            assert sliding_step.advance(qq, qd, command, *constants, h, 1, p, stats, np.zeros(n), lateral, method)
            assert stats[3] == (1 if method == 2 else 0)  # substeps solved through the Delassus matrix
            results.append((qd, p, lateral))
        reference = results[-1]
        for qd, p, lateral in results[:-1]:
            np.testing.assert_allclose(qd, reference[0], rtol=0, atol=1e-12 * (1 + np.max(np.abs(reference[0]))))
            np.testing.assert_allclose(p, reference[1], rtol=0, atol=1e-11 * np.max(grip * h))
            sliding = np.abs(lateral) > sliding_step.SLIDE_SPEED
            np.testing.assert_allclose(p[sliding], -grip[sliding] * h * np.sign(lateral[sliding]), rtol=1e-12)
            assert np.all(np.abs(p) <= grip * h * (1 + 1e-12))
            states["slide"] += int(np.sum(sliding))
            states["grip"] += int(np.sum(~sliding))
    assert min(states.values()) > 0  # both kinds of wheel were tested


def test_the_per_substep_calls_are_inlined_into_the_row_kernels():
    """The speed of a substep rests on them (sliding_step.SUBSTEP_CALLS_INLINED); the recorded forward fixture holds
    the bits."""
    for name in sliding_step.SUBSTEP_CALLS_INLINED:
        assert getattr(sliding_step, name).targetoptions.get("inline") == "always", name
