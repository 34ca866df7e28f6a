"""Automatic method choice: the cheapest method that meets a relative tolerance.

``choose_method(osc, window, rtol)`` walks a ladder of candidates ordered by cost — the
first-order symbolic methods (``hb1``, first-order modified L-P ``mlp1``, multiple scales
``ms``, Krylov–Bogoliubov ``kb``), second-order modified L-P ``mlp2``, numeric harmonic
balance with H = 3, 5, 9, 15, 31, 63 harmonics, and finally the exact solver — and stops at
the first one whose amplitudes agree with the exact periodic orbits to ``rtol``.

Spot checks
-----------
The exact orbits are computed at a few *spot frequencies* spread over the window (one
brute-force search per frequency, :func:`perturb.simulate.orbits.search.periodic_orbits`: no exact
sweep of the window), kept away from the folds of the cheap first-order response, where
amplitudes are most sensitive and solutions pair up.  At each spot frequency a candidate's
error is the relative amplitude error (``max |x|``) of the worst-reproduced exact orbit,
each exact orbit matched to the candidate's nearest solution; an exact orbit without any
candidate solution makes the error infinite.  For symbolic methods that give every solution
at a frequency, a candidate solution far from every exact orbit (spurious) counts as well.

A-posteriori estimate
---------------------
Besides the measured spot error, every candidate carries an estimate that needs no exact
solution: the relative amplitude difference to the next-richer harmonic-balance truncation
at the same orbits (H = 3 for the first-order methods, H = 5 for ``mlp2``, ``2H + 1`` for
numeric HB with H harmonics).  Its ratio to the spot error (the *calibration*) is reported,
so a user sees how far the estimate can be trusted for this system.  A candidate is accepted
when both its spot error and its estimate are at most ``rtol``.

Numeric HB at a spot frequency is solved by Newton from the Fourier coefficients of each
exact orbit, so it finds the HB solution that belongs to that orbit; HB solutions with no
exact counterpart are not looked for there.  The full-window HB response is one continuation
run (:func:`perturb.numeric.harmonic_balance.harmonic_balance_response`): branches it does
not connect to (isolas, in-well orbits) may be absent from the curve, and the report says so
when the traced curve misses spot orbits.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from perturb import checks
from perturb.errors import ParameterError, PerturbError
from perturb.model.oscillator import Oscillator
from perturb.response import Branch, Response

__all__ = [
    "Candidate",
    "CandidateResult",
    "AutoChoice",
    "LADDER",
    "check_rtol",
    "check_candidate",
    "derive_candidate",
    "spot_frequencies",
    "exact_spot_orbits",
    "candidate_spot_errors",
    "choose_method",
    "auto_frequency_response",
    "auto_solutions_at",
    "window_estimate",
    "SYSTEM_LADDER",
    "SpotOrbit",
    "exact_system_spot_orbits",
    "system_candidate_spot_errors",
    "system_spot_frequencies",
    "choose_system_method",
    "auto_system_response",
]


@dataclass(frozen=True)
class Candidate:
    """One rung of the ladder: a method and its settings.

    Attributes
    ----------
    name : str
        Short label (``"hb1"``, ``"mlp2"``, ``"hb9"``, ``"exact"``).
    method : str
        The method name of :func:`perturb.frequency_response`.
    order : int or None
        Expansion order of a symbolic method.
    harmonics : int or None
        Harmonics of numeric HB.
    """

    name: str
    method: str
    order: int | None = None
    harmonics: int | None = None

    def settings(self) -> dict[str, Any]:
        """The keyword arguments of :func:`perturb.frequency_response` for this candidate."""
        out: dict[str, Any] = {"method": self.method}
        if self.order is not None:
            out["order"] = self.order
        if self.harmonics is not None:
            out["harmonics"] = self.harmonics
        return out


#: Candidates in order of cost (cheapest first).
LADDER: tuple[Candidate, ...] = (
    Candidate("hb1", "hb1"),
    Candidate("mlp1", "mlp", order=1),
    Candidate("ms", "ms"),
    Candidate("kb", "kb"),
    Candidate("mlp2", "mlp", order=2),
    *(Candidate(f"hb{h}", "hb", harmonics=h) for h in (3, 5, 9, 15, 31, 63)),
    Candidate("exact", "exact"),
)


@dataclass(frozen=True)
class CandidateResult:
    """What the spot checks measured for one candidate.

    Attributes
    ----------
    candidate : Candidate
    spot_errors : tuple of float
        Relative amplitude error at each spot frequency (``inf``: an exact orbit without a
        counterpart, or a spurious solution).
    estimate : float
        The a-posteriori estimate (module docstring); ``nan`` when it could not be formed.
    seconds : float
        CPU time of the candidate's spot evaluation (without the exact orbits).
    note : str
        Why the candidate failed to evaluate, if it did.
    """

    candidate: Candidate
    spot_errors: tuple[float, ...]
    estimate: float
    seconds: float
    note: str = ""
    coordinate_errors: tuple[tuple[str, float], ...] = ()

    @property
    def error(self) -> float:
        """The largest spot error."""
        return max(self.spot_errors) if self.spot_errors else math.inf

    def meets(self, rtol: float) -> bool:
        """Whether spot error and estimate are both within ``rtol``."""
        return self.error <= rtol and not (self.estimate > rtol)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.candidate.name,
            "settings": self.candidate.settings(),
            "spot_errors": [_num(e) for e in self.spot_errors],
            "max_spot_error": _num(self.error),
            "estimate": _num(self.estimate),
            "cpu_seconds": round(self.seconds, 4),
            "note": self.note,
            **(
                {"coordinate_errors": {k: _num(v) for k, v in self.coordinate_errors}}
                if self.coordinate_errors
                else {}
            ),
        }


def _num(x: float) -> float | str:
    # JSON has no inf/nan
    return float(x) if math.isfinite(x) else str(x)


@dataclass(frozen=True)
class AutoChoice:
    """The outcome of :func:`choose_method`.

    Attributes
    ----------
    chosen : CandidateResult
        The first candidate that met ``rtol``.
    rejected : tuple of CandidateResult
        The cheaper candidates tried before it, with their errors.
    rtol : float
    window : tuple of float
    spot_frequencies : tuple of float
    exact_orbits : tuple of int
        Number of exact period-1 orbits found at each spot frequency.
    exact_seconds : float
        CPU time of the exact spot orbits.
    exact_amplitudes : tuple of tuple of float
        Their amplitudes (``max |x|``), per spot frequency.
    window_estimate, window_estimate_at : float
        For numeric HB, after the full-window trace: the largest estimate over points of the
        traced curve (:func:`window_estimate`) and its frequency; ``nan`` otherwise.
    notes : tuple of str
        Remarks added when the full-window response is computed.
    """

    chosen: CandidateResult
    rejected: tuple[CandidateResult, ...]
    rtol: float
    window: tuple[float, float]
    spot_frequencies: tuple[float, ...]
    exact_orbits: tuple[int, ...]
    exact_seconds: float
    exact_amplitudes: tuple[tuple[float, ...], ...] = ()
    window_estimate: float = math.nan
    window_estimate_at: float = math.nan
    notes: tuple[str, ...] = field(default=())

    @property
    def calibration(self) -> float:
        """Spot error over estimate for the chosen candidate (``nan`` if undefined)."""
        e, s = self.chosen.error, self.chosen.estimate
        if not (math.isfinite(s) and s > 0):
            return math.nan
        return e / s

    def summary(self) -> str:
        """Several lines of text for a person."""
        c = self.chosen
        spots = ", ".join(f"{w:.4g}" for w in self.spot_frequencies)
        errs = ", ".join(f"{e:.2e}" for e in c.spot_errors)
        lines = [
            f"auto: chose {c.candidate.name} ({_settings_text(c.candidate)}) for rtol = "
            f"{self.rtol:g}",
            f"  spot checks at Omega = {spots} ({', '.join(map(str, self.exact_orbits))} exact "
            f"orbits, {self.exact_seconds:.1f} s CPU)",
            f"  spot-check errors: {errs} (max {c.error:.2e})",
            *(
                [
                    "  per coordinate (max |.| at the spots): "
                    + ", ".join(f"{k} {v:.2e}" for k, v in c.coordinate_errors)
                ]
                if c.coordinate_errors
                else []
            ),
            f"  estimate (vs next richer HB): {c.estimate:.2e}; calibration error/estimate = "
            f"{self.calibration:.3g}",
        ]
        if math.isfinite(self.window_estimate):
            lines.append(
                f"  estimate over the traced curve: {self.window_estimate:.2e} (largest at "
                f"Omega = {self.window_estimate_at:.4g})"
            )
        for r in self.rejected:
            why = f" ({r.note})" if r.note else ""
            lines.append(
                f"  rejected {r.candidate.name}: spot error {r.error:.2e}, estimate "
                f"{r.estimate:.2e}{why}"
            )
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-serialisable summary."""
        return {
            "rtol": self.rtol,
            "window": list(self.window),
            "chosen": self.chosen.to_dict(),
            "spot_frequencies": list(self.spot_frequencies),
            "exact_orbits_per_spot": list(self.exact_orbits),
            "exact_amplitudes": [list(a) for a in self.exact_amplitudes],
            "exact_cpu_seconds": round(self.exact_seconds, 4),
            "calibration": _num(self.calibration),
            "window_estimate": _num(self.window_estimate),
            "window_estimate_at": _num(self.window_estimate_at),
            "rejected": [r.to_dict() for r in self.rejected],
            "notes": list(self.notes),
        }

    def write_json(self, path: str | Path) -> Path:
        """Write :meth:`to_dict` as JSON to ``path``."""
        from perturb.atomic import write_text

        p = Path(path)
        write_text(p, json.dumps(self.to_dict(), indent=1) + "\n")
        return p


