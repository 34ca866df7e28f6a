"""Exact n-dimensional piecewise-affine propagation (perturb.simulate.flows.affine_exact).

Every system is built by hand here, and every reference is independent of the propagator:
DOP853 (rtol = atol = 1e-12) on the equations of motion written out physically, with a
terminal event on every surface and a restart at each crossing (the region held fixed between
crossings, so the integrator never steps across a switch); the SDOF exact propagator for the
one-coordinate case; the harmonic steady state solved by ``numpy.linalg.solve``; the
augmented-matrix exponential of ``scipy.linalg.expm`` for the grazing construction.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.affine import PiecewiseAffineSystem
from perturb.simulate.flows.affine_exact import AffineExactFlow, propagate
from perturb.simulate.flows.base import Flow
from perturb.simulate.flows.piecewise_exact import PWLSystem
from perturb.simulate.flows.piecewise_exact import propagate as propagate_sdof

GAP = (1.0, -1.0, 0.0, 0.0)  # x1 - x2 in the state (x1, x2, v1, v2)


# ------------------------------------------------------------------------------------------
# the independent reference: DOP853 with events and restarts
# ------------------------------------------------------------------------------------------
def reference(rhs, surfaces, pattern, y0, t0, t1, *, t_eval=(), max_restarts=100_000):
    """DOP853 (rtol = atol = 1e-12) of ``rhs(t, y, pattern)`` with terminal events on every
    surface ``(c, d)`` and a restart (pattern flipped) at each crossing.  Returns the final
    state, the crossings ``[(t, j), ...]`` and the states at ``t_eval``."""
    t, y, pat = float(t0), np.array(y0, dtype=float), list(pattern)
    t_eval = np.asarray(t_eval, dtype=float)
    samples = np.full((t_eval.size, y.size), np.nan)
    log = []
    for _ in range(max_restarts):
        events = []
        for j, (c, d) in enumerate(surfaces):
            cj = np.asarray(c, dtype=float)

            def ev(tt, yy, c=cj, d=d):
                return c @ yy - d

            ev.terminal = True
            ev.direction = -pat[j]  # leaving the side pat[j]
            events.append(ev)
        p = tuple(pat)
        sol = solve_ivp(
            lambda tt, yy, p=p: rhs(tt, yy, p),
            (t, t1),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=events or None,
            dense_output=t_eval.size > 0,
        )
        assert sol.status in (0, 1), sol.message
        t_end = float(sol.t[-1])
        if t_eval.size:
            sel = (t_eval >= t) & (t_eval <= t_end)
            if np.any(sel):
                samples[sel] = sol.sol(t_eval[sel]).T
        if sol.status == 0:
            return sol.y[:, -1], log, samples
        j = min(
            (k for k in range(len(events)) if sol.t_events[k].size),
            key=lambda k: sol.t_events[k][0],
        )
        t, y = float(sol.t_events[j][0]), sol.y_events[j][0]
        pat[j] = -pat[j]
        log.append((t, j))
    raise AssertionError("reference: too many restarts")


def crossings(result):
    return [(e.time, e.surface) for e in result.events if not e.tangency]


def assert_same_orbit(result, ref_y, ref_log, tol, ref_samples=None, samples=None):
    ours = crossings(result)
    assert [j for _, j in ours] == [j for _, j in ref_log]
    times = np.array([t for t, _ in ours])
    ref_times = np.array([t for t, _ in ref_log])
    assert np.max(np.abs(times - ref_times), initial=0.0) < tol
    scale = max(1.0, float(np.abs(ref_y).max()))
    assert np.max(np.abs(result.y - ref_y)) < tol * scale
    if ref_samples is not None:
        assert np.max(np.abs(samples - ref_samples)) < tol * scale


# ------------------------------------------------------------------------------------------
# the systems, written twice: as a PiecewiseAffineSystem and as equations of motion
# ------------------------------------------------------------------------------------------
def chain(*, k1=1.0, k2=2.0, k12=0.3, c=0.1, c0=None, c12=0.0, kg=4.0, gap=0.2, F=0.6, W=1.1):
    """Two masses: x1 on k1 to ground, x2 on k2, coupled by k12 and a two-sided gap (contact
    stiffness kg once |x1 - x2| > gap); dampers c from each mass to ground (c0 overrides the
    first) and c12 between them; F cos(W t) on x1."""
    c1 = c if c0 is None else c0
    Cm = np.array([[c1 + c12, -c12], [-c12, c + c12]])

    def A_of(kc):
        K = np.array([[k1 + k12 + kc, -k12 - kc], [-k12 - kc, k2 + k12 + kc]])
        return np.block([[np.zeros((2, 2)), np.eye(2)], [-K, -Cm]])

    system = PiecewiseAffineSystem.build(
        ("x1", "x2", "v1", "v2"),
        [(GAP, gap, "x1 - x2 = gap"), (GAP, -gap, "x1 - x2 = -gap")],
        {
            (1, 1): (A_of(kg), (0, 0, kg * gap, -kg * gap)),
            (-1, 1): (A_of(0.0), (0, 0, 0, 0)),
            (-1, -1): (A_of(kg), (0, 0, -kg * gap, kg * gap)),
        },
        inputs=[(W, (0, 0, F, 0), (0, 0, 0, 0))],
        period=2 * math.pi / W,
    )

    def rhs(t, y, pat):
        x1, x2, v1, v2 = y
        r = x1 - x2
        contact = kg * (r - gap) if pat[0] > 0 else (kg * (r + gap) if pat[1] < 0 else 0.0)
        return [
            v1,
            v2,
            -c1 * v1 - c12 * (v1 - v2) - k1 * x1 - k12 * r - contact + F * math.cos(W * t),
            -c * v2 + c12 * (v1 - v2) - k2 * x2 + k12 * r + contact,
        ]

    return system, rhs, [(GAP, gap), (GAP, -gap)]


def nsd(k=-2.0, mu=0.05, F=2.0, W=1.2):
    """x'' + mu x' + k x + (1 - k)[(x - 1)H(x - 1) + (x + 1)H(-x - 1)] = F cos(W t)."""
    system = PiecewiseAffineSystem.build(
        ("x", "v"),
        [((1, 0), 1.0, "x = 1"), ((1, 0), -1.0, "x = -1")],
        {
            (1, 1): ([[0, 1], [-1, -mu]], (0, 1 - k)),
            (-1, 1): ([[0, 1], [-k, -mu]], (0, 0)),
            (-1, -1): ([[0, 1], [-1, -mu]], (0, k - 1)),
        },
        inputs=[(W, (0, F), (0, 0))],
        period=2 * math.pi / W,
    )

    def rhs(t, y, pat):
        x, v = y
        f = x - (1 - k) if pat[0] > 0 else (x + (1 - k) if pat[1] < 0 else k * x)
        return [v, -mu * v - f + F * math.cos(W * t)]

    sdof = PWLSystem(
        [-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0], damping=mu, forcing=((F, W, 0.0),)
    )
    return system, rhs, [((1, 0), 1.0), ((1, 0), -1.0)], sdof


