"""Tests of :mod:`perturb.fourier.coefficients` against independent mpmath oracles.

The oracle is never the code under test:

* ``mp_quad_coefficients`` -- mpmath quadrature at 30 significant digits of
  ``a_n = (2/pi) int_0^pi g(A cos psi + b) cos(n psi) dpsi`` (evenness), with ``[0, pi]`` split
  at the switching angles (so ``g`` is smooth -- linear or polynomial -- on every piece) and
  each piece subdivided so that it holds at most ~6 periods of ``cos(n_max psi)``; on each
  piece a 48-point Gauss-Legendre rule (mpmath's own nodes) is used.  This is what checks the
  derivations.
* ``mp_exact_pwl`` -- for piecewise-linear ``g``, the exact antiderivative of
  ``(alpha x + beta) cos(n psi)`` on each piece, evaluated in mpmath at 50 digits.  It is used
  for n up to 1e4 and beyond, where quadrature would need thousands of pieces, and
  ``test_oracles_agree`` checks it against the quadrature.

Tolerances (``assert_close``): ``|num - ref| <= max(1e-12 |ref|, 1e-14 * scale)``.
``scale`` is 1 for bounded functions (step, sign).  For ramp-like functions (ramp, |x|,
saturation, dead zone, PWL forces) it is ``max(1, A, |b|, |d|)``: their coefficients are
sums of terms as large as ``A`` and ``|b - d|`` (e.g. ``a0 = 2(b - d) + ...``), so a few
ulps *of those terms* is the floating-point floor when the coefficient itself is much smaller
(near a zero in ``n``, or where the ``x``-range hardly reaches the breakpoint).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import mpmath as mp
import numpy as np
import pytest
import sympy as sp
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from perturb.errors import FourierError, PerturbError
from perturb.fourier import coefficients as F

EPS = np.finfo(float).eps
QUAD_DPS = 30
EXACT_DPS = 50

HSET = settings(
    max_examples=25,
    deadline=None,
    derandomize=True,  # reproducible in CI; the explicit @example cases cover the edges
    database=None,  # do not write a .hypothesis/ directory into the checkout
    suppress_health_check=[HealthCheck.too_slow],
)

# ---------------------------------------------------------------------------------------------
# oracles
# ---------------------------------------------------------------------------------------------

_GL_CACHE: dict[int, list[tuple[mp.mpf, mp.mpf]]] = {}


def _gl_nodes(dps: int) -> list[tuple[mp.mpf, mp.mpf]]:
    """48-point Gauss-Legendre nodes/weights on [-1, 1] (mpmath's rule, degree 5)."""
    if dps not in _GL_CACHE:
        with mp.workdps(dps):
            rule = mp.calculus.quadrature.GaussLegendre(mp.mp)
            _GL_CACHE[dps] = rule.calc_nodes(5, mp.mp.prec)
    return _GL_CACHE[dps]


def exact_gaps(A: float | mp.mpf, b: float | mp.mpf, d: float) -> tuple[mp.mpf, mp.mpf]:
    """``A - (d - b)`` and ``A + (d - b)`` without rounding (float inputs are exact mpfs), so
    the oracle cannot mistake a crossing by 1e-122 for a tangency (hypothesis found one)."""
    diff = mp.fsub(mp.mpf(d), mp.mpf(b), exact=True)
    return mp.fsub(mp.mpf(A), diff, exact=True), mp.fadd(mp.mpf(A), diff, exact=True)


def psi_of(A: float | mp.mpf, b: float | mp.mpf, x: float) -> mp.mpf:
    """The angle in [0, pi] where A cos(psi) + b = x (clipped), at the working precision:
    acos((x - b)/A) written as 2 atan2(sqrt(A - (x - b)), sqrt(A + (x - b))) with exact gaps
    (acos itself is ill-conditioned at +-1, where the grazing tests live)."""
    if x == math.inf:
        return mp.mpf(0)
    if x == -math.inf:
        return +mp.pi
    lo, hi = exact_gaps(A, b, x)
    if lo <= 0 and hi <= 0:  # A == 0 and x == b
        return +mp.pi / 2
    return 2 * mp.atan2(mp.sqrt(max(lo, 0)), mp.sqrt(max(hi, 0)))


def _switch_angles(A: mp.mpf, b: mp.mpf, breakpoints: Sequence[float]) -> list[mp.mpf]:
    cuts = [mp.mpf(0), +mp.pi]
    for d in breakpoints:
        lo, hi = exact_gaps(A, b, d)
        if lo > 0 and hi > 0:
            cuts.append(psi_of(A, b, d))
    return sorted(set(cuts))


# Phase of cos(n_max psi) per Gauss-Legendre piece.  The 48-point rule's error for
# cos(omega t) on [-1, 1] is ~(e omega / (4 * 48))**96; with omega = 40/2 that is ~1e-53.
MAX_PHASE_PER_PIECE = 40


def mp_quad_coefficients(
    g: Callable[[mp.mpf], mp.mpf] | Sequence[Callable[[mp.mpf], mp.mpf]],
    ns: Sequence[int],
    A: float,
    b: float,
    breakpoints: Sequence[float] = (),
) -> list[mp.mpf]:
    """a_n for every n in ``ns`` by 30-digit Gauss-Legendre quadrature (see module docstring).

    ``A``, ``b`` and the breakpoints are converted exactly (binary floats -> mpf), so the
    oracle describes exactly the floating-point inputs the code receives.  ``g`` may be a
    list of functions sharing the breakpoints; the result is then a list per function.
    """
    gs = list(g) if isinstance(g, Sequence) else [g]
    nodes = _gl_nodes(QUAD_DPS)
    with mp.workdps(QUAD_DPS):
        Am, bm = mp.mpf(A), mp.mpf(b)
        cuts = _switch_angles(Am, bm, breakpoints)
        n_max = max(max(ns), 1)
        sums = [[mp.mpf(0)] * len(ns) for _ in gs]
        for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
            pieces = max(1, math.ceil(float(n_max * (hi - lo)) / MAX_PHASE_PER_PIECE))
            h = (hi - lo) / pieces
            for p in range(pieces):
                a = lo + p * h
                half, mid = h / 2, a + h / 2
                for t, w in nodes:
                    psi = mid + half * t
                    x = Am * mp.cos(psi) + bm
                    cosines = [mp.cos(n * psi) for n in ns]
                    for j, gj in enumerate(gs):
                        gv = gj(x) * w * half
                        row = sums[j]
                        for i, c in enumerate(cosines):
                            row[i] += gv * c
        out = [[2 * s / mp.pi for s in row] for row in sums]
        return out if isinstance(g, Sequence) else out[0]


def mp_exact_pwl(
    ns: Sequence[int],
    A: float,
    b: float,
    segments: Sequence[tuple[float, float, float, float]],
) -> list[mp.mpf]:
    """Exact a_n of a piecewise-linear g at 50 digits.

    ``segments``: ``(x_lo, x_hi, alpha, beta)`` meaning ``g(x) = alpha x + beta`` on
    ``x_lo < x < x_hi`` (``+-inf`` allowed).  Since ``x = A cos psi + b`` decreases on
    ``[0, pi]``, the segment is ``psi(x_hi) < psi < psi(x_lo)`` with
    ``psi(x) = acos(clip((x - b)/A, -1, 1))``, and
    ``int (alpha (A cos psi + b) + beta) cos(n psi) dpsi`` has the antiderivative
    ``alpha A K1(psi) + (alpha b + beta) K0(psi)``,
    ``K0 = sin(n psi)/n``, ``K1 = sin((n-1)psi)/(2(n-1)) + sin((n+1)psi)/(2(n+1))`` (n >= 2).
    """
    with mp.workdps(EXACT_DPS):
        Am, bm = mp.mpf(A), mp.mpf(b)

        def K0(n: int, p: mp.mpf) -> mp.mpf:
            return p if n == 0 else mp.sin(n * p) / n

        def K1(n: int, p: mp.mpf) -> mp.mpf:
            if n == 0:
                return mp.sin(p)
            if n == 1:
                return p / 2 + mp.sin(2 * p) / 4
            return mp.sin((n - 1) * p) / (2 * (n - 1)) + mp.sin((n + 1) * p) / (2 * (n + 1))

        out = []
        for n in ns:
            total = mp.mpf(0)
            for x_lo, x_hi, alpha, beta in segments:
                p_lo, p_hi = psi_of(Am, bm, x_hi), psi_of(Am, bm, x_lo)
                if p_hi <= p_lo:
                    continue
                al, be = mp.mpf(alpha), mp.mpf(beta)
                total += al * Am * (K1(n, p_hi) - K1(n, p_lo))
                total += (al * bm + be) * (K0(n, p_hi) - K0(n, p_lo))
            out.append(2 * total / mp.pi)
        return out


INF = math.inf


def seg_step(d: float) -> list[tuple[float, float, float, float]]:
    return [(d, INF, 0.0, 1.0)]


def seg_ramp(d: float) -> list[tuple[float, float, float, float]]:
    return [(d, INF, 1.0, -d)]


def seg_abs(d: float) -> list[tuple[float, float, float, float]]:
    return [(-INF, d, -1.0, d), (d, INF, 1.0, -d)]


def seg_sign(d: float) -> list[tuple[float, float, float, float]]:
    return [(-INF, d, 0.0, -1.0), (d, INF, 0.0, 1.0)]


def seg_sat(lo: float, hi: float) -> list[tuple[float, float, float, float]]:
    return [(-INF, lo, 0.0, lo), (lo, hi, 1.0, 0.0), (hi, INF, 0.0, hi)]


def seg_dz(lo: float, hi: float) -> list[tuple[float, float, float, float]]:
    return [(-INF, lo, 1.0, -lo), (hi, INF, 1.0, -hi)]


def mp_dirac(ns: Sequence[int], A: float, b: float, d: float) -> list[mp.mpf]:
    """Sifting property at 50 digits: the root psi* of A cos psi + b = d in (0, pi) gives
    (2/pi) cos(n psi*) / |d/dpsi (A cos psi)| = 2 cos(n psi*)/(pi A sin psi*)."""
    with mp.workdps(EXACT_DPS):
        lo, hi = exact_gaps(A, b, d)
        if not (lo > 0 and hi > 0):
            return [mp.mpf(0)] * len(ns)
        p = psi_of(A, b, d)
        a_sin = mp.sqrt(lo * hi)  # A sin(psi*)
        return [2 * mp.cos(n * p) / (mp.pi * a_sin) for n in ns]


def heaviside(d: float) -> Callable[[mp.mpf], mp.mpf]:
    dm = mp.mpf(d)
    return lambda x: mp.mpf(1) if x > dm else (mp.mpf(0.5) if x == dm else mp.mpf(0))


def ramp(d: float) -> Callable[[mp.mpf], mp.mpf]:
    dm = mp.mpf(d)
    return lambda x: x - dm if x > dm else mp.mpf(0)


def absval(d: float) -> Callable[[mp.mpf], mp.mpf]:
    dm = mp.mpf(d)
    return lambda x: abs(x - dm)


def signum(d: float) -> Callable[[mp.mpf], mp.mpf]:
    dm = mp.mpf(d)
    return lambda x: mp.sign(x - dm)


def saturation(lo: float, hi: float) -> Callable[[mp.mpf], mp.mpf]:
    lm, hm = mp.mpf(lo), mp.mpf(hi)
    return lambda x: min(max(x, lm), hm)


def deadzone(lo: float, hi: float) -> Callable[[mp.mpf], mp.mpf]:
    sat = saturation(lo, hi)
    return lambda x: x - sat(x)


def zou_nagarajaiah(k: float) -> Callable[[mp.mpf], mp.mpf]:
    """f(x) = k x + (1 - k)[(x - 1)H(x - 1) + (x + 1)H(-x - 1)], coded literally."""
    km = mp.mpf(k)

    def H(x: mp.mpf) -> mp.mpf:
        return mp.mpf(1) if x > 0 else mp.mpf(0)

    return lambda x: km * x + (1 - km) * ((x - 1) * H(x - 1) + (x + 1) * H(-x - 1))


def assert_close(num: float, ref: mp.mpf, *, scale: float = 1.0, what: str = "") -> None:
    """|num - ref| <= max(1e-12 |ref|, 1e-14 scale) (see the module docstring)."""
    ref_f = float(ref)
    err = abs(float(mp.mpf(float(num)) - ref))
    tol = max(1e-12 * abs(ref_f), 1e-14 * scale)
    assert err <= tol, f"{what}: got {float(num)!r}, mpmath {ref_f!r}, error {err:.3e} > {tol:.3e}"


def lin_scale(A: float, *xs: float) -> float:
    return max(1.0, A, *(abs(x) for x in xs))


# ---------------------------------------------------------------------------------------------
# strategies
# ---------------------------------------------------------------------------------------------

KINDS = ("random", "random", "random", "graze_in", "graze_out", "on", "off", "zero_amp")


@st.composite
def geometries(draw: st.DrawFn) -> tuple[float, float, float]:
    """(A, b, d): mostly crossing, plus grazing (both sides, both ends), no-crossing, A = 0."""
    kind = draw(st.sampled_from(KINDS))
    A = draw(st.floats(0.05, 10.0))
    b = draw(st.floats(-5.0, 5.0))
    side = draw(st.sampled_from((-1.0, 1.0)))
    if kind == "random":
        d = b + A * draw(st.floats(-0.999, 0.999))
    elif kind == "graze_in":  # just crossing: A - |d - b| = 1e-10 A
        d = b + side * A * (1 - 1e-10)
    elif kind == "graze_out":  # just not crossing
        d = b + side * A * (1 + 1e-10)
    elif kind in ("on", "off"):
        d = b + (1.0 if kind == "off" else -1.0) * A * draw(st.floats(1.0, 3.0))
    else:
        A = 0.0
        d = b + draw(st.sampled_from((-1.0, 0.0, 1.0)))
    return A, b, d


NS_SMALL = (0, 1, 2, 3, 4, 7, 16)
GRAZE = 1e-10

# ---------------------------------------------------------------------------------------------
# crossing angle
# ---------------------------------------------------------------------------------------------


@HSET
@given(geometries())
@example((1.0, 0.0, 1.0 - 1e-10))
@example((2.5, -1.0, -1.0 - 2.5 * (1 - 1e-10)))
def test_crossing_angle_matches_mpmath(geom: tuple[float, float, float]) -> None:
    A, b, d = geom
    theta = float(F.crossing_angle(A, b, d))
    with mp.workdps(EXACT_DPS):
        Am, bm, dm = mp.mpf(A), mp.mpf(b), mp.mpf(d)
        if Am == 0:
            ref = mp.mpf(0) if bm < dm else (mp.pi if bm > dm else mp.pi / 2)
        else:
            diff = mp.fsub(dm, bm, exact=True)
            ref = (
                mp.acos(min(max(diff / Am, mp.mpf(-1)), mp.mpf(1)))
                if abs(diff) < Am
                else (mp.mpf(0) if diff > 0 else +mp.pi)
            )
        # a few ulps of theta, relative -- also at grazing where naive arccos loses 6 digits
        assert abs(theta - ref) <= 4 * EPS * ref + 1e-300, (geom, theta, float(ref))


def test_crossing_angle_naive_arccos_would_fail() -> None:
    """Guard that the grazing example is hard: arccos((d-b)/A) is off by ~1e-6 relative."""
    A, b = 1.0, 0.3
    d = b + A * (1 - 1e-10)
    with mp.workdps(EXACT_DPS):
        ref = mp.acos((mp.mpf(d) - mp.mpf(b)) / mp.mpf(A))
    naive = math.acos((d - b) / A)
    assert abs(naive - ref) / ref > 1e-9  # the naive form is poor ...
    assert abs(float(F.crossing_angle(A, b, d)) - ref) / ref < 1e-15  # ... ours is not


def test_crossing_angle_clipping_is_exact() -> None:
    assert F.crossing_angle(1.0, 0.0, 1.0) == 0.0  # grazing from below: never on
    assert F.crossing_angle(1.0, 0.0, 5.0) == 0.0
    assert F.crossing_angle(1.0, 0.0, -1.0) == np.pi
    assert F.crossing_angle(1.0, 0.0, -5.0) == np.pi
    assert F.crossing_angle(0.0, 1.0, 2.0) == 0.0
    assert F.crossing_angle(0.0, 3.0, 2.0) == np.pi
    assert F.crossing_angle(0.0, 2.0, 2.0) == np.pi / 2  # Heaviside(0) = 1/2
    th = F.crossing_angle([0.0, 1.0, 2.0], 0.0, [[0.5], [3.0]])
    assert th.shape == (2, 3) and th.dtype == np.float64 and not np.isnan(th).any()


# ---------------------------------------------------------------------------------------------
# every function against 30-digit quadrature
# ---------------------------------------------------------------------------------------------


def _check_against_quadrature(
    numeric: Callable[..., np.ndarray],
    g: Callable[[mp.mpf], mp.mpf],
    A: float,
    b: float,
    breakpoints: Sequence[float],
    args: Sequence[float],
    scale: float,
    ns: Sequence[int] = NS_SMALL,
) -> None:
    refs = mp_quad_coefficients(g, ns, A, b, breakpoints)
    vals = numeric(np.array(ns), A, b, *args)  # one vectorised call for all n
    assert vals.shape == (len(ns),)
    for n, v, ref in zip(ns, vals, refs, strict=True):
        assert_close(v, ref, scale=scale, what=f"{numeric.__name__} n={n} A={A!r} b={b!r} {args}")


@HSET
@given(geometries())
def test_step_vs_quadrature(geom: tuple[float, float, float]) -> None:
    A, b, d = geom
    _check_against_quadrature(F.step_coefficients, heaviside(d), A, b, [d], [d], 1.0)


@HSET
@given(geometries())
def test_ramp_vs_quadrature(geom: tuple[float, float, float]) -> None:
    A, b, d = geom
    _check_against_quadrature(F.ramp_coefficients, ramp(d), A, b, [d], [d], lin_scale(A, b, d))


@HSET
@given(geometries())
def test_abs_vs_quadrature(geom: tuple[float, float, float]) -> None:
    A, b, d = geom
    _check_against_quadrature(F.abs_coefficients, absval(d), A, b, [d], [d], lin_scale(A, b, d))


@HSET
@given(geometries())
def test_sign_vs_quadrature(geom: tuple[float, float, float]) -> None:
    A, b, d = geom
    _check_against_quadrature(F.sign_coefficients, signum(d), A, b, [d], [d], 1.0)


@st.composite
def two_breakpoints(draw: st.DrawFn) -> tuple[float, float, float, float]:
    A, b, d1 = draw(geometries())
    A2, b2, d2 = draw(geometries())
    d2 = d2 - b2 + b  # second breakpoint relative to the same bias
    lo, hi = min(d1, d2), max(d1, d2)
    if draw(st.booleans()):
        hi = lo  # degenerate saturation: a constant
    return A, b, lo, hi


@HSET
@given(two_breakpoints())
def test_saturation_vs_quadrature(geom: tuple[float, float, float, float]) -> None:
    A, b, lo, hi = geom
    _check_against_quadrature(
        F.saturation_coefficients,
        saturation(lo, hi),
        A,
        b,
        [lo, hi],
        [lo, hi],
        lin_scale(A, b, lo, hi),
    )


@HSET
@given(two_breakpoints())
def test_deadzone_vs_quadrature(geom: tuple[float, float, float, float]) -> None:
    A, b, lo, hi = geom
    _check_against_quadrature(
        F.deadzone_coefficients,
        deadzone(lo, hi),
        A,
        b,
        [lo, hi],
        [lo, hi],
        lin_scale(A, b, lo, hi),
    )


@HSET
@given(st.floats(0.0, 4.0), st.floats(-3.0, 3.0), st.integers(0, 7))
def test_power_vs_quadrature(A: float, b: float, m: int) -> None:
    Am, bm = mp.mpf(A), mp.mpf(b)
    ns = (0, 1, 2, 3, m, m + 1, m + 5)
    refs = mp_quad_coefficients(lambda x: x**m, ns, A, b)
    vals = F.power_coefficients(np.array(ns), A, b, m)
    scale = max(1.0, float((abs(Am) + abs(bm)) ** m))  # |a_n| <= 2 (A + |b|)**m
    for n, v, ref in zip(ns, vals, refs, strict=True):
        assert_close(v, ref, scale=scale, what=f"x**{m} n={n} A={A} b={b}")
        if n > m:
            assert v == 0.0


@HSET
@given(geometries())
def test_dirac_vs_sifting(geom: tuple[float, float, float]) -> None:
    A, b, d = geom
    ns = (0, 1, 2, 3, 10, 1000, 10_000)
    with mp.workdps(EXACT_DPS):
        lo, hi = exact_gaps(A, b, d)
        if lo == 0 or hi == 0:  # tangency: infinite
            with pytest.raises(FourierError, match="tangency"):
                F.dirac_coefficients(np.array(ns), A, b, d)
            return
        env = float(2 / (mp.pi * mp.sqrt(lo * hi))) if lo > 0 and hi > 0 else 0.0
    refs = mp_dirac(ns, A, b, d)
    vals = F.dirac_coefficients(np.array(ns), A, b, d)
    for n, v, ref in zip(ns, vals, refs, strict=True):
        # Relative to the envelope 2/(pi A sin theta): theta itself is only representable to
        # ~eps*theta, so cos(n theta) has an unavoidable absolute error ~n*theta*eps.
        tol = max(1e-12 * abs(float(ref)), (1e-14 + 4 * n * EPS) * env)
        assert abs(v - float(ref)) <= tol, (geom, n, v, float(ref))


# ---------------------------------------------------------------------------------------------
# grazing, degenerate and exact cases
# ---------------------------------------------------------------------------------------------

FUNCS_1 = {
    "step": (F.step_coefficients, seg_step, False),
    "ramp": (F.ramp_coefficients, seg_ramp, True),
    "abs": (F.abs_coefficients, seg_abs, True),
    "sign": (F.sign_coefficients, seg_sign, False),
}


@pytest.mark.parametrize("name", sorted(FUNCS_1))
@pytest.mark.parametrize("side", [-1.0, 1.0])
@pytest.mark.parametrize("gap", [GRAZE, -GRAZE, 1e-6, 0.0])
@pytest.mark.parametrize("A, b", [(1.0, 0.0), (3.0, -1.2), (0.01, 5.0), (7.5, 2.0)])
def test_grazing(name: str, side: float, gap: float, A: float, b: float) -> None:
    """A - |d - b| = gap * A: just crossing (gap > 0), just not (gap < 0), exact tangency."""
    numeric, segs, linear = FUNCS_1[name]
    d = b + side * A * (1 - gap)
    ns = (0, 1, 2, 3, 10, 100, 10_000)
    refs = mp_exact_pwl(ns, A, b, segs(d))
    vals = numeric(np.array(ns), A, b, d)
    scale = lin_scale(A, b, d) if linear else 1.0
    for n, v, ref in zip(ns, vals, refs, strict=True):
        assert_close(v, ref, scale=scale, what=f"{name} n={n} A={A} b={b} d={d!r}")


@pytest.mark.parametrize("side", [-1.0, 1.0])
@pytest.mark.parametrize("A, b", [(1.0, 0.0), (3.0, -1.2), (0.01, 5.0)])
def test_ramp_grazing_is_relatively_accurate(side: float, A: float, b: float) -> None:
    """Stronger than the 1e-14*A floor: the O(A theta**3) grazing ramp keeps 12 digits."""
    d = b + side * A * (1 - GRAZE)
    ns = (0, 1, 2, 3, 10, 100)
    refs = mp_exact_pwl(ns, A, b, seg_ramp(d))
    vals = F.ramp_coefficients(np.array(ns), A, b, d)
    for n, v, ref in zip(ns, vals, refs, strict=True):
        if side < 0 and n <= 1:  # nearly x - d: not small, checked in test_grazing
            continue
        assert abs(v - float(ref)) <= 1e-12 * abs(float(ref)), (n, v, float(ref))


@settings(max_examples=60, deadline=None, derandomize=True, database=None)
@given(st.floats(-7.0, 0.0), st.floats(0.1, 10.0), st.sampled_from((0, 1, 2, 3, 5, 30, 999)))
def test_ramp_small_theta_relative(log_theta: float, A: float, n: int) -> None:
    """The O(A theta**3) region where the textbook formula cancels: 1e-12 relative."""
    theta = 10.0**log_theta
    d = A * math.cos(theta)
    if n * theta > 3:  # past the first zeros of a_n: relative accuracy is not meaningful
        return
    (ref,) = mp_exact_pwl([n], A, 0.0, seg_ramp(d))
    v = float(F.ramp_coefficients(n, A, 0.0, d))
    assert abs(v - float(ref)) <= 1e-12 * abs(float(ref)), (theta, n, v, float(ref))


def test_textbook_ramp_formula_cancels() -> None:
    """Guard: the naive n >= 2 closed form really is inaccurate where ours is not."""
    A, n, theta = 1.0, 3, 1e-5  # expected loss ~3/(n theta)**2 ulps ~ 4e-7
    d = math.cos(theta)
    th = float(F.crossing_angle(A, 0.0, d))
    naive = (
        (2 * A / math.pi)
        * (math.cos(th) * math.sin(n * th) - n * math.sin(th) * math.cos(n * th))
        / (n * (n * n - 1))
    )
    (ref,) = mp_exact_pwl([n], A, 0.0, seg_ramp(d))
    assert abs(naive - float(ref)) / abs(float(ref)) > 1e-9
    assert abs(float(F.ramp_coefficients(n, A, 0.0, d)) - float(ref)) / abs(float(ref)) < 1e-13


def test_zero_amplitude() -> None:
    ns = np.arange(5)
    # x == b: a0 = 2 g(b), a_n = 0 -- including the H(0) = 1/2 and sign(0) = 0 ties
    for b, d, h, s in [(1.0, 2.0, 0.0, -1.0), (3.0, 2.0, 1.0, 1.0), (2.0, 2.0, 0.5, 0.0)]:
        np.testing.assert_array_equal(F.step_coefficients(ns, 0.0, b, d), [2 * h, 0, 0, 0, 0])
        np.testing.assert_array_equal(F.sign_coefficients(ns, 0.0, b, d), [2 * s, 0, 0, 0, 0])
        r = max(b - d, 0.0)
        np.testing.assert_array_equal(F.ramp_coefficients(ns, 0.0, b, d), [2 * r, 0, 0, 0, 0])
        np.testing.assert_array_equal(
            F.abs_coefficients(ns, 0.0, b, d), [2 * abs(b - d), 0, 0, 0, 0]
        )
    np.testing.assert_array_equal(F.dirac_coefficients(ns, 0.0, 1.0, 2.0), np.zeros(5))
    np.testing.assert_array_equal(F.power_coefficients(ns, 0.0, 1.5, 3), [2 * 1.5**3, 0, 0, 0, 0])
    np.testing.assert_array_equal(
        F.saturation_coefficients(ns, 0.0, 5.0, -1.0, 1.0), [2.0, 0, 0, 0, 0]
    )


def test_no_crossing_is_exact() -> None:
    ns = np.arange(6)
    zeros = np.zeros(6)
    for d in (1.0, 1.5, 1e300):  # never on, including exact grazing from below (d - b == A)
        np.testing.assert_array_equal(F.step_coefficients(ns, 1.0, 0.0, d), zeros)
        np.testing.assert_array_equal(F.ramp_coefficients(ns, 1.0, 0.0, d), zeros)
        np.testing.assert_array_equal(F.dirac_coefficients(ns, 1.0, 0.0, d + 1), zeros)
    for d in (-1.0, -1.5):  # always on
        np.testing.assert_array_equal(F.step_coefficients(ns, 1.0, 0.0, d), [2, 0, 0, 0, 0, 0])
        np.testing.assert_array_equal(F.sign_coefficients(ns, 1.0, 0.0, d), [2, 0, 0, 0, 0, 0])
        np.testing.assert_array_equal(
            F.ramp_coefficients(ns, 1.0, 0.0, d), [2 * (0.0 - d), 1.0, 0, 0, 0, 0]
        )
    for arr in (
        F.step_coefficients(ns[:, None], 2.0, 0.5, [3.0, -3.0]),
        F.ramp_coefficients(ns, 2.0, 0.5, 9),
    ):
        assert np.isfinite(arr).all() and arr.dtype == np.float64


def test_dirac_tangency_raises() -> None:
    for A, b, d in [(1.0, 0.0, 1.0), (1.0, 0.0, -1.0), (0.0, 2.0, 2.0), (2.0, 1.0, 3.0)]:
        with pytest.raises(FourierError, match="tangency"):
            F.dirac_coefficients(3, A, b, d)
    with pytest.raises(FourierError, match="tangency"):  # one bad element in an array
        F.dirac_coefficients(3, [0.5, 1.0, 2.0], 0.0, 1.0)


# ---------------------------------------------------------------------------------------------
# large n
# ---------------------------------------------------------------------------------------------

NS_LARGE = (999, 1000, 4321, 9999, 10_000, 123_456)
LARGE_CASES = [(1.0, 0.0, 0.3), (2.5, 0.7, -1.9), (4.0, -1.0, 3.0 - 1e-9), (1.0, 0.2, 0.2)]


@pytest.mark.parametrize("A, b, d", LARGE_CASES)
def test_large_n_single_breakpoint(A: float, b: float, d: float) -> None:
    """n up to ~1e5 against the exact antiderivative at 50 digits (quadrature would need
    thousands of pieces; see test_large_n_quadrature for one such check)."""
    for name, (numeric, segs, linear) in FUNCS_1.items():
        refs = mp_exact_pwl(NS_LARGE, A, b, segs(d))
        vals = numeric(np.array(NS_LARGE), A, b, d)
        scale = lin_scale(A, b, d) if linear else 1.0
        for n, v, ref in zip(NS_LARGE, vals, refs, strict=True):
            assert_close(v, ref, scale=scale, what=f"{name} n={n}")


@pytest.mark.parametrize("A, b, lo, hi", [(3.0, 0.1, -1.0, 1.0), (1.0, 0.5, 0.2, 1.4)])
def test_large_n_two_breakpoints(A: float, b: float, lo: float, hi: float) -> None:
    for numeric, segs in [(F.saturation_coefficients, seg_sat), (F.deadzone_coefficients, seg_dz)]:
        refs = mp_exact_pwl(NS_LARGE, A, b, segs(lo, hi))
        vals = numeric(np.array(NS_LARGE), A, b, lo, hi)
        for n, v, ref in zip(NS_LARGE, vals, refs, strict=True):
            assert_close(v, ref, scale=lin_scale(A, b, lo, hi), what=f"{numeric.__name__} n={n}")


@pytest.mark.slow
def test_large_n_quadrature() -> None:
    """n = 1e4 by honest quadrature (~800 Gauss-Legendre pieces of 48 nodes)."""
    A, b, d = 2.5, 0.7, -1.9
    ns = (10_000,)
    (step_ref,), (ramp_ref,) = mp_quad_coefficients([heaviside(d), ramp(d)], ns, A, b, [d])
    assert_close(F.step_coefficients(ns[0], A, b, d), step_ref, what="step n=1e4")
    assert_close(
        F.ramp_coefficients(ns[0], A, b, d), ramp_ref, scale=lin_scale(A, b, d), what="ramp"
    )


def test_oracles_agree() -> None:
    """The exact-antiderivative oracle against the quadrature oracle (checks both)."""
    cases = [(2.0, 0.3, 1.1), (1.0, 0.0, -0.999), (0.7, -2.0, -2.5), (1.0, 0.0, 1 - 1e-10)]
    for A, b, d in cases:
        for g, segs in [(ramp(d), seg_ramp), (absval(d), seg_abs), (signum(d), seg_sign)]:
            q = mp_quad_coefficients(g, NS_SMALL, A, b, [d])
            e = mp_exact_pwl(NS_SMALL, A, b, segs(d))
            for qq, ee in zip(q, e, strict=True):
                assert abs(qq - ee) < mp.mpf(10) ** -25


# ---------------------------------------------------------------------------------------------
# identities
# ---------------------------------------------------------------------------------------------


@HSET
@given(geometries(), st.integers(0, 50))
def test_step_complement_identity(geom: tuple[float, float, float], n: int) -> None:
    """H(x - d) + H(d - x) = 1 (a.e.).  With x' = -x = A cos(psi + pi) - b, H(d - x) has the
    coefficients (-1)**n step(n, A, -b, -d), so the two must add to 2 delta_{n0}."""
    A, b, d = geom
    if A == 0 and b == d:
        return  # H(0) + H(0) = 1 too, but via the 1/2 convention, covered elsewhere
    total = F.step_coefficients(n, A, b, d) + (-1) ** n * F.step_coefficients(n, A, -b, -d)
    assert abs(total - (2.0 if n == 0 else 0.0)) <= 4e-15


@HSET
@given(geometries(), st.integers(1, 60))
def test_ramp_step_recurrence(geom: tuple[float, float, float], n: int) -> None:
    """Integration by parts: r_n = (A/(2n)) (s_{n-1} - s_{n+1}) for n >= 1."""
    A, b, d = geom
    r = F.ramp_coefficients(n, A, b, d)
    s = F.step_coefficients([n - 1, n + 1], A, b, d)
    rhs = A / (2 * n) * (s[0] - s[1])
    assert abs(r - rhs) <= 1e-14 * max(1.0, A) * (1 + abs(s[0]) + abs(s[1]))


@pytest.mark.parametrize("A, b, d", [(2.0, 0.3, 1.1), (1.0, 0.0, -0.6), (5.0, 2.0, 1.0)])
def test_derivative_relations(A: float, b: float, d: float) -> None:
    """d r_n/dd = -s_n, d r_n/db = s_n, d r_n/dA = (s_{n-1} + s_{n+1})/2 (s_{-1} = s_1),
    d s_n/dd = -delta_n: central differences of the numeric functions."""
    ns = np.arange(0, 8)
    h = 1e-6
    s = F.step_coefficients(ns, A, b, d)
    s_pm = F.step_coefficients(np.abs(np.concatenate([ns - 1, ns + 1])), A, b, d).reshape(2, -1)
    dr_dd = (F.ramp_coefficients(ns, A, b, d + h) - F.ramp_coefficients(ns, A, b, d - h)) / (2 * h)
    dr_db = (F.ramp_coefficients(ns, A, b + h, d) - F.ramp_coefficients(ns, A, b - h, d)) / (2 * h)
    dr_dA = (F.ramp_coefficients(ns, A + h, b, d) - F.ramp_coefficients(ns, A - h, b, d)) / (2 * h)
    ds_dd = (F.step_coefficients(ns, A, b, d + h) - F.step_coefficients(ns, A, b, d - h)) / (2 * h)
    np.testing.assert_allclose(dr_dd, -s, atol=1e-8)
    np.testing.assert_allclose(dr_db, s, atol=1e-8)
    np.testing.assert_allclose(dr_dA, 0.5 * (s_pm[0] + s_pm[1]), atol=1e-8)
    np.testing.assert_allclose(ds_dd, -F.dirac_coefficients(ns, A, b, d), atol=1e-7)


@HSET
@given(geometries(), st.integers(0, 30))
def test_abs_sign_saturation_relations(geom: tuple[float, float, float], n: int) -> None:
    """|x - d| = (x - d) sign(x - d) is not linear in coefficients, but these are:
    sat(x; l, u) + dz(x; l, u) = x and sign = 2H - 1, |x - d| = 2 ramp - (x - d)."""
    A, b, d = geom
    lin = {0: 2 * b, 1: A}.get(n, 0.0)
    sat = F.saturation_coefficients(n, A, b, d - 1.0, d + 0.5)
    dz = F.deadzone_coefficients(n, A, b, d - 1.0, d + 0.5)
    assert abs(sat + dz - lin) <= 1e-14 * lin_scale(A, b, d) * 4
    if not (A == 0 and b == d):
        sg = F.sign_coefficients(n, A, b, d)
        assert abs(sg - (2 * F.step_coefficients(n, A, b, d) - (2.0 if n == 0 else 0.0))) < 1e-14
    ab = F.abs_coefficients(n, A, b, d)
    lin_d = {0: 2 * (b - d), 1: A}.get(n, 0.0)
    assert abs(ab - (2 * F.ramp_coefficients(n, A, b, d) - lin_d)) <= 4e-14 * lin_scale(A, b, d)


# ---------------------------------------------------------------------------------------------
# general PWL and the Zou-Nagarajaiah force
# ---------------------------------------------------------------------------------------------


def zn_pwl(k: float) -> dict[str, object]:
    """f = k x + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)].  With (x+1)H(-x-1) = (x+1) - (x+1)H(x+1):
    f = x + (1-k) + (1-k)[(x-1)H(x-1) - (x+1)H(x+1)] -- ramps at -1 and +1 plus a line."""
    return dict(
        base_slope=1.0,
        base_offset=1.0 - k,
        breakpoints=[-1.0, 1.0],
        slope_jumps=[-(1.0 - k), 1.0 - k],
        value_jumps=[0.0, 0.0],
    )


@HSET
@given(st.floats(-2.0, 0.99), st.floats(0.05, 10.0), st.floats(-2.5, 2.5))
@example(0.5, 1.0 + 1e-10, 0.0)
@example(0.5, 1.0 - 1e-10, 0.0)
@example(-1.0, 0.5, 0.0)
def test_zou_nagarajaiah_vs_quadrature(k: float, A: float, b: float) -> None:
    ns = NS_SMALL
    refs = mp_quad_coefficients(zou_nagarajaiah(k), ns, A, b, [-1.0, 1.0])
    vals = F.pwl_coefficients(np.array(ns), A, b, **zn_pwl(k))
    scale = lin_scale(A, b, 1.0) * max(1.0, abs(k), abs(1 - k))
    for n, v, ref in zip(ns, vals, refs, strict=True):
        assert_close(v, ref, scale=scale, what=f"ZN k={k} n={n} A={A} b={b}")


@HSET
@given(st.floats(-2.0, 0.99), st.floats(1.0, 50.0))
def test_zou_nagarajaiah_first_harmonic_is_deadzone_describing_function(k: float, A: float) -> None:
    """a1 = kA + (1-k) c1 with the dead-zone first harmonic c1 = A(a0 + a2) - 2 a1 built from
    step coefficients a_n = 2 sin(n theta')/(n pi), theta' = arccos(1/A) (coded here, in
    mpmath); and c1 = A [1 - (2/pi)(asin(1/A) + sqrt(1 - 1/A^2)/A)] (classical form)."""
    with mp.workdps(EXACT_DPS):
        Am, km = mp.mpf(A), mp.mpf(k)
        th = mp.acos(1 / Am)
        s0, s1, s2 = 2 * th / mp.pi, 2 * mp.sin(th) / mp.pi, mp.sin(2 * th) / mp.pi
        c1 = Am * (s0 + s2) - 2 * s1
        classical = Am * (1 - 2 / mp.pi * (mp.asin(1 / Am) + mp.sqrt(1 - 1 / Am**2) / Am))
        assert abs(c1 - classical) < mp.mpf(10) ** -40
        ref = km * Am + (1 - km) * c1
    v = F.pwl_coefficients(1, A, 0.0, **zn_pwl(k))
    assert_close(v, ref, scale=A * max(1.0, abs(k), abs(1 - k)), what=f"k={k} A={A}")


@st.composite
def pwl_forces(draw: st.DrawFn) -> dict[str, object]:
    m = draw(st.integers(0, 3))
    real = st.floats(-3.0, 3.0)
    return dict(
        base_slope=draw(real),
        base_offset=draw(real),
        breakpoints=[draw(real) for _ in range(m)],
        slope_jumps=[draw(real) for _ in range(m)],
        value_jumps=[draw(real) for _ in range(m)],
    )


def pwl_oracle(spec: dict[str, object]) -> Callable[[mp.mpf], mp.mpf]:
    k0, f0 = mp.mpf(spec["base_slope"]), mp.mpf(spec["base_offset"])
    terms = [
        (mp.mpf(d), mp.mpf(s), mp.mpf(v))
        for d, s, v in zip(
            spec["breakpoints"], spec["slope_jumps"], spec["value_jumps"], strict=True
        )
    ]
    return lambda x: (
        k0 * x + f0 + sum((s * (x - d) + v if x > d else mp.mpf(0)) for d, s, v in terms)
    )


@HSET
@given(pwl_forces(), st.floats(0.0, 5.0), st.floats(-3.0, 3.0))
def test_pwl_general_vs_quadrature(spec: dict[str, object], A: float, b: float) -> None:
    ns = NS_SMALL
    if A == 0 and any(d == b for d in spec["breakpoints"]):
        return
    refs = mp_quad_coefficients(pwl_oracle(spec), ns, A, b, spec["breakpoints"])
    vals = F.pwl_coefficients(np.array(ns), A, b, **spec)
    mag = 1.0 + sum(abs(x) for x in spec["slope_jumps"]) + abs(spec["base_slope"])
    mag += sum(abs(x) for x in spec["value_jumps"]) + abs(spec["base_offset"])
    scale = mag * lin_scale(A, b, *spec["breakpoints"])
    for n, v, ref in zip(ns, vals, refs, strict=True):
        assert_close(v, ref, scale=scale, what=f"pwl {spec} n={n} A={A} b={b}")


def test_pwl_broadcasting_sorting_and_empty() -> None:
    A = np.linspace(0.0, 4.0, 7)
    b = np.array([[-0.5], [0.0], [0.8]])
    n = np.arange(6)[:, None, None]
    spec = zn_pwl(0.3)
    out = F.pwl_coefficients(n, A, b, **spec)
    assert out.shape == (6, 3, 7)
    for i in range(3):
        for j in range(7):
            np.testing.assert_allclose(
                out[:, i, j],
                F.pwl_coefficients(np.arange(6), A[j], b[i, 0], **spec),
                rtol=0,
                atol=1e-15,
            )
    rev = dict(spec, breakpoints=spec["breakpoints"][::-1], slope_jumps=spec["slope_jumps"][::-1])
    np.testing.assert_allclose(F.pwl_coefficients(n, A, b, **rev), out, rtol=0, atol=1e-14)
    empty = F.pwl_coefficients(np.arange(4), 2.0, 0.5, 3.0, 1.0, [], [], [])
    np.testing.assert_array_equal(empty, [2 * (3.0 * 0.5 + 1.0), 6.0, 0.0, 0.0])
    # ZN force with the motion inside (-1, 1): exactly k x
    np.testing.assert_allclose(
        F.pwl_coefficients(np.arange(4), 0.7, 0.0, **spec), [0, 0.3 * 0.7, 0, 0], atol=1e-16
    )


# ---------------------------------------------------------------------------------------------
# vectorisation: the fast sin/cos table path against elementwise evaluation
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "n",
    [
        np.arange(0, 1200)[:, None],  # contiguous from 0 (reshape path)
        np.arange(7, 700)[:, None],  # contiguous, offset
        np.arange(0, 6000, 7)[:, None],  # strided (gather path)
        np.array([3, 10_000, 0, 1, 2, 999, 5000] * 60)[:, None],  # unsorted, repeated
    ],
)
def test_table_path_matches_direct(n: np.ndarray) -> None:
    A = np.linspace(0.0, 3.0, 41)
    b, d = 0.1, 0.9
    fast = F.ramp_coefficients(n, A, b, d)
    assert fast.size >= F.CIS_TABLE_MIN  # large enough for the table plans
    slow = np.array([F.ramp_coefficients(n[:, 0], a, b, d) for a in A]).T
    np.testing.assert_allclose(fast, slow, rtol=0, atol=2e-15 * 3)
    # phi-first layout (A varies along the first axis, n along the second) and a reflected d
    fast2 = F.step_coefficients(n[:, 0], A[:, None], b, -d)
    slow2 = np.array([F.step_coefficients(n[:, 0], a, b, -d) for a in A])
    np.testing.assert_allclose(fast2, slow2, rtol=0, atol=1e-15)
    fast3 = F.dirac_coefficients(n, A[1:], b, d)
    slow3 = np.array([F.dirac_coefficients(n[:, 0], a, b, d) for a in A[1:]]).T
    # both carry the unavoidable ~n*theta*eps error of cos(n theta) (see test_dirac_vs_sifting)
    envelope = np.max(np.abs(slow3), axis=0)
    np.testing.assert_array_less(np.abs(fast3 - slow3), 4 * (n + 1) * EPS * envelope + 1e-300)


