"""compare() and relative_errors() on synthetic responses whose answers are known exactly:
closed-form curves (a linear resonance, a folded Duffing curve from its closed-form W(A), an
isola), sampled so that the interpolation of the reference is exact or negligible."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from perturb.comparison import Comparison, compare, relative_errors
from perturb.errors import ParameterError
from perturb.response import Branch, Response


def branch(w, a, stable=None) -> Branch:
    w, a = np.asarray(w, float), np.asarray(a, float)
    st = np.ones(w.size, bool) if stable is None else np.asarray(stable, bool)
    return Branch(w, a, a, np.zeros(w.size), st, np.where(st, 0.5, 2.0))


def response(*branches: Branch, method: str = "test") -> Response:
    return Response(tuple(branches), method)


# ------------------------------------------------------------------ closed-form curves
MU, F = 0.1, 0.5


def linear_amplitude(w):
    """x'' + mu x' + x = F cos(w t): A = F / sqrt((1 - W)^2 + mu^2 W), W = w^2."""
    W = np.asarray(w, float) ** 2
    return F / np.sqrt((1 - W) ** 2 + MU**2 * W)


EPS = 0.3  # Duffing x'' + mu x' + x + eps x^3, single-harmonic curve: folds at these values


def duffing_curve(amplitudes):
    """The closed-form W(A) of ((1 - W) A + 3/4 eps A^3)^2 + mu^2 W A^2 = F^2, both roots
    joined at the peak, as one branch ordered along the curve (omega, A)."""
    A = np.asarray(amplitudes, float)
    c = 1 + 0.75 * EPS * A**2
    disc = F**2 / A**2 - MU**2 * c + MU**4 / 4
    A, c, disc = A[disc >= 0], c[disc >= 0], disc[disc >= 0]
    W_lo = c - MU**2 / 2 - np.sqrt(disc)
    W_hi = c - MU**2 / 2 + np.sqrt(disc)
    lo = W_lo > 0.01  # the lower root starts at omega = 0 (the static response)
    w = np.concatenate([np.sqrt(W_lo[lo]), np.sqrt(W_hi[::-1])])
    return w, np.concatenate([A[lo], A[::-1]])


def duffing_roots(w):
    """Every amplitude at frequency w: positive roots y = A^2 of the cubic
    (9/16 eps^2) y^3 + (3/2 eps (1 - W)) y^2 + ((1 - W)^2 + mu^2 W) y - F^2 = 0."""
    W = w * w
    y = np.roots([9 / 16 * EPS**2, 1.5 * EPS * (1 - W), (1 - W) ** 2 + MU**2 * W, -(F**2)])
    y = y[(np.abs(y.imag) < 1e-9 * np.abs(y)) & (y.real > 0)].real
    return np.sqrt(np.sort(y))


def turning_points(w):
    """Indices where omega turns back along a sampled curve."""
    d = np.sign(np.diff(w))
    return np.nonzero(d[:-1] != d[1:])[0] + 1


def with_fold_stability(w, a):
    """Single-harmonic stability of a Duffing curve: unstable strictly between its folds."""
    f1, f2 = turning_points(w)
    idx = np.arange(w.size)
    return branch(w, a, ~((idx > f1) & (idx < f2)))


@pytest.fixture(scope="module")
def duffing_reference():
    grid = np.unique(np.concatenate([np.linspace(0.05, 3, 20000), np.geomspace(0.05, 3, 20000)]))
    w, a = duffing_curve(grid)
    return response(with_fold_stability(w, a), method="reference")


