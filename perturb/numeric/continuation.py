r"""Pseudo-arclength continuation of a solution curve of :math:`F(u, \lambda) = 0`.

A generic core: the caller supplies the residual :math:`F: \mathbb{R}^n \times \mathbb{R} \to
\mathbb{R}^n` and its Jacobian :math:`(F_u, F_\lambda)`; nothing here knows what the unknowns
mean (harmonic-balance coefficients, amplitude–phase unknowns of a symbolic method, shooting
states). :func:`continue_curve` traces the curve from a starting point through a window of
:math:`\lambda`, passing folds.

Coordinates
-----------
All steps, tangents and tolerances live in scaled coordinates :math:`\hat u = u / s_u`,
:math:`\hat\lambda = \lambda / s_\lambda` (``u_scale``, ``lam_scale``), so one arclength unit
means "the size of the solution" and "the width of the window" alike; without that, a
curve whose unknowns are of size 40 and whose parameter moves by 1 would be stepped almost
only by its unknowns. With ``adaptive_scale`` the scale of the unknowns follows the solution
(:math:`\max(s_u, \|u\|_\infty)`, re-set when it changes by more than 25 %, the current point
and tangent carried over), so the steps stay relative across a resonance peak.

Algorithm
---------
*Tangent*: the unit null vector :math:`t` of :math:`[F_u s_u \mid F_\lambda s_\lambda]`,
from the bordered system :math:`\begin{pmatrix}F_u s_u & F_\lambda s_\lambda\\ t_{prev}^T &
0\end{pmatrix} z = e_{n+1}`, which also orients it along the previous tangent (so a fold is
passed, not turned back from). At the start, :math:`F_u z = -F_\lambda` (SVD null vector if
:math:`F_u` is singular), oriented by ``direction``. The Jacobian used is the one of the last
Newton iterate of the point's correction, which differs from the point by the last (accepted
as negligible) correction: no extra evaluation per point.

*Predictor*: :math:`\hat w_{pred} = \hat w_i + \Delta s\, t_i`, or with ``predictor="hermite"``
the cubic Hermite arc through the last two points and their tangents, extrapolated by
:math:`\Delta s` (error :math:`O(h^2 \Delta s^2)` for points :math:`h` apart, against
:math:`O(\Delta s^2)`); the corrector then works on the hyperplane through the predicted point
orthogonal to :math:`t_i`. With ``early_accept`` a point whose first correction is small
enough, by the quadratic-convergence constant measured on recent points, is accepted after
that one correction: about one evaluation per point on a smooth curve.

*Corrector*: Newton on :math:`F(w) = 0,\ t_i\cdot(\hat w - \hat w_{pred}) = 0` (bordered
system): every correction is orthogonal to the tangent, so the corrector moves across the
curve, not along it, and works at folds where :math:`F_u` is singular. Converged when the
scaled correction is at most ``tol``, or from the second iteration on when the *next*
correction, estimated from quadratic convergence as :math:`|\Delta_k|^2/|\Delta_{k-1}|`, is
(the corrected iterate is then accepted without evaluating it); abandoned after
``max_newton`` iterations or when a correction does not at least halve.

*Step control*: a step whose corrector failed, or whose tangent turned by more than
``max_turn`` radians, is redone with half the step (a large turn means the predictor may have
jumped to a neighbouring part of the curve). After an accepted step the step grows by
``growth`` when the corrector needed at most two iterations, shrinks by 0.7 when it needed
more than three, and stays within ``[ds_min, ds_max]``.

*Folds*: the :math:`\lambda`-component of the tangent changes sign between consecutive
points. With ``refine_folds`` the fold is located by regula falsi (Illinois) on that
component as a function of the arclength from the point before it, each trial a full
correction, so the reported point lies on the curve and its :math:`\lambda` (stationary there)
is accurate to about the square of the arclength error.

*Branch points* (``detect_branch_points``): the determinant of the augmented Jacobian
:math:`\det\begin{pmatrix}F_u s_u & F_\lambda s_\lambda\\ t^T & 0\end{pmatrix}` is the test
function. It vanishes where the curve meets another one (the null space of :math:`[F_u \mid
F_\lambda]` becomes two-dimensional) and changes sign at a simple branch point, but not at a
fold, where :math:`\det F_u` changes sign while the augmented matrix stays regular (the
curve itself is regular there), so folds and branch points are told apart without looking
at :math:`d\lambda/ds`. Its sign does not depend on the (positive) scales, so it is compared
between consecutive points in whatever scaling is in force. A sign change is located by
regula falsi (bisection when it creeps) on the determinant along the arclength from the
point before it, each trial corrected onto the curve like a fold's; the second null vector
of :math:`[F_u s_u \mid F_\lambda s_\lambda]` there, orthogonal to the tangent (two smallest
right singular vectors), points off the traced curve (for a symmetry-breaking pitchfork:
along the other curve). :func:`branch_off` steps along it and
corrects onto the other curve. Cost: one LU (``slogdet``) of the augmented matrix per
accepted point, plus 10-40 corrections per branch point; off by default.

*Stopping*: at a window edge (the last point is placed exactly on the edge by Newton at fixed
:math:`\lambda`), on returning to the starting point (a closed curve), after ``max_points``
points, or when the step falls below ``ds_min``; :attr:`ContinuationCurve.stop_reason` says
which.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from perturb.errors import ParameterError, PerturbError

__all__ = [
    "ContinuationError",
    "FoldPoint",
    "BranchPoint",
    "ContinuationCurve",
    "continue_curve",
    "branch_off",
    "newton_fixed",
]

Residual = Callable[[np.ndarray, float], np.ndarray]
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


class _Counted:
    """The user's callables with call counters and shape checks."""

    def __init__(self, residual: Residual, jacobian: Jacobian, n: int) -> None:
        self._residual, self._jacobian, self.n = residual, jacobian, n
        self.residuals = 0
        self.jacobians = 0

    def residual(self, u: np.ndarray, lam: float) -> np.ndarray:
        self.residuals += 1
        r = np.asarray(self._residual(u, lam), dtype=float).reshape(-1)
        if r.size != self.n:
            raise ParameterError(f"residual returned {r.size} values: expected {self.n}")
        return r

    def jacobian(self, u: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
        self.jacobians += 1
        ju, jl = self._jacobian(u, lam)
        ju = np.asarray(ju, dtype=float)
        jl = np.asarray(jl, dtype=float).reshape(-1)
        if ju.shape != (self.n, self.n) or jl.size != self.n:
            raise ParameterError(
                f"jacobian returned shapes {ju.shape} and {jl.shape}: expected "
                f"({self.n}, {self.n}) and ({self.n},)"
            )
        return ju, jl


def newton_fixed(
    residual: Residual,
    jacobian: Jacobian,
    u0: ArrayLike,
    lam: float,
    *,
    u_scale: ArrayLike = 1.0,
    tol: float = 1e-10,
    max_iterations: int = 50,
    residual_tol: float = 0.0,
) -> tuple[np.ndarray, int]:
    """Solve :math:`F(u, \\lambda) = 0` at fixed :math:`\\lambda` by damped Newton.

    Each step is cut by halving until :math:`\\|F\\|_2` decreases (Armijo, up to 20 halvings),
    so a poor guess can still converge.

    Parameters
    ----------
    residual, jacobian
        As for :func:`continue_curve`; only :math:`F_u` is used.
    u0
        Starting guess.
    lam
        The fixed parameter value.
    u_scale
        Scale of the unknowns; convergence is :math:`\\|\\Delta u / s_u\\|_\\infty \\le` ``tol``.
    tol
        Convergence tolerance on the scaled Newton correction.
    max_iterations
        Newton steps before giving up.
    residual_tol
        Also converged when :math:`\\|F\\|_\\infty \\le` ``residual_tol`` (a solution at a
        fold, where :math:`F_u` is singular and the Newton correction meaningless).

    Returns
    -------
    u : numpy.ndarray
        The solution.
    iterations : int

    Raises
    ------
    ContinuationError
        When Newton does not converge (the message gives the residual reached).
    """
    u = np.array(u0, dtype=float).reshape(-1)
    su = np.broadcast_to(np.asarray(u_scale, dtype=float), u.shape)
    f = np.asarray(residual(u, lam), dtype=float)
    norm = float(np.linalg.norm(f))
    for it in range(1, max_iterations + 1):
        if float(np.max(np.abs(f))) <= residual_tol:
            return u, it - 1
        ju, _ = jacobian(u, lam)
        try:
            du = np.linalg.solve(ju, -f)
        except np.linalg.LinAlgError:
            du = np.linalg.lstsq(ju, -f, rcond=None)[0]
        if not np.all(np.isfinite(du)):
            break
        if np.max(np.abs(du / su)) <= tol:
            # converged: the residual is at rounding level, where a line search means nothing
            return u + du, it
        alpha = 1.0
        for _ in range(20):
            trial = u + alpha * du
            ft = np.asarray(residual(trial, lam), dtype=float)
            nt = float(np.linalg.norm(ft))
            if np.isfinite(nt) and nt <= (1.0 - 1e-4 * alpha) * norm:
                break
            alpha *= 0.5
        else:
            break  # no decrease along the Newton direction
        u, f, norm = trial, ft, nt
    raise ContinuationError(
        f"Newton at fixed parameter {lam!r} did not converge: residual {norm:.3g} after "
        f"{max_iterations} iterations at most"
    )


def _unit_tangent_start(
    ju: np.ndarray, jl: np.ndarray, su: np.ndarray, sl: float, direction: int
) -> np.ndarray:
    n = jl.size
    a = np.hstack([ju * su[None, :], (jl * sl)[:, None]])
    t = None
    try:
        z = np.linalg.solve(ju * su[None, :], -jl * sl)
        if np.all(np.isfinite(z)):
            t = np.append(z, 1.0)
    except np.linalg.LinAlgError:
        t = None
    if t is None or np.linalg.cond(a[:, :n]) > 1e14:
        # singular F_u (a start at a fold): the null vector of the full n x (n+1) matrix
        t = np.linalg.svd(a)[2][-1]
    t = t / np.linalg.norm(t)
    if t[-1] * direction < 0 or (t[-1] == 0.0 and direction < 0):
        t = -t
    return t


def _bordered_tangent(
    ju: np.ndarray, jl: np.ndarray, su: np.ndarray, sl: float, ref: np.ndarray
) -> np.ndarray | None:
    n = jl.size
    a = np.empty((n + 1, n + 1))
    a[:n, :n] = ju * su[None, :]
    a[:n, n] = jl * sl
    a[n] = ref
    rhs = np.zeros(n + 1)
    rhs[n] = 1.0
    try:
        z = np.linalg.solve(a, rhs)
    except np.linalg.LinAlgError:
        return None
    nz = np.linalg.norm(z)
    if not np.isfinite(nz) or nz == 0.0:
        return None
    return z / nz


class _Tracer:
    """State shared by the steps of one continuation."""

    def __init__(
        self,
        fun: _Counted,
        su: np.ndarray,
        sl: float,
        tol: float,
        max_newton: int,
    ) -> None:
        self.fun, self.su, self.sl = fun, su, sl
        self.tol, self.max_newton = tol, max_newton
        self.n = su.size
        self.last_ratio: float | None = None

    def scaled(self, u: np.ndarray, lam: float) -> np.ndarray:
        return np.append(u / self.su, lam / self.sl)

    def unscaled(self, w: np.ndarray) -> tuple[np.ndarray, float]:
        return w[: self.n] * self.su, float(w[self.n] * self.sl)

    def correct(
        self,
        w_pred: np.ndarray,
        row: np.ndarray,
        target: float,
        contraction: float | None = None,
    ) -> _Corrected | None:
        """Newton on ``F = 0, row . w = target`` from ``w_pred`` (scaled coordinates).

        Converged when the correction is at most ``tol``, or when the next one, estimated
        from the quadratic convergence as ``|dw_k|^2 / |dw_(k-1)|``, is (then the corrected
        iterate is accepted without another evaluation); with ``contraction`` (a bound on
        ``|dw_(k+1)| / |dw_k|^2`` measured on earlier points) already after the first
        correction when ``contraction |dw_1|^2 <= tol``. The Jacobian of the last evaluated
        iterate is returned with it: it differs from the Jacobian at the accepted point by
        the last correction only. :attr:`last_ratio` is the largest ``|dw_(k+1)| / |dw_k|^2``
        seen in this correction (None with a single iteration)."""
        self.last_ratio = None
        n = self.n
        w = w_pred.copy()
        a = np.empty((n + 1, n + 1))
        a[n] = row
        # second column: e_(n+1), whose solution is the (unnormalised) tangent at the iterate
        # when the bordering row is the previous tangent -- one factorisation for both
        rhs = np.zeros((n + 1, 2))
        rhs[n, 1] = 1.0
        prev = np.inf
        for it in range(1, self.max_newton + 1):
            u, lam = self.unscaled(w)
            f = self.fun.residual(u, lam)
            ju, jl = self.fun.jacobian(u, lam)
            a[:n, :n] = ju * self.su[None, :]
            a[:n, n] = jl * self.sl
            rhs[:n, 0] = -f
            rhs[n, 0] = target - float(row @ w)
            try:
                sol = np.linalg.solve(a, rhs)
            except np.linalg.LinAlgError:
                return None
            dw = sol[:, 0]
            size = float(np.max(np.abs(dw)))
            if not math.isfinite(size) or (it > 2 and size > 0.5 * prev):
                return None  # diverging, or converging too slowly to trust the step
            w = w + dw
            if it > 1 and prev > 0.0:
                ratio = size / (prev * prev)
                self.last_ratio = max(ratio, self.last_ratio or 0.0)
            if (
                size <= self.tol
                or (it > 1 and size < 0.5 * prev and size * size <= self.tol * prev)
                or (it == 1 and contraction is not None and contraction * size * size <= self.tol)
            ):
                return _Corrected(w, it, ju, jl, row, sol[:, 1])
            prev = size
        return None

    def tangent(self, c: _Corrected, ref: np.ndarray) -> np.ndarray | None:
        if c.row is ref:
            nz = float(np.linalg.norm(c.z))
            if math.isfinite(nz) and nz > 0.0:
                return c.z / nz
        return _bordered_tangent(c.ju, c.jl, self.su, self.sl, ref)


@dataclass(frozen=True, eq=False)
class _Corrected:
    """A corrected point with the Jacobian of its last Newton iterate."""

    w: np.ndarray
    iterations: int
    ju: np.ndarray
    jl: np.ndarray
    row: np.ndarray  # the bordering row of the correction
    z: np.ndarray  # [J; row]^-1 e_(n+1): the tangent direction when row is the old tangent


def _hermite_fold(
    w0: np.ndarray, t0: np.ndarray, w1: np.ndarray, t1: np.ndarray, ds: float
) -> np.ndarray:
    """Point of the cubic Hermite arc between two points where the last component is
    stationary (fallback when the refinement fails)."""
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


def _hermite_predict(
    w0: np.ndarray, t0: np.ndarray, w1: np.ndarray, t1: np.ndarray, step: float
) -> np.ndarray | None:
    """The cubic Hermite arc through the last two points (parametrised by the chord length
    ``h`` between them) extrapolated ``step`` beyond the last one: error ``O(h^2 step^2)``
    against ``O(step^2)`` for the tangent predictor, so the first Newton correction is
    small enough to be the last one. None when the points coincide."""
    h = float(np.linalg.norm(w1 - w0))
    if not math.isfinite(h) or h <= 0.0:
        return None
    s = 1.0 + step / h
    s2, s3 = s * s, s * s * s
    h00, h10 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s
    h01, h11 = -2 * s3 + 3 * s2, s3 - s2
    return h00 * w0 + h10 * h * t0 + h01 * w1 + h11 * h * t1


def _check_window(window: Sequence[float]) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in window)
    except (TypeError, ValueError):
        raise ParameterError(f"window = {window!r}: expected two numbers (low, high)") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ParameterError(f"window = ({lo}, {hi}): expected finite low < high")
    return lo, hi


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ParameterError(f"{name} = {value!r}: expected a positive finite number")
    return value


