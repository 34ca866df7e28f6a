"""Lindstedt–Poincaré: the classic results typed independently, the series of the exact
elliptic-integral frequency of Duffing's equation, exact periods of polynomial and PWL
oscillators, and the derivation documents."""

from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess

import mpmath as mp
import numpy as np
import pytest
import sympy as sp

from perturb.errors import ModelError, ParameterError
from perturb.methods.lindstedt import AMPLITUDES, lindstedt_poincare
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import real_symbol
from perturb.numeric.compile import bind_parameters, lambdify
from perturb.report.latex import latex_document
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.orbits.shooting import limit_cycle

A = sp.Symbol("A", positive=True)
eps, w0 = real_symbol("eps"), real_symbol("omega0")
lam, m = sp.symbols("lambda m", positive=True)


# ------------------------------------------------------------------ the exact Duffing series --
def _duffing_series(order: int) -> dict[str, list[sp.Rational]]:
    r"""Coefficients c_j of omega/omega0 = sum_j c_j lambda^j, lambda = eps a^2/omega0^2, for
    x'' + omega0^2 x + eps x^3 = 0, from the exact solution x = A cn(sqrt(omega0^2 + eps A^2) t
    | m), m = eps A^2 / (2 (omega0^2 + eps A^2)):

    - period 4K(m)/sqrt(omega0^2 + eps A^2), so omega = pi sqrt(omega0^2 + eps A^2) / (2K(m)),
      with K(m) = pi/2 sum_n (binom(2n, n)/4^n)^2 m^n;
    - first harmonic of cn: a = A 2 pi sqrt(q/m) / (K (1 + q)), q the nome,
      q = l + 2 l^5 + ..., l = (1 - (1-m)^(1/4)) / (2 (1 + (1-m)^(1/4))).

    ``initial``: a = A = x(0); ``first_harmonic``: a = the first-harmonic amplitude (series
    reversion of lambda_a = lambda (a/A)^2).
    """
    n_terms = order + 2
    K = sp.pi / 2 * sum((sp.binomial(2 * n, n) / 4**n) ** 2 * m**n for n in range(n_terms))
    mm = lam / (2 * (1 + lam))
    omega = sp.series(sp.pi * sp.sqrt(1 + lam) / (2 * K.subs(m, mm)), lam, 0, order + 1)
    omega = omega.removeO()
    root = (1 - m) ** sp.Rational(1, 4)
    ell = (1 - root) / (2 * (1 + root))
    q_over_m = sp.series((ell + 2 * ell**5) / m, m, 0, n_terms).removeO()
    ratio = 2 * sp.pi * sp.sqrt(q_over_m) / (K * (1 + m * q_over_m))  # a / A
    ratio = sp.series(ratio.subs(m, mm), lam, 0, order + 1).removeO()
    lam_a = sp.Symbol("lambda_a", positive=True)
    cs = sp.symbols(f"c1:{order + 1}")
    inverse = sum(c * lam_a ** (i + 1) for i, c in enumerate(cs))  # lambda(lambda_a)
    forward = sp.series(lam * ratio**2, lam, 0, order + 1).removeO()
    eqs = sp.expand(sp.series(forward.subs(lam, inverse), lam_a, 0, order + 1).removeO() - lam_a)
    sol = sp.solve([eqs.coeff(lam_a, i) for i in range(1, order + 1)], cs, dict=True)[0]
    omega_a = sp.series(omega.subs(lam, inverse.subs(sol)), lam_a, 0, order + 1).removeO()
    return {
        "initial": [sp.nsimplify(omega.coeff(lam, j)) for j in range(order + 1)],
        "first_harmonic": [sp.nsimplify(omega_a.coeff(lam_a, j)) for j in range(order + 1)],
    }


@pytest.fixture(scope="module")
def duffing_series():
    series = _duffing_series(4)
    # the reference itself against mpmath at lambda = 0.05 (u(0) = A; A = 1, eps = 0.05)
    e = 0.05
    mv = e / (2 * (1 + e))
    exact = mp.pi * mp.sqrt(1 + e) / (2 * mp.ellipk(mv))
    approx = sum(float(c) * e**j for j, c in enumerate(series["initial"]))
    assert abs(approx - exact) < 5 * e**5
    # and the first-harmonic amplitude of cn against quadrature
    K = mp.ellipk(mv)
    a1 = mp.quad(lambda u: mp.ellipfun("cn", u, m=mv) * mp.cos(mp.pi * u / (2 * K)), [0, 4 * K])
    a1 = a1 / (2 * K)
    exact_a = sum(
        float(c) * (e * float(a1) ** 2) ** j for j, c in enumerate(series["first_harmonic"])
    )
    assert abs(exact_a - exact) < 5 * e**5
    return series


