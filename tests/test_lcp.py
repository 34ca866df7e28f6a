"""Tests of :mod:`perturb.simulate.flows.lcp` (LCP time-stepping and Lemke's method).

Oracles, never the LCP code itself:

* :func:`enumerate_lcp` below: brute force over all 2^m complementary bases (a direct solve on
  each), for :func:`lcp_solve`;
* the exact piecewise-analytic propagator :func:`perturb.simulate.flows.piecewise_exact.propagate`,
  for the time-stepping (convergence order and agreement);
* the energy ½v² + V(x) of the free undamped oscillator, with V written down by hand, and the
  exact per-step energy error of the trapezoidal rule on a kink (derived in the module
  docstring and again in ``test_energy_free_undamped_nsd``);
* principal minors computed by brute force, for the closed-form P-matrix test.

Expected orders (θ = 1/2, the trapezoidal rule): local error O(h³) in a step that stays in one
segment; a step in which the orbit crosses a kink integrates a function with a kink in time, for
which the trapezoid is only O(h²) accurate (error (h − τ)τ/2 × jump of the slope, τ the
position of the crossing in the step).  There are O(1) crossing steps per period, so their
contribution to the global error is O(h²) too: the global order stays 2.  Because τ/h jumps
around as h changes, the error constant wobbles from one h to the next (local slopes between
consecutive h: 1.46 … 2.43 for the max error, −0.2 … 4.5 for the final-time error, which can
nearly cancel at one h), so the order is fitted by least squares over the
whole range T/50 … T/3200 (a factor 64 in h) and asserted in a band: max-over-run error
1.8 … 2.3, final-time error (a single signed sum of crossing contributions, noisier)
1.6 … 2.6.  θ = 1 (backward Euler) is first order: band 0.9 … 1.1.

Measured (h = T/50 … T/3200, 10 forcing periods; see ``ORDERS`` below for the numbers):
nsd k = −2, µ = 0.05, F = 2, Ω = 0.6 from its attractor: max-error order 2.04, final-time order
2.49, max error at T/3200 2.3e-5; clearance (defaults) from rest: 1.92 / 1.86, 2.9e-4.
The nsd run starts on the attractor (100-period exact warm-up) because from rest its transient
passes the saddle and amplifies errors ~2000x, which keeps T/50 … T/400 pre-asymptotic.
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.builtins import builtin_model
from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.lcp import (
    LCPTrajectory,
    is_p_matrix,
    lcp_solve,
    simulate_lcp,
    step_lcp,
)
from perturb.simulate.flows.piecewise_exact import PWLSystem, propagate
from perturb.simulate.flows.system import to_pwl_system

TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------------------------------------
# oracles
# ---------------------------------------------------------------------------------------------
def enumerate_lcp(M: np.ndarray, q: np.ndarray, tol: float = 1e-11) -> list[np.ndarray]:
    """All solutions of w = M z + q, 0 <= z ⟂ w >= 0, from the 2^m complementary bases."""
    m = q.size
    sols: list[np.ndarray] = []
    scale = 1.0 + np.abs(q).max() + np.abs(M).max()
    for size in range(m + 1):
        for J in itertools.combinations(range(m), size):
            z = np.zeros(m)
            if J:
                idx = np.array(J)
                MJ = M[np.ix_(idx, idx)]
                if abs(np.linalg.det(MJ)) < 1e-12:
                    continue
                z[idx] = np.linalg.solve(MJ, -q[idx])
            w = M @ z + q
            if np.all(z >= -tol * scale) and np.all(w >= -tol * scale):
                if not any(np.allclose(z, s, atol=1e-8 * scale) for s in sols):
                    sols.append(z)
    return sols


def principal_minors(M: np.ndarray) -> list[float]:
    m = M.shape[0]
    return [
        float(np.linalg.det(M[np.ix_(J, J)]))
        for size in range(1, m + 1)
        for J in map(list, itertools.combinations(range(m), size))
    ]


def check_complementarity(M, q, lam, w, tol=1e-9):
    M, q = np.asarray(M, float), np.asarray(q, float)
    scale = 1.0 + np.abs(q).max() + np.abs(M).max() * (1.0 + np.abs(lam).max())
    assert np.all(lam >= 0.0) and np.all(w >= 0.0)
    np.testing.assert_allclose(w, M @ lam + q, atol=tol * scale, rtol=0)
    assert np.max(np.abs(lam * w)) <= tol * scale * (1.0 + np.abs(lam).max())


# models (slopes/offsets by hand) -------------------------------------------------------------
def nsd(k=-2.0, mu=0.05, F=2.0, W=0.6) -> PWLSystem:
    """|x| <= 1: f = kx; x > 1: f = x + (k - 1); x < -1: f = x + (1 - k)."""
    return PWLSystem([-1.0, 1.0], [1.0, k, 1.0], [1.0 - k, 0.0, k - 1.0], damping=mu,
                     forcing=((F, W, 0.0),) if F else ())  # fmt: skip


def clearance(mu=0.02, r=10.0, d=0.5, F=0.3, W=0.9) -> PWLSystem:
    """f = x for x < d, x + r (x - d) above."""
    return PWLSystem([d], [1.0, 1.0 + r], [0.0, -r * d], damping=mu, forcing=((F, W, 0.0),))


def nsd_potential(x: np.ndarray, k: float = -2.0) -> np.ndarray:
    """G(x) = ½kx² + ½(1−k)(|x|−1)₊² (REFERENCES §1), with G' = f of :func:`nsd`."""
    return 0.5 * k * x * x + 0.5 * (1.0 - k) * np.maximum(np.abs(x) - 1.0, 0.0) ** 2


