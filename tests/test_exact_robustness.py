"""Robustness of the exact (reference) solvers: saltation in the monodromy of discontinuous
fields, bounded work (time budget, undamped systems, NaN guards), pool workers that die with
their parent, and all orbits at one frequency.

Oracles are independent of the code under test: ``solve_ivp`` (DOP853, rtol = atol = 1e-12)
with events at the switching surface and restarts, finite differences of that period map,
and closed forms (the determinant of the monodromy).  Every oracle loop is capped.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb.errors import ParameterError
from perturb.model.oscillator import Oscillator
from perturb.simulate.exact_response import exact_branches, exact_frequency_response
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.orbits.shooting import periodic_orbit

_RTOL = _ATOL = 1e-12
_MAX_SEGMENTS = 2000


# --------------------------------------------------------------------------------------------
# the oracle: x'' + c x' + k x + jump(s) = F cos(W t), s = sign(h), h = a x + b x' + d
# --------------------------------------------------------------------------------------------
def _period_map(
    y0,
    *,
    c,
    k,
    F,
    W,
    surface,
    jump,
    friction=False,
    periods=1,
    reversals=None,
    span=None,
    crossings=None,
):
    """The state after ``periods`` forcing periods, by DOP853 on each smooth piece with a
    terminal event at the surface and a restart on the other side.  With ``friction`` the
    surface is x' = 0 and a state there with |F cos - k x| <= r (r = jump(+1)) sticks
    (x constant) until the drive exceeds r.  ``reversals`` (a list) receives the
    accelerations (a_before, a_after) at every transversal crossing."""
    a_s, b_s, d_s = surface
    T = 2.0 * math.pi / W
    t, t1 = (0.0, periods * T) if span is None else span
    y = np.array(y0, float)

    def h(z):
        return a_s * z[0] + b_s * z[1] + d_s

    def acc(tt, z, s):
        return F * math.cos(W * tt) - c * z[1] - k * z[0] - jump(s)

    s = 1.0 if h(y) > 0 else -1.0
    stuck = False
    r_stick = jump(1.0)
    for _ in range(_MAX_SEGMENTS):
        if t >= t1:
            return y
        if stuck:

            def unstick(tt, z, r=r_stick):
                return abs(F * math.cos(W * tt) - k * z[0]) - r

            unstick.terminal, unstick.direction = True, 1
            sol = solve_ivp(
                lambda tt, z: [0.0, 0.0],
                (t, t1),
                y,
                method="DOP853",
                rtol=_RTOL,
                atol=_ATOL,
                events=[unstick],
                max_step=T / 512,
            )
            if sol.status != 1:
                return sol.y[:, -1].copy()
            t = float(sol.t_events[0][0])
            y = np.array([y[0], 0.0])
            s = 1.0 if F * math.cos(W * t) - k * y[0] > 0 else -1.0
            stuck = False
            continue

        def ev(tt, z):
            return h(z)

        ev.terminal, ev.direction = True, -s
        events = [ev]
        if b_s == 0.0:
            # closest approach to a surface in x (h' = a_s x' turning back): solve_ivp only
            # compares signs at step ends, so an excursion across the surface and back inside
            # one step is caught here, beyond the surface, and then redone in short steps
            def turn(tt, z, s=s, t_start=t):
                # masked at the start (a restart at a turning point is not a new one)
                return s * a_s * z[1] if tt > t_start + 1e-12 * T else 1.0

            turn.terminal, turn.direction = True, 1
            events.append(turn)
        fun = lambda tt, z, s=s: [z[1], acc(tt, z, s)]  # noqa: E731
        sol = solve_ivp(fun, (t, t1), y, method="DOP853", rtol=_RTOL, atol=_ATOL, events=events)
        if sol.status != 1:
            return sol.y[:, -1].copy()
        if len(events) == 2 and len(sol.t_events[1]) and not len(sol.t_events[0]):
            t_turn = float(sol.t_events[1][0])
            y_turn = np.array(sol.y_events[1][0], float)
            if s * h(y_turn) >= 0.0:
                t, y = t_turn, y_turn  # turned back inside: nothing happened
                continue
            sol = solve_ivp(
                fun,
                (t, t_turn),
                y,
                method="DOP853",
                rtol=_RTOL,
                atol=_ATOL,
                events=[ev],
                max_step=(t_turn - t) / 2000.0,
            )
            if not len(sol.t_events[0]):
                raise RuntimeError("oracle: lost a crossing")
        t = float(sol.t_events[0][0])
        y = np.array(sol.y_events[0][0], float)
        if friction:
            y[1] = 0.0
            if abs(F * math.cos(W * t) - k * y[0]) <= jump(1.0):
                stuck = True
                continue
        if reversals is not None:
            reversals.append((acc(t, y, s), acc(t, y, -s)))
        if crossings is not None:
            crossings.append(y.copy())
        s = -s
    raise RuntimeError(f"oracle: more than {_MAX_SEGMENTS} segments")


def _fd_monodromy(y0, h=1e-6, **kw):
    cols = []
    for e in np.eye(2):
        cols.append((_period_map(y0 + h * e, **kw) - _period_map(y0 - h * e, **kw)) / (2 * h))
    return np.column_stack(cols)


# --------------------------------------------------------------------------------------------
# 1. saltation at velocity reversals (Coulomb friction)
# --------------------------------------------------------------------------------------------
C, R, F = 0.1, 0.3, 1.0
COULOMB = f"x'' + {C}*x' + x + {R}*sign(x') = {F}*cos(Omega*t)"


def _coulomb_kw(W):
    return dict(c=C, k=1.0, F=F, W=W, surface=(0.0, 1.0, 0.0), jump=lambda s: R * s, friction=True)


def test_flow_family_of_a_friction_oscillator_is_event_driven():
    fam = FlowFamily(Oscillator.parse(COULOMB))
    assert fam.event and not fam.exact
    # the flows at two values share the compiled modes but not the frequency
    f1, f2 = fam.at(0.8), fam.at(1.3)
    assert f1.period == pytest.approx(2 * math.pi / 0.8, rel=1e-15)
    assert f2.period == pytest.approx(2 * math.pi / 1.3, rel=1e-15)
    y1 = f1([1.0, 0.5], 0.0, 3.0).y
    y2 = f2([1.0, 0.5], 0.0, 3.0).y
    assert np.max(np.abs(y1 - y2)) > 1e-3


@pytest.mark.parametrize("W", [0.8, 1.3, 2.0])
def test_coulomb_monodromy_matches_finite_differences_and_determinant(W):
    flow = FlowFamily(Oscillator.parse(COULOMB)).at(W)
    T = 2 * math.pi / W
    orbit = periodic_orbit(flow, [2.0, 0.0])
    y0 = np.array(orbit.y0)
    kw = _coulomb_kw(W)
    rev: list[tuple[float, float]] = []
    y1 = _period_map(y0, reversals=rev, **kw)
    assert np.max(np.abs(y1 - y0)) < 1e-9  # a periodic orbit of the oracle too
    assert len(rev) == 2  # two velocity reversals, no sticking
    M_fd = _fd_monodromy(y0, **kw)
    M = flow(y0, 0.0, T, sensitivity=True).sensitivity
    assert np.max(np.abs(M - M_fd)) < 1e-6 * max(1.0, np.max(np.abs(M_fd)))
    # det M = e^(-cT) prod(a+/a-) over the reversals (Liouville and the saltation matrices)
    det = math.exp(-C * T) * np.prod([a1 / a0 for a0, a1 in rev])
    assert np.linalg.det(M) == pytest.approx(det, rel=1e-8)
    mu_fd = np.max(np.abs(np.linalg.eigvals(M_fd)))
    assert orbit.max_multiplier == pytest.approx(mu_fd, rel=1e-6)
    # ... and it is not the value without friction, e^(-cT/2), that the smooth flow reported
    # (at W = 1.0 both happen to be close; these frequencies differ by 10-40 %)
    assert abs(orbit.max_multiplier - math.exp(-C * T / 2)) > 0.05


def test_coulomb_sticking_orbit_has_a_singular_monodromy():
    W = 0.5
    flow = FlowFamily(Oscillator.parse(COULOMB)).at(W)
    orbit = periodic_orbit(flow, [2.0, 0.0])
    y0 = np.array(orbit.y0)
    kw = _coulomb_kw(W)
    assert np.max(np.abs(_period_map(y0, **kw) - y0)) < 1e-9
    M_fd = _fd_monodromy(y0, **kw)
    M = flow(y0, 0.0, 2 * math.pi / W, sensitivity=True).sensitivity
    assert np.max(np.abs(M - M_fd)) < 1e-6
    # sticking forgets the velocity: rank one
    assert abs(np.linalg.det(M_fd)) < 1e-6 and abs(np.linalg.det(M)) < 1e-9


# --------------------------------------------------------------------------------------------
# 2. saltation at jumps of a force discontinuous in x (Heaviside step)
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "equation,exact",
    [
        # piecewise linear: the exact propagator
        ("x'' + 0.1*x' + x + 0.5*Heaviside(x - 0.3) = cos(Omega*t)", True),
        # not piecewise linear (a cubic term): the event-driven flow
        ("x'' + 0.1*x' + x + 0.1*x**3 + 0.5*Heaviside(x - 0.3) = cos(Omega*t)", False),
    ],
)
def test_heaviside_step_monodromy_matches_finite_differences(equation, exact):
    W = 1.1
    fam = FlowFamily(Oscillator.parse(equation))
    assert fam.exact == exact and (fam.event or exact)
    flow = fam.at(W)
    orbit = periodic_orbit(flow, [2.0, 0.0])
    y0 = np.array(orbit.y0)
    cubic = 0.1 if not exact else 0.0
    # the cubic term is smooth: fold it into the oracle's field through jump's argument
    kw = dict(c=0.1, k=1.0, F=1.0, W=W, surface=(1.0, 0.0, -0.3))

    def run(y, reversals=None):
        return _period_map_cubic(y, cubic, reversals=reversals, **kw)

    rev: list[tuple[float, float]] = []
    assert np.max(np.abs(run(y0, rev) - y0)) < 1e-9
    assert len(rev) == 2
    h = 1e-6
    M_fd = np.column_stack([(run(y0 + h * e) - run(y0 - h * e)) / (2 * h) for e in np.eye(2)])
    M = flow(y0, 0.0, 2 * math.pi / W, sensitivity=True).sensitivity
    assert np.max(np.abs(M - M_fd)) < 1e-6 * max(1.0, np.max(np.abs(M_fd)))
    # det S = v+/v- = 1 at a jump in x (x' is continuous), so det M = e^(-cT): the
    # saltation shows in M itself, not in its determinant
    assert np.linalg.det(M) == pytest.approx(math.exp(-0.1 * 2 * math.pi / W), rel=1e-8)


def _period_map_cubic(y0, cubic, *, c, k, F, W, surface, reversals=None):
    """As _period_map for x'' + c x' + k x + cubic x^3 + 0.5 H(x - 0.3) = F cos(W t)."""
    a_s, b_s, d_s = surface
    T = 2.0 * math.pi / W
    t, t1 = 0.0, T
    y = np.array(y0, float)

    def acc(tt, z, s):
        return F * math.cos(W * tt) - c * z[1] - k * z[0] - cubic * z[0] ** 3 - 0.5 * (s > 0)

    s = 1.0 if a_s * y[0] + b_s * y[1] + d_s > 0 else -1.0
    for _ in range(_MAX_SEGMENTS):
        if t >= t1:
            return y

        def ev(tt, z):
            return a_s * z[0] + b_s * z[1] + d_s

        ev.terminal, ev.direction = True, -s
        sol = solve_ivp(
            lambda tt, z, s=s: [z[1], acc(tt, z, s)],
            (t, t1),
            y,
            method="DOP853",
            rtol=_RTOL,
            atol=_ATOL,
            events=[ev],
        )
        if sol.status != 1:
            return sol.y[:, -1].copy()
        t = float(sol.t_events[0][0])
        y = np.array(sol.y_events[0][0], float)
        if reversals is not None:
            reversals.append((acc(t, y, s), acc(t, y, -s)))
        s = -s
    raise RuntimeError(f"oracle: more than {_MAX_SEGMENTS} segments")


