"""Benchmark: the exact frequency response of the nsd oscillator by continuation.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_continuation.py

Model: x'' + mu x' + kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)] = F cos(W t), k = -3, mu = 0.05,
F = 2, W in [0.2, 2] (Zou-Nagarajaiah Fig. 17d), all branches at 0.5 % output spacing
(``ds_max = 0.005``: consecutive points differ by at most 0.5 % of the window in W and 0.5 % in
amplitude).

* ``exact_branches`` with its defaults: closed-form seeds, virtual sweeps up and down (60
  frequencies), branch switching at every branch point, mirror images, refined folds; run
  serially (``workers=1``) and with two worker processes (``workers=2``: both halves of every
  branch at once, the closed-form seeds' branches at once; same branches, checked here point
  by point); and with the single-harmonic-balance approximation as the only extra seed source
  (no sweeps).
* CPU time: ``time.process_time`` of this process, plus (pool) the CPU time of the reaped
  worker processes (``resource.getrusage(RUSAGE_CHILDREN)``); the 1-minute load average at the
  end of every run is printed with it (other people's jobs inflate the wall time, and the
  pool's wall time most: its two halves then share the cores with them).
* the detached branch alone (``continue_orbits`` from the cross-well orbit at W = 0.6: the
  run that stalled at the branch point W ~ 0.4835 in the first version and took ~700 s).
* brute force: ``frequency_sweep(method="ode")`` (solve_ivp DOP853 rtol 1e-10, up and down,
  up to 200 transient periods) over the same W grid (0.5 % of the window: 201 frequencies);
  it is run on every ``--bf-stride``-th frequency and its cost per frequency extrapolated to
  the 201 (it finds stable orbits only).

The machine is shared: the exact propagator's cost per forcing period is measured before and
after (``calibration``), and times are also given in those units, which carry over to an idle
machine.  ``--profile`` adds a cProfile of the default run (share of the propagator).
"""

from __future__ import annotations

import argparse
import cProfile
import math
import os
import platform
import pstats
import resource
import statistics
import sys
import time

import numpy as np
import scipy

from perturb.model.builtins import builtin_model
from perturb.simulate.exact_response import continue_orbits, exact_branches
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.studies import frequency_sweep

PARAMS = {"k": -3.0, "mu": 0.05, "F": 2.0}
WINDOW = (0.2, 2.0)


def calibrate(n: int = 200) -> float:
    """Median seconds of one exact propagation over one forcing period, with sensitivity
    (the cross-well orbit at W = 0.6, 4 switches per period)."""
    flow = FlowFamily(builtin_model("nsd", **PARAMS)).at(0.6)
    y = np.array([11.43532506, 1.58868563])
    times = []
    for i in range(n):
        t = time.perf_counter()
        flow(y + 1e-9 * i, 0.0, flow.period, sensitivity=True)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def row(name: str, seconds: float, cal: float, extra: str, cpu: float = math.nan) -> str:
    return f"{name:<44} {seconds:9.2f} s {cpu:8.2f} s {seconds / cal:10.0f}   {extra}"


