"""The exact frequency response of ``impact_pair`` holds the unstable lower branch that
enters the window (0.6, 1.4) at its low edge (Omega 0.6 .. ~0.74, max |x1| 0.87 .. 1.4,
one contact per side and period, a saddle with a real multiplier ~14 at Omega 0.65).

It used to be missed: the march from a seed on that curve (at Omega ~0.7356) went the other
way first, round the resonance, and near the sharp grazing fold at Omega ~0.9698 its points
came within the join distance of the fold's other side: the march took that for the loop
closing, and a closed loop is not traced backward, so 0.6 .. 0.7356 was never traced.

The oracle is ``tests/impact_pair_oracle.py``, independent of perturb: the two masses
integrated by ``solve_ivp`` (DOP853, rtol = atol = 1e-12, ``max_step`` T/2000 so that no
shallow contact between two steps goes unseen) one contact state at a time (terminal events at
``|x1 - x2| = d``), Newton on the period map with a central-difference Jacobian from a fixed
start state.  The test asks that a branch of the exact response crosses Omega = 0.65 at the
oracle's max |x1|, and that the oracle's orbit is isolated and unstable there.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from impact_pair_oracle import P_DEFAULT, flow, monodromy, periodic_orbit

from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import exact_branches

D = P_DEFAULT["d"]
WINDOW = (0.6, 1.4)
OMEGA = 0.65
#: (x1, x2, x1', x2') at t = 0 near the orbit (a DOP853-shot orbit at Omega = 0.6505)
START = np.array([1.001282, 1.470803, -0.065087, 0.634958])


def _oracle_orbit(W: float, y0: np.ndarray):
    """The oracle's orbit, its period-map Jacobian, its switches per period and x1, x1 - x2
    and the contact state sampled over the period (~4000 samples per period)."""
    y = periodic_orbit(W, y0)
    J = monodromy(W, y)
    fl = flow(W, y, dense=True)
    T = 2.0 * math.pi / W
    xs, gaps, sides = [], [], []
    for t0, t1, side, sol in fl.segments:
        Y = sol(np.linspace(t0, t1, 2 + int(4000 * (t1 - t0) / T)))
        xs.append(Y[0])
        gaps.append(Y[0] - Y[1])
        sides.append(np.full(Y.shape[1], side))
    return y, J, fl.switches, np.hstack(xs), np.hstack(gaps), np.hstack(sides)


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
