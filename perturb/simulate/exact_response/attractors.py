"""Seeds from attractors: the stable period-1 orbits that one cheap vectorised simulation
of the piecewise-affine vector field settles on, at frequencies across the window, from a
grid of initial states and from both sides of every unstable orbit already traced.

They reach the branches that neither a closed-form arc, a sweep nor a branch point inside
the window reaches: a stable isola, or a branch that lies in the window only near one edge
and is stable only on a short stretch (an isola straddling the edge, a branch that folds back
out of it; on ``nsd`` with ``k = -3`` at low frequency there are many, with basins of a few
per cent of the box of states, that the unstable manifolds of the traced orbits lead to).
Every state found here only starts Newton on the exact period map (:meth:`Tracer.polish`);
the orbit is accepted on the exact flow's own residual.  Nothing here comes from an
approximation.

Part of :mod:`perturb.simulate.exact_response` (the method is described there).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from perturb.errors import PerturbError
from perturb.simulate.exact_response.march import Tracer
from perturb.simulate.exact_response.problem import Engine, Pt
from perturb.simulate.orbits.shooting import ShootingError

#: Initial states of the simulation per frequency: ``EDGE_GRID**2`` at the two window edges,
#: ``INNER_GRID**2`` at the frequencies between (a grid over ``(x, x')`` of an oscillator,
#: a fixed quasi-random set over the box of a system's states).
EDGE_GRID = 5
INNER_GRID = 3
#: Largest ratio of neighbouring frequencies of the scan and most frequencies: a stable
#: isola narrower than that ratio can be missed.
FREQUENCY_RATIO = 1.02
MAX_FREQUENCIES = 128
#: Most state-steps (RK4 steps times trajectories times states) of the simulation; beyond
#: it (light damping, stiff segments) the scan is skipped (~1e7 state-steps per CPU second:
#: nsd2 over (0.5, 2) needs 8.8e6, nsd k = -3 over (0.2, 2.5) 4e6).
MAX_WORK = 20_000_000
#: Settling time of the simulation in slowest decay times (a transient decays by e^-4) and
#: its least number of forcing periods.
DECAY_TIMES = 4.0
MIN_PERIODS = 3
#: RK4 step: this fraction of the inverse of the largest rate (stiffness, frequency).
STEP_FRACTION = 0.3
#: A trajectory has settled when its states one period apart differ by at most this fraction
#: of the state's size (max(1, |y|)); two settled states are one attractor within
#: ``SAME_ATTRACTOR``; a settled state lies on a traced branch within ``ON_TRACED``.
SETTLED = 0.05
SAME_ATTRACTOR = 0.01
ON_TRACED = 0.05
#: Offset of the starts beside an unstable traced orbit (relative to max(1, |y0|)).
SADDLE_OFFSET = 0.01
#: Newton iterations on the exact period map per settled state (it starts close: a few).
POLISH_ITERATIONS = 10
#: Factors on the states of the traced orbits at a window edge that start Newton there
#: (:func:`edge_starts`): a branch that enters and leaves the window through one edge and is
#: unstable at it (nsd2 over (1.2, 1.3): a fold at 1.2147, stable only on 1.2033-1.2147) has
#: no attractor at the edge and may have no traced saddle beside it; its orbits at the edge
#: are, in state, near a multiple of a traced orbit's (there 1.5 times the stable one's).
EDGE_SCALES = (0.5, 0.75, 1.25, 1.5, 2.0)


# =============================================================================================
# the vectorised vector field
# =============================================================================================
#: ``(drive, rhs)`` of a set of trajectories: ``drive(t)`` the time-dependent input of every
#: column at its own time ``t``, ``rhs(y, d)`` the vector field at states ``y`` with that input
#: (split so that RK4 evaluates the input once per distinct time).
Rhs = tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray, np.ndarray], np.ndarray]]


class _Field:
    """``y' = f(t, y)`` of many trajectories at once (states ``(n, C)``, one column per
    trajectory), each column at its own parameter value; built from the exact flows'
    piecewise data.  ``None`` from :func:`_field` where the flows have none."""

    def __init__(
        self, make: Callable[[np.ndarray], Rhs], rate: float, decay: float, scale: float
    ) -> None:
        self.make = make  # columns (indices of parameter values) -> Rhs of those trajectories
        self.rate = rate  # largest rate of the linear parts (step size)
        self.decay = decay  # slowest decay rate of the damped linear parts (settling time)
        self.scale = scale  # half-width of the box of initial states


def _oscillator_field(eng: Engine, ps: np.ndarray) -> _Field | None:
    systems = [eng.system(float(p)) for p in ps]
    s0 = systems[0]
    bp = np.asarray(s0.breakpoints, dtype=float)
    J = len(s0.forcing)
    if any(
        not np.array_equal(s.breakpoints, bp) or len(s.forcing) != J for s in systems
    ):  # the parameter moves a breakpoint: no common field
        return None
    S = np.array([s.slopes for s in systems], dtype=float)
    O = np.array([s.offsets for s in systems], dtype=float)
    mu = np.array([s.damping for s in systems], dtype=float)
    c = np.array([s.static_force for s in systems], dtype=float)
    if J:
        forcing = np.array([s.forcing for s in systems], dtype=float)  # (P, J, 3)
    else:
        forcing = np.zeros((len(systems), 1, 3))
    if not (np.all(np.isfinite(S)) and np.all(np.isfinite(O)) and np.all(mu > 0.0)):
        return None
    # the slowest decay and the fastest rate of the segments' linear parts
    decay, rate = math.inf, 0.0
    for s_row, m in zip(S, mu, strict=True):
        for s in s_row:
            lam = np.roots([1.0, m, s]).astype(complex)
            rate = max(rate, float(np.max(np.abs(lam))))
            neg = -lam.real[lam.real < 0.0]
            if neg.size:
                decay = min(decay, float(neg.min()))
    return _Field(
        lambda cols: _oscillator_rhs(bp, S[cols], O[cols], mu[cols], c[cols], forcing[cols]),
        rate,
        decay,
        max(3.0, 3.0 * float(np.abs(bp).max())) if bp.size else 3.0,
    )


def _oscillator_rhs(
    bp: np.ndarray,
    S: np.ndarray,
    O: np.ndarray,
    mu: np.ndarray,
    c: np.ndarray,
    forcing: np.ndarray,
) -> Rhs:
    """``x'' = c + sum_j F_j cos(w_j t + phi_j) - mu x' - (S_i x + O_i)`` in segment ``i``."""
    cols = np.arange(S.shape[0])
    amps, omegas, phases = forcing[:, :, 0], forcing[:, :, 1], forcing[:, :, 2]

    def drive(t: np.ndarray) -> np.ndarray:
        return c + np.sum(amps * np.cos(omegas * t[:, None] + phases), axis=1)

    def rhs(y: np.ndarray, d: np.ndarray) -> np.ndarray:
        x, v = y
        seg = np.searchsorted(bp, x, side="right")  # right-continuous, as segment_of
        return np.stack((v, d - mu * v - (S[cols, seg] * x + O[cols, seg])))

    return drive, rhs


