r"""Periodic orbits of smooth oscillators by periodic finite differences.

The third route of the literature study (besides single and multiple shooting): the orbit is
represented by its values on a uniform grid over one period and the equation of motion is
imposed at every grid point, so no integrator is involved in finding it.

Discretisation
--------------
Grid :math:`t_j = t_0 + jh`, :math:`h = P/N`, :math:`j = 0 .. N-1` (periodic: index
:math:`j + N \equiv j`).  Unknowns :math:`(x_j, v_j)`; with the centred, cyclic difference
operators of even order :math:`p` (stencil :math:`|l| \le p/2`, weights :math:`w^{(1)}_l,
w^{(2)}_l` from the Taylor/Vandermonde conditions),

.. math::

    (D_1 x)_j = \frac1h \sum_l w^{(1)}_l x_{j+l},\qquad
    (D_2 x)_j = \frac1{h^2} \sum_l w^{(2)}_l x_{j+l},

the :math:`2N` equations are

.. math::

    E_{1,j} = (D_1 x)_j - v_j = 0,\qquad E_{2,j} = (D_2 x)_j - a(t_j, x_j, v_j) = 0,

where :math:`\ddot x = a(t, x, \dot x)` is the oscillator.  The acceleration equation uses the
second-difference operator rather than :math:`D_1 v`: the centred first difference on a periodic
grid annihilates the alternating mode :math:`(-1)^j` (odd–even decoupling), the second difference
does not, so the discrete problem has no spurious checkerboard solutions.  Both operators are
:math:`O(h^p)` accurate, hence the orbit is too (verified by grid halving in the tests).

The Jacobian is sparse and *block cyclic* with 2x2 blocks (``scipy.sparse``): block
:math:`(j, j+l)` is :math:`\begin{pmatrix} w^{(1)}_l/h & -\delta_{l0} \\ w^{(2)}_l/h^2 -
\delta_{l0} a_x & -\delta_{l0} a_v\end{pmatrix}`, with wrap-around blocks in the corners.
Newton's method (the safeguarded iteration of :mod:`perturb.simulate.orbits.shooting`) solves it
with
SuperLU.  For autonomous systems the period is an unknown, with the extra column
:math:`\partial E_1/\partial P = -D_1x/P`, :math:`\partial E_2/\partial P = -2D_2x/P` and the
phase condition :math:`v_0 = 0`.

Multipliers
-----------
The finite-difference solution carries no monodromy.  The Floquet multipliers are computed by
**one pass of the supplied flow** (normally :class:`~perturb.simulate.flows.base.ODEFlow` with its
variational equations) over one period from the collocation state :math:`(x_0, v_0)`; they are
accurate to the orbit's discretisation error.  Amplitude, mean and first harmonic are those of
the trigonometric interpolant of the grid values (the discrete orbit itself, not a re-integration,
which for unstable orbits would drift away).
"""

from __future__ import annotations

import math
from fractions import Fraction
from functools import cache
from typing import Any

import numpy as np
import scipy.sparse as sps
from numpy.typing import ArrayLike

from perturb.errors import ParameterError
from perturb.simulate.flows.base import Flow
from perturb.simulate.orbits.shooting import (
    UNIT_TOL,
    PeriodicOrbit,
    check_count,
    check_finite,
    check_flow,
    check_positive,
    is_autonomous,
    reject_equilibrium,
    resolve_forcing_period,
    shooting_newton,
)

__all__ = ["collocation_orbit", "difference_weights"]

#: supported orders of the centred differences
ORDERS = (2, 4, 6, 8)


@cache
def difference_weights(order: int, derivative: int) -> tuple[float, ...]:
    r"""Centred weights :math:`w_l`, :math:`l = -p/2 .. p/2`, with
    :math:`\sum_l w_l f(l h) = h^d f^{(d)}(0) + O(h^{p+d})`.

    Exact rational solution of the Vandermonde conditions
    :math:`\sum_l w_l l^k = d!\,\delta_{kd}`, :math:`k = 0 .. p` (for example ``order=2``:
    ``(-1/2, 0, 1/2)`` and ``(1, -2, 1)``).
    """
    if order not in ORDERS:
        raise ParameterError(f"order = {order!r}: expected one of {ORDERS}")
    if derivative not in (1, 2):
        raise ParameterError(f"derivative = {derivative!r}: expected 1 or 2")
    q = order // 2
    offs = list(range(-q, q + 1))
    n = len(offs)
    A = [[Fraction(l) ** k for l in offs] + [Fraction(math.factorial(k) if k == derivative else 0)]
         for k in range(n)]  # fmt: skip
    # Gauss-Jordan elimination in exact arithmetic (n <= 9)
    for c in range(n):
        piv = next(r for r in range(c, n) if A[r][c] != 0)
        A[c], A[piv] = A[piv], A[c]
        inv = 1 / A[c][c]
        A[c] = [a * inv for a in A[c]]
        for r in range(n):
            if r != c and A[r][c] != 0:
                fac = A[r][c]
                A[r] = [a - fac * b for a, b in zip(A[r], A[c], strict=True)]
    return tuple(float(A[r][n]) for r in range(n))


