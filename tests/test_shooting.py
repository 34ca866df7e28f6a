"""Periodic orbits: exact PWL flow sensitivity, shooting, multiple shooting, collocation.

Oracles (never the code under test):

* central finite differences of the exact flow (for the sensitivity / saltation);
* closed-form steady states and exponents of linear oscillators (derived below);
* the exact energy-integral period of the free undamped nsd oscillator, rebuilt below in closed
  form (arccosh/arcsinh + arcsin pieces) and cross-checked against 30-digit mpmath tanh-sinh
  quadrature of the energy integral;
* long solve_ivp runs (DOP853, rtol = atol = 1e-13) with event location for van der Pol, and
  the Liouville/trace identity det M = exp(oint div f dt) by periodic trapezoidal quadrature;
* single shooting (itself checked above) for multiple shooting and collocation, and the
  observed convergence order of collocation under grid halving.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections import Counter

import mpmath as mp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.exact import ExactPWLFlow, common_period
from perturb.simulate.flows.piecewise_exact import PWLSystem, propagate
from perturb.simulate.orbits.collocation import collocation_orbit, difference_weights
from perturb.simulate.orbits.shooting import (
    PeriodicOrbit,
    ShootingError,
    classify_multipliers,
    limit_cycle,
    multiple_shooting,
    periodic_orbit,
)

TWO_PI = 2.0 * math.pi
K, MU, F, W = -2.0, 0.05, 2.0, 0.6  # Zou-Nagarajaiah Fig. 5 (reconstructed, docs/references.md §1)


def nsd_system(k=K, mu=MU, F=F, W=W) -> PWLSystem:
    """|x| <= 1: f = kx; x > 1: f = x + (k - 1); x < -1: f = x + (1 - k) (derived by hand)."""
    return PWLSystem(
        [-1.0, 1.0],
        [1.0, k, 1.0],
        [1.0 - k, 0.0, k - 1.0],
        damping=mu,
        forcing=((F, W, 0.0),) if F else (),
    )


@pytest.fixture(scope="module")
def nsd_flow() -> ExactPWLFlow:
    return ExactPWLFlow(builtin_model("nsd", k=K, mu=MU, F=F, Omega=W))


def fd_jacobian(flow, y, t0, t1, h=1e-6):
    cols = []
    for e in np.eye(2):
        cols.append((flow(y + h * e, t0, t1).y - flow(y - h * e, t0, t1).y) / (2 * h))
    return np.column_stack(cols)


# ---------------------------------------------------------------------------------------------
# ExactPWLFlow
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("y0", [(2.0, 0.3), (0.5, 0.0), (-3.0, 1.0), (9.4, 1.0)])
def test_exact_sensitivity_matches_finite_differences_nsd(nsd_flow, y0):
    y = np.array(y0)
    T = nsd_flow.period
    res = nsd_flow(y, 0.0, T, sensitivity=True)
    assert res.n_events >= 1 or abs(y0[0]) < 1
    np.testing.assert_allclose(res.sensitivity, fd_jacobian(nsd_flow, y, 0.0, T), atol=1e-7)
    # the oscillator and the hand-built system give the same flow
    same = ExactPWLFlow(nsd_system())(y, 0.0, T, sensitivity=True)
    np.testing.assert_allclose(same.sensitivity, res.sensitivity, rtol=1e-13, atol=1e-13)


def relay() -> PWLSystem:
    # f = x - 0.3 (x < 0), x + 0.3 (x >= 0): a restoring relay jump of 0.6 at x = 0
    return PWLSystem([0.0], [1.0, 1.0], [-0.3, 0.3], damping=0.1, forcing=((1.0, 0.8, 0.0),))


@pytest.mark.parametrize("y0", [(1.5, 0.0), (-1.0, 2.0), (0.7, -1.2)])
def test_saltation_matrix_needed_for_a_force_jump(y0):
    sys_ = relay()
    flow = ExactPWLFlow(sys_)
    y = np.array(y0)
    T = flow.period
    res = flow(y, 0.0, T, sensitivity=True)
    fd = fd_jacobian(flow, y, 0.0, T)
    assert res.n_events >= 2
    np.testing.assert_allclose(res.sensitivity, fd, atol=1e-7)
    # the same product without saltation (independent expm per piece) is wrong
    traj = propagate(sys_, y, (0.0, T))
    ends = [p.t0 for p in traj.pieces[1:]] + [T]
    M = np.eye(2)
    for p, t1 in zip(traj.pieces, ends, strict=True):
        A = np.array([[0.0, 1.0], [-sys_.slopes[p.segment], -sys_.damping]])
        M = expm(A * (t1 - p.t0)) @ M
    assert np.max(np.abs(M - fd)) > 1e-2


def test_exact_flow_protocol_and_t_eval(nsd_flow):
    T = nsd_flow.period
    t = np.linspace(0.0, T, 7)
    res = nsd_flow([0.5, 0.1], 0.0, T, t_eval=t)
    assert res.ys.shape == (7, 2) and res.sensitivity is None
    np.testing.assert_array_equal(res.ys[-1], res.y)
    np.testing.assert_allclose(nsd_flow.vector_field(0.0, [2.0, 1.0]), [1.0, 2.0 - 0.05 + 1.0])
    assert common_period([0.6, 1.2, 1.8]) == pytest.approx(TWO_PI / 0.6, rel=1e-14)
    assert common_period([1.0, math.sqrt(2.0)]) is None
    assert common_period([]) is None


def test_exact_flow_matches_ode_flow_for_smooth_system():
    osc = Oscillator.parse(
        "x'' + mu*x' + x = F*cos(Omega*t)", {"mu": 0.1, "F": 0.5, "Omega": 1.3}, name="linear"
    )
    ex, ode = ExactPWLFlow(osc), ODEFlow(osc, rtol=1e-13, atol=1e-14)
    a = ex([0.3, -0.2], 0.0, 7.0, sensitivity=True)
    b = ode([0.3, -0.2], 0.0, 7.0, sensitivity=True)
    np.testing.assert_allclose(a.y, b.y, atol=1e-11)
    np.testing.assert_allclose(a.sensitivity, b.sensitivity, atol=1e-11)


# ---------------------------------------------------------------------------------------------
# single shooting against closed forms
# ---------------------------------------------------------------------------------------------
def linear_steady_state(s, mu, F, W):
    """x'' + mu x' + s x = F cos Wt: x = Re(F e^{iWt} / (s - W^2 + i mu W)); state at t = 0."""
    z = F / complex(s - W * W, mu * W)
    return np.array([z.real, (1j * W * z).real]), abs(z)


