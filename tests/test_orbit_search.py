"""``periodic_orbits`` finds every orbit that exact continuation finds at one frequency
(issue 18, item 3d).

Oracle: :func:`perturb.simulate.exact_response.exact_branches` traced over a window (its own
sweeps and closed-form seeds, no input from ``periodic_orbits``), each crossing of a branch
with the frequency polished by shooting at exactly that frequency. Every orbit found must be a
true periodic orbit: checked independently by solve_ivp (DOP853, rtol 1e-11) from each of 32
points along it to the next (so strongly unstable orbits are checked too).

Before the harmonic-balance multi-start (grid of first- and superharmonic starts, closed-form
segment states, deflation near folds) and the mirror images, ``periodic_orbits`` found 3 of 5
orbits at nsd k = -2, Omega = 0.6 and 0.9, and 3 of 9 at k = -3, Omega = 0.6.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb.model.builtins import builtin_model
from perturb.simulate.exact_response import exact_branches
from perturb.solve import periodic_orbits

MU, F = 0.05, 2.0


def _crossings(found, W):
    out = []
    for br in found.branches:
        p = np.asarray(br.parameters)
        for j in np.flatnonzero((p[:-1] - W) * (p[1:] - W) <= 0.0):
            if p[j] == p[j + 1]:
                continue
            orbit = br.orbit_at(int(j), W)
            if orbit is not None and not any(_same(orbit, o) for o in out):
                out.append(orbit)
    return out


def _same(a, b, rtol=1e-5):
    scale = max(1.0, a.amplitude)
    return abs(a.amplitude - b.amplitude) < rtol * scale and abs(a.mean - b.mean) < rtol * scale


def _verify(orbit, k, W, n=32):
    """Integrate x'' + mu x' + f(x) = F cos(W t) between consecutive points of the orbit."""

    def rhs(t, y):
        x, v = y
        f = k * x + (1 - k) * ((x - 1) * (x > 1) + (x + 1) * (x < -1))
        return [v, F * np.cos(W * t) - MU * v - f]

    T = 2 * np.pi / W
    t, x, v = orbit.sample(n)
    pts = np.column_stack([x, v])
    scale = max(1.0, float(np.abs(pts).max()))
    worst = 0.0
    for i in range(n):
        sol = solve_ivp(rhs, (t[i], t[i] + T / n), pts[i], method="DOP853", rtol=1e-11, atol=1e-12)
        worst = max(worst, float(np.abs(sol.y[:, -1] - pts[(i + 1) % n]).max()))
    return worst / scale


def _check(k, window, frequencies):
    osc = builtin_model("nsd", k=k, mu=MU, F=F)
    found = exact_branches(osc, window, workers=1, progress=False)
    for W in frequencies:
        exact = _crossings(found, W)
        got = periodic_orbits(osc, W)
        missed = [(o.amplitude, o.mean) for o in exact if not any(_same(o, g) for g in got)]
        assert not missed, f"k = {k}, Omega = {W}: missed {missed}"
        for g in got:  # orbits continuation did not reach must still be true orbits
            assert _verify(g, k, W) < 1e-6, (k, W, g.amplitude, g.mean)
        # mirror pairs are complete: (x, t) -> (-x, t + T/2) maps orbits to orbits
        for g in got:
            assert any(
                abs(h.amplitude - g.amplitude) < 1e-6 * max(1, g.amplitude)
                and abs(h.mean + g.mean) < 1e-6 * max(1, g.amplitude)
                for h in got
            )


def test_nsd_k_minus_2_all_orbits_found():
    """Includes the issue's example: Omega = 1.5 has two stable one-well orbits (max|x| 4.597,
    mean +-3) and the unstable symmetric orbit."""
    _check(-2.0, (0.5, 1.7), (0.6, 0.9, 1.5))
    orbits = periodic_orbits(builtin_model("nsd", k=-2.0, mu=MU, F=F), 1.5)
    stable = [o for o in orbits if o.max_multiplier < 1]
    assert len(stable) == 2
    np.testing.assert_allclose([o.amplitude for o in stable], 4.597127752745, rtol=1e-9)
    np.testing.assert_allclose(sorted(o.mean for o in stable), [-3.0, 3.0], atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("k", [-0.5, -3.0])
def test_nsd_all_orbits_found(k):
    _check(k, (0.2, 2.2), (0.6, 0.9, 1.5))
