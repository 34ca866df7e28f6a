"""Branch points and branch switching in numeric harmonic balance (``all_branches=True``).

Oracles (never the code under test):

* closed-form curves for the continuation core: the pitchfork ``lam u - u^3 = 0`` (branches
  ``u = 0`` and ``u^2 = lam``, branch point at 0), the transcritical ``u (lam - u) = 0``
  (branches ``u = 0`` and ``u = lam``) and a cubic with two folds and no branch point;
* the exact frequency response of nsd at k = -3 (:func:`perturb.simulate.exact_response.
  exact_branches`, exact piecewise-linear propagation), compared with
  :func:`perturb.comparison.compare`, plus the mean and the fold of the branches that
  the amplitude comparison cannot tell apart (mirror pairs have equal amplitudes);
* the symmetry-breaking branch point of a symmetric orbit located independently of HB:
  the symmetric orbit solves ``phi_{T/2}(y) = -y`` (half-period map of the exact flow, or of
  DOP853 at rtol 1e-12 for the smooth system), regular at the branch point, and the branch
  point is the zero of ``det(I - P)``, ``P`` the half-period sensitivity (the full-period
  multiplier through +1 along the antisymmetric direction), found by bisection in Omega;
* tight shooting (:func:`perturb.simulate.orbits.shooting.periodic_orbit` on
  :class:`~perturb.simulate.flows.base.ODEFlow`, rtol = atol = 1e-12) for the double-well Duffing
  oscillator ``x'' + 0.1 x' - x + x^3 = 0.6 cos(Omega t)``.

Measured (development machine, recorded here so a change shows up): nsd k = -3, H = 15:
the two in-well branches that ``compare`` reported missed before (exact branches with the
fold at Omega = 0.616925) are matched with max relative error 1.5e-3; the branch point on the
symmetric cross-well loop is at Omega = 0.4835249 against 0.4834804 exact (9.2e-5 relative;
the exact solver's own special point, a linear interpolation between two continuation
points, says 0.48391); at H = 31, 0.4834842 (7.9e-6). Double well, H = 31: the switched
branch agrees with shooting to 9.4e-8 (relative, amplitude) and 2.6e-12 (mean) at
Omega >= 0.45, its branch point (Omega = 0.70280947) with the oracle to 4.5e-10.
"""

from __future__ import annotations

import functools
import math
import os

import numpy as np
import pytest

from perturb.comparison import compare
from perturb.errors import ParameterError
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator
from perturb.numeric.continuation import BranchPoint, branch_off, continue_curve
from perturb.numeric.harmonic_balance import (
    HarmonicBalanceSystem,
    harmonic_balance_branches,
    harmonic_balance_response,
    mirror_branch,
    odd_symmetry,
)
from perturb.seeds import single_harmonic_seeds
from perturb.simulate.exact_response import exact_branches
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.orbits.shooting import periodic_orbit

os.environ.setdefault("PERTURB_PROGRESS", "0")

NSD_K3 = {"k": -3.0, "mu": 0.05, "F": 2.0}
WINDOW = (0.2, 2.0)
DOUBLE_WELL = "x'' + 0.1*x' - x + x**3 = F*cos(Omega*t)"
DW_WINDOW = (0.3, 2.5)


# ---------------------------------------------------------------------------------------------
# independent oracles
# ---------------------------------------------------------------------------------------------
def symmetric_orbit(flow, y, period: float) -> tuple[np.ndarray, np.ndarray]:
    """The symmetric orbit ``x(t + T/2) = -x(t)`` of an odd system by Newton on the half-period
    map, ``phi_{T/2}(y) + y = 0`` (Jacobian ``P + I``, regular at a symmetry-breaking branch
    point, where ``P`` has the eigenvalue +1); returns ``y0`` and ``P``."""
    y = np.asarray(y, dtype=float)
    for _ in range(40):
        r = flow(y, 0.0, 0.5 * period, sensitivity=True)
        dy = np.linalg.solve(r.sensitivity + np.eye(2), -(r.y + y))
        y = y + dy
        if np.abs(dy).max() <= 1e-12 * max(1.0, np.abs(y).max()):
            return y, flow(y, 0.0, 0.5 * period, sensitivity=True).sensitivity
    raise AssertionError("the symmetric orbit did not converge")