def chamber(*, a=1.0, tr=0.5, q=0.2, C1=1.0, C2=4.0, pv=-0.3, F=1.0, W=0.9):
    """A mass on a spring pushing a fluid chamber (a first-order state, the pressure p):
    x'' + 0.1 x' + x + a p = F cos(W t),  C(p) p' = a x' - p / tr + q,
    the compliance C switching from C1 to C2 below the vapour level p = pv (the field is
    discontinuous there: p' jumps, p has a kink)."""

    def A_b(C):
        A = [[0, 1, 0], [-1, -0.1, -a], [0, a / C, -1 / (tr * C)]]
        return A, (0, 0, q / C)

    system = PiecewiseAffineSystem.build(
        ("x", "v", "p"),
        [((0, 0, 1), pv, "p = p_vapour")],
        {(1,): A_b(C1), (-1,): A_b(C2)},
        inputs=[(W, (0, F, 0), (0, 0, 0))],
        period=2 * math.pi / W,
    )

    def rhs(t, y, pat):
        x, v, p = y
        C = C1 if pat[0] > 0 else C2
        return [v, -0.1 * v - x - a * p + F * math.cos(W * t), (a * v - p / tr + q) / C]

    return system, rhs, [((0, 0, 1), pv)]


def settle(system, periods=40):
    """A time and state on the attractor (the comparisons are then free of transient chaos,
    where any two correct solvers part ways by rounding)."""
    t0 = periods * system.period
    return t0, propagate(system, np.zeros(system.n), 0.0, t0).y


