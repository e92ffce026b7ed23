"""Operation counting: the counter, the twins, and the exact polynomial orders."""

from fractions import Fraction

import numpy as np
import pytest

from snake_env.benchmarks import opcount
from snake_env.benchmarks.opcount import Counted, counted_array, counting, fit_polynomial, values_of
from snake_env.benchmarks.paper_table1 import PAPER_TABLE, PAPER_TOTALS, paper_inconsistencies, poly
from snake_env.dynamics import SnakeModel


def test_counter_counts_and_folds_constants():
    x, y = Counted(2.0), Counted(3.0)
    with counting() as t:
        z = x * y + x / y - 1.5 * x
        folded = (x * 0, x * 1, x + 0, 0 - x, x / 1, 0.0 / y, -x)
        trig = np.cos(np.array([x], dtype=object))
    assert (t.mul, t.div, t.add, t.trig) == (2, 1, 2, 1)
    assert z.value == pytest.approx(2 * 3 + 2 / 3 - 3.0)
    assert folded[0] == 0 and folded[1] is x and folded[2] is x and folded[3].value == -2.0
    assert folded[4] is x and folded[5] == 0 and folded[6].value == -2.0
    assert trig[0].value == pytest.approx(np.cos(2.0))
    assert t.M == 3 and t.A == 2


def test_nested_tallies_both_count():
    x = Counted(1.5)
    with counting() as outer:
        x * x
        with counting() as inner:
            x + x
    assert (outer.mul, outer.add, inner.mul, inner.add) == (1, 1, 0, 1)


@pytest.mark.parametrize("method", list(opcount.IMPLEMENTATIONS))
@pytest.mark.parametrize("n", [2, 3, 9])
def test_counting_run_computes_the_real_udot(method, n):
    """The counted execution (for Kane paper: its einsum-free twin) returns the same udot
    as the production code, so the counts are of the real algorithm."""
    rng = np.random.default_rng(n)
    model = SnakeModel(n, mass=rng.uniform(0.5, 2, n), length=rng.uniform(0.1, 0.4, n),
                       inertia=rng.uniform(0.002, 0.02, n), joint_damping=rng.uniform(0, 0.5, n - 1),
                       wheel_damping=rng.uniform(0, 1, n))
    _, value = opcount.count_udot(method, n, model)
    q, u, torques = opcount.sample_state(n)
    expected = model.udot(q, u, torques, method="kane" if method == "kane" else method)[0]
    np.testing.assert_allclose(value, expected, rtol=1e-11, atol=1e-11)


def test_kane_paper_twin_matches_kane_paper_on_float_arrays():
    rng = np.random.default_rng(7)
    n = 7
    model = SnakeModel(n, mass=rng.uniform(0.5, 2, n))
    q, u, torques = opcount.sample_state(n)
    np.testing.assert_allclose(opcount.kane_paper_twin(model, q, u, torques),
                               model.udot(q, u, torques, method="kane_paper"), rtol=1e-13)


def test_fit_polynomial_is_exact():
    f = lambda n: Fraction(4, 3) * n ** 3 - Fraction(1, 2) * n + 7  # noqa: E731
    ns = list(range(3, 10))
    p = fit_polynomial(ns, [f(n) for n in ns])
    assert p == [7, Fraction(-1, 2), 0, Fraction(4, 3)]
    assert opcount.format_polynomial(p) == "4/3 n^3 - 1/2 n + 7"


@pytest.fixture(scope="module")
def counts():
    return opcount.count_all()


@pytest.mark.parametrize("method, degree", [("kane_paper", 2), ("lagrange", 3), ("newton_euler", 3), ("kane", 1)])
def test_counts_are_exact_polynomials_of_the_claimed_degree(counts, method, degree):
    """Fitted through n = 3..10, the polynomial predicts n = 12 and 20 exactly; its
    degree is the paper's claim (our O(n) sweep: 1), for M and for A."""
    res = counts[method]
    assert res.predicts_exactly()
    assert len(res.poly_M) - 1 == degree and len(res.poly_A) - 1 == degree
    assert res.poly_M[-1] > 0 and res.poly_A[-1] > 0
    for n in (12, 20):
        assert n in res.counts and n not in opcount.FIT_NS


def test_counts_order_the_methods_as_the_paper(counts):
    for n in (12, 20):
        total = {m: r.counts[n].M + r.counts[n].A for m, r in counts.items()}
        assert total["kane"] < total["kane_paper"] < total["newton_euler"] < total["lagrange"]


def test_paper_table_inconsistencies_are_detected():
    """The printed Kane total is not the sum of its steps; Kane's and NE's numeric
    columns are the header formulas swapped; Lagrange's match."""
    notes = paper_inconsistencies()
    kane = [s for s in notes if s.startswith("Kane (paper")]
    assert "but the printed total" in kane[0]
    assert "the A column holds the M formula" in kane[1]
    lag = [s for s in notes if s.startswith("Lagrange")]
    assert "matches the header formulas" in lag[1] and "holds the M formula" not in lag[1]
    ne = [s for s in notes if s.startswith("Newton-Euler")]
    assert "the A column holds the M formula" in ne[1]
    # and the check itself is arithmetic, not text: Lagrange n = 12 from the header
    pM, pA = (poly(p) for p in PAPER_TOTALS["lagrange"])
    assert (opcount.evaluate(pA, 12), opcount.evaluate(pM, 12)) == PAPER_TABLE["lagrange"][12]


def test_counted_array_round_trip():
    a = np.arange(6.0).reshape(2, 3)
    np.testing.assert_array_equal(values_of(counted_array(a)), a)
