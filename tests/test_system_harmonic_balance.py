"""Single-harmonic balance of systems of several coordinates (issue 16, item 2).

Oracles, all independent of the code under test:

* the residuals at random ``(a, b, Omega)`` against an mpmath quadrature of the projected
  equations, ``(1/pi) int_0^{2 pi} row(tau) cos/sin tau dtau`` (and ``1/(2 pi)`` for the mean),
  with the rows written out here from the models' published equations and the integral split
  at the switching instants (solved here from ``s(tau) = d``);
* linear systems against the complex amplitude equation ``Z(Omega) X = F_c - i F_s`` with
  ``X = a - i b``, the impedance built here from the matrices written out by hand;
* an unforced cubic pair against the hand describing function ``3 g S^2 / 4``.
"""

from __future__ import annotations

import dataclasses

import mpmath as mp
import numpy as np
import pytest
import sympy as sp

from perturb.errors import ModelError, PerturbError
from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS
from perturb.methods.system_harmonic_balance import system_single_harmonic_balance
from perturb.model.system import System
from perturb.model.system_builtins import builtin_system

mp.mp.dps = 30


# ----------------------------------------------------------------------------- helpers --
def _H(x):
    return 1 if x > 0 else 0


def _crossings(mean, c, s, d) -> list:
    """tau in [0, 2 pi) where mean + c cos tau + s sin tau = d (solved here, in mpmath)."""
    S = mp.sqrt(mp.mpf(c) ** 2 + mp.mpf(s) ** 2)
    if S == 0 or abs(d - mean) >= S:
        return []
    phi = mp.atan2(s, c)
    th = mp.acos((d - mean) / S)
    return [(phi + sgn * th) % (2 * mp.pi) for sgn in (1, -1)]


def _project(row, splits, kind):
    """(1/pi) int row(tau) cos/sin tau over one period (mean: 1/(2 pi) int row)."""
    pts = sorted({mp.mpf(0), 2 * mp.pi, *splits})
    if kind == "mean":
        return mp.quad(row, pts) / (2 * mp.pi)
    w = mp.cos if kind == "cos" else mp.sin
    return mp.quad(lambda t: row(t) * w(t), pts) / mp.pi


def _numeric_residuals(res, point):
    """The residuals at ``point`` (name -> value) through lambdify with perturb's stable
    coefficient forms, as a numeric layer would evaluate them."""
    args = res.arguments
    values = {**{k: v for k, v in res.values.items() if v is not None}, **point}
    fn = sp.lambdify(args, list(res.residuals), modules=[NUMERIC_IMPLEMENTATIONS, "numpy"])
    return np.array([float(v) for v in fn(*(values[s.name] for s in args))])


def _wave(abar, a, b, Om):
    """x(tau), x'(tau) (time derivative) and x''(tau) of abar + a cos tau + b sin tau."""

    def x(t):
        return abar + a * mp.cos(t) + b * mp.sin(t)

    def v(t):
        return Om * (-a * mp.sin(t) + b * mp.cos(t))

    def acc(t):
        return -(Om**2) * (a * mp.cos(t) + b * mp.sin(t))

    return x, v, acc


# ----------------------------------------------------------------------- nsd2 vs quadrature --
def _nsd2_rows(p, a1, b1, a2, b2, Om):
    """The rows of builtin nsd2 (docstring of perturb.model.system_builtins), written out."""
    x1, v1, acc1 = _wave(0, a1, b1, Om)
    x2, v2, acc2 = _wave(0, a2, b2, Om)
    k, k2, m2, mu1, mu2, F = (mp.mpf(p[n]) for n in ("k", "k2", "m2", "mu1", "mu2", "F"))

    def f(x):  # Zou-Nagarajaiah: k x + (1 - k)[(x - 1)H(x - 1) + (x + 1)H(-x - 1)]
        return k * x + (1 - k) * ((x - 1) * _H(x - 1) + (x + 1) * _H(-x - 1))

    def row1(t):
        return (
            acc1(t)
            + mu1 * v1(t)
            + mu2 * (v1(t) - v2(t))
            + f(x1(t))
            + k2 * (x1(t) - x2(t))
            - F * mp.cos(t)
        )

    def row2(t):
        return m2 * acc2(t) + mu2 * (v2(t) - v1(t)) + k2 * (x2(t) - x1(t))

    splits = _crossings(0, a1, b1, 1) + _crossings(0, a1, b1, -1)
    return (row1, row2), splits