def continue_curve(
    residual: Residual,
    jacobian: Jacobian,
    u0: ArrayLike,
    lam0: float,
    window: Sequence[float],
    *,
    direction: int = 1,
    u_scale: ArrayLike = 1.0,
    lam_scale: float | None = None,
    adaptive_scale: bool = False,
    ds: float | None = None,
    ds_min: float | None = None,
    ds_max: float = 0.05,
    growth: float = 1.5,
    max_turn: float = 0.5,
    tol: float = 1e-10,
    max_newton: int = 8,
    max_points: int = 5000,
    correct_start: bool = True,
    refine_folds: bool = True,
    store_jacobians: bool = False,
    callback: Callable[[np.ndarray, float, np.ndarray, np.ndarray], Any] | None = None,
    predictor: str = "tangent",
    early_accept: bool = False,
    detect_branch_points: bool = False,
) -> ContinuationCurve:
    """Trace the solution curve of :math:`F(u, \\lambda) = 0` through a window of
    :math:`\\lambda` by pseudo-arclength continuation.

    Parameters
    ----------
    residual : callable
        ``residual(u, lam) -> F``, shape ``(n,)``.
    jacobian : callable
        ``jacobian(u, lam) -> (F_u, F_lam)``, shapes ``(n, n)`` and ``(n,)``. During a
        correction it is always called right after ``residual`` at the same point, so a
        caller whose residual and Jacobian share work can cache the last evaluation.
    u0 : array_like
        A point on (or, with ``correct_start``, near) the curve at ``lam0``.
    lam0 : float
        Starting parameter value, inside the window.
    window : (float, float)
        ``(low, high)``: the continuation stops when :math:`\\lambda` leaves it.
    direction : {1, -1}
        Initial direction of travel in :math:`\\lambda`.
    u_scale : float or array_like
        Scale of the unknowns (see the module docstring); broadcast to ``(n,)``.
    lam_scale : float, optional
        Scale of the parameter; default the window width.
    adaptive_scale : bool
        Let the scale of the unknowns follow the solution: after each point it becomes
        ``max(u_scale, max|u|)`` (re-set when it changes by more than 25 %), so ``ds_max`` is a
        relative step whether the solution is small or large.
    ds : float, optional
        First step (scaled arclength); default ``ds_max / 4``.
    ds_min : float, optional
        Smallest step; default ``1e-6 * ds_max``.
    ds_max : float
        Largest step: the output spacing along the curve.
    growth : float
        Step growth factor after an easy correction.
    max_turn : float
        Largest angle (radians) between consecutive tangents before a step is redone shorter.
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
        ``callback(u, lam, F_u, F_lam)`` at every accepted point (the start included),
        with the Jacobian of the point's last Newton iterate; its return values are kept in
        :attr:`ContinuationCurve.callback_values`. Stability or test functions go here,
        while the caller's own cache still holds that iterate.
    predictor : {'tangent', 'hermite'}
        ``'tangent'``: the Euler predictor along the unit tangent. ``'hermite'``: the cubic
        Hermite arc through the last two points and their tangents, extrapolated by the
        step (the tangent predictor for the first step and after a rescaling); a fourth-order
        predictor, whose first Newton correction is typically ``1e-6`` of the step.
    early_accept : bool
        Accept a point after one Newton correction when ``K |dw_1|^2 <= tol``, with ``K``
        four times the largest quadratic-convergence ratio ``|dw_(k+1)| / |dw_k|^2``
        measured in the corrections of the last eight points (a point is corrected to the
        end whenever no such measurement is at hand, which refreshes it). With the Hermite
        predictor this makes about one residual and Jacobian evaluation per point.
    detect_branch_points : bool
        Watch the sign of the augmented determinant (module docstring) and locate the
        branch points where it changes (:attr:`ContinuationCurve.branch_points`, ready for
        :func:`branch_off`): one extra ``(n + 1)``-square LU per point.

    Returns
    -------
    ContinuationCurve

    Raises
    ------
    ParameterError
        For a bad window, a start outside it, non-positive step settings, a bad direction or
        callables returning wrong shapes.
    ContinuationError
        When the start cannot be corrected onto the curve.
    """
    lo, hi = _check_window(window)
    lam0 = float(lam0)
    if not (lo <= lam0 <= hi):
        raise ParameterError(f"lam0 = {lam0!r} lies outside the window ({lo}, {hi})")
    if direction not in (1, -1):
        raise ParameterError(f"direction = {direction!r}: expected 1 or -1")
    u = np.array(u0, dtype=float).reshape(-1)
    if u.size == 0 or not np.all(np.isfinite(u)):
        raise ParameterError("u0: expected a non-empty vector of finite numbers")
    n = u.size
    su_base = np.array(np.broadcast_to(np.asarray(u_scale, dtype=float), (n,)))
    if not np.all(np.isfinite(su_base) & (su_base > 0)):
        raise ParameterError(f"u_scale = {u_scale!r}: expected positive finite numbers")
    sl = _positive("lam_scale", hi - lo if lam_scale is None else lam_scale)
    ds_max = _positive("ds_max", ds_max)
    ds_min = _positive("ds_min", 1e-6 * ds_max if ds_min is None else ds_min)
    step = min(ds_max, _positive("ds", ds_max / 4 if ds is None else ds))
    growth = _positive("growth", growth)
    tol = _positive("tol", tol)
    if int(max_points) < 1:
        raise ParameterError(f"max_points = {max_points!r}: expected at least 1")
    if predictor not in ("tangent", "hermite"):
        raise ParameterError(f"predictor = {predictor!r}: expected 'tangent' or 'hermite'")

    fun = _Counted(residual, jacobian, n)

    def scale_for(v: np.ndarray) -> np.ndarray:
        return np.maximum(su_base, float(np.max(np.abs(v)))) if adaptive_scale else su_base

    su = scale_for(u)
    tr = _Tracer(fun, su, sl, tol, int(max_newton))
    iters0 = 0
    if correct_start:
        u, iters0 = newton_fixed(fun.residual, fun.jacobian, u, lam0, u_scale=su, tol=tol)
        tr.su = su = scale_for(u)
    ju, jl = fun.jacobian(u, lam0)
    t = _unit_tangent_start(ju, jl, su, sl, direction)
    w = tr.scaled(u, lam0)

    # history in plain coordinates; (w, t) of the last point and of the previous one in the
    # current scaling
    us, lams, ts, its = [u], [lam0], [t], [iters0]
    jacs = [ju] if store_jacobians else None
    extras = [callback(u, lam0, ju, jl)] if callback is not None else None
    folds: list[FoldPoint] = []
    bps: list[BranchPoint] = []
    # sign of the augmented determinant at the last accepted point (None: not watched)
    bp_sign = _augmented_slogdet(ju, jl, su, sl, t)[0] if detect_branch_points else None
    cos_turn = math.cos(float(max_turn))
    stop = "max_points"
    travelled = 0.0
    start_u, start_lam, start_t = u, lam0, t

    def accept(c: _Corrected, t_new: np.ndarray) -> None:
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
        w_pred = None
        if predictor == "hermite" and prev_wt is not None:
            w_pred = _hermite_predict(prev_wt[0], prev_wt[1], w, t, step)
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
            step *= 0.5
            if step < ds_min:
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
                _record_fold(tr, folds, len(us) - 2, w, t, ce.w, te, refine_folds)
                if bp_sign is not None:
                    _record_branch_point(tr, bps, len(us) - 2, w, t, bp_sign, ce, te)
            stop = "window"
            break
        accept(c, t_new)
        _record_fold(tr, folds, len(us) - 2, w, t, c.w, t_new, refine_folds, float(t @ (c.w - w)))
        if bp_sign is not None:
            bp_sign = _record_branch_point(tr, bps, len(us) - 2, w, t, bp_sign, c, t_new)
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
        if c.iterations <= 2:
            step = min(ds_max, step * growth)
        elif c.iterations > 3:
            step = max(ds_min, step * 0.7)
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
        folds=tuple(folds),
        stop_reason=stop,
        residual_evaluations=fun.residuals,
        jacobian_evaluations=fun.jacobians,
        u_scale=tr.su,
        lam_scale=sl,
        callback_values=None if extras is None else tuple(extras),
        branch_points=tuple(bps),
    )


