r"""Lindstedt–Poincaré method, any order, for free conservative oscillators.

For ``x'' + f(x) = 0`` the restoring force is split about a reference linear frequency
:math:`\omega_0` (by default the linear stiffness, or for a piecewise-linear force the mean of
its two outer slopes),

.. math::

    x'' + \omega_0^2 x + \varepsilon\, g(x) = 0, \qquad g(x) = f(x) - \omega_0^2 x,

with the bookkeeping parameter :math:`\varepsilon` set to 1 at the end (``scaling="uniform"``);
or, for polynomial forces, by amplitude, :math:`x \to \varepsilon x`, which gives the term of
degree :math:`m` the factor :math:`\varepsilon^{m-1}` (``scaling="amplitude"``: the
small-amplitude expansion of Nayfeh & Mook, in which quadratic terms act at second order).
With :math:`\tau = \omega t`,

.. math::

    \omega^2 x'' + \omega_0^2 x + \sum_j \varepsilon^j g_j(x) = 0,\qquad
    \omega = \omega_0 + \sum_{n\ge1}\varepsilon^n\omega_n,\qquad
    x = \sum_{n\ge0}\varepsilon^n x_n(\tau).

Order :math:`\varepsilon^0` gives :math:`x_0 = A\cos\tau`; order :math:`\varepsilon^n`

.. math::

    \omega_0^2 (x_n'' + x_n) = -\sum_{i=1}^{n} W_i\, x_{n-i}''
        - \sum_j [\varepsilon^{n-j}]\, g_j\Big(\sum_k \varepsilon^k x_k\Big),
    \qquad W_i = \sum_{p+q=i}\omega_p\omega_q ,

and the coefficient of :math:`\cos\tau` on the right must vanish (no secular term), which
fixes :math:`\omega_n` (it enters as :math:`2\omega_0\omega_n A\cos\tau`). The bracket is the
Taylor expansion :math:`\sum_k g^{(k)}(x_0)/k!\,[\varepsilon^{m}](x-x_0)^k`. For a polynomial
``g`` every factor is a finite trigonometric polynomial; for a piecewise-linear ``g`` the
factors :math:`g^{(k)}(A\cos\tau)` are distributions with closed-form Fourier series from
:mod:`perturb.fourier.symbols` — ramps for ``k = 0``; steps, and Dirac deltas where the force
jumps, for ``k = 1`` — never a Taylor series in ``x``, truncated at ``harmonics`` (orders up to
:data:`PWL_MAX_ORDER`).

Two amplitude conventions are offered because the higher coefficients depend on them:
``amplitude="first_harmonic"`` (default) keeps every :math:`x_n`, :math:`n \ge 1`, free of
:math:`\cos\tau`, so ``A`` is the amplitude of the first harmonic; ``amplitude="initial"``
adds the homogeneous solution that makes :math:`x_n(0) = 0`, so ``A = x(0)`` (the turning
point). For Duffing :math:`x'' + \omega_0^2 x + \epsilon x^3 = 0`,
:math:`\omega = \omega_0 + 3\epsilon A^2/(8\omega_0) - 15\epsilon^2 A^4/(256\omega_0^3)` in the
first and :math:`-21/256` in the second.

Implementation: the harmonic bookkeeping works on harmonic coefficients directly (products by
the product-to-sum rules), never on whole expressions with ``trigsimp``/``dsolve``, and the
coefficients are Laurent polynomials with rational coefficients in the symbols and the
coefficient functions, so that no SymPy ``expand`` runs inside the loop: the series engine of
:mod:`perturb.methods.series`, shared with :mod:`perturb.methods.modified_lindstedt`.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import sympy as sp

from perturb.approximation import Approximation, Step
from perturb.errors import ModelError, ParameterError
from perturb.methods.applicability import check_order, require_centred
from perturb.methods.caveats import states_caveats
from perturb.methods.series import (
    AMPLITUDES,
    ONE,
    PWL_MAX_ORDER,
    ZERO,
    Coeff,
    Expansion,
    Force,
    LaurentPolynomial,
    Series,
    SplitModel,
    check_options,
    closed_form_step,
    derivation_step,
    equation,
    free_symbol,
    is_short,
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

__all__ = ["lindstedt_poincare", "AMPLITUDES", "SCALINGS", "PWL_MAX_ORDER"]

#: Bookkeeping of the small parameter: all of ``g`` at order 1, or by degree (x -> eps x).
SCALINGS = ("uniform", "amplitude")


def _require_free(osc: Oscillator, method: str) -> None:
    """A free conservative oscillator: no damping, forcing, velocity or parametric terms
    (terms whose parameter values are zero are dropped)."""
    if not vanishes(osc.damping, osc):
        raise ModelError(
            f"{method} covers free conservative oscillators x'' + f(x) = 0; model "
            f"{osc.name!r} has damping {osc.damping} (give it the value 0, or use the "
            "modified Lindstedt-Poincare method, which takes forced damped systems)"
        )
    if osc.velocity != 0 or osc.parametric != 0:
        raise ModelError(
            f"{method} covers x'' + f(x) = 0; model {osc.name!r} also has "
            f"{osc.velocity + osc.parametric}"
        )
    live = [h for h in osc.forcing.harmonics if not vanishes(h.amplitude, osc)]
    if live:
        raise ModelError(
            f"{method} covers free oscillators; model {osc.name!r} is forced by "
            f"{' + '.join(str(h) for h in live)} (give the amplitude the value 0, or use the "
            "modified Lindstedt-Poincare method)"
        )


@dataclass
class _Setup:
    """What the stages share: the split model, the pieces ``g_j`` of the bookkeeping, the
    method's symbols, the frequency corrections found so far and the expansion."""

    osc: Oscillator
    order: int
    amplitude: str
    scaling: str
    harmonics: int
    model: SplitModel
    pieces: dict[int, Force]
    A: sp.Symbol
    tau: sp.Symbol
    eps: sp.Dummy
    omega: sp.Symbol
    om_sym: list[sp.Expr]
    om: list[LaurentPolynomial]
    inv_w0: LaurentPolynomial
    inv_w2: LaurentPolynomial
    exp: Expansion
    xf: list[Any]


