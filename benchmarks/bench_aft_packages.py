"""Benchmark: public AFT harmonic-balance packages next to perturb's exact-Galerkin HB.

Reproduce with (the packages live in a separate venv; they are never a dependency)::

    python -m venv /tmp/aftvenv --system-site-packages
    /tmp/aftvenv/bin/pip install pyharm-os harmonicbalance
    OPENBLAS_NUM_THREADS=1 /tmp/aftvenv/bin/python benchmarks/bench_aft_packages.py

Problem: nsd, x'' + 0.05 x' - 0.5 x + 1.5[(x-1)H(x-1) + (x+1)H(-x-1)] = 2 cos(W t), W from 2
down to 0.3, H = 15.

* perturb: ``harmonic_balance_response(osc, (0.3, 2.0), harmonics=15, ds_max=0.04)``: exact
  Galerkin projection, started automatically, Hill stability at every point.
* pyHarm-os (``pyHarm.Maestro``): one DOF with a ``GOElement`` mass (dto 2), ``LinearSpring``
  k = -0.5, ``LinearDamper`` 0.05, ``PenaltyBilateralGap`` g = 1, k = 1.5 (which is exactly the
  nsd force beyond |x| = 1) and ``CosinusForcing`` 2; ``nti = 481`` time samples, analytic
  Jacobians, its ``frf`` study from ``puls_sup = 2`` downwards (its default start: the
  linear solution there, the hand-picked part is the direction, the step and the corrector:
  pseudo-arclength, tangent predictor, ``ds = 0.5`` in its unscaled coordinates, which gives
  ~250 points over this curve of arclength ~127). No stability.
* harmonicbalance (``PredictorCorrectorSolver``): the residual written with its ``Fourier``
  class, the nonlinearity by AFT at ``15*32 + 1 = 481`` samples, a hand-picked start (the
  closed-form response of the inner segment, |x| < 1, at W = 2: the same orbit perturb starts
  from), ``alpha_step = 0.5``, numerical (finite-difference) Jacobians as the package does.
  No stability.

Each package's run is limited to ``--timeout`` seconds of wall time (SIGALRM); what it did is
printed either way. Errors: relative error of max|x| against exact orbits (shooting on the
exact piecewise-linear flow: ``perturb.frequency_response(osc, "exact", frequencies=...)``) at
a few frequencies: each solution of the response there (linear interpolation between its
points) against the nearest exact orbit; "no point" when the response never reaches that
frequency.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import logging  # noqa: E402
import signal  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from perturb.model.builtins import builtin_model  # noqa: E402
from perturb.numeric.harmonic_balance import harmonic_balance_response  # noqa: E402

K, MU, F = -0.5, 0.05, 2.0
WINDOW = (0.3, 2.0)
H = 15
SAMPLES = 481
CHECK = (0.6, 0.9, 1.5)


class _Timeout(BaseException):
    pass


def _alarm(signum, frame):
    raise _Timeout


def run_limited(fn, timeout: float):
    """``(result or None, wall, cpu, reason)`` of ``fn()`` stopped after ``timeout`` s."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    t, c = time.perf_counter(), time.process_time()
    try:
        out, reason = fn(), ""
    except _Timeout:
        out, reason = None, f"stopped after {timeout:g} s"
    except Exception as exc:  # a package's own failure is a result here
        out, reason = None, f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, old)
    return out, time.perf_counter() - t, time.process_time() - c, reason


def max_abs(a0: float, a: np.ndarray, b: np.ndarray) -> float:
    """max |x| of ``a0 + sum a_k cos k t + b_k sin k t`` (dense grid, then Newton)."""
    k = np.arange(1, a.size + 1)
    t = np.linspace(0, 2 * np.pi, 8192, endpoint=False)
    x = a0 + np.cos(np.outer(t, k)) @ a + np.sin(np.outer(t, k)) @ b
    best = 0.0
    for j in (int(np.argmax(x)), int(np.argmin(x))):
        s = t[j]
        for _ in range(6):
            d1 = -np.sin(k * s) @ (k * a) + np.cos(k * s) @ (k * b)
            d2 = -np.cos(k * s) @ (k * k * a) - np.sin(k * s) @ (k * k * b)
            if d2 != 0:
                s -= d1 / d2
        best = max(best, abs(a0 + np.cos(k * s) @ a + np.sin(k * s) @ b))
    return best


def errors_at(omega: np.ndarray, amp: np.ndarray, exact: dict[float, list[float]]) -> str:
    out = []
    for W, refs in exact.items():
        seg = np.nonzero((omega[:-1] - W) * (omega[1:] - W) <= 0)[0]
        if seg.size == 0:
            out.append(f"W={W}: no point")
            continue
        vals = []
        for i in seg:
            f = 0.0 if omega[i + 1] == omega[i] else (W - omega[i]) / (omega[i + 1] - omega[i])
            vals.append((1 - f) * amp[i] + f * amp[i + 1])
        # each solution of the response against the exact orbit nearest to it (other exact
        # orbits at W, on branches the response does not trace, are not charged)
        errs = [min(abs(v - r) / r for r in refs) for v in vals]
        out.append(f"W={W}: {max(errs):.1e}")
    return ", ".join(out)


