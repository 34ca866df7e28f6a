"""Work-precision benchmark: wall time of a whole frequency response against its error.

For a fixed set of problems every applicable method and setting is run over the problem's
frequency window, timed (the time includes deriving and compiling the approximation, i.e.
what a user waits for) and compared with the exact response
(:func:`perturb.comparison.compare`: max / RMS relative amplitude error over the matched
branches).  The exact response is computed once per problem: it is the reference of every
row and the ``exact`` row's time.  Times are also given as ratios to a brute-force
stepped-sine sweep (:func:`perturb.simulate.studies.frequency_sweep` with the plain ODE flow,
up and down, at the spacing of ``--sweep-points`` frequencies over the window) measured in
the same process.  A method that fails or does not apply is a row ``n/a (reason)``; one that
runs past ``--timeout`` a row ``timeout``; known inaccuracies are explained in the ``note``.

Repeats adapt to the cost: a method is run once, and again (up to ``--repeat`` runs) only
while the runs so far took less than :data:`REPEAT_BUDGET` seconds; the median is reported,
and the first run (cold in-process caches: SymPy's and the methods' memoised helpers) in its
own column.  The brute-force sweep is too slow to run at full spacing on every problem: it is
timed on an evenly spaced subset of the full grid (``sweep_measured`` frequencies) and its
time extrapolated per frequency to the full grid, which the table says.

The van der Pol problem is autonomous: its "response" is the limit cycle over ``eps``
(amplitude ``max|x|`` and period), exact by shooting (:func:`perturb.simulate.orbits.shooting.
limit_cycle`, continued in ``eps``), approximate by averaging and multiple scales, brute
force by integrating until the transient has died.

The systems ``nsd2`` (2-DOF structure with the negative-stiffness device) and ``impact_pair``
(impact damper / backlash pair) are answered by the methods that take a system (``hb1``,
``shb``, numeric HB with H = 1 ... 63, exact or AFT projection, ``auto``): the output's
(``x1``) error is in the row's columns, every coordinate's in its note, ``missed`` says which
exact branches a method did not find; the time unit is the system's stepped-sine sweep
(:func:`perturb.simulate.studies.system_frequency_sweep`).

Outputs into ``--out``: ``work_precision.md``, ``work_precision.csv`` and one log-log PNG per
problem (``work_precision_<problem>.png``).

Command line: ``perturb bench [--fast] [--out DIR] [--problems P,...] [--methods M,...]``
or ``python benchmarks/work_precision.py`` with the same options.
"""

from __future__ import annotations

import argparse
import csv
import fnmatch
import math
import os
import platform
import signal
import statistics
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # numpy is loaded by the functions that run, not by `perturb --help`
    import numpy as np

__all__ = [
    "PROBLEMS",
    "COLUMNS",
    "Problem",
    "Row",
    "method_settings",
    "run_benchmark",
    "write_outputs",
    "add_parser",
    "cmd_bench",
    "main",
]

#: Columns of the CSV (the Markdown table shows the same ones, errors and times formatted).
COLUMNS = (
    "problem",
    "method",
    "setting",
    "status",
    "time_s",
    "first_s",
    "repeats",
    "time_vs_sweep",
    "max_rel_error",
    "rms_rel_error",
    "matched",
    "missed",
    "spurious",
    "note",
)


@dataclass(frozen=True)
class Problem:
    """One benchmark problem: a builtin model, its parameters and frequency window.

    ``kind`` is ``"forced"`` (a frequency response over ``window``) or ``"limit_cycle"``
    (an autonomous model's limit cycle over ``parameter`` in ``window``, at ``points``
    values)."""

    name: str
    model: str
    params: dict[str, float]
    window: tuple[float, float]
    description: str
    kind: str = "forced"
    parameter: str = "Omega"
    points: int = 0

    def oscillator(self):
        """The model: an oscillator, or for ``kind = "system"`` a
        :class:`~perturb.model.system.System` (:func:`~perturb.model.system_builtins.
        builtin_system`)."""
        if self.kind == "system":
            from perturb.model.system_builtins import builtin_system

            return builtin_system(self.model, **self.params)
        from perturb.model.builtins import builtin_model

        return builtin_model(self.model, **self.params)


#: Window of the impact pair: around the primary resonance (9 exact branches). Numeric HB
#: finds every one of them at H = 1..63 (2026-11-27), but its max error stays at 0.15-0.19:
#: at the sharp folds of grazing contacts the HB fold lies ~1e-5 in Omega from the exact one,
#: and the HB points past it (no exact orbit there) are compared with the other side.
IMPACT_PAIR_WINDOW = (0.6, 1.4)

#: The fixed problem set (issue 7 item 1; the systems nsd2 and impact_pair, issue 16).
PROBLEMS: dict[str, Problem] = {
    p.name: p
    for p in (
        Problem(
            "nsd_k-0.5",
            "nsd",
            {"k": -0.5, "mu": 0.05, "F": 2.0},
            (0.2, 2.5),
            "negative-stiffness device, k = -0.5 (mu = 0.05, F = 2)",
        ),
        Problem(
            "nsd_k-3",
            "nsd",
            {"k": -3.0, "mu": 0.05, "F": 2.0},
            (0.2, 2.5),
            "negative-stiffness device, k = -3 (detached loop)",
        ),
        Problem(
            "nsd_k2",
            "nsd",
            {"k": 2.0, "mu": 0.05, "F": 2.0},
            (0.2, 2.5),
            "nsd with k = 2 (stiff inner segment, softening)",
        ),
        Problem(
            "duffing",
            "duffing",
            {"alpha": 1.0, "mu": 0.1, "F": 0.5, "omega0": 1.0},
            (0.5, 2.5),
            "forced hardening Duffing (multivalued)",
        ),
        Problem(
            "clearance",
            "clearance",
            {"r": 10.0, "d": 0.5, "mu": 0.02, "F": 0.3},
            (0.5, 1.6),
            "clearance (one-sided spring r = 10 beyond d = 0.5)",
        ),
        Problem(
            "vdp",
            "vanderpol",
            {},
            # limit_cycle can run away to T -> 0 from a poor seed at large eps (eps = 5):
            # the window stays at eps <= 2, each shooting seeded with the previous cycle
            (0.1, 2.0),
            "van der Pol limit cycle over eps (amplitude max|x|; period in the note)",
            kind="limit_cycle",
            parameter="eps",
            points=20,
        ),
        Problem(
            "nsd2",
            "nsd2",
            {},
            (0.5, 2.0),
            "2-DOF structure with the nsd device (k = -0.5, F = 2): output x1, every "
            "coordinate compared",
            kind="system",
        ),
        Problem(
            "impact_pair",
            "impact_pair",
            {},
            IMPACT_PAIR_WINDOW,
            "impact damper / backlash pair (clearance d = 0.5, contact r = 20): output x1, "
            "every coordinate compared",
            kind="system",
        ),
    )
}