def test_mixed_sides_and_merged_groups_match_elementwise() -> None:
    """Large calls where b lies on both sides of the breakpoints (per-element reflection in
    the tables) and symmetric ones (breakpoints merged into one pass) against scalar calls."""
    n = np.arange(0, 600)[:, None]
    A = np.linspace(0.05, 3.0, 40)
    b = np.where(np.arange(40) % 2 == 0, -0.4, 0.4)
    spec = dict(
        base_slope=0.2,
        base_offset=0.1,
        breakpoints=[-0.3, 0.3],
        slope_jumps=[1.5, -0.7],
        value_jumps=[0.25, -0.5],
    )
    cases = [
        (F.pwl_coefficients, (n, A, b), spec),
        (F.saturation_coefficients, (n, A, b, -0.3, 0.3), {}),
        (F.deadzone_coefficients, (n, A, b, -0.3, 0.3), {}),
        (F.abs_coefficients, (n, A, b, 0.3), {}),
        (F.pwl_coefficients, (n, A, 0.0), spec),  # b = 0: both breakpoints share phi
        (F.pwl_coefficients, (n, A, 0.0), zn_pwl(0.25)),
    ]
    for func, args, kwargs in cases:
        big = func(*args, **kwargs)
        assert big.shape == (600, 40) and big.size >= F.CIS_TABLE_MIN
        for j in range(A.size):
            bj = args[2] if np.ndim(args[2]) == 0 else args[2][j]
            small = func(n[:, 0], A[j], bj, *args[3:], **kwargs)
            np.testing.assert_allclose(big[:, j], small, rtol=0, atol=1e-14, err_msg=func.__name__)


