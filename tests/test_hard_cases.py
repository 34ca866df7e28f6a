"""Hard cases (issue 7, item 3): where a PWL solver breaks first.

Grazing (A -> 1+, theta -> 0; orbits that just touch a breakpoint), mu -> 0, strong negative
stiffness (k = -10, -50), very large forcing (F = 100), Omega -> 0 and Omega = 10, the detached
branch of the approximate nsd response where it shrinks onto the saddle branch, the
"potentially chaotic" windows of Zou & Nagarajaiah (Figs. 6 and 8), subharmonic orbits
(period 2 and 3) and discontinuous forces (relay, Coulomb friction).  For each: no NaN or inf
in any output, no exception but a :class:`~perturb.errors.PerturbError` naming the issue, and
where a solution exists, agreement with an oracle written here and independent of perturb:

* ``pwl_oracle``: :func:`scipy.integrate.solve_ivp` (DOP853, rtol = atol = 1e-12) on the linear
  field of one segment at a time, terminal events at its breakpoints; an excursion across a
  breakpoint inside one integrator step (grazing: invisible to the events, which only compare
  signs at step ends) is caught at the turning point that lies beyond it;
* ``coulomb_oracle``: the same for ``x'' + mu x' + x + c sign(x') = F cos(W t)``, with the
  stick phases in closed form;
* closed forms (linear segment orbits, free flight, a grazing free orbit evaluated with mpmath
  at 40 digits) and mpmath quadrature of Fourier integrals;
* the first-harmonic balance equation of nsd written out here with the textbook coefficient
  ``a1 = kA + (1 - k) (2A/pi)(theta - sin theta cos theta)`` (mpmath), for the approximations.

Model data (slopes, offsets) are written by hand, not taken from ``to_pwl_system``.
"""

from __future__ import annotations

import cmath
import math
import warnings

import mpmath as mp
import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import perturb
from perturb import FourierError, PerturbError, builtin_model
from perturb.fourier.coefficients import (
    crossing_angle,
    dirac_coefficients,
    dirac_series,
    pwl_coefficients,
    ramp_coefficients,
    ramp_series,
    step_coefficients,
    step_series,
)
from perturb.methods import METHODS
from perturb.model.oscillator import Oscillator
from perturb.numeric.amplitude import approximation_response as traced_response
from perturb.numeric.amplitude import solutions_at
from perturb.simulate.flows.event_driven import EventFlow, simulate
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.flows.lcp import simulate_lcp
from perturb.simulate.flows.piecewise_exact import PWLSystem, propagate
from perturb.simulate.orbits.shooting import periodic_orbit
from perturb.simulate.studies import (
    bifurcation_diagram,
    frequency_sweep,
    lyapunov_exponent,
    poincare_section,
)
from perturb.simulate.time_history import time_history
from perturb.solve import periodic_orbits

TWO_PI = 2.0 * math.pi
QUIET = {"progress": False}


# ---------------------------------------------------------------------------------------------
# oracles
# ---------------------------------------------------------------------------------------------
class OracleFailure(Exception):
    """The oracle cannot integrate this case (sliding or grazing on a force jump)."""


def pwl_oracle(
    bp, slopes, offsets, mu, forcing, c, y0, t_span, t_eval=None, *, strict=False, rtol=1e-12
):
    """State at ``t_eval`` (shape (2, n)), or at ``t_span[1]``, of
    x'' + mu x' + s_i x + o_i = c + sum F cos(w t + p), segment i between bp[i-1] and bp[i].

    One solve_ivp run per segment visit.  Event functions are masked at the restart instant:
    the orbit starts on a zero of the breakpoint it just crossed, which solve_ivp would report
    as an immediate return.  ``strict``: refuse crossings of a force jump that turn straight
    back (sliding / grazing), where a PWL integrator without sliding is not defined."""
    bp = np.asarray(bp, float)
    slopes = np.asarray(slopes, float)
    offsets = np.asarray(offsets, float)

    def load(t):
        return c + sum(F * math.cos(w * t + p) for F, w, p in forcing)

    def accel(i, t, x, v):
        return load(t) - mu * v - slopes[i] * x - offsets[i]

    t0, t1 = map(float, t_span)
    x, v = map(float, y0)
    t = t0
    i = int(np.searchsorted(bp, x, side="left"))
    if i < bp.size and x == bp[i]:  # on a breakpoint: the side the orbit moves to
        s = v if v != 0.0 else accel(i + 1, t, x, v)
        i = i + 1 if s > 0 else i
    te = None if t_eval is None else np.asarray(t_eval, float)
    out = None if te is None else np.full((2, te.size), np.nan)
    for _ in range(20000):
        a0 = accel(i, t, x, v)
        if not forcing and v == 0.0 and a0 == 0.0:  # at rest in an equilibrium
            if te is None:
                return np.array([x, 0.0])
            out[0, te >= t], out[1, te >= t] = x, 0.0
            return out

        def f(tt, y, s=slopes[i], o=offsets[i]):
            return [y[1], load(tt) - mu * y[1] - s * y[0] - o]

        def ev_lo(tt, y, d=bp[i - 1] if i > 0 else -np.inf, t_start=t):
            return 1.0 if tt == t_start else y[0] - d

        def ev_hi(tt, y, d=bp[i] if i < bp.size else np.inf, t_start=t):
            return -1.0 if tt == t_start else y[0] - d

        def ev_turn(tt, y, t_start=t, s0=(v if v != 0.0 else a0)):
            return math.copysign(1.0, s0) if tt == t_start else y[1]

        ev_lo.terminal, ev_lo.direction = True, -1
        ev_hi.terminal, ev_hi.direction = True, 1
        ev_turn.terminal, ev_turn.direction = False, 0
        sol = solve_ivp(
            f,
            (t, t1),
            [x, v],
            method="DOP853",
            rtol=rtol,
            atol=1e-12,
            events=[ev_lo, ev_hi, ev_turn],
            dense_output=True,
        )
        assert sol.success, sol.message
        crossing = None
        if sol.t_events[0].size:
            crossing = (float(sol.t_events[0][0]), i - 1)
        elif sol.t_events[1].size:
            crossing = (float(sol.t_events[1][0]), i)
        t_prev = t
        for t_turn, y_turn in zip(sol.t_events[2], sol.y_events[2], strict=True):
            if crossing is not None and t_turn >= crossing[0]:
                break
            j = None
            if i > 0 and y_turn[0] < bp[i - 1]:
                j = i - 1
            elif i < bp.size and y_turn[0] > bp[i]:
                j = i
            if j is not None:  # x is monotone between two turning points: one crossing there
                d = bp[j]
                tc = brentq(
                    lambda tt, d=d, dense=sol.sol: dense(tt)[0] - d, t_prev, t_turn, xtol=1e-15
                )
                crossing = (tc, j)
                break
            t_prev = float(t_turn)
        t_end = float(sol.t[-1]) if crossing is None else crossing[0]
        if te is not None:
            sel = (te >= t) & (te <= t_end)
            if sel.any():
                out[:, sel] = sol.sol(te[sel])
        if crossing is None:
            return sol.y[:, -1] if te is None else out
        t, j = crossing
        up = j == i
        x, v = float(bp[j]), float(sol.sol(t)[1])
        i = i + 1 if up else i - 1
        if strict:
            a_new = accel(i, t, x, v)
            if a_new * (1 if up else -1) < 0 and v * v < 2e-9 * abs(a_new):
                raise OracleFailure(f"grazing or sliding at a force jump, t = {t}")
    raise OracleFailure("more than 20000 crossings")


