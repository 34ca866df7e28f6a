"""The exact frequency response of ``impact_pair`` holds the unstable lower branch that
enters the window (0.6, 1.4) at its low edge (Omega 0.6 .. ~0.74, max |x1| 0.87 .. 1.4,
one contact per side and period, a saddle with a real multiplier ~14 at Omega 0.65).

It used to be missed: the march from a seed on that curve (at Omega ~0.7356) went the other
way first, round the resonance, and near the sharp grazing fold at Omega ~0.9698 its points
came within the join distance of the fold's other side: the march took that for the loop
closing, and a closed loop is not traced backward, so 0.6 .. 0.7356 was never traced.

The oracle is written here, independently of perturb: the two masses integrated by
``solve_ivp`` (DOP853, rtol = atol = 1e-12, ``max_step`` T/2000 so that no shallow contact
between two steps goes unseen) one contact state at a time (terminal events at
``|x1 - x2| = d``), Newton on the period map with a central-difference Jacobian from a fixed
start state.  The test asks that a branch of the exact response crosses Omega = 0.65 at the
oracle's max |x1|, and that the oracle's orbit is isolated and unstable there.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import exact_branches

MU, MU2, R, D, M2, F = 0.05, 0.01, 20.0, 0.5, 0.2, 0.5
WINDOW = (0.6, 1.4)
OMEGA = 0.65
#: (x1, x1', x2, x2') at t = 0 near the orbit (a DOP853-shot orbit at Omega = 0.6505)
START = np.array([1.001282, -0.065087, 1.470803, 0.634958])


def _rhs(side: int, W: float):
    def f(t, y):
        x1, v1, x2, v2 = y
        s = x1 - x2
        b = s - D if side == 1 else (s + D if side == -1 else 0.0)
        a1 = F * math.cos(W * t) - MU * v1 - x1 - R * b
        a2 = (R * b - MU2 * (v2 - v1)) / M2
        return [v1, a1, v2, a2]

    return f


def _events(side: int):
    def up(t, y):
        return y[0] - y[2] - D

    def down(t, y):
        return y[0] - y[2] + D

    if side == 0:
        up.direction, down.direction = 1, -1
        evs = [up, down]
    elif side == 1:
        up.direction = -1
        evs = [up]
    else:
        down.direction = 1
        evs = [down]
    for e in evs:
        e.terminal = True
    return evs


def _flow(y0: np.ndarray, W: float, samples: bool = False):
    """The state after one forcing period (and the sampled x1, x1 - x2 and contact state)."""
    T = 2.0 * math.pi / W
    t, y = 0.0, np.array(y0, dtype=float)
    s = y[0] - y[2]
    side = 1 if s > D else (-1 if s < -D else 0)
    xs, gaps, sides, switches = [], [], [], 0
    for _ in range(200):  # switches per period: 4-8 here
        sol = solve_ivp(
            _rhs(side, W),
            (t, T),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            max_step=T / 2000,
            events=_events(side),
            dense_output=samples,
        )
        if samples:
            tt = np.linspace(sol.t[0], sol.t[-1], 2 + int(4000 * (sol.t[-1] - sol.t[0]) / T))
            Y = sol.sol(tt)
            xs.append(Y[0])
            gaps.append(Y[0] - Y[2])
            sides.append(np.full(tt.size, side))
        t, y = float(sol.t[-1]), sol.y[:, -1]
        if sol.status != 1 or t >= T:
            break
        switches += 1
        side = (1 if y[0] - y[2] > 0 else -1) if side == 0 else 0
    if samples:
        return y, switches, np.hstack(xs), np.hstack(gaps), np.hstack(sides)
    return y


def _jacobian(y: np.ndarray, W: float) -> np.ndarray:
    J = np.zeros((4, 4))
    for k in range(4):
        e = np.zeros(4)
        e[k] = 1e-6 * max(1.0, abs(y[k]))
        J[:, k] = (_flow(y + e, W) - _flow(y - e, W)) / (2 * e[k])
    return J


def _oracle_orbit(W: float, y0: np.ndarray):
    y = y0.copy()
    for _ in range(20):
        G = _flow(y, W) - y
        if np.linalg.norm(G) < 1e-11 * max(1.0, float(np.linalg.norm(y))):
            break
        y = y + np.linalg.solve(_jacobian(y, W) - np.eye(4), -G)
    G = _flow(y, W) - y
    assert np.linalg.norm(G) < 1e-9, f"oracle Newton did not converge at Omega = {W}"
    J = _jacobian(y, W)
    _, switches, x1, gap, side = _flow(y, W, samples=True)
    return y, J, switches, x1, gap, side


@pytest.fixture(scope="module")
def oracle():
    return _oracle_orbit(OMEGA, START)


@pytest.fixture(scope="module")
def exact():
    s = builtin_system("impact_pair")
    return exact_branches(s, WINDOW, progress=False, workers=1)


def test_oracle_orbit_is_an_isolated_saddle(oracle):
    y, J, switches, x1, gap, side = oracle
    # no contact between samples missed: |x1 - x2| <= d wherever the masses are apart
    assert np.max(np.abs(gap[side == 0])) <= D + 1e-9
    assert switches == 4  # one contact on each side per period
    mult = np.linalg.eigvals(J)
    assert np.max(np.abs(mult)) > 5.0  # unstable (a real multiplier ~14)
    # isolated: J - I far from singular (not a member of a family of orbits)
    assert np.linalg.svd(J - np.eye(4), compute_uv=False)[-1] > 0.1
    assert 0.95 < float(np.max(np.abs(x1))) < 1.05


def test_exact_response_holds_the_lower_branch(oracle, exact):
    A = float(np.max(np.abs(oracle[3])))
    crossings = []
    for br in exact.branches:
        p = np.array([q.parameter for q in br.points])
        a = np.array([q.amplitude for q in br.points])
        for j in np.flatnonzero((p[:-1] - OMEGA) * (p[1:] - OMEGA) <= 0):
            if p[j + 1] != p[j]:
                f = (OMEGA - p[j]) / (p[j + 1] - p[j])
                crossings.append(float(a[j] + f * (a[j + 1] - a[j])))
    assert crossings, "no exact branch crosses Omega = 0.65"
    err = min(abs(c - A) / A for c in crossings)
    assert err < 2e-3, f"oracle max|x1| {A:.6f}; exact crossings {sorted(crossings)}"
    # the branch reaches the window's low edge
    assert any(
        min(q.parameter for q in br.points) == WINDOW[0]
        and any(q.parameter < 0.66 and q.amplitude < 1.05 for q in br.points)
        for br in exact.branches
    )
