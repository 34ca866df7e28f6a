"""Numeric multi-harmonic harmonic balance and the generic continuation core.

Oracles (never the code under test):

* the exact Galerkin projection against scipy ``quad`` on each piece between crossings that
  are found independently, as roots of the degree-2K polynomial in ``z = exp(i theta)``
  (numpy companion matrix) — so neither the crossings nor the integrals come from the module;
* analytic Jacobians against central finite differences;
* exact periodic orbits of the nsd oscillator
(:func:`perturb.simulate.orbits.search.periodic_orbits`,
  exact piecewise-analytic flow) and their Fourier coefficients from 2**16 samples of the
  exact dense output (aliasing ~1e-19 for coefficients decaying like k**-4); the *floor* at
  ``H`` is the amplitude error of the exact orbit's own series truncated at ``H`` (its maximum
  found by dense sampling and scipy's bounded minimiser);
* a tight DOP853 shooting orbit (rtol 1e-13) of the forced Duffing oscillator, with its
  Floquet multipliers;
* closed-form curves (a cubic with two folds, a circle) for the continuation core.

Measured (recorded by ``test_aft_falls_short_of_the_floor`` with ``-s``): on nsd, k = -0.5,
the exact-Galerkin error stays within a factor 1.3 of the floor for H = 1..63 (2.2e-8 relative
at H = 63, Omega = 0.6); AFT with 4H + 1 samples is 7-850 times the floor for H >= 21 (median
over H = 21, 31, 47, 63: ~230 at Omega = 0.6, ~180 at Omega = 0.9).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.optimize import minimize_scalar

from perturb.errors import ModelError, ParameterError
from perturb.fourier.projection import HarmonicBasis, pwl_projection, switching_angles
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator
from perturb.model.pwl import NumericPWL
from perturb.numeric.continuation import ContinuationError, continue_curve, newton_fixed
from perturb.numeric.harmonic_balance import (
    HarmonicBalanceSolution,
    HarmonicBalanceSystem,
    harmonic_balance_branch,
    harmonic_balance_branch_through,
    harmonic_balance_branches,
    harmonic_balance_orbit,
    harmonic_balance_response,
)
from perturb.response import CSV_COLUMNS
from perturb.seeds import single_harmonic_seeds
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.orbits.shooting import periodic_orbit
from perturb.solve import periodic_orbits

TWO_PI = 2.0 * math.pi
NSD = {"k": -0.5, "mu": 0.05, "F": 2.0}
H_LIST = (1, 2, 3, 5, 7, 9, 11, 15, 21, 31, 47, 63)


def nsd(Omega: float = 0.6) -> Oscillator:
    return builtin_model("nsd", Omega=Omega, **NSD)


# ---------------------------------------------------------------------------------------------
# independent oracles
# ---------------------------------------------------------------------------------------------
def series(u: np.ndarray, basis: HarmonicBasis):
    """x(theta) and x'(theta) of a coefficient vector, written out from the definition."""
    a0 = u[0] if basis.bias else 0.0
    ks = np.array(basis.harmonics, dtype=float)
    a = u[int(basis.bias) :: 2][: ks.size]
    b = u[int(basis.bias) + 1 :: 2][: ks.size]

    def x(th):
        th = np.asarray(th, dtype=float)
        return a0 + np.cos(np.multiply.outer(th, ks)) @ a + np.sin(np.multiply.outer(th, ks)) @ b

    def dx(th):
        th = np.asarray(th, dtype=float)
        arg = np.multiply.outer(th, ks)
        return np.cos(arg) @ (ks * b) - np.sin(arg) @ (ks * a)

    return x, dx


def companion_crossings(u: np.ndarray, basis: HarmonicBasis, level: float) -> np.ndarray:
    """Real roots of x(theta) - level from the roots of z^K (x - level), |z| = 1."""
    K = basis.kmax
    coef = np.zeros(2 * K + 1, dtype=complex)  # coef[j] multiplies z**j
    coef[K] = (u[0] if basis.bias else 0.0) - level
    for i, k in enumerate(basis.harmonics):
        a, b = u[int(basis.bias) + 2 * i], u[int(basis.bias) + 2 * i + 1]
        coef[K + k] += 0.5 * (a - 1j * b)
        coef[K - k] += 0.5 * (a + 1j * b)
    roots = np.roots(coef[::-1])
    on_circle = roots[np.abs(np.abs(roots) - 1.0) < 1e-6]
    theta = np.sort(np.mod(np.angle(on_circle), TWO_PI))
    x, dx = series(u, basis)
    for _ in range(5):  # Newton polish in theta
        theta = theta - (x(theta) - level) / dx(theta)
    theta = np.sort(np.mod(theta, TWO_PI))
    keep = np.ones(theta.size, dtype=bool)
    keep[1:] = np.diff(theta) > 1e-9  # a double root of a tangency appears twice
    return theta[keep]


