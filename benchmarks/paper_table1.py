"""Table I: the paper's printed operation counts beside ours (``table1.md``).

The paper's formulas are transcribed as exact coefficient lists (lowest power
first) from sections III-V and Table I; :func:`paper_inconsistencies` checks
them against each other in rational arithmetic instead of trusting either.
"""

from __future__ import annotations

from fractions import Fraction as F

from .opcount import LABELS, TABLE_NS, CountResult, evaluate, format_polynomial

# (M, A) per step, as printed in the text; coefficients lowest power first.
PAPER_STEPS = {
    "kane_paper": {
        "V (eqs. 6)": ([-3, 3], [-1, 1]),
        "omega (eq. 7)": ([-4, 4], [-1, 1]),
        "dV/du (eqs. 12-13)": ([-6, 6], [-2, 2]),
        "domega/du (eq. 14)": ([-8, 8], [-2, 2]),
        "dV/dq (eqs. 15-21)": ([-9, F(9, 2), F(3, 2)], [-5, F(5, 2), F(1, 2)]),
        "domega/dq (eqs. 15-21)": ([-12, 6, 2], [-5, F(5, 2), F(1, 2)]),
        "F, N, M (eqs. 9-11)": ([-6, 14, 4], [-13, 10, 2]),
        "solve eq. 8": ([6], [3]),
    },
    "lagrange": {
        "inertia matrix (eq. 25)": ([-17, F(-19, 6), F(5, 2), F(5, 3)], [-5, F(4, 3), F(3, 2), F(1, 6)]),
        "bias vector": ([-4, 10], [-4, 6]),
        "Jacobian A": ([0, F(-3, 2), F(3, 2)], [0, F(-1, 2), F(1, 2)]),
        "Adot": ([0, F(-1, 2), F(3, 2)], [0, -1, 1]),
        "triangular decomposition": ([6, F(44, 3), 10, F(4, 3)], [3, F(29, 3), 8, F(4, 3)]),
    },
    "newton_euler": {
        "inertia matrix": ([-27, 56, 12], [-53, 67, 7]),
        "bias vector": ([-22, 137], [-11, 101]),
        "Jacobian A": ([0, F(-3, 2), F(3, 2)], [0, F(-1, 2), F(1, 2)]),
        "Adot": ([0, F(-1, 2), F(3, 2)], [0, -1, 1]),
        "triangular decomposition": ([6, F(44, 3), 10, F(4, 3)], [3, F(29, 3), 8, F(4, 3)]),
    },
}
# Printed totals (M, A), text and Table I header alike.
PAPER_TOTALS = {
    "kane_paper": ([-27, 24, 3], [-21, F(97, 2), F(15, 2)]),
    "lagrange": ([-11, F(39, 2), F(31, 2), 3], [-2, F(31, 2), 11, F(3, 2)]),
    "newton_euler": ([-50, F(1057, 6), F(33, 2), F(4, 3)], [-43, F(617, 3), 25, F(4, 3)]),
}
# Table I's numeric columns as printed: {method: {n: (A, M)}}.
PAPER_TABLE = {
    "kane_paper": {3: (72, 192), 12: (693, 1641), 20: (1653, 3949)},
    "lagrange": {3: (184, 268), 12: (4360, 7639), 20: (16708, 30579)},
    "newton_euler": {3: (663, 835), 12: (6744, 8329), 20: (20740, 24737)},
}


def poly(coeffs):
    return [F(c) for c in coeffs]


def add_polys(polys):
    out = [F(0)] * max(len(p) for p in polys)
    for p in polys:
        for i, c in enumerate(p):
            out[i] += F(c)
    while len(out) > 1 and out[-1] == 0:
        out.pop()
    return out


