"""derivations/course.py: the numbers it publishes, each against an oracle computed here
independently of the code that produced it, and the files it writes.

The script runs once per session, in ``--fast`` mode, into a temporary folder (the
``derivations_fast`` fixture of conftest.py, which the document build test shares); the tests
read its ``summary.json`` and CSV files. Oracles:

- the free Duffing period by quadrature of the energy integral (not the elliptic formula the
  script uses);
- the classical series, typed here: L-P ``1 + 3e/8 - 21e^2/256 + 81e^3/2048`` (x(0) = 1), the
  van der Pol frequency ``1 - e^2/16 + 17e^4/3072`` and its standard reference period at
  e = 1, 6.6632868593; ``kappa = 9 a3 w0^2 - 10 a2^2``;
- the course's response relations, typed here and solved numerically: primary resonance
  ``[mu_N^2 + (s - 3 alpha a^2/8)^2] a^2 = F^2/4``, superharmonic ``[mu_N^2 + (s - 3 alpha
  L^2 - 3 alpha a^2/8)^2] a^2 = alpha^2 L^6``, forced van der Pol ``rho[(1-rho)^2 + 4 s^2] =
  F^2/4``;
- the Mathieu characteristic values of ``scipy.special.mathieu_a/b`` (Zhang & Jin's
  algorithm, not a monodromy matrix);
- plain ``solve_ivp`` runs for the jump frequency and the superharmonic amplitude (slow).
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import mpmath as mp
import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp
from scipy.optimize import brentq
from scipy.special import mathieu_a, mathieu_b

FILES = (
    "section.tex",
    "summary.json",
    "duffing_free.csv",
    "quadratic_cubic.csv",
    "duffing_primary.png",
    "duffing_primary_exact.csv",
    "duffing_primary_ms.csv",
    "duffing_superharmonic.png",
    "duffing_superharmonic_ms.csv",
    "duffing_superharmonic_exact.csv",
    "vanderpol_limit_cycle.png",
    "vanderpol_limit_cycle.csv",
    "vanderpol_forced.png",
    "vanderpol_forced.csv",
    "vanderpol_forced_shooting.csv",
    "mathieu_ince_strutt.png",
    "mathieu_stability_map.csv",
    "mathieu_transition_curves.csv",
)


@pytest.fixture(scope="module")
def course(derivations_fast):
    out = derivations_fast("course") / "course"
    return out, json.loads((out / "summary.json").read_text())


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


# ------------------------------------------------------------------------------ files --
def test_files_and_latex_references(course):
    out, summary = course
    for name in FILES:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    text = (out / "section.tex").read_text()
    assert text.startswith("\\section{The course}")
    assert summary["fast"] is True
    # figures are named relative to the document folder (the parent of the output folder)
    figures = re.findall(r"\\includegraphics\[[^]]*\]\{([^}]+)\}", text)
    assert len(figures) == 5
    for fig in figures:
        assert fig.startswith("course/") and (out.parent / fig).is_file(), fig
    labels = set(re.findall(r"\\label\{([^}]+)\}", text))
    refs = set(re.findall(r"\\ref\{([^}]+)\}", text))
    assert refs <= labels, refs - labels
    # symbols are typeset (eps -> \varepsilon), never printed by name
    assert not re.search(r"(?<![A-Za-z\\])eps(?![A-Za-z])", text)


def test_section_compiles_with_pdflatex(course, tmp_path, compile_tex, derivation_module):
    out, _ = course
    # the section alone, in the assembled document's preamble, beside a link to its folder
    (tmp_path / "course").symlink_to(out, target_is_directory=True)
    doc = tmp_path / "doc.tex"
    doc.write_text(
        derivation_module("build").document(tmp_path, [tmp_path / "course" / "section.tex"])
    )
    compile_tex(doc)


# ----------------------------------------------------------------------- free Duffing --
def _duffing_omega_by_quadrature(eps: float) -> float:
    """x'' + x + eps x^3 = 0, x(0) = 1: T = 4 int_0^1 dx / sqrt(2 (V(1) - V(x))), V = x^2/2 +
    eps x^4/4. With x = sin(theta) the integrand is smooth:
    T = 4 int_0^{pi/2} dtheta / sqrt(1 + eps (1 + sin^2 theta) / 2)."""
    mp.mp.dps = 30
    T = 4 * mp.quad(lambda th: 1 / mp.sqrt(1 + eps * (1 + mp.sin(th) ** 2) / 2), [0, mp.pi / 2])
    return float(2 * mp.pi / T)


def test_duffing_exact_frequency_is_the_energy_integral(course):
    _, summary = course
    exact = summary["duffing_free"]["exact"]
    for e in (0.1, 1.0, 10.0):
        assert exact[str(e)] == pytest.approx(_duffing_omega_by_quadrature(e), rel=1e-13)


def test_duffing_table_against_the_classical_series(course):
    out, summary = course
    d = summary["duffing_free"]
    lp = [
        lambda e: 1 + 3 * e / 8,
        lambda e: 1 + 3 * e / 8 - 21 * e**2 / 256,
        lambda e: 1 + 3 * e / 8 - 21 * e**2 / 256 + 81 * e**3 / 2048,
    ]
    for e in (0.1, 1.0, 10.0):
        w = _duffing_omega_by_quadrature(e)
        for n, f in enumerate(lp, 1):
            assert d[f"L-P order {n}"]["omega"][str(e)] == pytest.approx(f(e), rel=1e-14)
            assert d[f"L-P order {n}"]["rel_error"][str(e)] == pytest.approx(f(e) / w - 1)
        # one-term balance (= mLP order 1): omega^2 = 1 + 3 eps a^2/4; K-B: 1 + 3 eps a^2/8
        for name in ("HB 1 term", "mLP order 1"):
            assert d[name]["omega"][str(e)] == pytest.approx(math.sqrt(1 + 0.75 * e), rel=1e-12)
        assert d["averaging (K-B)"]["omega"][str(e)] == pytest.approx(1 + 3 * e / 8, rel=1e-14)
    err = {
        k: {e: abs(v["rel_error"][str(e)]) for e in (0.1, 1.0, 10.0)}
        for k, v in d.items()
        if k != "exact"
    }
    # eps = 0.1: L-P converges, order 3 within 5e-6 (measured 2.2e-6); eps = 10: it diverges
    assert err["L-P order 3"][0.1] < 5e-6
    assert err["L-P order 1"][0.1] > err["L-P order 2"][0.1] > err["L-P order 3"][0.1]
    assert err["L-P order 1"][10.0] > 0.5 and err["L-P order 3"][10.0] > 5
    # mLP and three-term HB stay accurate at eps = 10 (measured 1.7e-2, 4.0e-4, 5.1e-5)
    assert err["mLP order 1"][10.0] < 0.02 and err["mLP order 2"][10.0] < 5e-4
    assert err["HB 3 terms"][10.0] < 1e-4 and err["HB 3 terms"][0.1] < 1e-8
    rows = _rows(out / "duffing_free.csv")
    assert len(rows) == 3 * (len(d) - 1)


# -------------------------------------------------------------- quadratic + cubic oscillator --
def test_quadratic_cubic_coefficients(course):
    out, summary = course
    qc = summary["quadratic_cubic"]
    got = {name: (c["alpha2^2"], c["alpha3*omega0^2"]) for name, c in qc["coefficients"].items()}
    want = {
        "Lindstedt": -10,
        "multiple scales": -10,
        "3 terms": -10,
        "bias + 1": -12,
        "(1 term)": 0,
        "averaging": 0,
    }
    for key, a2 in want.items():
        (name,) = [n for n in got if key in n]
        assert got[name] == (a2, 9), name
    assert qc["lp_equals_hb3"] and qc["lp_equals_ms"] and qc["hb1_differs"]
    text = (out / "section.tex").read_text()
    assert "- 10 \\alpha_{2}^{2}" in text and "- 12 \\alpha_{2}^{2}" in text


def test_quadratic_cubic_symbolically():
    """L-P against three-term and one-term harmonic balance, and the oracle kappa."""
    from perturb import builtin_model
    from perturb.methods import harmonic_balance, lindstedt_poincare
    from perturb.methods.harmonic_balance import backbone_series
    from perturb.model.parsing import real_symbol

    w0, a2, a3 = (real_symbol(n) for n in ("omega0", "alpha2", "alpha3"))
    qc = builtin_model("quadratic_cubic", omega0=None, alpha2=None, alpha3=None)
    lp = lindstedt_poincare(qc, 2)
    A = lp.amplitude
    a2_coeff = sp.expand(lp.backbone).coeff(A, 2)
    assert sp.simplify(a2_coeff * 24 * w0**3 - (9 * a3 * w0**2 - 10 * a2**2)) == 0
    hb3 = backbone_series(harmonic_balance(qc, (1, 2), bias=True), 2)
    hb1 = backbone_series(harmonic_balance(qc), 2)
    lp2 = sp.expand(lp.backbone.xreplace({A: hb3.amplitude})).coeff(hb3.amplitude, 2)
    assert sp.expand(hb3.frequency.coeff(hb3.amplitude, 2) - lp2) == 0
    one = sp.expand(hb1.frequency).coeff(hb1.amplitude, 2)
    assert sp.expand(one - lp2.xreplace({hb3.amplitude: hb1.amplitude})) != 0
    assert sp.simplify(one - 3 * a3 / (8 * w0)) == 0


# ------------------------------------------------------------------ primary resonance --
def _course_primary_folds(mu: float, alpha: float, F: float) -> list[float]:
    """Folds of [mu_N^2 + (s - 3 alpha a^2/8)^2] a^2 = F^2/4 (omega0 = 1, mu_N = mu/2): on the
    branch s+(a) = 3 alpha a^2/8 + sqrt(F^2/(4 a^2) - mu_N^2), where ds/da = 0."""
    muN = mu / 2
    top = F / (2 * muN)

    def s_plus(a):
        return 3 * alpha * a**2 / 8 + np.sqrt(F**2 / (4 * a**2) - muN**2)

    def ds(a, h=1e-7):
        return (s_plus(a + h) - s_plus(a - h)) / (2 * h)

    grid = np.linspace(0.05 * top, top * (1 - 1e-9), 20001)
    vals = ds(grid[1:-1])
    idx = np.nonzero(np.sign(vals[:-1]) * np.sign(vals[1:]) < 0)[0]
    return sorted(1 + s_plus(brentq(ds, grid[i + 1], grid[i + 2], xtol=1e-13)) for i in idx)


def test_primary_resonance_folds(course):
    _, summary = course
    p = summary["primary"]
    assert p["ms_response_is_course_form"]
    want = _course_primary_folds(p["params"]["mu"], p["params"]["alpha"], p["params"]["F"])
    got = [w for w, _ in p["ms_folds"]]
    assert len(got) == 2
    np.testing.assert_allclose(got, want, rtol=1e-7)
    assert p["ms_peak_amplitude"] == pytest.approx(p["params"]["F"] / p["params"]["mu"], rel=1e-6)
    # first order puts the jumps within 2 % of the exact ones (measured 0.2 % and 1.0 %)
    for key in ("up_sweep_jump_down", "down_sweep_jump_up"):
        ms, ex = p["jumps"]["ms"][key], p["jumps"]["exact"][key]
        assert abs(ms / ex - 1) < 0.02, key
    lo, hi = sorted(w for w, _ in p["exact_folds"])
    assert 1.0 < lo < hi < 1.2


def _settled_amplitude(W: float, y0, p: dict, periods: int = 150) -> tuple[float, np.ndarray]:
    mu, alpha, F = p["mu"], p["alpha"], p["F"]
    T = 2 * np.pi / W
    sol = solve_ivp(
        lambda t, y: [y[1], F * np.cos(W * t) - mu * y[1] - y[0] - alpha * y[0] ** 3],
        (0, periods * T),
        y0,
        method="DOP853",
        rtol=1e-9,
        atol=1e-11,
        dense_output=True,
    )
    t = np.linspace((periods - 3) * T, periods * T, 3000)
    return float(np.max(np.abs(sol.sol(t)[0]))), sol.y[:, -1]


@pytest.mark.slow
def test_exact_jump_down_frequency_by_plain_integration(course):
    """Sweeping up with solve_ivp: just below the exact upper fold the large orbit persists,
    just above it the motion falls to the small one."""
    _, summary = course
    p = summary["primary"]
    w_up = p["jumps"]["exact"]["up_sweep_jump_down"]
    big, y = _settled_amplitude(w_up - 0.006, [0.9, 0.0], p["params"], 250)
    assert big > 0.8
    below, _ = _settled_amplitude(w_up - 0.002, y, p["params"], 250)
    above, _ = _settled_amplitude(w_up + 0.003, y, p["params"], 250)
    assert below > 0.8 and above < 0.6, (below, above)


# ------------------------------------------------------------- superharmonic resonance --
def _course_superharmonic_amplitude(W: float, mu: float, alpha: float, F: float) -> list[float]:
    """Roots a of [mu_N^2 + (s - 3 alpha L^2 - 3 alpha a^2/8)^2] a^2 = alpha^2 L^6, omega0 = 1,
    s = 3 W - 1, L = F / (2 (1 - W^2)), mu_N = mu/2 (Nayfeh & Mook §4.1.3, typed here)."""
    L = F / (2 * (1 - W**2))
    s, muN = 3 * W - 1, mu / 2

    def r(a):
        return (muN**2 + (s - 3 * alpha * L**2 - 3 * alpha * a**2 / 8) ** 2) * a**2 - (
            alpha**2 * L**6
        )

    grid = np.geomspace(1e-4, 10, 20000)
    v = r(grid)
    idx = np.nonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)[0]
    return [brentq(r, grid[i], grid[i + 1], xtol=1e-14) for i in idx]


def test_superharmonic_against_the_course_formula(course):
    out, summary = course
    s = summary["superharmonic"]
    p = s["params"]
    want = _course_superharmonic_amplitude(s["check_omega"], p["mu"], p["alpha"], p["F"])
    np.testing.assert_allclose(s["ms_at_check"], want, rtol=1e-7)
    # on the rising flank first order is within 5 % of the exact 3-Omega harmonic (0.5 %)
    assert abs(s["ms_at_check"][0] / s["exact_at_check"] - 1) < 0.05
    # the peak: located within 0.01 in Omega, overestimated by first order
    assert abs(s["ms_peak"][0] - s["exact_peak"][0]) < 0.01
    assert s["ms_peak"][1] > s["exact_peak"][1]
    # the refined peaks: no sampled point above them, and the first-order one is a maximum of
    # the course formula (typed here) between its neighbours
    assert s["exact_peak"][1] >= s["exact_peak_up_sweep"][1] - 1e-9
    W0 = s["ms_peak"][0]
    top = max(_course_superharmonic_amplitude(W0, p["mu"], p["alpha"], p["F"]))
    assert s["ms_peak"][1] == pytest.approx(top, rel=1e-7)
    for dW in (-2e-3, 2e-3):
        near = _course_superharmonic_amplitude(W0 + dW, p["mu"], p["alpha"], p["F"])
        assert max(near, default=0.0) <= top + 1e-9
    rows = _rows(out / "duffing_superharmonic_ms.csv")
    for row in rows[:: max(1, len(rows) // 6)]:
        roots = _course_superharmonic_amplitude(float(row["omega"]), p["mu"], p["alpha"], p["F"])
        assert min(abs(float(row["a_superharmonic"]) - r) for r in roots) < 1e-6


def _superharmonic_by_plain_integration(p: dict, W: float) -> float:
    """The 3-Omega harmonic of the forced Duffing orbit after 250 periods of plain DOP853."""
    T = 2 * np.pi / W
    periods = 250
    sol = solve_ivp(
        lambda t, y: [
            y[1],
            p["F"] * np.cos(W * t) - p["mu"] * y[1] - y[0] - p["alpha"] * y[0] ** 3,
        ],
        (0, periods * T),
        [p["F"] / (1 - W**2), 0.0],
        method="DOP853",
        rtol=1e-10,
        atol=1e-12,
        dense_output=True,
    )
    t = (periods - 1) * T + T * np.arange(512) / 512
    return abs(np.fft.rfft(sol.sol(t)[0])[3]) / 256


@pytest.mark.slow
def test_superharmonic_exact_peak_by_plain_integration(course):
    # the refined exact peak of the 3-Omega harmonic: the orbit's value there, lower +-1e-3
    _, summary = course
    s = summary["superharmonic"]
    p, (W0, a0) = s["params"], s["exact_peak"]
    assert _superharmonic_by_plain_integration(p, W0) == pytest.approx(a0, rel=1e-5)
    for W in (W0 - 1e-3, W0 + 1e-3):
        assert _superharmonic_by_plain_integration(p, W) < a0


@pytest.mark.slow
def test_superharmonic_exact_amplitude_by_plain_integration(course):
    _, summary = course
    s = summary["superharmonic"]
    a3 = _superharmonic_by_plain_integration(s["params"], s["check_omega"])
    assert a3 == pytest.approx(s["exact_at_check"], rel=1e-5)


# ----------------------------------------------------------------------- van der Pol --
def test_vanderpol_limit_cycle(course):
    _, summary = course
    rows = {r["eps"]: r for r in summary["vanderpol"]}
    assert min(rows) <= 0.01 and max(rows) >= 5
    for r in rows.values():
        assert r["averaging_amplitude"] == 2 and r["averaging_omega"] == 1
        assert r["ms2_amplitude"] == pytest.approx(2.0, abs=1e-12)
    # amplitude -> 2 as eps -> 0, error O(eps^2)
    eps_sorted = sorted(rows)
    gaps = [rows[e]["exact_max_abs_x"] - 2 for e in eps_sorted]
    assert 0 < gaps[0] < 1e-5
    assert all(g0 <= g1 for g0, g1 in zip(gaps, gaps[1:], strict=False) if g1 < 0.01)
    for e in eps_sorted:
        if e <= 0.3:
            assert abs(rows[e]["exact_max_abs_x"] - 2) < e**2 / 50
            # the first harmonic is 2 + eps^2/64 + O(eps^4) (MMS order 4)
            assert rows[e]["exact_first_harmonic"] == pytest.approx(2 + e**2 / 64, abs=e**4 / 50)
            w = 1 - e**2 / 16 + 17 * e**4 / 3072
            assert abs(rows[e]["exact_omega"] - w) < max(e**6 / 10, 1e-10)
    # the literature period at eps = 1
    assert rows[1.0]["exact_period"] == pytest.approx(6.6632868593, abs=1e-7)
    eps = sp.Symbol("eps")
    series = summary["vanderpol_series"]
    assert (
        sp.expand(
            sp.sympify(series["ms4_omega"], locals={"eps": eps})
            - (1 - eps**2 / 16 + sp.Rational(17, 3072) * eps**4)
        )
        == 0
    )
    assert (
        sp.expand(sp.sympify(series["ms4_amplitude"], locals={"eps": eps}) - (2 + eps**2 / 64)) == 0
    )


def _classical_rho(F: float, sigma: float) -> np.ndarray:
    """Roots of rho[(1 - rho)^2 + 4 sigma^2] = F^2/4: rho^3 - 2 rho^2 + (1 + 4 s^2) rho - F^2/4."""
    r = np.roots([1, -2, 1 + 4 * sigma**2, -(F**2) / 4])
    return np.sort(r[np.abs(r.imag) < 1e-9].real)


def test_forced_vanderpol_against_the_classical_curves(course):
    out, summary = course
    fv = summary["forced_vanderpol"]
    eps = fv["eps"]
    # the engine keeps the exact Omega: O(eps) from the classical relation
    assert fv["max_classical_residual"] < 2 * eps
    rows = _rows(out / "vanderpol_forced.csv")
    assert {float(r["F"]) for r in rows} == {0.4, 0.8, 1.2}
    assert len(fv["shooting"]) >= 10
    for F, s, rho_avg, rho_exact, stability in fv["shooting"]:
        nearest = min(_classical_rho(F, s), key=lambda x: abs(x - rho_avg))
        assert abs(rho_avg - nearest) < 2 * eps
        assert abs(rho_exact - nearest) < 2 * eps, (F, s, rho_exact, nearest)
        assert stability in ("stable", "unstable", "fold", "neimark-sacker", "period-doubling")


# --------------------------------------------------------------------------- Mathieu --
def _mathieu_boundaries(n: int, eps: float) -> list[float]:
    """x'' + (delta + eps cos 2t) x = 0 is Mathieu's y'' + (a - 2q cos 2t) y = 0 with
    a = delta, q = -eps/2; the set of characteristic values is symmetric in q."""
    q = eps / 2
    if n == 0:
        return [float(mathieu_a(0, q))]
    return sorted([float(mathieu_b(n, q)), float(mathieu_a(n, q))])


def test_mathieu_floquet_boundaries_are_the_characteristic_values(course):
    _, summary = course
    bounds = summary["mathieu"]["boundaries"]
    assert len(bounds) == 5 * 3
    for n, _curve, eps, _pert, floquet in bounds:
        assert min(abs(floquet - b) for b in _mathieu_boundaries(n, eps)) < 1e-9


def test_mathieu_transition_curves_to_order_eps3(course):
    _, summary = course
    e = sp.Symbol("eps")
    curves = {
        int(n): [sp.sympify(c, locals={"eps": e}) for c in cs]
        for n, cs in summary["mathieu"]["curves"].items()
    }
    third = sp.Rational(1, 512) * e**3
    assert {sp.expand(c) for c in curves[1]} == {
        1 - e / 2 - e**2 / 32 + third,
        1 + e / 2 - e**2 / 32 - third,
    }
    assert sp.expand(curves[0][0] - (-(e**2) / 8 + sp.Rational(7, 2048) * e**4)) == 0
    assert {sp.expand(c).coeff(e, 2) for c in curves[2]} == {
        sp.Rational(-1, 48),
        sp.Rational(5, 48),
    }
    # the order-2 curves 1 +- eps/2 - eps^2/32 miss the boundary by O(eps^3) = eps^3/512 ...
    for sign, idx in ((-1, 0), (1, 1)):
        errs = []
        for ev in (0.05, 0.1, 0.2):
            exact = _mathieu_boundaries(1, ev)[idx]
            errs.append(abs(1 + sign * ev / 2 - ev**2 / 32 - exact))
            assert errs[-1] == pytest.approx(ev**3 / 512, rel=0.2)
        assert 6 < errs[1] / errs[0] < 10 and 6 < errs[2] / errs[1] < 10
    # ... and the engine's order-3 curves by O(eps^4)
    for n in (0, 1, 2):
        for c in curves[n]:
            for ev in (0.1, 0.2):
                val = float(c.subs(e, ev))
                err = min(abs(val - b) for b in _mathieu_boundaries(n, ev))
                assert err < ev**4 / 100, (n, c, ev, err)


def test_mathieu_stability_map(course):
    out, _ = course
    data = np.loadtxt(out / "mathieu_stability_map.csv", delimiter=",", skiprows=1)
    checked = 0
    for delta, eps, _tr, unstable in data[::7]:
        if eps > 2.0:
            continue
        q = eps / 2
        edges = [float(mathieu_a(0, q))]
        for n in (1, 2, 3):
            edges += [float(mathieu_b(n, q)), float(mathieu_a(n, q))]
        if min(abs(delta - x) for x in edges) < 0.02:
            continue  # the grid is coarse in fast mode: skip points at the boundary
        a0, b1, a1, b2, a2, b3, a3 = edges
        want = delta < a0 or b1 < delta < a1 or b2 < delta < a2 or b3 < delta < a3
        assert bool(unstable) == want, (delta, eps)
        checked += 1
    assert checked > 300