# ---------------------------------------------------------------------------------------------
# Lemke's method
# ---------------------------------------------------------------------------------------------
def random_p_matrix(rng: np.random.Generator, m: int, kind: int) -> np.ndarray:
    """P-matrices of several structures (all verified with the brute-force minors)."""
    if kind == 0:  # positive definite, nonsymmetric
        A = rng.normal(size=(m, m))
        B = rng.normal(size=(m, m))
        M = A @ A.T + 0.1 * np.eye(m) + (B - B.T)
    elif kind == 1:  # strictly diagonally dominant with a positive diagonal
        M = rng.normal(size=(m, m))
        np.fill_diagonal(M, 0.0)
        M += np.diag(np.abs(M).sum(axis=1) + rng.uniform(0.05, 1.0, m))
    elif kind == 2:  # triangular with a positive diagonal and large off-diagonal entries
        M = np.tril(rng.normal(scale=3.0, size=(m, m)), -1) + np.diag(rng.uniform(0.2, 2.0, m))
        if rng.random() < 0.5:
            M = M.T
    elif kind == 3:  # the step matrix I + c sigma ds^T of the scheme, in its P regime
        ds = rng.normal(scale=3.0, size=m)
        sig = rng.choice([-1.0, 1.0], size=m)
        neg = np.minimum(sig * ds, 0.0).sum()
        c = rng.uniform(0.0, 0.95 / -neg) if neg < 0 else rng.uniform(0.0, 5.0)
        M = np.eye(m) + c * np.outer(sig, ds)
    else:  # badly scaled: D1 P D2 with positive diagonal D1, D2 keeps the P-property
        M = random_p_matrix(rng, m, 0)
        M = np.diag(10.0 ** rng.uniform(-2, 2, m)) @ M @ np.diag(10.0 ** rng.uniform(-2, 2, m))
    return M


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    m=st.integers(1, 6),
    kind=st.integers(0, 4),
    qkind=st.integers(0, 2),
    seed=st.integers(0, 2**32 - 1),
)
def test_lemke_matches_enumeration_on_p_matrices(m, kind, qkind, seed):
    rng = np.random.default_rng(seed)
    M = random_p_matrix(rng, m, kind)
    assert min(principal_minors(M)) > 0.0
    if qkind == 0:
        q = rng.normal(scale=2.0, size=m)
    elif qkind == 1:  # integer data: exact ties in the ratio tests
        q = rng.integers(-3, 3, size=m).astype(float)
    else:  # degenerate solution: some indices with z_i = w_i = 0
        z_true = np.where(rng.random(m) < 0.5, rng.uniform(0.5, 2.0, m), 0.0)
        w_true = np.where(z_true > 0.0, 0.0, rng.uniform(0.5, 2.0, m))
        w_true[rng.random(m) < 0.4] = 0.0
        w_true[z_true > 0.0] = 0.0
        q = w_true - M @ z_true
    sols = enumerate_lcp(M, q)
    assert len(sols) == 1  # P-matrix: exactly one solution
    lam, w = lcp_solve(M, q)
    check_complementarity(M, q, lam, w)
    scale = 1.0 + np.abs(sols[0]).max()
    np.testing.assert_allclose(lam, sols[0], atol=1e-12 * scale * np.linalg.cond(M), rtol=0)


