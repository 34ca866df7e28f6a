"""Tests of ``derivations/hydraulic_mount.py`` (He & Singh hydraulic mount) against oracles
written here, never the script's own numbers:

* the transfer functions rebuilt by hand from the lumped equations (docs/references.md section 4):
  P_1/X = A_r (C_2 I_i s^2 + C_2 R_i s + 1)/(C_1 C_2 I_i s^2 + C_1 C_2 R_i s + C_1 + C_2),
  K_1 = k_r + A_r P_1/X; their coefficients give the identities and feed ``scipy.signal``;
* ``solve_ivp`` of the fixed-decoupler mount as one second-order ODE in the track volume,
  I_i V'' + R_i V' + (1/C_1 + 1/C_2) V = A_r X / C_1, with extrema located by ``brentq``;
* perturb's event-driven integrator on a vacuum oscillator written here;
* the floating-plate linear system, propagated by a matrix exponential;
* the ramp response as the running mean of the step response (linearity), by quadrature.

The last tests run the script in ``--fast`` mode (once per session, the ``derivations_fast``
fixture of conftest.py) and build the document with ``derivations/build.py`` (the
``pdflatex`` step is skipped where it is missing, except under CI).
"""

from __future__ import annotations

import csv
import math
import shutil

import numpy as np
import pytest
import sympy as sp
from scipy import signal
from scipy.integrate import quad, solve_ivp
from scipy.linalg import expm
from scipy.optimize import brentq, minimize_scalar

from perturb.model.oscillator import Oscillator
from perturb.simulate.flows.event_driven import simulate


@pytest.fixture(scope="module")
def hm(derivation_module):
    return derivation_module("hydraulic_mount")


@pytest.fixture(scope="module")
def build(derivation_module):
    return derivation_module("build")


def polynomials(m):
    """(num, den) of K_1 and of P_1/X, highest power first, by hand."""
    den = np.array([m.C1 * m.C2 * m.I_i, m.C1 * m.C2 * m.R_i, m.C1 + m.C2])
    p_num = m.A_r * np.array([m.C2 * m.I_i, m.C2 * m.R_i, 1.0])
    k_num = m.k_r * den + m.A_r * p_num
    return (k_num, den), (p_num, den)


def random_mounts(hm, n=6, seed=7):
    rng = np.random.default_rng(seed)
    base = hm.Mount()
    out = []
    for _ in range(n):
        f = np.exp(rng.uniform(-1.0, 1.0, size=6))
        out.append(
            hm.Mount(
                k_r=base.k_r * f[0],
                A_r=base.A_r * f[1],
                C1=base.C1 * f[2],
                C2=base.C2 * f[3],
                I_i=base.I_i * f[4],
                R_i=base.R_i * f[5] * 0.5,  # keep the denominator underdamped
            )
        )
    return out


def track_volume_run(m, X, t_end, rtol=1e-12):
    """Fixed decoupler, ideal step: V(t) and q(t) of the track, as a dense solution."""
    stiff = 1.0 / m.C1 + 1.0 / m.C2

    def rhs(_t, y):
        return [y[1], (m.A_r * X / m.C1 - stiff * y[0] - m.R_i * y[1]) / m.I_i]

    vref = abs(m.A_r * X)
    return solve_ivp(
        rhs,
        (0.0, t_end),
        [0.0, 0.0],
        method="DOP853",
        dense_output=True,
        rtol=rtol,
        atol=[1e-15 * vref, 1e-13 * vref],
    )


def force_from_volume(m, X, V):
    return m.k_r * X + m.A_r * (m.A_r * X - V) / m.C1


# --------------------------------------------------------------------------------------------
# symbolic reduction and identities
# --------------------------------------------------------------------------------------------
def test_symbolic_transfer_functions_match_hand_derivation(hm):
    red = hm.reduce_lumped_model()
    k_r, A_r, C1, C2, I_i, R_i = sp.symbols("k_r A_r C_1 C_2 I_i R_i", positive=True)
    s = sp.Symbol("s")
    P = (
        A_r
        * (C2 * I_i * s**2 + C2 * R_i * s + 1)
        / (C1 * C2 * I_i * s**2 + C1 * C2 * R_i * s + C1 + C2)
    )
    assert sp.cancel(red.P1X - P) == 0
    assert sp.cancel(red.K1 - (k_r + A_r * P)) == 0
    # every claim the script makes symbolically reduces to an exact zero
    assert red.zero and all(v == 0 for v in red.zero.values()), red.zero