#: A method is run again (up to ``repeat`` runs) only while its runs took less than this.
REPEAT_BUDGET = 5.0

HB_HARMONICS = (1, 3, 5, 9, 15, 31)
#: Harmonics of the systems' rows (the auto ladder's).
SYSTEM_HB_HARMONICS = (1, 3, 7, 15, 31, 63)


@dataclass(frozen=True)
class Setting:
    """One method/setting: ``key`` selects it (``--methods``), ``method`` and ``kwargs`` go to
    :func:`perturb.solve.frequency_response`."""

    key: str
    method: str
    setting: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    kinds: tuple[str, ...] = ("forced",)


def method_settings(kind: str = "forced") -> list[Setting]:
    """Every method/setting tried on a problem of ``kind`` (``exact`` and ``sweep`` are added
    apart)."""
    if kind == "system":
        return [
            Setting("hb1", "hb1", "symbolic single-harmonic balance of the system", kinds=(kind,)),
            Setting(
                "shb",
                "shb",
                "symbolic single-harmonic balance with bias",
                {"bias": True},
                kinds=(kind,),
            ),
            *(
                Setting(
                    f"hb-{proj}-H{h}",
                    "hb",
                    f"H={h}, projection={proj}, every branch",
                    {"harmonics": h, "projection": proj},
                    kinds=(kind,),
                )
                for proj, hs in (("exact", SYSTEM_HB_HARMONICS), ("aft", (3, 7, 15)))
                for h in hs
            ),
            Setting("auto", "auto", "auto, rtol = 1e-3", {"rtol": 1e-3}, kinds=(kind,)),
        ]
    if kind == "limit_cycle":
        return [
            Setting("kb", "kb", "averaging (Krylov-Bogoliubov)", kinds=(kind,)),
            Setting("ms", "ms", "multiple scales, order 1", {"order": 1}, kinds=(kind,)),
            Setting("ms2", "ms", "multiple scales, order 2", {"order": 2}, kinds=(kind,)),
            Setting("vdp", "vdp", "van der Pol averaging (Cartesian)", kinds=(kind,)),
        ]
    out = [
        Setting("mlp1", "mlp", "order 1", {"order": 1}),
        Setting("mlp2", "mlp", "order 2", {"order": 2}),
        Setting("ms", "ms", "multiple scales"),
        Setting("kb", "kb", "averaging (Krylov-Bogoliubov)"),
        Setting("hb1", "hb1", "symbolic single-harmonic balance"),
        Setting("vdp", "vdp", "van der Pol slow flow"),
        Setting("lp", "lp", "Lindstedt-Poincare"),
    ]
    for proj in ("exact", "aft"):
        for h in HB_HARMONICS:
            out.append(
                Setting(
                    f"hb-{proj}-H{h}",
                    "hb",
                    f"H={h}, projection={proj}, every branch from hb1 seeds",
                    # every branch continuation reaches from the automatic start and from the
                    # single-harmonic branches (detached loops, in-well orbits): the rows are
                    # compared with every exact branch, so a one-branch trace would count as
                    # missing what it never looked for
                    {"harmonics": h, "projection": proj, "all_branches": True},
                )
            )
    return out


@dataclass
class Row:
    problem: str
    method: str
    setting: str
    status: str = "ok"
    time_s: float = math.nan
    first_s: float = math.nan
    repeats: int = 0
    time_vs_sweep: float = math.nan
    max_rel_error: float = math.nan
    rms_rel_error: float = math.nan
    matched: str = ""
    missed: str = ""
    spurious: str = ""
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {c: getattr(self, c) for c in COLUMNS}


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if len(text) > 160:
        text = text[:157] + "..."
    return f"n/a ({type(exc).__name__}: {text})"


class MethodTimeout(BaseException):
    """A method ran past ``--timeout`` (a BaseException, so that the library's own
    ``except Exception`` handlers do not swallow it)."""


def _on_alarm(signum: int, frame: Any) -> None:
    raise MethodTimeout


def timed(
    fn: Callable[[], Any],
    repeat: int,
    timeout: float | None = None,
    budget: float | None = None,
) -> tuple[float, Any]:
    """Median wall time of up to ``repeat`` calls, and the last result.

    With ``budget`` (seconds) another call is made only while the calls so far took less in
    total, so expensive methods run once.  With ``timeout`` (seconds, per call; needs SIGALRM
    and the main thread) a longer call raises :class:`MethodTimeout`.  The number of calls
    and the first call's time are in :data:`timed.last` (``(calls, first)``)."""
    use_alarm = (
        timeout is not None
        and timeout > 0
        and hasattr(signal, "setitimer")
        and threading.current_thread() is threading.main_thread()
    )
    times: list[float] = []
    out = None
    for _ in range(max(1, repeat)):
        if times and budget is not None and sum(times) >= budget:
            break
        old = signal.signal(signal.SIGALRM, _on_alarm) if use_alarm else None
        if use_alarm:
            signal.setitimer(signal.ITIMER_REAL, float(timeout))
        t = time.perf_counter()
        try:
            out = fn()
        finally:
            if use_alarm:
                signal.setitimer(signal.ITIMER_REAL, 0.0)
                signal.signal(signal.SIGALRM, old)
        times.append(time.perf_counter() - t)
    timed.last = (len(times), times[0])  # type: ignore[attr-defined]
    return statistics.median(times), out


