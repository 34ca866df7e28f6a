r"""He & Singh (2007): step response of a hydraulic engine mount from a simplified linear model.

What this script checks (the seed's equations are partly lost; docs/references.md section 4):

1. *Symbolic reduction.*  The lumped fluid equations of a fixed-decoupler mount,

       A_r x' - q_i = C_1 p_1',   q_i = C_2 p_2',   p_1 - p_2 = I_i q_i' + R_i q_i,
       F_T = k_r x + A_r p_1,

   are Laplace-transformed and solved by SymPy for the dynamic stiffness K_1(s) = F_T/X and the
   pressure transfer function P_1/X; their coefficients are matched to the paper's canonical
   forms (gamma, omega_1, omega_2, zeta_1, zeta_2; lambda, varpi, xi) and the identities
   zeta_1 omega_1 = zeta_2 omega_2 = varpi xi = R_i/(2 I_i) are simplified to zero.
2. *Closed-form step responses* by partial fractions and SymPy's inverse Laplace transform,
   verified against their own ODE and initial values; peaks at n pi/omega_d, the decay
   envelope, the settling time.  Numerically: against ``scipy.signal.step`` of the transfer
   functions and against perturb's closed-form linear step response of the lumped ODEs (an
   eigen-decomposition of their matrix, not the transfer functions).
3. *Nonlinear mount.*  Top-chamber vacuum (the compliance C_1 switches to a larger value below
   a pressure -p_v) and a free decoupler (a plate in a gap, with inertance I_d and resistance
   R_d while it floats and no flow while it rests on a stop).  The fixed-decoupler vacuum model
   is piecewise linear and runs on perturb's exact closed-form propagation, and also, as one
   oscillator, on perturb's SDOF event-driven integrator
   (:func:`perturb.simulate.flows.event_driven.simulate`) and on its n-state event-driven flow;
   the free-decoupler model has four states (two flows and two volumes) and a stop, and runs on
   the n-state event-driven flow.  All through
   :func:`perturb.simulate.step_response.step_response`, with the models of
   :func:`perturb.model.system_builtins.mount_system`; they agree where several apply.

4. *Quasi-linear model* (the paper's eqs. 14-16, lost from the seed and reconstructed): with
   the decoupler floating, the track and the plate are two inertance/resistance branches in
   parallel; SymPy shows the mount is K_1(s) with the track impedance replaced by
   Z_e = Z_i Z_d/(Z_i + Z_d), and the one-branch model with the large-s asymptote
   I_e s + R_e of Z_e is compared with the full four-state model (perturb's closed-form step
   response, ``scipy.signal``) and with the small-s asymptote.
5. *The three step-response components* (static, decaying cosine, decaying sine): peak and
   energy shares of the sine term, the one the paper neglects, and what dropping it does to
   the extrema.

Parameter values are representative (the paper gives none); see :class:`Mount`.

Run ``python derivations/hydraulic_mount.py [--fast] [--out DIR]``; outputs go to ``DIR``
(default ``derivations/out/hydraulic_mount/``): section.tex, PNG figures, CSV tables.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path

import numpy as np
import sympy as sp
from scipy import signal
from scipy.optimize import brentq

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:  # imported by path (tests) rather than run as a script
    sys.path.insert(0, str(HERE))

from _common import Study, study  # noqa: E402

from perturb.model.oscillator import Oscillator  # noqa: E402
from perturb.model.system import System  # noqa: E402
from perturb.model.system_builtins import (  # noqa: E402
    builtin_system,
    mount_outputs,
    mount_system,
)
from perturb.printing import latex  # noqa: E402
from perturb.report.latex import escape  # noqa: E402
from perturb.simulate.flows.event_driven import simulate as event_driven_simulate  # noqa: E402
from perturb.simulate.step_response import step_response  # noqa: E402

NAME = "hydraulic_mount"
EPSILONS = (0.01, 0.02, 0.05)


# --------------------------------------------------------------------------------------------
# parameters
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Mount:
    """Lumped parameters of a hydraulic mount, SI units.

    The paper gives no values; these are representative of the passenger-car mounts in the
    works it cites (rubber stiffness a few hundred kN/m, top chamber ~100 times stiffer than
    the bottom one, inertia-track resonance near 10 Hz, decoupler gap below a millimetre).
    The step sizes are the paper's: release of a 3.7 mm preload to 0 (fixed decoupler) and to
    1.3 mm (free decoupler).  The seed text drops the digits 1 and 2, so "3.7" and ".3" are
    reconstructed (1.3 mm is our reading of ".3 mm").
    """

    k_r: float = 2.5e5  # N/m, rubber stiffness
    A_r: float = 3.0e-3  # m^2, effective piston area
    C1: float = 4.0e-11  # m^5/N, top chamber compliance
    C2: float = 4.0e-9  # m^5/N, bottom chamber compliance (C2 = 100 C1)
    I_i: float = 6.0e6  # kg/m^4, inertia-track inertance
    R_i: float = 9.0e7  # N s/m^5, inertia-track resistance
    # nonlinear extras
    p_vac: float = 9.0e4  # Pa, dynamic top-chamber suction at which vacuum/air release starts
    C1_vac: float = 2.0e-9  # m^5/N, top chamber compliance under vacuum (50 C1)
    I_d: float = 1.5e5  # kg/m^4, decoupler inertance
    R_d: float = 1.5e7  # N s/m^5, decoupler resistance
    V_gap: float = 7.5e-7  # m^3, decoupler half-stroke volume (plate area 15 cm^2, gap 0.5 mm)
    # steps (release of the compressive preload: the top chamber expands)
    X_fixed: float = -3.7e-3  # m
    X_free: float = -2.4e-3  # m
    rise: float = 8.0e-3  # s, rise time of the released step (the paper's is not ideal)

    def values(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


PARAM_TEX = {
    "k_r": (r"k_r", "N/m", "rubber stiffness"),
    "A_r": (r"A_r", "m$^2$", "effective piston area"),
    "C1": (r"C_1", "m$^5$/N", "top chamber compliance"),
    "C2": (r"C_2", "m$^5$/N", "bottom chamber compliance"),
    "I_i": (r"I_i", "kg/m$^4$", "inertia-track inertance"),
    "R_i": (r"R_i", "N\\,s/m$^5$", "inertia-track resistance"),
    "p_vac": (r"p_v", "Pa", "suction at which vacuum starts"),
    "C1_vac": (r"C_{1v}", "m$^5$/N", "top chamber compliance under vacuum"),
    "I_d": (r"I_d", "kg/m$^4$", "decoupler inertance"),
    "R_d": (r"R_d", "N\\,s/m$^5$", "decoupler resistance"),
    "V_gap": (r"V_g", "m$^3$", "decoupler half-stroke volume"),
    "X_fixed": (r"X", "m", "step, fixed decoupler (3.7 mm, reconstructed)"),
    "X_free": (r"X", "m", "step, free decoupler (3.7 to 1.3 mm, reconstructed)"),
    "rise": (r"t_r", "s", "rise time of the ramped step (nonlinear runs)"),
}


# --------------------------------------------------------------------------------------------
# 1. symbolic reduction
# --------------------------------------------------------------------------------------------
k_r, A_r, C1, C2, I_i, R_i = sp.symbols("k_r A_r C_1 C_2 I_i R_i", positive=True)
s = sp.Symbol("s")
t = sp.Symbol("t", positive=True)
gam, w1, w2, z1, z2 = sp.symbols("gamma omega_1 omega_2 zeta_1 zeta_2", positive=True)
sig, wd, U = sp.symbols("sigma omega_d u^2", positive=True)
#: on the paper's curve: sigma = zeta_2 omega_2, omega_d = omega_2 sqrt(1 - zeta_2^2), u = w2/w1
ON_CURVE = {w2: sp.sqrt(sig**2 + wd**2), w1: sp.sqrt(sig**2 + wd**2) / sp.sqrt(U)}


#: each symbolic claim of :func:`reduce_lumped_model` as a formula, for the LaTeX section
IDENTITY_TEX = {
    "gamma = k_r + A_r^2/(C_1+C_2)": r"\gamma = k_r + A_r^2/(C_1+C_2)",
    "omega_2^2 = (C_1+C_2)/(I_i C_1 C_2)": r"\omega_2^2 = (C_1+C_2)/(I_iC_1C_2)",
    "zeta_1 omega_1 = R_i/(2 I_i)": r"\zeta_1\omega_1 = R_i/(2I_i)",
    "zeta_2 omega_2 = R_i/(2 I_i)": r"\zeta_2\omega_2 = R_i/(2I_i)",
    "xi varpi = R_i/(2 I_i)": r"\xi\varpi = R_i/(2I_i)",
    "lambda = A_r/(C_1+C_2)": r"\lambda = A_r/(C_1+C_2)",
    "varpi^2 = 1/(I_i C_2)": r"\varpi^2 = 1/(I_iC_2)",
    "P_1/X has the denominator of K_1 (omega)": r"\omega_2^2\big|_{P_1/X} = \omega_2^2\big|_{K_1}",
    "P_1/X has the denominator of K_1 (zeta)": r"\zeta_2\omega_2\big|_{P_1/X} = "
    r"\zeta_2\omega_2\big|_{K_1}",
    "K_1(inf) = k_r + A_r^2/C_1": r"K_1(\infty) = k_r + A_r^2/C_1",
    "P_1/X(inf) = A_r/C_1": r"P_1/X(\infty) = A_r/C_1",
    "u^2 = K_1(inf)/gamma": r"\omega_2^2/\omega_1^2 = K_1(\infty)/\gamma",
    "inverse Laplace = docs/references.md form": r"\mathcal{L}^{-1}\{K_1/(\gamma s)\} = "
    r"\text{the form below}",
    "closed form solves (D^2 + 2 sigma D + omega_2^2) F = omega_2^2": r"\ddot F + 2\sigma\dot F"
    r" + \omega_2^2F = \omega_2^2",
    "F(0+) = u^2 = K_1(oo)/gamma": r"F(0^+) = u^2",
    "F'(0+) = 0": r"\dot F(0^+) = 0",
    "F' has no cos(omega_d t) part": r"\dot F \propto e^{-\sigma t}\sin\omega_d t",
    "R = (u^2-1)^2/(1-zeta_2^2)": r"R = (u^2-1)^2/(1-\zeta_2^2)",
    "R without the identity": r"R(\sigma_1) = \text{the form below}",
}


@dataclass(frozen=True)
class Reduction:
    """The symbolic results.

    ``zero`` maps each claimed identity to its residual after exact rational simplification
    (``cancel``/``expand``; a claim holds when the residual is 0).  Step responses are per
    unit step and unit gain, in sigma, omega_d and u^2 = (omega_2/omega_1)^2.
    """

    K1: sp.Expr
    P1X: sp.Expr
    coefficients: dict[str, sp.Expr]
    zero: dict[str, sp.Expr]
    step: sp.Expr  # F(t)/(gamma X) with the identity
    step_paper: sp.Expr  # the docs/references.md form, for comparison
    slope: sp.Expr  # d step/dt
    envelope_sq: sp.Expr  # R = (u^2-1)^2/(1-zeta_2^2) in sigma, omega_d
    envelope_sq_general: sp.Expr  # R for independent zeta_1 omega_1
    limits: dict[str, sp.Expr] = field(default_factory=dict)


def _quadratic(expr: sp.Expr) -> tuple[list[sp.Expr], list[sp.Expr]]:
    num, den = sp.fraction(sp.cancel(sp.together(expr)))
    return sp.Poly(num, s).all_coeffs(), sp.Poly(den, s).all_coeffs()


def _canonical(expr: sp.Expr) -> dict[str, sp.Expr]:
    """Gain, squared frequencies, zeta*omega products and high-frequency limit of a
    ratio of two quadratics in s."""
    (n2, n1, n0), (d2, d1, d0) = _quadratic(expr)
    return {
        "gain": sp.factor(n0 / d0),
        "num_w2": sp.factor(n0 / n2),
        "den_w2": sp.factor(d0 / d2),
        "num_zw": sp.factor(n1 / (2 * n2)),
        "den_zw": sp.factor(d1 / (2 * d2)),
        "high": sp.factor(n2 / d2),
    }


def inverse_step(zeta1_omega1: sp.Expr) -> sp.Expr:
    r"""Unit-gain step response of ``(s^2/w1^2 + 2 z1 s/w1 + 1)/(s^2/w2^2 + 2 z2 s/w2 + 1)``.

    Partial fractions split ``G(s)/s`` into ``1/s`` plus ``(alpha s + beta)/((s + sigma)^2 +
    omega_d^2)``; SymPy's inverse Laplace transform inverts the latter.  ``zeta1_omega1`` is
    the numerator's zeta_1 omega_1 (sigma for the paper's identity, a free symbol otherwise).
    """
    G = (s**2 / w1**2 + 2 * z1 * s / w1 + 1) / (s**2 / w2**2 + 2 * z2 * s / w2 + 1)
    den = s**2 + 2 * z2 * w2 * s + w2**2
    alpha, beta = sp.Poly(sp.cancel((G / s - 1 / s) * den), s).all_coeffs()
    sub = {z1: zeta1_omega1 / w1, z2: sig / w2}
    alpha, beta = (sp.cancel(sp.expand(c.subs(sub).subs(ON_CURVE))) for c in (alpha, beta))
    return 1 + sp.inverse_laplace_transform((alpha * s + beta) / ((s + sig) ** 2 + wd**2), s, t)


@cache
def reduce_lumped_model() -> Reduction:
    """SymPy reduction of the fixed-decoupler lumped model; see the module docstring."""
    X, P1, P2, Q = sp.symbols("X P_1 P_2 Q_i")
    eqs = [
        sp.Eq(C1 * s * P1, A_r * s * X - Q),  # top chamber continuity
        sp.Eq(C2 * s * P2, Q),  # bottom chamber continuity
        sp.Eq(P1 - P2, (I_i * s + R_i) * Q),  # inertia-track momentum
    ]
    sol = sp.solve(eqs, [P1, P2, Q], dict=True)[0]
    P1X = sp.cancel(sol[P1] / X)
    K1 = sp.cancel(k_r + A_r * P1X)  # F_T = k_r x + A_r p_1 (b_r = 0)
    ck, cp = _canonical(K1), _canonical(P1X)
    coeff = {
        "gamma": ck["gain"],
        "omega_1^2": ck["num_w2"],
        "omega_2^2": ck["den_w2"],
        "zeta_1 omega_1": ck["num_zw"],
        "zeta_2 omega_2": ck["den_zw"],
        "K_1(inf)": ck["high"],
        "lambda": cp["gain"],
        "varpi^2": cp["num_w2"],
        "xi varpi": cp["num_zw"],
        "P: omega_2^2": cp["den_w2"],
        "P: zeta_2 omega_2": cp["den_zw"],
        "P_1/X(inf)": cp["high"],
    }
    half_rate = R_i / (2 * I_i)
    zero = {
        "gamma = k_r + A_r^2/(C_1+C_2)": coeff["gamma"] - (k_r + A_r**2 / (C1 + C2)),
        "omega_2^2 = (C_1+C_2)/(I_i C_1 C_2)": coeff["omega_2^2"] - (C1 + C2) / (I_i * C1 * C2),
        "zeta_1 omega_1 = R_i/(2 I_i)": coeff["zeta_1 omega_1"] - half_rate,
        "zeta_2 omega_2 = R_i/(2 I_i)": coeff["zeta_2 omega_2"] - half_rate,
        "xi varpi = R_i/(2 I_i)": coeff["xi varpi"] - half_rate,
        "lambda = A_r/(C_1+C_2)": coeff["lambda"] - A_r / (C1 + C2),
        "varpi^2 = 1/(I_i C_2)": coeff["varpi^2"] - 1 / (I_i * C2),
        "P_1/X has the denominator of K_1 (omega)": coeff["P: omega_2^2"] - coeff["omega_2^2"],
        "P_1/X has the denominator of K_1 (zeta)": coeff["P: zeta_2 omega_2"]
        - coeff["zeta_2 omega_2"],
        "K_1(inf) = k_r + A_r^2/C_1": coeff["K_1(inf)"] - (k_r + A_r**2 / C1),
        "P_1/X(inf) = A_r/C_1": coeff["P_1/X(inf)"] - A_r / C1,
        "u^2 = K_1(inf)/gamma": coeff["omega_2^2"] / coeff["omega_1^2"]
        - coeff["K_1(inf)"] / coeff["gamma"],
    }
    step = inverse_step(sig)
    decay, cos_t, sin_t = sp.exp(-sig * t), sp.cos(wd * t), sp.sin(wd * t)
    step_paper = 1 + (U - 1) * decay * (cos_t + sig / wd * sin_t)  # zeta/sqrt(1-zeta^2) = s/wd
    zero["inverse Laplace = docs/references.md form"] = step - step_paper
    # the closed form against its own ODE and the initial-value theorem:
    # (D^2 + 2 sigma D + omega_2^2) F = omega_2^2, F(0+) = G(oo) = u^2, F'(0+) = 0
    w2sq = sig**2 + wd**2
    ode = sp.diff(step, t, 2) + 2 * sig * sp.diff(step, t) + w2sq * step - w2sq
    zero["closed form solves (D^2 + 2 sigma D + omega_2^2) F = omega_2^2"] = ode
    zero["F(0+) = u^2 = K_1(oo)/gamma"] = step.subs(t, 0) - U
    zero["F'(0+) = 0"] = sp.diff(step, t).subs(t, 0)
    slope = sp.diff(step, t)
    # peaks: F' is a multiple of exp(-sigma t) sin(omega_d t) -> zeros at n pi/omega_d
    zero["F' has no cos(omega_d t) part"] = sp.expand(slope / decay).coeff(cos_t)
    R = sp.expand(step_paper / decay).coeff(cos_t) ** 2 + (
        sp.expand(step_paper / decay).coeff(sin_t) ** 2
    )
    zero["R = (u^2-1)^2/(1-zeta_2^2)"] = R - (U - 1) ** 2 * w2sq / wd**2
    s1 = sp.Symbol("sigma_1", positive=True)  # the numerator's zeta_1 omega_1, left free
    general = inverse_step(s1)
    Rg = sp.expand(general / decay).coeff(cos_t) ** 2 + sp.expand(general / decay).coeff(sin_t) ** 2
    R_general = (U - 1) ** 2 + (2 * s1 * U - sig * (1 + U)) ** 2 / wd**2
    zero["R without the identity"] = Rg - R_general
    zero = {k: sp.cancel(sp.expand(v)) for k, v in zero.items()}
    eps = sp.Symbol("epsilon", positive=True)

    def c2_limit(expr):
        return sp.factor(sp.cancel(expr.subs(C2, 1 / eps)).subs(eps, 0))

    limits = {
        "omega_1^2": c2_limit(coeff["omega_1^2"]),
        "omega_2^2": c2_limit(coeff["omega_2^2"]),
        "gamma": c2_limit(coeff["gamma"]),
    }
    return Reduction(
        K1=K1,
        P1X=P1X,
        coefficients=coeff,
        zero=zero,
        step=step,
        step_paper=step_paper,
        slope=slope,
        envelope_sq=sp.factor(R),
        envelope_sq_general=R_general,
        limits=limits,
    )


# --------------------------------------------------------------------------------------------
# 2. linear model, numerically
# --------------------------------------------------------------------------------------------
def _physical(m: Mount) -> dict[sp.Symbol, float]:
    return {k_r: m.k_r, A_r: m.A_r, C1: m.C1, C2: m.C2, I_i: m.I_i, R_i: m.R_i}


def canonical(m: Mount) -> dict[str, float]:
    """Numbers of the canonical forms (from the symbolic coefficients) and derived rates."""
    return dict(_canonical_numbers(m))


@cache
def _canonical_numbers(m: Mount) -> dict[str, float]:
    red = reduce_lumped_model()
    sub = _physical(m)
    c = {k: float(v.subs(sub)) for k, v in red.coefficients.items()}
    out = {
        "gamma": c["gamma"],
        "omega_1": math.sqrt(c["omega_1^2"]),
        "omega_2": math.sqrt(c["omega_2^2"]),
        "lambda": c["lambda"],
        "varpi": math.sqrt(c["varpi^2"]),
    }
    out["zeta_1"] = c["zeta_1 omega_1"] / out["omega_1"]
    out["zeta_2"] = c["zeta_2 omega_2"] / out["omega_2"]
    out["xi"] = c["xi varpi"] / out["varpi"]
    out["sigma"] = c["zeta_2 omega_2"]
    out["omega_d"] = out["omega_2"] * math.sqrt(1.0 - out["zeta_2"] ** 2)
    out["u"] = out["omega_2"] / out["omega_1"]
    out["u_hat"] = out["omega_2"] / out["varpi"]
    out["v"] = out["zeta_2"] / out["zeta_1"]
    out["v_hat"] = out["zeta_2"] / out["xi"]
    root = math.sqrt(1.0 - out["zeta_2"] ** 2)
    out["sqrtR_F"] = abs(out["u"] ** 2 - 1.0) / root
    out["sqrtR_p"] = abs(out["u_hat"] ** 2 - 1.0) / root
    out["K_inf"] = c["K_1(inf)"]
    out["P_inf"] = c["P_1/X(inf)"]
    return out


@cache
def _step_functions() -> Callable:
    red = reduce_lumped_model()
    return sp.lambdify((t, sig, wd, U), red.step, "numpy")


def step_closed_form(m: Mount, times: np.ndarray, X: float = 1.0) -> tuple[np.ndarray, ...]:
    """Closed-form force and top-chamber pressure after a step ``x = X U(t)`` (t >= 0)."""
    c = canonical(m)
    f = _step_functions()
    times = np.asarray(times, dtype=float)
    F = X * c["gamma"] * f(times, c["sigma"], c["omega_d"], c["u"] ** 2)
    p = X * c["lambda"] * f(times, c["sigma"], c["omega_d"], c["u_hat"] ** 2)
    return np.broadcast_to(F, times.shape).copy(), np.broadcast_to(p, times.shape).copy()


def transfer_functions(m: Mount) -> tuple[signal.TransferFunction, signal.TransferFunction]:
    """K_1(s) and P_1/X(s) as ``scipy.signal`` systems, from the symbolic polynomials."""
    red = reduce_lumped_model()
    sub = _physical(m)
    out = []
    for expr in (red.K1, red.P1X):
        num, den = _quadratic(expr)
        num = np.array([float(a.subs(sub)) for a in num])
        den = np.array([float(a.subs(sub)) for a in den])
        out.append(signal.TransferFunction(num / den[0], den / den[0]))
    return out[0], out[1]


def step_scipy(m: Mount, times: np.ndarray, X: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.step`` of both transfer functions (uniform ``times`` from 0)."""
    K, H = transfer_functions(m)
    _, F = signal.step(K, T=times)
    _, p = signal.step(H, T=times)
    return X * F, X * p


