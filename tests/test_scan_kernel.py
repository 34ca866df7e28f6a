"""The compiled kernels against the Python code they translate: the switch scan
(perturb.simulate.flows.scan_kernel against affine_exact._scan_python), piece by piece, and
against closed-form crossing times; the orbit statistics (exact_response.statistics_numba
against Engine.nd_statistics), orbit by orbit, and against dense sampling.

The Python scan is certified separately (tests/test_affine_exact.py: DOP853 with events and
restarts, grazing constructions); with numba installed those tests run the compiled path, so
here the two versions are compared on the same pieces: same outcome, same surface, times to
rounding, the same grid (the same number of intervals scanned).
"""

from __future__ import annotations

import math
import signal

import numpy as np
import pytest

from perturb.errors import PerturbError
from perturb.model.affine import PiecewiseAffineSystem
from perturb.model.system_builtins import builtin_system
from perturb.simulate.exact_response import exact_branches, problem
from perturb.simulate.flows import affine_exact as ae
from perturb.simulate.flows import scan_kernel

pytest.importorskip("numba")


@pytest.fixture
def kernel():
    k = scan_kernel.compiled_scan()
    if k is None:
        pytest.skip("the compiled scan is switched off (PERTURB_COMPILED=0)")
    return k


def _compare_all(monkeypatch, kernel, run):
    """Run ``run()`` with every eligible piece scanned by both versions (the Python result
    drives the propagation); returns the tallies."""
    python_scan = ae._scan_python
    tally = {"pieces": 0, "crossings": 0, "tangencies": 0, "max_dt": 0.0}

    def both(piece, tau_end, touching, budget):
        eligible = piece.ns and tau_end > 0.0 and piece.region.kind == "modal"
        if not eligible or piece.has_res:
            return python_scan(piece, tau_end, touching, budget)
        own = ae._Budget(budget.left)
        got = ae._scan_compiled(kernel, piece, tau_end, set(touching), own)
        left = budget.left
        ref = python_scan(piece, tau_end, touching, budget)
        tally["pieces"] += 1
        assert left - budget.left == own.used  # the same grid
        assert (ref[0] is None) == (got[0] is None), (ref, got)
        if ref[0] is not None:
            assert ref[0][1] == got[0][1], (ref, got)
            tally["max_dt"] = max(tally["max_dt"], abs(ref[0][0] - got[0][0]))
            tally["crossings"] += 1
        assert [j for _, j in ref[1]] == [j for _, j in got[1]], (ref, got)
        for (ta, _), (tb, _) in zip(ref[1], got[1], strict=True):
            tally["max_dt"] = max(tally["max_dt"], abs(ta - tb))
        tally["tangencies"] += len(ref[1])
        return ref

    monkeypatch.setattr(ae, "_scan", both)
    run()
    return tally


@pytest.mark.parametrize(
    "name, omegas",
    [("nsd2", (0.6, 1.25, 1.7)), ("impact_pair", (0.65, 0.97, 1.2))],
)
def test_same_events_as_the_python_scan_on_builtin_systems(monkeypatch, kernel, name, omegas):
    rng = np.random.default_rng(7)

    def run():
        for w in omegas:
            pa = builtin_system(name).with_params({"Omega": w}).piecewise_affine()
            for _ in range(2):
                ae.propagate(pa, 2.0 * rng.normal(size=pa.n), 0.0, 12 * pa.period)

    tally = _compare_all(monkeypatch, kernel, run)
    assert tally["pieces"] > 100 and tally["crossings"] > 100
    # (measured 1.0e-13 over 8227 pieces of both systems: root solves to full precision of
    # the same closed form summed in another order)
    assert tally["max_dt"] < 1e-11


def _oscillator(offset: float, force: float = 0.0) -> PiecewiseAffineSystem:
    """``x'' + 0.1 x' + x = cos t`` on both sides of ``x = offset`` (a step force beyond)."""
    A = [[0.0, 1.0], [-1.0, -0.1]]
    return PiecewiseAffineSystem.build(
        ("x", "v"),
        [((1.0, 0.0), offset)],
        {(1,): (A, (0.0, force)), (-1,): (A, (0.0, 0.0))},
        inputs=[(1.0, (0.0, 1.0), (0.0, 0.0))],
    )


def _steady():
    """The harmonic steady state of ``x'' + 0.1 x' + x = cos t``: ``x = amp cos(t - phase)``
    (solved here, independently of the propagator)."""
    z = 1.0 / complex(1.0 - 1.0, 0.1)  # x = Re(z e^{it})
    return abs(z), -math.atan2(z.imag, z.real)


