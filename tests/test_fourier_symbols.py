"""Symbolic coefficient functions: values, exact derivatives, closed forms, vectorised series."""

from __future__ import annotations

import mpmath as mp
import numpy as np
import pytest
import sympy as sp

from perturb.errors import FourierError
from perturb.fourier.symbols import (
    RampCoefficient,
    StepCoefficient,
    closed_form,
    series_coefficient,
    series_coefficients,
)
from perturb.model.parsing import real_symbol

x = real_symbol("x")
A = sp.Symbol("A", positive=True)


def quad_coefficient(f, n, Av, bv, cuts):
    mp.mp.dps = 30
    pts = [0] + sorted(c for c in cuts if 0 < c < mp.pi) + [mp.pi]
    return float(2 / mp.pi * mp.quad(lambda p: f(Av * mp.cos(p) + bv) * mp.cos(n * p), pts))


def test_mixed_force_vectorised_equals_symbolic_and_quadrature():
    force = -2 * x + 3 * ((x - 1) * sp.Heaviside(x - 1) + (x + 1) * sp.Heaviside(-x - 1))
    force += sp.Rational(1, 10) * x**3
    Av, bv = 2.3, 0.2
    vec = series_coefficients(force, x, 12, Av, bv)

    def f(z):
        return -2 * z + 3 * (max(z - 1, 0) + min(z + 1, 0)) + z**3 / 10

    cuts = [mp.acos((1 - bv) / Av), mp.acos((-1 - bv) / Av)]
    for n in range(13):
        sym = float(series_coefficient(force, x, n, sp.Float(Av), sp.Float(bv)))
        assert vec[n] == pytest.approx(sym, rel=1e-12, abs=1e-13)
        assert vec[n] == pytest.approx(quad_coefficient(f, n, Av, bv, cuts), rel=1e-11, abs=1e-12)


def test_dirac_terms():
    force = 3 * sp.DiracDelta(2 * x - 1)  # = 1.5 * delta(x - 1/2)
    Av = 1.7
    th = np.arccos(0.5 / Av)
    vec = series_coefficients(force, x, 5, Av)
    expected = [1.5 * 2 * np.cos(n * th) / (np.pi * Av * np.sin(th)) for n in range(6)]
    np.testing.assert_allclose(vec, expected, rtol=1e-12)


def test_derivatives_are_exact():
    # d/dA of the ramp coefficient is (a_{n-1} + a_{n+1})/2 of the step: check numerically
    for n in (0, 1, 2, 5):
        expr = RampCoefficient(n, A, 0, 1)
        d = sp.diff(expr, A)
        h = 1e-6
        fd = (float(expr.subs(A, 2.0 + h)) - float(expr.subs(A, 2.0 - h))) / (2 * h)
        assert float(d.subs(A, 2.0)) == pytest.approx(fd, rel=1e-7, abs=1e-9)
    d = sp.diff(StepCoefficient(3, A, 0, 1), A)
    h = 1e-6
    fd = (float(StepCoefficient(3, 2.0 + h, 0, 1)) - float(StepCoefficient(3, 2.0 - h, 0, 1))) / (
        2 * h
    )
    assert float(d.subs(A, 2.0)) == pytest.approx(fd, rel=1e-7)


def test_closed_form_matches_functions_in_the_crossing_regime():
    force = -2 * x + 3 * ((x - 1) * sp.Heaviside(x - 1) + (x + 1) * sp.Heaviside(-x - 1))
    a1 = series_coefficient(force, x, 1, A)
    expr, defs, domains = closed_form(a1)
    assert not expr.has(RampCoefficient)
    for Av in (1.01, 2.0, 7.5):
        value = expr.subs({s: v for s, v in defs}).subs(A, Av)
        assert float(value) == pytest.approx(float(a1.subs(A, Av)), rel=1e-12)
    assert domains


def test_errors():
    with pytest.raises(FourierError, match="closed-form"):
        series_coefficients(sp.sin(x), x, 3, 1.0)
    with pytest.raises(FourierError, match="without values"):
        series_coefficients(real_symbol("k") * x, x, 3, 1.0)
    with pytest.raises(FourierError):
        series_coefficient(x, x, -1, A)
