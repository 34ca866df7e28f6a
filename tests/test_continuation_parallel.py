"""Parallel tracing in :func:`exact_branches` returns exactly the serial branches.

The two halves of every branch are marched in worker processes, blind to branches registered
meanwhile and to each other; the serial stop tests are replayed afterwards.  The oracle is the
serial run (``workers=1``, no pool, no replay), compared point by point; inside a worker
process of another pool the call must run serially and still answer.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os

import numpy as np
import pytest

from perturb.errors import ParameterError
from perturb.model.builtins import builtin_model
from perturb.simulate.exact_response import exact_branches

NSD_K3 = {"k": -3.0, "mu": 0.05, "F": 2.0}
WINDOW = (0.45, 0.75)  # the cross-well branch with its pitchfork, a fold and the saddle branch

needs_fork = pytest.mark.skipif(
    "fork" not in mp.get_all_start_methods() or (os.cpu_count() or 1) < 2,
    reason="parallel tracing needs fork and two CPUs",
)


def _run(workers):
    return exact_branches(builtin_model("nsd", **NSD_K3), WINDOW, progress=False, workers=workers)


def _same(a, b):
    assert len(a.branches) == len(b.branches)
    assert a.mirror_of == b.mirror_of
    for x, y in zip(a.branches, b.branches, strict=True):
        assert x.stop_reason == y.stop_reason and x.closed == y.closed
        assert len(x) == len(y)
        assert x.periods == pytest.approx(y.periods, rel=1e-12)
        for p, q in zip(x.points, y.points, strict=True):
            assert p.parameter == q.parameter and p.stable == q.stable
            assert np.array_equal(p.y0, q.y0) and p.amplitude == q.amplitude
            assert np.array_equal(p.multipliers, q.multipliers)
        assert [(s.kind, s.index, s.parameter) for s in x.special_points] == [
            (s.kind, s.index, s.parameter) for s in y.special_points
        ]
    assert a.periods == pytest.approx(b.periods, rel=1e-12)


@pytest.fixture(scope="module")
def serial():
    return _run(1)


@needs_fork
def test_two_workers_give_the_serial_branches(serial):
    par = _run(2)
    assert any("worker processes" in n for n in par.notes)
    assert not any("worker processes" in n for n in serial.notes)
    _same(serial, par)
    # the problem is not trivial: a branch point, folds, several branches
    kinds = {s.kind for b in serial.branches for s in b.special_points}
    assert {"fold", "branch_point"} <= kinds and len(serial.branches) >= 3


def _in_worker():
    res = _run(None)
    return res.notes, len(res.branches), [len(b) for b in res.branches]


@needs_fork
def test_inside_a_process_pool_runs_serially(serial):
    with cf.ProcessPoolExecutor(1, mp_context=mp.get_context("fork")) as pool:
        notes, n, lengths = pool.submit(_in_worker).result(timeout=600)
    assert not any("worker processes" in s for s in notes)  # no nested pool
    assert n == len(serial.branches) and lengths == [len(b) for b in serial.branches]


def test_workers_validation(monkeypatch):
    osc = builtin_model("nsd", **NSD_K3)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ParameterError, match="workers"):
            exact_branches(osc, WINDOW, progress=False, workers=bad)
    monkeypatch.setenv("PERTURB_WORKERS", "two")
    with pytest.raises(ParameterError, match="PERTURB_WORKERS"):
        exact_branches(osc, WINDOW, progress=False)
