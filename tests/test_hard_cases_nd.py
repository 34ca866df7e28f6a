"""Hard cases of the exact n-dimensional piecewise-linear flow (issue #15, "Hard cases"):
grazing of two surfaces in two coordinates at the same instant, a gap of 1e-9, a stop 1e6 times
stiffer than the structure, a near-singular and an exactly singular mass matrix. Each ends in
a correct answer, checked against an oracle written here (closed form, or DOP853 with
rtol = atol = 1e-12 on the equations written out by hand, region held fixed between
event-located crossings, restarts), or in a clear PerturbError within a small budget."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from perturb.errors import ModelError, PerturbError
from perturb.model.system import System, gap, stop
from perturb.model.system_builtins import builtin_system
from perturb.simulate.flows.affine_exact import AffineExactFlow, propagate
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.flows.system_lcp import simulate_system_lcp


# ------------------------------------------------------------------------------- oracle --
def pwl_reference(field, surfaces, y0, t0, t1, max_events=20_000, max_step=math.inf):
    """DOP853 (rtol = atol = 1e-12) with the region (the signs of ``c . y - d``) held fixed,
    every surface a terminal event in the direction that leaves the current side, restart on
    the far side. ``field(signs, t, y)`` is the vector field of a region, written by hand.
    solve_ivp sees an event only as a sign change between two steps: a shallow crossing
    shorter than a step is missed unless ``max_step`` is below its duration."""
    C = np.array([c for c, _ in surfaces], dtype=float)
    d = np.array([dd for _, dd in surfaces], dtype=float)
    y = np.array(y0, dtype=float)
    signs = np.where(C @ y - d >= 0.0, 1, -1)
    t = float(t0)
    crossings = []
    for _ in range(max_events):
        events = []
        for j in range(len(surfaces)):

            def g(t, y, j=j, sj=signs[j]):
                return sj * (C[j] @ y - d[j])

            g.terminal = True
            g.direction = -1
            events.append(g)
        sig = tuple(int(s) for s in signs)
        sol = solve_ivp(
            lambda t, y, sig=sig: field(sig, t, y),
            (t, t1),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=events,
            max_step=max_step,
        )
        if sol.status == 0:
            return sol.y[:, -1], crossings
        j = next(i for i, te in enumerate(sol.t_events) if te.size)
        t, y = float(sol.t_events[j][0]), sol.y_events[j][0].copy()
        signs[j] = -signs[j]
        # a second surface crossed at the same instant (to rounding): switch it as well
        other = signs * (C @ y - d) < 0.0
        other[j] = False
        signs[other] = -signs[other]
        crossings.append((t, j))
    raise AssertionError("the reference met more crossings than expected")


def gap_force(s, g, side_up, side_lo):
    """``(s - g)H(s - g) + (s + g)H(-s - g)`` with the region's signs of ``s - g``, ``s + g``."""
    if side_up > 0:
        return s - g
    if side_lo < 0:
        return s + g
    return 0.0


# --------------------------------------------------------------- grazing in two coordinates --
A_GRAZE, K1, K12 = 0.3, 5.0, 7.0
W2 = math.sqrt(3.0)  # the second mode of M = I, K = [[2, -1], [-1, 2]]: shape (1, -1)


def graze_system() -> System:
    """Two unit masses, springs [[2, -1], [-1, 2]], a gap on x1 (clearance 0.3, stiffness 5)
    and a gap on x1 - x2 (clearance 0.6, stiffness 7). The free second mode
    x = A sin(sqrt(3) t) (1, -1) with A = 0.3 reaches x1 = +-0.3 and x1 - x2 = +-0.6 at the
    same instants t_k = (k + 1/2) pi / sqrt(3), tangentially (velocity zero there)."""
    return System.from_matrices(
        [[1, 0], [0, 1]],
        [[0, 0], [0, 0]],
        [[2, -1], [-1, 2]],
        elements=[
            gap("x1", A_GRAZE, K1, name="g1"),
            gap("x1 - x2", 2 * A_GRAZE, K12, name="g12"),
        ],
    )


