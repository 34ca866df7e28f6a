r"""Root finders shared by the package: one regula falsi, one damped Newton.

Two algorithms were written several times over (continuation, shooting, the orbit search,
the grid kernels), each copy with its own caps and stopping rules.  This module holds one
implementation of each; callers choose the stopping rules through arguments, not copies.

Regula falsi, Illinois variant (:func:`illinois`, :func:`illinois_vectorized`)
    For a sign change of :math:`f` on :math:`[a, b]`.  Every iterate is the secant point of the
    current bracket (the midpoint if rounding puts it outside), so it never leaves the
    bracket.  Plain regula falsi keeps one end fixed for ever on a convex function and
    converges only linearly (the bracket does not shrink to zero); the Illinois rule halves the
    stored function value of an end that is kept twice in a row, which restores superlinear
    convergence (order :math:`\approx 1.44`).  Capped by ``max_iter`` evaluations.  Options
    for the continuation's event location: a bisection safeguard (``bisect``: a function that
    varies by orders of magnitude in the bracket), trials beside an iterate where ``f``
    cannot be evaluated (``retry``), the form of the secant point and where the bracket test
    applies (``secant``, ``final_iterate``: each caller keeps the rounding of its results).

Damped Newton (:func:`damped_newton`)
    Newton / Gauss-Newton on :math:`r(z) = 0` with a step cap, backtracking (halving) until the
    Armijo condition :math:`\phi(z + \alpha\Delta z) \le (1 - c\,\alpha)\,\phi(z)` holds
    (:math:`\phi = \|r\|_2` unless a merit function is given), convergence on the residual
    (:math:`\|r\|_\infty \le \text{tol}\cdot\text{scale}`) or on the step, and caps on the
    iterations and on the halvings per iteration.  Failures are reported in the result
    (``status``), never raised, so each caller keeps its own error type and message.  The
    tuning knobs (tolerances, caps, halvings, ...) are the fields of :class:`NewtonOptions`,
    passed as ``options=`` or as keywords of the same names.

This module belongs to the numeric layer: it imports only numpy, scipy and
:mod:`perturb.errors`.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from perturb import checks
from perturb.errors import ParameterError

__all__ = [
    "RootResult",
    "VectorRootResult",
    "NewtonResult",
    "NewtonOptions",
    "illinois",
    "illinois_vectorized",
    "damped_newton",
    "newton_direction",
    "lu_or_lstsq",
]

_EPS = float(np.finfo(float).eps)


# ---------------------------------------------------------------------------------------------
# regula falsi (Illinois)
# ---------------------------------------------------------------------------------------------
@dataclass
class RootResult:
    """Outcome of :func:`illinois`.

    Attributes
    ----------
    root : float
        The iterate with the smallest ``|f|`` (an end of the initial bracket when no
        iterate was evaluated or none beat the ends and ``include_ends`` was set; NaN when
        nothing qualifies).
    value : float
        ``f(root)``.
    converged : bool
        True when the bracket shrank below ``xtol``, ``|f| <= ftol`` was met, or ``f`` was
        exactly 0; False when the iteration cap was hit or ``f`` failed (returned None).
    iterations : int
        Evaluations of ``f`` made (those of ``retry`` included).
    bracket : tuple of float
        The final bracket ``(lo, hi)``.
    payload : object
        What ``f`` returned alongside the value at ``root`` (see :func:`illinois`), or None.
    failed : bool
        True when ``f`` returned None (the iteration stopped there).
    """

    root: float
    value: float
    converged: bool
    iterations: int
    bracket: tuple[float, float]
    payload: Any = None
    failed: bool = False


def _split(out: Any) -> tuple[float | None, Any]:
    if out is None:
        return None, None
    if isinstance(out, tuple):
        return float(out[0]), out[1]
    return float(out), None


def illinois(
    f: Callable[[float], Any],
    a: float,
    b: float,
    fa: float | None = None,
    fb: float | None = None,
    *,
    xtol: float | None = None,
    ftol: float = 0.0,
    max_iter: int = 100,
    include_ends: bool = True,
    bisect: bool = False,
    secant: str = "shift",
    final_iterate: bool = False,
    retry: float | None = None,
) -> RootResult:
    """Root of ``f`` in the bracket ``[a, b]`` by regula falsi with the Illinois modification.

    Parameters
    ----------
    f : callable
        ``f(x)`` returns the value (a float), or a tuple ``(value, payload)`` where
        ``payload`` is any object kept for the best iterate (e.g. a corrected continuation
        point), or None when it cannot be evaluated at ``x`` (the iteration stops there and
        the best iterate so far is returned, ``failed=True``).
    a, b : float
        The bracket, ``a < b``.
    fa, fb : float, optional
        ``f(a)`` and ``f(b)`` when already known (otherwise evaluated, without payload);
        they must have opposite signs (or one be 0).
    xtol : float, optional
        Stop when the bracket is narrower than this (default ``4 eps max(|a|, |b|)``, the
        resolution of double precision).
    ftol : float
        Stop when ``|f(x)| <= ftol`` (default 0: only an exact zero).
    max_iter : int
        Cap on the iterates, i.e. on the evaluations of ``f`` apart from the ``retry``
        evaluations (the loop always terminates).
    include_ends : bool
        Whether the ends ``a``, ``b`` compete with the iterates for ``root`` (with payload
        None).  When False and no iterate was evaluated, ``root`` is NaN.
    bisect : bool
        Bisection safeguard: the iterate is the midpoint of the bracket instead of its secant
        point whenever the last two iterates did not halve the bracket (so the first iterate
        is the midpoint).  Regula falsi creeps from one end, even with the Illinois rule, when
        ``f`` varies by orders of magnitude inside the bracket (a determinant); the safeguard
        keeps the worst case at bisection's (the width halves at least every other
        iterate).  Default False: the plain Illinois iteration.
    secant : {"shift", "mean"}
        How the secant point of the bracket ``[a, b]`` is written: ``"shift"``,
        ``b - f_b (b - a) / (f_b - f_a)``, or ``"mean"``, ``(a f_b - b f_a) / (f_b - f_a)``.
        The same point in exact arithmetic, rounded differently: callers keep the form their
        results were recorded with.
    final_iterate : bool
        Apply the ``xtol`` test (as ``width <= xtol``) to the bracket an iterate was taken
        from, before that iterate updates it: the iteration then ends with one iterate taken
        inside a bracket already narrower than ``xtol``, whose sign is not used.  Default
        False: the test is ``width < xtol`` on the updated bracket.
    retry : float, optional
        When ``f`` fails (returns None) at an iterate ``x``, evaluate it at
        ``x -+ retry * width`` instead (those inside the bracket) and update the bracket with
        each that succeeds, in that order; the iteration stops (``failed``) only when neither
        does.  For a root where ``f`` cannot be evaluated at all (a corrector whose matrix is
        singular at the root itself), which two points beside it bracket tightly.  Default
        None: a failure stops the iteration.

    Returns
    -------
    RootResult
        See :class:`RootResult`.

    Raises
    ------
    ParameterError
        When ``a >= b``, a bound is not finite, or ``f(a)``, ``f(b)`` have the same sign.
    """
    a, b = float(a), float(b)
    if not (math.isfinite(a) and math.isfinite(b) and a < b):
        raise ParameterError(f"illinois: expected finite a < b, got a = {a!r}, b = {b!r}")
    if max_iter < 0:
        raise ParameterError(f"illinois: max_iter = {max_iter!r} must be >= 0")
    fa = float(fa) if fa is not None else _split(f(a))[0]
    fb = float(fb) if fb is not None else _split(f(b))[0]
    if fa is None or fb is None or not (math.isfinite(fa) and math.isfinite(fb)):
        raise ParameterError(f"illinois: f is not finite at the bracket ends ({fa}, {fb})")
    if fa * fb > 0.0:
        raise ParameterError(f"illinois: f(a) = {fa:g} and f(b) = {fb:g} have the same sign")
    if secant not in ("shift", "mean"):
        raise ParameterError(f"illinois: secant = {secant!r}: expected 'shift' or 'mean'")
    if xtol is None:
        xtol = 4.0 * _EPS * max(abs(a), abs(b))
    if include_ends:
        best, fbest = (a, fa) if abs(fa) < abs(fb) else (b, fb)
    else:
        best, fbest = math.nan, math.inf
    payload = None
    if fa == 0.0 or fb == 0.0:
        return RootResult(best, fbest, True, 0, (a, b))
    sa, sb = a, b
    side = 0
    it = evaluations = 0
    converged = failed = False
    # bracket widths before the last two iterates (bisection safeguard)
    widths = [b - a, b - a]
    while it < max_iter:
        width = sb - sa
        if bisect and width > 0.5 * widths[-2]:
            s = 0.5 * (sa + sb)
        elif fb == fa:
            s = 0.5 * (sa + sb)
        else:
            # secant point of the current bracket ("shift": written as in the exact
            # continuation, whose results this reproduces bit for bit); the midpoint when
            # rounding puts it outside
            s = (
                sb - fb * (sb - sa) / (fb - fa)
                if secant == "shift"
                else (sa * fb - sb * fa) / (fb - fa)
            )
            if not sa < s < sb:
                s = 0.5 * (sa + sb)
        widths.append(width)
        fq, pq = _split(f(s))
        it += 1
        evaluations += 1
        if fq is not None:
            points = [(s, fq, pq)]
        elif retry is None:
            failed = True
            break
        else:
            # two points just beside the one that failed, inside the bracket
            points = []
            for x in (s - retry * width, s + retry * width):
                if sa < x < sb:
                    fx, px = _split(f(x))
                    evaluations += 1
                    if fx is not None:
                        points.append((x, fx, px))
            if not points:
                failed = True
                break
        for s, fq, pq in points:
            if abs(fq) < abs(fbest):
                best, fbest, payload = s, fq, pq
            if fq == 0.0 or abs(fq) <= ftol or (final_iterate and width <= xtol):
                converged = True
                break
            if fq * fa > 0:
                sa, fa = s, fq
                if side == -1:
                    fb *= 0.5  # b kept twice: Illinois halving
                side = -1
            else:
                sb, fb = s, fq
                if side == 1:
                    fa *= 0.5
                side = 1
        if converged:
            break
        if not final_iterate and sb - sa < xtol:
            converged = True
            break
    return RootResult(best, fbest, converged, evaluations, (sa, sb), payload, failed)


@dataclass
class VectorRootResult:
    """Outcome of :func:`illinois_vectorized`: ``root`` (the end of each final bracket with
    the smaller stored ``|f|``), ``converged`` (per bracket) and ``iterations`` (sweeps)."""

    root: np.ndarray
    converged: np.ndarray
    iterations: int


def illinois_vectorized(
    f: Callable[[np.ndarray], np.ndarray],
    a: np.ndarray,
    b: np.ndarray,
    fa: np.ndarray,
    fb: np.ndarray | None = None,
    *,
    max_iter: int = 60,
) -> VectorRootResult:
    """Roots of a vectorised ``f`` in many brackets ``[a_i, b_i]`` at once (Illinois).

    One call ``f(c)`` per sweep evaluates all brackets.  A bracket stops changing in effect
    once it is at double-precision resolution (``|b - a| <= 4 eps |b|``) or ``f`` is exactly 0
    there; the sweeps stop when all have, or after ``max_iter`` sweeps.

    Parameters
    ----------
    f : callable
        ``f(x)`` for an array ``x``, elementwise.
    a, b : ndarray
        Bracket ends (either order); ``fa = f(a)`` and ``fb = f(b)`` (evaluated when None)
        of opposite signs.
    max_iter : int
        Cap on the sweeps.

    Returns
    -------
    VectorRootResult
    """
    a = np.array(a, dtype=float)
    b = np.array(b, dtype=float)
    fa = np.array(fa, dtype=float)
    fb = f(b) if fb is None else np.array(fb, dtype=float)
    side = np.zeros(a.size, int)
    done = np.zeros(a.size, bool)
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007 (the count is reported)
        with np.errstate(all="ignore"):
            c = np.where(fb != fa, (a * fb - b * fa) / (fb - fa), 0.5 * (a + b))
        bad = ~((c > np.minimum(a, b)) & (c < np.maximum(a, b)))
        c = np.where(bad, 0.5 * (a + b), c)
        fc = f(c)
        same = np.sign(fc) == np.sign(fa)
        # replace the end of the same sign; halve the kept end's value when it is kept twice
        a_new = np.where(same, c, a)
        fa_new = np.where(same, fc, np.where(side == -1, 0.5 * fa, fa))
        b_new = np.where(same, b, c)
        fb_new = np.where(same, np.where(side == 1, 0.5 * fb, fb), fc)
        side = np.where(same, 1, -1)
        a, fa, b, fb = a_new, fa_new, b_new, fb_new
        done = (np.abs(b - a) <= 4 * _EPS * np.abs(b)) | (fc == 0)
        if np.all(done):
            break
    return VectorRootResult(np.where(np.abs(fa) <= np.abs(fb), a, b), done, it)


# ---------------------------------------------------------------------------------------------
# damped Newton
# ---------------------------------------------------------------------------------------------
@dataclass
class NewtonResult:
    """Outcome of :func:`damped_newton`.

    Attributes
    ----------
    z : ndarray
        The solution (``z_evaluated + step`` when the final correction was taken, see
        ``take_final_step``), or the last iterate on failure.
    converged : bool
        Whether ``status`` is ``"residual"``, ``"step"`` or ``"floor"``.
    status : str
        ``"residual"`` (residual test met), ``"step"`` (correction test met), ``"floor"``
        (no decrease but a correction below ``floor_step_tol``), or a failure:
        ``"initial_error"`` (``fun`` raised at ``z0``; see ``error``), ``"initial_nonfinite"``,
        ``"singular"`` (non-finite Newton direction), ``"no_decrease"`` (the line search ran
        out of halvings), ``"max_iter"``.
    iterations : int
        Newton steps taken (accepted iterates after ``z0``).
    rnorm : float
        ``max |r|`` at ``z_evaluated``.
    r, data : ndarray, object
        Residual and the ``data`` returned by ``fun`` at ``z_evaluated``.
    z_evaluated : ndarray
        The last point where ``fun`` was evaluated and accepted.
    step : ndarray or None
        The last Newton correction computed at ``z_evaluated`` (None if none was).
    evaluations : int
        Calls of ``fun`` (residual evaluations).
    error : BaseException or None
        The exception raised by ``fun`` at ``z0`` (status ``"initial_error"``).
    """

    z: np.ndarray
    converged: bool
    status: str
    iterations: int
    rnorm: float
    r: np.ndarray
    data: Any = None
    z_evaluated: np.ndarray = field(default=None)  # type: ignore[assignment]
    step: np.ndarray | None = None
    evaluations: int = 0
    error: BaseException | None = None


def newton_direction(J: Any, rhs: np.ndarray) -> np.ndarray:
    """Solve ``J d = rhs`` for a Newton direction: sparse LU, dense LU, or least squares.

    Sparse ``J``: SuperLU (an exactly singular matrix falls back to the dense path).  A
    2x2 ``J`` is solved by Cramer's rule when its exact condition number (singular values from
    ``s1 s2 = |det|``, ``s1^2 + s2^2 = |J|_F^2``) is below 1e14: a fraction of LAPACK's call
    overhead, which dominates single shooting.  Square and well conditioned (cond < 1e14):
    LU; otherwise (non-square, singular, ill conditioned) the minimum-norm least-squares
    solution (Gauss-Newton).
    """
    # scipy.sparse is imported only where a sparse J can exist (whoever built one imported
    # it): a dense caller's process does not pay its import (~0.1 s of CPU)
    sps = sys.modules.get("scipy.sparse")
    if sps is not None and sps.issparse(J):
        import scipy.sparse.linalg as spla

        try:
            with np.errstate(all="ignore"):
                return spla.splu(sps.csc_matrix(J)).solve(rhs)
        except RuntimeError:  # exactly singular: minimum-norm direction from the dense matrix
            J = J.toarray()
    J = np.asarray(J, dtype=float)
    if J.shape == (2, 2):
        a, b, c, d = (float(z) for z in J.ravel())
        det = a * d - b * c
        fro2 = a * a + b * b + c * c + d * d
        s1 = math.sqrt(0.5 * (fro2 + math.sqrt(max(fro2 * fro2 - 4.0 * det * det, 0.0))))
        if det != 0.0 and math.isfinite(s1) and s1 * s1 < 1e14 * abs(det):
            r0, r1 = float(rhs[0]), float(rhs[1])
            return np.array([(d * r0 - b * r1) / det, (a * r1 - c * r0) / det])
    if J.shape[0] == J.shape[1]:
        try:
            if np.linalg.cond(J) < 1e14:
                return np.linalg.solve(J, rhs)
        except np.linalg.LinAlgError:
            pass
    return np.linalg.lstsq(J, rhs, rcond=None)[0]


def lu_or_lstsq(J: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve a dense square ``J d = rhs``: LU, or the minimum-norm least-squares solution
    when LAPACK finds ``J`` exactly singular.  Unlike :func:`newton_direction` no condition
    estimate (an ill-conditioned ``J`` gets its LU solution): the direction of the
    continuation's Newton at fixed parameter, whose Jacobians are regular off folds."""
    try:
        return np.linalg.solve(J, rhs)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(J, rhs, rcond=None)[0]