def linear_multipliers(s, mu, T):
    """exp(lambda T), lambda = -mu/2 +- sqrt(mu^2/4 - s)."""
    r = np.sqrt(complex(mu * mu / 4 - s))
    return np.exp(np.array([-mu / 2 + r, -mu / 2 - r]) * T)


def sort_c(z):
    z = np.asarray(z, complex)
    return z[np.lexsort((z.imag, z.real))]


@pytest.mark.parametrize("mu, Wf", [(0.1, 0.8), (0.05, 1.3), (1.0, 0.4)])
def test_linear_oscillator_orbit_is_the_closed_form(mu, Wf):
    Ff = 1.7
    flow = ExactPWLFlow(PWLSystem([], [1.0], [0.0], damping=mu, forcing=((Ff, Wf, 0.0),)))
    y_exact, amp = linear_steady_state(1.0, mu, Ff, Wf)
    assert amp == pytest.approx(Ff / math.sqrt((1 - Wf**2) ** 2 + (mu * Wf) ** 2), rel=1e-15)
    orb = periodic_orbit(flow, [0.0, 0.0])
    np.testing.assert_allclose(orb.y0, y_exact, rtol=0, atol=1e-12)
    assert orb.amplitude == pytest.approx(amp, abs=1e-12)
    assert orb.first_harmonic_amplitude == pytest.approx(amp, abs=1e-12)
    assert abs(orb.mean) < 1e-12
    T = TWO_PI / Wf
    np.testing.assert_allclose(
        sort_c(orb.multipliers), sort_c(linear_multipliers(1.0, mu, T)), rtol=0, atol=1e-12
    )
    assert orb.stability == "stable"
    assert orb.max_multiplier == pytest.approx(math.exp(-mu * T / 2), rel=1e-12)


