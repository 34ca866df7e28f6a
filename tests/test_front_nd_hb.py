"""Front doors for systems (issue 16 item 3): the symbolic single-harmonic balance of a
system (``hb1`` / ``shb``) through frequency_response, compare per coordinate, bad input.

Oracles, all written here: the single-harmonic balance equations of nsd2 derived by hand from
its equations of motion, with the nonlinear force projected by a 2^16-point rectangle rule
(the force is piecewise linear: its error is O(N^-2), ~1e-9); the exact periodic orbit by
single shooting of the equations of motion (solve_ivp DOP853, rtol = atol = 1e-12, fsolve).
"""

from __future__ import annotations

import numpy as np
import pytest
from nsd2_oracle import P, exact_orbit_max, g
from scipy.integrate import solve_ivp

from perturb.comparison import compare, relative_errors
from perturb.errors import ParameterError, PerturbError
from perturb.model.system_builtins import builtin_system
from perturb.solve import frequency_response

WINDOW = (1.1, 1.3)
THETA = 2 * np.pi * np.arange(2**16) / 2**16


def hand_residuals(W, c, a, b):
    """Single-harmonic balance of nsd2 with means c, cosines a, sines b (per coordinate)."""
    x1 = c[0] + a[0] * np.cos(THETA) + b[0] * np.sin(THETA)
    G0, Gc, Gs = (
        np.mean(g(x1)),
        2 * np.mean(g(x1) * np.cos(THETA)),
        2 * np.mean(g(x1) * np.sin(THETA)),
    )
    mu1, mu2, k2, m2, F = P["mu1"], P["mu2"], P["k2"], P["m2"], P["F"]
    return np.array(
        [
            G0 + k2 * (c[0] - c[1]),
            k2 * (c[1] - c[0]),
            -(W**2) * a[0] + (mu1 + mu2) * W * b[0] - mu2 * W * b[1] + Gc + k2 * (a[0] - a[1]) - F,
            -(W**2) * b[0] - (mu1 + mu2) * W * a[0] + mu2 * W * a[1] + Gs + k2 * (b[0] - b[1]),
            -m2 * W**2 * a[1] + mu2 * W * (b[1] - b[0]) + k2 * (a[1] - a[0]),
            -m2 * W**2 * b[1] - mu2 * W * (a[1] - a[0]) + k2 * (b[1] - b[0]),
        ]
    )


def points(resp, every=7):
    """(W, means, cosines, sines, amplitude_x1, row) of every ``every``-th point."""
    out = []
    for b, br in enumerate(resp.branches):
        cols = resp.columns[b]
        for j in range(0, len(br), every):
            W = float(br.omega[j])
            y = cols["states"][j]
            c = np.array([cols["mean_x1"][j], cols["mean_x2"][j]])
            # an orbit with one harmonic: x(0) = c + a, x'(0) = W b
            out.append((W, c, y[:2] - c, y[2:] / W, float(cols["amplitude_x1"][j])))
    return out


@pytest.fixture(scope="module")
def nsd2():
    return builtin_system("nsd2")


def test_hb1_solves_the_hand_derived_balance(nsd2):
    resp = frequency_response(nsd2, "hb1", WINDOW)
    assert resp.method == "hb1-system" and resp.branches
    pts = points(resp, every=3)
    assert len(pts) >= 6
    for W, c, a, b, amp in pts:
        assert np.abs(c).max() <= 1e-12  # the zero-mean ansatz: odd system, no load
        assert np.abs(hand_residuals(W, c, a, b)).max() <= 1e-7
        assert amp == pytest.approx(np.hypot(a[0], b[0]), rel=1e-9)


