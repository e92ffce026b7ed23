"""Per-episode domain randomization (physics.randomization): reproducible by seed, within its bounds, each
row exactly the robot it reports, off by default, reported at autoresets, and one-line errors."""

import math

import numpy as np
import pytest

from snake_env.envs import SnakeEnv, SnakeVectorEnv
from snake_env.physics import PhysicsConfig
from snake_env.physics.randomization import RANGES
from tests.rows import assert_rows_step_like_singles

FULL = ("mass", "inertia", "stall_torque", "no_load_speed", "wheel_damping", "wheel_friction", "control_latency")


def drawn(info):
    return {key[len("randomized_"):]: value for key, value in info.items() if key.startswith("randomized_")}


@pytest.mark.parametrize("wheel_model", ["no_slip", "sliding"])
def test_draws_are_reproducible_by_seed_and_differ_between_seeds(rng, wheel_model):
    actions = rng.uniform(-1, 1, (30, 4))
    runs = []
    for seed in (7, 7, 8):
        env = SnakeEnv(wheel_model=wheel_model, n_links=5, randomize=True)
        obs, info = env.reset(seed=seed)
        trajectory = [obs] + [env.step(a)[0] for a in actions]
        runs.append((drawn(info), np.array(trajectory)))
    (first, path_a), (second, path_b), (other, _) = runs
    assert set(first) == set(FULL)
    for name in FULL:
        np.testing.assert_array_equal(first[name], second[name])
    np.testing.assert_array_equal(path_a, path_b)
    assert any(not np.array_equal(first[name], other[name]) for name in FULL)


def test_draws_stay_within_their_bounds():
    vec = SnakeVectorEnv(wheel_model="no_slip", num_envs=64, n_links=6, randomize=True)
    config = PhysicsConfig(wheel_model="no_slip", n_links=6)
    nominal = {"mass": 1.0, "inertia": 0.005, "stall_torque": config._motor.stall_torque,
               "no_load_speed": config._motor.no_load_speed, "wheel_damping": config.wheel_damping}
    seen = {name: [] for name in FULL}
    for seed in range(4):
        _, info = vec.reset(seed=seed)
        for name, value in drawn(info).items():
            seen[name].append(value)
    for name in FULL:
        values = np.concatenate([np.ravel(v) for v in seen[name]])
        kind, low, high = RANGES[name]
        if kind == "factor":
            values = values / nominal[name]
        assert values.min() >= low - 1e-12 and values.max() <= high + 1e-12, name
        assert values.max() - values.min() > 0.5 * (high - low), name  # the range is used, not one value
    latency = np.concatenate(seen["control_latency"]) / config.sim_dt
    np.testing.assert_allclose(latency, np.round(latency), atol=1e-9)  # whole substeps
    assert set(np.round(latency).astype(int)) == {0, 1, 2, 3, 4}
    masses = np.concatenate(seen["mass"])  # per link: the links of a snake differ
    assert np.all(masses.std(axis=1) > 0.0)


@pytest.mark.parametrize("wheel_model", ["no_slip", "sliding"])
def test_each_row_is_the_robot_it_reports(rng, wheel_model):
    """A randomized vector env's row steps bit for bit like a single env built with the drawn values (on sliding
    wheels, the same wheels slide)."""
    vec = SnakeVectorEnv(wheel_model=wheel_model, num_envs=3, n_links=5, randomize=True)
    _, info = vec.reset(seed=3)
    q, u = vec.state
    rows = []
    for b in range(3):
        values = {name: value[b] for name, value in drawn(info).items()}
        strength = values["stall_torque"]  # the servo preset's limit equals its stall torque
        env = SnakeEnv(wheel_model=wheel_model, n_links=5, mass=list(values["mass"]), inertia=list(values["inertia"]),
                       stall_torque=strength, torque_limit=strength, no_load_speed=values["no_load_speed"],
                       wheel_damping=float(values["wheel_damping"]), wheel_friction=float(values["wheel_friction"]),
                       control_latency=float(values["control_latency"]))
        env.reset(seed=0)
        env.set_state(q[b], u[b])
        rows.append(env)
    assert_rows_step_like_singles(vec, rows, rng, 20, ["wheel_lateral_force", "wheel_slip"])
    if wheel_model == "sliding":
        assert any(float(values) > 0.0 for values in info["randomized_control_latency"])  # a lagging row too


def test_off_by_default_and_named_ranges_draw_only_those():
    _, info = SnakeEnv(wheel_model="no_slip", n_links=4).reset(seed=0)
    assert not drawn(info)
    _, info = SnakeEnv(wheel_model="no_slip", n_links=4, randomize={"wheel_friction": [0.6, 0.7]}).reset(seed=0)
    assert set(drawn(info)) == {"wheel_friction"} and 0.6 <= info["randomized_wheel_friction"] <= 0.7
    ideal = SnakeEnv(wheel_model="no_slip", n_links=4, actuator="ideal", wheel_friction=None, randomize=True)
    assert set(drawn(ideal.reset(seed=0)[1])) == {"mass", "inertia", "wheel_damping", "control_latency"}


