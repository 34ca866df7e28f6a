"""Benchmark: one period-1 orbit of the nsd oscillator with its Floquet multipliers.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_shooting.py

Model: x'' + mu x' + kx + (1-k)[(x-1)H(x-1) + (x+1)H(-x-1)] = F cos(W t), k = -2, mu = 0.05,
F = 2, W = 0.6 (Zou-Nagarajaiah Fig. 5).  The orbit is the stable large orbit (amplitude ~9.52);
the guess is the converged state shifted by (+0.01, -0.01).

* exact: ``periodic_orbit(ExactPWLFlow(system), guess)`` (tol = 1e-12), i.e. Newton with the
  exact sensitivity (matrix exponentials x saltation), plus the orbit statistics (1024 dense
  samples, FFT, refined extrema).  A fresh flow per run, so no trajectory is reused across runs.
* baseline: the same call on ``ODEFlow`` (DOP853 + variational equations, rtol = 1e-10,
  atol = 1e-12, tol = 1e-8: the smooth integrator steps over the kinks of the force and cannot
  reach 1e-12).

Both are timed in the same process (median of ``--repeat`` runs); the errors of the baseline
are measured against the exact orbit.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

import numpy as np
import scipy

from perturb.model.builtins import builtin_model
from perturb.simulate.flows.base import ODEFlow
from perturb.simulate.flows.exact import ExactPWLFlow
from perturb.simulate.orbits.shooting import N_STATS, periodic_orbit

CPU: dict[str, tuple[float, float]] = {}


def timed(fn, repeat: int, name: str = "") -> tuple[float, float, object]:
    """Median and minimum wall time of ``fn()`` over ``repeat`` runs, and its last result.

    The minimum is printed too because a shared machine inflates the median (other processes
    compete for the cores); the median is the number to quote.  The CPU time of the process
    (``time.process_time``, median and minimum) is kept in ``CPU[name]``: it is less inflated
    by other processes than the wall time."""
    times, cpus = [], []
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        c = time.process_time()
        out = fn()
        cpus.append(time.process_time() - c)
        times.append(time.perf_counter() - t)
    CPU[name] = (statistics.median(cpus), min(cpus))
    return statistics.median(times), min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=30, help="timed runs per variant (>= 20)")
    args = ap.parse_args()
    repeat = max(20, args.repeat)
    print("command: PYTHONPATH=. python benchmarks/bench_shooting.py")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {sys.platform}, load average {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores"
    )
    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0, Omega=0.6)
    system = ExactPWLFlow(osc).system
    ref = periodic_orbit(ExactPWLFlow(system), [9.4, 1.0])
    guess = ref.y0 + np.array([0.01, -0.01])
    print(f"orbit: y0 = {ref.y0.tolist()}, amplitude {ref.amplitude:.12f}, {ref.stability}")
    print(f"guess: y0 + (0.01, -0.01); {repeat} runs per variant\n")

    # a fresh flow per run: no trajectory is reused across runs
    load0 = os.getloadavg()[0]
    t_exact, m_exact, o_exact = timed(
        lambda: periodic_orbit(ExactPWLFlow(system), guess), repeat, "exact"
    )
    T = ExactPWLFlow(system).period
    t_flow, m_flow, _ = timed(
        lambda: ExactPWLFlow(system)(ref.y0, 0.0, T, sensitivity=True), repeat, "flow"
    )
    ode = ODEFlow(osc, rtol=1e-10, atol=1e-12)
    t_ode, m_ode, o_ode = timed(lambda: periodic_orbit(ode, guess, tol=1e-8), repeat, "ode")
    load1 = os.getloadavg()[0]

    def err(o):
        dmu = np.sort_complex(o.multipliers) - np.sort_complex(ref.multipliers)
        return (
            float(np.max(np.abs(o.y0 - ref.y0))),
            float(np.max(np.abs(dmu))),
            abs(o.amplitude - ref.amplitude),
        )

    rows = [
        ("exact (ExactPWLFlow, tol 1e-12)", t_exact, m_exact, o_exact, "exact"),
        ("baseline (ODEFlow DOP853 1e-10, tol 1e-8)", t_ode, m_ode, o_ode, "ode"),
    ]
    head = f"{'variant':44s} {'wall med':>10s} {'wall min':>10s} {'CPU med':>10s} {'CPU min':>10s}"
    print(head + f" {'Newton':>7s} {'|dy0|':>9s} {'|dmu|':>9s} {'|dA|':>9s}")
    for name, t, tmin, o, key in rows:
        ey, em, ea = err(o)
        c_med, c_min = CPU[key]
        print(
            f"{name:44s} {t * 1e3:8.2f}ms {tmin * 1e3:8.2f}ms {c_med * 1e3:8.2f}ms "
            f"{c_min * 1e3:8.2f}ms {o.iterations:7d} {ey:9.1e} {em:9.1e} {ea:9.1e}"
        )
    print(
        f"\nload average {load0:.1f} before, {load1:.1f} after the timed runs "
        f"({os.cpu_count()} cores)"
    )
    print(
        f"ratio baseline / exact: {t_ode / t_exact:.1f}x (wall medians), {m_ode / m_exact:.1f}x "
        f"(wall minima), {CPU['ode'][0] / CPU['exact'][0]:.1f}x (CPU medians); target for "
        "exact: <= 5 ms"
    )
    print(
        f"exact cost split: one period with sensitivity {t_flow * 1e3:.2f} ms median "
        f"({m_flow * 1e3:.2f} ms min) x {o_exact.iterations + 1} Newton evaluations; the rest is "
        f"the orbit statistics ({N_STATS} dense samples, FFT, refined extrema)"
    )


if __name__ == "__main__":
    main()