def test_mount_identities_on_random_parameters(hm):
    for m in random_mounts(hm):
        (kn, kd), (pn, pd) = polynomials(m)
        rate = m.R_i / (2 * m.I_i)
        zeta1_omega1 = kn[1] / (2 * kn[0])
        zeta2_omega2 = kd[1] / (2 * kd[0])
        xi_varpi = pn[1] / (2 * pn[0])
        assert zeta1_omega1 == pytest.approx(rate, rel=1e-13)
        assert zeta2_omega2 == pytest.approx(rate, rel=1e-13)
        assert xi_varpi == pytest.approx(rate, rel=1e-13)
        # poles decay at R_i/(2 I_i)
        assert -np.roots(kd).real == pytest.approx([rate, rate], rel=1e-9)
        c = hm.canonical(m)
        assert c["gamma"] == pytest.approx(kn[2] / kd[2], rel=1e-13)
        assert c["omega_2"] ** 2 == pytest.approx(kd[2] / kd[0], rel=1e-13)
        assert c["omega_1"] ** 2 == pytest.approx(kn[2] / kn[0], rel=1e-13)
        assert c["zeta_1"] * c["omega_1"] == pytest.approx(rate, rel=1e-13)
        assert c["zeta_2"] * c["omega_2"] == pytest.approx(rate, rel=1e-13)
        assert c["xi"] * c["varpi"] == pytest.approx(rate, rel=1e-13)
        assert c["u"] * c["v"] == pytest.approx(1.0, rel=1e-13)  # the paper's u v = 1
        assert c["u_hat"] * c["v_hat"] == pytest.approx(1.0, rel=1e-13)


# --------------------------------------------------------------------------------------------
# closed forms
# --------------------------------------------------------------------------------------------
def test_closed_form_matches_scipy_signal(hm):
    for m in [hm.Mount(), *random_mounts(hm, n=3, seed=11)]:
        c = hm.canonical(m)
        times = np.linspace(0.0, 6.0 / c["sigma"], 3001)
        F, p = hm.step_closed_form(m, times)
        (kn, kd), (pn, pd) = polynomials(m)
        _, F_ref = signal.step(signal.lti(kn / kd[0], kd / kd[0]), T=times)
        _, p_ref = signal.step(signal.lti(pn / pd[0], pd / pd[0]), T=times)
        assert np.max(np.abs(F - F_ref)) / c["gamma"] < 1e-8
        assert np.max(np.abs(p - p_ref)) / c["lambda"] < 1e-8
        # initial values of the paper: F(0+) = k_r + A_r^2/C_1, p(0+) = A_r/C_1
        assert F[0] == pytest.approx(m.k_r + m.A_r**2 / m.C1, rel=1e-12)
        assert p[0] == pytest.approx(m.A_r / m.C1, rel=1e-12)


def test_closed_form_matches_integrated_ode_and_peak_times(hm):
    m = hm.Mount()
    X = m.X_fixed
    c = hm.canonical(m)
    t_end = 6.0 / c["sigma"]
    sol = track_volume_run(m, X, t_end)
    times = np.linspace(0.0, t_end, 4001)
    F_ref = force_from_volume(m, X, sol.sol(times)[0])
    F, _ = hm.step_closed_form(m, times, X)
    assert np.max(np.abs(F - F_ref)) / abs(c["gamma"] * X) < 1e-8
    # extrema of F are the zeros of the track flow; bracket sign changes and refine
    fine = np.linspace(0.0, t_end, 20001)[1:]
    q = sol.sol(fine)[1]
    idx = np.nonzero(np.sign(q[:-1]) != np.sign(q[1:]))[0]
    t_ext = np.array(
        [brentq(lambda tt: sol.sol(tt)[1], fine[i], fine[i + 1], xtol=1e-15) for i in idx]
    )
    assert len(t_ext) >= 10
    predicted = hm.peak_times(m, len(t_ext))
    assert np.max(np.abs(t_ext - predicted)) * c["omega_d"] < 1e-8
    # successive overshoots shrink by exp(-sigma pi/omega_d), the decay curve
    dev = np.abs(force_from_volume(m, X, sol.sol(t_ext)[0]) - c["gamma"] * X)
    ratios = dev[1:] / dev[:-1]
    assert ratios == pytest.approx(math.exp(-c["sigma"] * math.pi / c["omega_d"]), rel=1e-7)


