"""Every method checks that it applies before it answers (issue 18, items 1, 2, 3, 3a, 16, 17).

Oracles are independent of the methods: periodic orbits of the equation of motion by shooting
on ``scipy.integrate.solve_ivp`` (DOP853, rtol 1e-11) and the closed-form response of the
linear oscillator ``x'' + mu x' + x = F0 + F cos(Omega t)``: mean ``F0``, first harmonic
``F / |1 - Omega^2 + i mu Omega|``.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

from perturb import ModelError, Oscillator, ParameterError
from perturb.errors import ParseError
from perturb.methods import METHODS, harmonic_balance, single_harmonic_balance
from perturb.methods.applicability import ORDER_LIMITS, even_part, is_odd
from perturb.methods.averaging import (
    equivalent_linearisation,
    fourier_components,
    krylov_bogoliubov,
)
from perturb.methods.lindstedt import lindstedt_poincare
from perturb.methods.multiple_scales import modulation_equations
from perturb.model.parsing import real_symbol
from perturb.numeric.amplitude import approximation_response as traced
from perturb.numeric.balance import solve_residuals
from perturb.solve import frequency_response

# the user's equation of issue 18 item 1: numeric coefficients, no named parameter
ONE_SIDED = "x'' + 0.1*x' + x + 4*(x-0.5)*Heaviside(x-0.5) = 0.8*cos(Omega*t)"
TWO_SIDED = (
    "x'' + 0.1*x' + x + 4*((x-0.5)*Heaviside(x-0.5) + (x+0.5)*Heaviside(-x-0.5)) = 0.3*cos(Omega*t)"
)
WEAK_DUFFING = "x'' + 0.1*x' + x + 0.05*x**3 = 0.3*cos(Omega*t)"
HOSTILE = "__import__('os').system('echo pwned')"


# ------------------------------------------------------------------------------ oracle --
def exact_peak(force, mu, F, W, F0=0.0, x0=(0.0, 0.0)):
    """max |x| and mean of the periodic orbit of ``x'' + mu x' + force(x) = F0 + F cos(W t)``
    reached from ``x0`` (shooting on solve_ivp, DOP853, rtol 1e-11)."""
    T = 2 * np.pi / W

    def rhs(t, y):
        return [y[1], -mu * y[1] - force(y[0]) + F0 + F * np.cos(W * t)]

    def flow(y0, t1=T, dense=False):
        return solve_ivp(
            rhs, (0.0, t1), y0, method="DOP853", rtol=1e-11, atol=1e-12, dense_output=dense
        )

    settle = flow(list(x0), t1=T * math.ceil(12.0 / (mu * T)))  # about 6 time constants
    with warnings.catch_warnings():  # "not making good progress" at the ODE's noise level
        warnings.simplefilter("ignore", RuntimeWarning)
        y0 = fsolve(lambda y: flow(y).y[:, -1] - y, settle.y[:, -1], xtol=1e-12)
    sol = flow(y0, dense=True)
    assert np.max(np.abs(sol.y[:, -1] - y0)) < 1e-8
    xs = sol.sol(np.linspace(0.0, T, 4001))[0]
    return float(np.max(np.abs(xs))), float(np.mean(xs[:-1]))


def value_at(resp, W):
    """max |x| of every branch of ``resp`` passing through ``W`` (linear interpolation)."""
    out = []
    for br in resp.branches:
        w, a = br.omega, br.amplitude
        for j in np.nonzero((w[:-1] - W) * (w[1:] - W) <= 0)[0]:
            t = 0.0 if w[j + 1] == w[j] else (W - w[j]) / (w[j + 1] - w[j])
            out.append(a[j] + t * (a[j + 1] - a[j]))
    return out


def one_sided(x):
    return x + 4 * (x - 0.5) * (x > 0.5)


def two_sided(x):
    return x + 4 * ((x - 0.5) * (x > 0.5) + (x + 0.5) * (x < -0.5))


# ----------------------------------------------------- item 1: no named parameters at all --
def test_the_users_one_sided_equation_is_a_model_error_not_a_type_error():
    osc = Oscillator.parse(ONE_SIDED)
    assert not [v for v in osc.params.values() if v is not None]
    for call in (
        lambda: single_harmonic_balance(osc),
        lambda: frequency_response(osc, "hb1", (0.5, 2.0)),
    ):
        with pytest.raises(ModelError, match="not odd") as err:
            call()
        msg = str(err.value)
        assert "'hb'" in msg and "'exact'" in msg and "bias=True" in msg


@pytest.mark.parametrize("method", ["hb1", "hb", "kb", "vdp", "ms", "mlp"])
def test_every_forced_method_answers_a_model_without_named_parameters(method):
    """Weak Duffing with numeric coefficients only: every method within 2 % of the exact
    orbit (multiple scales, a primary-resonance expansion, within 4 % near resonance)."""
    osc = Oscillator.parse(WEAK_DUFFING)
    options = {"harmonics": 5} if method == "hb" else {}
    resp = frequency_response(osc, method, (0.5, 1.8), **options)
    assert resp.branches
    for W in (0.92, 1.08) if method == "ms" else (0.6, 1.6):
        ref, _ = exact_peak(lambda x: x + 0.05 * x**3, 0.1, 0.3, W)
        got = value_at(resp, W)
        assert got, (method, W)
        tol = 4e-2 if method == "ms" else 2e-2  # measured: ms 2.8 % at 0.92, others <= 0.6 %
        assert min(abs(g - ref) / ref for g in got) < tol, (method, W, got, ref)


def test_odd_piecewise_linear_force_without_parameters_against_the_exact_orbit():
    """The odd two-sided stop with numeric coefficients (the `_is_odd` path that crashed):
    hb1 answers, within 3 % of the exact orbit off resonance (one harmonic, stiff stops)."""
    osc = Oscillator.parse(TWO_SIDED)
    resp = traced(single_harmonic_balance(osc), (0.4, 3.0))
    for W in (0.5, 2.8):
        ref, mean = exact_peak(two_sided, 0.1, 0.3, W)
        assert abs(mean) < 1e-6
        got = value_at(resp, W)
        assert got and min(abs(g - ref) / ref for g in got) < 3e-2, (W, got, ref)


def test_free_methods_without_named_parameters():
    """Free x'' + x + 0.1 x^3 = 0 at amplitude 1: L-P order 3, mLP order 2 and K-B against the
    exact frequency 2 pi / period (period by quadrature of the energy integral)."""
    from scipy.integrate import quad

    osc = Oscillator.parse("x'' + x + 0.1*x**3 = 0")

    def V(x):
        return x * x / 2 + 0.1 * x**4 / 4

    period = 4 * quad(lambda s: 1 / math.sqrt(2 * (V(1.0) - V(s))), 0, 1.0, limit=200)[0]
    exact = 2 * math.pi / period
    lp = lindstedt_poincare(osc, 3, amplitude="initial")
    w_lp = float(lp.backbone.xreplace({lp.amplitude: 1}))
    assert abs(w_lp - exact) / exact < 1e-4
    mlp = METHODS["mlp"](osc, order=2, amplitude="initial")
    w_mlp = float(mlp.backbone.xreplace({mlp.amplitude: 1}))
    assert abs(w_mlp - exact) / exact < 1e-3
    kb = krylov_bogoliubov(osc)
    w_kb = float(kb.backbone.xreplace({kb.amplitude: 1}))
    assert abs(w_kb - exact) / exact < 5e-3


# ----------------------------------------------------------- item 2: forces that are not odd --
@pytest.mark.parametrize(
    "equation",
    [ONE_SIDED, "x'' + 0.02*x' + x + 9*(x-1)*Heaviside(x-1) = 0.5*cos(Omega*t)"],
)
@pytest.mark.parametrize("method", ["hb1", "kb", "vdp", "ms", "mlp"])
def test_zero_mean_methods_refuse_a_one_sided_spring_and_name_what_applies(method, equation):
    """Issue 18 item 2: max relative errors 12.7 and 122 against the exact response."""
    osc = Oscillator.parse(equation)
    with pytest.raises(ModelError, match="not odd") as err:
        METHODS[method](osc)
    msg = str(err.value)
    assert "does not apply" in msg and "'hb'" in msg and "'exact'" in msg, msg


@pytest.mark.parametrize(
    "equation",
    [
        "x'' + x + 4*(x-0.5)*Heaviside(x-0.5) = 0",  # one-sided stop, free
        "x'' + x + 3*x*Heaviside(x) = 0",  # bilinear
        "x'' + x + 0.5*Abs(x) = 0",  # even
    ],
)
def test_lindstedt_poincare_refuses_free_one_sided_forces(equation):
    with pytest.raises(ModelError, match="not odd"):
        lindstedt_poincare(Oscillator.parse(equation), 1)
    with pytest.raises(ModelError, match="not odd"):
        METHODS["mlp"](Oscillator.parse(equation), 1)


def test_symbolic_hb_without_bias_refuses_and_with_bias_answers():
    osc = Oscillator.parse(ONE_SIDED)
    with pytest.raises(ModelError, match="bias=True"):
        harmonic_balance(osc)
    assert len(harmonic_balance(osc, (1,), bias=True).unknowns) == 3


def test_what_the_message_recommends_is_right_on_the_one_sided_spring():
    """Numeric HB (the recommended method) against the exact orbit, where first-order mLP was
    off by 12.7 (its fold at Omega 1.57-1.67 does not exist; the exact peak is near 1.35)."""
    osc = Oscillator.parse(ONE_SIDED)
    resp = frequency_response(osc, "hb", (0.9, 2.0))
    for W in (1.0, 1.35, 1.9):
        ref, mean = exact_peak(one_sided, 0.1, 0.8, W)
        got = value_at(resp, W)
        assert got and min(abs(g - ref) / ref for g in got) < 5e-3, (W, got, ref)
        if W < 1.5:  # the orbit reaches the stop and is off centre: what zero-mean methods miss
            assert mean < -0.05, (W, mean)


def test_even_part_classification():
    assert even_part(Oscillator.parse(WEAK_DUFFING)) == frozenset()
    assert even_part(Oscillator.parse(TWO_SIDED)) == frozenset()
    assert even_part(Oscillator.parse(ONE_SIDED)) == {"nonsmooth"}
    assert even_part(Oscillator.parse("x'' + x + 0.3*x**2 = 0")) == {"polynomial"}
    assert even_part(Oscillator.parse("x'' + x = 0.2 + cos(Omega*t)")) == {"load"}
    # Coulomb friction and quadratic damping are odd in (x, x')
    coulomb = Oscillator.parse("x'' + 0.1*x' + x + 0.2*sign(x') + 0.1*x'*Abs(x') = cos(Omega*t)")
    assert even_part(coulomb) == frozenset()
    # a symbolic even coefficient with the value 0 is no even part
    assert even_part(Oscillator.parse("x'' + x + a*x**2 = 0", {"a": 0.0})) == frozenset()
    x = real_symbol("x")
    assert is_odd(sp.sign(x) * sp.Abs(x) ** 3, (x,), {})
    assert not is_odd(sp.Heaviside(x - 1), (x,), None)


def test_polynomial_even_part_is_kept_for_perturbation_methods_with_a_note():
    """x^2 enters the frequency at second order: the first-order methods answer (the course
    compares them on it) but the response says what they leave out; hb1 refuses."""
    osc = Oscillator.parse("x'' + 0.1*x' + x + 0.3*x**2 = 0.1*cos(Omega*t)")
    with pytest.raises(ModelError, match="not odd"):
        single_harmonic_balance(osc)
    resp = frequency_response(osc, "kb", (0.5, 2.0))
    assert resp.branches and any("even polynomial part" in n for n in resp.notes)


# ---------------------------------------------------------------- item 3a: a static load --
def test_static_load_refused_by_mlp_ms_kb_and_numeric_hb_is_the_closed_form():
    osc = Oscillator.parse("x'' + mu*x' + x = 0.2 + 0.8*cos(Omega*t)", {"mu": 0.05})
    for method in ("mlp", "ms", "kb", "vdp", "hb1"):
        with pytest.raises(ModelError, match="static load") as err:
            METHODS[method](osc)
        assert "'hb'" in str(err.value)
    resp = frequency_response(osc, "hb", (0.5, 1.8))
    (br,) = resp.branches
    first = 0.8 / np.abs(1 - br.omega**2 + 0.05j * br.omega)
    assert br.omega.min() == pytest.approx(0.5) and br.omega.max() == pytest.approx(1.8)
    assert np.max(np.abs(br.amplitude - (0.2 + first))) < 1e-8
    assert np.max(np.abs(br.mean - 0.2)) < 1e-9


def test_lindstedt_poincare_static_load_is_exact_on_the_linear_oscillator():
    lp = lindstedt_poincare(Oscillator.parse("x'' + x = 0.2"), 3)
    assert sp.simplify(lp.backbone - 1) == 0
    tau = lp.tau
    assert sp.simplify(lp.waveform - (lp.amplitude * sp.cos(tau) + sp.Rational(1, 5))) == 0


# --------------------------------------------------------- item 3: notes on what is missing --
def test_undamped_forced_response_carries_a_stability_note():
    undamped = Oscillator.parse("x'' + x + 0.1*x**3 = 0.3*cos(Omega*t)")
    resp = traced(single_harmonic_balance(undamped), (0.5, 2.0))
    assert resp.branches
    assert any("no damping" in n and "marginal" in n for n in resp.notes)
    damped = Oscillator.parse(WEAK_DUFFING)
    assert not any("no damping" in n for n in traced(single_harmonic_balance(damped)).notes)
    # a damping parameter with the value 0 is undamped too
    zero = Oscillator.parse("x'' + mu*x' + x = cos(Omega*t)", {"mu": 0.0})
    assert any("no damping" in n for n in traced(single_harmonic_balance(zero)).notes)


def test_zero_branches_come_with_a_reason():
    approx = single_harmonic_balance(Oscillator.parse(WEAK_DUFFING))
    resp = traced(approx, (0.5, 2.0), amplitude_range=(50.0, 60.0))
    assert not resp.branches
    assert resp.notes and "0 branches" in resp.notes[0] and "window" in resp.notes[0]


# ------------------------------------------------------ item 17: a window near Omega = 0 --
def test_tiny_frequency_window_is_answered_by_the_closed_form():
    """Omega in [1e-9, 1e-8]: Omega^2 is below the rounding of the amplitude equation; the
    linear oscillator's response there is F / |1 - W^2 + i mu W| (quasi-static)."""
    osc = Oscillator.parse("x'' + 0.1*x' + x = 0.5*cos(Omega*t)")
    resp = traced(single_harmonic_balance(osc), (1e-9, 1e-8))
    assert len(resp.branches) == 1 and any("fixed frequencies" in n for n in resp.notes)
    br = resp.branches[0]
    exact = 0.5 / np.abs(1 - br.omega**2 + 0.1j * br.omega)
    assert np.max(np.abs(br.amplitude - exact)) < 1e-10
    assert br.omega.min() == pytest.approx(1e-9) and br.omega.max() == pytest.approx(1e-8)