def symmetric_branch_point(make_flow, W_lo, y_lo, W_hi, y_hi, tol=1e-10) -> float:
    """Bisection in Omega for the zero of ``det(I - P)`` along the symmetric orbits."""

    def test(W, y):
        y, P = symmetric_orbit(make_flow(W), y, 2.0 * math.pi / W)
        return float(np.linalg.det(np.eye(2) - P)), y

    f_lo, y_lo = test(W_lo, y_lo)
    f_hi, y_hi = test(W_hi, y_hi)
    assert f_lo * f_hi < 0, "no branch point in the bracket"
    while W_hi - W_lo > tol:
        W = 0.5 * (W_lo + W_hi)
        f, y = test(W, y_lo if W - W_lo < W_hi - W else y_hi)
        if f * f_lo > 0:
            W_lo, f_lo, y_lo = W, f, y
        else:
            W_hi, y_hi = W, y
    return 0.5 * (W_lo + W_hi)


def hb_state(branch, i: int) -> np.ndarray:
    """``(x, v)`` at ``t = 0`` of the HB orbit ``i`` of a branch (m = 1: theta = Omega t)."""
    basis = branch.system.basis
    u = branch.coefficients[i]
    x0 = float(basis.evaluate(u, [0.0])[0])
    v0 = float(basis.evaluate(u, [0.0], 1)[0]) * float(branch.omega[i])
    return np.array([x0, v0])


@functools.cache
def nsd_exact():
    return exact_branches(builtin_model("nsd", **NSD_K3), WINDOW, progress=False)


@functools.cache
def nsd_hb(branch_points: bool = True):
    osc = builtin_model("nsd", **NSD_K3)
    # without branch switching: the other stages as they were before it (the attractor and
    # window-edge search, added later, finds some of the same branches another way)
    return harmonic_balance_branches(
        osc,
        WINDOW,
        harmonics=15,
        branch_points=branch_points,
        attractors=branch_points,
        seeds=single_harmonic_seeds,
    )


def double_well(F: float = 0.6) -> Oscillator:
    return Oscillator.parse(DOUBLE_WELL, {"F": F, "Omega": 1.0}, name="double_well")


@functools.cache
def double_well_hb():
    # H = 31: the cross-well orbits below Omega ~ 0.5 need it (H = 15 leaves 1e-4..1e-2 in
    # amplitude there); no stability, whose full Hill eigenproblem per point would dominate
    return harmonic_balance_branches(
        double_well(), DW_WINDOW, harmonics=31, stability="none", seeds=single_harmonic_seeds
    )


# ---------------------------------------------------------------------------------------------
# the continuation core
# ---------------------------------------------------------------------------------------------
def _trace_trivial(residual, jacobian):
    return continue_curve(
        residual,
        jacobian,
        [0.0],
        -1.0,
        (-1.0, 1.0),
        u_scale=1.0,
        lam_scale=1.0,
        ds_max=0.07,
        detect_branch_points=True,
    )


def test_core_pitchfork_branch_point_and_branch_off():
    """``lam u - u^3``: tracing ``u = 0`` finds one branch point at lam = 0 (the augmented
    determinant is ``-lam``), the other curve's direction is ``(u, lam) = (1, 0)``, and
    :func:`branch_off` lands on ``u^2 = lam`` on both sides."""

    def residual(u, lam):
        return lam * u - u**3

    def jacobian(u, lam):
        return np.array([[lam - 3 * u[0] ** 2]]), u.copy()

    curve = _trace_trivial(residual, jacobian)
    assert curve.stop_reason == "window" and not curve.folds
    assert len(curve.branch_points) == 1
    bp = curve.branch_points[0]
    assert isinstance(bp, BranchPoint) and bp.refined
    assert abs(bp.lam) < 1e-9 and abs(bp.u[0]) < 1e-12
    assert abs(abs(bp.direction[0]) - 1.0) < 1e-6
    assert abs(abs(bp.tangent[1]) - 1.0) < 1e-6
    sides = branch_off(residual, jacobian, bp, step=0.1)
    assert len(sides) == 2
    us = sorted(float(u[0]) for u, _ in sides)
    assert us[0] < -0.05 and us[1] > 0.05
    for u, lam in sides:
        assert abs(lam - u[0] ** 2) < 1e-10


