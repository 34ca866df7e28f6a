"""Frequency responses of approximations that give only residual equations.

Amplitude parametrisation (:mod:`perturb.numeric.frequency_response`) needs the amplitude
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
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import sympy as sp

from ..approximation import Approximation
from ..errors import ParameterError, PerturbError
from ..response import Branch, Response
from .compile import bind_parameters, lambdify
from .continuation import ContinuationError, continue_curve
from .frequency_response import _FLOQUET_SAMPLES, _WAVEFORM_SAMPLES, _floquet_in_chunks, _Waveform

__all__ = ["residual_response", "ResidualSystem"]

_STABILITY = ("hill", "slow_flow")


class ResidualSystem:
    """The residuals of an approximation compiled with their Jacobians.

    ``evaluate(U, W)`` takes unknowns of shape ``(m, n)`` and frequencies ``(m,)`` and returns
    ``R (m, n)``, ``R_u (m, n, n)``, ``R_Omega (m, n)`` in one call (shared subexpressions).
    """

    def __init__(self, approx: Approximation) -> None:
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

    def evaluate(self, U: np.ndarray, W: np.ndarray):
        """Residuals and Jacobians; NaN rows where the amplitude is negative (outside the
        domain of the closed-form Fourier coefficients)."""
        n, m = self.n, W.shape[0]
        R = np.full((m, n), np.nan)
        J = np.full((m, n, n), np.nan)
        Rw = np.full((m, n), np.nan)
        ok = U[:, self.amplitude_index] >= 0
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
        a = U[:, sys_.amplitude_index]
        da = dU[:, sys_.amplitude_index]
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


def residual_response(
    approximation: Approximation,
    omega_range: Sequence[float] = (0.2, 2.0),
    *,
    amplitude_range: Sequence[float] = (1e-2, 1e2),
    seed_frequencies: int = 8,
    seed_amplitudes: int = 24,
    seed_phases: int = 6,
    ds_max: float = 0.02,
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
        Amplitudes of the seeding grid (logarithmic).
    seed_frequencies, seed_amplitudes, seed_phases
        Size of the seeding grid: frequencies across the window, amplitudes, and values of
        every other unknown over ``[-pi, pi)``.
    ds_max
        Largest continuation step (scaled arclength: about the output spacing relative to the
        window and to the amplitude).
    stability
        ``"hill"`` or ``"slow_flow"`` (when the method gives a slow flow).

    Returns
    -------
    Response
        One branch per traced curve; ``folds`` from the continuation.

    Raises
    ------
    ParameterError
        Bad window, grid sizes or stability option.
    PerturbError
        A non-square residual system, or no slow flow for ``stability="slow_flow"``.
    """
    approx = approximation
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
    if stability not in _STABILITY:
        raise ParameterError(f"stability = {stability!r}: expected one of {', '.join(_STABILITY)}")
    if stability == "slow_flow" and approx.slow_flow is None:
        raise PerturbError(f"{approx.label} has no slow flow: use stability='hill'")
    sys_ = ResidualSystem(approx)
    n, amp = sys_.n, sys_.amplitude_index

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
    U, W = _unique(U, W, amp)

    def residual(u, lam):
        return sys_.evaluate(u[None, :], np.array([lam]))[0][0]

    def jacobian(u, lam):
        _, J, Rw = sys_.evaluate(u[None, :], np.array([lam]))
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
        a_scale = np.ones(n)
        a_scale[amp] = max(1.0, abs(u0[amp]))
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
                        u_scale=a_scale,
                        ds_max=ds_max,
                        max_points=4000,
                    )
                )
            except ContinuationError:
                parts.append(None)
        if parts[0] is None and parts[1] is None:
            continue
        back, fwd = parts
        if back is not None and back.stop_reason == "closed":
            u_c, w_c, folds = back.u, back.lam, list(back.folds)
        else:
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
            u_c, w_c = np.concatenate(us), np.concatenate(ls)
        good = (u_c[:, amp] > 0) & np.all(np.isfinite(u_c), axis=1)
        if np.count_nonzero(good) < 2:
            continue
        curves.append((u_c[good], w_c[good], folds))
        traced.append(key(u_c[good], w_c[good]))

    wave = _Waveform(approx, approx.amplitude or sys_.unknowns[amp], *_phase_and_freq(approx))
    branches, fold_pts = [], []
    for u_c, w_c, folds in curves:
        branches.append(_branch(approx, sys_, wave, u_c, w_c, stability))
        for f in folds:
            fold_pts.append((float(f.lam), float(f.u[amp])))
    notes = () if branches else ("no solution found on the seeding grid",)
    params = {k: v for k, v in approx.oscillator.params.items() if v is not None}
    return Response(
        tuple(branches),
        approx.label,
        approx.oscillator.name,
        params,
        folds=tuple(fold_pts),
        notes=notes,
    )


def _phase_and_freq(approx: Approximation):
    others = [u for u in approx.unknowns if u != approx.amplitude]
    phase = others[0] if others else sp.Symbol("phi")
    return phase, approx.frequency


def _branch(approx, sys_, wave: _Waveform, U: np.ndarray, w: np.ndarray, stability: str):
    if len(approx.unknowns) != 2:
        raise PerturbError(
            f"{approx.label}: waveform statistics need exactly two unknowns (amplitude, phase); "
            f"got {', '.join(map(str, approx.unknowns))}"
        )
    amp = sys_.amplitude_index
    a, phi = U[:, amp], U[:, 1 - amp]
    coefs = wave.coefficients(a, phi, w) if wave.terms is not None else None
    xs, _ = wave.samples(a, phi, w, _WAVEFORM_SAMPLES, coefs)
    amplitude = wave.max_abs(a, phi, w, xs, coefs)
    if coefs is not None:
        mean, first = coefs[0][:, 0], np.hypot(coefs[0][:, 1], coefs[1][:, 1])
    else:
        mean = xs.mean(axis=1)
        first = 2 * np.abs(np.fft.rfft(xs, axis=1)[:, 1]) / _WAVEFORM_SAMPLES
    period = 2 * np.pi / w
    if stability == "hill":
        xf, dxf = wave.samples(a, phi, w, _FLOQUET_SAMPLES, coefs)
        max_mult = _floquet_in_chunks(
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
