"""Symbolic harmonic balance over a harmonic set (method ``"shb"``) through the front door.

The oracles are independent of the tracer under test (residual continuation of the symbolic
balance system in all its unknowns, :mod:`perturb.numeric.residual`):

- numeric harmonic balance (method ``"hb"``, a different solver: Galerkin projection of the
  equation of motion, its own continuation and seeds) with 3 harmonics. For forced Duffing
  (an odd force) its harmonic 2 and its mean vanish by symmetry, so its solutions are those
  of the balance over the set (1, 3): the same orbits to rounding;
- single-harmonic balance (``"hb1"``, amplitude parametrisation, zero mean by construction)
  for an odd piecewise-linear force, where the balance with a bias must find the mean 0;
- the mirror symmetry ``x -> -x`` of an odd force: off-centre orbits come in pairs.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest

import perturb
from perturb import frequency_response
from perturb.errors import ParameterError


def _points(resp):
    """``(omega, amplitude, first harmonic, mean, stable)`` of every solution, sorted."""
    return sorted(
        (float(w), float(a), float(f), float(m), bool(s))
        for b in resp.branches
        for w, a, f, m, s in zip(
            b.omega, b.amplitude, b.first_harmonic_amplitude, b.mean, b.stable, strict=True
        )
    )


LISTED = [0.8, 1.0, 1.2, 1.5]  # 1.5: three solutions (two stable, one unstable)


@pytest.fixture(scope="module")
def duffing():
    return perturb.builtin_model("duffing")


@pytest.fixture(scope="module")
def numeric_hb(duffing):
    return frequency_response(duffing, "hb", frequencies=LISTED, harmonics=3)


def test_shb_1_3_equals_numeric_hb_3_at_listed_frequencies(duffing, numeric_hb):
    shb = frequency_response(duffing, "shb", frequencies=LISTED, harmonics=(1, 3))
    got, want = _points(shb), _points(numeric_hb)
    assert len(want) == 6  # the oracle's own count: one, one, one and three solutions
    assert [p[0] for p in got] == [p[0] for p in want]  # exactly at the listed frequencies
    for g, w in zip(got, want, strict=True):
        assert g[1] == pytest.approx(w[1], rel=1e-8, abs=1e-10)  # max |x|
        assert g[2] == pytest.approx(w[2], rel=1e-8, abs=1e-10)  # first harmonic
        assert abs(g[3]) < 1e-10 and abs(w[3]) < 1e-10  # no mean (odd force)
        assert g[4] == w[4]  # stability: Hill's method at harmonic 3 on both
    # max |x| is that of the waveform with its third harmonic, not the first harmonic alone
    assert any(g[1] > g[2] * (1 + 1e-3) for g in got)


def test_shb_traced_curve_lies_on_numeric_hb(duffing):
    resp = frequency_response(duffing, "shb", (0.5, 2.0), harmonics=(1, 3))
    assert resp.branches and resp.method.startswith("hb(")
    omega = np.concatenate([b.omega for b in resp.branches])
    assert omega.min() == pytest.approx(0.5) and omega.max() == pytest.approx(2.0)
    # the jump-down fold of the hardening curve lies inside the window
    assert resp.folds
    # a few traced points, each one checked against the numeric HB solutions at its frequency
    picks = []
    for b in resp.branches:
        for j in np.linspace(0, len(b) - 1, 4).astype(int)[1:-1]:
            picks.append((float(b.omega[j]), float(b.amplitude[j]), bool(b.stable[j])))
    ref = frequency_response(duffing, "hb", frequencies=[p[0] for p in picks], harmonics=3)
    by_w: dict[float, list[tuple[float, bool]]] = {}
    for w, a, _, _, s in _points(ref):
        by_w.setdefault(w, []).append((a, s))
    for w, a, s in picks:
        match = [r for r in by_w[w] if abs(r[0] - a) <= 1e-7 * a]
        assert match, (w, a, by_w[w])
        assert match[0][1] == s


def test_shb_bias_on_an_odd_pwl_force_has_zero_mean_and_is_hb1(tmp_path):
    # nsd with k = 0.5: an odd force with two breakpoints and no other equilibrium than 0
    osc = perturb.builtin_model("nsd", k=0.5)
    curve = frequency_response(osc, "shb", (0.3, 2.0), bias=True)
    assert curve.branches
    for b in curve.branches:
        assert np.all(np.abs(b.mean) <= 1e-9 * np.maximum(1.0, b.amplitude))
        # one harmonic plus a zero mean: max |x| is the first harmonic's amplitude
        np.testing.assert_allclose(b.amplitude, b.first_harmonic_amplitude, rtol=1e-12)
    ws = [0.8, 1.2]
    biased = _points(frequency_response(osc, "shb", frequencies=ws, bias=True))
    centred = _points(frequency_response(osc, "hb1", frequencies=ws))
    assert len(biased) == len(centred) >= 2
    for g, w in zip(biased, centred, strict=True):
        assert g[0] == w[0]
        assert g[1] == pytest.approx(w[1], rel=1e-8)
        assert abs(g[3]) < 1e-9


def test_shb_bias_finds_mirror_pairs_of_off_centre_orbits():
    # nsd with k = -2: a double well at x = +-3; orbits about one well have a mean, and the
    # odd force maps each onto its mirror image (mean -b, same amplitude of motion)
    osc = perturb.builtin_model("nsd", k=-2)
    pts = _points(frequency_response(osc, "shb", frequencies=[1.2], bias=True))
    off = [p for p in pts if abs(p[3]) > 1e-6]
    assert off, pts
    for p in off:
        assert any(abs(q[3] + p[3]) < 1e-7 and abs(q[2] - p[2]) < 1e-7 for q in off), p


def test_shb_options_and_refusals(duffing):
    with pytest.raises(ParameterError, match="positive integer"):
        frequency_response(duffing, "shb", (0.5, 2.0), harmonics=(1, 3), seed_frequencies=0)
    with pytest.raises(ParameterError, match="points sets the resolution"):
        frequency_response(duffing, "shb", frequencies=[1.0], harmonics=(1, 3), points=10)
    free = perturb.builtin_model("quadratic_cubic")
    with pytest.raises(ParameterError, match="backbone"):
        frequency_response(free, "shb", (0.5, 1.5), harmonics=(1, 2))


def test_cli_frc_shb_harmonic_set(tmp_path, numeric_hb, capsys):
    from perturb.apps.cli import main

    out = tmp_path / "shb.csv"
    argv = ["frc", "duffing", "--method", "shb", "--harmonics", "1,3", "--omega", "0.8,1.2"]
    assert main([*argv, "--out", str(out)]) == 0
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    got = sorted((float(r["omega"]), float(r["amplitude"])) for r in rows)
    want = [(p[0], p[1]) for p in _points(numeric_hb) if p[0] in (0.8, 1.2)]
    assert len(got) == len(want) == 2
    for g, w in zip(got, want, strict=True):
        assert g[0] == w[0] and g[1] == pytest.approx(w[1], rel=1e-8)
    # a comma list is a harmonic set of shb only; hb keeps its whole number of harmonics
    assert main(["frc", "duffing", "--method", "hb", "--harmonics", "1,3"]) != 0
    assert "for --method shb" in capsys.readouterr().err
    assert main(["frc", "duffing", "--method", "shb", "--harmonics", "one"]) == 2
    assert "invalid value 'one'" in capsys.readouterr().err
