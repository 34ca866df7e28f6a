r"""Exact Galerkin projection of piecewise-linear forces on a truncated Fourier series.

The Fourier layer's numeric half for multi-harmonic signals: a signal

.. math::

    x(\theta) = a_0 + \sum_{k \in K} a_k \cos k\theta + b_k \sin k\theta

(coefficients ``u = [a0, a_1, b_1, a_2, b_2, ...]`` in a :class:`HarmonicBasis`), the angles
where it crosses given levels (:func:`switching_angles`, :func:`crossing_intervals`), and the
Galerkin projection of a piecewise-linear force ``f(x(theta))`` on the basis with its exact
Jacobian (:func:`pwl_projection`, :class:`ExactProjector`),

.. math::

    P_0 = \frac{1}{2\pi}\int_0^{2\pi} f\,d\theta,\quad
    P_{a_k} = \frac{1}{\pi}\int_0^{2\pi} f\cos k\theta\,d\theta,\quad
    P_{b_k} = \frac{1}{\pi}\int_0^{2\pi} f\sin k\theta\,d\theta.

Numeric harmonic balance (:mod:`perturb.numeric.harmonic_balance`) balances its residual
with this projection (``projection="exact"``) and builds the exact monodromy of its Hill
stability test from the crossing intervals.

Exact projection of a piecewise-linear force (``projection="exact"``)
---------------------------------------------------------------------
With the force :math:`f(x) = s_i x + o_i` on segment :math:`i`, the composite :math:`f(x(\theta))
= q(\theta)\,x(\theta) + c(\theta)` *exactly*, where :math:`q` and :math:`c` are piecewise
constant in :math:`\theta` and switch at the crossings :math:`\theta_c` of the breakpoints. Their
complex Fourier coefficients are closed-form sums over the crossings,

.. math::

    Q_n = \frac{1}{2\pi}\sum_c (s_c^- - s_c^+)\,\frac{i\,e^{-in\theta_c}}{n}\ (n \ne 0),\qquad
    Q_0 = \frac{1}{2\pi}\sum_{\text{intervals}} s\,|\text{interval}|,

(likewise :math:`C_n` from the offsets; :math:`s_c^\mp` are the slopes before and after the
crossing), and since :math:`x` has finitely many harmonics, the projection of :math:`f` is the
finite convolution :math:`F_j = \sum_n Q_{j-n} X_n + C_j` with :math:`X_{\pm k} = (a_k \mp i
b_k)/2` — no sampling and no aliasing, exact up to rounding and the crossing angles. The
Jacobian is the Toeplitz matrix :math:`Q_{j-n}` (the Leibniz boundary terms cancel for a
continuous force). A jump :math:`J` of the force at a crossing adds
:math:`\frac{1}{2\pi}\sum_c \frac{f^+ - f^-}{x_\theta(\theta_c)} e^{-in\theta_c}` to
:math:`Q_n` in the Jacobian only (the derivative of the moving switch), i.e. the
:math:`J\,\delta(x - d)` term of :math:`f'`; it is unbounded at a tangential crossing of a jump,
as the true derivative is.

Crossings: all roots of the trigonometric polynomial :math:`x(\theta) - d` on
:math:`[0, 2\pi)` by *certified isolation* on a grid of ``4 max(K)`` intervals (at least 16),
then Halley/Newton polishing. With the global bounds :math:`B_j = \sum_k k^j r_k \ge
\max|x^{(j)}|`, :math:`r_k = \sqrt{a_k^2 + b_k^2}`, and the derivatives at the midpoint
:math:`c` of an interval of half-width :math:`\rho` (third-order Taylor bounds), the interval
holds no root when :math:`|x(c) - d| > \rho|x'| + \rho^2|x''|/2 + \rho^3 B_3/6`, at most one
(found from the sign change) when :math:`|x'(c)| > \rho|x''| + \rho^2 B_3/2` (``x``
monotone), and at most one extremum when :math:`|x''(c)| > \rho|x^{(3)}| + \rho^2 B_4/2` —
then the extremum is located by Newton on :math:`x'` and the two sides are monotone
brackets; otherwise the interval is halved. So no crossing is missed, tangential ones
included: an extremum within rounding of ``d`` is a tangency (the force does not switch),
and a pair of crossings :math:`10^{-5}` apart next to an extremum is resolved. This was
preferred to companion-matrix roots of the degree-``2K`` polynomial in :math:`z =
e^{i\theta}` (exact too, but an :math:`O(K^3)` eigenvalue problem per breakpoint and
evaluation: ~0.6 ms at ``K = 15`` on the development machine, against ~0.1 ms for the whole
isolation) and to dense bracketing with brentq (which loses a pair of crossings between two
samples).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from perturb.errors import ParameterError
from perturb.model.pwl import NumericPWL

__all__ = [
    "HarmonicBasis",
    "TruncatedSeries",
    "switching_angles",
    "CrossingIntervals",
    "crossing_intervals",
    "ExactProjector",
    "pwl_projection",
]

#: Grid intervals per highest harmonic for the isolation of crossings.
_GRID_PER_HARMONIC = 4
#: Smallest grid for the isolation of crossings.
_GRID_MIN = 16
#: Deepest bisection of an interval whose crossings the derivative bounds cannot decide.
_MAX_DEPTH = 40
_TWO_PI = 2.0 * math.pi
_EPS = float(np.finfo(float).eps)
#: Most level sets whose tables a grid keeps, and most bytes of their tiled design rows.
_LEVEL_TABLES = 16
_LEVEL_TABLES_BYTES = 32 * 2**20
#: Most roots polished with Python-float arithmetic (numpy's per-call cost dominates below).
_SCALAR_ROOTS = 16


# =============================================================================================
# the basis
# =============================================================================================
@dataclass(frozen=True)
class HarmonicBasis:
    """The truncated Fourier basis ``1, cos k theta, sin k theta`` (``k`` in ``harmonics``).

    Attributes
    ----------
    harmonics : tuple of int
        Increasing positive harmonic numbers.
    bias : bool
        Whether the constant ``a0`` is an unknown.
    """

    harmonics: tuple[int, ...]
    bias: bool = True

    def __post_init__(self) -> None:
        ks = tuple(int(k) for k in self.harmonics)
        if (
            not ks
            or any(k < 1 for k in ks)
            or any(b <= a for a, b in zip(ks, ks[1:], strict=False))
        ):
            raise ParameterError(
                f"harmonics = {self.harmonics!r}: expected increasing positive integers"
            )
        object.__setattr__(self, "harmonics", ks)

    @classmethod
    def make(cls, H: int, *, odd_only: bool = False, bias: bool | None = None) -> HarmonicBasis:
        """Harmonics ``1..H`` (odd ones only with ``odd_only``); ``bias`` defaults to
        ``not odd_only``.

        Raises
        ------
        ParameterError
            For ``H`` that is not an integer at least 1.
        """
        if isinstance(H, bool) or not isinstance(H, int | np.integer) or H < 1:
            raise ParameterError(f"harmonics = {H!r}: expected an integer H >= 1")
        ks = tuple(range(1, int(H) + 1, 2 if odd_only else 1))
        return cls(ks, (not odd_only) if bias is None else bool(bias))

    # ---- layout ------------------------------------------------------------------------------
    @property
    def size(self) -> int:
        """Number of unknowns."""
        return int(self.bias) + 2 * len(self.harmonics)

    @property
    def kmax(self) -> int:
        """Highest harmonic."""
        return self.harmonics[-1]

    @cached_property
    def k(self) -> np.ndarray:
        """Harmonic numbers as an integer array."""
        return np.array(self.harmonics, dtype=int)

    @cached_property
    def a_index(self) -> np.ndarray:
        """Positions of ``a_k`` in ``u``."""
        return int(self.bias) + 2 * np.arange(len(self.harmonics))

    @cached_property
    def b_index(self) -> np.ndarray:
        """Positions of ``b_k`` in ``u``."""
        return self.a_index + 1

    def index_of(self, k: int) -> int | None:
        """Position of ``a_k`` in ``u`` (``b_k`` follows), or None if ``k`` is not in the basis."""
        try:
            return int(self.bias) + 2 * self.harmonics.index(int(k))
        except ValueError:
            return None

    def check(self, u: ArrayLike) -> np.ndarray:
        """``u`` as a float array whose last dimension is :attr:`size`.

        Raises
        ------
        ParameterError
            For another last dimension.
        """
        arr = np.asarray(u, dtype=float)
        if arr.shape[-1:] != (self.size,):
            raise ParameterError(
                f"coefficient vector of shape {arr.shape}: expected last dimension {self.size}"
            )
        return arr

    # ---- evaluation --------------------------------------------------------------------------
    def split(self, u: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(a0, a, b)`` from ``u`` (``a0`` zero without bias); works along the last axis."""
        arr = self.check(u)
        a0 = arr[..., 0] if self.bias else np.zeros(arr.shape[:-1])
        return a0, arr[..., self.a_index], arr[..., self.b_index]

    def design(self, theta: ArrayLike, derivative: int = 0) -> np.ndarray:
        """Matrix ``Phi`` with ``x^(derivative)(theta) = Phi @ u``, shape ``(len(theta), n)``."""
        th = np.asarray(theta, dtype=float).reshape(-1)
        ks = self.k.astype(float)
        arg = np.outer(th, ks)
        c, s = np.cos(arg), np.sin(arg)
        # d^j/dtheta^j of (cos, sin) cycles through (cos, sin) -> (-sin, cos) -> ...
        cols_c, cols_s = [(c, s), (-s, c), (-c, -s), (s, -c)][derivative % 4]
        scale = ks**derivative
        out = np.zeros((th.size, self.size))
        if self.bias and derivative == 0:
            out[:, 0] = 1.0
        out[:, self.a_index] = cols_c * scale
        out[:, self.b_index] = cols_s * scale
        return out

    def evaluate(self, u: ArrayLike, theta: ArrayLike, derivative: int = 0) -> np.ndarray:
        """``x(theta)`` (or its ``derivative``-th derivative in ``theta``)."""
        arr = self.check(u)
        return arr @ self.design(theta, derivative).T

    def derivative_matrix(self) -> np.ndarray:
        """``D`` with ``x_theta = Phi @ (D @ u)``: ``(a_k, b_k) -> (k b_k, -k a_k)``."""
        D = np.zeros((self.size, self.size))
        ia, ib, ks = self.a_index, self.b_index, self.k
        D[ia, ib] = ks
        D[ib, ia] = -ks
        return D

    def complex_coefficients(self, u: ArrayLike) -> np.ndarray:
        """``X`` of length ``kmax + 1``: ``x = Re(X_0) + 2 Re sum_k X_k e^{ik theta}``,
        ``X_0 = a0``, ``X_k = (a_k - i b_k)/2`` (zero for harmonics outside the basis)."""
        a0, a, b = self.split(u)
        X = np.zeros(np.shape(a0) + (self.kmax + 1,), dtype=complex)
        X[..., 0] = a0
        X[..., self.k] = 0.5 * (a - 1j * b)
        return X