# --------------------------------------------------------------------------------------------
# 3. bounded work: undamped systems, the time budget
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "equation",
    [
        "x'' + x = cos(Omega*t)",  # exact PWL path (took ~250 s and returned 0 branches)
        "x'' + x + x**3 = 0.5*cos(Omega*t)",  # ODE path
        "x'' + x + 0.5*sign(x) = cos(Omega*t)",  # PWL with a jump
    ],
)
def test_undamped_system_is_explained_quickly(equation):
    t = time.perf_counter()
    r = exact_frequency_response(Oscillator.parse(equation), (0.2, 2.0), progress=False)
    assert time.perf_counter() - t < 10.0
    assert len(r.branches) == 0
    assert any("undamped" in n and "damping" in n for n in r.notes)


def test_time_budget_ends_the_search_with_a_note():
    # the friction oscillator's response takes ~40 s serial; 3 s of budget must stop it
    osc = Oscillator.parse(COULOMB)
    t = time.perf_counter()
    eb = exact_branches(osc, (0.2, 2.0), max_seconds=3.0, workers=1, progress=False)
    elapsed = time.perf_counter() - t
    assert elapsed < 20.0
    assert any("time budget" in n for n in eb.notes)
    assert any(b.stop_reason.count("time budget") for b in eb.branches)
    with pytest.raises(ParameterError):
        exact_branches(osc, (0.2, 2.0), max_seconds=float("nan"))
    with pytest.raises(ParameterError):
        exact_branches(osc, (0.2, 2.0), max_seconds=0)


