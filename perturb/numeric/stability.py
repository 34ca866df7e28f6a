"""Floquet multipliers of the linearisation about an approximate periodic orbit.

For ``x'' + g(x, x') = f(t)`` and an approximate orbit ``x_p(t)`` of period ``T``, a small
perturbation obeys ``y' = M(t) y`` with ``M = [[0, 1], [-g_x, -g_v]]`` evaluated on the orbit.
The monodromy matrix is the ordered product of the propagators over one period; its
eigenvalues (Floquet multipliers) decide stability. This is the time-domain counterpart of
Hill's method and does not depend on how the orbit was found, so every approximation is
judged the same way.

For piecewise-linear forces ``g_x`` is piecewise constant: the product of exact 2x2 matrix
exponentials, with each step split where the orbit crosses a breakpoint, is exact up to the
location of the crossing. For smooth forces the midpoint (second-order Magnus) rule is used.
Averaged slow flows cannot do this for a negative-stiffness segment — the averaging ansatz
assumes near-harmonic motion and misses the exponential divergence of the saddle — which
is why this module exists.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sympy as sp

from perturb.errors import PerturbError
from perturb.model.oscillator import Oscillator
from perturb.numeric.compile import lambdify

__all__ = ["expm2", "linearise", "Linearisation", "monodromy_multipliers", "hill_exponents"]


def expm2(p: np.ndarray, q: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``exp(h * [[0, 1], [-q, -p]])`` for arrays of ``p`` (damping), ``q`` (stiffness), ``h``.

    Closed form: with ``s = -p/2`` and ``beta^2 = p^2/4 - q``, ``exp(hM) = e^{sh}
    [C I + S (M - s I)]`` where ``C = cosh(beta h)``, ``S = sinh(beta h)/beta`` (their
    trigonometric forms when ``beta^2 < 0``, and the limit ``S = h`` at ``beta = 0``).
    Returns shape ``(..., 2, 2)``.
    """
    p, q, h = np.broadcast_arrays(np.asarray(p, float), np.asarray(q, float), np.asarray(h, float))
    b2 = p * p / 4 - q
    z = np.sqrt(np.abs(b2)) * h
    small = z < 1e-4
    with np.errstate(all="ignore"):
        zz = np.where(small, 1.0, z)
        C = np.where(b2 >= 0, np.cosh(zz), np.cos(zz))
        S = np.where(b2 >= 0, np.sinh(zz), np.sin(zz)) / zz * h
    # series for |beta h| small: cosh/cos -> 1 + b2 h^2/2, sinh/sin over beta -> h(1 + b2 h^2/6)
    C = np.where(small, 1 + b2 * h * h / 2, C)
    S = np.where(small, h * (1 + b2 * h * h / 6), S)
    s = -p / 2
    e = np.exp(s * h)
    out = np.empty(p.shape + (2, 2))
    out[..., 0, 0] = e * (C - s * S)
    out[..., 0, 1] = e * S
    out[..., 1, 0] = e * (-q * S)
    out[..., 1, 1] = e * (C + (-p - s) * S)
    return out


def _matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...jk->...ik", a, b)


def _ordered_product(steps: np.ndarray) -> np.ndarray:
    """``steps[:, N-1] @ ... @ steps[:, 0]`` by pairwise reduction: log2(N) vectorised
    products instead of N sequential ones."""
    while steps.shape[1] > 1:
        if steps.shape[1] % 2:
            eye = np.broadcast_to(np.eye(2), steps[:, :1].shape)
            steps = np.concatenate([steps, eye], axis=1)
        steps = _matmul(steps[:, 1::2], steps[:, 0::2])
    return steps[:, 0]


def _hermite_crossing(x0, x1, m0, m1, d, guess) -> np.ndarray:
    """Where the cubic Hermite interpolant of (x, dx/ds) on s in [0, 1] equals ``d``:
    Newton from the linear guess. Linear interpolation alone is only O(h^2) accurate near a
    turning point (grazing orbits), which shows in the multipliers."""
    s = guess
    for _ in range(4):
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        val = h00 * x0 + h10 * m0 + h01 * x1 + h11 * m1 - d
        der = (6 * s2 - 6 * s) * x0 + (3 * s2 - 4 * s + 1) * m0 + (-6 * s2 + 6 * s) * x1
        der = der + (3 * s2 - 2 * s) * m1
        with np.errstate(all="ignore"):
            step = np.where(der != 0, val / der, 0.0)
        s = np.clip(s - np.nan_to_num(step), 0.0, 1.0)
    return s


@dataclass(frozen=True)
class Linearisation:
    """The equation of motion linearised about sampled orbits, ``y'' + p(t) y' + q(t) y = 0``,
    as two sub-steps per sample interval with constant ``(p, q)`` on each.

    ``q = dg/dx`` and ``p = dg/dx'`` are evaluated at sub-step midpoints; each sample interval
    is split where the orbit crosses a breakpoint of a piecewise-linear force, so ``(p, q)`` is
    exact there and second-order (midpoint rule) for smooth forces. Arrays have shape
    ``(n_orbits, 2N)``: start time ``t``, duration ``h``, and ``p``, ``q``.
    """

    t: np.ndarray
    h: np.ndarray
    p: np.ndarray
    q: np.ndarray
    period: np.ndarray


