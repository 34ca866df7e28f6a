"""Pseudo-arclength continuation of periodic orbits and exact frequency responses.

Independent oracles: closed-form steady states of linear (segments of) oscillators, an
independent ``solve_ivp`` integration of every orbit, single-harmonic balance, direct
simulation (period-2 orbits, stable attractors), the shooting module's own Floquet
multipliers, and finite differences for the analytic parameter derivative.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb.errors import ParameterError
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator
from perturb.seeds import periodic_orbit_guesses
from perturb.simulate.exact_response import (
    ContinuationBranch,
    ExactBranches,
    SpecialPoint,
    continue_orbits,
    exact_branches,
    exact_frequency_response,
    exact_solutions_at,
    switch_branch,
)
from perturb.simulate.flows.factory import FlowFamily

NSD_K3 = {"k": -3.0, "mu": 0.05, "F": 2.0}


# ------------------------------------------------------------------------------------------
# helpers (independent of the code under test)
# ------------------------------------------------------------------------------------------
def nsd_force(x: np.ndarray | float, k: float) -> np.ndarray:
    """f(x) = kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)] (paper eq. 6)."""
    x = np.asarray(x, float)
    return k * x + (1 - k) * (np.maximum(x - 1, 0.0) + np.minimum(x + 1, 0.0))


def integrate(rhs, y0, t1, rtol=1e-12, atol=1e-12, t0=0.0):
    sol = solve_ivp(rhs, (t0, t1), np.asarray(y0, float), method="DOP853", rtol=rtol, atol=atol)
    assert sol.status == 0
    return sol.y[:, -1]


def nsd_rhs(k, mu, F, Om):
    def rhs(t, y):
        return [y[1], F * math.cos(Om * t) - mu * y[1] - float(nsd_force(y[0], k))]

    return rhs


def linear_amplitude(Om, s, mu, F):
    """Steady state of x'' + mu x' + s x = F cos(Om t): |F / (s - Om^2 + i mu Om)|."""
    return F / np.hypot(s - Om**2, mu * Om)


# ------------------------------------------------------------------------------------------
# linear oscillator (nsd with k = 1)
# ------------------------------------------------------------------------------------------
def test_linear_oscillator_is_one_exact_stable_branch():
    osc = builtin_model("nsd", k=1.0, mu=0.05, F=2.0)
    res = exact_branches(osc, (0.2, 2.0), progress=False)
    assert len(res.branches) == 1
    br = res.branches[0]
    W = br.parameters
    assert W[0] == pytest.approx(0.2) and W[-1] == pytest.approx(2.0)
    exact = linear_amplitude(W, 1.0, 0.05, 2.0)
    assert np.max(np.abs(br.amplitudes - exact) / exact) < 1e-9
    assert all(q.stable for q in br.points)
    # spacing: 0.5 % of the window in Omega and 0.5 % in amplitude (1.5 x before a redo)
    assert np.max(np.abs(np.diff(W))) <= 0.005 * 1.8 * 1.0001
    assert np.max(np.abs(np.diff(np.log(br.amplitudes)))) < 0.0075
    resp = res.to_response()
    assert resp.method == "exact" and len(resp.branches) == 1
    assert resp.to_csv().splitlines()[0] == (
        "branch,omega,amplitude,first_harmonic_amplitude,mean,stable,max_multiplier,method"
    )


def test_linear_oscillator_by_shooting_matches_closed_form():
    """The numerical path (no closed form): states to 1e-9, statistics to STATS_TOL."""
    osc = builtin_model("nsd", k=1.0, mu=0.05, F=2.0)
    br = continue_orbits(osc, 0.7, [0.0, 0.0], (0.3, 1.6), closed_form=False, ds_max=0.02)
    assert br.closed is False and br.stop_reason == "window edge / window edge"
    assert {q.source for q in br.points} == {"shooting"}
    W = br.parameters
    Z = 2.0 / (1.0 - W**2 + 0.05j * W)  # x = Re(Z e^{i W t})
    y0 = np.column_stack([Z.real, (1j * W * Z).real])
    scale = np.maximum(1.0, np.abs(y0).max(axis=1))
    assert np.max(np.abs(br.states - y0).max(axis=1) / scale) < 1e-9
    exact = np.abs(Z)
    assert np.max(np.abs(br.amplitudes - exact) / exact) < 1e-6
    assert np.max(np.abs([q.first_harmonic_amplitude for q in br.points] - exact) / exact) < 1e-6
    assert all(q.stable for q in br.points)