@states_caveats
def lindstedt_poincare(
    oscillator: Oscillator,
    order: int = 2,
    *,
    amplitude: str = "first_harmonic",
    scaling: str = "uniform",
    omega0: float | sp.Expr | str | None = None,
    harmonics: int = 15,
) -> Approximation:
    r"""Lindstedt–Poincaré expansion of a free conservative oscillator to ``order``.

    Parameters
    ----------
    oscillator
        ``x'' + f(x) = 0`` with ``f`` polynomial and/or piecewise linear (damping and forcing
        must be absent or have the value 0). Parameters stay symbolic in the result.
    order
        Highest power of the bookkeeping parameter kept in :math:`\omega` and :math:`x`.
        Polynomial forces: any order. Piecewise-linear forces: up to :data:`PWL_MAX_ORDER`
        (the second order of a force with jumps uses Dirac-delta coefficients).
    amplitude
        ``"first_harmonic"``: ``A`` is the amplitude of :math:`\cos\omega t` in :math:`x`;
        ``"initial"``: ``A = x(0)`` (the turning point, :math:`\dot x(0) = 0`).
    scaling
        ``"uniform"``: :math:`x'' + \omega_0^2 x + \varepsilon g(x) = 0`;
        ``"amplitude"`` (polynomial forces only): :math:`x \to \varepsilon x`, the term of
        degree :math:`m` carries :math:`\varepsilon^{m-1}`.
    omega0
        Reference linear frequency :math:`\omega_0`; default: the square root of the linear
        stiffness (plus the mean of the outer slopes of a piecewise-linear part, e.g. 1 for
        the ``nsd`` model). A symbol ``s`` with stiffness ``s**2`` is taken as positive.
    harmonics
        Highest harmonic kept for piecewise-linear forces (polynomial ones are exact).

    Returns
    -------
    Approximation
        ``backbone`` :math:`\omega(A)` (:math:`\varepsilon = 1`), ``waveform``
        :math:`x(\tau)` with :math:`\tau = \omega t`, ``unknowns = (A,)``, the residual
        :math:`\omega - \omega(A)`, ``fourier`` the harmonics of :math:`g(A\cos\tau)`, and
        ``steps`` the derivation order by order.

    Raises
    ------
    ModelError
        Damped, forced, velocity-dependent or parametric models, non-polynomial smooth terms,
        a non-positive reference stiffness, ``scaling="amplitude"`` on a PWL force, a
        piecewise-linear part that is not odd (or one with a static load).
    ParameterError
        Bad options; a piecewise-linear force above :data:`PWL_MAX_ORDER`; an order above
        :data:`~perturb.methods.applicability.ORDER_LIMITS` ``["lp"]``.
    """
    s = _setup(oscillator, order, amplitude, scaling, omega0, harmonics)
    steps = _opening_steps(s)
    fourier = _fourier_of_g(s, steps)
    for n in range(1, s.order + 1):
        steps.append(_solve_order(s, n))
    return _result(s, fourier, steps)