# ------------------------------------------------------------------------------------------
# accuracy against DOP853 over 100 forcing periods
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "case",
    ["chain", "chamber", "free_body_damped", "free_body_undamped"],
)
def test_agrees_with_dop853_over_100_periods(case):
    if case == "chain":
        system, rhs, surfaces = chain()
    elif case == "chamber":
        system, rhs, surfaces = chamber()
    elif case == "free_body_damped":
        # no spring to ground: A is singular (a rigid-body mode); damper to ground on x1
        system, rhs, surfaces = chain(k1=0.0, k2=0.0, k12=0.5, c=0.0, c0=0.1, gap=0.3, F=0.8)
    else:
        # no damper to ground either (one between the masses): a Jordan block at 0 (defective
        # A, the expm path)
        system, rhs, surfaces = chain(
            k1=0.0, k2=0.0, k12=0.5, c=0.0, c0=0.0, c12=0.1, gap=0.3, F=0.8
        )
    T = system.period
    if case == "free_body_undamped":
        t0, y0 = 3.0, np.array([0.1, 0.0, 0.0, 0.05])
    else:
        t0, y0 = settle(system)
    t1 = t0 + 100 * T
    marks = t0 + T * np.arange(1, 100)
    ours = propagate(system, y0, t0, t1, dense=True)
    ref_y, ref_log, ref_samples = reference(
        rhs, surfaces, system.pattern(y0), y0, t0, t1, t_eval=marks
    )
    assert len(ref_log) >= 100  # every case switches a lot
    assert_same_orbit(ours, ref_y, ref_log, 1e-9, ref_samples, ours.trajectory(marks).T)
    if case == "free_body_undamped":
        assert ours.stats.n_expm_pieces == ours.stats.n_pieces
    else:
        assert ours.stats.n_expm_pieces == 0


def test_nsd_agrees_with_dop853_and_the_sdof_propagator():
    system, rhs, surfaces, sdof = nsd()
    T = system.period
    # on the attractor: from rest this nsd goes through a chaotic transient, whose length
    # depends on rounding; settle until the state repeats after 5 periods (bounded)
    t0, y0 = settle(system, 400)
    for _ in range(400):
        y5 = propagate(system, y0, t0, t0 + 5 * T).y
        if np.max(np.abs(y5 - y0)) < 1e-9:
            break
        t0, y0 = t0 + 5 * T, y5
    t1 = t0 + 100 * T
    ours = propagate(system, y0, t0, t1)
    ref_y, ref_log, _ = reference(rhs, surfaces, system.pattern(y0), y0, t0, t1)
    assert len(ref_log) > 100
    assert_same_orbit(ours, ref_y, ref_log, 1e-9)
    traj = propagate_sdof(sdof, y0, (t0, t1))
    times = np.array([t for t, _ in crossings(ours)])
    sdof_times = np.array([e.time for e in traj.switches])
    assert times.size == sdof_times.size
    assert np.max(np.abs(times - sdof_times)) < 1e-10
    assert np.max(np.abs(ours.y - [traj.x[-1], traj.v[-1]])) < 1e-10


def test_expm_and_modal_representations_agree():
    system, _, _ = chain()
    t0, y0 = settle(system, 10)
    t1 = t0 + 10 * system.period
    a = propagate(system, y0, t0, t1)
    b = propagate(system, y0, t0, t1, representation="expm")
    assert b.stats.n_expm_pieces == b.stats.n_pieces and a.stats.n_expm_pieces == 0
    assert np.max(np.abs(a.y - b.y)) < 1e-10
    ta, tb = (np.array([t for t, _ in crossings(r)]) for r in (a, b))
    assert ta.size == tb.size and np.max(np.abs(ta - tb)) < 1e-10
    # and so do the sensitivities (eigen-decomposition vs the Taylor-squaring exponential)
    t1 = t0 + 2 * system.period
    Ma = AffineExactFlow(system)(y0, t0, t1, sensitivity=True).sensitivity
    Mb = AffineExactFlow(system, representation="expm")(y0, t0, t1, sensitivity=True).sensitivity
    assert np.max(np.abs(Ma - Mb)) < 1e-10 * np.max(np.abs(Ma))


