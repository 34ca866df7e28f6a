"""Frequency responses of approximations by amplitude parametrisation.

When an approximation's phase-eliminated amplitude equation is a polynomial in
``W = Omega**2`` of degree at most two (single-harmonic balance, first-order modified
Lindstedt–Poincaré, multiple scales and averaging on PWL and Duffing-type forces), fixing the
amplitude ``A`` and solving for ``W`` gives every point of the response, detached loops
included, without continuation and without a starting guess. The curve is then assembled
from the two roots, ``W_-(A)`` rising and ``W_+(A)`` falling, joined where the discriminant
vanishes (the peak), clipped to the requested frequency window and split into branches.
Stability comes from Hill's method, Floquet multipliers of the linearisation, or the
eigenvalues of the slow-flow Jacobian; ``max_multiplier`` is ``exp(max Re(lambda) * 2*pi/Omega)``.

Speed: every expression the tracer evaluates depends on the amplitude through a few Fourier
coefficient functions (``RampCoefficient(n, A, 0, 1)`` ...). Their stable numeric forms
cost a fixed set-up per call that exceeds the arithmetic on thousands of amplitudes, so
they are compiled as plain inputs (:class:`_Atoms`), evaluated once per new amplitude, and
all root refinements run vectorised over every bracket at once (:func:`bracketed_roots`,
:func:`safe_newton`). ``max |x|`` comes from the waveform's critical points
(:func:`critical_points`), and Hill's method for PWL oscillators integrates the piecewise-constant
stiffness exactly between the orbit's breakpoint crossings (:class:`_PWLHill`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import sympy as sp

from perturb import checks
from perturb.approximation import Approximation
from perturb.errors import ParameterError, PerturbError
from perturb.fourier.coefficients import UNCHECKED
from perturb.fourier.symbols import (
    NUMERIC_IMPLEMENTATIONS,
    DiracCoefficient,
    RampCoefficient,
    StepCoefficient,
)
from perturb.fourier.trig import split_argument as _split_arg
from perturb.numeric.compile import bind_parameters, lambdify
from perturb.numeric.stability import hill_exponents, monodromy_multipliers
from perturb.response import Branch, Response

__all__ = [
    "approximation_response",
    "solutions_at",
    "compile_response",
    "FrequencyResponseSolver",
    # the vectorised numerical kernels of the tracer (public so that they can be tested and
    # benchmarked on their own, against SciPy and LAPACK)
    "bracketed_roots",
    "safe_newton",
    "critical_points",
    "max_abs_at",
    "hill1_matrix",
    "hill1_exponents",
]

_SCAN_POINTS = 6000
_SCAN_RANGE = (1e-8, 1e8)
WAVEFORM_SAMPLES = 128
#: samples of a waveform that is not a trigonometric polynomial, for its extremes
EXTREMES_SAMPLES = 256
FLOQUET_SAMPLES = 512
_CHUNK = 512
_STABILITY = ("hill", "floquet", "slow_flow")
#: a branch moves by at most 1/_WINDOW_RESOLUTION of the window (in Omega and in log Omega)
#: between two points inside it
_WINDOW_RESOLUTION = 128
#: bisection passes of that refinement (each halves the offending amplitude steps)
_REFINE_PASSES = 40
_FOURIER = (StepCoefficient, RampCoefficient, DiracCoefficient)

#: atom values per amplitude: {atom index: values}
AtomValues = dict[int, np.ndarray]


def _check_window(omega_range: Sequence[float]) -> tuple[float, float]:
    return checks.window(omega_range, "omega_range")


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


def _in_window(wlo: np.ndarray, whi: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, ...]:
    """Whether each root ``W`` lies in ``[lo**2, hi**2]`` (frequencies ``lo`` to ``hi``)."""
    in_lo = (wlo >= lo * lo) & (wlo <= hi * hi)
    in_hi = (whi >= lo * lo) & (whi <= hi * hi)
    return in_lo, in_hi


def bracketed_roots(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray],
    a: np.ndarray,
    b: np.ndarray,
    fa: np.ndarray,
    fb: np.ndarray,
    max_iter: int = 400,
    guess: np.ndarray | None = None,
    probe: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Shrink every bracket ``[a, b]`` (``a < b``, ``f(a) f(b) < 0``) onto its root, all
    brackets in one call of ``f`` per iteration.

    ``f(x, idx)`` evaluates the functions of the brackets ``idx`` at ``x``. Regula falsi with
    the Illinois modification converges superlinearly; a bisection every second step where the
    bracket has not halved keeps the worst case at twice plain bisection (multiple roots). Stops
    when each bracket is two ulps wide or an exact zero is hit (then ``a == b``). Returns the
    final ``a, b`` and the signs-preserving values ``fa, fb`` (``f(a)`` and ``f(b)`` up to
    the Illinois halving).

    With ``probe > 0`` each step evaluates ``x -+ probe * (b - a)`` about the estimate ``x``
    (``guess`` on the first step) instead of ``x`` itself and keeps the sub-bracket with the
    sign change: once the estimate is that accurate the bracket shrinks by ``2 probe`` per
    call of ``f``, which is what counts when each call has a large fixed cost."""
    a, b = np.array(a, float), np.array(b, float)
    fa, fb = np.array(fa, float), np.array(fb, float)
    b = np.where(fa == 0, a, b)  # an end that is already a root
    a = np.where(fb == 0, b, a)
    side = np.zeros(a.shape, int)  # which end the last step replaced: -1 b, +1 a
    ref = b - a
    for it in range(max_iter):
        width = b - a
        active = (width > 2 * np.spacing(np.maximum(np.abs(a), np.abs(b)))) & (fa != 0)
        active &= fb != 0
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            break
        A, B, FA, FB = a[idx], b[idx], fa[idx], fb[idx]
        with np.errstate(all="ignore"):
            x = B - FB * (B - A) / (FB - FA)
        if it == 0 and guess is not None:
            x = np.asarray(guess, float)[idx]
        bisect = ~((x > A) & (x < B))
        if it % 2 == 1:  # safeguard: bisect the brackets that did not halve in two steps
            bisect |= width[idx] > 0.5 * ref[idx]
            ref[idx] = width[idx]
        x = np.where(bisect, 0.5 * (A + B), x)
        if probe > 0:
            e = np.maximum(probe * (B - A), np.spacing(np.abs(x)))
            xl, xr = np.maximum(x - e, A), np.minimum(x + e, B)
            fv = f(np.concatenate([xl, xr]), np.concatenate([idx, idx]))
            fl, fr = fv[: idx.size], fv[idx.size :]
            left = np.sign(fl) != np.sign(FA)  # the root lies in [A, xl]
            mid = ~left & (np.sign(fr) != np.sign(fl))  # in [xl, xr], else in [xr, B]
            a[idx] = np.where(left, A, np.where(mid, xl, xr))
            fa[idx] = np.where(left, FA, np.where(mid, fl, fr))
            b[idx] = np.where(left, xl, np.where(mid, xr, B))
            fb[idx] = np.where(left, fl, np.where(mid, fr, FB))
            for val, at in ((fl, xl), (fr, xr)):  # exact zeros close the bracket
                z = val == 0
                a[idx[z]] = b[idx[z]] = at[z]
                fa[idx[z]] = fb[idx[z]] = 0.0
            continue
        fx = f(x, idx)
        zero = fx == 0
        keep_a = (np.sign(fx) == np.sign(FA)) & ~zero  # the root lies in [x, B]
        keep_b = ~keep_a & ~zero
        s = side[idx]
        # Illinois: halve the stored value of an end retained twice in a row
        FB = np.where(keep_a & (s == 1), 0.5 * FB, FB)
        FA = np.where(keep_b & (s == -1), 0.5 * FA, FA)
        a[idx] = np.where(keep_a | zero, x, A)
        fa[idx] = np.where(keep_a | zero, fx, FA)
        b[idx] = np.where(keep_b | zero, x, B)
        fb[idx] = np.where(keep_b | zero, fx, FB)
        side[idx] = np.where(keep_a, 1, np.where(keep_b, -1, 0))
    return a, b, fa, fb