def test_envelope_bounds_and_touches(hm):
    m = hm.Mount()
    c = hm.canonical(m)
    times = np.linspace(0.0, 6.0 / c["sigma"], 20001)
    F, p = hm.step_closed_form(m, times)
    env_F = c["gamma"] * c["sqrtR_F"] * np.exp(-c["sigma"] * times)
    env_p = c["lambda"] * c["sqrtR_p"] * np.exp(-c["sigma"] * times)
    root = math.sqrt(1.0 - c["zeta_2"] ** 2)
    assert c["sqrtR_F"] == pytest.approx(abs(c["u"] ** 2 - 1) / root, rel=1e-14)
    for y, final, env in ((F, c["gamma"], env_F), (p, c["lambda"], env_p)):
        ratio = np.abs(y - final) / env
        assert ratio.max() <= 1.0 + 1e-12
        assert ratio.max() > 1.0 - 1e-5


@pytest.mark.parametrize("eps", [0.01, 0.02, 0.05])
def test_settling_time(hm, eps):
    m = hm.Mount()
    c = hm.canonical(m)
    out = hm.settling(m, eps)
    sol = track_volume_run(m, 1.0, 2.0 * out["estimate"])
    final = c["gamma"]

    def rel_dev(tt):
        return np.abs(force_from_volume(m, 1.0, sol.sol(tt)[0]) - final) / final

    after = np.linspace(out["exact"], 2.0 * out["estimate"], 20001)
    assert rel_dev(after).max() <= eps * (1 + 1e-9)
    assert rel_dev(np.array([out["exact"]]))[0] == pytest.approx(eps, rel=1e-7)
    assert out["exact"] <= out["estimate"]  # the envelope bound is conservative
    assert out["estimate"] == pytest.approx(math.log(c["sqrtR_F"] / eps) / c["sigma"], rel=1e-14)


# --------------------------------------------------------------------------------------------
# nonlinear mount
# --------------------------------------------------------------------------------------------
def test_vacuum_model_agrees_with_perturb_event_driven(hm):
    m = hm.Mount()
    X = m.X_fixed
    c = hm.canonical(m)
    times = np.linspace(0.0, 4.0 / c["sigma"], 1201)
    r = hm.simulate_mount(m, X, times, free_decoupler=False, rtol=1e-11)
    # the same physics, written here in the track volume V (m^3) scaled by 1e-6
    scale = 1e-6
    knee = -m.p_vac * m.C1
    osc = Oscillator.parse(
        "v'' + c*v' + a*v + b*(v - s) - e*(v - k)*Heaviside(v - k) = 0",
        {
            "c": m.R_i / m.I_i,
            "a": 1.0 / (m.I_i * m.C2),
            "b": 1.0 / (m.I_i * m.C1),
            "s": m.A_r * X / scale,
            "e": (1.0 / m.C1 - 1.0 / m.C1_vac) / m.I_i,
            "k": (m.A_r * X - knee) / scale,
        },
    )
    traj = simulate(osc, [0.0, 0.0], (0.0, float(times[-1])), t_eval=times)
    dV1 = m.A_r * X - scale * np.asarray(traj.x)
    p1 = np.where(dV1 < knee, -m.p_vac + (dV1 - knee) / m.C1_vac, dV1 / m.C1)
    F_ref = m.k_r * X + m.A_r * p1
    assert np.max(np.abs(r.F - F_ref)) / abs((m.k_r + m.A_r**2 / m.C1) * X) < 1e-7
    switches = [te for te, _ in r.events if te > 0]
    assert len(switches) == len(traj.events) == 3
    assert np.allclose(switches, [e.time for e in traj.events], rtol=0, atol=1e-9)
    # the vacuum clips the first extremum: p_1 never goes far below -p_v
    assert r.p1.min() > -m.p_vac - (m.A_r * abs(X)) / m.C1_vac
    assert r.p1.min() < -m.p_vac


