"""Results of a continuation: the traced curve and its special points.

Plain data, shared by the core loop (:mod:`.core`), the event tests (:mod:`.events`) and
branch switching (:mod:`.switching`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from perturb import checks
from perturb.errors import ParameterError, PerturbError

__all__ = [
    "ContinuationError",
    "FoldPoint",
    "BranchPoint",
    "ContinuationCurve",
    "Residual",
    "Jacobian",
    "check_window",
    "positive",
]

#: ``residual(u, lam) -> F``, shape ``(n,)``
Residual = Callable[[np.ndarray, float], np.ndarray]
#: ``jacobian(u, lam) -> (F_u, F_lam)``, shapes ``(n, n)`` and ``(n,)``
Jacobian = Callable[[np.ndarray, float], tuple[np.ndarray, np.ndarray]]


class ContinuationError(PerturbError):
    """The starting point could not be corrected onto the curve, or Newton at fixed
    parameter failed."""


@dataclass(frozen=True, eq=False)
class FoldPoint:
    """A fold (turning point in :math:`\\lambda`) between two consecutive curve points.

    Attributes
    ----------
    index : int
        The fold lies between ``curve.u[index]`` and ``curve.u[index + 1]``.
    lam : float
        Parameter value at the fold.
    u : numpy.ndarray
        Unknowns at the fold.
    refined : bool
        False when the regula-falsi refinement failed and the point is the Hermite
        interpolation of the two neighbours instead.
    """

    index: int
    lam: float
    u: np.ndarray
    refined: bool = True


@dataclass(frozen=True, eq=False)
class BranchPoint:
    """A simple branch point (another solution curve crosses this one) between two
    consecutive curve points.

    Attributes
    ----------
    index : int
        The branch point lies between ``curve.u[index]`` and ``curve.u[index + 1]``.
    lam : float
        Parameter value at the branch point.
    u : numpy.ndarray
        Unknowns at the branch point.
    tangent : numpy.ndarray
        Unit tangent of the traced curve there, scaled coordinates ``(u / u_scale, lam /
        lam_scale)``.
    direction : numpy.ndarray
        The second null vector of ``[F_u u_scale | F_lam lam_scale]`` there, orthogonal to
        ``tangent``, same coordinates; its sign is arbitrary. The other curve's tangent is a
        combination of the two (found by :func:`branch_off`'s correction); it *is* this
        vector at a symmetry-breaking pitchfork, where the two tangents lie in complementary
        symmetry subspaces (symmetric and antisymmetric).
    u_scale : numpy.ndarray
        Scale of the unknowns of those coordinates.
    lam_scale : float
    refined : bool
        False when the bracket of corrected trials did not shrink below ``1e-3`` of the step
        and no trial's determinant fell below 1 % of its values at the two points; the
        point is the secant estimate between the closest trials either way.
    """

    index: int
    lam: float
    u: np.ndarray
    tangent: np.ndarray
    direction: np.ndarray
    u_scale: np.ndarray
    lam_scale: float
    refined: bool = True


@dataclass(frozen=True, eq=False)
class ContinuationCurve:
    """A traced solution curve, ordered along the arclength.

    Attributes
    ----------
    u : numpy.ndarray
        Shape ``(n_points, n)``: the unknowns at each point.
    lam : numpy.ndarray
        Shape ``(n_points,)``.
    tangents : numpy.ndarray
        Shape ``(n_points, n + 1)``: unit tangents in scaled coordinates ``(u / u_scale,
        lam / lam_scale)`` (the scales in force at that point), pointing along the direction
        of travel.
    iterations : numpy.ndarray
        Newton iterations of each point's correction (0 for the start when not corrected).
    jacobians : numpy.ndarray or None
        Shape ``(n_points, n, n)``: :math:`F_u` at each point, when ``store_jacobians`` (at
        the last Newton iterate of the point's correction: it differs from the point by the
        last correction, at most about ``sqrt(tol * previous correction)``).
    callback_values : tuple or None
        What ``callback`` returned at each point.
    folds : tuple of FoldPoint
    branch_points : tuple of BranchPoint
        Empty unless ``detect_branch_points``.
    stop_reason : str
        ``'window'`` (reached an edge of the window; the last point is on it), ``'closed'``
        (returned to the start), ``'max_points'``, ``'step_underflow'`` (the step fell below
        ``ds_min``: the corrector kept failing).
    residual_evaluations, jacobian_evaluations : int
        Calls of the user's callables.
    u_scale, lam_scale
        The scales in force at the end (``u_scale`` changes with ``adaptive_scale``).
    """

    u: np.ndarray
    lam: np.ndarray
    tangents: np.ndarray
    iterations: np.ndarray
    jacobians: np.ndarray | None
    folds: tuple[FoldPoint, ...]
    stop_reason: str
    residual_evaluations: int = 0
    jacobian_evaluations: int = 0
    u_scale: np.ndarray = field(default_factory=lambda: np.ones(1))
    lam_scale: float = 1.0
    callback_values: tuple[Any, ...] | None = None
    branch_points: tuple[BranchPoint, ...] = ()

    def __len__(self) -> int:
        return int(self.lam.size)

    def __repr__(self) -> str:
        return (
            f"ContinuationCurve({len(self)} points, lam {self.lam.min():.6g}..{self.lam.max():.6g}"
            f", {len(self.folds)} folds, stopped: {self.stop_reason})"
        )


def check_window(window: Sequence[float]) -> tuple[float, float]:
    """``(low, high)`` of a parameter window: two finite numbers, low < high
    (:func:`perturb.checks.window` with ``positive=False``)."""
    return checks.window(window, "window", positive=False)


def positive(name: str, value: float) -> float:
    """``value`` as a float, checked positive and finite (ParameterError naming ``name``)."""
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{name} = {value!r}: expected a positive finite number")
    return value
