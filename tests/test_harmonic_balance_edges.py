"""Every branch of the exact response has numeric-HB points near it, branches that lie in the
window only near an edge (nsd k = -0.5 from 0.3, k = -3 from 0.2), stable isolas (nsd k =
2, clearance) and branches stable only on a very narrow band (k = -3) included.

Oracle: the exact response (continuation of exact periodic orbits of the piecewise-linear
flow), computed here. HB with H = 15 is within its truncation error of it: 2 % of the amplitude
(the largest HB error against the exact amplitudes on these problems is ~0.6 %, at the large
superharmonic orbits of k = -3 near Omega = 0.2), and of the mean (2 % of the amplitude,
at least 0.02).
"""

from __future__ import annotations

import numpy as np
import pytest

import perturb
from perturb.model.builtins import builtin_model

#: share of an exact branch's points that must have an HB point near them: the polyline of a
#: traced branch cuts corners at folds, where a few exact points fall between two chords
MIN_SHARE = 0.9


def _hb_values_at(branch, W: float) -> list[tuple[float, float]]:
    """``(amplitude, mean)`` of the HB branch's polyline at each crossing of ``W``."""
    Wb = np.asarray(branch.omega)
    A = np.asarray(branch.amplitude)
    M = np.asarray(branch.mean)
    out = []
    for i in np.nonzero((Wb[:-1] - W) * (Wb[1:] - W) <= 0.0)[0]:
        dw = Wb[i + 1] - Wb[i]
        f = 0.5 if dw == 0 else (W - Wb[i]) / dw
        out.append(((1 - f) * A[i] + f * A[i + 1], (1 - f) * M[i] + f * M[i + 1]))
    return out


def _near(hb, W: float, a: float, mean: float) -> bool:
    """An HB point within 2 % of the amplitude (and of the mean) at ``W`` or at a frequency
    0.1 % away: the truncation moves a fold a little, and the exact points beyond the HB fold's
    tip would otherwise have no HB point at their frequency."""
    tol = 0.02 * abs(a)
    return any(
        abs(ah - a) <= tol and abs(mh - mean) <= max(tol, 0.02)
        for b in hb.branches
        for w in (W, W * (1 - 1e-3), W * (1 + 1e-3))
        for ah, mh in _hb_values_at(b, w)
    )


@pytest.mark.parametrize(
    ("model", "params", "window", "exact_at_least"),
    [
        ("nsd", {"k": -0.5, "mu": 0.05, "F": 2.0}, (0.3, 2.0), 5),
        # the bench window: 23 exact branches, among them the mirror pairs stable only on
        # Omega ~0.3152-0.3164 and ~0.2349-0.2352 (narrow basins: HB reaches the second
        # only from simulations started beside the unstable orbits it has traced)
        ("nsd", {"k": -3.0, "mu": 0.05, "F": 2.0}, (0.2, 2.5), 23),
        ("nsd", {"k": 2.0, "mu": 0.05, "F": 2.0}, (0.2, 2.5), 2),
        # the bench problem: a superharmonic isola on Omega 0.508-0.654 beside the main branch
        ("clearance", {"r": 10.0, "d": 0.5, "mu": 0.02, "F": 0.3}, (0.5, 1.6), 1),
    ],
)
def test_every_exact_branch_has_hb_points(model, params, window, exact_at_least):
    osc = builtin_model(model, **params)
    exact = perturb.frequency_response(osc, "exact", Omega=window)
    # the exact solver finds the branches the issue names (else the comparison is weaker)
    assert len(exact.branches) >= exact_at_least
    hb = perturb.frequency_response(osc, "hb", Omega=window, harmonics=15, all_branches=True)
    for i, br in enumerate(exact.branches):
        W, A, M = (np.asarray(c) for c in (br.omega, br.amplitude, br.mean))
        hits = [_near(hb, w, a, m) for w, a, m in zip(W, A, M, strict=True)]
        share = float(np.mean(hits))
        assert share >= MIN_SHARE, (
            f"{model} {params}: exact branch {i} (Omega {W.min():.4f}-{W.max():.4f}, amplitude "
            f"{A.min():.3f}-{A.max():.3f}, mean {M.min():.3f}..{M.max():.3f}) has HB points "
            f"near only {share:.0%} of its points"
        )


def test_attractors_option_must_be_a_flag():
    from perturb.errors import ParameterError
    from perturb.numeric.harmonic_balance import harmonic_balance_branches

    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    with pytest.raises(ParameterError, match="attractors = 'yes'"):
        harmonic_balance_branches(osc, (0.3, 2.0), harmonics=3, attractors="yes")