def _children_cpu() -> float:
    """User + system CPU seconds of reaped child processes (the pool's workers)."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


class Clock:
    """Wall and CPU time of one run (``time.process_time`` plus the CPU time of child
    processes reaped during it), and the load average at its end (a shared machine inflates
    the wall time; the CPU time much less)."""

    def __enter__(self) -> Clock:
        self.w, self.c, self.k = time.perf_counter(), time.process_time(), _children_cpu()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall = time.perf_counter() - self.w
        self.own = time.process_time() - self.c
        self.children = _children_cpu() - self.k
        self.cpu = self.own + self.children
        self.load = os.getloadavg()[0]


def same_branches(a, b) -> bool:
    """Point-by-point equality of two exact_branches results (serial vs pool)."""
    if len(a.branches) != len(b.branches) or a.mirror_of != b.mirror_of:
        return False
    for x, y in zip(a.branches, b.branches, strict=True):
        if len(x) != len(y) or x.stop_reason != y.stop_reason:
            return False
        for p, q in zip(x.points, y.points, strict=True):
            if p.parameter != q.parameter or not np.array_equal(p.y0, q.y0):
                return False
        sa = [(s.kind, s.index, s.parameter) for s in x.special_points]
        if sa != [(s.kind, s.index, s.parameter) for s in y.special_points]:
            return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bf-stride", type=int, default=10, help="brute force on every n-th W")
    ap.add_argument("--profile", action="store_true", help="cProfile the default run")
    args = ap.parse_args()
    os.environ.setdefault("PERTURB_PROGRESS", "0")
    print("command: PYTHONPATH=. python benchmarks/bench_continuation.py")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{os.cpu_count()} cpus, load average {os.getloadavg()[0]:.2f} (1 min)"
    )
    osc = builtin_model("nsd", **PARAMS)
    cal0 = calibrate()
    print(f"calibration: {cal0 * 1e3:.3f} ms per exact propagation of one forcing period")
    print()
    print(f"{'run':<44} {'wall':>11} {'CPU':>10} {'periods eq.':>10}   result")
    lines = []

    with Clock() as ck:
        res = exact_branches(osc, WINDOW, progress=False, workers=1)
    t_def, c_def = ck.wall, ck.cpu
    n_pts = sum(len(b) for b in res.branches)
    closed = sum(q.source == "closed form" for b in res.branches for q in b.points)
    lines.append(
        row(
            "exact_branches (defaults, workers=1)",
            t_def,
            cal0,
            f"{len(res.branches)} branches, {n_pts} points ({closed} closed form), "
            f"{res.periods:.0f} periods propagated; load {ck.load:.2f} at the end",
            c_def,
        )
    )
    print(lines[-1])

    with Clock() as ck:
        res2 = exact_branches(osc, WINDOW, progress=False, workers=2)
    t_par, c_par = ck.wall, ck.cpu
    lines.append(
        row(
            "exact_branches (defaults, workers=2)",
            t_par,
            cal0,
            f"same branches as workers=1: {same_branches(res, res2)}; CPU {ck.own:.2f} s here "
            f"+ {ck.children:.2f} s workers; load {ck.load:.2f} at the end",
            c_par,
        )
    )
    print(lines[-1])

    from perturb.methods.harmonic_balance import single_harmonic_balance
    from perturb.seeds import approximation_seeds

    hb = single_harmonic_balance(osc)
    with Clock() as ck:
        hb_seeds = approximation_seeds(hb, WINDOW, 16)
        res_hb = exact_branches(osc, WINDOW, seeds=hb_seeds, sweep_points=0, progress=False)
    t_hb = ck.wall
    lines.append(
        row(
            "exact_branches (HB seeds, no sweeps)",
            t_hb,
            cal0,
            f"{len(res_hb.branches)} branches, {sum(len(b) for b in res_hb.branches)} points, "
            f"{res_hb.periods:.0f} periods",
            ck.cpu,
        )
    )
    print(lines[-1])

    with Clock() as ck:
        iso = continue_orbits(osc, 0.6, [11.43532506, 1.58868563], WINDOW)
    t_iso = ck.wall
    lines.append(
        row(
            "continue_orbits (detached branch from 0.6)",
            t_iso,
            cal0,
            f"{len(iso)} points, {iso.periods:.0f} periods "
            f"({iso.periods / len(iso):.2f} per point), ends: {iso.stop_reason}",
            ck.cpu,
        )
    )
    print(lines[-1])

    grid = np.linspace(*WINDOW, 201)
    sub = grid[:: max(1, args.bf_stride)]
    with Clock() as ck:
        sweep = frequency_sweep(
            osc,
            sub,
            direction="both",
            method="ode",
            transient_periods=200,
            record_periods=2,
            multipliers=False,
            progress=False,
        )
    t_bf, c_bf = ck.wall, ck.cpu
    per = t_bf / (2 * sub.size)
    t_bf_full = per * 2 * grid.size
    n_p1 = sum(int(np.sum(b.period == 1)) for b in sweep.branches)
    lines.append(
        row(
            f"brute force solve_ivp sweep ({sub.size} of 201 W, x2)",
            t_bf,
            cal0,
            f"{per:.2f} s per frequency; {n_p1} of {2 * sub.size} settled on period-1 orbits",
            c_bf,
        )
    )
    print(lines[-1])
    c_bf_full = c_bf * grid.size / sub.size
    lines.append(row("  extrapolated to the 201-point grid", t_bf_full, cal0, "", c_bf_full))
    print(lines[-1])

    cal1 = calibrate()
    cal = 0.5 * (cal0 + cal1)
    print()
    print(f"calibration after: {cal1 * 1e3:.3f} ms per period (mean {cal * 1e3:.3f} ms)")
    print(
        f"brute force / exact_branches = {t_bf_full / t_def:.1f} (wall), "
        f"{c_bf_full / c_def:.1f} (CPU) (the brute force finds stable orbits only)"
    )
    print(
        f"brute force / exact_branches (workers=2) = {t_bf_full / t_par:.1f} (wall), "
        f"{c_bf_full / c_par:.1f} (CPU, all processes)"
    )
    print(f"exact_branches (workers=1): {t_def:.2f} s wall, {c_def:.2f} s CPU; target <= 5 s")
    print(
        f"exact_branches (workers=2): {t_par:.2f} s wall, {c_par:.2f} s CPU (all processes); "
        f"serial / pool wall = {t_def / t_par:.2f}"
    )
    print(
        f"exact_branches (defaults) = {t_def / cal:.0f} exact periods of work "
        f"({res.periods:.0f} propagated + overhead); at 1 ms per period: {t_def / cal * 1e-3:.1f} s"
    )
    print()
    print("branches (defaults):")
    print(repr(res))

    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        exact_branches(osc, WINDOW, progress=False, workers=1)
        prof.disable()
        st = pstats.Stats(prof)
        total = st.total_tt
        prop = sum(
            v[3]
            for k, v in st.stats.items()
            if k[2] == "propagate" and k[0].endswith("piecewise_exact.py")
        )
        print()
        print(f"profile: {total:.1f} s under cProfile, propagate {prop / total:.0%} of it")
        st.sort_stats("tottime").print_stats(12)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
