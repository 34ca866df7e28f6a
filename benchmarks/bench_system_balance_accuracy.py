"""Benchmark: accuracy of the multi-harmonic balance of systems against the exact orbit, for
H = 1 ... 63 (issue 16: "the HB error of each coordinate's max|.| against the exact orbit
stays within 2x of the truncation floor (the exact orbit's Fourier series cut at H) for H = 1
... 63; AFT with 4H+1 samples shown beside it").

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_system_balance_accuracy.py [--H 1-63] [--out FILE]

Systems and frequencies (fixed Omega):

* ``nsd2`` (2-DOF structure with a negative-stiffness device, defaults k = -0.5, F = 2) at
  Omega = 1.2 and 0.7;
* ``impact_pair`` (backlash pair: contact-stiffness dead-zone spring r = 20 on the relative
  displacement) with ``mu2 = 0.2`` (a stable impacting orbit) at Omega = 1.2.

Reference: the exact periodic orbit (``periodic_orbit`` on the exact piecewise-affine flow,
``make_flow``: closed-form propagation between the switches, shooting), found from the H = 15
HB orbit (nsd2) or from 300 forcing periods of simulation (impact pair), sampled at 2^14
points; ``max|x_j|`` refined by the parabola through the largest sample. Truncation floor at
H: the error of ``max|x_j|`` of the exact samples' Fourier series cut at H (FFT). HB: Newton
from the exact orbit's series cut at H (the solution does not depend on the guess near it),
``projection="exact"`` (closed-form Galerkin projection) and ``projection="aft"`` with
``samples = 4H + 1``. Ratios: HB error over the coordinate's own floor, and over the orbit's
floor (the largest over its coordinates). A cell ``-`` is an HB run that did not converge.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402

from perturb.errors import PerturbError  # noqa: E402
from perturb.model.system_builtins import builtin_system  # noqa: E402
from perturb.numeric.system_balance import SystemBalance, system_balance_orbit  # noqa: E402
from perturb.simulate.flows.factory import make_flow  # noqa: E402
from perturb.simulate.orbits.shooting import periodic_orbit  # noqa: E402

N_SAMPLES = 2**14


def peak(x: np.ndarray) -> float:
    """max |x| of densely sampled periodic samples, refined by the parabola through the
    largest sample and its neighbours."""
    i = int(np.argmax(np.abs(x)))
    n = x.size
    a, b, c = x[(i - 1) % n], x[i], x[(i + 1) % n]
    den = a - 2 * b + c
    d = 0.5 * (a - c) / den if den != 0 else 0.0
    return abs(b - 0.25 * (a - c) * d)


def exact_orbit(system, W: float, y_guess: np.ndarray):
    flow = make_flow(system.with_params(Omega=W), W)
    orb = periodic_orbit(flow, y_guess)
    T = 2 * np.pi / W
    Y = np.asarray(flow(orb.y0, 0.0, T, t_eval=np.arange(N_SAMPLES) * T / N_SAMPLES).ys)
    return orb, Y[:, : len(system.coordinates)]


def series_cut(Q: np.ndarray, H: int) -> np.ndarray:
    """Rows ``[a0, a1, b1, ...]`` of the sampled coordinates (columns of Q), cut at H."""
    X = np.fft.rfft(Q, axis=0) / Q.shape[0]
    U = np.zeros((Q.shape[1], 2 * H + 1))
    U[:, 0] = X[0].real
    U[:, 1::2] = 2 * X[1 : H + 1].real.T
    U[:, 2::2] = -2 * X[1 : H + 1].imag.T
    return U


def floor(x: np.ndarray, H: int) -> float:
    X = np.fft.rfft(x)
    X[H + 1 :] = 0.0
    return abs(peak(np.fft.irfft(X, n=x.size)) - peak(x))


def hb_error(system, W, H, guess, exact, projection):
    sb = SystemBalance(
        system, H, projection=projection, samples=4 * H + 1 if projection == "aft" else None
    )
    try:
        u = sb.solve(W, guess.reshape(-1), max_iterations=60)
    except PerturbError:
        return None
    return [abs(sb.max_abs(u, W, c) - exact[j]) for j, c in enumerate(system.coordinates)]


def table(label, system, W, y_guess, Hs) -> list[str]:
    c0 = time.process_time()
    orb, Q = exact_orbit(system, W, y_guess)
    exact = [peak(Q[:, j]) for j in range(Q.shape[1])]
    names = system.coordinates
    lines = [
        f"### {label}, Omega = {W}",
        "",
        f"Exact orbit: {orb.stability}, max multiplier {orb.max_multiplier:.4f}; "
        + ", ".join(f"max|{c}| = {e:.10f}" for c, e in zip(names, exact, strict=True)),
        "",
        "| H | "
        + " | ".join(f"{c} floor | {c} HB exact | ratio | {c} AFT 4H+1 | ratio" for c in names)
        + " | exact / orbit floor (max over coordinates) |",
        "|---:|" + "---:|" * (5 * len(names) + 1),
    ]
    worst_orbit = []
    for H in Hs:
        guess = series_cut(Q, H)
        ex = hb_error(system, W, H, guess, exact, "exact")
        af = hb_error(system, W, H, guess, exact, "aft")
        fl = [floor(Q[:, j], H) for j in range(Q.shape[1])]
        cells = []
        for j in range(len(names)):
            cells.append(f"{fl[j]:.2e}")
            for e in (ex, af):
                if e is None:
                    cells += ["-", "-"]
                else:
                    cells += [f"{e[j]:.2e}", f"{e[j] / fl[j]:.2f}" if fl[j] > 0 else "inf"]
        orbit_ratio = "-" if ex is None else f"{max(ex) / max(fl):.2f}"
        if ex is not None:
            worst_orbit.append((max(ex) / max(fl), H))
        lines.append(f"| {H} | " + " | ".join(cells) + f" | {orbit_ratio} |")
    lines.append("")
    if worst_orbit:
        r, H = max(worst_orbit)
        within = sum(1 for q, _ in worst_orbit if q <= 2.0)
        lines.append(
            f"Exact projection within 2x of the orbit's floor at {within} of {len(worst_orbit)}"
            f" H; largest ratio {r:.2f} at H = {H}. CPU for this table: "
            f"{time.process_time() - c0:.1f} s."
        )
    lines.append("")
    return lines


def parse_h(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        if "-" in part:
            a, b = (int(v) for v in part.split("-"))
            out += list(range(a, b + 1))
        else:
            out.append(int(part))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--H", default="1-63", help="harmonics, e.g. 1-63 or 1,3,7,15,31,63")
    ap.add_argument("--out", default=None, help="also write the tables to this file")
    args = ap.parse_args(argv)
    Hs = parse_h(args.H)
    head = [
        "# Multi-harmonic balance of systems: error of max|x_j| against the exact orbit",
        "",
        "`PYTHONPATH=. python benchmarks/bench_system_balance_accuracy.py "
        f"--H {args.H}` (python {sys.version.split()[0]}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}, {platform.machine()}, load average "
        + " ".join(f"{v:.2f}" for v in os.getloadavg())
        + "). Floor: the exact orbit's Fourier series cut at H; ratio: HB error / floor.",
        "",
    ]
    print("\n".join(head), flush=True)
    lines = list(head)
    nsd2 = builtin_system("nsd2")
    for W in (1.2, 0.7):
        y0 = system_balance_orbit(nsd2, W, harmonics=15, stability=False).state(0.0)
        block = table("nsd2", nsd2, W, y0, Hs)
        print("\n".join(block), flush=True)
        lines += block
    pair = builtin_system("impact_pair").with_params(mu2=0.2)
    W = 1.2
    flow = make_flow(pair.with_params(Omega=W), W)
    y0 = flow(np.zeros(pair.n), 0.0, 300 * 2 * np.pi / W).y
    block = table("impact_pair (mu2 = 0.2)", pair, W, y0, Hs)
    print("\n".join(block), flush=True)
    lines += block
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
