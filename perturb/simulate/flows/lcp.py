r"""LCP time-stepping for oscillators with a continuous piecewise-linear spring.

This is the third, independent integrator of the project (Zou & Nagarajaiah computed their time
histories this way): the kinks of the spring are written as complementarity conditions and the
equation of motion is discretised with an implicit one-step scheme, so every step solves a small
linear complementarity problem (LCP) instead of locating switching times.

The system
----------
.. math::

    \ddot x + \mu\dot x + f(x) = L(t) = c + \sum_j F_j\cos(\omega_j t + \varphi_j),

with a *continuous* PWL force, slopes :math:`s_0,\dots,s_m` on the segments separated by the
breakpoints :math:`d_0 < \dots < d_{m-1}` (0-based: breakpoint ``i`` separates segments ``i`` and
``i + 1``) and slope jumps :math:`\Delta s_i = s_{i+1} - s_i`.  Relative to a *reference
segment* :math:`r`, with :math:`\sigma_i = +1` for the breakpoints above it (:math:`i \ge r`) and
:math:`\sigma_i = -1` below it,

.. math::

    f(x) = s_r x + o_r + \sum_{i=0}^{m-1} \Delta s_i\,\nu_i,\qquad
    \nu_i = \bigl(\sigma_i (x - d_i)\bigr)_+ ,

and :math:`\nu_i` is the unique solution of the complementarity condition

.. math::

    0 \le \nu_i \perp w_i = \nu_i - \sigma_i (x - d_i) \ge 0 .

(With :math:`r = 0` every :math:`\nu_i = (x - d_i)_+`, the textbook ramp form; the reference is
chosen to make the P-matrix condition below as weak as possible, see :func:`step_lcp`.)

The scheme (θ-method, Moreau–Jean type)
---------------------------------------
On the grid :math:`t_n = t_0 + nh`, with :math:`\bar\theta = 1 - \theta`,

.. math::

    x_{n+1} &= x_n + h\,(\bar\theta v_n + \theta v_{n+1}),\\
    v_{n+1} &= v_n + h\,\bigl(-\mu(\bar\theta v_n + \theta v_{n+1})
               - \bar\theta f(x_n) - \theta f(x_{n+1})
               + \bar\theta L(t_n) + \theta L(t_{n+1})\bigr),

with the complementarity condition imposed at the end point, :math:`\nu_{n+1} =
(\sigma(x_{n+1} - d))_+`.  For :math:`\theta = 1/2` this is the trapezoidal rule, for
:math:`\theta = 1` backward Euler.  Eliminating :math:`v_{n+1}` gives
:math:`x_{n+1} = \xi_n - c\,\Delta s^\top\nu_{n+1}` with

.. math::

    D = 1 + h\theta\mu + h^2\theta^2 s_r,\quad c = \frac{h^2\theta^2}{D},\quad
    \xi_n = \frac{(1 + h\theta\mu)\,r_1 + h\theta\,r_2 - h^2\theta^2 o_r}{D},

    r_1 = x_n + h\bar\theta v_n,\qquad
    r_2 = (1 - h\bar\theta\mu)\,v_n - h\bar\theta f(x_n) + h\bigl(\bar\theta L(t_n)
          + \theta L(t_{n+1})\bigr),

(:math:`\xi_n` is the end point the step would reach if the spring stayed linear with the
reference slope), and substituting into :math:`w` gives the LCP of size :math:`m`

.. math::

    w = M\nu + q,\quad 0 \le \nu \perp w \ge 0,\qquad
    M = I + c\,\sigma\,\Delta s^\top,\quad q = \sigma \circ (d - \xi_n\mathbf 1).

:math:`M` depends only on :math:`h, \theta, \mu` and the slopes, so it is built (and checked)
once.  After the LCP, :math:`f(x_{n+1}) = s_r x_{n+1} + o_r + \Delta s^\top\nu_{n+1}` and
:math:`v_{n+1} = (r_2 - h\theta f(x_{n+1}))/(1 + h\theta\mu)`.

Uniqueness: the P-property
--------------------------
By the matrix determinant lemma the principal minor of :math:`M` on an index set :math:`J` is
:math:`1 + c\sum_{i \in J}\sigma_i\Delta s_i`, so (for :math:`D > 0`) :math:`M` is a
P-matrix — the LCP has exactly one solution for every :math:`q` — iff

.. math::

    1 + h\theta\mu + h^2\theta^2 S_r > 0,\qquad
    S_r = s_r + \sum_i \min(0, \sigma_i\Delta s_i).

:math:`\sigma_i\Delta s_i` is the change of slope met when walking away from segment :math:`r`
across breakpoint :math:`i`, so :math:`S_r` is the smallest slope of any combination of
kinks; :func:`step_lcp` picks the reference that maximises it.  For a slope profile that only
increases away from its softest segment (nsd, dead zone, clearance, bilinear) :math:`S_r` is the
smallest slope and the condition is sharp: with a negative stiffness :math:`s_{\min} < 0` the
step is uniquely solvable only for :math:`h < h_{\max} = (\mu + \sqrt{\mu^2 - 4S})/(-2\theta S)`
(nsd, :math:`k = -2`, :math:`\mu = 0.05`, :math:`\theta = 1/2`: :math:`h_{\max} \approx 1.439`).
For larger steps the implicit equation for :math:`x_{n+1}` can have none or several solutions and
:func:`simulate_lcp` raises a :class:`~perturb.errors.PerturbError` giving :math:`h_{\max}`.
For other profiles (saturation) the test is sufficient, not necessary.

Accuracy
--------
The trapezoidal rule (:math:`\theta = 1/2`) has local error :math:`O(h^3)` in steps where
:math:`x` stays in one segment.  In a step that crosses a kink, :math:`\ddot x` has a kink in
time and the trapezoidal quadrature of it is only :math:`O(h^2)` accurate (the error of the
trapezoid on :math:`(t - t^*)_+` is :math:`(h - \tau)\tau/2`, :math:`\tau = t^* - t_n`); but
there are :math:`O(1)` such steps per period, so the global error stays :math:`O(h^2)`, with an
error constant that depends on where in their steps the crossings fall (so error-vs-h curves are
slightly irregular).  :math:`\theta \ne 1/2` is first order.  Energy: for :math:`\mu = 0`,
:math:`L = 0` and :math:`\theta = 1/2` the discrete energy :math:`\tfrac12 v^2 + V(x)` is
conserved *exactly* by steps that stay in one segment (the trapezoidal rule integrates an affine
:math:`f` exactly), and a step crossing kink :math:`i` changes it by
:math:`\Delta s_i (x_{n+1} - d_i)(d_i - x_n)/2` in size at most
:math:`|\Delta s_i|(x_{n+1} - x_n)^2/8`, with opposite signs going in and out, so the energy
error stays bounded and does not drift systematically.

Solver
------
:func:`lcp_solve` is Lemke's complementary pivoting method with covering vector
:math:`\mathbf 1`, the lexicographic minimum-ratio rule (which makes it finite on degenerate
problems) and one step of iterative refinement of the final basic solution.  It always finds the
solution when :math:`M` is a P-matrix (Lemke's theorem); it can need :math:`2^m` pivots (Murty's
examples), a step LCP needs one or two per kink crossed.  In :func:`simulate_lcp` the previous
step's complementary basis is tried first (for a P-matrix a feasible complementary basis *is*
the unique solution; since :math:`q` is affine in the scalar :math:`\xi_n`, each basis is
feasible on an interval of :math:`\xi_n` computed once), and Lemke is called only when the
orbit crosses a kink; ``warm_start=False`` runs Lemke at every step.

Forces that jump at a breakpoint (relays, Coulomb-type terms) are not LCPs of this form: they
are rejected with a pointer to the event-driven solver.
"""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from perturb import checks
from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.piecewise_exact import EVENT_DRIVEN_HINT, PWLSystem
from perturb.simulate.flows.system import to_pwl_system