@pytest.mark.parametrize("params", [{}, {"k": 0.3, "F": 0.6, "mu1": 0.1}], ids=["k=-0.5", "k=0.3"])
def test_nsd2_residuals_equal_quadrature(params):
    system = builtin_system("nsd2", **params)
    res = system_single_harmonic_balance(system)
    assert [s.name for s in res.unknowns] == ["a_1", "a_2", "b_1", "b_2"]
    assert res.labels == ("cos x1", "cos x2", "sin x1", "sin x2")
    assert res.options["bias"] is False and not res.autonomous
    assert res.frequency.name == "Omega"
    p = {k: v for k, v in res.values.items()}
    rng = np.random.default_rng(16)
    points = [rng.uniform([-3, -3, -3, -3, 0.3], [3, 3, 3, 3, 2.5]) for _ in range(5)]
    points.append(np.array([0.4, -0.2, 0.5, 1.1, 0.9]))  # |x1| < 1: no switching
    points.append(np.array([1.0 + 1e-9, 0.3, 0.0, -0.7, 1.3]))  # x1 grazes the breakpoint
    checked_crossing = False
    for a1, a2, b1, b2, Om in points:
        point = {"a_1": a1, "a_2": a2, "b_1": b1, "b_2": b2, "Omega": Om}
        got = _numeric_residuals(res, point)
        rows, splits = _nsd2_rows(p, *(mp.mpf(v) for v in (a1, b1, a2, b2, Om)))
        checked_crossing |= bool(splits)
        want = [
            _project(rows[i], splits, kind) for kind in ("cos", "sin") for i in range(2)
        ]  # (cos x1, cos x2, sin x1, sin x2)
        np.testing.assert_allclose(got, [float(w) for w in want], rtol=0, atol=1e-12)
        # the SymPy expressions evaluate (coefficient functions by their numeric forms) alike
        sym = {s: point.get(s.name, p.get(s.name)) for s in res.arguments}
        direct = [
            float(r.xreplace({s: sp.Float(v) for s, v in sym.items()})) for r in res.residuals
        ]
        np.testing.assert_allclose(direct, got, rtol=0, atol=1e-12)
    assert checked_crossing


def test_describing_function_of_nsd2_in_closed_form():
    res = system_single_harmonic_balance(builtin_system("nsd2"))
    (df,) = res.describing_functions
    S = df.amplitude_symbol
    k = next(s for s in df.gain.free_symbols if s.name == "k")
    ((theta, definition),) = df.definitions  # the two mirror angles fold into one
    assert sp.simplify(definition - sp.acos(1 / S)) == 0
    for kv in (-0.5, 0.3):
        for Sv in (1.0 + 1e-6, 1.3, 2.0, 7.5):
            th = float(sp.acos(1 / sp.Float(Sv, 30)))
            # element (1 - k)[(s - 1)H(s - 1) + (s + 1)H(-s - 1)]: two ramps, each with
            # a_1 = (S/pi)(theta - sin theta cos theta) (hand integration), divided by S
            hand = 2 * (1 - kv) * (th - np.sin(th) * np.cos(th)) / np.pi
            closed = float(df.gain_closed.xreplace({theta: th, k: kv, S: Sv}))
            assert closed == pytest.approx(hand, abs=1e-13)
            # the coefficient-function form (stable numeric forms) agrees
            assert float(df.gain.xreplace({S: Sv, k: kv})) == pytest.approx(hand, abs=1e-13)
        # below the breakpoints the element does nothing (the ramp-step form starts from the
        # outer slope and cancels it: rounding only)
        assert float(df.gain.xreplace({S: 0.7, k: kv})) == pytest.approx(0, abs=1e-15)


# ----------------------------------------------------- bias, velocity and polynomial elements --
_BIAS_EQS = [
    "x1'' + mu*x1' + x1 + k2*(x1-x2) + r*(x1-x2-d)*Heaviside(x1-x2-d) = F*cos(Omega*t)",
    "m2*x2'' + k2*(x2-x1) - r*(x1-x2-d)*Heaviside(x1-x2-d) + g*x2**3 + h*Max(-e, Min(e, x2')) = P",
]
_BIAS_PARAMS = dict(
    mu=0.1, k2=0.7, r=3.0, d=0.2, F=1.5, Omega=1.1, m2=0.8, g=0.4, h=0.3, e=0.25, P=0.3
)


@pytest.fixture(scope="module")
def bias_system():
    return System.parse(_BIAS_EQS, _BIAS_PARAMS)


