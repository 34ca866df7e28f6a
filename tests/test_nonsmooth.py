"""Tests of :mod:`perturb.model.pwl` (canonical piecewise-linear form).

The oracle throughout is the *original* SymPy expression, evaluated exactly at rational points
(``expr.subs(x, Rational(p))``) — never the canonical form itself. Points within 1e-9 of a
breakpoint are avoided because values at breakpoints are not represented by design.
"""

from __future__ import annotations

import dataclasses
import functools
from fractions import Fraction

import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from perturb.errors import NonsmoothError, ParameterError
from perturb.model.pwl import (
    NumericPWL,
    PiecewiseLinear,
    RampStepForm,
    Segment,
    is_nonsmooth,
    is_pwl,
    to_pwl,
)

X = sp.Symbol("x")
K = sp.Symbol("k")
R = sp.Symbol("r")
D = sp.Symbol("d", positive=True)
F0 = sp.Symbol("f0")
K1, K2 = sp.symbols("k1 k2")
H = sp.Heaviside


@functools.cache
def cached_pwl(expr: sp.Expr, values: tuple = ()) -> PiecewiseLinear:
    """to_pwl once per expression (hypothesis re-runs a test body many times)."""
    return to_pwl(expr, X, values=dict(values))


FAST = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def zou(k):
    """Zou–Nagarajaiah negative-stiffness force."""
    return k * X + (1 - k) * ((X - 1) * H(X - 1) + (X + 1) * H(-X - 1))


def oracle(expr: sp.Expr, point: float) -> float:
    """Exact value of the original expression at the (exactly represented) float point."""
    value = expr.subs(X, sp.Rational(Fraction(point)))
    return float(value)


def away_from(points: list[float], breakpoints) -> list[float]:
    """Drop points within 1e-9 of a breakpoint or of a simple fraction n/q (q <= 24).

    The second rule matters because canonical breakpoints are *minimal*: e.g.
    ``H(x)*H(-x)`` is 0 except at the removed point x = 0, where the original is 1/4. All
    switching points of the tested expressions are such fractions.
    """
    bps = [float(b) for b in breakpoints]
    return [
        p
        for p in points
        if all(abs(p - b) > 1e-9 for b in bps)
        and all(abs(p * q - round(p * q)) > 1e-9 * q for q in range(1, 25))
    ]


#: A ratio with a large prime denominator: probes built with it are never simple fractions.
OFF = sp.Rational(414214, 1000003)


def segment_probes(breakpoints) -> list[sp.Rational]:
    """One exact rational point strictly inside every segment, off any simple fraction."""
    b = [sp.nsimplify(v) if isinstance(v, sp.Float) else v for v in breakpoints]
    if not b:
        return [OFF - 3, OFF, OFF + 7]
    inner = [lo + (hi - lo) * OFF for lo, hi in zip(b, b[1:], strict=False)]
    return [b[0] - 1 - OFF, *inner, b[-1] + 1 + OFF]


def assert_close(got: float, want: float) -> None:
    assert abs(got - want) <= 1e-12 * (1.0 + abs(want)), (got, want)


def rebuild_ramp_step(form: RampStepForm, point: float) -> float:
    """Evaluate the ramp/step decomposition by its defining formula (independent of the class)."""
    k0, c0, bps, dks, jumps = form
    total = float(k0) * point + float(c0)
    for d, dk, jump in zip(bps, dks, jumps, strict=True):
        if point > float(d):
            total += float(dk) * (point - float(d)) + float(jump)
    return total


def check_everywhere(expr: sp.Expr, pwl: PiecewiseLinear, points: list[float]) -> None:
    """Canonical form (all its views) == original at ``points`` and inside every segment."""
    bps = [float(b) for b in pwl.breakpoints]
    probes = [float(q) for q in segment_probes(pwl.breakpoints)]
    n_symbolic = len(probes) + 2  # the slow SymPy views are checked on these probes only
    probes = probes + away_from(list(points), bps)
    numeric = pwl.numeric()
    piecewise = pwl.as_piecewise()
    heaviside = pwl.as_heaviside()
    form = pwl.ramp_step_form()
    nform = numeric.ramp_step_form()
    values = numeric(np.array(probes))
    for n, (p, v) in enumerate(zip(probes, values, strict=True)):
        want = oracle(expr, p)
        assert_close(v, want)
        assert_close(numeric(p), want)
        assert_close(rebuild_ramp_step(form, p), want)
        assert_close(rebuild_ramp_step(nform, p), want)
        if n >= n_symbolic:
            continue
        q = sp.Rational(Fraction(p))
        assert_close(float(piecewise.subs(X, q)), want)
        assert_close(float(heaviside.subs(X, q)), want)
        i = int(numeric.segment_index(p))
        assert_close(float(pwl.slopes[i] * q + pwl.offsets[i]), want)