def _setup(
    osc: Oscillator, order: int, amplitude: str, scaling: str, omega0: Any, harmonics: int
) -> _Setup:
    """Check that the model is a free conservative one the method covers, split its restoring
    force about :math:`\\omega_0`, order the remainder by the bookkeeping parameter (uniformly
    or by degree) and introduce the symbols and :math:`x_0 = A\\cos\\tau`."""
    order = check_options(order, amplitude, harmonics)
    if scaling not in SCALINGS:
        raise ParameterError(f"scaling = {scaling!r}: expected one of {', '.join(SCALINGS)}")
    _require_free(osc, "Lindstedt-Poincare")
    order = check_order("lp", order)
    # a polynomial force with a static load is expanded consistently; a one-sided
    # piecewise-linear force (or one with a load) has an orbit whose mean is of order one
    require_centred(osc, "Lindstedt-Poincare (lp)", load=True)
    model = split_model(osc, omega0)
    if model.ramps and order > PWL_MAX_ORDER:
        raise ParameterError(
            f"order = {order} for the piecewise-linear model {osc.name!r}: expected at most "
            f"{PWL_MAX_ORDER} (higher orders need products of whole truncated series)"
        )
    if scaling == "amplitude":
        if model.ramps:
            raise ModelError(
                "scaling='amplitude' expands in powers of the amplitude, which needs a "
                f"polynomial force; model {osc.name!r} is piecewise linear: use 'uniform'"
            )
        low = {m: c for m, c in model.poly.items() if m < 2}
        if low:
            raise ModelError(
                "scaling='amplitude' needs omega0**2 equal to the linear stiffness and no "
                f"static load; the remainder {sum(c * osc.x**m for m, c in low.items())} "
                "would not be small"
            )
        pieces = {m - 1: Force(((m, c),)) for m, c in sorted(model.poly.items())}
    else:
        pieces = {1: model.force}
    A = sp.Symbol("A", positive=True)
    eps = method_dummy("varepsilon")
    omega = free_symbol(osc, "omega")
    om_sym = [model.w0] + [method_dummy(f"omega_{n}") for n in range(1, order + 1)]
    w0_lp = omega0_coefficient(model.w0)
    inv_w0 = ONE / w0_lp
    return _Setup(
        osc=osc,
        order=order,
        amplitude=amplitude,
        scaling=scaling,
        harmonics=harmonics,
        model=model,
        pieces=pieces,
        A=A,
        tau=real_symbol("tau"),
        eps=eps,
        omega=omega,
        om_sym=om_sym,
        om=[w0_lp],
        inv_w0=inv_w0,
        inv_w2=inv_w0 * inv_w0,
        exp=Expansion(
            {1: (LaurentPolynomial.atom(A), ZERO)}, A, harmonics if model.ramps else None
        ),
        xf=[sp.Function(f"x_{n}") for n in range(order + 1)],
    )


