"""Harmonic bookkeeping: components against numerical quadrature and round trips."""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import quad

from perturb.errors import PerturbError
from perturb.fourier.trig import from_harmonics, harmonics, solve_harmonic_oscillator

psi, a, b, phi = sp.symbols("psi a b phi", real=True)
EXPRS = [
    (a * sp.cos(psi + phi)) ** 3 + b * sp.sin(2 * psi) * sp.cos(psi) + 3,
    sp.sin(psi) ** 4 * phi + a * sp.cos(3 * psi - 1) * sp.sin(psi + b),
    (a * sp.cos(psi) + a**2 * sp.cos(3 * psi)) ** 5,
]


@pytest.mark.parametrize("expr", EXPRS)
def test_components_equal_fourier_integrals(expr):
    vals = {a: 0.7, b: -1.3, phi: 0.4}
    f = sp.lambdify(psi, expr.subs(vals))
    for n, (c, s) in harmonics(expr, psi).items():
        w = 1 / (2 * np.pi) if n == 0 else 1 / np.pi
        c_ref = w * quad(lambda p, n=n: f(p) * np.cos(n * p), 0, 2 * np.pi, limit=200)[0]
        s_ref = w * quad(lambda p, n=n: f(p) * np.sin(n * p), 0, 2 * np.pi, limit=200)[0]
        assert float(c.subs(vals)) == pytest.approx(c_ref, abs=1e-11)
        assert float(s.subs(vals)) == pytest.approx(s_ref, abs=1e-11)


@pytest.mark.parametrize("expr", EXPRS)
def test_round_trip(expr):
    d = sp.lambdify((psi, a, b, phi), from_harmonics(harmonics(expr, psi), psi) - expr)
    f = sp.lambdify((psi, a, b, phi), expr)
    r = np.random.default_rng(1).uniform(-2, 2, (4, 40))
    # relative to the size of the terms (expr2 reaches ~1e4)
    assert np.max(np.abs(d(*r))) < 1e-13 * max(1.0, np.max(np.abs(f(*r))) * 10)


def test_particular_solution_solves_the_equation():
    rhs = {0: (sp.Integer(2), sp.Integer(0)), 3: (a, b), 5: (sp.Integer(1), sp.Integer(0))}
    u = solve_harmonic_oscillator(rhs, psi, omega2=4)
    residual = 4 * (sp.diff(u, psi, 2) + u) - from_harmonics(rhs, psi)
    assert sp.simplify(residual) == 0
    with pytest.raises(PerturbError, match="secular"):
        solve_harmonic_oscillator({1: (a, 0)}, psi)


def test_rejects_non_harmonic_dependence():
    with pytest.raises(PerturbError, match="integer"):
        harmonics(sp.cos(psi / 2), psi)
    with pytest.raises(PerturbError):
        harmonics(psi * sp.cos(psi), psi)


def test_folded_crossing_angle_keeps_the_given_assumptions():
    """The single crossing angle left after folding is ``Symbol('theta', positive=True)`` as
    given, not rebuilt from the inferred closure of its assumptions: the two print differently
    and SymPy's cache would otherwise hand either spelling to later expressions, so a saved
    derivation's text depended on what ran before it."""
    import sympy as sp

    from perturb.fourier.trig import fold_mirror_angles

    A = sp.Symbol("A", positive=True)
    t1, t2 = sp.Symbol("theta_1", positive=True), sp.Symbol("theta_2", positive=True)
    exprs = (sp.sin(t1) + sp.sin(t2),)
    defs = ((t1, sp.acos(1 / A)), (t2, sp.acos(-1 / A)))
    out, new_defs = fold_mirror_angles(exprs, defs)
    ((theta, value),) = new_defs
    assert sp.srepr(theta) == "Symbol('theta', positive=True)"
    assert value == sp.acos(1 / A)
    assert all(s.name != "theta_2" for s in out[0].free_symbols)