def test_tangent_matches_the_derivative_of_independent_orbits():
    """The branch tangent (the null vector of [dG/dz | dG/dOmega], with the parameter
    derivative in closed form) gives dy0/dOmega: against central differences of orbits found
    independently (solve_ivp + fsolve on the period map) at Omega +- h."""
    from scipy.optimize import fsolve

    k, mu, F = NSD_K3["k"], NSD_K3["mu"], NSD_K3["F"]
    lo, hi = 0.2, 2.0
    br = continue_orbits(builtin_model("nsd", **NSD_K3), 0.6, [11.4, 1.6], (lo, hi), ds_max=0.05)

    def orbit(Om, y):
        T = 2 * math.pi / Om

        def gap(y0):
            return integrate(nsd_rhs(k, mu, F, Om), y0, T) - y0

        y1 = fsolve(gap, y, xtol=1e-13)
        assert np.max(np.abs(gap(y1))) < 1e-9 * max(1.0, np.max(np.abs(y1)))
        return y1

    checked = 0
    for q in br.points[::7]:
        t = q.tangent
        if abs(t[2]) < 0.2 or q.nodes is not None or checked == 4:
            continue
        # tangent in scaled (x0, v0, Omega): state over the orbit size R, Omega over the window
        R = max(1.0, float(np.max(np.abs(q.y0))), q.amplitude)
        dydp = t[:2] * R / (t[2] * (hi - lo))
        h = 1e-5 * q.parameter
        fd = (orbit(q.parameter + h, q.y0) - orbit(q.parameter - h, q.y0)) / (2 * h)
        assert np.max(np.abs(dydp - fd)) < 1e-4 * np.max(np.abs(fd))
        checked += 1
    assert checked == 4


# ------------------------------------------------------------------------------------------
# smooth systems (ODE flow)
# ------------------------------------------------------------------------------------------
def test_duffing_two_folds_and_every_orbit_closes():
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5)
    br = continue_orbits(osc, 0.5, [0.0, 0.0], (0.5, 2.5), ds_max=0.05)
    assert br.stop_reason == "window edge / window edge"
    folds = br.folds
    assert len(folds) == 2
    # hardening: the upper fold (jump down) is at the larger frequency
    assert 1.3 < folds[1].parameter < 1.6 and 2.0 < folds[0].parameter < 2.4
    stable = np.array([q.stable for q in br.points])
    flips = np.flatnonzero(stable[1:] != stable[:-1])
    assert len(flips) == 2
    for f, s in zip(flips, folds, strict=True):
        assert abs(f - s.index) <= 1  # stability changes at the folds ...
        a, b = br.points[f], br.points[f + 1]
        unstable = a if not a.stable else b
        mu = unstable.multipliers[0]  # ... through a real multiplier above +1
        assert abs(mu.imag) == 0.0 and 1.0 < mu.real < 1.5
        det = [float(np.prod(1 - q.multipliers).real) for q in (a, b)]
        assert det[0] * det[1] < 0  # det(M - I) changes sign

    def rhs_at(Om):
        return lambda t, y: [y[1], 0.5 * math.cos(Om * t) - 0.1 * y[1] - y[0] - y[0] ** 3]

    for q in br.points:  # independent integration over one period
        T = 2 * math.pi / q.parameter
        yT = integrate(rhs_at(q.parameter), q.y0, T)
        assert np.max(np.abs(yT - q.y0)) < 1e-7 * max(1.0, np.max(np.abs(q.y0)))


def test_closed_loop_in_a_non_frequency_parameter():
    """x'' + mu x' + x^2 + p^2 - 1 = F cos(Omega t): the orbits about the equilibria
    x = +-sqrt(1 - p^2) form a closed loop in p with folds at p = +-1."""
    osc = Oscillator.parse(
        "x'' + mu*x' + x**2 + p**2 - 1 = F*cos(Omega*t)",
        {"mu": 0.1, "F": 0.05, "Omega": 3.0, "p": 0.0},
        name="circle",
    )
    br = continue_orbits(osc, 0.0, [1.0, 0.0], (-1.5, 1.5), parameter="p", ds_max=0.02)
    assert br.closed and br.stop_reason == "closed loop"
    assert len(br.folds) == 2
    assert sorted(abs(f.parameter) for f in br.folds) == pytest.approx([1.0, 1.0], abs=0.01)
    means = np.array([q.mean for q in br.points])
    stable = np.array([q.stable for q in br.points])
    # the upper half (x ~ +sqrt(1 - p^2), a centre) is stable, the lower (saddle) is not
    assert np.all(stable[means > 0.3]) and not np.any(stable[means < -0.3])
    P = br.parameters
    assert np.max(np.abs(means**2 + P**2 - 1)[np.abs(P) < 0.9]) < 0.01


