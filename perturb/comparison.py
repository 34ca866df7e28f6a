"""Comparison of two :class:`~perturb.response.Response` objects, point by point.

``compare(response, reference)`` measures how well ``response`` (usually an approximation)
reproduces ``reference`` (usually the exact response): amplitude errors per branch, which
branches correspond, which reference branches the response missed, which of its branches
have no counterpart, and where the two disagree about stability.

Matching
--------
The two responses need not share frequencies.  Each branch is a polyline in the
``(omega, amplitude)`` plane, ordered along the curve, and may fold back in ``omega``.  The
*solutions of a response at a frequency* ``omega`` are the points where its polylines cross
that frequency: linear interpolation on every segment whose ``omega`` interval contains it
(so on every monotone-in-``omega`` piece of every branch).  A segment of constant ``omega``
contributes its point nearest to the amplitude being matched.

A point ``(omega, a)`` of ``response`` is *compared* when the reference has at least one
solution at ``omega``; it is then matched to the reference solution ``r`` nearest on a
logarithmic amplitude scale (``|ln a - ln r|`` smallest: amplitudes span decades, and a
plain relative error would prefer a much larger ``r`` to a slightly smaller one), and its
error is the relative error ``|a - r| / r``.  Reference branches that coincide in amplitude
(the mirror-image pairs of odd systems) tie, and a tie counts for each of them.

A branch of ``response`` is *matched* to the reference branch that most of its points within
``tolerance`` go to, provided at least ``min_share`` of its compared points are within
``tolerance``; otherwise it is *spurious* (no counterpart).  Symmetrically, a reference branch
is *missed* when fewer than ``min_share`` of its solutions at the response's frequencies have
a response solution within ``tolerance`` (a reference branch none of whose frequencies the
response samples, but inside the response's frequency span, is missed too).  Sampling the
reverse direction at the response's own frequencies keeps it exact for responses computed
on a frequency grid (``solutions_at``).

Errors
------
The per-point error (:func:`relative_errors`, ``Comparison.rel_errors``, the ``rel_error``
CSV column) is against the nearest reference solution of any branch.  The per-branch
``max_error`` and ``rms_error`` of a matched branch are against its matched reference branch
only, over the points where that branch has a solution: a point of an approximation just
beyond the fold of its reference branch has no counterpart there and is counted as not
*covered* instead of being charged with the distance to some other branch.  The same holds
where the reference branch folds back (an S-shaped branch: beyond the fold only its other
side has a solution): a point farther than ``tolerance`` from the matched branch but within
``tolerance`` in amplitude of one of its folds, and within ``fold_overshoot`` of it in
relative frequency, is the overshooting tip of a displaced fold and is not covered either.

Stability
---------
Only points of matched branches are checked, each against the reference branch its branch
is matched to (the nearest solution overall may lie on another branch that passes closer):
the nearest solution of that branch at the point's frequency, if it is within ``tolerance``,
gives the reference flag, that of the reference point nearer to the interpolated solution
(the segment's start for ``t <= 1/2``, else its end).  Points where it differs from the
point's own flag are *stability disagreements*.  With ``fold_distance``, points within
``|omega - omega_f| <= fold_distance * omega_f`` of a fold ``omega_f`` of that reference
branch are left out (stability changes at a fold, and an approximate fold is displaced), as
are points that close to any of ``special_frequencies`` (branch points, period doublings of
the reference).  A reference fold is a turning point of ``omega`` along a branch, at its
extreme sample (also at the closing point of a loop that repeats its first point).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from perturb.errors import ParameterError
from perturb.response import Response

__all__ = [
    "Comparison",
    "BranchComparison",
    "ReferenceBranchComparison",
    "StabilityDisagreement",
    "compare",
    "compare_coordinates",
    "coordinate_response",
    "relative_errors",
]

#: Amplitudes that may be compared.
QUANTITIES = ("amplitude", "first_harmonic_amplitude")

# Reference branches whose log distances differ by less than this tie (mirror images are
# computed to ~1e-7 relative, not bitwise).
_TIE = 1e-6
# Zero amplitudes (the rest state) would have log distance -inf.
_FLOOR = 1e-300
# Query points times segments per vectorised block (memory ~ 10 arrays of this size).
_BLOCK = 1_000_000


# =============================================================================================
# result objects
# =============================================================================================
@dataclass(frozen=True)
class StabilityDisagreement:
    """A compared point whose stability flag differs from the reference's.

    Attributes
    ----------
    branch, index : int
        The point: ``response.branches[branch]``, point ``index``.
    omega, amplitude : float
        Its frequency and compared amplitude.
    stable : bool
        Its own flag.
    reference_branch : int
        The reference branch of the matched solution.
    reference_amplitude : float
        The matched reference solution.
    reference_stable : bool
        The reference's flag there.
    """

    branch: int
    index: int
    omega: float
    amplitude: float
    stable: bool
    reference_branch: int
    reference_amplitude: float
    reference_stable: bool


@dataclass(frozen=True)
class BranchComparison:
    """One branch of the compared response.

    Attributes
    ----------
    branch : int
        Index in ``response.branches``.
    points : int
        Its number of points.
    compared : int
        Points at frequencies where the reference has a solution.
    within : int
        Compared points whose error is at most the tolerance.
    matched : int or None
        The reference branch most of the points within tolerance go to (None: spurious or
        not compared).
    covered : int
        Points at frequencies where the matched reference branch has a solution (0 when
        not matched).
    max_error, rms_error : float
        Largest and root-mean-square relative error: for a matched branch over its covered
        points, against the nearest solution *of the matched branch* (a point beyond the
        fold of its reference branch is not charged with the distance to another branch);
        otherwise over the compared points, against the nearest solution of any branch.
        NaN when there is no such point.
    stability_disagreements : int
        Points within tolerance, not excluded near folds, whose stability flag differs.
    """

    branch: int
    points: int
    compared: int
    within: int
    matched: int | None
    covered: int
    max_error: float
    rms_error: float
    stability_disagreements: int


@dataclass(frozen=True)
class ReferenceBranchComparison:
    """How well one reference branch is reproduced.

    Attributes
    ----------
    branch : int
        Index in ``reference.branches``.
    points : int
        Its number of points.
    compared : int
        Its solutions at the response's frequencies.
    reproduced : int
        Those with a response solution within tolerance.
    matched_by : tuple of int
        Response branches matched to it (ties of mirror images included).
    """

    branch: int
    points: int
    compared: int
    reproduced: int
    matched_by: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class Comparison:
    """The result of :func:`compare`; ``print`` it for a summary table.

    Attributes
    ----------
    method, reference_method : str
        ``response.method`` and ``reference.method``.
    quantity : str
        The compared column (``'amplitude'`` or ``'first_harmonic_amplitude'``).
    tolerance, min_share : float
        The matching thresholds used.
    fold_distance : float or None
        Relative distance to reference folds (and ``special_frequencies``) within which
        stability was not compared.
    branches : tuple of BranchComparison
        One per branch of the response.
    reference_branches : tuple of ReferenceBranchComparison
        One per branch of the reference.
    missed : tuple of int
        Reference branches the response does not reproduce.
    spurious : tuple of int
        Response branches without a counterpart in the reference.
    uncompared : tuple of int
        Response branches entirely at frequencies where the reference has no solution.
    outside : tuple of int
        Reference branches entirely outside the response's frequency span.
    stability_disagreements : tuple of StabilityDisagreement
    excluded : int
        Points within tolerance left out of the stability check near folds.
    folds : tuple of (int, float, float)
        ``(reference branch, omega, amplitude)`` of the reference folds found.
    rel_errors : ndarray
        One relative error per row of ``response.rows()`` (NaN where not compared);
        read-only.
    coordinates : tuple of (str, float, float)
        Two responses of a system of several coordinates (both with ``amplitude_<name>``
        columns, :class:`perturb.solve.SystemResponse`): per coordinate its name and the max
        and RMS relative error of its ``max |.|`` (:func:`compare_coordinates`, matched branch
        by branch like the output); empty otherwise.
    """

    method: str
    reference_method: str
    quantity: str
    tolerance: float
    min_share: float
    fold_distance: float | None
    branches: tuple[BranchComparison, ...]
    reference_branches: tuple[ReferenceBranchComparison, ...]
    missed: tuple[int, ...]
    spurious: tuple[int, ...]
    uncompared: tuple[int, ...]
    outside: tuple[int, ...]
    stability_disagreements: tuple[StabilityDisagreement, ...]
    excluded: int
    folds: tuple[tuple[int, float, float], ...]
    rel_errors: np.ndarray
    coordinates: tuple[tuple[str, float, float], ...] = ()

    @property
    def matches(self) -> dict[int, int]:
        """``{response branch: reference branch}`` for every matched branch."""
        return {b.branch: b.matched for b in self.branches if b.matched is not None}

    @property
    def max_error(self) -> float:
        """Largest relative error over the matched branches (NaN if none is matched)."""
        errs = [b.max_error for b in self.branches if b.matched is not None and b.covered]
        return float(max(errs)) if errs else float("nan")

    @property
    def rms_error(self) -> float:
        """Root-mean-square relative error over the covered points of matched branches."""
        total, n = 0.0, 0
        for b in self.branches:
            if b.matched is not None and b.covered:
                total += b.rms_error**2 * b.covered
                n += b.covered
        return float(np.sqrt(total / n)) if n else float("nan")

    def __repr__(self) -> str:
        return (
            f"Comparison({self.method} vs {self.reference_method}: "
            f"{len(self.matches)}/{len(self.branches)} branches matched, "
            f"max error {self.max_error:.3g}, missed {list(self.missed)}, "
            f"spurious {list(self.spurious)}, "
            f"{len(self.stability_disagreements)} stability disagreements)"
        )

    def __str__(self) -> str:
        head = (
            f"{self.method} against {self.reference_method}: relative error of "
            f"{self.quantity}, tolerance {self.tolerance:g}, min share {self.min_share:g}"
        )
        lines = [head]
        lines.append(
            f"  {'branch':>6} {'points':>7} {'compared':>8} {'within':>7} {'matched':>7} "
            f"{'covered':>7} {'max error':>10} {'rms error':>10} {'stability':>9}"
        )
        for b in self.branches:
            if b.matched is not None:
                tag = str(b.matched)
            elif b.compared == 0:
                tag = "-"
            else:
                tag = "spurious"
            lines.append(
                f"  {b.branch:>6} {b.points:>7} {b.compared:>8} {b.within:>7} {tag:>7} "
                f"{b.covered:>7} {b.max_error:>10.3e} {b.rms_error:>10.3e} "
                f"{b.stability_disagreements:>9}"
            )
        lines.append(f"  {'reference':>9} {'points':>7} {'compared':>8} {'reproduced':>10}  by")
        for r in self.reference_branches:
            by = ", ".join(map(str, r.matched_by)) or "-"
            lines.append(f"  {r.branch:>9} {r.points:>7} {r.compared:>8} {r.reproduced:>10}  {by}")
        lines.append(f"  missed reference branches: {_list(self.missed)}")
        lines.append(f"  spurious branches: {_list(self.spurious)}")
        if self.uncompared:
            lines.append(f"  branches not compared: {_list(self.uncompared)}")
        if self.outside:
            lines.append(f"  reference branches outside the span: {_list(self.outside)}")
        if self.matches:
            lines.append(
                f"  matched branches: max error {self.max_error:.3e}, rms {self.rms_error:.3e}"
            )
        where = (
            f" ({self.excluded} points within {self.fold_distance:g} of folds left out)"
            if self.fold_distance is not None
            else ""
        )
        for name, mx, rms in self.coordinates:
            lines.append(f"  coordinate {name}: max |{name}| error max {mx:.3e}, rms {rms:.3e}")
        lines.append(f"  stability disagreements: {len(self.stability_disagreements)}{where}")
        for run in _runs(self.stability_disagreements):
            first = run[0]
            ws = [d.omega for d in run]
            lines.append(
                f"    branch {first.branch}: {len(run)} points, omega "
                f"{min(ws):.6g}..{max(ws):.6g}, "
                f"{'stable' if first.stable else 'unstable'} where reference branch "
                f"{first.reference_branch} is {'stable' if first.reference_stable else 'unstable'}"
            )
        return "\n".join(lines)


def _list(items: Sequence[int]) -> str:
    """``"none"``, or the count and the branch numbers: ``"1 (branch #0)"``, ``"2 (branches
    #0, #3)"`` -- a bare ``0`` would read as a count."""
    if not items:
        return "none"
    numbers = ", ".join(f"#{i}" for i in items)
    return f"{len(items)} (branch{'es' if len(items) > 1 else ''} {numbers})"


