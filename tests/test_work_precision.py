"""The work-precision benchmark (``perturb bench``, :mod:`perturb.bench`)."""

from __future__ import annotations

import argparse
import csv
import math
import time

import pytest

from perturb import bench


def _row(**kw):
    base = dict(problem="p", method="m", setting="s")
    base.update(kw)
    return bench.Row(**base)


def test_outputs_have_the_columns_and_reasons(tmp_path):
    rows = [
        _row(method="exact", time_s=2.0, repeats=1, max_rel_error=0.0, rms_rel_error=0.0),
        _row(method="hb-exact-H1", time_s=0.1, repeats=1, max_rel_error=0.1, rms_rel_error=0.01),
        _row(method="lp", status="n/a (ModelError: has damping mu)"),
    ]
    written = bench.write_outputs(rows, tmp_path)
    names = {p.name for p in written}
    assert {"work_precision.csv", "work_precision.md", "work_precision_p.png"} <= names
    with (tmp_path / "work_precision.csv").open() as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == bench.COLUMNS
        got = list(reader)
    assert got[2]["status"] == "n/a (ModelError: has damping mu)"
    md = (tmp_path / "work_precision.md").read_text()
    assert "n/a (ModelError: has damping mu)" in md
    assert "max rel. error" in md and "time / sweep" in md


def test_timeout_stops_a_method():
    with pytest.raises(bench.MethodTimeout):
        bench._timed(lambda: time.sleep(5), 1, timeout=0.2)
    t, out = bench._timed(lambda: 3, 2, timeout=5)
    assert out == 3 and t >= 0


def test_cli_parser_registers_bench():
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command")
    bench.add_parser(sub)
    args = parser.parse_args(["bench", "--fast", "--out", "x", "--methods", "hb-*"])
    assert args.func is bench.cmd_bench and args.fast and args.out == "x"


def test_unknown_problem_is_an_error():
    with pytest.raises(ValueError, match="unknown problem"):
        bench.run_benchmark(["nope"], log=None)


@pytest.mark.slow  # the exact reference of nsd k = -0.5 alone takes ~40 s on 2 shared cores
def test_nsd_subset_oracle(tmp_path):
    rows = bench.run_benchmark(
        ["nsd_k-0.5"],
        ["hb-exact-H1", "hb-exact-H5", "lp"],
        fast=True,
        sweep_points=4,
        log=None,
    )
    by = {r.method: r for r in rows}
    assert set(by) == {"exact", "sweep", "hb-exact-H1", "hb-exact-H5", "lp"}
    for r in rows:
        assert set(r.as_dict()) == set(bench.COLUMNS)
        if r.status == "ok":
            assert math.isfinite(r.time_s) and r.time_s > 0
        for v in (r.max_rel_error, r.rms_rel_error):
            assert math.isnan(v) or (math.isfinite(v) and v >= 0)
    assert by["exact"].status == "ok"
    # nsd has damping: Lindstedt-Poincare does not apply, and says why
    assert by["lp"].status.startswith("n/a (") and len(by["lp"].status) > 8
    h1, h5 = by["hb-exact-H1"], by["hb-exact-H5"]
    assert h1.status == "ok" and h5.status == "ok"
    assert math.isfinite(h1.max_rel_error) and math.isfinite(h5.max_rel_error)
    # more harmonics, against the exact orbits: not less accurate than one harmonic
    assert h5.max_rel_error <= h1.max_rel_error * 1.0001
    assert h5.rms_rel_error <= h1.rms_rel_error * 1.0001
    written = bench.write_outputs(rows, tmp_path)
    assert (tmp_path / "work_precision_nsd_k-0.5.png") in written
