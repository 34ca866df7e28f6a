"""SystemEventFlow (event-driven flow of n-state piecewise-smooth Systems) against independent
references written here: solve_ivp DOP853 (rtol = atol = 1e-12) with event-located mode
changes and restarts (impacts with restitution, resting on a plastic stop, Coulomb sticking of a
2-DOF system), and finite differences of the period map for the monodromy (saltation at
impacts, crossings, sticking)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from perturb.errors import ParameterError, PerturbError
from perturb.model.system import System, coulomb, step, stop
from perturb.model.system_builtins import builtin_system
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.flows.system_events import EventFlowError, SystemEventFlow
from perturb.simulate.orbits.shooting import periodic_orbit

TIGHT = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-12}


def _fd_monodromy(flow, y0, t0, t1, h=1e-6):
    n = len(y0)
    J = np.zeros((n, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = h
        J[:, i] = (flow(y0 + e, t0, t1).y - flow(y0 - e, t0, t1).y) / (2 * h)
    return J


# ------------------------------------------------------------ impact oscillator (e > 0) --
MU, OMEGA, LOW, HIGH, E = 0.1, 1.3, -1.0, 0.5, 0.7


def _impact_system():
    return System.from_matrices(
        [[1]],
        [[MU]],
        [[1]],
        elements=[stop("x1", LOW, HIGH, restitution=E, name="wall")],
        forcing=["cos(Omega*t)"],
        params={"Omega": OMEGA},
    )


def _impact_reference(y0, t0, t1):
    """x'' + MU x' + x = cos(OMEGA t) between walls LOW <= x <= HIGH, v -> -E v at a wall."""

    def rhs(t, y):
        return [y[1], math.cos(OMEGA * t) - MU * y[1] - y[0]]

    def hit_low(t, y):
        return y[0] - LOW

    def hit_high(t, y):
        return HIGH - y[0]

    hit_low.terminal = hit_high.terminal = True
    hit_low.direction = hit_high.direction = -1
    t, y, impacts = t0, np.array(y0, float), 0
    for _ in range(1000):
        sol = solve_ivp(rhs, (t, t1), y, events=[hit_low, hit_high], **TIGHT)
        if sol.status == 0:
            return sol.y[:, -1], impacts
        which = 0 if sol.t_events[0].size else 1
        t = float(sol.t_events[which][0])
        x, v = sol.y_events[which][0]
        y = np.array([LOW if which == 0 else HIGH, -E * v])
        impacts += 1
    raise AssertionError("too many impacts")


def test_impact_oscillator_matches_event_reference():
    flow = SystemEventFlow(_impact_system(), rtol=1e-12, atol=1e-13)
    T = 2 * math.pi / OMEGA
    y0 = np.array([0.0, 0.0])
    res = flow(y0, 0.0, 6 * T)
    ref, impacts = _impact_reference(y0, 0.0, 6 * T)
    assert impacts >= 6
    assert res.n_events == impacts
    assert np.max(np.abs(res.y - ref)) < 1e-9
    assert {e.kind for e in flow.events} == {"impact"}


def test_impact_orbit_monodromy_matches_finite_differences():
    flow = SystemEventFlow(_impact_system(), rtol=1e-12, atol=1e-13)
    T = flow.period
    settled = flow([0.0, 0.0], 0.0, 40 * T).y
    orb = periodic_orbit(flow, settled)
    # the orbit is a fixed point of the independent reference's period map too
    ref, impacts = _impact_reference(orb.y0, 0.0, T)
    assert impacts == 2
    assert np.max(np.abs(ref - orb.y0)) < 1e-9
    J = _fd_monodromy(flow, orb.y0, 0.0, T)
    assert np.max(np.abs(orb.monodromy - J)) < 1e-7 * max(1.0, np.abs(J).max())
    # each impact's saltation has determinant E**2 (it maps (dx, dv) to (-E dx, -E dv) up to a
    # shear), on top of Liouville's exp(-MU T): two impacts per period
    det = np.linalg.det(orb.monodromy)
    assert det == pytest.approx(E**4 * math.exp(-MU * T), rel=1e-8)


# ----------------------------------------------------------- plastic stop, resting --
F0, OM2 = 0.3, 0.8


def _plastic_system():
    return System.from_matrices(
        [[1]],
        [[0.1]],
        [[1]],
        elements=[stop("x1", -10, 0.5, name="plate")],
        forcing=[f"{F0} + cos(Omega*t)"],
        params={"Omega": OM2},
    )


