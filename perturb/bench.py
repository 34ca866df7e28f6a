"""Work-precision benchmark: wall time of a whole frequency response against its error.

For a fixed set of problems every applicable method and setting is run over the problem's
frequency window, timed (median of ``repeat`` runs; the time includes deriving and compiling
the approximation, i.e. what a user waits for) and compared with the exact response
(:func:`perturb.numeric.compare.compare`: max / RMS relative amplitude error over the matched
branches).  Times are also given as ratios to a brute-force stepped-sine sweep
(:func:`perturb.simulate.sweeps.frequency_sweep` with the plain ODE flow, up and down) run in
the same process.  A method that fails or does not apply is a row ``n/a (reason)``.

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
from typing import Any

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
    """One benchmark problem: a builtin model, its parameters and frequency window."""

    name: str
    model: str
    params: dict[str, float]
    window: tuple[float, float]
    description: str

    def oscillator(self):
        from .model import builtin_model

        return builtin_model(self.model, **self.params)


#: The fixed problem set (issue 7 item 1).  The van der Pol limit cycle is not in it yet.
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
    )
}

HB_HARMONICS = (1, 3, 5, 9, 15, 31)


@dataclass(frozen=True)
class Setting:
    """One method/setting: ``key`` selects it (``--methods``), ``method`` and ``kwargs`` go to
    :func:`perturb.api.frequency_response`."""

    key: str
    method: str
    setting: str
    kwargs: dict[str, Any] = field(default_factory=dict)


def method_settings() -> list[Setting]:
    """Every method/setting tried on each problem (``exact`` and ``sweep`` are added apart)."""
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
                    f"H={h}, projection={proj}",
                    {"harmonics": h, "projection": proj},
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


def _timed(fn: Callable[[], Any], repeat: int, timeout: float | None = None) -> tuple[float, Any]:
    """Median wall time of ``repeat`` calls, and the last result.  With ``timeout`` (seconds,
    per call; needs SIGALRM and the main thread) a longer call raises :class:`MethodTimeout`."""
    use_alarm = (
        timeout is not None
        and timeout > 0
        and hasattr(signal, "setitimer")
        and threading.current_thread() is threading.main_thread()
    )
    times, out = [], None
    for _ in range(max(1, repeat)):
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
    return statistics.median(times), out


def _fill_errors(row: Row, resp: Any, ref: Any) -> None:
    from .numeric.compare import compare

    c = compare(resp, ref)
    row.max_rel_error = c.max_error
    row.rms_rel_error = c.rms_error
    row.matched = f"{len(c.matches)}/{len(c.branches)}"
    row.missed = f"{len(c.missed)}/{len(c.reference_branches)}"
    row.spurious = str(len(c.spurious))
    if not c.matches:
        row.note = (row.note + "; " if row.note else "") + "no branch matched the exact response"


def _selected(key: str, patterns: Sequence[str] | None) -> bool:
    return patterns is None or any(fnmatch.fnmatchcase(key, p) for p in patterns)


def _run_problem(
    prob: Problem,
    pats: list[str] | None,
    fast: bool,
    rep: int,
    n_full: int,
    n_coarse: int,
    timeout: float | None,
    say: Callable[[str], None],
) -> list[Row]:
    from .api import frequency_response
    from .simulate.sweeps import frequency_sweep

    name = prob.name
    osc = prob.oscillator()
    lo, hi = prob.window
    say(f"== {name}: {prob.description}, Omega in [{lo}, {hi}]")
    # -- exact reference (also a timed row)
    ex = Row(name, "exact", "continuation of exact orbits")
    ref = None
    try:
        ex.time_s, ref = _timed(lambda: frequency_response(osc, "exact", Omega=(lo, hi)), rep)
        ex.repeats = rep
        ex.note = f"reference ({ref.method}, {sum(len(b) for b in ref.branches)} points)"
        ex.matched = f"{len(ref.branches)}/{len(ref.branches)}"
        ex.max_rel_error = ex.rms_rel_error = 0.0
    except Exception as exc:  # noqa: BLE001 - recorded in the table
        ex.status = _reason(exc)
    say(f"   exact: {ex.time_s:.3g} s {ex.status}")
    # -- brute-force sweep (the time unit of the ratios)
    sw = Row(name, "sweep", f"solve_ivp (DOP853) stepped sine up+down, {n_full} frequencies")
    sweep_time = math.nan
    # always run (the ratios need it), whatever --methods selects
    if n_coarse > 0:
        grid = np.linspace(lo, hi, n_coarse)
        try:
            t, sres = _timed(
                lambda g=grid: frequency_sweep(
                    osc, g, direction="both", method="ode", progress=False
                ),
                1 if fast else rep,
            )
            sw.repeats = 1 if fast else rep
            sweep_time = t * n_full / n_coarse
            sw.time_s = sweep_time
            if n_coarse != n_full:
                sw.note = (
                    f"measured on {n_coarse} frequencies ({t:.3g} s), extrapolated per "
                    f"frequency to {n_full}"
                )
            if ref is not None:
                _fill_errors(sw, sres.to_response(), ref)
                sw.note += ("; " if sw.note else "") + "stable branches only"
        except Exception as exc:  # noqa: BLE001 - recorded in the table
            sw.status = _reason(exc)
    say(f"   sweep: {sw.time_s:.3g} s {sw.status} {sw.note}")
    out_rows = [ex, sw]
    # -- the approximations
    for s in method_settings():
        if not _selected(s.key, pats):
            continue
        row = Row(name, s.key, s.setting)
        try:
            row.time_s, resp = _timed(
                lambda s=s: frequency_response(osc, s.method, Omega=(lo, hi), **s.kwargs),
                rep,
                timeout,
            )
            row.repeats = rep
        except MethodTimeout:
            row.status = f"timeout (stopped after {timeout:g} s)"
            say(f"   {s.key}: {row.status}")
            out_rows.append(row)
            continue
        except Exception as exc:  # noqa: BLE001 - recorded in the table
            row.status = _reason(exc)
            say(f"   {s.key}: {row.status}")
            out_rows.append(row)
            continue
        if ref is None:
            row.note = "no exact reference: error not measured"
        else:
            try:
                _fill_errors(row, resp, ref)
            except Exception as exc:  # noqa: BLE001 - recorded in the table
                row.note = f"comparison failed: {_reason(exc)[4:-1]}"
        say(
            f"   {s.key}: {row.time_s:.3g} s, max {row.max_rel_error:.3g}, "
            f"rms {row.rms_rel_error:.3g} {row.note}"
        )
        out_rows.append(row)
    for r in out_rows:
        if r.status == "ok" and np.isfinite(sweep_time) and sweep_time > 0:
            r.time_vs_sweep = r.time_s / sweep_time
    return out_rows


def run_benchmark(
    problems: Sequence[str] | None = None,
    methods: Sequence[str] | None = None,
    *,
    fast: bool = False,
    repeat: int | None = None,
    sweep_points: int | None = None,
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
        One repeat, and the brute-force sweep on a coarse grid, its time extrapolated to the
        full grid per frequency.
    repeat
        Timed runs per method (default 1 with ``fast``, else 3); the median is reported.
    sweep_points
        Frequencies of the brute-force sweep's full grid (default 100, up and down).
    timeout
        Seconds after which an approximation is stopped and recorded as a timeout (default
        10 with ``fast``, else 600; 0: none).  Not applied to the exact reference nor the
        sweep.
    cache
        Let the symbolic methods use the on-disk derivation cache (default off: the time then
        includes the symbolic derivation, as on a first use).
    """
    say = log or (lambda _s: None)
    if timeout is None:
        timeout = 10.0 if fast else 600.0
    names = list(PROBLEMS) if problems is None else list(problems)
    for n in names:
        if n not in PROBLEMS:
            raise ValueError(f"unknown problem {n!r}: expected one of {', '.join(PROBLEMS)}")
    pats = None if methods is None else list(methods)
    rep = repeat if repeat is not None else (1 if fast else 3)
    n_full = sweep_points if sweep_points is not None else 100
    n_coarse = min(n_full, 2) if fast else n_full
    saved = {k: os.environ.get(k) for k in ("PERTURB_PROGRESS", "PERTURB_CACHE")}
    os.environ["PERTURB_PROGRESS"] = "0"
    if not cache:
        os.environ["PERTURB_CACHE"] = "0"
    rows: list[Row] = []
    try:
        for name in names:
            prob = PROBLEMS[name]
            rows.extend(_run_problem(prob, pats, fast, rep, n_full, n_coarse, timeout, say))
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
        "repeats",
        "time / sweep",
        "max rel. error",
        "RMS rel. error",
        "matched",
        "missed",
        "spurious",
        "note",
    ]
    kinds = ["", "", "", "", "time", "", "time", "err", "err", "", "", "", ""]
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for r in rows:
        cells = [_fmt(r.as_dict()[c], k) for c, k in zip(COLUMNS, kinds, strict=True)]
        lines.append("| " + " | ".join(c.replace("|", "/") for c in cells) + " |")
    return "\n".join(lines)


