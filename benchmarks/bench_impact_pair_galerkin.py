"""Benchmark: is the excess of the impact pair's HB error over the truncation floor (issue 16)
a property of Galerkin harmonic balance itself? An independent Galerkin solver and an
independent exact orbit, side by side with perturb's ``SystemBalance``.

Reproduce with::

    PYTHONPATH=. python benchmarks/bench_impact_pair_galerkin.py [--H 1-63] [--out FILE]
        [--coverage-cache DIR]

System (hard-coded from ``perturb/model/system_builtins.py``, builtin ``impact_pair``)::

    x1'' + mu x1' + x1 + r b(x1 - x2) = F cos(W t)
    m2 x2'' + mu2 (x2' - x1') - r b(x1 - x2) = 0,   b(s) = (s-d)H(s-d) + (s+d)H(-s-d)

mu = 0.05, r = 20, d = 0.5, m2 = 0.2, F = 0.5; mu2 = 0.2 at W = 1.2 (the orbit of
``bench_system_balance_accuracy.py``); mu2 = 0.01 (the builtin default) for the coverage part.

Independent pieces (nothing from ``perturb.numeric`` or ``perturb.fourier``):

* **Exact orbit**: DOP853 (scipy, rtol = atol = 1e-12) with terminal events at the four
  contact switches ``s = +-d`` (the integration restarts at each switch, so the step never
  straddles the kink), monodromy from the variational equations integrated alongside (the
  field is continuous, so no saltation), Newton shooting on ``y(T) = y(0)``; started from a
  300-period DOP853 transient (rtol 1e-9) from rest (or from a given state). ``max|x_j|``:
  the largest ``|x_j|`` at the events ``x_j' = 0`` of the final period. Fourier series: FFT of
  2^14 samples of the dense output (aliasing below 1e-13: coefficients decay like k^-4).
  Cross-checked against perturb's reference layer (``make_flow`` + ``periodic_orbit``).
* **Galerkin HB**: unknowns ``[a0, a1, b1, ..., aH, bH]`` of x1 and of x2 (tau = W t);
  residual = the equations projected on 1, cos k tau, sin k tau; the contact force projected
  by Gauss-Legendre quadrature (16 nodes per piece) on the pieces between the switching
  points of ``s(tau) = x1 - x2`` (roots of ``s -+ d``: sign changes on a grid of
  max(4096, 64 H) points, refined by brentq, plus near-grazing extrema checked by a bounded
  minimisation), every piece at most 2 pi / (4 H) long -- the integrand is a trigonometric
  polynomial on each piece, so the projection is exact to rounding. Jacobian: the same
  quadrature of the contact indicator times the basis products (exact: b is continuous).
  Damped Newton (at most 60 iterations) from the exact orbit's series cut at H.

Coverage (``--coverage-cache DIR``; the exact branches of ``exact_branches`` with their
states are pickled there on the first run): impact_pair with its defaults (mu2 = 0.01) on
(0.6, 1.4) and (0.8, 1.3) at H = 15 -- for exact points, does an H = 15 Galerkin solution
exist near the exact orbit, and does one of ``system_balance_response``'s branches pass
through it (distance in coefficient space)? Section 4 of the output says how.

Errors of ``max|x_j|`` against the exact orbit's; **floor** (the issue's): the error of
``max|x_j|`` of the exact series cut at H; also the tail's sup norm ``max|x - x_H|`` and RMS
``sqrt(sum_{k>H} (a_k^2 + b_k^2) / 2)``, and the same two norms of the HB error ``x - x_HB``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import pickle  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402
from scipy.optimize import brentq, least_squares, minimize_scalar  # noqa: E402

P_MAIN = dict(mu=0.05, mu2=0.2, r=20.0, d=0.5, m2=0.2, F=0.5)
P_DEFAULT = dict(mu=0.05, mu2=0.01, r=20.0, d=0.5, m2=0.2, F=0.5)
W_MAIN = 1.2
N_SAMPLES = 2**14
GL_X, GL_W = np.polynomial.legendre.leggauss(16)


# ------------------------------------------------------------------ exact orbit ----------
def contact(s: float, d: float) -> float:
    return s - d if s > d else (s + d if s < -d else 0.0)


class Exact:
    """The impact pair's exact flow by DOP853 with restarts at the contact switches."""

    def __init__(self, p: dict, W: float):
        self.p, self.W, self.T = p, W, 2 * np.pi / W

    def field(self, t, y, var=False):
        p = self.p
        x1, x2, v1, v2 = y[:4]
        s = x1 - x2
        f = contact(s, p["d"])
        a1 = p["F"] * np.cos(self.W * t) - p["mu"] * v1 - x1 - p["r"] * f
        a2 = (p["r"] * f - p["mu2"] * (v2 - v1)) / p["m2"]
        out = [v1, v2, a1, a2]
        if var:
            chi = 1.0 if abs(s) > p["d"] else 0.0
            r, m2, mu, mu2 = p["r"], p["m2"], p["mu"], p["mu2"]
            A = np.array(
                [
                    [0, 0, 1, 0],
                    [0, 0, 0, 1],
                    [-1 - r * chi, r * chi, -mu, 0],
                    [r * chi / m2, -r * chi / m2, mu2 / m2, -mu2 / m2],
                ]
            )
            Phi = y[4:].reshape(4, 4)
            out = out + list((A @ Phi).reshape(-1))
        return np.array(out)

    def events(self):
        d = self.p["d"]
        e1 = lambda t, y: y[0] - y[1] - d  # noqa: E731
        e2 = lambda t, y: y[0] - y[1] + d  # noqa: E731
        for e in (e1, e2):
            e.terminal = True
        return [e1, e2]

    def run(self, y0, t0, t1, var=False, rtol=1e-12, t_eval=None, extra_events=()):
        """Integrate from t0 to t1 restarting at each switch; returns (y1, segments,
        extra event records (t, y, which))."""
        y = np.array(y0, float)
        if var:
            y = np.concatenate([y[:4], np.eye(4).reshape(-1)])
        t = t0
        evs = self.events() + list(extra_events)
        segs, recs = [], []
        for _ in range(100000):  # cap: switches per run
            sol = solve_ivp(
                lambda tt, yy: self.field(tt, yy, var),
                (t, t1),
                y,
                method="DOP853",
                rtol=rtol,
                atol=rtol,
                events=evs,
                dense_output=t_eval is not None,
            )
            if t_eval is not None:
                segs.append((t, sol.t[-1], sol.sol))
            for j in range(2, len(evs)):
                for te, ye in zip(sol.t_events[j], sol.y_events[j], strict=True):
                    recs.append((te, ye, j - 2))
            if sol.status == 1 and sol.t[-1] < t1 - 1e-14 * max(1.0, abs(t1)):
                t = float(sol.t[-1])
                y = sol.y[:, -1].copy()
                # step past the switch so the terminal event does not refire at once
                sol2 = solve_ivp(
                    lambda tt, yy: self.field(tt, yy, var),
                    (t, min(t1, t + 1e-9)),
                    y,
                    method="DOP853",
                    rtol=rtol,
                    atol=rtol,
                    dense_output=t_eval is not None,
                )
                if t_eval is not None:
                    segs.append((t, sol2.t[-1], sol2.sol))
                t, y = float(sol2.t[-1]), sol2.y[:, -1].copy()
                if t >= t1:
                    break
                continue
            y = sol.y[:, -1].copy()
            break
        else:
            raise RuntimeError("switch cap reached")
        return y, segs, recs

    def periodic(self, y_guess, max_iterations=30):
        y = np.array(y_guess, float)
        for _ in range(max_iterations):
            yT, _, _ = self.run(y, 0.0, self.T, var=True)
            g = yT[:4] - y
            if np.max(np.abs(g)) < 1e-11 * max(1.0, np.max(np.abs(y))):
                Phi = yT[4:].reshape(4, 4)
                return y, np.max(np.abs(np.linalg.eigvals(Phi)))
            Phi = yT[4:].reshape(4, 4)
            y = y - np.linalg.solve(Phi - np.eye(4), g)
        raise RuntimeError(f"shooting did not converge, |g| = {np.max(np.abs(g)):.2e}")

    def samples(self, y0):
        """(2^14 samples of (x1, x2) over one period, (max|x1|, max|x2|) from x_j' = 0)."""
        tt = np.arange(N_SAMPLES) * self.T / N_SAMPLES
        v1 = lambda t, y: y[2]  # noqa: E731
        v2 = lambda t, y: y[3]  # noqa: E731
        _, segs, recs = self.run(y0, 0.0, self.T, t_eval=True, extra_events=(v1, v2))
        Q = np.empty((N_SAMPLES, 2))
        for a, b, f in segs:
            m = (tt >= a) & (tt <= b)
            if m.any():
                Q[m] = f(tt[m])[:2].T
        peaks = [0.0, 0.0]
        for _, ye, j in recs:
            peaks[j] = max(peaks[j], abs(ye[j]))
        return Q, np.array(peaks)