def quadrature_projection(pwl: NumericPWL, basis: HarmonicBasis, u: np.ndarray) -> np.ndarray:
    """(1/2pi) int f, (1/pi) int f cos, (1/pi) int f sin by adaptive quadrature (scipy
    ``quad_vec``, all weights at once) on each piece between crossings."""
    x, _ = series(u, basis)
    cuts = [0.0, TWO_PI]
    for d in pwl.breakpoints:
        cuts += list(companion_crossings(u, basis, d))
    cuts = np.unique(np.array(cuts))
    ks = np.array(basis.harmonics, dtype=float)

    def weights(th: float) -> np.ndarray:
        w = np.empty(basis.size)
        if basis.bias:
            w[0] = 1.0 / TWO_PI
        w[int(basis.bias) :: 2] = np.cos(ks * th) / math.pi
        w[int(basis.bias) + 1 :: 2] = np.sin(ks * th) / math.pi
        return w

    out = np.zeros(basis.size)
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        seg = int(pwl.segment_index(x(0.5 * (lo + hi))))
        slope, offset = pwl.slopes[seg], pwl.offsets[seg]
        val, _ = quad_vec(
            lambda th, slope=slope, offset=offset: (slope * x(th) + offset) * weights(th),
            lo,
            hi,
            epsabs=1e-15,
            epsrel=1e-14,
        )
        out += val
    return out


def truncated_max(c: np.ndarray, H: int) -> float:
    """max |x| of the series sum_{|k| <= H} c_k e^{ik theta} (c from an FFT)."""
    k = np.arange(1, H + 1)

    def x(th):
        return c[0].real + 2.0 * np.real(np.exp(1j * np.multiply.outer(th, k)) @ c[1 : H + 1])

    grid = np.linspace(0.0, TWO_PI, 8192, endpoint=False)
    best = 0.0
    for sign in (1.0, -1.0):
        j = int(np.argmax(sign * x(grid)))
        res = minimize_scalar(
            lambda q, sign=sign: -sign * x(np.array([q]))[0],
            bounds=(grid[j] - 1e-3, grid[j] + 1e-3),
            method="bounded",
            options={"xatol": 1e-13},
        )
        best = max(best, -res.fun)
    return best


@functools.cache
def exact_orbits(Omega: float):
    return periodic_orbits(nsd(Omega), Omega)


def exact_fourier(orbit, Omega: float, n: int = 2**16) -> np.ndarray:
    _, x, _ = orbit.sample(n)
    c = np.fft.rfft(x) / n
    return c * np.exp(-1j * np.arange(c.size) * Omega * orbit.t0)  # theta = Omega t


# ---------------------------------------------------------------------------------------------
# exact projection and Jacobians
# ---------------------------------------------------------------------------------------------
def random_coefficients(rng, basis: HarmonicBasis, bias: float) -> np.ndarray:
    u = np.zeros(basis.size)
    if basis.bias:
        u[0] = bias
    for i, k in enumerate(basis.harmonics):
        u[int(basis.bias) + 2 * i : int(basis.bias) + 2 * i + 2] = rng.normal(size=2) * 2.0 / k
    return u


FORCES = {
    "nsd": NumericPWL([-1.0, 1.0], [1.0, -0.5, 1.0], [1.5, 0.0, -1.5]),
    "three_kinks": NumericPWL([-1.3, 0.2, 0.9], [0.5, 2.0, -1.0, 3.0], [0.0, 1.95, 2.55, -1.05]),
    "jumps": NumericPWL([-0.4, 0.7], [1.0, 0.3, 2.0], [-0.5, 0.2, -0.4]),
}


@pytest.mark.parametrize("force", sorted(FORCES))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_projection_matches_quadrature(force, seed):
    pwl = FORCES[force]
    if force == "three_kinks":  # the offsets above were chosen to make it continuous
        assert np.allclose(pwl.jumps, 0.0)
    rng = np.random.default_rng(seed)
    basis = HarmonicBasis.make(6)
    u = random_coefficients(rng, basis, rng.uniform(-0.5, 0.5))
    x, _ = series(u, basis)
    n_cross = sum(companion_crossings(u, basis, d).size for d in pwl.breakpoints)
    assert n_cross >= 4  # the test is about many switches
    ours = pwl_projection(pwl, basis, u)
    ref = quadrature_projection(pwl, basis, u)
    scale = max(1.0, float(np.abs(ref).max()))
    assert np.max(np.abs(ours - ref)) < 1e-12 * scale


def test_exact_projection_odd_basis_and_no_crossing():
    pwl = FORCES["nsd"]
    basis = HarmonicBasis.make(7, odd_only=True)
    u = random_coefficients(np.random.default_rng(5), basis, 0.0)
    assert np.max(np.abs(pwl_projection(pwl, basis, u) - quadrature_projection(pwl, basis, u))) < (
        1e-12 * max(1.0, np.abs(u).max())
    )
    # inside one segment the projection is the linear map itself
    full = HarmonicBasis.make(4)
    v = np.zeros(full.size)
    v[0], v[1], v[4] = 3.0, 0.7, 0.2
    np.testing.assert_allclose(pwl_projection(pwl, full, v), v - 1.5 * np.eye(full.size)[0])