def _plot(rows: Sequence[Row], problem: str, path: Path) -> bool:
    import matplotlib

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
        ax.loglog(r.time_s, r.max_rel_error, marker, label=f"{r.method} (max)")
        if np.isfinite(r.rms_rel_error) and r.rms_rel_error > 0:
            ax.loglog(r.time_s, r.rms_rel_error, "x", color=ax.lines[-1].get_color())
        ax.annotate(r.method, (r.time_s, r.max_rel_error), fontsize=7, xytext=(3, 3),
                    textcoords="offset points")  # fmt: skip
    ax.set_xlabel("wall time of the whole frequency response [s]")
    ax.set_ylabel("relative amplitude error vs exact (o/D/s max, x RMS)")
    ax.set_title(f"work-precision: {problem}")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def write_outputs(rows: Sequence[Row], out: str | Path, *, header: str = "") -> list[Path]:
    """Write ``work_precision.md``, ``work_precision.csv`` and the PNGs into ``out``."""
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
        help="1 repeat, brute-force sweep on a coarse grid extrapolated (a few minutes)",
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
        help="seconds before a method is stopped (default 10 fast, else 600; 0: none)",
    )
    p.add_argument(
        "--cache",
        action="store_true",
        help="use the derivation cache (default: off, times include the symbolic derivation)",
    )
    p.add_argument("--repeat", type=int, help="timed runs per method (default 1 fast, else 3)")
    p.add_argument(
        "--sweep-points", type=int, help="frequencies of the brute-force sweep (default 100)"
    )


