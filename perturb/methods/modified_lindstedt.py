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

from dataclasses import dataclass
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
    SplitModel,
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


@dataclass
class _Setup:
    """Everything the stages of the derivation share: the model split about
    :math:`\\omega_0`, the method's symbols and the expansion :math:`x = \\sum \\alpha^n x_n`
    as it grows."""

    osc: Oscillator
    order: int
    amplitude: str
    model: SplitModel
    forced: bool
    damped: bool
    A: sp.Symbol
    tau: sp.Symbol
    psi: sp.Symbol
    phi: sp.Symbol
    nu: sp.Dummy
    alpha: sp.Dummy
    deltas: list[Any]
    F: sp.Expr
    Omega: sp.Expr
    mu: sp.Expr
    eps: sp.Dummy
    om1: sp.Dummy
    om2: sp.Dummy
    inv_nu: LaurentPolynomial
    damp_lp: LaurentPolynomial
    A_lp: LaurentPolynomial
    w2_lp: LaurentPolynomial
    exp: Expansion
    xf: list[Any]

    @property
    def w0(self) -> sp.Expr:
        return self.model.w0

    @property
    def w2(self) -> sp.Expr:
        return self.model.w2


@dataclass
class _Orders:
    """What the orders :math:`\\alpha^1 \\dots \\alpha^N` determined: the first harmonic of
    :math:`g` (``g1``), the :math:`\\delta_n`, the sine coefficients :math:`S_n` (forced, order
    >= 2) and the first-order cosine/sine secular coefficients."""

    g1: LaurentPolynomial
    fourier: dict[str, sp.Expr]
    delta_val: dict[int, LaurentPolynomial]
    sines: dict[int, LaurentPolynomial]
    first: tuple[LaurentPolynomial, LaurentPolynomial]


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
    s = _setup(oscillator, order, amplitude, omega0, harmonics)
    steps = _transformation_steps(s) + _expansion_steps(s)
    orders = _solve_orders(s, steps)
    sol = _Solution(s, orders.delta_val)
    options: dict[str, Any] = {"order": s.order, "amplitude": amplitude, "omega0": s.w0}
    options["harmonics"] = sol.hmax
    if not s.forced:
        return _free_result(s, orders, sol, options, steps)
    if s.order == 1:
        return _forced_first_order_result(s, orders, sol, options, steps)
    return _forced_higher_order_result(s, orders, sol, options, steps)


def _setup(osc: Oscillator, order: int, amplitude: str, omega0: Any, harmonics: int) -> _Setup:
    """Check that the model is one the method covers, split its restoring force about
    :math:`\\omega_0` and introduce the method's symbols and the generating solution
    :math:`x_0 = A\\cos\\psi`."""
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
    w0_lp = omega0_coefficient(model.w0)
    A = sp.Symbol("A", positive=True)
    nu = method_dummy("nu")
    alpha = method_dummy("alphahat" if "alpha" in osc.params else "alpha")
    deltas = [None, None] + [method_dummy(f"delta_{n}") for n in range(2, order + 1)]
    if forced is not None:
        F, Omega = forced
        mu = osc.damping if damped else sp.Integer(0)
    else:
        F, Omega, mu = sp.Integer(0), free_symbol(osc, "omega"), sp.Integer(0)
    eps, om1, om2 = method_dummy("varepsilon"), method_dummy("omega_1"), method_dummy("omega_2")
    inv_nu = LaurentPolynomial.atom(nu, -1)
    A_lp = LaurentPolynomial.atom(A)
    return _Setup(
        osc=osc,
        order=order,
        amplitude=amplitude,
        model=model,
        forced=forced is not None,
        damped=damped,
        A=A,
        tau=real_symbol("tau"),
        psi=real_symbol("psi"),
        phi=real_symbol("phi"),
        nu=nu,
        alpha=alpha,
        deltas=deltas,
        F=F,
        Omega=Omega,
        mu=mu,
        eps=eps,
        om1=om1,
        om2=om2,
        inv_nu=inv_nu,
        damp_lp=lift(mu) * lift(Omega) * inv_nu,  # mu Omega / nu
        A_lp=A_lp,
        w2_lp=w0_lp * w0_lp,
        exp=Expansion({1: (A_lp, ZERO)}, A, harmonics if model.ramps else None),
        xf=[sp.Function(f"x_{n}") for n in range(order + 1)],
    )


