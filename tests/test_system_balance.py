"""Numeric multi-harmonic balance of systems of several coordinates
(perturb.numeric.system_balance), against independent oracles:

* the exact periodic orbit of the piecewise-affine system (closed-form propagation,
  ``periodic_orbit`` on ``AffineExactFlow``) and its Fourier series (FFT of dense samples),
  for the monodromy (the accuracy against the truncation floor, H = 1..63, is
  tests/test_system_balance_accuracy.py);
* the closed form ``(K - w^2 M + i w C)^-1 F`` per harmonic for a linear system (derived here,
  matrices written by hand);
* central finite differences of the residual for the Jacobian;
* the exact orbit's Floquet multipliers for the stability on a branch with folds.
"""

from __future__ import annotations

import numpy as np
import pytest

from perturb.errors import PerturbError
from perturb.model.system import System
from perturb.model.system_builtins import builtin_system
from perturb.numeric.system_balance import (
    SystemBalance,
    system_balance_branch,
    system_balance_orbit,
)
from perturb.simulate.flows.factory import make_flow
from perturb.simulate.orbits.shooting import periodic_orbit

N_SAMPLES = 2**14


def _exact_orbit(system: System, W: float, y_guess: np.ndarray):
    flow = make_flow(system.with_params(Omega=W), W)
    T = 2 * np.pi / W
    orb = periodic_orbit(flow, y_guess)
    t = np.arange(N_SAMPLES) * T / N_SAMPLES
    Y = np.asarray(flow(orb.y0, 0.0, T, t_eval=t).ys)
    return orb, t, Y


def _coefficients(Y: np.ndarray, H: int) -> np.ndarray:
    """Rows ``[a0, a1, b1, ...]`` of the sampled coordinates (columns of ``Y``), cut at H."""
    X = np.fft.rfft(Y, axis=0) / Y.shape[0]
    U = np.zeros((Y.shape[1], 2 * H + 1))
    U[:, 0] = X[0].real
    U[:, 1::2] = 2 * X[1 : H + 1].real.T
    U[:, 2::2] = -2 * X[1 : H + 1].imag.T
    return U


def test_linear_system_equals_closed_form():
    """M q'' + C q' + K q + E p + D p' = F: closed form per harmonic, two coordinates and a
    first-order state, forcing at Omega and 2 Omega."""
    eqs = [
        "2*x1'' + 0.1*x1' + 3*x1 - x2 + 0.5*p = 1.5*cos(Omega*t) + 0.2",
        "x2'' + 0.05*(x2' - x1') + x2 - x1 = 0.7*sin(2*Omega*t)",
        "0.3*p' + p - 0.4*x1' = 0",
    ]
    system = System.parse(eqs, {"Omega": 0.9})
    W = 0.9
    M = np.array([[2.0, 0, 0], [0, 1.0, 0], [0, 0, 0]])
    C = np.array([[0.1, 0, 0], [-0.05, 0.05, 0], [-0.4, 0, 0.3]])  # columns (x1', x2', p')
    K = np.array([[3.0, -1.0, 0.5], [-1.0, 1.0, 0], [0, 0, 1.0]])
    for H in (3, 7):
        sol = system_balance_orbit(system, W, harmonics=H)
        U = sol.U
        # bias: K z0 = F0
        z0 = np.linalg.solve(K, [0.2, 0, 0])
        assert np.allclose(U[:, 0], z0, rtol=0, atol=1e-12)
        for k, Fk in ((1, np.array([1.5, 0, 0])), (2, np.array([0, -0.7j, 0]))):
            w = k * W
            Z = np.linalg.solve(K - w**2 * M + 1j * w * C, Fk.astype(complex))
            # z = Re(Z e^{iwt}) = a cos + b sin with a = Re Z, b = -Im Z
            assert np.allclose(U[:, 2 * k - 1], Z.real, rtol=0, atol=1e-12)
            assert np.allclose(U[:, 2 * k], -Z.imag, rtol=0, atol=1e-12)
        assert np.abs(U[:, 5:]).max() <= 1e-12
        assert sol.stable


