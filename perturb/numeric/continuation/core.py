"""The pseudo-arclength loop: :func:`continue_curve` and its options.

Predictor, corrector, step control and event tests are the objects of the sibling modules;
this loop strings them together (module docstring of :mod:`perturb.numeric.continuation` for
the algorithm).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ParameterError
from perturb.numeric.continuation.corrector import (
    BorderedCorrector,
    Corrected,
    CountedProblem,
    newton_fixed,
    start_tangent,
)
from perturb.numeric.continuation.curve import (
    ContinuationCurve,
    Jacobian,
    Residual,
    check_window,
    positive,
)
from perturb.numeric.continuation.events import BranchPointTest, FoldTest
from perturb.numeric.continuation.predictors import hermite_extrapolate
from perturb.numeric.continuation.steps import StepControl

__all__ = ["ContinuationOptions", "continue_curve"]


@dataclass(frozen=True)
class ContinuationOptions:
    """Options of :func:`continue_curve` (each also accepted as a keyword of it).

    Attributes
    ----------
    direction : {1, -1}
        Initial direction of travel in :math:`\\lambda`.
    u_scale : float or array_like
        Scale of the unknowns (see the module docstring); broadcast to ``(n,)``.
    lam_scale : float, optional
        Scale of the parameter; default the window width.
    adaptive_scale : bool
        Let the scale of the unknowns follow the solution: after each point it becomes
        ``max(u_scale, max|u|)`` (re-set when it changes by more than 25 %), so ``ds_max`` is
        a relative step whether the solution is small or large.
    ds : float, optional
        First step (scaled arclength); default ``ds_max / 4``.
    ds_min : float, optional
        Smallest step; default ``1e-6 * ds_max``.
    ds_max : float
        Largest step: the output spacing along the curve.
    growth : float
        Step growth factor after an easy correction.
    max_turn : float
        Largest angle (radians) between consecutive tangents before a step is redone
        shorter.
    tol : float
        Convergence tolerance on the scaled Newton correction.
    max_newton : int
        Newton iterations per correction.
    max_points : int
        Largest number of points (the start included).
    correct_start : bool
        Newton at fixed ``lam0`` on ``u0`` first.
    refine_folds : bool
        Locate folds on the curve (a few extra corrections per fold).
    store_jacobians : bool
        Keep :math:`F_u` at every point (:attr:`ContinuationCurve.jacobians`).
    callback : callable, optional
        ``callback(u, lam, F_u, F_lam)`` at every accepted point (the start included), with
        the Jacobian of the point's last Newton iterate; its return values are kept in
        :attr:`ContinuationCurve.callback_values`.  Stability or test functions go here,
        while the caller's own cache still holds that iterate.
    predictor : {'tangent', 'hermite'}
        ``'tangent'``: the Euler predictor along the unit tangent.  ``'hermite'``: the cubic
        Hermite arc through the last two points and their tangents, extrapolated by the step
        (the tangent predictor for the first step and after a rescaling); a fourth-order
        predictor, whose first Newton correction is typically ``1e-6`` of the step.
    early_accept : bool
        Accept a point after one Newton correction when ``K |dw_1|^2 <= tol``, with ``K``
        four times the largest quadratic-convergence ratio ``|dw_(k+1)| / |dw_k|^2``
        measured in the corrections of the last eight points (a point is corrected to the
        end whenever no such measurement is at hand, which refreshes it).  With the Hermite
        predictor this makes about one residual and Jacobian evaluation per point.
    detect_branch_points : bool
        Watch the sign of the augmented determinant (module docstring) and locate the branch
        points where it changes (:attr:`ContinuationCurve.branch_points`, ready for
        :func:`branch_off`): one extra ``(n + 1)``-square LU per point.
    """

    direction: int = 1
    u_scale: ArrayLike = 1.0
    lam_scale: float | None = None
    adaptive_scale: bool = False
    ds: float | None = None
    ds_min: float | None = None
    ds_max: float = 0.05
    growth: float = 1.5
    max_turn: float = 0.5
    tol: float = 1e-10
    max_newton: int = 8
    max_points: int = 5000
    correct_start: bool = True
    refine_folds: bool = True
    store_jacobians: bool = False
    callback: Callable[[np.ndarray, float, np.ndarray, np.ndarray], Any] | None = None
    predictor: str = "tangent"
    early_accept: bool = False
    detect_branch_points: bool = False


_OPTION_NAMES = frozenset(f.name for f in dataclasses.fields(ContinuationOptions))


def continue_curve(
    residual: Residual,
    jacobian: Jacobian,
    u0: ArrayLike,
    lam0: float,
    window: Sequence[float],
    options: ContinuationOptions | None = None,
    **keywords: Any,
) -> ContinuationCurve:
    """Trace the solution curve of :math:`F(u, \\lambda) = 0` through a window of
    :math:`\\lambda` by pseudo-arclength continuation.

    Parameters
    ----------
    residual : callable
        ``residual(u, lam) -> F``, shape ``(n,)``.
    jacobian : callable
        ``jacobian(u, lam) -> (F_u, F_lam)``, shapes ``(n, n)`` and ``(n,)``.  During a
        correction it is always called right after ``residual`` at the same point, so a
        caller whose residual and Jacobian share work can cache the last evaluation.
    u0 : array_like
        A point on (or, with ``correct_start``, near) the curve at ``lam0``.
    lam0 : float
        Starting parameter value, inside the window.
    window : (float, float)
        ``(low, high)``: the continuation stops when :math:`\\lambda` leaves it.
    options : ContinuationOptions, optional
        Step, tolerance, predictor and event settings (defaults: ``ContinuationOptions()``).
    **keywords
        Any field of :class:`ContinuationOptions` (``direction``, ``u_scale``, ``lam_scale``,
        ``adaptive_scale``, ``ds``, ``ds_min``, ``ds_max``, ``growth``, ``max_turn``,
        ``tol``, ``max_newton``, ``max_points``, ``correct_start``, ``refine_folds``,
        ``store_jacobians``, ``callback``, ``predictor``, ``early_accept``,
        ``detect_branch_points``), replacing the one of ``options``.

    Returns
    -------
    ContinuationCurve

    Raises
    ------
    ParameterError
        For a keyword that is not an option, ``options`` not a ContinuationOptions, a bad
        window, a start outside it, non-positive step settings, a bad direction or
        callables returning wrong shapes.
    ContinuationError
        When the start cannot be corrected onto the curve.
    """
    options = checks.options_with(
        ContinuationOptions, options, keywords, "continue_curve", _OPTION_NAMES
    )
    return _trace(residual, jacobian, u0, lam0, window, options)


def _trace(
    residual: Residual,
    jacobian: Jacobian,
    u0: ArrayLike,
    lam0: float,
    window: Sequence[float],
    o: ContinuationOptions,
) -> ContinuationCurve:
    """The loop of :func:`continue_curve` with its options resolved."""
    lo, hi = check_window(window)
    lam0 = float(lam0)
    if not (lo <= lam0 <= hi):
        raise ParameterError(f"lam0 = {lam0!r} lies outside the window ({lo}, {hi})")
    direction = o.direction
    if direction not in (1, -1):
        raise ParameterError(f"direction = {direction!r}: expected 1 or -1")
    u = np.array(u0, dtype=float).reshape(-1)
    if u.size == 0 or not np.all(np.isfinite(u)):
        raise ParameterError("u0: expected a non-empty vector of finite numbers")
    n = u.size
    su_base = np.array(np.broadcast_to(np.asarray(o.u_scale, dtype=float), (n,)))
    if not np.all(np.isfinite(su_base) & (su_base > 0)):
        raise ParameterError(f"u_scale = {o.u_scale!r}: expected positive finite numbers")
    sl = positive("lam_scale", hi - lo if o.lam_scale is None else o.lam_scale)
    ds_max = positive("ds_max", o.ds_max)
    ds_min = positive("ds_min", 1e-6 * ds_max if o.ds_min is None else o.ds_min)
    first = min(ds_max, positive("ds", ds_max / 4 if o.ds is None else o.ds))
    growth = positive("growth", o.growth)
    tol = positive("tol", o.tol)
    max_points = o.max_points
    if int(max_points) < 1:
        raise ParameterError(f"max_points = {max_points!r}: expected at least 1")
    predictor = o.predictor
    if predictor not in ("tangent", "hermite"):
        raise ParameterError(f"predictor = {predictor!r}: expected 'tangent' or 'hermite'")
    adaptive_scale, callback, early_accept = o.adaptive_scale, o.callback, o.early_accept

    fun = CountedProblem(residual, jacobian, n)
    ctl = StepControl.growing(first, ds_min, ds_max, growth)

    def scale_for(v: np.ndarray) -> np.ndarray:
        return np.maximum(su_base, float(np.max(np.abs(v)))) if adaptive_scale else su_base

    su = scale_for(u)
    tr = BorderedCorrector(fun, su, sl, tol, int(o.max_newton))
    iters0 = 0
    if o.correct_start:
        u, iters0 = newton_fixed(fun.residual, fun.jacobian, u, lam0, u_scale=su, tol=tol)
        tr.su = su = scale_for(u)
    ju, jl = fun.jacobian(u, lam0)
    t = start_tangent(ju, jl, su, sl, direction)
    w = tr.scaled(u, lam0)

    # history in plain coordinates; (w, t) of the last point and of the previous one in the
    # current scaling
    us, lams, ts, its = [u], [lam0], [t], [iters0]
    jacs = [ju] if o.store_jacobians else None
    extras = [callback(u, lam0, ju, jl)] if callback is not None else None
    folds = FoldTest(o.refine_folds)
    # the sign of the augmented determinant at the last accepted point (None: not watched)
    bps = BranchPointTest(tr, ju, jl, t) if o.detect_branch_points else None
    cos_turn = math.cos(float(o.max_turn))
    stop = "max_points"
    travelled = 0.0
    start_u, start_lam, start_t = u, lam0, t

    def accept(c: Corrected, t_new: np.ndarray) -> None:
        u_new, lam_new = tr.unscaled(c.w)
        us.append(u_new)
        lams.append(lam_new)
        ts.append(t_new)
        its.append(c.iterations)
        if jacs is not None:
            jacs.append(c.ju)
        if extras is not None:
            extras.append(callback(u_new, lam_new, c.ju, c.jl))

    # the point before the last one in the current scaling (Hermite predictor) and the
    # quadratic-convergence ratios measured recently, as (point count, ratio)
    prev_wt: tuple[np.ndarray, np.ndarray] | None = None
    ratios: list[tuple[int, float]] = []
    while len(us) < int(max_points):
        step = ctl.step
        w_pred = None
        if predictor == "hermite" and prev_wt is not None:
            w_pred = hermite_extrapolate(prev_wt[0], prev_wt[1], w, t, step)
        if w_pred is None or not np.all(np.isfinite(w_pred)):
            w_pred = w + step * t
        contraction = None
        if early_accept:
            recent = [r for k, r in ratios if k >= len(us) - 8]
            contraction = 4.0 * max(recent) if recent else None
        c = tr.correct(w_pred, t, float(t @ w_pred), contraction)
        if tr.last_ratio is not None and c is not None:
            ratios.append((len(us), tr.last_ratio))
            del ratios[:-16]
        t_new = None if c is None else tr.tangent(c, t)
        if c is None or t_new is None or float(t_new @ t) < cos_turn:
            if not ctl.failed():
                stop = "step_underflow"
                break
            continue
        lam_new = c.w[n] * sl
        if lam_new < lo or lam_new > hi:
            edge = lo if lam_new < lo else hi
            frac = (edge / sl - w[n]) / (c.w[n] - w[n])
            e_row = np.zeros(n + 1)
            e_row[n] = 1.0
            ce = tr.correct(w + frac * (c.w - w), e_row, edge / sl)
            te = None if ce is None else tr.tangent(ce, t)
            if ce is not None and te is not None:
                # accept first: the callback runs while the caller's cache holds the point
                accept(ce, te)
                folds.check(tr, len(us) - 2, w, t, ce.w, te)
                if bps is not None:
                    bps.check(tr, len(us) - 2, w, t, ce, te)
            stop = "window"
            break
        accept(c, t_new)
        folds.check(tr, len(us) - 2, w, t, c.w, t_new, float(t @ (c.w - w)))
        if bps is not None:
            bps.check(tr, len(us) - 2, w, t, c, t_new)
        prev_wt = (w, t)
        w, t = c.w, t_new
        travelled += step
        # a closed curve: back at the start, moving the way it started
        gap = np.append((us[-1] - start_u) / tr.su, (lams[-1] - start_lam) / sl)
        if (
            len(us) > 3
            and travelled > 4 * step
            and float(np.max(np.abs(gap))) < 0.5 * step
            and float(t[n] * start_t[n]) > 0
        ):
            stop = "closed"
            break
        ctl.accepted(c.iterations)
        if adaptive_scale:
            new_su = scale_for(us[-1])
            ratio = float(new_su[0] / tr.su[0])
            if ratio > 1.25 or ratio < 0.8:
                # the same point and direction in the new coordinates
                t = np.append(t[:n] * tr.su / new_su, t[n])
                t /= np.linalg.norm(t)
                if prev_wt is not None:
                    tp = np.append(prev_wt[1][:n] * tr.su / new_su, prev_wt[1][n])
                    prev_wt = (np.append(us[-2] / new_su, lams[-2] / sl), tp / np.linalg.norm(tp))
                tr.su = new_su
                w = tr.scaled(us[-1], lams[-1])

    return ContinuationCurve(
        u=np.array(us),
        lam=np.array(lams),
        tangents=np.array(ts),
        iterations=np.array(its, dtype=int),
        jacobians=None if jacs is None else np.array(jacs),
        folds=tuple(folds.found),
        stop_reason=stop,
        residual_evaluations=fun.residuals,
        jacobian_evaluations=fun.jacobians,
        u_scale=tr.su,
        lam_scale=sl,
        callback_values=None if extras is None else tuple(extras),
        branch_points=tuple(bps.found) if bps is not None else (),
    )
