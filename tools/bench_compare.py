"""Compare the speed of two perturb trees (e.g. before and after the package redesign).

::

    python tools/bench_compare.py --old /work/baseline --new /work/main [--quick] \\
        [--only startup,shooting] [--rounds 2] [--out benchmarks/results/bench_compare_X.md]

Every measurement is a fresh subprocess (``sys.executable``) with ``cwd=<tree>`` and
``PYTHONPATH=<tree>`` (and ``PERTURB_PROGRESS=0``), run interleaved: old, new, new, old, ...
so that both trees see the same load on a shared machine.  Each tree runs ITS OWN copy of each
benchmark script and its own CLI module: ``perturb/apps/cli.py`` if the tree has it (the
redesigned layout), else ``perturb/cli.py``.  The startup part checks that the module imported
really is the tree's (``perturb.__file__``).

Parts (``--only`` takes a comma-separated list of these names):

``startup``
    Wall time of fresh processes, best of 5 (``--quick``: 3) each, interleaved:
    ``python -c pass`` (the interpreter's floor), ``python -c "import <cli module>"``,
    ``python -m <cli module> --version``, ``--help``, ``models``.  Then one untimed
    ``python -X importtime`` run of each that reports whether sympy, scipy.integrate, matplotlib
    (and numpy, scipy, xarray) got imported.
``continuation``
    ``benchmarks/bench_continuation.py`` (``--bf-stride 10``; quick: ``--bf-stride 200``, the
    brute-force sweep on 2 frequencies): wall and CPU of every run row, calibration.
``frequency_response``
    ``benchmarks/bench_frequency_response.py --repeat 7`` (quick: 3): wall median / min and CPU
    median of every variant row, derive and compile times.
``numeric_hb``
    ``benchmarks/bench_numeric_harmonic_balance.py --repeat 7`` (quick: ``--repeat 3
    --no-table``): wall median / min, CPU median per variant.
``shooting``
    ``benchmarks/bench_shooting.py --repeat 30`` (quick: 20, the script's minimum): wall median
    / min, CPU median per variant, cost of one period with sensitivity.
``perturb_bench``
    ``<cli module> bench --fast`` into a temporary ``--out`` (never into the tree); quick:
    ``--problems nsd_k2 --methods exact,mlp1,hb-exact-H15``.  The per-row ``time_s`` of its
    ``work_precision.csv`` and the process wall time.  The full ``--fast`` run over every
    problem and method costs about 1.5-2 min per tree on an idle 2-core machine (measured
    on the baseline), so it is run once per round like the others.

Every subprocess also gives its own wall time (quantity ``process wall``).  With ``--rounds N``
each benchmark runs N times per tree (order alternating) and the minimum of each quantity is
reported.  The Markdown table has: benchmark, quantity, old, new, ratio old/new (> 1: new is
faster) and ``SLOWER`` when the ratio is < 0.9 (``--flag-below``).  A script that fails in one
tree (e.g. an import the redesign moved) gives a ``failed`` row with the last line of its
stderr.  Nothing is written into either tree.

Noise: run with the same tree on both sides (``--old /work/baseline --new /work/baseline
--quick``) at a load average of ~3.4 on 2 cores, the ratios ranged 0.89-1.09: one false
``SLOWER`` (continuation, workers=2, whose pool competes with the other jobs for the cores).
For a verdict use ``--rounds 3`` (minimum per tree) and re-run a flagged part alone
(``--only continuation``).  The ``sweep`` rows of ``perturb bench`` are extrapolated by that
command from a few frequencies.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

PARTS = (
    "startup",
    "continuation",
    "frequency_response",
    "numeric_hb",
    "shooting",
    "perturb_bench",
)

HEAVY = ("sympy", "scipy.integrate", "matplotlib", "numpy", "scipy", "xarray")


def cli_module(tree: Path) -> str:
    if (tree / "perturb" / "apps" / "cli.py").exists():
        return "perturb.apps.cli"
    if (tree / "perturb" / "cli.py").exists():
        return "perturb.cli"
    raise SystemExit(f"{tree}: neither perturb/apps/cli.py nor perturb/cli.py")


def env_for(tree: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(tree)
    env["PERTURB_PROGRESS"] = "0"
    env.pop("PYTHONSTARTUP", None)
    return env


def run(
    tree: Path, args: list[str], timeout: float, extra_env: dict[str, str] | None = None
) -> tuple[float, subprocess.CompletedProcess]:
    env = env_for(tree)
    env.update(extra_env or {})
    t = time.perf_counter()
    p = subprocess.run(
        [sys.executable, *args],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    return time.perf_counter() - t, p


def _fail_text(p: subprocess.CompletedProcess) -> str:
    lines = [x for x in (p.stderr or "").strip().splitlines() if x.strip()]
    return f"failed (rc {p.returncode}): {lines[-1][:120] if lines else ''}"


# ---------------------------------------------------------------------------------------------
# parsers of the benchmark scripts' output: {quantity: seconds}
# ---------------------------------------------------------------------------------------------
_MS4 = re.compile(
    r"^(?P<ind>\s*)(?P<name>\S.*?)\s+(?P<a>[\d.]+)ms\s+(?P<b>[\d.]+)ms\s+(?P<c>[\d.]+)ms"
    r"\s+(?P<d>[\d.]+)ms"
)


def parse_ms_rows(text: str) -> dict[str, float]:
    """Rows ``name  wall-med wall-min CPU-med CPU-min`` in ms (frequency_response, shooting);
    indented rows are qualified by the last unindented one."""
    out: dict[str, float] = {}
    parent = ""
    for line in text.splitlines():
        m = _MS4.match(line)
        if not m:
            continue
        name = m["name"].strip()
        if m["ind"]:
            name = f"{parent} / {name}"
        else:
            parent = name
        out[f"{name}: wall median"] = float(m["a"]) / 1e3
        out[f"{name}: wall min"] = float(m["b"]) / 1e3
        out[f"{name}: CPU median"] = float(m["c"]) / 1e3
    return out


def parse_frequency_response(text: str) -> dict[str, float]:
    out = parse_ms_rows(text)
    m = re.search(r"derive ([\d.]+) s, compile ([\d.]+) s", text)
    if m:
        out["derive (1 run)"] = float(m[1])
        out["compile (1 run)"] = float(m[2])
    return out


def parse_shooting(text: str) -> dict[str, float]:
    out = parse_ms_rows(text)
    m = re.search(r"one period with sensitivity ([\d.]+) ms median \(([\d.]+) ms min\)", text)
    if m:
        out["one period with sensitivity: median"] = float(m[1]) / 1e3
        out["one period with sensitivity: min"] = float(m[2]) / 1e3
    return out


def parse_numeric_hb(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    pat = re.compile(
        r"^(?P<name>\S.*?)\s+wall median\s+(?P<w>[\d.]+) s \(min\s+(?P<m>[\d.]+) s\),"
        r" CPU median\s+(?P<c>[\d.]+) s"
    )
    for line in text.splitlines():
        m = pat.match(line)
        if m:
            name = m["name"].strip()
            out[f"{name}: wall median"] = float(m["w"])
            out[f"{name}: wall min"] = float(m["m"])
            out[f"{name}: CPU median"] = float(m["c"])
    return out


def parse_continuation(text: str) -> dict[str, float]:
    out: dict[str, float] = {}
    pat = re.compile(
        r"^(?P<name>\S.*?|\s+extrapolated.*?)\s+(?P<w>[\d.]+) s\s+(?P<c>[\d.]+) s\s+\d"
    )
    for line in text.splitlines():
        m = pat.match(line)
        if m:
            name = " ".join(m["name"].split())
            out[f"{name}: wall"] = float(m["w"])
            out[f"{name}: CPU"] = float(m["c"])
    m = re.search(r"calibration: ([\d.]+) ms per exact propagation", text)
    if m:
        out["calibration (one exact period)"] = float(m[1]) / 1e3
    return out


def script_part(script: str, full: list[str], quick: list[str], parser):
    def fn(tree: Path, args: argparse.Namespace) -> tuple[dict[str, float], str]:
        flags = quick if args.quick else full
        wall, p = run(tree, [f"benchmarks/{script}", *flags], args.timeout)
        if p.returncode != 0:
            return {"process wall": wall}, _fail_text(p)
        out = parser(p.stdout)
        out["process wall"] = wall
        return out, "" if len(out) > 1 else "output not parsed"

    return fn


def perturb_bench(tree: Path, args: argparse.Namespace) -> tuple[dict[str, float], str]:
    mod = cli_module(tree)
    flags = ["--fast"]
    if args.quick:
        flags += ["--problems", "nsd_k2", "--methods", "exact,mlp1,hb-exact-H15"]
    with tempfile.TemporaryDirectory(prefix="bench_compare_") as tmp:
        wall, p = run(tree, ["-m", mod, "bench", *flags, "--out", tmp], args.timeout)
        if p.returncode != 0:
            return {"process wall": wall}, _fail_text(p)
        out: dict[str, float] = {}
        path = Path(tmp) / "work_precision.csv"
        if path.exists():
            with path.open() as fh:
                for row in csv.DictReader(fh):
                    try:
                        t = float(row["time_s"])
                    except (KeyError, ValueError):
                        continue
                    if math.isfinite(t) and row.get("status", "ok") == "ok":
                        out[f"{row['problem']} {row['method']}: time"] = t
    out["process wall"] = wall
    return out, "" if len(out) > 1 else "no work_precision.csv rows"


BENCHES = {
    "continuation": script_part(
        "bench_continuation.py", ["--bf-stride", "10"], ["--bf-stride", "200"], parse_continuation
    ),
    "frequency_response": script_part(
        "bench_frequency_response.py",
        ["--repeat", "7"],
        ["--repeat", "3"],
        parse_frequency_response,
    ),
    "numeric_hb": script_part(
        "bench_numeric_harmonic_balance.py",
        ["--repeat", "7"],
        ["--repeat", "3", "--no-table"],
        parse_numeric_hb,
    ),
    "shooting": script_part(
        "bench_shooting.py", ["--repeat", "30"], ["--repeat", "20"], parse_shooting
    ),
    "perturb_bench": perturb_bench,
}


# ---------------------------------------------------------------------------------------------
# start-up
# ---------------------------------------------------------------------------------------------
def startup_commands(tree: Path) -> list[tuple[str, list[str]]]:
    mod = cli_module(tree)
    return [
        ("python -c pass (interpreter floor)", ["-c", "pass"]),
        ("import <cli>", ["-c", f"import {mod}"]),
        ("<cli> --version", ["-m", mod, "--version"]),
        ("<cli> --help", ["-m", mod, "--help"]),
        ("<cli> models", ["-m", mod, "models"]),
    ]


def imported_modules(tree: Path, argv: list[str], timeout: float) -> tuple[set[str], str]:
    """Top-level-or-dotted module names imported by ``python -X importtime <argv>``."""
    _, p = run(tree, ["-X", "importtime", *argv], timeout)
    names = set()
    for line in p.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            names.add(line.rsplit("|", 1)[1].strip())
    return names, "" if p.returncode == 0 else _fail_text(p)


def startup(old: Path, new: Path, args: argparse.Namespace) -> list[dict[str, Any]]:
    n = 3 if args.quick else 5
    rows = []
    # which perturb each tree imports (the PYTHONPATH must win over any installed copy)
    where = {}
    for label, tree in (("old", old), ("new", new)):
        _, p = run(tree, ["-c", "import perturb; print(perturb.__file__)"], args.timeout)
        where[label] = p.stdout.strip()
        if not where[label].startswith(str(tree.resolve())) and not where[label].startswith(
            str(tree)
        ):
            print(f"WARNING: {label} tree {tree} imports perturb from {where[label]}")
    oc, nc = startup_commands(old), startup_commands(new)
    best: dict[tuple[str, str], float] = {}
    errors: dict[tuple[str, str], str] = {}
    for i in range(n):
        pairs = [("old", old, oc), ("new", new, nc)]
        if i % 2:
            pairs.reverse()
        for (name, _), j in zip(oc, range(len(oc)), strict=True):
            for label, tree, cmds in pairs:
                wall, p = run(tree, cmds[j][1], args.timeout)
                if p.returncode != 0:
                    errors[(name, label)] = _fail_text(p)
                key = (name, label)
                best[key] = min(best.get(key, math.inf), wall)
    for name, _ in oc:
        rows.append(
            {
                "bench": "startup",
                "quantity": f"{name}: best of {n}",
                "old": best[(name, "old")],
                "new": best[(name, "new")],
                "note": "; ".join(
                    f"{lab}: {errors[(name, lab)]}"
                    for lab in ("old", "new")
                    if (name, lab) in errors
                ),
            }
        )
    for j, (name, _) in enumerate(oc[1:], start=1):
        got = {}
        for label, tree, cmds in (("old", old, oc), ("new", new, nc)):
            got[label], _err = imported_modules(tree, cmds[j][1], args.timeout)
        o = [m for m in HEAVY if m in got["old"]]
        w = [m for m in HEAVY if m in got["new"]]
        added = [m for m in w if m not in o]
        dropped = [m for m in o if m not in w]
        note = "; ".join(
            x
            for x in (
                f"NEW IMPORT: {', '.join(added)}" if added else "",
                f"no longer imported: {', '.join(dropped)}" if dropped else "",
            )
            if x
        )
        rows.append(
            {
                "bench": "startup imports",
                "quantity": f"{name}: which of {', '.join(HEAVY)} got imported",
                "old": ", ".join(o) or "none",
                "new": ", ".join(w) or "none",
                "note": note,
            }
        )
    rows.append(
        {
            "bench": "startup",
            "quantity": "perturb imported from",
            "old": where["old"],
            "new": where["new"],
            "note": f"cli: {cli_module(old)} / {cli_module(new)}",
        }
    )
    return rows


def benchmarks(name: str, old: Path, new: Path, args: argparse.Namespace) -> list[dict[str, Any]]:
    fn = BENCHES[name]
    vals: dict[str, dict[str, float]] = {"old": {}, "new": {}}
    notes: dict[str, str] = {}
    for r in range(args.rounds):
        order = [("old", old), ("new", new)]
        if r % 2:
            order.reverse()
        for label, tree in order:
            print(
                f"  {name} [{label}] round {r + 1}/{args.rounds} ...", file=sys.stderr, flush=True
            )
            try:
                got, note = fn(tree, args)
            except subprocess.TimeoutExpired:
                got, note = {}, f"timeout after {args.timeout:g} s"
            if note:
                notes[label] = note
            for k, v in got.items():
                vals[label][k] = min(vals[label].get(k, math.inf), v)
    rows = []
    keys = list(dict.fromkeys([*vals["old"], *vals["new"]]))
    for k in keys:
        rows.append(
            {
                "bench": name,
                "quantity": k,
                "old": vals["old"].get(k, math.nan),
                "new": vals["new"].get(k, math.nan),
                "note": "",
            }
        )
    for label, note in notes.items():
        rows.append({"bench": name, "quantity": f"{label} run", "old": "", "new": "", "note": note})
    return rows


def fmt_time(x: Any) -> str:
    if isinstance(x, str):
        return x
    if x is None or not math.isfinite(x):
        return "–"
    if x < 1.0:
        return f"{x * 1e3:.3g} ms"
    return f"{x:.3g} s"


def table(rows: list[dict[str, Any]], flag_below: float) -> str:
    lines = [
        "| benchmark | quantity | old | new | ratio old/new | flag |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        o, n = r["old"], r["new"]
        ratio, flag = "", r.get("note", "")
        if isinstance(o, float) and isinstance(n, float) and math.isfinite(o) and math.isfinite(n):
            q = o / n if n > 0 else math.nan
            ratio = f"{q:.2f}"
            if q < flag_below:
                flag = ("SLOWER " + flag).strip()
        cells = [r["bench"], r["quantity"], fmt_time(o), fmt_time(n), ratio, flag]
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, type=Path)
    ap.add_argument("--new", required=True, type=Path)
    ap.add_argument("--only", help=f"comma-separated parts: {', '.join(PARTS)} (default all)")
    ap.add_argument("--quick", action="store_true", help="fewer repeats, smaller workloads")
    ap.add_argument("--rounds", type=int, default=1, help="runs per benchmark and tree (min)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per subprocess")
    ap.add_argument("--flag-below", type=float, default=0.9, help="flag ratios below this")
    ap.add_argument("--out", help="also write the Markdown report here")
    args = ap.parse_args(argv)
    parts = [p.strip() for p in args.only.split(",")] if args.only else list(PARTS)
    bad = [p for p in parts if p not in PARTS]
    if bad:
        ap.error(f"unknown part(s) {bad}; expected {', '.join(PARTS)}")
    old, new = args.old.resolve(), args.new.resolve()
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    for part in parts:
        print(f"{part} ...", file=sys.stderr, flush=True)
        if part == "startup":
            rows += startup(old, new, args)
        else:
            rows += benchmarks(part, old, new, args)
    load1 = os.getloadavg()
    head = (
        f"# bench_compare: old {old} vs new {new}\n\n"
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; python "
        f"{platform.python_version()} ({sys.executable}); {os.cpu_count()} cores; load average "
        f"{load0[0]:.2f} at the start, {load1[0]:.2f} at the end; "
        f"{'--quick' if args.quick else 'full'}, {args.rounds} round(s), parts "
        f"{', '.join(parts)}; {time.perf_counter() - t0:.0f} s in all.  Times: minimum over "
        "rounds (start-up: best of the runs); ratio old/new > 1 means the new tree is faster; "
        f"SLOWER: ratio < {args.flag_below:g}.\n"
    )
    text = head + "\n" + table(rows, args.flag_below) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