def test_friction_response_is_traced_with_saltation_multipliers():
    """Over a short window (bounded time): one branch, multipliers from the event-driven
    flow, checked against finite differences of the oracle at one point."""
    osc = Oscillator.parse(COULOMB)
    t = time.perf_counter()
    eb = exact_branches(osc, (1.2, 1.4), workers=1, progress=False, sweep_points=6)
    assert time.perf_counter() - t < 120.0
    assert len(eb.branches) == 1
    br = eb.branches[0]
    pt = br.points[len(br) // 2]
    W = float(pt.parameter)
    M_fd = _fd_monodromy(np.array(pt.y0), **_coulomb_kw(W))
    assert pt.max_multiplier == pytest.approx(np.max(np.abs(np.linalg.eigvals(M_fd))), rel=1e-5)
    # max |x| is reached at a velocity reversal, where the acceleration jumps: read there,
    # not interpolated across the jump (a Hermite interpolant of (x, v, a) was off by 3e-6)
    for q in br.points[::10]:
        states: list[np.ndarray] = []
        _period_map(np.array(q.y0), crossings=states, **_coulomb_kw(float(q.parameter)))
        amp = max(abs(y[0]) for y in states)
        # (the statistics come from the iterate before the last correction: STATS_TOL)
        assert q.amplitude == pytest.approx(amp, rel=2e-7), q


# --------------------------------------------------------------------------------------------
# 4. pool workers die with their parent
# --------------------------------------------------------------------------------------------
_CHILD = textwrap.dedent(
    """
    import multiprocessing as mp, sys, threading, time
    from perturb.model.builtins import builtin_model
    from perturb.simulate.exact_response import exact_branches

    def report():
        for _ in range(600):  # capped: 60 s
            kids = mp.active_children()
            if kids:
                print(" ".join(str(k.pid) for k in kids), flush=True)
                return
            time.sleep(0.1)

    threading.Thread(target=report, daemon=True).start()
    osc = builtin_model("nsd").with_params({"k": -3, "mu": 0.05, "F": 2})
    for _ in range(20):  # long enough to be killed while the pool is up
        exact_branches(osc, (0.2, 2.0), workers=2, progress=False)
    """
)


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            state = fh.read().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_pool_workers_die_when_the_parent_is_killed():
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env={**os.environ, "PERTURB_PROGRESS": "0"},
    )
    try:
        line = proc.stdout.readline()  # the child prints within 60 s or exits
        pids = [int(q) for q in line.split()]
        assert pids, "the child started no pool"
        assert all(_alive(p) for p in pids)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    deadline = time.monotonic() + 15.0
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    left = [p for p in pids if _alive(p)]
    for p in left:  # do not leave them behind if the test fails
        os.kill(p, signal.SIGKILL)
    assert not left, f"workers {left} outlived their killed parent"


