"""The compiled switch scan (numba); see :mod:`perturb.simulate.flows.scan_kernel`, which
imports this module only where numba is installed and the compiled scan is wanted.

Compiled once per installation: ``cache=True`` keeps the machine code beside this file (in
``__pycache__``, like Python's own bytecode) or, where that is not writable, in the user's
own cache directory.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit as _njit

from perturb.simulate.flows.scan_kernel import (
    _CROSS,
    _NONE,
    _TANG,
    _UNDECIDED,
    BATCH_FIRST,
    BATCH_MAX,
    CACHE_OK,
    CROSSING,
    EPS,
    MAX_DEPTH,
    MAX_NODES,
    NO_CROSSING,
    OVER_BUDGET,
    OVERFLOW,
    ROOT_ITER,
    STEPS_PER_SCALE,
    UNDECIDED,
    WRONG_SIDE,
)

njit = _njit(cache=CACHE_OK, nogil=True)

#: the grid's exponentials are recomputed directly every this many steps (see scan_modal)
EXP_EVERY = 16


@njit
def constants():
    """The algorithm's constants as compiled into this module's machine code (numba freezes
    globals, and its cache is keyed by this file only: :func:`perturb.simulate.flows.
    scan_kernel.compiled_kernel` compares them with scan_kernel's and recompiles on a
    difference)."""
    return (EPS, STEPS_PER_SCALE, BATCH_FIRST, BATCH_MAX, MAX_DEPTH, ROOT_ITER, MAX_NODES)


@njit
def exps(mu, tau, e):
    for q in range(mu.size):
        e[q] = np.exp(mu[q] * tau)


@njit
def rowval(G4, p, j, e):
    s = 0.0
    for q in range(e.size):
        c = G4[p, j, q]
        s += c.real * e[q].real - c.imag * e[q].imag
    return s


@njit
def g_at(G4, j, mu, tau, e, p0, p1):
    """``(g^(p0), g^(p1))`` of surface ``j`` at ``tau``."""
    exps(mu, tau, e)
    return rowval(G4, p0, j, e), rowval(G4, p1, j, e)


@njit
def g012(G4, j, mu, tau, e):
    exps(mu, tau, e)
    return rowval(G4, 0, j, e), rowval(G4, 1, j, e), rowval(G4, 2, j, e)


@njit
def bound(aWp23, ns, mu, p, j, ta, tb):
    out = 0.0
    r = (p - 2) * ns + j
    for q in range(mu.size):
        re = mu[q].real
        out += aWp23[r, q] * math.exp(max(re * ta, re * tb))
    return out


@njit
def solve(G4, j, mu, e, p0, a, b, fa, fb):
    """Root of ``g^(p0)`` in ``[a, b]`` (``fa``, ``fb`` of opposite signs or zero):
    safeguarded Newton-bisection (``_solve``)."""
    if fb == 0.0:
        return b
    if fa == 0.0:
        return a
    pos_a = fa > 0.0
    lo, hi = a, b
    t = a + (b - a) * fa / (fa - fb)
    if not a < t < b:
        t = 0.5 * (a + b)
    dx_old = dx = b - a
    for _ in range(ROOT_ITER):
        f, df = g_at(G4, j, mu, t, e, p0, p0 + 1)
        if f == 0.0:
            return t
        if (f > 0.0) == pos_a:
            lo = t
        else:
            hi = t
        if lo < hi:
            left, right = lo, hi
        else:
            left, right = hi, lo
        tol = max(4.0 * EPS * abs(t), 1e-300)
        if abs(f) <= tol * abs(df):
            tn = t - f / df
            return tn if left <= tn <= right else t
        tn = t - f / df if df != 0.0 else math.nan
        if not (left < tn < right) or abs(2.0 * f) > abs(dx_old * df):
            dx_old, dx = dx, 0.5 * (right - left)
            tn = left + dx
        else:
            dx_old, dx = dx, t - tn
        if abs(dx) <= tol or right - left <= tol:
            return tn
        t = tn
    return t


@njit
def hermite_start(a, w, ga, gw, da, dw):
    L = w - a
    ma, mw = da * L, dw * L
    x = ga / (ga - gw)
    for _ in range(4):
        x2 = x * x
        x3 = x2 * x
        val = (2 * x3 - 3 * x2 + 1) * ga + (x3 - 2 * x2 + x) * ma + (3 * x2 - 2 * x3) * gw
        val += (x3 - x2) * mw
        der = (6 * x2 - 6 * x) * (ga - gw) + (3 * x2 - 4 * x + 1) * ma + (3 * x2 - 2 * x) * mw
        if der == 0.0:
            break
        xn = x - val / der
        if not 0.0 < xn < 1.0:
            break
        done = abs(xn - x) <= 1e-9
        x = xn
        if done:
            break
    t = a + L * x
    return t if a < t < w else math.nan


@njit
def solve_halley(G4, j, mu, e, a, w, ga, gw, start):
    """``(root, t, g'(t), g''(t))``: safeguarded Halley-bisection (``_solve_halley``)."""
    if gw == 0.0:
        _, d1, d2 = g012(G4, j, mu, w, e)
        return w, w, d1, d2
    if ga == 0.0:
        _, d1, d2 = g012(G4, j, mu, a, e)
        return a, a, d1, d2
    lo, hi = a, w
    t = start if a < start < w else a + (w - a) * ga / (ga - gw)
    if not a < t < w:
        t = 0.5 * (a + w)
    dx_old = dx = w - a
    f = df = d2f = 0.0
    for _ in range(ROOT_ITER):
        f, df, d2f = g012(G4, j, mu, t, e)
        if f == 0.0:
            return t, t, df, d2f
        if f > 0.0:
            lo = t
        else:
            hi = t
        tol = max(4.0 * EPS * abs(t), 1e-300)
        if abs(f) <= tol * abs(df):
            tn = t - f / df
            return (tn if lo <= tn <= hi else t), t, df, d2f
        den = 2.0 * df * df - f * d2f
        if den != 0.0:
            tn = t - 2.0 * f * df / den
        else:
            tn = t - f / df if df != 0.0 else math.nan
        if not (lo < tn < hi) or abs(2.0 * f) > abs(dx_old * df):
            dx_old, dx = dx, 0.5 * (hi - lo)
            tn = lo + dx
        else:
            dx_old, dx = dx, t - tn
        if abs(dx) <= tol or hi - lo <= tol:
            return tn, t, df, d2f
        t = tn
    return t, t, df, d2f


@njit
def crossing_or_graze(G4, j, mu, e, a, w, ga, gw, tol, has_slopes, s1, s2):
    start = math.nan
    if has_slopes and gw != 0.0:
        start = hermite_start(a, w, ga, gw, s1, s2)
    root, t_last, r1, r2 = solve_halley(G4, j, mu, e, a, w, ga, gw, start)
    if r1 < 0.0 and r2 > 0.0 and r1 * r1 <= 2.0 * r2 * tol:
        return t_last - r1 / r2, _TANG
    return root, _CROSS


@njit
def first_event(G4, aWp23, mu, e, st, ns, j, tol, u0, w0, G, i, touch0, clamp0, M2b, M3b):
    """The first crossing or tangency of ``g_j`` in ``(u0, w0]`` (``_first_event``), its
    recursive halving as a depth-first stack (the left half first)."""
    # stack rows (``st``, at least MAX_DEPTH + 2 of them): u, w, gu (3), gw (3), touching,
    # clamp, has_bounds, depth; the first row from the grid G at intervals i, i + 1
    st[0, 0], st[0, 1] = u0, w0
    for p in range(3):
        st[0, 2 + p] = G[p, j, i]
        st[0, 5 + p] = G[p, j, i + 1]
    st[0, 8], st[0, 9], st[0, 10], st[0, 11] = touch0, clamp0, 1.0, 0.0
    top = 1
    nodes = 0
    while top > 0:
        top -= 1
        nodes += 1
        if nodes > MAX_NODES:
            return u0, _UNDECIDED
        u, w = st[top, 0], st[top, 1]
        g0u, g1u, g2u = st[top, 2], st[top, 3], st[top, 4]
        g0w, g1w, g2w = st[top, 5], st[top, 6], st[top, 7]
        touching, clamp = st[top, 8] != 0.0, st[top, 9] != 0.0
        depth = int(st[top, 11])
        raw0, raw1, raw2 = g0u, g1u, g2u
        if touching:
            g0u = 0.0
            if clamp:
                g1u = max(g1u, 0.0)
        L = w - u
        if st[top, 10] != 0.0:
            M2, M3 = M2b, M3b
        else:
            M3 = bound(aWp23, ns, mu, 3, j, u, w)
            M2 = min(
                bound(aWp23, ns, mu, 2, j, u, w),
                0.5 * (abs(g2u) + abs(g2w) + M3 * L),
            )
        if min(g0u, g0w) - 0.125 * M2 * L * L > tol:
            continue
        if g1u * g1w > 0.0 and abs(g1u) + abs(g1w) > M2 * L:
            if g1u > 0.0 or g0w > 0.0:
                continue
            if touching:
                return u, _CROSS
            return crossing_or_graze(G4, j, mu, e, u, w, g0u, g0w, tol, True, g1u, g1w)
        simple = g2u * g2w > 0.0 and abs(g2u) + abs(g2w) > M3 * L
        if not simple and depth < MAX_DEPTH and L > 8.0 * EPS * max(abs(u), abs(w), 1e-300):
            if g0u > 0.0 and g0w > 0.0 and (abs(g1u) + M2 * L) * L <= tol:
                continue  # flat to rounding: no event (see affine_exact._first_event)
            m = 0.5 * (u + w)
            gm0, gm1, gm2 = g012(G4, j, mu, m, e)
            # the right half below the left (popped after it, if the left has no event)
            st[top, 0], st[top, 1] = m, w
            st[top, 2], st[top, 3], st[top, 4] = gm0, gm1, gm2
            st[top, 5], st[top, 6], st[top, 7] = g0w, g1w, g2w
            st[top, 8], st[top, 9], st[top, 10] = 0.0, 0.0, 0.0
            st[top, 11] = depth + 1
            top += 1
            st[top, 0], st[top, 1] = u, m
            st[top, 2], st[top, 3], st[top, 4] = raw0, raw1, raw2
            st[top, 5], st[top, 6], st[top, 7] = gm0, gm1, gm2
            st[top, 8] = 1.0 if touching else 0.0
            st[top, 9] = 1.0 if clamp else 0.0
            st[top, 10] = 0.0
            st[top, 11] = depth + 1
            top += 1
            continue
        convex = (g2u + g2w) > 0.0
        if g0w <= 0.0:
            a, ga = u, g0u
            if touching:
                if convex:
                    continue
                if g1u <= 0.0:
                    return u, _CROSS
                if g1w >= 0.0:
                    continue
                tmax = solve(G4, j, mu, e, 1, u, w, g1u, g1w)
                gmax = g_at(G4, j, mu, tmax, e, 0, 1)[0]
                if gmax <= 0.0:
                    return tmax, _CROSS
                a, ga = tmax, gmax
            return crossing_or_graze(G4, j, mu, e, a, w, ga, g0w, tol, False, 0.0, 0.0)
        if not convex or g1u >= 0.0 or g1w <= 0.0:
            continue
        tm = solve(G4, j, mu, e, 1, u, w, g1u, g1w)
        gm = g_at(G4, j, mu, tm, e, 0, 1)[0]
        if gm > tol:
            continue
        if gm >= -tol:
            return tm, _TANG
        return solve(G4, j, mu, e, 0, u, tm, g0u, gm), _CROSS
    return math.nan, _NONE


@njit
def step(colnorm, mu, amu1, tau):
    """Grid step ``1/(8 rho)`` from the terms that still matter at ``tau``."""
    nt = mu.size
    mag = np.empty(nt)
    for q in range(nt):
        if tau == 0.0:
            mag[q] = colnorm[q]
        else:
            mag[q] = colnorm[q] * math.exp(min(mu[q].real * tau, 700.0))
    big = -math.inf
    for q in range(nt):
        big = max(big, mag[q])
    thr = 1e-16 * big
    rho = 0.0
    for q in range(nt):
        if mag[q] > thr:
            rho = max(rho, amu1[q])
    return math.inf if rho == 0.0 else 1.0 / (STEPS_PER_SCALE * rho)


@njit
def state_at(Y, mu, tau):
    """``Re(Y @ e^{mu tau})``: the piece's state at ``tau``."""
    n, nt = Y.shape
    y = np.zeros(n)
    for q in range(nt):
        e = np.exp(mu[q] * tau)
        for i in range(n):
            c = Y[i, q]
            y[i] += c.real * e.real - c.imag * e.imag
    return y


@njit
def on_surface(Y, mu, tau, C, d, cc, j):
    """The state at ``tau`` placed exactly on surface ``j`` (rounding of the closed form
    leaves ``s ~ eps`` off)."""
    y = state_at(Y, mu, tau)
    s = 0.0
    for i in range(y.size):
        s += C[j, i] * y[i]
    f = (s - d[j]) / cc[j]
    for i in range(y.size):
        y[i] -= C[j, i] * f
    return y


@njit
def scan_modal(W, Y, mupow, amupow, sig, absd, tol_ulps, tau_end, touching, budget_left, C, d, cc):
    """First crossing of a modal piece without resonant pairs in ``(0, tau_end)``, from the
    surfaces whose bits are set in ``touching`` (the state is on them).

    Returns ``(status, tau, j, value, tangency_taus, tangency_surfaces, used, y)``:
    ``status`` one of NO_CROSSING, CROSSING (at ``tau`` through ``j``), OVER_BUDGET (at
    ``tau``), OVERFLOW (at ``tau``), WRONG_SIDE (surface ``j`` at ``tau``, ``value`` the
    signed ``s``); ``used`` the grid intervals scanned; ``y`` the state at the crossing,
    placed on surface ``j`` (surfaces ``C y = d``, ``cc = |C_j|^2``), or at ``tau_end``
    (no crossing), else empty."""
    ns, nt = W.shape
    mu = mupow[1].copy()
    amu1 = amupow[1].copy()
    # the piece's bounds and tolerances (as the Python piece computes them)
    aW = np.abs(W)
    aWp23 = np.empty((2 * ns, nt))
    tol = np.empty(ns)
    for j in range(ns):
        sc = 0.0
        for q in range(nt):
            aWp23[j, q] = aW[j, q] * amupow[2, q]
            aWp23[ns + j, q] = aW[j, q] * amupow[3, q]
            sc += aW[j, q]
        tol[j] = tol_ulps * EPS * (sc + absd[j])
    colnorm = np.zeros(nt)
    for i in range(Y.shape[0]):
        for q in range(nt):
            colnorm[q] += abs(Y[i, q])
    G4 = np.empty((4, ns, nt), dtype=np.complex128)
    for p in range(4):
        for j in range(ns):
            for q in range(nt):
                G4[p, j, q] = W[j, q] * (mupow[p, q] * sig[j])
    e = np.empty(nt, dtype=np.complex128)
    st = np.empty((MAX_DEPTH + 4, 12))
    empty = np.empty(0)
    tt = np.empty(8)
    tj = np.empty(8, dtype=np.int64)
    ntang = 0
    used = 0
    mmax = BATCH_MAX + 2
    taus = np.empty(mmax)
    E = np.empty((nt, mmax), dtype=np.complex128)
    aE = np.empty((nt, mmax))
    G = np.empty((3, ns, mmax))
    B = np.empty((2, ns, mmax))
    B2 = np.empty((ns, mmax))
    low = np.empty((ns, mmax))
    L = np.empty(mmax)
    touch = np.zeros(ns, dtype=np.bool_)
    for j in range(ns):
        touch[j] = (touching >> j) & 1 == 1
    clamp = touch.copy()
    tau = 0.0
    batch = BATCH_FIRST
    while tau < tau_end:
        h = step(colnorm, mu, amu1, tau)
        lim = 8.0 * EPS * max(abs(tau), 1.0)
        if not h > lim:
            h = lim
        span = tau_end - tau
        if h * batch < span:
            m1 = batch + 1
            for i in range(m1):
                taus[i] = tau + h * float(i)
        elif h < span:
            k = max(1, math.ceil(span / h - 0.5))
            m1 = k + 1
            for i in range(m1):
                taus[i] = tau + h * float(i)
            taus[k] = tau_end
        else:
            m1 = 2
            taus[0], taus[1] = tau, tau_end
        used += m1 - 1
        if used > budget_left:
            return OVER_BUDGET, tau, -1, 0.0, tt[:ntang], tj[:ntang], used, empty
        m = m1 - 1  # intervals
        for q in range(nt):
            # e^{mu t} on the uniform grid by products with e^{mu h}, recomputed directly every
            # EXP_EVERY steps and at the last point (taus[k] = tau_end): each value within
            # ~EXP_EVERY rounding units, a fraction of the tangency tolerance (TOL_ULPS); the
            # moduli (the rigorous bounds B) directly, as real exponentials
            mq = mu[q]
            ratio = np.exp(mq * h)
            v = np.exp(mq * taus[0])
            for i in range(m1):
                if i > 0:
                    if i % EXP_EVERY == 0 or i == m1 - 1:
                        v = np.exp(mq * taus[i])
                    else:
                        v = v * ratio
                E[q, i] = v
                aE[q, i] = math.exp(mq.real * taus[i])
        for p in range(3):
            for j in range(ns):
                for i in range(m1):
                    s = 0.0
                    for q in range(nt):
                        c = G4[p, j, q]
                        s += c.real * E[q, i].real - c.imag * E[q, i].imag
                    G[p, j, i] = s
        total = 0.0
        for r in range(2):
            for j in range(ns):
                for i in range(m):
                    s = 0.0
                    for q in range(nt):
                        s += aWp23[r * ns + j, q] * max(aE[q, i], aE[q, i + 1])
                    B[r, j, i] = s
                    total += s
        if not math.isfinite(total):
            return OVERFLOW, taus[m], -1, 0.0, tt[:ntang], tj[:ntang], used, empty
        for i in range(m):
            L[i] = taus[i + 1] - taus[i]
        for j in range(ns):
            for i in range(m):
                b2 = abs(G[2, j, i]) + abs(G[2, j, i + 1])
                b2 += B[1, j, i] * L[i]
                b2 *= 0.5
                B2[j, i] = min(B[0, j, i], b2)
        all_pos = True
        for j in range(ns):
            if not G[0, j, 0] >= 0.0:
                all_pos = False
        for j in range(ns):
            if touch[j]:
                G[0, j, 0] = 0.0
                if clamp[j]:
                    G[1, j, 0] = max(G[1, j, 0], 0.0)
            elif not all_pos and G[0, j, 0] < 0.0:
                if G[0, j, 0] < -tol[j]:
                    return (
                        WRONG_SIDE,
                        tau,
                        j,
                        sig[j] * G[0, j, 0],
                        tt[:ntang],
                        tj[:ntang],
                        used,
                        empty,
                    )
                if G[1, j, 0] < 0.0:
                    y = on_surface(Y, mu, tau, C, d, cc, j)
                    return CROSSING, tau, j, 0.0, tt[:ntang], tj[:ntang], used, y
                G[0, j, 0] = 0.0
                touch[j] = True
        for j in range(ns):
            for i in range(m):
                drop = 0.125 * B2[j, i]
                drop *= L[i]
                drop *= L[i]
                low[j, i] = min(G[0, j, i], G[0, j, i + 1]) - drop
            if clamp[j]:
                L0 = L[0]
                if G[1, j, 0] * L0 - 0.5 * B2[j, 0] * L0 * L0 > 0.0:
                    low[j, 0] = math.inf
        best_t = math.nan
        best_j = -1
        best_kind = _NONE
        for i in range(m):
            for j in range(ns):
                if not low[j, i] <= tol[j]:
                    continue
                first = i == 0 and touch[j]
                t_ev, kind = first_event(
                    G4,
                    aWp23,
                    mu,
                    e,
                    st,
                    ns,
                    j,
                    tol[j],
                    taus[i],
                    taus[i + 1],
                    G,
                    i,
                    1.0 if first else 0.0,
                    1.0 if (first and clamp[j]) else 0.0,
                    B2[j, i],
                    B[1, j, i],
                )
                if kind == _UNDECIDED:
                    return UNDECIDED, t_ev, j, 0.0, tt[:ntang], tj[:ntang], used, empty
                if kind != _NONE and (best_kind == _NONE or t_ev < best_t):
                    best_t, best_j, best_kind = t_ev, j, kind
            if best_kind != _NONE:
                break
        if best_kind == _NONE:
            tau = taus[m]
            touch[:] = False
            clamp[:] = False
            batch = min(2 * batch, BATCH_MAX)
            continue
        if best_t >= tau_end:
            y = state_at(Y, mu, tau_end)
            return NO_CROSSING, math.nan, -1, 0.0, tt[:ntang], tj[:ntang], used, y
        if best_kind == _CROSS:
            y = on_surface(Y, mu, best_t, C, d, cc, best_j)
            return CROSSING, best_t, best_j, 0.0, tt[:ntang], tj[:ntang], used, y
        if ntang == tt.size:
            tt2 = np.empty(2 * tt.size)
            tj2 = np.empty(2 * tt.size, dtype=np.int64)
            tt2[:ntang] = tt
            tj2[:ntang] = tj
            tt, tj = tt2, tj2
        tt[ntang] = best_t
        tj[ntang] = best_j
        ntang += 1
        tau = max(best_t, np.nextafter(tau, math.inf))
        touch[:] = False
        clamp[:] = False
        touch[best_j] = True
        clamp[best_j] = True
        batch = BATCH_FIRST
    y = state_at(Y, mu, tau_end)
    return NO_CROSSING, math.nan, -1, 0.0, tt[:ntang], tj[:ntang], used, y
