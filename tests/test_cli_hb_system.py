"""Numeric multi-harmonic balance of a system through the front doors: the API
(:func:`perturb.solve.frequency_response` with ``method="hb"``) and ``perturb frc
--method hb`` on the 2-DOF negative-stiffness structure ``nsd2``.

Independent check: at points spread along every HB branch the exact periodic orbit is shot
(``periodic_orbit`` on the closed-form ``AffineExactFlow``; the HB state only starts the
shooting) and its ``max |x_k|`` taken from 2^14 uniform samples of the orbit. Measured at
H = 7 on Omega in (1.1, 1.3) at all 101 points (``perturb frc nsd2 --method hb --harmonics 7
--omega 1.1:1.3 --output x2 --compare exact``): relative error of max|x1| up to 3.75e-4 and of
max|x2| up to 1.25e-4, both at the fold Omega = 1.1761 of the loop (the truncated branch's fold
is offset from the exact one, which a comparison at fixed Omega amplifies); away from it
<= 1.0e-4 (x1, the coordinate carrying the PWL force) and 7e-6 (x2); an orbit that stays in
one linear segment is an exact HB solution (1e-9). At H = 15 the same maxima are 6.1e-5 and
1.4e-5 (truncation error). Tolerances 1e-3 (x1) and 4e-4 (x2): ~3x the measured maxima; a wrong
harmonic or branch is off by > 1e-2.
"""

from __future__ import annotations

import contextlib
import csv
import io

import numpy as np
import pytest

from perturb.apps.cli import main
from perturb.errors import PerturbError
from perturb.model.system_builtins import builtin_system
from perturb.simulate.flows.affine_exact import AffineExactFlow
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.orbits.shooting import periodic_orbit
from perturb.solve import frequency_response

WINDOW = (1.1, 1.3)
TOL = {"x1": 1e-3, "x2": 4e-4}