def test_core_transcritical_branch_point():
    """``u (lam - u)``: branch point at 0, the other curve ``u = lam``. ``[F_u | F_lam]``
    vanishes there, so the second null vector orthogonal to the traced tangent ``(0, 1)`` is
    ``(1, 0)``; :func:`branch_off` still lands on ``u = lam`` (the hyperplane ``u = +-step``
    meets only that curve)."""

    def residual(u, lam):
        return u * (lam - u)

    def jacobian(u, lam):
        return np.array([[lam - 2 * u[0]]]), u.copy()

    curve = _trace_trivial(residual, jacobian)
    assert len(curve.branch_points) == 1
    bp = curve.branch_points[0]
    assert abs(bp.lam) < 1e-9
    assert abs(abs(bp.direction[0]) - 1.0) < 1e-6
    sides = branch_off(residual, jacobian, bp, step=0.1)
    assert len(sides) == 2
    for u, lam in sides:
        assert abs(u[0] - lam) < 1e-10 and abs(lam) > 0.05


def test_core_folds_are_not_branch_points():
    """``u^3 - u - lam``: two folds (det F_u changes sign twice), no branch point."""

    def residual(u, lam):
        return u**3 - u - lam

    def jacobian(u, lam):
        return np.array([[3 * u[0] ** 2 - 1]]), np.array([-1.0])

    curve = continue_curve(
        residual,
        jacobian,
        [-1.5],
        -1.875,
        (-2.0, 2.0),
        u_scale=1.0,
        lam_scale=1.0,
        ds_max=0.05,
        detect_branch_points=True,
    )
    assert curve.stop_reason == "window"
    assert len(curve.folds) == 2
    assert curve.branch_points == ()


# ---------------------------------------------------------------------------------------------
# nsd at k = -3 against the exact response
# ---------------------------------------------------------------------------------------------
def _exact_in_well(eb):
    """The exact in-well branches with the fold at Omega ~ 0.617 (mean -4..-1.3 and its
    mirror image), found by their shape, not by index."""
    out = []
    for b in eb.branches:
        br = b.to_branch()
        if 0.6 < br.omega.max() < 0.65 and np.min(np.abs(br.mean)) > 1.0:
            out.append((b, br))
    return out


def test_nsd_k3_in_well_branches_that_were_missed_now_match_exact():
    """Before branch switching and linear-segment seeds, ``compare`` reported the exact
    in-well branches 0 and 1 (Omega 0.2..0.617) missed. Now every exact branch has an HB
    counterpart, the HB branches matched to the in-well pair reproduce them to 5e-3 (H = 15;
    measured 1.5e-3), and one HB branch sits in each well: same mean range and fold as its
    exact branch (compare matches by amplitude, where a mirror pair ties)."""
    eb = nsd_exact()
    exact = eb.to_response()
    osc = builtin_model("nsd", **NSD_K3)
    resp = harmonic_balance_response(
        osc, WINDOW, harmonics=15, all_branches=True, seeds=single_harmonic_seeds
    )
    cmp = compare(resp, exact)
    assert cmp.missed == ()
    in_well = _exact_in_well(eb)
    assert len(in_well) == 2
    ref_index = {i for i, b in enumerate(eb.branches) if any(b is e for e, _ in in_well)}
    hb = nsd_hb()
    # each in-well exact branch is reproduced by its HB twin (same mean range), compared
    # alone: compare's matching of the whole response may pair an in-well exact branch with
    # another HB branch of equal amplitude (a real orbit family found by the attractor and
    # window-edge search, e.g. Omega 0.2-0.4834, mean 1.6-3.96, checked by shooting)
    for _, br in in_well:
        twins = [
            h
            for h in hb
            if abs(h.mean.min() - br.mean.min()) < 2e-2 and abs(h.mean.max() - br.mean.max()) < 2e-2
        ]
        assert len(twins) == 1
        sub = compare(twins[0].to_response(), exact)
        assert sub.matches[0] in ref_index
        assert sub.branches[0].max_error < 5e-3
    for b, br in in_well:
        fold = [s.parameter for s in b.special_points if s.kind == "fold"]
        twins = [
            h
            for h in hb
            if abs(h.mean.min() - br.mean.min()) < 2e-2 and abs(h.mean.max() - br.mean.max()) < 2e-2
        ]
        assert len(twins) == 1
        assert len(twins[0].folds) == 1
        assert twins[0].folds[0][0] == pytest.approx(fold[0], rel=1e-3)