def test_vectorised_shapes_and_types() -> None:
    out = F.step_coefficients(np.arange(4)[:, None], np.array([1.0, 2.0]), 0.0, 0.5)
    assert out.shape == (4, 2) and out.dtype == np.float64
    assert F.ramp_coefficients(3, 1.0, 0.0, 0.5).shape == ()
    assert F.step_coefficients(2.0, 1.0).shape == ()  # integral float n is accepted
    assert F.step_coefficients(np.uint8(2), 1.0).shape == ()
    sat = F.saturation_coefficients(1, [1.0, 2.0], 0.0, [[-1.0], [-0.5]], 1.0)
    assert sat.shape == (2, 2)


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "call, fragments",
    [
        (lambda: F.step_coefficients(1, -1.0, 0.0, 0.0), ("A", "-1.0", ">= 0")),
        (lambda: F.ramp_coefficients(1, float("nan")), ("A", "nan", "finite")),
        (lambda: F.step_coefficients(-1, 1.0), ("n", "-1", "non-negative integer")),
        (lambda: F.step_coefficients(1.5, 1.0), ("n", "1.5", "integer")),
        (lambda: F.step_coefficients(1, 1.0, 0.0, float("inf")), ("d", "inf", "finite")),
        (lambda: F.ramp_coefficients(1, 1.0, float("nan"), 0.0), ("b", "nan", "finite")),
        (lambda: F.crossing_angle(-1.0, 0.0, 0.0), ("A", "-1.0")),
        (lambda: F.step_coefficients([0, -3], 1.0), ("n", "-3", "index (1,)")),
        (lambda: F.step_coefficients(1, [1.0, -2.0]), ("A", "-2.0", "index (1,)")),
        (lambda: F.step_coefficients(1, 1.0 + 2j), ("A", "real")),
        (lambda: F.step_coefficients(True, 1.0), ("n", "integer")),
        (lambda: F.step_coefficients(1, [1.0, 2.0], 0.0, [1.0, 2.0, 3.0]), ("broadcast",)),
        (lambda: F.saturation_coefficients(1, 1.0, 0.0, 1.0, -1.0), ("lower", "upper", "1.0")),
        (lambda: F.power_coefficients(1, 1.0, 0.0, -1), ("m", "-1")),
        (lambda: F.power_coefficients(1, 1.0, 0.0, 1.5), ("m", "1.5")),
        (lambda: F.pwl_coefficients(1, 1.0, 0.0, 1.0, 0.0, [0.0], [1.0, 2.0], [0.0]), ("length",)),
        (
            lambda: F.pwl_coefficients(1, 1.0, 0.0, 1.0, 0.0, [float("inf")], [1.0], [0.0]),
            ("breakpoints", "inf"),
        ),
    ],
)
def test_bad_input_raises_fourier_error(
    call: Callable[[], object], fragments: tuple[str, ...]
) -> None:
    with pytest.raises(FourierError) as info:
        call()
    assert isinstance(info.value, PerturbError) and isinstance(info.value, ValueError)
    for frag in fragments:
        assert frag in str(info.value), (frag, str(info.value))