def test_one_sided_spring_velocity_saturation_cubic_with_bias(bias_system):
    res = system_single_harmonic_balance(bias_system)
    assert res.options["bias"] is True  # one-sided spring and a static load: automatic bias
    assert [s.name for s in res.unknowns] == ["abar_1", "abar_2", "a_1", "a_2", "b_1", "b_2"]
    assert len(res.residuals) == 6 and len(res.describing_functions) == 3
    p = {k: mp.mpf(v) for k, v in _BIAS_PARAMS.items()}
    rng = np.random.default_rng(3)
    for _ in range(4):
        c1, c2, a1, a2, b1, b2 = rng.uniform(-1.5, 1.5, 6)
        Om = rng.uniform(0.4, 2.0)
        x1, v1, acc1 = _wave(*(mp.mpf(v) for v in (c1, a1, b1, Om)))
        x2, v2, acc2 = _wave(*(mp.mpf(v) for v in (c2, a2, b2, Om)))

        def spring(t, x1=x1, x2=x2):
            s = x1(t) - x2(t)
            return p["r"] * (s - p["d"]) * _H(s - p["d"])

        def sat(v):
            return p["h"] * max(-p["e"], min(p["e"], v))

        def row1(t, x1=x1, x2=x2, v1=v1, acc1=acc1, spring=spring):
            return (
                acc1(t)
                + p["mu"] * v1(t)
                + x1(t)
                + p["k2"] * (x1(t) - x2(t))
                + spring(t)
                - p["F"] * mp.cos(t)
            )

        def row2(t, x1=x1, x2=x2, v2=v2, acc2=acc2, spring=spring, sat=sat):
            return (
                p["m2"] * acc2(t)
                + p["k2"] * (x2(t) - x1(t))
                - spring(t)
                + p["g"] * x2(t) ** 3
                + sat(v2(t))
                - p["P"]
            )

        Omm = mp.mpf(Om)
        splits = _crossings(mp.mpf(c1 - c2), a1 - a2, b1 - b2, p["d"])
        for level in (p["e"], -p["e"]):  # x2' = Om (b2 cos - a2 sin)
            splits += _crossings(0, Omm * b2, -Omm * a2, level)
        want = [
            _project(row, splits, kind) for kind in ("mean", "cos", "sin") for row in (row1, row2)
        ]
        point = dict(abar_1=c1, abar_2=c2, a_1=a1, a_2=a2, b_1=b1, b_2=b2, Omega=Om)
        got = _numeric_residuals(res, point)
        np.testing.assert_allclose(got, [float(w) for w in want], rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------ linear --
def test_linear_three_coordinates_is_the_complex_amplitude_equation():
    n = 3
    M = [[f"m{i}{j}" if i <= j else f"m{j}{i}" for j in range(1, n + 1)] for i in range(1, n + 1)]
    C = [[f"c{i}{j}" for j in range(1, n + 1)] for i in range(1, n + 1)]
    K = [[f"k{i}{j}" for j in range(1, n + 1)] for i in range(1, n + 1)]
    forcing = ["F1*cos(Omega*t) + G1*sin(Omega*t)", "F0 + G2*sin(Omega*t)", "F3*cos(Omega*t)"]
    system = System.from_matrices(M, C, K, forcing=forcing)
    res = system_single_harmonic_balance(system, bias=True)
    sym = {s.name: s for s in res.arguments}
    W = sym["Omega"]
    Mm = sp.Matrix(n, n, lambda i, j: sym[M[i][j]])
    Cm = sp.Matrix(n, n, lambda i, j: sym[C[i][j]])
    Km = sp.Matrix(n, n, lambda i, j: sym[K[i][j]])
    X = sp.Matrix([sym[f"a_{k}"] - sp.I * sym[f"b_{k}"] for k in range(1, n + 1)])
    Fc = sp.Matrix([sym["F1"], 0, sym["F3"]])
    Fs = sp.Matrix([sym["G1"], sym["G2"], 0])
    want = (Km - W**2 * Mm + sp.I * W * Cm) * X - (Fc - sp.I * Fs)
    mean, cos, sin = res.residuals[:n], res.residuals[n : 2 * n], res.residuals[2 * n :]
    for i in range(n):
        assert sp.simplify(cos[i] - sp.I * sin[i] - want[i]) == 0
    # the mean balance K abar = F_0
    abar = sp.Matrix([sym[f"abar_{k}"] for k in range(1, n + 1)])
    want0 = Km * abar - sp.Matrix([0, sym["F0"], 0])
    for i in range(n):
        assert sp.simplify(mean[i] - want0[i]) == 0
    assert res.describing_functions == ()


def test_linear_first_order_states_mount():
    # mount_linear (perturb.model.system_builtins docstring), y = (p1, p2, q_i, q_d):
    # E y + D y' = F with D = diag(C1, C2, I_i, I_d)
    res = system_single_harmonic_balance(builtin_system("mount_linear"))
    sym = {s.name: s for s in res.arguments}
    W = sym["Omega"]
    C1, C2, Ii, Id, Ri, Rd = (sym[k] for k in ("C1", "C2", "I_i", "I_d", "R_i", "R_d"))
    D = sp.diag(C1, C2, Ii, Id)
    E = sp.Matrix([[0, 0, 1, 1], [0, 0, -1, -1], [-1, 1, Ri, 0], [-1, 1, 0, Rd]])
    X = sp.Matrix([sym[f"a_{k}"] - sp.I * sym[f"b_{k}"] for k in range(1, 5)])
    # C1 p1' + q_i + q_d = -A_r Omega Xa sin(Omega t): F_s = -A_r Omega Xa
    F = sp.Matrix([sp.I * sym["A_r"] * W * sym["Xa"], 0, 0, 0])
    want = (E + sp.I * W * D) * X - F
    assert res.coordinates == ("p1", "p2", "q_i", "q_d")
    for i in range(4):
        assert sp.simplify(res.residuals[i] - sp.I * res.residuals[4 + i] - want[i]) == 0


def test_unforced_cubic_pair_hand_derivation():
    system = System.parse(["x1'' + x1 + g*x1**3 + k2*(x1 - x2) = 0", "x2'' + k2*(x2 - x1) = 0"])
    res = system_single_harmonic_balance(system)
    assert res.autonomous and res.frequency.name == "omega"
    sym = {s.name: s for s in res.arguments}
    assert res.phase_condition == sym["b_1"]
    w, g, k2 = sym["omega"], sym["g"], sym["k2"]
    a1, a2, b1 = sym["a_1"], sym["a_2"], sym["b_1"]
    N = 1 + sp.Rational(3, 4) * g * (a1**2 + b1**2)  # hand describing function of x + g x^3
    del N
    want_cos1 = (1 + k2 - w**2) * a1 - k2 * a2 + sp.Rational(3, 4) * g * (a1**2 + b1**2) * a1
    assert sp.expand(res.residuals[0] - want_cos1) == 0
    assert sp.expand(res.residuals[1] - ((k2 - w**2) * a2 - k2 * a1)) == 0


# ------------------------------------------------------------------------------- LaTeX --
@pytest.mark.parametrize("which", ["nsd2", "bias", "mount_linear"])
def test_latex_compiles_and_typesets_matrices(which, bias_system, tmp_path, compile_tex):
    system = bias_system if which == "bias" else builtin_system(which)
    res = system_single_harmonic_balance(system)
    doc = res.latex_document()
    assert doc.count("\\begin{bmatrix}") >= 6
    assert "\\left(K - \\Omega^{2} M\\right) a" in doc
    assert "\\cos\\tau:" in doc and "\\sin\\tau:" in doc
    if which == "nsd2":
        assert "\\mu_{1} + \\mu_{2}" in doc and "\\begin{cases}" in doc
        assert "\\theta &= \\operatorname{acos}" in doc
    if which == "bias":
        assert "\\text{mean}:" in doc
    tex = tmp_path / "hb1_system.tex"
    tex.write_text(doc)
    compile_tex(tex, timeout=120)


def test_result_is_immutable_and_printable():
    res = system_single_harmonic_balance(builtin_system("nsd2"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.residuals = ()  # type: ignore[misc]
    text = str(res)
    assert "cos x1" in text and "nonsmooth(x1)" in text and "Omega" in text


# ------------------------------------------------------------------------------ errors --
def test_element_on_a_zero_combination_is_refused():
    system = builtin_system("nsd2")
    (e,) = system.elements
    bad = dataclasses.replace(system, elements=(dataclasses.replace(e, combination=(0, 0, 0, 0)),))
    with pytest.raises(ModelError, match=r"nonsmooth\(x1\).*identically zero"):
        system_single_harmonic_balance(bad)


def test_switch_that_loses_its_combination_for_the_values_is_refused():
    system = System.parse(
        [
            "x1'' + x1 + (x1-x2)*Heaviside(a*x1 - a*x2 - 1) = F*cos(Omega*t)",
            "x2'' + x2 - (x1-x2)*Heaviside(a*x1 - a*x2 - 1) = 0",
        ],
        {"a": 0, "F": 1, "Omega": 1},
    )
    with pytest.raises(ModelError, match=r"nonsmooth\(x1 - x2\).*identically zero"):
        system_single_harmonic_balance(system)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda: builtin_system("mount"), "rigid stop"),
        (lambda: builtin_system("belt"), "no closed-form describing function"),
        (
            lambda: System.parse(_BIAS_EQS, _BIAS_PARAMS),
            "static load.*not odd \\(nonsmooth\\(x1 - x2\\)\\).*pass bias=True",
        ),
        (
            lambda: System.parse(
                ["x1'' + x1 + x1**3 = F*cos(Omega*t) + G*cos(W2*t)", "x2'' + x2 = 0"]
            ),
            "one forcing frequency",
        ),
        (lambda: "nsd2", "expected a perturb.model.system.System"),
    ],
    ids=["stop", "exp-friction", "bias-false", "two-frequencies", "not-a-system"],
)
def test_clear_errors(make, match):
    kw = {"bias": False} if match.startswith("static load") else {}
    with pytest.raises(PerturbError, match=match):
        system_single_harmonic_balance(make(), **kw)


