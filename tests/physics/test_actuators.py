"""Joint motors: the DC-motor envelope in the compiled sweep against its numpy reference, the ideal
source unchanged bit for bit, a driven joint that does not outrun the no-load speed, and one-line
errors for bad motor arguments."""

import math

import gymnasium as gym
import numpy as np
import pytest

from snake_env.dynamics import SnakeModel, compiled
from snake_env.dynamics.motor import motor_torque_reference
from snake_env.envs import SnakeEnv
from snake_env.physics import AUX_RESIDUAL
from snake_env.physics.actuators import PRESETS


def test_envelope_is_the_torque_speed_band_then_the_current_limit():
    phidot = np.array([-10.0, -3.0, 0.0, 1.0, 3.0, 6.0])
    command = np.full(6, 5.0)
    tau = motor_torque_reference(command, phidot, stall_torque=2.0, no_load_speed=3.0, torque_limit=2.5)
    # driving: 2 (1 - phidot / 3), zero at the no-load speed, braking beyond it; then |tau| <= 2.5
    np.testing.assert_allclose(tau, [2.5, 2.5, 2.0, 2.0 * (1 - 1 / 3), 0.0, -2.0])
    # the mirror image: driving backwards is zero at -3 rad/s; beyond it the motor brakes (positive)
    low = motor_torque_reference(-command, phidot, 2.0, 3.0, 2.5)
    np.testing.assert_allclose(low, [2.5, 0.0, -2.0, -2.5, -2.5, -2.5])


def test_back_emf_braking_clips_to_the_limit_first_and_differs_only_past_the_overlap():
    """With back-EMF braking (v4) the torque is the command clipped to the current limit, then to the band: the
    same bits as the band-first clip wherever the two overlap (|phidot| <= omega_0 (1 + limit / stall)), and
    past that a brake of at least stall (|phidot| / omega_0 - 1), beyond the limit."""
    stall, omega_0, limit = 1.0, 3.14, 1.0
    phidot = np.linspace(-20.0, 20.0, 4001)
    for command in (-5.0, -1.0, 0.0, 0.3, 1.0, 5.0):
        braking = motor_torque_reference(np.full_like(phidot, command), phidot, stall, omega_0, limit, braking=True)
        capped = motor_torque_reference(np.full_like(phidot, command), phidot, stall, omega_0, limit)
        edge = omega_0 * (1.0 + limit / stall)  # 6.28 rad/s; the samples within rounding of it are left out
        overlap, past = np.abs(phidot) < edge - 1e-9, np.abs(phidot) > edge + 1e-9
        assert np.array_equal(braking[overlap], capped[overlap])
        np.testing.assert_allclose(braking[past], -stall * (phidot[past] / omega_0 - np.sign(phidot[past])),
                                   rtol=1e-12)
        assert np.all(np.abs(capped) <= limit) and np.all(np.abs(braking[past]) > limit)


@pytest.mark.parametrize("n", [3, 8])
@pytest.mark.parametrize("braking", [False, True])
def test_compiled_sweep_applies_the_motor_to_the_command(rng, n, braking):
    """derivatives() with a motor equals the ideal sweep fed the motor's torques (phidot from eq. 7), with and
    without back-EMF braking, at joint rates up to several omega_0 (past the overlap of band and limit); the
    sliding wheels' joint torques apply the same motor."""
    from snake_env.dynamics import sliding_step

    model = SnakeModel(n, joint_damping=0.05, wheel_damping=0.1)
    params = model.parameters()
    motor = compiled.kernel_model(*params, 0.0, 0.0, 0.0, 1.2, 1.0 / 2.5, 1.5, back_emf_braking=braking)
    ideal = compiled.kernel_model(*params)
    for _ in range(20):
        q = np.r_[rng.uniform(-1, 1, n), 0.0, 0.0]
        u = rng.normal(size=2) * 8
        command = rng.uniform(-3, 3, n - 1)
        _, omega = model.link_velocities(q, u)
        delivered = motor_torque_reference(command, np.diff(omega), 1.2, 2.5, 1.5, braking=braking)
        dq, du, dq_ref, du_ref = np.empty(n + 2), np.empty(2), np.empty(n + 2), np.empty(2)
        power = compiled.derivatives(motor, q, u, command, dq, du)
        power_ref = compiled.derivatives(ideal, q, u, delivered, dq_ref, du_ref)
        np.testing.assert_allclose(du, du_ref, rtol=1e-12, atol=1e-12)
        assert power == pytest.approx(power_ref, rel=1e-12, abs=1e-12)
        torque, motor_share = np.empty(n - 1), np.empty(n - 1)
        sliding_step.joint_torques(command, np.zeros(n - 1), np.diff(omega), np.zeros(n - 1), 1.2, 1.0 / 2.5, 1.5,
                                   1.0 if braking else 0.0, 0.0, 0.0, 0.0, 0.0, torque, motor_share)
        np.testing.assert_allclose(motor_share, delivered, rtol=1e-12, atol=1e-12)


