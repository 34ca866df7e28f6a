"""Tests of ``perturb.simulate.step_response`` against oracles written here, never the code's
own earlier output:

* the closed form against ``scipy.signal.step`` of a hand-written state-space model and the
  augmented matrix exponential (``scipy.linalg.expm``) of hand-written matrices, to 1e-12;
  a drifting system (singular ``A``, ``b`` outside its range) against its polynomial solution;
* the exact piecewise-linear vacuum response of the He–Singh mount (ideal and ramped step)
  against ``solve_ivp`` (DOP853, rtol = atol = 1e-12 in scaled units) with event-located knee
  crossings and restarts, written here;
* the free-decoupler mount on the event-driven flow against the historical ``solve_ivp``
  loop of ``derivations/hydraulic_mount.py`` (before it moved onto perturb's solvers), copied
  here as the oracle;
* bad input: clear ``PerturbError`` subclasses naming the value.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.system import System
from perturb.model.system_builtins import (
    builtin_outputs,
    builtin_system,
    mount_outputs,
    mount_system,
)
from perturb.simulate.step_response import METHODS, StepResponse, step_response

# the builtin mount's values (system_builtins._MOUNT; the script's Mount()), SI units
A_r, C1, C2, I_i, R_i = 3.0e-3, 4.0e-11, 4.0e-9, 6.0e6, 9.0e7
P_VAC, C1V, I_d, R_d, V_GAP = 9.0e4, 2.0e-9, 1.5e5, 1.5e7, 7.5e-7
X_FIXED, X_FREE, RISE = -3.7e-3, -2.4e-3, 8.0e-3
KNEE = -P_VAC * C1  # top-chamber compression at which p_1 = -p_vac


def augmented_expm(A, b, y0, times):
    """``y' = A y + b`` from ``y0`` at 0 by the augmented exponential, one per time."""
    n = len(y0)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A, b
    return np.array([(expm(M * t) @ np.append(y0, 1.0))[:n] for t in times])


# --------------------------------------------------------------------------------------------
# closed form
# --------------------------------------------------------------------------------------------
def test_closed_form_matches_scipy_signal_and_expm():
    s = System.parse(
        ["x1'' + 0.1*x1' + 2*x1 - x2 = F", "x2'' + 0.05*x2' + x2 - x1 = 0"], {"F": 1.0}
    )
    t = np.linspace(0.0, 40.0, 2001)
    r = step_response(s, t, method="closed_form", outputs={"rel": "x1 - x2"})
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-2, 1, -0.1, 0], [1, -1, 0, -0.05]], float)
    B = np.array([[0.0], [0.0], [1.0], [0.0]])
    _, y = signal.step((A, B, np.eye(4), np.zeros((4, 1))), T=t)
    assert np.abs(r.states - y).max() < 1e-12 * np.abs(y).max()
    ref = augmented_expm(A, B[:, 0], np.zeros(4), t)
    assert np.abs(r.states - ref).max() < 1e-12 * np.abs(ref).max()
    assert np.abs(r["rel"] - (ref[:, 0] - ref[:, 1])).max() < 1e-12 * np.abs(ref).max()
    # equilibrium K^-1 F and the modes
    np.testing.assert_allclose(r.equilibrium, [1.0, 1.0, 0.0, 0.0], atol=1e-13)
    np.testing.assert_allclose(
        np.sort_complex(r.eigenvalues), np.sort_complex(np.linalg.eigvals(A))
    )
    # the dense solution between samples
    tt = np.array([0.123, 17.77, 39.999])
    assert np.abs(r.trajectory(tt).T - augmented_expm(A, B[:, 0], np.zeros(4), tt)).max() < 1e-12