def test_ramp_response_is_running_mean_of_step_response(hm):
    m = hm.Mount()
    X, rise = m.X_fixed, 0.02
    c = hm.canonical(m)
    times = np.linspace(0.0, 3.0 / c["sigma"], 301)
    r = hm.simulate_mount(m, X, times, free_decoupler=False, vacuum=False, rise=rise)

    def step(tt):
        return hm.step_closed_form(m, np.array([tt]))[0][0]

    for tt, F in zip(times[1::15], r.F[1::15], strict=True):
        a = max(0.0, tt - rise)
        ref = X / rise * quad(step, a, tt, epsabs=0, epsrel=1e-12, limit=200)[0]
        assert F == pytest.approx(ref, rel=1e-7, abs=1e-9 * abs(c["gamma"] * X))


def test_free_decoupler_floating_phase_matches_linear_system(hm):
    """A gap too wide to reach: the plate leaves the top stop once and floats for good."""
    base = hm.Mount()
    m = hm.Mount(V_gap=1e3 * base.A_r * abs(base.X_free))
    X = m.X_free
    c = hm.canonical(m)
    times = np.linspace(0.0, 3.0 / c["sigma"], 601)
    r = hm.simulate_mount(m, X, times, free_decoupler=True, vacuum=False, rtol=1e-11)
    assert [kind for _, kind in r.events] == ["open"]
    t_open = r.events[0][0]
    # closed phase: the fixed-decoupler ODE; the plate opens where p_1 = p_2
    sol = track_volume_run(m, X, t_open * 1.5)

    def dp(tt):
        V = sol.sol(tt)[0]
        return (m.A_r * X - V) / m.C1 - V / m.C2

    fine = np.linspace(1e-9, t_open * 1.5, 30001)
    i = np.nonzero(np.diff(np.sign(dp(fine))))[0][0]
    assert brentq(dp, fine[i], fine[i + 1], xtol=1e-15) == pytest.approx(t_open, rel=1e-8)
    # floating phase: exact propagation of the linear 4-state system about its equilibrium
    a, b = 1.0 / m.C1, 1.0 / m.C2
    A = np.array(
        [
            [0, 1, 0, 0],
            [-(a + b) / m.I_i, -m.R_i / m.I_i, -(a + b) / m.I_i, 0],
            [0, 0, 0, 1],
            [-(a + b) / m.I_d, 0, -(a + b) / m.I_d, -m.R_d / m.I_d],
        ]
    )
    forcing = np.array([0, a * m.A_r * X / m.I_i, 0, a * m.A_r * X / m.I_d])
    V0, q0 = sol.sol(t_open)
    y0 = np.array([V0, q0, 0.0, 0.0])
    later = times[times > t_open]
    # y' = A y + f: with w = y + A^+ f handled through the augmented matrix
    aug = np.zeros((5, 5))
    aug[:4, :4], aug[:4, 4] = A, forcing
    ys = np.array([(expm(aug * (tt - t_open)) @ np.append(y0, 1.0))[:4] for tt in later])
    V_tot = ys[:, 0] + ys[:, 2]
    F_ref = m.k_r * X + m.A_r * (m.A_r * X - V_tot) / m.C1
    F = r.F[times > t_open]
    assert np.max(np.abs(F - F_ref)) / abs(c["gamma"] * X) < 1e-7