@pytest.mark.parametrize("depth", [1e-4, 1e-7, 0.0, -1e-7, -1e-4])
def test_grazing_the_steady_orbit(monkeypatch, kernel, depth):
    amp, phase = _steady()
    y0 = np.array([amp * math.cos(-phase), -amp * math.sin(-phase)])
    system = _oscillator(amp - depth, force=0.0)
    t1 = 2.0 * math.pi
    res = {}

    def run():
        res["p"] = ae.propagate(system, y0, 0.0, t1)

    tally = _compare_all(monkeypatch, kernel, run)
    assert tally["pieces"] >= 1
    crossings = [e.time for e in res["p"].events if not e.tangency]
    if depth > 1e-9:
        # x = amp cos(t - phase) = amp - depth at t = phase +- arccos(1 - depth / amp)
        half = math.acos(1.0 - depth / amp)
        expect = sorted(((phase - half) % t1, (phase + half) % t1))
        assert len(crossings) == 2
        # (the roots of a graze depth d: condition ~ 1/sqrt(d); rounding of the state ~1e-15)
        assert np.allclose(sorted(crossings), expect, atol=1e-12 / math.sqrt(depth))
    elif depth < -1e-9:
        assert res["p"].events == ()
    else:
        assert len(crossings) in (0, 2)


def test_same_errors(kernel):
    pa = builtin_system("nsd2").with_params({"Omega": 1.0}).piecewise_affine()
    y0 = np.array([3.0, 0.0, 0.0, 0.0])
    for scan in ("compiled", "python"):
        if scan == "python":
            saved = list(scan_kernel._KERNEL)
            scan_kernel._KERNEL[:] = [None]
        try:
            with pytest.raises(PerturbError, match="max_steps = 50 grid intervals"):
                ae.propagate(pa, y0, 0.0, 40 * pa.period, max_steps=50)
            # an unstable region (negative damping, fast growth): overflow named, not NaN
            bad = PiecewiseAffineSystem.build(
                ("x", "v"),
                [((1.0, 0.0), 1e300)],
                {(1,): ([[0, 1], [-1, 50.0]], (0, 0)), (-1,): ([[0, 1], [-1, 50.0]], (0, 0))},
            )
            with pytest.raises(PerturbError, match="escapes to infinity"):
                ae.propagate(bad, [1.0, 0.0], 0.0, 100.0)
        finally:
            if scan == "python":
                scan_kernel._KERNEL[:] = saved


def test_switched_off_by_the_environment(monkeypatch):
    for flag, off in (("0", True), ("off", True), ("1", False)):
        monkeypatch.setattr(scan_kernel, "_KERNEL", [])
        monkeypatch.setattr(scan_kernel, "_KERNELS", {})
        monkeypatch.setenv("PERTURB_COMPILED", flag)
        assert (scan_kernel.compiled_scan() is None) is off


# ------------------------------------------------------------------------------------------
# the compiled orbit statistics (exact_response/statistics_numba.py)
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name, window", [("nsd2", (1.15, 1.35)), ("impact_pair", (0.9, 0.95))])
def test_compiled_statistics_equal_the_python_statistics(monkeypatch, kernel, name, window):
    compiled = problem.Engine._compiled_statistics
    python = problem.Engine.nd_statistics
    tally = {"orbits": 0, "worst": 0.0, "dense": 0.0}

    def both(self, flow, Z, P, trajs=None):
        got = python(self, flow, Z, P, trajs)
        monkeypatch.setattr(problem.Engine, "_compiled_statistics", lambda *a, **k: None)
        try:
            ref = python(self, flow, Z, P, trajs)
        finally:
            monkeypatch.setattr(problem.Engine, "_compiled_statistics", compiled)
        (a0, a1, a2), (aa, am), asig = got
        (b0, b1, b2), (ba, bm), bsig = ref
        scale = max(1.0, abs(b0))
        diff = max(
            abs(a0 - b0), abs(a1 - b1), abs(a2 - b2), np.max(np.abs(aa - ba)),
            np.max(np.abs(am - bm)), np.max(np.abs(asig - bsig)),
        )  # fmt: skip
        tally["worst"] = max(tally["worst"], diff / scale)
        if tally["orbits"] % 50 == 0:
            # an oracle of neither: max |x1| of the closed form sampled densely
            traj = flow.trajectory(Z[0], self.t0, self.t0 + P)
            dense = np.max(np.abs(traj(np.linspace(self.t0, self.t0 + P, 40001))[0]))
            # (a sample misses the peak by at most max|x1''| (P / 40000)^2 / 8 ~ 1e-9 here)
            tally["dense"] = max(tally["dense"], (aa[0] - dense) / scale)
            assert -1e-13 <= (aa[0] - dense) / scale < 1e-8
        tally["orbits"] += 1
        return got

    monkeypatch.setattr(problem.Engine, "nd_statistics", both)
    exact_branches(builtin_system(name), window, workers=1, attractors=False)
    assert tally["orbits"] > 100
    # (measured 6.5e-15 over 15,000 orbits of nsd2 (0.5, 2) and impact_pair (0.8, 1.0))
    assert tally["worst"] < 1e-12


