"""The Moreau–Jean LCP time-stepper for systems with several contacts
(perturb.simulate.flows.system_lcp), against oracles written here: an event-driven DOP853
reference (rtol = atol = 1e-12, impacts located as terminal events, Newton's law applied by
hand), closed-form impact outcomes, momentum / energy balances, brute-force LCP enumeration."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.system import System, coulomb, stop
from perturb.model.system_builtins import BUILTIN_SYSTEMS
from perturb.simulate.flows.base import Flow
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.flows.system_lcp import (
    SystemLCPFlow,
    simulate_system_lcp,
    solve_lcp,
)

# ------------------------------------------------------------------ the 2-DOF test system --
# x1 on a spring to ground and to x2; a wall x1 <= 0.5 (e = 0.8) and a two-sided clearance
# |x1 - x2| <= 0.4 (e = 0.6); light damping; 1.0 cos(1.3 t) on x1. From rest the first impacts
# are clean (no grazing): wall at t = 1.4929 (U = -0.072), gap at t = 2.1488 (U = -1.155).
MM = np.diag([1.0, 0.5])
KM = np.array([[2.0, -1.0], [-1.0, 1.0]])
CM = 0.02 * KM + np.diag([0.03, 0.0])
F, OM = 1.0, 1.3
# (gradient of the gap on q, limit, side (+1 lower, -1 upper), restitution)
STOPS = [
    (np.array([1.0, 0.0]), 0.5, -1, 0.8),
    (np.array([1.0, -1.0]), -0.4, 1, 0.6),
    (np.array([1.0, -1.0]), 0.4, -1, 0.6),
]


def two_dof() -> System:
    return System.from_matrices(
        MM.tolist(),
        CM.tolist(),
        KM.tolist(),
        forcing=[f"{F}*cos({OM}*t)", 0],
        elements=[
            stop("x1", -sp.oo, 0.5, restitution=0.8, name="wall"),
            stop("x1 - x2", -0.4, 0.4, restitution=0.6, name="gap"),
        ],
    )


def event_reference(y0, t0, t1, max_impacts=200):
    """DOP853 (rtol = atol = 1e-12) between impacts, each impact a terminal event of its gap,
    Newton's law U+ = -e U- applied by hand along the contact's own direction; returns the
    dense segments and the impacts (t, stop index, pre-impact normal velocity)."""
    Minv = np.linalg.inv(MM)

    def rhs(t, y):
        q, v = y[:2], y[2:]
        load = np.array([F * math.cos(OM * t), 0.0])
        return np.concatenate([v, Minv @ (load - CM @ v - KM @ q)])

    events = []
    for c, lim, side, _e in STOPS:

        def gap(t, y, c=c, lim=lim, side=side):
            return side * (c @ y[:2] - lim)

        gap.terminal = True
        gap.direction = -1
        events.append(gap)
    segments, impacts = [], []
    t, y = float(t0), np.array(y0, dtype=float)
    for _ in range(max_impacts):
        sol = solve_ivp(
            rhs,
            (t, t1),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=events,
            dense_output=True,
        )
        segments.append((t, sol.sol))
        if sol.status == 0:
            return segments, impacts
        k = next(i for i, te in enumerate(sol.t_events) if te.size)
        t, y = float(sol.t_events[k][0]), sol.y_events[k][0].copy()
        c, _lim, side, e = STOPS[k]
        n = side * c
        U = float(n @ y[2:])
        y[2:] += Minv @ n * (-(1.0 + e) * U / float(n @ Minv @ n))
        impacts.append((t, k, U))
    raise AssertionError("the reference met more impacts than expected")


def evaluate(segments, ts):
    starts = np.array([s for s, _ in segments])
    idx = np.clip(np.searchsorted(starts, ts, side="right") - 1, 0, len(segments) - 1)
    return np.array([segments[i][1](t) for i, t in zip(idx, ts, strict=True)])


def max_position_error(h, t1):
    segments, _ = event_reference([0, 0, 0, 0], 0.0, t1)
    traj = simulate_system_lcp(two_dof(), [0, 0, 0, 0], (0.0, t1), h)
    ref = evaluate(segments, traj.t)
    return float(np.abs(traj.y[:, :2] - ref[:, :2]).max()), traj


# ---------------------------------------------------------------------------- accuracy --
def test_reference_has_clean_impacts():
    """The oracle's own premise: two impacts before t = 3, both transversal."""
    _, impacts = event_reference([0, 0, 0, 0], 0.0, 3.0)
    assert [k for _, k, _ in impacts] == [0, 1]
    assert impacts[0][0] == pytest.approx(1.4929, abs=1e-3)
    assert min(abs(u) for _, _, u in impacts) > 0.05


