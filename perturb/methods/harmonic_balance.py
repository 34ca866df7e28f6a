"""Single-harmonic balance (describing-function method) in closed form.

For ``x'' + mu x' + f(x) = F cos(Omega t)`` with an odd restoring force ``f``, the ansatz
``x = A cos(psi)``, ``psi = Omega t - phi`` and projection on ``cos psi`` and ``sin psi`` give

    a_1(A) - Omega^2 A = F cos(phi),        mu Omega A = F sin(phi),

where ``a_1(A)`` is the first Fourier coefficient of ``f(A cos psi)`` — for a piecewise-linear
``f`` a closed form in ``theta = arccos(d/A)`` from the Fourier engine, never a Taylor series.
Eliminating the phase leaves a quadratic in ``W = Omega^2``,

    A^2 W^2 + (mu^2 A^2 - 2 A a_1) W + a_1^2 - F^2 = 0,

so every branch, detached loops included, follows from amplitude parametrisation. Averaging
the same ansatz (van der Pol's variation of parameters) gives the slow flow whose Jacobian
decides stability. For the Zou–Nagarajaiah model these are the paper's first-order modified
Lindstedt–Poincaré equations (54)–(55) written without the bookkeeping parameter.

This file is the single-harmonic, zero-bias case; the full harmonic-balance engine (bias,
several harmonics, subharmonics) is a separate capability.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from ..approximation import Approximation, Step
from ..errors import ModelError
from ..fourier_symbols import closed_form, series_coefficient
from ..model import Oscillator
from ..parsing import real_symbol

__all__ = ["single_harmonic_balance"]


def _is_odd(f: sp.Expr, x: sp.Symbol, values: dict) -> bool:
    diff = f + f.subs(x, -x)
    if sp.simplify(diff) == 0:
        return True
    # Piecewise forms do not always simplify: check numerically at the parameter values
    # (free parameters at two random draws) over a wide range of x.
    rng = np.random.default_rng(12345)
    pts = np.linspace(-7.3, 7.3, 211) * max(1.0, *(abs(float(v)) for v in values.values()))
    for _ in range(2):
        subs = dict(values)
        for s in diff.free_symbols - {x} - set(subs):
            subs[s] = sp.Float(rng.uniform(0.3, 1.7))
        fn = sp.lambdify(x, diff.xreplace(subs), modules=["numpy"])
        if not np.all(np.abs(np.asarray(fn(pts), dtype=float)) < 1e-12):
            return False
    return True


def single_harmonic_balance(oscillator: Oscillator) -> Approximation:
    """Derive the single-harmonic balance equations of ``oscillator``.

    Parameters
    ----------
    oscillator
        ``x'' + mu x' + f(x) = F cos(Omega t)`` (or unforced) with linear viscous damping and
        an odd restoring force ``f`` made of polynomial and piecewise-linear terms.

    Returns
    -------
    Approximation
        Unknowns ``(A, phi)``, residuals, slow flow, the frequency polynomial in
        ``Omega**2`` and the derivation steps.

    Raises
    ------
    ModelError
        If the oscillator has terms this method does not cover (nonlinear damping,
        parametric excitation, several forcing harmonics, an even part of ``f``).
    """
    osc = oscillator
    x = osc.x
    if osc.velocity != 0 or osc.parametric != 0:
        raise ModelError(
            f"single-harmonic balance covers x'' + mu x' + f(x) = F cos(Omega t); model "
            f"{osc.name!r} also has {osc.velocity + osc.parametric}"
        )
    if len(osc.forcing.harmonics) > 1 or osc.forcing.constant != 0:
        raise ModelError(
            f"single-harmonic balance needs at most one forcing harmonic and no static load; "
            f"model {osc.name!r} has forcing {osc.forcing.expr(osc.t)}"
        )
    f = osc.restoring_force
    if not _is_odd(f, x, osc.substitutions()):
        raise ModelError(
            f"the restoring force {f} of model {osc.name!r} is not odd, so its response has a "
            "bias; this zero-bias single-harmonic method does not apply"
        )
    if osc.forcing.harmonics:
        harmonic = osc.forcing.harmonics[0]
        F, Omega = harmonic.amplitude, harmonic.frequency
        if not isinstance(Omega, sp.Symbol):
            raise ModelError(
                f"the forcing frequency of model {osc.name!r} is {Omega}: expected a single "
                "parameter symbol (e.g. Omega) to sweep"
            )
    else:
        F, Omega = sp.Integer(0), real_symbol("Omega")
    mu = osc.damping
    A = sp.Symbol("A", positive=True)
    phi = real_symbol("phi")
    psi = real_symbol("psi")
    tau = real_symbol("tau")

    values = {n: v for n, v in osc.params.items() if v is not None}
    a1 = series_coefficient(f, x, 1, A, sp.Integer(0), values=values)
    a1_closed, definitions, domains = closed_form(a1)
    # Everything is first written with a_1(A) by name, as a paper would; the numeric fields
    # get the coefficient substituted in.
    a1s = sp.Function("a_1")(A)
    W = Omega**2
    shown_residuals = (a1s - W * A - F * sp.cos(phi), mu * Omega * A - F * sp.sin(phi))
    shown_poly = (a1s**2 - F**2, mu**2 * A**2 - 2 * A * a1s, A**2)
    shown_flow = (
        -(mu * Omega * A - F * sp.sin(phi)) / (2 * Omega),
        (F * sp.cos(phi) - a1s + W * A) / (2 * Omega * A),
    )

    def with_a1(exprs: tuple[sp.Expr, ...]) -> tuple[sp.Expr, ...]:
        return tuple(e.subs(a1s, a1) for e in exprs)

    residuals = with_a1(shown_residuals)
    c0, c1, c2 = with_a1(shown_poly)
    slow_flow = with_a1(shown_flow)
    steps = (
        Step("Equation of motion", (osc.equation,)),
        Step(
            "Ansatz",
            (sp.Eq(x, A * sp.cos(psi)), sp.Eq(psi, tau - phi), sp.Eq(tau, Omega * osc.t)),
            "One harmonic; no bias because the restoring force is odd.",
        ),
        Step(
            "First Fourier coefficient of the restoring force",
            (sp.Eq(a1s, a1),),
            "f(A cos psi) = a_1(A) cos psi + higher harmonics; the nonsmooth terms enter through "
            "the closed-form step and ramp coefficients (theta = arccos(d/A)).",
        ),
        Step(
            "The coefficient in closed form",
            (sp.Eq(a1s, a1_closed),) + tuple(sp.Eq(sym, value) for sym, value in definitions),
            "Valid where the orbit crosses every switching point ("
            + ", ".join(sp.sstr(c) for c in domains)
            + "); in the other regimes the terms are exactly zero or linear."
            if domains
            else "",
        ),
        Step(
            "Balance of the cosine and sine terms",
            tuple(sp.Eq(r, 0) for r in shown_residuals),
        ),
        Step(
            "Frequency-amplitude equation: phase eliminated, quadratic in the squared frequency",
            (sp.Eq(sp.Add(*(c * W**j for j, c in enumerate(shown_poly))), 0),),
        ),
        Step(
            "Slow flow (first-order averaging)",
            (
                sp.Eq(sp.Derivative(A, osc.t), shown_flow[0]),
                sp.Eq(sp.Derivative(phi, osc.t), shown_flow[1]),
            ),
        ),
    )
    return Approximation(
        oscillator=osc,
        method="hb1",
        options={"harmonics": 1},
        unknowns=(A, phi),
        residuals=residuals,
        waveform=A * sp.cos(tau - phi),
        tau=tau,
        frequency=Omega,
        slow_flow=slow_flow,
        amplitude=A,
        frequency_polynomial=(c0, c1, c2),
        phase_from=(
            (a1 - Omega**2 * A),
            mu * Omega * A,
        ),
        fourier={"a_1": a1},
        steps=steps,
    )