def test_nsd_k3_branch_point_and_switched_branch_match_exact():
    """The symmetric cross-well loop has one branch point (symmetry-breaking, subcritical);
    HB locates it within HB's own accuracy at H = 15 (the loop's max amplitude error against
    the exact response) and within 5e-4 relative of the exact branch point (refined by the
    symmetric-orbit oracle from the exact continuation's bracketing points; measured
    9.2e-5). The branch switched onto there is the exact asymmetric branch through both
    sides of it (mean -0.78..0.78, fold at the branch point, both ends at the low edge);
    without branch switching it is not found."""
    eb = nsd_exact()
    osc = builtin_model("nsd", **NSD_K3)
    # the cross-well loop (max|x| ~ 43); smaller branches may have branch points of their own
    loop = [b for b in eb.branches if b.branch_points and b.to_branch().amplitude.max() > 40.0]
    assert len(loop) == 1
    sp = loop[0].branch_points[0]
    a, c = loop[0].points[sp.index], loop[0].points[sp.index + 1]
    W_exact = symmetric_branch_point(
        lambda W: ExactPWLFlow(osc.with_params(Omega=W)), a.parameter, a.y0, c.parameter, c.y0
    )
    hb = nsd_hb()
    hb_loops = [h for h in hb if h.amplitude.max() > 40.0]
    assert len(hb_loops) == 1 and len(hb_loops[0].branch_points) == 1
    W_hb = hb_loops[0].branch_points[0][0]
    cmp = compare(hb_loops[0].to_response(), eb.to_response())
    rel = abs(W_hb - W_exact) / W_exact
    assert rel < cmp.branches[0].max_error
    assert rel < 5e-4
    assert hb_loops[0].branch_point_records[0].refined

    # the branch switched onto at the loop's branch point folds there (other branches found
    # at the window's edge have branch points of their own)
    switched = [
        h for h in hb if h.origin == "branch point" and abs(h.omega.max() - W_hb) <= 1e-3 * W_hb
    ]
    assert len(switched) == 1
    sw = switched[0]
    # the exact branch through both sides of the branch point: mean of both signs
    ref = [
        i
        for i, b in enumerate(eb.branches)
        if b.to_branch().mean.max() > 0.5 and b.to_branch().mean.min() < -0.5
    ]
    assert len(ref) == 1
    ref_br = eb.branches[ref[0]].to_branch()
    assert sw.mean.max() == pytest.approx(ref_br.mean.max(), abs=5e-3)
    assert sw.mean.min() == pytest.approx(ref_br.mean.min(), abs=5e-3)
    assert sw.omega.max() == pytest.approx(ref_br.omega.max(), rel=5e-4)
    assert sw.omega[0] == pytest.approx(WINDOW[0]) and sw.omega[-1] == pytest.approx(WINDOW[0])
    sub = compare(sw.to_response(), eb.to_response())
    assert sub.matches[0] == ref[0] and sub.branches[0].max_error < 5e-3
    # without branch switching no branch of the response has a mean beyond 0.5 and below 1
    plain = nsd_hb(False)
    assert not any(0.5 < np.abs(h.mean).max() < 1.0 for h in plain)
    assert all(h.origin != "branch point" for h in plain)


