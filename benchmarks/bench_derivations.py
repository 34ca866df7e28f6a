"""Benchmark: cold and warm (cached) derivation time of the symbolic engines.

Every case runs in a fresh ``python`` process, because SymPy's in-process caches would
otherwise make every run after the first a warm one.  Inside the child the imports of
``perturb``, the engines and the cache are timed on their own and excluded; the derivation is
:func:`perturb.io.cache.cached_derivation` (what ``perturb derive`` and scenes call) with
``PERTURB_CACHE_DIR`` pointing at a temporary folder:

- *cold*: the folder is empty, so the time is derivation + writing the entry.  Repeated in
  ``--repeat`` fresh processes, each with its own empty folder; the median is reported, and
  ``derive`` is the engine's share of it (the entry's serialisation is the rest).
- *warm*: more fresh processes reading the entry the last cold run wrote.  The child checks
  that the entry was a hit (the engine is never called) and that the rebuilt approximation
  serialises to the same text as the cold one.

Sizes are ``sympy.count_ops`` of the residuals (summed) and of the waveform, measured after
the timing.  The machine is usually shared, so the load average is printed with the table and
the child's CPU time (``time.process_time``) is reported next to the wall clock: a target met
in CPU time but missed on the wall clock was missed for want of a free core.

Run from the repository root::

    python benchmarks/bench_derivations.py                       # all cases, 3 cold runs each
    python benchmarks/bench_derivations.py --only ms- --repeat 5
    python benchmarks/bench_derivations.py --out out/bench_derivations.csv
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

DUFFING_FREE = "x'' + omega0**2*x + eps*alpha*x**3 = 0"
DUFFING_FORCED = "x'' + 2*eps*mu*x' + omega0**2*x + eps*alpha*x**3 = eps*k*cos(Omega*t)"


@dataclass(frozen=True)
class Case:
    name: str
    method: str  # short name in perturb.methods.METHODS
    model: tuple  # ("builtin", name, {params}) or ("parse", equation text)
    options: dict = field(default_factory=dict)
    target: float | None = None  # cold seconds


def _cases() -> list[Case]:
    lp_duffing = ("builtin", "duffing", {"mu": 0, "F": 0})
    cases = [
        Case(f"lp-duffing-{n}", "lp", lp_duffing, {"order": n}, 0.5 if n == 4 else None)
        for n in (1, 2, 3, 4)
    ]
    cases += [Case(f"mlp-duffing-{n}", "mlp", lp_duffing, {"order": n}) for n in (1, 2, 3)]
    cases += [
        Case(f"mlp-duffing-forced-{n}", "mlp", ("builtin", "duffing", {}), {"order": n})
        for n in (1, 2, 3)
    ]
    cases += [
        Case("mlp-nsd-1", "mlp", ("builtin", "nsd", {}), {"order": 1}, 1.0),
        Case("mlp-nsd-2", "mlp", ("builtin", "nsd", {}), {"order": 2}, 10.0),
    ]
    free, forced = ("parse", DUFFING_FREE), ("parse", DUFFING_FORCED)
    cases += [
        Case(f"ms-duffing-{n}", "ms", free, {"order": n, "epsilon": "eps"}) for n in (1, 2, 3, 4)
    ]
    cases += [
        Case(
            f"ms-duffing-forced-{n}",
            "ms",
            forced,
            {"order": n, "epsilon": "eps"},
            1.5 if n == 4 else None,
        )
        for n in (1, 2, 3, 4)
    ]
    cases += [
        Case(
            f"ms-vanderpol-{n}",
            "ms",
            ("builtin", "vanderpol", {}),
            {"order": n, "epsilon": "eps"},
            1.0 if n == 2 else None,
        )
        for n in (1, 2)
    ]
    cases.append(Case("ms-nsd-1", "ms", ("builtin", "nsd", {}), {"order": 1}))
    for method in ("kb", "vdp"):
        for model in ("duffing", "vanderpol", "nsd"):
            cases.append(Case(f"{method}-{model}", method, ("builtin", model, {})))
    cases += [
        Case("hb-duffing-1", "shb", ("builtin", "duffing", {}), {"harmonics": (1,)}),
        Case("hb-duffing-1,3", "shb", ("builtin", "duffing", {}), {"harmonics": (1, 3)}),
        Case("hb-nsd-bias", "shb", ("builtin", "nsd", {}), {"bias": True}),
    ]
    return cases


WARM_TARGET_MS = 50.0

# The child: imports timed apart, then one cached derivation; one JSON line on stdout.
_CHILD = textwrap.dedent(
    """
    import functools, hashlib, json, sys, time
    t0 = time.perf_counter()
    import sympy as sp
    from perturb import builtin_model
    from perturb.model.oscillator import Oscillator
    from perturb.methods import METHODS
    from perturb.io.cache import cached_derivation
    from perturb.io.serialize import approximation_to_dict
    t1 = time.perf_counter()
    case = json.loads(sys.argv[1])
    kind, *spec = case["model"]
    osc = builtin_model(spec[0], **spec[1]) if kind == "builtin" else Oscillator.parse(spec[0])
    options = {k: tuple(v) if isinstance(v, list) else v for k, v in case["options"].items()}
    engine = METHODS[case["method"]]
    spent = []

    # wraps() keeps __module__, so the cache key (which hashes the engine's source) is unchanged
    @functools.wraps(engine)
    def timed(*args, **kwargs):
        s = time.perf_counter()
        out = engine(*args, **kwargs)
        spent.append(time.perf_counter() - s)
        return out

    t2, c2 = time.perf_counter(), time.process_time()
    approx = cached_derivation(case["method"], timed, osc, **options)
    t3, c3 = time.perf_counter(), time.process_time()
    # srepr of every field, and options by repr (JSON would not tell a tuple from a list)
    text = json.dumps(approximation_to_dict(approx), sort_keys=True, default=repr)
    text += repr(sorted(approx.options.items()))
    out = {
        "import": t1 - t0,
        "total": t3 - t2,
        "cpu": c3 - c2,
        "derive": spent[0] if spent else None,
        "digest": hashlib.sha256(text.encode()).hexdigest(),
    }
    if case["sizes"]:
        out["residual_ops"] = int(sum(sp.count_ops(r) for r in approx.residuals))
        out["waveform_ops"] = int(sp.count_ops(approx.waveform))
    print(json.dumps(out))
    """
)


def _run_child(case: Case, cache: str, sizes: bool = False) -> dict:
    env = dict(os.environ, PERTURB_CACHE_DIR=cache, PERTURB_CACHE="1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    payload = json.dumps(
        {"model": case.model, "method": case.method, "options": case.options, "sizes": sizes}
    )
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, payload],
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
        timeout=900,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"{case.name}: child failed\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def bench(case: Case, repeat: int, warm_repeat: int) -> dict:
    cold, cold_cpu, derive, imports = [], [], [], []
    with tempfile.TemporaryDirectory(prefix="perturb-bench-") as tmp:
        for i in range(repeat):
            cache = os.path.join(tmp, f"cold{i}")  # empty: a cold derivation
            r = _run_child(case, cache)
            if r["derive"] is None:
                raise RuntimeError(f"{case.name}: the empty cache answered without deriving")
            cold.append(r["total"])
            cold_cpu.append(r["cpu"])
            derive.append(r["derive"])
            imports.append(r["import"])
            digest = r["digest"]
        warm, warm_cpu, problems = [], [], set()
        for i in range(warm_repeat):
            r = _run_child(case, cache, sizes=i == 0)
            # reported, not raised: an entry that cannot be read back is a finding of the run
            if r["derive"] is not None:
                problems.add("cache miss")
            elif r["digest"] != digest:
                problems.add("cached result differs")
            warm.append(r["total"])
            warm_cpu.append(r["cpu"])
            if i == 0:
                ops = (r["residual_ops"], r["waveform_ops"])
    med = statistics.median
    cold_med, warm_ms = med(cold), 1e3 * med(warm)
    cpu_med, warm_cpu_ms = med(cold_cpu), 1e3 * med(warm_cpu)

    def within(cold_s: float, warm_ms: float) -> bool:
        return warm_ms <= WARM_TARGET_MS and (case.target is None or cold_s <= case.target)

    met = not problems and within(cold_med, warm_ms)
    # on a shared machine the wall clock also counts other processes' time slices
    cpu_note = (
        " (cpu time: yes)" if not problems and not met and within(cpu_med, warm_cpu_ms) else ""
    )
    return {
        "case": case.name,
        "method": case.method,
        "options": json.dumps(case.options),
        "cold_median_s": round(cold_med, 4),
        "cold_runs_s": " ".join(f"{t:.3f}" for t in cold),
        "cold_cpu_median_s": round(cpu_med, 4),
        "derive_median_s": round(med(derive), 4),
        "warm_median_ms": round(warm_ms, 2),
        "warm_cpu_median_ms": round(warm_cpu_ms, 2),
        "import_median_s": round(med(imports), 3),
        "residual_ops": ops[0],
        "waveform_ops": ops[1],
        "target": (f"cold <= {case.target:g} s, " if case.target else "")
        + f"warm <= {WARM_TARGET_MS:g} ms",
        "met": "yes" if met else "NO" + cpu_note + "".join(f" ({p})" for p in sorted(problems)),
    }


def _table(rows: list[dict]) -> str:
    head = (
        "| case | cold median (s) | cold cpu (s) | derive (s) | warm median (ms) | warm cpu (ms) "
        "| residual ops | waveform ops | target | met? |"
    )
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['cold_median_s']:.3f} | {r['cold_cpu_median_s']:.3f} "
            f"| {r['derive_median_s']:.3f} | {r['warm_median_ms']:.1f} "
            f"| {r['warm_cpu_median_ms']:.1f} | {r['residual_ops']} | {r['waveform_ops']} "
            f"| {r['target']} | {r['met']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="cold runs per case (median)")
    parser.add_argument("--warm", type=int, default=3, help="warm runs per case (median)")
    parser.add_argument("--only", action="append", help="run cases whose name contains this")
    parser.add_argument("--out", type=Path, help="also write the results as CSV here")
    args = parser.parse_args(argv)
    cases = [c for c in _cases() if not args.only or any(s in c.name for s in args.only)]
    if not cases:
        parser.error("no case matches --only")
    load_before = os.getloadavg()
    rows = []
    for case in cases:
        rows.append(bench(case, args.repeat, args.warm))
        print(
            f"{case.name}: cold {rows[-1]['cold_runs_s']} s, warm {rows[-1]['warm_median_ms']} ms",
            file=sys.stderr,
            flush=True,
        )
    load_after = os.getloadavg()
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cpus")
    print("load average (1, 5, 15 min): before " + ", ".join(f"{x:.2f}" for x in load_before))
    print("                              after  " + ", ".join(f"{x:.2f}" for x in load_after))
    imports = statistics.median(r["import_median_s"] for r in rows)
    print(
        f"cold: median of {args.repeat} fresh processes, warm: of {args.warm}; imports "
        f"(median {imports:.2f} s) excluded"
    )
    print()
    print(_table(rows))
    missed = [r["case"] for r in rows if r["met"] != "yes"]
    print()
    print("all targets met" if not missed else f"targets missed: {', '.join(missed)}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with args.out.open("w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