def mode2(amp, t):
    s, c = math.sin(W2 * t), math.cos(W2 * t)
    return amp * np.array([s, -s, W2 * c, -W2 * c])


def graze_field(signs, t, y):
    q, v = y[:2], y[2:]
    f1 = K1 * gap_force(q[0], A_GRAZE, signs[0], signs[1])
    f12 = K12 * gap_force(q[0] - q[1], 2 * A_GRAZE, signs[2], signs[3])
    acc = -np.array([[2.0, -1.0], [-1.0, 2.0]]) @ q - np.array([f1 + f12, -f12])
    return np.concatenate([v, acc])


GRAZE_SURFACES = [
    ((1, 0, 0, 0), A_GRAZE),
    ((1, 0, 0, 0), -A_GRAZE),
    ((1, -1, 0, 0), 2 * A_GRAZE),
    ((1, -1, 0, 0), -2 * A_GRAZE),
]


def test_double_grazing_at_one_instant():
    """Exact tangency of both gaps at once, three times: the orbit is the free mode (closed
    form) to rounding, and every event is a touch of one of the two gaps at a tangency
    instant t_k, both gaps at each."""
    flow = make_flow(graze_system(), method="exact")
    t1 = 3 * math.pi / W2 + 0.3
    res = propagate(flow.affine_system, mode2(A_GRAZE, 0.0), 0.0, t1)
    np.testing.assert_allclose(res.y, mode2(A_GRAZE, t1), rtol=0, atol=1e-13)
    assert len(res.events) >= 6
    labels = flow.affine_system.surfaces
    by_instant: dict[int, set[str]] = {}
    for ev in res.events:
        k = (ev.time * W2 / math.pi) - 0.5
        assert abs(k - round(k)) < 1e-9, ev.time
        assert ev.tangency
        by_instant.setdefault(round(k), set()).add(labels[ev.surface].label.split(" =")[0])
    assert by_instant == {0: {"x1", "x1 - x2"}, 1: {"x1", "x1 - x2"}, 2: {"x1", "x1 - x2"}}
    # the flow object gives the same state; its sensitivity is the free one (no saltation:
    # the gap forces are continuous), e^{A t1} of the linear structure
    out = flow(mode2(A_GRAZE, 0.0), 0.0, t1, sensitivity=True)
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.array([[2, -1], [-1, 2]]), np.zeros((2, 2))]])
    np.testing.assert_allclose(out.sensitivity, expm(A * t1), atol=1e-12)


def test_double_grazing_shallow_crossings():
    """Amplitude 1 + 1e-6 times the grazing one: each gap is entered by ~3e-7 for ~1.6e-3
    time units, both at the same instants; the exact flow crosses each gap twice per touch
    (8 crossings at the first two touch instants) and agrees to 1e-9 with the event-located
    reference (which needs max_step = 4e-4 to see such a short dip at all: with its default
    steps of ~0.1 it misses every contact and returns the free mode)."""
    flow = make_flow(graze_system(), method="exact")
    t1 = 2 * math.pi / W2 - 0.1
    y0 = mode2(A_GRAZE * (1 + 1e-6), 0.0)
    res = propagate(flow.affine_system, y0, 0.0, t1)
    ref, crossings = pwl_reference(graze_field, GRAZE_SURFACES, y0, 0.0, t1, max_step=4e-4)
    np.testing.assert_allclose(res.y, ref, rtol=0, atol=1e-9)
    assert len([e for e in res.events if not e.tangency]) == 8 == len(crossings)
    # the gap on x1 alone breaks the mode's symmetry x2 = -x1: the contact was felt
    assert abs(res.y[0] + res.y[1]) > 1e-10