def _system_field(eng: Engine, ps: np.ndarray) -> _Field | None:
    pas_all = []
    for p in ps:
        pas = getattr(eng.flow(float(p)), "affine_system", None)
        if pas is None:
            return None
        pas_all.append(pas)
    pas0 = pas_all[0]
    keys = sorted(pas0.regions)
    normals = np.array([s.normal for s in pas0.surfaces], dtype=float).reshape(-1, eng.n)
    offsets = np.array([s.offset for s in pas0.surfaces], dtype=float)
    J = len(pas0.inputs)
    for pas in pas_all[1:]:
        same = (
            sorted(pas.regions) == keys
            and len(pas.inputs) == J
            and all(
                np.array_equal(pas.regions[k].A, pas0.regions[k].A)
                and np.array_equal(pas.regions[k].b, pas0.regions[k].b)
                for k in keys
            )
            and all(
                np.array_equal(a.normal, b.normal) and a.offset == b.offset
                for a, b in zip(pas.surfaces, pas0.surfaces, strict=True)
            )
        )
        if not same:  # the parameter changes more than the inputs: no common field
            return None
    n = eng.n
    A = np.array([pas0.regions[k].A for k in keys], dtype=float)
    b = np.array([pas0.regions[k].b for k in keys], dtype=float)
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
        return None
    # region of every sign pattern (bit j set: s_j >= 0); patterns naming no region give NaN
    n_s = offsets.size
    lookup = np.full(2**n_s, len(keys), dtype=int)
    for i, k in enumerate(keys):
        lookup[sum(1 << j for j, s in enumerate(k) if s > 0)] = i
    A = np.concatenate((A, np.full((1, n, n), np.nan)))
    b = np.concatenate((b, np.full((1, n), np.nan)))
    U = np.array([[h.u for h in pas.inputs] for pas in pas_all], dtype=float).reshape(-1, J, n)
    V = np.array([[h.v for h in pas.inputs] for pas in pas_all], dtype=float).reshape(-1, J, n)
    W = np.array([[h.omega for h in pas.inputs] for pas in pas_all], dtype=float).reshape(-1, J)
    decay, rate = math.inf, 0.0
    for Ak in A[:-1]:
        lam = np.linalg.eigvals(Ak)
        rate = max(rate, float(np.max(np.abs(lam))))
        neg = -lam.real[lam.real < 0.0]
        if neg.size:
            decay = min(decay, float(neg.min()))
    scale = 3.0
    norms = np.linalg.norm(normals, axis=1) if n_s else np.zeros(0)
    where = np.abs(offsets) / np.where(norms > 0, norms, 1.0) if n_s else np.zeros(0)
    if where.size:
        scale = max(scale, 3.0 * float(where.max()))
    # (the pattern code as a float product: exact for the few surfaces of a PWL system)
    bits = (2.0 ** np.arange(n_s))[None, :]
    off = offsets[:, None]
    A_stack = A.reshape(-1, n)
    b_stack = b[:, :, None]

    def make(cols: np.ndarray) -> Rhs:
        u, v, w = U[cols], V[cols], W[cols]
        every_col = np.arange(cols.size)
        # one input (the common case): its vectors as (n, C) columns, no einsum
        u1, v1, w1 = (u[:, 0, :].T.copy(), v[:, 0, :].T.copy(), w[:, 0]) if J == 1 else (0, 0, 0)

        def drive(t: np.ndarray) -> np.ndarray:
            if not J:
                return np.zeros((n, t.size))
            if J == 1:
                ph1 = w1 * t
                return u1 * np.cos(ph1) + v1 * np.sin(ph1)
            ph = w * t[:, None]
            return np.einsum("cj,cjn->nc", np.cos(ph), u) + np.einsum("cj,cjn->nc", np.sin(ph), v)

        def rhs(y: np.ndarray, d: np.ndarray) -> np.ndarray:
            if n_s:
                code = (bits @ (normals @ y >= off))[0]
                r = lookup[code.astype(np.intp)]
            else:
                r = np.zeros(y.shape[1], dtype=np.intp)
            # every region's field at every state (one matrix product: regions are few),
            # then each state's own region (one fancy index)
            every = (A_stack @ y).reshape(len(keys) + 1, n, -1) + b_stack
            return every[r, :, every_col].T + d

        return drive, rhs

    return _Field(make, rate, decay, scale)


