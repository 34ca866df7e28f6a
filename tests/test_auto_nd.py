"""method = "auto" for systems of several coordinates (issue 16 item 3): the ladder hb1 ->
HB H = 3 ... 63 -> exact with exact spot checks in n dimensions.

Oracle, written here: the exact periodic orbit of nsd2 by single shooting of its equations of
motion (solve_ivp DOP853, rtol = atol = 1e-12, fsolve), started from the chosen method's
state at t = 0; max |x_i| from 20000 samples of the orbit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from nsd2_oracle import exact_orbit_max
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

from perturb.auto import Candidate, auto_system_response
from perturb.errors import ParameterError, PerturbError
from perturb.model.system_builtins import builtin_system
from perturb.solve import frequency_response

WINDOW = (1.1, 1.3)


def worst_errors(resp, every=6, fold_gap=0.02, minimum=5):
    """Largest relative error of max|x1|, max|x2| over points away from the folds."""
    folds = [w for w, _ in resp.folds]
    worst = np.zeros(2)
    checked = 0
    for b, br in enumerate(resp.branches):
        cols = resp.columns[b]
        for j in range(0, len(br), every):
            W = float(br.omega[j])
            if any(abs(W - f) < fold_gap * f for f in folds):
                continue
            ex = exact_orbit_max(W, cols["states"][j])
            mine = np.array([cols["amplitude_x1"][j], cols["amplitude_x2"][j]])
            worst = np.maximum(worst, np.abs(mine - ex) / ex)
            checked += 1
    assert checked >= minimum
    return worst


@pytest.fixture(scope="module")
def nsd2():
    return builtin_system("nsd2")


@pytest.fixture(scope="module")
def chosen(nsd2):
    return auto_system_response(nsd2, WINDOW, 1e-2, output="x2")


def test_auto_meets_rtol_on_the_output_against_orbits_shot_here(chosen):
    resp, choice = chosen
    cand = choice.chosen.candidate
    assert cand.method == "hb"  # cheaper than exact, richer than one harmonic here
    assert resp.notes[0].startswith(f"auto: chose {cand.name}")
    assert resp.output == "x2"
    err = worst_errors(resp)
    assert err[1] <= 1e-2  # the output decides
    # every coordinate's spot error is reported, and it is what the orbits say (x1 carries
    # the PWL force and is reproduced worse than x2 by a truncated balance)
    coords = dict(choice.chosen.coordinate_errors)
    assert set(coords) == {"x1", "x2"}
    assert coords["x1"] > coords["x2"]
    assert err[0] > err[1]


def test_rejected_single_harmonic_misses_rtol_against_orbits_shot_here(nsd2, chosen):
    resp, choice = chosen
    rejected = {r.candidate.name: r for r in choice.rejected}
    assert "hb1" in rejected and rejected["hb1"].error > 1e-2
    # at the first spot frequency: the exact orbits (shot here from the chosen response's
    # nearby states), each against the nearest single-harmonic solution there
    W = choice.spot_frequencies[0]
    exact = []
    for b, br in enumerate(resp.branches):
        j = int(np.argmin(np.abs(br.omega - W)))
        if abs(float(br.omega[j]) - W) < 0.01:
            exact.append(exact_orbit_max(W, resp.columns[b]["states"][j])[1])
    assert len(exact) >= 2
    hb1 = frequency_response(nsd2, "hb1", frequencies=[W], output="x2")
    mine = [float(b.amplitude[0]) for b in hb1.branches]
    worst = max(min(abs(a - e) / e for a in mine) for e in exact)
    assert worst > 1e-2


def test_auto_at_listed_frequencies(nsd2):
    resp = frequency_response(nsd2, "auto", frequencies=[1.15, 1.25], rtol=1e-2, output="x2")
    omegas = sorted({float(b.omega[0]) for b in resp.branches})
    assert omegas == [1.15, 1.25]
    assert "spot checks at Omega = 1.15, 1.25" in resp.notes[1]
    err = worst_errors(resp, every=1, fold_gap=0.0, minimum=3)
    assert err[1] <= 1e-2


def test_bad_input(nsd2):
    with pytest.raises(ParameterError, match="rtol"):
        frequency_response(nsd2, "auto", WINDOW, rtol=2.0)
    with pytest.raises(ParameterError, match="harmonics.*rtol"):
        frequency_response(nsd2, "auto", WINDOW, harmonics=3)
    with pytest.raises(PerturbError, match="x3.*x1, x2"):
        frequency_response(nsd2, "auto", WINDOW, output="x3")
    with pytest.raises(ParameterError, match="mlp.*does not take a system"):
        auto_system_response(nsd2, WINDOW, 1e-2, ladder=[Candidate("mlp1", "mlp", order=1)])


# a weakly nonlinear pair with a 1:1 internal resonance (x2 couples through g x1 x2^2; with
# x2 at rest the motion is x1's hardening Duffing response)
PAIR = {"w2sq": 1.02, "c": 0.02, "g": 0.5, "h": 0.2, "a": 0.1, "F": 0.01}


def pair_system():
    from perturb.model.system import System

    return System.parse(
        [
            "x1'' + c*x1' + x1 + a*x1**3 + g*x1*x2**2 = F*cos(Omega*t)",
            "x2'' + c*x2' + w2sq*x2 + h*x2**3 + g*x1**2*x2 = 0",
        ],
        {**PAIR, "Omega": 1.0},
        name="pair11",
    )


def pair_orbit_max(W, y0):
    """max |x1| of the pair's periodic orbit, shot here (DOP853 1e-12, fsolve)."""
    p = PAIR

    def f(t, y):
        x1, x2, v1, v2 = y
        return [
            v1,
            v2,
            p["F"] * np.cos(W * t) - p["c"] * v1 - x1 - p["a"] * x1**3 - p["g"] * x1 * x2**2,
            -p["c"] * v2 - p["w2sq"] * x2 - p["h"] * x2**3 - p["g"] * x1**2 * x2,
        ]

    T = 2 * np.pi / W

    def flow(y):
        return solve_ivp(f, (0, T), y, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]

    y = fsolve(lambda y: flow(y) - y, np.asarray(y0, float), xtol=1e-12)
    assert np.abs(flow(y) - y).max() <= 1e-9 * (1 + np.abs(y).max())
    t = np.linspace(0, T, 4000, endpoint=False)
    sol = solve_ivp(f, (0, T), y, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
    return float(np.abs(sol.y[0]).max())


def test_averaging_rung_chosen_for_a_weak_internal_resonance():
    system = pair_system()
    resp, choice = auto_system_response(system, (0.95, 1.05), 0.1, spots=(1.0,), curve_checks=3)
    assert choice.chosen.candidate.name == "ms-ir"
    # hb1 cannot take a smooth term of several states: skipped with the reason
    (hb1,) = [r for r in choice.rejected if r.candidate.name == "hb1"]
    assert "several states" in hb1.note
    assert resp.method == "ms-ir-system" and resp.branches
    br, cols = resp.branches[0], resp.columns[0]
    errs = []
    for j in np.linspace(0, len(br) - 1, 3).round().astype(int):
        ex = pair_orbit_max(float(br.omega[j]), cols["states"][j])
        errs.append(abs(float(br.amplitude[j]) - ex) / ex)
    # first order in the small terms: within rtol, and not exact (it is an approximation)
    assert max(errs) <= 0.1
    assert max(errs) > 1e-4


def test_system_derivations_reachable():
    from perturb.model.system import System
    from perturb.solve import derive_system

    # the NNM of x1'' + 2 x1 - x2 + g x1^3 = 0, x2'' + 2 x2 - x1 = 0 along mode 1
    # (x1 = x2 = u/sqrt 2): u'' + u + (g/4) u^3 = 0, first-order L-P: 1 + 3 (g/4) A^2 / 8
    conservative = System.parse(
        ["x1'' + 2*x1 - x2 + g*x1**3 = 0", "x2'' + 2*x2 - x1 = 0"], {"g": 0.1}
    )
    nnm = derive_system(conservative, "nnm", order=1)
    for A in (0.3, 1.0):
        assert float(nnm.frequency_at(A)) == pytest.approx(1 + 3 * 0.1 * A**2 / 32, rel=1e-12)
    # the modified L-P backbone through both doors (method= is the backbone's own option:
    # derive_system's method is positional only); first order: omega^2 = 1 + (3/4)(g/4) A^2
    for mlp in (
        derive_system(conservative, "nnm", method="mlp", order=1),
        derive_system(conservative, "nnm-mlp", order=1),
    ):
        for A in (0.3, 1.0, 3.0):
            assert float(mlp.frequency_at(A)) == pytest.approx(
                math.sqrt(1 + 3 * 0.1 * A**2 / 16), rel=1e-12
            )
    with pytest.raises(ParameterError, match="'nnm-mlp' is the derivation with method = 'mlp'"):
        derive_system(conservative, "nnm-mlp", method="lp")
    slow = derive_system(pair_system(), "internal-resonance")
    assert len(slow.slow_flow) == 4
    with pytest.raises(ParameterError, match="hb1, ms-ir, nnm"):
        derive_system(pair_system(), "mlp")
    with pytest.raises(ParameterError, match="order.*bias"):
        derive_system(pair_system(), "hb1", order=2)


def test_cli_derive_lists_the_system_derivations_it_takes():
    from perturb.apps.cli import SYSTEM_DERIVATION_NAMES, build_parser
    from perturb.solve import SYSTEM_DERIVATION_ALIASES, SYSTEM_DERIVATIONS

    # the help text's names (kept beside the parser so --help needs no SymPy) are the table's
    assert set(SYSTEM_DERIVATION_NAMES) == set(SYSTEM_DERIVATIONS) | set(SYSTEM_DERIVATION_ALIASES)
    derive = build_parser()._subparsers._group_actions[0].choices["derive"]
    text = derive.format_help().replace("\n", " ")
    for name in SYSTEM_DERIVATION_NAMES:
        assert name in text