def test_first_order_with_impacts():
    """Positions converge at first order through two impacts (Moreau–Jean places an impact
    at a step's end): the slope fitted over h = T/500 .. T/8000 is about 1, and the error at
    the finest step is below 1e-3. (Measured: order 0.83 over h = 0.012 .. 0.0001875 with
    two more steps, errors 6.8e-3 .. 3.1e-4; the error is erratic by a factor ~2 with the
    impact's phase within its step.)"""
    t1 = 3.0
    hs = [t1 / n for n in (500, 1000, 2000, 4000, 8000)]
    errs = [max_position_error(h, t1)[0] for h in hs]
    order = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert 0.6 < order < 1.5, (order, errs)
    assert errs[-1] < 1e-3
    assert errs[-1] < errs[0] / 5.0


def test_second_order_before_the_first_impact():
    """Before any contact the scheme is the trapezoidal rule: second order (fitted slope
    within 0.2 of 2) and the error at h = 1.4/4000 is below 1e-7."""
    t1 = 1.4  # the wall is first reached at t = 1.4929
    hs = [t1 / n for n in (500, 1000, 2000, 4000)]
    errs = []
    for h in hs:
        err, traj = max_position_error(h, t1)
        assert traj.n_lcp == 0  # no contact entered the LCP
        errs.append(err)
    order = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert abs(order - 2.0) < 0.2, (order, errs)
    assert errs[-1] < 1e-7


def test_penetration_is_of_order_h():
    """Velocity-level contact: the gaps may go negative by O(h |U|), no more."""
    for h in (0.006, 0.0015):
        traj = simulate_system_lcp(two_dof(), [0, 0, 0, 0], (0.0, 3.0), h)
        gaps = traj.gaps(two_dof())
        assert np.nanmin(gaps) > -2.0 * h * 1.2  # |U| <= 1.2 at these impacts


def test_pwl_springs_second_order_against_the_exact_flow():
    """nsd2 (a negative-stiffness PWL spring with kinks at x1 = +-1) with a stop that is never
    reached: the elements enter through their exact Jacobian, linearised about y_k, so the
    kinks cost no order. Against the exact closed-form flow (AffineExactFlow, no stop) over 3
    periods from rest: fitted order 2.05 measured over h = T/100 .. T/1600 (1.5e-2 .. 4.6e-5)."""
    spec = BUILTIN_SYSTEMS["nsd2"]
    free = System.parse(list(spec.equations), dict(spec.defaults))
    far = [stop("x2", -1e2, 1e2)]
    walled = System.parse(list(spec.equations), dict(spec.defaults), elements=far)
    flow = make_flow(free, method="exact")
    T = flow.period
    hs = [T / n for n in (100, 200, 400, 800)]
    errs = []
    for h in hs:
        traj = simulate_system_lcp(walled, [0, 0, 0, 0], (0.0, 3 * T), h)
        exact = flow([0, 0, 0, 0], 0.0, 3 * T, t_eval=traj.t)
        assert np.abs(traj.y[:, 0]).max() > 2.0  # the kinks at |x1| = 1 are crossed
        errs.append(np.abs(traj.y[:, :2] - exact.ys[:, :2]).max())
    order = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    assert 1.7 < order < 2.5, (order, errs)
    assert errs[-1] < 3e-4