@pytest.mark.parametrize(
    ("M", "q", "expected"),
    [
        # q >= 0: no pivot, zero solution
        (np.eye(3), np.zeros(3), [0.0, 0.0, 0.0]),
        (np.eye(2), [0.0, 1.0], [0.0, 0.0]),
        # all components tie in the first ratio test
        (np.eye(3), [-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]),
        ([[2.0, 1.0], [1.0, 2.0]], [-3.0, -3.0], [1.0, 1.0]),
        # a zero q_i with the solution on the boundary (z_0 = 0, w_0 = 1/2)
        ([[2.0, 1.0], [1.0, 2.0]], [0.0, -1.0], [0.0, 0.5]),
        # doubly degenerate index 1: z_1 = w_1 = 0 at the solution z = (1, 0)
        ([[2.0, 1.0], [1.0, 2.0]], [-2.0, -1.0], [1.0, 0.0]),
        # triangular, both bases tie in the second ratio test
        ([[1.0, 0.0], [2.0, 1.0]], [-1.0, 2.0], [1.0, 0.0]),
        # doubly degenerate index 1: z_1 = w_1 = 0 at the solution z = (1, 0, 0)
        ([[1.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 1.0]], [-1.0, -1.0, 2.0], [1.0, 0.0, 0.0]),
    ],
)
def test_lemke_known_degenerate_cases(M, q, expected):
    lam, w = lcp_solve(M, q)
    check_complementarity(M, q, lam, w, tol=1e-12)
    np.testing.assert_allclose(lam, expected, atol=1e-13)
    assert [np.round(s, 12).tolist() for s in enumerate_lcp(np.asarray(M), np.asarray(q))] == [
        expected
    ]


@pytest.mark.parametrize("m", [2, 4, 6])
def test_lemke_murty_exponential_example(m):
    """Murty's P-matrix (1 on the diagonal, 2 below), q = −1: Lemke needs 2^m pivots."""
    M = np.eye(m) + 2.0 * np.tril(np.ones((m, m)), -1)
    q = -np.ones(m)
    lam, w = lcp_solve(M, q)
    check_complementarity(M, q, lam, w, tol=1e-12)
    (sol,) = enumerate_lcp(M, q)
    np.testing.assert_allclose(lam, sol, atol=1e-12)
    with pytest.raises(PerturbError, match="max_pivots"):
        lcp_solve(M, q, max_pivots=2 ** (m - 1))


