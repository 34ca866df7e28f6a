"""First-order averaging (van der Pol, Krylov–Bogoliubov) and equivalent linearisation.

Oracles are the classical results, typed here independently of the code:

- forced van der Pol, ρ[(1 − ρ)² + 4σ²] = F²/4 (docs/references.md §2; Nayfeh & Mook 1979 §4.2);
- Krylov–Bogoliubov Duffing backbone ω = ω0 + 3εa²/(8ω0); free van der Pol limit cycle a = 2;
- describing functions of the dead zone, the saturation, the relay, Coulomb friction and
  quadratic damping (Gelb & Vander Velde 1968; Den Hartog's equivalent damping).
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest
import sympy as sp

from perturb import ModelError, Oscillator, builtin_model
from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS
from perturb.methods.averaging import (
    equivalent_linearisation,
    fourier_components,
    krylov_bogoliubov,
    van_der_pol_averaging,
)
from perturb.methods.harmonic_balance import single_harmonic_balance
from perturb.model.parsing import real_symbol
from perturb.report.latex import latex_document


def _num(expr: sp.Expr, *args: sp.Symbol):
    return sp.lambdify(args, expr, modules=[NUMERIC_IMPLEMENTATIONS, "numpy"])


# ------------------------------------------------------------------ forced van der Pol --
def test_forced_van_der_pol_frequency_response_in_the_classical_scaling():
    # Scaling (Nayfeh & Mook 1979, §4.2; docs/references.md §2):
    #     x'' + x = eps [(1 - x^2) x' + F cos(Omega t)],   Omega = 1 + eps sigma,
    # rho = a^2/4 with x ~ a cos(Omega t - phi). To O(eps) the averaged steady states obey
    #     rho [(1 - rho)^2 + 4 sigma^2] = F^2/4.
    # The methods keep the exact Omega, so the classical form is their eps -> 0 limit.
    osc = Oscillator.parse("x'' - eps*(1 - x**2)*x' + x = eps*F*cos(Omega*t)")
    eps, F, Omega = (real_symbol(n) for n in ("eps", "F", "Omega"))
    sigma, rho = sp.symbols("sigma rho", positive=True)
    kb = krylov_bogoliubov(osc)
    a = kb.amplitude
    W = sp.Symbol("W")
    poly = sum(c * W**j for j, c in enumerate(kb.frequency_polynomial))
    scaled = poly.xreplace({W: (1 + eps * sigma) ** 2, a: 2 * sp.sqrt(rho)}) / (4 * eps**2)
    classical = rho * ((1 - rho) ** 2 + 4 * sigma**2) - F**2 / 4
    assert sp.simplify(sp.limit(sp.expand(scaled), eps, 0) - classical) == 0


def _polar_to_cartesian_gap(osc: Oscillator, samples: int = 5) -> float:
    """max |(p', q') - d/dt (a cos phi, a sin phi)| over random states, Cartesian vs polar."""
    kb, vdp = krylov_bogoliubov(osc), van_der_pol_averaging(osc)
    a, phi = kb.unknowns
    p, q = vdp.unknowns
    a_dot, phi_dot = kb.slow_flow
    target = (
        a_dot * sp.cos(phi) - a * phi_dot * sp.sin(phi),
        a_dot * sp.sin(phi) + a * phi_dot * sp.cos(phi),
    )
    subs = osc.substitutions()
    Omega = kb.frequency
    polar = _num([t.xreplace(subs) for t in target], a, phi, Omega)
    cart = _num([f.xreplace(subs) for f in vdp.slow_flow], p, q, Omega)
    rng = np.random.default_rng(7)
    gap = 0.0
    for _ in range(samples):
        A, ph, W = rng.uniform(0.3, 4.0), rng.uniform(-np.pi, np.pi), rng.uniform(0.3, 2.0)
        lhs = np.array(cart(A * np.cos(ph), A * np.sin(ph), W), float)
        rhs = np.array(polar(A, ph, W), float)
        gap = max(gap, float(np.max(np.abs(lhs - rhs))))
    return gap


@pytest.mark.parametrize(
    "model",
    [
        "x'' - eps*(1 - x**2)*x' + x = eps*F*cos(Omega*t)",
        "nsd",
        "x'' + 0.05*x' + x + 0.2*sign(x') + 0.1*x'*Abs(x') = 0.8*cos(Omega*t)",
    ],
)
def test_van_der_pol_cartesian_flow_is_the_polar_flow(model):
    if model in ("nsd",):
        osc = builtin_model(model)
    else:
        osc = Oscillator.parse(model, {"eps": 0.3, "F": 0.7} if "eps" in model else None)
    assert _polar_to_cartesian_gap(osc) < 1e-12


def test_cartesian_van_der_pol_is_polynomial():
    osc = Oscillator.parse("x'' - eps*(1 - x**2)*x' + x = eps*F*cos(Omega*t)")
    vdp = van_der_pol_averaging(osc)
    p, q = vdp.unknowns
    eps, F, Omega = (real_symbol(n) for n in ("eps", "F", "Omega"))
    # p' = -[(Omega^2 - 1) q + eps Omega (r^2/4 - 1) p] / (2 Omega),  r^2 = p^2 + q^2
    r2 = p**2 + q**2
    p_dot = -((Omega**2 - 1) * q + eps * Omega * (r2 / 4 - 1) * p) / (2 * Omega)
    q_dot = ((Omega**2 - 1) * p - eps * Omega * (r2 / 4 - 1) * q + eps * F) / (2 * Omega)
    assert sp.expand(vdp.slow_flow[0] - p_dot) == 0
    assert sp.expand(vdp.slow_flow[1] - q_dot) == 0


# ------------------------------------------------------------------- free oscillators --
def test_krylov_bogoliubov_duffing_backbone():
    kb = krylov_bogoliubov(Oscillator.parse("x'' + omega0**2*x + eps*x**3 = 0"))
    a = kb.amplitude
    omega0, eps = real_symbol("omega0"), real_symbol("eps")
    assert sp.simplify(kb.backbone - (omega0 + 3 * eps * a**2 / (8 * omega0))) == 0
    # the residual of the frequency is omega - backbone
    assert sp.simplify(kb.residuals[1] - (kb.frequency - kb.backbone)) == 0


def test_free_van_der_pol_limit_cycle_amplitude_two_and_stable():
    kb = krylov_bogoliubov(builtin_model("vanderpol"))
    a = kb.amplitude
    roots = sp.solve(kb.residuals[0], a)
    assert roots == [2]
    slope = sp.diff(kb.slow_flow[0], a).subs(a, 2).xreplace(kb.oscillator.substitutions())
    assert float(slope) < 0  # stable limit cycle for eps > 0
    assert sp.simplify(kb.backbone - 1) == 0  # no frequency correction at first order
    # Cartesian form: the circle p^2 + q^2 = 4 is invariant
    vdp = van_der_pol_averaging(builtin_model("vanderpol"))
    p, q = vdp.unknowns
    th = sp.Symbol("th")
    on_circle = [f.xreplace({p: 2 * sp.cos(th), q: 2 * sp.sin(th)}) for f in vdp.slow_flow]
    assert all(sp.simplify(e) == 0 for e in on_circle)


def test_van_der_pol_limit_cycle_against_shooting():
    # Measured: for eps = 0.1 the exact limit cycle (shooting) has max|x| = 2.000104, first
    # harmonic 2.000156 and frequency 0.999376; first-order averaging says 2 and 1, errors
    # O(eps^2).
    from perturb.simulate.flows.base import ODEFlow
    from perturb.simulate.orbits.shooting import limit_cycle

    osc = builtin_model("vanderpol", eps=0.1)
    orbit = limit_cycle(ODEFlow(osc), [2.0, 0.0], 2 * np.pi)
    assert abs(orbit.amplitude - 2.0) < 1e-3
    assert abs(2 * np.pi / orbit.period - 1.0) < 1e-3


def test_free_system_needs_a_positive_generating_frequency():
    osc = Oscillator.parse(
        "x'' + mu*x' + k*x + (1 - k)*((x - 1)*Heaviside(x - 1) + (x + 1)*Heaviside(-x - 1)) = 0",
        {"k": -2.0, "mu": 0.05},
    )
    with pytest.raises(ModelError, match="generating_frequency"):
        krylov_bogoliubov(osc)
    # about omega_g the backbone is the tangent of sqrt(k_eq):
    # omega_g + (k_eq - omega_g^2)/(2 omega_g)
    kb = krylov_bogoliubov(osc, generating_frequency=1)
    eq = equivalent_linearisation(osc, amplitude=kb.amplitude, frequency=sp.Integer(1))
    assert sp.simplify(kb.backbone - (1 + (eq.stiffness - 1) / 2)) == 0


# -------------------------------------------------------------- describing functions --
def _deadzone_df(A, d, k=1.0):
    """Classical dead-zone describing function (Gelb & Vander Velde 1968): slope k outside
    |x| < d, zero inside."""
    A = np.asarray(A, float)
    r = np.minimum(d / A, 1.0)
    return np.where(A > d, k * (1 - (2 / np.pi) * (np.arcsin(r) + r * np.sqrt(1 - r * r))), 0.0)


def _saturation_df(A, d, k=1.0):
    """Classical saturation describing function: k x for |x| < d, k d sign(x) outside."""
    A = np.asarray(A, float)
    r = np.minimum(d / A, 1.0)
    return np.where(A > d, k * (2 / np.pi) * (np.arcsin(r) + r * np.sqrt(1 - r * r)), k)


AMPLITUDES = np.concatenate([np.linspace(0.05, 0.999, 7), np.geomspace(1.001, 40.0, 40)])


@pytest.mark.parametrize("d", [0.5, 1.0, 2.5])
def test_deadzone_equivalent_stiffness_is_the_describing_function(d):
    x = real_symbol("x")
    k = 1.7
    eq = equivalent_linearisation(k * (x - sp.Max(-d, sp.Min(d, x))))
    a = eq.amplitude
    got = _num(eq.stiffness, a)(AMPLITUDES * d)
    assert np.max(np.abs(got - _deadzone_df(AMPLITUDES * d, d, k))) < 1e-12
    # the textbook theta-form agrees too (where the orbit crosses both breakpoints)
    closed, _, defs = eq.closed()
    theta_form = _num(closed.xreplace(dict(defs)), a)
    big = AMPLITUDES[AMPLITUDES > 1] * d
    assert np.max(np.abs(theta_form(big) - _deadzone_df(big, d, k))) < 1e-12


@pytest.mark.parametrize("d", [0.5, 1.0, 2.5])
def test_saturation_equivalent_stiffness_is_the_describing_function(d):
    x = real_symbol("x")
    eq = equivalent_linearisation(2.0 * sp.Max(-d, sp.Min(d, x)))
    got = _num(eq.stiffness, eq.amplitude)(AMPLITUDES * d)
    assert np.max(np.abs(got - _saturation_df(AMPLITUDES * d, d, 2.0))) < 1e-12


def test_builtin_deadzone_and_saturation_keep_their_stiffness_symbols():
    k1, k2 = real_symbol("k1"), real_symbol("k2")
    for name, df in (("deadzone", _deadzone_df), ("saturation", _saturation_df)):
        eq = equivalent_linearisation(builtin_model(name))
        assert eq.stiffness.has(k1, k2)  # the coefficients stay symbolic; d = 1 orders them
        assert sp.simplify(eq.damping - real_symbol("mu")) == 0
        f = _num(eq.stiffness, eq.amplitude, k1, k2)
        assert np.max(np.abs(f(AMPLITUDES, 0.3, 2.0) - (0.3 + df(AMPLITUDES, 1.0, 2.0)))) < 1e-12


@pytest.mark.parametrize("k", [-2.0, -0.5, 0.5])
def test_nsd_first_harmonic_is_the_deadzone_describing_function(k):
    # f(x) = k x + (1 - k)[(x-1)H(x-1) + (x+1)H(-x-1)] = k x + (1 - k) dz(x), so
    # a_1(A)/A = k + (1 - k) N_dz(A; d = 1)  (issue text)
    osc = builtin_model("nsd", k=k)
    eq = equivalent_linearisation(osc)
    want = k + (1 - k) * _deadzone_df(AMPLITUDES, 1.0)
    k_eq = eq.stiffness.xreplace(osc.substitutions())
    assert np.max(np.abs(_num(k_eq, eq.amplitude)(AMPLITUDES) - want)) < 1e-12
    # and it is the coefficient single-harmonic balance uses
    hb = single_harmonic_balance(osc)
    a1 = _num(hb.fourier["a_1"].xreplace(osc.substitutions()), hb.amplitude)(AMPLITUDES)
    assert np.max(np.abs(a1 / AMPLITUDES - want)) < 1e-12


def test_velocity_switches_use_the_quarter_period_shift():
    osc = Oscillator.parse(
        "x'' + mu*x' + x + r*sign(x') + c*x'*Abs(x') + e*x**2*sign(x') = F*cos(Omega*t)"
    )
    eq = equivalent_linearisation(osc)
    a, w = eq.amplitude, eq.frequency
    mu, r, c, e = (real_symbol(n) for n in ("mu", "r", "c", "e"))
    # Coulomb 4r/(pi a w), quadratic damping 8 c a w/(3 pi) (Den Hartog), x^2 sign(x'):
    # (1/(pi a w)) int a^2 cos^2 |a w sin| ... = 4 a e/(3 pi w)
    want = mu + 4 * r / (sp.pi * a * w) + 8 * c * a * w / (3 * sp.pi) + 4 * a * e / (3 * sp.pi * w)
    assert sp.simplify(eq.damping - want) == 0
    assert sp.simplify(eq.stiffness - 1) == 0
    # the relay sign(x): k_eq = 4/(pi a)
    relay = equivalent_linearisation(sp.sign(real_symbol("x")))
    assert sp.simplify(relay.stiffness - 4 / (sp.pi * relay.amplitude)) == 0
    assert relay.damping == 0


def test_fourier_components_agree_with_quadrature():
    x, v = real_symbol("x"), real_symbol("x'")
    expr = (
        0.3 * x**3
        - 0.2 * (1 - x**2) * v
        + 0.7 * sp.sign(v)
        + 0.4 * v * sp.Abs(v)
        + 0.5 * x * sp.Heaviside(x - 0.3)
        + 1.5 * (x - 1) * sp.Heaviside(x - 1)
    )
    A, w, b = sp.Rational(13, 10), sp.Rational(7, 10), sp.Rational(-1, 5)
    comps = fourier_components(expr, x, v, A, w, b, orders=(0, 1, 2, 3))
    psi = np.linspace(0, 2 * np.pi, 200001)[:-1]
    f = sp.lambdify((x, v), expr, modules="numpy")
    vals = f(float(b) + float(A) * np.cos(psi), -float(A * w) * np.sin(psi))
    for n, (c, s) in comps.items():
        if n == 0:
            ref_c, ref_s = vals.mean(), 0.0
        else:
            ref_c, ref_s = 2 * np.mean(vals * np.cos(n * psi)), 2 * np.mean(vals * np.sin(n * psi))
        # the rectangle rule on a periodic function with jumps converges like 1/N
        assert abs(float(c) - ref_c) < 1e-4 and abs(float(s) - ref_s) < 1e-4, n


# ---------------------------------------------------------------- forced = HB steady states --
@pytest.mark.parametrize("model", ["duffing", "nsd", "deadzone"])
def test_forced_krylov_bogoliubov_has_the_single_harmonic_balance_steady_states(model):
    osc = builtin_model(model)
    kb, hb = krylov_bogoliubov(osc), single_harmonic_balance(osc)
    subs = {s: v for s, v in osc.substitutions().items() if s != hb.frequency}
    reps = dict(zip(kb.unknowns, hb.unknowns, strict=True))
    args = (*hb.unknowns, hb.frequency)
    f_kb = _num([r.xreplace(reps).xreplace(subs) for r in kb.residuals], *args)
    f_hb = _num([r.xreplace(subs) for r in hb.residuals], *args)
    rng = np.random.default_rng(1)
    pts = rng.uniform([0.1, -3.0, 0.2], [6.0, 3.0, 2.5], size=(50, 3)).T
    assert np.allclose(np.array(f_kb(*pts), float), np.array(f_hb(*pts), float), atol=1e-12)
    W = sp.Symbol("W")
    for c_kb, c_hb in zip(kb.frequency_polynomial, hb.frequency_polynomial, strict=True):
        g1 = _num(c_kb.xreplace(reps).xreplace(subs), hb.amplitude, W)(pts[0], pts[2])
        g2 = _num(c_hb.xreplace(subs), hb.amplitude, W)(pts[0], pts[2])
        assert np.allclose(g1, g2, atol=1e-10)


def test_coulomb_friction_frequency_equation_is_den_hartogs():
    # x'' + x + r sign(x') = F cos(Omega t): a^2 (1 - W)^2 + (4 r/pi)^2 = F^2
    osc = Oscillator.parse("x'' + x + r*sign(x') = F*cos(Omega*t)")
    kb = krylov_bogoliubov(osc)
    a, W = kb.amplitude, sp.Symbol("W")
    r, F = real_symbol("r"), real_symbol("F")
    poly = sum(c * W**j for j, c in enumerate(kb.frequency_polynomial))
    assert sp.expand(poly - (a**2 * (1 - W) ** 2 + (4 * r / sp.pi) ** 2 - F**2)) == 0


def test_forced_krylov_bogoliubov_duffing_against_shooting():
    # Primary resonance of a weakly non-linear Duffing oscillator (mu = 0.05, alpha = 0.1,
    # F = 0.1, Omega = 1.1): three steady states. Each is corrected by single shooting from the
    # averaged orbit; measured first-harmonic errors 0.30 %, 0.45 % (unstable), 0.007 %, and
    # the slow-flow stability agrees with the Floquet multipliers.
    from perturb.numeric.amplitude import solutions_at
    from perturb.simulate.flows.base import ODEFlow
    from perturb.simulate.orbits.shooting import periodic_orbit

    W = 1.1
    osc = builtin_model("duffing", mu=0.05, alpha=0.1, F=0.1, Omega=W)
    kb = krylov_bogoliubov(osc)
    resp = solutions_at(kb, [W], stability="slow_flow")
    cos_p, sin_p = (_num(e.xreplace(osc.substitutions()), kb.amplitude) for e in kb.phase_from)
    flow = ODEFlow(osc)
    errors = []
    for br in resp.branches:
        for A, stable in zip(br.first_harmonic_amplitude, br.stable, strict=True):
            phi = np.arctan2(sin_p(A), cos_p(A))
            orbit = periodic_orbit(flow, [A * np.cos(phi), W * A * np.sin(phi)])
            errors.append(A / orbit.first_harmonic_amplitude - 1)
            assert (orbit.stability == "stable") == bool(stable)
    assert len(errors) == 3
    assert max(abs(e) for e in errors) < 6e-3


# --------------------------------------------------------------------------- errors --
def test_unsupported_models_raise_model_errors():
    with pytest.raises(ModelError, match="parametric"):
        krylov_bogoliubov(builtin_model("mathieu"))
    with pytest.raises(ModelError, match="closed-form"):
        krylov_bogoliubov(builtin_model("pendulum", F=0.3))
    with pytest.raises(ModelError, match="static load"):
        van_der_pol_averaging(Oscillator.parse("x'' + x + x**3 = 1 + cos(Omega*t)"))
    with pytest.raises(ModelError, match="closed-form"):
        equivalent_linearisation(Oscillator.parse("x'' + Heaviside(x)*sign(x') + x = 0"))


def test_results_are_immutable():
    kb = krylov_bogoliubov(builtin_model("duffing"))
    with pytest.raises(TypeError):
        kb.fourier["k_eq"] = 0  # type: ignore[index]
    eq = equivalent_linearisation(builtin_model("duffing"))
    with pytest.raises(AttributeError):
        eq.stiffness = 0  # type: ignore[misc]


def test_approximations_serialise_and_read_back():
    import json

    from perturb.io.serialize import approximation_from_dict, approximation_to_dict

    for approx in (
        krylov_bogoliubov(builtin_model("nsd")),
        krylov_bogoliubov(builtin_model("vanderpol")),
        van_der_pol_averaging(builtin_model("nsd")),
    ):
        data = json.loads(json.dumps(approximation_to_dict(approx)))
        back = approximation_from_dict(data, approx.oscillator)
        assert back.residuals == approx.residuals and back.slow_flow == approx.slow_flow
        assert back.steps == approx.steps


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
        lambda: krylov_bogoliubov(builtin_model("nsd")),
        lambda: krylov_bogoliubov(builtin_model("vanderpol")),
        lambda: van_der_pol_averaging(builtin_model("nsd")),
        lambda: van_der_pol_averaging(
            Oscillator.parse("x'' + mu*x' + x + r*sign(x') = F*cos(Omega*t)")
        ),
    ],
    ids=["kb-nsd", "kb-vanderpol", "vdp-nsd", "vdp-coulomb"],
)
def test_averaging_derivations_compile(make, tmp_path):
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
