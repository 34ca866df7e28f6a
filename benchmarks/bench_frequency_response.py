"""Benchmark: first-order modified L-P frequency response of nsd, every branch, 2000 points.

Reproduce with::

    python benchmarks/bench_frequency_response.py --repeat 21

Model: Zou-Nagarajaiah nsd, k = -3, mu = 0.05, F = 2, Omega in [0.2, 2] (Fig. 17d: the response
has a detached loop). ``modified_lindstedt(osc, 1)`` is derived once; the response is traced
by amplitude parametrisation (``perturb.numeric.amplitude``) from a solver compiled
once (``compile_response``), with each stability option. Each is compared with its baseline
in the same process, interleaved call by call so that both see the same load: the previous
path, i.e. the amplitude's Fourier atoms through the validating public kernels of
``perturb.fourier.coefficients`` (``solver.atoms.unchecked = False``) and Hill's exponents from
LAPACK's
``eigvals`` of the 6x6 matrices (``hill1_matrix``) instead of the closed-form cubic; and
the critical points and breakpoint crossings of the waveforms as they were before the last
step of issue 5 (frozen copies ``_previous_extrema`` / ``_previous_crossings`` below: derivative
tables per order, ``lexsort``, Newton from each piece's middle for every breakpoint, where
the fast path mirrors half-wave symmetric orbits and starts Halley's steps from a
half-cosine guess). The call that compiles on every call is reported too. Target (issue 5):
<= 20 ms after compile, for ``stability="slow_flow"`` and for ``"hill"`` (the default of
``approximation_response``).

Both wall time (``time.perf_counter``) and CPU time of this process (``time.process_time``,
all threads) are reported, with the load average: on a shared machine the load inflates wall
time, and a threaded BLAS that waits for busy cores inflates CPU time as well.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import statistics
import time

import numpy as np

from perturb.methods import modified_lindstedt
from perturb.model.builtins import builtin_model
from perturb.numeric import amplitude as fr
from perturb.numeric.amplitude import approximation_response, compile_response

TARGET_S = 0.020


def timed(fn, repeat: int) -> dict[str, object]:
    """Median and minimum of wall and CPU time over ``repeat`` calls (after one warm-up)."""
    return timed_pair({"x": fn}, repeat)["x"]


def timed_pair(fns: dict[str, object], repeat: int) -> dict[str, dict[str, object]]:
    """:func:`timed` for several callables, interleaved call by call (one warm-up each)."""
    out = {k: f() for k, f in fns.items()}
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for k, f in fns.items():
            t, c = time.perf_counter(), time.process_time()
            out[k] = f()
            wall[k].append(time.perf_counter() - t)
            cpu[k].append(time.process_time() - c)
    return {
        k: {
            "wall": statistics.median(wall[k]),
            "wall_min": min(wall[k]),
            "cpu": statistics.median(cpu[k]),
            "cpu_min": min(cpu[k]),
            "out": out[k],
        }
        for k in fns
    }


@contextlib.contextmanager
def previous_path(solver):
    """The path before the fast one: validating Fourier kernels and LAPACK for Hill."""
    saved = fr.hill1_exponents
    solver.atoms.unchecked = False  # the setter drops the plans built with the other kernels
    fr.hill1_exponents = lambda *a: np.linalg.eigvals(fr.hill1_matrix(*a))
    try:
        yield
    finally:
        fr.hill1_exponents = saved
        solver.atoms.unchecked = True


@contextlib.contextmanager
def previous_extrema():
    """The critical points and breakpoint crossings before issue 5's last step (the frozen
    copies below): everything else as in the fast path."""
    saved = fr.critical_points, fr._PWLHill.crossings, fr._PWLHill.max_multiplier
    fr.critical_points = _previous_extrema
    fr._PWLHill.crossings = _previous_crossings
    fr._PWLHill.max_multiplier = _previous_max_multiplier
    try:
        yield
    finally:
        fr.critical_points, fr._PWLHill.crossings, fr._PWLHill.max_multiplier = saved


# --- the path before this change (frozen copy, commit HEAD of 2026-11-26): critical points
# --- with lexsort and per-order derivative tables, crossings by Newton from the middle of
# --- each piece for every breakpoint; the same-process baseline of `previous_extrema`


class _PreviousTrigRows:
    """Trigonometric polynomials ``x_i(t) = sum_n C_in cos(n t) + S_in sin(n t)`` for the rows
    ``rows`` of ``C, S``, restricted to the harmonics present (e.g. the odd ones of a
    waveform with half-wave symmetry), evaluated at one ``t`` each."""

    def __init__(self, C: np.ndarray, S: np.ndarray, rows: np.ndarray) -> None:
        present = np.any(C != 0, axis=0) | np.any(S != 0, axis=0)
        self.ns = np.nonzero(present)[0]
        self.n = self.ns.astype(float)[:, None]
        self.CT = C.T[self.ns][:, rows]
        self.ST = S.T[self.ns][:, rows]
        self._der: dict[int, tuple[np.ndarray, np.ndarray]] = {0: (self.CT, self.ST)}

    def _coefs(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        if k not in self._der:  # d/dt (C cos + S sin) = n S cos - n C sin
            c, s = self._coefs(k - 1)
            self._der[k] = (self.n * s, -self.n * c)
        return self._der[k]

    def _powers(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``cos(n t), sin(n t)`` for the harmonics present, from products of
        ``exp(i g t)`` over the gaps ``g`` between them (each adds ~1 ulp)."""
        z = np.empty((self.ns.size, t.size), complex)
        steps: dict[int, np.ndarray] = {}
        prev_n, prev = 0, None
        for i, n in enumerate(self.ns):
            g = int(n) - prev_n
            if g == 0:
                z[i] = 1.0
            else:
                if g not in steps:
                    steps[g] = np.exp(1j * g * t)
                if prev is None:
                    z[i] = steps[g]
                else:
                    np.multiply(prev, steps[g], out=z[i])
            prev, prev_n = z[i], int(n)
        return z.real, z.imag

    def __call__(self, t: np.ndarray, idx: np.ndarray | None = None, orders=(0,)):
        """``d^k x_i / dt^k (t)`` for ``k`` in ``orders`` and the polynomials ``idx``."""
        ct, st = self._powers(t)
        out = []
        for k in orders:
            c, s = self._coefs(k)
            if idx is not None and idx.size < c.shape[1]:
                c, s = c[:, idx], s[:, idx]
            out.append(np.einsum("ji,ji->i", c, ct) + np.einsum("ji,ji->i", s, st))
        return out