# =============================================================================================
# crossings of a truncated Fourier series
# =============================================================================================
class _Grid:
    """Design matrices of one basis on the isolation grid (``x`` at the endpoints, ``x`` and
    its first two derivatives at the midpoints, stacked for one matrix-vector product per
    signal), and the harmonic tables of the evaluations, shared by every evaluation."""

    def __init__(self, basis: HarmonicBasis) -> None:
        N = max(_GRID_MIN, _GRID_PER_HARMONIC * basis.kmax)
        self.N = N
        self.h = _TWO_PI / N
        self.points = self.h * np.arange(N + 1)
        self.points[-1] = _TWO_PI
        self.lo, self.hi = self.points[:-1].copy(), self.points[1:].copy()
        mids = self.points[:-1] + 0.5 * self.h
        # rows: x, x', x'' at the midpoints, then x at the left ends (the crossing search
        # appends x(0) as the value at 2 pi)
        self.stack = np.concatenate(
            [basis.design(mids, j) for j in range(3)] + [basis.design(self.points[:-1])]
        )
        ks = basis.k.astype(float)
        self.ks = ks
        self.iks = 1j * ks
        # the layout [a0,] a_1, b_1, a_2, b_2, ... (HarmonicBasis's)
        self.contiguous = bool(
            np.array_equal(basis.a_index, int(basis.bias) + 2 * np.arange(ks.size))
            and np.array_equal(basis.b_index, basis.a_index + 1)
        )
        self.k_pow = np.array([ks**j for j in range(5)])
        # (i k)^j, j = 0..3: the derivatives of e^{ik theta}
        self.ik_pow = (1j * ks[:, None]) ** np.arange(4)
        self.ik_pow3 = np.ascontiguousarray(self.ik_pow[:, :3])
        self._levels: dict[bytes, _LevelTables] = {}

    def tables(self, levels: np.ndarray) -> _LevelTables:
        """The tables of the crossing search at ``levels`` (cached: a few sets, a few MB)."""
        key = levels.tobytes()
        t = self._levels.get(key)
        if t is None:
            t = _LevelTables(self, levels)
            if (
                len(self._levels) >= _LEVEL_TABLES
                or sum(v.stack.nbytes for v in self._levels.values()) + t.stack.nbytes
                > _LEVEL_TABLES_BYTES
            ):
                self._levels.clear()
            self._levels[key] = t
        return t


