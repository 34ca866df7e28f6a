r"""First-order averaging: van der Pol's Cartesian technique and Krylov–Bogoliubov polar form.

Both start from the oscillator in *standard form* about a generating frequency
:math:`\omega` (the forcing frequency :math:`\Omega` of a forced system, the linear natural
frequency :math:`\omega_0 = \sqrt{k}` of a free one),

.. math:: x'' + \omega^2 x = R, \qquad R = \omega^2 x - g(x, x') + F\cos(\Omega t + p_0),

and vary the constants of the linear solution (Nayfeh & Mook 1979, §4.2; docs/references.md §2):

* **Krylov–Bogoliubov** (:func:`krylov_bogoliubov`): :math:`x = a\cos\psi`,
  :math:`x' = -a\omega\sin\psi`, with :math:`\psi = \Omega t + p_0 - \varphi` (forced) or
  :math:`\psi = \omega_0 t + \beta` (free). Exactly :math:`\dot a = -R\sin\psi/\omega`,
  :math:`a\dot\varphi = R\cos\psi/\omega` (free: :math:`a\dot\beta = -R\cos\psi/\omega`);
  averaging over :math:`\psi` at fixed :math:`a, \varphi` keeps only the first harmonic of
  :math:`g`.
* **van der Pol** (:func:`van_der_pol_averaging`): :math:`x = p\cos\tau + q\sin\tau`,
  :math:`x' = \omega(-p\sin\tau + q\cos\tau)`, :math:`\tau = \omega t`, so
  :math:`\dot p = -R\sin\tau/\omega`, :math:`\dot q = R\cos\tau/\omega`. The Cartesian flow is
  regular at :math:`a = 0` (the Hopf point of a self-excited oscillator); for polynomial forces
  it is a polynomial in :math:`p, q`.

Everything the averaged equations need from the force is its first harmonic under
:math:`x = a\cos\psi`, :math:`x' = -a\omega\sin\psi`,

.. math:: g \approx G_c(a)\cos\psi + G_s(a, \omega)\sin\psi, \qquad
          k_{eq}(a) = \frac{G_c}{a},\quad c_{eq}(a, \omega) = -\frac{G_s}{a\omega},

i.e. the *equivalent linearisation* :math:`g \approx k_{eq}x + c_{eq}x'` (Krylov–Bogoliubov's
equivalent linearisation; :math:`N = k_{eq} + i\omega c_{eq}` is the describing function of a
Lur'e loop), returned by :func:`equivalent_linearisation`. :func:`fourier_components`
computes such coefficients for any force the Fourier engine handles:

* polynomials in :math:`x, x'` exactly, through :func:`~perturb.fourier.trig.harmonics`;
* piecewise-linear functions of :math:`x` through the closed-form step/ramp coefficients
  (:func:`~perturb.fourier.symbols.series_coefficient`), never a Taylor series;
* piecewise-linear functions of :math:`x'` (Coulomb friction ``sign(x')``, saturating
  dampers) by the same coefficients with a phase shift: :math:`x' = -a\omega\sin\psi =
  a\omega\cos(\psi + \pi/2)`, so a coefficient :math:`\alpha_n(a\omega)` of
  :math:`\cos n\chi` becomes :math:`\alpha_n\cos(n\pi/2)` on :math:`\cos n\psi` and
  :math:`-\alpha_n\sin(n\pi/2)` on :math:`\sin n\psi`;
* products :math:`P(x, x')\,\phi(s)` of a polynomial and a PWL function of one state
  :math:`s` (``x'*Abs(x')``, ``x**2*sign(x')``): the polynomial has harmonics up to its degree
  :math:`D`, so the coefficients of harmonic :math:`n` of the product need those of
  :math:`\phi` up to :math:`n + D` only — a finite, exact sum.

Coefficients whose switching point sits at the centre of the motion (``sign(x')``,
``Abs(x)`` with zero bias) are replaced by their exact values (:math:`\theta = \pi/2`), so
Coulomb friction gives :math:`c_{eq} = 4r/(\pi a\omega)` in closed form.

First order means: the results are the :math:`O(\varepsilon)` averaged equations when the
non-linear, damping, forcing and detuning terms are all :math:`O(\varepsilon)`; the methods
keep the exact :math:`\Omega` rather than expanding :math:`\Omega = \omega_0 + \varepsilon\sigma`
(so for a forced system the steady states coincide with single-harmonic balance), and the
classical detuned forms follow by that substitution (see ``tests/test_averaging.py``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import sympy as sp

from perturb.approximation import Approximation, Step
from perturb.errors import FourierError, ModelError, NonsmoothError, PerturbError
from perturb.fourier.symbols import (
    DiracCoefficient,
    RampCoefficient,
    StepCoefficient,
    closed_form,
    series_coefficient,
)
from perturb.fourier.trig import fold_mirror_angles, harmonics
from perturb.methods.applicability import expression_argument, require_centred
from perturb.methods.caveats import states_caveats
from perturb.model.oscillator import Oscillator
from perturb.model.parsing import real_symbol
from perturb.model.pwl import is_nonsmooth, to_pwl
from perturb.printing import latex

__all__ = [
    "fourier_components",
    "frequency_polynomial_coefficients",
    "response_frequency_symbol",
    "EquivalentLinearisation",
    "equivalent_linearisation",
    "krylov_bogoliubov",
    "van_der_pol_averaging",
]

Components = dict[int, tuple[sp.Expr, sp.Expr]]


# ------------------------------------------------------------------ Fourier components --
def _values(osc: Oscillator) -> dict[str, float]:
    return {n: v for n, v in osc.params.items() if v is not None}


def _pwl_ok(term: sp.Expr, s: sp.Symbol, values: Mapping[str, float] | None) -> bool:
    """Whether ``term`` is piecewise linear in ``s`` (ordering symbolic breakpoints by the
    parameter values when SymPy cannot, as :func:`series_coefficient` does)."""
    try:
        to_pwl(term, s)
        return True
    except NonsmoothError:
        if not values:
            return False
    try:
        to_pwl(term, s, values=values)
        return True
    except NonsmoothError:
        return False


_SWITCHES = (sp.Heaviside, sp.Max, sp.Min, sp.Abs, sp.sign, sp.Piecewise, sp.DiracDelta)


def _switch_values(expr: sp.Expr, values: Mapping[str, float] | None) -> Mapping[str, float] | None:
    """The parameter values that order breakpoints: those of symbols inside the switches.
    Coefficients outside stay symbolic (``k2 (x - sat(x))`` keeps ``k2``)."""
    if not values:
        return None
    names = {s.name for f in expr.atoms(*_SWITCHES) for s in f.free_symbols}
    return {n: v for n, v in values.items() if n in names} or None


def _centred(expr: sp.Expr) -> sp.Expr:
    """Replace coefficient functions whose switching point is the centre of the motion
    (``d == b``) by their exact values: the crossing angle is pi/2 for every amplitude > 0,
    so e.g. ``StepCoefficient(1, a, 0, 0) = 2/pi`` (the relay and Coulomb terms)."""
    reps = {}
    for call in expr.atoms(StepCoefficient, RampCoefficient, DiracCoefficient):
        _, _, b, d = call.args
        if sp.simplify(d - b) == 0:
            value, definitions, _ = closed_form(call)
            reps[call] = sp.simplify(value.xreplace(dict(definitions)))
    return expr.xreplace(reps) if reps else expr


def _split_product(
    term: sp.Expr, x: sp.Symbol, v: sp.Symbol
) -> tuple[sp.Expr, sp.Expr, sp.Symbol] | None:
    """``term = P(x, v) * phi(s)`` with ``P`` polynomial and ``phi`` nonsmooth in one state
    ``s``; None if it is not of that form."""
    poly, phi = sp.Integer(1), sp.Integer(1)
    for factor in sp.Mul.make_args(term):
        if is_nonsmooth(factor):
            phi *= factor
        else:
            poly *= factor
    states = [s for s in (x, v) if phi.has(s)]
    if len(states) != 1 or not poly.is_polynomial(x, v):
        return None
    return poly, phi, states[0]


def fourier_components(
    expr: sp.Expr,
    x: sp.Symbol,
    v: sp.Symbol,
    amplitude: sp.Expr,
    frequency: sp.Expr,
    bias: sp.Expr | int = 0,
    orders: Iterable[int] = (1,),
    values: Mapping[str, float] | None = None,
) -> Components:
    r"""Harmonic components of ``expr(x, v)`` on :math:`x = b + a\cos\psi`,
    :math:`v = x' = -a\omega\sin\psi`.

    .. math:: \mathrm{expr} = c_0 + \sum_{n\ge1} \big(c_n\cos n\psi + s_n\sin n\psi\big),
              \qquad c_0 = \text{mean},\;
              c_n = \frac1\pi\int_0^{2\pi}\!\mathrm{expr}\cos n\psi\,d\psi,\;
              s_n = \frac1\pi\int_0^{2\pi}\!\mathrm{expr}\sin n\psi\,d\psi.

    Parameters
    ----------
    expr
        Polynomial terms in ``x`` and ``v``, piecewise-linear terms in ``x`` alone or ``v``
        alone, and products of a polynomial with a PWL function of one of them.
    x, v
        The state symbols (``v`` is the velocity ``x'``).
    amplitude, frequency, bias
        :math:`a`, :math:`\omega`, :math:`b` (the velocity has no bias).
    orders
        The harmonics wanted (``0`` gives the mean).
    values
        Parameter values, used only to order symbolic breakpoints.

    Returns
    -------
    dict
        ``{n: (c_n, s_n)}`` (``s_0 = 0``).

    Raises
    ------
    ModelError
        For terms without closed-form coefficients (``sin(x)``, ``Heaviside(x)*sign(x')``,
        products that make a piece nonlinear in the switching variable...).
    """
    orders = sorted({int(n) for n in orders})
    if not orders or orders[0] < 0:
        raise PerturbError(f"orders = {orders}: expected harmonic indices >= 0")
    a = expression_argument(amplitude, "amplitude")
    w = expression_argument(frequency, "frequency")
    b = expression_argument(bias, "bias")
    expr = expression_argument(expr, "expr", allow_derivatives=True)
    values = _switch_values(expr, values)
    psi = sp.Dummy("psi", real=True)
    on_orbit = {x: b + a * sp.cos(psi), v: -a * w * sp.sin(psi)}
    cos_parts = {n: sp.Integer(0) for n in orders}
    sin_parts = {n: sp.Integer(0) for n in orders}

    def add(parts: Mapping[int, tuple[sp.Expr, sp.Expr]]) -> None:
        for n in orders:
            c, s = parts.get(n, (0, 0))
            cos_parts[n] += c
            sin_parts[n] += s

    polynomial, pwl_x, pwl_v = sp.Integer(0), sp.Integer(0), sp.Integer(0)
    products: list[tuple[sp.Expr, sp.Expr, sp.Symbol]] = []
    for term in sp.Add.make_args(sp.sympify(expr)):
        if not term.has(x, v):
            polynomial += term
        elif not is_nonsmooth(term):
            if not term.is_polynomial(x, v):
                raise ModelError(
                    f"term {term} has no closed-form Fourier coefficients: expected polynomial "
                    f"or piecewise-linear terms in {x} and {v}"
                )
            polynomial += term
        elif not term.has(v) and _pwl_ok(term, x, values):
            pwl_x += term
        elif not term.has(x) and _pwl_ok(term, v, values):
            pwl_v += term
        else:
            split = _split_product(term, x, v)
            if split is None or not _pwl_ok(split[1], split[2], values):
                raise ModelError(
                    f"term {term} has no closed-form Fourier coefficients here: expected a "
                    f"polynomial in {x}, {v} times a piecewise-linear function of one of them"
                )
            products.append(split)

    if polynomial != 0:
        add(harmonics(sp.expand(polynomial.xreplace(on_orbit)), psi))
    try:
        if pwl_x != 0:
            # f(b + a cos psi) = a_0/2 + sum a_n cos(n psi): the engine's a_n convention
            for n in orders:
                an = series_coefficient(pwl_x, x, n, a, b, values=values)
                cos_parts[n] += an / 2 if n == 0 else an
        if pwl_v != 0:
            # v = a w cos(chi), chi = psi + pi/2: cos(n chi) = cos(n pi/2) cos(n psi)
            #                                                - sin(n pi/2) sin(n psi)
            for n in orders:
                an = series_coefficient(pwl_v, v, n, a * w, 0, values=values)
                if n == 0:
                    cos_parts[0] += an / 2
                else:
                    cos_parts[n] += an * sp.cos(n * sp.pi / 2)
                    sin_parts[n] -= an * sp.sin(n * sp.pi / 2)
        for poly, phi, s in products:
            add(_product_components(poly, phi, s, x, on_orbit, (a, w, b), psi, orders, values))
    except (FourierError, NonsmoothError) as exc:
        raise ModelError(f"no closed-form Fourier coefficients for {expr}: {exc}") from exc
    return {n: (_tidy(cos_parts[n]), _tidy(sin_parts[n])) for n in orders}


def _tidy(expr: sp.Expr) -> sp.Expr:
    """Expanded, centred coefficients, grouped by coefficient function so that the
    derivation reads ``(1 - k) a^R_1(...)`` rather than four separate terms."""
    expr = _centred(sp.expand(expr))
    calls = sorted(
        expr.atoms(StepCoefficient, RampCoefficient, DiracCoefficient), key=sp.default_sort_key
    )
    return sp.collect(expr, calls, sp.factor) if calls else expr


def _product_components(
    poly: sp.Expr,
    phi: sp.Expr,
    s: sp.Symbol,
    x: sp.Symbol,
    on_orbit: Mapping[sp.Symbol, sp.Expr],
    scales: tuple[sp.Expr, sp.Expr, sp.Expr],
    psi: sp.Symbol,
    orders: list[int],
    values: Mapping[str, float] | None,
) -> Components:
    # P(x, v) has harmonics up to its total degree D, so harmonic n of P*phi involves the
    # harmonics of phi up to n + D only: truncating phi's series there is exact.
    a, w, b = scales
    states = [sym for sym in on_orbit]
    degree = sp.Poly(poly, *states).total_degree()
    top = max(orders) + degree
    if s == x:  # x = b + a cos(psi)
        amp, centre, shift = a, b, sp.Integer(0)
    else:  # x' = -a w sin(psi) = a w cos(psi + pi/2)
        amp, centre, shift = a * w, sp.Integer(0), sp.pi / 2
    alpha = [sp.Dummy(f"alpha{n}") for n in range(top + 1)]
    series = alpha[0] / 2 + sp.Add(
        *(alpha[n] * sp.cos(n * psi + n * shift) for n in range(1, top + 1))
    )
    parts = harmonics(sp.expand(poly.xreplace(on_orbit) * series), psi)
    reps = {
        alpha[n]: series_coefficient(phi, s, n, amp, centre, values=values) for n in range(top + 1)
    }
    return {n: (c.xreplace(reps), si.xreplace(reps)) for n, (c, si) in parts.items()}


# --------------------------------------------------------------- equivalent linearisation --
@dataclass(frozen=True)
class EquivalentLinearisation:
    r"""First-harmonic (describing-function) equivalent of a force :math:`g(x, x')`.

    On :math:`x = a\cos\psi`, :math:`x' = -a\omega\sin\psi`,
    :math:`g \approx G_c\cos\psi + G_s\sin\psi = k_{eq}x + c_{eq}x'` with

    .. math:: k_{eq}(a) = \frac{1}{\pi a}\int_0^{2\pi} g\cos\psi\,d\psi = \frac{G_c}{a},
              \qquad
              c_{eq}(a, \omega) = -\frac{1}{\pi a\omega}\int_0^{2\pi} g\sin\psi\,d\psi
              = -\frac{G_s}{a\omega}.

    Attributes
    ----------
    amplitude, frequency
        The symbols :math:`a`, :math:`\omega`.
    stiffness, damping
        :math:`k_{eq}` and :math:`c_{eq}` (coefficient functions of PWL terms kept by name;
        :meth:`closed` gives the theta-forms).
    cos_component, sin_component
        :math:`G_c`, :math:`G_s`.
    """

    amplitude: sp.Symbol
    frequency: sp.Symbol
    stiffness: sp.Expr
    damping: sp.Expr
    cos_component: sp.Expr
    sin_component: sp.Expr

    @property
    def describing_function(self) -> sp.Expr:
        r""":math:`N(a, \omega) = k_{eq} + i\omega c_{eq}`: the complex gain from
        :math:`x = a\cos\omega t` to the first harmonic of :math:`g` (for a static
        nonlinearity :math:`N = k_{eq}`, the classical describing function)."""
        return self.stiffness + sp.I * self.frequency * self.damping

    def closed(self) -> tuple[sp.Expr, sp.Expr, tuple[tuple[sp.Symbol, sp.Expr], ...]]:
        """``(k_eq, c_eq, definitions)`` in the textbook theta-form of
        :func:`~perturb.fourier.symbols.closed_form` (valid where every switching point is
        crossed)."""
        k, dk, _ = closed_form(self.stiffness)
        c, dc, _ = closed_form(self.damping, theta="vartheta")
        return k, c, tuple(dict(dk + dc).items())


def equivalent_linearisation(
    model: Oscillator | sp.Expr,
    *,
    x: sp.Symbol | None = None,
    v: sp.Symbol | None = None,
    amplitude: sp.Symbol | None = None,
    frequency: sp.Expr | None = None,
    values: Mapping[str, float] | None = None,
) -> EquivalentLinearisation:
    r"""Equivalent stiffness :math:`k_{eq}(a)` and damping :math:`c_{eq}(a, \omega)`.

    Parameters
    ----------
    model
        An :class:`~perturb.model.oscillator.Oscillator` (its whole left-hand side ``g(x, x')``:
        linear stiffness and viscous damping included, so :math:`k_{eq}` and
        :math:`c_{eq}` are totals) or a SymPy expression of ``x`` and ``v``.
    x, v
        State symbols for an expression (default: the real symbols ``x`` and ``x'``).
    amplitude, frequency
        Symbols to use (default: positive ``a`` and ``omega``).
    values
        Parameter values to order symbolic breakpoints (taken from an oscillator).

    Raises
    ------
    ModelError
        For parametric terms or forces without closed-form coefficients.

    Examples
    --------
    The dead zone of width ``d`` gives the classical describing function
    ``k2 [1 - (2/pi)(arcsin(d/a) + (d/a) sqrt(1 - d**2/a**2))]`` (see the tests).
    """
    if isinstance(model, Oscillator):
        if model.parametric != 0:
            raise ModelError(
                f"model {model.name!r} has parametric terms {model.parametric}; the "
                "equivalent linearisation is of a time-invariant force g(x, x')"
            )
        g, x, v = model.g, model.x, model.v
        values = _values(model) if values is None else values
    else:
        g = expression_argument(model, "model", allow_derivatives=True)
        x = x if x is not None else real_symbol("x")
        v = v if v is not None else real_symbol("x'")
    a = amplitude if amplitude is not None else sp.Symbol("a", positive=True)
    w = frequency if frequency is not None else sp.Symbol("omega", positive=True)
    (gc, gs) = fourier_components(g, x, v, a, w, 0, (1,), values)[1]
    k_eq = _tidy(gc / a)
    c_eq = _tidy(-gs / (a * w))
    return EquivalentLinearisation(a, w, k_eq, c_eq, gc, gs)


# ------------------------------------------------------------------------ the methods --
@dataclass(frozen=True)
class _Setup:
    """What both averaging techniques read off the oscillator."""

    forced: bool
    omega: sp.Expr  # generating frequency (Omega, or omega_0)
    F: sp.Expr
    phase: sp.Expr  # forcing phase p_0
    values: Mapping[str, float] = field(default_factory=dict)


def _setup(osc: Oscillator, generating_frequency: sp.Expr | float | None, name: str) -> _Setup:
    if osc.parametric != 0:
        raise ModelError(
            f"{name} here covers x'' + g(x, x') = F cos(Omega t + p); model {osc.name!r} has "
            f"parametric terms {osc.parametric}"
        )
    # a static load or a one-sided (non-odd piecewise-linear) force: the orbit has a mean,
    # which first-order averaging about x = a cos(psi) leaves out
    require_centred(osc, f"first-order {name}")
    if len(osc.forcing.harmonics) > 1:
        raise ModelError(
            f"{name} handles one forcing harmonic; model {osc.name!r} has "
            f"{len(osc.forcing.harmonics)} ({osc.forcing.expr(osc.t)})"
        )
    values = _values(osc)
    if osc.forcing.harmonics:
        h = osc.forcing.harmonics[0]
        if not isinstance(h.frequency, sp.Symbol):
            raise ModelError(
                f"the forcing frequency of model {osc.name!r} is {h.frequency}: expected a "
                "single parameter symbol (e.g. Omega)"
            )
        if generating_frequency is not None:
            raise ModelError(
                "a forced system is averaged about its forcing frequency; "
                "generating_frequency is for free systems"
            )
        return _Setup(True, h.frequency, h.amplitude, h.phase, values)
    if generating_frequency is not None:
        omega = expression_argument(generating_frequency, "generating_frequency")
    else:
        k = osc.linear_stiffness
        k_value = k.xreplace(osc.substitutions())
        if k == 0 or (k_value.is_number and not k_value > 0):
            raise ModelError(
                f"model {osc.name!r} has linear stiffness {k} = {k_value}: there is no linear "
                "natural frequency to average about; pass generating_frequency= (any "
                "positive frequency near the expected response)"
            )
        # a frequency is positive: sqrt(omega0**2) -> omega0
        omega = sp.powdenest(sp.sqrt(k), force=True)
    return _Setup(False, omega, sp.Integer(0), sp.Integer(0), values)


def _linearisation_step(
    eq: EquivalentLinearisation, x: sp.Symbol, v: sp.Symbol, g: sp.Expr, psi: sp.Symbol
) -> tuple[Step, ...]:
    a, w = eq.amplitude, eq.frequency
    kf, cf = sp.Function("k_eq")(a), sp.Function("c_eq")(a)
    steps = [
        Step(
            "First harmonic of the force: equivalent linearisation",
            (
                sp.Eq(sp.Function("g")(x, v), g),
                sp.Eq(
                    sp.Function("g")(a * sp.cos(psi), -a * w * sp.sin(psi)),
                    a * kf * sp.cos(psi) - a * w * cf * sp.sin(psi) + sp.Symbol("\\ldots"),
                ),
                sp.Eq(kf, eq.stiffness),
                sp.Eq(cf, eq.damping),
            ),
            "The averaged equations see the force only through its first harmonic, i.e. "
            "through the equivalent stiffness $k_{eq}$ (the describing function of the static "
            "part) and the equivalent damping $c_{eq}$; polynomial terms are projected exactly, "
            "piecewise-linear ones through the closed-form step and ramp coefficients, "
            "velocity switches with the quarter-period shift "
            "$x' = a\\omega\\cos(\\psi + \\pi/2)$.",
        )
    ]
    k_c, c_c, defs = eq.closed()
    (k_c, c_c), defs = fold_mirror_angles((k_c, c_c), defs)
    if defs:
        steps.append(
            Step(
                "The coefficients in closed form",
                (sp.Eq(kf, k_c), sp.Eq(cf, c_c)) + tuple(sp.Eq(s, d) for s, d in defs),
                "Valid while the orbit crosses every switching point (the angles $\\theta$ are "
                "real); outside, the terms are exactly linear.",
            )
        )
    return tuple(steps)


def frequency_polynomial_coefficients(
    cos_part: sp.Expr, sin_part: sp.Expr, F: sp.Expr, Omega: sp.Expr
) -> tuple[sp.Expr, ...] | None:
    """Coefficients in W = Omega**2 of cos_part**2 + sin_part**2 - F**2, if it is a
    polynomial of degree <= 2 in W (not when the damping depends on the frequency
    otherwise than through an odd power)."""
    if not isinstance(Omega, sp.Symbol):
        return None
    W = sp.Dummy("W", positive=True)
    total = sp.expand(cos_part**2 + sin_part**2 - F**2)
    total = sp.expand(total.xreplace({Omega: sp.sqrt(W)}))
    if total.has(Omega):
        return None
    try:
        poly = sp.Poly(total, W)
    except sp.PolynomialError:
        return None
    if poly.degree() > 2 or any(c.has(W) for c in poly.all_coeffs()):
        return None
    coeffs = [sp.expand(poly.coeff_monomial(W**j)) for j in range(poly.degree() + 1)]
    return tuple(coeffs)


@states_caveats
def krylov_bogoliubov(
    oscillator: Oscillator, *, generating_frequency: sp.Expr | float | None = None
) -> Approximation:
    r"""First-order Krylov–Bogoliubov (polar) averaging.

    Forced, :math:`x'' + g(x, x') = F\cos(\Omega t + p_0)`: with
    :math:`x = a\cos\psi`, :math:`\psi = \Omega t + p_0 - \varphi`,

    .. math:: \dot a = \frac{G_s(a) + F\sin\varphi}{2\Omega}
              = \frac{-a\Omega c_{eq} + F\sin\varphi}{2\Omega},\qquad
              a\dot\varphi = \frac{\Omega^2 a - a k_{eq} + F\cos\varphi}{2\Omega},

    steady states :math:`a^2[(k_{eq} - \Omega^2)^2 + \Omega^2c_{eq}^2] = F^2`.

    Free, :math:`x'' + g(x, x') = 0`, about :math:`\omega_0` (default
    :math:`\sqrt{k}`): :math:`x = a\cos(\omega_0 t + \beta)`,

    .. math:: \dot a = \frac{G_s(a)}{2\omega_0} = -\frac{a\,c_{eq}(a, \omega_0)}{2},\qquad
              \dot\beta = \frac{k_{eq}(a) - \omega_0^2}{2\omega_0},

    backbone :math:`\omega = \omega_0 + \dot\beta` (Duffing: :math:`\omega_0 +
    3\varepsilon a^2/(8\omega_0)`), limit cycles where :math:`c_{eq}(a) = 0` (van der Pol:
    :math:`a = 2`).

    Parameters
    ----------
    oscillator
        ``x'' + g(x, x') = F cos(Omega t + p)`` or free; ``g`` may hold polynomial and
        piecewise-linear terms in ``x`` and ``x'`` (see :func:`fourier_components`).
    generating_frequency
        Free systems only: the frequency to average about (default: the linear natural
        frequency; required when the linear stiffness is not positive).

    Returns
    -------
    Approximation
        Forced: unknowns ``(a, phi)``, residuals, slow flow, ``frequency_polynomial`` when
        the amplitude equation is a polynomial of degree <= 2 in ``Omega**2`` (so
        :func:`~perturb.numeric.amplitude.approximation_response` applies), ``phase_from``.
        Free: unknowns ``(a, beta)``, slow flow ``(a', beta')``, residuals
        ``(a', omega - omega_0 - beta')`` and the ``backbone``.
        ``fourier`` holds ``k_eq``, ``c_eq``, ``G_c``, ``G_s``.

    Raises
    ------
    ModelError
        For parametric terms, several forcing harmonics, a static load or a force whose
        piecewise-linear part is not odd (the message names what applies), forces without
        closed-form coefficients, or a free system without a positive generating frequency.
    """
    osc = oscillator
    s = _setup(osc, generating_frequency, "Krylov-Bogoliubov averaging")
    a = sp.Symbol("a", positive=True)
    psi = real_symbol("psi")
    tau = real_symbol("tau")
    t = osc.t
    w = s.omega
    eq = equivalent_linearisation(osc, amplitude=a, frequency=w, values=s.values)
    gc, gs = eq.cos_component, eq.sin_component
    kf, cf = sp.Function("k_eq")(a), sp.Function("c_eq")(a)
    R = sp.Symbol("R")
    standard = sp.Eq(
        sp.Symbol(osc.x.name + "''") + w**2 * osc.x,
        w**2 * osc.x - osc.g + (osc.forcing.expr(t) if s.forced else 0),
    )
    steps: list[Step] = [Step("Equation of motion", (osc.equation,))]
    fourier = MappingProxyType({"k_eq": eq.stiffness, "c_eq": eq.damping, "G_c": gc, "G_s": gs})
    if s.forced:
        phi = real_symbol("phi")
        F, Omega = s.F, w
        a_dot = (gs + F * sp.sin(phi)) / (2 * Omega)
        phi_dot = (Omega**2 * a - gc + F * sp.cos(phi)) / (2 * Omega * a)
        cos_part, sin_part = gc - Omega**2 * a, -gs
        residuals = (sp.expand(cos_part - F * sp.cos(phi)), sp.expand(sin_part - F * sp.sin(phi)))
        steps += [
            Step(
                "Standard form about the forcing frequency",
                (standard,),
                "The right-hand side $R$ collects everything that is small in the weakly "
                "non-linear, lightly damped, near-resonant limit.",
            ),
            Step(
                "Variation of parameters (Krylov–Bogoliubov)",
                (
                    sp.Eq(osc.x, a * sp.cos(psi)),
                    sp.Eq(osc.v, -a * Omega * sp.sin(psi)),
                    sp.Eq(psi, Omega * t + s.phase - phi),
                    sp.Eq(sp.Derivative(a, t), -R * sp.sin(psi) / Omega),
                    sp.Eq(a * sp.Derivative(phi, t), R * sp.cos(psi) / Omega),
                ),
                "Requiring $x'$ to keep the form of the linear solution makes the two "
                "equations for the slowly varying amplitude $a$ and phase $\\varphi$ exact.",
            ),
            *_linearisation_step(eq, osc.x, osc.v, osc.g, psi),
            Step(
                "Averaging over one period of $\\psi$ at fixed $a$, $\\varphi$",
                (
                    sp.Eq(
                        sp.Derivative(a, t),
                        (-a * Omega * cf + F * sp.sin(phi)) / (2 * Omega),
                    ),
                    sp.Eq(
                        a * sp.Derivative(phi, t),
                        (Omega**2 * a - a * kf + F * sp.cos(phi)) / 2 / Omega,
                    ),
                ),
            ),
            Step(
                "Steady states: frequency-amplitude equation",
                (
                    sp.Eq(a * (kf - Omega**2), F * sp.cos(phi)),
                    sp.Eq(a * Omega * cf, F * sp.sin(phi)),
                    sp.Eq(a**2 * ((kf - Omega**2) ** 2 + Omega**2 * cf**2), F**2),
                ),
                "Squaring and adding eliminates the phase; these are the single-harmonic "
                "balance equations, so first-order averaging and harmonic balance share "
                "their steady states and averaging adds their stability.",
            ),
        ]
        return Approximation(
            oscillator=osc,
            method="kb",
            options={"order": 1, "harmonics": 1},
            unknowns=(a, phi),
            residuals=residuals,
            waveform=a * sp.cos(tau + s.phase - phi),
            tau=tau,
            frequency=Omega,
            slow_flow=(sp.expand(a_dot), phi_dot),
            amplitude=a,
            frequency_polynomial=frequency_polynomial_coefficients(cos_part, sin_part, F, Omega),
            phase_from=(cos_part, sin_part),
            fourier=fourier,
            steps=tuple(steps),
        )
    beta = real_symbol("beta")
    omega = response_frequency_symbol(osc)
    a_dot = sp.expand(gs / (2 * w))
    beta_dot = sp.expand((eq.stiffness - w**2) / (2 * w))
    backbone = w + beta_dot
    steps += [
        Step(
            "Standard form about the linear natural frequency",
            (standard,),
            f"Generating frequency ${latex(w)}$; the right-hand side $R$ is small for weak "
            "non-linearity and damping.",
        ),
        Step(
            "Variation of parameters (Krylov–Bogoliubov)",
            (
                sp.Eq(osc.x, a * sp.cos(psi)),
                sp.Eq(osc.v, -a * w * sp.sin(psi)),
                sp.Eq(psi, w * t + beta),
                sp.Eq(sp.Derivative(a, t), -R * sp.sin(psi) / w),
                sp.Eq(a * sp.Derivative(beta, t), -R * sp.cos(psi) / w),
            ),
        ),
        *_linearisation_step(eq, osc.x, osc.v, osc.g, psi),
        Step(
            "Averaged equations",
            (
                sp.Eq(sp.Derivative(a, t), -a * cf / 2),
                sp.Eq(sp.Derivative(beta, t), (kf - w**2) / (2 * w)),
                sp.Eq(sp.Derivative(a, t), a_dot),
                sp.Eq(sp.Derivative(beta, t), beta_dot),
            ),
        ),
        Step(
            "Frequency of the free oscillation and limit cycles",
            (sp.Eq(omega, backbone), sp.Eq(a_dot, 0)),
            "The phase drifts at the rate $\\beta'$, so the oscillation frequency is "
            "$\\omega_0 + \\beta'$ — the first-order Taylor form of the describing-function "
            "frequency $\\sqrt{k_{eq}(a)}$; amplitudes where the averaged damping vanishes are "
            "limit cycles, stable where $\\mathrm{d}a'/\\mathrm{d}a < 0$.",
        ),
    ]
    return Approximation(
        oscillator=osc,
        method="kb",
        options={"order": 1, "harmonics": 1},
        unknowns=(a, beta),
        residuals=(a_dot, omega - backbone),
        waveform=a * sp.cos(tau + beta),
        tau=tau,
        frequency=omega,
        slow_flow=(a_dot, beta_dot),
        amplitude=a,
        backbone=backbone,
        fourier=fourier,
        steps=tuple(steps),
    )


def response_frequency_symbol(osc: Oscillator) -> sp.Symbol:
    """The symbol for the (unknown) frequency of a free oscillation, not clashing with a
    parameter name; positive, so that ``sqrt(omega**2) = omega``."""
    name = "omega"
    while name in osc.params:
        name += "_r"
    return sp.Symbol(name, positive=True)


@states_caveats
def van_der_pol_averaging(
    oscillator: Oscillator, *, generating_frequency: sp.Expr | float | None = None
) -> Approximation:
    r"""First-order averaging by van der Pol's Cartesian technique.

    With :math:`x = p\cos\tau + q\sin\tau`, :math:`x' = \omega(-p\sin\tau + q\cos\tau)`,
    :math:`\tau = \omega t` (:math:`\omega = \Omega` forced, :math:`\omega_0` free) and
    :math:`R = \omega^2x - g + F\cos(\tau + p_0)`:

    .. math:: \dot p = -\frac{\langle R\sin\tau\rangle}{\omega}
                     = -\frac{(\omega^2 - k_{eq})q + \omega c_{eq}p - F\sin p_0}{2\omega},
              \qquad
              \dot q = \frac{\langle R\cos\tau\rangle}{\omega}
                     = \frac{(\omega^2 - k_{eq})p - \omega c_{eq}q + F\cos p_0}{2\omega},

    with :math:`k_{eq}, c_{eq}` at :math:`a = \sqrt{p^2 + q^2}`. Polynomial terms are averaged
    directly in :math:`\tau` (so the flow of a polynomial oscillator is a polynomial in
    :math:`p, q`, e.g. forced van der Pol); PWL terms enter through the closed-form
    :math:`k_{eq}(a)`, :math:`c_{eq}(a)`. Under :math:`p = a\cos\varphi`,
    :math:`q = a\sin\varphi` it is the Krylov–Bogoliubov flow (:func:`krylov_bogoliubov`).

    Returns
    -------
    Approximation
        Unknowns ``(p, q)``, residuals (``2*omega*(q', -p')`` = 0: cosine and sine balance),
        slow flow, waveform ``p cos(tau) + q sin(tau)``. No ``frequency_polynomial``: the
        amplitude equation is in the steps and in :func:`krylov_bogoliubov`.

    Raises
    ------
    ModelError
        As :func:`krylov_bogoliubov`.
    """
    osc = oscillator
    st = _setup(osc, generating_frequency, "van der Pol averaging")
    p, q = real_symbol("p"), real_symbol("q")
    tau = real_symbol("tau")
    t = osc.t
    w = st.omega
    x, v = osc.x, osc.v
    # polynomial terms exactly in tau; everything else through k_eq, c_eq at a = |(p, q)|
    poly = sp.Add(
        *(
            term
            for term in sp.Add.make_args(osc.g)
            if not is_nonsmooth(term) and term.is_polynomial(x, v)
        )
    )
    rest = sp.expand(osc.g - poly) if not is_nonsmooth(osc.g) else osc.g - poly
    forcing = st.F * sp.cos(tau + st.phase)
    on_orbit = {x: p * sp.cos(tau) + q * sp.sin(tau), v: w * (-p * sp.sin(tau) + q * sp.cos(tau))}
    R_poly = sp.expand(w**2 * on_orbit[x] - poly.xreplace(on_orbit) + forcing)
    c1, s1 = harmonics(R_poly, tau).get(1, (sp.Integer(0), sp.Integer(0)))
    mean_R_cos, mean_R_sin = c1 / 2, s1 / 2
    fourier: dict[str, sp.Expr] = {}
    a = sp.Symbol("a", positive=True)
    if rest != 0:
        eq = equivalent_linearisation(rest, x=x, v=v, amplitude=a, frequency=w, values=st.values)
        radius = sp.sqrt(p**2 + q**2)
        k_eq = eq.stiffness.xreplace({a: radius})
        c_eq = eq.damping.xreplace({a: radius})
        mean_R_cos -= (k_eq * p + c_eq * w * q) / 2
        mean_R_sin -= (k_eq * q - c_eq * w * p) / 2
        fourier.update(
            {"k_eq (non-polynomial part)": eq.stiffness, "c_eq (non-polynomial part)": eq.damping}
        )
    p_dot = sp.expand(-mean_R_sin / w)
    q_dot = sp.expand(mean_R_cos / w)
    eq_all = equivalent_linearisation(osc, amplitude=a, frequency=w, values=st.values)
    fourier.update({"k_eq": eq_all.stiffness, "c_eq": eq_all.damping})
    R = sp.Symbol("R")
    kf, cf = sp.Function("k_eq")(a), sp.Function("c_eq")(a)
    if rest != 0:
        # the PWL coefficients at a = sqrt(p^2 + q^2) make the explicit flow unreadable: the
        # derivation shows it with k_eq, c_eq by name (the fields hold it in full)
        p_show = -((w**2 - kf) * q + w * cf * p - st.F * sp.sin(st.phase)) / (2 * w)
        q_show = ((w**2 - kf) * p - w * cf * q + st.F * sp.cos(st.phase)) / (2 * w)
    else:
        p_show, q_show = p_dot, q_dot
    label = "forcing frequency" if st.forced else "linear natural frequency"
    steps = (
        Step("Equation of motion", (osc.equation,)),
        Step(
            f"Standard form about the {label}",
            (
                sp.Eq(
                    sp.Symbol(x.name + "''") + w**2 * x,
                    w**2 * x - osc.g + (osc.forcing.expr(t) if st.forced else 0),
                ),
            ),
        ),
        Step(
            "Van der Pol's transformation",
            (
                sp.Eq(x, on_orbit[x]),
                sp.Eq(v, on_orbit[v]),
                sp.Eq(tau, w * t),
                sp.Eq(sp.Derivative(p, t) * sp.cos(tau) + sp.Derivative(q, t) * sp.sin(tau), 0),
                sp.Eq(sp.Derivative(p, t), -R * sp.sin(tau) / w),
                sp.Eq(sp.Derivative(q, t), R * sp.cos(tau) / w),
            ),
            "The slowly varying Cartesian amplitudes $p$, $q$ replace the constants of the "
            "linear solution; the constraint keeps the velocity of the linear form.",
        ),
        *(_linearisation_step(eq_all, x, v, osc.g, real_symbol("psi")) if rest != 0 else ()),
        Step(
            "Averaged equations (first order)",
            (sp.Eq(sp.Derivative(p, t), p_show), sp.Eq(sp.Derivative(q, t), q_show))
            + ((sp.Eq(a, sp.sqrt(p**2 + q**2)),) if rest != 0 else ()),
            "Averaging over one period of $\\tau$ at fixed $p$, $q$; polynomial terms are "
            "averaged exactly, the others through $k_{eq}$ and $c_{eq}$ at "
            "$a = \\sqrt{p^2 + q^2}$.",
        ),
        Step(
            "Steady states",
            (
                sp.Eq(p_show, 0),
                sp.Eq(q_show, 0),
                sp.Eq(a**2 * ((kf - w**2) ** 2 + w**2 * cf**2), st.F**2),
            ),
            "With $p = a\\cos\\varphi$, $q = a\\sin\\varphi$ the fixed points satisfy the same "
            "frequency-amplitude equation as the polar (Krylov–Bogoliubov) form.",
        ),
    )
    return Approximation(
        oscillator=osc,
        method="vdp",
        options={"order": 1, "harmonics": 1},
        unknowns=(p, q),
        residuals=(sp.expand(2 * w * q_dot), sp.expand(-2 * w * p_dot)),
        waveform=p * sp.cos(tau) + q * sp.sin(tau),
        tau=tau,
        frequency=w if st.forced else response_frequency_symbol(osc),
        slow_flow=(p_dot, q_dot),
        fourier=MappingProxyType(fourier),
        steps=steps,
    )
