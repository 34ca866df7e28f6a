r"""Modified Lindstedt–Poincaré method (Cheung, Chen & Lau 1991), any order, free or forced.

For ``x'' + mu x' + f(x) = F cos(Omega t)`` (``mu = F = 0`` for the free conservative case)
split the restoring force about a reference frequency, :math:`f(x) = \omega_0^2 x + g(x)`
(default :math:`\omega_0^2`: the linear stiffness, or the mean outer slope of a
piecewise-linear force — 1 for the Zou–Nagarajaiah ``nsd`` model, whose paper writes
:math:`k = 1 - \varepsilon\bar k`). With :math:`\tau = \Omega t`,

.. math::

    \Omega^2 x'' + \mu\Omega x' + \omega_0^2 x + g(x) = F\cos\tau .

The damping, ``g`` and ``F`` are :math:`O(\varepsilon)`; expand
:math:`\Omega^2 = \omega_0^2 + \varepsilon\omega_1 + \varepsilon^2\omega_2 + \dots` and trade
:math:`\varepsilon` for the parameter that stays below 1 however large the nonlinearity,

.. math::

    \alpha = \frac{\varepsilon\omega_1}{\omega_0^2 + \varepsilon\omega_1}, \qquad
    \Omega^2 = \omega_0^2\,\frac{1 + \delta_2\alpha^2 + \delta_3\alpha^3 + \dots}{1 - \alpha}.

Only :math:`\nu = \varepsilon\omega_1` (the first-order shift of :math:`\Omega^2`) appears, and
multiplying by :math:`(1-\alpha)/\omega_0^2 = \alpha/\nu` gives the equation exactly linear in
:math:`\alpha` apart from the :math:`\delta`'s,

.. math::

    (1 + \delta_2\alpha^2 + \dots)\,x'' + x
      + \alpha\Big[\frac{\mu\Omega}{\nu}x' - x + \frac{g(x)}{\nu} - \frac{F}{\nu}\cos\tau\Big] = 0,

solved with :math:`x = x_0 + \alpha x_1 + \dots`, :math:`x_0 = A\cos\psi`,
:math:`\psi = \tau + \varphi` (the phase convention of Zou & Nagarajaiah), and at order
:math:`\alpha^n`

.. math::

    x_n'' + x_n = -\sum_{j=2}^{n}\delta_j x_{n-j}'' - \frac{\mu\Omega}{\nu}x_{n-1}' + x_{n-1}
      - \frac{1}{\nu}[\alpha^{n-1}]\,g(X) + [n = 1]\,\frac{F}{\nu}\cos(\psi - \varphi).

Secular conditions. Order 1: the :math:`\cos\psi` and :math:`\sin\psi` coefficients give

.. math::

    \nu A - \hat g_1(A) + F\cos\varphi = 0, \qquad \mu\Omega A + F\sin\varphi = 0,

(:math:`\hat g_1` the first Fourier coefficient of :math:`g(A\cos\psi)`); free: :math:`\nu =
\hat g_1/A`. With :math:`\nu = \Omega^2 - \omega_0^2` (first order) these are Zou–Nagarajaiah
eqs. (54)–(55) times :math:`\varepsilon`, and :math:`x_0 + \alpha x_1` is their eq. (59)
(:math:`\alpha/\nu = 1/\Omega^2`). Order :math:`n \ge 2`: the :math:`\cos\psi` coefficient
fixes :math:`\delta_n` (it enters as :math:`\delta_n A`); the :math:`\sin\psi` coefficients
(absent for free systems and at order 2) are summed with the first-order one,
:math:`\sum_n \alpha^{n-1}\nu S_n = 0`, which fixes the phase. The forced residuals at order
:math:`N \ge 2` are therefore

.. math::

    (\omega_0^2 + \nu)\Big(1 + \sum_{n\ge2}\delta_n\alpha^n\Big) - \Omega^2 = 0,\qquad
    \mu\Omega A + F\sin\varphi + \sum_{n\ge2}\alpha^{n-1}\nu S_n = 0,

with :math:`\nu(A, \varphi) = (\hat g_1 - F\cos\varphi)/A` and
:math:`\alpha = \nu/(\omega_0^2 + \nu)`. Everything is written with
:math:`\beta = \alpha/\nu = 1/(\omega_0^2+\nu)` so that nothing is singular where
:math:`\nu = 0`.

Piecewise-linear ``g`` enter through the closed-form ramp/step/Dirac Fourier coefficients of
:mod:`perturb.fourier.symbols` (the Taylor terms :math:`g^{(k)}(x_0)` are distributions along
:math:`x_0 = A\cos\psi`: steps at order 2, Dirac deltas at order 3 — eq. (48) of the paper,
whose Dirac terms :math:`(x_0 \mp 1)\,\delta(x_0 \mp 1)` vanish identically for the
continuous ``nsd`` force), truncated at ``harmonics``.
"""