@pytest.mark.parametrize("scale", [1 + 1e-12, 1 - 1e-12, 1 - 1e-6])
def test_double_grazing_within_rounding_and_near_misses(scale):
    """Within 1e-12 of the tangency either way, or a clear miss: the answer is the free mode
    (closed form) to 1e-12 — a contact of depth 3e-13 and duration ~2e-6 moves the state by
    ~1e-18 — with no event (a miss) or shallow crossings / tangencies at the instants t_k."""
    flow = make_flow(graze_system(), method="exact")
    t1 = 3 * math.pi / W2 + 0.3
    res = propagate(flow.affine_system, mode2(A_GRAZE * scale, 0.0), 0.0, t1)
    np.testing.assert_allclose(res.y, mode2(A_GRAZE * scale, t1), rtol=0, atol=1e-12)
    for ev in res.events:
        k = (ev.time * W2 / math.pi) - 0.5
        assert abs(k - round(k)) < 1e-5
    if scale < 1 - 1e-9:
        assert not res.events


# --------------------------------------------------------------------------- a 1e-9 gap --
IMPACT = {"mu": 0.05, "mu2": 0.01, "r": 20.0, "m2": 0.2, "F": 0.5, "Omega": 1.0}


def impact_field(params):
    mu, mu2, r, m2 = params["mu"], params["mu2"], params["r"], params["m2"]
    F, Om, d = params["F"], params["Omega"], params["d"]

    def field(signs, t, y):
        x1, x2, v1, v2 = y
        b = gap_force(x1 - x2, d, signs[0], signs[1])
        a1 = F * math.cos(Om * t) - mu * v1 - x1 - r * b
        a2 = (-mu2 * (v2 - v1) + r * b) / m2
        return np.array([v1, v2, a1, a2])

    return field, [((1, -1, 0, 0), d), ((1, -1, 0, 0), -d)]


def test_gap_of_1e9():
    """The impact pair with a clearance of 1e-9 (the relative coordinate crosses the gap
    37 times per period, each passage two crossings 1e-10 apart in time): 10 periods agree with
    the event-located reference to 1e-9, and differ from the zero-clearance linear system by
    no more than the force difference r d allows (here < 1e-6)."""
    params = dict(IMPACT, d=1e-9)
    flow = make_flow(builtin_system("impact_pair", **params), method="exact")
    t1 = 10 * flow.period
    y0 = [0.1, 0.0, 0.0, 0.0]
    res = propagate(flow.affine_system, y0, 0.0, t1)
    field, surfaces = impact_field(params)
    ref, crossings = pwl_reference(field, surfaces, y0, 0.0, t1)
    np.testing.assert_allclose(res.y, ref, rtol=0, atol=1e-9)
    assert res.stats.n_crossings == len(crossings) > 300
    # the d = 0 linear system in closed form (first-order matrix with the forcing state)
    r, m2, mu, mu2, Om, F = (IMPACT[k] for k in ("r", "m2", "mu", "mu2", "Omega", "F"))
    K = np.array([[1 + r, -r], [-r / m2, r / m2]])
    Cd = np.array([[mu, 0.0], [-mu2 / m2, mu2 / m2]])
    Aug = np.zeros((6, 6))
    Aug[:2, 2:4] = np.eye(2)
    Aug[2:4, :2], Aug[2:4, 2:4] = -K, -Cd
    Aug[2, 4] = F  # F cos(Om t) = F * z4, (z4, z5) = (cos, sin)
    Aug[4, 5], Aug[5, 4] = -Om, Om
    lin = expm(Aug * t1) @ np.array([*y0, 1.0, 0.0])
    assert np.abs(res.y - lin[:4]).max() < 1e-6


