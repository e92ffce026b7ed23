"""The traction limit (compiled.traction_derivatives): with finite grip the motors' torques are
scaled by the largest s <= 1 that keeps every wheel's lateral force within mu m_k g, or adds no
excess where the motion alone exceeds it.

Cross-checked against the kernel without grip (the same state under the scaled torques gives the
same udot and wheel forces), checked for maximality, for the lane kernel = the per-snake kernel, for
the work-energy balance of the step, and for its limit: ample grip gives the no-slip trajectories.
"""

import math

import gymnasium as gym
import numpy as np
import pytest

from snake_env.dynamics import compiled
from snake_env.physics import GRAVITY, PhysicsConfig
from snake_env.physics.config import SLIP_TOLERANCE, sliding, sliding_into


def _models(n, friction, **kwargs):
    """(kernel model with grip, the same without) of an env config, with ideal torque sources unless
    ``actuator`` is given (the scale multiplies the motor's output, so only for ideal sources is it a
    scale of the commands)."""
    kwargs.setdefault("actuator", "ideal")
    _, params = PhysicsConfig(wheel_model="no_slip", n_links=n, wheel_friction=friction, **kwargs).build()
    _, plain = PhysicsConfig(wheel_model="no_slip", n_links=n, **kwargs).build()
    return params.kernel_model, plain.kernel_model


def _random_state(rng, n, speed=1.0):
    """A state with joint angles within 1 rad and speeds of scale ``speed`` (m/s, rad/s)."""
    q = np.empty(n + 2)
    q[0] = rng.uniform(-math.pi, math.pi)
    q[1:n] = q[0] + np.cumsum(rng.uniform(-1.0, 1.0, n - 1))
    q[n:] = rng.uniform(-1.0, 1.0, 2)
    return q, rng.normal(0.0, speed, 2)


@pytest.mark.parametrize("n", [2, 3, 5, 12])
def test_scaled_step_is_the_plain_sweep_under_the_scaled_torques(rng, n):
    """udot, the power, the motors' absolute power and lambda at the chosen scale equal the grip-free
    kernel's under s * torques."""
    model, plain = _models(n, 0.6, joint_limit=None)
    links = np.empty((n, compiled.LINK_CHANNELS))
    scales = []
    for _ in range(40):
        q, u = _random_state(rng, n, speed=0.1)
        torques = rng.uniform(-1.0, 1.0, n - 1) * rng.choice([0.05, 3.0])
        dq, du, lam = np.empty(n + 2), np.empty(2), np.empty(n)
        power, scale, motor = compiled.traction_derivatives(model, q, u, torques, dq, du, links, lam)
        dq_ref, du_ref, lam_ref = np.empty(n + 2), np.empty(2), np.empty(n)
        power_ref = compiled.derivatives(plain, q, u, scale * torques, dq_ref, du_ref)
        _, motor_ref = compiled.derivatives_motor(plain, q, u, scale * torques, np.empty(n + 2), np.empty(2))
        compiled.wheel_lateral_forces(plain, q, u, scale * torques, np.empty((n, compiled.LINK_CHANNELS)),
                                      np.empty(n + 2), np.empty(2), lam_ref)
        np.testing.assert_allclose(du, du_ref, rtol=1e-10, atol=1e-10)
        np.testing.assert_array_equal(dq, dq_ref)
        assert power == pytest.approx(power_ref, rel=1e-10, abs=1e-10)
        assert motor == pytest.approx(motor_ref, rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(lam, lam_ref, rtol=1e-10, atol=1e-9)
        scales.append(scale)
    assert min(scales) < 1.0 and max(scales) == 1.0  # the draws exercise both cases


def test_scale_is_the_largest_that_keeps_the_wheels_within_their_grip(rng):
    """No wheel ends beyond max(mu m g, |lambda_0|), and below s = 1 one wheel is at that bound (so a
    larger s would push it out): torque that would make a wheel slip buys no acceleration."""
    n, mu = 6, 0.7
    model, plain = _models(n, mu, joint_limit=None)
    grip = mu * 1.0 * GRAVITY  # paper links: 1 kg
    links = np.empty((n, compiled.LINK_CHANNELS))
    scratch = (np.empty((n, compiled.LINK_CHANNELS)), np.empty(n + 2), np.empty(2))
    limited = 0
    for _ in range(200):
        q, u = _random_state(rng, n, speed=rng.choice([0.1, 2.0]))
        torques = rng.uniform(-3.0, 3.0, n - 1)
        lam, lam0 = np.empty(n), np.empty(n)
        _, scale, _ = compiled.traction_derivatives(model, q, u, torques, np.empty(n + 2), np.empty(2), links, lam)
        compiled.wheel_lateral_forces(plain, q, u, 0.0 * torques, *scratch, lam0)
        bound = np.maximum(grip, np.abs(lam0))
        assert 0.0 <= scale <= 1.0
        assert np.all(np.abs(lam) <= bound * (1 + 1e-9) + 1e-9)
        if scale < 1.0:
            limited += 1
            assert np.max(np.abs(lam) / bound) == pytest.approx(1.0, rel=1e-9)
    assert limited >= 50


def test_lane_kernel_steps_as_the_per_snake_kernel_with_grip(rng):
    """rk4_step_lanes (SIMD over snakes) = rk4_step_batch per snake, to rounding (sin/cos, <= 1 ulp)."""
    n, B = 5, 37
    model, _ = _models(n, 0.5, actuator="servo")
    q = np.empty((B, n + 2))
    u = np.empty((B, 2))
    for b in range(B):
        q[b], u[b] = _random_state(rng, n)
    torques = rng.uniform(-1.0, 1.0, (B, n - 1))
    q_ref, u_ref, w_ref = q.copy(), u.copy(), np.empty(B)
    compiled.rk4_step_batch(model, q_ref, u_ref, torques, 0.005, 4, w_ref)
    w = np.empty(B)
    compiled.rk4_step_lanes(model, q, u, torques, 0.005, 4, w)
    np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-11)
    np.testing.assert_allclose(u, u_ref, rtol=0, atol=1e-11)
    np.testing.assert_allclose(w, w_ref, rtol=0, atol=1e-11)