# ---------------------------------------------------------------------------------------------
# symbolic layer
# ---------------------------------------------------------------------------------------------

A_s, b_s, d_s = sp.symbols("A b d", real=True)
SERIES = {
    "step": (F.step_series, F.step_coefficients, heaviside),
    "ramp": (F.ramp_series, F.ramp_coefficients, ramp),
    "dirac": (F.dirac_series, F.dirac_coefficients, None),
}


@settings(max_examples=8, deadline=None, derandomize=True, database=None)
@given(geometries())
@example((2.0, 0.25, 2.25))  # d - b == A exactly: grazing from below
@example((2.0, 0.25, -1.75))  # d - b == -A exactly: tangent from above
@example((2.0, 0.3, 2.3))  # 2.3 - 0.3 < 2 by ~2e-16 in binary: a real (tiny) crossing
def test_series_agree_with_numeric_and_mpmath(geom: tuple[float, float, float]) -> None:
    A, b, d = geom
    ks = (0, 1, 2, 5)
    for name, (make, numeric, g) in SERIES.items():
        series = make(A_s, b_s, d_s)
        if name == "dirac":
            lo, hi = exact_gaps(A, b, d)
            if lo == 0 or hi == 0:
                with pytest.raises(FourierError):
                    series.evaluate(1, A=A, b=b, d=d)
                continue
            refs = mp_dirac(ks, A, b, d)
        else:
            if A == 0 and b == d and name == "step":
                refs = [mp.mpf(1), 0, 0, 0]
            else:
                refs = mp_quad_coefficients(g(d), ks, A, b, [d])
        for k, ref in zip(ks, refs, strict=True):
            sym = series.evaluate(k, A=A, b=b, d=d)
            num = float(numeric(k, A, b, d))
            scale = lin_scale(A, b, d) if name == "ramp" else 1.0
            if name == "dirac":
                scale = abs(float(ref)) + 1.0
            assert_close(sym, ref, scale=scale, what=f"symbolic {name} k={k} {geom}")
            assert_close(num, mp.mpf(sym), scale=scale, what=f"numeric vs symbolic {name} k={k}")