@pytest.mark.parametrize("name", ["nsd2", "impact_pair"])
def test_jacobian_matches_central_differences(name):
    system = builtin_system(name)
    sb = SystemBalance(system, 7)
    rng = np.random.default_rng(3)
    # a signal large enough to cross every breakpoint several times
    u = rng.standard_normal(sb.n_unknowns) * np.tile(1.0 / (1 + np.arange(sb.size)) ** 2, sb.neq)
    u[:: sb.size] += 0.2
    u *= 3.0
    W = 1.1
    r, J, dW = sb.evaluate(u, W)
    h = 1e-6
    Jfd = np.empty_like(J)
    for i in range(u.size):
        e = np.zeros(u.size)
        e[i] = h
        Jfd[:, i] = (sb.evaluate(u + e, W, False)[0] - sb.evaluate(u - e, W, False)[0]) / (2 * h)
    dWfd = (sb.evaluate(u, W + h, False)[0] - sb.evaluate(u, W - h, False)[0]) / (2 * h)
    scale = np.abs(J).max()
    assert np.abs(J - Jfd).max() <= 1e-7 * scale
    assert np.abs(dW - dWfd).max() <= 1e-7 * max(1.0, np.abs(dW).max())
    Js = sb.evaluate(u, W, True, sparse=True)[1]
    assert np.abs(Js.toarray() - J).max() == 0.0


def test_stability_agrees_with_exact_orbits_on_branch_with_folds():
    """nsd2 with a hardening device (k = 0.3, F = 0.6): the branch from Omega = 2 has folds;
    HB stability (monodromy of the linearisation about the HB orbit, H = 15) agrees with the
    exact orbit's Floquet multipliers at points on both sides of every fold."""
    system = builtin_system("nsd2").with_params(k=0.3, F=0.6)
    br = system_balance_branch(system, (0.5, 2.0), harmonics=15)
    assert len(br.folds) >= 2
    assert br.stable is not None and br.stable.any() and not br.stable.all()
    # points clearly off the unit circle, every 8th, plus those next to the folds
    margin = np.abs(br.max_multiplier - 1.0) > 0.02
    idx = set(np.flatnonzero(margin)[::8].tolist())
    for lam in br.folds:
        near = np.argsort(np.abs(br.Omega - lam))[:12]
        idx |= {int(i) for i in near if margin[i]}
    checked = {True: 0, False: 0}
    for p in sorted(idx):
        W = float(br.Omega[p])
        sb_state = _branch_state(br, p)
        flow = make_flow(system.with_params(Omega=W), W)
        orb = periodic_orbit(flow, sb_state)
        assert np.abs(orb.y0 - sb_state).max() < 1e-2 * max(1.0, np.abs(orb.y0).max())
        exact_stable = orb.max_multiplier <= 1.0 + 1e-6
        assert bool(br.stable[p]) == exact_stable, (W, br.max_multiplier[p], orb.max_multiplier)
        checked[exact_stable] += 1
    assert checked[True] >= 3 and checked[False] >= 3


def _branch_state(br, p: int) -> np.ndarray:
    U = br.U[p]
    H = (U.shape[1] - 1) // 2
    k = np.arange(1, H + 1)
    W = float(br.Omega[p])
    q = U[:, 0] + U[:, 1::2].sum(axis=1)
    v = W * (U[:, 2::2] * k).sum(axis=1)
    return np.concatenate([q, v])


def test_bad_input():
    system = builtin_system("nsd2")
    with pytest.raises(PerturbError, match="harmonics = 0"):
        SystemBalance(system, 0)
    with pytest.raises(PerturbError, match="expected an integer"):
        system_balance_orbit(system, 1.0, harmonics=-3)
    # an element whose combination is identically zero for the parameter values
    zero = System.parse(
        ["x1'' + 0.1*x1' + x1 + (a*x1 - 1)*Heaviside(a*x1 - 1) = cos(Omega*t)"],
        {"a": 0.0, "Omega": 1.0},
    )
    with pytest.raises(PerturbError, match="never changes sign|identically zero"):
        SystemBalance(zero, 3)
    with pytest.raises(PerturbError, match="x3"):
        system_balance_branch(system, (1.0, 2.0), harmonics=3, output="x3")
    with pytest.raises(PerturbError, match="expected an integer harmonic"):
        # the forcing at Omega is harmonic 2 of Omega/2: not in a basis of H = 1
        SystemBalance(system, 1, m=2)
    with pytest.raises(PerturbError, match="window"):
        system_balance_branch(system, (2.0, 1.0), harmonics=3)


