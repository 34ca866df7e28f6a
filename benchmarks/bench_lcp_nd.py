"""Benchmark: measured order of the Moreau–Jean LCP stepper for systems with several stops.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_lcp_nd.py

Model (the system of tests/test_lcp_nd.py): two masses (1, 0.5), springs k1 = 1 to ground and
k2 = 1 between them, light damping, 1.0 cos(1.3 t) on x1; a wall x1 <= 0.5 (restitution 0.8)
and a two-sided clearance |x1 - x2| <= 0.4 (restitution 0.6): three contacts. From rest.

Reference: ``solve_ivp`` (DOP853, rtol = atol = 1e-12) on the equations written out, every
stop limit a terminal event, Newton's impact law applied by hand at each located impact,
restart (written here, independent of the stepper). Two spans: ``--span`` (default 6: four
impacts, all transversal) and the interval before the first impact (t < 1.4, no contact: the
trapezoidal rule). For each step ``h = span / n``: the largest position error over the grid,
the error at the final time, the CPU time of the stepper (median of ``--repeat``), the LCP
work; the order fitted by least squares on log(error) vs log(h). Also the cost per step of a
chain of ``n`` masses with gaps between neighbours (n = 2, 4, 8), which makes the LCP larger.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import sympy as sp  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from perturb.model.system import System, stop  # noqa: E402
from perturb.simulate.flows.system_lcp import simulate_system_lcp  # noqa: E402

COMMAND = "PYTHONPATH=. python benchmarks/bench_lcp_nd.py"
MM = np.diag([1.0, 0.5])
KM = np.array([[2.0, -1.0], [-1.0, 1.0]])
CM = 0.02 * KM + np.diag([0.03, 0.0])
F, OM = 1.0, 1.3
STOPS = [
    (np.array([1.0, 0.0]), 0.5, -1, 0.8),
    (np.array([1.0, -1.0]), -0.4, 1, 0.6),
    (np.array([1.0, -1.0]), 0.4, -1, 0.6),
]


def two_dof() -> System:
    return System.from_matrices(
        MM.tolist(),
        CM.tolist(),
        KM.tolist(),
        forcing=[f"{F}*cos({OM}*t)", 0],
        elements=[
            stop("x1", -sp.oo, 0.5, restitution=0.8, name="wall"),
            stop("x1 - x2", -0.4, 0.4, restitution=0.6, name="gap"),
        ],
    )


def reference(t1: float):
    Minv = np.linalg.inv(MM)

    def rhs(t, y):
        q, v = y[:2], y[2:]
        load = np.array([F * math.cos(OM * t), 0.0])
        return np.concatenate([v, Minv @ (load - CM @ v - KM @ q)])

    events = []
    for c, lim, side, _ in STOPS:

        def g(t, y, c=c, lim=lim, side=side):
            return side * (c @ y[:2] - lim)

        g.terminal = True
        g.direction = -1
        events.append(g)
    segs, impacts = [], []
    t, y = 0.0, np.zeros(4)
    for _ in range(1000):
        sol = solve_ivp(
            rhs, (t, t1), y, method="DOP853", rtol=1e-12, atol=1e-12, events=events,
            dense_output=True,
        )  # fmt: skip
        segs.append((t, sol.sol))
        if sol.status == 0:
            return segs, impacts
        k = next(i for i, te in enumerate(sol.t_events) if te.size)
        t, y = float(sol.t_events[k][0]), sol.y_events[k][0].copy()
        c, _, side, e = STOPS[k]
        n = side * c
        U = float(n @ y[2:])
        y[2:] += Minv @ n * (-(1.0 + e) * U / float(n @ Minv @ n))
        impacts.append((t, k, U))
    raise RuntimeError("more than 1000 impacts")


def evaluate(segs, ts):
    starts = np.array([s for s, _ in segs])
    idx = np.clip(np.searchsorted(starts, ts, side="right") - 1, 0, len(segs) - 1)
    return np.array([segs[i][1](t) for i, t in zip(idx, ts, strict=True)])


def order_table(span: float, ns: list[int], repeat: int) -> float:
    segs, impacts = reference(span)
    sysm = two_dof()
    print(
        f"\nspan [0, {span:g}]: {len(impacts)} impacts in the reference "
        f"({', '.join(f't={t:.4f} U={u:.3f}' for t, _, u in impacts)})"
    )
    print(f"{'n':>7} {'h':>10} {'max pos err':>12} {'err at t1':>11} {'cpu s':>8} {'LCPs':>6}")
    hs, errs = [], []
    for n in ns:
        h = span / n
        times = []
        for _ in range(repeat):
            t0 = time.process_time()
            traj = simulate_system_lcp(sysm, np.zeros(4), (0.0, span), h)
            times.append(time.process_time() - t0)
        ref = evaluate(segs, traj.t)
        err = float(np.abs(traj.y[:, :2] - ref[:, :2]).max())
        end = float(np.abs(traj.y[-1, :2] - ref[-1, :2]).max())
        hs.append(traj.h)
        errs.append(err)
        print(
            f"{n:>7} {traj.h:>10.3e} {err:>12.3e} {end:>11.3e} {statistics.median(times):>8.3f} "
            f"{traj.n_lcp:>6}"
        )
    order = float(np.polyfit(np.log(hs), np.log(errs), 1)[0])
    print(f"fitted order (max position error): {order:.2f} over h = {hs[0]:.3g} .. {hs[-1]:.3g}")
    return order


def chain(n: int) -> System:
    """``n`` unit masses, springs 1 to ground and between neighbours, a clearance of 0.05
    between neighbours (restitution 0.7), 0.8 cos(1.1 t) on the first."""
    K = 2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    K[-1, -1] = 1.0
    K = K + np.eye(n)
    forcing = ["0.8*cos(1.1*t)"] + [0] * (n - 1)
    elements = [
        stop(f"x{i} - x{i + 1}", -0.05, 0.05, restitution=0.7, name=f"gap{i}") for i in range(1, n)
    ]
    return System.from_matrices(
        np.eye(n).tolist(), (0.02 * np.eye(n)).tolist(), K.tolist(), forcing=forcing,
        elements=elements,
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per entry (median)")
    parser.add_argument("--span", type=float, default=6.0)
    args = parser.parse_args()
    print(f"# {COMMAND}")
    print(f"# python {platform.python_version()}, numpy {np.__version__}, {platform.machine()}")
    ns = [250, 500, 1000, 2000, 4000, 8000, 16000, 32000]
    with_impacts = order_table(args.span, ns, args.repeat)
    smooth = order_table(1.4, [250, 500, 1000, 2000, 4000], args.repeat)
    print(
        f"\nsummary: order {with_impacts:.2f} through impacts (expected ~1), {smooth:.2f} "
        "before the first impact (trapezoidal rule, expected 2)"
    )
    print(f"\n{'chain n':>7} {'contacts':>8} {'steps':>6} {'LCP steps':>9} {'pivots':>7} "
          f"{'us/step':>8}")  # fmt: skip
    for n in (2, 4, 8):
        sys_ = chain(n)
        y0 = np.zeros(2 * n)
        times = []
        for _ in range(args.repeat):
            t0 = time.process_time()
            traj = simulate_system_lcp(sys_, y0, (0.0, 20.0), 0.002)
            times.append(time.process_time() - t0)
        print(
            f"{n:>7} {len(traj.contacts):>8} {traj.n_steps:>6} {traj.n_lcp:>9} "
            f"{traj.n_pivots:>7} {1e6 * statistics.median(times) / traj.n_steps:>8.1f}"
        )


if __name__ == "__main__":
    main()