def coulomb_oracle(mu, c, F, W, y0, t_eval):
    """x'' + mu x' + x + c sign(x') = F cos(W t) with sticking, at ``t_eval`` (from 0).

    Slip: solve_ivp with the sign frozen, terminal event v = 0.  At v = 0 the mass sticks if
    the net applied force |F cos(W t) - x| is at most c; it stays (x frozen, v = 0) until the
    load leaves [x - c, x + c], located by brentq on a scan of 4000 points per period."""
    te = np.asarray(t_eval, float)
    t1 = float(te[-1])
    out = np.full((2, te.size), np.nan)
    x, v = map(float, y0)
    t = 0.0
    mode = int(np.sign(v))
    for _event in range(100_000):  # an oracle must end: a cap on stick/slip events
        if t >= t1:
            break
        if mode == 0:
            net = F * math.cos(W * t) - x
            if abs(net) > c:
                mode = int(np.sign(net))
                continue
            h, tt, end = TWO_PI / W / 4000, t, None
            while tt < t1 and end is None:
                tn = min(tt + h, t1)
                g = F * math.cos(W * tn) - x
                if abs(g) > c:
                    lim = math.copysign(c, g)
                    end = brentq(lambda s, lim=lim, x=x: F * math.cos(W * s) - x - lim, tt, tn)
                tt = tn
            sel = (te >= t) & (te <= (t1 if end is None else end))
            out[0, sel], out[1, sel] = x, 0.0
            if end is None:
                return out
            t, mode = end, int(np.sign(F * math.cos(W * end) - x))
            continue

        def f(tt, y, s=mode):
            return [y[1], F * math.cos(W * tt) - mu * y[1] - y[0] - c * s]

        def ev(tt, y, t_start=t, s=mode):
            return float(s) if tt == t_start else y[1]

        ev.terminal, ev.direction = True, -mode
        sol = solve_ivp(
            f,
            (t, t1),
            [x, v],
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=[ev],
            dense_output=True,
        )
        sel = (te >= t) & (te <= sol.t[-1])
        if sel.any():
            out[:, sel] = sol.sol(te[sel])
        if sol.status != 1:
            break
        t, x, v = float(sol.t_events[0][0]), float(sol.y_events[0][0][0]), 0.0
        net = F * math.cos(W * t) - x
        mode = 0 if abs(net) <= c else int(np.sign(net))
    return out


def nsd_system(k, mu, F, W):
    """x'' + mu x' + kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)] = F cos Wt, by hand:
    |x| < 1: f = kx; x > 1: f = x + (k - 1); x < -1: f = x + (1 - k)."""
    return PWLSystem(
        [-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0], damping=mu, forcing=((F, W, 0.0),)
    )


def oracle_of(system, y0, t_span, t_eval=None, **kw):
    return pwl_oracle(
        system.breakpoints,
        system.slopes,
        system.offsets,
        system.damping,
        system.forcing,
        system.static_force,
        y0,
        t_span,
        t_eval,
        **kw,
    )


def segment_orbit(s, o, mu, F, W):
    """Steady state of x'' + mu x' + s x + o = F cos Wt: (x0, v0) at t = 0, amplitude of the
    oscillation about the centre -o/s, and the largest Floquet exponent."""
    Z = F / complex(s - W * W, mu * W)
    lam = -0.5 * mu + cmath.sqrt(0.25 * mu * mu - s).real
    return np.array([-o / s + Z.real, (1j * W * Z).real]), abs(Z), lam


def a1_nsd(A, k):
    """First Fourier coefficient of the nsd force under x = A cos psi (textbook form)."""
    A = mp.mpf(A)
    if A <= 1:
        return k * A
    th = mp.acos(1 / A)
    return k * A + (1 - k) * (2 * A / mp.pi) * (th - mp.sin(th) * mp.cos(th))


def hb1_residual(A, W, k, mu, F):
    """First-harmonic balance of nsd, phase eliminated: (a1 - W^2 A)^2 + (mu W A)^2 - F^2."""
    a1 = a1_nsd(A, k)
    return float((a1 - W * W * A) ** 2 + (mu * W * A) ** 2 - F * F)


def assert_finite_response(resp):
    assert isinstance(resp, perturb.Response)
    for b in resp.branches:
        for name in ("omega", "amplitude", "first_harmonic_amplitude", "mean", "max_multiplier"):
            assert np.all(np.isfinite(getattr(b, name))), name
        assert np.all(b.omega > 0) and np.all(b.amplitude >= 0)


def assert_orbit_is_finite(orb):
    for name in ("y0", "monodromy", "multipliers"):
        assert np.all(np.isfinite(getattr(orb, name))), name
    for name in ("amplitude", "first_harmonic_amplitude", "mean", "max_multiplier", "period"):
        assert math.isfinite(getattr(orb, name)), name


# ---------------------------------------------------------------------------------------------
# 1. grazing: A -> 1+, theta -> 0, orbits that just touch a breakpoint
# ---------------------------------------------------------------------------------------------
def quad_coefficient(f, n, A, b, cuts, scale=1):
    """(2/pi) int_0^pi f(A cos psi + b) cos(n psi) dpsi, split at the switching angles.

    mpmath's quadrature stops on an absolute error estimate, so the integrand is divided by
    the size of f (``scale``) first: at f ~ 1e-176 it would otherwise stop at once."""
    pts = sorted({mp.mpf(0), mp.pi, *(c for c in cuts if 0 < c < mp.pi)})
    return 2 * scale / mp.pi * mp.quad(lambda p: f(A * mp.cos(p) + b) * mp.cos(n * p) / scale, pts)


GRAZING_AMPLITUDES = [
    *(1.0 + 10.0**-e for e in (1, 2, 4, 8, 12, 15)),
    float(np.nextafter(1.0, 2.0)),  # theta = 2.1e-8, the smallest crossing there is
    1.0,  # grazing exactly: never on
    float(np.nextafter(1.0, 0.0)),
    1.0 - 1e-8,
]


@pytest.mark.parametrize("A", GRAZING_AMPLITUDES)
def test_fourier_coefficients_at_grazing_match_quadrature(A):
    """x = A cos psi about the breakpoint d = 1 as A -> 1 from both sides (theta -> 0; no
    crossing at all from A = 1 down): step, ramp and the nsd force against 40-digit
    quadrature.  The ramp is O(A theta^3): the textbook formula loses ~2 log10(1/theta)
    digits there, the stable forms must not."""
    k = -2.0
    ns = np.array([0, 1, 2, 3, 7, 50])
    got_step = step_coefficients(ns, A, 0.0, 1.0)
    got_ramp = ramp_coefficients(ns, A, 0.0, 1.0)
    got_nsd = pwl_coefficients(ns, A, 0.0, 1.0, 1.0 - k, [-1.0, 1.0], [k - 1, 1 - k], [0, 0])
    assert np.all(np.isfinite([got_step, got_ramp, got_nsd]))
    with mp.workdps(40):
        Am = mp.mpf(A)
        th = mp.acos(1 / Am) if Am > 1 else mp.mpf(0)
        assert float(crossing_angle(A, 0.0, 1.0)) == pytest.approx(float(th), rel=1e-13)
        for n, s, r, g in zip(ns, got_step, got_ramp, got_nsd, strict=True):
            step = quad_coefficient(lambda x: mp.mpf(x > 1), int(n), Am, 0, [th])
            ramp = quad_coefficient(lambda x: max(x - 1, 0), int(n), Am, 0, [th])
            force = quad_coefficient(
                lambda x: k * x + (1 - k) * (max(x - 1, 0) + min(x + 1, 0)),
                int(n),
                Am,
                0,
                [th, mp.pi - th],
            )
            assert abs(s - float(step)) <= 1e-13 * abs(float(step))
            # relative accuracy even where the ramp coefficient is ~theta^3 ~ 1e-24
            assert abs(r - float(ramp)) <= 1e-12 * abs(float(ramp))
            assert abs(g - float(force)) <= 1e-14 * 3 * A