def test_work_energy_balance_holds_under_the_traction_limit(rng):
    """K(t1) - K(t0) = the work of every load, with the motors' work at the substeps' scales."""
    n = 5
    snake, params = PhysicsConfig(wheel_model="no_slip", n_links=n, wheel_friction=0.3, joint_limit=None, joint_damping=0.05).build()
    model = params.kernel_model
    q, u = _random_state(rng, n)
    torques = rng.uniform(-1.0, 1.0, n - 1)

    def kinetic(q, u):
        return snake.kinetic_energy(q, u)

    k0 = kinetic(q, u)
    work = 0.0
    for _ in range(200):
        work += compiled.rk4_step(model, q, u, torques, 0.001, 1)
    assert kinetic(q, u) - k0 == pytest.approx(work, rel=1e-6, abs=1e-9)


def test_ample_grip_gives_the_no_slip_trajectories():
    """As mu grows the traction limit stops acting: the env's trajectory converges to the no-slip model's."""
    actions = np.random.default_rng(3).uniform(-1, 1, (100, 4))
    final = {}
    for mu in (None, 1e6, 0.5):
        env = gym.make("snake_env/Snake5-v2", wheel_friction=mu)
        env.reset(seed=3)
        for a in actions:
            env.step(a)
        final[mu] = env.unwrapped.state[0].copy()
    np.testing.assert_allclose(final[1e6], final[None], rtol=0, atol=1e-9)
    assert np.max(np.abs(final[0.5] - final[None])) > 1e-2  # finite grip changes the motion


def test_slip_info_flags_only_the_motions_excess():
    """With the traction limit a wheel reported slipping (|lambda| > mu m g) is one the motion alone
    pushes past its grip: the torques add nothing there."""
    env = gym.make("snake_env/Snake5-v2", wheel_friction=0.3)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    scales = []
    for _ in range(200):
        _, _, _, _, info = env.step(rng.choice([-1.0, 1.0], 4))
        assert 0.0 <= info["traction_scale"] <= 1.0
        scales.append(info["traction_scale"])
    assert min(scales) < 0.5


