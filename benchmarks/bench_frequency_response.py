"""Benchmark: first-order modified L-P frequency response of nsd, every branch, 2000 points.

Reproduce with::

    cd /work/main && python benchmarks/bench_frequency_response.py

Model: Zou-Nagarajaiah nsd, k = -3, mu = 0.05, F = 2, Omega in [0.2, 2] (Fig. 17d: the response
has a detached loop). ``modified_lindstedt(osc, 1)`` is derived once; the response is traced
by amplitude parametrisation (``perturb.numeric.frequency_response``) from a solver compiled
once (``compile_response``), with each stability option. The baseline, in the same process,
is the same call given the approximation itself, which compiles it on every call.
Target (issue 5): <= 20 ms after compile.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np

from perturb.methods import modified_lindstedt
from perturb.model import builtin_model
from perturb.numeric.frequency_response import compile_response, frequency_response


def timed(fn, repeat: int) -> tuple[float, float, object]:
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    print("command: cd /work/main && python benchmarks/bench_frequency_response.py")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    )
    osc = builtin_model("nsd", k=-3.0, mu=0.05, F=2.0)
    t = time.perf_counter()
    approx = modified_lindstedt(osc, 1)
    t_derive = time.perf_counter() - t
    t = time.perf_counter()
    solver = compile_response(approx)
    t_compile = time.perf_counter() - t
    print(f"derive {t_derive:.3f} s, compile {t_compile:.3f} s\n")
    print(f"{'variant':44s} {'median':>10s} {'min':>10s} {'points':>7s} {'branches':>8s}")
    base = None
    for stability in ("slow_flow", "hill"):
        med, mn, resp = timed(
            lambda st=stability: frequency_response(solver, (0.2, 2.0), points=2000, stability=st),
            args.repeat,
        )
        n = sum(len(b) for b in resp.branches)
        print(
            f"{'compiled, stability=' + stability:44s} {med * 1e3:8.1f}ms {mn * 1e3:8.1f}ms "
            f"{n:7d} {len(resp.branches):8d}"
        )
        if stability == "slow_flow":
            base = med
    med_b, mn_b, _ = timed(
        lambda: frequency_response(approx, (0.2, 2.0), points=2000, stability="slow_flow"),
        max(3, args.repeat // 2),
    )
    print(f"{'baseline: compile + trace, slow_flow':44s} {med_b * 1e3:8.1f}ms {mn_b * 1e3:8.1f}ms")
    print(f"\nratio baseline / compiled (slow_flow): {med_b / base:.1f}x; target <= 20 ms")


if __name__ == "__main__":
    main()
