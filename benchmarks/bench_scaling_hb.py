"""Benchmark: how numeric harmonic balance grows with the number of harmonics H (issue 7, item 4).

Reproduce with::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_scaling_hb.py

Model: nsd, k = -0.5, mu = 0.05, F = 2, at Omega = 0.9 (a stable orbit crossing |x| = 1
twice per half period), exact Galerkin projection. For H = 1, 3, 7, 15, 31, 63, 127 (n = 2H + 1
unknowns) it measures, each as the median CPU time (``time.process_time``) of repeated calls and
the peak of ``tracemalloc`` over one call:

* ``eval``: one residual + Jacobian evaluation (crossings by certified isolation, the Toeplitz
  Jacobian ``Q_{j-n}`` assembled from the ``2H + 1`` closed-form coefficients: O(H^2) entries,
  plus the O(H * crossings) exponentials);
* ``solve``: one HB solve, Newton (:func:`perturb.numeric.continuation.newton_fixed`, tol
  1e-12) from the converged solution of the next smaller H in the list (zero-padded; at H = 1
  from the solution itself), the system already built: a few evaluations and dense LU solves,
  O(n^3) with a small constant;
* ``hill``: Hill stability as the continuation uses it (exact monodromy seed, inverse iteration
  on the ``n x n`` quadratic pencil when the exponents are real, O(n^3) per linear solve; at
  Omega = 0.9 they are a complex pair, so this is the monodromy path: O(crossings));
* ``hill full``: the full ``2n x 2n`` eigenproblem (single orbits): O(n^3) with a large constant.

The growth exponent is the least-squares slope of log(time) against log(H) over H >= 15 (below
that, fixed per-call overhead dominates). Wall time is printed too, with the load average: on
a shared machine it includes waiting for a core.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402

import numpy as np  # noqa: E402

from perturb.model.builtins import builtin_model  # noqa: E402
from perturb.numeric.continuation import newton_fixed  # noqa: E402
from perturb.numeric.harmonic_balance import (  # noqa: E402
    HarmonicBalanceSystem,
    _guess_vector,
    harmonic_balance_orbit,
)

H_LIST = (1, 3, 7, 15, 31, 63, 127)
W = 0.9


def measure(fn, repeat: int) -> tuple[float, float, float]:
    """Median CPU s, median wall s, peak traced MiB of ``fn()``."""
    cpu, wall = [], []
    for _ in range(repeat):
        c, t = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - t)
    tracemalloc.start()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return statistics.median(cpu), statistics.median(wall), peak / 2**20


def slope(H: list[int], t: list[float]) -> float:
    h = np.log(np.array(H, dtype=float))
    return float(np.polyfit(h, np.log(np.array(t)), 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print("command: OPENBLAS_NUM_THREADS=1 python benchmarks/bench_scaling_hb.py")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0, Omega=W)
    rows = []
    guess = None
    for H in H_LIST:
        system = HarmonicBalanceSystem(osc, harmonics=H)
        sol = harmonic_balance_orbit(osc, W, harmonics=H, guess=guess, stability="none")
        u = sol.coefficients
        rep = max(1, args.repeat if H <= 63 else 3)

        def ev(system=system, u=u):
            system._cache = None  # a fresh point every call
            system.evaluate(u, W)

        start = _guess_vector(system, guess) if guess is not None else u

        def solve(system=system, start=start):
            scale = max(1.0, float(np.abs(start).max()))
            system._cache = None
            newton_fixed(system.residual, system.jacobian, start, W, u_scale=scale, tol=1e-12)

        J = system.evaluate(u, W)[1]

        def hill(system=system, u=u, J=J):
            system.hill_exponents(u, W, J, refine_complex=False)

        def hill_full(system=system, u=u, J=J):
            system.hill_exponents(u, W, J, full=True)

        r = {"H": H, "n": system.basis.size}
        for name, fn in (("eval", ev), ("solve", solve), ("hill", hill), ("hill full", hill_full)):
            r[name] = measure(fn, rep)
        rows.append(r)
        guess = sol
    names = ("eval", "solve", "hill", "hill full")
    print(
        f"\n{'H':>4s} {'n':>4s} "
        + " ".join(f"{n + ' CPU ms':>14s} {'wall ms':>8s} {'MiB':>7s}" for n in names)
    )
    for r in rows:
        cells = " ".join(
            f"{r[n][0] * 1e3:14.3f} {r[n][1] * 1e3:8.3f} {r[n][2]:7.3f}" for n in names
        )
        print(f"{r['H']:4d} {r['n']:4d} {cells}")
    big = [r for r in rows if r["H"] >= 15]
    Hs = [r["H"] for r in big]
    print("\ngrowth exponent p in time ~ H^p (CPU, H >= 15) and memory ~ H^q:")
    for n in names:
        p = slope(Hs, [r[n][0] for r in big])
        q = slope(Hs, [max(r[n][2], 1e-6) for r in big])
        print(f"  {n:10s} p = {p:4.2f}, q = {q:4.2f}")


if __name__ == "__main__":
    main()