# ------------------------------------------------------------------------------ errors
def test_errors_are_exact_where_response_and_reference_share_frequencies():
    w = np.linspace(0.2, 2.0, 2001)
    ref = response(branch(w, linear_amplitude(w)), method="exact")
    ws = w[::7]
    delta = 0.01 * np.sin(3 * ws) + 0.002  # known relative deviation, both signs
    resp = response(branch(ws, linear_amplitude(ws) * (1 + delta)), method="approx")
    c = compare(resp, ref)
    expected = np.abs(delta)
    np.testing.assert_allclose(c.rel_errors, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(relative_errors(resp, ref), expected, rtol=1e-12, atol=1e-15)
    (b,) = c.branches
    assert b.matched == 0 and b.compared == b.points == ws.size and b.within == ws.size
    assert b.max_error == pytest.approx(expected.max(), rel=1e-12)
    assert b.rms_error == pytest.approx(np.sqrt(np.mean(expected**2)), rel=1e-12)
    assert c.max_error == pytest.approx(expected.max(), rel=1e-12)
    assert c.rms_error == pytest.approx(b.rms_error, rel=1e-12)
    assert c.matches == {0: 0} and c.missed == () and c.spurious == () and c.uncompared == ()
    assert c.stability_disagreements == () and c.excluded == 0
    assert c.method == "approx" and c.reference_method == "exact"


def test_interpolation_between_reference_points_is_linear_in_omega():
    # a reference that is linear in omega is reproduced exactly between its 5 points
    ref = response(branch([0.5, 0.75, 1.0, 1.25, 1.5], [1.5, 1.75, 2.0, 2.25, 2.5]))
    w = np.array([0.5, 0.61, 0.9, 1.33, 1.5])
    factor = np.array([1.0, 1.05, 0.9, 1.2, 1.0])
    resp = response(branch(w, (1 + w) * factor))
    np.testing.assert_allclose(relative_errors(resp, ref), np.abs(factor - 1), atol=1e-14)


def test_nan_only_outside_the_reference_and_one_value_per_row():
    w = np.linspace(0.5, 1.5, 11)
    ref = response(branch(w, 2 + w))
    inside = branch([0.4, 0.5, 1.0, 1.5, 1.6], [2.4, 2.5, 3.0, 3.5, 3.6])
    outside = branch([2.0, 2.5], [1.0, 1.0])
    resp = response(inside, outside)
    e = relative_errors(resp, ref)
    assert e.shape == (len(resp.rows()),) == (7,)
    assert np.array_equal(np.isnan(e), [True, False, False, False, True, True, True])
    np.testing.assert_allclose(e[1:4], 0, atol=1e-15)
    c = compare(resp, ref)
    assert c.uncompared == (1,) and c.spurious == () and c.matches == {0: 0}
    assert c.branches[0].compared == 3 and c.branches[1].compared == 0
    assert np.isnan(c.branches[1].max_error)
    np.testing.assert_array_equal(np.isnan(c.rel_errors), np.isnan(e))


def test_nearest_solution_is_nearest_on_a_log_scale():
    # solutions 1 and 10 at every frequency; a = 3 is 3x the first and 0.3x the second:
    # log-nearest is 1 (|ln 3| < |ln 0.3|) although |3 - 10|/10 < |3 - 1|/1
    w = np.linspace(1, 2, 5)
    ref = response(branch(w, np.ones(5)), branch(w, 10 * np.ones(5)))
    resp = response(branch([1.5], [3.0]), branch([1.5], [4.0]))
    np.testing.assert_allclose(relative_errors(resp, ref), [2.0, 0.6])


def test_vertical_reference_segment_holds_every_amplitude_between_its_ends():
    ref = response(branch([0.9, 1.0, 1.0, 1.1], [1.0, 1.0, 2.0, 2.0]))
    resp = response(branch([1.0, 1.0, 1.0], [1.5, 3.0, 0.5]))
    np.testing.assert_allclose(relative_errors(resp, ref), [0.0, 0.5, 0.5])


# ---------------------------------------------------------------- folded reference curve
def test_folded_duffing_curve_every_solution_at_each_frequency(duffing_reference):
    ref = duffing_reference
    w_ref = ref.branches[0].omega
    folds = w_ref[turning_points(w_ref)]
    assert folds.size == 2  # EPS, MU, F give a hysteresis loop
    # another sampling of the same curve: only interpolation error
    w, a = duffing_curve(np.linspace(0.051, 2.99, 3001))
    resp = response(with_fold_stability(w, a))
    c = compare(resp, ref)
    assert c.matches == {0: 0} and c.missed == () and c.spurious == ()
    away = np.min(np.abs(w[:, None] / folds[None, :] - 1), axis=1) > 1e-3
    assert np.max(c.rel_errors[away]) < 1e-5
    # a point just beyond the sampled fold of the reference finds only the other piece
    assert c.max_error < 1e-4
    # a 3 % deviation: the expected error is against the closed-form root nearest on a log
    # scale among all 1 or 3 roots at that frequency
    w, a = w[away], a[away]
    dev = 1.03 * a
    e = relative_errors(response(branch(w, dev)), ref)
    expected = []
    for wi, ai in zip(w, dev, strict=True):
        r = duffing_roots(wi)
        k = np.argmin(np.abs(np.log(ai / r)))
        expected.append(abs(ai - r[k]) / r[k])
    # interpolation of the reference is the only difference: largest at the peak, where the
    # two roots meet and omega moves fast along the sampled curve
    assert np.max(np.abs(e - expected)) < 1e-4
    assert np.mean(np.abs(e - expected) < 1e-6) > 0.99
    # in the hysteresis band three roots exist and some points are nearest another branch
    inside = (w > folds.min()) & (w < folds.max())
    assert inside.sum() > 100
    assert np.max(e) < 0.0301


def test_stability_disagreements_exactly_where_flags_were_flipped(duffing_reference):
    ref = duffing_reference
    w, a = duffing_curve(np.linspace(0.051, 2.99, 3001))
    good = with_fold_stability(w, a)
    w_ref = ref.branches[0].omega
    folds = w_ref[turning_points(w_ref)]
    near = np.min(np.abs(w[:, None] - folds[None, :]) / folds[None, :], axis=1)
    far = np.nonzero(near > 0.05)[0]
    middle = far[~good.stable[far]]  # the unstable part between the folds
    assert middle.size > 50
    flipped = np.r_[far[100:130], middle[20:30], far[-5:-2]]
    stable = good.stable.copy()
    stable[flipped] = ~stable[flipped]
    resp = response(branch(w, a, stable))
    c = compare(resp, ref, fold_distance=0.02)
    got = sorted(d.index for d in c.stability_disagreements)
    assert got == sorted(flipped.tolist())
    assert c.excluded == int(np.sum(near <= 0.02))
    assert c.branches[0].stability_disagreements == flipped.size
    for d in c.stability_disagreements:
        assert d.branch == 0 and d.reference_branch == 0
        assert d.stable == stable[d.index] and d.reference_stable == good.stable[d.index]
        assert d.omega == w[d.index] and d.amplitude == a[d.index]
        assert d.reference_amplitude == pytest.approx(a[d.index], rel=1e-5)
    # without the exclusion the flipped points are still all found, and whatever else
    # disagrees lies at a fold (the two samplings put the stability change a point apart)
    c0 = compare(resp, ref)
    extra = {d.index for d in c0.stability_disagreements} - set(flipped.tolist())
    assert {d.index for d in c0.stability_disagreements} >= set(flipped.tolist())
    assert all(near[i] < 1e-3 for i in extra)
    assert c0.excluded == 0 and c0.fold_distance is None
    # and special frequencies exclude regardless of folds
    k = int(flipped[15])
    c1 = compare(resp, ref, fold_distance=0.0, special_frequencies=[w[k]])
    assert k not in {d.index for d in c1.stability_disagreements}
    assert c1.excluded >= 1


def test_stability_flag_from_the_nearer_reference_point():
    ref = response(branch([0.0 + 1, 1 + 1, 2 + 1, 3 + 1], [1, 1, 1, 1], [1, 1, 0, 0]))
    resp = response(branch([2.4, 2.6], [1.0, 1.0], [True, True]))
    c = compare(resp, ref)
    assert [(d.omega, d.stable, d.reference_stable) for d in c.stability_disagreements] == [
        (2.6, True, False)
    ]


def test_isola_folding_back_at_both_ends_is_matched_on_both_halves():
    t = np.linspace(0, 2 * np.pi, 721)
    isola = branch(1.5 + 0.1 * np.cos(t), 5 + np.sin(t))
    w_main = np.linspace(0.2, 2.0, 901)
    ref = response(branch(w_main, linear_amplitude(w_main)), isola)
    s = np.linspace(0.01, 2 * np.pi - 0.01, 100)  # another sampling, both halves
    resp = response(branch(1.5 + 0.1 * np.cos(s), 5 + np.sin(s)))
    c = compare(resp, ref)
    assert c.matches == {0: 1}
    assert c.missed == (0,)  # the main curve has no counterpart in this response
    assert c.branches[0].max_error < 2e-4  # interpolation error of the 721-point isola
    assert c.folds == tuple(c.folds) and sorted(round(f[1], 6) for f in c.folds) == [1.4, 1.6]


# ------------------------------------------------------------------ missed and spurious
def test_missed_spurious_uncompared_outside_and_mirror_ties():
    w = np.linspace(0.2, 2.0, 901)
    t = np.linspace(0, 2 * np.pi, 361)
    wm = np.linspace(0.5, 1.0, 51)
    ref = response(
        branch(w, linear_amplitude(w)),  # 0: reproduced
        branch(1.5 + 0.1 * np.cos(t), 5 + np.sin(t)),  # 1: isola, missed
        branch(wm, 3 + 0.5 * wm),  # 2 and 3: mirror images (same amplitudes)
        branch(wm, 3 + 0.5 * wm),
        branch([5.0, 6.0], [1.0, 1.0]),  # 4: beyond the response's frequencies
        method="exact",
    )
    resp = response(
        branch(w[::3], 1.01 * linear_amplitude(w[::3])),  # 0 -> 0
        branch(wm[::2], 1.02 * (3 + 0.5 * wm[::2])),  # 1 -> 2 (and 3: tie)
        branch([0.5, 1.0, 1.5], [20.0, 20.0, 20.0]),  # 2: spurious
        branch([2.5, 3.0], [1.0, 1.0]),  # 3: no reference solution there
        method="approx",
    )
    c = compare(resp, ref)
    assert c.matches == {0: 0, 1: 2}
    assert c.missed == (1,)
    assert c.spurious == (2,)
    assert c.uncompared == (3,)
    assert c.outside == (4,)
    assert [r.matched_by for r in c.reference_branches] == [(0,), (), (1,), (1,), ()]
    assert c.branches[0].max_error == pytest.approx(0.01, rel=1e-9)
    assert c.branches[1].max_error == pytest.approx(0.02, rel=1e-9)
    assert c.max_error == pytest.approx(0.02, rel=1e-9)
    assert c.branches[2].matched is None and c.branches[2].within == 0
    assert c.branches[2].max_error > 1  # spurious errors are reported, not hidden
    r0 = c.reference_branches[0]
    assert r0.compared > 0 and r0.reproduced == r0.compared


def test_branch_spanning_two_reference_branches_misses_neither():
    w1, w2 = np.linspace(0.5, 1.0, 41), np.linspace(1.0, 1.8, 61)
    ref = response(branch(w1, 1 + w1), branch(w2, 1 + w2))
    w = np.linspace(0.5, 1.8, 131)
    c = compare(response(branch(w, 1 + w)), ref)
    assert c.matches == {0: 1}  # most points lie on the longer one
    assert c.missed == () and c.spurious == ()
    assert c.max_error < 1e-14


def test_a_response_on_a_coarse_frequency_grid_still_finds_curved_branches():
    # five frequencies, as solutions_at returns them: interpolating the response between
    # them would miss the resonance peak, sampling the reference at them does not
    w = np.linspace(0.5, 1.5, 2001)
    ref = response(branch(w, linear_amplitude(w)))
    ws = np.array([0.6, 0.8, 1.0, 1.2, 1.4])
    c = compare(response(branch(ws, linear_amplitude(ws))), ref)
    assert c.missed == () and c.spurious == () and c.matches == {0: 0}
    assert c.reference_branches[0].compared == 5


def test_tolerance_and_min_share_decide_the_match():
    w = np.linspace(1, 2, 11)
    ref = response(branch(w, np.ones(11)))
    a = np.where(np.arange(11) < 6, 1.1, 1.5)  # 6 points at 10 %, 5 at 50 %
    resp = response(branch(w, a))
    assert compare(resp, ref).matches == {0: 0}  # 6/11 within 20 %
    assert compare(resp, ref, min_share=0.6).spurious == (0,)
    assert compare(resp, ref, tolerance=0.05).spurious == (0,)
    assert compare(resp, ref, tolerance=0.6, min_share=1.0).matches == {0: 0}


def test_first_harmonic_column_can_be_compared():
    w = np.linspace(1, 2, 11)
    b = Branch(w, 2 * np.ones(11), np.ones(11), np.zeros(11), np.ones(11, bool), np.zeros(11))
    ref = response(branch(w, np.ones(11)))
    assert compare(response(b), ref, quantity="first_harmonic_amplitude").max_error == 0.0
    assert compare(response(b), ref).spurious == (0,)


# ------------------------------------------------------------------- the result object
def test_comparison_is_immutable_and_printable(duffing_reference):
    w, a = duffing_curve(np.linspace(0.051, 2.99, 1001))
    stable = with_fold_stability(w, a).stable.copy()
    stable[100:105] = False
    resp = response(branch(w, a, stable), branch([0.5, 1.0], [30.0, 30.0]), method="hb1")
    c = compare(resp, duffing_reference, fold_distance=0.01)
    assert isinstance(c, Comparison)
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.missed = ()  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.branches[0].max_error = 0.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        c.rel_errors[0] = 1.0
    text = str(c)
    assert text.startswith("hb1 against reference: relative error of amplitude")
    assert "spurious branches: 1" in text
    assert "missed reference branches: none" in text
    assert "branch 0: 5 points, omega" in text and "unstable where reference branch 0" in text
    assert "within 0.01 of folds left out" in text
    lines = text.splitlines()
    row = next(line for line in lines if line.split()[:2] == ["0", str(len(w))])
    assert row.split()[4] == "0"  # matched to reference branch 0
    assert "spurious" in next(line for line in lines if line.split()[:2] == ["1", "2"])
    assert "Comparison(hb1 vs reference" in repr(c)


# ------------------------------------------------------------------------- bad input
GOOD = response(branch([1.0, 2.0], [1.0, 1.0]))


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        ((None, GOOD), {}, "response = None: expected a perturb.Response"),
        ((GOOD, "exact"), {}, "reference = 'exact': expected a perturb.Response"),
        ((Response((), "hb1"), GOOD), {}, r"response \(hb1\) has no points"),
        ((GOOD, Response((branch([], []),), "exact")), {}, r"reference \(exact\) has no points"),
        ((GOOD, GOOD), {"quantity": "mean"}, "quantity = 'mean'"),
        ((GOOD, GOOD), {"tolerance": 0}, "tolerance = 0"),
        ((GOOD, GOOD), {"tolerance": float("nan")}, "tolerance = nan"),
        ((GOOD, GOOD), {"tolerance": True}, "tolerance = True"),
        ((GOOD, GOOD), {"tolerance": "big"}, "tolerance = 'big': expected a number"),
        ((GOOD, GOOD), {"min_share": 1.5}, "min_share = 1.5: expected 0 < min_share <= 1"),
        ((GOOD, GOOD), {"fold_distance": -0.1}, "fold_distance = -0.1"),
        ((GOOD, GOOD), {"fold_distance": "near"}, "fold_distance = 'near'"),
        (
            (GOOD, GOOD),
            {"fold_distance": 0.1, "special_frequencies": ["x"]},
            "special_frequencies",
        ),
        ((GOOD, GOOD), {"special_frequencies": [1.0]}, "needs fold_distance"),
        (
            (GOOD, GOOD),
            {"fold_distance": 0.1, "special_frequencies": [-1.0]},
            "special_frequencies",
        ),
    ],
)
def test_bad_input_is_a_clear_parameter_error(args, kwargs, match):
    with pytest.raises(ParameterError, match=match):
        compare(*args, **kwargs)