__all__ = [
    "lcp_solve",
    "is_p_matrix",
    "StepLCP",
    "step_lcp",
    "LCPTrajectory",
    "simulate_lcp",
]

_EPS = float(np.finfo(float).eps)
#: default largest number of time steps of one simulate_lcp call (memory guard)
_MAX_STEPS = 20_000_000
#: largest ``h * omega_max`` (``omega_max = sqrt`` of the stiffest positive slope) that
#: ``stiff="refine"``/``"error"`` accept: about 2 pi steps per period of the stiffest segment,
#: a frequency error of 7 % there with the trapezoidal rule (``2 atan(h omega / 2) / h``)
MAX_STEP_PHASE = 1.0
#: ``h * omega_max`` of a refined step: 25 steps per period of the stiffest segment (frequency
#: error 0.5 % there), since a refined run pays for the contact's time scale anyway
REFINED_STEP_PHASE = 0.25


# --------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------
def _finite(name: str, value: object) -> float:
    return checks.finite(value, name)


def _finite_array(name: str, value: ArrayLike, ndim: int) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected a real {ndim}-D array") from None
    if arr.ndim != ndim:
        raise ParameterError(f"{name} has shape {arr.shape}: expected a {ndim}-D array")
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"{name} = {arr.tolist()!r}: expected finite values")
    return arr


# --------------------------------------------------------------------------------------------
# Lemke's method
# --------------------------------------------------------------------------------------------
def _lex_less(a: list[float], b: list[float], tol: float) -> bool:
    """``a < b`` lexicographically, entries equal within ``tol`` (relative) counting as ties."""
    for x, y in zip(a, b, strict=True):
        diff = x - y
        if abs(diff) > tol * (1.0 + abs(x) + abs(y)):
            return diff < 0.0
    return False