def test_first_order_state_with_a_stop():
    """A second-order coordinate coupled to a first-order state (``p' + p - x/2 = 0``, the
    [M D] form with D != 0) and a stop |x| <= 0.6 with restitution 0.5: 5 impacts on [0, 12]
    in the event-located reference (written here). The stepper converges to it (max error
    of x and p 2.1e-2, 8.1e-3, 7.6e-3, 4.1e-3 measured for h = 12/1000 .. 12/8000), and p,
    which no impulse reaches, stays continuous (steps of O(h))."""
    sys_ = System.parse(
        ["x'' + 0.1*x' + x - p = 1.2*cos(t)", "p' + p - 0.5*x = 0"],
        elements=[stop("x", -0.6, 0.6, restitution=0.5)],
    )
    assert sys_.state_names == ("x", "x'", "p")

    def rhs(t, y):
        x, v, p = y
        return [v, 1.2 * math.cos(t) - 0.1 * v - x + p, -p + 0.5 * x]

    events = []
    for lim, side in ((0.6, -1), (-0.6, 1)):

        def g(t, y, lim=lim, side=side):
            return side * (y[0] - lim)

        g.terminal = True
        g.direction = -1
        events.append(g)
    t, y, segments, impacts = 0.0, np.zeros(3), [], 0
    while True:
        sol = solve_ivp(
            rhs, (t, 12.0), y, method="DOP853", rtol=1e-12, atol=1e-12, events=events,
            dense_output=True,
        )  # fmt: skip
        segments.append((t, sol.sol))
        if sol.status == 0:
            break
        k = next(i for i, te in enumerate(sol.t_events) if te.size)
        t, y = float(sol.t_events[k][0]), sol.y_events[k][0].copy()
        y[1] *= -0.5
        impacts += 1
        assert impacts < 20
    assert impacts == 5
    errs = []
    for h in (12 / 1000, 12 / 8000):
        traj = simulate_system_lcp(sys_, [0, 0, 0], (0.0, 12.0), h)
        ref = evaluate(segments, traj.t)
        errs.append(np.abs(traj.y[:, [0, 2]] - ref[:, [0, 2]]).max())
        assert np.abs(np.diff(traj.y[:, 2])).max() < 2 * h
    assert errs[1] < 1e-2 and errs[1] < errs[0] / 3, errs


# ------------------------------------------------------------ impacts: exact outcomes --
def balls(e: float = 1.0) -> System:
    """Three unit point masses on a line, free flight, contacts x2 - x1 >= 0, x3 - x2 >= 0."""
    z = [[0, 0, 0]] * 3
    return System.from_matrices(
        np.eye(3).tolist(),
        z,
        z,
        elements=[
            stop("x2 - x1", 0, sp.oo, restitution=e, name="a"),
            stop("x3 - x2", 0, sp.oo, restitution=e, name="b"),
        ],
    )


def test_simultaneous_contacts_three_balls():
    """Ball 1 (v = 1) hits balls 2 and 3 at rest in contact: both contacts close in one step
    and one LCP with the coupled Delassus matrix [[2, -1], [-1, 2]] gives Moreau's outcome,
    solved by hand: U_a+ = 1, U_b+ = 0, impulses 4/3 and 2/3, velocities (-1/3, 2/3, 2/3);
    momentum and kinetic energy are conserved."""
    traj = simulate_system_lcp(balls(), [-0.01, 0, 0, 1, 0, 0], (0.0, 0.3), 0.03)
    v = traj.y[-1, 3:]
    np.testing.assert_allclose(v, [-1 / 3, 2 / 3, 2 / 3], atol=1e-14)
    k = int(np.flatnonzero(traj.impulses.any(axis=1))[0])
    np.testing.assert_allclose(traj.impulses[k], [4 / 3, 2 / 3], atol=1e-14)
    assert traj.impulses[k + 1 :].max() == 0.0  # separating afterwards
    assert np.all(np.abs(traj.y[:, 3:].sum(axis=1) - 1.0) < 1e-14)
    assert 0.5 * float(v @ v) == pytest.approx(0.5, abs=1e-14)