def test_relative_errors_checks_its_input():
    with pytest.raises(ParameterError, match="expected a perturb.Response"):
        relative_errors(GOOD, [1, 2])
    with pytest.raises(ParameterError, match="quantity"):
        relative_errors(GOOD, GOOD, quantity="stable")


def test_branch_errors_are_against_the_matched_branch_and_skip_points_beyond_its_fold():
    # reference: a parabola folding at omega = 1 (upper and lower halves) and a far branch;
    # the response follows the parabola but overshoots the fold by two points
    s = np.linspace(-1, 1, 201)
    ref = response(branch(1 - s**2, 2 + s), branch(np.linspace(0.5, 1.5, 11), 0.1 * np.ones(11)))
    s2 = np.linspace(-1, 1, 41)
    w = 1 - s2**2
    w[19:22] = [1.01, 1.02, 1.01]  # beyond the reference's fold
    c = compare(response(branch(w, 2 + s2)), ref)
    (b,) = c.branches
    assert b.matched == 0 and b.points == 41 and b.compared == 41 and b.covered == 38
    assert b.max_error < 1e-3  # the covered points are on the parabola
    e = c.rel_errors
    np.testing.assert_allclose(e[19:22], (2 + s2[19:22]) / 0.1 - 1)  # nearest: the far branch
    assert c.max_error == b.max_error and c.rms_error == b.rms_error


