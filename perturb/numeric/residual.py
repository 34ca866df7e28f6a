"""Frequency responses of approximations that give only residual equations.

Amplitude parametrisation (:mod:`perturb.numeric.amplitude`) needs the amplitude
equation as a polynomial of degree at most two in ``Omega**2``. Higher-order approximations —
second-order modified Lindstedt–Poincaré on a PWL force, for instance — give residuals
``R(u, Omega) = 0`` in their unknowns ``u`` (amplitude, phase, ...) with no such structure.
Here every branch is found by

1. *seeding*: at a few frequencies across the window, vectorised Newton from a grid of starts
   (a logarithmic grid of the amplitude times a grid of every other unknown over a period)
   collects the solutions it converges to;
2. *continuation*: each seed that does not lie on a branch traced already is continued both
   ways through the window by pseudo-arclength continuation
   (:func:`perturb.numeric.continuation.continue_curve`), with the residuals' analytic
   Jacobians; folds are located on the curve.

A detached loop is found when a seed frequency crosses it (the seeding grid is the knob).
Stability is Hill's method about the approximate orbit, truncated at one harmonic as for the
amplitude-parametrised solver, or the slow flow's Jacobian when the method gives one.

Balance systems in more unknowns — symbolic harmonic balance over a harmonic set (``"shb"``,
unknowns ``a_n, b_n`` and a mean ``c_0``) or with a bias (``A, b, phi``) — are traced the
same way in all their unknowns (:class:`_BalanceCurves`): Newton starts put one harmonic at a
time (the one at the forcing frequency, and the lowest of a subharmonic set) on the
amplitude-times-phase grid with every other harmonic zero and each mean at zero and at the
static equilibria (a bounded number of starts); every curve through a seed is continued both
ways. Each solution's waveform is a trigonometric polynomial whose coefficients come exactly
from an FFT of its samples: ``amplitude`` is max ``|x|`` at its refined critical points,
``first_harmonic_amplitude`` the component at the forcing frequency, ``mean`` the constant
term, and stability Hill's method truncated at the ansatz's highest harmonic (so its
singularity falls on the balance's folds; numeric harmonic balance does the same).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
import sympy as sp

from perturb.approximation import Approximation
from perturb.errors import ParameterError, PerturbError
from perturb.numeric.amplitude import (
    FLOQUET_SAMPLES,
    WAVEFORM_SAMPLES,
    Waveform,
    floquet_in_chunks,
    response_notes,
)
from perturb.numeric.compile import bind_parameters, lambdify
from perturb.numeric.continuation import ContinuationError, continue_curve
from perturb.response import Branch, Response, covering_window, polyline_crossings

__all__ = ["residual_response", "residual_solutions_at", "ResidualSystem"]

_STABILITY = ("hill", "slow_flow")

# Each evaluation of compiled PWL residuals costs tens of milliseconds however few points it
# gets, so the continuation should evaluate about once per point: the Hermite predictor with
# early acceptance does.
_FAST_CONTINUATION = {"predictor": "hermite", "early_accept": True}


class ResidualSystem:
    """The residuals of an approximation compiled with their Jacobians.

    ``evaluate(U, W)`` takes unknowns of shape ``(m, n)`` and frequencies ``(m,)`` and returns
    ``R (m, n)``, ``R_u (m, n, n)``, ``R_Omega (m, n)`` in one call (shared subexpressions).
    """

    def __init__(self, approx: Approximation, positive: bool = True) -> None:
        if not approx.residuals or len(approx.residuals) != len(approx.unknowns):
            raise PerturbError(
                f"{approx.label}: {len(approx.residuals)} residuals for "
                f"{len(approx.unknowns)} unknowns; a square system is needed"
            )
        self.approx = approx
        self.unknowns = tuple(approx.unknowns)
        self.n = len(self.unknowns)
        W = approx.frequency
        keep = (*self.unknowns, W, approx.tau)
        R = bind_parameters(approx, list(approx.residuals), keep)
        J = [sp.diff(r, u) for r in R for u in self.unknowns]
        Rw = [sp.diff(r, W) for r in R]
        self._fn = lambdify((*self.unknowns, W), [*R, *J, *Rw])
        self.amplitude_index = (
            self.unknowns.index(approx.amplitude) if approx.amplitude in self.unknowns else 0
        )
        # the unknown that must stay >= 0 (a polar amplitude); None for Cartesian harmonic
        # coefficients, which take any sign (harmonic balance over a harmonic set)
        self.positive_index: int | None = self.amplitude_index
        if not positive:
            self.positive_index = (
                self.unknowns.index(approx.amplitude) if approx.amplitude in self.unknowns else None
            )

    def evaluate(self, U: np.ndarray, W: np.ndarray, amplitude_max: float = math.inf):
        """Residuals and Jacobians; NaN rows where the amplitude is negative (outside the
        domain of the closed-form Fourier coefficients) or above ``amplitude_max`` (NaN makes
        a continuation step fail, so a branch running away to infinite amplitude stops
        there without evaluating the expressions).  Without a positive amplitude
        (``positive_index`` None: Cartesian harmonic coefficients) the bound applies to the
        largest unknown in absolute value."""
        n, m = self.n, W.shape[0]
        R = np.full((m, n), np.nan)
        J = np.full((m, n, n), np.nan)
        Rw = np.full((m, n), np.nan)
        if self.positive_index is None:
            ok = np.max(np.abs(U), axis=1) <= amplitude_max
        else:
            amp = U[:, self.positive_index]
            ok = (amp >= 0) & (amp <= amplitude_max)
        if np.any(ok):
            out = self._fn(*(U[ok, i] for i in range(n)), W[ok])
            k = int(np.count_nonzero(ok))
            R[ok] = np.stack(out[:n], axis=-1).reshape(k, n)
            J[ok] = np.stack(out[n : n + n * n], axis=-1).reshape(k, n, n)
            Rw[ok] = np.stack(out[n + n * n :], axis=-1).reshape(k, n)
        return R, J, Rw


def _newton_many(sys_: ResidualSystem, U: np.ndarray, W: np.ndarray, iters: int = 40):
    """Damped Newton from every row of ``U`` at once; rows that converge are returned."""
    scale = np.maximum(1.0, np.abs(U))
    for _ in range(iters):
        R, J, _ = sys_.evaluate(U, W)
        with np.errstate(all="ignore"):
            try:
                dU = np.linalg.solve(J, -R[..., None])[..., 0]
            except np.linalg.LinAlgError:
                dU = np.stack(
                    [np.linalg.lstsq(j, -r, rcond=None)[0] for j, r in zip(J, R, strict=True)]
                )
        dU = np.where(np.isfinite(dU), dU, 0.0)
        # a step of at most half the size of the unknowns keeps Newton inside the basin of
        # the root it is heading for instead of jumping across the amplitude grid
        cap = 0.5 * scale
        big = np.max(np.abs(dU) / cap, axis=1, keepdims=True)
        # and the amplitude stays positive: at most halved per step
        if sys_.positive_index is None:
            shrink = np.ones(U.shape[0])
        else:
            a = U[:, sys_.positive_index]
            da = dU[:, sys_.positive_index]
            shrink = np.where(da < -0.5 * a, -da / (0.5 * np.maximum(a, 1e-300)), 1.0)
        dU = dU / np.maximum(np.maximum(1.0, big), shrink[:, None])
        U = U + dU
        scale = np.maximum(1.0, np.abs(U))
    R, _, _ = sys_.evaluate(U, W)
    ok = np.all(np.isfinite(U), axis=1) & (np.max(np.abs(R), axis=1) < 1e-9)
    return U[ok], W[ok]


def _unique(U: np.ndarray, W: np.ndarray, amp: int, tol: float = 1e-6):
    keep: list[int] = []
    for i in range(U.shape[0]):
        if all(
            W[i] != W[j] or np.max(np.abs(U[i] - U[j]) / np.maximum(1.0, np.abs(U[j]))) > tol
            for j in keep
        ):
            keep.append(i)
    return U[keep], W[keep]


def _densify(
    sys_: ResidualSystem,
    U: np.ndarray,
    W: np.ndarray,
    sub: int,
    lam_scale: float,
    amplitude_max: float,
    iters: int = 8,
) -> tuple[np.ndarray, np.ndarray]:
    """Insert ``sub - 1`` points between consecutive points of a traced curve.

    Each new point starts on the chord between its neighbours and is corrected by Newton on
    ``R(u, Omega) = 0`` plus the condition that it stays on the hyperplane through its start
    orthogonal to the chord (so it works across folds, like a pseudo-arclength corrector).
    All points are corrected at once: one evaluation of the compiled residuals for a whole
    batch costs about as much as for a single point, whereas the continuation that traced the
    curve evaluates point after point.  A point that does not converge, or converges farther
    from its start than half the chord, is left out.
    """
    n = sys_.n
    m = W.size - 1
    if sub < 2 or m < 1:
        return U, W
    t = np.arange(1, sub) / sub
    u0, u1, w0, w1 = U[:-1], U[1:], W[:-1], W[1:]
    # scaled coordinates, as in the continuation: unknowns relative to their size
    su = np.maximum(1.0, np.maximum(np.abs(u0), np.abs(u1)))
    d = np.concatenate([(u1 - u0) / su, ((w1 - w0) / lam_scale)[:, None]], axis=1)
    rep = np.repeat(np.arange(m), sub - 1)
    tt = np.tile(t, m)[:, None]
    Zg = np.concatenate([u0[rep] / su[rep], (w0[rep] / lam_scale)[:, None]], axis=1)
    Zg = Zg + tt * d[rep]
    Z = Zg.copy()
    D, S = d[rep], su[rep]
    A = np.zeros((Z.shape[0], n + 1, n + 1))
    rhs = np.zeros((Z.shape[0], n + 1))
    for _ in range(iters):
        R, J, Rw = sys_.evaluate(Z[:, :n] * S, Z[:, n] * lam_scale, amplitude_max)
        A[:, :n, :n] = J * S[:, None, :]
        A[:, :n, n] = Rw * lam_scale
        A[:, n] = D
        rhs[:, :n] = -R
        rhs[:, n] = -np.einsum("ij,ij->i", D, Z - Zg)
        with np.errstate(all="ignore"):
            try:
                dZ = np.linalg.solve(A, rhs[..., None])[..., 0]
            except np.linalg.LinAlgError:
                # a singular row would spoil the batch: solve row by row, NaN where singular
                dZ = np.full_like(Z, np.nan)
                for i in range(Z.shape[0]):
                    try:
                        dZ[i] = np.linalg.solve(A[i], rhs[i])
                    except np.linalg.LinAlgError:
                        pass
        Z = Z + dZ
    R, _, _ = sys_.evaluate(Z[:, :n] * S, Z[:, n] * lam_scale, amplitude_max)
    chord = np.linalg.norm(D, axis=1)
    ok = (
        np.all(np.isfinite(Z), axis=1)
        & (np.max(np.abs(R), axis=1) < 1e-9)
        & (np.linalg.norm(Z - Zg, axis=1) <= 0.5 * chord)
    )
    Un, Wn = Z[:, :n] * S, Z[:, n] * lam_scale
    out_u, out_w = [U[:1]], [W[:1]]
    for j in range(m):
        sel = np.arange(j * (sub - 1), (j + 1) * (sub - 1))
        sel = sel[ok[sel]]
        out_u += [Un[sel], U[j + 1 : j + 2]]
        out_w += [Wn[sel], W[j + 1 : j + 2]]
    return np.concatenate(out_u), np.concatenate(out_w)


def _slice(b: Branch, i: int, j: int) -> Branch:
    return Branch(
        omega=b.omega[i:j],
        amplitude=b.amplitude[i:j],
        first_harmonic_amplitude=b.first_harmonic_amplitude[i:j],
        mean=b.mean[i:j],
        stable=b.stable[i:j],
        max_multiplier=b.max_multiplier[i:j],
    )


def _valid_runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of True in ``ok`` that have at least two points."""
    edges = np.diff(np.concatenate([[0], ok.astype(int), [0]]))
    starts, stops = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]
    return [(a, b) for a, b in zip(starts, stops, strict=True) if b - a >= 2]