# ------------------------------------------------------------------------------------------
# the Zou-Nagarajaiah negative-stiffness device, k = -3 (paper Fig. 17d)
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def nsd_k3() -> ExactBranches:
    return exact_branches(builtin_model("nsd", **NSD_K3), (0.2, 2.0), progress=False)


def test_k3_detached_branch(nsd_k3):
    """The upper branch of cross-well orbits is detached from the main branch: it reaches the
    resonance peak (~42.8 at the fold Omega ~ 0.943), both its ends lie on the low-frequency
    edge of the window (the loop closes below 0.2: below 0.05 in fact), and no branch that
    reaches Omega = 2 connects to it."""
    brs = nsd_k3.branches
    top = max(range(len(brs)), key=lambda i: brs[i].amplitudes.max())
    iso = brs[top]
    assert 42.0 < iso.amplitudes.max() < 44.0
    assert len(iso.folds) == 1 and iso.folds[0].parameter == pytest.approx(0.9431, abs=2e-3)
    assert iso.parameters[0] == pytest.approx(0.2) and iso.parameters[-1] == pytest.approx(0.2)
    assert np.max(np.abs([q.mean / q.amplitude for q in iso.points])) < 1e-6  # symmetric
    main = [b for b in brs if b.parameters.max() > 1.99]
    assert main and all("joined" not in b.stop_reason for b in brs)

    def descr(b):  # (Omega, amplitude, mean) per point
        return np.array([(q.parameter, q.amplitude, q.mean) for q in b.points])

    a = descr(iso)
    for b in main:  # no orbit of the detached branch lies on a main branch
        d = np.abs(a[:, None, :] - descr(b)[None, :, :])
        d[..., 0] /= 1.8
        d[..., 1:] /= a[:, None, 1:2]
        # (the lower part passes within 0.5 % of the asymmetric branch in (Omega, amplitude)
        # near Omega ~ 0.4, but its orbits are symmetric: the means differ by ~0.7)
        assert np.min(d.max(axis=2)[a[:, 0] > 0.25]) > 1e-2


def test_k3_inner_branch_is_the_closed_form_saddle_orbit(nsd_k3):
    """Inside |x| < 1 the force is kx: x = Re(F e^{i W t} / (k - W^2 + i mu W)), unstable
    with the multiplier exp(lambda T), lambda = -mu/2 + sqrt(mu^2/4 - k)."""
    k, mu, F = NSD_K3["k"], NSD_K3["mu"], NSD_K3["F"]
    inner = [b for b in nsd_k3.branches if b.amplitudes.max() < 1.0]
    assert len(inner) == 1
    br = inner[0]
    W = br.parameters
    assert W[0] == pytest.approx(0.2) and W[-1] == pytest.approx(2.0)
    amp = linear_amplitude(W, k, mu, F)
    assert np.max(np.abs(br.amplitudes - amp) / amp) < 1e-12
    lam = -mu / 2 + math.sqrt(mu * mu / 4 - k)
    mult = np.exp(lam * 2 * math.pi / W)
    assert np.max(np.abs(np.array([q.max_multiplier for q in br.points]) - mult) / mult) < 1e-9
    assert not any(q.stable for q in br.points)
    assert {q.source for q in br.points} == {"closed form"}


def test_k3_stability_labels_and_orbits(nsd_k3):
    """Labels agree with the multipliers, and with the shooting module's Floquet analysis of
    the polished orbit; every sampled orbit closes under an independent integration."""
    k, mu, F = NSD_K3["k"], NSD_K3["mu"], NSD_K3["F"]
    rng = np.random.default_rng(3)
    for br in nsd_k3.branches:
        for q in br.points:
            assert q.stable == (q.max_multiplier < 1.0)
        for i in rng.choice(len(br), size=min(4, len(br)), replace=False):
            q = br.points[int(i)]
            orb = br.orbit(int(i))
            assert orb.is_stable == q.stable or abs(q.max_multiplier - 1) < 1e-3
            assert orb.amplitude == pytest.approx(q.amplitude, rel=1e-6)
            if q.max_multiplier < 1e3:
                T = 2 * math.pi / q.parameter
                yT = integrate(nsd_rhs(k, mu, F, q.parameter), q.y0, T, rtol=1e-12, atol=1e-12)
                tol = 1e-6 * max(1.0, q.max_multiplier) * max(1.0, np.max(np.abs(q.y0)))
                assert np.max(np.abs(yT - q.y0)) < tol


