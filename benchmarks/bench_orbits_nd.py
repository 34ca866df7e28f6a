"""Benchmark: one exact period-1 orbit with its Floquet multipliers, several coordinates.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_orbits_nd.py [--repeat 10]

Three comparisons, all timed in this one process (median and minimum of the runs, wall and
CPU), each run with a fresh flow (no trajectory reused across runs; the per-system data --
the SDOF segments kept on the ``PWLSystem``, the n-D region eigen-decompositions kept per
``PiecewiseAffineSystem`` object -- are built once, in both cases):

1. ``n = 2`` against the SDOF case (issue 15: "n = 2 within 2x the current SDOF time"):
   the SDOF orbit of ``benchmarks/bench_shooting.py`` (nsd, k = -2, mu = 0.05, F = 2,
   W = 0.6, ``periodic_orbit(ExactPWLFlow(...))``) against the 2-DOF ``nsd2`` builtin at
   W = 1.2 (its stable orbit, 4 states: ``periodic_orbit(AffineExactFlow(pas))`` with
   ``pas = system.piecewise_affine()`` built once, as the SDOF run starts from its numeric
   ``PWLSystem``; ``make_flow(system)``, the symbolic build, is timed separately). Guess: the
   orbit + 0.01.  The two are run alternately (SDOF, nsd2, SDOF, ...) so that a changing
   load on a shared machine hits both alike; CPU medians are the measure (wall time on a
   loaded machine includes waiting for a core); the line ``RATIO`` is the result.
2. ``n = 2, 4, 8`` masses in a chain built with ``System.from_matrices``: each mass on a
   spring (1) to ground, neighbours coupled by a spring (0.5) and a two-sided gap (clearance
   0.2, contact stiffness 4), damping 0.05 per mass to ground, ``F cos(W t)`` on the first
   mass (F = 1, W = 1.1); the orbit shooting finds from the state 200 periods after rest
   (or one of the next 100 periods), guess = orbit + 0.01.
   Exact (AffineExactFlow, tol 1e-12) against DOP853 shooting
   (:class:`~perturb.simulate.flows.factory.SystemODEFlow`, ``make_flow(method="ode")``:
   DOP853 with variational equations on ``System.field``, rtol 1e-10, atol 1e-12,
   tol 1e-8 -- the smooth integrator steps over the contact switches and cannot reach 1e-12),
   its errors measured against the exact orbit.
"""

from __future__ import annotations

import os

# one BLAS thread: the matrices here are 4x4 to 16x16, and on a loaded machine a BLAS thread
# pool makes a LAPACK call wait for a free core (wall time many times the CPU time)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

from perturb.errors import PerturbError  # noqa: E402
from perturb.model.builtins import builtin_model  # noqa: E402
from perturb.model.system import System, gap  # noqa: E402
from perturb.model.system_builtins import builtin_system  # noqa: E402
from perturb.simulate.flows.affine_exact import AffineExactFlow, propagate  # noqa: E402
from perturb.simulate.flows.exact import ExactPWLFlow  # noqa: E402
from perturb.simulate.flows.factory import make_flow  # noqa: E402
from perturb.simulate.orbits.shooting import periodic_orbit  # noqa: E402


def timed(fn, repeat: int) -> tuple[float, float, float, float, object]:
    """Wall median, wall minimum, CPU median, CPU minimum of ``fn()``, and its last result."""
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        cpus.append(time.process_time() - c)
        walls.append(time.perf_counter() - t)
    return statistics.median(walls), min(walls), statistics.median(cpus), min(cpus), out


def interleaved(fns: dict, repeat: int) -> dict:
    """Like :func:`timed` for several functions run alternately, ``repeat`` rounds."""
    walls: dict = {k: [] for k in fns}
    cpus: dict = {k: [] for k in fns}
    outs: dict = {}
    for _ in range(repeat):
        for k, fn in fns.items():
            t, c = time.perf_counter(), time.process_time()
            outs[k] = fn()
            cpus[k].append(time.process_time() - c)
            walls[k].append(time.perf_counter() - t)
    return {
        k: (
            statistics.median(walls[k]),
            min(walls[k]),
            statistics.median(cpus[k]),
            min(cpus[k]),
            outs[k],
        )
        for k in fns
    }


def orbit_from_rest(flow, n: int, periods: int = 200, tries: int = 100):
    """The period-1 orbit that shooting finds from the state ``periods`` forcing periods
    after rest, else from the states one, two, ... periods later (at most ``tries``): from
    rest the motion passes through chaotic transients whose course depends on rounding, so
    a fixed state is not always in Newton's basin."""
    system, T = flow.affine_system, flow.period
    y = propagate(system, np.zeros(2 * n), 0.0, periods * T).y
    for k in range(periods, periods + tries):
        try:
            return periodic_orbit(flow, y)
        except PerturbError:
            y = propagate(system, y, k * T, (k + 1) * T).y
    raise SystemExit(f"chain n={n}: no period-1 orbit from {tries} states after rest")


def chain(n: int, W: float = 1.1) -> System:
    """``n`` masses, springs to ground and between neighbours, gaps between neighbours."""
    K = np.zeros((n, n))
    for i in range(n):
        K[i, i] += 1.0
    for i in range(n - 1):
        K[i, i] += 0.5
        K[i + 1, i + 1] += 0.5
        K[i, i + 1] -= 0.5
        K[i + 1, i] -= 0.5
    forcing = [f"cos({W}*t)"] + ["0"] * (n - 1)
    elements = [gap(f"x{i + 1} - x{i + 2}", 0.2, 4.0) for i in range(n - 1)]
    return System.from_matrices(
        np.eye(n).tolist(),
        (0.05 * np.eye(n)).tolist(),
        K.tolist(),
        elements=elements,
        forcing=forcing,
        name=f"chain{n}",
    )