class _TrigDense:
    """Trigonometric interpolant of grid values of ``(x, v)`` over one period."""

    def __init__(self, X: np.ndarray, t0: float, P: float) -> None:
        self.N = X.shape[0]
        self.t0, self.P = t0, P
        self.c = np.fft.rfft(X, axis=0) / self.N  # (N//2 + 1, 2)
        k = np.arange(self.c.shape[0], dtype=float)
        w = np.full(k.size, 2.0)
        w[0] = 1.0
        if self.N % 2 == 0:
            w[-1] = 1.0  # the Nyquist term appears once
        self.k, self.w = k, w

    def _series(self, t: np.ndarray, deriv: int) -> np.ndarray:
        th = 2.0 * np.pi * (np.asarray(t, float).reshape(-1) - self.t0) / self.P
        E = np.exp(1j * np.outer(th, self.k))
        coef = self.c * self.w[:, None]
        if deriv:
            coef = coef * (1j * 2.0 * np.pi * self.k / self.P)[:, None]
        if self.N % 2 == 0 and deriv:
            coef[-1] = 0.0  # the derivative of the Nyquist cosine is not resolved: drop it
        return (E @ coef).real.T  # (2, n)

    def __call__(self, t: ArrayLike) -> np.ndarray:
        return self._series(np.asarray(t, float), 0)

    def local(self, y_a: np.ndarray, t_a: float, t: float) -> np.ndarray:
        return self._series(np.array([t]), 0)[:, 0]

    def field(self, t: float, y: np.ndarray) -> np.ndarray:
        return self._series(np.array([t]), 1)[:, 0]


def _resample(X: np.ndarray, N: int) -> np.ndarray:
    """Periodic samples ``(M, 2)`` -> ``(N, 2)`` by trigonometric interpolation."""
    M = X.shape[0]
    if M == N:
        return X.copy()
    dense = _TrigDense(X, 0.0, 1.0)
    return dense(np.arange(N) / N).T.copy()


