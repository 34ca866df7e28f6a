"""Tests of :mod:`perturb.model.symmetry` (the odd half-period symmetry of forced oscillators).

Oracles: hand-written vector fields whose symmetry is known from their formula, trigonometric
polynomials evaluated at shifted times (the image ``-x(t + T/2)`` computed directly), and
Fourier coefficients recovered from samples by the discrete orthogonality of cos/sin.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perturb.errors import ParameterError, PerturbError
from perturb.model.symmetry import is_odd_symmetric, mirror_harmonic, mirror_nodes


def _duffing(static=0.0, second=0.0, offset=0.0, W=1.3):
    """x'' + 0.1 x' + x + x^3 + offset = static + cos(W t) + second cos(2 W t)."""

    def field(t, y):
        x, v = y
        load = static + math.cos(W * t) + second * math.cos(2 * W * t)
        return np.array([v, load - 0.1 * v - x - x**3 - offset])

    return field, 2 * math.pi / W


def test_odd_symmetric_recognises_the_symmetry_from_the_formula():
    field, T = _duffing()
    assert is_odd_symmetric(field, T, 3.0)
    # a third harmonic of the forcing is negated by the half-period shift as well
    W = 0.7

    def third(t, y):
        return np.array([y[1], math.cos(W * t) + 0.4 * math.sin(3 * W * t) - y[0] ** 3])

    assert is_odd_symmetric(third, 2 * math.pi / W, 2.0)


@pytest.mark.parametrize(
    "kw", [{"static": 0.2}, {"second": 0.3}, {"offset": 0.1}], ids=["static", "even", "offset"]
)
def test_odd_symmetric_rejects_broken_symmetry(kw):
    field, T = _duffing(**kw)
    assert not is_odd_symmetric(field, T, 3.0)


def test_odd_symmetric_sees_an_asymmetric_breakpoint_inside_the_box_only():
    # clearance spring at x = 0.5: asymmetric, but invisible from a box inside |x| < 0.5
    def field(t, y):
        x, v = y
        return np.array([v, math.cos(t) - x - 10.0 * max(x - 0.5, 0.0)])

    assert not is_odd_symmetric(field, 2 * math.pi, 3.0)
    assert is_odd_symmetric(field, 2 * math.pi, 0.4)


def test_odd_symmetric_failing_field_and_bad_arguments():
    def failing(t, y):
        raise PerturbError("outside the domain")

    assert not is_odd_symmetric(failing, 1.0, 1.0)
    field, T = _duffing()
    with pytest.raises(ParameterError, match="period"):
        is_odd_symmetric(field, 0.0, 1.0)
    with pytest.raises(ParameterError, match="extent"):
        is_odd_symmetric(field, T, float("nan"))


@pytest.mark.parametrize("m", [1, 2, 3])
def test_mirror_nodes_is_minus_x_half_a_forcing_period_later(m):
    T = 2.0
    P = m * T
    w = 2 * math.pi / P  # orbit frequency

    def y(t):
        x = 0.4 + math.cos(w * t + 0.3) + 0.2 * math.sin(2 * w * t) + 0.05 * math.cos(5 * w * t)
        v = -w * math.sin(w * t + 0.3) + 0.4 * w * math.cos(2 * w * t)
        v -= 0.25 * w * math.sin(5 * w * t)
        return np.array([x, v])

    N = 12 * m
    t = P * np.arange(N) / N
    nodes = np.array([y(ti) for ti in t])
    image = mirror_nodes(nodes, m)
    expected = np.array([-y(ti + T / 2) for ti in t])
    np.testing.assert_allclose(image, expected, atol=1e-13)
    # twice: the orbit one forcing period later (the identity for m = 1)
    np.testing.assert_array_equal(mirror_nodes(image, m), np.roll(nodes, -N // m, axis=0))


def test_mirror_nodes_validates():
    with pytest.raises(ParameterError, match="multiple"):
        mirror_nodes(np.zeros((7, 2)))
    with pytest.raises(ParameterError, match="multiple"):
        mirror_nodes(np.zeros((6, 2)), m=2)
    with pytest.raises(ParameterError, match="m ="):
        mirror_nodes(np.zeros((8, 2)), m=0)


@pytest.mark.parametrize(("k", "m"), [(1, 1), (2, 1), (3, 1), (1, 2), (3, 2), (2, 3), (5, 4)])
def test_mirror_harmonic_matches_the_coefficients_of_the_image(k, m):
    a, b = 0.7, -0.45
    n = 64
    theta = 2 * math.pi * np.arange(n) / n
    delta = math.pi / m
    image = -(a * np.cos(k * (theta + delta)) + b * np.sin(k * (theta + delta)))
    # discrete orthogonality (n > 2k): exact projection onto cos k theta, sin k theta
    coeffs = np.array([image @ np.cos(k * theta), image @ np.sin(k * theta)]) * 2 / n
    np.testing.assert_allclose(mirror_harmonic(k, m) @ np.array([a, b]), coeffs, atol=1e-14)
    if m == 1:  # odd harmonics unchanged, even ones negated
        assert np.allclose(mirror_harmonic(k, m), (1.0 if k % 2 else -1.0) * np.eye(2))
