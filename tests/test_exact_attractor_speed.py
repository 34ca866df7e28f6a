"""The vectorised RK4 of the exact response's attractor stage
(:mod:`perturb.simulate.exact_response.attractors`) against a scalar RK4 written here.

The stage's simulation forms the piecewise-affine field of all its trajectories with a few
matrix products (ramps ``max(s, 0)`` of the switching functions, or every region's rows and a
gather), advances the inputs by a rotation instead of cosines, and records each trajectory
at its last two whole periods.  Here each trajectory is stepped alone by the textbook RK4 of
the flow's own scalar data (``PWLSystem.rhs`` of an oscillator; the regions, surfaces and
inputs of a system's ``affine_system``, the region by the signs of ``Surface.value``), with
the forcing evaluated by ``cos``/``sin`` at every stage time, over the same steps.  The two
agree to rounding; a mis-scaled ramp, region row, input or step fails by orders of magnitude
more than the tolerance.  Also: the proximity test ``on_traced`` and ``saddle_starts`` against
plain loops.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perturb.model.builtins import builtin_model
from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import attractors as at
from perturb.simulate.exact_response.options import flow_family
from perturb.simulate.exact_response.problem import Engine, Pt


def _engine(model, window, parameter=None):
    return Engine(flow_family(model, parameter), 1, 0.0, window, 1e-10)


def _scalar_rhs(eng, p):
    """The field at parameter value ``p`` from the flow's scalar data."""
    if not eng.nd:
        system = eng.system(p)
        return lambda t, y: np.asarray(system.rhs(t, y), dtype=float)
    pas = eng.flow(p).affine_system

    def rhs(t, y):
        key = tuple(1 if float(s.value(y)) >= 0.0 else -1 for s in pas.surfaces)
        region = pas.regions[key]
        out = region.A @ y + region.b
        for h in pas.inputs:
            out = out + h.u * math.cos(h.omega * t) + h.v * math.sin(h.omega * t)
        return out

    return rhs


