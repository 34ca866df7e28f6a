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

import numpy as np
import sympy as sp

from ..errors import PerturbError
from ..model import Oscillator
from .compile import lambdify

__all__ = ["expm2", "monodromy_multipliers"]


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


def monodromy_multipliers(
    oscillator: Oscillator,
    x: np.ndarray,
    v: np.ndarray,
    period: np.ndarray,
    frequency: sp.Symbol | None = None,
    frequency_values: np.ndarray | None = None,
) -> np.ndarray:
    """Largest Floquet multiplier modulus about sampled approximate orbits.

    Parameters
    ----------
    oscillator
        The system; its parameters must have values (the forcing frequency may be given
        per orbit through ``frequency``/``frequency_values``).
    x, v
        Shape ``(n_orbits, N)``: the orbits sampled at ``N`` equally spaced instants over one
        period (``N >= 64``; ``x[:, 0]`` at ``t = 0``).
    period
        Shape ``(n_orbits,)``.

    Returns
    -------
    numpy.ndarray
        ``max |mu|`` for each orbit.

    Raises
    ------
    PerturbError
        If the linearisation depends on time explicitly (parametric terms).
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
    gx = sp.diff(g, osc.x)
    gv = sp.diff(g, osc.v)
    # Heaviside'(.) = DiracDelta: the jump of a PWL force is treated by the crossing split,
    # so the delta terms of g_x are dropped here (continuous PWL forces have none).
    gx = gx.replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    gv = gv.replace(sp.DiracDelta, lambda *a: sp.Integer(0))
    coeff = lambdify((osc.x, osc.v), [gv, gx])
    breakpoints: np.ndarray = np.array([])
    if osc.is_piecewise_linear and osc.nonsmooth != 0:
        breakpoints = np.asarray(osc.piecewise_linear().numeric().breakpoints, float)

    h = np.asarray(period, float)[:, None] / N * np.ones((1, N))
    x0, x1 = x, np.roll(x, -1, axis=1)
    v0, v1 = v, np.roll(v, -1, axis=1)
    xm, vm = (x0 + x1) / 2, (v0 + v1) / 2
    if breakpoints.size == 0:
        p, q = coeff(xm, vm)
        steps = expm2(p, q, h)
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
        frac = np.where(cross, _hermite_crossing(x0, x1, v0 * h, v1 * h, d, frac), frac)
        xa = (x0 + np.where(cross, d, x1)) / 2
        xb = (np.where(cross, d, x0) + x1) / 2
        pa, qa = coeff(xa, vm)
        pb, qb = coeff(xb, vm)
        first = expm2(pa, qa, h * frac)
        second = expm2(pb, qb, h * (1 - frac))
        steps = _matmul(second, first)
    P = _ordered_product(steps)
    mult = np.linalg.eigvals(P)
    return np.max(np.abs(mult), axis=-1)
