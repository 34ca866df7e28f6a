"""The time-history front door and the all-orbits search, against independent oracles."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from perturb import ParameterError, builtin_model
from perturb.apps.cli import main
from perturb.simulate.time_history import time_history
from perturb.solve import periodic_orbits

NSD = dict(k=-2.0, mu=0.05, F=2.0, Omega=0.6)
T = 2 * np.pi / 0.6


def nsd_rhs(t, y, k=-2.0, mu=0.05, F=2.0, W=0.6):
    x, v = y
    f = k * x + (1 - k) * ((x - 1) * (x > 1) + (x + 1) * (x < -1))
    return [v, F * np.cos(W * t) - mu * v - f]


def test_three_integrators_agree_on_an_nsd_time_history():
    osc = builtin_model("nsd", **NSD)
    exact = time_history(osc, [0.3, 0.1], (0, 10 * T), method="exact")
    event = time_history(osc, [0.3, 0.1], (0, 10 * T), method="event")
    assert exact.method == "exact" and exact.n_events > 0
    np.testing.assert_allclose(event.x, exact.x, atol=1e-8)
    # LCP is second order: halving the step divides the error by about four
    errs = []
    for h in (T / 400, T / 800):
        lcp = time_history(osc, [0.3, 0.1], (0, 10 * T), method="lcp", h=h)
        errs.append(np.max(np.abs(lcp.x - exact.x)))
    assert errs[1] < errs[0] / 3 and errs[1] < 1e-2


def test_auto_picks_the_integrator_the_model_needs():
    assert time_history(builtin_model("nsd", **NSD), [0, 0], (0, 1)).method == "exact"
    assert time_history(builtin_model("duffing"), [0, 0], (0, 1)).method == "ode"
    from perturb import Oscillator

    relay = Oscillator.parse("x'' + x + 0.2*sign(x') = 0")
    hist = time_history(relay, [3.37, 0.0], (0, 40))
    assert hist.method == "event"
    # free Coulomb friction: sticks at 3.37 - 8*0.2*... after 7 reversals, at x = 0.17
    assert hist.x[-1] == pytest.approx(0.17, abs=1e-9)
    with pytest.raises(ParameterError, match="method"):
        time_history(relay, [0, 0], (0, 1), method="rk4")
    with pytest.raises(ParameterError, match="t_span"):
        time_history(relay, [0, 0], (1, 0))


def test_all_orbits_at_fig5_parameters():
    orbits = periodic_orbits(builtin_model("nsd", **NSD))
    assert len(orbits) >= 3
    # the saddle orbit inside |x| < 1 is the linear closed form F/|k - W^2 + i mu W|
    small = orbits[0]
    assert small.amplitude == pytest.approx(2.0 / abs(-2.0 - 0.36 + 0.03j), rel=1e-10)
    assert not small.is_stable
    assert sum(o.is_stable for o in orbits) == 1  # the paper: one attractor at these values
    for o in orbits:
        # each orbit closes under an independent integrator (unstable ones amplify its
        # 1e-13 error by their multiplier)
        sol = solve_ivp(nsd_rhs, (0, T), o.y0, method="DOP853", rtol=1e-13, atol=1e-13)
        gap = np.max(np.abs(sol.y[:, -1] - o.y0))
        assert gap < 1e-9 * max(1.0, o.max_multiplier), (o, gap)


def test_cli_simulate_and_periodic(tmp_path, capsys):
    ts = tmp_path / "ts.csv"
    png = tmp_path / "ts.png"
    assert (
        main(
            [
                "simulate",
                "nsd",
                "--param",
                "Omega=0.6",
                "--y0",
                "0.3,0.1",
                "--t",
                "0:20",
                "--samples",
                "11",
                "--out",
                str(ts),
                "--plot",
                str(png),
            ]
        )
        == 0
    )
    rows = list(csv.DictReader(open(ts)))
    assert list(rows[0]) == ["t", "x", "v"] and len(rows) == 11
    sol = solve_ivp(
        nsd_rhs,
        (0, 20),
        [0.3, 0.1],
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        t_eval=[float(r["t"]) for r in rows],
    )
    np.testing.assert_allclose([float(r["x"]) for r in rows], sol.y[0], atol=1e-7)
    assert png.read_bytes()[:4] == b"\x89PNG"
    out = tmp_path / "orbits.csv"
    assert main(["periodic", "nsd", "--omega", "0.6", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out)))
    assert sum(int(r["stable"]) for r in rows) == 1
    assert main(["simulate", "nsd", "--y0", "1"]) == 2
    assert "two finite numbers" in capsys.readouterr().err