def test_rigid_clearance_of_1e9_by_lcp_stepper():
    """The same pair with a *rigid* two-sided stop |x1 - x2| <= 1e-9 (restitution 0.5): an
    event-driven solver would face an accumulation of impacts (Zeno); the Moreau stepper
    solves one LCP per step at a fixed cost and the pair moves as one rigid body, whose
    closed-form-free reference is DOP853 on (1 + m2) x'' + mu x' + x = F cos t. Measured:
    max error 6.7e-4, 1.7e-4, 4.1e-5 at h = T/500, T/1000, T/2000 (second order: the clearance
    holds, so no impact is ever resolved at a step's end)."""
    rigid = System.parse(
        ["x1'' + mu*x1' + x1 = F*cos(Omega*t)", "m2*x2'' + mu2*(x2' - x1') = 0"],
        {k: IMPACT[k] for k in ("mu", "mu2", "m2", "F", "Omega")},
        elements=[stop("x1 - x2", -1e-9, 1e-9, restitution=0.5)],
    )
    mu, m2, F = IMPACT["mu"], IMPACT["m2"], IMPACT["F"]
    t1 = 5 * 2 * math.pi
    ref = solve_ivp(
        lambda t, y: [y[1], (F * math.cos(t) - mu * y[1] - y[0]) / (1 + m2)],
        (0.0, t1),
        [0.0, 0.3],
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        dense_output=True,
    )
    errs = []
    for n in (500, 1000):
        traj = simulate_system_lcp(rigid, [0, 0, 0.3, 0.3], (0.0, t1), 2 * math.pi / n)
        x = ref.sol(traj.t)[0]
        errs.append(max(np.abs(traj.y[:, 0] - x).max(), np.abs(traj.y[:, 1] - x).max()))
        assert traj.n_lcp >= traj.n_steps - 2  # in contact all along
    assert errs[1] < 3e-4 and 3.0 < errs[0] / errs[1] < 5.0, errs


# ------------------------------------------------------------------------ a stiff stop --
def test_stiff_stop_1e6():
    """The impact pair with contact stiffness r = 1e6 (the primary's spring is 1): contacts
    last ~1.3e-3 time units at frequency ~2450. Two periods from rest (10 crossings) agree
    with the event-located reference to 1e-9, within a budget of grid intervals. (The impacts
    amplify any difference: exact vs reference measured 2.5e-12, 1.5e-10, 2.3e-9, 1.0e-7,
    3.6e-6 after 1..5 periods; so a longer span compares rounding, not the solvers.)"""
    params = dict(IMPACT, r=1e6, d=0.5)
    flow = make_flow(builtin_system("impact_pair", **params), method="exact")
    t1 = 2 * flow.period
    y0 = [0.0, 0.0, 0.0, 0.0]
    res = propagate(flow.affine_system, y0, 0.0, t1, max_steps=200_000)
    field, surfaces = impact_field(params)
    ref, crossings = pwl_reference(field, surfaces, y0, 0.0, t1)
    assert res.stats.n_crossings == len(crossings) >= 10
    np.testing.assert_allclose(res.y, ref, rtol=0, atol=1e-9)


def test_stiff_stop_rigid_limit_by_lcp():
    """The same clearance as a rigid stop with restitution 1 (the r -> infinity limit of an
    undamped contact spring is an elastic impact): the Moreau stepper with h = T/4000 and the
    exact r = 1e6 flow stay within 2e-2 of each other over one period (the contact spring's
    finite duration and the scheme's O(h) error)."""
    params = dict(IMPACT, r=1e6, d=0.5)
    flow = make_flow(builtin_system("impact_pair", **params), method="exact")
    T = flow.period
    rigid = System.parse(
        [
            "x1'' + mu*x1' + x1 = F*cos(Omega*t)",
            "m2*x2'' + mu2*(x2' - x1') = 0",
        ],
        {k: v for k, v in IMPACT.items() if k != "r"},
        elements=[stop("x1 - x2", -0.5, 0.5, restitution=1.0)],
    )
    traj = simulate_system_lcp(rigid, [0, 0, 0, 0], (0.0, T), T / 4000)
    exact = flow([0, 0, 0, 0], 0.0, T, t_eval=traj.t[::400])
    assert np.abs(traj.y[::400, :2] - exact.ys[:, :2]).max() < 2e-2


# ----------------------------------------------------------------- near-singular mass --
EPS_M = 4e-12  # cond([[1, 1], [1, 1 + 4e-12]]) = 1.0e12