def test_switching_angles_match_companion_roots_including_near_tangency():
    basis = HarmonicBasis.make(5)
    rng = np.random.default_rng(11)
    for _ in range(20):
        u = random_coefficients(rng, basis, rng.uniform(-1, 1))
        level = rng.uniform(-1, 1)
        np.testing.assert_allclose(
            switching_angles(basis, u, level), companion_crossings(u, basis, level), atol=1e-12
        )
    # x = cos(theta) + 0.2 cos(3 theta): max 1.2 at theta = 0
    u = np.zeros(basis.size)
    u[1], u[5] = 1.0, 0.2
    assert switching_angles(basis, u, 1.2).size == 0  # touching is not crossing
    eps = 1e-10
    th = switching_angles(basis, u, 1.2 - eps)
    assert th.size == 2  # a pair 2 sqrt(2 eps / 2.8) apart across theta = 0
    gap = min(th[0], TWO_PI - th[1]) * 2
    assert abs(gap - 2 * math.sqrt(2 * eps / 2.8)) < 1e-3 * gap
    x, _ = series(u, basis)
    np.testing.assert_allclose(x(th), 1.2 - eps, atol=1e-15)


@pytest.mark.parametrize("force", sorted(FORCES))
def test_projection_jacobian_matches_finite_differences(force):
    pwl = FORCES[force]
    basis = HarmonicBasis.make(5)
    u = random_coefficients(np.random.default_rng(3), basis, 0.1)
    _, J = pwl_projection(pwl, basis, u, jacobian=True)
    h = 1e-6
    fd = np.column_stack(
        [
            (pwl_projection(pwl, basis, u + h * e) - pwl_projection(pwl, basis, u - h * e))
            / (2 * h)
            for e in np.eye(basis.size)
        ]
    )
    assert np.max(np.abs(J - fd)) < 1e-7 * max(1.0, np.abs(J).max())


@pytest.mark.parametrize(
    "osc, projection",
    [
        (nsd(), "exact"),
        (nsd(), "aft"),
        (builtin_model("duffing"), "aft"),
        (
            Oscillator.parse(
                "x'' - eps*(1 - x**2)*x' + x = F*cos(Omega*t)", {"eps": 0.3, "F": 0.4, "Omega": 1.1}
            ),
            "aft",
        ),
    ],
    ids=["nsd-exact", "nsd-aft", "duffing-aft", "forced-vdp-aft"],
)
def test_system_jacobians_match_finite_differences(osc, projection):
    system = HarmonicBalanceSystem(osc, harmonics=4, projection=projection)
    u = random_coefficients(np.random.default_rng(7), system.basis, 0.2)
    W = 0.83
    _, Ju, Jw = system.evaluate(u, W)
    h = 1e-6
    fd_u = np.column_stack(
        [
            (system.residual(u + h * e, W) - system.residual(u - h * e, W)) / (2 * h)
            for e in np.eye(u.size)
        ]
    )
    fd_w = (system.residual(u, W + h) - system.residual(u, W - h)) / (2 * h)
    scale = max(1.0, np.abs(Ju).max())
    assert np.max(np.abs(Ju - fd_u)) < 1e-7 * scale
    assert np.max(np.abs(Jw - fd_w)) < 1e-7 * scale