def test_dirac_coefficient_at_tangency_is_a_clear_fourier_error():
    # the coefficient is 2 cos(n theta)/(pi A sin theta): infinite at |d - b| = A
    with pytest.raises(FourierError, match="tangency"):
        dirac_coefficients([0, 1], 1.0, 0.0, 1.0)
    # just beyond tangency: finite and exact (pi A sin theta = pi sqrt(A^2 - 1))
    A = 1.0 + 1e-12
    got = dirac_coefficients([0, 1, 5], A, 0.0, 1.0)
    th = mp.acos(1 / mp.mpf(A))
    want = [float(2 * mp.cos(n * th) / (mp.pi * mp.sqrt(mp.mpf(A) ** 2 - 1))) for n in (0, 1, 5)]
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_symbolic_and_stable_numeric_coefficients_agree_at_grazing():
    """The textbook theta-forms (evaluated at 30 digits) and the cancellation-free numeric forms
    are two implementations; at grazing only the second is fast, both must agree."""
    rs, ss, ds = ramp_series("A", "b", "d"), step_series("A", "b", "d"), dirac_series("A", "b", "d")
    for e in (4, 12, 15):
        A = 1.0 + 10.0**-e
        for n in (0, 1, 7):
            r = rs.evaluate(n, A=A, b=0.0, d=1.0)
            assert float(ramp_coefficients(n, A, 0.0, 1.0)) == pytest.approx(r, rel=1e-14)
            s = ss.evaluate(n, A=A, b=0.0, d=1.0)
            assert float(step_coefficients(n, A, 0.0, 1.0)) == pytest.approx(s, rel=1e-14)
            d = ds.evaluate(n, A=A, b=0.0, d=1.0)
            assert float(dirac_coefficients(n, A, 0.0, 1.0)) == pytest.approx(d, rel=1e-14)
    with pytest.raises(FourierError):
        ds.evaluate(1, A=1.0, b=0.0, d=1.0)


def grazing_free_orbit(r, A, t):
    """x'' + x + r (x - 1) H(x - 1) = 0 from (0, A), A >= 1, at time t (mpmath, 40 digits):
    x = A sin t below 1; above, x = c + (1 - c) cos w s + (v1/w) sin w s, w^2 = 1 + r,
    c = r/(1 + r), v1 = sqrt(A^2 - 1), for tau = (2/w) atan(v1/(w (1 - c))); periodic."""
    with mp.workdps(40):
        A, r = mp.mpf(A), mp.mpf(r)
        w, c = mp.sqrt(1 + r), r / (1 + r)
        v1 = mp.sqrt(A * A - 1)
        t_in = mp.asin(1 / A)
        tau = 2 / w * mp.atan(v1 / (w * (1 - c)))
        t = mp.mpf(t) % (mp.pi + 2 * t_in + tau)
        if t <= t_in:
            return A * mp.sin(t), A * mp.cos(t)
        t -= t_in
        if t <= tau:
            return (
                c + (1 - c) * mp.cos(w * t) + v1 / w * mp.sin(w * t),
                -(1 - c) * w * mp.sin(w * t) + v1 * mp.cos(w * t),
            )
        s = mp.pi - t_in + t - tau
        return A * mp.sin(s), A * mp.cos(s)


@pytest.mark.parametrize("r", [10.0, -0.5])
@pytest.mark.parametrize("delta", [0.0, 1e-15, 1e-12, 1e-8, 1e-4, 1e-2])
def test_free_orbit_that_just_touches_a_breakpoint(r, delta):
    """Amplitude 1 + delta against a breakpoint at 1 (stiffer, r = 10, or softer, r = -0.5,
    beyond it): ten cycles, exact to rounding.  The penetration delta lasts ~sqrt(delta): a
    plain solve_ivp with events steps over it (an error of 1.7e-4 at delta = 1e-4, r = 10,
    if the oracle lacked its turning-point check)."""
    system = PWLSystem.continuous([1.0], [1.0, 1.0 + r], 0.0)
    A = 1.0 + delta
    t_end = 10 * TWO_PI
    tr = propagate(system, [0.0, A], (0.0, t_end), t_eval=[t_end])
    x, v = grazing_free_orbit(r, A, t_end)
    assert abs(tr.x[0] - float(x)) < 1e-12 and abs(tr.v[0] - float(v)) < 1e-12
    ref = oracle_of(system, [0.0, A], (0.0, t_end))
    assert np.max(np.abs(ref - [float(x), float(v)])) < 1e-9
    if delta >= 1e-12:
        assert len(tr.switches) == 20  # one excursion per cycle, in and out
    elif delta == 0.0:
        assert len(tr.switches) in (0, 20) and all(abs(e.v) < 1e-7 for e in tr.events)


def test_forced_saddle_orbit_touching_both_breakpoints():
    """nsd, k = -2, Omega = 1 with F = |k - W^2 + i mu W|: the closed-form saddle orbit inside
    |x| <= 1 has amplitude exactly 1 and grazes both breakpoints every period.  Shooting keeps
    it (a continuous force grazing changes the orbit by O(delta^(3/2)) only), its multipliers
    are those of the linear saddle, and single-harmonic balance — exact for an orbit in one
    linear segment — has the solution A = 1 there."""
    k, mu, W = -2.0, 0.05, 1.0
    F = abs(complex(k - W * W, mu * W))
    y0, amp, lam = segment_orbit(k, 0.0, mu, F, W)
    assert amp == pytest.approx(1.0, abs=1e-15)
    flow = ExactPWLFlow(nsd_system(k, mu, F, W))
    orb = periodic_orbit(flow, y0)
    assert_orbit_is_finite(orb)
    assert np.max(np.abs(orb.y0 - y0)) < 1e-12
    assert orb.amplitude == pytest.approx(1.0, abs=1e-12)
    T = TWO_PI / W
    lam2 = -mu - lam
    np.testing.assert_allclose(np.abs(orb.multipliers), np.exp([lam * T, lam2 * T]), rtol=1e-10)
    tr = propagate(flow.system, y0, (0.0, T))
    assert all(abs(e.x) == pytest.approx(1.0, abs=1e-12) for e in tr.events)
    osc = builtin_model("nsd", k=k, mu=mu, F=F)
    resp = perturb.frequency_response(osc, "hb1", frequencies=[W])
    assert_finite_response(resp)
    amps = np.concatenate([b.first_harmonic_amplitude for b in resp.branches])
    assert np.min(np.abs(amps - 1.0)) < 1e-9
    for a in amps:
        assert abs(hb1_residual(a, W, k, mu, F)) < 1e-9 * F * F