def sym_equal(a, b) -> bool:
    return sp.simplify(sp.sympify(a) - sp.sympify(b)) == 0


def assert_form(pwl, breakpoints, slopes, offsets) -> None:
    assert len(pwl.breakpoints) == len(breakpoints), pwl
    for got, want in zip(
        (*pwl.breakpoints, *pwl.slopes, *pwl.offsets),
        (*breakpoints, *slopes, *offsets),
        strict=True,
    ):
        assert sym_equal(got, want), (str(pwl), got, want)


# ------------------------------------------------------------------------------------------
# named models: exact symbolic forms (derived by hand) and round trips
# ------------------------------------------------------------------------------------------


def test_zou_symbolic_k_slopes_and_offsets():
    # x < -1: kx + (1-k)(x+1) = x + (1-k); |x| < 1: kx; x > 1: kx + (1-k)(x-1) = x - (1-k)
    pwl = to_pwl(zou(K), X)
    assert pwl.breakpoints == (-1, 1)
    assert pwl.slopes == (1, K, 1)
    assert_form(pwl, (-1, 1), (1, K, 1), (1 - K, 0, K - 1))
    assert pwl.is_continuous and pwl.jumps == (0, 0)
    assert len(pwl.slope_jumps) == 2
    assert sym_equal(pwl.slope_jumps[0], K - 1) and sym_equal(pwl.slope_jumps[1], 1 - K)
    assert not pwl.is_numeric


@pytest.mark.parametrize("k", [sp.Rational(-1, 2), -2, 0, sp.Rational(3, 10), 0.3, 2])
@FAST
@given(points=st.lists(st.floats(-6, 6), min_size=1, max_size=12))
def test_zou_numeric_k_round_trip(k, points):
    pwl = cached_pwl(zou(K), (("k", k),))
    assert_form(pwl, (-1, 1), (1, k, 1), (1 - k, 0, k - 1))
    check_everywhere(zou(k), pwl, points)


def test_zou_k_equal_one_is_linear():
    # k = 1: the force is x; canonical (minimal) form has no breakpoints
    pwl = to_pwl(zou(K), X, values={K: 1})
    assert pwl.breakpoints == () and pwl.slopes == (1,) and pwl.offsets == (0,)
    assert to_pwl(zou(K), X).subs({"k": 1}) == pwl


def clearance(d, r=R):
    return X + r * (X - d) * H(X - d)


def test_clearance_symbolic():
    pwl = to_pwl(clearance(D), X)
    assert_form(pwl, (D,), (1, 1 + R), (0, -R * D))
    assert pwl.is_continuous


@pytest.mark.parametrize(("d", "r"), [(1, 3), (sp.Rational(1, 4), -1), (0.7, 2.5)])
@FAST
@given(points=st.lists(st.floats(-5, 5), min_size=1, max_size=12))
def test_clearance_numeric_round_trip(d, r, points):
    expr = clearance(d, r)
    pwl = cached_pwl(expr)
    assert_form(pwl, (d,), (1, 1 + r), (0, -r * d))
    check_everywhere(expr, pwl, points)


def dead_zone(k1=K1, k2=K2, d=D):
    return k1 * X + k2 * (X - sp.Max(-d, sp.Min(d, X)))


def saturation(k1=K1, k2=K2, d=D):
    return k1 * X + k2 * sp.Max(-d, sp.Min(d, X))