def _transformation_steps(s: _Setup) -> list[Step]:
    """Derivation steps 1–3: the equation of motion, the split of the restoring force about
    :math:`\\omega_0^2 x` and the :math:`\\alpha`-transformation of :math:`\\Omega^2`."""
    osc, w2, alpha, deltas = s.osc, s.w2, s.alpha, s.deltas
    xpp = real_symbol(osc.x.name + "''")
    gfun = sp.Function("g")
    return [
        derivation_step("Equation of motion", (osc.equation,)),
        derivation_step(
            "Split of the restoring force",
            (
                equation(gfun(osc.x), s.model.g_written(osc)),
                equation(
                    xpp + s.mu * osc.v + w2 * osc.x + gfun(osc.x), s.F * sp.cos(s.Omega * osc.t)
                ),
            ),
            "The restoring force is a linear reference term plus the remainder $g$"
            + (
                " (the reference stiffness is the mean stiffness of the outer segments)"
                if s.model.ramps and s.model.default_w0
                else ""
            )
            + ". The damping, $g$ and the forcing are taken small, of order $\\varepsilon$.",
        ),
        derivation_step(
            "Alpha-transformation",
            (
                equation(s.tau, s.Omega * osc.t),
                equation(s.Omega**2, w2 + s.eps * s.om1 + s.eps**2 * s.om2 + sp.Symbol("...")),
                equation(s.nu, s.eps * s.om1),
                equation(alpha, s.eps * s.om1 / (w2 + s.eps * s.om1)),
                equation(alpha, s.nu / (w2 + s.nu)),
                equation(
                    s.Omega**2,
                    w2
                    * (1 + sp.Add(*(deltas[n] * alpha**n for n in range(2, s.order + 1))))
                    / (1 - alpha),
                ),
            ),
            "Time is scaled by the response frequency and its square expanded in "
            "$\\varepsilon$. The first-order shift $\\nu$ defines the new expansion parameter "
            "$\\alpha$ (Cheung, Chen and Lau), which stays below one however strong the "
            "nonlinearity; the higher shifts become the coefficients $\\delta_n$.",
        ),
    ]


def _expansion_steps(s: _Setup) -> list[Step]:
    """Derivation steps 4–5: the transformed equation, linear in :math:`\\alpha` apart from
    the :math:`\\delta_n`, the expansion :math:`x = \\sum\\alpha^n x_n` and its order zero,
    :math:`x_0 = A\\cos\\psi`."""
    osc, tau, alpha, xf, nu = s.osc, s.tau, s.alpha, s.xf, s.nu
    return [
        derivation_step(
            "Transformed equation and expansion",
            (
                equation(
                    (1 + sp.Add(*(s.deltas[n] * alpha**n for n in range(2, s.order + 1))))
                    * sp.Derivative(osc.x, tau, 2)
                    + osc.x
                    + alpha
                    * (
                        s.mu * s.Omega / nu * sp.Derivative(osc.x, tau)
                        - osc.x
                        + sp.Function("g")(osc.x) / nu
                        - s.F / nu * sp.cos(tau)
                    ),
                    0,
                ),
                equation(osc.x, sp.Add(*(alpha**n * xf[n](tau) for n in range(s.order + 1)))),
            ),
            "Dividing by the squared frequency at first order, $\\omega_0^2 + \\nu$, leaves an "
            "equation linear in $\\alpha$ apart from the $\\delta_n$; $x$ is expanded in powers "
            "of $\\alpha$.",
        ),
        derivation_step(
            "Order zero in $\\alpha$",
            (
                equation(sp.Derivative(xf[0](tau), tau, 2) + xf[0](tau), 0),
                equation(xf[0](tau), s.A * sp.cos(s.psi)),
                equation(s.psi, tau + s.phi),
            ),
            "The amplitude $A$ is "
            + (
                "the initial value $x(0)$."
                if s.amplitude == "initial"
                else "that of the first harmonic."
            )
            + (
                "" if s.forced else " The phase of a free oscillation is arbitrary and set to zero."
            ),
        ),
    ]


