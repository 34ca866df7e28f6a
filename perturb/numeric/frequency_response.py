"""Frequency responses of approximations by amplitude parametrisation.

When an approximation's phase-eliminated amplitude equation is a polynomial in
``W = Omega**2`` of degree at most two (single-harmonic balance, first-order modified
Lindstedt–Poincaré, multiple scales and averaging on PWL and Duffing-type forces), fixing the
amplitude ``A`` and solving for ``W`` gives every point of the response, detached loops
included, without continuation and without a starting guess. The curve is then assembled
from the two roots, ``W_-(A)`` rising and ``W_+(A)`` falling, joined where the discriminant
vanishes (the peak), clipped to the requested frequency window and split into branches.
Stability comes from the eigenvalues of the slow-flow Jacobian; ``max_multiplier`` is
``exp(max Re(lambda) * 2*pi/Omega)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import sympy as sp

from ..approximation import Approximation
from ..errors import ParameterError, PerturbError
from ..methods.trig import _split_arg
from ..response import Branch, Response
from .compile import bind_parameters, lambdify
from .floquet import hill_exponents, monodromy_multipliers

__all__ = ["frequency_response", "solutions_at", "compile_response", "FrequencyResponseSolver"]

_SCAN_POINTS = 6000
_WAVEFORM_SAMPLES = 128
_FLOQUET_SAMPLES = 512
_CHUNK = 512
_STABILITY = ("hill", "floquet", "slow_flow")
#: a branch moves by at most 1/_WINDOW_RESOLUTION of the window (in Omega and in log Omega)
#: between two points inside it
_WINDOW_RESOLUTION = 128
#: bisection passes of that refinement (each halves the offending amplitude steps)
_REFINE_PASSES = 40


def _check_window(omega_range: Sequence[float]) -> tuple[float, float]:
    try:
        lo, hi = (float(w) for w in omega_range)
    except (TypeError, ValueError):
        raise ParameterError(
            f"omega_range = {omega_range!r}: expected two numbers (low, high)"
        ) from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ParameterError(f"omega_range = ({lo}, {hi}): expected 0 < low < high, both finite")
    return lo, hi


def _roots(c0: np.ndarray, c1: np.ndarray, c2: np.ndarray) -> tuple[np.ndarray, ...]:
    """Both roots of c2 W^2 + c1 W + c0 (NaN where complex), computed without cancellation."""
    disc = c1 * c1 - 4.0 * c2 * c0
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    q = -0.5 * (c1 + np.copysign(sq, c1))
    with np.errstate(divide="ignore", invalid="ignore"):
        r1 = q / c2
        r2 = c0 / q
        linear = c2 == 0
        r1 = np.where(linear, -c0 / c1, r1)
        r2 = np.where(linear, np.nan, r2)
    lo, hi = np.fmin(r1, r2), np.fmax(r1, r2)
    return lo, hi, disc


def _check_approximation(approx: Approximation, stability: str) -> None:
    if (
        approx.frequency_polynomial is None
        or approx.amplitude is None
        or approx.slow_flow is None
        or len(approx.unknowns) != 2
    ):
        raise PerturbError(
            f"{approx.label} has no amplitude equation in Omega^2 with a two-state slow flow; "
            "amplitude parametrisation does not apply"
        )
    if len(approx.frequency_polynomial) > 3:
        raise PerturbError(
            f"{approx.label}: amplitude equation of degree {len(approx.frequency_polynomial) - 1} "
            "in Omega^2; only degree <= 2 is traced by amplitude parametrisation"
        )
    if stability not in _STABILITY:
        raise ParameterError(f"stability = {stability!r}: expected one of {', '.join(_STABILITY)}")


def _polynomial(approx: Approximation):
    coeffs = list(approx.frequency_polynomial or ())
    coeffs += [sp.Integer(0)] * (3 - len(coeffs))
    return lambdify((approx.amplitude,), bind_parameters(approx, coeffs, keep=(approx.amplitude,)))


def solutions_at(
    approximation: Approximation,
    omegas: Sequence[float],
    *,
    stability: str = "hill",
    amplitude_range: Sequence[float] = (1e-8, 1e8),
) -> Response:
    """Every solution of ``approximation`` at exactly the forcing frequencies ``omegas``.

    All roots ``A`` of the amplitude equation at each frequency are bracketed on a
    logarithmic scan (pairs closer than its spacing, near a double root, by a search for the
    minimum between the scan points) and refined by bisection; solutions at consecutive
    frequencies are linked into branches by nearest amplitude. Use this when the output must
    contain given frequencies; :func:`frequency_response` traces smoother curves.

    Raises
    ------
    ParameterError
        For non-positive or non-finite frequencies.
    """
    cp = compile_response(approximation, stability)
    approx = cp.approx
    w_all = np.asarray(omegas, dtype=float).reshape(-1)
    if w_all.size == 0 or not np.all(np.isfinite(w_all)) or np.any(w_all <= 0):
        raise ParameterError(f"omegas = {list(omegas)!r}: expected positive finite frequencies")
    a_lo, a_hi = (float(a) for a in amplitude_range)
    if not (0 < a_lo < a_hi and np.isfinite(a_hi)):
        raise ParameterError(f"amplitude_range = {amplitude_range!r}: expected 0 < low < high")
    poly = cp.poly
    grid = np.geomspace(a_lo, a_hi, _SCAN_POINTS)
    c0, c1, c2 = poly(grid)
    W = (w_all**2)[:, None]
    vals = c0[None, :] + c1[None, :] * W + c2[None, :] * W * W
    iw, ia = np.nonzero(np.sign(vals[:, :-1]) * np.sign(vals[:, 1:]) < 0)
    lo_a, hi_a = grid[ia], grid[ia + 1]
    f_lo = vals[iw, ia]
    Wr = W[iw, 0]
    hidden = _hidden_root_pairs(poly, grid, vals, W)
    if hidden[0].size:
        iw = np.concatenate([iw, hidden[0], hidden[0]])
        lo_a = np.concatenate([lo_a, hidden[1], hidden[2]])
        hi_a = np.concatenate([hi_a, hidden[2], hidden[3]])
        Wr = W[iw, 0]
        d0, d1, d2 = poly(lo_a)
        f_lo = d0 + d1 * Wr + d2 * Wr * Wr
    for _ in range(80):  # bisection to full precision, all roots at once
        mid = 0.5 * (lo_a + hi_a)
        d0, d1, d2 = poly(mid)
        f_mid = d0 + d1 * Wr + d2 * Wr * Wr
        left = np.sign(f_mid) == np.sign(f_lo)
        lo_a, f_lo = np.where(left, mid, lo_a), np.where(left, f_mid, f_lo)
        hi_a = np.where(left, hi_a, mid)
    roots = 0.5 * (lo_a + hi_a)
    # Link the solutions into branches along the amplitude-parametrised curve: each solution
    # joins the traced branch passing nearest to it, ordered by position along that branch
    # (nearest-amplitude linking between frequencies fails on coarse grids near folds).
    span = (float(w_all.min()) * 0.95, float(w_all.max()) * 1.05)
    traced = frequency_response(cp, span, points=2000, stability="slow_flow")
    branches: list[list[tuple[float, float, float]]] = [[] for _ in traced.branches]
    wr = w_all[iw]
    for w, a in zip(wr, roots, strict=True):
        best = (np.inf, -1, 0)
        for b, br in enumerate(traced.branches):
            d = np.hypot(np.log(br.omega / w), np.log(br.first_harmonic_amplitude / a))
            k = int(np.argmin(d))
            if d[k] < best[0]:
                best = (d[k], b, k)
        if best[1] < 0 or best[0] > 0.1:  # no traced curve passes here: a branch of its own
            branches.append([(0, float(w), float(a))])
        else:
            branches[best[1]].append((best[2], float(w), float(a)))
    branches = [sorted(pts) for pts in branches if pts]
    out = []
    for pts in branches:
        w_b = np.array([p[1] for p in pts])
        a_b = np.array([p[2] for p in pts])
        out.append(_branch(cp, a_b, w_b, stability))
    return Response(tuple(out), approx.label, approx.oscillator.name, _params(approx))


def _hidden_root_pairs(poly, grid: np.ndarray, vals: np.ndarray, W: np.ndarray):
    """Pairs of roots in ``A`` that fall between two scan points without a sign change.

    Near a double root (where a detached branch meets another, or shrinks to a point as a
    parameter varies) the two roots are closer than the scan spacing and the sign test misses
    both.  Every interior local minimum of ``|P|`` on the scan (``P`` keeping its sign) is
    followed by golden-section search on ``sign * P`` over its two neighbouring intervals; a
    minimum of the other sign brackets two roots.  Returns the frequency indices and the
    brackets ``(left, minimum, right)``."""
    v = vals
    sg = np.sign(v[:, 1:-1])
    with np.errstate(invalid="ignore"):
        dip = (sg != 0) & (np.sign(v[:, :-2]) == sg) & (np.sign(v[:, 2:]) == sg)
        dip &= (sg * v[:, 1:-1] < sg * v[:, :-2]) & (sg * v[:, 1:-1] <= sg * v[:, 2:])
    iw, ic = np.nonzero(dip)
    ic = ic + 1
    empty = np.empty(0)
    if iw.size == 0:
        return np.empty(0, int), empty, empty, empty
    sgn = sg[iw, ic - 1]
    Wr = W[iw, 0]

    def f(a: np.ndarray) -> np.ndarray:
        c0, c1, c2 = poly(a)
        return sgn * (c0 + c1 * Wr + c2 * Wr * Wr)

    a, b = grid[ic - 1].copy(), grid[ic + 1].copy()
    g = 0.5 * (math.sqrt(5.0) - 1.0)
    x1, x2 = b - g * (b - a), a + g * (b - a)
    f1, f2 = f(x1), f(x2)
    for _ in range(90):
        left = f1 < f2  # the minimum lies in [a, x2]
        a, b = np.where(left, a, x1), np.where(left, x2, b)
        xn = np.where(left, b - g * (b - a), a + g * (b - a))
        fn = f(xn)
        x1, x2, f1, f2 = (
            np.where(left, xn, x2),
            np.where(left, x1, xn),
            np.where(left, fn, f2),
            np.where(left, f1, fn),
        )
    x_min = np.where(f1 < f2, x1, x2)
    found = np.minimum(f1, f2) < 0.0
    return iw[found], grid[ic - 1][found], x_min[found], grid[ic + 1][found]


def frequency_response(
    approximation: Approximation,
    omega_range: Sequence[float] = (0.2, 2.0),
    *,
    points: int = 2000,
    amplitude_range: Sequence[float] | None = None,
    stability: str = "hill",
) -> Response:
    """Every branch of the frequency response of ``approximation`` in ``omega_range``.

    Parameters
    ----------
    approximation
        Must provide ``frequency_polynomial`` (degree <= 2 in ``Omega**2``), ``amplitude``,
        ``phase_from`` and ``slow_flow``; all parameters but the frequency need values.
    omega_range
        ``(low, high)`` forcing frequencies.
    points
        Number of amplitudes on the fine grid (the response has up to twice as many points).
    amplitude_range
        ``(low, high)`` amplitudes to search; found automatically by default.
    stability
        ``"hill"`` (default): Hill's method about the approximate orbit, truncated at the
        approximation's harmonics, so stability changes exactly at its folds;
        ``"floquet"``: multipliers of the equation of motion linearised about the approximate
        orbit (all harmonics of the orbit's linearisation; changes near, not at, the folds of a
        coarse approximation); ``"slow_flow"``: eigenvalues of the method's slow-flow
        Jacobian (right only where the averaging ansatz holds: it calls the saddle orbit inside
        a negative-stiffness well stable).

    Returns
    -------
    Response

    Raises
    ------
    PerturbError
        If the approximation has no frequency polynomial; ParameterError for bad ranges or
        missing parameter values.
    """
    cp = compile_response(approximation, stability)
    approx = cp.approx
    if int(points) < 10:
        raise ParameterError(f"points = {points}: expected at least 10")
    lo, hi = _check_window(omega_range)
    poly = cp.poly

    def valid_mask(a: np.ndarray) -> tuple[np.ndarray, ...]:
        c0, c1, c2 = poly(a)
        wlo, whi, disc = _roots(c0, c1, c2)
        in_lo = (wlo >= lo * lo) & (wlo <= hi * hi)
        in_hi = (whi >= lo * lo) & (whi <= hi * hi)
        return wlo, whi, disc, in_lo, in_hi

    if amplitude_range is None:
        scan = np.geomspace(1e-8, 1e8, _SCAN_POINTS)
        wlo, whi, _, in_lo, in_hi = valid_mask(scan)
        # a root may also cross the window between two scan points without landing in it
        # (a narrow window, or Omega -> 0 where W = Omega**2 is tiny)
        through = _passes_window(wlo, whi, lo * lo, hi * hi)
        near = np.append(through, False) | np.insert(through, 0, False)
        hits = np.nonzero(in_lo | in_hi | near)[0]
        if hits.size == 0:
            return Response(
                (),
                approx.label,
                approx.oscillator.name,
                _params(approx),
                notes=("no periodic solution in the frequency window",),
            )
        a_lo = scan[max(hits[0] - 1, 0)]
        a_hi = scan[min(hits[-1] + 1, scan.size - 1)]
    else:
        a_lo, a_hi = (float(a) for a in amplitude_range)
        if not (0 < a_lo < a_hi and np.isfinite(a_hi)):
            raise ParameterError(
                f"amplitude_range = {amplitude_range!r}: expected 0 < low < high, finite"
            )
    grid = np.unique(
        np.concatenate(
            [np.geomspace(a_lo, a_hi, int(points) // 2), np.linspace(a_lo, a_hi, int(points) // 2)]
        )
    )
    grid = _insert_peaks(grid, poly)
    grid = _refine_in_window(grid, valid_mask, lo, hi)
    wlo, whi, disc, in_lo, in_hi = valid_mask(grid)

    # Walk each interval where real roots exist: W_- upwards in A, then W_+ back down.
    branches_pts: list[tuple[np.ndarray, np.ndarray]] = []
    real = np.isfinite(wlo) & (disc >= 0)
    idx = np.nonzero(real)[0]
    if idx.size:
        runs = np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1)
        for run in runs:
            a_path = np.concatenate([grid[run], grid[run][::-1]])
            w_path = np.concatenate([wlo[run], whi[run][::-1]])
            ok = np.concatenate([in_lo[run], in_hi[run][::-1]])
            ok &= np.isfinite(w_path) & (w_path > 0)
            cut = np.nonzero(np.diff(ok.astype(int)) != 0)[0] + 1
            for seg_a, seg_w, seg_ok in zip(
                np.split(a_path, cut), np.split(w_path, cut), np.split(ok, cut), strict=True
            ):
                if seg_ok.all() and seg_a.size >= 2:
                    branches_pts.append((seg_a, np.sqrt(seg_w)))
    branches = []
    folds: list[tuple[float, float]] = []
    for a_br, w_br in branches_pts:
        branches.append(_branch(cp, a_br, w_br, stability))
        folds.extend(_folds(a_br, w_br))
    return Response(
        tuple(branches),
        approx.label,
        approx.oscillator.name,
        _params(approx),
        folds=tuple(folds),
    )


def _params(approx: Approximation) -> dict[str, float]:
    return {k: v for k, v in approx.oscillator.params.items() if v is not None}


def _insert_peaks(grid: np.ndarray, poly) -> np.ndarray:
    """Add the amplitudes where the discriminant changes sign (response peaks and the ends of
    detached loops), found by bisection, so the two roots join exactly there."""
    c0, c1, c2 = poly(grid)
    disc = c1 * c1 - 4 * c2 * c0
    s = np.sign(disc)
    k = np.nonzero(s[:-1] * s[1:] < 0)[0]
    if k.size == 0:
        return grid
    a, b = grid[k].copy(), grid[k + 1].copy()
    fa = disc[k]
    for _ in range(60):
        m = 0.5 * (a + b)
        c0, c1, c2 = poly(m)
        fm = c1 * c1 - 4 * c2 * c0
        left = np.sign(fm) == np.sign(fa)
        a = np.where(left, m, a)
        fa = np.where(left, fm, fa)
        b = np.where(left, b, m)
    # keep the side with disc >= 0 so that the joining point has real roots
    c0, c1, c2 = poly(a)
    da = c1 * c1 - 4 * c2 * c0
    peaks = np.where(da >= 0, a, b)
    return np.unique(np.concatenate([grid, peaks]))


def _passes_window(wlo: np.ndarray, whi: np.ndarray, lo2: float, hi2: float) -> np.ndarray:
    """Per grid interval: does a root ``W`` meet ``[lo2, hi2]`` between its two ends?"""
    out = np.zeros(max(wlo.size - 1, 0), bool)
    for r in (wlo, whi):
        a, b = r[:-1], r[1:]
        with np.errstate(invalid="ignore"):
            out |= np.isfinite(a) & np.isfinite(b) & (np.fmin(a, b) <= hi2) & (np.fmax(a, b) >= lo2)
    return out


def _refine_in_window(grid: np.ndarray, valid_mask, lo: float, hi: float) -> np.ndarray:
    """Bisect the amplitude intervals over which a root's frequency moves by more than the
    window's resolution while inside it.

    The amplitude grid alone resolves the curve in ``A`` only: where ``Omega`` changes fast
    with ``A`` (a window narrow compared with that change, or ``Omega -> 0``, where a small
    step in ``A`` sweeps all of ``W = Omega**2 < lo**2 .. hi**2``) it would step over the
    window, and branches would be lost or start far inside it."""
    lin = (hi - lo) / _WINDOW_RESOLUTION
    log = math.log(hi / lo) / _WINDOW_RESOLUTION
    lo2, hi2 = lo * lo, hi * hi
    for _ in range(_REFINE_PASSES):
        wlo, whi = valid_mask(grid)[:2]
        need = np.zeros(grid.size - 1, bool)
        for r in (wlo, whi):
            a, b = r[:-1], r[1:]
            with np.errstate(invalid="ignore"):
                meets = np.isfinite(a) & np.isfinite(b) & (np.fmin(a, b) <= hi2)
                meets &= np.fmax(a, b) >= lo2
            # the part of the move that lies inside the window
            wa = np.sqrt(np.clip(np.where(meets, a, lo2), lo2, hi2))
            wb = np.sqrt(np.clip(np.where(meets, b, lo2), lo2, hi2))
            need |= meets & ((np.abs(wb - wa) > lin) | (np.abs(np.log(wb / wa)) > log))
        if not need.any():
            break
        grid = np.unique(np.concatenate([grid, 0.5 * (grid[:-1] + grid[1:])[need]]))
    return grid


def _folds(a: np.ndarray, w: np.ndarray) -> list[tuple[float, float]]:
    """Turning points of Omega along the branch (jump frequencies), by local parabolas."""
    dw = np.diff(w)
    out = []
    for i in np.nonzero(dw[:-1] * dw[1:] < 0)[0]:
        j = i + 1
        if a[j - 1] == a[j + 1]:  # the join of the two roots at a peak is not a fold
            continue
        out.append((float(w[j]), float(a[j])))
    return out


class _Waveform:
    """x(tau) of an approximation as a trigonometric polynomial with coefficients that depend
    on the unknowns: ``x = sum_n C_n cos(n tau) + S_n sin(n tau)``.

    The coefficients are compiled once and evaluated once per solution; samples, the mean, the
    first harmonic, the refined maximum and dx/dtau then cost matrix products. Evaluating the
    expression itself at every sample would recompute every closed-form Fourier coefficient
    of a PWL force (a dozen per solution) at each of hundreds of samples. A waveform that is
    not linear in cos/sin(n tau + c) falls back to sampling the compiled expression."""

    def __init__(self, approx: Approximation, A, phase, Omega) -> None:
        tau = approx.tau
        keep = (A, Omega, phase, tau)
        wave = bind_parameters(approx, [approx.waveform], keep)[0]
        self.args = (A, phase, Omega)
        self.terms: list[tuple[int, bool]] | None = None
        atoms = sorted(
            (f for f in wave.atoms(sp.cos, sp.sin) if f.has(tau)), key=sp.default_sort_key
        )
        dummies = [sp.Dummy(f"u{i}") for i in range(len(atoms))]
        sub = wave.xreplace(dict(zip(atoms, dummies, strict=True)))
        linear = not sub.has(tau)
        split: list[tuple[int, sp.Expr]] = []
        coefs: list[sp.Expr] = []
        if linear:
            try:
                split = [_split_arg(f.args[0], tau) for f in atoms]
            except PerturbError:
                linear = False
        if linear:
            coefs = [sp.diff(sub, d) for d in dummies]
            linear = not any(c.has(*dummies) for c in coefs)
        if linear:
            const = sub.xreplace({d: 0 for d in dummies})
            for i, (f, (n, c)) in enumerate(zip(atoms, split, strict=True)):
                if n < 0:  # cos(-n t + c) = cos(n t - c), sin(-n t + c) = -sin(n t - c)
                    split[i] = (-n, -c)
                    if isinstance(f, sp.sin):
                        coefs[i] = -coefs[i]
            self.terms = [
                (n, isinstance(f, sp.sin)) for (n, _), f in zip(split, atoms, strict=True)
            ]
            self.order = max([n for n, _ in split] + [1])
            self.fn = lambdify(self.args, [const, *coefs, *(c for _, c in split)])
        else:
            self.fn = lambdify((tau, *self.args), wave)
            self.dfn = lambdify((tau, *self.args), sp.diff(wave, tau))

    def coefficients(self, a, phi, w) -> tuple[np.ndarray, np.ndarray]:
        """``C, S`` of shape ``(n, order + 1)``."""
        assert self.terms is not None
        out = self.fn(a, phi, w)
        m = len(self.terms)
        C = np.zeros((a.size, self.order + 1))
        S = np.zeros_like(C)
        C[:, 0] = out[0]
        for (n, is_sin), coef, c in zip(self.terms, out[1 : 1 + m], out[1 + m :], strict=True):
            cc, sc = np.cos(c), np.sin(c)
            # cos(n tau + c) = cos c cos n tau - sin c sin n tau; sin(n tau + c) likewise
            if is_sin:
                C[:, n] += coef * sc
                S[:, n] += coef * cc
            else:
                C[:, n] += coef * cc
                S[:, n] -= coef * sc
        return C, S

    def samples(self, a, phi, w, count: int, coefs=None) -> tuple[np.ndarray, np.ndarray]:
        """``x`` and ``dx/dtau`` at ``count`` equally spaced phases, shape ``(n, count)``."""
        tau = np.linspace(0, 2 * np.pi, count, endpoint=False)
        if self.terms is None:
            args = (tau[None, :], a[:, None], phi[:, None], w[:, None])
            return self.fn(*args), self.dfn(*args)
        C, S = self.coefficients(a, phi, w) if coefs is None else coefs
        n = np.arange(C.shape[1])
        cos_t, sin_t = np.cos(np.outer(n, tau)), np.sin(np.outer(n, tau))
        x = C @ cos_t + S @ sin_t
        dx = (S * n) @ cos_t - (C * n) @ sin_t
        return x, dx

    def max_abs(self, a, phi, w, xs: np.ndarray, coefs=None) -> np.ndarray:
        """max |x(tau)|: the best of the samples ``xs`` polished by Newton on dx/dtau = 0
        (sampling alone would be low by up to 1 - cos(pi/N))."""
        count = xs.shape[1]
        step = 2 * np.pi / count
        t = step * np.argmax(np.abs(xs), axis=1)
        if self.terms is None:
            return np.max(np.abs(xs), axis=1)
        C, S = self.coefficients(a, phi, w) if coefs is None else coefs
        n = np.arange(C.shape[1])
        for _ in range(8):
            ct, st = np.cos(np.outer(t, n)), np.sin(np.outer(t, n))
            g1 = np.sum(n * (S * ct - C * st), axis=1)
            g2 = -np.sum(n * n * (C * ct + S * st), axis=1)
            with np.errstate(all="ignore"):
                dt = np.where(g2 != 0, -g1 / g2, 0.0)
            t = t + np.clip(np.nan_to_num(dt), -step, step)
        ct, st = np.cos(np.outer(t, n)), np.sin(np.outer(t, n))
        x = np.sum(C * ct + S * st, axis=1)
        return np.maximum(np.abs(x), np.max(np.abs(xs), axis=1))


class FrequencyResponseSolver:
    """An approximation compiled for :func:`frequency_response` and :func:`solutions_at`.

    Compiling (SymPy to numpy, with common subexpressions) costs far more than tracing a
    response; build one solver with :func:`compile_response` and pass it instead of the
    approximation when tracing many windows or parameter values' worth of responses.
    """

    def __init__(self, approx: Approximation) -> None:
        self.approx = approx
        self.A, self.Omega = approx.amplitude, approx.frequency
        self.phase = approx.unknowns[1] if len(approx.unknowns) > 1 else sp.Symbol("phi")
        keep = (self.A, self.Omega, self.phase, approx.tau)
        self.poly = _polynomial(approx)
        cos_part, sin_part = bind_parameters(approx, list(approx.phase_from or (1, 0)), keep)
        self.phase_fn = lambdify((self.A, self.Omega), [cos_part, sin_part])
        self.wave = _Waveform(approx, self.A, self.phase, self.Omega)
        self._jac = None

    def jacobian(self):
        if self._jac is None:
            keep = (self.A, self.Omega, self.phase, self.approx.tau)
            flow = bind_parameters(self.approx, list(self.approx.slow_flow or ()), keep)
            jac = sp.Matrix(flow).jacobian(sp.Matrix(self.approx.unknowns))
            self._jac = lambdify((self.A, self.phase, self.Omega), list(jac))
        return self._jac


def compile_response(
    approximation: Approximation | FrequencyResponseSolver, stability: str = "hill"
) -> FrequencyResponseSolver:
    """Compile ``approximation`` for tracing (a solver passes through unchanged).

    Raises
    ------
    PerturbError
        If the approximation has no amplitude equation in ``Omega**2`` of degree <= 2.
    ParameterError
        For an unknown ``stability`` or parameters without values.
    """
    if isinstance(approximation, FrequencyResponseSolver):
        _check_approximation(approximation.approx, stability)
        return approximation
    if not isinstance(approximation, Approximation):
        raise ParameterError(
            f"approximation = {approximation!r}: expected an Approximation (from a method in "
            "perturb.methods) or a compiled FrequencyResponseSolver"
        )
    _check_approximation(approximation, stability)
    return FrequencyResponseSolver(approximation)


def _branch(cp: FrequencyResponseSolver, a: np.ndarray, w: np.ndarray, stability: str) -> Branch:
    approx = cp.approx
    pc, ps = cp.phase_fn(a, w)
    phi = np.arctan2(ps, pc)
    phi = np.where(np.isfinite(phi), phi, 0.0)
    wave = cp.wave
    coefs = wave.coefficients(a, phi, w) if wave.terms is not None else None
    xs, _ = wave.samples(a, phi, w, _WAVEFORM_SAMPLES, coefs)
    amplitude = wave.max_abs(a, phi, w, xs, coefs)
    if coefs is not None:
        mean = coefs[0][:, 0]
        first = np.hypot(coefs[0][:, 1], coefs[1][:, 1])
    else:
        mean = xs.mean(axis=1)
        first = 2 * np.abs(np.fft.rfft(xs, axis=1)[:, 1]) / _WAVEFORM_SAMPLES

    period = 2 * np.pi / w
    if stability in ("floquet", "hill"):
        xf, dxf = wave.samples(a, phi, w, _FLOQUET_SAMPLES, coefs)
        vf = w[:, None] * dxf  # dx/dt = Omega dx/dtau
        max_mult = _floquet_in_chunks(approx, xf, vf, period, cp.Omega, w, stability)
        stable = max_mult < 1 - 1e-9
    else:
        j11, j12, j21, j22 = cp.jacobian()(a, phi, w)
        tr = j11 + j22
        det = j11 * j22 - j12 * j21
        disc = tr * tr / 4 - det
        # largest real part of the two eigenvalues of the 2x2 slow-flow Jacobian
        re_max = np.where(disc >= 0, tr / 2 + np.sqrt(np.abs(disc)), tr / 2)
        max_mult = np.exp(np.clip(re_max * period, -700, 700))
        stable = re_max < 0
    return Branch(
        omega=w,
        amplitude=amplitude,
        first_harmonic_amplitude=first,
        mean=mean,
        stable=stable,
        max_multiplier=max_mult,
    )


def _floquet_in_chunks(approx, xf, vf, period, Omega, w, stability) -> np.ndarray:
    out = np.empty(period.size)
    # amplitude parametrisation applies to single-harmonic amplitude equations (two unknowns,
    # amplitude and phase): Hill's truncation must match the balanced harmonics, one, for its
    # singularity to fall on the folds; the waveform's extra harmonics (a method's
    # ``harmonics`` option, e.g. 15 for modified L-P on a PWL force) enter only through the
    # linearisation's coefficients
    harmonics = 1
    for start in range(0, period.size, _CHUNK):
        sl = slice(start, start + _CHUNK)
        if stability == "hill":
            lam = hill_exponents(approx.oscillator, xf[sl], vf[sl], period[sl], harmonics, Omega)
            re = np.max(lam.real, axis=1)
            out[sl] = np.exp(np.clip(re * period[sl], -700, 700))
        else:
            out[sl] = monodromy_multipliers(approx.oscillator, xf[sl], vf[sl], period[sl], Omega)
    return out
