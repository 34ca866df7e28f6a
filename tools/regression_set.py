"""Behaviour regression set: record frequency responses with one tree, compare with another.

Only the public top-level API is used (``perturb.builtin_model``, ``perturb.frequency_response``
and the returned ``Response`` / ``Branch`` objects), so the same script runs against the code
before and after the package redesign; the tree is chosen by ``PYTHONPATH``::

    PYTHONPATH=/work/baseline python tools/regression_set.py record \\
        --out benchmarks/results/regression_baseline.json
    PYTHONPATH=/work/main python tools/regression_set.py compare \\
        --baseline benchmarks/results/regression_baseline.json

Cases (problems and windows of ``perturb/bench.py``, the work-precision benchmark; ``deadzone``
is not among them and uses its builtin defaults over ``(0.2, 2.0)``, the default window of
``frequency_response``): ``exact`` and ``hb`` (15 harmonics, every branch) of ``nsd`` with
k = -0.5, -3, 2, ``duffing``, ``clearance`` and ``deadzone``, plus ``mlp`` (order 1), ``ms``
(order 1) and ``kb`` (first order, takes no ``order``) of each.  A method that refuses a model
(a ``perturb.PerturbError``) is recorded as ``refused`` with its message; any other exception as
``error``.  ``--only`` selects cases by fnmatch pattern (``'nsd_k-3/*'``, ``'*/exact'``).

Recorded per response: the count of branches; per branch the number of points, omega min/max,
the full ``omega`` and ``amplitude`` arrays (JSON numbers are Python's shortest round-trip
``repr``: exact doubles, nothing rounded), every point of ``first_harmonic_amplitude``,
``mean`` and ``max_multiplier`` at 9 significant digits (see below), and the ``stable``
labels run-length encoded (``[["S", 12], ["U", 40], ...]``); the response's ``method``,
``model``, ``params``, ``folds`` (Omega, amplitude) and ``notes``; and the wall time of the
call (informational, never compared).  The public ``Response`` has no branch-point field:
``hb`` responses name theirs only in a note (``branch points at Omega = 0.483525
(A=10.4392), ...``, 6 significant digits), parsed into ``branch_points``; the exact solver
finds them (``special_points`` of its internal branches) but its ``to_response`` keeps only
the folds, so exact cases have no branch points on record.

Size: with all five columns as exact doubles the set was 5.1 MB (about 63,000 points).  Every
point is kept (no subsampling, so point counts and labels stay exact), but the three columns
that are only reported, never tested against the tolerances, are stored at float32 round-trip
precision (9 significant digits; both sides of a comparison are rounded the same way, so
equal doubles still compare equal): 4.1 MB.  The record command prints the size.

``compare`` prints one row per case: status, identical structure (branch count, point counts,
stability labels, fold count, branch points of the notes), max relative |Δ amplitude| and
|Δ omega| (branches matched by order; if the branch counts or a branch's point count differ,
each branch is matched to the nearest baseline curve and its points are measured by their
relative distance to that curve's polyline), max |Δ fold Omega| and whether the notes are
equal.  It exits 1 when a status or the structure differs or a Δ exceeds ``--amp-tol``
(relative, on amplitude and omega; default 1e-9) or ``--fold-tol`` (absolute, on fold Omega;
default 1e-9); different notes only exit 1 with ``--strict-notes`` (their wording may change
in a redesign).  ``--current FILE`` compares two recordings without running anything.

``compare --curves`` is for a change that moves points by rounding (a merged corrector: same
curves, points shifted along them): instead of point-by-point differences it requires the same
branch count, the same order of stability labels (run lengths may differ), the same fold count
with fold Omega within ``--fold-tol`` by order, the same branch points (within the 6-digit
note text), and measures the amplitude of every baseline point two points or more away from a
turning point of its monotone-Omega run against the new branch's run interpolated at its
Omega (cubic through the 4 nearest points) to ``--amp-tol``.  With ``--orbits FILE`` (written
by the ``orbits`` command run against the baseline tree) the exact cases also compare the
polished exact orbits at 6 fixed frequencies per problem (``frequency_response(osc, "exact",
frequencies=[...])``, every solution, sorted) to ``--orbit-tol`` (default 1e-10, relative to
each orbit's amplitude)::

    PYTHONPATH=/work/baseline python tools/regression_set.py orbits \
        --out benchmarks/results/regression_orbits.json
    python tools/regression_set.py compare --curves \
        --baseline benchmarks/results/regression_baseline.json \
        --orbits benchmarks/results/regression_orbits.json

The interpolation certifies ``--amp-tol`` 1e-9 only while the new points lie within rounding of
the old ones (a query at a sample point is exact); a genuinely resampled curve shows the
interpolation error instead (measured: 1.5e-3 on duffing/exact traced with ``ds_max``
0.00499 instead of 0.005, near the folds), and the branch order may change with the tracing
history (nsd_k-3/exact, same run): there the polished orbits are the accurate comparison.

Environment: ``PERTURB_CACHE=0`` (each run derives its approximation, so times compare and the
on-disk derivation cache cannot mask a change) and ``PERTURB_PROGRESS=0`` are set unless given.
The exact solver traces with its default worker pool (two processes); its documentation
promises the serial branches whatever the timing, which the record-vs-record comparison tests
(``--exact-workers 1`` forces serial tracing if it ever does not hold).
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import platform
import re
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PERTURB_CACHE", "0")
os.environ.setdefault("PERTURB_PROGRESS", "0")

import numpy as np  # noqa: E402

FORMAT = "perturb-regression-set/1"

#: (name, builtin model, parameters, window): the forced problems of perturb/bench.py + deadzone
PROBLEMS: tuple[tuple[str, str, dict[str, float], tuple[float, float]], ...] = (
    ("nsd_k-0.5", "nsd", {"k": -0.5, "mu": 0.05, "F": 2.0}, (0.2, 2.5)),
    ("nsd_k-3", "nsd", {"k": -3.0, "mu": 0.05, "F": 2.0}, (0.2, 2.5)),
    ("nsd_k2", "nsd", {"k": 2.0, "mu": 0.05, "F": 2.0}, (0.2, 2.5)),
    ("duffing", "duffing", {"alpha": 1.0, "mu": 0.1, "F": 0.5, "omega0": 1.0}, (0.5, 2.5)),
    ("clearance", "clearance", {"r": 10.0, "d": 0.5, "mu": 0.02, "F": 0.3}, (0.5, 1.6)),
    ("deadzone", "deadzone", {}, (0.2, 2.0)),
)

#: (method label, method, keyword arguments of frequency_response)
METHODS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("exact", "exact", {}),
    ("hb", "hb", {"harmonics": 15}),
    ("mlp1", "mlp", {"order": 1}),
    ("ms1", "ms", {"order": 1}),
    ("kb", "kb", {}),
)

#: window fractions of the fixed frequencies of the polished exact orbits (``orbits`` command)
ORBIT_FRACTIONS = (0.07, 0.23, 0.41, 0.58, 0.77, 0.93)

FIELDS = ("omega", "amplitude", "first_harmonic_amplitude", "mean", "max_multiplier")
#: stored as exact doubles; the other FIELDS at 9 significant digits (float32 round trip)
EXACT_FIELDS = ("omega", "amplitude")


def cases(exact_workers: int | None = None) -> list[dict[str, Any]]:
    out = []
    for name, model, params, window in PROBLEMS:
        for label, method, kwargs in METHODS:
            kw = dict(kwargs)
            if method == "exact" and exact_workers is not None:
                kw["workers"] = exact_workers
            out.append(
                {
                    "id": f"{name}/{label}",
                    "model": model,
                    "params": params,
                    "window": list(window),
                    "method": method,
                    "kwargs": kw,
                }
            )
    return out


def _rle(stable: np.ndarray) -> list[list[Any]]:
    out: list[list[Any]] = []
    for s in stable:
        lab = "S" if bool(s) else "U"
        if out and out[-1][0] == lab:
            out[-1][1] += 1
        else:
            out.append([lab, 1])
    return out


def _floats(a: Any, full: bool = True) -> list[float]:
    if full:
        return [float(x) for x in np.asarray(a, dtype=float)]
    return [float(f"{x:.9g}") for x in np.asarray(a, dtype=float)]


_BP_NOTE = re.compile(r"branch points at Omega = (.*)")
_BP_ITEM = re.compile(r"([-+0-9.eE]+) \(A=([-+0-9.eE]+)\)")


def _branch_points(notes: Any) -> list[list[float]]:
    """(Omega, amplitude) of the branch points a note lists (hb responses), in note order."""
    out = []
    for note in notes:
        m = _BP_NOTE.search(str(note))
        if m:
            out += [[float(w), float(a)] for w, a in _BP_ITEM.findall(m.group(1))]
    return out


def record_response(resp: Any) -> dict[str, Any]:
    branches = []
    for b in resp.branches:
        n = len(b)
        entry: dict[str, Any] = {
            "points": n,
            "omega_min": float(np.min(b.omega)) if n else None,
            "omega_max": float(np.max(b.omega)) if n else None,
            "stable_rle": _rle(np.asarray(b.stable)),
        }
        for f in FIELDS:
            entry[f] = _floats(getattr(b, f), full=f in EXACT_FIELDS)
        branches.append(entry)
    return {
        "method": str(resp.method),
        "model": str(resp.model),
        "params": {str(k): float(v) for k, v in dict(resp.params).items()},
        "n_branches": len(resp.branches),
        "branches": branches,
        "folds": [[float(w), float(a)] for w, a in resp.folds],
        "branch_points": _branch_points(resp.notes),
        "notes": [str(s) for s in resp.notes],
        # anything else a redesigned Response might carry (branch points, ...), as text
        "extra_attributes": sorted(
            a
            for a in vars(resp)
            if a not in ("branches", "method", "model", "params", "folds", "notes")
        ),
    }


def run_case(case: dict[str, Any]) -> dict[str, Any]:
    import perturb

    out = {k: case[k] for k in ("id", "model", "params", "window", "method", "kwargs")}
    t0 = time.perf_counter()
    try:
        osc = perturb.builtin_model(case["model"], **case["params"])
        resp = perturb.frequency_response(
            osc, case["method"], tuple(case["window"]), **case["kwargs"]
        )
    except perturb.PerturbError as exc:
        out.update(status="refused", reason=f"{type(exc).__name__}: {exc}")
    except Exception as exc:  # noqa: BLE001 - recorded
        out.update(status="error", reason=f"{type(exc).__name__}: {exc}")
    else:
        out.update(status="ok", response=record_response(resp))
    out["wall_s"] = time.perf_counter() - t0
    return out


def cmd_record(args: argparse.Namespace) -> int:
    import perturb

    selected = [
        c for c in cases(args.exact_workers) if not args.only or fnmatch.fnmatch(c["id"], args.only)
    ]
    results = []
    t_all = time.perf_counter()
    for c in selected:
        r = run_case(c)
        results.append(r)
        extra = ""
        if r["status"] == "ok":
            resp = r["response"]
            extra = (
                f"{resp['n_branches']} branches, "
                f"{sum(b['points'] for b in resp['branches'])} points, {len(resp['folds'])} folds"
            )
        else:
            extra = r["reason"][:100]
        print(f"{c['id']:<22} {r['status']:<8} {r['wall_s']:8.2f} s  {extra}", flush=True)
    doc = {
        "format": FORMAT,
        "perturb_file": getattr(perturb, "__file__", ""),
        "perturb_version": getattr(perturb, "__version__", ""),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "total_wall_s": time.perf_counter() - t_all,
        "environment": {
            k: os.environ.get(k, "")
            for k in ("PERTURB_CACHE", "PERTURB_PROGRESS", "PERTURB_WORKERS")
        },
        "cases": results,
    }
    text = json.dumps(doc, indent=None, separators=(",", ":"))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(text + "\n")
    print(f"wrote {args.out}: {len(text) / 1e6:.2f} MB, {len(results)} cases")
    return 0


# ---------------------------------------------------------------------------------------------
# comparison
# ---------------------------------------------------------------------------------------------
def _rel(new: np.ndarray, old: np.ndarray) -> float:
    if new.size == 0:
        return 0.0
    d = np.abs(new - old) / np.maximum(np.abs(old), 1e-300)
    # exact zeros on both sides are no difference
    d[(new == old)] = 0.0
    return float(np.max(d))


def _curve_distance(w: np.ndarray, a: np.ndarray, bw: np.ndarray, ba: np.ndarray) -> np.ndarray:
    """Per point of (w, a): distance to the polyline (bw, ba) in the plane, each axis scaled by
    the baseline curve's magnitude (so the result is relative)."""
    sw = max(float(np.max(np.abs(bw))), 1e-300) if bw.size else 1.0
    sa = max(float(np.max(np.abs(ba))), 1e-300) if ba.size else 1.0
    p = np.column_stack([w / sw, a / sa])
    q = np.column_stack([bw / sw, ba / sa])
    if q.shape[0] == 0:
        return np.full(p.shape[0], math.inf)
    if q.shape[0] == 1:
        return np.linalg.norm(p - q[0], axis=1)
    best = np.full(p.shape[0], math.inf)
    for j in range(q.shape[0] - 1):
        s0, s1 = q[j], q[j + 1]
        d = s1 - s0
        dd = float(d @ d)
        t = np.zeros(p.shape[0]) if dd == 0 else np.clip((p - s0) @ d / dd, 0.0, 1.0)
        proj = s0 + t[:, None] * d
        best = np.minimum(best, np.linalg.norm(p - proj, axis=1))
    return best


