"""The L-P series engine (:mod:`perturb.methods.series`) against SymPy and numbers.

The engine multiplies trigonometric series by the product-to-sum rules on Laurent
polynomials of its own; the oracle here is SymPy's arithmetic on the same expressions,
compared numerically at random points (no output of the engine is hard-coded).
"""

from __future__ import annotations

import random

import pytest
import sympy as sp

from perturb.methods.series import (
    ONE,
    ZERO,
    LaurentPolynomial,
    lift,
    series_at_zero,
    series_combine,
    series_derivative,
    series_mul,
    series_solve,
    series_to_sympy,
    series_truncate,
    tidy_coefficient,
)

A, w, k = sp.symbols("A w k", positive=True)
psi = sp.Symbol("psi", real=True)


def _random_series(rng: random.Random, nmax: int = 3):
    terms = {}
    for n in range(nmax + 1):
        c = sp.Rational(rng.randint(-5, 5), rng.randint(1, 4)) * A ** rng.randint(0, 2)
        s = sp.Rational(rng.randint(-5, 5), rng.randint(1, 4)) * k ** rng.randint(0, 1) / w
        terms[n] = (lift(c), lift(s) if n else ZERO)
    return terms


def _close(e1: sp.Expr, e2: sp.Expr, rng: random.Random, trials: int = 6) -> bool:
    for _ in range(trials):
        at = {A: rng.uniform(0.3, 2), w: rng.uniform(0.5, 2), k: rng.uniform(-1, 1)}
        at[psi] = rng.uniform(-3, 3)
        if abs(complex(sp.N((e1 - e2).xreplace(at)))) > 1e-10:
            return False
    return True


def test_laurent_polynomial_arithmetic_matches_sympy():
    rng = random.Random(1)
    p = LaurentPolynomial.from_sympy(3 * A**2 / w - sp.Rational(1, 2) * k + 2)
    q = LaurentPolynomial.from_sympy(A - 4 * k * w)
    expr_p, expr_q = p.to_sympy(), q.to_sympy()
    assert _close((p * q).to_sympy(), expr_p * expr_q, rng)
    assert _close((p + q - ONE).to_sympy(), expr_p + expr_q - 1, rng)
    assert _close((p / LaurentPolynomial.atom(A, 2)).to_sympy(), expr_p / A**2, rng)
    assert _close((q**3).to_sympy(), expr_q**3, rng)
    assert p.degree(w) == (-1, 0) and q.degree(A) == (0, 1)
    with pytest.raises(ZeroDivisionError):
        p / q  # only monomials divide exactly
    # the readable form of the derivation text is the same polynomial
    assert _close(tidy_coefficient(p * q), expr_p * expr_q, rng)


@pytest.mark.parametrize("seed", range(3))
def test_series_product_is_the_product_of_the_functions(seed):
    rng = random.Random(seed)
    a, b = _random_series(rng), _random_series(rng)
    fa, fb = series_to_sympy(a, psi), series_to_sympy(b, psi)
    assert _close(series_to_sympy(series_mul(a, b), psi), fa * fb, rng)
    # truncation keeps exactly the harmonics up to nmax of the full product
    cut = series_mul(a, b, nmax=2)
    assert set(cut) <= {0, 1, 2}
    assert series_to_sympy(cut, psi) == series_to_sympy(series_truncate(series_mul(a, b), 2), psi)
    combo = series_combine((2, a), (lift(-A), b))
    assert _close(series_to_sympy(combo, psi), 2 * fa - A * fb, rng)
    assert _close(series_to_sympy(series_derivative(a, 2), psi), sp.diff(fa, psi, 2), rng)
    assert _close(series_at_zero(a).to_sympy(), fa.subs(psi, 0), rng)


def test_series_solve_inverts_the_linear_operator_off_resonance():
    rng = random.Random(7)
    rhs = _random_series(rng, 4)
    rhs.pop(1)  # the secular part is removed before solving
    u = series_solve(rhs, lift(1 / w**2))
    fu = series_to_sympy(u, psi)
    residual = w**2 * (sp.diff(fu, psi, 2) + fu) - series_to_sympy(rhs, psi)
    assert _close(residual, sp.Integer(0), rng)