def test_free_decoupler_regions_and_constraints(hm):
    m = hm.Mount()
    X = m.X_free
    c = hm.canonical(m)
    times = np.linspace(0.0, 7.0 / c["sigma"], 2001)
    r = hm.simulate_mount(m, X, times, free_decoupler=True, rise=m.rise)
    kinds = [k for _, k in r.events]
    # the paper's regions: vacuum with the plate closed, then the plate opens, hits a stop,
    # ... and finally floats to the end
    assert kinds[:3] == ["vacuum-on", "vacuum-off", "open"]
    assert kinds[-1] == "open" and "stop-bottom" in kinds
    assert np.all(np.abs(r.plate) <= m.V_gap * (1 + 1e-9))
    on_stop = np.isin(r.dec, (-1, 1))
    assert np.allclose(r.plate[on_stop], r.dec[on_stop] * m.V_gap, rtol=0, atol=1e-12 * m.V_gap)
    # on a stop the pressure difference pushes the plate into it
    assert np.all(r.dec[on_stop] * (r.p1[on_stop] - r.p2[on_stop]) >= -1e-6 * m.p_vac)
    # the static gain does not depend on the decoupler
    assert r.F[-1] == pytest.approx(c["gamma"] * X, rel=1e-6)
    # once floating for good the transient dies faster than with the decoupler closed
    assert hm.open_decoupler_rates(m)[0] > 2 * c["sigma"]


# --------------------------------------------------------------------------------------------
# the quasi-linear model (He & Singh eqs. 14-16, reconstructed) and the three step components
# --------------------------------------------------------------------------------------------
def floating_matrix(m):
    """The floating-decoupler lumped ODEs y' = A y, y = (p_1, p_2, q_i, q_d), by hand."""
    return np.array(
        [
            [0.0, 0.0, -1.0 / m.C1, -1.0 / m.C1],
            [0.0, 0.0, 1.0 / m.C2, 1.0 / m.C2],
            [1.0 / m.I_i, -1.0 / m.I_i, -m.R_i / m.I_i, 0.0],
            [1.0 / m.I_d, -1.0 / m.I_d, 0.0, -m.R_d / m.I_d],
        ]
    )


def floating_force(m, times, X=1.0):
    """F_T(t) after an ideal step, by the matrix exponential (p_1 jumps by A_r X / C_1)."""
    A = floating_matrix(m)
    y0 = np.array([m.A_r * X / m.C1, 0.0, 0.0, 0.0])
    return np.array([m.k_r * X + m.A_r * (expm(A * tt) @ y0)[0] for tt in times])


def test_quasi_linear_identities_and_full_transfer_function(hm):
    q = hm.quasi_linear_model()
    assert q.zero and all(v == 0 for v in q.zero.values()), q.zero
    for m in [hm.Mount(), *random_mounts(hm, n=3, seed=11)]:
        m = hm.replace(m, I_d=m.I_i / 30.0, R_d=m.R_i / 5.0)
        K = hm.full_transfer(m)
        # oracle: the Laplace-domain equations solved numerically at a few complex s
        for sv in (3.0 + 40.0j, 0.5 + 400.0j, 20.0 - 5.0j):
            M = np.array(
                [
                    [m.C1 * sv, 0, 1, 1],
                    [0, m.C2 * sv, -1, -1],
                    [1, -1, -(m.I_i * sv + m.R_i), 0],
                    [1, -1, 0, -(m.I_d * sv + m.R_d)],
                ],
                dtype=complex,
            )
            P1 = np.linalg.solve(M, np.array([m.A_r * sv, 0, 0, 0], dtype=complex))[0]
            want = m.k_r + m.A_r * P1
            got = np.polyval(K.num, sv) / np.polyval(K.den, sv)
            assert abs(got / want - 1.0) < 1e-10
        # the effective branch: asymptotes of 1/(1/Z_i + 1/Z_d), numerically
        br = hm.effective_branches(m)
        I_e, R_e = br["high"]
        I_0, R_0 = br["low"]

        def Ze(sv, m=m):
            return 1.0 / (1.0 / (m.I_i * sv + m.R_i) + 1.0 / (m.I_d * sv + m.R_d))

        big = 1e9
        assert (Ze(big) - Ze(big / 2)) / (big / 2) == pytest.approx(I_e, rel=1e-6)
        assert Ze(big) - I_e * big == pytest.approx(R_e, rel=1e-4)
        tiny = 1e-6
        assert Ze(0.0) == pytest.approx(R_0, rel=1e-12)
        assert (Ze(tiny) - Ze(0.0)) / tiny == pytest.approx(I_0, rel=1e-6)


