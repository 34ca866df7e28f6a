"""Benchmark: a forced Duffing H = 7 frequency response by perturb and by the
``harmonicbalance`` package, each as a whole process (interpreter start, imports, model,
response), as a user running one script would pay it.

Reproduce with (the package lives in a separate venv; it is never a dependency of perturb)::

    python -m venv /tmp/aftvenv --system-site-packages
    /tmp/aftvenv/bin/pip install pyharm-os harmonicbalance
    OPENBLAS_NUM_THREADS=1 /tmp/aftvenv/bin/python benchmarks/bench_duffing_harmonicbalance.py

Problem (the ``duffing`` problem of ``perturb bench``): ``x'' + 0.1 x' + x + x^3 = 0.5 cos(W
t)``, W from 2.5 down to 0.5 through both folds, H = 7 harmonics.

* perturb: ``harmonic_balance_response(builtin_model("duffing", ...), (0.5, 2.5),
  harmonics=7)`` (the connected branch, automatic start, AFT with 29 samples, analytic
  Jacobian, Hill stability at every point).
* perturb front door: ``perturb.frequency_response(osc, "hb", Omega=(0.5, 2.5),
  harmonics=7)``: every branch, Newton also started from the symbolic single-harmonic balance
  response (derived and compiled in the process), the window-edge and branch-point searches.
* harmonicbalance: ``PredictorCorrectorSolver`` on the residual written with its ``Fourier``
  class (``X.dt().dt() + mu X.dt() + X + alpha X**3 - F cos``: AFT at ``4 H + 1`` samples,
  its default), started from the linear response at W = 2.5, ``alpha_step = 0.05``, its
  finite-difference Jacobian (``use_jac=True``). No stability.

All snippets run with the same interpreter (the venv's, which sees perturb through
``--system-site-packages``), interleaved (perturb, harmonicbalance, perturb, ...), ``--repeat``
times each; wall time from ``time.perf_counter`` around ``subprocess.run`` and CPU time of the
child from ``resource.getrusage(RUSAGE_CHILDREN)`` (user + system). Each snippet prints its
branch as JSON; this script (not timed) measures the error of max|x| against exact periodic
orbits at a few frequencies (``perturb.frequency_response(osc, "exact", frequencies=...)``,
shooting on the flow), each solution of a response there against the nearest exact orbit.

Measured (2-core machine shared with ~7 jobs, load average 8-10; median CPU of 5 interleaved
runs each): perturb 0.72 s, the perturb front door 1.04 s, harmonicbalance 1.33 s: perturb
1.85x and its front door 1.28x the speed of harmonicbalance (wall 1.83x and 1.31x). Errors
of max|x| (H = 7 truncation plus interpolation between points) are of the same size: perturb
5.2e-4, 7.0e-5, 2.2e-4, 3.8e-4 and harmonicbalance 3.5e-5, 5.4e-5, 6.5e-4, 3.8e-4 at W = 0.8,
1.2, 1.5, 2.0 (155 and 174 points).
Before the compile cache, the monomial tables and the lazy SciPy imports: perturb 0.90 s
(1.38x; 3 runs) and the front door 1.49 s (0.91x; 3 runs, with the lazy ``numeric.roots``
import already in).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PARAMS = {"alpha": 1.0, "mu": 0.1, "F": 0.5, "omega0": 1.0}
WINDOW = (0.5, 2.5)
H = 7
CHECK = (0.8, 1.2, 1.5, 2.0)

PERTURB = f"""
import json
from perturb.model.builtins import builtin_model
from perturb.numeric.harmonic_balance import harmonic_balance_response
osc = builtin_model("duffing", **{PARAMS!r})
r = harmonic_balance_response(osc, {WINDOW!r}, harmonics={H})
b = r.branches[0]
print(json.dumps({{"omega": b.omega.tolist(), "amplitude": b.amplitude.tolist()}}))
"""

# the front door: every branch (seeded from the symbolic single-harmonic balance), the call a
# user of ``perturb frc`` / ``frequency_response`` makes
FRONT_DOOR = f"""
import json
import perturb
from perturb.model.builtins import builtin_model
osc = builtin_model("duffing", **{PARAMS!r})
r = perturb.frequency_response(osc, "hb", Omega={WINDOW!r}, harmonics={H})
b = r.branches[0]
print(json.dumps({{"omega": b.omega.tolist(), "amplitude": b.amplitude.tolist()}}))
"""

HARMONICBALANCE = f"""
import contextlib, io, json
import numpy as np
from harmonicbalance.fourier import Fourier
from harmonicbalance.predictorcorrector import PredictorCorrectorSolver
H, mu, alpha, F = {H}, {PARAMS["mu"]}, {PARAMS["alpha"]}, {PARAMS["F"]}
lo, hi = {WINDOW!r}