def test_linear_oscillator_with_ode_flow():
    osc = Oscillator.parse(
        "x'' + mu*x' + x = F*cos(Omega*t)", {"mu": 0.1, "F": 1.7, "Omega": 0.8}, name="linear"
    )
    orb = periodic_orbit(ODEFlow(osc, rtol=1e-12, atol=1e-13), [0.0, 0.0], tol=1e-10)
    y_exact, amp = linear_steady_state(1.0, 0.1, 1.7, 0.8)
    np.testing.assert_allclose(orb.y0, y_exact, atol=1e-9)
    assert orb.amplitude == pytest.approx(amp, abs=1e-9)
    np.testing.assert_allclose(
        sort_c(orb.multipliers), sort_c(linear_multipliers(1.0, 0.1, TWO_PI / 0.8)), atol=1e-9
    )


def test_static_load_shifts_the_mean():
    flow = ExactPWLFlow(
        PWLSystem([], [2.0], [0.0], damping=0.2, forcing=((1.0, 0.9, 0.3),), static_force=0.5)
    )
    orb = periodic_orbit(flow, [1.0, 0.0])
    assert orb.mean == pytest.approx(0.25, abs=1e-12)
    _, amp = linear_steady_state(2.0, 0.2, 1.0, 0.9)
    assert orb.first_harmonic_amplitude == pytest.approx(amp, abs=1e-12)
    assert orb.amplitude == pytest.approx(0.25 + amp, abs=1e-12)


def test_nsd_small_orbit_is_the_linear_saddle_orbit(nsd_flow):
    # |x| < 1: x'' + mu x' + k x = F cos Wt, a linear oscillator with negative stiffness
    y_exact, amp = linear_steady_state(K, MU, F, W)
    assert amp < 1.0
    # The orbit is a saddle with multiplier ~2e6: a perturbation d leaves |x| < 1 within the
    # period unless |d| e^{lambda T} << 1, so single shooting only converges from |d| <~ 1e-7
    # (inside that ball the flow is linear and Newton is exact in one step).  From coarse
    # guesses multiple shooting is the method (test_nsd_multiple_shooting_exact_flow).
    orb = periodic_orbit(nsd_flow, y_exact + np.array([3e-8, -5e-8]))
    np.testing.assert_allclose(orb.y0, y_exact, atol=1e-12)
    assert orb.amplitude == pytest.approx(amp, abs=1e-12)
    assert orb.stability == "unstable"
    expected = sort_c(linear_multipliers(K, MU, nsd_flow.period))
    got = sort_c(orb.multipliers)
    # the large multiplier ~ 2e6: compare relatively
    np.testing.assert_allclose(got, expected, rtol=1e-9)
    assert orb.max_multiplier > 1e6


def test_period_m_of_a_period_one_orbit(nsd_flow):
    o1 = periodic_orbit(nsd_flow, [9.4, 1.0])
    o2 = periodic_orbit(nsd_flow, o1.y0 + 0.01, m=2)
    np.testing.assert_allclose(o2.y0, o1.y0, atol=1e-11)
    assert o2.period == pytest.approx(2 * o1.period, rel=1e-15)
    np.testing.assert_allclose(sort_c(o2.multipliers), sort_c(o1.multipliers**2), atol=1e-10)
    assert o2.first_harmonic_amplitude == pytest.approx(o1.first_harmonic_amplitude, abs=1e-10)
    assert o2.amplitude == pytest.approx(o1.amplitude, abs=1e-12)


