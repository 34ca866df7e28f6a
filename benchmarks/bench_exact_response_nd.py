"""Benchmark: the whole exact frequency response of the 2-DOF nsd structure against the
brute-force solve_ivp sweep a user would write.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_exact_response_nd.py            # nsd2, whole sweep
    PYTHONPATH=. python benchmarks/bench_exact_response_nd.py --sdof     # also SDOF nsd k=-0.5

Model ``builtin_system('nsd2')`` (k = -0.5, mu1 = 0.05, mu2 = 0.02, k2 = 1, m2 = 1, F = 2), the
resonance window W in [0.5, 2] (both modes of the structure, the device's wells):

* exact: :func:`perturb.simulate.exact_response.exact_branches` with its defaults, serial
  (``workers=1``): every branch (stable and unstable, folds, branch points, closed loops,
  mirror images), exact multipliers, every coordinate's max |.| and mean.
* brute force: what a user writes: the equations as a plain Python ``rhs``, ``solve_ivp``
  (DOP853, rtol = atol = 1e-8) at 100 frequencies swept up and then down (200 runs), each
  starting from the previous end state; the transient is integrated period by period until
  the stroboscopic points repeat with a period m <= 8 to ``--settle-tol`` (relative to
  1 + max |y|), at most 400 periods: the settling rule and caps of the library's stepped-sine
  sweep (:class:`perturb.simulate.studies.SweepOptions`; on a torus, after a Neimark-Sacker
  bifurcation, the sweep never settles and runs the 400 periods), then 5 periods are sampled
  (200 samples per period) for max |x1|, max |x2|. The default settling tolerance is 1e-8,
  the library's own stepped-sine sweep (``SweepOptions.tol``, used by the SDOF benchmark
  ``bench_exact_vs_sweep.py``); by default the brute force also runs with 1e-6 (a looser
  user) and both ratios are printed (``--settle-tol 1e-8`` runs one).  ``--transient N``
  discards a fixed N periods instead (100 is too few here: many rows are still drifting).
  It finds stable orbits only (one per frequency and direction).
* ``--sdof``: the same for the one-coordinate ``nsd`` at k = -0.5 over W in [0.3, 2] (the
  issue's ">= 100x serial" goal for the oscillator).

Both are timed by CPU time of this process (``time.process_time``: the machine is shared, and
the wall time of either is inflated by other jobs), after one warm-up call of the exact solver
on a small window when the compiled kernels (numba, ``pip install perturb[fast]``) are in use
(it loads them from numba's cache, or compiles them once per installation), interleaved:
exact, brute force (each settling tolerance), exact (the ratios use the mean of the two exact
runs).
``--bf-stride n`` runs the brute force on every n-th frequency of each sweep and scales its
time by n (an estimate: each frequency costs about the same number of periods whatever the
previous state).
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import numpy as np
import scipy
from scipy.integrate import solve_ivp

from perturb.model.builtins import builtin_model
from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import exact_branches
from perturb.simulate.flows.scan_kernel import compiled_scan

NSD2 = {"k": -0.5, "mu1": 0.05, "mu2": 0.02, "k2": 1.0, "m2": 1.0, "F": 2.0}
WINDOW_2DOF = (0.5, 2.0)
NSD = {"k": -0.5, "mu": 0.05, "F": 2.0}
WINDOW_SDOF = (0.3, 2.0)
RTOL = 1e-8
MEASURE, SAMPLES = 5, 200
#: settling test of the brute force: chunks of periods, relative repeat tolerance, cap
MAX_TRANSIENT, MAX_PERIOD = 400, 8
SETTLE_TOLS = (1e-8, 1e-6)


def rhs_nsd2(W, k, mu1, mu2, k2, m2, F):
    def rhs(t, y):
        x1, x2, v1, v2 = y
        nsd = k * x1 + (1 - k) * ((x1 - 1) * (x1 > 1) + (x1 + 1) * (x1 < -1))
        a1 = F * math.cos(W * t) - mu1 * v1 - mu2 * (v1 - v2) - nsd - k2 * (x1 - x2)
        a2 = (-mu2 * (v2 - v1) - k2 * (x2 - x1)) / m2
        return [v1, v2, a1, a2]

    return rhs


def rhs_nsd(W, k, mu, F):
    def rhs(t, y):
        x, v = y
        nsd = k * x + (1 - k) * ((x - 1) * (x > 1) + (x + 1) * (x < -1))
        return [v, F * math.cos(W * t) - mu * v - nsd]

    return rhs


def period_of(strobe, tol):
    """Smallest m <= MAX_PERIOD whose last 2m + 1 stroboscopic points repeat with period m
    to ``tol`` relative to 1 + max |point| (the residual of the library's stepped-sine sweep,
    ``perturb.simulate.studies``); 0 when none does."""
    P = np.asarray(strobe)
    w = min(2 * MAX_PERIOD + 1, len(P))
    scale = 1.0 + float(np.max(np.abs(P[len(P) - w :])))
    for m in range(1, MAX_PERIOD + 1):
        if len(P) < 2 * m + 1:
            break
        tail = P[len(P) - 2 * m - 1 :]
        if float(np.max(np.abs(tail[m:] - tail[:-m]))) <= tol * scale:
            return m
    return 0


def settle(rhs, y, T, transient=None, tol=1e-8):
    """The state after the transient: a fixed number of periods, or period by period until
    the stroboscopic points repeat with some period m <= MAX_PERIOD to ``tol`` (at most
    MAX_TRANSIENT periods), as the library's stepped-sine sweep settles (one integration per
    forcing period, so every stroboscopic point is an integration end point: a dense-output
    value would differ from it by the interpolation error, ~1e-8 at rtol 1e-8, and a 1e-8
    test could never pass).  Returns (state, periods integrated, settled)."""
    if transient is not None:
        s = solve_ivp(rhs, (0, transient * T), y, method="DOP853", rtol=RTOL, atol=RTOL)
        return s.y[:, -1], transient, True
    strobe = [y]
    n = 0
    while n < MAX_TRANSIENT:
        s = solve_ivp(rhs, (n * T, (n + 1) * T), y, method="DOP853", rtol=RTOL, atol=RTOL)
        y, n = s.y[:, -1], n + 1
        strobe.append(y)
        del strobe[: max(0, len(strobe) - (2 * MAX_PERIOD + 1))]
        if period_of(strobe, tol):
            return y, n, True
    return y, n, False


def brute_sweep(make_rhs, params, window, n_states, stride=1, transient=None, n=100, tol=1e-8):
    """Up and down sweep of ``n`` frequencies (every ``stride``-th): (CPU seconds scaled by
    ``stride``, rows (W, max|x1|, ...), periods integrated (scaled), rows not settled)."""
    grid = np.linspace(window[0], window[1], n)
    rows = []
    periods = unsettled = 0
    c0 = time.process_time()
    for sweep in (grid, grid[::-1]):
        y = np.zeros(n_states)
        for W in sweep[::stride]:
            T = 2 * math.pi / W
            rhs = make_rhs(W, **params)
            y, k, ok = settle(rhs, y, T, transient, tol)
            periods += k + MEASURE
            unsettled += not ok
            s = solve_ivp(
                rhs, (0, MEASURE * T), y, method="DOP853", rtol=RTOL, atol=RTOL, dense_output=True
            )
            X = s.sol(np.linspace(0, MEASURE * T, SAMPLES * MEASURE))
            rows.append((W, *np.abs(X[: n_states // 2]).max(axis=1)))
            y = s.y[:, -1]
    return (time.process_time() - c0) * stride, rows, periods * stride, unsettled


def exact_run(model, window, ds_max):
    c0 = time.process_time()
    res = exact_branches(model, window, workers=1, progress=False, ds_max=ds_max)
    return time.process_time() - c0, res


def compare(name, model, window, make_rhs, params, n_states, stride, transient, ds_max, tols):
    c1, res = exact_run(model, window, ds_max)
    brute = [
        (tol, *brute_sweep(make_rhs, params, window, n_states, stride, transient, tol=tol))
        for tol in (tols if transient is None else (None,))
    ]
    c2, _ = exact_run(model, window, ds_max)
    ce = 0.5 * (c1 + c2)
    pts = sum(len(b) for b in res.branches)
    stable = sum(int(q.stable) for b in res.branches for q in b.points)
    print(f"\n{name}: W in {window}")
    print(
        f"  exact_branches (serial, ds_max {ds_max:g}): {len(res.branches)} branches, {pts} "
        f"points, {stable} stable"
    )
    print(f"    CPU {c1:.2f} s and {c2:.2f} s (interleaved runs), {res.periods:.0f} periods")
    amps = np.array([q.amplitude for b in res.branches for q in b.points if q.stable])
    ws = np.array([q.parameter for b in res.branches for q in b.points if q.stable])
    ratios = []
    for tol, cb, rows, periods, unsettled in brute:
        how = (
            f"{transient} periods"
            if transient is not None
            else f"until settled to {tol:g} (cap {MAX_TRANSIENT})"
        )
        print(
            f"  brute force DOP853 rtol {RTOL:g} up/down sweep of 100 W ({len(rows)} runs, "
            f"stride {stride}, transient {how} + {MEASURE} periods): CPU {cb:.2f} s, "
            f"{periods} periods, {unsettled} runs unsettled"
            + (" (scaled by the stride)" if stride > 1 else "")
        )
        print(f"  ratio brute force / exact (CPU, serial): {cb / ce:.1f}x")
        # the brute force's settled stable orbits lie on the exact branches (a check of both)
        off = 0
        for W, a1, *_ in rows:
            near = np.abs(ws - W) < 0.01 * (window[1] - window[0])
            if not np.any(np.abs(amps[near] - a1) < 0.02 * max(1.0, a1)):
                off += 1
        print(f"  brute-force rows without a stable exact point within 1 % (W), 2 % (amp): {off}")
        ratios.append(cb / ce)
    return ratios


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bf-stride", type=int, default=1, help="brute force on every n-th W")
    ap.add_argument("--sdof", action="store_true", help="also the SDOF nsd at k = -0.5")
    ap.add_argument("--transient", type=int, default=None, help="fixed transient periods")
    ap.add_argument("--ds-max", type=float, default=0.005, help="exact output spacing")
    ap.add_argument(
        "--settle-tol",
        type=float,
        nargs="+",
        default=list(SETTLE_TOLS),
        help="brute-force settling tolerance(s) (default 1e-8 = the library sweep, and 1e-6)",
    )
    ap.add_argument(
        "--window", type=float, nargs=2, default=WINDOW_2DOF, help="nsd2 frequency window"
    )
    args = ap.parse_args()
    os.environ.setdefault("PERTURB_PROGRESS", "0")
    cmd = "PYTHONPATH=. python benchmarks/bench_exact_response_nd.py"
    extra = (f" --bf-stride {args.bf_stride}" if args.bf_stride != 1 else "") + (
        " --sdof" if args.sdof else ""
    )
    if args.transient is not None:
        extra += f" --transient {args.transient}"
    if args.ds_max != 0.005:
        extra += f" --ds-max {args.ds_max:g}"
    if tuple(args.settle_tol) != SETTLE_TOLS:
        extra += " --settle-tol " + " ".join(f"{v:g}" for v in args.settle_tol)
    if tuple(args.window) != WINDOW_2DOF:
        extra += f" --window {args.window[0]:g} {args.window[1]:g}"
    print(f"command: {cmd}{extra}")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{os.cpu_count()} cpus, load average {os.getloadavg()[0]:.2f} (1 min)"
    )
    kernel = compiled_scan()
    if kernel is None:
        print("compiled kernels: off (numba not installed, or PERTURB_COMPILED=0): pure numpy")
    else:
        import numba

        # the kernels are compiled once per installation (numba's cache) and loaded at their
        # first call in a process: that first call is timed here, not in the rows below
        c0 = time.process_time()
        # ((1.15, 1.35): orbits with switches, so both the scan and the statistics kernel run)
        exact_branches(
            builtin_system("nsd2", **NSD2), (1.15, 1.35), workers=1, progress=False,
            attractors=False,
        )  # fmt: skip
        print(
            f"compiled kernels: numba {numba.__version__}; warm-up call (nsd2 over (1.15, 1.35), "
            f"loads or compiles the kernels) {time.process_time() - c0:.2f} s CPU, not counted"
        )
    compare(
        "nsd2 (2-DOF)",
        builtin_system("nsd2", **NSD2),
        tuple(args.window),
        rhs_nsd2,
        NSD2,
        4,
        args.bf_stride,
        args.transient,
        args.ds_max,
        tuple(args.settle_tol),
    )
    if args.sdof:
        compare(
            "nsd (SDOF) k = -0.5",
            builtin_model("nsd", **NSD),
            WINDOW_SDOF,
            rhs_nsd,
            NSD,
            2,
            args.bf_stride,
            args.transient,
            args.ds_max,
            tuple(args.settle_tol),
        )
    print(f"\nload average at the end {os.getloadavg()[0]:.2f} (1 min)")


if __name__ == "__main__":
    main()
