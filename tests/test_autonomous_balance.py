"""Autonomous harmonic balance (limit cycles with unknown frequency) against independent
oracles: the van der Pol series in eps and its literature period at eps = 1, a DOP853
(rtol = atol = 1e-12) shooting of the cycle and of its monodromy written here, SciPy
quadrature of the projected friction force, finite differences of its Jacobian, and the
event-driven exact stick-slip cycle of the belt (perturb.solve.limit_cycles)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp
from scipy.optimize import brentq

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.model.builtins import builtin_model
from perturb.model.system import System
from perturb.model.system_builtins import builtin_system
from perturb.numeric.autonomous_balance import (
    AutonomousBalance,
    AutonomousBalanceError,
    autonomous_balance_branch,
    autonomous_balance_orbit,
)

VDP = "x'' - eps*(1 - x**2)*x' + x = 0"


def vdp(eps: float) -> System:
    return System.parse([VDP], {"eps": eps}, name="vdp")


def vdp_shooting(eps: float):
    """Period, max|x| and the monodromy of the van der Pol cycle by DOP853 shooting: the
    cycle started at its maximum (x' = 0, x > 0), period = the time of the next maximum."""

    def f(t, z):
        x, v = z[0], z[1]
        out = [v, eps * (1 - x * x) * v - x]
        if z.size > 2:
            Phi = z[2:].reshape(2, 2)
            A = np.array([[0.0, 1.0], [-2 * eps * x * v - 1.0, eps * (1 - x * x)]])
            out += list((A @ Phi).reshape(-1))
        return out

    def first_return(x0):
        def ev(t, z):
            return z[1]

        ev.direction = -1.0  # x' = 0 going down: a maximum of x
        sol = solve_ivp(f, (0, 100), [x0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12, events=ev)
        ts = [t for t in sol.t_events[0] if t > 1e-6]
        i = list(sol.t_events[0]).index(ts[0])
        return ts[0], sol.y_events[0][i][0]

    # settle, then solve x0 = P(x0) for the maximum on the cycle by the secant method
    x0 = 2.0
    for _ in range(6):  # the cycle attracts strongly for eps >= 0.5 (multiplier <= 0.04)
        x0 = first_return(x0)[1]
    a, b = x0, x0 + 1e-6
    ga, gb = first_return(a)[1] - a, first_return(b)[1] - b
    for _ in range(8):
        if gb == ga or abs(gb) < 1e-15:
            break
        a, b, ga = b, b - gb * (b - a) / (gb - ga), gb
        gb = first_return(b)[1] - b
    x0 = b
    T = first_return(x0)[0]
    z0 = np.concatenate([[x0, 0.0], np.eye(2).reshape(-1)])
    sol = solve_ivp(f, (0, T), z0, method="DOP853", rtol=1e-12, atol=1e-12)
    Mono = sol.y[2:, -1].reshape(2, 2)
    return T, x0, Mono


def test_vdp_small_eps_series():
    # Lindstedt: amplitude 2 + O(eps^2), period 2 pi (1 + eps^2/16 + O(eps^4))
    eps = 0.1
    sol = autonomous_balance_orbit(vdp(eps), 7)
    assert sol.period == pytest.approx(2 * math.pi * (1 + eps**2 / 16), rel=2e-5)
    assert sol.amplitudes["x"] == pytest.approx(2.0, abs=2e-3)
    assert sol.stable is True
    assert sol.jump_width == 0.0
    assert "limit cycle" in str(sol)


def test_vdp_eps1_literature_period_shooting_and_multipliers():
    # H = 25: the period converges faster than the waveform (H = 15: period 7e-13, max|x|
    # 5.5e-6 relative; H = 25: 1e-15 and 5e-9)
    sol = autonomous_balance_orbit(vdp(1.0), 25)
    assert sol.period == pytest.approx(6.663286859323130, rel=1e-12)
    T, xmax, Mono = vdp_shooting(1.0)
    assert T == pytest.approx(6.663286859323130, rel=1e-10)  # the oracle itself
    assert sol.period == pytest.approx(T, rel=1e-11)
    assert sol.amplitudes["x"] == pytest.approx(xmax, rel=1e-7)
    mu_exact = np.sort(np.abs(np.linalg.eigvals(Mono)))
    assert mu_exact[1] == pytest.approx(1.0, abs=1e-7)
    # the trivial multiplier is reported apart; the other one matches the shooting's
    assert abs(sol.trivial_multiplier - 1.0) < 1e-4
    assert sol.nontrivial_multipliers.size == 1
    assert abs(sol.nontrivial_multipliers[0]) == pytest.approx(mu_exact[0], rel=2e-3)
    assert sol.stable is True
    # the series satisfies the ODE: residual of x'' - eps (1 - x^2) x' + x on a grid
    t = np.linspace(0, sol.period, 200)
    h = 1e-4
    x = sol(t)
    v = (sol(t + h) - sol(t - h)) / (2 * h)
    a = (sol(t + h) - 2 * x + sol(t - h)) / h**2
    assert np.abs(a - (1 - x**2) * v + x).max() < 1e-4


def test_oscillator_input_and_guess_from_other_H():
    osc = builtin_model("vanderpol", eps=0.5)
    low = autonomous_balance_orbit(osc, 5, stability=False)
    assert low.multipliers is None and low.stable is None
    high = autonomous_balance_orbit(osc, 11, guess=low)
    T = vdp_shooting(0.5)[0]
    assert high.period == pytest.approx(T, rel=1e-9)
    assert abs(high.period - T) < abs(low.period - T)
    # a (frequency, coefficients) guess
    again = autonomous_balance_orbit(osc, 11, guess=(high.frequency, high.coefficients))
    assert again.period == pytest.approx(high.period, rel=1e-12)


def test_vdp_branch_in_eps_against_shooting():
    br = autonomous_balance_branch(vdp(1.0), "eps", (0.5, 2.0), 15)
    assert br.stop_reasons == ("window", "window")
    assert br.values[0] == pytest.approx(0.5) and br.values[-1] == pytest.approx(2.0)
    assert np.all(np.diff(br.values) > 0)
    for i in (0, len(br) - 1):
        T = vdp_shooting(float(br.values[i]))[0]
        assert br.period[i] == pytest.approx(T, rel=1e-7)
    assert np.all(br.stable)
    cols = br.columns()
    assert set(cols) >= {"eps", "frequency", "period", "amplitude_x", "mean_x", "stable"}
    assert "branch of limit cycles" in str(br)


def belt_projection_oracle(ab, s_coeffs, k_max):
    """Galerkin coefficients of the belt friction on s(theta) by adaptive quadrature split at
    the crossings of s = v_b found by brentq on a fine grid."""
    v_b, mu_s, mu_k, v_s = 0.2, 0.4, 0.25, 0.5

    def s(th):
        return ab.basis.evaluate(s_coeffs, np.atleast_1d(th))[0]

    def f(th):
        z = s(th) - v_b
        return (mu_k + (mu_s - mu_k) * math.exp(-abs(z) / v_s)) * np.sign(z)

    grid = np.linspace(0, 2 * math.pi, 2001)
    vals = np.array([s(t) - v_b for t in grid])
    cuts = [
        brentq(lambda t: s(t) - v_b, grid[i], grid[i + 1], xtol=1e-15)
        for i in range(grid.size - 1)
        if vals[i] * vals[i + 1] < 0
    ]
    edges = [0.0, *cuts, 2 * math.pi]
    out = []
    for k in range(k_max + 1):
        for trig in (math.cos, math.sin) if k else (math.cos,):

            def g(t, k=k, trig=trig):
                return f(t) * trig(k * t)

            tot = sum(
                quad(g, a, b, epsabs=1e-13, epsrel=1e-12, limit=200)[0]
                for a, b in zip(edges[:-1], edges[1:], strict=True)
            )
            out.append(tot / (2 * math.pi if k == 0 else math.pi))
    return np.array(out), len(cuts)


def test_friction_projection_quadrature_and_jacobian():
    ab = AutonomousBalance(builtin_system("belt"), 5, jump_width=0.0)
    name = ab.jump_elements()[0]
    s = np.zeros(ab.size)
    s[0], s[1], s[2], s[5] = 0.05, 0.3, 0.1, 0.04  # crosses v_b = 0.2 twice
    P, J = ab.project(name, s)
    ref, n_cuts = belt_projection_oracle(ab, s, ab.H)
    assert n_cuts == 2
    assert np.abs(P - ref).max() < 1e-12
    # exact Jacobian (smooth part and the moving switches) against central differences
    h = 1e-7
    Jfd = np.column_stack(
        [
            (
                ab.project(name, s + h * e, jacobian=False)[0]
                - ab.project(name, s - h * e, jacobian=False)[0]
            )
            / (2 * h)
            for e in np.eye(ab.size)
        ]
    )
    assert np.abs(J - Jfd).max() < 1e-6 * max(1.0, np.abs(J).max())


def test_belt_converges_to_exact_stick_slip_cycle_with_H():
    from perturb.solve import limit_cycles

    belt = builtin_system("belt")
    exact = limit_cycles(belt).cycles[0]
    T, amp = exact.period, float(exact.max_abs()[0])
    errs = []
    for H in (5, 9, 25):
        sol = autonomous_balance_orbit(belt, H)
        assert sol.jump_width > 0 and sol.stable is True
        # the exact cycle sticks: its nontrivial multiplier is 0; the HB one is near it
        assert abs(sol.nontrivial_multipliers[0]) < 0.05
        errs.append((abs(sol.period - T) / T, abs(sol.amplitudes["x"] - amp) / amp))
    assert errs[2][0] < errs[1][0] < errs[0][0]
    assert errs[2][1] < errs[0][1]
    assert errs[2][0] < 5e-3 and errs[2][1] < 1e-2
    # the exact discontinuous law (narrowed start, Newton on the exact switching-angle
    # projection; measured: converges at H = 15) is as close to the exact cycle
    ex = autonomous_balance_orbit(belt, 15, jump_width=0.0, stability=False)
    assert ex.jump_width == 0.0 and ex.residual_norm < 1e-10
    assert abs(ex.period - T) / T < 5e-3
    assert abs(ex.amplitudes["x"] - amp) / amp < 1e-2


def test_belt_branch_in_belt_speed():
    belt = builtin_system("belt")
    br = autonomous_balance_branch(belt, "v_b", (0.2, 0.3), 9, stability=False)
    assert br.stop_reasons == ("window", "window")
    assert br.values[0] == pytest.approx(0.2) and br.values[-1] == pytest.approx(0.3)
    assert br.stable is None
    # a faster belt: a larger stick-slip cycle (exact cycle at the edge within the H = 9 error)
    from perturb.solve import limit_cycles

    exact = limit_cycles(belt.with_params(v_b=0.3)).cycles[0]
    assert br.amplitudes["x"][-1] == pytest.approx(float(exact.max_abs()[0]), rel=0.02)
    assert br.period[-1] == pytest.approx(exact.period, rel=0.02)
    assert br.amplitudes["x"][-1] > br.amplitudes["x"][0]


def test_bad_input():
    damped = System.parse(["x'' + 0.1*x' + x = 0"], name="damped")
    with pytest.raises(AutonomousBalanceError, match="no self-excited oscillation"):
        autonomous_balance_orbit(damped, 5)
    assert issubclass(AutonomousBalanceError, PerturbError)
    with pytest.raises(ParameterError, match="harmonics"):
        autonomous_balance_orbit(vdp(1.0), 0)
    with pytest.raises(ParameterError, match="not in system"):
        autonomous_balance_branch(vdp(1.0), "mu", (0.1, 1.0), 5)
    with pytest.raises(ParameterError, match="guess"):
        autonomous_balance_orbit(vdp(1.0), 5, guess=(1.0, np.zeros((2, 11))))
    with pytest.raises(ParameterError, match="jump_width"):
        autonomous_balance_orbit(vdp(1.0), 5, jump_width=-1.0)
    forced = System.parse(["x'' + 0.1*x' + x + x**3 = cos(Omega*t)"], {"Omega": 1.0})
    with pytest.raises(ModelError, match="forced"):
        autonomous_balance_orbit(forced, 5)
    with pytest.raises(ParameterError, match="start"):
        autonomous_balance_branch(vdp(1.0), "eps", (0.5, 1.0), 5, start=2.0)


def settled_cycle(f, jac, y0, idx):
    """DOP853 (rtol = atol = 1e-12): settle from y0 for 40 time units (about 7 periods;
    the cycles attract with multipliers <= 0.4), take the period between the last two upward
    zero crossings of state idx, and integrate the variational equations over that period
    from the last crossing: (period, max |y_idx|, multipliers)."""
    n = len(y0)

    def ev(t, y):
        return y[idx]

    ev.direction = 1.0
    sol = solve_ivp(f, (0, 40), y0, method="DOP853", rtol=1e-12, atol=1e-12, events=ev)
    tc = sol.t_events[0]
    T = float(tc[-1] - tc[-2])
    ys = sol.y_events[0][-1]

    def g(t, z):
        y, Phi = z[:n], z[n:].reshape(n, n)
        return np.concatenate([f(t, y), (jac(y) @ Phi).reshape(-1)])

    z0 = np.concatenate([ys, np.eye(n).reshape(-1)])
    out = solve_ivp(g, (0, T), z0, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
    tt = np.linspace(0, T, 40001)  # spacing 1.5e-4: max found to ~1e-8
    amp = float(np.abs(out.sol(tt)[idx]).max())
    mu = np.linalg.eigvals(out.y[n:, -1].reshape(n, n))
    return T, amp, mu[np.argsort(-np.abs(mu))]


def test_several_coordinates_and_first_order_states_against_dop853():
    # two coupled coordinates (van der Pol driving a damped one) and a first-order state
    c2 = System.parse(
        [
            "x1'' - eps*(1 - x1**2)*x1' + x1 + k*(x1 - 2*x2) = 0",
            "x2'' + 0.3*x2' + 2*x2 + k*(2*x2 - x1) = 0",
        ],
        {"eps": 0.8, "k": 0.3},
    )
    mix = System.parse(["x'' - eps*(1 - x**2)*x' + x + p = 0", "p' + p - 0.5*x = 0"], {"eps": 1.0})

    def f_c2(t, y):
        x1, x2, v1, v2 = y
        return np.array(
            [
                v1,
                v2,
                0.8 * (1 - x1**2) * v1 - x1 - 0.3 * (x1 - 2 * x2),
                -0.3 * v2 - 2 * x2 - 0.3 * (2 * x2 - x1),
            ]
        )

    def j_c2(y):
        x1, _, v1, _ = y
        return np.array(
            [
                [0, 0, 1, 0],
                [0, 0, 0, 1],
                [-1.6 * x1 * v1 - 1.3, 0.6, 0.8 * (1 - x1**2), 0],
                [0.3, -2.6, 0, -0.3],
            ]
        )

    def f_mix(t, y):
        x, v, p = y
        return np.array([v, (1 - x * x) * v - x - p, -p + 0.5 * x])

    def j_mix(y):
        x, v, _ = y
        return np.array([[0, 1, 0], [-2 * x * v - 1, 1 - x * x, -1], [0.5, 0, -1]])

    for system, f, jac, name in ((c2, f_c2, j_c2, "x1"), (mix, f_mix, j_mix, "x")):
        sol = autonomous_balance_orbit(system, 31)
        # the reference starts from the HB state only to shorten the transient: a state off
        # the cycle by e is left off by e * 0.4^7 after the settling, far above 1e-8 for any
        # error the assertions below could miss
        T, amp, mu = settled_cycle(f, jac, sol.state(0.0), 0)
        assert sol.period == pytest.approx(T, rel=1e-8)
        assert sol.amplitudes[name] == pytest.approx(amp, rel=1e-7)
        assert abs(sol.trivial_multiplier - 1) < 1e-4
        nontrivial = np.sort(np.abs(sol.nontrivial_multipliers))
        ref = np.sort(np.abs(mu))[:-1]  # drop the exact trivial multiplier (modulus 1)
        assert np.allclose(nontrivial, ref, rtol=1e-3, atol=1e-6)
        assert sol.stable is True


def test_branch_ends_at_the_hopf_point():
    # x'' - (mu - x^2) x' + x = 0: the equilibrium's pair crosses the imaginary axis at
    # mu = 0 (closed form: lambda = mu/2 +- i sqrt(1 - mu^2/4)); averaging: amplitude
    # 2 sqrt(mu) for small mu. The branch must stop there, not come back as the same cycles
    # shifted by half a period.
    hopf = System.parse(["x'' - (mu - x**2)*x' + x = 0"], {"mu": 1.0})
    br = autonomous_balance_branch(hopf, "mu", (-0.5, 1.0), 9, stability=False)
    assert br.stop_reasons[0].startswith("hopf at mu = ")
    assert abs(float(br.stop_reasons[0].split("=")[1])) < 1e-6
    assert np.all(br.values > 0) and np.all(np.diff(br.values) > 0)
    i = int(np.argmin(np.abs(br.values - 0.02)))
    mu = float(br.values[i])
    assert br.amplitudes["x"][i] == pytest.approx(2 * math.sqrt(mu), rel=2e-2)


def test_huge_harmonics_and_bad_tol_are_refused_by_name():
    # H = 10**6 used to reach numpy's allocator (MemoryError for a 29 TiB Jacobian), and a
    # tol given as text or NaN was accepted silently (the Hopf start never read it)
    with pytest.raises(ParameterError, match="harmonics = 1000000"):
        autonomous_balance_orbit(vdp(1.0), 10**6)
    for bad in ("1e-8", float("nan"), -1.0, 0.0):
        with pytest.raises(ParameterError, match="tol"):
            autonomous_balance_orbit(vdp(1.0), 3, tol=bad)
    # 10**6 quadrature nodes at H = 200 meant a 3.2 GB design matrix (and ~1 min per
    # evaluation at H = 7): bounded by 10**7 entries
    with pytest.raises(ParameterError, match=r"quadrature = 1000000: expected an integer in"):
        autonomous_balance_orbit(vdp(1.0), 200, quadrature=10**6)
    with pytest.raises(ParameterError, match="monodromy_steps"):
        AutonomousBalance(vdp(1.0), 7, monodromy_steps=10**6)
    # stability="no" is truthy: it computed the multipliers
    with pytest.raises(ParameterError, match="stability = 'no'"):
        autonomous_balance_orbit(vdp(1.0), 3, stability="no")
    with pytest.raises(ParameterError, match="stability = 'no'"):
        autonomous_balance_branch(vdp(1.0), "eps", (0.5, 1.5), 3, stability="no")


def test_solution_refuses_times_that_are_not_finite_numbers():
    sol = autonomous_balance_orbit(vdp(1.0), 3, stability=False)
    for bad in ("a", float("nan"), [0.0, float("inf")]):
        with pytest.raises(ParameterError, match="t = "):
            sol(bad, "x")
    with pytest.raises(ParameterError, match="t = "):
        sol.state("a")
    # the series at t = 0 and one period later agree (a periodic answer, not a NaN)
    assert sol(sol.period, "x") == pytest.approx(sol(0.0, "x"), abs=1e-12)


def test_relaxation_oscillation_starts_from_an_unstable_node():
    # at eps >= 2 the equilibrium of van der Pol is an unstable node (real eigenvalues
    # 0.38, 2.62 at eps = 3): refused before as "no self-excited oscillation"
    sol = autonomous_balance_orbit(vdp(3.0), 25)

    def f(t, y):
        return [y[1], 3.0 * (1 - y[0] ** 2) * y[1] - y[0]]

    def up(t, y):
        return y[0]

    up.direction = 1.0
    ref = solve_ivp(f, (0, 120), [2.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12, events=up)
    crossings = ref.t_events[0]
    T = float(crossings[-1] - crossings[-2])
    assert sol.period == pytest.approx(T, rel=1e-6)
    assert sol.stable
    saddle = System.parse(["x'' + 0.1*x' - x = 0"], name="saddle")
    with pytest.raises(AutonomousBalanceError, match="no self-excited oscillation"):
        autonomous_balance_orbit(saddle, 5)


def test_mass_towards_zero_ends_the_branch_with_a_reason_not_a_linalg_error():
    # m x'' - eps (1 - x**2) x' + x = 0 continued in m towards 0: the variational equation
    # stiffens until its monodromy overflows; this raised numpy's LinAlgError ("Array must
    # not contain infs or NaNs") from inside the branch
    m = System.parse(["m*x'' - eps*(1 - x**2)*x' + x = 0"], {"eps": 0.5, "m": 1.0}, name="m")
    cheap = autonomous_balance_branch(m, "m", (-1.0, 1.0), 5, stability=False)
    k = int(np.argmin(abs(cheap.values - 1e-5)))
    guess = (float(cheap.frequency[k]), cheap.coefficients[k])
    start = float(cheap.values[k])
    br = autonomous_balance_branch(m, "m", (1e-9, 2e-5), 5, start=start, guess=guess)
    assert br.stop_reasons[0].startswith("stability failed at m = ")
    assert br.values[0] > 1e-9 and np.all(np.isfinite(br.max_multiplier))
    with pytest.raises(AutonomousBalanceError, match="overflows"):
        autonomous_balance_orbit(
            m.with_params({"m": float(cheap.values[0])}),
            5,
            guess=(float(cheap.frequency[0]), cheap.coefficients[0]),
        )
    with pytest.raises(ModelError, match=r"\[M D\] = \[\[0.0\]\] of 'm' is singular: expected"):
        autonomous_balance_orbit(m.with_params({"m": 0.0}), 5)