def _settings_text(c: Candidate) -> str:
    return ", ".join(f"{k}={v}" for k, v in c.settings().items())


def check_rtol(rtol: Any) -> float:
    """``rtol`` as a float in ``(0, 1)`` (the registry's check of the option ``rtol`` of
    ``method="auto"``, :func:`perturb.methods.registry.check_rtol`).

    Raises
    ------
    ParameterError
        Naming the bad value.
    """
    from perturb.methods.registry import check_rtol as check

    return check(rtol)


def _away_from_folds(edges: np.ndarray, folds: np.ndarray) -> tuple[float, ...]:
    """The middle of each interval of ``edges``, moved within it as far as it goes from the
    ``folds`` when one is nearer than 3 % of the window (orbits crowd there)."""
    gap = 0.03 * (edges[-1] - edges[0])
    out = []
    for i in range(len(edges) - 1):
        w = 0.5 * (edges[i] + edges[i + 1])
        if folds.size and np.min(np.abs(folds - w)) < gap:
            cand = np.linspace(edges[i], edges[i + 1], 41)[1:-1]
            dist = np.min(np.abs(folds[None, :] - cand[:, None]), axis=1)
            w = cand[int(np.argmax(dist))]
        # rounded so scenes and reports show the frequencies that were used
        out.append(float(f"{w:.6g}"))
    return tuple(out)


def spot_frequencies(
    oscillator: Oscillator, window: Sequence[float], n: int = 4
) -> tuple[float, ...]:
    """``n`` frequencies spread over ``window``, kept away from folds.

    The frequencies start at the midpoints of ``n`` equal parts of the window; one closer
    than 3 % of the window to a fold of the first-order (``hb1``) response moves to the
    farthest point from every fold within its part.  A model ``hb1`` cannot treat keeps the
    plain midpoints.
    """
    lo, hi = checks.window(window)
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 50:
        raise ParameterError(f"n = {n!r}: expected an integer number of spot checks in [1, 50]")
    edges = np.linspace(lo, hi, n + 1)
    try:
        from perturb.solve import frequency_response

        folds = np.array([w for w, _ in frequency_response(oscillator, "hb1", (lo, hi)).folds])
    except PerturbError:
        folds = np.empty(0)
    return _away_from_folds(edges, folds)


def exact_spot_orbits(oscillator: Oscillator, frequencies: Sequence[float]) -> list[list[Any]]:
    """Every exact period-1 orbit at each frequency (one brute-force search each)."""
    from perturb.solve import periodic_orbits

    return [[o for o in periodic_orbits(oscillator, float(w)) if o.m == 1] for w in frequencies]


def _coefficients(orbit: Any, H: int, Omega: float) -> np.ndarray:
    """HB coefficients ``[a0, a1, b1, ...]`` of an exact orbit (phase of cos(Omega t))."""
    n = max(256, 8 * H)
    t, x, _ = orbit.sample(n)
    th = Omega * t
    u = [float(np.mean(x))]
    for k in range(1, H + 1):
        u += [2.0 * float(np.mean(x * np.cos(k * th))), 2.0 * float(np.mean(x * np.sin(k * th)))]
    return np.array(u)


def _hb_amplitudes(oscillator: Oscillator, H: int, w: float, orbits: Sequence[Any]) -> list[float]:
    """HB amplitude (``max |x|``) near each exact orbit; ``nan`` where Newton fails."""
    from perturb.numeric.harmonic_balance import harmonic_balance_orbit

    out = []
    for o in orbits:
        try:
            s = harmonic_balance_orbit(
                oscillator, w, harmonics=H, guess=_coefficients(o, H, w), stability="none"
            )
            out.append(float(s.amplitude))
        except PerturbError:
            out.append(math.nan)
    return out


def _rel(a: float, r: float) -> float:
    if not (math.isfinite(a) and math.isfinite(r)):
        return math.inf
    return abs(a - r) / abs(r) if r != 0 else (0.0 if a == 0 else math.inf)


def _hausdorff(found: Sequence[float], exact: Sequence[float], two_sided: bool) -> float:
    """Worst relative amplitude error matching every exact value to its nearest found one
    (and, ``two_sided``, every found value to its nearest exact one)."""
    if not exact:
        return 0.0 if not (two_sided and found) else math.inf
    if not found:
        return math.inf
    err = max(min(_rel(a, r) for a in found) for r in exact)
    if two_sided:
        err = max(err, max(min(_rel(a, r) for r in exact) for a in found))
    return err


def check_candidate(c: Candidate) -> Candidate:
    """``c`` checked against the method registry before any work: a method
    :func:`perturb.solve.frequency_response` knows (not ``"auto"`` itself), with an order and
    harmonics that method takes and within its limits.

    Raises
    ------
    ParameterError
        Naming the rung and what is wrong.
    """
    from perturb.methods.registry import spec

    try:
        s = spec(c.method)
        if s.kind == "auto":
            raise ParameterError("'auto' cannot be a rung of its own ladder")
        s.validate({"order": c.order, "harmonics": c.harmonics})
    except ParameterError as exc:
        raise ParameterError(f"ladder rung {c.name!r}: {exc}") from None
    return c


def derive_candidate(c: Candidate, oscillator: Oscillator):
    """The approximation of a symbolic rung ``c`` for ``oscillator`` (through the one
    dispatcher, :func:`perturb.solve.derive`, with the derivation cache).

    Raises
    ------
    ParameterError
        When ``c.method`` is not a symbolic method.
    """
    from perturb.solve import derive

    return derive(oscillator, c.method, use_cache=True, order=c.order)