def test_gain_at_rest_is_the_limit_of_the_describing_function(bias_system):
    res = system_single_harmonic_balance(bias_system)
    values = {k: v for k, v in res.values.items() if v is not None}
    for df in res.describing_functions:
        syms = df.gain.free_symbols | df.gain_at_rest.free_symbols | df.function.free_symbols
        reps = {s: values[s.name] for s in syms if s.name in values}
        for sigma in (-0.6, -0.1, 0.05, 0.4):
            limit = float(df.gain_at_rest.xreplace({**reps, df.mean_symbol: sigma}))
            near = float(
                df.gain.xreplace({**reps, df.mean_symbol: sigma, df.amplitude_symbol: 1e-4})
            )
            # the slope f'(sigma) by a central difference of f, written independently
            f = sp.lambdify(sp.Symbol("s", real=True), df.function.xreplace(reps))
            slope = (f(sigma + 1e-6) - f(sigma - 1e-6)) / 2e-6
            assert near == pytest.approx(limit, abs=1e-7)
            assert limit == pytest.approx(slope, abs=1e-6)


def test_an_oscillator_is_the_one_coordinate_case_of_hb1():
    # hb1 balances x = A cos(tau - phi): a = A cos phi, b = A sin phi turn its two equations
    # r1 = a_1(A) - Omega^2 A - F cos phi, r2 = mu Omega A - F sin phi into ours:
    # cos = cos(phi) r1 + sin(phi) r2, sin = sin(phi) r1 - cos(phi) r2
    from perturb import builtin_model
    from perturb.methods.harmonic_balance import single_harmonic_balance

    osc = builtin_model("nsd")
    ours = system_single_harmonic_balance(osc)
    theirs = single_harmonic_balance(osc)
    A, phi = theirs.unknowns
    values = {k: v for k, v in osc.params.items() if v is not None}
    for Av, pv, Om in ((0.7, 0.3, 0.8), (2.5, -1.1, 1.4), (5.0, 2.0, 0.5)):
        sub = {A: Av, phi: pv}
        for s in set().union(*(r.free_symbols for r in theirs.residuals)) - {A, phi}:
            sub[s] = Om if s.name == "Omega" else values[s.name]
        r1, r2 = (float(r.xreplace(sub)) for r in theirs.residuals)
        point = {"a_1": Av * np.cos(pv), "b_1": Av * np.sin(pv), "Omega": Om}
        got = _numeric_residuals(ours, point)
        want = [np.cos(pv) * r1 + np.sin(pv) * r2, np.sin(pv) * r1 - np.cos(pv) * r2]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("which", ["nsd2", "bias"])
