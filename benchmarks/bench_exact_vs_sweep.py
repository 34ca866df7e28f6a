"""Benchmark: the whole exact SDOF response against a brute-force DOP853 sweep (issue 15).

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_exact_vs_sweep.py  # ~6 min CPU (16 min wall at load 5)
    PYTHONPATH=. python benchmarks/bench_exact_vs_sweep.py --repeat 2

Problem: the ``nsd`` builtin at k = -0.5 (mu = 0.05, F = 2), forcing frequency window
Omega in [0.3, 2].

* **exact**: :func:`perturb.simulate.exact_response.exact_frequency_response` on the window,
  serial (``workers=1``), default options: every branch (the issue's reference: 5 branches,
  2 205 points), each point an exact periodic orbit with its Floquet multipliers.
* **sweep**: what a user without the toolkit's exact response would write, a stepped-sine
  sweep up then down over ``--frequencies`` (100) equally spaced frequencies
  (:func:`perturb.simulate.studies.frequency_sweep`, ``method="ode"``: ``solve_ivp`` DOP853,
  ``rtol = 1e-8``, ``atol`` the sweep's default 1e-12; each frequency integrated from the
  previous state until the stroboscopic points repeat to 1e-8 or for 400 periods, then 8
  periods recorded; no multipliers).  It finds the stable attractors only (above Omega ~ 1.2
  they are not period-1 orbits: the check at the end counts them apart).

Both run serially in this one process, alternately (exact, sweep, exact, sweep, ...,
exact: ``--repeat`` sweeps between ``--repeat + 1`` exact runs), so that a changing load on a
shared machine hits both alike.  The ratio is sweep / exact, on the medians of process CPU
time (wall time on a loaded machine includes waiting for a core; printed too).  The goal of
issue 15 is >= 100x.
"""

from __future__ import annotations

import os

os.environ.setdefault("PERTURB_PROGRESS", "0")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

from perturb.model.builtins import builtin_model  # noqa: E402
from perturb.simulate.exact_response import exact_frequency_response  # noqa: E402
from perturb.simulate.studies import frequency_sweep  # noqa: E402

COMMAND = "PYTHONPATH=. python benchmarks/bench_exact_vs_sweep.py"
WINDOW = (0.3, 2.0)


def run_exact(osc):
    return exact_frequency_response(osc, WINDOW, workers=1)


def run_sweep(osc, n: int, rtol: float):
    omegas = np.linspace(WINDOW[0], WINDOW[1], n)
    return frequency_sweep(
        osc, omegas, direction="both", method="ode", rtol=rtol, multipliers=False, progress=False
    )


def clock(fn):
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - t, time.process_time() - c, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1, help="sweeps timed (default 1)")
    ap.add_argument("--frequencies", type=int, default=100, help="sweep frequencies (100)")
    ap.add_argument("--rtol", type=float, default=1e-8, help="DOP853 rtol of the sweep (1e-8)")
    args = ap.parse_args(argv)
    rep = max(1, args.repeat)
    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    print(f"command: {COMMAND} --repeat {rep} --frequencies {args.frequencies}")
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {sys.platform}, {os.cpu_count()} cores, load average "
        f"{os.getloadavg()[0]:.1f}"
    )
    print(f"nsd k=-0.5 mu=0.05 F=2, Omega in {WINDOW}; serial; exact / sweep / exact / ...")
    ex_w, ex_c, sw_w, sw_c = [], [], [], []
    exact = sweep = None
    for i in range(rep + 1):
        w, c, exact = clock(lambda: run_exact(osc))
        ex_w.append(w)
        ex_c.append(c)
        n_pts = sum(b.omega.size for b in exact.branches)
        print(
            f"  exact #{i + 1}: {c:8.2f} s CPU {w:8.2f} s wall  "
            f"({len(exact.branches)} branches, {n_pts} points)",
            flush=True,
        )
        if i == rep:
            break
        w, c, sweep = clock(lambda: run_sweep(osc, args.frequencies, args.rtol))
        sw_w.append(w)
        sw_c.append(c)
        print(
            f"  sweep #{i + 1}: {c:8.2f} s CPU {w:8.2f} s wall  ({args.frequencies} "
            f"frequencies up and down, DOP853 rtol {args.rtol:g})",
            flush=True,
        )
    assert exact is not None and sweep is not None
    # the sweep's amplitudes against the exact period-1 branches: a check that both computed
    # the same response where the attractor is a period-1 orbit (the sweep's own error:
    # ~1e-6 relative from the sampled maximum, plus what is left of the transient); the
    # states farther than 1e-3 from every exact period-1 point are other attractors
    # (subharmonic or chaotic motion, which the period-1 response does not contain)
    errs, others = [], 0
    for br in sweep.branches:
        for st in br.states:
            best = np.inf
            for b in exact.branches:
                p, a = b.omega, b.amplitude
                for j in np.flatnonzero(np.diff(np.sign(p - st.omega))):
                    s = (st.omega - p[j]) / (p[j + 1] - p[j])
                    amp = a[j] + s * (a[j + 1] - a[j])
                    best = min(best, abs(amp - st.amplitude) / max(abs(amp), 1e-300))
                for j in np.flatnonzero(p == st.omega):
                    best = min(best, abs(a[j] - st.amplitude) / max(abs(a[j]), 1e-300))
            if best <= 1e-3:
                errs.append(best)
            else:
                others += 1
    ce, we = statistics.median(ex_c), statistics.median(ex_w)
    cs, ws = statistics.median(sw_c), statistics.median(sw_w)
    if errs:
        print(
            f"sweep states on an exact period-1 branch (within 1e-3): {len(errs)}, relative "
            f"amplitude difference median {np.median(errs):.1e}, max {np.max(errs):.1e}; "
            f"{others} states on other attractors (no period-1 orbit of that amplitude)"
        )
    print("(the sweep records the sampled maximum of 8 periods at 128 samples per period)")
    print(f"exact: {ce:.2f} s CPU, {we:.2f} s wall (medians of {len(ex_c)})")
    print(f"sweep: {cs:.2f} s CPU, {ws:.2f} s wall (medians of {len(sw_c)})")
    print(
        f"RATIO sweep / exact = {cs / ce:.1f}x (CPU medians; {ws / we:.1f}x wall), "
        f"goal >= 100x: {'met' if cs / ce >= 100 else 'NOT met'}"
    )
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