#: a point whose largest multiplier is this close to 1 in both runs (a fold, a period
#: doubling, a branch point: exactly 1 there) may carry either stability label
UNIT_MULTIPLIER = 1e-9


def _expand(rle: list) -> list[str]:
    return [label for label, count in rle for _ in range(int(count))]


def _labels_differ_at_unit_multipliers(x: dict[str, Any], y: dict[str, Any]) -> bool:
    """Whether two branches' stability labels differ only at points whose largest multiplier
    is within UNIT_MULTIPLIER of 1 in both (a refined fold point: its label is rounding)."""
    a, b = _expand(x["stable_rle"]), _expand(y["stable_rle"])
    ma, mb = x.get("max_multiplier"), y.get("max_multiplier")
    if len(a) != len(b) or ma is None or mb is None or len(ma) != len(a) or len(mb) != len(b):
        return False
    return all(
        la == lb
        or (abs(float(pa) - 1.0) <= UNIT_MULTIPLIER and abs(float(pb) - 1.0) <= UNIT_MULTIPLIER)
        for la, lb, pa, pb in zip(a, b, ma, mb, strict=True)
    )


def compare_responses(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    ob, nb = old["branches"], new["branches"]
    problems = []
    if len(ob) != len(nb):
        problems.append(f"branches {len(ob)} -> {len(nb)}")
    counts_same = len(ob) == len(nb) and all(
        x["points"] == y["points"] for x, y in zip(ob, nb, strict=True)
    )
    if len(ob) == len(nb) and not counts_same:
        diffs = [
            f"#{i}: {x['points']}->{y['points']}"
            for i, (x, y) in enumerate(zip(ob, nb, strict=True))
            if x["points"] != y["points"]
        ]
        problems.append("points " + ", ".join(diffs[:4]) + (" ..." if len(diffs) > 4 else ""))
    if counts_same:
        bad = [
            i
            for i, (x, y) in enumerate(zip(ob, nb, strict=True))
            if x["stable_rle"] != y["stable_rle"] and not _labels_differ_at_unit_multipliers(x, y)
        ]
        if bad:
            problems.append(f"stability labels differ on branches {bad[:6]}")
    if len(old["folds"]) != len(new["folds"]):
        problems.append(f"folds {len(old['folds'])} -> {len(new['folds'])}")
    obp, nbp = old.get("branch_points", []), new.get("branch_points", [])
    if len(obp) != len(nbp):
        problems.append(f"branch points {len(obp)} -> {len(nbp)}")
    elif obp != nbp:
        problems.append("branch points moved (6-digit note text)")
    # amplitude / omega differences
    d_amp = d_om = d_other = 0.0
    mode = "by order"
    if counts_same:
        for x, y in zip(ob, nb, strict=True):
            d_amp = max(d_amp, _rel(np.array(y["amplitude"]), np.array(x["amplitude"])))
            d_om = max(d_om, _rel(np.array(y["omega"]), np.array(x["omega"])))
            for f in ("first_harmonic_amplitude", "mean", "max_multiplier"):
                if f in x and f in y:
                    d_other = max(d_other, _rel(np.array(y[f]), np.array(x[f])))
    else:
        mode = "nearest curve"
        d_om = math.nan
        d_other = math.nan
        for y in nb:
            yw, ya = np.array(y["omega"]), np.array(y["amplitude"])
            best = math.inf
            for x in ob:
                dist = _curve_distance(yw, ya, np.array(x["omega"]), np.array(x["amplitude"]))
                m = float(np.max(dist)) if dist.size else 0.0
                best = min(best, m)
            d_amp = max(d_amp, best)
        if not nb and ob:
            d_amp = math.inf
    # folds: by order when the counts agree, else each new fold to the nearest old one
    of, nf = np.array(old["folds"]).reshape(-1, 2), np.array(new["folds"]).reshape(-1, 2)
    if len(of) == len(nf):
        d_fold = float(np.max(np.abs(nf[:, 0] - of[:, 0]))) if len(of) else 0.0
    elif len(of) and len(nf):
        d_fold = float(np.max(np.min(np.abs(nf[:, 0][:, None] - of[:, 0][None, :]), axis=1)))
    else:
        d_fold = math.inf
    return {
        "structure_same": not problems,
        "problems": problems,
        "mode": mode,
        "d_amp": d_amp,
        "d_omega": d_om,
        "d_other": d_other,
        "d_fold": d_fold,
        "notes_same": old["notes"] == new["notes"],
    }


# ---------------------------------------------------------------------------------------------
# --curves: the same curves, sampled differently (a change that moves points by rounding)
# ---------------------------------------------------------------------------------------------
def orbit_frequencies(window: list[float]) -> list[float]:
    lo, hi = window
    return [round(lo + f * (hi - lo), 4) for f in ORBIT_FRACTIONS]


def run_orbits(case: dict[str, Any]) -> dict[str, Any]:
    """Every polished exact orbit at the case's fixed frequencies (``frequency_response(...,
    "exact", frequencies=...)``): per frequency the distinct solutions ``[amplitude, first
    harmonic, mean, stable]``, sorted by amplitude (the answer's grouping into branches
    follows the traced curve, so it is not compared)."""
    import perturb

    freqs = orbit_frequencies(case["window"])
    osc = perturb.builtin_model(case["model"], **case["params"])
    resp = perturb.frequency_response(
        osc, "exact", tuple(case["window"]), frequencies=freqs, **case["kwargs"]
    )
    out: dict[str, list[list[float]]] = {repr(w): [] for w in freqs}
    for b in resp.branches:
        cols = zip(b.omega, b.amplitude, b.first_harmonic_amplitude, b.mean, b.stable, strict=True)
        for w, a, a1, m, st in cols:
            row = [float(a), float(a1), float(m), float(bool(st))]
            rows = out[repr(min(freqs, key=lambda f, w=float(w): abs(f - w)))]
            if not any(row == r for r in rows):
                rows.append(row)
    for rows in out.values():
        # mirror pairs of an odd system share the amplitude to rounding: order them by the
        # amplitude's 8 digits, then the mean (its sign), so rounding cannot swap them
        rows.sort(key=lambda r: (float(f"{r[0]:.8g}"), r[2], r[1]))
    return {"id": case["id"], "frequencies": freqs, "orbits": out}


def cmd_orbits(args: argparse.Namespace) -> int:
    results = []
    for c in cases(args.exact_workers):
        if c["method"] != "exact" or (args.only and not fnmatch.fnmatch(c["id"], args.only)):
            continue
        t0 = time.perf_counter()
        r = run_orbits(c)
        results.append(r)
        n = sum(len(v) for v in r["orbits"].values())
        print(f"{c['id']:<22} {n:4d} orbits {time.perf_counter() - t0:8.2f} s", flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"format": FORMAT + "/orbits", "cases": results}) + "\n")
    print(f"wrote {args.out}: {len(results)} cases")
    return 0