def _augmented_slogdet(
    ju: np.ndarray, jl: np.ndarray, su: np.ndarray, sl: float, t: np.ndarray
) -> tuple[float, float]:
    """``(sign, log|det|)`` of the augmented matrix ``[[F_u s_u, F_lam s_lam], [t^T]]``: the
    branch-point test function (its sign is independent of the positive scales)."""
    n = jl.size
    a = np.empty((n + 1, n + 1))
    a[:n, :n] = ju * su[None, :]
    a[:n, n] = jl * sl
    a[n] = t
    sign, logdet = np.linalg.slogdet(a)
    return float(sign), float(logdet)


def _record_branch_point(
    tr: _Tracer,
    bps: list[BranchPoint],
    index: int,
    w0: np.ndarray,
    t0: np.ndarray,
    sign0: float,
    c: _Corrected,
    t_new: np.ndarray,
) -> float:
    """Append a branch point if the augmented determinant changes sign between the point
    ``index`` (``w0, t0``, determinant sign ``sign0``) and the new point ``c``; return the
    new point's sign."""
    sign1, log1 = _augmented_slogdet(c.ju, c.jl, tr.su, tr.sl, t_new)
    if sign0 == 0.0 or sign1 == 0.0 or sign0 == sign1:
        return sign1 if sign1 != 0.0 else sign0
    # the determinant at the old point is not stored (one LU per point is the budget), so
    # the refinement measures it again, with a correction from the old point itself
    located = _refine_branch_point(tr, w0, t0, float(t0 @ (c.w - w0)), c.w, t_new, (sign1, log1))
    if located is None:
        return sign1
    w, t, ju, jl, refined = located
    u, lam = tr.unscaled(w)
    a = np.hstack([ju * tr.su[None, :], (jl * tr.sl)[:, None]])
    # the two smallest right singular vectors span the null space of [F_u | F_lam] at a
    # branch point; the other curve's tangent is the combination orthogonal to this one's
    v = np.linalg.svd(a)[2][-2:].T
    proj = v.T @ t
    direction = v @ np.array([-proj[1], proj[0]])
    t = v @ proj  # this curve's tangent, within the null space
    t /= max(1e-300, float(np.linalg.norm(t)))
    norm = float(np.linalg.norm(direction))
    if not math.isfinite(norm) or norm == 0.0:
        return sign1
    bps.append(
        BranchPoint(index, lam, u, t.copy(), direction / norm, tr.su.copy(), float(tr.sl), refined)
    )
    return sign1