def exact_orbit(p, W, y_start=None, transient=300):
    ex = Exact(p, W)
    y = np.zeros(4) if y_start is None else np.asarray(y_start, float)
    if transient:
        y, _, _ = ex.run(y, 0.0, transient * ex.T, rtol=1e-9)
    y0, mult = ex.periodic(y)
    Q, peaks = ex.samples(y0)
    return y0, mult, Q, peaks


def coefficients(Q: np.ndarray, H: int) -> np.ndarray:
    """(2, 2H+1) rows [a0, a1, b1, ...] of the sampled coordinates, cut at H."""
    X = np.fft.rfft(Q, axis=0) / Q.shape[0]
    U = np.zeros((Q.shape[1], 2 * H + 1))
    U[:, 0] = X[0].real
    U[:, 1::2] = 2 * X[1 : H + 1].real.T
    U[:, 2::2] = -2 * X[1 : H + 1].imag.T
    return U


# ------------------------------------------------------------ trig polynomials ----------
def trig_eval(c: np.ndarray, tau: np.ndarray, deriv: int = 0) -> np.ndarray:
    H = (c.size - 1) // 2
    k = np.arange(1, H + 1)
    a, b = c[1::2], c[2::2]
    A = np.outer(tau, k)
    C, S = np.cos(A), np.sin(A)
    if deriv == 0:
        return c[0] + C @ a + S @ b
    if deriv == 1:
        return C @ (k * b) - S @ (k * a)
    return -(C @ (k * k * a) + S @ (k * k * b))