def near_singular(eps: float) -> System:
    return System.from_matrices(
        [[1, 1], [1, 1 + eps]],
        [[0.1, 0], [0, 0.1]],
        [[1, 0], [0, 1]],
        elements=[gap("x1", 0.5, 4.0)],
    )


def test_near_singular_mass_short_span_is_right():
    """cond(M) = 1e12: the model is accepted (numeric condition below 1e14). Over a short
    span, inside the gap (a linear region), the exact flow equals e^{A t} y0 with A built
    here from M^-1 (the fast mode, rate 5e10, decays within the span) to 1e-9."""
    sys_ = near_singular(EPS_M)
    assert np.linalg.cond(np.array([[1, 1], [1, 1 + EPS_M]])) == pytest.approx(1e12, rel=0.01)
    flow = make_flow(sys_, method="exact")
    y0 = np.array([0.1, -0.05, 0.3, 0.2])
    t1 = 2e-8
    res = propagate(flow.affine_system, y0, 0.0, t1, max_steps=200_000)
    M = np.array([[1.0, 1.0], [1.0, 1.0 + EPS_M]])
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-Minv, -0.1 * Minv]])
    np.testing.assert_allclose(res.y, expm(A * t1) @ y0, rtol=0, atol=1e-9)


def test_near_singular_mass_long_span_gives_up_within_its_budget():
    """Over a useful span the exact flow's grid follows the fast mode's rate (5e10) in the
    matrix-exponential representation: it gives up with a PerturbError naming max_steps, in
    well under a second for a budget of 2e5 intervals (not a hang)."""
    flow = make_flow(near_singular(EPS_M), method="exact")
    assert isinstance(flow, AffineExactFlow)
    start = time.process_time()
    with pytest.raises(PerturbError, match="max_steps"):
        propagate(flow.affine_system, [0.1, -0.05, 0.3, 0.2], 0.0, 2.0, max_steps=200_000)
    assert time.process_time() - start < 20.0


