r"""Event tests of the pseudo-arclength core: folds and branch points between consecutive
points, each located on the curve.

An event test is an object watched at every accepted point: :meth:`FoldTest.check` and
:meth:`BranchPointTest.check` compare a test function at the previous and the new point and,
on a sign change, locate its zero by regula falsi along the arclength, every trial corrected
onto the curve by the :class:`~perturb.numeric.continuation.corrector.BorderedCorrector`.

- *Fold*: the :math:`\lambda`-component of the unit tangent.
- *Branch point*: the determinant of the augmented Jacobian
  :math:`\det\begin{pmatrix}F_u s_u & F_\lambda s_\lambda\\ t^T & 0\end{pmatrix}`, regular at
  a fold, zero where another curve crosses (the null space of :math:`[F_u \mid F_\lambda]`
  becomes two-dimensional); its sign does not depend on the positive scales.
"""

from __future__ import annotations

import math

import numpy as np

from perturb.numeric.continuation.corrector import BorderedCorrector, Corrected
from perturb.numeric.continuation.curve import BranchPoint, FoldPoint
from perturb.numeric.continuation.predictors import hermite_fold
from perturb.numeric.roots import illinois

__all__ = [
    "FoldTest",
    "BranchPointTest",
    "FloquetCrossings",
    "augmented_slogdet",
    "crossing_weight",
]


class FoldTest:
    """Folds: the tangent's :math:`\\lambda`-component changes sign.

    Parameters
    ----------
    refine : bool
        Locate the fold on the curve by regula falsi (Illinois) on that component as a
        function of the arclength from the point before it, each trial a full correction,
        so the reported point lies on the curve and its :math:`\\lambda` (stationary there)
        is accurate to about the square of the arclength error.  Otherwise (or when the
        refinement fails) the stationary point of the cubic Hermite arc between the two
        points.
    max_trials : int
        Corrections of the refinement.

    Attributes
    ----------
    found : list of FoldPoint
    """

    def __init__(self, refine: bool = True, max_trials: int = 12) -> None:
        self.refine = refine
        self.max_trials = max_trials
        self.found: list[FoldPoint] = []

    @staticmethod
    def crossed(t0: np.ndarray, t1: np.ndarray) -> bool:
        """Whether the last component changes sign from ``t0`` to ``t1`` (both nonzero)."""
        return float(t0[-1]) * float(t1[-1]) < 0.0

    def check(
        self,
        tr: BorderedCorrector,
        index: int,
        w0: np.ndarray,
        t0: np.ndarray,
        w_new: np.ndarray,
        t_new: np.ndarray,
        step: float | None = None,
    ) -> FoldPoint | None:
        """Record (and return) a fold between the point ``index`` (``w0, t0``) and the new
        point (``w_new, t_new``); ``step`` the arclength between them along ``t0``."""
        if not self.crossed(t0, t_new):
            return None
        g0, g1 = float(t0[-1]), float(t_new[-1])
        s1 = float(t0 @ (w_new - w0)) if step is None else step
        point = self.locate(tr, w0, t0, g0, s1, g1) if self.refine else None
        if point is None:
            w = hermite_fold(w0, t0, w_new, t_new, s1)
            u, lam = tr.unscaled(w)
            fold = FoldPoint(index, lam, u, refined=False)
        else:
            u, lam = tr.unscaled(point)
            fold = FoldPoint(index, lam, u)
        self.found.append(fold)
        return fold

    def locate(
        self,
        tr: BorderedCorrector,
        w0: np.ndarray,
        t0: np.ndarray,
        g0: float,
        s1: float,
        g1: float,
    ) -> np.ndarray | None:
        """Regula falsi (Illinois, :func:`perturb.numeric.roots.illinois`) for the arclength
        where the tangent's lam-component vanishes; every trial is corrected onto the curve on
        the hyperplane ``t0 . (w - w0) = s``.  Returns the last corrected trial (None when
        none was made).

        The last trial, not the one with the smallest ``|g|``: on a nonsmooth curve (the
        harmonic balance of a piecewise-linear force) ``g`` can jump through zero at a corner
        instead of vanishing, and the last trial, taken in the narrowest bracket, is then the
        closest (one more trial is taken in a bracket below the width tolerance,
        ``final_iterate``).  No bisection safeguard: ``g`` is smooth and nearly linear in
        ``s`` at a smooth fold, where the secant steps converge fastest; halving the bracket
        first made the folds of the regression set no more accurate, and some less."""
        if not s1 > 0.0:
            return None
        base = float(t0 @ w0)
        last: list[np.ndarray] = []

        def trial(s: float) -> float | None:
            c = tr.correct(w0 + s * t0, t0, base + s)
            tc = None if c is None else tr.tangent(c, t0)
            if c is None or tc is None:
                return None
            last[:] = [c.w]
            return float(tc[-1])

        # lam is stationary at the fold: |g| = 1e-8 leaves an error ~1e-16 / curvature
        illinois(
            trial,
            0.0,
            s1,
            g0,
            g1,
            xtol=1e-10 * max(1.0, abs(s1)),
            ftol=1e-8,
            max_iter=self.max_trials,
            include_ends=False,
            secant="mean",
            final_iterate=True,
        )
        return last[0] if last else None