def _fourier_of_g(s: _Setup, steps: list[Step]) -> tuple[LaurentPolynomial, dict[str, sp.Expr]]:
    """Fourier coefficients of :math:`g(A\\cos\\psi)` along the generating solution (closed-form
    ramp/step coefficients for piecewise-linear terms); appends their derivation step and
    returns :math:`\\hat g_1` and the ``fourier`` field."""
    g0 = s.exp.compose(s.model.force, 0)
    g1 = g0.get(1, (ZERO, ZERO))[0]
    ghat = sp.Function("ghat_1")(s.A)
    fourier = {f"g_{n}": (2 * c if n == 0 else c).to_sympy() for n, (c, _) in g0.items()}
    fourier["f_1"] = (s.w2_lp * s.A_lp + g1).to_sympy()
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
    return g1, fourier


def _order_rhs(s: _Setup, n: int, delta_val: dict[int, LaurentPolynomial]) -> Series:
    """Right-hand side of :math:`x_n'' + x_n = \\dots` at order :math:`\\alpha^n`, collected by
    harmonic of :math:`\\psi` (the :math:`\\delta_n x_0''` term, unknown yet, left out)."""
    exp = s.exp
    terms: list[tuple[Any, Series]] = [
        (1, exp.x[n - 1]),
        (-s.inv_nu, exp.compose(s.model.force, n - 1)),
    ]
    if s.damped:
        terms.append((-s.damp_lp, series_derivative(exp.x[n - 1])))
    for j in range(2, n):
        terms.append((-delta_val[j], series_derivative(exp.x[n - j], 2)))
    if n == 1 and s.forced:
        # (F/nu) cos(psi - phi) = (F/nu)(cos phi cos psi + sin phi sin psi)
        fl = lift(s.F) * s.inv_nu
        cs = (LaurentPolynomial.atom(sp.cos(s.phi)), LaurentPolynomial.atom(sp.sin(s.phi)))
        terms.append((fl, {1: cs}))
    return series_combine(*terms)


def _first_order_conditions(
    s: _Setup, c1: LaurentPolynomial, s1: LaurentPolynomial, g1: LaurentPolynomial
) -> tuple[tuple[sp.Equality, ...], str]:
    """Secular conditions at order :math:`\\alpha^1`: free, :math:`\\nu = \\hat g_1/A`; forced,
    the :math:`\\cos\\psi` and :math:`\\sin\\psi` coefficients (Zou–Nagarajaiah (54)–(55))."""
    if not s.forced:
        if s1:
            raise ModelError(f"sine secular term {s1.to_sympy()}: not conservative")
        conditions = (equation(s.nu, tidy_coefficient(g1 / s.A_lp)),)
        note = "No secular term: the coefficient of $\\cos\\psi$ vanishes, which gives $\\nu$."
        return conditions, note
    conditions = (
        equation(tidy_coefficient(c1 * LaurentPolynomial.atom(s.nu)), 0),
        equation(tidy_coefficient(s1 * LaurentPolynomial.atom(s.nu)), 0),
    )
    note = "No secular terms: the coefficients of $\\cos\\psi$ and $\\sin\\psi$ vanish" + (
        ". Times $\\nu$, these are Zou and Nagarajaiah's eqs. (54) and (55) for "
        "their model, without the bookkeeping parameter."
        if s.model.ramps
        else "."
    )
    return conditions, note


def _higher_order_conditions(
    s: _Setup,
    n: int,
    c1: LaurentPolynomial,
    s1: LaurentPolynomial,
    delta_val: dict[int, LaurentPolynomial],
    sines: dict[int, LaurentPolynomial],
) -> tuple[tuple[sp.Equality, ...], str]:
    """Secular conditions at order :math:`\\alpha^n`, :math:`n \\ge 2`: the :math:`\\cos\\psi`
    coefficient fixes :math:`\\delta_n` (stored in ``delta_val``); a :math:`\\sin\\psi`
    coefficient (forced only) is kept in ``sines`` for the phase condition."""
    # the unknown enters as -delta_n x_0'' = delta_n A cos(psi)
    delta_val[n] = -c1 / s.A_lp
    if s1:
        sines[n] = s1
        if not s.forced:
            raise ModelError(f"sine secular term {s1.to_sympy()}: not conservative")
    conditions = (equation(s.deltas[n], tidy_coefficient(delta_val[n])),)
    note = (
        "No secular term: the coefficient of $\\cos\\psi$ vanishes, which gives "
        f"$\\delta_{n}$"
        + ("; the coefficient of $\\sin\\psi$ joins the phase condition." if n in sines else ".")
    )
    return conditions, note


