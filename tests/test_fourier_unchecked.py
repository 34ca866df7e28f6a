"""The unchecked kernels of :mod:`perturb.fourier.coefficients` used by the compiled numeric layer.

They skip input validation only: on valid input they must give exactly the bits of the public,
validating functions, including at grazing (``A -> |d - b|+``), where the kernels switch
between closed forms and series.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perturb.errors import FourierError
from perturb.fourier import coefficients as F

PAIRS = [
    (F.step_coefficients, F.UNCHECKED[F.step_coefficients]),
    (F.ramp_coefficients, F.UNCHECKED[F.ramp_coefficients]),
    (F.dirac_coefficients, F.UNCHECKED[F.dirac_coefficients]),
]

EPS = np.finfo(float).eps


def _amplitudes(rng: np.random.Generator, gap: float, size: int) -> np.ndarray:
    """Amplitudes about the breakpoint distance ``gap``: grazing from above by 1..8 ulps and
    by 1e-16..1e-1 relative, exactly tangent, a wide range, and A = 0."""
    graze_ulps = gap * (1 + EPS * rng.integers(1, 9, size))
    graze_rel = gap * (1 + 10.0 ** rng.uniform(-16, -1, size))
    wide = 10.0 ** rng.uniform(-3, 6, size)
    return np.concatenate([graze_ulps, graze_rel, [gap, 0.0], wide])


@pytest.mark.parametrize("checked, unchecked", PAIRS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("seed", range(6))
def test_unchecked_is_bit_identical_to_checked(checked, unchecked, seed) -> None:
    rng = np.random.default_rng(seed)
    b = float(rng.choice([0.0, rng.normal(0, 0.5)]))
    d = float(rng.choice([1.0, -1.0, rng.normal()]))
    A = _amplitudes(rng, abs(d - b), 200)
    if checked is F.dirac_coefficients:  # infinite at tangency: not a valid input there
        A = A[np.abs(A - abs(d - b)) > 0]
        A = A[A > 0]
    layouts = [
        np.array([[1]]),  # the frequency response's single first harmonic
        np.array([3, 5, 7, 9, 11, 13, 15])[:, None],  # its odd harmonics of one breakpoint
        np.array([0, 2])[:, None],
        np.arange(0, 120)[:, None],  # large enough for the baby/giant-step trig tables
        rng.integers(0, 40, A.size),  # elementwise n, not an outer product
    ]
    for n in layouts:
        want = checked(n, A, b, d)
        got = unchecked(n, A, b, d)
        assert got.shape == want.shape
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_unchecked_accepts_scalars_and_arrays_for_b_d() -> None:
    A = np.array([0.5, 1.0 + 1e-12, 3.0])
    b = np.array([0.0, 0.1, -0.2])
    for checked, unchecked in PAIRS[:2]:
        np.testing.assert_array_equal(unchecked(4, A, b, 1.0), checked(4, A, b, 1.0))
        np.testing.assert_array_equal(unchecked(2, 1.5, 0.0, 1.0), checked(2, 1.5, 0.0, 1.0))


def test_public_functions_still_validate() -> None:
    # the fast path is internal; users keep the clear errors
    with pytest.raises(FourierError, match="A must be"):
        F.ramp_coefficients(1, -1.0, 0.0, 1.0)
    with pytest.raises(FourierError, match="n must be"):
        F.step_coefficients(1.5, 2.0, 0.0, 1.0)
    with pytest.raises(FourierError, match="b must be"):
        F.ramp_coefficients(1, 2.0, math.nan, 1.0)
    with pytest.raises(FourierError, match="tangency"):
        F.UNCHECKED[F.dirac_coefficients](1, 1.0, 0.0, 1.0)  # a value property, still raised


def test_unchecked_table_maps_the_public_kernels() -> None:
    # exactly the three kernels, each to a twin of its own (not to itself: the checks are gone)
    assert set(F.UNCHECKED) == {F.step_coefficients, F.ramp_coefficients, F.dirac_coefficients}
    twins = list(F.UNCHECKED.values())
    assert len(set(twins)) == 3 and not set(twins) & set(F.UNCHECKED)


def _ramp_integral_reference(m, phi, c, s):
    """The series as first written: one Horner loop per row (the vectorised kernel must
    perform the same multiply-then-add per element, hence give the same bits)."""
    mf = m.astype(np.float64)
    series = (m >= 2) | (phi < 1.0)
    x = phi * phi
    y = (mf * phi) ** 2
    P = np.zeros_like(phi)
    for j in range(F.RAMP_SERIES.shape[0] - 1, -1, -1):
        Qj = np.zeros_like(phi)
        for k in range(F.RAMP_SERIES.shape[1] - 1, -1, -1):
            Qj = Qj * y + F.RAMP_SERIES[j, k]
        P = P * x + Qj
    closed = np.where(m == 0, s - phi * c, 0.5 * (phi - s * c))
    return np.where(series, phi**3 * P, closed)


@pytest.mark.parametrize("seed", range(4))
def test_ramp_integral_matches_the_row_by_row_series_bitwise(seed) -> None:
    rng = np.random.default_rng(seed)
    size = 3000
    m = rng.integers(0, 4, size)
    # small angles (grazing), angles about the series/closed-form switch at 1, and up to pi/2
    phi = np.concatenate(
        [10.0 ** rng.uniform(-9, -1, size // 3), rng.uniform(0.9, 1.1, size // 3)]
        + [rng.uniform(0, 0.5 * np.pi, size - 2 * (size // 3))]
    )
    phi[:3] = [0.0, 1.0, np.nextafter(1.0, 0.0)]
    keep = (m <= 1) | (np.maximum(m, 1) * phi < 1)  # the kernel's domain
    m, phi = m[keep], phi[keep]
    c, s = np.cos(phi), np.sin(phi)
    np.testing.assert_array_equal(
        F.ramp_integral(m, phi, c, s), _ramp_integral_reference(m, phi, c, s)
    )
    none = phi >= 1.0  # no element needs the series
    np.testing.assert_array_equal(
        F.ramp_integral(np.ones(none.sum(), int), phi[none], c[none], s[none]),
        _ramp_integral_reference(np.ones(none.sum(), int), phi[none], c[none], s[none]),
    )