def test_dead_zone_and_saturation_symbolic():
    # dead zone: slope k1 inside |x| < d, k1 + k2 outside, continuous at ±d
    assert_form(to_pwl(dead_zone(), X), (-D, D), (K1 + K2, K1, K1 + K2), (D * K2, 0, -D * K2))
    # saturation: slope k1 + k2 inside, k1 outside, plateau offsets ∓k2 d
    assert_form(to_pwl(saturation(), X), (-D, D), (K1, K1 + K2, K1), (-D * K2, 0, D * K2))


def test_bilinear_and_relay_symbolic():
    bilinear = to_pwl(X + (R - 1) * X * H(X), X)
    assert_form(bilinear, (0,), (1, R), (0, 0))
    relay = to_pwl(F0 * sp.sign(X), X)
    assert_form(relay, (0,), (0, 0), (-F0, F0))
    assert relay.is_continuous is False  # undecidable jump 2*f0 counts as not continuous
    assert sym_equal(relay.jumps[0], 2 * F0)
    f0 = sp.Symbol("f0", positive=True)
    assert to_pwl(f0 * sp.sign(X), X).is_continuous is False
    f0 = sp.Symbol("f0", nonnegative=True)
    assert to_pwl(f0 * sp.sign(X), X, values={"f0": 0}).is_continuous is True
    assert to_pwl(f0 * sp.sign(X), X).subs({"f0": 0}).breakpoints == ()


NAMED = {
    "zou k=-0.5": zou(sp.Rational(-1, 2)),
    "dead zone": dead_zone(2, 3, sp.Rational(1, 2)),
    "saturation": saturation(1, -4, 2),
    "bilinear": X + (5 - 1) * X * H(X),
    "relay": sp.Rational(3, 2) * sp.sign(X),
    "abs": sp.Abs(2 * X - 3),
    "abs nested": sp.Abs(sp.Abs(X) - 1) - 2 * sp.Abs(X + 2),
    "sign reflected": sp.sign(-X + 1) + H(-X - 1),
    "max of 4": sp.Max(X, 1 - X, 2 * X - 3, 0),
    "min max nested": sp.Min(sp.Max(X, -1), 2 - X, sp.Max(3 * X - 7, 1)),
    "window": H(X - 1) * H(2 - X),
    "x sign x": X * sp.sign(X) - 3 * X * sp.sign(X - 2),
    "piecewise": sp.Piecewise((-X, X < -1), (2, sp.And(X >= -1, X < 3)), (X - 4, True)),
    "piecewise or": sp.Piecewise((1, (X < -2) | (X > 2)), (X / 2, True)) + 3,
    "heaviside H0": H(X - 1, 0) + H(-X, 1),
    "abs over x": X * sp.Abs(X - 1) / (X - 1),
    # switch arguments identically zero on a whole segment: H(0) = 1/2, sign(0) = 0, x <= 0 true
    "flat arguments": sp.Piecewise((1, sp.Max(X, 0) <= 0), (X, True))
    + 4 * H(sp.Max(X - 1, 0))
    + sp.sign(sp.Min(X, 0))
    + H(sp.Min(X, 2) - 2, 0),
}


@pytest.mark.parametrize("name", sorted(NAMED))
@FAST
@given(points=st.lists(st.floats(-8, 8), min_size=1, max_size=10))
def test_named_models_round_trip(name, points):
    expr = NAMED[name]
    check_everywhere(expr, cached_pwl(expr), points)


def test_relay_numeric_jump_and_abs_form():
    relay = to_pwl(NAMED["relay"], X)
    assert relay.jumps == (3,) and not relay.is_continuous
    assert_form(to_pwl(sp.Abs(2 * X - 3), X), (sp.Rational(3, 2),), (-2, 2), (3, -3))
    window = to_pwl(NAMED["window"], X)
    assert window.breakpoints == (1, 2) and window.jumps == (1, -1)


def test_piecewise_exact_form():
    pwl = to_pwl(NAMED["piecewise"], X)
    assert_form(pwl, (-1, 3), (-1, 0, 1), (0, 2, -4))
    assert pwl.jumps == (1, -3)


# ------------------------------------------------------------------------------------------
# random PWL functions
# ------------------------------------------------------------------------------------------

coef = st.integers(-5, 5)
nonzero = st.integers(-4, 4).filter(bool)
place = st.integers(-8, 8).map(lambda n: sp.Rational(n, 2))