def test_shb_with_bias_keeps_the_asymmetric_orbits(nsd2):
    resp = frequency_response(nsd2, "shb", WINDOW, bias=True)
    pts = points(resp, every=5)
    assert any(abs(c[0]) > 1e-3 for _, c, _, _, _ in pts)  # orbits with a mean are there
    for W, c, a, b, _ in pts:
        assert np.abs(hand_residuals(W, c, a, b)).max() <= 1e-7
    # the zero-mean answer holds fewer branches: those with a mean are left out, said so
    hb1 = frequency_response(nsd2, "hb1", WINDOW)
    assert len(hb1.branches) < len(resp.branches)
    assert any("with a mean left out" in n for n in hb1.notes)


def test_compare_per_coordinate_against_exact_orbits(nsd2):
    hb = frequency_response(nsd2, "hb", WINDOW, harmonics=3)
    ex = frequency_response(nsd2, "exact", WINDOW)
    c = compare(hb, ex)
    names = [n for n, _, _ in c.coordinates]
    assert names == ["x1", "x2"]
    assert "coordinate x2" in str(c)
    e2 = relative_errors(hb, ex, quantity="amplitude_x2")
    # the errors of x2's max |.| at points away from the folds, against orbits shot here
    folds = [w for w, _ in hb.folds]
    rows = [(b, j) for b, br in enumerate(hb.branches) for j in range(len(br))]
    checked = 0
    for r in range(0, len(rows), 9):
        b, j = rows[r]
        W = float(hb.branches[b].omega[j])
        if any(abs(W - f) < 0.02 * f for f in folds):
            continue
        _, m2 = exact_orbit_max(W, hb.columns[b]["states"][j])
        own = abs(float(hb.columns[b]["amplitude_x2"][j]) - m2) / m2
        assert e2[r] == pytest.approx(own, rel=0.2, abs=2e-5)
        checked += 1
    assert checked >= 4
    with pytest.raises(ParameterError, match="x3.*x1, x2"):
        relative_errors(hb, ex, quantity="amplitude_x3")


@pytest.mark.parametrize("method", ["hb1", "shb", "hb", "auto", "exact"])
def test_output_not_a_coordinate_names_it(nsd2, method):
    with pytest.raises(PerturbError, match="x3") as info:
        frequency_response(nsd2, method, WINDOW, output="x3")
    assert "x1" in str(info.value) and "x2" in str(info.value)


def test_methods_that_do_not_take_systems_name_those_that_do(nsd2):
    for method in ("mlp", "kb", "ms", "lp"):
        with pytest.raises(ParameterError, match=method) as info:
            frequency_response(nsd2, method, WINDOW)
        for name in ("exact", "hb", "hb1", "shb", "auto"):
            assert name in str(info.value)
    with pytest.raises(ParameterError, match="bias"):
        frequency_response(nsd2, "hb1", WINDOW, bias=True)
    with pytest.raises(ParameterError, match=r"harmonics.*\(1,\)"):
        frequency_response(nsd2, "shb", WINDOW, harmonics=(1, 3))
    with pytest.raises(ParameterError, match="order"):
        frequency_response(nsd2, "hb1", WINDOW, order=2)


