"""derivations/zou_nagarajaiah.py in fast mode: its numerical claims against oracles written
here (an independent energy-integral quadrature, long ``solve_ivp`` runs of the equation of
motion), and its output files."""

from __future__ import annotations

import importlib.util
import math
import re
import sys
from pathlib import Path

import mpmath as mp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

SCRIPT = Path(__file__).resolve().parents[1] / "derivations" / "zou_nagarajaiah.py"


@pytest.fixture(scope="module")
def zn():
    spec = importlib.util.spec_from_file_location("zou_nagarajaiah_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve annotations through sys.modules
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------------------------------
# oracles, independent of the script and of perturb
# ------------------------------------------------------------------------------------------
def nsd_force(x, k):
    x = np.asarray(x, float)
    return k * x + (1 - k) * (np.maximum(x - 1, 0.0) + np.minimum(x + 1, 0.0))


def nsd_rhs(k, mu, F, W):
    def rhs(t, y):
        return [y[1], F * math.cos(W * t) - mu * y[1] - float(nsd_force(y[0], k))]

    return rhs


def integrate(k, mu, F, W, y0, periods, samples_per_period=400):
    """DOP853 with tight tolerances; samples of the last period."""
    T = 2 * math.pi / W
    t_last = np.linspace((periods - 1) * T, periods * T, samples_per_period + 1)
    sol = solve_ivp(
        nsd_rhs(k, mu, F, W),
        (0.0, periods * T),
        np.asarray(y0, float),
        method="DOP853",
        rtol=1e-11,
        atol=1e-11,
        t_eval=t_last,
        dense_output=True,
    )
    assert sol.status == 0
    return sol


def peak_of(sol):
    """max |x| over the sampled period, refined on the dense output near the best sample."""
    x = sol.y[0]
    i = int(np.argmax(np.abs(x)))
    lo = sol.t[max(i - 1, 0)]
    hi = sol.t[min(i + 1, x.size - 1)]
    fine = np.linspace(lo, hi, 2001)
    return float(np.max(np.abs(sol.sol(fine)[0])))


def potential(x, k):
    ax = abs(x)
    return k * x * x / 2 + ((1 - k) * (ax - 1) ** 2 / 2 if ax > 1 else 0)


def _bisect(f, lo, hi):
    flo, fhi = f(lo), f(hi)
    if flo == 0:
        return lo
    if fhi == 0:
        return hi
    assert flo * fhi < 0, (lo, hi)
    for _ in range(200):
        mid = (lo + hi) / 2
        fm = f(mid)
        if fm == 0:
            return mid
        lo, flo, hi = (mid, fm, hi) if fm * flo > 0 else (lo, flo, mid)
    return (lo + hi) / 2


def energy_period(A, k):
    """T = 2 int_a^b dx / sqrt(2 (G(A) - G(x))) between the turning points of the orbit
    through (A, 0): the other turning point by bisection on G(x) = G(A) in the interval where
    it must lie, the integral with x = (a + b)/2 - (b - a)/2 cos(theta) (no endpoint
    singularity), split where G changes form and at x = 0."""
    with mp.workdps(40):
        A, k = mp.mpf(A), mp.mpf(k)
        E = potential(A, k)
        xb, xc, xd = 1 - k, 1 - 2 * k, 1 - k + mp.sqrt(k * (k - 1))
        if A > xd:
            other = -A
        else:
            if A < 1:
                lo, hi = xc, xd
            elif A < xb:
                lo, hi = xb, xc
            elif A <= xc:
                lo, hi = mp.mpf(1), xb
            else:
                lo, hi = mp.mpf(0), mp.mpf(1)
            other = _bisect(lambda x: potential(x, k) - E, lo, hi)
        a, b = min(A, other), max(A, other)
        c, r = (a + b) / 2, (b - a) / 2
        cuts = [mp.mpf(0), mp.pi] + [mp.acos((c - x) / r) for x in (-1, 0, 1) if a < x < b]

        def integrand(th):
            x = c - r * mp.cos(th)
            d = E - potential(x, k)
            # nodes within rounding of a turning point: a finite integrand, negligible weight
            return r * mp.sin(th) / mp.sqrt(2 * d) if d > 0 else mp.mpf(0)

        return float(2 * mp.quad(integrand, sorted(cuts)))


# ------------------------------------------------------------------------------------------
# free vibration
# ------------------------------------------------------------------------------------------
def test_free_period_matches_the_energy_integral(zn):
    k = zn.K_FREE
    fp = zn.free_periods(k, fast=True)
    pick = fp["pick"]
    amps, shoot = fp["amplitudes"][pick], fp["shooting"][pick]
    assert set(fp["regimes"][pick]) == {"one well", "outer segment", "three segments"}
    for A, T in zip(amps, shoot, strict=True):
        assert T == pytest.approx(energy_period(A, k), rel=1e-10), A
        assert float(zn.period_closed_form(A, k)) == pytest.approx(T, rel=1e-10)
    assert fp["closed_vs_quad"] < 1e-25
    # the period diverges at the separatrix and tends to 2 pi
    assert energy_period(5.4495, k) > 15 and abs(energy_period(200.0, k) / (2 * np.pi) - 1) < 0.02


# ------------------------------------------------------------------------------------------
# Fig. 5: one stable period-1 orbit, but not one attractor
# ------------------------------------------------------------------------------------------
def test_fig5_one_stable_period_one_orbit(zn):
    k, mu, F, W = (zn.FIG5[n] for n in ("k", "mu", "F", "Omega"))
    orbits = zn.fig5_orbits(fast=True)
    stable = [o for o in orbits if o.is_stable]
    assert len(stable) == 1
    orbit = stable[0]
    # a long independent run from a state 0.2 off the orbit returns to it
    sol = integrate(k, mu, F, W, orbit.y0 + np.array([0.2, -0.1]), 60)
    assert peak_of(sol) == pytest.approx(orbit.amplitude, rel=1e-7)
    np.testing.assert_allclose(sol.y[:, -1], orbit.y0, atol=1e-6)
    # the saddle orbit inside |x| < 1 is the linear closed form F/|k - W^2 + i mu W|
    assert orbits[0].amplitude == pytest.approx(F / abs(complex(k - W * W, mu * W)), rel=1e-9)


@pytest.mark.slow
def test_fig5_every_reported_attractor_is_real(zn, tmp_path):
    run = zn.Run(tmp_path, fast=True)
    part = zn.one_limit_cycle(run)
    k, mu, F, W = (zn.FIG5[n] for n in ("k", "mu", "F", "Omega"))
    T = 2 * math.pi / W
    assert part.numbers["stable"] == 1
    for a in [a for a in part.numbers["attractors"] if a.m > 1]:
        # it closes after m periods and attracts a perturbed start, independently integrated
        sol = solve_ivp(
            nsd_rhs(k, mu, F, W), (0, a.m * T), a.y0, method="DOP853", rtol=1e-12, atol=1e-12
        )
        np.testing.assert_allclose(sol.y[:, -1], a.y0, atol=1e-6)
        back = integrate(k, mu, F, W, a.y0 + np.array([1e-3, 0.0]), 14 * a.m)
        pts = []
        y = np.array(a.y0, float)
        for _ in range(a.m):
            y = solve_ivp(
                nsd_rhs(k, mu, F, W), (0, T), y, method="DOP853", rtol=1e-12, atol=1e-12
            ).y[:, -1]
            pts.append(y)
        assert min(np.max(np.abs(back.y[:, -1] - p)) for p in pts) < 1e-5
    assert (part.numbers["verdict"] == "matches") == (len(part.numbers["attractors"]) == 1)
    for name in ("fig05_limit_cycle.png", "fig05_orbits.csv", "fig05_basins.csv"):
        assert (tmp_path / "zou_nagarajaiah" / name).stat().st_size > 0


# ------------------------------------------------------------------------------------------
# Fig. 11: negative stiffness plus damping lowers the peak restoring force
# ------------------------------------------------------------------------------------------
def check_peaks(P, F):
    """Each reported resonance peak, integrated independently: the orbit closes, with the
    same peak displacement and peak spring force, and it is stable (a kicked start comes
    back). Returns the peak forces measured here."""
    force = {}
    for name, p in P.items():
        assert np.isfinite(p.amplitude) and not p.at_edge, (F, name, p)
        y0 = np.array(p.y0)
        sol = integrate(p.k, p.mu, F, p.Omega, y0, 3)
        np.testing.assert_allclose(sol.y[:, -1], y0, atol=1e-6 * np.max(np.abs(y0)))
        x = sol.sol(np.linspace(sol.t[0], sol.t[-1], 20001))[0]
        assert peak_of(sol) == pytest.approx(p.amplitude, rel=1e-7), (F, name)
        force[name] = float(np.max(np.abs(nsd_force(x, p.k))))
        assert force[name] == pytest.approx(p.restoring_force, rel=1e-6), (F, name)
        kick = 1e-3 * np.max(np.abs(y0))
        back = integrate(p.k, p.mu, F, p.Omega, y0 + [kick, 0.0], 20)
        assert np.max(np.abs(back.y[:, -1] - y0)) < 0.5 * kick, (F, name)
    return force


def test_force_reduction_conclusion(zn):
    """A: k = 6, mu = 0.1; B: k = -1, mu = 0.1; C: k = -1, mu = 0.2; D: k = 6, mu = 0.2."""
    P = zn.design_points(2.0, zn.FirstOrderPeaks(), fast=True)
    force = check_peaks(P, 2.0)
    assert force["B"] < force["A"] and force["C"] < force["D"]
    assert force["C"] < min(force["A"], force["B"], force["D"])
    assert force["C"] / force["A"] - 1 < -0.5
    # negative stiffness alone costs displacement; more damping takes it back
    assert P["B"].amplitude > P["A"].amplitude and P["C"].amplitude < P["B"].amplitude


@pytest.mark.slow
def test_capacity_demand_part(zn, tmp_path):
    run = zn.Run(tmp_path, fast=True)
    part = zn.capacity_demand(run, zn.FirstOrderPeaks())
    for F in (2.0, 1.0):
        P = part.numbers[F]["points"]
        force = check_peaks(P, F)
        red = part.numbers[F]["restoring"]
        assert red["B/A"] == pytest.approx(force["B"] / force["A"] - 1, abs=1e-6)
        assert red["B/A"] < 0 and red["C/D"] < 0 and red["C/A"] < -0.5
    assert "holds in sign" in part.tex
    assert (tmp_path / "zou_nagarajaiah" / "fig11_capacity_demand.csv").stat().st_size > 0


# ------------------------------------------------------------------------------------------
# the whole script
# ------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_whole_script_fast_mode(zn, tmp_path):
    assert zn.main(["--fast", "--out", str(tmp_path)]) == 0
    out = tmp_path / "zou_nagarajaiah"
    section = (out / "section.tex").read_text()
    assert section.startswith(r"\section{Zou \& Nagarajaiah")
    # every figure and input the section names exists, relative to the root
    named = re.findall(r"\\(?:includegraphics\[[^]]*\]|input)\{([^}]+)\}", section)
    assert len(named) >= 12
    for rel in named:
        assert (tmp_path / rel).stat().st_size > 0, rel
    for name in (
        "fig16_period.csv",
        "fig05_attractors.csv",
        "fig11_capacity_demand.csv",
        "fig17_errors.csv",
        "fig18_limit_cycles.csv",
        "fig19_errors.csv",
        "fig06a_bifurcation.csv",
        "fig09a_peaks.csv",
        "fig13_time_history.csv",
        "mlp_order1.tex",
        "mlp_order2.tex",
        "log.txt",
    ):
        assert (out / name).stat().st_size > 0, name
    assert (out / "fig17_frequency_response.png").read_bytes()[:4] == b"\x89PNG"
    # first-order mLP reproduces the exact resonant branches of Fig. 17 off the folds
    rows = (out / "fig17_errors.csv").read_text().splitlines()[1:]
    for row in rows:
        k, _, _, method, matched, _, _, off_folds, *_ = row.split(",")
        assert int(matched) >= 1, row
        assert float(off_folds) < 0.25, row