@pytest.mark.parametrize("amplitude", AMPLITUDES)
def test_duffing_matches_exact_elliptic_series_symbolic_omega0(duffing_series, amplitude):
    osc = Oscillator.parse("x'' + omega0**2*x + eps*x**3 = 0")
    approx = lindstedt_poincare(osc, 4, amplitude=amplitude)
    expected = w0 * sum(
        c * (eps * A**2 / w0**2) ** j for j, c in enumerate(duffing_series[amplitude])
    )
    assert sp.expand(approx.backbone - expected) == 0
    assert approx.backbone.free_symbols == {A, eps, w0}


@pytest.mark.parametrize("amplitude", AMPLITUDES)
def test_duffing_with_omega0_not_one(duffing_series, amplitude):
    # omega0 = 2 written as the stiffness 4: every order must carry the right power of omega0
    approx = lindstedt_poincare(
        Oscillator.parse("x'' + 4*x + eps*x**3 = 0"), 4, amplitude=amplitude
    )
    expected = 2 * sum(c * (eps * A**2 / 4) ** j for j, c in enumerate(duffing_series[amplitude]))
    assert sp.expand(approx.backbone - expected) == 0


def test_duffing_classic_coefficients():
    osc = Oscillator.parse("x'' + x + eps*x**3 = 0")
    initial = sp.expand(lindstedt_poincare(osc, 2, amplitude="initial").backbone)
    first = sp.expand(lindstedt_poincare(osc, 2).backbone)
    assert initial == 1 + sp.Rational(3, 8) * eps * A**2 - sp.Rational(21, 256) * eps**2 * A**4
    assert first == 1 + sp.Rational(3, 8) * eps * A**2 - sp.Rational(15, 256) * eps**2 * A**4


def test_initial_convention_starts_at_A_and_first_harmonic_convention_has_amplitude_A():
    osc = Oscillator.parse("x'' + omega0**2*x + eps*x**3 = 0")
    tau = real_symbol("tau")
    x_init = lindstedt_poincare(osc, 3, amplitude="initial").waveform
    assert sp.expand(x_init.subs(tau, 0) - A) == 0
    x_fh = lindstedt_poincare(osc, 3).waveform
    c1 = sp.integrate(sp.expand(x_fh * sp.cos(tau)), (tau, 0, 2 * sp.pi)) / sp.pi
    assert sp.simplify(c1 - A) == 0


def test_waveform_residual_is_of_the_next_order():
    """x(tau) and omega(A) leave a residual O(eps^(N+1)) in omega^2 x'' + x + eps x^3."""
    osc = Oscillator.parse("x'' + x + eps*x**3 = 0")
    tau = real_symbol("tau")
    for order in (1, 2, 3):
        ap = lindstedt_poincare(osc, order)
        res = ap.backbone**2 * sp.diff(ap.waveform, tau, 2) + ap.waveform + eps * ap.waveform**3
        f = sp.lambdify((tau, A, eps), res)
        t = np.linspace(0, 2 * np.pi, 64)
        r1 = np.max(np.abs(f(t, 1.0, 0.02)))
        r2 = np.max(np.abs(f(t, 1.0, 0.01)))
        assert r1 / r2 == pytest.approx(2 ** (order + 1), rel=0.15)


# ------------------------------------------------------------------ quadratic + cubic --
def test_quadratic_cubic_frequency_and_drift():
    """omega = omega0 [1 + (9 a3 omega0^2 - 10 a2^2) a^2/(24 omega0^4)] and the drift
    -a^2 a2/(2 omega0^2) [1 - cos(2 tau)/3] (Nayfeh & Mook), symbolic omega0."""
    a2, a3 = real_symbol("alpha2"), real_symbol("alpha3")
    osc = builtin_model("quadratic_cubic").with_params(omega0=None, alpha2=None, alpha3=None)
    ap = lindstedt_poincare(osc, 2, scaling="amplitude")
    expected = w0 * (1 + (9 * a3 * w0**2 - 10 * a2**2) * A**2 / (24 * w0**4))
    assert sp.expand(ap.backbone - expected) == 0
    tau = real_symbol("tau")
    x = sp.expand(ap.waveform)
    drift = -(A**2) * a2 / (2 * w0**2) * (1 - sp.cos(2 * tau) / 3)
    even_part = x.coeff(sp.cos(2 * tau)) * sp.cos(2 * tau) + x.subs(
        {sp.cos(tau): 0, sp.cos(2 * tau): 0, sp.cos(3 * tau): 0}
    )
    assert sp.expand(even_part - drift) == 0
    # the uniform bookkeeping gives the same a^2 coefficient (plus higher powers of a)
    uniform = sp.expand(lindstedt_poincare(osc, 2).backbone)
    assert sp.expand(uniform.coeff(A, 2) - expected.expand().coeff(A, 2)) == 0


