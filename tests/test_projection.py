"""The exact Galerkin projection of piecewise-linear forces (perturb.fourier.projection).

Oracle (never the code under test): the projection integrals evaluated by mpmath at 30
digits, with the force written out by hand from the model's equation (not from the
``NumericPWL`` the code reads), the crossings of the signal found by dense float sampling and
mpmath bisection, and Gauss-Legendre quadrature on each piece between crossings (where the
integrand is smooth). The Jacobian is checked against central differences of that
quadrature, so the Dirac terms of a force with a jump are checked too.
"""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
import pytest

from perturb.errors import ParameterError
from perturb.fourier.projection import (
    CrossingIntervals,
    ExactProjector,
    HarmonicBasis,
    TruncatedSeries,
    crossing_intervals,
    pwl_projection,
    switching_angles,
)
from perturb.model.builtins import builtin_model
from perturb.model.pwl import NumericPWL

mp.mp.dps = 30
TOL = 1e-12


# ---------------------------------------------------------------------------------------------
# forces written out by hand (and the NumericPWL the code under test reads)
# ---------------------------------------------------------------------------------------------
def nsd_force(k: float):
    """nsd: ``k x + (1 - k)((x - 1) H(x - 1) + (x + 1) H(-x - 1))``."""

    def f(x):
        return k * x + (1 - k) * (max(x - 1, 0) + min(x + 1, 0))

    return f, (-1.0, 1.0)


def nsd_pwl(k: float) -> NumericPWL:
    return builtin_model("nsd", k=k, mu=0.05, F=2.0).piecewise_linear().numeric()


def jump_force():
    """``x`` below 0.5, ``2 x + 0.3`` above: a jump of 0.8 at ``x = 0.5`` and a kink."""

    def f(x):
        return x if x < mp.mpf("0.5") else 2 * x + mp.mpf("0.3")

    return f, (0.5,)


JUMP_PWL = NumericPWL(np.array([0.5]), np.array([1.0, 2.0]), np.array([0.0, 0.3]))

FORCES = {
    "nsd_k-0.5": (nsd_force(-0.5), lambda: nsd_pwl(-0.5)),
    "nsd_k-3": (nsd_force(-3.0), lambda: nsd_pwl(-3.0)),
    "jump": (jump_force(), lambda: JUMP_PWL),
}


# ---------------------------------------------------------------------------------------------
# signals: {harmonic: (a_k, b_k)} and a0, in a basis that holds them
# ---------------------------------------------------------------------------------------------
SIGNALS = {
    # s = a0 + a1 cos(theta) + b3 sin(3 theta)
    "a0_a1_b3": (HarmonicBasis.make(3), 0.2, {1: (1.7, 0.0), 3: (0.0, 0.4)}),
    # one breakpoint crossed (mean above it)
    "biased": (HarmonicBasis.make(4), 1.1, {1: (0.6, -0.2), 2: (0.0, 0.15), 4: (0.05, 0.0)}),
    # odd basis, no bias
    "odd": (
        HarmonicBasis.make(5, odd_only=True),
        0.0,
        {1: (1.5, 0.3), 3: (-0.2, 0.1), 5: (0.0, 0.1)},
    ),
    # inside one segment: no crossing at all
    "inside": (HarmonicBasis.make(2), 0.1, {1: (0.3, 0.1), 2: (0.0, 0.05)}),
}


def coefficients(basis: HarmonicBasis, a0: float, parts: dict) -> np.ndarray:
    u = np.zeros(basis.size)
    if basis.bias:
        u[0] = a0
    for k, (a, b) in parts.items():
        i = basis.index_of(k)
        u[i], u[i + 1] = a, b
    return u


def signal(basis: HarmonicBasis, u):
    """``x(theta)`` in mpmath from the coefficient vector (the layout of the basis), and the
    same signal in floats for the sampling grid."""
    terms = []
    for k in basis.harmonics:
        i = basis.index_of(k)
        terms.append((k, mp.mpf(u[i]), mp.mpf(u[i + 1])))
    a0 = mp.mpf(u[0]) if basis.bias else mp.mpf(0)

    def x(t):
        return a0 + mp.fsum(a * mp.cos(k * t) + b * mp.sin(k * t) for k, a, b in terms)

    def x_float(t: np.ndarray) -> np.ndarray:
        return float(a0) + sum(
            float(a) * np.cos(k * t) + float(b) * np.sin(k * t) for k, a, b in terms
        )

    x.floats = x_float
    return x