from __future__ import annotations

from types import MappingProxyType
from typing import Any

import sympy as sp

from perturb.approximation import Approximation, Step
from perturb.errors import ModelError, ParameterError
from perturb.fourier.symbols import DiracCoefficient, RampCoefficient, StepCoefficient
from perturb.methods.applicability import check_order, require_centred
from perturb.methods.caveats import states_caveats
from perturb.methods.series import (
    ONE,
    PWL_MAX_ORDER,
    ZERO,
    Expansion,
    LaurentPolynomial,
    Series,
    check_options,
    closed_form_step,
    derivation_step,
    equation,
    free_symbol,
    is_short,
    lift,
    method_dummy,
    omega0_coefficient,
    series_at_zero,
    series_combine,
    series_derivative,
    series_solve,
    series_to_sympy,
    split_model,
    tidy_coefficient,
    vanishes,
)
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import real_symbol

__all__ = ["modified_lindstedt"]


def _forcing(osc: Oscillator) -> tuple[sp.Expr, sp.Expr] | None:
    """``(F, Omega)`` of a single forcing harmonic ``F cos(Omega t)``, or None if free."""
    live = [h for h in osc.forcing.harmonics if not vanishes(h.amplitude, osc)]
    if not live:
        return None
    if len(live) > 1:
        raise ModelError(
            f"the modified Lindstedt-Poincare method takes one forcing harmonic; model "
            f"{osc.name!r} has {' + '.join(str(h) for h in live)}"
        )
    h = live[0]
    if h.phase != 0:
        raise ModelError(
            f"forcing {h} of model {osc.name!r}: expected F*cos(Omega*t) with no phase (shift "
            "the time origin)"
        )
    if not isinstance(h.frequency, sp.Symbol):
        raise ModelError(
            f"the forcing frequency of model {osc.name!r} is {h.frequency}: expected a single "
            "parameter symbol (e.g. Omega) to sweep"
        )
    return h.amplitude, h.frequency


def _readable_difference(A: sp.Symbol, W: sp.Expr, f1: sp.Expr) -> sp.Expr:
    """``A W - f1`` for display, as a person writes it: collected in ``A`` and the Fourier
    coefficient functions, each coefficient factored with its brackets' constant positive,
    e.g. ``A(Omega**2 - k) - 2(1 - k) a^R_1`` for the negative-stiffness model."""
    e = sp.expand(A * W - f1)
    funcs = sorted(
        e.atoms(StepCoefficient, RampCoefficient, DiracCoefficient), key=sp.default_sort_key
    )
    collected = sp.collect(e, [A, *funcs], evaluate=False)
    terms = []
    for key in sorted(collected, key=lambda k: (not k.has(A), sp.default_sort_key(k))):
        c = sp.factor_terms(collected[key])
        sign, factors = 1, []
        for f in sp.Mul.make_args(c):
            if isinstance(f, sp.Add) and f.as_coeff_add()[0].is_negative:
                sign, f = -sign, -f
            factors.append(f)
        numbers = [f for f in factors if f.is_number]
        coeff = sign * sp.Mul(*numbers)
        rest = [f for f in factors if not f.is_number]
        if coeff == 1:
            terms.append(sp.Mul(*rest, key, evaluate=False) if rest else key)
        else:
            terms.append(sp.Mul(coeff, *rest, key, evaluate=False))
    return sp.Add(*terms, evaluate=False)


