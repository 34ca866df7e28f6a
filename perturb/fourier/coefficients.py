"""Closed-form Fourier coefficients of piecewise-linear (Heaviside) nonlinearities.

Convention
----------
Under the single-harmonic ansatz ``x = A cos(psi) + b`` (amplitude ``A >= 0``, bias ``b``) a
function ``g(x)`` becomes an even, 2*pi-periodic function of ``psi``::

    g(A cos psi + b) = a0/2 + sum_{n>=1} a_n cos(n psi),
    a_n = (1/pi) int_{-pi}^{pi} g(A cos psi + b) cos(n psi) dpsi

so ``a0`` is *twice* the mean.  For a breakpoint ``d`` the switching ("crossing") angle is
``theta = arccos((d - b)/A)`` in ``[0, pi]``: ``x > d`` exactly for ``|psi| < theta``.
Without a crossing the angle is clipped: ``theta = 0`` when ``d - b >= A`` (the switch is never
on; grazing from below counts as never on) and ``theta = pi`` when ``d - b <= -A`` (always on).

Two layers
----------
*Numeric* (vectorised numpy, broadcasting over ``n``, ``A``, ``b``, ``d``): ``step_coefficients``,
``ramp_coefficients``, ``dirac_coefficients``, ``abs_coefficients``, ``sign_coefficients``,
``saturation_coefficients``, ``deadzone_coefficients``, ``power_coefficients`` and the general
``pwl_coefficients``.  They use cancellation-free forms (reflection about ``theta = pi/2``,
compensated breakpoint distances, a double series for the ramp at small ``n*theta``), so they
are accurate to ~1e-13 relative (or ~1e-16 times the natural scale) for ``n`` up to 1e4 and
beyond, including grazing.

*Symbolic* (SymPy): :class:`FourierSeries` objects built by :func:`step_series`,
:func:`ramp_series` and :func:`dirac_series`, in the textbook ``theta``-form the literature uses
(``a_n = 2 sin(n theta)/(n pi)`` ...), with ``theta`` kept as a symbol and its definition in
``definitions``; :meth:`FourierSeries.piecewise` adds the exact no-crossing regimes.  The two
layers are implemented independently (the stable numeric forms are not the textbook forms), so
tests comparing them are meaningful.

Conventions for the degenerate amplitude ``A = 0`` (``x`` is the constant ``b``): ``a0 = 2 g(b)``
and ``a_n = 0`` for ``n >= 1``; at ``b == d`` the step uses SymPy's ``Heaviside(0) = 1/2``
(and ``sign(0) = 0``), the Dirac term is infinite and raises :class:`~perturb.errors.FourierError`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from typing import NamedTuple

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike, NDArray

from perturb.errors import FourierError

__all__ = [
    "crossing_angle",
    "step_coefficients",
    "ramp_coefficients",
    "dirac_coefficients",
    "abs_coefficients",
    "sign_coefficients",
    "saturation_coefficients",
    "deadzone_coefficients",
    "power_coefficients",
    "pwl_coefficients",
    "FourierSeries",
    "Regime",
    "step_series",
    "ramp_series",
    "dirac_series",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_TWO_OVER_PI = 2.0 / math.pi
_MAX_POWER = 1000

# ---------------------------------------------------------------------------------------------
# input validation
# ---------------------------------------------------------------------------------------------


def _first_bad(arr: np.ndarray, bad: np.ndarray) -> tuple[float, str]:
    """Return the first offending value of ``arr`` (where ``bad``) and a location suffix."""
    idx = tuple(int(i) for i in np.argwhere(bad)[0]) if arr.ndim else ()
    where = f" at index {idx}" if arr.ndim else ""
    return arr[idx] if idx else arr[()], where


def _as_real(name: str, value: ArrayLike, *, nonnegative: bool = False) -> FloatArray:
    """Convert ``value`` to a float array, rejecting non-numeric, non-finite (and negative)."""
    expected = "a finite real number >= 0" if nonnegative else "a finite real number"
    try:
        arr = np.asarray(value)
    except Exception as exc:  # ragged sequences and the like
        raise FourierError(
            f"{name} must be {expected} (or an array of them), got {value!r}"
        ) from exc
    if arr.dtype.kind not in "iuf":
        # bool, complex, strings, objects: refuse rather than guess what was meant
        raise FourierError(f"{name} must be {expected} (or an array of them), got {value!r}")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr)
    if nonnegative:
        bad |= np.isfinite(arr) & (arr < 0)
    if bad.any():
        v, where = _first_bad(arr, bad)
        raise FourierError(f"{name} must be {expected}, got {name}={float(v)!r}{where}")
    return arr


def _as_scalar(name: str, value: ArrayLike) -> float:
    arr = _as_real(name, value)
    if arr.ndim != 0:
        raise FourierError(f"{name} must be a single finite real number, got shape {arr.shape}")
    return float(arr)


def _as_amplitude(A: ArrayLike) -> FloatArray:
    return _as_real("A", A, nonnegative=True)


def _as_order(n: ArrayLike) -> IntArray:
    """Harmonic indices: integers >= 0 (integral floats such as ``2.0`` are accepted)."""
    expected = "a non-negative integer harmonic index (or an integer array)"
    try:
        arr = np.asarray(n)
    except Exception as exc:
        raise FourierError(f"n must be {expected}, got {n!r}") from exc
    if arr.dtype.kind in "iu":
        out = arr.astype(np.int64)
    elif arr.dtype.kind == "f":
        bad = ~np.isfinite(arr) | (np.floor(arr) != arr)
        if bad.any():
            v, where = _first_bad(arr, bad)
            raise FourierError(f"n must be {expected}, got n={float(v)!r}{where}")
        out = arr.astype(np.int64)
    else:
        raise FourierError(f"n must be {expected}, got {n!r}")
    if (out < 0).any():
        v, where = _first_bad(out, out < 0)
        raise FourierError(f"n must be {expected}, got n={int(v)}{where}")
    return out


def _broadcast(**arrays: np.ndarray) -> tuple[tuple[int, ...], list[np.ndarray]]:
    try:
        shape = np.broadcast_shapes(*(a.shape for a in arrays.values()))
    except ValueError as exc:
        shapes = ", ".join(f"{k}{v.shape}" for k, v in arrays.items())
        raise FourierError(f"argument shapes do not broadcast: {shapes}") from exc
    return shape, [np.broadcast_to(a, shape) for a in arrays.values()]


# ---------------------------------------------------------------------------------------------
# crossing geometry
# ---------------------------------------------------------------------------------------------


def _two_sum(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Knuth's error-free transformation: ``a + b == s + err`` exactly (round-to-nearest)."""
    s = a + b
    bb = s - a
    err = (a - (s - bb)) + (b - bb)
    return s, err


class _Geometry(NamedTuple):
    """Everything the kernels need about one breakpoint ``d`` relative to ``x = A cos psi + b``.

    ``phi`` is the *smaller* of the crossing angle ``theta`` and its complement ``pi - theta``:
    every kernel works with ``phi <= pi/2`` and reflects (``psi -> pi - psi``) when ``d < b``,
    because ``sin(n theta)`` evaluated at ``theta ~ pi`` has an absolute error ``~n*pi*eps``
    that would swamp a value ``~n*(pi - theta)``.
    """

    theta: FloatArray  # crossing angle in [0, pi]
    phi: FloatArray  # theta if up else pi - theta; always in [0, pi/2]
    cos_phi: FloatArray  # cos(phi) = |d - b|/A (clipped to 1)
    sin_theta: FloatArray  # sin(theta) = sin(phi)
    a_sin: FloatArray  # A sin(theta), computed without cancellation
    up: NDArray[np.bool_]  # d >= b: the switch is on for |psi| < theta <= pi/2
    crossing: NDArray[np.bool_]  # |d - b| < A strictly
    tangent: NDArray[np.bool_]  # |d - b| == A (A > 0), or A == 0 and b == d


def _geometry(A: FloatArray, b: FloatArray, d: FloatArray) -> _Geometry:
    # d - b = s + e exactly.  Near grazing, A - (d - b) is a tiny difference of large numbers:
    # forming d - b in floating point first would leave an absolute error ~eps*|d - b| that is
    # a relative error of 1e-6 in a gap of 1e-10*A.  The compensated sums below keep the gaps
    # A -+ (d - b) accurate to a few ulps of themselves.
    with np.errstate(over="ignore", invalid="ignore"):  # tiny/huge A: clipped values are right
        return _geometry_unchecked(A, b, d)


