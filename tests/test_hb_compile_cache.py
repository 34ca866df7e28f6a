"""Numeric harmonic balance compiles a system once: polynomial forces as numeric monomial
tables (no code generation), and one system per (oscillator, options) in a process.

Oracles: the polynomials and their derivatives written out by hand in numpy (and central
differences), and a DOP853 steady state (rtol = atol = 1e-12) of the Duffing equation
integrated here.
"""

from __future__ import annotations

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp

from perturb.errors import ParameterError
from perturb.model.builtins import builtin_model
from perturb.numeric.compile import PolynomialTable, polynomial_table
from perturb.numeric.harmonic_balance import compiled_system, harmonic_balance_orbit

x, v = sp.symbols("x v")


def test_polynomial_table_values_and_derivatives():
    expr = sp.Rational(3, 2) * x**3 - 2 * x * v**2 + sp.sqrt(2) * v - 7
    table = polynomial_table(expr, (x, v))
    assert table is not None
    xs = np.linspace(-2.0, 3.0, 7)
    vs = np.linspace(1.5, -1.0, 7)
    by_hand = 1.5 * xs**3 - 2.0 * xs * vs**2 + np.sqrt(2.0) * vs - 7.0
    np.testing.assert_allclose(table(xs, vs), by_hand, rtol=1e-14, atol=1e-13)
    h = 1e-6
    for j, (dx, dv) in enumerate(((h, 0.0), (0.0, h))):
        fd = (table(xs + dx, vs + dv) - table(xs - dx, vs - dv)) / (2 * h)
        np.testing.assert_allclose(table.derivative(j)(xs, vs), fd, rtol=1e-7, atol=1e-7)
    # broadcasting: a scalar velocity with an array of positions
    assert table(xs, 0.5).shape == xs.shape


@pytest.mark.parametrize(
    "expr",
    [x * sp.Heaviside(x - 1), sp.sign(v), sp.Abs(x) * x, sp.Symbol("a") * x**3, sp.sin(x)],
)
def test_polynomial_table_refuses_what_is_not_a_numeric_polynomial(expr):
    assert polynomial_table(expr, (x, v)) is None


def test_polynomial_table_bad_input():
    with pytest.raises(ParameterError, match="exponents >= 0"):
        PolynomialTable(np.array([1.0]), np.array([[-1, 0]]))
    with pytest.raises(ParameterError, match="finite coefficients"):
        PolynomialTable(np.array([np.nan]), np.array([[1, 0]]))
    with pytest.raises(ParameterError, match="2 variables called with 1"):
        polynomial_table(x**2 + v, (x, v))(1.0)


def test_one_system_per_oscillator_and_options():
    params = {"alpha": 1.0, "mu": 0.1, "F": 0.5, "omega0": 1.0}
    a = compiled_system(builtin_model("duffing", **params), harmonics=7)
    # an equal oscillator built again finds the same compiled system
    assert compiled_system(builtin_model("duffing", **params), harmonics=7) is a
    assert compiled_system(builtin_model("duffing", **params), harmonics=9) is not a
    other = builtin_model("duffing", **{**params, "F": 0.6})
    assert compiled_system(other, harmonics=7) is not a
    with pytest.raises(ParameterError):
        compiled_system(builtin_model("duffing", **params), harmonics=[7])


def test_duffing_orbit_from_the_table_matches_dop853():
    mu, F, W = 0.1, 0.5, 1.2
    osc = builtin_model("duffing", alpha=1.0, mu=mu, F=F, omega0=1.0)
    sol = harmonic_balance_orbit(osc, W, harmonics=7, projection="aft")

    def rhs(t, y):
        return [y[1], F * np.cos(W * t) - mu * y[1] - y[0] - y[0] ** 3]

    T = 2 * np.pi / W
    # start on the HB orbit (the attractor it approximates) and let the transient decay
    y0 = [float(sol(0.0)), float(sol.velocity(0.0))]
    settle = solve_ivp(rhs, (0.0, 60 * T), y0, method="DOP853", rtol=1e-12, atol=1e-12)
    t = np.linspace(0.0, T, 2001)
    last = solve_ivp(
        rhs, (0.0, T), settle.y[:, -1], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t
    )
    exact_amplitude = float(np.abs(last.y[0]).max())
    # the orbit is stable: the ODE stays on it, and H = 7 is within 1e-3 of its max |x|
    assert sol.stable
    assert abs(sol.amplitude - exact_amplitude) <= 1e-3 * exact_amplitude