def test_lemke_non_p_matrices():
    # PSD, infinitely many solutions z_0 + z_1 = 1: Lemke returns one of them
    lam, w = lcp_solve([[1.0, 1.0], [1.0, 1.0]], [-1.0, -1.0])
    check_complementarity([[1.0, 1.0], [1.0, 1.0]], [-1.0, -1.0], lam, w)
    assert lam.sum() == pytest.approx(1.0)
    # w = -z - 1 >= 0 is impossible: secondary ray, clear error
    with pytest.raises(PerturbError, match="secondary ray"):
        lcp_solve([[-1.0]], [-1.0])
    assert lcp_solve(np.zeros((0, 0)), np.zeros(0))[0].shape == (0,)


@pytest.mark.parametrize(
    ("M", "q", "match"),
    [
        ([[1.0, np.nan], [0.0, 1.0]], [1.0, -1.0], "finite"),
        (np.eye(2), [np.inf, -1.0], "finite"),
        (np.eye(2), [1.0, 2.0, 3.0], "shape"),
        ([[1.0, 2.0]], [1.0], "shape"),
        (np.eye(2), [[1.0], [2.0]], "1-D"),
        ("abc", [1.0], "real"),
    ],
)
def test_lcp_solve_rejects_bad_input(M, q, match):
    with pytest.raises(ParameterError, match=match):
        lcp_solve(M, q)


def test_lcp_solve_rejects_bad_max_pivots():
    with pytest.raises(ParameterError, match="max_pivots"):
        lcp_solve(np.eye(1), [-1.0], max_pivots=0)


# ---------------------------------------------------------------------------------------------
# the step matrix and its P-property
# ---------------------------------------------------------------------------------------------
@settings(max_examples=150, deadline=None)
@given(
    m=st.integers(1, 5),
    seed=st.integers(0, 2**32 - 1),
    log_h=st.floats(-3.0, 1.0),
    theta=st.sampled_from([0.5, 0.75, 1.0]),
    mu=st.sampled_from([0.0, 0.05, 1.0]),
)
def test_step_matrix_minors_closed_form(m, seed, log_h, theta, mu):
    rng = np.random.default_rng(seed)
    slopes = rng.normal(scale=2.0, size=m + 1)
    system = PWLSystem.continuous(np.sort(rng.uniform(-2, 2, m)) + np.arange(m), slopes,
                                  damping=mu)  # fmt: skip
    h = 10.0**log_h
    lcp = step_lcp(system, h, theta)
    # the reference maximises S_r; it reproduces the force with ramps (sigma (x - d))_+
    r, sig, d = lcp.reference, lcp.sigma, system.breakpoints
    xs = np.linspace(d[0] - 3.0, d[-1] + 3.0, 101)
    ramps = np.maximum(sig * (xs[:, None] - d), 0.0)
    f = slopes[r] * xs + system.offsets[r] + ramps @ np.diff(slopes)
    np.testing.assert_allclose(f, system.force(xs), atol=1e-10 * (1 + np.abs(f).max()))
    if lcp.D <= 0.0:
        assert not lcp.p_matrix and h > lcp.h_max
        return
    minors = principal_minors(lcp.M)
    assert lcp.min_minor == pytest.approx(min(minors), abs=1e-9)
    if abs(lcp.min_minor) > 1e-9:
        assert lcp.p_matrix == is_p_matrix(lcp.M) == (h < lcp.h_max)