def test_start_exactly_on_a_surface():
    system, rhs, surfaces = chain()
    # x1 - x2 = gap exactly, separating: the side the field moves into, no event at t0
    y0 = np.array([0.2, 0.0, 0.5, 0.0])
    res = propagate(system, y0, 0.0, 20.0)
    assert res.events[0].time > 0.1 and res.events[0].pattern_before == (1, 1)
    ref_y, ref_log, _ = reference(rhs, surfaces, (1, 1), y0, 0.0, 20.0)
    assert_same_orbit(res, ref_y, ref_log, 1e-9)
    # approaching: the region before the surface
    y0[2] = -0.5
    res = propagate(system, y0, 0.0, 20.0)
    assert res.events[0].pattern_before == (-1, 1) and res.events[0].time > 0.1


# ------------------------------------------------------------------------------------------
# closed forms
# ------------------------------------------------------------------------------------------
def test_linear_case_is_the_harmonic_steady_state():
    system, _, _ = chain(gap=50.0)  # the contact is never reached
    W = system.inputs[0].omega
    A = np.asarray(system.regions[(-1, 1)].A)
    Z = np.linalg.solve(1j * W * np.eye(4) - A, np.array([0, 0, 0.6, 0]))

    def steady(t):
        return (np.multiply.outer(np.exp(1j * W * np.asarray(t)), Z)).real

    t0, t1 = 0.7, 0.7 + 100 * system.period
    res = propagate(system, steady(t0), t0, t1, dense=True)
    assert res.events == ()
    ts = np.linspace(t0, t1, 2001)
    assert np.max(np.abs(res.trajectory(ts).T - steady(ts))) < 1e-12
    assert np.max(np.abs(res.y - steady(t1))) < 1e-12


def test_exact_resonance_of_an_undamped_mode():
    # x'' + x = cos t (the surface is never reached): x = t sin(t) / 2 from rest
    system = PiecewiseAffineSystem.build(
        ("x", "v"),
        [((1, 0), 1e3)],
        {(1,): ([[0, 1], [-1, 0]], (0, 0)), (-1,): ([[0, 1], [-1, 0]], (0, 0))},
        inputs=[(1.0, (0, 1), (0, 0))],
    )
    ts = np.linspace(0, 60, 301)
    res = propagate(system, (0.0, 0.0), 0.0, 60.0, dense=True)
    y = res.trajectory(ts)
    assert np.max(np.abs(y[0] - ts * np.sin(ts) / 2)) < 1e-12
    assert np.max(np.abs(y[1] - (np.sin(ts) + ts * np.cos(ts)) / 2)) < 1e-12


def test_free_drift_under_a_constant_load():
    # a first-order state without restoring term: p' = 0.5 (A = 0); x'' = -x + p
    system = PiecewiseAffineSystem.build(
        ("x", "v", "p"),
        [((0, 0, 1), 10.0)],
        {(s,): ([[0, 1, 0], [-1, 0, 1], [0, 0, 0]], (0, 0, 0.5)) for s in (1, -1)},
    )
    res = propagate(system, (0.0, 0.0, 0.0), 0.0, 30.0, dense=True)
    ts = np.linspace(0, 30, 31)
    # x = 0.5 (t - sin t), p = 0.5 t; the surface p = 10 is crossed at t = 20
    y = res.trajectory(ts)
    np.testing.assert_allclose(y[2], 0.5 * ts, atol=1e-13)
    np.testing.assert_allclose(y[0], 0.5 * (ts - np.sin(ts)), atol=1e-12)
    assert len(res.events) == 1 and abs(res.events[0].time - 20.0) < 1e-13