def _previous_extrema(C: np.ndarray, S: np.ndarray, count: int = fr.WAVEFORM_SAMPLES):
    """Every critical point of the rows ``x(tau) = sum_n C_n cos(n tau) + S_n sin(n tau)``.

    Returns flat arrays ``rows, tau, x`` ordered by row, then ``tau`` in ``[0, 2 pi)``.
    Where the first harmonic ``c1 cos(tau - t1)`` dominates (``R1 = sum n |c_n|`` and
    ``R2 = sum n^2 |c_n|`` over ``n >= 2`` with ``R2 < c1 sqrt(1 - (R1/c1)^2)``), ``x'`` can
    vanish only where ``|sin(tau - t1)| <= R1/c1`` and is strictly monotone there: exactly one
    critical point near ``t1`` and one near ``t1 + pi``, each bracketed (only the first when
    the harmonics are all odd: then ``x(t + pi) = -x(t)``). Other rows are
    bracketed by sign changes of ``x'`` at ``count`` samples. All brackets are then refined
    together to full precision."""
    n_rows, K = C.shape
    n = np.arange(K)
    amp = np.hypot(C, S)
    c1 = amp[:, 1] if K > 1 else np.zeros(n_rows)
    R1 = amp[:, 2:] @ n[2:].astype(float)
    R2 = amp[:, 2:] @ (n[2:] ** 2).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = R1 / c1
        rho_max = np.sqrt(np.clip(1 - (R2 / c1) ** 2, 0, None))
    dom = (c1 > 0) & (rho < rho_max)
    rows_d = np.nonzero(dom)[0]
    # half-width of the two regions, with room so that x' has a strict sign at their ends
    half = np.arcsin(0.5 * (rho[rows_d] + rho_max[rows_d]))
    t1 = np.arctan2(S[rows_d, 1], C[rows_d, 1]) if K > 1 else np.zeros(0)
    # half-wave symmetry (odd harmonics only): x(t + pi) = -x(t), one region suffices
    sym = np.all(C[rows_d, 0::2] == 0, axis=1) & np.all(S[rows_d, 0::2] == 0, axis=1)
    n_max, n_min = rows_d.size, int(np.count_nonzero(~sym))
    centre = np.concatenate([t1, t1[~sym] + np.pi])
    r_b = np.concatenate([rows_d, rows_d[~sym]])
    half = np.concatenate([half, half[~sym]])
    lo_b, hi_b = centre - half, centre + half
    other = np.nonzero(~dom)[0]
    dxs, ro, j = np.empty((0, count)), np.empty(0, int), np.empty(0, int)
    if other.size:
        dxs = fr._trig_samples(S[other] * n, -C[other] * n, count)
        up = dxs >= 0
        ro, j = np.nonzero(up != np.roll(up, -1, axis=1))
        step = 2 * np.pi / count
        r_b = np.concatenate([r_b, other[ro]])
        lo_b = np.concatenate([lo_b, step * j])
        hi_b = np.concatenate([hi_b, step * (j + 1)])
    if r_b.size == 0:
        empty = np.empty(0)
        return np.empty(0, int), empty, empty
    guess = np.concatenate([centre, 0.5 * (lo_b[centre.size :] + hi_b[centre.size :])])
    # x' is known to be > 0 at the left end of the region about the maximum t1 and < 0 at
    # its right end (the reverse about t1 + pi); the sampled brackets carry their samples
    f_lo = np.concatenate([np.ones(n_max), -np.ones(n_min), dxs[ro, j]])
    f_hi = np.concatenate([-np.ones(n_max), np.ones(n_min), dxs[ro, (j + 1) % count]])
    poly = _PreviousTrigRows(C, S, r_b)

    def slope(t: np.ndarray, idx: np.ndarray):
        return poly(t, idx, (1, 2, 3))

    # after a Halley step below 1e-3 the position is good to ~1e-9 (times the curvature
    # scale), and the value at a critical point depends on it only to second order
    t = fr.safe_newton(slope, lo_b, hi_b, f_lo, f_hi, guess, 1e-3)
    x = poly(t)[0]
    r_b = np.concatenate([r_b, rows_d[sym]])
    t = np.mod(np.concatenate([t, t[:n_max][sym] + np.pi]), 2 * np.pi)
    x = np.concatenate([x, -x[:n_max][sym]])
    order = np.lexsort((t, r_b))
    return r_b[order], t[order], x[order]


