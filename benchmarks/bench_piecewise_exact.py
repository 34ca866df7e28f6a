"""Benchmark: exact piecewise-analytic propagation vs solve_ivp (DOP853, events), nsd model.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_piecewise_exact.py

Model: x'' + mu x' + kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)] = F cos(W t), k = -2, mu = 0.05,
F = 2, W = 0.6, from rest, 100 forcing periods.  The reference is DOP853 at rtol = atol = 1e-12
on the linear field of the current segment, with terminal events at its breakpoints, restarted
on the breakpoint after every crossing (the oracle of tests/test_piecewise_exact.py, without its
extremum check).  Both are timed in the same process, median of ``--repeat`` runs (wall clock
and process CPU time: the latter is steadier on a shared machine); the maximum difference is
over 20001 equally spaced times.  The reference is also run once at rtol = 3e-14 to show which of
the two is closer to the truth.  Two starts: from rest (a transient that amplifies errors about
2000x, so the 1e-12 reference itself is only good to ~6e-9) and on the attractor.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import platform
import statistics
import sys
import time

import numpy as np
import scipy
from scipy.integrate import solve_ivp

from perturb.simulate.flows.piecewise_exact import PWLSystem, propagate

COMMAND = "PYTHONPATH=. python benchmarks/bench_piecewise_exact.py"


def nsd(k: float = -2.0, mu: float = 0.05, F: float = 2.0, W: float = 0.6) -> PWLSystem:
    return PWLSystem([-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0], damping=mu,
                     forcing=((F, W, 0.0),))  # fmt: skip


def solve_ivp_events(system: PWLSystem, y0, t_span, t_eval, rtol=1e-12, atol=1e-12):
    """DOP853 per segment with terminal breakpoint events, restarted at each crossing."""
    bp, sl, of = system.breakpoints, system.slopes, system.offsets
    mu, forcing = system.damping, system.forcing

    def load(t):
        return system.static_force + sum(F * math.cos(w * t + p) for F, w, p in forcing)

    x, v = map(float, y0)
    t, t1 = map(float, t_span)
    i = int(np.searchsorted(bp, x, side="right"))
    pieces = []
    while t < t1:
        s_i, o_i = float(sl[i]), float(of[i])

        def fun(tt, y, s_i=s_i, o_i=o_i):
            return np.array([y[1], load(tt) - o_i - mu * y[1] - s_i * y[0]])

        events, targets = [], []
        if i > 0:
            e = functools.partial(lambda tt, y, d: y[0] - d, d=float(bp[i - 1]))
            e.terminal, e.direction = True, -1
            events.append(e)
            targets.append((float(bp[i - 1]), i - 1))
        if i < bp.size:
            e = functools.partial(lambda tt, y, d: y[0] - d, d=float(bp[i]))
            e.terminal, e.direction = True, 1
            events.append(e)
            targets.append((float(bp[i]), i + 1))
        sol = solve_ivp(fun, (t, t1), [x, v], method="DOP853", rtol=rtol, atol=atol,
                        events=events, dense_output=True)  # fmt: skip
        pieces.append((t, sol.sol))
        if sol.status == 1:
            k = next(j for j, te in enumerate(sol.t_events) if te.size)
            (x, i), v = targets[k], float(sol.y_events[k][0][1])
        t = float(sol.t[-1])
    te = np.asarray(t_eval)
    starts = np.array([p[0] for p in pieces])
    idx = np.clip(np.searchsorted(starts, te, side="right") - 1, 0, len(pieces) - 1)
    out = np.empty((2, te.size))
    for k in np.unique(idx):
        out[:, idx == k] = pieces[k][1](te[idx == k])
    return out, len(pieces)


def median_time(fn, repeat: int) -> tuple[float, float, object]:
    """Median wall-clock and CPU (process) time of ``repeat`` calls, and the last result."""
    wall, cpu, result = [], [], None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        result = fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu), result


def run_case(system: PWLSystem, y0, T: float, repeat: int) -> dict:
    t_eval = np.linspace(0.0, T, 20001)
    propagate(system, y0, (0.0, T))  # warm-up (imports, caches)
    w_ex, c_ex, traj = median_time(lambda: propagate(system, y0, (0.0, T)), repeat)
    w_ref, c_ref, (ref, n_ref) = median_time(
        lambda: solve_ivp_events(system, y0, (0.0, T), t_eval), repeat
    )
    y_exact = traj(t_eval)
    tight, _ = solve_ivp_events(system, y0, (0.0, T), t_eval, rtol=3e-14, atol=1e-15)
    return dict(
        traj=traj,
        wall=(w_ex, w_ref),
        cpu=(c_ex, c_ref),
        pieces=(traj.n_segments, n_ref),
        diff=float(np.max(np.abs(y_exact - ref))),
        err=(float(np.max(np.abs(y_exact - tight))), float(np.max(np.abs(ref - tight)))),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per method (median)")
    parser.add_argument("--periods", type=int, default=100)
    args = parser.parse_args(argv)

    print(f"command: {COMMAND}" + (f" {' '.join(sys.argv[1:])}" if sys.argv[1:] else ""))
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__},"
        f" {platform.machine()}, {os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.2f}"
        if hasattr(os, "getloadavg")
        else ""
    )
    system = nsd()
    W = system.forcing[0][1]
    P = 2.0 * math.pi / W
    T = args.periods * P
    settle = propagate(system, (0.0, 0.0), (0.0, 300 * P))
    starts = {
        "from rest": (0.0, 0.0),
        "on attractor": (float(settle.x[-1]), float(settle.v[-1])),
    }
    print(
        f"\nnsd k=-2, mu=0.05, F=2, W=0.6, {args.periods} forcing periods (t in [0, {T:.2f}]), "
        f"median of {args.repeat} runs; 'on attractor' starts from the state after 300 periods"
    )
    print(
        "diff: max |x|,|v| difference over 20001 times; 'err vs 3e-14': against DOP853 at "
        "rtol = 3e-14, atol = 1e-15 (which of the two is closer to the truth)\n"
    )
    rows = [("start", "method", "wall [s]", "cpu [s]", "pieces", "diff vs 1e-12 ref",
             "err vs 3e-14 ref")]  # fmt: skip
    results = {}
    for label, y0 in starts.items():
        r = run_case(system, y0, T, args.repeat)
        results[label] = r
        rows.append(
            (
                label,
                "propagate (exact)",
                f"{r['wall'][0]:.4f}",
                f"{r['cpu'][0]:.4f}",
                f"{r['pieces'][0]}",
                f"{r['diff']:.2e}",
                f"{r['err'][0]:.2e}",
            )
        )
        rows.append(("", "solve_ivp DOP853+events", f"{r['wall'][1]:.4f}", f"{r['cpu'][1]:.4f}",
                     f"{r['pieces'][1]}", "-", f"{r['err'][1]:.2e}"))  # fmt: skip
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    for r, row in enumerate(rows):
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
        if r == 0:
            print("  ".join("-" * w for w in widths))
    print()
    for label, r in results.items():
        s = r["traj"].stats
        print(
            f"{label}: speed-up {r['wall'][1] / r['wall'][0]:.1f}x wall, "
            f"{r['cpu'][1] / r['cpu'][0]:.1f}x cpu; propagate work: {s.n_pieces} pieces, "
            f"{s.n_grid_points} bracketing-grid points, {s.n_root_solves} root solves"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
