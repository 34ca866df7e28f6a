"""Tests of :mod:`perturb.simulate.studies` (sweeps, sections, diagrams, basins, Lyapunov).

Oracles, never the module itself:

* the closed-form steady state of the linear oscillator x'' + mu x' + x = F cos(W t),
  amplitude F / sqrt((1 - W^2)^2 + mu^2 W^2), and its closed-form monodromy
  exp(A T) (scipy.linalg.expm), whose multipliers have modulus exp(-mu T / 2);
* single-harmonic balance of the forced Duffing oscillator, solved in the test;
* monodromy matrices by central finite differences of the flow map (independent of the
  flow's sensitivity code, saltation included);
* Liouville: det(monodromy) = exp(-mu T), so lambda_1 + lambda_2 = -mu for every orbit;
* the exact symmetry y -> -y of the unforced nsd oscillator.

Parameter sets from Zou & Nagarajaiah are the reconstructions of docs/references.md §1.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.linalg import expm

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator
from perturb.response import CSV_COLUMNS
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.studies import (
    BasinResult,
    BifurcationDiagram,
    LyapunovResult,
    PoincareSection,
    SweepResult,
    basins,
    bifurcation_diagram,
    frequency_sweep,
    lyapunov_exponent,
    poincare_section,
)

TWO_PI = 2.0 * math.pi
QUIET = {"progress": False}


def linear(mu: float = 0.1, F: float = 1.0, Omega: float = 1.0) -> Oscillator:
    # nsd with k = 1: (1 - k) = 0 removes the PWL terms, x'' + mu x' + x = F cos(W t)
    return builtin_model("nsd", k=1.0, mu=mu, F=F, Omega=Omega)


def linear_amplitude(mu: float, F: float, w: np.ndarray) -> np.ndarray:
    return F / np.sqrt((1 - w**2) ** 2 + (mu * w) ** 2)


def linear_monodromy(mu: float, T: float) -> np.ndarray:
    return expm(np.array([[0.0, 1.0], [-1.0, -mu]]) * T)


def log_growth(M: np.ndarray, w0: np.ndarray, n: int) -> float:
    """ln|M^n w0| for unit w0, with the product renormalised (M^n itself underflows)."""
    w, acc = np.array(w0, float), 0.0
    for _ in range(n):
        w = M @ w
        r = float(np.linalg.norm(w))
        acc += math.log(r)
        w /= r
    return acc


def fd_monodromy(flow, y, t0: float, t1: float, h: float = 1e-4) -> np.ndarray:
    """Central differences of the flow map; h = 1e-4 balances the O(h^2) truncation against
    the ~1e-12 rounding of the propagated states (measured: 1e-8 agreement at h = 1e-4,
    worse below 1e-6)."""
    cols = [(flow(y + h * e, t0, t1).y - flow(y - h * e, t0, t1).y) / (2 * h) for e in np.eye(2)]
    return np.column_stack(cols)


# ---------------------------------------------------------------------------------------------
# flow selection
# ---------------------------------------------------------------------------------------------
def test_make_flow_picks_exact_for_pwl_and_ode_otherwise():
    pwl = make_flow(builtin_model("nsd", k=-2, mu=0.05, F=2, Omega=0.6))
    try:
        from perturb.simulate.flows.exact import ExactPWLFlow
    except ImportError:  # before the exact flow lands the factory falls back
        assert isinstance(pwl, ODEFlow)
    else:
        assert isinstance(pwl, ExactPWLFlow)
        with pytest.raises(ModelError, match="not piecewise linear"):
            make_flow(builtin_model("duffing"), method="exact")
    assert isinstance(make_flow(builtin_model("duffing")), ODEFlow)
    assert isinstance(make_flow(builtin_model("nsd"), method="ode"), ODEFlow)
    assert make_flow(builtin_model("nsd"), 0.7).period == pytest.approx(TWO_PI / 0.7, rel=1e-15)


# ---------------------------------------------------------------------------------------------
# frequency sweeps
# ---------------------------------------------------------------------------------------------
def test_linear_sweep_equals_closed_form_amplitude():
    # Fixed transients (tol=None): after n periods the transient left is C exp(-mu n T / 2)
    # with C <= |y_start - orbit| * cond <~ 50 here; n = 150 at W <= 1.5 gives t >= 628 and
    # 50 exp(-0.05 * 628) < 1e-12 (relative to A >= 0.79). The rest is the peak located on
    # the quintic Hermite interpolant of (x, x', x'') at 128 samples per period, whose error
    # is <= (2 pi/128)^6 / 720 ~ 2e-11 relative, and less at a maximum (second order in the
    # location error). Measured: 2.8e-13. The sampled maximum alone would be off by up to
    # A (pi/128)^2 / 2 = 3e-4 relative.
    mu = 0.1
    w = np.linspace(0.5, 1.5, 7)
    res = frequency_sweep(linear(mu), w, transient_periods=150, tol=None, **QUIET)
    up = res.up
    exact = linear_amplitude(mu, 1.0, w)
    np.testing.assert_allclose(up.omega, w)
    np.testing.assert_allclose(up.amplitude, exact, rtol=3e-11)
    # a single harmonic: first-harmonic amplitude = amplitude, zero mean (FFT over whole
    # periods of a pure harmonic is exact up to rounding)
    np.testing.assert_allclose(up.first_harmonic_amplitude, exact, rtol=1e-12)
    np.testing.assert_allclose(up.mean, 0.0, atol=1e-12)
    assert np.all(up.period == 1)
    # multipliers of the linear oscillator: modulus exp(-mu T/2) per forcing period
    np.testing.assert_allclose(up.max_multiplier, np.exp(-mu / 2 * TWO_PI / w), rtol=1e-10)
    assert all(s.transient_periods == 150 for s in up.states)


def test_linear_sweep_has_no_hysteresis_and_tol_mode_is_accurate():
    # Early stop at residual r <= tol: the distance to the orbit is about
    # r (1 + |y|) / (1 - exp(-mu T/2)) <= 1e-10 * 11 / (1 - 0.73) ~ 4e-9 (T <= 2 pi here).
    mu = 0.1
    w = np.array([0.6, 0.9, 1.0, 1.2])
    res = frequency_sweep(linear(mu), w, direction="both", tol=1e-10, **QUIET)
    exact = linear_amplitude(mu, 1.0, w)
    np.testing.assert_allclose(res.up.amplitude, exact, rtol=1e-8)
    np.testing.assert_allclose(res.down.amplitude[::-1], exact, rtol=1e-8)
    np.testing.assert_allclose(res.down.omega, w[::-1])
    assert res.up.jumps(0.9) == [] and res.down.jumps(0.9) == []
    assert np.all(res.up.residual <= 4e-10)


def test_multiplier_from_transient_decay_without_sensitivities():
    # multipliers=False: |mu| per period from the geometric decay of the stroboscopic
    # residuals; the max-norm of a rotating, decaying error oscillates, so only ~5 %
    mu = 0.1
    w = np.array([0.6, 0.9, 1.0, 1.2])
    res = frequency_sweep(linear(mu), w, multipliers=False, **QUIET)
    np.testing.assert_allclose(res.up.max_multiplier, np.exp(-mu / 2 * TWO_PI / w), rtol=0.05)


def duffing_hb_folds() -> tuple[float, float]:
    r"""Folds of single-harmonic balance for x'' + 0.1 x' + x + x^3 = 0.5 cos(W t).

    With x = A cos(W t - phi): (1 + 3A^2/4 - W^2) A = 0.5 cos(phi), 0.1 W A = 0.5 sin(phi), so
    (W^2 - 1 - 3A^2/4)^2 A^2 + (0.1 W A)^2 = 0.25. With c = 1 + 3A^2/4 and u = c - W^2 this
    is u^2 - 0.01 u + 0.01 c - 0.25/A^2 = 0: u = 0.005 -+ sqrt(D), D = 2.5e-5 - 0.01 c +
    0.25/A^2, so W^2 = c - 0.005 +- sqrt(D). The folds are the turning points dW/dA = 0 of
    the '+' branch W_+^2(A): the lower fold is its interior minimum (where the small-amplitude
    branch above resonance ends), the upper fold its maximum next to the peak A_max (D = 0).
    """
    A = np.linspace(0.05, 3.0, 600_001)
    c = 1 + 0.75 * A**2
    D = 2.5e-5 - 0.01 * c + 0.25 / A**2
    A, c, D = A[D >= 0], c[D >= 0], D[D >= 0]
    wp = c - 0.005 + np.sqrt(D)
    i_low = int(np.argmin(wp))
    upper = wp[i_low:]
    return math.sqrt(wp[i_low]), math.sqrt(upper.max())


def test_duffing_hb_folds_oracle_sanity():
    lo, hi = duffing_hb_folds()
    # backbone W^2 = 1 + 3A^2/4 with A_peak ~ F/(mu W): W^4 - W^2 - 18.75 = 0 -> W ~ 2.20
    assert lo == pytest.approx(1.4378, abs=2e-4)
    assert hi == pytest.approx(2.2047, abs=2e-4)


def test_duffing_up_and_down_sweeps_show_the_hysteresis_window():
    r"""Hardening Duffing x'' + 0.1 x' + x + x^3 = 0.5 cos(W t).

    Tolerance on the fold frequencies: one-term harmonic balance drops the third harmonic,
    whose size relative to the first is about (A^2/4) / |9 W^2 - 1 - 3A^2/2| ~ 4 % at the
    upper fold (A ~ 2.27, W ~ 2.2) and < 1 % at the lower one (A ~ 0.7, W ~ 1.44); it shifts
    the fold frequency at second order (measured with a 0.01 grid: 2.21-2.22 vs HB 2.205,
    1.43-1.44 vs HB 1.438). The jump is only located to the grid step (0.04-0.06, <= 2.8 %
    of W), so the HB fold must lie in the bracketing interval widened by 3 %.
    """
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5)
    # below 1.3 HB has a single solution, so the up sweep from rest climbs the large branch
    w = np.array([1.3, 1.36, 1.40, 1.44, 1.48, 1.52, 1.6, 1.8, 2.0, 2.1, 2.16, 2.22, 2.28, 2.34])
    res = frequency_sweep(
        osc,
        w,
        direction="both",
        tol=1e-5,
        record_periods=2,
        multipliers=False,
        rtol=1e-7,
        atol=1e-9,
        **QUIET,
    )
    lo_hb, hi_hb = duffing_hb_folds()
    up_jumps, down_jumps = res.up.jumps(0.5), res.down.jumps(0.5)
    assert len(up_jumps) == 1 and len(down_jumps) == 1
    (w0, w1, a0, a1), (v0, v1, b0, b1) = up_jumps[0], down_jumps[0]
    # up sweep: jump DOWN just past the upper fold
    assert a0 > 5 * a1 and w0 * 0.97 <= hi_hb <= w1 * 1.03
    # down sweep: jump UP just past the lower fold
    assert b1 > 2 * b0 and v1 * 0.97 <= lo_hb <= v0 * 1.03
    # inside the window both a large and a small response exist and both were reached by
    # simulation (so both are stable); outside it the two sweeps agree
    up = dict(zip(np.round(res.up.omega, 6), res.up.amplitude, strict=True))
    dn = dict(zip(np.round(res.down.omega, 6), res.down.amplitude, strict=True))
    for om in (1.6, 1.8, 2.0, 2.1, 2.16):
        assert up[om] > 1.0 > 0.5 > dn[om], (om, up[om], dn[om])
    for om in (1.3, 1.36, 2.28, 2.34):
        assert up[om] == pytest.approx(dn[om], rel=1e-4)
    assert np.all(res.up.period == 1) and np.all(res.down.period == 1)


@pytest.mark.slow
def test_duffing_folds_on_a_fine_grid():
    # 0.01 steps near the folds: the jumps bracket the HB folds to within 1 %
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5)
    w = np.round(
        np.concatenate(
            [np.arange(1.3, 1.5, 0.01), np.arange(1.6, 2.11, 0.1), np.arange(2.15, 2.3, 0.01)]
        ),
        6,
    )
    res = frequency_sweep(osc, w, direction="both", tol=1e-6, record_periods=2, **QUIET)
    lo_hb, hi_hb = duffing_hb_folds()
    (w0, w1, _, _), (v0, v1, _, _) = res.up.jumps(0.5)[0], res.down.jumps(0.5)[0]
    assert w0 * 0.99 <= hi_hb <= w1 * 1.01
    assert v1 * 0.99 <= lo_hb <= v0 * 1.01


def test_sweep_converts_to_response_and_csv():
    res = frequency_sweep(linear(0.2), [0.8, 1.0], direction="both", **QUIET)
    r_up = res.to_response("up")
    assert r_up.method == "sweep-up" and len(r_up.branches) == 1
    r_dn = res.to_response("down")
    assert r_dn.method == "sweep-down"
    both = res.to_response()
    assert both.method == "sweep-both" and len(both.branches) == 2
    lines = r_up.to_csv().splitlines()
    assert lines[0] == ",".join(CSV_COLUMNS)
    assert all(line.split(",")[5] == "1" for line in lines[1:])  # stable
    assert all(line.endswith(",sweep-up") for line in lines[1:])
    assert float(lines[1].split(",")[6]) == pytest.approx(math.exp(-0.1 * TWO_PI / 0.8))
    single = frequency_sweep(linear(0.2), [0.8], direction="down", **QUIET)
    assert single.to_response().method == "sweep-down"
    with pytest.raises(ParameterError, match="this sweep has down"):
        single.to_response("up")


def test_results_are_frozen_and_printable():
    res = frequency_sweep(linear(0.2), [0.9], **QUIET)
    assert isinstance(res, SweepResult)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.model = "x"  # type: ignore[misc]
    st = res.up.states[0]
    with pytest.raises(ValueError):
        st.poincare[0, 0] = 1.0
    text = repr(res)
    assert "SweepBranch(up, 1 points" in text and "period-1" in repr(st)


def test_progress_is_reported_on_stderr(capsys, monkeypatch):
    monkeypatch.delenv("PERTURB_PROGRESS", raising=False)
    frequency_sweep(linear(0.2), [0.8, 0.9], progress=True)
    assert "[perturb] sweep up 2/2" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# Poincaré sections
# ---------------------------------------------------------------------------------------------
def test_poincare_section_of_period_one_orbit_is_one_point():
    # Fig. 5: k = -2, mu = 0.05, F = 2, W = 0.6, one stable orbit
    osc = builtin_model("nsd", k=-2, mu=0.05, F=2, Omega=0.6)
    ps = poincare_section(osc, [0.0, 0.0], 12, transient=300, **QUIET)
    assert isinstance(ps, PoincareSection) and len(ps) == 12
    assert ps.spread < 1e-9
    assert ps.detected_period(1e-9) == 1
    np.testing.assert_allclose(np.diff(ps.times), TWO_PI / 0.6, rtol=1e-13)
    # another phase of the same orbit is another single point
    ps_half = poincare_section(osc, ps.points[-1], 5, phase=0.5, transient=0, **QUIET)
    assert ps_half.spread < 1e-9
    assert np.max(np.abs(ps_half.points[0] - ps.points[0])) > 0.1


def test_poincare_section_of_period_two_orbit_is_two_points():
    # Found by the F-diagram of Fig. 8's setting (k = -4, mu = 0.25, W = 1.2): the orbit is
    # period-2 for F in [6, 7] (period-5 for F in [7.25, 8.5], period-1 from 8.75)
    osc = builtin_model("nsd", k=-4, mu=0.25, F=6.5, Omega=1.2)
    ps = poincare_section(osc, [0.0, 0.0], 10, transient=300, **QUIET)
    pts = ps.distinct(1e-9)
    assert len(pts) == 2
    assert np.max(np.abs(pts[0] - pts[1])) > 1.0
    assert np.max(np.abs(ps.points[2:] - ps.points[:-2])) < 1e-9
    assert ps.detected_period(1e-9) == 2


# ---------------------------------------------------------------------------------------------
# Lyapunov exponents
# ---------------------------------------------------------------------------------------------
def test_lyapunov_of_linear_oscillator_is_minus_half_mu():
    # Monodromy M = exp(A T) (closed form): lambda_n = ln|M^n w0| / (nT) exactly, and since M
    # has the complex pair exp(-mu T/2 +- i beta T), |lambda_n + mu/2| <= ln(cond V) / (nT)
    # (V = eigenvectors of M). n = 2000 periods of T = 2 pi/0.8 gives a bound ~3e-6.
    mu, W, n = 0.1, 0.8, 2000
    T = TWO_PI / W
    w0 = np.array([1.0, 0.0])
    res = lyapunov_exponent(linear(mu, Omega=W), [0.3, 0.0], n, transient=0, tangent0=w0, **QUIET)
    assert isinstance(res, LyapunovResult)
    M = linear_monodromy(mu, T)
    ev, V = np.linalg.eig(M)
    np.testing.assert_allclose(np.abs(ev), math.exp(-mu * T / 2), rtol=1e-12)
    bound = math.log(np.linalg.cond(V)) / (n * T)
    assert bound < 4e-6
    assert abs(res.value + mu / 2) <= bound
    # the same finite-n number from the closed-form monodromy: a check of every step
    pred = log_growth(M, w0, n) / (n * T)
    assert res.value == pytest.approx(pred, abs=1e-12)
    # Liouville: lambda_1 + lambda_2 = -mu
    assert sum(res.exponents) == pytest.approx(-mu, abs=1e-12)
    assert res.spread < 1e-4


class _StructuralFlow:
    """A flow with only the structural interface (not derived from Flow), forcing period
    declared or absent."""

    def __init__(self, inner, period):
        self.inner = inner
        if period is not None:
            self.period = period

    def __call__(self, y0, t0, t1, *, sensitivity=False, t_eval=None):
        return self.inner(y0, t0, t1, sensitivity=sensitivity, t_eval=t_eval)

    def vector_field(self, t, y):
        return self.inner.vector_field(t, y)


def test_structural_flow_is_read_through_its_declared_period():
    # the linear oscillator: lambda = -mu/2 whichever flow object carries it; a structural
    # flow's period is read as declared, and one without a period is autonomous (needs one)
    mu, W = 0.1, 0.8
    inner = ODEFlow(linear(mu, Omega=W))
    res = lyapunov_exponent(_StructuralFlow(inner, inner.period), [0.3, 0.0], 200, **QUIET)
    assert res.period == pytest.approx(TWO_PI / W, rel=1e-15)
    assert res.value == pytest.approx(-mu / 2, abs=2e-3)
    with pytest.raises(ParameterError, match="autonomous"):
        poincare_section(_StructuralFlow(inner, None), [0.3, 0.0], 2, **QUIET)
    sec = poincare_section(_StructuralFlow(inner, None), [0.3, 0.0], 2, period=1.0, **QUIET)
    assert sec.period == 1.0


def _period_two_orbit():
    osc = builtin_model("nsd", k=-4, mu=0.25, F=6.5, Omega=1.2)
    flow = make_flow(osc)
    ps = poincare_section(flow, [0.0, 0.0], 1, transient=300, **QUIET)
    return flow, ps.points[-1], ps.times[-1]


def test_lyapunov_of_periodic_orbit_equals_floquet_multiplier():
    # Period-2 orbit of nsd (k = -4, mu = 0.25, F = 6.5, W = 1.2). Its monodromy over 2T is
    # computed by finite differences of the flow map (independent of the sensitivity and
    # saltation code); real multipliers, so ln|mu_max| / (2T) differs from -mu/2 and the
    # test would catch a tangent dynamics reduced to its determinant.
    flow, y, t0 = _period_two_orbit()
    T = flow.period
    M = fd_monodromy(flow, y, t0, t0 + 2 * T)
    mult = np.linalg.eigvals(M)
    assert np.all(np.isreal(mult))
    mu_max = float(np.max(np.abs(mult)))
    expected = math.log(mu_max) / (2 * T)
    assert abs(expected + 0.125) > 0.05
    n = 200
    w0 = np.array([1.0, 0.0])
    res = lyapunov_exponent(flow, y, n, transient=0, tangent0=w0, **QUIET)
    # finite n: lambda_n = ln|M^(n/2) w0| / (nT); with real multipliers the error is
    # ln|c1| / (nT) + O((mu_2/mu_1)^n) (c1: component of w0 along the dominant eigenvector)
    pred = log_growth(M, w0, n // 2) / (n * T)
    assert res.value == pytest.approx(pred, abs=1e-8)  # FD monodromy good to ~1e-8
    ev, V = np.linalg.eig(M)
    c = np.linalg.solve(V, w0)
    k = int(np.argmax(np.abs(ev)))
    bound = abs(math.log(abs(c[k]) * np.linalg.norm(V[:, k]))) / (n * T) + 1e-8
    assert abs(res.value - expected) <= bound
    assert sum(res.exponents) == pytest.approx(-0.25, abs=1e-12)


def test_lyapunov_of_period_one_orbit_matches_complex_floquet_pair():
    # Fig. 5 orbit: complex pair |mu| = exp(-mu T / 2); bound ln(cond V) / (nT)
    osc = builtin_model("nsd", k=-2, mu=0.05, F=2, Omega=0.6)
    flow = make_flow(osc)
    ps = poincare_section(flow, [0.0, 0.0], 1, transient=300, **QUIET)
    y, t0, T = ps.points[-1], ps.times[-1], flow.period
    M = fd_monodromy(flow, y, t0, t0 + T)
    ev, V = np.linalg.eig(M)
    n = 100
    res = lyapunov_exponent(flow, y, n, transient=0, **QUIET)
    expected = math.log(np.max(np.abs(ev))) / T
    assert abs(res.value - expected) <= math.log(np.linalg.cond(V)) / (n * T) + 1e-8


def test_lyapunov_of_chaotic_nsd_is_positive_and_converged():
    # nsd k = -0.5, mu = 0.05, F = 2, W = 1.2: chaotic (perturbations of 1e-10 reach O(1) in
    # ~50 periods, tests/test_piecewise_exact.py). Measured: lambda_1 = 0.098 over 1000
    # periods; over 400 periods the running estimate varies by < 0.02 over the last half.
    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2, Omega=1.2)
    res = lyapunov_exponent(osc, [0.5, 0.0], 400, transient=100, **QUIET)
    assert 0.06 < res.value < 0.14
    assert res.spread < 0.02
    assert sum(res.exponents) == pytest.approx(-0.05, abs=1e-10)
    assert "lambda1=" in repr(res)


@pytest.mark.slow
def test_lyapunov_of_ueda_attractor():
    # Ueda: x'' + 0.05 x' + x^3 = 7.5 cos t, lambda_1 ~ 0.1 (Ueda 1980; smooth, ODE flow)
    ueda = Oscillator.parse("x'' + 0.05*x' + x**3 = 7.5*cos(t)")
    res = lyapunov_exponent(ueda, [2.5, 0.0], 400, transient=50, **QUIET)
    assert 0.08 < res.value < 0.13
    assert res.spread < 0.03
    assert sum(res.exponents) == pytest.approx(-0.05, abs=1e-7)


# ---------------------------------------------------------------------------------------------
# bifurcation diagrams
# ---------------------------------------------------------------------------------------------
def test_bifurcation_diagram_over_mu_fig7():
    # Fig. 7 as reconstructed: k = -4, F = 1, W = 0.45, mu swept; two runs (rest and a state
    # in the other well) continued over mu. At mu = 1 (and 0.7) the attractor is period-1.
    osc = builtin_model("nsd", k=-4, mu=0.1, F=1.0, Omega=0.45)
    mus = [0.1, 0.4, 0.7, 1.0]
    bd = bifurcation_diagram(
        osc, "mu", mus, initial_conditions=[[0.0, 0.0], [-5.0, 0.0]], record_periods=8, **QUIET
    )
    assert isinstance(bd, BifurcationDiagram)
    assert bd.x.shape == (2, 4, 8) and np.all(np.isfinite(bd.x))
    p, x = bd.points()
    assert p.shape == x.shape == (64,)
    distinct = bd.n_distinct(1e-8)
    assert np.all(distinct[:, 2:] == 1), distinct
    assert np.all(bd.period[:, 2:] == 1)
    assert "BifurcationDiagram(nsd" in repr(bd)


def test_bifurcation_diagram_detects_period_two_and_phase():
    osc = builtin_model("nsd", k=-4, mu=0.25, F=6.0, Omega=1.2)
    bd = bifurcation_diagram(osc, "F", [6.0, 6.5], record_periods=6, phase=0.25, **QUIET)
    assert np.all(bd.period == 2)
    assert np.all(bd.n_distinct(1e-8) == 2)


@pytest.mark.slow
def test_bifurcation_diagram_over_F_fig8_period_change_near_8_7():
    # Fig. 8 (k = -4, mu = 0.25, W = 1.2, F swept): the paper reports the period changing
    # near F ~ 8.7; continued from rest at F = 6 the response is period-5 up to F = 8.5 and
    # period-1 from F = 8.75
    osc = builtin_model("nsd", k=-4, mu=0.25, F=6.0, Omega=1.2)
    Fs = np.arange(6.0, 10.01, 0.25)
    bd = bifurcation_diagram(osc, "F", Fs, record_periods=16, **QUIET)
    per = dict(zip(np.round(Fs, 2), bd.period[0], strict=True))
    assert per[6.0] == 2 and per[8.5] == 5 and per[8.75] == 1 and per[10.0] == 1


# ---------------------------------------------------------------------------------------------
# basins of attraction
# ---------------------------------------------------------------------------------------------
def test_basins_of_free_damped_nsd_are_two_mirrored_wells():
    # F = 0, mu = 0.1, k = -2: stable foci at +-(1 - k) = +-3, saddle at 0. The grid is
    # exactly symmetric and the vectorised RK4 exactly odd-equivariant, so the label of
    # (x, v) and of (-x, -v) must be swapped — an exact property, not a tolerance.
    osc = builtin_model("nsd", k=-2, mu=0.1, F=0.0, Omega=1.0)
    b = basins(osc, (-5, 5), (-4, 4), 16, **QUIET)
    assert isinstance(b, BasinResult)
    assert b.labels.shape == (16, 16)
    np.testing.assert_array_equal(b.x, -b.x[::-1])
    np.testing.assert_array_equal(b.v, -b.v[::-1])
    assert len(b.attractors) == 2
    centres = sorted(a.mean_x for a in b.attractors)
    assert centres == pytest.approx([-3.0, 3.0], abs=1e-8)
    for a in b.attractors:
        assert a.period == 1 and abs(a.points[0, 1]) < 1e-8
    assert set(np.unique(b.labels)) == {0, 1}
    mirror = {0: 1, 1: 0}
    np.testing.assert_array_equal(b.labels[::-1, ::-1], np.vectorize(mirror.get)(b.labels))
    # at rest near a focus the orbit stays in that well
    right = int(np.argmax([a.mean_x for a in b.attractors]))
    assert b.label_at(3.0, 0.0) == right
    assert sum(b.fractions().values()) == pytest.approx(1.0)
    assert "2 attractors" in repr(b)


def test_basins_per_initial_condition_flow_agrees_with_vectorised():
    osc = builtin_model("nsd", k=-2, mu=0.1, F=0.0, Omega=1.0)
    kw = dict(n=(4, 3), **QUIET)
    fast = basins(osc, (-4.5, 4.5), (-3, 3), **kw)
    slow = basins(osc, (-4.5, 4.5), (-3, 3), vectorised=False, **kw)
    centre = {i: round(a.mean_x) for i, a in enumerate(fast.attractors)}
    centre_slow = {i: round(a.mean_x) for i, a in enumerate(slow.attractors)}
    np.testing.assert_array_equal(
        np.vectorize(centre.get)(fast.labels), np.vectorize(centre_slow.get)(slow.labels)
    )


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: frequency_sweep(linear(), [0.5, -1.0]), "expected positive values"),
        (lambda: frequency_sweep(linear(), []), "non-empty"),
        (lambda: frequency_sweep(linear(), [1.0], direction="sideways"), "'up', 'down'"),
        (lambda: frequency_sweep(linear(), [1.0], record_periods=0), "record_periods"),
        (lambda: frequency_sweep(linear(), [1.0], tol=2.0), "relative tolerance"),
        (lambda: frequency_sweep(linear(), [1.0], y0=[1.0, np.nan]), "y0"),
        (lambda: frequency_sweep(linear(), [1.0], samples_per_period=4), "samples_per_period"),
        (lambda: frequency_sweep("nsd", [1.0]), "expected an Oscillator"),
        (lambda: frequency_sweep(linear(), [1.0], method="magic"), "method"),
        (lambda: poincare_section(linear(), [0, 0], 0), "n_points"),
        (lambda: poincare_section(linear(), [0, 0], 3, phase=1.0), "phase"),
        (lambda: poincare_section(42, [0, 0], 3), "Oscillator or a Flow"),
        (lambda: bifurcation_diagram(linear(), "nope", [1.0]), "parameter = 'nope'"),
        (lambda: bifurcation_diagram(linear(), "mu", [0.1, np.inf]), "finite"),
        (
            lambda: bifurcation_diagram(linear(), "mu", [0.1], initial_conditions=[[1, 2, 3]]),
            "n_runs, 2",
        ),
        (lambda: basins(linear(), (1, -1), (0, 1), 4), "low < high"),
        (lambda: basins(linear(), (0, 1), (0, 1), (4,)), "nx, nv"),
        (lambda: lyapunov_exponent(linear(), [0, 0], 1), "n_periods"),
        (lambda: lyapunov_exponent(linear(), [0, 0], 5, tangent0=[0, 0]), "nonzero"),
    ],
)
def test_bad_input_raises_clear_errors(call, match):
    with pytest.raises(ParameterError, match=match):
        call()


def test_unforced_and_autonomous_models_are_rejected_clearly():
    free = Oscillator.parse("x'' + 0.1*x' + x = 0")
    with pytest.raises(ModelError, match="no forcing-frequency parameter"):
        frequency_sweep(free, [1.0])
    with pytest.raises(ParameterError, match="autonomous"):
        poincare_section(free, [1.0, 0.0], 3)
    # with an explicit sampling period the autonomous flow is fine: the focus at 0
    ps = poincare_section(free, [1.0, 0.0], 3, period=1.0, transient=600, **QUIET)
    assert np.max(np.abs(ps.points)) < 1e-12


def test_unbounded_response_raises():
    # negative stiffness everywhere: x'' + 0.1 x' - x = cos(t) escapes
    osc = Oscillator.parse("x'' + 0.1*x' - x = F*cos(Omega*t)", {"F": 1.0, "Omega": 1.0})
    with pytest.raises(PerturbError):
        frequency_sweep(osc, [1.0], transient_periods=400, **QUIET)


def test_options_objects_equal_their_keywords():
    """The tuning knobs of basins and frequency_sweep as a frozen options object or as
    keywords are one configuration (a keyword replaces the object's field); a misspelt knob
    is refused by name, not ignored."""
    from perturb.simulate.studies import BasinOptions, BifurcationOptions, SweepOptions

    osc = builtin_model("nsd", k=-2, mu=0.1, F=0.0, Omega=1.0)
    by_keywords = basins(osc, (-5, 5), (-4, 4), 8, max_periods=300, progress=False)
    opts = BasinOptions(max_periods=300, progress=False)
    by_object = basins(osc, (-5, 5), (-4, 4), 8, opts)
    overridden = basins(
        osc, (-5, 5), (-4, 4), 8, BasinOptions(max_periods=5), max_periods=300, progress=False
    )
    for other in (by_object, overridden):
        np.testing.assert_array_equal(other.labels, by_keywords.labels)
    # too short to settle: every orbit unresolved, so max_periods really reaches the solver
    short = basins(osc, (-5, 5), (-4, 4), 8, opts, max_periods=1, check_every=1, refine=False)
    assert np.all(short.labels == -1)
    w = [0.8, 1.0]
    a = frequency_sweep(
        linear(0.2), w, SweepOptions(tol=None, transient_periods=50, progress=False)
    )
    b = frequency_sweep(linear(0.2), w, tol=None, transient_periods=50, progress=False)
    np.testing.assert_array_equal(a.up.amplitude, b.up.amplitude)
    with pytest.raises(ParameterError, match="max_period_s"):
        basins(osc, (-5, 5), (-4, 4), 8, max_period_s=3)
    with pytest.raises(ParameterError, match="SweepOptions"):
        frequency_sweep(linear(0.2), w, BasinOptions())
    with pytest.raises(ParameterError, match="phases"):
        bifurcation_diagram(osc, "F", [0.0], BifurcationOptions(progress=False), phases=0.5)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.tol = 1.0  # type: ignore[misc]