def trig_max_abs(c: np.ndarray, n: int = 4096) -> float:
    """max |x(tau)| of a trigonometric polynomial: grid argmax then Newton on x' = 0."""
    H = (c.size - 1) // 2
    n = max(n, 64 * H)
    tau = np.arange(n) * 2 * np.pi / n
    x = trig_eval(c, tau)
    best = 0.0
    for i in np.argsort(-np.abs(x))[:4]:
        t = tau[i]
        for _ in range(30):
            d1 = trig_eval(c, np.array([t]), 1)[0]
            d2 = trig_eval(c, np.array([t]), 2)[0]
            if d2 == 0:
                break
            step = d1 / d2
            t -= step
            if abs(step) < 1e-15:
                break
        val = abs(trig_eval(c, np.array([t]))[0])
        if abs(t - tau[i]) < 4 * np.pi / n:
            best = max(best, val)
        best = max(best, abs(x[i]))
    return best


# ----------------------------------------------------------------- Galerkin HB ----------
class Galerkin:
    """Independent Galerkin HB of the impact pair (switching points + Gauss quadrature)."""

    def __init__(self, p: dict, H: int):
        self.p, self.H = p, H
        self.n = 2 * H + 1
        self.k = np.arange(1, H + 1)

    def basis(self, tau):
        A = np.outer(tau, self.k)
        Phi = np.empty((tau.size, self.n))
        Phi[:, 0] = 1.0
        Phi[:, 1::2] = np.cos(A)
        Phi[:, 2::2] = np.sin(A)
        return Phi

    def switches(self, s: np.ndarray) -> np.ndarray:
        """Sorted roots of s(tau) = +-d in [0, 2 pi)."""
        d = self.p["d"]
        n = max(4096, 64 * self.H)
        tau = np.arange(n + 1) * 2 * np.pi / n
        v = trig_eval(s, tau)
        roots = []
        f = lambda t, c: trig_eval(s, np.array([t]))[0] - c  # noqa: E731
        for c in (d, -d):
            g = v - c
            idx = np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)
            roots += [brentq(f, tau[i], tau[i + 1], args=(c,), xtol=1e-15) for i in idx]
            roots += [tau[i] for i in np.flatnonzero(g[:-1] == 0)]
            # near-grazing: a local extremum of g within reach of zero between grid points
            ext = np.flatnonzero((g[1:-1] - g[:-2]) * (g[2:] - g[1:-1]) <= 0) + 1
            for i in ext:
                sg = np.sign(g[i - 1 : i + 2])
                if abs(g[i]) > 1e-3 or sg[0] == 0 or np.any(sg != sg[0]):
                    continue
                sign = 1.0 if g[i] > 0 else -1.0
                m = minimize_scalar(
                    lambda t, c=c, sign=sign: sign * f(t, c),
                    bounds=(tau[i - 1], tau[i + 1]),
                    method="bounded",
                    options={"xatol": 1e-14},
                )
                if m.fun < 0:  # crosses: two roots on either side of the extremum
                    roots.append(brentq(f, tau[i - 1], m.x, args=(c,), xtol=1e-15))
                    roots.append(brentq(f, m.x, tau[i + 1], args=(c,), xtol=1e-15))
        return np.unique(np.mod(np.array(roots), 2 * np.pi))

    def quadrature(self, s):
        """Nodes and weights on [0, 2 pi): pieces between switches, each <= 2 pi / (4H)."""
        edges = np.unique(np.concatenate([[0.0, 2 * np.pi], self.switches(s)]))
        hmax = 2 * np.pi / (4 * self.H)
        nodes, weights = [], []
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            m = max(1, int(np.ceil((b - a) / hmax)))
            e = np.linspace(a, b, m + 1)
            h = 0.5 * np.diff(e)
            c = 0.5 * (e[1:] + e[:-1])
            nodes.append((c[:, None] + h[:, None] * GL_X[None, :]).reshape(-1))
            weights.append((h[:, None] * GL_W[None, :]).reshape(-1))
        return np.concatenate(nodes), np.concatenate(weights)

    def contact_projection(self, s):
        """Galerkin coefficients of b(s(tau)) and d/ds-coefficients (matrix)."""
        d = self.p["d"]
        tau, w = self.quadrature(s)
        Phi = self.basis(tau)
        sv = Phi @ s
        bv = np.where(sv > d, sv - d, np.where(sv < -d, sv + d, 0.0))
        chi = (np.abs(sv) > d).astype(float)
        scale = np.full(self.n, 1.0 / np.pi)
        scale[0] = 0.5 / np.pi
        P = scale * (Phi.T @ (w * bv))
        G = scale[:, None] * (Phi.T @ ((w * chi)[:, None] * Phi))
        return P, G

    def linear(self, W):
        """Matrices L1, L2 (each (n, n)) of x'' , x' in coefficient space (tau = W t):
        D = d/dtau on [a0, a1, b1, ...]."""
        D = np.zeros((self.n, self.n))
        for k in self.k:
            D[2 * k - 1, 2 * k] = k  # cos coefficient of x' = k b_k
            D[2 * k, 2 * k - 1] = -k  # sin coefficient of x' = -k a_k
        return D

    def residual(self, u, W, jac=True):
        p, n = self.p, self.n
        x1, x2 = u[:n], u[n:]
        D = self.linear(W)
        D2 = D @ D
        I = np.eye(n)
        f = np.zeros(n)
        f[1] = p["F"]
        P, G = self.contact_projection(x1 - x2)
        r = p["r"]
        R1 = (W * W * D2 + W * p["mu"] * D + I) @ x1 + r * P - f
        R2 = p["m2"] * W * W * D2 @ x2 + W * p["mu2"] * D @ (x2 - x1) - r * P
        R = np.concatenate([R1, R2])
        if not jac:
            return R, None
        J = np.block(
            [
                [W * W * D2 + W * p["mu"] * D + I + r * G, -r * G],
                [-W * p["mu2"] * D - r * G, p["m2"] * W * W * D2 + W * p["mu2"] * D + r * G],
            ]
        )
        return R, J

    def newton(self, u0, W, tol=1e-12, max_iterations=60):
        """Damped Newton (backtracking on |R|_2, Armijo); returns (u, |R|_inf, iterations,
        converged)."""
        u = np.array(u0, float)
        R, J = self.residual(u, W)
        n2 = float(R @ R)
        for it in range(max_iterations):
            if np.max(np.abs(R)) < tol:
                return u, np.max(np.abs(R)), it, True
            try:
                du = np.linalg.solve(J, -R)
            except np.linalg.LinAlgError:
                return u, np.max(np.abs(R)), it, False
            lam = 1.0
            for _ in range(30):  # backtracking cap
                un = u + lam * du
                Rn, Jn = self.residual(un, W)
                if float(Rn @ Rn) <= (1 - 1e-4 * lam) * n2:
                    break
                lam *= 0.5
            else:
                return u, np.max(np.abs(R)), it, False
            u, R, J, n2 = un, Rn, Jn, float(Rn @ Rn)
        return u, np.max(np.abs(R)), max_iterations, np.max(np.abs(R)) < tol

    def max_abs(self, u):
        n = self.n
        return np.array([trig_max_abs(u[:n]), trig_max_abs(u[n:])])