def _is_polynomial(approx: Any) -> bool:
    poly = approx.frequency_polynomial
    return poly is not None and len(poly) <= 3 and approx.slow_flow is not None


def candidate_spot_errors(
    oscillator: Oscillator,
    candidate: Candidate,
    frequencies: Sequence[float],
    orbits: Sequence[Sequence[Any]],
    window: Sequence[float] | None = None,
) -> CandidateResult:
    """Spot errors and estimate of ``candidate`` against the exact ``orbits``.

    Parameters
    ----------
    oscillator : Oscillator
    candidate : Candidate
    frequencies : sequence of float
        The spot frequencies.
    orbits : sequence of sequences of PeriodicOrbit
        The exact period-1 orbits at each frequency (:func:`exact_spot_orbits`).
    window : (float, float), optional
        Needed only by methods traced by residual continuation (``mlp2``), whose solutions
        at the spot frequencies are read off the traced curve; default: the span of the spots
        widened by 10 %.

    Returns
    -------
    CandidateResult
    """
    t0 = time.process_time()
    exact_amp = [[float(o.amplitude) for o in row] for row in orbits]
    ws = [float(w) for w in frequencies]
    if candidate.method == "exact":
        # the reference itself: its spot error is zero by construction
        zeros = tuple(0.0 for _ in ws)
        return CandidateResult(candidate, zeros, 0.0, time.process_time() - t0, "reference")
    try:
        if candidate.method == "hb":
            H = int(candidate.harmonics or 15)
            found = [_hb_amplitudes(oscillator, H, w, o) for w, o in zip(ws, orbits, strict=True)]
            richer = [
                _hb_amplitudes(oscillator, 2 * H + 1, w, o) for w, o in zip(ws, orbits, strict=True)
            ]
            errs = tuple(
                max((_rel(a, r) for a, r in zip(f, e, strict=True)), default=0.0)
                for f, e in zip(found, exact_amp, strict=True)
            )
            est = max(
                (
                    _rel(a, r)
                    for f, g in zip(found, richer, strict=True)
                    for a, r in zip(f, g, strict=True)
                ),
                default=0.0,
            )
            return CandidateResult(candidate, errs, est, time.process_time() - t0)
        approx = derive_candidate(candidate, oscillator)
        H_ref = 3 if candidate.order in (None, 1) else 5
        ref = [_hb_amplitudes(oscillator, H_ref, w, o) for w, o in zip(ws, orbits, strict=True)]
        if _is_polynomial(approx):
            from perturb.numeric.amplitude import solutions_at

            resp = solutions_at(approx, ws)
            found = [[] for _ in ws]
            for b in resp.branches:
                for w, a in zip(b.omega, b.amplitude, strict=True):
                    found[ws.index(float(w))].append(float(a))
            errs = tuple(_hausdorff(f, e, True) for f, e in zip(found, exact_amp, strict=True))
            est = max(
                (_hausdorff(f, [r], False) for f, g in zip(found, ref, strict=True) for r in g),
                default=0.0,
            )
        else:
            from perturb.comparison import relative_errors
            from perturb.numeric.residual import residual_response

            if window is None:
                window = (0.9 * min(ws), 1.1 * max(ws))
            traced = residual_response(approx, tuple(window))
            errs, est = _traced_errors(traced, ws, exact_amp, ref, relative_errors)
        return CandidateResult(candidate, errs, est, time.process_time() - t0)
    except PerturbError as exc:
        inf = tuple(math.inf for _ in ws)
        return CandidateResult(candidate, inf, math.nan, time.process_time() - t0, str(exc))


def _points_response(ws: Sequence[float], amps: Sequence[Sequence[float]]) -> Response | None:
    """Isolated points as one-point branches (for :func:`relative_errors`)."""
    branches = [
        Branch([w], [a], [a], [0.0], [True], [0.0])
        for w, row in zip(ws, amps, strict=True)
        for a in row
        if math.isfinite(a)
    ]
    return Response(tuple(branches), "points") if branches else None


def _traced_errors(traced, ws, exact_amp, ref, relative_errors):
    """Errors of a traced curve at the spot frequencies (one-sided: exact -> curve)."""
    errs = []
    for w, row in zip(ws, exact_amp, strict=True):
        pts = _points_response([w], [row])
        if pts is None:
            errs.append(0.0)
            continue
        e = relative_errors(pts, traced)
        errs.append(float(np.max(np.where(np.isfinite(e), e, np.inf))))
    pts = _points_response(ws, ref)
    est = math.nan
    if pts is not None:
        e = relative_errors(pts, traced)
        est = float(np.max(np.where(np.isfinite(e), e, np.inf)))
    return tuple(errs), est


def _spot_line(cand: Candidate, res: CandidateResult) -> str:
    """The log line of one rung's spot check."""
    note = f" ({res.note})" if res.note and res.note != "reference" else ""
    return (
        f"{cand.name}: spot error {res.error:.2e}, estimate {res.estimate:.2e}, "
        f"{res.seconds:.2f} s CPU{note}"
    )


def choose_method(
    oscillator: Oscillator,
    window: Sequence[float],
    rtol: float,
    *,
    spots: Sequence[float] | None = None,
    n_spots: int = 4,
    ladder: Sequence[Candidate] = LADDER,
    log=None,
) -> AutoChoice:
    """The cheapest candidate of ``ladder`` whose spot checks meet ``rtol``.

    Parameters
    ----------
    oscillator : Oscillator
        A forced oscillator with parameter values.
    window : (float, float)
        The frequency window ``(low, high)``.
    rtol : float
        Relative amplitude tolerance in ``(0, 1)``.
    spots : sequence of float, optional
        Spot frequencies (default :func:`spot_frequencies` with ``n_spots``).
    n_spots : int
        Number of spot frequencies when ``spots`` is not given (default 4).
    ladder : sequence of Candidate
        Candidates, cheapest first (default :data:`LADDER`); the exact solver always ends it.
    log : callable, optional
        Called with a line of text per candidate tried.

    Returns
    -------
    AutoChoice

    Raises
    ------
    ParameterError
        Bad ``rtol``, window or spot frequencies.
    """
    return _choose(oscillator, window, rtol, spots, n_spots, ladder, log)[0]


def _skip_reason(cand: Candidate, tried: Sequence[CandidateResult], rtol: float) -> str:
    """Why a higher-order expansion is not worth its cost here ('' if it is).

    A second order improves on the first by about one power of the small parameter; when the
    first order of the same method misses by more than 100 x rtol, the second will not close
    the gap, and its residual continuation costs more than every HB truncation together."""
    if cand.order is None or cand.order < 2:
        return ""
    for r in tried:
        c = r.candidate
        if c.method == cand.method and c.order in (None, cand.order - 1) and r.error > 100 * rtol:
            return f"skipped: order {cand.order - 1} misses by {r.error:.2e} > 100 x rtol"
    return ""