# ---------------------------------------------------------------------------------------------
# a smooth odd system: the double-well Duffing oscillator
# ---------------------------------------------------------------------------------------------
def test_double_well_switched_branch_matches_shooting():
    """x'' + 0.1 x' - x + x^3 = 0.6 cos(Omega t), H = 31: the symmetric cross-well branch
    (found from the single-harmonic seeds) has a symmetry-breaking branch point; the
    asymmetric branch switched onto there is checked at six strongly asymmetric points
    (Omega >= 0.45, where H = 31 resolves the orbits to ~1e-7) against tight shooting from
    the HB state (amplitude and mean; measured 9.4e-8 and 2.6e-12), and its branch point
    against the symmetric-orbit oracle (measured 4.5e-10)."""
    osc = double_well()
    brs = double_well_hb()
    switched = [b for b in brs if b.origin == "branch point"]
    assert len(switched) == 1
    sw = switched[0]
    assert sw.mean.max() > 0.3 and sw.mean.min() < -0.3  # both sides of the pitchfork
    asym = np.nonzero((np.abs(sw.mean) > 0.5 * np.abs(sw.mean).max()) & (sw.omega >= 0.45))[0]
    assert asym.size >= 6
    worst_amp = worst_mean = 0.0
    for i in asym[np.linspace(0, asym.size - 1, 6).round().astype(int)]:
        W = float(sw.omega[i])
        flow = ODEFlow(osc.with_params(Omega=W), rtol=1e-12, atol=1e-12)
        ref = periodic_orbit(flow, hb_state(sw, i))
        assert abs(ref.mean) > 0.1  # shooting kept the asymmetric orbit
        worst_amp = max(worst_amp, abs(sw.amplitude[i] - ref.amplitude) / ref.amplitude)
        worst_mean = max(worst_mean, abs(sw.mean[i] - ref.mean))
    assert worst_amp < 1e-6 and worst_mean < 1e-8

    parents = [b for b in brs if b.origin != "branch point" and b.branch_points]
    bp = next(
        r
        for b in parents
        for r in b.branch_point_records
        if abs(r.lam - sw.branch_points[0][0]) < 1e-6
    )
    system = sw.system
    W0 = float(bp.lam)

    def y_sym(W):
        # the HB symmetric orbit at the branch point as the guess (Newton on the half-period
        # map is equivariant, so it stays symmetric)
        x0 = float(system.basis.evaluate(bp.u, [0.0])[0])
        v0 = float(system.basis.evaluate(bp.u, [0.0], 1)[0]) * W
        return np.array([x0, v0])

    W_ref = symmetric_branch_point(
        lambda W: ODEFlow(osc.with_params(Omega=W), rtol=1e-12, atol=1e-12),
        W0 - 0.01,
        y_sym(W0 - 0.01),
        W0 + 0.01,
        y_sym(W0 + 0.01),
        tol=1e-11,
    )
    assert abs(W0 - W_ref) < 1e-7


# ---------------------------------------------------------------------------------------------
# symmetry, reporting and input checks
# ---------------------------------------------------------------------------------------------
def test_nsd_k05_every_exact_branch_once():
    """k = -0.5: the exact solver's four branches (the resonant one, the cross-well loop
    between its folds at Omega ~ 0.244 and 0.486, the in-well pair joined at 1.16, the low
    branch below 0.239) are each found once. Regression: the mirror image of the loop, which
    is the loop itself traced the other way, was added as a fifth branch, because its fold
    tips lie beyond every sample of the original and no chord brackets them."""
    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    exact = exact_branches(osc, (0.2, 2.0), progress=False).to_response()
    # (at H = 31 the loop's image was added again; at H = 15 it happened to be caught)
    hb = harmonic_balance_response(
        osc, (0.2, 2.0), harmonics=31, all_branches=True, seeds=single_harmonic_seeds
    )
    assert len(hb.branches) == len(exact.branches) == 4
    cmp = compare(hb, exact)
    assert not cmp.missed and not cmp.spurious
    # errors below 5e-3 (H = 31 on orbits with kinks) except at the tip of a fold that HB
    # places a hair beyond the exact one (the nearest exact solution there lies on the
    # fold's other side): measured 0.16 on 5 points up to 1.4e-4 (relative) beyond the exact
    # fold at 0.2132, and 9.7e-3 at 5e-6 from the fold at 0.2386
    folds = np.array([f[0] for f in exact.folds])
    w = np.concatenate([b.omega for b in hb.branches])
    big = np.asarray(cmp.rel_errors, dtype=float) > 5e-3
    assert big.sum() <= 10 and all(np.min(np.abs(folds - x)) <= 5e-4 * x for x in w[big])