def _check_options(
    approx,
    omega_range,
    amplitude_range,
    seed_frequencies,
    seed_amplitudes,
    seed_phases,
    refine,
    max_correction,
    stability,
) -> tuple[float, float, float, float, float]:
    """The options of :func:`residual_response` checked: ``lo, hi, a_lo, a_hi,
    max_correction``."""
    if not isinstance(approx, Approximation):
        raise ParameterError(f"approximation = {approx!r}: expected an Approximation")
    try:
        lo, hi = (float(w) for w in omega_range)
    except (TypeError, ValueError):
        raise ParameterError(f"omega_range = {omega_range!r}: expected (low, high)") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ParameterError(f"omega_range = {omega_range!r}: expected 0 < low < high")
    a_lo, a_hi = (float(a) for a in amplitude_range)
    if not (0 < a_lo < a_hi and math.isfinite(a_hi)):
        raise ParameterError(f"amplitude_range = {amplitude_range!r}: expected 0 < low < high")
    for name, v in (
        ("seed_frequencies", seed_frequencies),
        ("seed_amplitudes", seed_amplitudes),
        ("seed_phases", seed_phases),
    ):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ParameterError(f"{name} = {v!r}: expected a positive integer")
    if isinstance(refine, bool) or not isinstance(refine, int) or refine < 1:
        raise ParameterError(f"refine = {refine!r}: expected a positive integer")
    try:
        max_correction = float(max_correction)
    except (TypeError, ValueError):
        max_correction = float("nan")
    if not max_correction > 0:
        raise ParameterError(f"max_correction = {max_correction!r}: expected a number > 0")
    if stability not in _STABILITY:
        raise ParameterError(f"stability = {stability!r}: expected one of {', '.join(_STABILITY)}")
    if stability == "slow_flow" and approx.slow_flow is None:
        raise PerturbError(f"{approx.label} has no slow flow: use stability='hill'")
    return lo, hi, a_lo, a_hi, max_correction


