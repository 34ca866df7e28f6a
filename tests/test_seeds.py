"""The reference solvers need no approximation, and a seed only starts Newton.

:mod:`perturb.seeds` is the one bridge from the approximations to the exact solvers of
:mod:`perturb.simulate` (and to the seeding of numeric harmonic balance).  These tests check
the two promises of that design:

- without any approximation seed the exact search still finds the orbits that its own
  closed-form seeds and attractors reach, and they are the same orbits as with the seeds;
- a seed never decides an orbit: a deliberately bad seed yields nothing or a true orbit.

Oracles independent of the code under test: the closed-form steady states of the linear
segments of ``nsd`` (an orbit that stays in one segment is the forced response of that linear
system), and periodicity checked by SciPy's ``solve_ivp`` on a right-hand side written here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb import builtin_model
from perturb.methods.harmonic_balance import single_harmonic_balance
from perturb.numeric.harmonic_balance import harmonic_balance_branches
from perturb.seeds import approximation_seeds, periodic_orbit_guesses, single_harmonic_seeds
from perturb.simulate.exact_response import exact_branches
from perturb.simulate.orbits.search import periodic_orbits as search_orbits
from perturb.solve import periodic_orbits

K, MU, F, W = -2.0, 0.05, 2.0, 1.5


def _nsd_rhs(k: float, mu: float, F_: float, W_: float):
    """``x'' + mu x' + g(x) = F cos(W t)``, ``g`` slope ``k`` inside ``|x| < 1`` and 1 outside
    (continuous): written from the model's definition, not taken from the package."""

    def g(x: float) -> float:
        if x > 1.0:
            return k + (x - 1.0)
        if x < -1.0:
            return -k + (x + 1.0)
        return k * x

    def rhs(t, y):
        return [y[1], F_ * math.cos(W_ * t) - mu * y[1] - g(y[0])]

    return rhs


def _periodic_residual(y0, k=K, mu=MU, F_=F, W_=W) -> float:
    """``|y(T) - y(0)|`` after one forcing period, relative to ``max(1, |y0|)``."""
    T = 2.0 * math.pi / W_
    sol = solve_ivp(
        _nsd_rhs(k, mu, F_, W_), (0.0, T), np.asarray(y0, float), rtol=1e-11, atol=1e-12
    )
    y1 = sol.y[:, -1]
    return float(np.max(np.abs(y1 - y0)) / max(1.0, float(np.max(np.abs(y0)))))


def _closed_forms(k=K, mu=MU, F_=F, W_=W) -> list[tuple[float, float]]:
    """(amplitude max|x|, mean) of the three orbits of nsd at W that stay in one segment: one
    per outer well (slope 1 about x = +-(1 - k) ... the static point +-3 for k = -2) and the
    saddle orbit of the middle segment (slope k about 0)."""
    outer = F_ / abs(complex(1.0 - W_ * W_, mu * W_))
    centre = 1.0 - k  # the outer segments' static point: g(x) = 0 at x = +-(1 - k)
    inner = F_ / abs(complex(k - W_ * W_, mu * W_))
    return sorted([(centre + outer, centre), (centre + outer, -centre), (inner, 0.0)])


def _key(orbits) -> list[tuple[float, float]]:
    return sorted((o.amplitude, o.mean) for o in orbits if o.m == 1)


def test_exact_search_without_approximation_seeds_finds_the_closed_form_orbits():
    osc = builtin_model("nsd", k=K, mu=MU, F=F)
    bare = search_orbits(osc, W)  # attractors and closed-form segment orbits only
    got = _key(bare)
    want = _closed_forms()
    assert len(got) == len(want) == 3
    for (a, m), (a0, m0) in zip(got, want, strict=True):
        assert a == pytest.approx(a0, rel=1e-8)
        assert m == pytest.approx(m0, abs=1e-7)
    for o in bare:
        assert _periodic_residual(o.y0) < 1e-7


def test_approximation_seeds_add_orbits_but_never_change_the_ones_found_without():
    osc = builtin_model("nsd", k=K, mu=MU, F=F)
    bare = search_orbits(osc, W)
    seeded = periodic_orbits(osc, W)  # the front door adds perturb.seeds' guesses
    assert len(seeded) >= len(bare)
    for o in bare:
        scale = max(1.0, float(np.max(np.abs(o.y0))))
        assert any(float(np.max(np.abs(o.y0 - s.y0))) < 1e-7 * scale for s in seeded)
    # every orbit the seeds brought in is an orbit of the exact flow
    for s in seeded:
        assert _periodic_residual(s.y0) < 1e-6