def test_series_textbook_form_and_fields() -> None:
    s = F.step_series(A_s, b_s, d_s)
    th = sp.Symbol("theta", positive=True)
    assert s.definitions == ((th, sp.acos((d_s - b_s) / A_s)),)
    assert sp.simplify(s.an - 2 * sp.sin(s.n * th) / (s.n * sp.pi)) == 0
    assert s.coefficient(0) == 2 * th / sp.pi
    assert s.coefficient(3) == 2 * sp.sin(3 * th) / (3 * sp.pi)
    assert s.n.is_integer and s.n.is_positive
    assert s.domain == (sp.Abs(d_s - b_s) < A_s)
    r = F.ramp_series(A_s, b_s, d_s, theta="phi")
    phi = sp.Symbol("phi", positive=True)
    assert r.definitions[0][0] == phi and r.coefficient(1) == A_s / sp.pi * (
        phi - sp.sin(phi) * sp.cos(phi)
    )
    assert th not in r.an.free_symbols and phi in r.an.free_symbols
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.a0 = sp.Integer(0)  # type: ignore[misc]
    text = str(s)
    assert "Heaviside" in text and "theta" in text and "acos" in text
    assert repr(s).startswith("FourierSeries(")
    assert hash(s) == hash(F.step_series(A_s, b_s, d_s))