def residual_response(
    approximation: Approximation,
    omega_range: Sequence[float] = (0.2, 2.0),
    *,
    amplitude_range: Sequence[float] = (1e-2, 1e2),
    seed_frequencies: int = 8,
    seed_amplitudes: int = 24,
    seed_phases: int = 6,
    ds_max: float = 0.02,
    refine: int = 4,
    max_correction: float = 1.0,
    stability: str = "hill",
) -> Response:
    """Every branch of ``approximation``'s residuals ``R(u, Omega) = 0`` over ``omega_range``.

    Parameters
    ----------
    approximation
        Square residual system in its unknowns; all parameters but the frequency need values.
    omega_range
        ``(low, high)`` forcing frequencies.
    amplitude_range
        Amplitudes of the seeding grid (logarithmic); a branch is followed up to the upper
        end (a higher-order expansion can have branches running away to infinite amplitude,
        far outside its range of validity).
    seed_frequencies, seed_amplitudes, seed_phases
        Size of the seeding grid: frequencies across the window, amplitudes, and values of
        every other unknown over ``[-pi, pi)``.
    ds_max
        Output spacing along a branch (scaled arclength, relative to the window and to the
        amplitude).
    refine
        The continuation steps up to ``refine * ds_max``; ``refine - 1`` points are inserted
        between consecutive continuation points by one vectorised Newton correction of all of
        them (1: plain continuation at ``ds_max``).  Each continuation point costs one
        evaluation of the compiled residuals, a batch of any size about the same.
    max_correction
        Validity bound: points whose waveform ``x(tau)`` departs from its first harmonic by
        more than ``max_correction`` times that harmonic's amplitude
        (``max|x| > (1 + max_correction) * first-harmonic amplitude``) are left out, and a
        branch is split there.  A higher-order expansion whose correction terms outgrow the
        leading term is outside its range of validity (second-order mLP of ``nsd`` at low
        frequency, where a small divisor of the correction vanishes, for instance); its
        solutions there are artefacts of the truncation.  ``inf``: keep every point.  No
        effect on a first-order waveform.
    stability
        ``"hill"`` or ``"slow_flow"`` (when the method gives a slow flow).

    Returns
    -------
    Response
        One branch per traced curve; ``folds`` from the continuation.

    Notes
    -----
    An approximation with more than two unknowns, or without an amplitude symbol (symbolic
    harmonic balance over a harmonic set or with a bias), is traced in all its unknowns (see
    the module docstring): ``seed_amplitudes`` and ``seed_phases`` then grid one harmonic at a
    time, and ``max_correction`` has no effect (the waveform is the balance's own ansatz, and
    an off-centre orbit's ``max|x|`` may well exceed twice its first harmonic).

    Raises
    ------
    ParameterError
        Bad window, grid sizes or stability option.
    PerturbError
        A non-square residual system, or no slow flow for ``stability="slow_flow"``.
    """
    approx = approximation
    lo, hi, a_lo, a_hi, max_correction = _check_options(
        approx,
        omega_range,
        amplitude_range,
        seed_frequencies,
        seed_amplitudes,
        seed_phases,
        refine,
        max_correction,
        stability,
    )
    approx = _polar(approx)
    if _is_general(approx):
        return _general_response(
            approx,
            lo,
            hi,
            (a_lo, a_hi),
            seed_frequencies,
            seed_amplitudes,
            seed_phases,
            ds_max,
            refine,
            stability,
        )[0]
    sys_ = ResidualSystem(approx)
    U, W = _seed_solutions(
        sys_, lo, hi, (a_lo, a_hi), seed_frequencies, seed_amplitudes, seed_phases
    )
    curves = _trace_seeds(sys_, U, W, lo, hi, a_hi, ds_max, refine)
    return _curves_response(
        approx, sys_, curves, lo, hi, max_correction, stability, seed_frequencies
    )


