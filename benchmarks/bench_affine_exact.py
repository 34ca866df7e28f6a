"""Benchmark: exact n-dimensional piecewise-affine propagation vs DOP853 with events (issue 15).

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_affine_exact.py

System: the 2-DOF gap chain of tests/test_affine_exact.py — x1 on k1 = 1 to ground, x2 on
k2 = 2, coupled by k12 = 0.3 and a two-sided gap (contact stiffness 4 once |x1 - x2| > 0.2),
dampers 0.1 to ground, 0.6 cos(1.1 t) on x1; states (x1, x2, v1, v2), 4 crossings per period.
100 forcing periods from a state on the attractor (40 periods from rest; before that the
motion is a chaotic transient on which any two correct solvers part by rounding).

Reference: ``solve_ivp`` (DOP853, rtol = atol = 1e-12) on the equations of motion written out,
the region held fixed between crossings, terminal events on both surfaces, restart at each
crossing.  Both are timed in the same process, interleaved, median of ``--repeat`` runs (wall
clock and process CPU time; CPU is steadier on a shared machine).  Also reported: the largest
difference of the crossing times and of the final state, and the exact propagator through its
augmented-matrix (expm) representation.
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
from scipy.integrate import solve_ivp  # noqa: E402

from perturb.model.affine import PiecewiseAffineSystem  # noqa: E402
from perturb.simulate.flows.affine_exact import propagate  # noqa: E402

COMMAND = "PYTHONPATH=. python benchmarks/bench_affine_exact.py"
K1, K2, K12, C, KG, GAP, F, W = 1.0, 2.0, 0.3, 0.1, 4.0, 0.2, 0.6, 1.1
NORMAL = (1.0, -1.0, 0.0, 0.0)


def chain() -> PiecewiseAffineSystem:
    def A_of(kc: float) -> np.ndarray:
        K = np.array([[K1 + K12 + kc, -K12 - kc], [-K12 - kc, K2 + K12 + kc]])
        return np.block([[np.zeros((2, 2)), np.eye(2)], [-K, -C * np.eye(2)]])

    return PiecewiseAffineSystem.build(
        ("x1", "x2", "v1", "v2"),
        [(NORMAL, GAP, "x1 - x2 = gap"), (NORMAL, -GAP, "x1 - x2 = -gap")],
        {
            (1, 1): (A_of(KG), (0, 0, KG * GAP, -KG * GAP)),
            (-1, 1): (A_of(0.0), (0, 0, 0, 0)),
            (-1, -1): (A_of(KG), (0, 0, -KG * GAP, KG * GAP)),
        },
        inputs=[(W, (0, 0, F, 0), (0, 0, 0, 0))],
        period=2 * math.pi / W,
    )


def rhs(t: float, y: np.ndarray, pat: tuple[int, int]) -> list[float]:
    x1, x2, v1, v2 = y
    r = x1 - x2
    contact = KG * (r - GAP) if pat[0] > 0 else (KG * (r + GAP) if pat[1] < 0 else 0.0)
    return [
        v1,
        v2,
        -C * v1 - K1 * x1 - K12 * r - contact + F * math.cos(W * t),
        -C * v2 - K2 * x2 + K12 * r + contact,
    ]


def reference(y0, t0, t1, pattern):
    """DOP853 with events on both surfaces and a restart at each crossing."""
    t, y, pat = t0, np.array(y0, dtype=float), list(pattern)
    log = []
    normal = np.array(NORMAL)
    for _ in range(1_000_000):
        events = []
        for j, d in enumerate((GAP, -GAP)):

            def ev(tt, yy, d=d):
                return normal @ yy - d

            ev.terminal = True
            ev.direction = -pat[j]
            events.append(ev)
        p = tuple(pat)
        sol = solve_ivp(
            lambda tt, yy, p=p: rhs(tt, yy, p),
            (t, t1),
            y,
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            events=events,
        )
        if sol.status == 0:
            return sol.y[:, -1], log
        j = min((k for k in (0, 1) if sol.t_events[k].size), key=lambda k: sol.t_events[k][0])
        t, y = float(sol.t_events[j][0]), sol.y_events[j][0]
        pat[j] = -pat[j]
        log.append(t)
    raise RuntimeError("reference: too many restarts")


def timed(fn):
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timed runs of each (median)")
    parser.add_argument("--periods", type=int, default=100, help="forcing periods")
    args = parser.parse_args(argv)

    system = chain()
    T = system.period
    t0 = 40 * T
    y0 = propagate(system, np.zeros(4), 0.0, t0).y
    t1 = t0 + args.periods * T
    pattern = system.pattern(y0)

    runs: dict[str, list[tuple[float, float]]] = {"exact": [], "exact (expm)": [], "dop853": []}
    out = {}
    propagate(system, y0, t0, t1)  # warm-up (region caches, imports)
    for _ in range(args.repeat):
        for label, fn in (
            ("exact", lambda: propagate(system, y0, t0, t1)),
            ("exact (expm)", lambda: propagate(system, y0, t0, t1, representation="expm")),
            ("dop853", lambda: reference(y0, t0, t1, pattern)),
        ):
            res, wall, cpu = timed(fn)
            runs[label].append((wall, cpu))
            out[label] = res

    ours = out["exact"]
    ref_y, ref_log = out["dop853"]
    times = np.array([e.time for e in ours.events if not e.tangency])
    expm_times = np.array([e.time for e in out["exact (expm)"].events if not e.tangency])
    print(f"# {COMMAND}")
    print(
        f"# python {platform.python_version()}, numpy {np.__version__}, "
        f"{os.cpu_count()} cpus, load average {os.getloadavg()[0]:.2f}"
    )
    print(f"# 2-DOF gap chain, {args.periods} forcing periods, {times.size} crossings")
    med = {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v))
           for k, v in runs.items()}  # fmt: skip
    for label, (wall, cpu) in med.items():
        print(f"{label:14s} wall {wall * 1e3:9.2f} ms   cpu {cpu * 1e3:9.2f} ms")
    for label in ("exact", "exact (expm)"):
        print(
            f"dop853 / {label}: wall {med['dop853'][0] / med[label][0]:.1f}x, "
            f"cpu {med['dop853'][1] / med[label][1]:.1f}x"
        )
    same = times.size == len(ref_log)
    dt = float(np.max(np.abs(times - np.array(ref_log)))) if same else math.nan
    print(f"crossings: exact {times.size}, dop853 {len(ref_log)}; max |dt| = {dt:.2e}")
    print(f"final state: max |y_exact - y_dop853| = {np.max(np.abs(ours.y - ref_y)):.2e}")
    same_expm = expm_times.size == times.size
    print(
        "expm vs modal: max |dt| = "
        f"{float(np.max(np.abs(expm_times - times))) if same_expm else math.nan:.2e}, "
        f"max |dy| = {np.max(np.abs(out['exact (expm)'].y - ours.y)):.2e}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