def _lemke(
    M: np.ndarray, q: np.ndarray, max_pivots: int
) -> tuple[np.ndarray, np.ndarray, int, tuple[int, ...]]:
    """Lemke's method on validated input: ``(z, w, pivots, J)`` with ``J`` = basic z indices.

    Tableau of ``w - M z - e z0 = q`` over the variables ``w_0..w_{m-1}, z_0..z_{m-1}, z0``
    (columns ``0..m-1``, ``m..2m-1``, ``2m``; the last column is the right-hand side).  The
    columns of ``w`` start as the identity, so at every stage they hold the inverse of the
    current basis, which the lexicographic ratio test uses to break ties (the perturbed problem
    ``q + (eps, eps^2, ...)`` is nondegenerate, so no basis repeats and the method is finite).

    The tableau is kept in Python lists: for the handful of rows of a step LCP this is several
    times faster than numpy, whose per-call overhead dominates at this size.
    """
    m = q.size
    ql = q.tolist()
    if min(ql) >= 0.0:
        return np.zeros(m), q.copy(), 0, ()
    Ml = M.tolist()
    scale = max(1.0, max(abs(a) for row in Ml for a in row), max(abs(a) for a in ql))
    piv_tol = 1e3 * _EPS * scale
    lex_tol = 64.0 * _EPS
    T = [
        [1.0 if j == i else 0.0 for j in range(m)] + [-a for a in Ml[i]] + [-1.0, ql[i]]
        for i in range(m)
    ]
    basis = list(range(m))
    z0 = 2 * m

    def pivot(r: int, col: int) -> None:
        inv = 1.0 / T[r][col]
        pr = [a * inv for a in T[r]]
        for i in range(m):
            if i != r:
                f = T[i][col]
                if f != 0.0:
                    T[i] = [a - f * b for a, b in zip(T[i], pr, strict=True)]
        T[r] = pr

    # first pivot: z0 enters where q is (lexicographically) most negative, making all of the
    # basic variables non-negative
    r = 0
    for i in range(1, m):
        if _lex_less([T[i][-1], *T[i][:m]], [T[r][-1], *T[r][:m]], lex_tol):
            r = i
    leaving = basis[r]
    pivot(r, z0)
    basis[r] = z0
    pivots = 1
    entering = leaving + m  # the complement of w_r is z_r
    while True:
        if pivots >= max_pivots:
            raise PerturbError(
                f"Lemke's method did not terminate within max_pivots = {max_pivots} pivots "
                f"(m = {m}); the LCP may be badly conditioned"
            )
        rows = [i for i in range(m) if T[i][entering] > piv_tol]
        if not rows:
            raise PerturbError(
                "Lemke's method ended on a secondary ray: the LCP has no solution that this "
                "method can find (M is not a P-matrix, or not copositive-plus); for "
                "simulate_lcp this means the time step is too large"
            )
        ratios = [T[i][-1] / T[i][entering] for i in rows]
        rmin = min(ratios)
        cut = rmin + lex_tol * (1.0 + abs(rmin)) + piv_tol
        ties = [i for i, rt in zip(rows, ratios, strict=True) if rt <= cut]
        zrow = [i for i in ties if basis[i] == z0]
        if zrow:
            r = zrow[0]  # z0 can leave: the next basis is complementary, stop there
        else:
            r = ties[0]
            if len(ties) > 1:
                best = [a / T[r][entering] for a in [T[r][-1], *T[r][:m]]]
                for i in ties[1:]:
                    key = [a / T[i][entering] for a in [T[i][-1], *T[i][:m]]]
                    if _lex_less(key, best, lex_tol):
                        r, best = i, key
        leaving = basis[r]
        pivot(r, entering)
        basis[r] = entering
        pivots += 1
        if leaving == z0:
            break
        entering = leaving + m if leaving < m else leaving - m

    # polish: one step of iterative refinement of the basic solution x_B = B^-1 q, with B^-1
    # read off the w columns of the tableau and the residual from the original columns
    xB = [row[-1] for row in T]
    res = list(ql)
    for i, b in enumerate(basis):
        x = xB[i]
        if b < m:
            res[b] -= x
        elif b < 2 * m:
            for k in range(m):
                res[k] += Ml[k][b - m] * x
        else:
            for k in range(m):
                res[k] += x
    xB = [x + sum(a * rk for a, rk in zip(T[i][:m], res, strict=True)) for i, x in enumerate(xB)]
    zl = [0.0] * m
    for i, b in enumerate(basis):
        if m <= b < 2 * m:
            zl[b - m] = max(xB[i], 0.0)
    J = tuple(sorted(b - m for b in basis if m <= b < 2 * m))
    wl = [max(sum(a * zj for a, zj in zip(Ml[i], zl, strict=True)) + ql[i], 0.0) for i in range(m)]
    for j in J:
        wl[j] = 0.0
    return np.array(zl), np.array(wl), pivots, J


