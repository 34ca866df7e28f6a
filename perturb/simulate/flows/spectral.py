r"""Chebyshev collocation steps for a smooth second-order field ``x'' = a(t, x, x')``.

The event-driven flow (:mod:`perturb.simulate.flows.event_driven`) integrates, between two
switches, a *frozen* field that is smooth (analytic) in the state.  For such a field a step of
one global polynomial is far cheaper in Python than an explicit Runge–Kutta method, whose
cost is interpreter overhead per stage: one step here is a few vectorised evaluations of the
field at all nodes and small dense solves.

A step of length ``H`` from ``(t_a, x_0, v_0)`` takes the acceleration ``u_k = x''(t_k)`` at
the ``N + 1`` Chebyshev–Lobatto points ``t_k = t_a + (s_k + 1) H / 2`` as unknowns; with the
spectral integration matrix ``Q`` (``(Q f)_k`` is the integral from ``-1`` to ``s_k`` of the
degree-``N`` interpolant of ``f``)

.. math::

    v = v_0 + \tfrac{H}{2} Q u, \qquad x = x_0 + \tau v_0 + \tfrac{H^2}{4} Q^2 u,
    \qquad R(u) = u - a(t, x, v) = 0

is solved by Newton's method (Jacobian ``I - diag(a_x) H^2/4 Q^2 - diag(a_v) H/2 Q``).  The
sensitivity of the step to ``(x_0, v_0)`` comes from the same factorised Jacobian (two more
right-hand sides: ``du/dx_0 = J^{-1} a_x``, ``du/dv_0 = J^{-1}(a_x \tau + a_v)``), so the
monodromy costs almost nothing beyond the orbit — the derivative of the discrete map, exact to
the collocation error.  The step is accepted when the last Chebyshev coefficients of ``u``
(times ``H^2/4`` for ``x`` and ``H/2`` for ``v``) are below the tolerance, the geometric decay
of a Chebyshev series of an analytic function making that tail an error estimate; otherwise it
is repeated with a shorter ``H``.  States (and sensitivities) anywhere inside the step come
from the barycentric interpolant of the node values: the step's dense output, of the same
accuracy as its end point.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.polynomial import chebyshev as cheb
from scipy.linalg import lapack

from perturb.errors import ParameterError

__all__ = [
    "ChebyshevRule",
    "ChebyshevStep",
    "Chunk",
    "chebyshev_rule",
    "interpolation_matrix",
    "interpolation_row",
]

#: Newton iterations per step attempt before the step is shortened
MAX_NEWTON = 12
#: Newton stops when the collocation residual is below this, relative to max(1, max |u|): the
#: update it would still make moves x by about H^2/8 of it
_NEWTON_TOL = 1e-13
#: ... or after an update below this (relative to the same): the next would be below rounding
_SKIP = 1e-8

_getrf, _getrs = lapack.dgetrf, lapack.dgetrs


@dataclass(frozen=True)
class ChebyshevRule:
    """Nodes, barycentric weights, spectral integration matrices and the values-to-
    coefficients map of one degree ``N`` (on ``[-1, 1]``)."""

    n: int
    s: np.ndarray
    bary: np.ndarray
    Q: np.ndarray
    Q2: np.ndarray
    to_coef: np.ndarray
    #: the rows of ``to_coef`` giving the last three Chebyshev coefficients (error estimate)
    tail: np.ndarray
    #: the identity of the nodes' dimension
    eye: np.ndarray


@lru_cache(maxsize=8)
def chebyshev_rule(n: int) -> ChebyshevRule:
    """The Chebyshev–Lobatto rule of degree ``n`` (``n + 1`` nodes, ascending)."""
    k = np.arange(n + 1)
    s = -np.cos(np.pi * k / n)
    s[0], s[-1] = -1.0, 1.0
    if n % 2 == 0:
        s[n // 2] = 0.0
    bary = (-1.0) ** k
    bary[0] *= 0.5
    bary[-1] *= 0.5
    V = cheb.chebvander(s, n)
    to_coef = np.linalg.inv(V)
    # integral from -1 of each basis polynomial, evaluated at the nodes, truncated to degree n
    # by re-interpolation (exact for the degree-n interpolant up to the dropped T_{n+1} term,
    # which is below the step's own error estimate)
    eye = np.eye(n + 1)
    ints = np.column_stack([cheb.chebval(s, cheb.chebint(eye[j], lbnd=-1.0)) for j in range(n + 1)])
    Q = ints @ to_coef
    for arr in (s, bary, Q, to_coef):
        arr.setflags(write=False)
    Q2 = Q @ Q
    Q2.setflags(write=False)
    tail = np.ascontiguousarray(to_coef[-3:])
    tail.setflags(write=False)
    eye.setflags(write=False)
    return ChebyshevRule(n, s, bary, Q, Q2, to_coef, tail, eye)


def interpolation_row(rule: ChebyshevRule, s: float) -> np.ndarray:
    """Weights ``l`` with ``p(s) = l . p(s_k)`` for the interpolant at ``s`` in [-1, 1]."""
    d = s - rule.s
    w = rule.bary / d if d.all() else (d == 0.0).astype(float)
    return w / w.sum()


def interpolation_matrix(rule: ChebyshevRule, s: np.ndarray) -> np.ndarray:
    """Rows of :func:`interpolation_row` for many points (vectorised)."""
    s = np.asarray(s, dtype=float).reshape(-1)
    d = s[:, None] - rule.s[None, :]
    exact = d == 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        w = rule.bary[None, :] / d
        w = w / w.sum(axis=1, keepdims=True)
    rows = np.flatnonzero(exact.any(axis=1))
    if rows.size:
        w[rows] = exact[rows].astype(float)
    return w


@dataclass
class Chunk:
    """One accepted collocation step: node times, states, and (optionally) the node
    sensitivities ``d(x_k, v_k)/d(x_0, v_0)`` as the four arrays ``xx, xv, vx, vv``."""

    ta: float
    H: float
    rule: ChebyshevRule
    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    u: np.ndarray
    sens: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None

    def s_of(self, t: np.ndarray | float) -> np.ndarray | float:
        """The step's coordinate in [-1, 1] of times inside it (clipped: rounding)."""
        if isinstance(t, float):
            return min(1.0, max(-1.0, 2.0 * (t - self.ta) / self.H - 1.0))
        return np.clip(2.0 * (np.asarray(t) - self.ta) / self.H - 1.0, -1.0, 1.0)

    def states(self, t: np.ndarray) -> np.ndarray:
        """States ``(2, len(t))`` at times inside the step."""
        L = interpolation_matrix(self.rule, self.s_of(t))
        return np.vstack([L @ self.x, L @ self.v])

    def state(self, t: float) -> tuple[float, float, np.ndarray | None]:
        """``(x, v, sensitivity)`` at one time inside the step."""
        row = interpolation_row(self.rule, float(self.s_of(t)))
        x, v = float(row @ self.x), float(row @ self.v)
        if self.sens is None:
            return x, v, None
        xx, xv, vx, vv = (float(row @ q) for q in self.sens)
        return x, v, np.array([[xx, xv], [vx, vv]])