# --------------------------------------------------------------------------------------------
# 5. all orbits at one frequency include those continuation traces through it
# --------------------------------------------------------------------------------------------
def test_solutions_at_one_frequency_include_the_one_well_orbits():
    """nsd, k = -2, Omega = 1.5: the one-well orbits are the linear responses of the outer
    segments, x = +-3 + A cos(Omega t - phi) with A = F / |1 - Omega^2 + i mu Omega|
    (closed form; x stays beyond +-1), stable; the saddle-type in-well orbit as well."""
    from perturb.model.builtins import builtin_model
    from perturb.simulate.exact_response import exact_solutions_at

    k, mu, F_, W = -2.0, 0.05, 2.0, 1.5
    osc = builtin_model("nsd", k=k, mu=mu, F=F_)
    resp = exact_solutions_at(osc, [W], progress=False)
    rows = resp.rows()
    A = F_ / abs(complex(1.0 - W * W, mu * W))
    assert 3.0 - A > 1.0  # the closed form is an orbit of the whole system
    wells = [r for r in rows if abs(abs(r["mean"]) - 3.0) < 1e-6]
    assert len(wells) == 2 and {round(r["mean"]) for r in wells} == {-3, 3}
    for r in wells:
        assert r["amplitude"] == pytest.approx(3.0 + A, rel=1e-9)
        assert r["stable"]
    # the in-well orbit: the linear response of the middle segment (slope k), unstable
    A0 = F_ / abs(complex(k - W * W, mu * W))
    assert any(r["amplitude"] == pytest.approx(A0, rel=1e-9) and not r["stable"] for r in rows)
    # no orbit twice
    keys = sorted((round(r["amplitude"], 8), round(r["mean"], 8)) for r in rows)
    assert len(keys) == len(set(keys))