timed.last = (0, math.nan)  # type: ignore[attr-defined]


def _fill_errors(row: Row, resp: Any, ref: Any) -> None:
    import numpy as np

    from perturb.comparison import compare

    c = compare(resp, ref)
    row.matched = f"{len(c.matches)}/{len(c.branches)}"
    row.missed = f"{len(c.missed)}/{len(c.reference_branches)}"
    row.spurious = str(len(c.spurious))
    if c.matches:
        row.max_rel_error = c.max_error
        row.rms_rel_error = c.rms_error
        return
    # no branch has most of its points within the matching tolerance of the exact response:
    # an error that large is still an error, measured against the nearest exact solution at
    # each frequency rather than left blank
    e = c.rel_errors[np.isfinite(c.rel_errors)]
    if e.size:
        row.max_rel_error = float(e.max())
        row.rms_rel_error = float(np.sqrt(np.mean(e * e)))
        _note(
            row,
            f"no branch within {c.tolerance:g} of an exact branch on {c.min_share:.0%} of its "
            "points: errors against the nearest exact solution at each frequency",
        )
    else:
        _note(row, "no point at a frequency where the exact response has a solution")


def _selected(key: str, patterns: Sequence[str] | None) -> bool:
    return patterns is None or any(fnmatch.fnmatchcase(key, p) for p in patterns)


def sweep_subset(n_full: int, n_measured: int) -> np.ndarray:
    """Indices of ``n_measured`` evenly spaced frequencies of the full grid (ends included)."""
    import numpy as np

    n = max(1, min(n_full, n_measured))
    return np.unique(np.round(np.linspace(0, n_full - 1, n)).astype(int))


def _note(row: Row, text: str) -> None:
    row.note = f"{row.note}; {text}" if row.note else text


def _run_setting(
    row: Row,
    fn: Callable[[], Any],
    rep: int,
    timeout: float | None,
    say: Callable[[str], None],
) -> Any:
    """Time ``fn`` into ``row``; None (and the row's status set) if it failed."""
    try:
        row.time_s, out = timed(fn, rep, timeout, REPEAT_BUDGET)
        row.repeats, row.first_s = timed.last  # type: ignore[attr-defined]
        return out
    except MethodTimeout:
        row.status = f"timeout (stopped after {timeout:g} s)"
    except Exception as exc:  # noqa: BLE001 - recorded in the table
        row.status = _reason(exc)
    say(f"   {row.method}: {row.status}")
    return None


def _say_row(say: Callable[[str], None], row: Row) -> None:
    say(
        f"   {row.method}: {row.time_s:.3g} s x{row.repeats}, max {row.max_rel_error:.3g}, "
        f"rms {row.rms_rel_error:.3g} {row.note}"
    )


def _run_problem(
    prob: Problem,
    pats: list[str] | None,
    fast: bool,
    rep: int,
    n_full: int,
    n_measured: int,
    timeout: float | None,
    say: Callable[[str], None],
) -> list[Row]:
    import numpy as np

    if prob.kind == "limit_cycle":
        return _run_limit_cycle(prob, pats, rep, timeout, say)
    if prob.kind == "system":
        return _run_system(prob, pats, rep, timeout, say, n_full, n_measured)
    from perturb.simulate.studies import frequency_sweep
    from perturb.solve import frequency_response

    name = prob.name
    osc = prob.oscillator()
    lo, hi = prob.window
    say(f"== {name}: {prob.description}, Omega in [{lo}, {hi}]")
    # -- exact reference: computed once, the reference of every row and the exact row's time
    ex, ref = _exact_row(name, osc, (lo, hi), "continuation of exact orbits", say)
    # -- brute-force sweep (the time unit of the ratios), always run whatever --methods says
    grid = np.linspace(lo, hi, n_full)
    sub = grid[sweep_subset(n_full, n_measured)]
    extrapolated = sub.size != n_full
    sw = Row(
        name,
        "sweep",
        f"solve_ivp (DOP853, rtol 1e-10) stepped sine up+down, {n_full} frequencies"
        + (f" (time EXTRAPOLATED from {sub.size})" if extrapolated else ""),
    )
    sweep_time = math.nan
    sres = _run_setting(
        sw,
        lambda: frequency_sweep(
            osc, sub, direction="both", method="ode", multipliers=False, progress=False
        ),
        1,
        None,
        say,
    )
    if sres is not None:
        measured = sw.time_s
        sweep_time = sw.time_s = sw.first_s = measured * n_full / sub.size
        if extrapolated:
            sw.note = (
                f"time measured on {sub.size} of the {n_full} frequencies "
                f"({measured:.3g} s, evenly spaced, ends included) and extrapolated per "
                "frequency; errors over those frequencies"
            )
        if ref is not None:
            try:
                _fill_errors(sw, sres.to_response(), ref)
            except Exception as exc:  # noqa: BLE001 - recorded in the table
                _note(sw, f"comparison failed: {_reason(exc)[4:-1]}")
        _note(sw, "stable branches only")
        # a sweep settles on whatever attractor it meets, also a subharmonic or non-periodic
        # one that the period-1 reference does not contain: say so where it happened
        for text in sres.to_response().notes:
            if "subharmonic" in text or "no periodic" in text:
                _note(sw, text.split(";")[0])
        _say_row(say, sw)
    out_rows = [ex, sw]
    # -- the approximations
    for s in method_settings(prob.kind):
        if not _selected(s.key, pats):
            continue
        row = Row(name, s.key, s.setting)
        resp = _run_setting(
            row,
            lambda s=s: frequency_response(osc, s.method, Omega=(lo, hi), **s.kwargs),
            rep,
            timeout,
            say,
        )
        out_rows.append(row)
        if resp is None:
            continue
        if ref is None:
            row.note = "no exact reference: error not measured"
        else:
            try:
                _fill_errors(row, resp, ref)
            except Exception as exc:  # noqa: BLE001 - recorded in the table
                _note(row, f"comparison failed: {_reason(exc)[4:-1]}")
        for text in getattr(resp, "notes", ()) or ():
            if "left out" in text:
                _note(row, text)
        explain_row(row)
        _say_row(say, row)
    for r in out_rows:
        if r.status == "ok" and np.isfinite(sweep_time) and sweep_time > 0:
            r.time_vs_sweep = r.time_s / sweep_time
    return out_rows