class _LevelTables:
    """The isolation grid tiled once per level, so that every test of the crossing search is
    one elementwise operation on flat arrays of ``L N`` cells (level-major: cell ``i`` of
    level ``l`` at ``l N + i``), without broadcasting."""

    def __init__(self, grid: _Grid, levels: np.ndarray) -> None:
        N, L = grid.N, levels.size
        self.LN = L * N
        r = 0.5 * grid.h
        r2 = 0.5 * r * r
        self.r, self.r2, self.r3 = r, r2, r * r2 / 3.0
        blocks = [grid.stack[j * N : (j + 1) * N] for j in (1, 2, 2, 0, 3)]
        # rows: x', x'', x'', x at the midpoints, x at the left ends, each block L times (all
        # blocks a multiple of 4 rows: the product's rows come out as those of grid.stack)
        self.stack = np.ascontiguousarray(np.concatenate([np.tile(b, (L, 1)) for b in blocks]))
        self.levels2 = np.tile(np.repeat(levels, N), 2)  # for x at the midpoints and ends
        self.abs_max = _abs_max(levels)
        # r |x'|, r^2/2 |x''|, r |x''| from |x'|, |x''|, |x''|; the constants (times B_3) of
        # the exclusion bound and of the monotonicity bound
        self.r_r2_r = np.concatenate(
            [np.full(self.LN, r), np.full(self.LN, r2), np.full(self.LN, r)]
        )
        self.r3_r2 = np.concatenate([np.full(self.LN, self.r3), np.full(self.LN, r2)])
        cells = np.tile(np.arange(N), L)
        self.level = np.repeat(np.arange(L), N)
        self.cell = cells
        self.next = self.level * N + (cells + 1) % N  # the right end of a cell: x(2 pi) = x(0)
        self.lo, self.hi = grid.lo[cells], grid.hi[cells]


_GRIDS: dict[HarmonicBasis, _Grid] = {}


def _grid(basis: HarmonicBasis) -> _Grid:
    g = _GRIDS.get(basis)
    if g is None:
        g = _GRIDS[basis] = _Grid(basis)
    return g


class TruncatedSeries:
    """One truncated series ``x(theta)`` with fast evaluation of its derivatives and the
    bounds ``B_j = sum k^j r_k >= max |x^(j)|``.

    Parameters
    ----------
    basis : HarmonicBasis
    u : numpy.ndarray
        Coefficients of ``x`` (one-dimensional, laid out as ``basis``; not checked: callers
        pass :meth:`HarmonicBasis.check`-ed vectors).

    Attributes
    ----------
    a0 : float
        The mean (0 without bias).
    c : numpy.ndarray
        Complex coefficients ``a_k - i b_k``: ``x = a0 + Re sum_k c_k e^{ik theta}``.
    B : numpy.ndarray
        ``B_j = sum_k k^j |c_k|`` for ``j = 0..4``: bounds of ``max |x^(j)|`` (``j >= 1``).
    scale : float
        ``|a0| + B_0``, a bound of ``max |x|``: the scale of rounding-level tests.
    """

    def __init__(self, basis: HarmonicBasis, u: np.ndarray) -> None:
        self.basis, self.u = basis, u
        grid = self.grid = _grid(basis)
        self.a0 = float(u[0]) if basis.bias else 0.0
        self.ks = grid.ks
        if grid.contiguous and u.dtype == np.float64 and u.flags.c_contiguous:
            # u = [a0,] a_1, b_1, a_2, b_2, ... read as complex a_k + i b_k: c = conj (the
            # numbers of a - 1j b, up to the sign of a zero imaginary part)
            self.c = (u[1:] if basis.bias else u).view(complex).conj()
        else:
            self.c = u[basis.a_index] - 1j * u[basis.b_index]
        # x = a0 + Re sum c_k e^{ik theta}
        self.B = grid.k_pow @ np.abs(self.c)
        self.scale = abs(self.a0) + float(self.B[0])
        self._coefficients: np.ndarray | None = None  # built by values
        self._columns: dict[tuple, np.ndarray] = {}

    @property
    def _derivative_coefficients(self) -> np.ndarray:
        # column j: the complex coefficients of the j-th derivative, c_k (i k)^j, j = 0..3
        if self._coefficients is None:
            self._coefficients = self.c[:, None] * self.grid.ik_pow
        return self._coefficients

    def columns(self, orders: tuple[int, ...]) -> np.ndarray:
        """The coefficient columns ``c_k (i k)^j`` for ``j`` in ``orders`` (cached)."""
        cols = self._columns.get(orders)
        if cols is None:
            cols = self._columns[orders] = self._derivative_coefficients[:, list(orders)]
        return cols

    def values(self, theta: np.ndarray, orders: Sequence[int] = (0,)) -> list[np.ndarray]:
        """``x`` and its derivatives in ``theta``.

        Parameters
        ----------
        theta : numpy.ndarray
            Angles (any shape).
        orders : sequence of int
            Derivative orders, each in ``0..3``.

        Returns
        -------
        list of numpy.ndarray
            One array shaped like ``theta`` per order, in the order asked.
        """
        e = np.exp(np.multiply.outer(theta, self.grid.iks))
        # one matrix product for every order asked (the root polishing asks for three); the
        # columns of each tuple of orders gathered once per series
        key = tuple(orders)
        vals = (e @ self.columns(key)).real
        out = []
        for col, j in enumerate(key):
            out.append(vals[..., col] + self.a0 if j == 0 else vals[..., col])
        return out