def test_series_derivation_by_sympy_integration() -> None:
    """The ramp formula against SymPy's own integral of (2A/pi)(cos psi - cos theta) cos k psi."""
    A, th, psi = sp.symbols("A theta psi", positive=True)
    r = F.ramp_series(A, 0, sp.Symbol("d"), theta=th)
    for k in (0, 1, 2, 3):
        integral = (
            2 * A / sp.pi * sp.integrate((sp.cos(psi) - sp.cos(th)) * sp.cos(k * psi), (psi, 0, th))
        )
        diff = (integral - r.coefficient(k)).rewrite(sp.exp)
        assert sp.simplify(diff) == 0, k


def test_series_piecewise_regimes_are_exact() -> None:
    s = F.step_series(A_s, b_s, d_s)
    pw = s.piecewise(2)
    assert isinstance(pw, sp.Piecewise)
    assert pw.subs({A_s: 1, b_s: 0, d_s: 2}) == 0  # never on
    assert pw.subs({A_s: 1, b_s: 0, d_s: 1}) == 0  # grazing from below
    assert pw.subs({A_s: 1, b_s: 0, d_s: -3}) == 0
    assert s.piecewise(0).subs({A_s: 1, b_s: 0, d_s: -3}) == 2  # always on
    assert s.piecewise(0).subs({A_s: 0, b_s: 1, d_s: 1}) == 1  # Heaviside(0) = 1/2
    assert s.piecewise(0).subs({A_s: 2, b_s: 0, d_s: 1}) == sp.Rational(2, 3)  # theta = pi/3
    r = F.ramp_series(A_s, b_s, d_s)
    assert r.piecewise(0).subs({A_s: 1, b_s: 0, d_s: -3}) == 6
    assert r.piecewise(1).subs({A_s: 1, b_s: 0, d_s: -3}) == 1
    assert r.piecewise(4).subs({A_s: 1, b_s: 0, d_s: -3}) == 0
    assert r.piecewise(1).subs({A_s: 1, b_s: 0, d_s: 3}) == 0
    dr = F.dirac_series(A_s, b_s, d_s)
    assert dr.piecewise(3).subs({A_s: 1, b_s: 0, d_s: 3}) == 0
    assert dr.piecewise(3).subs({A_s: 1, b_s: 0, d_s: 1}) is sp.nan
    assert s.evaluate(2, A=1.0, b=0.0, d=1.0 + 1e-15) == 0.0