def test_subharmonic_basis_of_linear_system():
    """m = 2 (response period two forcing periods): the forcing at Omega is harmonic 2 of
    Omega/2; a linear system's solution is the closed form there and zero elsewhere."""
    system = System.parse(
        ["x1'' + 0.1*x1' + 2*x1 - x2 = cos(Omega*t)", "x2'' + 0.2*x2' + x2 - x1 = 0"],
        {"Omega": 1.3},
    )
    W = 1.3
    sol = system_balance_orbit(system, W, harmonics=5, m=2)
    M = np.eye(2)
    C = np.diag([0.1, 0.2])
    K = np.array([[2.0, -1.0], [-1.0, 1.0]])
    Z = np.linalg.solve(K - W**2 * M + 1j * W * C, np.array([1.0, 0.0], dtype=complex))
    U = sol.U
    assert np.allclose(U[:, 3], Z.real, rtol=0, atol=1e-12)
    assert np.allclose(U[:, 4], -Z.imag, rtol=0, atol=1e-12)
    others = np.delete(U, [3, 4], axis=1)
    assert np.abs(others).max() <= 1e-12
    # sampled at the forcing period, the m = 2 series repeats
    t = np.linspace(0, 2 * np.pi / W, 7)
    assert np.allclose(sol(t, "x1"), sol(t + 2 * np.pi / W, "x1"), rtol=0, atol=1e-12)


def test_monodromy_with_a_jump_equals_exact_orbit():
    """A force that jumps (0.3 H(x1 - x2 - 0.2)) between two masses: the monodromy of the
    linearisation about the exact orbit's series (H = 400), with the saltation matrices at the
    jumps, equals the exact orbit's monodromy (AffineExactFlow, closed-form propagation with
    saltation); the H = 31 HB orbit's multipliers are within 1e-3 of the exact ones."""
    system = System.parse(
        [
            "x1'' + 0.1*x1' + x1 - 0.5*(x2 - x1) + 0.3*Heaviside(x1 - x2 - 0.2) = cos(Omega*t)",
            "x2'' + 0.05*x2' + 0.5*(x2 - x1) - 0.3*Heaviside(x1 - x2 - 0.2) = 0",
        ],
        {"Omega": 0.8},
    )
    W = 0.8
    sol = system_balance_orbit(system, W, harmonics=31)
    orb, _, Y = _exact_orbit(system, W, sol.state(0.0))
    mu_exact = np.sort(np.abs(orb.multipliers))
    assert np.abs(np.sort(np.abs(sol.multipliers)) - mu_exact).max() < 1e-3
    H = 400
    sb = SystemBalance(system, H)
    mono = sb.monodromy(_coefficients(Y[:, :2], H).reshape(-1), W)
    assert np.abs(mono - orb.monodromy).max() < 2e-4


def test_branch_response_columns_and_output():
    """The branch's output measures equal the coordinates' ones for output = a coordinate,
    and the Response branch carries them; the output x1 - x2 is measured on its own series."""
    system = builtin_system("nsd2").with_params(k=0.3, F=0.6)
    br = system_balance_branch(system, (1.7, 2.0), harmonics=7, output="x1 - x2")
    assert br.output == "x1 - x2"
    cols = br.columns()
    assert set(cols) == {"amplitude_x1", "amplitude_x2", "mean_x1", "mean_x2"}
    W = br.Omega
    # independent: the difference series sampled densely
    th = np.linspace(0, 2 * np.pi, 4001)
    H = 7
    k = np.arange(1, H + 1)
    D = br.U[:, 0, :] - br.U[:, 1, :]
    vals = D[:, :1] + D[:, 1::2] @ np.cos(np.outer(k, th)) + D[:, 2::2] @ np.sin(np.outer(k, th))
    assert np.allclose(br.output_amplitude, np.abs(vals).max(axis=1), rtol=1e-6, atol=0)
    resp = br.to_response()
    b = resp.branches[0]
    assert np.array_equal(b.omega, W) and np.array_equal(b.amplitude, br.output_amplitude)
    assert np.allclose(b.first_harmonic_amplitude, np.hypot(D[:, 1], D[:, 2]))
    br1 = system_balance_branch(system, (1.7, 2.0), harmonics=7, output="x2")
    assert np.allclose(br1.output_amplitude, br1.amplitudes["x2"], rtol=1e-12, atol=0)
