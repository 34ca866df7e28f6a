"""Benchmark: the n-dimensional event-driven flow (SystemEventFlow) on friction limit cycles.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_events_nd.py [--repeat 3]

Timed in this one process (median of the runs, wall and CPU):

1. The belt stick-slip limit cycle (``builtin_system('belt')``): ``limit_cycle`` on
   :class:`~perturb.simulate.flows.system_events.SystemEventFlow` (rtol = atol = 1e-12, guess
   (0.6, 0), 6.5; period, max|x| and the multipliers) against the brute-force run a user would
   write: ``solve_ivp`` DOP853 (rtol = atol = 1e-12) slip phases with event-located stick
   entry and closed-form sticking, 5 cycles, the period between the last two stick exits.
   Both periods are printed; their difference is the accuracy.
2. The forced 2-DOF Coulomb system of ``tests/test_events_nd.py`` (stick-slip twice per period,
   Omega = 0.6): the period-1 orbit with its monodromy by ``periodic_orbit`` from a guess 1e-2
   off the orbit, against the transient a user would run to reach it (60 forcing periods of
   the same flow) -- the shooting answer also carries the multipliers.
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
from scipy.integrate import solve_ivp

from perturb.model.system import System, coulomb
from perturb.model.system_builtins import builtin_system
from perturb.simulate.flows.system_events import SystemEventFlow
from perturb.simulate.orbits.shooting import limit_cycle, periodic_orbit

TIGHT = {"method": "DOP853", "rtol": 1e-12, "atol": 1e-12}


def timed(fn, repeat: int):
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        cpus.append(time.process_time() - c)
        walls.append(time.perf_counter() - t)
    return statistics.median(walls), statistics.median(cpus), out


def belt_brute_force(p, x0=0.5, cycles=5):
    """Period of the belt cycle by a stick-slip solve_ivp loop (slip: DOP853 + events; stick:
    closed form)."""
    m, c, k, N = p["m"], p["c"], p["k"], p["N"]
    mu_s, mu_k, v_s, vb = p["mu_s"], p["mu_k"], p["v_s"], p["v_b"]

    def rhs(sigma):
        def f(t, y):
            u = abs(y[1] - vb)
            return [
                y[1],
                -(c * y[1] + k * y[0] + sigma * N * (mu_k + (mu_s - mu_k) * math.exp(-u / v_s)))
                / m,
            ]

        return f

    def rel(t, y):
        return y[1] - vb

    rel.terminal = True
    x_exit = (N * mu_s - c * vb) / k
    t, y, sigma, exits = 0.0, np.array([x0, 0.0]), -1, []
    for _ in range(50 * cycles):
        rel.direction = -sigma
        sol = solve_ivp(rhs(sigma), (t, t + 200.0), y, events=[rel], **TIGHT)
        t = float(sol.t_events[0][0])
        y = np.array(sol.y_events[0][0])
        if abs(c * vb + k * y[0]) > N * mu_s:
            sigma, y[1] = -sigma, vb
            continue
        t = t + (x_exit - y[0]) / vb
        exits.append(t)
        y, sigma = np.array([x_exit, vb]), -1
        if len(exits) == cycles + 1:
            break
    return exits[-1] - exits[-2]


def friction_2dof() -> System:
    return System.from_matrices(
        [[1, 0], [0, 1]],
        [[0.02, 0], [0, 0.02]],
        [[2, -1], [-1, 2]],
        elements=[coulomb("x2'", 0.45, name="pad")],
        forcing=["0.8*cos(Omega*t)", 0],
        params={"Omega": 0.6},
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    print(
        f"python {sys.version.split()[0]}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}"
    )
    belt = builtin_system("belt")
    p = {k: float(v) for k, v in belt.params.items()}

    def shoot():
        return limit_cycle(SystemEventFlow(belt, rtol=1e-12, atol=1e-12), [0.6, 0.0], 6.5)

    w1, c1, orb = timed(shoot, args.repeat)
    w2, c2, period = timed(lambda: belt_brute_force(p), args.repeat)
    print("\n1. belt stick-slip limit cycle")
    print(
        f"   limit_cycle(SystemEventFlow)  wall {w1:.3f} s  cpu {c1:.3f} s  period "
        f"{orb.period:.15g}  max|x| {orb.amplitude:.15g}  multipliers "
        f"{np.abs(orb.multipliers).round(12).tolist()}"
    )
    print(f"   solve_ivp stick-slip loop     wall {w2:.3f} s  cpu {c2:.3f} s  period {period:.15g}")
    print(
        f"   |period difference| {abs(orb.period - period):.2e}; cpu ratio loop/shooting "
        f"{c2 / c1:.2f}"
    )

    system = friction_2dof()
    flow = SystemEventFlow(system, rtol=1e-12, atol=1e-13)
    T = flow.period
    settled = flow([1.0, 0.0, 0.0, 0.3], 0.0, 60 * T).y
    ref = periodic_orbit(flow, settled)
    guess = ref.y0 + 1e-2

    def orbit():
        return periodic_orbit(SystemEventFlow(system, rtol=1e-12, atol=1e-13), guess)

    def transient():
        return SystemEventFlow(system, rtol=1e-12, atol=1e-13)(guess, 0.0, 60 * T).y

    w3, c3, o2 = timed(orbit, args.repeat)
    w4, c4, y60 = timed(transient, args.repeat)
    print("\n2. forced 2-DOF Coulomb stick-slip orbit (Omega = 0.6)")
    print(
        f"   periodic_orbit from orbit+1e-2   wall {w3:.3f} s  cpu {c3:.3f} s  "
        f"{o2.iterations} Newton steps, max|mu| {o2.max_multiplier:.6g}"
    )
    print(
        f"   60-period transient              wall {w4:.3f} s  cpu {c4:.3f} s  "
        f"distance to the orbit {np.abs(y60 - ref.y0).max():.2e}"
    )
    print(f"   cpu ratio transient/shooting {c4 / c3:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
