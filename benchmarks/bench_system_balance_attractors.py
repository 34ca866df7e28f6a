"""Coverage of the exact branches by ``system_balance_response`` with and without its
attractor stage (stage 4: Newton from the orbits a vectorised RK4 simulation settles on).

For every 8th point ``(Omega, A = max|x1|, M = mean x1)`` of every exact branch
(:func:`perturb.simulate.exact_response.exact_branches`, the independent PWL solver) the HB
response is asked for a solution at the same ``Omega`` near it: Newton from the interpolated
point of each of the two nearest segments of the HB polylines (in ``(Omega / width, A / s,
M / s)``, ``s = max(1, A)``), distance ``hypot(A - A_hb, M - M_hb) / s``; where no correction
converges near the polyline point (within 5 % of its largest coefficient: Newton from the
polyline may land on another branch's solution), the polyline distance. A point is *missed*
when that distance exceeds 2.5e-2.
CPU by ``time.process_time``, both variants in this process. The exact responses are cached
in ``--cache`` (pickles; the impact pair's take minutes).

Run: ``python benchmarks/bench_system_balance_attractors.py [--cache DIR] [--only NAME[:H[:LOW]]]``

Measured at commit 3b990cf (load 4-7 on 2 shared cores; exact points every 8th, missed
without -> with the stage, CPU of ``system_balance_response`` without -> with):

=============================  ===  ======  ==================  ==============
problem                        H    points  missed              CPU s
=============================  ===  ======  ==================  ==============
nsd2 (0.5, 2.0)                15   628     0 -> 0              1.20 -> 1.56
impact_pair (0.8, 1.3)         15   1097    120 -> 43           2.61 -> 8.37
impact_pair (0.6, 1.4)         15   998     104 -> 2            2.34 -> 8.07
impact_pair (0.8, 1.3)         31   1097    130 -> 20           89.2 -> 12.4
impact_pair (0.6, 1.4)         31   998     no start -> 0       0.69 -> 20.3
=============================  ===  ======  ==================  ==============

(0.6, 1.4) at H = 31 without the stage: SystemBalanceError, no HB solution at any seed
frequency. With it, 16 branches at H = 15 and H = 31 (the ``max_branches`` cap: mirror images
may be cut). Every missed point is an impacting one (switches > 0).
"""

from __future__ import annotations

import argparse
import os
import pickle
import time

import numpy as np

from perturb.model.system_builtins import builtin_system
from perturb.numeric.system_balance import (
    SystemBalance,
    SystemBalanceError,
    system_balance_response,
)
from perturb.simulate.exact_response import exact_branches

STRIDE = 8
MISS = 2.5e-2
CASES = (
    ("nsd2", (0.5, 2.0), 15),
    ("impact_pair", (0.8, 1.3), 15),
    ("impact_pair", (0.6, 1.4), 15),
    ("impact_pair", (0.8, 1.3), 31),
    ("impact_pair", (0.6, 1.4), 31),
)


def exact(name, window, cache):
    path = os.path.join(cache, f"exact_{name}_{window[0]}_{window[1]}.pkl")
    if os.path.exists(path):
        with open(path, "rb") as fh:
            return pickle.load(fh)
    ex = exact_branches(builtin_system(name), window, output="x1", workers=1)
    # the response holds read-only mappings that do not pickle: the measured columns only
    branches = [
        dict(
            Omega=np.asarray(b.parameters, dtype=float),
            amplitude=np.asarray(b.coordinate_amplitudes[:, 0], dtype=float),
            mean=np.asarray(b.coordinate_means[:, 0], dtype=float),
            switches=np.array([p.switches for p in b.points]),
        )
        for b in ex.branches
    ]
    with open(path, "wb") as fh:
        pickle.dump(branches, fh)
    return branches


def nearest(hb, w, a, m, width, count=2):
    s = max(1.0, abs(a))
    q = np.array([w / width, a / s, m / s])
    out = []
    for h in hb.branches:
        P = np.column_stack([h.Omega / width, h.amplitudes["x1"] / s, h.U[:, 0, 0] / s])
        if len(P) == 1:
            out.append((float(np.linalg.norm(P[0] - q)), h, 0, 0.0))
            continue
        d = np.diff(P, axis=0)
        dd = np.einsum("ij,ij->i", d, d)
        t = np.clip(np.einsum("ij,ij->i", q - P[:-1], d) / np.where(dd > 0, dd, 1.0), 0, 1)
        e = P[:-1] + t[:, None] * d - q
        dist = np.sqrt(np.einsum("ij,ij->i", e, e))
        for i in np.argsort(dist)[:count]:
            out.append((float(dist[i]), h, int(i), float(t[i])))
    out.sort(key=lambda r: r[0])
    return out[:count]


def coverage(ex, hb, sb, window):
    """(points, missed, missed with switches > 0)."""
    width = window[1] - window[0]
    total = missed = missed_impacting = 0
    for b in ex:
        W, A, Mx, switches = b["Omega"], b["amplitude"], b["mean"], b["switches"]
        for i in range(0, len(W), STRIDE):
            total += 1
            s = max(1.0, abs(A[i]))
            near = nearest(hb, W[i], A[i], Mx[i], width) if hb.branches else []
            best = np.inf
            for _, h, j, t in near:
                k = min(j + 1, len(h) - 1)
                guess = ((1 - t) * h.U[j] + t * h.U[k]).reshape(-1)
                try:
                    u = sb.solve(float(W[i]), guess, max_iterations=8)
                except SystemBalanceError:
                    continue
                if np.abs(u - guess).max() > 0.05 * max(1.0, float(np.abs(guess).max())):
                    continue  # Newton left the branch: another solution, not this branch's
                a_hb = sb.max_abs(u, float(W[i]), "x1")
                best = min(best, float(np.hypot(A[i] - a_hb, Mx[i] - u[0])) / s)
            if not np.isfinite(best) and near:
                best = near[0][0]
            if not best <= MISS:
                missed += 1
                missed_impacting += int(switches[i] > 0)
    return total, missed, missed_impacting


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", default="/tmp/sysedge")
    ap.add_argument("--only", default=None, help="a system name, or name:H, or name:H:low")
    args = ap.parse_args()
    os.makedirs(args.cache, exist_ok=True)
    print("load average", os.getloadavg())
    for name, window, H in CASES:
        if args.only and args.only not in (name, f"{name}:{H}", f"{name}:{H}:{window[0]}"):
            continue
        ex = exact(name, window, args.cache)
        system = builtin_system(name)
        for attractors in (False, True):
            sb = SystemBalance(system, H)
            t0 = time.process_time()
            try:
                hb = system_balance_response(
                    system, window, harmonics=H, balance=sb, attractors=attractors
                )
            except SystemBalanceError as exc:
                cpu = time.process_time() - t0
                print(f"{name} {window} H={H} attractors={attractors}: {exc}, CPU {cpu:.2f} s")
                continue
            cpu = time.process_time() - t0
            total, missed, missed_imp = coverage(ex, hb, sb, window)
            print(
                f"{name} {window} H={H} attractors={attractors}: {len(hb)} HB branches "
                f"({sum(o == 'attractor' for o in hb.origins)} from attractors), "
                f"exact {len(ex)} branches, missed {missed}/{total} points "
                f"({missed_imp} impacting), CPU {cpu:.2f} s",
                flush=True,
            )


if __name__ == "__main__":
    main()