def test_nsd_step_bound_is_sharp_and_enforced():
    """nsd: the softest segment has slope k = −2, so h_max solves 1 + hθµ + h²θ²k = 0."""
    system = nsd()
    theta, mu, k = 0.5, 0.05, -2.0
    h_max = (mu + math.sqrt(mu * mu - 4.0 * k)) / (-2.0 * theta * k)
    assert step_lcp(system, 1.0).h_max == pytest.approx(h_max, rel=1e-14)
    assert h_max == pytest.approx(1.4394345, rel=1e-6)
    assert step_lcp(system, 0.999 * h_max).p_matrix
    above = step_lcp(system, 1.001 * h_max)
    assert not above.p_matrix and not is_p_matrix(above.M)
    # beyond h_max the step really is ill-posed: x_{n+1} solves g(x) = xi with
    # g(x) = x + c[-3(x + 1)_+ + 3(x - 1)_+] (reference segment 0), whose middle slope 1 - 3c
    # is now negative; xi = g(0) = -3c has three solutions x_{n+1}, one in each segment
    big = step_lcp(system, 1.3 * h_max)
    assert big.reference == 0 and 1.0 - 3.0 * big.c < 0.0
    sols = enumerate_lcp(big.M, big.q(-3.0 * big.c, system.breakpoints))
    assert len(sols) == 3
    with pytest.raises(PerturbError, match=r"not a P-matrix.*smaller step, h < 1\.43943"):
        simulate_lcp(system, (0.0, 0.0), (0.0, 3 * 1.001 * h_max), 1.001 * h_max)
    # stiffening springs never lose the P-property
    assert step_lcp(clearance(), 1e3).h_max == math.inf


# ---------------------------------------------------------------------------------------------
# convergence against the exact propagator
# ---------------------------------------------------------------------------------------------
N_PER_PERIOD = (50, 100, 200, 400, 800, 1600, 3200)
PERIODS = 10


@functools.cache
def nsd_attractor_state() -> tuple[float, float]:
    T = TWO_PI / 0.6
    x, v = propagate(nsd(), (0.0, 0.0), (0.0, 100 * T))(100 * T)
    return float(x), float(v)


@functools.cache
def convergence(name: str, theta: float) -> dict:
    if name == "nsd":
        system, W, y0 = nsd(), 0.6, nsd_attractor_state()
    else:
        system, W, y0 = clearance(), 0.9, (0.0, 0.0)
    T = TWO_PI / W
    exact = propagate(system, y0, (0.0, PERIODS * T))
    hs, e_end, e_max, lam_err = [], [], [], []
    for n in N_PER_PERIOD:
        tr = simulate_lcp(system, y0, (0.0, PERIODS * T), T / n, theta=theta)
        X = exact(tr.t)
        err = np.hypot(tr.x - X[0], tr.v - X[1])
        hs.append(tr.h)
        e_end.append(float(err[-1]))
        e_max.append(float(err.max()))
        ramps = np.maximum(tr.sigma * (X[0][:, None] - system.breakpoints), 0.0)
        lam_err.append(float(np.abs(tr.lam - ramps).max()))
    lh = np.log(hs)
    return {
        "h": np.array(hs),
        "e_end": np.array(e_end),
        "e_max": np.array(e_max),
        "lam_err": np.array(lam_err),
        "order_end": float(np.polyfit(lh, np.log(e_end), 1)[0]),
        "order_max": float(np.polyfit(lh, np.log(e_max), 1)[0]),
        "n_switches": len(exact.switches),
    }


# measured (this machine; deterministic up to rounding): (order_max, order_end, e_max(T/3200))
ORDERS = {
    ("nsd", 0.5): (2.04, 2.49, 2.33e-5),
    ("clearance", 0.5): (1.92, 1.86, 2.87e-4),
    ("nsd", 1.0): (0.95, 1.00, 6.18e-2),
}


@pytest.mark.parametrize("name", ["nsd", "clearance"])
def test_trapezoidal_order_is_two(name):
    res = convergence(name, 0.5)
    assert res["n_switches"] >= 15  # the kinks are really crossed, many times
    assert 1.8 <= res["order_max"] <= 2.3, res
    assert 1.6 <= res["order_end"] <= 2.6, res
    # error decreases by >= 3.3x per halving on average (2^1.7), not only in the fit
    ratio = res["e_max"][0] / res["e_max"][-1]
    assert ratio >= 64.0**1.7