def _field(eng: Engine, ps: np.ndarray) -> _Field | None:
    """The vectorised field at the parameter values ``ps`` (None: no exact PWL flow, no
    damping, or a parameter that changes the pieces)."""
    if not eng.exact or eng.m != 1:
        return None
    try:
        f = _system_field(eng, ps) if eng.nd else _oscillator_field(eng, ps)
    except (PerturbError, ValueError, np.linalg.LinAlgError):
        return None
    if f is None or not (math.isfinite(f.decay) and f.decay > 0.0 and f.rate > 0.0):
        return None
    return f


# =============================================================================================
# the simulation
# =============================================================================================
def _initial_states(n: int, count: int, scale: float, rng: np.random.Generator) -> np.ndarray:
    """``count**2`` initial states in ``[-scale, scale]^n`` (a grid for two states)."""
    if n == 2:
        g = np.linspace(-scale, scale, count)
        return np.stack((np.repeat(g, count), np.tile(g, count)))
    return rng.uniform(-scale, scale, size=(n, count * count))


def scan_frequencies(eng: Engine) -> np.ndarray:
    """The parameter values of the attractor scan: ``FREQUENCY_RATIO`` apart across the
    window, both edges included (at most ``MAX_FREQUENCIES``; evenly spaced when the window
    reaches zero or below)."""
    lo, hi = eng.lo, eng.hi
    if lo > 0:
        count = math.ceil(math.log(hi / lo) / math.log(FREQUENCY_RATIO)) + 1
        return np.geomspace(lo, hi, min(MAX_FREQUENCIES, max(2, count)))
    return np.linspace(lo, hi, MAX_FREQUENCIES)