def _geometry_unchecked(A: FloatArray, b: FloatArray, d: FloatArray) -> _Geometry:
    s, e = _two_sum(d, -b)
    t, f = _two_sum(A, -s)
    gap_lo = t + (f - e)  # A - (d - b) = A (1 - cos theta)
    t, f = _two_sum(A, s)
    gap_hi = t + (f + e)  # A + (d - b) = A (1 + cos theta)
    finite = np.isfinite(s)
    if not finite.all():  # |d - b| overflowed: certainly no crossing, keep the clipping exact
        gap_lo = np.where(finite, gap_lo, -s)
        gap_hi = np.where(finite, gap_hi, s)
    r_lo = np.sqrt(np.maximum(gap_lo, 0.0))
    r_hi = np.sqrt(np.maximum(gap_hi, 0.0))
    # tan(theta/2) = sqrt((1 - c)/(1 + c)); atan2 of the two square roots is accurate for every
    # theta (arccos(c) loses ~half the digits near c = +-1, i.e. at grazing).  The common
    # factor sqrt(A) cancels, so this also gives the right clipped value when A == 0.
    theta = 2.0 * np.arctan2(r_lo, r_hi)
    theta_c = 2.0 * np.arctan2(r_hi, r_lo)
    positive = A > 0
    tie = ~positive & (s == 0)  # A == 0 and b == d: Heaviside(0) = 1/2 <=> theta = pi/2
    theta = np.where(tie, 0.5 * np.pi, theta)
    theta_c = np.where(tie, 0.5 * np.pi, theta_c)
    up = s >= 0
    phi = np.where(up, theta, theta_c)
    a_sin = r_lo * r_hi
    safe_A = np.where(positive, A, 1.0)
    sin_theta = np.where(positive, a_sin / safe_A, np.where(tie, 1.0, 0.0))
    cos_phi = np.where(positive, np.minimum(np.abs(s) / safe_A, 1.0), np.where(tie, 0.0, 1.0))
    crossing = (gap_lo > 0) & (gap_hi > 0)
    tangent = (positive & ((gap_lo == 0) | (gap_hi == 0))) | tie
    return _Geometry(theta, phi, cos_phi, sin_theta, a_sin, up, crossing, tangent)


def crossing_angle(A: ArrayLike, b: ArrayLike, d: ArrayLike) -> FloatArray:
    r"""Switching angle of the breakpoint ``d`` under ``x = A cos psi + b``.

    .. math:: \theta = \arccos\frac{d - b}{A}, \qquad \text{clipped to } [0, \pi]

    ``theta = 0`` when ``d - b >= A`` (never reached; exact grazing from below included),
    ``theta = pi`` when ``d - b <= -A``.  For ``A = 0``: ``0`` if ``b < d``, ``pi`` if
    ``b > d`` and ``pi/2`` if ``b == d`` (``Heaviside(0) = 1/2``: the step is "on" for
    ``theta/pi`` of the period).

    The value is accurate to a few ulps even at grazing: ``1 -+ cos theta`` are formed as
    compensated ``(A -+ (d - b))/A`` and ``theta = 2 atan2(sqrt(1 - c), sqrt(1 + c))``
    (the naive ``arccos`` loses ~6 digits when ``A - |d - b| = 1e-10 A``).

    Parameters
    ----------
    A : array_like
        Amplitude, finite and ``>= 0``.
    b, d : array_like
        Bias and breakpoint, finite.

    Returns
    -------
    ndarray
        ``theta`` with shape ``broadcast(A, b, d)``.

    Raises
    ------
    FourierError
        For negative or non-finite ``A``, non-finite ``b`` or ``d``.
    """
    A_ = _as_amplitude(A)
    b_ = _as_real("b", b)
    d_ = _as_real("d", d)
    _, (A_, b_, d_) = _broadcast(A=A_, b=b_, d=d_)
    return _geometry(A_, b_, d_).theta


# ---------------------------------------------------------------------------------------------
# weighted sums of sin(n phi), cos(n phi) for many n
# ---------------------------------------------------------------------------------------------

#: Outputs from which the kernels evaluate cos/sin(n phi) through trig tables (below it the
#: direct cos/sin is as fast).
CIS_TABLE_MIN = 1 << 14
# Per-call cache of trig tables: {(n0, B, Q): (phi, giant, baby)}; see _cis_tables.
_TableCache = dict[tuple[int, int, int], tuple[FloatArray, np.ndarray, np.ndarray]]


def _split_n(nf: IntArray) -> tuple[int, int, int, IntArray, IntArray]:
    """``n = n0 + q B + r`` with ``0 <= r < B ~ sqrt(n_max - n0)``: (n0, B, Q, q, r)."""
    n0 = int(nf.min())
    m = nf - n0
    B = max(1, math.isqrt(int(m.max())) + 1)
    q, r = np.divmod(m, B)
    return n0, B, int(q.max()) + 1, q, r