@pytest.mark.parametrize("key", list(ORDERS))
def test_measured_orders_are_the_reported_ones(key):
    """Regression guard on the numbers quoted in the module docstring and the final report."""
    res = convergence(*key)
    order_max, order_end, e_finest = ORDERS[key]
    assert res["order_max"] == pytest.approx(order_max, abs=0.01)
    assert res["order_end"] == pytest.approx(order_end, abs=0.01)
    assert res["e_max"][-1] == pytest.approx(e_finest, rel=0.01)


def test_backward_euler_order_is_one():
    res = convergence("nsd", 1.0)
    assert 0.9 <= res["order_max"] <= 1.1, res
    assert 0.9 <= res["order_end"] <= 1.1, res


@pytest.mark.parametrize(("name", "bound"), [("nsd", 5e-5), ("clearance", 6e-4)])
def test_finest_step_agrees_to_predicted_accuracy(name, bound):
    """At h = T/3200 the error is what the second-order fit of the coarser steps predicts."""
    res = convergence(name, 0.5)
    h, e = res["h"], res["e_max"]
    p, logC = np.polyfit(np.log(h[:-1]), np.log(e[:-1]), 1)
    predicted = math.exp(logC) * h[-1] ** p
    assert predicted / 3.0 <= e[-1] <= 3.0 * predicted
    assert e[-1] <= bound  # measured 2.3e-5 (nsd, |x| up to 9.5) and 2.9e-4 (clearance)
    # the complementarity variables are (sigma (x - d))_+ of the exact orbit to the same
    # accuracy (the map is 1-Lipschitz in x)
    assert res["lam_err"][-1] <= e[-1] * (1 + 1e-9)


def test_linear_system_no_breakpoints():
    """m = 0: plain trapezoidal rule on x'' + 0.1x' + 2x = cos t; second order, empty LCP."""
    system = PWLSystem([], [2.0], [0.0], damping=0.1, forcing=((1.0, 1.0, 0.0),))
    exact = propagate(system, (1.0, 0.0), (0.0, 20.0))
    errs = []
    for h in (0.04, 0.02, 0.01):
        tr = simulate_lcp(system, (1.0, 0.0), (0.0, 20.0), h)
        assert tr.lam.shape == (tr.t.size, 0) and tr.n_pivots == 0
        errs.append(np.abs(tr.x - exact(tr.t)[0]).max())
    assert errs[0] / errs[1] == pytest.approx(4.0, rel=0.05)
    assert errs[1] / errs[2] == pytest.approx(4.0, rel=0.05)


# ---------------------------------------------------------------------------------------------
# energy
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("x0", [6.0, 0.5])
def test_energy_free_undamped_nsd(x0):
    r"""Free undamped nsd, θ = 1/2, 100 periods.

    Expected: per step ΔE = ∫f − trapezoid(f) over [x_n, x_{n+1}], which is 0 for a step in
    one segment (f affine) and ∓Δs (x_{n+1} − d)(d − x_n)/2 — at most |Δs| Δx²/8 — for a step
    across the kink d.  So (i) no energy change away from the kinks, (ii) each crossing kicks E
    by at most |Δs| Δx²/8 = 3 Δx²/8, with signs that alternate between entering and leaving;
    over 100 periods the error stays O(h²) (bounded, no drift).  Measured at h = P/100:
    max |E − E0| = 2.2e-2 (x0 = 6, over all three segments) and 2.9e-3 (x0 = 0.5, one well),
    against the worst-case sum of the kicks 9.4 and 0.6 and their random-walk scale
    √(Σ kick²) = 0.47 and 0.042; at h = P/400 the drift is 16x and 3.3x smaller.
    """
    system = nsd(F=0.0, mu=0.0)
    # the period from the exact propagator: time between two upward crossings of x = 1
    ex = propagate(system, (x0, 0.0), (0.0, 40.0))
    ups = [e.time for e in ex.switches if e.breakpoint == 1 and e.direction == 1]
    P = ups[1] - ups[0]
    drift = {}
    for n in (100, 400):
        tr = simulate_lcp(system, (x0, 0.0), (0.0, 100 * P), P / n)
        E = 0.5 * tr.v**2 + nsd_potential(tr.x)
        dE = np.diff(E)
        lo = np.minimum(tr.x[1:], tr.x[:-1])
        hi = np.maximum(tr.x[1:], tr.x[:-1])
        n_kinks = ((lo < -1.0) & (hi > -1.0)).astype(int) + ((lo < 1.0) & (hi > 1.0))
        kick = 3.0 * n_kinks * np.diff(tr.x) ** 2 / 8.0
        rounding = 1e-12 * (1.0 + abs(E[0]))
        assert n_kinks.sum() >= 190  # two (x0 = 0.5) or four (x0 = 6) crossings per period
        assert np.all(np.abs(dE[n_kinks == 0]) <= rounding)
        assert np.all(np.abs(dE) <= kick * (1.0 + 1e-9) + rounding)
        drift[n] = float(np.abs(E - E[0]).max())
        # no systematic drift: the deviation stays below the random-walk scale of the kicks
        # (a drift would grow like their sum, 9.4 and 0.6 at h = P/100)
        assert drift[n] <= math.sqrt(np.sum(kick**2))
    E_scale = float(nsd_potential(np.array(x0)) - nsd_potential(np.array(3.0)))
    assert drift[100] <= 0.01 * E_scale  # E_scale = E0 − min G = 4.5 or 2.75
    assert drift[400] <= drift[100] / 2.0  # O(h²) up to the kink-position wobble


