"""SymPy functions that stand for the closed-form Fourier coefficients.

The symbolic engines keep the coefficient of a nonsmooth term as a named function —
``StepCoefficient(n, A, b, d)`` is a_n of ``H(x - d)`` under ``x = A cos(psi) + b`` — rather than
as its formula. That keeps derivations short and readable (they print as the paper writes
them, ``a_n``), lets SymPy differentiate them exactly (the derivative of a ramp coefficient is
a step coefficient, of a step coefficient a Dirac coefficient), and lets the numeric layer
evaluate them with the stable vectorised forms of :mod:`perturb.fourier.coefficients` through
:data:`NUMERIC_IMPLEMENTATIONS` (a ``lambdify`` module) instead of the textbook formula, which
cancels catastrophically near grazing.

:func:`series_coefficient` turns any restoring force the Fourier engine handles — polynomial
terms plus a piecewise-linear part — into such an expression.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping

import numpy as np
import sympy as sp

from perturb.errors import FourierError, NonsmoothError
from perturb.fourier import coefficients as fourier
from perturb.model.pwl import PiecewiseLinear, is_nonsmooth, to_pwl

__all__ = [
    "StepCoefficient",
    "RampCoefficient",
    "DiracCoefficient",
    "NUMERIC_IMPLEMENTATIONS",
    "power_coefficient",
    "pwl_coefficient",
    "series_coefficient",
    "series_coefficients",
    "closed_form",
    "MAX_SERIES_ORDER",
    "MAX_SYMBOLIC_POWER",
]

#: Highest harmonic index :func:`series_coefficients` evaluates (``n_max``): the numeric forms
#: are accurate to ``n`` ~ 1e4 and 1e5 coefficients take well under a second, while
#: ``n_max = 1e9`` would allocate 8 GB before computing anything.
MAX_SERIES_ORDER = 100_000

#: Largest exponent ``m`` of :func:`power_coefficient` (exact binomial sums grow with ``m``; the
#: parser allows degrees up to 50, ``m = 1000`` takes about two seconds).
MAX_SYMBOLIC_POWER = 1000


def _as_sympy(value: object, name: str) -> sp.Expr:
    """A caller's amplitude or bias as a SymPy expression: strings through the safe parser
    (never ``sympify``), other values only if they are numbers or SymPy expressions."""
    if isinstance(value, str):
        from perturb.model.parsing import parse_expression

        return parse_expression(value)
    try:
        out = sp.sympify(value, strict=True)  # strict: no string parsing
    except (sp.SympifyError, TypeError) as exc:
        raise FourierError(f"{name} must be a SymPy expression or a number, got {value!r}") from exc
    if not isinstance(out, sp.Expr):
        raise FourierError(f"{name} must be a scalar SymPy expression, got {out!r}")
    if out.is_number and (out.has(sp.nan, sp.zoo, sp.oo, -sp.oo) or out.is_real is False):
        raise FourierError(f"{name} must be finite and real, got {name}={out}")
    return out


def _mirror(n: sp.Expr) -> sp.Expr:
    # a_{-n} = a_n for an even function of psi; used by the derivative rules at n = 0.
    return sp.Abs(n) if n.is_number else n


class _Coefficient(sp.Function):
    nargs = 4
    _letter = "a"
    _tag = ""

    def _latex(self, printer: sp.printing.latex.LatexPrinter, exp: str | None = None) -> str:
        n, A, b, d = (printer._print(a) for a in self.args)
        shift = f"{A}\\cos\\psi" + ("" if self.args[2] == 0 else f" + {b}")
        tex = f"{self._letter}^{{{self._tag}}}_{{{n}}}\\!\\left({shift};\\, {d}\\right)"
        return f"\\left({tex}\\right)^{{{exp}}}" if exp else tex

    @classmethod
    def eval(cls, n, A, b, d):  # noqa: D102 - SymPy hook
        if n.is_number and (n.is_integer is False or n.is_negative):
            raise FourierError(f"{cls.__name__}: harmonic index n = {n}, expected an integer >= 0")
        if all(a.is_number for a in (n, A, b, d)):
            return sp.Float(float(cls._numeric(int(n), float(A), float(b), float(d))), 17)
        return None

    @staticmethod
    def _numeric(n: int, A: float, b: float, d: float) -> float:
        raise NotImplementedError


class StepCoefficient(_Coefficient):
    r"""a_n of ``Heaviside(x - d)`` under ``x = A cos(psi) + b``.

    For ``|d - b| < A``: :math:`a_0 = 2\theta/\pi`, :math:`a_n = 2\sin(n\theta)/(n\pi)`,
    :math:`\theta = \arccos((d - b)/A)`; zero when ``x`` never exceeds ``d``; ``a_0 = 2`` and
    the rest zero when it always does.
    """

    _tag = "H"

    @staticmethod
    def _numeric(n, A, b, d):
        return fourier.step_coefficients(n, A, b, d)

    def fdiff(self, argindex: int = 1) -> sp.Expr:
        n, A, b, d = self.args
        if argindex == 2:  # d/dA H(A cos + b - d) = delta(...) cos(psi)
            return (
                DiracCoefficient(_mirror(n - 1), A, b, d) + DiracCoefficient(n + 1, A, b, d)
            ) / 2
        if argindex == 3:
            return DiracCoefficient(n, A, b, d)
        if argindex == 4:
            return -DiracCoefficient(n, A, b, d)
        raise sp.ArgumentIndexError(self, argindex)


class RampCoefficient(_Coefficient):
    r"""a_n of ``(x - d) Heaviside(x - d)`` under ``x = A cos(psi) + b``."""

    _tag = "R"

    @staticmethod
    def _numeric(n, A, b, d):
        return fourier.ramp_coefficients(n, A, b, d)

    def fdiff(self, argindex: int = 1) -> sp.Expr:
        n, A, b, d = self.args
        if argindex == 2:  # d/dA (A cos + b - d) H(...) = cos(psi) H(...)
            return (StepCoefficient(_mirror(n - 1), A, b, d) + StepCoefficient(n + 1, A, b, d)) / 2
        if argindex == 3:
            return StepCoefficient(n, A, b, d)
        if argindex == 4:
            return -StepCoefficient(n, A, b, d)
        raise sp.ArgumentIndexError(self, argindex)


class DiracCoefficient(_Coefficient):
    r"""a_n of ``DiracDelta(x - d)`` under ``x = A cos(psi) + b``:
    :math:`2\cos(n\theta)/(\pi A \sin\theta)` when ``|d - b| < A``, else zero."""

    _tag = "\\delta"

    @staticmethod
    def _numeric(n, A, b, d):
        return fourier.dirac_coefficients(n, A, b, d)

    def fdiff(self, argindex: int = 1) -> sp.Expr:
        raise FourierError(
            "derivatives of Dirac-delta Fourier coefficients are not available: they are "
            "singular at grazing"
        )


#: ``lambdify`` module mapping the function names above to perturb's numeric forms.
NUMERIC_IMPLEMENTATIONS: dict[str, object] = {
    "StepCoefficient": fourier.step_coefficients,
    "RampCoefficient": fourier.ramp_coefficients,
    "DiracCoefficient": fourier.dirac_coefficients,
}


def power_coefficient(m: int, n: int, A: sp.Expr, b: sp.Expr) -> sp.Expr:
    """a_n of ``x**m`` under ``x = A cos(psi) + b``, exactly.

    Uses :math:`\\cos^k\\psi = 2^{1-k}\\sum_j \\binom{k}{j}\\cos((k-2j)\\psi)` (with the
    ``k = 2j`` term halved), so only harmonics ``n <= m`` appear.

    Raises
    ------
    FourierError
        For ``m`` or ``n`` that are not integers ``>= 0``, or ``m >`` :data:`MAX_SYMBOLIC_POWER`.
    """
    for label, value in (("m", m), ("n", n)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise FourierError(f"power_coefficient: {label} = {value!r}, expected an integer >= 0")
    if m > MAX_SYMBOLIC_POWER:
        raise FourierError(
            f"power_coefficient: exponent m = {m}, expected at most {MAX_SYMBOLIC_POWER}"
        )
    m, n = int(m), int(n)
    total = sp.Integer(0)
    for k in range(n, m + 1):
        if (k - n) % 2:
            continue
        # coefficient of cos(n psi) in cos^k psi, in the a_n convention (a_0 is twice the mean)
        c = sp.Rational(2, 2**k) * sp.binomial(k, (k - n) // 2)
        total += sp.binomial(m, k) * b ** (m - k) * A**k * c
    return sp.expand(total)


def pwl_coefficient(pwl: PiecewiseLinear, n: int, A: sp.Expr, b: sp.Expr) -> sp.Expr:
    """a_n of a piecewise-linear force under ``x = A cos(psi) + b``, as step/ramp functions."""
    base_slope, base_offset, points, slope_jumps, value_jumps = pwl.ramp_step_form()
    expr = base_slope * power_coefficient(1, n, A, b) + base_offset * power_coefficient(0, n, A, b)
    for d, ds, dv in zip(points, slope_jumps, value_jumps, strict=True):
        if ds != 0:
            expr += ds * RampCoefficient(n, A, b, d)
        if dv != 0:
            expr += dv * StepCoefficient(n, A, b, d)
    return expr


def _classify(force: sp.Expr, x: sp.Symbol):
    """Split ``force`` into polynomial terms, piecewise-linear terms and Dirac terms
    ``(coefficient, d)`` meaning ``coefficient * DiracDelta(x - d)``."""
    poly_terms, pwl_terms, dirac_terms = [], [], []
    for term in sp.Add.make_args(sp.expand(force) if not is_nonsmooth(force) else force):
        if term.has(sp.DiracDelta):
            coeff, delta = term.as_independent(x, as_Add=False)
            if not isinstance(delta, sp.DiracDelta):
                raise FourierError(f"term {term}: expected c*DiracDelta(x - d)")
            arg = sp.expand(delta.args[0])
            slope = arg.coeff(x)
            if slope == 0 or sp.expand(arg - slope * x).has(x):
                raise FourierError(f"term {term}: the argument of DiracDelta must be linear in {x}")
            dirac_terms.append((coeff / sp.Abs(slope), -sp.expand(arg - slope * x) / slope))
        elif is_nonsmooth(term):
            pwl_terms.append(term)
        elif term.is_polynomial(x):
            poly_terms.append(term)
        else:
            raise FourierError(
                f"term {term} of the force has no closed-form Fourier coefficients: expected "
                "polynomial, piecewise-linear or DiracDelta terms"
            )
    return poly_terms, pwl_terms, dirac_terms


def _pwl_of(terms: list[sp.Expr], x: sp.Symbol, values: Mapping[str, float] | None):
    nonsmooth = sp.Add(*terms)
    try:
        return to_pwl(nonsmooth, x)
    except NonsmoothError:
        if not values:
            raise
        # symbolic breakpoints that cannot be ordered (d and -d with d merely real): order
        # them with the values of the parameters inside the switches only, so that the
        # other parameters (a stiffness k2 in front) stay symbolic
        inside: set[str] = set()
        for f in nonsmooth.atoms(sp.Heaviside, sp.Max, sp.Min, sp.Abs, sp.sign, sp.Piecewise):
            inside |= {str(sym) for sym in f.free_symbols if sym != x}
        return to_pwl(nonsmooth, x, values={k: v for k, v in values.items() if k in inside})


def series_coefficient(
    force: sp.Expr,
    x: sp.Symbol,
    n: int,
    A: sp.Expr,
    b: sp.Expr | int = 0,
    values: Mapping[str, float] | None = None,
) -> sp.Expr:
    """a_n of ``force(x)`` under ``x = A cos(psi) + b``.

    ``force`` may mix polynomial terms with piecewise-linear ones (Heaviside, Max, Min, Abs,
    sign, Piecewise) and ``DiracDelta(x - d)`` terms. ``values`` (parameter name -> number)
    are used only when symbolic breakpoints cannot be ordered otherwise.

    Raises
    ------
    FourierError
        For terms that are neither (``sin(x)`` has no finite closed form here).
    """
    if n < 0 or int(n) != n:
        raise FourierError(f"harmonic index n = {n}: expected an integer >= 0")
    n = int(n)
    A = _as_sympy(A, "A")
    b = _as_sympy(b, "b")
    poly_terms, pwl_terms, dirac_terms = _classify(force, x)
    expr = sp.Add(*(c * DiracCoefficient(n, A, b, d) for c, d in dirac_terms))
    for term in poly_terms:
        for (deg,), coeff in sp.Poly(term, x).terms():
            expr += coeff * power_coefficient(deg, n, A, b)
    if pwl_terms:
        expr += pwl_coefficient(_pwl_of(pwl_terms, x, values), n, A, b)
    return expr


def series_coefficients(
    force: sp.Expr, x: sp.Symbol, n_max: int, A: float, b: float = 0.0
) -> np.ndarray:
    """a_0 ... a_{n_max} of a force with numeric coefficients, vectorised over ``n``.

    The same decomposition as :func:`series_coefficient`, evaluated by the stable numeric
    forms of :mod:`perturb.fourier.coefficients` in one pass (fast for ``n_max`` in the thousands).

    Raises
    ------
    FourierError
        For ``n_max`` not an integer in ``[0, MAX_SERIES_ORDER]``, an amplitude ``A`` that is
        not finite and ``>= 0`` or a bias ``b`` that is not finite, free parameters, and for
        coefficients that overflow (``x**3`` at ``A = 1e200``: the message names ``A`` and
        ``b``).
    """
    if isinstance(n_max, bool) or not isinstance(n_max, numbers.Real):
        raise FourierError(f"n_max = {n_max!r}: expected an integer >= 0")
    if not math.isfinite(n_max) or int(n_max) != n_max or n_max < 0:
        raise FourierError(f"n_max = {n_max}: expected an integer >= 0")
    if n_max > MAX_SERIES_ORDER:
        raise FourierError(f"n_max = {n_max}: expected at most {MAX_SERIES_ORDER} harmonics")
    A = fourier._as_scalar("A", A)
    b = fourier._as_scalar("b", b)
    if A < 0:
        raise FourierError(f"A must be a finite real number >= 0, got A={A!r}")
    n = np.arange(int(n_max) + 1)
    poly_terms, pwl_terms, dirac_terms = _classify(force, x)
    out = np.zeros(n.size)
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported below
            _accumulate(out, n, A, b, x, poly_terms, pwl_terms, dirac_terms)
    except TypeError:
        free = sorted(str(s) for s in force.free_symbols - {x})
        raise FourierError(
            f"force {force} has parameters without values ({', '.join(free)})"
        ) from None
    if not np.all(np.isfinite(out)):
        raise FourierError(
            f"the Fourier coefficients of {force} overflow at A = {A:g}, b = {b:g}: expected "
            "an amplitude and bias for which the force stays below ~1e300"
        )
    return out


def _accumulate(out, n, A, b, x, poly_terms, pwl_terms, dirac_terms) -> None:
    """Add the coefficients of each kind of term to ``out`` (see :func:`series_coefficients`)."""
    for c, d in dirac_terms:
        out += float(c) * fourier.dirac_coefficients(n, A, b, float(d))
    for term in poly_terms:
        for (deg,), coeff in sp.Poly(term, x).terms():
            out += float(coeff) * fourier.power_coefficients(n, A, b, int(deg))
    if pwl_terms:
        rs = _pwl_of(pwl_terms, x, None).numeric().ramp_step_form()
        out += fourier.pwl_coefficients(n, A, b, *rs)


_SERIES = {
    StepCoefficient: fourier.step_series,
    RampCoefficient: fourier.ramp_series,
    DiracCoefficient: fourier.dirac_series,
}


def closed_form(
    expr: sp.Expr, theta: str = "theta"
) -> tuple[sp.Expr, tuple[tuple[sp.Symbol, sp.Expr], ...], tuple[sp.Basic, ...]]:
    """Replace the coefficient functions in ``expr`` by their textbook theta-forms.

    Each distinct switching point gets its own angle ``theta_i = arccos((d_i - b)/A)``,
    numbered in increasing ``d``. The forms hold where every switching point is crossed
    (``|d_i - b| < A``); the other regimes are exact zeros or linear terms, which the numeric
    layer evaluates anyway.

    Returns
    -------
    (expression, definitions, domains)
        ``definitions`` pairs each angle with its arccos; ``domains`` are the validity
        conditions.
    """
    calls = sorted(
        expr.atoms(StepCoefficient, RampCoefficient, DiracCoefficient),
        key=lambda c: sp.default_sort_key(c.args[1:]),
    )
    keys: list[tuple[sp.Expr, ...]] = []
    for c in calls:
        if tuple(c.args[1:]) not in keys:
            keys.append(tuple(c.args[1:]))
    if len(keys) > 1:
        try:
            keys.sort(key=lambda k: float(k[2] - k[1]))
        except TypeError:  # symbolic switching points: keep SymPy's order
            pass
    names = {
        k: sp.Symbol(f"{theta}_{i + 1}" if len(keys) > 1 else theta, positive=True)
        for i, k in enumerate(keys)
    }
    reps, definitions, domains = {}, {}, {}
    for c in calls:
        n, A, b, d = c.args
        if not n.is_Integer:
            continue
        series = _SERIES[type(c)](A, b, d, theta=names[(A, b, d)])
        reps[c] = series.coefficient(int(n))
        for sym, value in series.definitions:
            definitions[sym] = value
        domains[series.domain] = True
    return expr.xreplace(reps), tuple(definitions.items()), tuple(domains)