def test_closed_form_of_the_fixed_decoupler_mount():
    """The linear fixed-decoupler mount (V_i'' I_i + R_i V_i' + V_i (1/C1 + 1/C2) = A_r X/C1)
    and the floating-decoupler lumped ODEs in pressures and flows (a zero eigenvalue: the
    volume C1 p1 + C2 p2 is conserved), against expm of hand-written matrices."""
    t = np.linspace(0.0, 0.8, 801)
    r = step_response(builtin_system("mount_fixed_linear"), t, outputs=dict(mount_outputs(
        decoupler="fixed", vacuum=False)))  # fmt: skip
    assert r.method == "closed_form"
    k = 1.0 / C1 + 1.0 / C2
    A = np.array([[0.0, 1.0], [-k / I_i, -R_i / I_i]])
    b = np.array([0.0, A_r * X_FIXED / C1 / I_i])
    ref = augmented_expm(A, b, np.zeros(2), t)
    scale = np.abs(ref).max(axis=0)
    assert np.max(np.abs(r.states - ref) / scale) < 1e-12
    assert r.equilibrium[0] == pytest.approx(A_r * X_FIXED / C1 / k, rel=1e-13)
    p1 = (A_r * X_FIXED - ref[:, 0]) / C1
    assert np.abs(r["p1"] - p1).max() < 1e-12 * np.abs(p1).max()
    # extrema of p_1: zeros of the flow at n pi / omega_d (the closed form of the paper)
    sigma = R_i / (2 * I_i)
    omega_d = math.sqrt(k / I_i - sigma**2)
    r2 = step_response(builtin_system("mount_fixed_linear"), t, crossings=["V_i'"])
    n = np.arange(1, len(r2.crossings["V_i'"]) + 1)
    assert len(n) >= 10
    assert np.abs(r2.crossings["V_i'"] - n * math.pi / omega_d).max() * omega_d < 1e-10
    # floating decoupler, first-order states (p1, p2, q_i, q_d); p1 jumps by A_r X / C1
    lin = builtin_system("mount_linear", Xa=0.0)
    y0 = np.array([A_r * X_FREE / C1, 0.0, 0.0, 0.0])
    rl = step_response(lin, t, y0=y0, method="closed_form")
    Af = np.array(
        [
            [0.0, 0.0, -1.0 / C1, -1.0 / C1],
            [0.0, 0.0, 1.0 / C2, 1.0 / C2],
            [1.0 / I_i, -1.0 / I_i, -R_i / I_i, 0.0],
            [1.0 / I_d, -1.0 / I_d, 0.0, -R_d / I_d],
        ]
    )
    ref = np.array([expm(Af * tt) @ y0 for tt in t])
    assert np.max(np.abs(rl.states - ref) / np.abs(ref).max(axis=0)) < 1e-12
    assert rl.equilibrium is None  # A singular: no unique equilibrium