_BOUNDED_SCRIPT = """
import os, threading, time
from perturb.errors import PerturbError
from perturb.model.system import System, gap
from perturb.simulate.flows.factory import make_flow
sys_ = System.from_matrices([[1, 1], [1, 1 + 4e-12]], [[0.1, 0], [0, 0.1]], [[1, 0], [0, 1]],
                            elements=[gap("x1", 0.5, 4.0)])
flow = make_flow(sys_, method="exact")
page = os.sysconf("SC_PAGE_SIZE")
def rss():
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * page
base = rss()
def watch():
    while True:
        time.sleep(0.1)
        if rss() > base + 2**29:
            print("MEMORY", flush=True)
            os._exit(3)
threading.Thread(target=watch, daemon=True).start()
try:
    out = flow([0.1, -0.05, 0.3, 0.2], 0.0, 2.0)
    print("RESULT", *out.y.tolist())
except PerturbError as exc:
    print("PERTURBERROR", exc)
"""


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="needs /proc (Linux)")
def test_near_singular_mass_flow_is_bounded():
    """Through the flow object (the budget users get): the answer, or a PerturbError, within
    60 s and 512 MB of extra memory (a subprocess, so neither can hang or exhaust this run)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _BOUNDED_SCRIPT],
            capture_output=True,
            text=True,
            timeout=60,
            env=env,
        )
    except subprocess.TimeoutExpired:
        pytest.fail("the exact flow neither answered nor raised within 60 s")
    out = proc.stdout.strip()
    assert proc.returncode == 0 and not out.startswith("MEMORY"), (proc.returncode, out[-300:])
    # refused at once, naming the cause (a stiff region) and the budget: the grid of the
    # fast mode (5e10) cannot reach t = 2 within 5e7 intervals
    assert out.startswith("PERTURBERROR") and "max_steps" in out and "stiff" in out, out[-300:]


def test_near_singular_mass_by_lcp_stepper():
    """The implicit Moreau stepper on cond(M) = 1e12 with a stop that is never reached
    (|x1| <= 5): one linear solve per step, no grid that follows the fast rate. Reference:
    e^{A t} y0 with A built here from M^-1 (two evaluations of it, e^{5A} and (e^{A/2})^10,
    differ by 1.2e-6: the data's own conditioning). theta = 1/2 gets the positions to the
    reference's accuracy, but as the trapezoidal rule is not L-stable the fast mode (rate
    5e10, h * rate ~ 5e8) keeps ringing in the velocities with alternating sign (documented
    limitation); theta = 1 (backward Euler) damps it: all four states converge at first order."""
    sys_ = System.from_matrices(
        [[1, 1], [1, 1 + EPS_M]],
        [[0.1, 0], [0, 0.1]],
        [[1, 0], [0, 1]],
        elements=[stop("x1", -5, 5)],
    )
    y0 = np.array([0.1, -0.05, 0.0, 0.0])
    Minv = np.linalg.inv(np.array([[1.0, 1.0], [1.0, 1.0 + EPS_M]]))
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-Minv, -0.1 * Minv]])
    ref = expm(A * 5.0) @ y0
    for h in (0.01, 0.005):
        end = simulate_system_lcp(sys_, y0, (0.0, 5.0), h).y[-1]
        assert np.abs(end[:2] - ref[:2]).max() < 5e-6
        assert np.abs(end[2:] - ref[2:]).max() > 0.1  # the ringing fast mode (theta = 1/2)
    errs = [
        np.abs(simulate_system_lcp(sys_, y0, (0.0, 5.0), h, theta=1.0).y[-1] - ref).max()
        for h in (0.01, 0.005, 0.0025)
    ]
    assert errs[0] < 1e-3 and 1.7 < errs[0] / errs[1] < 2.3 and 1.7 < errs[1] / errs[2] < 2.3


# ---------------------------------------------------------------------- singular mass --
def test_exactly_singular_mass_is_refused():
    """An exactly singular M without a first-order declaration: a ModelError naming the
    matrix and what was expected, from every way in (matrices, equations, parameter values),
    before any flow is built."""
    with pytest.raises(ModelError, match="singular"):
        System.from_matrices([[1, 1], [1, 1]], [[0, 0], [0, 0]], [[1, 0], [0, 1]])
    with pytest.raises(ModelError, match="first-order"):
        System.parse(["x1'' + x2'' + x1 = 0", "x1'' + x2'' + x2 = cos(t)"])
    sys_ = System.parse(["x1'' + a*x2'' + x1 = 0", "a*x1'' + x2'' + x2 = cos(t)"], {"a": 1.0})
    with pytest.raises(ModelError, match="singular"):
        make_flow(sys_, method="exact")
    with pytest.raises(ModelError, match="singular"):
        sys_.numeric_form()


def test_long_visit_of_a_defective_region_keeps_exact_crossings():
    """A free mass (A = [[0, 1], [0, 0]]: a Jordan block, the augmented-exponential form)
    coasts for ~27 000 grid intervals before it reaches the spring at x = 1e5: the long visit
    keeps only every 32nd grid node (bounded memory), and the crossing and the dense
    trajectory between nodes are still the closed form x = 30 t, t_c = 1e5 / 30."""
    sys_ = System.from_matrices([[1]], [[0]], [[0]], elements=[gap("x1", 1e5, 1.0)])
    run = propagate(sys_.piecewise_affine(), np.array([0.0, 30.0]), 0.0, 3400.0, dense=True)
    assert run.stats.n_grid > 20_000 and run.stats.n_expm_pieces >= 1
    first = run.events[0]
    assert first.time == pytest.approx(1e5 / 30, rel=4e-16)
    np.testing.assert_allclose(first.y, [1e5, 30.0], rtol=1e-15)
    ts = np.linspace(0.0, 3333.0, 101) + 0.0123  # between grid nodes
    np.testing.assert_allclose(run.trajectory(ts)[0], 30.0 * ts, rtol=1e-14, atol=1e-10)
