"""The fast reference for piecewise-smooth oscillators that are not piecewise linear (issue 15,
'Accuracy and speed'): ``x'' + 0.05x' + x + 0.3x^3 + 2(x-1)H(x-1) + 2(x+1)H(-x-1) = 1.5 cos Wt``.

The event-driven flow (:class:`perturb.simulate.flows.event_driven.EventFlow`) integrates the
smooth field between the switches by Chebyshev collocation steps
(:mod:`perturb.simulate.flows.spectral`).  Checked against references that share no code
with it:

* a closed form (the undamped linear oscillator) for one collocation step and its
  sensitivity;
* the period map integrated by DOP853 (rtol = atol = 1e-12) on the equation written out here,
  with terminal events at ``x = +-1`` and restarts in the region the velocity carries the
  orbit into (the force is continuous, so no saltation), its Jacobian by central differences;
* periodic orbits by Newton's method on that map, started from this file's own single-harmonic
  balance of the equation (every root of the amplitude equation; the describing function of
  the two springs in closed form): the reference's set of orbits, each with ``max|x|`` from
  the zeros of ``x'`` on the dense output and its Floquet multipliers.

Every orbit of ``frequency_response(..., "exact", frequencies=...)`` (the issue's ``perturb frc
... --method exact --omega 0.8,1.5,2.5,3.5``) must be one of the reference's, the reference's
set must be found whole, and amplitudes agree to 1e-8 (relative), stability labels exactly,
the largest multiplier to 1e-5 (the reference's finite differences).  Two frequencies in the
default suite, all four marked slow.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.event_driven import EventFlow
from perturb.simulate.flows.spectral import ChebyshevStep
from perturb.solve import frequency_response, periodic_orbits

EQUATION = (
    "x'' + 0.05*x' + x + 0.3*x**3 + 2*(x-1)*Heaviside(x-1) + 2*(x+1)*Heaviside(-x-1)"
    " = 1.5*cos(Omega*t)"
)
MU, CUBIC, KS, F = 0.05, 0.3, 2.0, 1.5
RTOL = ATOL = 1e-12


# ------------------------------------------------------------------------------------------
# the reference: DOP853 with events at x = +-1, written out here
# ------------------------------------------------------------------------------------------
def _acc(t, x, v, region, W):
    spring = KS * (x - 1.0) if region > 0 else (KS * (x + 1.0) if region < 0 else 0.0)
    return F * math.cos(W * t) - MU * v - x - CUBIC * x**3 - spring


def _region(x, v):
    if x > 1.0 or (x == 1.0 and v > 0):
        return 1
    if x < -1.0 or (x == -1.0 and v < 0):
        return -1
    return 0


def reference_map(y0, W, T, *, extrema=False):
    """``y(T)`` from ``y(0) = y0`` (and, with ``extrema``, every value of x where x' = 0)."""
    t, y = 0.0, np.array(y0, dtype=float)
    region = _region(*y)
    peaks: list[float] = [abs(y[0])]
    for _ in range(10_000):

        def rhs(tt, z, region=region):
            return [z[1], _acc(tt, z[0], z[1], region, W)]

        def hit_up(tt, z):
            return z[0] - 1.0

        def hit_down(tt, z):
            return z[0] + 1.0

        def turn(tt, z):
            return z[1]

        # only exits from the current region count (a restart lies on its surface)
        hit_up.terminal = hit_down.terminal = True
        hit_up.direction = 1.0 if region == 0 else -1.0
        hit_down.direction = -1.0 if region == 0 else 1.0
        events = [hit_up, hit_down, turn]
        sol = solve_ivp(rhs, (t, T), y, method="DOP853", rtol=RTOL, atol=ATOL, events=events)
        assert sol.status >= 0
        peaks += [abs(z[0]) for z in sol.y_events[2]]
        if sol.status == 0:
            y = sol.y[:, -1]
            break
        k = 0 if len(sol.t_events[0]) else 1
        t = float(sol.t_events[k][0])
        y = np.array(sol.y_events[k][0], dtype=float)
        y[0] = 1.0 if k == 0 else -1.0  # on the surface
        region = (1 if y[1] > 0 else 0) if k == 0 else (-1 if y[1] < 0 else 0)
    else:
        raise AssertionError("too many switches")
    peaks.append(abs(y[0]))
    return (y, max(peaks)) if extrema else y


def reference_jacobian(y0, W, T, h=1e-6):
    cols = []
    for e in np.eye(2):
        cols.append((reference_map(y0 + h * e, W, T) - reference_map(y0 - h * e, W, T)) / (2 * h))
    return np.column_stack(cols)


def reference_orbit(y0, W):
    """Newton on y -> P(y) - y from ``y0``: (y*, max|x|, max |multiplier|) or None."""
    T = 2.0 * math.pi / W
    y = np.array(y0, dtype=float)
    for _ in range(30):
        r = reference_map(y, W, T) - y
        if np.max(np.abs(r)) < 1e-11 * max(1.0, np.max(np.abs(y))):
            y_end, amp = reference_map(y, W, T, extrema=True)
            mult = np.linalg.eigvals(reference_jacobian(y, W, T))
            return y, amp, float(np.max(np.abs(mult)))
        J = reference_jacobian(y, W, T) - np.eye(2)
        step = np.linalg.solve(J, -r)
        scale = max(1.0, float(np.max(np.abs(y))))
        if np.max(np.abs(step)) > scale:  # a damped step far from the orbit
            step *= scale / np.max(np.abs(step))
        y = y + step
        if not np.all(np.isfinite(y)) or np.max(np.abs(y)) > 100:
            return None
    return None


def harmonic_balance_seeds(W):
    """Initial states of this equation's single-harmonic balance x = A cos(W t - phi): every
    root A of ((k(A) - W^2)^2 + (mu W)^2) A^2 = F^2 with the equivalent stiffness
    k(A) = 1 + 3/4 c A^2 + ks (1 - 2/pi (asin(1/A) + sqrt(1 - 1/A^2)/A)) (the springs act
    beyond |x| = 1)."""

    def k_eq(A):
        k = 1.0 + 0.75 * CUBIC * A * A
        if A > 1.0:
            k += KS * (1.0 - 2.0 / math.pi * (math.asin(1.0 / A) + math.sqrt(1 - 1 / A**2) / A))
        return k

    def g(A):
        return ((k_eq(A) - W * W) ** 2 + (MU * W) ** 2) * A * A - F * F

    grid = np.linspace(1e-3, 12.0, 4001)
    vals = [g(a) for a in grid]
    seeds = []
    for a, b, ga, gb in zip(grid[:-1], grid[1:], vals[:-1], vals[1:], strict=True):
        if ga * gb < 0:
            A = brentq(g, a, b, xtol=1e-14)
            phi = math.atan2(MU * W, k_eq(A) - W * W)
            seeds.append(np.array([A * math.cos(phi), A * W * math.sin(phi)]))
    return seeds


def reference_orbits(W):
    """The reference's set of period-1 orbits at W: (y0, amplitude, max multiplier) sorted."""
    found = []
    for seed in harmonic_balance_seeds(W):
        orbit = reference_orbit(seed, W)
        if orbit is None:
            continue
        if all(np.max(np.abs(orbit[0] - o[0])) > 1e-6 for o in found):
            found.append(orbit)
    return sorted(found, key=lambda o: o[1])


# ------------------------------------------------------------------------------------------
# one collocation step against a closed form
# ------------------------------------------------------------------------------------------
def test_collocation_step_matches_the_closed_form_and_its_sensitivity():
    """x'' = -x from (x0, v0): x = x0 cos t + v0 sin t; the sensitivity is the rotation."""

    def field(t, x, v):
        return -x, -1.0, 0.0

    step = ChebyshevStep(field, rtol=1e-12, atol=1e-14)
    x0, v0, H = 0.7, -0.3, 1.2
    chunk, ratio = step.attempt(0.5, x0, v0, H, True)
    assert chunk is not None and ratio <= 1.0
    t = chunk.t - 0.5
    assert np.max(np.abs(chunk.x - (x0 * np.cos(t) + v0 * np.sin(t)))) < 1e-13
    assert np.max(np.abs(chunk.v - (-x0 * np.sin(t) + v0 * np.cos(t)))) < 1e-13
    x, v, S = chunk.state(0.5 + 0.37 * H)
    c, s = math.cos(0.37 * H), math.sin(0.37 * H)
    assert abs(x - (x0 * c + v0 * s)) < 1e-13
    assert np.max(np.abs(S - np.array([[c, s], [-s, c]]))) < 1e-13
    # too long a step for degree 24 is refused by its error estimate
    chunk, ratio = step.attempt(0.0, x0, v0, 60.0, False)
    assert chunk is None and ratio > 1.0


# ------------------------------------------------------------------------------------------
# the flow against the reference map
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("W", [0.8, 3.5])
def test_period_map_and_monodromy_match_the_reference(W):
    osc = Oscillator.parse(EQUATION).with_params({"Omega": W})
    flow = EventFlow(osc)
    T = flow.period
    assert T == pytest.approx(2 * math.pi / W, rel=1e-15)
    rng = np.random.default_rng(3)
    switches = 0
    for y0 in [*rng.uniform(-4, 4, (3, 2)), np.array([0.05, 0.0])]:
        res = flow(y0, 0.0, T, sensitivity=True)
        ref = reference_map(y0, W, T)
        assert np.max(np.abs(res.y - ref)) < 1e-9 * max(1.0, np.max(np.abs(ref)))
        jac = reference_jacobian(y0, W, T)
        assert np.max(np.abs(res.sensitivity - jac)) < 1e-5 * max(1.0, np.max(np.abs(jac)))
        switches += res.n_events
        # the DOP853 path of earlier versions agrees too
        old = EventFlow(osc, integrator="dop853")(y0, 0.0, T, sensitivity=True)
        assert np.max(np.abs(old.y - res.y)) < 1e-9 * max(1.0, np.max(np.abs(ref)))
        assert old.n_events == res.n_events
    assert switches > 0  # the springs were reached


def test_samples_repeat_the_run_exactly():
    """A t_eval call after a call from the same state returns what a new run would."""
    osc = Oscillator.parse(EQUATION).with_params({"Omega": 1.5})
    flow = EventFlow(osc)
    T = flow.period
    y0 = np.array([2.0, 0.5])
    te = np.linspace(0.0, T, 41)
    fresh = EventFlow(osc)(y0, 0.0, T, t_eval=te)
    flow(y0, 0.0, T, sensitivity=True)
    again = flow(y0, 0.0, T, t_eval=te)
    assert np.array_equal(fresh.y, again.y)
    assert np.max(np.abs(fresh.ys - again.ys)) < 1e-14 * np.max(np.abs(fresh.ys))
    ref = np.array([reference_map(y0, 1.5, t) for t in te[8::8]])
    assert np.max(np.abs(again.ys[8::8] - ref)) < 1e-9 * np.max(np.abs(ref))


# ------------------------------------------------------------------------------------------
# every orbit at the issue's frequencies
# ------------------------------------------------------------------------------------------
def _check_frequency_response(frequencies):
    osc = Oscillator.parse(EQUATION)
    resp = frequency_response(osc, "exact", frequencies=frequencies)
    rows: dict[float, list[tuple[float, bool, float]]] = {w: [] for w in frequencies}
    for br in resp.branches:
        for w, amp, stable, mm in zip(
            br.omega, br.amplitude, br.stable, br.max_multiplier, strict=True
        ):
            rows[float(w)].append((float(amp), bool(stable), float(mm)))
    for W in frequencies:
        ref = reference_orbits(W)
        assert ref, f"the reference found no orbit at {W}"
        got = sorted(rows[W])
        # the same set: every reference orbit found, nothing else
        assert len(got) == len(ref), (W, got, [(o[1], o[2]) for o in ref])
        for (amp, stable, mm), (_, r_amp, r_mult) in zip(got, ref, strict=True):
            assert abs(amp - r_amp) <= 1e-8 * r_amp, (W, amp, r_amp)
            assert stable == (r_mult < 1.0)
            assert abs(mm - r_mult) <= 1e-5, (W, mm, r_mult)


def test_every_orbit_at_two_frequencies_matches_the_reference():
    _check_frequency_response([1.5, 3.5])


@pytest.mark.slow
def test_every_orbit_at_the_four_frequencies_of_the_issue_matches_the_reference():
    _check_frequency_response([0.8, 1.5, 2.5, 3.5])


def test_periodic_orbits_front_door_matches_the_reference_states():
    """``perturb periodic`` at one frequency: the initial states themselves to 1e-8."""
    W = 2.5
    osc = Oscillator.parse(EQUATION)
    orbits = periodic_orbits(osc, W)
    ref = reference_orbits(W)
    assert len(orbits) == len(ref) == 3
    for orbit, (y_ref, amp_ref, mult_ref) in zip(orbits, ref, strict=True):
        assert np.max(np.abs(orbit.y0 - y_ref)) <= 1e-8 * max(1.0, np.max(np.abs(y_ref)))
        assert abs(orbit.amplitude - amp_ref) <= 1e-8 * amp_ref
        assert abs(orbit.max_multiplier - mult_ref) <= 1e-5


def test_bad_arguments_are_named():
    from perturb.errors import ParameterError

    osc = Oscillator.parse(EQUATION).with_params({"Omega": 1.0})
    with pytest.raises(ParameterError, match="integrator = 'rk4'"):
        EventFlow(osc, integrator="rk4")

    def field(t, x, v):
        return -x, -1.0, 0.0

    with pytest.raises(ParameterError, match="n = 2"):
        ChebyshevStep(field, rtol=1e-10, atol=1e-12, n=2)
    with pytest.raises(ParameterError, match="rtol = -1"):
        ChebyshevStep(field, rtol=-1, atol=1e-12)
