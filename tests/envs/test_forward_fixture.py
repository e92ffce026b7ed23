"""The forward-running task reproduces the trajectories recorded before the env
was split into a physics core and tasks (``fixtures/forward_v1.npz``), bit for bit; and v4's sliding wheels
those recorded before their substep calls were inlined (``fixtures/sliding_v4.npz``)."""

import numpy as np
import pytest

from tests.envs.fixtures.record_forward import (PATH, SINGLE_CASES, SLIDING_INFO_KEYS, SLIDING_PATH,
                                                SLIDING_SINGLE_CASES, SLIDING_VECTOR_CASES, VECTOR_CASES, run_single,
                                                run_vector)

RECORDED = np.load(PATH)
RECORDED_SLIDING = np.load(SLIDING_PATH)


def _compare(name, replayed, recorded=RECORDED):
    keys = sorted(k.split("/", 1)[1] for k in recorded.files if k.startswith(name + "/"))
    assert keys, f"no recorded arrays for {name}"
    assert sorted(replayed) == keys
    for key in keys:
        expected = recorded[f"{name}/{key}"]
        got = replayed[key]
        assert got.shape == expected.shape, f"{name}/{key}: shape {got.shape} != {expected.shape}"
        assert np.array_equal(got, expected), f"{name}/{key} differs from the recorded trajectory"


@pytest.mark.parametrize("case", SINGLE_CASES, ids=[c[0] for c in SINGLE_CASES])
def test_single_env_reproduces_recording(case):
    name, n, seed, kwargs = case
    _compare(name, run_single(n, seed, kwargs))


@pytest.mark.parametrize("case", VECTOR_CASES, ids=[c[0] for c in VECTOR_CASES])
def test_vector_env_reproduces_recording(case):
    name, n, num_envs, seed, mode, steps = case
    _compare(name, run_vector(n, num_envs, seed, mode, steps))


@pytest.mark.parametrize("case", SLIDING_SINGLE_CASES, ids=[c[0] for c in SLIDING_SINGLE_CASES])
def test_sliding_single_env_reproduces_recording(case):
    name, n, seed, kwargs = case
    _compare(name, run_single(n, seed, kwargs, "v4", SLIDING_INFO_KEYS), RECORDED_SLIDING)


@pytest.mark.parametrize("case", SLIDING_VECTOR_CASES, ids=[c[0] for c in SLIDING_VECTOR_CASES])
def test_sliding_vector_env_reproduces_recording(case):
    name, n, num_envs, seed, mode, steps = case
    _compare(name, run_vector(n, num_envs, seed, mode, steps, "v4", SLIDING_INFO_KEYS), RECORDED_SLIDING)