def _opening_steps(s: _Setup) -> list[Step]:
    """Derivation steps up to order zero: the equation of motion, the bookkeeping of the
    remainder :math:`g`, strained time with the expansions of :math:`\\omega` and :math:`x`,
    and :math:`x_0 = A\\cos\\tau`."""
    osc, order, eps, tau, xf, w2 = s.osc, s.order, s.eps, s.tau, s.xf, s.model.w2
    xpp = real_symbol(osc.x.name + "''")
    if s.scaling == "amplitude":
        g_shown = sp.Add(*(eps**j * p.expr(osc.x) for j, p in s.pieces.items()))
    else:
        g_shown = eps * s.model.g_written(osc)
    return [
        derivation_step("Equation of motion", (osc.equation,)),
        derivation_step(
            "Bookkeeping",
            (equation(xpp + w2 * osc.x + g_shown, 0),),
            "The restoring force is split into a linear reference term and a remainder"
            + (
                " (the mean stiffness of the outer segments)"
                if s.model.ramps and s.model.default_w0
                else ""
            )
            + ", which is ordered by the bookkeeping parameter $\\varepsilon$ (set to one at the "
            "end)"
            + (
                "; the amplitude is scaled by $\\varepsilon$, so a term of degree $m$ carries "
                "$\\varepsilon^{m - 1}$."
                if s.scaling == "amplitude"
                else "."
            ),
        ),
        derivation_step(
            "Strained time and expansions",
            (
                equation(tau, s.omega * osc.t),
                equation(
                    s.omega,
                    s.model.w0 + sp.Add(*(eps**n * s.om_sym[n] for n in range(1, order + 1))),
                ),
                equation(osc.x, sp.Add(*(eps**n * xf[n](tau) for n in range(order + 1)))),
            ),
            "Time is strained by the unknown frequency, which is expanded with the response; "
            "primes are now derivatives with respect to $\\tau$ and powers of $\\varepsilon$ "
            "are collected.",
        ),
        derivation_step(
            "Order zero in $\\varepsilon$",
            (
                equation(w2 * (sp.Derivative(xf[0](tau), tau, 2) + xf[0](tau)), 0),
                equation(xf[0](tau), s.A * sp.cos(tau)),
            ),
            "The amplitude $A$ is "
            + ("that of the first harmonic." if s.amplitude == "first_harmonic" else "$x(0)$."),
        ),
    ]


def _fourier_of_g(s: _Setup, steps: list[Step]) -> dict[str, sp.Expr]:
    """The harmonics of :math:`g(A\\cos\\tau)` (the ``fourier`` field; first-order piece only)
    and, when it has one, the closed form of the first harmonic as a derivation step."""
    fourier: dict[str, sp.Expr] = {}
    if 1 in s.pieces:
        for n, (c, _) in s.exp.compose(s.pieces[1], 0).items():
            fourier[f"g_{n}"] = (2 * c if n == 0 else c).to_sympy()
        cf = closed_form_step(
            sp.Function("g_1")(s.A),
            fourier.get("g_1", sp.Integer(0)),
            "First harmonic of $g$ in closed form",
        )
        if cf is not None:
            steps.append(cf)
    return fourier