def _scalar_rk4(f, y, t0, h, steps, K):
    """Textbook RK4; the states after the last two whole periods (multiples of K steps)."""
    y = np.array(y, dtype=float)
    marks = {}
    last_at = (steps // K) * K
    for i in range(steps):
        t = t0 + i * h
        k1 = f(t, y)
        k2 = f(t + 0.5 * h, y + 0.5 * h * k1)
        k3 = f(t + 0.5 * h, y + 0.5 * h * k2)
        k4 = f(t + h, y + h * k3)
        y = y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if i + 1 in (last_at - K, last_at):
            marks[i + 1] = y.copy()
    return marks[last_at - K], marks[last_at]


def _compare(eng, ps, starts, K_per_period=(40, 47, 53), periods=3, tol=1e-10):
    """Run _simulate on every start at every parameter value of ps and the scalar RK4 on
    each; assert agreement within tol (relative to max(1, |y|))."""
    field = at._field(eng, ps)
    assert field is not None
    P = np.array([eng.period(float(p)) for p in ps])
    K = np.array(K_per_period[: ps.size])
    cols = np.repeat(np.arange(ps.size), len(starts))
    y = np.tile(np.array(starts, dtype=float).T, (1, ps.size))
    steps = periods * int(K.max())
    prev, last = at._simulate(field, cols, y, K, steps, eng.t0, P)
    worst = 0.0
    for c in range(cols.size):
        i = cols[c]
        f = _scalar_rhs(eng, float(ps[i]))
        h = P[i] / K[i]
        p_ref, l_ref = _scalar_rk4(f, y[:, c], eng.t0, h, steps, int(K[i]))
        size = max(1.0, float(np.max(np.abs(l_ref))))
        err = max(np.max(np.abs(prev[:, c] - p_ref)), np.max(np.abs(last[:, c] - l_ref)))
        worst = max(worst, float(err) / size)
    assert worst <= tol, worst
    # the starts cross the switching surfaces: the states moved by far more than tol
    assert float(np.max(np.abs(last - y))) > 0.1
    return field


NSD2_STARTS = [(1.6, -0.4, 0.3, 0.0), (-2.2, 0.9, -1.0, 0.5), (0.2, 0.1, 2.5, -1.0)]
PAIR_STARTS = [(0.9, 0.1, 0.2, -0.4), (-0.3, 0.6, 1.0, 0.0), (0.0, 0.0, 0.0, 0.0)]
NSD_STARTS = [(1.8, 0.0), (-0.5, 2.5), (0.3, -0.2)]


def test_system_ramps_nsd2_matches_scalar_rk4():
    eng = _engine(builtin_system("nsd2"), (0.5, 2.0))
    ps = np.array([0.55, 1.1, 1.9])
    field = _compare(eng, ps, NSD2_STARTS)
    assert at._ramps(field) is not None  # the ramp form was the one tested


def test_system_ramps_impact_pair_matches_scalar_rk4():
    # the surfaces act on x1 - x2 (not one state): the switching function is a product
    eng = _engine(builtin_system("impact_pair"), (0.6, 1.4))
    ps = np.array([0.7, 1.0, 1.3])
    field = _compare(eng, ps, PAIR_STARTS, K_per_period=(400, 420, 450), periods=2)
    assert at._ramps(field) is not None


def test_oscillator_ramps_matches_scalar_rk4():
    eng = _engine(builtin_model("nsd", k=-3, mu=0.05, F=2), (0.2, 2.5))
    ps = np.array([0.3, 1.0, 2.4])
    field = _compare(eng, ps, NSD_STARTS)
    assert field.own is None and at._ramps(field) is not None


@pytest.mark.parametrize("blocks", [at.MAX_PATTERN_BLOCKS, 0])
def test_region_gather_matches_scalar_rk4(monkeypatch, blocks):
    # the path of a field that is no sum of ramps (a block of rows per sign pattern, or per
    # region with the pattern looked up), forced on nsd2, the impact pair and nsd
    monkeypatch.setattr(at, "_ramps", lambda field: None)
    monkeypatch.setattr(at, "MAX_PATTERN_BLOCKS", blocks)
    _compare(_engine(builtin_system("nsd2"), (0.5, 2.0)), np.array([0.6, 1.7]), NSD2_STARTS)
    _compare(
        _engine(builtin_system("impact_pair"), (0.6, 1.4)),
        np.array([0.8, 1.2]),
        PAIR_STARTS,
        K_per_period=(400, 430),
        periods=2,
    )
    _compare(
        _engine(builtin_model("nsd", k=-3, mu=0.05, F=2), (0.2, 2.5)),
        np.array([0.4, 2.0]),
        NSD_STARTS,
    )


def test_parameter_moving_the_pieces_or_the_input_matches_scalar_rk4():
    model = builtin_model("nsd", k=-0.5, mu=0.05, F=2)
    # k moves the slopes: each column its own pieces
    field = _compare(_engine(model, (-1.0, -0.2), "k"), np.array([-0.9, -0.5]), NSD_STARTS)
    assert field.own is not None
    # F moves the input only: the input per column
    _compare(_engine(model, (1.0, 3.0), "F"), np.array([1.2, 2.8]), NSD_STARTS)
    _compare(_engine(builtin_system("nsd2"), (1.0, 3.0), "F"), np.array([1.5, 2.5]), NSD2_STARTS)


def test_surface_of_opposite_sign_gives_the_same_trajectories():
    # nsd2 with its second surface written as -s(y) >= 0 (its sign bit flipped): the ramp of
    # a surface whose normal's largest entry is negative, which the builtins do not have
    eng = _engine(builtin_system("nsd2"), (0.5, 2.0))
    ps = np.array([0.55, 1.1, 1.9])
    field = _compare(eng, ps, NSD2_STARTS)
    flipped = at._field(eng, ps)
    flipped.normals = field.normals.copy()
    flipped.offsets = field.offsets.copy()
    flipped.normals[1] *= -1.0
    flipped.offsets[1] *= -1.0
    flipped.lookup = np.array([field.lookup[code ^ 2] for code in range(4)])
    assert at._ramps(flipped) is not None
    P = np.array([eng.period(float(p)) for p in ps])
    K = np.array([40, 47, 53])
    cols = np.repeat(np.arange(3), len(NSD2_STARTS))
    y = np.tile(np.array(NSD2_STARTS, dtype=float).T, (1, 3))
    want = at._simulate(field, cols, y, K, 150, eng.t0, P)
    got = at._simulate(flipped, cols, y, K, 150, eng.t0, P)
    for a, b in zip(got, want, strict=True):
        assert np.max(np.abs(a - b)) <= 1e-10 * max(1.0, float(np.max(np.abs(b))))


# ---------------------------------------------------------------------------------------------
# the proximity test and the starts beside unstable orbits, against plain loops
# ---------------------------------------------------------------------------------------------
def _branches(rng, count=4, n=2):
    out = []
    for _ in range(count):
        m = int(rng.integers(1, 30))
        p = np.cumsum(rng.uniform(-0.02, 0.05, m)) + rng.uniform(0.3, 1.5)
        if m > 3:
            p[m // 2] = p[m // 2 - 1]  # a pair at one parameter value
        pts = []
        for j in range(m):
            q = Pt(p[j], rng.normal(size=(1, n)) * 2.0, n)
            q.mult = rng.uniform(0.2, 1.5, n).astype(complex)
            pts.append(q)
        out.append(pts)
    out.append([])
    return out


def _on_traced_loop(internals, p, y, tol):
    size = max(1.0, float(np.max(np.abs(y))))
    for pts in internals:
        if not pts or pts[0].Z.shape[1] != y.size:
            continue
        for j in range(len(pts) - 1):
            a, b = pts[j], pts[j + 1]
            if not min(a.p, b.p) <= p <= max(a.p, b.p):
                continue
            s = 0.0 if b.p == a.p else (p - a.p) / (b.p - a.p)
            if float(np.max(np.abs((1.0 - s) * a.y0 + s * b.y0 - y))) <= tol * size:
                return True
    return False


def _saddle_loop(ps, internals, traced):
    out = []
    for b in traced:
        pts = internals[b]
        for j in range(len(pts) - 1):
            a, c = pts[j], pts[j + 1]
            if not (a.max_mult >= 1.0 or c.max_mult >= 1.0) or a.p == c.p:
                continue
            for i in range(ps.size):
                if min(a.p, c.p) <= ps[i] <= max(a.p, c.p):
                    s = (ps[i] - a.p) / (c.p - a.p)
                    y = (1.0 - s) * a.y0 + s * c.y0
                    d = at.SADDLE_OFFSET * max(1.0, float(np.max(np.abs(y))))
                    for sgn in (1.0, -1.0):
                        z = y.copy()
                        z[0] += sgn * d
                        out.append((i, z))
    return out


def test_on_traced_and_saddle_starts_match_plain_loops():
    rng = np.random.default_rng(7)
    hits = 0
    for trial in range(20):
        internals = _branches(rng)
        poly = at._Polylines()
        for _ in range(30):
            p = float(rng.uniform(0.2, 2.5))
            pts = internals[int(rng.integers(0, len(internals) - 1))]
            if pts and rng.uniform() < 0.5:  # near a point of a branch
                q = pts[int(rng.integers(0, len(pts)))]
                p = q.p if rng.uniform() < 0.5 else q.p + float(rng.normal()) * 1e-3
                y = q.y0 + rng.normal(size=2) * 0.05
            else:
                y = rng.normal(size=2) * 2.0
            for tol in (0.01, 0.05, 0.3):
                want = _on_traced_loop(internals, p, y, tol)
                assert at.on_traced(internals, p, y, tol, poly) == want
                assert at.on_traced(internals, p, y, tol) == want
                hits += want
        if trial % 5 == 0:  # a branch added between calls: the cached arrays are renewed
            extra = [q for q in _branches(rng, 3) if len(q) >= 2][0]
            internals.append(extra)
            assert at.on_traced(internals, extra[1].p, extra[1].y0, 1e-12, poly)
        ps = np.geomspace(0.25, 2.4, 40)
        traced = list(range(len(internals)))
        got, want = at.saddle_starts(ps, internals, traced), _saddle_loop(ps, internals, traced)
        assert len(got) == len(want)
        for (i, z), (k, w) in zip(got, want, strict=True):
            assert i == k and np.array_equal(z, w)
    assert hits > 100  # both answers occurred (273 here)
