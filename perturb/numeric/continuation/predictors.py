r"""Predictors: the cubic Hermite arc through the last two points and their tangents.

Used by :func:`~perturb.numeric.continuation.continue_curve` (``predictor="hermite"``) and by
the exact frequency response (:mod:`perturb.simulate.exact_response`), whose shooting points
are extrapolated by the same formula.  Parametrised by the chord length ``h`` between the two
points, the arc extrapolated by ``step`` beyond the last one has error
:math:`O(h^2 \, step^2)` against :math:`O(step^2)` for the tangent predictor, so the first
Newton correction is small enough to be the last one.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["hermite_extrapolate", "hermite_direction", "hermite_fold"]


def hermite_extrapolate(
    w0: np.ndarray,
    t0: np.ndarray,
    w1: np.ndarray,
    t1: np.ndarray,
    step: float,
    h: float | None = None,
) -> np.ndarray | None:
    """The cubic Hermite arc through ``w0`` and ``w1`` (unit tangents ``t0``, ``t1``)
    extrapolated ``step`` beyond ``w1``.

    Parameters
    ----------
    w0, t0, w1, t1 : numpy.ndarray
        The two points and their unit tangents (same coordinates).
    step : float
        Arclength beyond ``w1``.
    h : float, optional
        The chord length ``|w1 - w0|`` when the caller has it.

    Returns
    -------
    numpy.ndarray or None
        The predicted point; None when the points coincide.
    """
    if h is None:
        h = float(np.linalg.norm(w1 - w0))
    if not math.isfinite(h) or h <= 0.0:
        return None
    s = 1.0 + step / h
    s2, s3 = s * s, s * s * s
    h00, h10 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s
    h01, h11 = -2 * s3 + 3 * s2, s3 - s2
    return h00 * w0 + h10 * h * t0 + h01 * w1 + h11 * h * t1


def hermite_direction(
    w0: np.ndarray, t0: np.ndarray, w1: np.ndarray, t1: np.ndarray, step: float, h: float
) -> np.ndarray:
    """Unit derivative of the arc of :func:`hermite_extrapolate` at the predicted point (a
    corrector's hyperplane normal there); ``h > 0`` the chord length."""
    s = 1.0 + step / h
    s2 = s * s
    du = (6 * s2 - 6 * s) * w0 + (3 * s2 - 4 * s + 1) * h * t0
    du = du + (-6 * s2 + 6 * s) * w1 + (3 * s2 - 2 * s) * h * t1
    return du / np.linalg.norm(du)


def hermite_fold(
    w0: np.ndarray, t0: np.ndarray, w1: np.ndarray, t1: np.ndarray, ds: float
) -> np.ndarray:
    """Point of the cubic Hermite arc between two points where the last component is
    stationary (a fold's estimate when its refinement fails)."""
    # lam(s) = h00 l0 + h10 ds m0 + h01 l1 + h11 ds m1, s in [0, 1]; its derivative is a
    # quadratic whose root in (0, 1) is the fold
    l0, l1, m0, m1 = w0[-1], w1[-1], t0[-1] * ds, t1[-1] * ds
    c2 = 3 * (2 * l0 + m0 - 2 * l1 + m1)
    c1 = 2 * (-3 * l0 - 2 * m0 + 3 * l1 - m1)
    c0 = m0
    roots = np.roots([c2, c1, c0]) if c2 != 0 else np.array([-c0 / c1])
    roots = roots[np.isreal(roots)].real
    inside = roots[(roots > 0) & (roots < 1)]
    s = float(inside[0]) if inside.size else 0.5
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * w0 + h10 * ds * t0 + h01 * w1 + h11 * ds * t1