@pytest.mark.parametrize("e", [0.0, 0.5, 1.0])
def test_two_free_masses_momentum_and_restitution(e):
    """Masses 1 and 3 in a clearance |x1 - x2| <= 0.1: internal impacts conserve momentum to
    rounding; each impact reverses the relative velocity times e (closed form of a two-body
    collision), so the kinetic energy after the first impact is the momentum's share plus
    e^2 times the relative part."""
    m1, m2 = 1.0, 3.0
    sys_ = System.from_matrices(
        [[m1, 0], [0, m2]],
        [[0, 0], [0, 0]],
        [[0, 0], [0, 0]],
        elements=[stop("x1 - x2", -0.1, 0.1, restitution=e)],
    )
    v1, v2 = 1.0, -0.2
    traj = simulate_system_lcp(sys_, [0, 0, v1, v2], (0.0, 0.5), 1e-3)
    p = m1 * traj.y[:, 2] + m2 * traj.y[:, 3]
    assert np.abs(p - (m1 * v1 + m2 * v2)).max() < 1e-13
    k = int(np.flatnonzero(traj.impulses.any(axis=1))[0])
    vr = traj.y[k, 2] - traj.y[k, 3]
    assert vr == pytest.approx(-e * (v1 - v2), abs=1e-13)
    mu = m1 * m2 / (m1 + m2)
    assert traj.impulses[k].sum() == pytest.approx(mu * (1 + e) * (v1 - v2), abs=1e-13)
    ke = 0.5 * (m1 * traj.y[k, 2] ** 2 + m2 * traj.y[k, 3] ** 2)
    vc = (m1 * v1 + m2 * v2) / (m1 + m2)
    assert ke == pytest.approx(0.5 * (m1 + m2) * vc**2 + 0.5 * mu * (e * (v1 - v2)) ** 2, abs=1e-13)


def oscillator_with_walls(e: float) -> System:
    """Two undamped coupled masses between walls x1 >= -0.3 and x2 <= 0.3."""
    return System.from_matrices(
        [[1, 0], [0, 2]],
        [[0, 0], [0, 0]],
        [[2, -1], [-1, 1]],
        elements=[
            stop("x1", -0.3, sp.oo, restitution=e, name="w1"),
            stop("x2", -sp.oo, 0.3, restitution=e, name="w2"),
        ],
    )


def energy(y):
    q, v = y[:, :2], y[:, 2:]
    K = np.array([[2.0, -1.0], [-1.0, 1.0]])
    return 0.5 * (v[:, 0] ** 2 + 2 * v[:, 1] ** 2) + 0.5 * np.einsum("ki,ij,kj->k", q, K, q)