# ------------------------------------------------------------- item 16: bounded orders --
@pytest.mark.parametrize("method", ["mlp", "ms", "lp"])
def test_huge_orders_are_refused_at_once_naming_the_maximum(method):
    osc = Oscillator.parse("x'' + x + 0.1*x**3 = 0")
    t0 = time.perf_counter()
    with pytest.raises(ParameterError) as err:
        METHODS[method](osc, order=50)
    assert time.perf_counter() - t0 < 5
    msg = str(err.value)
    assert "50" in msg and str(ORDER_LIMITS[method]) in msg


def test_symbolic_hb_harmonic_count_is_bounded():
    osc = Oscillator.parse(WEAK_DUFFING)
    top = ORDER_LIMITS["hb"]
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=f"number of harmonics = {top + 1}.*at most {top}"):
        harmonic_balance(osc, tuple(range(1, 2 * top + 2, 2)))
    assert time.perf_counter() - t0 < 5


# ------------------------------------------------ item 14: caller strings, never sympify --
def test_averaging_functions_parse_strings_safely():
    x, v = real_symbol("x"), real_symbol("x'")
    a = sp.Symbol("a", positive=True)
    comps = fourier_components("x**3", x, v, a, "2", 0, (1,))
    assert sp.simplify(comps[1][0] - sp.Rational(3, 4) * a**3) == 0
    eq = equivalent_linearisation("x**3")
    assert sp.simplify(eq.stiffness - sp.Rational(3, 4) * eq.amplitude**2) == 0
    free = Oscillator.parse("x'' + x + 0.1*x**3 = 0")
    kb = krylov_bogoliubov(free, generating_frequency="1")
    assert sp.simplify(kb.backbone - (1 + sp.Rational(3, 80) * kb.amplitude**2)) == 0
    for call in (
        lambda: fourier_components(HOSTILE, x, v, a, 1),
        lambda: fourier_components("x**3", x, v, HOSTILE, 1),
        lambda: equivalent_linearisation(HOSTILE),
        lambda: krylov_bogoliubov(free, generating_frequency=HOSTILE),
        lambda: modulation_equations(Oscillator.parse(WEAK_DUFFING), 1).in_frequency(HOSTILE),
    ):
        with pytest.raises(ParseError):
            call()
    with pytest.raises(ParameterError, match="type"):
        fourier_components(object(), x, v, a, 1)


