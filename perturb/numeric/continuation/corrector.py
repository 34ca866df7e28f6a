r"""The corrector of the pseudo-arclength core: Newton on the bordered system in scaled
coordinates, the tangent from the same factorisation, and Newton at fixed parameter.

:class:`BorderedCorrector` solves :math:`F(w) = 0,\ r\cdot\hat w = c` for any bordering row
:math:`r` (the previous tangent for a continuation step, :math:`e_{n+1}` at a window edge, the
branch direction when switching branches), so the step loop (:mod:`.core`), the event tests
(:mod:`.events`) and branch switching (:mod:`.switching`) all correct onto the curve the same
way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from perturb.errors import ParameterError
from perturb.numeric.continuation.curve import ContinuationError, Jacobian, Residual
from perturb.numeric.roots import damped_newton, lu_or_lstsq

__all__ = [
    "CountedProblem",
    "Corrected",
    "BorderedCorrector",
    "newton_fixed",
    "null_tangent",
    "start_tangent",
    "bordered_tangent",
]


class CountedProblem:
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

    :func:`perturb.numeric.roots.damped_newton` with a scale per unknown: each step is cut by
    halving until :math:`\\|F\\|_2` decreases (Armijo, up to 19 halvings), so a poor guess
    can still converge; :math:`F_u` is evaluated only at iterates that need a correction.

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

    def direction(z: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        # the Jacobian is evaluated here, i.e. only at iterates that fail the residual test
        return lu_or_lstsq(jacobian(z, lam)[0], rhs)

    res = damped_newton(
        lambda z: (np.asarray(residual(z, lam), dtype=float), z, None),
        u,
        solve=direction,  # "J" is the iterate itself: direction() evaluates F_u on demand
        tol=residual_tol,
        max_iter=max_iterations,
        scale=su,  # per unknown: converged when max |du / s_u| <= tol
        step_tol=tol,
        # converged on the correction: the residual is at rounding level, where a line
        # search means nothing
        take_final_step=True,
        max_halvings=19,
    )
    if res.converged:
        # Newton steps, counting the final correction of the step test
        return res.z, res.iterations + (res.status == "step")
    raise ContinuationError(
        f"Newton at fixed parameter {lam!r} did not converge: residual "
        f"{float(np.linalg.norm(res.r)):.3g} after {max_iterations} iterations at most"
    )


def null_tangent(a: np.ndarray, rtol: float = 1e-8) -> tuple[np.ndarray, bool]:
    """Unit null vector of an ``n x (n+1)`` scaled Jacobian ``[F_u s_u | F_lam s_lam]``
    (its last right singular vector; the sign is arbitrary) and whether the matrix is rank
    deficient (smallest singular value at most ``rtol`` times the largest: a branch point,
    where the null space is two-dimensional).  Defined at a fold too, where :math:`F_u` is
    singular but the full matrix is not."""
    _, sv, vh = np.linalg.svd(a)
    return vh[-1], bool(sv[-1] <= rtol * sv[0])


def start_tangent(
    ju: np.ndarray, jl: np.ndarray, su: np.ndarray, sl: float, direction: int
) -> np.ndarray:
    """Unit tangent at the start: :math:`F_u z = -F_\\lambda` (the SVD null vector of
    ``[F_u s_u | F_lam s_lam]`` when :math:`F_u` is singular), oriented by ``direction`` in
    :math:`\\lambda`."""
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
        t = null_tangent(a)[0]
    t = t / np.linalg.norm(t)
    if t[-1] * direction < 0 or (t[-1] == 0.0 and direction < 0):
        t = -t
    return t


def bordered_tangent(
    ju: np.ndarray, jl: np.ndarray, su: np.ndarray, sl: float, ref: np.ndarray
) -> np.ndarray | None:
    """Unit tangent from ``[[F_u s_u, F_lam s_lam], [ref^T]] z = e_(n+1)``, oriented along
    ``ref``; None when that matrix is singular."""
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


@dataclass(frozen=True, eq=False)
class Corrected:
    """A corrected point with the Jacobian of its last Newton iterate."""

    w: np.ndarray
    iterations: int
    ju: np.ndarray
    jl: np.ndarray
    row: np.ndarray  # the bordering row of the correction
    z: np.ndarray  # [J; row]^-1 e_(n+1): the tangent direction when row is the old tangent


class BorderedCorrector:
    """Scaled coordinates and the bordered Newton corrector of one continuation.

    Parameters
    ----------
    fun : CountedProblem
    su : numpy.ndarray
        Scale of the unknowns (may be re-set between steps: ``adaptive_scale``).
    sl : float
        Scale of the parameter.
    tol : float
        Convergence tolerance on the scaled correction.
    max_newton : int
        Newton iterations per correction.
    """

    def __init__(
        self,
        fun: CountedProblem,
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
    ) -> Corrected | None:
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
                return Corrected(w, it, ju, jl, row, sol[:, 1])
            prev = size
        return None

    def tangent(self, c: Corrected, ref: np.ndarray) -> np.ndarray | None:
        """Unit tangent at a corrected point, oriented along ``ref`` (free when ``ref`` was
        the correction's bordering row: the factorisation's second solution)."""
        if c.row is ref:
            nz = float(np.linalg.norm(c.z))
            if math.isfinite(nz) and nz > 0.0:
                return c.z / nz
        return bordered_tangent(c.ju, c.jl, self.su, self.sl, ref)