def series_from(u: np.ndarray, n_samples: int = N_SAMPLES) -> np.ndarray:
    """Samples (N, 2) of the two coordinates of flat Galerkin coefficients."""
    n = u.size // 2
    tau = np.arange(n_samples) * 2 * np.pi / n_samples
    return np.column_stack([trig_eval(u[:n], tau), trig_eval(u[n:], tau)])


# ------------------------------------------------------------------ perturb side ----------
def perturb_hb(W, H, guess, mu2):
    """perturb's exact-projection HB (the API of bench_system_balance_accuracy.py)."""
    from perturb.errors import PerturbError
    from perturb.model.system_builtins import builtin_system
    from perturb.numeric.system_balance import SystemBalance

    system = builtin_system("impact_pair").with_params(mu2=mu2)
    sb = SystemBalance(system, H, projection="exact")
    try:
        u = sb.solve(W, guess.reshape(-1), max_iterations=60)
    except PerturbError:
        return None, None
    return u, np.array([sb.max_abs(u, W, c) for c in system.coordinates])


def perturb_auto(W, H, mu2):
    """perturb's SystemBalance.solve without a guess (its own starts)."""
    from perturb.errors import PerturbError
    from perturb.model.system_builtins import builtin_system
    from perturb.numeric.system_balance import SystemBalance

    system = builtin_system("impact_pair").with_params(mu2=mu2)
    sb = SystemBalance(system, H, projection="exact")
    try:
        u = sb.solve(W)
    except PerturbError:
        return None, None
    return u, np.array([sb.max_abs(u, W, c) for c in system.coordinates])


def perturb_exact_check(W, y0, mu2):
    from perturb.model.system_builtins import builtin_system
    from perturb.simulate.flows.factory import make_flow
    from perturb.simulate.orbits.shooting import periodic_orbit

    system = builtin_system("impact_pair").with_params(mu2=mu2, Omega=W)
    orb = periodic_orbit(make_flow(system, W), y0)
    return np.asarray(orb.y0, float), orb.max_multiplier


# ---------------------------------------------------------------------- tables ----------
def fmt(v):
    return "-" if v is None or not np.isfinite(v) else f"{v:.2e}"


