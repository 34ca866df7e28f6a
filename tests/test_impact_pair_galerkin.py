"""perturb's multi-harmonic balance of the impact pair against an independent Galerkin solver
written here (issue 16; the full comparison, H = 1..63, is
benchmarks/bench_impact_pair_galerkin.py with its results in
benchmarks/results/bench_impact_pair_galerkin.md).

System: builtin ``impact_pair`` with mu2 = 0.2, Omega = 1.2 (the orbit of
bench_system_balance_accuracy.py); the equations are typed here from the builtin's docstring::

    x1'' + mu x1' + x1 + r b(x1 - x2) = F cos(W t),
    m2 x2'' + mu2 (x2' - x1') - r b(x1 - x2) = 0,   b(s) = (s-d)H(s-d) + (s+d)H(-s-d).

Oracle: unknowns ``[a0, a1, b1, ...]`` of x1 and x2 (tau = W t); the contact force projected by
16-point Gauss-Legendre quadrature on the pieces between the switching points of
``s = x1 - x2`` (roots of ``s -+ d`` by sign change on 4096 points and brentq), each piece at
most 2 pi / (4 H) long -- exact to rounding, since the integrand is a trigonometric polynomial
on each piece; Newton with the quadrature Jacobian. No perturb.numeric / perturb.fourier code.
Start for both solvers: the exact orbit's series cut at H (the exact orbit from the independent
oracle ``tests/impact_pair_oracle.py``, DOP853 shooting, sampled at 2^14 points; perturb's
reference layer, ``make_flow`` + ``periodic_orbit``, gives the same samples to 8e-15).

Measured (bench_impact_pair_galerkin.py): the two solutions agree to 5e-16 (H = 11) and
1e-14 (H = 23), 7.1e-13 at worst over H = 1..63; the max|x1| error is 3.55e-3 = 68x the
truncation floor 5.2e-5 at H = 11 for both, 5.89e-6 = 0.93x at H = 23. Tolerances: 1e-9 on
the coefficients (rounding of two different quadratures; measured <= 7.1e-13 over
H = 1..63); the H = 11 excess asserted as > 30x (measured 68x) -- the issue's 2x target is
not met by the Galerkin solution itself there.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from impact_pair_oracle import P_DEFAULT, flow, periodic_orbit
from scipy.optimize import brentq

from perturb.model.system_builtins import builtin_system
from perturb.numeric.system_balance import SystemBalance

P = dict(P_DEFAULT, mu2=0.2)
W = 1.2
N = 2**14
#: (x1, x2, x1', x2') at t = 0 of the orbit (the oracle's, from the benchmark's
#: [-0.6155, -0.9958, 0.4075, -0.3628]; periodic to 6e-13, so Newton takes no step)
Y_GUESS = [-0.615507364562, -0.995773097351, 0.407516376802, -0.362845544436]
GL_X, GL_W = np.polynomial.legendre.leggauss(16)


def basis(tau, H):
    A = np.outer(tau, np.arange(1, H + 1))
    Phi = np.empty((tau.size, 2 * H + 1))
    Phi[:, 0] = 1.0
    Phi[:, 1::2] = np.cos(A)
    Phi[:, 2::2] = np.sin(A)
    return Phi


def switches(s, H):
    tau = np.arange(4097) * 2 * np.pi / 4096
    v = basis(tau, H) @ s
    roots = []
    for c in (P["d"], -P["d"]):
        g = v - c
        for i in np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0):
            roots.append(
                brentq(lambda t, c=c: basis(np.array([t]), H)[0] @ s - c, tau[i], tau[i + 1])
            )
    return np.unique(roots)


def residual(u, H):
    n = 2 * H + 1
    x1, x2 = u[:n], u[n:]
    edges = np.unique(np.concatenate([[0.0, 2 * np.pi], switches(x1 - x2, H)]))
    nodes, weights = [], []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        e = np.linspace(a, b, max(1, int(np.ceil((b - a) * 4 * H / (2 * np.pi)))) + 1)
        h, c = 0.5 * np.diff(e), 0.5 * (e[1:] + e[:-1])
        nodes.append((c[:, None] + h[:, None] * GL_X).reshape(-1))
        weights.append((h[:, None] * GL_W).reshape(-1))
    tau, w = np.concatenate(nodes), np.concatenate(weights)
    Phi = basis(tau, H)
    sv = Phi @ (x1 - x2)
    bv = np.where(sv > P["d"], sv - P["d"], np.where(sv < -P["d"], sv + P["d"], 0.0))
    chi = (np.abs(sv) > P["d"]).astype(float)
    scale = np.full(n, 1 / np.pi)
    scale[0] = 0.5 / np.pi
    Pb = scale * (Phi.T @ (w * bv))
    G = scale[:, None] * (Phi.T @ ((w * chi)[:, None] * Phi))
    D = np.zeros((n, n))
    for k in range(1, H + 1):
        D[2 * k - 1, 2 * k], D[2 * k, 2 * k - 1] = k, -k
    D2, eye, f = D @ D, np.eye(n), np.zeros(n)
    f[1] = P["F"]
    r, mu, mu2, m2 = P["r"], P["mu"], P["mu2"], P["m2"]
    A1 = W * W * D2 + W * mu * D + eye
    A2 = m2 * W * W * D2 + W * mu2 * D
    R = np.concatenate([A1 @ x1 + r * Pb - f, A2 @ x2 - W * mu2 * D @ x1 - r * Pb])
    J = np.block([[A1 + r * G, -r * G], [-W * mu2 * D - r * G, A2 + r * G]])
    return R, J


def newton(u, H):
    for _ in range(30):
        R, J = residual(u, H)
        if np.abs(R).max() < 1e-12:
            return u
        u = u - np.linalg.solve(J, R)
    raise AssertionError(f"independent Newton: |R| = {np.abs(R).max():.2e}")


def peak(x):
    i = int(np.argmax(np.abs(x)))
    a, b, c = x[i - 1], x[i], x[(i + 1) % x.size]
    den = a - 2 * b + c
    d = 0.5 * (a - c) / den if den != 0 else 0.0
    return abs(b - 0.25 * (a - c) * d)


def series_max(c, H):
    tau = np.arange(N) * 2 * np.pi / N
    return peak(basis(tau, H) @ c)


@functools.cache
def exact():
    """The exact orbit (the independent oracle), sampled at N points, and its max|x1|, max|x2|."""
    y0 = periodic_orbit(W, Y_GUESS, P)
    T = 2 * np.pi / W
    Q = flow(W, y0, P, dense=True).sample(np.arange(N) * T / N)[:2].T
    return Q, np.array([peak(Q[:, 0]), peak(Q[:, 1])])


def cut(Q, H):
    X = np.fft.rfft(Q, axis=0) / N
    U = np.zeros((2, 2 * H + 1))
    U[:, 0] = X[0].real
    U[:, 1::2] = 2 * X[1 : H + 1].real.T
    U[:, 2::2] = -2 * X[1 : H + 1].imag.T
    return U


@pytest.mark.parametrize("H", [11, 23])
def test_perturb_hb_equals_the_independent_galerkin_solution(H):
    Q, peaks = exact()
    guess = cut(Q, H)
    u_ind = newton(guess.reshape(-1).copy(), H)
    system = builtin_system("impact_pair").with_params(mu2=P["mu2"])
    sb = SystemBalance(system, H, projection="exact")
    u_p = sb.solve(W, guess.reshape(-1), max_iterations=60)
    assert np.abs(u_p - u_ind).max() < 1e-9  # measured 5e-16 (H = 11), 1e-14 (H = 23)
    assert np.abs(residual(u_p, H)[0]).max() < 1e-10
    err = abs(series_max(u_ind[: 2 * H + 1], H) - peaks[0])
    err_p = abs(sb.max_abs(u_p, W, "x1") - peaks[0])
    assert abs(err - err_p) < 1e-8 * max(1.0, err)
    floor = abs(series_max(guess[0], H) - peaks[0])
    if H == 11:
        # the excess over the floor belongs to the Galerkin solution: 68x measured
        assert err > 30 * floor, (err, floor)
    else:
        assert err < 2 * floor, (err, floor)  # measured 0.93x