def _system_note(row: Row, comparison: Any) -> None:
    """Every coordinate's error (the output's is in the row's columns)."""
    if comparison.coordinates:
        _note(
            row,
            "per coordinate max|.| error: "
            + ", ".join(f"{n} {mx:.2e} (rms {rms:.2e})" for n, mx, rms in comparison.coordinates),
        )


def _exact_row(name: str, model: Any, window: tuple[float, float], what: str, say) -> tuple:
    """The exact row (its time) and the exact response, the reference of every other row
    (``None`` when it failed: the row says why)."""
    from perturb.solve import frequency_response

    ex = Row(name, "exact", what)
    ref = None
    try:
        t = time.perf_counter()
        ref = frequency_response(model, "exact", Omega=window)
        ex.time_s = ex.first_s = time.perf_counter() - t
        ex.repeats = 1
        ex.note = f"reference ({ref.method}, {sum(len(b) for b in ref.branches)} points)"
        ex.matched = f"{len(ref.branches)}/{len(ref.branches)}"
        ex.max_rel_error = ex.rms_rel_error = 0.0
    except Exception as exc:  # noqa: BLE001 - recorded in the table
        ex.status = _reason(exc)
    say(f"   exact: {ex.time_s:.3g} s {ex.status} {ex.note}")
    return ex, ref


def _run_system(
    prob: Problem,
    pats: list[str] | None,
    rep: int,
    timeout: float | None,
    say: Callable[[str], None],
    n_full: int = 100,
    n_measured: int = 3,
) -> list[Row]:
    """A system of several coordinates: the exact response (every branch by continuation of
    exact orbits) is the reference; each method's output error is in the row's columns, every
    coordinate's in its note, ``missed`` says whether it found every exact branch. The time
    unit of the ratios is the brute-force stepped-sine sweep of the system
    (:func:`perturb.simulate.studies.system_frequency_sweep`, up and down, timed on
    ``n_measured`` of ``n_full`` frequencies and extrapolated, as for one coordinate)."""
    import numpy as np

    from perturb.comparison import compare
    from perturb.simulate.studies import system_frequency_sweep
    from perturb.solve import frequency_response

    name = prob.name
    system = prob.oscillator()
    lo, hi = prob.window
    say(f"== {name}: {prob.description}, Omega in [{lo}, {hi}]")
    ex, ref = _exact_row(name, system, (lo, hi), "continuation of exact orbits (every branch)", say)
    grid = np.linspace(lo, hi, n_full)
    sub = grid[sweep_subset(n_full, n_measured)]
    sw = Row(
        name,
        "sweep",
        f"stepped sine up+down (system_frequency_sweep), {n_full} frequencies"
        + (f" (time EXTRAPOLATED from {sub.size})" if sub.size != n_full else ""),
    )
    sres = _run_setting(
        sw, lambda: system_frequency_sweep(system, sub, direction="both"), 1, None, say
    )
    sweep_time = math.nan
    if sres is not None:
        sweep_time = sw.time_s = sw.first_s = sw.time_s * n_full / sub.size
        if ref is not None:
            try:
                _fill_errors(sw, sres.to_response(), ref)
            except Exception as exc:  # noqa: BLE001 - recorded in the table
                _note(sw, f"comparison failed: {_reason(exc)[4:-1]}")
        _note(sw, "stable branches only; errors over the measured frequencies")
        _say_row(say, sw)
    rows = [ex, sw]
    for s in method_settings("system"):
        if not _selected(s.key, pats):
            continue
        row = Row(name, s.key, s.setting)
        resp = _run_setting(
            row,
            lambda s=s: frequency_response(system, s.method, Omega=(lo, hi), **s.kwargs),
            rep,
            timeout,
            say,
        )
        rows.append(row)
        if resp is None:
            continue
        if ref is None:
            row.note = "no exact reference: error not measured"
        else:
            try:
                _fill_errors(row, resp, ref)
                _system_note(row, compare(resp, ref))
            except Exception as exc:  # noqa: BLE001 - recorded in the table
                _note(row, f"comparison failed: {_reason(exc)[4:-1]}")
        if s.method == "auto":
            _note(row, resp.notes[0].removeprefix("auto: "))
        for text in resp.notes:
            if "left out" in text:
                _note(row, text)
        explain_row(row)
        _say_row(say, row)
    for r in rows:
        if r.status == "ok" and np.isfinite(sweep_time) and sweep_time > 0:
            r.time_vs_sweep = r.time_s / sweep_time
    return rows