def _plastic_reference(y0, t1):
    """Free flight until x = 0.5 (v -> 0); resting while the free acceleration
    F0 + cos(OM2 t) - 0.5 pushes into the stop; lift-off at its zero."""

    def rhs(t, y):
        return [y[1], F0 + math.cos(OM2 * t) - 0.1 * y[1] - y[0]]

    def hit(t, y):
        return 0.5 - y[0]

    hit.terminal, hit.direction = True, -1

    def push(t, y):
        return F0 + math.cos(OM2 * t) - 0.5

    push.terminal, push.direction = True, -1
    t, y, log = 0.0, np.array(y0, float), []
    for _ in range(100):
        sol = solve_ivp(rhs, (t, t1), y, events=[hit], **TIGHT)
        if sol.status == 0:
            return sol.y[:, -1], log
        t = float(sol.t_events[0][0])
        y = np.array([0.5, 0.0])
        if push(t, y) <= 0:
            log.append(("impact", t))
            continue
        log.append(("rest", t))
        # resting: x = 0.5, v = 0 exactly; lift-off where the push vanishes
        # (a short max_step: the trivial ODE would let the step jump over two zeros of push)
        sol = solve_ivp(lambda tt, z: [0.0], (t, t1), [0.0], events=[push], max_step=0.05, **TIGHT)
        if sol.status == 0:
            return y, log
        t = float(sol.t_events[0][0])
        log.append(("lift", t))
    raise AssertionError("too many events")


def test_plastic_stop_rests_and_lifts_off_like_reference():
    flow = SystemEventFlow(_plastic_system(), rtol=1e-12, atol=1e-13)
    t1 = 4 * flow.period
    res = flow([0.0, 0.0], 0.0, t1)
    ref, log = _plastic_reference([0.0, 0.0], t1)
    kinds = [e.kind for e in flow.events]
    assert kinds == [k for k, _ in log]
    assert kinds.count("rest") >= 2 and kinds.count("lift") >= 2
    times = np.array([e.t for e in flow.events])
    assert np.max(np.abs(times - np.array([t for _, t in log]))) < 1e-8
    assert np.max(np.abs(res.y - ref)) < 1e-9


# ----------------------------------------------- 2-DOF with Coulomb friction, sticking --
FR, OM3 = 0.45, 0.6


def _friction_system():
    return System.from_matrices(
        [[1, 0], [0, 1]],
        [[0.02, 0], [0, 0.02]],
        [[2, -1], [-1, 2]],
        elements=[coulomb("x2'", FR, name="pad")],
        forcing=["0.8*cos(Omega*t)", 0],
        params={"Omega": OM3},
    )


def _friction_reference(y0, t1):
    """x1'' + .02 x1' + 2 x1 - x2 = .8 cos(OM3 t), x2'' + .02 x2' - x1 + 2 x2 + FR sign(x2') = 0
    with sticking (x2' = 0 while |x1 - 2 x2| <= FR): slip / stick phases by solve_ivp events."""

    def slip(sigma):
        def rhs(t, y):
            return [
                y[2],
                y[3],
                0.8 * math.cos(OM3 * t) - 0.02 * y[2] - 2 * y[0] + y[1],
                -0.02 * y[3] + y[0] - 2 * y[1] - sigma * FR,
            ]

        def zero(t, y):
            return y[3]

        zero.terminal, zero.direction = True, -sigma
        return rhs, [zero]

    def stick_rhs(t, y):
        return [y[2], 0.0, 0.8 * math.cos(OM3 * t) - 0.02 * y[2] - 2 * y[0] + y[1], 0.0]

    def over(t, y):
        return y[0] - 2 * y[1] - FR

    def under(t, y):
        return y[0] - 2 * y[1] + FR

    over.terminal = under.terminal = True
    over.direction, under.direction = 1, -1
    t, y, log = 0.0, np.array(y0, float), []
    sigma = 1 if y[3] > 0 else -1
    for _ in range(1000):
        rhs, ev = slip(sigma)
        sol = solve_ivp(rhs, (t, t1), y, events=ev, **TIGHT)
        if sol.status == 0:
            return sol.y[:, -1], log
        t = float(sol.t_events[0][0])
        y = np.array(sol.y_events[0][0])
        y[3] = 0.0
        need = y[0] - 2 * y[1]
        if abs(need) > FR:
            sigma = 1 if need > 0 else -1
            log.append(("cross", t))
            continue
        log.append(("stick", t))
        sol = solve_ivp(stick_rhs, (t, t1), y, events=[over, under], **TIGHT)
        if sol.status == 0:
            return sol.y[:, -1], log
        which = 0 if sol.t_events[0].size else 1
        t = float(sol.t_events[which][0])
        y = np.array(sol.y_events[which][0])
        sigma = 1 if which == 0 else -1
        log.append(("slip", t))
    raise AssertionError("too many events")