# ---------------------------------------------------------------------------------------------
# accuracy against exact orbits
# ---------------------------------------------------------------------------------------------
@functools.cache
def error_table(Omega: float) -> dict[str, np.ndarray]:
    orbits = exact_orbits(Omega)
    assert len(orbits) == 1  # one period-1 orbit at these frequencies: no matching needed
    orbit = orbits[0]
    c = exact_fourier(orbit, Omega)
    A = orbit.amplitude
    assert np.abs(c[c.size // 4 :]).max() < 1e-15 * A  # resolved: no aliasing to speak of
    osc = nsd(Omega)
    rows = {"H": [], "exact": [], "floor": [], "aft": []}
    guess = None
    for H in H_LIST:
        sol = harmonic_balance_orbit(osc, Omega, harmonics=H, guess=guess, stability="none")
        guess = sol
        aft = harmonic_balance_orbit(
            osc, Omega, harmonics=H, projection="aft", guess=sol, stability="none"
        )
        # the same orbit as the exact one (the only one): first harmonic within the floor
        assert abs(sol.first_harmonic_amplitude - orbit.first_harmonic_amplitude) < 0.05 * A
        rows["H"].append(H)
        rows["exact"].append(abs(sol.amplitude - A) / A)
        rows["floor"].append(abs(truncated_max(c, H) - A) / A)
        rows["aft"].append(abs(aft.amplitude - A) / A)
    return {k: np.array(v) for k, v in rows.items()}


@pytest.mark.parametrize("Omega", [0.6, 0.9])
def test_exact_galerkin_reaches_the_truncation_floor(Omega):
    t = error_table(Omega)
    ratio = t["exact"] / t["floor"]
    assert np.all(ratio < 2.0) and np.all(ratio > 0.5), ratio
    assert t["exact"][t["H"] == 63][0] < 1e-7


@pytest.mark.parametrize("Omega", [0.6, 0.9])
def test_aft_falls_short_of_the_floor(Omega, record_property):
    t = error_table(Omega)
    ratio = t["aft"] / t["floor"]
    lines = [f"nsd k=-0.5 Omega={Omega}: H, exact-Galerkin err, floor, AFT(4H+1) err, AFT/floor"]
    for H, e, f, a, r in zip(t["H"], t["exact"], t["floor"], t["aft"], ratio, strict=True):
        lines.append(f"  {H:3d}  {e:.2e}  {f:.2e}  {a:.2e}  {r:7.1f}")
    print("\n".join(lines))
    record_property(
        f"aft_over_floor_{Omega}", dict(zip(t["H"].tolist(), ratio.tolist(), strict=True))
    )
    high = t["H"] >= 21
    assert np.all(ratio[high] > 5.0), ratio  # aliasing of the kinks, not truncation
    assert np.median(ratio[high]) > 50.0


def test_odd_basis_and_subharmonic_embedding_agree():
    osc = nsd(0.6)
    full = harmonic_balance_orbit(osc, 0.6, harmonics=15, stability="none")
    odd = harmonic_balance_orbit(osc, 0.6, harmonics=15, odd_only=True, stability="none")
    assert abs(odd.amplitude - full.amplitude) < 1e-12 * full.amplitude
    np.testing.assert_allclose(full.b[1::2], 0.0, atol=1e-12)  # even harmonics vanish
    # the period-1 orbit seen as a period-2 one: harmonic k becomes 2k
    sub_basis = HarmonicBasis.make(30)
    guess = np.zeros(sub_basis.size)
    guess[0] = full.a0
    for k, a, b in zip(full.harmonics, full.a, full.b, strict=True):
        guess[1 + 2 * (2 * k - 1)], guess[2 + 2 * (2 * k - 1)] = a, b
    sub = harmonic_balance_orbit(osc, 0.6, harmonics=30, m=2, guess=guess, stability="none")
    assert sub.iterations <= 1 and abs(sub.amplitude - full.amplitude) < 1e-12 * full.amplitude
    assert abs(sub.first_harmonic_amplitude - full.first_harmonic_amplitude) < 1e-12


@pytest.mark.parametrize("Omega", [0.8, 1.2, 1.6])
def test_duffing_matches_tight_shooting(Omega):
    osc = builtin_model("duffing")  # x'' + 0.1 x' + x + x^3 = 0.5 cos(Omega t)
    sol = harmonic_balance_orbit(osc, Omega, harmonics=21)
    ref = periodic_orbit(
        ODEFlow(osc, Omega, rtol=1e-13, atol=1e-14),
        [float(sol(0.0)), float(sol.velocity(0.0))],
        tol=1e-13,
    )
    assert abs(sol.amplitude - ref.amplitude) < 1e-10 * ref.amplitude
    assert abs(sol.first_harmonic_amplitude - ref.first_harmonic_amplitude) < 1e-10
    assert abs(sol.max_multiplier - ref.max_multiplier) < 1e-8
    assert sol.stable == ref.is_stable


def test_discontinuous_force_orbit_and_multipliers():
    # a step of 0.3 at x = 0.5: the Jacobian and the Hill matrix carry the switch terms
    osc = Oscillator.parse(
        "x'' + mu*x' + x + r*Heaviside(x - d) = F*cos(Omega*t)",
        {"mu": 0.1, "r": 0.3, "d": 0.5, "F": 1.0, "Omega": 1.3},
    )
    sol = harmonic_balance_orbit(osc, 1.3, harmonics=31)
    (ref,) = periodic_orbits(osc, 1.3)
    assert abs(sol.amplitude - ref.amplitude) < 1e-5 * ref.amplitude  # k^-3 coefficients
    assert abs(sol.max_multiplier - ref.max_multiplier) < 1e-4


# ---------------------------------------------------------------------------------------------
# frequency responses
# ---------------------------------------------------------------------------------------------
@functools.cache
def nsd_branch():
    return harmonic_balance_branch(nsd(), (0.3, 2.0), harmonics=15)


@pytest.mark.parametrize("Omega", [0.6, 0.9, 1.05, 1.5])
def test_frequency_response_passes_through_exact_orbits(Omega):
    br = nsd_branch()
    assert br.curve.stop_reason == "window"
    assert br.omega.min() == pytest.approx(0.3, abs=1e-12)
    assert br.omega.max() == pytest.approx(2.0, abs=1e-12)
    orbits = exact_orbits(Omega)
    crossing = np.nonzero((br.omega[:-1] - Omega) * (br.omega[1:] - Omega) <= 0)[0]
    assert crossing.size >= 1
    for i in crossing:
        f = (Omega - br.omega[i]) / (br.omega[i + 1] - br.omega[i])
        guess = (1 - f) * br.coefficients[i] + f * br.coefficients[i + 1]
        sol = harmonic_balance_orbit(nsd(), Omega, harmonics=15, guess=guess)
        match = min(orbits, key=lambda o: abs(o.amplitude - sol.amplitude))
        assert abs(sol.amplitude - match.amplitude) < 1e-4 * match.amplitude
        # stability away from folds: Hill on the HB orbit against the exact multipliers
        assert sol.stable == match.is_stable
        assert br.stable[i] == br.stable[i + 1] == match.is_stable
        assert abs(sol.max_multiplier - match.max_multiplier) < 1e-3 * match.max_multiplier


def test_response_columns_mean_the_same_as_elsewhere():
    br = nsd_branch()
    resp = br.to_response()
    assert len(resp.branches) == 1 and resp.model == "nsd"
    assert resp.to_csv().splitlines()[0] == ",".join(CSV_COLUMNS)
    for i in range(0, len(br), 20):
        u = br.coefficients[i]
        # max |x| of the series by dense sampling and scipy's bounded minimiser
        c = np.concatenate([[u[0]], 0.5 * (u[1::2] - 1j * u[2::2])])
        assert br.amplitude[i] == pytest.approx(truncated_max(c, 15), rel=1e-11)
        assert br.first_harmonic_amplitude[i] == pytest.approx(math.hypot(u[1], u[2]))
        assert br.mean[i] == u[0]
    again = harmonic_balance_response(nsd(), (0.3, 2.0), harmonics=15)
    np.testing.assert_array_equal(again.branches[0].amplitude, br.amplitude)


def test_fast_hill_path_agrees_with_the_full_eigenproblem():
    br = nsd_branch()
    idx = np.arange(0, len(br), 8)
    system = br.system
    for i in idx:
        fast = system.hill_exponents(br.coefficients[i], br.omega[i])
        full = system.hill_exponents(br.coefficients[i], br.omega[i], full=True)
        assert np.max(fast.real) == pytest.approx(np.max(full.real), rel=1e-8, abs=1e-10)
        np.testing.assert_allclose(np.sort_complex(fast), np.sort_complex(full), atol=1e-4)


def test_duffing_folds_are_where_hill_exponents_vanish():
    osc = builtin_model("duffing")
    br = harmonic_balance_branch(osc, (0.5, 2.5), harmonics=9)
    assert len(br.folds) == 2
    lows = sorted(f[0] for f in br.folds)
    assert 1.3 < lows[0] < 1.6 and 2.1 < lows[1] < 2.4
    for u, (W, _) in zip(br.fold_coefficients, br.folds, strict=True):
        lam = br.system.hill_exponents(u, W, full=True)
        assert np.min(np.abs(lam)) < 1e-6  # a real exponent through 0 at a fold
    flips = np.nonzero(br.stable[1:] != br.stable[:-1])[0]
    assert flips.size == 2
    for j, (W, _) in zip(flips, sorted(br.folds, key=lambda f: -f[0]), strict=False):
        assert (
            min(br.omega[j], br.omega[j + 1]) - 1e-3
            <= W
            <= max(br.omega[j], br.omega[j + 1]) + 1e-3
        )


@functools.cache
def duffing_aft_branch():
    return harmonic_balance_branch(builtin_model("duffing"), (0.5, 2.5), harmonics=9)


def test_duffing_aft_response_is_right_up_to_its_fold():
    """Regression for the work-precision report's max relative error ~17 of AFT HB on forced
    Duffing (H = 3..15, Omega 0.5..2.5). The HB response is not at fault: its upper branch
    reaches Omega = 2.21194, and tight DOP853 shooting (rtol 1e-13) finds the upper orbits
    there; the exact reference stopped sampling its upper branch at 2.21191, so compare
    charged the HB points beyond with the lower branch of the same S-curve (amplitude 0.13
    against 2.32). Oracle: shooting on the ODE, never HB itself."""
    osc = builtin_model("duffing")
    br = duffing_aft_branch()
    assert br.system.projection == "aft"
    upper_fold = max(f[0] for f in br.folds)
    assert upper_fold == pytest.approx(2.21194, abs=2e-5)
    # the points run from Omega = 0.5 along the upper branch to its fold, back along the
    # middle one and out along the lower one to 2.5
    i_peak = int(np.nonzero(np.diff(br.omega) < 0)[0][0])
    flow_W = {}
    # the branch's own points (no re-solve) just below the fold of the upper branch, on the
    # middle and the lower branch: each is the exact orbit to the H = 9 truncation error
    # (measured 4.9e-8 at amplitude 2.3, far less on the lower branches)
    picks = [i_peak - 1, i_peak, i_peak + 3, len(br) - 10, 20]
    for i in picks:
        W = float(br.omega[i])
        u = br.coefficients[i]
        x0 = float(br.system.basis.evaluate(u, np.array([0.0]))[0])
        v0 = float(br.system.basis.evaluate(u, np.array([0.0]), 1)[0]) * W
        flow = flow_W.setdefault(W, ODEFlow(osc, W, rtol=1e-13, atol=1e-14))
        ref = periodic_orbit(flow, [x0, v0], tol=1e-12)
        assert abs(br.amplitude[i] - ref.amplitude) < 2e-7 * ref.amplitude, (W, i)
    assert br.amplitude[i_peak] > 2.3  # the upper orbit, just below the fold
    assert br.omega[i_peak] > 2.2119


def test_duffing_aft_equals_the_converged_galerkin_solution():
    """AFT at 4H + 1 samples projects a cubic exactly: at H = 9 it equals the Galerkin
    solution with 64H samples (no aliasing there) to rounding, across the window."""
    osc = builtin_model("duffing")
    br = duffing_aft_branch()
    for i in range(0, len(br), 25):
        W = float(br.omega[i])
        dense = harmonic_balance_orbit(
            osc,
            W,
            harmonics=9,
            projection="aft",
            samples=576,
            guess=br.coefficients[i],
            stability="none",
        )
        assert abs(dense.amplitude - br.amplitude[i]) < 1e-9 * dense.amplitude


def test_every_branch_point_is_a_solution_and_output_spacing_holds():
    """The Hermite predictor with acceptance after one correction: every returned point
    solves the HB equations to the continuation tolerance (re-solved by Newton at fixed
    Omega to 1e-13), with about one evaluation per point."""
    br = nsd_branch()
    system = br.system
    worst = 0.0
    for u, W in zip(br.coefficients[::4], br.omega[::4], strict=True):
        scale = max(1.0, float(np.abs(u).max()))
        again, _ = newton_fixed(system.residual, system.jacobian, u, W, u_scale=scale, tol=1e-13)
        worst = max(worst, float(np.abs(again - u).max()) / scale)
    assert worst < 1e-8
    assert br.curve.residual_evaluations < 1.6 * len(br)
    steps = np.hypot(np.diff(br.omega) / 1.7, np.diff(br.amplitude) / br.amplitude.max())
    assert steps.max() < 0.1


@functools.cache
def nsd_k3_branches():
    osc = builtin_model("nsd", k=-3.0, mu=0.05, F=2.0)
    return harmonic_balance_branches(osc, (0.2, 2.0), harmonics=9, seeds=single_harmonic_seeds)


def test_detached_loop_found_from_single_harmonic_seeds():
    """nsd at k = -3 (paper Fig. 17d): the branch connected to the automatic start is the
    in-well one; the detached branch of symmetric cross-well orbits (peak ~42.8, fold at
    Omega ~ 0.9431, both ends on the low window edge) and the inner linear branch are found
    from the single-harmonic balance response. Oracle: exact orbits by shooting on the exact
    piecewise-linear flow from the HB state, at Omega = 0.8 on both parts of the loop. (The
    branches found after these three, from linear-segment seeds and by branch switching, are
    checked in ``test_hb_branch_switching.py``.)"""
    brs = nsd_k3_branches()
    assert [b.origin for b in brs[:3]] == ["start", "seed", "seed"]
    assert len(brs) > 3
    detached = [b for b in brs if b.amplitude.max() > 40.0]
    assert len(detached) == 1
    iso = detached[0]
    assert np.max(np.abs(iso.mean)) < 1e-8 * iso.amplitude.max()  # symmetric orbits
    assert iso.omega[0] == pytest.approx(0.2) and iso.omega[-1] == pytest.approx(0.2)
    assert len(iso.folds) == 1 and iso.folds[0][0] == pytest.approx(0.9431, abs=2e-3)
    inner = [b for b in brs[:3] if b.amplitude.max() < 1.0]
    assert len(inner) == 1 and not inner[0].stable.any()
    osc = builtin_model("nsd", k=-3.0, mu=0.05, F=2.0, Omega=0.8)
    W = 0.8
    seg = np.nonzero((iso.omega[:-1] - W) * (iso.omega[1:] - W) <= 0)[0]
    assert seg.size == 2  # the upper and the lower part of the loop
    amps = []
    for i in seg:
        f = (W - iso.omega[i]) / (iso.omega[i + 1] - iso.omega[i])
        guess = (1 - f) * iso.coefficients[i] + f * iso.coefficients[i + 1]
        sol = harmonic_balance_orbit(osc, W, harmonics=9, guess=guess)
        ref = periodic_orbit(ExactPWLFlow(osc), [float(sol(0.0)), float(sol.velocity(0.0))])
        # H = 9 on orbits with kinks: measured 1.7e-4 and 1.8e-4
        assert abs(sol.amplitude - ref.amplitude) < 1e-3 * ref.amplitude
        assert sol.stable == ref.is_stable
        amps.append(ref.amplitude)
    assert min(amps) > 8.0 and max(amps) > 19.0  # 8.928 and 19.567
    resp = harmonic_balance_response(
        builtin_model("nsd", k=-3.0, mu=0.05, F=2.0),
        (0.2, 2.0),
        harmonics=9,
        all_branches=True,
        seeds=single_harmonic_seeds,
    )
    assert len(resp.branches) == len(brs)


def test_branch_through_an_interior_solution_is_the_whole_branch():
    """A branch started from an orbit in the middle of the window (Duffing, Omega = 1.6 on the
    upper, resonant branch, found by Newton from the exact orbit's harmonics) reaches its fold
    going up and the window edge going down, every point a solution; its fold is the fold of
    the edge-started branch. Oracle for the orbit: tight shooting on the ODE."""
    osc = builtin_model("duffing", mu=0.1, F=0.5)
    window = (0.5, 3.0)
    ref = periodic_orbit(ODEFlow(osc.with_params(Omega=1.6), rtol=1e-12, atol=1e-12), [2.0, 0.0])
    sol = harmonic_balance_orbit(osc, 1.6, harmonics=7, guess=ref)
    assert abs(sol.amplitude - ref.amplitude) < 1e-6 * ref.amplitude
    system = HarmonicBalanceSystem(osc, harmonics=7)
    br = harmonic_balance_branch_through(system, sol.coefficients, 1.6, window)
    assert br.omega.min() == pytest.approx(window[0], abs=1e-12)
    res = [
        np.abs(system.residual(u, W)).max() for u, W in zip(br.coefficients, br.omega, strict=True)
    ]
    assert max(res) < 1e-8
    edge = harmonic_balance_branch(osc, window, harmonics=7, direction=1)
    assert len(br.folds) >= 1 and len(edge.folds) >= 1
    assert max(f[0] for f in br.folds) == pytest.approx(max(f[0] for f in edge.folds), rel=1e-6)
    with pytest.raises(ParameterError, match="inside the window"):
        harmonic_balance_branch_through(system, sol.coefficients, 3.5, window)
    with pytest.raises(ParameterError, match="finite coefficients"):
        harmonic_balance_branch_through(system, [1.0, 2.0], 1.6, window)
    with pytest.raises(ParameterError, match="guess = 'orbit'"):
        harmonic_balance_orbit(osc, 1.6, harmonics=7, guess="orbit")


# ---------------------------------------------------------------------------------------------
# the generic continuation core
# ---------------------------------------------------------------------------------------------
def test_continuation_core_cubic_folds_and_window_edge():
    # lam = u0^3 - u0 with a decoupled second unknown u1 = 2 lam: folds at u0 = -+1/sqrt(3)
    def residual(u, lam):
        return np.array([u[0] ** 3 - u[0] - lam, u[1] - 2.0 * lam])

    def jacobian(u, lam):
        return np.array([[3 * u[0] ** 2 - 1, 0.0], [0.0, 1.0]]), np.array([-1.0, -2.0])

    curve = continue_curve(residual, jacobian, [-2.0, -12.0], -6.0, (-6.0, 6.0), ds_max=0.05)
    assert curve.stop_reason == "window"
    assert curve.lam[-1] == pytest.approx(6.0, abs=1e-12)
    assert np.max(np.abs([residual(u, w) for u, w in zip(curve.u, curve.lam, strict=True)])) < 1e-9
    assert len(curve.folds) == 2
    fold_lam = sorted(f.lam for f in curve.folds)
    expect = 2.0 / (3.0 * math.sqrt(3.0))
    assert fold_lam == pytest.approx([-expect, expect], abs=1e-10)
    assert sorted(abs(f.u[0]) for f in curve.folds) == pytest.approx([3**-0.5] * 2, abs=1e-5)
    assert all(f.refined for f in curve.folds)


def test_continuation_core_closed_curve_and_callback():
    def residual(u, lam):
        return np.array([u[0] ** 2 + lam**2 - 1.0])

    def jacobian(u, lam):
        return np.array([[2 * u[0]]]), np.array([2 * lam])

    seen = []
    curve = continue_curve(
        residual,
        jacobian,
        [1.0],
        0.0,
        (-2.0, 2.0),
        lam_scale=1.0,
        ds_max=0.1,
        callback=lambda u, lam, ju, jl: seen.append(lam) or float(ju[0, 0]),
    )
    assert curve.stop_reason == "closed"
    assert len(curve.folds) == 2
    assert sorted(f.lam for f in curve.folds) == pytest.approx([-1.0, 1.0], abs=1e-10)
    assert len(seen) == len(curve) and len(curve.callback_values) == len(curve)


def test_continuation_core_hermite_predictor_on_a_circle():
    """The Hermite predictor and early acceptance on lam^2 + u^2 = 1 (closed form): the
    points lie on the circle to the tolerance, the two folds are at lam = -+1, and most
    points cost one evaluation."""

    def residual(u, lam):
        return np.array([u[0] ** 2 + lam**2 - 1.0])

    def jacobian(u, lam):
        return np.array([[2 * u[0]]]), np.array([2 * lam])

    curve = continue_curve(
        residual,
        jacobian,
        [1.0],
        0.0,
        (-2.0, 2.0),
        lam_scale=1.0,
        ds_max=0.05,
        predictor="hermite",
        early_accept=True,
    )
    assert curve.stop_reason == "closed"
    radius = np.hypot(curve.u[:, 0], curve.lam)
    assert np.max(np.abs(radius - 1.0)) < 1e-9
    assert sorted(f.lam for f in curve.folds) == pytest.approx([-1.0, 1.0], abs=1e-10)
    assert np.mean(curve.iterations[1:] == 1) > 0.6
    with pytest.raises(ParameterError, match="predictor = 'secant'"):
        continue_curve(residual, jacobian, [1.0], 0.0, (-2.0, 2.0), predictor="secant")


def test_continuation_core_rejects_bad_input():
    def residual(u, lam):
        return u - lam

    def jacobian(u, lam):
        return np.eye(1), -np.ones(1)

    with pytest.raises(ParameterError, match="window"):
        continue_curve(residual, jacobian, [0.0], 0.0, (1.0, -1.0))
    with pytest.raises(ParameterError, match="outside the window"):
        continue_curve(residual, jacobian, [3.0], 3.0, (-1.0, 1.0))
    with pytest.raises(ParameterError, match="ds_max"):
        continue_curve(residual, jacobian, [0.0], 0.0, (-1.0, 1.0), ds_max=0.0)
    with pytest.raises(ContinuationError, match="did not converge"):
        newton_fixed(
            lambda u, lam: np.array([u[0] ** 2 + 1.0]),
            lambda u, lam: (np.array([[2 * u[0]]]), np.zeros(1)),
            [0.5],
            0.0,
        )


# ---------------------------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"harmonics": 0}, "harmonics = 0"),
        ({"harmonics": 2.5}, "harmonics = 2.5"),
        ({"m": 0}, "m = 0"),
        ({"projection": "fft"}, "projection = 'fft'"),
        ({"projection": "aft", "samples": 10}, "samples = 10"),
        ({"stability": "floquet"}, "stability = 'floquet'"),
    ],
)
def test_bad_options_raise_parameter_errors(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        harmonic_balance_orbit(nsd(), 0.6, **kwargs)


def test_bad_input_raises_clear_errors():
    with pytest.raises(ParameterError, match="Omega_window"):
        harmonic_balance_response(nsd(), (2.0, 0.3))
    with pytest.raises(ParameterError, match="Omega_window"):
        harmonic_balance_response(nsd(), (0.0, 1.0))
    with pytest.raises(ParameterError, match="Omega = -1"):
        harmonic_balance_orbit(nsd(), -1.0)
    with pytest.raises(ParameterError, match="guess of 3 values"):
        harmonic_balance_orbit(nsd(), 0.6, harmonics=5, guess=[1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match="projection = 'exact'"):
        harmonic_balance_orbit(builtin_model("duffing"), 1.0, projection="exact")
    with pytest.raises(ParameterError, match="k"):
        harmonic_balance_orbit(nsd().with_params(k=None), 0.6)
    with pytest.raises(ModelError, match="no harmonic forcing"):
        harmonic_balance_orbit(builtin_model("vanderpol"), 1.0)
    assert isinstance(harmonic_balance_orbit(nsd(), 0.6, harmonics=3), HarmonicBalanceSolution)


def test_options_object_and_keywords_are_one_configuration():
    """The tuning knobs as a HarmonicBalanceOptions or as keywords give the same branch; a
    keyword replaces the object's field; an unknown knob (or one the single-branch tracer does
    not use) is refused by name instead of being ignored."""
    from dataclasses import FrozenInstanceError

    from perturb.numeric.harmonic_balance import HarmonicBalanceOptions, harmonic_balance_branch

    osc = builtin_model("duffing")
    window = (0.8, 1.6)
    by_keywords = harmonic_balance_branch(osc, window, harmonics=3, ds_max=0.08)
    opts = HarmonicBalanceOptions(harmonics=3, ds_max=0.08)
    by_object = harmonic_balance_branch(osc, window, opts)
    overridden = harmonic_balance_branch(
        osc, window, HarmonicBalanceOptions(harmonics=7), harmonics=3, ds_max=0.08
    )
    for other in (by_object, overridden):
        assert np.array_equal(other.omega, by_keywords.omega)
        assert np.array_equal(other.coefficients, by_keywords.coefficients)
    # a coarser step gives fewer points: the knob is really used
    coarse = harmonic_balance_branch(osc, window, opts, ds_max=0.3)
    assert len(coarse.omega) < len(by_keywords.omega)
    with pytest.raises(FrozenInstanceError):
        opts.harmonics = 5  # type: ignore[misc]
    with pytest.raises(ParameterError, match="harmonic"):
        harmonic_balance_branch(osc, window, harmonic=3)
    with pytest.raises(ParameterError, match="mirror"):
        harmonic_balance_branch(osc, window, mirror=False)
    with pytest.raises(ParameterError, match="HarmonicBalanceOptions"):
        harmonic_balance_branch(osc, window, {"harmonics": 3})
