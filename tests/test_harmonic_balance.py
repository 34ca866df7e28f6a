"""Harmonic balance with a chosen harmonic set, bias, subharmonics; PWL single harmonic + bias.

Oracles, typed independently of the code:

- one term on u'' + w0^2 u + a2 u^2 + a3 u^3 = 0: omega^2 = w0^2 + 3 a3 a^2/4 (no a2);
- bias + 2 harmonics: the Lindstedt–Poincaré omega = w0[1 + (9 a3 w0^2 - 10 a2^2) a^2/(24 w0^4)]
  and drift -a2 a^2/(2 w0^2)[1 - cos(2 omega t)/3] (docs/references.md §2);
- the exact Duffing frequency from the complete elliptic integral (mpmath);
- exact periodic orbits by shooting (perturb.simulate), for the PWL oscillator and the others.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from fractions import Fraction

import mpmath as mp
import numpy as np
import pytest
import sympy as sp

from perturb import ModelError, Oscillator, ParameterError, PerturbError, builtin_model
from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS
from perturb.fourier.trig import harmonics
from perturb.methods.harmonic_balance import (
    backbone_series,
    harmonic_balance,
    single_harmonic_balance,
)
from perturb.model.parsing import real_symbol
from perturb.numeric.balance import balance_solutions, solve_residuals
from perturb.report.latex import latex_document

omega0, alpha2, alpha3 = (real_symbol(n) for n in ("omega0", "alpha2", "alpha3"))


def _qc():
    return builtin_model("quadratic_cubic", omega0=None, alpha2=None, alpha3=None)


def _num(expr, *args):
    return sp.lambdify(args, expr, modules=[NUMERIC_IMPLEMENTATIONS, "numpy"])


# ------------------------------------------------------- quadratic + cubic: -10 vs -12 --
def test_one_term_misses_the_quadratic_term():
    hb = harmonic_balance(_qc())
    A, w = hb.amplitude, hb.frequency
    assert hb.unknowns == (w,)
    # omega^2 = w0^2 + (3/4) a3 a^2: the quadratic term only feeds the mean and 2 omega,
    # which a single cosine does not balance
    assert (
        sp.expand(hb.residuals[0] - A * (omega0**2 - w**2 + sp.Rational(3, 4) * alpha3 * A**2)) == 0
    )
    assert sp.simplify(hb.backbone**2 - (omega0**2 + sp.Rational(3, 4) * alpha3 * A**2)) == 0
    assert not any(r.has(alpha2) for r in hb.residuals)


def test_bias_plus_one_harmonic_gives_the_minus_twelve_of_the_literature_study():
    # The literature study (docs/references.md §3) notes that "one-term" harmonic balance gives
    # -12 a2^2 where Lindstedt-Poincare gives -10 a2^2. Its one term is x = A0 + A1 cos(wt)
    # (Nayfeh & Mook's M = 1 *with* the constant A0): the mean balance gives
    # A0 = -a2 a^2/(2 w0^2), which feeds 2 a2 A0 into the first harmonic, so
    # omega^2 = w0^2 + 3 a3 a^2/4 - a2^2 a^2/w0^2 and
    # omega = w0 [1 + (9 a3 w0^2 - 12 a2^2) a^2 / (24 w0^4)]. The cos(2wt) component, which
    # the ansatz cannot balance, accounts for the missing +2 a2^2 (see the next test).
    hb = harmonic_balance(_qc(), bias=True)
    series = backbone_series(hb, order=2)
    a = series.amplitude
    want = omega0 * (1 + (9 * alpha3 * omega0**2 - 12 * alpha2**2) * a**2 / (24 * omega0**4))
    assert sp.simplify(series.frequency - sp.expand(want)) == 0
    (b,) = [u for u in hb.unknowns if u.name == "b"]
    assert sp.simplify(series.unknowns[b] + alpha2 * a**2 / (2 * omega0**2)) == 0


def test_bias_plus_two_harmonics_recovers_lindstedt_poincare():
    hb = harmonic_balance(_qc(), (1, 2), bias=True)
    series = backbone_series(hb, order=2)
    a = series.amplitude
    want = omega0 * (1 + (9 * alpha3 * omega0**2 - 10 * alpha2**2) * a**2 / (24 * omega0**4))
    assert sp.simplify(series.frequency - sp.expand(want)) == 0
    # the L-P drift term -a2 a^2/(2 w0^2) [1 - cos(2 theta)/3]
    c0, a2_ = (next(u for u in hb.unknowns if u.name == n) for n in ("c_0", "a_2"))
    assert sp.simplify(series.unknowns[c0] + alpha2 * a**2 / (2 * omega0**2)) == 0
    assert sp.simplify(series.unknowns[a2_] - alpha2 * a**2 / (6 * omega0**2)) == 0


def test_multi_harmonic_projection_equals_the_trig_bookkeeping():
    # the ring-based projection against trig.harmonics on the expanded residual
    osc = Oscillator.parse(
        "x'' + mu*x' - eps*(1 - x**2)*x' + w0**2*x + a2*x**2 + a3*x**3 + c*x'**2 "
        "= P + F*cos(Omega*t) + G*cos(2*Omega*t)"
    )
    for hs, bias in (((1, 2), True), ((Fraction(1, 2), 1), True), ((1, 3), True)):
        hb = harmonic_balance(osc, hs, bias=bias)
        m = hb.options["m"]
        theta, t = real_symbol("theta"), osc.t
        x = hb.waveform.xreplace({hb.tau: m * theta})
        nu = hb.frequency / m
        rhs = osc.forcing.expr(t).xreplace({t: m * theta / hb.frequency})
        residual = (
            nu**2 * sp.diff(x, theta, 2)
            + osc.g.xreplace({osc.x: x, osc.v: nu * sp.diff(x, theta)})
            - rhs
        )
        parts = harmonics(sp.expand(residual), theta)
        want = [parts[0][0]] if bias else []
        for h in hb.options["set"]:
            c, s = parts.get(int(Fraction(h) * m), (0, 0))
            want += [c, s]
        assert len(want) == len(hb.residuals)
        for r, w in zip(hb.residuals, want, strict=True):
            assert sp.expand(r - w) == 0


# ----------------------------------------------------- Duffing: 1, 2, 3 odd harmonics --
def _exact_duffing_frequency(X: float, eps: float = 1.0) -> float:
    """x'' + x + eps x^3 = 0, x(0) = X, x'(0) = 0: T = 4 K(m)/sqrt(1 + eps X^2),
    m = eps X^2 / (2 (1 + eps X^2)) (parameter convention of mpmath.ellipk)."""
    m = eps * X**2 / (2 * (1 + eps * X**2))
    return float(mp.pi * mp.sqrt(1 + eps * X**2) / (2 * mp.ellipk(m)))


def test_elliptic_oracle_against_a_numerical_period():
    from scipy.integrate import solve_ivp

    X = np.sqrt(10.0)

    def turning(t, y):  # v crosses zero upwards at x = -X: half a period
        return y[1]

    turning.direction = 1.0
    sol = solve_ivp(
        lambda t, y: [y[1], -y[0] - y[0] ** 3],
        (0, 10),
        [X, 0.0],
        rtol=1e-12,
        atol=1e-12,
        events=turning,
    )
    half = sol.t_events[0][0]  # first velocity zero after the start: half a period
    assert abs(np.pi / half - _exact_duffing_frequency(X)) < 1e-9


def _hb_frequency_at_peak(hb, X: float) -> float:
    # x(0) = a_1 + a_3 + a_5 = X: compare at the same turning point as the exact solution
    w = hb.frequency
    guess = {u: 0.0 for u in hb.unknowns}
    guess[hb.amplitude] = X
    guess[w] = np.sqrt(1 + 0.75 * X**2)
    sol = solve_residuals(hb, guess, extra=[hb.waveform.xreplace({hb.tau: 0}) - X])
    return sol[w]


def test_odd_harmonics_on_duffing_converge_to_the_elliptic_frequency():
    # Measured relative errors of omega at eps X^2 = 0.1, 1, 10 (X = turning point):
    #   1 harmonic:  1.0e-4, 3.9e-3, 1.7e-2
    #   2 (1, 3):    5.9e-7, 1.4e-4, 1.3e-3
    #   3 (1, 3, 5): 1.7e-9, 2.5e-6, 5.1e-5
    osc = Oscillator.parse("x'' + x + eps*x**3 = 0", {"eps": 1.0})
    hbs = [harmonic_balance(osc, hs) for hs in ((1,), (1, 3), (1, 3, 5))]
    bounds = {0.1: (2e-4, 1e-6, 1e-8), 1.0: (5e-3, 2e-4, 5e-6), 10.0: (2e-2, 2e-3, 1e-4)}
    for eps_x2, bound in bounds.items():
        X = np.sqrt(eps_x2)
        exact = _exact_duffing_frequency(X)
        errors = [abs(_hb_frequency_at_peak(hb, X) / exact - 1) for hb in hbs]
        assert errors[0] > errors[1] > errors[2], (eps_x2, errors)
        assert all(e < b for e, b in zip(errors, bound, strict=True)), (eps_x2, errors)


# --------------------------------------------------------------- self-excited oscillator --
def test_van_der_pol_by_harmonic_balance():
    # one harmonic: a = 2, omega = 1 for every eps; (1, 3, 5) at eps = 1 against the exact
    # limit cycle (shooting): omega 0.942942 vs 0.942956, first harmonic 2.01485 vs 2.01491
    from perturb.simulate.flows.base import ODEFlow
    from perturb.simulate.orbits.shooting import limit_cycle

    hb1 = harmonic_balance(builtin_model("vanderpol"))
    A, w = hb1.amplitude, hb1.frequency
    assert set(sp.solve(hb1.residuals, [A, w], dict=True)[0].items()) == {(A, 2), (w, 1)}
    osc = builtin_model("vanderpol", eps=1.0)
    hb = harmonic_balance(osc, (1, 3, 5))
    guess = {u: 0.0 for u in hb.unknowns}
    guess[hb.amplitude], guess[hb.frequency] = 2.0, 1.0
    sol = solve_residuals(hb, guess)
    orbit = limit_cycle(ODEFlow(osc), [2.0, 0.0], 2 * np.pi)
    assert abs(sol[hb.frequency] / (2 * np.pi / orbit.period) - 1) < 3e-5
    assert abs(sol[hb.amplitude] / orbit.first_harmonic_amplitude - 1) < 1e-4


# ------------------------------------------------------------------------- subharmonics --
def test_one_third_subharmonic_of_duffing_against_shooting():
    # x'' + 0.02 x' + x + x^3 = 10 cos(4.5 t): a stable period-3 orbit. Harmonics 1/3 and 1
    # of the forcing; measured: HB peak 1.37282 vs exact 1.37722 (0.3 %), forced component
    # 0.57571 vs 0.57581.
    from perturb.simulate.flows.base import ODEFlow
    from perturb.simulate.orbits.shooting import periodic_orbit

    W = 4.5
    osc = builtin_model("duffing", mu=0.02, alpha=1.0, F=10.0, Omega=W)
    hb = harmonic_balance(osc, (Fraction(1, 3), 1))
    assert hb.options["m"] == 3 and len(hb.unknowns) == 4
    names = {u.name: u for u in hb.unknowns}
    guess = {u: 0.0 for u in hb.unknowns}
    guess[names["a_{1/3}"]], guess[names["a_1"]] = 1.3, -10 / (W**2 - 1)
    sol = solve_residuals(hb, guess)
    wave = sp.lambdify(hb.tau, hb.waveform.xreplace(dict(sol)))
    dwave = sp.lambdify(hb.tau, W * sp.diff(hb.waveform.xreplace(dict(sol)), hb.tau))
    orbit = periodic_orbit(ODEFlow(osc), [float(wave(0.0)), float(dwave(0.0))], m=3)
    assert orbit.stability == "stable"
    peak = np.max(np.abs(wave(np.linspace(0, 6 * np.pi, 6001))))
    assert abs(peak / orbit.amplitude - 1) < 5e-3
    forced = np.hypot(sol[names["a_1"]], sol[names["b_1"]])
    assert abs(forced / orbit.first_harmonic_amplitude - 1) < 1e-3
    assert abs(sol[names["a_{1/3}"]]) > 1.0  # a genuine subharmonic


# -------------------------------------------------- single harmonic (+ bias), closed form --
@pytest.mark.parametrize("model", ["duffing", "nsd", "deadzone", "saturation"])
def test_single_harmonic_matches_single_harmonic_balance(model):
    osc = builtin_model(model)
    new, old = harmonic_balance(osc), single_harmonic_balance(osc)
    assert new.unknowns == old.unknowns and new.slow_flow is not None
    subs = {s: v for s, v in osc.substitutions().items() if s != old.frequency}
    args = (*old.unknowns, old.frequency)
    rng = np.random.default_rng(3)
    pts = rng.uniform([0.05, -3.0, 0.2], [8.0, 3.0, 2.5], size=(60, 3)).T
    for f_new, f_old in zip(new.residuals, old.residuals, strict=True):
        a = _num(f_new.xreplace(subs), *args)(*pts)
        b = _num(f_old.xreplace(subs), *args)(*pts)
        assert np.allclose(a, b, atol=1e-12)
    W = sp.Symbol("W")
    for c_new, c_old in zip(new.frequency_polynomial, old.frequency_polynomial, strict=True):
        assert np.allclose(
            _num(c_new.xreplace(subs), new.amplitude, W)(pts[0], pts[2]),
            _num(c_old.xreplace(subs), old.amplitude, W)(pts[0], pts[2]),
            atol=1e-10,
        )


def test_single_harmonic_frequency_response_is_the_lead_one():
    from perturb.numeric.amplitude import approximation_response

    osc = builtin_model("nsd")
    kw = {"points": 300, "stability": "slow_flow"}
    r_new = approximation_response(harmonic_balance(osc), (0.3, 2.0), **kw)
    r_old = approximation_response(single_harmonic_balance(osc), (0.3, 2.0), **kw)
    assert len(r_new.branches) == len(r_old.branches)
    for b1, b2 in zip(r_new.branches, r_old.branches, strict=True):
        assert np.allclose(b1.omega, b2.omega) and np.allclose(b1.amplitude, b2.amplitude)


def test_pwl_bias_coefficients_in_closed_form():
    hb = harmonic_balance(builtin_model("nsd"), bias=True)
    A, b, phi = hb.unknowns
    assert [u.name for u in hb.unknowns] == ["A", "b", "phi"]
    assert hb.slow_flow is None  # the bias has second-order dynamics: no first-order slow flow
    text = "\n".join(str(s) for s in hb.steps)
    assert "acos((-b - 1)/A)" in text and "acos((1 - b)/A)" in text
    # the mean balance is free of the frequency and, at b = 0, vanishes (odd force)
    assert not hb.residuals[0].has(hb.frequency)
    mean_at_zero = _num(hb.residuals[0].xreplace({b: 0, real_symbol("k"): -2.0}), A)
    assert np.max(np.abs(mean_at_zero(np.geomspace(0.01, 50, 200)))) < 1e-13
    # linear regime inside one well: x > 1 all the time, f = x - (1 - k): g_0 = b - (1 - k)
    g0 = _num(hb.residuals[0].xreplace({real_symbol("k"): -2.0}), A, b)
    assert abs(g0(0.5, 3.2) - 0.2) < 1e-14


NSD = {"k": -2.0, "mu": 0.05}


def test_nsd_bias_at_the_brief_parameters():
    # k = -2, mu = 0.05, F = 2, Omega = 0.4 (the parameters of the brief, after Fig. 14).
    # Measured: no stable orbit around one well exists there (the exact search, with the
    # balance solutions as extra guesses, finds only unstable in-well pairs), and the balance
    # solutions' biases are all 0 (|b| < 1e-12). At F = 2 the in-well static response already
    # reaches the snap-through point x = 1 (f(1) = -2 = -F). Besides the symmetric orbits the
    # exact search finds a stable pair with mean +-1.038 (first harmonic 6.197, max|x|
    # 10.216) that single harmonic + bias does not produce. Errors of the symmetric ones
    # (first harmonic):
    #   saddle orbit in |x| < 1   0.925886 vs 0.925886 (exact: a linear segment)
    #   middle orbit              1.961257 vs 1.519634 (29 %)
    #   large orbit               6.906613 vs 6.716416 (2.8 %; HB calls it stable, the exact
    #                             symmetric orbit is unstable and its stable neighbours are
    #                             the asymmetric pair, 11 % lower in first harmonic)
    from perturb.solve import periodic_orbits

    osc = builtin_model("nsd", F=2.0, **NSD)
    sols = balance_solutions(harmonic_balance(osc, bias=True), 0.4)
    assert [round(s.amplitude, 4) for s in sols] == [0.9259, 1.9613, 6.9066]
    assert max(abs(s.bias) for s in sols) < 1e-12
    guesses = [
        (s.bias + s.amplitude * np.cos(s.phase), 0.4 * s.amplitude * np.sin(s.phase)) for s in sols
    ]
    exact = periodic_orbits(osc, 0.4, guesses=guesses)
    # The all-orbits search (since it also seeds from linear segments) finds unstable in-well
    # pairs too (mean +-2.444 and +-2.284, each checked to close over a period by DOP853),
    # which one harmonic plus bias does not produce either; no stable orbit sits in one well.
    assert not any(abs(o.mean) > 2 and o.stability == "stable" for o in exact)
    symmetric = sorted(o.first_harmonic_amplitude for o in exact if abs(o.mean) < 1e-8)
    assert abs(sols[0].amplitude - symmetric[0]) < 1e-10
    assert abs(sols[2].amplitude / symmetric[-1] - 1) < 0.03
    asym = [o for o in exact if abs(o.mean) > 0.5 and o.stability == "stable"]
    assert len(asym) == 2 and all(o.stability == "stable" for o in asym)
    assert abs(abs(asym[0].mean) - 1.038) < 1e-3


def test_nsd_in_well_orbits_with_bias():
    # Same k, mu, Omega with F = 1.5: the balance finds the orbits around each well,
    # b = +-(1 - k) = +-3 exactly and A = F/|1 - Omega^2 + i mu Omega| = 1.785208 (they never
    # reach x = 1, so the outer linear segment makes them exact), stable; and a pair of
    # unstable in-well orbits crossing into the negative-stiffness segment (b = +-2.776,
    # A = 2.294) near the separatrix, where one harmonic is a poor description.
    from perturb.solve import periodic_orbits

    F, W = 1.5, 0.4
    osc = builtin_model("nsd", F=F, **NSD)
    sols = balance_solutions(harmonic_balance(osc, bias=True), W)
    wells = [s for s in sols if abs(abs(s.bias) - 3.0) < 1e-9]
    assert len(wells) == 2 and {np.sign(s.bias) for s in wells} == {-1.0, 1.0}
    linear = F / abs(complex(1 - W**2, 0.05 * W))
    assert all(abs(s.amplitude - linear) < 1e-10 and s.stable for s in wells)
    crossing = [s for s in sols if 2.0 < abs(s.bias) < 2.9]
    assert len(crossing) == 2 and not any(s.stable for s in crossing)
    assert all(
        s.bias - s.amplitude < 1 if s.bias > 0 else s.bias + s.amplitude > -1 for s in crossing
    )
    # the stable in-well pair (the search also finds unstable in-well orbits, mean +-2.898,
    # +-2.455, +-2.018, which close over a period under DOP853 to 1e-6 or better)
    exact = [o for o in periodic_orbits(osc, W) if abs(o.mean) > 2 and o.stability == "stable"]
    assert len(exact) == 2
    for o in exact:
        (s,) = [s for s in wells if np.sign(s.bias) == np.sign(o.mean)]
        assert abs(o.mean - s.bias) < 1e-8 and abs(o.first_harmonic_amplitude - s.amplitude) < 1e-8
        assert o.stability == "stable"


def test_static_load_bias_on_a_polynomial_oscillator():
    # x'' + 0.1 x' + x + x^3 = 0.5 + 0.3 cos(1.4 t). Exact orbit (shooting): first harmonic
    # 1.18308, mean 0.13659. One harmonic + bias: 1.20696, 0.15579 (2.0 %, 0.019);
    # (1, 2, 3) + bias: 1.18349, 0.13682 (0.03 %, 2.3e-4).
    from perturb.simulate.flows.base import ODEFlow
    from perturb.simulate.orbits.shooting import periodic_orbit

    W = 1.4
    osc = Oscillator.parse(
        "x'' + mu*x' + x + x**3 = P + F*cos(Omega*t)", {"mu": 0.1, "P": 0.5, "F": 0.3, "Omega": W}
    )
    (s,) = balance_solutions(harmonic_balance(osc, bias=True))
    assert s.stable
    orbit = periodic_orbit(
        ODEFlow(osc), [s.bias + s.amplitude * np.cos(s.phase), W * s.amplitude * np.sin(s.phase)]
    )
    assert abs(s.amplitude / orbit.first_harmonic_amplitude - 1) < 0.025
    assert abs(s.bias - orbit.mean) < 0.025
    hb3 = harmonic_balance(osc, (1, 2, 3), bias=True)
    names = {u.name: u for u in hb3.unknowns}
    guess = {u: 0.0 for u in hb3.unknowns}
    guess[names["c_0"]] = s.bias
    guess[names["a_1"]], guess[names["b_1"]] = (
        s.amplitude * np.cos(s.phase),
        s.amplitude * np.sin(s.phase),
    )
    sol = solve_residuals(hb3, guess)
    first = np.hypot(sol[names["a_1"]], sol[names["b_1"]])
    assert abs(first / orbit.first_harmonic_amplitude - 1) < 1e-3
    assert abs(sol[names["c_0"]] - orbit.mean) < 2e-3


# --------------------------------------------------------------------------- errors --
def test_errors_name_the_problem():
    with pytest.raises(ModelError, match="polynomial"):
        harmonic_balance(builtin_model("nsd"), (1, 3))
    with pytest.raises(ParameterError):
        harmonic_balance(builtin_model("duffing"), (0,))
    with pytest.raises(ParameterError):
        harmonic_balance(builtin_model("duffing"), (1, 1))
    with pytest.raises(ParameterError, match="fundamental"):
        harmonic_balance(_qc(), (Fraction(1, 2), 1))
    with pytest.raises(ModelError, match="static load"):
        harmonic_balance(Oscillator.parse("x'' + x + x**3 = 1 + cos(Omega*t)"))
    with pytest.raises(ModelError, match="parametric"):
        harmonic_balance(builtin_model("mathieu"))
    with pytest.raises(PerturbError):
        backbone_series(harmonic_balance(builtin_model("duffing")))
    with pytest.raises(PerturbError):
        balance_solutions(harmonic_balance(_qc()))
    with pytest.raises(ParameterError):
        solve_residuals(harmonic_balance(builtin_model("duffing")), {"A": 1.0})


def test_results_are_immutable():
    hb = harmonic_balance(_qc(), (1, 2), bias=True)
    with pytest.raises(TypeError):
        hb.fourier["x"] = 0  # type: ignore[index]
    series = backbone_series(hb)
    with pytest.raises(TypeError):
        series.unknowns[hb.unknowns[0]] = 0  # type: ignore[index]


def test_approximations_serialise_and_read_back():
    import json

    from perturb.io.serialize import approximation_from_dict, approximation_to_dict

    for hb in (
        harmonic_balance(builtin_model("nsd"), bias=True),
        harmonic_balance(builtin_model("duffing"), (Fraction(1, 3), 1)),
        harmonic_balance(_qc(), (1, 2), bias=True),
    ):
        data = json.loads(json.dumps(approximation_to_dict(hb)))
        back = approximation_from_dict(data, hb.oscillator)
        assert back.residuals == hb.residuals and back.steps == hb.steps


# ---------------------------------------------------------------------------- LaTeX --
def _pdflatex():
    exe = shutil.which("pdflatex")
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("pdflatex is missing in CI: .ci/run must install texlive")
        pytest.skip("pdflatex not installed")
    return exe


@pytest.mark.parametrize(
    "make",
    [
        lambda: harmonic_balance(builtin_model("nsd"), bias=True),
        lambda: harmonic_balance(Oscillator.parse("x'' + x + eps*x**3 = 0"), (1, 3, 5)),
        lambda: harmonic_balance(builtin_model("duffing"), (Fraction(1, 3), 1)),
        lambda: harmonic_balance(_qc(), (1, 2), bias=True),
        lambda: harmonic_balance(builtin_model("vanderpol")),
    ],
    ids=["nsd-bias", "duffing-135", "subharmonic", "qc-bias-12", "vanderpol"],
)
def test_harmonic_balance_derivations_compile(make, tmp_path):
    exe = _pdflatex()
    tex = tmp_path / "doc.tex"
    latex_document(make(), tex)
    proc = subprocess.run(
        [exe, "-interaction=nonstopmode", "-halt-on-error", tex.name],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout[-3000:]