def test_solve_residuals_extra_equations_go_through_the_parser():
    free = harmonic_balance(Oscillator.parse("x'' + x + 0.1*x**3 = 0"))
    with pytest.raises(ParseError):
        solve_residuals(free, {"omega": 1.0, "A": 1.0}, extra=[HOSTILE])


def test_trig_harmonics_parses_strings_safely():
    from perturb.fourier.trig import harmonics

    psi = real_symbol("psi")
    assert harmonics("3*cos(2*psi) + 1", psi) == {0: (1, 0), 2: (3, 0)}
    with pytest.raises(ParseError):
        harmonics(HOSTILE, psi)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["mlp", "ms", "lp", "hb"])
def test_a_derivation_at_its_order_limit_finishes(method):
    """The bound is not only a refusal: at the limit the derivation answers in bounded time
    (measured 2.4-14 s cold on the loaded two-core machine; 60 s leaves room for load)."""
    top = ORDER_LIMITS[method]
    t0 = time.perf_counter()
    if method == "lp":
        approx = lindstedt_poincare(Oscillator.parse("x'' + x + 0.3*x**3 + 0.2*x**2 = 0"), top)
    elif method == "hb":
        approx = harmonic_balance(Oscillator.parse(WEAK_DUFFING), tuple(range(1, 2 * top, 2)))
    else:
        approx = METHODS[method](Oscillator.parse(WEAK_DUFFING), order=top)
    assert approx.residuals
    assert time.perf_counter() - t0 < 60