def _solve_orders(s: _Setup, steps: list[Step]) -> _Orders:
    """Orders :math:`\\alpha^1 \\dots \\alpha^N`: collect by harmonic, impose the secular
    conditions, solve for :math:`x_n` (shifted to vanish at :math:`\\tau = 0` for
    ``amplitude="initial"``) and append one derivation step per order."""
    g1, fourier = _fourier_of_g(s, steps)
    delta_val: dict[int, LaurentPolynomial] = {}
    sines: dict[int, LaurentPolynomial] = {}
    first: tuple[LaurentPolynomial, LaurentPolynomial] | None = None
    tau, psi, xf = s.tau, s.psi, s.xf
    for n in range(1, s.order + 1):
        rhs = _order_rhs(s, n, delta_val)
        c1, s1 = rhs.get(1, (ZERO, ZERO))
        shown = series_to_sympy(rhs, psi, tidy=True)
        if n == 1:
            first = (c1, s1)
            conditions, note = _first_order_conditions(s, c1, s1, g1)
        else:
            conditions, note = _higher_order_conditions(s, n, c1, s1, delta_val, sines)
        xn = series_solve(rhs)
        if s.amplitude == "initial":
            at0 = series_at_zero(xn)
            if at0:
                xn = series_combine((1, xn), (-at0, {1: (ONE, ZERO)}))
        s.exp.push(xn)
        shown_delta = s.deltas[n] * s.A * sp.cos(psi) if n >= 2 else 0
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
    return _Orders(g1, fourier, delta_val, sines, first)


class _Solution:
    r"""Assembly of the solution: :math:`\alpha^n x_n = \beta^n (\nu^n x_n)` with
    :math:`\beta = \alpha/\nu = 1/(\omega_0^2 + \nu)`, and the frequency factor
    :math:`1 + \sum\delta_n\alpha^n`; :math:`\nu^n x_n` is a polynomial in :math:`\nu`, so
    nothing is singular where :math:`\nu = 0`."""

    def __init__(self, s: _Setup, delta_val: dict[int, LaurentPolynomial]) -> None:
        self.s = s
        nu = s.nu
        self.beta = 1 / (s.w2 + nu)
        self.scaled: list[Series] = []
        for n in range(1, s.order + 1):
            nun = LaurentPolynomial.atom(nu, n)
            self.scaled.append({m: (c * nun, sn * nun) for m, (c, sn) in s.exp.x[n].items()})
            assert all(min(v.degree(nu)[0] for v in cs) >= 0 for cs in self.scaled[-1].values())
        corr_terms = [
            self.beta**n * (delta_val[n] * LaurentPolynomial.atom(nu, n)).to_sympy()
            for n in delta_val
        ]
        self.freq_factor = 1 + sp.Add(*corr_terms)  # 1 + sum delta_n alpha^n
        self.hmax = max([1] + [m for ser in self.scaled for m in ser])

    def waveform_in(self, psi_value: sp.Expr, tidy: bool = False) -> sp.Expr:
        """:math:`x` with :math:`\\psi` = ``psi_value`` (coefficients tidied for display)."""
        conv = tidy_coefficient if tidy else LaurentPolynomial.to_sympy
        out = self.s.A * sp.cos(psi_value)
        for n, ser in enumerate(self.scaled, start=1):
            for m, (c, sn) in sorted(ser.items()):
                trig = conv(c) * sp.cos(m * psi_value) + conv(sn) * sp.sin(m * psi_value)
                out += self.beta**n * trig
        return out

    def shown_wave(self, psi_value: sp.Expr, reps: dict | None = None) -> sp.Equality:
        """The waveform for the text: explicit when short, else as the sum of the x_n."""
        s = self.s
        terms = sum(len(c.t) + len(sn.t) for ser in self.scaled for c, sn in ser.values())
        if terms <= 60:
            explicit = self.waveform_in(psi_value, tidy=True).xreplace(reps or {})
            if is_short(explicit):
                return equation(s.osc.x, explicit)
        return equation(s.osc.x, sp.Add(*(s.alpha**n * s.xf[n](s.tau) for n in range(s.order + 1))))