def test_two_dof_friction_matches_stick_slip_reference():
    flow = SystemEventFlow(_friction_system(), rtol=1e-12, atol=1e-13)
    y0 = np.array([1.0, 0.0, 0.0, 0.3])
    t1 = 5 * flow.period
    res = flow(y0, 0.0, t1)
    ref, log = _friction_reference(y0, t1)
    kinds = [e.kind for e in flow.events]
    assert kinds == [k for k, _ in log]
    assert kinds.count("stick") >= 3
    times = np.array([e.t for e in flow.events])
    assert np.max(np.abs(times - np.array([t for _, t in log]))) < 1e-8
    assert np.max(np.abs(res.y - ref)) < 1e-9


def test_friction_orbit_monodromy_matches_finite_differences():
    flow = SystemEventFlow(_friction_system(), rtol=1e-12, atol=1e-13)
    T = flow.period
    settled = flow([1.0, 0.0, 0.0, 0.3], 0.0, 60 * T).y
    orb = periodic_orbit(flow, settled)
    flow(orb.y0, 0.0, T)
    assert "stick" in [e.kind for e in flow.events]
    ref, _ = _friction_reference(orb.y0, T)
    assert np.max(np.abs(ref - orb.y0)) < 1e-9
    J = _fd_monodromy(flow, orb.y0, 0.0, T)
    assert np.max(np.abs(orb.monodromy - J)) < 1e-6 * max(1.0, np.abs(J).max())


# ------------------------------------------------------------------- the mount --
def test_mount_free_decoupler_rests_on_both_stops():
    flow = SystemEventFlow(builtin_system("mount"), rtol=1e-10, atol=1e-18)
    res = flow([0.0, 0.0, 0.0, 0.0], 0.0, 0.2)
    kinds = [e.kind for e in flow.events]
    assert "rest" in kinds and "lift" in kinds
    gap = 2 * builtin_system("mount").params["V_gap"]
    for e in flow.events:
        if e.kind == "rest":  # the plate is on a stop with no flow through it
            assert min(abs(e.y[1]), abs(e.y[1] - gap)) < 1e-15 and e.y[3] == 0.0
    assert 0.0 <= res.y[1] <= gap


# ------------------------------------------------------------------- bad input --
def test_bad_input_is_a_clear_error():
    flow = SystemEventFlow(_impact_system())
    with pytest.raises(EventFlowError, match="violates the stop"):
        flow([0.7, 0.0], 0.0, 1.0)
    with pytest.raises(ParameterError, match="expected 2 finite"):
        flow([0.0], 0.0, 1.0)
    with pytest.raises(ParameterError, match="t1 > t0"):
        flow([0.0, 0.0], 1.0, 0.0)
    with pytest.raises(ParameterError, match="rtol"):
        SystemEventFlow(_impact_system(), rtol=0.0)
    with pytest.raises(ParameterError, match="Omega"):
        SystemEventFlow(builtin_system("belt"), Omega=1.0)
    small = SystemEventFlow(_impact_system(), max_steps=5)
    with pytest.raises(EventFlowError, match="integration steps"):
        small([0.0, 0.0], 0.0, 50.0)
    few = SystemEventFlow(_impact_system(), max_events=2)
    with pytest.raises(PerturbError, match="more than 2 transitions"):
        few([0.0, 0.0], 0.0, 50.0)


# ------------------------------------------------- a crossing and return inside one step --
def test_cross_and_return_inside_one_step_is_found():
    # x'' + x + J H(x - d) = 0 from (0, 1): the orbit pokes 1e-7 beyond d = 1 - 1e-7 for about
    # 9e-4 time units, far shorter than a DOP853 step; closed form on both sides
    d, J = 1 - 1e-7, 1e-3
    system = System.from_matrices([[1]], [[0]], [[1]], elements=[step("x1", d, J, name="bump")])
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-12)
    res = flow([0.0, 1.0], 0.0, 4.0)
    t_in = math.asin(d)
    vc = math.cos(t_in)
    # inside: x = -J + (d + J) cos(tau) + vc sin(tau) until it is back at d
    tau = brentq(lambda u: -J + (d + J) * math.cos(u) + vc * math.sin(u) - d, 1e-9, 1.0, xtol=1e-16)
    t_out = t_in + tau
    v_out = -(d + J) * math.sin(tau) + vc * math.cos(tau)
    u = 4.0 - t_out
    exact = np.array(
        [d * math.cos(u) + v_out * math.sin(u), -d * math.sin(u) + v_out * math.cos(u)]
    )
    times = [e.t for e in flow.events]
    assert [e.kind for e in flow.events] == ["cross", "cross"]
    # the crossing times are ill-conditioned (x' = 4.5e-4 there): state error / x'
    assert times == pytest.approx([t_in, t_out], abs=5e-8)
    assert np.max(np.abs(res.y - exact)) < 1e-9