def test_lindstedt_poincare_static_load_on_a_nonlinear_force_converges_to_the_exact_period():
    """x'' + x + 0.3 x^3 = 0.2 (free, off-centre): L-P expands the load with the other terms.
    Exact period of the orbit through L-P's turning point x(0) (DOP853 to the next turning
    point and back); measured relative frequency errors 1.5e-2, 1.4e-2, 3.6e-3, 7.5e-5 at
    orders 1-4 (first-harmonic amplitude 0.5)."""
    osc = Oscillator.parse("x'' + x + 0.3*x**3 = 0.2")
    errors = []
    for order in (1, 4):
        lp = lindstedt_poincare(osc, order)
        at = {lp.amplitude: sp.Rational(1, 2)}
        w_lp = float(lp.backbone.xreplace(at))
        x0 = float(lp.waveform.xreplace({**at, lp.tau: 0}))

        def rhs(t, y):
            return [y[1], 0.2 - y[0] - 0.3 * y[0] ** 3]

        def turning(t, y):
            return y[1]

        turning.direction = 1  # the minimum, half a period later
        sol = solve_ivp(rhs, (0, 50), [x0, 0.0], events=turning, rtol=1e-12, atol=1e-12)
        errors.append(abs(math.pi / sol.t_events[0][0] - w_lp) / w_lp)
    assert errors[1] < 2e-4 and errors[0] > 10 * errors[1], errors
