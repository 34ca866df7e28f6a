"""Floquet multipliers about approximate orbits, against scipy.linalg.expm products."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from perturb import PerturbError, builtin_model
from perturb.numeric.stability import expm2, monodromy_multipliers


def M(p, q):
    return np.array([[0.0, 1.0], [-q, -p]])


@pytest.mark.parametrize(
    "p, q, h",
    [
        (0.1, 1.0, 0.7),
        (0.05, -2.0, 1.3),
        (2.0, 1.0, 0.5),
        (2.0, 1.0 + 1e-12, 0.9),
        (0.0, 0.0, 2.0),
        (0.3, 1e-9, 5.0),
        (0.0, 4.0, 10.0),
        (1.0, -50.0, 0.2),
    ],
)
def test_expm2_matches_scipy(p, q, h):
    np.testing.assert_allclose(expm2(p, q, h), expm(M(p, q) * h), rtol=1e-12, atol=1e-13)


def test_linear_system_multipliers_are_eigenvalues_of_expm():
    osc = builtin_model("duffing", alpha=0.0, mu=0.1, omega0=1.3)
    T = 2 * np.pi / 0.8
    t = np.linspace(0, T, 256, endpoint=False)
    x = np.cos(0.8 * t)[None, :]
    v = -0.8 * np.sin(0.8 * t)[None, :]
    got = monodromy_multipliers(osc, x, v, np.array([T]))
    expected = np.max(np.abs(np.linalg.eigvals(expm(M(0.1, 1.69) * T))))
    assert got[0] == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("A, W", [(1.5, 0.7), (3.0, 1.1), (1.02, 0.4), (0.8, 0.9)])
def test_pwl_orbit_monodromy_matches_exact_piece_product(A, W):
    # x(t) = A cos(W t) in the nsd force (k = -2): the segment changes at W t = theta,
    # pi - theta, pi + theta, 2 pi - theta with theta = arccos(1/A) -- an exact product.
    k, mu = -2.0, 0.05
    osc = builtin_model("nsd", k=k, mu=mu)
    T = 2 * np.pi / W
    N = 2048
    t = np.linspace(0, T, N, endpoint=False)
    got = monodromy_multipliers(
        osc, (A * np.cos(W * t))[None], (-A * W * np.sin(W * t))[None], np.array([T])
    )[0]
    if A <= 1:
        P = expm(M(mu, k) * T)
    else:
        th = np.arccos(1 / A)
        cuts = np.array([0, th, np.pi - th, np.pi + th, 2 * np.pi - th, 2 * np.pi]) / W
        slopes = [1.0, k, 1.0, k, 1.0]
        P = np.eye(2)
        for s, t0, t1 in zip(slopes, cuts[:-1], cuts[1:], strict=True):
            P = expm(M(mu, s) * (t1 - t0)) @ P
    expected = np.max(np.abs(np.linalg.eigvals(P)))
    # crossing instants come from cubic Hermite interpolation between samples (O(h^4))
    assert got == pytest.approx(expected, rel=1e-8)


def test_refuses_time_dependent_linearisation_and_coarse_sampling():
    with pytest.raises(PerturbError, match="parametric"):
        monodromy_multipliers(
            builtin_model("mathieu"), np.zeros((1, 64)), np.zeros((1, 64)), np.array([np.pi])
        )
    with pytest.raises(PerturbError, match="at least 64"):
        monodromy_multipliers(
            builtin_model("nsd"), np.zeros((1, 8)), np.zeros((1, 8)), np.array([1.0])
        )


def test_hill_exponents_of_a_constant_coefficient_system_are_exact():
    # x'' + mu x' + q x = 0: multipliers exp(lambda T), lambda = -mu/2 +- sqrt(mu^2/4 - q),
    # whatever harmonic truncation (exponents are defined modulo i*w)
    from perturb.numeric.stability import hill_exponents

    for mu, q, W in ((0.1, 1.69, 0.8), (0.05, -2.0, 0.6), (0.3, 0.2, 2.0)):
        osc = builtin_model("duffing", alpha=0.0, mu=mu, omega0=np.sqrt(q) if q > 0 else 1.0)
        if q < 0:
            osc = builtin_model("nsd", k=q, mu=mu)  # |x| < 1 keeps it in the linear segment
        T = 2 * np.pi / W
        t = np.linspace(0, T, 256, endpoint=False)
        x, v = (0.5 * np.cos(W * t))[None], (-0.5 * W * np.sin(W * t))[None]
        for H in (1, 3):
            lam = hill_exponents(osc, x, v, np.array([T]), H)[0]
            roots = np.roots([1.0, mu, q]).astype(complex)
            got = np.exp(lam * T)
            expected = np.exp(roots * T)
            # compare as sets: each expected multiplier has a computed one next to it
            for e in expected:
                assert np.min(np.abs(got - e)) <= 1e-9 * abs(e) + 1e-12, (got, expected)
            assert abs(np.prod(got) - np.prod(expected)) <= 1e-9 * abs(np.prod(expected))


def test_hill_converges_to_the_monodromy_of_the_same_linearisation():
    from perturb.numeric.stability import hill_exponents

    osc = builtin_model("nsd", k=-0.5, mu=0.05)
    A, W = 2.0, 0.9
    T = 2 * np.pi / W
    t = np.linspace(0, T, 1024, endpoint=False)
    x, v = (A * np.cos(W * t))[None], (-A * W * np.sin(W * t))[None]
    reference = monodromy_multipliers(osc, x, v, np.array([T]))[0]
    errors = []
    for H in (4, 16, 64):
        lam = hill_exponents(osc, x, v, np.array([T]), H)[0]
        errors.append(abs(np.max(np.abs(np.exp(lam * T))) - reference) / reference)
    assert errors[-1] < 1e-3
    assert errors[2] < errors[0]  # converging with H
