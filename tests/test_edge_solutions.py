"""perturb.numeric.edge_solutions: HB solutions at a window edge reached from known ones.

The case of issue 16's coverage gap (bench_impact_pair_galerkin.md, section 4): the impact
pair (builtin defaults, mu2 = 0.01) has at Omega = 0.8 an unstable multi-impact orbit (10
contact switches per period, largest multiplier ~8) on a branch with both ends on the low
edge of the window (0.8, 1.3); no seed there converges to it. The oracle is the exact orbit,
shot by ``tests/impact_pair_oracle.py`` (DOP853, rtol = atol = 1e-12, max_step T/2000,
restarted at every contact switch, finite-difference Newton on the period map) from the state
the brief gives (periodic to 3e-12 there: Newton takes no step); nothing of perturb's exact
solvers is used.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from impact_pair_oracle import flow, periodic_orbit

from perturb.errors import ParameterError
from perturb.model.system_builtins import builtin_system
from perturb.numeric.edge_solutions import edge_solutions
from perturb.numeric.system_balance import SystemBalance

W = 0.8
H = 15
#: State (x1, x2, x1', x2') at t = 0 of the unstable orbit (the brief's example state).
Y_TARGET = np.array([2.279620860783, 2.597551100167, 0.273568064789, 0.979483535735])
#: A state of the branch the response traces to the edge (the stable-and-unstable impacting
#: branch on 0.8..1.012); its HB solution is the known solution the search starts from.
Y_KNOWN = np.array([2.350279500737, 2.730798403567, 0.347915076992, 0.709499209407])


def _orbit_samples(y0, n=8192):
    """n samples over one period of the oracle's orbit from ``y0`` (state rows)."""
    T = 2 * math.pi / W
    t = np.linspace(0.0, T, n, endpoint=False)
    Y = flow(W, y0, dense=True).sample(t)
    assert Y.shape[1] == n
    return t, Y


def _cut_series(sb, Y):
    """The orbit's Fourier coefficients up to H (theta = W t), laid out as sb's unknowns."""
    n = Y.shape[1]
    out = np.zeros((sb.neq, sb.size))
    theta = 2 * math.pi * np.arange(n) / n
    for j in range(sb.neq):
        x = Y[j]
        out[j, 0] = x.mean()
        for col_a, col_b, k in zip(sb.basis.a_index, sb.basis.b_index, sb.basis.k, strict=True):
            out[j, col_a] = 2 * np.mean(x * np.cos(k * theta))
            out[j, col_b] = 2 * np.mean(x * np.sin(k * theta))
    return out.reshape(-1)


def _case():
    sb = SystemBalance(builtin_system("impact_pair"), H)
    y_known = periodic_orbit(W, Y_KNOWN)
    _, Yk = _orbit_samples(y_known, 2048)
    known = sb.solve(W, _cut_series(sb, Yk))
    y_target = periodic_orbit(W, Y_TARGET)
    t, Y = _orbit_samples(y_target)
    return sb, known, y_target, Y


@pytest.fixture(scope="module")
def case():
    return _case()


def test_edge_solutions_reach_the_unstable_multi_impact_orbit(case):
    sb, known, y_target, Y = case
    new = edge_solutions(sb, W, known=[known], outward=-1, margin=0.05, homotopy_points=0)
    assert 1 <= len(new) <= 16
    assert all(np.abs(u - known).max() > 1e-6 * np.abs(known).max() for u in new)
    # each is an HB solution at W
    for u in new:
        assert np.linalg.norm(sb.residual(u, W)) < 1e-8 * max(1.0, np.abs(u).max())
    # the one whose state at t = 0 is nearest the exact orbit's
    basis = sb.basis

    def state0(u):
        U = sb.unpack(u)
        x = U @ basis.design(np.array([0.0]))[0]
        v = W * (U @ basis.design(np.array([0.0]), derivative=1)[0])
        return np.concatenate([x, v])

    dist = [np.abs(state0(u) - y_target).max() for u in new]
    u = new[int(np.argmin(dist))]
    # the same orbit: its HB state at t = 0 is 4e-2 from the exact one (truncation: x2' jumps
    # at the contacts), the other orbits at the edge (the mirror image on the other branch of
    # the pair, the known branch's end) start 0.27-1.2 away
    assert min(dist) < 0.1
    # max|x1| against the exact orbit's, at the truncation level: the exact orbit's Fourier
    # tail beyond H has sup norm `tail`; the Galerkin error of this PWL orbit at H <= 20 is
    # 2.8-4x that tail's sup norm (bench_impact_pair_galerkin.md), so 5 tail is the bound
    exact = float(np.abs(Y[0]).max())
    cut = _cut_series(sb, Y).reshape(sb.neq, sb.size)[0]
    theta = 2 * math.pi * np.arange(Y.shape[1]) / Y.shape[1]
    tail = float(np.abs(Y[0] - basis.evaluate(cut, theta)).max())
    err = abs(sb.max_abs(u, W, "x1") - exact)
    assert err <= 5.0 * tail, (err, tail, exact)
    assert err <= 2e-2 * exact
    # unstable, as the exact orbit
    mult = float(np.abs(sb.multipliers(u, W)).max())
    print(
        f"new {len(new)}, state distance {min(dist):.2e}, max|x1| exact {exact:.6f} error "
        f"{err:.2e}, tail {tail:.2e}, largest multiplier {mult:.3g}"
    )
    assert mult > 1.0 + 1e-3


def test_edge_solutions_bounds_and_arguments(case):
    sb, known, _, _ = case
    # nothing to do: no outward margin and no homotopy
    assert edge_solutions(sb, W, known=[known], outward=0, homotopy_points=0) == []
    # max_new caps what is returned
    assert (
        len(
            edge_solutions(
                sb, W, known=[known], outward=-1, margin=0.05, max_new=1, homotopy_points=0
            )
        )
        <= 1
    )
    for bad in (
        {"outward": 2},
        {"lam_range": (1.5, 2.0)},
    ):
        with pytest.raises(ParameterError):
            edge_solutions(sb, W, known=[known], **bad)
    with pytest.raises(ParameterError):
        edge_solutions(sb, -1.0, known=[known])


def test_response_traces_the_pair_that_leaves_and_reenters_through_the_low_edge(case):
    """system_balance_response over (0.8, 1.3) (attractor stage off, so only the seeds and
    the edge stage can reach it): a branch passes through the HB image of the exact unstable
    orbit at the edge. Without the edge stage the nearest traced state at 0.8 is 0.18 away
    (measured: 4 branches, none through it); with it 0.04 (6 branches)."""
    from perturb.numeric.system_balance import system_balance_response

    sb, _, y_target, Y = case
    resp = system_balance_response(
        builtin_system("impact_pair"), (0.8, 1.3), harmonics=H, attractors=False
    )
    exact = float(np.abs(Y[0]).max())
    best = (np.inf, None)
    for br in resp.branches:
        om = np.asarray(br.Omega)
        states = br.states(0.0)
        for i in np.flatnonzero(np.abs(om - W) <= 1e-9):
            d = float(np.abs(states[i] - y_target).max())
            if d < best[0]:
                best = (d, br.U.reshape(len(br), -1)[i])
    # the same threshold as above: the other orbits at the edge start 0.18-1.2 away
    assert best[0] < 0.1, best[0]
    assert abs(sb.max_abs(best[1], W, "x1") - exact) <= 2e-2 * exact