def test_jacobian_against_central_differences(which, bias_system):
    system = bias_system if which == "bias" else builtin_system("nsd2")
    res = system_single_harmonic_balance(system)
    args = res.arguments
    modules = [NUMERIC_IMPLEMENTATIONS, "numpy"]
    R = sp.lambdify(args, list(res.residuals), modules=modules)
    J = sp.lambdify(args, res.jacobian(frequency=True), modules=modules)
    values = {k: v for k, v in res.values.items() if v is not None}
    rng = np.random.default_rng(7)
    wrt = res.unknowns + (res.frequency,)
    for _ in range(3):
        point = dict(zip([s.name for s in wrt], rng.uniform(-1.5, 1.5, len(wrt)), strict=True))
        point[res.frequency.name] = rng.uniform(0.5, 1.8)
        full = {**values, **point}
        x = np.array([full[s.name] for s in args], dtype=float)
        got = np.asarray(J(*x), dtype=float)
        h = 1e-6
        for j in range(len(wrt)):
            up, dn = x.copy(), x.copy()
            up[j] += h
            dn[j] -= h
            fd = (np.array(R(*up), dtype=float) - np.array(R(*dn), dtype=float)) / (2 * h)
            np.testing.assert_allclose(got[:, j], fd, rtol=1e-6, atol=1e-6)
