"""Exact frequency responses of systems with several coordinates (issue 15, item 4).

:func:`perturb.simulate.exact_response.exact_branches` on the 2-DOF ``nsd2`` structure
(:func:`perturb.model.system_builtins.builtin_system`), checked against references that share
no code with it:

* the period map integrated by DOP853 (rtol = atol = 1e-12) on the equations of motion
  written out by hand here, restarted at every crossing of ``x1 = +-1`` (the integrator never
  steps across a kink of the force), with the variational equations of the hand-written
  Jacobian (the force is continuous: no saltation), Newton on ``phi_T(y) - y``; ``max |.|`` of
  every coordinate (and of ``x1 - x2``) from non-terminal events at the roots of its rate;
* the closed-form modal response ``(K - W^2 M + i W C) Q = F`` when no contact is reached.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from perturb.errors import ModelError, ParameterError
from perturb.model.builtins import builtin_model
from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import (
    continue_orbits,
    exact_branches,
    exact_frequency_response,
)

TOL = 1e-12
NSD2 = {"k": -0.5, "mu1": 0.05, "mu2": 0.02, "k2": 1.0, "m2": 1.0, "F": 2.0}


# ------------------------------------------------------------------------------------------
# the reference: nsd2 written out by hand, DOP853 with restarts at the kinks
# ------------------------------------------------------------------------------------------
def nsd2_field(W, k, mu1, mu2, k2, m2, F):
    def f(t, y):
        x1, x2, v1, v2 = y[:4]
        h = (x1 - 1.0) if x1 > 1.0 else ((x1 + 1.0) if x1 < -1.0 else 0.0)
        a1 = F * math.cos(W * t) - mu1 * v1 - mu2 * (v1 - v2) - k * x1 - (1 - k) * h
        a1 -= k2 * (x1 - x2)
        a2 = (-mu2 * (v2 - v1) - k2 * (x2 - x1)) / m2
        return np.array([v1, v2, a1, a2])

    def jac(y):
        s = k if abs(y[0]) < 1.0 else 1.0
        return np.array(
            [
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
                [-s - k2, k2, -mu1 - mu2, mu2],
                [k2 / m2, -k2 / m2, mu2 / m2, -mu2 / m2],
            ]
        )

    return f, jac, (lambda y: y[0] - 1.0, lambda y: y[0] + 1.0)


IMPACT = {"mu": 0.05, "mu2": 0.01, "r": 20.0, "d": 0.5, "m2": 0.2, "F": 0.5}


def impact_field(W, mu, mu2, r, d, m2, F):
    """x1'' + mu x1' + x1 + r b(x1 - x2) = F cos W t, m2 x2'' + mu2 (x2' - x1') - r b = 0,
    b(s) = (s - d)^+ - (-s - d)^+ (contact springs outside the clearance |s| <= d)."""

    def f(t, y):
        x1, x2, v1, v2 = y[:4]
        s = x1 - x2
        b = (s - d) if s > d else ((s + d) if s < -d else 0.0)
        a1 = F * math.cos(W * t) - mu * v1 - x1 - r * b
        a2 = (-mu2 * (v2 - v1) + r * b) / m2
        return np.array([v1, v2, a1, a2])

    def jac(y):
        g = r if abs(y[0] - y[1]) > d else 0.0
        return np.array(
            [
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
                [-1.0 - g, g, -mu, 0.0],
                [g / m2, -g / m2, mu2 / m2, -mu2 / m2],
            ]
        )

    return f, jac, (lambda y: y[0] - y[1] - d, lambda y: y[0] - y[1] + d)


def period_map(f, jac, kinks, y0, T, extrema=False):
    """``y(T)``, the monodromy and (on request) max |x1|, |x2|, |x1 - x2| over ``[0, T]``;
    the integration restarts at every root of a function in ``kinks`` (the switches)."""

    def aug(t, z):
        return np.concatenate([f(t, z[:4]), (jac(z[:4]) @ z[4:].reshape(4, 4)).ravel()])

    def kink_up(t, z):
        return kinks[0](z)

    def kink_down(t, z):
        return kinks[1](z)

    kink_up.terminal = kink_down.terminal = True
    rates = [lambda t, z: z[2], lambda t, z: z[3], lambda t, z: z[2] - z[3]]
    combos = [np.array([1.0, 0, 0, 0]), np.array([0, 1.0, 0, 0]), np.array([1.0, -1.0, 0, 0])]
    z = np.concatenate([np.asarray(y0, float), np.eye(4).ravel()])
    t = 0.0
    values = [[float(c @ z[:4])] for c in combos]
    for _ in range(1000):
        if t >= T:
            break
        sol = solve_ivp(
            aug,
            (t, T),
            z,
            method="DOP853",
            rtol=TOL,
            atol=TOL,
            events=[kink_up, kink_down] + (rates if extrema else []),
        )
        assert sol.status >= 0
        if extrema:
            for kk, c in enumerate(combos):
                values[kk] += [float(c @ q[:4]) for q in sol.y_events[2 + kk]]
        z, t = sol.y[:, -1], float(sol.t[-1])
        if sol.status == 1 and t < T:
            # past the kink by 1e-10 (an Euler step: error ~1e-20, below any tolerance)
            t1 = min(T, t + 1e-10)
            z = z + (t1 - t) * aug(t, z)
            t = t1
    amps = [max(abs(min(v)), abs(max(v))) for v in values]
    return z[:4], z[4:].reshape(4, 4), np.array(amps)


def reference_orbit(W, y0, model="nsd2", m=1, **params):
    """The period-``m`` orbit near ``y0`` at frequency ``W``: (y0, [max|x1|, max|x2|,
    max|x1-x2|], multipliers)."""
    if model == "nsd2":
        f, jac, kinks = nsd2_field(W, **dict(NSD2, **params))
    else:
        f, jac, kinks = impact_field(W, **dict(IMPACT, **params))
    T = 2 * math.pi * m / W
    y = np.array(y0, dtype=float)
    for _ in range(30):
        yT, M, _ = period_map(f, jac, kinks, y, T)
        dy = np.linalg.solve(M - np.eye(4), y - yT)
        y = y + dy
        if np.max(np.abs(dy)) < 1e-13 * max(1.0, float(np.max(np.abs(y)))):
            break
    _, M, amps = period_map(f, jac, kinks, y, T, extrema=True)
    return y, amps, np.linalg.eigvals(M)


def assert_multipliers(got, ref, tol):
    """Every reference multiplier has a computed one within ``tol`` (relative to max(1, |mu|))."""
    got = list(np.asarray(got, dtype=complex))
    for mu in ref:
        j = int(np.argmin([abs(g - mu) for g in got]))
        assert abs(got[j] - mu) <= tol * max(1.0, abs(mu)), (got, ref)
        got.pop(j)


# ------------------------------------------------------------------------------------------
# the whole response over a resonance window (one run shared by the tests)
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def response():
    return exact_branches(
        builtin_system("nsd2"), (0.9, 1.3), workers=1, progress=False, period_doubling=True
    )


def _sample_points(res, stable, count):
    """``count`` points of the given stability spread over the period-1 branches."""
    pts = [(b, j) for b, br in enumerate(res.branches) if br.m == 1 for j in range(len(br.points))]
    pts = [(b, j) for b, j in pts if res.branches[b].points[j].stable == stable]
    assert len(pts) >= count
    pick = np.linspace(0, len(pts) - 1, count).round().astype(int)
    return [pts[i] for i in pick]


@pytest.mark.parametrize("stable", [True, False])
def test_branch_points_match_the_reference(response, stable):
    res = response
    assert res.coordinates == ("x1", "x2") and res.output == "x1"
    for b, j in _sample_points(res, stable, 4):
        q = res.branches[b].points[j]
        y, amps, mult = reference_orbit(q.parameter, q.y0)
        np.testing.assert_allclose(q.y0, y, rtol=1e-9, atol=1e-9)
        # max |.| of each coordinate to 1e-9 (relative to max(1, |.|)), the output (x1) too
        np.testing.assert_allclose(q.coordinate_amplitudes, amps[:2], rtol=1e-9, atol=1e-9)
        assert q.amplitude == pytest.approx(amps[0], rel=1e-9, abs=1e-9)
        assert_multipliers(q.multipliers, mult, 1e-7)
        assert q.stable == (np.max(np.abs(mult)) < 1.0)


def test_period_doubled_branches_match_the_reference(response):
    res = response
    pds = [s for br in res.branches if br.m == 1 for s in br.period_doublings]
    doubled = [br for br in res.branches if br.m == 2]
    assert pds and doubled
    for br in doubled:
        # not a refined fold: there M - I is singular (a multiplier at +1 to ~1e-10), so the
        # reference's Newton drifts along the null direction (by ~1e-6 at a residual of 1e-14)
        folds = {s.index for s in br.folds}
        picks = [
            next(j for j in range(i, len(br)) if j not in folds)
            for i in (len(br) // 3, (2 * len(br)) // 3)
        ]
        for q in (br.points[j] for j in picks):
            y, amps, mult = reference_orbit(q.parameter, q.y0, m=2)
            np.testing.assert_allclose(q.y0, y, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(q.coordinate_amplitudes, amps[:2], rtol=1e-9, atol=1e-9)
            assert_multipliers(q.multipliers, mult, 1e-7)
            # a genuine period-2 orbit: not its own shift by one forcing period
            y1, _, _ = reference_orbit(q.parameter, q.y0, m=1)
            assert np.max(np.abs(y1 - y)) > 1e-3


def test_folds_and_unstable_branches_are_detected(response):
    res = response
    folds = [(b, s) for b, br in enumerate(res.branches) if br.m == 1 for s in br.folds]
    assert len(folds) >= 2
    assert any(not q.stable for br in res.branches for q in br.points)
    # a refined fold is a point of its branch: an orbit of the reference period map whose
    # monodromy has a multiplier at +1.  (The reference's own Newton is not used here: at a
    # fold M - I is singular and its iterate drifts along the null direction, ~1e-7 at a
    # residual of 1e-14, which moves the multiplier by up to ~1e-3.)
    checked = 0
    for b, s in folds:
        q = res.branches[b].points[s.index]
        if q.parameter != s.parameter:
            continue  # interpolated (not refined): no orbit to check
        f, jac, kinks = nsd2_field(q.parameter, **NSD2)
        y0 = np.asarray(q.y0, dtype=float)
        T = 2 * math.pi * res.branches[b].m / q.parameter
        yT, M, _ = period_map(f, jac, kinks, y0, T)
        assert np.max(np.abs(yT - y0)) <= 1e-9 * max(1.0, float(np.max(np.abs(y0))))
        assert np.min(np.abs(np.linalg.eigvals(M) - 1.0)) < 1e-5
        # and the parameter is extreme there: both neighbours on the same side
        pa = res.branches[b].points[s.index - 1].parameter
        pb = res.branches[b].points[s.index + 1].parameter
        assert (pa - q.parameter) * (pb - q.parameter) >= 0.0
        checked += 1
    assert checked >= 1


def test_columns_carry_every_coordinate(response):
    res = response
    cols = res.columns()
    resp = res.to_response()
    assert len(cols) == len(resp.branches) == len(res.branches)
    for br, c, rb in zip(res.branches, cols, resp.branches, strict=True):
        assert set(c) == {"amplitude_x1", "amplitude_x2", "mean_x1", "mean_x2"}
        assert c["amplitude_x1"].shape == (len(br),)
        # the default output is x1: the amplitude column is max |x1|
        np.testing.assert_array_equal(rb.amplitude, c["amplitude_x1"])
        np.testing.assert_array_equal(rb.mean, c["mean_x1"])


def test_output_combination_measures_the_relative_displacement():
    system = builtin_system("nsd2")
    br = continue_orbits(system, 1.1, [1.5, 2.0, 0.1, 0.2], (1.05, 1.15), output="x1 - x2")
    assert br.output == "x1 - x2"
    for j in (0, len(br) // 2, len(br) - 1):
        q = br.points[j]
        _, amps, _ = reference_orbit(q.parameter, q.y0)
        assert q.amplitude == pytest.approx(amps[2], rel=1e-9, abs=1e-9)
        np.testing.assert_allclose(q.coordinate_amplitudes, amps[:2], rtol=1e-9, atol=1e-9)


def test_impact_pair_branches_match_the_reference():
    res = exact_branches(
        builtin_system("impact_pair"), (1.2, 1.3), workers=1, progress=False, sweep_points=10
    )
    assert res.coordinates == ("x1", "x2")
    pts = [q for br in res.branches for q in br.points]
    assert any(q.switches > 0 for q in pts)  # orbits with contacts
    for q in [pts[i] for i in np.linspace(0, len(pts) - 1, 5).round().astype(int)]:
        y, amps, mult = reference_orbit(q.parameter, q.y0, model="impact_pair")
        np.testing.assert_allclose(q.y0, y, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(q.coordinate_amplitudes, amps[:2], rtol=1e-9, atol=1e-9)
        assert_multipliers(q.multipliers, mult, 1e-7)


# ------------------------------------------------------------------------------------------
# the linear case: no contact reached, the closed-form modal response
# ------------------------------------------------------------------------------------------
def test_linear_case_equals_the_modal_response():
    k, mu1, mu2, k2, m2, F = -0.5, 0.05, 0.02, 1.0, 1.0, 0.01
    res = exact_branches(
        builtin_system("nsd2", F=F), (0.5, 2.5), workers=1, progress=False, tol=1e-14
    )
    Mm = np.diag([1.0, m2])
    Cm = np.array([[mu1 + mu2, -mu2], [-mu2, mu2]])
    Km = np.array([[k + k2, -k2], [-k2, k2]])
    A = np.block(
        [[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(Mm, Km), -np.linalg.solve(Mm, Cm)]]
    )
    # the orbit around the saddle (|x1| < 1 throughout, mean 0) is one traced branch
    inner = [br for br in res.branches if np.max(np.abs(br.coordinate_means)) < 1e-9]
    assert len(inner) == 1
    br = inner[0]
    assert br.parameters.min() == 0.5 and br.parameters.max() == 2.5
    for q in br.points[:: max(1, len(br) // 25)]:
        W = q.parameter
        Q = np.linalg.solve(Km - W**2 * Mm + 1j * W * Cm, [F, 0.0])
        assert np.abs(Q).max() < 1.0
        np.testing.assert_allclose(q.y0, np.r_[Q.real, (1j * W * Q).real], rtol=0, atol=1e-12)
        np.testing.assert_allclose(q.coordinate_amplitudes, np.abs(Q), rtol=0, atol=1e-12)
        np.testing.assert_allclose(q.coordinate_means, 0.0, rtol=0, atol=1e-12)
        mu = np.linalg.eigvals(scipy.linalg.expm(A * 2 * math.pi / W))
        assert_multipliers(q.multipliers, mu, 1e-10)
        assert not q.stable  # the negative stiffness: a saddle inside |x1| < 1


# ------------------------------------------------------------------------------------------
# front door and bad input
# ------------------------------------------------------------------------------------------
def test_frequency_response_of_a_system_with_output():
    resp = exact_frequency_response(
        builtin_system("nsd2", F=0.01), (1.2, 1.4), output="x2", workers=1, progress=False
    )
    assert resp.method == "exact" and resp.model == "nsd2"
    assert len(resp.branches) >= 1
    assert all(np.all(b.amplitude > 0) for b in resp.branches)


def test_bad_output_and_seeds_are_named():
    system = builtin_system("nsd2")
    with pytest.raises(ModelError, match="x3"):
        exact_branches(system, (1.0, 1.1), output="x3", workers=1, progress=False)
    with pytest.raises(ParameterError, match="output"):
        exact_branches(system, (1.0, 1.1), output=[1.0, 0.0], workers=1, progress=False)
    with pytest.raises(ParameterError, match="4 states"):
        exact_branches(system, (1.0, 1.1), seeds=[(1.05, (0.0, 0.0))], progress=False)
    with pytest.raises(ParameterError, match="output is for systems"):
        exact_branches(builtin_model("nsd"), (1.0, 1.1), output="x", progress=False)


def test_parallel_tracing_gives_the_serial_branches():
    system = builtin_system("nsd2")
    a = exact_branches(system, (1.05, 1.2), workers=1, progress=False, sweep_points=10)
    b = exact_branches(system, (1.05, 1.2), workers=2, progress=False, sweep_points=10)
    assert len(a.branches) == len(b.branches) and a.mirror_of == b.mirror_of
    for x, y in zip(a.branches, b.branches, strict=True):
        assert len(x) == len(y) and x.stop_reason == y.stop_reason
        for p, q in zip(x.points, y.points, strict=True):
            assert p.parameter == q.parameter
            np.testing.assert_array_equal(p.y0, q.y0)
            np.testing.assert_array_equal(p.coordinate_amplitudes, q.coordinate_amplitudes)


def test_detached_branch_is_found_and_closed():
    # a closed loop of period-1 orbits inside [0.6447, 0.7199], reached by no other branch
    res = exact_branches(builtin_system("nsd2"), (0.62, 0.75), workers=1, progress=False)
    loops = [br for br in res.branches if br.closed]
    assert loops
    br = loops[0]
    assert 0.62 < br.parameters.min() and br.parameters.max() < 0.75
    first, last = br.points[0], br.points[-1]
    scale = max(1.0, first.amplitude)
    assert abs(first.parameter - last.parameter) < 0.02 * (0.75 - 0.62)
    assert abs(first.amplitude - last.amplitude) < 0.05 * scale
    for q in (br.points[len(br) // 4], br.points[(3 * len(br)) // 4]):
        y, amps, mult = reference_orbit(q.parameter, q.y0)
        np.testing.assert_allclose(q.y0, y, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(q.coordinate_amplitudes, amps[:2], rtol=1e-9, atol=1e-9)
        assert_multipliers(q.multipliers, mult, 1e-7)


def test_undamped_and_unforced_systems_are_explained():
    res = exact_branches(
        builtin_system("nsd2", mu1=0.0, mu2=0.0), (1.0, 1.2), workers=1, progress=False
    )
    assert res.branches == () and "undamped" in res.notes[0]
    # the mount is a step response: no forcing frequency to continue in
    with pytest.raises(ModelError, match="no parameter 'Omega'"):
        exact_branches(builtin_system("mount"), (1.0, 1.2), workers=1, progress=False)