@pytest.mark.parametrize("s", [0.0, 1e-200, 2.7e-176, 1e-30])
def test_free_flight_segment_without_time_scale(s):
    """A middle segment with slope 0 (or a denormal-ish one), no damping, no forcing: the
    orbit is a parabola with no time scale of its own.  Regression: a rounding tolerance built
    from 1/rate (rate -> 0) swallowed the exit crossing (an O(1) error), and s = 0 divided by
    zero; the exact crossing times follow from the parabola."""
    bp = [0.4, 0.6, 0.8]
    slopes = [0.0, 0.7, s, -1.1]
    offsets = [0.0]
    for i, d in enumerate(bp):
        offsets.append(offsets[-1] + (slopes[i] - slopes[i + 1]) * d)
    system = PWLSystem(bp, slopes, offsets)
    y0 = (0.3, 2.0)
    te = np.linspace(0.0, 4.0, 9)
    tr = propagate(system, y0, (0.0, 4.0), t_eval=te)
    ref = oracle_of(system, y0, (0.0, 4.0), te)
    assert np.all(np.isfinite(tr.x))
    np.testing.assert_allclose(np.vstack([tr.x, tr.v]), ref, rtol=1e-10, atol=1e-10)
    # in segment 2 (0.6 < x < 0.8): x'' = -offsets[2] - s x ~ -offsets[2] (constant)
    ev = [e for e in tr.switches if e.breakpoint == 2]
    enter = next(e for e in tr.switches if e.breakpoint == 1 and e.direction == 1)
    g = -offsets[2]
    dt = (-enter.v + math.sqrt(enter.v**2 + 2 * g * 0.2)) / g if g else 0.2 / enter.v
    assert ev[0].time == pytest.approx(enter.time + dt, rel=1e-12)


def test_relay_without_stiffness_is_not_zeno():
    """x'' + 0.5 sign(x) = 0: piecewise free flight, period 8 from (1, 0).  Regression: with no
    time scale anywhere (t_ref = inf), any 64 switches were taken for Zeno behaviour."""
    for s in (0.0, 1e-30):
        tr = propagate(PWLSystem([0.0], [s, s], [-0.5, 0.5]), (1.0, 0.0), (0.0, 600.0))
        assert len(tr.switches) == 150
        assert tr.x[-1] == pytest.approx(1.0, abs=1e-9) and abs(tr.v[-1]) < 1e-9


# ---------------------------------------------------------------------------------------------
# 2. mu -> 0
# ---------------------------------------------------------------------------------------------
def test_tiny_damping_propagation_matches_oracle():
    system = nsd_system(-2.0, 1e-6, 2.0, 0.6)
    T = TWO_PI / 0.6
    te = np.linspace(0.0, 5 * T, 41)
    tr = propagate(system, [0.0, 0.0], (0.0, 5 * T), t_eval=te)
    ref = oracle_of(system, [0.0, 0.0], (0.0, 5 * T), te)
    scale = 1.0 + np.max(np.abs(ref))
    assert np.max(np.abs(np.vstack([tr.x, tr.v]) - ref)) < 1e-8 * scale


def test_tiny_damping_orbits_and_their_stability():
    """mu = 1e-6, Omega = 10: the saddle orbit (|x| < 1) and the two well orbits are linear
    segment orbits (closed form).  The well orbits are stable with |multipliers| =
    exp(-mu T/2) = 1 - 3e-7: within unit_tol of the unit circle, yet stable (max |mu| < 1),
    as traced branches say.  Regression: exact_solutions_at reported them unstable."""
    k, mu, F, W = -2.0, 1e-6, 2.0, 10.0
    T = TWO_PI / W
    osc = builtin_model("nsd", k=k, mu=mu, F=F)
    resp = perturb.frequency_response(osc, "exact", frequencies=[W])
    assert_finite_response(resp)
    rows = sorted(
        (float(b.amplitude[0]), bool(b.stable[0]), float(b.max_multiplier[0]))
        for b in resp.branches
    )
    _, a_saddle, _ = segment_orbit(k, 0.0, mu, F, W)
    _, a_well, _ = segment_orbit(1.0, k - 1.0, mu, F, W)
    assert len(rows) == 3
    assert rows[0][0] == pytest.approx(a_saddle, rel=1e-10) and not rows[0][1]
    for amp, stable, mult in rows[1:]:
        assert amp == pytest.approx(1.0 - k + a_well, rel=1e-10)
        assert stable and mult == pytest.approx(math.exp(-0.5 * mu * T), abs=1e-12)


def test_tiny_damping_lyapunov_exponents_sum_to_minus_mu():
    mu = 1e-6
    osc = builtin_model("nsd", k=-2.0, mu=mu, F=2.0, Omega=10.0)
    y0, _, _ = segment_orbit(1.0, -3.0, mu, 2.0, 10.0)
    res = lyapunov_exponent(osc, y0, 200, transient=0, **QUIET)
    assert np.all(np.isfinite(res.running))
    assert sum(res.exponents) == pytest.approx(-mu, abs=1e-12)
    # on the well orbit (a complex pair of modulus exp(-mu T/2)) both exponents are -mu/2
    assert res.value == pytest.approx(-0.5 * mu, abs=2e-3)


def test_tiny_damping_first_harmonic_response():
    """The resonance peak of hb1 grows like F/mu: finite, and every point satisfies the
    first-harmonic balance written out independently."""
    k, mu, F = -2.0, 1e-6, 2.0
    resp = perturb.frequency_response(builtin_model("nsd", k=k, mu=mu, F=F), "hb1", (0.5, 1.5))
    assert_finite_response(resp)
    assert max(b.amplitude.max() for b in resp.branches) > 1e3
    for b in resp.branches:
        for j in np.linspace(0, len(b) - 1, 7).astype(int):
            a, w = b.first_harmonic_amplitude[j], b.omega[j]
            assert abs(hb1_residual(a, w, k, mu, F)) < 1e-8 * max(F * F, (a * w * w) ** 2)


# ---------------------------------------------------------------------------------------------
# 3. strong negative stiffness, 4. large forcing
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("k", "F"), [(-10.0, 2.0), (-50.0, 2.0), (-2.0, 100.0), (-50.0, 100.0)])
def test_extreme_parameters_propagation_matches_oracle(k, F):
    system = nsd_system(k, 0.05, F, 0.6)
    T = TWO_PI / 0.6
    te = np.linspace(0.0, 2 * T, 25)
    for y0 in ([0.5, 0.0], [0.0, 3.0]):
        tr = propagate(system, y0, (0.0, 2 * T), t_eval=te)
        ref = oracle_of(system, y0, (0.0, 2 * T), te)
        scale = 1.0 + np.max(np.abs(ref))
        assert np.max(np.abs(np.vstack([tr.x, tr.v]) - ref)) < 1e-9 * scale


