"""Seeds from attractors: the stable period-1 orbits that one cheap vectorised simulation
of the piecewise-affine vector field settles on, at frequencies across the window, from a
grid of initial states and from both sides of every unstable orbit already traced.

They reach the branches that neither a closed-form arc, a sweep nor a branch point inside
the window reaches: a stable isola, or a branch that lies in the window only near one edge
and is stable only on a short stretch (an isola straddling the edge, a branch that folds back
out of it; on ``nsd`` with ``k = -3`` at low frequency there are many, with basins of a few
per cent of the box of states, that the unstable manifolds of the traced orbits lead to).
Last, Newton at the window edges from states near the traced orbits there (multiples of
them; beside a symmetric unstable one, each state moved in turn): the branches that enter and
leave the window through one edge and are unstable there.
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
from perturb.simulate.exact_response.symmetry import mirror_point
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
#: it (light damping, stiff segments) the scan is skipped: nsd2 over (0.5, 2) needs 1.2e7
#: (0.13 s: ~1e8 state-steps per CPU second since the stage products of :class:`_Stepper`,
#: ~2e7 before), nsd k = -3 over (0.2, 2.5) 4e6; the impact pair over (0.6, 1.4) 2.5e7 is
#: skipped (its 9 branches come from the other seeds; with the scan, 15 in 41 s).
MAX_WORK = 20_000_000
#: Settling time of the simulation in slowest decay times (a transient decays by e^-4) and
#: its least number of forcing periods.
DECAY_TIMES = 4.0
MIN_PERIODS = 3
#: RK4 step: this fraction of the inverse of the largest rate (the largest eigenvalue modulus
#: of the regions' matrices, or the highest forcing frequency).  Not a stability limit (RK4
#: is stable to |h lambda| ~ 2.8 on the imaginary axis): which attractors the trajectories
#: reach depends on the step.  On nsd with k = -3 over (0.2, 2.5) (23 branches, 5 from this
#: stage) steps of 0.25, 0.28, 0.32, 0.36, 0.45 and 0.6 each lose 2 to 4 of its short stable
#: stretches near Omega = 0.2-0.32 (nsd2 kept its branches at 0.45 and 0.6): kept at 0.3.
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
#: Offsets (relative to ``max(1, |y0|)``) of the starts beside a symmetric unstable orbit at a
#: window edge of an odd system (:func:`symmetric_edge_starts`), each state in turn, both
#: signs.  On ``impact_pair`` over (0.6, 1.4) the 40 starts reach each of the four isolas that
#: cross Omega = 0.6 from two or three of them (the same starts with and without the compiled
#: kernels); (0.2, 0.4) reached each from one.
EDGE_OFFSETS = (0.1, 0.15, 0.2, 0.3, 0.5)


# =============================================================================================
# the vectorised vector field
# =============================================================================================
class _Field:
    """``y' = A_r y + b_r + sum_j (u_j cos(w_j t + phi_j) + v_j sin(w_j t + phi_j))`` of many
    trajectories at once, built from the exact flows' piecewise data at the parameter values
    ``ps`` (index ``i`` below), the region ``r`` fixed by the signs of the switching functions
    ``normals . y - offsets``; ``None`` from :func:`_field` where the flows have none.

    The regions' ``[A_r | b_r]`` are shared by every parameter value (``AB``, ``(R, n, n + 1)``)
    except for an oscillator whose parameter moves its force or damping (``own``: per value
    ``(slopes, offsets - static force, damping)``); the inputs may differ per value.  The
    region of an oscillator is its segment of ``x``, the number of breakpoints at or below it
    (``lookup`` None; right-continuous as ``segment_of``); of a system, ``lookup[code]`` of the
    sign code (bit ``j`` set for ``s_j >= 0``), ``R`` for a pattern that names no region (its
    field NaN)."""

    def __init__(
        self,
        n: int,
        rate: float,
        decay: float,
        scale: float,
        inputs: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        surfaces: tuple[np.ndarray, np.ndarray],
        *,
        AB: np.ndarray | None = None,
        lookup: np.ndarray | None = None,
        own: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.n = n
        self.rate = rate  # largest eigenvalue modulus of the regions' A_r (step size)
        self.decay = decay  # slowest decay rate of the damped linear parts (settling time)
        self.scale = scale  # half-width of the box of initial states
        self.omega, self.phase, self.U, self.V = inputs  # (P, J), (P, J), (P, J, n), (P, J, n)
        self.normals, self.offsets = surfaces  # (n_s, n), (n_s,)
        self.breakpoints = self.offsets if lookup is None else None
        self.AB = AB
        self.lookup = lookup
        self.own = own


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
    forcing = np.array([s.forcing for s in systems], dtype=float).reshape(len(systems), J, 3)
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
    U = np.zeros((len(systems), J, 2))
    U[:, :, 1] = forcing[:, :, 0]  # F_j cos(w_j t + phi_j) in the acceleration
    inputs = (forcing[:, :, 1], forcing[:, :, 2], U, np.zeros_like(U))
    scale = max(3.0, 3.0 * float(np.abs(bp).max())) if bp.size else 3.0
    surfaces = (np.eye(1, 2).repeat(bp.size, axis=0), bp)  # x - d_j
    if np.all(S == S[0]) and np.all(O == O[0]) and np.all(mu == mu[0]) and np.all(c == c[0]):
        # x' = v, v' = c - O_i - S_i x - mu v (+ the inputs) in segment i
        AB = np.zeros((S.shape[1], 2, 3))
        AB[:, 0, 1] = 1.0
        AB[:, 1, 0] = -S[0]
        AB[:, 1, 1] = -mu[0]
        AB[:, 1, 2] = c[0] - O[0]
        return _Field(2, rate, decay, scale, inputs, surfaces, AB=AB)
    return _Field(2, rate, decay, scale, inputs, surfaces, own=(S, O - c[:, None], mu))


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
    A = np.array([pas0.regions[k].A for k in keys], dtype=float).reshape(-1, n, n)
    b = np.array([pas0.regions[k].b for k in keys], dtype=float).reshape(-1, n)
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
        return None
    # region of every sign pattern (bit j set: s_j >= 0); patterns naming no region: len(keys)
    n_s = offsets.size
    lookup = np.full(2**n_s, len(keys), dtype=np.intp)
    for i, k in enumerate(keys):
        lookup[sum(1 << j for j, s in enumerate(k) if s > 0)] = i
    U = np.array([[h.u for h in pas.inputs] for pas in pas_all], dtype=float).reshape(-1, J, n)
    V = np.array([[h.v for h in pas.inputs] for pas in pas_all], dtype=float).reshape(-1, J, n)
    W = np.array([[h.omega for h in pas.inputs] for pas in pas_all], dtype=float).reshape(-1, J)
    decay, rate = math.inf, 0.0
    for Ak in A:
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
    AB = np.concatenate((A, b[:, :, None]), axis=2)
    return _Field(
        n,
        rate,
        decay,
        scale,
        (W, np.zeros_like(W), U, V),
        (normals, offsets),
        AB=AB,
        lookup=lookup,
    )


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


#: Most sign patterns of a system's surfaces given a block of rows each in the stage product
#: of a field that is not a sum of ramps (the block of a pattern then starts at a linear
#: function of its sign bits); beyond it the pattern's region is looked up.
MAX_PATTERN_BLOCKS = 32


def _feasible(pattern: int, normals: np.ndarray, offsets: np.ndarray) -> bool:
    """Whether no two parallel surfaces rule out the sign pattern (``False``: no state has
    it; ``True``: it may occur, as far as this pairwise test tells)."""
    n_s = offsets.size
    for i in range(n_s):
        for j in range(i + 1, n_s):
            a, b = normals[i], normals[j]
            k = int(np.argmax(np.abs(a)))
            if a[k] == 0.0:
                continue
            lam = b[k] / a[k]
            if not np.allclose(b, lam * a, rtol=1e-14, atol=0.0):
                continue
            # in t = a . y: s_i >= 0 is t >= off_i; s_j >= 0 is lam t >= off_j
            lo, hi = -math.inf, math.inf
            for bit, scale, off in (
                (pattern >> i & 1, 1.0, offsets[i]),
                (pattern >> j & 1, lam, offsets[j]),
            ):
                edge = off / scale
                if (scale > 0) == bool(bit):  # t >= edge (or t > edge when bit is 0)
                    lo = max(lo, edge)
                else:
                    hi = min(hi, edge)
            if lo > hi:  # (equal: the one point may be allowed)
                return False
    return True


def _ramps(field: _Field) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(A, b, W)`` with ``A_r y + b_r = A y + b + sum_j W[:, j] max(s_j(y), 0)`` in every
    region (a continuous field whose surfaces act independently: the PWL springs of ``nsd``,
    ``nsd2`` and the impact pair), None when the regions are not of that form or a sign
    pattern that names no region may occur (:func:`_feasible`)."""
    AB, normals, offsets = field.AB, field.normals, field.offsets
    if AB is None:
        return None
    n, n_s = field.n, offsets.size
    if field.lookup is None:  # an oscillator: segment i has the bits of the i lowest points
        region = {(1 << i) - 1: i for i in range(n_s + 1)}
    else:
        region = {p: int(r) for p, r in enumerate(field.lookup) if r < AB.shape[0]}
    for p in range(2**n_s):
        if p not in region and _feasible(p, normals, offsets):
            return None
    W = np.zeros((n, n_s))
    for j in range(n_s):
        pair = next((p for p in region if not p >> j & 1 and p | 1 << j in region), None)
        if pair is None:
            return None
        dA = AB[region[pair | 1 << j], :, :n] - AB[region[pair], :, :n]
        nj = normals[j]
        W[:, j] = dA @ nj / float(nj @ nj)
    p0 = next(iter(region))
    bits0 = np.array([p0 >> j & 1 for j in range(n_s)], dtype=float)
    A = AB[region[p0], :, :n] - (W * bits0) @ normals
    b = AB[region[p0], :, n] + (W * bits0) @ offsets
    size = 1.0 + float(np.abs(AB).max())
    for p, r in region.items():
        bits = np.array([p >> j & 1 for j in range(n_s)], dtype=float)
        ok_A = np.abs(A + (W * bits) @ normals - AB[r, :, :n]).max() <= 1e-13 * size
        ok_b = np.abs(b - (W * bits) @ offsets - AB[r, :, n]).max() <= 1e-13 * size
        if not (ok_A and ok_b):
            return None
    return A, b, W