def _refine_branch_point(
    tr: _Tracer,
    w0: np.ndarray,
    t0: np.ndarray,
    s1: float,
    w1: np.ndarray,
    t1: np.ndarray,
    end: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool] | None:
    """Regula falsi (Illinois, with bisection whenever two trials did not halve the bracket)
    on the augmented determinant along the arclength ``s`` in ``(0, s1)`` from ``w0``
    (``w1``, ``t1``: the point at ``s1`` and its tangent, ``end``: its ``(sign,
    log|det|)``); every trial is corrected onto the curve on the hyperplane ``t0 . (w - w0)
    = s``.

    The corrector's bordered matrix is the augmented one, singular at the branch point, so
    the trials stop converging very close to it; the point returned is the secant zero of
    the determinant between the two closest trials of opposite sign (linear interpolation
    of the corrected points: error of the order of the curvature times the squared
    bracket; a trial that fails is replaced by two at ``1e-4`` of the bracket on either
    side), with ``(w, tangent, F_u, F_lam, refined)`` there; ``refined`` when the bracket
    shrank below ``1e-3 s1`` or a trial's determinant fell below 1 % of its values at both
    ends. None when no sign change is measured again.

    The determinant is compared as ``sign exp(log|det| - log|det(w0)|)``: it varies by orders
    of magnitude along a branch, but is smooth between two points."""
    base = float(t0 @ w0)

    def trial(s: float) -> tuple[np.ndarray, float, np.ndarray] | None:
        c = tr.correct(w0 + s * t0, t0, base + s)
        tc = None if c is None else tr.tangent(c, t0)
        if c is None or tc is None:
            return None
        sign, logdet = _augmented_slogdet(c.ju, c.jl, tr.su, tr.sl, tc)
        return c.w, sign * math.exp(max(-700.0, min(700.0, logdet - ld0))), tc

    ld0 = 0.0
    c0 = tr.correct(w0.copy(), t0, base)
    tc0 = None if c0 is None else tr.tangent(c0, t0)
    if c0 is None or tc0 is None:
        return None
    sg0, ld0 = _augmented_slogdet(c0.ju, c0.jl, tr.su, tr.sl, tc0)
    g_end = end[0] * math.exp(max(-700.0, min(700.0, end[1] - ld0)))
    if sg0 * g_end >= 0.0:
        return None  # no sign change measured again: not a branch point
    # bracket (s, true g, corrected point, tangent) on each side, and the Illinois-scaled
    # values
    lo, hi = (0.0, sg0, c0.w, tc0), (s1, g_end, w1, t1)
    ga, gb = lo[1], hi[1]
    small = 0.01 * min(abs(sg0), abs(g_end))
    close = False
    side = 0
    widths = [s1, s1]
    for _ in range(40):
        width = hi[0] - lo[0]
        if width > 0.5 * widths[-2]:
            # the determinant can vary by orders of magnitude inside the bracket, where
            # regula falsi creeps from one end: bisect when two trials did not halve it
            s = 0.5 * (lo[0] + hi[0])
        else:
            s = (lo[0] * gb - hi[0] * ga) / (gb - ga)
        widths.append(width)
        got = trial(s)
        if got is None:
            # the trial fell (within Newton's reach) onto the branch point itself: trials a
            # little to either side bracket it tightly instead
            delta = 1e-4 * width
            sides = [(x, trial(x)) for x in (s - delta, s + delta) if lo[0] < x < hi[0]]
            sides = [(x, got) for x, got in sides if got is not None]
            if not sides:
                break
        else:
            sides = [(s, got)]
        for s, (w, g, tc) in sides:
            close = close or abs(g) <= small
            if g * lo[1] > 0:
                lo, ga = (s, g, w, tc), g
                if side == -1:
                    gb *= 0.5
                side = -1
            elif g * hi[1] > 0:
                hi, gb = (s, g, w, tc), g
                if side == 1:
                    ga *= 0.5
                side = 1
            else:  # g == 0: the branch point itself
                lo = hi = (s, g, w, tc)
        if lo[1] == 0.0 or abs(hi[0] - lo[0]) <= 1e-10 * max(1.0, abs(s1)):
            break
    weight = 0.0 if lo[1] == hi[1] else lo[1] / (lo[1] - hi[1])
    w = lo[2] + weight * (hi[2] - lo[2])
    u, lam = tr.unscaled(w)
    ju, jl = tr.fun.jacobian(u, lam)
    # not the bordered tangent at w: its matrix is the singular augmented one there; the
    # tangents of the two bracketing trials are regular and close
    t = lo[3] + weight * (hi[3] - lo[3])
    t = t / np.linalg.norm(t)
    refined = close or abs(hi[0] - lo[0]) <= 1e-3 * abs(s1)
    return w, t, ju, jl, refined


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
    step = _positive("step", step)
    tol = _positive("tol", tol)
    n = point.u.size
    fun = _Counted(residual, jacobian, n)
    tr = _Tracer(fun, np.asarray(point.u_scale, dtype=float), point.lam_scale, tol, max_newton)
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


