"""Benchmark: first-order modified L-P frequency response of nsd, every branch, 2000 points.

Reproduce with::

    cd /work/main && python benchmarks/bench_frequency_response.py --repeat 7

Model: Zou-Nagarajaiah nsd, k = -3, mu = 0.05, F = 2, Omega in [0.2, 2] (Fig. 17d: the response
has a detached loop). ``modified_lindstedt(osc, 1)`` is derived once; the response is traced
by amplitude parametrisation (``perturb.numeric.frequency_response``) from a solver compiled
once (``compile_response``), with each stability option. Each is compared with its baseline
in the same process, interleaved call by call so that both see the same load: the previous
path, i.e. the amplitude's Fourier atoms through the validating public kernels of
``perturb.fourier`` (``solver.atoms.unchecked = False``) and Hill's exponents from LAPACK's
``eigvals`` of the 6x6 matrices (``_hill1_matrix``) instead of the closed-form cubic. The
call that compiles on every call is reported too. Target (issue 5): <= 20 ms after compile,
for the benchmark's primary variant ``stability="slow_flow"``; ``"hill"`` (the default of
``frequency_response``) is reported against the same target.

Both wall time (``time.perf_counter``) and CPU time of this process (``time.process_time``,
all threads) are reported, with the load average: on a shared machine the load inflates wall
time, and a threaded BLAS that waits for busy cores inflates CPU time as well.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import statistics
import time

import numpy as np

from perturb.methods import modified_lindstedt
from perturb.model import builtin_model
from perturb.numeric import frequency_response as fr
from perturb.numeric.frequency_response import compile_response, frequency_response

TARGET_S = 0.020


def timed(fn, repeat: int) -> dict[str, object]:
    """Median and minimum of wall and CPU time over ``repeat`` calls (after one warm-up)."""
    return timed_pair({"x": fn}, repeat)["x"]


def timed_pair(fns: dict[str, object], repeat: int) -> dict[str, dict[str, object]]:
    """:func:`timed` for several callables, interleaved call by call (one warm-up each)."""
    out = {k: f() for k, f in fns.items()}
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for k, f in fns.items():
            t, c = time.perf_counter(), time.process_time()
            out[k] = f()
            wall[k].append(time.perf_counter() - t)
            cpu[k].append(time.process_time() - c)
    return {
        k: {
            "wall": statistics.median(wall[k]),
            "wall_min": min(wall[k]),
            "cpu": statistics.median(cpu[k]),
            "cpu_min": min(cpu[k]),
            "out": out[k],
        }
        for k in fns
    }


@contextlib.contextmanager
def previous_path(solver):
    """The path before the fast one: validating Fourier kernels and LAPACK for Hill."""
    saved = fr._hill1_exponents
    solver.atoms.unchecked = False
    solver.atoms._plans.clear()
    fr._hill1_exponents = lambda *a: np.linalg.eigvals(fr._hill1_matrix(*a))
    try:
        yield
    finally:
        fr._hill1_exponents = saved
        solver.atoms.unchecked = True
        solver.atoms._plans.clear()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    cmd = "cd /work/main && python benchmarks/bench_frequency_response.py"
    print(f"command: {cmd} --repeat {args.repeat}")
    load0 = os.getloadavg()
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} cores, "
        f"load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}"
    )
    osc = builtin_model("nsd", k=-3.0, mu=0.05, F=2.0)
    t = time.perf_counter()
    approx = modified_lindstedt(osc, 1)
    t_derive = time.perf_counter() - t
    t = time.perf_counter()
    solver = compile_response(approx)
    t_compile = time.perf_counter() - t
    print(f"derive {t_derive:.3f} s, compile {t_compile:.3f} s (wall)\n")

    header = (
        f"{'variant':44s} {'wall med':>9s} {'wall min':>9s} {'cpu med':>9s} {'cpu min':>9s} "
        f"{'points':>7s} {'branches':>8s} {'base/this':>15s}"
    )
    print(header)

    def row(name, r, base=None, n: int | str = "", nb: int | str = "") -> None:
        ratio = ""
        if base is not None:  # wall median and CPU median ratios
            ratio = f"{base['wall'] / r['wall']:.2f}x/{base['cpu'] / r['cpu']:.2f}x"
        print(
            f"{name:44s} {r['wall'] * 1e3:7.1f}ms {r['wall_min'] * 1e3:7.1f}ms "
            f"{r['cpu'] * 1e3:7.1f}ms {r['cpu_min'] * 1e3:7.1f}ms {n!s:>7s} {nb!s:>8s} "
            f"{ratio:>15s}"
        )

    results = {}
    for stability in ("slow_flow", "hill"):

        def fast(st=stability):
            return frequency_response(solver, (0.2, 2.0), points=2000, stability=st)

        def before(st=stability):
            with previous_path(solver):
                return frequency_response(solver, (0.2, 2.0), points=2000, stability=st)

        r = timed_pair({"fast": fast, "before": before}, args.repeat)
        resp = r["fast"]["out"]
        n = sum(len(b) for b in resp.branches)
        row(f"compiled, stability={stability}", r["fast"], r["before"], n, len(resp.branches))
        row(f"  baseline: previous path, {stability}", r["before"], r["before"])
        results[stability] = r["fast"]
    base = timed(
        lambda: frequency_response(approx, (0.2, 2.0), points=2000, stability="slow_flow"),
        max(3, args.repeat // 2),
    )
    row("compile + trace, slow_flow (no ratio)", base)
    print("(base/this: previous path's median wall / this median wall, same for CPU)")
    load1 = os.getloadavg()
    print()
    for stability, r in results.items():
        verdict = "met" if r["wall"] <= TARGET_S else "NOT met"
        print(
            f"target <= {TARGET_S * 1e3:.0f} ms after compile (stability={stability}): {verdict} "
            f"(median wall {r['wall'] * 1e3:.1f} ms, min {r['wall_min'] * 1e3:.1f} ms, "
            f"CPU {r['cpu'] * 1e3:.1f} ms)"
        )
    print(f"load average at the end {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")


if __name__ == "__main__":
    main()