def test_rotor_inertia_is_drawn_only_with_rotors_and_leaves_the_other_draws_alone(rng):
    """With rotors randomize=True also draws rotor_inertia, within its bounds and after every other draw (so
    the other draws of a seed are those without rotors); a row is the single env with the drawn rotors."""
    plain = SnakeEnv(wheel_model="no_slip", n_links=5, randomize=True).reset(seed=4)[1]
    geared = SnakeEnv(wheel_model="no_slip", n_links=5, rotor_inertia=0.004, randomize=True).reset(seed=4)[1]
    assert set(drawn(geared)) == set(FULL) | {"rotor_inertia"} and set(drawn(plain)) == set(FULL)
    for name in FULL:
        np.testing.assert_array_equal(drawn(plain)[name], drawn(geared)[name])
    vec = SnakeVectorEnv(wheel_model="no_slip", num_envs=32, n_links=4, rotor_inertia=0.004, randomize={"rotor_inertia": [0.5, 1.5]})
    _, info = vec.reset(seed=1)
    factors = info["randomized_rotor_inertia"] / 0.004
    assert factors.min() >= 0.5 and factors.max() <= 1.5 and factors.max() - factors.min() > 0.5
    few = SnakeVectorEnv(wheel_model="no_slip", num_envs=2, n_links=4, rotor_inertia=0.004, randomize={"rotor_inertia": [0.5, 1.5]})
    _, info = few.reset(seed=1)
    q, u = few.state
    rows = []
    for b in range(2):
        env = SnakeEnv(wheel_model="no_slip", n_links=4, rotor_inertia=float(info["randomized_rotor_inertia"][b]))
        env.reset(seed=0)
        env.set_state(q[b], u[b])
        rows.append(env)
    assert_rows_step_like_singles(few, rows, rng, 10, ["wheel_lateral_force"])


def test_autoreset_reports_the_new_robots():
    vec = SnakeVectorEnv(wheel_model="no_slip", num_envs=2, n_links=4, max_episode_steps=2, randomize={"mass": [0.5, 1.5]})
    _, info = vec.reset(seed=0)
    before = info["randomized_mass"].copy()
    zeros = np.zeros((2, 3), np.float32)
    vec.step(zeros)
    _, _, _, truncated, info = vec.step(zeros)
    assert truncated.all() and "randomized_mass" not in info
    _, _, _, _, info = vec.step(zeros)  # the autoreset step
    assert info["_randomized_mass"].all() and not np.array_equal(info["randomized_mass"], before)


@pytest.mark.parametrize("kwargs, message", [
    (dict(randomize="yes"), "randomize must be None, True or a non-empty mapping"),
    (dict(randomize={"color": [0, 1]}), r"randomize has unknown name\(s\) \['color'\]"),
    (dict(randomize={"mass": [1.2, 0.8]}), r"randomize\['mass'\] must be a pair \[low, high\]"),
    (dict(randomize={"inertia": [0.0, 1.0]}), r"randomize\['inertia'\] must be a pair \[low, high\] with > 0"),
    (dict(randomize={"control_latency": [0.0, 0.05]}), r"randomize\['control_latency'\] must be a range"),
    (dict(randomize={"control_latency": [0.012, 0.018]}), "whole number of sim_dt"),
    (dict(actuator="ideal", randomize={"stall_torque": [0.9, 1.1]}), "actuator='ideal' has none"),
    (dict(wheel_friction=None, randomize={"wheel_friction": [0.5, 1.0]}), "wheel_friction=None"),
    (dict(randomize={"rotor_inertia": [0.5, 1.5]}), "rotor_inertia=0"),
    (dict(paper_model=True, randomize=True), "do not also pass randomize"),
    (dict(sim_dt=0.01, randomize={"inertia": [0.01, 1.0]}), "sim_dt must be in"),
])
def test_bad_randomize_is_a_one_line_error(kwargs, message):
    with pytest.raises(ValueError, match=message) as error:
        SnakeEnv(wheel_model="no_slip", n_links=5, **kwargs)
    assert "\n" not in str(error.value)


def test_stiff_draws_get_their_substeps_with_the_default_sim_dt():
    """Light links drawn under the default sim_dt are run with more substeps, not refused."""
    env = SnakeEnv(wheel_model="no_slip", n_links=5, randomize={"inertia": [0.01, 0.02]})
    env.reset(seed=0)
    robots = env.unwrapped._batch.physics
    assert robots.rows[0].params.substeps > 1 and math.isclose(env.unwrapped.dt, 0.04)
    for _ in range(20):
        assert not env.step(np.ones(4))[4]["sim_failure"]