# ---------------------------------------------------------------------------------------------
# exact period of the free undamped nsd oscillator (docs/references.md §1, rebuilt here)
# ---------------------------------------------------------------------------------------------
#   G(x) = k x^2/2 (|x| <= 1),  k x^2/2 + (1-k)(|x|-1)^2/2 outside.  For x > 1, with b = 1 - k,
#   G = (x - b)^2/2 - b(b-1)/2: a unit-frequency harmonic well centred at b.  An orbit with
#   turning point A (= max x) has E = G(A) = R^2/2 - b(b-1)/2, R = A - b, and
#   T = 2 int dx / sqrt(2 (E - G)) over one sweep:
#   * b <= A <= x_c = 1 - 2k: stays in x >= 1 (left turning point 2b - A >= 1): T = 2 pi;
#   * x_c < A < x_d (k/2 < E < 0): one well, crossing x = 1, inner turning point
#     x_in = sqrt(2E/k) in (0, 1):
#     int_{x_in}^1 dx/sqrt(|k|(x^2 - x_in^2)) = arccosh(1/x_in)/sqrt|k|,
#     int_1^A dx/sqrt(R^2 - (x-b)^2) = pi/2 + arcsin((b-1)/R);  T = 2 (both);
#   * A > x_d (E > 0): over all three segments, symmetric:
#     int_0^1 dx/sqrt(2E + |k| x^2) = arcsinh(sqrt(|k|/(2E)))/sqrt|k|;  T = 4 (inner + outer).
#   T -> 2 pi as A -> infinity; T -> infinity at the separatrix A = x_d.
def energy_period(A: float, k: float = K) -> float:
    b = 1.0 - k
    xc, xd = 1.0 - 2.0 * k, 1.0 - k + math.sqrt(k * (k - 1.0))
    assert A >= b
    if A <= xc:
        return TWO_PI
    R = A - b
    E = 0.5 * R * R - 0.5 * b * (b - 1.0)
    outer = 0.5 * math.pi + math.asin((b - 1.0) / R)
    if A < xd:
        x_in = math.sqrt(2.0 * E / k)
        return 2.0 * (math.acosh(1.0 / x_in) / math.sqrt(-k) + outer)
    return 4.0 * (math.asinh(math.sqrt(-k / (2.0 * E))) / math.sqrt(-k) + outer)


def energy_period_quadrature(A: float, k: float = K) -> float:
    """Same period by 30-digit tanh-sinh quadrature (endpoint singularities handled)."""
    with mp.workdps(30):
        A_, k_ = mp.mpf(A), mp.mpf(k)
        b = 1 - k_

        def G(x):
            x = abs(x)
            return k_ * x * x / 2 if x <= 1 else k_ * x * x / 2 + (1 - k_) * (x - 1) ** 2 / 2

        E = G(A_)

        def f(x):
            return 1 / mp.sqrt(abs(2 * (E - G(x))))

        if A_ <= 1 - 2 * k_:
            return float(2 * mp.quad(f, [2 * b - A_, b, A_]))
        if E < 0:
            return float(2 * mp.quad(f, [mp.sqrt(2 * E / k_), 1, A_]))
        return float(4 * mp.quad(f, [0, 1, A_]))


# x_c = 5, x_d = 3 + sqrt(6) = 5.449...: two amplitudes in each regime
AMPLITUDES = [4.0, 4.9, 5.05, 5.3, 5.7, 8.0, 25.0]


@pytest.mark.parametrize("A", AMPLITUDES)
def test_free_nsd_period_matches_energy_integral(A):
    T_exact = energy_period(A)
    assert T_exact == pytest.approx(energy_period_quadrature(A), rel=1e-13)
    flow = ExactPWLFlow(nsd_system(mu=0.0, F=0.0))
    assert flow.period is None and flow.autonomous
    orb = limit_cycle(flow, [A, 0.0], T_exact * 1.03, phase="anchor", tol=1e-14)
    assert abs(orb.period - T_exact) < 1e-10
    assert orb.amplitude == pytest.approx(A, abs=1e-12)
    # conservative: both multipliers 1 (a family of orbits)
    np.testing.assert_allclose(orb.multipliers, [1.0, 1.0], atol=1e-5)


def test_free_nsd_period_limits():
    assert energy_period(5.0 + 1e-9) == pytest.approx(TWO_PI, abs=1e-3)
    assert energy_period(1e6) == pytest.approx(TWO_PI, rel=1e-5)
    assert energy_period(3.0 + math.sqrt(6.0) + 1e-9) > 30.0