def _norm2(z: np.ndarray, r: np.ndarray) -> float:
    return float(np.linalg.norm(r))


@dataclass(frozen=True)
class NewtonOptions:
    r"""Tuning knobs of :func:`damped_newton` (its stopping rules, caps and damping).

    :func:`damped_newton` takes them as ``options=`` and also as keyword arguments of the
    same names, which replace the fields of ``options`` (so ``damped_newton(f, z0, tol=1e-12)``
    and ``damped_newton(f, z0, options=NewtonOptions(tol=1e-12))`` are the same call); any
    other keyword is a :class:`~perturb.errors.ParameterError` naming it.  The defaults are
    those of :func:`damped_newton` before the options object existed.

    Attributes
    ----------
    tol : float
        Residual tolerance relative to ``scale`` (0: only an exact zero).
    max_iter : int
        Cap on Newton steps (>= 0).
    scale : float, array or callable
        ``s(z)``: the scale of the tolerances and of the step cap (e.g. ``max(1, |z|)``).
        An array (or a callable returning one), shaped like ``z``, is a scale per unknown:
        the correction is then measured componentwise, :math:`\max_i |d_i| / s_i`, in the
        step test, the step cap and the floor test, and the residual test is
        :math:`\|r\|_\infty \le \text{tol}` (the residual has units of its own, not those
        of ``z``).
    step_tol, step_residual_tol : float
        Correction test (step 3 of :func:`damped_newton`; ``step_tol = 0`` disables it).
    take_final_step : bool
        Whether a correction-test solution includes the final correction.
    floor_step_tol : float, optional
        Accept a negligible correction when the line search fails (the residual floor of a
        problem whose residual cannot decrease below rounding); None: never.
    max_step : float, optional
        Step cap relative to ``s(z)`` (None: uncapped).
    max_halvings : int
        Cap on step halvings per iteration (>= 0).
    decrease : float
        Armijo constant ``c``.
    """

    tol: float = 0.0
    max_iter: int = 50
    scale: float | Callable[[np.ndarray], float] = 1.0
    step_tol: float = 0.0
    step_residual_tol: float = math.inf
    take_final_step: bool = False
    floor_step_tol: float | None = None
    max_step: float | None = None
    max_halvings: int = 12
    decrease: float = 1e-4


