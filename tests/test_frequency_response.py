"""Single-harmonic balance and its frequency response, against independent closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from perturb import ModelError, ParameterError, builtin_model
from perturb.methods.harmonic_balance import single_harmonic_balance
from perturb.numeric.frequency_response import frequency_response


def nsd_amplitude_equation(A, W, k, mu, F):
    """Zou–Nagarajaiah eqs. (54)-(55) with the phase eliminated, written out separately:
    (W^2 - k)A - (1-k)(A(a0 + a2) - 2a1) = -F cos(phi), mu W A = F sin(phi),
    a_n = 2 sin(n theta)/(n pi), a0 = 2 theta/pi, theta = arccos(1/A) (zero for A <= 1)."""
    A = np.asarray(A, float)
    theta = np.arccos(np.minimum(1.0, 1.0 / A))
    a0, a1, a2 = 2 * theta / np.pi, 2 * np.sin(theta) / np.pi, np.sin(2 * theta) / np.pi
    cos_part = (W**2 - k) * A - (1 - k) * (A * (a0 + a2) - 2 * a1)
    return cos_part**2 + (mu * W * A) ** 2 - F**2


@pytest.fixture(scope="module")
def nsd_response():
    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0)
    return frequency_response(single_harmonic_balance(osc), (0.2, 2.0), points=1500)


def test_every_point_satisfies_the_papers_first_order_equations(nsd_response):
    assert nsd_response.branches
    for br in nsd_response.branches:
        res = nsd_amplitude_equation(br.first_harmonic_amplitude, br.omega, -2.0, 0.05, 2.0)
        assert np.max(np.abs(res)) / 4.0 < 1e-9


def test_no_branch_is_missed(nsd_response):
    # brute force: all roots A of the amplitude equation at fixed Omega, by a fine scan
    grid = np.geomspace(1e-3, 200, 40001)
    for W in (0.3, 0.6, 0.9, 0.95, 1.2, 1.8):
        f = nsd_amplitude_equation(grid, W, -2.0, 0.05, 2.0)
        idx = np.nonzero(np.sign(f[:-1]) * np.sign(f[1:]) < 0)[0]
        roots = [
            brentq(nsd_amplitude_equation, grid[i], grid[i + 1], args=(W, -2.0, 0.05, 2.0))
            for i in idx
        ]
        assert roots, W
        for root in roots:
            # some branch passes through (W, root)
            best = np.inf
            for br in nsd_response.branches:
                w, a = br.omega, br.first_harmonic_amplitude
                s = np.nonzero(np.sign(w[:-1] - W) * np.sign(w[1:] - W) <= 0)[0]
                for j in s:
                    t = 0.0 if w[j + 1] == w[j] else (W - w[j]) / (w[j + 1] - w[j])
                    best = min(best, abs(a[j] + t * (a[j + 1] - a[j]) - root) / root)
            assert best < 2e-3, (W, root, best)


def test_branch_inside_the_negative_stiffness_well_is_unstable(nsd_response):
    # |x| < 1 on that branch: a linear oscillator with stiffness k = -2 (a saddle), unstable
    # for every forcing; the paper computes this branch exactly and reports it unstable.
    small = [br for br in nsd_response.branches if br.amplitude.max() < 1]
    assert small
    for br in small:
        assert not br.stable.any()
        lam = -0.025 + np.sqrt(0.025**2 + 2.0)  # growth rate of x'' + 0.05x' - 2x = 0
        expected = np.exp(lam * 2 * np.pi / br.omega)
        np.testing.assert_allclose(br.max_multiplier, expected, rtol=1e-6)


def test_linear_oscillator_multipliers_are_exact():
    # k = 1 makes nsd linear: x'' + mu x' + x = F cos(Omega t)
    osc = builtin_model("nsd", k=1.0, mu=0.1, F=0.5)
    resp = frequency_response(single_harmonic_balance(osc), (0.3, 3.0), points=200)
    assert len(resp.branches) == 1
    br = resp.branches[0]
    W = br.omega
    np.testing.assert_allclose(
        br.amplitude, 0.5 / np.sqrt((1 - W**2) ** 2 + (0.1 * W) ** 2), rtol=1e-9
    )
    np.testing.assert_allclose(br.max_multiplier, np.exp(-0.05 * 2 * np.pi / W), rtol=1e-9)
    assert br.stable.all()
    np.testing.assert_allclose(br.mean, 0, atol=1e-12)


def test_duffing_backbone_form_and_jump():
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5)
    resp = frequency_response(single_harmonic_balance(osc), (0.5, 2.5), points=1500)
    for br in resp.branches:
        A, W = br.first_harmonic_amplitude, br.omega
        res = ((W**2 - 1 - 0.75 * A**2) * A) ** 2 + (0.1 * W * A) ** 2 - 0.25
        assert np.max(np.abs(res)) < 1e-9
    # hardening: two folds (jump up and jump down), the middle branch unstable between them
    assert len(resp.folds) == 2
    lo, hi = sorted(w for w, _ in resp.folds)
    assert 1.0 < lo < hi
    mid = 0.5 * (lo + hi)
    found = []  # (amplitude, stable) of every solution at Omega = mid
    for br in resp.branches:
        w = br.omega
        for j in np.nonzero(np.sign(w[:-1] - mid) * np.sign(w[1:] - mid) <= 0)[0]:
            found.append((br.amplitude[j], bool(br.stable[j])))
    found.sort()
    assert len(found) == 3
    assert [st for _, st in found] == [True, False, True]


def test_bad_requests_are_clear_errors():
    osc = builtin_model("nsd")
    approx = single_harmonic_balance(osc)
    with pytest.raises(ParameterError, match="omega_range"):
        frequency_response(approx, (2.0, 0.2))
    with pytest.raises(ParameterError, match="omega_range"):
        frequency_response(approx, (0.0, float("nan")))
    with pytest.raises(ParameterError, match="needs values for mu"):
        frequency_response(single_harmonic_balance(osc.with_params(mu=None)), (0.2, 2))
    with pytest.raises(ModelError, match="not odd"):
        single_harmonic_balance(builtin_model("clearance"))
    with pytest.raises(ModelError, match="covers"):
        single_harmonic_balance(builtin_model("vanderpol"))


def test_hill_stability_changes_exactly_at_the_folds():
    """Hill's method truncated at the solution's harmonic changes stability where the
    harmonic-balance branch turns (a saddle-node), unlike Floquet about the approximate orbit
    with all harmonics, which on this strongly nonlinear Duffing case turns far from it."""
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5)
    approx = single_harmonic_balance(osc)
    resp = frequency_response(approx, (0.5, 2.5), points=3000)
    (br,) = resp.branches
    flips = np.nonzero(np.diff(br.stable.astype(int)))[0]
    assert len(flips) == 2 == len(resp.folds)
    for (w_fold, a_fold), j in zip(
        sorted(resp.folds), sorted(flips, key=lambda j: br.omega[j]), strict=True
    ):
        assert abs(br.omega[j] - w_fold) < 1e-3
        assert abs(br.first_harmonic_amplitude[j] - a_fold) / a_fold < 1e-2
    floquet = frequency_response(approx, (0.5, 2.5), points=3000, stability="floquet")
    assert not np.array_equal(floquet.branches[0].stable, br.stable)