# ---------------------------------------------------------------------------------------------
# API, consistency and bad input
# ---------------------------------------------------------------------------------------------
def test_trajectory_is_consistent():
    system = nsd()
    tr = simulate_lcp(system, (0.2, 0.0), (0.0, 40.0), 0.05)
    assert isinstance(tr, LCPTrajectory)
    n = tr.t.size
    assert tr.x.shape == tr.v.shape == (n,) and tr.lam.shape == (n, 2) and tr.y.shape == (2, n)
    assert tr.n_steps == 800 and tr.t[0] == 0.0 and tr.t[-1] == 40.0
    # the LCP variables are the ramps of the discrete x, and complementary to w
    np.testing.assert_allclose(tr.lam, np.maximum(tr.sigma * (tr.x[:, None] - [-1, 1]), 0),
                               atol=1e-13)  # fmt: skip
    assert tr.w.min() >= -1e-13 and np.abs(tr.lam * tr.w).max() <= 1e-13
    # the scheme's equations hold at every step (trapezoidal rule, theta = 1/2)
    f = system.force(tr.x)
    L = system.load(tr.t)
    h = tr.h
    np.testing.assert_allclose(np.diff(tr.x), h * (tr.v[1:] + tr.v[:-1]) / 2, atol=1e-13)
    acc = -0.05 * tr.v - f + L
    np.testing.assert_allclose(np.diff(tr.v), h * (acc[1:] + acc[:-1]) / 2, atol=1e-13)
    with pytest.raises(AttributeError):
        tr.h = 1.0  # type: ignore[misc]
    assert not tr.x.flags.writeable


def test_step_is_made_uniform():
    tr = simulate_lcp(nsd(), (0.0, 0.0), (1.0, 2.0), 0.3)
    assert tr.n_steps == 4 and tr.h == pytest.approx(0.25)
    np.testing.assert_allclose(tr.t, [1.0, 1.25, 1.5, 1.75, 2.0])
    assert simulate_lcp(nsd(), (0.0, 0.0), (0.0, 1.0), 1.0).n_steps == 1  # h = span is fine


