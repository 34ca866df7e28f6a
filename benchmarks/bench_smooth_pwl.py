"""Benchmark: the exact reference of a piecewise-smooth oscillator that is not piecewise linear.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_smooth_pwl.py [--repeat 2] [--no-cli]

The system of issue 15 ('Accuracy and speed'):
``x'' + 0.05x' + x + 0.3x^3 + 2(x-1)H(x-1) + 2(x+1)H(-x-1) = 1.5 cos(Omega t)``, every
period-1 orbit at Omega = 0.8, 1.5, 2.5, 3.5 (``perturb frc EQ --method exact --omega
0.8,1.5,2.5,3.5``).  Its event-driven flow (:class:`~perturb.simulate.flows.event_driven.
EventFlow`) integrates between the switches by Chebyshev collocation steps (``integrator=
"chebyshev"``, the default now) or by DOP853 (``integrator="dop853"``, the old path).  Timed in
this one process, old and new run alternately so that a changing load on the shared machine
hits both alike; CPU medians are the measure (wall time on a loaded machine includes waiting
for a core):

1. the flow alone: one forcing period with its sensitivity from each of the 8 orbits' initial
   states (the unit of work of shooting and continuation), both integrators, and their
   largest difference (state and monodromy);
2. the whole answer, serial (``frequency_response(osc, "exact", frequencies=[...],
   workers=1)``): old (the ``EventFlow`` default switched to ``"dop853"`` for the call) and
   new; the rows (frequency, amplitude, stability) of both and their largest amplitude
   difference.  The line ``RATIO`` is the result;
3. (unless ``--no-cli``) the command line itself, as a user runs it (two worker processes):
   wall time and the CPU time of the process and its children.

Accuracy against an independent solver is the business of
``tests/test_smooth_pwl_reference.py`` (DOP853 at 1e-12 with events, Newton shooting from its
own harmonic balance); here only old against new.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import subprocess
import sys
import time

import numpy as np
import scipy

os.environ.setdefault("PERTURB_PROGRESS", "0")

from perturb.model.oscillator import Oscillator  # noqa: E402
from perturb.simulate.flows.event_driven import EventFlow  # noqa: E402
from perturb.solve import frequency_response  # noqa: E402

EQUATION = (
    "x'' + 0.05*x' + x + 0.3*x**3 + 2*(x-1)*Heaviside(x-1) + 2*(x+1)*Heaviside(-x-1)"
    " = 1.5*cos(Omega*t)"
)
FREQUENCIES = [0.8, 1.5, 2.5, 3.5]


def interleaved(fns: dict, repeat: int) -> dict:
    """Wall median, wall minimum, CPU median, CPU minimum and the last result of each
    function, run alternately ``repeat`` rounds."""
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


def response(integrator: str):
    """The 4-frequency answer with the event-driven flows' integrator set for the call."""
    defaults = EventFlow.__init__.__kwdefaults__
    saved = defaults["integrator"]
    defaults["integrator"] = integrator
    try:
        resp = frequency_response(
            Oscillator.parse(EQUATION), "exact", frequencies=FREQUENCIES, workers=1
        )
    finally:
        defaults["integrator"] = saved
    rows = []
    for br in resp.branches:
        for w, a, s in zip(br.omega, br.amplitude, br.stable, strict=True):
            rows.append((float(w), float(a), bool(s)))
    return sorted(rows)


def flow_part(repeat: int, states: dict[float, list[np.ndarray]]) -> None:
    print("1. one forcing period with sensitivity from each orbit's initial state")
    for W, ys in states.items():
        osc = Oscillator.parse(EQUATION).with_params({"Omega": W})
        new, old = EventFlow(osc), EventFlow(osc, integrator="dop853")
        T = new.period

        def run(flow, ys=ys, T=T):
            return [flow(y, 0.0, T, sensitivity=True) for y in ys]

        fns = {"dop853": lambda f=old: run(f), "chebyshev": lambda f=new: run(f)}
        res = interleaved(fns, repeat)
        dy = max(
            float(np.max(np.abs(a.y - b.y)))
            for a, b in zip(res["dop853"][4], res["chebyshev"][4], strict=True)
        )
        dm = max(
            float(np.max(np.abs(a.sensitivity - b.sensitivity)))
            for a, b in zip(res["dop853"][4], res["chebyshev"][4], strict=True)
        )
        c_old, c_new = res["dop853"][2] / len(ys), res["chebyshev"][2] / len(ys)
        print(
            f"   Omega {W}: {len(ys)} orbit(s), CPU per period dop853 {1e3 * c_old:.2f} ms, "
            f"chebyshev {1e3 * c_new:.2f} ms, ratio {c_old / c_new:.1f}; "
            f"max |dy| {dy:.1e}, max |d monodromy| {dm:.1e}"
        )


def cli_part() -> None:
    cmd = [sys.executable, "-m", "perturb.apps.cli", "frc", EQUATION, "--method", "exact"]
    cmd += ["--omega", ",".join(str(w) for w in FREQUENCIES)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    rows = [r for r in out.stdout.splitlines()[1:] if r]
    print("3. the command line (two worker processes):")
    print(f"   perturb frc EQ --method exact --omega {','.join(map(str, FREQUENCIES))}")
    print(f"   {len(rows)} rows, wall {wall:.1f} s, CPU (process + children) {cpu:.1f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=2, help="rounds of the whole answer")
    ap.add_argument("--no-cli", action="store_true", help="skip the command-line timing")
    args = ap.parse_args()
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}"
    )
    # warm-up (imports, derivations, compiled fields) outside the timings
    response("chebyshev")
    res = interleaved(
        {"dop853": lambda: response("dop853"), "chebyshev": lambda: response("chebyshev")},
        args.repeat,
    )
    old_rows, new_rows = res["dop853"][4], res["chebyshev"][4]
    states: dict[float, list[np.ndarray]] = {}
    for W in FREQUENCIES:
        from perturb.solve import periodic_orbits

        states[W] = [o.y0 for o in periodic_orbits(Oscillator.parse(EQUATION), W)]
    flow_part(max(3, args.repeat), states)
    print("2. every orbit at the four frequencies, serial (frequency_response, workers=1)")
    for name in ("dop853", "chebyshev"):
        wm, wmin, cm, cmin, rows = res[name]
        print(
            f"   {name:9s}: CPU median {cm:.2f} s (min {cmin:.2f}), wall median {wm:.2f} s; "
            f"{len(rows)} rows"
        )
    same = len(old_rows) == len(new_rows) and all(
        a[0] == b[0] and a[2] == b[2] for a, b in zip(old_rows, new_rows, strict=False)
    )
    d_amp = (
        max(abs(a[1] - b[1]) / b[1] for a, b in zip(old_rows, new_rows, strict=True))
        if same
        else float("nan")
    )
    for w, a, s in new_rows:
        print(f"     Omega {w}: amplitude {a:.10f} {'stable' if s else 'unstable'}")
    print(f"   same orbits and stability: {same}; max relative |d amplitude| {d_amp:.1e}")
    print(f"RATIO (CPU, old / new, whole answer): {res['dop853'][2] / res['chebyshev'][2]:.2f}")
    if not args.no_cli:
        cli_part()


if __name__ == "__main__":
    main()