def test_a_bad_seed_does_not_make_a_bad_orbit():
    """Node guesses that are no orbit at all (a large circle, a point far away) and a seed of
    the exact continuation far from every orbit: nothing is accepted that the exact flow does
    not confirm."""
    osc = builtin_model("nsd", k=K, mu=MU, F=F)
    theta = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    circle = np.column_stack([40.0 * np.cos(theta), 40.0 * np.sin(theta)])
    far = np.tile([25.0, -60.0], (16, 1))
    bare = search_orbits(osc, W)
    bad = search_orbits(osc, W, node_guesses=[circle, far], guesses=[[1e3, -1e3]])
    for o in bad:
        assert _periodic_residual(o.y0) < 1e-7
    # nothing spurious: whatever the bad seeds reached is one of the closed-form orbits
    assert len(_key(bad)) == len(_key(bare))
    np.testing.assert_allclose(np.array(_key(bad)), np.array(_key(bare)), rtol=1e-7, atol=1e-7)

    res = exact_branches(
        osc,
        (1.45, 1.55),
        seeds=[(W, (80.0, -80.0))],
        sweep_points=0,
        closed_form=False,
        symmetry=False,
        branch_points=False,
        progress=False,
        workers=1,
    )
    points = [p for br in res.branches for p in br.points]
    if not points:  # the seed did not converge: said so
        assert any("did not converge" in n for n in res.notes)
    for p in points[:: max(1, len(points) // 5)]:
        assert _periodic_residual(np.asarray(p.y0), W_=p.parameter) < 1e-6


def test_approximation_seeds_lie_in_the_window_and_start_shooting_onto_orbits():
    """Single-harmonic balance seeds for the exact continuation of Duffing: in the window,
    finite, and close to an exact orbit (its harmonic content is small), which shooting from
    them reaches (through the front door of the search at the seed's frequency)."""
    osc = builtin_model("duffing")
    window = (0.6, 1.8)
    seeds = approximation_seeds(single_harmonic_balance(osc), window, 3)
    assert seeds
    for w, y in seeds:
        assert window[0] <= w <= window[1]
        assert y.shape == (2,) and np.all(np.isfinite(y))
    w, y = seeds[len(seeds) // 2]
    orbits = search_orbits(osc, w, guesses=[y], grid=1, transient_periods=1)
    near = [o for o in orbits if float(np.max(np.abs(o.y0 - y))) < 0.1 * max(1.0, abs(y[0]))]
    assert near


def test_periodic_orbit_guesses_are_node_arrays():
    osc = builtin_model("nsd", k=-3.0, mu=MU, F=F)
    guesses = periodic_orbit_guesses(osc, 0.6)
    assert guesses
    for g in guesses:
        assert g.ndim == 2 and g.shape[1] == 2 and np.all(np.isfinite(g))


def test_numeric_harmonic_balance_runs_without_approximation_seeds():
    """Without seeds numeric HB still traces the connected branch and the branches of its
    own linear-segment seeds; the approximation seeds only add branches; a seed function that
    returns nonsense adds no branch whose points are not HB solutions."""
    osc = builtin_model("nsd", k=-3.0, mu=MU, F=F)
    window = (0.2, 2.0)
    plain = harmonic_balance_branches(osc, window, harmonics=5, branch_points=False)
    seeded = harmonic_balance_branches(
        osc, window, harmonics=5, branch_points=False, seeds=single_harmonic_seeds
    )
    assert plain[0].origin == "start"
    assert len(seeded) >= len(plain)

    def nonsense(system, window_, per_branch):
        rng = np.random.default_rng(3)
        return [(1.0, 50.0 * rng.standard_normal(system.basis.size)) for _ in range(3)]

    bad = harmonic_balance_branches(
        osc, window, harmonics=5, branch_points=False, mirror=False, seeds=nonsense
    )
    for br in bad:
        sys_ = br.system
        for W_, u in list(zip(br.omega, br.coefficients, strict=True))[::10]:
            r = sys_.residual(u, float(W_))
            assert float(np.max(np.abs(r))) < 1e-7 * max(1.0, float(np.max(np.abs(u))))