def linearise(
    oscillator: Oscillator,
    x: np.ndarray,
    v: np.ndarray,
    period: np.ndarray,
    frequency: sp.Symbol | None = None,
) -> Linearisation:
    """Linearise ``oscillator`` about orbits sampled at ``N`` equally spaced instants.

    Parameters
    ----------
    oscillator
        The system; its parameters must have values (``frequency`` names a parameter, the
        forcing frequency, that the linearisation does not need and may lack a value).
    x, v
        Shape ``(n_orbits, N)``, ``N >= 64``; ``x[:, 0]`` at ``t = 0``.
    period
        Shape ``(n_orbits,)``.

    Raises
    ------
    PerturbError
        If the linearisation depends on time explicitly (parametric terms), on too few
        samples or on parameters without values.
    """
    osc = oscillator
    if osc.parametric != 0:
        raise PerturbError(
            f"model {osc.name!r} has parametric terms; the orbit linearisation needs time too"
        )
    x = np.atleast_2d(np.asarray(x, float))
    v = np.atleast_2d(np.asarray(v, float))
    N = x.shape[1]
    if N < 64:
        raise PerturbError(f"{N} samples per period: expected at least 64")
    subs = {s: val for s, val in osc.substitutions().items() if s != frequency}
    g = osc.g.xreplace(subs)
    free = g.free_symbols - {osc.x, osc.v}
    if free:
        raise PerturbError(f"model {osc.name!r} needs values for {sorted(map(str, free))}")
    # Heaviside'(.) = DiracDelta: the jump of a PWL force is treated by the crossing split,
    # so the delta terms are dropped here (continuous PWL forces have none).
    gx = sp.diff(g, osc.x).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    gv = sp.diff(g, osc.v).replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    coeff = lambdify((osc.x, osc.v), [gv, gx])
    breakpoints: np.ndarray = np.array([])
    if osc.is_piecewise_linear and osc.nonsmooth != 0:
        breakpoints = np.asarray(osc.piecewise_linear().numeric().breakpoints, float)

    period = np.asarray(period, float).reshape(-1)
    h = period[:, None] / N * np.ones((1, N))
    t0 = period[:, None] * np.arange(N)[None, :] / N
    x0, x1 = x, np.roll(x, -1, axis=1)
    v0, v1 = v, np.roll(v, -1, axis=1)
    vm = (v0 + v1) / 2
    if breakpoints.size == 0:
        frac = np.full_like(x0, 0.5)
        xa, xb = (3 * x0 + x1) / 4, (x0 + 3 * x1) / 4
    else:
        # split each step at the first breakpoint crossed (one per step at these sample
        # rates; a second crossing in one step would need a grazing orbit and is caught by
        # the fraction clipping below)
        seg0 = np.searchsorted(breakpoints, x0)
        seg1 = np.searchsorted(breakpoints, x1)
        cross = seg0 != seg1
        k = np.clip(np.where(x1 > x0, seg0, seg0 - 1), 0, breakpoints.size - 1)
        d = breakpoints[k]
        with np.errstate(all="ignore"):
            frac = np.where(cross, (d - x0) / (x1 - x0), 1.0)
        frac = np.clip(np.nan_to_num(frac, nan=0.5), 0.0, 1.0)
        if cross.any():  # only the few crossing intervals need the Newton polish
            frac[cross] = _hermite_crossing(
                x0[cross], x1[cross], (v0 * h)[cross], (v1 * h)[cross], d[cross], frac[cross]
            )
        xa = (x0 + np.where(cross, d, x1)) / 2
        xb = (np.where(cross, d, x0) + x1) / 2
    pa, qa = coeff(xa, vm)
    pb, qb = coeff(xb, vm)
    ha, hb = h * frac, h * (1 - frac)

    def interleave(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = np.empty(a.shape[:-1] + (2 * a.shape[-1],))
        out[..., 0::2], out[..., 1::2] = a, b
        return out

    return Linearisation(
        t=interleave(t0, t0 + ha),
        h=interleave(ha, hb),
        p=interleave(np.broadcast_to(pa, ha.shape), np.broadcast_to(pb, hb.shape)),
        q=interleave(np.broadcast_to(qa, ha.shape), np.broadcast_to(qb, hb.shape)),
        period=period,
    )


def monodromy_multipliers(
    oscillator: Oscillator,
    x: np.ndarray,
    v: np.ndarray,
    period: np.ndarray,
    frequency: sp.Symbol | None = None,
) -> np.ndarray:
    """Largest Floquet multiplier modulus about sampled approximate orbits: the ordered
    product of the exact propagators of the :func:`linearise` pieces.

    Returns
    -------
    numpy.ndarray
        ``max |mu|`` for each orbit.
    """
    lin = linearise(oscillator, x, v, period, frequency)
    P = _ordered_product(expm2(lin.p, lin.q, lin.h))
    return np.max(np.abs(np.linalg.eigvals(P)), axis=-1)


def hill_exponents(
    oscillator: Oscillator,
    x: np.ndarray,
    v: np.ndarray,
    period: np.ndarray,
    harmonics: int,
    frequency: sp.Symbol | None = None,
) -> np.ndarray:
    """Floquet exponents by Hill's method with perturbation harmonics ``-H..H``.

    With ``y = exp(lambda t) sum_n c_n exp(i n w t)``, ``w = 2 pi / T``, the linearisation
    ``y'' + p y' + q y = 0`` becomes the quadratic eigenproblem

        (lambda + i n w)^2 c_n + sum_m p_{n-m} (lambda + i m w) c_m + sum_m q_{n-m} c_m = 0,

    with ``p_k, q_k`` the Fourier coefficients of ``p(t), q(t)`` (integrated exactly over the
    constant pieces of :func:`linearise`). Truncated at the harmonics of a harmonic-balance
    solution, its singularity at ``lambda = 0`` coincides with the solution's folds, so the
    stability it reports changes exactly where the approximate branch turns. Of the
    ``2(2H+1)`` eigenvalues the two with the smallest ``|Im lambda|`` are the Floquet exponents
    (the others are copies shifted by multiples of ``i w``), the second chosen among the next
    few by Liouville's formula ``lambda_1 + lambda_2 = -mean(p)`` modulo ``i w`` so that two
    real negative multipliers are not replaced by one of them counted twice.

    Returns
    -------
    numpy.ndarray
        Shape ``(n_orbits, 2)``, complex.
    """
    if int(harmonics) < 1:
        raise PerturbError(f"harmonics = {harmonics}: expected at least 1")
    H = int(harmonics)
    lin = linearise(oscillator, x, v, period, frequency)
    w = 2 * np.pi / lin.period
    ks = np.arange(-2 * H, 2 * H + 1)
    # Fourier coefficients c_k = (1/T) int c(t) exp(-i k w t) dt of the piecewise-constant
    # coefficients, exact per piece.
    # exp(-i k w t) at the piece ends by powers of exp(-i w t): one complex exponential per
    # point instead of one per harmonic
    e_a = np.exp(-1j * w[:, None] * lin.t)
    e_b = np.exp(-1j * w[:, None] * (lin.t + lin.h))
    kernel = np.empty((lin.t.shape[0], ks.size, lin.t.shape[1]), dtype=complex)
    kernel[:, 2 * H, :] = lin.h
    pa, pb = np.ones_like(e_a), np.ones_like(e_b)
    for k in range(1, 2 * H + 1):
        pa, pb = pa * e_a, pb * e_b
        val = (pb - pa) / (-1j * k * w[:, None])
        kernel[:, 2 * H + k, :] = val
        kernel[:, 2 * H - k, :] = np.conj(val)
    T = lin.period[:, None]
    pk = np.einsum("okj,oj->ok", kernel, lin.p) / T
    qk = np.einsum("okj,oj->ok", kernel, lin.q) / T
    n = np.arange(-H, H + 1)
    size = n.size
    idx = (n[:, None] - n[None, :]) + 2 * H  # index of k = n - m
    Pm = pk[:, idx]
    Qm = qk[:, idx]
    eye = np.eye(size)
    inw = 1j * n[None, :] * w[:, None]  # (n_orb, size)
    C = 2 * inw[:, :, None] * eye + Pm
    K = (inw**2)[:, :, None] * eye + Pm * inw[:, None, :] + Qm
    n_orb = lin.period.size
    big = np.zeros((n_orb, 2 * size, 2 * size), dtype=complex)
    big[:, :size, size:] = eye
    big[:, size:, :size] = -K
    big[:, size:, size:] = -C
    lam = np.linalg.eigvals(big)
    order = np.argsort(np.abs(lam.imag) + 1e-12 * np.abs(lam.real), axis=1)
    # the first exponent has the smallest |Im|; its partner is not the runner-up but the one
    # of the next few that satisfies Liouville's formula lam1 + lam2 = -mean(p) modulo i w:
    # for real negative multipliers a + i w/2 and a - i w/2 tie on |Im| yet are one multiplier
    # counted twice (they differ by i w), and the other multiplier would be lost
    ranked = np.take_along_axis(lam, order, axis=1)
    first = ranked[:, 0]
    pool = ranked[:, 1 : min(ranked.shape[1], 8)]
    d = pool - (-pk[:, 2 * H].real - first)[:, None]
    d = d - 1j * w[:, None] * np.round(d.imag / w[:, None])
    score = np.abs(d) + 1e-9 * (np.abs(first) + w)[:, None] * np.arange(pool.shape[1])
    second = np.take_along_axis(pool, np.argmin(score, axis=1)[:, None], axis=1)[:, 0]
    return np.column_stack([first, second])