def paper_inconsistencies() -> list[str]:
    """Checks of the paper's counts against themselves, as sentences."""
    notes = []
    for method, steps in PAPER_STEPS.items():
        sum_M = add_polys([poly(m) for m, _ in steps.values()])
        sum_A = add_polys([poly(a) for _, a in steps.values()])
        tot_M, tot_A = (poly(p) for p in PAPER_TOTALS[method])
        label = LABELS[method]
        if sum_M == tot_M and sum_A == tot_A:
            notes.append(f"{label}: the printed total equals the sum of the printed steps.")
        else:
            notes.append(
                f"{label}: the printed steps add up to M = {format_polynomial(sum_M)}, "
                f"A = {format_polynomial(sum_A)}, but the printed total is M = {format_polynomial(tot_M)}, "
                f"A = {format_polynomial(tot_A)}.")
        columns = []
        for n, (printed_A, printed_M) in PAPER_TABLE[method].items():
            fM, fA = evaluate(tot_M, n), evaluate(tot_A, n)
            if (printed_A, printed_M) == (fA, fM):
                columns.append(f"n={n}: matches the header formulas")
            elif (printed_A, printed_M) == (fM, fA):
                columns.append(f"n={n}: the A column holds the M formula ({fM}) and the M column the A formula ({fA})")
            else:
                columns.append(f"n={n}: printed (A, M) = ({printed_A}, {printed_M}), header formulas give ({fA}, {fM})")
        notes.append(f"{label}, Table I numeric columns: " + "; ".join(columns) + ".")
    return notes


def _fmt_poly(coeffs) -> str:
    return format_polynomial(poly(coeffs))


def render_table1(results: dict[str, CountResult], stages: dict[str, dict] | None = None) -> str:
    """Markdown for ``table1.md``."""
    lines = ["# Table I reproduced: operation counts of one udot evaluation", ""]
    lines += [
        "Counted by executing each implementation once on numpy object arrays of a counting scalar "
        "(`benchmarks/opcount.py`): M = multiplications + divisions (the paper counts the division of "
        "eq. 7 as a multiplication), A = additions + subtractions; sign changes, sin/cos and operations "
        "with a structural 0 or 1 are not counted (see the module docstring). Table II parameters, no "
        "damping. The polynomial is the exact (rational) interpolant through n = "
        f"{min(next(iter(results.values())).counts)}..10; it reproduces every counted n, including 12 and 20.",
        "",
        "## Totals", "",
        "| method | source | M (general n) | A (general n) | " + " | ".join(f"n={n} A | n={n} M" for n in TABLE_NS) + " |",
        "|---|---|---|---|" + "---|---|" * len(TABLE_NS),
    ]
    for method, res in results.items():
        cells = " | ".join(f"{res.counts[n].A} | {res.counts[n].M}" for n in TABLE_NS)
        lines.append(f"| {LABELS[method]} | counted | {format_polynomial(res.poly_M)} | "
                     f"{format_polynomial(res.poly_A)} | {cells} |")
        if method in PAPER_TOTALS:
            pM, pA = PAPER_TOTALS[method]
            printed = " | ".join(f"{PAPER_TABLE[method][n][0]} | {PAPER_TABLE[method][n][1]}" for n in TABLE_NS)
            lines.append(f"| {LABELS[method]} | paper, printed | {_fmt_poly(pM)} | {_fmt_poly(pA)} | {printed} |")
            formula = " | ".join(f"{evaluate(poly(pA), n)} | {evaluate(poly(pM), n)}" for n in TABLE_NS)
            lines.append(f"| {LABELS[method]} | paper, header formulas evaluated | | | {formula} |")
    lines += ["", "Divisions (part of M) and sin/cos evaluations, counted:", "",
              "| method | divisions | sin + cos |", "|---|---|---|"]
    for method, res in results.items():
        lines.append(f"| {LABELS[method]} | {format_polynomial(res.poly_div)} | {format_polynomial(res.poly_trig)} |")
    lines += ["", "## The paper's own inconsistencies (checked in exact arithmetic)", ""]
    lines += [f"- {note}" for note in paper_inconsistencies()]
    if stages:
        lines += ["", "## Per-step counts at n = 12: ours beside the paper's step formulas", ""]
        for method, table in stages.items():
            lines += [f"### {LABELS[method]}", "", "| step (ours) | M | A |", "|---|---|---|"]
            lines += [f"| {name} | {t.M} | {t.A} |" for name, t in table.items()]
            lines += ["", "| step (paper) | M | A |", "|---|---|---|"]
            for name, (pM, pA) in PAPER_STEPS[method].items():
                lines.append(f"| {name} | {evaluate(poly(pM), 12)} | {evaluate(poly(pA), 12)} |")
            lines.append("")
    return "\n".join(lines) + "\n"