def cli(*argv: str) -> tuple[int, list[dict[str, str]], str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    text = out.getvalue()
    rows = list(csv.DictReader(io.StringIO(text))) if code == 0 and "," in text else []
    return code, rows, err.getvalue()


def exact_max(system, W, y0):
    """max |x1|, max |x2| of the exact orbit at W shot from y0 (2^14 samples)."""
    flow = make_flow(system.with_params(Omega=W))
    assert isinstance(flow, AffineExactFlow)
    orbit = periodic_orbit(flow, y0)
    _, Y = orbit.sample_states(2**14)
    return {"x1": float(np.abs(Y[0]).max()), "x2": float(np.abs(Y[1]).max())}


@pytest.fixture(scope="module")
def response():
    return frequency_response(builtin_system("nsd2"), "hb", WINDOW, harmonics=7, output="x2")


def test_api_columns_and_values_against_exact_orbits(response):
    system = builtin_system("nsd2")
    assert response.method == "hb-system"
    assert len(response.branches) >= 2  # the main branch and the detached loop's part
    header = response.to_csv(None).splitlines()[0].split(",")
    for name in ("amplitude_x1", "amplitude_x2", "mean_x1", "mean_x2", "stable"):
        assert name in header
    checked = 0
    for br, cols in zip(response.branches, response.columns, strict=True):
        # the output column is max|x2|
        assert np.allclose(br.amplitude, cols["amplitude_x2"])
        for j in np.unique(np.linspace(0, len(br) - 1, 4).round().astype(int)):
            ex = exact_max(system, float(br.omega[j]), cols["states"][j])
            for c in ("x1", "x2"):
                rel = abs(cols[f"amplitude_{c}"][j] - ex[c]) / ex[c]
                assert rel <= TOL[c], (c, float(br.omega[j]), rel)
            checked += 1
    assert checked >= 6


def test_listed_frequencies_hold_the_stable_orbit():
    system = builtin_system("nsd2")
    resp = frequency_response(system, "hb", frequencies=[1.2], harmonics=7)
    assert all(b.omega[0] == 1.2 for b in resp.branches)
    stable = [(b, c) for b, c in zip(resp.branches, resp.columns, strict=True) if b.stable[0]]
    assert stable
    b, c = stable[0]
    ex = exact_max(system, 1.2, c["states"][0])
    assert abs(c["amplitude_x1"][0] - ex["x1"]) / ex["x1"] <= TOL["x1"]


def test_cli_frc_hb_and_compare(tmp_path):
    out = tmp_path / "frc.csv"
    code, _, err = cli(
        "frc", "nsd2", "--method", "hb", "--harmonics", "7", "--omega", "1.1:1.3",
        "--output", "x2", "--compare", "exact", "--out", str(out),
    )  # fmt: skip
    assert code == 0, err
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert rows and {"amplitude_x1", "mean_x2", "rel_error", "rel_error_x1"} <= set(rows[0])
    assert all(r["method"] == "hb-system" for r in rows)
    rel = np.array([float(r["rel_error_x1"]) for r in rows])
    # fewer rows (98) than the points the comparison checks (MAX_ERROR_POINTS = 200): every
    # HB point has its exact orbit, none may be left NaN
    assert len(rows) <= 200 and np.all(np.isfinite(rel)), rel
    assert rel.max() <= TOL["x1"]
    assert "compare with exact orbits" in err


def test_cli_refuses_other_approximations_for_systems():
    for argv in (
        ("frc", "nsd2", "--method", "kb", "--omega", "1:1.2"),
        ("frc", "nsd2", "--method", "mlp", "--omega", "1:1.2"),
        ("frc", "nsd2", "--method", "hb", "--order", "2", "--omega", "1:1.2"),
        ("frc", "nsd2", "--method", "exact", "--harmonics", "7", "--omega", "1:1.2"),
    ):
        code, _, err = cli(*argv)
        assert code != 0
        assert argv[3] in err or "--order" in err or "--harmonics" in err, err
    with pytest.raises(PerturbError, match="kb.*hb1"):
        frequency_response(builtin_system("nsd2"), "kb", (1.0, 1.2))
    with pytest.raises(PerturbError, match="seeds"):
        frequency_response(builtin_system("nsd2"), "hb", (1.0, 1.2), seeds=3)


def test_scene_hb_with_compare(tmp_path):
    scene = tmp_path / "hb.toml"
    scene.write_text(
        '[model]\nsystem = "nsd2"\noutput = "x2"\n[ask]\nkind = "frequency_response"\n'
        'omega = [1.1, 1.3]\n[method]\nname = "hb"\nharmonics = 7\n'
        '[compare]\nreference = "exact"\n'
    )
    code, _, err = cli("run", str(scene), "--out", str(tmp_path / "out"))
    assert code == 0, err
    rows = list(csv.DictReader(io.StringIO((tmp_path / "out" / "frc.csv").read_text())))
    assert {"amplitude_x1", "amplitude_x2", "rel_error_x1", "rel_error_x2"} <= set(rows[0])
    assert all(r["method"] == "hb-system" for r in rows)
    rel = np.array([float(r["rel_error_x2"]) for r in rows])
    assert np.nanmax(rel) <= TOL["x2"]
    # the same numbers as the API (H = 7 read from [method] harmonics)
    api = frequency_response(builtin_system("nsd2"), "hb", WINDOW, harmonics=7, output="x2")
    assert len(rows) == sum(len(b) for b in api.branches)
    for bad, match in (
        ('[method]\nname = "kb"', "kb"),
        ('[method]\nname = "exact"\n[compare]\nreference = "exact"', "compare"),
        ('[method]\nname = "exact"\nharmonics = 7', "harmonics"),
    ):
        scene.write_text('[model]\nsystem = "nsd2"\n' + bad)
        code, _, err = cli("run", str(scene), "--out", str(tmp_path / "bad"))
        assert code != 0 and match in err, err