def test_strong_negative_stiffness_saddle_orbit_at_low_frequency():
    """k = -50, Omega = 0.1: the saddle orbit's multiplier is exp(lambda T) = 1.9e192.
    Regressions: periodic_orbits seeded this closed-form orbit by single shooting, which
    cannot correct an orbit that amplifies rounding by 1e192 (now: multiple shooting on its
    closed-form nodes), and the eigenvalues squared the trace (overflow beyond 1e154)."""
    k, mu, F, W = -50.0, 0.05, 2.0, 0.1
    T = TWO_PI / W
    y0, amp, lam = segment_orbit(k, 0.0, mu, F, W)
    assert 1e190 < math.exp(lam * T) < 1e300
    osc = builtin_model("nsd", k=k, mu=mu, F=F, Omega=W)
    orbits = periodic_orbits(osc, grid=1, transient_periods=10)
    for o in orbits:
        assert_orbit_is_finite(o)
    saddle = [o for o in orbits if o.amplitude < 1.0]
    assert len(saddle) == 1
    assert saddle[0].amplitude == pytest.approx(amp, rel=1e-10)
    assert np.max(np.abs(saddle[0].y0 - y0)) < 1e-10
    assert saddle[0].max_multiplier == pytest.approx(math.exp(lam * T), rel=1e-9)
    assert abs(saddle[0].multipliers[1]) == pytest.approx(math.exp((-mu - lam) * T), rel=1e-9)
    # the well orbits (closed form too: |x| > 1 throughout) are stable
    _, a_well, _ = segment_orbit(1.0, k - 1.0, mu, F, W)
    wells = [o for o in orbits if o.amplitude > 1.0]
    assert wells and all(o.is_stable for o in wells)
    assert all(o.amplitude == pytest.approx(1.0 - k + a_well, rel=1e-10) for o in wells)


@pytest.mark.parametrize("k", [-10.0, -50.0])
def test_strong_negative_stiffness_first_harmonic_inner_branch_is_exact(k):
    """hb1 is exact for an orbit inside one linear segment: its branch below amplitude 1 is
    the saddle orbit F/|k - W^2 + i mu W| (and stays unstable: a saddle)."""
    mu, F = 0.05, 2.0
    resp = perturb.frequency_response(builtin_model("nsd", k=k, mu=mu, F=F), "hb1", (0.2, 2.0))
    assert_finite_response(resp)
    inner = [b for b in resp.branches if b.amplitude.max() < 1.0]
    assert len(inner) == 1
    b = inner[0]
    np.testing.assert_allclose(
        b.amplitude, F / np.abs(k - b.omega**2 + 1j * mu * b.omega), rtol=1e-9
    )
    assert not b.stable.any()


def test_large_forcing_orbit_and_approximation():
    """F = 100: the stable period-1 orbit (amplitude ~ 160) against the oracle over one period,
    and hb1 (first harmonic) against the orbit's first harmonic: the nonsmooth part is
    O((1 - k)/A) of the force, so hb1 is close (measured: 2.9e-7 relative)."""
    k, mu, F, W = -2.0, 0.05, 100.0, 0.6
    T = TWO_PI / W
    flow = ExactPWLFlow(nsd_system(k, mu, F, W))
    y = flow([0.0, 0.0], 0.0, 60 * T).y
    orb = periodic_orbit(flow, y)
    assert_orbit_is_finite(orb) and orb.is_stable
    ref = oracle_of(flow.system, orb.y0, (0.0, T))
    assert np.max(np.abs(ref - orb.y0)) < 1e-10 * (1.0 + np.max(np.abs(orb.y0)))
    resp = perturb.frequency_response(builtin_model("nsd", k=k, mu=mu, F=F), "hb1", frequencies=[W])
    assert_finite_response(resp)
    best = min(
        abs(b.first_harmonic_amplitude[0] / orb.first_harmonic_amplitude - 1) for b in resp.branches
    )
    assert best < 1e-5


@pytest.mark.parametrize(
    ("k", "mu", "F"),
    [(-10.0, 0.05, 2.0), (-50.0, 0.05, 2.0), (-2.0, 1e-6, 2.0), (-2.0, 0.05, 100.0)],
)
def test_lcp_time_stepping_converges_at_second_order_in_hard_cases(k, mu, F):
    """The theta = 1/2 LCP scheme (stated O(h^2), with an irregular constant) against the
    oracle: quartering h gains more than first order would (measured: a factor 7.5 to 170),
    and a step beyond the P-matrix bound is refused with the bound in the message."""
    system = nsd_system(k, mu, F, 0.6)
    T = TWO_PI / 0.6
    ref = oracle_of(system, [0.5, 0.0], (0.0, T))
    errs = []
    for h in (4e-3, 1e-3):
        tr = simulate_lcp(system, (0.5, 0.0), (0.0, T), h)
        assert np.all(np.isfinite(tr.x))
        errs.append(abs(tr.x[-1] - ref[0]) / (1.0 + abs(ref[0])))
    assert errs[1] < 1e-5 and errs[1] < errs[0] / 5.0, errs
    if k < -2:
        with pytest.raises(PerturbError, match="P-matrix"):
            simulate_lcp(system, (0.5, 0.0), (0.0, T), 1.0)


# ---------------------------------------------------------------------------------------------
# 5. Omega -> 0 and Omega = 10
# ---------------------------------------------------------------------------------------------
def test_low_frequency_window_is_traced():
    """nsd k = -2, F = 2 in the window (1e-3, 1e-2): three hb1 solutions at every frequency
    (the saddle branch near A = 1, the hilltop one near 1.52, the well one near 5.80).
    Regression: the amplitude grid stepped over the narrow window in W = Omega^2 (a step of
    0.6 % in A moves W by far more than 1e-4), and the response came back empty."""
    k, mu, F = -2.0, 0.05, 2.0
    approx = METHODS["hb1"](builtin_model("nsd", k=k, mu=mu, F=F))
    resp = traced_response(approx, (1e-3, 1e-2))
    assert_finite_response(resp)
    assert len(resp.branches) == 3
    for b in resp.branches:
        assert b.omega.min() < 1.1e-3 and b.omega.max() > 0.99e-2  # the whole window
        assert len(b) >= 64
        for j in np.linspace(0, len(b) - 1, 5).astype(int):
            a, w = b.first_harmonic_amplitude[j], b.omega[j]
            assert abs(hb1_residual(a, w, k, mu, F)) < 1e-9 * F * F
    exact_at = solutions_at(approx, [1e-3, 3e-3, 1e-2])
    assert len(exact_at.branches) == 3 and all(len(b) == 3 for b in exact_at.branches)


def test_quasi_static_orbit_at_omega_1e_3():
    """Omega = 1e-3 (T = 6283), F = 1 < the barrier: the orbit follows the static equilibrium
    of one well, x = 3 + cos(W t) + O(W^2), a linear segment orbit.  Shooting finds it from the
    static guess; its multiplier is exp(-mu T/2) ~ 6e-69 (not 0, not NaN)."""
    k, mu, F, W = -2.0, 0.05, 1.0, 1e-3
    T = TWO_PI / W
    flow = ExactPWLFlow(nsd_system(k, mu, F, W))
    y0, a_well, _ = segment_orbit(1.0, k - 1.0, mu, F, W)
    orb = periodic_orbit(flow, [1.0 - k + F, 0.0])
    assert_orbit_is_finite(orb)
    assert np.max(np.abs(orb.y0 - y0)) < 1e-9
    assert orb.amplitude == pytest.approx(1.0 - k + a_well, rel=1e-12)
    assert orb.max_multiplier == pytest.approx(math.exp(-0.5 * mu * T), rel=1e-6)
    resp = perturb.frequency_response(builtin_model("nsd", k=k, mu=mu, F=F), "hb1", frequencies=[W])
    assert_finite_response(resp)