def _choose(
    oscillator, window, rtol, spots, n_spots, ladder, log, known=None, before=(), exact_s=0.0
):
    """:func:`choose_method`; ``known`` caches exact orbits by frequency (filled in here),
    ``before`` are results of cheaper rungs already rejected (reported, not re-run)."""
    known = {} if known is None else known
    rtol = check_rtol(rtol)
    lo, hi = checks.window(window)
    for c in ladder:  # before any work
        check_candidate(c)
    if spots is None:
        spots = spot_frequencies(oscillator, (lo, hi), n_spots)
    try:
        ws = tuple(float(w) for w in spots)
    except (TypeError, ValueError):
        raise ParameterError(f"spots = {spots!r}: expected positive frequencies") from None
    if not ws or not all(math.isfinite(w) and w > 0 for w in ws) or len(set(ws)) != len(ws):
        raise ParameterError(f"spots = {spots!r}: expected distinct positive frequencies")
    t0 = time.process_time()
    missing = [w for w in ws if w not in known]
    known.update(zip(missing, exact_spot_orbits(oscillator, missing), strict=True))
    orbits = [known[w] for w in ws]
    exact_s += time.process_time() - t0
    ladder = [c for c in ladder if c.method != "exact"] + [Candidate("exact", "exact")]
    tried = list(before)
    for cand in ladder:
        skip = _skip_reason(cand, tried, rtol)
        if skip:
            res = CandidateResult(cand, tuple(math.inf for _ in ws), math.nan, 0.0, skip)
            tried.append(res)
            if log is not None:
                log(f"{cand.name}: {skip}")
            continue
        res = candidate_spot_errors(oscillator, cand, ws, orbits, (lo, hi))
        if log is not None:
            log(_spot_line(cand, res))
        if res.meets(rtol):
            choice = AutoChoice(
                res,
                tuple(tried),
                rtol,
                (lo, hi),
                ws,
                tuple(len(o) for o in orbits),
                exact_s,
                tuple(tuple(float(o.amplitude) for o in row) for row in orbits),
            )
            return choice, [(w, o) for w, row in zip(ws, orbits, strict=True) for o in row]
        tried.append(res)
    raise AssertionError("unreachable: the exact candidate always meets rtol")


def _hb_multistart(
    oscillator: Oscillator, H: int, window: tuple[float, float], orbits: Sequence[tuple[float, Any]]
) -> Response:
    """Numeric HB traced from the high end of the window and through every exact spot orbit
    the curves so far do not pass near (both ways from it until the branch leaves the window
    or closes), so branches that one continuation run would not reach (in-well orbits,
    isolas) are on the curve too."""
    from perturb.comparison import relative_errors
    from perturb.numeric.harmonic_balance import (
        harmonic_balance_branch,
        harmonic_balance_branch_through,
        harmonic_balance_orbit,
    )

    lo, hi = window
    raw = [harmonic_balance_branch(oscillator, window, harmonics=H)]
    parts = [raw[0].to_response()]

    def covered(w: float, a: float) -> bool:
        pts = _points_response([w], [[a]])
        for r in parts:
            e = relative_errors(pts, r)
            if np.isfinite(e[0]) and e[0] < 0.02:
                return True
        return False

    for w, orbit in orbits:
        if covered(w, float(orbit.amplitude)):
            continue
        try:
            sol = harmonic_balance_orbit(
                oscillator, w, harmonics=H, guess=_coefficients(orbit, H, w), stability="none"
            )
        except PerturbError:
            continue
        try:
            br = harmonic_balance_branch_through(raw[0].system, sol.coefficients, sol.Omega, window)
        except PerturbError:
            continue
        raw.append(br)
        parts.append(br.to_response())
    first = parts[0]
    branches = tuple(b for r in parts for b in r.branches if len(b) > 1)
    folds = tuple(f for r in parts for f in r.folds)
    notes = tuple(first.notes) + (
        f"{len(parts)} continuation runs: from the window's high end and from exact spot orbits",
    )
    resp = Response(branches, first.method, first.model, dict(first.params), folds, notes)
    return resp, raw


def window_estimate(
    oscillator: Oscillator, branches: Sequence[Any], samples: int = 32
) -> tuple[float, float]:
    """The a-posteriori estimate between the spot frequencies for numeric HB.

    At up to ``samples`` points spread over the traced HB branches (H harmonics), HB with
    ``2H + 1`` harmonics is solved at the same frequency from the point's coefficients; the
    largest relative amplitude difference, and the frequency where it occurs, are returned
    (``(nan, nan)`` when no point could be re-solved).  Points next to a fold are skipped:
    there the amplitude at fixed frequency is ill-conditioned and Newton may change branch.

    Parameters
    ----------
    oscillator : Oscillator
    branches : sequence of HarmonicBalanceBranch
    samples : int

    Returns
    -------
    (float, float)
        ``(estimate, Omega)``.
    """
    from perturb.numeric.harmonic_balance import harmonic_balance_orbit

    pts = [(b, j) for b in branches for j in range(len(b))]
    if not pts:
        return math.nan, math.nan
    pick = np.unique(np.linspace(0, len(pts) - 1, min(samples, len(pts))).round().astype(int))
    worst, where = math.nan, math.nan
    for i in pick:
        b, j = pts[int(i)]
        w = float(b.omega[j])
        if any(abs(w - wf) < 0.01 * w for wf, _ in b.folds):
            continue
        H = b.system.harmonics
        u = np.zeros(1 + 2 * (2 * H + 1))
        u[: b.coefficients.shape[1]] = b.coefficients[j]
        try:
            s = harmonic_balance_orbit(
                oscillator, w, harmonics=2 * H + 1, guess=u, stability="none"
            )
        except PerturbError:
            continue
        e = _rel(float(b.amplitude[j]), float(s.amplitude))
        if not (e <= worst):  # also replaces the initial nan
            worst, where = e, w
    return worst, where


def _full_response(
    oscillator: Oscillator,
    c: Candidate,
    window: tuple[float, float],
    points: int,
    orbits: Sequence[tuple[float, Any]] = (),
) -> Response:
    from perturb.solve import frequency_response

    if c.method == "hb":
        return _hb_multistart(oscillator, int(c.harmonics or 15), window, orbits)
    if c.method == "exact":
        return frequency_response(oscillator, "exact", window)
    from perturb.solve import trace_approximation

    return trace_approximation(derive_candidate(c, oscillator), window, points=points)


def _coverage_notes(resp: Response, choice: AutoChoice) -> tuple[str, ...]:
    """Say when the traced curve misses spot orbits the spot checks did verify."""
    from perturb.comparison import relative_errors

    pts = _points_response(choice.spot_frequencies, choice.exact_amplitudes)
    if pts is None or not resp.branches:
        return ()
    e = relative_errors(pts, resp)
    bad = int(np.sum(~np.isfinite(e) | (e > 0.05)))
    if bad:
        return (
            f"the traced {choice.chosen.candidate.name} curve passes near {e.size - bad} of "
            f"{e.size} exact spot orbits: branches not connected to the traced one are missing "
            "(their method was verified at the spot frequencies)",
        )
    return ()


