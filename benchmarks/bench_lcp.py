"""Benchmark: LCP time-stepping (θ = 1/2) work-precision table against the exact propagator, nsd.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_lcp.py

Model: x'' + mu x' + kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)] = F cos(W t), k = -2, mu = 0.05,
F = 2, W = 0.6, 100 forcing periods, two starts: from rest (the transient passes the saddle and
amplifies errors ~2000x) and from the attractor (state after a 100-period exact warm-up).  For
each step h = T/n: wall time of :func:`simulate_lcp` (median of ``--repeat`` runs, the default
warm-started basis), the error ``|(x, v) - exact|`` at the final time and its maximum over all
grid points, the fitted order, and the Lemke work.  One extra row runs Lemke at every step
(``warm_start=False``) to show the price of solving every LCP from scratch.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time

import numpy as np
import scipy

from perturb.simulate.flows.lcp import simulate_lcp
from perturb.simulate.flows.piecewise_exact import PWLSystem, propagate

COMMAND = "PYTHONPATH=. python benchmarks/bench_lcp.py"


def nsd(k: float = -2.0, mu: float = 0.05, F: float = 2.0, W: float = 0.6) -> PWLSystem:
    return PWLSystem([-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0], damping=mu,
                     forcing=((F, W, 0.0),))  # fmt: skip


def median_time(fn, repeat: int) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def table(rows: list[tuple[str, ...]]) -> None:
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    for r, row in enumerate(rows):
        print("  ".join(cell.rjust(w) for cell, w in zip(row, widths, strict=True)))
        if r == 0:
            print("  ".join("-" * w for w in widths))


def run(system, y0, t1, per_period, T, repeat, label):
    t_exact, exact = median_time(lambda: propagate(system, y0, (0.0, t1)), repeat)
    print(f"\n{label}: y0 = ({y0[0]:.6g}, {y0[1]:.6g}), t in [0, {t1:.2f}]; exact propagator "
          f"{t_exact:.4f} s ({exact.n_segments} pieces)\n")  # fmt: skip
    rows = [("h = T/n", "steps", "time [s]", "us/step", "err(t1)", "max err", "order",
             "Lemke calls", "pivots")]  # fmt: skip
    hs, errs, warm = [], [], {}
    for n in per_period:
        h = T / n
        sec, tr = median_time(lambda h=h: simulate_lcp(system, y0, (0.0, t1), h), repeat)
        X = exact(tr.t)
        err = np.hypot(tr.x - X[0], tr.v - X[1])
        order = "" if not hs else f"{math.log(errs[-1] / err.max()) / math.log(hs[-1] / tr.h):.2f}"
        hs.append(tr.h)
        errs.append(float(err.max()))
        warm[n] = tr
        rows.append((f"T/{n}", f"{tr.n_steps}", f"{sec:.4f}", f"{1e6 * sec / tr.n_steps:.2f}",
                     f"{err[-1]:.2e}", f"{err.max():.2e}", order, f"{tr.n_lcp_solves}",
                     f"{tr.n_pivots}"))  # fmt: skip
    n = per_period[len(per_period) // 2]
    sec, tr = median_time(
        lambda: simulate_lcp(system, y0, (0.0, t1), T / n, warm_start=False), repeat
    )
    diff = np.hypot(tr.x - warm[n].x, tr.v - warm[n].v)
    rows.append((f"T/{n} cold*", f"{tr.n_steps}", f"{sec:.4f}", f"{1e6 * sec / tr.n_steps:.2f}",
                 f"{diff[-1]:.1e}*", f"{diff.max():.1e}*", "", f"{tr.n_lcp_solves}",
                 f"{tr.n_pivots}"))  # fmt: skip
    table(rows)
    print(f"* cold: Lemke at every step (warm_start=False); its error columns give the difference "
          f"from the warm-started run at T/{n}, not the error")  # fmt: skip
    fit = np.polyfit(np.log(hs), np.log(errs), 1)[0]
    print(f"least-squares order of the max error over h = T/{per_period[0]} .. "
          f"T/{per_period[-1]}: {fit:.2f}")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per entry (median), >= 3")
    parser.add_argument("--periods", type=int, default=100)
    args = parser.parse_args(argv)
    print(f"command: {COMMAND}" + (f" {' '.join(sys.argv[1:])}" if sys.argv[1:] else ""))
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__},"
        f" {platform.machine()}"
    )
    system = nsd()
    W = system.forcing[0][1]
    T = 2.0 * math.pi / W
    t1 = args.periods * T
    print(f"nsd k=-2, mu=0.05, F=2, W=0.6, {args.periods} forcing periods, theta = 1/2, "
          f"median of {args.repeat} runs")  # fmt: skip
    simulate_lcp(system, (0.0, 0.0), (0.0, T), T / 50)  # warm-up (imports)
    per_period = (50, 100, 200, 400, 800, 1600, 3200)
    run(system, (0.0, 0.0), t1, per_period, T, args.repeat, "from rest")
    y_att = tuple(float(c) for c in propagate(system, (0.0, 0.0), (0.0, 100 * T))(100 * T))
    run(system, y_att, t1, per_period, T, args.repeat, "from the attractor")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
