"""The joint motors' reflected rotor inertia (``rotor_inertia``, N^2 J_r; MuJoCo's joint armature).

The rotor of joint k adds 1/2 J_r phidot_k^2 to the kinetic energy. Cross-checked: the O(n) sweep's
udot and wheel forces against eq. 27 solved by Lagrange and by Newton-Euler with the rotors in M; the
traction limit with rotors against the grip-free sweep and the multipliers under the scaled torques;
the lane step against the per-snake step; the work-energy balance with the rotors' kinetic energy;
and 0 (every preset's) against the previous physics, bit for bit.
"""

import math

import gymnasium as gym
import numpy as np
import pytest

from snake_env.dynamics import compiled, lagrange, newton_euler
from snake_env import physics
from snake_env.physics import AUX_FAILED, PhysicsConfig, stepping

from .test_traction import _random_state

ROTOR = 0.005  # kg m^2: the order of the Dynamixel MX armature of MuJoCo Menagerie's dynamixel_2r


def _built(n, **kwargs):
    kwargs.setdefault("actuator", "ideal")
    kwargs.setdefault("joint_limit", None)
    return PhysicsConfig(n_links=n, **kwargs).build()


@pytest.mark.parametrize("formulation", [lagrange, newton_euler])
@pytest.mark.parametrize("n", [2, 3, 5, 12])
def test_sweep_with_rotors_equals_the_multiplier_formulations(rng, formulation, n):
    """udot and the wheels' lateral forces of the O(n) sweep equal eq. 27's solution and multipliers
    with the rotors in M, to 1e-9 relative; without the rotors udot would differ by far more."""
    model, params = _built(n, wheel_friction=None, rotor_inertia=ROTOR)
    _, plain = _built(n, wheel_friction=None)
    rotors = np.full(n - 1, ROTOR)
    scratch = (np.empty((n, compiled.LINK_CHANNELS)), np.empty(n + 2), np.empty(2))
    changes = []
    for _ in range(20):
        q, u = _random_state(rng, n)
        torques = rng.uniform(-2.0, 2.0, n - 1)
        du, lam, du_plain = np.empty(2), np.empty(n), np.empty(2)
        compiled.derivatives(params.kernel_model, q, u, torques, np.empty(n + 2), du)
        compiled.wheel_lateral_forces(params.kernel_model, q, u, torques, *scratch, lam)
        compiled.derivatives(plain.kernel_model, q, u, torques, np.empty(n + 2), du_plain)
        qd = lagrange.consistent_qdot(model, q, u)
        qdd, lam_ref = formulation.qddot(model, q, qd, torques, with_multipliers=True, rotor_inertia=rotors)
        du_ref = lagrange.udot_from_qddot(q, qd, qdd)
        scale = np.max(np.abs(du_ref)) + 1.0
        np.testing.assert_allclose(du, du_ref, rtol=1e-9, atol=1e-9 * scale)
        np.testing.assert_allclose(lam, lam_ref, rtol=1e-9, atol=1e-9 * (np.max(np.abs(lam_ref)) + 1.0))
        changes.append(np.max(np.abs(du - du_plain)) / scale)
    assert max(changes) > 1e-2  # the rotors matter at these states