def _runs(dis: Sequence[StabilityDisagreement]) -> list[list[StabilityDisagreement]]:
    """Consecutive disagreements of one kind along one branch, as groups."""
    runs: list[list[StabilityDisagreement]] = []
    for d in dis:
        if runs:
            p = runs[-1][-1]
            if (
                p.branch == d.branch
                and p.index + 1 == d.index
                and (p.stable, p.reference_stable, p.reference_branch)
                == (d.stable, d.reference_stable, d.reference_branch)
            ):
                runs[-1].append(d)
                continue
        runs.append([d])
    return runs


# =============================================================================================
# input checks
# =============================================================================================
def _check_response(r: object, name: str) -> Response:
    if not isinstance(r, Response):
        raise ParameterError(f"{name} = {r!r:.80}: expected a perturb.Response")
    if sum(len(b) for b in r.branches) == 0:
        raise ParameterError(f"{name} ({r.method}) has no points to compare")
    return r


def _check_quantity(quantity: str) -> str:
    if quantity not in QUANTITIES:
        raise ParameterError(
            f"quantity = {quantity!r}: expected one of {', '.join(QUANTITIES)}, or "
            "'amplitude_<coordinate>' for responses of a system of several coordinates"
        )
    return quantity


def _coordinates(r: Response) -> tuple[str, ...]:
    """The coordinates whose ``amplitude_<name>`` columns ``r`` carries (a system's response)."""
    return tuple(getattr(r, "coordinates", ()) or ())