def test_quasi_linear_step_response_against_matrix_exponential(hm):
    m = hm.Mount()
    q = hm.quasi_study(m, 401)
    times = q["times"]
    F_full = floating_force(m, times)
    swing = abs(F_full[0] - (m.k_r + m.A_r**2 / (m.C1 + m.C2)))
    assert np.max(np.abs(q["F_ivp"] - F_full)) / swing < 1e-9
    errors = {}
    for key, (Ik, Rk) in hm.effective_branches(m).items():
        # the one-branch model integrated here: the fixed-decoupler track-volume ODE
        mk = hm.replace(m, I_i=Ik, R_i=Rk)
        sol = track_volume_run(mk, 1.0, float(times[-1]))
        F_red = force_from_volume(mk, 1.0, sol.sol(times)[0])
        errors[key] = np.max(np.abs(F_red - F_full)) / swing
        assert q["errors"][key] == pytest.approx(errors[key], rel=1e-4, abs=1e-9)
    assert errors["high"] < 0.01  # the quasi-linear model: within 1 % of the transient
    assert errors["low"] > 0.5 and errors["track"] > 1.0  # the other reductions fail
    # the real pole of the full model sits next to the pole of Z_e and carries little
    lam = np.linalg.eigvals(floating_matrix(m))
    real = lam[np.abs(lam.imag) < 1e-9 * np.abs(lam).max()].real
    slow = -real[np.abs(real) > 1e-6].max()  # C_1 p_1 + C_2 p_2 is conserved: one zero root
    assert q["slow"] == pytest.approx(slow, rel=1e-9)
    assert abs(q["slow"] / ((m.R_i + m.R_d) / (m.I_i + m.I_d)) - 1.0) < 0.01


def test_three_step_components(hm):
    m = hm.Mount()
    c = hm.canonical(m)
    cs = hm.component_study(m)
    # oracle: the components by quadrature and on a dense grid
    T = 40.0 / c["sigma"]
    tt = np.linspace(0.0, T, 400_001)
    one, cos_t, sin_t = hm.step_components(m, tt)
    F, _ = hm.step_closed_form(m, tt)
    assert np.max(np.abs(one + cos_t + sin_t - F / c["gamma"])) < 1e-12
    kw = {"limit": 2000, "epsabs": 1e-15, "epsrel": 1e-12}

    def comp(tv, k):
        return hm.step_components(m, np.array([tv]))[k][0]

    E_cos = quad(lambda tv: comp(tv, 1) ** 2, 0.0, T, **kw)[0]
    E_sin = quad(lambda tv: comp(tv, 2) ** 2, 0.0, T, **kw)[0]
    E_tr = quad(lambda tv: (comp(tv, 1) + comp(tv, 2)) ** 2, 0.0, T, **kw)[0]
    assert cs["E_cos"] == pytest.approx(E_cos, rel=1e-8)
    assert cs["E_sin"] == pytest.approx(E_sin, rel=1e-8)
    assert cs["energy_share"] == pytest.approx(E_sin / E_tr, rel=1e-8)
    # the sine term's largest value: grid maximum polished by a bounded scalar search
    j = int(np.argmax(np.abs(sin_t)))
    best = minimize_scalar(
        lambda tv: -abs(comp(tv, 2)), bounds=(tt[j - 1], tt[j + 1]), method="bounded",
        options={"xatol": 1e-13},
    )  # fmt: skip
    assert cs["peak_sin"] == pytest.approx(-best.fun, rel=1e-10)
    assert cs["peak_ratio"] == pytest.approx(-best.fun / np.max(np.abs(cos_t)), rel=1e-10)
    # the claim: negligible in energy (< 2 %), below 10 % at its peak, zero at the extrema
    assert E_sin / E_tr < 0.02 and cs["peak_ratio"] < 0.1
    tp = hm.peak_times(m, 6)
    assert np.max(np.abs(hm.step_components(m, tp)[2])) < 1e-14
    # the two-term form's extrema: located here by brentq on its derivative
    A, sg, w = c["u"] ** 2 - 1.0, c["sigma"], c["omega_d"]

    def slope(tv):
        return -sg * math.cos(w * tv) - w * math.sin(w * tv)

    errs = []
    for t_true in tp:
        t2 = brentq(slope, t_true - 0.45 * math.pi / w, t_true + 0.05 * math.pi / w, xtol=1e-15)
        assert t_true - t2 == pytest.approx(cs["shift"], rel=1e-7)
        two = A * math.exp(-sg * t2) * math.cos(w * t2)
        true = A * math.exp(-sg * t_true) * math.cos(w * t_true)
        errs.append(abs(two / true - 1.0))
    assert cs["overshoot_error"] == pytest.approx(max(errs), rel=1e-8)