@dataclass(frozen=True)
class LumpedRun:
    t: np.ndarray
    F: np.ndarray
    p1: np.ndarray
    extrema: np.ndarray  # times where q_i = 0, i.e. dF/dt = A_r dp_1/dt = 0


def lumped_system(m: Mount) -> System:
    """The fixed-decoupler lumped ODEs in (p_1, p_2, q_i) for t > 0 (x' = 0), as a perturb
    system of three first-order states."""
    return System.parse(
        ["C1*p1' + q_i = 0", "C2*p2' - q_i = 0", "I_i*q_i' + R_i*q_i - p1 + p2 = 0"],
        {"C1": m.C1, "C2": m.C2, "I_i": m.I_i, "R_i": m.R_i},
        name="mount-lumped",
    )


def integrate_lumped(m: Mount, times: np.ndarray, X: float = 1.0) -> LumpedRun:
    """The lumped ODEs in (p_1, p_2, q_i) after an ideal step, by perturb's closed-form linear
    step response (:func:`perturb.simulate.step_response.step_response`, eigen-decomposition
    of the balanced system matrix: no transfer function, no SymPy).

    Across t = 0 only the top-chamber continuity sees the impulse A_r x'(t): p_1 jumps by
    A_r X / C_1 while p_2 and q_i stay 0.  For t > 0, x' = 0.  The extrema of F_T are the
    zeros of q_i, located on the closed form.
    """
    r = step_response(
        lumped_system(m),
        times,
        y0=[m.A_r * X / m.C1, 0.0, 0.0],
        method="closed_form",
        crossings=["q_i"],
    )
    ext = r.crossings["q_i"]
    ext = ext[ext > 1e-9 * times[-1]]  # q_i = 0 at the start is not an extremum
    p1 = np.array(r.state("p1"))
    return LumpedRun(t=np.array(r.times), F=m.k_r * X + m.A_r * p1, p1=p1, extrema=ext)


def peak_times(m: Mount, n: int) -> np.ndarray:
    """t_p(k) = k pi / omega_d, k = 1..n."""
    return np.arange(1, n + 1) * math.pi / canonical(m)["omega_d"]


def settling(m: Mount, eps: float, X: float = 1.0) -> dict[str, float]:
    """Settling of the force to within ``eps`` of its final value.

    ``estimate``: ln(sqrt(R)/eps)/sigma (the envelope reaches eps); ``crude``: ln(1/eps)/sigma
    (the paper's simplification, sqrt(R) ~ 1); ``exact``: the last time |F - F_inf| =
    eps |F_inf|, found on the closed form; ``error_at_crude``: the largest relative deviation
    after the crude time.
    """
    c = canonical(m)
    est = math.log(c["sqrtR_F"] / eps) / c["sigma"]
    crude = math.log(1.0 / eps) / c["sigma"]
    T = 1.5 * max(est, crude)
    grid = np.linspace(0.0, T, 200_001)
    F, _ = step_closed_form(m, grid, X)
    final = c["gamma"] * X
    dev = np.abs(F - final) / abs(final) - eps
    last = np.nonzero(dev > 0)[0][-1]

    def g(tt):
        return abs(step_closed_form(m, np.array([tt]), X)[0][0] - final) / abs(final) - eps

    exact = brentq(g, grid[last], grid[last + 1], xtol=1e-15, rtol=1e-14)
    after = grid >= crude
    return {
        "eps": eps,
        "estimate": est,
        "crude": crude,
        "exact": exact,
        "error_at_crude": float(np.max(np.abs(F[after] - final)) / abs(final)),
    }