def test_closed_form_with_a_drift():
    """``x'' = F`` (A singular, b outside its range): x = F t^2 / 2, x' = F t exactly."""
    s = System.parse(["m*x'' = F"], {"m": 2.0, "F": 3.0})
    t = np.linspace(0.0, 10.0, 11)
    r = step_response(s, t, y0=[1.0, -0.5])
    assert r.method == "closed_form" and r.equilibrium is None
    np.testing.assert_allclose(r.state("x"), 1.0 - 0.5 * t + 0.75 * t**2, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(r.state("x'"), -0.5 + 1.5 * t, rtol=1e-13, atol=1e-13)


# --------------------------------------------------------------------------------------------
# exact piecewise-linear propagation: the vacuum model against DOP853 with located knees
# --------------------------------------------------------------------------------------------
def vacuum_reference(X, times, rise):
    """The fixed-decoupler vacuum mount by ``solve_ivp`` (DOP853, rtol = atol = 1e-12) in
    scaled volumes ``z = V_i / (A_r |X|)``, with terminal events at the knee (and at the end
    of the ramp) and restarts in the other region."""
    vref = abs(A_r * X)

    def x_of(t):
        return X if rise <= 0 else X * min(t / rise, 1.0)

    def knee(t, z):  # > 0: vacuum (the top chamber expanded past p1 = -p_vac)
        return (KNEE - (A_r * x_of(t) - z[0] * vref)) / vref

    def rhs_for(vac):
        def rhs(t, z):
            u = A_r * x_of(t) - z[0] * vref
            p1 = -P_VAC + (u - KNEE) / C1V if vac else u / C1
            p2 = z[0] * vref / C2
            return [z[1], (p1 - p2 - R_i * z[1] * vref) / (I_i * vref)]

        return rhs

    t0, z = 0.0, np.zeros(2)
    vac = knee(0.0, z) > 0
    T = float(times[-1])
    out = np.empty((len(times), 2))
    switches = []
    for _ in range(100):
        ev_knee = lambda t, zz: knee(t, zz)  # noqa: E731
        ev_knee.terminal, ev_knee.direction = True, -1 if vac else 1
        events = [ev_knee]
        if t0 < rise:
            ev_ramp = lambda t, zz: t - rise  # noqa: E731
            ev_ramp.terminal = True
            events.append(ev_ramp)
        sol = solve_ivp(
            rhs_for(vac), (t0, T), z, method="DOP853", rtol=1e-12, atol=1e-12, events=events,
            dense_output=True,
        )  # fmt: skip
        t1 = float(sol.t[-1])
        sel = (times >= t0) & (times <= t1)
        out[sel] = sol.sol(times[sel]).T
        if sol.status == 0:
            break
        z = sol.y[:, -1].copy()
        if sol.t_events[0].size:
            switches.append(t1)
            vac = not vac
        t0 = t1
    return out * vref, np.array(switches)


@pytest.mark.parametrize("rise", [0.0, RISE])
def test_exact_vacuum_response_matches_dop853_with_located_knees(rise):
    t = np.linspace(0.0, 0.6, 1201)
    system = mount_system(decoupler="fixed", rise=rise)
    r = step_response(system, t, method="exact")
    ref, switches = vacuum_reference(X_FIXED, t, rise)
    knees = np.array([e.time for e in r.events if "clock" not in e.label])
    assert len(knees) == len(switches) >= 3
    assert np.abs(knees - switches).max() < 1e-9
    vref = abs(A_r * X_FIXED)
    qref = np.abs(ref[:, 1]).max()
    assert np.abs(r.state("V_i") - ref[:, 0]).max() < 1e-9 * vref
    assert np.abs(r.state("V_i'") - ref[:, 1]).max() < 1e-9 * qref
    assert all(e.kind == "crossing" for e in r.events)
    # vacuum holds p1 near -p_v: the PWL output expression, against the reference's states
    u = A_r * (np.minimum(t / rise, 1.0) * X_FIXED if rise else X_FIXED) - ref[:, 0]
    p1 = np.where(u < KNEE, -P_VAC + (u - KNEE) / C1V, u / C1)
    out = step_response(system, t, method="exact", outputs={"p1": mount_outputs(
        decoupler="fixed", rise=rise)["p1"]})["p1"]  # fmt: skip
    assert np.abs(out - p1).max() < 1e-8 * P_VAC


# --------------------------------------------------------------------------------------------
# event-driven: the free decoupler against the script's historical loop
# --------------------------------------------------------------------------------------------
def historical_mount_loop(X, times, rise, rtol=1e-11):
    """``simulate_mount`` of derivations/hydraulic_mount.py before it called perturb's
    solvers (free decoupler, vacuum): ``solve_ivp`` with terminal events that fire only on
    leaving the current mode, plastic impacts, restarts. States (V_i, q_i, V_d, q_d); the
    plate (position z0 + V_d, z0 = -V_gap) starts on the top stop. Returns p1 at ``times``,
    the event log and the zeros of q_i + q_d after the ramp."""
    z0 = -V_GAP
    T = float(times[-1])
    vref = abs(A_r * X)
    qref = vref * math.sqrt((C1 + C2) / (I_i * C1 * C2))
    atol = 1e-3 * rtol * np.array([vref, qref, vref, qref])

    def x_of(tt):
        return X if rise <= 0.0 else X * np.minimum(np.asarray(tt) / rise, 1.0)

    def dv1(tt, y):
        return A_r * x_of(tt) - y[0] - y[2]

    def pressures(tt, y, vac):
        u = dv1(tt, y)
        p1 = -P_VAC + (u + P_VAC * C1) / C1V if vac else u / C1
        return p1, (y[0] + y[2]) / C2

    def rhs_for(vac, dec):
        def rhs(tt, y):
            p1, p2 = pressures(tt, y, vac)
            dq_i = (p1 - p2 - R_i * y[1]) / I_i
            if dec == 0:
                return [y[1], dq_i, y[3], (p1 - p2 - R_d * y[3]) / I_d]
            return [y[1], dq_i, 0.0, 0.0]

        return rhs

    def terminal(fun, direction):
        fun.terminal, fun.direction = True, direction
        return fun

    y = np.zeros(4)
    vac = dv1(0.0, y) < KNEE
    dec = -1
    log = [(0.0, "vacuum-on")] if vac else []
    p1_out = np.empty(len(times))
    extrema = []
    t0 = 0.0
    for _ in range(500):
        events = [lambda _t, y: y[1] + y[3]]
        kinds = ["extremum"]
        if t0 < rise:
            events.append(terminal(lambda tt, _y: tt - rise, 1))
            kinds.append("ramp-end")
        events.append(terminal(lambda tt, y: dv1(tt, y) - KNEE, 1 if vac else -1))
        kinds.append("vacuum")
        if dec == 0:
            events.append(terminal(lambda _t, y: z0 + y[2] - V_GAP, 1))
            kinds.append("stop-bottom")
            events.append(terminal(lambda _t, y: z0 + y[2] + V_GAP, -1))
            kinds.append("stop-top")
        else:
            events.append(terminal(lambda tt, y, v=vac: np.subtract(*pressures(tt, y, v)), -dec))
            kinds.append("open")
        sol = solve_ivp(
            rhs_for(vac, dec), (t0, T), y, method="DOP853", events=events, dense_output=True,
            rtol=rtol, atol=atol,
        )  # fmt: skip
        t1 = float(sol.t[-1])
        extrema += [te for te in sol.t_events[0] if te > max(t0, rise) + 1e-12 * T]
        last = sol.status == 0
        sel = (times >= t0) & ((times <= t1) if last else (times < t1))
        p1_out[sel] = pressures(times[sel], sol.sol(times[sel]), vac)[0]
        if last:
            break
        te, i = min(
            (float(sol.t_events[i][0]), i) for i in range(1, len(events)) if sol.t_events[i].size
        )
        y = np.array(sol.y_events[i][0], dtype=float)
        kind = kinds[i]
        if kind == "vacuum":
            vac = not vac
            log.append((te, "vacuum-on" if vac else "vacuum-off"))
        elif kind in ("stop-bottom", "stop-top"):
            side = 1 if kind == "stop-bottom" else -1
            y[2], y[3] = side * V_GAP - z0, 0.0
            if side * np.subtract(*pressures(te, y, vac)) > 0:
                dec = side
                log.append((te, kind))
        elif kind == "open":
            dec, y[3] = 0, 0.0
            log.append((te, "open"))
        t0 = te
    return p1_out, log, np.array(extrema)


@pytest.mark.parametrize("rise", [0.0, RISE])
def test_free_decoupler_events_match_the_historical_loop(rise):
    t = np.linspace(0.0, 0.6, 1801)
    system = mount_system(rise=rise)
    outs = dict(mount_outputs(rise=rise))
    r = step_response(
        system, t, outputs=outs, crossings=["flow"], rtol=1e-11, atol=1e-14 * abs(A_r * X_FREE)
    )
    assert r.method == "events"
    p1, log, extrema = historical_mount_loop(X_FREE, t, rise)
    assert np.abs(r["p1"] - p1).max() < 1e-8 * P_VAC
    # the script's event names from ours: knee crossings (direction), lift-off, coming to rest
    ours = []
    for e in r.events:
        if e.kind == "cross" and "clock" not in e.label:
            ours.append((e.time, "vacuum-on" if e.direction > 0 else "vacuum-off"))
        elif e.kind == "lift":
            ours.append((e.time, "open"))
        elif e.kind == "rest" and e.time > 1e-9:
            side = r.trajectory(e.time)[1] > V_GAP
            ours.append((e.time, "stop-bottom" if side else "stop-top"))
    theirs = [ev for ev in log if ev[0] > 0]
    assert [k for _, k in ours] == [k for _, k in theirs]
    assert {"open", "stop-top", "stop-bottom", "vacuum-off"} <= {k for _, k in theirs}
    assert np.abs(np.subtract([a for a, _ in ours], [a for a, _ in theirs])).max() < 1e-9
    ext = r.crossings["flow"]
    ext = ext[ext > rise + 1e-12 * t[-1]]
    assert len(ext) == len(extrema) >= 10
    assert np.abs(ext - extrema).max() < 1e-9
    # the plate stays in its gap, on a stop exactly while resting
    assert np.all(np.abs(r["plate"]) <= V_GAP * (1 + 1e-9))


# --------------------------------------------------------------------------------------------
# choice of solver, outputs, the result object
# --------------------------------------------------------------------------------------------
def test_auto_picks_the_solver_the_model_needs():
    t = np.linspace(0.0, 0.1, 11)
    assert step_response(builtin_system("mount_fixed_linear"), t).method == "closed_form"
    assert step_response(builtin_system("mount_fixed"), t).method == "exact"
    assert step_response(builtin_system("mount"), t, atol=1e-17).method == "events"
    held = step_response(builtin_system("mount"), t, active={"decoupler": -1})
    assert held.method == "exact"
    # the plate held on its top stop (to rounding: a knee crossing is placed on its surface)
    assert np.abs(held.state("V_d")).max() < 1e-12 * V_GAP


def test_outputs_crossings_and_the_result_object():
    s = System.parse(["x'' + 0.2*x' + x = 1"])
    t = np.linspace(0.0, 30.0, 301)
    r = step_response(s, t, outputs={"x": "x", "v": "x'", "over": "Max(x - 1, 0)"}, crossings=["v"])
    # closed form of x'' + 2 z w x' + w^2 x = 1 from rest: extrema at n pi / w_d
    wd = math.sqrt(1.0 - 0.01)
    n = np.arange(1, len(r.crossings["v"]) + 1)
    assert len(n) == int(30.0 * wd / math.pi)
    assert np.abs(r.crossings["v"] - n * math.pi / wd).max() < 1e-12
    x = 1.0 - np.exp(-0.1 * t) * (np.cos(wd * t) + 0.1 / wd * np.sin(wd * t))
    assert np.abs(r["x"] - x).max() < 1e-13
    assert np.abs(r["over"] - np.maximum(x - 1.0, 0.0)).max() < 1e-13
    assert isinstance(r, StepResponse) and set(METHODS) == {
        "auto",
        "closed_form",
        "exact",
        "events",
    }
    text = str(r)
    assert "closed_form" in text and "zeros of v: " in text and "over" in text
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.method = "x"  # type: ignore[misc]
    with pytest.raises(ValueError):
        r.states[0, 0] = 1.0
    with pytest.raises(ModelError, match="'q'"):
        r.state("q")
    # named outputs of the builtins
    assert set(builtin_outputs("mount")) == {"p1", "p2", "flow", "plate"}
    assert builtin_outputs("nsd2") == {}


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------
def _raises(exc, match, *args, **kw):
    with pytest.raises(exc, match=match) as info:
        step_response(*args, **kw)
    assert isinstance(info.value, PerturbError)


def test_bad_input_is_a_clear_error():
    lin = System.parse(["x'' + x = 1"])
    t = np.linspace(0.0, 1.0, 5)
    _raises(ParameterError, r"not strictly increasing: times\[1\]", lin, [0.0, 0.5, 0.5, 1.0])
    _raises(ParameterError, r"not strictly increasing", lin, [1.0, 0.0])
    _raises(ParameterError, "at least two", lin, [0.0])
    _raises(ParameterError, "finite", lin, [0.0, math.nan])
    _raises(ParameterError, "method = 'rk4'", lin, t, method="rk4")
    _raises(ParameterError, r"y0 = .*expected 2 finite numbers", lin, t, y0=[1.0, 2.0, 3.0])
    _raises(ParameterError, "expected a System", "x'' + x = 1", t)
    _raises(ModelError, r"unknown name\(s\) \['y'\]", lin, t, outputs=["y + x"])
    _raises(ParameterError, "only method='events' takes", lin, t, rtol=1e-9)
    _raises(ParameterError, "refine", lin, t, crossings=["x"], refine=0)
    _raises(ParameterError, r"crossings = 5: expected output names", lin, t, crossings=5)
    # a system that is not piecewise linear, for "exact" (and "closed_form")
    duff = System.parse(["x'' + 0.1*x' + x + x**3 = 0"])
    _raises(ModelError, "needs a piecewise-linear system", duff, t, method="exact")
    _raises(ModelError, "needs a piecewise-linear system", duff, t, method="closed_form")
    # closed form of a switching system; exact with a free stop; events with held stops
    _raises(ModelError, "needs a linear system.*V_i", builtin_system("mount_fixed"), t,
            method="closed_form")  # fmt: skip
    _raises(PerturbError, r"stop\(s\).*\['decoupler'\].*method='events'",
            builtin_system("mount"), t, method="exact")  # fmt: skip
    _raises(ParameterError, "finds the contact modes itself", builtin_system("mount"), t,
            method="events", active={"decoupler": -1})  # fmt: skip
    _raises(ParameterError, r"unknown option\(s\) \['tol'\]", builtin_system("mount"), t,
            method="events", tol=1.0)  # fmt: skip
    _raises(ParameterError, "'plate' is not a stop", builtin_system("mount"), t,
            method="exact", active={"plate": -1})  # fmt: skip
    # a forced system has no step response in this sense
    _raises(ModelError, "harmonic inputs", builtin_system("nsd2"), t, method="exact")
    # the mount family's arguments
    for kw, match in (
        ({"decoupler": "loose"}, "decoupler = 'loose'"),
        ({"vacuum": 1}, "vacuum = 1"),
        ({"rise": -1.0}, "rise = -1.0"),
    ):
        with pytest.raises(ParameterError, match=match):
            mount_system(**kw)
    # the events solver's own bound: too few events allowed is its error, not a hang
    with pytest.raises(PerturbError, match="transitions"):
        step_response(builtin_system("mount"), np.linspace(0.0, 0.5, 11), atol=1e-17,
                      max_events=2)  # fmt: skip


def test_event_driven_zeros_do_not_depend_on_the_sampling():
    """The event-driven dense solution is rebuilt per sample interval: the zeros of the flow
    found with 101 and 1001 samples agree, also when an event (the end of the ramp) falls
    exactly on a sample time."""
    for rise in (0.01, RISE):
        system = mount_system(rise=rise)
        flow = {"flow": mount_outputs(rise=rise)["flow"]}
        a, b = (
            step_response(system, np.linspace(0.0, 0.1, n), outputs=flow, crossings=["flow"])
            for n in (101, 1001)
        )
        assert len(a.crossings["flow"]) == len(b.crossings["flow"]) == 3
        assert np.abs(a.crossings["flow"] - b.crossings["flow"]).max() < 1e-10
        assert any(abs(e.time - rise) < 1e-15 for e in a.events)


def test_an_overflowing_closed_form_is_an_error_not_nan():
    system = builtin_system("mount_fixed_linear")
    with np.errstate(all="ignore"), pytest.raises(PerturbError, match="overflows at t = "):
        step_response(system, np.linspace(0.0, 0.1, 11), y0=[1e308] * system.n)