# ------------------------------------------------------------------------------------------
# grazing
# ------------------------------------------------------------------------------------------
def _free_chain_relative(system, y0, t):
    """x1 - x2 along the free region's solution, by the augmented-matrix exponential."""
    A = np.asarray(system.regions[(-1, 1)].A)
    h = system.inputs[0]
    At = np.zeros((6, 6))
    At[:4, :4] = A
    At[:4, 4], At[:4, 5] = h.u, h.v
    At[4, 5], At[5, 4] = -h.omega, h.omega
    z0 = np.concatenate([y0, [1.0, 0.0]])  # cos, sin at t = 0
    return float(GAP @ (scipy.linalg.expm(At * t) @ z0)[:4])


@pytest.mark.parametrize("depth", [1e-7, 1e-10, -1e-10, -1e-7, 0.0])
def test_grazing_crossing_found_or_correctly_absent(depth):
    base, _, _ = chain(gap=10.0)  # free: used only to place the graze
    y0 = np.array([0.0, 0.0, 0.3, 0.0])
    r = lambda t: _free_chain_relative(base, y0, t)  # noqa: E731
    # the first maximum of x1 - x2 (bracket by the sign of its numerical derivative)
    dr = lambda t: (r(t + 1e-6) - r(t - 1e-6)) / 2e-6  # noqa: E731
    ts = np.linspace(0.05, 4.0, 80)
    k = next(i for i in range(len(ts) - 1) if dr(ts[i]) > 0 > dr(ts[i + 1]))
    t_star = brentq(dr, ts[k], ts[k + 1], xtol=1e-14)
    # polish the maximum value by a parabola through three close points
    hs = 1e-3
    r0, rp, rm = r(t_star), r(t_star + hs), r(t_star - hs)
    r_max = r0 - (rp - rm) ** 2 / (8 * (rp - 2 * r0 + rm))
    system, _, _ = chain(gap=r_max - depth)
    t1 = t_star + 0.5
    res = propagate(system, y0, 0.0, t1)
    cross = crossings(res)
    if depth > 1e-9:
        # a dip of depth 1e-7 lasting ~1e-3: found, at the roots of x1 - x2 = gap
        g = lambda t: r(t) - (r_max - depth)  # noqa: E731
        w = math.sqrt(2 * depth / abs(rp - 2 * r0 + rm) * hs * hs)
        roots = [
            brentq(g, t_star - 3 * w, t_star, xtol=1e-15),
            brentq(g, t_star, t_star + 3 * w, xtol=1e-15),
        ]
        assert [j for _, j in cross] == [0, 0]
        assert abs(cross[0][0] - roots[0]) < 1e-8 and abs(cross[1][0] - roots[1]) < 1e-8
    elif depth < -1e-9:
        assert res.events == ()  # a near miss: correctly absent
    else:
        # at the rounding level: a tangency, a crossing pair, or nothing; never lost
        assert len(cross) in (0, 2)
    # whatever happened at the graze, the orbit is the free one up to the impulse of the
    # contact force (stiffness 4, at most 1e-7 deep for ~1e-3: below 1e-9)
    free = propagate(base, y0, 0.0, t1).y
    assert np.max(np.abs(res.y - free)) < (1e-9 if depth > 1e-9 else 1e-12)


def test_a_graze_between_grid_points_is_not_missed():
    # nsd middle region: choose the breakpoint just below the maximum of x along a fast
    # oscillation, so that the excursion lasts a tiny fraction of the grid step
    system0 = PiecewiseAffineSystem.build(
        ("x", "v"),
        [((1, 0), 100.0)],
        {(1,): ([[0, 1], [-400, -0.02]], (0, 0)), (-1,): ([[0, 1], [-400, -0.02]], (0, 0))},
    )
    y0 = np.array([0.0, 20.0])  # x ~ sin(20 t): max ~ 1 at t ~ pi/40
    res0 = propagate(system0, y0, 0.0, 0.1, dense=True)
    ts = np.linspace(0.0, 0.1, 100001)
    xs = res0.trajectory(ts)[0]
    i = int(np.argmax(xs))
    top = float(np.max(res0.trajectory(np.linspace(ts[i - 1], ts[i + 1], 20001))[0]))
    for depth, found in ((1e-9, True), (-1e-9, False)):
        system = PiecewiseAffineSystem.build(
            ("x", "v"),
            [((1, 0), top - depth)],
            {
                (1,): ([[0, 1], [-400, -0.02]], (0, 50.0)),  # a step force: discontinuous
                (-1,): ([[0, 1], [-400, -0.02]], (0, 0)),
            },
        )
        res = propagate(system, y0, 0.0, 0.1)
        assert (len(crossings(res)) == 2) is found