def saddle_starts(
    ps: np.ndarray, internals: Sequence[Sequence[Pt]], traced: Sequence[int]
) -> list[tuple[int, np.ndarray]]:
    """``(index into ps, y)``: beside every unstable orbit of the branches ``traced`` that
    crosses ``ps[i]`` (its first node interpolated between neighbouring points), the states
    ``y0 +- SADDLE_OFFSET max(1, |y0|)`` in the first state: the two sides of its unstable
    manifold in a generic direction, which lead to the attractors connected to it (a stable
    stretch of a branch near its fold, whose basin a grid of states rarely meets)."""
    out: list[tuple[int, np.ndarray]] = []
    for b in traced:
        pts = internals[b]
        if len(pts) < 2:
            continue
        pp = np.array([q.p for q in pts])
        unstable = np.array([q.max_mult >= 1.0 for q in pts])
        for j in range(len(pts) - 1):
            if not (unstable[j] or unstable[j + 1]) or pp[j] == pp[j + 1]:
                continue
            a, c = sorted((pp[j], pp[j + 1]))
            for i in np.flatnonzero((ps >= a) & (ps <= c)):
                s = (ps[i] - pp[j]) / (pp[j + 1] - pp[j])
                y = (1.0 - s) * pts[j].y0 + s * pts[j + 1].y0
                d = SADDLE_OFFSET * max(1.0, float(np.max(np.abs(y))))
                for sgn in (1.0, -1.0):
                    z = y.copy()
                    z[0] += sgn * d
                    out.append((int(i), z))
    return out


def edge_starts(
    edges: Sequence[float], internals: Sequence[Sequence[Pt]], traced: Sequence[int]
) -> list[tuple[float, np.ndarray]]:
    """``(p, y)``: at every parameter value of ``edges`` (the window's two), the first node of
    every crossing of ``p`` by the branches ``traced`` (interpolated linearly between
    neighbouring points; a point exactly at ``p`` taken as it is) times every factor of
    ``EDGE_SCALES``.  Starts of Newton at the edge for the orbits of branches that enter and
    leave the window through that edge (every period-1 orbit at an edge frequency seeds the
    trace); most converge to a traced orbit and are dropped there."""
    out: list[tuple[float, np.ndarray]] = []
    for p in edges:
        for b in traced:
            pts = internals[b]
            if not pts:
                continue
            if len(pts) == 1:
                ys = [pts[0].y0] if pts[0].p == p else []
            else:
                ys = []
                for j in range(len(pts) - 1):
                    a, c = pts[j], pts[j + 1]
                    if not min(a.p, c.p) <= p <= max(a.p, c.p):
                        continue
                    s = 0.0 if c.p == a.p else (p - a.p) / (c.p - a.p)
                    ys.append((1.0 - s) * a.y0 + s * c.y0)
            for y in ys:
                for f in EDGE_SCALES:
                    out.append((float(p), f * np.asarray(y, dtype=float)))
    return out