def test_high_frequency_orbits_omega_10():
    """Omega = 10: every period-1 orbit is a linear segment orbit (saddle and two wells)."""
    k, mu, F, W = -2.0, 0.05, 2.0, 10.0
    osc = builtin_model("nsd", k=k, mu=mu, F=F, Omega=W)
    orbits = periodic_orbits(osc, grid=2, transient_periods=20)
    _, a_saddle, lam = segment_orbit(k, 0.0, mu, F, W)
    _, a_well, _ = segment_orbit(1.0, k - 1.0, mu, F, W)
    amps = sorted(o.amplitude for o in orbits)
    assert len(amps) == 3
    np.testing.assert_allclose(amps, [a_saddle, 1 - k + a_well, 1 - k + a_well], rtol=1e-10)
    saddle = min(orbits, key=lambda o: o.amplitude)
    assert saddle.max_multiplier == pytest.approx(math.exp(lam * TWO_PI / W), rel=1e-10)
    resp = perturb.frequency_response(builtin_model("nsd", k=k, mu=mu, F=F), "hb1", (9.0, 10.0))
    assert_finite_response(resp)


# ---------------------------------------------------------------------------------------------
# 6. the detached branch of the approximate response where it meets the saddle branch
# ---------------------------------------------------------------------------------------------
def test_detached_branch_near_the_value_where_it_vanishes():
    """nsd k = -3, mu = 0.05, first-harmonic balance at Omega -> 0.  Below the static barrier
    F* = max_A (-a1(A)) (a1 of the nsd force, A* = 1.294, F* = 3.2325) the upper loop of
    cross-well orbits is detached from the saddle branch: at a low frequency two solutions
    A1 < A* < A2 bound the gap.  As F -> F* the gap shrinks to the point A*, then the loop
    joins the saddle branch.  The two roots come within 2e-3 of each other, closer than the
    amplitude scan (0.6 %).  Regression: solutions_at lost both (no sign change between two
    scan points) at F = F* (1 - 1e-6) and F* (1 - 1e-8)."""
    k, mu, W = -3.0, 0.05, 1e-3
    with mp.workdps(30):
        a_star = mp.findroot(lambda A: mp.diff(lambda z: a1_nsd(z, k), A), 1.29)
        f_star = -a1_nsd(a_star, k)
        assert float(a_star) == pytest.approx(1.2941, abs=1e-4)
        for delta in (1e-2, 1e-4, 1e-6, 1e-8, -1e-4):
            F = float(f_star * (1 - delta))
            approx = METHODS["hb1"](builtin_model("nsd", k=k, mu=mu, F=F))
            at = solutions_at(approx, [W])
            assert_finite_response(at)
            near = sorted(
                float(b.first_harmonic_amplitude[0])
                for b in at.branches
                if 1.0 < b.first_harmonic_amplitude[0] < 2.0
            )
            if delta < 0:
                assert near == []
            else:

                def g(A, F=F):
                    return a1_nsd(A, k) - W * W * A + mp.sqrt(F * F - (mu * W * A) ** 2)

                roots = [
                    float(mp.findroot(g, (mp.mpf(1.0001), a_star), solver="anderson")),
                    float(mp.findroot(g, (a_star, mp.mpf(2)), solver="anderson")),
                ]
                assert len(near) == 2
                np.testing.assert_allclose(near, roots, rtol=1e-9)
            resp = traced_response(approx, (W, 0.05), stability="slow_flow")
            assert_finite_response(resp)
            lows = sorted(
                float(b.first_harmonic_amplitude[np.argmin(b.omega)])
                for b in resp.branches
                if b.omega.min() < 1.1 * W
            )
            inner = [a for a in lows if 1.0 < a < 2.0]
            assert len(inner) == (2 if delta > 0 else 0)


# ---------------------------------------------------------------------------------------------
# 7. the "potentially chaotic" windows (Figs. 6 and 8)
# ---------------------------------------------------------------------------------------------
CHAOTIC = {
    # Fig. 6(a): F = 1, Omega = 0.4, mu = 0.1, k between -0.5 and -2 (measured lambda ~ 0.04)
    "fig6": {"k": -1.0, "mu": 0.1, "F": 1.0, "Omega": 0.4},
    # Fig. 8: k = -4, mu = 0.25, Omega = 1.2, mid-sized F (measured lambda ~ 0.06)
    "fig8": {"k": -4.0, "mu": 0.25, "F": 3.0, "Omega": 1.2},
}


@pytest.mark.parametrize("name", sorted(CHAOTIC))
def test_chaotic_window_reports_no_stable_periodic_orbit(name):
    p = CHAOTIC[name]
    osc = builtin_model("nsd", **p)
    lya = lyapunov_exponent(osc, [0.5, 0.0], 300, transient=100, **QUIET)
    assert np.all(np.isfinite(lya.running))
    assert lya.value > 0.02, lya
    assert sum(lya.exponents) == pytest.approx(-p["mu"], abs=1e-9)  # Liouville
    bd = bifurcation_diagram(osc, "F", [p["F"]], record_periods=12, **QUIET)
    assert bd.period[0, 0] == 0 and bd.n_distinct(1e-6)[0, 0] == 12
    assert np.all(np.isfinite(bd.x))
    sweep = frequency_sweep(osc, [p["Omega"]], **QUIET)
    assert sweep.up.period[0] == 0
    resp = sweep.to_response()
    # regression: the chaotic attractor came out as a stable periodic solution
    assert sum(len(b) for b in resp.branches) == 0
    assert any("no periodic response" in n for n in resp.notes)


# fig6 takes ~9 s (four unstable orbits, each corrected from many seeds): in the slow set
@pytest.mark.parametrize("name", ["fig8", pytest.param("fig6", marks=pytest.mark.slow)])
def test_chaotic_window_exact_orbits_are_all_unstable(name):
    """Every period-1 orbit the exact solver finds there is unstable, and genuine: one period
    of the oracle returns to it (to rounding amplified by its multiplier)."""
    p = CHAOTIC[name]
    osc = builtin_model("nsd", **p)
    resp = perturb.frequency_response(osc, "exact", frequencies=[p["Omega"]])
    assert_finite_response(resp)
    assert resp.branches and not any(b.stable.any() for b in resp.branches)
    system = nsd_system(p["k"], p["mu"], p["F"], p["Omega"])
    T = TWO_PI / p["Omega"]
    for o in periodic_orbits(osc, grid=2, transient_periods=20):
        assert not o.is_stable and o.max_multiplier > 1.0
        ref = oracle_of(system, o.y0, (0.0, T))
        assert np.max(np.abs(ref - o.y0)) < 1e-10 * o.max_multiplier * (1 + o.amplitude)


# ---------------------------------------------------------------------------------------------
# 8. subharmonic orbits
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("F", "m"), [(6.0, 2), (4.25, 3)])
def test_subharmonic_orbits(F, m):
    """nsd k = -4, mu = 0.25, Omega = 1.2 (Fig. 8): period 2 at F = 6 and period 3 at F = 4.25
    (measured with bifurcation diagrams).  Shooting with m forcing periods converges from the
    settled state; the oracle returns to y0 after m periods (not after fewer); the section has
    m points; the Lyapunov exponent is ln|mu_max|/(mT)."""
    k, mu, W = -4.0, 0.25, 1.2
    T = TWO_PI / W
    osc = builtin_model("nsd", k=k, mu=mu, F=F, Omega=W)
    flow = ExactPWLFlow(nsd_system(k, mu, F, W))
    y = flow([0.0, 0.0], 0.0, 300 * T).y
    orb = periodic_orbit(flow, y, m=m)
    assert_orbit_is_finite(orb)
    assert orb.m == m and orb.is_stable and orb.period == pytest.approx(m * T)
    system = flow.system
    pts = [orb.y0]
    for j in range(m):
        pts.append(oracle_of(system, pts[-1], (j * T, (j + 1) * T)))
    scale = 1.0 + np.max(np.abs(orb.y0))
    assert np.max(np.abs(pts[-1] - orb.y0)) < 1e-9 * scale
    assert all(np.max(np.abs(q - orb.y0)) > 1e-3 * scale for q in pts[1:-1])
    sec = poincare_section(osc, orb.y0, 4 * m, transient=0, **QUIET)
    assert len(sec.distinct(1e-8)) == m and sec.detected_period(1e-8) == m
    lya = lyapunov_exponent(flow, orb.y0, 60 * m, transient=0, **QUIET)
    assert lya.value == pytest.approx(math.log(orb.max_multiplier) / (m * T), abs=0.02)