# ---------------------------------------------------------------------------------------------
# van der Pol against long integrations
# ---------------------------------------------------------------------------------------------
def vdp_reference(eps: float, n_periods: int):
    """Period (between the last two upward zero crossings) and max x, from a long DOP853 run."""

    def f(t, y):
        return [y[1], eps * (1 - y[0] ** 2) * y[1] - y[0]]

    def up(t, y):
        return y[0]

    def top(t, y):
        return y[1]

    up.direction, top.direction = 1, -1
    sol = solve_ivp(
        f, (0, n_periods * 6.7), [2.0, 0.0], method="DOP853", rtol=1e-13, atol=1e-13,
        events=[up, top],
    )  # fmt: skip
    tu = sol.t_events[0]
    return tu[-1] - tu[-2], sol.y_events[1][-1, 0]


@functools.cache
def vdp_orbit(eps: float):
    flow = ODEFlow(builtin_model("vanderpol", eps=eps), rtol=1e-13, atol=1e-13)
    orb = limit_cycle(flow, [1.8, 0.4], TWO_PI * 1.05)
    return flow, orb


@pytest.mark.parametrize("eps", [0.1, 1.0])
def test_vanderpol_limit_cycle_matches_long_run(eps):
    _, orb = vdp_orbit(eps)
    T_ref, A_ref = vdp_reference(eps, 50 if eps < 0.5 else 15)
    assert abs(orb.period - T_ref) < 1e-9
    assert abs(orb.amplitude - A_ref) < 1e-9
    assert orb.y0[1] == 0.0 or abs(orb.y0[1]) < 1e-12  # phase condition
    assert orb.stability == "stable" and orb.autonomous


@pytest.mark.parametrize("eps", [0.1, 1.0])
def test_vanderpol_multipliers_trivial_and_trace_identity(eps):
    _, orb = vdp_orbit(eps)
    mu = orb.multipliers
    k = int(np.argmin(np.abs(mu - 1)))
    assert abs(mu[k] - 1) < 1e-10
    other = mu[1 - k]
    # det M = exp(oint div f dt), div f = eps (1 - x^2); periodic trapezoid is spectral
    _, x, _ = orb.sample(1024)
    det = math.exp(eps * np.sum(1 - x**2) * orb.period / x.size)
    assert abs(other.imag) == 0 and other.real == pytest.approx(det, rel=1e-9)
    assert 0 < other.real < 1
    assert orb.max_multiplier == pytest.approx(other.real, rel=1e-14)


def test_vanderpol_multiple_shooting_and_collocation():
    flow, orb = vdp_orbit(1.0)
    _, x, v = orb.sample(6)
    guesses = np.column_stack([x, v]) * 1.02
    ms = multiple_shooting(flow, guesses, period_guess=orb.period * 0.98)
    assert abs(ms.period - orb.period) < 1e-10
    np.testing.assert_allclose(ms.y0, orb.y0, atol=1e-10)
    np.testing.assert_allclose(sort_c(ms.multipliers), sort_c(orb.multipliers), atol=1e-9)
    # collocation, order 4: error ratio under grid halving ~ 2^4
    errs = []
    for n in (64, 128, 256):
        co = collocation_orbit(flow, orb, n_points=n, order=4)
        errs.append(abs(co.period - orb.period))
    r1, r2 = errs[0] / errs[1], errs[1] / errs[2]
    assert 12 < r1 < 20 and 12 < r2 < 20, errs
    assert errs[-1] < 5e-6
    # a 6th-order grid gets much closer
    co6 = collocation_orbit(flow, orb, n_points=256, order=6)
    assert abs(co6.period - orb.period) < 1e-8
    assert abs(co6.amplitude - orb.amplitude) < 1e-8
    assert (
        co6.stability == "stable" and abs(co6.nontrivial_multipliers[0] - ms.multipliers[1]) < 1e-6
    )


# ---------------------------------------------------------------------------------------------
# forced Duffing: three methods agree
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def duffing():
    osc = builtin_model("duffing", mu=0.1, omega0=1.0, alpha=1.0, F=0.5, Omega=1.2)
    flow = ODEFlow(osc, rtol=1e-13, atol=1e-13)
    orb = periodic_orbit(flow, [1.0, 0.0], tol=1e-11)
    return flow, orb