# --------------------------------------------------------------------------------------------
# the script end to end, and the document
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fast_run(derivations_fast, tmp_path_factory):
    # a root of its own, so the document built here holds this study only
    root = tmp_path_factory.mktemp("derivations-mount")
    shutil.copytree(
        derivations_fast("hydraulic_mount") / "hydraulic_mount", root / "hydraulic_mount"
    )
    return root


def test_script_writes_outputs(fast_run):
    folder = fast_run / "hydraulic_mount"
    for name in (
        "section.tex",
        "linear_step.png",
        "nonlinear_step.png",
        "linear_step.csv",
        "peaks.csv",
        "settling.csv",
        "checks.csv",
        "parameters.csv",
        "nonlinear_step.csv",
        "nonlinear_events.csv",
        "symbolic_identities.csv",
        "quasi_linear.png",
        "quasi_linear.csv",
        "quasi_linear_branches.csv",
        "step_components.csv",
    ):
        assert (folder / name).stat().st_size > 0, name
    with (folder / "checks.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert rows and all(row["ok"] == "True" for row in rows)
    with (folder / "peaks.csv").open() as fh:
        peaks = list(csv.DictReader(fh))
    assert all(abs(float(p["difference"])) < 1e-9 for p in peaks)
    tex = (folder / "section.tex").read_text()
    assert tex.lstrip().startswith(r"\section{")
    assert "representative" in tex and "reconstructed" in tex
    assert "hydraulic_mount/nonlinear_step.png" in tex
    # the quasi-linear model and the negligible component, stated with their numbers
    with (folder / "quasi_linear_branches.csv").open() as fh:
        branches = {row["model"]: row for row in csv.DictReader(fh)}
    high = float(branches["high"]["max_error_over_swing"])
    assert high < 0.01
    assert f"{100 * high:.3g}" in tex
    assert "Quasi-linear model" in tex and "hydraulic_mount/quasi_linear.png" in tex
    with (folder / "step_components.csv").open() as fh:
        comp = {row["quantity"]: float(row["value"]) for row in csv.DictReader(fh)}
    assert "negligible in energy" in tex and f"{100 * comp['energy_ratio']:.3g}" in tex


def test_document_builds(build, fast_run, request):
    assert build.main(["--root", str(fast_run), "--no-pdf"]) == 0
    doc = (fast_run / "derivations.tex").read_text()
    assert r"\input{hydraulic_mount/section.tex}" in doc
    for package in ("amsmath", "graphicx", "booktabs"):
        assert package in doc
    assert r"\usepackage[T1]{fontenc}" in doc
    request.getfixturevalue("pdflatex")  # skips without it (fails under CI)
    assert build.main(["--root", str(fast_run)]) == 0
    assert (fast_run / "derivations.pdf").stat().st_size > 10_000


def test_build_without_pdflatex_fails_loudly(build, fast_run, monkeypatch, capsys):
    monkeypatch.setattr(build.shutil, "which", lambda _name: None)
    assert build.main(["--root", str(fast_run)]) != 0
    assert "pdflatex" in capsys.readouterr().err
    assert build.main(["--root", str(fast_run), "--no-pdf"]) == 0


def test_build_without_sections_fails(build, tmp_path):
    assert build.main(["--root", str(tmp_path), "--no-pdf"]) != 0