def _free_result(
    s: _Setup, o: _Orders, sol: _Solution, options: dict[str, Any], steps: list[Step]
) -> Approximation:
    """Free oscillation: :math:`\\nu = \\hat g_1/A` in the backbone
    :math:`\\Omega = \\omega_0\\sqrt{(1 + \\sum\\delta_n\\alpha^n)/(1 - \\alpha)}` and the
    waveform; the result step and the Approximation."""
    nu, w2, alpha, deltas = s.nu, s.w2, s.alpha, s.deltas
    nu_value = o.g1.to_sympy() / s.A
    backbone = sp.sqrt((w2 + nu_value) * sol.freq_factor.xreplace({nu: nu_value}))
    waveform = sol.waveform_in(s.tau).xreplace({nu: nu_value})
    alpha_value = nu_value / (w2 + nu_value)
    shown_deltas = []
    for n, dv in o.delta_val.items():
        value = dv.to_sympy().xreplace({nu: nu_value})
        if not s.model.ramps:
            value = sp.factor(sp.cancel(value))
        shown_deltas.append(equation(deltas[n], value))
    steps.append(
        derivation_step(
            "Result",
            (
                equation(nu, tidy_coefficient(o.g1 / s.A_lp)),
                equation(alpha, sp.factor(alpha_value) if not s.model.ramps else alpha_value),
                *shown_deltas,
                equation(
                    s.Omega,
                    s.w0
                    * sp.sqrt(
                        (1 + sp.Add(*(deltas[n] * alpha**n for n in o.delta_val))) / (1 - alpha)
                    ),
                ),
                sol.shown_wave(s.tau),
            ),
            "The frequency-amplitude relation (backbone) of the free oscillation and its "
            "waveform; each term in a power of $\\alpha$ is written over powers of "
            "$\\omega_0^2 + \\nu$, which keeps it finite where $\\nu$ vanishes.",
        )
    )
    return Approximation(
        oscillator=s.osc,
        method="mlp",
        options=MappingProxyType(options),
        unknowns=(s.A,),
        residuals=(s.Omega - backbone,),
        waveform=waveform,
        tau=s.tau,
        frequency=s.Omega,
        amplitude=s.A,
        backbone=backbone,
        fourier=MappingProxyType(o.fourier),
        steps=tuple(steps),
    )


def _forced_first_order_result(
    s: _Setup, o: _Orders, sol: _Solution, options: dict[str, Any], steps: list[Step]
) -> Approximation:
    """Forced, first order: :math:`\\nu = \\Omega^2 - \\omega_0^2` exactly, the two secular
    conditions as residuals, the waveform (Zou–Nagarajaiah eq. (59)), the frequency polynomial
    (phase eliminated, quadratic in :math:`\\Omega^2`) and the averaged slow flow."""
    A, nu, w2, Omega, mu, F = s.A, s.nu, s.w2, s.Omega, s.mu, s.F
    cphi, sphi = sp.cos(s.phi), sp.sin(s.phi)
    f1 = o.fourier["f_1"]
    c1, s1 = o.first
    cos_res = (c1 * LaurentPolynomial.atom(nu)).to_sympy()  # nu A - ghat_1 + F cos(phi)
    sin_res = (s1 * LaurentPolynomial.atom(nu)).to_sympy()  # mu Omega A + F sin(phi)
    # first order: nu = Omega^2 - omega_0^2 exactly, alpha/nu = 1/Omega^2 (eq. (59))
    residuals = (sp.expand(cos_res.xreplace({nu: Omega**2 - w2})), sin_res)
    waveform = sol.waveform_in(s.tau + s.phi).xreplace({nu: Omega**2 - w2})
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
                sol.shown_wave(s.tau + s.phi, {nu: Omega**2 - w2}),
            ),
            "At first order the squared forcing frequency is $\\omega_0^2 + \\nu$, so "
            "$\\alpha/\\nu$ is one over the squared frequency: the waveform is Zou and "
            f"Nagarajaiah's eq. (59), here to harmonic ${sol.hmax}$.",
        )
    )
    steps.append(_frequency_equation_step(s, f1, (c0p, c1p, c2p), slow_flow))
    return Approximation(
        oscillator=s.osc,
        method="mlp",
        options=MappingProxyType(options),
        unknowns=(A, s.phi),
        residuals=residuals,
        waveform=waveform,
        tau=s.tau,
        frequency=Omega,
        slow_flow=slow_flow,
        amplitude=A,
        frequency_polynomial=(c0p, c1p, c2p),
        phase_from=(f1 - W * A, -mu * Omega * A),
        fourier=MappingProxyType(o.fourier),
        steps=tuple(steps),
    )


