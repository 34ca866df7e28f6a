"""Periodic orbits of systems with several coordinates (issue 15, items 2 and 4).

Shooting (:func:`perturb.simulate.orbits.shooting.periodic_orbit`) on the exact n-dimensional
flow (:class:`perturb.simulate.flows.affine_exact.AffineExactFlow`) against references that
share no code with it:

* the period map integrated by DOP853 (rtol = atol = 1e-12) on the equations of motion written
  out by hand here, with a terminal event on every switching surface and a restart (the region
  held fixed between crossings), its variational equations with the hand-written Jacobian
  (both builtins have a continuous force, so no saltation), solved by
  :func:`scipy.optimize.root`; ``max |.|`` of every state from non-terminal events at the roots
  of its rate;
* the closed-form modal response ``(K - W^2 M + i W C) Q = F`` when no contact is reached;
* DOP853 with events and restarts over 100 forcing periods for every builtin piecewise-linear
  system.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp
from scipy.optimize import root

from perturb.model.affine import PiecewiseAffineSystem
from perturb.model.system_builtins import builtin_system
from perturb.simulate.flows.affine_exact import AffineExactFlow, propagate
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.orbits.shooting import (
    classify_multipliers,
    multiple_shooting,
    periodic_orbit,
)

RTOL = ATOL = 1e-12


# ------------------------------------------------------------------------------------------
# the builtins written out by hand: field, Jacobian and surfaces, state (x1, x2, x1', x2')
# ------------------------------------------------------------------------------------------
def nsd2_equations(k=-0.5, mu1=0.05, mu2=0.02, k2=1.0, m2=1.0, F=2.0, W=1.0):
    """x1'' + mu1 x1' + mu2 (x1' - x2') + k x1 + (1 - k) h(x1) + k2 (x1 - x2) = F cos W t,
    m2 x2'' + mu2 (x2' - x1') + k2 (x2 - x1) = 0, h = (x1 - 1)^+ - (-1 - x1)^+."""

    def rhs(t, y, pat):
        x1, x2, v1, v2 = y
        h = x1 - 1.0 if pat[0] > 0 else (x1 + 1.0 if pat[1] < 0 else 0.0)
        a1 = -mu1 * v1 - mu2 * (v1 - v2) - k * x1 - (1 - k) * h - k2 * (x1 - x2)
        a2 = (-mu2 * (v2 - v1) - k2 * (x2 - x1)) / m2
        return np.array([v1, v2, a1 + F * math.cos(W * t), a2])

    def jac(t, y, pat):
        outer = pat[0] > 0 or pat[1] < 0
        kk = 1.0 if outer else k
        return np.array(
            [
                [0, 0, 1, 0],
                [0, 0, 0, 1],
                [-kk - k2, k2, -mu1 - mu2, mu2],
                [k2 / m2, -k2 / m2, mu2 / m2, -mu2 / m2],
            ]
        )

    surfaces = [((1, 0, 0, 0), 1.0), ((1, 0, 0, 0), -1.0)]
    return rhs, jac, surfaces


def impact_equations(mu=0.05, mu2=0.01, r=20.0, d=0.5, m2=0.2, F=0.5, W=1.0):
    """x1'' + mu x1' + x1 + r b(x1 - x2) = F cos W t, m2 x2'' + mu2 (x2' - x1') = r b,
    b(s) = (s - d)^+ - (-d - s)^+."""

    def rhs(t, y, pat):
        x1, x2, v1, v2 = y
        s = x1 - x2
        b = s - d if pat[0] > 0 else (s + d if pat[1] < 0 else 0.0)
        a1 = -mu * v1 - x1 - r * b + F * math.cos(W * t)
        a2 = (-mu2 * (v2 - v1) + r * b) / m2
        return np.array([v1, v2, a1, a2])

    def jac(t, y, pat):
        rc = r if (pat[0] > 0 or pat[1] < 0) else 0.0
        return np.array(
            [
                [0, 0, 1, 0],
                [0, 0, 0, 1],
                [-1 - rc, rc, -mu, 0],
                [rc / m2, -rc / m2, mu2 / m2, -mu2 / m2],
            ]
        )

    surfaces = [((1, -1, 0, 0), d), ((1, -1, 0, 0), -d)]
    return rhs, jac, surfaces


def pattern_of(surfaces, y):
    return [1 if np.dot(c, y) - d >= 0.0 else -1 for c, d in surfaces]


def reference(rhs, jac, surfaces, y0, t0, t1, *, sens=False, extrema=False, atol=None):
    """DOP853 (rtol = 1e-12, atol = 1e-12 or ``atol``) of ``rhs`` with terminal events on the
    surfaces and a restart at each crossing; optionally the variational equations (``Phi``)
    and ``max |y_i|`` over the run (non-terminal events at the roots of ``y_i'``).

    Returns ``(y(t1), Phi or None, maxima or None, number of crossings)``."""
    n = len(y0)
    t, y, pat = float(t0), np.array(y0, dtype=float), pattern_of(surfaces, y0)
    phi = np.eye(n)
    maxima = np.abs(y).copy()
    crossings = 0
    tol_a = ATOL if atol is None else atol
    for _ in range(100_000):
        p = tuple(pat)
        events = []
        for j, (c, d) in enumerate(surfaces):

            def ev(tt, zz, c=c, d=d):
                return np.dot(c, zz[:n]) - d

            ev.terminal = True
            ev.direction = -pat[j]
            events.append(ev)
        n_surf = len(events)
        if extrema:
            for i in range(n):

                def ex(tt, zz, i=i, p=p):
                    return rhs(tt, zz[:n], p)[i]

                events.append(ex)
        if sens:

            def fun(tt, zz, p=p):
                ph = zz[n:].reshape(n, n)
                return np.concatenate([rhs(tt, zz[:n], p), (jac(tt, zz[:n], p) @ ph).ravel()])

            z0 = np.concatenate([y, phi.ravel()])
            at = np.concatenate([np.broadcast_to(tol_a, (n,)), np.full(n * n, ATOL)])
        else:

            def fun(tt, zz, p=p):
                return rhs(tt, zz, p)

            z0, at = y, tol_a
        sol = solve_ivp(fun, (t, t1), z0, method="DOP853", rtol=RTOL, atol=at, events=events)
        assert sol.status in (0, 1), sol.message
        if extrema:
            for i in range(n):
                ye = sol.y_events[n_surf + i]
                if ye.size:
                    maxima[i] = max(maxima[i], float(np.abs(ye[:, i]).max()))
            maxima = np.maximum(maxima, np.abs(sol.y[:n, -1]))
        if sol.status == 0:
            z = sol.y[:, -1]
            return z[:n], (z[n:].reshape(n, n) if sens else None), maxima, crossings
        j = min(
            (k for k in range(n_surf) if sol.t_events[k].size), key=lambda k: sol.t_events[k][0]
        )
        t = float(sol.t_events[j][0])
        z = sol.y_events[j][0]
        y = z[:n]
        if sens:
            phi = z[n:].reshape(n, n)  # continuous force: the saltation matrix is I
        pat[j] = -pat[j]
        crossings += 1
        if extrema:
            maxima = np.maximum(maxima, np.abs(y))
    raise AssertionError("reference: too many restarts")


def reference_orbit(eqs, y_start, T):
    """Fixed point of the reference period map by scipy's root (hybr, Jacobian Phi - I), its
    monodromy and ``max |y_i|``."""
    rhs, jac, surfaces = eqs

    def G(y):
        yT, phi, _, _ = reference(rhs, jac, surfaces, y, 0.0, T, sens=True)
        return yT - y, phi - np.eye(y.size)

    sol = root(G, y_start, jac=True, method="hybr", options={"xtol": 1e-14})
    y0 = sol.x
    _, phi, maxima, _ = reference(rhs, jac, surfaces, y0, 0.0, T, sens=True, extrema=True)
    return y0, phi, maxima


def settled(system, y0, *, tol=1e-9, max_periods=5000):
    """The state at a whole number of periods (>= 100) from ``y0`` once one period maps it
    to within ``tol`` of itself: a transient through chaotic motion lasts a number of periods
    that depends on rounding, so a fixed count may stop short of the attractor."""
    T = system.period
    y = propagate(system, y0, 0.0, 100 * T).y
    for k in range(100, max_periods):
        y1 = propagate(system, y, k * T, (k + 1) * T).y
        if np.max(np.abs(y1 - y)) < tol * max(1.0, np.max(np.abs(y))):
            return y1
        y = y1
    raise AssertionError(f"no period-1 attractor within {max_periods} periods")


def assert_multipliers_match(ours, ref, tol):
    ref = list(np.asarray(ref, dtype=complex))
    for mu in ours:
        k = int(np.argmin([abs(mu - r) for r in ref]))
        assert abs(mu - ref[k]) <= tol * max(1.0, abs(ref[k])), (ours, ref)
        ref.pop(k)


# ------------------------------------------------------------------------------------------
# period-1 orbits, stable and unstable, against the independent reference
# ------------------------------------------------------------------------------------------
CASES = {
    ("nsd2", 0.8): (
        nsd2_equations,
        [[-2.4, -3.5, 0.3, -0.1], [0.4, -1.9, -0.1, 0.3]],
    ),
    ("nsd2", 1.2): (
        nsd2_equations,
        [[1.3, -2.9, 0.35, -0.45], [2.2, -0.4, 0.1, -0.1], [-0.6, -3.1, 0.1, -0.1]],
    ),
    ("impact_pair", 1.0): (impact_equations, [[-1.9, -2.2, 0.5, 0.1], [-2.4, -2.2, 0.4, 1.6]]),
    # (Newton's basin of this orbit is narrow: 0.01 off fails; the state reached from rest works)
    ("impact_pair", 1.4): (impact_equations, ["settled", [-0.2183, -0.7963, 0.0312, -0.0029]]),
}


@pytest.mark.parametrize("name, W", list(CASES))
def test_period_one_orbits_match_the_independent_reference(name, W):
    make_eqs, starts = CASES[(name, W)]
    flow = make_flow(builtin_system(name, Omega=W))
    assert isinstance(flow, AffineExactFlow)
    T = 2 * math.pi / W
    orbits = []
    for y in starts:
        if isinstance(y, str):  # the state reached from rest, on the attractor
            y = settled(flow.affine_system, np.zeros(4))
        orb = periodic_orbit(flow, y, max_iter=40)
        if not any(np.max(np.abs(orb.y0 - o.y0)) < 1e-6 for o in orbits):
            orbits.append(orb)
    kinds = {o.stability for o in orbits}
    expected = {
        ("nsd2", 0.8): {"unstable"},
        ("nsd2", 1.2): {"stable", "unstable"},
        ("impact_pair", 1.0): {"unstable"},
        ("impact_pair", 1.4): {"stable"},
    }[(name, W)]
    assert kinds == expected
    eqs = make_eqs(W=W)
    for orb in orbits:
        assert orb.y0.shape == (4,) and orb.monodromy.shape == (4, 4)
        y_ref, phi, maxima = reference_orbit(eqs, orb.y0 * (1 + 1e-5), T)
        np.testing.assert_allclose(orb.y0, y_ref, rtol=0, atol=1e-9 * max(1.0, np.abs(y_ref).max()))
        ours = orb.max_abs()
        np.testing.assert_allclose(ours, maxima, rtol=1e-9, atol=1e-9)
        assert orb.amplitude == pytest.approx(maxima[0], rel=1e-9)
        assert_multipliers_match(orb.multipliers, np.linalg.eigvals(phi), 1e-7)
        assert orb.max_abs([1, -1, 0, 0]) <= maxima[0] + maxima[1] + 1e-12


@pytest.mark.parametrize(
    "name, W, start",
    [
        ("nsd2", 1.2, [2.2, -0.4, 0.1, -0.1]),
        ("impact_pair", 1.0, [-1.9, -2.2, 0.5, 0.1]),
    ],
)
def test_monodromy_is_the_derivative_of_the_exact_period_map(name, W, start):
    flow = make_flow(builtin_system(name, Omega=W))
    orb = periodic_orbit(flow, start)
    T = flow.period
    fd = np.empty((4, 4))
    for i in range(4):
        h = 1e-6 * max(1.0, abs(orb.y0[i]))
        e = np.zeros(4)
        e[i] = h
        fd[:, i] = (flow(orb.y0 + e, 0.0, T).y - flow(orb.y0 - e, 0.0, T).y) / (2 * h)
    err = np.max(np.abs(fd - orb.monodromy)) / np.max(np.abs(orb.monodromy))
    assert err < 1e-6
    assert orb.stability == "unstable"


# ------------------------------------------------------------------------------------------
# the linear case: the closed-form modal response
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("W", [0.8, 1.2, 2.5])
def test_linear_case_equals_the_modal_response(W):
    k, mu1, mu2, k2, m2, F = -0.5, 0.05, 0.02, 1.0, 1.0, 0.01
    system = builtin_system("nsd2", Omega=W, F=F)
    flow = make_flow(system)
    Mm = np.diag([1.0, m2])
    Cm = np.array([[mu1 + mu2, -mu2], [-mu2, mu2]])
    Km = np.array([[k + k2, -k2], [-k2, k2]])
    Q = np.linalg.solve(Km - W**2 * Mm + 1j * W * Cm, [F, 0.0])
    assert np.abs(Q).max() < 1.0  # |x1| < 1: the device's inner (linear) region only
    y_modal = np.concatenate([Q.real, (1j * W * Q).real])
    orb = periodic_orbit(flow, np.zeros(4))
    np.testing.assert_allclose(orb.y0, y_modal, rtol=0, atol=1e-12)
    np.testing.assert_allclose(orb.max_abs(), np.abs(np.concatenate([Q, W * Q])), atol=1e-12)
    A = np.block(
        [[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(Mm, Km), -np.linalg.solve(Mm, Cm)]]
    )
    mu = np.linalg.eigvals(scipy.linalg.expm(A * 2 * math.pi / W))
    assert_multipliers_match(orb.multipliers, mu, 1e-10)
    assert orb.stability == "unstable"  # the negative stiffness: a saddle inside |x1| < 1


# ------------------------------------------------------------------------------------------
# Floquet classification in four dimensions: Neimark-Sacker
# ------------------------------------------------------------------------------------------
def two_modes(c2, W=1.0):
    """Two uncoupled forced modes, the second with damping ``c2`` (its multiplier pair
    ``exp((-c2/2 +- i w2) T)`` leaves the unit circle as ``c2`` turns negative)."""
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-1.0, 0, -0.1, 0], [0, -math.sqrt(2.7), 0, -c2]])
    return PiecewiseAffineSystem.build(
        ("x1", "x2", "v1", "v2"),
        [],
        {(): (A, (0, 0, 0, 0))},
        inputs=[(W, (0, 0, 1.0, 0.3), (0, 0, 0, 0))],
        period=2 * math.pi / W,
    )


@pytest.mark.parametrize(
    "c2, label",
    [(0.01, "stable"), (0.0, "neimark-sacker"), (-1e-8, "neimark-sacker"), (-0.01, "unstable")],
)
def test_neimark_sacker_a_complex_pair_leaves_the_circle(c2, label):
    orb = periodic_orbit(make_flow(two_modes(c2)), np.zeros(4))
    assert orb.stability == label
    lead = orb.multipliers[0]
    assert abs(lead.imag) > 0.1  # the critical multipliers are a complex pair
    assert abs(lead) == pytest.approx(math.exp(-c2 / 2 * orb.period), rel=1e-12)


def test_classify_multipliers_four_dimensional():
    ring = np.exp(1j * 1.3)
    assert classify_multipliers([ring, ring.conjugate(), 0.5, 0.2])[0] == "neimark-sacker"
    assert classify_multipliers([1.01 * ring, 1.01 * ring.conjugate(), 0.5, 0.2])[0] == "unstable"
    assert classify_multipliers([0.9 * ring, 0.9 * ring.conjugate(), -1.0, 0.2])[0] == (
        "period-doubling"
    )
    assert classify_multipliers([0.9, 1.0 + 1e-9, 0.5, 0.2]) == ("fold", 1.0 + 1e-9)
    assert classify_multipliers([3.0, 0.5j, -0.5j, 0.1])[0] == "unstable"


def test_multiple_shooting_in_four_dimensions_equals_single_shooting():
    flow = make_flow(builtin_system("nsd2", Omega=1.2))
    single = periodic_orbit(flow, [2.2, -0.4, 0.1, -0.1])
    T = flow.period
    nodes = [flow(single.y0, 0.0, i * T / 4).y if i else single.y0 for i in range(4)]
    multi = multiple_shooting(flow, np.array(nodes) + 1e-3)
    np.testing.assert_allclose(multi.y0, single.y0, atol=1e-10)
    np.testing.assert_allclose(multi.monodromy, single.monodromy, rtol=1e-8, atol=1e-9)
    assert multi.nodes.shape == (4, 4) and multi.stability == single.stability


# ------------------------------------------------------------------------------------------
# every builtin piecewise-linear system: AffineExactFlow against DOP853 over 100 periods
# ------------------------------------------------------------------------------------------
def mount_equations(active):
    """The He-Singh mount after the step (builtin ``mount`` defaults), the decoupler free
    (``active`` None) or resting on its lower stop (``V_d = 0`` held)."""
    A_r, C1, C2, I_i, R_i = 3.0e-3, 4.0e-11, 4.0e-9, 6.0e6, 9.0e7
    p_vac, C1v, I_d, R_d, X = 9.0e4, 2.0e-9, 1.5e5, 1.5e7, -2.4e-3
    u_k = -p_vac * C1

    def rhs(t, y, pat):
        V_i, V_d, q_i, q_d = y
        u = A_r * X - V_i - V_d
        p1 = u / C1 + ((1 / C1v - 1 / C1) * (u - u_k) if pat[0] > 0 else 0.0)
        p2 = (V_i + V_d) / C2
        a_i = (p1 - p2 - R_i * q_i) / I_i
        if active is None:
            return np.array([q_i, q_d, a_i, (p1 - p2 - R_d * q_d) / I_d])
        return np.array([q_i, 0.0, a_i, 0.0])

    # vacuum below u_k: u < u_k  <=>  V_i + V_d > A_r X - u_k
    return rhs, [((1, 1, 0, 0), A_r * X - u_k)]


def scaled(system, D):
    """The similarity transform ``y = D z`` of a piecewise-affine system."""
    D = np.asarray(D, dtype=float)
    Di = 1.0 / D
    regions = {k: (Di[:, None] * r.A * D[None, :], Di * r.b) for k, r in system.regions.items()}
    surfaces = [(s.normal * D, s.offset, s.label) for s in system.surfaces]
    inputs = [(h.omega, Di * h.u, Di * h.v) for h in system.inputs]
    return PiecewiseAffineSystem.build(system.state_names, surfaces, regions, inputs, system.period)


def compare_100(system, rhs, surfaces, y0, t0, span, scale):
    ours = propagate(system, y0, t0, t0 + span)
    ref, _, _, n_cross = reference(
        rhs, None, surfaces, y0, t0, t0 + span, atol=ATOL * np.asarray(scale)
    )
    assert ours.stats.n_crossings == n_cross
    assert np.max(np.abs(ours.y - ref) / scale) < 1e-9
    return n_cross


@pytest.mark.parametrize("name", ["nsd2", "impact_pair"])
def test_exact_flow_agrees_with_dop853_over_100_periods_structures(name):
    W = {"nsd2": 1.2, "impact_pair": 1.4}[name]
    system = builtin_system(name, Omega=W).piecewise_affine()
    rhs, _, surfaces = (nsd2_equations if name == "nsd2" else impact_equations)(W=W)
    T = system.period
    t0 = 50 * T
    y0 = propagate(system, [0.5, 0.0, 0.0, 0.0], 0.0, t0).y  # on the attractor
    n = compare_100(system, rhs, surfaces, y0, t0, 100 * T, np.ones(4))
    assert n >= 100


@pytest.mark.parametrize("active", [None, -1])
def test_exact_flow_agrees_with_dop853_mount_step_response(active):
    system = builtin_system("mount").piecewise_affine({"decoupler": active})
    rhs, surfaces = mount_equations(active)
    # the step response from rest: the slowest mode's period is ~0.76 s; it has settled
    # (rate 7.5/s) long before 100 of them, so 2 s hold the whole transient and the crossing
    n = compare_100(system, rhs, surfaces, np.zeros(4), 0.0, 2.0, [1e-6, 1e-6, 1e-5, 1e-5])
    assert n >= 1


def test_exact_flow_agrees_with_dop853_mount_linear_scaled():
    """``mount_linear`` in units where its states are O(1) (pressures in 1e4 Pa, flows in
    1e-5 m^3/s): the same system up to a diagonal similarity transform."""
    W, Xa = 60.0, 1.0e-4
    raw = builtin_system("mount_linear").piecewise_affine()
    D = np.array([1e4, 1e4, 1e-5, 1e-5])
    system = scaled(raw, D)
    A_r, C1, C2, I_i, R_i, I_d, R_d = 3.0e-3, 4.0e-11, 4.0e-9, 6.0e6, 9.0e7, 1.5e5, 1.5e7

    def rhs(t, y, pat):
        p1, p2, q_i, q_d = y * D
        x_rate = -Xa * W * math.sin(W * t)
        dy = [
            (A_r * x_rate - q_i - q_d) / C1,
            (q_i + q_d) / C2,
            (p1 - p2 - R_i * q_i) / I_i,
            (p1 - p2 - R_d * q_d) / I_d,
        ]
        return np.array(dy) / D

    T = system.period
    compare_100(system, rhs, [], np.zeros(4), 0.0, 100 * T, np.ones(4))


def test_exact_flow_on_the_raw_mount_linear_finishes():
    code = (
        "import numpy as np\n"
        "from perturb.model.system_builtins import builtin_system\n"
        "from perturb.simulate.flows.affine_exact import propagate\n"
        "p = builtin_system('mount_linear').piecewise_affine()\n"
        "propagate(p, np.zeros(4), 0.0, p.period)\n"
    )
    try:
        subprocess.run([sys.executable, "-c", code], timeout=8, check=True)
    except subprocess.TimeoutExpired:
        pytest.fail("one period of mount_linear did not finish in 8 s")


def test_exact_flow_agrees_with_dop853_mount_linear_raw():
    """``mount_linear`` in its own units (Pa, m^3/s: entries of A from 1e-7 to 2.5e10) over
    100 forcing periods, against DOP853 on the equations written out in those units (atol
    scaled per state: 1e-12 of 1e4 Pa and of 1e-5 m^3/s), also through the sensitivity:
    the flow's derivative against central differences of the reference."""
    W, Xa = 60.0, 1.0e-4
    system = builtin_system("mount_linear").piecewise_affine()
    A_r, C1, C2, I_i, R_i, I_d, R_d = 3.0e-3, 4.0e-11, 4.0e-9, 6.0e6, 9.0e7, 1.5e5, 1.5e7

    def rhs(t, y, pat):
        p1, p2, q_i, q_d = y
        x_rate = -Xa * W * math.sin(W * t)
        return np.array(
            [
                (A_r * x_rate - q_i - q_d) / C1,
                (q_i + q_d) / C2,
                (p1 - p2 - R_i * q_i) / I_i,
                (p1 - p2 - R_d * q_d) / I_d,
            ]
        )

    scale = np.array([1e4, 1e4, 1e-5, 1e-5])
    T = system.period
    assert T == pytest.approx(2 * math.pi / W, rel=1e-15)
    compare_100(system, rhs, [], np.zeros(4), 0.0, 100 * T, scale)
    # from a state off the attractor (a transient in every state), over 3 periods
    y0 = np.array([2.0e3, -1.0e3, 3.0e-6, -2.0e-6])
    compare_100(system, rhs, [], y0, 0.0, 3 * T, scale)
    # the exact sensitivity: linear system, so the flow is affine and central differences of
    # the reference are exact up to its tolerance
    res = AffineExactFlow(system)(y0, 0.0, T, sensitivity=True)
    fd = np.empty((4, 4))
    for i in range(4):
        e = np.zeros(4)
        e[i] = scale[i]
        yp = reference(rhs, None, [], y0 + e, 0.0, T, atol=ATOL * scale)[0]
        ym = reference(rhs, None, [], y0 - e, 0.0, T, atol=ATOL * scale)[0]
        fd[:, i] = (yp - ym) / 2.0
    # compare in scaled units: (D^-1 M D) against the differences of D^-1 y
    ours = res.sensitivity * scale[None, :] / scale[:, None]
    ref = fd / scale[:, None]
    assert np.max(np.abs(ours - ref)) < 1e-9 * max(1.0, np.abs(ref).max())