@states_caveats
def modified_lindstedt(
    oscillator: Oscillator,
    order: int = 1,
    *,
    amplitude: str = "first_harmonic",
    omega0: float | sp.Expr | str | None = None,
    harmonics: int = 15,
) -> Approximation:
    r"""Modified Lindstedt–Poincaré (α-transformation) approximation to ``order``.

    Parameters
    ----------
    oscillator
        ``x'' + mu x' + f(x) = F cos(Omega t)`` with ``f`` polynomial and/or piecewise linear;
        either free and conservative (``mu`` and ``F`` absent or with value 0) or forced by
        one harmonic (``Omega`` a parameter symbol), damped or not.
    order
        Highest power of :math:`\alpha` (>= 1). Polynomial forces: any order; piecewise-linear
        forces: up to :data:`PWL_MAX_ORDER`.
    amplitude
        Free systems: ``"first_harmonic"`` (default; every :math:`x_n` is free of
        :math:`\cos\psi`) or ``"initial"`` (``A = x(0)``). Forced systems: only
        ``"first_harmonic"``.
    omega0
        Reference linear frequency (default: square root of the linear stiffness plus the mean
        outer slope of a piecewise-linear part).
    harmonics
        Highest harmonic kept for piecewise-linear forces (the paper's figures use 15, i.e.
        its eq. (60) with n <= 7).

    Returns
    -------
    Approximation
        Free: ``unknowns = (A,)``, ``backbone`` :math:`\Omega(A)`, ``waveform`` in
        :math:`\tau = \Omega t`. Forced: ``unknowns = (A, phi)`` with
        :math:`x = A\cos(\tau + \varphi) + \dots`, ``residuals`` (eqs. (54)–(55) of Zou &
        Nagarajaiah at first order); at first order also ``frequency_polynomial`` (quadratic
        in :math:`\Omega^2`), ``phase_from`` and the averaged ``slow_flow``, so
        :func:`perturb.numeric.amplitude.approximation_response` traces every branch.

    Raises
    ------
    ModelError
        Free damped systems (no periodic orbit), several forcing harmonics, velocity or
        parametric terms, non-polynomial smooth terms, non-positive reference stiffness, a
        static load or a force whose piecewise-linear part is not odd (its orbit has a mean;
        the message names what applies).
    ParameterError
        Bad options, ``amplitude="initial"`` for a forced system, a piecewise-linear force
        above :data:`PWL_MAX_ORDER`, an order above
        :data:`~perturb.methods.applicability.ORDER_LIMITS` ``["mlp"]``.
    """
    osc = oscillator
    order = check_order("mlp", check_options(order, amplitude, harmonics))
    if osc.velocity != 0 or osc.parametric != 0:
        raise ModelError(
            f"the modified Lindstedt-Poincare method covers x'' + mu x' + f(x) = F cos(Omega t); "
            f"model {osc.name!r} also has {osc.velocity + osc.parametric}"
        )
    forced = _forcing(osc)
    damped = not vanishes(osc.damping, osc)
    if forced is None and damped:
        raise ModelError(
            f"model {osc.name!r} is free and damped ({osc.damping}): it has no periodic orbit "
            "to expand; give the damping the value 0 or add forcing"
        )
    if forced is not None and amplitude != "first_harmonic":
        raise ParameterError(
            f"amplitude = {amplitude!r} is for free systems; a forced response is "
            "parametrised by its first-harmonic amplitude and phase"
        )
    # a static load: the alpha-expansion gives the mean as F0/Omega**2 instead of F0/omega0**2
    # (the series of 1/(1 - alpha) cut at the first term), even on a linear oscillator;
    # a one-sided piecewise-linear force: its mean is of order one, not a correction
    require_centred(osc, "the modified Lindstedt-Poincare method (mlp)")
    model = split_model(osc, omega0)
    if model.ramps and order > PWL_MAX_ORDER:
        raise ParameterError(
            f"order = {order} for the piecewise-linear model {osc.name!r}: expected at most "
            f"{PWL_MAX_ORDER} (higher orders need products of whole truncated series)"
        )
    w0, w2 = model.w0, model.w2
    w0_lp = omega0_coefficient(w0)
    w2_lp = w0_lp * w0_lp
    nmax = harmonics if model.ramps else None
    force = model.force

    A = sp.Symbol("A", positive=True)
    tau = real_symbol("tau")
    psi = real_symbol("psi")
    phi = real_symbol("phi")
    nu = method_dummy("nu")
    alpha = method_dummy("alphahat" if "alpha" in osc.params else "alpha")
    deltas = [None, None] + [method_dummy(f"delta_{n}") for n in range(2, order + 1)]
    if forced is not None:
        F, Omega = forced
        mu = osc.damping if damped else sp.Integer(0)
    else:
        F, Omega, mu = sp.Integer(0), free_symbol(osc, "omega"), sp.Integer(0)
    eps, om1, om2 = method_dummy("varepsilon"), method_dummy("omega_1"), method_dummy("omega_2")
    cphi, sphi = sp.cos(phi), sp.sin(phi)
    inv_nu = LaurentPolynomial.atom(nu, -1)
    damp_lp = lift(mu) * lift(Omega) * inv_nu  # mu Omega / nu
    A_lp = LaurentPolynomial.atom(A)

    exp = Expansion({1: (A_lp, ZERO)}, A, nmax)
    xf = [sp.Function(f"x_{n}") for n in range(order + 1)]
    xpp = real_symbol(osc.x.name + "''")
    g_expr = model.g_written(osc)
    gfun = sp.Function("g")
    steps: list[Step] = [
        derivation_step("Equation of motion", (osc.equation,)),
        derivation_step(
            "Split of the restoring force",
            (
                equation(gfun(osc.x), g_expr),
                equation(xpp + mu * osc.v + w2 * osc.x + gfun(osc.x), F * sp.cos(Omega * osc.t)),
            ),
            "The restoring force is a linear reference term plus the remainder $g$"
            + (
                " (the reference stiffness is the mean stiffness of the outer segments)"
                if model.ramps and model.default_w0
                else ""
            )
            + ". The damping, $g$ and the forcing are taken small, of order $\\varepsilon$.",
        ),
        derivation_step(
            "Alpha-transformation",
            (
                equation(tau, Omega * osc.t),
                equation(Omega**2, w2 + eps * om1 + eps**2 * om2 + sp.Symbol("...")),
                equation(nu, eps * om1),
                equation(alpha, eps * om1 / (w2 + eps * om1)),
                equation(alpha, nu / (w2 + nu)),
                equation(
                    Omega**2,
                    w2
                    * (1 + sp.Add(*(deltas[n] * alpha**n for n in range(2, order + 1))))
                    / (1 - alpha),
                ),
            ),
            "Time is scaled by the response frequency and its square expanded in "
            "$\\varepsilon$. The first-order shift $\\nu$ defines the new expansion parameter "
            "$\\alpha$ (Cheung, Chen and Lau), which stays below one however strong the "
            "nonlinearity; the higher shifts become the coefficients $\\delta_n$.",
        ),
        derivation_step(
            "Transformed equation and expansion",
            (
                equation(
                    (1 + sp.Add(*(deltas[n] * alpha**n for n in range(2, order + 1))))
                    * sp.Derivative(osc.x, tau, 2)
                    + osc.x
                    + alpha
                    * (
                        mu * Omega / nu * sp.Derivative(osc.x, tau)
                        - osc.x
                        + gfun(osc.x) / nu
                        - F / nu * sp.cos(tau)
                    ),
                    0,
                ),
                equation(osc.x, sp.Add(*(alpha**n * xf[n](tau) for n in range(order + 1)))),
            ),
            "Dividing by the squared frequency at first order, $\\omega_0^2 + \\nu$, leaves an "
            "equation linear in $\\alpha$ apart from the $\\delta_n$; $x$ is expanded in powers "
            "of $\\alpha$.",
        ),
        derivation_step(
            "Order zero in $\\alpha$",
            (
                equation(sp.Derivative(xf[0](tau), tau, 2) + xf[0](tau), 0),
                equation(xf[0](tau), A * sp.cos(psi)),
                equation(psi, tau + phi),
            ),
            "The amplitude $A$ is "
            + (
                "the initial value $x(0)$."
                if amplitude == "initial"
                else "that of the first harmonic."
            )
            + ("" if forced else " The phase of a free oscillation is arbitrary and set to zero."),
        ),
    ]
    g0 = exp.compose(force, 0)
    g1 = g0.get(1, (ZERO, ZERO))[0]
    ghat = sp.Function("ghat_1")(A)
    fourier = {f"g_{n}": (2 * c if n == 0 else c).to_sympy() for n, (c, _) in g0.items()}
    fourier["f_1"] = (w2_lp * A_lp + g1).to_sympy()
    cf = closed_form_step(ghat, g1.to_sympy(), "First harmonic of $g$ in closed form")
    steps.append(
        derivation_step(
            "Fourier coefficients of $g$ along the generating solution",
            (equation(ghat, tidy_coefficient(g1)),),
            "$g(A\\cos\\psi)$ is expanded in $\\cos n\\psi$; piecewise-linear terms enter "
            "through their closed-form ramp and step coefficients, never through a Taylor "
            "series.",
        )
    )
    if cf is not None:
        steps.append(cf)

    delta_val: dict[int, LaurentPolynomial] = {}
    sines: dict[int, LaurentPolynomial] = {}
    first: tuple[LaurentPolynomial, LaurentPolynomial] | None = None
    for n in range(1, order + 1):
        terms: list[tuple[Any, Series]] = [(1, exp.x[n - 1]), (-inv_nu, exp.compose(force, n - 1))]
        if damped:
            terms.append((-damp_lp, series_derivative(exp.x[n - 1])))
        for j in range(2, n):
            terms.append((-delta_val[j], series_derivative(exp.x[n - j], 2)))
        if n == 1 and forced is not None:
            # (F/nu) cos(psi - phi) = (F/nu)(cos phi cos psi + sin phi sin psi)
            fl = lift(F) * inv_nu
            terms.append((fl, {1: (LaurentPolynomial.atom(cphi), LaurentPolynomial.atom(sphi))}))
        rhs = series_combine(*terms)
        c1, s1 = rhs.get(1, (ZERO, ZERO))
        shown = series_to_sympy(rhs, psi, tidy=True)
        if n == 1:
            first = (c1, s1)
            if forced is None:
                if s1:
                    raise ModelError(f"sine secular term {s1.to_sympy()}: not conservative")
                conditions = (equation(nu, tidy_coefficient(g1 / A_lp)),)
                note = (
                    "No secular term: the coefficient of $\\cos\\psi$ vanishes, which gives $\\nu$."
                )
            else:
                conditions = (
                    equation(tidy_coefficient(c1 * LaurentPolynomial.atom(nu)), 0),
                    equation(tidy_coefficient(s1 * LaurentPolynomial.atom(nu)), 0),
                )
                note = (
                    "No secular terms: the coefficients of $\\cos\\psi$ and $\\sin\\psi$ vanish"
                    + (
                        ". Times $\\nu$, these are Zou and Nagarajaiah's eqs. (54) and (55) for "
                        "their model, without the bookkeeping parameter."
                        if model.ramps
                        else "."
                    )
                )
        else:
            # the unknown enters as -delta_n x_0'' = delta_n A cos(psi)
            delta_val[n] = -c1 / A_lp
            if s1:
                sines[n] = s1
                if forced is None:
                    raise ModelError(f"sine secular term {s1.to_sympy()}: not conservative")
            conditions = (equation(deltas[n], tidy_coefficient(delta_val[n])),)
            note = (
                "No secular term: the coefficient of $\\cos\\psi$ vanishes, which gives "
                f"$\\delta_{n}$"
                + (
                    "; the coefficient of $\\sin\\psi$ joins the phase condition."
                    if n in sines
                    else "."
                )
            )
        xn = series_solve(rhs)
        if amplitude == "initial":
            at0 = series_at_zero(xn)
            if at0:
                xn = series_combine((1, xn), (-at0, {1: (ONE, ZERO)}))
        exp.push(xn)
        shown_delta = deltas[n] * A * sp.cos(psi) if n >= 2 else 0
        steps.append(
            derivation_step(
                f"Order {n} in $\\alpha$",
                (
                    equation(sp.Derivative(xf[n](tau), tau, 2) + xf[n](tau), shown + shown_delta),
                    *conditions,
                    equation(xf[n](tau), series_to_sympy(xn, psi, tidy=True)),
                ),
                note,
            )
        )

    assert first is not None
    # alpha^n x_n = beta^n (nu^n x_n), beta = alpha/nu = 1/(omega_0^2 + nu): nu^n x_n is a
    # polynomial in nu, so nothing is singular where nu = 0
    beta = 1 / (w2 + nu)
    scaled: list[Series] = []
    for n in range(1, order + 1):
        nun = LaurentPolynomial.atom(nu, n)
        scaled.append({m: (c * nun, s * nun) for m, (c, s) in exp.x[n].items()})
        assert all(min(v.degree(nu)[0] for v in cs) >= 0 for cs in scaled[-1].values())
    corr_terms = [
        beta**n * (delta_val[n] * LaurentPolynomial.atom(nu, n)).to_sympy() for n in delta_val
    ]
    freq_factor = 1 + sp.Add(*corr_terms)  # 1 + sum delta_n alpha^n

    def waveform_in(psi_value: sp.Expr, tidy: bool = False) -> sp.Expr:
        conv = tidy_coefficient if tidy else LaurentPolynomial.to_sympy
        out = A * sp.cos(psi_value)
        for n, ser in enumerate(scaled, start=1):
            for m, (c, s) in sorted(ser.items()):
                trig = conv(c) * sp.cos(m * psi_value) + conv(s) * sp.sin(m * psi_value)
                out += beta**n * trig
        return out

    def shown_wave(psi_value: sp.Expr, reps: dict | None = None) -> sp.Equality:
        """The waveform for the text: explicit when short, else as the sum of the x_n."""
        terms = sum(len(c.t) + len(s.t) for ser in scaled for c, s in ser.values())
        if terms <= 60:
            explicit = waveform_in(psi_value, tidy=True).xreplace(reps or {})
            if is_short(explicit):
                return equation(osc.x, explicit)
        return equation(osc.x, sp.Add(*(alpha**n * xf[n](tau) for n in range(order + 1))))

    options: dict[str, Any] = {"order": order, "amplitude": amplitude, "omega0": w0}
    hmax = max([1] + [m for ser in scaled for m in ser])
    options["harmonics"] = hmax
    f1 = fourier["f_1"]
    g1_sym = g1.to_sympy()

    if forced is None:
        nu_value = g1_sym / A
        backbone = sp.sqrt((w2 + nu_value) * freq_factor.xreplace({nu: nu_value}))
        waveform = waveform_in(tau).xreplace({nu: nu_value})
        alpha_value = nu_value / (w2 + nu_value)
        shown_deltas = []
        for n, dv in delta_val.items():
            value = dv.to_sympy().xreplace({nu: nu_value})
            if not model.ramps:
                value = sp.factor(sp.cancel(value))
            shown_deltas.append(equation(deltas[n], value))
        steps.append(
            derivation_step(
                "Result",
                (
                    equation(nu, tidy_coefficient(g1 / A_lp)),
                    equation(alpha, sp.factor(alpha_value) if not model.ramps else alpha_value),
                    *shown_deltas,
                    equation(
                        Omega,
                        w0
                        * sp.sqrt(
                            (1 + sp.Add(*(deltas[n] * alpha**n for n in delta_val))) / (1 - alpha)
                        ),
                    ),
                    shown_wave(tau),
                ),
                "The frequency-amplitude relation (backbone) of the free oscillation and its "
                "waveform; each term in a power of $\\alpha$ is written over powers of "
                "$\\omega_0^2 + \\nu$, which keeps it finite where $\\nu$ vanishes.",
            )
        )
        return Approximation(
            oscillator=osc,
            method="mlp",
            options=MappingProxyType(options),
            unknowns=(A,),
            residuals=(Omega - backbone,),
            waveform=waveform,
            tau=tau,
            frequency=Omega,
            amplitude=A,
            backbone=backbone,
            fourier=MappingProxyType(fourier),
            steps=tuple(steps),
        )

    c1, s1 = first
    cos_res = (c1 * LaurentPolynomial.atom(nu)).to_sympy()  # nu A - ghat_1 + F cos(phi)
    sin_res = (s1 * LaurentPolynomial.atom(nu)).to_sympy()  # mu Omega A + F sin(phi)
    if order == 1:
        # first order: nu = Omega^2 - omega_0^2 exactly, alpha/nu = 1/Omega^2 (eq. (59))
        residuals = (sp.expand(cos_res.xreplace({nu: Omega**2 - w2})), sin_res)
        waveform = waveform_in(tau + phi).xreplace({nu: Omega**2 - w2})
        W = Omega**2
        c0p, c1p, c2p = f1**2 - F**2, mu**2 * A**2 - 2 * A * f1, A**2
        slow_flow = (
            -(mu * Omega * A + F * sphi) / (2 * Omega),
            -(F * cphi - f1 + W * A) / (2 * Omega * A),
        )
        steps.append(
            derivation_step(
                "First-order result",
                (
                    equation(nu, Omega**2 - w2),
                    *(equation(r, 0) for r in residuals),
                    shown_wave(tau + phi, {nu: Omega**2 - w2}),
                ),
                "At first order the squared forcing frequency is $\\omega_0^2 + \\nu$, so "
                "$\\alpha/\\nu$ is one over the squared frequency: the waveform is Zou and "
                f"Nagarajaiah's eq. (59), here to harmonic ${hmax}$.",
            )
        )
        steps.append(
            derivation_step(
                "Frequency-amplitude equation and slow flow",
                (
                    equation(
                        sp.Add(
                            sp.Pow(_readable_difference(A, W, f1), 2, evaluate=False),
                            sp.Pow(sp.Mul(mu, Omega, A, evaluate=False), 2, evaluate=False),
                            evaluate=False,
                        ),
                        F**2,
                    ),
                    equation(c2p * W**2 + c1p * W + c0p, 0),
                    equation(sp.Derivative(A, osc.t), slow_flow[0]),
                    equation(sp.Derivative(phi, osc.t), slow_flow[1]),
                ),
                "Squaring and adding the two conditions eliminates the phase; the result is "
                "a quadratic in the squared frequency, with $f_1$ the first harmonic of the whole "
                "restoring force (the second equation): the same curve as "
                "single-harmonic balance. The slow flow comes from averaging the first-order "
                "ansatz; its fixed points are the two conditions above.",
            )
        )
        return Approximation(
            oscillator=osc,
            method="mlp",
            options=MappingProxyType(options),
            unknowns=(A, phi),
            residuals=residuals,
            waveform=waveform,
            tau=tau,
            frequency=Omega,
            slow_flow=slow_flow,
            amplitude=A,
            frequency_polynomial=(c0p, c1p, c2p),
            phase_from=(f1 - W * A, -mu * Omega * A),
            fourier=MappingProxyType(fourier),
            steps=tuple(steps),
        )

    # order >= 2: nu from the first-order cosine condition, the deltas from the higher ones,
    # the sine conditions summed into the phase equation
    nu_value = (g1_sym - F * cphi) / A
    phase_terms = [
        beta ** (n - 1) * (sv * LaurentPolynomial.atom(nu, n)).to_sympy()
        for n, sv in sorted(sines.items())
    ]
    residuals = (
        ((w2 + nu) * freq_factor - Omega**2).xreplace({nu: nu_value}),
        (sin_res + sp.Add(*phase_terms)).xreplace({nu: nu_value}),
    )
    waveform = waveform_in(tau + phi).xreplace({nu: nu_value})
    S = {n: sp.Symbol(f"S_{n}") for n in sines}
    steps.append(
        derivation_step(
            f"Order-{order} result",
            (
                equation(nu, nu_value),
                equation(alpha, nu / (w2 + nu)),
                equation(
                    Omega**2,
                    (w2 + nu) * (1 + sp.Add(*(deltas[n] * alpha**n for n in delta_val))),
                ),
                equation(
                    sin_res + sp.Add(*(alpha ** (n - 1) * nu * S[n] for n in sorted(sines))),
                    0,
                ),
                *(
                    equation(S[n], tidy_coefficient(sv))
                    for n, sv in sorted(sines.items())
                    if is_short(tidy_coefficient(sv), 30)
                ),
                shown_wave(tau + phi),
            ),
            "$\\nu$ follows from the first-order cosine condition and the $\\delta_n$ from the "
            "higher ones; the sine conditions of all orders ($S_n$, the coefficient of "
            "$\\sin\\psi$ at order $n$) summed fix the phase. Roots where $\\omega_0^2 + \\nu$ "
            "nearly vanishes ($\\alpha$ very large) are artefacts of the truncation.",
        )
    )
    return Approximation(
        oscillator=osc,
        method="mlp",
        options=MappingProxyType(options),
        unknowns=(A, phi),
        residuals=residuals,
        waveform=waveform,
        tau=tau,
        frequency=Omega,
        amplitude=A,
        fourier=MappingProxyType(fourier),
        steps=tuple(steps),
    )