def _solve_order(s: _Setup, n: int) -> Step:
    """Order :math:`\\varepsilon^n`: collect the right-hand side by harmonic, set the
    :math:`\\cos\\tau` coefficient to zero (which gives :math:`\\omega_n`), solve for
    :math:`x_n` (shifted to vanish at 0 for ``amplitude="initial"``); returns the step."""
    om, exp, tau, A = s.om, s.exp, s.tau, s.A

    # W_i = sum_{p+q=i} omega_p omega_q, the unknown omega_n left out of W_n
    def W(i: int) -> LaurentPolynomial:
        total = ZERO
        for p in range(i + 1):
            if p != n and i - p != n:
                total = total + om[p] * om[i - p]
        return total

    terms: list[tuple[Coeff, Series]] = [
        (-W(i), series_derivative(exp.x[n - i], 2)) for i in range(1, n + 1)
    ]
    for j, piece in s.pieces.items():
        if j <= n:
            terms.append((-1, exp.compose(piece, n - j)))
    rhs = series_combine(*terms)
    c1, s1 = rhs.get(1, (ZERO, ZERO))
    if s1:
        raise ModelError(
            f"a sine secular term {s1.to_sympy()} at order {n}: the model is not conservative"
        )
    # the unknown enters as -2 omega_0 omega_n x_0'' = 2 omega_0 omega_n A cos(tau)
    wn = -c1 * s.inv_w0 / (2 * LaurentPolynomial.atom(A))
    om.append(wn)
    xn = series_solve(rhs, s.inv_w2)
    if s.amplitude == "initial":
        x_at0 = series_at_zero(xn)
        if x_at0:
            xn = series_combine((1, xn), (-x_at0, {1: (ONE, ZERO)}))
    exp.push(xn)
    w0, w2, xf = s.model.w0, s.model.w2, s.xf
    shown_rhs = series_to_sympy(rhs, tau, tidy=True) + 2 * w0 * s.om_sym[n] * A * sp.cos(tau)
    return derivation_step(
        f"Order {n} in $\\varepsilon$",
        (
            equation(w2 * (sp.Derivative(xf[n](tau), tau, 2) + xf[n](tau)), shown_rhs),
            equation(s.om_sym[n], tidy_coefficient(wn)),
            equation(xf[n](tau), series_to_sympy(xn, tau, tidy=True)),
        ),
        "No secular term: the coefficient of $\\cos\\tau$ vanishes, which gives the "
        f"frequency correction of order {n}; "
        + (
            "the particular solution has no $\\cos\\tau$ part."
            if s.amplitude == "first_harmonic"
            else "a homogeneous term makes the correction vanish at $\\tau = 0$."
        ),
    )


def _result(s: _Setup, fourier: dict[str, sp.Expr], steps: list[Step]) -> Approximation:
    """Assembly with :math:`\\varepsilon = 1`: the backbone :math:`\\omega = \\sum\\omega_n`,
    the waveform :math:`\\sum x_n`, the result step and the Approximation."""
    osc, tau, om = s.osc, s.tau, s.om
    backbone_lp = ZERO
    for w in om:
        backbone_lp = backbone_lp + w
    backbone = backbone_lp.to_sympy()
    waveform = sp.Add(*(series_to_sympy(xn, tau) for xn in s.exp.x))
    wave_shown = sp.Add(*(series_to_sympy(xn, tau, tidy=True) for xn in s.exp.x))
    if not is_short(wave_shown):  # a long waveform is in the steps above, order by order
        wave_shown = sp.Add(*(s.xf[n](tau) for n in range(s.order + 1)))
    steps.append(
        derivation_step(
            "Result with $\\varepsilon = 1$",
            (
                equation(s.omega, sp.Add(*(tidy_coefficient(w) for w in om))),
                equation(osc.x, wave_shown),
            ),
            "The frequency-amplitude relation (backbone) and the waveform"
            + (f"; harmonics above {s.harmonics} are dropped." if s.model.ramps else "."),
        )
    )
    options: dict[str, Any] = {
        "order": s.order,
        "amplitude": s.amplitude,
        "scaling": s.scaling,
        "omega0": s.model.w0,
    }
    if s.model.ramps:
        options["harmonics"] = s.harmonics
    return Approximation(
        oscillator=osc,
        method="lp",
        options=MappingProxyType(options),
        unknowns=(s.A,),
        residuals=(s.omega - backbone,),
        waveform=waveform,
        tau=tau,
        frequency=s.omega,
        amplitude=s.A,
        backbone=backbone,
        fourier=MappingProxyType(fourier),
        steps=tuple(steps),
    )
