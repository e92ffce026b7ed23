"""Operation counts of the four formulations (paper Table I), by execution.

Each formulation's udot is run once on numpy object arrays whose entries are
:class:`Counted` scalars: every arithmetic operation on a state-dependent
value is tallied as it is executed, so the count is that of the real code,
not of a hand derivation. Conventions:

* M (multiplications) counts products and divisions (the paper counts the
  division by h_{i+1} of eq. 7 as one multiplication: 4n - 4 for omega);
  divisions are also reported on their own.
* A (additions) counts additions and subtractions; sign changes are free.
* sin and cos are counted apart (the paper counts neither).
* Constant folding: an operation whose result is known without the state is
  not counted: x + 0, x * 0, x * 1, x * -1, x / 1, 0 / x, where 0 and 1 are
  model constants or structural zeros. A scalar code generated from the same
  algorithm would not execute them; this is how the zero structure of
  eq. 21 and of the lever arms is credited to every formulation alike.
  Operations among model constants alone (plain floats) are precomputation
  and are not counted either.

The numpy Kane-paper code contracts with einsum, which on object arrays adds
every product to an initial 0; :func:`kane_paper_twin` repeats its ``udot``
line by line with explicit sums instead (same partials functions), and the
tests check that it returns the same udot.
"""

from __future__ import annotations

import math
import numbers
from contextlib import contextmanager
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from snake_env.dynamics import SnakeModel, kane, kane_paper, lagrange, newton_euler
from snake_env.dynamics.forces import effective_joint_torques, wheel_forces
from snake_env.dynamics.kinematics import joint_angles, link_speeds


# ---------------------------------------------------------------- counting scalar
@dataclass
class Tally:
    mul: int = 0
    div: int = 0
    add: int = 0
    trig: int = 0

    @property
    def M(self) -> int:
        """Multiplications, divisions included (the paper's M)."""
        return self.mul + self.div

    @property
    def A(self) -> int:
        """Additions and subtractions (the paper's A)."""
        return self.add

    def __sub__(self, other: "Tally") -> "Tally":
        return Tally(self.mul - other.mul, self.div - other.div, self.add - other.add, self.trig - other.trig)


_TALLIES: list[Tally] = []


@contextmanager
def counting():
    """Tally every operation on :class:`Counted` values inside the block."""
    tally = Tally()
    _TALLIES.append(tally)
    try:
        yield tally
    finally:
        _TALLIES.remove(tally)


def _count(kind: str) -> None:
    for tally in _TALLIES:
        setattr(tally, kind, getattr(tally, kind) + 1)


def _is_const(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, Counted)


