"""Hill's method must return two DISTINCT Floquet multipliers (issue 18, item 3c).

Beyond a period-doubling both multipliers are real and negative: the exponents are
``a + i w/2`` and ``b + i w/2``, and ``a + i w/2`` and its conjugate ``a - i w/2`` (equally
centred, equally small ``|Im|``) are one multiplier counted twice. The old selection took that
conjugate pair, so on a stiff one-sided stop H = 15 reported only the unstable multiplier
(-4.56, twice) and H = 31 only the stable one (-0.172, twice): the verdict flipped with H.

Oracle: the monodromy of the exact orbit by solve_ivp (DOP853, rtol 1e-11) on the state and
its variational equations, split at the contact events (the force is continuous, so no
saltation); the orbit's initial state is checked to be periodic by the same integration.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import perturb
from perturb.numeric.harmonic_balance import HarmonicBalanceSystem, harmonic_balance_orbit
from perturb.numeric.stability import hill_exponents
from perturb.simulate.flows.factory import FlowFamily
from perturb.simulate.orbits.shooting import periodic_orbit

MU, K, D, F = 0.1, 50.0, 0.5, 4.0
EQ = f"x'' + {MU}*x' + x + {K}*(x-{D})*Heaviside(x-{D}) = {F}*cos(Omega*t)"


def _stop_monodromy(y0, W, max_segments=200):
    """``(phi(T), M)`` of the stop oscillator from ``y0`` by DOP853 between contact events."""

    def rhs(t, z, inside):
        x, v = z[0], z[1]
        q = 1.0 + (K if inside else 0.0)
        Y = z[2:].reshape(2, 2)
        A = np.array([[0.0, 1.0], [-q, -MU]])
        f = F * np.cos(W * t) - MU * v - x - (K * (x - D) if inside else 0.0)
        return np.concatenate([[v, f], (A @ Y).ravel()])

    def contact(t, z, inside):
        return z[0] - D

    contact.terminal = True
    T = 2 * np.pi / W
    t, z = 0.0, np.concatenate([np.asarray(y0, float), np.eye(2).ravel()])
    for _ in range(max_segments):
        inside = z[0] > D or (z[0] == D and z[1] > 0)
        sol = solve_ivp(
            rhs,
            (t, T),
            z,
            method="DOP853",
            rtol=1e-11,
            atol=1e-12,
            events=contact,
            args=(inside,),
        )
        t, z = sol.t[-1], sol.y[:, -1].copy()
        if sol.status == 0:
            return z[:2], z[2:].reshape(2, 2)
        # restart just past the crossing in the other piece (z[0] = D exactly)
        z[0] = D
        inside = z[1] > 0
        nxt = solve_ivp(
            rhs,
            (t, min(T, t + 1e-9)),
            z,
            method="DOP853",
            rtol=1e-11,
            atol=1e-12,
            args=(inside,),
        )
        t, z = nxt.t[-1], nxt.y[:, -1].copy()
        if t >= T:
            return z[:2], z[2:].reshape(2, 2)
    raise AssertionError("oracle: too many contact segments in one period")


@pytest.fixture(scope="module")
def case():
    osc = perturb.Oscillator.parse(EQ)
    W = 2.6  # beyond the period-doubling at W ~ 2.31: multipliers -4.559 and -0.172
    ref = harmonic_balance_orbit(osc, W, harmonics=63)
    orbit = periodic_orbit(FlowFamily(osc).at(W), [float(ref(0.0)), float(ref.velocity(0.0))])
    end, M = _stop_monodromy(orbit.y0, W)
    assert np.max(np.abs(end - orbit.y0)) < 1e-8  # the oracle's orbit is periodic
    exact = np.sort(np.linalg.eigvals(M).real)
    assert np.all(np.abs(np.linalg.eigvals(M).imag) < 1e-9)
    assert exact[0] < -1.0 < exact[1] < 0.0  # unstable, both multipliers real negative
    return osc, W, orbit, exact


@pytest.mark.parametrize("H", [15, 31])
def test_full_hill_finds_both_negative_multipliers(case, H):
    osc, W, orbit, exact = case
    sol = harmonic_balance_orbit(osc, W, harmonics=H, guess=orbit)
    mult = np.exp(sol.exponents * 2 * np.pi / W)
    got = np.sort(mult.real)
    assert np.all(np.abs(mult.imag) < 1e-3 * np.abs(mult))
    np.testing.assert_allclose(got, exact, rtol=2e-3 if H == 15 else 1e-4)
    assert not sol.stable
    assert sol.max_multiplier == pytest.approx(abs(exact[0]), rel=2e-3)
    # the continuation's fast path (exact monodromy about the HB orbit + Ruhe) agrees
    system = HarmonicBalanceSystem(osc, harmonics=H)
    fast = np.exp(system.hill_exponents(sol.coefficients, W) * 2 * np.pi / W)
    np.testing.assert_allclose(np.sort(fast.real), exact, rtol=2e-3 if H == 15 else 1e-4)


@pytest.mark.parametrize("H", [15, 31])
def test_floquet_hill_exponents_distinct_on_sampled_orbit(case, H):
    osc, W, orbit, exact = case
    t, x, v = orbit.sample(2048)
    lam = hill_exponents(osc.with_params({"Omega": W}), x[None, :], v[None, :], [2 * np.pi / W], H)
    mult = np.exp(lam[0] * 2 * np.pi / W)
    np.testing.assert_allclose(np.sort(mult.real), exact, rtol=2e-3 if H == 15 else 2e-4)


def test_complex_pair_still_conjugate():
    """Below the period-doubling the multipliers are a complex pair of modulus e^{-mu T/2}."""
    osc = perturb.Oscillator.parse(EQ)
    W = 1.5
    sol = harmonic_balance_orbit(osc, W, harmonics=31)
    orbit = periodic_orbit(FlowFamily(osc).at(W), [float(sol(0.0)), float(sol.velocity(0.0))])
    end, M = _stop_monodromy(orbit.y0, W)
    exact = np.linalg.eigvals(M)
    mult = np.exp(sol.exponents * 2 * np.pi / W)
    key = lambda z: (z.real, z.imag)  # noqa: E731
    np.testing.assert_allclose(
        sorted(mult, key=key), sorted(exact, key=key), atol=2e-4 * np.abs(exact).max()
    )


# ---------------------------------------------------------------------------------------------
# item 3b: Coulomb friction, x'' + c x' + x + r sign(x') = cos(W t)
# ---------------------------------------------------------------------------------------------
C_F, R_F = 0.1, 0.2


def _coulomb_period_map(y0, W, max_segments=100):
    """One forcing period by DOP853 (rtol 1e-12) between velocity reversals (events v = 0);
    the orbits used here never stick."""

    def rhs(t, y, s):
        return [y[1], np.cos(W * t) - C_F * y[1] - y[0] - R_F * s]

    def reversal(t, y, s):
        return y[1]

    reversal.terminal = True
    T = 2 * np.pi / W
    t, y = 0.0, np.asarray(y0, float)
    s = np.sign(y[1]) if y[1] != 0 else np.sign(1.0 - y[0])
    for _ in range(max_segments):
        sol = solve_ivp(
            rhs, (t, T), y, method="DOP853", rtol=1e-12, atol=1e-13, events=reversal, args=(s,)
        )
        t, y = sol.t[-1], sol.y[:, -1].copy()
        if sol.status == 0:
            return y
        y[1] = 0.0
        assert np.sign(np.cos(W * t) - y[0] + R_F * s) == -s, "oracle: the orbit sticks"
        s = -s
        sol = solve_ivp(
            rhs, (t, min(T, t + 1e-7)), y, method="DOP853", rtol=1e-12, atol=1e-13, args=(s,)
        )
        t, y = sol.t[-1], sol.y[:, -1].copy()
        if t >= T:
            return y
    raise AssertionError("oracle: too many reversals")


def _coulomb_exact_multipliers(y, W, h=1e-7):
    """Periodic orbit by Newton on the exact period map, multipliers by central differences."""
    for _ in range(30):
        P = _coulomb_period_map(y, W)
        J = np.column_stack(
            [
                (_coulomb_period_map(y + h * e, W) - _coulomb_period_map(y - h * e, W)) / (2 * h)
                for e in np.eye(2)
            ]
        )
        dy = np.linalg.solve(J - np.eye(2), y - P)
        y = y + dy
        if np.abs(dy).max() < 1e-11:
            break
    else:
        raise AssertionError("oracle: no periodic orbit")
    M = np.column_stack(
        [
            (_coulomb_period_map(y + h * e, W) - _coulomb_period_map(y - h * e, W)) / (2 * h)
            for e in np.eye(2)
        ]
    )
    return np.linalg.eigvals(M)


@pytest.mark.parametrize("W", [0.8, 1.3])
def test_coulomb_hill_multipliers_include_reversal_saltation(W):
    """The exact monodromy has det = e^{-cT} prod(a+/a-) over the reversals; without the
    Dirac term of d sign(x')/dx' Hill gave |multiplier| = e^{-cT/2} (0.675 at W = 0.8 against
    0.524 exact, 0.785 against 0.654 at W = 1.3)."""
    osc = perturb.Oscillator.parse(f"x'' + {C_F}*x' + x + {R_F}*sign(x') = cos(Omega*t)")
    T = 2 * np.pi / W
    sol = harmonic_balance_orbit(osc, W, harmonics=31)
    assert sol.projection == "aft"
    exact = _coulomb_exact_multipliers(np.array([float(sol(0.0)), float(sol.velocity(0.0))]), W)
    assert abs(np.prod(exact)) < 0.8 * np.exp(-C_F * T)  # the saltation matters here
    mult = np.exp(sol.exponents * T)
    np.testing.assert_allclose(np.abs(mult), np.abs(exact), rtol=1e-2)
    np.testing.assert_allclose(abs(np.prod(mult)), abs(np.prod(exact)), rtol=2e-2)
    assert sol.max_multiplier == pytest.approx(np.abs(exact).max(), rel=1e-2)
