"""Harmonic balance: single harmonic in closed form (PWL too), with bias, and multi-harmonic.

Single harmonic, zero bias (:func:`single_harmonic_balance`)
    For ``x'' + mu x' + f(x) = F cos(Omega t)`` with an odd restoring force ``f``, the ansatz
    ``x = A cos(psi)``, ``psi = Omega t - phi`` and projection on ``cos psi`` and ``sin psi``
    give

        a_1(A) - Omega^2 A = F cos(phi),        mu Omega A = F sin(phi),

    where ``a_1(A)`` is the first Fourier coefficient of ``f(A cos psi)`` — for a
    piecewise-linear ``f`` a closed form in ``theta = arccos(d/A)`` from the Fourier engine,
    never a Taylor series. Eliminating the phase leaves a quadratic in ``W = Omega^2``,

        A^2 W^2 + (mu^2 A^2 - 2 A a_1) W + a_1^2 - F^2 = 0,

    so every branch, detached loops included, follows from amplitude parametrisation.
    Averaging the same ansatz (van der Pol's variation of parameters) gives the slow flow
    whose Jacobian decides stability. For the Zou–Nagarajaiah model these are the paper's
    first-order modified Lindstedt–Poincaré equations (54)–(55) written without the
    bookkeeping parameter.

:func:`harmonic_balance` — a chosen harmonic set
    ``harmonics=(1,)`` (optionally ``bias=True``) works for every force the Fourier engine
    handles (polynomial and PWL in ``x``, PWL in ``x'``, products; see
    :func:`~perturb.methods.averaging.fourier_components`). With a bias the ansatz is
    ``x = b + A cos(psi)`` and the mean balance

        a_0(A, b)/2 = F_0        (F_0 the static load)

    joins the two first-harmonic equations. For the negative-stiffness oscillator (``k < 0``)
    it has, besides ``b = 0``, roots ``b`` near the wells ``+-(1 - k)``: the orbits around one
    well. The mean equation does not contain the frequency, so :func:`balance_solutions`
    finds all solutions at one frequency by a two-dimensional sign scan in ``(A, b)``
    followed by Newton's method.

    Several harmonics (odd sets ``(1, 3, 5)``, a bias plus ``(1, 2)``, subharmonics
    ``(Fraction(1, 3), 1)``) are balanced exactly for forces polynomial in ``x`` and ``x'``:
    the ansatz is substituted, the residual's components are read off with
    :func:`~perturb.fourier.trig.harmonics` and every component outside the set is dropped.
    PWL forces with several harmonics need switching instants found numerically (the
    Galerkin projection of docs/architecture.md's Fourier layer) and are refused here.

Free conservative systems (``x'' + f(x) = 0``) are parametrised by the amplitude ``a_1`` of
the fundamental with the frequency ``omega`` among the unknowns; :func:`backbone_series`
expands such a result in powers of ``a_1`` (where harmonic balance meets
Lindstedt–Poincaré).  Solving an approximation's residuals numerically
(:func:`perturb.numeric.balance.solve_residuals`, :func:`perturb.numeric.balance.balance_solutions`)
is the numeric layer's work: this module derives equations and never imports it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from types import MappingProxyType

import sympy as sp

from perturb.approximation import Approximation, Step
from perturb.errors import ModelError, ParameterError, PerturbError
from perturb.fourier.symbols import closed_form, series_coefficient
from perturb.fourier.trig import fold_mirror_angles
from perturb.fourier.trig import harmonics as trig_harmonics
from perturb.methods.applicability import check_order, require_centred
from perturb.methods.averaging import (
    fourier_components,
    frequency_polynomial_coefficients,
    response_frequency_symbol,
)
from perturb.methods.caveats import states_caveats
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import real_symbol
from perturb.model.pwl import is_nonsmooth
from perturb.printing import latex

__all__ = [
    "single_harmonic_balance",
    "harmonic_balance",
    "BackboneSeries",
    "backbone_series",
]


@states_caveats
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
        parametric excitation, several forcing harmonics, a static load, an even part of
        ``f``); the message names the methods that apply
        (:func:`~perturb.methods.applicability.require_centred`).
    """
    osc = oscillator
    x = osc.x
    if osc.velocity != 0 or osc.parametric != 0:
        raise ModelError(
            f"single-harmonic balance covers x'' + mu x' + f(x) = F cos(Omega t); model "
            f"{osc.name!r} also has {osc.velocity + osc.parametric}"
        )
    if len(osc.forcing.harmonics) > 1:
        raise ModelError(
            f"single-harmonic balance needs at most one forcing harmonic; model {osc.name!r} "
            f"has forcing {osc.forcing.expr(osc.t)}: use numeric harmonic balance ('hb') or "
            "'exact'"
        )
    f = osc.restoring_force
    require_centred(osc, "single-harmonic balance without bias (hb1)", polynomial=False)
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
    (a1_closed,), definitions = fold_mirror_angles((a1_closed,), definitions)
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
            "$f(A\\cos\\psi) = a_1(A)\\cos\\psi + \\ldots$ (higher harmonics); the nonsmooth "
            "terms enter through the closed-form step and ramp coefficients "
            "($\\theta = \\arccos(d/A)$ for a switching point $d$).",
        ),
        Step(
            "The coefficient in closed form",
            (sp.Eq(a1s, a1_closed),) + tuple(sp.Eq(sym, value) for sym, value in definitions),
            "Valid where the orbit crosses every switching point ("
            + ", ".join(f"${latex(c)}$" for c in domains)
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


# ------------------------------------------------------------------- harmonic_balance --
def _values(osc: Oscillator) -> dict[str, float]:
    return {n: v for n, v in osc.params.items() if v is not None}


_MAX_DENOMINATOR = 64


def _harmonic_set(harmonics: Sequence[int | Fraction | str | sp.Rational]) -> tuple[Fraction, ...]:
    out: list[Fraction] = []
    for h in harmonics:
        if isinstance(h, bool):
            raise ParameterError(f"harmonic {h!r}: expected a positive integer or fraction k/m")
        try:
            fr = Fraction(h) if isinstance(h, int | Fraction) else Fraction(str(h))
        except (ValueError, ZeroDivisionError, TypeError):
            raise ParameterError(
                f"harmonic {h!r}: expected a positive integer or fraction k/m (e.g. 1, 3, '1/3')"
            ) from None
        if fr <= 0:
            raise ParameterError(f"harmonic {h!r}: expected a positive multiple of the frequency")
        if fr.denominator > _MAX_DENOMINATOR:
            # a float such as 1/3 = 0.333... arrives as a huge fraction
            raise ParameterError(
                f"harmonic {h!r} = {fr}: denominator above {_MAX_DENOMINATOR}; write "
                "subharmonics exactly, e.g. Fraction(1, 3) or '1/3'"
            )
        out.append(fr)
    if not out or len(set(out)) != len(out):
        raise ParameterError(
            f"harmonics = {list(harmonics)!r}: expected a non-empty set of distinct harmonics"
        )
    return tuple(sorted(out))


def _forcing_frequency(osc: Oscillator) -> sp.Symbol:
    Omega = osc.forcing.harmonics[0].frequency
    if not isinstance(Omega, sp.Symbol):
        raise ModelError(
            f"the forcing frequency of model {osc.name!r} is {Omega}: expected a single "
            "parameter symbol (e.g. Omega) to sweep"
        )
    return Omega


@states_caveats
def harmonic_balance(
    oscillator: Oscillator,
    harmonics: Sequence[int | Fraction | str] = (1,),
    *,
    bias: bool = False,
) -> Approximation:
    r"""Harmonic balance with a chosen harmonic set.

    Parameters
    ----------
    oscillator
        ``x'' + g(x, x') = F_0 + sum_j F_j cos(r_j Omega t + p_j)`` (forced, ``Omega`` a
        parameter symbol) or ``x'' + g(x, x') = 0`` (free).
    harmonics
        Multiples of the forcing frequency (forced) or of the unknown frequency ``omega``
        (free; must contain 1). Fractions ``k/m`` give subharmonics: the ansatz is then a
        series in ``theta = Omega t / m`` with ``m`` the least common denominator.
    bias
        Add a constant term (needed for non-odd forces, static loads and orbits around one
        well of a double-well potential).

    Returns
    -------
    Approximation
        ``harmonics=(1,)``, forced: unknowns ``(A, phi)`` or ``(A, b, phi)`` with
        ``x = b + A cos(Omega t + p - phi)``; residuals in closed form for PWL forces
        (step/ramp coefficients by name), ``phase_from``, ``frequency_polynomial`` (in
        ``Omega**2`` at fixed ``b``), and without bias the averaged slow flow, so
        :func:`~perturb.numeric.amplitude.approximation_response` applies; with bias use
        :func:`balance_solutions`.

        Several harmonics (polynomial forces): unknowns ``c_0`` (bias), ``a_n``, ``b_n``
        (cosine and sine amplitudes of harmonic ``n`` of ``theta``); waveform in
        ``tau = Omega t``.

        Free systems: the frequency ``omega`` is the last unknown and the fundamental's
        amplitude (``A``, or ``a_1``) is the ``amplitude`` parameter; a conservative
        oscillation is even in time (cosines only), a self-excited one gets the phase
        condition ``b_1 = 0`` and its amplitude becomes an unknown.

    Raises
    ------
    ModelError
        For parametric terms, a static load without ``bias``, several forcing harmonics with
        the single-harmonic ansatz, several harmonics with a non-polynomial force, forcing
        harmonics that are not multiples of the ansatz's base frequency, or forces without
        closed-form coefficients.
    ParameterError
        For a bad harmonic set, or more harmonics than
        :data:`~perturb.methods.applicability.ORDER_LIMITS` ``["hb"]``.

    Notes
    -----
    Single-harmonic balance without bias of an odd force coincides with
    :func:`single_harmonic_balance` (and with first-order Krylov–Bogoliubov averaging); on
    ``u'' + w0^2 u + alpha2 u^2 + alpha3 u^3 = 0`` it gives ``omega^2 = w0^2 + 3 alpha3 a^2/4``
    and misses ``alpha2``; a bias recovers ``-12 alpha2^2`` and bias plus second harmonic the
    Lindstedt–Poincaré ``-10 alpha2^2`` in the ``a^2`` term of ``omega`` (see
    :func:`backbone_series`).
    """
    osc = oscillator
    hs = _harmonic_set(harmonics)
    if osc.parametric != 0:
        raise ModelError(
            f"harmonic balance here covers x'' + g(x, x') = f(t); model {osc.name!r} has "
            f"parametric terms {osc.parametric}"
        )
    forced = bool(osc.forcing.harmonics)
    if not forced and (any(h.denominator != 1 for h in hs) or Fraction(1) not in hs):
        raise ParameterError(
            f"harmonics = {[str(h) for h in hs]}: a free oscillation is expanded in integer "
            "multiples of its own (unknown) frequency, which must include the fundamental 1"
        )
    if osc.forcing.constant != 0 and not bias:
        raise ModelError(
            f"model {osc.name!r} has a static load {osc.forcing.constant}: its response has a "
            "mean; pass bias=True"
        )
    if not bias:
        try:
            require_centred(osc, "harmonic balance without bias")
        except ModelError as exc:
            raise ModelError(f"{exc} (here: pass bias=True)") from None
    check_order("hb", len(hs), "number of harmonics")
    if hs == (Fraction(1),):
        return _single(osc, bias)
    return _multi(osc, hs, bias)


def _single(osc: Oscillator, bias: bool) -> Approximation:
    """One harmonic (plus bias), for every force the Fourier engine handles."""
    x, v, t = osc.x, osc.v, osc.t
    A = sp.Symbol("A", positive=True)
    phi, b = real_symbol("phi"), real_symbol("b")
    psi, tau = real_symbol("psi"), real_symbol("tau")
    forced = bool(osc.forcing.harmonics)
    F0 = osc.forcing.constant
    if forced:
        if len(osc.forcing.harmonics) > 1:
            raise ModelError(
                f"model {osc.name!r} has {len(osc.forcing.harmonics)} forcing harmonics: the "
                "single-harmonic ansatz balances one; use harmonics=(1, 2, ...) (polynomial "
                "forces)"
            )
        h = osc.forcing.harmonics[0]
        F, w, p0 = h.amplitude, _forcing_frequency(osc), h.phase
    else:
        F, w, p0 = sp.Integer(0), response_frequency_symbol(osc), sp.Integer(0)
    conservative = not osc.g.has(v)
    bias_sym = b if bias else sp.Integer(0)
    comps = fourier_components(osc.g, x, v, A, w, bias_sym, (0, 1) if bias else (1,), _values(osc))
    gc, gs = comps[1]
    g0 = comps[0][0] if bias else sp.Integer(0)
    args = (A, b) if bias else (A,)
    g0f, gcf, gsf = (sp.Function(n)(*args) for n in ("g_0", "g_c", "g_s"))
    names = {g0f: g0, gcf: gc, gsf: gs}

    def named(e: sp.Expr) -> sp.Expr:
        return e.xreplace(names)

    steps: list[Step] = [Step("Equation of motion", (osc.equation,))]
    ansatz = (sp.Eq(x, bias_sym + A * sp.cos(psi)),)
    if forced:
        ansatz += (sp.Eq(psi, w * t + p0 - phi),)
        why = (
            "One harmonic plus a bias b: the orbit may sit off-centre (a static load, a "
            "non-odd force, or motion around one well of a double-well potential)."
            if bias
            else "One harmonic, no bias."
        )
    else:
        ansatz += (sp.Eq(psi, w * t),)
        why = (
            "A free oscillation of unknown frequency $\\omega$; time origin at a maximum of $x$."
            + (" Plus a bias $b$." if bias else "")
        )
    steps.append(Step("Ansatz", ansatz, why))
    on_orbit = {x: bias_sym + A * sp.cos(psi), v: -A * w * sp.sin(psi)}
    coefficient_rows = ((sp.Eq(g0f, g0),) if bias else ()) + (sp.Eq(gcf, gc), sp.Eq(gsf, gs))
    steps.append(
        Step(
            "Fourier coefficients of the force on the ansatz",
            (
                sp.Eq(sp.Function("g")(x, v), osc.g),
                sp.Eq(
                    sp.Function("g")(on_orbit[x], on_orbit[v]),
                    (g0f if bias else 0)
                    + gcf * sp.cos(psi)
                    + gsf * sp.sin(psi)
                    + sp.Symbol("\\ldots"),
                ),
            )
            + coefficient_rows,
            "Polynomial terms exactly; piecewise-linear terms through the closed-form step "
            "and ramp coefficients $a_n(A\\cos\\psi + b;\\, d)$ of the Fourier engine.",
        )
    )
    closed, definitions, domains = closed_form(sp.Matrix([g0, gc, gs]))
    closed, definitions = fold_mirror_angles(tuple(closed), definitions)
    if definitions:
        rows = ((sp.Eq(g0f, closed[0]),) if bias else ()) + (
            sp.Eq(gcf, closed[1]),
            sp.Eq(gsf, closed[2]),
        )
        steps.append(
            Step(
                "The coefficients in closed form",
                rows + tuple(sp.Eq(s, d) for s, d in definitions),
                "Valid where the orbit crosses every switching point ("
                + ", ".join(f"${latex(c)}$" for c in domains)
                + "); in the other regimes the terms are exactly linear.",
            )
        )
    if forced:
        shown = ((g0f - F0,) if bias else ()) + (
            gcf - w**2 * A - F * sp.cos(phi),
            -gsf - F * sp.sin(phi),
        )
        cos_part, sin_part = gc - w**2 * A, -gs
        residuals = tuple(sp.expand(named(e)) for e in shown)
        unknowns: tuple[sp.Symbol, ...] = (A, b, phi) if bias else (A, phi)
        steps.append(
            Step(
                "Balance of the " + ("mean, " if bias else "") + "cosine and sine terms",
                tuple(sp.Eq(e, 0) for e in shown),
                "The mean balance does not contain the frequency: for each amplitude $A$ it "
                "fixes the bias $b$ (several roots for a double-well force: $b = 0$ and one root "
                "near each well)."
                if bias
                else "",
            )
        )
        W = w**2
        steps.append(
            Step(
                "Frequency-amplitude equation: phase eliminated",
                (sp.Eq((gcf - W * A) ** 2 + gsf**2, F**2),),
                "Together with the mean balance when there is a bias." if bias else "",
            )
        )
        slow_flow = None
        if not bias:
            slow_flow = (
                sp.expand((gs + F * sp.sin(phi)) / (2 * w)),
                (W * A - gc + F * sp.cos(phi)) / (2 * w * A),
            )
            steps.append(
                Step(
                    "Slow flow (first-order averaging)",
                    (
                        sp.Eq(sp.Derivative(A, t), (gsf + F * sp.sin(phi)) / (2 * w)),
                        sp.Eq(sp.Derivative(phi, t), (W * A - gcf + F * sp.cos(phi)) / (2 * w * A)),
                    ),
                    "Van der Pol's variation of parameters on the same ansatz; its fixed points "
                    "are the balance solutions and its Jacobian their stability.",
                )
            )
        return Approximation(
            oscillator=osc,
            method="hb",
            options={"harmonics": 1, "bias": bias},
            unknowns=unknowns,
            residuals=residuals,
            waveform=bias_sym + A * sp.cos(tau + p0 - phi),
            tau=tau,
            frequency=w,
            slow_flow=slow_flow,
            amplitude=A,
            frequency_polynomial=frequency_polynomial_coefficients(cos_part, sin_part, F, w),
            phase_from=(cos_part, sin_part),
            fourier=MappingProxyType({"g_0": g0, "g_c": gc, "g_s": gs}),
            steps=tuple(steps),
        )
    shown = ((g0f - F0,) if bias else ()) + (gcf - w**2 * A,) + (() if conservative else (-gsf,))
    residuals = tuple(sp.expand(named(e)) for e in shown)
    unknowns = (() if conservative else (A,)) + ((b,) if bias else ()) + (w,)
    backbone = None
    if conservative and not bias:
        backbone = sp.sqrt(sp.expand(gc / A))
    steps.append(
        Step(
            "Balance of the " + ("mean and " if bias else "") + "first harmonic",
            tuple(sp.Eq(e, 0) for e in shown),
            "A conservative oscillation has no sine component; the amplitude A parametrises "
            "the family."
            if conservative
            else "The sine balance fixes the amplitude of the self-excited oscillation.",
        )
    )
    if backbone is not None:
        steps.append(
            Step(
                "Backbone: the describing-function frequency",
                (sp.Eq(w, sp.sqrt(gcf / A)), sp.Eq(w, backbone)),
            )
        )
    return Approximation(
        oscillator=osc,
        method="hb",
        options={"harmonics": 1, "bias": bias},
        unknowns=unknowns,
        residuals=residuals,
        waveform=bias_sym + A * sp.cos(tau),
        tau=tau,
        frequency=w,
        amplitude=A,
        backbone=backbone,
        fourier=MappingProxyType({"g_0": g0, "g_c": gc, "g_s": gs}),
        steps=tuple(steps),
    )


def _label(h: Fraction) -> str:
    return str(h.numerator) if h.denominator == 1 else f"{{{h.numerator}/{h.denominator}}}"


def _trig_mul(
    p: dict[int, tuple[object, object]], q: dict[int, tuple[object, object]], zero: object
) -> dict[int, tuple[object, object]]:
    """Product of two real trigonometric polynomials ``{n: (cos coeff, sin coeff)}``, n >= 0:
    cos n cos m = [cos(n+m) + cos(n-m)]/2, sin n sin m = [cos(n-m) - cos(n+m)]/2,
    cos n sin m = [sin(n+m) - sin(n-m)]/2, sin n cos m = [sin(n+m) + sin(n-m)]/2."""
    out: dict[int, list[object]] = {}

    def add(k: int, c: object, s_: object) -> None:
        if k < 0:  # cos(-k) = cos k, sin(-k) = -sin k
            k, s_ = -k, -s_
        cur = out.setdefault(k, [zero, zero])
        cur[0] += c
        cur[1] += s_ if k else zero

    for n, (c1, s1) in p.items():
        for m, (c2, s2) in q.items():
            cc, ss, cs, sc = c1 * c2, s1 * s2, c1 * s2, s1 * c2
            add(n + m, (cc - ss) / 2, (cs + sc) / 2)
            add(n - m, (cc + ss) / 2, (sc - cs) / 2)
    return {k: (c, s_) for k, (c, s_) in out.items()}


def _polynomial_components(
    g: sp.Expr,
    x: sp.Symbol,
    v: sp.Symbol,
    cos_syms: Mapping[int, sp.Symbol],
    sin_syms: Mapping[int, sp.Symbol],
    ansatz: sp.Expr,
    nu: sp.Expr,
) -> dict[int, tuple[sp.Expr, sp.Expr]]:
    """Components of ``g(x, v)`` on a multi-harmonic ansatz, ``v = nu dx/dtheta``.

    The ansatz is held as a real trigonometric polynomial with coefficients in a sparse
    polynomial ring (unknowns and parameters as generators), and ``g`` is evaluated monomial
    by monomial with the product-to-sum rules. This is the same bookkeeping as
    :func:`~perturb.fourier.trig.harmonics` but never builds the expanded SymPy expression of
    ``g(ansatz)`` (which for a cubic of eight coefficients has thousands of terms and made the
    derivation take tens of seconds).
    """
    from sympy.polys.rings import ring

    bias_part = ansatz.xreplace({s: 0 for s in (*cos_syms.values(), *sin_syms.values())})
    used = [s for s in (*cos_syms.values(), *sin_syms.values()) if ansatz.has(s)]
    gens = list(bias_part.free_symbols) + used
    poly_g = sp.Poly(g, x, v)
    others = sorted(
        (set().union(*(sp.sympify(c).free_symbols for c in poly_g.coeffs())) | nu.free_symbols)
        - set(gens),
        key=sp.default_sort_key,
    )
    try:
        R, *_ = ring(gens + others, sp.QQ)
        conv = R.from_expr
        conv(sp.Add(*poly_g.coeffs()) + nu)
    except (ValueError, sp.PolynomialError):  # coefficients not polynomial (k/m): EX domain
        R, *_ = ring(gens, sp.EX)
        conv = R.from_expr
    zero = R.zero
    X: dict[int, tuple[object, object]] = {0: (conv(bias_part), zero)}
    V: dict[int, tuple[object, object]] = {}
    nu_r = conv(nu)
    for n, an in cos_syms.items():
        bn = sin_syms[n]
        a_r = conv(an) if an in used else zero
        b_r = conv(bn) if bn in used else zero
        X[n] = (a_r, b_r)
        V[n] = (nu_r * n * b_r, -nu_r * n * a_r)
    deg_x, deg_v = poly_g.degree(x), poly_g.degree(v)
    one = {0: (R.one, zero)}
    Xp, Vp = [one], [one]
    for _ in range(deg_x):
        Xp.append(_trig_mul(Xp[-1], X, zero))
    for _ in range(deg_v):
        Vp.append(_trig_mul(Vp[-1], V, zero))
    total: dict[int, list[object]] = {}
    for (i, j), coeff in poly_g.terms():
        c_r = conv(coeff)
        term = Xp[i] if j == 0 else (Vp[j] if i == 0 else _trig_mul(Xp[i], Vp[j], zero))
        for n, (c, s_) in term.items():
            cur = total.setdefault(n, [zero, zero])
            cur[0] += c_r * c
            cur[1] += c_r * s_
    symbols = R.symbols
    return {
        n: (sp.expand(c.as_expr(*symbols)), sp.expand(s_.as_expr(*symbols)))
        for n, (c, s_) in sorted(total.items())
    }


def _multi(osc: Oscillator, hs: tuple[Fraction, ...], bias: bool) -> Approximation:
    """Several harmonics, polynomial forces: exact projection with the trig bookkeeping."""
    x, v, t = osc.x, osc.v, osc.t
    g = osc.g
    if is_nonsmooth(g) or not g.is_polynomial(x, v):
        raise ModelError(
            f"several harmonics are balanced exactly only for forces polynomial in {x} and "
            f"{v}; model {osc.name!r} has g = {g}. For piecewise-linear forces use "
            "harmonics=(1,) with bias=True (closed form)"
        )
    m = math.lcm(*(h.denominator for h in hs))
    theta, tau = real_symbol("theta"), real_symbol("tau")
    forced = bool(osc.forcing.harmonics)
    forcing = osc.forcing.constant
    if forced:
        Omega = _forcing_frequency(osc)
        w, nu = Omega, Omega / m
        for h in osc.forcing.harmonics:
            ratio = sp.nsimplify(h.frequency / Omega)
            k = ratio * m
            if not (ratio.is_Rational and k.is_Integer):
                raise ModelError(
                    f"forcing harmonic {h} of model {osc.name!r} has frequency {ratio} Omega, "
                    f"not a multiple of the ansatz's base frequency Omega/{m}"
                )
            forcing += h.amplitude * sp.cos(int(k) * theta + h.phase)
    else:
        w = nu = response_frequency_symbol(osc)
    conservative = not forced and not g.has(v)
    c0 = real_symbol("c_0")
    ansatz = c0 if bias else sp.Integer(0)
    unknowns: list[sp.Symbol] = [c0] if bias else []
    amplitude = None
    cos_syms, sin_syms = {}, {}
    for h in hs:
        n = int(h * m)
        an, bn = real_symbol(f"a_{_label(h)}"), real_symbol(f"b_{_label(h)}")
        cos_syms[n], sin_syms[n] = an, bn
        ansatz += an * sp.cos(n * theta)
        if forced:
            unknowns += [an, bn]
            ansatz += bn * sp.sin(n * theta)
            continue
        if n == 1:  # time origin at a maximum of the fundamental: b_1 = 0
            amplitude = an
            if not conservative:
                unknowns.append(an)
            continue
        unknowns.append(an)
        if not conservative:
            unknowns.append(bn)
            ansatz += bn * sp.sin(n * theta)
    if not forced:
        unknowns.append(w)
    g_parts = _polynomial_components(g, x, v, cos_syms, sin_syms, ansatz, nu)
    parts = {n: (c, si) for n, (c, si) in g_parts.items()}
    for n, (an, bn) in ((n, (cos_syms[n], sin_syms[n])) for n in cos_syms):
        # x'' = nu^2 d^2x/dtheta^2: -nu^2 n^2 times each harmonic
        c, si = parts.get(n, (sp.Integer(0), sp.Integer(0)))
        parts[n] = (
            c - nu**2 * n**2 * an,
            si - (nu**2 * n**2 * bn if ansatz.has(bn) else 0),
        )
    for n, (c, si) in trig_harmonics(sp.expand(forcing), theta).items():
        c0_, s0_ = parts.get(n, (sp.Integer(0), sp.Integer(0)))
        parts[n] = (c0_ - c, s0_ - si)
    eqs: list[sp.Expr] = []
    fourier: dict[str, sp.Expr] = {}
    zero = (sp.Integer(0), sp.Integer(0))
    if bias:
        eqs.append(parts.get(0, zero)[0])
        fourier["g mean"] = g_parts.get(0, zero)[0]
    for n in cos_syms:
        c, s = parts.get(n, zero)
        eqs.append(c)
        fourier[f"g cos {n}"] = g_parts.get(n, zero)[0]
        if not conservative:
            eqs.append(s)
            fourier[f"g sin {n}"] = g_parts.get(n, zero)[1]
        elif sp.expand(s) != 0:  # pragma: no cover - a conservative even orbit has none
            raise PerturbError(f"sine component {s} of a conservative oscillation")
    if len(eqs) != len(unknowns):  # pragma: no cover - guarded by the construction
        raise PerturbError(f"{len(eqs)} equations for {len(unknowns)} unknowns")
    dropped = sorted(
        n
        for n, (c, si) in parts.items()
        if n not in cos_syms and (n or not bias) and (c, si) != (0, 0)
    )
    base = sp.Eq(theta, w * t / m) if m > 1 else sp.Eq(theta, w * t)
    steps = (
        Step("Equation of motion", (osc.equation,)),
        Step(
            "Ansatz",
            (sp.Eq(x, ansatz), base),
            f"Harmonics {', '.join(str(h) for h in hs)} of the "
            + ("forcing frequency" if forced else "unknown frequency $\\omega$")
            + (" and a bias" if bias else "")
            + (
                "; a free conservative oscillation is even in time, so only cosines"
                if conservative
                else ("; phase condition $b_1 = 0$" if not forced else "")
            )
            + ".",
        ),
        Step(
            "Substitution",
            (sp.Eq(sp.Symbol(x.name + "''"), nu**2 * sp.diff(ansatz, theta, 2)),),
            "The residual $x'' + g - f(t)$ is a trigonometric polynomial in $\\theta$; its "
            "components are read off exactly.",
        ),
        Step(
            "Balance of the harmonics in the set",
            tuple(sp.Eq(sp.Integer(0), sp.expand(e), evaluate=False) for e in eqs),
            "Components at the other harmonics of $\\theta$ ("
            + ", ".join(map(str, dropped))
            + ") are the truncation error and are dropped."
            if dropped
            else "",
        ),
    )
    return Approximation(
        oscillator=osc,
        method="hb",
        options={
            "harmonics": int(max(cos_syms)),
            "set": tuple(str(h) for h in hs),
            "bias": bias,
            "m": m,
        },
        unknowns=tuple(unknowns),
        residuals=tuple(sp.expand(e) for e in eqs),
        waveform=ansatz.xreplace({theta: tau / m}),
        tau=tau,
        frequency=w,
        amplitude=amplitude,
        fourier=MappingProxyType(fourier),
        steps=steps,
    )


# -------------------------------------------------------------------- amplitude series --
@dataclass(frozen=True)
class BackboneSeries:
    """A free conservative harmonic-balance result expanded in its amplitude.

    Attributes
    ----------
    amplitude
        The expansion variable (the fundamental's amplitude).
    frequency, frequency_squared
        ``omega`` and ``omega**2`` to ``O(amplitude**order)``.
    unknowns
        Every other unknown to the same order.
    order
        The highest power kept.
    """

    amplitude: sp.Symbol
    frequency: sp.Expr
    frequency_squared: sp.Expr
    unknowns: Mapping[sp.Symbol, sp.Expr]
    order: int


def backbone_series(approximation: Approximation, order: int = 2) -> BackboneSeries:
    r"""Expand a free conservative harmonic-balance result in powers of its amplitude ``a``.

    Every unknown ``u`` (bias, higher harmonics) is written ``sum_{k=1}^{order} u_k a^k`` and
    ``omega^2 = omega_0^2 + sum_k w_k a^k`` with ``omega_0^2`` the linear stiffness; at each
    power of ``a`` the residuals are linear in ``(u_k, w_k)`` (the fundamental's equation is
    first divided by its leading power), which are solved in turn. This is where harmonic
    balance meets Lindstedt–Poincaré: with a bias and the second harmonic,
    ``omega = omega_0 [1 + (9 alpha3 omega_0^2 - 10 alpha2^2) a^2 / (24 omega_0^4)]``.

    Raises
    ------
    PerturbError
        If ``approximation`` is not a free conservative result of :func:`harmonic_balance`,
        or a linear system at some order is singular (an internal resonance).
    """
    approx = approximation
    A, w = approx.amplitude, approx.frequency
    if (
        approx.method != "hb"
        or A is None
        or w not in approx.unknowns
        or A in approx.unknowns
        or int(order) < 1
    ):
        raise PerturbError(
            f"backbone_series expands free conservative harmonic-balance results (amplitude "
            f"given, frequency unknown) to order >= 1; got {approx.label} with unknowns "
            f"{approx.unknowns}, order {order}"
        )
    order = int(order)
    W0 = approx.oscillator.linear_stiffness
    if W0 == 0:
        raise PerturbError(
            f"model {approx.oscillator.name!r} has no linear stiffness: its frequency is not a "
            "power series in the amplitude about a = 0"
        )
    others = [u for u in approx.unknowns if u != w]
    ucoef = {u: [sp.Dummy(f"{u.name}_{k}") for k in range(1, order + 1)] for u in others}
    wcoef = [sp.Dummy(f"w_{k}") for k in range(1, order + 1)]
    W = W0 + sp.Add(*(wk * A ** (k + 1) for k, wk in enumerate(wcoef)))
    subs = {u: sp.Add(*(c * A ** (k + 1) for k, c in enumerate(cs))) for u, cs in ucoef.items()}
    subs[w] = sp.sqrt(W)
    polys = []
    for r in approx.residuals:
        e = sp.expand(r.xreplace(subs))
        try:
            polys.append(sp.Poly(e, A))
        except sp.PolynomialError as exc:
            raise PerturbError(f"residual {r} is not polynomial in {A} and {w}**2") from exc
    lowest = []
    for p in polys:
        powers = sorted(mon[0] for mon, c in p.terms() if sp.expand(c) != 0)
        if not powers:
            raise PerturbError("a residual vanishes identically")
        lowest.append(powers[0])
    known: dict[sp.Symbol, sp.Expr] = {}
    for k in range(1, order + 1):
        level = [cs[k - 1] for cs in ucoef.values()] + [wcoef[k - 1]]
        eqs = [
            sp.expand(p.coeff_monomial(A ** (lo + k - 1)).xreplace(known))
            for p, lo in zip(polys, lowest, strict=True)
        ]
        sol = sp.linsolve(eqs, level)
        if not sol or len(sol) != 1:
            raise PerturbError(f"no unique solution at order {k} (internal resonance?)")
        (values,) = sol
        if any(val.has(*level) for val in values):
            raise PerturbError(f"the order-{k} equations are singular (internal resonance?)")
        known.update({s: sp.simplify(val) for s, val in zip(level, values, strict=True)})
    W_series = sp.expand(W.xreplace(known))
    omega = sp.series(sp.sqrt(W_series), A, 0, order + 1).removeO()
    omega = sp.expand(sp.powdenest(omega, force=True))
    return BackboneSeries(
        amplitude=A,
        frequency=omega,
        frequency_squared=W_series,
        unknowns=MappingProxyType({u: sp.expand(subs[u].xreplace(known)) for u in others}),
        order=order,
    )
