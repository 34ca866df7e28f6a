"""L-P / mLP backbones of a nonlinear normal mode of a two-coordinate conservative System.

Oracles, all independent of the engine:

* the numerical NNM, by shooting written here: a symmetric orbit starts at rest,
  ``q(0) = (a, c)``, ``q'(0) = 0``; ``c`` and the period ``T`` are found (scipy ``root``) so
  that both velocities vanish at ``T/2`` (solve_ivp DOP853, rtol = atol = 1e-12), giving
  ``omega = 2 pi / T``. The expansion's amplitude ``A`` is the first-harmonic amplitude of the
  modal coordinate ``u_j = phi_j^T M q``; the oracle measures it on the orbit (trapezoidal
  Fourier coefficient over one period, 256 samples, mode shapes from numpy's ``eigh``), and
  the backbone is evaluated there;
* closed forms derived by hand: the linear modes, the first-order correction of the cubic
  spring to ground, and the invariant modes of the hardening coupling spring (mode 1 is exactly
  linear; mode 2 is a Duffing oscillator, whose L-P backbone is
  ``w0 + 3 e A^2/(8 w0) - 15 e^2 A^4/(256 w0^3)``);
* quadrature of the piecewise-linear force for the first harmonic of the nsd2 device.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import subprocess

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import quad, solve_ivp
from scipy.optimize import root

from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.methods.system_lindstedt import InternalResonanceError, NNMBackbone, nnm_backbone
from perturb.model.system import System, stop
from perturb.model.system_builtins import builtin_system
from perturb.report.latex import derivation_body

GROUND = ["x1'' + 2*x1 - x2 + eps*x1**3 = 0", "x2'' + 2*x2 - x1 = 0"]
K_CHAIN = [[2, -1], [-1, 2]]  # the linear part of both examples
K_NSD2 = [[2, -1], [-1, 1]]  # nsd2's reference stiffness: outer slope 1 plus k2 = 1
COUPLING = ["x1'' + 2*x1 - x2 + eps*(x1 - x2)**3 = 0", "x2'' + 2*x2 - x1 - eps*(x1 - x2)**3 = 0"]


def ground(eps: float) -> System:
    return System.parse(GROUND, {"eps": eps}, name="cubic_ground")


def nsd2() -> System:
    return builtin_system("nsd2").with_params(mu1=0, mu2=0, F=0)


# ------------------------------------------------------------------------- the oracle --
def shoot(rhs, a: float, c0: float, T0: float) -> tuple[float, float]:
    """The symmetric periodic orbit through ``q = (a, c)`` at rest: ``(c, T)``."""

    def half_period_velocities(z):
        c, T = z
        sol = solve_ivp(
            rhs, (0.0, T / 2), [a, c, 0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12
        )
        return sol.y[2:, -1]

    out = root(half_period_velocities, [c0, T0], method="hybr", options={"xtol": 1e-13})
    # accepted on the residual: an exact guess (an invariant mode) ends with "no progress" at
    # a zero residual, and the nsd2 kinks hold DOP853's velocities at ~1e-10..1e-9
    assert np.max(np.abs(half_period_velocities(out.x))) < 1e-8, out.message
    # v(T/2) = 0 also holds at odd multiples of the half period: stay on the continued orbit
    assert abs(out.x[1] / T0 - 1) < 0.3, (T0, out.x)
    return float(out.x[0]), float(out.x[1])


def ground_rhs(eps: float):
    def rhs(t, y):
        x1, x2, v1, v2 = y
        return [v1, v2, -(2 * x1 - x2 + eps * x1**3), -(2 * x2 - x1)]

    return rhs


def coupling_rhs(eps: float):
    def rhs(t, y):
        x1, x2, v1, v2 = y
        f = eps * (x1 - x2) ** 3
        return [v1, v2, -(2 * x1 - x2 + f), -(2 * x2 - x1 - f)]

    return rhs


def nsd2_rhs(k: float = -0.5, k2: float = 1.0):
    def rhs(t, y):
        x1, x2, v1, v2 = y
        f = k * x1 + (1 - k) * ((x1 - 1) * (x1 > 1) + (x1 + 1) * (x1 < -1))
        return [v1, v2, -(f + k2 * (x1 - x2)), -k2 * (x2 - x1)]

    return rhs


def linear_modes(K: np.ndarray) -> np.ndarray:
    """Mass-normalised mode shapes of (I, K), increasing frequency, first entry positive."""
    _, vecs = np.linalg.eigh(K)
    return vecs * np.sign(vecs[0])


def numeric_backbone(rhs, amplitudes, K, mode: int, substeps: int = 1):
    """``[(A, omega)]`` of the numerical NNM at the turning points ``q1(0) = a``, continued
    from the linear mode through ``substeps`` amplitudes per interval; ``A`` is the
    first-harmonic amplitude of ``u_mode`` (M = I in every system here)."""
    phi = linear_modes(np.asarray(K, dtype=float))[:, mode - 1]
    w0 = math.sqrt(float(phi @ np.asarray(K, dtype=float) @ phi))
    out, c, T, prev = [], None, 2 * math.pi / w0, 0.0
    for a in amplitudes:
        for b in np.linspace(prev, a, substeps + 1)[1:]:
            guess = phi[1] / phi[0] * b if c is None else c * b / prev
            c, T = shoot(rhs, b, guess, T)
            prev = b
        n = 256
        t = np.arange(n) * T / n
        sol = solve_ivp(
            rhs, (0.0, T), [a, c, 0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t
        )
        u = phi @ sol.y[:2]
        A = 2 / n * float(np.sum(u * np.cos(2 * math.pi * t / T)))
        out.append((A, 2 * math.pi / T))
    return out


def errors(r: NNMBackbone, points, invalid: str = "raise") -> list[float]:
    return [float(r.frequency_at(A, invalid=invalid)) - om for A, om in points]


def rate(errors, scales) -> float:
    """Slope of log|error| against log(scale)."""
    return float(np.polyfit(np.log(scales), np.log(np.abs(errors)), 1)[0])


# -------------------------------------------------------------------- linear modes --
def test_modal_matrix_is_m_orthonormal_with_unequal_masses():
    # 2 x1'' + 3 x1 - x2 = 0, x2'' + x2 - x1 = 0: det(K - l M) = 2 l^2 - 5 l + 2, l = 1/2, 2;
    # mode shapes (1, 2) and (1, -1), M-normalised by sqrt(6) and sqrt(3)
    sysm = System.parse(["2*x1'' + 3*x1 - x2 + eps*x1**3 = 0", "x2'' + x2 - x1 = 0"])
    r = nnm_backbone(sysm, 2, 1)
    M = sp.Matrix([[2, 0], [0, 1]])
    Phi = sp.Matrix(r.modal_matrix)
    assert sp.simplify(Phi.T * M * Phi - sp.eye(2)) == sp.zeros(2, 2)
    assert sp.simplify(Phi.T * sp.Matrix([[3, -1], [-1, 1]]) * Phi) == sp.diag(sp.Rational(1, 2), 2)
    assert sp.simplify(Phi[:, 0] - sp.Matrix([1, 2]) / sp.sqrt(6)) == sp.zeros(2, 1)
    assert sp.simplify(Phi[:, 1] - sp.Matrix([1, -1]) / sp.sqrt(3)) == sp.zeros(2, 1)
    assert r.natural_frequencies == (1 / sp.sqrt(2), sp.sqrt(2))


def test_first_order_correction_of_the_cubic_spring_to_ground():
    # mode 1: u = A cos(tau) e_1, x1 = A cos(tau)/sqrt(2); n_1 = eps x1^3/sqrt(2) has the first
    # harmonic 3 eps A^3/16, so omega_1 = 3 eps A^2/32 (L-P) and nu = 3 eps A^2/16 (mLP)
    eps, A = sp.Symbol("eps", real=True), sp.Symbol("A", positive=True)
    lp = nnm_backbone(ground(0.1), 1, 1)
    assert sp.simplify(lp.backbone - (1 + 3 * eps * A**2 / 32)) == 0
    mlp = nnm_backbone(ground(0.1), 1, 1, method="mlp")
    assert sp.simplify(mlp.backbone - sp.sqrt(1 + 3 * eps * A**2 / 16)) == 0
    assert lp.parameters == (eps,) and lp.values["eps"] == 0.1


def test_hardening_coupling_spring_invariant_modes_in_closed_form():
    eps, A = sp.Symbol("eps", real=True), sp.Symbol("A", positive=True)
    sysm = System.parse(COUPLING, {"eps": 0.3})
    # mode 1 (x1 = x2) never stretches the coupling spring: exactly linear
    r1 = nnm_backbone(sysm, 1, 2)
    assert r1.backbone == 1
    assert all(sp.simplify(w - A * sp.cos(r1.tau) / sp.sqrt(2)) == 0 for w in r1.waveforms)
    # mode 2 (x1 = -x2 = u/sqrt(2)): u'' + 3u + 4 eps u^3 = 0, a Duffing oscillator
    r2 = nnm_backbone(sysm, 2, 2)
    w0, e = sp.sqrt(3), 4 * eps
    duffing = w0 + 3 * e * A**2 / (8 * w0) - 15 * e**2 * A**4 / (256 * w0**3)
    assert sp.simplify(r2.backbone - duffing) == 0
    assert sp.simplify(r2.waveforms[0] + r2.waveforms[1]) == 0


# --------------------------------------------------------- against the numerical NNM --
@pytest.mark.parametrize("mode", [1, 2])
def test_lp_error_shrinks_like_eps_cubed(mode):
    """Turning point q1(0) = 1, eps = 0.4, 0.2, 0.1: first order O(eps^2), second O(eps^3)."""
    epss = [0.4, 0.2, 0.1]
    errs = {"lp1": [], "lp2": [], "mlp1": [], "mlp2": []}
    for eps in epss:
        points = numeric_backbone(ground_rhs(eps), [1.0], K_CHAIN, mode)
        for key in errs:
            r = nnm_backbone(ground(eps), mode, int(key[-1]), method=key[:-1])
            errs[key] += errors(r, points)
    assert 1.7 < rate(errs["lp1"], epss) < 2.3, errs
    assert 1.7 < rate(errs["mlp1"], epss) < 2.3, errs
    assert 2.7 < rate(errs["lp2"], epss) < 3.3, errs
    assert 2.7 < rate(errs["mlp2"], epss) < 3.3, errs
    assert abs(errs["lp2"][-1]) < 1e-4


def test_lp_error_shrinks_like_amplitude_to_the_sixth():
    """eps = 0.1, mode 2, q1(0) = 0.8, 0.4, 0.2: the second-order error is O((eps A^2)^3)."""
    points = numeric_backbone(ground_rhs(0.1), [0.8, 0.4, 0.2], K_CHAIN, 2)
    errs = errors(nnm_backbone(ground(0.1), 2, 2), points)
    assert 5.5 < rate(errs, [A for A, _ in points]) < 6.5, errs


def test_mlp_beats_lp_at_large_amplitude():
    """eps = 1: the cubic spring to ground (mode 1) and the hardening coupling (mode 2, a
    Duffing oscillator) where eps A^2 is of order one and more."""
    points = numeric_backbone(ground_rhs(1.0), [0.5, 1.0, 1.5], K_CHAIN, 1, substeps=3)
    # L-P's omega(A) turns negative beyond A ~ 3 (NaN): mLP still answers there
    e_lp = errors(nnm_backbone(ground(1.0), 1, 2), points, invalid="nan")
    e_mlp = errors(nnm_backbone(ground(1.0), 1, 2, method="mlp"), points)
    assert not math.isnan(e_lp[0]) and math.isnan(e_lp[-1]), e_lp
    for p, m in zip(e_lp, e_mlp, strict=True):
        assert math.isnan(p) or abs(m) < abs(p) / 3, (points, e_lp, e_mlp)
    sysm = System.parse(COUPLING, {"eps": 1.0})
    points = numeric_backbone(coupling_rhs(1.0), [1.0, 2.0, 4.0], K_CHAIN, 2, substeps=6)
    e_lp = errors(nnm_backbone(sysm, 2, 2), points, invalid="nan")
    e_mlp = errors(nnm_backbone(sysm, 2, 2, method="mlp"), points)
    for (_, om), p, m in zip(points, e_lp, e_mlp, strict=True):
        assert abs(m) < 0.02 * om and (math.isnan(p) or abs(m) < abs(p) / 10), (
            points,
            e_lp,
            e_mlp,
        )


# ---------------------------------------------------------- piecewise linear (nsd2) --
def test_nsd2_first_harmonic_equals_quadrature():
    """First order: omega = omega_j + nhat/(2 omega_j A), nhat the first harmonic of
    phi_1j g(phi_1j A cos tau), g(s) = f(s) - s = (k - 1) sat(s) for the device."""
    k = -0.5
    phis = linear_modes(np.array(K_NSD2, dtype=float))
    for mode in (1, 2):
        r = nnm_backbone(nsd2(), mode, 1)
        phi = phis[0, mode - 1]
        w = math.sqrt(phis[:, mode - 1] @ np.array(K_NSD2) @ phis[:, mode - 1])
        for A in (0.5, 3.0, 12.0):

            def g(tau, A=A, phi=phi):
                s = phi * A * math.cos(tau)
                return (k - 1) * max(-1.0, min(1.0, s)) * phi * math.cos(tau)

            # the kinks of sat: phi A cos(tau) = +-1
            S = abs(phi) * A
            th = math.acos(1 / S) if S > 1 else None
            kinks = [th, math.pi - th, math.pi + th, 2 * math.pi - th] if th else None
            nhat = quad(g, 0, 2 * math.pi, points=kinks, limit=200, epsabs=1e-14, epsrel=1e-13)
            nhat = nhat[0] / math.pi
            assert float(r.frequency_at(A, invalid="nan")) == pytest.approx(
                w + nhat / (2 * w * A), rel=1e-12, abs=1e-13
            )


def test_nsd2_backbone_converges_to_the_numerical_one_at_large_amplitude():
    """The device's correction falls like 1/amplitude: first-order errors shrink, mLP's
    faster (mode 2, turning points q1(0) = 20, 10, 5)."""
    points = numeric_backbone(nsd2_rhs(), [20.0, 10.0, 5.0], K_NSD2, 2)
    amps = [A for A, _ in points]
    err = {m: errors(nnm_backbone(nsd2(), 2, 1, method=m), points) for m in ("lp", "mlp")}
    assert rate(err["lp"], amps) < -1.5 and rate(err["mlp"], amps) < -2.5, err
    assert all(abs(e) < 3e-3 for e in err["lp"]) and abs(err["mlp"][0]) < 1e-5, err
    # the equilibrium at rest is unstable (negative stiffness): no real mLP frequency there
    mode1 = nnm_backbone(nsd2(), 1, 1, method="mlp")
    with pytest.raises(ParameterError, match="no real positive frequency at A = 0.1"):
        mode1.frequency_at([0.1, 5.0])
    assert np.isnan(mode1.frequency_at(0.1, invalid="nan"))


def test_nsd2_second_order_is_refused():
    with pytest.raises(ParameterError, match="order = 2 .*piecewise-linear.*expected order = 1"):
        nnm_backbone(nsd2(), 1, 2)


# ----------------------------------------------------------------------- bad input --
def test_bad_input_names_the_value():
    with pytest.raises(ModelError, match="damping C\\[1,1\\] = mu1 \\+ mu2"):
        nnm_backbone(builtin_system("nsd2").with_params(mu2=0, F=0), 1, 1)
    with pytest.raises(ModelError, match="forced: F\\[1\\] = F\\*cos"):
        nnm_backbone(builtin_system("nsd2").with_params(mu1=0, mu2=0), 1, 1)
    three = System.parse(["x1'' + x1 = 0", "x2'' + x2 - x1 = 0", "x3'' + x3 - x2 = 0"])
    with pytest.raises(ModelError, match="3 second-order coordinate\\(s\\).*exactly 2"):
        nnm_backbone(three, 1)
    for mode in (0, 3, True, "1"):
        with pytest.raises(ParameterError, match="mode = .*expected 1 or 2"):
            nnm_backbone(ground(0.1), mode)
    with pytest.raises(ParameterError, match="method = 'hb'"):
        nnm_backbone(ground(0.1), 1, method="hb")
    for order in (0, 5, 1.0):
        with pytest.raises(ParameterError, match="order = "):
            nnm_backbone(ground(0.1), 1, order)
    with pytest.raises(ModelError, match="expected a perturb.model.system.System"):
        nnm_backbone("x1'' + x1 = 0")
    stopped = System.parse(GROUND, {"eps": 0.1}, elements=[stop("x1 - x2", -1, 1)])
    with pytest.raises(ModelError, match="is a stop"):
        nnm_backbone(stopped, 1)
    with pytest.raises(PerturbError, match="damping"):
        nnm_backbone(
            System.parse(["x1'' + c*x1' + 2*x1 - x2 = 0", "x2'' + 2*x2 - x1 = 0"], {"c": 0.1})
        )


def test_internal_resonance_is_refused_with_the_ratio():
    # omega_2 = 3 omega_1 and the cubic of x1 + x2 drives mode 2 at 3 omega: resonant
    sysm = System.parse(["x1'' + x1 + eps*(x1 + x2)**3 = 0", "x2'' + 9*x2 + eps*(x1 + x2)**3 = 0"])
    with pytest.raises(InternalResonanceError, match=r"omega_2 = 3\*omega_1"):
        nnm_backbone(sysm, 1)
    with pytest.raises(InternalResonanceError, match=r"omega_2 = 3\*omega_1"):
        nnm_backbone(sysm, 1, method="mlp")
    # equal frequencies, coupled only by the nonlinearity: 1:1
    equal = System.parse(["x1'' + x1 + eps*(x1 + x2)**3 = 0", "x2'' + x2 + eps*(x1 + x2)**3 = 0"])
    with pytest.raises(InternalResonanceError, match="1:1 internal resonance"):
        nnm_backbone(equal, 1)
    # mode 2 of the first system is not resonant (omega_1 = omega_2/3 is no harmonic)
    assert nnm_backbone(sysm, 2).resonance_denominators


# -------------------------------------------------------------- object and LaTeX --
def test_result_is_immutable_and_printable():
    r = nnm_backbone(ground(0.1), 1, 2, method="mlp")
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.backbone = sp.S.One
    text = str(r)
    assert "mlp(mode=1, order=2)" in text and "omega(A) =" in text and "x2(tau) =" in text
    assert [s.title for s in r.steps][:4] == [
        "Equations of motion",
        "Bookkeeping",
        "Linear modes",
        "Modal equations",
    ]
    assert {"Alpha-transformation", "Order 1 in $\\alpha$", "Order 2 in $\\alpha$"} <= {
        s.title for s in r.steps
    }


def _pdflatex():
    exe = shutil.which("pdflatex")
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail("pdflatex is missing in CI")
        pytest.skip("pdflatex not installed")
    return exe


@pytest.mark.parametrize(
    "make",
    [
        lambda: nnm_backbone(ground(0.1), 1, 2),
        lambda: nnm_backbone(System.parse(COUPLING), 2, 2, method="mlp"),
        lambda: nnm_backbone(nsd2(), 1, 1),
        lambda: nnm_backbone(nsd2(), 2, 1, method="mlp"),
    ],
    ids=["ground-lp2", "coupling-mlp2", "nsd2-lp1", "nsd2-mlp1"],
)
def test_derivation_compiles(make, tmp_path):
    exe = _pdflatex()
    body = derivation_body(make().steps)
    # matrices typeset as matrices; the order-1 equations collected by harmonic
    assert "\\begin{matrix}" in body and "\\cos {3 \\tau}" in body
    doc = "\n".join(
        [
            r"\documentclass[11pt]{article}",
            r"\usepackage[T1]{fontenc}",
            r"\usepackage{lmodern}",
            r"\usepackage{amsmath,amssymb}",
            r"\usepackage[margin=2cm]{geometry}",
            r"\allowdisplaybreaks",
            r"\begin{document}",
            body,
            r"\end{document}",
            "",
        ]
    )
    (tmp_path / "nnm.tex").write_text(doc)
    proc = subprocess.run(
        [exe, "-interaction=nonstopmode", "-halt-on-error", "nnm.tex"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stdout[-3000:]


def test_symbolic_linear_part_is_refused_and_element_parameters_stay_symbolic():
    chain = ["x1'' + (1 + k2)*x1 - k2*x2 + eps*x1**3 = 0", "x2'' + k2*x2 - k2*x1 = 0"]
    with pytest.raises(ParameterError, match=r"parameters without values \(k2\)"):
        nnm_backbone(System.parse(chain), 1)
    r = nnm_backbone(System.parse(chain, {"k2": 2}), 1, 1)
    assert [p.name for p in r.parameters] == ["eps"] and r.values["eps"] is None
    with pytest.raises(ParameterError, match="needs values for eps"):
        r.frequency_at(1.0)


def test_forces_without_a_potential_or_symmetry_are_refused():
    # a cubic of x2 acting on x1 alone: w = (1, 0) is not along c = (0, 1)
    follower = System.parse(["x1'' + 2*x1 - x2 + eps*x2**3 = 0", "x2'' + 2*x2 - x1 = 0"])
    with pytest.raises(ModelError, match="not conservative"):
        nnm_backbone(follower, 1)
    skew = System.parse(["x1'' + 2*x1 - x2 = 0", "x2'' + 2*x2 - 3*x1 + eps*x2**3 = 0"])
    with pytest.raises(ModelError, match="must be symmetric"):
        nnm_backbone(skew, 1)
    one_sided = System.parse(
        ["x1'' + 2*x1 - x2 + (x1 - 1)*Heaviside(x1 - 1) = 0", "x2'' + 2*x2 - x1 = 0"]
    )
    with pytest.raises(ModelError, match="is not odd"):
        nnm_backbone(one_sided, 1, 1)
    unstable = System.parse(["x1'' - x1 + eps*x1**3 = 0", "x2'' + x2 = 0"])
    with pytest.raises(ModelError, match="eigenvalue omega\\*\\*2 = -1"):
        nnm_backbone(unstable, 1)


def test_near_internal_resonance_is_stated_in_the_notes():
    # omega_2/omega_1 = sqrt(9.3) ~ 3.05: the divisor omega_2^2 - 9 omega_1^2 = 0.3 is small
    near = System.parse(
        ["x1'' + x1 + eps*(x1 + x2)**3 = 0", "x2'' + 93/10*x2 + eps*(x1 + x2)**3 = 0"]
    )
    r = nnm_backbone(near, 1, 1)
    assert any("near internal resonance omega_2 ~ 3*omega_1" in n for n in r.notes), r.notes
    assert dict(r.resonance_denominators)[3] == sp.Rational(3, 10)


def test_gap_element_with_symbolic_clearance_takes_the_parameter_values():
    """impact_pair: a two-sided gap of clearance d and contact stiffness r on x1 - x2; the
    reference stiffness is the contact one, [[1 + r, -r], [-r, r]] with M = diag(1, m2)."""
    r_, m2 = 20.0, 0.2
    sysm = builtin_system("impact_pair").with_params(mu=0, mu2=0, F=0, r=r_, m2=m2, d=0.5)
    r = nnm_backbone(sysm, 2, 1, method="mlp")
    K = np.array([[1 + r_, -r_], [-r_, r_]])
    Minv_sqrt = np.diag([1.0, 1 / math.sqrt(m2)])
    expected = np.sqrt(np.linalg.eigvalsh(Minv_sqrt @ K @ Minv_sqrt))
    assert [float(w) for w in r.natural_frequencies] == pytest.approx(expected, rel=1e-12)
    # far beyond the clearance the gap is the contact spring: the linear frequency
    assert float(r.frequency_at(1e4)) == pytest.approx(expected[1], rel=1e-3)


QUADRATIC = ["x1'' + x1 + a*x1*x2 = 0", "x2'' + 2.2*x2 + a*x1**2/2 = 0"]


def quadratic_brake_orbit(x0: float, a: float = 1.0) -> tuple[float, float]:
    """DOP853 (rtol = atol = 1e-12) NNM of mode 1 of QUADRATIC (potential x1**2/2 +
    1.1 x2**2 + a x1**2 x2/2): the brake orbit from (x0, y; 0, 0) whose velocities vanish
    again at half the period (y and the half period by a root solve); returns (first-harmonic
    amplitude of x1, frequency)."""

    def f(t, y):
        x1, x2, v1, v2 = y
        return [v1, v2, -x1 - a * x1 * x2, -2.2 * x2 - a * x1**2 / 2]

    def half(z):
        s = solve_ivp(f, (0, z[1]), [x0, z[0], 0, 0], method="DOP853", rtol=1e-12, atol=1e-12)
        return [s.y[2, -1], s.y[3, -1]]

    sol = root(half, [-5 / 44 * a * x0**2, math.pi], tol=1e-13)
    assert sol.success
    y0, T = sol.x[0], 2 * sol.x[1]
    w = 2 * math.pi / T
    tt = np.linspace(0, T, 4001)
    s = solve_ivp(f, (0, T), [x0, y0, 0, 0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=tt)
    # periodic, smooth integrand: the trapezoid rule on a full period is spectrally accurate
    amp = 2 / T * float(np.sum(s.y[0, :-1] * np.cos(w * tt[:-1])) * (tt[1] - tt[0]))
    return amp, w


def test_conservative_pair_with_a_quadratic_coupling_against_brake_orbits():
    # x1**2/2 acts on x2 alone and x1*x2 on x1 alone: neither element is along its own
    # combination, but together they are the gradient of a x1**2 x2/2 (refused before as
    # "not along its combination")
    r = nnm_backbone(System.parse(QUADRATIC, {"a": 1.0}), 1, 2)
    errs = []
    for x0 in (0.1, 0.2):
        amp, w = quadratic_brake_orbit(x0)
        errs.append(abs(float(r.frequency_at(amp)) - w))
    # order 2 leaves O(A**4): the frequency shift itself is 2.2e-4 at x0 = 0.1
    assert errs[0] < 1e-6
    assert 10 < errs[1] / errs[0] < 24
    # with only quadratic terms nu = 0: mLP would divide by it (delta_2 = zoo before)
    with pytest.raises(ModelError, match="method='lp'"):
        nnm_backbone(System.parse(QUADRATIC, {"a": 1.0}), 1, 2, method="mlp")


def test_one_sided_polynomial_force_names_the_potential_not_a_static_load():
    # e*x2*x1**2 in the second equation only: the first equation's part is 0, which was
    # reported as "a static load 0"
    s = System.parse(["x1'' + x1 + e*x1**3 = 0", "x2'' + 9.01*x2 + e*x2*x1**2 = 0"])
    with pytest.raises(ModelError, match="not conservative") as info:
        nnm_backbone(s, 1, 2)
    assert "static load" not in str(info.value)


def test_mode_given_as_a_whole_float_is_the_mode():
    s = System.parse(GROUND)
    assert nnm_backbone(s, 2.0, 1).backbone == nnm_backbone(s, 2, 1).backbone
    with pytest.raises(ParameterError, match="mode"):
        nnm_backbone(s, "2", 1)


def test_numeric_evaluation_refuses_text_nan_and_negative_amplitudes_by_name():
    # displacement_at("x") raised a bare ValueError, displacement_at(0.5, nan) returned NaN
    # silently, and frequency_at("0.5") read text as a number
    r = nnm_backbone(ground(0.5), 1, 2)
    for bad in ("0.5", None, float("nan"), -0.5, [0.1, float("inf")]):
        with pytest.raises(ParameterError, match="A = "):
            r.frequency_at(bad)
        with pytest.raises(ParameterError, match="A = "):
            r.displacement_at(bad)
    for bad in ("a", float("nan")):
        with pytest.raises(ParameterError, match="tau = "):
            r.displacement_at(0.5, bad)
    # the turning point at tau = 0 and at tau = 2 pi are the same state
    assert np.allclose(r.displacement_at(0.3, 0.0), r.displacement_at(0.3, 2 * math.pi))