def _validate_lcp(M: ArrayLike, q: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    Ma = _finite_array("M", M, 2)
    qa = _finite_array("q", q, 1)
    if Ma.shape != (qa.size, qa.size):
        raise ParameterError(
            f"M has shape {Ma.shape} and q has length {qa.size}: expected M of shape "
            f"({qa.size}, {qa.size})"
        )
    return Ma, qa


def lcp_solve(
    M: ArrayLike, q: ArrayLike, *, max_pivots: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    r"""Solve the LCP :math:`w = M\lambda + q,\ 0 \le \lambda \perp w \ge 0` by Lemke's method.

    Complementary pivoting with covering vector :math:`\mathbf 1` and the lexicographic
    minimum-ratio rule (ties broken by the rows of the basis inverse, so degenerate problems
    cannot cycle), followed by one step of iterative refinement of the basic solution on the
    final basis for full accuracy.  Pure-Python tableau: meant for the small LCPs of time
    stepping (``m`` up to a few dozen).

    Parameters
    ----------
    M : array_like, shape (m, m)
    q : array_like, shape (m,)
    max_pivots : int, optional
        Safety limit; default ``max(1000, 2**(m + 2))`` (Lemke can need :math:`2^m` pivots on
        Murty's P-matrices).

    Returns
    -------
    lam, w : ndarray, shape (m,)
        :math:`\lambda \ge 0`, :math:`w = M\lambda + q \ge 0`, :math:`\lambda_i w_i = 0`
        (``w`` is exactly zero on the basis and tiny negatives from rounding are clipped).

    Raises
    ------
    ParameterError
        Non-finite or mis-shaped input.
    PerturbError
        Secondary-ray termination (possible only if ``M`` is not a P-matrix; e.g. no solution
        exists) or too many pivots.

    Examples
    --------
    >>> lam, w = lcp_solve([[2.0, 1.0], [1.0, 2.0]], [-5.0, -6.0])
    >>> lam.round(12).tolist(), w.round(12).tolist()
    ([1.333333333333, 2.333333333333], [0.0, 0.0])
    """
    Ma, qa = _validate_lcp(M, q)
    m = qa.size
    if max_pivots is None:
        max_pivots = max(1000, 2 ** min(m + 2, 30))
    elif isinstance(max_pivots, bool) or not isinstance(max_pivots, int) or max_pivots < 1:
        raise ParameterError(f"max_pivots = {max_pivots!r}: expected a positive integer")
    if m == 0:
        return np.zeros(0), np.zeros(0)
    lam, w, _, _ = _lemke(Ma, qa, max_pivots)
    return lam, w


def is_p_matrix(M: ArrayLike, *, tol: float = 0.0) -> bool:
    r"""Whether every principal minor of ``M`` exceeds ``tol`` (brute force, :math:`2^m - 1` dets).

    A P-matrix is exactly a matrix for which the LCP has a unique solution for every ``q``.
    Meant for small ``m`` (checks and tests); :func:`step_lcp` uses the closed form.
    """
    Ma = _finite_array("M", M, 2)
    m = Ma.shape[0]
    if Ma.shape != (m, m):
        raise ParameterError(f"M has shape {Ma.shape}: expected a square matrix")
    if m > 20:
        raise ParameterError(f"M is {m}x{m}: the brute-force P-matrix test is for m <= 20")
    for size in range(1, m + 1):
        for J in itertools.combinations(range(m), size):
            idx = np.array(J)
            if not np.linalg.det(Ma[np.ix_(idx, idx)]) > tol:
                return False
    return True


# --------------------------------------------------------------------------------------------
# the step LCP
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StepLCP:
    r"""The LCP of one θ-step: :math:`M = I + c\,\sigma\Delta s^\top`, :math:`q = \sigma(d - \xi)`.

    Attributes
    ----------
    M : ndarray, shape (m, m)
    sigma : ndarray, shape (m,)
        :math:`+1` for breakpoints above the reference segment, :math:`-1` below.
    reference : int
        Reference segment :math:`r` (the one maximising :math:`S_r`).
    c, D : float
        :math:`c = h^2\theta^2/D`, :math:`D = 1 + h\theta\mu + h^2\theta^2 s_r`.
    min_minor : float
        Smallest principal minor, :math:`1 + c\sum_i\min(0, \sigma_i\Delta s_i)` when some
        :math:`\sigma_i\Delta s_i < 0`, else :math:`1 + c\min_i\sigma_i\Delta s_i` (1 when
        ``m = 0``); for :math:`D \le 0` it is reported as :math:`-\infty`.
    p_matrix : bool
        ``min_minor > 0``: every step has exactly one solution.
    h_max : float
        Largest step for which ``M`` is a P-matrix (``inf`` when it always is).
    h, theta : float
    """

    M: np.ndarray
    sigma: np.ndarray
    reference: int
    c: float
    D: float
    min_minor: float
    p_matrix: bool
    h_max: float
    h: float
    theta: float

    def q(self, xi: float, breakpoints: np.ndarray) -> np.ndarray:
        r""":math:`q = \sigma\circ(d - \xi)` for the free end point :math:`\xi`."""
        return self.sigma * (breakpoints - xi)


def _check_theta(theta: object) -> float:
    th = _finite("theta", theta)
    if not 0.5 <= th <= 1.0:
        raise ParameterError(
            f"theta = {th!r}: expected 1/2 <= theta <= 1 (theta < 1/2 amplifies the undamped "
            "oscillation every step; 1/2 is the trapezoidal rule, 1 backward Euler)"
        )
    return th


def _check_continuous(system: PWLSystem) -> None:
    cont = system.continuous_at()
    if not np.all(cont):
        bad = [
            f"x = {float(d)!r} (jump {float(j):.6g})"
            for d, j, ok in zip(system.breakpoints, system.jumps, cont, strict=True)
            if not ok
        ]
        raise PerturbError(
            "the restoring force jumps at " + ", ".join(bad) + ": LCP time-stepping covers "
            "continuous piecewise-linear springs (kinks) only, a force discontinuity is a "
            f"relay / friction-type law outside this LCP form; {EVENT_DRIVEN_HINT}"
        )


def step_lcp(system: PWLSystem, h: float, theta: float = 0.5) -> StepLCP:
    r"""Build the step matrix of :func:`simulate_lcp` and check the P-property in closed form.

    For every candidate reference segment :math:`r`,
    :math:`S_r = s_r + \sum_i\min(0, \sigma_i\Delta s_i)`; the reference with the largest
    :math:`S_r` (the smallest index among ties, so that :math:`\nu_i = (x - d_i)_+` whenever that
    costs nothing) is used.  :math:`M` is a P-matrix iff
    :math:`1 + h\theta\mu + h^2\theta^2 S_r > 0`.

    Raises
    ------
    ParameterError
        ``h <= 0``, non-finite, or ``theta`` outside ``[1/2, 1]``.
    PerturbError
        The force is discontinuous.
    """
    if not isinstance(system, PWLSystem):
        raise ParameterError(f"system = {system!r}: expected a PWLSystem")
    hh = _finite("h", h)
    if hh <= 0.0:
        raise ParameterError(f"h = {hh!r}: expected a step size h > 0")
    th = _check_theta(theta)
    _check_continuous(system)
    d = system.breakpoints
    s = system.slopes
    mu = system.damping
    m = d.size
    ds = np.diff(s)
    idx = np.arange(m)
    # ties within rounding (slopes like 0.1 and 1.1 parsed from text) go to the smallest index
    tie = 64.0 * _EPS * (1.0 + float(np.abs(s).sum()))
    best_r, best_S, best_sig = 0, -math.inf, np.ones(m)
    for r in range(m + 1):
        sig = np.where(idx >= r, 1.0, -1.0)
        S = float(s[r] + np.minimum(sig * ds, 0.0).sum())
        if S > best_S + tie:
            best_r, best_S, best_sig = r, S, sig
    ht = hh * th
    D = 1.0 + ht * mu + ht * ht * float(s[best_r])
    if best_S >= 0.0:
        h_max = math.inf
    else:
        h_max = (mu + math.sqrt(mu * mu - 4.0 * best_S)) / (-2.0 * th * best_S)
    if D > 0.0:
        c = ht * ht / D
        terms = best_sig * ds
        # smallest sum over a non-empty index set: all negative terms, else the smallest one
        if np.any(terms < 0.0):
            worst = float(terms[terms < 0.0].sum())
        else:
            worst = float(terms.min()) if m else 0.0
        min_minor = 1.0 + c * worst
        M = np.eye(m) + c * np.outer(best_sig, ds)
    else:
        c = math.inf
        min_minor = -math.inf
        M = np.full((m, m), np.nan)
    M.setflags(write=False)
    best_sig.setflags(write=False)
    return StepLCP(
        M=M,
        sigma=best_sig,
        reference=best_r,
        c=c,
        D=D,
        min_minor=min_minor,
        p_matrix=bool(min_minor > 0.0),
        h_max=h_max,
        h=hh,
        theta=th,
    )


class _Basis:
    """Affine solution of the step LCP on one complementary basis ``J`` (internal).

    With ``q = sigma*d - sigma*xi`` the basic variables are ``nu_J = alpha_J + beta_J xi`` and
    the non-basic ``w`` are affine too, so the basis is feasible exactly on an interval
    ``lo <= xi <= hi``; ``p + r xi`` is ``Delta s . nu``.
    """

    __slots__ = ("J", "alpha", "beta", "lo", "hi", "p", "r")

    def __init__(self, J: tuple[int, ...], lcp: StepLCP, d: np.ndarray, ds: np.ndarray) -> None:
        m = d.size
        M, sig = lcp.M, lcp.sigma
        a0, b0 = sig * d, -sig  # q = a0 + b0 xi
        alpha, beta = np.zeros(m), np.zeros(m)
        if J:
            idx = np.array(J)
            MJ = M[np.ix_(idx, idx)]
            alpha[idx] = np.linalg.solve(MJ, -a0[idx])
            beta[idx] = np.linalg.solve(MJ, -b0[idx])
        # w = M nu + q, zero on J by construction
        wa, wb = M @ alpha + a0, M @ beta + b0
        inJ = np.zeros(m, bool)
        inJ[list(J)] = True
        ca = np.where(inJ, alpha, wa)
        cb = np.where(inJ, beta, wb)
        lo, hi = -math.inf, math.inf
        for a, b in zip(ca, cb, strict=True):  # feasibility a + b xi >= 0
            if b > 0.0:
                lo = max(lo, -a / b)
            elif b < 0.0:
                hi = min(hi, -a / b)
            elif a < 0.0:
                lo, hi = math.inf, -math.inf
        self.J = J
        self.alpha, self.beta = alpha, beta
        self.lo, self.hi = float(lo), float(hi)
        self.p, self.r = float(ds @ alpha), float(ds @ beta)


# --------------------------------------------------------------------------------------------
# trajectory
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LCPTrajectory:
    r"""Result of :func:`simulate_lcp` on the uniform grid :math:`t_n = t_0 + nh`.

    Attributes
    ----------
    t, x, v : ndarray, shape (n,)
        Grid times and the discrete solution (``n = steps + 1``, ``t[0] = t0``, ``t[-1] = t1``).
    lam : ndarray, shape (n, m)
        Complementarity variables :math:`\nu_i = (\sigma_i(x - d_i))_+` of the LCP solutions
        (row 0 from the initial state).
    n_pivots : int
        Total number of Lemke pivots.
    n_lcp_solves : int
        Number of calls to Lemke's method (every step with ``warm_start=False``; otherwise only
        steps where the previous complementary basis stopped being feasible).
    sigma : ndarray, shape (m,)
        Orientation of each ramp (:math:`+1`: :math:`(x - d_i)_+`, :math:`-1`:
        :math:`(d_i - x)_+`).
    reference_segment : int
    h : float
        Step actually used: ``(t1 - t0) / steps`` with ``steps = ceil((t1 - t0) / h_requested)``.
    theta : float
    system : PWLSystem
    """

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    lam: np.ndarray
    n_pivots: int
    n_lcp_solves: int
    sigma: np.ndarray
    reference_segment: int
    h: float
    theta: float
    system: PWLSystem

    @property
    def w(self) -> np.ndarray:
        r"""Slack :math:`w = \nu - \sigma\circ(x - d)`, shape (n, m) (complementary to ``lam``)."""
        return self.lam - self.sigma * (self.x[:, None] - self.system.breakpoints)

    @property
    def y(self) -> np.ndarray:
        """State ``(x, v)`` as an array of shape (2, n)."""
        return np.vstack([self.x, self.v])

    @property
    def n_steps(self) -> int:
        """Number of time steps (``len(t) - 1``)."""
        return int(self.t.size - 1)


def simulate_lcp(
    system_or_oscillator: PWLSystem | Oscillator,
    y0: ArrayLike,
    t_span: Sequence[float],
    h: float,
    *,
    theta: float = 0.5,
    Omega: float | None = None,
    warm_start: bool = True,
    max_steps: int = _MAX_STEPS,
    stiff: str = "refine",
) -> LCPTrajectory:
    r"""Integrate a continuous-PWL oscillator by θ-method time-stepping with one LCP per step.

    Scheme, LCP and P-matrix condition: see the module docstring.  The step is made uniform:
    ``steps = ceil((t1 - t0) / h)`` and the step used is ``(t1 - t0) / steps <= h``.

    Parameters
    ----------
    system_or_oscillator : PWLSystem or Oscillator
        An :class:`~perturb.model.oscillator.Oscillator` must be piecewise linear (converted with
        :func:`~perturb.simulate.flows.system.to_pwl_system`).
    y0 : array_like, shape (2,)
        Initial ``(x, v)`` at ``t_span[0]``.
    t_span : (t0, t1)
        ``t1 > t0``.
    h : float
        Requested step, ``0 < h <= t1 - t0``.
    theta : float
        ``1/2`` (default, trapezoidal, second order, energy-conserving between kinks) to ``1``
        (backward Euler, first order, dissipative).
    Omega : float, optional
        Forcing frequency override, for an ``Oscillator`` only.
    warm_start : bool
        Reuse the previous complementary basis while it stays feasible (default); ``False``
        calls Lemke's method at every step (same solution, slower; for checking).
    max_steps : int
        Upper limit on the number of steps (a guard against a mistyped ``h``).
    stiff : {'refine', 'error', 'ignore'}
        What to do when the step cannot resolve the stiffest segment, ``h * omega_max >
        MAX_STEP_PHASE`` (``omega_max`` the square root of the largest positive slope; a stiff
        contact, e.g. a stop of stiffness ratio ``1e6``, has ``omega_max = 1000``). The
        trapezoidal step then jumps across a whole contact: each crossing adds an energy error
        of order ``Delta s (x_{n+1} - x_n)^2 / 8`` that no longer cancels between entry and exit,
        and the orbit gains energy (``x'' + 0.1 x' + x + 1e6 (x - 0.5) H(x - 0.5) = cos t`` with
        ``h = T/200``: max|x| 101 over ``t < 100`` where the exact solution has 1.77).
        ``'refine'`` (default) shortens the step to ``REFINED_STEP_PHASE / omega_max`` with a
        warning that names the stiffness ratio and both steps, or raises when that needs
        more than ``max_steps`` steps; ``'error'`` raises; ``'ignore'`` takes ``h`` as given.

    Returns
    -------
    LCPTrajectory

    Raises
    ------
    ParameterError
        Non-finite ``y0``, bad ``t_span``, ``h <= 0`` or ``h > t1 - t0``, ``theta`` outside
        ``[1/2, 1]``, too many steps, ``Omega`` with a ``PWLSystem``, a bad ``stiff``.
    ModelError
        The oscillator is not piecewise linear.
    PerturbError
        The force is discontinuous (use the event-driven solver), the step matrix is not a
        P-matrix (use a smaller ``h``; the message gives the bound), the step is too coarse
        for a stiff segment (``stiff``), or the orbit overflows.

    Examples
    --------
    >>> from perturb.model.builtins import builtin_model
    >>> osc = builtin_model("nsd", k=-2, mu=0.05, F=2, Omega=0.6)
    >>> traj = simulate_lcp(osc, (0.0, 0.0), (0.0, 10.0), 0.01)
    >>> traj.x.shape, traj.lam.shape
    ((1001,), (1001, 2))
    """
    if isinstance(system_or_oscillator, Oscillator):
        system = to_pwl_system(system_or_oscillator, Omega=Omega)
    elif isinstance(system_or_oscillator, PWLSystem):
        if Omega is not None:
            raise ParameterError(
                f"Omega = {Omega!r} was given with a PWLSystem: the override applies to an "
                "Oscillator only (build the PWLSystem with the forcing frequency you want)"
            )
        system = system_or_oscillator
    else:
        raise ParameterError(
            f"system_or_oscillator = {system_or_oscillator!r}: expected a PWLSystem or a "
            "piecewise-linear Oscillator"
        )
    y = _finite_array("y0", y0, 1)
    if y.size != 2:
        raise ParameterError(f"y0 = {y.tolist()!r}: expected two values (x, v)")
    ts = _finite_array("t_span", t_span, 1)
    if ts.size != 2 or not ts[1] > ts[0]:
        raise ParameterError(f"t_span = {ts.tolist()!r}: expected (t0, t1) with t1 > t0")
    t0, t1 = float(ts[0]), float(ts[1])
    span = t1 - t0
    hh = _finite("h", h)
    if hh <= 0.0:
        raise ParameterError(f"h = {hh!r}: expected a step size h > 0")
    if hh > span * (1.0 + 4.0 * _EPS):
        raise ParameterError(
            f"h = {hh!r} is larger than the time span t1 - t0 = {span!r}: expected 0 < h <= t1 - t0"
        )
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 1:
        raise ParameterError(f"max_steps = {max_steps!r}: expected a positive integer")
    # a tiny relative slack so that span = N h up to rounding gives exactly N steps
    steps = max(1, math.ceil(span / hh * (1.0 - 8.0 * _EPS)))
    if steps > max_steps:
        raise ParameterError(
            f"h = {hh!r} over t_span = ({t0!r}, {t1!r}) needs {steps} steps: more than "
            f"max_steps = {max_steps}; use a larger h or raise max_steps"
        )
    if stiff not in ("refine", "error", "ignore"):
        raise ParameterError(f"stiff = {stiff!r}: expected 'refine', 'error' or 'ignore'")
    h_used = span / steps
    lcp = step_lcp(system, h_used, theta)
    th = lcp.theta
    if not lcp.p_matrix:
        raise PerturbError(
            f"h = {h_used!r} is too large for theta = {th!r}: the step LCP matrix "
            f"M = I + c sigma ds^T is not a P-matrix (smallest principal minor "
            f"{lcp.min_minor:.6g} <= 0; the softest combination of segment stiffnesses is "
            "negative), so the implicit step can have no or several solutions; use a "
            f"smaller step, h < {lcp.h_max:.6g}"
        )
    # the requested step is well posed; it may still be too coarse for a stiff segment
    refined = _resolve_stiff(system, span, steps, max_steps, stiff)
    if refined != steps:
        steps = refined
        lcp = step_lcp(system, span / steps, theta)
    return _run(system, lcp, float(y[0]), float(y[1]), t0, t1, steps, warm_start)


def _resolve_stiff(system: PWLSystem, span: float, steps: int, max_steps: int, stiff: str) -> int:
    """The number of steps after the ``stiff`` policy of :func:`simulate_lcp`."""
    positive = system.slopes[system.slopes > 0.0]
    if stiff == "ignore" or positive.size == 0:
        return steps
    omega = math.sqrt(float(positive.max()))
    h = span / steps
    if h * omega <= MAX_STEP_PHASE * (1.0 + 1e-12):
        return steps
    softest = float(np.abs(system.slopes[system.slopes != 0.0]).min())
    ratio = float(positive.max()) / softest
    needed = math.ceil(span * omega / REFINED_STEP_PHASE)
    what = (
        f"the step h = {h:.4g} is too coarse for the stiffest segment of the spring (slope "
        f"{float(positive.max()):.4g}, stiffness ratio {ratio:.4g}, natural frequency "
        f"{omega:.4g}): h * omega = {h * omega:.3g} > {MAX_STEP_PHASE}, so the trapezoidal LCP "
        "step jumps across whole contacts and the discrete orbit gains energy (a wrong answer, "
        "not a rough one)"
    )
    fix = (
        f"use h <= {REFINED_STEP_PHASE / omega:.4g} ({needed} steps over this span), or the exact "
        "piecewise-analytic solver (method 'exact') or the event-driven one, which resolve "
        "every contact exactly"
    )
    if stiff == "error" or needed > max_steps:
        limit = "" if stiff == "error" else f" (more than max_steps = {max_steps})"
        raise PerturbError(f"{what}; {fix}{limit}")
    warnings.warn(
        f"{what}; refined to h = {span / needed:.4g} ({needed} steps; stiff='ignore' keeps "
        "the requested step)",
        RuntimeWarning,
        stacklevel=3,
    )
    return needed


def _overflow(t: float) -> None:
    raise PerturbError(
        f"the discrete orbit overflowed near t = {float(t)!r} (floating-point overflow: the orbit "
        "escapes to infinity); shorten t_span"
    )


def _run(
    system: PWLSystem,
    lcp: StepLCP,
    x: float,
    v: float,
    t0: float,
    t1: float,
    steps: int,
    warm_start: bool,
) -> LCPTrajectory:
    h, th = lcp.h, lcp.theta
    tb = 1.0 - th
    mu = system.damping
    d = system.breakpoints
    ds = np.diff(system.slopes)
    m = d.size
    r_seg = lcp.reference
    s_r, o_r = float(system.slopes[r_seg]), float(system.offsets[r_seg])
    sig = lcp.sigma
    D, c = lcp.D, lcp.c
    ht = h * th
    # per-step scalar coefficients (see the module docstring)
    h1t = h * tb
    cv = 1.0 - h1t * mu
    a1 = (1.0 + ht * mu) / D
    a2 = ht / D
    a0 = ht * ht * o_r / D
    inv1 = 1.0 / (1.0 + ht * mu)

    t = t0 + (t1 - t0) * (np.arange(steps + 1) / steps)
    t[-1] = t1
    load = system.load(t)
    g_list = (h * (tb * load[:-1] + th * load[1:])).tolist()

    nu0 = np.maximum(sig * (x - d), 0.0)
    f = s_r * x + o_r + float(ds @ nu0)  # = system.force(x0) for a continuous force
    xs = [x]
    vs = [v]
    xis = [0.0]
    ids = [-1]  # basis id per step (-1: the initial state)
    bases: list[_Basis] = []
    by_J: dict[tuple[int, ...], int] = {}
    max_piv = max(1000, 2 ** min(m + 2, 30))
    n_piv = 0
    n_solves = 0

    def basis_id(J: tuple[int, ...]) -> int:
        k = by_J.get(J)
        if k is None:
            k = len(bases)
            bases.append(_Basis(J, lcp, d, ds))
            by_J[J] = k
        return k

    M = lcp.M
    sd = sig * d
    if m == 0:
        cur = basis_id(())
    else:
        # basis of the initial state: the ramps that are active at x0
        cur = basis_id(tuple(int(i) for i in np.flatnonzero(nu0 > 0.0)))
    B = bases[cur]
    lo, hi, p, r = B.lo, B.hi, B.p, B.r
    lam_direct: list[np.ndarray] | None = None if warm_start else [nu0]
    xs_append, vs_append, xis_append, ids_append = xs.append, vs.append, xis.append, ids.append
    for n in range(steps):
        r1 = x + h1t * v
        r2 = cv * v - h1t * f + g_list[n]
        xi = a1 * r1 + a2 * r2 - a0
        if warm_start:
            if not lo <= xi <= hi:
                if not math.isfinite(xi):
                    _overflow(t[n])
                _, _, npv, J = _lemke(M, sd - sig * xi, max_piv)
                n_piv += npv
                n_solves += 1
                cur = basis_id(J)
                B = bases[cur]
                lo, hi, p, r = B.lo, B.hi, B.p, B.r
            S = p + r * xi
        else:
            if not math.isfinite(xi):
                _overflow(t[n])
            nu, _, npv, J = _lemke(M, sd - sig * xi, max_piv)
            n_piv += npv
            n_solves += 1
            cur = basis_id(J)
            lam_direct.append(nu)  # type: ignore[union-attr]
            S = float(ds @ nu)
        x = xi - c * S
        f = s_r * x + o_r + S
        v = (r2 - ht * f) * inv1
        xs_append(x)
        vs_append(v)
        xis_append(xi)
        ids_append(cur)

    xa = np.array(xs)
    va = np.array(vs)
    if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(va))):
        _overflow(t[int(np.argmin(np.isfinite(xa) & np.isfinite(va)))])
    if m == 0:
        lam = np.zeros((steps + 1, 0))
    elif lam_direct is not None:
        lam = np.array(lam_direct)
    else:
        # LCP solutions reconstructed in one shot from the affine basis maps
        id_arr = np.array(ids)
        alphas = np.array([b.alpha for b in bases] + [nu0])  # id -1 -> the initial ramps
        betas = np.array([b.beta for b in bases] + [np.zeros(m)])
        xi_arr = np.array(xis)
        lam = np.maximum(alphas[id_arr] + betas[id_arr] * xi_arr[:, None], 0.0)
    for arr in (t, xa, va, lam):
        arr.setflags(write=False)
    return LCPTrajectory(
        t=t,
        x=xa,
        v=va,
        lam=lam,
        n_pivots=n_piv,
        n_lcp_solves=n_solves,
        sigma=sig,
        reference_segment=r_seg,
        h=h,
        theta=th,
        system=system,
    )
