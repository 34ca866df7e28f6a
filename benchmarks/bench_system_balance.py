"""Benchmark: numeric multi-harmonic balance of systems of several coordinates
(:mod:`perturb.numeric.system_balance`).

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_system_balance.py [--repeat 3] [--quick]
        [--parts 1,1b,1c,2,3] [--baseline /tmp/old_system_balance.py]

Everything is timed in this one process (``time.process_time`` CPU, the measure: on a shared
machine the wall time includes waiting for a core; ``time.perf_counter`` wall shown beside it
in part 1; minimum over ``--repeat`` runs; one BLAS thread):

1. **nsd2, whole response**: ``system_balance_branch(nsd2, (0.5, 2.0), harmonics=15)`` (default
   nsd2, k = -0.5, F = 2; and the hardening k = 0.3, F = 0.6 with its folds), Floquet
   multipliers at every point; the set-up (``SystemBalance``, SymPy once per system) apart.
   Target (issue 16): <= 0.5 s.
1b. **nsd2, every branch**: ``system_balance_response(nsd2, window, harmonics=15)`` over
   (0.5, 2.0) (the exact solver's 4 branches: the connected one, two closed loops, one born
   at the high edge), (0.62, 0.75) (3), (0.3, 1.5) (4: one born at the low edge) and
   (0.2, 2.0) (6), multipliers at every point, beside the one-branch trace of part 1 in the
   same process (the ratio is the price of the seeds, the branch-point test and switching,
   and tracing the other branches). Target (issue 16): <= 0.5 s. Then the call exactly as a
   user makes it (no prepared ``balance=``: the ``SystemBalance`` is built inside), with the
   attractor stage (the default) and without it (``attractors=False``); with ``--baseline
   FILE`` (a copy of an older ``perturb/numeric/system_balance.py``, imported under another
   name) the same calls of that module too, the two timed alternately in this process, and
   whether the responses are identical (branch count, origins, every point's Omega,
   coefficients and multiplier modulus by ``np.array_equal``).
1c. **Stability per point**: the Floquet multipliers from the monodromy of the linearisation
   (one point at a time, and a whole branch with its crossings found at once), beside the
   eigenvalue problem of a Hill matrix of the same balance (``2 x unknowns`` square).
2. **Accuracy at fixed Omega** (nsd2, Omega = 1.2): error of each coordinate's max|.| against
   the exact orbit (``periodic_orbit`` on ``AffineExactFlow``, 2^14 samples), exact
   projection and AFT with 4H + 1 samples (``projection="aft"``) beside the truncation floor
   (the exact orbit's Fourier series cut at H), H = 1, 3, 7, 15, 31, 63.
3. **Chain of n masses** (n = 2, 4, 8, 16, 32), one two-sided gap per mass on the relative
   displacement to its left neighbour (ground for the first): per (n, H) the time of one
   residual + Jacobian assembly (dense, and sparse CSC), of a dense LU of the same matrix, of
   one sparse Newton solve at fixed Omega (SuperLU), and of a whole response (continuation,
   dense Jacobians: the core takes dense matrices; automatic start at Omega = 1.3) over
   (0.8, 1.3), with its number of residual + Jacobian evaluations and the CPU per evaluation
   (the branches differ with n: folds, lengths).
   The assembly's growth with n is the point: per gap it is ``nnz(w) nnz(c) = 4`` blocks of
   ``O(H^2)``, so the sparse assembly grows ~linearly in n, while the dense LU grows like
   ``(n H)^3``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402
import scipy.linalg as sla  # noqa: E402

from perturb.model.system import System, gap  # noqa: E402
from perturb.model.system_builtins import builtin_system  # noqa: E402
from perturb.numeric.system_balance import (  # noqa: E402
    SystemBalance,
    system_balance_branch,
    system_balance_orbit,
    system_balance_response,
)
from perturb.simulate.flows.factory import make_flow  # noqa: E402
from perturb.simulate.orbits.shooting import periodic_orbit  # noqa: E402


def timed(fn, repeat: int):
    """(min wall, min CPU, last result) over ``repeat`` runs."""
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return min(walls), min(cpus), out


def nsd2_response(repeat: int) -> None:
    print("== 1. nsd2 whole response, H = 15, window (0.5, 2.0), multipliers at every point")
    for label, params in (
        ("k=-0.5 F=2 (default)", {}),
        ("k=0.3 F=0.6 (folds)", dict(k=0.3, F=0.6)),
    ):
        system = builtin_system("nsd2").with_params(**params)
        w, c, sb = timed(lambda system=system: SystemBalance(system, 15), 1)
        print(f"  {label}: set-up {w * 1e3:.1f} ms")
        for stab in (False, True):
            w, c, br = timed(
                lambda system=system, sb=sb, stab=stab: system_balance_branch(
                    system, (0.5, 2.0), balance=sb, stability=stab
                ),
                repeat,
            )
            print(
                f"    stability={stab!s:5}: {len(br)} points, folds {len(br.folds)}, "
                f"CPU {c:.3f} s (wall {w:.3f} s) "
                f"({br.curve.residual_evaluations} residual evaluations)"
            )


def nsd2_every_branch(repeat: int) -> None:
    print("== 1b. nsd2 every branch (system_balance_response), H = 15, multipliers everywhere")
    system = builtin_system("nsd2")
    sb = SystemBalance(system, 15)
    _, c1, br = timed(
        lambda: system_balance_branch(system, (0.5, 2.0), balance=sb, stability=True), repeat
    )
    print(f"  one branch (0.5, 2.0): {len(br)} points, CPU {c1:.3f} s")
    for window in ((0.5, 2.0), (0.62, 0.75), (0.3, 1.5), (0.2, 2.0)):
        w, c, r = timed(
            lambda window=window: system_balance_response(system, window, balance=sb), repeat
        )
        pts = sum(len(b) for b in r.branches)
        desc = ", ".join(
            f"{o}{' loop' if cl else ''} {b.Omega.min():.4f}..{b.Omega.max():.4f}"
            for o, cl, b in zip(r.origins, r.closed(), r.branches, strict=True)
        )
        ratio = f" = {c / c1:.2f}x the one-branch trace" if window == (0.5, 2.0) else ""
        print(
            f"  every branch {window}: {len(r)} branches, {pts} points, CPU {c:.3f} s "
            f"(wall {w:.3f} s){ratio}\n    [{desc}]"
        )


def _load_module(path: str):
    """A copy of an older ``system_balance.py`` as a module of its own (its imports of the
    package resolve to the current tree)."""
    spec = importlib.util.spec_from_file_location("perturb.numeric._bench_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def _same_response(a, b) -> bool:
    if len(a.branches) != len(b.branches) or a.origins != b.origins:
        return False
    for x, y in zip(a.branches, b.branches, strict=True):
        mx, my = x.max_multiplier, y.max_multiplier
        if not (
            np.array_equal(x.Omega, y.Omega)
            and np.array_equal(x.U, y.U)
            and (mx is None) == (my is None)
            and (mx is None or np.array_equal(mx, my))
        ):
            return False
    return True


def nsd2_default_call(repeat: int, baseline: str | None) -> None:
    """The call of issue 16's target as a user makes it, this module against a baseline copy
    (alternating, minimum of ``repeat`` runs each)."""
    print(
        "== 1b'. system_balance_response(builtin_system('nsd2'), window, harmonics=15) as called "
        "(SystemBalance built inside), CPU min of runs, calls alternating"
    )
    mods = [("current", sys.modules[system_balance_response.__module__])]
    if baseline:
        mods.insert(0, ("baseline", _load_module(baseline)))
    system = builtin_system("nsd2")
    for window in ((0.5, 2.0), (0.62, 0.75), (0.3, 1.5), (0.2, 2.0)):
        for attractors in (True, False):
            best = {name: np.inf for name, _ in mods}
            out = {}
            for mod in (m for _, m in mods):  # warm-up: SymPy/lambdify caches of the system
                mod.system_balance_response(system, window, harmonics=15, attractors=attractors)
            for _ in range(repeat):
                for name, mod in mods:
                    c0 = time.process_time()
                    out[name] = mod.system_balance_response(
                        system, window, harmonics=15, attractors=attractors
                    )
                    best[name] = min(best[name], time.process_time() - c0)
            cur = out["current"]
            line = (
                f"  {window} attractors={attractors!s:5}: {len(cur)} branches, "
                f"{sum(len(b) for b in cur.branches)} points, CPU {best['current']:.3f} s"
            )
            if baseline:
                same = _same_response(out["baseline"], cur)
                line += (
                    f"; baseline {len(out['baseline'])} branches, CPU {best['baseline']:.3f} s "
                    f"(current/baseline {best['current'] / best['baseline']:.2f}); "
                    f"responses identical: {same}"
                )
            print(line)
    print("  load average after: " + " ".join(f"{v:.2f}" for v in os.getloadavg()))


def stability_cost(repeat: int) -> None:
    print("== 1c. stability per point: monodromy (the method used) vs a Hill matrix")
    system = builtin_system("nsd2")
    sb = SystemBalance(system, 15)
    br = system_balance_branch(system, (0.5, 2.0), balance=sb, stability=False)
    Us, Ws = br.U.reshape(len(br), -1), br.Omega
    c_one, _ = timed(lambda: [sb.multipliers(Us[p], Ws[p]) for p in range(len(br))], repeat)[1:]
    c_branch, _ = timed(lambda: sb._max_multipliers(Us, Ws), repeat)[1:]
    # Hill: eigenvalues of the first-order Hill matrix (2 x unknowns square); the eigenvalue
    # problem alone, its assembly left out -- a lower bound of its cost
    n = 2 * sb.n_unknowns
    A = np.random.default_rng(1).standard_normal((n, n))
    _, c_hill, _ = timed(lambda: np.linalg.eigvals(A), repeat)
    print(
        f"  {len(br)} points, H = 15: monodromy per point {c_one / len(br) * 1e3:.3f} ms "
        f"(one point at a time), {c_branch / len(br) * 1e3:.3f} ms (crossings of the whole "
        f"branch at once, as system_balance_response does); Hill eigenvalues of a {n} x {n} "
        f"matrix alone {c_hill * 1e3:.2f} ms ({c_hill / (c_branch / len(br)):.0f}x)"
    )


def _peak(x):
    i = int(np.argmax(np.abs(x)))
    n = x.size
    a, b, c = x[(i - 1) % n], x[i], x[(i + 1) % n]
    den = a - 2 * b + c
    d = 0.5 * (a - c) / den if den != 0 else 0.0
    return abs(b - 0.25 * (a - c) * d)


def accuracy(Hs) -> None:
    print("== 2. nsd2 at Omega = 1.2: |max|x_j|_HB - max|x_j|_exact| (exact, AFT 4H+1, floor)")
    system = builtin_system("nsd2")
    W = 1.2
    ref = system_balance_orbit(system, W, harmonics=15, stability=False)
    flow = make_flow(system.with_params(Omega=W), W)
    orb = periodic_orbit(flow, ref.state(0.0))
    N = 2**14
    T = 2 * np.pi / W
    Y = np.asarray(flow(orb.y0, 0.0, T, t_eval=np.arange(N) * T / N).ys)[:, :2]
    exact = [_peak(Y[:, j]) for j in range(2)]
    print(f"  exact orbit {orb.stability}, max|x1| = {exact[0]:.10f}, max|x2| = {exact[1]:.10f}")
    print("    H   x1 exact     x1 AFT       x1 floor  |  x2 exact     x2 AFT       x2 floor")
    for H in Hs:
        guess = np.zeros((2, 2 * H + 1))
        k = min(2 * H + 1, ref.U.shape[1])
        guess[:, :k] = ref.U[:, :k]
        line = f"  {H:3d}"
        errs = {}
        for proj in ("exact", "aft"):
            try:
                sol = system_balance_orbit(
                    system, W, harmonics=H, guess=guess, stability=False, projection=proj
                )
                a = sol.max_abs()
                errs[proj] = [abs(a[c] - exact[j]) for j, c in enumerate(("x1", "x2"))]
            except Exception:  # noqa: BLE001 -- a benchmark row, not a result
                errs[proj] = [float("nan")] * 2
        for j in range(2):
            X = np.fft.rfft(Y[:, j])
            X[H + 1 :] = 0
            floor = abs(_peak(np.fft.irfft(X, n=N)) - exact[j])
            line += f"   {errs['exact'][j]:.3e}    {errs['aft'][j]:.3e}    {floor:.3e}"
            if j == 0:
                line += "  |"
        print(line)


def chain(n: int) -> System:
    """n unit masses, springs 1 to ground and 0.5 between neighbours, damping 0.05 per mass,
    a gap (clearance 0.2, stiffness 2) on each mass's displacement relative to its left
    neighbour (ground for the first), F = 0.05 cos(W t) on the first mass."""
    K = np.zeros((n, n))
    for i in range(n):
        K[i, i] += 1.0
        if i + 1 < n:
            K[i, i] += 0.5
            K[i + 1, i + 1] += 0.5
            K[i, i + 1] -= 0.5
            K[i + 1, i] -= 0.5
    names = [f"x{i + 1}" for i in range(n)]
    els = [gap("x1", 0.2, 4.0)] + [
        gap(f"{names[i]} - {names[i - 1]}", 0.2, 4.0) for i in range(1, n)
    ]
    forcing = ["0.05*cos(Omega*t)"] + ["0"] * (n - 1)
    return System.from_matrices(
        np.eye(n).tolist(),
        (0.05 * np.eye(n)).tolist(),
        K.tolist(),
        elements=els,
        forcing=forcing,
        coordinates=names,
        params={"Omega": 1.1},
        name=f"chain{n}",
    )


W_CHAIN = 1.1


def chain_table(ns, Hs, repeat: int, response_limit: int, W: float = W_CHAIN) -> None:
    print(f"== 3. chain of n masses, one gap each: CPU ms per operation at W = {W}")
    print(
        "    n    H  unknowns  assemble-dense  assemble-sparse  dense-LU  sparse-Newton-solve"
        "  response(points, s)"
    )
    for n in ns:
        w0 = time.perf_counter()
        system = chain(n)
        build = time.perf_counter() - w0
        for H in Hs:
            sb = SystemBalance(system, H)
            u = sb.solve(W)
            # CPU times (process_time): wall time on a shared machine includes waiting for a core
            # a new point each call: the balance keeps the last projections of each element
            calls = iter(range(1, 10**6))

            def fresh(u=u, calls=calls):
                return u * (1.0 + 1e-12 * next(calls))

            _, td, J = timed(lambda sb=sb, W=W, f=fresh: sb.evaluate(f(), W)[1], repeat)
            _, ts, _ = timed(
                lambda sb=sb, W=W, f=fresh: sb.evaluate(f(), W, sparse=True)[1], repeat
            )
            _, tl, _ = timed(lambda J=J: sla.lu_factor(J), repeat)
            _, tn, _ = timed(lambda sb=sb, u=u, W=W: sb.solve(W, u * 1.01), repeat)
            resp = "-"
            if sb.n_unknowns <= response_limit:
                ev0 = sb.evaluations
                _, tr, br = timed(
                    lambda sb=sb, system=system: system_balance_branch(
                        system, (0.8, 1.3), balance=sb, stability=True
                    ),
                    1,
                )
                ev = sb.evaluations - ev0
                resp = (
                    f"{len(br)} pts, {ev} evals, {tr:.2f} s, {tr / ev * 1e3:.1f} ms/eval "
                    f"(multipliers included)"
                )
            print(
                f"  {n:3d} {H:4d} {sb.n_unknowns:9d} {td * 1e3:14.2f} {ts * 1e3:16.2f} "
                f"{tl * 1e3:9.2f} {tn * 1e3:20.2f}  {resp}"
            )
        print(f"       (System.from_matrices for n = {n}: {build:.2f} s, not in the table)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="n <= 8, H <= 15, no H = 63")
    ap.add_argument(
        "--parts", default="1,1b,1c,2,3", help="comma-separated parts to run (1,1b,1c,2,3)"
    )
    ap.add_argument(
        "--baseline",
        default=None,
        help="a copy of an older perturb/numeric/system_balance.py timed beside (part 1b)",
    )
    args = ap.parse_args(argv)
    parts = {p.strip() for p in args.parts.split(",")}
    print(
        f"python {sys.version.split()[0]}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"{platform.machine()}, {os.cpu_count()} cpus, load average "
        + " ".join(f"{v:.2f}" for v in os.getloadavg())
    )
    if "1" in parts:
        nsd2_response(args.repeat)
    if "1b" in parts:
        nsd2_every_branch(args.repeat)
        nsd2_default_call(args.repeat, args.baseline)
    if "1c" in parts:
        stability_cost(args.repeat)
    if "2" in parts:
        accuracy((1, 3, 7, 15, 31) if args.quick else (1, 3, 7, 15, 31, 63))
    if "3" in parts:
        ns = (2, 4, 8) if args.quick else (2, 4, 8, 16, 32)
        chain_table(ns, (3, 7, 15), args.repeat, 300 if args.quick else 500)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