def test_energy_elastic_and_dissipative():
    """Undamped structure between walls. The energy balance of the theta = 1/2 step is
    E_{k+1} - E_k = sum_a Lambda_a (U_{a,k+1} + U_{a,k}) / 2 (the trapezoidal rule conserves
    the quadratic energy of a linear structure; the contact impulse works on the mean normal
    velocity). With e = 1 an impulse acts only when U_{k+1} = -U_k, so the energy is conserved
    to rounding through every impact (Acary 2016 for Moreau–Jean); with e = 0 the work is
    -Lambda |U_k| / 2 <= 0: the energy never increases and every impact removes some. theta = 1
    dissipates between impacts (numerical damping), but its impact work is Lambda U_{k+1} =
    e Lambda |U_k| >= 0: an elastic impact *gains* energy there (checked: a known property of
    the scheme, documented in the module)."""
    y0 = [0.0, 0.0, 1.0, -0.6]
    traj = simulate_system_lcp(oscillator_with_walls(1.0), y0, (0.0, 20.0), 2e-3)
    assert int(np.count_nonzero(traj.impulses.sum(axis=1) > 0)) >= 10
    E = energy(traj.y)
    assert np.abs(E - E[0]).max() < 1e-12 * E[0]
    traj = simulate_system_lcp(oscillator_with_walls(0.0), y0, (0.0, 20.0), 1e-3)
    E = energy(traj.y)
    assert np.diff(E).max() < 1e-12 * E[0]
    hit = traj.impulses.sum(axis=1) > 0
    U = np.abs(traj.y[:-1, 2:]).max(axis=1)  # |U_k| of a wall contact is |x1'| or |x2'|
    impacts = hit[1:] & (U > 1e-3)
    assert np.count_nonzero(impacts) >= 3  # the check below must see the run's impacts
    assert np.all(np.diff(E)[impacts] < -1e-6)
    assert E[-1] < 0.9 * E[0]
    traj = simulate_system_lcp(oscillator_with_walls(1.0), y0, (0.0, 20.0), 2e-3, theta=1.0)
    E = energy(traj.y)
    hit = traj.impulses[1:].sum(axis=1) > 0
    assert np.diff(E)[~hit].max() < 0.0 and np.diff(E)[hit].max() > 0.0
    assert E[-1] < 0.99 * E[0]


def test_resting_contact_impulse_is_h_times_the_load():
    """A unit mass pushed onto the stop x >= 0 by a constant load 0.7: it stays at rest, and
    the stop's impulse in every step is exactly h * 0.7 (the contact force equals the load);
    a plastic impact at speed 2 has the percussion 2 (m |U| (1 + e))."""
    sys_ = System.from_matrices([[1]], [[0]], [[0]], forcing=[-0.7], elements=[stop("x1", 0, 5)])
    traj = simulate_system_lcp(sys_, [0.0, 0.0], (0.0, 1.0), 0.01)
    assert np.abs(traj.y).max() < 1e-15
    np.testing.assert_allclose(traj.impulses[1:, 0], 0.01 * 0.7, rtol=1e-13)
    free = System.from_matrices([[1]], [[0]], [[0]], elements=[stop("x1", 0, 5)])
    traj = simulate_system_lcp(free, [0.005, -2.0], (0.0, 0.05), 0.01)
    assert traj.impulses[:, 0].sum() == pytest.approx(2.0, abs=1e-13)
    assert traj.y[-1, 1] == 0.0


# ----------------------------------------------------------------------------- friction --
@pytest.mark.parametrize("push", [0.6, 1.5])
def test_coulomb_stick_and_slide(push):
    """x'' = P - 1 * sign(x') from rest: P < 1 sticks (velocity 0, friction impulse of size
    h P), P > 1 slides with the constant acceleration P - 1 (the trapezoidal rule is exact
    for it)."""
    sys_ = System.from_matrices(
        [[1]], [[0]], [[0]], forcing=[push], elements=[coulomb("x1'", 1.0, name="fr")]
    )
    traj = simulate_system_lcp(sys_, [0.0, 0.0], (0.0, 2.0), 0.01)
    if push < 1.0:
        assert np.abs(traj.y).max() < 1e-14
        np.testing.assert_allclose(np.abs(traj.impulses[1:, 0]), 0.01 * push, rtol=1e-12)
    else:
        np.testing.assert_allclose(traj.y[:, 1], (push - 1.0) * traj.t, atol=1e-12)
        np.testing.assert_allclose(traj.y[:, 0], 0.5 * (push - 1.0) * traj.t**2, atol=1e-12)