def residual(X):
    forcing = Fourier(0.0, np.eye(H)[0] * F, np.zeros(H), X.omega, H)
    return X.dt().dt() + mu * X.dt() + X + alpha * X**3 - forcing

Z = F / complex(1.0 - hi**2, mu * hi)
X0 = Fourier(0.0, np.eye(H)[0] * Z.real, np.eye(H)[0] * -Z.imag, hi, H)
pc = PredictorCorrectorSolver(residual, X0, hi, lo, 0.05, use_jac=True)
with contextlib.redirect_stdout(io.StringIO()):
    sols = pc.solve()

def max_abs(X):
    t = np.linspace(0.0, 2.0 * np.pi / X.omega, 4096, endpoint=False)
    return float(np.abs(X(t)).max())

omega = [float(s.omega) for s in sols]
print(json.dumps({{"omega": omega, "amplitude": [max_abs(s) for s in sols]}}))
"""


def run(code: str, python: str) -> tuple[float, float, dict]:
    """``(wall, cpu, printed json)`` of ``python -c code`` as a child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    out = subprocess.run(
        [python, "-c", code], capture_output=True, text=True, cwd=ROOT, check=False
    )
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if out.returncode != 0:
        raise RuntimeError(f"child failed:\n{out.stderr[-2000:]}")
    return wall, cpu, json.loads(out.stdout.strip().splitlines()[-1])


def errors(data: dict, exact: dict[float, list[float]]) -> str:
    omega, amp = np.asarray(data["omega"]), np.asarray(data["amplitude"])
    out = []
    for W, refs in exact.items():
        seg = np.nonzero((omega[:-1] - W) * (omega[1:] - W) <= 0)[0]
        if seg.size == 0:
            out.append(f"W={W}: no point")
            continue
        errs = []
        for i in seg:
            f = 0.0 if omega[i + 1] == omega[i] else (W - omega[i]) / (omega[i + 1] - omega[i])
            v = (1 - f) * amp[i] + f * amp[i + 1]
            errs.append(min(abs(v - r) / r for r in refs))
        out.append(f"W={W}: {max(errs):.1e} ({len(errs)} sol.)")
    return ", ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5, help="runs of each snippet")
    ap.add_argument("--python", default=sys.executable, help="interpreter of both snippets")
    args = ap.parse_args()
    print(
        f"command: OPENBLAS_NUM_THREADS=1 {args.python} benchmarks/bench_duffing_harmonicbalance.py"
    )
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    have_hb = (
        subprocess.run(
            [args.python, "-c", "import harmonicbalance"], capture_output=True, check=False
        ).returncode
        == 0
    )
    runs: dict[str, list[tuple[float, float]]] = {
        "perturb": [],
        "perturb front door": [],
        "harmonicbalance": [],
    }
    last: dict[str, dict] = {}
    for _ in range(args.repeat):
        for name, code in (
            ("perturb", PERTURB),
            ("harmonicbalance", HARMONICBALANCE),
            ("perturb front door", FRONT_DOOR),
        ):
            if name == "harmonicbalance" and not have_hb:
                continue
            wall, cpu, data = run(code, args.python)
            runs[name].append((wall, cpu))
            last[name] = data
    import perturb
    from perturb.model.builtins import builtin_model

    osc = builtin_model("duffing", **PARAMS)
    ex = perturb.frequency_response(osc, "exact", frequencies=list(CHECK))
    exact: dict[float, list[float]] = {W: [] for W in CHECK}
    for br in ex.branches:
        for W, A in zip(br.omega, br.amplitude, strict=True):
            exact[min(CHECK, key=lambda c: abs(c - W))].append(float(A))
    med = {}
    for name, rr in runs.items():
        if not rr:
            print(f"{name:18s} not importable with {args.python}: skipped")
            continue
        walls, cpus = [w for w, _ in rr], [c for _, c in rr]
        med[name] = (statistics.median(walls), statistics.median(cpus))
        data = last[name]
        print(
            f"{name:18s} whole process: wall median {med[name][0]:.3f} s "
            f"(min {min(walls):.3f}), CPU median {med[name][1]:.3f} s (min {min(cpus):.3f}); "
            f"{len(data['omega'])} points, W {min(data['omega']):.3f}..{max(data['omega']):.3f}; "
            f"max|x| error {errors(data, exact)}"
        )
    if "harmonicbalance" in med:
        ref = med["harmonicbalance"]
        for name in ("perturb", "perturb front door"):
            print(
                f"speed of {name} relative to harmonicbalance (>1: perturb faster): wall "
                f"{ref[0] / med[name][0]:.2f}x, CPU {ref[1] / med[name][1]:.2f}x"
            )


if __name__ == "__main__":
    main()