def mp_crossings(x, levels, samples: int = 20000) -> list:
    """Crossings of ``x = d`` on ``[0, 2 pi)``: sign changes on a dense float grid, each
    refined by 110 bisections in mpmath (bracket 3e-4 -> below 1e-30)."""
    grid = np.linspace(0.0, 2.0 * math.pi, samples + 1)
    xf = x.floats(grid)
    out = []
    for d in levels:
        e = xf - d
        for i in np.nonzero((e[:-1] >= 0) != (e[1:] >= 0))[0]:
            lo, hi = mp.mpf(grid[i]), mp.mpf(grid[i + 1])
            flo = x(lo) - d
            for _ in range(110):
                mid = (lo + hi) / 2
                fm = x(mid) - d
                if (fm >= 0) == (flo >= 0):
                    lo, flo = mid, fm
                else:
                    hi = mid
            out.append((lo + hi) / 2)
    return sorted(out)


def mp_projection(force, basis: HarmonicBasis, u) -> list:
    """``[(1/2pi) int f, (1/pi) int f cos k, (1/pi) int f sin k, ...]`` at 30 digits."""
    f, levels = force
    x = signal(basis, u)
    cuts = [mp.mpf(0)] + mp_crossings(x, levels) + [2 * mp.pi]
    pieces = list(zip(cuts[:-1], cuts[1:], strict=True))

    def integral(weight):
        return mp.fsum(mp.quad(lambda t: f(x(t)) * weight(t), [a, b]) for a, b in pieces)

    out = []
    if basis.bias:
        out.append(integral(lambda t: 1) / (2 * mp.pi))
    for k in basis.harmonics:
        out.append(integral(lambda t, k=k: mp.cos(k * t)) / mp.pi)
        out.append(integral(lambda t, k=k: mp.sin(k * t)) / mp.pi)
    return out


CASES = [(f, s) for f in FORCES for s in SIGNALS]


@pytest.mark.parametrize(("force_name", "signal_name"), CASES)
def test_projection_matches_mpmath_quadrature(force_name, signal_name):
    force, make_pwl = FORCES[force_name]
    basis, a0, parts = SIGNALS[signal_name]
    u = coefficients(basis, a0, parts)
    ours = pwl_projection(make_pwl(), basis, u)
    ref = np.array([float(v) for v in mp_projection(force, basis, u)])
    scale = max(1.0, float(np.abs(ref).max()))
    assert np.max(np.abs(ours - ref)) < TOL * scale, (ours, ref)


@pytest.mark.parametrize("force_name", ["nsd_k-0.5", "jump"])
def test_jacobian_matches_differences_of_the_quadrature(force_name):
    """Central differences (step 1e-10, at 30 digits) of the mpmath projection: this includes
    the moving switches of a force with a jump (the Dirac terms of the Jacobian)."""
    force, make_pwl = FORCES[force_name]
    basis, a0, parts = SIGNALS["a0_a1_b3"]
    u = coefficients(basis, a0, parts)
    _, J = pwl_projection(make_pwl(), basis, u, jacobian=True)
    h = mp.mpf("1e-10")
    ref = np.empty_like(J)
    for j in range(basis.size):
        up = [mp.mpf(v) for v in u]
        dn = [mp.mpf(v) for v in u]
        up[j] += h
        dn[j] -= h
        plus, minus = mp_projection(force, basis, up), mp_projection(force, basis, dn)
        ref[:, j] = [float((p - m) / (2 * h)) for p, m in zip(plus, minus, strict=True)]
    assert np.max(np.abs(J - ref)) < 1e-9 * max(1.0, float(np.abs(ref).max())), (J, ref)


