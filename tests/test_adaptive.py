"""method = "auto": the cheapest method that meets rtol, checked against exact periodic orbits.

The oracle is the exact solver (closed-form propagation of the piecewise-linear flow plus
shooting, :func:`perturb.simulate.orbits.search.periodic_orbits`) at frequencies that were *not*
used for the choice, and, for the exact orbits themselves, a DOP853 integration at tight
tolerance that must close the period.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import perturb
from perturb import ParameterError, PerturbError
from perturb.apps.cli import main
from perturb.apps.scene import load_scene, parse_scene
from perturb.auto import (
    LADDER,
    Candidate,
    auto_frequency_response,
    candidate_spot_errors,
    check_rtol,
    choose_method,
    exact_spot_orbits,
)

ROOT = Path(__file__).resolve().parents[1]


def _rank(choice) -> int:
    return [c.name for c in LADDER].index(choice.chosen.candidate.name)


def _check_orbit_by_integration(osc, w: float, orbit) -> None:
    """An exact orbit closes after one forcing period under DOP853 at rtol 1e-12."""
    p = {k: float(v) for k, v in osc.params.items()}
    k, mu, F = p["k"], p["mu"], p["F"]

    def rhs(t, y):
        x, v = y
        f = k * x + (1 - k) * ((x - 1) * (x > 1) + (x + 1) * (x < -1))
        return [v, F * math.cos(w * t) - mu * v - f]

    T = 2 * math.pi / w
    sol = solve_ivp(
        rhs,
        (orbit.t0, orbit.t0 + T),
        orbit.y0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        max_step=T / 400,
        dense_output=True,
    )
    assert np.allclose(sol.y[:, -1], orbit.y0, rtol=1e-6, atol=1e-6)
    t = np.linspace(orbit.t0, orbit.t0 + T, 20001)
    assert np.max(np.abs(sol.sol(t)[0])) == pytest.approx(orbit.amplitude, rel=1e-6)


@pytest.mark.parametrize("bad", [0, 1, 1.5, -1e-3, float("nan"), "x", True, None])
def test_bad_rtol_is_a_parameter_error_naming_it(bad):
    with pytest.raises(ParameterError, match="rtol"):
        check_rtol(bad)


def test_front_door_auto_rejects_bad_rtol_and_grids():
    osc = perturb.builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    with pytest.raises(ParameterError, match="rtol = 0"):
        perturb.frequency_response(osc, "auto", Omega=(0.8, 1.2), rtol=0)
    # listed frequencies are answered (tests/test_method_registry.py); bad ones are refused
    with pytest.raises(ParameterError, match="frequencies"):
        perturb.frequency_response(osc, "auto", frequencies=[0.9, -1.0], rtol=1e-3)
    with pytest.raises(ParameterError, match="'auto' takes no order"):
        perturb.frequency_response(osc, "auto", Omega=(0.8, 1.2), order=2)


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("[method]\nname='auto'\n", "needs [accuracy] rtol"),
        ("[method]\nname='auto'\n[accuracy]\nrtol=1.0", "rtol = 1.0"),
        ("[accuracy]\nrtol=1e-3\nspots=[-1]", "spots"),
    ],
)
def test_bad_auto_scenes(text, fragment):
    with pytest.raises(PerturbError) as info:
        parse_scene("[model]\nname='nsd'\n" + text, "t.toml")
    assert fragment in str(info.value)


@pytest.mark.slow
def test_auto_on_a_small_window_tightens_with_rtol_and_holds_at_fresh_frequencies():
    # positive k: the flow is cheap to shoot and HB converges algebraically (PWL), so the
    # rungs separate cleanly; two spots keep the test short
    osc = perturb.builtin_model("nsd", k=2.0, mu=0.05, F=2.0)
    window, spots = (0.8, 1.4), (0.9, 1.3)
    orbits = exact_spot_orbits(osc, spots)
    loose = choose_method(osc, window, 1e-2, spots=spots)
    tight = choose_method(osc, window, 1e-5, spots=spots)
    assert _rank(loose) < _rank(tight)
    assert loose.chosen.error <= 1e-2 and tight.chosen.error <= 1e-5
    # every rejected candidate really missed: its spot error or estimate exceeds rtol
    for r in tight.rejected:
        assert r.error > 1e-5 or r.estimate > 1e-5
    assert sum(len(o) for o in orbits) == sum(tight.exact_orbits)
    # fresh frequencies, not used for the choice: the chosen settings hold there too (the
    # spot checks are a sample, so allow a factor 3 over rtol between spots)
    fresh = (1.0, 1.2)
    fresh_orbits = exact_spot_orbits(osc, fresh)
    for w, row in zip(fresh, fresh_orbits, strict=True):
        for o in row:
            _check_orbit_by_integration(osc, w, o)
    for choice, rtol in ((loose, 1e-2), (tight, 1e-5)):
        res = candidate_spot_errors(osc, choice.chosen.candidate, fresh, fresh_orbits, window)
        assert res.error <= 3 * rtol, (choice.chosen.candidate, res)


def test_auto_report_names_the_choice_and_rejections():
    osc = perturb.builtin_model("nsd", k=2.0, mu=0.05, F=2.0)
    ladder = (Candidate("hb1", "hb1"), Candidate("hb3", "hb", harmonics=3))
    resp = perturb.frequency_response(
        osc, "auto", Omega=(0.8, 1.4), rtol=1e-4, spots=(1.1,), ladder=ladder
    )
    # neither rung meets 1e-4 at Omega = 1.1: the exact solver answers
    assert resp.method == "exact"
    assert resp.notes[0].startswith("auto: chose exact")
    assert any("rejected hb1" in n for n in resp.notes)
    assert any("rejected hb3" in n for n in resp.notes)


def test_auto_adds_a_spot_check_where_the_traced_hb_estimate_exceeds_rtol():
    # one spot at 1.3: HB with 15 harmonics meets 1e-5 there, but its estimate along the
    # traced curve exceeds rtol near the lower end of the window; that frequency becomes a
    # spot check (exact orbits there) and the ladder resumes
    osc = perturb.builtin_model("nsd", k=2.0, mu=0.05, F=2.0)
    window, rtol = (0.8, 1.4), 1e-5
    _, once = auto_frequency_response(
        osc, window, rtol, spots=(1.3,), points=300, max_extra_spots=1
    )
    added = [w for w in once.spot_frequencies if w != 1.3]
    assert len(added) == 1 and window[0] <= added[0] <= window[1]
    assert any(f"Omega = {added[0]:g}: exact spot check added" in n for n in once.notes)
    # the oracle: the chosen settings against exact orbits at the added frequency
    res = candidate_spot_errors(
        osc, once.chosen.candidate, added, exact_spot_orbits(osc, added), window
    )
    assert res.error <= rtol
    # no spot may be added: the same spot alone, and a note telling where to add one
    _, never = auto_frequency_response(
        osc, window, rtol, spots=(1.3,), points=300, max_extra_spots=0
    )
    assert never.spot_frequencies == (1.3,)
    assert never.window_estimate > rtol
    where = f"(at Omega = {never.window_estimate_at:.4g}): add spot frequencies there"
    assert any(where in n for n in never.notes)


@pytest.mark.slow
def test_paper_scene_rtol_1e3_is_cheaper_than_1e8_and_both_hold(tmp_path):
    """The issue's "done when", on Fig. 17 with k = -0.5 (exact orbits are cheap there)."""
    scene = load_scene(ROOT / "scenes" / "zou_fig17_k-0.5.toml")
    assert scene.method == "auto" and scene.rtol == 1e-3
    osc = scene.oscillator()
    loose = choose_method(osc, scene.omega, 1e-3)
    tight = choose_method(osc, scene.omega, 1e-8, spots=loose.spot_frequencies)
    assert _rank(loose) < _rank(tight)
    assert loose.chosen.error <= 1e-3 and tight.chosen.error <= 1e-8
    # the oracle at frequencies not used for the choice
    fresh = tuple(w for w in (0.5, 1.05, 1.7) if w not in loose.spot_frequencies)
    fresh_orbits = exact_spot_orbits(osc, fresh)
    for w, row in zip(fresh, fresh_orbits, strict=True):
        assert row
        for o in row:
            _check_orbit_by_integration(osc, w, o)
    res = candidate_spot_errors(osc, loose.chosen.candidate, fresh, fresh_orbits, scene.omega)
    assert res.error <= 3e-3, res
    if tight.chosen.candidate.method == "hb":
        res = candidate_spot_errors(osc, tight.chosen.candidate, fresh, fresh_orbits, scene.omega)
        assert res.error <= 3e-8, res

    # `perturb run` on the shipped scene: prints the choice and writes it next to the CSV
    out = tmp_path / "out"
    assert main(["run", str(ROOT / "scenes" / "zou_fig17_k-0.5.toml"), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    # the run may add spot checks where the estimate along the traced curve exceeds rtol, and
    # then climb further; never beyond what 1e-8 needs
    names = [c.name for c in LADDER]
    ran = names.index(report["auto"]["chosen"]["name"])
    assert _rank(loose) <= ran < _rank(tight)
    assert report["auto"]["chosen"]["max_spot_error"] <= 1e-3
    assert set(loose.spot_frequencies) <= set(report["auto"]["spot_frequencies"])
    assert (out / "frc.csv").read_text().startswith("branch,omega")
    assert (out / "frc.png").read_bytes()[:4] == b"\x89PNG"


def test_a_ladder_rung_the_registry_refuses_is_an_error_before_any_work():
    """Rungs are checked against the method registry (method name, options, limits) before
    the spot checks run."""
    import time

    from perturb.auto import Candidate, choose_method

    osc = perturb.builtin_model("duffing")
    for rung, fragment in (
        (Candidate("x", "hb1", order=2), "'hb1' takes no order"),
        (Candidate("y", "nosuch"), "method 'nosuch'"),
        (Candidate("z", "hb", harmonics=10**6), "at most"),
        (Candidate("w", "auto"), "own ladder"),
    ):
        t0 = time.perf_counter()
        with pytest.raises(ParameterError, match=fragment):
            choose_method(osc, (0.5, 1.5), 1e-3, ladder=[rung])
        assert time.perf_counter() - t0 < 1.0
