"""Benchmark: harmonic balance of a chain of n masses with one gap element each
(:mod:`perturb.numeric.system_balance`), time per response against n and H, and the share of
the Jacobian assembly in it (issue 16: "the Jacobian assembly must not be the quadratic
term").

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_system_balance_chain.py [--quick] [--repeat 3]

The chain (``chain(n)`` of ``bench_system_balance.py``): n unit masses, springs 1 to ground and
0.5 between neighbours, damping 0.05, a two-sided gap (clearance 0.2, stiffness 4) on each
mass's displacement relative to its left neighbour (ground for the first), forcing
``0.05 cos(Omega t)`` on the first mass: ``n`` PWL elements, each touching at most two
coordinates (``nnz(w) nnz(c) <= 4`` blocks of ``(2H+1)^2``).

Per ``(n, H)``, all CPU time (``time.process_time``; the machine is shared: the load average
is printed; one BLAS thread), minimum over ``--repeat`` runs:

* ``assemble``: one residual + Jacobian evaluation at (a point next to) the solution at
  Omega = 1.1, sparse CSC (what Newton at fixed frequency factors above 400 unknowns) and
  dense (what the continuation core takes), and the residual alone (every element's exact
  projection included);
* ``LU``: one dense LU of the same Jacobian (``scipy.linalg.lu_factor``), and one sparse LU
  (SuperLU) of the CSC matrix;
* ``response``: ``system_balance_branch(chain(n), (0.8, 1.3), harmonics=H)`` (one branch from
  Omega = 1.3 with Floquet multipliers at every point), its points, its residual + Jacobian
  evaluations, the CPU inside ``SystemBalance.evaluate`` (the assembly: residual, projection,
  Jacobian) and its share of the response, and the CPU of the Floquet multipliers (monodromy
  of the ``2n``-state linearisation); the rest is the continuation core (a dense bordered LU
  per Newton step: the core takes dense matrices, ``(nH)^3``).

Then the growth exponents ``d log t / d log n`` between consecutive n at each H: the sparse
assembly grows ~linearly in n (n elements of fixed cost), the dense LU like ``n^3``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402
import scipy.linalg as sla  # noqa: E402
import scipy.sparse.linalg as spla  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_system_balance import chain  # noqa: E402

from perturb.numeric.system_balance import SystemBalance, system_balance_branch  # noqa: E402

W_FIXED = 1.1
WINDOW = (0.8, 1.3)


def cpu(fn, repeat: int):
    """(min CPU seconds, last result) over ``repeat`` runs."""
    best, out = math.inf, None
    for _ in range(repeat):
        c0 = time.process_time()
        out = fn()
        best = min(best, time.process_time() - c0)
    return best, out


class _Timed:
    """Wraps one method of one instance (``sb.evaluate``, ``sb._max_multipliers``): CPU spent
    inside it."""

    def __init__(self, sb: SystemBalance, name: str) -> None:
        self.sb, self.name, self.inner, self.cpu = sb, name, getattr(sb, name), 0.0
        setattr(sb, name, self)  # instance attribute: the other methods call through it

    def __call__(self, *args, **kwargs):
        c0 = time.process_time()
        try:
            return self.inner(*args, **kwargs)
        finally:
            self.cpu += time.process_time() - c0

    def remove(self) -> None:
        delattr(self.sb, self.name)


def row(n: int, H: int, repeat: int, response_limit: int) -> dict:
    system = chain(n)
    sb = SystemBalance(system, H)
    u0 = sb.solve(W_FIXED)
    calls = iter(range(1, 10**6))

    def fresh():
        # a new point each call: the balance keeps the last projections of each element
        return u0 * (1.0 + 1e-12 * next(calls))

    t_sparse, Js = cpu(lambda: sb.evaluate(fresh(), W_FIXED, sparse=True)[1], repeat)
    t_dense, Jd = cpu(lambda: sb.evaluate(fresh(), W_FIXED)[1], repeat)
    t_res, _ = cpu(lambda: sb.evaluate(fresh(), W_FIXED, False), repeat)
    t_lu, _ = cpu(lambda: sla.lu_factor(Jd), repeat)
    t_splu, _ = cpu(lambda: spla.splu(Js.tocsc()), repeat)
    out = dict(
        n=n,
        H=H,
        unknowns=sb.n_unknowns,
        sparse=t_sparse,
        dense=t_dense,
        residual=t_res,
        lu=t_lu,
        splu=t_splu,
        nnz=Js.nnz,
    )
    if sb.n_unknowns <= response_limit:
        timer, mult = _Timed(sb, "evaluate"), _Timed(sb, "_max_multipliers")
        ev0 = sb.evaluations
        c0 = time.process_time()
        br = system_balance_branch(system, WINDOW, balance=sb, stability=True)
        total = time.process_time() - c0
        timer.remove()
        mult.remove()
        out.update(
            points=len(br),
            evals=sb.evaluations - ev0,
            response=total,
            assembly=timer.cpu,
            multipliers=mult.cpu,
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="n <= 8")
    ap.add_argument(
        "--response-limit",
        type=int,
        default=1100,
        help="whole responses only up to this many unknowns (default 1100: n = 32, H = 15)",
    )
    args = ap.parse_args(argv)
    print(
        f"python {sys.version.split()[0]}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {os.cpu_count()} cpus, load average "
        + " ".join(f"{v:.2f}" for v in os.getloadavg())
    )
    ns = (2, 4, 8) if args.quick else (2, 4, 8, 16, 32)
    Hs = (3, 7, 15)
    print(
        "\n   n   H  unknowns     nnz | eval sparse  eval dense  residual | dense LU  sparse LU"
        " | response: points evals  CPU s  in evaluate  share  ms/eval  multipliers"
    )
    rows = []
    for H in Hs:
        for n in ns:
            r = row(n, H, args.repeat, args.response_limit)
            rows.append(r)
            resp = "-"
            if "response" in r:
                resp = (
                    f"{r['points']:6d} {r['evals']:5d} {r['response']:6.2f}  "
                    f"{r['assembly']:9.2f} s  {r['assembly'] / r['response']:5.0%}  "
                    f"{r['assembly'] / r['evals'] * 1e3:7.2f}  {r['multipliers']:8.2f} s"
                )
            print(
                f"  {n:3d} {H:3d} {r['unknowns']:8d} {r['nnz']:8d} | {r['sparse'] * 1e3:8.2f} ms"
                f" {r['dense'] * 1e3:8.2f} ms {r['residual'] * 1e3:7.2f} ms |"
                f" {r['lu'] * 1e3:7.2f} ms {r['splu'] * 1e3:7.2f} ms | {resp}",
                flush=True,
            )
    print("\ngrowth exponents d log t / d log n between consecutive n (same H):")
    print("   H   n -> 2n   eval sparse  eval dense  dense LU  response")
    for H in Hs:
        sub = [r for r in rows if r["H"] == H]
        for a, b in zip(sub[:-1], sub[1:], strict=True):
            f = math.log(b["n"] / a["n"])

            def g(key, a=a, b=b, f=f):
                if key not in a or key not in b or a[key] <= 0 or b[key] <= 0:
                    return "   -"
                return f"{math.log(b[key] / a[key]) / f:5.2f}"

            print(
                f"  {H:3d} {a['n']:3d} -> {b['n']:3d}    {g('sparse')}       {g('dense')}"
                f"      {g('lu')}     {g('response')}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