def test_overshooting_fold_tip_of_an_s_shaped_branch_is_not_covered(duffing_reference):
    # the approximation is the closed-form curve with its frequencies 0.2 % too high: the tip
    # of its upper fold lies beyond the reference's fold, where the same (S-shaped) reference
    # branch has only its lower part -- a relative error of ~10 that says nothing about the
    # approximation; everywhere else the error is that of the frequency shift
    w, a = duffing_curve(np.geomspace(0.05, 3, 3000))
    shifted = response(branch(1.002 * w, a))
    c = compare(shifted, duffing_reference)
    (b,) = c.branches
    assert b.matched == 0

    # oracle: the root of the closed-form cubic at each point's own frequency nearest on a
    # log scale (compare's rule), and the relative error to it
    def nearest_error(v, x):
        r = duffing_roots(v)
        if not r.size:
            return np.nan
        r = r[np.argmin(np.abs(np.log(r / x)))]
        return abs(x - r) / r

    oracle = np.array([nearest_error(v, x) for v, x in zip(1.002 * w, a, strict=True)])
    inside = np.isfinite(c.rel_errors)  # within the reference's frequency span
    tip = inside & ~(oracle <= 0.2)
    assert 0 < tip.sum() < 0.01 * w.size and b.covered == inside.sum() - tip.sum()
    assert b.max_error == pytest.approx(np.max(oracle[inside & ~tip]), rel=1e-3)
    # without the fold rule the tip is charged with the distance to the lower part
    bare = compare(shifted, duffing_reference, fold_overshoot=1e-12)
    assert bare.branches[0].covered == inside.sum()
    assert bare.max_error > 5
    with pytest.raises(ParameterError, match="fold_overshoot"):
        compare(shifted, duffing_reference, fold_overshoot=-1)