def test_solutions_at_one_frequency_from_the_traced_branches_alone(monkeypatch):
    """With the brute-force search returning nothing, the crossings of the traced branches
    still give the three orbits of nsd (k = -2) at Omega = 1.5 (closed forms as above)."""
    import perturb.simulate.orbits.search as orbits_module
    from perturb.model.builtins import builtin_model
    from perturb.simulate.exact_response import exact_solutions_at

    monkeypatch.setattr(orbits_module, "periodic_orbits", lambda *a, **k: ())
    k, mu, F_, W = -2.0, 0.05, 2.0, 1.5
    resp = exact_solutions_at(builtin_model("nsd", k=k, mu=mu, F=F_), [W], progress=False)
    rows = resp.rows()
    A = F_ / abs(complex(1.0 - W * W, mu * W))
    A0 = F_ / abs(complex(k - W * W, mu * W))
    got = sorted((round(r["amplitude"], 9), round(r["mean"], 9), r["stable"]) for r in rows)
    want = sorted(
        [(round(A0, 9), 0.0, False), (round(3 + A, 9), -3.0, True), (round(3 + A, 9), 3.0, True)]
    )
    assert len(got) == 3
    for g, w_ in zip(got, want, strict=True):
        assert g[0] == pytest.approx(w_[0], rel=1e-8)
        assert g[1] == pytest.approx(w_[1], abs=1e-7)
        assert g[2] == w_[2]


# --------------------------------------------------------------------------------------------
# 6. a relay restoring force, sign(x): marches that creep at the smallest step stop
# --------------------------------------------------------------------------------------------
def _relay_map(y0, W, span):
    """x'' + 0.1 x' + x + 0.5 sign(x) = cos(W t) over ``span`` (DOP853, events at x = 0)."""
    kw = dict(c=0.1, k=1.0, F=1.0, W=W, surface=(1.0, 0.0, 0.0), jump=lambda s: 0.5 * s)
    return _period_map(y0, span=span, **kw)