def _taylor_tests(x0, x1, x2, x3, r, B, slack):
    """The three isolation tests on intervals of half-width ``r`` from the derivatives at the
    midpoint (third-order Taylor bounds with the global ``B_3``, ``B_4``): no root of
    ``x - d`` (``x0`` is ``x(c) - d``), ``x`` monotone, ``x'`` monotone."""
    r2 = 0.5 * r * r
    B3, B4 = float(B[3]), float(B[4])  # Python floats: the same double arithmetic, cheaper
    excluded = abs(x0) > r * abs(x1) + r2 * abs(x2) + (r * r2 / 3.0) * B3 + slack
    monotone = abs(x1) > r * abs(x2) + r2 * B3 + slack
    one_extremum = abs(x2) > r * abs(x3) + r2 * B4 + slack
    return excluded, monotone, one_extremum


def _sign_change(e0: float, e1: float) -> bool:
    return (e0 >= 0.0) != (e1 >= 0.0)


def _extremum(series: TruncatedSeries, a: float, b: float, d1a: float, d1b: float) -> float:
    """The zero of ``x'`` in ``[a, b]`` (``x'`` monotone there, opposite signs at the ends)."""
    lo, hi, flo = a, b, d1a
    t = a - d1a * (b - a) / (d1b - d1a)
    iks, cols = series.grid.iks, series.columns((1, 2))
    for _ in range(60):
        # series.values(np.array([t]), (1, 2)), the same product
        ((d1, d2),) = (np.exp(np.multiply.outer(np.array([t]), iks)) @ cols).real.tolist()
        if d1 == 0.0:
            return t
        if (d1 > 0) == (flo > 0):
            lo, flo = t, d1
        else:
            hi = t
        step = d1 / d2 if d2 != 0.0 else np.inf
        tn = t - step
        if not (lo < tn < hi):
            tn = 0.5 * (lo + hi)
        if abs(tn - t) <= 4e-16 * max(1.0, abs(t)) or hi - lo <= 4e-16 * max(1.0, abs(t)):
            return tn
        t = tn
    return t


def _isolate_hard(
    series: TruncatedSeries,
    d: float,
    a: float,
    b: float,
    ea: float,
    eb: float,
    slack: float,
    depth: int,
) -> list[tuple[float, float, float, float]]:
    """Root brackets ``(lo, hi, e_lo, e_hi)`` of ``x - d`` in ``[a, b]`` when the grid tests
    were inconclusive: at most one extremum -> locate it and split; else bisect."""
    c, r = 0.5 * (a + b), 0.5 * (b - a)
    x0, x1, x2, x3 = (float(v[0]) for v in series.values(np.array([c]), (0, 1, 2, 3)))
    e = x0 - d
    excluded, monotone, one_extremum = _taylor_tests(e, x1, x2, x3, r, series.B, slack)
    if excluded:
        return []
    if abs(e) + r * abs(x1) + 0.5 * r * r * abs(x2) + (r**3 / 6.0) * series.B[3] <= slack:
        # x stays within rounding of d on the whole interval (x == d constant, the zero
        # signal on a breakpoint at 0): no crossing, and bisecting it would never decide
        return []
    if monotone or depth >= _MAX_DEPTH:
        return [(a, b, ea, eb)] if _sign_change(ea, eb) else []
    if one_extremum:
        d1a, d1b = (float(v) for v in series.values(np.array([a, b]), (1,))[0])
        # an x' within rounding of zero at an end is an extremum there (grid points on an
        # exact tangency: x'(2 pi) comes out as +-1e-16)
        flat = 64 * _EPS * float(series.B[1])
        if abs(d1a) <= flat:
            te = a
        elif abs(d1b) <= flat:
            te = b
        elif d1a * d1b > 0.0:
            return [(a, b, ea, eb)] if _sign_change(ea, eb) else []
        else:
            te = _extremum(series, a, b, d1a, d1b)
        ee = float(series.values(np.array([te]), (0,))[0][0]) - d
        if abs(ee) <= slack:
            return []  # a tangency: x touches d and turns back, no switch
        out = []
        if te > a and _sign_change(ea, ee):
            out.append((a, te, ea, ee))
        if te < b and _sign_change(ee, eb):
            out.append((te, b, ee, eb))
        return out
    return _isolate_hard(series, d, a, c, ea, e, slack, depth + 1) + _isolate_hard(
        series, d, c, b, e, eb, slack, depth + 1
    )