@pytest.mark.parametrize("name", ["nsd", "clearance", "deadzone", "saturation", "bilinear"])
def test_oscillator_input_and_cold_lemke(name):
    osc = builtin_model(name)
    system = to_pwl_system(osc)
    a = simulate_lcp(osc, (0.3, 0.0), (0.0, 15.0), 0.02)
    b = simulate_lcp(system, (0.3, 0.0), (0.0, 15.0), 0.02)
    np.testing.assert_array_equal(a.x, b.x)
    # Lemke at every step instead of the warm-started basis: same solution
    c = simulate_lcp(system, (0.3, 0.0), (0.0, 15.0), 0.02, warm_start=False)
    assert c.n_lcp_solves == c.n_steps and c.n_pivots >= b.n_pivots
    np.testing.assert_allclose(c.x, b.x, atol=1e-11)
    np.testing.assert_allclose(c.lam, b.lam, atol=1e-11)


def test_omega_override():
    osc = builtin_model("nsd", k=-2, mu=0.05, F=2, Omega=1.0)
    a = simulate_lcp(osc, (0.0, 0.0), (0.0, 10.0), 0.05, Omega=0.6)
    b = simulate_lcp(nsd(), (0.0, 0.0), (0.0, 10.0), 0.05)
    np.testing.assert_array_equal(a.x, b.x)
    with pytest.raises(ParameterError, match="Oscillator only"):
        simulate_lcp(nsd(), (0.0, 0.0), (0.0, 10.0), 0.05, Omega=0.6)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"y0": (math.nan, 0.0)}, "y0.*finite"),
        ({"y0": (0.0, math.inf)}, "y0.*finite"),
        ({"y0": (0.0, 0.0, 0.0)}, "two values"),
        ({"h": 0.0}, r"h = 0\.0: expected a step size h > 0"),
        ({"h": -0.1}, "h > 0"),
        ({"h": math.nan}, "finite"),
        ({"h": 10.5}, "larger than the time span"),
        ({"t_span": (1.0, 0.0)}, "t1 > t0"),
        ({"t_span": (0.0, math.nan)}, "finite"),
        ({"theta": 0.4}, "theta = 0.4"),
        ({"theta": 1.5}, "theta"),
        ({"max_steps": 10}, "max_steps"),
    ],
)
def test_bad_input(kwargs, match):
    args = {"y0": (0.0, 0.0), "t_span": (0.0, 10.0), "h": 0.1} | kwargs
    y0, t_span, h = args.pop("y0"), args.pop("t_span"), args.pop("h")
    with pytest.raises(ParameterError, match=match):
        simulate_lcp(nsd(), y0, t_span, h, **args)


def test_discontinuous_force_is_rejected():
    relay = PWLSystem([0.0], [1.0, 1.0], [-0.5, 0.5], damping=0.1, forcing=((1.0, 1.0, 0.0),))
    with pytest.raises(PerturbError, match=r"jumps at x = 0\.0.*event-driven"):
        simulate_lcp(relay, (0.1, 0.0), (0.0, 1.0), 0.01)
    osc = Oscillator.parse("x'' + 0.1*x' + x + Heaviside(x - 1) = cos(t)", {}, name="step")
    with pytest.raises(PerturbError, match="event-driven"):
        simulate_lcp(osc, (0.1, 0.0), (0.0, 1.0), 0.01)


def test_non_pwl_and_wrong_types_are_rejected():
    with pytest.raises(ModelError, match="not piecewise linear"):
        simulate_lcp(builtin_model("duffing"), (0.1, 0.0), (0.0, 1.0), 0.01)
    with pytest.raises(ParameterError, match="PWLSystem"):
        simulate_lcp("nsd", (0.1, 0.0), (0.0, 1.0), 0.01)  # type: ignore[arg-type]


def test_escaping_orbit_overflows_clearly():
    """A purely negative spring drives the orbit to infinity: a clear error, not NaNs."""
    system = PWLSystem([1.0], [-1.0, -1.0], [0.0, 0.0])
    with pytest.raises(PerturbError, match="overflow"):
        simulate_lcp(system, (0.5, 0.0), (0.0, 2000.0), 0.1)