def _cis_tables(
    n0: int, B: int, Q: int, pf: FloatArray, ff: NDArray[np.bool_], cache: _TableCache | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Giant steps ``exp(i (n0 + qB) phi)`` (Q, M) and baby steps ``exp(i r phi)`` (B, M), with
    the reflection sign ``(-1)**n = (-1)**(n0 + qB) (-1)**r`` folded in where ``ff``.

    Every output ``exp(i n phi) = giant[q] * baby[r]`` then costs one complex product instead
    of a ``cos`` and a ``sin`` (~25 ns each here).  The arguments ``(n0 + qB) phi`` and
    ``r phi`` are rounded like the direct ``n phi`` would be, and the product adds ~2 ulps: the
    error does *not* accumulate as in a Chebyshev three-term recurrence (growth ~n/sin(phi)).
    """
    key = (n0, B, Q)
    cached = cache.get(key) if cache is not None else None
    if cached is not None and np.array_equal(cached[0], pf):
        # within one call, e.g. the symmetric Zou-Nagarajaiah force (b = 0): both breakpoints
        # have the same angle phi (one "up", one reflected), so the tables are shared
        Tq, Tr = cached[1].copy(), cached[2].copy()
    else:
        giant_n = (n0 + B * np.arange(Q)).astype(np.float64)
        arg = giant_n[:, None] * pf[None, :]
        Tq = np.empty(arg.shape, dtype=np.complex128)
        Tq.real = np.cos(arg)
        Tq.imag = np.sin(arg)
        arg = np.arange(B, dtype=np.float64)[:, None] * pf[None, :]
        Tr = np.empty(arg.shape, dtype=np.complex128)
        Tr.real = np.cos(arg)
        Tr.imag = np.sin(arg)
        if cache is not None:
            cache[key] = (pf.copy(), Tq.copy(), Tr.copy())
    if ff.any():
        Tq[np.ix_((n0 + B * np.arange(Q)) % 2 == 1, ff)] *= -1.0
        Tr[np.ix_(np.arange(B) % 2 == 1, ff)] *= -1.0
    return Tq, Tr


class _Trig:
    """Weighted sums ``sum_j u_j(phi) v_j(n) sigma trig_j(n phi)`` over ``broadcast(n, phi)``.

    ``sigma = (-1)**n`` where ``flip`` (reflected breakpoints), else 1; ``trig_j`` is ``sin`` or
    ``cos``.  Two evaluation plans:

    * *table* -- ``n`` is a contiguous run laid out on axes before those of ``phi`` (e.g.
      ``n[:, None]`` with ``A`` of shape ``(M,)``, the frequency-response use): with
      ``n = n0 + qB + r`` the whole weighted sum is *one* ``einsum`` over the baby/giant tables,
      ``out[q, r, m] = sum_t X[t, q, m] Y[t, r, m] W[t, q, r]``, where the ``phi`` weights are
      folded into the giant table ``X`` and the ``n`` weights into ``W``.  No full-size
      ``cos``/``sin`` is ever evaluated and the output is written once.
    * *dense* -- anything else: ``sigma exp(i n phi)`` is formed once (per-element trig, or the
      table plus a row gather when ``n`` is an arbitrary 1-D list), then ordinary products.
    """

    def __init__(
        self,
        n: IntArray,
        phi: FloatArray,
        flip: NDArray[np.bool_],
        cache: _TableCache | None = None,
    ) -> None:
        self.shape = np.broadcast_shapes(n.shape, phi.shape)
        self.n, self.phi, self.flip = n, phi, flip
        self.table: tuple[int, int, int, int, np.ndarray, np.ndarray] | None = None
        self._cos: FloatArray | None = None
        self._sin: FloatArray | None = None
        layout = self._outer_layout(n.shape, phi.shape)
        if layout == "n-first" and math.prod(self.shape) >= CIS_TABLE_MIN:
            nf = n.reshape(-1)
            if nf.size > 1 and bool(np.all(np.diff(nf) == 1)):
                n0, B, Q, _, _ = _split_n(nf)
                Tq, Tr = _cis_tables(n0, B, Q, phi.reshape(-1), flip.reshape(-1), cache)
                self.table = (n0, B, Q, nf.size, Tq, Tr)
        self.layout = layout

    def _outer_layout(self, n_shape: tuple[int, ...], p_shape: tuple[int, ...]) -> str:
        D = len(self.shape)
        pn = (1,) * (D - len(n_shape)) + n_shape
        pp = (1,) * (D - len(p_shape)) + p_shape
        n_axes = [k for k in range(D) if pn[k] > 1]
        p_axes = [k for k in range(D) if pp[k] > 1]
        if len(n_axes) and len(p_axes) and not set(n_axes) & set(p_axes):
            if max(n_axes) < min(p_axes):
                return "n-first"
            if max(p_axes) < min(n_axes):
                return "phi-first"
        return "other"

    def _dense(self) -> tuple[FloatArray, FloatArray]:
        if self._cos is None:
            n, phi, flip = self.n, self.phi, self.flip
            if (
                self.layout in ("n-first", "phi-first")
                and math.prod(self.shape) >= CIS_TABLE_MIN
                and n.size >= 16
            ):
                # arbitrary n (strided, unsorted, repeated): tables + row gather, then transpose
                nf, pf, ff = n.reshape(-1), phi.reshape(-1), flip.reshape(-1)
                n0, B, Q, q, r = _split_n(nf)
                Tq, Tr = _cis_tables(n0, B, Q, pf, ff)
                z = np.take(Tq, q, axis=0)
                z *= np.take(Tr, r, axis=0)  # (K, M): n along rows
                # C order of the output is (n, phi) for n-first and (phi, n) for phi-first
                z = z.reshape(self.shape) if self.layout == "n-first" else z.T.reshape(self.shape)
                self._cos = np.ascontiguousarray(z.real)
                self._sin = np.ascontiguousarray(z.imag)
            else:
                x = n * phi
                self._cos = np.array(np.cos(x))  # np.array: 0-d results must stay arrays
                self._sin = np.array(np.sin(x))
                neg = np.broadcast_to(flip & (n % 2 == 1), self.shape)
                if neg.any():
                    self._cos[neg] *= -1.0
                    self._sin[neg] *= -1.0
        assert self._sin is not None
        return self._cos, self._sin

    def weighted(self, parts: Sequence[tuple[str, FloatArray, FloatArray]]) -> FloatArray:
        """``sum over (kind, u_phi, v_n) in parts of u_phi v_n sigma kind(n phi)``, a new array."""
        if self.table is None:
            cos, sin = self._dense()
            out = np.zeros(self.shape)
            for kind, u, v in parts:
                out += (u * v) * (sin if kind == "sin" else cos)
            return out
        n0, B, Q, K, Tq, Tr = self.table
        M = Tq.shape[1]
        X, Y, W = [], [], []
        vpad = np.zeros(Q * B)
        for kind, u, v in parts:
            giant = Tq * u.reshape(-1)[None, :]
            vpad[:K] = np.broadcast_to(v, self.n.shape).reshape(-1)
            w = vpad.reshape(Q, B).copy()
            if kind == "sin":  # Im(g b) = g.imag b.real + g.real b.imag
                X += [giant.imag, giant.real]
            else:  # Re(g b) = g.real b.real - g.imag b.imag
                X += [giant.real, -giant.imag]
            Y += [Tr.real, Tr.imag]
            W += [w, w]
        out = np.einsum("tqm,trm,tqr->qrm", np.stack(X), np.stack(Y), np.stack(W))
        return out.reshape(Q * B, M)[:K].reshape(self.shape)


# ---------------------------------------------------------------------------------------------
# the ramp kernel
# ---------------------------------------------------------------------------------------------


def _ramp_series_table(order: int = 10) -> np.ndarray:
    """``C[j, k] = (-1)**(j+k) / ((2j+1)! (2k+1)! (2j+2k+3))`` (exact, then rounded once)."""
    C = np.empty((order, order))
    for j in range(order):
        for k in range(order):
            c = Fraction((-1) ** (j + k), math.factorial(2 * j + 1) * math.factorial(2 * k + 1))
            C[j, k] = float(c / (2 * j + 2 * k + 3))
    return C


#: Coefficients of the double series of :func:`ramp_integral` (rows: powers of ``phi**2``,
#: columns: powers of ``(m phi)**2``).
RAMP_SERIES = _ramp_series_table()


def ramp_integral(m: IntArray, phi: FloatArray, c: FloatArray, s: FloatArray) -> FloatArray:
    r"""``I_m(phi) = int_0^phi (cos psi - cos phi) cos(m psi) dpsi`` for ``m <= 1`` or
    ``max(m, 1) phi < 1`` (the region where the closed forms cancel catastrophically).

    From ``I_m(phi) = (1/m) int_0^phi sin t sin(m t) dt`` and the Taylor series of ``sin t`` and
    ``sin(m t)``:

    .. math:: I_m(\phi) = \phi^3 \sum_{j,k \ge 0}
              \frac{(-1)^{j+k}\, \phi^{2j} (m\phi)^{2k}}{(2j+1)!\,(2k+1)!\,(2j+2k+3)}

    an absolutely convergent double series whose leading term ``phi**3/3`` dominates when
    ``phi, m phi <= 1`` (no cancellation; ten terms in each index reach 1e-19).
    Outside it (``m <= 1`` and ``phi >= 1``) the closed forms ``sin phi - phi cos phi`` and
    ``(phi - sin phi cos phi)/2`` are used, which are well conditioned there.
    """
    # m >= 2 is only ever passed here with m phi < 1 (up to rounding at the boundary, where the
    # series still converges fast); m <= 1 uses the series below phi = 1
    series = (m >= 2) | (phi < 1.0)
    closed = np.where(m == 0, s - phi * c, 0.5 * (phi - s * c))
    # phi**3 (a libm/SIMD pow) on the whole array as before, so that no element's rounding
    # depends on which others are selected; the rest is exact IEEE multiply/add, element by
    # element, so summing the series only where it is used changes no bit
    out = np.where(series, phi**3, closed)
    sel = np.flatnonzero(series)
    if sel.size == 0:
        return out
    ph = phi.reshape(-1)[sel]
    x = ph * ph
    y = (m.reshape(-1)[sel].astype(np.float64) * ph) ** 2
    # Horner in y for all ten rows j at once, then in x: the same multiply-then-add per element
    # as ten separate row loops (so bit-identical), but 40 array operations instead of 220,
    # which is most of this kernel's cost on the few hundred points of a frequency response
    rows = RAMP_SERIES.shape[0]
    Q = np.zeros((rows, sel.size))
    for k in range(RAMP_SERIES.shape[1] - 1, -1, -1):
        Q *= y
        Q += RAMP_SERIES[:, k, None]
    P = np.zeros(sel.size)
    for j in range(rows - 1, -1, -1):
        P *= x
        P += Q[j]
    out.reshape(-1)[sel] *= P
    return out


class _Term(NamedTuple):
    geometry: _Geometry
    slope: FloatArray | float  # coefficient of the ramp (x - d) H(x - d)
    value: FloatArray | float  # coefficient of the step H(x - d)


def _group_terms(terms: Sequence[_Term]) -> list[list[_Term]]:
    """Group breakpoints that share the angle array ``phi`` and are uniformly up or down.

    For such a group (e.g. the breakpoints -1 and +1 of a symmetric force at ``b = 0``) the
    reflection sign ``(-1)**n`` and the jump sizes only weight the harmonic index, so the whole
    group is *one* weighted trig sum (one pass over the output) instead of one per breakpoint.
    """
    groups: list[list[_Term]] = []
    for term in terms:
        for group in groups:
            head = group[0]
            if (
                _mergeable(term)
                and _mergeable(head)
                and np.array_equal(head.geometry.phi, term.geometry.phi)
            ):
                group.append(term)
                break
        else:
            groups.append([term])
    return groups


def _mergeable(term: _Term) -> bool:
    """Scalar jumps and the same side of ``b`` everywhere (``sigma`` then depends on n only)."""
    up = term.geometry.up
    uniform = bool(up.all()) or not bool(up.any())
    return uniform and np.ndim(term.slope) == 0 and np.ndim(term.value) == 0


def _assemble(
    n: IntArray,
    A: FloatArray,
    loc_value: FloatArray,
    loc_slope: FloatArray,
    terms: Sequence[_Term],
) -> FloatArray:
    r"""Coefficients of ``f(x) = f_loc(x) + sum_i [s_i ramp_i + v_i step_i]`` in *local* form.

    Each breakpoint is written relative to the bias ``b``: for ``d >= b`` the ramp and step are
    used as they are ("up" form, angle ``theta <= pi/2``); for ``d < b`` they are rewritten as
    ``(x - d)H(x - d) = (x - d) + (d - x)H(d - x)`` and ``H(x - d) = 1 - H(d - x)`` ("down"
    form, angle ``pi - theta <= pi/2``, reflected with ``(-1)**n``) and their linear parts are
    already included in ``f_loc``, the linear function on the segment that contains ``b``
    (value ``loc_value = f_loc(b)``, slope ``loc_slope``).  This way nothing large is
    added and later subtracted: fully-on and fully-off breakpoints contribute exactly 0.

    For one breakpoint with angle ``phi`` (``sigma = 1`` up, ``(-1)**n`` down):

    * ramp: ``s (2A/pi) sigma I_n(phi)`` with, for ``n >= 2``,
      ``I_n = (cos phi sin n phi - n sin phi cos n phi) / (n (n**2 - 1))``;
    * step: ``v (2/pi) sigma sin(n phi)/n`` (up) or ``-v (2/pi) sigma sin(n phi)/n`` (down),
      and ``+-v (2/pi) phi`` for ``n = 0``.
    """
    shape = np.broadcast_shapes(n.shape, A.shape)
    nf = n.astype(np.float64)
    is0 = n == 0
    low = n <= 1
    odd = n % 2 == 1
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_ramp_sin = np.where(low, 0.0, 1.0 / (nf * (nf * nf - 1.0)))  # x sin(n phi)
        inv_ramp_cos = np.where(low, 0.0, 1.0 / (nf * nf - 1.0))  # x cos(n phi), = n*inv_ramp_sin
        inv_step = np.where(is0, 0.0, 1.0 / nf)
    n_eff = np.maximum(nf, 1.0)

    out: FloatArray | None = None
    cache: _TableCache = {}
    for group in _group_terms(terms):
        members = [t for t in group if np.any(t.slope != 0) or np.any(t.value != 0)]
        if not members:
            continue
        g = members[0].geometry
        has_ramp = any(bool(np.any(t.slope != 0)) for t in members)
        has_step = any(bool(np.any(t.value != 0)) for t in members)
        merged = all(_mergeable(t) for t in members)
        if merged:
            # uniform up/down per member: (-1)**n and the jumps go into the n-weights
            def n_weight(t: _Term, jump: str) -> FloatArray:
                down = not bool(t.geometry.up.all())
                sign = np.where(odd, -1.0, 1.0) if down else np.ones(n.shape)
                if jump == "step":
                    return float(t.value) * (-sign if down else sign)
                return float(t.slope) * sign

            k_ramp = sum((n_weight(t, "ramp") for t in members), np.zeros(n.shape))
            k_step = sum((n_weight(t, "step") for t in members), np.zeros(n.shape))
            trig = _Trig(n, g.phi, np.zeros(g.phi.shape, dtype=bool), cache)
            w_ramp = _TWO_OVER_PI * A
            w_step = np.full(A.shape, _TWO_OVER_PI)
        else:
            (term,) = members
            k_ramp = k_step = np.ones(n.shape)
            trig = _Trig(n, g.phi, ~g.up, cache)  # per-element reflection in the tables
            w_ramp = term.slope * _TWO_OVER_PI * A
            w_step = term.value * _TWO_OVER_PI * np.where(g.up, 1.0, -1.0)
        parts: list[tuple[str, FloatArray, FloatArray]] = []
        if has_ramp:
            # generic n >= 2 closed form; accurate when n phi >= 1 (terms ~ the value there)
            parts += [
                ("sin", w_ramp * g.cos_phi, k_ramp * inv_ramp_sin),
                ("cos", -w_ramp * g.sin_theta, k_ramp * inv_ramp_cos),
            ]
        if has_step:
            parts.append(("sin", np.broadcast_to(w_step, A.shape), k_step * inv_step))
        acc = trig.weighted(parts)
        flat = acc.reshape(-1)  # a view: acc is C-contiguous
        if has_ramp:
            # n <= 1, or n phi < 1 where the closed form loses ~2 log10(1/(n phi)) digits:
            # overwrite with the series / the n = 0, 1 closed forms.  n < 1/phi avoids a
            # full-size float temporary; phi = 0 gives 1/phi = inf (series, value 0).
            with np.errstate(divide="ignore"):
                fix = np.less(n_eff, 1.0 / g.phi) | low
            idx = np.flatnonzero(fix)
            if idx.size:
                at = np.unravel_index(idx, shape) if shape else ()

                def pick(x: np.ndarray, at: tuple[np.ndarray, ...] = at) -> np.ndarray:
                    return np.broadcast_to(x, shape)[at]

                m = pick(n)
                if merged:
                    sigma = np.ones(m.shape)
                else:
                    sigma = np.where(~pick(g.up) & (m % 2 == 1), -1.0, 1.0)
                ph = pick(g.phi)
                val = (
                    pick(w_ramp)
                    * pick(k_ramp)
                    * sigma
                    * ramp_integral(m, ph, pick(g.cos_phi), pick(g.sin_theta))
                )
                if has_step:  # keep the step part of these elements
                    mf = m.astype(np.float64)
                    sin_part = np.where(m == 0, ph, sigma * np.sin(mf * ph) / np.maximum(mf, 1.0))
                    val += pick(w_step) * pick(k_step) * sin_part
                flat[idx] = val
        if has_step and not has_ramp and is0.any():  # (with a ramp, done in the fix-up above)
            sel = np.flatnonzero(np.broadcast_to(is0, shape))
            at0 = np.unravel_index(sel, shape) if shape else ()
            flat[sel] += (np.broadcast_to(w_step * g.phi, shape) * np.broadcast_to(k_step, shape))[
                at0
            ]
        if out is None:
            out = acc
        else:
            out += acc
    if out is None:
        out = np.zeros(shape)

    # the local linear part only touches n = 0 (a0 = 2 f_loc(b)) and n = 1 (a1 = A f_loc')
    flat_out = out.reshape(-1)
    for order, contribution in ((0, 2.0 * loc_value), (1, A * loc_slope)):
        sel = n == order
        if sel.any():
            idx = np.flatnonzero(np.broadcast_to(sel, shape))
            at = np.unravel_index(idx, shape) if shape else ()
            flat_out[idx] += np.broadcast_to(contribution, shape)[at]
    zero_amp = A == 0
    if zero_amp.any():
        # x is constant: only a0 survives (the H(0) = 1/2 tie would otherwise leak sin(n pi/2))
        out[np.broadcast_to(zero_amp, shape) & np.broadcast_to(n >= 1, shape)] = 0.0
    return out


def _prepare(n: ArrayLike, A: ArrayLike, **reals: ArrayLike) -> tuple[IntArray, list[FloatArray]]:
    n_ = _as_order(n)
    A_ = _as_amplitude(A)
    rest = {k: _as_real(k, v) for k, v in reals.items()}
    _broadcast(n=n_, A=A_, **rest)  # only to report incompatible shapes early
    base_shape = np.broadcast_shapes(A_.shape, *(v.shape for v in rest.values()))
    # (np.ascontiguousarray would turn 0-d inputs into shape (1,))
    base = [np.broadcast_to(a, base_shape).copy() for a in (A_, *rest.values())]
    return n_, base


def _prepare_unchecked(
    n: ArrayLike, A: ArrayLike, b: ArrayLike, d: ArrayLike
) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:
    """:func:`_prepare` of ``n, A, b, d`` for inputs known to be valid, without the checks.

    The compiled numeric layer (:mod:`perturb.numeric.amplitude`) calls the kernels
    several times per response with harmonic indices and amplitudes it built itself; there
    the validation (finiteness scans, error-location bookkeeping, a trial broadcast) is pure
    fixed cost.  The arrays returned are equal in value, dtype and shape to those of
    :func:`_prepare`, so every kernel computes bit-identical results from them.
    """
    n_ = np.asarray(n, dtype=np.int64)
    A_ = np.asarray(A, dtype=np.float64)
    b_ = np.asarray(b, dtype=np.float64)
    d_ = np.asarray(d, dtype=np.float64)
    base_shape = np.broadcast_shapes(A_.shape, b_.shape, d_.shape)
    A_, b_, d_ = (np.broadcast_to(a, base_shape).copy() for a in (A_, b_, d_))
    return n_, A_, b_, d_


# ---------------------------------------------------------------------------------------------
# public numeric API
# ---------------------------------------------------------------------------------------------


def step_coefficients(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    r"""Fourier coefficients of the unit step ``H(x - d)`` under ``x = A cos psi + b``.

    .. math:: a_0 = \frac{2\theta}{\pi}, \qquad a_n = \frac{2\sin n\theta}{n\pi},
              \qquad \theta = \arccos\frac{d-b}{A}

    with ``theta`` clipped as in :func:`crossing_angle` (never on: all 0; always on:
    ``a0 = 2``, ``a_n = 0``).  For ``theta > pi/2`` the reflected form
    ``a_n = -(-1)^n 2 sin(n(pi - theta))/(n pi)`` is evaluated, which keeps full relative
    accuracy when the step is almost always on.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0`` (``n = 0`` gives ``a0``, twice the mean).
    A : array_like
        Amplitude ``>= 0``.
    b, d : array_like, optional
        Bias and breakpoint (default 0).

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b, d)``.

    Raises
    ------
    FourierError
        If ``n`` is not a non-negative integer (array), ``A`` is negative or not finite, or
        ``b``/``d`` are not finite; the message names the offending value.
    """
    n_, (A_, b_, d_) = _prepare(n, A, b=b, d=d)
    return _step_kernel(n_, A_, b_, d_)


def _step_kernel(n_: IntArray, A_: FloatArray, b_: FloatArray, d_: FloatArray) -> FloatArray:
    """:func:`step_coefficients` of prepared arrays (``A_, b_, d_`` of one shape)."""
    g = _geometry(A_, b_, d_)
    loc_value = np.where(g.up, 0.0, 1.0)
    return _assemble(n_, A_, loc_value, np.zeros_like(A_), [_Term(g, 0.0, 1.0)])


def ramp_coefficients(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    r"""Fourier coefficients of the ramp ``(x - d) H(x - d)`` under ``x = A cos psi + b``.

    .. math::
        a_0 &= \frac{2A}{\pi}(\sin\theta - \theta\cos\theta), \qquad
        a_1 = \frac{A}{\pi}(\theta - \sin\theta\cos\theta), \\
        a_n &= \frac{2A}{\pi}\,
              \frac{\cos\theta\sin n\theta - n\sin\theta\cos n\theta}{n(n^2-1)}, \quad n\ge 2

    (from ``a_n = (2/pi) int_0^theta (A cos psi + b - d) cos n psi dpsi``).  The value is
    ``O(A theta**3)`` for small ``theta`` while the terms are ``O(A n theta)``: the formula above
    loses ``~2 log10(1/(n theta))`` digits, so for ``max(n, 1) theta < 1`` a cancellation-free
    double series is summed instead (see ``ramp_integral``), and for ``theta > pi/2`` the
    reflection ``(x - d)H(x - d) = (x - d) + (d - x)H(d - x)`` is used.  Accuracy ~1e-13
    relative wherever the value exceeds ~1e-16 A.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0``.
    A : array_like
        Amplitude ``>= 0``.
    b, d : array_like, optional
        Bias and breakpoint (default 0).

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b, d)``.

    Raises
    ------
    FourierError
        If ``n`` is not a non-negative integer (array), ``A`` is negative or not finite, or
        ``b``/``d`` are not finite; the message names the offending value.
    """
    n_, (A_, b_, d_) = _prepare(n, A, b=b, d=d)
    return _ramp_kernel(n_, A_, b_, d_)


def _ramp_kernel(n_: IntArray, A_: FloatArray, b_: FloatArray, d_: FloatArray) -> FloatArray:
    """:func:`ramp_coefficients` of prepared arrays (``A_, b_, d_`` of one shape)."""
    g = _geometry(A_, b_, d_)
    loc_value = np.where(g.up, 0.0, b_ - d_)
    loc_slope = np.where(g.up, 0.0, 1.0)
    return _assemble(n_, A_, loc_value, loc_slope, [_Term(g, 1.0, 0.0)])


def dirac_coefficients(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    r"""Fourier coefficients of the Dirac impulse ``delta(x - d)`` under ``x = A cos psi + b``.

    .. math:: a_n = \frac{2\cos n\theta}{\pi A\sin\theta}\quad(|d - b| < A), \qquad
              a_n = 0 \quad(|d - b| > A)

    (sifting: ``x`` passes ``d`` at ``psi = +-theta`` with speed ``A sin theta``).
    ``A sin theta = sqrt((A - (d - b)) (A + (d - b)))`` is formed from the compensated gaps.
    For large ``n`` the absolute error is ~``n theta eps`` times ``2/(pi A sin theta)``: theta
    itself is only representable to ``~eps theta``.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0`` (``n = 0`` gives ``a0``, twice the mean).
    A : array_like
        Amplitude ``>= 0``.
    b, d : array_like, optional
        Bias and breakpoint (default 0).

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b, d)``.

    Raises
    ------
    FourierError
        At tangency ``|d - b| = A`` (including ``A = 0``, ``b = d``): the coefficient is
        infinite.  Also for bad inputs as in :func:`step_coefficients`.
    """
    n_, (A_, b_, d_) = _prepare(n, A, b=b, d=d)
    return _dirac_kernel(n_, A_, b_, d_)


def _dirac_kernel(n_: IntArray, A_: FloatArray, b_: FloatArray, d_: FloatArray) -> FloatArray:
    """:func:`dirac_coefficients` of prepared arrays (``A_, b_, d_`` of one shape)."""
    g = _geometry(A_, b_, d_)
    if g.tangent.any():
        idx = tuple(int(i) for i in np.argwhere(g.tangent)[0]) if g.tangent.ndim else ()
        Av, bv, dv = (float(a[idx]) for a in (A_, b_, d_))
        raise FourierError(
            f"dirac_coefficients: |d - b| == A (tangency: A={Av!r}, b={bv!r}, d={dv!r}); "
            "the coefficients are infinite there, expected |d - b| != A"
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(g.crossing, _TWO_OVER_PI / np.where(g.crossing, g.a_sin, 1.0), 0.0)
    return _Trig(n_, g.phi, ~g.up).weighted([("cos", scale, np.ones(n_.shape))])


# ---------------------------------------------------------------------------------------------
# unchecked entry points for the compiled numeric layer
# ---------------------------------------------------------------------------------------------


def _step_coefficients_unchecked(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    """:func:`step_coefficients` without input validation (internal callers only).

    ``n`` must be non-negative integers, ``A`` finite and ``>= 0``, ``b`` and ``d`` finite,
    all broadcastable: nothing is checked, invalid input gives undefined values instead of
    a :class:`~perturb.errors.FourierError`.  Valid input gives bit-identical results.
    """
    return _step_kernel(*_prepare_unchecked(n, A, b, d))


def _ramp_coefficients_unchecked(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    """:func:`ramp_coefficients` without input validation (see
    :func:`_step_coefficients_unchecked`)."""
    return _ramp_kernel(*_prepare_unchecked(n, A, b, d))


def _dirac_coefficients_unchecked(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    """:func:`dirac_coefficients` without input validation (see
    :func:`_step_coefficients_unchecked`); tangency still raises, being a property of the
    values, not a malformed input."""
    return _dirac_kernel(*_prepare_unchecked(n, A, b, d))


#: checked public function -> its unchecked twin, for callers that build valid inputs
#: themselves (looked up by function so that a caller falls back to the checked one for
#: anything not listed)
UNCHECKED = {
    step_coefficients: _step_coefficients_unchecked,
    ramp_coefficients: _ramp_coefficients_unchecked,
    dirac_coefficients: _dirac_coefficients_unchecked,
}


def abs_coefficients(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    r"""Fourier coefficients of ``|x - d|`` under ``x = A cos psi + b``.

    .. math:: |x - d| = 2(x-d)H(x-d) - (x-d)
              \;\Rightarrow\; a_n = 2 r_n - \ell_n, \quad
              \ell_0 = 2(b - d),\ \ell_1 = A,\ \ell_{n\ge2} = 0

    where ``r_n`` are the :func:`ramp_coefficients`.  Evaluated in the local form (around the
    side of ``d`` on which ``b`` lies) so no large terms cancel; ``a1`` near ``b = d`` uses
    ``a1 = -(2A/pi)(arcsin c + c sin theta)``, ``c = (d - b)/A``.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0`` (``n = 0`` gives ``a0``, twice the mean).
    A : array_like
        Amplitude ``>= 0``.
    b, d : array_like, optional
        Bias and breakpoint (default 0).

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b, d)``.

    Raises
    ------
    FourierError
        If ``n`` is not a non-negative integer (array), ``A`` is negative or not finite, or
        ``b``/``d`` are not finite; the message names the offending value.
    """
    n_, (A_, b_, d_) = _prepare(n, A, b=b, d=d)
    g = _geometry(A_, b_, d_)
    loc_value = np.abs(d_ - b_)
    loc_slope = np.where(g.up, -1.0, 1.0)
    out = _assemble(n_, A_, loc_value, loc_slope, [_Term(g, 2.0, 0.0)])
    # a1 = -A + 2 r_1 cancels when theta ~ pi/2 (b ~ d); the arcsin form is exact in spirit there
    c_signed = np.where(g.up, g.cos_phi, -g.cos_phi)
    near = (np.abs(c_signed) < 0.5) & (A_ > 0)
    if near.any() and (n_ == 1).any():
        shape = out.shape
        a1 = -_TWO_OVER_PI * A_ * (np.arcsin(c_signed) + c_signed * g.sin_theta)
        mask = np.broadcast_to(near, shape) & np.broadcast_to(n_ == 1, shape)
        out[mask] = np.broadcast_to(a1, shape)[mask]
    return out


def sign_coefficients(
    n: ArrayLike, A: ArrayLike, b: ArrayLike = 0.0, d: ArrayLike = 0.0
) -> FloatArray:
    r"""Fourier coefficients of ``sign(x - d)`` (``sign(0) = 0``) under ``x = A cos psi + b``.

    .. math:: \operatorname{sign}(x - d) = 2H(x - d) - 1 \;\Rightarrow\;
              a_0 = \frac{4\theta}{\pi} - 2 = -\frac{4}{\pi}\arcsin\frac{d-b}{A},\qquad
              a_n = \frac{4\sin n\theta}{n\pi}

    ``a0`` uses the ``arcsin`` form when ``|d - b| < A/2`` (where ``4 theta/pi - 2`` cancels)
    and ``2 (theta - (pi - theta))/pi`` otherwise.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0`` (``n = 0`` gives ``a0``, twice the mean).
    A : array_like
        Amplitude ``>= 0``.
    b, d : array_like, optional
        Bias and breakpoint (default 0).

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b, d)``.

    Raises
    ------
    FourierError
        If ``n`` is not a non-negative integer (array), ``A`` is negative or not finite, or
        ``b``/``d`` are not finite; the message names the offending value.
    """
    n_, (A_, b_, d_) = _prepare(n, A, b=b, d=d)
    g = _geometry(A_, b_, d_)
    loc_value = np.where(g.up, -1.0, 1.0)
    out = _assemble(n_, A_, loc_value, np.zeros_like(A_), [_Term(g, 0.0, 2.0)])
    c_signed = np.where(g.up, g.cos_phi, -g.cos_phi)
    near = (np.abs(c_signed) < 0.5) & (A_ > 0)
    if near.any() and (n_ == 0).any():
        shape = out.shape
        a0 = -2.0 * _TWO_OVER_PI * np.arcsin(c_signed)
        mask = np.broadcast_to(near, shape) & np.broadcast_to(n_ == 0, shape)
        out[mask] = np.broadcast_to(a0, shape)[mask]
    return out


def _check_order(lower: FloatArray, upper: FloatArray) -> None:
    bad = lower > upper
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0]) if bad.ndim else ()
        lo, hi = float(lower[idx]), float(upper[idx])
        raise FourierError(f"expected lower <= upper, got lower={lo!r} > upper={hi!r}")


def saturation_coefficients(
    n: ArrayLike, A: ArrayLike, b: ArrayLike, lower: ArrayLike, upper: ArrayLike
) -> FloatArray:
    r"""Fourier coefficients of the saturation ``min(max(x, lower), upper)``.

    .. math:: \operatorname{sat}(x) = \ell + (x-\ell)H(x-\ell) - (x-u)H(x-u)

    i.e. ``a_n = 2 l delta_{n0} + r_n(l) - r_n(u)`` with ramp coefficients ``r_n``; evaluated in
    local form (constant ``l`` below, ``x`` between, constant ``u`` above the bias) so that a
    response that is mostly saturated is not computed as a difference of large ramps.
    Requires ``lower <= upper``.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0``.
    A : array_like
        Amplitude ``>= 0``.
    b : array_like
        Bias.
    lower, upper : array_like
        Limits, ``lower <= upper`` elementwise.

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b, lower, upper)``.

    Raises
    ------
    FourierError
        For bad ``n``/``A``/``b`` (see :func:`step_coefficients`) or ``lower > upper``.
    """
    n_, (A_, b_, lo, hi) = _prepare(n, A, b=b, lower=lower, upper=upper)
    _check_order(lo, hi)
    g_lo = _geometry(A_, b_, lo)
    g_hi = _geometry(A_, b_, hi)
    middle = ~g_lo.up & g_hi.up
    loc_value = np.where(g_lo.up, lo, np.where(middle, b_, hi))
    loc_slope = np.where(middle, 1.0, 0.0)
    terms = [_Term(g_lo, 1.0, 0.0), _Term(g_hi, -1.0, 0.0)]
    return _assemble(n_, A_, loc_value, loc_slope, terms)


def deadzone_coefficients(
    n: ArrayLike, A: ArrayLike, b: ArrayLike, lower: ArrayLike, upper: ArrayLike
) -> FloatArray:
    r"""Fourier coefficients of the dead zone ``x - min(max(x, lower), upper)``.

    .. math:: \operatorname{dz}(x) = (x - u)H(x - u) - (\ell - x)H(\ell - x)

    ``a_n = r_n(u) - (r_n(l) - \ell_n(l))`` with ramp coefficients ``r_n`` and the linear part
    ``l_0 = 2(b - l)``, ``l_1 = A``; evaluated in local form.  Requires ``lower <= upper``.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0``.
    A : array_like
        Amplitude ``>= 0``.
    b : array_like
        Bias.
    lower, upper : array_like
        Limits, ``lower <= upper`` elementwise.

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b, lower, upper)``.

    Raises
    ------
    FourierError
        For bad ``n``/``A``/``b`` (see :func:`step_coefficients`) or ``lower > upper``.
    """
    n_, (A_, b_, lo, hi) = _prepare(n, A, b=b, lower=lower, upper=upper)
    _check_order(lo, hi)
    g_lo = _geometry(A_, b_, lo)
    g_hi = _geometry(A_, b_, hi)
    middle = ~g_lo.up & g_hi.up
    loc_value = np.where(g_lo.up, b_ - lo, np.where(middle, 0.0, b_ - hi))
    loc_slope = np.where(middle, 0.0, 1.0)
    terms = [_Term(g_lo, -1.0, 0.0), _Term(g_hi, 1.0, 0.0)]
    return _assemble(n_, A_, loc_value, loc_slope, terms)


def power_coefficients(n: ArrayLike, A: ArrayLike, b: ArrayLike, m: int) -> FloatArray:
    r"""Fourier coefficients of the monomial ``x**m`` (exact finite series).

    From ``(A cos psi + b)^m = sum_k C(m,k) b^(m-k) A^k cos^k psi`` and
    ``cos^k psi = 2^(-k) sum_j C(k,j) cos((k - 2j) psi)``:

    .. math:: a_n = 2\sum_{\substack{k=n\\ k\equiv n\ (2)}}^{m}
              \binom{m}{k}\binom{k}{(k-n)/2}\, b^{m-k}\Big(\frac{A}{2}\Big)^k,
              \qquad a_n = 0 \text{ for } n > m.

    All terms of the sum have the same sign (``k`` runs over one parity), so there is no
    cancellation.  ``0**0 = 1``.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0``.
    A : array_like
        Amplitude ``>= 0``.
    b : array_like
        Bias.
    m : int
        Exponent, an integer in ``[0, 1000]``.

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b)``.

    Raises
    ------
    FourierError
        For a bad ``m`` or bad ``n``/``A``/``b``.
    """
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or not 0 <= m <= _MAX_POWER:
        raise FourierError(f"m must be an integer exponent in [0, {_MAX_POWER}], got m={m!r}")
    m = int(m)
    n_, (A_, b_) = _prepare(n, A, b=b)
    shape = np.broadcast_shapes(n_.shape, A_.shape)
    out = np.zeros(shape)
    idx = np.minimum(n_, m + 1)  # index m+1 of each table row is a 0 (n > m)
    half = 0.5 * A_
    for k in range(m + 1):
        row = np.zeros(m + 2)
        ck = math.comb(m, k)
        for nn in range(k % 2, k + 1, 2):
            row[nn] = 2.0 * float(ck * math.comb(k, (k - nn) // 2))
        coef = row[idx]
        if not coef.any():
            continue
        out += coef * (b_ ** (m - k) * half**k)
    return out


def pwl_coefficients(
    n: ArrayLike,
    A: ArrayLike,
    b: ArrayLike,
    base_slope: float,
    base_offset: float,
    breakpoints: Sequence[float] | ArrayLike,
    slope_jumps: Sequence[float] | ArrayLike,
    value_jumps: Sequence[float] | ArrayLike,
) -> FloatArray:
    r"""Fourier coefficients of a general piecewise-linear force.

    .. math:: f(x) = k_0 x + f_0 + \sum_i \big[\Delta k_i\,(x - d_i)H(x - d_i)
                     + \Delta f_i\,H(x - d_i)\big]

    (``k_0 = base_slope``, ``f_0 = base_offset``, ``d_i = breakpoints``, ``Delta k_i =
    slope_jumps``, ``Delta f_i = value_jumps``), hence
    ``a_n = k_0 l_n + 2 f_0 delta_{n0} + sum_i [Delta k_i r_n(d_i) + Delta f_i s_n(d_i)]`` with
    ramp/step coefficients ``r_n``/``s_n`` and ``l_0 = 2b``, ``l_1 = A``.

    It is evaluated in local form: breakpoints below the bias are reflected
    (``(x-d)H(x-d) = (x-d) + (d-x)H(d-x)``) and their linear parts are collected into the linear
    function on the segment containing ``b``, obtained by walking the sorted breakpoints (value
    at the nearest breakpoint below ``b`` plus slope times distance).  So a breakpoint that the
    motion never (or always) crosses contributes exactly nothing beyond that linear function.

    The Zou-Nagarajaiah force ``k x + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)]`` is
    ``base_slope=1, base_offset=1-k, breakpoints=(-1, 1), slope_jumps=(k-1, 1-k),
    value_jumps=(0, 0)``.

    Parameters
    ----------
    n : int or array_like of int
        Harmonic indices ``>= 0``.
    A, b : array_like
        Amplitude ``>= 0`` and bias; broadcast with ``n``.
    base_slope, base_offset : float
        Slope and offset of ``f`` below every breakpoint.
    breakpoints, slope_jumps, value_jumps : sequence of float
        1-D, equal lengths (may be empty).

    Returns
    -------
    ndarray
        Shape ``broadcast(n, A, b)``.

    Raises
    ------
    FourierError
        For non-finite parameters, breakpoint/jump sequences that are not 1-D or differ in
        length, or bad ``n``/``A``/``b``.
    """
    k0, f0 = (
        _as_scalar(name, v)
        for name, v in (("base_slope", base_slope), ("base_offset", base_offset))
    )
    dk = [
        _as_real(name, v)
        for name, v in (
            ("breakpoints", breakpoints),
            ("slope_jumps", slope_jumps),
            ("value_jumps", value_jumps),
        )
    ]
    for name, arr in zip(("breakpoints", "slope_jumps", "value_jumps"), dk, strict=True):
        if arr.ndim != 1:
            raise FourierError(f"{name} must be a 1-D sequence, got shape {arr.shape}")
    d_all, s_all, v_all = dk
    if not (d_all.size == s_all.size == v_all.size):
        raise FourierError(
            "breakpoints, slope_jumps and value_jumps must have equal lengths, got "
            f"{d_all.size}, {s_all.size}, {v_all.size}"
        )
    n_, (A_, b_) = _prepare(n, A, b=b)
    order = np.argsort(d_all, kind="stable")
    d_all, s_all, v_all = d_all[order], s_all[order], v_all[order]

    # Walk the segments: slope[j] and value_at[j] describe f just right of d[j-1] (j >= 1);
    # j = 0 is the base line.  Computed once on the (few) breakpoints, in plain floats.
    nb = d_all.size
    seg_slope = np.empty(nb + 1)
    seg_value = np.empty(nb + 1)  # f at d[j-1]^+ for j >= 1 (unused for j = 0)
    seg_slope[0] = k0
    seg_value[0] = 0.0
    val = k0 * d_all[0] + f0 if nb else 0.0
    for j in range(nb):
        if j > 0:
            val += seg_slope[j] * (d_all[j] - d_all[j - 1])
        val += v_all[j]
        seg_slope[j + 1] = seg_slope[j] + s_all[j]
        seg_value[j + 1] = val
    j_of_b = np.searchsorted(d_all, b_, side="left")  # number of breakpoints strictly below b
    d_prev = np.where(j_of_b > 0, d_all[np.maximum(j_of_b - 1, 0)] if nb else 0.0, 0.0)
    loc_slope = seg_slope[j_of_b]
    loc_value = np.where(j_of_b == 0, k0 * b_ + f0, seg_value[j_of_b] + loc_slope * (b_ - d_prev))
    terms = [
        _Term(_geometry(A_, b_, np.full_like(A_, d_all[i])), float(s_all[i]), float(v_all[i]))
        for i in range(nb)
    ]
    return _assemble(n_, A_, loc_value, loc_slope, terms)


# ---------------------------------------------------------------------------------------------
# symbolic layer
# ---------------------------------------------------------------------------------------------

_N = sp.Symbol("n", integer=True, positive=True)


@dataclass(frozen=True)
class Regime:
    """An exact no-crossing case of a :class:`FourierSeries`.

    Attributes
    ----------
    condition : sympy.Basic
        Where the regime applies, e.g. ``d - b >= A``.
    a0, an : sympy.Expr
        Coefficients in the regime (``an`` may contain the series' ``n``).
    exceptional : tuple of (int, Expr)
        Orders ``k`` whose value differs from ``an`` at ``n = k`` (e.g. ``a1 = A``).
    label : str
        Human description.
    """

    condition: sp.Basic
    a0: sp.Expr
    an: sp.Expr
    exceptional: tuple[tuple[int, sp.Expr], ...] = ()
    label: str = ""

    def coefficient(self, k: int, n: sp.Symbol) -> sp.Expr:
        """``a_k`` in this regime."""
        if k == 0:
            return self.a0
        for kk, expr in self.exceptional:
            if kk == k:
                return expr
        return self.an.subs(n, k)


def _check_k(k: int) -> int:
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
        raise FourierError(f"k must be a non-negative integer, got k={k!r}")
    return int(k)


@dataclass(frozen=True)
class FourierSeries:
    r"""A closed-form cosine series ``g(A cos psi + b) = a0/2 + sum_{n>=1} a_n cos(n psi)``.

    Attributes
    ----------
    a0 : sympy.Expr
        Twice the mean.
    an : sympy.Expr
        ``a_n`` as an expression in the integer symbol ``n`` (valid for ``n >= 1`` except the
        orders listed in ``exceptional``).
    n : sympy.Symbol
        The harmonic-index symbol (integer, positive).
    definitions : tuple of (Symbol, Expr)
        Auxiliary symbols, e.g. ``(theta, acos((d - b)/A))``; :meth:`substituted` inserts them.
    domain : sympy.Basic
        Where the formulas hold, e.g. ``Abs(d - b) < A``.
    label : str
        Human description.
    exceptional : tuple of (int, Expr)
        Orders where ``an`` is singular (``0/0``) and the value is given separately.
    regimes : tuple of Regime
        Exact values outside ``domain`` (no crossing), in the order they are tested.
    """

    a0: sp.Expr
    an: sp.Expr
    n: sp.Symbol
    definitions: tuple[tuple[sp.Symbol, sp.Expr], ...]
    domain: sp.Basic
    label: str
    exceptional: tuple[tuple[int, sp.Expr], ...] = ()
    regimes: tuple[Regime, ...] = ()

    def __str__(self) -> str:
        lines = [f"{self.label}:", f"  a0  = {self.a0}", f"  a_{self.n} = {self.an}"]
        lines += [f"  a_{k}  = {e}" for k, e in self.exceptional]
        lines += [f"  where {s} = {e}" for s, e in self.definitions]
        lines.append(f"  valid for {self.domain}")
        for r in self.regimes:
            lines.append(
                f"  otherwise if {r.condition}: a0 = {r.a0}, a_{self.n} = {r.an}"
                + "".join(f", a_{k} = {e}" for k, e in r.exceptional)
                + (f"  ({r.label})" if r.label else "")
            )
        return "\n".join(lines)

    def coefficient(self, k: int) -> sp.Expr:
        """``a_k`` in the ``theta``-form (definitions not substituted).

        Parameters
        ----------
        k : int
            Harmonic index ``>= 0``; ``k = 0`` gives ``a0`` (twice the mean), orders in
            ``exceptional`` give their special value, others ``an`` with ``n = k``.

        Returns
        -------
        sympy.Expr
        """
        k = _check_k(k)
        if k == 0:
            return self.a0
        for kk, expr in self.exceptional:
            if kk == k:
                return expr
        return self.an.subs(self.n, k)

    def partial_sum(self, psi: sp.Expr | str, N: int) -> sp.Expr:
        r"""The truncated series :math:`a_0/2 + \sum_{k=1}^{N} a_k \cos k\psi`.

        Parameters
        ----------
        psi : sympy.Expr or str
            The phase variable (a symbol or any expression). A string that is a plain name
            (``"psi"``) becomes ``Symbol(psi)``; any other string is read by the safe parser
            :func:`perturb.model.parsing.parse_expression` (never ``sympify``).
        N : int
            Number of harmonics, ``0 <= N <=`` :data:`MAX_PARTIAL_SUM_HARMONICS`.

        Returns
        -------
        sympy.Expr

        Raises
        ------
        FourierError
            For a bad ``N`` or a ``psi`` that is neither an expression nor a number.
        ParseError
            For a string ``psi`` the parser refuses.
        """
        N = _check_k(N)
        if N > MAX_PARTIAL_SUM_HARMONICS:
            raise FourierError(
                f"partial_sum: N = {N} harmonics, expected at most {MAX_PARTIAL_SUM_HARMONICS} "
                "(a symbolic sum that long is unusable; evaluate coefficients numerically)"
            )
        psi = _phase(psi)
        return self.a0 / 2 + sp.Add(
            *(self.coefficient(k) * sp.cos(k * psi) for k in range(1, N + 1))
        )

    def _subs_definitions(self, expr: sp.Expr) -> sp.Expr:
        for sym, value in reversed(self.definitions):
            expr = expr.subs(sym, value)
        return expr

    def substituted(self) -> FourierSeries:
        """The same series with ``definitions`` substituted (expressions in the raw parameters).

        Returns
        -------
        FourierSeries
            With ``theta`` replaced by ``acos((d - b)/A)`` etc. and ``definitions == ()``.
        """
        return replace(
            self,
            a0=self._subs_definitions(self.a0),
            an=self._subs_definitions(self.an),
            exceptional=tuple((k, self._subs_definitions(e)) for k, e in self.exceptional),
            definitions=(),
        )

    def piecewise(self, k: int, substitute: bool = True) -> sp.Expr:
        """``a_k`` including the exact no-crossing regimes, as a ``Piecewise``.

        ``Piecewise((formula, domain), (regime_1 value, regime_1 condition), ...,
        (last regime value, True))``.  For the step, e.g.
        ``Piecewise((2 sin(k theta)/(k pi), |d - b| < A), (0, d - b >= A), (0, True))``
        (``a0``: ``..., (1, A = 0 and d = b), (0, d - b >= A), (2, True)``).

        Parameters
        ----------
        k : int
            Harmonic index ``>= 0``.
        substitute : bool, optional
            Insert the ``definitions`` (default), so the result is in the raw parameters.

        Returns
        -------
        sympy.Expr
            A ``Piecewise`` (or a plain expression if SymPy could decide the conditions).
        """
        k = _check_k(k)
        formula = self.coefficient(k)
        if substitute:
            formula = self._subs_definitions(formula)
        pieces = [(formula, self.domain)]
        for i, r in enumerate(self.regimes):
            cond = sp.true if i == len(self.regimes) - 1 else r.condition
            pieces.append((r.coefficient(k, self.n), cond))
        return sp.Piecewise(*pieces)

    def evaluate(self, k: int, **values: float) -> float:
        """Numerical value of ``a_k`` at the given parameter values (by symbol name).

        Uses :meth:`piecewise`, so the no-crossing regimes are exact; inputs are converted to
        exact rationals and the result evaluated to 30 significant digits.

        Parameters
        ----------
        k : int
            Harmonic index ``>= 0``.
        **values : float
            A value for every free symbol, keyed by the symbol's name (e.g. ``A=2.0``).

        Returns
        -------
        float

        Raises
        ------
        FourierError
            If a free symbol has no value, or the value is undefined (e.g. Dirac tangency).
        """
        expr = self.piecewise(k)
        names = {s.name: s for s in expr.free_symbols}
        missing = sorted(set(names) - set(values))
        if missing:
            raise FourierError(f"evaluate: no value given for {', '.join(missing)}")
        subs = {}
        for name, sym in names.items():
            try:
                fv = float(values[name])
            except (TypeError, ValueError) as exc:
                raise FourierError(
                    f"evaluate: {name} must be a real number, got {values[name]!r}"
                ) from exc
            if not math.isfinite(fv):
                raise FourierError(f"evaluate: {name} must be finite, got {name}={fv!r}")
            subs[sym] = sp.Rational(fv)  # the exact binary value
        # Choose the branch with exact rational arithmetic (a grazing crossing by 1e-16 must not
        # be decided in floating point), then evaluate only that branch with evalf(subs=...),
        # which tracks precision itself; a plain .subs() would let SymPy auto-evaluate
        # acos/sin of near-1 rationals and can trip its assumption system.
        branch = None
        for piece, cond in expr.args if isinstance(expr, sp.Piecewise) else [(expr, sp.true)]:
            decided = cond.subs(subs) if cond is not sp.true else sp.true
            if decided is sp.true:
                branch = piece
                break
            if decided is not sp.false:
                raise FourierError(f"evaluate: cannot decide {cond} at {values}")
        if branch is None or branch.has(sp.nan, sp.zoo):
            raise FourierError(f"evaluate: a_{k} is undefined (infinite) at {values}")
        result = branch.evalf(30, subs=subs)
        if not result.is_number or result.has(sp.nan, sp.zoo, sp.oo, -sp.oo) or not result.is_real:
            raise FourierError(f"evaluate: a_{k} is undefined at {values} (got {result})")
        return float(result)


#: Longest symbolic partial sum :meth:`FourierSeries.partial_sum` builds (each term is a
#: substituted coefficient; 1000 of them take about a second, 1e9 would never finish).
MAX_PARTIAL_SUM_HARMONICS = 1000


def _name_symbol(value: str, name: str, **assumptions: bool) -> sp.Symbol:
    """A symbol from a caller's string, which must be a plain name (never parsed)."""
    if len(value) > 100 or not value.isidentifier():
        shown = value if len(value) <= 40 else value[:37] + "..."
        raise FourierError(
            f"{name} = {shown!r}: expected a plain name (letters, digits, _), a number or a "
            "SymPy expression"
        )
    return sp.Symbol(value, **assumptions)


def _phase(psi: sp.Expr | str) -> sp.Expr:
    """The phase argument of :meth:`FourierSeries.partial_sum` as a SymPy expression."""
    if isinstance(psi, str):
        if psi.isidentifier() and len(psi) <= 100:
            return sp.Symbol(psi)
        from perturb.model.parsing import parse_expression

        return parse_expression(psi)
    try:
        out = sp.sympify(psi, strict=True)  # strict: numbers and SymPy objects only
    except (sp.SympifyError, TypeError) as exc:
        raise FourierError(f"psi must be a SymPy expression or a number, got {psi!r}") from exc
    if not isinstance(out, sp.Expr):
        raise FourierError(f"psi must be a scalar SymPy expression, got {out!r}")
    return out


def _sym(value: sp.Expr | float | str, name: str) -> sp.Expr:
    if isinstance(value, str):
        expr = _name_symbol(value, name)
    else:
        try:
            expr = sp.sympify(value, strict=True)  # strict: numbers and SymPy objects only
        except (sp.SympifyError, TypeError) as exc:
            raise FourierError(
                f"{name} must be a SymPy expression or number, got {value!r}"
            ) from exc
    if expr.is_number:
        if expr.has(sp.nan, sp.zoo, sp.oo, -sp.oo) or expr.is_real is False:
            raise FourierError(f"{name} must be finite and real, got {name}={expr}")
        if name == "A" and expr.is_negative:
            raise FourierError(f"A must be >= 0, got A={expr}")
    return expr


def _x_minus(d: sp.Expr) -> str:
    return sp.sstr(sp.Symbol("x") - d)


def _theta_symbol(theta: sp.Symbol | str | None) -> sp.Symbol:
    if theta is None:
        return sp.Symbol("theta", positive=True)
    if isinstance(theta, str):
        return _name_symbol(theta, "theta", positive=True)
    if isinstance(theta, sp.Symbol):
        return theta
    raise FourierError(f"theta must be a SymPy Symbol or a name, got {theta!r}")


def step_series(
    A: sp.Expr | float,
    b: sp.Expr | float = 0,
    d: sp.Expr | float = 0,
    theta: sp.Symbol | str | None = None,
) -> FourierSeries:
    r"""Symbolic series of ``H(x - d)``, ``x = A cos psi + b``.

    ``a0 = 2 theta/pi``, ``a_n = 2 sin(n theta)/(n pi)``, ``theta = acos((d - b)/A)`` for
    ``|d - b| < A``; regimes: ``A = 0, b = d`` gives ``a0 = 1`` (``Heaviside(0) = 1/2``),
    ``d - b >= A`` gives 0, otherwise (``d - b <= -A``) ``a0 = 2``, ``a_n = 0``.

    Parameters
    ----------
    A, b, d : sympy.Expr or number or str
        Amplitude, bias and breakpoint (strings become symbols).
    theta : sympy.Symbol or str, optional
        Symbol for the crossing angle (default ``Symbol('theta', positive=True)``).

    Returns
    -------
    FourierSeries

    Raises
    ------
    FourierError
        For non-finite or non-real numbers, or a negative numeric ``A``.
    """
    A, b, d = _sym(A, "A"), _sym(b, "b"), _sym(d, "d")
    th = _theta_symbol(theta)
    n = _N
    return FourierSeries(
        a0=2 * th / sp.pi,
        an=2 * sp.sin(n * th) / (n * sp.pi),
        n=n,
        definitions=((th, sp.acos((d - b) / A)),),
        domain=sp.Abs(d - b) < A,
        label=f"Heaviside({_x_minus(d)}), x = {sp.sstr(A)}*cos(psi) + {sp.sstr(b)}",
        regimes=(
            Regime(
                sp.Eq(A, 0) & sp.Eq(d, b),
                sp.Integer(1),
                sp.Integer(0),
                label="A = 0 and x = d: Heaviside(0) = 1/2",
            ),
            Regime(d - b >= A, sp.Integer(0), sp.Integer(0), label="never on"),
            Regime(d - b <= -A, sp.Integer(2), sp.Integer(0), label="always on"),
        ),
    )


def ramp_series(
    A: sp.Expr | float,
    b: sp.Expr | float = 0,
    d: sp.Expr | float = 0,
    theta: sp.Symbol | str | None = None,
) -> FourierSeries:
    r"""Symbolic series of the ramp ``(x - d) H(x - d)``, ``x = A cos psi + b``.

    ``a0 = (2A/pi)(sin theta - theta cos theta)``, ``a1 = (A/pi)(theta - sin theta cos theta)``,
    ``a_n = (2A/pi)(cos theta sin n theta - n sin theta cos n theta)/(n (n**2 - 1))``;
    regimes: ``d - b >= A`` gives 0, otherwise ``x - d`` (``a0 = 2(b - d)``, ``a1 = A``).

    Parameters
    ----------
    A, b, d : sympy.Expr or number or str
        Amplitude, bias and breakpoint (strings become symbols).
    theta : sympy.Symbol or str, optional
        Symbol for the crossing angle (default ``Symbol('theta', positive=True)``).

    Returns
    -------
    FourierSeries

    Raises
    ------
    FourierError
        For non-finite or non-real numbers, or a negative numeric ``A``.
    """
    A, b, d = _sym(A, "A"), _sym(b, "b"), _sym(d, "d")
    th = _theta_symbol(theta)
    n = _N
    c, s = sp.cos(th), sp.sin(th)
    return FourierSeries(
        a0=2 * A / sp.pi * (s - th * c),
        an=2 * A / sp.pi * (c * sp.sin(n * th) - n * s * sp.cos(n * th)) / (n * (n**2 - 1)),
        n=n,
        definitions=((th, sp.acos((d - b) / A)),),
        domain=sp.Abs(d - b) < A,
        label=f"ramp ({_x_minus(d)})*Heaviside({_x_minus(d)}), "
        f"x = {sp.sstr(A)}*cos(psi) + {sp.sstr(b)}",
        exceptional=((1, A / sp.pi * (th - s * c)),),
        regimes=(
            Regime(d - b >= A, sp.Integer(0), sp.Integer(0), label="never on"),
            Regime(
                d - b <= -A,
                2 * (b - d),
                sp.Integer(0),
                exceptional=((1, A),),
                label="always on: x - d",
            ),
        ),
    )


def dirac_series(
    A: sp.Expr | float,
    b: sp.Expr | float = 0,
    d: sp.Expr | float = 0,
    theta: sp.Symbol | str | None = None,
) -> FourierSeries:
    r"""Symbolic series of ``DiracDelta(x - d)``, ``x = A cos psi + b``.

    ``a_n = 2 cos(n theta)/(pi A sin theta)`` (``a0`` likewise with ``n = 0``) for
    ``|d - b| < A``; 0 for ``|d - b| > A``; undefined (``nan``: infinite) at tangency.

    Parameters
    ----------
    A, b, d : sympy.Expr or number or str
        Amplitude, bias and breakpoint (strings become symbols).
    theta : sympy.Symbol or str, optional
        Symbol for the crossing angle (default ``Symbol('theta', positive=True)``).

    Returns
    -------
    FourierSeries

    Raises
    ------
    FourierError
        For non-finite or non-real numbers, or a negative numeric ``A``.
    """
    A, b, d = _sym(A, "A"), _sym(b, "b"), _sym(d, "d")
    th = _theta_symbol(theta)
    n = _N
    return FourierSeries(
        a0=2 / (sp.pi * A * sp.sin(th)),
        an=2 * sp.cos(n * th) / (sp.pi * A * sp.sin(th)),
        n=n,
        definitions=((th, sp.acos((d - b) / A)),),
        domain=sp.Abs(d - b) < A,
        label=f"DiracDelta({_x_minus(d)}), x = {sp.sstr(A)}*cos(psi) + {sp.sstr(b)}",
        regimes=(
            Regime(sp.Abs(d - b) > A, sp.Integer(0), sp.Integer(0), label="no crossing"),
            Regime(sp.Eq(sp.Abs(d - b), A), sp.nan, sp.nan, label="tangency: infinite"),
        ),
    )