def row(label: str, t: tuple, extra: str = "") -> str:
    wmed, wmin, cmed, cmin, o = t
    return (
        f"{label:46s} {wmed * 1e3:9.2f}ms {wmin * 1e3:9.2f}ms {cmed * 1e3:9.2f}ms "
        f"{cmin * 1e3:9.2f}ms {o.iterations:6d}  {extra}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10, help="timed runs of the exact variants")
    ap.add_argument("--repeat-ode", type=int, default=3, help="timed runs of DOP853 shooting")
    args = ap.parse_args()
    rep, rep_ode = max(3, args.repeat), max(1, args.repeat_ode)
    print("command: PYTHONPATH=. python benchmarks/bench_orbits_nd.py")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {sys.platform}, load average {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores; {rep} runs (exact), {rep_ode} (DOP853)"
    )
    head = (
        f"{'variant':46s} {'wall med':>11s} {'wall min':>11s} {'CPU med':>11s} {'CPU min':>11s}"
        f" {'Newton':>6s}"
    )

    # 1. n = 2 against the SDOF orbit of bench_shooting.py
    load0 = os.getloadavg()[0]
    osc = builtin_model("nsd", k=-2.0, mu=0.05, F=2.0, Omega=0.6)
    sdof = ExactPWLFlow(osc).system
    ref1 = periodic_orbit(ExactPWLFlow(sdof), [9.4, 1.0])
    g1 = ref1.y0 + 0.01 * np.array([1.0, -1.0])
    nsd2 = builtin_system("nsd2", Omega=1.2)
    pas = nsd2.piecewise_affine()  # numbers, as the SDOF PWLSystem
    ref2 = periodic_orbit(AffineExactFlow(pas), [1.3, -2.9, 0.35, -0.45])
    g2 = ref2.y0 + 0.01 * np.array([1.0, -1.0, 1.0, -1.0])
    both = interleaved(
        {
            "sdof": lambda: periodic_orbit(ExactPWLFlow(sdof), g1),
            "nsd2": lambda: periodic_orbit(AffineExactFlow(pas), g2),
        },
        max(rep, 30),  # (a few ms each: enough rounds for steady medians)
    )
    t_sdof, t_nsd2 = both["sdof"], both["nsd2"]
    t_make = timed(lambda: make_flow(nsd2), rep)
    print("\n1. n = 2 coordinates against the SDOF orbit (both exact, tol 1e-12)")
    print(head)
    print(row("SDOF nsd k=-2 W=0.6 (ExactPWLFlow)", t_sdof, f"{ref1.stability}"))
    print(row("2-DOF nsd2 W=1.2 (AffineExactFlow, 4 states)", t_nsd2, f"{ref2.stability}"))
    print(
        f"(building the flow from the System, make_flow(nsd2): {t_make[0] * 1e3:.2f} ms median,"
        " not in the rows above: the SDOF row starts from its PWLSystem too)"
    )
    print(
        f"(Newton iterations from the same +-0.01 guess: SDOF {t_sdof[4].iterations}, nsd2 "
        f"{t_nsd2[4].iterations}; each propagates one period with its sensitivity)"
    )
    ratio = t_nsd2[2] / t_sdof[2]
    print(
        f"RATIO nsd2 / SDOF = {ratio:.2f}x (CPU medians; {t_nsd2[0] / t_sdof[0]:.2f}x wall "
        f"medians, {t_nsd2[3] / t_sdof[3]:.2f}x CPU minima), target <= 2x: "
        f"{'met' if ratio <= 2.0 else 'NOT met'}"
    )

    # 2. the chain, n = 2, 4, 8 masses: exact against DOP853 shooting
    print("\n2. chain of n masses with gaps: exact (tol 1e-12) vs DOP853 shooting (tol 1e-8)")
    print(head + "  errors of DOP853 vs exact: |dy0|, |dmu|, |dmax|x1||")
    summary = []
    for n in (2, 4, 8):
        system = chain(n)
        flow = make_flow(system)
        T = flow.period
        ref = orbit_from_rest(flow, n)
        guess = ref.y0 + 0.01
        pa = flow.affine_system
        te = timed(lambda p=pa, g=guess: periodic_orbit(AffineExactFlow(p), g), rep)
        ode = make_flow(system, method="ode", rtol=1e-10, atol=1e-12)
        to = timed(lambda f=ode, g=guess: periodic_orbit(f, g, tol=1e-8), rep_ode)
        o = to[4]
        dy = float(np.max(np.abs(o.y0 - ref.y0)))
        dmu = float(
            np.max(np.abs(np.sort_complex(o.multipliers) - np.sort_complex(ref.multipliers)))
        )
        damp = abs(o.amplitude - ref.amplitude)
        n_ev = flow(ref.y0, 0.0, T).n_events
        print(row(f"chain n={n} exact ({2 * n} states, {n_ev} switches/period)", te, ref.stability))
        print(row(f"chain n={n} DOP853 shooting", to, f"{dy:.1e} {dmu:.1e} {damp:.1e}"))
        summary.append((n, te[0], to[0], te[2], to[2]))
    load1 = os.getloadavg()[0]
    print()
    for n, we, wo, ce, co in summary:
        print(
            f"n = {n}: DOP853 / exact = {wo / we:.1f}x (wall medians), {co / ce:.1f}x (CPU "
            f"medians); exact {we * 1e3:.1f} ms"
        )
    print(f"load average {load0:.1f} before, {load1:.1f} after ({os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