class _Stepper:
    """The field of :class:`_Field` on columns ``cols`` (indices of its parameter values) in
    the form one RK4 stage evaluates with a few numpy calls.  The states are the first ``n``
    rows of an augmented array ``(width, C)``; the rows below hold the inputs at the stage's
    time, a row of ones and workspace, so that one matrix product gives the field:

    * a field that is a sum of ramps (:func:`_ramps`): ``[A | input vectors | b | W]`` times
      ``[y; inputs; 1; r]``, ``r_j = max(c . y, e_j)`` (``n_j = lam_j c``, ``e_j = offset_j /
      lam_j``; the ramp ``max(s_j, 0)`` is affine in ``r_j`` and ``y``), the rows ``r`` of
      the surfaces of one direction ``c`` by one maximum (and one product when ``c`` is not
      a single state);
    * any other: one product gives every region's field (only the rows that differ between
      regions, in one block per region or sign pattern, NaN rows for a pattern that names no
      region) and the switching functions, and each column takes its block's rows by one
      flat ``take`` (a stage buffer of :meth:`buffer`);
    * an oscillator whose parameter moves its pieces (``own``): its segment's slope and
      offset per column.

    The inputs' phases advance by the rotation ``exp(i w h / 2)`` per half step (``h`` each
    column's step): no cosine in the loop.  The input rows of an augmented array are written
    only by :meth:`augmented` and :meth:`advance`."""

    def __init__(self, field: _Field, cols: np.ndarray, h: np.ndarray, t0: float) -> None:
        n, C = field.n, cols.size
        self.n, self.C = n, C
        omega, phase = field.omega[cols].T, field.phase[cols].T  # (J, C)
        U, V = field.U[cols], field.V[cols]  # (C, J, n)
        J = omega.shape[0]
        self.z = np.exp(1j * (omega * t0 + phase))  # (J, C): exp(i (w t + phi)) at t0
        self.rot = np.exp(0.5j * omega * h)  # a half step
        # the input rows: shared vectors (cos and sin of each input, the vectors in the
        # matrix), or per column the input itself (its nonzero state rows, unit columns)
        self.shared = bool(np.all(U == U[:1]) and np.all(V == V[:1]))
        if self.shared:
            self.use_re = J > 0 and bool(np.any(U[0]))
            self.use_im = J > 0 and bool(np.any(V[0]))
            blocks = ([U[0].T] if self.use_re else []) + ([V[0].T] if self.use_im else [])
            D = np.concatenate(blocks, axis=1) if blocks else np.zeros((n, 0))
        else:
            rows_in = np.flatnonzero(np.any(U != 0.0, axis=(0, 1)) | np.any(V != 0.0, axis=(0, 1)))
            self.Uc = U[:, :, rows_in].transpose(1, 2, 0).copy()  # (J, rows, C)
            self.Vc = V[:, :, rows_in].transpose(1, 2, 0).copy()
            D = np.zeros((n, rows_in.size))
            D[rows_in, np.arange(rows_in.size)] = 1.0
        self.n_in = D.shape[1]
        self.inputs = slice(n, n + self.n_in)
        k = n + self.n_in + 1  # the rows of states, inputs and the ones
        self.k = k
        normals, offsets = field.normals, field.offsets
        n_s = self.n_s = offsets.size
        sig = np.zeros((n_s, k))  # s(y) = normals . y - offsets
        sig[:, :n] = normals
        sig[:, -1] = -offsets
        self.own = field.own
        self.ramps = None
        if self.own is not None:  # an oscillator whose pieces move with the parameter
            S, O, mu = self.own
            nseg = S.shape[1]
            self.width = k
            self.bp = field.breakpoints
            self.S, self.O, self.mu = S[cols].ravel(), O[cols].ravel(), mu[cols]
            self.colbase = np.arange(C) * nseg
            self.idx = np.empty(C, dtype=np.intp)
            self.tmp = np.empty(C)
            self.D1 = D[1:2].copy()  # the input's row of the acceleration
            return
        self.ramps = _ramps(field)
        if self.ramps is not None:
            # max(s_j, 0) = lam_j (r_j - e_j) for lam_j > 0, |lam_j| (r_j - t) for lam_j < 0,
            # with r_j = max(t, e_j), t = c . y, n_j = lam_j c (c = 1 at its largest entry)
            # and e_j = offset_j / lam_j: one maximum gives the rows r_j of the surfaces
            # of one c
            A, b, W = (x.copy() for x in self.ramps)
            Wr = np.zeros((n, n_s))
            lam = np.array([nj[np.argmax(np.abs(nj))] for nj in normals]).reshape(-1)
            dirs = normals / lam[:, None] if n_s else normals
            members: dict[bytes, list[int]] = {}
            for j in range(n_s):
                members.setdefault(dirs[j].tobytes(), []).append(j)
            self.groups: list[tuple[int, np.ndarray, slice, np.ndarray]] = []
            row = k
            for js in members.values():
                c = dirs[js[0]]
                for q, j in enumerate(js):
                    Wr[:, row - k + q] = W[:, j] * abs(lam[j])
                    if lam[j] > 0:
                        b -= W[:, j] * offsets[j]
                    else:
                        A -= np.outer(W[:, j] * abs(lam[j]), c)
                nz = np.flatnonzero(c)
                unit = int(nz[0]) if nz.size == 1 else -1  # t = y[unit]
                E = (offsets[js] / lam[js])[:, None]
                self.groups.append((unit, c[None, :].copy(), slice(row, row + len(js)), E))
                row += len(js)
            self.t_row = np.empty((1, C))
            self.width = k + n_s
            self.M = np.concatenate((A, D, b[:, None], Wr), axis=1)
            self.m_rows = n
            return
        self.width = k
        AB = field.AB
        R = AB.shape[0]
        M = np.concatenate(
            (AB[:, :, :n], np.broadcast_to(D, (R, n, self.n_in)), AB[:, :, n:]), axis=2
        )
        # rows that differ between regions, formed for every block below the n rows
        vary = np.flatnonzero(np.any(M != M[:1], axis=(0, 2)))
        v = self.v = vary.size
        self.vary = vary
        if field.lookup is None:  # an oscillator: the segment counts the breakpoints passed
            regions, linear = list(range(R)), np.full(n_s, 1.0)
        elif 2**n_s <= MAX_PATTERN_BLOCKS:  # a block per sign pattern
            regions, linear = list(field.lookup), 2.0 ** np.arange(n_s)
        else:  # a block per region, the pattern's looked up
            regions, linear = [*range(R), R], None
        nan_rows = np.full((v, k), np.nan)
        blocks = [M[r][vary] if r < R else nan_rows for r in regions]
        self.M = np.concatenate([M[0], *blocks, sig], axis=0)
        self.m_rows = self.M.shape[0]
        # the flat index of row j of a column's block: (n + j) C + c + (block) v C
        self.jbase = (n + np.arange(v))[:, None] * float(C) + np.arange(C)[None, :]
        self.gidx = np.empty((v, C), dtype=np.intp)
        self.off = np.empty((1, C))
        if linear is not None:
            self.strides = (linear * (v * C))[None, :]
            self.lut = None
        else:
            self.bits = (2.0 ** np.arange(n_s))[None, :]
            lut = np.array([r if r < R else R for r in field.lookup], dtype=np.intp)
            self.lut = (lut * (v * C)).astype(np.intp)
            self.jbase_i = self.jbase.astype(np.intp)
        self.contiguous = v > 0 and bool(np.all(np.diff(vary) == 1))

    def buffer(self) -> int:
        """Rows of a stage buffer: its first ``n`` rows are the field (the rest workspace)."""
        return self.n if self.own is not None else self.m_rows

    def augmented(self, y: np.ndarray) -> np.ndarray:
        """The augmented array of states ``y`` at ``t0`` (the inputs' rows and the ones)."""
        Y = np.zeros((self.width, self.C))
        Y[: self.n] = y
        Y[self.k - 1] = 1.0
        self._write_inputs(Y)
        return Y

    def _write_inputs(self, Y: np.ndarray) -> None:
        if self.n_in == 0:
            return
        n, z = self.n, self.z
        if self.shared:
            k, J = n, z.shape[0]
            if self.use_re:
                Y[k : k + J] = z.real
                k += J
            if self.use_im:
                Y[k : k + J] = z.imag
            return
        rows = Y[self.inputs]
        np.einsum("jdc,jc->dc", self.Uc, z.real, out=rows)
        rows += np.einsum("jdc,jc->dc", self.Vc, z.imag)

    def advance(self, Y: np.ndarray) -> None:
        """Advance the inputs half a step and write them into ``Y``."""
        if self.n_in:
            self.z *= self.rot
            self._write_inputs(Y)

    def __call__(self, Y: np.ndarray, out: np.ndarray) -> None:
        """The field at the augmented states ``Y`` into ``out[:n]`` (``buffer()`` rows)."""
        if self.ramps is not None:
            for unit, c, rows, E in self.groups:
                if unit >= 0:
                    t = Y[unit]
                else:
                    np.matmul(c, Y[: self.n], out=self.t_row)
                    t = self.t_row[0]
                np.maximum(t, E, out=Y[rows])
            np.matmul(self.M, Y, out=out)
            return
        if self.own is not None:
            # v' = input - (S_i x + (O_i - c) + mu v), each column its own S, O, mu
            x, v = Y[0], Y[1]
            idx, acc = self.idx, out[1]
            np.add(np.searchsorted(self.bp, x, side="right"), self.colbase, out=idx)
            np.multiply(self.S.take(idx), x, out=acc)
            acc += self.O.take(idx)
            np.multiply(self.mu, v, out=self.tmp)
            acc += self.tmp
            np.matmul(self.D1, Y[self.inputs], out=out[0:1])
            np.subtract(out[0], acc, out=acc)
            out[0] = v
            return
        m = self.m_rows
        np.matmul(self.M, Y, out=out)
        v = self.v
        if not v:
            return
        sig = out[m - self.n_s :] >= 0.0
        if self.lut is None:  # the block's start: linear in the sign bits
            np.matmul(self.strides, sig, out=self.off)
            np.add(self.jbase, self.off, out=self.gidx, casting="unsafe")
        else:
            code = (self.bits @ sig)[0].astype(np.intp)
            np.add(self.jbase_i, self.lut.take(code), out=self.gidx)
        if self.contiguous:
            a = self.vary[0]
            out.take(self.gidx, out=out[a : a + v], mode="clip")
        else:
            out[self.vary] = out.take(self.gidx, mode="clip")