def vdp_cycle_oracle(eps):
    """Period and max |x| of the van der Pol limit cycle: a long DOP853 run (rtol 1e-12),
    upward zero crossings of x located on the dense output by brentq."""
    from scipy.optimize import brentq

    def f(t, y):
        return [y[1], eps * (1 - y[0] ** 2) * y[1] - y[0]]

    sol = solve_ivp(
        f, (0, 300), [2.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True
    )
    t = np.linspace(200, 300, 200001)
    x = sol.sol(t)[0]
    idx = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    ups = [brentq(lambda s: sol.sol(s)[0], t[i], t[i + 1], xtol=1e-14) for i in idx]
    period = float(np.mean(np.diff(ups)))
    tt = np.linspace(ups[-2], ups[-1], 200001)
    return period, float(np.abs(sol.sol(tt)[0]).max())


def test_limit_cycles_by_autonomous_balance():
    from perturb.model.system import System
    from perturb.solve import limit_cycles, orbit_columns

    vdp = System.parse(["x'' - eps*(1 - x**2)*x' + x = 0"], {"eps": 1.0})
    period, amp = vdp_cycle_oracle(1.0)
    found = limit_cycles(vdp, method="hb", harmonics=31)
    (cycle,) = found.cycles
    assert cycle.period == pytest.approx(period, rel=1e-9)
    assert orbit_columns(vdp, cycle)["amplitude_x"] == pytest.approx(amp, rel=1e-9)
    assert cycle.stability == "stable"
    # fewer harmonics: a larger error, still measured against the same oracle
    coarse = limit_cycles(vdp, method="hb", harmonics=7).cycles[0]
    assert abs(coarse.period - period) > 1e3 * abs(cycle.period - period)
    with pytest.raises(ParameterError, match="harmonics"):
        limit_cycles(vdp, harmonics=7)
    with pytest.raises(ParameterError, match="grid"):
        limit_cycles(vdp, method="hb", grid=5)
    with pytest.raises(ParameterError, match="'exact'.*'hb'"):
        limit_cycles(vdp, method="shooting")


def test_stepped_sine_sweep_of_a_system(nsd2):
    from perturb.simulate.studies import system_frequency_sweep

    sw = system_frequency_sweep(nsd2, [1.1, 1.125, 1.175], output="x2")
    states = sw.up.states
    periodic = [s for s in states if s.period == 1]
    assert len(periodic) >= 2
    for st in periodic:
        # the settled state at forcing phase 0 is on the period-1 orbit: shoot it here
        m1, m2 = exact_orbit_max(st.omega, st.y_end)
        assert st.amplitude == pytest.approx(m2, rel=1e-6)
        assert st.coordinates["x1"] == pytest.approx(m1, rel=1e-6)
        assert st.coordinates["x2"] == pytest.approx(m2, rel=1e-6)
    # at 1.175 the attractor reached from below is no period-1 orbit (a slow period-3 or a
    # motion not settled in 400 periods): reported, and left out of the response's branch
    assert states[-1].period != 1
    notes = sw.to_response().notes
    assert any("subharmonic" in n or "no periodic response" in n for n in notes)
    with pytest.raises(PerturbError, match="x3"):
        system_frequency_sweep(nsd2, [1.1], output="x3")


def test_grid_sweep_of_a_system_scene(tmp_path):
    import perturb.apps.grid as ps

    # nsd2 with k = 1 is linear: x = Re(X e^{i W t}), (K - W^2 M + i W C) X = (F, 0)
    scene = tmp_path / "sweep.toml"
    scene.write_text(
        '[model]\nsystem = "nsd2"\noutput = "x2"\n[params]\nk = 1.0\n'
        '[ask]\nkind = "frequency_response"\nomega = [0.8, 1.2]\n'
        '[sweep]\nsolver = "simulation"\nquantity = "frequency_response"\nomega_points = 3\n'
        'direction = "up"\n[sweep.params]\nF = "1:2:2"\n'
    )
    ds = ps.sweep(ps.load_sweep_scene(scene), executor="serial", progress=False)
    amp = ds["amplitude"].values  # (F, Omega, direction)
    mu1, mu2, k2, m2 = P["mu1"], P["mu2"], P["k2"], P["m2"]
    K = np.array([[1 + k2, -k2], [-k2, k2]])
    C = np.array([[mu1 + mu2, -mu2], [-mu2, mu2]])
    M = np.diag([1.0, m2])
    for i, F in enumerate((1.0, 2.0)):
        for j, W in enumerate((0.8, 1.0, 1.2)):
            X = np.linalg.solve(K - W**2 * M + 1j * W * C, [F, 0.0])
            assert amp[i, j, 0] == pytest.approx(abs(X[1]), rel=1e-6)
    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[model]\nsystem = "nsd2"\n[ask]\nkind = "frequency_response"\nomega = [0.8, 1.2]\n'
        '[sweep]\nsolver = "approximation"\n[sweep.params]\nF = "1:2:2"\n'
    )
    with pytest.raises(PerturbError, match="stepped-sine"):
        ps.load_sweep_scene(bad)