#: Rows whose error is large for a reason found by investigation: ``(problem, methods)``
#: fnmatch patterns (methods comma-separated) and the explanation added to the row's note.
KNOWN: tuple[tuple[str, str, str], ...] = (
    (
        "nsd_k-*",
        "mlp2",
        "second-order mLP: at low Omega a small divisor of its correction vanishes and the "
        "waveform blows up (for k = -0.5 a spurious branch below Omega ~ 0.26 up to max|x| "
        "~ 5e5); those points are left out as outside the expansion's validity "
        "(residual_response max_correction)",
    ),
    (
        "clearance",
        "hb-exact-H1",
        "one harmonic (with the mean) of the r = 10 one-sided spring peaks at Omega 1.463, "
        "the exact response at 1.515: on the steep flanks fewer than half its points are "
        "within 0.2, so nothing matches; the H = 1 solution itself was checked by quadrature",
    ),
    (
        "clearance",
        "ms,kb",
        "first order without a mean term: the one-sided spring's bias is missing and the "
        "response stays below max|x| ~ 1 up to Omega = 1.6 (exact peak 14 at 1.513)",
    ),
    (
        "clearance",
        "mlp*",
        "mLP expands about omega0 = sqrt(1 + r/2) = 2.45 (see its label), not the "
        "small-amplitude frequency 1 of this gap spring: its resonance moves right, out of "
        "the window (order 1: max|x| 1.2 at Omega = 1.6; order 2: its upper branch runs past "
        "the exact jump-down at 1.515 to the window's end, where only the exact lower "
        "branch exists)",
    ),
    (
        "nsd_k2",
        "hb-aft-H9,hb-aft-H15",
        "AFT's largest errors sit at the superharmonic resonance's folds (exact folds at Omega "
        "0.5915 and 0.6151, max|x| ~ 1.2-1.3), which its aliasing moves; the exact Galerkin "
        "projection at the same H is not affected",
    ),
    (
        "duffing",
        "ms",
        "first-order multiple scales' backbone 1 + 3a^2/8 (expanded for small a) overshoots "
        "at a ~ 2: its upper branch runs past the exact jump-down (2.21) to the window's end, "
        "where only the exact lower branch exists (error ~20 there)",
    ),
    (
        "vdp",
        "ms2",
        "the O(eps) waveform term -a^3 eps sin 3(t + beta) / 32 overshoots max|x| at eps ~ 2 "
        "(an expansion in eps); the period is better than first order",
    ),
)


def explain_row(row: Row) -> None:
    """Append to ``row.note`` the known explanation of its outcome (:data:`KNOWN`), if any."""
    for prob, meth, text in KNOWN:
        if fnmatch.fnmatchcase(row.problem, prob) and any(
            fnmatch.fnmatchcase(row.method, m) for m in meth.split(",")
        ):
            _note(row, text)