# ------------------------------------------------------------------------------------------
# robustness of both scans and of the switch (found by review)
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("compiled", [True, False])
def test_a_switching_function_flat_within_rounding_of_zero_does_not_hang(monkeypatch, compiled):
    # x' = v, v' = -x - 0.3 v + 1 settles on x = 1; the surface one ulp below it: once the
    # homogeneous part underflows, g is a constant within the tangency tolerance of zero,
    # which the halving search explored to depth 60 (2^60 intervals) on both scans
    if compiled:
        if scan_kernel.compiled_scan() is None:
            pytest.skip("the compiled scan is switched off")
    else:
        monkeypatch.setattr(scan_kernel, "_KERNEL", [None])
    A = [[0.0, 1.0], [-1.0, -0.3]]
    system = PiecewiseAffineSystem.build(
        ("x", "v"),
        [((1.0, 0.0), 1.0 - math.ulp(1.0))],
        {(1,): (A, (0.0, 1.0)), (-1,): (A, (0.0, 1.0))},
    )
    signal.signal(signal.SIGALRM, _timeout)
    signal.alarm(60)  # (a regression fails here instead of hanging; numba code ignores it, the
    try:  # CI's own time cap remains)
        res = ae.propagate(system, [0.0, 0.0], 0.0, 8000.0)
    finally:
        signal.alarm(0)
    # the orbit itself: the closed form of the linear field (no switch changes it)
    assert abs(res.y[0] - 1.0) < 1e-12 and abs(res.y[1]) < 1e-12


def _timeout(*_):
    raise TimeoutError("the scan did not return within 60 s")


def test_the_kernel_constants_are_scan_kernels(kernel):
    from perturb.simulate.flows import scan_kernel_numba

    assert tuple(scan_kernel_numba.constants()) == scan_kernel._CONSTANTS
    assert scan_kernel._CONSTANTS == (
        ae._EPS, ae._STEPS_PER_SCALE, ae._BATCH_FIRST, ae._BATCH_MAX, ae._MAX_DEPTH,
        ae._ROOT_ITER, ae._MAX_NODES,
    )  # fmt: skip


def test_a_failing_kernel_falls_back_to_numpy_with_a_warning(monkeypatch, kernel):
    def broken(*args):
        raise RuntimeError("cannot compile")

    monkeypatch.setattr(scan_kernel, "_KERNEL", [broken])
    monkeypatch.setattr(scan_kernel, "_KERNELS", {})
    pa = builtin_system("nsd2").with_params({"Omega": 1.2}).piecewise_affine()
    y0 = np.array([2.0, 0.0, 0.0, 0.0])
    with pytest.warns(RuntimeWarning, match="compiled kernel scan_modal failed"):
        got = ae.propagate(pa, y0, 0.0, 3 * pa.period)
    assert scan_kernel.compiled_scan() is None  # off for the rest of the process
    ref = ae.propagate(pa, y0, 0.0, 3 * pa.period)
    assert np.array_equal(got.y, ref.y)


def test_numbas_cache_only_where_nobody_else_writes(tmp_path):
    private = tmp_path / "mine"
    private.mkdir(mode=0o755)
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    assert scan_kernel._private(str(private))
    assert not scan_kernel._private(str(shared))
    assert scan_kernel._private(str(tmp_path / "absent"))


def test_whether_the_kernels_are_wanted_is_known_without_numba(monkeypatch):
    # (a checkpointed sweep records it: see perturb.apps.grid)
    monkeypatch.setenv("PERTURB_COMPILED", "0")
    assert scan_kernel.wanted() is False
    monkeypatch.setenv("PERTURB_COMPILED", "1")
    assert scan_kernel.wanted() is True  # (numba is installed: importorskip above)
