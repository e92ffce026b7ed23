"""Bad input is rejected with a ValueError that names the argument."""

import pickle

import numpy as np
import pytest

from snake_env.dynamics import SnakeModel, simulate


@pytest.mark.parametrize("n_links", [1, 0, -3, 2.0, 2.5, "5", None, True])
def test_n_links_must_be_integer_at_least_two(n_links):
    with pytest.raises(ValueError, match="n_links"):
        SnakeModel(n_links)


@pytest.mark.parametrize("name", ["mass", "length", "inertia"])
@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf, [1.0, 1.0, 1.0], "heavy"])
def test_physical_parameters_must_be_positive_finite_and_right_length(name, bad):
    with pytest.raises(ValueError, match=name):
        SnakeModel(4, **{name: bad})


@pytest.mark.parametrize("name,size", [("joint_damping", 3), ("wheel_damping", 4)])
def test_damping_may_be_zero_but_not_negative(name, size):
    SnakeModel(4, **{name: 0.0})
    SnakeModel(4, **{name: np.linspace(0.0, 1.0, size)})
    for bad in (-0.1, np.nan, np.zeros(size + 1)):
        with pytest.raises(ValueError, match=name):
            SnakeModel(4, **{name: bad})


def test_per_link_sequences_are_used():
    model = SnakeModel(3, mass=[1.0, 2.0, 3.0], length=(0.1, 0.2, 0.3))
    np.testing.assert_array_equal(model.mass, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(model.half_length, [0.05, 0.1, 0.15])
    np.testing.assert_array_equal(model.inertia, [0.005] * 3)


@pytest.fixture
def model():
    return SnakeModel(4)


@pytest.mark.parametrize("argument,value", [
    ("q", np.zeros(5)), ("q", np.zeros((3, 7))), ("u", np.zeros(3)), ("torques", np.zeros(4)), ("q", 0.0),
])
def test_wrong_trailing_shape_names_the_argument(model, argument, value):
    args = {"q": np.zeros(6), "u": np.zeros(2), "torques": np.zeros(3)}
    args[argument] = value
    with pytest.raises(ValueError, match=rf"{argument} must have shape \(\.\.\., \d\)"):
        model.udot(**args)


@pytest.mark.parametrize("argument", ["q", "u", "torques"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_state_is_rejected(model, argument, bad):
    args = {"q": np.zeros(6), "u": np.zeros(2), "torques": np.zeros(3)}
    args[argument] = args[argument].copy()
    args[argument][0] = bad
    with pytest.raises(ValueError, match=f"{argument} must be finite"):
        model.udot(**args)


def test_incompatible_batch_shapes_are_rejected(model):
    with pytest.raises(ValueError, match=r"broadcastable leading \(batch\) dimensions, got q \(3, 6\), u \(4, 2\)"):
        model.udot(np.zeros((3, 6)), np.zeros((4, 2)), np.zeros(3))


def test_unknown_method_lists_the_valid_ones(model):
    with pytest.raises(ValueError, match="method must be one of .*kane.*kane_paper"):
        model.udot(np.zeros(6), np.zeros(2), np.zeros(3), method="hamilton")


def test_non_numeric_state_is_rejected(model):
    with pytest.raises(ValueError, match="q must be a real numeric array"):
        model.udot(np.array(["a"] * 6), np.zeros(2), np.zeros(3))


@pytest.mark.parametrize("kwargs,match", [
    (dict(t_end=0.0), "t_end"), (dict(t_end=-1.0), "t_end"), (dict(dt=0.0), "dt"), (dict(dt=np.nan), "dt"),
    (dict(torque_fn=3.0), "torque_fn"), (dict(dtype=np.int32), "dtype"), (dict(method="euler"), "method"),
    (dict(q0=np.zeros(5)), "q0"), (dict(t_end=1e-4, dt=1e-3), "t_end"),
])
def test_simulate_rejects_bad_arguments(model, kwargs, match):
    args = dict(q0=np.zeros(6), u0=np.zeros(2), torque_fn=lambda t, q, u: np.zeros(3), t_end=0.01, dt=1e-3)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        simulate(model, **args)


def test_simulate_rejects_torque_function_of_wrong_shape(model):
    with pytest.raises(ValueError, match=r"torque_fn\(t, q, u\) must have shape"):
        simulate(model, np.zeros(6), np.zeros(2), lambda t, q, u: np.zeros(2), t_end=0.01, dt=1e-3)


def test_model_pickles_and_keeps_behaviour(model):
    rng = np.random.default_rng(0)
    q, u, T = rng.normal(size=6), rng.normal(size=2), rng.normal(size=3)
    model.udot(q, u, T)  # fills the dtype cache
    clone = pickle.loads(pickle.dumps(model))
    np.testing.assert_array_equal(clone.udot(q, u, T), model.udot(q, u, T))