def auto_frequency_response(
    oscillator: Oscillator,
    window: Sequence[float],
    rtol: float,
    *,
    spots: Sequence[float] | None = None,
    n_spots: int = 4,
    points: int = 2000,
    ladder: Sequence[Candidate] = LADDER,
    log=None,
    max_extra_spots: int = 3,
    frequencies: Sequence[float] | None = None,
    output: str | None = None,
) -> tuple[Response, AutoChoice]:
    """Choose the method (:func:`choose_method`), then trace only it over ``window``.

    A :class:`~perturb.model.system.System` goes to :func:`auto_system_response` (with
    ``output``; :data:`SYSTEM_LADDER` unless a ladder is given).

    Parameters
    ----------
    oscillator, window, rtol, spots, n_spots, ladder, log
        As in :func:`choose_method`.
    points : int
        Curve resolution of amplitude-parametrised methods.
    max_extra_spots : int
        Spot checks that may be added where the estimate along a traced HB curve exceeds
        ``rtol`` (default 3).
    frequencies : sequence of float, optional
        Answer at exactly these frequencies instead of tracing ``window``
        (:func:`auto_solutions_at`; ``window`` and ``points`` are then not used).

    Returns
    -------
    (Response, AutoChoice)
        The response's ``notes`` start with the choice (method, estimate, spot errors).
    Notes
    -----
    When the chosen method is numeric HB, the estimate is also formed along the traced
    curve (:func:`window_estimate`).  Where it exceeds ``rtol`` — the spot frequencies were
    a sample and missed the hardest part of the window — that frequency becomes one more
    spot check (exact orbits there) and the ladder resumes at the chosen rung, at most
    ``max_extra_spots`` times; what remains is reported in the notes.
    """
    from perturb.solve import is_system

    if is_system(oscillator):
        return auto_system_response(
            oscillator,
            window,
            rtol,
            output=output,
            spots=spots,
            n_spots=n_spots,
            ladder=SYSTEM_LADDER if ladder is LADDER else ladder,
            log=log,
            frequencies=frequencies,
        )
    if frequencies is not None:
        return auto_solutions_at(
            oscillator, frequencies, rtol, spots=spots, n_spots=n_spots, ladder=ladder, log=log
        )
    known: dict[float, list] = {}
    exact_s = 0.0
    ladder = list(ladder)
    before: tuple[CandidateResult, ...] = ()
    extra: list[str] = []
    for attempt in range(max_extra_spots + 1):
        choice, orbits = _choose(
            oscillator, window, rtol, spots, n_spots, ladder, log, known, before, exact_s
        )
        exact_s = choice.exact_seconds
        spots = choice.spot_frequencies
        lo, hi = choice.window
        cand = choice.chosen.candidate
        resp = _full_response(oscillator, cand, (lo, hi), points, orbits)
        notes: tuple[str, ...] = ()
        if cand.method != "hb":
            break
        resp, raw = resp
        choice, w_new, notes = _traced_estimate(
            oscillator, raw, choice, spots, last=attempt == max_extra_spots
        )
        if w_new is None:
            break
        msg = (
            f"{cand.name}: estimate {choice.window_estimate:.2e} > rtol on the traced curve at "
            f"Omega = {w_new:g}: exact spot check added there"
        )
        extra.append(msg)
        if log is not None:
            log(msg)
        spots = (*spots, w_new)
        # resume at the chosen rung: the cheaper ones already failed at the other spots
        i = next(j for j, c in enumerate(ladder) if c == cand)
        before = choice.rejected
        ladder = ladder[i:]
    choice = _with_notes(choice, tuple(extra) + notes + _coverage_notes(resp, choice))
    return _headed(resp, choice), choice


def _traced_estimate(
    oscillator: Oscillator,
    raw,
    choice: AutoChoice,
    spots: tuple[float, ...],
    *,
    last: bool,
) -> tuple[AutoChoice, float | None, tuple[str, ...]]:
    """One check of a chosen numeric HB along its traced curve (:func:`window_estimate`).

    Parameters
    ----------
    raw
        The traced HB solution (second item of :func:`_full_response` for HB).
    choice
        The choice; returned with ``window_estimate`` and ``window_estimate_at`` filled in.
    spots
        The spot frequencies checked so far.
    last
        No more spot checks may be added (``max_extra_spots`` reached).

    Returns
    -------
    (choice, w_new, notes)
        ``w_new``: the frequency (6 significant digits) where the estimate exceeds ``rtol``,
        to become one more spot check; None when the estimate is within ``rtol``, when that
        frequency is already a spot (the estimate is pessimistic there), or when ``last`` --
        the last two cases with a note saying so.
    """
    est, at = window_estimate(oscillator, raw)
    choice = dataclasses.replace(choice, window_estimate=est, window_estimate_at=at)
    if not est > choice.rtol:
        return choice, None, ()
    w_new = float(f"{at:.6g}")
    if w_new in spots:
        err_there = choice.chosen.spot_errors[spots.index(w_new)]
        note = (
            f"the estimate along the traced curve reaches {est:.2e} at Omega = {w_new:g}, "
            f"where the exact spot check gives {err_there:.2e} <= rtol: the estimate is "
            "pessimistic there (or follows an orbit the exact search did not find)"
        )
        return choice, None, (note,)
    if last:
        note = (
            f"between the spot frequencies the estimate reaches {est:.2e} > rtol "
            f"(at Omega = {at:.4g}): add spot frequencies there or tighten rtol"
        )
        return choice, None, (note,)
    return choice, w_new, ()


def _headed(resp: Response, choice: AutoChoice) -> Response:
    """``resp`` with the choice's summary heading its notes (what was chosen, and why)."""
    head = tuple(choice.summary().splitlines())
    return Response(
        resp.branches,
        resp.method,
        resp.model,
        dict(resp.params),
        folds=resp.folds,
        notes=head + tuple(resp.notes),
    )


def auto_solutions_at(
    oscillator: Oscillator,
    frequencies: Sequence[float],
    rtol: float,
    *,
    spots: Sequence[float] | None = None,
    n_spots: int = 4,
    ladder: Sequence[Candidate] = LADDER,
    log=None,
) -> tuple[Response, AutoChoice]:
    """The cheapest method that meets ``rtol``, answering at exactly ``frequencies``.

    The spot checks run at the requested frequencies themselves when there are at most
    ``n_spots`` of them (the error is measured where the answer is given), else at
    :func:`spot_frequencies` over the window they span; the chosen method then answers at
    every requested frequency (:func:`perturb.solve.frequency_response` with
    ``frequencies=``).

    Returns
    -------
    (Response, AutoChoice)
        The response's ``notes`` start with the choice (method, estimate, spot errors).
    """
    from perturb.methods.registry import MAX_FREQUENCIES
    from perturb.solve import frequency_response

    targets = checks.frequencies(frequencies, MAX_FREQUENCIES)
    unique = sorted(set(targets))
    # a window around the frequencies (also for a single one), for the spot checks
    window = (unique[0] * (1 - 0.02), unique[-1] * (1 + 0.02))
    if spots is None and len(unique) <= n_spots:
        spots = unique
    choice, _ = _choose(oscillator, window, rtol, spots, n_spots, ladder, log)
    cand = choice.chosen.candidate
    settings = cand.settings()
    method = settings.pop("method")
    resp = frequency_response(oscillator, method, frequencies=targets, **settings)
    head = tuple(choice.summary().splitlines())
    resp = Response(
        resp.branches,
        resp.method,
        resp.model,
        dict(resp.params),
        folds=resp.folds,
        notes=head + tuple(resp.notes),
    )
    return resp, choice


def _with_notes(choice: AutoChoice, notes: tuple[str, ...]) -> AutoChoice:
    if not notes:
        return choice
    return dataclasses.replace(choice, notes=choice.notes + notes)


# ------------------------------------------------------------------------------------------
# Systems of several coordinates: the same ladder with exact spot checks in n dimensions
# ------------------------------------------------------------------------------------------
#: The ladder of a :class:`~perturb.model.system.System`, cheapest first: the symbolic
#: single-harmonic balance of systems, numeric multi-harmonic balance with H = 3 ... 63,
#: the exact solver.
SYSTEM_LADDER: tuple[Candidate, ...] = (
    Candidate("hb1", "hb1"),
    # averaging: the slow flow of two coordinates with a 1:1 or 1:3 internal resonance (a
    # system it does not fit is skipped with the derivation's reason)
    Candidate("ms-ir", "ms-ir"),
    *(Candidate(f"hb{h}", "hb", harmonics=h) for h in (3, 7, 15, 31, 63)),
    Candidate("exact", "exact"),
)


@dataclass(frozen=True)
class SpotOrbit:
    """What a spot check measures on one exact orbit of a system.

    Attributes
    ----------
    orbit
        The exact :class:`~perturb.simulate.orbits.shooting.PeriodicOrbit`.
    output : float
        ``max |c . y|`` of the output combination.
    coordinates : tuple of (str, float)
        ``max |.|`` of every coordinate.
    """

    orbit: Any
    output: float
    coordinates: tuple[tuple[str, float], ...]