def _polish(
    series: TruncatedSeries,
    lo: np.ndarray,
    hi: np.ndarray,
    elo: np.ndarray,
    ehi: np.ndarray,
    d: np.ndarray,
):
    """Roots of ``x - d`` in monotone brackets, and ``x'`` there.

    Halley's iteration (cubic) from the regula-falsi point, all brackets at once (two or
    three steps on these short brackets) until the residual is at rounding level, then one
    Newton step. Brackets that do not get there (a root next to an extremum, where the steps
    are small long before the root is reached), or whose iterate leaves the bracket, are redone
    by the safeguarded Newton-bisection of :func:`_polish_safe`."""
    ftol = _residual_floor(series, d)
    # x, x', x'' in one product per step: e^{ik t} times the columns c_k (i k)^j
    # (columns 0..2 of _derivative_coefficients, the same numbers, contiguous)
    grid, a0 = series.grid, series.a0
    iks, coef = grid.iks, series.c[:, None] * grid.ik_pow3
    width = hi - lo
    t = lo - elo * width / (ehi - elo)
    converged = False
    with np.errstate(all="ignore"):
        for _ in range(7):
            vals = (np.exp(np.multiply.outer(t, iks)) @ coef).real
            f = (vals[:, 0] + a0) - d
            x1 = vals[:, 1]
            if np.abs(f).max() <= ftol:  # NaN compares False, as np.all did
                converged = True
                break
            x2 = vals[:, 2]
            t = t - 2.0 * f * x1 / (2.0 * x1 * x1 - f * x2)
        t_new = t - f / x1
    margin = 1e-12 * width
    inside = (t_new >= lo - margin) & (t_new <= hi + margin)
    if converged:
        if inside.all():
            return t_new, x1
        bad = ~inside
    else:
        bad = (np.abs(f) > ftol) | ~inside
    t_new[bad], x1[bad] = _polish_safe(series, lo[bad], hi[bad], elo[bad], d[bad])
    return t_new, x1


def _polish_scalar(series, lo, hi, elo, ehi, d):
    """:func:`_polish` with the arithmetic of the few roots in Python floats (the same IEEE
    operations in the same order, so the same numbers; only the evaluation is a numpy
    product), the angles and ``x'`` as lists: the common case, when every root converges
    inside its bracket; None otherwise (a zero division too), and :func:`_polish` runs."""
    ftol = _residual_floor(series, d)
    grid, a0 = series.grid, series.a0
    iks, coef = grid.iks, series.c[:, None] * grid.ik_pow3
    lo_l, hi_l, d_l = lo.tolist(), hi.tolist(), d.tolist()
    width = [b - a for a, b in zip(lo_l, hi_l, strict=True)]
    try:
        t = [
            a - ea * w / (eb - ea)
            for a, w, ea, eb in zip(lo_l, width, elo.tolist(), ehi.tolist(), strict=True)
        ]
        for _ in range(7):
            vals = (np.exp(np.multiply.outer(np.array(t), iks)) @ coef).real.tolist()
            f = [(v[0] + a0) - di for v, di in zip(vals, d_l, strict=True)]
            if all(map(ftol.__ge__, map(abs, f))):  # NaN compares False
                break
            t = [
                ti - 2.0 * fi * v[1] / (2.0 * v[1] * v[1] - fi * v[2])
                for ti, fi, v in zip(t, f, vals, strict=True)
            ]
        else:
            return None
        t_new = [ti - fi / v[1] for ti, fi, v in zip(t, f, vals, strict=True)]
    except ZeroDivisionError:
        return None
    for tn, a, b, w in zip(t_new, lo_l, hi_l, width, strict=True):
        margin = 1e-12 * w
        if not (tn >= a - margin and tn <= b + margin):
            return None
    return t_new, [v[1] for v in vals]


def _residual_floor(series: TruncatedSeries, d: np.ndarray) -> float:
    """``|x - d|`` at rounding level: the evaluation's own error bound."""
    return 64.0 * _EPS * (series.scale + _abs_max(d))