@st.composite
def lines(draw):
    return draw(coef) * X + draw(place)


@st.composite
def pwl_terms(draw):
    kind = draw(
        st.sampled_from(["ramp", "abs", "max", "min", "nested", "sign", "step", "pw", "window"])
    )
    if kind == "ramp":
        return draw(coef) * H(X - draw(place)) * (X - draw(place))
    if kind == "abs":
        return draw(coef) * sp.Abs(draw(nonzero) * X - draw(place))
    if kind in ("max", "min"):
        args = draw(st.lists(lines(), min_size=2, max_size=4))
        return (sp.Max if kind == "max" else sp.Min)(*args)
    if kind == "nested":
        return sp.Max(draw(lines()), sp.Min(draw(lines()), draw(lines())))
    if kind == "sign":
        return draw(coef) * sp.sign(draw(nonzero) * X + draw(place))
    if kind == "step":
        return draw(coef) * H(-X + draw(place))
    if kind == "pw":
        d1, d2 = sorted((draw(place), draw(place)))
        return sp.Piecewise(
            (draw(lines()), X < d1), (draw(lines()), X <= d2), (draw(lines()), True)
        )
    a, b = sorted((draw(place), draw(place)))
    return H(X - a) * H(b - X) * draw(lines())


random_pwl = st.builds(
    lambda base, terms: base + sp.Add(*terms), lines(), st.lists(pwl_terms(), max_size=4)
)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(expr=random_pwl, points=st.lists(st.floats(-12, 12), max_size=8))
def test_random_pwl_matches_original_everywhere(expr, points):
    pwl = to_pwl(expr, X)
    bps = [float(b) for b in pwl.breakpoints]
    assert bps == sorted(set(bps))  # strictly increasing
    # exact check (rational arithmetic) at a point inside every segment
    for q in segment_probes(pwl.breakpoints):
        i = int(pwl.numeric().segment_index(float(q)))
        assert pwl.slopes[i] * q + pwl.offsets[i] == expr.subs(X, q)
    # minimality: every breakpoint changes the slope or the value
    for dk, jump in zip(pwl.slope_jumps, pwl.jumps, strict=True):
        assert dk != 0 or jump != 0
    check_everywhere(expr, pwl, points)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(expr=random_pwl, d=st.integers(1, 9).map(lambda n: sp.Rational(n, 3)))
def test_random_symbolic_scaling_then_subs_equals_direct(expr, d):
    # every place p becomes p*d with d > 0 symbolic: breakpoints are orderable multiples of d,
    # and the symbolic canonical form evaluated at d must equal the canonical form at d
    scaled = expr.subs(X, X / D) * D  # f(x/d)*d: PWL in x with breakpoints scaled by d
    sym = to_pwl(scaled, X)
    assert sym.subs({D: d}) == to_pwl(scaled.subs(D, d), X)
    for q in segment_probes(sym.subs({D: d}).breakpoints):
        i = sum(1 for b in sym.breakpoints if b.subs(D, d) < q)
        assert (sym.slopes[i] * q + sym.offsets[i]).subs(D, d) == scaled.subs({D: d, X: q})


# ------------------------------------------------------------------------------------------
# ramp/step bookkeeping, conversions, records
# ------------------------------------------------------------------------------------------


def test_ramp_step_bookkeeping_by_hand():
    # x*H(x-1) + 2*H(x-2): at 1 the slope rises by 1 and the value jumps 0 -> 1;
    # at 2 the value jumps by 2, slope unchanged
    pwl = to_pwl(X * H(X - 1) + 2 * H(X - 2), X)
    assert pwl.ramp_step_form() == RampStepForm(0, 0, (1, 2), (1, 0), (1, 2))
    assert pwl.offsets == (0, 0, 2)  # offset_{i+1} = offset_i - dk*d + jump
    n = pwl.numeric().ramp_step_form()
    assert n.base_slope == 0.0 and list(n.value_jumps) == [1.0, 2.0]