def _previous_crossings(self, C, S, r, te, xe):
    """Breakpoint crossings of the orbits with critical points ``(r, te, xe)`` (from
    :func:`critical_points`): row, phase ``tau`` in ``[0, 2 pi)`` and jump of ``q``."""
    empty = np.empty(0)
    if r.size == 0 or self.breakpoints.size == 0:
        return np.empty(0, int), empty, empty
    # monotone pieces from each critical point to the next one of the same orbit (cyclic)
    nxt = np.arange(r.size) + 1
    first = np.ones(r.size, bool)
    first[1:] = r[1:] != r[:-1]
    last = np.ones(r.size, bool)
    last[:-1] = r[1:] != r[:-1]
    starts = np.nonzero(first)[0]
    nxt[last] = starts[np.cumsum(first)[last] - 1]
    t_end = np.where(last, te[nxt] + 2 * np.pi, te[nxt])
    x_end = xe[nxt]
    rows, taus, jumps = [], [], []
    for i, d in enumerate(self.breakpoints):
        k = np.nonzero((xe - d) * (x_end - d) < 0)[0]
        if k.size == 0:
            continue
        rk = r[k]
        poly = _PreviousTrigRows(C, S, rk)

        def level(t, idx, poly=poly, d=d):
            x, dx = poly(t, idx, (0, 1))
            return x - d, dx

        lo, hi = te[k], t_end[k]
        tc = fr.safe_newton(level, lo, hi, xe[k] - d, x_end[k] - d, 0.5 * (lo + hi), 1e-13)
        rows.append(rk)
        taus.append(np.mod(tc, 2 * np.pi))
        dq = self.slopes[i + 1] - self.slopes[i]
        jumps.append(np.where(x_end[k] > xe[k], dq, -dq))
    if not rows:
        return np.empty(0, int), empty, empty
    return np.concatenate(rows), np.concatenate(taus), np.concatenate(jumps)


def _previous_max_multiplier(self, coefs, extrema, w) -> np.ndarray:
    """``exp(max Re(lambda) T)`` of the two Floquet exponents of Hill's ``H = 1``
    truncation, for orbits ``x(tau)`` with coefficients ``coefs``, critical points
    ``extrema`` (from :func:`critical_points`) and frequencies ``w``."""
    C, S = coefs
    n_orb = C.shape[0]
    rows, tau, jump = self.crossings(C, S, *extrema)
    # q_0 = q(0+) + sum_c dq_c (2 pi - tau_c) / (2 pi); q_k by parts (see the class)
    x0 = C.sum(axis=1)
    seg = np.searchsorted(self.breakpoints, x0) if self.breakpoints.size else 0
    q0 = self.slopes[seg] + np.bincount(
        rows, jump * (2 * np.pi - tau) / (2 * np.pi), minlength=n_orb
    )
    # q = q0 + sum_k qc_k cos(k tau) + qs_k sin(k tau), k = 1, 2
    qc, qs = [], []
    for k in (1, 2):
        z = jump * np.exp(-1j * k * tau) / (2j * np.pi * k)  # q_k = (qc_k - i qs_k) / 2
        qc.append(2 * np.bincount(rows, z.real, minlength=n_orb))
        qs.append(-2 * np.bincount(rows, z.imag, minlength=n_orb))
    lam = fr.hill1_exponents(q0, qc[0], qs[0], qc[1], qs[1], w, self.damping)
    # of the 2 (2H + 1) eigenvalues the two with the smallest |Im| are the exponents
    order = np.argsort(np.abs(lam.imag) + 1e-12 * np.abs(lam.real), axis=1)
    re = np.max(np.take_along_axis(lam, order[:, :2], axis=1).real, axis=1)
    return np.exp(np.clip(re * 2 * np.pi / w, -700, 700))