def coordinate_response(response: Response, coordinate: str) -> Response:
    """``response`` with its ``amplitude`` column replaced by ``amplitude_<coordinate>`` (the
    ``max |.|`` of one coordinate of a system's response), so that it is compared like an
    output; folds (of the output) are dropped, the other columns kept.

    Raises
    ------
    ParameterError
        A response without that coordinate (naming the coordinates it has).
    """
    from perturb.response import Branch

    _check_response(response, "response")
    name = coordinate.removeprefix("amplitude_") if isinstance(coordinate, str) else coordinate
    coords = _coordinates(response)
    cols = getattr(response, "columns", ())
    if name not in coords or len(cols) != len(response.branches):
        have = ", ".join(coords) if coords else "none (not a system's response)"
        raise ParameterError(
            f"coordinate {coordinate!r}: response {response.method!r} has the coordinates {have}"
        )
    key = f"amplitude_{name}"
    branches = tuple(
        Branch(
            b.omega,
            np.asarray(c[key], dtype=float),
            b.first_harmonic_amplitude,
            b.mean,
            b.stable,
            b.max_multiplier,
        )
        for b, c in zip(response.branches, cols, strict=True)
    )
    return Response(branches, response.method, response.model, response.params, (), response.notes)


def _resolve_quantity(
    response: Response, reference: Response, quantity: str
) -> tuple[Response, Response, str]:
    """``amplitude_<name>``: both responses projected on that coordinate
    (:func:`coordinate_response`), compared as ``amplitude``."""
    if isinstance(quantity, str) and quantity.startswith("amplitude_"):
        return (
            coordinate_response(response, quantity),
            coordinate_response(reference, quantity),
            "amplitude",
        )
    return response, reference, _check_quantity(quantity)


def _check_fraction(value: object, name: str, *, upper: float | None) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r}: expected a number") from None
    if isinstance(value, bool) or not np.isfinite(v) or v <= 0 or (upper and v > upper):
        bound = f"0 < {name} <= {upper:g}" if upper else f"{name} > 0, finite"
        raise ParameterError(f"{name} = {value!r}: expected {bound}")
    return v


# =============================================================================================
# geometry: solutions of a response at given frequencies
# =============================================================================================
@dataclass(frozen=True)
class _Piece:
    """A monotone-in-omega run of one branch, stored with omega ascending."""

    branch: int
    w: np.ndarray
    a: np.ndarray
    s: np.ndarray


@dataclass(frozen=True)
class _Segments:
    """Loose segments, searched by brute force: those of short pieces, segments of constant
    omega, single-point branches (as degenerate segments)."""

    w0: np.ndarray
    w1: np.ndarray
    a0: np.ndarray
    a1: np.ndarray
    s0: np.ndarray
    s1: np.ndarray
    branch: np.ndarray


@dataclass(frozen=True)
class _Curves:
    """A response as monotone pieces (binary search) plus loose segments."""

    pieces: tuple[_Piece, ...]
    loose: _Segments
    n_branches: int
    folds: tuple[tuple[int, float, float], ...]


# Pieces shorter than this are searched by brute force with the loose segments (a branch
# that zigzags in omega would otherwise cost one pass over the queries per segment).
_LONG = 8