# --------------------------------------------------------------------------------------------
# 2b. the quasi-linear model: inertia track and floating decoupler as one effective branch
# --------------------------------------------------------------------------------------------
I_d, R_d = sp.symbols("I_d R_d", positive=True)

#: the claims of :func:`quasi_linear_model` as formulas, for the LaTeX section
QUASI_TEX = {
    "K_full = K_1 with I_i s + R_i -> Z_e": r"K(s) = K_1(s)\big|_{I_is+R_i\,\to\,Z_e(s)}",
    "I_e = I_i I_d/(I_i+I_d)": r"I_e = I_iI_d/(I_i+I_d)",
    "R_e = (I_i^2 R_d + I_d^2 R_i)/(I_i+I_d)^2": r"R_e = (I_i^2R_d+I_d^2R_i)/(I_i+I_d)^2",
    "R_0 = R_i R_d/(R_i+R_d)": r"R_0 = R_iR_d/(R_i+R_d)",
    "I_0 = (I_i R_d^2 + I_d R_i^2)/(R_i+R_d)^2": r"I_0 = (I_iR_d^2+I_dR_i^2)/(R_i+R_d)^2",
}


@dataclass(frozen=True)
class QuasiLinear:
    """The floating-decoupler linear model and its one-branch reductions (symbolic).

    ``zero`` maps each claim to its residual after exact rational simplification.  ``I_e``,
    ``R_e`` match Z_e(s) for large s (the quasi-linear model used here), ``I_0``, ``R_0``
    for small s.
    """

    K_full: sp.Expr
    Z_e: sp.Expr
    I_e: sp.Expr
    R_e: sp.Expr
    I_0: sp.Expr
    R_0: sp.Expr
    zero: dict[str, sp.Expr]


@cache
def quasi_linear_model() -> QuasiLinear:
    """He & Singh eqs. 14-16 as reconstructed here (the seed's displayed equations are lost).

    The floating decoupler is a second inertance/resistance branch in parallel with the inertia
    track: ``p_1 - p_2 = (I_d s + R_d) Q_d = (I_i s + R_i) Q_i``, and both flows leave the top
    chamber.  SymPy solves the four Laplace-domain equations for K(s) = F_T/X and shows it is
    K_1(s) with the track impedance replaced by ``Z_e = Z_i Z_d/(Z_i + Z_d)`` (parallel
    impedances add as admittances).  ``Z_e`` is not of the form I s + R; its asymptotes are
    ``I_e s + R_e`` for large s (polynomial division) and ``R_0 + I_0 s`` for small s (Taylor).
    """
    X, P1, P2, Qi, Qd, Q, Z = sp.symbols("X P_1 P_2 Q_i Q_d Q Z")
    eqs = [
        sp.Eq(C1 * s * P1, A_r * s * X - Qi - Qd),
        sp.Eq(C2 * s * P2, Qi + Qd),
        sp.Eq(P1 - P2, (I_i * s + R_i) * Qi),
        sp.Eq(P1 - P2, (I_d * s + R_d) * Qd),
    ]
    sol = sp.solve(eqs, [P1, P2, Qi, Qd], dict=True)[0]
    K_full = sp.cancel(k_r + A_r * sol[P1] / X)
    one = sp.solve(
        [sp.Eq(C1 * s * P1, A_r * s * X - Q), sp.Eq(C2 * s * P2, Q), sp.Eq(P1 - P2, Z * Q)],
        [P1, P2, Q],
        dict=True,
    )[0]
    Zi, Zd = I_i * s + R_i, I_d * s + R_d
    Z_e = Zi * Zd / (Zi + Zd)
    num, den = sp.fraction(sp.cancel(Z_e))
    quotient, _ = sp.div(sp.Poly(num, s), sp.Poly(den, s))
    I_e_sym, R_e_sym = (sp.factor(cf) for cf in quotient.all_coeffs())
    taylor = sp.series(Z_e, s, 0, 2).removeO()
    R_0_sym, I_0_sym = sp.factor(taylor.coeff(s, 0)), sp.factor(taylor.coeff(s, 1))
    zero = {
        "K_full = K_1 with I_i s + R_i -> Z_e": K_full - (k_r + A_r * one[P1] / X).subs(Z, Z_e),
        "I_e = I_i I_d/(I_i+I_d)": I_e_sym - I_i * I_d / (I_i + I_d),
        "R_e = (I_i^2 R_d + I_d^2 R_i)/(I_i+I_d)^2": R_e_sym
        - (I_i**2 * R_d + I_d**2 * R_i) / (I_i + I_d) ** 2,
        "R_0 = R_i R_d/(R_i+R_d)": R_0_sym - R_i * R_d / (R_i + R_d),
        "I_0 = (I_i R_d^2 + I_d R_i^2)/(R_i+R_d)^2": I_0_sym
        - (I_i * R_d**2 + I_d * R_i**2) / (R_i + R_d) ** 2,
    }
    zero = {k: sp.cancel(sp.expand(v)) for k, v in zero.items()}
    return QuasiLinear(K_full, sp.factor(Z_e), I_e_sym, R_e_sym, I_0_sym, R_0_sym, zero)


def _decoupler_values(m: Mount) -> dict[sp.Symbol, float]:
    return {**_physical(m), I_d: m.I_d, R_d: m.R_d}


def effective_branches(m: Mount) -> dict[str, tuple[float, float]]:
    """(I, R) of the one-branch models: ``high`` (I_e, R_e), ``low`` (I_0, R_0), ``track``
    (the decoupler ignored: I_i, R_i)."""
    q = quasi_linear_model()
    v = _decoupler_values(m)
    return {
        "high": (float(q.I_e.subs(v)), float(q.R_e.subs(v))),
        "low": (float(q.I_0.subs(v)), float(q.R_0.subs(v))),
        "track": (m.I_i, m.R_i),
    }


def full_transfer(m: Mount) -> signal.TransferFunction:
    """K(s) of the floating-decoupler linear model as a ``scipy.signal`` system."""
    num, den = sp.fraction(sp.cancel(quasi_linear_model().K_full.subs(_decoupler_values(m))))
    num = np.array([float(a) for a in sp.Poly(num, s).all_coeffs()])
    den = np.array([float(a) for a in sp.Poly(den, s).all_coeffs()])
    return signal.TransferFunction(num / den[0], den / den[0])


def integrate_full(m: Mount, times: np.ndarray, X: float = 1.0) -> np.ndarray:
    """The floating-decoupler lumped ODEs in (p_1, p_2, q_i, q_d) (the builtin
    ``mount_linear`` without harmonic input) after an ideal step, by perturb's closed-form
    linear step response; returns F_T(t).  As for the fixed decoupler, p_1 jumps by
    A_r X / C_1 at t = 0 and nothing else does."""
    system = builtin_system(
        "mount_linear",
        Xa=0.0,
        **{k: getattr(m, k) for k in ("A_r", "C1", "C2", "I_i", "R_i", "I_d", "R_d")},
    )
    r = step_response(system, times, y0=[m.A_r * X / m.C1, 0.0, 0.0, 0.0], method="closed_form")
    return m.k_r * X + m.A_r * np.array(r.state("p1"))


def quasi_study(m: Mount, n_time: int) -> dict:
    """The full floating-decoupler model against its one-branch reductions (unit step)."""
    K = full_transfer(m)
    poles = np.sort_complex(np.roots(K.den))
    slow = float(-poles[np.argmin(np.abs(poles.imag))].real)
    branches = effective_branches(m)
    I_e, R_e = branches["high"]
    times = np.linspace(0.0, 7.0 / slow, n_time)
    _, F_signal = signal.step(K, T=times)
    F_ivp = integrate_full(m, times)
    gamma = m.k_r + m.A_r**2 / (m.C1 + m.C2)
    swing = abs(F_ivp[0] - gamma)  # F(0+) - gamma: the size of the transient
    reduced, errors = {}, {}
    for key, (Ik, Rk) in branches.items():
        reduced[key] = step_closed_form(replace(m, I_i=Ik, R_i=Rk), times)[0]
        errors[key] = float(np.max(np.abs(reduced[key] - F_ivp)) / swing)
    osc = poles[np.argmax(poles.imag)]
    c_e = canonical(replace(m, I_i=I_e, R_i=R_e))
    # the slow pole's share of the response: its residue in K(s)/s over the swing
    r, p, _ = signal.residue(K.num, np.polymul(K.den, [1.0, 0.0]))
    j = int(np.argmin(np.abs(p + slow)))
    return {
        "times": times,
        "F_ivp": F_ivp,
        "F_signal": F_signal,
        "reduced": reduced,
        "errors": errors,
        "branches": branches,
        "poles": poles,
        "slow": slow,
        "slow_share": float(abs(r[j]) / swing),
        "slow_predicted": (m.R_i + m.R_d) / (m.I_i + m.I_d),
        "omega_d_full": float(osc.imag),
        "sigma_full": float(-osc.real),
        "omega_d_e": c_e["omega_d"],
        "sigma_e": c_e["sigma"],
        "zeta_e": c_e["zeta_2"],
        "swing": swing,
        "gamma": gamma,
        "signal_vs_ivp": float(np.max(np.abs(F_signal - F_ivp)) / swing),
    }


# --------------------------------------------------------------------------------------------
# 2c. the three components of the step response
# --------------------------------------------------------------------------------------------
@cache
def component_energies() -> tuple[sp.Expr, sp.Expr, sp.Expr]:
    """∫_0^∞ of e^{-2σt}cos², e^{-2σt}sin², e^{-2σt}sin·cos (SymPy), in sigma, omega_d."""
    e = sp.exp(-2 * sig * t)
    out = tuple(
        sp.simplify(sp.integrate(e * f, (t, 0, sp.oo)))
        for f in (
            sp.cos(wd * t) ** 2,
            sp.sin(wd * t) ** 2,
            sp.sin(wd * t) * sp.cos(wd * t),
        )
    )
    return out  # type: ignore[return-value]