# ---------------------------------------------------------------------------------------------
# the autonomous problem: the van der Pol limit cycle over a parameter
# ---------------------------------------------------------------------------------------------
def limit_cycle_exact(prob: Problem, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude ``max|x|`` and period of the limit cycle at each value of ``grid``, by
    autonomous shooting, each seeded with the previous cycle."""
    import numpy as np

    from perturb.model.builtins import builtin_model
    from perturb.simulate.flows.factory import make_flow
    from perturb.simulate.orbits.shooting import limit_cycle

    amp, per = np.empty(grid.size), np.empty(grid.size)
    # the small-eps cycle is x = 2 cos t
    y, T = np.array([2.0, 0.0]), 2 * np.pi
    for i, e in enumerate(grid):
        osc = builtin_model(prob.model, **{**prob.params, prob.parameter: float(e)})
        orb = limit_cycle(make_flow(osc), y, T)
        y, T = orb.y0, orb.period
        amp[i], per[i] = orb.amplitude, orb.period
    return amp, per


def _lc_sweep(prob: Problem, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The brute force a user would write: ``solve_ivp`` (DOP853, rtol 1e-10) from the
    previous value's end state for 60 time units at least and 6 cycles, then the amplitude
    as ``max|x|`` over the last cycle and the period as the spacing of the last upward zero
    crossings of ``x``."""
    import numpy as np
    from scipy.integrate import solve_ivp

    amp, per = np.empty(grid.size), np.empty(grid.size)
    y = np.array([2.0, 0.0])
    for i, e in enumerate(grid):
        e = float(e)

        def rhs(_t, z, e=e):
            return (z[1], e * (1 - z[0] ** 2) * z[1] - z[0])

        # attraction to the cycle goes like exp(-eps t): from the previous cycle's state a
        # few e-folds suffice, and a cycle lasts at most ~8 time units for eps <= 2
        t_end = max(60.0, 10.0 / e)
        sol = solve_ivp(rhs, (0, t_end), y, method="DOP853", rtol=1e-10, atol=1e-12,
                        dense_output=True)  # fmt: skip
        t = np.linspace(0.6 * t_end, t_end, 20000)
        x = sol.sol(t)[0]
        up = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
        tz = t[up] - x[up] * (t[up + 1] - t[up]) / (x[up + 1] - x[up])
        per[i] = tz[-1] - tz[-2]
        last = (t >= tz[-2]) & (t <= tz[-1])
        amp[i] = np.max(np.abs(x[last]))
        y = sol.y[:, -1]
    return amp, per


def limit_cycle_approx(
    prob: Problem, s: Setting, grid: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude ``max|x|`` and period of the approximate limit cycle at each value of
    ``grid``: derived once with the parameter symbolic, then the stable nonzero root ``a`` of
    the amplitude equation, the frequency ``1 + dbeta/dt`` (polar unknowns ``(a, beta)``) or
    ``1 + dq/dt / a`` at ``(p, q) = (a, 0)`` (Cartesian), and ``max|x|`` of the waveform."""
    import numpy as np
    import sympy as sp
    from scipy.optimize import brentq

    from perturb.model.builtins import builtin_model
    from perturb.numeric.compile import lambdify
    from perturb.solve import derive

    osc = builtin_model(prob.model, **{**prob.params, prob.parameter: None})
    approx = derive(osc, s.method, **s.kwargs)
    flow = list(approx.slow_flow or ())
    if len(flow) != 2 or len(approx.unknowns) != 2:
        raise ValueError(f"{approx.label}: expected a slow flow in two unknowns")
    psym = next(sym for e in flow for sym in e.free_symbols if sym.name == prob.parameter)
    a = sp.Symbol("a_lc", positive=True)
    u0, u1 = approx.unknowns
    if approx.amplitude is not None:  # polar (a, beta)
        at = {approx.amplitude: a, (u1 if u0 == approx.amplitude else u0): 0}
        rate_a = flow[approx.unknowns.index(approx.amplitude)].xreplace(at)
        rate_w = flow[1 - approx.unknowns.index(approx.amplitude)].xreplace(at)
    else:  # Cartesian (p, q) at q = 0
        at = {u0: a, u1: 0}
        rate_a, rate_w = flow[0].xreplace(at), flow[1].xreplace(at) / a
    tau = approx.tau
    wave = approx.waveform.xreplace(at)
    f_a = lambdify((a, psym), sp.simplify(rate_a / a))
    df_a = lambdify((a, psym), sp.diff(rate_a, a))
    f_w = lambdify((a, psym), rate_w)
    f_x = lambdify((a, psym, tau), wave)
    taus = np.linspace(0, 2 * np.pi, 512, endpoint=False)
    scan = np.geomspace(1e-3, 1e2, 400)
    amp, per = np.full(grid.size, np.nan), np.full(grid.size, np.nan)
    for i, e in enumerate(grid):
        v = np.asarray(f_a(scan, e), dtype=float)
        roots = [
            brentq(lambda z, e=e: float(f_a(z, e)), scan[j], scan[j + 1], xtol=1e-14)
            for j in np.nonzero(np.sign(v[:-1]) * np.sign(v[1:]) < 0)[0]
        ]
        roots = [r for r in roots if float(df_a(r, e)) < 0]
        if not roots:
            continue
        r = roots[0]
        amp[i] = np.max(np.abs(f_x(r, e, taus)))
        per[i] = 2 * np.pi / (1.0 + float(f_w(r, e)))
    return amp, per


def _lc_errors(row: Row, amp: np.ndarray, per: np.ndarray, ref: tuple) -> None:
    import numpy as np

    ra, rp = ref
    ok = np.isfinite(amp)
    if not np.any(ok):
        _note(row, "no stable limit cycle found")
        return
    ea = np.abs(amp[ok] - ra[ok]) / ra[ok]
    ep = np.abs(per[ok] - rp[ok]) / rp[ok]
    row.max_rel_error = float(ea.max())
    row.rms_rel_error = float(np.sqrt(np.mean(ea**2)))
    row.matched = "1/1"
    row.missed = "0/1" if ok.all() else f"{int((~ok).sum())} values"
    row.spurious = "0"
    _note(row, f"period: max rel. error {ep.max():.2e}")


def _run_limit_cycle(
    prob: Problem,
    pats: list[str] | None,
    rep: int,
    timeout: float | None,
    say: Callable[[str], None],
) -> list[Row]:
    import numpy as np

    name = prob.name
    lo, hi = prob.window
    grid = np.linspace(lo, hi, prob.points)
    say(f"== {name}: {prob.description}, {prob.parameter} in [{lo}, {hi}], {grid.size} values")
    ex = Row(name, "exact", f"autonomous shooting (limit_cycle), {grid.size} values")
    ref = _run_setting(ex, lambda: limit_cycle_exact(prob, grid), 1, None, say)
    if ref is not None:
        ex.max_rel_error = ex.rms_rel_error = 0.0
        ex.matched, ex.note = "1/1", "reference"
        _say_row(say, ex)
    sw = Row(name, "sweep", f"solve_ivp (DOP853, rtol 1e-10) until settled, {grid.size} values")
    sres = _run_setting(sw, lambda: _lc_sweep(prob, grid), 1, None, say)
    if sres is not None and ref is not None:
        _lc_errors(sw, *sres, ref)
        _say_row(say, sw)
    rows = [ex, sw]
    for s in method_settings(prob.kind):
        if not _selected(s.key, pats):
            continue
        row = Row(name, s.key, s.setting)
        res = _run_setting(row, lambda s=s: limit_cycle_approx(prob, s, grid), rep, timeout, say)
        rows.append(row)
        if res is not None and ref is not None:
            _lc_errors(row, *res, ref)
            explain_row(row)
            _say_row(say, row)
    if sw.status == "ok":
        for r in rows:
            if r.status == "ok":
                r.time_vs_sweep = r.time_s / sw.time_s
    return rows


def run_benchmark(
    problems: Sequence[str] | None = None,
    methods: Sequence[str] | None = None,
    *,
    fast: bool = False,
    repeat: int | None = None,
    sweep_points: int | None = None,
    sweep_measured: int | None = None,
    timeout: float | None = None,
    cache: bool = False,
    log: Callable[[str], None] | None = print,
) -> list[Row]:
    """Run the benchmark and return its rows.

    Parameters
    ----------
    problems
        Names of :data:`PROBLEMS` (default all).
    methods
        ``fnmatch`` patterns of method keys (``mlp1``, ``hb-exact-H5``, ``hb-*``, ``sweep``,
        default all).  The exact response (the reference) and the sweep (the unit of the
        time ratios) are always run and reported.
    fast
        One run per method, the brute-force sweep timed on 2 frequencies, timeout 10 s.
    repeat
        Most timed runs per method (default 1 with ``fast``, else 3); the median is
        reported.  A method is run again only while its runs took less than
        :data:`REPEAT_BUDGET` seconds in total.
    sweep_points
        Frequencies of the brute-force sweep's full grid (default 100, up and down).
    sweep_measured
        Frequencies of that grid the sweep is actually timed on (evenly spaced, ends
        included; default 2 with ``fast``, else 3); its time is extrapolated per frequency.
        The full grid when equal to ``sweep_points``.
    timeout
        Seconds after which a run of an approximation is stopped and recorded as a timeout
        (default 10 with ``fast``, else 90; 0: none).  Not applied to the exact reference
        nor the sweep.
    cache
        Let the symbolic methods use the on-disk derivation cache (default off: the time then
        includes the symbolic derivation, as on a first use).
    """
    say = log or (lambda _s: None)
    if timeout is None:
        timeout = 10.0 if fast else 90.0
    names = list(PROBLEMS) if problems is None else list(problems)
    for n in names:
        if n not in PROBLEMS:
            raise ValueError(f"unknown problem {n!r}: expected one of {', '.join(PROBLEMS)}")
    pats = None if methods is None else list(methods)
    rep = repeat if repeat is not None else (1 if fast else 3)
    n_full = sweep_points if sweep_points is not None else 100
    n_measured = sweep_measured if sweep_measured is not None else (2 if fast else 3)
    saved = {k: os.environ.get(k) for k in ("PERTURB_PROGRESS", "PERTURB_CACHE")}
    os.environ["PERTURB_PROGRESS"] = "0"
    if not cache:
        os.environ["PERTURB_CACHE"] = "0"
    rows: list[Row] = []
    try:
        for name in names:
            prob = PROBLEMS[name]
            t0, c0 = time.perf_counter(), time.process_time()
            rows.extend(_run_problem(prob, pats, fast, rep, n_full, n_measured, timeout, say))
            say(
                f"   ({name}: {time.perf_counter() - t0:.0f} s wall, "
                f"{time.process_time() - c0:.0f} s CPU, load {os.getloadavg()[0]:.1f})"
            )
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return rows


def _fmt(v: Any, kind: str) -> str:
    if isinstance(v, float):
        if not math.isfinite(v):
            return "–"
        if kind == "time":
            return f"{v:.3g}"
        return f"{v:.2e}" if v != 0 else "0 (reference)"
    return str(v)


def markdown_table(rows: Sequence[Row]) -> str:
    """The rows as a Markdown table (same columns as the CSV)."""
    heads = [
        "problem",
        "method",
        "setting",
        "status",
        "time [s]",
        "first run [s]",
        "runs",
        "time / sweep",
        "max rel. error",
        "RMS rel. error",
        "matched",
        "missed",
        "spurious",
        "note",
    ]
    kinds = ["", "", "", "", "time", "time", "", "time", "err", "err", "", "", "", ""]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for r in rows:
        cells = [_fmt(r.as_dict()[c], k) for c, k in zip(COLUMNS, kinds, strict=True)]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)


#: Accuracy levels of the summary table.
SUMMARY_TARGETS = (1e-1, 1e-2, 1e-3, 1e-4, 1e-6)


def _missed_count(text: str) -> int:
    """``'2/13'`` -> 2 (missed of the reference's branches); ``''`` -> 0."""
    head = text.split("/")[0].strip()
    return int(head) if head.isdigit() else 0


def cheapest_rows(
    rows: Sequence[Row], targets: Sequence[float] = SUMMARY_TARGETS
) -> list[tuple[str, float, Row | None]]:
    """For every problem and accuracy target, the fastest row that meets it.

    A row meets ``target`` when it ran (``status == 'ok'``), its max relative amplitude error
    against the exact reference is at most ``target`` and it missed no branch of the
    reference (a method that is accurate on the one branch it found does not answer the
    question). The exact reference meets every target by construction, so each entry names
    a method unless the exact run itself failed (then ``None``).

    Returns
    -------
    list of (problem, target, row or None)
    """
    out = []
    for prob in dict.fromkeys(r.problem for r in rows):
        mine = [r for r in rows if r.problem == prob and r.status == "ok"]
        for target in targets:
            ok = [
                r
                for r in mine
                if math.isfinite(r.time_s)
                and math.isfinite(r.max_rel_error)
                and r.max_rel_error <= target
                and _missed_count(r.missed) == 0
            ]
            out.append((prob, float(target), min(ok, key=lambda r: r.time_s) if ok else None))
    return out


def summary_table(rows: Sequence[Row], targets: Sequence[float] = SUMMARY_TARGETS) -> str:
    """Markdown table of :func:`cheapest_rows`: per problem and accuracy, the cheapest method,
    its time, its error and its speed-up over the exact response of the same run."""
    exact = {r.problem: r.time_s for r in rows if r.method == "exact" and r.status == "ok"}
    lines = [
        "| problem | max rel. error <= | cheapest method | setting | time [s] "
        "| max rel. error | exact time / time |",
        "|---|---|---|---|---|---|---|",
    ]
    for prob, target, r in cheapest_rows(rows, targets):
        if r is None:
            lines.append(f"| {prob} | {target:g} | – | – | – | – | – |")
            continue
        speed = exact.get(prob, math.nan) / r.time_s
        cells = [
            prob,
            f"{target:g}",
            r.method,
            r.setting,
            _fmt(r.time_s, "time"),
            _fmt(r.max_rel_error, "err"),
            f"{speed:.3g}" if math.isfinite(speed) else "–",
        ]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)


def _plot(rows: Sequence[Row], problem: str, path: Path) -> bool:
    import matplotlib
    import numpy as np

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [
        r
        for r in rows
        if r.problem == problem
        and r.status == "ok"
        and np.isfinite(r.time_s)
        and np.isfinite(r.max_rel_error)
        and r.max_rel_error > 0
    ]
    if not pts:
        return False
    fig, ax = plt.subplots(figsize=(7, 5))
    for r in pts:
        marker = "s" if r.method.startswith("hb-aft") else "o"
        if r.method.startswith("hb-exact"):
            marker = "D"
        # hollow: the method missed branches of the exact response (its error covers only
        # what it found), so a low point does not mean it answers the question
        missed = _missed_count(r.missed) > 0
        ax.loglog(
            r.time_s,
            r.max_rel_error,
            marker,
            label=f"{r.method} (max)",
            **({"markerfacecolor": "none"} if missed else {}),
        )
        if np.isfinite(r.rms_rel_error) and r.rms_rel_error > 0:
            ax.loglog(r.time_s, r.rms_rel_error, "x", color=ax.lines[-1].get_color())
        ax.annotate(r.method, (r.time_s, r.max_rel_error), fontsize=7, xytext=(3, 3),
                    textcoords="offset points")  # fmt: skip
    ref = [
        r
        for r in rows
        if r.problem == problem and r.method == "exact" and r.status == "ok"
        if np.isfinite(r.time_s)
    ]
    if ref:  # zero error: no place on a log axis, so its time is a line
        ax.axvline(ref[0].time_s, color="k", ls="--", lw=1)
        ax.annotate(
            "exact (reference)",
            (ref[0].time_s, 0.02),
            xycoords=("data", "axes fraction"),
            rotation=90,
            fontsize=7,
            xytext=(-9, 0),
            textcoords="offset points",
        )
    lc = any(r.problem == problem and r.setting.startswith("autonomous") for r in rows)
    ax.set_xlabel(
        "wall time of the whole limit-cycle curve [s]"
        if lc
        else "wall time of the whole frequency response [s]"
    )
    ax.set_ylabel("relative amplitude error vs exact (o/D/s max, x RMS)")
    ax.set_title(f"work-precision: {problem} (hollow: missed exact branches)")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def write_outputs(rows: Sequence[Row], out: str | Path, *, header: str = "") -> list[Path]:
    """Write ``work_precision.md``, ``work_precision.csv``, ``work_precision_summary.md`` (the
    cheapest method per accuracy, :func:`summary_table`) and the PNGs into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    csv_path = out / "work_precision.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(COLUMNS))
        w.writeheader()
        for r in rows:
            w.writerow(r.as_dict())
    written.append(csv_path)
    md = out / "work_precision.md"
    md.write_text(f"# Work-precision benchmark\n\n{header}\n\n{markdown_table(rows)}\n")
    written.append(md)
    summary = out / "work_precision_summary.md"
    summary.write_text(
        "# Cheapest method per accuracy\n\n"
        "Per problem and accuracy: the fastest method whose max relative amplitude error "
        "against the exact response is at most the target and which missed none of its "
        f"branches (from work_precision.csv).\n\n{summary_table(rows)}\n"
    )
    written.append(summary)
    for prob in dict.fromkeys(r.problem for r in rows):
        png = out / f"work_precision_{prob}.png"
        if _plot(rows, prob, png):
            written.append(png)
    return written


def _split(text: str | None) -> list[str] | None:
    if text is None:
        return None
    return [t.strip() for t in text.split(",") if t.strip()]


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``bench`` subcommand to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser(
        "bench",
        help="work-precision benchmark of every method (Markdown, CSV, PNG)",
        description=__doc__.splitlines()[0],
    )
    _arguments(p)
    p.set_defaults(func=cmd_bench)
    return p


def _arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--fast",
        action="store_true",
        help="1 run per method, sweep timed on 2 frequencies, timeout 10 s",
    )
    p.add_argument("--out", default="out/bench", help="output directory (default out/bench)")
    p.add_argument(
        "--problems", help=f"comma-separated subset of: {', '.join(PROBLEMS)} (default all)"
    )
    p.add_argument(
        "--methods",
        help="comma-separated fnmatch patterns of method keys: exact, sweep, mlp1, mlp2, ms, "
        "kb, hb1, vdp, lp, hb-exact-H<H>, hb-aft-H<H> (e.g. 'hb-*,mlp1'; default all)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        help="seconds before a run of a method is stopped (default 10 fast, else 90; 0: none)",
    )
    p.add_argument(
        "--cache",
        action="store_true",
        help="use the derivation cache (default: off, times include the symbolic derivation)",
    )
    p.add_argument("--repeat", type=int, help="most timed runs per method (default 1 fast, else 3)")
    p.add_argument(
        "--sweep-points", type=int, help="frequencies of the brute-force sweep (default 100)"
    )
    p.add_argument(
        "--sweep-measured",
        type=int,
        help="frequencies the sweep is timed on, extrapolated to --sweep-points "
        "(default 2 fast, else 3)",
    )


def cmd_bench(args: argparse.Namespace) -> int:
    """The ``perturb bench`` command."""
    import numpy as np

    t0, c0, load0 = time.perf_counter(), time.process_time(), os.getloadavg()[0]
    rows = run_benchmark(
        _split(args.problems),
        _split(args.methods),
        fast=args.fast,
        repeat=args.repeat,
        sweep_points=args.sweep_points,
        sweep_measured=args.sweep_measured,
        timeout=args.timeout,
        cache=args.cache,
        log=lambda m: print(m, flush=True),
    )
    total = time.perf_counter() - t0
    cpu = time.process_time() - c0
    header = (
        f"Mode: {'--fast' if args.fast else 'full'}; total {total:.0f} s wall, {cpu:.0f} s "
        f"CPU; python {platform.python_version()}, numpy {np.__version__}; load average "
        f"{load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end, on "
        f"{os.cpu_count()} cores (the load inflates wall times).\n\n"
        "Time: median wall time of the whole frequency response over the window ("
        + ("derivation cache on" if args.cache else "symbolic derivation and compilation included")
        + f"); a method is run again (up to --repeat runs) only while its runs took less "
        f"than {REPEAT_BUDGET:g} s; `first run` is the first, with cold in-process caches. "
        "The exact response is computed once per problem and is the reference of every row. "
        "Errors: `compare(resp, exact)` max / RMS relative amplitude error over matched "
        "branches. `time / sweep`: ratio to the brute-force solve_ivp stepped-sine sweep "
        "(up and down), whose time is measured on a few evenly spaced frequencies of its "
        "grid and EXTRAPOLATED per frequency to the full grid when its setting says so. "
        "van der Pol (`vdp`): limit cycle over eps, errors of the amplitude max|x| at each eps."
    )
    for p in write_outputs(rows, args.out, header=header):
        print(f"wrote {p}")
    print("\ncheapest method per accuracy:\n" + summary_table(rows))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="work_precision", description=__doc__.splitlines()[0])
    _arguments(p)
    return cmd_bench(p.parse_args(argv))