def _system_measures(system: Any, c: np.ndarray) -> Any:
    from perturb.solve import system_coordinates

    names = system.state_names
    coords = system_coordinates(system)
    eye = np.eye(len(names))

    def measure(orbit: Any) -> SpotOrbit:
        return SpotOrbit(
            orbit,
            float(orbit.max_abs(c)),
            tuple((n, float(orbit.max_abs(eye[names.index(n)]))) for n in coords),
        )

    return measure


def exact_system_spot_orbits(
    system: Any, frequencies: Sequence[float], output: str | None = None
) -> list[list[SpotOrbit]]:
    """Every exact period-1 orbit of ``system`` at each frequency
    (:func:`perturb.solve.periodic_orbits`: linear-part, transient and random starts, shooting
    on the exact flow), with the ``max |.|`` of the output and of every coordinate."""
    from perturb.solve import periodic_orbits, system_output

    c, _ = system_output(system, output)
    measure = _system_measures(system, c)
    return [
        [measure(o) for o in periodic_orbits(system, float(w), output=output) if o.m == 1]
        for w in frequencies
    ]


def _system_coefficients(system: Any, orbit: Any, H: int, Omega: float) -> np.ndarray:
    """Balance coefficients ``(n2 + n1, 2H + 1)`` (``[a0, a1, b1, ...]`` of cos/sin
    ``k Omega t``) of an exact orbit's coordinates and first-order states."""
    n = max(256, 8 * H)
    t, Y = orbit.sample_states(n)
    n2 = len(system.coordinates)
    rows = np.concatenate([Y[:n2], Y[2 * n2 :]])
    th = Omega * t
    out = np.empty((rows.shape[0], 2 * H + 1))
    out[:, 0] = rows.mean(axis=1)
    for k in range(1, H + 1):
        out[:, 2 * k - 1] = 2.0 * (rows * np.cos(k * th)).mean(axis=1)
        out[:, 2 * k] = 2.0 * (rows * np.sin(k * th)).mean(axis=1)
    return out


