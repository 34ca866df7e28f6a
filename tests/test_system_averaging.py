"""First-order multiple-scales slow flow of two-coordinate systems at a 1:1 or 1:3 internal
resonance (perturb.methods.system_averaging), against independent oracles:

(a) the slow flow of systems already in modal form against the hand derivation written here
    (Nayfeh-Mook: (3/8) alpha a^3 / omega, the a_1^2 a_2 and a_1^3 coupling of 1:3, the
    A_1 A_2 conj(A_2) terms of 1:1), and the slow flow of coupled (non-modal) systems against
    the averaging integrals evaluated by quadrature in this file (modes from numpy.linalg.eigh),
    for a cubic element under 1:3 and a dead zone (describing function) under 1:1;
(b) the fixed points against the first harmonics of periodic orbits converged by shooting with
    a DOP853 (rtol = atol = 1e-12) integration written here: the relative error is O(eps)
    (first order), measured 3.8e-4 / 7.6e-4 at eps = 0.01 / 0.02, ratio 2.0;
(c) the stability of the three fixed points at one frequency against the Floquet multipliers of
    the orbits (growth rate log|mu|/T against the largest real part of the Jacobian's
    eigenvalues);
plus the LaTeX derivation compiling with pdflatex and the refusals of bad input.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.fourier.symbols import NUMERIC_IMPLEMENTATIONS
from perturb.methods.system_averaging import internal_resonance_slow_flow
from perturb.model.system import System, dead_zone, pwl_spring, stop
from perturb.report.latex import derivation_body


def _sym(result, name):
    found = {
        s.name: s for x in (*result.slow_flow, *result.polar_slow_flow) for s in x.free_symbols
    }
    return found[name]


# --------------------------------------------------------------------- (a) hand derivations --
MODAL_13 = System.parse(
    [
        "x1'' + 2*mu*x1' + x1 + alpha*x1**3 + beta*x1**2*x2 = F*cos(Omega*t)",
        "x2'' + 2*mu*x2' + 9*x2 + delta*x1**3 + kappa*x2**3 = 0",
    ],
    name="modal13",
)


def test_one_to_three_polar_slow_flow_equals_hand_derivation():
    r = internal_resonance_slow_flow(MODAL_13, "1:3")
    assert r.resonance == "1:3" and r.near == 1
    assert sp.Matrix(r.modal_matrix) == sp.eye(2)
    assert [sp.nsimplify(w) for w in r.natural_frequencies] == [1, 3]
    names = ("mu", "alpha", "beta", "delta", "kappa", "F", "Omega", "a_1", "a_2")
    mu, al, be, de, ka, F, Om, a1, a2 = (_sym(r, n) for n in names)
    g1, g2 = _sym(r, "gamma_1"), _sym(r, "gamma_2")
    sig = Om - 1  # Omega = omega_1 + sigma
    ph = 3 * g1 - g2
    # hand derivation (eta_k = a_k cos(nu_k t - gamma_k), nu = (Omega, 3 Omega)):
    #   mode 1: c_1 = -3 alpha A1^2 conj(A1) - beta conj(A1)^2 A2 - 2 i mu A1 + F/2
    #   mode 2: c_2 = -delta A1^3 - 3 kappa A2^2 conj(A2) - 6 i mu A2
    hand = [
        -mu * a1 + F / 2 * sp.sin(g1) - be * a1**2 * a2 / 8 * sp.sin(ph),
        sig * a1
        - sp.Rational(3, 8) * al * a1**3
        - be * a1**2 * a2 / 8 * sp.cos(ph)
        + F / 2 * sp.cos(g1),
        -mu * a2 + de * a1**3 / 24 * sp.sin(ph),
        (3 * Om - 3) * a2 - de * a1**3 / 24 * sp.cos(ph) - ka * a2**3 / 8,
    ]
    for got, want in zip(r.polar_slow_flow, hand, strict=True):
        assert sp.simplify(sp.expand_trig(got - want)) == 0, (got, want)
    # the Cartesian flow is the same flow: p = a cos(gamma), q = a sin(gamma)
    rng = np.random.default_rng(1)
    fc = sp.lambdify(r.cartesian + (Om, mu, al, be, de, ka, F), r.slow_flow)
    fp = sp.lambdify((a1, g1, a2, g2, Om, mu, al, be, de, ka, F), hand)
    for _ in range(5):
        a, g = rng.uniform(0.2, 2, 2), rng.uniform(-3, 3, 2)
        pars = rng.uniform(0.1, 1.5, 7)
        da1, a1g1, da2, a2g2 = fp(a[0], g[0], a[1], g[1], *pars)
        want = [
            da1 * np.cos(g[0]) - a1g1 * np.sin(g[0]),
            da1 * np.sin(g[0]) + a1g1 * np.cos(g[0]),
            da2 * np.cos(g[1]) - a2g2 * np.sin(g[1]),
            da2 * np.sin(g[1]) + a2g2 * np.cos(g[1]),
        ]
        pq = [a[0] * np.cos(g[0]), a[0] * np.sin(g[0]), a[1] * np.cos(g[1]), a[1] * np.sin(g[1])]
        np.testing.assert_allclose(fc(*pq, *pars), want, rtol=1e-12, atol=1e-12)


def test_one_to_one_secular_terms_equal_hand_derivation():
    system = System.parse(
        [
            "x1'' + c*x1' + x1 + g*x1*x2**2 = F*cos(Omega*t)",
            "x2'' + c*x2' + w2sq*x2 + h*x2**3 = 0",
        ],
        {"w2sq": 1.1},
        name="modal11",
    )
    r = internal_resonance_slow_flow(system, "1:1")
    A1, A2 = r.complex_amplitudes
    c, g, h, F = (_sym(r, n) for n in ("c", "g", "h", "F"))
    w2 = sp.sqrt(sp.Rational(11, 10))
    assert abs(float(r.natural_frequencies[1] - w2)) < 1e-14
    B1, B2 = sp.conjugate(A1), sp.conjugate(A2)
    # x1 x2^2 at e^{i Omega t}: A1 (2 A2 conj A2) + conj(A1) A2^2; x2^3: 3 A2^2 conj(A2)
    hand1 = -g * (2 * A1 * A2 * B2 + B1 * A2**2) - sp.I * c * A1 + F / 2
    hand2 = -3 * h * A2**2 * B2 - sp.I * c * w2 * A2
    assert sp.expand(r.secular_terms[0] - hand1) == 0
    assert sp.simplify(sp.expand(r.secular_terms[1] - hand2)) == 0


# ------------------------------------------------- (a) averaging integrals by quadrature --
PAIR_13 = System.parse(
    [
        "x1'' + c*x1' + 5*x1 - 4*x2 + alpha*x1**3 = F*cos(Omega*t)",
        "x2'' + c*x2' + 5*x2 - 4*x1 = 0",
    ],
    name="pair13",
)


def _pair11_dead_zone(kd="kd"):
    return System.from_matrices(
        [[1, 0], [0, 1]],
        [["c", 0], [0, "c"]],
        [["1+kc", "-kc"], ["-kc", "1+kc"]],
        elements=[dead_zone("x1", "d", kd)],
        forcing=["F*cos(Omega*t)", 0],
        params={"kc": 0.05, "d": 0.5},
        name="pair11_dead_zone",
    )


def _quadrature_slow_flow(M, K, C, force, F, ratios, Om, pq, n=4096):
    """The first-order averaging integrals, by the trapezoid rule on one period:
    p_k' = -(nu_k - w_k) q_k - <N_k sin(r_k th)>/w_k, q_k' = (nu_k - w_k) p_k +
    <N_k cos(r_k th)>/w_k, N = Phi^T (F cos(th) - C q' - f(q, q')), eta_k' evaluated as
    w_k (-p_k sin + q_k cos)."""
    L = np.linalg.cholesky(M)
    Li = np.linalg.inv(L)
    lam, V = np.linalg.eigh(Li @ K @ Li.T)
    Phi = Li.T @ V
    Phi *= np.sign(Phi[0])  # first entry of each mode positive (the module's convention)
    w = np.sqrt(lam)
    th = 2 * np.pi * np.arange(n) / n
    p, q = pq[0::2], pq[1::2]
    eta = np.array([p[k] * np.cos(ratios[k] * th) + q[k] * np.sin(ratios[k] * th) for k in (0, 1)])
    etad = np.array(
        [w[k] * (-p[k] * np.sin(ratios[k] * th) + q[k] * np.cos(ratios[k] * th)) for k in (0, 1)]
    )
    x, v = Phi @ eta, Phi @ etad
    N = Phi.T @ (np.outer(F, np.cos(th)) - C @ v - force(x, v))
    out = []
    nu = np.array(ratios, float) * Om
    for k in (0, 1):
        s_avg = np.mean(N[k] * np.sin(ratios[k] * th))
        c_avg = np.mean(N[k] * np.cos(ratios[k] * th))
        out += [-(nu[k] - w[k]) * q[k] - s_avg / w[k], (nu[k] - w[k]) * p[k] + c_avg / w[k]]
    return np.array(out), Phi


def test_one_to_three_cubic_slow_flow_equals_quadrature_of_averages():
    r = internal_resonance_slow_flow(PAIR_13, "1:3")
    M, K = np.eye(2), np.array([[5.0, -4.0], [-4.0, 5.0]])
    Phi = np.array(r.modal_matrix.evalf(), float)
    np.testing.assert_allclose(Phi.T @ M @ Phi, np.eye(2), atol=1e-14)
    np.testing.assert_allclose(Phi.T @ K @ Phi, np.diag([1.0, 9.0]), atol=1e-13)
    f = sp.lambdify(r.arguments, list(r.slow_flow))
    names = [s.name for s in r.arguments[5:]]
    assert sorted(names) == ["F", "alpha", "c"]
    rng = np.random.default_rng(2)
    for _ in range(4):
        pq = rng.uniform(-1.5, 1.5, 4)
        Om, c, F, al = 1 + rng.uniform(-0.1, 0.1), *rng.uniform(0.05, 1.0, 3)
        par = {"c": c, "F": F, "alpha": al}
        got = np.array(f(*pq, Om, *(par[n] for n in names)))

        def force(x, v, al=al):
            return np.array([al * x[0] ** 3, 0 * x[0]])

        want, Phi_np = _quadrature_slow_flow(
            M, K, c * np.eye(2), force, np.array([F, 0.0]), (1, 3), Om, pq
        )
        np.testing.assert_allclose(Phi_np, Phi, atol=1e-12)
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)


def test_one_to_one_dead_zone_uses_describing_function_equal_to_quadrature():
    system = _pair11_dead_zone()
    r = internal_resonance_slow_flow(system, "1:1")
    assert any("describing function" in n for n in r.notes)
    names = [s.name for s in r.arguments[5:]]
    f = sp.lambdify(r.arguments, list(r.slow_flow), modules=[NUMERIC_IMPLEMENTATIONS, "numpy"])
    kc, d, kd, c, F = 0.05, 0.5, 0.7, 0.1, 0.3
    par = {"d": d, "kd": kd, "c": c, "F": F}
    M = np.eye(2)
    K = np.array([[1 + kc, -kc], [-kc, 1 + kc]])
    rng = np.random.default_rng(3)
    for amp in (0.3, 1.2, 3.0):  # inside the dead zone, just beyond, far beyond
        pq = rng.normal(size=4)
        pq *= amp / np.linalg.norm(pq)
        Om = 1.02
        got = np.array(f(*pq, Om, *(par[n] for n in names)))

        def force(x, v):
            s = x[0]
            return np.array([kd * (s - np.clip(s, -d, d)), 0 * s])

        # the kinks of the dead zone make the trapezoid rule second order: 2^18 points
        want, _ = _quadrature_slow_flow(
            M, K, c * M, force, np.array([F, 0.0]), (1, 1), Om, pq, n=2**18
        )
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-11)


# ------------------------------------------------ (b), (c): numerical periodic orbits --
def _pair13_rhs(t, y, Om, c, F, al):
    x1, x2, v1, v2 = y[:4]
    out = [
        v1,
        v2,
        F * np.cos(Om * t) - c * v1 - 5 * x1 + 4 * x2 - al * x1**3,
        -c * v2 - 5 * x2 + 4 * x1,
    ]
    if len(y) == 4:
        return out
    P = y[4:].reshape(4, 4)
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-5 - 3 * al * x1**2, 4, -c, 0], [4, -5, 0, -c]])
    return np.concatenate([out, (A @ P).ravel()])


def _shoot(y0, Om, pars, max_iter=25):
    """A periodic orbit of period 2 pi/Omega by Newton on y(T) - y0 with the monodromy from
    the variational equations (DOP853, rtol = atol = 1e-12); returns y0 and the monodromy."""
    T = 2 * np.pi / Om
    for _ in range(max_iter):
        sol = solve_ivp(
            _pair13_rhs,
            (0, T),
            np.concatenate([y0, np.eye(4).ravel()]),
            method="DOP853",
            rtol=1e-12,
            atol=1e-12,
            args=(Om, *pars),
        )
        res = sol.y[:4, -1] - y0
        P = sol.y[4:, -1].reshape(4, 4)
        if np.max(np.abs(res)) < 1e-10:
            return y0, P
        y0 = y0 - np.linalg.solve(P - np.eye(4), res)
    raise AssertionError("shooting did not converge")


def _first_harmonics(y0, Om, pars, Phi, n=256):
    """(p_1, q_1, p_2, q_2): the cos/sin coefficients of eta = Phi^T q at Omega and 3 Omega."""
    T = 2 * np.pi / Om
    ts = np.arange(n) * T / n
    sol = solve_ivp(
        _pair13_rhs,
        (0, T),
        y0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        args=(Om, *pars),
        t_eval=ts,
    )
    eta = Phi.T @ sol.y[:2]
    out = []
    for k, rk in enumerate((1, 3)):
        out += [
            2 * np.mean(eta[k] * np.cos(rk * Om * ts)),
            2 * np.mean(eta[k] * np.sin(rk * Om * ts)),
        ]
    return np.array(out)


@pytest.fixture(scope="module")
def pair13():
    r = internal_resonance_slow_flow(PAIR_13, "1:3")
    names = [s.name for s in r.arguments[5:]]
    f = sp.lambdify(r.arguments, list(r.slow_flow))
    J = sp.lambdify(r.arguments, r.jacobian)
    Phi = np.array(r.modal_matrix.evalf(), float)

    def fixed_points(Om, par, radii=(0.3, 0.8, 1.5, 2.5, 3.5)):
        """Every fixed point fsolve reaches from mode-1 starts on circles of these radii."""
        args = [par[n] for n in names]
        found = []
        starts = [
            np.array([a * np.cos(t), a * np.sin(t), 0.0, 0.0])
            for a in radii
            for t in np.linspace(0, 2 * np.pi, 8, endpoint=False)
        ]
        for x0 in starts:
            x, _, ier, _ = fsolve(lambda x: f(*x, Om, *args), x0, full_output=True, xtol=1e-13)
            if ier == 1 and np.max(np.abs(f(*x, Om, *args))) < 1e-10:
                if not any(np.allclose(x, y, atol=1e-7) for y in found):
                    found.append(x)
        return [(x, np.linalg.eigvals(np.array(J(*x, Om, *args), float))) for x in found]

    return fixed_points, Phi


def _guess(fp, Om, Phi):
    # the fixed point only starts Newton; the orbit is accepted on its own residual
    return np.concatenate([Phi @ fp[[0, 2]], Phi @ (np.array([Om, 3 * Om]) * fp[[1, 3]])])


@pytest.mark.parametrize("sigma", [0.0, 0.6])
def test_fixed_point_matches_periodic_orbit_error_shrinks_like_eps(pair13, sigma):
    fixed_points, Phi = pair13
    errors = []
    for eps in (0.02, 0.01):
        par = {"c": 0.4 * eps, "F": 1.0 * eps, "alpha": 1.0 * eps}
        Om = 1 + sigma * eps
        fps = fixed_points(Om, par, radii=(0.5, 2.0))
        assert len(fps) == 1
        fp, _ = fps[0]
        y0, _ = _shoot(_guess(fp, Om, Phi), Om, (par["c"], par["F"], par["alpha"]))
        h = _first_harmonics(y0, Om, (par["c"], par["F"], par["alpha"]), Phi)
        errors.append(np.linalg.norm(h - fp) / np.linalg.norm(fp))
    # first order: relative error O(eps) (measured 7.6e-4, 3.8e-4 at sigma = 0; 8.3e-3,
    # 4.2e-3 at sigma = 0.6), halving with eps
    assert errors[1] < 0.5 * 0.02 * (1 if sigma == 0 else 10)
    assert 1.7 < errors[0] / errors[1] < 2.3, errors


def test_stability_of_fixed_points_matches_floquet_multipliers(pair13):
    fixed_points, Phi = pair13
    eps = 0.02
    par = {"c": 0.4 * eps, "F": 2.0 * eps, "alpha": 1.0 * eps}
    Om = 1 + 1.0 * eps
    fps = fixed_points(Om, par)
    assert len(fps) == 3  # the hardening fold of mode 1: two stable, one saddle
    verdicts = []
    for fp, lam in fps:
        _, P = _shoot(_guess(fp, Om, Phi), Om, (par["c"], par["F"], par["alpha"]))
        mu = np.linalg.eigvals(P)
        rate = np.log(np.abs(mu)).max() * Om / (2 * np.pi)  # growth rate of the orbit
        assert (lam.real.max() < 0) == (np.abs(mu).max() < 1)
        # slow-flow eigenvalues are O(eps); their first-order error O(eps^2) (measured 9e-4)
        assert abs(lam.real.max() - rate) < 3 * eps**2, (lam, mu)
        verdicts.append(lam.real.max() < 0)
    assert sorted(verdicts) == [False, True, True]


# ------------------------------------------------------------------------ LaTeX, object --
def test_derivation_compiles_with_matrices_and_harmonics(tmp_path, compile_tex):
    for system, res in ((PAIR_13, "1:3"), (_pair11_dead_zone(), "1:1")):
        r = internal_resonance_slow_flow(system, res)
        body = derivation_body(r.steps)
        assert "\\begin{matrix}" in body  # M, K, Phi typeset as matrices
        assert "e^{3 i \\theta}" in body or res == "1:1"  # the harmonics of the forces
        assert "Solvability conditions" in body and "Polar slow flow" in body
        doc = "\n".join(
            [
                r"\documentclass[11pt]{article}",
                r"\usepackage[T1]{fontenc}",
                r"\usepackage{lmodern}",
                r"\usepackage{amsmath,amssymb}",
                r"\usepackage[margin=2cm]{geometry}",
                r"\allowdisplaybreaks",
                r"\begin{document}",
                r"\sloppy",
                body,
                r"\end{document}",
            ]
        )
        tex = tmp_path / f"ir_{res.replace(':', '_')}.tex"
        tex.write_text(doc)
        compile_tex(tex)


def test_result_is_immutable_and_printable():
    r = internal_resonance_slow_flow(PAIR_13, "1:3")
    text = str(r)
    assert "1:3 internal resonance" in text and "p_1' =" in text
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.resonance = "1:1"
    assert len(r.steady_state) == 4 and r.jacobian.shape == (4, 4)
    assert internal_resonance_slow_flow(PAIR_13, None).resonance == "1:3"  # detected


# ------------------------------------------------------------------------------ bad input --
def test_bad_input_is_refused_with_the_value():
    with pytest.raises(ParameterError, match="'1:2'"):
        internal_resonance_slow_flow(PAIR_13, "1:2")
    with pytest.raises(ParameterError, match="near = 3"):
        internal_resonance_slow_flow(PAIR_13, "1:3", near=3)
    three = System.from_matrices(np.eye(3).tolist(), np.zeros((3, 3)).tolist(), np.eye(3).tolist())
    with pytest.raises(ModelError, match="3 coordinate"):
        internal_resonance_slow_flow(three, "1:1")
    far = System.parse(["x1'' + 2*x1 - x2 = 0", "x2'' + 2*x2 - x1 = 0"])  # ratio sqrt(3)
    with pytest.raises(ModelError, match=r"1\.73205.*-42\.3% from the declared 1:3"):
        internal_resonance_slow_flow(far, "1:3")
    with pytest.raises(ModelError, match=r"\+73\.2% from the declared 1:1"):
        internal_resonance_slow_flow(far, "1:1")
    first = System.parse(["x1'' + x1 - p = 0", "x2'' + x2 = 0", "p' = -p + x1"])
    with pytest.raises(ModelError, match="first-order states p"):
        internal_resonance_slow_flow(first, "1:1")
    sym_k = System.parse(["x1'' + k*x1 = 0", "x2'' + x2 = 0"])
    with pytest.raises(ParameterError, match="k without values"):
        internal_resonance_slow_flow(sym_k, "1:1")
    pwl13 = System.from_matrices(
        [[1, 0], [0, 1]], [[0, 0], [0, 0]], [[5, -4], [-4, 5]], elements=[dead_zone("x1", 1, 1)]
    )
    with pytest.raises(ModelError, match="1:3 resonance its signal"):
        internal_resonance_slow_flow(pwl13, "1:3")
    one_sided = System.from_matrices(
        [[1, 0], [0, 1]],
        [[0, 0], [0, 0]],
        [[1, 0], [0, 1]],
        elements=[pwl_spring("x1", [1], [0, 1])],
    )
    with pytest.raises(ModelError, match="is not odd"):
        internal_resonance_slow_flow(one_sided, "1:1")
    stopped = System.from_matrices(
        [[1, 0], [0, 1]], [[0, 0], [0, 0]], [[1, 0], [0, 1]], elements=[stop("x1", -1, 1)]
    )
    with pytest.raises(ModelError, match="rigid stop"):
        internal_resonance_slow_flow(stopped, "1:1")
    static = System.parse(["x1'' + x1 = P", "x2'' + x2 = 0"])
    with pytest.raises(ModelError, match="static load"):
        internal_resonance_slow_flow(static, "1:1")
    with pytest.raises(PerturbError, match="tolerance"):
        internal_resonance_slow_flow(PAIR_13, "1:3", tolerance=2)


def test_resonance_and_near_of_the_wrong_type_are_refused_or_read():
    # a list for resonance raised a bare "unhashable type" TypeError; near=2.0 indexed a
    # tuple with a float (bare TypeError)
    s = System.parse(
        ["x1'' + 0.01*x1' + x1 + x1**3 = F*cos(Omega*t)", "x2'' + 0.01*x2' + 1.02*x2 = 0"]
    )
    with pytest.raises(ParameterError, match="resonance"):
        internal_resonance_slow_flow(s, ["1:1"])
    with pytest.raises(ParameterError, match="near"):
        internal_resonance_slow_flow(s, "1:1", near="2")
    as_float = internal_resonance_slow_flow(s, "1:1", near=2.0)
    as_int = internal_resonance_slow_flow(s, "1:1", near=2)
    assert as_float.slow_flow == as_int.slow_flow


def test_resonance_defaults_to_the_nearer_ratio():
    # the default was "1:1": a 1:3 pair without resonance= was refused as "+200% from the
    # declared 1:1 ratio" though nothing was declared
    s = System.parse(
        [
            "x1'' + 2*mu*x1' + x1 + a*x1**3 = F*cos(Omega*t)",
            "x2'' + 2*mu*x2' + 9*x2 + b*(x2 - x1)**3 = 0",
        ]
    )
    r = internal_resonance_slow_flow(s)
    assert r.resonance == "1:3"
    assert r.frame_frequencies == (sp.Symbol("Omega", real=True), 3 * sp.Symbol("Omega", real=True))