@pytest.mark.slow
def test_relay_response_is_bounded_and_its_orbits_are_periodic():
    """Issue 18/16: ran past 120 s (a march creeping at ds_min for thousands of steps near a
    zero-speed touch of x = 0); now it ends on its own, well inside the time budget."""
    osc = Oscillator.parse("x'' + 0.1*x' + x + 0.5*sign(x) = cos(Omega*t)")
    t = time.perf_counter()
    eb = exact_branches(osc, (0.2, 2.0), progress=False, max_seconds=250.0)
    assert time.perf_counter() - t < 200.0
    assert not any("time budget" in n for n in eb.notes)
    assert len(eb.branches) >= 4
    checked = 0
    for br in eb.branches:
        pt = br.points[len(br) // 2]
        W = float(pt.parameter)
        T = 2 * math.pi / W
        # node by node (strongly unstable orbits are multiple-shooting solutions: one
        # period from y0 alone amplifies its rounding by up to ~1e7 here)
        Z = np.array(pt.nodes) if pt.nodes is not None else np.array([pt.y0])
        N = len(Z)
        if np.min(np.abs(Z[:, 0])) < 1e-3:
            continue  # a node on the switching surface: the oracle's start is ambiguous
        for i in range(N):
            span = (i * T / N, (i + 1) * T / N)
            y1 = _relay_map(Z[i], W, span)
            assert np.max(np.abs(y1 - Z[(i + 1) % N])) < 1e-7 * max(1.0, np.max(np.abs(Z))), (
                pt,
                i,
            )
        checked += 1
    assert checked >= 4


def test_event_family_over_a_parameter_that_moves_a_switching_surface():
    """The varied parameter sits in a switching argument (Heaviside(x - d)): one event-driven
    flow per value, the same orbit as the frequency family's at the same parameters."""
    eq = "x'' + 0.1*x' + x + 0.1*x**3 + 0.5*Heaviside(x - d) = cos(Omega*t)"
    by_d = FlowFamily(Oscillator.parse(eq, {"Omega": 1.1}), "d")
    by_w = FlowFamily(Oscillator.parse(eq, {"d": 0.3}))
    assert by_d.event and by_w.event
    a = periodic_orbit(by_d.at(0.3), [2.0, 0.0])
    b = periodic_orbit(by_w.at(1.1), [2.0, 0.0])
    assert np.max(np.abs(np.array(a.y0) - np.array(b.y0))) < 1e-9
    assert a.max_multiplier == pytest.approx(b.max_multiplier, rel=1e-8)
    c = periodic_orbit(by_d.at(0.35), [2.0, 0.0])
    assert abs(c.amplitude - a.amplitude) > 1e-4


def test_ode_flow_across_a_jump_ends_with_an_error_instead_of_chattering():
    """DOP853 without events on a sticking friction orbit: millions of tiny steps (one period
    ran past 600 s); the step budget ends it with a clear error."""
    from perturb.errors import PerturbError

    osc = Oscillator.parse(COULOMB)
    flow = FlowFamily(osc, exact=False).at(0.5)
    t = time.perf_counter()
    with pytest.raises(PerturbError, match="step size collapsed"):
        flow([0.5, 0.0], 0.0, 4 * math.pi, sensitivity=True)
    assert time.perf_counter() - t < 60.0
    # a smooth model over 200 periods stays well inside the budget, and matches DOP853
    duff = FlowFamily(Oscillator.parse("x'' + 0.1*x' + x + x**3 = cos(Omega*t)")).at(1.2)
    T = 2 * math.pi / 1.2
    y = duff([0.5, 0.0], 0.0, 200 * T).y
    ref = solve_ivp(
        lambda tt, z: [z[1], math.cos(1.2 * tt) - 0.1 * z[1] - z[0] - z[0] ** 3],
        (0.0, 200 * T),
        [0.5, 0.0],
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
    ).y[:, -1]
    assert np.max(np.abs(y - ref)) < 1e-7