def attractor_states(
    eng: Engine,
    extra: Sequence[tuple[int, np.ndarray]] = (),
    *,
    max_work: int = MAX_WORK,
) -> list[tuple[float, np.ndarray]]:
    """``(p, y0)``: states at ``t0`` (mod the forcing period) of the period-1 attractors
    that one fixed-step RK4 simulation settles on, from a grid of initial states at the
    frequencies of :func:`scan_frequencies` (``EDGE_GRID**2`` states at the two edges,
    ``INNER_GRID**2`` between) and from ``extra`` states ``(index of the frequency, y)``.

    Every trajectory steps its own forcing period in a whole number of steps (so the state
    after each period is at the section ``t0``), for ``DECAY_TIMES`` of the slowest decay
    and at least ``MIN_PERIODS`` periods; a trajectory has settled when its states one period
    apart agree within ``SETTLED``; one state per attractor and frequency.  Only a start for
    Newton on the exact period map, so the step is coarse.  Nothing (an empty list) for a flow
    without piecewise-affine data, an undamped one, a parameter that changes the pieces, or
    work beyond ``max_work`` state-steps.
    """
    ps = scan_frequencies(eng)
    field = _field(eng, ps)
    if field is None:
        return []
    periods = np.array([eng.period(float(p)) for p in ps])
    if not np.all(np.isfinite(periods) & (periods > 0.0)):
        return []
    rng = np.random.default_rng(20261127)  # a fixed set: the same seeds every call
    grids = [INNER_GRID] * ps.size
    grids[0] = grids[-1] = EDGE_GRID
    starts = [_initial_states(eng.n, g, field.scale, rng) for g in grids]
    cols = np.repeat(np.arange(ps.size), [s.shape[1] for s in starts])
    y = np.concatenate(starts, axis=1)
    if len(extra):
        cols = np.concatenate((cols, np.array([i for i, _ in extra], dtype=int)))
        y = np.concatenate((y, np.array([z for _, z in extra], dtype=float).T), axis=1)
    h_max = STEP_FRACTION / max(field.rate, 2.0 * math.pi / float(periods.min()))
    K = np.maximum(8, np.ceil(periods / h_max)).astype(int)  # steps per period
    t_settle = DECAY_TIMES / field.decay
    steps_needed = np.maximum(MIN_PERIODS, np.ceil(t_settle / periods)).astype(int) * K
    steps = int(steps_needed.max())
    if steps * y.size > max_work:
        return []
    h = (periods / K)[cols]
    Kc = K[cols]
    drive, rhs = field.make(cols)
    t = np.full(cols.size, eng.t0)
    prev = np.full_like(y, np.nan)
    last = np.full_like(y, np.nan)
    with np.errstate(all="ignore"):
        d0 = drive(t)
        for i in range(1, steps + 1):
            dm = drive(t + 0.5 * h)
            t = eng.t0 + i * h  # no accumulated rounding: the section stays at t0 mod P
            d1 = drive(t)
            k1 = rhs(y, d0)
            k2 = rhs(y + (0.5 * h) * k1, dm)
            k3 = rhs(y + (0.5 * h) * k2, dm)
            k4 = rhs(y + h * k3, d1)
            y = y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            d0 = d1
            at = i % Kc == 0
            if at.any():
                prev[:, at] = last[:, at]
                last[:, at] = y[:, at]
    size = np.maximum(1.0, np.max(np.abs(last), axis=0))
    settled = np.all(np.isfinite(last), axis=0) & np.all(np.isfinite(prev), axis=0)
    with np.errstate(invalid="ignore"):
        settled &= np.max(np.abs(last - prev), axis=0) <= SETTLED * size
    out: list[tuple[float, np.ndarray]] = []
    kept: dict[int, list[np.ndarray]] = {}
    for j in np.flatnonzero(settled):
        c = int(cols[j])
        yj = last[:, j]
        same = kept.setdefault(c, [])
        if any(np.max(np.abs(yj - q)) <= SAME_ATTRACTOR * size[j] for q in same):
            continue
        same.append(yj)
        out.append((float(ps[c]), yj.copy()))
    return out


