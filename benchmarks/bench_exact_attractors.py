"""Benchmark: the cost of the attractor stage of the exact frequency response
(:mod:`perturb.simulate.exact_response.attractors`, option ``attractors``).

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_exact_attractors.py [--repeat 2] [--only nsd_k-3]

Per case (the ``exact`` cases of ``tools/regression_set.py`` — the bench problems and windows
— plus nsd k = -0.5 over (0.3, 2) and the 2-coordinate ``nsd2`` over (0.5, 2)):
``exact_branches(model, window, workers=1, progress=False)`` with ``attractors=False`` and
``attractors=True``, interleaved in the same process, CPU time by ``time.process_time``
(minimum over ``--repeat`` runs; one warm-up call first), the branch counts, the CPU ratio, and
the CPU spent inside the scan itself (:func:`attractor_states`, the simulation) — the rest of
the difference is Newton on the settled states and the tracing of the new branches.  The
machine is shared: the load average is printed.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import fnmatch
import time

from perturb import builtin_model
from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import attractors as attractor_module
from perturb.simulate.exact_response import exact_branches

CASES = (
    ("nsd_k-0.5", "nsd", {"k": -0.5, "mu": 0.05, "F": 2.0}, (0.2, 2.5)),
    ("nsd_k-0.5_w0.3", "nsd", {"k": -0.5, "mu": 0.05, "F": 2.0}, (0.3, 2.0)),
    ("nsd_k-3", "nsd", {"k": -3.0, "mu": 0.05, "F": 2.0}, (0.2, 2.5)),
    ("nsd_k2", "nsd", {"k": 2.0, "mu": 0.05, "F": 2.0}, (0.2, 2.5)),
    ("duffing", "duffing", {"alpha": 1.0, "mu": 0.1, "F": 0.5, "omega0": 1.0}, (0.5, 2.5)),
    ("clearance", "clearance", {"r": 10.0, "d": 0.5, "mu": 0.02, "F": 0.3}, (0.5, 1.6)),
    ("deadzone", "deadzone", {}, (0.2, 2.0)),
    ("nsd2", "nsd2", None, (0.5, 2.0)),
)


def _model(name: str, params: dict | None):
    return builtin_system(name) if params is None else builtin_model(name, **params)


def _scan_timer() -> dict:
    """Wrap attractor_states to add its CPU time to the returned dict."""
    spent = {"cpu": 0.0}
    inner = attractor_module.attractor_states

    def timed(*args, **kwargs):
        t = time.process_time()
        try:
            return inner(*args, **kwargs)
        finally:
            spent["cpu"] += time.process_time() - t

    attractor_module.attractor_states = timed
    return spent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--only", default="*", help="fnmatch pattern of case names")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()}")
    spent = _scan_timer()
    exact_branches(builtin_model("nsd", k=-0.5), (0.9, 1.1), progress=False, workers=1)
    rows = []
    for case, name, params, window in CASES:
        if not fnmatch.fnmatch(case, args.only):
            continue
        model = _model(name, params)
        best = {False: float("inf"), True: float("inf")}
        count = {}
        scan = float("inf")
        for _ in range(max(1, args.repeat)):
            for on in (False, True):
                spent["cpu"] = 0.0
                t = time.process_time()
                res = exact_branches(model, window, progress=False, workers=1, attractors=on)
                best[on] = min(best[on], time.process_time() - t)
                count[on] = len(res.branches)
                if on:
                    scan = min(scan, spent["cpu"])
        rows.append((case, window, best[False], best[True], scan, count[False], count[True]))
        print(
            f"{case:16s} {str(window):12s} CPU off {best[False]:6.2f} s  on {best[True]:6.2f} s"
            f"  ratio {best[True] / best[False]:5.2f}  scan {scan:5.2f} s"
            f"  branches {count[False]} -> {count[True]}",
            flush=True,
        )
    print(f"load average {os.getloadavg()}")


if __name__ == "__main__":
    main()