def cmd_bench(args: argparse.Namespace) -> int:
    """The ``perturb bench`` command."""
    t0 = time.perf_counter()
    rows = run_benchmark(
        _split(args.problems),
        _split(args.methods),
        fast=args.fast,
        repeat=args.repeat,
        sweep_points=args.sweep_points,
        timeout=args.timeout,
        cache=args.cache,
        log=lambda m: print(m, flush=True),
    )
    total = time.perf_counter() - t0
    header = (
        f"Mode: {'--fast' if args.fast else 'full'}; total {total:.0f} s; python "
        f"{platform.python_version()}, numpy {np.__version__}; load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores.\n\n"
        "Time: median wall time of the whole frequency response over the window ("
        + ("derivation cache on" if args.cache else "symbolic derivation and compilation included")
        + "). Errors: `compare(resp, exact)` max / RMS relative "
        "amplitude error over matched branches. `time / sweep`: ratio to the brute-force "
        "solve_ivp stepped-sine sweep (up and down)"
        + (
            ", which in --fast is measured on a coarse grid and extrapolated per frequency."
            if args.fast
            else "."
        )
    )
    for p in write_outputs(rows, args.out, header=header):
        print(f"wrote {p}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="work_precision", description=__doc__.splitlines()[0])
    _arguments(p)
    return cmd_bench(p.parse_args(argv))
