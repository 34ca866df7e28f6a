"""Safe parsing: what the parser accepts, what it builds, and what it refuses."""

from __future__ import annotations

import os

import pytest
import sympy as sp

from perturb.errors import ParseError, PerturbError
from perturb.model.parsing import MAX_LENGTH, parse_equation, parse_expression, real_symbol

x, k, mu, F, W, t = (real_symbol(n) for n in ("x", "k", "mu", "F", "Omega", "t"))
v, a = real_symbol("x'"), real_symbol("x''")

NSD = "x'' + mu*x' + k*x + (1-k)*((x-1)*Heaviside(x-1) + (x+1)*Heaviside(-x-1)) = F*cos(Omega*t)"


def test_nsd_equation_builds_the_expected_sympy_objects():
    eq = parse_equation(NSD)
    expected = (
        a
        + mu * v
        + k * x
        + (1 - k) * ((x - 1) * sp.Heaviside(x - 1) + (x + 1) * sp.Heaviside(-x - 1))
    )
    assert sp.simplify(eq.lhs - expected) == 0
    assert eq.rhs == F * sp.cos(W * t)
    assert eq.state == "x" and eq.derivative_order == 2


def test_decimals_are_exact_and_powers_both_spellings():
    assert parse_expression("0.05") == sp.Rational(1, 20)
    assert parse_expression("1e-3*x^2") == parse_expression("x**2/1000")
    assert parse_expression("2**-1") == sp.Rational(1, 2)


def test_functions_constants_and_piecewise():
    e = parse_expression("Piecewise((x, x > 0), (-x, True)) + abs(x) + max(x, 0) + pi")
    for val in (-1.5, 0.3, 2.0):
        ref = 2 * abs(val) + max(val, 0) + float(sp.pi)
        assert float(e.subs(x, val)) == pytest.approx(ref, rel=1e-15)


def test_state_variable_may_have_any_name():
    eq = parse_equation("u'' + u = 0")
    assert eq.state == "u"


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("x'' + + x", "two signs in a row"),
        ("x'' - - x", "two signs in a row"),
        ("foo(x) + x''", "unknown function 'foo'"),
        ("eval(x)", "unknown function 'eval'"),
        ("__import__('os')", "'__import__'"),
        ("x.__class__", "unexpected character '.'"),
        ("x; x", "unexpected character ';'"),
        ("x'' + x = 1 = 2", "single '='"),
        ("x''' + x", "only first"),
        ("x'' + y' = 0", "two different variables"),
        ("cos + x", "without arguments"),
        ("(x + 1", "')'"),
        ("x +", "end of input"),
        ("1/0", "division by zero"),
        ("x**100000", "too large"),
        ("((10**1000)**1000)**1000", "digits"),
        ("Heaviside(x, 1, 2)", "exactly 1 argument"),
        ("Max(x)", "at least 2"),
        ("Piecewise((x, x), (0, True))", "comparison"),
    ],
)
def test_malformed_or_hostile_input_is_refused_with_a_precise_message(text, fragment):
    with pytest.raises(ParseError) as info:
        parse_equation(text)
    assert fragment in str(info.value)
    assert isinstance(info.value, PerturbError)


def test_hostile_input_is_never_executed(tmp_path):
    marker = tmp_path / "pwned"
    for text in (
        f"__import__('os').system('touch {marker}')",
        f"os.system('touch {marker}')",
        f'exec(\'open("{marker}", "w")\')',
        "lambda: 0",
    ):
        with pytest.raises(ParseError):
            parse_equation(text)
    assert not marker.exists()
    assert not os.path.exists(marker)


def test_size_and_depth_limits():
    with pytest.raises(ParseError, match="at most"):
        parse_expression("x+" * MAX_LENGTH + "x")
    with pytest.raises(ParseError, match="nested deeper"):
        parse_expression("(" * 300 + "x" + ")" * 300)


def test_expression_parser_rejects_derivatives_and_equations():
    with pytest.raises(ParseError, match="not allowed here"):
        parse_expression("x' + x")
    with pytest.raises(ParseError, match="not an equation"):
        parse_expression("x = 1")


def test_non_string_input():
    with pytest.raises(ParseError, match="string"):
        parse_expression(3)  # type: ignore[arg-type]
