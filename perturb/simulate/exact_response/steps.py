"""Steps of the shooting continuation: output spacing and key steps, the curve
registry and polylines used by proximity tests, the step control on the generic core,
the corrector (``correct_point``) and the tangent / chord / orientation helpers.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from perturb.errors import PerturbError
from perturb.numeric.continuation import (
    Corrector,
    Evaluation,
    StepControl,
    null_tangent,
)
from perturb.simulate.exact_response.base import (
    JOIN_FRACTION,
    ND_STATS_TOL,
    SIG_PHASES,
    STATS_TOL,
)
from perturb.simulate.exact_response.closed_form import segment_distance
from perturb.simulate.exact_response.options import Settings
from perturb.simulate.exact_response.problem import Engine, Pt


def key_step(a: Pt, b: Pt, Sp: float) -> float:
    """Distance of two points in the proximity metric."""
    R = max(a.R, b.R)
    if a.sig.size != b.sig.size:
        return math.inf
    ds_ = b.sig - a.sig
    d2 = float(ds_ @ ds_) + sum((x - y) ** 2 for x, y in zip(b.stats, a.stats, strict=True))
    return math.sqrt(d2 / (R * R) + ((b.p - a.p) / Sp) ** 2)


class _Growing:
    """An array that grows along its first axis by appending rows (amortised O(1))."""

    def __init__(self, shape: tuple[int, ...] = ()) -> None:
        self._a = np.empty((64, *shape))
        self.n = 0

    def append(self, row: Any) -> None:
        if self.n == self._a.shape[0]:
            self._a = np.concatenate([self._a, np.empty_like(self._a)])
        self._a[self.n] = row
        self.n += 1

    @property
    def arr(self) -> np.ndarray:
        return self._a[: self.n]


#: Candidate segments (after the parameter prefilter) above which Poly.near first bounds the
#: distance from five coordinates of the keys before the full distance.
_PRUNE_MIN = 8


class Poly:
    """The keys of a traced curve, for "does this point lie on it" queries.

    A point lies on segment k when its distance is below JOIN_FRACTION of the longest of
    ``ds_max``, the segment and the step ``h`` that produced the point (a sampled curve
    deviates from its chords by ``kappa L^2 / 8``).  The distance is at least the parameter
    gap over ``Sp``, so a per-segment parameter range (grown by that tolerance) rules out
    most segments before any distance is computed."""

    def __init__(self, width: int, Sp: float, ds_max: float, m: int = 1) -> None:
        self.keys = _Growing((width,))
        self.lo = _Growing()
        self.hi = _Growing()
        self.seglen = _Growing()  # each segment's length L in its own scale (see append)
        self.lo_min, self.hi_max = math.inf, -math.inf
        self.Sp, self.base, self.m = Sp, ds_max, m

    @classmethod
    def of(cls, pts: list[Pt], Sp: float, ds_max: float, m: int = 1) -> Poly:
        width = pts[0].key().size if pts else 2 * SIG_PHASES * m + 5
        out = cls(width, Sp, ds_max, m)
        for q in pts:
            out.append(q.key())
        return out

    def __len__(self) -> int:
        return self.keys.n

    def append(self, key: np.ndarray) -> None:
        if not self.keys.n and self.keys.arr.shape[1:] != key.shape:
            self.keys = _Growing(key.shape)  # an empty polyline of another state size
        if self.keys.n:
            prev = self.keys.arr[-1]
            # the segment's length in the metric of segment_distance (a margin of the
            # parameter prefilter only: computed without its array machinery)
            inv = 1.0 / max(float(prev[-1]), float(key[-1]))
            ab = key[:-2] * inv - prev[:-2] * inv
            abp = (float(key[-2]) - float(prev[-2])) / self.Sp
            L = math.sqrt(float(ab @ ab) + abp * abp)
            grow = self.Sp * JOIN_FRACTION * max(L, self.base)
            lo, hi = min(prev[-2], key[-2]) - grow, max(prev[-2], key[-2]) + grow
            self.lo.append(lo)
            self.hi.append(hi)
            self.seglen.append(L)
            self.lo_min, self.hi_max = min(self.lo_min, lo), max(self.hi_max, hi)
        self.keys.append(key)

    def near(self, q: np.ndarray, h: float = 0.0, start: int = 0, stop: int | None = None) -> int:
        """Index of a segment (among segments ``start .. stop-1``) that key ``q`` lies on,
        else -1."""
        n = self.keys.n
        if n == 0 or self.keys.arr.shape[1] != q.size:
            return -1
        if n == 1:
            d, _ = segment_distance(q, self.keys.arr, self.keys.arr, self.Sp)
            return 0 if d[0] < JOIN_FRACTION * max(h, self.base) else -1
        stop = n - 1 if stop is None else min(stop, n - 1)
        if stop <= start:
            return -1
        extra = self.Sp * JOIN_FRACTION * h
        qp = q[-2]
        if start == 0 and not self.lo_min - extra <= qp <= self.hi_max + extra:
            return -1
        lo, hi = self.lo.arr[start:stop], self.hi.arr[start:stop]
        idx = np.flatnonzero((lo - extra <= qp) & (qp <= hi + extra)) + start
        if idx.size == 0:
            return -1
        K = self.keys.arr
        if idx.size > _PRUNE_MIN:
            idx = self._prune(q, h, idx)
            if idx.size == 0:
                return -1
        d, L = segment_distance(q, K[idx], K[idx + 1], self.Sp)
        ok = d < JOIN_FRACTION * np.maximum(np.maximum(L, h), self.base)
        if not np.any(ok):
            return -1
        return int(idx[int(np.argmin(np.where(ok, d, np.inf)))])

    def _prune(self, q: np.ndarray, h: float, idx: np.ndarray) -> np.ndarray:
        """The segments of ``idx`` that key ``q`` may lie on: a lower bound of the distance
        of :func:`segment_distance` from the statistics and the parameter alone (the distance
        to the box of the segment's two ends in those coordinates, each state coordinate
        over the largest ``R`` of the point and the ends, as there) against the largest
        threshold ``JOIN_FRACTION max(L, h, ds_max)`` (``L`` with the segment's own ``R``,
        at least the ``L`` measured with the point's); a margin of 1e-6 covers rounding, so
        no segment that passes the full test is dropped."""
        K = self.keys.arr
        a, b = K[idx, -5:], K[idx + 1, -5:]  # (amplitude, first harmonic, mean, p, R)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        gap = np.maximum(np.maximum(lo - q[-5:], q[-5:] - hi), 0.0)
        R = np.maximum(hi[:, 4], q[-1])
        lb2 = (gap[:, 0] ** 2 + gap[:, 1] ** 2 + gap[:, 2] ** 2) / (R * R)
        lb2 += (gap[:, 3] / self.Sp) ** 2
        thr = JOIN_FRACTION * np.maximum(np.maximum(self.seglen.arr[idx], h), self.base)
        return idx[lb2 <= (thr * (1.0 + 1e-6)) ** 2]

    def parallel(self, k: int, a: np.ndarray, b: np.ndarray) -> float:
        """|cos| of the angle between segment ``k`` and the step from key ``a`` to ``b``."""
        K = self.keys.arr
        R = max(K[k, -1], K[k + 1, -1], a[-1], b[-1])
        scale = np.append(np.full(a.size - 2, R), self.Sp)
        u = (K[k + 1, :-1] - K[k, :-1]) / scale
        v = (b[:-1] - a[:-1]) / scale
        nu, nv = float(np.linalg.norm(u)), float(np.linalg.norm(v))
        return abs(float(u @ v)) / (nu * nv) if nu > 0 and nv > 0 else 1.0


class Registry:
    """Traced branches (their key polylines), to skip seeds on them and to stop where a march
    runs into one."""

    def __init__(self, Sp: float, ds_max: float) -> None:
        self.items: list[Poly] = []
        self.Sp = Sp
        self.ds_max = ds_max

    def add(self, pts: list[Pt], m: int) -> int:
        self.items.append(Poly.of(pts, self.Sp, self.ds_max, m))
        return len(self.items) - 1

    def near(self, q: Pt, m: int, h: float = 0.0) -> tuple[int, int]:
        """(branch, segment) of a traced branch of period ``m`` that ``q`` (in any of its
        ``m`` representations) lies on, else (-1, -1)."""
        keys = q.keys(m)
        for i, it in enumerate(self.items):
            if it.m != m:
                continue
            for key in keys:
                k = it.near(key, h)
                if k >= 0:
                    return i, k
        return -1, -1


def output_spacing(a: Pt, b: Pt, Sp: float) -> float:
    """Output spacing of two consecutive points: the larger of the parameter step over the
    window and the relative amplitude step."""
    da = abs(b.stats[0] - a.stats[0]) / max(1.0, a.stats[0], b.stats[0])
    return max(abs(b.p - a.p) / Sp, da)


class ShootingStepControl(StepControl):
    """Step length in scaled (Z, p) arclength: the core's :class:`~perturb.numeric.
    continuation.StepControl` with this engine's pace and an output-spacing cap.

    The corrector's work sets the pace (grow after at most two propagations, shrink after
    four); the output spacing caps it: the ratio of output spacing to step of the last step
    predicts the step that gives ``ds_max`` of spacing, and a step whose spacing exceeds
    ``1.5 ds_max`` is redone shorter.  The step itself may exceed ``ds_max`` where the state
    turns (the phase of the orbit rotates through a resonance) while (p, amplitude) move
    little, up to ``DS_CAP`` times ``ds_max``.
    """

    DS_CAP = 8.0
    #: (most Newton iterations, step factor)
    PACE = ((2, 1.6), (3, 1.15), (4, 1.0), (math.inf, 0.6))

    def __init__(self, st: Settings) -> None:
        # start a quarter of the largest step: the spacing ratio is not known yet
        super().__init__(0.25 * st.ds_max, st.ds_min, st.ds_max, self.PACE)
        self.st = st
        self.last_ok = st.ds_max
        self.iters = 0
        # quadratic-convergence constant |d1| / |d0|^2 of the corrector (largest recent)
        self.quad = 1.0e4
        self._quads: list[float] = []

    def observe(self, c: float) -> None:
        self._quads = (self._quads + [min(max(c, 1.0), 1e8)])[-8:]
        self.quad = max(max(self._quads), 10.0)

    def restart(self) -> None:
        self.step = 0.25 * self.st.ds_max

    def accept(self, ds: float, evals: int, spacing: float, force: bool = False) -> bool:
        """Pace the next step after a converged step ``ds``; False (and a shorter step) when
        its output spacing is too coarse and it must be redone."""
        st = self.st
        rho = spacing / ds if ds > 0 else 1.0
        if not force and spacing > 1.5 * st.ds_max and ds > 4 * st.ds_min:
            self.step = max(st.ds_min, 0.8 * st.ds_max / max(rho, 1e-12))
            return False
        self.last_ok = ds
        # the pace follows the Newton iterations (a forward-difference column is not one)
        it = self.iters if self.iters else evals
        self.iters = 0
        self.step = ds
        self.accepted(it, limit=min(self.DS_CAP * st.ds_max, 0.9 * st.ds_max / max(rho, 1e-12)))
        return True

    def jumps(self) -> list[float]:
        return [min(self.st.ds_max, k * self.last_ok) for k in (4.0, 16.0)]


def correct_point(
    eng: Engine,
    u_pred: np.ndarray,
    N: int,
    D: np.ndarray,
    dvec: np.ndarray,
    ds: float,
    st: Settings,
    *,
    max_iter: int | None = None,
    first_cap: float = 0.75,
    ctl: ShootingStepControl | None = None,
) -> tuple[Pt | None, int]:
    r"""Newton on :math:`G(u) = 0,\ \hat d\cdot(\hat u - \hat u_{pred}) = 0` from ``u_pred``
    (scales ``D``, unit normal ``dvec`` in scaled coordinates).

    A correction is accepted when the estimated error of the next iterate is below ``tol``
    and the correction itself below STATS_TOL (the statistics come from the propagated
    iterate).  With a step control that knows the quadratic-convergence constant
    :math:`C = \|\Delta_1\|/\|\Delta_0\|^2` of earlier corrections, a first correction with
    :math:`C\|\Delta_0\|^2 \le` tol is accepted after one propagation (an accurate
    predictor).  Returns the point (None on failure) and the propagations used.

    The Newton loop is the continuation core's :class:`~perturb.numeric.continuation.Corrector`
    in unscaled coordinates (``u += du D``, border through the scaled prediction), with one
    shooting propagation per iterate for :math:`G, G_Z, G_p` and the monodromy, the forward
    difference + Broyden column when the flow gives no :math:`G_p`, the parameter window as an
    unevaluable iterate, and the first-step cap ``first_cap ds + 10 tol``."""
    Sp = eng.Sp
    max_iter = st.max_iter if max_iter is None else max_iter
    # a system's statistics follow the tolerance (its default 1e-10 gives ND_STATS_TOL)
    stats_tol = min(ND_STATS_TOL, 10.0 * st.tol) if eng.nd else STATS_TOL

    def evaluate(u: np.ndarray) -> Evaluation | None:
        p = float(u[-1])
        if not (eng.lo - 0.5 * Sp < p < eng.hi + 0.5 * Sp) or (eng.positive and p <= 0.0):
            return None
        try:
            ev = eng.evaluate(u[:-1].reshape(N, eng.n), p)
        except PerturbError:
            return None
        return Evaluation(ev.r, ev.Gz, ev.Gp, ev)

    def fd_column(u: np.ndarray, r: np.ndarray) -> np.ndarray | None:
        try:
            return eng.gp_fd(u[:-1].reshape(N, eng.n), float(u[-1]), r)
        except PerturbError:
            return None

    def observe(k: int, n: float, prev: float) -> None:
        if ctl is not None and k == 1 and prev > 1e-12:
            ctl.observe(n / (prev * prev))

    def accept(k: int, n: float, prev: float, e: Evaluation) -> bool:
        # accept: the next iterate's error is below tol, and the statistics (from the
        # propagated iterate) within STATS_TOL of the stored orbit: the correction times the
        # growth of a perturbation over one node interval
        if k == 0:
            est = n if ctl is None else max(n * n * ctl.quad, 1e-3 * n)
        else:
            est = n * min(1.0, n / prev)
        # (systems, after one propagation: the statistics are those of the predicted orbit,
        # a tenth of the tolerance keeps their error well inside it; the quintic predictor
        # of march.Tracer makes this the common case)
        lim = 0.1 * stats_tol if (k == 0 and eng.nd) else stats_tol
        return est <= st.tol and n * e.payload.node_growth(N) <= lim

    newton = Corrector(evaluate, scaled=False, fd_column=fd_column)
    c = newton.correct(
        u_pred,
        D,
        dvec,
        max_iter=max_iter,
        accept=accept,
        observe=observe,
        anchor=u_pred / D,
        cap=first_cap * ds + 10 * st.tol,
    )
    if c is None:
        return None, newton.evaluations
    pt = Pt(float(c.x[-1]), c.x[:-1], eng.n)
    eng.finish(
        pt,
        c.evaluation.payload,
        c.x_evaluated[:-1].reshape(N, eng.n).copy(),
        float(c.x_evaluated[-1]),
    )
    pt.J = np.hstack([c.evaluation.ju, c.jl[:, None]])
    if ctl is not None:
        ctl.iters = c.iterations
    return pt, c.evaluations


def point_null_tangent(pt: Pt, Sp: float) -> tuple[np.ndarray, bool]:
    """Scaled unit null vector of [G_z | G_p] and whether the Jacobian is rank deficient."""
    assert pt.J is not None
    return null_tangent(pt.J * pt.D(Sp)[None, :])


def scaled_chord(a: Pt, b: Pt, Sp: float) -> np.ndarray | None:
    """Scaled chord from a to b in (Z, p) with b's scales, or None if N differs."""
    if a.N != b.N:
        return None
    return (b.u() - a.u()) / b.D(Sp)


def chord3(a: Pt, b: Pt, Sp: float) -> np.ndarray:
    """Scaled chord on (x0, v0, p) (on ``(y0, p)`` for n states)."""
    R = max(a.R, b.R)
    if a.Z.shape[1] != 2:
        return np.append((b.Z[0] - a.Z[0]) / R, (b.p - a.p) / Sp)
    return np.array([(b.Z[0, 0] - a.Z[0, 0]) / R, (b.Z[0, 1] - a.Z[0, 1]) / R, (b.p - a.p) / Sp])


def orient(pt: Pt, t: np.ndarray, prev: Pt | None, ref3: np.ndarray | None, Sp: float):
    """Orient a tangent of ``pt`` along the chord from ``prev`` (or along ``ref3``)."""
    if prev is not None:
        ch = scaled_chord(prev, pt, Sp)
        if ch is not None and np.linalg.norm(ch) > 0:
            return -t if float(t @ ch) < 0 else t
        ref3 = chord3(prev, pt, Sp)
    if ref3 is None:
        return t
    n = pt.Z.shape[1]
    t3 = np.array([t[0], t[1], t[-1]]) if n == 2 else np.append(t[:n], t[-1])
    return -t if float(t3 @ ref3) < 0 else t