def test_ideal_actuator_is_the_v2_torque_source_bit_for_bit():
    rng = np.random.default_rng(4)
    default = gym.make("snake_env/Snake5-v2").unwrapped  # ideal torque sources by registration
    ideal = SnakeEnv(n_links=5, actuator="ideal", wheel_friction=None)
    assert ideal.params.torque_limit == math.inf and ideal.params.substeps == 1
    for env in (default, ideal):
        env.reset(seed=4)
    for action in rng.uniform(-1, 1, (50, 4)):
        a, b = default.step(action), ideal.step(action)
        assert np.array_equal(a[0], b[0]) and a[1] == b[1]


def test_a_driven_joint_does_not_outrun_the_no_load_speed():
    """Two links, the joint driven by the full command from rest: its rate rises towards the servo's
    no-load speed (3.14 rad/s) and does not pass it before the joint limit; the ideal source passes it."""
    omega_0 = PRESETS["servo"].no_load_speed
    peaks = {}
    for actuator in ("servo", "ideal"):
        env = SnakeEnv(n_links=2, actuator=actuator, joint_damping=0.0, reset_noise_scale=0.0)
        env.reset(seed=0)
        peak = 0.0
        for _ in range(40):
            env.step(np.ones(1))
            phi, phidot, _ = env.joint_state()
            if abs(phi[0]) >= env.joint_limit:
                break
            peak = max(peak, abs(phidot[0]))
            assert env._batch.aux[0, AUX_RESIDUAL] <= env.energy_tolerance  # work-energy balance with the motor
        peaks[actuator] = peak
    assert 0.8 * omega_0 < peaks["servo"] <= omega_0 * (1 + 1e-6)
    assert peaks["ideal"] > 1.5 * omega_0


@pytest.mark.parametrize("kwargs, match", [
    (dict(actuator="servo", stall_torque=-1.0), "stall_torque must be a finite number > 0"),
    (dict(actuator="stepper"), "actuator must be one of"),
    (dict(actuator="ideal", stall_torque=2.0), "stall_torque needs a motor"),
    (dict(actuator="dc_motor", stall_torque=2.0), "actuator='dc_motor' needs no_load_speed"),
    (dict(actuator="servo", no_load_speed=0.0), "no_load_speed must be a finite number > 0"),
    (dict(actuator="xh430_w350", paper_model=True), "paper_model=True fixes .* actuator='ideal'"),
    (dict(wheel_friction=0.5, paper_model=True), "paper_model=True fixes .* wheel_friction=None"),
])
def test_bad_motor_arguments_are_one_line_errors(kwargs, match):
    with pytest.raises(ValueError, match=match) as info:
        SnakeEnv(**kwargs)
    assert "\n" not in str(info.value)


def test_a_preset_field_can_be_overridden_and_a_stiff_motor_runs_in_substeps():
    env = SnakeEnv(actuator="servo", no_load_speed=6.0)
    assert env.params.stall_torque == 1.0 and env.params.inverse_no_load_speed == pytest.approx(1 / 6.0)
    stiff = SnakeEnv(actuator="xh430_w350")  # back-EMF slope 1.08 N m s/rad: RK4 needs ~6 ms steps
    assert stiff.params.substeps >= 2 and stiff.dt == 0.04
