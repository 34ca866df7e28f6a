"""Benchmark: numeric harmonic balance, full frequency response of nsd with exact Galerkin.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_numeric_harmonic_balance.py

Model: x'' + mu x' + kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)] = F cos(W t), k = -0.5, mu = 0.05,
F = 2, W from 0.3 to 2.

* exact: ``harmonic_balance_response(osc, (0.3, 2.0), harmonics=15, ds_max=0.04)``: exact
  Galerkin projection of the PWL force (crossings by certified root isolation, closed-form
  integrals), pseudo-arclength continuation started automatically (the exact linear-segment
  orbit at W = 2), Hill stability at every point (~250 points). Everything from the
  ``Oscillator`` on is inside the timed call; the system is built by the first call and reused by
  the repeats (``compiled_system``: once per process and options, as in a session). Target: <=
  0.7 s.
  The continuation uses the Hermite predictor with acceptance after one correction (about 1.3
  evaluations per point); ``--previous`` also times the call with the tangent predictor and
  full corrections (2.3 evaluations per point), the previous continuation, in the same
  process, so the ratio holds under load.
* baseline: the same call with ``projection="aft", samples=481`` (AFT with 32 samples per
  highest-harmonic period), in the same process.

Both are timed ``--repeat`` times; medians of wall time and of process (CPU) time are printed,
with the minimum wall time: on a shared machine the wall time includes waiting for a core, the
CPU time does not. BLAS runs single-threaded (set below before numpy is imported): the
matrices are 31 x 31, where threads only add contention.

Then the error table at W = 0.6: relative error of max|x| against the exact orbit
(:func:`perturb.simulate.orbits.search.periodic_orbits`), for exact Galerkin, AFT with 4H + 1
samples
and the floor (the exact orbit's own Fourier series truncated at H; coefficients from 2**16
samples of the exact dense output).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402
from scipy.optimize import minimize_scalar  # noqa: E402

from perturb.model.builtins import builtin_model  # noqa: E402
from perturb.numeric import harmonic_balance as hb  # noqa: E402
from perturb.numeric.harmonic_balance import (  # noqa: E402
    harmonic_balance_orbit,
    harmonic_balance_response,
)
from perturb.solve import periodic_orbits  # noqa: E402

PARAMS = {"k": -0.5, "mu": 0.05, "F": 2.0}
WINDOW = (0.3, 2.0)
H = 15
DS_MAX = 0.04
H_TABLE = (1, 3, 5, 7, 9, 11, 15, 21, 31, 47, 63)


def timed(fn, repeat: int):
    """Median wall time, minimum wall time, median CPU time of ``fn()``, and its last result."""
    wall, cpu = [], []
    out = None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return statistics.median(wall), min(wall), statistics.median(cpu), out


def truncated_max(c: np.ndarray, H: int) -> float:
    """max |x| of the exact orbit's series truncated at H (dense grid + bounded minimiser)."""
    k = np.arange(1, H + 1)

    def x(th):
        return c[0].real + 2.0 * np.real(np.exp(1j * np.multiply.outer(th, k)) @ c[1 : H + 1])

    grid = np.linspace(0.0, 2 * np.pi, 8192, endpoint=False)
    best = 0.0
    for sign in (1.0, -1.0):
        j = int(np.argmax(sign * x(grid)))
        res = minimize_scalar(
            lambda q, sign=sign: -sign * x(np.array([q]))[0],
            bounds=(grid[j] - 1e-3, grid[j] + 1e-3),
            method="bounded",
            options={"xatol": 1e-13},
        )
        best = max(best, -res.fun)
    return best


