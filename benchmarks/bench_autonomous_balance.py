"""Benchmark: autonomous harmonic balance (limit cycles with unknown frequency,
:mod:`perturb.numeric.autonomous_balance`) against the exact limit cycles, in one process.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_autonomous_balance.py [--repeat 3] [--quick]

CPU time (``time.process_time``, minimum over ``--repeat`` runs, one BLAS thread; the load
average is printed: the machine is shared) of

1. **van der Pol, eps = 1**: the HB cycle (automatic Hopf start, Floquet multipliers) for
   H = 3 ... 31 beside the exact references: ``perturb.solve.limit_cycles`` (the whole
   search: settling runs + shooting, DOP853 rtol 1e-12) and a DOP853 shooting polish alone
   (``perturb.simulate.orbits.shooting.limit_cycle`` from the HB cycle's state and period).
   Errors: period against the literature value 6.663286859323130, max|x| and the nontrivial
   multiplier against the shooting cycle.
2. **belt (Stribeck stick-slip)**: the HB cycle for H = 3 ... 63 (friction jump spread into a
   tanh of the default width 0.05 d / H), error of period and max|x| against the event-driven
   exact cycle (``limit_cycles``, Filippov sticking), time beside the exact search and the
   exact polish; and the exact discontinuous law (``jump_width=0``: the smoothed cycle
   narrowed to 1/100 of its start width, then Newton on the exact law) for H = 9, 15, 25,
   which converges at some H only (the HB orbit chatters across the sticking phase; module
   docstring).
3. **Continuation**: ``autonomous_balance_branch`` of van der Pol in eps over (0.2, 2), H = 15,
   and of the belt in v_b over (0.15, 0.3), H = 9, multipliers at every point.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

from perturb.errors import PerturbError  # noqa: E402
from perturb.model.system import System  # noqa: E402
from perturb.model.system_builtins import builtin_system  # noqa: E402
from perturb.numeric.autonomous_balance import (  # noqa: E402
    autonomous_balance_branch,
    autonomous_balance_orbit,
)
from perturb.simulate.flows.factory import make_flow  # noqa: E402
from perturb.simulate.flows.system_events import SystemEventFlow  # noqa: E402
from perturb.simulate.orbits.shooting import limit_cycle  # noqa: E402
from perturb.solve import limit_cycles  # noqa: E402

VDP_PERIOD_EPS1 = 6.663286859323130  # literature value


def timed(fn, repeat: int):
    """(min CPU, last result) over ``repeat`` runs."""
    cpus, out = [], None
    for _ in range(repeat):
        c0 = time.process_time()
        out = fn()
        cpus.append(time.process_time() - c0)
    return min(cpus), out


def header() -> None:
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}; load average {os.getloadavg()}"
    )


def vdp_part(repeat: int, quick: bool) -> None:
    print("\n== 1. van der Pol eps = 1: HB (Hopf start + multipliers) vs exact limit cycles")
    vdp = System.parse(["x'' - eps*(1 - x**2)*x' + x = 0"], {"eps": 1.0}, name="vdp")
    t_search, exact = timed(lambda: limit_cycles(vdp), repeat)
    cyc = exact.cycles[0]
    flow = make_flow(vdp, rtol=1e-12, atol=1e-12)
    y0, T0 = cyc.y0, cyc.period
    t_polish, polished = timed(lambda: limit_cycle(flow, y0 * 1.01, T0 * 1.01), repeat)
    amp = float(polished.max_abs()[0])
    mu = np.sort(np.abs(polished.multipliers))[0]
    print(
        f"exact: limit_cycles (search) {t_search:.3f} s, shooting polish {t_polish:.3f} s; "
        f"period {polished.period:.15g} (literature {VDP_PERIOD_EPS1}), max|x| {amp:.12g}, "
        f"nontrivial multiplier {mu:.6e}"
    )
    print(
        f"{'H':>3} {'CPU s':>8} {'x search':>9} {'x polish':>9} {'period err':>11} "
        f"{'max|x| err':>11} {'mu rel err':>11} {'|trivial-1|':>11}"
    )
    for H in (3, 5, 7, 11, 15) if quick else (3, 5, 7, 9, 11, 15, 21, 25, 31):
        t, sol = timed(lambda H=H: autonomous_balance_orbit(vdp, H), repeat)
        mu_hb = abs(sol.nontrivial_multipliers[0])
        print(
            f"{H:3d} {t:8.4f} {t_search / t:9.1f} {t_polish / t:9.2f} "
            f"{abs(sol.period - VDP_PERIOD_EPS1) / VDP_PERIOD_EPS1:11.2e} "
            f"{abs(sol.amplitudes['x'] - amp) / amp:11.2e} {abs(mu_hb - mu) / mu:11.2e} "
            f"{abs(sol.trivial_multiplier - 1):11.2e}"
        )


def belt_part(repeat: int, quick: bool) -> None:
    print("\n== 2. belt (Stribeck stick-slip): HB vs the event-driven exact cycle")
    belt = builtin_system("belt")
    t_search, exact = timed(lambda: limit_cycles(belt), repeat)
    cyc = exact.cycles[0]
    T, amp = cyc.period, float(cyc.max_abs()[0])
    flow = SystemEventFlow(belt, rtol=1e-12, atol=1e-12)
    t_polish, polished = timed(lambda: limit_cycle(flow, cyc.y0, cyc.period * 1.001), repeat)
    print(
        f"exact: limit_cycles (search) {t_search:.3f} s, event-driven shooting polish "
        f"{t_polish:.3f} s; period {T:.12g} (polish {polished.period:.12g}), max|x| "
        f"{amp:.10g}, multipliers {np.round(np.abs(cyc.multipliers), 6).tolist()}"
    )
    print(
        f"{'H':>3} {'width':>9} {'CPU s':>8} {'x search':>9} {'period err':>11} "
        f"{'max|x| err':>11} {'|mu|':>9} | exact law (jump_width=0): period err, max|x| err"
    )
    for H in (3, 5, 9, 15, 25) if quick else (3, 5, 9, 15, 25, 40, 63):
        t, sol = timed(lambda H=H: autonomous_balance_orbit(belt, H), repeat)
        line = (
            f"{H:3d} {sol.jump_width:9.2e} {t:8.4f} {t_search / t:9.1f} "
            f"{abs(sol.period - T) / T:11.2e} {abs(sol.amplitudes['x'] - amp) / amp:11.2e} "
            f"{abs(sol.nontrivial_multipliers[0]):9.2e} | "
        )
        if H in (9, 15, 25):
            c0 = time.process_time()
            try:
                ex = autonomous_balance_orbit(belt, H, jump_width=0.0, stability=False)
                line += (
                    f"{abs(ex.period - T) / T:.2e}, {abs(ex.amplitudes['x'] - amp) / amp:.2e} "
                    f"({time.process_time() - c0:.2f} s)"
                )
            except PerturbError:
                line += f"no convergence ({time.process_time() - c0:.2f} s)"
        else:
            line += "not tried"
        print(line)


def branch_part(repeat: int) -> None:
    print("\n== 3. continuation in a parameter (multipliers at every point)")
    vdp = System.parse(["x'' - eps*(1 - x**2)*x' + x = 0"], {"eps": 1.0}, name="vdp")
    t, br = timed(lambda: autonomous_balance_branch(vdp, "eps", (0.2, 2.0), 15), repeat)
    print(
        f"vdp eps (0.2, 2), H = 15: {len(br)} points, {t:.3f} s, stops {br.stop_reasons}, "
        f"period {br.period[0]:.8g} -> {br.period[-1]:.8g}, all stable {bool(np.all(br.stable))}"
    )
    belt = builtin_system("belt")
    t, br = timed(lambda: autonomous_balance_branch(belt, "v_b", (0.15, 0.3), 9), repeat)
    print(
        f"belt v_b (0.15, 0.3), H = 9: {len(br)} points, {t:.3f} s, stops {br.stop_reasons}, "
        f"max|x| {br.amplitudes['x'][0]:.6g} -> {br.amplitudes['x'][-1]:.6g}, all stable "
        f"{bool(np.all(br.stable))}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    header()
    vdp_part(args.repeat, args.quick)
    belt_part(args.repeat, args.quick)
    branch_part(args.repeat)
    print(f"\nload average at the end {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