# Points inserted on each side of a fold vertex of the reference by _refine_turns.
_FOLD_POINTS = 16


def _refine_turns(
    w: np.ndarray, a: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample the reference around every vertex where omega turns.

    Near a fold the amplitude goes like the square root of the frequency distance, so the
    straight segments through the fold's extreme sample are poor there (a point of an
    approximation near the fold tip is charged with the chord's error, ~5e-3 on a Duffing
    response traced with 733 points; and the true fold lies a little beyond the extreme
    sample, leaving no reference solution on one side).  Omega is smooth in the amplitude
    through a fold: the parabola ``omega(a)`` through the vertex and its two neighbours is
    sampled densely between them instead.  Vertices where the amplitude turns as well are
    left alone."""
    n = w.size
    steps = np.diff(w)
    nz = np.nonzero(steps)[0]
    if n < 3 or nz.size < 2:
        return w, a, s
    sgn = np.sign(steps[nz])
    turns = nz[np.nonzero(sgn[:-1] != sgn[1:])[0]] + 1
    ws, as_, ss, last = [], [], [], 0
    for v in turns:
        if v < 1 or v > n - 2 or v <= last:
            continue
        a3, w3 = a[v - 1 : v + 2], w[v - 1 : v + 2]
        if not (a3[1] - a3[0]) * (a3[2] - a3[1]) > 0:
            continue
        coef = np.polyfit(a3, w3, 2)
        t = np.linspace(a3[0], a3[2], 2 * _FOLD_POINTS + 3)[1:-1]
        wt = np.polyval(coef, t)
        if not np.all(np.isfinite(wt)):
            continue
        ws += [w[last:v], wt]
        as_ += [a[last:v], t]
        ss += [s[last:v], np.where(np.abs(t - a3[0]) < np.abs(t - a3[2]), s[v - 1], s[v + 1])]
        last = v + 1
    if not ws:
        return w, a, s
    ws.append(w[last:])
    as_.append(a[last:])
    ss.append(s[last:])
    return np.concatenate(ws), np.concatenate(as_), np.concatenate(ss)


def _curves(r: Response, quantity: str, refine_folds: bool = False) -> _Curves:
    pieces: list[_Piece] = []
    loose: list[list[np.ndarray]] = [[] for _ in range(7)]
    folds: list[tuple[int, float, float]] = []

    def add_loose(i: int, w, a, s, lo: np.ndarray, hi: np.ndarray) -> None:
        for store, arr in zip(
            loose, (w[lo], w[hi], a[lo], a[hi], s[lo], s[hi], np.full(lo.size, i)), strict=True
        ):
            store.append(arr)

    for i, b in enumerate(r.branches):
        n = len(b)
        if n == 0:
            continue
        w, a, s = b.omega, getattr(b, quantity), b.stable
        if refine_folds:
            w, a, s = _refine_turns(w, a, s)
            n = w.size
        if n == 1:
            add_loose(i, w, a, s, np.zeros(1, int), np.zeros(1, int))
            continue
        steps = np.diff(w)
        nz = np.nonzero(steps)[0]
        sgn = np.sign(steps[nz])
        turns = nz[np.nonzero(sgn[:-1] != sgn[1:])[0]] + 1  # vertices where omega turns
        folds.extend((i, float(w[v]), float(a[v])) for v in turns)
        # a closed loop that repeats its first point turns there too if its ends do
        if nz.size and w[0] == w[-1] and a[0] == a[-1] and sgn[0] != sgn[-1]:
            folds.append((i, float(w[0]), float(a[0])))
        flat = np.nonzero(steps == 0)[0]
        add_loose(i, w, a, s, flat, flat + 1)
        bounds = np.concatenate([[0], turns, [n - 1]])
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
            idx = np.arange(lo, hi + 1)
            if w[hi] == w[lo]:
                continue  # all of constant omega: already loose
            if idx.size < _LONG:
                seg = idx[:-1][steps[idx[:-1]] != 0]
                add_loose(i, w, a, s, seg, seg + 1)
                continue
            if w[hi] < w[lo]:
                idx = idx[::-1]
            pieces.append(_Piece(i, w[idx], a[idx], s[idx]))
    cat = [np.concatenate(x) if x else np.empty(0) for x in loose]
    seg = _Segments(
        cat[0], cat[1], cat[2], cat[3], cat[4].astype(bool), cat[5].astype(bool), cat[6].astype(int)
    )
    return _Curves(tuple(pieces), seg, len(r.branches), tuple(folds))


def _on_piece(p: _Piece, wq: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interpolated amplitude and stability flag of piece ``p`` at frequencies ``wq`` (all
    inside its range); vertices are returned exactly, not re-rounded."""
    i = np.clip(np.searchsorted(p.w, wq, side="right") - 1, 0, p.w.size - 2)
    dw = p.w[i + 1] - p.w[i]
    t = np.where(dw > 0, (wq - p.w[i]) / np.where(dw > 0, dw, 1.0), 0.0)
    r = np.where(t >= 1.0, p.a[i + 1], p.a[i] + t * (p.a[i + 1] - p.a[i]))
    return r, np.where(t > 0.5, p.s[i + 1], p.s[i]), i


@dataclass(frozen=True)
class _Nearest:
    """For each query point: the nearest solution of a response at its frequency."""

    found: np.ndarray  # bool: any solution at that frequency
    value: np.ndarray  # nearest solution (NaN if none)
    branch: np.ndarray  # its branch (-1 if none)
    stable: np.ndarray  # its stability flag
    ties: np.ndarray  # bool (queries x branches): branches tied for nearest


