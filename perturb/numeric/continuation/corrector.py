r"""The corrector of the pseudo-arclength core: Newton on the bordered system in scaled
coordinates, the tangent from the same factorisation, and Newton at fixed parameter.

:class:`Corrector` is the one bordered Newton loop of the package: the caller supplies the
evaluation (residual and Jacobians in one call, with a payload), the acceptance rule, the
cap on the first correction and, for problems without :math:`F_\lambda`, a finite-difference
column kept current by Broyden updates. :class:`BorderedCorrector` is the continuation
core's use of it: :math:`F(w) = 0,\ r\cdot\hat w = c` for any bordering row :math:`r` (the
previous tangent for a continuation step, :math:`e_{n+1}` at a window edge, the branch
direction when switching branches), so the step loop (:mod:`.core`), the event tests
(:mod:`.events`) and branch switching (:mod:`.switching`) all correct onto the curve the same
way; the exact frequency response (:mod:`perturb.simulate.exact_response`) uses it with its
shooting residual, its own acceptance (orbit statistics within tolerance) and its step caps.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from perturb.errors import ParameterError
from perturb.numeric.continuation.curve import ContinuationError, Jacobian, Residual
from perturb.numeric.roots import damped_newton, lu_or_lstsq

__all__ = [
    "CountedProblem",
    "Evaluation",
    "Correction",
    "Corrector",
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
class Evaluation:
    """One evaluation of a bordered problem at an iterate: the residual :math:`F`, its
    Jacobians :math:`F_u` and :math:`F_\\lambda` (unscaled; ``jl`` None when the problem has
    no parameter derivative: the :class:`Corrector` then uses its ``fd_column`` and a
    Broyden update), and whatever else the caller needs from that evaluation (``payload``:
    the exact response's monodromy and orbit statistics)."""

    r: np.ndarray
    ju: np.ndarray
    jl: np.ndarray | None
    payload: Any = None


@dataclass(frozen=True, eq=False)
class Correction:
    """A converged correction of :meth:`Corrector.correct`.

    ``x`` is the accepted iterate (the last evaluated one plus the last Newton correction),
    ``x_evaluated`` the iterate of the last evaluation, ``evaluation`` that evaluation,
    ``jl`` the parameter column used in the last solve (the evaluation's, or the
    finite-difference/Broyden column), ``z`` the second solution ``[J; row]^-1 e_(n+1)``
    (the unnormalised tangent; None unless the corrector solves for it), ``iterations`` the
    Newton steps taken and ``evaluations`` the calls of ``evaluate`` and ``fd_column``."""

    x: np.ndarray
    x_evaluated: np.ndarray
    evaluation: Evaluation
    jl: np.ndarray
    z: np.ndarray | None
    iterations: int
    evaluations: int


#: ``accept(k, size, prev, evaluation) -> bool`` and ``observe(k, size, prev) -> None``: the
#: iteration index k (0 for the first correction), the scaled size ``max |dx / D|`` of its
#: correction and that of the previous one (``inf`` at k = 0)
AcceptRule = Callable[[int, float, float, Evaluation], bool]
ObserveRule = Callable[[int, float, float], None]


class Corrector:
    r"""Newton on the bordered system :math:`F(x) = 0,\ \text{row}\cdot\hat x = c`: the one
    pseudo-arclength corrector of the continuation core (:class:`BorderedCorrector`, hence
    :func:`continue_curve`, the event tests and branch switching) and of the exact frequency
    response (:mod:`perturb.simulate.exact_response`).

    Each iteration evaluates :math:`F, F_u, F_\lambda` (one callback, so a shooting problem
    propagates once for all three and hands back its monodromy as payload), solves

    .. math:: \begin{pmatrix} F_u\,\mathrm{diag}(D_u) & F_\lambda D_\lambda \\
              \text{row} \end{pmatrix} \Delta = \begin{pmatrix} -F \\ b \end{pmatrix}

    in scaled coordinates and updates the iterate. The policies are the caller's:

    - ``accept(k, size, prev, evaluation)``: converged after the correction of size
      ``size = max|Delta|`` (the iterate is accepted corrected, without another
      evaluation);
    - ``observe(k, size, prev)``: told every correction (contraction statistics);
    - ``cap``: the first correction may be at most this large (a predictor far from the
      curve: the caller shortens the step);
    - a later correction larger than half the previous one (from the third on) fails (not
      converging), as does a non-finite evaluation, correction or singular matrix.

    Two coordinate conventions, both with the scales ``D`` (length n+1, ``D[n]`` the
    parameter's):

    - ``scaled=True``: ``x`` is the scaled point :math:`\hat x = x/D`, updated
      :math:`\hat x \mathrel{+}= \Delta`, border :math:`b = c - \text{row}\cdot\hat x`;
    - ``scaled=False``: ``x`` is the point itself, updated :math:`x \mathrel{+}= \Delta D`,
      the border the hyperplane through an anchor :math:`\hat a` (scaled),
      :math:`b = -\text{row}\cdot(x/D - \hat a)`.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(x) -> Evaluation | None`` (None: the iterate cannot be evaluated, e.g.
        outside the parameter window; not counted as an evaluation). A non-finite residual
        or :math:`F_u` fails the correction after it is counted.
    scaled : bool
        The coordinate convention above.
    tangent : bool
        Also solve for ``[J; row]^-1 e_(n+1)`` with the same factorisation (the tangent when
        the row is the previous tangent): returned as :attr:`Correction.z`.
    fd_column : callable, optional
        ``fd_column(x, r) -> F_lambda | None`` for evaluations without ``jl`` (one counted
        evaluation): a finite difference at the first such iterate, then updated by Broyden's
        secant condition along each Newton step whose parameter part is at least a tenth of
        its largest scaled component (:math:`F_u` is exact at both ends of the step), which
        keeps Newton superlinear.

    Attributes
    ----------
    evaluations : int
        Evaluations of the last :meth:`correct`, converged or not.
    """

    def __init__(
        self,
        evaluate: Callable[[np.ndarray], Evaluation | None],
        *,
        scaled: bool = True,
        tangent: bool = False,
        fd_column: Callable[[np.ndarray, np.ndarray], np.ndarray | None] | None = None,
    ) -> None:
        self.evaluate, self.scaled, self.tangent = evaluate, scaled, tangent
        self.fd_column = fd_column
        self.evaluations = 0

    def correct(
        self,
        x0: np.ndarray,
        D: np.ndarray,
        row: np.ndarray,
        *,
        max_iter: int,
        accept: AcceptRule,
        observe: ObserveRule | None = None,
        target: float = 0.0,
        anchor: np.ndarray | None = None,
        cap: float = math.inf,
    ) -> Correction | None:
        """Newton from ``x0`` on ``F = 0`` bordered by ``row`` (``target`` with
        ``scaled=True``, the hyperplane through ``anchor`` otherwise); None when it fails."""
        self.evaluations = 0
        n = D.size - 1
        x = x0.copy()
        a = np.empty((n + 1, n + 1))
        a[n] = row
        if self.tangent:
            # second column: e_(n+1), whose solution is the (unnormalised) tangent at the
            # iterate when the bordering row is the previous tangent -- one factorisation
            rhs = np.zeros((n + 1, 2))
            rhs[n, 1] = 1.0
            b = rhs[:, 0]
        else:
            rhs = b = np.empty(n + 1)
        du_scale, dl_scale = D[None, :n], D[n]
        prev = math.inf
        chord: np.ndarray | None = None
        last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        for k in range(max_iter):
            ev = self.evaluate(x)
            if ev is None:
                return None
            self.evaluations += 1
            if not np.all(np.isfinite(ev.r)) or not np.all(np.isfinite(ev.ju)):
                return None
            jl = ev.jl
            if jl is None:
                if self.fd_column is None:
                    raise ParameterError("the evaluation has no F_lambda and no fd_column")
                if chord is None:
                    chord = self.fd_column(x, ev.r)
                    if chord is None:
                        return None
                    self.evaluations += 1
                elif last is not None:
                    r0, ju0, dx0 = last
                    dl = dx0[n]
                    if abs(dl) / D[n] >= 0.1 * float(np.max(np.abs(dx0 / D))):
                        chord = (ev.r - r0 - 0.5 * (ju0 + ev.ju) @ dx0[:n]) / dl
                jl = chord
            a[:n, :n] = ev.ju * du_scale
            a[:n, n] = jl * dl_scale
            b[:n] = -ev.r
            if self.scaled:
                b[n] = target - float(row @ x)
            else:
                b[n] = -(row @ (x / D - anchor))
            try:
                sol = np.linalg.solve(a, rhs)
            except np.linalg.LinAlgError:
                return None
            dx = sol[:, 0] if self.tangent else sol
            size = float(np.max(np.abs(dx)))
            if not math.isfinite(size):
                return None
            if k == 0 and size > cap:
                return None  # the predictor is far from the curve: shorten the step
            if k >= 2 and size > 0.5 * prev:
                return None  # diverging, or converging too slowly to trust the step
            x_ev = x
            # the step in unscaled coordinates, for the Broyden update of the next iterate
            step = dx * D if (not self.scaled or ev.jl is None) else dx
            last = (ev.r, ev.ju, step) if ev.jl is None else None
            x = x + dx if self.scaled else x + step
            if observe is not None:
                observe(k, size, prev)
            if accept(k, size, prev, ev):
                z = sol[:, 1] if self.tangent else None
                return Correction(x, x_ev, ev, jl, z, k + 1, self.evaluations)
            prev = size
        return None


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
        self._newton = Corrector(self._evaluate, scaled=True, tangent=True)

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
        tol = self.tol

        def observe(k: int, size: float, prev: float) -> None:
            if k > 0 and prev > 0.0:
                ratio = size / (prev * prev)
                self.last_ratio = max(ratio, self.last_ratio or 0.0)

        def accept(k: int, size: float, prev: float, ev: Evaluation) -> bool:
            return (
                size <= tol
                or (k > 0 and size < 0.5 * prev and size * size <= tol * prev)
                or (k == 0 and contraction is not None and contraction * size * size <= tol)
            )

        c = self._newton.correct(
            w_pred,
            np.append(self.su, self.sl),
            row,
            max_iter=self.max_newton,
            accept=accept,
            observe=observe,
            target=target,
        )
        if c is None:
            return None
        return Corrected(c.x, c.iterations, c.evaluation.ju, c.jl, row, c.z)

    def _evaluate(self, w: np.ndarray) -> Evaluation:
        u, lam = self.unscaled(w)
        f = self.fun.residual(u, lam)
        ju, jl = self.fun.jacobian(u, lam)
        return Evaluation(f, ju, jl)

    def tangent(self, c: Corrected, ref: np.ndarray) -> np.ndarray | None:
        """Unit tangent at a corrected point, oriented along ``ref`` (free when ``ref`` was
        the correction's bordering row: the factorisation's second solution)."""
        if c.row is ref:
            nz = float(np.linalg.norm(c.z))
            if math.isfinite(nz) and nz > 0.0:
                return c.z / nz
        return bordered_tangent(c.ju, c.jl, self.su, self.sl, ref)