def _seed_solutions(
    sys_: ResidualSystem,
    lo: float,
    hi: float,
    amplitude_range: tuple[float, float],
    seed_frequencies: int,
    seed_amplitudes: int,
    seed_phases: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Step 1 of :func:`residual_response` (seeding): vectorised Newton from every
    combination of the seeding grids; the distinct solutions ``U`` (positive amplitude,
    phases wrapped to ``(-pi, pi]``) at frequencies ``W``."""
    n, amp = sys_.n, sys_.amplitude_index
    a_lo, a_hi = amplitude_range
    # seeds: every combination of the grids, all Newton iterations vectorised
    ws = np.linspace(lo, hi, seed_frequencies + 2)[1:-1]
    axes = [
        np.geomspace(a_lo, a_hi, seed_amplitudes)
        if i == amp
        else np.linspace(-np.pi, np.pi, seed_phases, endpoint=False)
        for i in range(n)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
    U0 = np.tile(grid, (ws.size, 1))
    W0 = np.repeat(ws, grid.shape[0])
    U, W = _newton_many(sys_, U0, W0)
    pos = U[:, amp] > 0
    U, W = U[pos], W[pos]
    if n > 1:  # phases modulo 2 pi, so the same solution from different starts is one seed
        other = [i for i in range(n) if i != amp]
        U[:, other] = np.angle(np.exp(1j * U[:, other]))
    return _unique(U, W, amp)


def _trace_seeds(
    sys_: ResidualSystem,
    U: np.ndarray,
    W: np.ndarray,
    lo: float,
    hi: float,
    a_hi: float,
    ds_max: float,
    refine: int,
) -> list[tuple[np.ndarray, np.ndarray, list]]:
    """Step 2 of :func:`residual_response` (continuation): every seed not on a curve traced
    already is continued both ways through the window; the curves ``(u, Omega, folds)``,
    densified by ``refine``."""
    amp = sys_.amplitude_index
    # continue_curve asks for the Jacobian right after the residual at the same point, and
    # one evaluation of the compiled expressions gives both: evaluate once per point
    last: list = [None, None, None]

    def point(u, lam):
        if last[0] is None or last[1] != lam or not np.array_equal(last[0], u):
            last[0], last[1] = u.copy(), lam
            last[2] = sys_.evaluate(u[None, :], np.array([lam]), a_hi)
        return last[2]

    def residual(u, lam):
        return point(u, lam)[0][0]

    def jacobian(u, lam):
        _, J, Rw = point(u, lam)
        return J[0], Rw[0]

    def key(u: np.ndarray, w: np.ndarray) -> np.ndarray:
        # where a solution lies in the plane of the response plot: frequency over the window
        # and log amplitude, so seeds on traced branches are recognised at any amplitude
        return np.column_stack([w / (hi - lo), np.log(np.maximum(u[:, amp], 1e-300))])

    curves = []
    traced: list[np.ndarray] = []
    for u0, w0 in zip(U, W, strict=True):
        k0 = key(u0[None, :], np.array([w0]))[0]
        if any(np.min(np.linalg.norm(t - k0, axis=1)) < 2 * ds_max for t in traced):
            continue  # on a branch traced already
        a_scale = np.ones(u0.size)
        a_scale[amp] = max(1.0, abs(u0[amp]))
        curve = _continue_both_ways(residual, jacobian, u0, w0, a_scale, lo, hi, ds_max * refine)
        if curve is None:
            continue
        u_c, w_c, folds = curve
        good = (u_c[:, amp] > 0) & np.all(np.isfinite(u_c), axis=1)
        if np.count_nonzero(good) < 2:
            continue
        u_c, w_c = _densify(sys_, u_c[good], w_c[good], refine, hi - lo, a_hi)
        curves.append((u_c, w_c, folds))
        traced.append(key(u_c, w_c))
    return curves


def _continue_both_ways(residual, jacobian, u0, w0, u_scale, lo, hi, ds):
    """Step 2a of :func:`residual_response`: the curve through the seed ``(u0, w0)``,
    continued down and up in frequency (steps up to ``ds``, unknowns scaled by ``u_scale``)
    and joined into one polyline ``(u, Omega, folds)`` (a closed loop as traced once); None if
    both directions fail."""
    parts = []
    for direction in (-1, 1):
        try:
            parts.append(
                continue_curve(
                    residual,
                    jacobian,
                    u0,
                    float(w0),
                    (lo, hi),
                    direction=direction,
                    u_scale=u_scale,
                    # steps relative to the amplitude: a branch growing by decades is
                    # traced in a few hundred points, not cut off by max_points
                    adaptive_scale=True,
                    ds_max=ds,
                    max_points=4000,
                    **_FAST_CONTINUATION,
                )
            )
        except ContinuationError:
            parts.append(None)
    if parts[0] is None and parts[1] is None:
        return None
    back, fwd = parts
    if back is not None and back.stop_reason == "closed":
        return back.u, back.lam, list(back.folds)
    us, ls, folds = [], [], []
    if back is not None:
        us.append(back.u[::-1])
        ls.append(back.lam[::-1])
        folds += list(back.folds)
    if fwd is not None:
        start = 1 if back is not None else 0
        us.append(fwd.u[start:])
        ls.append(fwd.lam[start:])
        folds += list(fwd.folds)
    return np.concatenate(us), np.concatenate(ls), folds


def _curves_response(
    approx: Approximation,
    sys_: ResidualSystem,
    curves: Sequence[tuple[np.ndarray, np.ndarray, list]],
    lo: float,
    hi: float,
    max_correction: float,
    stability: str,
    seed_frequencies: int,
) -> Response:
    """Step 3 of :func:`residual_response`: branches (waveform statistics and stability)
    from the traced curves, split where the waveform's correction exceeds
    ``max_correction`` (those points and their folds left out), with notes."""
    amp = sys_.amplitude_index
    wave = Waveform(approx, approx.amplitude or sys_.unknowns[amp], *_phase_and_freq(approx))
    branches, fold_pts = [], []
    dropped = 0
    for u_c, w_c, folds in curves:
        b = _branch(approx, sys_, wave, u_c, w_c, stability)
        ok = b.amplitude <= (1.0 + max_correction) * b.first_harmonic_amplitude
        if np.all(ok):
            branches.append(b)
        else:
            dropped += int(np.count_nonzero(~ok))
            branches += [_slice(b, i, j) for i, j in _valid_runs(ok)]
        for f in folds:
            # a fold of the left-out part is not reported either
            near = np.argmin(np.abs(w_c - f.lam) + np.abs(u_c[:, amp] - f.u[amp]))
            if ok[near]:
                fold_pts.append((float(f.lam), float(f.u[amp])))
    notes: tuple[str, ...] = ()
    if not branches:
        notes += (
            f"no solution found on the seeding grid ({seed_frequencies} frequencies in "
            f"[{lo:.6g}, {hi:.6g}])",
        )
    notes += response_notes(approx, branches, (lo, hi))
    if dropped:
        notes += (
            f"{dropped} points left out where the waveform's correction exceeds "
            f"{max_correction:g} times its first harmonic (outside the expansion's validity)",
        )
    params = {k: v for k, v in approx.oscillator.params.items() if v is not None}
    return Response(
        tuple(branches),
        approx.label,
        approx.oscillator.name,
        params,
        folds=tuple(fold_pts),
        notes=notes,
    )


def _polar(approx: Approximation) -> Approximation:
    """A Cartesian approximation (unknowns ``p, q`` with waveform ``p cos tau + q sin tau``
    and no amplitude symbol, as van der Pol's averaging gives) in polar unknowns
    ``p = A cos phi``, ``q = A sin phi``: the seeding grid, the positive-amplitude domain and
    the waveform statistics are all in amplitude and phase.  Others pass through."""
    if approx.amplitude is not None or len(approx.unknowns) != 2:
        return approx
    p, q = approx.unknowns
    c, sn = approx.waveform.coeff(sp.cos(approx.tau)), approx.waveform.coeff(sp.sin(approx.tau))
    if sp.simplify(approx.waveform - p * sp.cos(approx.tau) - q * sp.sin(approx.tau)) != 0 or (
        c != p or sn != q
    ):
        return approx
    A = sp.Symbol("A", positive=True)
    phi = sp.Symbol("phi", real=True)
    to = {p: A * sp.cos(phi), q: A * sp.sin(phi)}
    res = [sp.sympify(r).xreplace(to) for r in approx.residuals]
    # the balance of the cosine and sine parts, rotated to the (A, phi) directions
    rot = (
        res[0] * sp.cos(phi) + res[1] * sp.sin(phi),
        -res[0] * sp.sin(phi) + res[1] * sp.cos(phi),
    )
    flow = None
    if approx.slow_flow is not None and len(approx.slow_flow) == 2:
        dp, dq = (sp.sympify(f).xreplace(to) for f in approx.slow_flow)
        flow = (
            dp * sp.cos(phi) + dq * sp.sin(phi),
            (-dp * sp.sin(phi) + dq * sp.cos(phi)) / A,
        )
    return dataclasses.replace(
        approx,
        unknowns=(A, phi),
        residuals=rot,
        waveform=A * sp.cos(approx.tau - phi),
        slow_flow=flow,
        amplitude=A,
    )


def _phase_and_freq(approx: Approximation):
    others = [u for u in approx.unknowns if u != approx.amplitude]
    phase = others[0] if others else sp.Symbol("phi")
    return phase, approx.frequency


def _branch(approx, sys_, wave: Waveform, U: np.ndarray, w: np.ndarray, stability: str):
    if len(approx.unknowns) != 2:
        raise PerturbError(
            f"{approx.label}: waveform statistics need exactly two unknowns (amplitude, phase); "
            f"got {', '.join(map(str, approx.unknowns))}"
        )
    amp = sys_.amplitude_index
    a, phi = U[:, amp], U[:, 1 - amp]
    coefs = wave.coefficients(a, phi, w) if wave.terms is not None else None
    xs, _ = wave.samples(a, phi, w, WAVEFORM_SAMPLES, coefs)
    amplitude = wave.max_abs(a, phi, w, xs, coefs)
    if coefs is not None:
        mean, first = coefs[0][:, 0], np.hypot(coefs[0][:, 1], coefs[1][:, 1])
    else:
        mean = xs.mean(axis=1)
        first = 2 * np.abs(np.fft.rfft(xs, axis=1)[:, 1]) / WAVEFORM_SAMPLES
    period = 2 * np.pi / w
    if stability == "hill":
        xf, dxf = wave.samples(a, phi, w, FLOQUET_SAMPLES, coefs)
        max_mult = floquet_in_chunks(
            approx, xf, w[:, None] * dxf, period, approx.frequency, w, "hill"
        )
        stable = max_mult < 1 - 1e-9
    else:
        keep = (*approx.unknowns, approx.frequency, approx.tau)
        flow = bind_parameters(approx, list(approx.slow_flow or ()), keep)
        jac = lambdify(
            (*approx.unknowns, approx.frequency),
            list(sp.Matrix(flow).jacobian(sp.Matrix(approx.unknowns))),
        )
        vals = jac(*(U[:, i] for i in range(U.shape[1])), w)
        Jm = np.stack(vals, axis=-1).reshape(-1, 2, 2)
        re = np.max(np.linalg.eigvals(Jm).real, axis=1)
        max_mult = np.exp(np.clip(re * period, -700, 700))
        stable = re < 0
    return Branch(
        omega=w,
        amplitude=amplitude,
        first_harmonic_amplitude=first,
        mean=mean,
        stable=stable,
        max_multiplier=max_mult,
    )


def residual_solutions_at(
    approximation: Approximation, frequencies: Sequence[float], **options
) -> Response:
    """Every solution of a residual-traced approximation at exactly ``frequencies``.

    The branches are traced over a window covering the frequencies
    (:func:`residual_response`, which takes ``options``), and every solution at each
    requested frequency is found by Newton on the residuals (the counterpart of
    :func:`perturb.numeric.amplitude.solutions_at` for approximations without an amplitude
    polynomial).

    Parameters
    ----------
    approximation
        Square residual system in its unknowns; all parameters but the frequency need values.
    frequencies
        Positive forcing frequencies (validated by the caller,
        :func:`perturb.solve.frequency_response`).
    options
        The keyword options of :func:`residual_response`; ``stability``,
        ``max_correction`` and ``amplitude_range`` also apply to the solutions here.

    Returns
    -------
    Response
        One branch per rank of amplitude at a frequency (the k-th smallest amplitude at each
        frequency forms branch k); the traced curve's method, model and parameters.

    Notes
    -----
    The residuals' unknowns along a traced branch are not kept by the tracer, so Newton
    starts at each frequency from the tracer's own seeding grid (amplitudes times phases,
    denser than the tracer's); every crossing of a traced branch with a requested frequency
    must then be matched by one of the solutions (within 2 % in ``amplitude``), else a note
    says which was missed.
    """
    approx = approximation
    targets = [float(w) for w in frequencies]
    if isinstance(approx, Approximation) and _is_general(_polar(approx)):
        # validate the options as the tracer does (it raises on a bad one), then solve
        return _general_solutions_at(approx, targets, **options)
    window = covering_window(targets)
    traced = residual_response(approx, window, **options)
    stability = options.get("stability", "hill")
    max_correction = float(options.get("max_correction", 1.0))
    a_lo, a_hi = (float(a) for a in options.get("amplitude_range", (1e-2, 1e2)))
    polar = _polar(approx)
    sys_ = ResidualSystem(polar)
    n, amp = sys_.n, sys_.amplitude_index
    wanted = np.array(sorted(set(targets)))
    axes = [
        np.geomspace(a_lo, a_hi, 48) if i == amp else np.linspace(-np.pi, np.pi, 12, endpoint=False)
        for i in range(n)
    ]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
    U, W = _newton_many(sys_, np.tile(grid, (wanted.size, 1)), np.repeat(wanted, grid.shape[0]))
    pos = U[:, amp] > 0
    U, W = U[pos], W[pos]
    if n > 1:
        other = [i for i in range(n) if i != amp]
        U[:, other] = np.angle(np.exp(1j * U[:, other]))
    U, W = _unique(U, W, amp)
    order = np.lexsort((U[:, amp], W))
    U, W = U[order], W[order]
    notes = [
        f"{W.size} solutions at {wanted.size} frequencies by Newton from a grid at each, "
        f"checked against the branches traced over Omega = {window[0]:.6g}..{window[1]:.6g}"
    ]
    branches: list[Branch] = []
    if W.size:
        wave = Waveform(polar, polar.amplitude or sys_.unknowns[amp], *_phase_and_freq(polar))
        b = _branch(polar, sys_, wave, U, W, stability)
        ok = b.amplitude <= (1.0 + max_correction) * b.first_harmonic_amplitude
        if not np.all(ok):
            notes.append(
                f"{int(np.count_nonzero(~ok))} solutions left out where the waveform's "
                f"correction exceeds {max_correction:g} times its first harmonic"
            )
        # one branch per frequency rank: the k-th smallest amplitude at each frequency
        rank = np.zeros(W.size, int)
        keep = np.nonzero(ok)[0]
        for w in wanted:
            idx = keep[W[keep] == w]
            rank[idx] = np.arange(idx.size)
        for r in range(int(rank[keep].max()) + 1 if keep.size else 0):
            sel = keep[rank[keep] == r]
            branches.append(
                Branch(
                    omega=b.omega[sel],
                    amplitude=b.amplitude[sel],
                    first_harmonic_amplitude=b.first_harmonic_amplitude[sel],
                    mean=b.mean[sel],
                    stable=b.stable[sel],
                    max_multiplier=b.max_multiplier[sel],
                )
            )
    got: dict[float, list[float]] = {float(w): [] for w in wanted}
    for br in branches:
        for ww, a in zip(br.omega, br.amplitude, strict=True):
            got[float(ww)].append(float(a))
    for bi, br in enumerate(traced.branches):
        for w, j in polyline_crossings(br.omega, list(wanted)):
            w0, w1 = float(br.omega[j]), float(br.omega[j + 1])
            t = 0.0 if w1 == w0 else (w - w0) / (w1 - w0)
            a = (1 - t) * float(br.amplitude[j]) + t * float(br.amplitude[j + 1])
            if not any(abs(v - a) <= 0.02 * abs(a) for v in got[float(w)]):
                notes.append(
                    f"traced branch {bi} crosses Omega = {w!r} near amplitude {a:.6g}, but "
                    "Newton from the grid found no solution there"
                )
    return Response(
        tuple(branches),
        traced.method,
        traced.model,
        dict(traced.params),
        notes=tuple(notes),
    )


# --------------------------------------------------------------------------------------------
# square balance systems in any unknowns: symbolic harmonic balance over a harmonic set
# --------------------------------------------------------------------------------------------
#: Most static equilibria used as starting biases (each multiplies the seeding grid).
_MAX_BIAS_STARTS = 5
#: Newton starts per seed frequency at most (bounds the seeding work of a large set).
_MAX_STARTS = 4096
#: The keyword defaults of :func:`residual_response`.
_TRACER_DEFAULTS = {
    "amplitude_range": (1e-2, 1e2),
    "seed_frequencies": 8,
    "seed_amplitudes": 24,
    "seed_phases": 6,
    "ds_max": 0.02,
    "refine": 4,
    "max_correction": 1.0,
    "stability": "hill",
}


def _is_general(approx: Approximation) -> bool:
    """Whether ``approx`` (after :func:`_polar`) is traced in its own unknowns rather than as
    an (amplitude, phase) pair: more than two unknowns (a harmonic set, a mean term) or no
    amplitude symbol (Cartesian coefficients of one harmonic that is not the fundamental)."""
    return len(approx.unknowns) > 2 or approx.amplitude is None


class _Roles:
    """What each unknown of a balance system is, read from the waveform ``x(tau)``.

    Attributes
    ----------
    m
        ``tau = m s``: the waveform is a trigonometric polynomial in ``s`` (``m > 1`` for a
        subharmonic set; the forcing frequency is harmonic ``m`` of ``s``).
    order
        The highest harmonic of ``s`` in the waveform.
    phases, biases
        Indices of phase unknowns (only inside trigonometric arguments) and of terms free of
        ``tau`` (means).
    pairs
        ``(harmonic, cos index, sin index)`` for Cartesian coefficient pairs.
    """

    def __init__(self, approx: Approximation, wave: sp.Expr, s: sp.Symbol, m: int) -> None:
        from perturb.fourier.trig import split_argument

        self.m = m
        trig = [f for f in wave.atoms(sp.cos, sp.sin) if f.has(s)]
        harmonic_of: dict[sp.Expr, int] = {}
        for f in trig:
            n, _ = split_argument(f.args[0], s)
            harmonic_of[f] = abs(int(n))
        self.order = max([1, *harmonic_of.values()])
        self.phases: list[int] = []
        self.biases: list[int] = []
        cos_of: dict[int, int] = {}
        sin_of: dict[int, int] = {}
        for i, u in enumerate(approx.unknowns):
            if u == approx.amplitude:
                continue
            in_args = any(f.args[0].has(u) for f in trig)
            if in_args:
                self.phases.append(i)
                continue
            d = sp.expand(sp.diff(wave, u))
            if not d.has(s):
                self.biases.append(i)
                continue
            for f, n in harmonic_of.items():
                if d == f:
                    (cos_of if isinstance(f, sp.cos) else sin_of)[n] = i
        self.pairs = [(n, cos_of[n], sin_of.get(n)) for n in sorted(cos_of)]


def _static_biases(osc, a_hi: float) -> list[float]:
    """Up to :data:`_MAX_BIAS_STARTS` roots of the static balance ``g(x, 0) = F_0`` in
    ``|x| <= a_hi`` (sign changes on a grid, then bisection): starting means for the orbits
    about each equilibrium (the wells of a double-well force)."""
    from perturb.numeric.compile import lambdify as _lam

    values = {s: v for s, v in osc.substitutions().items() if s != osc.x}
    expr = (sp.sympify(osc.g).xreplace({osc.v: 0}) - osc.forcing.constant).xreplace(values)
    if expr.free_symbols - {osc.x}:
        return []
    f = _lam((osc.x,), expr)
    xs = np.linspace(-a_hi, a_hi, 4001)
    ys = f(xs)
    roots: list[float] = []
    for j in np.nonzero(np.sign(ys[:-1]) * np.sign(ys[1:]) <= 0)[0]:
        lo, hi = float(xs[j]), float(xs[j + 1])
        flo = float(ys[j])
        for _ in range(60):  # bisection to ~1e-18 of the grid step
            mid = 0.5 * (lo + hi)
            fm = float(f(np.array([mid]))[0])
            if np.sign(fm) == np.sign(flo) and fm != 0:
                lo, flo = mid, fm
            else:
                hi = mid
        x0 = 0.5 * (lo + hi)
        if not roots or abs(x0 - roots[-1]) > 1e-6 * max(1.0, abs(x0)):
            roots.append(x0)
    roots.sort(key=abs)
    return roots[:_MAX_BIAS_STARTS]


class _BalanceCurves:
    """Seeding and continuation of a square balance system in all its unknowns."""

    def __init__(self, approx: Approximation, amplitude_range, stability: str) -> None:
        self.approx = approx
        self.sys = ResidualSystem(approx, positive=False)
        self.a_lo, self.a_hi = (float(a) for a in amplitude_range)
        s = sp.Dummy("s", real=True)
        keep = (*approx.unknowns, approx.frequency, approx.tau)
        wave = bind_parameters(approx, [approx.waveform], keep)[0]
        m = self._m(approx)
        wave_s = sp.expand(wave.xreplace({approx.tau: m * s}))
        self.roles = _Roles(approx, wave_s, s, m)
        self._x = lambdify((s, *approx.unknowns, approx.frequency), wave_s)
        self._dx = lambdify((s, *approx.unknowns, approx.frequency), sp.diff(wave_s, s))
        self.stability = stability
        if stability == "slow_flow":
            flow = bind_parameters(approx, list(approx.slow_flow or ()), keep)
            self._flow_jac = lambdify(
                (*approx.unknowns, approx.frequency),
                list(sp.Matrix(flow).jacobian(sp.Matrix(approx.unknowns))),
            )

    @staticmethod
    def _m(approx: Approximation) -> int:
        try:
            return int(approx.options.get("m", 1))
        except (AttributeError, TypeError, ValueError):
            return 1

    # -- seeds ---------------------------------------------------------------------------
    def starts(self, amplitudes: int, phases: int) -> np.ndarray:
        """Newton starts: one harmonic at a time (the one at the forcing frequency, and the
        lowest when that is a subharmonic) over a log grid of amplitudes and a grid of phases,
        every other harmonic zero, each mean at zero and at the static equilibria."""
        n, r = self.sys.n, self.roles
        amp = np.geomspace(self.a_lo, self.a_hi, amplitudes)
        ph = np.linspace(-np.pi, np.pi, phases, endpoint=False)
        biases = [0.0]
        if r.biases:
            biases += [b for b in _static_biases(self.approx.oscillator, self.a_hi) if b != 0.0]
        rows = []
        pos = self.sys.positive_index
        if pos is not None:  # polar amplitude and phase(s) plus means
            A, P = np.meshgrid(amp, ph, indexing="ij")
            for b in biases:
                U = np.zeros((A.size, n))
                U[:, pos] = A.ravel()
                for i in r.phases:
                    U[:, i] = P.ravel()
                for i in r.biases:
                    U[:, i] = b
                rows.append(U)
        else:
            wanted = {r.m, min((p[0] for p in r.pairs), default=r.m)}
            for k, ic, is_ in r.pairs:
                if k not in wanted:
                    continue
                A, P = np.meshgrid(amp, ph, indexing="ij")
                for b in biases:
                    U = np.zeros((A.size, n))
                    U[:, ic] = (A * np.cos(P)).ravel()
                    if is_ is not None:
                        U[:, is_] = (A * np.sin(P)).ravel()
                    for i in r.biases:
                        U[:, i] = b
                    rows.append(U)
        if not rows:
            rows.append(np.zeros((1, n)))
        U = np.concatenate(rows)
        return U[:_MAX_STARTS]

    def solve_at(self, U0: np.ndarray, W0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Newton from every row; converged, phases wrapped, duplicates removed."""
        U, W = _newton_many(self.sys, U0, W0)
        bound = np.max(np.abs(U), axis=1) <= self.a_hi if U.size else np.ones(0, bool)
        U, W = U[bound], W[bound]
        if self.sys.positive_index is not None:
            keep = U[:, self.sys.positive_index] > 0
            U, W = U[keep], W[keep]
        if self.roles.phases:
            U[:, self.roles.phases] = np.angle(np.exp(1j * U[:, self.roles.phases]))
        return _unique(U, W, 0)

    # -- continuation ------------------------------------------------------------------------
    def trace(self, lo, hi, seed_frequencies, seed_amplitudes, seed_phases, ds_max, refine):
        """``[(U, W, folds)]``: every curve through a seed, continued both ways."""
        sys_ = self.sys
        n = sys_.n
        ws = np.linspace(lo, hi, seed_frequencies + 2)[1:-1]
        grid = self.starts(seed_amplitudes, seed_phases)
        U, W = self.solve_at(np.tile(grid, (ws.size, 1)), np.repeat(ws, grid.shape[0]))
        scale = max(1.0, float(np.max(np.abs(U)))) if U.size else 1.0
        last: list = [None, None, None]
        a_hi = self.a_hi

        def point(u, lam):
            if last[0] is None or last[1] != lam or not np.array_equal(last[0], u):
                last[0], last[1] = u.copy(), lam
                last[2] = sys_.evaluate(u[None, :], np.array([lam]), a_hi)
            return last[2]

        def residual(u, lam):
            return point(u, lam)[0][0]

        def jacobian(u, lam):
            _, J, Rw = point(u, lam)
            return J[0], Rw[0]

        phases = self.roles.phases

        def key(u: np.ndarray, w: np.ndarray) -> np.ndarray:
            # a point of the response in scaled coordinates: frequency over the window and
            # every unknown over the largest seed (phases by their cosine and sine, so a
            # wrapped seed matches its unwrapped curve)
            cols = [w / (hi - lo)]
            for i in range(n):
                if i in phases:
                    cols += [np.cos(u[:, i]), np.sin(u[:, i])]
                else:
                    cols.append(u[:, i] / scale)
            return np.column_stack(cols)

        curves = []
        traced: list[np.ndarray] = []
        for u0, w0 in zip(U, W, strict=True):
            k0 = key(u0[None, :], np.array([w0]))[0]
            if any(np.min(np.linalg.norm(t - k0, axis=1)) < 2 * ds_max for t in traced):
                continue  # on a curve traced already
            curve = _continue_both_ways(
                residual,
                jacobian,
                u0,
                w0,
                np.full(n, max(1.0, float(np.max(np.abs(u0))))),
                lo,
                hi,
                ds_max * refine,
            )
            if curve is None:
                continue
            u_c, w_c, folds = curve
            good = np.all(np.isfinite(u_c), axis=1)
            if sys_.positive_index is not None:
                good &= u_c[:, sys_.positive_index] > 0
            if np.count_nonzero(good) < 2:
                continue
            u_c, w_c = _densify(sys_, u_c[good], w_c[good], refine, hi - lo, a_hi)
            curves.append((u_c, w_c, folds))
            traced.append(key(u_c, w_c))
        return curves

    # -- statistics and stability -----------------------------------------------------------
    def coefficients(self, U: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``C, S`` of ``x = sum_n C_n cos(n s) + S_n sin(n s)`` (``s = tau / m``), exact: the
        FFT of more than ``2 * order`` samples of a trigonometric polynomial."""
        K = self.roles.order
        N = max(WAVEFORM_SAMPLES, 4 * K + 4)
        s = np.linspace(0, 2 * np.pi, N, endpoint=False)
        xs = self._x(s[None, :], *(U[:, i : i + 1] for i in range(U.shape[1])), w[:, None])
        F = np.fft.rfft(xs, axis=1)[:, : K + 1] / N
        C = 2 * F.real
        S = -2 * F.imag
        C[:, 0] = F[:, 0].real
        return C, S

    def branch(self, U: np.ndarray, w: np.ndarray) -> Branch:
        """The response columns of the solutions ``U`` at ``w``: ``amplitude`` (max |x| at
        the refined critical points), the component at the forcing frequency, the mean and
        stability (Hill's method truncated at the ansatz's highest harmonic, or the slow
        flow's Jacobian)."""
        from perturb.numeric.amplitude import critical_points, max_abs_at
        from perturb.numeric.stability import hill_exponents

        C, S = self.coefficients(U, w)
        m, K = self.roles.m, self.roles.order
        ks = np.arange(K + 1)
        s = np.linspace(0, 2 * np.pi, WAVEFORM_SAMPLES, endpoint=False)
        xs = C @ np.cos(np.outer(ks, s)) + S @ np.sin(np.outer(ks, s))
        rows, _, xe = critical_points(C, S, WAVEFORM_SAMPLES)
        amplitude = np.maximum(
            np.max(np.abs(xs), axis=1), max_abs_at(rows, xe, C.shape[0], C[:, 0])
        )
        first = np.hypot(C[:, m], S[:, m]) if m <= K else np.zeros(w.size)
        mean = C[:, 0]
        period = 2 * np.pi * m / w
        if self.stability == "slow_flow":
            n = U.shape[1]
            vals = self._flow_jac(*(U[:, i] for i in range(n)), w)
            Jm = np.stack(vals, axis=-1).reshape(-1, n, n)
            re = np.max(np.linalg.eigvals(Jm).real, axis=1)
            max_mult = np.exp(np.clip(re * period, -700, 700))
            stable = re < 0
        else:
            sf = np.linspace(0, 2 * np.pi, FLOQUET_SAMPLES, endpoint=False)
            cf, sn = np.cos(np.outer(ks, sf)), np.sin(np.outer(ks, sf))
            xf = C @ cf + S @ sn
            # dx/dt = (Omega / m) dx/ds
            vf = (w / m)[:, None] * ((S * ks) @ cf - (C * ks) @ sn)
            max_mult = np.empty(w.size)
            chunk = 512
            for a in range(0, w.size, chunk):
                sl = slice(a, a + chunk)
                # truncated at the ansatz's harmonics, so the singularity of Hill's matrix
                # falls on the balance's folds
                lam = hill_exponents(
                    self.approx.oscillator, xf[sl], vf[sl], period[sl], K, self.approx.frequency
                )
                re = np.max(lam.real, axis=1)
                max_mult[sl] = np.exp(np.clip(re * period[sl], -700, 700))
            stable = max_mult < 1 - 1e-9
        return Branch(
            omega=w,
            amplitude=amplitude,
            first_harmonic_amplitude=first,
            mean=mean,
            stable=stable,
            max_multiplier=max_mult,
        )


def _general_response(
    approx: Approximation,
    lo: float,
    hi: float,
    amplitude_range,
    seed_frequencies: int,
    seed_amplitudes: int,
    seed_phases: int,
    ds_max: float,
    refine: int,
    stability: str,
) -> tuple[Response, _BalanceCurves, list]:
    """:func:`residual_response` for a balance system in any unknowns (see there)."""
    bc = _BalanceCurves(approx, amplitude_range, stability)
    curves = bc.trace(lo, hi, seed_frequencies, seed_amplitudes, seed_phases, ds_max, refine)
    branches, fold_pts = [], []
    for u_c, w_c, folds in curves:
        b = bc.branch(u_c, w_c)
        branches.append(b)
        for f in folds:
            fb = bc.branch(np.asarray(f.u, float)[None, :], np.array([float(f.lam)]))
            fold_pts.append((float(f.lam), float(fb.amplitude[0])))
    notes: tuple[str, ...] = (
        f"traced in all {bc.sys.n} unknowns ({', '.join(map(str, approx.unknowns))}) by "
        "continuation of the balance residuals, seeded by Newton from one harmonic at a time "
        f"at {seed_frequencies} frequencies; stability by "
        + (
            "the slow flow's Jacobian"
            if stability == "slow_flow"
            else f"Hill's method truncated at harmonic {bc.roles.order}"
            + (f" of Omega/{bc.roles.m}" if bc.roles.m > 1 else "")
        ),
    )
    if not branches:
        notes += (
            f"no solution found on the seeding grid ({seed_frequencies} frequencies in "
            f"[{lo:.6g}, {hi:.6g}])",
        )
    params = {k: v for k, v in approx.oscillator.params.items() if v is not None}
    resp = Response(
        tuple(branches),
        approx.label,
        approx.oscillator.name,
        params,
        folds=tuple(fold_pts),
        notes=notes,
    )
    return resp, bc, curves


def _general_solutions_at(approx: Approximation, targets: list[float], **options) -> Response:
    """:func:`residual_solutions_at` for a balance system in any unknowns: the curves are
    traced over a covering window and every solution at each requested frequency is found by
    Newton from the traced curve where it crosses the frequency and from the seeding grid
    there."""
    window = covering_window(targets)
    unknown = sorted(set(options) - set(_TRACER_DEFAULTS))
    if unknown:
        raise ParameterError(
            f"{', '.join(unknown)}: not options of residual continuation (expected: "
            f"{', '.join(_TRACER_DEFAULTS)})"
        )
    o = {**_TRACER_DEFAULTS, **options}
    lo, hi, a_lo, a_hi, _ = _check_options(
        approx,
        window,
        o["amplitude_range"],
        o["seed_frequencies"],
        o["seed_amplitudes"],
        o["seed_phases"],
        o["refine"],
        o["max_correction"],
        o["stability"],
    )
    traced, bc, curves = _general_response(
        _polar(approx),
        lo,
        hi,
        (a_lo, a_hi),
        o["seed_frequencies"],
        o["seed_amplitudes"],
        o["seed_phases"],
        o["ds_max"],
        o["refine"],
        o["stability"],
    )
    wanted = np.array(sorted(set(targets)))
    starts_u, starts_w = [], []
    crossing_count = 0
    for u_c, w_c, _ in curves:
        for w, j in polyline_crossings(w_c, list(wanted)):
            w0, w1 = float(w_c[j]), float(w_c[j + 1])
            t = 0.0 if w1 == w0 else (w - w0) / (w1 - w0)
            starts_u.append((1 - t) * u_c[j] + t * u_c[j + 1])
            starts_w.append(w)
            crossing_count += 1
    grid = bc.starts(48, 12)
    starts_u.append(np.tile(grid, (wanted.size, 1)))
    starts_w.append(np.repeat(wanted, grid.shape[0]))
    U0 = np.vstack([np.atleast_2d(u) for u in starts_u])
    W0 = np.concatenate([np.atleast_1d(np.asarray(w, float)) for w in starts_w])
    U, W = bc.solve_at(U0, W0)
    notes = [
        f"{W.size} solutions at {wanted.size} frequencies by Newton from the {crossing_count} "
        f"crossings of the branches traced over Omega = {window[0]:.6g}..{window[1]:.6g} and "
        "from a grid at each"
    ]
    branches: list[Branch] = []
    if W.size:
        b = bc.branch(U, W)
        order = np.lexsort((b.amplitude, W))
        Ws = W[order]
        rank = np.zeros(W.size, int)
        for w in wanted:
            idx = np.nonzero(Ws == w)[0]
            rank[idx] = np.arange(idx.size)
        for r in range(int(rank.max()) + 1):
            sel = order[rank == r]
            branches.append(
                Branch(
                    omega=b.omega[sel],
                    amplitude=b.amplitude[sel],
                    first_harmonic_amplitude=b.first_harmonic_amplitude[sel],
                    mean=b.mean[sel],
                    stable=b.stable[sel],
                    max_multiplier=b.max_multiplier[sel],
                )
            )
    return Response(
        tuple(branches),
        traced.method,
        traced.model,
        dict(traced.params),
        notes=tuple(notes) + traced.notes[:1],
    )