@pytest.mark.parametrize("n", [3, 5, 12])
def test_traction_limit_with_rotors(rng, n):
    """With finite grip and rotors, udot and lambda at the traction scale equal the grip-free sweep's and
    eq. 27's multipliers under the scaled torques, and no wheel ends past max(grip, |lambda_0|)."""
    model, params = _built(n, wheel_friction=0.6, rotor_inertia=ROTOR)
    _, plain = _built(n, wheel_friction=None, rotor_inertia=ROTOR)
    grip = params.wheel_grip
    links = np.empty((n, compiled.LINK_CHANNELS))
    scratch = (np.empty((n, compiled.LINK_CHANNELS)), np.empty(n + 2), np.empty(2))
    scales = []
    for _ in range(40):
        q, u = _random_state(rng, n, speed=rng.choice([0.1, 1.0]))
        torques = rng.uniform(-1.0, 1.0, n - 1) * rng.choice([0.05, 3.0])
        du, lam = np.empty(2), np.empty(n)
        _, scale, _ = compiled.traction_derivatives(params.kernel_model, q, u, torques, np.empty(n + 2), du,
                                                    links, lam)
        du_ref, lam_ref, lam0 = np.empty(2), np.empty(n), np.empty(n)
        compiled.derivatives(plain.kernel_model, q, u, scale * torques, np.empty(n + 2), du_ref)
        compiled.wheel_lateral_forces(plain.kernel_model, q, u, scale * torques, *scratch, lam_ref)
        compiled.wheel_lateral_forces(plain.kernel_model, q, u, 0.0 * torques, *scratch, lam0)
        np.testing.assert_allclose(du, du_ref, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(lam, lam_ref, rtol=1e-10, atol=1e-9)
        qd = lagrange.consistent_qdot(model, q, u)
        _, lam_multipliers = lagrange.qddot(model, q, qd, scale * torques, with_multipliers=True,
                                            rotor_inertia=np.full(n - 1, ROTOR))
        np.testing.assert_allclose(lam, lam_multipliers, rtol=1e-9, atol=1e-9 * (np.max(np.abs(lam)) + 1.0))
        assert np.all(np.abs(lam) <= np.maximum(grip, np.abs(lam0)) * (1 + 1e-9) + 1e-9)
        scales.append(scale)
    assert min(scales) < 1.0 and max(scales) == 1.0


@pytest.mark.parametrize("n", [3, 8])
def test_lane_step_with_rotors_equals_the_per_snake_step(rng, n):
    """The env's default robot (servo motors, grip) with rotors: the lane kernel's step equals the per-snake
    kernel's, state, observation, kinetic energy, work and wheel forces."""
    _, params = PhysicsConfig(n_links=n, rotor_inertia=ROTOR).build()
    B = 2 * compiled.LANES + 3
    theta = rng.uniform(-np.pi, np.pi, (B, 1)) + np.cumsum(rng.uniform(-0.6, 0.6, (B, n)), axis=1)
    q = np.concatenate([theta, rng.normal(size=(B, 2))], axis=1)
    u = rng.normal(scale=0.5, size=(B, 2))
    torques = rng.uniform(-1, 1, (B, n - 1))
    q_lane, u_lane = q.copy(), u.copy()
    obs_lane, aux_lane = np.empty((B, params.obs_size)), np.empty((B, physics.AUX_SIZE))
    forces, scale = np.empty((B, n)), np.empty(B)
    stepping.step_inplace(params, q_lane, u_lane, torques, obs_lane, aux_lane, forces, scale)
    assert not aux_lane[:, AUX_FAILED].any()
    scratch = (np.empty((n, compiled.LINK_CHANNELS)), np.empty(n + 2), np.empty(2))
    for b in range(B):
        qb, ub = q[b].copy(), u[b].copy()
        obs, aux = np.empty(params.obs_size), np.empty(physics.AUX_SIZE)
        stepping._step_one(params.kernel_model, params.kernel_settings, qb, ub, torques[b], obs, aux)
        np.testing.assert_allclose(q_lane[b], qb, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(u_lane[b], ub, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(obs_lane[b], obs, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(aux_lane[b], aux, rtol=1e-12, atol=1e-12)
        lam = np.empty(n)
        compiled.wheel_lateral_forces(params.kernel_model, qb, ub, torques[b], *scratch, lam)
        np.testing.assert_allclose(forces[b], lam, rtol=1e-12, atol=1e-10)


def test_work_energy_balance_counts_the_rotors(rng):
    """Over fine RK4 steps the change of K with the rotors' 1/2 J_r phidot^2 equals the loads' work
    (1e-8 of the energy), and K without the rotors' share would miss by far more."""
    n = 5
    _, params = _built(n, wheel_friction=None, rotor_inertia=ROTOR)
    _, plain = _built(n, wheel_friction=None)
    q, u = _random_state(rng, n)
    torques = rng.uniform(-1.0, 1.0, n - 1)
    k0 = stepping._measures(params.kernel_model, q, u)[0]
    k0_links = stepping._measures(plain.kernel_model, q, u)[0]
    work = 0.0
    for _ in range(200):
        work += compiled.rk4_step(params.kernel_model, q, u, torques, 1e-3, 1)
    k1 = stepping._measures(params.kernel_model, q, u)[0]
    k1_links = stepping._measures(plain.kernel_model, q, u)[0]
    energy = max(k0, k1)
    assert abs(k1 - k0 - work) < 1e-8 * energy
    assert abs(k1_links - k0_links - work) > 1e-3 * energy


def test_env_with_rotors_steps_checked_and_slower_joints(rng):
    """Snake5-v3 with the rotors runs random bang-bang commands without a failed step, and its peak joint
    rate stays below the rotor-free robot's."""
    peaks = {}
    for rotor in (0.0, ROTOR):
        env = gym.make("snake_env/Snake5-v3", rotor_inertia=rotor)
        env.reset(seed=3)
        actions = np.random.default_rng(7).choice([-1.0, 1.0], size=(150, 4))
        peak = 0.0
        for a in actions:
            obs, _, terminated, truncated, info = env.step(a)
            assert not info["sim_failure"] and not terminated
            peak = max(peak, float(np.max(np.abs(obs[-4:]))))
        peaks[rotor] = peak
        env.close()
    assert peaks[ROTOR] < peaks[0.0]


def test_zero_rotor_is_the_previous_physics_bit_for_bit():
    """rotor_inertia=0 (every preset's) leaves the kernels' rotor terms out: the same trajectory bit for bit."""
    _, params = PhysicsConfig(rotor_inertia=0.0).build()
    assert params.rotor_inertia is None and params.kernel_model[12].shape == (0,)
    runs = []
    for kwargs in ({}, {"rotor_inertia": 0.0}):
        env = gym.make("snake_env/Snake5-v3", **kwargs)
        obs, _ = env.reset(seed=11)
        trace = [obs]
        for a in np.random.default_rng(5).uniform(-1, 1, (60, 4)):
            trace.append(env.step(a)[0])
        runs.append(np.array(trace))
        env.close()
    np.testing.assert_array_equal(runs[0], runs[1])


@pytest.mark.parametrize("kwargs, words", [
    ({"rotor_inertia": -0.01}, "rotor_inertia"),
    ({"rotor_inertia": math.nan}, "rotor_inertia"),
    ({"paper_model": True, "rotor_inertia": 0.01}, "rotor_inertia"),
])
def test_bad_rotor_inertia_is_a_one_line_error(kwargs, words):
    with pytest.raises(ValueError) as err:
        PhysicsConfig(**kwargs)
    assert words in str(err.value) and "\n" not in str(err.value)