def test_mirror_images_are_solutions_and_symmetry_is_detected():
    """The image of an asymmetric branch under x -> -x(t + T/2) solves the HB equations at
    every point (residual at the continuation tolerance) with the opposite mean; the
    symmetry is found for nsd (PWL, exact projection) and the double well (AFT), and not for
    a bilinear spring, a static load or an odd-only basis."""
    hb = nsd_hb()
    system = hb[0].system
    S = odd_symmetry(system, WINDOW)
    assert S is not None
    asym = next(b for b in hb if abs(b.mean).max() > 1.0)
    image = mirror_branch(asym, S)
    assert image.origin == "mirror"
    np.testing.assert_allclose(image.mean, -asym.mean, atol=1e-14)
    np.testing.assert_allclose(image.amplitude, asym.amplitude, rtol=1e-12)
    res = max(
        float(np.abs(system.residual(u, W)).max())
        for u, W in zip(image.coefficients, image.omega, strict=True)
    )
    assert res < 1e-7
    assert odd_symmetry(HarmonicBalanceSystem(double_well(), harmonics=5), DW_WINDOW) is not None
    bilinear = HarmonicBalanceSystem(builtin_model("bilinear"), harmonics=5)
    assert odd_symmetry(bilinear, (0.5, 2.0)) is None
    loaded = Oscillator.parse("x'' + 0.1*x' + x + x**3 = 0.2 + F*cos(Omega*t)", {"F": 0.5})
    assert odd_symmetry(HarmonicBalanceSystem(loaded, harmonics=5), (0.5, 2.0)) is None
    odd = HarmonicBalanceSystem(double_well(), harmonics=5, odd_only=True)
    assert odd_symmetry(odd, DW_WINDOW) is None


def test_branch_points_are_reported_in_the_response_notes():
    hb = nsd_hb()
    resp = harmonic_balance_response(
        builtin_model("nsd", **NSD_K3),
        WINDOW,
        harmonics=15,
        all_branches=True,
        seeds=single_harmonic_seeds,
    )
    assert len(resp.branches) == len(hb)
    note = [n for n in resp.notes if n.startswith("branch points at Omega")]
    assert len(note) == 1 and "0.483525" in note[0]
    # the plain response (all_branches=False) is unchanged: no detection, no such note
    plain = harmonic_balance_response(builtin_model("nsd", **NSD_K3), WINDOW, harmonics=15)
    assert not any("branch point" in n for n in plain.notes)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"max_branches": 0}, "max_branches = 0"),
        ({"max_branches": 2.5}, "max_branches = 2.5"),
        ({"branch_points": "yes"}, "branch_points = 'yes'"),
        ({"mirror": 1}, "mirror = 1"),
        ({"direction": 0}, "direction = 0"),
    ],
)
def test_bad_options_raise_parameter_errors(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        harmonic_balance_branches(builtin_model("nsd", **NSD_K3), WINDOW, harmonics=3, **kwargs)


def test_branch_off_rejects_bad_input():
    def residual(u, lam):
        return u

    def jacobian(u, lam):
        return np.eye(1), np.zeros(1)

    with pytest.raises(ParameterError, match="expected a BranchPoint"):
        branch_off(residual, jacobian, (0.0, 0.0))
    bp = BranchPoint(
        0, 0.0, np.zeros(1), np.array([0.0, 1.0]), np.array([1.0, 0.0]), np.ones(1), 1.0
    )
    with pytest.raises(ParameterError, match="step"):
        branch_off(residual, jacobian, bp, step=-1.0)