def _rows(q):
    """A per-node factor as a column (scaling the rows of a matrix); a scalar as it is."""
    return q[:, None] if np.ndim(q) else q


class ChebyshevStep:
    """Collocation steps of one vectorised field.

    Parameters
    ----------
    field
        ``field(t, x, v) -> (a, a_x, a_v)``: the acceleration and its partial derivatives,
        evaluated on arrays (scalars are broadcast).
    rtol, atol
        Tolerances of the step's error estimate (on ``x`` and ``v``).
    n
        Degree of the polynomial of one step.
    """

    def __init__(
        self,
        field: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple],
        rtol: float,
        atol: float,
        n: int = 24,
    ) -> None:
        if isinstance(n, bool) or not isinstance(n, int) or not 4 <= n <= 64:
            raise ParameterError(f"n = {n!r}: expected a whole number from 4 to 64")
        for name, value in (("rtol", rtol), ("atol", atol)):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ParameterError(f"{name} = {value!r}: expected a positive finite number")
        self.field = field
        self.rtol, self.atol = float(rtol), float(atol)
        self.rule = chebyshev_rule(n)

    def _raw(self, t, x, v):
        """``(a, a_x, a_v)`` with ``a`` an array of the nodes' shape; the partial derivatives
        may be scalars (constants)."""
        a, ax, av = self.field(t, x, v)
        if type(a) is not np.ndarray or a.shape != t.shape:
            a = np.full(t.shape, float(a)) if np.ndim(a) == 0 else np.broadcast_to(a, t.shape)
        return a, ax, av

    def attempt(
        self,
        ta: float,
        x0: float,
        v0: float,
        H: float,
        sensitivity: bool,
        u0: np.ndarray | None = None,
    ) -> tuple[Chunk | None, float]:
        """One step of length ``H`` from ``(ta, x0, v0)``.

        Parameters
        ----------
        ta, x0, v0
            Start time and state.
        H
            Step length (positive).
        sensitivity
            Also compute the node sensitivities ``d(x_k, v_k)/d(x0, v0)``.
        u0
            Starting accelerations at the nodes for Newton (default: the field's value at
            the start, at every node).

        Returns
        -------
        (Chunk or None, float)
            The step and its error ratio (error estimate over tolerance, at most 1), or None
            when Newton fails (ratio ``inf``) or the estimate exceeds the tolerance (the ratio
            says by how much: the caller shortens the step).
        """
        rule = self.rule
        n1 = rule.n + 1
        h1 = 0.5 * H
        h2 = h1 * h1
        tau = (rule.s + 1.0) * h1
        t = ta + tau
        Qh = h1 * rule.Q
        Q2h = h2 * rule.Q2
        base_x = x0 + tau * v0
        if u0 is None:
            a, _, _ = self._raw(t[:1], np.array([x0]), np.array([v0]))
            u = np.full(n1, float(a[0]))
        else:
            u = np.array(u0, dtype=float)
        eye = rule.eye
        # Newton stops on a small residual, or on an update so small that the next one would
        # be below rounding (quadratic convergence); the iterates do not depend on
        # ``sensitivity``, so a run with and without it takes the same steps
        refactor = False
        J_v = None  # eye - a_v H/2 Q, formed once when a_v is a constant (linear damping)
        with np.errstate(all="ignore"):
            for _ in range(MAX_NEWTON):
                x = base_x + Q2h @ u
                v = v0 + Qh @ u
                a, ax, av = self._raw(t, x, v)
                r = u - a
                if J_v is None:
                    J_v = eye - av * Qh if np.ndim(av) == 0 else False
                if J_v is False:
                    J = eye - _rows(ax) * Q2h - _rows(av) * Qh
                else:
                    J = J_v - _rows(ax) * Q2h
                lu, piv, info = _getrf(J, overwrite_a=True)
                if info != 0:
                    return None, math.inf
                scale_u = max(1.0, float(np.abs(u).max()))
                res = float(np.abs(r).max())
                if not math.isfinite(res):
                    return None, math.inf
                if res <= _NEWTON_TOL * scale_u:
                    break
                du, info = _getrs(lu, piv, r)
                u = u - du
                if float(np.abs(du).max()) <= _SKIP * scale_u:
                    x = base_x + Q2h @ u
                    v = v0 + Qh @ u
                    refactor = True
                    break
            else:
                return None, math.inf
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
            return None, math.inf
        # error estimate: the tail of the Chebyshev series of u, integrated once (v) and
        # twice (x); a decaying series has its error below the last coefficients
        tail = float(np.abs(rule.tail @ u).sum())
        err_v = h1 * tail
        err_x = h2 * tail
        tol_x = self.atol + self.rtol * float(np.abs(x).max())
        tol_v = self.atol + self.rtol * float(np.abs(v).max())
        ratio = max(err_x / tol_x, err_v / tol_v)
        if not math.isfinite(ratio) or ratio > 1.0:
            return None, ratio if math.isfinite(ratio) else math.inf
        sens = None
        if sensitivity:
            if refactor:  # the Jacobian at the accepted iterate
                _, ax, av = self._raw(t, x, v)
                J = eye - _rows(ax) * Q2h - _rows(av) * Qh
                lu, piv, info = _getrf(J, overwrite_a=True)
                if info != 0:
                    return None, math.inf
            ax = np.broadcast_to(ax, tau.shape)
            # one right-hand side at a time: OpenBLAS runs a solve with several in threads,
            # whose start-up and spinning cost far more than this small solve (measured: the
            # whole frequency response took 7x the CPU time on a loaded machine)
            dx0, _ = _getrs(lu, piv, ax)
            dv0, _ = _getrs(lu, piv, ax * tau + av)
            sens = (1.0 + Q2h @ dx0, tau + Q2h @ dv0, Qh @ dx0, 1.0 + Qh @ dv0)
        return Chunk(ta, H, rule, t, x, v, u, sens), ratio
