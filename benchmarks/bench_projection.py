"""Benchmark: the exact Galerkin projection of a PWL force (``ExactProjector.project`` in
:mod:`perturb.fourier.projection`) against an older copy of the module, per call and inside
whole responses.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_projection.py [--baseline-rev d68d82b~1]
        [--baseline FILE] [--repeat 5] [--no-response]

The baseline is ``perturb/fourier/projection.py`` at ``--baseline-rev`` (``git show``) or the
file ``--baseline``, imported under another name (its imports of the package resolve to the
current tree). Everything runs in this one process with one BLAS thread; CPU is
``time.process_time``, the minimum over ``--repeat`` runs, the baseline and the current module
timed alternately (on a shared machine only the ratio within one run is meaningful).

1. **Per call on captured inputs**: every ``(u, jacobian)`` that
   ``system_balance_response(builtin_system('nsd2'), (0.5, 2.0), harmonics=15)`` (issue 16's
   call) and the SDOF ``harmonic_balance_response(nsd k=-0.5 mu=0.05 F=2, (0.3, 2.0),
   harmonics=15, ds_max=0.04)`` pass to ``ExactProjector.project``, captured by wrapping the
   method; then all of them projected by each module's projector, and the outputs compared
   (projection, Jacobian and crossing intervals: how many are ``np.array_equal``, and the
   largest difference relative to the largest entry).
2. **Whole responses**: the same two calls with the response module's imported names
   (``ExactProjector``, ``TruncatedSeries``, ``crossing_intervals``, ``CrossingIntervals``)
   pointing at the baseline or at the current module (and the projector of the compiled SDOF
   system that ``harmonic_balance`` keeps between calls replaced), and whether the responses
   are identical (branch count, origins, and every array of every branch: Omega,
   coefficients, amplitudes, multiplier modulus, by ``np.array_equal``).
3. **Rough signals**: 200 random signals with 1/k spectra (nsd and a force with a jump,
   H = 5, 15, 63), where many grid cells are hard (an extremum near a breakpoint) and the
   certified isolation bisects and locates extrema: per call, and outputs equal.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import platform  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

import perturb.fourier.projection as current  # noqa: E402
import perturb.numeric.harmonic_balance as hb  # noqa: E402
import perturb.numeric.system_balance as sb  # noqa: E402
from perturb.model.builtins import builtin_model  # noqa: E402
from perturb.model.system_builtins import builtin_system  # noqa: E402

NAMES = ("ExactProjector", "TruncatedSeries", "crossing_intervals", "CrossingIntervals")


def load_baseline(rev: str | None, path: str | None):
    """The older projection module, from a git revision or a file."""
    if path is None:
        src = subprocess.run(
            ["git", "show", f"{rev}:perturb/fourier/projection.py"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        tmp = tempfile.NamedTemporaryFile("w", suffix=".py", delete=False)
        tmp.write(src)
        tmp.close()
        path = tmp.name
    spec = importlib.util.spec_from_file_location("perturb.fourier._bench_projection_old", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def nsd2_response():
    return sb.system_balance_response(builtin_system("nsd2"), (0.5, 2.0), harmonics=15)


def nsd_response():
    osc = builtin_model("nsd", k=-0.5, mu=0.05, F=2.0)
    return hb.harmonic_balance_response(osc, (0.3, 2.0), harmonics=15, ds_max=0.04)


CALLS = {
    "nsd2 system_balance_response (0.5, 2.0) H=15": (nsd2_response, sb),
    "nsd harmonic_balance_response (0.3, 2.0) H=15": (nsd_response, hb),
}


def use(module, projection) -> None:
    """Point ``module``'s projection names at ``projection``; the compiled SDOF systems that
    harmonic_balance keeps between calls get a projector of that module too."""
    for name in NAMES:
        setattr(module, name, getattr(projection, name))
    for system in getattr(module, "_SYSTEMS", {}).values():
        if getattr(system, "_exact", None) is not None:
            system._exact = projection.ExactProjector(system.pwl, system.basis)
            system._cache = None


def capture(call) -> list:
    """The ``(pwl, basis, u, jacobian)`` of every ``ExactProjector.project`` of ``call``."""
    seen = []
    original = current.ExactProjector.project

    def recording(self, u, jacobian=True, series=None):
        seen.append((self.pwl, self.basis, np.array(u, dtype=float), bool(jacobian)))
        return original(self, u, jacobian, series)

    current.ExactProjector.project = recording
    try:
        call()
    finally:
        current.ExactProjector.project = original
    return seen


def compare(inputs, old, repeat: int) -> None:
    projectors = {}
    for mod in (old, current):
        for pwl, basis, _, _ in inputs:
            key = (mod.__name__, id(pwl), basis)
            if key not in projectors:
                projectors[key] = mod.ExactProjector(pwl, basis)

    def run(mod):
        return [
            projectors[(mod.__name__, id(pwl), basis)].project(u, jac)
            for pwl, basis, u, jac in inputs
        ]

    ro, rn = run(old), run(current)
    equal, worst_p, worst_j, worst_t = 0, 0.0, 0.0, 0.0
    for (po, jo, co), (pn, jn, cn) in zip(ro, rn, strict=True):
        same_pieces = all(
            np.array_equal(getattr(co, f), getattr(cn, f))
            for f in ("start", "length", "segment", "d1")
        )
        equal += bool(
            np.array_equal(po, pn) and (jo is None or np.array_equal(jo, jn)) and same_pieces
        )
        worst_p = max(worst_p, float(np.abs(po - pn).max() / max(1e-300, np.abs(po).max())))
        if jo is not None:
            worst_j = max(worst_j, float(np.abs(jo - jn).max() / max(1e-300, np.abs(jo).max())))
        if co.start.size == cn.start.size:
            worst_t = max(worst_t, float(np.abs(co.start - cn.start).max(initial=0.0)))
        else:
            worst_t = np.inf
    best = {"baseline": np.inf, "current": np.inf}
    for _ in range(repeat):
        for name, mod in (("baseline", old), ("current", current)):
            t0 = time.process_time()
            run(mod)
            best[name] = min(best[name], time.process_time() - t0)
    n = len(inputs)
    print(
        f"   {n} calls ({sum(j for *_, j in inputs)} with the Jacobian): "
        f"baseline {best['baseline'] / n * 1e6:.1f} us/call, current "
        f"{best['current'] / n * 1e6:.1f} us/call, ratio {best['baseline'] / best['current']:.2f}"
    )
    print(
        f"   outputs np.array_equal in {equal} of {n}; largest relative difference: "
        f"projection {worst_p:.1e}, Jacobian {worst_j:.1e}; crossing angles {worst_t:.1e} rad"
    )


FIELDS = (
    "Omega",
    "U",
    "omega",
    "amplitude",
    "first_harmonic_amplitude",
    "mean",
    "stable",
    "max_multiplier",
)


def same_response(a, b) -> bool:
    """Branch count, origins (where recorded) and every array field of every branch equal."""
    if len(a.branches) != len(b.branches) or getattr(a, "origins", None) != getattr(
        b, "origins", None
    ):
        return False
    for x, y in zip(a.branches, b.branches, strict=True):
        for f in FIELDS:
            if hasattr(x, f):
                fx, fy = getattr(x, f), getattr(y, f)
                if (fx is None) != (fy is None) or (fx is not None and not np.array_equal(fx, fy)):
                    return False
    return True


def points(r) -> int:
    return sum(len(getattr(b, "Omega", getattr(b, "omega", ()))) for b in r.branches)


def whole(call, module, old, repeat: int) -> None:
    best = {"baseline": np.inf, "current": np.inf}
    out = {}
    try:
        for _ in range(repeat):
            for name, mod in (("baseline", old), ("current", current)):
                use(module, mod)
                t0 = time.process_time()
                out[name] = call()
                best[name] = min(best[name], time.process_time() - t0)
    finally:
        use(module, current)
    r = out["current"]
    print(
        f"   baseline {best['baseline']:.3f} s, current {best['current']:.3f} s CPU "
        f"(saved {best['baseline'] - best['current']:.3f} s); {len(r.branches)} branches, "
        f"{points(r)} points; responses identical: "
        f"{same_response(out['baseline'], r)}"
    )


def rough(old, repeat: int) -> None:
    """Random signals with 1/k spectra (many hard cells: extrema near the breakpoints)."""
    from perturb.model.pwl import NumericPWL

    nsd = NumericPWL(np.array([-1.0, 1.0]), np.array([1.0, -0.5, 1.0]), np.array([1.5, 0.0, -1.5]))
    jump = NumericPWL(np.array([0.5]), np.array([1.0, 2.0]), np.array([0.0, 0.3]))
    rng = np.random.default_rng(1)
    for H, pwl, name in ((63, nsd, "nsd"), (15, nsd, "nsd"), (15, jump, "jump"), (5, nsd, "nsd")):
        basis = current.HarmonicBasis.make(H)
        ks = np.arange(1, H + 1)
        us = []
        for _ in range(200):
            u = np.zeros(basis.size)
            u[0] = rng.uniform(-0.5, 0.5)
            u[1::2] = 2.0 * rng.standard_normal(H) / ks
            u[2::2] = 2.0 * rng.standard_normal(H) / ks
            us.append(u)
        po, pn = old.ExactProjector(pwl, basis), current.ExactProjector(pwl, basis)
        best = {"baseline": np.inf, "current": np.inf}
        for _ in range(repeat):
            for label, p in (("baseline", po), ("current", pn)):
                t0 = time.process_time()
                for u in us:
                    p.project(u)
                best[label] = min(best[label], (time.process_time() - t0) / len(us))
        equal = 0
        for u in us:
            a, b = po.project(u), pn.project(u)
            equal += bool(
                np.array_equal(a[0], b[0])
                and np.array_equal(a[1], b[1])
                and all(
                    np.array_equal(getattr(a[2], f), getattr(b[2], f))
                    for f in ("start", "length", "segment", "d1")
                )
            )
        print(
            f"   H = {H}, {name}: baseline {best['baseline'] * 1e6:.0f} us/call, current "
            f"{best['current'] * 1e6:.0f} us/call; outputs np.array_equal in {equal} of {len(us)}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline-rev", default="d68d82b~1", help="git revision of the baseline")
    ap.add_argument("--baseline", default=None, help="a file to use as the baseline instead")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--no-response", action="store_true", help="skip part 2")
    args = ap.parse_args()
    old = load_baseline(args.baseline_rev, args.baseline)
    print("command: PYTHONPATH=. python benchmarks/bench_projection.py " + " ".join(sys.argv[1:]))
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
        f"baseline {args.baseline or args.baseline_rev}"
    )
    print("== 1. ExactProjector.project per call on the inputs of a whole response")
    for label, (call, _) in CALLS.items():
        print(f" {label}")
        compare(capture(call), old, args.repeat)
    if not args.no_response:
        print("== 2. whole responses, the response module's projection names swapped")
        for label, (call, module) in CALLS.items():
            print(f" {label}")
            whole(call, module, old, args.repeat)
    print("== 3. 200 rough signals (1/k spectra, a0 in [-0.5, 0.5]: many hard cells), seed 1")
    rough(old, args.repeat)


if __name__ == "__main__":
    main()