def test_ramp_step_symbolic_rebuild_equals_function():
    pwl = to_pwl(zou(K) + F0 * sp.sign(X - 2), X)
    k0, c0, bps, dks, jumps = pwl.ramp_step_form()
    rebuilt = (
        k0 * X
        + c0
        + sum((dk * (X - d) + j) * H(X - d) for d, dk, j in zip(bps, dks, jumps, strict=True))
    )
    original = zou(K) + F0 * sp.sign(X - 2)
    for p in (-3, sp.Rational(-1, 2), sp.Rational(3, 2), 5):
        assert sp.simplify((rebuilt - original).subs(X, p)) == 0
        assert sp.simplify((pwl.as_heaviside() - original).subs(X, p)) == 0
        assert sp.simplify((pwl.as_piecewise() - original).subs(X, p)) == 0


def test_segments_records_and_str():
    pwl = to_pwl(saturation(), X)
    segs = pwl.segments
    assert [s.lower for s in segs] == [-sp.oo, -D, D]
    assert [s.upper for s in segs] == [-D, D, sp.oo]
    assert isinstance(segs[0], Segment) and list(pwl) == list(segs)
    with pytest.raises(dataclasses.FrozenInstanceError):
        segs[0].slope = 3
    text = str(pwl)
    assert "-d < x < d" in text and "k1 + k2" in text and "continuous" in text


def test_numeric_object():
    n = to_pwl(sp.Abs(X - 1) + sp.sign(X), X).numeric()
    assert isinstance(n, NumericPWL)
    np.testing.assert_array_equal(n.breakpoints, [0.0, 1.0])
    np.testing.assert_array_equal(n.segment_index([-1, 0, 0.5, 1, 3]), [0, 1, 1, 2, 2])
    # right limit at breakpoints: f(0+) = 2, f(1+) = 1
    np.testing.assert_allclose(n(np.array([0.0, 1.0])), [2.0, 1.0])
    assert isinstance(n(0.25), float) and n(0.25) == pytest.approx(1.75)
    assert n(np.zeros((2, 3))).shape == (2, 3)
    np.testing.assert_allclose(n.jumps, [2.0, 0.0])
    with pytest.raises(ValueError):
        n.slopes[0] = 5.0  # read-only
    with pytest.raises(dataclasses.FrozenInstanceError):
        n.slopes = np.zeros(3)
    assert n == to_pwl(sp.Abs(X - 1) + sp.sign(X), X).numeric()
    with pytest.raises(NonsmoothError, match="strictly increasing"):
        NumericPWL(np.array([1.0, 0.0]), np.zeros(3), np.zeros(3))
    with pytest.raises(NonsmoothError, match="need 2 slopes"):
        NumericPWL(np.array([1.0]), np.zeros(3), np.zeros(3))


def test_numeric_requires_values_and_names_symbols():
    with pytest.raises(NonsmoothError, match="d, r"):
        to_pwl(clearance(D), X).numeric()


def test_constructor_validation():
    with pytest.raises(NonsmoothError, match="strictly increasing"):
        PiecewiseLinear(X, (1, 1), (0, 0, 0), (0, 1, 2))
    with pytest.raises(NonsmoothError, match="2 slopes"):
        PiecewiseLinear(X, (1,), (0,), (0,))
    with pytest.raises(NonsmoothError, match="depends on the variable"):
        PiecewiseLinear(X, (), (X,), (0,))
    with pytest.raises(TypeError, match="string"):
        PiecewiseLinear(X, ("1",), (0, 0), (0, 1))


# ------------------------------------------------------------------------------------------
# subs
# ------------------------------------------------------------------------------------------


@FAST
@given(
    d=st.integers(1, 12).map(lambda n: sp.Rational(n, 4)),
    r=st.integers(-3, 3).map(lambda n: sp.Rational(n, 2)),
)
def test_subs_clearance_equals_to_pwl_of_substituted(d, r):
    sym = to_pwl(clearance(D), X)
    by_subs = sym.subs({"d": d, R: r})
    direct = to_pwl(clearance(d, r), X)
    assert by_subs == direct  # exact values: identical canonical form (incl. merge at r = 0)
    assert by_subs == to_pwl(clearance(D), X, values={D: d, "r": r})