def _cubic_guess(x: np.ndarray, y: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Root in ``[x[k], x[k+1]]`` (where ``y`` changes sign) of the cubic through the four
    samples ``k-1 .. k+2`` (shifted inwards at the ends): error ~h^4 instead of the ~h^2 of
    the secant, so :func:`bracketed_roots` with a small ``probe`` closes in a few calls."""
    if x.size < 4:
        return x[k] - y[k] * (x[k + 1] - x[k]) / (y[k + 1] - y[k])
    j = np.clip(k - 1, 0, x.size - 4)
    lo, hi = x[k], x[k + 1]
    # cubic in u = (x - lo) / (hi - lo) through the four points: a batch of 4x4 solves
    u = (np.stack([x[j + i] for i in range(4)], axis=1) - lo[:, None]) / (hi - lo)[:, None]
    V = u[:, :, None] ** np.arange(4)
    c = np.linalg.solve(V, np.stack([y[j + i] for i in range(4)], axis=1)[:, :, None])[:, :, 0]
    t = np.clip(y[k] / (y[k] - y[k + 1]), 0.0, 1.0)
    for _ in range(6):  # Newton on the cubic, kept inside the bracket
        p = ((c[:, 3] * t + c[:, 2]) * t + c[:, 1]) * t + c[:, 0]
        dp = (3 * c[:, 3] * t + 2 * c[:, 2]) * t + c[:, 1]
        with np.errstate(all="ignore"):
            t = np.clip(np.nan_to_num(t - p / dp, nan=0.5), 0.0, 1.0)
    t = lo + t * (hi - lo)
    return t


class _Atoms:
    """The Fourier-coefficient functions of the amplitude alone that appear in an
    approximation's expressions, evaluated together.

    In the compiled expressions each such function (``RampCoefficient(n, A, b, d)`` with
    numbers ``n, b, d``) is a plain input; :meth:`evaluate` computes them with the stable
    numeric forms of :mod:`perturb.fourier.coefficients`, all harmonics of one breakpoint in one
    call.
    Evaluated inside a lambdified expression, each would cost a separate call with its fixed
    set-up (0.3-1 ms on the development machine) per use, which dominated the tracing time."""

    def __init__(self, A: sp.Symbol, unchecked: bool = True) -> None:
        self.A = A
        self._plans: dict[tuple[int, ...], list] = {}
        self._unchecked = bool(unchecked)
        self.atoms: list[sp.Expr] = []
        self.symbols: list[sp.Dummy] = []
        self._index: dict[sp.Expr, int] = {}

    @property
    def unchecked(self) -> bool:
        """Evaluate with the unchecked kernels of :mod:`perturb.fourier.coefficients`
        (bit-identical on valid input); ``False`` keeps the public, validating ones (the
        benchmark's same-process baseline). Setting it drops the evaluation plans, which hold
        the kernels chosen."""
        return self._unchecked

    @unchecked.setter
    def unchecked(self, value: bool) -> None:
        self._unchecked = bool(value)
        self._plans.clear()

    def absorb(self, exprs: Sequence[sp.Expr]) -> tuple[list[sp.Expr], list[int]]:
        """``exprs`` with the atoms replaced by their symbols, and the atom indices used."""
        found: set[sp.Expr] = set()
        for e in exprs:
            found |= sp.sympify(e).atoms(*_FOURIER)
        mapping: dict[sp.Expr, sp.Expr] = {}
        for f in sorted(found, key=sp.default_sort_key):
            n, arg, b, d = f.args
            if not (
                n.is_Integer
                and b.is_number
                and d.is_number
                and arg.free_symbols <= {self.A}
                and not arg.has(*_FOURIER)
            ):
                continue  # left inside the expression, evaluated by lambdify as before
            if f not in self._index:
                self._index[f] = len(self.atoms)
                self.atoms.append(f)
                self.symbols.append(sp.Dummy(f"atom{len(self.atoms)}"))
            mapping[f] = self.symbols[self._index[f]]
        rows = sorted(self._index[f] for f in mapping)
        return [sp.sympify(e).xreplace(mapping) for e in exprs], rows

    def evaluate(self, a: np.ndarray, rows: Sequence[int], into: AtomValues | None = None):
        """Values of the atoms ``rows`` at the amplitudes ``a`` (added to ``into``)."""
        out: AtomValues = {} if into is None else into
        rows = tuple(r for r in rows if r not in out)
        if not rows:
            return out
        plan = self._plans.get(rows)
        if plan is None:
            groups: dict[tuple, list[tuple[int, int]]] = {}
            for r in rows:
                f = self.atoms[r]
                n, arg, b, d = f.args
                groups.setdefault((type(f).__name__, arg, b, d), []).append((r, int(n)))
            plan = []
            for (name, arg, b, d), members in groups.items():
                arg_fn = None if arg == self.A else lambdify((self.A,), arg)
                ns = np.array([n for _, n in members])[:, None]
                # the unchecked twin of the public kernel: ns, the amplitudes and b, d are
                # built here and valid, and the checks would be most of a call's fixed cost
                checked = NUMERIC_IMPLEMENTATIONS[name]
                fn = UNCHECKED.get(checked, checked) if self.unchecked else checked
                plan.append((fn, arg_fn, float(b), float(d), members, ns))
            self._plans[rows] = plan
        a = np.asarray(a, float)
        for fn, arg_fn, b, d, members, ns in plan:
            x = a if arg_fn is None else np.asarray(arg_fn(a), float)
            vals = np.asarray(fn(ns, x, b, d), float) if a.size else np.empty((len(members), 0))
            for (r, _), v in zip(members, vals, strict=True):
                out[r] = v
        return out


class _Compiled:
    """Expressions in ``args`` and the amplitude's Fourier atoms, compiled with the atoms as
    plain inputs; call as ``f(U, *values)`` with ``U`` from :meth:`_Atoms.evaluate`."""

    def __init__(self, atoms: _Atoms, args: Sequence[sp.Symbol], exprs: Sequence[sp.Expr]):
        exprs, self.rows = atoms.absorb(exprs)
        # plain sympy.lambdify (same modules as .compile.lambdify): these are called with
        # arrays of one shape, so only constant outputs need broadcasting, not every output
        self.fn = sp.lambdify(
            (*args, *(atoms.symbols[r] for r in self.rows)),
            list(exprs),
            modules=[NUMERIC_IMPLEMENTATIONS, "numpy"],
            cse=True,
        )

    def __call__(self, U: AtomValues, *values):
        inputs = (*values, *(U[r] for r in self.rows))
        shape = np.broadcast_shapes(*(np.shape(v) for v in inputs))
        with np.errstate(all="ignore"):
            out = self.fn(*inputs)
        return [
            o
            if isinstance(o, np.ndarray) and o.shape == shape and o.dtype == float
            else np.broadcast_to(np.asarray(o, dtype=float), shape)
            for o in out
        ]


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


def solutions_at(
    approximation: Approximation | FrequencyResponseSolver,
    omegas: Sequence[float],
    *,
    stability: str = "hill",
    amplitude_range: Sequence[float] = _SCAN_RANGE,
) -> Response:
    """Every solution of ``approximation`` at exactly the forcing frequencies ``omegas``.

    All roots ``A`` of the amplitude equation at each frequency are bracketed on a
    logarithmic scan (pairs closer than its spacing, near a double root, by a search for the
    minimum between the scan points) and refined to full precision; solutions at
    consecutive frequencies are linked into branches along the traced curve. Use this when
    the output must contain given frequencies; :func:`approximation_response` traces smoother
    curves.

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
    iw, roots = _roots_at(cp, w_all, a_lo, a_hi)
    wr = w_all[iw]
    # Link the solutions into branches along the amplitude-parametrised curve: each solution
    # joins the traced branch passing nearest to it, ordered by position along that branch
    # (nearest-amplitude linking between frequencies fails on coarse grids near folds).
    span = (float(w_all.min()) * 0.95, float(w_all.max()) * 1.05)
    traced = approximation_response(cp, span, points=2000, stability="slow_flow")
    branches: list[list[tuple[float, float, float]]] = [[] for _ in traced.branches]
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
    groups = [sorted(pts) for pts in branches if pts]
    out: list[Branch] = []
    if groups:
        sizes = [len(pts) for pts in groups]
        a_all = np.array([p[2] for pts in groups for p in pts])
        w_b = np.array([p[1] for pts in groups for p in pts])
        U = cp.atoms.evaluate(a_all, cp.branch_rows(stability))
        out = _branches(cp, a_all, w_b, U, sizes, stability)
    notes = response_notes(approx, out, (float(w_all.min()), float(w_all.max())))
    return Response(tuple(out), approx.label, approx.oscillator.name, _params(approx), notes=notes)


def _roots_at(
    cp: FrequencyResponseSolver,
    w_all: np.ndarray,
    a_lo: float,
    a_hi: float,
    params: Sequence[float] = (),
    points: int = _SCAN_POINTS,
    pairs: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Every root ``A`` of the amplitude equation at each frequency of ``w_all`` (with the
    free parameters at ``params``): ``(frequency indices, amplitudes)``, one entry per root,
    bracketed on a logarithmic scan of ``[a_lo, a_hi]`` with ``points`` amplitudes and refined
    to full precision; ``pairs``: also the root pairs between two scan points
    (:func:`_hidden_root_pairs`)."""

    def poly(x: np.ndarray) -> list[np.ndarray]:
        return cp.poly(x, *params)

    if (a_lo, a_hi) == _SCAN_RANGE and points == _SCAN_POINTS and cp.scan is not None:
        grid, (c0, c1, c2) = cp.scan
    else:
        grid = np.geomspace(a_lo, a_hi, points)
        c0, c1, c2 = poly(grid)
    W = (w_all**2)[:, None]
    vals = c0[None, :] + c1[None, :] * W + c2[None, :] * W * W
    iw, ia = np.nonzero(np.sign(vals[:, :-1]) * np.sign(vals[:, 1:]) < 0)
    lo_a, hi_a = grid[ia], grid[ia + 1]
    f_lo, f_hi = vals[iw, ia], vals[iw, ia + 1]
    if pairs:
        hidden = _hidden_root_pairs(poly, grid, vals, W)
    else:
        hidden = (np.empty(0, int),)
    if hidden[0].size:
        iw = np.concatenate([iw, hidden[0], hidden[0]])
        lo_a = np.concatenate([lo_a, hidden[1], hidden[2]])
        hi_a = np.concatenate([hi_a, hidden[2], hidden[3]])
        Wh = W[iw, 0]
        d0, d1, d2 = poly(lo_a)
        f_lo = d0 + d1 * Wh + d2 * Wh * Wh
        d0, d1, d2 = poly(hi_a)
        f_hi = d0 + d1 * Wh + d2 * Wh * Wh
    Wr = W[iw, 0]

    def residual(x: np.ndarray, idx: np.ndarray) -> np.ndarray:
        d0, d1, d2 = poly(x)
        return d0 + d1 * Wr[idx] + d2 * Wr[idx] * Wr[idx]

    lo_a, hi_a, _, _ = bracketed_roots(residual, lo_a, hi_a, f_lo, f_hi)
    roots = 0.5 * (lo_a + hi_a)
    return iw, roots


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
        if np.all(np.minimum(f1, f2) < 0.0):  # every pair bracketed: the minimum is not needed
            break
    x_min = np.where(f1 < f2, x1, x2)
    found = np.minimum(f1, f2) < 0.0
    return iw[found], grid[ic - 1][found], x_min[found], grid[ic + 1][found]


class _Grid:
    """Increasing amplitudes with their polynomial atoms and coefficients ``c`` (3, n)."""

    def __init__(self, cp: FrequencyResponseSolver, a: np.ndarray) -> None:
        self.cp = cp
        self.a = a
        self.U = cp.atoms.evaluate(a, cp.poly_rows)
        self.c = np.array(cp.poly_u(self.U, a)).reshape(3, -1)

    def add(self, new: np.ndarray) -> None:
        if new.size == 0:
            return
        U = self.cp.atoms.evaluate(new, self.cp.poly_rows)
        c = np.array(self.cp.poly_u(U, new)).reshape(3, -1)
        a = np.concatenate([self.a, new])
        order = np.argsort(a, kind="stable")
        keep = np.ones(a.size, bool)
        keep[1:] = np.diff(a[order]) > 0
        sel = order[keep]
        self.a = a[sel]
        self.U = {r: np.concatenate([self.U[r], U[r]])[sel] for r in self.U}
        self.c = np.concatenate([self.c, c], axis=1)[:, sel]

    def roots(self, lo: float, hi: float) -> tuple[np.ndarray, ...]:
        wlo, whi, disc = _roots(*self.c)
        return (wlo, whi, disc, *_in_window(wlo, whi, lo, hi))


def approximation_response(
    approximation: Approximation | FrequencyResponseSolver,
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
        ``phase_from`` and ``slow_flow``; all parameters but the frequency need values. A
        :class:`FrequencyResponseSolver` from :func:`compile_response` skips compiling.
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

    if amplitude_range is None:
        scan, coeffs = cp.scan
        wlo, whi, _ = _roots(*coeffs)
        in_lo, in_hi = _in_window(wlo, whi, lo, hi)
        # a root may also cross the window between two scan points without landing in it
        # (a narrow window, or Omega -> 0 where W = Omega**2 is tiny)
        through = _passes_window(wlo, whi, lo * lo, hi * hi)
        near = np.append(through, False) | np.insert(through, 0, False)
        hits = np.nonzero(in_lo | in_hi | near)[0]
        if hits.size == 0:
            return _fixed_frequency_response(cp, lo, hi, stability)
        a_lo = scan[max(hits[0] - 1, 0)]
        a_hi = scan[min(hits[-1] + 1, scan.size - 1)]
    else:
        a_lo, a_hi = (float(a) for a in amplitude_range)
        if not (0 < a_lo < a_hi and np.isfinite(a_hi)):
            raise ParameterError(
                f"amplitude_range = {amplitude_range!r}: expected 0 < low < high, finite"
            )
    grid = _Grid(
        cp,
        np.unique(
            np.concatenate(
                [
                    np.geomspace(a_lo, a_hi, int(points) // 2),
                    np.linspace(a_lo, a_hi, int(points) // 2),
                ]
            )
        ),
    )
    _refine_in_window(grid, lo, hi, extra=_peaks(grid))
    wlo, whi, disc, in_lo, in_hi = grid.roots(lo, hi)

    # Walk each interval where real roots exist: W_- upwards in A, then W_+ back down.
    segments: list[tuple[np.ndarray, np.ndarray]] = []  # (grid indices, Omega)
    real = np.isfinite(wlo) & (disc >= 0)
    idx = np.nonzero(real)[0]
    if idx.size:
        runs = np.split(idx, np.nonzero(np.diff(idx) > 1)[0] + 1)
        for run in runs:
            i_path = np.concatenate([run, run[::-1]])
            w_path = np.concatenate([wlo[run], whi[run][::-1]])
            ok = np.concatenate([in_lo[run], in_hi[run][::-1]])
            ok &= np.isfinite(w_path) & (w_path > 0)
            cut = np.nonzero(np.diff(ok.astype(int)) != 0)[0] + 1
            for seg_i, seg_w, seg_ok in zip(
                np.split(i_path, cut), np.split(w_path, cut), np.split(ok, cut), strict=True
            ):
                if seg_ok.all() and seg_i.size >= 2:
                    segments.append((seg_i, np.sqrt(seg_w)))
    folds: list[tuple[float, float]] = []
    branches: list[Branch] = []
    if segments:
        gi = np.concatenate([s[0] for s in segments])
        w_all = np.concatenate([s[1] for s in segments])
        # the remaining atoms only where a branch passes, each amplitude once
        used, inverse = np.unique(gi, return_inverse=True)
        U_used = {r: v[used] for r, v in grid.U.items()}
        cp.atoms.evaluate(grid.a[used], cp.branch_rows(stability), into=U_used)
        U = {r: v[inverse] for r, v in U_used.items()}
        sizes = [s[0].size for s in segments]
        branches = _branches(cp, grid.a[gi], w_all, U, sizes, stability)
        for seg_i, seg_w in segments:
            folds.extend(_folds(grid.a[seg_i], seg_w))
    if not branches and amplitude_range is None:
        return _fixed_frequency_response(cp, lo, hi, stability)
    return Response(
        tuple(branches),
        approx.label,
        approx.oscillator.name,
        _params(approx),
        folds=tuple(folds),
        notes=response_notes(approx, branches, (lo, hi)),
    )


#: Frequencies solved one by one when amplitude parametrisation finds nothing in a window.
_FIXED_FREQUENCIES = 41


def _fixed_frequency_response(
    cp: FrequencyResponseSolver, lo: float, hi: float, stability: str
) -> Response:
    """The response at ``_FIXED_FREQUENCIES`` frequencies solved one by one.

    Amplitude parametrisation resolves ``W = Omega**2`` only to the rounding of the amplitude
    equation's coefficients: a window such as ``Omega`` in ``[1e-9, 1e-8]`` (``W`` below
    ``1e-16``) is crossed between two amplitudes that differ in the last bit, so no point lands
    in it. At a fixed frequency the equation in ``A`` is well conditioned; when every
    frequency has the same number of solutions they are joined in amplitude order."""
    approx = cp.approx
    w_grid = np.linspace(lo, hi, _FIXED_FREQUENCIES)
    iw, roots = _roots_at(cp, w_grid, *_SCAN_RANGE)
    wr = w_grid[iw]
    counts = np.array([np.count_nonzero(wr == w) for w in w_grid])
    branches: list[Branch] = []
    notes: tuple[str, ...] = ()
    if roots.size and np.all(counts == counts[0]):
        m = int(counts[0])
        order = np.lexsort((roots, wr))  # by frequency, then amplitude
        table = roots[order].reshape(w_grid.size, m)
        a_all = table.T.reshape(-1)
        w_b = np.tile(w_grid, m)
        U = cp.atoms.evaluate(a_all, cp.branch_rows(stability))
        branches = list(_branches(cp, a_all, w_b, U, [w_grid.size] * m, stability))
        notes = (
            f"solved at {w_grid.size} fixed frequencies: amplitude parametrisation cannot "
            f"resolve Omega**2 in [{lo * lo:.3g}, {hi * hi:.3g}] (the window is too narrow or too "
            "close to 0 for the rounding of the amplitude equation)",
        )
    elif roots.size:
        notes = (
            f"no branch traced: amplitude parametrisation cannot resolve Omega**2 in "
            f"[{lo * lo:.3g}, {hi * hi:.3g}], and the number of solutions changes across the "
            "window (between "
            f"{int(counts.min())} and {int(counts.max())}); ask for the solutions at given "
            "frequencies (frequencies=[...], `--omega w1,w2,...`) or widen the window",
        )
    return Response(
        tuple(branches),
        approx.label,
        approx.oscillator.name,
        _params(approx),
        notes=notes + response_notes(approx, branches, (lo, hi)),
    )


def _undamped(approx: Approximation) -> bool:
    """True when the oscillator has neither viscous damping (at its parameter values) nor
    velocity-dependent terms: a conservative system."""
    osc = approx.oscillator
    damping = sp.sympify(osc.damping).xreplace(osc.substitutions())
    return damping.is_zero is True and osc.velocity == 0


def response_notes(
    approx: Approximation, branches: Sequence[Branch], window: tuple[float, float]
) -> tuple[str, ...]:
    """What a reader of a response must know that the numbers do not say.

    - no branch at all: why, and what to try instead;
    - a conservative (undamped) forced model: stability is marginal and undecided;
    - the approximation's own ``notes``, which its method wrote when it derived it (e.g. a
      force with an even polynomial part under a first-order zero-mean method,
      :mod:`perturb.methods.caveats`): copied, this layer writes no method-specific note.

    Used by :func:`approximation_response`, :func:`solutions_at` and
    :func:`perturb.numeric.residual.residual_response`.
    """
    notes: list[str] = []
    lo, hi = window
    if not branches:
        notes.append(
            f"0 branches: {approx.label} has no periodic solution with Omega in "
            f"[{lo:.6g}, {hi:.6g}] (its amplitude equation has no root there); try a wider "
            "window, check the parameter values, or use numeric harmonic balance ('hb') or "
            "'exact'"
        )
    osc = approx.oscillator
    if osc.forcing.harmonics and _undamped(approx):
        notes.append(
            "no damping: the model is conservative, so the Floquet multipliers of every forced "
            "orbit lie on the unit circle (up to rounding) and stability is marginal, not "
            "decided by linearisation: the 'stable' column is not meaningful here. Add damping "
            "(e.g. --param mu=0.01) to decide stability, or compute the backbone (the free "
            "undamped response)"
        )
    notes.extend(approx.notes)
    return tuple(notes)


def _params(approx: Approximation) -> dict[str, float]:
    return {k: v for k, v in approx.oscillator.params.items() if v is not None}


def _discriminant(c: np.ndarray) -> np.ndarray:
    return c[1] * c[1] - 4 * c[2] * c[0]


def _peaks(grid: _Grid) -> np.ndarray:
    """The amplitudes where the discriminant changes sign (response peaks and the ends of
    detached loops), to full precision, so that the two roots join exactly there (to be
    added to the grid)."""
    disc = _discriminant(grid.c)
    s = np.sign(disc)
    k = np.nonzero(s[:-1] * s[1:] < 0)[0]
    if k.size == 0:
        return np.empty(0)
    cp = grid.cp

    def f(x: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return _discriminant(np.array(cp.poly_u(cp.atoms.evaluate(x, cp.poly_rows), x)))

    guess = _cubic_guess(grid.a, disc, k)
    a, b, fa, _ = bracketed_roots(
        f, grid.a[k], grid.a[k + 1], disc[k], disc[k + 1], guess=guess, probe=1e-6
    )
    # keep the side with disc >= 0 so that the joining point has real roots
    return np.where(fa >= 0, a, b)


def _passes_window(wlo: np.ndarray, whi: np.ndarray, lo2: float, hi2: float) -> np.ndarray:
    """Per grid interval: does a root ``W`` meet ``[lo2, hi2]`` between its two ends?"""
    out = np.zeros(max(wlo.size - 1, 0), bool)
    for r in (wlo, whi):
        a, b = r[:-1], r[1:]
        with np.errstate(invalid="ignore"):
            out |= np.isfinite(a) & np.isfinite(b) & (np.fmin(a, b) <= hi2) & (np.fmax(a, b) >= lo2)
    return out


def _refine_in_window(grid: _Grid, lo: float, hi: float, extra: np.ndarray | None = None) -> None:
    """Subdivide the amplitude intervals over which a root's frequency moves by more than the
    window's resolution while inside it.

    The amplitude grid alone resolves the curve in ``A`` only: where ``Omega`` changes fast
    with ``A`` (a window narrow compared with that change, or ``Omega -> 0``, where a small
    step in ``A`` sweeps all of ``W = Omega**2 < lo**2 .. hi**2``) it would step over the
    window, and branches would be lost or start far inside it. An offending interval is cut
    into as many equal parts as its move exceeds the resolution (at most 16 per pass, so one
    pass usually suffices where the move is smooth in ``A``); only new points are evaluated,
    ``extra`` amplitudes together with the first pass."""
    lin = (hi - lo) / _WINDOW_RESOLUTION
    log = math.log(hi / lo) / _WINDOW_RESOLUTION
    lo2, hi2 = lo * lo, hi * hi
    for _ in range(_REFINE_PASSES):
        wlo, whi = grid.roots(lo, hi)[:2]
        excess = np.zeros(grid.a.size - 1)
        for r in (wlo, whi):
            a, b = r[:-1], r[1:]
            with np.errstate(invalid="ignore"):
                meets = np.isfinite(a) & np.isfinite(b) & (np.fmin(a, b) <= hi2)
                meets &= np.fmax(a, b) >= lo2
            # the part of the move that lies inside the window
            wa = np.sqrt(np.clip(np.where(meets, a, lo2), lo2, hi2))
            wb = np.sqrt(np.clip(np.where(meets, b, lo2), lo2, hi2))
            move = np.maximum(np.abs(wb - wa) / lin, np.abs(np.log(wb / wa)) / log)
            excess = np.maximum(excess, np.where(meets, move, 0.0))
        need = np.nonzero(excess > 1)[0]
        if need.size == 0 and extra is None:
            break
        parts = np.clip(np.ceil(1.25 * excess[need]), 2, 16).astype(int)
        start = np.repeat(grid.a[need], parts - 1)
        width = np.repeat(grid.a[need + 1] - grid.a[need], parts - 1)
        # fraction j / parts for j = 1 .. parts - 1 of each interval
        first = np.repeat(np.cumsum(parts - 1) - (parts - 1), parts - 1)
        j = np.arange(first.size) - first + 1
        new = start + width * j / np.repeat(parts, parts - 1)
        if extra is not None:  # checked by the next pass like any other new point
            new, extra = np.concatenate([new, extra]), None
        grid.add(new)


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


def _trig_samples(C: np.ndarray, S: np.ndarray, count: int) -> np.ndarray:
    """The rows ``sum_n C_n cos(n tau_j) + S_n sin(n tau_j)`` at ``tau_j = 2 pi j / count``,
    shape ``(rows, count)``, by an inverse real FFT (``count > 2 * order``). A matrix
    product with a table of cos/sin would go through a threaded BLAS, which on a busy
    machine spends more time waiting for its threads than computing these small products."""
    X = np.empty(C.shape, complex)
    X.real, X.imag = 0.5 * count * C, -0.5 * count * S
    X[:, 0] = count * C[:, 0]
    return np.fft.irfft(X, n=count, axis=1)


class _TrigRows:
    """Trigonometric polynomials ``x_i(t) = sum_n C_in cos(n t) + S_in sin(n t)`` for the rows
    ``rows`` of ``C, S``, restricted to the harmonics present (e.g. the odd ones of a
    waveform with half-wave symmetry), evaluated at one ``t`` each.

    With ``P_n = C_n cos(n t) + S_n sin(n t)`` and ``Q_n = S_n cos(n t) - C_n sin(n t)`` the
    derivatives are ``x^(k) = (-1)^(k // 2) sum_n n^k (P_n if k is even else Q_n)``: weighted
    sums of the same products for every order, where scaled copies of ``C, S`` per order
    (and their gathering for each active set) cost more than the sums themselves."""

    def __init__(self, C: np.ndarray, S: np.ndarray, rows: np.ndarray) -> None:
        self.ns = np.flatnonzero(np.any(C, axis=0) | np.any(S, axis=0))
        self.n = self.ns.astype(float)
        # (harmonic, row) in row-major order, the layout of the tables of _powers: the
        # transposed view of C would make every sum stride across memory
        self.CT = np.ascontiguousarray(C.T[self.ns]).take(rows, axis=1)
        self.ST = np.ascontiguousarray(S.T[self.ns]).take(rows, axis=1)

    def _powers(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``cos(n t), sin(n t)`` for the harmonics present, from products of
        ``exp(i g t)`` over the gaps ``g`` between them (each adds ~1 ulp)."""
        z = np.empty((self.ns.size, t.size), complex)
        steps: dict[int, np.ndarray] = {}
        prev_n, prev = 0, None
        for i, n in enumerate(self.ns):
            g = int(n) - prev_n
            if g == 0:
                z[i] = 1.0
            else:
                if g not in steps:
                    steps[g] = np.exp(1j * g * t)
                if prev is None:
                    z[i] = steps[g]
                else:
                    np.multiply(prev, steps[g], out=z[i])
            prev, prev_n = z[i], int(n)
        return z.real, z.imag

    def __call__(self, t: np.ndarray, idx: np.ndarray | None = None, orders=(0,)):
        """``d^k x_i / dt^k (t)`` for ``k`` in ``orders`` and the polynomials ``idx``."""
        ct, st = self._powers(t)
        c, s = self.CT, self.ST
        if idx is not None and idx.size < c.shape[1]:
            c, s = c[:, idx], s[:, idx]
        out = []
        for k in orders:
            # x^(k) = (-1)^(k // 2) sum_n n^k P_n (k even) or Q_n (k odd); each sum fused in
            # one einsum: the tables are too large for the cache, and temporaries for P_n,
            # Q_n made the sums memory-bound (twice slower on all points at once)
            wk = (-1.0) ** (k // 2) * self.n**k
            if k % 2 == 0:
                out.append(np.einsum("j,ji,ji->i", wk, c, ct) + np.einsum("j,ji,ji->i", wk, s, st))
            else:
                out.append(np.einsum("j,ji,ji->i", wk, s, ct) - np.einsum("j,ji,ji->i", wk, c, st))
        return out


def safe_newton(
    fdf: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]],
    lo: np.ndarray,
    hi: np.ndarray,
    f_lo: np.ndarray,
    f_hi: np.ndarray,
    x: np.ndarray,
    xtol: float,
    max_iter: int = 100,
) -> np.ndarray:
    """Roots of functions with known derivatives in brackets ``[lo, hi]`` (values of
    opposite signs at the ends), all at once: Newton from ``x``, replaced by a bisection
    whenever it leaves the bracket or does not halve the previous step (as in Numerical
    Recipes' ``rtsafe``). ``fdf(x, idx)`` returns the values and derivatives of the
    functions ``idx`` at ``x`` (optionally also second derivatives: Halley's method); stops
    after a step below ``xtol`` (whose own error is of the order of its square, or cube)."""
    neg = np.where(f_lo < 0, lo, hi).astype(float)
    pos = np.where(f_lo < 0, hi, lo).astype(float)
    x = np.array(x, float)
    x = np.where(f_lo == 0, lo, np.where(f_hi == 0, hi, x))
    step_old = np.abs(hi - lo)
    active = (f_lo != 0) & (f_hi != 0)
    for _ in range(max_iter):
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            break
        xi = x[idx]
        f, df, *d2f = fdf(xi, idx)
        ng, ps = np.where(f < 0, xi, neg[idx]), np.where(f > 0, xi, pos[idx])
        neg[idx], pos[idx] = ng, ps
        with np.errstate(all="ignore"):
            dx = f / df
            if d2f:  # Halley's correction: cubic convergence for the price of one more sum
                dx = dx / (1 - 0.5 * dx * d2f[0] / df)
        xn = xi - dx
        # converged: the Newton step itself is below xtol (the check must not wait for the
        # bracket test, which rounding fails once xn == xi)
        done = (f == 0) | (np.abs(dx) <= xtol)
        inside = (xn - ng) * (xn - ps) < 0
        bisect = ~done & (~inside | (np.abs(2 * f) > np.abs(step_old[idx] * df)))
        xn = np.where(bisect, 0.5 * (ng + ps), np.where(f == 0, xi, xn))
        step_old[idx] = np.abs(xn - xi)
        x[idx] = xn
        active[idx] = ~done
    return x


def _level_crossings(C, S, rows, d, lo, hi, x_lo, x_hi) -> np.ndarray:
    """The ``tau`` in ``[lo, hi]`` where the rows ``rows`` of ``x = sum_n C_n cos(n tau) +
    S_n sin(n tau)``, monotone from ``x_lo = x(lo)`` to ``x_hi = x(hi)`` (consecutive
    critical points), cross the level ``d``, to full precision.

    The first guess takes the piece for half a cosine wave, ``x ~ m + h cos(pi s)`` with
    ``s`` the position in ``[lo, hi]`` (exact for a pure first harmonic); Halley's steps
    (cubic convergence, the second derivative costs one more weighted sum of the products
    already formed) then stop after a step below ``1e-7``, whose own error is of the order
    of its cube (``~1e-21`` times the curvature scale): two or three evaluations for most
    pieces (a few non-sinusoidal ones need up to seven), where Newton's steps from the
    bracket's middle needed 5 to 9."""
    poly = _TrigRows(C, S, rows)
    m, h = 0.5 * (x_lo + x_hi), 0.5 * (x_lo - x_hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.arccos(np.clip(np.nan_to_num((d - m) / h), -1.0, 1.0)) / np.pi
    guess = lo + s * (hi - lo)

    def level(t, idx):
        x, dx, d2x = poly(t, idx, (0, 1, 2))
        return x - d, dx, d2x

    return safe_newton(level, lo, hi, x_lo - d, x_hi - d, guess, 1e-7)


def critical_points(C: np.ndarray, S: np.ndarray, count: int = WAVEFORM_SAMPLES):
    """Every critical point of the rows ``x(tau) = sum_n C_n cos(n tau) + S_n sin(n tau)``.

    Returns flat arrays ``rows, tau, x`` ordered by row, then ``tau`` in ``[0, 2 pi)``.
    Where the first harmonic ``c1 cos(tau - t1)`` dominates (``R1 = sum n |c_n|`` and
    ``R2 = sum n^2 |c_n|`` over ``n >= 2`` with ``R2 < c1 sqrt(1 - (R1/c1)^2)``), ``x'`` can
    vanish only where ``|sin(tau - t1)| <= R1/c1`` and is strictly monotone there: exactly one
    critical point near ``t1`` and one near ``t1 + pi``, each bracketed (only the first when
    the harmonics are all odd: then ``x(t + pi) = -x(t)``). Other rows are
    bracketed by sign changes of ``x'`` at ``count`` samples. All brackets are then refined
    together to full precision."""
    n_rows, K = C.shape
    n = np.arange(K)
    # (only for the dominance test below: sqrt(C^2 + S^2) is within an ulp of hypot, at a
    # third of its cost)
    amp = np.sqrt(C * C + S * S)
    c1 = amp[:, 1] if K > 1 else np.zeros(n_rows)
    R1 = amp[:, 2:] @ n[2:].astype(float)
    R2 = amp[:, 2:] @ (n[2:] ** 2).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = R1 / c1
        rho_max = np.sqrt(np.clip(1 - (R2 / c1) ** 2, 0, None))
    dom = (c1 > 0) & (rho < rho_max)
    rows_d = np.nonzero(dom)[0]
    # half-width of the two regions, with room so that x' has a strict sign at their ends
    half = np.arcsin(0.5 * (rho[rows_d] + rho_max[rows_d]))
    t1 = np.arctan2(S[rows_d, 1], C[rows_d, 1]) if K > 1 else np.zeros(0)
    # half-wave symmetry (odd harmonics only): x(t + pi) = -x(t), one region suffices
    sym = ~(np.any(C[rows_d, 0::2], axis=1) | np.any(S[rows_d, 0::2], axis=1))
    n_max, n_min = rows_d.size, int(np.count_nonzero(~sym))
    centre = np.concatenate([t1, t1[~sym] + np.pi])
    r_b = np.concatenate([rows_d, rows_d[~sym]])
    half = np.concatenate([half, half[~sym]])
    lo_b, hi_b = centre - half, centre + half
    other = np.nonzero(~dom)[0]
    dxs, ro, j = np.empty((0, count)), np.empty(0, int), np.empty(0, int)
    if other.size:
        dxs = _trig_samples(S[other] * n, -C[other] * n, count)
        up = dxs >= 0
        ro, j = np.nonzero(up != np.roll(up, -1, axis=1))
        step = 2 * np.pi / count
        r_b = np.concatenate([r_b, other[ro]])
        lo_b = np.concatenate([lo_b, step * j])
        hi_b = np.concatenate([hi_b, step * (j + 1)])
    if r_b.size == 0:
        empty = np.empty(0)
        return np.empty(0, int), empty, empty
    guess = np.concatenate([centre, 0.5 * (lo_b[centre.size :] + hi_b[centre.size :])])
    # x' is known to be > 0 at the left end of the region about the maximum t1 and < 0 at
    # its right end (the reverse about t1 + pi); the sampled brackets carry their samples
    f_lo = np.concatenate([np.ones(n_max), -np.ones(n_min), dxs[ro, j]])
    f_hi = np.concatenate([-np.ones(n_max), np.ones(n_min), dxs[ro, (j + 1) % count]])
    poly = _TrigRows(C, S, r_b)

    def slope(t: np.ndarray, idx: np.ndarray):
        return poly(t, idx, (1, 2, 3))

    # after a Halley step below 1e-3 the position is good to ~1e-9 (times the curvature
    # scale), and the value at a critical point depends on it only to second order
    t = safe_newton(slope, lo_b, hi_b, f_lo, f_hi, guess, 1e-3)
    x = poly(t)[0]
    mirror = np.nonzero(sym)[0]
    r_b = np.concatenate([r_b, r_b[mirror]])
    t = np.mod(np.concatenate([t, t[mirror] + np.pi]), 2 * np.pi)
    x = np.concatenate([x, -x[mirror]])
    # by row, then tau: one argsort of the key row * 8 + tau (tau < 2 pi < 8), a fifth of
    # lexsort's cost; rounding of the key can only tie (not swap) two taus of a row, and
    # lexsort settles the rare ties
    order = np.argsort(r_b * 8.0 + t, kind="stable")
    ro_, to_ = r_b[order], t[order]
    if np.any((ro_[1:] == ro_[:-1]) & (to_[1:] <= to_[:-1])):
        order = np.lexsort((t, r_b))
    return r_b[order], t[order], x[order]


def max_abs_at(rows: np.ndarray, xe: np.ndarray, n_rows: int, const: np.ndarray) -> np.ndarray:
    """max |x| per row from its critical values (``|const|`` for rows without any)."""
    out = np.abs(np.asarray(const, float)).copy()
    if rows.size:
        first = np.ones(rows.size, bool)
        first[1:] = rows[1:] != rows[:-1]
        starts = np.nonzero(first)[0]
        out[rows[starts]] = np.maximum.reduceat(np.abs(xe), starts)
    return out


class Waveform:
    """x(tau) of an approximation as a trigonometric polynomial with coefficients that depend
    on the unknowns: ``x = sum_n C_n cos(n tau) + S_n sin(n tau)``.

    The coefficients are compiled once and evaluated once per solution; samples, the mean, the
    first harmonic, the refined maximum and dx/dtau then cost matrix products. Evaluating the
    expression itself at every sample would recompute every closed-form Fourier coefficient
    of a PWL force (a dozen per solution) at each of hundreds of samples. A waveform that is
    not linear in cos/sin(n tau + c) falls back to sampling the compiled expression. With
    ``atoms`` (:class:`_Atoms` of the amplitude ``A``) the coefficients are also compiled with
    the amplitude's Fourier coefficients as inputs (``coefficients(..., U=...)``)."""

    def __init__(
        self,
        approx: Approximation,
        A,
        phase,
        Omega,
        atoms: _Atoms | None = None,
        parameters: Sequence[sp.Symbol] = (),
    ):
        tau = approx.tau
        keep = (A, Omega, phase, tau, *parameters)
        wave = bind_parameters(approx, [approx.waveform], keep)[0]
        self.args = (A, phase, Omega, *parameters)
        self._tau = tau
        self._expr = wave
        self._d2fn: Callable | None = None
        self.terms: list[tuple[int, bool]] | None = None
        self.fn_atoms: _Compiled | None = None
        atoms_ = sorted(
            (f for f in wave.atoms(sp.cos, sp.sin) if f.has(tau)), key=sp.default_sort_key
        )
        dummies = [sp.Dummy(f"u{i}") for i in range(len(atoms_))]
        sub = wave.xreplace(dict(zip(atoms_, dummies, strict=True)))
        linear = not sub.has(tau)
        split: list[tuple[int, sp.Expr]] = []
        coefs: list[sp.Expr] = []
        if linear:
            try:
                split = [_split_arg(f.args[0], tau) for f in atoms_]
            except PerturbError:
                linear = False
        if linear:
            coefs = [sp.diff(sub, d) for d in dummies]
            linear = not any(c.has(*dummies) for c in coefs)
        if linear:
            const = sub.xreplace({d: 0 for d in dummies})
            for i, (f, (n, c)) in enumerate(zip(atoms_, split, strict=True)):
                if n < 0:  # cos(-n t + c) = cos(n t - c), sin(-n t + c) = -sin(n t - c)
                    split[i] = (-n, -c)
                    if isinstance(f, sp.sin):
                        coefs[i] = -coefs[i]
            self.terms = [
                (n, isinstance(f, sp.sin)) for (n, _), f in zip(split, atoms_, strict=True)
            ]
            self.order = max([n for n, _ in split] + [1])
            exprs = [const, *coefs, *(c for _, c in split)]
            self.fn = lambdify(self.args, exprs)
            if atoms is not None:
                self.fn_atoms = _Compiled(atoms, self.args, exprs)
        else:
            self.fn = lambdify((tau, *self.args), wave)
            self.dfn = lambdify((tau, *self.args), sp.diff(wave, tau))

    @property
    def rows(self) -> list[int]:
        """The atoms :meth:`coefficients` needs with ``U``."""
        return [] if self.fn_atoms is None else self.fn_atoms.rows

    def coefficients(self, a, phi, w, U: AtomValues | None = None, params: Sequence[float] = ()):
        """``C, S`` of shape ``(n, order + 1)`` (``params``: values of the free parameters)."""
        assert self.terms is not None
        a = np.asarray(a, float)
        if U is not None and self.fn_atoms is not None:
            out = self.fn_atoms(U, a, phi, w, *params)
        else:
            out = self.fn(a, phi, w, *params)
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

    def samples(
        self, a, phi, w, count: int, coefs=None, params: Sequence[float] = ()
    ) -> tuple[np.ndarray, np.ndarray]:
        """``x`` and ``dx/dtau`` at ``count`` equally spaced phases, shape ``(n, count)``."""
        if self.terms is None:
            tau = np.linspace(0, 2 * np.pi, count, endpoint=False)
            args = (tau[None, :], a[:, None], phi[:, None], w[:, None], *params)
            return self.fn(*args), self.dfn(*args)
        C, S = self.coefficients(a, phi, w, params=params) if coefs is None else coefs
        n = np.arange(C.shape[1])
        if count <= 2 * (C.shape[1] - 1):  # too few samples for the FFT: sum directly
            tau = np.linspace(0, 2 * np.pi, count, endpoint=False)
            ct, st = np.cos(np.outer(n, tau)), np.sin(np.outer(n, tau))
            return np.einsum("ik,kj->ij", C, ct) + np.einsum("ik,kj->ij", S, st), np.einsum(
                "ik,kj->ij", S * n, ct
            ) - np.einsum("ik,kj->ij", C * n, st)
        return _trig_samples(C, S, count), _trig_samples(S * n, -C * n, count)

    def extremes(
        self, a, phi, w, U: AtomValues | None = None, params: Sequence[float] = ()
    ) -> tuple[np.ndarray, np.ndarray]:
        """``min x`` and ``max x`` over a period for each orbit ``(a, phi, w)``.

        A trigonometric polynomial: the extreme values at its critical points (see
        :func:`critical_points`; the constant where there is none). Otherwise the best of
        ``EXTREMES_SAMPLES`` samples, each polished by Newton steps on ``dx/dtau = 0`` kept
        within a sample spacing (samples alone are low by up to ``A (1 - cos(pi / count))``).
        """
        a = np.asarray(a, float)
        if self.terms is not None:
            C, S = self.coefficients(a, phi, w, U, params)
            rows, _, xe = critical_points(C, S)
            lo, hi = C[:, 0].copy(), C[:, 0].copy()
            if rows.size:
                first = np.ones(rows.size, bool)
                first[1:] = rows[1:] != rows[:-1]
                starts = np.nonzero(first)[0]
                lo[rows[starts]] = np.minimum.reduceat(xe, starts)
                hi[rows[starts]] = np.maximum.reduceat(xe, starts)
            return lo, hi
        if self._d2fn is None:
            self._d2fn = lambdify((self._tau, *self.args), sp.diff(self._expr, self._tau, 2))
        tau = np.linspace(0.0, 2 * np.pi, EXTREMES_SAMPLES, endpoint=False)
        xs = self.fn(tau[None, :], a[:, None], phi[:, None], w[:, None], *params)
        step = tau[1] - tau[0]
        out = []
        for pick in (np.argmin, np.argmax):
            t = tau[pick(xs, axis=1)]
            for _ in range(8):  # Newton on dx/dtau = 0, capped at 8 steps
                d1 = self.dfn(t, a, phi, w, *params)
                d2 = self._d2fn(t, a, phi, w, *params)
                with np.errstate(all="ignore"):
                    dt = np.where(d2 != 0, -d1 / d2, 0.0)
                t = t + np.clip(np.nan_to_num(dt), -step, step)
            out.append(self.fn(t, a, phi, w, *params))
        return np.minimum(out[0], xs.min(axis=1)), np.maximum(out[1], xs.max(axis=1))

    def max_abs(self, a, phi, w, xs: np.ndarray, coefs=None) -> np.ndarray:
        """max |x(tau)|: the largest value at the critical points of the trigonometric
        polynomial (see :func:`critical_points`), or of the samples ``xs`` if that is larger or the
        waveform is not a trigonometric polynomial."""
        best = np.max(np.abs(xs), axis=1)
        if self.terms is None:
            return best
        C, S = self.coefficients(a, phi, w) if coefs is None else coefs
        rows, _, xe = critical_points(C, S, max(xs.shape[1], WAVEFORM_SAMPLES))
        return np.maximum(best, max_abs_at(rows, xe, C.shape[0], C[:, 0]))


class _PWLHill:
    """Hill's method with one harmonic about orbits of a piecewise-linear oscillator with
    constant damping, ``x'' + p x' + g(x) = f(t)``.

    The linearisation's stiffness ``q(t) = g'(x(t))`` is piecewise constant, jumping by
    ``dq`` where the orbit crosses a breakpoint at ``tau_c``; integrating by parts gives its
    Fourier coefficients exactly, ``q_k = sum_c dq_c exp(-i k tau_c) / (2 pi i k)``
    (``k != 0``), so only the crossings of the trigonometric polynomial ``x(tau)`` are needed,
    found to full precision between its extrema (no crossing is missed however close to
    grazing). :func:`~perturb.numeric.stability.hill_exponents` integrates the same
    coefficients over hundreds of sampled pieces per orbit."""

    def __init__(self, breakpoints: np.ndarray, slopes: np.ndarray, damping: float) -> None:
        self.breakpoints = breakpoints
        self.slopes = slopes
        self.damping = damping

    @classmethod
    def build(cls, osc, frequency: sp.Symbol) -> _PWLHill | None:
        """``None`` unless the model is PWL in ``x`` with a constant damping coefficient."""
        if not osc.is_piecewise_linear or osc.parametric != 0:
            return None
        subs = {s: val for s, val in osc.substitutions().items() if s != frequency}
        g = osc.g.xreplace(subs)
        gv = sp.diff(g, osc.v).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
        if gv.free_symbols or sp.expand(g - gv * osc.v).has(osc.v):
            return None
        gx = sp.diff(g, osc.x).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
        if gx.free_symbols - {osc.x}:
            return None
        bps = np.array([])
        if osc.nonsmooth != 0:
            try:
                bps = np.sort(np.asarray(osc.piecewise_linear().numeric().breakpoints, float))
            except PerturbError:
                return None
        # one probe inside each segment: the breakpoints' midpoints and one beyond each end
        if bps.size:
            probe = np.concatenate([[bps[0] - 1], 0.5 * (bps[:-1] + bps[1:]), [bps[-1] + 1]])
        else:
            probe = np.zeros(1)
        slopes = np.asarray(lambdify((osc.x,), gx)(probe), float)
        if not np.all(np.isfinite(slopes)):
            return None
        return cls(bps, slopes, float(gv))

    def crossings(self, C, S, r, te, xe):
        """Breakpoint crossings of the orbits with critical points ``(r, te, xe)`` (from
        :func:`critical_points`): row, phase ``tau`` in ``[0, 2 pi)`` and jump of ``q``.

        An orbit with half-wave symmetry (odd harmonics only: ``x(tau + pi) = -x(tau)``)
        crosses ``-d`` at ``tau + pi`` where it crosses ``d`` at ``tau``, in the other
        direction: where ``-d`` is a breakpoint too, only the crossings of ``d > 0`` are
        solved for such orbits (half the work on the symmetric PWL forces of the seeds)."""
        empty = np.empty(0)
        if r.size == 0 or self.breakpoints.size == 0:
            return np.empty(0, int), empty, empty
        # monotone pieces from each critical point to the next one of the same orbit (cyclic)
        nxt = np.arange(r.size) + 1
        first = np.ones(r.size, bool)
        first[1:] = r[1:] != r[:-1]
        last = np.ones(r.size, bool)
        last[:-1] = r[1:] != r[:-1]
        starts = np.nonzero(first)[0]
        nxt[last] = starts[np.cumsum(first)[last] - 1]
        t_end = np.where(last, te[nxt] + 2 * np.pi, te[nxt])
        x_end = xe[nxt]
        bps, dqs = self.breakpoints, np.diff(self.slopes)
        sym_row = ~(np.any(C[:, 0::2], axis=1) | np.any(S[:, 0::2], axis=1))
        rows, taus, jumps = [], [], []
        solved: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        # positive breakpoints first, so that their mirrors can reuse them
        for i in sorted(range(bps.size), key=lambda i: -bps[i]):
            d, dq = bps[i], dqs[i]
            k = np.nonzero((xe - d) * (x_end - d) < 0)[0]
            mirror = solved.get(-d) if d < 0 else None
            if mirror is not None:
                k = k[~sym_row[r[k]]]
                rm, tm, upm = mirror
                m = sym_row[rm]
                rows.append(rm[m])
                taus.append(np.mod(tm[m] + np.pi, 2 * np.pi))
                # x crosses -d downwards at tau + pi where it crosses d upwards at tau
                jumps.append(np.where(upm[m], -dq, dq))
            if k.size == 0:
                continue
            rk = r[k]
            tc = _level_crossings(C, S, rk, d, te[k], t_end[k], xe[k], x_end[k])
            up = x_end[k] > xe[k]
            solved[d] = (rk, tc, up)
            rows.append(rk)
            taus.append(np.mod(tc, 2 * np.pi))
            jumps.append(np.where(up, dq, -dq))
        if not rows:
            return np.empty(0, int), empty, empty
        return np.concatenate(rows), np.concatenate(taus), np.concatenate(jumps)

    def max_multiplier(self, coefs, extrema, w) -> np.ndarray:
        """``exp(max Re(lambda) T)`` of the two Floquet exponents of Hill's ``H = 1``
        truncation, for orbits ``x(tau)`` with coefficients ``coefs``, critical points
        ``extrema`` (from :func:`critical_points`) and frequencies ``w``."""
        C, S = coefs
        n_orb = C.shape[0]
        rows, tau, jump = self.crossings(C, S, *extrema)
        # q_0 = q(0+) + sum_c dq_c (2 pi - tau_c) / (2 pi); q_k by parts (see the class)
        x0 = C.sum(axis=1)
        seg = np.searchsorted(self.breakpoints, x0) if self.breakpoints.size else 0
        q0 = self.slopes[seg] + np.bincount(
            rows, jump * (2 * np.pi - tau) / (2 * np.pi), minlength=n_orb
        )
        # q = q0 + sum_k qc_k cos(k tau) + qs_k sin(k tau), k = 1, 2
        qc, qs = [], []
        e1 = np.exp(-1j * tau)
        for k, e in ((1, e1), (2, e1 * e1)):  # (squaring: one complex exp fewer, ~1 ulp)
            z = jump * e / (2j * np.pi * k)  # q_k = (qc_k - i qs_k) / 2
            qc.append(2 * np.bincount(rows, z.real, minlength=n_orb))
            qs.append(-2 * np.bincount(rows, z.imag, minlength=n_orb))
        lam = hill1_exponents(q0, qc[0], qs[0], qc[1], qs[1], w, self.damping)
        # of the 2 (2H + 1) eigenvalues the two with the smallest |Im| are the exponents
        order = np.argsort(np.abs(lam.imag) + 1e-12 * np.abs(lam.real), axis=1)
        re = np.max(np.take_along_axis(lam, order[:, :2], axis=1).real, axis=1)
        return np.exp(np.clip(re * 2 * np.pi / w, -700, 700))


def hill1_matrix(q0, qc1, qs1, qc2, qs2, w, p) -> np.ndarray:
    """The ``(n, 6, 6)`` first-order matrices of Hill's ``H = 1`` truncation whose eigenvalues
    :func:`hill1_exponents` returns (the reference it is tested against).

    In the real basis ``(1, cos wt, sin wt)`` -- the same subspace as the harmonics
    ``n = -1, 0, 1`` of :func:`~perturb.numeric.stability.hill_exponents` -- ``y = exp(lambda t)
    u`` turns ``u'' + (2 lambda + p) u' + (lambda^2 + p lambda + q) u = 0`` into
    ``(lambda^2 + lambda (2 D + p) + D^2 + p D + Q) u = 0``, ``D`` the derivative and ``Q``
    the product with ``q = q0 + sum_k qc_k cos(k wt) + qs_k sin(k wt)``."""
    n_orb = np.size(w)
    Qr = np.empty((n_orb, 3, 3))
    Qr[:, 0] = np.stack([q0, qc1 / 2, qs1 / 2], axis=1)
    Qr[:, 1] = np.stack([qc1, q0 + qc2 / 2, qs2 / 2], axis=1)
    Qr[:, 2] = np.stack([qs1, qs2 / 2, q0 - qc2 / 2], axis=1)
    D = np.zeros((n_orb, 3, 3))
    D[:, 1, 2], D[:, 2, 1] = w, -w
    eye = np.eye(3)
    big = np.zeros((n_orb, 6, 6))
    big[:, :3, 3:] = eye
    big[:, 3:, :3] = -(D @ D + p * D + Qr)
    big[:, 3:, 3:] = -(2 * D + p * eye)
    return big


def hill1_exponents(q0, qc1, qs1, qc2, qs2, w, p) -> np.ndarray:
    """The six eigenvalues ``lambda`` of :func:`hill1_matrix`, shape ``(n, 6)``, in closed form.

    ``lambda = nu - p/2`` removes the damping: ``det((nu + D)^2 + Q - p^2/4) = 0``, and as
    ``D`` is skew and ``Q`` symmetric in an orthonormal basis this determinant is even in
    ``nu`` -- a cubic ``s^3 + a s^2 + b s + c`` in ``s = nu^2`` (coefficients from SymPy; ``c``
    is the determinant at ``nu = 0``). Its roots by Cardano (one real root, Newton-polished,
    then the deflated quadratic, each complex root given one guarded Newton step) cost a few
    dozen array operations for all orbits, where ``numpy.linalg.eigvals`` ran LAPACK's
    ``dgeev`` once per 6x6 matrix (~6 us each: 2/3 of a response's Hill stability). The
    eigenvalues agree with ``dgeev``'s to its own backward error (see the tests)."""
    r = q0 - 0.25 * p * p
    w2 = w * w
    a = 3 * r + 2 * w2
    b = 3 * r * r + w2 * w2 - 0.25 * (2 * qc1 * qc1 + qc2 * qc2 + 2 * qs1 * qs1 + qs2 * qs2)
    # c = det(D^2 + Q - p^2/4): rows (r, qc1/2, qs1/2), (qc1, r - w2 + qc2/2, qs2/2),
    # (qs1, qs2/2, r - w2 - qc2/2)
    m11, m22 = r - w2 + 0.5 * qc2, r - w2 - 0.5 * qc2
    m12 = 0.5 * qs2
    c = (
        r * (m11 * m22 - m12 * m12)
        - 0.5 * qc1 * (qc1 * m22 - m12 * qs1)
        + 0.5 * qs1 * (qc1 * m12 - m11 * qs1)
    )
    # one real root: Cardano where the discriminant is positive, else the trigonometric form
    shift = a / 3
    pp = b - a * shift
    qq = (2 * shift * shift - b) * shift + c
    disc = 0.25 * qq * qq + pp * pp * pp / 27
    with np.errstate(all="ignore"):
        u = np.cbrt(-0.5 * qq - np.copysign(np.sqrt(np.maximum(disc, 0.0)), qq))
        one = u - np.where(u != 0, pp / (3 * u), 0.0)
        m = 2 * np.sqrt(np.maximum(-pp / 3, 0.0))
        arg = np.clip(np.where(m > 0, 3 * qq / (pp * m), 0.0), -1.0, 1.0)
        three = m * np.cos(np.arccos(arg) / 3)
        s1 = np.where(disc > 0, one, three) - shift
        for _ in range(2):  # Newton on the cubic itself (removes the cancellation of the shift)
            f = ((s1 + a) * s1 + b) * s1 + c
            df = (3 * s1 + 2 * a) * s1 + b
            s1 = np.where(df != 0, s1 - f / np.where(df != 0, df, 1.0), s1)
        # deflate: s^2 + B s + C, roots without cancellation
        B = a + s1
        C = b + B * s1
        sq = np.sqrt((B * B - 4 * C).astype(complex))
        big = -0.5 * (B + np.where(B >= 0, sq, -sq))
        s2 = big
        s3 = np.where(big != 0, C / np.where(big != 0, big, 1.0), 0.0)
        roots = [s1.astype(complex)]
        for z in (s2, s3):  # one Newton step each, kept only where it lowers the residual
            f = ((z + a) * z + b) * z + c
            df = (3 * z + 2 * a) * z + b
            zn = z - f / np.where(df != 0, df, 1.0)
            fn = ((zn + a) * zn + b) * zn + c
            roots.append(np.where((df != 0) & (np.abs(fn) < np.abs(f)), zn, z))
    nu = np.sqrt(np.stack(roots, axis=1))
    return np.concatenate([nu, -nu], axis=1) - 0.5 * p


class FrequencyResponseSolver:
    """An approximation compiled for amplitude parametrisation: the amplitude equation, the
    phase and the waveform as numpy functions of the amplitude (and frequency, phase).

    Compiling (SymPy to numpy, with common subexpressions, and the amplitude polynomial on
    the fixed amplitude scan) costs far more than tracing a response; build one solver with
    :func:`compile_response` and pass it instead of the approximation when tracing many
    windows or parameter values' worth of responses.

    Parameters
    ----------
    approx : Approximation
        With ``frequency_polynomial``, ``amplitude``, ``phase_from`` and ``waveform``.
    parameters : sequence of sympy.Symbol, optional
        Oscillator parameters left free (their values ``None`` in ``approx.oscillator``):
        every compiled function then takes their values as trailing arguments, so one solver
        serves a whole parameter grid (:func:`perturb.apps.grid.sweep` builds it once per
        worker). A solver with free parameters answers :meth:`poly`, :meth:`window_roots`,
        :meth:`roots_at` and :meth:`extremes`; :func:`approximation_response` and
        :func:`solutions_at` need every value bound (no ``parameters``).
    """

    def __init__(self, approx: Approximation, parameters: Sequence[sp.Symbol] = ()) -> None:
        self.approx = approx
        self.parameters = tuple(parameters)
        P = self.parameters
        self.A, self.Omega = approx.amplitude, approx.frequency
        self.phase = approx.unknowns[1] if len(approx.unknowns) > 1 else sp.Symbol("phi")
        keep = (self.A, self.Omega, self.phase, approx.tau, *P)
        self.atoms = _Atoms(self.A)
        coeffs = list(approx.frequency_polynomial or ())
        coeffs += [sp.Integer(0)] * (3 - len(coeffs))
        self.poly_u = _Compiled(
            self.atoms, (self.A, *P), bind_parameters(approx, coeffs, (self.A, *P))
        )
        self.poly_rows = self.poly_u.rows
        cos_part, sin_part = bind_parameters(approx, list(approx.phase_from or (1, 0)), keep)
        self.phase_u = _Compiled(self.atoms, (self.A, self.Omega, *P), [cos_part, sin_part])
        self.wave = Waveform(approx, self.A, self.phase, self.Omega, atoms=self.atoms, parameters=P)
        self._jac: _Compiled | None = None
        # Hill's fast path and the precomputed scan need every parameter's value
        self.hill = None if P else _PWLHill.build(approx.oscillator, self.Omega)
        self.scan: tuple[np.ndarray, tuple[np.ndarray, ...]] | None = None
        if not P:
            scan = np.geomspace(*_SCAN_RANGE, _SCAN_POINTS)
            self.scan = scan, tuple(self.poly(scan))

    def poly(self, a: np.ndarray, *params: float) -> list[np.ndarray]:
        """``c0, c1, c2`` of the amplitude equation ``c0 + c1 W + c2 W^2`` at amplitudes ``a``
        (and the values ``params`` of the free :attr:`parameters`)."""
        a = np.asarray(a, float)
        return self.poly_u(self.atoms.evaluate(a, self.poly_rows), a, *params)

    def window_roots(self, a: np.ndarray, lo: float, hi: float, *params: float):
        """Both roots ``W_- <= W_+`` (``W = Omega**2``, NaN where complex) of the amplitude
        equation at amplitudes ``a``, and whether each lies in ``[lo**2, hi**2]``.

        Returns
        -------
        wlo, whi, in_lo, in_hi : ndarray
        """
        wlo, whi, _ = _roots(*self.poly(a, *params))
        return (wlo, whi, *_in_window(wlo, whi, lo, hi))

    def roots_at(
        self,
        omegas: np.ndarray,
        *params: float,
        amplitude_range: Sequence[float] = _SCAN_RANGE,
        points: int = _SCAN_POINTS,
        pairs: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every root ``A`` of the amplitude equation at each frequency of ``omegas``.

        Bracketed on ``points`` amplitudes spaced logarithmically over ``amplitude_range``
        and refined to full precision. With ``pairs`` (as :func:`solutions_at`), also the
        root pairs closer than that spacing (near a double root), by a search for the minimum
        of ``|P|`` between the samples: up to ~90 more evaluations of the amplitude equation,
        which a parameter sweep may not afford per cell.

        Returns
        -------
        index, amplitude : ndarray
            One entry per root: the index of its frequency in ``omegas`` (increasing) and the
            amplitude.
        """
        w_all = np.asarray(omegas, dtype=float).reshape(-1)
        a_lo, a_hi = (float(a) for a in amplitude_range)
        return _roots_at(self, w_all, a_lo, a_hi, params, int(points), pairs)

    def phases(self, a: np.ndarray, w: np.ndarray, *params: float, U=None) -> np.ndarray:
        """The phase of the orbit at amplitudes ``a`` and frequencies ``w``, from
        ``phase_from`` (0 where it is undefined); ``U``: the atoms at ``a`` if at hand."""
        a = np.asarray(a, float)
        if U is None:
            U = self.atoms.evaluate(a, self.phase_u.rows)
        pc, ps = self.phase_u(U, a, w, *params)
        phi = np.arctan2(ps, pc)
        return np.where(np.isfinite(phi), phi, 0.0)

    def extremes(self, a: np.ndarray, w: np.ndarray, *params: float):
        """``min x`` and ``max x`` over a period of the orbits at amplitudes ``a`` and
        frequencies ``w``: at the waveform's critical points (:meth:`Waveform.extremes`)."""
        a = np.asarray(a, float)
        w = np.asarray(w, float)
        rows = sorted(set(self.phase_u.rows) | set(self.wave.rows))
        U = self.atoms.evaluate(a, rows)
        phi = self.phases(a, w, *params, U=U)
        return self.wave.extremes(a, phi, w, U, params)

    def jacobian(self) -> _Compiled:
        """The slow-flow Jacobian in ``(A, phase, Omega, *parameters)`` and the atoms
        (compiled on use: only ``stability="slow_flow"`` needs it)."""
        if self._jac is None:
            P = self.parameters
            keep = (self.A, self.Omega, self.phase, self.approx.tau, *P)
            flow = bind_parameters(self.approx, list(self.approx.slow_flow or ()), keep)
            jac = sp.Matrix(flow).jacobian(sp.Matrix(self.approx.unknowns))
            self._jac = _Compiled(self.atoms, (self.A, self.phase, self.Omega, *P), list(jac))
        return self._jac

    def branch_rows(self, stability: str) -> list[int]:
        """The atoms the branch statistics need for ``stability``."""
        rows = set(self.poly_rows) | set(self.phase_u.rows) | set(self.wave.rows)
        if stability == "slow_flow":
            rows |= set(self.jacobian().rows)
        return sorted(rows)


def compile_response(
    approximation: Approximation | FrequencyResponseSolver,
    stability: str = "hill",
    *,
    parameters: Sequence[sp.Symbol] = (),
) -> FrequencyResponseSolver:
    """Compile ``approximation`` for tracing (a solver passes through unchanged).

    ``parameters``: oscillator parameters left free, given as arguments to the compiled
    functions (see :class:`FrequencyResponseSolver`); a solver passed in must have the same.

    Raises
    ------
    PerturbError
        If the approximation has no amplitude equation in ``Omega**2`` of degree <= 2.
    ParameterError
        For an unknown ``stability``, parameters without values, or a solver compiled with
        other free parameters.
    """
    parameters = tuple(parameters)
    if isinstance(approximation, FrequencyResponseSolver):
        _check_approximation(approximation.approx, stability)
        if approximation.parameters != parameters:
            raise ParameterError(
                "the solver was compiled with free parameters "
                f"{[s.name for s in approximation.parameters]}, not "
                f"{[s.name for s in parameters]}: compile one with the parameter values to "
                "trace a response"
            )
        return approximation
    if not isinstance(approximation, Approximation):
        raise ParameterError(
            f"approximation = {approximation!r}: expected an Approximation (from a method in "
            "perturb.methods) or a compiled FrequencyResponseSolver"
        )
    _check_approximation(approximation, stability)
    return FrequencyResponseSolver(approximation, parameters)


def _branches(
    cp: FrequencyResponseSolver,
    a: np.ndarray,
    w: np.ndarray,
    U: AtomValues,
    sizes: Sequence[int],
    stability: str,
) -> list[Branch]:
    """Branch statistics of all points at once (``U``: the atoms at ``a``), split into
    branches of ``sizes`` points."""
    approx = cp.approx
    phi = cp.phases(a, w, U=U)
    wave = cp.wave
    coefs = wave.coefficients(a, phi, w, U) if wave.terms is not None else None
    extrema = None
    if coefs is not None:
        extrema = critical_points(*coefs)
        amplitude = max_abs_at(extrema[0], extrema[2], a.size, coefs[0][:, 0])
        mean = coefs[0][:, 0]
        first = np.hypot(coefs[0][:, 1], coefs[1][:, 1])
    else:
        xs, _ = wave.samples(a, phi, w, WAVEFORM_SAMPLES)
        amplitude = np.max(np.abs(xs), axis=1)
        mean = xs.mean(axis=1)
        first = 2 * np.abs(np.fft.rfft(xs, axis=1)[:, 1]) / WAVEFORM_SAMPLES

    period = 2 * np.pi / w
    if stability == "hill" and cp.hill is not None and extrema is not None:
        max_mult = cp.hill.max_multiplier(coefs, extrema, w)
        stable = max_mult < 1 - 1e-9
    elif stability in ("floquet", "hill"):
        xf, dxf = wave.samples(a, phi, w, FLOQUET_SAMPLES, coefs)
        vf = w[:, None] * dxf  # dx/dt = Omega dx/dtau
        max_mult = floquet_in_chunks(approx, xf, vf, period, cp.Omega, w, stability)
        stable = max_mult < 1 - 1e-9
    else:
        j11, j12, j21, j22 = cp.jacobian()(U, a, phi, w)
        tr = j11 + j22
        det = j11 * j22 - j12 * j21
        disc = tr * tr / 4 - det
        # largest real part of the two eigenvalues of the 2x2 slow-flow Jacobian
        re_max = np.where(disc >= 0, tr / 2 + np.sqrt(np.abs(disc)), tr / 2)
        max_mult = np.exp(np.clip(re_max * period, -700, 700))
        stable = re_max < 0
    out = []
    edges = np.cumsum([0, *sizes])
    for s, e in zip(edges[:-1], edges[1:], strict=True):
        out.append(
            Branch(
                omega=w[s:e],
                amplitude=amplitude[s:e],
                first_harmonic_amplitude=first[s:e],
                mean=mean[s:e],
                stable=stable[s:e],
                max_multiplier=max_mult[s:e],
            )
        )
    return out


def floquet_in_chunks(approx, xf, vf, period, Omega, w, stability) -> np.ndarray:
    """Largest Floquet multiplier of the orbit sampled as ``xf`` (positions) and ``vf``
    (velocities) at each frequency ``w`` (periods ``period``), by ``stability`` (``"hill"``
    or the time-domain monodromy), in chunks that bound the memory of one batch."""
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


def frequency_response(*args, **kwargs):
    """Deprecated name of :func:`approximation_response`.

    ``perturb.frequency_response(oscillator, method, ...)`` is the front door that takes an
    oscillator; this function takes an :class:`~perturb.approximation.Approximation`, so it
    has a name of its own.
    """
    import warnings

    warnings.warn(
        "perturb.numeric.amplitude.frequency_response(approximation, ...) is now "
        "approximation_response(approximation, ...); perturb.frequency_response takes an "
        "oscillator",
        DeprecationWarning,
        stacklevel=2,
    )
    return approximation_response(*args, **kwargs)