def test_duffing_multiple_shooting_matches_single(duffing):
    flow, orb = duffing
    _, x, v = orb.sample(5)
    ms = multiple_shooting(flow, np.column_stack([x, v]) + 0.05, tol=1e-11)
    np.testing.assert_allclose(ms.nodes[0], orb.y0, atol=1e-10)
    np.testing.assert_allclose(ms.nodes, np.column_stack([x, v]), atol=1e-10)
    np.testing.assert_allclose(sort_c(ms.multipliers), sort_c(orb.multipliers), atol=1e-9)
    assert ms.amplitude == pytest.approx(orb.amplitude, abs=1e-10)
    assert ms.method == "multiple shooting" and orb.stability == ms.stability == "stable"


@pytest.mark.parametrize("order", [2, 4])
def test_duffing_collocation_converges_at_its_order(duffing, order):
    flow, orb = duffing
    errs = []
    for n in (64, 128, 256):
        co = collocation_orbit(flow, [1.0, 0.0], n_points=n, order=order)
        errs.append(np.max(np.abs(co.y0 - orb.y0)))
    p_obs = [math.log2(errs[0] / errs[1]), math.log2(errs[1] / errs[2])]
    assert all(abs(p - order) < 0.3 for p in p_obs), (errs, p_obs)
    assert co.amplitude == pytest.approx(orb.amplitude, abs=50 * errs[-1])
    np.testing.assert_allclose(sort_c(co.multipliers), sort_c(orb.multipliers), atol=1e-3)


def test_difference_weights():
    assert difference_weights(2, 1) == (-0.5, 0.0, 0.5)
    assert difference_weights(2, 2) == (1.0, -2.0, 1.0)
    np.testing.assert_allclose(difference_weights(6, 2), [1 / 90, -3 / 20, 1.5, -49 / 18, 1.5,
                                                          -3 / 20, 1 / 90])  # fmt: skip


# ---------------------------------------------------------------------------------------------
# nsd: multiple shooting on the strongly unstable orbit, and the Fig. 5 attractor set
# ---------------------------------------------------------------------------------------------
def test_nsd_multiple_shooting_exact_flow(nsd_flow):
    y_exact, amp = linear_steady_state(K, MU, F, W)
    small = periodic_orbit(nsd_flow, y_exact)
    big = periodic_orbit(nsd_flow, [9.4, 1.0])
    # coarse guesses (0.05 off): hopeless for single shooting on the saddle orbit (see
    # test_nsd_small_orbit_is_the_linear_saddle_orbit), fine with 16 nodes (growth e^{lambda T/16})
    for orb in (small, big):
        _, x, v = orb.sample(16)
        ms = multiple_shooting(nsd_flow, np.column_stack([x, v]) + np.array([0.05, -0.05]))
        np.testing.assert_allclose(ms.y0, orb.y0, atol=1e-11)
        np.testing.assert_allclose(
            sort_c(ms.multipliers), sort_c(orb.multipliers), rtol=1e-8, atol=1e-10
        )
        assert ms.amplitude == pytest.approx(orb.amplitude, abs=1e-12)
        assert ms.stability == orb.stability
    # one node is single shooting through the sparse cyclic system
    one = multiple_shooting(nsd_flow, [[9.4, 1.0]])
    np.testing.assert_allclose(one.y0, big.y0, atol=1e-11)


def test_nsd_fig5_attractor_set(nsd_flow):
    """A grid of initial conditions over both wells (|x| <= 4, |v| <= 3), 50 periods of exact
    propagation, then shooting (m = 1, else 2, 3, 4) from the end state.

    Result: every one of the 63 initial conditions converges to one and the same stable
    period-1 orbit (the large orbit over all three segments, amplitude ~ 9.52); no other
    stable orbit and no subharmonic.  This matches the paper's claim for Fig. 5 that every
    initial condition converges to one and the same limit cycle.
    """
    T = nsd_flow.period
    found: list[PeriodicOrbit] = []
    periods = Counter()
    for x0 in np.linspace(-4.0, 4.0, 9):
        for v0 in np.linspace(-3.0, 3.0, 7):
            end = nsd_flow([x0, v0], 0.0, 50 * T).y
            for m in (1, 2, 3, 4):
                try:
                    orb = periodic_orbit(nsd_flow, end, m=m)
                    break
                except ShootingError:
                    continue
            else:
                pytest.fail(f"no periodic orbit from {(x0, v0)}")
            periods[m] += 1
            if not any(np.max(np.abs(o.y0 - orb.y0)) < 1e-8 for o in found):
                found.append(orb)
    stable = [o for o in found if o.stability == "stable"]
    assert periods == Counter({1: 63})
    assert len(found) == 1 and len(stable) == 1
    orb = stable[0]
    assert orb.m == 1 and 9.4 < orb.amplitude < 9.6 and orb.max_multiplier < 0.8
    assert abs(orb.mean) < 1e-10  # symmetric orbit


