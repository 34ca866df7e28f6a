"""Benchmark: pyHarm-os next to perturb's multi-harmonic balance on a 2-DOF system with a gap.

Reproduce with (pyHarm-os lives in a separate venv; it is never a dependency of perturb)::

    python -m venv /tmp/aftvenv --system-site-packages
    /tmp/aftvenv/bin/pip install pyharm-os
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_pyharm_nd.py \
        [--repeat 3] [--nti 481 1025] [--points 16] [--timeout 120] \
        [--venv-python /tmp/aftvenv/bin/python]

The table is written to ``benchmarks/results/bench_pyharm_nd.md`` by hand from the output.

Problem
-------
pyHarm's own examples with a gap are its non-regression cases ``onedofgap`` (one DOF, a
``PenaltyUnilateralGap`` to ground) and ``yx`` (a rotor whose ``PenaltyBilateralGap`` acts on
two directions at once: a circular clearance, the norm of a 2-D displacement, which is no
scalar piecewise-linear force and which perturb does not model). The system here is the
``onedofgap`` contact on a chain of two coordinates, built from the elements those examples
use (``GOElement`` masses, ``LinearSpring``, ``LinearDamper``, ``PenaltyUnilateralGap``,
``CosinusForcing``, two ``onlydofs`` substructures)::

    x1'' + c x1' + c (x1' - x2') + k x1 + k (x1 - x2)                  = F cos(W t)
    x2'' + c (x2' - x1') + k (x2 - x1) + kg (x2 - g) H(x2 - g)         = 0

``c = 0.02``, ``k = 1``, ``F = 0.3``, contact (one-sided: only for ``x2 > g``) ``g = 1``,
``kg = 10`` (``--kg``; 100 as a second case): linear modes at W = 0.618 and 1.618, the second
mass hits the stop near both; window W = 0.3 .. 2.2, H = 15. In perturb the contact is
``pwl_spring("x2", [g], [0, kg])``: the same ``kg (s - g) H(s - g)`` as pyHarm's
``PenaltyUnilateralGap`` (contact where ``x2 >= g``).

* perturb, in this process: ``system_balance_branch`` (the branch from the high end
  downwards, the analogue of pyHarm's trace) and ``system_balance_response`` (every branch in
  the window: seeds, branch points, mirrors), exact Galerkin projection of the contact force,
  exact Jacobians, Floquet multipliers (stability) at every point, default settings
  (``ds_max = 0.05``, ``tol = 1e-9``); the branch also with ``ds_max = 0.1, 0.2`` (its point
  density, the same knob as pyHarm's ``ds``). The ``SystemBalance`` set-up (SymPy, once per call)
  is inside the time.
* pyHarm-os (``pyHarm.Maestro``) in a subprocess of the venv that stays alive between runs
  (so its numba compilation is paid once, as in a session; the cold first run is reported
  apart): AFT with ``nti`` time samples, analytic Jacobians, its ``frf`` study from
  ``puls_sup`` downwards (its default start: the linear solution there), pseudo-arclength
  corrector, tangent predictor, step ``ds`` (its unscaled coordinates) for several ``ds``
  (the point density of its curve is the only accuracy knob besides ``nti``). No stability.

Runs are interleaved (perturb, then each pyHarm setting, ``--repeat`` times); each run is
capped at ``--timeout`` s of wall time (SIGALRM in the worker, a kill from here if it does not
answer). Times: CPU (``time.process_time`` in the process that computes) and wall, minimum
over the repeats; load average printed before and after.

Errors (relative, per coordinate, against exact orbits: shooting on the exact
piecewise-linear flow, an independent solver):

* ``curve``: the response as delivered, at the check frequencies: max|x_j| of every crossing
  of the curve with W (linear interpolation between its points) against the nearest exact
  orbit there (``perturb.frequency_response(system, "exact", frequencies=CHECK)``, every
  exact orbit found at each W) -- point density counts here;
* ``point``: the HB orbit itself, at nearly the same W for every run: on each curve the
  points nearest to ``--points`` frequencies spread over the window; the exact orbit shot from
  the HB state at that point's own W (``periodic_orbit(make_flow(...), y0)``; a shot that
  lands on another orbit is counted as failed), max|x_j| of the HB series against the exact
  orbit's (2^14 samples, parabolic peak): the truncation (and, for AFT, sampling) error. Beside
  it the worst ratio to the truncation floor (the exact orbit's series cut at H): ~1 for the
  coordinate that carries the contact; x1 carries none, its own series converges much faster
  and its HB error is the one propagated from x2, so its ratio is large for every method.
  The stability flags of perturb are compared with the exact orbits' at the same points.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import json  # noqa: E402
import select  # noqa: E402
import shutil  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

C, K, F = 0.02, 1.0, 0.3
GAP, KG = 1.0, 10.0
WINDOW = (0.3, 2.2)
H = 15
SAMPLES = 32 * H + 1  # AFT time samples for pyHarm (as bench_aft_packages: 481)
CHECK = (0.5, 0.62, 0.9, 1.3, 1.62, 2.0)
PYHARM_DS = (0.5, 0.2, 0.1, 0.05, 0.02)
PERTURB_DS_MAX = (0.1, 0.2)  # besides the default 0.05
COORDS = ("x1", "x2")
# "as accurate": within 10 % (the point errors of both sit at the truncation floor, where the
# sampled points' scatter is of that order)
ACCURACY_SLACK = 1.1


# --------------------------------------------------------------------------- pyHarm worker --
def pyharm_problem(ds: float, nti: int, kg: float = KG) -> dict:
    """The pyHarm input dictionary of the system (two one-node ``onlydofs`` substructures)."""

    def node() -> dict:
        return {"type": "onlydofs", "ndofs": 1, "nnodes": 1}

    def on(*subs: str) -> dict:
        return {"connect": {s: [0] for s in subs}, "dirs": [0]}

    return {
        "system": {"type": "Base", "nh": H, "nti": nti},
        "substructures": {"m1": node(), "m2": node()},
        "connectors": {
            "mass1": {"type": "GOElement", "dto": 2, "xo": 1, "k": 1.0, **on("m1")},
            "mass2": {"type": "GOElement", "dto": 2, "xo": 1, "k": 1.0, **on("m2")},
            "spring1": {"type": "LinearSpring", "k": K, **on("m1")},
            "spring12": {"type": "LinearSpring", "k": K, **on("m1", "m2")},
            "damper1": {"type": "LinearDamper", "k": C, **on("m1")},
            "damper12": {"type": "LinearDamper", "k": C, **on("m1", "m2")},
            "contact": {"type": "PenaltyUnilateralGap", "g": GAP, "k": kg, **on("m2")},
            "force": {"type": "CosinusForcing", "amp": F, **on("m1")},
        },
        "analysis": {
            "frf": {
                "study": "frf",
                "puls_inf": WINDOW[0],
                "puls_sup": WINDOW[1],
                "sign_ds": -1,
                "ds0": ds,
                "ds_max": ds,
                "ds_min": 1e-6,
                "corrector": "pseudo_arc_length",
                "predictor": "tangent",
                "stopper": "solnumber",
                "stopper_options": {"max_solutions": 20000},
                "verbose": False,
            }
        },
    }


class _Timeout(BaseException):
    pass


def _alarm(signum, frame):
    raise _Timeout


def worker() -> None:
    """Serve pyHarm runs: read ``ds nti timeout kg path`` lines, answer one JSON line each.

    The coefficients of the accepted points go to ``path`` (``.npy``: one row per point, the
    coefficients of x1 then x2, ``[a0, a1, b1, ...]``, then W).
    """
    import logging
    from importlib.metadata import version as _version

    import pyHarm

    version = f"pyHarm-os {_version('pyHarm-os')}, numba {_version('numba')}"
    logging.disable(logging.WARNING)
    import warnings

    warnings.simplefilter("ignore")
    for line in sys.stdin:
        ds_s, nti_s, timeout_s, kg_s, path = line.split()
        ds, nti, timeout, kg = float(ds_s), int(nti_s), float(timeout_s), float(kg_s)
        old = signal.signal(signal.SIGALRM, _alarm)
        signal.setitimer(signal.ITIMER_REAL, timeout)
        t, c = time.perf_counter(), time.process_time()
        reason = ""
        try:
            M = pyHarm.Maestro(pyharm_problem(ds, nti, kg))
            with contextlib.redirect_stdout(io.StringIO()):
                M.operate()
            sols = [s.x.copy() for s in M.nls["frf"].SolList if s.flag_accepted]
        except _Timeout:
            sols, reason = None, f"stopped after {timeout:g} s"
        except Exception as exc:  # noqa: BLE001 -- the package's own failure is a result here
            sols, reason = None, f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, old)
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        n = 0
        if sols:
            X = np.array(sols)
            # pyHarm interleaves the dofs: coefficient i of dof d at index d + 2 i
            rows = np.hstack([X[:, 0:-1:2], X[:, 1:-1:2], X[:, -1:]])
            np.save(path, rows)
            n = len(sols)
        ans = {"wall": wall, "cpu": cpu, "n": n, "reason": reason, "version": version}
        print(json.dumps(ans), flush=True)


class PyHarmWorker:
    """A live pyHarm worker process in the venv, with a wall-time cap on every answer."""

    def __init__(self, python: str) -> None:
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
        self.proc = subprocess.Popen(
            [python, os.path.abspath(__file__), "--worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        self.tmp = tempfile.mkdtemp(prefix="bench_pyharm_nd_")
        self.count = 0
        self.version = "?"

    def run(self, ds: float, nti: int, timeout: float, kg: float = KG):
        """``(rows or None, wall, cpu, reason)`` of one pyHarm frf run."""
        self.count += 1
        path = os.path.join(self.tmp, f"run{self.count}.npy")
        if self.proc.poll() is not None:
            return None, float("nan"), float("nan"), "worker not running"
        try:
            self.proc.stdin.write(f"{ds} {nti} {timeout} {kg!r} {path}\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            return None, float("nan"), float("nan"), "worker exited (pyHarm-os not importable?)"
        # the worker's own alarm stops a run; this cap also covers imports and a hung worker
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout + 120.0)
        if not ready:
            self.close()
            return None, float("nan"), float("nan"), "worker did not answer: killed"
        line = self.proc.stdout.readline()
        if not line:
            return None, float("nan"), float("nan"), "worker exited (pyHarm-os not importable?)"
        ans = json.loads(line)
        self.version = ans.get("version", "?")
        rows = np.load(path) if ans["n"] else None
        return rows, ans["wall"], ans["cpu"], ans["reason"]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        shutil.rmtree(self.tmp, ignore_errors=True)


# --------------------------------------------------------------------------- perturb side --
def build_system(kg: float = KG):
    from perturb.model.system import System, pwl_spring

    return System.from_matrices(
        [[1.0, 0.0], [0.0, 1.0]],
        [[2 * C, -C], [-C, C]],
        [[2 * K, -K], [-K, K]],
        elements=[pwl_spring("x2", [GAP], [0, kg], name="contact")],
        forcing=[f"{F}*cos(Omega*t)", "0"],
        coordinates=list(COORDS),
        params={"Omega": 1.0},
        name="chain2_contact",
    )


def max_abs_series(c: np.ndarray) -> float:
    """max |x| of ``a0 + sum a_k cos k t + b_k sin k t`` (``c = [a0, a1, b1, ...]``): dense grid,
    then Newton on the extrema."""
    a, b = c[1::2], c[2::2]
    k = np.arange(1, a.size + 1)
    t = np.linspace(0, 2 * np.pi, 4096, endpoint=False)
    x = c[0] + np.cos(np.outer(t, k)) @ a + np.sin(np.outer(t, k)) @ b
    best = 0.0
    for j in (int(np.argmax(x)), int(np.argmin(x))):
        s = t[j]
        for _ in range(6):
            d1 = -np.sin(k * s) @ (k * a) + np.cos(k * s) @ (k * b)
            d2 = -np.cos(k * s) @ (k * k * a) - np.sin(k * s) @ (k * k * b)
            if d2 != 0:
                s -= d1 / d2
        best = max(best, abs(c[0] + np.cos(k * s) @ a + np.sin(k * s) @ b))
    return best


class Curve:
    """One HB curve: frequencies ``W`` and coefficients ``coef[point, coordinate, :]``."""

    def __init__(self, W: np.ndarray, coef: np.ndarray, stable=None) -> None:
        self.W = np.asarray(W, dtype=float)
        self.coef = np.asarray(coef, dtype=float)
        self.stable = None if stable is None else np.asarray(stable, dtype=bool)
        self.amp = np.array([[max_abs_series(c) for c in pt] for pt in self.coef])

    def state(self, i: int) -> np.ndarray:
        """``(q(0), q'(0))`` of point ``i`` (theta = W t, m = 1)."""
        c = self.coef[i]
        k = np.arange(1, (c.shape[1] - 1) // 2 + 1)
        q = c[:, 0] + c[:, 1::2].sum(axis=1)
        v = self.W[i] * (c[:, 2::2] @ k)
        return np.concatenate([q, v])


def pyharm_curve(rows: np.ndarray) -> Curve:
    n = (rows.shape[1] - 1) // 2
    coef = np.stack([rows[:, :n], rows[:, n : 2 * n]], axis=1)
    return Curve(rows[:, -1], coef)


def perturb_curves(result) -> list[Curve]:
    branches = [result] if hasattr(result, "U") else list(result)
    return [Curve(b.Omega, b.U, b.stable) for b in branches]


def exact_at_checks(system) -> dict[float, np.ndarray]:
    """Every exact orbit at each check frequency: ``{W: array (orbits, coordinates)}``."""
    import perturb

    with contextlib.redirect_stderr(io.StringIO()):
        ex = perturb.frequency_response(system, "exact", frequencies=list(CHECK))
    out: dict[float, list] = {W: [] for W in CHECK}
    for br, cols in zip(ex.branches, ex.columns, strict=True):
        for i, W in enumerate(br.omega):
            Wc = min(CHECK, key=lambda c: abs(c - W))
            out[Wc].append([float(cols[f"amplitude_{c}"][i]) for c in COORDS])
    return {W: np.array(v) for W, v in out.items()}


def curve_errors(curves: list[Curve], exact: dict[float, np.ndarray]) -> tuple[float, ...]:
    """Worst relative error per coordinate at the check frequencies (inf if some W is missed)."""
    worst = np.zeros(len(COORDS))
    for W, refs in exact.items():
        vals = []
        for cv in curves:
            seg = np.nonzero((cv.W[:-1] - W) * (cv.W[1:] - W) <= 0)[0]
            for i in seg:
                d = cv.W[i + 1] - cv.W[i]
                f = 0.0 if d == 0 else (W - cv.W[i]) / d
                vals.append((1 - f) * cv.amp[i] + f * cv.amp[i + 1])
        if not vals or refs.size == 0:
            worst[:] = np.inf
            continue
        for v in vals:
            # each crossing against the exact orbit nearest to it (exact orbits on branches the
            # curve does not trace are not charged)
            j = int(np.argmin(np.abs(refs - v).sum(axis=1)))
            worst = np.maximum(worst, np.abs(v - refs[j]) / refs[j])
    return tuple(worst)


def _peak(x: np.ndarray) -> float:
    i = int(np.argmax(np.abs(x)))
    n = x.size
    a, b, c = x[(i - 1) % n], x[i], x[(i + 1) % n]
    den = a - 2 * b + c
    d = 0.5 * (a - c) / den if den != 0 else 0.0
    return abs(b - 0.25 * (a - c) * d)


def point_errors(
    system, curves: list[Curve], count: int
) -> tuple[tuple[float, ...], tuple[float, ...], int]:
    """HB orbits against exact orbits at the same W, at the points of the curves nearest to
    ``count`` frequencies spread evenly over the window (so that every run is sampled at nearly
    the same W; one point per curve and frequency).

    Returns the worst relative error per coordinate of the HB max|x_j| against the exact orbit
    shot from the HB state; the worst ratio of that error to the truncation floor (the exact
    orbit's Fourier series cut at H, against the exact max; floors below 1e-9 of the max count
    as 1e-9: an orbit that stays off the contact is linear, and HB then exact to rounding); and
    the number of points whose shooting failed or converged to another orbit; and ``(agree,
    compared)``: HB stability flags (where the curve has them) that agree with the exact
    orbit's ('stable' / 'unstable'; points the shooting classifies otherwise, at a fold, are
    not compared).
    """
    from perturb.simulate.flows.factory import make_flow
    from perturb.simulate.orbits.shooting import periodic_orbit

    worst = np.zeros(len(COORDS))
    ratio = np.zeros(len(COORDS))
    failed = agree = compared = 0
    N = 2**14
    width = WINDOW[1] - WINDOW[0]
    for cv in curves:
        picks = set()
        for target in np.linspace(WINDOW[0], WINDOW[1], count):
            i = int(np.argmin(np.abs(cv.W - target)))
            if abs(cv.W[i] - target) <= 0.5 * width / count:
                picks.add(i)
        for i in sorted(picks):
            W = float(cv.W[i])
            y0 = cv.state(i)
            try:
                flow = make_flow(system.with_params(Omega=W), W)
                orb = periodic_orbit(flow, y0)
                T = 2 * np.pi / W
                Y = np.asarray(flow(orb.y0, 0.0, T, t_eval=np.arange(N) * T / N).ys)
            except Exception:  # noqa: BLE001 -- counted, not hidden
                failed += 1
                continue
            if np.linalg.norm(orb.y0 - y0) > 0.05 * (1.0 + np.linalg.norm(y0)):
                failed += 1  # another orbit: not this HB point's
                continue
            if cv.stable is not None and orb.stability in ("stable", "unstable"):
                compared += 1
                agree += bool(cv.stable[i]) == (orb.stability == "stable")
            for j in range(len(COORDS)):
                ex = _peak(Y[:, j])
                X = np.fft.rfft(Y[:, j])
                X[H + 1 :] = 0
                floor = max(abs(_peak(np.fft.irfft(X, n=N)) - ex), 1e-9 * ex)
                err = abs(cv.amp[i, j] - ex)
                worst[j] = max(worst[j], err / ex)
                ratio[j] = max(ratio[j], err / floor)
    return tuple(worst), tuple(ratio), failed, (agree, compared)


def summary(stats) -> None:
    """Speed-up at equal or better accuracy: for each perturb run, the fastest pyHarm run whose
    curve and point errors are at most ``ACCURACY_SLACK`` times perturb's in every coordinate
    (else a lower bound from the pyHarm run with the smallest curve error)."""
    ph = {k: v for k, v in stats.items() if k.startswith("pyHarm")}
    for name, (cpu, ce, pe) in stats.items():
        if name.startswith("pyHarm") or not ph:
            continue
        ok = [
            (c, k)
            for k, (c, e, p) in ph.items()
            if all(a <= ACCURACY_SLACK * b for a, b in zip(e + p, ce + pe, strict=True))
        ]
        if ok:
            c, k = min(ok)
            print(f"{name}: {c / cpu:.1f}x less CPU than {k}, the fastest pyHarm run as accurate")
            continue
        k = min(ph, key=lambda k: max(ph[k][1]))
        c, e, p = ph[k]
        print(
            f"{name}: no pyHarm run is as accurate (curve {max(ce):.1e}, point {max(pe):.1e}); "
            f"the one with the smallest curve error, {k} (curve {max(e):.1e}, point "
            f"{max(p):.1e}), takes {c / cpu:.1f}x its CPU (a lower bound at equal accuracy)"
        )


# ------------------------------------------------------------------------------------ main --
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=120.0, help="wall seconds per pyHarm run")
    ap.add_argument("--kg", type=float, default=KG, help="contact stiffness (default 10)")
    ap.add_argument("--venv-python", default="/tmp/aftvenv/bin/python")
    ap.add_argument("--points", type=int, default=16, help="frequencies for 'point' errors")
    ap.add_argument(
        "--nti",
        type=int,
        nargs="+",
        default=[SAMPLES, 1025],
        help="pyHarm AFT time samples (each; 1025 about pyHarm's onedofgap 1024)",
    )
    args = ap.parse_args()
    if args.worker:
        worker()
        return
    if not 1 <= args.repeat <= 20:
        ap.error(f"--repeat {args.repeat}: expected 1..20")
    if not 0 < args.kg < 1e6:
        ap.error(f"--kg {args.kg}: expected a contact stiffness in (0, 1e6)")
    from perturb.numeric.system_balance import system_balance_branch, system_balance_response

    print(
        "command: OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/bench_pyharm_nd.py "
        f"--repeat {args.repeat} --nti {' '.join(map(str, args.nti))} --kg {args.kg:g}"
    )
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (start)")
    system = build_system(args.kg)
    ours = {
        "perturb branch (one trace)": lambda: system_balance_branch(
            system, WINDOW, harmonics=H, direction=-1, stability=True
        ),
        "perturb response (every branch)": lambda: system_balance_response(
            system, WINDOW, harmonics=H, stability=True
        ),
    }
    # perturb's own accuracy knob (the step cap of the continuation), for equal-accuracy pairs
    for cap in PERTURB_DS_MAX:
        ours[f"perturb branch, ds_max={cap:g}"] = lambda cap=cap: system_balance_branch(
            system, WINDOW, harmonics=H, direction=-1, stability=True, ds_max=cap
        )
    ph = PyHarmWorker(args.venv_python)
    try:
        rows, wall, cpu, why = ph.run(PYHARM_DS[0], args.nti[0], args.timeout + 300.0, args.kg)
        import scipy

        print(
            f"python {sys.version.split()[0]}, numpy {np.__version__}, scipy {scipy.__version__}"
            f"; worker: {ph.version}"
        )
        print(
            f"pyHarm cold first run (imports, numba compile or cache load): wall {wall:.2f} s, "
            f"CPU {cpu:.2f} s {why}"
        )
        times: dict[str, list[tuple[float, float]]] = {}
        results: dict[str, object] = {}
        notes: dict[str, str] = {}
        for fn in ours.values():
            fn()  # warm: imports, first lambdify caches
        for _ in range(args.repeat):
            for name, fn in ours.items():
                w0, c0 = time.perf_counter(), time.process_time()
                res = fn()
                times.setdefault(name, []).append(
                    (time.perf_counter() - w0, time.process_time() - c0)
                )
                results[name] = res
            for nti, ds in ((n, d) for n in args.nti for d in PYHARM_DS):
                name = f"pyHarm AFT {nti}, ds={ds:g}"
                rows, wall, cpu, why = ph.run(ds, nti, args.timeout, args.kg)
                times.setdefault(name, [])
                if np.isfinite(cpu):
                    times[name].append((wall, cpu))
                if rows is not None:
                    results[name] = rows
                if why:
                    notes[name] = why
    finally:
        ph.close()
    print(f"load average {os.getloadavg()[0]:.2f} (after the timed runs)")

    exact = exact_at_checks(system)
    print(
        "exact orbits at the check frequencies (W: max|x1|, max|x2| of each): "
        + "; ".join(
            f"{W}: " + ", ".join(f"({a[0]:.4f}, {a[1]:.4f})" for a in v) for W, v in exact.items()
        )
    )
    base = min(c for _, c in times["perturb response (every branch)"])
    one = min(c for _, c in times["perturb branch (one trace)"])
    print(
        "\n| run | points | W reached | stability | CPU s | wall s | CPU / perturb branch "
        "| CPU / perturb response | curve err x1 | curve err x2 | point err x1 | point err x2 "
        "| point err / floor x1 | x2 |"
    )
    print("|" + "---|" * 14)
    stats: dict[str, tuple[float, tuple[float, ...], tuple[float, ...]]] = {}
    for name, tw in times.items():
        cpu = min((c for _, c in tw), default=float("nan"))
        wall = min((w for w, _ in tw), default=float("nan"))
        if name not in results:
            print(f"| {name} | - | - | - | {cpu:.3f} | {wall:.3f} | | | {notes.get(name, '')} |")
            continue
        res = results[name]
        curves = pyharm_curve(res) if name.startswith("pyHarm") else None
        curves = [curves] if curves is not None else perturb_curves(res)
        npts = sum(len(c.W) for c in curves)
        lo = min(c.W.min() for c in curves)
        hi = max(c.W.max() for c in curves)
        ce = curve_errors(curves, exact)
        pe, pr, failed, (agree, compared) = point_errors(system, curves, args.points)
        if name.startswith("pyHarm"):
            stab = "none"
        else:
            n_st = sum(int(c.stable.sum()) for c in curves)
            stab = (
                f"Floquet, every point ({n_st} stable, {npts - n_st} unstable; agrees with the "
                f"exact orbit at {agree}/{compared} checked)"
            )
        fail = f" ({failed} shots failed)" if failed else ""
        label = name + (f" [{len(curves)} branches]" if len(curves) > 1 else "")
        stats[name] = (cpu, ce, pe)
        print(
            f"| {label} | {npts} | {lo:.3f}..{hi:.3f} | {stab} | {cpu:.3f} | {wall:.3f} | "
            f"{cpu / one:.1f}x | {cpu / base:.2f}x | {ce[0]:.1e} | {ce[1]:.1e} | "
            f"{pe[0]:.1e} | {pe[1]:.1e} | {pr[0]:.2f} | {pr[1]:.2f}{fail} |"
        )
    print(f"\nload average {os.getloadavg()[0]:.2f} (end)")
    summary(stats)


if __name__ == "__main__":
    main()