def accuracy_table(Hs, Q, peaks, lines):
    c0 = time.process_time()
    lines += [
        "## 1-2. Error of max|x_j| at Omega = 1.2 (mu2 = 0.2): perturb HB vs independent "
        "Galerkin vs floors",
        "",
        "Per coordinate: floor = |max|x_H| - max|x||; `pert` = perturb's HB error; `ind` = "
        "independent Galerkin error; ratio = ind / floor; `sup tail` = max|x - x_H|, `rms "
        "tail` = RMS of x - x_H; `sup HB` / `rms HB` = the same norms of x - x_HB (independent "
        "solution); `du` = max |u_perturb - u_independent| over all coefficients; `it` = "
        "Newton iterations of the independent solver from the cut series (`ms`: Newton from "
        "the cut series failed; of 20 starts around it and the previous H's solution padded "
        "with zeros, the converged solution nearest to it; "
        "perturb then from its own starts, `solve(Omega)` without a guess); `|R|` its final "
        "residual.",
        "",
        "| H | x1 floor | x1 pert | x1 ind | ratio | x1 sup tail | x1 sup HB | x1 rms tail | "
        "x1 rms HB | x2 floor | x2 pert | x2 ind | ratio | x2 sup tail | x2 sup HB | "
        "x2 rms tail | x2 rms HB | du | it | |R| |",
        "|---:|" + "---:|" * 20,
    ]
    X = np.fft.rfft(Q, axis=0) / Q.shape[0]
    rows = []
    prev = None
    for H in Hs:
        g = Galerkin(P_MAIN, H)
        cut = coefficients(Q, H)
        u0 = cut.reshape(-1)
        u, nr, it, ok = g.newton(u0, W_MAIN)
        it = str(it)
        if not ok:  # multi-start around the cut series; the solution nearest to it
            rng = np.random.default_rng(H)
            found = []
            for _ in range(20):
                v0 = u0 + np.abs(u0).max() * rng.normal(0, 0.5, u0.size)
                v, nv, _, okv = g.newton(v0, W_MAIN, max_iterations=40)
                if okv:
                    found.append((np.max(np.abs(v - u0)), v, nv))
            if prev is not None:  # and from the previous H's solution padded with zeros
                Hp = (prev.size // 2 - 1) // 2
                v0 = np.zeros((2, 2 * H + 1))
                v0[:, : 2 * Hp + 1] = prev.reshape(2, -1)[:, : 2 * H + 1]
                v, nv, _, okv = g.newton(v0.reshape(-1), W_MAIN, max_iterations=40)
                if okv:
                    found.append((np.max(np.abs(v - u0)), v, nv))
            if found:
                _, u, nr = min(found, key=lambda f: f[0])
                ok, it = True, "ms"
        prev = u if ok else None
        Qc = series_from(u0)
        fl = np.abs(np.array([trig_max_abs(cut[0]), trig_max_abs(cut[1])]) - peaks)
        sup_tail = np.max(np.abs(Q - Qc), axis=0)
        rms_tail = np.sqrt(np.sum(2 * np.abs(X[H + 1 :]) ** 2, axis=0))
        if ok:
            err = np.abs(g.max_abs(u) - peaks)
            Qh = series_from(u)
            sup_hb = np.max(np.abs(Q - Qh), axis=0)
            rms_hb = np.sqrt(np.mean((Q - Qh) ** 2, axis=0))
        else:
            err = sup_hb = rms_hb = np.full(2, np.nan)
        up, pe = perturb_hb(W_MAIN, H, cut, P_MAIN["mu2"])
        if up is None:  # perturb's own starts (no guess)
            up, pe = perturb_auto(W_MAIN, H, P_MAIN["mu2"])
        perr = np.full(2, np.nan) if pe is None else np.abs(pe - peaks)
        du = np.nan if (up is None or not ok) else float(np.max(np.abs(up - u)))
        cells = [str(H)]
        for j in range(2):
            cells += [
                fmt(fl[j]),
                fmt(perr[j]),
                fmt(err[j]),
                "-" if not ok else f"{err[j] / fl[j]:.2f}",
                fmt(sup_tail[j]),
                fmt(sup_hb[j]),
                fmt(rms_tail[j]),
                fmt(rms_hb[j]),
            ]
        cells += [fmt(du), it, fmt(nr)]
        lines.append("| " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
        rows.append(
            dict(
                H=H,
                ok=ok,
                fl=fl,
                err=err,
                perr=perr,
                du=du,
                sup_tail=sup_tail,
                sup_hb=sup_hb,
                rms_tail=rms_tail,
                rms_hb=rms_hb,
            )
        )
    lines.append("")
    good = [r for r in rows if r["ok"]]
    same = [r for r in good if np.isfinite(r["du"]) and r["du"] < 1e-8]
    lines.append(
        f"Independent Newton converged at {len(good)} of {len(rows)} H; perturb's coefficients "
        f"equal the independent ones (max diff < 1e-8) at {len(same)} of them (largest diff "
        f"{max((r['du'] for r in good if np.isfinite(r['du'])), default=np.nan):.1e})."
    )
    ratio_max = [max(r["err"] / np.maximum(r["fl"], 1e-300)) for r in good]
    over = [r["H"] for r, q in zip(good, ratio_max, strict=True) if q > 2]
    lines.append(f"Independent Galerkin error / issue floor > 2 (either coordinate) at H = {over}.")
    orb = [r["H"] for r in good if max(r["err"]) > 2 * max(r["fl"])]
    lines.append(
        "Orbit ratio of `bench_system_balance_accuracy.py` (largest error over the coordinates "
        f"/ largest floor) > 2 at H = {orb}."
    )
    lines.append(
        "Sup-norm tail of x1 non-increasing in H (the issue floor of max|x1| is not): "
        + str(
            all(
                b["sup_tail"][0] <= a["sup_tail"][0] * (1 + 1e-6)
                for a, b in zip(rows[:-1], rows[1:], strict=True)
            )
        )
        + "."
    )
    q_sup = [max(r["sup_hb"] / r["sup_tail"]) for r in good]
    q_rms = [max(r["rms_hb"] / r["rms_tail"]) for r in good]
    if good:
        lines.append(
            f"Quasi-optimality: sup|x - x_HB| / sup|x - x_H| in [{min(q_sup):.2f}, "
            f"{max(q_sup):.2f}], RMS(x - x_HB) / RMS(x - x_H) in [{min(q_rms):.2f}, "
            f"{max(q_rms):.2f}] over these H (max over the two coordinates)."
        )
    lines.append(f"CPU for this table: {time.process_time() - c0:.1f} s.")
    lines.append("")
    return rows


def low_h(Q, peaks, lines, starts=60, seed=1):
    """H = 1, 2: Newton and least squares from the cut series, then a multi-start."""
    lines += ["## 3. H = 1, 2: is there a Galerkin solution near the exact orbit?", ""]
    rng = np.random.default_rng(seed)
    floors = {}
    for H in (1, 2):
        cut = coefficients(Q, H)
        floors[H] = np.abs(np.array([trig_max_abs(cut[0]), trig_max_abs(cut[1])]) - peaks)
    for H in (1, 2):
        c0 = time.process_time()
        g = Galerkin(P_MAIN, H)
        u0 = coefficients(Q, H).reshape(-1)
        R0, _ = g.residual(u0, W_MAIN, jac=False)
        u, nr, it, ok = g.newton(u0, W_MAIN)
        ls = least_squares(
            lambda v, g=g: g.residual(v, W_MAIN, jac=False)[0],
            u0,
            jac=lambda v, g=g: g.residual(v, W_MAIN)[1],
            xtol=1e-15,
            ftol=1e-15,
            gtol=1e-15,
            max_nfev=2000,
        )
        lines.append(
            f"- H = {H}: the cut series has |R|_inf = {np.max(np.abs(R0)):.3e}; Newton from it "
            f"{'converged' if ok else 'stopped'} after {it} iterations at |R|_inf = {nr:.3e}; "
            f"least squares from it stops at |R|_2^2 = {np.sum(ls.fun**2):.3e} "
            f"(|R|_inf {np.max(np.abs(ls.fun)):.3e}) at distance "
            f"{np.max(np.abs(ls.x - u0)):.3f} from the cut series (max over coefficients)."
        )
        sols = []
        scale = np.abs(u0).max()
        for i in range(starts):
            if i < starts // 2:
                v0 = u0 + scale * rng.normal(0, 0.5, u0.size)
            else:
                v0 = scale * rng.uniform(-3, 3, u0.size)
            v, nv, _, okv = g.newton(v0, W_MAIN, max_iterations=40)
            if okv and not any(np.max(np.abs(v - s)) < 1e-8 for s in sols):
                sols.append(v)
        lines.append(
            f"  Multi-start ({starts} damped-Newton starts: half the cut series + N(0, 0.5 "
            f"max|u|), half uniform in +-3 max|u|): {len(sols)} distinct solutions."
        )
        for v in sols:
            e = g.max_abs(v)
            gap = np.abs(e - peaks)
            sw = len(g.switches(v[: g.n] - v[g.n :]))
            up, _ = perturb_hb(W_MAIN, H, v, P_MAIN["mu2"])
            same = "-" if up is None else f"{np.max(np.abs(up - v)):.0e}"
            lines.append(
                f"  * max|x1| = {e[0]:.4f}, max|x2| = {e[1]:.4f} (errors {gap[0]:.2e}, "
                f"{gap[1]:.2e}; floors {floors[H][0]:.2e}, {floors[H][1]:.2e}); {sw} "
                f"switches/period; mean x1 {v[0]:.1e}; distance to the cut series "
                f"{np.max(np.abs(v - u0)):.3f}; perturb's solve from it moves "
                f"{same}"
            )
        ua, ea = perturb_auto(W_MAIN, H, P_MAIN["mu2"])
        lines.append(
            "  perturb's `SystemBalance.solve(Omega)` without a guess (its own starts): "
            + (
                "no solution"
                if ua is None
                else f"max|x1| = {ea[0]:.4f}, max|x2| = {ea[1]:.4f}, "
                + (
                    "one of the above"
                    if any(np.max(np.abs(ua - v)) < 1e-8 for v in sols)
                    else "not among the above"
                )
            )
        )
        lines.append(f"  CPU {time.process_time() - c0:.1f} s.")
    lines.append("")


# -------------------------------------------------------------------- coverage ----------
def polyline_distance(u: np.ndarray, hb):
    """Nearest point of the response's polylines to u in coefficient space (Euclidean
    projection on each segment): (max|u - P| / max(1, max|u|), that segment's length in the
    same units, the point P)."""
    best = (np.inf, 0.0, None)
    scale = max(1.0, float(np.abs(u).max()))
    for h in hb.branches:
        P = h.U.reshape(len(h.U), -1)
        if len(P) == 1:
            cand = [(np.abs(P[0] - u).max(), 0.0, P[0])]
        else:
            d = np.diff(P, axis=0)
            dd = np.einsum("ij,ij->i", d, d)
            t = np.clip(np.einsum("ij,ij->i", u - P[:-1], d) / np.where(dd > 0, dd, 1.0), 0, 1)
            X = P[:-1] + t[:, None] * d
            e = np.abs(X - u).max(axis=1)
            j = int(np.argmin(e))
            cand = [(e[j], np.abs(d[j]).max(), X[j])]
        for e, L, X in cand:
            if e < best[0] * scale:
                best = (e / scale, L / scale, X)
    return best


def exact_branches_cached(cache, window):
    """The exact branches of impact_pair (defaults) on window, with the states of their
    points, pickled in cache (perturb's independent PWL solver; ~25 s CPU per window)."""
    path = os.path.join(cache, f"exact_{window[0]}_{window[1]}.pkl")
    if os.path.exists(path):
        with open(path, "rb") as fh:
            return pickle.load(fh)
    from perturb.model.system_builtins import builtin_system
    from perturb.simulate.exact_response import exact_branches

    res = exact_branches(
        builtin_system("impact_pair"), window, output="x1", workers=1, progress=False
    )
    out = [
        dict(
            Omega=np.asarray(b.parameters, float),
            amplitude=np.asarray(b.coordinate_amplitudes[:, 0], float),
            mean=np.asarray(b.coordinate_means[:, 0], float),
            switches=np.array([p.switches for p in b.points]),
            y0=np.array([np.asarray(p.y0, float) for p in b.points]),
        )
        for b in res.branches
    ]
    os.makedirs(cache, exist_ok=True)
    with open(path, "wb") as fh:
        pickle.dump(out, fh)
    return out


def coverage(cache, lines, stride=96, on_branch=2e-2):
    """impact_pair (mu2 = 0.01), H = 15: does every exact point have an H = 15 Galerkin
    solution near it, and is that solution on one of perturb's response branches? Needs the
    exact branches with their states (``perturb.simulate.exact_response.exact_branches``,
    pickled in ``cache`` as exact_<lo>_<hi>.pkl)."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import bench_system_balance_attractors as B

    from perturb.errors import PerturbError
    from perturb.model.system_builtins import builtin_system
    from perturb.numeric.system_balance import SystemBalance, system_balance_response

    system = builtin_system("impact_pair")
    lines += [
        "## 4. Coverage: impact_pair (mu2 = 0.01, builtin defaults), H = 15",
        "",
        f"Exact points: every {stride}th point of each branch of `exact_branches(impact_pair, "
        "window, output='x1')` plus every point that `bench_system_balance_attractors.py`'s "
        "metric reports missed (`bench`: every 8th point, no solution of the H = 15 response "
        "within 2.5e-2 max(1, A) in (max|x1|, mean x1) after its fixed-Omega Newton). Per "
        "point: the exact orbit re-shot by the independent DOP853 solver from the branch's "
        "state; the independent Galerkin Newton from its series cut at H (A err = error of "
        "max|x1|); `du` = max |u_p - u_ind| with u_p = perturb's `SystemBalance.solve` from "
        "the same cut series; `cdist` = distance in **coefficient space** of the independent "
        "H = 15 solution to perturb's H = 15 response polylines (max-norm, relative to "
        f"max(1, max|u|); `seg` = the length of that polyline segment, same units). Classes: "
        f"**on** (cdist <= max({on_branch:g}, seg), or perturb's Newton at Omega from the "
        "nearest polyline point converges to the solution: a traced branch passes through "
        "it), **gap** (the Galerkin solution exists within 2.5e-2 max(1, A) "
        "of the exact max|x1| but no traced branch passes through it), **far** (exists, "
        "beyond that threshold), **none** (Newton from the cut series fails: no H = 15 "
        "solution near the exact orbit).",
        "",
    ]
    gaps: list = []
    for window in ((0.6, 1.4), (0.8, 1.3)):
        ex = exact_branches_cached(cache, window)
        c0 = time.process_time()
        sb = SystemBalance(system, 15)
        hb = system_balance_response(system, window, harmonics=15, balance=sb, attractors=True)
        picks = []
        n_missed = 0
        for bi, b in enumerate(ex):
            for i in range(0, len(b["Omega"]), B.STRIDE):
                one = [{k: v[i : i + 1] for k, v in b.items() if k != "y0"}]
                missed = B.coverage(one, hb, sb, window)[1] > 0
                n_missed += missed
                if missed or i % stride == 0:
                    picks.append((bi, i, missed))
        lines += [
            f"### Window {window}: perturb's response at H = 15: {len(hb)} branches (Omega "
            + ", ".join(f"{h.Omega.min():.3f}-{h.Omega.max():.3f}" for h in hb.branches)
            + f"); exact: {len(ex)} branches; bench metric: {n_missed} missed",
            "",
            "| exact branch (Omega range) | Omega | switches | A exact | mult | bench | "
            "H=15 A err | du | cdist / seg | class | H=31 A err | du | H=63 A err |",
            "|---|---:|---:|---:|---:|---|---:|---:|---:|---|---:|---:|---:|",
        ]
        classes: dict[str, int] = {}
        states: list[str] = []
        for bi, i, missed in picks:
            b = ex[bi]
            W = float(b["Omega"][i])
            p = dict(P_DEFAULT)
            cells = [
                f"{bi} ({b['Omega'].min():.4f}-{b['Omega'].max():.4f})",
                f"{W:.6f}",
                str(int(b["switches"][i])),
                f"{b['amplitude'][i]:.5f}",
            ]
            try:
                y, mult, Q, peaks = exact_orbit(p, W, b["y0"][i], transient=0)
            except RuntimeError as exc:
                lines.append("| " + " | ".join(cells) + f" | shooting failed: {exc} |")
                continue
            cells += [f"{mult:.3g}", "missed" if missed else ""]
            thr = 2.5e-2 * max(1.0, peaks[0])
            cls = "none"
            for H in (15, 31, 63):
                g = Galerkin(p, H)
                cut = coefficients(Q, H)
                u, nr, it, ok = g.newton(cut.reshape(-1), W)
                if not ok:
                    cells.append(f"none (|R| {nr:.1e})")
                    cells += {15: ["-", "-", "none"], 31: ["-"], 63: []}[H]
                    continue
                a_err = abs(g.max_abs(u)[0] - peaks[0])
                cells.append(f"{a_err:.2e}")
                if H == 63:
                    continue
                try:
                    up = SystemBalance(system, H).solve(W, cut.reshape(-1), max_iterations=60)
                    cells.append(f"{np.max(np.abs(up - u)):.0e}")
                except PerturbError:
                    cells.append("fails")
                if H == 15:
                    cd, seg, X = polyline_distance(u, hb)
                    hit = False
                    if X is not None and cd > max(on_branch, seg):
                        try:  # perturb's Newton from the nearest polyline point
                            hit = np.abs(sb.solve(W, X, max_iterations=30) - u).max() < 1e-8
                        except PerturbError:
                            pass
                    if a_err > thr:
                        cls = "far"
                    else:
                        cls = "on" if (cd <= max(on_branch, seg) or hit) else "gap"
                    cells += [f"{cd:.1e} / {seg:.1e}", f"**{cls}**" if cls == "gap" else cls]
                    if cls == "gap" and not any(s0[1] == bi for s0 in states):
                        states.append((f"- gap, exact branch {bi}, Omega = {W:.6f}", bi, y, u))
            classes[cls] = classes.get(cls, 0) + 1
            lines.append("| " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
        lines.append("")
        for text, _, y, u in states:
            lines.append(
                f"{text}: exact y0 = {np.array2string(y, precision=8, separator=', ')}; "
                "H = 15 Galerkin coefficients (x1 then x2, [a0, a1, b1, ...]) = "
                + np.array2string(u, precision=5, separator=", ", max_line_width=10**6)
            )
        lines += [
            "",
            f"Classes: {classes}; CPU for the window {time.process_time() - c0:.1f} s.",
            "",
        ]
        gaps += [(window, bi) for _, bi, _, _ in states if bi not in [g[1] for g in gaps]]
    follow_up(gaps, lines, cache)


def follow_up(gaps, lines, cache, limit=1):
    """For the first gap branch: the same Galerkin solutions against perturb's response on a
    wider window at H = 15 and on the same window at H = 31; perturb's solve at the window
    edge without a guess."""
    from perturb.errors import PerturbError
    from perturb.model.system_builtins import builtin_system
    from perturb.numeric.system_balance import SystemBalance, system_balance_response

    if not gaps:
        return
    system = builtin_system("impact_pair")
    lines += ["### The gap: does a wider window or H = 31 trace it?", ""]
    for window, bi in gaps[:limit]:
        c0 = time.process_time()
        b = exact_branches_cached(cache, window)[bi]
        idx = [0, len(b["Omega"]) // 4, len(b["Omega"]) // 2, len(b["Omega"]) - 1]
        sols = {}
        for i in idx:
            W = float(b["Omega"][i])
            _, _, Q, _ = exact_orbit(dict(P_DEFAULT), W, b["y0"][i], transient=0)
            for H in (15, 31):
                u, _, _, ok = Galerkin(dict(P_DEFAULT), H).newton(coefficients(Q, H).reshape(-1), W)
                sols[H, i] = (W, u if ok else None)
        wider = (round(window[0] - 0.1, 3), window[1])
        for H, win in ((15, window), (15, wider), (31, window)):
            hb = system_balance_response(system, win, harmonics=H, attractors=True)
            cells = []
            for i in idx:
                W, u = sols[H, i]
                if u is None:
                    cells.append(f"Omega {W:.4f}: no Galerkin solution")
                    continue
                cd, seg, _ = polyline_distance(u, hb)
                cells.append(f"Omega {W:.4f}: cdist {cd:.1e} (seg {seg:.1e})")
            lines.append(
                f"- exact branch {bi} of {window}, H = {H}, response on {win} "
                f"({len(hb)} branches): " + "; ".join(cells)
            )
        try:
            sb = SystemBalance(system, 15)
            u = sb.solve(window[0])
            W0, u0 = sols[15, 0]
            txt = (
                f"max|x1| = {sb.max_abs(u, window[0], 'x1'):.4f}, distance to the gap "
                f"branch's solution at Omega = {W0:.4f}: "
                + ("-" if u0 is None else f"{np.abs(u - u0).max():.2e}")
            )
        except PerturbError as exc:
            txt = f"fails ({str(exc)[:120]})"
        lines.append(
            f"- perturb's `SystemBalance(impact_pair, 15).solve({window[0]})` without a guess: "
            f"{txt}. CPU {time.process_time() - c0:.1f} s."
        )
    lines.append("")


def parse_h(text):
    out = []
    for part in text.split(","):
        if "-" in part:
            a, b = (int(v) for v in part.split("-"))
            out += list(range(a, b + 1))
        else:
            out.append(int(part))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--H", default="1-63")
    ap.add_argument("--out", default=None)
    ap.add_argument(
        "--coverage-cache", default=None, help="run section 4; exact branches cached here"
    )
    ap.add_argument("--starts", type=int, default=60)
    args = ap.parse_args(argv)
    c0 = time.process_time()
    lines = [
        "# impact_pair: independent Galerkin HB vs perturb's HB vs the truncation floor",
        "",
        f"`PYTHONPATH=. python benchmarks/bench_impact_pair_galerkin.py --H {args.H}"
        + (f" --coverage-cache {args.coverage_cache}" if args.coverage_cache else "")
        + f"` (python {sys.version.split()[0]}, numpy {np.__version__}, scipy "
        f"{scipy.__version__}, {platform.machine()}, load average "
        + " ".join(f"{v:.2f}" for v in os.getloadavg())
        + ").",
        "",
    ]
    y0, mult, Q, peaks = exact_orbit(P_MAIN, W_MAIN)
    yp, mp = perturb_exact_check(W_MAIN, y0, P_MAIN["mu2"])
    lines += [
        "## Exact orbit (independent DOP853 shooting), Omega = 1.2, mu2 = 0.2",
        "",
        f"y0 = {np.array2string(y0, precision=12, separator=', ')}, max multiplier "
        f"{mult:.6f}; max|x1| = {peaks[0]:.12f}, max|x2| = {peaks[1]:.12f}. perturb's "
        f"`periodic_orbit(make_flow(...))` from this y0: max |y0 difference| = "
        f"{np.max(np.abs(yp - y0)):.1e}, max multiplier {mp:.6f}.",
        "",
    ]
    print("\n".join(lines), flush=True)
    accuracy_table(parse_h(args.H), Q, peaks, lines)
    low_h(Q, peaks, lines, starts=args.starts)
    if args.coverage_cache:
        coverage(args.coverage_cache, lines)
    lines.append(f"Total CPU {time.process_time() - c0:.1f} s.")
    print("\n".join(lines[-40:]), flush=True)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
