"""wheel_model="sliding" (snake_env.physics.sliding_wheels): the env on wheels that slide under Coulomb
friction. It is a Gymnasium env like any other, follows the no-slip env where the wheels grip hard and
the regularised reference model where they slide, keeps its wheels' forces within their grip, balances
its energy with friction's work, steps a batch as its rows alone, and refuses what it does not model."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import snake_env  # noqa: F401
from snake_env.dynamics import sliding_step
from snake_env.physics.config import PhysicsConfig
from snake_env.physics.sliding_reference import SlidingSnake
from tests.newest_ids import newest_id

ENV = newest_id("Snake5")


def actions(n, steps, seed=0):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, n - 1)).astype(np.float32)


def test_passes_gymnasiums_checker():
    env = gym.make(ENV, wheel_model="sliding")
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_follows_the_no_slip_env_when_the_wheels_grip_hard():
    """At mu = 1000 no wheel slides and the two physics differ by their integrators only (RK4 at 10 ms
    against first-order time stepping at 1 ms)."""
    envs = [gym.make(ENV, wheel_friction=1000.0, wheel_model=model) for model in ("no_slip", "sliding")]
    obs = [env.reset(seed=0)[0] for env in envs]
    np.testing.assert_array_equal(obs[0], obs[1])
    for action in actions(5, 25):
        out = [env.step(action) for env in envs]
        assert not np.any(out[1][4]["wheel_slip"])
    (obs_a, _, _, _, info_a), (obs_b, _, _, _, info_b) = out
    assert np.max(np.abs(obs_a - obs_b)) < 0.05  # rad, rad/s, m/s after 1 s
    assert abs(info_a["x_position"] - info_b["x_position"]) < 2e-3  # m


def test_follows_the_regularised_reference_where_wheels_slide():
    """At mu = 0.8 the wheels slide; the LSODA reference (v_eps = 0.1 mm/s) follows the env."""
    env = gym.make(ENV, wheel_model="sliding")
    obs, _ = env.reset(seed=1)
    base = env.unwrapped
    reference = SlidingSnake(base.config, slip_speed=1e-4)
    reference.reset(*base.state)
    slid = []
    for action in actions(5, 8, seed=1):
        obs, _, _, _, info = env.step(action)
        mine, _ = reference.step(action)
        slid.append(info["wheel_slip"])
    assert np.mean(slid) > 0.1
    assert np.max(np.abs(mine - obs)) < 0.05
    env.close()


def test_forces_within_grip_sliding_wheels_at_it():
    env = gym.make(newest_id("Snake8"), wheel_model="sliding")
    env.reset(seed=0)
    grip = env.unwrapped.config.grip()
    slid = 0
    for action in actions(8, 50):
        _, _, _, _, info = env.step(action)
        force, slip = info["wheel_lateral_force"], info["wheel_slip"]
        assert np.all(np.abs(force) <= grip * (1 + 1e-9))
        np.testing.assert_allclose(np.abs(force[slip]), grip[slip], rtol=1e-9)
        assert info["traction_scale"] == 1.0
        slid += int(np.sum(slip))
    assert slid > 0
    env.close()


def test_energy_balance_in_info():
    """kinetic energy's change = power * dt (the work of every load, friction's included), within the check's
    tolerance."""
    env = gym.make(ENV, wheel_model="sliding")
    _, info = env.reset(seed=2)
    k0 = info["kinetic_energy"]
    for action in actions(5, 40, seed=2):
        _, _, _, _, info = env.step(action)
        assert not info["sim_failure"]
        k1 = info["kinetic_energy"]
        # the env's own tolerance (energy_tolerance 1e-2 of max(K0, K1) plus a floor of 1e-3 J); the residual
        # is friction's and the bias's first-order share (tests/dynamics/test_sliding_step.py: O(h))
        assert abs(k1 - k0 - info["power"] * env.unwrapped.dt) < 1e-2 * (max(k0, k1) + 1e-3)
        assert info["actuator_power"] >= 0.0
        k0 = info["kinetic_energy"]
    env.close()


def test_vector_env_rows_equal_single_envs():
    n_envs = 3
    vec = gym.make_vec(ENV, num_envs=n_envs, vectorization_mode="vector_entry_point", wheel_model="sliding")
    singles = [gym.make(ENV, wheel_model="sliding") for _ in range(n_envs)]
    obs, _ = vec.reset(seed=10)
    q, u = vec.unwrapped.state
    for b, env in enumerate(singles):
        env.reset(seed=0)
        env.unwrapped.set_state(q[b], u[b])
    acts = np.stack([actions(5, 20, seed=b) for b in range(n_envs)], axis=1)
    for step_actions in acts:
        obs, rewards, _, _, info = vec.step(step_actions)
        for b, env in enumerate(singles):
            o, r, _, _, i = env.step(step_actions[b])
            np.testing.assert_array_equal(o, obs[b])
            assert r == rewards[b]
            np.testing.assert_array_equal(i["wheel_slip"], info["wheel_slip"][b])
    vec.close()


def test_rows_whose_fast_solve_fails_are_stepped_by_the_delassus_solve(monkeypatch):
    """Where the O(n) friction solve does not settle (forced here on row 1), the step is taken again from the
    row's pre-step state by the Delassus solve: that row then equals a run on the Delassus solve alone, bit for
    bit, and the other rows are untouched."""
    fast, dense = sliding_step.ADVANCE_ROWS[0], sliding_step.ADVANCE_ROWS[2]

    def failing_row_1(*args):
        ok = fast(*args)
        q, qdot, rows = args[0], args[1], args[23]
        if 1 in rows:
            q[1], qdot[1], ok[1] = np.nan, np.nan, False
        return ok

    runs = {}
    for name, kernel in (("fast", fast), ("row 1 fails", failing_row_1), ("dense", dense)):
        monkeypatch.setattr(sliding_step, "ADVANCE_ROWS", (kernel,) + sliding_step.ADVANCE_ROWS[1:])
        vec = gym.make_vec(ENV, num_envs=3, vectorization_mode="vector_entry_point", wheel_model="sliding")
        vec.reset(seed=4)
        out = [vec.step(a) for a in np.stack([actions(5, 10, seed=b) for b in range(3)], axis=1)]
        runs[name] = (np.stack([o[0] for o in out]), np.stack([o[4]["wheel_slip"] for o in out]))
        vec.close()
    assert np.all(np.isfinite(runs["row 1 fails"][0]))
    for part in range(2):
        np.testing.assert_array_equal(runs["row 1 fails"][part][:, 1], runs["dense"][part][:, 1])
        np.testing.assert_array_equal(runs["row 1 fails"][part][:, [0, 2]], runs["fast"][part][:, [0, 2]])
    assert np.any(runs["fast"][0][:, 1] != runs["dense"][0][:, 1])  # the two solves differ by rounding


def test_set_state_restarts_with_gripping_wheels():
    env = gym.make(ENV, wheel_model="sliding")
    env.reset(seed=0)
    for action in actions(5, 10):
        env.step(action)
    base = env.unwrapped
    q, u = base.state
    twin = gym.make(ENV, wheel_model="sliding")
    twin.reset(seed=5)
    twin.unwrapped.set_state(q, u)
    base.set_state(q, u)  # both restart from (q, u) with every wheel gripping
    for action in actions(5, 5, seed=3):
        a, b = env.step(action), twin.step(action)
        np.testing.assert_array_equal(a[0], b[0])


@pytest.mark.parametrize("kwargs, message", [
    (dict(wheel_model="slide"), "wheel_model must be one of"),
    (dict(wheel_model="sliding", wheel_friction=None), "wheel_model='sliding' needs wheel_friction"),
    (dict(wheel_model="sliding", control_latency=0.05), "a latency longer than a step"),
])
def test_bad_settings_are_one_line_errors(kwargs, message):
    with pytest.raises(ValueError, match=message) as error:
        PhysicsConfig(**kwargs)
    assert "\n" not in str(error.value)


def test_rows_that_fail_the_check_are_refined_alone():
    """A tight work-energy tolerance makes some rows' steps fail the check and be stepped again with halved
    substeps: each row of a batch then equals the same row stepped alone, bit for bit (state, wheels' own state,
    observation, aux with its refinement count and forces), each refined row's substep is halved per refinement,
    and the batch holds both refined and unrefined rows."""
    from snake_env.physics import AUX_REFINEMENTS
    from snake_env.physics.sliding_wheels import SlidingWheelPhysics

    config = PhysicsConfig(n_links=5, wheel_model="sliding", energy_tolerance=2e-4)
    _, params = config.build()
    B, n = 4, 5
    noise = np.random.default_rng(3).uniform(-0.3, 0.3, (B, n + 2))
    batch = SlidingWheelPhysics(config, params, B)
    alone = [SlidingWheelPhysics(config, params, 1) for _ in range(B)]
    q, u, obs, aux = batch.reset(np.arange(B), noise, None)
    rows = [list(one.reset(np.arange(1), noise[b:b + 1], None)) for b, one in enumerate(alone)]
    torques = 2.0 * np.random.default_rng(4).uniform(-1.0, 1.0, (30, B, n - 1))
    forces, scale = np.empty((B, n)), np.empty((B, n))
    refined = []
    for step_torques in torques:
        batch.step(q, u, step_torques, obs, aux, forces, scale)
        refined.append(aux[:, AUX_REFINEMENTS].copy())
        # each refinement halves the row's substep: dt in 40 * 2^r substeps of the last_h it reports
        np.testing.assert_array_equal(batch.last_h, params.dt / (batch.substeps * 2 ** refined[-1].astype(np.int64)))
        for b, one in enumerate(alone):
            f, s = np.empty((1, n)), np.empty((1, n))
            one.step(rows[b][0], rows[b][1], step_torques[b:b + 1], rows[b][2], rows[b][3], f, s)
            for mine, theirs in zip((q, u, obs, aux, forces, batch.qdot, batch.impulse, batch.slip, batch.last_h),
                                    (rows[b][0], rows[b][1], rows[b][2], rows[b][3], f, one.qdot, one.impulse,
                                     one.slip, one.last_h)):
                np.testing.assert_array_equal(mine[b], theirs[0])
    refined = np.array(refined)
    assert np.any(refined > 0) and np.any(refined == 0), refined.max()