# ---------------------------------------------------------------------------------------------
def run_pyharm(timeout: float):
    try:
        import pyHarm
    except ImportError as exc:
        return None, f"pyHarm-os not importable ({exc}): skipped"
    logging.disable(logging.WARNING)

    def problem():
        return {
            "system": {"type": "Base", "nh": H, "nti": SAMPLES},
            "substructures": {"sub": {"type": "onlydofs", "ndofs": 1, "nnodes": 1}},
            "connectors": {
                "mass": {
                    "type": "GOElement",
                    "connect": {"sub": [0]},
                    "dirs": [0],
                    "dto": 2,
                    "xo": 1,
                    "k": 1.0,
                },
                "spring": {"type": "LinearSpring", "connect": {"sub": [0]}, "dirs": [0], "k": K},
                "damper": {"type": "LinearDamper", "connect": {"sub": [0]}, "dirs": [0], "k": MU},
                "gap": {
                    "type": "PenaltyBilateralGap",
                    "connect": {"sub": [0]},
                    "dirs": [0],
                    "g": 1.0,
                    "k": 1.0 - K,
                },
                "force": {"type": "CosinusForcing", "connect": {"sub": [0]}, "dirs": [0], "amp": F},
            },
            "analysis": {
                "frf": {
                    "study": "frf",
                    "puls_inf": WINDOW[0],
                    "puls_sup": WINDOW[1],
                    "sign_ds": -1,
                    "ds0": 0.5,
                    "ds_max": 0.5,
                    "ds_min": 1e-6,
                    "corrector": "pseudo_arc_length",
                    "predictor": "tangent",
                    "stopper": "solnumber",
                    "stopper_options": {"max_solutions": 2000},
                    "verbose": False,
                }
            },
        }

    def solve():
        M = pyHarm.Maestro(problem())
        with contextlib.redirect_stdout(io.StringIO()):
            M.operate()
        return [s.x.copy() for s in M.nls["frf"].SolList if s.flag_accepted]

    run_limited(solve, timeout)  # numba compilation and caches, as in a session
    sols, wall, cpu, reason = run_limited(solve, timeout)
    if sols is None:
        return None, f"pyHarm-os: {reason}"
    X = np.array(sols)
    omega = X[:, -1]
    amp = np.array([max_abs(x[0], x[1 : 2 * H : 2], x[2 : 2 * H + 1 : 2]) for x in X])
    return (omega, amp, wall, cpu), ""


def run_harmonicbalance(timeout: float):
    try:
        from harmonicbalance.fourier import Fourier
        from harmonicbalance.predictorcorrector import PredictorCorrectorSolver
    except ImportError as exc:
        return None, f"harmonicbalance not importable ({exc}): skipped"

    def force(x):
        return K * x + (1 - K) * (np.maximum(x - 1.0, 0.0) + np.minimum(x + 1.0, 0.0))

    def residual(X):
        fx = X._from_time_domain(force(X._to_time_domain(osr=(SAMPLES - 1) // H)))
        forcing = Fourier(0.0, np.eye(H)[0] * F, np.zeros(H), X.omega, H)
        return X.dt().dt() + MU * X.dt() + fx - forcing

    W0 = WINDOW[1]
    # hand-picked start: at W = 2 the orbit stays inside |x| < 1, where the force is k x, so
    # the closed form of x'' + mu x' + k x = F cos W t is the exact orbit there
    Z = F / complex(K - W0**2, MU * W0)
    X0 = Fourier(0.0, np.eye(H)[0] * Z.real, np.eye(H)[0] * -Z.imag, W0, H)

    def solve():
        pc = PredictorCorrectorSolver(residual, X0, W0, WINDOW[0], 0.5, use_jac=True)
        with contextlib.redirect_stdout(io.StringIO()):
            return [
                (s.omega, s.coeff_dc, s.coeffs_cos.copy(), s.coeffs_sin.copy()) for s in pc.solve()
            ]

    sols, wall, cpu, reason = run_limited(solve, timeout)
    if sols is None:
        return None, f"harmonicbalance: {reason}"
    omega = np.array([s[0] for s in sols])
    amp = np.array([max_abs(s[1], s[2], s[3]) for s in sols])
    return (omega, amp, wall, cpu), ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per package run")
    args = ap.parse_args()
    print(
        "command: OPENBLAS_NUM_THREADS=1 /tmp/aftvenv/bin/python benchmarks/bench_aft_packages.py"
    )
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    import perturb

    osc = builtin_model("nsd", k=K, mu=MU, F=F)
    ex = perturb.frequency_response(osc, "exact", frequencies=list(CHECK))
    exact: dict[float, list[float]] = {W: [] for W in CHECK}
    for br in ex.branches:
        for W, A in zip(br.omega, br.amplitude, strict=True):
            exact[min(CHECK, key=lambda c: abs(c - W))].append(float(A))

    def ours():
        return harmonic_balance_response(osc, WINDOW, harmonics=H, ds_max=0.04)

    ours()
    resp, wall, cpu, _ = run_limited(ours, args.timeout)
    br = resp.branches[0]
    print(
        f"{'perturb exact Galerkin H=15':34s} wall {wall:6.3f} s, CPU {cpu:6.3f} s, "
        f"{len(br)} points, W {br.omega.min():.3f}..{br.omega.max():.3f}, Hill stability; "
        f"max|x| error {errors_at(br.omega, br.amplitude, exact)}"
    )
    for name, runner in (
        ("pyHarm-os AFT 481", run_pyharm),
        ("harmonicbalance AFT 481", run_harmonicbalance),
    ):
        res, why = runner(args.timeout)
        if res is None:
            print(f"{name:34s} {why}")
            continue
        omega, amp, w, c = res
        note = "" if omega.min() <= WINDOW[0] + 1e-9 else f" (did not reach W = {WINDOW[0]})"
        print(
            f"{name:34s} wall {w:6.3f} s, CPU {c:6.3f} s, {omega.size} points, "
            f"W {omega.min():.3f}..{omega.max():.3f}{note}, no stability; "
            f"max|x| error {errors_at(omega, amp, exact)}"
        )


if __name__ == "__main__":
    main()