def compare_orbits(old: dict[str, Any], new: dict[str, Any]) -> float:
    """Max difference of the polished orbits relative to each orbit's amplitude (the mean
    of a symmetric orbit is 0 to rounding); inf when a frequency's count or a stability
    label differs."""
    worst = 0.0
    for key, rows in old["orbits"].items():
        other = new["orbits"].get(key, [])
        if len(rows) != len(other):
            return math.inf
        for r, q in zip(rows, other, strict=True):
            if r[3] != q[3]:
                return math.inf
            scale = max(abs(r[0]), 1e-300)
            worst = max(worst, max(abs(x - y) for x, y in zip(q[:3], r[:3], strict=True)) / scale)
    return worst


def _runs(w: np.ndarray) -> list[np.ndarray]:
    """Index ranges of a branch on which omega is monotone (split at the turning points)."""
    if w.size < 2:
        return [np.arange(w.size)]
    d = np.sign(np.diff(w))
    cuts = [i + 1 for i in range(1, d.size) if d[i] != 0 and d[i] != d[i - 1] and d[i - 1] != 0]
    edges = [0, *cuts, w.size]
    # a turning point belongs to both runs
    return [np.arange(max(a - 1, 0), b) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def _interp(wq: float, w: np.ndarray, a: np.ndarray) -> float:
    """Cubic (Lagrange) interpolation of a monotone-omega run at wq, through the 4 nearest
    points (exact at a sample point)."""
    order = np.argsort(w)
    w, a = w[order], a[order]
    j = int(np.searchsorted(w, wq))
    if j < w.size and w[j] == wq:
        return float(a[j])
    lo = min(max(j - 2, 0), max(w.size - 4, 0))
    xs, ys = w[lo : lo + 4], a[lo : lo + 4]
    val = 0.0
    for i in range(xs.size):
        li = 1.0
        for k in range(xs.size):
            if k != i:
                li *= (wq - xs[k]) / (xs[i] - xs[k])
        val += ys[i] * li
    return val


def compare_curves(old: dict[str, Any], new: dict[str, Any]) -> dict[str, Any]:
    """Same curves, possibly sampled at other points: the branch count, the order of the
    stability labels (run lengths may differ), the folds (count, omega by order) and branch
    points (count, omega within the 6-digit note text), and the amplitude of every old point
    away from the turning points (2 points in from each end of a monotone run) against the
    new branch's run interpolated there (cubic through the 4 nearest points)."""
    ob, nb = old["branches"], new["branches"]
    problems = []
    if len(ob) != len(nb):
        problems.append(f"branches {len(ob)} -> {len(nb)}")
    labels = [[lab for lab, _ in x["stable_rle"]] for x in ob]
    if len(ob) == len(nb) and labels != [[lab for lab, _ in y["stable_rle"]] for y in nb]:
        problems.append("stability label order differs")
    if len(old["folds"]) != len(new["folds"]):
        problems.append(f"folds {len(old['folds'])} -> {len(new['folds'])}")
    obp, nbp = old.get("branch_points", []), new.get("branch_points", [])
    if len(obp) != len(nbp):
        problems.append(f"branch points {len(obp)} -> {len(nbp)}")
    elif any(abs(x[0] - y[0]) > 1e-5 * abs(x[0]) for x, y in zip(obp, nbp, strict=True)):
        problems.append("branch points moved beyond the note's 6 digits")
    d_amp = 0.0
    if len(ob) == len(nb):
        for x, y in zip(ob, nb, strict=True):
            xw, xa = np.array(x["omega"]), np.array(x["amplitude"])
            yw, ya = np.array(y["omega"]), np.array(y["amplitude"])
            xr, yr = _runs(xw), _runs(yw)
            if len(xr) != len(yr):
                problems.append("monotone runs differ")
                d_amp = math.inf
                continue
            for rx, ry in zip(xr, yr, strict=True):
                if ry.size < 2:
                    continue
                wlo, whi = float(np.min(yw[ry])), float(np.max(yw[ry]))
                for i in rx[2:-2]:
                    if wlo <= xw[i] <= whi:
                        got = _interp(float(xw[i]), yw[ry], ya[ry])
                        d_amp = max(d_amp, abs(got - xa[i]) / max(abs(xa[i]), 1e-300))
    of, nf = np.array(old["folds"]).reshape(-1, 2), np.array(new["folds"]).reshape(-1, 2)
    d_fold = (
        float(np.max(np.abs(nf[:, 0] - of[:, 0]), initial=0.0)) if len(of) == len(nf) else math.inf
    )
    return {
        "structure_same": not problems,
        "problems": problems,
        "mode": "curves",
        "d_amp": d_amp,
        "d_omega": math.nan,
        "d_other": math.nan,
        "d_fold": d_fold,
        "notes_same": old["notes"] == new["notes"],
    }


def _g(x: float) -> str:
    if isinstance(x, float) and math.isnan(x):
        return "–"
    return "0" if x == 0 else f"{x:.2e}"


def cmd_compare(args: argparse.Namespace) -> int:
    base = json.loads(Path(args.baseline).read_text())
    if base.get("format") != FORMAT:
        print(f"{args.baseline}: not a {FORMAT} file", file=sys.stderr)
        return 2
    if args.current:
        cur_doc = json.loads(Path(args.current).read_text())
        current = {c["id"]: c for c in cur_doc["cases"]}
        run = False
    else:
        current, run = {}, True
        import perturb

        print(f"running against {perturb.__file__}", flush=True)
    rows, failed = [], False
    new_cases = []
    orbit_base = None
    if args.curves and args.orbits:
        orbit_base = {c["id"]: c for c in json.loads(Path(args.orbits).read_text())["cases"]}
    if args.curves and not run:
        print("--curves runs the cases (polished orbits are not recorded)", file=sys.stderr)
        return 2
    for bc in base["cases"]:
        if args.only and not fnmatch.fnmatch(bc["id"], args.only):
            continue
        if run:
            case = {k: bc[k] for k in ("id", "model", "params", "window", "method", "kwargs")}
            nc = run_case(case)
            new_cases.append(nc)
        else:
            nc = current.get(bc["id"])
            if nc is None:
                rows.append((bc["id"], "missing", "no", "", "", "", "", "", "", "not in current"))
                failed = True
                continue
        st = bc["status"] if bc["status"] == nc["status"] else f"{bc['status']}->{nc['status']}"
        t_ratio = bc["wall_s"] / nc["wall_s"] if nc["wall_s"] > 0 else math.nan
        if bc["status"] != "ok" or nc["status"] != "ok":
            same = bc["status"] == nc["status"]
            failed |= not same
            why = "" if same else nc.get("reason", "")[:60]
            rows.append(
                (bc["id"], st, "yes" if same else "NO", "", "", "", "", "", f"{t_ratio:.2f}", why)
            )
            continue
        if args.curves:
            c = compare_curves(bc["response"], nc["response"])
        else:
            c = compare_responses(bc["response"], nc["response"])
        if args.curves and bc["method"] == "exact" and orbit_base is not None:
            ob_case = orbit_base.get(bc["id"])
            d_orb = compare_orbits(ob_case, run_orbits(case)) if ob_case else math.inf
            c["d_other"] = d_orb
            if not d_orb <= args.orbit_tol:
                c["problems"].append(f"polished orbits differ ({_g(d_orb)})")
                c["structure_same"] = False
        over = [
            name
            for name, val, tol, used in (
                ("Δamp", c["d_amp"], args.amp_tol, True),
                ("Δomega", c["d_omega"], args.amp_tol, c["mode"] == "by order" and not args.curves),
                ("Δfold", c["d_fold"], args.fold_tol, True),
            )
            if used and not (val <= tol)
        ]
        if args.strict_notes and not c["notes_same"]:
            over.append("notes")
        c["problems"] += [f"{x} over tolerance" for x in over]
        bad = not c["structure_same"] or bool(over)
        failed |= bad
        rows.append(
            (
                bc["id"],
                st,
                "yes" if c["structure_same"] else "NO",
                _g(c["d_amp"])
                + {"by order": "", "curves": " (interp.)"}.get(c["mode"], " (curve)"),
                _g(c["d_omega"]),
                _g(c["d_fold"]),
                _g(c["d_other"]),
                "yes" if c["notes_same"] else "differ",
                f"{t_ratio:.2f}",
                ("FAIL " if bad else "") + "; ".join(c["problems"]),
            )
        )
    head = (
        "case",
        "status",
        "same structure",
        "max rel Δamp",
        "max rel Δomega",
        "max |Δfold Ω|",
        "max rel Δ other cols",
        "notes",
        "time old/new",
        "remark",
    )
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for r in rows:
        print("| " + " | ".join(str(x) for x in r) + " |")
    if args.curves:
        print(
            "\n--curves: 'max rel Δamp' is the amplitude of each old point (away from turning "
            "points) against the new curve interpolated at its omega; 'other cols' of exact "
            f"cases is the polished orbits' max rel difference (tolerance {args.orbit_tol:g})"
        )
    print(
        f"\ntolerances: amplitude/omega {args.amp_tol:g} relative, fold Omega {args.fold_tol:g}; "
        f"'other cols' (first harmonic, mean, max multiplier) informational; "
        f"result: {'DIFFERENT' if failed else 'identical within tolerances'}"
    )
    if args.save_current and run:
        Path(args.save_current).write_text(
            json.dumps({"format": FORMAT, "cases": new_cases}, separators=(",", ":")) + "\n"
        )
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="run every case and write the JSON")
    r.add_argument("--out", required=True)
    r.add_argument("--only", help="fnmatch pattern of case ids, e.g. 'nsd_k-3/*'")
    r.add_argument(
        "--exact-workers", type=int, help="pass workers=N to the exact solver (default: its own)"
    )
    c = sub.add_parser("compare", help="run (or load) the cases and compare with a baseline")
    c.add_argument("--baseline", required=True)
    c.add_argument("--current", help="a recorded JSON instead of running the cases")
    c.add_argument("--save-current", help="also write what this run recorded to this file")
    c.add_argument("--only", help="fnmatch pattern of case ids")
    c.add_argument("--amp-tol", type=float, default=1e-9, help="relative (amplitude, omega)")
    c.add_argument("--fold-tol", type=float, default=1e-9, help="absolute (fold Omega)")
    c.add_argument("--strict-notes", action="store_true", help="different notes fail too")
    c.add_argument(
        "--curves",
        action="store_true",
        help="same curves sampled at other points (see compare_curves); with --orbits also "
        "the polished exact orbits at fixed frequencies",
    )
    c.add_argument("--orbits", help="JSON of the orbits command (recorded with the baseline)")
    c.add_argument("--orbit-tol", type=float, default=1e-10, help="relative (polished orbits)")
    o = sub.add_parser("orbits", help="record the polished exact orbits at fixed frequencies")
    o.add_argument("--out", required=True)
    o.add_argument("--only", help="fnmatch pattern of case ids")
    o.add_argument("--exact-workers", type=int, help="pass workers=N to the exact solver")
    args = ap.parse_args(argv)
    if args.cmd == "orbits":
        return cmd_orbits(args)
    return cmd_record(args) if args.cmd == "record" else cmd_compare(args)


if __name__ == "__main__":
    sys.exit(main())