# ------------------------------------------------------------------------------------------
# sensitivity: product of exponentials and saltation matrices vs finite differences
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", ["chain", "chamber"])
def test_sensitivity_matches_finite_differences(case):
    system = chain()[0] if case == "chain" else chamber()[0]
    flow = AffineExactFlow(system)
    assert isinstance(flow, Flow) and flow.period == system.period
    t0, y0 = settle(system, 10)
    t1 = t0 + 3 * system.period
    res = flow(y0, t0, t1, sensitivity=True)
    assert res.n_events >= 4
    M = res.sensitivity
    h = 1e-6
    fd = np.empty_like(M)
    for i in range(system.n):
        e = np.zeros(system.n)
        e[i] = h * max(1.0, abs(y0[i]))
        fd[:, i] = (flow(y0 + e, t0, t1).y - flow(y0 - e, t0, t1).y) / (2 * e[i])
    assert np.max(np.abs(M - fd)) < 1e-6 * np.max(np.abs(M))
    if case == "chamber":
        # the saltation matters: without it the product of exponentials is wrong
        model = flow._model
        run = flow._propagate(y0, t0, t1)
        P = np.eye(system.n)
        for ta, tb, piece in run.pieces:
            P = piece.region.transition(tb - ta) @ P
        assert np.max(np.abs(P - fd)) > 1e-2 * np.max(np.abs(M))
        assert not model.continuous[0]


def test_flow_interface():
    system, _, _ = chain()
    flow = AffineExactFlow(system)
    t0, y0 = settle(system, 5)
    t1 = t0 + system.period
    ts = np.linspace(t0, t1, 7)
    res = flow(y0, t0, t1, t_eval=ts)
    assert res.ys.shape == (7, 4) and np.allclose(res.ys[-1], res.y, atol=1e-14)
    np.testing.assert_allclose(flow.trajectory(y0, t0, t1)(ts).T, res.ys)
    np.testing.assert_allclose(flow.vector_field(0.0, y0), system.field(0.0, y0))
    assert flow.exact_dense_output and not flow.autonomous and flow.system is None


# ------------------------------------------------------------------------------------------
# errors
# ------------------------------------------------------------------------------------------
def test_sliding_is_a_clear_error():
    # x' = -1 above 0, +1 below: both sides push into x = 0
    system = PiecewiseAffineSystem.build(
        ("x",), [((1.0,), 0.0)], {(1,): ([[0.0]], (-1.0,)), (-1,): ([[0.0]], (1.0,))}
    )
    with pytest.raises(PerturbError, match="sliding.*event-driven"):
        propagate(system, (1.0,), 0.0, 3.0)


def test_bad_input_and_limits():
    system, _, _ = chain()
    with pytest.raises(ParameterError, match="expected 4 finite numbers"):
        propagate(system, (0.0, 0.0), 0.0, 1.0)
    with pytest.raises(ParameterError, match="t1 > t0"):
        propagate(system, np.zeros(4), 1.0, 1.0)
    with pytest.raises(ParameterError, match="representation"):
        propagate(system, np.zeros(4), 0.0, 1.0, representation="taylor")
    with pytest.raises(ParameterError, match="PiecewiseAffineSystem"):
        propagate("chain", np.zeros(4), 0.0, 1.0)
    with pytest.raises(PerturbError, match="max_events = 3"):
        propagate(system, np.zeros(4), 0.0, 10 * system.period, max_events=3)
    with pytest.raises(PerturbError, match="max_steps = 10"):
        propagate(system, np.zeros(4), 0.0, 10 * system.period, max_steps=10)
    # a region that is missing from the system
    lone = PiecewiseAffineSystem.build(
        ("x", "v"), [((1, 0), 0.5)], {(-1,): ([[0, 1], [-1, 0]], (0, 0))}
    )
    with pytest.raises(ModelError, match="names no region"):
        propagate(lone, (0.0, 1.0), 0.0, 5.0)