def _frequency_equation_step(
    s: _Setup, f1: sp.Expr, poly: tuple[sp.Expr, sp.Expr, sp.Expr], slow_flow: tuple
) -> Step:
    """The derivation step of the first-order frequency-amplitude equation (the two secular
    conditions squared and added) and of the slow flow."""
    A, Omega, mu = s.A, s.Omega, s.mu
    W = Omega**2
    c0p, c1p, c2p = poly
    return derivation_step(
        "Frequency-amplitude equation and slow flow",
        (
            equation(
                sp.Add(
                    sp.Pow(_readable_difference(A, W, f1), 2, evaluate=False),
                    sp.Pow(sp.Mul(mu, Omega, A, evaluate=False), 2, evaluate=False),
                    evaluate=False,
                ),
                s.F**2,
            ),
            equation(c2p * W**2 + c1p * W + c0p, 0),
            equation(sp.Derivative(A, s.osc.t), slow_flow[0]),
            equation(sp.Derivative(s.phi, s.osc.t), slow_flow[1]),
        ),
        "Squaring and adding the two conditions eliminates the phase; the result is "
        "a quadratic in the squared frequency, with $f_1$ the first harmonic of the whole "
        "restoring force (the second equation): the same curve as "
        "single-harmonic balance. The slow flow comes from averaging the first-order "
        "ansatz; its fixed points are the two conditions above.",
    )


def _forced_higher_order_result(
    s: _Setup, o: _Orders, sol: _Solution, options: dict[str, Any], steps: list[Step]
) -> Approximation:
    """Forced, order >= 2: :math:`\\nu` from the first-order cosine condition, the
    :math:`\\delta_n` from the higher ones, the sine conditions of all orders summed into the
    phase equation; the result step and the Approximation."""
    A, nu, w2, Omega, alpha, phi = s.A, s.nu, s.w2, s.Omega, s.alpha, s.phi
    s1 = o.first[1]
    sin_res = (s1 * LaurentPolynomial.atom(nu)).to_sympy()  # mu Omega A + F sin(phi)
    nu_value = (o.g1.to_sympy() - s.F * sp.cos(phi)) / A
    phase_terms = [
        sol.beta ** (n - 1) * (sv * LaurentPolynomial.atom(nu, n)).to_sympy()
        for n, sv in sorted(o.sines.items())
    ]
    residuals = (
        ((w2 + nu) * sol.freq_factor - Omega**2).xreplace({nu: nu_value}),
        (sin_res + sp.Add(*phase_terms)).xreplace({nu: nu_value}),
    )
    waveform = sol.waveform_in(s.tau + phi).xreplace({nu: nu_value})
    S = {n: sp.Symbol(f"S_{n}") for n in o.sines}
    steps.append(
        derivation_step(
            f"Order-{s.order} result",
            (
                equation(nu, nu_value),
                equation(alpha, nu / (w2 + nu)),
                equation(
                    Omega**2,
                    (w2 + nu) * (1 + sp.Add(*(s.deltas[n] * alpha**n for n in o.delta_val))),
                ),
                equation(
                    sin_res + sp.Add(*(alpha ** (n - 1) * nu * S[n] for n in sorted(o.sines))),
                    0,
                ),
                *(
                    equation(S[n], tidy_coefficient(sv))
                    for n, sv in sorted(o.sines.items())
                    if is_short(tidy_coefficient(sv), 30)
                ),
                sol.shown_wave(s.tau + phi),
            ),
            "$\\nu$ follows from the first-order cosine condition and the $\\delta_n$ from the "
            "higher ones; the sine conditions of all orders ($S_n$, the coefficient of "
            "$\\sin\\psi$ at order $n$) summed fix the phase. Roots where $\\omega_0^2 + \\nu$ "
            "nearly vanishes ($\\alpha$ very large) are artefacts of the truncation.",
        )
    )
    return Approximation(
        oscillator=s.osc,
        method="mlp",
        options=MappingProxyType(options),
        unknowns=(A, phi),
        residuals=residuals,
        waveform=waveform,
        tau=s.tau,
        frequency=Omega,
        amplitude=A,
        fourier=MappingProxyType(o.fourier),
        steps=tuple(steps),
    )