def _solution_measures(system: Any, sol: Any, c: np.ndarray) -> tuple[float, dict[str, float]]:
    """``max |.|`` of the output combination ``c`` and of every coordinate of a balance
    solution (:class:`~perturb.numeric.system_balance.SystemBalanceSolution`)."""
    from perturb.numeric.system_balance import SystemBalanceSolution

    n2 = len(system.coordinates)
    U = sol.U
    w = sol.Omega / sol.m
    # the output's series: positions and first-order states enter as they are, velocities
    # through the derivative of each harmonic (a_k, b_k) -> (k b_k, -k a_k)
    alpha = np.concatenate([c[:n2], c[2 * n2 :]])
    beta = c[n2 : 2 * n2]
    s = alpha @ U
    if np.any(beta):
        k = np.arange(1, (U.shape[1] - 1) // 2 + 1)
        dU = np.zeros_like(U[:n2])
        dU[:, 1::2] = k * U[:n2, 2::2]
        dU[:, 2::2] = -k * U[:n2, 1::2]
        s = s + w * (beta @ dU)
    series = SystemBalanceSolution(sol.Omega, s[None, :], ("output",), sol.basis, sol.m, None, 1)
    return float(series.max_abs()["output"]), sol.max_abs()


def _system_candidate_at(
    system: Any,
    H: int,
    w: float,
    spots: Sequence[SpotOrbit],
    c: np.ndarray,
    zero_mean: bool,
    residuals: Any = None,
) -> list[tuple[float, dict[str, float]] | None]:
    """The balance solution with ``H`` harmonics started from each exact orbit's Fourier
    coefficients (it belongs to that orbit), measured; None where Newton fails, where the
    ansatz has no mean but the solution has one, or where ``residuals`` (a system's symbolic
    single-harmonic residuals) do not vanish at it."""
    from perturb.numeric.system_balance import system_balance_orbit

    out: list[tuple[float, dict[str, float]] | None] = []
    for sp in spots:
        guess = _system_coefficients(system, sp.orbit, H, w)
        if zero_mean:
            guess[:, 0] = 0.0
        try:
            sol = system_balance_orbit(system, w, harmonics=H, guess=guess, stability=False)
        except PerturbError:
            out.append(None)
            continue
        size = max(1.0, float(np.abs(sol.U).max()))
        if zero_mean and float(np.abs(sol.U[:, 0]).max()) > 1e-7 * size:
            out.append(None)
            continue
        if residuals is not None:
            R = float(np.abs(residuals(sol.U[None, :, :3], np.array([w]))).max())
            if not R <= 1e-7 * size:
                out.append(None)
                continue
        out.append(_solution_measures(system, sol, c))
    return out


def _spot_errors(
    spots: Sequence[SpotOrbit], found: Sequence[tuple[float, dict[str, float]] | None]
) -> tuple[float, dict[str, float]]:
    """The output's error at one frequency (each exact orbit against its own solution, else
    the nearest other one found there; ``inf`` without any) and each coordinate's."""
    valid = [f for f in found if f is not None]
    worst = 0.0
    coord: dict[str, float] = {}
    for sp, own in zip(spots, found, strict=True):
        if own is None:
            if not valid:
                worst = math.inf
                for n, _ in sp.coordinates:
                    coord[n] = math.inf
                continue
            own = min(valid, key=lambda f, sp=sp: _rel(f[0], sp.output))
        worst = max(worst, _rel(own[0], sp.output))
        for n, a in sp.coordinates:
            coord[n] = max(coord.get(n, 0.0), _rel(own[1][n], a))
    return worst, coord


def system_candidate_spot_errors(
    system: Any,
    candidate: Candidate,
    frequencies: Sequence[float],
    orbits: Sequence[Sequence[SpotOrbit]],
    output: str | None = None,
    derivation: Any = None,
) -> CandidateResult:
    """Spot errors of ``candidate`` on a system against the exact ``orbits``
    (:func:`exact_system_spot_orbits`): at each spot frequency the relative error of the
    output's ``max |.|`` (what decides), and per coordinate the largest over the spots
    (``coordinate_errors``); the estimate is the difference to the next richer balance
    (``2H + 1`` harmonics; ``H = 3`` for ``hb1``) at the same orbits.

    ``hb1`` is the symbolic single-harmonic balance of the system: its solutions at a spot are
    those of the balance with one harmonic (the same equations), checked on the symbolic
    residuals of ``derivation`` (:func:`perturb.methods.system_harmonic_balance.
    system_single_harmonic_balance`), zero means when the derivation has no bias.
    """
    from perturb.solve import (
        SYSTEM_ONLY_METHODS,
        system_output,
        system_single_harmonic_residuals,
    )

    t0 = time.process_time()
    ws = [float(w) for w in frequencies]
    if candidate.method == "exact":
        zeros = tuple(0.0 for _ in ws)
        return CandidateResult(candidate, zeros, 0.0, time.process_time() - t0, "reference")
    c, _ = system_output(system, output)
    try:
        if candidate.method in SYSTEM_ONLY_METHODS:
            return _slow_flow_spot_errors(system, candidate, ws, orbits, c, derivation, t0)
        if candidate.method in ("hb1", "shb"):
            if derivation is None:
                from perturb.methods.system_harmonic_balance import (
                    system_single_harmonic_balance,
                )

                derivation = system_single_harmonic_balance(system)
            H, richer_H = 1, 3
            zero_mean = not derivation.biases
            residuals = system_single_harmonic_residuals(derivation)
        elif candidate.method == "hb":
            H = int(candidate.harmonics or 15)
            richer_H, zero_mean, residuals = 2 * H + 1, False, None
        else:
            raise ParameterError(
                f"ladder rung {candidate.name!r}: method {candidate.method!r} does not take a "
                "system (expected hb1, hb or exact)"
            )
        errs, est = [], 0.0
        coord: dict[str, float] = {}
        for w, spots in zip(ws, orbits, strict=True):
            found = _system_candidate_at(system, H, w, spots, c, zero_mean, residuals)
            e, ce = _spot_errors(spots, found)
            errs.append(e)
            for k, v in ce.items():
                coord[k] = max(coord.get(k, 0.0), v)
            richer = _system_candidate_at(system, richer_H, w, spots, c, False)
            for f, g in zip(found, richer, strict=True):
                if f is not None and g is not None:
                    est = max(est, _rel(f[0], g[0]))
        return CandidateResult(
            candidate, tuple(errs), est, time.process_time() - t0, "", tuple(coord.items())
        )
    except PerturbError as exc:
        inf = tuple(math.inf for _ in ws)
        return CandidateResult(candidate, inf, math.nan, time.process_time() - t0, str(exc))


def _slow_flow_guess(solver: Any, orbit: Any, W: float) -> np.ndarray:
    """The slow flow's Cartesian amplitudes of an exact orbit: its coordinates in modal form
    ``eta = Phi^-1 q`` projected on ``cos nu_k t`` and ``sin nu_k t`` of each mode's frame
    frequency, over the slow flow's period (the orbit's samples repeated to fill it)."""
    import sympy as sp

    flow = solver.flow
    Wsym = flow.arguments[len(flow.cartesian)]
    subs = {Wsym: W, **{p: v for p, v in zip(flow.parameters, solver._values, strict=True)}}
    nus = [float(sp.sympify(nu).subs(subs)) for nu in flow.frame_frequencies]
    Phi = np.array(sp.Matrix(flow.modal_matrix).subs(subs).evalf(), dtype=float)
    n = 512
    t, Y = orbit.sample_states(n)
    T = float(orbit.period)
    reps = max(1, round(2 * np.pi / min(nus) / T))
    t = np.concatenate([t + k * T for k in range(reps)])
    q = np.tile(Y[: Phi.shape[0]], reps)
    eta = np.linalg.solve(Phi, q)
    out = []
    for k, nu in enumerate(nus):
        out += [2 * np.mean(eta[k] * np.cos(nu * t)), 2 * np.mean(eta[k] * np.sin(nu * t))]
    return np.array(out)


def _slow_flow_spot_errors(system, candidate, ws, orbits, c, derivation, t0) -> CandidateResult:
    """Spot errors of the internal-resonance slow flow (``"ms-ir"``): its fixed point by
    Newton from each exact orbit's modal amplitudes, measured like a balance solution; the
    estimate against the balance with H = 3 at the same orbits."""
    from perturb.solve import SlowFlowSolver

    solver = SlowFlowSolver(derivation, system)
    errs, est = [], 0.0
    coord: dict[str, float] = {}
    for w, spots in zip(ws, orbits, strict=True):
        found: list[tuple[float, dict[str, float]] | None] = []
        for sp_ in spots:
            x = solver.newton(_slow_flow_guess(solver, sp_.orbit, w), w)
            if x is None:
                found.append(None)
                continue
            amp, coords, _, _ = solver.measures(x, w, c)
            found.append((amp, coords))
        e, ce = _spot_errors(spots, found)
        errs.append(e)
        for k, v in ce.items():
            coord[k] = max(coord.get(k, 0.0), v)
        richer = _system_candidate_at(system, 3, w, spots, c, False)
        for f, g in zip(found, richer, strict=True):
            if f is not None and g is not None:
                est = max(est, _rel(f[0], g[0]))
    return CandidateResult(
        candidate, tuple(errs), est, time.process_time() - t0, "", tuple(coord.items())
    )


def system_spot_frequencies(system: Any, window: Sequence[float], n: int = 4) -> tuple[float, ...]:
    """``n`` frequencies spread over ``window``, kept 3 % of the window away from the folds of
    the system's one-harmonic balance (as :func:`spot_frequencies` for one coordinate)."""
    lo, hi = checks.window(window)
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 50:
        raise ParameterError(
            f"n_spots = {n!r}: expected an integer number of spot checks in [1, 50]"
        )
    edges = np.linspace(lo, hi, n + 1)
    try:
        from perturb.solve import frequency_response

        r = frequency_response(system, "hb", (lo, hi), harmonics=1, stability=False)
        folds = np.array([w for w, _ in r.folds])
    except PerturbError:
        folds = np.empty(0)
    return _away_from_folds(edges, folds)


def choose_system_method(
    system: Any,
    window: Sequence[float],
    rtol: float,
    *,
    output: str | None = None,
    spots: Sequence[float] | None = None,
    n_spots: int = 4,
    ladder: Sequence[Candidate] = SYSTEM_LADDER,
    log=None,
) -> AutoChoice:
    """The cheapest rung of ``ladder`` whose spot checks on ``system`` meet ``rtol`` (the
    output's error decides; :class:`CandidateResult` ``coordinate_errors`` holds each
    coordinate's). See :func:`auto_system_response`."""
    return _choose_system(system, window, rtol, output, spots, n_spots, ladder, log)[0]


def _choose_system(
    system, window, rtol, output, spots, n_spots, ladder, log, known=None, before=()
):
    """:func:`choose_system_method`; ``known`` caches the exact spot orbits (filled in here),
    ``before`` are results of cheaper rungs already rejected (reported, not re-run)."""
    from perturb.solve import SYSTEM_METHODS, SYSTEM_ONLY_METHODS

    rtol = check_rtol(rtol)
    lo, hi = checks.window(window)
    ladder = list(ladder)
    for c in ladder:
        if c.method in SYSTEM_ONLY_METHODS:
            continue  # not in the registry of one-coordinate methods
        check_candidate(c)
        if c.method not in SYSTEM_METHODS or c.method == "auto":
            raise ParameterError(
                f"ladder rung {c.name!r}: method {c.method!r} does not take a system (expected "
                f"one of {', '.join(m for m in SYSTEM_METHODS if m != 'auto')})"
            )
    if spots is None:
        spots = system_spot_frequencies(system, (lo, hi), n_spots)
    try:
        ws = tuple(float(w) for w in spots)
    except (TypeError, ValueError):
        raise ParameterError(f"spots = {spots!r}: expected positive frequencies") from None
    if not ws or not all(math.isfinite(w) and w > 0 for w in ws) or len(set(ws)) != len(ws):
        raise ParameterError(f"spots = {spots!r}: expected distinct positive frequencies")
    known = {} if known is None else known
    t0 = time.process_time()
    if ws not in known:
        known[ws] = exact_system_spot_orbits(system, ws, output)
        known["seconds"] = known.get("seconds", 0.0) + time.process_time() - t0
    orbits = known[ws]
    exact_s = known.get("seconds", 0.0)
    ladder = [c for c in ladder if c.method != "exact"] + [Candidate("exact", "exact")]
    derivations: dict[str, Any] = {}
    tried: list[CandidateResult] = list(before)
    for cand in ladder:
        kind = "ms-ir" if cand.method in SYSTEM_ONLY_METHODS else cand.method
        if kind in ("hb1", "shb", "ms-ir") and kind not in derivations:
            from perturb.solve import derive_system

            try:
                derivations[kind] = derive_system(system, "hb1" if kind == "shb" else kind)
            except PerturbError as exc:
                derivations[kind] = exc
        if isinstance(derivations.get(kind), PerturbError):
            res = CandidateResult(
                cand,
                tuple(math.inf for _ in ws),
                math.nan,
                0.0,
                f"not derived: {derivations[kind]}",
            )
            tried.append(res)
            if log is not None:
                log(f"{cand.name}: {res.note}")
            continue
        res = system_candidate_spot_errors(system, cand, ws, orbits, output, derivations.get(kind))
        if log is not None:
            log(_spot_line(cand, res))
        if res.meets(rtol):
            choice = AutoChoice(
                res,
                tuple(tried),
                rtol,
                (lo, hi),
                ws,
                tuple(len(o) for o in orbits),
                exact_s,
                tuple(tuple(s.output for s in row) for row in orbits),
            )
            return choice, orbits
        tried.append(res)
    raise AssertionError("unreachable: the exact candidate always meets rtol")


def auto_system_response(
    system: Any,
    window: Sequence[float],
    rtol: float,
    *,
    output: str | None = None,
    spots: Sequence[float] | None = None,
    n_spots: int = 4,
    ladder: Sequence[Candidate] = SYSTEM_LADDER,
    log=None,
    frequencies: Sequence[float] | None = None,
    curve_checks: int = 12,
    max_climbs: int = 2,
) -> tuple[Any, AutoChoice]:
    """The cheapest method that meets ``rtol`` on a system of several coordinates, then only
    it over ``window`` (or at exactly ``frequencies``).

    The ladder (:data:`SYSTEM_LADDER`): the symbolic single-harmonic balance of the system
    (``hb1``), numeric multi-harmonic balance with H = 3, 7, 15, 31, 63, the exact solver. At
    each spot frequency (:func:`system_spot_frequencies`, or the listed ``frequencies`` when
    there are at most ``n_spots``) every exact period-1 orbit is found
    (:func:`exact_system_spot_orbits`) and each rung's balance solved from each orbit's
    Fourier coefficients; the relative error of the output's ``max |.|`` decides, every
    coordinate's is reported (``coordinate_errors``, the summary's "per coordinate" line).
    A rung is accepted when its spot error and its estimate (the next richer balance at the
    same orbits) are both within ``rtol``.

    Parameters
    ----------
    system
        A forced :class:`~perturb.model.system.System` with parameter values.
    window, rtol, spots, n_spots, log
        As :func:`choose_method`.
    output
        What the ``amplitude`` column measures and the spot error judges (default the first
        coordinate), as :func:`perturb.solve.system_output`.
    ladder
        Rungs of methods that take a system (``hb1``, ``shb``, ``hb``, ``exact``).
    curve_checks, max_climbs
        After the trace, exact orbits are shot from ``curve_checks`` points of the chosen
        balance's curve (away from its folds, :func:`perturb.solve.system_errors`); where the
        output's error exceeds ``rtol`` between the spot frequencies the next rung is taken,
        at most ``max_climbs`` times (the notes say what was found).

    Returns
    -------
    (SystemResponse, AutoChoice)
        The response's ``notes`` start with the choice.
    """
    from perturb.solve import frequency_response

    if frequencies is not None:
        from perturb.methods.registry import MAX_FREQUENCIES

        targets = checks.frequencies(frequencies, MAX_FREQUENCIES)
        unique = sorted(set(targets))
        window = (unique[0] * (1 - 0.02), unique[-1] * (1 + 0.02))
        if spots is None and len(unique) <= n_spots:
            spots = unique
    known: dict = {}
    ladder = list(ladder)
    before: tuple[CandidateResult, ...] = ()
    extra: list[str] = []
    resp = None
    climbs = 0
    # the climbs after a curve check, plus one per rung whose trace fails (each such rung
    # leaves the ladder, so the loop ends at the exact solver at the latest)
    for _ in range(max_climbs + 1 + len(ladder)):
        choice, _ = _choose_system(
            system, window, rtol, output, spots, n_spots, ladder, log, known, before
        )
        spots = choice.spot_frequencies
        cand = choice.chosen.candidate
        settings = cand.settings()
        method = settings.pop("method")
        if frequencies is not None:
            resp = frequency_response(
                system, method, frequencies=targets, output=output, **settings
            )
            break
        if method == "exact":
            resp = frequency_response(system, method, choice.window, output=output, **settings)
            break
        try:
            resp = frequency_response(system, method, choice.window, output=output, **settings)
        except PerturbError as exc:
            # verified at the spots from the exact orbits, but its own start over the window
            # failed (the impact pair's balance off resonance): the next rung answers
            worst, at, failed_trace = math.inf, math.nan, str(exc)
        else:
            failed_trace = ""
            worst, at = _curve_check(system, resp, output, curve_checks)
        if failed_trace:
            msg = f"{cand.name}: tracing the window failed ({failed_trace})"
            extra.append(msg + ": the next rung is tried")
            if log is not None:
                log(msg)
            i = next(j for j, c in enumerate(ladder) if c == cand)
            failed = dataclasses.replace(choice.chosen, note="trace failed")
            before = (*choice.rejected, failed)
            ladder = ladder[i + 1 :]
            continue
        if not worst > rtol:
            if math.isfinite(worst):
                extra.append(
                    f"{cand.name} on the traced curve: exact orbits shot from {curve_checks} "
                    f"of its points away from folds, largest error {worst:.2e} <= rtol"
                )
            break
        msg = (
            f"{cand.name}: error {worst:.2e} > rtol against the exact orbit at Omega = "
            f"{at:.6g} on the traced curve (between the spot frequencies)"
        )
        if climbs == max_climbs:
            extra.append(msg + "; kept (no more climbs): tighten rtol or give spots there")
            break
        extra.append(msg + ": the next rung is tried")
        if log is not None:
            log(msg)
        climbs += 1
        i = next(j for j, c in enumerate(ladder) if c == cand)
        failed = dataclasses.replace(choice.chosen, note=f"curve check {worst:.2e} at {at:.6g}")
        before = (*choice.rejected, failed)
        ladder = ladder[i + 1 :]
    if frequencies is None:
        extra += list(_coverage_notes(resp, choice))
    choice = _with_notes(choice, tuple(extra))
    head = tuple(choice.summary().splitlines())
    return dataclasses.replace(resp, notes=head + tuple(resp.notes)), choice


def _curve_check(system: Any, resp: Any, output: str | None, points: int) -> tuple[float, float]:
    """The largest relative error of the output's ``max |.|`` over up to ``points`` points of a
    traced balance response, each against the exact orbit shot from its state
    (:func:`perturb.solve.system_errors`), points within 1 % of a fold left out (there the
    amplitude at a fixed frequency is ill-conditioned and the truncated fold is displaced);
    ``(nan, nan)`` when none could be checked."""
    from perturb.solve import system_errors

    rows = [
        (b, j)
        for b, br in enumerate(resp.branches)
        for j in range(len(br))
        if not any(abs(float(br.omega[j]) - f) < 0.01 * f for f, _ in resp.folds)
    ]
    if not rows or not resp.columns or "states" not in resp.columns[0]:
        return math.nan, math.nan
    pick = np.unique(np.linspace(0, len(rows) - 1, min(points, len(rows))).round().astype(int))
    chosen = {rows[int(i)] for i in pick}
    # a response of only the chosen points (system_errors checks every point it is given)
    branches, cols, where = [], [], []
    for b, br in enumerate(resp.branches):
        idx = [j for j in range(len(br)) if (b, j) in chosen]
        if not idx:
            continue
        branches.append(
            Branch(
                br.omega[idx],
                br.amplitude[idx],
                br.first_harmonic_amplitude[idx],
                br.mean[idx],
                br.stable[idx],
                br.max_multiplier[idx],
            )
        )
        cols.append({k: np.asarray(v)[idx] for k, v in resp.columns[b].items()})
        where += [float(br.omega[j]) for j in idx]
    part = dataclasses.replace(resp, branches=tuple(branches), columns=tuple(cols), folds=())
    errs, _ = system_errors(system, part, output, max_points=len(where))
    e = errs["rel_error"]
    if not np.any(np.isfinite(e)):
        return math.nan, math.nan
    i = int(np.nanargmax(e))
    return float(e[i]), where[i]