def test_friction_and_stop_together():
    """A block pushed by 1.5 against friction level 1 toward the stop x <= 0.2, then resting
    on it: the friction impulse is h (sliding), then the stop holds the net load 0.5 and the
    friction is free to take any value in the box; the position ends on the stop (within
    the O(h) penetration)."""
    sys_ = System.from_matrices(
        [[1]],
        [[0]],
        [[0]],
        forcing=[1.5],
        elements=[coulomb("x1'", 1.0, name="fr"), stop("x1", -1, 0.2, name="s")],
    )
    traj = simulate_system_lcp(sys_, [0.0, 0.0], (0.0, 3.0), 0.01)
    # reached the stop at t = sqrt(2 * 0.2 / 0.5) = 0.894 (free sliding, exact closed form)
    assert abs(traj.y[-1, 0] - 0.2) < 0.01 * 0.9
    assert abs(traj.y[-1, 1]) < 1e-12
    assert [c.name for c in traj.contacts] == ["fr", "s:lower", "s:upper"]
    fr, lower, upper = traj.impulses[-1]
    # resting: the upper stop (force -Lambda) and the friction (force -beta) together balance
    # the load over the step, h * 1.5; the split is not unique, the box and signs are
    assert fr + upper == pytest.approx(0.015, abs=1e-12)
    assert lower == 0.0 and upper >= 0.0 and abs(fr) <= 0.01 + 1e-14


# ------------------------------------------------------------------------- the flow API --
def test_flow_interface():
    sys_ = two_dof()
    flow = SystemLCPFlow(sys_, 0.005)
    assert isinstance(flow, Flow)
    assert flow.n_states == 4
    assert flow.period == pytest.approx(2 * math.pi / OM)
    res = flow([0, 0, 0, 0], 0.0, 3.0, t_eval=[0.0, 1.0, 2.5, 3.0])
    direct = simulate_system_lcp(sys_, [0, 0, 0, 0], (0.0, 3.0), 0.005)
    np.testing.assert_array_equal(res.y, direct.y[-1])
    assert res.ys.shape == (4, 4)
    np.testing.assert_array_equal(res.ys[-1], direct.y[-1])
    assert res.n_events >= 2
    np.testing.assert_allclose(flow.vector_field(0.0, [0, 0, 0, 0]), [0, 0, F, 0])
    with pytest.raises(ParameterError, match="sensitivity"):
        flow([0, 0, 0, 0], 0.0, 1.0, sensitivity=True)
    with pytest.raises(ParameterError, match="t_eval"):
        flow([0, 0, 0, 0], 0.0, 1.0, t_eval=[2.0])