def _simulate(
    field: _Field,
    cols: np.ndarray,
    y: np.ndarray,
    K: np.ndarray,
    steps: int,
    t0: float,
    periods: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Classical RK4 of the trajectories ``y`` (states ``(n, C)``, column ``c`` at the
    parameter value ``cols[c]``) from ``t0``, each with its own step ``periods / K`` of its
    forcing period, for ``steps`` steps: the states at the last two whole periods of each
    (``prev``, ``last``; a column records at every multiple of ``K`` up to ``steps``)."""
    C = cols.size
    Kc = K[cols]
    h = (periods / K)[cols]
    st = _Stepper(field, cols, h, t0)
    n = st.n
    # the steps after which some columns record a state: the last two whole periods
    last_at = (steps // Kc) * Kc
    marks: dict[int, list[tuple[np.ndarray, bool]]] = {}
    for at_step, is_last in ((last_at - Kc, False), (last_at, True)):
        for s in np.unique(at_step):
            marks.setdefault(int(s), []).append((np.flatnonzero(at_step == s), is_last))
    prev = np.full((n, C), np.nan)
    last = np.full((n, C), np.nan)
    Yc = st.augmented(y)
    Zc = Yc.copy()
    Y, Z = Yc[:n], Zc[:n]
    rows = st.buffer()
    E = np.empty((4, rows, C))  # the stages' buffers, the fields k1..k4 their first n rows
    K1, K2, K3, K4 = E[:, :n]
    weights = np.array([[1.0, 2.0, 2.0, 1.0]])
    acc_all = np.empty((1, rows * C))
    acc = acc_all.reshape(rows, C)[:n]
    E_flat = E.reshape(4, rows * C)
    hh, h6 = 0.5 * h, h / 6.0
    inputs = st.inputs
    with np.errstate(all="ignore"):
        for i in range(1, steps + 1):
            st(Yc, E[0])
            st.advance(Zc)  # t + h / 2
            np.multiply(hh, K1, out=Z)
            Z += Y
            st(Zc, E[1])
            np.multiply(hh, K2, out=Z)
            Z += Y
            st(Zc, E[2])
            st.advance(Zc)  # t + h
            np.multiply(h, K3, out=Z)
            Z += Y
            st(Zc, E[3])
            # Y + h/6 (k1 + 2 k2 + 2 k3 + k4): the sum of every buffer row in one product
            np.matmul(weights, E_flat, out=acc_all)
            acc *= h6
            Y += acc
            Yc[inputs] = Zc[inputs]
            rec = marks.get(i)
            if rec is not None:
                for c, is_last in rec:
                    (last if is_last else prev)[:, c] = Y[:, c]
    return prev, last


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
    ascending = bool(np.all(ps[1:] >= ps[:-1]))
    for b in traced:
        pts = internals[b]
        if len(pts) < 2:
            continue
        pp = np.array([q.p for q in pts])
        unstable = _unstable(pts)
        cand = (unstable[:-1] | unstable[1:]) & (pp[:-1] != pp[1:])
        a_all, c_all = np.minimum(pp[:-1], pp[1:]), np.maximum(pp[:-1], pp[1:])
        if ascending:  # the frequencies in [a, c]: one search for every pair of points
            first = np.searchsorted(ps, a_all, side="left")
            cand &= first < np.searchsorted(ps, c_all, side="right")
        for j in np.flatnonzero(cand):
            a, c = a_all[j], c_all[j]
            for i in np.flatnonzero((ps >= a) & (ps <= c)):
                s = (ps[i] - pp[j]) / (pp[j + 1] - pp[j])
                y = (1.0 - s) * pts[j].y0 + s * pts[j + 1].y0
                d = SADDLE_OFFSET * max(1.0, float(np.max(np.abs(y))))
                for sgn in (1.0, -1.0):
                    z = y.copy()
                    z[0] += sgn * d
                    out.append((int(i), z))
    return out


def _unstable(pts: Sequence[Pt]) -> np.ndarray:
    """``max_mult >= 1`` of every point (a non-finite multiplier counts as unstable)."""
    try:
        mult = np.array([q.mult for q in pts])
    except ValueError:  # multipliers of different lengths
        return np.array([q.max_mult >= 1.0 for q in pts])
    if mult.ndim != 2:
        return np.array([q.max_mult >= 1.0 for q in pts])
    with np.errstate(invalid="ignore"):
        return ~(np.max(np.abs(mult), axis=1) < 1.0)


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


def symmetric_edge_starts(
    tracer: Tracer, edges: Sequence[float], internals: Sequence[Sequence[Pt]], traced: Sequence[int]
) -> list[tuple[float, np.ndarray]]:
    """``(p, y)``: beside every end point of the branches ``traced`` that lies on a window edge
    of ``edges``, is unstable and is its own mirror image (an odd system's symmetric orbit,
    :func:`~perturb.simulate.exact_response.symmetry.mirror_point`), the states ``y0`` with one
    state moved by ``+-f max(1, |y0|)`` for every ``f`` of ``EDGE_OFFSETS``.

    Starts of Newton for the asymmetric orbits (mirror pairs) next to an unstable symmetric
    one at the edge, on branches that enter and leave the window through that edge and are
    unstable everywhere (no attractor, sweep or branch point leads to them): on
    ``impact_pair`` over (0.6, 1.4) four unstable isolas (each with its mirror image; folds at
    Omega ~0.51-0.54 below the window and ~0.76-0.80 inside) cross Omega = 0.6 next to the
    symmetric saddle.  No scaling of the symmetric orbit reaches them (they differ from it in
    the contact pattern, not in size); which of them the sweeps' Newton starts and
    :func:`edge_starts` reached depended on rounding (two, or none)."""
    out: list[tuple[float, np.ndarray]] = []
    seen: set[tuple[float, ...]] = set()
    for b in traced:
        pts = internals[b]
        for q in (pts[0], pts[-1]) if pts else ():
            key = (q.p, *q.y0.tolist())
            if q.p not in edges or q.max_mult < 1.0 or key in seen:
                continue
            seen.add(key)
            y = np.asarray(q.y0, dtype=float)
            size = max(1.0, float(np.max(np.abs(y))))
            try:
                image = mirror_point(tracer, q).y0
            except PerturbError:
                continue
            if float(np.max(np.abs(image - y))) > 1e-6 * size:
                continue  # an asymmetric orbit: its neighbours are the image's
            for k in range(y.size):
                for f in EDGE_OFFSETS:
                    for sgn in (1.0, -1.0):
                        z = y.copy()
                        z[k] += sgn * f * size
                        out.append((float(q.p), z))
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
    prev, last = _simulate(field, cols, y, K, steps, eng.t0, periods)
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
class _Polylines:
    """Every pair of consecutive points of the traced branches (parameter values and first
    nodes) as arrays, read again when a branch was added or changed length, for
    :func:`on_traced`."""

    def __init__(self) -> None:
        self._key: tuple[int, ...] | None = None
        self._lists: list[Sequence[Pt]] = []  # (kept: their ids stay theirs)

    def segments(self, internals: Sequence[Sequence[Pt]], n: int) -> tuple[np.ndarray, ...]:
        """``(lo, hi, pa, pb, ya, yb)``: the range, the end points' parameter values and
        first nodes of every pair of consecutive points of a branch of ``n`` states."""
        key = (n, *(k for pts in internals for k in (id(pts), len(pts))))
        if key != self._key:
            self._lists = list(internals)
            pa, pb, ya, yb = [], [], [], []
            for pts in internals:
                if len(pts) < 2 or pts[0].Z.shape[1] != n:
                    continue
                ps = np.array([q.p for q in pts])
                ys = np.array([q.y0 for q in pts])
                pa.append(ps[:-1])
                pb.append(ps[1:])
                ya.append(ys[:-1])
                yb.append(ys[1:])
            if pa:
                pa_, pb_ = np.concatenate(pa), np.concatenate(pb)
                ya_, yb_ = np.concatenate(ya), np.concatenate(yb)
            else:
                pa_ = pb_ = np.zeros(0)
                ya_ = yb_ = np.zeros((0, n))
            self._arrays = (np.minimum(pa_, pb_), np.maximum(pa_, pb_), pa_, pb_, ya_, yb_)
            self._key = key
        return self._arrays


def on_traced(
    internals: Sequence[Sequence[Pt]],
    p: float,
    y: np.ndarray,
    tol: float,
    polylines: _Polylines | None = None,
) -> bool:
    """Whether state ``y`` at ``p`` lies within ``tol`` (relative to ``max(1, |y|)``) of the
    first node of a traced branch, interpolated linearly in ``p`` between consecutive points
    (every crossing of ``p`` by a branch that folds).  A cheap test before Newton; the exact
    orbit is tested again by the registry's signatures.  ``polylines`` keeps the branches'
    arrays between calls."""
    size = max(1.0, float(np.max(np.abs(y))))
    polylines = polylines if polylines is not None else _Polylines()
    lo, hi, pa, pb, ya, yb = polylines.segments(internals, y.size)
    k = np.flatnonzero((lo <= p) & (p <= hi))
    if not k.size:
        return False
    pa, pb = pa[k], pb[k]
    flat = pb == pa
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(flat, 0.0, (p - pa) / np.where(flat, 1.0, pb - pa))[:, None]
    yi = (1.0 - s) * ya[k] + s * yb[k]
    return bool(np.any(np.max(np.abs(yi - y), axis=1) <= tol * size))


def attractor_stage(
    tracer: Tracer,
    internals: Sequence[Sequence[Pt]],
    traced: Sequence[int],
    try_seed: Callable[[Pt], bool],
    budget_left: Callable[[], bool],
    *,
    symmetric: bool = False,
) -> tuple[int, int]:
    """Trace the branches of the attractors of :func:`attractor_states`, started from the grid
    and from :func:`saddle_starts` beside the unstable orbits of the branches ``traced`` (their
    indices into ``internals``; mirror images left out: their attractors are the images),
    then of the orbits at the window edges that Newton reaches from :func:`edge_starts` (of
    those branches and the ones added here) and, when ``symmetric`` (an odd system), from
    :func:`symmetric_edge_starts`, that lie on no traced branch (checked against
    ``internals`` before Newton, then by ``try_seed`` on the exact orbit, which traces the
    branch).  Returns (states polished, branches added)."""
    eng = tracer.eng
    polished = added = 0
    polylines = _Polylines()

    def start(p: float, y: np.ndarray) -> None:
        nonlocal polished, added
        if not budget_left() or on_traced(internals, p, y, ON_TRACED, polylines):
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
    # traced before and those this stage added (with their mirror images: a few more starts),
    # then (odd systems) beside their symmetric unstable orbits at the edges.  Exact flows
    # only (where Newton is cheap), as the scan
    if eng.exact and eng.m == 1:
        found = [*traced, *range(n_before, len(internals))]
        for p, y in edge_starts((eng.lo, eng.hi), internals, found):
            start(p, y)
        if symmetric:
            for p, y in symmetric_edge_starts(tracer, (eng.lo, eng.hi), internals, found):
                start(p, y)
    return polished, added