def augmented_slogdet(
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


class BranchPointTest:
    """Branch points: the augmented determinant changes sign.

    Cost: one LU (``slogdet``) of the augmented matrix per accepted point, plus 10-40
    corrections per branch point.  The second null vector of
    :math:`[F_u s_u \\mid F_\\lambda s_\\lambda]` at a located point, orthogonal to the
    tangent (two smallest right singular vectors), points off the traced curve (for a
    symmetry-breaking pitchfork: along the other curve), ready for
    :func:`~perturb.numeric.continuation.branch_off`.

    Parameters
    ----------
    tr : BorderedCorrector
    ju, jl, t : numpy.ndarray
        Jacobian and tangent at the start: the sign the next point is compared with.

    Attributes
    ----------
    sign : float
        Sign of the determinant at the last accepted point.
    found : list of BranchPoint
    """

    def __init__(
        self, tr: BorderedCorrector, ju: np.ndarray, jl: np.ndarray, t: np.ndarray
    ) -> None:
        self.sign = augmented_slogdet(ju, jl, tr.su, tr.sl, t)[0]
        self.found: list[BranchPoint] = []

    def check(
        self,
        tr: BorderedCorrector,
        index: int,
        w0: np.ndarray,
        t0: np.ndarray,
        c: Corrected,
        t_new: np.ndarray,
    ) -> BranchPoint | None:
        """Record (and return) a branch point if the determinant changes sign between the
        point ``index`` (``w0, t0``, sign :attr:`sign`) and the new point ``c``; then
        :attr:`sign` is the new point's."""
        sign0 = self.sign
        sign1, log1 = augmented_slogdet(c.ju, c.jl, tr.su, tr.sl, t_new)
        if sign0 == 0.0 or sign1 == 0.0 or sign0 == sign1:
            self.sign = sign1 if sign1 != 0.0 else sign0
            return None
        self.sign = sign1
        # the determinant at the old point is not stored (one LU per point is the budget), so
        # the refinement measures it again, with a correction from the old point itself
        located = self.locate(tr, w0, t0, float(t0 @ (c.w - w0)), c.w, t_new, (sign1, log1))
        if located is None:
            return None
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
            return None
        bp = BranchPoint(
            index, lam, u, t.copy(), direction / norm, tr.su.copy(), float(tr.sl), refined
        )
        self.found.append(bp)
        return bp

    @staticmethod
    def locate(
        tr: BorderedCorrector,
        w0: np.ndarray,
        t0: np.ndarray,
        s1: float,
        w1: np.ndarray,
        t1: np.ndarray,
        end: tuple[float, float],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool] | None:
        """Regula falsi (:func:`perturb.numeric.roots.illinois`, with bisection whenever two
        trials did not halve the bracket, and two trials beside one that fails) on the
        augmented determinant along the arclength ``s`` in ``(0, s1)`` from ``w0`` (``w1``,
        ``t1``: the point at ``s1`` and its tangent, ``end``: its ``(sign, log|det|)``);
        every trial is corrected onto the curve on the hyperplane ``t0 . (w - w0) = s``.

        The corrector's bordered matrix is the augmented one, singular at the branch point,
        so the trials stop converging very close to it; the point returned is the secant
        zero of the determinant between the two closest trials of opposite sign (linear
        interpolation of the corrected points: error of the order of the curvature times the
        squared bracket; a trial that fails is replaced by two at ``1e-4`` of the bracket on
        either side), with ``(w, tangent, F_u, F_lam, refined)`` there; ``refined`` when the
        bracket shrank below ``1e-3 s1`` or a trial's determinant fell below 1 % of its
        values at both ends. None when no sign change is measured again.

        The determinant is compared as ``sign exp(log|det| - log|det(w0)|)``: it varies by
        orders of magnitude along a branch, but is smooth between two points."""
        if not s1 > 0.0:
            return None
        base = float(t0 @ w0)

        def trial(s: float) -> tuple[np.ndarray, float, np.ndarray] | None:
            c = tr.correct(w0 + s * t0, t0, base + s)
            tc = None if c is None else tr.tangent(c, t0)
            if c is None or tc is None:
                return None
            sign, logdet = augmented_slogdet(c.ju, c.jl, tr.su, tr.sl, tc)
            return c.w, sign * math.exp(max(-700.0, min(700.0, logdet - ld0))), tc

        ld0 = 0.0
        c0 = tr.correct(w0.copy(), t0, base)
        tc0 = None if c0 is None else tr.tangent(c0, t0)
        if c0 is None or tc0 is None:
            return None
        sg0, ld0 = augmented_slogdet(c0.ju, c0.jl, tr.su, tr.sl, tc0)
        g_end = end[0] * math.exp(max(-700.0, min(700.0, end[1] - ld0)))
        if sg0 * g_end >= 0.0:
            return None  # no sign change measured again: not a branch point
        # every corrected trial (true g, point, tangent) by its s: the final bracket's ends
        seen = {0.0: (sg0, c0.w, tc0), s1: (g_end, w1, t1)}
        small = 0.01 * min(abs(sg0), abs(g_end))

        def f(s: float) -> float | None:
            got = trial(s)
            if got is None:
                return None
            w, g, tc = got
            seen[s] = (g, w, tc)
            return g

        # the determinant can vary by orders of magnitude inside the bracket, where regula
        # falsi creeps from one end: bisect when two trials did not halve it; a trial that
        # fails fell (within Newton's reach) onto the branch point itself: trials a little to
        # either side bracket it tightly instead
        found = illinois(
            f,
            0.0,
            s1,
            sg0,
            g_end,
            xtol=1e-10 * max(1.0, abs(s1)),
            max_iter=40,
            include_ends=False,
            bisect=True,
            secant="mean",
            retry=1e-4,
        )
        close = any(abs(g) <= small for g, _, _ in list(seen.values())[2:])
        if found.value == 0.0:  # the branch point itself
            lo = hi = (found.root, *seen[found.root])
        else:
            lo, hi = ((x, *seen[x]) for x in found.bracket)
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


def crossing_weight(fa: float, fb: float) -> float:
    """Linear-interpolation weight of the zero of a test function between two points
    (values ``fa``, ``fb`` of opposite signs); 0.5 when both vanish."""
    return abs(fa) / (abs(fa) + abs(fb)) if (abs(fa) + abs(fb)) > 0 else 0.5


class FloquetCrossings:
    """Stability changes of a periodic orbit between two consecutive points, from the
    Floquet multipliers :math:`\\mu_i` at both (any continuation of periodic orbits).

    Test functions, each changing sign where a multiplier crosses the unit circle:

    - ``'branch_point'``: :math:`\\prod_i (1 - \\mu_i)` (a multiplier through +1; also at a
      fold, which the caller tells apart by the sign of :math:`d\\lambda/ds`);
    - ``'period_doubling'``: :math:`\\prod_i (1 + \\mu_i)` (through -1);
    - ``'torus'``: :math:`|\\mu_0| - 1` when both points have a complex pair (Neimark-Sacker).
    """

    @staticmethod
    def values(mult: np.ndarray) -> tuple[float, float]:
        """``(prod(1 - mu), prod(1 + mu))`` (real parts) at one point."""
        return float(np.prod(1 - mult).real), float(np.prod(1 + mult).real)

    @classmethod
    def crossings(cls, mult_a: np.ndarray, mult_b: np.ndarray) -> list[tuple[str, float]]:
        """``(kind, weight)`` of every sign change between the two points, in the order
        branch point, period doubling, torus; ``weight`` locates it by linear interpolation
        (:func:`crossing_weight`)."""
        out = []
        f1a, f2a = cls.values(mult_a)
        f1b, f2b = cls.values(mult_b)
        if f1a * f1b < 0:
            out.append(("branch_point", crossing_weight(f1a, f1b)))
        if f2a * f2b < 0:
            out.append(("period_doubling", crossing_weight(f2a, f2b)))
        ca = bool(np.any(np.abs(mult_a.imag) > 0))
        cb = bool(np.any(np.abs(mult_b.imag) > 0))
        if ca and cb and (abs(mult_a[0]) - 1) * (abs(mult_b[0]) - 1) < 0:
            out.append(("torus", crossing_weight(abs(mult_a[0]) - 1, abs(mult_b[0]) - 1)))
        return out