# =============================================================================================
# proximity to traced branches and the stage itself
# =============================================================================================
def on_traced(internals: Sequence[Sequence[Pt]], p: float, y: np.ndarray, tol: float) -> bool:
    """Whether state ``y`` at ``p`` lies within ``tol`` (relative to ``max(1, |y|)``) of the
    first node of a traced branch, interpolated linearly in ``p`` between consecutive points
    (every crossing of ``p`` by a branch that folds).  A cheap test before Newton; the exact
    orbit is tested again by the registry's signatures."""
    size = max(1.0, float(np.max(np.abs(y))))
    for pts in internals:
        if not pts or pts[0].Z.shape[1] != y.size:
            continue
        ps = np.array([q.p for q in pts])
        lo = np.minimum(ps[:-1], ps[1:])
        hi = np.maximum(ps[:-1], ps[1:])
        for j in np.flatnonzero((lo <= p) & (p <= hi)):
            a, b = pts[j], pts[j + 1]
            s = 0.0 if b.p == a.p else (p - a.p) / (b.p - a.p)
            yi = (1.0 - s) * a.y0 + s * b.y0
            if float(np.max(np.abs(yi - y))) <= tol * size:
                return True
    return False


def attractor_stage(
    tracer: Tracer,
    internals: Sequence[Sequence[Pt]],
    traced: Sequence[int],
    try_seed: Callable[[Pt], bool],
    budget_left: Callable[[], bool],
) -> tuple[int, int]:
    """Trace the branches of the attractors of :func:`attractor_states`, started from the grid
    and from :func:`saddle_starts` beside the unstable orbits of the branches ``traced`` (their
    indices into ``internals``; mirror images left out: their attractors are the images),
    then of the orbits at the window edges that Newton reaches from :func:`edge_starts` (of
    those branches and the ones added here), that lie on no traced branch (checked against
    ``internals`` before Newton, then by ``try_seed`` on the exact orbit, which traces the
    branch).  Returns (states polished, branches added)."""
    eng = tracer.eng
    polished = added = 0

    def start(p: float, y: np.ndarray) -> None:
        nonlocal polished, added
        if not budget_left() or on_traced(internals, p, y, ON_TRACED):
            return
        polished += 1
        try:
            pt = tracer.polish(p, y, max_iter=POLISH_ITERATIONS)
        except (ShootingError, PerturbError):
            return
        if try_seed(pt):
            added += 1

    extra = saddle_starts(scan_frequencies(eng), internals, traced)
    n_before = len(internals)
    for p, y in attractor_states(eng, extra):
        start(p, y)
    # last, so the branches of the attractors are traced as without them; from the branches
    # traced before and those this stage added (with their mirror images: a few more starts).
    # Exact flows only (where Newton is cheap), as the scan
    if eng.exact and eng.m == 1:
        found = [*traced, *range(n_before, len(internals))]
        for p, y in edge_starts((eng.lo, eng.hi), internals, found):
            start(p, y)
    return polished, added
