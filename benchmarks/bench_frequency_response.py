"""Benchmark: first-order modified L-P frequency response of nsd, every branch, 2000 points.

Reproduce with::

    cd /work/main && python benchmarks/bench_frequency_response.py --repeat 7

Model: Zou-Nagarajaiah nsd, k = -3, mu = 0.05, F = 2, Omega in [0.2, 2] (Fig. 17d: the response
has a detached loop). ``modified_lindstedt(osc, 1)`` is derived once; the response is traced
by amplitude parametrisation (``perturb.numeric.frequency_response``) from a solver compiled
once (``compile_response``), with each stability option. The baseline, in the same process,
is the same call given the approximation itself, which compiles it on every call.
Target (issue 5): <= 20 ms after compile, for the benchmark's primary variant
``stability="slow_flow"`` (``"hill"`` is reported too).

Both wall time (``time.perf_counter``) and CPU time of this process (``time.process_time``,
all threads) are reported, with the load average: on a shared machine the load inflates wall
time, and a threaded BLAS that waits for busy cores inflates CPU time as well.
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

TARGET_S = 0.020


def timed(fn, repeat: int) -> dict[str, object]:
    """Median and minimum of wall and CPU time over ``repeat`` calls (after one warm-up)."""
    out = fn()
    wall, cpu = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return {
        "wall": statistics.median(wall),
        "wall_min": min(wall),
        "cpu": statistics.median(cpu),
        "cpu_min": min(cpu),
        "out": out,
    }


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

    base = timed(
        lambda: frequency_response(approx, (0.2, 2.0), points=2000, stability="slow_flow"),
        max(3, args.repeat // 2),
    )
    header = (
        f"{'variant':40s} {'wall med':>9s} {'wall min':>9s} {'cpu med':>9s} {'cpu min':>9s} "
        f"{'points':>7s} {'branches':>8s} {'base/this':>9s}"
    )
    print(header)

    def row(name: str, r: dict[str, object], n: int | str = "", nb: int | str = "") -> None:
        print(
            f"{name:40s} {r['wall'] * 1e3:7.1f}ms {r['wall_min'] * 1e3:7.1f}ms "
            f"{r['cpu'] * 1e3:7.1f}ms {r['cpu_min'] * 1e3:7.1f}ms {n!s:>7s} {nb!s:>8s} "
            f"{base['wall'] / r['wall']:8.1f}x"
        )

    results = {}
    for stability in ("slow_flow", "hill"):
        r = timed(
            lambda st=stability: frequency_response(solver, (0.2, 2.0), points=2000, stability=st),
            args.repeat,
        )
        resp = r["out"]
        n = sum(len(b) for b in resp.branches)
        row(f"compiled, stability={stability}", r, n, len(resp.branches))
        results[stability] = r
    row("baseline: compile + trace, slow_flow", base)
    load1 = os.getloadavg()
    primary = results["slow_flow"]
    verdict = "met" if primary["wall"] <= TARGET_S else "NOT met"
    print(
        f"\ntarget <= {TARGET_S * 1e3:.0f} ms after compile (stability=slow_flow): {verdict} "
        f"(median wall {primary['wall'] * 1e3:.1f} ms, CPU {primary['cpu'] * 1e3:.1f} ms); "
        f"load average at the end {load1[0]:.2f}"
    )


if __name__ == "__main__":
    main()