def test_reference_folds_are_interpolated_along_the_amplitude():
    # a coarse reference (120 amplitudes) against the exact curve sampled finely, near its
    # folds: there the amplitude goes like sqrt(omega distance), and straight segments
    # through the extreme sample are off (and leave no solution between that sample and the
    # true fold); compare models omega(a) by the parabola through the fold vertex and its
    # neighbours, exact up to O(h^3)
    cw, ca = duffing_curve(np.linspace(0.05, 3, 120))
    coarse = response(branch(cw, ca), method="coarse")
    w, a = duffing_curve(np.geomspace(0.05, 3, 20000))
    # the lower fold (the upper one of this closed form is the join of its two roots at one
    # amplitude, where the amplitude turns too: left as sampled)
    for v in turning_points(cw)[1:]:
        near = (np.abs(w / cw[v] - 1) < 5e-3) & (np.abs(a / ca[v] - 1) < 0.05)
        fine = response(branch(w[near], a[near]))
        err = relative_errors(fine, coarse)
        # oracle for the fine curve: the exact roots at its own frequencies (it is exact),
        # and for the chord: linear interpolation of the coarse samples on each side
        chord = []
        for x, y in zip(w[near], a[near], strict=True):
            sides = [(cw[v - 1 : v + 1], ca[v - 1 : v + 1]), (cw[v : v + 2], ca[v : v + 2])]
            cand = [
                np.interp(x, *(sw[::-1], sa[::-1]) if sw[0] > sw[1] else (sw, sa))
                for sw, sa in sides
                if min(sw) <= x <= max(sw)
            ]
            chord.append(min((abs(y - r) / r for r in cand), default=np.nan))
        chord = np.array(chord)
        assert np.nanmax(chord) > 2e-3  # what straight segments would charge
        assert np.all(np.isfinite(err))  # every point has a counterpart, beyond the sample too
        assert np.max(err) < 0.1 * np.nanmax(chord)
        assert np.isnan(chord).sum() > 0  # the chord leaves points beyond the extreme sample
