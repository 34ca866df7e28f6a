"""perturb bench on systems of several coordinates (issue 16 item 3): the nsd2 and
impact_pair problems, rows of the methods that take a system, errors per coordinate.

Oracle, written here: exact periodic orbits of nsd2 by single shooting of its equations of
motion (solve_ivp DOP853, rtol = atol = 1e-12, fsolve), compared with the benchmarked
response's own points.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from nsd2_oracle import exact_orbit_max

from perturb.apps import bench
from perturb.model.system_builtins import builtin_system
from perturb.solve import frequency_response

WINDOW = (1.1, 1.3)


def test_the_systems_are_problems():
    for name in ("nsd2", "impact_pair"):
        prob = bench.PROBLEMS[name]
        assert prob.kind == "system"
        assert prob.oscillator().state_names == builtin_system(name).state_names
    keys = [s.key for s in bench.method_settings("system")]
    assert {"hb1", "shb", "hb-exact-H3", "hb-exact-H63", "hb-aft-H7", "auto"} <= set(keys)


def test_bench_rows_of_a_system(monkeypatch):
    small = bench.Problem("nsd2_small", "nsd2", {}, WINDOW, "nsd2 near resonance", kind="system")
    monkeypatch.setitem(bench.PROBLEMS, "nsd2_small", small)
    rows = bench.run_benchmark(
        ["nsd2_small"], ["hb-exact-H3", "hb1"], repeat=1, timeout=0, log=None
    )
    by = {r.method: r for r in rows}
    assert set(by) == {"exact", "sweep", "hb-exact-H3", "hb1"}
    # the time unit: the system's stepped-sine sweep, every row's ratio to it
    assert by["sweep"].status == "ok" and by["hb-exact-H3"].time_vs_sweep > 0
    ex = frequency_response(builtin_system("nsd2"), "exact", WINDOW)
    assert by["exact"].matched == f"{len(ex.branches)}/{len(ex.branches)}"
    h3 = by["hb-exact-H3"]
    assert h3.status == "ok" and h3.missed.startswith("0/")  # every exact branch found
    # each coordinate's error in the note; the output's (x1) in the columns
    found = dict(re.findall(r"(x\d) ([0-9.e+-]+) \(rms", h3.note))
    assert set(found) == {"x1", "x2"}
    assert float(found["x1"]) == pytest.approx(h3.max_rel_error, rel=1e-2)
    # the row's max error is at least the error at points of the H = 3 curve measured here
    hb = frequency_response(builtin_system("nsd2"), "hb", WINDOW, harmonics=3)
    folds = [w for w, _ in hb.folds]
    measured = np.zeros(2)
    for b, br in enumerate(hb.branches):
        for j in range(0, len(br), 10):
            W = float(br.omega[j])
            if any(abs(W - f) < 0.02 * f for f in folds):
                continue
            e = exact_orbit_max(W, hb.columns[b]["states"][j])
            a = np.array([hb.columns[b]["amplitude_x1"][j], hb.columns[b]["amplitude_x2"][j]])
            measured = np.maximum(measured, np.abs(a - e) / e)
    assert measured[0] > 1e-5  # the check measures something
    assert h3.max_rel_error >= 0.9 * measured[0]
    assert float(found["x2"]) >= 0.9 * measured[1]
    # the zero-mean single harmonic leaves out the orbits with a mean: an exact branch missed
    assert by["hb1"].status == "ok"
    assert int(by["hb1"].missed.split("/")[0]) >= 1, by["hb1"]
