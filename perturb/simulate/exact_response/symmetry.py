"""Mirroring of odd systems: the symmetry test of an engine, the image of a point and of
a branch under :math:`(x, t) \to (-x, t + T/2)`, and walking along a traced polyline.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import math

import numpy as np

from perturb.errors import PerturbError
from perturb.model.symmetry import is_odd_symmetric, mirror_nodes
from perturb.simulate.exact_response.base import SIG_PHASES
from perturb.simulate.exact_response.march import Tracer
from perturb.simulate.exact_response.problem import Engine, Pt
from perturb.simulate.exact_response.steps import chord3


# =============================================================================================
# symmetry of odd systems
# =============================================================================================
def engine_is_odd_symmetric(eng: Engine) -> bool:
    r"""True when :math:`f(t + T/2, -y) = -f(t, y)` (odd force, odd harmonics only):
    :func:`perturb.model.symmetry.is_odd_symmetric` on the vector field at two parameter
    values (the symmetry may hold only for some parameters of the family), in the box
    :math:`|x|, |v| \le 16` (past the breakpoints of the builtin models) to ``1e-10``."""
    for p in (eng.lo + 0.3 * eng.Sp, eng.lo + 0.8 * eng.Sp):
        flow = eng.flow(p)
        if eng.n != 2:
            if not _odd_n(flow.vector_field, float(flow.period), eng.n):
                return False
            continue
        if not is_odd_symmetric(flow.vector_field, float(flow.period), 16.0, rtol=1e-10):
            return False
    return True


def _odd_n(vector_field, period: float, n: int, samples: int = 64, extent: float = 16.0) -> bool:
    r""":math:`f(t + T/2, -y) = -f(t, y)` for a system of ``n`` states, at ``samples``
    pseudo-random times and states in :math:`[-16, 16]^n` (a fixed seed), to 1e-10 relative
    (the test of :func:`perturb.model.symmetry.is_odd_symmetric`, which samples two states)."""
    rng = np.random.default_rng(1)
    for _ in range(samples):
        t = float(rng.uniform(0.0, period))
        y = rng.uniform(-extent, extent, n)
        try:
            a = np.asarray(vector_field(t, y), float)
            b = np.asarray(vector_field(t + 0.5 * period, -y), float)
        except (PerturbError, ValueError, ArithmeticError):
            return False
        if not np.all(np.abs(a + b) <= 1e-10 * (1.0 + np.abs(a))):
            return False
    return True


def mirror_point(tracer: Tracer, q: Pt) -> Pt:
    r"""The orbit :math:`-y(t + T/2)` of an odd system: same multipliers and amplitude,
    opposite mean, signature shifted by two quarter periods and negated."""
    eng = tracer.eng
    m = eng.m
    if q.mode == "closed" and q.seg >= 0 and tracer.closed is not None:
        r = tracer.closed.point(q.p, eng.system0.n_segments - 1 - q.seg)
        r.grazing = q.grazing
        return r
    N = q.N
    if N % (2 * m) == 0:
        Z = mirror_nodes(q.Z, m)
    else:
        # node i of the image is -y(t_i + T/2): propagate from the nearest earlier node of
        # the orbit (never over a whole period: the orbit may be strongly unstable)
        flow = eng.flow(q.p)
        T = float(flow.period)
        P = m * T
        tn = eng.node_times(P, N)
        Z = np.empty_like(q.Z)
        for i in range(N):
            tau = eng.t0 + ((tn[i] + T / 2 - eng.t0) % P)
            k = min(int(np.searchsorted(tn, tau, side="right") - 1), N - 1)
            if abs(tn[k] - tau) <= 1e-14 * P:
                Z[i] = -q.Z[k]
                continue
            Z[i] = -flow(q.Z[k], tn[k], tau).y
            eng.periods += m * (tau - tn[k]) / P
            eng.calls += 1
    r = Pt(q.p, Z, eng.n)
    r.mult = q.mult.copy()
    r.stats = (q.stats[0], q.stats[1], -q.stats[2])
    r.sig = -np.roll(q.sig.reshape(-1, eng.n), -(SIG_PHASES // 2), axis=0).ravel()
    if q.extra is not None:
        r.extra = (q.extra[0].copy(), -q.extra[1])
    r.switches, r.grazing, r.mode, r.fold = q.switches, q.grazing, "shoot", q.fold
    r.source = "mirror"
    return r


def mirror_branch(tracer: Tracer, pts: list[Pt]) -> list[Pt]:
    out = [mirror_point(tracer, q) for q in pts]
    Sp = tracer.eng.Sp
    n = len(out)
    for i, (r, q) in enumerate(zip(out, pts, strict=True)):
        tq = q.tangent3()
        a, b = out[max(i - 1, 0)], out[min(i + 1, n - 1)]
        k = r.Z.shape[1]
        sec = chord3(a, b, Sp)[:k] if n > 1 else np.zeros(k)
        ns = float(np.linalg.norm(sec))
        ypart = sec / ns * math.sqrt(max(0.0, 1 - tq[k] ** 2)) if ns > 0 else np.zeros(k)
        r.tangent = np.r_[ypart, np.zeros(k * r.N - k), tq[k]]
    return out


def walk(pts: list[Pt], closed: bool, i: int, target: float) -> tuple[bool, int, int]:
    """Follow a branch from point ``i`` towards parameter ``target`` over stable points only:
    (reached, index reached, last stable index)."""
    n = len(pts)
    sgn = float(np.sign(target - pts[i].p))
    if sgn == 0.0:
        return True, i, i

    def step(j: int, s: int) -> int | None:
        k = j + s
        if closed:
            return k % n
        return k if 0 <= k < n else None

    s = 0
    for cand in (1, -1):
        k = step(i, cand)
        if k is not None and (pts[k].p - pts[i].p) * sgn > 0:
            s = cand
            break
    if s == 0:
        return False, i, i
    j = i
    for _ in range(n):
        k = step(j, s)
        if k is None or (pts[k].p - pts[j].p) * sgn < 0 or pts[k].max_mult >= 1.0:
            return False, j, j
        j = k
        if (pts[j].p - target) * sgn >= 0:
            return True, j, j
    return False, j, j