# ---------------------------------------------------------------------------- bad input --
def test_bad_input():
    sys_ = two_dof()
    y0 = [0, 0, 0, 0]
    for h in (0.0, -1e-3, math.nan, "0.1", True):
        with pytest.raises(ParameterError, match="h = "):
            simulate_system_lcp(sys_, y0, (0, 1), h)
    with pytest.raises(ParameterError, match="theta"):
        simulate_system_lcp(sys_, y0, (0, 1), 0.01, theta=0.3)
    with pytest.raises(ParameterError, match="gamma"):
        simulate_system_lcp(sys_, y0, (0, 1), 0.01, gamma=2.0)
    with pytest.raises(ParameterError, match="y0"):
        simulate_system_lcp(sys_, [0, 0], (0, 1), 0.01)
    with pytest.raises(ParameterError, match="y0"):
        simulate_system_lcp(sys_, [0, 0, math.inf, 0], (0, 1), 0.01)
    with pytest.raises(ParameterError, match="t1 > t0"):
        simulate_system_lcp(sys_, y0, (1, 1), 0.01)
    with pytest.raises(ParameterError, match="max_steps"):
        simulate_system_lcp(sys_, y0, (0, 10), 1e-3, max_steps=100)
    with pytest.raises(ParameterError, match="expected a System"):
        simulate_system_lcp("x'' + x = 0", y0, (0, 1), 0.01)
    no_stop = System.from_matrices([[1]], [[0]], [[1]])
    with pytest.raises(ModelError, match="no stop and no friction"):
        simulate_system_lcp(no_stop, [0, 0], (0, 1), 0.01)
    with pytest.raises(ModelError, match="no stop and no friction"):
        SystemLCPFlow(no_stop, 0.01)
    free = System.parse(["x'' + k*x = 0"], elements=[stop("x", -1, 1)])
    with pytest.raises(ParameterError, match="k"):
        simulate_system_lcp(free, [0, 0], (0, 1), 0.01)
    backwards = System.from_matrices([[1]], [[0]], [[1]], elements=[stop("x1", 1, -1)])
    with pytest.raises(ModelError, match="lower"):
        simulate_system_lcp(backwards, [0, 0], (0, 1), 0.01)
    pulls = System.from_matrices(
        [[1]], [[0]], [[1]], elements=[stop("x1", -1, 1, force={"x1": -1})]
    )
    with pytest.raises(ModelError, match="does not act against"):
        simulate_system_lcp(pulls, [0, 0], (0, 1), 0.01)
    on_position = System.from_matrices(
        [[1]], [[0]], [[1]], elements=[coulomb("x1", 1.0, name="bad")]
    )
    with pytest.raises(ModelError, match="velocities"):
        simulate_system_lcp(on_position, [0, 0], (0, 1), 0.01)


# ------------------------------------------------------------------------ Lemke's method --
def brute_force_lcp(M, q):
    """Every complementary basis: the solutions of w = M z + q, 0 <= z ⊥ w >= 0."""
    m = len(q)
    out = []
    for mask in itertools.product([False, True], repeat=m):
        J = np.flatnonzero(mask)
        z = np.zeros(m)
        if J.size:
            try:
                z[J] = np.linalg.solve(M[np.ix_(J, J)], -q[J])
            except np.linalg.LinAlgError:
                continue
        w = M @ z + q
        if z.min() >= -1e-10 and w.min() >= -1e-10:
            out.append(z)
    return out


def test_lemke_against_enumeration():
    """Random P-matrices (symmetric positive definite plus a skew part) of size 1..6: the
    LCP has exactly one solution, which enumeration of the 2^m bases finds; Lemke agrees."""
    rng = np.random.default_rng(7)
    for trial in range(60):
        m = 1 + trial % 6
        A = rng.normal(size=(m, m))
        M = A @ A.T + 0.1 * np.eye(m) + 0.5 * (lambda S: S - S.T)(rng.normal(size=(m, m)))
        q = rng.normal(size=m) * 3
        (z_ref,) = brute_force_lcp(M, q)
        z, w, _ = solve_lcp(M, q)
        np.testing.assert_allclose(z, z_ref, atol=1e-9)
        np.testing.assert_allclose(w, M @ z + q, atol=1e-12)


def test_lemke_degenerate_and_failures():
    # degenerate: q with zeros and equal ratios (a cycling-prone tableau); solution z = 0 + ...
    M = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    z, w, _ = solve_lcp(M, [-1.0, -1.0, 0.0])
    assert z.min() >= 0 and w.min() >= -1e-12 and abs(z @ w) < 1e-12
    assert z[0] + z[1] == pytest.approx(1.0)
    with pytest.raises(PerturbError, match="ray"):
        solve_lcp([[-1.0]], [-1.0])  # w = -z - 1 >= 0 has no solution with z >= 0
    M = np.eye(4) + np.triu(np.ones((4, 4)), 1) * 2
    with pytest.raises(PerturbError, match="max_pivots"):
        solve_lcp(M, -np.ones(4), max_pivots=1)
    with pytest.raises(ParameterError, match="square"):
        solve_lcp([[1.0, 2.0]], [1.0])