# ------------------------------------------------------------- starting on a stop --
def test_start_on_a_stop_moving_into_it_or_away():
    flow = SystemEventFlow(_impact_system(), rtol=1e-12, atol=1e-13)
    T = flow.period
    into = flow([HIGH, 0.3], 0.0, T)
    assert flow.events[0].kind == "impact" and flow.events[0].t == 0.0
    ref, _ = _impact_reference([HIGH, -E * 0.3], 0.0, T)
    assert np.max(np.abs(into.y - ref)) < 1e-9
    away = flow([HIGH, -0.3], 0.0, T)
    assert all(e.t > 0.0 for e in flow.events)
    ref, _ = _impact_reference([HIGH, -0.3], 0.0, T)
    assert np.max(np.abs(away.y - ref)) < 1e-9


def test_zero_push_at_the_start_rests_without_chattering():
    # x'' = sin t against the plastic stop x <= 0 from rest: the push is zero at t = 0 and
    # into the stop on (0, pi); after lift-off at pi, x = -sin t - (t - pi), x' = -cos t - 1
    system = System.from_matrices(
        [[1]], [[0]], [[0]], elements=[stop("x1", -100, 0, name="wall")], forcing=["sin(t)"]
    )
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-13, max_events=10)
    res = flow([0.0, 0.0], 0.0, 2 * math.pi)
    # (the initial rest is the starting mode, not a transition)
    assert [e.kind for e in flow.events] == ["lift"]
    assert flow.events[0].t == pytest.approx(math.pi, abs=1e-9)
    assert res.y == pytest.approx([-math.pi, -2.0], abs=1e-9)


# ------------------------------------------- piecewise-linear builtins: the exact flow --
@pytest.mark.parametrize("name", ["nsd2", "impact_pair"])
def test_pwl_builtins_agree_with_exact_affine_flow(name):
    # the closed-form n-dimensional propagator (matrix exponentials, exact saltation) is an
    # independent reference for the switching of PWL elements (no stops, no friction)
    system = builtin_system(name)
    exact = make_flow(system)
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-13)
    y0 = np.array([0.5, -0.2, 0.1, 0.0])
    T = exact.period
    a = exact(y0, 0.0, 2 * T, sensitivity=True)
    b = flow(y0, 0.0, 2 * T, sensitivity=True)
    assert b.n_events >= 6
    assert np.max(np.abs(a.y - b.y)) < 1e-9
    scale = np.abs(a.sensitivity).max()
    assert np.max(np.abs(a.sensitivity - b.sensitivity)) < 1e-9 * scale


def test_bouncing_ball_accumulation_ends_at_rest():
    # x'' = -1 above a floor x >= 0 with e = 0.5 from x = 1 at rest: infinitely many impacts
    # accumulating at t = 3 sqrt(2); the flow stops them at rest_velocity and rests
    system = System.from_matrices(
        [[1]],
        [[0]],
        [[0]],
        elements=[stop("x1", 0, 100, restitution=0.5, name="floor")],
        forcing=["-1"],
    )
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-13)
    res = flow([1.0, 0.0], 0.0, 10.0)
    kinds = [e.kind for e in flow.events]
    assert kinds[-1] == "rest" and set(kinds[:-1]) == {"impact"}
    assert len(kinds) < 60
    assert flow.events[-1].t == pytest.approx(3 * math.sqrt(2), abs=1e-9)
    assert res.y == pytest.approx([0.0, 0.0], abs=1e-12)


def test_a_span_beyond_the_budget_rule_is_refused_at_once():
    """A span of 1e300 would give a step budget of ~1e10 (hours): refused with its size."""
    flow = SystemEventFlow(builtin_system("mount"))
    with pytest.raises(ParameterError, match="t1 - t0 = 1e"):
        flow(np.zeros(4), 0.0, 1e300)


def test_bad_contact_modes_tolerances_and_sample_times_are_named():
    mount = builtin_system("mount")
    with pytest.raises(ParameterError, match="active = 5: expected a mapping"):
        make_flow(mount, active=5)
    with pytest.raises(ParameterError, match="rest_velocity = 'a'"):
        SystemEventFlow(mount, rest_velocity="a")
    with pytest.raises(ParameterError, match="t_eval = 'ab'"):
        SystemEventFlow(mount)(np.zeros(4), 0.0, 0.01, t_eval="ab")