def error_table(W: float) -> None:
    osc = builtin_model("nsd", Omega=W, **PARAMS)
    (orbit,) = periodic_orbits(osc, W)
    n = 2**16
    _, x, _ = orbit.sample(n)
    c = np.fft.rfft(x) / n * np.exp(-1j * np.arange(n // 2 + 1) * W * orbit.t0)
    A = orbit.amplitude
    print(f"\nerror of max|x| vs H at Omega = {W} (exact orbit amplitude {A:.12f}, stable)")
    print(
        f"{'H':>4s} {'exact Galerkin':>15s} {'AFT 4H+1':>10s} {'floor':>10s} {'exact/floor':>12s}"
    )
    guess = None
    for h in H_TABLE:
        sol = harmonic_balance_orbit(osc, W, harmonics=h, guess=guess, stability="none")
        guess = sol
        aft = harmonic_balance_orbit(
            osc, W, harmonics=h, projection="aft", guess=sol, stability="none"
        )
        e, a = abs(sol.amplitude - A) / A, abs(aft.amplitude - A) / A
        f = abs(truncated_max(c, h) - A) / A
        print(f"{h:4d} {e:15.2e} {a:10.2e} {f:10.2e} {e / f:12.2f}")


def calibration() -> float:
    """CPU seconds of a fixed pure-Python loop (about 15 ms on an unloaded desktop core), to
    put the timings in proportion."""
    c = time.process_time()
    sum(range(10**6))
    return time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="timed runs per variant (>= 3)")
    ap.add_argument("--previous", action="store_true", help="also time the previous continuation")
    ap.add_argument("--no-table", action="store_true", help="skip the error table")
    args = ap.parse_args()
    repeat = max(3, args.repeat)
    print("command: PYTHONPATH=. python benchmarks/bench_numeric_harmonic_balance.py")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {sys.platform}, load average {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores; calibration sum(range(10**6)) = {calibration() * 1e3:.0f} ms CPU"
    )
    osc = builtin_model("nsd", **PARAMS)

    def exact():
        return harmonic_balance_response(osc, WINDOW, harmonics=H, ds_max=DS_MAX)

    def aft():
        return harmonic_balance_response(
            osc, WINDOW, harmonics=H, ds_max=DS_MAX, projection="aft", samples=481
        )

    def previous():
        # the same call with the continuation as it was before the Hermite predictor
        original = hb.continue_curve

        def tangent_predictor(*a, **k):
            k.update(predictor="tangent", early_accept=False)
            return original(*a, **k)

        hb.continue_curve = tangent_predictor
        try:
            return exact()
        finally:
            hb.continue_curve = original

    exact()  # imports and sympy caches warm, as in a session
    rows = []
    variants = [
        (f"exact Galerkin, H={H}", exact),
        (f"baseline AFT 481 samples, H={H}", aft),
    ]
    if args.previous:
        variants.append((f"exact Galerkin, H={H}, previous", previous))
    for name, fn in variants:
        wall, wmin, cpu, resp = timed(fn, repeat)
        br = resp.branches[0]
        rows.append((name, wall, wmin, cpu, br))
        print(
            f"{name:34s} wall median {wall:6.3f} s (min {wmin:6.3f} s), CPU median {cpu:6.3f} s;"
            f" {len(br)} points, {int(br.stable.sum())} stable, folds {len(resp.folds)},"
            f" peak max|x| {br.amplitude.max():.6f} at Omega {br.omega[br.amplitude.argmax()]:.4f}"
        )
    (_, w0, m0, c0, b0), (_, w1, m1, c1, b1) = rows[:2]
    print(
        f"ratio AFT / exact: {w1 / w0:.2f}x (wall medians), {m1 / m0:.2f}x (wall minima), "
        f"{c1 / c0:.2f}x (CPU medians); target for exact: <= 0.7 s"
    )
    if args.previous:
        _, w2, m2, c2, _ = rows[2]
        print(
            f"ratio exact / previous continuation: {w0 / w2:.2f} (wall medians), "
            f"{m0 / m2:.2f} (wall minima), {c0 / c2:.2f} (CPU medians)"
        )
    if not args.no_table:
        error_table(0.6)


if __name__ == "__main__":
    main()