# ---------------------------------------------------------------------------------------------
# the orbit object, classification
# ---------------------------------------------------------------------------------------------
def test_orbit_is_frozen_printable_and_serialisable(nsd_flow):
    orb = periodic_orbit(nsd_flow, [9.4, 1.0])
    text = str(orb)
    assert "single shooting" in text and "stable" in text and "multipliers" in text
    assert "PeriodicOrbit(" in repr(orb)
    with pytest.raises(dataclasses.FrozenInstanceError):
        orb.period = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        orb.y0[0] = 1.0
    d = json.loads(json.dumps(orb.to_dict()))
    assert d["stability"] == "stable" and d["m"] == 1
    t, x, v = orb.sample(16)
    assert t.shape == x.shape == v.shape == (16,)
    assert x[0] == pytest.approx(orb.y0[0], abs=1e-14)


@pytest.mark.parametrize(
    "mu, auto, label",
    [
        ([0.5, 0.2], False, "stable"),
        ([1.5, 0.2], False, "unstable"),
        ([1.0 + 1e-8, 0.3], False, "fold"),
        ([-1.0 + 1e-9, 0.3], False, "period-doubling"),
        ([np.exp(0.7j), np.exp(-0.7j)], False, "neimark-sacker"),
        ([(1 + 1e-8) * np.exp(0.7j), (1 + 1e-8) * np.exp(-0.7j)], False, "neimark-sacker"),
        # lightly damped forced orbit: |mu| = exp(-mu T/2) = 1 - 3e-7, within unit_tol, stable
        ([(1 - 3e-7) * np.exp(0.7j), (1 - 3e-7) * np.exp(-0.7j)], False, "stable"),
        ([1.0, 0.4], True, "stable"),
        ([1.0, 3.0], True, "unstable"),
        ([1.0, -1.0], True, "period-doubling"),
    ],
)
def test_classify_multipliers(mu, auto, label):
    assert classify_multipliers(mu, autonomous=auto)[0] == label