# ---------------------------------------------------------------------------------------------
# 9. discontinuous forces: Coulomb friction and relays
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("mu", "c", "F", "W"),
    [
        (0.05, 0.3, 1.0, 0.8),  # a stick phase, then slipping
        (0.1, 0.5, 0.6, 0.5),  # stick-slip every half period
        (0.0, 0.2, 2.0, 1.0),  # undamped, resonant: the amplitude grows linearly
        (1e-6, 0.3, 100.0, 1.3),  # tiny damping, very large forcing
    ],
)
def test_coulomb_friction_event_driven_matches_oracle(mu, c, F, W):
    osc = Oscillator.parse(f"x'' + {mu}*x' + x + {c}*sign(x') = {F}*cos({W}*t)")
    T = TWO_PI / W
    te = np.linspace(0.0, 6 * T, 301)
    tr = simulate(osc, [0.5, 0.0], (0.0, 6 * T), t_eval=te)
    ref = coulomb_oracle(mu, c, F, W, [0.5, 0.0], te)
    got = np.vstack([tr.x, tr.v])
    assert np.all(np.isfinite(got))
    assert np.max(np.abs(got - ref)) < 1e-8 * (1.0 + np.max(np.abs(ref)))
    th = time_history(osc, [0.5, 0.0], (0.0, T))
    assert th.method == "event" and np.all(np.isfinite(th.x))


def test_coulomb_stick_slip_periodic_orbit():
    """Shooting through stick phases (the saltation resets the velocity sensitivity): the
    stick-slip orbit is stable, and one period of the oracle returns to it."""
    mu, c, F, W = 0.1, 0.5, 0.6, 0.5
    osc = Oscillator.parse(f"x'' + {mu}*x' + x + {c}*sign(x') = {F}*cos({W}*t)")
    orb = periodic_orbit(EventFlow(osc), [0.1, 0.0])
    assert_orbit_is_finite(orb) and orb.is_stable
    T = TWO_PI / W
    ref = coulomb_oracle(mu, c, F, W, orb.y0, [0.0, T])
    assert np.max(np.abs(ref[:, -1] - orb.y0)) < 1e-8


@pytest.mark.parametrize(("mu", "a", "F", "W"), [(0.1, 0.5, 2.0, 1.3), (0.05, 0.3, 1.0, 0.7)])
def test_relay_exact_and_event_driven_match_oracle(mu, a, F, W):
    """x'' + mu x' + x + a sign(x) = F cos(W t): a force jump of 2a at x = 0."""
    T = TWO_PI / W
    te = np.linspace(0.0, 6 * T, 201)
    system = PWLSystem([0.0], [1.0, 1.0], [-a, a], damping=mu, forcing=((F, W, 0.0),))
    ref = oracle_of(system, [1.0, 0.0], (0.0, 6 * T), te, strict=True)
    ex = propagate(system, [1.0, 0.0], (0.0, 6 * T), t_eval=te)
    osc = Oscillator.parse(f"x'' + {mu}*x' + x + {a}*sign(x) = {F}*cos({W}*t)")
    ed = simulate(osc, [1.0, 0.0], (0.0, 6 * T), t_eval=te)
    scale = 1.0 + np.max(np.abs(ref))
    assert np.max(np.abs(np.vstack([ex.x, ex.v]) - ref)) < 1e-9 * scale
    assert np.max(np.abs(np.vstack([ed.x, ed.v]) - ref)) < 1e-8 * scale
    with pytest.raises(PerturbError, match="event-driven"):
        simulate_lcp(system, (1.0, 0.0), (0.0, T), 0.01)


def test_discontinuities_that_stick_raise_clear_errors():
    """A jump both sides of which push into the breakpoint: the exact propagator does not
    slide and says so (pointing to the event-driven solver), which does."""
    system = PWLSystem([0.0], [0.0, 0.0], [-1.0, 1.0], damping=0.1, forcing=((0.5, 1.0, 0.0),))
    with pytest.raises(PerturbError, match="event-driven"):
        propagate(system, [0.0, 0.0], (0.0, 10.0))
    # a switch of the same size on the velocity (Coulomb friction, no spring) sticks and slips
    # in the event-driven solver
    osc = Oscillator.parse("x'' + 0.1*x' + sign(x') = 0.5*cos(t)")
    tr = simulate(osc, [0.0, 1.0], (0.0, 20.0))
    assert tr.of_kind("stick") and np.all(np.isfinite(tr.x))


# ---------------------------------------------------------------------------------------------
# degenerate inputs: a PerturbError that names the problem, never a bare exception
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: perturb.frequency_response(builtin_model("nsd"), "hb1", (0.0, 1.0)), "0 < low"),
        (lambda: perturb.frequency_response(builtin_model("nsd"), "hb1", frequencies=[0]), "posit"),
        (
            lambda: perturb.frequency_response(builtin_model("nsd"), "exact", frequencies=[np.nan]),
            "positive finite",
        ),
        (lambda: builtin_model("nsd", F=math.inf), "'F' = inf"),
        (lambda: periodic_orbits(builtin_model("nsd", mu=-0.1)), "mu >= 0"),
        (lambda: periodic_orbits(builtin_model("nsd"), 0.0), "omega > 0"),
        # regression: with F = 0 no forcing is left, and this was a bare TypeError
        (
            lambda: perturb.frequency_response(
                builtin_model("nsd", F=0.0), "exact", frequencies=[1.0]
            ),
            "no forcing period",
        ),
    ],
)
def test_degenerate_inputs_raise_clear_perturb_errors(call, match):
    with pytest.raises(PerturbError, match=match):
        call()