def collocation_orbit(
    flow: Flow,
    guess: ArrayLike | PeriodicOrbit,
    *,
    n_points: int = 128,
    order: int = 4,
    period: float | None = None,
    period_guess: float | None = None,
    m: int = 1,
    t0: float = 0.0,
    tol: float = 1e-10,
    max_iter: int = 50,
    unit_tol: float = UNIT_TOL,
) -> PeriodicOrbit:
    r"""Periodic orbit of a smooth oscillator by periodic finite differences of order ``order``.

    Parameters
    ----------
    flow
        A smooth flow exposing its right-hand side and Jacobian as ``flow.rhs.fun`` /
        ``flow.rhs.jac`` (:class:`~perturb.simulate.flows.base.ODEFlow`); it is also used once, for
        the multipliers (module docstring).
    guess
        A :class:`PeriodicOrbit` (sampled on the grid, its period taken as the period guess), an
        ``(M, 2)`` array of states on ``M`` equally spaced times over one period (resampled to
        the grid by trigonometric interpolation), or one state ``(x, v)`` at ``t0``, from which
        the flow is run over one period to make the initial grid values.
    n_points
        Grid points :math:`N` per period.
    order
        Order :math:`p` of the centred differences: 2, 4, 6 or 8.
    period, period_guess, m, t0, max_iter, unit_tol
        As in :func:`~perturb.simulate.orbits.shooting.multiple_shooting`.
    tol
        :math:`\max_j |E_j| \le \text{tol}\cdot\max(1, |x|, |v|)`.  The second differences
        amplify rounding by :math:`\sim 4/h^2`, so much smaller values than the default
        :math:`10^{-10}` are not reachable on fine grids.

    Returns
    -------
    PeriodicOrbit
        ``method = 'collocation'``; ``nodes`` holds the grid values ``(N, 2)``; ``residual`` is
        the discrete residual (it says nothing about the :math:`O(h^p)` discretisation error).

    Raises
    ------
    ParameterError
        Bad arguments, a flow without ``rhs``.
    ShootingError
        Newton did not converge.
    """
    flow, N, tol, max_iter = _check_grid_options(flow, n_points, order, tol, max_iter)
    auto, P0, m, t0, T_forcing = _period_setup(flow, guess, period, period_guess, m, t0)
    X0 = _initial_values(flow, guess, N, t0, P0)
    evaluate = _discrete_system(flow.rhs, N, order, t0, P0, auto)
    n = 2 * N
    z0 = X0.ravel().copy()
    if auto:
        z0 = np.append(z0, P0)
    what = f"collocation (N = {N}, order {order})"
    out = shooting_newton(
        evaluate,
        z0,
        tol=tol,
        max_iter=max_iter,
        scale=lambda z: max(1.0, float(np.max(np.abs(z[:n])))),
        what=what,
        admissible=(lambda z: bool(z[-1] > 0.0)) if auto else None,
    )
    X = out.z[:n].reshape(N, 2).copy()
    P = float(out.z[-1]) if auto else P0
    y0 = X[0].copy()
    if auto:
        reject_equilibrium(flow, y0, P, what, out.rnorm, out.iterations)
    # multipliers: one flow pass with the variational equations from the collocation state
    M = np.asarray(flow(y0, t0, t0 + P, sensitivity=True).sensitivity, dtype=float)
    return PeriodicOrbit.from_solution(
        dense=_TrigDense(X, t0, P),
        y0=y0,
        t0=t0,
        P=P,
        m=m,
        forcing_period=T_forcing,
        monodromy=M,
        residual=out.rnorm,
        iterations=out.iterations,
        method="collocation",
        unit_tol=unit_tol,
        nodes=X,
    )


def _check_grid_options(
    flow: Flow, n_points: int, order: int, tol: float, max_iter: int
) -> tuple[Flow, int, float, int]:
    """Step 1 of :func:`collocation_orbit`: the flow (it must expose ``rhs.fun`` and
    ``rhs.jac``), the grid size, the order and the Newton options checked."""
    flow = check_flow(flow)
    rhs = flow.rhs
    if (
        rhs is None
        or not callable(getattr(rhs, "fun", None))
        or not callable(getattr(rhs, "jac", None))
    ):
        raise ParameterError(
            f"flow = {flow!r}: collocation needs the smooth right-hand side and its Jacobian "
            "(flow.rhs.fun, flow.rhs.jac): pass an ODEFlow"
        )
    N = check_count(n_points, "n_points", 8)
    if order not in ORDERS:
        raise ParameterError(f"order = {order!r}: expected one of {ORDERS}")
    if N <= order:
        raise ParameterError(f"n_points = {N}: expected more than order = {order} points")
    tol = check_positive(tol, "tol")
    max_iter = check_count(max_iter, "max_iter", 0)
    return flow, N, tol, max_iter


def _period_setup(
    flow: Flow,
    guess: ArrayLike | PeriodicOrbit,
    period: float | None,
    period_guess: float | None,
    m: int,
    t0: float,
) -> tuple[bool, float, int, float, float | None]:
    """Step 2 of :func:`collocation_orbit`: ``(autonomous, P0, m, t0, forcing period)``.
    An autonomous flow's period is an unknown starting at ``period_guess`` (default the
    guess orbit's period); a forced flow's is ``m`` forcing periods."""
    auto = is_autonomous(flow)
    if auto and period is not None:
        raise ParameterError(
            f"period = {period!r} given for an autonomous flow: its period is an unknown; "
            "pass period_guess="
        )
    if isinstance(guess, PeriodicOrbit) and auto and period_guess is None:
        period_guess = guess.period
    if auto:
        if period_guess is None:
            raise ParameterError(
                "collocation_orbit: autonomous flow: expected period_guess for the unknown period"
            )
        return True, check_positive(period_guess, "period_guess"), 1, 0.0, None
    if period_guess is not None:
        raise ParameterError(
            f"period_guess = {period_guess!r} given for a forced flow: the period is "
            "m x the forcing period; pass period= to override the forcing period"
        )
    m = check_count(m, "m")
    t0 = check_finite(t0, "t0")
    T_forcing = resolve_forcing_period(flow, period, "collocation_orbit")
    return False, m * T_forcing, m, t0, T_forcing