# ---------------------------------------------------------------------------------------------
# bad input and failures
# ---------------------------------------------------------------------------------------------
def test_bad_inputs(nsd_flow):
    with pytest.raises(ParameterError, match="y_guess"):
        periodic_orbit(nsd_flow, [math.nan, 0.0])
    with pytest.raises(ParameterError, match="y_guess"):
        periodic_orbit(nsd_flow, [1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match="m = 0"):
        periodic_orbit(nsd_flow, [1.0, 0.0], m=0)
    with pytest.raises(ParameterError, match="tol"):
        periodic_orbit(nsd_flow, [1.0, 0.0], tol=-1.0)
    with pytest.raises(ParameterError, match="expected a Flow"):
        periodic_orbit("not a flow", [1.0, 0.0])  # type: ignore[arg-type]
    free = ExactPWLFlow(nsd_system(mu=0.1, F=0.0))
    with pytest.raises(ParameterError, match="limit_cycle"):
        periodic_orbit(free, [1.0, 0.0])
    with pytest.raises(ParameterError, match="periodic_orbit"):
        limit_cycle(nsd_flow, [1.0, 0.0], 6.0)
    with pytest.raises(ParameterError, match="period_guess"):
        limit_cycle(free, [1.0, 0.0], -1.0)
    with pytest.raises(ParameterError, match="phase"):
        limit_cycle(free, [1.0, 0.0], 6.0, phase="integral")
    with pytest.raises(ParameterError, match="period_guess"):
        multiple_shooting(free, np.ones((3, 2)))
    with pytest.raises(ParameterError, match="autonomous"):
        multiple_shooting(free, np.ones((3, 2)), period=6.0, period_guess=6.0)
    with pytest.raises(ParameterError, match="limit_cycle"):
        periodic_orbit(free, [1.0, 0.0], period=6.0)
    with pytest.raises(ParameterError, match=r"\(N, 2\)"):
        multiple_shooting(nsd_flow, np.ones((3, 3)))
    with pytest.raises(ParameterError, match="ODEFlow"):
        collocation_orbit(nsd_flow, [1.0, 0.0])
    with pytest.raises(ModelError, match="not piecewise linear"):
        ExactPWLFlow(builtin_model("duffing"))
    with pytest.raises(ParameterError, match="Omega"):
        ExactPWLFlow(nsd_system(), Omega=0.5)
    with pytest.raises(ParameterError, match="t1 > t0"):
        nsd_flow([1.0, 0.0], 1.0, 1.0)


def test_non_convergence_reports_the_residual():
    flow = ODEFlow(builtin_model("duffing", mu=0.1, F=0.5, Omega=1.2), rtol=1e-10, atol=1e-12)
    with pytest.raises(ShootingError, match="residual") as info:
        periodic_orbit(flow, [0.1, 0.0], max_iter=2)
    assert info.value.residual > 1e-3 and np.all(np.isfinite(info.value.z))
    assert isinstance(info.value, PerturbError)


def test_relaxation_cycle_from_the_harmonic_guess():
    """van der Pol eps = 5 from the harmonic guess (2, 0), 2 pi: Newton alone ran away (|x|
    doubling per iteration with a shrinking period, each step stiffer); the run-away guard
    stops it and the settled-transient restart converges. Oracle: a long DOP853 run with
    events."""
    flow = ODEFlow(builtin_model("vanderpol", eps=5.0), rtol=1e-12, atol=1e-12)
    orb = limit_cycle(flow, [2.0, 0.0], TWO_PI)
    T_ref, A_ref = vdp_reference(5.0, 25)
    assert abs(orb.period - T_ref) < 1e-8 * T_ref
    assert abs(orb.amplitude - A_ref) < 1e-8 * A_ref
    assert orb.stability == "stable"


def test_limit_cycle_refuses_an_equilibrium():
    flow = ODEFlow(builtin_model("vanderpol", eps=0.5))
    with pytest.raises(ShootingError, match="equilibrium"):
        limit_cycle(flow, [0.0, 0.0], 6.0)


@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    x=st.floats(-6.0, 6.0, allow_nan=False),
    v=st.floats(-4.0, 4.0, allow_nan=False),
)
def test_shooting_never_returns_nan(nsd_flow, x, v):
    try:
        orb = periodic_orbit(nsd_flow, [x, v], max_iter=12)
    except PerturbError as exc:
        assert "residual" in str(exc)
        return
    values = [*orb.y0, orb.amplitude, orb.mean, orb.max_multiplier, orb.residual]
    scale = max(1.0, float(np.max(np.abs(orb.y0))))
    assert np.all(np.isfinite(values)) and orb.residual <= 1e-6 * scale
    # the flow closes the orbit: re-propagate independently of the solver's bookkeeping
    end = propagate(nsd_flow.system, orb.y0, (0.0, orb.period))
    assert abs(end.x[-1] - orb.y0[0]) + abs(end.v[-1] - orb.y0[1]) <= 1e-6 * scale


def test_two_by_two_newton_direction_matches_lapack():
    # single shooting solves 2x2 systems by Cramer's rule with the exact condition number;
    # oracle: LAPACK (np.linalg.solve), and lstsq for an exactly singular matrix
    from perturb.numeric.roots import newton_direction

    rng = np.random.default_rng(7)
    for _ in range(200):
        J = rng.normal(size=(2, 2)) * 10.0 ** rng.uniform(-3, 3)
        r = rng.normal(size=2)
        cond = np.linalg.cond(J)
        # both are backward stable: they differ by ~cond * eps
        np.testing.assert_allclose(
            newton_direction(J, r), np.linalg.solve(J, r), rtol=1e-13 * cond, atol=0
        )
    S = np.array([[1.0, 2.0], [2.0, 4.0]])
    r = np.array([1.0, 0.5])
    np.testing.assert_allclose(
        newton_direction(S, r), np.linalg.lstsq(S, r, rcond=None)[0], rtol=1e-12
    )