def test_subs_merges_coinciding_breakpoints():
    e = sp.Symbol("e", nonnegative=True)
    expr = H(X - D) + (X - D - e) * H(X - D - e)
    sym = to_pwl(expr, X)
    assert sym.breakpoints == (D, D + e)  # ordered non-strictly: kept distinct
    merged = sym.subs({"e": 0})
    assert merged == to_pwl(expr.subs(e, 0), X)
    assert merged.breakpoints == (D,) and merged.jumps == (1,)
    assert merged.slope_jumps == (1,)


def test_subs_rejects_reversed_order_and_bad_values():
    a, b = sp.symbols("a b")
    pwl = PiecewiseLinear(X, (a, b), (0, 1, 2), (0, 0, 0))  # order not decidable: trusted
    with pytest.raises(NonsmoothError, match="reverse the order"):
        pwl.subs({"a": 2, "b": 1})
    with pytest.raises(ParameterError, match="positive"):
        to_pwl(clearance(D), X).subs({"d": -1})
    with pytest.raises(ParameterError, match="finite"):
        to_pwl(clearance(D), X).subs({"d": float("inf")})
    with pytest.raises(ParameterError, match="variable x"):
        to_pwl(clearance(D), X).subs({"x": 1})
    # names that do not occur are ignored (a whole parameter dict may be passed)
    assert to_pwl(clearance(D), X).subs({"mu": 0.1, "d": 1, "r": 1}).breakpoints == (1,)


# ------------------------------------------------------------------------------------------
# rejections
# ------------------------------------------------------------------------------------------

V = sp.Symbol("v")
REJECTED = [
    (X**2 * H(X), "x**2*Heaviside(x)"),
    (H(X**2 - 1), "Heaviside(x**2 - 1)"),
    (sp.sign(X**2 - X) + X, "x**2 - x"),
    (sp.Abs(X) * X, "x*Abs(x)"),
    (sp.Max(X**2, 1), "Max(1, x**2)"),
    (sp.DiracDelta(X - 1), "DiracDelta(x - 1)"),
    (sp.sin(X), "sin(x)"),
    (X + sp.exp(X) * H(X), "exp(x)"),
    (2**X, "2**x"),
    (X + sp.sign(V), "sign(v)"),
    (X + sp.Function("v")(sp.Symbol("t")), "v(t)"),
    (H(X - K) + H(X - 1), "k"),
    (sp.sign(K * X), "k*x"),
    (sp.Piecewise((X, X < 1)), "undefined"),
    (sp.Piecewise((X, X**2 < 1), (0, True)), "x**2 - 1"),
    (1 / (1 + X * H(X)), "1/(x + 1)"),
]


@pytest.mark.parametrize(("expr", "text"), REJECTED, ids=[t for _, t in REJECTED])
def test_rejections(expr, text):
    with pytest.raises(NonsmoothError) as info:
        to_pwl(expr, X)
    assert text in str(info.value)
    assert not is_pwl(expr, X)


def test_rejection_messages_say_what_to_do():
    with pytest.raises(NonsmoothError, match="Fourier engine"):
        to_pwl(X + sp.DiracDelta(X), X)
    with pytest.raises(NonsmoothError, match=r"could not order .*values="):
        to_pwl(H(X - K) + H(X - 1), X)
    with pytest.raises(NonsmoothError, match="other state variables"):
        to_pwl(X * V, X, parameters=["k"])
    # the same expression is fine once the order is decidable
    assert to_pwl(H(X - K) + H(X - 1), X, values={"k": 3}).breakpoints == (1, 3)
    assert to_pwl(X * V, X, parameters=[V]).slopes == (V,)


def test_strings_are_never_parsed():
    with pytest.raises(TypeError, match="string"):
        to_pwl("Heaviside(x)", X)
    with pytest.raises(TypeError):
        to_pwl(H(X), "x")


def test_predicates():
    assert is_nonsmooth(H(X)) and is_nonsmooth(sp.DiracDelta(X)) and is_nonsmooth(sp.Max(X, 1))
    assert is_nonsmooth(sp.Piecewise((1, X > 0), (0, True)))
    assert not is_nonsmooth(X**2 + sp.sin(X))
    assert is_pwl(zou(K), X) and is_pwl(3 * X + 1, X)
    assert not is_pwl(X**2, X)