def test_escaping_orbit_raises_a_clear_error_without_floating_point_warnings():
    """k = -50 everywhere: exp(7 t) overflows near t = 100.  Regression: the finiteness test
    itself (x + v) raised an overflow RuntimeWarning first."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(PerturbError, match="escapes to infinity"):
            propagate(PWLSystem([0.0], [-50.0, -50.0], [0.0, 0.0]), [1.0, 0.0], (0.0, 1000.0))


# ---------------------------------------------------------------------------------------------
# 10. properties over random PWL oscillators
# ---------------------------------------------------------------------------------------------
@st.composite
def pwl_oscillators(draw):
    """1-3 breakpoints at least 0.2 apart, slopes in [-2, 4] (negative ones included),
    continuous or with force jumps, damping 0 or in [0, 0.5], a harmonic load (or none), a
    static load and an initial state."""
    m = draw(st.integers(1, 3))
    gaps = draw(st.lists(st.floats(0.2, 1.5), min_size=m - 1, max_size=m - 1))
    bp = draw(st.floats(-2.0, 1.0)) + np.cumsum([0.0, *gaps])
    slopes = draw(st.lists(st.floats(-2.0, 4.0), min_size=m + 1, max_size=m + 1))
    jumps = draw(st.lists(st.one_of(st.just(0.0), st.floats(-1.0, 1.0)), min_size=m, max_size=m))
    offsets = [draw(st.floats(-1.0, 1.0))]
    for i, d in enumerate(bp):
        offsets.append(offsets[-1] + (slopes[i] - slopes[i + 1]) * d + jumps[i])
    mu = draw(st.one_of(st.just(0.0), st.floats(0.0, 0.5)))
    F = draw(st.one_of(st.just(0.0), st.floats(0.1, 5.0)))
    forcing = ((F, draw(st.floats(0.3, 3.0)), draw(st.floats(0.0, TWO_PI))),) if F else ()
    c = draw(st.floats(-1.0, 1.0))
    # states rounded to 1e-12: a velocity of 1e-308 on a breakpoint makes x underflow to 0
    # during its excursion (x ~ v^2 ~ 1e-616), which no double-precision integrator resolves
    y0 = tuple(round(draw(st.floats(-3.0, 3.0)), 12) for _ in range(2))
    return bp, slopes, offsets, mu, forcing, c, y0, any(jumps)


@settings(
    max_examples=60, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(pwl_oscillators())
def test_property_exact_propagation_matches_event_driven_oracle(case):
    """Over 8 time units (~2 forcing periods): agreement to 1e-8 of the state's scale
    (measured: worst 1.4e-11).  Across a force jump the oracle declines sliding and grazing;
    the propagator may then only raise a PerturbError."""
    bp, slopes, offsets, mu, forcing, c, y0, has_jumps = case
    system = PWLSystem(bp, slopes, offsets, damping=mu, forcing=forcing, static_force=c)
    te = np.linspace(0.0, 8.0, 17)
    try:
        ref = pwl_oracle(bp, slopes, offsets, mu, forcing, c, y0, (0.0, 8.0), te, strict=has_jumps)
    except OracleFailure:
        assume(False)
    try:
        tr = propagate(system, y0, (0.0, 8.0), t_eval=te)
    except PerturbError as err:
        assert has_jumps, err
        assert "event-driven" in str(err)
        return
    got = np.vstack([tr.x, tr.v])
    assert np.all(np.isfinite(got))
    assert np.max(np.abs(got - ref)) < 1e-8 * (1.0 + np.max(np.abs(ref)))


@st.composite
def pwl_forces(draw):
    """A PWL force in ramp-step form and a motion A cos psi + b, a third of them grazing a
    breakpoint from either side (|d - b| = A (1 +- 10^-e))."""
    m = draw(st.integers(0, 4))
    ds = sorted(draw(st.lists(st.floats(-3, 3), min_size=m, max_size=m, unique=True)))
    dks = draw(st.lists(st.floats(-20, 20), min_size=m, max_size=m))
    js = draw(st.lists(st.one_of(st.just(0.0), st.floats(-5, 5)), min_size=m, max_size=m))
    k0, f0, b = draw(st.floats(-10, 10)), draw(st.floats(-5, 5)), draw(st.floats(-3, 3))
    if ds and draw(st.integers(0, 2)) == 0:
        d = draw(st.sampled_from(ds))
        A = abs(d - b) * (1 + draw(st.sampled_from([-1, 1])) * 10.0 ** -draw(st.integers(1, 15)))
    else:
        A = draw(st.floats(0, 6))
    return ds, dks, js, k0, f0, b, A


@settings(max_examples=30, derandomize=True, deadline=None)
@given(pwl_forces())
def test_property_pwl_coefficients_match_mpmath_quadrature(case):
    """Closed-form coefficients of k0 x + f0 + sum [dk (x-d)H(x-d) + J H(x-d)] against 30-digit
    quadrature split at the switching angles, to 1e-13 of the natural scale (measured: 4e-16).
    H(0) = 1/2 (SymPy's convention, used for A = 0 on a breakpoint)."""
    ds, dks, js, k0, f0, b, A = case
    with mp.workdps(30):

        def f(x):
            out = mp.mpf(k0) * x + f0
            for d, dk, j in zip(ds, dks, js, strict=True):
                if x > d:
                    out += dk * (x - mp.mpf(d)) + j
                elif x == d:
                    out += mp.mpf(j) / 2
            return out

        ns = np.array([0, 1, 2, 3, 7, 16])
        got = pwl_coefficients(ns, A, b, k0, f0, ds, dks, js)
        assert np.all(np.isfinite(got))
        Am, bm = mp.mpf(A), mp.mpf(b)
        cuts = [mp.acos((mp.mpf(d) - bm) / Am) for d in ds if A > 0 and abs(d - b) < A]
        size = max(map(abs, ds), default=0.0)
        scale = (abs(k0) + sum(map(abs, dks))) * (A + abs(b) + size) + abs(f0) + sum(map(abs, js))
        for n, g in zip(ns, got, strict=True):
            if A == 0:  # x = b: a0 = 2 f(b), nothing else
                want = 2 * f(bm) if n == 0 else 0
            else:
                want = quad_coefficient(f, int(n), Am, bm, cuts, mp.mpf(scale) or 1)
            assert abs(g - float(want)) <= 1e-13 * scale + 1e-300


# ---------------------------------------------------------------------------------------------
# 11. exact continuation through the hard cases
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("params", "window"),
    [
        ({"k": -2.0, "mu": 1e-6, "F": 2.0}, (1.5, 2.0)),
        ({"k": -10.0, "mu": 0.05, "F": 2.0}, (1.0, 1.5)),
        ({"k": -2.0, "mu": 0.05, "F": 100.0}, (1.5, 2.0)),
        ({"k": -2.0, "mu": 0.05, "F": 2.0}, (9.0, 10.0)),
    ],
)
def test_exact_continuation_in_hard_cases(params, window):
    """Every traced point is finite, its stability agrees with its multiplier, and the
    saddle branch (amplitude < 1) is the closed form F/|k - W^2 + i mu W|."""
    osc = builtin_model("nsd", **params)
    resp = perturb.frequency_response(osc, "exact", window, **QUIET)
    assert_finite_response(resp)
    assert resp.branches
    k, mu, F = params["k"], params["mu"], params["F"]
    for b in resp.branches:
        assert np.array_equal(b.stable, b.max_multiplier < 1.0)
        assert b.omega.min() >= window[0] - 1e-12 and b.omega.max() <= window[1] + 1e-12
        if b.amplitude.max() < 1.0:
            want = F / np.abs(k - b.omega**2 + 1j * mu * b.omega)
            np.testing.assert_allclose(b.amplitude, want, rtol=1e-8)
            assert not b.stable.any()


@pytest.mark.slow  # ~4 s, but ~6000 time units of the oracle: kept out of the quick set
def test_quasi_static_orbit_at_omega_1e_3_against_oracle():
    """One period (T = 6283) of the oracle from the shooting solution of the F = 3 orbit,
    which snaps through between the wells twice per period (F above the barrier 2)."""
    k, mu, F, W = -2.0, 0.05, 3.0, 1e-3
    T = TWO_PI / W
    flow = ExactPWLFlow(nsd_system(k, mu, F, W))
    y = flow([0.0, 0.0], 0.0, 3 * T).y
    orb = periodic_orbit(flow, y)
    assert_orbit_is_finite(orb) and orb.is_stable
    ref = oracle_of(flow.system, orb.y0, (0.0, T))
    assert np.max(np.abs(ref - orb.y0)) < 1e-8 * (1 + orb.amplitude)