def _exact_frequency(flow, a):
    orbit = limit_cycle(flow, [a, 0.0], 2 * np.pi, phase="anchor")
    return 2 * np.pi / orbit.period, orbit


def _numeric_backbone(ap):
    return lambdify((ap.amplitude,), bind_parameters(ap, [ap.backbone], (ap.amplitude,))[0])


def test_quadratic_cubic_against_exact_periods():
    """Errors against shooting fall with the amplitude at the rate of the order: x(0) = A
    (initial) is O(A^(N+1)); the first-harmonic convention O(a^(N+2))."""
    osc = builtin_model("quadratic_cubic")  # omega0 = 1, alpha2 = 0.5, alpha3 = 1
    flow = ODEFlow(osc)
    for amplitude in AMPLITUDES:
        fns = {
            n: _numeric_backbone(
                lindstedt_poincare(osc, n, scaling="amplitude", amplitude=amplitude)
            )
            for n in (2, 4)
        }
        errors = {n: [] for n in fns}
        for a0 in (0.2, 0.1):
            w, orbit = _exact_frequency(flow, a0)
            a = a0 if amplitude == "initial" else orbit.first_harmonic_amplitude
            for n, f in fns.items():
                errors[n].append(abs(float(f(a)) / w - 1))
        for n, (e1, e2) in errors.items():
            rate = n + 1 if amplitude == "initial" else n + 2
            assert e1 / e2 > 0.5 * 2**rate, (amplitude, n, e1, e2)
        assert errors[4][1] < errors[2][1] / 50
        assert errors[4][1] < 1e-6


# ------------------------------------------------------------------ PWL: the nsd backbone --
NSD_OUTER = (6.0, 8.0, 10.0, 20.0)  # beyond x_d = 3 + sqrt(6) = 5.449 for k = -2


@pytest.fixture(scope="module")
def nsd_exact():
    """Exact frequencies of the free nsd oscillator (k = -2) with turning point A."""
    flow = ExactPWLFlow(builtin_model("nsd", mu=0, F=0))
    return {a: _exact_frequency(flow, a) for a in NSD_OUTER}


def test_nsd_free_backbone_outer_regime(nsd_exact):
    osc = builtin_model("nsd", mu=0, F=0)
    table = {}
    for order in (1, 2):
        ap = lindstedt_poincare(osc, order, amplitude="initial")
        assert ap.options["omega0"] == 1  # the outer stiffness
        f = _numeric_backbone(ap)
        table[order] = [float(f(a)) / nsd_exact[a][0] - 1 for a in NSD_OUTER]
    print("\nnsd free backbone, k = -2, relative error of omega(A) (A = x(0)):")
    for a, e1, e2 in zip(NSD_OUTER, table[1], table[2], strict=True):
        print(f"  A = {a:5.1f}  omega = {nsd_exact[a][0]:.6f}  L-P1 {e1:+.2e}  L-P2 {e2:+.2e}")
    # measured: 2.3e-1, 7.1e-2, 3.7e-2, 6.6e-3 (first order); 1.3e-1, 2.6e-2, 1.0e-2, 8.6e-4
    assert np.all(np.abs(table[1]) < [0.25, 0.08, 0.04, 0.007])
    assert np.all(np.abs(table[2]) < np.abs(table[1]))
    assert abs(table[2][-1]) < 1e-3


def test_nsd_first_order_is_the_describing_function_mean():
    """First order: omega = (omega0^2 + a_1(A)/A)/(2 omega0) with a_1 the first harmonic of
    the whole restoring force (closed form from the Fourier engine)."""
    from perturb.fourier.symbols import series_coefficient

    osc = builtin_model("nsd", mu=0, F=0).with_params(k=None)
    ap = lindstedt_poincare(osc, 1)
    a1 = series_coefficient(osc.restoring_force, osc.x, 1, A)
    k = real_symbol("k")
    f = sp.lambdify((A, k), ap.backbone - (1 + a1 / A) / 2, modules=[_numeric_modules(), "numpy"])
    rng = np.random.default_rng(3)
    assert np.max(np.abs(f(rng.uniform(1.01, 30, 200), rng.uniform(-4, 0.9, 200)))) < 1e-13


