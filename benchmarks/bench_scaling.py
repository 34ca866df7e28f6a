"""Memory and scale (issue 7 item 4): how time, expression size and memory grow with the
expansion order of the symbolic engines, and how time grows with the number of points of a
frequency response.

Reproduce with::

    python benchmarks/bench_scaling.py            # everything, ~10 min
    python benchmarks/bench_scaling.py --only orders --max-order 3  # a subset

Parts
-----
``orders``
    Every derivation runs in a fresh Python process (``PERTURB_CACHE=0``: no on-disk cache;
    a fresh process: no warm SymPy or memoised helpers), which reports the wall and CPU time
    of the derivation alone (imports excluded), the size of its result (``count_ops`` of the
    residuals and slow flow, ``len(srepr)`` of residuals, slow flow and waveform) and the
    peak resident memory of the process above its size after the imports.  Lindstedt-Poincare
    (``lp``) on the free undamped Duffing oscillator and multiple scales (``ms``) on the forced
    damped one at orders 1..4; modified Lindstedt-Poincare (``mlp``) on ``nsd`` (k = -0.5,
    mu = 0.05, F = 2) at orders 1..2.
``points``
    In this process: the amplitude-parametrised solver (single-harmonic balance of ``nsd``,
    compiled once by ``compile_response``; the solve alone is timed, median of 3) at 250,
    1000, 4000 and 16000 points, and exact continuation of the clearance oscillator (the
    cheapest exact problem of ``perturb bench``) at ``ds_max`` 0.04, 0.02, 0.01, 0.005
    (the output spacing; the number of points it gives is reported).

Each table ends with the fitted growth exponent ``p`` of ``time ~ x**p`` (least squares on
log-log over the rows) and, for orders, the mean factor per order.  Wall times are inflated
by the load of the machine (printed); CPU times are not.
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

import numpy as np

DERIVATIONS = {
    # method: (model, params, orders)
    "lp": ("duffing", {"mu": 0.0, "F": 0.0, "alpha": 1.0, "omega0": 1.0}, (1, 2, 3, 4)),
    "ms": ("duffing", {"mu": 0.1, "F": 0.5, "alpha": 1.0, "omega0": 1.0}, (1, 2, 3, 4)),
    "mlp": ("nsd", {"k": -0.5, "mu": 0.05, "F": 2.0}, (1, 2)),
}


def _child(method: str, order: int) -> None:
    """Run one derivation and print its measurements as one JSON line."""
    import sympy as sp

    from perturb.methods import METHODS
    from perturb.model.builtins import builtin_model

    model, params, _ = DERIVATIONS[method]
    osc = builtin_model(model, **params)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t, c = time.perf_counter(), time.process_time()
    approx = METHODS[method](osc, order=order)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    eqs = [*approx.residuals, *(approx.slow_flow or ())]
    ops = int(sum(sp.count_ops(e) for e in eqs))
    size = len(sp.srepr(eqs)) + len(sp.srepr(approx.waveform))
    print(
        json.dumps(
            {"wall": wall, "cpu": cpu, "ops": ops, "srepr": size, "mem_kb": peak - base},
        )
    )


def _last(x: list[float], y: list[float]) -> float:
    """Local exponent between the last two rows (where fixed overheads matter least)."""
    if len(x) < 2 or min(x[-2:]) <= 0 or min(y[-2:]) <= 0:
        return float("nan")
    return float(np.log(y[-1] / y[-2]) / np.log(x[-1] / x[-2]))


def _fit(x: list[float], y: list[float]) -> float:
    """Slope of log y against log x (NaN with fewer than two usable rows)."""
    xs, ys = np.asarray(x, float), np.asarray(y, float)
    ok = (xs > 0) & (ys > 0) & np.isfinite(ys)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(xs[ok]), np.log(ys[ok]), 1)[0])


def orders(max_order: int, timeout: float) -> None:
    print("== expansion order (fresh process per derivation, PERTURB_CACHE=0)")
    print(
        f"{'method':>6} {'model':>8} {'order':>5} {'wall [s]':>9} {'CPU [s]':>8} "
        f"{'count_ops':>10} {'len(srepr)':>11} {'peak mem [MB]':>14}"
    )
    env = {**os.environ, "PERTURB_CACHE": "0", "PERTURB_PROGRESS": "0"}
    for method, (model, _, ords) in DERIVATIONS.items():
        xs, cpus, ops = [], [], []
        for order in ords:
            if order > max_order:
                continue
            try:
                done = subprocess.run(
                    [sys.executable, __file__, "--child", method, str(order)],
                    capture_output=True,
                    text=True,
                    timeout=timeout,
                    env=env,
                    check=False,
                )
            except subprocess.TimeoutExpired:
                print(f"{method:>6} {model:>8} {order:>5}  timeout after {timeout:g} s")
                break
            lines = done.stdout.strip().splitlines()
            if done.returncode != 0 or not lines:
                err = (done.stderr.strip().splitlines() or ["?"])[-1]
                print(f"{method:>6} {model:>8} {order:>5}  failed: {err[:100]}")
                continue
            m = json.loads(lines[-1])
            xs.append(order)
            cpus.append(m["cpu"])
            ops.append(m["ops"])
            print(
                f"{method:>6} {model:>8} {order:>5} {m['wall']:>9.3g} {m['cpu']:>8.3g} "
                f"{m['ops']:>10} {m['srepr']:>11} {m['mem_kb'] / 1024:>14.1f}",
                flush=True,
            )
        if len(xs) >= 2:
            factor = (cpus[-1] / cpus[0]) ** (1 / (xs[-1] - xs[0])) if cpus[0] > 0 else np.nan
            print(
                f"{'':>6} {method}: CPU time ~ order^{_fit(xs, cpus):.2f} (x{factor:.2f} per "
                f"order), count_ops ~ order^{_fit(xs, ops):.2f}"
            )


def _median_time(fn, repeat: int = 3) -> tuple[float, float, object]:
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    return statistics.median(walls), statistics.median(cpus), out


def points(exact_steps: list[float]) -> None:
    from perturb.methods import METHODS
    from perturb.model.builtins import builtin_model
    from perturb.numeric.amplitude import approximation_response, compile_response
    from perturb.simulate.exact_response import exact_frequency_response

    os.environ["PERTURB_PROGRESS"] = "0"
    print("== number of points: amplitude-parametrised hb1 of nsd k = -0.5, Omega 0.2..2.5")
    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    t = time.perf_counter()
    solver = compile_response(METHODS["hb1"](osc))
    print(f"   derive + compile once: {time.perf_counter() - t:.3g} s wall")
    print(f"{'points':>7} {'output pts':>10} {'wall [s]':>9} {'CPU [s]':>8}")
    ns, cs = [], []
    for n in (250, 1000, 4000, 16000):
        w, c, r = _median_time(lambda n=n: approximation_response(solver, (0.2, 2.5), points=n))
        out = sum(len(b) for b in r.branches)
        ns.append(n)
        cs.append(c)
        print(f"{n:>7} {out:>10} {w:>9.3g} {c:>8.3g}", flush=True)
    print(f"   CPU time ~ points^{_fit(ns, cs):.2f} (last step: ^{_last(ns, cs):.2f})")

    print("== number of points: exact continuation of clearance (r 10, d 0.5), Omega 0.5..1.6")
    osc = builtin_model("clearance", r=10.0, d=0.5, mu=0.02, F=0.3)
    print(f"{'ds_max':>7} {'output pts':>10} {'wall [s]':>9} {'CPU [s]':>8}")
    pts, cs = [], []
    for ds in exact_steps:
        w, c, r = _median_time(
            lambda ds=ds: exact_frequency_response(osc, (0.5, 1.6), ds_max=ds), repeat=1
        )
        out = sum(len(b) for b in r.branches)
        pts.append(out)
        cs.append(c)
        print(f"{ds:>7g} {out:>10} {w:>9.3g} {c:>8.3g}", flush=True)
    print(f"   CPU time ~ points^{_fit(pts, cs):.2f} (last step: ^{_last(pts, cs):.2f})")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--child", nargs=2, metavar=("METHOD", "ORDER"), help=argparse.SUPPRESS)
    p.add_argument("--only", choices=("orders", "points"), help="run one part")
    p.add_argument("--max-order", type=int, default=4, help="highest order (default 4)")
    p.add_argument(
        "--timeout", type=float, default=600.0, help="seconds per derivation (default 600)"
    )
    p.add_argument(
        "--exact-steps",
        default="0.04,0.02,0.01,0.005",
        help="ds_max values of the exact continuation (default 0.04,0.02,0.01,0.005)",
    )
    a = p.parse_args(argv)
    if a.child:
        _child(a.child[0], int(a.child[1]))
        return 0
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    if a.only in (None, "orders"):
        orders(a.max_order, a.timeout)
    if a.only in (None, "points"):
        points([float(s) for s in a.exact_steps.split(",")])
    print(f"load average {os.getloadavg()[0]:.1f} at the end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
