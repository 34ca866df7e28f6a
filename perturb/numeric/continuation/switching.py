"""Branch switching at a located branch point: step off along the other curve's direction
and correct onto it."""

from __future__ import annotations

import numpy as np

from perturb.errors import ParameterError
from perturb.numeric.continuation.corrector import BorderedCorrector, CountedProblem
from perturb.numeric.continuation.curve import BranchPoint, Jacobian, Residual, positive

__all__ = ["branch_off"]


def branch_off(
    residual: Residual,
    jacobian: Jacobian,
    point: BranchPoint,
    *,
    step: float = 0.05,
    tol: float = 1e-10,
    max_newton: int = 8,
) -> list[tuple[np.ndarray, float]]:
    """Points on the other curve through a branch point, one on each side.

    From the branch point ``w_b`` a predictor ``w_b +- step d`` along the other curve's
    direction ``d`` (:attr:`BranchPoint.direction`) is corrected by Newton on the
    hyperplane ``d . (w - w_b) = +-step`` (bordered system, scaled coordinates of the
    branch point): the traced curve crosses that hyperplane only far away (it leaves the
    branch point orthogonally to ``d``), so the corrector lands on the other curve. A
    failed correction is retried with half the step, twice.

    Parameters
    ----------
    residual, jacobian
        As for :func:`continue_curve`.
    point : BranchPoint
        From :attr:`ContinuationCurve.branch_points`.
    step : float
        Distance from the branch point in its scaled coordinates (``u / u_scale``,
        ``lam / lam_scale``).
    tol, max_newton
        As for :func:`continue_curve`.

    Returns
    -------
    list of (numpy.ndarray, float)
        ``(u, lam)`` of each side whose correction converged (at most two).

    Raises
    ------
    ParameterError
        For a ``point`` that is not a BranchPoint or a non-positive ``step`` or ``tol``.
    """
    if not isinstance(point, BranchPoint):
        raise ParameterError(f"point = {point!r}: expected a BranchPoint")
    step = positive("step", step)
    tol = positive("tol", tol)
    n = point.u.size
    fun = CountedProblem(residual, jacobian, n)
    tr = BorderedCorrector(
        fun, np.asarray(point.u_scale, dtype=float), point.lam_scale, tol, max_newton
    )
    wb = tr.scaled(point.u, point.lam)
    d = point.direction
    out = []
    for sign in (1.0, -1.0):
        h = step
        for _ in range(3):
            w_pred = wb + sign * h * d
            c = tr.correct(w_pred, d, float(d @ w_pred))
            if c is not None:
                out.append(tr.unscaled(c.w))
                break
            h *= 0.5
    return out