def check_same(resp, ref) -> None:
    """The fast path's response equals the baseline's to rounding (printed, not asserted)."""
    worst = {}
    for field in ("omega", "amplitude", "max_multiplier"):
        x = np.concatenate([getattr(b, field) for b in resp.branches])
        y = np.concatenate([getattr(b, field) for b in ref.branches])
        worst[field] = float(np.max(np.abs(x - y) / np.abs(y))) if x.shape == y.shape else np.inf
    print(
        "  max relative difference vs previous extrema: "
        + ", ".join(f"{k} {v:.1e}" for k, v in worst.items())
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    cmd = "python benchmarks/bench_frequency_response.py"
    print(f"command: {cmd} --repeat {args.repeat}")
    load0 = os.getloadavg()
    print(
        f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} cores, "
        f"load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}"
    )
    osc = builtin_model("nsd", k=-3.0, mu=0.05, F=2.0)
    t = time.perf_counter()
    approx = modified_lindstedt(osc, 1)
    t_derive = time.perf_counter() - t
    t = time.perf_counter()
    solver = compile_response(approx)
    t_compile = time.perf_counter() - t
    print(f"derive {t_derive:.3f} s, compile {t_compile:.3f} s (wall)\n")

    header = (
        f"{'variant':44s} {'wall med':>9s} {'wall min':>9s} {'cpu med':>9s} {'cpu min':>9s} "
        f"{'points':>7s} {'branches':>8s} {'base/fast':>15s}"
    )
    print(header)

    def row(name, r, fast=None, n: int | str = "", nb: int | str = "") -> None:
        ratio = ""
        if fast is not None:  # this baseline's median wall and CPU over the fast path's
            ratio = f"{r['wall'] / fast['wall']:.2f}x/{r['cpu'] / fast['cpu']:.2f}x"
        print(
            f"{name:44s} {r['wall'] * 1e3:7.1f}ms {r['wall_min'] * 1e3:7.1f}ms "
            f"{r['cpu'] * 1e3:7.1f}ms {r['cpu_min'] * 1e3:7.1f}ms {n!s:>7s} {nb!s:>8s} "
            f"{ratio:>15s}"
        )

    results = {}
    for stability in ("slow_flow", "hill"):

        def fast(st=stability):
            return approximation_response(solver, (0.2, 2.0), points=2000, stability=st)

        def before(st=stability):
            with previous_path(solver):
                return approximation_response(solver, (0.2, 2.0), points=2000, stability=st)

        def before_extrema(st=stability):
            with previous_extrema():
                return approximation_response(solver, (0.2, 2.0), points=2000, stability=st)

        r = timed_pair(
            {"fast": fast, "before": before, "before_extrema": before_extrema}, args.repeat
        )
        resp = r["fast"]["out"]
        n = sum(len(b) for b in resp.branches)
        row(f"compiled, stability={stability}", r["fast"], None, n, len(resp.branches))
        row("  baseline: previous path (kernels, LAPACK)", r["before"], r["fast"])
        row("  baseline: previous extrema + crossings", r["before_extrema"], r["fast"])
        check_same(resp, r["before_extrema"]["out"])
        results[stability] = r["fast"]
    base = timed(
        lambda: approximation_response(approx, (0.2, 2.0), points=2000, stability="slow_flow"),
        max(3, args.repeat // 2),
    )
    row("compile + trace, slow_flow (no ratio)", base)
    print("(base/fast: the baseline's median wall / the fast path's median wall, same for CPU;")
    print(" all three variants interleaved call by call in this process)")
    load1 = os.getloadavg()
    print()
    for stability, r in results.items():
        verdict = "met" if r["wall"] <= TARGET_S else "NOT met"
        print(
            f"target <= {TARGET_S * 1e3:.0f} ms after compile (stability={stability}): {verdict} "
            f"(median wall {r['wall'] * 1e3:.1f} ms, min {r['wall_min'] * 1e3:.1f} ms, "
            f"CPU {r['cpu'] * 1e3:.1f} ms)"
        )
    print(f"load average at the end {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")


if __name__ == "__main__":
    main()