def _numeric_modules():
    from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS

    return NUMERIC_IMPLEMENTATIONS


# ------------------------------------------------------------------ contract and errors --
def test_result_is_immutable_and_complete():
    ap = lindstedt_poincare(builtin_model("duffing", mu=0, F=0), 2)
    assert ap.method == "lp" and ap.unknowns == (ap.amplitude,)
    assert sp.simplify(ap.residuals[0] - (ap.frequency - ap.backbone)) == 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        ap.backbone = sp.Integer(1)  # type: ignore[misc]
    with pytest.raises(TypeError):
        ap.options["order"] = 3  # type: ignore[index]
    assert [s.title for s in ap.steps][:2] == ["Equation of motion", "Bookkeeping"]
    assert ap.fourier["g_3"] != 0


@pytest.mark.parametrize(
    "make, exc, match",
    [
        (lambda: lindstedt_poincare(builtin_model("duffing"), 2), ModelError, "damping"),
        (lambda: lindstedt_poincare(builtin_model("duffing", mu=0), 2), ModelError, "forced"),
        (lambda: lindstedt_poincare(builtin_model("vanderpol"), 2), ModelError, "x'' \\+ f"),
        (lambda: lindstedt_poincare(builtin_model("pendulum"), 2), ModelError, "polynomial"),
        (
            lambda: lindstedt_poincare(builtin_model("nsd", mu=0, F=0), 2, scaling="amplitude"),
            ModelError,
            "piecewise linear",
        ),
        (lambda: lindstedt_poincare(builtin_model("nsd", mu=0, F=0), 3), ParameterError, "at most"),
        (lambda: lindstedt_poincare(builtin_model("quadratic_cubic"), 0), ParameterError, "order"),
        (
            lambda: lindstedt_poincare(builtin_model("quadratic_cubic"), 2, amplitude="peak"),
            ParameterError,
            "amplitude",
        ),
        (
            lambda: lindstedt_poincare(builtin_model("quadratic_cubic"), 2, scaling="x"),
            ParameterError,
            "scaling",
        ),
        (
            lambda: lindstedt_poincare(Oscillator.parse("x'' - x + x**3 = 0"), 2),
            ModelError,
            "not positive",
        ),
        (
            lambda: lindstedt_poincare(Oscillator.parse("x'' + x**3 = 0"), 1, omega0=-1.0),
            ParameterError,
            "omega0",
        ),
    ],
)
def test_clear_errors(make, exc, match):
    with pytest.raises(exc, match=match):
        make()


def test_reference_frequency_can_be_chosen():
    # a pure cubic has no linear frequency: any omega0 works, the first order is omega0-free
    # when expanded in omega^2 but not in omega (plain L-P: the mean of omega0 and a1/(A omega0))
    ap = lindstedt_poincare(Oscillator.parse("x'' + x**3 = 0"), 1, omega0=1)
    assert sp.expand(ap.backbone - (1 + sp.Rational(3, 4) * A**2) / 2) == 0


# ------------------------------------------------------------------ LaTeX --
def _pdflatex():
    exe = shutil.which("pdflatex")
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("pdflatex is missing in CI")
        pytest.skip("pdflatex not installed")
    return exe


@pytest.mark.parametrize(
    "make",
    [
        lambda: lindstedt_poincare(builtin_model("duffing", mu=0, F=0), 4, amplitude="initial"),
        lambda: lindstedt_poincare(builtin_model("quadratic_cubic"), 2, scaling="amplitude"),
        lambda: lindstedt_poincare(builtin_model("nsd", mu=0, F=0), 2),
    ],
    ids=["duffing-4", "quadratic-cubic-2", "nsd-2"],
)
def test_derivation_compiles(make, tmp_path):
    exe = _pdflatex()
    tex = tmp_path / "lp.tex"
    doc = latex_document(make(), tex)
    assert "Order 1 in $\\varepsilon$" in doc and "secular" in doc
    proc = subprocess.run(
        [exe, "-interaction=nonstopmode", "-halt-on-error", tex.name],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout[-3000:]