def test_k3_symmetry_and_strongly_unstable_orbits(nsd_k3):
    """Mirror branches are the images under (x, t) -> (-x, t + T/2); multiple shooting holds
    orbits whose multipliers exceed 1e10."""
    res = nsd_k3
    assert any(m is not None for m in res.mirror_of)
    for b, m in zip(res.branches, res.mirror_of, strict=True):
        if m is None:
            continue
        a = res.branches[m]
        assert np.allclose(b.amplitudes, a.amplitudes, rtol=1e-12)
        assert np.allclose([q.mean for q in b.points], [-q.mean for q in a.points], atol=1e-9)
        j = len(b) // 2
        assert b.orbit(j).amplitude == pytest.approx(b.points[j].amplitude, rel=1e-6)
    big = [
        (br, i)
        for br in res.branches
        for i, q in enumerate(br.points)
        if q.max_multiplier > 1e10 and q.source != "closed form"
    ]
    assert big
    br, i = big[len(big) // 2]
    q = br.points[i]
    assert q.nodes is not None and len(q.nodes) >= 4
    orb = br.orbit(i)
    assert orb.method == "multiple shooting"
    assert orb.max_multiplier == pytest.approx(q.max_multiplier, rel=1e-4)


def test_k3_response_and_special_points(nsd_k3):
    resp = nsd_k3.to_response()
    assert resp.method == "exact" and len(resp.branches) == len(nsd_k3.branches)
    assert any("mirror image" in n for n in resp.notes)
    kinds = {s.kind for b in nsd_k3.branches for s in b.special_points}
    assert {"fold", "branch_point", "period_doubling", "grazing"} <= kinds
    # the symmetry-breaking pitchfork of the cross-well orbits that stalled the old code
    bps = [s.parameter for b in nsd_k3.branches for s in b.branch_points]
    assert any(abs(p - 0.4835) < 2e-3 for p in bps)
    # the grazing of the one-well orbit: |Z| = 3 with Z = F / (1 - W^2 + i mu W)
    from scipy.optimize import brentq

    wg = brentq(lambda w: linear_amplitude(w, 1.0, 0.05, 2.0) - 3.0, 0.3, 0.9)
    graz = [s.parameter for b in nsd_k3.branches for s in b.grazings]
    assert min(abs(g - wg) for g in graz) < 1e-9


def test_pitchfork_is_passed_not_stalled():
    """From the cross-well orbit at 0.6 down through the branch point at ~0.4835 (the stall
    of the first version): the symmetric branch continues, the point is reported."""
    osc = builtin_model("nsd", **NSD_K3)
    br = continue_orbits(osc, 0.6, [11.43532506, 1.58868563], (0.45, 0.7))
    assert br.stop_reason == "window edge / window edge"
    assert br.parameters.min() == pytest.approx(0.45) and br.parameters.max() == pytest.approx(0.7)
    assert len(br.branch_points) == 1 and br.branch_points[0].parameter == pytest.approx(
        0.4835, abs=1e-3
    )
    assert np.max(np.abs([q.mean / q.amplitude for q in br.points])) < 1e-6  # symmetric
    # the other branch at the pitchfork: asymmetric orbits of both signs, through the
    # branch point, where it turns back (a fold of the parabola p ~ p* - c mean^2)
    child = switch_branch(br, br.special_points.index(br.branch_points[0]))
    means = np.array([q.mean for q in child.points])
    assert means.min() < -0.1 and means.max() > 0.1
    assert len(child.folds) == 1
    assert child.folds[0].parameter == pytest.approx(br.branch_points[0].parameter, abs=1e-3)
    assert child.parameters.max() <= br.branch_points[0].parameter + 1e-3


@pytest.mark.slow
def test_k3_branch_count_independent_of_seeds(nsd_k3):
    from perturb.methods.harmonic_balance import single_harmonic_balance
    from perturb.seeds import approximation_seeds

    osc = builtin_model("nsd", **NSD_K3)
    seeds = approximation_seeds(single_harmonic_balance(osc), (0.2, 2.0), 16)
    with_hb = exact_branches(osc, (0.2, 2.0), seeds=seeds, progress=False)
    assert len(with_hb.branches) == len(nsd_k3.branches)
    key = sorted((round(b.amplitudes.max(), 1), len(b.folds)) for b in with_hb.branches)
    assert key == sorted((round(b.amplitudes.max(), 1), len(b.folds)) for b in nsd_k3.branches)


# ------------------------------------------------------------------------------------------
# k = -0.5 against single-harmonic balance
# ------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_km05_every_hb_point_has_an_exact_branch_nearby():
    """Single-harmonic balance is within ~2.5 % of the exact response (worst near
    Omega ~ 0.31, where the exact orbit has a strong third harmonic; median 0.13 %): every HB
    point lies within 4 % (in first-harmonic amplitude and in window-scaled frequency) of an
    exact point, so no branch HB knows of is missed."""
    from perturb.methods.harmonic_balance import single_harmonic_balance
    from perturb.numeric.amplitude import approximation_response

    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    res = exact_branches(osc, (0.2, 2.0), progress=False)
    hb = approximation_response(single_harmonic_balance(osc), (0.2, 2.0), stability="slow_flow")
    P = np.concatenate([b.parameters for b in res.branches])
    A = np.concatenate([[q.first_harmonic_amplitude for q in b.points] for b in res.branches])
    worst = 0.0
    for b in hb.branches:
        for w, a in zip(b.omega, b.first_harmonic_amplitude, strict=True):
            worst = max(worst, float(np.min(np.hypot((P - w) / 1.8, (A - a) / a))))
    assert worst < 0.04
    assert any(b.closed for b in res.branches)  # a detached loop near 0.25 .. 0.49


# ------------------------------------------------------------------------------------------
# period doubling (nsd k = -4, mu = 0.25, F = 6.5)
# ------------------------------------------------------------------------------------------
PD = {"k": -4.0, "mu": 0.25, "F": 6.5}


def _check_period2(q, m=2):
    k, mu, F = PD["k"], PD["mu"], PD["F"]
    T = 2 * math.pi / q.parameter
    rhs = nsd_rhs(k, mu, F, q.parameter)
    yT = integrate(rhs, q.y0, T)
    y2T = integrate(rhs, yT, 2 * T, t0=T)
    scale = max(1.0, np.max(np.abs(q.y0)))
    assert np.max(np.abs(y2T - q.y0)) < 1e-6 * max(1.0, q.max_multiplier) * scale
    assert np.max(np.abs(yT - q.y0)) > 1e-3 * scale  # not a period-1 orbit


def test_period_doubling_switch_to_period_two():
    osc = builtin_model("nsd", **PD)
    res = exact_branches(osc, (1.0, 1.4), period_doubling=True, progress=False)
    twos = [b for b in res.branches if b.m == 2]
    assert twos
    # the sweeps meet the stable period-2 motion at Omega ~ 1.2 too: a detached loop
    assert any(b.closed and 1.3 < b.parameters.max() < 1.4 for b in twos)
    twos = [b for b in twos if not b.closed]
    parents = [b for b in res.branches if b.m == 1 and b.period_doublings]
    assert parents
    p2 = twos[0]
    assert "collapsed onto the period-1 orbit" in p2.stop_reason
    pd_at = [s.parameter for s in parents[0].period_doublings]
    assert min(abs(p2.parameters.min() - p) for p in pd_at) < 2e-3
    for i in np.linspace(1, len(p2) - 1, 6).astype(int):
        _check_period2(p2.points[int(i)])
    # the same branch through the public switch_branch
    parent = parents[0]
    child = switch_branch(parent, parent.special_points.index(parent.period_doublings[0]))
    assert child.m == 2 and len(child) > 10
    q = child.points[len(child) // 2]
    _check_period2(q)


def test_period_two_isola_closed_and_stable_orbits_attract():
    """The stable period-2 motion at Omega = 1.2 lies on a detached closed loop of period-2
    orbits; its stable orbits attract a direct simulation."""
    osc = builtin_model("nsd", **PD)
    flow = FlowFamily(osc).at(1.2)
    y = flow(np.zeros(2), 0.0, 300 * flow.period).y
    br = continue_orbits(osc, 1.2, y, (0.8, 2.0), m=2, ds_max=0.01)
    assert br.closed and len(br.folds) == 2
    assert 1.0 < br.parameters.min() < 1.1 and 1.3 < br.parameters.max() < 1.4
    stable = [q for q in br.points if q.stable and q.max_multiplier < 0.8]
    assert stable
    k, mu, F = PD["k"], PD["mu"], PD["F"]
    for q in stable[:: max(1, len(stable) // 3)]:
        _check_period2(q)
        T = 2 * math.pi / q.parameter
        # 60 orbit periods from a perturbed state: the perturbation decays like 0.8^60
        y = integrate(nsd_rhs(k, mu, F, q.parameter), q.y0 * (1 + 1e-3), 120 * T, rtol=1e-10)
        assert np.max(np.abs(y - q.y0)) < 1e-5 * max(1.0, np.max(np.abs(q.y0)))


# ------------------------------------------------------------------------------------------
# API
# ------------------------------------------------------------------------------------------
def test_validation_and_frozen_results():
    osc = builtin_model("nsd", **NSD_K3)
    with pytest.raises(ParameterError):
        continue_orbits(osc, 3.0, [0.0, 0.0], (0.2, 2.0))
    with pytest.raises(ParameterError):
        continue_orbits(osc, 0.5, [0.0, 0.0], (2.0, 0.2))
    with pytest.raises(ParameterError):
        continue_orbits(osc, 0.5, [0.0, 0.0], (0.2, 2.0), m=0)
    with pytest.raises(ParameterError):
        continue_orbits(osc, 0.5, [0.0, 0.0], (0.2, 2.0), ds_max=-1.0)
    with pytest.raises(ParameterError):
        exact_branches(osc, (0.0, 2.0))
    br = continue_orbits(osc, 1.6, [-5.0, 0.0], (1.5, 2.0))
    assert isinstance(br, ContinuationBranch)
    assert br.points[0].parameter == pytest.approx(1.5) and br.points[-1].parameter == 2.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        br.closed = True  # type: ignore[misc]
    with pytest.raises(ValueError):
        br.points[0].y0[0] = 1.0
    assert "ContinuationBranch(period 1" in repr(br)
    assert "ContinuationPoint(p=" in repr(br.points[0])
    with pytest.raises(ParameterError):  # not a special point of this branch
        switch_branch(br, SpecialPoint("period_doubling", 0, 1.6, 1.0, (0.0, 0.0)))
    resp = exact_frequency_response(
        builtin_model("nsd", k=1.0, mu=0.05, F=2.0), (0.5, 1.5), progress=False, sweep_points=0
    )
    assert resp.method == "exact" and len(resp.branches) == 1


def test_exact_solutions_at_given_frequencies_only():
    """Every row is at a requested frequency; the in-well saddle orbit is the closed-form
    linear response of the middle segment; the stable cross-well orbit is what a long DOP853
    run from a nearby state settles on."""
    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0)
    ws = [0.5, 0.55, 0.6, 0.65, 0.7]
    # the approximations' orbits as extra starting guesses, as the front door passes them
    # (the reference solver itself no longer derives approximations)
    resp = exact_solutions_at(osc, ws, orbit_guesses=lambda w: periodic_orbit_guesses(osc, w))
    rows = resp.rows()
    assert {r["omega"] for r in rows} == set(ws)
    per_w = {w: sorted((r["amplitude"], r["stable"]) for r in rows if r["omega"] == w) for w in ws}
    for w, sols in per_w.items():
        # the in-well saddle (smallest), unstable orbits (at least the cross-well saddle; the
        # seeds of periodic_orbits also reach strongly unstable asymmetric ones, e.g. at
        # 0.5), and one stable orbit: the large cross-well one
        assert len(sols) >= 3 and [s for _, s in sols[:-1]] == [False] * (len(sols) - 1)
        assert sols[-1][1], (w, sols)
        assert sols[0][0] == pytest.approx(linear_amplitude(w, -2.0, 0.05, 2.0), rel=1e-9)
    rhs = nsd_rhs(-2.0, 0.05, 2.0, 0.6)
    T = 2 * math.pi / 0.6
    y = integrate(rhs, [9.4, 1.0], 300 * T, rtol=1e-11, atol=1e-11)
    sol = solve_ivp(
        rhs, (300 * T, 301 * T), y, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True
    )
    x = sol.sol(np.linspace(300 * T, 301 * T, 20001))[0]
    assert per_w[0.6][-1][0] == pytest.approx(np.max(np.abs(x)), rel=1e-7)
    with pytest.raises(ParameterError, match="positive finite"):
        exact_solutions_at(osc, [0.6, -1.0])