def _nearest(w: np.ndarray, a: np.ndarray, cur: _Curves) -> _Nearest:
    nq = w.size
    best = np.full(nq, np.inf)
    value = np.full(nq, np.nan)
    branch = np.full(nq, -1)
    stable = np.zeros(nq, bool)
    per_branch = np.full((nq, cur.n_branches), np.inf)
    la = np.log(np.maximum(a, _FLOOR))

    def offer(q: np.ndarray, r: np.ndarray, st: np.ndarray, br: np.ndarray) -> None:
        d = np.abs(np.log(np.maximum(r, _FLOOR)) - la[q])
        np.minimum.at(per_branch, (q, br), d)
        # a query may come with several candidates: keep its nearest before comparing
        order = np.lexsort((d, q))
        first = order[np.r_[True, q[order][1:] != q[order][:-1]]]
        q, r, st, br, d = q[first], r[first], st[first], br[first], d[first]
        better = d < best[q]
        qb = q[better]
        best[qb], value[qb], stable[qb], branch[qb] = d[better], r[better], st[better], br[better]

    for p in cur.pieces:
        q = np.nonzero((w >= p.w[0]) & (w <= p.w[-1]))[0]
        if q.size:
            r, st, _ = _on_piece(p, w[q])
            offer(q, r, st, np.full(q.size, p.branch))
    g = cur.loose
    ns = g.w0.size
    if ns:
        lo_w, hi_w = np.minimum(g.w0, g.w1), np.maximum(g.w0, g.w1)
        flat = g.w0 == g.w1
        dw = np.where(flat, 1.0, g.w1 - g.w0)
        a_lo, a_hi = np.minimum(g.a0, g.a1), np.maximum(g.a0, g.a1)
        step = max(1, _BLOCK // ns)
        for q0 in range(0, nq, step):
            wq, aq = w[q0 : q0 + step, None], a[q0 : q0 + step, None]
            qi, si = np.nonzero((lo_w <= wq) & (wq <= hi_w))
            if qi.size == 0:
                continue
            t = np.clip((wq[qi, 0] - g.w0[si]) / dw[si], 0.0, 1.0)
            r = np.where(
                flat[si],
                np.clip(aq[qi, 0], a_lo[si], a_hi[si]),
                g.a0[si] + t * (g.a1[si] - g.a0[si]),
            )
            # on a segment of constant omega the nearer end is the one nearer in amplitude
            late = np.where(flat[si], np.abs(r - g.a1[si]) < np.abs(r - g.a0[si]), t > 0.5)
            offer(qi + q0, r, np.where(late, g.s1[si], g.s0[si]), g.branch[si])
    found = np.isfinite(best)
    ties = found[:, None] & (per_branch <= best[:, None] + _TIE)
    return _Nearest(found, value, branch, stable, ties)


def _crossings(cur: _Curves, rw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every solution of ``cur`` at the sorted frequencies ``rw``: (frequency index, value,
    branch), a solution at a vertex shared by two pieces or segments counted once."""
    fi, val, br = [], [], []
    for p in cur.pieces:
        lo, hi = np.searchsorted(rw, p.w[0], "left"), np.searchsorted(rw, p.w[-1], "right")
        if hi > lo:
            r, _, _ = _on_piece(p, rw[lo:hi])
            fi.append(np.arange(lo, hi))
            val.append(r)
            br.append(np.full(hi - lo, p.branch))
    g = cur.loose
    if g.w0.size:
        lo_w, hi_w = np.minimum(g.w0, g.w1), np.maximum(g.w0, g.w1)
        qi, si = np.nonzero((lo_w[None, :] <= rw[:, None]) & (rw[:, None] <= hi_w[None, :]))
        dw = g.w1[si] - g.w0[si]
        t = np.where(dw == 0, 0.0, (rw[qi] - g.w0[si]) / np.where(dw == 0, 1.0, dw))
        r = np.where(t >= 1.0, g.a1[si], g.a0[si] + t * (g.a1[si] - g.a0[si]))
        # a segment of constant omega: its other end too
        v = dw == 0
        fi += [qi, qi[v]]
        val += [r, g.a1[si][v]]
        br += [g.branch[si], g.branch[si][v]]
    if not fi:
        return np.empty(0, int), np.empty(0), np.empty(0, int)
    key = np.unique(
        np.column_stack([np.concatenate(br), np.concatenate(fi), np.concatenate(val)]), axis=0
    )
    return key[:, 1].astype(int), key[:, 2], key[:, 0].astype(int)


def _points(r: Response, quantity: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All points of ``r`` in row order: omega, amplitude, owning branch."""
    w = np.concatenate([b.omega for b in r.branches]) if r.branches else np.empty(0)
    a = np.concatenate([getattr(b, quantity) for b in r.branches]) if r.branches else w
    br = np.concatenate([np.full(len(b), i) for i, b in enumerate(r.branches)])
    return w, a, br


def _rel(a: np.ndarray, r: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.abs(a - r) / np.abs(r)
    # r = 0 only for a response at rest: exact if a is too
    return np.where(r == 0, np.where(a == 0, 0.0, np.inf), e)


# =============================================================================================
# public functions
# =============================================================================================
def relative_errors(
    response: Response, reference: Response, *, quantity: str = "amplitude"
) -> np.ndarray:
    """The relative error of every point of ``response`` against ``reference``.

    Each point ``(omega, a)`` is compared with the reference solution at ``omega`` nearest on
    a logarithmic scale (module docstring): ``|a - r| / r``.

    Parameters
    ----------
    response, reference : Response
        ``reference`` is interpolated along its branches, which may fold back in omega.
    quantity : {'amplitude', 'first_harmonic_amplitude', 'amplitude_<coordinate>'}
        The compared column (``amplitude_<coordinate>``: one coordinate's ``max |.|`` of two
        responses of a system, :func:`coordinate_response`).

    Returns
    -------
    ndarray
        One value per row of ``response.rows()``, in order (the ``rel_error`` column of a
        CSV file).  NaN only where the reference has no solution at that frequency (outside
        the frequency ranges its branches cover); ``inf`` only against a zero reference
        amplitude.

    Raises
    ------
    ParameterError
        If an argument is not a Response, has no points, or ``quantity`` is unknown.
    """
    response = _check_response(response, "response")
    reference = _check_response(reference, "reference")
    response, reference, quantity = _resolve_quantity(response, reference, quantity)
    w, a, _ = _points(response, quantity)
    near = _nearest(w, a, _curves(reference, quantity, refine_folds=True))
    return np.where(near.found, _rel(a, near.value), np.nan)


def compare(
    response: Response,
    reference: Response,
    *,
    quantity: str = "amplitude",
    tolerance: float = 0.2,
    min_share: float = 0.5,
    fold_distance: float | None = None,
    special_frequencies: Sequence[float] = (),
    fold_overshoot: float = 0.02,
) -> Comparison:
    """Compare ``response`` with ``reference`` branch by branch (see the module docstring).

    Parameters
    ----------
    response : Response
        The response judged (an approximation, say).
    reference : Response
        The response judged against (the exact one, say); should be traced densely, since
        it is interpolated linearly between its points.
    quantity : {'amplitude', 'first_harmonic_amplitude', 'amplitude_<coordinate>'}
        The compared column: ``max |x|`` (default), the first-harmonic amplitude, or one
        coordinate's ``max |.|`` of two responses of a system. With ``'amplitude'`` and two
        such responses, :attr:`Comparison.coordinates` also holds every coordinate's errors.
    tolerance : float
        Relative error up to which a point counts as reproducing a solution (default 0.2).
    min_share : float
        Share of compared points within ``tolerance`` that a branch needs to have a
        counterpart (default 0.5: "most of its points"); ``0 < min_share <= 1``.
    fold_distance : float, optional
        Leave out of the stability check the points within this relative frequency distance
        of a fold of their reference branch, or of any of ``special_frequencies``.
    special_frequencies : sequence of float
        More frequencies where stability changes without a fold (branch points, period
        doublings); needs ``fold_distance``.
    fold_overshoot : float
        Relative frequency distance (default 0.02) within which a point of a matched branch
        that is farther than ``tolerance`` from its reference branch, but within
        ``tolerance`` in amplitude of a fold of it, is taken for the tip of a displaced fold
        and not covered (module docstring).

    Returns
    -------
    Comparison

    Raises
    ------
    ParameterError
        If an argument is not a Response or has no points, or a threshold is out of range.

    Examples
    --------
    >>> from perturb.response import Branch, Response
    >>> w = np.linspace(0.5, 1.5, 5)
    >>> def resp(a, method):
    ...     b = Branch(w, a, a, 0 * w, w < 2, 0.5 + 0 * w)
    ...     return Response((b,), method)
    >>> c = compare(resp(1.01 * (1 + w), "approx"), resp(1 + w, "exact"))
    >>> c.matches, c.missed, c.spurious, round(c.max_error, 12)
    ({0: 0}, (), (), 0.01)
    """
    response = _check_response(response, "response")
    reference = _check_response(reference, "reference")
    kwargs = {
        "tolerance": tolerance,
        "min_share": min_share,
        "fold_distance": fold_distance,
        "special_frequencies": special_frequencies,
        "fold_overshoot": fold_overshoot,
    }
    per_coordinate: tuple[tuple[str, float, float], ...] = ()
    shared = [c for c in _coordinates(response) if c in _coordinates(reference)]
    if quantity == "amplitude" and shared:
        per_coordinate = tuple(
            (name, c.max_error, c.rms_error)
            for name, c in compare_coordinates(response, reference, **kwargs).items()
        )
    response, reference, quantity = _resolve_quantity(response, reference, quantity)
    tolerance = _check_fraction(tolerance, "tolerance", upper=None)
    min_share = _check_fraction(min_share, "min_share", upper=1.0)
    fold_overshoot = _check_fraction(fold_overshoot, "fold_overshoot", upper=None)
    fold_distance, special = _check_exclusions(fold_distance, special_frequencies)

    ref_cur = _curves(reference, quantity, refine_folds=True)
    pts = _compared_points(response, ref_cur, quantity, tolerance)
    votes = _votes(pts, len(response.branches), len(reference.branches))
    matched, spurious, uncompared = _match_branches(pts, votes, min_share)
    om = _against_matched(
        pts, reference, quantity, matched, ref_cur.folds, tolerance, fold_overshoot
    )
    dis, differ, excluded = _stability(pts, om, ref_cur.folds, fold_distance, special)
    branches = _branch_rows(response, pts, om, matched, differ)
    ref_rows, missed, outside = _reference_rows(
        response, reference, ref_cur, pts.w, quantity, tolerance, min_share, matched, votes
    )

    pts.err.setflags(write=False)
    return Comparison(
        method=response.method,
        reference_method=reference.method,
        quantity=quantity,
        tolerance=tolerance,
        min_share=min_share,
        fold_distance=fold_distance,
        branches=branches,
        reference_branches=ref_rows,
        missed=missed,
        spurious=spurious,
        uncompared=uncompared,
        outside=outside,
        stability_disagreements=dis,
        excluded=int(excluded.sum()),
        folds=tuple(ref_cur.folds),
        rel_errors=pts.err,
        coordinates=per_coordinate,
    )


def compare_coordinates(
    response: Response, reference: Response, **options: object
) -> dict[str, Comparison]:
    """One :class:`Comparison` per coordinate of two responses of a system of several
    coordinates: each compares that coordinate's ``max |.|`` (``amplitude_<name>`` columns,
    :func:`coordinate_response`) branch by branch, with the options of :func:`compare`.

    Raises
    ------
    ParameterError
        Responses without common coordinates (naming what each has), or an argument that is
        no ``Response``.
    """
    for name, value in (("response", response), ("reference", reference)):
        if not isinstance(value, Response):
            raise ParameterError(f"{name} = {value!r:.80}: expected a perturb Response")
    shared = [c for c in _coordinates(response) if c in _coordinates(reference)]
    if not shared:
        raise ParameterError(
            f"responses {response.method!r} (coordinates: "
            f"{', '.join(_coordinates(response)) or 'none'}) and {reference.method!r} "
            f"(coordinates: {', '.join(_coordinates(reference)) or 'none'}) share no "
            "coordinate: expected two responses of the same system (frequency_response(system, "
            "...))"
        )
    return {
        name: compare(response, reference, quantity=f"amplitude_{name}", **options)  # type: ignore[arg-type]
        for name in shared
    }


# =============================================================================================
# the stages of compare
# =============================================================================================
def _check_exclusions(
    fold_distance: object, special_frequencies: Sequence[float]
) -> tuple[float | None, np.ndarray]:
    """``fold_distance`` (None, or a number >= 0) and ``special_frequencies`` (positive,
    only with ``fold_distance``) checked: ``(fold_distance, special as a flat array)``.

    Raises
    ------
    ParameterError
        Naming the bad value.
    """
    if fold_distance is not None:
        given = fold_distance
        try:
            fold_distance = float(given)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            fold_distance = float("nan")
        if isinstance(given, bool) or not (np.isfinite(fold_distance) and fold_distance >= 0):
            raise ParameterError(f"fold_distance = {given!r}: expected a number >= 0")
    try:
        special = np.asarray(special_frequencies, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        special = np.array([np.nan])
    if special.size and fold_distance is None:
        raise ParameterError("special_frequencies needs fold_distance (the distance to keep)")
    if not np.all(np.isfinite(special) & (special > 0)):
        raise ParameterError(
            f"special_frequencies = {list(special_frequencies)!r}: expected positive numbers"
        )
    return fold_distance, special  # type: ignore[return-value]


@dataclass(frozen=True)
class _Compared:
    """Every point of the response, in row order, against the nearest reference solution
    of any branch (the first stage of :func:`compare`)."""

    w: np.ndarray  # frequency
    a: np.ndarray  # compared amplitude
    owner: np.ndarray  # its branch
    index: np.ndarray  # its index along the branch
    stable: np.ndarray  # its own stability flag
    near: _Nearest  # the nearest reference solution at its frequency
    err: np.ndarray  # relative error against it (NaN: no reference solution there)
    within: np.ndarray  # bool: a reference solution there, within tolerance


def _compared_points(
    response: Response, ref_cur: _Curves, quantity: str, tolerance: float
) -> _Compared:
    """Stage 1: each point of ``response`` against the nearest reference solution at its
    frequency (the ``rel_errors`` of the result)."""
    w, a, owner = _points(response, quantity)
    near = _nearest(w, a, ref_cur)
    err = np.where(near.found, _rel(a, near.value), np.nan)
    return _Compared(
        w=w,
        a=a,
        owner=owner,
        index=np.concatenate([np.arange(len(b)) for b in response.branches]),
        stable=np.concatenate([b.stable for b in response.branches]),
        near=near,
        err=err,
        within=near.found & (err <= tolerance),
    )


def _votes(pts: _Compared, n_branches: int, n_ref: int) -> np.ndarray:
    """``votes[i, j]``: points of response branch ``i`` within tolerance whose nearest
    reference solution is on branch ``j`` (a tie of mirror images votes for each)."""
    votes = np.zeros((n_branches, n_ref), int)
    np.add.at(votes, pts.owner[pts.within], pts.near.ties[pts.within].astype(int))
    return votes


def _match_branches(
    pts: _Compared, votes: np.ndarray, min_share: float
) -> tuple[list[int | None], tuple[int, ...], tuple[int, ...]]:
    """Stage 2: ``(matched, spurious, uncompared)`` -- each response branch's reference branch
    (the one most of its points within tolerance vote for, when at least ``min_share`` of its
    compared points are within tolerance; else None), the branches without a counterpart, and
    those with no compared point."""
    matched: list[int | None] = []
    spurious, uncompared = [], []
    for i in range(votes.shape[0]):
        sel = pts.owner == i
        n_c = int(pts.near.found[sel].sum())
        n_in = int(pts.within[sel].sum())
        if n_c == 0:
            matched.append(None)
            uncompared.append(i)
        elif n_in < min_share * n_c or votes[i].max() == 0:
            matched.append(None)
            spurious.append(i)
        else:
            matched.append(int(np.argmax(votes[i])))
    return matched, tuple(spurious), tuple(uncompared)


@dataclass(frozen=True)
class _OnMatch:
    """Every point of a matched branch against its matched reference branch alone (NaN,
    False or -1 at points of unmatched branches)."""

    on_match: np.ndarray  # bool: covered (a solution of the matched branch, no fold overshoot)
    err_match: np.ndarray  # relative error against it (NaN: not covered)
    check: np.ndarray  # bool: covered and within tolerance (its stability is compared)
    ref_value: np.ndarray  # the nearest solution of the matched branch
    ref_stable: np.ndarray  # its stability flag
    ref_branch: np.ndarray  # the matched reference branch


def _against_matched(
    pts: _Compared,
    reference: Response,
    quantity: str,
    matched: Sequence[int | None],
    folds: Sequence[tuple[int, float, float]],
    tolerance: float,
    fold_overshoot: float,
) -> _OnMatch:
    """Stage 3: each point of a matched branch against the matched reference branch only
    (the nearest solution overall may sit on another branch that happens to pass closer);
    points at the overshooting tip of a displaced fold are not covered."""
    w, a, n = pts.w, pts.a, pts.w.size
    beyond = np.zeros(n, bool)
    check = np.zeros(n, bool)
    ref_value = np.full(n, np.nan)
    ref_stable = np.zeros(n, bool)
    ref_branch = np.full(n, -1)
    on_match = np.zeros(n, bool)
    err_match = np.full(n, np.nan)
    for i, j in enumerate(matched):
        if j is None:
            continue
        sel = np.nonzero(pts.owner == i)[0]
        alone = Response((reference.branches[j],), reference.method)
        one = _nearest(w[sel], a[sel], _curves(alone, quantity, refine_folds=True))
        e_one = np.where(one.found, _rel(a[sel], one.value), np.nan)
        # the tip of an approximate fold that overshoots the reference fold: the reference
        # branch has no counterpart there, only its other side (a point 1e-4 beyond the
        # fold of a Duffing response would be charged with the distance to the lower branch)
        far = ~(e_one <= tolerance)
        for jf, wf, af in folds:
            if jf == j and np.any(far):
                near_fold = (np.abs(a[sel] - af) <= tolerance * af) & (
                    np.abs(w[sel] - wf) <= fold_overshoot * wf
                )
                beyond[sel] |= far & near_fold
        on_match[sel] = one.found & ~beyond[sel]
        err_match[sel] = np.where(on_match[sel], e_one, np.nan)
        check[sel] = one.found & (err_match[sel] <= tolerance)
        ref_value[sel], ref_stable[sel], ref_branch[sel] = one.value, one.stable, j
    return _OnMatch(on_match, err_match, check, ref_value, ref_stable, ref_branch)


def _stability(
    pts: _Compared,
    om: _OnMatch,
    folds: Sequence[tuple[int, float, float]],
    fold_distance: float | None,
    special: np.ndarray,
) -> tuple[tuple[StabilityDisagreement, ...], np.ndarray, np.ndarray]:
    """Stage 4: ``(disagreements, differ, excluded)`` -- the checked points whose stability
    flag differs from the matched reference branch's, leaving out (``excluded``) those within
    ``fold_distance`` of a fold of their reference branch or of a special frequency."""
    w = pts.w
    excluded = np.zeros(w.size, bool)
    if fold_distance is not None:
        for j, wf, _ in folds:
            excluded |= (om.ref_branch == j) & (np.abs(w - wf) <= fold_distance * wf)
        for ws in special:
            excluded |= np.abs(w - ws) <= fold_distance * ws
        excluded &= om.check
    differ = om.check & ~excluded & (pts.stable != om.ref_stable)
    dis = tuple(
        StabilityDisagreement(
            branch=int(pts.owner[k]),
            index=int(pts.index[k]),
            omega=float(w[k]),
            amplitude=float(pts.a[k]),
            stable=bool(pts.stable[k]),
            reference_branch=int(om.ref_branch[k]),
            reference_amplitude=float(om.ref_value[k]),
            reference_stable=bool(om.ref_stable[k]),
        )
        for k in np.nonzero(differ)[0]
    )
    return dis, differ, excluded


def _branch_rows(
    response: Response,
    pts: _Compared,
    om: _OnMatch,
    matched: Sequence[int | None],
    differ: np.ndarray,
) -> tuple[BranchComparison, ...]:
    """Stage 5: one :class:`BranchComparison` per response branch -- errors of a matched
    branch over its covered points against its reference branch, of any other branch over
    its compared points against the nearest reference solution."""
    branches = []
    for i, b in enumerate(response.branches):
        mine = pts.owner == i
        if matched[i] is not None:
            e = om.err_match[mine & om.on_match]
        else:
            e = pts.err[mine & pts.near.found]
        branches.append(
            BranchComparison(
                branch=i,
                points=len(b),
                compared=int((mine & pts.near.found).sum()),
                within=int((pts.within & mine).sum()),
                matched=matched[i],
                covered=int((mine & om.on_match).sum()),
                max_error=float(e.max()) if e.size else float("nan"),
                rms_error=float(np.sqrt(np.mean(e * e))) if e.size else float("nan"),
                stability_disagreements=int((differ & (pts.owner == i)).sum()),
            )
        )
    return tuple(branches)


def _reference_rows(
    response: Response,
    reference: Response,
    ref_cur: _Curves,
    w: np.ndarray,
    quantity: str,
    tolerance: float,
    min_share: float,
    matched: Sequence[int | None],
    votes: np.ndarray,
) -> tuple[tuple[ReferenceBranchComparison, ...], tuple[int, ...], tuple[int, ...]]:
    """Stage 6: ``(rows, missed, outside)`` -- each reference branch's solutions at the
    response's frequencies ``w`` and how many of them the response reproduces within
    tolerance; a branch is missed when fewer than ``min_share`` of them are (or none is
    compared inside the response's span), outside when it lies beyond that span."""
    n_ref = len(reference.branches)
    rw = np.unique(w)
    span = (float(rw[0]), float(rw[-1]))
    ref_compared = np.zeros(n_ref, int)
    ref_reproduced = np.zeros(n_ref, int)
    fi, qa, qb = _crossings(ref_cur, rw)
    if fi.size:
        back = _nearest(rw[fi], qa, _curves(response, quantity))
        ok = back.found & (_rel(back.value, qa) <= tolerance)
        np.add.at(ref_compared, qb, 1)
        np.add.at(ref_reproduced, qb, ok.astype(int))
    missed, outside, ref_rows = [], [], []
    for j, rb in enumerate(reference.branches):
        by = tuple(
            i
            for i, m in enumerate(matched)
            if m is not None and votes[i, j] == votes[i, m] and votes[i, j] > 0
        )
        ref_rows.append(
            ReferenceBranchComparison(
                branch=j,
                points=len(rb),
                compared=int(ref_compared[j]),
                reproduced=int(ref_reproduced[j]),
                matched_by=by,
            )
        )
        if len(rb) == 0:
            continue
        if rb.omega.max() < span[0] or rb.omega.min() > span[1]:
            outside.append(j)
        elif ref_compared[j] == 0 or ref_reproduced[j] < min_share * ref_compared[j]:
            missed.append(j)
    return tuple(ref_rows), tuple(missed), tuple(outside)