_NEWTON_FIELDS = frozenset(NewtonOptions.__dataclass_fields__)
_DEFAULT_NEWTON = NewtonOptions()


def _newton_options(options: NewtonOptions | None, knobs: dict[str, Any]) -> NewtonOptions:
    return checks.options_with(
        NewtonOptions,
        options,
        knobs,
        "damped_newton",
        _NEWTON_FIELDS,
        default=_DEFAULT_NEWTON,
        hint=" (fields of NewtonOptions) or jac, options, merit, modify_step, admissible, "
        "bounds, solve, catch",
    )


def damped_newton(
    fun: Callable[[np.ndarray], Any],
    z0: np.ndarray,
    *,
    jac: Callable[[np.ndarray], Any] | None = None,
    options: NewtonOptions | None = None,
    merit: Callable[[np.ndarray, np.ndarray], float] | None = None,
    modify_step: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    admissible: Callable[[np.ndarray], bool] | None = None,
    bounds: tuple[Any, Any] | None = None,
    solve: Callable[[Any, np.ndarray], np.ndarray] = newton_direction,
    catch: tuple[type[BaseException], ...] = (),
    **knobs: Any,
) -> NewtonResult:
    r"""Damped (safeguarded) Newton / Gauss-Newton for ``r(z) = 0``.

    Each iteration at the current ``z`` (residual ``r``, Jacobian ``J``), with the fields
    ``tol``, ``max_iter``, ... of :class:`NewtonOptions`:

    1. converged (``"residual"``) if :math:`\|r\|_\infty \le \text{tol}\cdot s(z)`;
       stop (``"max_iter"``) after ``max_iter`` steps;
    2. direction ``d = solve(J, -r)`` (non-finite: ``"singular"``);
    3. converged (``"step"``) if :math:`\|d\|_\infty \le \text{step\_tol}\cdot s(z)` and
       :math:`\|r\|_\infty \le \text{step\_residual\_tol}\cdot s(z)`; the solution is ``z``,
       or ``z + d`` with ``take_final_step``;
    4. ``d = modify_step(z, d)`` (e.g. deflation), then cut to
       :math:`\|d\|_\infty \le \text{max\_step}\cdot s(z)`;
    5. line search: ``alpha = 1, 1/2, ..., 2**-max_halvings``; a trial ``z + alpha d`` is
       accepted when it is admissible (``admissible``, ``bounds``), ``fun`` does not raise one
       of ``catch``, ``r`` is finite and ``merit <= (1 - decrease alpha) merit(z)``.  None
       accepted: converged (``"floor"``, solution ``z + d``) when
       :math:`\|d\|_\infty \le \text{floor\_step\_tol}\cdot s(z)`, else ``"no_decrease"``.

    Parameters
    ----------
    fun : callable
        Without ``jac``: ``fun(z) -> (r, J, data)`` (residual, Jacobian — dense, sparse or
        anything ``solve`` takes — and any data the caller wants back at the solution).  With
        ``jac``: ``fun(z) -> r`` and ``jac(z) -> J``, the Jacobian then being evaluated only at
        accepted iterates (``data`` is None).
    z0 : ndarray
        Initial guess.
    jac : callable, optional
        Separate Jacobian (see ``fun``).
    options : NewtonOptions, optional
        The tuning knobs (default ``NewtonOptions()``): tolerances, caps, step cap,
        halvings, Armijo constant.
    **knobs
        Fields of :class:`NewtonOptions` (``tol``, ``max_iter``, ``scale``, ``step_tol``,
        ``step_residual_tol``, ``take_final_step``, ``floor_step_tol``, ``max_step``,
        ``max_halvings``, ``decrease``) as keywords, replacing those of ``options``.
    merit : callable, optional
        ``merit(z, r)`` of the line search (default :math:`\|r\|_2`).
    modify_step : callable, optional
        ``modify_step(z, d) -> d`` applied after the correction test.
    admissible : callable, optional
        ``admissible(z) -> bool``: trials outside the domain count as rejected.
    bounds : (lower, upper), optional
        Elementwise bounds (scalars or arrays, ``None`` for no bound); trials outside are
        rejected (as by ``admissible``), so every iterate stays within them.
    solve : callable
        ``solve(J, rhs)`` for the direction (default :func:`newton_direction`); a
        ``numpy.linalg.LinAlgError`` it raises means ``"singular"``.
    catch : tuple of exception types
        Exceptions of ``fun`` (or ``jac``) that mark a trial as rejected (at ``z0``: status
        ``"initial_error"``).  Others propagate.

    Returns
    -------
    NewtonResult
        Never raises for a failure of the iteration; see ``status``.

    Raises
    ------
    ParameterError
        An unknown keyword, ``options`` not a :class:`NewtonOptions`, or a negative
        ``max_iter`` / ``max_halvings``.
    """
    o = _newton_options(options, knobs)
    tol, max_iter, scale, max_halvings = o.tol, o.max_iter, o.scale, o.max_halvings
    step_tol, step_residual_tol, take_final_step = (
        o.step_tol,
        o.step_residual_tol,
        o.take_final_step,
    )
    floor_step_tol, max_step, decrease = o.floor_step_tol, o.max_step, o.decrease
    if max_iter < 0 or max_halvings < 0:
        raise ParameterError(
            f"damped_newton: max_iter = {max_iter!r} and max_halvings = {max_halvings!r} "
            "must be >= 0"
        )
    if callable(scale):
        s_of = scale
    else:
        fixed = float(scale) if np.ndim(scale) == 0 else np.array(scale, dtype=float)

        def s_of(z: np.ndarray, _s: Any = fixed) -> Any:
            return _s

    merit_of = merit if merit is not None else _norm2
    lower, upper = bounds if bounds is not None else (None, None)

    def inside(zt: np.ndarray) -> bool:
        if admissible is not None and not admissible(zt):
            return False
        if lower is not None and not np.all(zt >= lower):
            return False
        return upper is None or bool(np.all(zt <= upper))

    def evaluate(zt: np.ndarray) -> tuple[np.ndarray, Any, Any]:
        if jac is None:
            return fun(zt)
        return fun(zt), None, None

    z = z0
    evaluations = 1
    try:
        r, J, data = evaluate(z0)
        if jac is not None:
            J = jac(z0)
    except catch as exc:
        return NewtonResult(z0, False, "initial_error", 0, math.inf, None, None, z0, None, 1, exc)
    if not np.all(np.isfinite(r)):
        return NewtonResult(z0, False, "initial_nonfinite", 0, math.inf, r, data, z0, None, 1)

    def result(zs, converged, status, it, rn, step=None) -> NewtonResult:
        return NewtonResult(zs, converged, status, it, rn, r, data, z, step, evaluations)

    rn = math.inf
    for it in range(max_iter + 1):
        rn = float(np.max(np.abs(r)))
        s = s_of(z)
        # a scale per unknown: corrections are measured in it, the residual in its own units
        per_unknown = np.ndim(s) != 0
        if per_unknown:
            s_z, s = s, 1.0
        if rn <= tol * s:
            return result(z, True, "residual", it, rn)
        if it == max_iter:
            break
        try:
            dz = solve(J, -r)
        except np.linalg.LinAlgError:
            return result(z, False, "singular", it, rn)
        if not np.all(np.isfinite(dz)):
            return result(z, False, "singular", it, rn)
        dn = float(np.max(np.abs(dz / s_z))) if per_unknown else float(np.max(np.abs(dz)))
        if dn <= step_tol * s and rn <= step_residual_tol * s:
            return result(z + dz if take_final_step else z, True, "step", it, rn, dz)
        if modify_step is not None:
            dz = modify_step(z, dz)
        if max_step is not None:
            cap = max_step * s
            if dn > cap:
                dz = dz * (cap / dn)
        phi0 = merit_of(z, r)
        alpha = 1.0
        accepted = False
        for _ in range(max_halvings + 1):
            zt = z + alpha * dz
            if inside(zt):
                try:
                    evaluations += 1
                    rt, Jt, dt = evaluate(zt)
                    if bool(np.all(np.isfinite(rt))):
                        accepted = merit_of(zt, rt) <= (1.0 - decrease * alpha) * phi0
                except catch:
                    accepted = False  # the trial left the domain of fun: shorten the step
            if accepted:
                break
            alpha *= 0.5
        if not accepted:
            if floor_step_tol is not None and dn <= floor_step_tol * s:
                return result(z + dz, True, "floor", it, rn, dz)
            return result(z, False, "no_decrease", it, rn, dz)
        if jac is not None:
            try:
                Jt = jac(zt)
            except catch:
                return result(z, False, "singular", it, rn, dz)
        z, r, J, data = zt, rt, Jt, dt
    return result(z, False, "max_iter", max_iter, rn)
