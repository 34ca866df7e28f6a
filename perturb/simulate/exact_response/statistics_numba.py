"""The statistics of an exact orbit of a piecewise-affine system, compiled (numba).

The same algorithm as :meth:`perturb.simulate.exact_response.problem.Engine.nd_statistics`
and :func:`~perturb.simulate.exact_response.problem._refine_nd` for the common case: one
shooting node, every piece of the trajectory in closed modal form without resonant pairs
(:meth:`perturb.simulate.flows.affine_exact.AffineTrajectory.modal_pieces`).  The samples,
the functionals, their extrema (cubic Hermite root, then regula falsi on the orbit itself),
the means and the first harmonic in one call instead of ~50 small numpy calls.  Values agree
with the Python version to rounding.

Imported only where numba is installed (see :func:`perturb.simulate.flows.scan_kernel.
compiled_kernel`); compiled once per installation where numba's cache is private
(:data:`perturb.simulate.flows.scan_kernel.CACHE_OK`), else once per process.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit as _njit

from perturb.simulate.flows.scan_kernel import CACHE_OK

njit = _njit(cache=CACHE_OK, nogil=True)


@njit
def _state_rate(starts, Y, mu, D, scaled, t, y, f):
    """``(y, y')`` at ``t`` into ``y``, ``f``: the piece ``k`` with ``starts[k] <= t`` (the
    last such, clamped to the pieces), its closed form at ``t - starts[k]``."""
    npc = starts.size
    k = np.searchsorted(starts, t, side="right") - 1
    k = min(max(k, 0), npc - 1)
    tau = t - starts[k]
    n, nt = Y.shape[1], Y.shape[2]
    for i in range(n):
        y[i] = 0.0
        f[i] = 0.0
    for q in range(nt):
        e = np.exp(mu[k, q] * tau)
        em = e * mu[k, q]
        for i in range(n):
            c = Y[k, i, q]
            y[i] += c.real * e.real - c.imag * e.imag
            f[i] += c.real * em.real - c.imag * em.imag
    if scaled:
        for i in range(n):
            y[i] *= D[i]
            f[i] *= D[i]


@njit
def _quadratic_root01(a, b, c):
    if a == 0.0:
        return -c / b if b != 0.0 else math.nan
    disc = b * b - 4.0 * a * c
    if not disc >= 0.0:
        return math.nan
    q = -0.5 * (b + math.copysign(math.sqrt(disc), b))
    if q == 0.0:
        return math.nan
    best = math.nan
    for r in (q / a, c / q):
        if 0.0 <= r <= 1.0 and not best <= r:
            best = r
    return best


@njit
def _refine(c, g, gd, t, j, sign, ns, starts, Y, mu, D, scaled, lo_t0, hi_t0, y, f):
    """``c . y`` at its extremum next to sample ``j`` (``_refine_nd``, ``max_iter = 4``)."""
    gj = g[j]
    rj = sign * gd[j]
    if rj > 0.0:
        a, b = j, j + 1
    elif rj < 0.0:
        if j > 0:
            a, b = j - 1, j
        else:
            a, b = ns - 1, ns
    else:
        return gj
    ra, rb = sign * gd[a], sign * gd[b]
    if not (ra > 0.0 >= rb):
        return gj
    ta, tb = t[a], t[b]
    h = tb - ta
    ga, gb = sign * g[a], sign * g[b]
    ma, mb = ra * h, rb * h
    qa = 6.0 * ga + 3.0 * ma - 6.0 * gb + 3.0 * mb
    qb = -6.0 * ga - 4.0 * ma + 6.0 * gb - 2.0 * mb
    qc = ma
    lo, hi = 0.0, 1.0
    s = _quadratic_root01(qa, qb, qc)
    iters = 0 if 0.0 <= s <= 1.0 else 40
    if iters:
        s = ra / (ra - rb)
    for _ in range(iters):
        q = (qa * s + qb) * s + qc
        if q > 0.0:
            lo = s
        else:
            hi = s
        dq = 2.0 * qa * s + qb
        sn = s - q / dq if dq != 0.0 else 0.5 * (lo + hi)
        if not lo < sn < hi:
            sn = 0.5 * (lo + hi)
        if abs(sn - s) < 1e-15:
            s = sn
            break
        s = sn
    best = gj
    lo_t, hi_t, rlo, rhi = ta, tb, ra, rb
    tt = ta + s * h
    n = c.size
    for _ in range(4):
        ti = min(max(tt, lo_t0), hi_t0)
        _state_rate(starts, Y, mu, D, scaled, ti, y, f)
        val = 0.0
        rate = 0.0
        for i in range(n):
            val += c[i] * y[i]
            rate += c[i] * f[i]
        rate *= sign
        if sign * val > sign * best:
            best = val
        if rate > 0.0:
            lo_t, rlo = tt, rate
        else:
            hi_t, rhi = tt, rate
        curv = (rlo - rhi) / max(hi_t - lo_t, 1e-300)
        step = abs(rate) / curv if curv > 0.0 else hi_t - lo_t
        if abs(rate) * step <= 1e-13 * max(1.0, abs(val)) or hi_t - lo_t <= 1e-14 * h:
            break
        tt = lo_t + (hi_t - lo_t) * rlo / (rlo - rhi) if rlo != rhi else 0.5 * (lo_t + hi_t)
    return best


@njit
def orbit_statistics(starts, Y, mu, D, scaled, funcs, t, node0, node1, ns, h, m, out_is):
    """Samples and statistics of one orbit (one node).

    ``starts`` (pieces), ``Y`` (pieces, n, nt) and ``mu`` (pieces, nt): the closed forms;
    ``D``: the state scale (``scaled``); ``funcs`` (K, n): the output and the coordinates;
    ``t`` (ns + 1) the sample times (evaluated clipped to ``[node0, node1]``), ``h`` their
    spacing; ``m`` the forcing periods per orbit; ``out_is`` the row equal to the
    output (-1: none).

    Returns ``(amps, means, first, X)``: max |.| and mean of every row, the output's first
    harmonic amplitude, and the sampled states ``X`` (n, ns + 1)."""
    n = Y.shape[1]
    K = funcs.shape[0]
    npts = ns + 1
    tc = np.empty(npts)
    for i in range(npts):
        tc[i] = min(max(t[i], node0), node1)
    X = np.empty((n, npts))
    F = np.empty((n, npts))
    # the samples: piece k holds the samples up to and including its end time (as
    # AffineTrajectory.state_and_rate cuts them)
    npc = starts.size
    lo = 0
    for k in range(npc):
        if k + 1 < npc:
            hi = np.searchsorted(tc, starts[k + 1], side="right")
        else:
            hi = npts
        for i in range(lo, hi):
            tau = tc[i] - starts[k]
            for r in range(n):
                X[r, i] = 0.0
                F[r, i] = 0.0
            for q in range(Y.shape[2]):
                e = np.exp(mu[k, q] * tau)
                em = e * mu[k, q]
                for r in range(n):
                    cc = Y[k, r, q]
                    X[r, i] += cc.real * e.real - cc.imag * e.imag
                    F[r, i] += cc.real * em.real - cc.imag * em.imag
        lo = max(lo, hi)
    if scaled:
        for r in range(n):
            for i in range(npts):
                X[r, i] *= D[r]
                F[r, i] *= D[r]
    G = funcs @ X
    Gd = funcs @ F
    means = np.empty(K)
    for k in range(K):
        s = 0.0
        for i in range(ns):
            s += G[k, i]
        means[k] = s / ns
    amps = np.zeros(K)
    y = np.empty(n)
    f = np.empty(n)
    for k in range(K):
        if k == 0 and out_is >= 0:
            continue
        jmax, jmin = 0, 0
        for i in range(1, ns):
            if G[k, i] > G[k, jmax]:
                jmax = i
            if G[k, i] < G[k, jmin]:
                jmin = i
        s0, j0, s1, j1 = 1.0, jmax, -1.0, jmin
        v0, v1 = abs(G[k, jmax]), abs(G[k, jmin])
        if v1 > v0:
            s0, j0, s1, j1 = -1.0, jmin, 1.0, jmax
            v0, v1 = v1, v0
        best = 0.0
        v = _refine(funcs[k], G[k], Gd[k], t, j0, s0, ns, starts, Y, mu, D, scaled, node0,
                    node1, y, f)  # fmt: skip
        best = max(best, abs(v))
        rmax = 0.0
        for i in range(ns):
            rmax = max(rmax, abs(Gd[k, i]))
        if not v1 + 2.0 * h * rmax < best:
            v = _refine(funcs[k], G[k], Gd[k], t, j1, s1, ns, starts, Y, mu, D, scaled, node0,
                        node1, y, f)  # fmt: skip
            best = max(best, abs(v))
        amps[k] = best
    if out_is >= 0:
        amps[0] = amps[out_is]
    # the first harmonic of the output: one bin of the discrete Fourier transform
    re = 0.0
    im = 0.0
    for i in range(ns):
        ang = -2.0 * math.pi * m * i / ns
        re += G[0, i] * math.cos(ang)
        im += G[0, i] * math.sin(ang)
    first = 2.0 * math.hypot(re, im) / ns if m < ns // 2 + 1 else 0.0
    return amps, means, first, X
