"""Closed-form arcs of the exact frequency response: the steady state of one linear
segment of a PWL force (orbit, statistics, margin to the breakpoints), the closed-form
stepping along it (``Closed``) and the distance of an orbit to a segment.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from perturb.model.segments import SegmentSteadyState, segment_steady_states
from perturb.simulate.exact_response.base import SIG_PHASES, STAT_SAMPLES
from perturb.simulate.exact_response.problem import Engine, Pt


# =============================================================================================
# closed-form orbits inside one linear segment
# =============================================================================================
def _segment_state(sys_: Any, seg: int) -> SegmentSteadyState | None:
    """The closed-form steady state of linear segment ``seg`` (:mod:`perturb.model.segments`,
    the one place the formula is written), or None."""
    return segment_steady_states(
        sys_.breakpoints,
        sys_.slopes,
        sys_.offsets,
        sys_.damping,
        sys_.forcing,
        sys_.static_force,
    )[seg]


def _segment_orbit(sys_: Any, seg: int, P: float, t: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """(x, v) of the steady state of linear segment ``seg`` at times ``t``, or None."""
    state = _segment_state(sys_, seg)
    return None if state is None else state.states(t)


def _segment_info(sys_: Any, seg: int, P: float) -> tuple[float, float, float, float] | None:
    """(margin, xmin, xmax, xc) of segment ``seg``'s steady state; margin > 0 when it stays
    inside the segment."""
    state = _segment_state(sys_, seg)
    if state is None:
        return None
    if len(state.forcing) == 1:
        xmin, xmax = state.xmin, state.xmax  # exact for one load
    else:
        # several loads: the extremes of the sampled orbit (the segment's half_range is only
        # a bound there)
        x, _ = state.states(np.linspace(0.0, P, 513))
        xmin, xmax = float(x.min()), float(x.max())
    return min(state.upper - xmax, xmin - state.lower), xmin, xmax, state.centre


class Closed:
    """Closed-form points for one engine (m = 1, exact PWL flows)."""

    def __init__(self, eng: Engine) -> None:
        self.eng = eng

    def margin(self, p: float, seg: int) -> float:
        info = _segment_info(self.eng.system(p), seg, self.eng.period(p))
        return -math.inf if info is None else info[0]

    def y0(self, p: float, seg: int) -> np.ndarray:
        eng = self.eng
        out = _segment_orbit(eng.system(p), seg, eng.period(p), np.array([eng.t0]))
        assert out is not None
        return np.array([out[0][0], out[1][0]])

    def amplitude(self, p: float, seg: int) -> float:
        info = _segment_info(self.eng.system(p), seg, self.eng.period(p))
        return 0.0 if info is None else max(abs(info[1]), abs(info[2]))

    def damplitude(self, p: float, seg: int) -> float:
        h = 1e-6 * max(self.eng.Sp, 1e-3)
        return (self.amplitude(p + h, seg) - self.amplitude(p - h, seg)) / (2 * h)

    def dydp(self, p: float, seg: int) -> np.ndarray:
        h = 1e-6 * max(self.eng.Sp, 1e-3)
        return (self.y0(p + h, seg) - self.y0(p - h, seg)) / (2 * h)

    def point(self, p: float, seg: int, N: int = 1) -> Pt:
        """The exact orbit of segment ``seg`` at ``p`` (nodes at ``t0 + iT/N``)."""
        eng = self.eng
        sys_ = eng.system(p)
        P = eng.period(p)
        tn = eng.t0 + P * np.arange(N) / N
        out = _segment_orbit(sys_, seg, P, tn)
        info = _segment_info(sys_, seg, P)
        assert out is not None and info is not None
        pt = Pt(p, np.column_stack(out))
        s, mu = float(sys_.slopes[seg]), float(sys_.damping)
        lam = np.roots([1.0, mu, s]).astype(complex) * P
        mult = np.exp(np.minimum(lam.real, 700.0)) * np.exp(1j * lam.imag)
        pt.mult = mult[np.argsort(-np.abs(mult), kind="stable")]
        tt = eng.t0 + P * np.arange(STAT_SAMPLES) / STAT_SAMPLES
        xs, vs = _segment_orbit(sys_, seg, P, tt)
        c = np.fft.rfft(xs) / STAT_SAMPLES
        _, xmin, xmax, xc = info
        pt.stats = (max(abs(xmin), abs(xmax)), float(2.0 * abs(c[1])), float(xc))
        q = STAT_SAMPLES // SIG_PHASES
        pt.sig = np.column_stack([xs[::q], vs[::q]]).ravel()
        pt.switches = 0
        pt.mode = "closed"
        pt.seg = seg
        pt.source = "closed form"
        return pt

    def set_tangent(self, pt: Pt, direction: float) -> None:
        """Tangent of a closed-form arc (a graph over p), oriented by ``direction``."""
        d = self.dydp(pt.p, pt.seg)
        D = pt.D(self.eng.Sp)
        t = np.r_[d / D[0], np.zeros(2 * pt.N - 2), 1.0 / D[-1]]
        pt.tangent = direction * t / np.linalg.norm(t)
        pt.singular = False

    def match(self, pt: Pt) -> int:
        """Segment whose closed-form orbit ``pt`` is (strictly inside it), else -1."""
        if pt.switches != 0 or pt.N != 1:
            return -1
        seg = int(self.eng.system(pt.p).segment_of(float(pt.y0[0])))
        if self.margin(pt.p, seg) <= 1e-9 * pt.R:
            return -1
        if np.max(np.abs(self.y0(pt.p, seg) - pt.y0)) > 1e-6 * pt.R:
            return -1
        return seg

    def seeds(self, n: int = 64) -> list[Pt]:
        """One closed-form point per run of the window where a segment's orbit stays inside."""
        eng = self.eng
        grid = np.linspace(eng.lo, eng.hi, n)
        out = []
        for seg in range(eng.system0.n_segments):
            inside = np.array([self.margin(p, seg) > 0 for p in grid])
            idx = np.flatnonzero(inside)
            if idx.size == 0:
                continue
            for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
                out.append(self.point(float(grid[run[len(run) // 2]]), seg))
        return out


# =============================================================================================
# proximity to traced branches (orbit signatures)
# =============================================================================================
def segment_distance(
    q: np.ndarray, A: np.ndarray, B: np.ndarray, Sp: float
) -> tuple[np.ndarray, np.ndarray]:
    """Distances of key ``q`` to the segments [A_k, B_k] and their lengths, with states
    scaled per segment by the largest ``R`` of the point and the ends, the parameter by
    ``Sp``."""
    R = np.maximum(np.maximum(A[:, -1], B[:, -1]), q[-1])
    inv = (1.0 / R)[:, None]
    a = A[:, :-2] * inv
    ab = B[:, :-2] * inv - a
    qa = q[None, :-2] * inv - a
    abp = (B[:, -2] - A[:, -2]) / Sp
    qap = (q[-2] - A[:, -2]) / Sp
    L2 = np.einsum("ij,ij->i", ab, ab) + abp * abp
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(L2 > 0, (np.einsum("ij,ij->i", qa, ab) + qap * abp) / L2, 0.0)
    s = np.clip(s, 0.0, 1.0)
    e = qa - s[:, None] * ab
    ep = qap - s * abp
    return np.sqrt(np.einsum("ij,ij->i", e, e) + ep * ep), np.sqrt(L2)