def test_series_substituted_partial_sum_and_numbers() -> None:
    r = F.ramp_series(A_s, b_s, d_s)
    sub = r.substituted()
    assert sub.definitions == () and not any(
        s.name == "theta" for s in sub.an.free_symbols | sub.a0.free_symbols
    )
    vals = {A_s: sp.Rational(3, 2), b_s: sp.Rational(1, 5), d_s: sp.Rational(1, 2)}
    for k in (0, 1, 4):
        assert (
            abs(float(sub.coefficient(k).subs(vals)) - r.evaluate(k, A=1.5, b=0.2, d=0.5)) < 1e-14
        )
    # partial sums of the (continuous) ramp converge like 1/N^2 to the function
    num = F.ramp_series(sp.Rational(3, 2), sp.Rational(1, 5), sp.Rational(1, 2)).substituted()
    psi = sp.Symbol("psi")
    ps = sp.lambdify(psi, num.partial_sum(psi, 40), "mpmath")
    for p in (0.0, 0.4, 1.0, 2.5):
        x = 1.5 * math.cos(p) + 0.2
        assert abs(float(ps(p)) - max(x - 0.5, 0.0)) < 2e-3
    # numeric parameters give plain numbers
    st_num = F.step_series(2, 0, 1)
    assert st_num.substituted().coefficient(0) == sp.Rational(2, 3)
    assert st_num.evaluate(0) == pytest.approx(2 / 3, rel=1e-15)


def test_series_bad_input() -> None:
    with pytest.raises(FourierError, match="A"):
        F.step_series(-1, 0, 0)
    with pytest.raises(FourierError, match="nan"):
        F.ramp_series(1, sp.nan, 0)
    s = F.step_series(A_s, b_s, d_s)
    with pytest.raises(FourierError, match="k"):
        s.coefficient(-1)
    with pytest.raises(FourierError, match="d"):
        s.evaluate(1, A=1.0, b=0.0)
    with pytest.raises(FourierError, match="tangen|undefined"):
        F.dirac_series(A_s, b_s, d_s).evaluate(1, A=1.0, b=0.0, d=1.0)
