"""The IQM and its stratified-bootstrap CI (snake_env.train.aggregate, on rliable)."""

import numpy as np
import pytest

from snake_env.train.aggregate import iqm


@pytest.fixture(autouse=True)
def fewer_resamples(monkeypatch):
    monkeypatch.setattr("snake_env.train.aggregate.BOOTSTRAP_REPS", 2000)  # 20000 takes seconds per call


def test_iqm_is_the_mean_of_the_middle_half():
    # 8 runs: the middle 50 % are 3, 4, 5, 6 whatever the outliers
    scores = np.array([-100.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 1000.0])
    result = iqm(scores)
    assert result.point == pytest.approx(4.5)
    assert result.low <= result.point <= result.high


def test_identical_runs_give_a_point_interval():
    result = iqm(np.full(5, 0.7))
    assert (result.point, result.low, result.high) == pytest.approx((0.7, 0.7, 0.7))


def test_stratified_over_tasks_and_reproducible():
    rng = np.random.default_rng(3)
    scores = np.stack([rng.normal(1.0, 0.1, 5), rng.normal(2.0, 0.1, 5)], axis=1)  # (runs, tasks)
    np.random.seed(7)
    before = np.random.random()
    np.random.seed(7)
    first, second = iqm(scores), iqm(scores)
    assert first == second
    assert np.random.random() == before  # numpy's global generator is left as it was
    assert first.low < first.point < first.high
    assert 1.0 < first.point < 2.0
    assert str(first).startswith(f"{first.point:.2f} [")


@pytest.mark.parametrize("bad", [np.array([]), np.array([1.0, np.nan]), np.zeros((2, 2, 2))])
def test_bad_scores_are_a_one_line_error(bad):
    with pytest.raises(ValueError, match="^scores: "):
        iqm(bad)