def test_a_wheel_the_traction_limit_holds_at_its_grip_is_not_flagged():
    """The limit holds the wheels it saturates at mu m_k g up to rounding, a few ulps on either side;
    ``wheel_slip`` flags only a wheel above its grip by more than SLIP_TOLERANCE of it, which only the
    motion's own excess reaches."""
    env = gym.make("snake_env/Snake5-v3")
    env.reset(seed=0)
    grip = env.unwrapped.config.grip()
    rng = np.random.default_rng(0)
    rounded_above = excess = 0
    for _ in range(1000):
        info = env.step(rng.choice([-1.0, 1.0], 4))[4]
        above = np.abs(info["wheel_lateral_force"]) / grip - 1.0
        flagged = info["wheel_slip"]
        assert not flagged[above <= 1e-12].any()
        assert np.all(above[flagged] > SLIP_TOLERANCE)
        assert flagged[above > 1e-6].all()
        rounded_above += np.count_nonzero((above > 0.0) & (above <= 1e-12))
        excess += np.count_nonzero(above > 1e-6)
    assert rounded_above > 0  # held wheels that |lambda| > mu m g alone would flag
    assert excess > 0  # and the motion's own excess, which is flagged


def test_the_compiled_slip_test_is_the_numpy_rule_bit_for_bit(rng):
    """sliding_into (the env step's) gives sliding's verdict on every wheel, also one ulp either side of
    the threshold, zero, negative forces and infinite grip."""
    grip = rng.uniform(0.5, 20.0, (6, 7))
    grip[5] = math.inf
    threshold = grip * (1.0 + SLIP_TOLERANCE)
    force = np.stack([threshold, np.nextafter(threshold, 0.0), np.nextafter(threshold, np.inf), grip,
                      rng.normal(0.0, 10.0, grip.shape), np.zeros_like(grip)])
    force *= rng.choice([-1.0, 1.0], force.shape)
    out = np.ones(grip.shape, np.bool_)
    for rows in force:
        sliding_into(rows, grip, out)
        np.testing.assert_array_equal(out, sliding(rows, grip))
    assert sliding(force[2], grip)[:5].all() and not sliding(force[0], grip).any()


def test_a_randomized_vector_env_flags_slip_against_each_rows_own_grip():
    """Each row's wheel_slip is judged against the grip its own drawn mu gives (the batch keeps the drawn
    grips, not one robot's)."""
    vec = gym.make_vec("snake_env/Snake5-v3", num_envs=4, vectorization_mode="vector_entry_point",
                       randomize={"wheel_friction": [0.3, 1.2]})
    vec.reset(seed=3)
    batch = vec.unwrapped._batch
    rng = np.random.default_rng(1)
    flagged = 0
    for _ in range(300):
        info = vec.step(rng.choice([-1.0, 1.0], (4, 4)))[4]
        np.testing.assert_array_equal(info["wheel_slip"], sliding(info["wheel_lateral_force"], batch.physics.grip))
        flagged += info["wheel_slip"].sum()
    assert flagged > 0
    assert np.ptp(batch.physics.grip[:, 0]) > 0.0  # the rows' grips differ


def test_slip_cost_is_the_wheels_excess_over_their_grip_in_link_weights(rng):
    """slip_cost_weight: info reward_slip = -w * sum_k max(0, |lambda_k| - mu m_k g) / (m_k g), and the
    reward loses exactly that; it needs a finite grip."""
    from snake_env.envs import SnakeEnv

    kwargs = dict(n_links=5, wheel_friction=0.3, mass=[1.0, 0.5, 2.0, 1.0, 1.5])
    costed, plain = SnakeEnv(wheel_model="no_slip", slip_cost_weight=0.7, **kwargs), SnakeEnv(wheel_model="no_slip", **kwargs)
    costed.reset(seed=0)
    plain.reset(seed=0)
    load = np.array(kwargs["mass"]) * 9.81
    seen = 0.0
    for _ in range(60):
        a = np.sign(rng.uniform(-1, 1, 4))
        _, r1, _, _, info = costed.step(a)
        _, r0, _, _, _ = plain.step(a)
        excess = np.maximum(np.abs(info["wheel_lateral_force"]) - 0.3 * load, 0.0) / load
        assert info["reward_slip"] == pytest.approx(-0.7 * excess.sum(), abs=1e-15)
        assert r1 == pytest.approx(r0 + info["reward_slip"], abs=1e-12)
        seen += excess.sum()
    assert seen > 0.0  # bang-bang torques on a low-grip snake make the motion exceed the grip
    with pytest.raises(ValueError, match="slip_cost_weight needs wheel_friction"):
        SnakeEnv(wheel_model="no_slip", n_links=5, wheel_friction=None, slip_cost_weight=1.0)