class Counted:
    """A float that counts the arithmetic done with it (see module doc)."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = float(value)

    def __repr__(self):
        return f"Counted({self.value!r})"

    # -- additions
    def __add__(self, other):
        if _is_const(other):
            if other == 0:
                return self
            _count("add")
            return Counted(self.value + float(other))
        if not isinstance(other, Counted):
            return NotImplemented
        _count("add")
        return Counted(self.value + other.value)

    __radd__ = __add__

    def __sub__(self, other):
        if _is_const(other):
            if other == 0:
                return self
            _count("add")
            return Counted(self.value - float(other))
        if not isinstance(other, Counted):
            return NotImplemented
        _count("add")
        return Counted(self.value - other.value)

    def __rsub__(self, other):
        if _is_const(other):
            if other == 0:
                return -self
            _count("add")
            return Counted(float(other) - self.value)
        return NotImplemented

    def __neg__(self):
        return Counted(-self.value)

    def __pos__(self):
        return self

    # -- multiplications
    def __mul__(self, other):
        if _is_const(other):
            if other == 0:
                return 0.0
            if other == 1:
                return self
            if other == -1:
                return -self
            _count("mul")
            return Counted(self.value * float(other))
        if not isinstance(other, Counted):
            return NotImplemented
        _count("mul")
        return Counted(self.value * other.value)

    __rmul__ = __mul__

    def __truediv__(self, other):
        if _is_const(other):
            if other == 1:
                return self
            if other == -1:
                return -self
            _count("div")
            return Counted(self.value / float(other))
        if not isinstance(other, Counted):
            return NotImplemented
        _count("div")
        return Counted(self.value / other.value)

    def __rtruediv__(self, other):
        if _is_const(other):
            if other == 0:
                return 0.0
            _count("div")
            return Counted(float(other) / self.value)
        return NotImplemented

    # -- what numpy calls for np.cos / np.sin on object arrays
    def cos(self):
        _count("trig")
        return Counted(math.cos(self.value))

    def sin(self):
        _count("trig")
        return Counted(math.sin(self.value))


def counted_array(values) -> np.ndarray:
    """An object array of :class:`Counted` with the shape of ``values``."""
    values = np.asarray(values, dtype=np.float64)
    out = np.empty(values.shape, dtype=object)
    for index, v in np.ndenumerate(values):
        out[index] = Counted(v)
    return out


def values_of(array) -> np.ndarray:
    """Float array of the values of a (possibly partly constant) object array."""
    array = np.asarray(array, dtype=object)
    out = np.empty(array.shape)
    for index, v in np.ndenumerate(array):
        out[index] = v.value if isinstance(v, Counted) else float(v)
    return out


# ---------------------------------------------------------------- the Kane-paper twin
def _contract(a, b):
    """sum_k a[..., k, i] b[..., k, j] -> (..., i, j), written out (einsum's twin)."""
    return np.sum(a[..., :, :, None] * b[..., :, None, :], axis=-3)


def kane_paper_twin(model, q, u, torques):
    """:func:`snake_env.dynamics.kane_paper.udot` line by line, einsum written as sums."""
    m, h, inertia, c_joint, c_wheel = model.parameters(u.dtype)
    n = model.n_links
    phi = joint_angles(q[..., :n])
    C, S = np.cos(phi), np.sin(phi)
    batch = np.broadcast_shapes(phi.shape[:-1], u.shape[:-1])
    V, W = link_speeds(h, C, S, u)
    dVdu, dWdu = kane_paper.partials_wrt_u(h, C, S, u.dtype, batch)
    dVdq, dWdq = kane_paper.partials_wrt_q(h, C, S, V, W, u.dtype, batch)

    mdVdu = m[:, None] * dVdu
    IdWdu = inertia[:, None] * dWdu
    M = _contract(mdVdu, dVdu) + _contract(IdWdu, dWdu)  # eq. 9
    N = _contract(mdVdu, dVdq) + _contract(IdWdu, dWdq)  # eq. 10
    T = effective_joint_torques(c_joint, torques, W)
    f = wheel_forces(c_wheel, V)
    F = np.sum(T[..., :, None] * (dWdu[..., 1:, :] - dWdu[..., :-1, :]), axis=-2)  # eq. 11
    F = F + np.sum(f[..., :, None] * dVdu, axis=-2)
    rhs = F - np.sum(N * W[..., None, :], axis=-1)
    return kane.solve_2x2(M[..., 0, 0], M[..., 0, 1], M[..., 1, 1], rhs[..., 0], rhs[..., 1])


# The implementations whose operations are counted: name -> udot(model, q, u, torques).
IMPLEMENTATIONS = {
    "kane_paper": kane_paper_twin,  # the paper's O(n^2) recursion (eqs. 8-21)
    "kane": kane.udot_sweep,  # the O(n) sweep
    "lagrange": lagrange.udot,  # eqs. 22-27
    "newton_euler": newton_euler.udot,  # Walker-Orin + eq. 27
}
LABELS = {"kane_paper": "Kane (paper, eqs. 8-21)", "kane": "Kane O(n) sweep",
          "lagrange": "Lagrange (eq. 27)", "newton_euler": "Newton-Euler (Walker-Orin)"}
CLAIMED_DEGREE = {"kane_paper": 2, "kane": 1, "lagrange": 3, "newton_euler": 3}


def sample_state(n: int, seed: int = 0):
    """A generic state (no accidental zeros or ones): q, u, torques, batch of 1."""
    rng = np.random.default_rng(seed + n)
    q = np.concatenate([rng.uniform(-1.0, 1.0, n), rng.normal(size=2)])[None]
    return q, rng.normal(size=(1, 2)), rng.normal(size=(1, n - 1))


def paper_model(n: int) -> SnakeModel:
    """Table II parameters (L = 0.2 m, m = 1 kg, I = 0.005 kg m^2), no damping."""
    return SnakeModel(n, mass=1.0, length=0.2, inertia=0.005)


def count_udot(method: str, n: int, model: SnakeModel | None = None):
    """(Tally, udot values (2,)) of one udot evaluation of ``method`` for n links."""
    model = paper_model(n) if model is None else model
    q, u, torques = sample_state(n)
    with counting() as tally:
        result = IMPLEMENTATIONS[method](model, counted_array(q), counted_array(u), counted_array(torques))
    return tally, values_of(result)[0]


# ---------------------------------------------------------------- stage breakdowns
def _count_call(fn, *args):
    with counting() as tally:
        fn(*args)
    return tally


def stage_counts(method: str, n: int) -> dict[str, Tally]:
    """Counts of the stages the paper lists for ``method`` (Kane paper, Lagrange, NE).

    Each stage is run on its own from the state, so shared quantities (sines,
    cosines, velocities) are counted in the stage that first needs them.
    """
    model = paper_model(n)
    q, u, torques = (counted_array(a) for a in sample_state(n))
    m, h, inertia, _, _ = model.parameters(object)
    stages: dict[str, Tally] = {}
    if method == "kane_paper":
        phi = joint_angles(q[..., :n])
        with counting():  # trig only; not a stage
            C, S = np.cos(phi), np.sin(phi)
        with counting() as t_vw:
            V, W = link_speeds(h, C, S, u)
        stages["V, omega (eqs. 6-7)"] = t_vw
        stages["dV/du, domega/du (eqs. 12-14)"] = _count_call(kane_paper.partials_wrt_u, h, C, S, object, (1,))
        stages["dV/dq, domega/dq (eqs. 15-21)"] = _count_call(kane_paper.partials_wrt_q, h, C, S, V, W, object, (1,))
        total, _ = count_udot(method, n)
        with counting() as t_solve:
            kane.solve_2x2(*(counted_array(np.full(1, v)) for v in (2.0, 0.3, 1.5, 0.7, 0.2)))
        stages["solve eq. 8 (2 x 2)"] = t_solve
        rest = total
        for t in stages.values():
            rest = rest - t
        stages["M, N, F (eqs. 9-11)"] = rest
        return stages
    module = lagrange if method == "lagrange" else newton_euler
    total, _ = count_udot(method, n)
    with counting() as t_rest:
        qd = lagrange.consistent_qdot(model, q, u)
    with counting() as t_trig:
        e, e_perp = lagrange.unit_vectors(q[..., :n])
    c = lagrange.lever_arms(h)
    if module is lagrange:
        with counting() as stages["link Jacobians (shared by M and B)"]:
            J = lagrange.link_jacobians(c, e_perp)
    with counting() as stages["inertia matrix"]:
        if module is lagrange:
            M = lagrange._inertia_from_jacobians(m, inertia, J, (1,), object)
        else:
            M = newton_euler._composite_inertia(m, inertia, c, e_perp, (1,), object)
    with counting() as stages["bias vector"]:
        if module is lagrange:
            B = lagrange._bias_from_geometry(m, c, e, J, qd, n)
        else:
            B = newton_euler._recursive_bias(m, h, c, e, e_perp, qd)
    with counting() as stages["constraint matrix A"]:
        A = lagrange.constraint_matrix(c, e_perp)
    with counting() as stages["Adot"]:
        Adot = lagrange.constraint_matrix_rate(c, e, e_perp, qd, n)
    with counting() as t_rhs:
        Q = lagrange.generalized_forces(model, q, qd, torques, e, None)
        rhs_c = -lagrange.matvec(Adot, qd)
        system, rhs = lagrange.augmented_system(M, A, Q - B, rhs_c)
    with counting() as stages["LU solve of eq. 27"]:
        lagrange.lu_solve(system, rhs)
    rest = total
    for t in stages.values():
        rest = rest - t
    stages["other (qdot from u, Q, right side, udot from qddot)"] = rest
    return stages


# ---------------------------------------------------------------- exact polynomial fits
def fit_polynomial(ns, values) -> list[Fraction]:
    """Exact interpolating polynomial coefficients (lowest first), trimmed.

    Newton divided differences in rational arithmetic through all points;
    the result has the lowest degree that reproduces every point exactly.
    """
    xs = [Fraction(x) for x in ns]
    table = [Fraction(v) for v in values]
    coeffs_newton = [table[0]]
    for level in range(1, len(xs)):
        table = [(table[i + 1] - table[i]) / (xs[i + level] - xs[i]) for i in range(len(table) - 1)]
        coeffs_newton.append(table[0])
    # expand Newton form into monomials
    poly = [Fraction(0)]
    for k in range(len(coeffs_newton) - 1, -1, -1):
        # poly = poly * (x - xs[k]) + coeffs_newton[k]
        shifted = [Fraction(0)] + poly
        for i in range(len(poly)):
            shifted[i] -= xs[k] * poly[i]
        shifted[0] += coeffs_newton[k]
        poly = shifted
    while len(poly) > 1 and poly[-1] == 0:
        poly.pop()
    return poly


def evaluate(poly, n) -> Fraction:
    return sum((c * Fraction(n) ** i for i, c in enumerate(poly)), Fraction(0))


def format_polynomial(poly) -> str:
    """e.g. '4/3 n^3 + 10 n^2 - 2/3 n + 6'."""
    terms = []
    for power in range(len(poly) - 1, -1, -1):
        c = poly[power]
        if c == 0:
            continue
        sign = "-" if c < 0 else "+"
        mag = abs(c)
        mag_s = "" if (mag == 1 and power > 0) else str(mag)
        var = "" if power == 0 else ("n" if power == 1 else f"n^{power}")
        body = (mag_s + " " + var).strip()
        terms.append((sign, body))
    if not terms:
        return "0"
    first_sign, first = terms[0]
    out = ("-" if first_sign == "-" else "") + first
    for sign, body in terms[1:]:
        out += f" {sign} {body}"
    return out


FIT_NS = tuple(range(3, 11))  # fitting points; 12 and 20 are then predicted and checked
TABLE_NS = (3, 12, 20)


@dataclass
class CountResult:
    method: str
    counts: dict[int, Tally] = field(default_factory=dict)
    poly_M: list[Fraction] = field(default_factory=list)
    poly_A: list[Fraction] = field(default_factory=list)
    poly_div: list[Fraction] = field(default_factory=list)
    poly_trig: list[Fraction] = field(default_factory=list)

    @property
    def degree(self) -> int:
        return max(len(self.poly_M), len(self.poly_A)) - 1

    def predicts_exactly(self) -> bool:
        """The fitted polynomials reproduce every counted n, fitted or not."""
        return all(evaluate(self.poly_M, n) == t.M and evaluate(self.poly_A, n) == t.A for n, t in self.counts.items())


def count_method(method: str, fit_ns=FIT_NS, check_ns=TABLE_NS) -> CountResult:
    result = CountResult(method)
    for n in sorted(set(fit_ns) | set(check_ns)):
        result.counts[n], _ = count_udot(method, n)
    fit = [result.counts[n] for n in fit_ns]
    result.poly_M = fit_polynomial(fit_ns, [t.M for t in fit])
    result.poly_A = fit_polynomial(fit_ns, [t.A for t in fit])
    result.poly_div = fit_polynomial(fit_ns, [t.div for t in fit])
    result.poly_trig = fit_polynomial(fit_ns, [t.trig for t in fit])
    return result


def count_all(fit_ns=FIT_NS, check_ns=TABLE_NS) -> dict[str, CountResult]:
    return {method: count_method(method, fit_ns, check_ns) for method in IMPLEMENTATIONS}