def _record_fold(
    tr: _Tracer,
    folds: list[FoldPoint],
    index: int,
    w0: np.ndarray,
    t0: np.ndarray,
    w_new: np.ndarray,
    t_new: np.ndarray,
    refine: bool,
    step: float | None = None,
) -> None:
    """Append a fold if the lam-component of the tangent changes sign between the point
    ``index`` (``w0, t0``) and the new point."""
    g0, g1 = float(t0[-1]), float(t_new[-1])
    if g0 == 0.0 or g0 * g1 >= 0.0:
        return
    s1 = float(t0 @ (w_new - w0)) if step is None else step
    point = _refine_fold(tr, w0, t0, g0, s1, g1) if refine else None
    if point is None:
        w = _hermite_fold(w0, t0, w_new, t_new, s1)
        u, lam = tr.unscaled(w)
        folds.append(FoldPoint(index, lam, u, refined=False))
        return
    u, lam = tr.unscaled(point)
    folds.append(FoldPoint(index, lam, u))


def _refine_fold(
    tr: _Tracer, w0: np.ndarray, t0: np.ndarray, g0: float, s1: float, g1: float
) -> np.ndarray | None:
    """Regula falsi (Illinois) for the arclength where the tangent's lam-component vanishes;
    every trial is corrected onto the curve on the hyperplane ``t0 . (w - w0) = s``."""
    a, ga, b, gb = 0.0, g0, s1, g1
    side = 0
    best = None
    base = float(t0 @ w0)
    for _ in range(12):
        s = (a * gb - b * ga) / (gb - ga)
        c = tr.correct(w0 + s * t0, t0, base + s)
        tc = None if c is None else tr.tangent(c, t0)
        if c is None or tc is None:
            return best
        g = float(tc[-1])
        best = c.w
        # lam is stationary at the fold: |g| = 1e-8 leaves an error ~1e-16 / curvature
        if abs(g) <= 1e-8 or abs(b - a) <= 1e-10 * max(1.0, abs(s1)):
            return best
        if g * ga > 0:
            a, ga = s, g
            if side == -1:
                gb *= 0.5
            side = -1
        else:
            b, gb = s, g
            if side == 1:
                ga *= 0.5
            side = 1
    return best