def step_components(m: Mount, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three terms of F_T/(gamma X): 1, (u^2-1) e^{-σt} cos ω_d t and
    (u^2-1)(σ/ω_d) e^{-σt} sin ω_d t."""
    c = canonical(m)
    A, sg, w = c["u"] ** 2 - 1.0, c["sigma"], c["omega_d"]
    e = np.exp(-sg * times)
    return np.ones_like(times), A * e * np.cos(w * times), A * sg / w * e * np.sin(w * times)


def component_study(m: Mount, n_peaks: int = 6) -> dict:
    """Peak and energy shares of the three components; what dropping the sine term does to
    the extrema (the sine term is zero at t = nπ/ω_d, the true extrema)."""
    c = canonical(m)
    A, sg, w = c["u"] ** 2 - 1.0, c["sigma"], c["omega_d"]
    Ec, Es, Ecs = (
        float(v.subs({sig: sg, wd: w})) for v in component_energies()
    )  # per unit amplitude
    E_cos = A**2 * Ec
    E_sin = (A * sg / w) ** 2 * Es
    E_tr = E_cos + E_sin + 2 * A * (A * sg / w) * Ecs  # ∫ (F/γ - 1)^2
    t_star = math.atan2(w, sg) / w  # the sine term's largest value
    peak_sin = abs(A) * sg / w * math.exp(-sg * t_star) * math.sin(w * t_star)
    # dropping the sine: the two-term form's extrema, tan(ω_d t) = -σ/ω_d
    n = np.arange(1, n_peaks + 1)
    t_true = n * math.pi / w
    t_two = (n * math.pi - math.atan(sg / w)) / w
    true_over = A * np.exp(-sg * t_true) * np.cos(w * t_true)
    two_over = A * np.exp(-sg * t_two) * np.cos(w * t_two)
    return {
        "A": A,
        "zeta": c["zeta_2"],
        "peak_cos": abs(A),
        "peak_sin": peak_sin,
        "t_star": t_star,
        "peak_ratio": peak_sin / abs(A),
        "E_cos": E_cos,
        "E_sin": E_sin,
        "E_transient": E_tr,
        "energy_ratio": E_sin / E_cos,
        "energy_share": E_sin / E_tr,
        "shift": float(math.atan(sg / w) / w),
        "overshoot_error": float(np.max(np.abs(two_over / true_over - 1.0))),
        "true_over": true_over,
        "two_over": two_over,
    }


# --------------------------------------------------------------------------------------------
# 3. nonlinear mount
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MountResponse:
    """Time history of the nonlinear mount after a (ramped) step to ``x = X``.

    ``dec``: -1 plate on the top stop, +1 on the bottom stop, 0 floating, 2 fixed decoupler.
    ``events``: (time, kind), kind in vacuum-on, vacuum-off, stop-top, stop-bottom, open.
    ``extrema``, ``extrema_F``: times after the ramp where q_i + q_d = 0, i.e. where F_T and
    p_1 are stationary, and F_T there.
    """

    t: np.ndarray
    F: np.ndarray
    p1: np.ndarray
    p2: np.ndarray
    plate: np.ndarray  # plate position as a volume, in [-V_gap, V_gap]
    vacuum: np.ndarray
    dec: np.ndarray
    events: tuple[tuple[float, str], ...]
    extrema: np.ndarray
    extrema_F: np.ndarray

    def intervals(self, kind_on: str, kinds_off: Sequence[str]) -> list[tuple[float, float]]:
        """Time intervals from each ``kind_on`` event to the next event in ``kinds_off``."""
        out, start = [], None
        for te, kind in self.events:
            if kind == kind_on and start is None:
                start = te
            elif kind in kinds_off and start is not None:
                out.append((start, te))
                start = None
        if start is not None:
            out.append((start, float(self.t[-1])))
        return out


def top_pressure(m: Mount, dV1, vacuum: bool):
    """p_1 from the top chamber's compression volume dV1; PWL, continuous at the knee
    dV1 = -p_v C_1 where the compliance switches from C_1 to C_1v (vacuum)."""
    if not vacuum:
        return dV1 / m.C1
    return -m.p_vac + (dV1 + m.p_vac * m.C1) / m.C1_vac


def mount_model(m: Mount, X: float, *, free_decoupler: bool, vacuum: bool, rise: float):
    """The nonlinear mount as a perturb system (:func:`perturb.model.system_builtins.
    mount_system`) with the parameters of ``m`` and the step ``X``, and its named outputs."""
    kw = {"decoupler": "free" if free_decoupler else "fixed", "vacuum": vacuum, "rise": rise}
    base = mount_system(**kw)
    # the Mount's own fields (not its step sizes or rise time: those are arguments here)
    values = {k: getattr(m, k) for k in base.params if hasattr(m, k) and k not in ("X", "rise")}
    return base.with_params(values, X=X), dict(mount_outputs(**kw))


def simulate_mount(
    m: Mount,
    X: float,
    times: np.ndarray,
    *,
    free_decoupler: bool,
    vacuum: bool = True,
    rise: float = 0.0,
    rtol: float = 1e-10,
    max_events: int = 500,
) -> MountResponse:
    """The nonlinear mount's step response by perturb's own solvers
    (:func:`perturb.simulate.step_response.step_response`).

    The displacement ramps from 0 to ``X`` in ``rise`` seconds (an ideal step for 0; the ramp
    is two more states of the model, a clock and the displacement).  V_d is the volume passed
    through the decoupler since t = 0; the plate starts on the top stop (position -V_gap),
    where the suction after the release holds it.  The fixed-decoupler model is piecewise
    linear and runs on the exact closed-form propagation (closed form itself without vacuum
    and ramp); the free decoupler is a stop (plastic impacts: the decoupler flow stops; a
    plate that reaches a stop while the pressure pulls it back keeps floating) and runs on
    the event-driven flow (DOP853, ``rtol``).  The extrema are the zeros of the total flow
    q_i + q_d after the ramp.
    """
    knee = -m.p_vac * m.C1  # compression volume at which p_1 = -p_vac
    system, outputs = mount_model(m, X, free_decoupler=free_decoupler, vacuum=vacuum, rise=rise)
    vref = abs(m.A_r * X)
    options = {"rtol": rtol, "atol": 1e-3 * rtol * vref} if free_decoupler else {}
    if free_decoupler and m.A_r * X / m.C1 > 0:
        raise ValueError("the step must expand the top chamber (X < 0) to hold the plate up")
    r = step_response(
        system,
        times,
        method="events" if free_decoupler else "auto",
        outputs=outputs,
        crossings=["flow"],
        max_events=max_events,
        **options,
    )
    x = np.array(r.state("x")) if rise > 0 else np.full(len(times), X)
    vol = np.array(r.state("V_i")) + (np.array(r.state("V_d")) if free_decoupler else 0.0)
    dv1 = m.A_r * x - vol
    in_vacuum = (dv1 < knee) if vacuum else np.zeros(len(times), dtype=bool)
    log: list[tuple[float, str]] = [(0.0, "vacuum-on")] if vacuum and m.A_r * X < knee else []
    if rise > 0:
        log = []  # the ramp starts at x = 0, no vacuum
    dec_changes: list[tuple[float, int]] = []
    for e in r.events:
        if e.kind in ("crossing", "cross") and "clock" not in e.label:
            log.append((e.time, "vacuum-on" if e.direction > 0 else "vacuum-off"))
        elif e.kind == "lift":
            log.append((e.time, "open"))
            dec_changes.append((e.time, 0))
        elif e.kind == "rest" and e.time > 1e-9 * float(times[-1]):
            # the plate comes to rest after an impact: which stop, from the plate position
            side = 1 if float(r.trajectory(e.time)[1]) > m.V_gap else -1
            log.append((e.time, "stop-bottom" if side > 0 else "stop-top"))
            dec_changes.append((e.time, side))
    dec = np.full(len(times), -1 if free_decoupler else 2)
    for te, mode in dec_changes:
        dec[np.asarray(times) >= te] = mode
    ext = r.crossings["flow"]
    ext = ext[ext > rise + 1e-12 * float(times[-1])]
    p1 = np.array(r.outputs["p1"])
    if len(ext):
        ye = np.asarray(r.trajectory(ext)).T
        xe = ye[:, system.state_names.index("x")] if rise > 0 else X
        ve = ye[:, 0] + (ye[:, 1] if free_decoupler else 0.0)
        ext_F = m.k_r * xe + m.A_r * top_pressure_pwl(m, m.A_r * xe - ve, vacuum)
    else:
        ext_F = np.empty(0)
    return MountResponse(
        t=np.array(r.times),
        F=m.k_r * x + m.A_r * p1,
        p1=p1,
        p2=np.array(r.outputs["p2"]),
        plate=np.array(r.outputs["plate"]) if free_decoupler else np.zeros(len(times)),
        vacuum=in_vacuum,
        dec=dec,
        events=tuple(log),
        extrema=np.asarray(ext, dtype=float),
        extrema_F=np.asarray(ext_F, dtype=float),
    )


def top_pressure_pwl(m: Mount, dV1, vacuum: bool):
    """p_1 of the compression volume dV1 on either side of the vacuum knee."""
    knee = -m.p_vac * m.C1
    dV1 = np.asarray(dV1, dtype=float)
    if not vacuum:
        return dV1 / m.C1
    return np.where(dV1 < knee, top_pressure(m, dV1, True), top_pressure(m, dV1, False))


def vacuum_oscillator(m: Mount, X: float) -> Oscillator:
    r"""The fixed-decoupler vacuum mount as one perturb oscillator in y = V_i/(A_r |X|).

    With q_d = 0 the track volume obeys I_i V'' + R_i V' + V/C_2 = p_1(A_r X - V); dividing by
    I_i A_r|X| gives y'' + c y' + w_2 y + w_1 (y - e) - d (y - y_k) H(y - y_k) = 0, e = sign X,
    where y > y_k is the vacuum stage (the top chamber expanded past p_1 = -p_v).
    """
    vref = abs(m.A_r * X)
    params = {
        "c": m.R_i / m.I_i,
        "w_2": 1.0 / (m.I_i * m.C2),
        "w_1": 1.0 / (m.I_i * m.C1),
        "d": (1.0 / m.C1 - 1.0 / m.C1_vac) / m.I_i,
        "e": math.copysign(1.0, X),
        "y_k": math.copysign(1.0, X) + m.p_vac * m.C1 / vref,
    }
    return Oscillator.parse(
        "y'' + c*y' + w_2*y + w_1*(y - e) - d*(y - y_k)*Heaviside(y - y_k) = 0",
        params,
        name="mount-vacuum",
    )


def simulate_vacuum_event_driven(m: Mount, X: float, times: np.ndarray):
    """F_T, p_1 and the event log of the fixed-decoupler vacuum mount after an ideal step,
    from perturb's event-driven integrator."""
    traj = event_driven_simulate(
        vacuum_oscillator(m, X), [0.0, 0.0], (0.0, float(times[-1])), t_eval=times
    )
    dV1 = m.A_r * X - abs(m.A_r * X) * np.asarray(traj.x)
    p1 = np.where(dV1 < -m.p_vac * m.C1, top_pressure(m, dV1, True), top_pressure(m, dV1, False))
    return m.k_r * X + m.A_r * p1, p1, traj.events


def open_decoupler_modes(m: Mount) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues of the linear mount with the plate floating (no vacuum, no stops), and
    how much each mode moves the chamber pressures (|V_i + V_d| part of its unit eigenvector).

    p_1 and p_2 (hence F_T) depend on V_i + V_d only; the circulation between the track and
    the decoupler (V_i = -V_d) does not load the chambers.
    """
    a, b = 1.0 / m.C1, 1.0 / m.C2
    J = np.array(
        [
            [0, 1, 0, 0],
            [-(a + b) / m.I_i, -m.R_i / m.I_i, -(a + b) / m.I_i, 0],
            [0, 0, 0, 1],
            [-(a + b) / m.I_d, 0, -(a + b) / m.I_d, -m.R_d / m.I_d],
        ]
    )
    lam, vec = np.linalg.eig(J)
    vec = vec / np.linalg.norm(vec[[0, 2]], axis=0)
    return lam, np.abs(vec[0] + vec[2])


def open_decoupler_rates(m: Mount) -> np.ndarray:
    """Distinct decay rates (-Re lambda) of the open-decoupler modes that load the chambers,
    ascending."""
    lam, load = open_decoupler_modes(m)
    return np.unique(np.round(-lam[load > 1e-6].real, 12))


def decay_rate(times: np.ndarray, deviation: np.ndarray) -> float:
    """Rate of |deviation| at successive extrema (least-squares fit of its logarithm)."""
    return float(-np.polyfit(times, np.log(np.abs(deviation)), 1)[0])


# --------------------------------------------------------------------------------------------
# 4. the study: numbers, figures, CSV, LaTeX
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Check:
    """One measured claim: ``value`` against ``expected`` within ``tol`` (absolute)."""

    name: str
    tex: str
    value: float
    expected: float
    tol: float

    @property
    def ok(self) -> bool:
        return abs(self.value - self.expected) <= self.tol


@dataclass
class Results:
    mount: Mount
    canon: dict[str, float]
    times: np.ndarray
    closed: tuple[np.ndarray, np.ndarray]
    scipy_: tuple[np.ndarray, np.ndarray]
    lumped: LumpedRun
    checks: list[Check] = field(default_factory=list)
    peaks: list[tuple[int, float, float]] = field(default_factory=list)
    settle: list[dict[str, float]] = field(default_factory=list)
    nonlinear: dict = field(default_factory=dict)
    quasi: dict = field(default_factory=dict)
    components: dict = field(default_factory=dict)


def _maxrel(a: np.ndarray, b: np.ndarray, scale: float) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / abs(scale))


def linear_study(m: Mount, n_time: int) -> Results:
    """Closed form vs scipy.signal vs perturb's step response, peak times, envelope, settling
    (unit step)."""
    c = canonical(m)
    times = np.linspace(0.0, 7.0 / c["sigma"], n_time)
    closed = step_closed_form(m, times)
    sci = step_scipy(m, times)
    lumped = integrate_lumped(m, times)
    res = Results(m, c, times, closed, sci, lumped)
    g, lmb, rate = c["gamma"], c["lambda"], m.R_i / (2 * m.I_i)
    K, _ = transfer_functions(m)
    ext = lumped.extrema
    pred = peak_times(m, len(ext))
    res.peaks = [(n, float(a), float(b)) for n, (a, b) in enumerate(zip(pred, ext, strict=True), 1)]
    envelope = np.abs(closed[0] - g) / (g * c["sqrtR_F"] * np.exp(-c["sigma"] * times))
    res.checks = [
        Check(
            "closed form vs scipy.signal, F",
            r"$\max|F-F_{\mathrm{signal}}|/\gamma$",
            _maxrel(closed[0], sci[0], g),
            0.0,
            1e-8,
        ),
        Check(
            "closed form vs scipy.signal, p",
            r"$\max|p_1-p_{\mathrm{signal}}|/\lambda$",
            _maxrel(closed[1], sci[1], lmb),
            0.0,
            1e-8,
        ),
        Check(
            "closed form vs perturb step response, F",
            r"$\max|F-F_{\mathrm{perturb}}|/\gamma$",
            _maxrel(closed[0], lumped.F, g),
            0.0,
            1e-8,
        ),
        Check(
            "closed form vs perturb step response, p",
            r"$\max|p_1-p_{\mathrm{perturb}}|/\lambda$",
            _maxrel(closed[1], lumped.p1, lmb),
            0.0,
            1e-8,
        ),
        Check(
            "peak times",
            r"$\max_n \omega_d\,|t_{\mathrm{perturb}}(n) - n\pi/\omega_d|$",
            float(np.max(np.abs(ext - pred)) * c["omega_d"]),
            0.0,
            1e-8,
        ),
        Check(
            "F(0+)",
            r"$F(0^+)/(k_r + A_r^2/C_1)$",
            float(closed[0][0] / (m.k_r + m.A_r**2 / m.C1)),
            1.0,
            1e-12,
        ),
        Check("p(0+)", r"$p_1(0^+)/(A_r/C_1)$", float(closed[1][0] / (m.A_r / m.C1)), 1.0, 1e-12),
        Check(
            "zeta_1 omega_1",
            r"$\zeta_1\omega_1/(R_i/2I_i)$",
            c["zeta_1"] * c["omega_1"] / rate,
            1.0,
            1e-12,
        ),
        Check(
            "zeta_2 omega_2",
            r"$\zeta_2\omega_2/(R_i/2I_i)$",
            c["zeta_2"] * c["omega_2"] / rate,
            1.0,
            1e-12,
        ),
        Check("xi varpi", r"$\xi\varpi/(R_i/2I_i)$", c["xi"] * c["varpi"] / rate, 1.0, 1e-12),
        Check(
            "poles of K_1",
            r"$-\mathrm{Re}\,s_{\mathrm{pole}}/(R_i/2I_i)$ (numpy roots)",
            float(-np.roots(K.den)[0].real / rate),
            1.0,
            1e-9,
        ),
        Check(
            "u v = 1",
            r"$uv$, $u=\omega_2/\omega_1$, $v=\zeta_2/\zeta_1$",
            c["u"] * c["v"],
            1.0,
            1e-12,
        ),
        Check(
            "envelope touches",
            r"$\max_t |F-\gamma| / (\gamma\sqrt{R}e^{-\sigma t})$",
            float(envelope.max()),
            1.0,
            1e-4,
        ),
    ]
    res.settle = [settling(m, eps) for eps in EPSILONS]
    return res


def quasi_checks(m: Mount, res: Results, n_time: int) -> None:
    """The quasi-linear model (floating decoupler) and the three step components, measured."""
    q = res.quasi = quasi_study(m, n_time)
    cs = res.components = component_study(m)
    res.checks += [
        Check(
            "floating decoupler: scipy.signal vs perturb step response",
            r"$\max|F_{\mathrm{signal}}-F_{\mathrm{perturb}}|/|F(0^+)-\gamma|$, floating "
            "decoupler",
            q["signal_vs_ivp"],
            0.0,
            1e-8,
        ),
        Check(
            "quasi-linear (I_e, R_e) vs full floating-decoupler model",
            r"$\max|F_{I_e,R_e}-F_{\mathrm{perturb}}|/|F(0^+)-\gamma|$ (quasi-linear model)",
            q["errors"]["high"],
            0.0,
            0.01,
        ),
        Check(
            "slow pole = (R_i+R_d)/(I_i+I_d)",
            r"slow pole of $K(s)$ over $(R_i+R_d)/(I_i+I_d)$",
            q["slow"] / q["slow_predicted"],
            1.0,
            0.01,
        ),
        Check(
            "sine component: energy ratio = zeta^2/(1+zeta^2)",
            r"$E_{\sin}/E_{\cos}$ over $\zeta_2^2/(1+\zeta_2^2)$",
            cs["energy_ratio"] / (cs["zeta"] ** 2 / (1.0 + cs["zeta"] ** 2)),
            1.0,
            1e-12,
        ),
    ]


def _lag(extrema: np.ndarray, omega_d: float) -> np.ndarray:
    """Each extremum's offset from the nearest n pi/omega_d."""
    n = np.round(extrema * omega_d / math.pi)
    return extrema - n * math.pi / omega_d


def nonlinear_study(m: Mount, res: Results, n_time: int, rtol: float) -> None:
    """The two nonlinear cases, their linear counterparts, cross-checks and measurements."""
    c = res.canon
    times = np.linspace(0.0, 7.0 / c["sigma"], n_time)
    out: dict = {"times": times, "cases": {}}
    for key, X, free in (("fixed", m.X_fixed, False), ("free", m.X_free, True)):
        nl = simulate_mount(m, X, times, free_decoupler=free, rise=m.rise, rtol=rtol)
        ramp = simulate_mount(
            m, X, times, free_decoupler=False, vacuum=False, rise=m.rise, rtol=rtol
        )
        ideal = step_closed_form(m, times, X)
        final = c["gamma"] * X
        ext, dev = nl.extrema, nl.extrema_F - final
        if free:
            since = max(te for te, kind in nl.events if kind != "open")
            tail_from = [te for te, kind in nl.events if kind == "open"][-1]
        else:
            since = tail_from = max(te for te, _ in nl.events)
        tail = (ext > tail_from) & (np.abs(dev) > 1e-7 * abs(final))
        out["cases"][key] = {
            "X": X,
            "nonlinear": nl,
            "ramp": ramp,
            "ideal": ideal,
            "F_peak_ideal": float(ideal[0][0]),
            "F_peak_ramp": float(ramp.F[np.argmax(np.abs(ramp.F))]),
            "F_peak": float(nl.F[np.argmax(np.abs(nl.F))]),
            "p_min_ideal": float(ideal[1].min()),
            "p_min_ramp": float(ramp.p1.min()),
            "p_min": float(nl.p1.min()),
            "vacuum": nl.intervals("vacuum-on", ("vacuum-off",)),
            "last_mode_change": since,
            "lag_ramp": float(np.mean(_lag(ramp.extrema, c["omega_d"]))),
            "lag_after": math.nan if free else float(np.mean(_lag(ext[ext > since], c["omega_d"]))),
            "spacing_after": math.nan if free else float(np.mean(np.diff(ext[ext > since]))),
            "tail_from": float(tail_from),
            "tail_rate": decay_rate(ext[tail], dev[tail]),
            "n_tail": int(np.count_nonzero(tail)),
            "settle": _settling_time(nl.t, nl.F, final, 0.02),
            "settle_ramp": _settling_time(ramp.t, ramp.F, final, 0.02),
            "settle_ideal": _settling_time(times, ideal[0], final, 0.02),
            "final": float(nl.F[-1]),
            "final_linear": final,
        }
    free_case = out["cases"]["free"]
    free_case["floating"] = free_case["nonlinear"].intervals("open", ("stop-top", "stop-bottom"))
    lo, hi = open_decoupler_rates(m)[[0, -1]]
    free_case["open_rates"] = (float(lo), float(hi))
    res.checks.append(
        Check(
            "vacuum model: tail decay rate = sigma",
            r"fixed decoupler, after the last vacuum: fitted decay rate$/\sigma$",
            out["cases"]["fixed"]["tail_rate"] / c["sigma"],
            1.0,
            1e-3,
        )
    )
    res.checks.append(
        Check(
            "free decoupler: tail rate within the open-decoupler rates",
            r"free decoupler, plate floating: fitted rate in "
            f"[{lo:.4g}, {hi:.4g}]" + r"\,s$^{-1}$ (eigenvalues)",
            free_case["tail_rate"],
            0.5 * (lo + hi),
            0.5 * (hi - lo),
        )
    )
    # the same fixed-decoupler vacuum model, ideal step, on perturb's event-driven integrators
    ivp = simulate_mount(m, m.X_fixed, times, free_decoupler=False, rtol=rtol)
    nd = step_response(
        mount_model(m, m.X_fixed, free_decoupler=False, vacuum=True, rise=0.0)[0],
        times,
        method="events",
        outputs={"p1": mount_outputs(decoupler="fixed")["p1"]},
        rtol=rtol,
        atol=1e-3 * rtol * abs(m.A_r * m.X_fixed),
    )
    F_ed, p_ed, ev_ed = simulate_vacuum_event_driven(m, m.X_fixed, times)
    switch_ivp = [te for te, _ in ivp.events if te > 0]
    switch_ed = [e.time for e in ev_ed]
    out["event_driven"] = {"ivp": ivp, "F": F_ed, "p1": p_ed, "events": ev_ed}
    scale = (m.k_r + m.A_r**2 / m.C1) * abs(m.X_fixed)
    res.checks.append(
        Check(
            "vacuum model: exact PWL vs SDOF event-driven, F",
            r"vacuum, fixed decoupler: $\max|F_{\mathrm{exact}}-F_{\mathrm{SDOF\,events}}|/F(0^+)$",
            _maxrel(ivp.F, F_ed, scale),
            0.0,
            1e-7,
        )
    )
    res.checks.append(
        Check(
            "vacuum model: exact PWL vs n-state event-driven, F",
            r"vacuum, fixed decoupler: $\max|F_{\mathrm{exact}}-F_{\mathrm{events}}|/F(0^+)$",
            _maxrel(ivp.p1, nd.outputs["p1"], scale / m.A_r),
            0.0,
            1e-7,
        )
    )
    res.checks.append(
        Check(
            "vacuum model: switching times",
            r"vacuum knee crossings: "
            r"$\max|t_{\mathrm{exact}}-t_{\mathrm{SDOF\,events}}|\,\omega_d$",
            float(np.max(np.abs(np.subtract(switch_ivp, switch_ed)))) * c["omega_d"]
            if len(switch_ivp) == len(switch_ed)
            else math.inf,
            0.0,
            1e-7,
        )
    )
    lin = simulate_mount(m, m.X_fixed, times, free_decoupler=False, vacuum=False, rtol=rtol)
    res.checks.append(
        Check(
            "nonlinear code, linear limit",
            r"no vacuum, fixed decoupler: $\max|F-F_{\mathrm{closed}}|/|\gamma X|$",
            _maxrel(lin.F, step_closed_form(m, times, m.X_fixed)[0], c["gamma"] * m.X_fixed),
            0.0,
            1e-7,
        )
    )
    res.nonlinear = out


def _settling_time(times, F, final, eps) -> float:
    """First sample time after which |F - final| <= eps |final| (nan if never)."""
    out = np.nonzero(np.abs(F - final) > eps * abs(final))[0]
    if not len(out):
        return float(times[0])
    return float(times[out[-1] + 1]) if out[-1] + 1 < len(times) else math.nan


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_linear(res: Results, path: Path) -> None:
    """Closed form vs scipy.signal vs perturb's step response, envelope and peak times;
    errors below."""
    plt = _pyplot()
    m, c, tt = res.mount, res.canon, res.times
    X = m.X_fixed
    every = max(1, len(tt) // 60)
    fig, axes = plt.subplots(3, 1, figsize=(7.2, 8.2), dpi=130, sharex=True)
    for ax, k, gain, scale, unit, R in (
        (axes[0], 0, c["gamma"], 1e-3, "kN", c["sqrtR_F"]),
        (axes[1], 1, c["lambda"], 1e-3, "kPa", c["sqrtR_p"]),
    ):
        final = gain * X * scale
        env = gain * X * scale * R * np.exp(-c["sigma"] * tt)
        ax.plot(tt, res.closed[k] * X * scale, "-", lw=1.2, label="closed form")
        ax.plot(
            tt[::every],
            res.scipy_[k][::every] * X * scale,
            "o",
            ms=3,
            mfc="none",
            label="scipy.signal.step",
        )
        half = slice(every // 2, None, every)  # between the circles, so both stay visible
        ivp = res.lumped.F if k == 0 else res.lumped.p1
        ax.plot(
            tt[half], ivp[half] * X * scale, "x", ms=3, label="perturb step response (lumped ODEs)"
        )
        ax.plot(tt, final + env, "--", color="0.4", lw=0.8, label="decay envelope")
        ax.plot(tt, final - env, "--", color="0.4", lw=0.8)
        for tp in peak_times(m, int(tt[-1] * c["omega_d"] / math.pi)):
            ax.axvline(tp, color="C3", lw=0.4, alpha=0.5)
        ax.set_ylabel(("$F_T$" if k == 0 else "$p_1$") + f" [{unit}]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="lower right")
    err = [
        (np.abs(res.closed[0] - res.scipy_[0]) / c["gamma"], r"$|F-F_{\rm signal}|/\gamma$"),
        (np.abs(res.closed[0] - res.lumped.F) / c["gamma"], r"$|F-F_{\rm perturb}|/\gamma$"),
        (np.abs(res.closed[1] - res.lumped.p1) / c["lambda"], r"$|p_1-p_{\rm perturb}|/\lambda$"),
    ]
    for e, label in err:
        axes[2].semilogy(tt[1:], np.maximum(e[1:], 1e-18), lw=0.7, label=label)
    axes[2].set_ylabel("difference")
    axes[2].set_xlabel("time t [s]")
    axes[2].legend(fontsize=7, ncol=3)
    axes[2].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def figure_quasi(res: Results, path: Path) -> None:
    """Top: floating-decoupler model against its one-branch reductions.  Bottom: the three
    components of the fixed-decoupler step response."""
    plt = _pyplot()
    q, m, c = res.quasi, res.mount, res.canon
    fig, axes = plt.subplots(2, 1, figsize=(7.2, 6.4), dpi=130)
    ax = axes[0]
    tt = q["times"]
    short = tt <= 8.0 / q["sigma_e"]
    g = q["gamma"]
    ax.plot(tt[short] * 1e3, q["F_ivp"][short] / g, "k-", lw=1.6, label="full model (perturb)")
    styles = {
        "high": ("C0", "--", r"one branch $I_e s+R_e$ (large $s$)"),
        "low": ("C1", ":", r"one branch $I_0 s+R_0$ (small $s$)"),
        "track": ("C2", "-.", "decoupler ignored ($I_i$, $R_i$)"),
    }
    for key, (col, ls, label) in styles.items():
        err = 100 * q["errors"][key]
        ax.plot(
            tt[short] * 1e3, q["reduced"][key][short] / g, ls, color=col, lw=1.1,
            label=f"{label}: max error {err:.3g} %",
        )  # fmt: skip
    ax.set_ylabel(r"$F_T/(\gamma X)$")
    ax.set_xlabel("time t [ms]")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    ax = axes[1]
    tc = np.linspace(0.0, 4.0 / c["sigma"], 1500)
    _, cos_t, sin_t = step_components(m, tc)
    ax.plot(tc * 1e3, cos_t, "C0-", lw=1.1, label=r"$(u^2-1)e^{-\sigma t}\cos\omega_d t$")
    ax.plot(
        tc * 1e3, sin_t, "C3-", lw=1.1,
        label=r"$(u^2-1)(\sigma/\omega_d)e^{-\sigma t}\sin\omega_d t$",
    )  # fmt: skip
    ax.axhline(1.0, color="k", lw=0.8, label="1 (static part)")
    for tp in peak_times(m, int(tc[-1] * c["omega_d"] / math.pi)):
        ax.axvline(tp * 1e3, color="0.6", lw=0.4)
    ax.set_ylabel(r"component of $F_T/(\gamma X)$")
    ax.set_xlabel(r"time t [ms] (grey: $t_p=n\pi/\omega_d$)")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def figure_nonlinear(res: Results, path: Path) -> None:
    """Nonlinear vs linear step responses, fixed (left) and free (right) decoupler."""
    plt = _pyplot()
    m, c = res.mount, res.canon
    nl = res.nonlinear
    tt = nl["times"]
    fig, axes = plt.subplots(3, 2, figsize=(10.5, 8.0), dpi=130, sharex=True)
    for col, key in enumerate(("fixed", "free")):
        case = nl["cases"][key]
        r: MountResponse = case["nonlinear"]
        ramp: MountResponse = case["ramp"]
        X = case["X"]
        lin_F, lin_p = case["ideal"]
        for row, (nl_y, ramp_y, ideal_y, gain, R, scale, label) in enumerate(
            (
                (r.F, ramp.F, lin_F, c["gamma"], c["sqrtR_F"], 1e-3, "$F_T$ [kN]"),
                (r.p1, ramp.p1, lin_p, c["lambda"], c["sqrtR_p"], 1e-3, "$p_1$ [kPa]"),
            )
        ):
            ax = axes[row, col]
            ax.plot(tt, ideal_y * scale, "-", color="C0", lw=0.8, label="linear, ideal step")
            ax.plot(tt, ramp_y * scale, "--", color="C2", lw=0.9, label="linear, ramped step")
            ax.plot(r.t, nl_y * scale, "-", color="k", lw=1.3, label="nonlinear model")
            env = gain * X * R * np.exp(-c["sigma"] * tt) * scale
            ax.plot(tt, gain * X * scale + env, ":", color="0.4", lw=0.8, label="decay envelope")
            ax.plot(tt, gain * X * scale - env, ":", color="0.4", lw=0.8)
            ax.set_ylabel(label)
        ax = axes[2, col]
        if key == "fixed":
            ax.plot(r.t, (r.F - ramp.F) * 1e-3, "-", color="k", lw=1.0)
            ax.set_ylabel("$F_T$ nonlinear $-$ linear [kN]")
        else:
            ax.plot(r.t, r.plate / m.V_gap, "-", color="C4", lw=1.0)
            ax.set_ylabel("plate position / gap")
            ax.set_ylim(-1.2, 1.2)
        ax.set_xlabel("time t [s]")
        for ax in axes[:, col]:
            for a, b in case["vacuum"]:
                ax.axvspan(a, b, color="0.6", alpha=0.35, lw=0)
            for a, b in case.get("floating", []):
                ax.axvspan(a, b, color="C9", alpha=0.15, lw=0)
            for tp in peak_times(m, int(tt[-1] * c["omega_d"] / math.pi)):
                ax.axvline(tp, color="C3", lw=0.4, alpha=0.4)
            ax.grid(alpha=0.3)
        axes[1, col].set_ylim(-1.15 * m.p_vac * 1e-3 * 2.2, 1.15 * m.p_vac * 1e-3 * 2.2)
        title = (
            f"fixed decoupler, X = {X * 1e3:.1f} mm (vacuum: grey)"
            if key == "fixed"
            else f"free decoupler, X = {X * 1e3:.1f} mm (vacuum: grey, plate floating: blue)"
        )
        axes[0, col].set_title(title, fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="lower right")
    axes[0, 0].set_xlim(0.0, tt[-1] * 0.6)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# CSV and LaTeX
# --------------------------------------------------------------------------------------------
def write_csv(st: Study, red: Reduction, res: Results) -> None:
    m, c = res.mount, res.canon
    st.write_csv(
        "parameters.csv",
        ["name", "value", "unit", "meaning"],
        [
            (k, float(v), PARAM_TEX[k][1].replace("$", ""), PARAM_TEX[k][2])
            for k, v in m.values().items()
        ],
    )
    st.write_csv("canonical.csv", ["name", "value"], [(k, float(v)) for k, v in c.items()])
    st.write_csv(
        "symbolic_identities.csv",
        ["identity", "residual after cancel/expand"],
        [(k, str(v)) for k, v in red.zero.items()],
    )
    tt = res.times
    st.write_csv(
        "linear_step.csv",
        [
            "t_s",
            "F_closed/gamma",
            "F_signal/gamma",
            "F_perturb/gamma",
            "p_closed/lambda",
            "p_signal/lambda",
            "p_perturb/lambda",
        ],
        zip(
            *(
                np.asarray(a, dtype=float).tolist()
                for a in (
                    tt,
                    res.closed[0] / c["gamma"],
                    res.scipy_[0] / c["gamma"],
                    res.lumped.F / c["gamma"],
                    res.closed[1] / c["lambda"],
                    res.scipy_[1] / c["lambda"],
                    res.lumped.p1 / c["lambda"],
                )
            ),
            strict=True,
        ),
    )
    st.write_csv(
        "peaks.csv",
        ["n", "t_pred_n_pi_over_omega_d", "t_perturb_q_i_zero", "difference"],
        [(n, a, b, b - a) for n, a, b in res.peaks],
    )
    st.write_csv(
        "settling.csv",
        ["eps", "estimate_ln(sqrtR/eps)/sigma", "crude_ln(1/eps)/sigma", "exact", "error_at_crude"],
        [
            tuple(float(d[k]) for k in ("eps", "estimate", "crude", "exact", "error_at_crude"))
            for d in res.settle
        ],
    )
    st.write_csv(
        "checks.csv",
        ["claim", "measured", "expected", "tolerance", "ok"],
        [(ch.name, ch.value, ch.expected, ch.tol, ch.ok) for ch in res.checks],
    )
    q, cs = res.quasi, res.components
    st.write_csv(
        "quasi_linear.csv",
        ["t_s", "F_full_perturb/gamma", "F_full_signal/gamma"]
        + [f"F_{k}/gamma" for k in q["reduced"]],
        zip(
            *(
                np.asarray(a, dtype=float).tolist()
                for a in [q["times"], q["F_ivp"] / q["gamma"], q["F_signal"] / q["gamma"]]
                + [v / q["gamma"] for v in q["reduced"].values()]
            ),
            strict=True,
        ),
    )
    st.write_csv(
        "quasi_linear_branches.csv",
        ["model", "inertance_kg_m4", "resistance_N_s_m5", "max_error_over_swing"],
        [(k, float(i), float(r), q["errors"][k]) for k, (i, r) in q["branches"].items()],
    )
    st.write_csv(
        "step_components.csv",
        ["quantity", "value"],
        [(k, float(v)) for k, v in cs.items() if np.ndim(v) == 0],
    )
    nl = res.nonlinear
    cols, header = [nl["times"]], ["t_s"]
    for key in ("fixed", "free"):
        case = nl["cases"][key]
        r, ramp = case["nonlinear"], case["ramp"]
        cols += [
            r.F,
            ramp.F,
            case["ideal"][0],
            r.p1,
            ramp.p1,
            case["ideal"][1],
            r.vacuum.astype(int),
            r.dec,
            r.plate / m.V_gap,
        ]
        header += [
            f"{key}_{q}"
            for q in (
                "F_nonlinear",
                "F_linear_ramp",
                "F_linear_ideal",
                "p1_nonlinear",
                "p1_linear_ramp",
                "p1_linear_ideal",
                "vacuum",
                "decoupler_mode",
                "plate_over_gap",
            )
        ]
    rows = zip(*(np.asarray(a).tolist() for a in cols), strict=True)
    st.write_csv("nonlinear_step.csv", header, rows)
    st.write_csv(
        "nonlinear_events.csv",
        ["case", "t_s", "event"],
        [
            (key, te, kind)
            for key in ("fixed", "free")
            for te, kind in nl["cases"][key]["nonlinear"].events
        ],
    )


def _num(x: float, digits: int = 4) -> str:
    """A number for LaTeX math: 1.234\\times10^{-5}."""
    if x == 0 or not math.isfinite(x):
        return "0" if x == 0 else r"\mathrm{n/a}"
    mant, exp = f"{x:.{digits - 1}e}".split("e")
    exp = int(exp)
    if -2 <= exp <= 4:
        return f"{x:.{max(digits - 1 - exp, 0)}f}" if exp < digits else f"{x:.0f}"
    return rf"{mant}\times10^{{{exp}}}"


def _eq(lhs: str, expr: sp.Expr) -> str:
    return f"{lhs} &= {latex(expr)}"


def _components_tex(res: Results) -> str:
    """The three step-response components and which one is negligible, in numbers."""
    cs = res.components
    E = component_energies()
    ratio = cs["energy_ratio"]
    verdict = (
        "negligible in energy" if cs["energy_share"] < 0.02 else "not negligible in energy either"
    )
    n_over = len(cs["true_over"])
    return rf"""\subsection{{The three components of the step response}}
The closed form has three terms, $F_T/(\gamma X) = 1 + (u^2-1)e^{{-\sigma t}}\cos\omega_d t
+ (u^2-1)(\sigma/\omega_d)e^{{-\sigma t}}\sin\omega_d t$: the static part, a decaying cosine
and a decaying sine. The paper keeps the first two and calls one component negligible; the
seed's words are lost with its equations, and the only candidate is the sine term, whose
amplitude is $\zeta_2/\sqrt{{1-\zeta_2^2}}$ times the cosine's. (Of the three force paths
$k_rx + b_r\dot x + A_rp_1$, the damping path is an impulse at $t=0$ for an ideal step and
absent from $K_1$, since $b_r=0$ here.) With $\zeta_2={_num(cs["zeta"])}$:
\begin{{itemize}}
\item \emph{{peak}}: the sine term is largest at $t^*=\operatorname{{atan2}}(\omega_d,\sigma)
/\omega_d={_num(cs["t_star"] * 1e3)}$\,ms, where it is $|u^2-1|\zeta_2e^{{-\sigma t^*}}=
{_num(cs["peak_sin"])}$, i.e.\ ${_num(100 * cs["peak_ratio"], 3)}$\,\% of the cosine term's
peak $|u^2-1|={_num(cs["peak_cos"])}$ (at $t=0$) and ${_num(100 * cs["peak_sin"], 3)}$\,\% of
the static part;
\item \emph{{energy}}: with SymPy's $\int_0^\infty e^{{-2\sigma t}}\cos^2\omega_d t\,dt =
{latex(E[0])}$ and $\int_0^\infty e^{{-2\sigma t}}\sin^2\omega_d t\,dt = {latex(E[1])}$,
$E_{{\sin}}/E_{{\cos}} = \zeta_2^2/(1+\zeta_2^2) = {_num(100 * ratio, 3)}$\,\%, and the sine
term carries ${_num(100 * cs["energy_share"], 3)}$\,\% of $\int_0^\infty(F_T/\gamma X-1)^2dt$;
\item \emph{{extrema}}: the sine term vanishes at $t_p=n\pi/\omega_d$, the extrema of the full
response, so the peak \emph{{times and values}} of the closed form do not depend on it. Dropping
it moves the extrema of the two-term form earlier by $\operatorname{{atan}}(\sigma/\omega_d)
/\omega_d={_num(cs["shift"] * 1e3)}$\,ms and changes the first {n_over} overshoots
$F_T/(\gamma X)-1$ by at most ${_num(100 * cs["overshoot_error"], 3)}$\,\% of themselves.
\end{{itemize}}
So the sine component is {verdict} (about $\zeta_2^2$), below ten per cent of the transient at
its largest (about $\zeta_2$), and exactly zero where the response peaks; ``negligible''
holds for a lightly damped track ($\zeta_2\ll1$) and grows with $\zeta_2$.
Tested in \texttt{{tests/test\_derivations\_mount.py}} against quadrature and a dense time
grid."""


def _quasi_tex(st: Study, res: Results) -> str:
    """The quasi-linear model of the floating decoupler (He & Singh eqs. 14-16), in numbers."""
    q, m = res.quasi, res.mount
    ql = quasi_linear_model()
    n_zero = sum(v == 0 for v in ql.zero.values())
    ids = ", ".join(f"${QUASI_TEX[k]}$" for k, v in ql.zero.items() if v == 0)
    best = min(q["errors"], key=q["errors"].get)
    names = {"high": "large-$s$", "low": "small-$s$", "track": "decoupler-free"}
    I_e, R_e = q["branches"]["high"]
    I_0, R_0 = q["branches"]["low"]
    poles = ", ".join(f"${_num(p.real)}{'+' if p.imag >= 0 else '-'}{_num(abs(p.imag))}i$"
                      for p in q["poles"] if p.imag > 0)  # fmt: skip
    fig = st.tex_path("quasi_linear.png")
    err = {k: _num(100 * v, 3) for k, v in q["errors"].items()}
    return rf"""\subsection{{Quasi-linear model: track and floating decoupler as one branch}}
\label{{sec:mount-quasi}}
The paper's eqs.~14--16 (lost from the seed text) build a simplified linear model of the
free-decoupler mount with an effective inertia and damping. We reconstruct it from the lumped
equations with the plate floating (no stop): $A_r\dot x - q_i - q_d = C_1\dot p_1$,
$q_i + q_d = C_2\dot p_2$, $p_1-p_2 = I_d\dot q_d + R_dq_d = I_i\dot q_i + R_iq_i$. SymPy
solves them for $K(s)=F_T/X$ (cubic over cubic in $s$) and shows that the two branches act as
one of impedance
\[
Z_e(s) = \frac{{(I_is+R_i)(I_ds+R_d)}}{{(I_i+I_d)s + R_i+R_d}},\qquad
\frac1{{Z_e}}=\frac1{{I_is+R_i}}+\frac1{{I_ds+R_d}},
\]
which is not of the form $Is+R$. \emph{{Assumption}} (the exact form of eqs.~14--16 is
lost): the quasi-linear model is $K_1(s)$ of the fixed-decoupler mount with $I_is+R_i$ replaced
by an asymptote of $Z_e$: for large $s$ (polynomial division) $Z_e = I_es+R_e+O(1/s)$, for small
$s$ (Taylor) $Z_e = R_0 + I_0s + O(s^2)$, with
\[
I_e = {latex(ql.I_e)},\quad R_e = {latex(ql.R_e)},\qquad
I_0 = {latex(ql.I_0)},\quad R_0 = {latex(ql.R_0)}.
\]
For large $s$ the inertances combine as parallel elements do (the light plate dominates,
$I_e\approx I_d$); for small $s$ the resistances do. {n_zero} of {len(ql.zero)} identities
reduce to exactly 0: {ids}. All closed forms of the fixed-decoupler mount then hold with
$(I_e, R_e)$, e.g.\ $\omega_2^2=(C_1+C_2)/(I_eC_1C_2)$ and $\sigma=R_e/(2I_e)$.

With Table~\ref{{tab:mount-params}}: $I_e={_num(I_e)}$\,kg/m$^4$ (${_num(I_e / m.I_d)}I_d$),
$R_e={_num(R_e)}$\,N\,s/m$^5$ (${_num(R_e / m.R_d)}R_d$); $I_0={_num(I_0)}$, $R_0={_num(R_0)}$.
The full model's poles are {poles} (and conjugate) and $-{_num(q["slow"])}$\,s$^{{-1}}$; the
quasi-linear model
has $-\sigma\pm i\omega_d = -{_num(q["sigma_e"])}\pm{_num(q["omega_d_e"])}i$
($\zeta={_num(q["zeta_e"])}$), and drops the real pole, which sits at
$(R_i+R_d)/(I_i+I_d)={_num(q["slow_predicted"])}$\,s$^{{-1}}$ (the pole of $Z_e$: flow
redistributing between track and plate) and carries a residue of
${_num(100 * q["slow_share"], 3)}$\,\% of the transient $|F(0^+)-\gamma|$.
Against perturb's closed-form step response of the four lumped ODEs
(\texttt{{perturb.simulate.step\_response}}, the eigen-decomposition of their balanced matrix;
\texttt{{scipy.signal.step}} of $K(s)$ agrees with it to ${_num(q["signal_vs_ivp"], 2)}$), the
largest step-response error over $[0, 7/{_num(q["slow"])}\,\mathrm{{s}}^{{-1}}]$, relative to
$|F(0^+)-\gamma|$, is {err["high"]}\,\% for $(I_e,R_e)$, {err["low"]}\,\% for
$(I_0,R_0)$ and {err["track"]}\,\% with the decoupler ignored (Fig.~\ref{{fig:mount-quasi}}):
the {names[best]} reduction is the quasi-linear model of a floating-decoupler step response,
since the transient lives near $\omega_2$, far above the pole of $Z_e$. It describes the
plate while it floats; once the plate reaches a stop (the nonlinear runs above, with a gap of
${_num(m.V_gap)}$\,m$^3$) the track alone carries the flow.

\begin{{figure}}[ht]
\centering
\includegraphics[width=0.85\textwidth]{{{fig}}}
\caption{{Top: unit-step force of the floating-decoupler linear model (representative
parameters) against three one-branch models; errors relative to $|F(0^+)-\gamma|$. Bottom:
the cosine and sine components of the fixed-decoupler step response; the sine is zero at every
extremum $t_p$.}}
\label{{fig:mount-quasi}}
\end{{figure}}"""


def section_tex(st: Study, red: Reduction, res: Results, seconds: float) -> str:
    m, c = res.mount, res.canon
    nl = res.nonlinear
    fx, fr = nl["cases"]["fixed"], nl["cases"]["free"]
    ms = 1e3
    params = "\n".join(
        rf"${PARAM_TEX[k][0]}$ & ${_num(v)}$ & {PARAM_TEX[k][1]} & {escape(PARAM_TEX[k][2])} \\"
        for k, v in m.values().items()
    )
    ids = ", ".join(
        f"${IDENTITY_TEX.get(k, escape(k))}$" + ("" if v == 0 else f" (residual ${latex(v)}$)")
        for k, v in red.zero.items()
    )
    checks = "\n".join(
        rf"{ch.tex} & ${_num(ch.value)}$ & ${_num(ch.expected)}$ & ${_num(ch.tol, 2)}$ & "
        rf"{'yes' if ch.ok else 'NO'} \\"
        for ch in res.checks
    )
    settle = "\n".join(
        rf"{d['eps'] * 100:.0f}\% & {_num(d['crude'] * ms)} & {_num(d['estimate'] * ms)} & "
        rf"{_num(d['exact'] * ms)} & {_num(d['error_at_crude'] * 100, 3)}\% \\"
        for d in res.settle
    )
    peaks = ", ".join(f"{n}: ${_num(a * ms, 6)}$/${_num(b * ms, 6)}$" for n, a, b in res.peaks[:4])
    vac_fx = "; ".join(f"${_num(a * ms, 3)}$--${_num(b * ms, 3)}$" for a, b in fx["vacuum"])
    vac_fr = "; ".join(f"${_num(a * ms, 3)}$--${_num(b * ms, 3)}$" for a, b in fr["vacuum"])
    float_fr = "; ".join(f"${_num(a * ms, 3)}$--${_num(b * ms, 3)}$" for a, b in fr["floating"])
    first_open = fr["floating"][0]
    R_ie = 2 * m.I_i * fr["tail_rate"]

    def row(label, key, scale=1e-3, unit_digits=4):
        return (
            f"{label} & ${_num(fx[key + '_ideal'] * scale, unit_digits)}$ & "
            f"${_num(fx[key + '_ramp'] * scale, unit_digits)}$ & "
            f"${_num(fx[key] * scale, unit_digits)}$ & "
            f"${_num(fr[key + '_ideal'] * scale, unit_digits)}$ & "
            f"${_num(fr[key + '_ramp'] * scale, unit_digits)}$ & "
            f"${_num(fr[key] * scale, unit_digits)}$ \\\\"
        )

    fig_lin, fig_nl = st.tex_path("linear_step.png"), st.tex_path("nonlinear_step.png")
    by_name = {ch.name: ch.value for ch in res.checks}
    n_zero = sum(v == 0 for v in red.zero.values())
    r_general = latex(red.envelope_sq_general.subs(U, sp.Symbol("u", positive=True) ** 2))
    agree_F = _num(by_name["vacuum model: exact PWL vs SDOF event-driven, F"], 2)
    agree_ev = _num(by_name["vacuum model: exact PWL vs n-state event-driven, F"], 2)
    agree_t = _num(by_name["vacuum model: switching times"], 2)
    agree_lin = _num(by_name["nonlinear code, linear limit"], 2)
    final_row = (
        rf"$F_T(7/\sigma)$; ideal: $\gamma X$ & ${_num(fx['final_linear'] * 1e-3)}$ & & "
        rf"${_num(fx['final'] * 1e-3)}$ & ${_num(fr['final_linear'] * 1e-3)}$ & & "
        rf"${_num(fr['final'] * 1e-3)}$ \\"
    )
    settle_label = r"2\% settling time (s)"
    slope_tex = latex(sp.factor(sp.expand(red.slope / sp.exp(-sig * t)).coeff(sp.sin(wd * t))))
    pairs = [
        (r"\gamma", "gamma", r"\lambda", "lambda"),
        (r"\omega_1^2", "omega_1^2", r"\omega_2^2", "omega_2^2"),
        (r"\zeta_1\omega_1", "zeta_1 omega_1", r"\zeta_2\omega_2", "zeta_2 omega_2"),
        (r"\varpi^2", "varpi^2", r"\xi\varpi", "xi varpi"),
    ]
    coeff_rows = ",\\\\\n".join(
        f"{_eq(a, red.coefficients[ka])}, & {_eq(b, red.coefficients[kb])}"
        for a, ka, b, kb in pairs
    )
    components_tex = _components_tex(res)
    quasi_tex = _quasi_tex(st, res)
    return rf"""
\section{{He \& Singh (2007): step response of a hydraulic engine mount}}
\label{{sec:hydraulic-mount}}

He and Singh reduce a lumped fluid model of a hydraulic engine mount to a linear dynamic
stiffness and invert its step response in closed form, then argue that this linear model
predicts the peak times and the decay of the measured (nonlinear) response, but not the
flattened first overshoot (top-chamber vacuum) nor the fast decay of a free-decoupler mount.
This section redoes each step with SymPy, checks every closed form against two independent
numerical solutions, and replaces the measurements by a nonlinear lumped model with vacuum
and a switching decoupler. The paper prints no parameter values; all numbers below use the
\emph{{representative}} values of Table~\ref{{tab:mount-params}}. The seed text drops the
digits 1 and 2, so the step sizes (release of a 3.7\,mm preload to 0, and to 1.3\,mm for the
free decoupler) are \emph{{reconstructed}}. Script: \texttt{{derivations/hydraulic\_mount.py}}
({"fast mode, " if st.fast else ""}{seconds:.1f}\,s).

\begin{{table}}[ht]
\centering\small
\caption{{Representative mount parameters (not from the paper, which gives none; the step
sizes are reconstructed from damaged digits).}}
\label{{tab:mount-params}}
\begin{{tabular}}{{llll}}
\toprule
symbol & value & unit & meaning \\
\midrule
{params}
\bottomrule
\end{{tabular}}
\end{{table}}

\subsection{{Symbolic reduction to $K_1(s)$ and $P_1/X(s)$}}
With a fixed decoupler ($q_d=0$) and $b_r=0$, the Laplace transforms of
$A_r\dot x - q_i = C_1\dot p_1$, $q_i = C_2\dot p_2$, $p_1-p_2 = I_i\dot q_i + R_i q_i$ and
$F_T = k_r x + A_r p_1$ are solved by SymPy for
\begin{{align*}}
{_eq("K_1(s) = F_T/X", red.K1)},\\
{_eq("P_1/X(s)", red.P1X)}.
\end{{align*}}
Matching numerator and denominator to $\gamma(s^2/\omega_1^2+2\zeta_1 s/\omega_1+1)/
(s^2/\omega_2^2+2\zeta_2 s/\omega_2+1)$ and
$\lambda(s^2/\varpi^2+2\xi s/\varpi+1)/(s^2/\omega_2^2+2\zeta_2 s/\omega_2+1)$ gives
\begin{{align*}}
{coeff_rows}
\end{{align*}}
so $\zeta_1\omega_1=\zeta_2\omega_2=\xi\varpi=R_i/(2I_i)$ exactly (the paper's $uv=\hat u\hat
v=1$ with $u=\omega_2/\omega_1$, $v=\zeta_2/\zeta_1$), and $P_1/X$ shares the denominator of
$K_1$. For $C_2\to\infty$ (the paper's $C_2\gg C_1$):
$\omega_1^2\to {latex(red.limits["omega_1^2"])}$,
$\omega_2^2\to {latex(red.limits["omega_2^2"])}$, $\gamma\to {latex(red.limits["gamma"])}$.
Each claim was reduced to a residual by exact rational simplification
(\texttt{{cancel}}/\texttt{{expand}}, no numerics), and {n_zero} of {len(red.zero)}
residuals are exactly 0: {ids}; $F$ stands for $F_T/(\gamma X)$.

\subsection{{Closed-form step responses}}
Partial fractions split $K_1(s)/(\gamma s)$ into $1/s + (\alpha s+\beta)/((s+\sigma)^2+
\omega_d^2)$, $\sigma=\zeta_2\omega_2$, $\omega_d=\omega_2\sqrt{{1-\zeta_2^2}}$; SymPy's inverse
Laplace transform then gives, with the identity,
\begin{{align*}}
\frac{{F_T(t)}}{{\gamma X}} &= {latex(red.step_paper)},
\qquad u^2 = \omega_2^2/\omega_1^2 = \frac{{k_r + A_r^2/C_1}}{{\gamma}},\\
\frac{{\mathrm{{d}}}}{{\mathrm{{d}}t}}\frac{{F_T}}{{\gamma X}} &=
{slope_tex}\,
e^{{-\sigma t}}\sin\omega_d t,
\end{{align*}}
and the same form for $p_1/(\lambda X)$ with $\hat u^2=\omega_2^2/\varpi^2$. Hence
$F_T(0^+)=(k_r+A_r^2/C_1)X$, $p_1(0^+)=A_rX/C_1$, the extrema sit exactly at
$t_p(n)=n\pi/\omega_d$, and the transient is bounded by the envelope
$\gamma X(1\pm\sqrt R\,e^{{-\sigma t}})$ with $R={latex(red.envelope_sq)}=(u^2-1)^2/(1-\zeta_2^2)$.
Without the identity (numerator rate $\sigma_1=\zeta_1\omega_1$ free),
$R={r_general}$, which is the $R$ above when $\sigma_1=\sigma$.
The settling time to a band $\pm\epsilon$ follows from the envelope,
$t_{{\mathrm{{set}}}}=\ln(\sqrt R/\epsilon)/\sigma$, and the paper's shortcut is
$\ln(1/\epsilon)/\sigma$ ($\sqrt R\approx1$). Here $\sigma={_num(c["sigma"])}$\,s$^{{-1}}$,
$\omega_d={_num(c["omega_d"])}$\,rad/s, $\zeta_2={_num(c["zeta_2"])}$, $u^2={_num(c["u"] ** 2)}$,
$\sqrt R={_num(c["sqrtR_F"])}$ for the force and ${_num(c["sqrtR_p"])}$ for the pressure
($\hat u^2={_num(c["u_hat"] ** 2)}$: the pressure transient is a hundred times its final value).

Figure~\ref{{fig:mount-linear}} compares the closed form with \texttt{{scipy.signal.step}} of
$K_1$ and $P_1/X$ (polynomials from the SymPy result) and with perturb's closed-form linear
step response (\texttt{{perturb.simulate.step\_response}}: the eigen-decomposition of the
balanced matrix of the lumped ODEs in $(p_1,p_2,q_i)$, no transfer function), started from the
jump $p_1(0^+)=A_rX/C_1$ that the impulse $A_r\dot x$ produces. Its extrema are the zeros of
$q_i$ (there $\dot F_T = -A_r q_i/C_1 = 0$), located on that closed form by Brent's method;
in ms, predicted/computed: {peaks}, \ldots ({len(res.peaks)} peaks in $7/\sigma$).

\begin{{table}}[ht]
\centering\small
\caption{{Measured claims of the linear model (unit step, {len(res.times)} time points on
$[0, 7/\sigma]$).}}
\begin{{tabular}}{{p{{0.5\textwidth}}llll}}
\toprule
claim & measured & expected & tolerance & holds \\
\midrule
{checks}
\bottomrule
\end{{tabular}}
\end{{table}}

\begin{{table}}[ht]
\centering\small
\caption{{Settling time of $F_T$ (ms). ``exact'': last exit from the band, on the closed form;
the last column is the largest deviation after the shortcut time, the paper's ``actual
error''.}}
\begin{{tabular}}{{lllll}}
\toprule
$\epsilon$ & $\ln(1/\epsilon)/\sigma$ & $\ln(\sqrt R/\epsilon)/\sigma$ & exact &
error after shortcut \\
\midrule
{settle}
\bottomrule
\end{{tabular}}
\end{{table}}

\begin{{figure}}[ht]
\centering
\includegraphics[width=0.8\textwidth]{{{fig_lin}}}
\caption{{Linear fixed-decoupler mount, step $X={_num(m.X_fixed * 1e3, 2)}$\,mm
(representative parameters; step size reconstructed). Closed form (line),
\texttt{{scipy.signal.step}} (circles), perturb's step response of the lumped ODEs (crosses),
decay envelope $\gamma X(1\pm\sqrt R e^{{-\sigma t}})$ (dashed) and $t_p=n\pi/\omega_d$ (red
lines). Bottom: the differences, at rounding level.}}
\label{{fig:mount-linear}}
\end{{figure}}

{components_tex}

\subsection{{Nonlinear mount: vacuum and a switching decoupler}}
The nonlinear model keeps the lumped equations and adds (i) top-chamber vacuum: below
$p_1=-p_v$ the top-chamber compliance switches from $C_1$ to $C_{{1v}}=
{_num(m.C1_vac / m.C1, 3)}\,C_1$ (continuous, piecewise-linear $p_1$ of the chamber volume);
(ii) a free decoupler: a plate that floats in a gap of $\pm V_g$ (volume) with
$p_1-p_2=I_d\dot q_d+R_d q_d$, rests on a stop ($q_d=0$, plastic impact) while the pressure
difference pushes it there, and leaves when that difference reverses. The plate starts on
the top stop, held by the suction after the release; the step is a ramp of
$t_r={_num(m.rise * ms, 2)}$\,ms (the measured step is not ideal; its rise time is not
given, so $t_r$ is representative too).

\emph{{Solvers.}} Every run is perturb's own step response
(\texttt{{perturb.simulate.step\_response}}) of a model of
\texttt{{perturb.model.system\_builtins.mount\_system}}; the ramp is two more states (a clock
and the displacement), so the ramped model is autonomous too. The fixed-decoupler models are
piecewise linear and run on the exact closed-form propagation (switching times found on the
closed form); the free decoupler is a plastic stop and runs on the event-driven flow of
several states (DOP853 between events, impacts, resting and lift-off located as events). The
fixed-decoupler vacuum model is also one oscillator in the track volume $y=V_i/(A_r|X|)$,
$y''+c\,y'+w_2y+w_1(y-e)-d\,(y-y_k)H(y-y_k)=0$, for perturb's SDOF event-driven solver
(\texttt{{perturb.simulate.event\_driven.simulate}}, ideal step): it agrees with the exact
propagation to ${agree_F}$ of $F(0^+)$, with switching times equal to ${agree_t}/\omega_d$,
and the event-driven flow of several states to ${agree_ev}$; with vacuum switched off the
nonlinear code reproduces the closed form to ${agree_lin}$ (table above, last rows).

\begin{{figure}}[ht]
\centering
\includegraphics[width=\textwidth]{{{fig_nl}}}
\caption{{Step responses of the nonlinear mount (black; the stand-in for the paper's
measurements) against the linear model with the same ramp (green dashed) and the closed form
for an ideal step (blue), with the decay envelope (dotted) and $t_p=n\pi/\omega_d$ (red).
Grey: vacuum in the top chamber; blue bands: decoupler plate floating. Representative
parameters (the paper gives none); step sizes {_num(abs(m.X_fixed) * ms, 2)} and
{_num(abs(m.X_free) * ms, 2)}\,mm reconstructed. Left, fixed decoupler: the linear model
misses the flattened first extremum and the phase lag the vacuum leaves behind, and captures
the final value and the decay rate. Right, free decoupler: the five regions of the paper.}}
\label{{fig:mount-nonlinear}}
\end{{figure}}

\begin{{table}}[ht]
\centering\small
\caption{{What the linear model captures and misses (forces in kN, pressures in kPa; ideal:
closed form, ramp: linear model with the ramped step, NL: nonlinear model).}}
\begin{{tabular}}{{lllllll}}
\toprule
& \multicolumn{{3}}{{c}}{{fixed decoupler}} & \multicolumn{{3}}{{c}}{{free decoupler}} \\
& ideal & ramp & NL & ideal & ramp & NL \\
\midrule
{row("largest $|F_T|$ (signed)", "F_peak")}
{row("lowest $p_1$", "p_min")}
{row(settle_label, "settle", 1.0)}
{final_row}
\bottomrule
\end{{tabular}}
\end{{table}}

\emph{{Fixed decoupler}} ($X={_num(m.X_fixed * ms, 2)}$\,mm). The linear model predicts a
first force extremum of ${_num(fx["F_peak_ideal"] * 1e-3)}$\,kN
($(k_r+A_r^2/C_1)X$; ${_num(fx["F_peak_ramp"] * 1e-3)}$\,kN with the ramp); vacuum
({vac_fx}\,ms) caps it at ${_num(fx["F_peak"] * 1e-3)}$\,kN and holds $p_1$ near
$-p_v$ (lowest ${_num(fx["p_min"] * 1e-3)}$\,kPa against
${_num(fx["p_min_ramp"] * 1e-3)}$\,kPa): the flat region. Afterwards the mount is linear
again: the extrema decay at ${_num(fx["tail_rate"])}$\,s$^{{-1}}$ (fit over {fx["n_tail"]}
extrema; $\sigma={_num(c["sigma"])}$), are spaced by ${_num(fx["spacing_after"] * ms, 5)}$\,ms
($\pi/\omega_d={_num(math.pi / c["omega_d"] * ms, 5)}$\,ms), but lag the predicted
$n\pi/\omega_d$ by ${_num(fx["lag_after"] * ms, 3)}$\,ms on average (the ramp alone:
${_num(fx["lag_ramp"] * ms, 3)}$\,ms). At $t=7/\sigma$ the force is within
${_num(100 * abs(fx["final"] / fx["final_linear"] - 1), 2)}$\% of $\gamma X$.

\emph{{Free decoupler}} ($X={_num(m.X_free * ms, 2)}$\,mm). The event log shows the paper's
sequence: region 1, linear and plate closed, until vacuum at ${_num(fr["vacuum"][0][0] * ms, 3)}$
\,ms; region 2, vacuum with the plate closed ({vac_fr}\,ms); region 3, the pressure
difference reverses, the plate leaves the top stop and crosses the gap
(${_num(first_open[0] * ms, 3)}$--${_num(first_open[1] * ms, 3)}$\,ms) while the flow
bypasses the inertia track and $p_1$ drops towards $p_2\approx0$; region 4, plate on a stop,
linear decay; the plate crosses the gap each half period (floating: {float_fr}\,ms) until,
from ${_num(fr["floating"][-1][0] * ms, 3)}$\,ms on, the oscillation is too small to close
it (region 5). There the transient decays at ${_num(fr["tail_rate"], 3)}$\,s$^{{-1}}$
(fit over {fr["n_tail"]} extrema), ${_num(fr["tail_rate"] / c["sigma"], 3)}$ times
$\sigma$, between the rates of the open-decoupler modes that load the chambers
(${_num(fr["open_rates"][0], 4)}$ and ${_num(fr["open_rates"][1], 4)}$\,s$^{{-1}}$, from
the eigenvalues of the floating-plate linear system). An effective resistance
$R_{{ie}}=2I_i\sigma_{{\mathrm{{eff}}}}={_num(R_ie, 3)}$\,N\,s/m$^5$
(${_num(R_ie / m.R_i, 3)}R_i$) is what a linear fit of this response would return, the
paper's route for free-decoupler mounts. The 2\% settling time drops from
${_num(fr["settle_ramp"], 3)}$ to ${_num(fr["settle"], 3)}$\,s.
The linear model thus captures the static gain, the peak spacing and the decay rate with the
decoupler closed; it misses the clipped peaks ($|F_T|$ and $p_1$ limited by vacuum, here
${_num(100 * (1 - fx["F_peak"] / fx["F_peak_ramp"]), 3)}$\% below the linear peak for the
fixed and ${_num(100 * (1 - fr["F_peak"] / fr["F_peak_ramp"]), 3)}$\% for the free
decoupler), the phase lag after vacuum, and the faster decay once the decoupler floats.

{quasi_tex}
"""


# --------------------------------------------------------------------------------------------
# main
# --------------------------------------------------------------------------------------------
def run(fast: bool) -> tuple[Reduction, Results]:
    m = Mount()
    red = reduce_lumped_model()
    res = linear_study(m, 1501 if fast else 8001)
    nonlinear_study(m, res, 1201 if fast else 6001, rtol=1e-9 if fast else 1e-11)
    quasi_checks(m, res, 1501 if fast else 6001)
    return red, res


def main(argv: Sequence[str] | None = None) -> int:
    st = study(NAME, "He & Singh hydraulic mount: step response, linear and nonlinear", argv)
    start = time.perf_counter()
    red, res = run(st.fast)
    figure_linear(res, st.path("linear_step.png"))
    figure_nonlinear(res, st.path("nonlinear_step.png"))
    figure_quasi(res, st.path("quasi_linear.png"))
    write_csv(st, red, res)
    seconds = time.perf_counter() - start
    st.write_section(section_tex(st, red, res, seconds))
    identities = {**red.zero, **quasi_linear_model().zero}
    bad_identities = [k for k, v in identities.items() if v != 0]
    bad_checks = [ch.name for ch in res.checks if not ch.ok]
    for ch in res.checks:
        print(f"{'ok ' if ch.ok else 'BAD'} {ch.name}: {ch.value:.6g} (expected {ch.expected:g})")
    print(f"{len(identities) - len(bad_identities)}/{len(identities)} symbolic identities hold")
    print(f"wrote {st.dir} in {seconds:.1f} s")
    if bad_identities or bad_checks:
        print("FAILED: " + ", ".join(bad_identities + bad_checks), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
