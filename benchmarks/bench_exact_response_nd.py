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
  starting from the previous end state; the transient is discarded in chunks of 10 forcing
  periods until the stroboscopic state repeats to 1e-6 (relative) over one period (settled
  on a period-1 orbit), at most 400 periods (the cap of
  :class:`perturb.simulate.studies.SweepOptions`; where no stable period-1 orbit exists,
  after a torus bifurcation, the sweep never settles), then 5 periods are sampled (200
  samples per period) for max |x1|, max |x2|. ``--transient N`` discards a fixed N periods
  instead (100 is too few here: many rows are still drifting). It finds stable orbits only
  (one per frequency and direction).
* ``--sdof``: the same for the one-coordinate ``nsd`` at k = -0.5 over W in [0.3, 2] (the
  issue's ">= 100x serial" goal for the oscillator).

Both are timed by CPU time of this process (``time.process_time``: the machine is shared, and
the wall time of either is inflated by other jobs), interleaved: exact, brute force, exact
(the ratio uses the mean of the two exact runs). ``--bf-stride n`` runs the brute force on
every n-th frequency of each sweep and scales its time by n (an estimate: each frequency
costs the same fixed number of periods whatever the previous state).
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

NSD2 = {"k": -0.5, "mu1": 0.05, "mu2": 0.02, "k2": 1.0, "m2": 1.0, "F": 2.0}
WINDOW_2DOF = (0.5, 2.0)
NSD = {"k": -0.5, "mu": 0.05, "F": 2.0}
WINDOW_SDOF = (0.3, 2.0)
RTOL = 1e-8
MEASURE, SAMPLES = 5, 200
#: settling test of the brute force: chunks of periods, relative repeat tolerance, cap
CHUNK, SETTLE_TOL, MAX_TRANSIENT = 10, 1e-6, 400


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


def settle(rhs, y, T, transient=None):
    """The state after the transient: a fixed number of periods, or chunks of CHUNK periods
    until the stroboscopic state repeats to SETTLE_TOL (at most MAX_TRANSIENT periods).
    Returns (state, periods integrated, settled)."""
    if transient is not None:
        s = solve_ivp(rhs, (0, transient * T), y, method="DOP853", rtol=RTOL, atol=RTOL)
        return s.y[:, -1], transient, True
    t, n = 0.0, 0
    while n < MAX_TRANSIENT:
        s = solve_ivp(
            rhs, (t, t + CHUNK * T), y, method="DOP853", rtol=RTOL, atol=RTOL, dense_output=True
        )
        last = s.sol(t + T * (CHUNK - 1))
        y, t, n = s.y[:, -1], t + CHUNK * T, n + CHUNK
        if np.max(np.abs(y - last)) < SETTLE_TOL * max(1.0, float(np.max(np.abs(y)))):
            return y, n, True
    return y, n, False


def brute_sweep(make_rhs, params, window, n_states, stride=1, n=100, transient=None):
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
            y, k, ok = settle(rhs, y, T, transient)
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


def compare(name, model, window, make_rhs, params, n_states, stride, transient, ds_max):
    c1, res = exact_run(model, window, ds_max)
    cb, rows, periods, unsettled = brute_sweep(
        make_rhs, params, window, n_states, stride, transient=transient
    )
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
    how = f"{transient} periods" if transient is not None else "until settled (cap 400)"
    print(
        f"  brute force DOP853 rtol {RTOL:g} up/down sweep of 100 W ({len(rows)} runs, stride "
        f"{stride}, transient {how} + {MEASURE} periods): CPU {cb:.2f} s, {periods} periods, "
        f"{unsettled} runs unsettled" + (" (scaled by the stride)" if stride > 1 else "")
    )
    print(f"  ratio brute force / exact (CPU, serial): {cb / ce:.1f}x")
    # the brute force's settled stable orbits lie on the exact branches (a check of both)
    amps = np.array([q.amplitude for b in res.branches for q in b.points if q.stable])
    ws = np.array([q.parameter for b in res.branches for q in b.points if q.stable])
    off = 0
    for W, a1, *_ in rows:
        near = np.abs(ws - W) < 0.01 * (window[1] - window[0])
        if not np.any(np.abs(amps[near] - a1) < 0.02 * max(1.0, a1)):
            off += 1
    print(f"  brute-force rows without a stable exact point within 1 % (W), 2 % (amp): {off}")
    return cb / ce


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bf-stride", type=int, default=1, help="brute force on every n-th W")
    ap.add_argument("--sdof", action="store_true", help="also the SDOF nsd at k = -0.5")
    ap.add_argument("--transient", type=int, default=None, help="fixed transient periods")
    ap.add_argument("--ds-max", type=float, default=0.005, help="exact output spacing")
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
    if tuple(args.window) != WINDOW_2DOF:
        extra += f" --window {args.window[0]:g} {args.window[1]:g}"
    print(f"command: {cmd}{extra}")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{os.cpu_count()} cpus, load average {os.getloadavg()[0]:.2f} (1 min)"
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
        )
    print(f"\nload average at the end {os.getloadavg()[0]:.2f} (1 min)")


if __name__ == "__main__":
    main()