@pytest.mark.parametrize("signal_name", ["a0_a1_b3", "biased", "odd"])
def test_switching_angles_and_intervals_match_mpmath_crossings(signal_name):
    basis, a0, parts = SIGNALS[signal_name]
    u = coefficients(basis, a0, parts)
    x = signal(basis, u)
    for level in (-1.0, 1.0):
        ref = np.array([float(t) for t in mp_crossings(x, [level])])
        got = switching_angles(basis, u, level)
        assert got.shape == ref.shape
        np.testing.assert_allclose(got, ref, rtol=0, atol=TOL)
    pwl = nsd_pwl(-0.5)
    pc = crossing_intervals(pwl, basis, TruncatedSeries(basis, u))
    assert isinstance(pc, CrossingIntervals)
    ref = np.array([float(t) for t in mp_crossings(x, [-1.0, 1.0])])
    np.testing.assert_allclose(pc.start, ref, rtol=0, atol=TOL)
    assert math.isclose(float(pc.length.sum()), 2 * math.pi, rel_tol=1e-14)
    # the segment of each interval is the one its midpoint lies in
    mids = pc.start + 0.5 * pc.length
    np.testing.assert_array_equal(
        pc.segment, pwl.segment_index(np.array([float(x(mp.mpf(t))) for t in mids]))
    )
    # the projector object gives the same projection and intervals as the function
    proj, jac, pieces = ExactProjector(pwl, basis).project(u, jacobian=True)
    np.testing.assert_array_equal(proj, pwl_projection(pwl, basis, u))
    np.testing.assert_array_equal(pieces.start, pc.start)
    assert jac.shape == (basis.size, basis.size)


def _no_hang(seconds: int):
    """An alarm that turns a hang (the bisection of a cell no test can decide) into a failure
    instead of a stuck test run."""
    import signal

    def fail(signum, frame):
        raise TimeoutError(f"took more than {seconds} s")

    signal.signal(signal.SIGALRM, fail)
    signal.alarm(seconds)


@pytest.mark.parametrize("level_shift", [0.0, 1.0])
def test_a_constant_signal_on_a_breakpoint_has_no_crossing_and_finishes(level_shift):
    """x(theta) == d on the whole period: every grid cell is undecided by the Taylor tests
    (x - d, x', x'' all zero); it used to be bisected to the depth cap (2^40 calls per cell,
    a hang: the zero signal of a bilinear force kinked at 0, as SystemBalance.linear_guess
    evaluates it). The projection of a constant signal is the constant f(d), f evaluated
    directly."""
    import signal

    bps = np.array([-1.0, 0.0, 1.0])
    # continuous: slopes 1, 4, 2, 0.5 with offsets that join the pieces at -1, 0 and 1
    pwl = NumericPWL(bps, np.array([1.0, 4.0, 2.0, 0.5]), np.array([-3.0, 0.0, 0.0, 1.5]))
    basis = HarmonicBasis.make(5)
    d = float(bps[1] + level_shift)
    u = np.zeros(basis.size)
    u[0] = d
    _no_hang(60)
    try:
        ci = crossing_intervals(pwl, basis, TruncatedSeries(basis, u))
        proj, J = pwl_projection(pwl, basis, u, jacobian=True)
        assert switching_angles(basis, u, d).size == 0
    finally:
        signal.alarm(0)
    assert ci.start.size == 1 and ci.d1.size == 0
    expected = np.zeros(basis.size)
    expected[0] = float(pwl(np.array([d]))[0])
    np.testing.assert_allclose(proj, expected, atol=1e-14)
    assert np.all(np.isfinite(J))


def test_non_finite_coefficients_are_refused_by_name():
    """NaN or inf coefficients defeat every isolation test (they used to hang the crossing
    search); the crossing search refuses them."""
    import signal

    basis = HarmonicBasis.make(3)
    for bad in (np.inf, np.nan):
        u = np.zeros(basis.size)
        u[1] = bad
        _no_hang(60)
        try:
            with pytest.raises(ParameterError, match="finite"):
                crossing_intervals(
                    builtin_model("bilinear").piecewise_linear().numeric(),
                    basis,
                    TruncatedSeries(basis, u),
                )
        finally:
            signal.alarm(0)