def _polish_safe(
    series: TruncatedSeries, lo: np.ndarray, hi: np.ndarray, elo: np.ndarray, d: np.ndarray
):
    """Safeguarded Newton (bisection fallback) on monotone brackets, until the residual is at
    rounding level or the bracket at the resolution of the angle."""
    ftol = _residual_floor(series, d)
    lo, hi, elo = lo.copy(), hi.copy(), elo.copy()
    t = 0.5 * (lo + hi)
    act = np.arange(t.size)
    for _ in range(200):
        ta = t[act]
        x, xd = series.values(ta, (0, 1))
        e = x - d[act]
        same = (e >= 0.0) == (elo[act] >= 0.0)
        lo_a = np.where(same, ta, lo[act])
        hi_a = np.where(same, hi[act], ta)
        elo[act] = np.where(same, e, elo[act])
        lo[act], hi[act] = lo_a, hi_a
        with np.errstate(divide="ignore", invalid="ignore"):
            tn = ta - e / xd
        inside = np.isfinite(tn) & (tn > lo_a) & (tn < hi_a)
        conv = (np.abs(e) <= ftol) | (hi_a - lo_a <= 4e-16 * np.maximum(1.0, np.abs(ta)))
        t[act] = np.where(conv, ta, np.where(inside, tn, 0.5 * (lo_a + hi_a)))
        act = act[~conv]
        if act.size == 0:
            break
    x, xd = series.values(t, (0, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        step = (x - d) / xd
    ok = np.isfinite(step) & (t - step >= lo) & (t - step <= hi)
    return np.where(ok, t - step, t), xd


def _crossings(series: TruncatedSeries, levels: np.ndarray, as_lists: bool = False) -> tuple:
    """All crossings of ``x(theta) = d`` for ``d`` in ``levels``: sorted angles in
    ``[0, 2 pi)``, the level index of each and ``x'`` there (arrays; Python lists with
    ``as_lists`` when the few-roots path found them, for :func:`crossing_intervals`)."""
    if not math.isfinite(series.scale):
        # NaN/inf coefficients defeat every isolation test (each cell would be bisected to
        # the depth cap: 2^40 calls)
        raise ParameterError(
            f"the signal's Fourier coefficients must be finite, got bound {series.scale!r}"
        )
    grid = series.grid
    T = grid.tables(levels)
    LN = T.LN
    v = T.stack @ series.u
    a = np.abs(v[: 3 * LN])  # |x'|, |x''|, |x''| at the midpoints
    slack = 64 * _EPS * (series.scale + T.abs_max)
    # the exclusion and monotonicity tests of _taylor_tests, the same expressions in the
    # same order (the extremum test is not needed on the grid):
    # |x - d| > r |x'| + r^2/2 |x''| + r^3/6 B_3 + slack and |x'| > r |x''| + r^2/2 B_3 + slack
    p = a * T.r_r2_r
    w = p[LN:]  # (r |x'| + r^2/2 |x''|, r |x''|)
    np.add(p[:LN], w[:LN], out=w[:LN])
    w += T.r3_r2 * series.B[3]
    w += slack
    xd = v[3 * LN :] - T.levels2  # x - d at the midpoints, then at the left ends
    excluded = np.abs(xd[:LN]) > w[:LN]
    monotone = a[:LN] > w[LN:]
    e = xd[LN:]
    pos = e >= 0.0
    # on booleans a > b is a & ~b: monotone, not excluded, and a sign change
    simple = ((monotone > excluded) & (pos != pos[T.next])).nonzero()[0]
    lo = T.lo[simple]
    hi = T.hi[simple]
    elo = e[simple]
    ehi = e[T.next[simple]]
    level_idx = T.level[simple]
    settled = excluded | monotone
    if not np.logical_and.reduce(settled):  # hard cells: neither excluded nor monotone
        hard = (~settled).nonzero()[0]
        hard_l, hard_i = T.level[hard], T.cell[hard]
        e_a, e_b = e[hard], e[T.next[hard]]
        points = grid.points
        extra = []
        for j, i, ea, eb in zip(hard_l, hard_i, e_a.tolist(), e_b.tolist(), strict=True):
            for a, b, ea_, eb_ in _isolate_hard(
                series, float(levels[j]), points[i], points[i + 1], ea, eb, slack, 0
            ):
                extra.append((a, b, ea_, eb_, j))
        if extra:
            ex = np.array(extra)
            lo = np.concatenate([lo, ex[:, 0]])
            hi = np.concatenate([hi, ex[:, 1]])
            elo = np.concatenate([elo, ex[:, 2]])
            ehi = np.concatenate([ehi, ex[:, 3]])
            level_idx = np.concatenate([level_idx, ex[:, 4].astype(int)])
    if lo.size == 0:
        return np.empty(0), np.empty(0, dtype=int), np.empty(0)
    d = levels[level_idx]
    if lo.size <= _SCALAR_ROOTS:
        out = _polish_scalar(series, lo, hi, elo, ehi, d)
        if out is not None:
            # np.mod and a stable argsort, in Python: the same remainder (fmod, then the
            # sign of the divisor) and the same order
            t, x1 = out
            theta = [ti % _TWO_PI for ti in t]
            order = sorted(range(len(theta)), key=theta.__getitem__)
            lev = level_idx.tolist()
            found = [theta[i] for i in order], [lev[i] for i in order], [x1[i] for i in order]
            if as_lists:
                return found
            return np.array(found[0]), np.array(found[1], dtype=level_idx.dtype), np.array(found[2])
    theta, d1 = _polish(series, lo, hi, elo, ehi, d)
    theta = np.mod(theta, _TWO_PI)
    order = np.argsort(theta, kind="stable")
    return theta[order], level_idx[order], d1[order]


def _abs_max(a: np.ndarray) -> float:
    """``max |a|`` (0 for an empty array) of finite levels (breakpoints are finite); Python's
    max on a few elements is cheaper than the numpy call."""
    if a.size <= 8:
        return max(map(abs, a.tolist()), default=0.0)
    return float(np.abs(a).max(initial=0.0))


def switching_angles(basis: HarmonicBasis, u: ArrayLike, level: float) -> np.ndarray:
    """All angles ``theta`` in ``[0, 2 pi)`` where ``x(theta)`` crosses ``level``.

    Tangential touches (``x`` reaches ``level`` within rounding and turns back) are not
    crossings and are not returned; see the module docstring for the isolation method.

    Parameters
    ----------
    basis : HarmonicBasis
    u : array_like
        Coefficients ``[a0, a_1, b_1, ...]``.
    level : float

    Returns
    -------
    numpy.ndarray
        Sorted crossing angles.
    """
    u = basis.check(u).reshape(-1)
    level = float(level)
    if not math.isfinite(level):
        raise ParameterError(f"level = {level!r}: expected a finite number")
    theta, _, _ = _crossings(TruncatedSeries(basis, u), np.array([level]))
    return theta


# =============================================================================================
# exact Galerkin projection of a piecewise-linear force
# =============================================================================================
@dataclass(frozen=True, eq=False)
class CrossingIntervals:
    """The crossing intervals of one signal: where ``x(theta)`` stays in one segment of a
    piecewise-linear force.

    Attributes
    ----------
    start : numpy.ndarray
        Start angle of each interval, sorted in ``[0, 2 pi)`` (a crossing angle; ``[0.]``
        when there is no crossing).
    length : numpy.ndarray
        Length of each interval (the last wraps around ``2 pi``); the lengths sum to ``2 pi``.
    segment : numpy.ndarray
        Segment index of the force on each interval (as :meth:`NumericPWL.segment_index`).
    d1 : numpy.ndarray
        ``x'(theta)`` at each crossing (the start of each interval); empty when there is no
        crossing.
    """

    start: np.ndarray
    length: np.ndarray
    segment: np.ndarray
    d1: np.ndarray


def crossing_intervals(
    pwl: NumericPWL, basis: HarmonicBasis, series: TruncatedSeries
) -> CrossingIntervals:
    """Split one period of ``x(theta)`` at its crossings of the breakpoints of ``pwl``.

    Parameters
    ----------
    pwl : NumericPWL
        The force whose breakpoints are the levels.
    basis : HarmonicBasis
        The basis of ``series`` (kept for the signature shared with the callers).
    series : TruncatedSeries
        The signal ``x(theta)``.

    Returns
    -------
    CrossingIntervals
        With one interval (the segment of the mean) when ``x`` crosses no breakpoint;
        tangential touches are not crossings (see the module docstring).
    """
    bps = pwl.breakpoints
    if bps.size == 0:
        return CrossingIntervals(np.zeros(1), np.array([_TWO_PI]), np.array([0]), np.zeros(0))
    theta, level, d1 = _crossings(series, bps, as_lists=True)
    if isinstance(theta, list):
        # the same differences and sums as below, in Python floats
        length = [b - a for a, b in zip(theta, theta[1:], strict=False)]
        length.append(theta[0] + _TWO_PI - theta[-1])
        seg = [j + (x > 0.0) for j, x in zip(level, d1, strict=True)]
        return CrossingIntervals(np.array(theta), np.array(length), np.array(seg), np.array(d1))
    if theta.size == 0:
        # no crossing: x stays in one closed segment, whose interior holds the mean
        seg = pwl.segment_index(np.array([series.a0]))
        return CrossingIntervals(np.zeros(1), np.array([_TWO_PI]), seg, np.zeros(0))
    length = np.empty(theta.size)
    length[:-1] = theta[1:] - theta[:-1]
    length[-1] = theta[0] + _TWO_PI - theta[-1]
    # crossing breakpoint j upwards enters segment j + 1, downwards segment j
    seg = level + (d1 > 0.0)
    return CrossingIntervals(theta, length, seg, d1)


class ExactProjector:
    """``proj(u)`` and its Jacobian for a numeric PWL force on a basis.

    The index tables of the convolution and of the real/complex layouts are built once, so
    one projector serves every evaluation of a Newton iteration or a continuation.

    Parameters
    ----------
    pwl : NumericPWL
        The force ``f(x)``.
    basis : HarmonicBasis
        The basis of ``x`` and of the projection.

    Attributes
    ----------
    continuous : bool
        Whether the force has no jumps (then the Jacobian is the Toeplitz matrix alone).
    """

    def __init__(self, pwl: NumericPWL, basis: HarmonicBasis) -> None:
        self.pwl, self.basis = pwl, basis
        self.continuous = bool(np.all(pwl.jumps == 0.0))
        K = basis.kmax
        self.K = K
        ks = basis.k
        # complex indices of x: -k (descending), 0 (bias), +k
        n_idx = np.concatenate([-ks[::-1], [0] if basis.bias else [], ks]).astype(int)
        j_idx = np.concatenate([[0] if basis.bias else [], ks]).astype(int)
        self.n_idx, self.j_idx = n_idx, j_idx
        self.n_freq = np.arange(1, 2 * K + 1)
        # -i n for e^{-i n theta_c}, n = 1..2K
        self._minus_in = -1j * self.n_freq
        # the weights i / (2 pi n) of Q_n, C_n as real factors of (Re, Im) of sum_c ds_c
        # e^{-i n theta_c}: (Re Q_n, Im Q_n) = w_n (-Im, Re)
        self._w = (1j / (_TWO_PI * self.n_freq)).imag
        self._slopes = np.ascontiguousarray(pwl.slopes, dtype=float)
        self._offsets = np.ascontiguousarray(pwl.offsets, dtype=float)
        self._before: dict[int, np.ndarray] = {}
        self._gather_tables(basis)

    def _gather_tables(self, basis: HarmonicBasis) -> None:
        """Index tables of the real Jacobian and constant term as sums of two entries of the
        spectrum buffers of :meth:`_spectra` read as floats.

        With ``x``'s complex coefficients ``X_{+-k} = (a_k -+ i b_k)/2`` and ``G_j = sum_n
        Q_{j-n} X_n`` (``Q_{-m} = conj Q_m``), the real rows ``Re G_0, 2 Re G_j, -2 Im G_j``
        are, column by column (``a0``, ``a_k``, ``b_k``)::

            a0 row:  Re Q_0            Re Q_k                   -Im Q_k
            a_j row: 2 Re Q_j          Re Q_{j-k} + Re Q_{j+k}  Im Q_{j-k} - Im Q_{j+k}
            b_j row: -2 Im Q_j         -Im Q_{j-k} - Im Q_{j+k}  Re Q_{j-k} - Re Q_{j+k}

        and the constant ``Re C_0, 2 Re C_j, -2 Im C_j``: each entry a sum of two signed
        entries (a single one plus an exact zero). The factors 1/2 and 2 of the complex
        assembly are exact, so these sums round as it did.
        """
        S = 2 * self.K + 1

        def re(kind: int, m: int, sign: int) -> int:
            # sign * Re X_m (X = Q for kind 0, C for kind 1); Re X_{-m} = Re X_m
            return (((1 if sign > 0 else 0) * 2 + kind) * S + abs(m)) * 2 + 1

        def im(kind: int, m: int, sign: int) -> int:
            # sign * Im X_m; Im X_{-m} = -Im X_m, Im X_0 = 0 (the zero at index 0)
            if m == 0:
                return 0
            s = sign * (1 if m > 0 else -1)
            return (((0 if s > 0 else 1) * 2 + kind) * S + abs(m)) * 2

        n = basis.size
        I1 = np.zeros((n, n), dtype=np.intp)
        I2 = np.zeros((n, n), dtype=np.intp)
        c1 = np.zeros(n, dtype=np.intp)
        c2 = np.zeros(n, dtype=np.intp)
        ia, ib = basis.a_index, basis.b_index
        ks = [int(k) for k in basis.k]
        if basis.bias:
            I1[0, 0] = re(0, 0, 1)
            c1[0] = re(1, 0, 1)
            for q, k in enumerate(ks):
                I1[0, ia[q]] = re(0, k, 1)
                I1[0, ib[q]] = im(0, k, -1)
        for p, j in enumerate(ks):
            aj, bj = ia[p], ib[p]
            c1[aj] = c2[aj] = re(1, j, 1)
            c1[bj] = c2[bj] = im(1, j, -1)
            if basis.bias:
                I1[aj, 0] = I2[aj, 0] = re(0, j, 1)
                I1[bj, 0] = I2[bj, 0] = im(0, j, -1)
            for q, k in enumerate(ks):
                ak, bk = ia[q], ib[q]
                I1[aj, ak], I2[aj, ak] = re(0, j - k, 1), re(0, j + k, 1)
                I1[aj, bk], I2[aj, bk] = im(0, j + k, -1), im(0, j - k, 1)
                I1[bj, ak], I2[bj, ak] = im(0, j - k, -1), im(0, j + k, -1)
                I1[bj, bk], I2[bj, bk] = re(0, j + k, -1), re(0, j - k, 1)
        # the constant as one more row: one pair of gathers for both
        self._I1, self._I2 = np.vstack([I1, c1]), np.vstack([I2, c2])

    def _spectra(
        self, pc: CrossingIntervals, with_jumps: bool
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The spectra of ``Q_n, C_n`` for ``n = 0..2K`` (and of the jump part of ``Q`` for
        the Jacobian, else None) as complex buffers ``F[sign, kind, n]`` (``kind`` 0 for
        ``Q``, 1 for ``C``): ``F[0, kind, n] = -i X_n = Im X_n - i Re X_n``, ``F[1] = -F[0]``;
        read as floats, the entries that :meth:`_gather_tables` indexes."""
        S = 2 * self.K + 1
        F = np.empty((2, 2, S), dtype=complex)
        F0 = F[0]
        seg = pc.segment
        s, o = self._slopes[seg], self._offsets[seg]  # of each interval
        q0 = float(np.add.reduce(s * pc.length)) / _TWO_PI  # = np.sum (pairwise)
        c0 = float(np.add.reduce(o * pc.length)) / _TWO_PI
        F0[:, 0] = (complex(0.0, -q0), complex(0.0, -c0))
        M = pc.d1.size
        if M == 0:
            F0[:, 1:] = 0.0
            np.negative(F0, out=F[1])
            return F, None
        before = self._before.get(M)
        if before is None:
            before = self._before[M] = np.arange(-1, M - 1)  # the interval ending at c
        ds = s[before] - s  # the jumps of slope and offset at each crossing
        do = o[before] - o
        # -i Q_n = w_n sum_c ds_c e^{-i n theta_c}, w_n = 1 / (2 pi n) (likewise C): the
        # products of the complex assembly
        E = np.exp(np.multiply.outer(self._minus_in, pc.start))  # (2K, M)
        w = self._w
        np.multiply(E @ ds, w, out=F0[0, 1:])
        np.multiply(E @ do, w, out=F0[1, 1:])
        np.negative(F0, out=F[1])
        Z = None
        if with_jumps and not self.continuous:
            x_c = self.pwl.breakpoints[np.minimum(seg, seg[before])]
            jump = (-(ds) * x_c - do) / pc.d1
            jump = np.where(seg == seg[before], 0.0, jump)
            Z = np.zeros((2, 2, S), dtype=complex)
            Z[0, 0, 0] = complex(0.0, -float(np.sum(jump)) / _TWO_PI)
            Z[0, 0, 1:] = -1j * ((E @ jump) * (1.0 / _TWO_PI))
            np.negative(Z[0], out=Z[1])
        return F, Z

    def project(
        self, u: np.ndarray, jacobian: bool = True, series: TruncatedSeries | None = None
    ) -> tuple[np.ndarray, np.ndarray | None, CrossingIntervals]:
        """The projection of ``f(x(theta))``, its Jacobian and the crossing intervals.

        Parameters
        ----------
        u : numpy.ndarray
            Coefficients of ``x`` (one-dimensional float array, not checked: see
            :func:`pwl_projection` for the checked entry point).
        jacobian : bool
            Also return ``d proj / d u``.
        series : TruncatedSeries, optional
            ``x`` already built from ``u`` (saves rebuilding it).

        Returns
        -------
        proj : numpy.ndarray
            Laid out like ``u``.
        jac : numpy.ndarray or None
            Shape ``(n, n)`` with ``jacobian``, including the derivative of the moving
            switches of a discontinuous force; None otherwise.
        pieces : CrossingIntervals
            The crossing intervals of ``x`` (e.g. for the exact monodromy).
        """
        series = series if series is not None else TruncatedSeries(self.basis, u)
        pc = crossing_intervals(self.pwl, self.basis, series)
        F, Z = self._spectra(pc, jacobian)
        # f(x(theta)) = q x + c exactly, so proj = (Toeplitz(Q) P) u + C: the matrix is the
        # Jacobian of a continuous force
        F = F.view(float).reshape(-1)
        G = F[self._I1] + F[self._I2]  # (n + 1, n): the matrix, then the constant
        n = G.shape[1]
        TP = G[:n]
        proj = TP @ u + G[n]
        if not jacobian:
            return proj, None, pc
        if Z is not None:
            Z = Z.view(float).reshape(-1)
            TP = TP + (Z[self._I1[:n]] + Z[self._I2[:n]])
        return proj, TP, pc


def pwl_projection(
    pwl: NumericPWL, basis: HarmonicBasis, u: ArrayLike, *, jacobian: bool = False
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Exact Galerkin projection of a piecewise-linear force on a truncated Fourier series.

    Parameters
    ----------
    pwl : NumericPWL
        The force ``f(x)`` (e.g. ``oscillator.piecewise_linear().numeric()``).
    basis : HarmonicBasis
    u : array_like
        Coefficients of ``x(theta)``.
    jacobian : bool
        Also return ``d proj / d u``.

    Returns
    -------
    proj : numpy.ndarray
        ``[(1/2pi) int f, (1/pi) int f cos k theta, (1/pi) int f sin k theta, ...]`` over
        ``[0, 2 pi)``, laid out like ``u`` (no constant entry without bias).
    jac : numpy.ndarray
        Shape ``(n, n)``, with ``jacobian=True``; for a discontinuous force it includes the
        derivative of the moving switches (module docstring).
    """
    if not isinstance(pwl, NumericPWL):
        raise ParameterError(f"pwl = {pwl!r}: expected a NumericPWL (PiecewiseLinear.numeric())")
    u = basis.check(u).reshape(-1).astype(float)
    if not np.all(np.isfinite(u)):
        raise ParameterError("u: expected finite coefficients")
    proj, J, _ = ExactProjector(pwl, basis).project(u, jacobian)
    return (proj, J) if jacobian else proj