def _initial_values(
    flow: Flow, guess: ArrayLike | PeriodicOrbit, N: int, t0: float, P0: float
) -> np.ndarray:
    """Step 3 of :func:`collocation_orbit`: the initial grid values ``(N, 2)`` from the
    guess (an orbit sampled, an array resampled, or one state run over a period)."""
    if isinstance(guess, PeriodicOrbit):
        _, xg, vg = guess.sample(N)
        return np.column_stack([xg, vg])
    try:
        G = np.array(guess, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(
            f"guess = {guess!r}: expected a PeriodicOrbit, an (M, 2) array or a state"
        ) from None
    if not np.all(np.isfinite(G)):
        raise ParameterError(f"guess = {G.tolist()!r}: expected finite values")
    if G.shape == (2,):
        tg = t0 + P0 * np.arange(N) / N
        return np.asarray(flow(G, t0, t0 + P0, t_eval=tg).ys, dtype=float)
    if G.ndim == 2 and G.shape[1] == 2 and G.shape[0] >= 2:
        return _resample(G, N)
    raise ParameterError(f"guess has shape {G.shape}: expected (2,) or (M, 2) with M >= 2")


def _discrete_system(rhs: Any, N: int, order: int, t0: float, P0: float, auto: bool):
    """Step 4 of :func:`collocation_orbit`: ``evaluate(z) -> (residual, sparse Jacobian,
    None)`` of the periodic finite-difference equations in ``z = (x_0, v_0, ..., [P])``
    (the period ``P`` an unknown, with the phase condition ``v_0 = 0``, when ``auto``)."""
    q = order // 2
    offs = np.arange(-q, q + 1)
    w1 = np.array(difference_weights(order, 1))
    w2 = np.array(difference_weights(order, 2))
    j = np.arange(N)
    # static sparsity of the x-columns: row block j, column block (j + l) mod N
    cols_x = 2 * ((j[:, None] + offs[None, :]) % N)  # (N, 2q+1)
    rows_e1 = np.repeat(2 * j, offs.size)
    rows_e2 = rows_e1 + 1
    n = 2 * N
    size = n + (1 if auto else 0)

    def operators(x: np.ndarray, P: float) -> tuple[np.ndarray, np.ndarray, float]:
        h = P / N
        xs = x[(j[:, None] + offs[None, :]) % N]  # (N, 2q+1)
        return xs @ w1 / h, xs @ w2 / (h * h), h

    def evaluate(z: np.ndarray) -> tuple[np.ndarray, Any, None]:
        P = float(z[-1]) if auto else P0
        x, v = z[0:n:2], z[1:n:2]
        d1, d2, h = operators(x, P)
        tj = t0 + h * j
        acc = np.empty(N)
        ax = np.empty(N)
        av = np.empty(N)
        for i in range(N):
            yi = np.array([x[i], v[i]])
            acc[i] = rhs.fun(tj[i], yi)[1]
            Ji = rhs.jac(tj[i], yi)
            ax[i], av[i] = Ji[1, 0], Ji[1, 1]
        r = np.empty(size)
        r[0:n:2] = d1 - v
        r[1:n:2] = d2 - acc
        # duplicate (row, col) pairs are summed by the sparse constructor: -a_x adds to the
        # diagonal weight of D2
        rows = [rows_e1, rows_e2, 2 * j, 2 * j + 1, 2 * j + 1]
        cols = [cols_x.ravel(), cols_x.ravel(), 2 * j + 1, 2 * j, 2 * j + 1]
        vals = [np.tile(w1 / h, N), np.tile(w2 / (h * h), N), -np.ones(N), -ax, -av]
        if auto:
            r[n] = v[0]
            dcol = np.empty(n)
            dcol[0:n:2] = -d1 / P
            dcol[1:n:2] = -2.0 * d2 / P
            rows += [np.arange(n), np.array([n])]
            cols += [np.full(n, n), np.array([1])]
            vals += [dcol, np.array([1.0])]
        J = sps.csc_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(size, size),
        )
        return r, J, None

    return evaluate
